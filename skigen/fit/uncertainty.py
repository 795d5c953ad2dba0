"""Error bars from the curvature of the likelihood, and what the data cannot identify.

Filter error: the innovations of a correct model are white, so the inverse
Fisher information (the Gram matrix of the whitened pseudo-residuals) is the
covariance. Output error: the simulation residuals are coloured whenever
process noise or model error is present, and the Fisher information then
overstates what the data know. The covariance is the sandwich
A⁻¹ B A⁻¹ (A the Fisher information, B the covariance of the summed scores
Σ_k J_kᵀ ρ_k), with B from a noise model of the residuals (Ljung, System
Identification, 2nd ed., §9.3): each output's residual series is fitted by an
autoregression ρ = w / A(q), order chosen by AIC (Levinson–Durbin), and
B = Σ_m ψ̃_mᵀ Σ_w ψ̃_m with ψ̃_m = Σ_j h_j J_{m+j}, the sensitivities filtered
backwards by the impulse response h of 1/A(q), per recording (recordings are
independent). With white residuals the order is 0, B ≈ A and the two agree.
The autoregression follows a slow drift (process noise seen through a slow
plant) that a kernel estimate with a data-chosen bandwidth cuts short when
fast measurement noise hides it at short lags.

Equality constraints (multiple shooting) are handled in the null space of
their Jacobian, where the free directions live.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import null_space
from scipy.signal import lfilter

__all__ = ["covariance", "autoregression", "coloured_score_covariance", "unidentified", "recording_shifts"]

UNSEEN = 1e-12       # relative eigenvalue of the normalised information below which a direction has none
SINGULAR = 1e-9      # relative eigenvalue of the normalised Fisher information below which a direction is lost


def autoregression(e: np.ndarray, max_order: int | None = None) -> tuple[np.ndarray, float]:
    """AR model of a residual series: (a with a[0] = 1, so that a(q) e = w, and var w).
    Levinson–Durbin on the biased autocovariances; the order minimises AIC, up to
    ``max_order`` (default min(N/10, 200))."""
    e = np.asarray(e, float) - np.mean(e)
    N = len(e)
    p_max = int(min(N // 10, 200) if max_order is None else max_order)
    n_fft = 1 << int(np.ceil(np.log2(2 * N)))
    spec = np.fft.rfft(e, n_fft)
    r = np.fft.irfft(spec * spec.conj(), n_fft)[:p_max + 1] / N
    if r[0] <= 0:
        return np.ones(1), 0.0
    a, s2 = np.ones(1), r[0]
    best = (N * np.log(s2), a, s2)
    for p in range(1, p_max + 1):
        k = -(r[p] + a[1:] @ r[p - 1:0:-1]) / s2
        a = np.r_[a, 0.0] + k * np.r_[a, 0.0][::-1]
        s2 *= 1 - k * k
        if s2 <= 0:
            break
        aic = N * np.log(s2) + 2 * p
        if aic < best[0]:
            best = (aic, a.copy(), s2)
    return best[1], best[2]


def coloured_score_covariance(J: np.ndarray, rho: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """B = Var(Σ_k J_kᵀ ρ_k) for one recording under an AR noise model per residual:
    J (N, n_rho, p) sensitivities, rho (N, n_rho) residuals. Returns (B, AR orders)."""
    N, n_rho, p = J.shape
    W, Psi, orders = np.zeros((N, n_rho)), np.zeros((N, n_rho, p)), []
    for j in range(n_rho):
        a, _ = autoregression(rho[:, j])
        orders.append(len(a) - 1)
        W[:, j] = lfilter(a, [1.0], rho[:, j])                         # the white part w
        Psi[:, j] = lfilter([1.0], a, J[::-1, j], axis=0)[::-1]         # Σ_j h_j J_{m+j}
    Sw = W.T @ W / N
    return np.einsum("mip,ij,mjq->pq", Psi, Sw, Psi), orders


def covariance(J: np.ndarray, rho: np.ndarray | None, lengths: list[int], prior: np.ndarray,
               G: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """Covariance of the scaled variables: the inverse Fisher information A⁻¹, or with the
    residuals ``rho`` the sandwich A⁻¹ B A⁻¹.

    J: (Σ N_r · n_rho) × p Jacobian of the pseudo-residuals, sample-major (A = JᵀJ + prior,
    the Fisher information); rho: n_rho × Σ N_r pseudo-residuals (B: their AR noise model,
    per recording); prior: prior precision per variable; G: Jacobian of the equality
    constraints (or None). Returns (C, info) with the AR orders used and the variances of A⁻¹
    (``fisher_var``: what a white-residual model with the prior would claim). A variable in a
    direction the information does not see at all (a limit the inputs never reach) has an
    infinite variance and no correlation (NaN): the pseudo-inverse would have given it 0.
    """
    p = J.shape[1]
    Z = null_space(G) if G is not None and G.shape[0] else np.eye(p)
    Jz = J @ Z
    A = Jz.T @ Jz + Z.T @ np.diag(prior) @ Z
    d = np.sqrt(np.clip(np.diag(A), 1e-300, None))         # invert in the normalised basis
    lam, U = np.linalg.eigh(A / np.outer(d, d))
    seen = lam > UNSEEN * max(lam[-1], 1e-300) if len(lam) else lam > 0
    Ainv = (U[:, seen] / lam[seen]) @ U[:, seen].T / np.outer(d, d)
    lost = np.abs(Z @ U[:, ~seen]).max(axis=1, initial=0.0) > 1e-6

    def unseen(C):
        C = np.array(C, float)
        C[lost, :], C[:, lost] = np.nan, np.nan
        C[lost, lost] = np.inf
        return C
    fisher = Z @ Ainv @ Z.T
    if rho is None:
        return unseen(fisher), {"ar_orders": [], "fisher_var": np.diag(unseen(fisher))}
    n_rho = rho.shape[0]
    Jr = Jz.reshape(-1, n_rho, Jz.shape[1])
    B, start, info = Z.T @ np.diag(prior) @ Z, 0, {"ar_orders": [], "fisher_var": np.diag(fisher)}
    for n in lengths:
        Bi, orders = coloured_score_covariance(Jr[start:start + n], rho[:, start:start + n].T)
        B += Bi
        info["ar_orders"].append(orders)
        start += n
    info["fisher_var"] = np.diag(unseen(fisher))
    return unseen(Z @ (Ainv @ B @ Ainv) @ Z.T), info


def unidentified(J: np.ndarray, prior: np.ndarray, names: list[str], G: np.ndarray | None = None) -> list[str]:
    """Sentences naming the variables (or combinations) the Fisher information cannot see."""
    p = J.shape[1]
    with np.errstate(over="ignore", invalid="ignore"):
        F = J.T @ J + np.diag(prior)
    d = np.sqrt(np.clip(np.diag(F), 0, None))
    out = [f"'{names[i]}' has no effect on the likelihood" for i in range(p) if d[i] == 0]
    keep = d > 0
    if keep.sum() < 1 or not np.isfinite(F).all():     # overflowed (a diverging filter): nothing to read
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


def recording_shifts(J: np.ndarray, w: np.ndarray, lengths: list[int], prior: np.ndarray,
                     cols: list[int]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per recording, (δ, its covariance): the one Gauss–Newton step from the pooled fit that the
    recording alone takes in the variables ``cols`` (its own copy of them, the others'
    re-estimated: Rao's score test of its own values is δᵀ C⁻¹ δ, χ² under a right model whose
    innovations are white).

    J: (Σ N_r · n_rho) × p Jacobian of the pseudo-residuals, sample-major; w: the residuals whose
    J-weighted sum is the gradient of −log L, same order; prior: prior precision per variable.
    A recording's own copy has the score g = J_rᵀ w_r and, the pooled variables re-estimated, the
    information V = I_δδ − I_δη A⁻¹ I_ηδ (A = JᵀJ + prior): δ = −V⁻¹ g, C = V⁻¹."""
    A = J.T @ J + np.diag(prior)
    Ainv = np.linalg.pinv(A, hermitian=True)
    n_rho, out, start = J.shape[0] // sum(lengths), [], 0
    for n in lengths:
        rows = slice(start * n_rho, (start + n) * n_rho)
        Jr, start = J[rows], start + n
        cross = Jr[:, cols].T @ Jr
        C = np.linalg.pinv(Jr[:, cols].T @ Jr[:, cols] - cross @ Ainv @ cross.T, hermitian=True, rcond=1e-10)
        out.append((-C @ (Jr[:, cols].T @ w[rows]), C))
    return out
