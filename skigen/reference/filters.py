"""Reference augmented EKF, UKF and SKI steps in plain NumPy/SciPy: test oracle.

Conventions (shared with the CasADi derivation):

* One step at sample k takes the prior (mean ``z`` (n,), covariance or its lower
  Cholesky factor) for sample k, UPDATES with ``y_k`` (ny,), optionally runs ARD (SKI),
  records the posterior at k, then PREDICTS to k+1.
* ``f(z)`` (n,) -> (n,) is the discrete augmented transition and ``h(z)`` (n,) -> (ny,)
  the output map, both closures with u_k already bound.
* ``valid`` (ny,) bool: invalid outputs are dropped from the update. The returned
  innovation ``e`` (ny,) is 0 in invalid rows; ``Pyy`` (ny, ny) holds the innovation
  covariance in the valid block and the identity elsewhere; ``nis`` and ``loglik``
  use the valid block only (both 0 when no output is valid).
* EKF Jacobians default to complex-step differentiation, so model closures used with
  the reference EKF must be complex-step safe: only analytic operations on the state
  (write |x| as ``x * np.sign(np.real(x))``, avoid ``abs``, ``max``, ``np.real`` of the result...).
"""

import numpy as np

from .ard import ard_correct, ard_fixed_point, ard_optimise

LOG_2PI = np.log(2.0 * np.pi)


# --------------------------------------------------------------------------- helpers

def jacobian_cs(fun, z, h=1e-30):
    """Complex-step Jacobian (len(fun(z)), n) of fun at real z (n,): column j = imag(fun(z + i h e_j))/h."""
    z = np.asarray(z, dtype=float)
    cols = [np.imag(np.asarray(fun(z + 1j * h * e))) / h for e in np.eye(len(z))]
    return np.array(cols).reshape(len(z), -1).T


def chol(P):
    """Lower Cholesky factor of the symmetrised P."""
    return np.linalg.cholesky(0.5 * (P + P.T))


def merwe_weights(n, alpha, beta, kappa):
    """Merwe scaled weights: returns (Wm (2n+1,), Wc (2n+1,), gamma)."""
    lam = alpha**2 * (n + kappa) - n
    Wm = np.full(2 * n + 1, 0.5 / (n + lam))
    Wc = Wm.copy()
    Wm[0] = lam / (n + lam)
    Wc[0] = Wm[0] + 1.0 - alpha**2 + beta
    return Wm, Wc, np.sqrt(n + lam)


def sigma_points(z, S, gamma):
    """Sigma points as rows (2n+1, n): [z, z + γ S[:, i] (i = 0..n−1), z − γ S[:, i]]."""
    return np.vstack([z, z + gamma * S.T, z - gamma * S.T])


def _weighted_cov(Wc, A, B):
    """Σ_i Wc_i A_i B_iᵀ for rows A_i, B_i (deviations)."""
    return (A * Wc[:, None]).T @ B


def innovation_update(z, y, valid, yhat, Pyy, Pzy):
    """Shared measurement update on the valid outputs.

    yhat (ny,), Pyy (ny, ny) (incl. R), Pzy (n, ny): predicted output statistics.
    Returns a dict: z_post (n,), K (n, nv), Pyy_v (nv, nv), v (valid indices),
    e (ny,), Pyy (ny, ny), nis, loglik.
    """
    v = np.flatnonzero(valid)
    ev = (np.asarray(y, float) - yhat)[v]
    Pyy_v = Pyy[np.ix_(v, v)]
    K = np.linalg.solve(Pyy_v, Pzy[:, v].T).T if len(v) else np.zeros((len(z), 0))
    nis = float(ev @ np.linalg.solve(Pyy_v, ev)) if len(v) else 0.0
    loglik = -0.5 * (nis + len(v) * LOG_2PI + np.linalg.slogdet(Pyy_v)[1]) if len(v) else 0.0
    e = np.zeros(len(yhat))
    e[v] = ev
    Pyy_out = np.eye(len(yhat))
    Pyy_out[np.ix_(v, v)] = Pyy_v
    return dict(z_post=z + K @ ev, K=K, Pyy_v=Pyy_v, v=v,
                e=e, Pyy=Pyy_out, nis=nis, loglik=loglik)


def _out(upd, **kw):
    """Public step result: the innovation statistics plus the given entries."""
    return dict(e=upd["e"], Pyy=upd["Pyy"], nis=upd["nis"], loglik=upd["loglik"], **kw)


# --------------------------------------------------------------------------- EKF

def hessians_cs(fun, z, delta=1e-6):
    """Hessians (m, n, n) of fun's m outputs at real z: central differences (step delta × max(1, |z_j|))
    of the complex-step Jacobian, accurate to O(delta²)."""
    z = np.asarray(z, dtype=float)
    cols = []
    for j in range(len(z)):
        d = delta * max(1.0, abs(z[j])) * np.eye(len(z))[j]
        cols.append((jacobian_cs(fun, z + d) - jacobian_cs(fun, z - d)) / (2 * d[j]))
    H = np.stack(cols, axis=2)                     # H[i, k, j] = ∂²f_i / ∂z_k ∂z_j
    return 0.5 * (H + H.transpose(0, 2, 1))


