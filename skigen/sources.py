"""Readers: a CSV, Parquet or PX4 ULog file, or a pandas DataFrame, as time-stamped samples.

Every reader returns :class:`Samples`: one or more groups of rows sharing a time
stamp (a CSV file is one group; a ULog file has a group per topic instance),
with only the columns the model uses, as float arrays (NaN = no sample).
Columns the model does not use are never parsed. Number parsing is strict
(ASCII decimal only: no ``1_0``, no ``0x10``, no non-ASCII digits); an empty
cell, ``nan``, ``NaN`` or ``N/A`` means "no sample". A CSV time column may hold
ISO-8601 time stamps instead (seconds since 1970, as a datetime column). Anything
malformed raises :class:`RecordingError` naming the file, row and column, its
content quoted :func:`printable`.
"""
from __future__ import annotations

import contextlib
import csv
import io
import itertools
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .recording import RecordingError

__all__ = ["Group", "Samples", "read_samples", "stream_csv", "CsvStream", "NotStreamable", "TIME_NAMES", "MISSING",
           "parse_number", "is_csv", "printable"]

TIME_NAMES = ("t", "time", "timestamp")           # looked for (case-insensitive) when no --time is given
MISSING = ("", "nan", "NaN", "N/A")               # cells that mean "no sample"
FLOAT_MAX = float(np.finfo(np.float32).max)
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*(?:[eE][+-]?\d+)?|\.\d+(?:[eE][+-]?\d+)?|inf|infinity)",
                     re.ASCII | re.IGNORECASE)
_ISO_STAMP = re.compile(r"\d{4}-\d{2}-\d{2}[T ]\d", re.ASCII)    # an ISO-8601 date and time
_ULOG_COLUMN = re.compile(r"(?P<topic>\w+)(?::(?P<instance>\d+))?\.(?P<field>\w+(?:\[\d+\])?(?:\.\w+(?:\[\d+\])?)*)$",
                          re.ASCII)     # a nested field as pyulog flattens it: esc_status.esc[0].esc_rpm


def parse_number(cell: str) -> float:
    """A strict decimal number; NaN for the missing spellings; ValueError otherwise."""
    c = cell.strip()
    if c in MISSING:
        return float("nan")
    if not _NUMBER.fullmatch(c):
        raise ValueError(f"{cell!r} is not a number")
    return float(c)


def printable(text, limit: int = 80) -> str:
    """``text`` for a message: non-printable characters escaped (``\\x00``), cut to ``limit`` characters."""
    text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(text))
    return text if len(text) <= limit else text[:limit - 1] + "…"


def _found(header) -> str:
    """The columns found, for a message: each printable, at most 30 of them."""
    more = f", … ({len(header)} columns)" if len(header) > 30 else ""
    return ", ".join(printable(h, 40) for h in header[:30]) + more


@dataclass
class Group:
    """Rows that share a time stamp: ``t`` (N,) in the source's unit, or seconds if ``seconds``."""

    t: np.ndarray
    values: dict[str, np.ndarray]            # model name -> (N,) float, NaN = no sample
    where: Callable[[int], str]              # "row 17" for index i, for messages
    seconds: bool = False                    # t is already in seconds (ULog, datetimes)


@dataclass
class Samples:
    """What a reader found: the groups, and how each model name was read."""

    source: str                              # file path or "DataFrame"
    groups: list[Group]
    columns: dict[str, str]                  # model name -> column it was read from
    time_column: str | None
    notes: list[str] = field(default_factory=list)


def _where(source, row=None, col=None) -> str:
    return str(source) + ("" if row is None else f", {row}") + ("" if col is None else f", column '{col}'")


def _columns_for(names, mapping) -> dict[str, str]:
    """Model name -> column, from ``mapping`` (name -> column) or the name itself."""
    mapping = dict(mapping or {})
    unknown = [k for k in mapping if k not in names]
    if unknown:
        raise RecordingError(f"--map (columns= in Python) names {', '.join(repr(k) for k in unknown)}, which the model does not "
                             f"have (inputs and outputs: {', '.join(names)})")
    columns = {n: mapping.get(n, n) for n in names}
    readers = {}
    for n, c in columns.items():
        readers.setdefault(c, []).append(n)
    if shared := {c: ns for c, ns in readers.items() if len(ns) > 1}:
        c, ns = next(iter(shared.items()))
        raise RecordingError(f"column '{c}' would be read as {' and '.join(repr(n) for n in ns)} (--map / columns=): "
                             f"each input and output of the model reads a column of its own")
    return columns


