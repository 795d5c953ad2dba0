"""Augmented extended Kalman filter, derived symbolically."""
from __future__ import annotations

import casadi as ca

from .common import measurement_factor, model_functions, process_noise
from .linalg import chol, spd_solve, symmetrize

__all__ = ["ekf_update", "ekf_predict"]


def ekf_update(aug, z, P, u, mem, y, valid):
    """Measurement update (Joseph form). Returns z⁺, P⁺, e, Pyy, Ly."""
    _, H = model_functions(aug)
    Hz = ca.Function("Hz", [aug.z, aug.u, aug.mem], [ca.jacobian(aug.h, aug.z)])
    C = ca.diag(valid) @ Hz(z, u, mem)
    Rf = measurement_factor(aug, valid)
    Rm = Rf @ Rf.T
    Pyy = symmetrize(C @ P @ C.T + Rm)
    Ly = chol(Pyy)
    K = spd_solve(Ly, C @ P).T
    e = valid * (y - H(z, u, mem))
    I_KC = ca.SX.eye(aug.n) - K @ C
    P_post = symmetrize(I_KC @ P @ I_KC.T + K @ Rm @ K.T)
    return z + K @ e, P_post, e, Pyy, Ly


def ekf_predict(aug, z, P, u, mem, second_order=False):
    """Time update: z⁻ = F(z), P⁻ = A P Aᵀ + Q with A = ∂F/∂z at z.

    second_order: the second-order EKF (Gelb, Applied Optimal Estimation, 1974, §6.1) — with
    Hᵢ = ∂²Fᵢ/∂z² at z, z⁻ᵢ += ½ tr(Hᵢ P) and P⁻ᵢⱼ += ½ tr(Hᵢ P Hⱼ P), exact for a quadratic F and
    Gaussian z. The product w·φ(x) of the augmented model is such a term: the first-order
    prediction drops the mean E[δw δφ] and the variance var(w) var(φ) it adds, and so
    grows overconfident while the weights are uncertain.
    """
    F, _ = model_functions(aug)
    Fz = ca.Function("Fz", [aug.z, aug.u, aug.mem], [ca.jacobian(aug.f, aug.z)])
    A = Fz(z, u, mem)
    z_next, P_next = F(z, u, mem), A @ P @ A.T + process_noise(aug)
    if second_order:
        rows = [i for i in range(aug.n) if ca.depends_on(ca.jacobian(aug.f[i], aug.z), aug.z)]
        HP = {i: ca.Function("Hz", [aug.z, aug.u, aug.mem], [ca.hessian(aug.f[i], aug.z)[0]])(z, u, mem) @ P
              for i in rows}
        corr = ca.SX.zeros(aug.n)
        for i in rows:
            corr[i] = 0.5 * ca.trace(HP[i])
            for j in rows:
                P_next[i, j] += 0.5 * ca.sum1(ca.sum2(HP[i] * HP[j].T))     # ½ tr(Hᵢ P Hⱼ P)
        z_next = z_next + corr
    return z_next, symmetrize(P_next)
