"""Flight-test recordings as CSV: strict reading, exact writing.

Contract: a header row; first column ``t`` (seconds, strictly increasing);
one column per model input and output, named as in the model.  Extra columns
are ignored but must hold numbers or be empty.  An empty or NaN output cell
means "not measured" and stays NaN (the filter skips that update).  Anything
else malformed raises :class:`RecordingError` naming file, row and column.
"""
from __future__ import annotations

import csv
import dataclasses
import io
import os
from dataclasses import dataclass

import numpy as np

__all__ = ["RecordingError", "Recording", "read_recording", "write_recording", "write_table"]


class RecordingError(ValueError):
    """A recording file that breaks the contract; the message says where."""


@dataclass(frozen=True, eq=False)
class Recording:
    """Time, inputs and outputs of one run, as read-only arrays."""

    path: str
    t: np.ndarray  # (N,) seconds
    inputs: np.ndarray  # (N, nu), never NaN
    outputs: np.ndarray  # (N, ny), NaN where not measured
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]

    def __post_init__(self):
        for a in (self.t, self.inputs, self.outputs):
            a.flags.writeable = False

    def __len__(self) -> int:
        return len(self.t)

    @property
    def dt(self) -> float:
        """Median sample interval in seconds (NaN with fewer than 2 samples)."""
        return float(np.median(np.diff(self.t))) if len(self.t) > 1 else float("nan")

    def slice(self, start: int | None, stop: int | None) -> Recording:
        """The samples with index in ``range(start, stop)`` (Python slice rules)."""
        s = slice(start, stop)
        return dataclasses.replace(self, t=self.t[s], inputs=self.inputs[s], outputs=self.outputs[s])


def _where(path, row=None, col=None) -> str:
    return str(path) + ("" if row is None else f", row {row}") + ("" if col is None else f", column '{col}'")


def read_recording(path, input_names, output_names, *, min_samples: int = 2) -> Recording:
    """Read and validate a CSV recording; see the module docstring for the contract."""
    input_names, output_names = tuple(input_names), tuple(output_names)
    try:
        with open(path, encoding="utf-8-sig", newline="") as f:
            text = f.read()
    except FileNotFoundError:
        raise RecordingError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise RecordingError(f"{path}: cannot read file ({e})") from None

    reader = csv.reader(io.StringIO(text))
    try:
        rows = list(reader)
    except csv.Error as e:
        raise RecordingError(f"{_where(path, reader.line_num)}: malformed CSV ({e})") from None
    while rows and not any(c.strip() for c in rows[-1]):  # trailing blank lines
        rows.pop()
    if not rows:
        raise RecordingError(f"{path}: file is empty")

    def fail(i, col, msg):
        """Raise for data row ``i`` (0-based), numbered as its line in the file (header = 1)."""
        reader = csv.reader(io.StringIO(text))  # count physical lines: a quoted cell may span several
        for _ in range(i + 1):
            next(reader)
        raise RecordingError(f"{_where(path, reader.line_num + 1, col)}: {msg}")

    header = [h.strip() for h in rows[0]]
    body = rows[1:]
    if not header or header[0] != "t":
        where = f"'t' is column {header.index('t') + 1}" if "t" in header else "there is no 't' column"
        raise RecordingError(f"{_where(path, 1, 't')}: the first column must be time 't' in seconds; "
                             f"{where} (columns found: {', '.join(header)})")
    seen = {}
    for j, h in enumerate(header):
        if h in seen:
            raise RecordingError(f"{_where(path, 1, h)}: duplicate column name "
                                 f"(columns {seen[h] + 1} and {j + 1})")
        seen[h] = j
    missing = [n for n in input_names + output_names if n not in seen]
    if missing:
        raise RecordingError(f"{path}: missing required column(s) {', '.join(repr(m) for m in missing)} "
                             f"(columns found: {', '.join(header)})")

    ncol = len(header)
    for i, r in enumerate(body):
        if len(r) != ncol:
            fail(i, None, f"expected {ncol} fields (as in the header), found {len(r)}")

    try:  # fast path: plain numbers, empty cells as NaN
        data = np.array([[float(c or "nan") for c in r] for r in body], dtype=float).reshape(len(body), ncol)
    except ValueError:  # slow path: tolerate blank cells, locate the bad one
        data = np.empty((len(body), ncol))
        for i, r in enumerate(body):
            for j, c in enumerate(r):
                try:
                    data[i, j] = float(c.strip() or "nan")
                except ValueError:
                    fail(i, header[j], f"{c!r} is not a number")

    def first_bad(mask):
        return int(np.argmax(mask)) if mask.any() else None

    for name in ("t",) + input_names:
        j = seen[name]
        i = first_bad(~np.isfinite(data[:, j]))
        if i is not None:
            what = "time must be a finite number" if name == "t" else "inputs must be present"
            fail(i, name, f"{body[i][j].strip()!r}: {what} in every row")
    for name in output_names:
        j = seen[name]
        i = first_bad(np.isinf(data[:, j]))
        if i is not None:
            fail(i, name, f"{body[i][j].strip()!r}: outputs must be finite (leave the cell empty if not measured)")

    t = data[:, 0]
    i = first_bad(np.diff(t) <= 0)
    if i is not None:
        now, before = body[i + 1][0].strip(), body[i][0].strip()
        fail(i + 1, "t", f"time must be strictly increasing: {now} follows {before} (row above)")
    if len(body) < min_samples:
        raise RecordingError(f"{path}: {len(body)} data row(s), at least {min_samples} needed")

    return Recording(
        path=str(path),
        t=t.copy(),
        inputs=data[:, [seen[n] for n in input_names]],
        outputs=data[:, [seen[n] for n in output_names]],
        input_names=input_names,
        output_names=output_names,
    )


def write_recording(path, t, inputs: dict, outputs: dict, extra: dict | None = None) -> None:
    """Write a recording readable by :func:`read_recording`; NaN outputs become empty cells."""
    columns = {"t": t}
    for group in (inputs, outputs, extra or {}):
        for name, values in group.items():
            if name in columns:
                raise ValueError(f"duplicate column name {name!r}")
            columns[name] = values
    write_table(path, columns)


def write_table(path, columns: dict) -> None:
    """Write equal-length 1-D columns as CSV: header, then rows in '%.17g' (exact), NaN as empty."""
    names = list(columns)
    cols = [np.asarray(v, dtype=float) for v in columns.values()]
    for name, c in zip(names, cols):
        if c.ndim != 1 or len(c) != len(cols[0]):
            raise ValueError(f"column {name!r}: expected a 1-D array of length {len(cols[0])}, got shape {c.shape}")
    cells = [["" if x != x else "%.17g" % x for x in c.tolist()] for c in cols]
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w", encoding="utf-8", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(names)
        w.writerows(zip(*cells))