def _time_like(header, used=()) -> list[str]:
    """The columns named like time (TIME_NAMES, any case) that the model does not use, in the order
    of TIME_NAMES, each name's exact spelling first: an input named 'T' (a thrust) is no clock."""
    found = [h for h in header if h.lower() in TIME_NAMES and h not in set(used)]
    return sorted(found, key=lambda h: (TIME_NAMES.index(h.lower()), h != h.lower(), header.index(h)))


def _time_column(header, time, source, used=()) -> str:
    """The time column: ``time`` if given, else the first of :func:`_time_like`."""
    if time is not None:
        if time not in header:
            raise RecordingError(f"{source}: no time column '{time}' (columns found: {_found(header)})")
        return time
    if like := _time_like(header, used):
        return like[0]
    raise RecordingError(f"{source}: no time column: expected one named {', '.join(TIME_NAMES)} or given with "
                         f"--time COLUMN (time=COLUMN in Python; columns found: {_found(header)})")


def _require(columns: dict, header, source, time_col) -> None:
    missing = [f"'{c}'" + (f" (for '{n}')" if c != n else "") for n, c in columns.items() if c not in header]
    if missing:
        raise RecordingError(f"{source}: missing required column(s) {', '.join(missing)} "
                             f"(columns found: {_found(header)}); map others with --map NAME=COLUMN (in Python, "
                             f"columns={{NAME: COLUMN}})")
    if time_col in columns.values():
        raise RecordingError(f"{source}: column '{time_col}' is the time column and cannot be a model "
                             f"input or output")


def _check_advances(g: Group, source, time_col, header) -> None:
    """An error when every time stamp of a recording is the same (a constant column read as time)."""
    if len(g.t) > 1 and np.all(g.t == g.t[0]):
        others = [h for h in header if h.lower() in TIME_NAMES and h != time_col]
        raise RecordingError(f"{source}, column '{time_col}': every time stamp is {g.t[0]:.15g} ({len(g.t)} rows): "
                             f"time does not advance" + (f"; column '{others[0]}' looks like time too "
                                                         f"(--time {others[0]})" if others else ""))


def check_group(g: Group, columns: dict, time_col: str, real: str, fail) -> None:
    """Finite, non-decreasing time; finite values, within float range if ``real == 'float'``.

    ``fail(i, column, message)`` raises for sample ``i``.
    """
    bad = ~np.isfinite(g.t)
    if bad.any():
        i = int(np.argmax(bad))
        fail(i, time_col, f"{g.t[i]:g}: time must be a finite number in every row")
    back = np.diff(g.t) < 0
    if back.any():
        i = int(np.argmax(back)) + 1
        fail(i, time_col, f"time goes backwards: {float(g.t[i])!r} follows {float(g.t[i - 1])!r} (the sample before)")
    for name, v in g.values.items():
        inf = np.isinf(v)
        if inf.any():
            i = int(np.argmax(inf))
            fail(i, columns[name], f"{v[i]:g}: values must be finite (an inf, or a number beyond "
                                   f"±{np.finfo(float).max:.4g} written; leave the cell empty if not measured)")
        if real == "float":
            big = np.abs(v) > FLOAT_MAX
            if big.any():
                i = int(np.argmax(big))
                fail(i, columns[name], f"{v[i]:.17g} overflows the C float (largest {FLOAT_MAX:.7g}); "
                                       f"run with --real double")


# --------------------------------------------------------------------------- CSV

class _Retry(Exception):
    """The fast CSV path met something the exact path must report."""


