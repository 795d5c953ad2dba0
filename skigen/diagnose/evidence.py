"""Evidence per finding: what it adds, given the others, on data not used to fit it.

evidence = cross-validated log-likelihood of the corrected model minus that of
the corrected model without this one finding (drop-one), each with its
additive coefficients refitted without the fold it is scored on (structural
parameters stay at their whole-recording values), each under the better of
the two noises calibrated: the corrected model's and the one without the
finding (where the process noise takes up what it explained). Under the
corrected model's small noise alone, the nominal without a heater's lag lost
350 000 nat (its in-sample gain 998); under each model's own alone, a
cart-pole's Coulomb friction lost 149 (its noise, calibrated in-sample with
the friction, is too small for coefficients fitted without the fold; under
the nominal's it gains 123). It is the log of the Bayes
factor of the two models' one-step predictions on held-out data, so the
findings' evidences need not add up to the total gain: two findings that
explain the same thing each add little given the other. A finding whose
evidence does not pass 0.5·χ²₁(1 − α) (3.3 at α = 0.01), or is under 1 % of
the strongest finding's, is dropped, the weakest first, and the rest are
refitted and weighed again.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from ..model import Model
from ..recording import Recording
from .cv import Folds
from .name import MIN_SHARE, Correction, best_cv_loglik, cv_loglik, evidence_threshold, refit

__all__ = ["weigh", "cv_loglik"]


def weigh(nominal: Model, corr: Correction, rec: Recording, folds: Folds, alpha: float, rms: dict,
          size: dict, noise_for: Callable[[Correction], Model]) -> tuple[Correction, dict, np.ndarray]:
    """(the kept correction, {candidate: evidence}, its per-fold cross-validated log-likelihood).
    ``nominal`` carries the noise calibrated under ``corr``; ``noise_for(c)``: the nominal with the
    noise calibrated under correction c."""
    threshold = evidence_threshold(alpha)
    while True:
        items = [a[0] for a in corr.found] + [s[0] for s in corr.structural]
        full = cv_loglik(nominal, corr, rec, folds, rms, size)
        if not items:
            return corr, {}, full

        def without(c):
            less = corr.without(c)
            other = noise_for(less)
            return (max(float(full.sum()), best_cv_loglik([other], corr, rec, folds, rms, size))
                    - best_cv_loglik([other, nominal], less, rec, folds, rms, size))
        ev = {c: without(c) for c in items}
        weakest = min(items, key=lambda c: ev[c])
        if ev[weakest] >= max(threshold, MIN_SHARE * max(ev.values())):
            return corr, ev, full
        corr = refit(nominal, corr.without(weakest), rec, rms, size)
