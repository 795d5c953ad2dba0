import io

import numpy as np
import pytest

from skigen.progress import progress
from skigen.recording import Recording, RecordingError, read_recording, write_recording, write_table

INS, OUTS = ("delta",), ("p", "phi")


def _csv(tmp_path, text, name="run.csv", **open_kw):
    path = tmp_path / name
    path.write_text(text, **open_kw)
    return str(path)


GOOD = "t,delta,p,phi\n0,1,2,3\n0.1,1.5,,nan\n0.2,2,4,NaN\n"


def test_roundtrip_exact_with_nan_outputs_and_extra(tmp_path):
    rng = np.random.default_rng(0)
    n = 50
    t = np.cumsum(rng.uniform(0.001, 0.1, n))
    u = rng.normal(size=n) * 1e-7
    p, phi = rng.normal(size=n), rng.normal(size=n) * 1e5
    p[[3, 10]] = np.nan
    path = str(tmp_path / "sub" / "rt.csv")
    write_recording(path, t, {"delta": u}, {"p": p, "phi": phi}, extra={"note": np.arange(n)})
    lines = open(path).read().splitlines()
    assert lines[0] == "t,delta,p,phi,note"
    assert lines[4].split(",")[2] == ""  # NaN written as an empty cell
    rec = read_recording(path, INS, OUTS)
    assert isinstance(rec, Recording) and rec.path == path
    assert rec.input_names == INS and rec.output_names == OUTS
    assert np.array_equal(rec.t, t)
    assert np.array_equal(rec.inputs[:, 0], u)
    assert np.array_equal(rec.outputs, np.column_stack([p, phi]), equal_nan=True)
    assert rec.inputs.shape == (n, 1) and rec.outputs.shape == (n, 2)
    assert rec.dt == pytest.approx(np.median(np.diff(t)))
    part = rec.slice(5, 9)
    assert len(part) == 4 and np.array_equal(part.t, t[5:9]) and part.outputs.shape == (4, 2)
    with pytest.raises(ValueError):
        rec.t[0] = 1.0  # read-only


def test_nan_spellings_and_column_order(tmp_path):
    rec = read_recording(_csv(tmp_path, GOOD), INS, ("phi", "p"))
    assert np.array_equal(rec.outputs, [[3, 2], [np.nan, np.nan], [np.nan, 4]], equal_nan=True)
    assert np.array_equal(rec.inputs[:, 0], [1, 1.5, 2])


def test_crlf_bom_whitespace_trailing_blank_line(tmp_path):
    text = "\ufefft, delta ,p,phi \r\n0,1 ,2, 3\r\n0.1,1.5,  ,nan \r\n0.2,2,4,NaN\r\n\r\n"
    path = _csv(tmp_path, text, encoding="utf-8", newline="")
    rec = read_recording(path, INS, OUTS)
    assert np.array_equal(rec.t, [0, 0.1, 0.2])
    assert np.array_equal(rec.outputs, [[2, 3], [np.nan, np.nan], [4, np.nan]], equal_nan=True)


def test_write_table(tmp_path):
    path = str(tmp_path / "res.csv")
    write_table(path, {"a": [0.1, np.nan], "b": np.array([1, 2])})
    assert open(path).read() == "a,b\n0.1,1\n,2\n"            # shortest exact form; NaN empty
    with pytest.raises(ValueError):
        write_table(path, {"a": [1, 2], "b": [1]})
    with pytest.raises(ValueError):
        write_recording(path, [0, 1], {"p": [0, 1]}, {"p": [0, 1]})


def _error(path, ins=INS, outs=OUTS, **kw):
    with pytest.raises(RecordingError) as e:
        read_recording(path, ins, outs, **kw)
    return str(e.value)