def _csv_header(path) -> list[str]:
    try:
        with open(path, encoding="utf-8-sig", newline="") as f:
            first = next(csv.reader(f), None)
            second = f.readline()
    except FileNotFoundError:
        raise RecordingError(f"{path}: file not found") from None
    except UnicodeDecodeError:
        raise RecordingError(_undecodable(path)) from None
    except (OSError, csv.Error) as e:
        raise RecordingError(f"{path}: cannot read file ({e})") from None
    if not first or not any(c.strip() for c in first):
        raise RecordingError(f"{path}: file is empty")
    if any("\0" in c for c in first):
        raise RecordingError(f"{path}: not a CSV file: it holds binary data (it begins "
                             f"'{printable(','.join(first), 40)}')")
    header = [h.strip() for h in first]
    if len(header) == 1 and (sep := next((c for c in ";\t|" if c in header[0]), None)):
        comma = any(re.fullmatch(r"[+-]?\d+,\d+", c.strip()) for c in second.split(sep))
        raise RecordingError(f"{_where(path, 'row 1')}: one column '{printable(header[0])}': the file seems "
                             f"separated by {'tabs' if sep == chr(9) else repr(sep)}, and skigen reads comma-"
                             f"separated values. Convert it (pandas.read_csv(path, sep={sep!r}"
                             f"{', decimal=' + repr(',') if comma else ''}).to_csv(new_path, index=False)) "
                             f"or pass a DataFrame")
    seen = {}
    for j, h in enumerate(header):
        if h in seen:
            raise RecordingError(f"{_where(path, 'row 1', printable(h))}: duplicate column name (columns "
                                 f"{seen[h] + 1} and {j + 1})")
        seen[h] = j
    return header


def _iso_time(path, header, time_col) -> bool:
    """True when the time column's first value is an ISO-8601 date and time, not a number."""
    j = header.index(time_col)
    try:
        with open(path, encoding="utf-8-sig", newline="") as f:
            for r in itertools.islice(csv.reader(f), 1, None):
                cell = r[j].strip() if len(r) > j else ""
                if cell not in MISSING:
                    return bool(_ISO_STAMP.match(cell))
    except (OSError, UnicodeDecodeError, csv.Error):
        pass                                  # the exact reader names it
    return False


def _iso_seconds(cells, fail=None) -> np.ndarray:
    """Seconds since 1970 of ISO-8601 time stamps (UTC unless they carry a zone), NaN for a missing
    cell; ``fail(i, message)`` for the first cell that is neither (else NaN there too)."""
    import pandas as pd

    text = pd.Series(cells, dtype=object).fillna("").astype(str).str.strip()
    missing = text.isin(MISSING).to_numpy()
    stamps = pd.to_datetime(text.where(~missing), format="ISO8601", utc=True, errors="coerce")
    bad = stamps.isna().to_numpy() & ~missing
    if bad.any() and fail is not None:
        i = int(np.argmax(bad))
        fail(i, f"'{printable(text[i])}' is not an ISO-8601 time stamp (the column's first value is one)")
    return _column_values(None, None, stamps, None)[0]


BLOCK_SIZE = 4 << 20          # bytes per block of pyarrow's streaming CSV reader (whole-file reading)
STREAM_BLOCK_SIZE = 1 << 20   # the same when streaming: pyarrow reads up to 32 blocks ahead


def _open_csv(path, header, wanted, block_size=BLOCK_SIZE, text=None):
    """pyarrow's streaming reader of the used columns, as float64 (NaN for the missing spellings);
    the column ``text`` (ISO time stamps) as strings (None for the missing spellings)."""
    import pyarrow as pa
    import pyarrow.csv as pc

    return pc.open_csv(
        path, read_options=pc.ReadOptions(column_names=header, skip_rows=1, block_size=block_size,
                                          use_threads=True),
        parse_options=pc.ParseOptions(ignore_empty_lines=False),
        convert_options=pc.ConvertOptions(include_columns=wanted, null_values=list(MISSING),
                                          column_types={c: pa.string() if c == text else pa.float64()
                                                        for c in wanted},
                                          strings_can_be_null=True, quoted_strings_can_be_null=True))


def _block_values(batch, wanted, iso_col) -> dict:
    """A pyarrow batch's used columns as float arrays (ISO time stamps as seconds since 1970)."""
    return {c: _iso_seconds(batch.column(c).to_numpy(zero_copy_only=False)) if c == iso_col
            else batch.column(c).to_numpy(zero_copy_only=False) for c in wanted}


def _csv_fast(path, header, wanted, columns, time_col, real, iso) -> Group:
    """pyarrow's streaming reader: blocks of 4 MB, only the used columns. Raises _Retry on anything odd."""
    import pyarrow as pa

    try:
        reader = _open_csv(path, header, wanted, text=time_col if iso else None)
        chunks = {c: [] for c in wanted}
        for batch in reader:
            for c, v in _block_values(batch, wanted, time_col if iso else None).items():
                chunks[c].append(v)
    except (pa.ArrowInvalid, pa.ArrowTypeError):
        raise _Retry from None
    data = {c: np.concatenate(chunks[c]) if chunks[c] else np.zeros(0) for c in wanted}
    g = Group(data[time_col], {n: data[c] for n, c in columns.items()}, lambda i: f"row {i + 2}", iso)

    def retry(i, col, msg):
        raise _Retry
    check_group(g, columns, time_col, real, retry)
    return g