def ekf_step(z, P, y, valid, f, h, Q, R, jac_f=None, jac_h=None, second_order=False):
    """One augmented-EKF step (update at k, then predict to k+1).

    z (n,), P (n, n): prior at k; y (ny,); valid (ny,) bool; Q (n, n); R (ny, ny).
    jac_f, jac_h: optional callables z -> Jacobian; default complex-step.
    second_order: the second-order prediction, z⁻ᵢ += ½ tr(Hᵢ P), P⁻ᵢⱼ += ½ tr(Hᵢ P Hⱼ P)
    (Hessians by :func:`hessians_cs`).
    Returns dict: z_post, P_post, z, P (prior at k+1), e, Pyy, nis, loglik.
    """
    H = jac_h(z) if jac_h is not None else jacobian_cs(h, z)
    upd = innovation_update(z, y, valid, np.asarray(h(z), float), H @ P @ H.T + R, P @ H.T)
    K, v = upd["K"], upd["v"]
    IKH = np.eye(len(z)) - K @ H[v]
    z_post = upd["z_post"]
    P_post = IKH @ P @ IKH.T + K @ R[np.ix_(v, v)] @ K.T
    A = jac_f(z_post) if jac_f is not None else jacobian_cs(f, z_post)
    z_next, P_next = np.asarray(f(z_post), float), A @ P_post @ A.T + Q
    if second_order:
        HP = hessians_cs(f, z_post) @ P_post
        z_next = z_next + 0.5 * np.trace(HP, axis1=1, axis2=2)
        P_next = P_next + 0.5 * np.einsum("iab,jba->ij", HP, HP)
    return _out(upd, z_post=z_post, P_post=P_post, z=z_next, P=P_next)


# --------------------------------------------------------------------------- UKF / SKI

def _ukf_update(z, S, y, valid, h, R, Wm, Wc, gamma):
    """Unscented update from (z, S); returns (innovation dict, posterior covariance P)."""
    X = sigma_points(z, S, gamma)
    Y = np.array([np.asarray(h(x), float) for x in X])
    yhat = Wm @ Y
    dY = Y - yhat
    upd = innovation_update(z, y, valid, yhat,
                            _weighted_cov(Wc, dY, dY) + R, _weighted_cov(Wc, X - z, dY))
    K = upd["K"]
    return upd, S @ S.T - K @ upd["Pyy_v"] @ K.T


def _ukf_predict(z, S, f, Q, Wm, Wc, gamma):
    """Unscented prediction from the posterior (z, S); returns (z⁻, S⁻)."""
    Xf = np.array([np.asarray(f(x), float) for x in sigma_points(z, S, gamma)])
    z_pred = Wm @ Xf
    dX = Xf - z_pred
    return z_pred, chol(_weighted_cov(Wc, dX, dX) + Q)


def ukf_step(z, S, y, valid, f, h, Q, R, alpha, beta, kappa):
    """One augmented-UKF step (textbook covariance form, Merwe scaled sigma points).

    z (n,), S (n, n) lower Cholesky factor of the prior covariance at k; y (ny,);
    valid (ny,) bool; Q (n, n); R (ny, ny).
    Returns dict: z_post, S_post, z, S (prior at k+1), e, Pyy, nis, loglik.
    """
    W = merwe_weights(len(z), alpha, beta, kappa)
    upd, P = _ukf_update(z, S, y, valid, h, R, *W)
    S_post = chol(P)
    z_pred, S_pred = _ukf_predict(upd["z_post"], S_post, f, Q, *W)
    return _out(upd, z_post=upd["z_post"], S_post=S_post, z=z_pred, S=S_pred)


def ski_step(z, S, s, y, valid, f, h, Q, R, w_idx, alpha, beta, kappa,
             eta=0.3, n_steps=1, margin=0.9, s_min=1e-10, s_max=1e6, max_step=1.0, backtracks=3,
             ard="gradient", s0=None, s_floor=1e-8):
    """One SKI step: UKF update, ARD on the prior variances s (m,) of z[w_idx], UKF predict.

    Arguments as ukf_step plus the ARD settings. ard='gradient' (see ard.ard_optimise): the
    posterior is corrected to the new prior and predicted from. ard='em' (see
    ard.ard_fixed_point, s0 the declared prior variances): the UKF posterior is kept and
    predicted from; the reported mean z_post is the posterior mean under the new prior and
    the reported factor S_post that of P + (z_post − z)(z_post − z)ᵀ, z the UKF's mean.
    Returns the ukf_step dict plus "s" (m,), the new prior variances.
    """
    W = merwe_weights(len(z), alpha, beta, kappa)
    upd, P = _ukf_update(z, S, y, valid, h, R, *W)
    w_idx = np.asarray(w_idx)
    z_post = upd["z_post"]
    if ard == "gradient":
        s_new = ard_optimise(s, z_post[w_idx], P[np.ix_(w_idx, w_idx)],
                             eta, n_steps, margin, s_min, s_max, max_step, backtracks)
        z_post, P = ard_correct(z_post, P, w_idx, s_new, s)
        z_report = z_post
    else:
        drift = np.any(Q[np.ix_(w_idx, w_idx)])
        z_report, s_new = ard_fixed_point(z_post, P, w_idx, s, np.asarray(s0, float), margin,
                                          s_floor, s_max, drift)
    S_post = chol(P)
    z_pred, S_pred = _ukf_predict(z_post, S_post, f, Q, *W)
    d = z_report - z_post                  # EM: the covariance reported about the reported mean
    return _out(upd, z_post=z_report, S_post=chol(P + np.outer(d, d)), z=z_pred, S=S_pred, s=s_new)
