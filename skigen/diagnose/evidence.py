"""Evidence per finding: what it adds, given the others, on data not used to fit it.

evidence = cross-validated log-likelihood of the corrected model minus that of
the corrected model without this one finding (drop-one), each with its
additive coefficients refitted without the fold it is scored on (structural
parameters stay at their whole-recording values). It is the log of the Bayes
factor of the two models' one-step predictions on held-out data, so the
findings' evidences need not add up to the total gain: two findings that
explain the same thing each add little given the other. A finding whose
evidence does not pass 0.5·χ²₁(1 − α) (3.3 at α = 0.01), or is under 1 % of
the strongest finding's, is dropped, the weakest first, and the rest are
refitted and weighed again.
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from ..model import Model
from ..recording import Recording
from .cv import Folds, fit_without, fold_loglik
from .name import MIN_SHARE, Correction, _prior, refit, start_trace

__all__ = ["weigh", "cv_loglik"]


def cv_loglik(nominal: Model, corr: Correction, rec: Recording, folds: Folds, rms: dict, size: dict) -> np.ndarray:
    """Per-fold log-likelihood of ``corr`` with its additive coefficients fitted without each fold."""
    if not corr.additive:
        return fold_loglik(corr.build(nominal), rec, folds)
    base = Correction([], corr.structural)
    cands = [a[0] for a in corr.additive]
    m = base.build(nominal, unknown=cands, prior_variance=_prior(cands, rms, size))
    start = start_trace(base.build(nominal), rec)
    out = np.empty(len(folds))
    for f in range(len(folds)):
        try:
            w, sd = fit_without(m, "ukf", rec, folds, f, start)
        except (FloatingPointError, RuntimeError, np.linalg.LinAlgError):
            out[f] = -np.inf
            continue
        fold_corr = Correction([(c, float(wi), float(si)) for c, wi, si in zip(cands, w, sd)], corr.structural)
        out[f] = fold_loglik(fold_corr.build(nominal), rec, folds)[f]
    return out


def weigh(nominal: Model, corr: Correction, rec: Recording, folds: Folds, alpha: float, rms: dict,
          size: dict) -> tuple[Correction, dict, np.ndarray]:
    """(the kept correction, {candidate: evidence}, its per-fold cross-validated log-likelihood)."""
    threshold = 0.5 * stats.chi2.isf(alpha, 1)
    while True:
        items = [a[0] for a in corr.additive] + [s[0] for s in corr.structural]
        full = cv_loglik(nominal, corr, rec, folds, rms, size)
        if not items:
            return corr, {}, full
        ev = {c: float(full.sum() - cv_loglik(nominal, corr.without(c), rec, folds, rms, size).sum())
              for c in items}
        weakest = min(items, key=lambda c: ev[c])
        if ev[weakest] >= max(threshold, MIN_SHARE * max(ev.values())):
            return corr, ev, full
        corr = refit(nominal, corr.without(weakest), rec, rms, size)
