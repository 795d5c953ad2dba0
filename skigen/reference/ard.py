"""Online ARD (automatic relevance determination) in plain NumPy: test oracle.

Implements section 4 of ``docs/ski-math.md``. Notation, for ``m`` weights:

* ``s`` (m,): current prior variances of the weights, ``w ~ N(0, diag(s))``;
* ``s_new`` / ``s'`` (m,): proposed prior variances;
* ``mu`` (m,), ``Pww`` (m, m): the filter's posterior of ``w`` obtained under ``s``;
* ``D = diag(1/s' - 1/s)`` (1/variance units; zero when nothing changes).

All variances are in the squared units of the weights. No CasADi here.
"""

import numpy as np
from scipy.special import expit


def softplus(x):
    """log(1 + exp(x)), elementwise and overflow-free."""
    return np.logaddexp(0.0, x)


def softplus_inv(s):
    """Inverse of softplus for s > 0: log(expm1(s)) = s + log(1 - exp(-s)), stable for large s."""
    s = np.asarray(s, dtype=float)
    return s + np.log(-np.expm1(-s))


def sigmoid(x):
    """1 / (1 + exp(-x)), the derivative of softplus."""
    return expit(x)


def _d(s_new, s_old):
    """Diagonal of D = diag(1/s_new - 1/s_old), shape (m,)."""
    return 1.0 / np.asarray(s_new, float) - 1.0 / np.asarray(s_old, float)


def ard_loss(s_new, s_old, mu, Pww):
    """ARD loss L(s') (scalar), = -log p(y|s') + log p(y|s) + ½Σ log s_i for a linear-Gaussian model.

    L(s') = ½ Σ log s'_i + ½ log det(I + D Pww) + ½ μᵀ (I + D Pww)⁻¹ D μ.
    Returns nan when det(I + D Pww) <= 0 (the proposal is not admissible).
    """
    d = _d(s_new, s_old)
    A = np.eye(len(d)) + d[:, None] * Pww
    sign, logdet = np.linalg.slogdet(A)
    if sign <= 0:
        return np.nan
    quad = mu @ np.linalg.solve(A, d * mu)
    return 0.5 * (np.sum(np.log(s_new)) + logdet + quad)


def ard_grad(xi, s_old, mu, Pww):
    """Gradient dL/dξ (m,) of ard_loss with s' = softplus(ξ).

    b = (I + Pww D)⁻¹ μ, M = Pww (I + D Pww)⁻¹ (= (I + Pww D)⁻¹ Pww),
    grad_i = sigmoid(ξ_i) [1/(2 s'_i) − (M_ii + b_i²)/(2 s'_i²)].
    """
    s = softplus(xi)
    d = _d(s, s_old)
    B = np.eye(len(d)) + Pww * d[None, :]          # I + Pww D
    b = np.linalg.solve(B, mu)
    M = np.linalg.solve(B, Pww)
    return sigmoid(xi) * (0.5 / s - (np.diag(M) + b**2) / (2.0 * s**2))


def ard_correct(m, P, w_idx, s_new, s_old):
    """Posterior under prior variances s_new from the posterior (m (n,), P (n, n)) under s_old.

    Pseudo-observation 0 = w + v, v ~ N(0, D⁻¹), in a form finite as D → 0:
    K = P[:, w] (I + D Pww)⁻¹ D; m' = m − K m[w]; P' = P − K P[w, :].
    Returns (m' (n,), P' (n, n)), P' symmetrised.
    """
    w_idx = np.asarray(w_idx)
    d = _d(s_new, s_old)
    A = np.eye(len(d)) + d[:, None] * P[np.ix_(w_idx, w_idx)]
    K = P[:, w_idx] @ np.linalg.solve(A, np.diag(d))
    m_new = m - K @ m[w_idx]
    P_new = P - K @ P[w_idx, :]
    return m_new, 0.5 * (P_new + P_new.T)


def ard_project(s_new, s_old, Pww, margin, s_min, s_max):
    """Guard a proposal s_new (m,): keep λmin(I + LᵀDL) ≥ margin (L = chol(Pww)) and s' in [s_min, s_max].

    g = max_i Σ_j |Pww_ij| (Gershgorin bound on λmax(Pww)), c = (1 − margin)/g;
    D is clipped to ≥ −c, ≥ 1/s_max − 1/s_old, ≤ 1/s_min − 1/s_old; returns 1/(1/s_old + D).
    """
    g = np.max(np.sum(np.abs(Pww), axis=1))
    with np.errstate(divide="ignore"):
        c = (1.0 - margin) / g
    d = _d(s_new, s_old)
    d = np.maximum(d, -c)
    d = np.maximum(d, 1.0 / s_max - 1.0 / s_old)
    d = np.minimum(d, 1.0 / s_min - 1.0 / s_old)
    return 1.0 / (1.0 / s_old + d)


def ard_optimise(s_old, mu, Pww, eta, n_steps, margin, s_min, s_max, max_step, backtracks=3):
    """n_steps projected, backtracked gradient steps on ξ = softplus⁻¹(s'), from s' = s_old; returns s' (m,).

    Each step: Δ = clip(η ∂L/∂ξ, ±max_step); among the trial points
    ard_project(softplus(ξ − 2⁻ʲ Δ)), j = backtracks … 0, keep the longest one that
    lowers L (else stay); ξ ← softplus⁻¹(s'). With n_steps = 0 returns s_old.
    """
    s = np.array(s_old, dtype=float)
    xi = softplus_inv(s)
    for _ in range(n_steps):
        step = np.clip(eta * ard_grad(xi, s_old, mu, Pww), -max_step, max_step)
        loss = ard_loss(s, s_old, mu, Pww)
        best = s
        for j in range(backtracks, -1, -1):
            trial = ard_project(softplus(xi - 2.0 ** -j * step), s_old, Pww, margin, s_min, s_max)
            if ard_loss(trial, s_old, mu, Pww) < loss:
                best = trial
        s = best
        xi = softplus_inv(s)
    return s


def ard_fixed_point(m, P, w_idx, s, s0, margin, s_floor, s_max, drift=False):
    """One fixed-point ARD update on a posterior (m (n,), P (n, n)) under the declared prior s0.

    The posterior under s is the exact correction of (m, P) from s0 to s; the EM update
    s' = μ_s² + diag(P_s)[w] is bounded to [s_floor Pww_ii, s_max] and, with random-walk
    weights (drift), D_i = 1/s' − 1/s0 ≥ −(1 − margin)/(m Pww_ii). Returns (m' (n,), the mean under s', s' (m,)).
    """
    w_idx = np.asarray(w_idx)
    m_s, P_s = ard_correct(m, P, w_idx, s, s0)
    s_new = m_s[w_idx] ** 2 + np.diag(P_s)[w_idx]
    p = np.diag(P)[w_idx]
    if drift:
        s_new = 1.0 / (1.0 / s0 + np.maximum(_d(s_new, s0), -(1.0 - margin) / (len(s) * p)))
    s_new = np.minimum(np.maximum(s_new, s_floor * p), s_max)
    return ard_correct(m, P, w_idx, s_new, s0)[0], s_new
