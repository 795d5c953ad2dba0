"""The emitted C library: equal to the derived step, guarded against bad data, portable.

Every test runs on each kernel: the unrolled EKF, UKF and SKI and the looped UKF and SKI
(``ukf_loops``, ``ski_loops``: the same filters, the algebra written as C loops).

Float builds are held to FLOAT_RTOL of the state scale against the double Python step on
the 750-sample WingRock run (measured max |z_float - z_double| / max(|z|, 1): EKF 1.3e-4,
UKF 4e-5, SKI 1.1e-5) and to FLOAT_IN_STD of the posterior standard deviation (measured:
EKF 0.024, UKF 0.0006, SKI 0.0012), i.e. the rounding is far below the filter's own doubt.
"""
import dataclasses
import os
import re
import shutil
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from models.wingrock import build
from models.wingrock_sim import simulate
from skigen import derive
from skigen.emit import CFilter, Status, compile_shared, emit_c
from skigen.recording import Recording
from skigen.runtime import PythonStepper, run
from skigen.emit.c import DEFAULT_FLAGS
from skigen.guard import Guard

VARIANTS = {"ekf": ("ekf", "unrolled"), "ukf": ("ukf", "unrolled"), "ski": ("ski", "unrolled"),
            "ukf_loops": ("ukf", "loops"), "ski_loops": ("ski", "loops")}    # name: (kind, style)
KINDS = tuple(VARIANTS)
REALS = ("double", "float")
RTOL = 1e-9
FLOAT_RTOL = 1e-3
FLOAT_IN_STD = 0.1
FLOAT_STRICT = ("-Wdouble-promotion", "-Wfloat-conversion")   # no silent double maths
M7 = ("-mcpu=cortex-m7", "-mthumb", "-mfpu=fpv5-d16", "-mfloat-abi=hard")
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "flight_computer"
DOUBLE_MATHS = {"sqrt", "cbrt", "exp", "expm1", "log", "log1p", "log2", "log10", "pow", "fabs",
                "fmax", "fmin", "fmod", "floor", "ceil", "round", "trunc", "hypot", "erf",
                "sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh"}
APT = {"aarch64-linux-gnu-gcc": "gcc-aarch64-linux-gnu",
       "arm-none-eabi-gcc": "gcc-arm-none-eabi libnewlib-arm-none-eabi",
       "qemu-aarch64": "qemu-user"}


def _need(*tools):
    """Skip without a cross toolchain; in CI (CI=true) its absence is a failure."""
    for tool in tools:
        if shutil.which(tool) is None:
            why = f"{tool} not installed: apt-get install -y {APT[tool]}"
            if os.environ.get("CI") == "true":
                pytest.fail(f"CI=true: {why}")
            pytest.skip(why)


def _parallel(fn, items):
    with ThreadPoolExecutor(os.cpu_count() or 2) as ex:
        return list(ex.map(fn, items))


def _run(cmd, **kw):
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))}\n{r.stdout}{r.stderr}"
    return r.stdout


def _close(a, b, rtol=RTOL):
    a, b = np.asarray(a, float), np.asarray(b, float)
    np.testing.assert_allclose(a, b, rtol=0, atol=rtol * max(np.abs(b).max(initial=0.0), 1.0))


@pytest.fixture(scope="module")
def filters():
    derived = {kind: derive(build(), kind) for kind, _ in VARIANTS.values()}
    return {v: derived[kind] for v, (kind, _) in VARIANTS.items()}


@pytest.fixture(scope="module")
def emitted(filters, tmp_path_factory):
    root = tmp_path_factory.mktemp("emit")
    return {(v, r): emit_c(filters[v], root / f"{v}_{r}", r, style=VARIANTS[v][1]) for v in KINDS for r in REALS}


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("cache")


@pytest.fixture(scope="module")
def libs(emitted, cache):
    """Every emitted library built for the host with -Werror (float: no double promotion)."""
    keys = list(emitted)
    build_one = lambda key: compile_shared(emitted[key], cache_dir=cache,
                                           flags=DEFAULT_FLAGS + (FLOAT_STRICT if key[1] == "float" else ()))
    return dict(zip(keys, _parallel(build_one, keys)))


