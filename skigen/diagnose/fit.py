"""Show the fit: nominal and corrected model side by side on the validation segment.

Both models' EKFs run over the whole recording (the corrected model's
coefficients were fitted on the first part only); every statistic is taken
on the held-out validation samples: innovation RMS per output, mean NIS,
summed predictive log-likelihood, and the RMSE of free runs — the model
simulated from the filtered state with the recorded inputs, without
measurement updates, over ``horizon`` seconds, restarted every horizon.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..derive import augment, derive
from ..model import Model
from ..recording import Recording
from ..runtime import RunResult
from .fastrun import run_fast
from .transform import memory_values

__all__ = ["Fit", "evaluate_fit", "free_run"]


@dataclass
class Fit:
    metrics: dict
    run: RunResult
    free: np.ndarray        # (N, ny) free-run prediction on the validation segment (NaN elsewhere)


def free_run(model: Model, run: RunResult, rec: Recording, start: int, horizon: int) -> np.ndarray:
    """Outputs of free runs from the filtered state at start, start + horizon, … over the samples
    after each start up to the next (NaN at the starts themselves)."""
    aug = augment(model)
    nx = len(model.states)
    x = aug.z[:nx]
    F = ca.Function("F", [x, aug.u, aug.mem], [aug.f[:nx]])
    H = ca.Function("H", [x, aug.u, aug.mem], [aug.h])
    N = len(rec.t)
    starts = np.arange(start, N - 1, horizon)
    mem = memory_values(model, rec)
    out = np.full((N, len(model.outputs)), np.nan)
    X = run.mean[starts, :nx].T                          # posterior at each start
    Fm, Hm = F.map(len(starts)), H.map(len(starts))
    for j in range(1, horizon):
        k_prev = starts + j - 1
        ok = k_prev + 1 < N
        kp = np.minimum(k_prev, N - 1)
        X = np.asarray(Fm(X, rec.inputs[kp].T, mem[kp].T))
        k = np.minimum(kp + 1, N - 1)
        Y = np.asarray(Hm(X, rec.inputs[k].T, mem[k].T)).T
        out[k[ok]] = Y[ok]
    return out


def evaluate_fit(model: Model, rec: Recording, n_fit: int, horizon_s: float = 1.0,
                 run: RunResult | None = None) -> Fit:
    """Validation statistics of ``model`` (see the module docstring)."""
    run = run or run_fast(derive(model, "ekf"), rec)
    val = slice(n_fit, None)
    e = run.innovation[val]
    horizon = max(2, int(round(horizon_s / model.dt)))
    free = free_run(model, run, rec, n_fit, horizon)
    err = free[val] - rec.outputs[val]
    names = model.output_names
    with np.errstate(invalid="ignore"):
        metrics = {
            "innovation_rms": {n: float(np.sqrt(np.nanmean(e[:, i] ** 2))) for i, n in enumerate(names)},
            "nis_mean": float(np.nanmean(run.nis[val])),
            "loglik": float(np.sum(run.loglik[val])),
            "loglik_per_sample": float(np.mean(run.loglik[val])),
            "free_run_rmse": {n: float(np.sqrt(np.nanmean(err[:, i] ** 2))) for i, n in enumerate(names)},
        }
    return Fit(metrics, run, free)
