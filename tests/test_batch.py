"""skigen batch on a 2-worker LocalCluster: a fleet of 22 small logs (2 corrupt), the same numbers
as each log run alone, resume after a deleted result, the C library compiled once, the move rule."""
import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import skigen
from models.wingrock_sim import simulate
from skigen.batch import BatchError, batch
from skigen.batch.summary import moves, threshold
from skigen.modelfile import load_model
from skigen.recording import write_recording

MODEL = "models/wingrock.py"
FILTER = "ukf"
GOOD = [f"flight_{i:02d}" for i in range(20)]


@pytest.fixture(scope="module")
def client():
    from distributed import Client, LocalCluster
    import logging
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0",
                           silence_logs=logging.CRITICAL)
    c = Client(cluster)
    yield c
    c.close()
    cluster.close()


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """20 short WingRock flights (3 s, 151 samples) and 2 corrupt logs."""
    d = tmp_path_factory.mktemp("fleet")
    for i, name in enumerate(GOOD):
        sim = simulate(seed=i, duration=3.0)
        write_recording(d / f"{name}.csv", sim.t, {"delta": sim.delta}, {"phi": sim.phi})
    (d / "flight_bad_cell.csv").write_text("t,delta,phi\n0,0.1,0.2\n0.02,abc,0.3\n0.04,0.1,0.2\n")
    (d / "flight_no_phi.csv").write_text("t,delta\n0,0.1\n0.02,0.2\n0.04,0.1\n")
    return d


@pytest.fixture(scope="module")
def first(fleet, client, tmp_path_factory):
    out = tmp_path_factory.mktemp("out")
    return batch(MODEL, str(fleet / "flight_*.csv"), out, filter=FILTER, client=client, show_progress=False), out


def _summary(out: Path) -> dict:
    with open(out / "summary.csv", newline="") as f:
        return {r["log"]: r for r in csv.DictReader(f)}


def test_22_logs_give_20_ok_rows_and_2_failed_rows_with_their_messages(first, fleet):
    result, out = first
    rows = _summary(out)
    assert len(rows) == 22 and result.counts == {"ok": 20, "diverged": 0, "failed": 2}
    assert [r["log"] for r in result.rows] == sorted(rows)          # ordered by file name (no epoch stamps)
    assert rows["flight_bad_cell"]["status"] == "failed"
    assert "row 3, column 'delta': 'abc' is not a number" in rows["flight_bad_cell"]["message"]
    assert rows["flight_no_phi"]["status"] == "failed" and "phi" in rows["flight_no_phi"]["message"]
    for name in GOOD:
        r = rows[name]
        assert r["status"] == "ok" and r["message"] == r["notes"] == "" and int(r["samples"]) == 151
        assert float(r["duration_s"]) == pytest.approx(3.0)
        assert 0.2 < float(r["mean_nis"]) < 5 and float(r["nis_expected"]) == 1.0
        assert r["verdict"] in ("consistent", "inconsistent", "conservative")
        assert r["verdict"] == skigen.run(load_model(MODEL), fleet / f"{name}.csv", filter=FILTER).summary(
        ).verdict().partition(":")[0] if name == "flight_00" else True
        assert (out / name / "done.json").exists() and (out / name / "result.csv").exists()
    for bad in ("flight_bad_cell", "flight_no_phi"):
        assert not (out / bad / "done.json").exists()
        assert "Traceback" in (out / bad / "error.txt").read_text()
    assert (out / "summary.png").stat().st_size > 10_000
    assert not list(out.glob(".*.tmp-*"))