@pytest.fixture(scope="module")
def record():
    """A 751-sample closed-loop WingRock flight: 750 steps are run."""
    return simulate(seed=0, duration=15)


def _c(libs, filters, kind, real="double", gate=0.0):
    """The library through ctypes; the kernel's equality tests run it without the innovation gate
    (the derived step has none: tests/test_guard.py holds the gate to the reference)."""
    cf = CFilter(libs[kind, real], filters[kind], real)
    cf.configure(gate=gate)
    return cf


def _py_step(d, st, u, y):
    """The derived CasADi step from state dict ``st``: (outputs, next state)."""
    y = np.asarray(y, float)
    valid = np.isfinite(y)
    args = dict(z=st["z"], C=st["C"], u=u, mem=st["mem"], y=np.where(valid, y, 0.0),
                valid=valid.astype(float))
    if d.kind == "ski":
        args["s"] = st["s"]
    r = {k: np.array(v) for k, v in d.step(**args).items()}
    nxt = dict(z=r["z_next"].ravel(), C=r["C_next"], mem=r["mem_next"].ravel())
    if d.kind == "ski":
        nxt["s"] = r["s_next"].ravel()
    return r, nxt


def _c_state(cf):
    st = dict(z=cf.z, C=cf.C, mem=cf.mem)
    if cf.kind == "ski":
        st["s"] = cf.s
    return st


def _measurement(record, k):
    return np.nan if k % 7 == 3 else record.phi[k]          # some samples not measured


# ---------------------------------------------------------------- equality with the derived step

@pytest.mark.parametrize("kind", KINDS)
def test_double_matches_python_step_and_run(kind, filters, libs, record):
    d, cf = filters[kind], _c(libs, filters, kind)
    ours = d.initial()
    for name, v in ours.items():
        _close(cf.get(name), v)
    for k in range(750):
        u, y = [record.delta[k]], [_measurement(record, k)]
        prior = _c_state(cf)
        code = cf.step(u, y)
        assert code == (Status.MEASUREMENT_SKIPPED if np.isnan(y[0]) else Status.OK)
        # Per step: the Python step from the C prior gives the C results.
        r, nxt = _py_step(d, prior, u, y)
        for name in ("z_post", "C_post", "e", "Pyy", "nis", "loglik"):
            _close(cf.get(name), np.reshape(r[name], cf.shapes[name]))
        # Whole run: Python fed its own previous state stays on the C trajectory.
        r_own, ours = _py_step(d, ours, u, y)
        _close(cf.z_post, r_own["z_post"].ravel())
        for name, v in nxt.items():
            _close(cf.get(name), v)
            _close(cf.get(name), ours[name])
    sd = cf.std()
    C = cf.C_post
    _close(sd, np.sqrt(np.diag(C @ C.T)) if d.square_root else np.sqrt(np.diag(C)))


@pytest.mark.parametrize("kind", KINDS)
def test_float_tracks_double(kind, filters, libs, record):
    d, cf = filters[kind], _c(libs, filters, kind, "float")
    ours, worst, worst_in_std = d.initial(), 0.0, 0.0
    for k in range(750):
        u, y = [record.delta[k]], [_measurement(record, k)]
        cf.step(u, y)
        r, ours = _py_step(d, ours, u, y)
        ref, C = r["z_post"].ravel(), r["C_post"]
        std = np.sqrt(np.diag(C @ C.T) if d.square_root else np.diag(C))
        worst = max(worst, np.abs(cf.z_post - ref).max() / max(np.abs(ref).max(), 1.0))
        worst_in_std = max(worst_in_std, (np.abs(cf.z_post - ref) / std).max())
    assert worst < FLOAT_RTOL, f"float posterior off by {worst:.2e} of the state scale"
    assert worst_in_std < FLOAT_IN_STD, f"float posterior off by {worst_in_std:.2e} posterior stds"
    assert cf.z_post.dtype == np.float32


