"""The command line as a user meets it: results on good data, one-line errors on bad."""
import csv
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from models.wingrock_sim import simulate
from skigen.recording import write_recording

MODEL = "models/wingrock.py"
ROOT = Path(__file__).resolve().parents[1]


def skigen(*args, cwd=None):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, "-m", "skigen", *args], capture_output=True, text=True, cwd=cwd, env=env)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    sim = simulate(seed=0, duration=4.0)
    phi = sim.phi.copy()
    phi[10] = np.nan                                   # one missing sample
    path = tmp_path_factory.mktemp("rec") / "wingrock.csv"
    write_recording(path, sim.t, {"delta": sim.delta}, {"phi": phi})
    return path


def test_run_writes_the_result_contract(recording, tmp_path):
    out = tmp_path / "result.csv"
    r = skigen("run", MODEL, str(recording), "--filter", "ski", "--out", str(out))
    assert r.returncode == 0, r.stderr
    rows = list(csv.reader(open(out)))
    header = rows[0]
    names = ["theta", "p", "w_one", "w_theta", "w_p", "w_abs_theta_p", "w_abs_p_p", "w_theta3"]
    assert header[:1 + 2 * len(names)] == ["t"] + names + [f"std_{n}" for n in names]
    assert header[17:20] == ["innov_phi", "nis", "loglik"]
    assert len(rows) == 1 + 201
    assert rows[1 + 10][17] == "" and rows[1 + 10][18] == ""          # missing sample: no innovation
    assert all(np.isfinite(float(v)) for v in rows[-1][:17])


def test_run_with_the_casadi_backend(recording, tmp_path):
    """--backend casadi (no guard policy) writes the same table as python on this clean flight."""
    tables = []
    for backend in ("python", "casadi"):
        out = tmp_path / f"{backend}.csv"
        r = skigen("run", MODEL, str(recording), "--filter", "ekf", "--backend", backend, "--out", str(out))
        assert r.returncode == 0, r.stderr
        assert f"ekf ({backend})" in r.stdout
        tables.append(list(csv.reader(open(out))))
    a, b = tables
    assert a[0] == b[0] and len(a) == len(b) == 1 + 201
    num = lambda rows, j: np.array([float(r[j]) if r[j] else np.nan for r in rows[1:]])
    for j, name in enumerate(a[0]):
        if name == "status":
            assert [r[j] for r in b] == [r[j] for r in a]
        else:
            np.testing.assert_allclose(num(b, j), num(a, j), rtol=1e-9, atol=1e-12, err_msg=name)


def test_run_takes_the_filter_options(recording, tmp_path):
    """--alpha and --second-order reach the filter (the table differs from the default's); out of
    range or on the wrong filter, a one-line error."""
    tables = {}
    for extra in ((), ("--alpha", "0.5"), ("--filter", "ekf"), ("--filter", "ekf", "--second-order")):
        out = tmp_path / f"{len(tables)}.csv"
        r = skigen("run", MODEL, str(recording), "--out", str(out), *extra)
        assert r.returncode == 0, r.stderr
        tables[extra] = np.genfromtxt(out, delimiter=",", skip_header=1, usecols=range(17))
    for a, b in (((), ("--alpha", "0.5")), (("--filter", "ekf"), ("--filter", "ekf", "--second-order"))):
        assert np.nanmax(np.abs(tables[a] - tables[b])) > 1e-6, (a, b)
    for extra, said in ((("--alpha", "0"), "--alpha must be in (0, 1], got 0.0"),
                        (("--second-order",), "--second-order is the EKF's (its prediction's second-order terms); --filter is ski")):
        r = skigen("run", MODEL, str(recording), "--out", str(tmp_path / "x.csv"), *extra)
        assert r.returncode != 0 and said in r.stderr and "Traceback" not in r.stderr, r.stderr


@pytest.mark.parametrize("content, expected", [
    ("t,delta,phi\n0,0,0\n0.02,abc,0.1\n", ["row 3", "column 'delta'", "'abc' is not a number"]),
    ("t,delta,phi\n0,0,0\n0.02,0\n", ["row 3", "fields"]),
    ("t,delta,phi\n0,0,0\n0.02,0,0.1\n0.01,0,0.1\n", ["row 4", "column 't'", "time goes backwards"]),
    ("t,delta\n0,0\n0.02,0\n", ["missing", "phi"]),
    ("", ["empty"]),
    ("t,delta,phi\n0,0,0\n0.02,1_0,0.1\n", ["row 3", "column 'delta'", "'1_0' is not a number"]),
    ("t,delta,phi\n0,0,0\n0.02,1e39,0.1\n", ["row 3", "column 'delta'", "overflows the C float"]),
])
def test_malformed_recordings_get_one_line_errors(tmp_path, content, expected):
    bad = tmp_path / "bad.csv"
    bad.write_text(content)
    r = skigen("run", MODEL, str(bad), "--out", str(tmp_path / "o.csv"), "--backend", "c", "--real", "float")
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert "bad.csv" in r.stderr
    for piece in expected:
        assert piece in r.stderr


