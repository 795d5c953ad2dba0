"""The model's sample grid is the clock: time-stamped samples laid onto it.

The grid has step ``dt`` (the model's) and runs from the first time stamp at
which every input is known to the last time stamp of any used column. Every
sample belongs to the grid sample nearest its time stamp (within dt/2), so
jittered stamps land where they were meant to. Inputs are held from there
(zero-order hold) or interpolated linearly between their stamps (first-order
hold); an output is used at its grid sample (a nearer sample of the same
output wins; the others are counted and reported). Grid samples without one are "not measured" and
the filter predicts through them. A column with no sample for longer than
``max_gap`` seconds is a :class:`Hole`, reported with its time span.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .recording import Recording, RecordingError
from .sources import Samples

__all__ = ["UNITS", "Hole", "time_scale", "to_grid"]

UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
RATE_MISMATCH = 300.0        # stamps this many times further apart (or closer) than dt: a wrong unit
GRID_PER_STAMP = 100         # a grid this many times longer than the stamps: a wrong time stamp


@dataclass(frozen=True)
class Hole:
    """A span of ``t1 - t0`` seconds in which the listed columns have no sample."""

    t0: float
    t1: float
    columns: tuple[str, ...]
    inputs: bool = False      # an input is among them: it is not known in the hole


    def __str__(self) -> str:
        return f"{self.t0:.6g}–{self.t1:.6g} s ({self.t1 - self.t0:.3g} s) without {', '.join(self.columns)}"


def _spacing(samples: Samples) -> float:
    """Median positive interval between consecutive time stamps, in the source's unit."""
    d = np.concatenate([np.diff(g.t) for g in samples.groups])
    d = d[d > 0]
    return float(np.median(d)) if d.size else float("nan")


def _plausible(t0_seconds: float) -> bool:
    """A first time stamp that reads as time since start (< 11 days) or an epoch date (2001–2100)."""
    return abs(t0_seconds) < 1e6 or 1e9 <= t0_seconds <= 4.1e9


def time_scale(samples: Samples, time_unit: str, dt: float) -> tuple[float, str | None]:
    """(seconds per time unit, a note saying what was decided or None).

    'auto' takes the unit in which the median spacing is nearest the model's dt
    (on a log scale), preferring one in which the first stamp is plausible.
    An explicit unit that makes the spacing 300× off dt is an error naming the likely unit.
    """
    if time_unit not in (*UNITS, "auto"):
        raise RecordingError(f"time unit '{time_unit}' unknown: choose s, ms, us, ns or auto")
    if all(g.seconds for g in samples.groups):
        return 1.0, None
    spacing, t0 = _spacing(samples), float(samples.groups[0].t[0]) if len(samples.groups[0].t) else 0.0

    def score(unit):
        s = UNITS[unit]
        off = abs(np.log10(spacing * s / dt)) if np.isfinite(spacing) else 0.0
        return off + (0.0 if _plausible(t0 * s) else 1.0)
    best = min(UNITS, key=score)
    if time_unit == "auto":
        return UNITS[best], (f"time unit: {best} (auto: time stamps {spacing:g} {best} apart (median) "
                             f"against the model's dt = {dt:g} s)")
    ratio = spacing * UNITS[time_unit] / dt
    if np.isfinite(ratio) and not 1 / RATE_MISMATCH < ratio < RATE_MISMATCH:
        raise RecordingError(
            f"{samples.source}: time stamps in column '{samples.time_column}' are {spacing:g} {time_unit} apart "
            f"(median), {ratio:.3g}× the model's dt = {dt:g} s: is the time in {best}? "
            f"(--time-unit {best}, or --time-unit auto)")
    return UNITS[time_unit], None


def _series(samples: Samples, scale: float, origin: float):
    """name -> (stamps in seconds after ``origin``, values, group, row index) of the samples present."""
    out = {}
    for g in samples.groups:
        t = (g.t if g.seconds else g.t * scale) - origin
        for name, v in g.values.items():
            ok = np.isfinite(v)
            out[name] = (t[ok], v[ok], g, np.flatnonzero(ok))
    return out


def _check_length(samples, series, start, end, dt) -> int:
    """The grid size; an error naming the largest jump when the stamps cannot be right."""
    span = (end - start) / dt
    n = int(np.floor(span + 0.5)) + 1 if np.isfinite(span) and span < 2 ** 62 else -1
    stamps = sum(len(s[0]) for s in series.values())
    if 0 < n <= GRID_PER_STAMP * stamps + 10_000:
        return n
    name, (ts, _, g, rows) = max(series.items(), key=lambda kv: np.max(np.diff(kv[1][0]), initial=0))
    i = int(np.argmax(np.diff(ts))) + 1 if len(ts) > 1 else 0
    raise RecordingError(
        f"{samples.source}, {g.where(rows[i])}, column '{samples.time_column}': the time stamps span "
        f"{end - start:.3g} s, {n if n > 0 else 'too many'} samples of the model's dt = {dt:g} s for {stamps} "
        f"values; the largest jump is here, {ts[i] - (ts[i - 1] if i else start):.3g} s "
        f"(check this time stamp and --time-unit)")