@pytest.mark.parametrize("text, row, col, extra", [
    ("t,delta,p,phi\n0,1,2,3\n0.1,abc,2,3\n", 3, "delta", "'abc' is not a number"),
    ("t,delta,p,phi\n0,1,2,3\n0.1,,2,3\n", 3, "delta", "inputs must be present in every row"),
    ("t,delta,p,phi\n0,1,2,3\n0.1,1,2,3\n0.2,nan,2,3\n", 4, "delta", "inputs must be present in every row"),
    ("t,delta,p,phi\n0,1,2,3\n0.1,inf,2,3\n", 3, "delta", "inf: values must be finite"),
    ("t,delta,p,phi\n0,1,2,3\n0.1,1e400,2,3\n", 3, "delta", "a number beyond ±1.798e+308 written"),
    ("t,delta,p,phi\n0,1,2,3\n,1,2,3\n", 3, "t", "'t'"),
    ("t,delta,p,phi\n0,1,2,3\nnan,1,2,3\n", 3, "t", "finite"),
    ("t,delta,p,phi\n0,1,2,3\n0.1,1,2,-inf\n", 3, "phi", "-inf: values must be finite"),
    ("t,delta,p,phi\n0,1,2,3\n0.1,1_0,2,3\n", 3, "delta", "'1_0' is not a number"),
    ("t,delta,p,phi\n0,1,2,3\n0.1,\uff11,2,3\n", 3, "delta", "is not a number"),      # a full-width digit
    ("t,delta,p,phi\n0,1,2,3\n0.1,0x10,2,3\n", 3, "delta", "'0x10' is not a number"),
    ("t,delta,p,phi\n0,1,2,3\n0.5,1,2,3\n0.5,1,2,3\n", 4, "t", "0.5 follows 0.5"),
    ("t,delta,p,phi\n0,1,2,3\n0.5,1,2,3\n0.25,1,2,3\n", 4, "t", "0.25 follows 0.5"),
    ("t,delta,p,phi\n0,1,2,3\n0.39,1,2,3\n0.1,1,2,3\n", 4, "t", "time goes backwards: 0.1 follows 0.39 (the"),
    ("t,delta,p,phi\n0,1,2,3\n0.1,1,2,3\n0.10000000000000002,1,2,3\n0.10000000000000001,1,2,3\n", 5, "t",
     "0.1 follows 0.10000000000000002"),                     # the shortest digits that tell them apart
    ("t,delta,p,phi\n0,1,2,3\n1e308,1,2,3\n0.25,1,2,3\n", 4, "t", "backwards"),
    ("t,delta,p,phi\n0,1,2,3\n0.1,1,2\n", 3, None, "found 3"),
    ("t,delta,p,phi\n0,1,2,3\n0.1,1,2,3,4\n", 3, None, "found 5"),
    ("t,delta,p,phi\n0,1,2,3\n\n0.1,1,2,3\n", 3, None, "found 0"),
    ("t,delta,p,phi\n0,1,2,\"3\n\"\n0.1,x,2,3\n", 4, "delta", "'x'"),  # quoted cell spans 2 lines
    ("t,delta,p,delta\n0,1,2,3\n", 1, "delta", "duplicate"),
])
def test_errors_name_file_row_column(tmp_path, text, row, col, extra):
    msg = _error(_csv(tmp_path, text))
    assert "run.csv" in msg and f"row {row}" in msg and extra in msg
    if col is not None:
        assert f"column '{col}'" in msg


def test_missing_columns_named_with_columns_found(tmp_path):
    msg = _error(_csv(tmp_path, "t,p,x\n0,1,2\n0.1,1,2\n"), ("delta", "beta"), ("p", "phi"))
    assert "run.csv" in msg and "'delta'" in msg and "'beta'" in msg and "'phi'" in msg
    assert "columns found: t, p, x" in msg


def test_empty_missing_short(tmp_path):
    assert "empty" in _error(_csv(tmp_path, ""))
    assert "empty" in _error(_csv(tmp_path, "\n\n", name="blank.csv"))
    msg = _error(str(tmp_path / "nope.csv"))
    assert "nope.csv" in msg and "not found" in msg
    msg = _error(_csv(tmp_path, "t,delta,p,phi\n0,1,2,3\n"))
    assert "run.csv" in msg and "1 data row" in msg and "at least 2" in msg
    assert "0 data row" in _error(_csv(tmp_path, "t,delta,p,phi\n"))
    assert "at least 5" in _error(_csv(tmp_path, GOOD), min_samples=5)
    bad = tmp_path / "bin.csv"
    bad.write_bytes(b"t,p\n\xff\xfe\n")
    assert "bin.csv" in _error(str(bad))


