"""Show the fit: a model's statistics on a recording, the nominal and the corrected side by side.

Per recording: the EKF's innovation RMS per output, mean NIS and summed
predictive log-likelihood, and the RMSE of a free-run simulation over the whole
record — the model driven by the recorded inputs alone, from the EKF's state
at sample ``k0`` (the first 1 %, at least 50 samples, settle the filter and
are not scored).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..derive import augment
from ..derive.augment import step_inputs
from ..model import Model
from ..recording import Recording
from ..runtime import RunResult
from .cv import ekf_run
from .transform import memory_values

__all__ = ["Fit", "evaluate_fit", "free_run", "settle", "simulation_worth"]


@dataclass
class Fit:
    metrics: dict
    run: RunResult
    free: np.ndarray        # (N, ny) free-run prediction (NaN before k0)


def settle(n: int) -> int:
    """Samples not scored at the start of a free run."""
    return int(min(max(50, n // 100), n // 2))


def free_run(model: Model, run: RunResult, rec: Recording, k0: int) -> np.ndarray:
    """Outputs of one free run from the filtered state at ``k0`` to the end (NaN up to ``k0``)."""
    aug = augment(model)
    nx = len(model.states)
    x = aug.z[:nx]
    f, h = aug.f[:nx], aug.h
    if aug.z.shape[0] > nx:                                # weights, estimated parameters: as declared
        f, h = (ca.substitute(e, aug.z[nx:], ca.DM(aug.z0[nx:])) for e in (f, h))
    F = ca.Function("F", [x, aug.u, aug.mem], [f])
    H = ca.Function("H", [x, aug.u, aug.mem], [h])
    N = len(rec.t)
    U = step_inputs(model, rec.inputs)
    mem = memory_values(model, rec)
    n = N - 1 - k0
    out = np.full((N, len(model.outputs)), np.nan)
    if n <= 0:
        return out
    sim = F.mapaccum("sim", n)
    X = np.asarray(sim(run.mean[k0, :nx], U[k0:N - 1].T, mem[k0:N - 1].T))
    out[k0 + 1:] = np.asarray(H.map(n)(X, U[k0 + 1:].T, mem[k0 + 1:].T)).T
    return out


def evaluate_fit(model: Model, rec: Recording, run: RunResult | None = None) -> Fit:
    """Statistics of ``model`` on ``rec`` (see the module docstring)."""
    run = run or ekf_run(model, rec)
    k0 = settle(len(rec.t))
    free = free_run(model, run, rec, k0)
    err = free - rec.outputs
    e = run.innovation
    names = model.output_names
    with np.errstate(invalid="ignore"):
        metrics = {
            "recording": str(rec.path), "samples": len(rec.t),
            "innovation_rms": {n: float(np.sqrt(np.nanmean(e[:, i] ** 2))) for i, n in enumerate(names)},
            "nis_mean": float(np.nanmean(run.nis)),
            "loglik": float(np.sum(run.loglik)),
            "loglik_per_sample": float(np.mean(run.loglik)),
            "free_run_rmse": {n: float(np.sqrt(np.nanmean(err[k0 + 1:, i] ** 2))) for i, n in enumerate(names)},
            "free_run_from": float(rec.t[k0]),
        }
    for k in ("free_run_rmse",):
        metrics[k] = {n: (v if np.isfinite(v) else None) for n, v in metrics[k].items()}
    return Fit(metrics, run, free)


def simulation_worth(nominal: Model, corr, rec: Recording) -> tuple[float, dict]:
    """What each finding of ``corr`` (a :class:`~skigen.diagnose.name.Correction`) is worth to a
    simulation: (the free-run error of the corrected model, {finding: that error without it}),
    the error being the whole-record free-run RMSE over the output's spread, mean over the
    outputs (∞ where the free run diverges). One step ahead, a delay or a sensor effect can
    outweigh a force that a simulation cannot do without; this measures the latter."""
    spread = np.maximum(np.nanstd(rec.outputs, axis=0), 1e-300)

    def error(c) -> float:
        rmse = evaluate_fit(c.build(nominal), rec).metrics["free_run_rmse"]
        return float(np.mean([np.inf if rmse[n] is None else rmse[n] / s
                              for n, s in zip(nominal.output_names, spread)]))
    items = [a[0] for a in corr.found] + [s[0] for s in corr.structural]
    return error(corr), {c: error(corr.without(c)) for c in items}
