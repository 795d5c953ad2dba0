"""What every filter step shares: options, measurement masking, innovation statistics."""
from __future__ import annotations

from dataclasses import dataclass, asdict

import casadi as ca
import numpy as np

from .linalg import chol, forward

__all__ = ["ARD_UPDATES", "FilterOptions", "masked_noise_factor", "innovation_stats", "model_functions",
           "process_factor", "process_noise", "measurement_factor"]

ARD_UPDATES = ("em", "gradient")


@dataclass(frozen=True)
class FilterOptions:
    """Tuning of the filters; the same values serve every filter compared.

    alpha, beta, kappa: Merwe's scaled sigma points. second_order: the EKF predicts with the
    second-order terms of the transition (ekf.ekf_predict); no effect on the other kinds. ard: the ARD update of
    SKI — 'em' (default), the EM fixed point s' = μ² + P_s of the relevance,
    the filter kept on the declared prior and the ARD posterior a correction
    of it (ard.py); 'gradient', the paper's softplus gradient steps with the
    correction fed back. s_floor: 'em' keeps s ≥ s_floor × the filter's
    posterior variance of the weight (a pruned weight's ARD std is then 1 %
    of what the data leave it; it bounds the correction's conditioning).
    The rest configure 'gradient': ard_steps (N_hp) and eta: gradient steps
    on ξ (softplus⁻¹ of the prior variances) per sample. max_step: clip of one ξ step; backtracks: halvings tried so that a step
    lowers the ARD loss (else the prior stays). margin: lower bound kept on the eigenvalues
    of I + Lᵀ D L (the posterior correction amplifies the mean at most
    1/margin). s_min, s_max: bounds on the prior variances (weight units²).
    """

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0
    second_order: bool = False
    ard: str = "em"
    s_floor: float = 1e-8
    ard_steps: int = 1
    eta: float = 0.3
    max_step: float = 1.0
    backtracks: int = 3
    margin: float = 0.9
    s_min: float = 1e-10
    s_max: float = 1e6

    def __post_init__(self):
        if self.ard not in ARD_UPDATES:
            raise ValueError(f"ard must be one of {', '.join(ARD_UPDATES)}, got '{self.ard}'")

    def asdict(self) -> dict:
        return asdict(self)


def masked_noise_factor(R: np.ndarray, valid: ca.SX, factor: ca.SX | None = None) -> ca.SX:
    """A square root of R' = V R V + (I − V), V = diag(valid).

    Invalid (missing) outputs become decoupled unit-variance rows whose
    innovation is forced to zero, so one branch-free update serves every
    pattern of missing outputs and equals the update on the valid subset.
    R may be numeric or an SX expression (a fitted noise scale); ``factor``,
    any L with R = L Lᵀ, replaces it.
    """
    if factor is not None:
        Lr = factor
    else:
        Lr = chol(R) if isinstance(R, ca.SX) else ca.SX(np.linalg.cholesky(R))
    return ca.horzcat(ca.diag(valid) @ Lr, ca.diag(1 - valid))


def measurement_factor(aug, valid: ca.SX) -> ca.SX:
    """The masked factor of R: from the step's setting R_sqrt when tunable, else from aug.R."""
    return masked_noise_factor(aug.R, valid, getattr(aug, "R_sqrt", None))


def process_factor(aug) -> ca.SX:
    """G with Q = G Gᵀ: the step's setting Q_sqrt when tunable, else from aug.Q."""
    from .ukf import sqrt_psd
    G = getattr(aug, "Q_sqrt", None)
    return G if G is not None else ca.SX(sqrt_psd(aug.Q))


def process_noise(aug):
    """Q itself (the EKF's form)."""
    G = getattr(aug, "Q_sqrt", None)
    return G @ G.T if G is not None else aug.Q


def innovation_stats(Ly: ca.SX, e: ca.SX, valid: ca.SX) -> tuple[ca.SX, ca.SX]:
    """NIS = eᵀ Pyy⁻¹ e and the predictive log-likelihood log N(e; 0, Pyy),
    Pyy = Ly Lyᵀ, counting only valid outputs."""
    a = forward(Ly, e)
    nis = ca.dot(a, a)
    logdet = 2 * ca.sum1(ca.log(ca.diag(Ly)))
    loglik = -0.5 * (nis + logdet + ca.sum1(valid) * np.log(2 * np.pi))
    return nis, loglik


def model_functions(aug) -> tuple[ca.Function, ca.Function]:
    """F(z, u, mem) → z[k+1] and H(z, u, mem) → y, for calling on sigma points."""
    args = [aug.z, aug.u, aug.mem]
    return ca.Function("F", args, [aug.f]), ca.Function("H", args, [aug.h])
