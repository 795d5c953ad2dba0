"""Evidence per finding: what it buys on data not used to fit it.

evidence = log-likelihood of the validation segment under the corrected
model minus that under the corrected model without this one finding (the
others keep their coefficients) — the log of the Bayes factor of the two
models' one-step predictions on held-out data. A finding whose evidence does
not pass 0.5·χ²₁(1 − α) (3.3 at α = 0.01), or is under 1 % of the strongest
finding's (it then only absorbs the approximation of the others: a grid
resolution, a smoothing width), is dropped, the weakest first, and the rest
are weighed again.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
from scipy import stats

from ..derive import derive
from ..model import Model
from ..recording import Recording
from .fastrun import run_fast
from .name import MIN_SHARE, Correction

__all__ = ["weigh", "validation_loglik"]


def validation_loglik(model: Model, rec: Recording, n_fit: int) -> float:
    return float(np.sum(run_fast(derive(model, "ekf"), rec).loglik[n_fit:]))


def weigh(nominal: Model, corr: Correction, rec: Recording, n_fit: int, alpha: float,
          refit: Callable[[Correction], Correction]) -> tuple[Correction, dict]:
    """(the kept correction, {candidate: evidence})."""
    threshold = 0.5 * stats.chi2.isf(alpha, 1)
    while True:
        items = [a[0] for a in corr.additive] + [s[0] for s in corr.structural]
        if not items:
            return corr, {}
        full = validation_loglik(corr.build(nominal), rec, n_fit)
        ev = {c: full - validation_loglik(corr.without(c).build(nominal), rec, n_fit) for c in items}
        weakest = min(items, key=lambda c: ev[c])
        if ev[weakest] >= max(threshold, MIN_SHARE * max(ev.values())):
            return corr, ev
        corr = refit(corr.without(weakest))