def _csv_exact(path, header, wanted, columns, time_col, real, iso) -> Group:
    """The csv module, cell by cell: slow, and names the exact line of any problem."""
    idx = {c: header.index(c) for c in wanted}
    rows, lines, blank_from = {c: [] for c in wanted}, [], None
    with open(path, encoding="utf-8-sig", newline="") as f:
        reader = csv.reader(f)
        next(reader)
        try:
            for r in reader:
                line = reader.line_num
                if not any(c.strip() for c in r):
                    blank_from = blank_from or line
                    continue
                if blank_from is not None:
                    raise RecordingError(f"{_where(path, f'row {blank_from}')}: expected {len(header)} fields "
                                         f"(as in the header), found 0")
                if len(r) != len(header):
                    raise RecordingError(f"{_where(path, f'row {line}')}: expected {len(header)} fields "
                                         f"(as in the header), found {len(r)}")
                for c in wanted:
                    try:
                        rows[c].append(r[idx[c]] if iso and c == time_col else parse_number(r[idx[c]]))
                    except ValueError as e:
                        raise RecordingError(f"{_where(path, f'row {line}', c)}: {e}") from None
                lines.append(line)
        except csv.Error as e:
            raise RecordingError(f"{_where(path, f'row {reader.line_num}')}: malformed CSV ({e})") from None
        except UnicodeDecodeError:
            raise RecordingError(_undecodable(path, header)) from None

    def fail(i, col, msg):
        raise RecordingError(f"{_where(path, f'row {lines[i]}', col)}: {msg}")
    data = {c: _iso_seconds(v, lambda i, msg: fail(i, c, msg)) if iso and c == time_col else np.array(v, dtype=float)
            for c, v in rows.items()}
    g = Group(data[time_col], {n: data[c] for n, c in columns.items()}, lambda i: f"row {lines[i]}", iso)
    check_group(g, columns, time_col, real, fail)
    return g


def _undecodable(path, header=()) -> str:
    """Where a file stops being UTF-8 text: its row, column and bytes (a CSV saved in Latin-1, a
    corrupt block)."""
    data = Path(path).read_bytes()
    try:
        data.decode("utf-8")
        return f"{path}: not UTF-8 text"
    except UnicodeDecodeError as e:
        at = e.start
    row, row_start = data.count(b"\n", 0, at) + 1, data.rfind(b"\n", 0, at) + 1
    if not header and row > 1:                  # the header is text: its names
        header = [h.strip() for h in data[:data.find(b"\n")].decode("utf-8-sig").split(",")]
    j = data.count(b",", row_start, at)
    where = _where(path, f"row {row}", header[j] if j < len(header) else None)
    return (f"{where}: byte {at} ({data[at:at + 4].hex(' ')}) is not UTF-8 text: a corrupt block, or a file "
            f"saved in another encoding (re-save it as UTF-8, e.g. pandas.read_csv(path, encoding='latin-1')"
            f".to_csv(new_path, index=False))")


def _read_csv(path, names, mapping, time, real) -> Samples:
    header = _csv_header(path)
    columns = _columns_for(names, mapping)
    time_col = _time_column(header, time, path, columns.values())
    _require(columns, header, path, time_col)
    wanted = list(dict.fromkeys([time_col, *columns.values()]))
    iso = _iso_time(path, header, time_col)
    try:
        g = _csv_fast(path, header, wanted, columns, time_col, real, iso)
    except _Retry:
        g = _csv_exact(path, header, wanted, columns, time_col, real, iso)
    _check_advances(g, path, time_col, header)
    return Samples(str(path), [g], columns, time_col)


class NotStreamable(Exception):
    """The streamed path met something only the whole-file path decides (a malformed row, time going
    backwards, a grid it cannot bound): read the file whole instead, which gives the verdict."""


