"""Online automatic relevance determination (ski-math.md section 4), symbolic.

All quantities go through B = I + Lᵀ D L (L = chol(P_ww), D = diag(1/s' − 1/s)),
which is symmetric, stays positive definite under the guard, and reduces to
I when nothing changes:

    (I + D P)⁻¹ D = D − D L B⁻¹ Lᵀ D,   (I + P D)⁻¹ μ = μ − L B⁻¹ Lᵀ D μ,
    P (I + D P)⁻¹ = L B⁻¹ Lᵀ,           det(I + D P) = det B.
"""
from __future__ import annotations

import casadi as ca

from .linalg import backward, chol, forward, spd_solve, symmetrize

__all__ = ["softplus", "softplus_inv", "sigmoid", "ard_loss", "ard_grad", "ard_project",
           "ard_optimise", "ard_correct"]


def softplus(x):
    return ca.fmax(x, 0) + ca.log1p(ca.exp(-ca.fabs(x)))


def softplus_inv(s):
    return s + ca.log(-ca.expm1(-s))


def sigmoid(x):
    return 1 / (1 + ca.exp(-x))


def _pieces(s_new, s_old, mu, Lw):
    D = 1 / s_new - 1 / s_old
    Lb = chol(ca.SX.eye(Lw.shape[0]) + Lw.T @ ca.diag(D) @ Lw)
    G = forward(Lb, Lw.T)                       # M = Gᵀ G = L B⁻¹ Lᵀ
    c = forward(Lb, Lw.T @ (D * mu))            # ‖c‖² = μᵀ D L B⁻¹ Lᵀ D μ
    return D, Lb, G, c


def ard_loss(s_new, s_old, mu, Lw):
    """L(s') up to a constant: minus the log evidence of past data under s'."""
    D, Lb, _, c = _pieces(s_new, s_old, mu, Lw)
    quad = ca.dot(mu, D * mu) - ca.dot(c, c)
    return 0.5 * ca.sum1(ca.log(s_new)) + ca.sum1(ca.log(ca.diag(Lb))) + 0.5 * quad


def ard_grad(xi, s_old, mu, Lw):
    """∂L/∂ξ with s' = softplus(ξ)."""
    s_new = softplus(xi)
    D, Lb, G, c = _pieces(s_new, s_old, mu, Lw)
    b = mu - Lw @ backward(Lb.T, c)
    M_diag = ca.sum1(G * G).T
    return sigmoid(xi) * (1 / (2 * s_new) - (M_diag + b * b) / (2 * s_new ** 2))


def ard_project(s_new, s_old, Pww, opts):
    """Keep λmin(I + Lᵀ D L) ≥ margin (Gershgorin bound on λmax(P_ww)) and s' in [s_min, s_max]."""
    g = ca.mmax(ca.sum2(ca.fabs(Pww)))
    D = 1 / s_new - 1 / s_old
    D = ca.fmax(D, -(1 - opts.margin) / g)
    D = ca.fmax(D, 1 / opts.s_max - 1 / s_old)
    D = ca.fmin(D, 1 / opts.s_min - 1 / s_old)
    return 1 / (1 / s_old + D)


def ard_optimise(s_old, mu, Pww, opts):
    """N_hp clipped gradient steps on ξ from ξ = softplus⁻¹(s), each projected and
    backtracked: the longest of the steps 2⁻ʲ Δ (j = backtracks … 0) that lowers L."""
    Lw = chol(Pww)
    xi = softplus_inv(s_old)
    s_new = s_old
    for _ in range(opts.ard_steps):
        step = ca.fmin(ca.fmax(opts.eta * ard_grad(xi, s_old, mu, Lw), -opts.max_step), opts.max_step)
        loss = ard_loss(s_new, s_old, mu, Lw)
        best = s_new
        for j in range(opts.backtracks, -1, -1):
            trial = ard_project(softplus(xi - 2.0 ** -j * step), s_old, Pww, opts)
            best = ca.if_else(ard_loss(trial, s_old, mu, Lw) < loss, trial, best)
        s_new = best
        xi = softplus_inv(s_new)
    return s_new


def ard_correct(z, P, w_index, s_new, s_old):
    """Posterior under the new prior: the pseudo-observation 0 = w + v, v ~ N(0, D⁻¹)."""
    w = list(w_index)
    Pzw = P[:, w]
    Lw = chol(P[w, w])
    D, Lb, _, _ = _pieces(s_new, s_old, z[w], Lw)
    DL = ca.diag(D) @ Lw
    X = ca.diag(D) - DL @ spd_solve(Lb, DL.T)   # (I + D P_ww)⁻¹ D
    K = Pzw @ X
    return z - K @ z[w], symmetrize(P - K @ Pzw.T)
