"""Sparse Kalman identification: square-root UKF + online ARD, one step."""
from __future__ import annotations

import casadi as ca
import numpy as np

from .ard import ard_correct, ard_guard, ard_optimise, ard_view
from .linalg import cholupdate

__all__ = ["ard_step", "random_walk_weights", "bounded_by_prior"]


def random_walk_weights(aug) -> bool:
    """Whether the declared numeric Q gives the weights a random walk (Q_ww ≠ 0)."""
    w = list(aug.w_index)
    return bool(np.any(aug.Q[np.ix_(w, w)]))


def bounded_by_prior(aug, opts) -> bool:
    """Whether the step needs P_ww ≤ diag(s₀) (Loewner order) at every step: the EM update on
    constant weights, whose view (ard.ard_view) is well posed for every s only under that bound."""
    return opts.ard == "em" and not random_walk_weights(aug)


def ard_step(aug, opts, z, S, s):
    """Re-weigh the prior of the weights on the posterior (z, S Sᵀ).

    Returns (z, S) to report, the new prior variances s' and (z, S) to predict from.
    'gradient' (the paper's): the posterior corrected to s', reported and predicted from.
    'em': the filter stays on the declared prior s₀ (prediction unchanged); s' = μ² + diag P_s
    from the weights' moments under s (the EM fixed point of the evidence), guarded
    (ard.ard_guard); the reported mean z' is the posterior mean under s', and the reported
    covariance the filter posterior's second moment about it, P + (z' − z)(z' − z)ᵀ: the
    expected squared error of the reported mean under the filter's (declared-prior) posterior.
    """
    w = list(aug.w_index)
    if opts.ard == "gradient":
        s_new = ard_optimise(s, z[w], S[w, :], opts)
        z, S = ard_correct(z, S, w, s_new, s)
        return z, S, s_new, z, S
    # s₀ and the drift decision are generation-time constants even in the tunable step (Q_sqrt a
    # run-time setting): drift is read from the declared numeric Q_w (aug.Q, not aug.Q_sqrt).
    s0 = ca.DM(aug.s0)
    z_s, p_s = ard_view(z, S, w, s, s0)
    s_new = ard_guard(z_s[w] * z_s[w] + p_s, s0, ca.sum2(S[w, :] * S[w, :]), opts, random_walk_weights(aug))
    z_rep = ard_view(z, S, w, s_new, s0)[0]
    return z_rep, cholupdate(S, z_rep - z, 1.0), s_new, z, S