def test_a_binary_file_is_named_and_its_bytes_are_shown_escaped(tmp_path):
    """A zip file named .csv: no raw bytes (NUL, escape sequences) in the message, and no page of them."""
    zipped = tmp_path / "flight_08.csv"
    zipped.write_bytes(b"PK\x03\x04garbage\x00\x1b[31m" * 500 + b"\n")
    message = _error(str(zipped))
    assert message.startswith(f"{zipped}: not a CSV file: it holds binary data (it begins 'PK\\x03\\x04garbage\\x00")
    assert message.isprintable() and len(message) < 200 + len(str(zipped))
    control = tmp_path / "control.csv"                  # text, but a header of control characters
    control.write_bytes(b"\x1b[31mred," + b"x" * 500 + b"\n1,2\n")
    message = _error(str(control))
    assert "columns found: \\x1b[31mred, xxx" in message and message.isprintable() and len(message) < 400


class FakeTTY(io.StringIO):
    def isatty(self):
        return True


def test_progress_tty(monkeypatch):
    monkeypatch.delenv("SKIGEN_PROGRESS", raising=False)
    out = FakeTTY()
    assert list(progress(range(20), 20, "filtering", stream=out, min_seconds=0)) == list(range(20))
    text = out.getvalue()
    assert "filtering" in text and "100% (20/20)" in text and "\r" in text and text.endswith("\n")


def test_progress_not_tty(monkeypatch):
    monkeypatch.delenv("SKIGEN_PROGRESS", raising=False)
    out = io.StringIO()
    assert list(progress(range(20), 20, "filtering", stream=out, min_seconds=0)) == list(range(20))
    assert out.getvalue() == ""
    monkeypatch.setenv("SKIGEN_PROGRESS", "1")
    list(progress(range(3), 3, "forced", stream=out, min_seconds=0))
    assert out.getvalue().splitlines()[-1].startswith("forced: 100% (3/3)")
    assert "\r" not in out.getvalue() and out.getvalue().endswith("\n")


def test_forced_progress_is_written_as_lines_as_the_work_goes(monkeypatch):
    """Onto a pipe (SKIGEN_PROGRESS=1) a line every LINE_SECONDS while the work goes on, not one at the end."""
    import skigen.progress as pg
    monkeypatch.setenv("SKIGEN_PROGRESS", "1")
    clock = iter(range(0, 10_000, 1))                  # each look at the clock: one second later
    monkeypatch.setattr(pg.time, "perf_counter", lambda: float(next(clock)))
    out = io.StringIO()
    work = progress(range(10), 10, "run", stream=out)
    for _ in range(6):
        next(work)
    lines = out.getvalue().splitlines()
    assert len(lines) >= 2 and "\r" not in out.getvalue() and out.getvalue().endswith("\n")
    assert all(line.startswith("run: ") for line in lines) and "(1/10)" in lines[0]
    list(work)
    assert out.getvalue().splitlines()[-1].startswith("run: 100% (10/10)")


def test_diagnosis_stages_are_lines_in_a_log_file(monkeypatch):
    """Forced onto a file, each stage and note is a line of its own (no carriage returns joining them)."""
    from skigen.diagnose import _Stages
    monkeypatch.setenv("SKIGEN_PROGRESS", "1")
    out = io.StringIO()
    stage = _Stages(True, out)
    stage("calibrating the noise")
    stage.note("a note")
    stage("naming")
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue() and len(lines) == 3 and lines[1] == "diagnose: a note"
    assert lines[0].startswith("diagnose ") and lines[0].endswith(" s: calibrating the noise")


def test_progress_quiet_when_fast(monkeypatch):
    monkeypatch.delenv("SKIGEN_PROGRESS", raising=False)
    out = FakeTTY()
    list(progress(range(5), 5, "quick", stream=out, min_seconds=10))
    assert out.getvalue() == ""