@dataclass
class CsvStream:
    """A CSV file's used columns as a sequence of :class:`Group` blocks (see :func:`stream_csv`)."""

    source: str
    columns: dict[str, str]
    time_column: str
    real: str
    header: list[str]
    block_size: int = STREAM_BLOCK_SIZE
    rows: int | None = None              # re-cut the blocks into pieces of at most this many rows (tests)
    notes: list[str] = field(default_factory=list)
    iso: bool = False                    # the time column holds ISO-8601 stamps (read as seconds since 1970)
    def stamps(self) -> tuple[float, float] | None:
        """The file's first and last time stamps as written (their unit: the file's), read from its
        first and last rows; None where they do not read as numbers (ISO stamps, a ragged end)."""
        j = self.header.index(self.time_column)
        try:
            with open(self.source, "rb") as f:
                head = f.read(1 << 16).decode("utf-8", "replace").splitlines()
                f.seek(max(os.path.getsize(self.source) - (1 << 16), 0))
                tail = f.read().decode("utf-8", "replace").splitlines()
            rows = [next(csv.reader([line])) for line in (head[1:2] + [x for x in tail if x.strip()][-1:])]
            first, last = (float(r[j]) for r in rows)
        except (OSError, ValueError, IndexError, StopIteration):
            return None
        return (first, last) if np.isfinite([first, last]).all() and last > first else None

    def __iter__(self):
        import pyarrow as pa

        wanted = list(dict.fromkeys([self.time_column, *self.columns.values()]))
        first, last = 0, None            # data rows before this block; the last time stamp before it

        def retry(i, col, msg):
            raise NotStreamable(msg)
        try:
            reader = _open_csv(self.source, self.header, wanted, self.block_size,
                               text=self.time_column if self.iso else None)
            for batch in reader:
                data = _block_values(batch, wanted, self.time_column if self.iso else None)
                step = self.rows or max(len(data[self.time_column]), 1)
                for a in range(0, len(data[self.time_column]), step):
                    t = data[self.time_column][a:a + step]
                    g = Group(t, {n: data[c][a:a + step] for n, c in self.columns.items()},
                              lambda i, o=first + a: f"row {o + i + 2}", self.iso)
                    check_group(g, self.columns, self.time_column, self.real, retry)
                    if last is not None and t[0] < last:
                        raise NotStreamable("time goes backwards between blocks")
                    last = t[-1]
                    yield g
                first += len(data[self.time_column])
        except (pa.ArrowInvalid, pa.ArrowTypeError) as e:
            raise NotStreamable(str(e)) from None


def is_csv(source) -> bool:
    """True when ``source`` is a path the CSV reader would read (not Parquet, ULog or a DataFrame)."""
    return not (hasattr(source, "columns") and hasattr(source, "index")) and _kind(Path(source)) == "csv"


def stream_csv(path, names, *, columns=None, time=None, real: str = "double", block_size: int = STREAM_BLOCK_SIZE,
               rows: int | None = None) -> CsvStream:
    """The CSV file ``path`` for the model ``names`` as blocks of rows, read as they are used.

    The header, the time column and the mapped columns are checked now, as :func:`read_samples`
    does. Iterating yields a :class:`Group` per block (``block_size`` bytes of file, cut into pieces
    of at most ``rows`` rows if given). pyarrow reads up to 32 blocks ahead in a thread, so memory
    holds at most about 32 ``block_size`` of the file, however long it is. Iterating raises
    :class:`NotStreamable` on anything the exact whole-file reader must name (a malformed cell or
    row, time going backwards, a non-finite value).
    """
    header = _csv_header(path)
    cols = _columns_for(list(names), columns)
    time_col = _time_column(header, time, path, cols.values())
    _require(cols, header, path, time_col)
    return CsvStream(str(path), cols, time_col, real, header, block_size, rows,
                     iso=_iso_time(path, header, time_col))


# --------------------------------------------------------------------------- Parquet and DataFrame

def _fail_at(source, where, name, message):
    raise RecordingError(f"{_where(source, where, name)}: {message}")


