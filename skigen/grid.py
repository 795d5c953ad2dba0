"""The model's sample grid is the clock: time-stamped samples laid onto it.

The grid has step ``dt`` (the model's) and runs from the first time stamp at
which every input is known to the last time stamp of any used column, its phase
centred on the inputs' first PHASE_STAMPS stamps (the outputs', without inputs)
when they keep to a grid of step dt (:func:`grid_phase`: a jittered first stamp
does not set it). Every
sample belongs to the grid sample nearest its time stamp (within dt/2), so
jittered stamps land where they were meant to. Inputs are held from there
(zero-order hold) or interpolated linearly between their stamps (first-order
hold); an output is used at its grid sample (a nearer sample of the same
output wins; the others are counted and reported). Grid samples without one are "not measured" and
the filter predicts through them. A column with no sample for longer than
``max_gap`` seconds (and MIN_GAP_SAMPLES samples of dt) is a :class:`Hole`, reported with its
time span; so is an input's gap longer than RATE_GAP of its own sample intervals (the median of
its first RATE_STAMPS; :func:`gap_limit`): held through it, a 1 kHz voltage missing for 0.1 s
would drive the model with a value it did not have.
"""
from __future__ import annotations

import re

from dataclasses import dataclass

import numpy as np

from .recording import Recording, RecordingError, held_run
from .sources import Samples

__all__ = ["UNITS", "Hole", "clock", "time_scale", "to_grid", "GridStream", "GridBlock"]

UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
RATE_MISMATCH = 300.0        # stamps this many times further apart (or closer) than dt: a wrong unit
GRID_PER_STAMP = 100         # a grid this many times longer than the stamps: a wrong time stamp
PHASE_STAMPS = 256           # the inputs' first stamps that set the grid's phase
TIE = 1e-6                   # samples: a stamp this close to half-way between two grid samples is a tie
PHASE_ALPHA = 0.01           # Rayleigh test: stamps whose phase is uniform this likely set none
MIN_GAP_SAMPLES = 5         # a hole is longer than max_gap and than this many samples of the model's dt
OFF_GRID = 0.25              # samples: an output stamped on average this far from where it is used is noted
OFFSET_UNIT = 1e-6           # samples: offsets are summed as integers of this (the stream sums to the same)
RATE_GAP = 10                # an input without a sample for this many of its own intervals has a hole
RATE_STAMPS = 256            # the input's first stamps whose median interval is its own
RATE_OFF = 0.005             # a column's own interval this far (relative) from dt, and under 1/6, is noted
SPARSE = 4.0                 # a column whose pace is this many dt or more: said (the grid is mostly between its samples)
GAP_SHARE = 1.75             # a column's interval past this share of its median one is a gap, not its pace
RATE_MIN = 8                 # intervals needed to know it (fewer: max_gap alone)


def clock(t: float) -> str:
    """A time stamp in seconds as a person reads it: 6 significant digits, to the millisecond
    from 10⁵ s on (an epoch stamp, 1772360000.125, not 1.77236e+09)."""
    return f"{t:.3f}" if abs(t) >= 1e5 else f"{t:.6g}"


@dataclass(frozen=True)
class Hole:
    """A span of ``t1 - t0`` seconds in which the listed columns have no sample."""

    t0: float
    t1: float
    columns: tuple[str, ...]
    inputs: bool = False      # an input is among them: it is not known in the hole


    def __str__(self) -> str:
        return f"{clock(self.t0)}–{clock(self.t1)} s ({self.t1 - self.t0:.3g} s) without {', '.join(self.columns)}"


def _spacing(samples: Samples) -> float:
    """Median positive interval between consecutive time stamps, in the source's unit."""
    d = np.concatenate([np.diff(g.t) for g in samples.groups])
    d = d[d > 0]
    return float(np.median(d)) if d.size else float("nan")


MIN_SPAN = 50      # grid samples: a time unit in which a recording spans fewer is unlikely ('auto')


def _plausible(t0_seconds: float) -> bool:
    """A first time stamp that reads as time since start (< 11 days) or an epoch date (2001–2100)."""
    return abs(t0_seconds) < 1e6 or 1e9 <= t0_seconds <= 4.1e9


def time_scale(samples: Samples, time_unit: str, dt: float) -> tuple[float, str | None]:
    """(seconds per time unit, a note saying what was decided or None).

    'auto' takes the unit in which the median spacing is nearest the model's dt
    (on a log scale), preferring one in which the first stamp is plausible and the
    recording spans at least MIN_SPAN grid samples (a 2 Hz log in seconds for a 100 Hz
    model, 50 dt apart, was read as milliseconds, 0.05 dt apart: 60 s became 6 samples).
    An explicit unit that makes the spacing 300× off dt is an error naming the likely unit.
    """
    if time_unit not in (*UNITS, "auto"):
        raise RecordingError(f"time unit '{time_unit}' unknown: choose s, ms, us, ns or auto")
    if all(g.seconds for g in samples.groups):
        return 1.0, None
    spacing, t0 = _spacing(samples), float(samples.groups[0].t[0]) if len(samples.groups[0].t) else 0.0
    span = max((float(g.t[-1] - g.t[0]) for g in samples.groups if len(g.t)), default=0.0)

    def score(unit):
        s = UNITS[unit]
        off = abs(np.log10(spacing * s / dt)) if np.isfinite(spacing) else 0.0
        return off + (0.0 if _plausible(t0 * s) else 1.0) + (2.0 if span * s < MIN_SPAN * dt else 0.0)
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


