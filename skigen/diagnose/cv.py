"""Blocked cross-validation: every coefficient is scored on data it was not fitted on.

The recording is cut into k·b contiguous blocks, dealt to k folds in turn
(fold f holds blocks f, f + k, …): an effect excited in only a fifth of the
recording is still in the data every fold's fit sees (with one block per fold,
a drag whose swings filled one fold was scored there with a coefficient
extrapolated from swings 25× smaller, and a viscous damping won). For fold f,
a candidate's coefficients are estimated from the other folds only — the
augmented filter runs over the data before each of the fold's blocks, then
restarts after it from the current model's prior state there, carrying the
weights' posterior (mean, covariance, ARD variances) across the gap — and the
candidate model's EKF is then scored
by its summed one-step predictive log-likelihood over fold f (the filter runs
over the whole recording: a prediction at sample k uses only data before k).
The restart state after a gap is the current model's prior there, which has
seen the block's last samples: the fold lends the states' starting point, never
the coefficients' information.
The sum over folds is the cross-validated log-likelihood; every part of the
recording is scored, so an effect that acts only early is weighed where it acts.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..derive import DerivedFilter, FilterOptions, derive
from ..derive.augment import memory_values
from ..model import Model
from ..recording import Recording
from ..runtime import RunResult, iter_run, parallel, run

__all__ = ["Folds", "ekf_run", "ekf_priors", "fold_loglik", "loglik", "fit_without", "fits_without"]

DEFAULT_FOLDS = 5
DEFAULT_BLOCKS = 3        # per fold: an effect excited in a fifth of the recording is in every fit's data
MIN_BLOCK = 100           # samples
MIN_SEGMENT = 20          # samples: a shorter piece of a split is skipped when fitting


def ekf_run(model: Model | DerivedFilter, rec: Recording, **options) -> RunResult:
    """``model``'s EKF (or the derived filter given) over the whole recording, unguarded (the CasADi
    backend of :func:`skigen.runtime.run`; ``options``: its trace, strict, init)."""
    filt = model if isinstance(model, DerivedFilter) else derive(model, "ekf")
    return run(filt, rec, backend="casadi", show_progress=False, **options)


@dataclass(frozen=True)
class Folds:
    """k folds of N samples, each the union of contiguous blocks dealt in turn: block b,
    [edges[b], edges[b + 1]), belongs to fold b mod k."""

    edges: tuple
    k: int

    @classmethod
    def of(cls, n: int, k: int = DEFAULT_FOLDS, blocks: int = 1) -> "Folds":
        """``blocks`` per fold where each keeps MIN_BLOCK samples (fewer where it cannot)."""
        per = max(1, min(int(blocks), n // (k * MIN_BLOCK))) if k > 1 else 1
        return cls(tuple(int(e) for e in np.linspace(0, n, k * per + 1).round()), k)

    def __len__(self) -> int:
        return self.k

    def blocks(self, f: int) -> list[tuple[int, int]]:
        """Fold f's blocks, [a, b) each."""
        return [(self.edges[b], self.edges[b + 1]) for b in range(f, len(self.edges) - 1, self.k)]

    def sums(self, per_sample: np.ndarray) -> np.ndarray:
        """Per-fold sums of a per-sample array."""
        c = np.concatenate([[0.0], np.cumsum(per_sample)])
        return np.array([sum(c[b] - c[a] for a, b in self.blocks(f)) for f in range(self.k)])

    def outside(self, f: int | None) -> list[tuple[int, int]]:
        """The pieces of the recording not in fold f (all of it for None)."""
        if f is None:
            return [(0, self.edges[-1])]
        pieces: list[tuple[int, int]] = []
        for b, (a, e) in enumerate(zip(self.edges[:-1], self.edges[1:])):
            if b % self.k == f:
                continue
            if pieces and pieces[-1][1] == a:
                pieces[-1] = (pieces[-1][0], e)
            else:
                pieces.append((a, e))
        return [(s, e) for s, e in pieces if e - s >= MIN_SEGMENT]

    def spans(self, f: int, t: np.ndarray) -> list[tuple[float, float]]:
        """Fold f's blocks as (first, last) sample times."""
        return [(float(t[a]), float(t[b - 1])) for a, b in self.blocks(f)]


def ekf_priors(model: Model, rec: Recording, samples) -> dict[int, tuple]:
    """k → (mean, covariance): the prior of ``model``'s strict EKF run over ``rec`` for sample k (where
    it stands after sample k − 1), for each k of ``samples`` inside the recording; the trace's
    z_next[k − 1], C_next[k − 1] without keeping a trace. Raises what the run raises."""
    want = {int(k) for k in samples if 0 < k < len(rec.t)}
    return {k: part.next_prior for k, part in _cut_run(derive(model, "ekf"), rec, sorted(want)) if k in want}


