"""Figures a person would rather look at than read (matplotlib, Agg backend)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["plot_weights", "plot_ard", "save_figure"]

COLORS = {"sindy": "tab:gray", "aekf": "tab:orange", "aukf": "tab:blue", "ski": "tab:green"}


def plot_weights(path, t, estimates: dict, names, truth=None, title="") -> Path:
    """One panel per weight: each method's estimate over time with a ±2σ band.

    estimates: method → (W (N, m), W_std (N, m) or None).
    """
    m = len(names)
    cols = 2 if m > 3 else 1
    rows = int(np.ceil(m / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(5.5 * cols, 2.1 * rows), sharex=True, squeeze=False)
    for i, ax in enumerate(axes.flat):
        if i >= m:
            ax.axis("off")
            continue
        for method, (W, S) in estimates.items():
            color = COLORS.get(method)
            tt = t if len(W) == len(t) else np.linspace(t[0], t[-1], len(W))
            ax.plot(tt, W[:, i], color=color, lw=1.2, label=method)
            if S is not None:
                ax.fill_between(tt, W[:, i] - 2 * S[:, i], W[:, i] + 2 * S[:, i], color=color, alpha=0.15)
        if truth is not None:
            ax.axhline(truth[i], color="k", ls="--", lw=1, label="truth")
        ax.set_ylabel(names[i])
        lo, hi = _range(estimates, i, truth)
        ax.set_ylim(lo, hi)
    axes.flat[0].legend(loc="upper right", fontsize=7, ncol=len(estimates) + 1)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    fig.suptitle(title or "weight estimates (±2σ)")
    return save_figure(fig, path)


def _range(estimates, i, truth):
    """Axis limits from the filters' estimates (those with a σ band; a batch baseline may
    leave the frame) after the first tenth of the run, so early transients do not flatten it."""
    banded = [W for W, S in estimates.values() if S is not None] or [W for W, _ in estimates.values()]
    vals = [W[len(W) // 10:, i] for W in banded]
    vals = np.concatenate(vals + ([np.atleast_1d(truth[i])] if truth is not None else []))
    vals = vals[np.isfinite(vals)]
    lo, hi = np.percentile(vals, [1, 99]) if vals.size else (-1, 1)
    pad = 0.25 * max(hi - lo, 1e-3)
    return lo - pad, hi + pad


def plot_ard(path, names, variances, highlight: int | None = None, title="final ARD prior variances") -> Path:
    """Bars of the final ARD prior variances (log scale); ``highlight`` in red."""
    fig, ax = plt.subplots(figsize=(max(4.0, 0.7 * len(names) + 1.5), 3.0))
    colors = ["tab:red" if i == highlight else "tab:green" for i in range(len(names))]
    ax.bar(range(len(names)), variances, color=colors)
    ax.set_yscale("log")
    ax.set_xticks(range(len(names)))
    ax.set_xticklabels(names, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("prior variance")
    ax.set_title(title)
    return save_figure(fig, path)


def save_figure(fig, path, dpi: int = 110) -> Path:
    """Write a figure (creating its folder) and close it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