def _repeats(ts, before=None) -> tuple[int, float | None]:
    """(how many stamps in ``ts`` equal the one before them, the first such stamp); ``before``: the
    stamp before ts[0], if any."""
    ts = np.asarray(ts) if before is None else np.concatenate([[before], ts])
    same = np.flatnonzero(np.diff(ts) == 0)
    return len(same), (float(ts[same[0] + 1]) if len(same) else None)


COARSE_STAMPS = 16          # stamps needed to judge a column's time as written too coarsely


def coarse(ts) -> bool:
    """Whether more than half of a column's stamps ``ts`` (at least COARSE_STAMPS) repeat the one
    before them: a time written with too few digits (an epoch in whole seconds for a 50 Hz log)."""
    return len(ts) >= COARSE_STAMPS and _repeats(ts)[0] > len(ts) / 2


def _refuse_coarse(samples, name, ts, dt) -> None:
    if coarse(ts):
        apart = np.diff(np.unique(ts))
        where = f"column '{samples.time_column}'" if samples.time_column else "the time"
        raise RecordingError(
            f"{samples.source}, {where}: {_repeats(ts)[0]} of the {len(ts)} samples of "
            f"'{samples.columns[name]}' repeat the time stamp before them, whose distinct values are "
            f"{np.median(apart) if len(apart) else 0:.3g} s apart (the model's dt is {dt:g} s): the time is "
            f"written too coarsely (too few digits?); write it with more digits, or name a finer time column "
            f"with --time")


def _offset_units(ts, k, start, dt) -> int:
    """The sum of stamps ``ts`` minus their grid samples' times ``k``, in OFFSET_UNIT samples."""
    return int(np.sum(np.rint((np.asarray(ts) - (start + np.asarray(k) * dt)) / (dt * OFFSET_UNIT)).astype(np.int64)))


def _offset_note(name, used, offset, dt, phase_from) -> list[str]:
    """A note when an output's ``used`` samples are stamped on average OFF_GRID samples or more from
    the grid samples they are used at (``offset``: their sum, in OFFSET_UNIT samples)."""
    mean = offset * OFFSET_UNIT / used if used else 0.0
    if abs(mean) < OFF_GRID:
        return []
    ms, later = abs(mean) * dt * 1e3, mean > 0
    return [f"output '{name}': its samples are stamped {ms:.3g} ms ({abs(mean):.2f} dt) "
            f"{'after' if later else 'before'} the grid samples they are used at, on average (the grid "
            f"takes its phase from the {phase_from}' stamps): the model at t is compared with the reading "
            f"stamped at t {'+' if later else '−'} {ms:.3g} ms"]


def merged(notes: list[str]) -> list[str]:
    """``notes`` with those that say the same of several columns said once, naming them all
    ("outputs 'x_m', 'y_m', each: …", their own name in the rest read "it"): a 100 Hz log of six outputs
    for a 50 Hz model gave six sentences alike in one summary cell."""
    said = re.compile(r"(input|output) '([^']*)'(: .*)$", re.S)
    groups: dict = {}
    for n in notes:
        m = said.match(n)
        groups.setdefault((m[1], m[3].replace(f"'{m[2]}'", "it")) if m else n, []).append((n, m and m[2]))
    return [same[0][0] if len(same) == 1 else f"{key[0]}s {', '.join(repr(x) for _, x in same)}, each{key[1]}"
            for key, same in groups.items()]