def test_slow_symbolic_derivation_is_announced(monkeypatch, capsys):
    """Above SLOW_DERIVATION_N states the Python backend says it is deriving; only once."""
    from benchmarks.common import recording
    from models.wingrock import build
    from models.wingrock_sim import simulate
    from skigen import derive, runtime

    monkeypatch.setenv("SKIGEN_PROGRESS", "1")
    monkeypatch.setattr(runtime, "SLOW_DERIVATION_N", 7)           # WingRock SKI has n = 8
    filt, rec = derive(build(), "ski"), recording(simulate(seed=0, duration=0.1))
    runtime.run(filt, rec)
    assert "deriving the ski step of 'wingrock' symbolically (n = 8" in capsys.readouterr().err
    runtime.run(filt, rec)
    assert "deriving" not in capsys.readouterr().err


def _digits(text: str) -> int:
    """Significant digits of a number's text."""
    mantissa = text.lower().split("e")[0].lstrip("+-").replace(".", "")
    return len(mantissa.strip("0")) or 1


def test_result_numbers_are_exact_and_shortest_in_a_background_writer(tmp_path):
    from skigen.recording import TableWriter

    rng = np.random.default_rng(0)
    x = rng.normal(size=3000) * 10.0 ** rng.integers(-300, 300, 3000)
    x[:6] = [0.1 + 0.2, 1e-5, 5e-324, 1.7976931348623157e308, -0.0, np.nan]
    path = tmp_path / "x.csv"
    with TableWriter(path, background=True, queue=1) as w:
        for a in range(0, 3000, 700):
            w.write({"x": x[a:a + 700], "k": np.arange(a, min(a + 700, 3000)), "s": np.full(len(x[a:a + 700]), "ok")})
    rows = open(path).read().splitlines()
    assert rows[0] == "x,k,s" and rows[6] == ",5,ok"                    # NaN: an empty cell
    cells = [r.split(",")[0] for r in rows[1:]]
    back = np.array([float(c) if c else np.nan for c in cells])
    assert np.array_equal(back, x, equal_nan=True)                       # exact
    assert all(_digits(c) <= _digits(repr(v)) for c, v in zip(cells, x.tolist()) if c)   # shortest
    assert [int(r.split(",")[1]) for r in rows[1:]] == list(range(3000))
    with pytest.raises(ValueError):
        with TableWriter(path, background=True) as w:
            w.write({"a": [1.0, 2.0], "b": [1.0]})


def test_stuck_readings_are_told_from_a_quantised_sensor_and_a_clipped_one():
    """Recording.unstuck: a run of 10 identical readings inside the range of a sensor whose other
    readings never repeat is stuck; the same run of a quantised sensor (at rest), at the sensor's
    extreme (a clip at its bound), at the start (at rest) or of a sensor logged at 10 times its
    rate is data; that sensor's stuck run is 50 readings."""
    rng = np.random.default_rng(0)
    t = np.arange(200) * 0.01
    y = np.sin(t) + 0.01 * rng.normal(size=200)
    rec = lambda *cols: Recording("r.csv", t, np.zeros((200, 1)), np.column_stack(cols), ("u",),
                                  tuple(f"y{i}" for i in range(len(cols))))
    frozen, short = y.copy(), y.copy()
    frozen[50:62] = frozen[50]
    short[50:59] = short[50]                                    # 9 in a row: not yet stuck
    clipped = np.minimum(y, 0.8)
    quantised = np.round(np.where(t < 1, 0.0, y) / 0.05) * 0.05  # at rest for 1 s, in steps of 0.05
    frozen[:30] = frozen[0]                                     # at rest before it starts: data
    slow = np.repeat(y[::10], 10)                                # each reading logged 10 times
    slow_stuck = slow.copy()
    slow_stuck[100:150] = slow_stuck[100]
    out, notes = rec(frozen, short, clipped, quantised, slow, slow_stuck).unstuck()
    assert np.isnan(out.outputs[50:62, 0]).all() and np.isfinite(np.delete(out.outputs[:, 0], range(50, 62))).all()
    assert np.isfinite(out.outputs[:, 1:5]).all()
    assert np.isnan(out.outputs[100:150, 5]).all() and np.isfinite(np.delete(out.outputs[:, 5], range(100, 150))).all()
    assert notes[0] == ("r.csv: output 'y0' holds one reading in 12 samples (1 run(s) of 10 or more; the first reads "
                        f"{frozen[50]:g} from t = 0.5 to 0.61 s), far longer than its readings repeat elsewhere: "
                        "a stuck sensor, those readings left out")
    assert len(notes) == 2 and "'y5' holds one reading in 50 samples (1 run(s) of 50 or more" in notes[1]