@pytest.fixture(scope="module")
def long_record():
    return simulate(seed=1, duration=2000)          # 100001 samples, bounded by the PID loop


@pytest.mark.parametrize("kind", KINDS)
def test_float_long_run_stays_finite(kind, filters, libs, long_record):
    """With the default gate: the UKF and SKI are consistent (no sample gated in 100 001); the
    EKF's linearisation is over-confident early in the run (|e| up to 9.9 sd at k = 478-491, in
    double too), which the gate rejects and recovers from with a few restarts."""
    cf, rec = _c(libs, filters, kind, "float", gate=5.0), long_record
    codes = np.bincount([cf.step((u,), (y,)) for u, y in zip(rec.delta.tolist(), rec.phi.tolist())],
                        minlength=len(Status))
    gated = codes[Status.OUTLIER_REJECTED] + codes[Status.REINITIALISED]
    assert codes[Status.OK] + gated == rec.n, f"codes {codes}"
    assert gated == 0 if kind != "ekf" else gated < 400, f"codes {codes}"
    for name in cf.shapes:
        assert np.all(np.isfinite(cf.get(name))), name
    assert abs(cf.z_post[0] - rec.theta[-1]) < 1.0            # still tracks the roll angle
    assert np.all(cf.std() > 0) and np.all(cf.std() < 10)


def test_run_c_equals_python_runtime(filters, libs, cache, record):
    y = np.array([_measurement(record, k) for k in range(record.n)])
    rec = Recording("sim", record.t, record.delta[:, None], y[:, None], ("delta",), ("phi",))
    ours = run(filters["ski"], rec, backend="c", cache_dir=cache, show_progress=False)
    theirs = run(filters["ski"], rec, show_progress=False)
    np.testing.assert_array_equal(ours.code, theirs.code)
    for name in ("mean", "std", "innovation", "innovation_var", "nis", "loglik", "prior_var", "final_cov"):
        a, b = getattr(ours, name), getattr(theirs, name)
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=name)
        _close(np.nan_to_num(a), np.nan_to_num(b))


# ----------------------------------------------------------------------------------- guards

def _warm(cf, record, n=20):
    for k in range(n):
        cf.step([record.delta[k]], [record.phi[k]])


def _fields(cf):
    return {name: cf.get(name) for name in cf.shapes if not name.endswith("_next")}


@pytest.mark.parametrize("kind", KINDS)
def test_missing_measurement_skips_update_but_predicts(kind, filters, libs, record):
    d, cf = filters[kind], _c(libs, filters, kind)
    _warm(cf, record)
    prior = _c_state(cf)
    assert cf.step([1.5], [np.nan]) == Status.MEASUREMENT_SKIPPED
    r, nxt = _py_step(d, prior, [1.5], [np.nan])
    # The posterior is the prior mean (for SKI: the prior after its ARD re-weighing, which
    # runs every step, as in the derived step).
    _close(cf.z_post, prior["z"] if d.kind != "ski" else r["z_post"].ravel())
    assert cf.e[0] == 0 and cf.nis == 0 and cf.loglik == 0
    _close(cf.z, nxt["z"])
    assert not np.allclose(cf.z, prior["z"])                 # it did predict


@pytest.mark.parametrize("bad", [np.nan, np.inf])
@pytest.mark.parametrize("kind", KINDS)
def test_a_bad_input_is_held_and_the_step_goes_on(kind, bad, filters, libs, record):
    """A non-finite input: the state is predicted with the last finite input and no reading is
    used, every field as a step with that input and no reading, and the state stays in step with
    the vehicle (before, the step was skipped: the state a sample behind from then on, its
    readings gated, and restarted 25 samples later); the Python stepper the same."""
    a, b = _c(libs, filters, kind), _c(libs, filters, kind)
    py = PythonStepper(filters[kind])
    py.configure(dataclasses.replace(Guard(), gate=0.0))
    for cf in (a, b):
        _warm(cf, record)
    for k in range(20):
        py.step([record.delta[k]], [record.phi[k]])
    assert a.step([bad], [record.phi[20]]) == Status.BAD_INPUT == py.step([bad], [record.phi[20]])
    assert b.step([record.delta[19]], [np.nan]) == Status.MEASUREMENT_SKIPPED
    for name, v in _fields(a).items():
        np.testing.assert_array_equal(v, _fields(b)[name], err_msg=name)
    _close(py.z, a.z)
    codes = [a.step([record.delta[k]], [record.phi[k]]) for k in range(21, 60)]
    assert codes == [Status.OK] * len(codes)


