"""Error bars from the curvature of the likelihood, and what the data cannot identify.

Filter error: the innovations of a correct model are white, so the inverse
Fisher information (the Gram matrix of the whitened pseudo-residuals) is the
covariance. Output error: the simulation residuals are coloured whenever
process noise or model error is present, and the Fisher information then
overstates what the data know. The covariance is the sandwich
A⁻¹ B A⁻¹ (A the Fisher information, B the long-run covariance of the
per-sample scores g_k = ∂(−log L_k)/∂θ = J_kᵀ ρ_k), with B estimated by Newey and West's
Bartlett-weighted sum of score autocovariances and the bandwidth chosen by
Andrews' (1991) AR(1) plug-in rule, per recording (recordings are
independent). With white residuals B ≈ A and the two agree.

Equality constraints (multiple shooting) are handled in the null space of
their Jacobian, where the free directions live.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import null_space

__all__ = ["covariance", "hac_bandwidth", "long_run_covariance", "unidentified"]

SINGULAR = 1e-9      # relative eigenvalue of the normalised Fisher information below which a direction is lost


def hac_bandwidth(scores: np.ndarray) -> float:
    """Andrews' AR(1) plug-in bandwidth of the Bartlett kernel for the columns of ``scores`` (N × p)."""
    g = scores - scores.mean(axis=0)
    N = len(g)
    num = den = 0.0
    for a in g.T:
        prev, now = a[:-1], a[1:]
        ss = prev @ prev
        if ss <= 0:
            continue
        rho = float(np.clip(prev @ now / ss, -0.97, 0.97))
        s2 = float(np.mean((now - rho * prev) ** 2))
        num += 4 * rho ** 2 * s2 ** 2 / ((1 - rho) ** 6 * (1 + rho) ** 2)
        den += s2 ** 2 / (1 - rho) ** 4
    alpha = num / den if den > 0 else 0.0
    return float(min(1.1447 * (alpha * N) ** (1 / 3), N / 4))


def long_run_covariance(scores: np.ndarray, bandwidth: float | None = None) -> tuple[np.ndarray, float]:
    """Σ_l w_l Γ_l of the rows of ``scores`` (N × p), Bartlett weights; returns (B, bandwidth)."""
    L = hac_bandwidth(scores) if bandwidth is None else bandwidth
    B = scores.T @ scores
    for lag in range(1, int(L) + 1):
        G = scores[lag:].T @ scores[:-lag]
        B += (1 - lag / (L + 1)) * (G + G.T)
    return B, L


def covariance(J: np.ndarray, scores: np.ndarray | None, lengths: list[int], prior: np.ndarray,
               G: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """Covariance of the scaled variables: the inverse Fisher information A⁻¹, or with
    ``scores`` the sandwich A⁻¹ B A⁻¹.

    J: (Σ N_r · n_rho) × p Jacobian of the pseudo-residuals (A = JᵀJ + prior, the
    Fisher information); scores: Σ N_r × p per-sample gradients of −log L (B, their
    long-run covariance, per recording); prior: prior precision per variable; G:
    Jacobian of the equality constraints (or None). Returns (C, info) with the
    bandwidths used.
    """
    p = J.shape[1]
    Z = null_space(G) if G is not None and G.shape[0] else np.eye(p)
    Jz = J @ Z
    A = Jz.T @ Jz + Z.T @ np.diag(prior) @ Z
    d = np.sqrt(np.clip(np.diag(A), 1e-300, None))         # invert in the normalised basis
    Ainv = np.linalg.pinv(A / np.outer(d, d), rcond=1e-12) / np.outer(d, d)
    if scores is None:
        return Z @ Ainv @ Z.T, {"bandwidth": []}
    per_sample = scores @ Z
    B, start, info = Z.T @ np.diag(prior) @ Z, 0, {"bandwidth": []}
    for n in lengths:
        Bi, L = long_run_covariance(per_sample[start:start + n])
        B += Bi
        info["bandwidth"].append(L)
        start += n
    return Z @ (Ainv @ B @ Ainv) @ Z.T, info


def unidentified(J: np.ndarray, prior: np.ndarray, names: list[str], G: np.ndarray | None = None) -> list[str]:
    """Sentences naming the variables (or combinations) the Fisher information cannot see."""
    p = J.shape[1]
    F = J.T @ J + np.diag(prior)
    d = np.sqrt(np.clip(np.diag(F), 0, None))
    out = [f"'{names[i]}' has no effect on the likelihood" for i in range(p) if d[i] == 0]
    keep = d > 0
    if keep.sum() < 1:
        return out
    Fn = F[np.ix_(keep, keep)] / np.outer(d[keep], d[keep])
    Z = null_space(G[:, keep]) if G is not None and G.shape[0] else np.eye(keep.sum())
    lam, V = np.linalg.eigh(Z.T @ Fn @ Z)
    kept = [n for n, k in zip(names, keep) if k]
    for value, v in zip(lam, (Z @ V).T):
        if value > SINGULAR * max(lam[-1], 1e-300):
            break
        big = np.argsort(-np.abs(v))[:4]
        big = [i for i in big if abs(v[i]) > 0.1 * np.abs(v).max()]
        combo = " ".join(f"{v[i]:+.2f}·{kept[i]}" for i in big)
        out.append(f"{', '.join(repr(kept[i]) for i in big)} cannot be told apart "
                   f"(the data do not see {combo}, in scaled units)")
    return out