def test_input_holes_cut_a_recording_into_parts():
    """Recording.input_parts: the samples inside an input hole belong to no part; an output hole
    cuts nothing and stays with its part."""
    from skigen.grid import Hole
    t = np.arange(100) * 0.1
    holes = (Hole(2.0, 4.5, ("u",), True), Hole(6.0, 7.5, ("y",), False))
    rec = Recording("r.csv", t, np.zeros((100, 1)), np.zeros((100, 1)), ("u",), ("y",), holes=holes)
    first, second = rec.input_parts()
    assert (first.t[0], first.t[-1], second.t[0], second.t[-1]) == (0.0, 2.0, 4.5, 9.9)
    assert first.path == "r.csv [0–2 s]" and first.holes == () and second.holes == holes[1:]
    assert Recording("r.csv", t, np.zeros((100, 1)), np.zeros((100, 1)), ("u",), ("y",)).input_parts()[0].t is t


def test_an_input_logged_ten_times_slower_than_the_grid_is_one_short_error():
    """Every sample of the grid in a 10 s hole: one line naming five holes, how many more, and
    max_gap (the 360 holes of a user's log made a 13.5 kB message without the remedy)."""
    from skigen.grid import Hole
    t = np.arange(3600.0)
    holes = tuple(Hole(a, a + 10.0, ("P",), True) for a in np.arange(0.0, 3600.0, 10.0))
    rec = Recording("slow.csv", t, np.zeros((3600, 1)), np.zeros((3600, 1)), ("P",), ("T",), holes=holes)
    with pytest.raises(RecordingError) as err:
        rec.usable()
    text = str(err.value)
    assert len(text) < 500 and "… 355 more" in text and "max_gap exceeds its longest hole, 10 s (--max-gap" in text


def test_an_input_named_like_time_is_not_the_clock(tmp_path):
    """A thrust input 'T' beside a time column 't', 'time' or 'timestamp' (in any order), or beside a
    Parquet file's pandas index 't': the time is the clock column and 'T' the input (a user's fleet
    failed with "column 'T' is the time column" on four of these layouts)."""
    import pandas as pd
    from skigen import Model
    from skigen.recording import load_recording
    m = Model("hexa", dt=0.1)
    h = m.state("h", std=1.0)
    T = m.input("T")
    m.dynamics({h: T})
    m.output("baro", h, noise_std=0.1)
    t, thrust = np.arange(20) * 0.1, np.linspace(1.0, 2.0, 20)
    for clock in ("t", "time", "timestamp"):
        for frame in (pd.DataFrame({"T": thrust, clock: t, "baro": t}), pd.DataFrame({clock: t, "T": thrust, "baro": t})):
            frame.to_csv(tmp_path / "a.csv", index=False)
            rec = load_recording(tmp_path / "a.csv", m)
            np.testing.assert_allclose(rec.t, t, atol=1e-12)
            np.testing.assert_allclose(rec.inputs[:, 0], thrust)
    pd.DataFrame({"T": thrust, "baro": t}, index=pd.Index(t, name="t")).to_parquet(tmp_path / "a.parquet")
    np.testing.assert_allclose(load_recording(tmp_path / "a.parquet", m).inputs[:, 0], thrust)