@pytest.mark.parametrize("real", REALS)
@pytest.mark.parametrize("kind", KINDS)
def test_numerical_failure_is_rejected(kind, real, filters, libs, record):
    """P not positive definite (EKF) or an overflowing factor S: the step is rejected."""
    cf = _c(libs, filters, kind, real)
    _warm(cf, record)
    n, huge = cf.n, 1e300 if real == "double" else 1e30
    cf.set("C", huge * np.eye(n) if filters[kind].square_root else -np.eye(n))
    before = _fields(cf)
    assert cf.step([1.0], [0.5]) == Status.NUMERICAL_FAILURE
    after = _fields(cf)
    for name in ("z", "C", "s", "mem"):
        if name in before:
            np.testing.assert_array_equal(after[name], before[name], err_msg=name)
    np.testing.assert_array_equal(cf.z_post, cf.z)
    np.testing.assert_array_equal(cf.C_post, cf.C)
    assert cf.e[0] == cf.Pyy[0, 0] == cf.nis == cf.loglik == 0
    for name, v in after.items():
        assert np.all(np.isfinite(v)), name
    cf.set("C", filters[kind].initial()["C"])                # recovers once C is sane again
    assert cf.step([1.0], [0.5]) == Status.OK


@pytest.mark.parametrize("kind", KINDS)
def test_bad_settings_do_nothing_until_fixed(kind, filters, libs, record):
    """R_sqrt's diagonal 0 (R singular): the step returns BAD_SETTINGS and leaves every byte of the
    state as it was; with R_sqrt restored the run goes on as one that never had the bad setting."""
    a, b = _c(libs, filters, kind), _c(libs, filters, kind)
    for cf in (a, b):
        _warm(cf, record)
    R = a.setting("R_sqrt")
    a.configure(R_sqrt=0 * R)
    assert a.settings_check() == "R_sqrt"
    before = bytes(a._buf)
    for k in range(20, 23):
        assert a.step([record.delta[k]], [record.phi[k]]) == Status.BAD_SETTINGS
        assert bytes(a._buf) == before
    a.configure(R_sqrt=R)
    assert a.settings_check() is None
    for k in range(20, 60):
        code = a.step([record.delta[k]], [record.phi[k]])
        assert code == b.step([record.delta[k]], [record.phi[k]])
        assert bytes(a._buf) == bytes(b._buf), k           # every field, counter and work buffer
    assert code == Status.OK


@pytest.mark.parametrize("kind", KINDS)
def test_reset_refuses_an_invalid_start(kind, filters, libs, record):
    """A NaN in z0 or on C0's diagonal, a negative variance, for S an entry above the diagonal, for P
    one not symmetric or not positive semi-definite: ValueError, the state unchanged (its scratch
    aside); a valid start is then taken."""
    d, cf = filters[kind], _c(libs, filters, kind)
    _warm(cf, record)
    z0, C0 = d.initial()["z"], d.initial()["C"]
    bad_C = [np.where(np.eye(cf.n, dtype=bool) & (np.arange(cf.n) == 1), np.nan, C0), C0 - 2 * np.diag(np.diag(C0))]
    if d.square_root:
        bad_C.append(C0 + np.triu(np.full_like(C0, 1e-3), 1))
    else:                                                   # correlation 10: indefinite (a user's probe)
        indefinite = C0.copy()
        indefinite[0, 1] = indefinite[1, 0] = 10 * np.sqrt(C0[0, 0] * C0[1, 1])
        bad_C += [indefinite, C0 + np.triu(np.full_like(C0, 1e-3), 1)]        # and one not symmetric
    state = lambda: {**_fields(cf), **{name: cf.get(name) for name in cf.counters}}
    before = state()
    with pytest.raises(ValueError, match="z0 has a non-finite entry"):
        cf.reset(np.where(np.arange(cf.n) == 0, np.nan, z0))
    for C in bad_C:
        with pytest.raises(ValueError, match="reset refused: C0 is not a"):
            cf.reset(z0, C)
    for name, v in state().items():
        np.testing.assert_array_equal(v, before[name], err_msg=name)
    shifted = z0 + np.eye(cf.n)[0]
    cf.reset(shifted, C0)
    assert np.array_equal(cf.z, shifted) and np.array_equal(cf.C, C0)
    assert cf.step([record.delta[0]], [record.phi[0]]) == Status.OK