def _column_values(source, name, values, where, time: bool = False) -> tuple[np.ndarray, bool]:
    """(float array, is_datetime) of one column: numbers, datetimes (as seconds) or strictly parsed
    text; ``time``: ISO-8601 text read as seconds, as in a CSV's time column."""
    import pandas as pd

    s = pd.Series(values)
    if pd.api.types.is_datetime64_any_dtype(s):
        s = s.dt.tz_convert("UTC").dt.tz_localize(None) if getattr(s.dt, "tz", None) is not None else s
        ns = s.to_numpy(dtype="datetime64[ns]").astype("int64").astype(float)
        return np.where(s.isna().to_numpy(), np.nan, ns * 1e-9), True
    if pd.api.types.is_timedelta64_dtype(s):
        return s.dt.total_seconds().to_numpy(dtype=float), True
    if pd.api.types.is_complex_dtype(s):
        raise RecordingError(f"{_where(source, None, name)}: complex values; give the real part (or the magnitude)")
    if pd.api.types.is_bool_dtype(s) or pd.api.types.is_numeric_dtype(s):
        return s.to_numpy(dtype=float, na_value=np.nan), False
    first = s.dropna()
    if time and len(first) and isinstance(first.iloc[0], str) and _ISO_STAMP.match(first.iloc[0].strip()):
        return _iso_seconds(s.to_numpy(), lambda i, m: _fail_at(source, where(i), name, m)), True
    out = np.empty(len(s))
    for i, v in enumerate(s.tolist()):
        try:
            out[i] = np.nan if v is None else float(v) if isinstance(v, (int, float)) else parse_number(str(v))
        except ValueError as e:
            raise RecordingError(f"{_where(source, where(i), name)}: {e}") from None
    return out, False


def _frame_group(source, frame, columns, time_col, where, real) -> Group:
    vals, seconds = {}, False
    for c in dict.fromkeys([time_col, *columns.values()]):
        vals[c], dt = _column_values(source, c, frame[c], where, time=c == time_col)
        seconds = seconds or (dt and c == time_col)
    g = Group(vals[time_col], {n: vals[c] for n, c in columns.items()}, where, seconds)

    def fail(i, col, msg):
        raise RecordingError(f"{_where(source, where(i), col)}: {msg}")
    check_group(g, columns, time_col, real, fail)
    return g