def test_a_logger_s_held_readings_are_told_from_a_quantised_sensor():
    """A 1 Hz fix written on every row of a 10 Hz log repeats each reading 10 times (9–11 with a
    jittered logger); an encoder at rest, a quantised slow ramp, a noisy signal and a reading
    repeated irregularly are not held readings."""
    from skigen.recording import held_run
    rng = np.random.default_rng(0)
    fix = np.repeat(rng.normal(size=40), 10)
    assert held_run(fix[3:260]) == 10
    jittered = np.repeat(rng.normal(size=40), rng.integers(9, 12, 40))
    assert held_run(jittered[:257]) in (9, 10, 11)
    ramp = np.round(np.linspace(0, 3, 257) / 0.1) * 0.1              # each count ~8.6 samples, on a 0.1 grid
    assert held_run(ramp) == 0
    encoder = np.round(np.cumsum(rng.normal(0, 1, 257) * (rng.random(257) < 0.3))) * 0.01
    assert held_run(encoder) == 0
    assert held_run(rng.normal(size=257)) == 0
    assert held_run(np.repeat(rng.normal(size=60), rng.choice([1, 1, 2, 7], 60))[:257]) == 0


def test_held_readings_are_used_once_by_run_in_streamed_and_whole_file_reading(tmp_path):
    """`skigen run` on a log whose 1 Hz position is forward-filled on every row (10 Hz): the note
    says so and the result equals that of the log with empty cells, byte for byte (the streamed
    reader hands such a file to the whole-file one)."""
    from skigen.cli import main
    rng = np.random.default_rng(1)
    t = np.arange(600) * 0.1
    pos = np.where(np.arange(600) % 10 == 0, np.sin(0.1 * t) + rng.normal(0, 0.05, 600), np.nan)
    spec = tmp_path / "m.py"
    spec.write_text("from skigen import Model\nmodel = Model('m', dt=0.1)\n"
                    "x = model.state('x', std=1.0, process_std=0.01)\nv = model.state('v', std=1.0, process_std=0.01)\n"
                    "a = model.input('a')\nmodel.dynamics({x: v, v: a})\nmodel.output('pos', x, noise_std=0.05)\n")
    a = -0.01 * np.sin(0.1 * t)
    write_recording(tmp_path / "gaps.csv", t, {"a": a}, {"pos": pos})
    held = pos.copy()
    for k in range(1, 600):
        held[k] = held[k] if np.isfinite(held[k]) else held[k - 1]
    write_recording(tmp_path / "held.csv", t, {"a": a}, {"pos": held})
    for name in ("gaps", "held"):
        assert main(["run", str(spec), str(tmp_path / f"{name}.csv"), "--filter", "ukf", "--out",
                     str(tmp_path / f"{name}_out.csv")]) == 0
    assert (tmp_path / "gaps_out.csv").read_text() == (tmp_path / "held_out.csv").read_text()


def test_bytes_that_are_not_utf8_name_their_row_and_column(tmp_path):
    """A Latin-1 'é' in row 203's phi, and a header written in Latin-1: the error names the file, the
    row, the column and the byte, and how to re-save it (before: "'utf-8' codec can't decode byte
    0xe9 in position 738", a position in a buffer, not in the file)."""
    rows = "".join(f"{k * 0.1:.1f},1,2,3\n" for k in range(300))
    lines = ("t,delta,p,phi\n" + rows).encode().split(b"\n")
    lines[202] = lines[202][:-1] + "é".encode("latin-1")
    path = tmp_path / "latin.csv"
    path.write_bytes(b"\n".join(lines))
    at = b"\n".join(lines).index(b"\xe9")
    assert _error(path) == (f"{path}, row 203, column 'phi': byte {at} (e9 0a 32 30) is not UTF-8 text: a corrupt block, or a "
                            "file saved in another encoding (re-save it as UTF-8, e.g. pandas.read_csv(path, "
                            "encoding='latin-1').to_csv(new_path, index=False))")
    path.write_bytes("t,delta,p,phï\n0,1,2,3\n".encode("latin-1"))
    assert _error(path).startswith(f"{path}, row 1: byte 12 (ef 0a 30 2c) is not UTF-8 text")   # the header
