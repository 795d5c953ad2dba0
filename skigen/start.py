"""The state a recording starts in, tested against the model's declared initial state.

A recording cut from a longer one, or a log that begins in flight, starts where the
declared initial state (often "at rest") is not: a filter started there spends its
first samples on a transient that its process noise must absorb, and a noise
calibration or a filter-error fit inflates Q to explain it. The state at the first
sample is estimated from the data by an EKF started from the declared mean with
DIFFUSE times the declared initial standard deviations and smoothed back
(:mod:`skigen.smoother`), and the declared start is tested against it:

    d² = (x̂ − x₀)ᵀ (P₀ + P̂)⁻¹ (x̂ − x₀)  >  χ²_{nx}(1 − α)

(x̂, P̂ the smoothed mean and covariance at the first sample, x₀, P₀ the declared
ones; states declared with zero initial std are known and left out of the test).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from .derive import derive
from .model import Model
from .recording import Recording
from .smoother import smooth

__all__ = ["DIFFUSE", "RecordedStart", "recorded_start"]

DIFFUSE = 100.0     # the declared initial std widened this much for the estimate


@dataclass(frozen=True)
class RecordedStart:
    """The smoothed state at a recording's first sample and the test of the declared start."""

    names: tuple
    mean: np.ndarray        # (nx,) the state at the first sample, from the data
    std: np.ndarray         # (nx,) its smoothed standard deviation
    declared: np.ndarray    # (nx,) the model's initial state
    declared_std: np.ndarray
    distance: float         # d², χ² with `dof` degrees of freedom under the declared start
    threshold: float        # χ²_{dof}(1 − α)
    dof: int

    @property
    def consistent(self) -> bool:
        return self.distance <= self.threshold

    def note(self, path: str, what: str) -> str:
        """A sentence naming the states that are off the declared start, ending in ``what``."""
        z = np.abs(self.mean - self.declared) / np.hypot(self.declared_std, self.std).clip(1e-300)
        off = [i for i in np.argsort(-z) if z[i] > 2 and self.declared_std[i] > 0] or [int(np.argmax(z))]
        said = ", ".join(f"{self.names[i]} {self.mean[i]:.4g} ± {self.std[i]:.2g} against {self.declared[i]:.4g} "
                         f"± {self.declared_std[i]:.2g}" for i in off)
        return (f"{path}: the recording does not start at the model's initial state ({said} declared; "
                f"χ² {self.distance:.3g} > {self.threshold:.3g}, α = 1 %): {what}")


def recorded_start(model: Model, rec: Recording, alpha: float = 0.01) -> RecordedStart | None:
    """The state ``rec`` starts in, tested against ``model``'s declared initial state at level
    ``alpha``; None when the diffuse EKF or its smoother fails (the declared start then stands)."""
    filt = derive(model, "ekf")
    nx = len(model.states)
    init = filt.initial()
    init["C"] = init["C"].copy()
    init["C"][:nx, :nx] *= DIFFUSE ** 2
    try:
        sm = smooth(filt, rec, init)
    except (FloatingPointError, ArithmeticError, ValueError, RuntimeError, np.linalg.LinAlgError):
        return None
    x, P = sm.mean[0, :nx], sm.first[:nx, :nx]
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
        return None
    x0, P0 = np.asarray(model.x0, float), model.initial_covariance()
    known = np.diag(P0) > 0
    d = (x - x0)[known]
    S = (P0 + P)[np.ix_(known, known)]
    distance = float(d @ np.linalg.lstsq(S, d, rcond=None)[0]) if known.any() else 0.0
    dof = int(known.sum())
    return RecordedStart(tuple(model.state_names), x, np.sqrt(np.clip(np.diag(P), 0, None)), x0,
                         np.sqrt(np.diag(P0)), distance, float(stats.chi2.ppf(1 - alpha, max(dof, 1))), dof)