def test_bad_model_specs_are_explained(tmp_path, recording):
    r = skigen("run", "nope.py", str(recording), "--out", str(tmp_path / "o.csv"))
    assert r.returncode == 2 and "model file 'nope.py' not found" in r.stderr
    broken = tmp_path / "broken.py"
    broken.write_text("from skigen import Model\nmodel = Model('m', dt=0.1)\nx = model.state('x')\n"
                      "model.dynamics({'y': x})\n")
    r = skigen("run", str(broken), str(recording), "--out", str(tmp_path / "o.csv"))
    assert r.returncode == 2 and "'y', which is not a declared state" in r.stderr
    assert f"model file '{broken}', line 4:" in r.stderr and "Traceback" not in r.stderr
    broken.write_text("from skigen import Model\nmodel = Model('m', dt=0.1)\nx = model.state('x')\n"
                      "model.dynamics({x: -kk * x})\n")
    r = skigen("run", str(broken), str(recording), "--out", str(tmp_path / "o.csv"))
    assert r.returncode == 2 and f"'{broken}' failed to load, line 4: NameError: name 'kk'" in r.stderr
    r = skigen("run", "models.wingrock:nothing", str(recording), "--out", str(tmp_path / "o.csv"))
    assert r.returncode == 2 and "defines no skigen.Model named 'nothing'" in r.stderr


def test_module_attribute_spec_works(recording, tmp_path):
    r = skigen("run", "models.wingrock:model", str(recording), "--filter", "ekf", "--out", str(tmp_path / "o.csv"))
    assert r.returncode == 0, r.stderr
    assert "mean NIS" in r.stdout


def test_a_float_run_says_float(recording, tmp_path):
    """The run's header names the precision of a float C run (it said '(c)' alone)."""
    r = skigen("run", MODEL, str(recording), "--filter", "ekf", "--backend", "c", "--real", "float",
               "--out", str(tmp_path / "o.csv"))
    assert r.returncode == 0 and "wingrock ekf (c, float): 201 samples" in r.stdout, r.stdout + r.stderr


def test_float_precision_needs_the_c_backend(recording, tmp_path):
    r = skigen("run", MODEL, str(recording), "--filter", "ekf", "--real", "float", "--out", str(tmp_path / "o.csv"))
    assert r.returncode == 1 and "real='float' is the precision of the generated C: give backend 'c'" in r.stderr
    assert not (tmp_path / "o.csv").exists()


def test_a_model_file_in_a_package_loads_by_path_from_anywhere(recording, tmp_path):
    """models/wingrock_delay.py imports from its package (``from .wingrock import ...``)."""
    r = skigen("run", str(ROOT / "models" / "wingrock_delay.py"), str(recording), "--filter", "ekf",
               "--out", "o.csv", cwd=tmp_path)
    assert r.returncode == 0 and "mean NIS" in r.stdout, r.stderr


def test_a_model_file_imports_its_siblings_and_a_module_spec_resolves_from_the_working_directory(
        recording, tmp_path, monkeypatch):
    """A model file that imports a module beside it loads from any directory, as Python would run
    it; ``module:attribute`` finds a module in the working directory, also from the installed
    ``skigen`` script, whose sys.path does not hold it."""
    import sys as _sys
    from skigen.modelfile import load_model
    home = tmp_path / "ship"
    home.mkdir()
    (home / "ship_constants.py").write_text("GAIN = 2.0\n")
    (home / "ship_model.py").write_text(
        "from skigen import Model\nfrom ship_constants import GAIN\nmodel = Model('ship', dt=0.02)\n"
        "p = model.state('p', std=1.0)\nd = model.input('delta')\nmodel.dynamics({p: -p + GAIN * d})\n"
        "model.output('phi', p, noise_std=0.1)\n")
    r = skigen("run", str(home / "ship_model.py"), str(recording), "--filter", "ekf", "--out", "o.csv", cwd=tmp_path)
    assert r.returncode == 0 and "mean NIS" in r.stdout, r.stderr
    monkeypatch.chdir(home)
    monkeypatch.setattr(_sys, "path", [p for p in _sys.path if p not in ("", str(home))])
    monkeypatch.delitem(_sys.modules, "ship_constants", raising=False)
    assert load_model("ship_model:model").name == "ship"


