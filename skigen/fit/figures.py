"""Figures of a fit: measured against simulated or predicted outputs, residuals, correlations."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..plots import plt, save_figure

__all__ = ["recording_figure", "correlation_figure"]


def recording_figure(path, title: str, rec, predicted: np.ndarray, names: list[str], start: int = 0) -> Path:
    """Per output: measured and model output over time (top), their difference (bottom), its RMS
    from sample ``start`` on (the head before it, where a filter learns the recording's start,
    shaded), as the report counts it."""
    ny, start = len(names), min(start, len(rec.t) - 1)      # a recording shorter than its head: all shaded
    fig, axes = plt.subplots(2 * ny, 1, figsize=(9, 2.6 * ny + 1.2), sharex=True, squeeze=False)
    for j, name in enumerate(names):
        top, bottom = axes[2 * j, 0], axes[2 * j + 1, 0]
        top.plot(rec.t, rec.outputs[:, j], ".", ms=1.5, color="0.4", label="measured")
        top.plot(rec.t, predicted[:, j], lw=0.8, color="tab:blue", label="model")
        top.set_ylabel(name)
        e = rec.outputs[:, j] - predicted[:, j]
        bottom.plot(rec.t, e, lw=0.6, color="tab:red")
        bottom.set_ylabel(f"{name} residual")
        bottom.axhline(0, color="k", lw=0.5)
        if start:
            bottom.axvspan(rec.t[0], rec.t[start], color="0.9", lw=0)
        seen = e[start:][np.isfinite(e[start:])]
        if start and len(seen) and np.max(np.abs(seen)) > 0:      # the head's spike off the scale
            bottom.set_ylim(-1.2 * np.max(np.abs(seen)), 1.2 * np.max(np.abs(seen)))
        bottom.set_title((f"RMS {np.sqrt(np.mean(seen ** 2)):.4g}" + (f" from t = {rec.t[start]:g} s" if start else ""))
                         if len(seen) else "never measured", fontsize=8, loc="right")
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[0, 0].set_title(title)
    axes[-1, 0].set_xlabel("t (s)")
    return save_figure(fig, path)


def correlation_figure(path, result) -> Path:
    """The correlation matrix of the fitted quantities as a heat map, values written in."""
    names, C = result.correlation["names"], np.array(result.correlation["matrix"], float)   # None: unseen
    n = len(names)
    fig, ax = plt.subplots(figsize=(1.0 + 0.7 * n, 0.8 + 0.6 * n))
    im = ax.imshow(C, vmin=-1, vmax=1, cmap="RdBu_r")
    ax.set_xticks(range(n), names, rotation=45, ha="right")
    ax.set_yticks(range(n), names)
    for i in range(n):
        for j in range(n):
            ax.text(j, i, f"{C[i, j]:.2f}" if np.isfinite(C[i, j]) else "–", ha="center", va="center", fontsize=7,
                    color="w" if abs(C[i, j]) > 0.6 else "k")
    fig.colorbar(im, ax=ax, shrink=0.8)
    ax.set_title(f"correlation of the estimates ({result.method})")
    return save_figure(fig, path)