def _nearest(ts, start, dt, n):
    """(grid index of each sample used, the samples' positions): the nearest within dt/2, nearest wins."""
    k = np.rint((ts - start) / dt).astype(np.int64)
    dist = np.abs(ts - (start + k * dt))
    ok = np.flatnonzero((k >= 0) & (k < n) & (dist <= 0.5 * dt * (1 + 1e-9)))
    order = ok[np.lexsort((dist[ok], k[ok]))]
    first = np.ones(len(order), bool)
    first[1:] = k[order][1:] != k[order][:-1]
    return k[order[first]], order[first]


def _holes(series, names, inputs, start, end, max_gap, columns) -> list[Hole]:
    spans = {}
    for name in names:
        ts = series[name][0]
        edges = np.concatenate([[start], ts[(ts > start) & (ts < end)], [end]])
        gaps = np.flatnonzero(np.diff(edges) > max_gap)
        for j in gaps:
            spans.setdefault((float(edges[j]), float(edges[j + 1])), []).append(name)
    return [Hole(a, b, tuple(columns[n] for n in c), any(n in inputs for n in c)) for (a, b), c in sorted(spans.items())]


def to_grid(samples: Samples, dt: float, input_names, output_names, input_hold: str = "zoh", *,
            time_unit: str = "s", max_gap: float = 1.0, min_samples: int = 2) -> Recording:
    """The samples on the grid of step ``dt`` (seconds); see the module docstring for the rule."""
    input_names, output_names = tuple(input_names), tuple(output_names)
    scale, note = time_scale(samples, time_unit, dt)
    notes = list(samples.notes) + ([note] if note else [])
    origin = min(float(g.t[0]) * (1.0 if g.seconds else scale) for g in samples.groups if len(g.t))
    series, cols = _series(samples, scale, origin), samples.columns   # relative times: exact arithmetic
    for name in input_names:
        if not len(series[name][0]):
            raise RecordingError(f"{samples.source}, column '{cols[name]}': input '{name}' has no value")
    firsts = [series[n][0][0] for n in input_names] or [series[n][0][0] for n in output_names if len(series[n][0])]
    if not firsts:
        raise RecordingError(f"{samples.source}: no output has a value")
    start = float(max(firsts) if input_names else min(firsts))
    end = float(max(s[0][-1] for s in series.values() if len(s[0])))
    n = _check_length(samples, series, start, end, dt)
    if n < min_samples:
        raise RecordingError(f"{samples.source}: {n} sample(s) of the model's grid (dt = {dt:g} s) from "
                             f"t = {start:g} to {end:g} s, at least {min_samples} needed")
    t = start + dt * np.arange(n)
    inputs = np.empty((n, len(input_names)))
    for j, name in enumerate(input_names):
        ts, v = series[name][:2]
        if input_hold == "foh":
            inputs[:, j] = np.interp(t, ts, v)
        else:
            inputs[:, j] = v[np.searchsorted(ts, t + dt / 2, side="left") - 1]   # the last sample nearest ≤ t
    outputs = np.full((n, len(output_names)), np.nan)
    for j, name in enumerate(output_names):
        ts, v = series[name][:2]
        k, used = _nearest(ts, start, dt, n)
        outputs[k, j] = v[used]
        early = int(np.sum(ts < start - dt / 2))
        dropped = len(ts) - len(used) - early
        if early:
            notes.append(f"output '{name}': {early} sample(s) before the inputs are known (t < {origin + start:g} s) "
                         f"not used")
        if dropped:
            notes.append(f"output '{name}': {dropped} sample(s) not used: a nearer sample of '{name}' had "
                         f"the same grid sample (the log is faster than the model's 1/dt = {1 / dt:g} Hz)")
        if not len(ts):
            notes.append(f"output '{name}' (column '{cols[name]}') has no value: never measured")
    holes = [Hole(h.t0 + origin, h.t1 + origin, h.columns, h.inputs) for h in
             _holes(series, input_names + output_names, input_names, start, end, max_gap, cols)]
    return Recording(samples.source, origin + t, inputs, outputs, input_names, output_names,
                     holes=tuple(holes), notes=tuple(notes), columns=dict(cols), max_gap=max_gap)
