"""Blocked cross-validation: every coefficient is scored on data it was not fitted on.

The recording is cut into k contiguous folds. For fold f, a candidate's
coefficients are estimated from the other folds only — the augmented filter
runs over the data before the fold, then restarts after it from the current
model's prior state there, carrying the weights' posterior (mean, covariance,
ARD variances) across the gap — and the candidate model's EKF is then scored
by its summed one-step predictive log-likelihood over fold f (the filter runs
over the whole recording: a prediction at sample k uses only data before k).
The restart state after a gap is the current model's prior there, which has
seen the fold's last samples: the fold lends the states' starting point, never
the coefficients' information.
The sum over folds is the cross-validated log-likelihood; every part of the
recording is scored, so an effect that acts only early is weighed where it acts.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..derive import FilterOptions, derive
from ..derive.augment import memory_values
from ..model import Model
from ..recording import Recording
from ..runtime import RunResult, run

__all__ = ["Folds", "fold_loglik", "loglik", "fit_without"]

DEFAULT_FOLDS = 5
MIN_SEGMENT = 20          # samples: a shorter piece of a split is skipped when fitting


@dataclass(frozen=True)
class Folds:
    """k contiguous folds of N samples: fold f is [edges[f], edges[f + 1])."""

    edges: tuple

    @classmethod
    def of(cls, n: int, k: int = DEFAULT_FOLDS) -> "Folds":
        return cls(tuple(int(e) for e in np.linspace(0, n, k + 1).round()))

    def __len__(self) -> int:
        return len(self.edges) - 1

    def sums(self, per_sample: np.ndarray) -> np.ndarray:
        """Per-fold sums of a per-sample array."""
        c = np.concatenate([[0.0], np.cumsum(per_sample)])
        return np.array([c[b] - c[a] for a, b in zip(self.edges[:-1], self.edges[1:])])

    def outside(self, f: int | None) -> list[tuple[int, int]]:
        """The pieces of the recording not in fold f (all of it for None)."""
        if f is None:
            return [(0, self.edges[-1])]
        a, b = self.edges[f], self.edges[f + 1]
        return [(s, e) for s, e in ((0, a), (b, self.edges[-1])) if e - s >= MIN_SEGMENT]

    def span(self, f: int, t: np.ndarray) -> tuple[float, float]:
        return float(t[self.edges[f]]), float(t[self.edges[f + 1] - 1])


def fold_loglik(model: Model, rec: Recording, folds: Folds) -> np.ndarray:
    """Per-fold summed predictive log-likelihood of ``model``'s EKF over ``rec`` (−inf if it diverges)."""
    try:
        return folds.sums(run(derive(model, "ekf"), rec, backend="casadi", show_progress=False).loglik)
    except (FloatingPointError, RuntimeError):
        return np.full(len(folds), -np.inf)


def loglik(model: Model, rec: Recording, start: int = 0) -> float:
    """Summed predictive log-likelihood of the model's EKF over ``rec`` from sample ``start``
    on (the filter runs from the beginning); −inf if it diverges."""
    try:
        return float(np.sum(run(derive(model, "ekf"), rec, backend="casadi", show_progress=False).loglik[start:]))
    except (FloatingPointError, RuntimeError):
        return -np.inf


def _restart(filt, start: RunResult, rec: Recording, k: int, w: np.ndarray, Pw: np.ndarray, s) -> dict:
    """The augmented filter's state before sample k: the physical states' prior from ``start``
    (the current model's EKF), the weights' posterior carried from the previous piece."""
    aug = filt.aug
    nx = len(aug.model.states)
    init = filt.initial()
    P = init["C"] @ init["C"].T if filt.square_root else init["C"].copy()
    if k > 0:
        init["z"][:nx] = start.trace.z_next[k - 1, :nx]
        P[:nx, :nx] = start.trace.C_next[k - 1][:nx, :nx]
        P[:nx, nx:] = P[nx:, :nx] = 0.0
    if w is not None:
        idx = aug.w_index
        init["z"][idx] = w
        P[np.ix_(idx, idx)] = Pw
        if s is not None and "s" in init:
            init["s"] = s
    init["C"] = np.linalg.cholesky(0.5 * (P + P.T)) if filt.square_root else P
    init["mem"] = memory_values(aug.model, rec.inputs)[k] if aug.model.memory else init["mem"]
    return init


def fit_without(model: Model, kind: str, rec: Recording, folds: Folds, f: int | None,
                start: RunResult, options: FilterOptions | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(weights, their std) of ``model``'s unknown term estimated by filter ``kind`` ("ekf", "ukf" or "ski")
    from every fold but f (f = None: the whole recording). ``start``: the current model's EKF run with its trace,
    where each piece after a gap restarts; ``options``: the filter's (default FilterOptions()).
    Raises FloatingPointError if the filter diverges."""
    filt = derive(model, kind, options)
    idx = filt.aug.w_index
    w = Pw = s = None
    for a, b in folds.outside(f):
        init = _restart(filt, start, rec, a, w, Pw, s) if (a > 0 or w is not None) else None
        res = run(filt, rec.slice(a, b), backend="casadi", init=init, strict=True, show_progress=False)
        w, Pw = res.mean[-1, idx], res.final_cov[np.ix_(idx, idx)]
        s = res.prior_var[-1] if res.prior_var.size else None
    return w, np.sqrt(np.clip(np.diag(Pw), 0, None))