def _column_notes(name, column, output, count, early, dropped, repeated, first_repeat, origin, start, dt,
                  own=None, pace=None):
    """What the grid did with one column's samples, as notes (times relative to ``origin``, s);
    own: its median interval, pace: its mean one (:func:`pace`)."""
    kind = "output" if output else "input"
    notes = []
    if early:
        notes.append(f"output '{name}': {early} sample(s) before the inputs are known "
                     f"(t < {clock(origin + start)} s) not used")
    if repeated:
        use = "the first at each stamp is used" if output else "the last at each stamp is used from it on"
        notes.append(f"{kind} '{name}': {repeated} sample(s) repeat the time stamp before them "
                     f"(first at t = {clock(origin + first_repeat)} s): {use}")
    faster = dropped - repeated
    if faster > 0:
        why = (f"the log is faster than the model's 1/dt = {1 / dt:g} Hz" if own is None or own < 0.75 * dt else
               f"its stamps, {1 / own:.3g} Hz, are irregular: two fell nearest one grid sample")
        notes.append(f"output '{name}': {faster} sample(s) not used: a nearer sample of '{name}' had "
                     f"the same grid sample ({why})")
    if pace is not None and RATE_OFF < abs(pace / dt - 1) < 1 / 6:
        notes.append(f"{kind} '{name}': its first stamps are {pace:.4g} s apart on average, "
                     f"{abs(pace / dt - 1):.1%} {'longer' if pace > dt else 'shorter'} than the model's dt = {dt:g} s: "
                     f"if it was logged at the model's rate, the logger's clock runs {pace / dt:.4g}× the true time, "
                     f"and the recording's dynamics with it")
    if pace is not None and pace >= SPARSE * dt * (1 - RATE_OFF):
        notes.append(f"{kind} '{name}': its samples are {pace:.4g} s apart, {pace / dt:.3g}× the model's dt = "
                     f"{dt:g} s: " + (f"the filter predicts about {pace / dt - 1:.0f} grid samples between "
                                      f"readings" if output else
                                      f"each is held over about {pace / dt:.0f} grid samples") +
                     " (a model faster than its log; or a dt in other units than the stamps?)")
    if output and not count:
        notes.append(f"output '{name}' (column '{column}') has no value: never measured")
    return notes


class Wraps:
    """An output's readings in order, looked at as an angle wrapped to one turn (2π or 360): jumps
    of about a turn between consecutive readings, in a column that otherwise moves in small steps
    and stays within a turn. A heading logged in (−π, π] crossing south jumps by 2π: the filter
    took each crossing for 25 outliers and a restart, said as nothing but outliers."""

    TURNS = {2 * np.pi: ("2π", "radians", ""), 360.0: ("360", "degrees", ", period=360")}
    NEAR = 0.2       # a jump within this share of a turn of a full turn
    SMALL = 0.05     # ... in a column whose other steps are under this share of a turn,
    SMOOTH = 0.9     # ... this share of its steps at least

    def __init__(self):
        self.last, self.lo, self.hi, self.steps = None, np.inf, -np.inf, 0
        self.jumps = dict.fromkeys(self.TURNS, 0)
        self.small = dict.fromkeys(self.TURNS, 0)
        self.first = dict.fromkeys(self.TURNS)

    def add(self, t, v) -> None:
        ok = np.isfinite(v)
        t, v = np.asarray(t, float)[ok], np.asarray(v, float)[ok]
        if not len(v):
            return
        seq = v if self.last is None else np.r_[self.last, v]
        step, at = np.abs(np.diff(seq)), t[len(t) - len(seq) + 1:]
        for turn in self.TURNS:
            near = np.flatnonzero(np.abs(step - turn) < self.NEAR * turn)
            self.jumps[turn] += len(near)
            self.small[turn] += int(np.sum(step < self.SMALL * turn))
            if len(near) and self.first[turn] is None:
                self.first[turn] = float(at[near[0]])
        self.steps += len(step)
        self.lo, self.hi, self.last = min(self.lo, v.min()), max(self.hi, v.max()), float(v[-1])

    def note(self, name: str, origin: float = 0.0) -> list[str]:
        """The note for output ``name`` (times relative to ``origin``, s), or none."""
        for turn, (text, unit, period) in self.TURNS.items():
            within = self.lo >= -0.5001 * turn and self.hi <= 1.0001 * turn and self.hi - self.lo <= 1.0001 * turn
            if self.jumps[turn] and within and self.jumps[turn] + self.small[turn] >= self.SMOOTH * self.steps:
                return [f"output '{name}': its readings jump by about {text} {self.jumps[turn]} time(s) (first at "
                        f"t = {clock(origin + self.first[turn])} s) and stay within one turn ({self.lo:.4g} to "
                        f"{self.hi:.4g}): an angle in {unit} wrapped to one turn, while the model's is continuous: "
                        f"each jump reads as a turn the plant did not make (a filter gates it as outliers and "
                        f"restarts; a fit takes it for a disturbance). Unwrap it first "
                        f"(numpy.unwrap(angle{period}))"]
        return []


def _held_note(name, column, run, repeats) -> str:
    return (f"output '{name}' (column '{column}') repeats each reading about {run} times in a row, as a "
            f"logger that holds a slower sensor's last reading writes it: only the first of each run is "
            f"used ({repeats} repeats left out), at its own time stamp; used as readings, the repeats "
            f"would count one measurement {run} times and narrow the error bars. Write an empty cell "
            f"where no new reading came")


def grid_phase(r: np.ndarray, dt: float) -> float:
    """The shift in (−dt/2, dt/2] of a grid of step ``dt`` that centres stamps ``r`` (seconds from
    its first sample) on it: the circular mean of their phase, when the Rayleigh test rejects a
    uniform phase at PHASE_ALPHA (n·R² > −ln α: stamps that keep to a grid of step dt, jittered or
    not); else 0 (a log at another rate, or too few stamps). Shifts below 10⁻⁶ dt are 0."""
    if not len(r):
        return 0.0
    with np.errstate(over="ignore", invalid="ignore"):    # an absurd stamp: its length check names it
        a = 2 * np.pi * np.asarray(r, float) / dt
        c, s = np.mean(np.cos(a)), np.mean(np.sin(a))
    if not len(a) * (c * c + s * s) > -np.log(PHASE_ALPHA):
        return 0.0
    phase = dt * np.arctan2(s, c) / (2 * np.pi)
    return float(phase) if abs(phase) > 1e-6 * dt else 0.0