def _read_parquet(path, names, mapping, time, real) -> Samples:
    """A Parquet file's used columns; a pandas index stored in it (``df.to_parquet``) is read as
    :func:`_read_frame` reads a DataFrame's index."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        pf = pq.ParquetFile(path)
    except (OSError, pa.ArrowInvalid) as e:
        raise RecordingError(f"{path}: cannot read Parquet file ({e})") from None
    meta = pf.schema_arrow.pandas_metadata or {}
    stored = [c for c in meta.get("index_columns", []) if isinstance(c, str)]   # a RangeIndex is not stored
    header = [n for n in pf.schema_arrow.names if n not in stored]
    index = next((str(c["name"] or "index") for c in meta.get("columns", []) if stored == [c.get("field_name")]),
                 None)
    columns = _columns_for(names, mapping)
    _require(columns, header, path, None)
    if time is not None and time != index:
        _time_column(header, time, path)
    keep = [h for h in header if h in columns.values() or h == time or h.lower() in TIME_NAMES]
    try:
        frame = pf.read(columns=keep, use_pandas_metadata=True).to_pandas()
    except (OSError, pa.ArrowInvalid) as e:
        raise RecordingError(f"{path}: cannot read Parquet file ({e})") from None
    return _read_frame(frame, names, mapping, time, real, str(path), header, lambda i: f"row {i + 1}")


def _read_frame(frame, names, mapping, time, real, source="DataFrame", header=None, where=None) -> Samples:
    """A DataFrame's columns; its index is the time when ``time`` names it, or when no ``time`` is
    given and no column is named like time. ``header``: the source's columns, when ``frame`` holds
    only those used."""
    import pandas as pd

    header = header or [str(c) for c in frame.columns]
    for j, h in enumerate(header):
        if h in header[:j]:
            raise RecordingError(f"{_where(source, None, printable(h))}: duplicate column name (columns "
                                 f"{header.index(h) + 1} and {j + 1})")
    columns = _columns_for(names, mapping)
    idx = frame.index
    index = str("index" if idx.name is None else idx.name)
    if (time is None and not _time_like(header, columns.values())) or (time == index and time not in header):
        if isinstance(idx, pd.RangeIndex) or not (pd.api.types.is_numeric_dtype(idx)
                                                  or pd.api.types.is_datetime64_any_dtype(idx)
                                                  or pd.api.types.is_timedelta64_dtype(idx)):
            mapped = [f"'{c}' is mapped to '{n}'" for n, c in columns.items() if c.lower() in TIME_NAMES]
            raise RecordingError(f"{source}: no time: give a column named {', '.join(TIME_NAMES)}, name one "
                                 f"with time=..., or use a numeric or datetime index (columns: {_found(header)})"
                                 + (f"; {', '.join(mapped)}, so it is not the time" if mapped else ""))
        time_col = index
        frame = frame.reset_index(names=[time_col]) if time_col not in frame.columns else frame.set_index(
            pd.RangeIndex(len(frame))).assign(**{time_col: idx.to_numpy()})
        header = [*header, time_col]
    else:
        time_col = _time_column(header, time, source, columns.values())
    _require(columns, header, source, time_col)
    labels = frame.index if where is None else None
    frame = frame.rename(columns=str)
    label = lambda v: v.item() if isinstance(v, np.generic) else v
    g = _frame_group(source, frame, columns, time_col,
                     where or (lambda i: f"row {i + 1} (index {label(labels[i])!r})"), real)
    _check_advances(g, source, time_col, header)
    return Samples(source, [g], columns, time_col)


# --------------------------------------------------------------------------- ULog

class _Watched:
    """A file for pyulog that notes a read cut short by the end of the file (pyulog stops there quietly)."""

    def __init__(self, path):
        self.file, self.cut = open(path, "rb"), False

    def read(self, n=-1):
        data = self.file.read(n)
        self.cut = self.cut or 0 < len(data) < n
        return data

    def seek(self, *args):
        return self.file.seek(*args)

    def tell(self):
        return self.file.tell()

    def close(self):
        self.file.close()


def _parse_ulog(path, topics=None):
    """(pyulog's ULog of ``topics``, a phrase saying where the file is truncated or corrupt, or
    None). pyulog's prints are kept off stdout (they go into the sentence)."""
    from pyulog import ULog

    f, said = _Watched(path), io.StringIO()
    try:
        with contextlib.redirect_stdout(said):
            log = ULog(f, topics)
    finally:
        f.close()
    if not f.cut and not log.file_corruption:
        return log, None
    stamps = [d.data["timestamp"][[0, -1]] for d in log.data_list if len(d.data.get("timestamp", ()))]
    last = max(s[1] for s in stamps) * 1e-6 if stamps else log.last_timestamp * 1e-6   # pyulog's can be the header's
    start = min([log.start_timestamp, *(s[0] for s in stamps)]) * 1e-6
    data = f"{last - start:.3f} s after its start (t = {last:.3f} s)" if last > start else None
    if f.cut:
        return log, (f"the log is truncated: it ends inside a message, at byte {Path(path).stat().st_size}; "
                     + (f"its data end {data}" if data else "it ends before any data"))
    said = said.getvalue().strip()
    return log, ("the log is corrupt" + (f" (pyulog: {printable(said.splitlines()[0])})" if said else "") + ": "
                 + (f"pyulog skipped damaged bytes; data around them may be missing; its data end {data}" if data
                    else "no data could be read"))


def _read_ulog(path, names, mapping, time, real) -> Samples:
    """PX4 ULog: COLUMN = ``topic.field``, ``topic.field[i]`` or ``topic:instance.field``; µs stamps.
    A truncated or corrupt file is read as far as pyulog can, with a note saying where it ends."""
    columns = _columns_for(names, mapping)
    specs = {}
    for n, c in columns.items():
        m = _ULOG_COLUMN.match(c)
        if not m:
            raise RecordingError(f"{path}: '{n}' reads column '{c}', which is not a ULog column: use "
                                 f"topic.field, topic.field[i], topic.field[i].subfield or topic:instance.field "
                                 f"(--map {n}=COLUMN, or columns= in Python)")
        specs[n] = (m["topic"], int(m["instance"] or 0), m["field"])
    try:
        log, damage = _parse_ulog(path, sorted({s[0] for s in specs.values()}))
    except FileNotFoundError:
        raise RecordingError(f"{path}: file not found") from None
    except Exception as e:  # pyulog raises plain exceptions for corrupt files
        raise RecordingError(f"{path}: cannot read ULog file ({type(e).__name__}: {e})") from None
    topics = {(d.name, d.multi_id): d for d in log.data_list}
    groups, notes = {}, [f"{path}: {damage}"] if damage else []
    for n, (topic, inst, fld) in specs.items():
        d = topics.get((topic, inst))
        if d is None:
            have = sorted({k[1] for k in topics if k[0] == topic})
            every = sorted({x.name for x in _parse_ulog(path)[0].data_list}) if not have else []
            raise RecordingError(
                f"{path}: '{n}' reads '{columns[n]}', but the log has no topic '{topic}'" +
                (f" instance {inst} (instances: {', '.join(map(str, have))})" if have else
                 f" (topics: {', '.join(every)})" if every else f" (no topic holds data{': ' if damage else ''}"
                                                                f"{damage or ''})"))
        if fld not in d.data:
            fields = [f for f in d.data if f != "timestamp"]
            raise RecordingError(f"{path}: '{n}' reads '{columns[n]}', but topic '{topic}' has no field '{fld}' "
                                 f"(fields: {', '.join(fields[:40])}"
                                 f"{', …' if len(fields) > 40 else ''})")
        key = (topic, inst)
        if key not in groups:
            label = topic if inst == 0 else f"{topic}:{inst}"
            stamp, said = _stamps(label, d.data, time == "timestamp_sample")
            notes += said
            groups[key] = Group(stamp * 1e-6, {},
                                lambda i, label=label: f"topic '{label}' message {i + 1}", seconds=True)
        groups[key].values[n] = np.asarray(d.data[fld], float)
    for g in groups.values():
        def fail(i, col, msg, g=g):
            raise RecordingError(f"{_where(path, g.where(i), col)}: {msg}")
        check_group(g, columns, "timestamp", real, fail)
    if time not in (None, "timestamp", "timestamp_sample"):
        notes.append(f"--time '{time}' ignored: every ULog topic has its own 'timestamp' (µs, when published) "
                     f"and many a 'timestamp_sample' (when sampled), which --time timestamp_sample uses")
    return Samples(str(path), list(groups.values()), columns, "timestamp", notes)


