"""Recordings: time-stamped samples read from a file or a DataFrame, laid onto the model's grid.

:func:`load_recording` is the entry point: it reads a CSV, Parquet or PX4 ULog
file or a pandas DataFrame (:mod:`skigen.sources`) and lays the samples onto
the model's sample grid (:mod:`skigen.grid`), reporting holes. A
:class:`Recording` holds the result as read-only arrays. :func:`read_recording`
reads a file by names; given ``dt`` it returns the grid, without it the rows as
they are (strictly increasing time, every input present). Anything malformed
raises :class:`RecordingError` naming the file, row and column.
"""
from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field

import numpy as np

__all__ = ["RecordingError", "Recording", "resolution", "load_recording", "stream_recording", "read_recording", "write_recording",
           "write_table", "TableWriter"]


class RecordingError(ValueError):
    """A recording file that breaks the contract; the message says where."""


STUCK_RUN = 10      # identical readings in a row from which a sensor counts as stuck (the guard's stuck_limit)


def _listed(items, most: int = 5) -> str:
    """The first ``most`` items, '; '-separated, and how many more."""
    items = list(items)
    more = f"; … {len(items) - most} more" if len(items) > most else ""
    return "; ".join(map(str, items[:most])) + more


@dataclass(frozen=True, eq=False)
class Recording:
    """Time, inputs and outputs of one run, as read-only arrays."""

    path: str
    t: np.ndarray  # (N,) seconds
    inputs: np.ndarray  # (N, nu), never NaN
    outputs: np.ndarray  # (N, ny), NaN where not measured
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    holes: tuple = ()             # grid.Hole: spans longer than max_gap without a sample of some column
                                  # (an input's: or than 10 of its own intervals, grid.gap_limit)
    notes: tuple[str, ...] = ()   # what reading decided (time unit, samples not used)
    columns: dict = field(default_factory=dict)   # model name -> column it was read from
    max_gap: float = float("nan")  # seconds: the hole threshold used

    def __post_init__(self):
        for a in (self.t, self.inputs, self.outputs):
            a.flags.writeable = False

    def __len__(self) -> int:
        return len(self.t)

    @property
    def measured(self) -> np.ndarray:
        """(N, ny) True where an output was measured."""
        return np.isfinite(self.outputs)

    @property
    def dt(self) -> float:
        """Median sample interval in seconds (NaN with fewer than 2 samples)."""
        return float(np.median(np.diff(self.t))) if len(self.t) > 1 else float("nan")

    def stuck_output(self) -> str | None:
        """A sentence naming the first output that reads the same value in every sample where it
        is measured (a stuck or disconnected sensor: nothing to fit or judge), or None."""
        for name, y in zip(self.output_names, self.outputs.T):
            y = y[np.isfinite(y)]
            if len(y) > 1 and np.all(y == y[0]):
                return (f"{self.path}: output '{name}' reads {y[0]:g} in all {len(y)} samples where it is "
                        f"measured: a stuck or disconnected sensor carries nothing to fit (drop the output "
                        f"from the model, or read another column with --map {name}=COLUMN or columns=)")
        return None

    def unstuck(self) -> tuple[Recording, list[str]]:
        """This recording with a stuck sensor's readings as not measured, and a sentence per output
        naming them. Stuck: identical readings in a row, at least STUCK_RUN and 5 times as many as
        the output's readings usually repeat (a slow sensor logged at a faster rate repeats each
        reading), of a value inside the range of its other readings (a clipped sensor reads its
        bound: an extreme), after the first reading (a recording may begin at rest), from a
        sensor that is not quantised (:func:`resolution` 0: a quantised one reads the same count
        at rest)."""
        outputs, notes = self.outputs.copy(), []
        for j, name in enumerate(self.output_names):
            at = np.flatnonzero(np.isfinite(outputs[:, j]))
            y = outputs[at, j]
            if len(y) < 2 or resolution(y) > 0:
                continue
            starts = np.flatnonzero(np.r_[True, y[1:] != y[:-1]])
            ends = np.r_[starts[1:], len(y)]
            limit = max(STUCK_RUN, 5 * np.median(ends - starts))
            runs = [(a, b) for a, b in zip(starts, ends) if b - a >= limit and a > 0 and y.min() < y[a] < y.max()]
            if runs:
                for a, b in runs:
                    outputs[at[a:b], j] = np.nan
                a, b = runs[0]
                notes.append(f"{self.path}: output '{name}' holds one reading in {sum(b - a for a, b in runs)} "
                             f"samples ({len(runs)} run(s) of {limit:g} or more; the first reads {y[a]:g} from t = "
                             f"{self.t[at[a]]:g} to {self.t[at[b - 1]]:g} s), far longer than its readings "
                             f"repeat elsewhere: a stuck sensor, those readings left out")
        return (dataclasses.replace(self, outputs=outputs) if notes else self), notes

    @property
    def input_holes(self) -> tuple:
        """The holes in which an input is not known."""
        return tuple(h for h in self.holes if h.inputs)

    def usable(self) -> tuple[list[Recording], list[str]]:
        """(this recording without a stuck sensor's readings (:meth:`unstuck`), cut at its input
        holes (:meth:`input_parts`), a sentence per stuck sensor); an error where no stretch
        between the holes remains."""
        rec, notes = self.unstuck()
        parts = rec.input_parts()
        if not parts:
            longest = max(h.t1 - h.t0 for h in rec.input_holes)
            raise RecordingError(f"{rec.path}: no two consecutive samples with every input known between the "
                                 f"input holes ({_listed(rec.input_holes)}); an input logged this sparsely is held "
                                 f"between its samples when max_gap exceeds its longest hole, {longest:.3g} s "
                                 f"(--max-gap SECONDS; max_gap= in Python)")
        return parts, notes

    def said(self) -> list[str]:
        """The reading's notes, each naming this recording (one of several a fit reads)."""
        return [n if n.startswith(str(self.path)) else f"{self.path}: {n}" for n in self.notes]

    def hole_note(self, what: str) -> str:
        """A sentence on this recording's input holes, ending in what was done about them; where the
        stretches between them hold less than half the samples, how to hold a sparse input."""
        from .grid import RATE_GAP
        kept = sum(len(p.t) for p in self.input_parts())
        sparse = ""
        if kept < len(self.t) / 2:
            longest = max(h.t1 - h.t0 for h in self.input_holes)
            sparse = (f"; those stretches hold {kept} of the {len(self.t)} samples: an input logged only when "
                      f"it changes is held between its samples with a max_gap longer than its longest hole, "
                      f"{longest:.3g} s (--max-gap SECONDS; max_gap= in Python)")
        return (f"{self.path}: the held input is not the input in its hole(s) longer than max_gap = "
                f"{self.max_gap:g} s or than {RATE_GAP} of the input's own sample intervals "
                f"({_listed(self.input_holes)}): {what}{sparse}")

    def input_parts(self) -> list[Recording]:
        """The stretches between this recording's input holes (an input without a sample for
        longer than ``max_gap``: the value held there is not the input), each with at least two
        samples and named ``'<path> [t0–t1 s]'``; ``[self]`` where no input has a hole."""
        from .grid import clock
        spans = [(h.t0, h.t1) for h in self.input_holes]
        if not spans:
            return [self]
        tol = 1e-6 * self.dt
        keep = np.ones(len(self.t), bool)
        for t0, t1 in spans:
            keep &= ~((self.t > t0 + tol) & (self.t < t1 - tol))
        edges = np.flatnonzero(np.diff(np.r_[0, keep.astype(int), 0]))
        parts = []
        for a, b in zip(edges[::2], edges[1::2]):
            if b - a < 2:
                continue
            ta, tb = self.t[a], self.t[b - 1]
            parts.append(dataclasses.replace(
                self.slice(a, b), path=f"{self.path} [{clock(ta)}–{clock(tb)} s]",
                holes=tuple(h for h in self.holes if not h.inputs and h.t1 > ta and h.t0 < tb)))
        return parts

    def slice(self, start: int | None, stop: int | None) -> Recording:
        """The samples with index in ``range(start, stop)`` (Python slice rules)."""
        s = slice(start, stop)
        return dataclasses.replace(self, t=self.t[s], inputs=self.inputs[s], outputs=self.outputs[s])