def grid_index(ts, start: float, dt: float) -> np.ndarray:
    """The grid sample nearest each stamp; at a tie (half-way within TIE) the later one, for every
    stamp alike (np.rint's half-to-even, under the stamps' rounding, sent readings logged half a
    sample off the inputs to either side, two to one sample: 155 of 400 lost)."""
    return np.floor((np.asarray(ts, float) - start) / dt + (0.5 + TIE)).astype(np.int64)


def _nearest(ts, start, dt, n):
    """(grid index of each sample used, the samples' positions): the nearest within dt/2, nearest wins."""
    k = grid_index(ts, start, dt)
    dist = np.abs(ts - (start + k * dt))
    ok = np.flatnonzero((k >= 0) & (k < n) & (dist <= (0.5 + TIE) * dt))
    order = ok[np.lexsort((dist[ok], k[ok]))]
    first = np.ones(len(order), bool)
    first[1:] = k[order][1:] != k[order][:-1]
    return k[order[first]], order[first]


def first_known(after: float, dt: float, input_hold: str) -> float:
    """The grid sample (a float, from the grid start) at which an input stamped ``after`` seconds
    after the grid start is first used: the one nearest it under a zero-order hold (the grid's
    rule), the first at or after it under a first-order hold (interpolation reaches back)."""
    k = after / dt
    return np.floor(k - 0.5) + 1 if input_hold == "zoh" else np.ceil(k - 1e-6)


def gap_limit(head, max_gap: float, dt: float) -> float:
    """Seconds without a sample that make a hole in an input whose first stamps are ``head``
    (RATE_STAMPS + 1 of them, or all it has): ``max_gap`` (already at least MIN_GAP_SAMPLES of dt),
    or RATE_GAP of its median interval where that is shorter (but not below MIN_GAP_SAMPLES of dt)."""
    own = interval(head)
    return max_gap if own is None else min(max_gap, max(RATE_GAP * own, MIN_GAP_SAMPLES * dt) + TIE * dt)


SHORT_GAP = 4       # an input without a sample for this many of its own intervals (3 missing), short of a hole: held


def interval(head) -> float | None:
    """An input's own sample interval: the median of its first stamps' (None: too few)."""
    iv = np.diff(np.asarray(head, float)[:RATE_STAMPS + 1])
    iv = iv[iv > 0]
    return float(np.median(iv)) if iv.size >= RATE_MIN else None


def pace(head) -> float | None:
    """A column's mean sample interval over its first stamps, its gaps left out (an interval past
    GAP_SHARE of the median: a reading missing, twice it; a jitter of ±0.3 intervals reaches 1.6):
    a clock's rate, to 0.2 % under that jitter (their median's error is 2 %). A gyro missing 4 % of
    its single readings was said a clock running 5 % slow."""
    iv = np.diff(np.asarray(head, float)[:RATE_STAMPS + 1])
    if iv.size < RATE_MIN or not np.all(iv > 0):
        return None
    iv = iv[iv <= GAP_SHARE * np.median(iv)]
    return float(np.mean(iv)) if iv.size >= RATE_MIN else None


def short_gaps(gaps, own: float | None, limit: float, dt: float) -> tuple[int, int, float]:
    """(how many of the intervals ``gaps`` (s) are gaps short of a hole, the grid samples they
    hold the input over, the longest): longer than SHORT_GAP of the input's own interval ``own``
    and than 3 dt, at most ``limit``."""
    if own is None:
        return 0, 0, 0.0
    gaps = np.asarray(gaps, float)
    short = gaps[(gaps > max(SHORT_GAP * own, 3 * dt)) & (gaps <= limit)]
    held = int(np.sum(np.rint((short - max(own, dt)) / dt)))
    return len(short), held, float(short.max(initial=0.0))


def _short_gap_note(name, count, held, longest, limit) -> list[str]:
    if not count:
        return []
    return [f"input '{name}': {count} gap(s) short of a hole (the longest {longest:.3g} s; a hole is longer than "
            f"{limit:.3g} s) hold its last value over {held} grid sample(s), where the plant's input is not known; "
            f"the states are not restarted there (--max-gap shorter makes them holes)"]


def _holes(series, names, inputs, start, end, max_gap, columns, dt) -> list[Hole]:
    spans = {}
    for name in names:
        ts = series[name][0]
        limit = gap_limit(ts, max_gap, dt) if name in inputs else max_gap
        edges = np.concatenate([[start], ts[(ts > start) & (ts < end)], [end]])
        gaps = np.flatnonzero(np.diff(edges) > limit)
        for j in gaps:
            spans.setdefault((float(edges[j]), float(edges[j + 1])), []).append(name)
    return [Hole(a, b, tuple(columns[n] for n in c), any(n in inputs for n in c)) for (a, b), c in sorted(spans.items())]