SAMPLE_LAG = 1e3      # µs: a topic sampled this much before it is published, on average, gets a note
MOST_LAG = 1e6        # µs: a timestamp_sample further before its timestamp is not a sampling time (0, unset)


def _stamps(label: str, data: dict, sampled: bool) -> tuple[np.ndarray, list[str]]:
    """One topic's stamps (µs): its timestamp_sample where asked for (``sampled``) and a sampling
    time on every message (at most MOST_LAG before the timestamp), else its timestamp; and notes
    saying which, or what timestamp_sample would do."""
    published = np.asarray(data["timestamp"], float)
    if "timestamp_sample" not in data:
        return published, [f"topic '{label}' has no timestamp_sample: its timestamp is used"] if sampled else []
    at = np.asarray(data["timestamp_sample"], float)
    lag = published - at
    if not np.all((lag >= 0) & (lag <= MOST_LAG)):
        bad = int(np.sum((lag < 0) | (lag > MOST_LAG)))
        return published, [f"topic '{label}': timestamp_sample is not a sampling time on {bad} of {len(at)} messages "
                           f"(0, or more than {MOST_LAG / 1e6:g} s before or after its timestamp): its timestamp is "
                           f"used"] if sampled else []
    if sampled:
        return at, []
    mean = float(np.mean(lag))
    return published, [f"topic '{label}' is published {mean / 1e3:.3g} ms after it is sampled, on average: its "
                       f"readings are placed at their timestamp (publication); --time timestamp_sample places them "
                       f"when sampled"] if mean >= SAMPLE_LAG else []


# --------------------------------------------------------------------------- dispatch

def _kind(path: Path) -> str:
    try:
        with open(path, "rb") as f:
            magic = f.read(7)
    except FileNotFoundError:
        raise RecordingError(f"{path}: file not found") from None
    except OSError as e:
        raise RecordingError(f"{path}: cannot read file ({e})") from None
    if magic == b"ULog\x01\x12\x35" or path.suffix.lower() == ".ulg":
        return "ulog"
    if magic.startswith(b"PAR1") or path.suffix.lower() in (".parquet", ".pq"):
        return "parquet"
    return "csv"


def read_samples(source, names, *, columns=None, time=None, real: str = "double") -> Samples:
    """The samples of the model ``names`` (inputs then outputs) in ``source``: a path or a DataFrame.

    columns: model name -> column (default the name itself). time: the time column
    (default the first of t, time, timestamp). real: 'float' also rejects values beyond
    the C float range.
    """
    names = list(names)
    if hasattr(source, "columns") and hasattr(source, "index"):
        return _read_frame(source, names, columns, time, real)
    path = Path(source)
    reader = {"csv": _read_csv, "parquet": _read_parquet, "ulog": _read_ulog}[_kind(path)]
    return reader(source, names, columns, time, real)