def test_the_same_numbers_as_running_each_log_alone(first, fleet):
    result, out = first
    model = load_model(MODEL)
    rows = _summary(out)
    weights = [n for n in rows["flight_00"] if n.startswith("w_")]
    assert len(weights) == 6
    for name in GOOD:
        alone = skigen.run(model, fleet / f"{name}.csv", filter=FILTER)
        w, s = alone.weights[-1], alone.weight_std[-1]
        got = np.array([float(rows[name][n]) for n in weights])
        got_std = np.array([float(rows[name][f"std_{n}"]) for n in weights])
        np.testing.assert_allclose(got, w, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(got_std, s, rtol=1e-9, atol=1e-12)
        assert float(rows[name]["mean_nis"]) == pytest.approx(np.nanmean(alone.nis), rel=1e-9)
    alone = skigen.run(model, fleet / "flight_07.csv", filter=FILTER).to_frame()
    table = pd.read_csv(out / "flight_07" / "result.csv")
    assert list(table.columns) == list(alone.columns)
    num = [c for c in alone.columns if c != "status"]
    np.testing.assert_allclose(table[num].to_numpy(float), alone[num].to_numpy(float), rtol=1e-9, equal_nan=True)
    assert (table["status"] == alone["status"]).all()


def test_rerun_skips_complete_logs_and_redoes_a_deleted_or_changed_one(first, fleet, client, tmp_path):
    import shutil
    _, out = first
    copy = tmp_path / "out"
    shutil.copytree(out, copy)
    before = {n: (copy / n / "done.json").stat().st_mtime_ns for n in GOOD}
    shutil.rmtree(copy / "flight_05")
    again = batch(MODEL, str(fleet / "flight_*.csv"), copy, filter=FILTER, client=client, show_progress=False)
    assert again.skipped == 19 and again.counts == {"ok": 20, "diverged": 0, "failed": 2}
    after = {n: (copy / n / "done.json").stat().st_mtime_ns for n in GOOD}
    assert [n for n in GOOD if after[n] != before[n]] == ["flight_05"]
    drop = lambda rows: {n: {k: v for k, v in r.items() if k != "seconds"} for n, r in rows.items()}
    assert drop(_summary(copy)) == drop(_summary(out))         # the redone log has the same numbers
    # a changed log is done again
    sim = simulate(seed=99, duration=3.0)
    write_recording(fleet / "flight_19.csv", sim.t, {"delta": sim.delta}, {"phi": sim.phi})
    changed = batch(MODEL, str(fleet / "flight_*.csv"), copy, filter=FILTER, client=client, show_progress=False)
    assert changed.skipped == 19 and (copy / "flight_19" / "done.json").stat().st_mtime_ns != after["flight_19"]
    # another filter is another result: every log is done again
    other = batch(MODEL, [str(fleet / "flight_0[0-2].csv")], copy, filter="ekf", client=client,
                  show_progress=False, figures=False)
    assert other.skipped == 0 and other.counts["ok"] == 3


def test_c_backend_is_compiled_once_and_gives_the_python_numbers(first, fleet, client, tmp_path):
    _, out = first
    res = batch(MODEL, [str(fleet / f"flight_0{i}.csv") for i in range(4)], tmp_path, filter=FILTER, backend="c",
                client=client, show_progress=False, figures=False)
    assert res.counts["ok"] == 4
    assert len(list((tmp_path / ".build" / "c").glob("*.so"))) == 1
    py = {r["log"]: r for r in first[0].rows}
    for r in res.rows:
        for q, (v, s) in r["quantities"].items():
            assert v == pytest.approx(py[r["log"]]["quantities"][q][0], rel=1e-7, abs=1e-10)


def test_fit_each_log_gives_parameters_with_std(fleet, client, tmp_path):
    from skigen.fit import fit
    logs = [str(fleet / f"flight_1{i}.csv") for i in range(3)]
    holed = pd.read_csv(logs[2])
    holed.loc[(holed.t > 1.0) & (holed.t < 2.3), "phi"] = np.nan        # a 1.3 s output hole: said, as a run does
    holed.to_csv(tmp_path / "flight_holed.csv", index=False)
    res = batch(MODEL, logs + [str(tmp_path / "flight_holed.csv")], tmp_path / "out", mode="fit", client=client,
                show_progress=False, figures=False)
    assert res.counts["ok"] == 4
    holes = {r["log"]: [n for n in r["notes"] if "hole" in n] for r in res.rows}
    (said,) = holes.pop("flight_holed")
    assert "output hole(s) longer than max_gap = 1 s, 43% of the recording: 1–2.3 s (1.3 s) without phi" in said
    assert not any(holes.values())
    tmp_path = tmp_path / "out"
    model = load_model(MODEL)
    alone = fit(model, [skigen.recording.load_recording(logs[1], model)], show_progress=False)
    row = next(r for r in res.rows if r["log"] == "flight_11")
    for name, p in alone.weights.items():
        assert row["quantities"][name][0] == pytest.approx(p["value"], rel=1e-6)
        assert row["quantities"][name][1] == pytest.approx(p["std"], rel=1e-6)
    assert (tmp_path / "flight_11" / "fit.json").exists() and (tmp_path / "flight_11" / "fitted_model.py").exists()
    import csv
    table = list(csv.DictReader(open(tmp_path / "summary.csv")))
    assert "std_w_abs_theta_p" in table[0] and "mean_nis" not in table[0]     # a fit has no filter NIS
    line = next(r for r in table if r["log"] == "flight_11")
    for o, e in alone.recordings[0]["rmse"].items():                           # but each output's rmse
        assert float(line[f"rmse_{o}"]) == pytest.approx(e, rel=1e-6)


def test_a_diagnosis_row_gives_the_nis_per_measured_sample_as_a_run_row():
    """A log read at half the model's rate: the run's summary and the diagnosis's consistency, as
    the batch writes them, give the same mean NIS and expectation (the diagnosis's were per grid
    sample: half)."""
    from skigen.batch.task import per_measured
    from skigen.diagnose.detect import consistency
    from skigen.runtime import RunSummary
    m = skigen.Model("still", dt=0.01)
    x = m.state("x", std=1e-3, process_std=1e-6)
    m.dynamics({x: 0 * x})
    m.output("a", x, noise_std=0.1)
    m.output("b", x, noise_std=0.1)
    rng = np.random.default_rng(0)
    a, b = rng.normal(0, 0.1, 1000), rng.normal(0, 0.1, 1000)
    a[1::2] = b[1::2] = np.nan
    res = skigen.run(m, pd.DataFrame({"t": np.arange(1000) * 0.01, "a": a, "b": b}), filter="ekf")
    run = RunSummary(skigen.derive(m, "ekf")).add(res)
    c = consistency(res, m.output_names).asdict()
    assert c["measured_samples"] == 500 and c["nis_expected"] == pytest.approx(1.0, abs=0.002)   # per grid sample
    mean, expected = per_measured(c)
    assert expected == pytest.approx(run.expected_sum / run.nis_count) == pytest.approx(2.0)
    assert mean == pytest.approx(run.nis_sum / run.nis_count, rel=1e-9)


def test_the_terminal_says_when_the_fits_call_their_error_bars_optimistic(tmp_path):
    """A fleet fit by output error under a disturbance: its moves rest on error bars its notes call
    optimistic (a user's healthy flight moved at z = 3.7); the terminal says so beside them."""
    from skigen.batch import BatchResult
    from skigen.fit import OPTIMISTIC
    rows = [dict(log=f"f{k}", status="ok", notes=[f"{OPTIMISTIC} (phi 2.1× its std): …"] if k != 1 else [])
            for k in range(3)]
    moved = [dict(quantity="Lp", log="f2", before=-5.5, after=-2.6, z=8.8, threshold=2.39)]
    res = BatchResult(tmp_path, rows, moved, "file name", tmp_path / "summary.csv", None, 0, 1.0, 1, {"ok": 3})
    lines = res.lines()
    assert lines[1].startswith("  moved: Lp at f2") and lines[2].startswith(
        "  note: the fits of f0, f2 say their error bars are optimistic") and "--method filter-error" in lines[2]
    assert not any("note:" in line for line in BatchResult(tmp_path, rows[1:2], moved, "file name", tmp_path,
                                                          None, 0, 1.0, 1, {"ok": 1}).lines())


def test_a_log_in_other_units_is_said_and_two_sided_findings_keep_their_columns(tmp_path):
    """A fleet's roll angle logged in degrees: its diagnosis said 'check the units' in its report,
    the fleet's row and terminal not (they named a gyro saturation instead); and its two findings,
    the gyro's lower and upper saturation, shared one column: the lower was lost without a word."""
    from skigen.batch import BatchResult
    from skigen.batch.task import _finding_key
    hint = "check the units: output 'phi_m' [rad] is 57.05× the nominal free run: is the recording in degrees …"
    rows = [dict(log="f03", status="ok", notes=[hint, "other"]), dict(log="f01", status="ok", notes=["other"])]
    lines = BatchResult(tmp_path, rows, [], "file name", tmp_path / "summary.csv", None, 0, 1.0, 1, {"ok": 2}).lines()
    assert lines[1:] == ["  check the units: f03: output 'phi_m' [rad] is 57.05× the nominal free run: is the "
                         "recording in degrees …"], lines
    found = [dict(effect="sensor_saturation", output="p_m", equation="p", side=side) for side in ("lower", "upper")]
    assert [_finding_key(f) for f in found] == ["sensor_saturation@p_m@lower", "sensor_saturation@p_m@upper"]
    assert _finding_key(dict(effect="input_delay", equation="v", through="u")) == "input_delay@v@u"
    assert _finding_key(dict(effect="constant", input="g", equation="v")) == "constant@g"


def test_a_flight_far_above_the_fleets_nis_is_said():
    """Seven flights under a sensor noise declared 10–30× too large ran 'conservative', one of them
    logged in km/h among flights in m/s (mean NIS 1.18 against the others' 0.0095): said of it
    alone (its row and the terminal: the next test); not said in a fleet whose flights agree, nor
    among fewer than three logs with a NIS."""
    from skigen.batch.summary import UNLIKE, unlike_the_fleet
    nis = [0.0093, 0.0097, 0.0095, 1.18, 0.0096, 0.0094, 0.0099]
    rows = [dict(log=f"f{i:02d}", status="ok", mean_nis=x, nis_expected=1.0, notes=[]) for i, x in enumerate(nis)]
    ((log, x, median),) = unlike_the_fleet(rows + [dict(log="f07", status="failed")])
    assert (log, x, median) == ("f03", 1.18, 0.0096) and x / median > UNLIKE
    assert unlike_the_fleet([dict(r, mean_nis=1.0 + 0.01 * i) for i, r in enumerate(rows)]) == []
    assert unlike_the_fleet(rows[2:4]) == []

def test_a_run_batch_says_a_log_in_other_units(client, tmp_path):
    """Four cart flights, one whose encoder is logged in mm: a filter-run batch said nothing of
    it (the units were checked by fit and diagnose only); it now says 'check the units' of that log
    alone, on its row and the terminal, and it stands far above the fleet's NIS."""
    from models import cart
    for i in range(4):
        run_ = cart.simulate(cart.smooth(cart.steps([0.1, -0.1, 0.05], 1.0)), 3.0, seed=i)
        write_recording(tmp_path / f"c{i}.csv", run_.t, run_.inputs(), {"p_meas": run_.p_meas * (1e3 if i == 2 else 1)})
    res = batch("models/cart.py", str(tmp_path / "c*.csv"), tmp_path / "out", filter="ekf", client=client,
                show_progress=False)
    said = {r["log"]: [n for n in r["notes"] if n.startswith(("check the units", "unlike the fleet"))] for r in res.rows}
    assert [len(said[f"c{i}"]) for i in range(4)] == [0, 0, 2, 0], said
    assert said["c2"][0].endswith("× the nominal free run: is the recording in a unit 1000× smaller (mm for m, mV "
                                  "for V)?") and said["c2"][1].startswith("unlike the fleet: "), said
    assert any(line.startswith("  check the units: c2: output 'p_meas'") for line in res.lines())

def test_a_step_is_a_move_and_a_slow_drift_is_not():
    rows = []
    for k in range(100):
        drift = 1.0 + 0.002 * k                      # 0.2 over the fleet, 0.1σ per flight
        step = 0.010 if k < 60 else 0.015            # 0.005 = 7σ of the difference
        rows.append(dict(log=f"f{k:03d}", status="ok" if k != 30 else "failed",
                         quantities={"theta": [drift, 0.015], "phi": [step, 0.0005]}))
    m = moves(rows)
    assert [(x["quantity"], x["log"], x["previous"]) for x in m] == [("phi", "f060", "f059")]
    assert m[0]["z"] == pytest.approx(0.005 / np.hypot(0.0005, 0.0005))
    assert threshold(98) == pytest.approx(3.48, abs=0.01) and threshold(3) == pytest.approx(2.39, abs=0.01) and threshold(1) == 2.0


def test_one_log_off_the_fleet_is_a_move_and_a_move_back():
    """Lp −4 on every flight but one other aircraft's (−14.8): the move is at that log, and the next
    flight's return to −4 is a move back, not a second move (before, the healthy flight after it was
    flagged too). A step that stays is still a move at each end it has."""
    from skigen.batch import BatchResult
    rows = [dict(log=f"f{k}", status="ok", quantities={"Lp": [-14.8 if k == 3 else -4.0 + 0.01 * k, 0.13]})
            for k in range(8)]
    m = moves(rows)
    assert [(x["log"], x.get("back", False)) for x in m] == [("f3", False), ("f4", True)]
    lines = BatchResult(Path("."), rows, m, "file name", Path("summary.csv"), None, 0, 1.0, 1, {"ok": 8}).lines()
    assert lines[1].startswith("  moved: Lp at f3: -3.98 -> -14.8")
    assert lines[2].startswith("  back: Lp at f4: -14.8 -> -3.96, the level before f3") and lines[2].endswith(
        "f3 alone moved")
    steps = [dict(log=f"s{k}", status="ok", quantities={"Lp": [-4.0 if k < 3 else -8.0 if k == 3 else -12.0, 0.13]})
             for k in range(6)]
    assert [(x["log"], x.get("back", False)) for x in moves(steps)] == [("s3", False), ("s4", False)]


def test_clear_errors(fleet, tmp_path):
    with pytest.raises(BatchError, match=r"no log file matches '.*nothing_\*\.csv'"):
        batch(MODEL, str(fleet / "nothing_*.csv"), tmp_path)
    with pytest.raises(BatchError, match=r"^cannot connect to the Dask scheduler at 'tcp://127.0.0.1:9'"):
        batch(MODEL, str(fleet / "flight_00.csv"), tmp_path, scheduler="tcp://127.0.0.1:9", connect_timeout=1)
    with pytest.raises(BatchError, match="file path or package.module:attribute"):
        batch(load_model(MODEL), str(fleet / "flight_00.csv"), tmp_path)
    with pytest.raises(BatchError, match="model file 'nope.py' not found"):
        batch("nope.py", str(fleet / "flight_00.csv"), tmp_path)
    with pytest.raises(BatchError, match=r"SKI needs basis weights \(model.unknown\(...\)\); the EKF or UKF runs"):
        batch("models/cart.py", str(fleet / "flight_00.csv"), tmp_path, filter="ski")
    with pytest.raises(BatchError, match=r"^logs: file names or globs, not a DataFrame \(.*df.to_parquet"):
        batch(MODEL, [pd.DataFrame({"t": [0.0, 0.02], "delta": 0.0, "phi": 0.0})], tmp_path)
    with pytest.raises(BatchError, match=r"no log file matches '.*nothing_\*\.csv'"):   # the logs first
        batch("models/cart.py", str(fleet / "nothing_*.csv"), tmp_path, filter="ski")


def test_cli_batch_on_its_own_two_workers(fleet, tmp_path):
    logs = [str(fleet / "flight_0[0-2].csv"), str(fleet / "flight_bad_cell.csv")]
    r = subprocess.run([sys.executable, "-m", "skigen", "batch", MODEL, *logs, "--out", str(tmp_path),
                        "--filter", FILTER, "--workers", "2", "--no-figures"], capture_output=True, text=True,
                       env=dict(os.environ, SKIGEN_PROGRESS="0"))
    assert r.returncode == 1, r.stderr                # a failed log: exit 1, the others done
    assert r.stdout.startswith("4 logs: 3 ok, 0 diverged, 1 failed") and "on 2 worker(s)" in r.stdout
    assert "failed: flight_bad_cell:" in r.stdout and "'abc' is not a number" in r.stdout
    assert len(_summary(tmp_path)) == 4
    r = subprocess.run([sys.executable, "-m", "skigen", "batch", MODEL, "nope/*.csv", "--out", str(tmp_path)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.strip() == "skigen: error: no log file matches 'nope/*.csv'"


def test_diagnose_each_log_lists_its_findings(client, tmp_path):
    from benchmarks.scenarios import make
    (tmp_path / "logs").mkdir()
    for name, seconds in (("cart_clean", 10.0), ("cart_coulomb", 20.0)):
        sc = make(name, seconds, 1)
        sc.write_csv(tmp_path / "logs" / f"{name}.csv")
    clean = pd.read_csv(tmp_path / "logs" / "cart_clean.csv")      # the force unlogged for 1.5 s
    clean.loc[(clean.t >= 3.0) & (clean.t < 4.5), list(sc.inputs)] = np.nan
    clean.to_csv(tmp_path / "logs" / "cart_clean.csv", index=False)
    res = batch(sc.model_file, str(tmp_path / "logs" / "*.csv"), tmp_path / "out", mode="diagnose", client=client,
                show_progress=False, figures=False)
    rows = _summary(tmp_path / "out")
    assert rows["cart_clean"]["mismatch"] == "False" and rows["cart_clean"]["findings"] == ""
    stretch = clean[clean.t >= 4.5]                  # the stretch diagnosed, not the file
    assert int(rows["cart_clean"]["samples"]) == len(stretch), rows["cart_clean"]["samples"]
    assert float(rows["cart_clean"]["start"]) == pytest.approx(stretch.t.iloc[0])
    assert rows["cart_coulomb"]["mismatch"] == "True" and rows["cart_coulomb"]["findings"].startswith("coulomb_friction on v (")
    assert float(rows["cart_coulomb"]["coulomb_friction@v"]) > 5 * float(rows["cart_coulomb"]["std_coulomb_friction@v"])
    report = json.loads((tmp_path / "out" / "cart_coulomb" / "report.json").read_text())
    assert report["corrected_model"] == str(tmp_path / "out" / "cart_coulomb" / "corrected_model.py")
    assert Path(report["corrected_model"]).exists() and res.counts["ok"] == 2
    assert rows["cart_coulomb"]["remains"] == "False" and rows["cart_clean"]["remains"] == "False"
    said = [line for line in res.lines() if line.startswith("  mismatch: ")]     # the terminal names the log
    assert said == [f"  mismatch: cart_coulomb: {rows['cart_coulomb']['findings']}"], res.lines()


def test_diagnose_puts_the_calibrated_constants_in_the_summary(client, tmp_path):
    """A model declaring Mα, Mq, Mδ 30 % off: the diagnosis calibrates them, and summary.csv has them
    (a fleet user's heavier vehicle showed only in its report.md, its row 'mismatch False')."""
    from benchmarks.scenarios import make
    from models import short_period as pitch
    (tmp_path / "logs").mkdir()
    make("pitch_clean", 30.0, 1).write_csv(tmp_path / "logs" / "pitch.csv")
    batch("benchmarks.scenarios:PITCH_GREY", str(tmp_path / "logs" / "*.csv"), tmp_path / "out", mode="diagnose",
          client=client, show_progress=False, figures=False)
    row = _summary(tmp_path / "out")["pitch"]
    for name, truth in (("Ma", pitch.MA), ("Mq", pitch.MQ), ("Mde", pitch.MDE)):
        assert abs(float(row[name]) - truth) < 3 * float(row[f"std_{name}"]), (name, row[name], truth)
        assert abs(float(row[name]) - truth) < 0.1 * abs(truth)           # declared 30 % off


def test_logs_of_one_name_keep_apart_and_the_output_folder_is_not_read(tmp_path):
    """c.csv beside c.parquet get their own folders (they shared one: a log was lost); a glob that
    reaches into the batch's own output folder does not take its results for logs."""
    from skigen.batch import expand_logs, log_names
    for rel in ("a/f.csv", "b/f.csv", "c.csv", "c.parquet", "out/c/result.csv"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("t\n")
    paths = expand_logs(str(tmp_path / "**" / "*.*"), outside=tmp_path / "out")
    assert [p.relative_to(tmp_path).as_posix() for p in paths] == ["a/f.csv", "b/f.csv", "c.csv", "c.parquet"]
    assert log_names(paths) == ["a__f.csv", "b__f.csv", "c.csv", "c.parquet"]
    assert log_names(paths[:3]) == ["a__f", "b__f", "c"]
    with pytest.raises(BatchError, match="no log file matches"):
        expand_logs(str(tmp_path / "out" / "**" / "*.csv"), outside=tmp_path / "out")


def test_a_broken_link_is_a_failed_row_and_a_folder_is_no_log(tmp_path):
    """A glob over a folder with a log, a link to a log that is gone and a subfolder named like a
    log: the link is a row that fails naming it (it was dropped in silence, or stopped the batch
    reading its size), the folder is not a log."""
    from skigen.batch import expand_logs
    from skigen.batch.task import log_digest
    (tmp_path / "a.csv").write_text("t\n")
    (tmp_path / "sub.csv").mkdir()
    (tmp_path / "gone.csv").symlink_to(tmp_path / "nowhere" / "x.csv")
    paths = expand_logs(str(tmp_path / "*.csv"))
    assert [p.name for p in paths] == ["a.csv", "gone.csv"] and log_digest(paths[1]) == "missing"


def test_a_constant_imported_by_the_model_file_is_part_of_its_digest(tmp_path):
    """A resumed batch redoes its logs when the model changes, also through a module it imports."""
    from skigen.batch.task import model_digest
    pkg = tmp_path / "vehicle"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "model.py").write_text(
        "from skigen import Model\nfrom .constants import GAIN\nmodel = Model('m', dt=0.1)\n"
        "x = model.state('x', std=1.0, process_std=0.1)\nu = model.input('u')\n"
        "model.dynamics({x: -x + GAIN * u})\nmodel.output('y', x, noise_std=0.1)\n")
    digests = []
    for gain in ("1.0", "1.0", "1.2000001"):
        (pkg / "constants.py").write_text(f"GAIN = {gain}\n")
        for name in [n for n in sys.modules if n == "vehicle" or n.startswith("vehicle.")]:
            del sys.modules[name]                     # a new process: the constants as they are now
        digests.append(model_digest(str(pkg / "model.py"), load_model(str(pkg / "model.py"))))
    assert digests[0] == digests[1] != digests[2]


def test_a_log_that_could_not_be_read_does_not_reorder_the_fleet():
    """Logs with calendar time stamps stay in time order when one failed to be read (it goes last);
    the moves are then between the right flights."""
    from skigen.batch.summary import order_rows
    rows = [dict(file="z_first.csv", log="z_first", status="ok", start=1.7e9),
            dict(file="m_second.csv", log="m_second", status="ok", start=1.7e9 + 86400),
            dict(file="a_third.csv", log="a_third", status="ok", start=1.7e9 + 2 * 86400),
            dict(file="empty.csv", log="empty", status="failed", start=None)]
    ordered, order = order_rows(rows)
    assert order == "time stamp" and [r["log"] for r in ordered] == ["z_first", "m_second", "a_third", "empty"]
    assert order_rows(rows[:3] + [dict(rows[3], status="ok")])[1] == "file name"


def test_a_binary_log_is_a_failed_row_whose_message_is_printable(tmp_path):
    """A zip file named flight_08.csv: its bytes (NUL, escape sequences) reach neither summary.csv nor the
    terminal, and a message quoting content is cut short."""
    from skigen.batch.summary import write_summary
    from skigen.batch.task import run_log
    log = tmp_path / "flight_08.csv"
    log.write_bytes(b"PK\x03\x04garbage\x00\x1b[2J" * 400 + b"\n")
    options = dict(spec=MODEL, digest="d", mode="run", filter=FILTER, backend="python", real="double",
                   build=str(tmp_path / ".build"), track=[], estimate=[], read={}, fingerprint="f")
    row = run_log(MODEL, str(log), str(tmp_path / "out"), "flight_08", options)
    assert row["status"] == "failed" and row["message"].startswith(f"{log}: not a CSV file: it holds binary data")
    assert row["message"].isprintable() and len(row["message"]) < 300
    odd = dict(row, log="odd", message="a\x00b\x1b[2J " + "x" * 2000, notes=["c\x07d"])
    text = write_summary(tmp_path / "summary.csv", [row, odd], []).read_text()
    assert "\x00" not in text and "\x1b" not in text and "\x07" not in text
    assert "a\\x00b\\x1b[2J x" in text and "c\\x07d" in text and len(text) < 2000


def test_the_terminal_names_the_runs_that_are_not_consistent_and_their_moves(tmp_path):
    """A run's verdict is a column and, where not consistent, a line; a move at a log whose run is
    inconsistent says its ± may be too small (a gusty flight's Lda 14σ from the fleet's, listed as
    a move like a real aileron degradation)."""
    from skigen.batch import BatchResult
    rows = [dict(log="f0", status="ok", verdict="consistent", mean_nis=1.02, nis_expected=1.0),
            dict(log="f1", status="ok", verdict="inconsistent", mean_nis=5.2, nis_expected=1.66),
            dict(log="f2", status="ok", verdict="consistent", mean_nis=0.98, nis_expected=1.0)]
    moved = [dict(quantity="Lda", log="f1", before=20.0, after=16.6, z=14.0, threshold=2.39),
             dict(quantity="Lda", log="f2", before=16.6, after=20.0, z=14.0, threshold=2.39)]
    lines = BatchResult(tmp_path, rows, moved, "file name", tmp_path / "summary.csv", None, 0, 1.0, 1, {"ok": 3}).lines()
    assert lines[1].endswith("(z = 14.0 > 2.39); its run is inconsistent: its ± may be too small, the move false")
    assert lines[2].endswith("(z = 14.0 > 2.39)")
    assert lines[3] == f"  inconsistent: f1: mean NIS 5.2 (expected 1.66); see {tmp_path / 'f1' / 'summary.txt'}"
    assert len(lines) == 4


def test_a_log_without_readings_is_said_not_listed_as_ok(fleet, tmp_path):
    """A log whose output column is empty ran 'ok' with its weights at their priors (k = 3 ± 1) and
    nothing on the terminal: its verdict is 'no reading' and the terminal says its estimates are
    the priors."""
    import pandas as pd
    from skigen.batch import BatchResult
    from skigen.batch.task import run_log
    log = pd.read_csv(fleet / "flight_00.csv").assign(phi=np.nan)
    log.to_csv(tmp_path / "empty.csv", index=False)
    options = dict(spec=MODEL, mode="run", filter=FILTER, backend="python", real="double", build=str(tmp_path / ".build"),
                   read=dict(time=None, time_unit="s", columns=None, max_gap=1.0), track=[], estimate=[],
                   method="output-error", figures=False, digest="d", fingerprint="f")
    row = run_log(MODEL, str(tmp_path / "empty.csv"), str(tmp_path / "out"), "empty", options)
    assert row["status"] == "ok" and row["verdict"] == "no reading", row
    lines = BatchResult(tmp_path, [row], [], "file name", tmp_path / "summary.csv", None, 0, 1.0, 1, {"ok": 1}).lines()
    assert lines[1] == f"  no reading: empty: its estimates are the declared priors; see {tmp_path / 'empty' / 'summary.txt'}"
