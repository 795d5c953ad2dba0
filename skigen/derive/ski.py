"""Sparse Kalman identification: square-root UKF + online ARD, one step."""
from __future__ import annotations

from .ard import ard_correct, ard_optimise
from .linalg import chol

__all__ = ["ard_step"]


def ard_step(aug, opts, z, S, s):
    """Re-weigh the prior of the weights on the posterior (z, S S ᵀ).

    Returns the corrected (z, S) and the new prior variances s'.
    """
    w = list(aug.w_index)
    P = S @ S.T
    s_new = ard_optimise(s, z[w], P[w, w], opts)
    z, P = ard_correct(z, P, w, s_new, s)
    return z, chol(P), s_new