def test_generate_then_run_with_the_c_backend(recording, tmp_path):
    r = skigen("generate", MODEL, "--filter", "ukf", "--real", "float", "--out", str(tmp_path / "c"))
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "c").iterdir()) == [
        "wingrock_ukf.c", "wingrock_ukf.h", "wingrock_ukf_kernel.c", "wingrock_ukf_kernel.h"]
    assert "sqrtf(" in (tmp_path / "c" / "wingrock_ukf_kernel.c").read_text()
    header = (tmp_path / "c" / "wingrock_ukf.h").read_text()           # every index with its declared unit
    assert "#define WINGROCK_UKF_Z_P 1 /* deg/s */" in header and "#define WINGROCK_UKF_U_DELTA 0 /* deg */" in header
    assert "#define WINGROCK_UKF_Z_W_THETA3 7 /* times theta^3 in the rate of p */" in header
    py, c = tmp_path / "py.csv", tmp_path / "c.csv"
    assert skigen("run", MODEL, str(recording), "--filter", "ukf", "--out", str(py)).returncode == 0
    r = skigen("run", MODEL, str(recording), "--filter", "ukf", "--backend", "c", "--out", str(c))
    assert r.returncode == 0, r.stderr
    a = np.genfromtxt(py, delimiter=",", skip_header=1)
    b = np.genfromtxt(c, delimiter=",", skip_header=1)
    np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12, equal_nan=True)