@pytest.mark.parametrize("real", REALS)
@pytest.mark.parametrize("kind", ["ski", "ski_loops"])
def test_ski_reset_keeps_the_weights_within_their_prior(kind, real, filters, libs, record):
    """The EM update needs P_ww <= diag(s0): a start with the weights' factor 1.5x the declared one
    (accepted before, then every step failed) is refused by C and Python alike, fields unchanged; a
    saved posterior and a narrower start are taken; a random walk on the weights set at run time
    is refused by settings_check (the step was generated for constant weights)."""
    d, cf = filters[kind], _c(libs, filters, kind, real)
    _warm(cf, record)
    z0, C0, nx = d.initial()["z"], d.initial()["C"], d.aug.shapes["nx"]
    wide, narrow = C0.copy(), C0.copy()
    wide[nx:, nx:] *= 1.5
    narrow[nx:, nx:] *= 0.999
    before = _fields(cf)
    for reset in (cf.reset, PythonStepper(d).reset):
        with pytest.raises(ValueError, match=r"not within the ARD prior, P_ww <= diag\(s0\)"):
            reset(z0, wide)
    for name, v in _fields(cf).items():
        np.testing.assert_array_equal(v, before[name], err_msg=name)
    cf.reset(cf.z, cf.C)                                     # the posterior after 20 steps
    cf.reset(z0, narrow)
    codes = [cf.step([record.delta[k]], [record.phi[k]]) for k in range(100)]
    assert codes.count(Status.OK) == 100
    Q = cf.setting("Q_sqrt")
    Q[nx + 1, nx + 1] = 1e-3
    cf.configure(Q_sqrt=Q)
    assert cf.settings_check() == "Q_sqrt"
    assert cf.step([record.delta[100]], [record.phi[100]]) == Status.BAD_SETTINGS


# ---------------------------------------------------------------------------- generated text

@pytest.mark.parametrize("style", ["unrolled", "loops"])
def test_emission_is_deterministic_and_path_free(style, filters, tmp_path):
    a = emit_c(filters["ski"], tmp_path / "a", "float", style=style)
    b = emit_c(filters["ski"], tmp_path / "b", "float", style=style)
    names = ["wingrock_ski.h", "wingrock_ski.c", "wingrock_ski_kernel.c", "wingrock_ski_kernel.h"]
    names += ["wingrock_ski_model.c", "wingrock_ski_model.h"] if style == "loops" else []
    assert sorted(p.name for p in a) == sorted(names)
    for p, q in zip(a, b):
        assert p.read_bytes() == q.read_bytes()
        assert str(tmp_path) not in p.read_text()
        if p.suffix == ".c":
            code = p.read_text()
            assert not re.search(r"\b(sqrt|exp|log|fabs|fmax|fmin|expm1|log1p)\(", code), p.name
            assert not re.search(r"(?<![\w.])\d+\.\d*(e[+-]?\d+)?(?![\w.])", code), p.name  # float literals