def hole_threshold(max_gap: float, dt: float) -> float:
    """Seconds without a sample that make a hole: ``max_gap``, and at least MIN_GAP_SAMPLES of the
    model's dt (a building model at dt = 60 s under the default 1 s listed every sample interval
    of its log as a hole), and TIE of a sample more: a gap as long as it is none (stamps every 0.05 s
    under --max-gap 0.05 made 215 holes of 0.2 − 0.15 > 0.05 in floating point)."""
    return max(float(max_gap), MIN_GAP_SAMPLES * dt) + TIE * dt


def to_grid(samples: Samples, dt: float, input_names, output_names, input_hold: str = "zoh", *,
            time_unit: str = "s", max_gap: float = 1.0, min_samples: int = 2) -> Recording:
    """The samples on the grid of step ``dt`` (seconds); see the module docstring for the rule."""
    max_gap = hole_threshold(max_gap, dt)
    input_names, output_names = tuple(input_names), tuple(output_names)
    scale, note = time_scale(samples, time_unit, dt)
    notes = list(samples.notes) + ([note] if note else [])
    if not any(len(g.t) for g in samples.groups):
        raise RecordingError(f"{samples.source}: no samples (nothing below the header)")
    origin = min(float(g.t[0]) * (1.0 if g.seconds else scale) for g in samples.groups if len(g.t))
    series, cols = _series(samples, scale, origin), samples.columns   # relative times: exact arithmetic
    for name in input_names:
        if not len(series[name][0]):
            raise RecordingError(f"{samples.source}, column '{cols[name]}': input '{name}' has no value")
    for name in input_names + output_names:
        _refuse_coarse(samples, name, series[name][0], dt)
    firsts = [series[n][0][0] for n in input_names] or [series[n][0][0] for n in output_names if len(series[n][0])]
    if not firsts:
        raise RecordingError(f"{samples.source}: no output has a value")
    start = float(max(firsts) if input_names else min(firsts))
    first = np.sort(np.concatenate([series[n][0][:PHASE_STAMPS] for n in input_names or output_names]))
    start += grid_phase(first[:PHASE_STAMPS] - start, dt)
    end = float(max(s[0][-1] for s in series.values() if len(s[0])))
    n = _check_length(samples, series, start, end, dt)
    if n < min_samples:
        raise RecordingError(f"{samples.source}: {n} sample(s) of the model's grid (dt = {dt:g} s) from "
                             f"t = {clock(start)} to {clock(end)} s, at least {min_samples} needed")
    t = start + dt * np.arange(n)
    inputs = np.empty((n, len(input_names)))
    for j, name in enumerate(input_names):
        ts, v = series[name][:2]
        if input_hold == "foh":
            inputs[:, j] = np.interp(t, ts, v)
        else:
            inputs[:, j] = v[np.searchsorted(ts, t + dt / 2, side="left") - 1]   # the last sample nearest ≤ t
        notes += _column_notes(name, cols[name], False, len(ts), 0, 0, *_repeats(ts), origin, start, dt,
                               pace=pace(ts))
        limit = gap_limit(ts, max_gap, dt)
        inside = ts[(ts > start) & (ts < end)]
        notes += _short_gap_note(name, *short_gaps(np.diff(np.concatenate([[start], inside, [end]])),
                                                   interval(ts), limit, dt), limit)
    outputs = np.full((n, len(output_names)), np.nan)
    for j, name in enumerate(output_names):
        ts, v = series[name][:2]
        if run := held_run(v[:RATE_STAMPS + 1]):
            fresh = np.r_[True, v[1:] != v[:-1]]
            notes.append(_held_note(name, cols[name], run, int(np.sum(~fresh))))
            ts, v = ts[fresh], v[fresh]
        k, used = _nearest(ts, start, dt, n)
        outputs[k, j] = v[used]
        wraps = Wraps()
        wraps.add(ts, v)
        notes += wraps.note(name, origin)
        early = int(np.sum(ts < start - dt / 2))
        notes += _column_notes(name, cols[name], True, len(ts), early, len(ts) - len(used) - early,
                               *_repeats(ts), origin, start, dt, interval(ts), pace(ts))
        notes += _offset_note(name, len(used), _offset_units(ts[used], k, start, dt), dt,
                              "inputs" if input_names else "outputs")
    holes = [Hole(h.t0 + origin, h.t1 + origin, h.columns, h.inputs) for h in
             _holes(series, input_names + output_names, input_names, start, end, max_gap, cols, dt)]
    return Recording(samples.source, origin + t, inputs, outputs, input_names, output_names,
                     holes=tuple(holes), notes=tuple(merged(notes)), columns=dict(cols), max_gap=max_gap)


# --------------------------------------------------------------------------- streamed