def test_run_reads_a_mapped_log_in_ms_and_says_what_happened(tmp_path):
    sim = simulate(seed=0, duration=4.0)
    keep = (sim.t < 1.5) | (sim.t >= 2.1)    # a 0.6 s hole (the UKF inside SKI predicts ~0.75 s open loop)
    path = tmp_path / "log.csv"
    write_recording(path, np.round(sim.t[keep] * 1000), {"cmd": sim.delta[keep]}, {"roll": sim.phi[keep]},
                    extra={"mode": np.zeros(keep.sum())})
    out = tmp_path / "r.csv"
    r = skigen("run", MODEL, str(path), "--filter", "ski", "--map", "delta=cmd", "--map", "phi=roll",
               "--time-unit", "auto", "--max-gap", "0.5", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "time unit: ms (auto" in r.stdout
    assert "1 hole(s) longer than the maximum gap:\n  1.48–2.1 s (0.62 s) without cmd, roll" in r.stdout
    assert "final ± 2σ" in r.stdout and "kept" in r.stdout and "w_theta3" in r.stdout
    assert "mean NIS" in r.stdout and "expected 1.000" in r.stdout
    rows = list(csv.reader(open(out)))
    assert len(rows) == 1 + 201 and rows[0][20:22] == ["status", "measured_phi"]
    assert rows[1 + 80][20:22] == ["bad_input", "0"] and rows[1][20:22] == ["measured", "1"]   # the input unknown
    r = skigen("run", MODEL, str(path), "--map", "delta=cmd", "--map", "phi=roll", "--out", str(out))
    assert r.returncode == 2 and "is the time in ms?" in r.stderr and "Traceback" not in r.stderr
    r = skigen("run", MODEL, str(path), "--map", "delta", "--out", str(out))
    assert r.returncode == 2 and "expected NAME=COLUMN" in r.stderr


def test_bench_import_errors_are_shown_as_such(monkeypatch, capsys):
    import importlib

    from skigen import cli

    def broken(name):
        raise ModuleNotFoundError("No module named 'examples'", name="examples")
    monkeypatch.setattr(importlib, "import_module", broken)
    assert cli.main(["bench", "diagnose"]) == 2
    assert "benchmark 'diagnose' failed to import: No module named 'examples'" in capsys.readouterr().err


def test_every_benchmark_imports_outside_the_repository(tmp_path):
    from skigen.cli import BENCHMARKS

    code = "import importlib\n" + "".join(f"importlib.import_module('benchmarks.{b}')\n" for b in BENCHMARKS)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("prefix, why", [("_x", "it does not start with a letter"),
                                         ("a__b", "it has two underscores in a row"),
                                         ("x_", "it ends with '_'")])
def test_generate_refuses_a_prefix_casadi_cannot_use(tmp_path, prefix, why):
    """The prefix names CasADi Functions (`<prefix>_kernel`): refused before anything is derived,
    by the CLI and by emit_c, with the rule it breaks."""
    from models.wingrock import build
    from skigen import derive
    from skigen.emit import emit_c

    r = skigen("generate", MODEL, "--filter", "ekf", "--prefix", prefix, "--out", str(tmp_path / "gen"))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"prefix '{prefix}' cannot name CasADi Functions: {why}" in r.stderr, r.stderr
    assert not (tmp_path / "gen").exists()
    with pytest.raises(ValueError, match=f"prefix '{prefix}' cannot name CasADi Functions: {why}"):
        emit_c(derive(build(), "ekf"), tmp_path / "emit", prefix=prefix)


@pytest.mark.parametrize("prefix", ["math", "stdio", "main"])
def test_a_prefix_that_would_hide_a_standard_header_is_refused(prefix):
    """`--prefix math` wrote math.h, which hid <math.h> from the generated code: it did not compile."""
    from skigen.emit.c import check_prefix
    with pytest.raises(ValueError, match=f"prefix '{prefix}' would name the generated header '{prefix}.h'"):
        check_prefix(prefix)
    assert check_prefix("math_ekf") == "math_ekf"


@pytest.mark.parametrize("prefix", ["pp_model", "wingrock_ukf_kernel"])
def test_a_prefix_named_like_another_filter_s_part_is_refused(prefix):
    """`--prefix pp_model` wrote pp_model.h, the header `--prefix pp --style loops` writes for its
    model: the two in one folder overwrote each other and a unity build failed."""
    from skigen.emit.c import check_prefix
    with pytest.raises(ValueError, match=f"prefix '{prefix}' would name its files like a part of filter"):
        check_prefix(prefix)
    assert check_prefix("modeled") == "modeled"


@pytest.mark.parametrize("prefix", ["casadi", "casadi_ukf"])
def test_a_prefix_casadi_takes_for_its_own_is_refused(prefix):
    """`--prefix casadi` (or a model named 'casadi', whose default prefix is casadi_ukf) named the
    kernel casadi_…_kernel, which CasADi's generator made static: the C did not link."""
    from skigen.emit.c import check_prefix
    with pytest.raises(ValueError, match=f"prefix '{prefix}' would name the kernel '{prefix}_kernel', which CasADi"):
        check_prefix(prefix)
    assert check_prefix("casadix") == "casadix"


def test_a_prefix_too_long_for_a_file_name_and_an_empty_out_are_refused(capsys):
    """A 250-character prefix failed with a raw CasADi stream error (its file names passed 255
    characters); `--out ''` wrote into the current folder without a word."""
    from skigen.cli import main
    from skigen.emit.c import check_prefix
    with pytest.raises(ValueError, match="has 250 characters: the files it names"):
        check_prefix("a" * 250)
    assert main(["generate", "models/wingrock.py", "--filter", "ekf", "--out", ""]) == 2
    assert "--out is empty" in capsys.readouterr().err


def test_an_out_of_the_wrong_kind_is_refused_before_any_work(tmp_path, capsys):
    """`run --out DIR` ran 10⁶ rows, then failed renaming its 365 MB partial file onto the folder;
    `generate --out afile.txt` said "[Errno 17] File exists"."""
    from skigen.cli import main
    afile = tmp_path / "afile.txt"
    afile.write_text("x")
    for argv, said in ((["run", "models/wingrock.py", "missing.csv", "--out", str(tmp_path)], "is a folder; give the "
                        "name of the CSV file to write"),
                       (["generate", "models/wingrock.py", "--out", str(afile)], "is a file; give a folder"),
                       (["run", "models/wingrock.py", "missing.csv", "--out", str(afile / "r.csv")],
                        f"{afile} is a file, not a folder")):
        assert main(argv) == 2
        assert said in capsys.readouterr().err, argv


@pytest.mark.parametrize("origin, noted", [(5e5, True), (0.0, False)])
def test_a_float_build_of_a_state_far_from_its_origin_is_noted(tmp_path, origin, noted):
    """A position 500 km from its origin with a 1 m std: float rounds it to 0.03 m, and a user's
    float UKF diverged with every step's code normal. `generate --real float` says so and how to
    avoid it; at the origin, or in double, nothing is said."""
    spec = tmp_path / "rail.py"
    spec.write_text("from skigen import Model\nmodel = Model('rail', dt=0.1)\n"
                    f"x = model.state('x', std=1.0, initial={origin!r}, process_std=0.01)\n"
                    "v = model.state('v', std=1.0, process_std=0.01)\na = model.input('a')\n"
                    "model.dynamics({x: v, v: a})\nmodel.output('gps', x, noise_std=0.5)\n")
    for real in ("float", "double"):
        r = skigen("generate", str(spec), "--filter", "ukf", "--real", real, "--out", str(tmp_path / real))
        assert r.returncode == 0, r.stderr
        said = "note: in float, 'x' starts more than 1000 declared std from 0 ('x' at 5e+05 with std 1)" in r.stderr
        assert said == (noted and real == "float"), r.stderr


def test_run_and_generate_estimate_a_declared_parameter_online(tmp_path):
    """--estimate augments a declared parameter into the state (the batch command had it; run and
    generate refused it as an unknown argument): a first-order lag's rate a = 2 (declared 1 ± 1)
    is read within its error bars, the C build of the same filter writes the same table, and a
    parameter without a std, or without a name, is a one-line error."""
    rng = np.random.default_rng(4)
    t = np.arange(1500) * 0.01
    u = np.sign(np.sin(2 * np.pi * t / 3))
    x, xs = 0.0, []
    for uk in u:
        xs.append(x)
        x += 0.01 * (-2.0 * x + uk)
    write_recording(tmp_path / "lag.csv", t, {"u": u}, {"y": np.array(xs) + 0.01 * rng.standard_normal(len(t))})
    (tmp_path / "lag.py").write_text(
        "from skigen import Model\nmodel = Model('lag', dt=0.01, discretization='euler')\n"
        "x = model.state('x', unit='V', std=0.1, process_std=1e-4)\nu = model.input('u', unit='V')\n"
        "a = model.parameter('a', 1.0, unit='1/s', std=1.0)\nb = model.parameter('b', 1.0, unit='1/s')\n"
        "model.dynamics({x: -a * x + b * u})\nmodel.output('y', x, unit='V', noise_std=0.01)\n")
    lag, data = str(tmp_path / "lag.py"), str(tmp_path / "lag.csv")
    tables = {}
    for backend in ("python", "c"):
        out = tmp_path / f"{backend}.csv"
        r = skigen("run", lag, data, "--filter", "ukf", "--estimate", "a", "--backend", backend, "--out", str(out))
        assert r.returncode == 0, r.stderr
        assert "(estimated online)" in r.stdout
        tables[backend] = np.genfromtxt(out, delimiter=",", names=True)
    a, std = tables["python"]["a"][-1], tables["python"]["std_a"][-1]
    assert abs(a - 2.0) < 3 * std < 0.1, (a, std)
    np.testing.assert_allclose(tables["c"]["a"], tables["python"]["a"], rtol=1e-9)
    r = skigen("generate", lag, "--filter", "ekf", "--estimate", "a", "--out", str(tmp_path / "gen"))
    assert r.returncode == 0 and "#define LAG_EKF_Z_A 1" in (tmp_path / "gen" / "lag_ekf.h").read_text(), r.stderr
    for name, said in (("b", "parameter 'b' is estimated online but declares no std"),
                       ("c", "model 'lag' has no parameter 'c' (parameters: a, b)")):
        r = skigen("run", lag, data, "--filter", "ukf", "--estimate", name, "--out", str(tmp_path / "x.csv"))
        assert r.returncode != 0 and said in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_run_without_filter_takes_ski_for_unknown_terms_else_the_ukf(recording, tmp_path):
    """`skigen run` (and generate, batch) defaulted to SKI, so a model without unknown terms failed
    with 'SKI needs basis weights' unless --filter was given: now the UKF runs it."""
    plain = tmp_path / "plain.py"
    plain.write_text("from skigen import Model\nmodel = Model('plain', dt=0.02)\n"
                     "theta = model.state('theta', std=1.0, process_std=0.01)\n"
                     "p = model.state('p', std=1.0, process_std=0.01)\ndelta = model.input('delta')\n"
                     "model.dynamics({theta: p, p: -2 * theta - p + delta})\n"
                     "model.output('phi', theta, noise_std=0.1)\n")
    for model, kind in ((MODEL, "ski"), (str(plain), "ukf")):
        r = skigen("run", model, str(recording), "--out", str(tmp_path / f"{kind}.csv"))
        assert r.returncode == 0 and f" {kind} (python)" in r.stdout, (r.stdout, r.stderr)
