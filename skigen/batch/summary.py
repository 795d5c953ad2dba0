"""The fleet view: ``summary.csv`` (one row per log), the logs where a quantity moved, ``summary.png``.

Order. Logs are ordered by their first time stamp when every log that was read
starts at an epoch date (2001–2100: the logs carry calendar time), else by file
name (the order of the sorted glob).

Moved significantly. Between consecutive logs (in that order, ``ok`` rows only)
a quantity moved when ``|v_k − v_{k−1}| > z·sqrt(σ_k² + σ_{k−1}²)``: the
difference of two independent Gaussian estimates, tested at a family-wise false
alarm rate ``ALPHA`` over the ``m`` consecutive pairs of the fleet (Bonferroni:
``z = Φ⁻¹(1 − ALPHA / 2m)``, never below 2). With 2σ per pair, a fleet of 100
steady flights would show ~5 false moves per quantity; with this rule, one in
twenty fleets shows one. A slow drift (a small step at each flight) is not a
move: it shows as a trend in the figure.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
from scipy.stats import norm

from ..sources import printable

__all__ = ["order_rows", "moves", "unlike_the_fleet", "write_summary", "plot_summary", "threshold", "ALPHA", "EPOCH"]

ALPHA = 0.05
EPOCH = (1e9, 4.1e9)      # seconds since 1970: 2001–2100
FIXED = ["file", "log", "status", "message", "notes", "samples", "duration_s", "start", "seconds"]
NIS = ["mean_nis", "nis_expected"]        # a filter's (a run, a diagnosis); a fit gives each output's rmse instead


def order_rows(rows: list[dict]) -> tuple[list[dict], str]:
    """(rows in fleet order, 'time stamp' or 'file name'): by time stamp when every log read has
    a calendar start (a log that could not be read has none: it goes last, by file name)."""
    read = [r for r in rows if r.get("start") is not None]
    unread = sorted((r for r in rows if r.get("start") is None), key=lambda r: r["file"])
    if read and all(EPOCH[0] <= r["start"] <= EPOCH[1] for r in read) and all(r["status"] == "failed" for r in unread):
        return sorted(read, key=lambda r: (r["start"], r["file"])) + unread, "time stamp"
    return sorted(rows, key=lambda r: r["file"]), "file name"


def quantities(rows: list[dict]) -> list[str]:
    names: dict = {}
    for r in rows:
        names.update(dict.fromkeys(r.get("quantities") or {}))
    return list(names)


def threshold(pairs: int, alpha: float = ALPHA) -> float:
    """The z above which a step between consecutive logs is a move (Bonferroni over ``pairs``)."""
    return max(2.0, float(norm.isf(alpha / (2 * max(pairs, 1)))))


def _z(va, sa, vb, sb) -> float:
    sd = math.hypot(sa, sb)
    return abs(vb - va) / sd if sd > 0 else (math.inf if vb != va else 0.0)


def moves(rows: list[dict], alpha: float = ALPHA) -> list[dict]:
    """The significant moves between consecutive ok logs: quantity, log, previous log, values, z.
    A move that returns to the level of the log before the previous one (within the same
    threshold) is marked ``back``: the previous log alone moved (one aircraft's log among a fleet's
    flagged the healthy flight after it as well)."""
    out = []
    for q in quantities(rows):
        pts = [(r, *r["quantities"][q]) for r in rows if r["status"] == "ok" and q in (r.get("quantities") or {})]
        pts = [(r, v, s) for r, v, s in pts if v is not None and s is not None and math.isfinite(v)
               and math.isfinite(s)]
        z_crit = threshold(len(pts) - 1, alpha)
        moved_at = set()
        for k in range(1, len(pts)):
            (ra, va, sa), (rb, vb, sb) = pts[k - 1], pts[k]
            z = _z(va, sa, vb, sb)
            if z > z_crit:
                back = k - 1 in moved_at and _z(*pts[k - 2][1:], vb, sb) <= z_crit
                moved_at.add(k)
                out.append(dict(quantity=q, log=rb["log"], previous=ra["log"], before=va, after=vb, z=z,
                                threshold=z_crit) | ({"back": True} if back else {}))
    return out


UNLIKE = 10.0     # a log's mean NIS (over the expected) this many times the fleet's median: said


def unlike_the_fleet(rows: list[dict]) -> list[tuple[str, float, float]]:
    """(log, its mean NIS over the expected, the fleet's median of that) for each ``ok`` log at
    UNLIKE times the median or more, among at least three logs with a NIS: one flight's readings
    disagree with the model far more than the others', whatever the declared noise makes of each
    alone (a flight logged in km/h, 1.18 against the fleet's 0.0095 under a sensor noise declared
    10–30× too large, was 'conservative' like all the others)."""
    nis = {r["log"]: r["mean_nis"] / r["nis_expected"] for r in rows if r.get("status") == "ok"
           and r.get("mean_nis") is not None and r.get("nis_expected")}
    if len(nis) < 3:
        return []
    median = float(np.median(list(nis.values())))
    return [(log, x, median) for log, x in nis.items() if median > 0 and x >= UNLIKE * median]


def _cell(x) -> str:
    if x is None:
        return ""
    if isinstance(x, float):
        return "" if not math.isfinite(x) else f"{x:.10g}"
    if isinstance(x, (list, tuple)):
        return "; ".join(map(_cell, x))
    return printable(x, 1000)


def write_summary(path, rows: list[dict], moved: list[dict], mode: str = "run") -> Path:
    """``summary.csv``: the fixed columns, the NIS (a run, a diagnosis; a run's ``verdict`` on it:
    consistent, inconsistent, conservative) or each output's ``rmse_`` (a fit), each quantity and
    its ``std_``, then ``moved`` (the quantities that moved at this log), and for a diagnosis ``mismatch`` (detected in the nominal), ``findings`` and
    ``remains`` (a mismatch remains after the correction)."""
    qs = quantities(rows)
    diag = mode == "diagnose"
    outputs = list(dict.fromkeys(o for r in rows for o in r.get("rmse") or {}))
    own = [f"rmse_{o}" for o in outputs] if mode == "fit" else NIS + ["verdict"] * (mode == "run")
    header = (FIXED + own + [c for q in qs for c in (q, f"std_{q}")] + ["moved"]
              + (["mismatch", "findings", "remains"] if diag else []))
    at = {}
    for m in moved:
        if not m.get("back"):                  # a return to the level before an outlier log: not a move here
            at.setdefault(m["log"], []).append(m["quantity"])
    path = Path(path)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for r in rows:
            vals = [r.get(c) for c in FIXED]
            vals += [(r.get("rmse") or {}).get(o) for o in outputs] if mode == "fit" else [r.get(c) for c in own]
            for q in qs:
                vals += list((r.get("quantities") or {}).get(q, [None, None]))
            vals.append(at.get(r["log"], []))
            if diag:
                vals += [r.get("mismatch"), r.get("findings") or [], r.get("remains")]
            w.writerow([_cell(v) for v in vals])
    return path


def plot_summary(path, rows: list[dict], moved: list[dict], order: str, title: str = "") -> Path | None:
    """``summary.png``: each quantity across the logs with its ±2σ band; moves marked in red,
    failed and diverged logs as grey lines. None when there is nothing to plot."""
    qs = quantities(rows)
    if not qs:
        return None
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    shown = qs[:12]
    fig, axes = plt.subplots(len(shown), 1, figsize=(9, 1.9 + 1.7 * len(shown)), sharex=True, squeeze=False)
    x = np.arange(len(rows))
    index = {r["log"]: i for i, r in enumerate(rows)}
    for ax, q in zip(axes[:, 0], shown):
        v = np.full(len(rows), np.nan)
        s = np.full(len(rows), np.nan)
        for i, r in enumerate(rows):
            val = (r.get("quantities") or {}).get(q)
            if r["status"] == "ok" and val is not None:
                v[i] = np.nan if val[0] is None else val[0]
                s[i] = np.nan if val[1] is None else val[1]
        ax.fill_between(x, v - 2 * s, v + 2 * s, color="C0", alpha=0.25, lw=0, label="±2σ")
        ax.plot(x, v, "o-", color="C0", ms=2.5, lw=1, label=q)
        for i, r in enumerate(rows):
            if r["status"] != "ok":
                ax.axvline(i, color="0.6", lw=0.8, ls=":")
        for m in (m for m in moved if m["quantity"] == q and not m.get("back")):
            i = index[m["log"]]
            ax.axvline(i - 0.5, color="C3", lw=1.2)
            ax.annotate(f"{m['log']} (z = {m['z']:.1f})", (i - 0.5, 1.0), xycoords=("data", "axes fraction"),
                        xytext=(3, -3), textcoords="offset points", va="top", color="C3", fontsize=8)
        ax.set_ylabel(q)
        ax.grid(alpha=0.3)
    n_bad = sum(r["status"] != "ok" for r in rows)
    axes[0, 0].set_title((title + "\n" if title else "") + f"{len(rows)} logs ordered by {order}; red: moved "
                         f"significantly from the previous log" + (f"; dotted: {n_bad} failed or diverged"
                                                                  if n_bad else ""), fontsize=9)
    ax = axes[-1, 0]
    if len(rows) <= 30:
        ax.set_xticks(x, [r["log"] for r in rows], rotation=60, ha="right", fontsize=7)
    ax.set_xlabel(f"log (ordered by {order})")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