@dataclass
class GridBlock:
    """Consecutive grid samples ``k0, k0 + 1, …`` of a streamed recording."""

    k0: int
    t: np.ndarray          # (m,) seconds
    inputs: np.ndarray     # (m, nu)
    outputs: np.ndarray    # (m, ny), NaN where not measured


class _Column:
    """What the stream keeps of one column: its samples not yet laid on the grid, and counts."""

    def __init__(self, output: bool):
        self.t, self.v = np.zeros(0), np.zeros(0)
        self.new = []                 # stamps not yet looked at for holes
        self.first = self.last = None
        self.count = self.early = self.used = self.repeated = 0
        self.offset = 0               # the used samples' stamps minus their grid times, in OFFSET_UNIT
        self.first_repeat = None
        self.prev = None              # the last stamp looked at for holes (the grid start at first)
        self.head = np.zeros(0)       # its first RATE_STAMPS + 1 stamps (an input's own interval)
        self.head_v = np.zeros(0)     # and values (an output held by the logger, :func:`held_run`)
        self.judged = False           # whether those values were judged
        self.limit = None             # seconds without a sample that make a hole, once known
        self.own = None               # an input's own sample interval, once known
        self.short = (0, 0, 0.0)      # an input's gaps short of a hole: count, grid samples held, longest
        self.wraps = Wraps() if output else None   # an output's readings as a wrapped angle

    def add(self, t, v):
        if len(t):
            if len(self.head) <= RATE_STAMPS:
                self.head_v = np.concatenate([self.head_v, v[:RATE_STAMPS + 1 - len(self.head)]])
                self.head = np.concatenate([self.head, t[:RATE_STAMPS + 1 - len(self.head)]])
            repeated, first = _repeats(t, self.last)
            self.repeated += repeated
            self.first_repeat = first if self.first_repeat is None else self.first_repeat
            self.t, self.v = np.concatenate([self.t, t]), np.concatenate([self.v, v])
            if self.wraps is not None:
                self.wraps.add(t, v)
            self.new.append(t)
            self.first = float(t[0]) if self.first is None else self.first
            self.last = float(t[-1])
            self.count += len(t)

    def drop(self, i):
        self.t, self.v = self.t[i:], self.v[i:]


