"""Online automatic relevance determination (ski-math.md section 4), symbolic.

Everything works from a factor F of the weights' posterior covariance,
P_ww = F Fᵀ — for SKI the weight rows of the filter's own Cholesky factor,
F = S[w, :], so nothing is squared — through B = I + Fᵀ D F,
D = diag(1/s' − 1/s), which is symmetric, stays positive definite under the
guard, and is I when nothing changes:

    (I + D P)⁻¹ D = D − D F B⁻¹ Fᵀ D,   (I + P D)⁻¹ μ = μ − F B⁻¹ Fᵀ D μ,
    P (I + D P)⁻¹ = F B⁻¹ Fᵀ,           det(I + D P) = det B,

and the corrected covariance is P' = S B⁻¹ Sᵀ, so S' = tria(S L_B⁻ᵀ).

The EM update ('em') keeps the filter on the declared prior s₀; the ARD
posterior is a view of the filter's, corrected with D = 1/s − 1/s₀ by the
same pieces (never fed back; SKI reports its mean z′ with the filter's second
moment about it, P + (z′ − z)(z′ − z)ᵀ, ski.py), and the relevance update is the EM fixed point
s' = μ² + P_s,ii from the weights' moments under s, diag P_s = diag(F B⁻¹ Fᵀ)
the column sums of squares of G (no cancellation). With constant
weights P_ww ≤ diag(s₀) (updates only shrink it, predictions leave it), so
P_s⁻¹ = P_ww⁻¹ + D ≥ diag(1/s) and B is positive definite for any s; with
random-walk weights the guard D_i ≥ −(1 − margin)/(m P_ii) (a trace bound:
λmin(B) ≥ margin) limits the widening.
"""
from __future__ import annotations

import casadi as ca

from .linalg import backward, chol, forward, tria

__all__ = ["softplus", "softplus_inv", "sigmoid", "ard_loss", "ard_grad", "ard_project",
           "ard_optimise", "ard_correct", "ard_view", "ard_guard"]


def softplus(x):
    return ca.fmax(x, 0) + ca.log1p(ca.exp(-ca.fabs(x)))


def softplus_inv(s):
    return s + ca.log(-ca.expm1(-s))


def sigmoid(x):
    return 1 / (1 + ca.exp(-x))


def _pieces(s_new, s_old, mu, F):
    D = 1 / s_new - 1 / s_old
    Lb = chol(ca.SX.eye(F.shape[1]) + F.T @ ca.diag(D) @ F)
    G = forward(Lb, F.T)                        # M = Gᵀ G = F B⁻¹ Fᵀ
    c = forward(Lb, F.T @ (D * mu))             # ‖c‖² = μᵀ D F B⁻¹ Fᵀ D μ
    return D, Lb, G, c


def ard_loss(s_new, s_old, mu, F):
    """L(s') up to a constant: minus the log evidence of past data under s'."""
    D, Lb, _, c = _pieces(s_new, s_old, mu, F)
    quad = ca.dot(mu, D * mu) - ca.dot(c, c)
    return 0.5 * ca.sum1(ca.log(s_new)) + ca.sum1(ca.log(ca.diag(Lb))) + 0.5 * quad


def ard_grad(xi, s_old, mu, F):
    """∂L/∂ξ with s' = softplus(ξ)."""
    s_new = softplus(xi)
    D, Lb, G, c = _pieces(s_new, s_old, mu, F)
    b = mu - F @ backward(Lb.T, c)
    M_diag = ca.sum1(G * G).T
    return sigmoid(xi) * (1 / (2 * s_new) - (M_diag + b * b) / (2 * s_new ** 2))


def ard_project(s_new, s_old, F, opts):
    """Keep λmin(I + Fᵀ D F) ≥ margin (Gershgorin bound on λmax(P_ww)) and s' in [s_min, s_max]."""
    g = ca.mmax(ca.sum2(ca.fabs(F @ F.T)))
    D = 1 / s_new - 1 / s_old
    D = ca.fmax(D, -(1 - opts.margin) / g)
    D = ca.fmax(D, 1 / opts.s_max - 1 / s_old)
    D = ca.fmin(D, 1 / opts.s_min - 1 / s_old)
    return 1 / (1 / s_old + D)


def ard_optimise(s_old, mu, F, opts):
    """N_hp clipped gradient steps on ξ from ξ = softplus⁻¹(s), each projected and
    backtracked: the longest of the steps 2⁻ʲ Δ (j = backtracks … 0) that lowers L."""
    xi = softplus_inv(s_old)
    s_new = s_old
    for _ in range(opts.ard_steps):
        step = ca.fmin(ca.fmax(opts.eta * ard_grad(xi, s_old, mu, F), -opts.max_step), opts.max_step)
        loss = ard_loss(s_new, s_old, mu, F)
        best = s_new
        for j in range(opts.backtracks, -1, -1):
            trial = ard_project(softplus(xi - 2.0 ** -j * step), s_old, F, opts)
            best = ca.if_else(ard_loss(trial, s_old, mu, F) < loss, trial, best)
        s_new = best
        xi = softplus_inv(s_new)
    return s_new


def ard_correct(z, S, w_index, s_new, s_old):
    """Posterior under the new prior, the pseudo-observation 0 = w + v, v ~ N(0, D⁻¹),
    in square-root form: returns z' and the lower factor S' of P'."""
    w = list(w_index)
    F = S[w, :]
    D, Lb, _, c = _pieces(s_new, s_old, z[w], F)
    X_mu = D * z[w] - D * (F @ backward(Lb.T, c))          # (I + D P_ww)⁻¹ D μ
    return z - S @ (F.T @ X_mu), tria(forward(Lb, S.T).T)


def ard_view(z, S, w_index, s, s0):
    """The posterior under prior variances s from (z, S Sᵀ) under s₀ (the pseudo-observation
    with D = 1/s − 1/s₀, any sign). Returns z_s and diag P_s,ww."""
    w = list(w_index)
    F = S[w, :]
    D, Lb, G, c = _pieces(s, s0, z[w], F)
    x = D * z[w] - D * (F @ backward(Lb.T, c))              # (I + D P_ww)⁻¹ D μ
    return z - S @ (F.T @ x), ca.sum1(G * G).T


def ard_guard(s, s0, p, opts, drift):
    """s within [s_floor p, s_max], p = diag P_ww (B's condition stays below about
    1 + m/s_floor), and with random-walk weights (drift) D_i ≥ −(1 − margin)/(m p_i)."""
    if drift:
        s = 1 / (1 / s0 + ca.fmax(1 / s - 1 / s0, -(1 - opts.margin) / (s.shape[0] * p)))
    return ca.fmin(ca.fmax(s, opts.s_floor * p), opts.s_max)


