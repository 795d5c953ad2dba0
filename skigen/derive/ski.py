"""Sparse Kalman identification: square-root UKF + online ARD, one step."""
from __future__ import annotations

from .ard import ard_correct, ard_optimise

__all__ = ["ard_step"]


def ard_step(aug, opts, z, S, s):
    """Re-weigh the prior of the weights on the posterior (z, S Sᵀ).

    Returns the corrected (z, S) and the new prior variances s'.
    """
    w = list(aug.w_index)
    s_new = ard_optimise(s, z[w], S[w, :], opts)
    z, S = ard_correct(z, S, w, s_new, s)
    return z, S, s_new