class GridStream:
    """:func:`to_grid` block by block: feed the :class:`~skigen.sources.Group` blocks of a CSV file in
    order (:meth:`feed`), then :meth:`finish`; each yields the :class:`GridBlock` s that are decided.

    The result is that of :func:`to_grid` on the whole file, sample for sample (the same
    expressions on the same numbers): a grid sample is laid out once no later time stamp can change
    it (every input has a stamp at or past it, every output a sample nearer the next grid sample:
    whether a sample after an input's last stamp is in a hole is known at its next stamp or the
    end of the file), and only the samples that can still matter are kept, so memory does not
    grow with the file (it grows with an input's hole, whose rows wait for its end). Three
    decisions are taken on the first block instead of the whole file: the time origin (the same:
    the first row), ``--time-unit auto`` and the check of the unit against dt (both from the
    median spacing of the first block). Holes and notes are complete after :meth:`finish`;
    ``restarts`` holds the grid samples at which an input is known again after a hole, each
    found before that sample is laid out. Anything the whole-file path would refuse raises
    :class:`~skigen.sources.NotStreamable`.
    """

    def __init__(self, stream, dt: float, input_names, output_names, input_hold: str = "zoh", *,
                 time_unit: str = "s", max_gap: float = 1.0, min_samples: int = 2, block: int = 1 << 16):
        self.stream, self.dt, self.hold, self.max_gap = stream, dt, input_hold, hole_threshold(max_gap, dt)
        self.input_names, self.output_names = tuple(input_names), tuple(output_names)
        self.names = self.input_names + self.output_names
        self.time_unit, self.min_samples, self.block = time_unit, min_samples, block
        self.cols = {n: _Column(n in self.output_names) for n in self.names}
        self.scale = self.origin = self.start = None
        self.next_k, self.end, self.row_t, self.n = 0, -np.inf, -np.inf, None
        self.spans, self.restarts = {}, set()
        self.notes, self.holes = list(stream.notes), ()
        self.first = []                 # the inputs' first PHASE_STAMPS stamps (the grid's phase)

    def __iter__(self):
        """Every grid block of the file, in order."""
        for g in self.stream:
            yield from self.feed(g)
        yield from self.finish()

    # ---------------------------------------------------------------- reading
    def feed(self, g):
        """Lay a block of rows: yields the grid blocks now decided."""
        from .sources import NotStreamable, Samples

        if not len(g.t):
            return
        if self.scale is None:
            first = Samples(self.stream.source, [g], self.stream.columns, self.stream.time_column)
            try:
                self.scale, note = time_scale(first, self.time_unit, self.dt)
            except RecordingError as e:
                raise NotStreamable(str(e)) from None
            self.notes += [note] if note else []
            self.origin = float(g.t[0]) * (1.0 if g.seconds else self.scale)
        t = (g.t if g.seconds else g.t * self.scale) - self.origin
        if len(self.first) < PHASE_STAMPS:
            ts = [t[np.isfinite(g.values[n])] for n in self.input_names or self.output_names]
            self.first += list(np.sort(np.concatenate(ts))[:PHASE_STAMPS - len(self.first)])
        for name in self.names:
            v = g.values[name]
            ok = np.isfinite(v)
            self.cols[name].add(t[ok], v[ok])
            if ok.any():
                self.end = max(self.end, float(t[ok][-1]))
        self._limits()
        self.row_t = float(t[-1])
        if self.start is None:
            self._find_start(len(self.first) < PHASE_STAMPS)
        if self.start is not None:
            self._scan_holes()
            self._check_length()
            yield from self._emit(self._frontier())

    def _find_start(self, wait: bool = False):
        """The grid start, once every input is known (``wait``: not before the phase's stamps are read)."""
        ins = [self.cols[n] for n in self.input_names]
        if wait and (not ins or all(c.first is not None for c in ins)):
            return
        if ins and all(c.first is not None for c in ins):
            self.start = max(c.first for c in ins)
        elif not ins and any(self.cols[n].first is not None for n in self.output_names):
            self.start = min(self.cols[n].first for n in self.output_names if self.cols[n].first is not None)
        else:                                   # an input not seen yet: the grid starts at or after this row
            low, half = self.row_t, self.dt / 2
            for n in self.input_names:
                c = self.cols[n]
                c.drop(max(int(np.searchsorted(c.t, low, side="right")) - 1, 0))
            for n in self.output_names:
                c = self.cols[n]
                gone = int(np.sum(c.t < low - half))        # before the inputs are known, whatever the start
                c.early += gone
                c.drop(gone)
            return
        self.start += grid_phase(np.asarray(self.first) - self.start, self.dt)
        for c in self.cols.values():
            c.prev = self.start

    def _limits(self, final: bool = False):
        """Each column's hole threshold, once known: an input's when it has RATE_STAMPS + 1 stamps
        (or at the end of the file), as :func:`to_grid` reads it from the whole file. An output
        held by the logger (:func:`held_run`) is left to the whole-file reader."""
        from .sources import NotStreamable

        for name in self.names:
            c = self.cols[name]
            if not c.judged and (final or len(c.head) > RATE_STAMPS):
                c.judged = True
                if name in self.output_names and held_run(c.head_v):
                    raise NotStreamable(f"output '{name}' is held by the logger")
                if coarse(c.head):              # the whole-file reader says where
                    raise NotStreamable(f"column '{name}' has coarse time stamps")
            if c.limit is None and (name not in self.input_names or final or len(c.head) > RATE_STAMPS):
                c.limit = gap_limit(c.head, self.max_gap, self.dt) if name in self.input_names else self.max_gap
                c.own = interval(c.head) if name in self.input_names else None

    def _scan_holes(self):
        for name in self.names:
            c = self.cols[name]
            if not c.new or c.limit is None:
                continue
            ts = np.concatenate(c.new)
            c.new = []
            ts = ts[ts > self.start]
            if not len(ts):
                continue
            edges = np.concatenate([[c.prev], ts])
            for j in np.flatnonzero(np.diff(edges) > c.limit):
                self._span(float(edges[j]), float(edges[j + 1]), name)
            self._short(c, np.diff(edges))
            c.prev = float(ts[-1])

    def _short(self, c, gaps):
        """Count an input's gaps short of a hole (:func:`short_gaps`)."""
        if c.own is not None:
            n, held, longest = short_gaps(gaps, c.own, c.limit, self.dt)
            c.short = (c.short[0] + n, c.short[1] + held, max(c.short[2], longest))

    def _span(self, a, b, name):
        self.spans.setdefault((a, b), []).append(name)
        if name in self.input_names:        # as runtime.restarts computes it from the whole recording
            k = first_known((b + self.origin) - (self.origin + self.start), self.dt, self.hold)
            if not k < 2 ** 62:             # a stamp far beyond the others: the whole-file reader names it
                from .sources import NotStreamable
                raise NotStreamable("the grid is too long for the time stamps")
            self.restarts.add(int(k))

    def _stamps(self) -> int:
        return sum(c.count for c in self.cols.values())

    def _check_length(self):
        from .sources import NotStreamable

        span = (self.end - self.start) / self.dt
        n = int(np.floor(span + 0.5)) + 1 if np.isfinite(span) and span < 2 ** 62 else -1
        if not 0 < n <= GRID_PER_STAMP * self._stamps() + 10_000:
            raise NotStreamable("the grid is too long for the time stamps")
        return n

    # ---------------------------------------------------------------- the grid
    def _time(self, k):
        return self.start + self.dt * np.asarray(k)

    def _count(self, decided, guess) -> int:
        """The number of grid samples k ≥ 0 for which ``decided(t_k)`` holds (it holds up to some k)."""
        k = max(int(guess) - 2, 0)
        while k > 0 and not decided(self._time(k - 1)):
            k -= 1
        while decided(self._time(k)):
            k += 1
        return k

    def _frontier(self) -> int:
        """Grid samples below this are decided by the samples read so far."""
        dt, half, row = self.dt, self.dt / 2, self.row_t
        if any(self.cols[n].limit is None for n in self.input_names):
            return self.next_k               # an input's holes are not known yet: nothing decided
        guess = lambda T: np.floor((T - self.start) / dt) if np.isfinite(T) else 0
        k = self._check_length()                                   # grid samples that exist already
        # an input hole up to the last stamp restarts the states about there (known at the end): keep a margin
        k = min(k, self._count(lambda t: t < self.end - dt, guess(self.end)))
        for name in self.input_names:
            c = self.cols[name]
            if self.hold == "foh":
                k = min(k, self._count(lambda t, T=c.last: T > t, guess(c.last)))
            else:          # its value: no stamp can come before row; a hole: none after its last stamp yet
                k = min(k, self._count(lambda t, a=c.last: t <= a and t + half <= row, guess(c.last)))
        for name in self.output_names:
            c = self.cols[name]
            T = max(c.last if c.last is not None else -np.inf, row)
            k = min(k, int(grid_index(T, self.start, dt)))
        return max(k, self.next_k)

    def _emit(self, stop):
        """The grid samples from next_k to ``stop``, in blocks."""
        while self.next_k < stop:
            a = self.next_k
            b = min(stop, a + self.block)
            yield self._lay(a, b)
            self.next_k = b

    def _lay(self, a, b) -> GridBlock:
        dt, n = self.dt, self.n if self.n is not None else b
        t = self.start + dt * np.arange(a, b)
        inputs = np.empty((b - a, len(self.input_names)))
        t_next = self.start + dt * b
        for j, name in enumerate(self.input_names):
            c = self.cols[name]
            if self.hold == "foh":
                inputs[:, j] = np.interp(t, c.t, c.v)
                keep = int(np.searchsorted(c.t, t_next, side="right")) - 1
            else:
                inputs[:, j] = c.v[np.searchsorted(c.t, t + dt / 2, side="left") - 1]
                keep = int(np.searchsorted(c.t, t_next + dt / 2, side="left")) - 1
            c.drop(max(keep, 0))
        outputs = np.full((b - a, len(self.output_names)), np.nan)
        for j, name in enumerate(self.output_names):
            c = self.cols[name]
            k = grid_index(c.t, self.start, dt)
            m = len(c.t) if self.n is not None else int(np.searchsorted(k, b, side="left"))
            ts, v = c.t[:m], c.v[:m]
            kk, used = _nearest(ts, self.start, dt, n)
            inside = (kk >= a) & (kk < b)
            outputs[kk[inside] - a, j] = v[used[inside]]
            c.offset += _offset_units(ts[used[inside]], kk[inside], self.start, dt)
            c.early += int(np.sum(ts < self.start - dt / 2))
            c.used += len(used)
            c.drop(m)
        return GridBlock(a, self.origin + t, inputs, outputs)

    def finish(self):
        """The rest of the grid; then ``holes``, ``notes`` and ``n`` are complete."""
        from .sources import NotStreamable

        if self.start is None:
            self._find_start()
        if self.start is None:
            raise NotStreamable("no grid start")
        self._limits(final=True)
        self._scan_holes()
        self.n = self._check_length()
        if self.n < self.min_samples:
            raise NotStreamable("too few grid samples")
        for name in self.names:
            c = self.cols[name]
            if self.end - c.prev > c.limit:
                self._span(c.prev, self.end, name)
            self._short(c, [self.end - c.prev])
        yield from self._emit(self.n)
        order = {n: i for i, n in enumerate(self.names)}
        cols, dt = self.stream.columns, self.dt
        holes = []
        for (a, b), names in sorted(self.spans.items()):
            names = sorted(names, key=order.get)
            holes.append(Hole(a + self.origin, b + self.origin, tuple(cols[n] for n in names),
                              any(n in self.input_names for n in names)))
        self.holes = tuple(holes)
        for name in self.names:
            c, output = self.cols[name], name in self.output_names
            self.notes += _column_notes(name, cols[name], output, c.count, c.early,
                                        c.count - c.used - c.early if output else 0, c.repeated,
                                        c.first_repeat, self.origin, self.start, dt, interval(c.head),
                                        pace(c.head))
            if output:
                self.notes += _offset_note(name, c.used, c.offset, dt, "inputs" if self.input_names else "outputs")
                self.notes += c.wraps.note(name, self.origin)
            else:
                self.notes += _short_gap_note(name, *c.short, c.limit)
        self.notes = merged(self.notes)

    def time(self, k) -> float:
        """The time of grid sample ``k`` (seconds), as in the recording."""
        return self.origin + (self.start + self.dt * k)

    @property
    def restart_list(self):
        return sorted(k for k in self.restarts if 0 < k < (self.n or np.inf))
