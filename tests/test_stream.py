"""`skigen run` streams a CSV file: the grid laid block by block equals the whole-file grid
sample for sample (jitter, holes, separate rows, faster and slower logs, first-order hold, blocks
cut anywhere), the result file is the same byte for byte, and memory does not grow with the file."""
import tracemalloc

import numpy as np
import pandas as pd
import pytest

import skigen
from skigen.cli import main
from skigen.recording import load_recording, stream_recording
from skigen.sources import NotStreamable


def small_model(hold="zoh"):
    """Two states, two inputs (u fast, g slow), two outputs: a quick model to derive and step."""
    m = skigen.Model(f"small_{hold}", dt=0.02, input_hold=hold)
    x = m.state("x", std=1.0, process_std=1e-2)
    v = m.state("v", std=1.0, process_std=1e-2)
    u, g = m.input("u"), m.input("g")
    m.dynamics({x: v, v: u - 0.5 * v + 0.1 * g})
    m.output("xm", x, noise_std=0.1)
    m.output("vm", v, noise_std=0.2)
    return m


def awkward_log(seed=0, seconds=30.0):
    """A log with everything that makes a grid hard: jittered stamps, inputs and outputs on their own
    rows, an output faster than the model, one slower, outputs before the inputs are known, an input
    hole (a restart), a shorter one that is a hole only for its rate (0.3 s of a 50 Hz input; the
    10 Hz input's 0.5 s gap is not), output holes, empty cells, rows without any value at the end,
    duplicate stamps."""
    rng = np.random.default_rng(seed)
    k = np.arange(int(seconds / 0.02))
    t = 0.3 + k * 0.02 + rng.uniform(-0.4, 0.4, len(k)) * 0.02
    t = np.maximum.accumulate(t)
    u = np.sin(0.3 * t) + rng.normal(0, 0.1, len(t))
    ins = pd.DataFrame({"t": t, "u": u})
    ins = ins[(ins.t < 9.0) | (ins.t > 10.7)]                          # an input hole: restart
    ins = ins[(ins.t < 20.0) | (ins.t > 20.3)]                         # 15 of its intervals: a hole
    slow = pd.DataFrame({"t": np.arange(0.25, seconds, 0.1), "g": 1.0})
    slow.loc[::7, "g"] = 2.0
    slow = slow[(slow.t < 22.0) | (slow.t > 22.5)]                     # 5 of its intervals: held
    tf = np.sort(rng.uniform(0.0, seconds, int(seconds * 120)))         # faster than the model
    outs = pd.DataFrame({"t": tf, "xm": np.cos(tf) + rng.normal(0, 0.1, len(tf))})
    outs = outs[(outs.t < 15) | (outs.t > 17.5)]                        # an output-only hole
    tv = np.arange(0.1, seconds, 0.04)
    vm = pd.DataFrame({"t": tv, "vm": np.where(rng.random(len(tv)) < 0.1, np.nan, np.sin(tv))})
    tail = pd.DataFrame({"t": seconds + np.arange(5) * 0.02})           # rows with no value
    df = pd.concat([ins, slow, outs, vm, tail]).sort_values("t", kind="stable").reset_index(drop=True)
    df.loc[len(df) // 2, "t"] = df.loc[len(df) // 2 - 1, "t"]          # a duplicate stamp
    df.insert(1, "mode", "AUTO")
    return df


@pytest.fixture(scope="module")
def log_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp("stream") / "log.csv"
    awkward_log().to_csv(path, index=False)
    return path


def streamed_grid(path, model, **kw):
    grid = stream_recording(path, model, **kw)
    blocks = list(grid)
    cat = lambda a: np.concatenate([getattr(b, a) for b in blocks])
    return grid, cat("t"), cat("inputs"), cat("outputs"), [b.k0 for b in blocks]


@pytest.mark.parametrize("hold", ["zoh", "foh"])
@pytest.mark.parametrize("after", [0.0, 0.009, 0.011])
def test_the_states_restart_where_the_input_after_a_hole_is_first_used(hold, after):
    """The grid uses an input at the sample nearest its stamp (zero-order hold) or interpolates up
    to it (first-order hold); the restart after a hole is where the new value is first used (a
    stamp 0.45 dt after a grid sample once restarted a sample late, after its reading had been
    judged against the states of before the hole)."""
    model = small_model(hold)
    t = np.arange(500) * 0.02
    u = t.copy()
    frame = pd.DataFrame({"t": t, "g": 0.0, "xm": 0.0, "vm": 0.0, "u": u})
    frame = frame[(frame.t < 3.0) | (frame.t > 5.0)].copy()
    frame.loc[frame.t > 5.0, "t"] += after                          # the stamps after the hole, late
    rec = load_recording(frame.reset_index(drop=True), model)
    (k,) = skigen.runtime.restarts(rec, model)
    first = int(np.argmax(rec.inputs[:, 0] > 3.0))                  # the first sample using a new value
    assert k == first if hold == "zoh" else rec.t[k] >= 5.02 + after > rec.t[k - 1]


@pytest.mark.parametrize("hold", ["zoh", "foh"])
@pytest.mark.parametrize("rows, block", [(1, 5), (2, 1 << 16), (3, 7), (17, 3), (250, 100), (None, 1 << 16)])
def test_the_streamed_grid_is_the_whole_file_grid(log_csv, hold, rows, block):
    model = small_model(hold)
    rec = load_recording(log_csv, model)
    grid, t, inputs, outputs, k0 = streamed_grid(log_csv, model, rows=rows, block=block)
    assert k0[0] == 0 and len(t) == len(rec.t)
    assert np.array_equal(t, rec.t) and np.array_equal(inputs, rec.inputs)
    assert np.array_equal(outputs, rec.outputs, equal_nan=True)
    assert grid.holes == rec.holes and tuple(grid.notes) == rec.notes
    assert grid.restart_list == skigen.runtime.restarts(rec, model) != []
    assert len(rec.holes) >= 2 and any("faster than the model" in n for n in rec.notes)
    later = [(h.t0, h.t1, h.columns) for h in rec.input_holes if h.t0 > 19]     # u's, not g's
    assert len(later) == 1 and 19.96 < later[0][0] < 20.0 and 20.3 < later[0][1] < 20.34 and later[0][2] == ("u",)


def test_blocks_of_a_few_bytes_and_mapped_columns(tmp_path):
    df = awkward_log(seed=1, seconds=6).rename(columns={"u": "cmd"})
    path = tmp_path / "log.csv"
    df.to_csv(path, index=False)
    model = small_model()
    rec = load_recording(path, model, columns={"u": "cmd"}, max_gap=0.5)
    _, t, inputs, outputs, _ = streamed_grid(path, model, columns={"u": "cmd"}, max_gap=0.5, block_size=97)
    assert np.array_equal(t, rec.t) and np.array_equal(inputs, rec.inputs)
    assert np.array_equal(outputs, rec.outputs, equal_nan=True)


@pytest.mark.parametrize("rows", [None, 7])
def test_iso_time_stamps_stream_to_the_whole_file_grid(tmp_path, monkeypatch, capsys, rows):
    """ISO-8601 stamps in the time column: seconds since 1970, streamed as read whole; a cell that is not
    a stamp in a later block is named by the whole-file reader."""
    df = awkward_log(seed=2, seconds=6)
    stamps = pd.Timestamp("2026-03-01T10:00:00Z") + pd.to_timedelta(df.t - df.t[0], unit="s")
    path = tmp_path / "iso.csv"
    df.assign(t=stamps.dt.strftime("%Y-%m-%dT%H:%M:%S.%fZ")).to_csv(path, index=False)
    model = small_model()
    rec = load_recording(path, model)
    grid, t, inputs, outputs, _ = streamed_grid(path, model, rows=rows, time_unit="ms")
    assert rec.t[0] == pytest.approx(stamps[0].timestamp()) and np.array_equal(t, rec.t)
    assert np.array_equal(inputs, rec.inputs) and np.array_equal(outputs, rec.outputs, equal_nan=True)
    assert grid.holes == rec.holes and tuple(grid.notes) == rec.notes
    lines = path.read_text().splitlines()
    lines[200] = "12.5," + lines[200].split(",", 1)[1]
    path.write_text("\n".join(lines) + "\n")
    monkeypatch.setattr(__import__("skigen").sources.CsvStream, "rows", 50)
    assert main(["run", "tests.test_stream:MODEL", str(path), "--filter", "ekf", "--out", str(tmp_path / "o.csv")]) == 2
    assert "iso.csv, row 201, column 't': '12.5' is not an ISO-8601 time stamp" in capsys.readouterr().err


def test_a_late_input_and_outputs_before_it(tmp_path):
    """The grid starts where the last input is first known, many blocks in: the outputs before are
    counted as not used, and what is kept meanwhile does not grow."""
    rng = np.random.default_rng(2)
    t = np.arange(3000) * 0.01
    df = pd.DataFrame({"t": t, "u": np.where(t > 4, rng.normal(size=len(t)), np.nan),
                       "g": np.where(t > 12.345, 1.0, np.nan), "xm": rng.normal(size=len(t)), "vm": np.nan})
    path = tmp_path / "late.csv"
    df.to_csv(path, index=False)
    for hold in ("zoh", "foh"):
        model = small_model(hold)
        rec = load_recording(path, model)
        grid, tt, inputs, outputs, _ = streamed_grid(path, model, rows=10)
        assert np.array_equal(tt, rec.t) and np.array_equal(inputs, rec.inputs)
        assert np.array_equal(outputs, rec.outputs, equal_nan=True) and tuple(grid.notes) == rec.notes
        assert any("before the inputs are known" in n for n in rec.notes)


@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_epoch_stamps_and_an_input_that_stops_before_the_end(tmp_path, hold):
    """Stamps of 1.7e9 s, an input that stops 1.5 s before the last output (a hole to the end: the
    states restart near the last sample, known only at the end of the file)."""
    df = awkward_log(seed=5, seconds=8)
    df["t"] += 1.7e9
    df.loc[df.t > 1.7e9 + 6.4, "u"] = np.nan
    path = tmp_path / "epoch.csv"
    df.to_csv(path, index=False, float_format="%.17g")
    model = small_model(hold)
    rec = load_recording(path, model)
    for rows in (3, 40):
        grid, t, inputs, outputs, _ = streamed_grid(path, model, rows=rows)
        assert np.array_equal(t, rec.t) and np.array_equal(inputs, rec.inputs)
        assert np.array_equal(outputs, rec.outputs, equal_nan=True) and grid.holes == rec.holes
        assert grid.restart_list == skigen.runtime.restarts(rec, model)
    assert rec.holes[-1].inputs and rec.holes[-1].columns[0] == "u" and rec.holes[-1].t1 >= rec.t[-1] - model.dt


@pytest.mark.parametrize("unit, scale, offset", [("s", 1.0, 0.0), ("ms", 1e3, 1.7e12)])
def test_a_streamed_run_shows_the_share_of_the_file_done(tmp_path, monkeypatch, unit, scale, offset):
    """The progress of a streamed run is the share of the file's time span its parts have reached
    (its first and last stamps read first; stamps in ms since 1970 as in s from 0): rising to 1,
    through the middle (it counted parts before, with no total)."""
    from skigen import runtime
    df = awkward_log(seed=2, seconds=10)
    df["t"] = df["t"] * scale + offset
    path = tmp_path / "log.csv"
    df.to_csv(path, index=False, float_format="%.17g")
    model = small_model()
    grid = stream_recording(path, model, time_unit=unit)
    assert grid.stream.stamps() == (df.t.iloc[0], df.t.iloc[-1])
    seen = []

    def recorder(items, total, label, measure=None, **kw):
        assert total == 1.0 and label.endswith(", streamed")
        for item in items:
            yield item
            seen.append(measure())
    monkeypatch.setattr(runtime, "progress", recorder)
    list(runtime.iter_run_stream(skigen.derive(model, "ekf"), grid, chunk=25))
    assert len(seen) > 10 and seen == sorted(seen) and seen[-1] == pytest.approx(1.0, abs=0.01)
    assert any(0.4 < x < 0.6 for x in seen), seen


def run_cli(tmp_path, data, name, *args):
    out = tmp_path / name
    assert main(["run", *args, str(data), "--out", str(out)]) == 0
    return out.read_bytes()


@pytest.mark.parametrize("hold, backend", [("zoh", "python"), ("foh", "python"), ("foh", "c")])
def test_skigen_run_streams_csv_with_the_same_result(tmp_path, monkeypatch, capsys, hold, backend):
    df = awkward_log(seed=3, seconds=12)
    path = tmp_path / "log.csv"
    df.to_csv(path, index=False)
    spec = tmp_path / "m.py"
    spec.write_text(f"import sys\nsys.path.insert(0, {str(__import__('pathlib').Path(__file__).parent)!r})\n"
                    f"from test_stream import small_model\nmodel = small_model({hold!r})\n")
    args = [str(spec), "--filter", "ekf", "--backend", backend]
    from skigen import runtime, sources
    whole = tmp_path / "whole.parquet"                  # the whole-file path: the same samples, not a CSV
    df.to_parquet(whole)
    expected = run_cli(tmp_path, whole, "whole.csv", *args)
    printed_whole = capsys.readouterr().out
    streamed = {}
    for rows in (None, 5, 64):
        monkeypatch.setattr(sources.CsvStream, "rows", rows)
        monkeypatch.setitem(runtime.CHUNK, backend, 33)
        streamed[rows] = run_cli(tmp_path, path, f"s{rows}.csv", *args)
        assert streamed[rows] == expected
    printed = capsys.readouterr().out
    assert printed.split("->")[0] == printed_whole.split("->")[0].replace("whole.parquet", "log.csv")
    assert "hole(s) longer than the maximum gap" in printed and sum(line.startswith("mean NIS")
                                                                      for line in printed.splitlines()) == 3


@pytest.mark.parametrize("rows", [None, 5, 64])
def test_an_input_that_stops_before_the_end_is_a_hole_in_the_streamed_run(tmp_path, monkeypatch, rows):
    """An input empty for the last 0.8 s of a 12 s log whose rows go on: its hole is known only at
    the end of the file, and the streamed run had filtered those 39 samples against the held input
    (1 bad input, 38 readings fused, where the whole-file run has 39 bad inputs). It now waits for
    the input's next stamp and gives the whole-file run, byte for byte."""
    from skigen import sources
    t = np.arange(600) * 0.02
    df = pd.DataFrame({"t": t, "u": np.sin(t), "g": 1.0, "xm": np.cos(t), "vm": 0.0})
    df.loc[df.t > 11.2, "u"] = np.nan
    df.to_csv(tmp_path / "log.csv", index=False)
    df.to_parquet(tmp_path / "log.parquet")
    spec = "tests.test_stream:MODEL"
    assert main(["run", spec, str(tmp_path / "log.parquet"), "--filter", "ekf", "--out", str(tmp_path / "w.csv")]) == 0
    monkeypatch.setattr(sources.CsvStream, "rows", rows)
    assert main(["run", spec, str(tmp_path / "log.csv"), "--filter", "ekf", "--out", str(tmp_path / "s.csv")]) == 0
    whole = pd.read_csv(tmp_path / "w.csv")
    assert (whole.status == "bad_input").sum() == 39
    assert (tmp_path / "s.csv").read_bytes() == (tmp_path / "w.csv").read_bytes()


def test_errors_are_those_of_the_whole_file_reader(tmp_path, capsys, monkeypatch):
    """Time going backwards between blocks, a bad cell in a later block: the message names the row."""
    from skigen import sources
    monkeypatch.setattr(sources.CsvStream, "rows", 50)                  # row 302 starts a block
    t = np.arange(400) * 0.02
    df = pd.DataFrame({"t": t, "u": 0.1, "g": 1.0, "xm": 0.0, "vm": 0.0})
    df.loc[300, "t"] = 1.0
    path = tmp_path / "back.csv"
    df.to_csv(path, index=False)
    spec = "tests.test_stream:MODEL"
    with pytest.raises(NotStreamable):
        list(stream_recording(path, MODEL, rows=50))
    assert main(["run", spec, str(path), "--filter", "ekf", "--out", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err
    assert "row 302, column 't'" in err and "time goes backwards" in err
    assert not (tmp_path / "o.csv").exists()
    df.loc[300, "t"] = 6.0
    df["u"] = df["u"].astype(object)
    df.loc[350, "u"] = "0x10"
    df.to_csv(path, index=False)
    assert main(["run", spec, str(path), "--filter", "ekf", "--out", str(tmp_path / "o.csv")]) == 2
    assert "row 352, column 'u': '0x10' is not a number" in capsys.readouterr().err
    # An earlier result at --out outlives a run that fails part way (the partial file is removed).
    (tmp_path / "o.csv").write_text("kept\n")
    assert main(["run", spec, str(path), "--filter", "ekf", "--out", str(tmp_path / "o.csv")]) == 2
    assert (tmp_path / "o.csv").read_text() == "kept\n" and sorted(p.name for p in tmp_path.iterdir()) == [
        "back.csv", "o.csv"]
    df.loc[350, "u"] = "0.1"
    df.to_csv(path, index=False)
    assert main(["run", spec, str(path), "--filter", "ekf", "--out", str(tmp_path / "o.csv")]) == 0
    assert len(pd.read_csv(tmp_path / "o.csv")) == 400 and not (tmp_path / "o.csv.partial").exists()


MODEL = small_model()


def peak_kept(path, model, rows):
    """The most samples a GridStream keeps at once, and the peak traced memory (bytes), over a run."""
    tracemalloc.start()
    grid = stream_recording(path, model, rows=rows, block=rows, block_size=1 << 16)
    most, n = 0, 0
    for blk in grid:
        most = max(most, sum(len(c.t) for c in grid.cols.values()))
        n += len(blk.t)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return most, peak, n


def test_memory_does_not_grow_with_the_file(tmp_path):
    rng = np.random.default_rng(4)
    sizes = {}
    for n in (20_000, 80_000):
        t = np.arange(n) * 0.02 + rng.uniform(-0.005, 0.005, n)
        df = pd.DataFrame({"t": t, "u": rng.normal(size=n), "g": 1.0, "xm": rng.normal(size=n),
                           "vm": np.where(np.arange(n) % 3 == 0, rng.normal(size=n), np.nan)})
        path = tmp_path / f"long{n}.csv"
        df.to_csv(path, index=False)
        sizes[n] = peak_kept(path, MODEL, 500)
        assert sizes[n][2] == n
    (kept_short, peak_short, _), (kept_long, peak_long, _) = sizes[20_000], sizes[80_000]
    assert kept_long <= 4 * 600 and kept_long <= kept_short + 10
    assert peak_long < 1.3 * peak_short                 # 4x the rows, not 4x the memory


def test_a_time_written_too_coarsely_is_refused_by_both_readers(tmp_path, capsys):
    """An epoch written with 10 significant digits at 50 Hz: about 50 rows share each whole second.
    Used as stamps, the first at each second was the only reading used (6 of 601) and the run said
    ok; the whole-file reader refuses it, naming the time column and the stamps' resolution, and the
    streamed reader leaves it to that. 14 duplicated rows in 400 are read, with their note."""
    t = 1.7e9 + np.arange(400) * 0.02
    df = pd.DataFrame({"t": t, "u": 0.1, "g": 1.0, "xm": 0.0, "vm": 0.0})
    coarse_path, dup_path = tmp_path / "coarse.csv", tmp_path / "dup.csv"
    df.assign(t=np.floor(t)).to_csv(coarse_path, index=False, float_format="%.10g")
    with pytest.raises(NotStreamable):
        list(stream_recording(coarse_path, MODEL, rows=50))
    with pytest.raises(ValueError, match=r"coarse.csv, column 't': 392 of the 400 samples of 'u' repeat the time stamp "
                                         r"before them, whose distinct values are 1 s apart \(the model's dt is 0.02 s\): "
                                         r"the time is written too coarsely"):
        load_recording(coarse_path, MODEL)
    assert main(["run", "tests.test_stream:MODEL", str(coarse_path), "--filter", "ekf", "--out",
                 str(tmp_path / "o.csv")]) == 2
    assert "written too coarsely" in capsys.readouterr().err
    pd.concat([df, df.iloc[100:114]]).sort_values("t", kind="stable").to_csv(dup_path, index=False, float_format="%.15g")
    rec = load_recording(dup_path, MODEL)
    assert any("14 sample(s) repeat the time stamp before them" in n for n in rec.notes)


def test_short_input_gaps_are_counted_by_both_readers(tmp_path):
    """Three gaps of 6 empty rows in a 50 Hz input (0.14 s, short of its 0.2 s hole): the input is held
    over them, unknown to the plant, and a note counts the gaps and the 18 grid samples held (before,
    a fleet's aileron with 14 such gaps said nothing and Lp came out 5σ off). The streamed grid says the
    same; a log without gaps says nothing."""
    t = np.arange(500) * 0.02
    df = pd.DataFrame({"t": t, "u": np.sin(t), "g": 1.0, "xm": 0.0, "vm": 0.0})
    df["u"] = df["u"].astype(object)
    for a in (100, 200, 300):
        df.loc[a:a + 5, "u"] = ""
    path = tmp_path / "gaps.csv"
    df.to_csv(path, index=False)
    note = ("input 'u': 3 gap(s) short of a hole (the longest 0.14 s; a hole is longer than 0.2 s) hold its last "
            "value over 18 grid sample(s), where the plant's input is not known")
    whole = load_recording(path, MODEL)
    assert [n for n in whole.notes if n.startswith("input 'u'")][0].startswith(note) and whole.holes == ()
    grid = stream_recording(path, MODEL, rows=50)
    for _ in grid:
        pass
    assert [n for n in grid.notes if n.startswith("input 'u'")] == [n for n in whole.notes if n.startswith("input 'u'")]
    df.assign(u=np.sin(t)).to_csv(path, index=False)
    assert not any("short of a hole" in n for n in load_recording(path, MODEL).notes)