def test_a_full_disk_leaves_no_half_filter_and_names_the_file(filters, tmp_path, monkeypatch):
    """Out of space while writing the .c, generate left the header written and said only
    "[Errno 28] No space left on device": the files are written whole or not at all."""
    import errno
    write = Path.write_text

    def full(self, text, *args, **kwargs):
        if self.name.endswith(".c.partial") and "kernel" not in self.name:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return write(self, text, *args, **kwargs)
    monkeypatch.setattr(Path, "write_text", full)
    with pytest.raises(OSError, match=r"cannot write .*wingrock_ekf\.c: No space left on device"):
        emit_c(filters["ekf"], tmp_path / "gen", "double")
    assert list((tmp_path / "gen").iterdir()) == []


def test_filters_link_into_one_program(filters, emitted, tmp_path):
    """Three kinds, a looped float SKI and a float copy under other prefixes in one binary,
    headers together."""
    f32 = emit_c(filters["ski"], tmp_path / "f32", "float", prefix="wingrock_ski_f32")
    loops = emit_c(filters["ski"], tmp_path / "loops", "float", prefix="wingrock_ski_loops", style="loops")
    sources = [p for k in ("ekf", "ukf", "ski") for p in emitted[k, "double"]] + f32 + loops
    main = tmp_path / "main.c"
    main.write_text("""#include <stdio.h>
#include "wingrock_ekf.h"
#include "wingrock_ukf.h"
#include "wingrock_ski.h"
#include "wingrock_ski_f32.h"
#include "wingrock_ski_loops.h"
int main(void)
{
    static wingrock_ekf_state a; static wingrock_ukf_state b;
    static wingrock_ski_state c; static wingrock_ski_f32_state d; static wingrock_ski_loops_state e;
    double u = 1.0, y = 0.1; float uf = 1.0f, yf = 0.1f;
    wingrock_ekf_init(&a); wingrock_ukf_init(&b); wingrock_ski_init(&c); wingrock_ski_f32_init(&d);
    wingrock_ski_loops_init(&e);
    printf("%d %d %d %d %d\\n", wingrock_ekf_step(&a, &u, &y), wingrock_ukf_step(&b, &u, &y),
           wingrock_ski_step(&c, &u, &y), wingrock_ski_f32_step(&d, &uf, &yf),
           wingrock_ski_loops_step(&e, &uf, &yf));
    return 0;
}
""")
    dirs = sorted({f"-I{p.parent}" for p in sources})
    exe = tmp_path / "together"
    _run(["gcc", *(f for f in DEFAULT_FLAGS if not f.startswith("-O")), "-O0", *dirs, main, *[p for p in sources if p.suffix == ".c"],
          "-o", exe, "-lm"])
    assert _run([exe]).split() == ["0"] * 5
    # As one translation unit (a unity build): each file's statics, typedefs and macros stay its own
    # (every file's `real`, `copy_n` and CasADi's macros clashed; a float kernel took a double one's type).
    unity = tmp_path / "unity.c"
    unity.write_text("".join(f'#include "{p}"\n' for p in sources if p.suffix == ".c") + main.read_text())
    _run(["gcc", *(f for f in DEFAULT_FLAGS if not f.startswith("-O")), "-O0", *dirs, unity, "-o", exe, "-lm"])
    assert _run([exe]).split() == ["0"] * 5


# --------------------------------------------------------------------------- cross toolchains

GENERATED = Path(__file__).resolve().parents[1] / "generated"
GENERATED_SOURCES = sorted(GENERATED.glob("*/*.c"))


def _cross_objects(cc, flags, out):
    """Compile every checked-in generated source (tests/test_generated.py keeps them current)."""
    jobs = [(src.parent.name.rsplit("_", 1)[1], src) for src in GENERATED_SOURCES]

    def one(job):
        real, src = job
        obj = out / f"{src.parent.name}_{src.stem}.o"
        _run([cc, *DEFAULT_FLAGS, *(FLOAT_STRICT if real == "float" else ()), *flags,
              f"-I{src.parent}", "-c", src, "-o", obj])
        return real, obj
    out.mkdir(exist_ok=True)
    return _parallel(one, jobs)


