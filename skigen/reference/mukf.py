"""Reference marginalised UKF (Morelande & Moran, 2007) in plain NumPy: test oracle.

Model, with u_k already bound into the callables, the state split into the
nonlinear part z_n = z[nl] and the conditionally linear part z_l = z[ll]:

    z[k+1] = d(z_n) + A(z_n) z_l + w,   w ~ N(0, Q)      d: (n,),  A: (n, n_l)
    y[k]   = c(z_n) + C(z_n) z_l + v,   v ~ N(0, R)      c: (ny,), C: (ny, n_l)

Textbook covariance form, written from the equations and nothing else:
with the prior N(m, P) split into blocks, sigma points χ_i of N(m_n, P_nn)
(Merwe scaled, 2 n_n + 1 points; one point of weight 1 when n_n = 0), and for
each point the Gaussian conditional of z_l given z_n = χ_i,

    m_l|i = m_l + P_ln P_nn⁻¹ (χ_i − m_n),   P_l|n = P_ll − P_ln P_nn⁻¹ P_nl,

the moments of an affine function g(z) = a(z_n) + G(z_n) z_l are matched
exactly given each point (law of total covariance):

    ḡ   = Σ Wm_i g_i,                  g_i = a(χ_i) + G(χ_i) m_l|i
    Cov = Σ Wc_i (g_i − ḡ)(g_i − ḡ)ᵀ + Σ Wm_i G(χ_i) P_l|n G(χ_i)ᵀ
    Cov(z, g) = Σ Wc_i (ζ_i − m)(g_i − ḡ)ᵀ + Σ Wm_i E_l P_l|n G(χ_i)ᵀ,   ζ_i = (χ_i, m_l|i)

Step conventions (update with y_k, then predict; ``valid``; outputs) are those
of :mod:`skigen.reference.filters`.
"""

import numpy as np

from .filters import _out, chol, innovation_update, merwe_weights, sigma_points


def affine_from_closures(f, h, nl, ll, n):
    """(d, A, c, C) of f(z), h(z) that are affine in z[ll] given z[nl], by evaluating them at
    z_l = 0 and at the unit vectors (exact for affine maps)."""
    nl, ll = np.asarray(nl, int), np.asarray(ll, int)

    def split(fun):
        def at(zn, zl):
            z = np.zeros(n)
            z[nl], z[ll] = zn, zl
            return np.asarray(fun(z), float)

        def a(zn):
            return at(zn, np.zeros(len(ll)))

        def G(zn):
            base = a(zn)
            return np.column_stack([at(zn, e) - base for e in np.eye(len(ll))]) if len(ll) else \
                np.zeros((len(base), 0))
        return a, G

    d, A = split(f)
    c, C = split(h)
    return d, A, c, C


def _weights(n_n, alpha, beta, kappa):
    if n_n == 0:
        return np.ones(1), np.ones(1), 0.0
    return merwe_weights(n_n, alpha, beta, kappa)


def _points(m, P, nl, ll, W):
    """Sigma points χ_i (rows), full conditional means ζ_i (rows) and P_l|n."""
    Wm, Wc, gamma = W
    Pnn, Pln, Pll = P[np.ix_(nl, nl)], P[np.ix_(ll, nl)], P[np.ix_(ll, ll)]
    if len(nl):
        chi = sigma_points(m[nl], chol(Pnn), gamma)
        gain = np.linalg.solve(Pnn, Pln.T).T                    # P_ln P_nn⁻¹
    else:
        chi, gain = np.zeros((1, 0)), np.zeros((len(ll), 0))
    zeta = np.tile(m, (len(chi), 1))
    zeta[:, nl] = chi
    zeta[:, ll] = m[ll] + (chi - m[nl]) @ gain.T
    return chi, zeta, Pll - gain @ Pln.T


def _moments(a, G, chi, zeta, Pc, ll, n, W):
    """Mean, covariance (without noise) and cross-covariance with z of g = a + G z_l."""
    Wm, Wc, _ = W
    g = np.array([a(x) + G(x) @ zl for x, zl in zip(chi, zeta[:, ll])])
    gbar = Wm @ g
    dg, dz = g - gbar, zeta - zeta[0]
    cov = (dg * Wc[:, None]).T @ dg
    cross = (dz * Wc[:, None]).T @ dg
    for w, x in zip(Wm, chi):
        Gx = G(x)
        cov += w * Gx @ Pc @ Gx.T
        cross[ll] += w * Pc @ Gx.T
    return gbar, cov, cross


def mukf_update(z, S, y, valid, nl, ll, c, C, R, alpha, beta, kappa):
    """Measurement update from the prior (z, S S ᵀ); returns (innovation dict, posterior P)."""
    nl, ll = np.asarray(nl, int), np.asarray(ll, int)
    W = _weights(len(nl), alpha, beta, kappa)
    P = S @ S.T
    chi, zeta, Pc = _points(z, P, nl, ll, W)
    yhat, Pyy, Pzy = _moments(c, C, chi, zeta, Pc, ll, len(z), W)
    upd = innovation_update(z, y, valid, yhat, Pyy + R, Pzy)
    K = upd["K"]
    return upd, P - K @ upd["Pyy_v"] @ K.T


def mukf_predict(z, P, nl, ll, d, A, Q, alpha, beta, kappa):
    """Time update from the posterior (z, P); returns (z⁻, S⁻)."""
    nl, ll = np.asarray(nl, int), np.asarray(ll, int)
    W = _weights(len(nl), alpha, beta, kappa)
    chi, zeta, Pc = _points(z, P, nl, ll, W)
    m, Pm, _ = _moments(d, A, chi, zeta, Pc, ll, len(z), W)
    return m, chol(Pm + Q)


def mukf_step(z, S, y, valid, nl, ll, d, A, c, C, Q, R, alpha, beta, kappa):
    """One MUKF step (update at k, predict to k+1); returns the dict of
    :func:`skigen.reference.filters.ukf_step`: z_post, S_post, z, S, e, Pyy, nis, loglik."""
    upd, P = mukf_update(z, S, y, valid, nl, ll, c, C, R, alpha, beta, kappa)
    z_pred, S_pred = mukf_predict(upd["z_post"], P, nl, ll, d, A, Q, alpha, beta, kappa)
    return _out(upd, z_post=upd["z_post"], S_post=chol(P), z=z_pred, S=S_pred)