def held_run(values, runs: int = 8) -> int:
    """L ≥ 2 when ``values`` (a column's first readings, in order) repeat each reading L times in
    a row, as a logger that holds a slower sensor's last reading writes it (a 1 Hz fix in a 10 Hz
    log: each value 10 times); else 0. Regular runs — at least ``runs`` complete ones, nine in
    ten longer than 1, the middle 80 % within a quarter of their median — of values that are not
    on a quantisation grid (:func:`resolution`: an encoder at rest repeats its count)."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    edges = np.flatnonzero(np.r_[True, v[1:] != v[:-1], True])
    lengths = np.diff(edges)[1:-1]                     # the first and last runs may be cut
    if len(lengths) < runs or np.mean(lengths > 1) < 0.9 or resolution(v) > 0:
        return 0
    lo, mid, hi = np.percentile(lengths, [10, 50, 90])
    return int(round(mid)) if mid >= 2 and hi - lo <= max(1.0, 0.25 * mid) else 0


REPEATS = 10    # readings equal to the one before them that show a quantised signal with many levels


def resolution(values) -> float:
    """The step of a quantised signal (an encoder's count, an ADC's least significant bit), or 0
    when it is not quantised: the smallest gap between distinct values, when values repeat (fewer
    distinct values than half the samples, or REPEATS readings equal to the one before them: a
    moving encoder reads 1687 counts in 3000 samples and repeats one while the motor rests) and
    every gap is a whole multiple of it. (A number format's last digit on a noisy signal gives
    whole multiples too, but no repeats.)"""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    levels = np.unique(v)
    if len(levels) < 3 or (len(levels) > len(v) / 2 and np.sum(v[1:] == v[:-1]) < REPEATS):
        return 0.0
    gaps = np.diff(levels)
    k = gaps / gaps.min()
    return float(gaps.min()) if np.all(np.abs(k - np.round(k)) < 0.01) else 0.0


def load_recording(source, model, *, time=None, time_unit: str = "s", columns=None, max_gap: float = 1.0,
                   real: str = "double") -> Recording:
    """``source`` (a CSV, Parquet or ULog path, or a DataFrame) on ``model``'s grid.

    time: the time column (default t, time or timestamp); time_unit: s, ms, us, ns or auto;
    columns: model input/output name -> column; max_gap: seconds without a sample reported as
    a hole; real: 'float' also rejects values beyond the C float range.
    """
    return read_recording(source, model.input_names, model.output_names, dt=model.dt,
                          input_hold=model.input_hold, time=time, time_unit=time_unit, columns=columns,
                          max_gap=max_gap, real=real)


def stream_recording(path, model, *, time=None, time_unit: str = "s", columns=None, max_gap: float = 1.0,
                     real: str = "double", block_size: int | None = None, rows: int | None = None,
                     block: int = 1 << 16):
    """A CSV file on ``model``'s grid, read as it is used: a :class:`~skigen.grid.GridStream`
    whose iteration yields blocks of at most ``block`` grid samples, the same samples as
    :func:`load_recording` gives, holding a block of the file (``block_size`` bytes; ``rows``
    re-cuts it, for tests) instead of the whole recording. The header and the columns are checked
    now; iterating raises :class:`~skigen.sources.NotStreamable` where only the whole-file reader
    can decide (it names the row). Options as in :func:`load_recording`.
    """
    from .grid import GridStream
    from .sources import STREAM_BLOCK_SIZE, stream_csv

    stream = stream_csv(path, model.input_names + model.output_names, columns=columns, time=time, real=real,
                        block_size=block_size or STREAM_BLOCK_SIZE, rows=rows)
    return GridStream(stream, model.dt, model.input_names, model.output_names, model.input_hold,
                      time_unit=time_unit, max_gap=max_gap, block=block)


def read_recording(path, input_names, output_names, *, dt: float | None = None, input_hold: str = "zoh",
                   time=None, time_unit: str = "s", columns=None, max_gap: float = 1.0, real: str = "double",
                   min_samples: int = 2) -> Recording:
    """Read ``path`` (or a DataFrame) for the named inputs and outputs.

    With ``dt`` (seconds): the samples on that grid (see :mod:`skigen.grid`). Without: the
    rows as they are, which then need strictly increasing time and every input in every row.
    Other options as in :func:`load_recording`.
    """
    from .grid import UNITS, to_grid
    from .sources import read_samples

    input_names, output_names = tuple(input_names), tuple(output_names)
    samples = read_samples(path, input_names + output_names, columns=columns, time=time, real=real)
    if dt is not None:
        return to_grid(samples, dt, input_names, output_names, input_hold, time_unit=time_unit,
                       max_gap=max_gap, min_samples=min_samples)
    (g,) = samples.groups
    src, cols = samples.source, samples.columns

    def fail(i, col, msg):
        raise RecordingError(f"{src}, {g.where(i)}, column '{col}': {msg}")
    for name in input_names:
        bad = ~np.isfinite(g.values[name])
        if bad.any():
            fail(int(np.argmax(bad)), cols[name], "no value: inputs must be present in every row "
                                                  "(or give the model's dt to hold them)")
    same = np.diff(g.t) <= 0
    if same.any():
        i = int(np.argmax(same)) + 1
        fail(i, samples.time_column, f"time must be strictly increasing: {float(g.t[i])!r} follows "
                                     f"{float(g.t[i - 1])!r} (row above)")
    if len(g.t) < min_samples:
        raise RecordingError(f"{src}: {len(g.t)} data row(s), at least {min_samples} needed")
    if time_unit not in UNITS:
        raise RecordingError(f"time unit '{time_unit}': choose s, ms, us or ns (auto needs the model's dt)")
    scale = 1.0 if g.seconds else UNITS[time_unit]
    return Recording(src, g.t * scale,
                     np.column_stack([g.values[n] for n in input_names]).reshape(len(g.t), len(input_names)),
                     np.column_stack([g.values[n] for n in output_names]).reshape(len(g.t), len(output_names)),
                     input_names, output_names, notes=tuple(samples.notes), columns=dict(cols))


def write_recording(path, t, inputs: dict, outputs: dict, extra: dict | None = None) -> None:
    """Write a recording readable by :func:`read_recording`; NaN outputs become empty cells."""
    columns = {"t": t}
    for group in (inputs, outputs, extra or {}):
        for name, values in group.items():
            if name in columns:
                raise ValueError(f"duplicate column name {name!r}")
            columns[name] = values
    write_table(path, columns)


def _csv_cell(text: str) -> str:
    return '"' + text.replace('"', '""') + '"' if any(c in text for c in ',"\r\n') else text


class TableWriter:
    """CSV written a block of columns at a time (pyarrow): numbers in their shortest exact form,
    NaN as an empty cell, text as is. Use as a context manager; :meth:`write` each block.

    With ``background=True`` the blocks are formatted and written by a thread (pyarrow releases
    the GIL), at most ``queue`` blocks behind, while the caller computes the next: formatting
    numbers is the slowest part of a run over a long log, and this overlaps it with the filter.
    An error in the thread is raised by the next :meth:`write` or by :meth:`close`.

    The blocks go to ``<path>.partial``, renamed to ``path`` when the writer closes without an
    error: a run that fails part way leaves an earlier result at ``path`` as it was.
    """

    def __init__(self, path, background: bool = False, queue: int = 2):
        self.path, self._writer, self._error = path, None, None
        self._partial = f"{os.fspath(path)}.partial"
        self._thread = self._queue = None
        if background:
            import queue as q
            self._queue = q.Queue(maxsize=queue)
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)

    def write(self, columns: dict) -> None:
        n = len(np.asarray(next(iter(columns.values()))))
        columns = {name: np.asarray(v) for name, v in columns.items()}
        for name, v in columns.items():
            if v.ndim != 1 or len(v) != n:
                raise ValueError(f"column {name!r}: expected a 1-D array of equal length, got shape {v.shape}")
        if self._queue is None:
            self._write(columns)
            return
        if self._error is not None:
            raise self._error
        if self._thread is None:
            import threading
            self._thread = threading.Thread(target=self._drain, name="TableWriter", daemon=True)
            self._thread.start()
        self._queue.put(columns)

    def _drain(self):
        while (columns := self._queue.get()) is not None:
            if self._error is None:
                try:
                    self._write(columns)
                except BaseException as e:  # raised in the caller's thread
                    self._error = e

    def _write(self, columns: dict) -> None:
        import pyarrow as pa
        import pyarrow.csv as pc

        table = pa.Table.from_arrays(
            [pa.array(v if v.dtype.kind in "iu" else v.astype(float) if v.dtype.kind in "bf" else v, from_pandas=True)
             for v in columns.values()], names=list(columns))

        if self._writer is None:
            self._file = open(self._partial, "wb")
            self._file.write((",".join(_csv_cell(n) for n in table.column_names) + "\n").encode())
            self._writer = pc.CSVWriter(self._file, table.schema, write_options=pc.WriteOptions(
                include_header=False, quoting_style="none"))
        self._writer.write_table(table)

    def close(self, keep: bool = True) -> None:
        """Finish the file and rename it to ``path``; keep=False: remove it instead."""
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join()
            self._thread = None
        written = self._writer is not None
        if written:
            self._writer.close()
            self._file.close()
            self._writer = None
        if self._error is not None or not keep:
            if written:
                os.remove(self._partial)
            if self._error is not None:
                error, self._error = self._error, None
                raise error
        elif written:
            os.replace(self._partial, self.path)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        try:
            self.close(keep=exc[0] is None)
        except BaseException:
            if exc[0] is None:
                raise


def write_table(path, columns: dict) -> None:
    """Write equal-length 1-D columns as one CSV (see :class:`TableWriter`)."""
    with TableWriter(path) as w:
        w.write(columns)
