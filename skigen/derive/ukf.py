"""Square-root unscented Kalman filter (Van der Merwe & Wan, 2001), symbolic.

The covariance is held as its lower Cholesky factor S (P = S Sᵀ): QR for the
spread of the sigma points, a rank-one update (downdate when Wc0 < 0) for the
centre point, two triangular solves for the gain and a rank-ny downdate for
the measurement update.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from .common import measurement_factor, model_functions, process_factor
from .linalg import cholupdate, spd_solve, tria

__all__ = ["merwe_weights", "sqrt_psd", "ukf_update", "ukf_predict", "gain_update"]


def merwe_weights(n: int, alpha: float, beta: float, kappa: float):
    """(Wm, Wc, gamma) of Merwe's scaled sigma points for dimension n."""
    lam = alpha ** 2 * (n + kappa) - n
    Wm = np.full(2 * n + 1, 1 / (2 * (n + lam)))
    Wc = Wm.copy()
    Wm[0] = lam / (n + lam)
    Wc[0] = Wm[0] + 1 - alpha ** 2 + beta
    return Wm, Wc, np.sqrt(n + lam)


def sigma_points(z, S, gamma):
    n = z.shape[0]
    return [z] + [z + gamma * S[:, i] for i in range(n)] + [z - gamma * S[:, i] for i in range(n)]


def _spread_factor(points, mean, Wc, extra):
    """Lower factor of Σ Wc_i (X_i − mean)(X_i − mean)ᵀ + extra extraᵀ."""
    devs = [p - mean for p in points]
    S = tria(ca.horzcat(*[np.sqrt(Wc[1]) * d for d in devs[1:]], extra))
    if Wc[0] != 0:
        S = cholupdate(S, np.sqrt(abs(Wc[0])) * devs[0], float(np.sign(Wc[0])))
    return S, devs


def ukf_update(aug, opts, z, S, u, mem, y, valid):
    """Measurement update. Returns z⁺, S⁺, e, Pyy, Sy."""
    _, H = model_functions(aug)
    Wm, Wc, gamma = merwe_weights(aug.n, opts.alpha, opts.beta, opts.kappa)
    X = sigma_points(z, S, gamma)
    Y = [valid * H(x, u, mem) for x in X]
    y_hat = sum((w * yi for w, yi in zip(Wm, Y)), ca.SX.zeros(aug.h.shape[0]))
    Sy, dY = _spread_factor(Y, y_hat, Wc, measurement_factor(aug, valid))
    Pzy = sum((w * (x - z) @ d.T for w, x, d in zip(Wc, X, dY)), ca.SX.zeros(aug.n, Sy.shape[0]))
    return gain_update(z, S, Sy, Pzy, valid * y - y_hat)


def gain_update(z, S, Sy, Pzy, e):
    """The square-root Kalman update from the innovation factor Sy and the
    cross-covariance Pzy: K by two triangular solves, S⁺ by rank-ny downdates.
    Returns z⁺, S⁺, e, Pyy, Sy."""
    K = spd_solve(Sy, Pzy.T).T
    U = K @ Sy
    S_post = S
    for j in range(U.shape[1]):
        S_post = cholupdate(S_post, U[:, j], -1.0)
    return z + K @ e, S_post, e, Sy @ Sy.T, Sy


def ukf_predict(aug, opts, z, S, u, mem):
    """Time update through the sigma points. Returns z⁻, S⁻."""
    F, _ = model_functions(aug)
    Wm, Wc, gamma = merwe_weights(aug.n, opts.alpha, opts.beta, opts.kappa)
    Xf = [F(x, u, mem) for x in sigma_points(z, S, gamma)]
    z_next = sum((w * x for w, x in zip(Wm, Xf)), ca.SX.zeros(aug.n))
    S_next, _ = _spread_factor(Xf, z_next, Wc, process_factor(aug))
    return z_next, S_next


def sqrt_psd(Q: np.ndarray) -> np.ndarray:
    """A factor G with G Gᵀ = Q for a positive semi-definite Q (zero columns dropped)."""
    lam, V = np.linalg.eigh(Q)
    keep = lam > 1e-15 * max(lam.max(initial=0), 1e-300)
    if np.allclose(Q, np.diag(np.diag(Q))):
        d = np.sqrt(np.diag(Q))
        return np.diag(d)[:, d > 0]
    return V[:, keep] * np.sqrt(lam[keep])
