"""The diagnosis figures: residuals with the located windows, the disturbance beside the
identified term, predicted vs measured before and after (matplotlib, Agg)."""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from ..model import Model  # noqa: E402
from ..plots import save_figure  # noqa: E402
from ..recording import Recording  # noqa: E402
from . import transform as T  # noqa: E402

__all__ = ["plot_residuals", "plot_disturbance", "plot_fit", "diagnosis_figures", "identified_rate",
           "identified_output"]


def _shade(ax, windows, t_val):
    for i, (a, b) in enumerate(windows):
        ax.axvspan(a, b, color="tab:red", alpha=0.12, lw=0, label="located window" if i == 0 else None)
    if t_val is not None:
        ax.axvline(t_val, color="k", ls=":", lw=1, label="validation starts")


def _save(fig, path) -> Path:
    return save_figure(fig, path, dpi=100)


def plot_residuals(path, t, eps, names, windows, t_val, title) -> Path:
    """Normalised innovations of the nominal filter per output, located windows shaded."""
    fig, axes = plt.subplots(len(names), 1, figsize=(9, 2.2 * len(names) + 0.6), sharex=True, squeeze=False)
    for i, (ax, name) in enumerate(zip(axes[:, 0], names)):
        ax.plot(t, eps[:, i], lw=0.5, color="tab:blue", label="e/√Pyy (nominal)")
        ax.axhline(3, color="gray", lw=0.8, ls="--")
        ax.axhline(-3, color="gray", lw=0.8, ls="--", label="±3")
        _shade(ax, windows, t_val)
        ax.set_ylabel(name)
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=4)
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle(title)
    return _save(fig, path)


def plot_disturbance(path, t, panels, windows, t_val, title) -> Path:
    """One panel per located equation: the smoothed random-walk disturbance (±2σ) and the
    rate the identified terms add along the corrected model's filtered trajectory.
    panels: equation → (d, sd, identified or None, unit)."""
    fig, axes = plt.subplots(len(panels), 1, figsize=(9, 2.6 * len(panels) + 0.6), sharex=True, squeeze=False)
    for ax, (eq, (d, sd, ident, unit)) in zip(axes[:, 0], panels.items()):
        if ident is not None:
            ax.plot(t, ident, color="k", lw=0.6, label="identified term(s)")
        ax.fill_between(t, d - 2 * sd, d + 2 * sd, color="tab:orange", alpha=0.3, lw=0)
        ax.plot(t, d, color="tab:orange", lw=0.9, label="estimated disturbance (smoothed, ±2σ)")
        _shade(ax, windows, t_val)
        ax.set_ylabel(f"d{eq}/dt [{unit}]" if unit else f"d{eq}/dt")
        ax.legend(loc="upper right", fontsize=7)
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle(title)
    return _save(fig, path)


FIT_SAMPLES = 1000      # samples fit.png shows: the first located window, a fifth of them before it


def plot_fit(path, t, measured, before, after, names, span, title) -> Path:
    """Measured outputs vs free-run predictions of the nominal and corrected models."""
    k = (t >= span[0]) & (t <= span[1])
    fig, axes = plt.subplots(len(names), 1, figsize=(9, 2.4 * len(names) + 0.6), sharex=True, squeeze=False)
    for i, (ax, name) in enumerate(zip(axes[:, 0], names)):
        ax.plot(t[k], measured[k, i], ".", ms=1.5, color="0.5", label="measured")
        ax.plot(t[k], before[k, i], color="tab:red", lw=1, label="nominal (free run)")
        if after is not None:
            ax.plot(t[k], after[k, i], color="tab:green", lw=1, label="corrected (free run)")
        ax.set_ylabel(name)
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=3)
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle(title)
    return _save(fig, path)


def diagnosis_figures(out, nominal, rec, eps, loc, before, after, t_val) -> list[Path]:
    """residuals.png, disturbance.png, fit.png of a diagnosis."""
    figs = [plot_residuals(out / "residuals.png", rec.t, eps, nominal.output_names, loc.windows, t_val,
                           "normalised innovations of the nominal model, located windows shaded")]
    panels = {}
    for eq, (d, sd) in loc.disturbance.items():
        ident = None
        if after is not None:
            ident = identified_rate(nominal, after, rec, eq)
        unit = next((v.unit for v in nominal.states if v.name == eq), "")
        panels[eq] = (d, sd, ident, f"{unit}/s" if unit else "")
    figs.append(plot_disturbance(out / "disturbance.png", rec.t, panels, loc.windows, t_val,
                                 "where the nominal model needs help, and what the found terms supply"))
    first = int(np.argmax(np.isfinite(before.free).any(axis=1)))   # the free run starts after the filter settles
    lead = int(np.searchsorted(rec.t, loc.windows[0][0])) - FIT_SAMPLES // 5 if loc.windows else first
    a = min(max(first, lead), max(first, len(rec.t) - FIT_SAMPLES))
    span = (rec.t[a], rec.t[min(len(rec.t), a + FIT_SAMPLES) - 1])
    figs.append(plot_fit(out / "fit.png", rec.t, np.asarray(rec.outputs), before.free,
                         None if after is None else after.free, nominal.output_names, span,
                         "measured vs free-run simulation, nominal and corrected"))
    return figs


def identified_rate(nominal: Model, after, rec: Recording, eq: str) -> np.ndarray:
    """Corrected minus nominal rate of ``eq`` along the corrected filter's trajectory."""
    diff = _along(nominal, after, rec, lambda m: m.rhs[eq])
    return diff / after.run.filter.aug.model.dt if after.run.filter.aug.model.discretization == "discrete" else diff


def identified_output(nominal: Model, after, rec: Recording, y: str) -> np.ndarray:
    """Corrected minus nominal expression of output ``y`` (a clipped sensor) along the corrected
    filter's trajectory, in the output's unit."""
    return _along(nominal, after, rec, lambda m: next(v.sym for v in m.outputs if v.name == y))


def _along(nominal: Model, after, rec: Recording, expr) -> np.ndarray:
    """expr(corrected) − expr(nominal) (``expr``: model → SX) along the corrected filter's trajectory."""
    corrected, nominal = T.constants(after.run.filter.aug.model), T.constants(nominal)
    xs = ca.vertcat(*[v.sym for v in corrected.states])
    u = ca.vertcat(*[v.sym for v in corrected.inputs])
    mem = ca.vertcat(*[m.sym for m in corrected.memory]) if corrected.memory else ca.SX(0, 1)
    by_name = T.symbols(corrected)
    old = T.symbols(nominal)
    base = ca.substitute(ca.SX(expr(nominal)), ca.vertcat(*old.values()), ca.vertcat(*[by_name[n] for n in old]))
    f = ca.Function("d", [xs, u, mem], [ca.SX(expr(corrected)) - base]).map(len(rec.t))
    return np.asarray(f(after.run.mean[:, :len(corrected.states)].T, rec.inputs.T,
                        T.memory_values(corrected, rec).T)).ravel()