def _cut_run(filt: DerivedFilter, rec: Recording, cuts: list[int]):
    """(k, part) for each part of ``filt``'s strict run over ``rec``, cut at each of ``cuts``: k the
    samples run once the part is done."""
    k = 0
    for part in iter_run(filt, rec, backend="casadi", strict=True, show_progress=False, cuts=cuts):
        k += len(part.t)
        yield k, part


def fold_loglik(model: Model | DerivedFilter, rec: Recording, folds: Folds) -> np.ndarray:
    """Per-fold summed predictive log-likelihood of ``model``'s EKF over ``rec`` (−inf if it diverges:
    a step that gives a non-finite number anywhere; see :func:`loglik`)."""
    try:
        return folds.sums(ekf_run(model, rec, strict=True).loglik)
    except (FloatingPointError, RuntimeError):
        return np.full(len(folds), -np.inf)


def loglik(model: Model | DerivedFilter, rec: Recording, start: int = 0) -> float:
    """Summed predictive log-likelihood of the model's EKF over ``rec`` from sample ``start``
    on (the filter runs from the beginning); −inf if it diverges. Strict: a guarded rerun (gate,
    restarts) would be another predictor, which scores each rejected or failed sample 0: above a
    right model wherever the predictive densities are below 1."""
    try:
        return float(np.sum(ekf_run(model, rec, strict=True).loglik[start:]))
    except (FloatingPointError, RuntimeError):
        return -np.inf


def _restart(filt, start: dict, rec: Recording, k: int, w: np.ndarray, Pw: np.ndarray, s) -> dict:
    """The augmented filter's state before sample k: the physical states' prior from ``start``
    (the current model's EKF, :func:`ekf_priors`), the weights' posterior carried from the previous piece."""
    aug = filt.aug
    nx = len(aug.model.states)
    init = filt.initial()
    P = init["C"] @ init["C"].T if filt.square_root else init["C"].copy()
    if k > 0:
        z, C = start[k]
        init["z"][:nx] = z[:nx]
        P[:nx, :nx] = C[:nx, :nx]
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
                start: dict | None, options: FilterOptions | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(weights, their std) of ``model``'s unknown term estimated by filter ``kind`` ("ekf", "ukf" or "ski")
    from every fold but f (f = None: the whole recording). ``start``: the current model's EKF priors
    at the folds' edges (:func:`ekf_priors`), where each piece after a gap restarts; ``options``:
    the filter's (default FilterOptions()).
    Raises FloatingPointError if the filter diverges."""
    return _fit(derive(model, kind, options), rec, folds.outside(f), start)


def fits_without(model: Model, kind: str, rec: Recording, folds: Folds, start: dict) -> list:
    """:func:`fit_without` for every fold: per fold (weights, std), or the exception its fit raised.
    The filter's runs from the start of the recording to each fold are one run, stopped at each fold
    (the filter is causal: the same numbers)."""
    filt = derive(model, kind)
    ends = sorted({b for f in range(len(folds)) for a, b in folds.outside(f) if a == 0})
    ahead = _ahead(filt, rec, ends) if ends else None

    def without(f):
        try:
            return _fit(filt, rec, folds.outside(f), start, ahead)
        except (FloatingPointError, RuntimeError, np.linalg.LinAlgError) as exc:
            return exc
    return parallel(without, range(len(folds)))


def _fit(filt, rec: Recording, pieces, start: dict | None, ahead=None) -> tuple[np.ndarray, np.ndarray]:
    """The weights' posterior after the filter has run over ``pieces`` in turn, each after the first
    restarting from ``start`` (see :func:`_restart`); ``ahead(b)``: the carried values of the run over [0, b)."""
    w = Pw = s = None
    for a, b in pieces:
        if a == 0 and ahead is not None:
            w, Pw, s = ahead(b)
            continue
        init = _restart(filt, start, rec, a, w, Pw, s) if (a > 0 or w is not None) else None
        w, Pw, s = _carried(filt, run(filt, rec.slice(a, b), backend="casadi", init=init, strict=True,
                                      show_progress=False))
    return w, np.sqrt(np.clip(np.diag(Pw), 0, None))


def _carried(filt, res: RunResult) -> tuple:
    """What a fit carries across a gap: the weights' posterior mean and covariance, the ARD variances."""
    idx = filt.aug.w_index
    return res.mean[-1, idx], res.final_cov[np.ix_(idx, idx)], res.prior_var[-1] if res.prior_var.size else None


def _ahead(filt, rec: Recording, ends: list[int]):
    """b → :func:`_carried` of the strict run over [0, b), for b in ``ends``: one run, cut at each;
    raises what that run raised before b."""
    got, failed = {}, None
    try:
        for k, part in _cut_run(filt, rec.slice(0, ends[-1]), ends):
            got[k] = _carried(filt, part)
    except (FloatingPointError, RuntimeError) as exc:
        failed = exc

    def at(b: int) -> tuple:
        if b not in got:
            raise failed
        return got[b]
    return at
