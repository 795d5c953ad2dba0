"""Show the fit: a model's statistics on a recording, the nominal and the corrected side by side.

Per recording: the EKF's innovation RMS per output, mean NIS and summed
predictive log-likelihood, and the RMSE of a free-run simulation over the whole
record — the model driven by the recorded inputs alone, from the EKF's state
at sample ``k0`` (the first 1 %, at least 50 samples, settle the filter and
are not scored). Where the free run amplifies a state error more than
AMPLIFICATION-fold over the record (an open-loop unstable plant flown in closed
loop: no simulation of it follows a recording for long), it is restarted from the
EKF's state every window within which it does so AMPLIFICATION-fold (the largest
Lyapunov exponent along the filtered trajectory, skigen.simulate.growth_rate).
Beside each RMSE, the one the model's own noise would give the right model's free
run (skigen.simulate.free_run_noise): a free run within it is as good as the noise
lets a simulation be, however its RMSE compares with another model's.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model import Model
from ..recording import Recording
from ..runtime import RunResult
from ..simulate import free_run_noise, growth_rate, simulation_window, windowed_free_run
from .cv import ekf_run

__all__ = ["Fit", "evaluate_fit", "free_run", "free_run_window", "settle", "simulation_worth"]


@dataclass
class Fit:
    metrics: dict
    run: RunResult
    free: np.ndarray        # (N, ny) free-run prediction (NaN before k0)
    window: int             # samples per free run


DIVERGED = 1e6      # a free run this many times the recording's spread away from its mean has diverged


def settle(n: int) -> int:
    """Samples not scored at the start of a free run."""
    return int(min(max(50, n // 100), n // 2))


def free_run_window(model: Model, rec: Recording, run: RunResult) -> int:
    """Samples per free-run window of ``model`` on ``rec`` (see the module docstring): the whole
    scored record unless the free run amplifies state errors more than AMPLIFICATION-fold over it."""
    nx = len(model.states)
    rate = growth_rate(model, run.mean[:, :nx], rec.inputs)
    return simulation_window(rate, model.dt, len(rec.t) - 1 - settle(len(rec.t)))


def free_run(model: Model, run: RunResult, rec: Recording, k0: int, window: int | None = None) -> np.ndarray:
    """Outputs of the free run from the filtered state at ``k0`` to the end, restarted from the
    filtered state every ``window`` samples when given (NaN up to ``k0``)."""
    nx = len(model.states)
    return windowed_free_run(model, run.mean[:, :nx], rec.inputs, k0, window or len(rec.t))


def evaluate_fit(model: Model, rec: Recording, run: RunResult | None = None, window: int | None = None) -> Fit:
    """Statistics of ``model`` on ``rec`` (see the module docstring); ``window``: samples per
    free run (default: free_run_window of ``model``; pass the nominal's to compare models)."""
    run = run or ekf_run(model, rec)
    k0 = settle(len(rec.t))
    window = window or free_run_window(model, rec, run)
    with np.errstate(all="ignore"):
        free = free_run(model, run, rec, k0, window)
        away = ~(np.abs(free - np.nanmean(rec.outputs, axis=0)) <= DIVERGED * np.nanstd(rec.outputs, axis=0))
    away[:k0 + 1] = False
    gone = np.flatnonzero(away.any(axis=1))
    free[away] = np.nan
    err = free - rec.outputs
    e = run.innovation
    names = model.output_names
    with np.errstate(invalid="ignore"):
        metrics = {
            "recording": str(rec.path), "samples": len(rec.t),
            "innovation_rms": {n: float(np.sqrt(np.nanmean(e[:, i] ** 2))) for i, n in enumerate(names)},
            "nis_mean": float(np.nanmean(run.nis)),
            "nis_sum": float(np.nansum(run.nis)), "nis_dof": int(np.sum(run.measured)),
            "loglik": float(np.sum(run.loglik)),
            "loglik_per_sample": float(np.mean(run.loglik)),
            "free_run_rmse": {n: float(np.sqrt(np.nanmean(err[k0 + 1:, i] ** 2))) for i, n in enumerate(names)},
            "free_run_from": float(rec.t[k0]),
            "free_run_window": None if window >= len(rec.t) - 1 - k0 else float(window * model.dt),
            "free_run_diverges_at": float(rec.t[gone[0]]) if len(gone) else None,
        }
    metrics["free_run_rmse"] = {n: (v if np.isfinite(v) and not away[:, i].any() else None)
                                for i, (n, v) in enumerate(metrics["free_run_rmse"].items())}
    nx = len(model.states)
    noise = free_run_noise(model, run.mean[:, :nx], rec.inputs, k0, window)
    metrics["free_run_noise"] = {n: float(v) if np.isfinite(v) else None for n, v in zip(names, noise)}
    return Fit(metrics, run, free, window)


def simulation_worth(nominal: Model, corr, rec: Recording, window: int | None = None) -> tuple[float, dict, float]:
    """What each finding of ``corr`` (a :class:`~skigen.diagnose.name.Correction`) is worth to a
    simulation: (the free-run error of the corrected model, {finding: that error without it},
    the error the corrected model's own noise gives a right model's free run), the error being
    the whole-record free-run RMSE over the output's spread, mean over the outputs (∞ where the
    free run diverges). One step ahead, a delay or a sensor effect can outweigh a force that a
    simulation cannot do without; this measures the latter."""
    spread = np.maximum(np.nanstd(rec.outputs, axis=0), 1e-300)
    mean = lambda m, key, unknown=np.inf: float(np.mean([unknown if m[key].get(n) is None else m[key][n] / s
                                                         for n, s in zip(nominal.output_names, spread)]))
    error = lambda c: mean(evaluate_fit(c.build(nominal), rec, window=window).metrics, "free_run_rmse")
    items = [a[0] for a in corr.found] + [s[0] for s in corr.structural]
    full = evaluate_fit(corr.build(nominal), rec, window=window).metrics
    noise = mean(full, "free_run_noise", 0.0) if "free_run_noise" in full else 0.0
    return mean(full, "free_run_rmse"), {c: error(corr.without(c)) for c in items}, noise