def test_a_missing_cross_toolchain_fails_in_ci(monkeypatch):
    monkeypatch.setitem(APT, "skigen-no-such-cc", "no-such-package")
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match="no-such-package"):
        _need("skigen-no-such-cc")
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="CI=true: skigen-no-such-cc not installed"):
        _need("skigen-no-such-cc")


@pytest.mark.slow
@pytest.mark.parametrize("opt", ["-O2", "-O3", "-Os"])
def test_generated_compiles_for_the_host(opt, tmp_path):
    """At every optimisation level a flight build may use, looped and unrolled kernels (at -O3 gcc
    once refused the looped kernel's triangular solve: -Waggressive-loop-optimizations)."""
    assert len(_cross_objects("gcc", (opt,), tmp_path)) == len(GENERATED_SOURCES) >= 40


def test_a_fast_math_build_stops(emitted):
    """-ffast-math makes isfinite() always true, so a NaN reading (not measured) would be used: a
    user's build with it made every state NaN at the first missing reading, with status OK."""
    source = next(p for p in emitted["ski", "double"] if p.name == "wingrock_ski.c")
    r = subprocess.run(["gcc", "-std=c99", "-ffast-math", "-c", str(source), "-o", os.devnull],
                       capture_output=True, text=True)
    assert r.returncode != 0 and "-fno-finite-math-only" in r.stderr, r.stderr
    _run(["gcc", "-std=c99", "-ffast-math", "-fno-finite-math-only", "-c", source, "-o", os.devnull])


@pytest.mark.slow
def test_cross_compiles_for_aarch64(tmp_path):
    _need("aarch64-linux-gnu-gcc")
    assert len(_cross_objects("aarch64-linux-gnu-gcc", (), tmp_path)) == len(GENERATED_SOURCES)


@pytest.mark.slow
def test_cross_compiles_for_cortex_m7(tmp_path):
    """No heap; float builds call no double maths and hold no double-precision instruction."""
    _need("arm-none-eabi-gcc")
    for real, obj in _cross_objects("arm-none-eabi-gcc", M7, tmp_path):
        undefined = set(_run(["arm-none-eabi-nm", "-u", obj]).split()) - {"U"}
        assert not undefined & {"malloc", "free", "calloc", "realloc"}, obj
        if real == "float":
            assert not undefined & DOUBLE_MATHS, (obj, undefined & DOUBLE_MATHS)
            assert not [s for s in undefined if s.startswith("__aeabi_d")], obj
            assert not re.search(r"\.f64\b", _run(["arm-none-eabi-objdump", "-d", obj])), obj


# ------------------------------------------------------------------------- flight-computer example

def _recording_csv(record, path, n=200):
    rows = ["t,delta,phi"]
    for k in range(n):
        phi = "" if k % 11 == 5 else ("nan" if k % 13 == 6 else repr(float(record.phi[k])))
        rows.append(f"{float(record.t[k])!r},{float(record.delta[k])!r},{phi}")
    path.write_text("\n".join(rows) + "\n")
    return path


def _make_example(gen, out, **make):
    out.mkdir()
    _run(["make", "-s", "-C", EXAMPLE, f"GEN={gen}", f"BUILD={out}", *(f"{k}={v}" for k, v in make.items())])
    return out / "flight_computer"


@pytest.fixture(scope="module")
def example(filters, record, tmp_path_factory):
    """The example built for the host from freshly emitted sources: (gen dir, binary, csv)."""
    root = tmp_path_factory.mktemp("example")
    emit_c(filters["ski"], root / "gen", "double")
    return root / "gen", _make_example(root / "gen", root / "host"), _recording_csv(record, root / "rec.csv")


def _table(text):
    lines = text.strip().splitlines()
    return lines[0].split(","), np.array([[float(v) for v in line.split(",")] for line in lines[1:]])


