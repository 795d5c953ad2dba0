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


def ekf_predict(aug, z, P, u, mem):
    """Time update: z⁻ = F(z), P⁻ = A P Aᵀ + Q with A = ∂F/∂z at z."""
    F, _ = model_functions(aug)
    Fz = ca.Function("Fz", [aug.z, aug.u, aug.mem], [ca.jacobian(aug.f, aug.z)])
    A = Fz(z, u, mem)
    return F(z, u, mem), symmetrize(A @ P @ A.T + process_noise(aug))