def test_flight_computer_example_matches_ctypes(example, filters, libs, record):
    """The example starts at the first roll reading (reset), steps with the default settings and
    prints the posterior and code of each row; `-g` sets the gate."""
    _, exe, csv = example
    header, table = _table(_run([exe, csv]))
    assert header == ["t"] + filters["ski"].aug.names + ["code"]
    assert _run([exe], input=csv.read_text()) == _run([exe, csv])          # stdin works too
    n = len(table)
    y = np.array([np.nan if (k % 11 == 5 or k % 13 == 6) else record.phi[k] for k in range(n)])
    cf = _c(libs, filters, "ski", gate=5.0)
    z0 = cf.z
    z0[0] = y[0]
    cf.reset(z0)
    ref = cf.run(record.delta[:n, None], y[:, None])
    _close(table[:, 0], record.t[:n])
    _close(table[:, 1:-1], ref["z_post"])
    np.testing.assert_array_equal(table[:, -1], ref["code"])
    _, ungated = _table(_run([exe, "-g", "0", csv]))
    _close(ungated, table)                               # a clean flight: nothing to gate


def test_flight_computer_example_with_the_looped_kernel(example, filters, tmp_path):
    """The same example built from `--style loops` sources prints the same table."""
    _, host, csv = example
    emit_c(filters["ski"], tmp_path / "gen", "double", style="loops")
    looped = _make_example(tmp_path / "gen", tmp_path / "build")
    h, ours = _table(_run([host, csv]))
    lh, theirs = _table(_run([looped, csv]))
    assert h == lh
    _close(theirs, ours)


def test_flight_computer_example_under_qemu_aarch64(example, tmp_path):
    _need("aarch64-linux-gnu-gcc", "qemu-aarch64")
    gen, host, csv = example
    arm = _make_example(gen, tmp_path / "arm", CC="aarch64-linux-gnu-gcc", LDFLAGS="-static")
    h, host_out = _table(_run([host, csv]))
    a, arm_out = _table(_run(["qemu-aarch64", arm, csv]))
    assert h == a
    _close(arm_out, host_out)


def test_float_ski_stays_close_on_the_delay_model():
    """Float SKI stays within a small fraction of a posterior standard deviation of double
    (with float's ARD floor, single_precision_options) on the ill-conditioned delay model."""
    from benchmarks.common import recording
    from models import wingrock_delay
    from models.wingrock_sim import simulate
    from skigen.emit.c import single_precision_options

    filt = derive(wingrock_delay.build(), "ski")
    rec = recording(simulate(seed=1, delay=6))
    double = run(single_precision_options(filt), rec, backend="c", show_progress=False)
    single = run(filt, rec, backend="c", real="float", show_progress=False)
    assert not np.any(single.code == Status.NUMERICAL_FAILURE)
    assert np.max(np.abs(single.mean - double.mean) / double.std) < 0.01


def test_a_discrete_model_s_weight_is_said_to_enter_the_next_value(tmp_path):
    """The header's index comment said 'times 1 in the rate of Tc' for a discrete model, whose
    unknown term is added to the next value, not to a rate."""
    from skigen import Model
    from skigen.library import polynomial
    m = Model("tank", dt=0.1, discretization="discrete")
    h = m.state("h", unit="m", std=0.1, process_std=0.01)
    m.dynamics({h: 0.9 * h})                                         # h[k+1]
    m.output("h_m", h, unit="m", noise_std=0.01)
    m.unknown(h, polynomial([h], 1), prior_variance=1.0)
    header = next(p for p in emit_c(derive(m, "ski"), tmp_path, "double") if p.name == "tank_ski.h").read_text()
    assert "#define TANK_SKI_Z_W_ONE 1 /* times 1 in the next value of h */" in header, header


def test_files_another_style_left_in_the_folder_are_named(filters, tmp_path):
    """Generating a folder again unrolled left the looped kernel's model files in it without a word:
    dead code in a build of the folder. `generate` names them (``left_over``)."""
    from skigen.emit.c import left_over
    looped = emit_c(filters["ukf"], tmp_path, "double", style="loops")
    assert left_over(looped) == []
    (tmp_path / "notes.txt").write_text("mine")
    unrolled = emit_c(filters["ukf"], tmp_path, "double", style="unrolled")
    assert [p.name for p in left_over(unrolled)] == ["wingrock_ukf_model.c", "wingrock_ukf_model.h"]
