"""Outlier gate, recovery and run-time settings of the generated C and the Python runner.

The policy (skigen/guard.py) against its covariance-form reference (skigen/reference/guard.py
around the reference filters), per step; fault injection through the flight-computer example
in double and float and through the Python runner; the C API's settings, reset, index macros
and prefixes from C.
"""
import re
import subprocess
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from benchmarks import faults as F
from models.wingrock import NOISE_STD, build
from skigen import Model, derive
from skigen.library import polynomial
from skigen.cli import main as cli
from skigen.emit import Status, emit_c
from skigen.emit.c import DEFAULT_FLAGS, load_c
from skigen.guard import Guard
from skigen.recording import Recording
from skigen.reference import guard as ref
from skigen.runtime import PythonStepper, RunResult, iter_run, run
from tests.test_derive_vs_reference import _ref_step

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "flight_computer"
RTOL = 1e-9


def _run(cmd, **kw):
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))}\n{r.stdout}{r.stderr}"
    return r.stdout


def _close(a, b, rtol=RTOL):
    a, b = np.asarray(a, float), np.asarray(b, float)
    np.testing.assert_allclose(a, b, rtol=0, atol=rtol * max(np.abs(b).max(initial=0.0), 1.0))


@pytest.fixture(scope="module")
def sim():
    return F.flight(30_000, seed=2)


# ------------------------------------------------------------------- the policy against the reference

def _reference_run(d, u, y, guard, std_max):
    """The reference filters under the policy as stated (skigen/guard.py), in covariance form."""
    nx, sr = d.aug.shapes["nx"], d.square_root
    st = d.initial()
    z0, P0 = st["z"].copy(), d.aug.P0
    run_, gap, zs, codes = np.zeros(y.shape[1], int), 0, [], []
    for k in range(len(u)):
        valid = np.isfinite(y[k])
        code = Status.OK if valid.all() else Status.MEASUREMENT_SKIPPED
        after_gap = valid.any() and gap >= guard.gap_limit
        recover = valid.any() and (valid & (run_ >= guard.reject_limit)).any()

        def restart():
            P = st["C"] @ st["C"].T if sr else st["C"]
            st["z"], P = ref.restart(st["z"], P, nx, z0, P0, guard.reinit_scale)
            st["C"] = np.linalg.cholesky(P) if sr else P
        if recover:
            restart()
        q = _ref_step(d.kind, d, st, u[k], y[k], valid)
        out = np.zeros_like(valid) if recover else ref.gate_mask(q["e"], q["Pyy"], valid, guard.gate)
        if after_gap and not recover and out.any():            # the prediction lost the vehicle
            recover = True
            restart()
            q = _ref_step(d.kind, d, st, u[k], y[k], valid)
        elif out.any():
            valid = valid & ~out
            q, code = _ref_step(d.kind, d, st, u[k], y[k], valid), Status.OUTLIER_REJECTED
        gap = 0 if valid.any() else gap + 1
        run_ = np.where(valid, 0, run_ + np.isfinite(y[k]))      # per output: its readings refused in a row
        C = q["S"] if sr else q["P"]
        P = ref.bound(C @ C.T if sr else C, std_max)
        st = dict(z=q["z"], C=np.linalg.cholesky(P) if sr else P, mem=st["mem"],
                  **({"s": q["s"]} if "s" in q else {}))
        zs.append(q["z_post"])
        codes.append(Status.REINITIALISED if recover else code)
    return np.array(zs), np.array(codes)


@pytest.mark.parametrize("kind", ["ekf", "ukf", "ski"])
def test_gate_restart_and_bound_match_the_reference(kind, sim):
    """Single absurd readings, a 3-degree offset for longer than reject_limit (a restart onto it,
    gated readings after it, a restart back), a gap longer than gap_limit whose first reading the
    prediction explains (used, no restart), one after which it does not (the input logged as 0
    through it: a restart) and an active std bound on p."""
    d = derive(build(), kind)
    guard = Guard(gap_limit=80)
    std_max = guard.std_max(d.aug.P0)
    std_max[1] = 2.0                                       # caps p's prior std after a restart (10)
    n = 800
    u, y = sim.delta[:n].copy(), sim.phi[:n].copy()
    y[[60, 61, 140]] = [1e4 * NOISE_STD, -1e6 * NOISE_STD, 1e3 * NOISE_STD]
    y[250:290] += 3.0                                      # 40 readings off by 30 noise stds
    y[400:500] = np.nan                                    # 100 samples without a reading
    y[560:660] = np.nan                                    # and 100 more, the input lost too
    u[560:660] = 0.0
    cf = load_c(d)
    cf.configure(guard, std_max=std_max)
    out = cf.run_many(u[:, None], y[:, None])
    z_ref, codes_ref = _reference_run(d, u, y[:, None], guard, std_max)
    np.testing.assert_array_equal(out["code"], codes_ref)
    _close(out["z_post"], z_ref)
    code = out["code"]
    gated = [60, 61, 140, *range(250, 275), *range(290, 315)]
    np.testing.assert_array_equal(np.flatnonzero(code == Status.OUTLIER_REJECTED), gated)
    np.testing.assert_array_equal(np.flatnonzero(code == Status.REINITIALISED), [275, 315, 660])
    assert cf.reinits == 3 and cf.rejected[0] == len(gated)
    assert out["std"][275, 1] == pytest.approx(10.0, rel=1e-6)       # restarted: 10 x its declared std
    assert out["std"][276, 1] <= 2.0                                  # the bound acted on the prior
    # The reading after the first gap is used, with the weights' knowledge: the roll angle is on
    # the truth within 5 noise stds from then until the second gap, and 60 samples after its restart.
    assert code[500] == Status.OK
    assert np.abs(out["z_post"][500:560, 0] - sim.theta[500:560]).max() < 5 * NOISE_STD
    assert np.abs(out["z_post"][720:, 0] - sim.theta[720:n]).max() < 5 * NOISE_STD


@pytest.mark.parametrize("kind,style", [("ekf", "unrolled"), ("ski", "unrolled"), ("ski", "loops")])
def test_a_rejected_reading_never_changes_the_state(kind, style, sim):
    d = derive(build(), kind)
    a, b = load_c(d, style=style), load_c(d, style=style)
    for k in range(300):
        a.step([sim.delta[k]], [sim.phi[k]])
        b.step([sim.delta[k]], [sim.phi[k]])
    assert a.step([1.0], [1e6 * NOISE_STD]) == Status.OUTLIER_REJECTED
    assert b.step([1.0], [np.nan]) == Status.MEASUREMENT_SKIPPED
    for name in a.shapes:
        if name != "y_last":
            np.testing.assert_array_equal(a.get(name), b.get(name), err_msg=name)
    assert list(a.rejected) == [1] and list(b.rejected) == [0] and a.used[0] == 0


def test_python_stepper_equals_c_under_faults(sim):
    """The Python runner follows the C's policy step for step, codes and estimates."""
    d = derive(build(), "ukf")
    faults = [F.Fault("absurd", 1e6, 300, 303), F.Fault("stuck", 200, 500, 700),
              F.Fault("nonfinite", 50, 900, 950), F.Fault("dropout", 600, 1100, 1700)]
    u, y = F.inject(sim.delta[:2000, None], sim.phi[:2000, None], faults, NOISE_STD)
    c = load_c(d).run_many(u, y)
    py = F.run_filter(d, u, y, backend="python")
    np.testing.assert_array_equal(py["code"], c["code"])
    _close(py["z"][np.isfinite(c["z_post"][:, 0])], c["z_post"][np.isfinite(c["z_post"][:, 0])])
    assert set(c["code"]) == {Status.OK, Status.OUTLIER_REJECTED, Status.SENSOR_STUCK, Status.BAD_INPUT,
                              Status.MEASUREMENT_SKIPPED, Status.REINITIALISED, Status.NUMERICAL_FAILURE}


def test_a_limit_of_0_never_restarts(sim):
    """reject_limit = 0 and gap_limit = 0 mean never, as gate = 0 and stuck_limit = 0 mean off (a
    user's 0 used to restart the states at every sample: 2001 of 2001 'recovered', the weights never
    moved); C and Python alike, through absurd readings and a long dropout."""
    d = derive(build(), "ukf")
    u, y = F.inject(sim.delta[:1500, None], sim.phi[:1500, None],
                    [F.Fault("absurd", 1e6, 300, 330), F.Fault("dropout", 600, 700, 1300)], NOISE_STD)
    never = Guard(reject_limit=0, gap_limit=0)
    cf = load_c(d)
    cf.configure(never)
    py = PythonStepper(d)
    py.configure(never)
    c = cf.run_many(u, y)["code"]
    np.testing.assert_array_equal(c, [py.step(u[k], y[k]) for k in range(len(u))])
    assert Status.REINITIALISED not in c and Status.OUTLIER_REJECTED in c and cf.reinits == 0
    assert np.count_nonzero(c[:700] == Status.OK) == 670            # all but the 30 absurd readings


# ----------------------------------------------------------------------------- fault injection

def _example(gen: Path, out: Path) -> Path:
    out.mkdir()
    _run(["make", "-s", "-C", EXAMPLE, f"GEN={gen}", f"BUILD={out}"])
    return out / "flight_computer"


def _csv(path, t, u, y):
    cell = lambda v: "" if np.isnan(v) else repr(float(v))          # an empty reading: not measured
    rows = ["t,delta,phi"] + [f"{float(ti)!r},{float(ui)!r},{cell(yi)}" for ti, ui, yi in zip(t, u, y)]
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("real", ["double", "float"])
def test_fault_injection_through_the_flight_computer(real, sim, tmp_path):
    """Absurd readings of 1e3-1e6 sd, dropouts of 1e2-1e4 samples, a sensor stuck for up to
    3000 samples, NaN/inf inputs and inf readings: the C example's estimate is back within its
    normal error 500 samples after every fault, never NaN, and its codes say what happened.
    (The float build uses the looped kernel: both styles are covered, and it compiles in a second.)"""
    emit_c(derive(build(), "ski"), tmp_path / "gen", real, style="unrolled" if real == "double" else "loops")
    exe = _example(tmp_path / "gen", tmp_path / "build")
    t, u, y = sim.t, sim.delta, sim.phi
    table = lambda csv: np.loadtxt(_run([exe, csv]).splitlines()[1:], delimiter=",")
    clean = table(_csv(tmp_path / "clean.csv", t, u, y))
    truth = np.column_stack([sim.theta, sim.p])
    bound = F.normal_error(clean[:, 1:3] - truth)
    S = Status
    during = {"absurd": {S.OUTLIER_REJECTED},                      # codes while the fault lasts
              "dropout": {S.MEASUREMENT_SKIPPED, S.NUMERICAL_FAILURE},   # long predictions blow up
              "stuck": {S.OK, S.OUTLIER_REJECTED, S.SENSOR_STUCK, S.NUMERICAL_FAILURE},
              "nonfinite": {S.BAD_INPUT, S.NUMERICAL_FAILURE}}   # predicted with the input held: as a dropout
    signature = {"absurd": S.OUTLIER_REJECTED, "dropout": S.MEASUREMENT_SKIPPED, "stuck": S.SENSOR_STUCK,
                 "nonfinite": S.BAD_INPUT}
    for kind in F.FAULTS:
        faults = F.schedule(kind, len(t))
        fu, fy = F.inject(u[:, None], y[:, None], faults, NOISE_STD)
        out = table(_csv(tmp_path / f"{kind}.csv", t, fu[:, 0], fy[:, 0]))
        assert np.all(np.isfinite(out)), kind
        rec = F.recovery(out[:, 1:3] - truth, faults, bound)
        assert all(r is not None and r <= F.RECOVERY for r in rec), (kind, rec)
        codes = out[:, -1].astype(int)
        for f in faults:
            assert set(codes[f.start:f.end]) <= during[kind] and signature[kind] in codes[f.start:f.end], kind
            assert S.NUMERICAL_FAILURE not in codes[f.end + F.RECOVERY:f.end + F.FAULT_SPACING], kind
        assert len(faults) >= (3 if kind != "absurd" else 6)


def test_the_python_runner_recovers_from_each_fault(sim):
    """The same scenarios through skigen.runtime.run (one fault of each type, UKF)."""
    d, n = derive(build(), "ukf"), 3200
    truth = np.column_stack([sim.theta, sim.p])[:n]
    clean = load_c(d).run_many(sim.delta[:n, None], sim.phi[:n, None])     # equal to Python's (above)
    bound = F.normal_error(clean["z_post"][:, :2] - truth)
    for fault in [F.Fault("absurd", 1e6, 1500, 1503), F.Fault("dropout", 1000, 1500, 2500),
                  F.Fault("stuck", 1000, 1500, 2500), F.Fault("nonfinite", 1000, 1500, 2500)]:
        u, y = F.inject(sim.delta[:n, None], sim.phi[:n, None], [fault], NOISE_STD)
        res = run(d, Recording("sim", sim.t[:n], u, y, ("delta",), ("phi",)), show_progress=False)
        stepped = res.code != Status.BAD_INPUT
        assert np.all(np.isfinite(res.mean[stepped])), fault.kind
        assert F.recovery(res.mean[:, :2] - truth, [fault], bound)[0] <= F.RECOVERY, fault.kind
        lines = res.summary().lines()
        assert any(line.startswith("events: ") and "restart" in line or fault.kind == "absurd"
                   for line in lines), lines


# ------------------------------------------------------------------------------- the C API

def _gain_model(gain=3.0, noise=NOISE_STD, process_std=(1e-4, 1e-3)):
    """WingRock with its control gain a declared parameter."""
    model = Model("wr", dt=0.02, discretization="rk4")
    theta = model.state("theta", std=1.0, process_std=process_std[0])
    p = model.state("p", std=1.0, process_std=process_std[1])
    delta = model.input("delta")
    L = model.parameter("L", gain)
    model.dynamics({theta: p, p: L * delta})
    model.output("phi", theta, noise_std=noise)
    model.unknown(p, polynomial([theta, p], 1), prior_variance=1.0)
    return model


@pytest.mark.parametrize("kind,style", [("ski", "unrolled"), ("ukf", "loops"), ("ski", "loops")])
def test_settings_changed_mid_run_equal_a_rebuild(kind, style, sim):
    """Q, R and the parameter L changed between two steps give, from then on, the steps of the
    filter generated from a model declaring them, bit for bit."""
    a = load_c(derive(_gain_model(), kind), style=style)
    other = derive(_gain_model(gain=2.5, noise=0.3, process_std=(1e-3, 1e-2)), kind)
    b = load_c(other, style=style)
    assert a.setting("param")[0] == 3.0 and b.setting("param")[0] == 2.5
    for cf in (a, b):
        cf.configure(gate=0)              # the policy's counters are not copied below
    for k in range(200):
        a.step([sim.delta[k]], [sim.phi[k]])
    Q = b.setting("Q_sqrt")
    Q[0, 1] = 7.0                                          # upper triangle: ignored
    a.configure(Q_sqrt=Q, **{k: b.setting(k) for k in ("R_sqrt", "param")})
    for name in ("z", "C", "mem") + (("s",) if kind == "ski" else ()):
        b.set(name, a.get(name))
    for k in range(200, 400):
        assert a.step([sim.delta[k]], [sim.phi[k]]) == b.step([sim.delta[k]], [sim.phi[k]])
        for name in ("z_post", "C_post", "z", "C", "nis"):
            np.testing.assert_array_equal(a.get(name), b.get(name), err_msg=name)
    _close(b.setting("R_sqrt"), [[0.3]])


def test_settings_check_names_the_first_invalid_field(tmp_path):
    """<prefix>_settings_check returns 1 + the field's index in the struct, in the order the header
    documents; the step refuses while it is nonzero; Status follows the header's enum."""
    d = derive(_gain_model(), "ukf")
    cf = load_c(d)
    header = emit_c(d, tmp_path)[0].read_text()
    assert {k: int(v) for k, v in re.findall(r"SKIGEN_(\w+) = (\d+)", header)} == {s.name: s.value for s in Status}
    order = " ".join(f"{i} {name}" for i, name in enumerate(cf.settings, 1))   # 1 Q_sqrt 2 R_sqrt ...
    assert order in " ".join(re.sub(r"\([^)]*\)|[,*]", " ", header).split()), order
    nan, Q, R = float("nan"), cf.setting("Q_sqrt"), cf.setting("R_sqrt")
    fine = [dict(Q_sqrt=np.where(np.tri(len(Q), dtype=bool), Q, nan)),   # the upper triangle is ignored
            dict(R_sqrt=-R), dict(gate=0), dict(std_max=np.inf), dict(stuck_limit=0)]
    bad = [("Q_sqrt", np.where(np.tri(len(Q), k=-1, dtype=bool), nan, Q)), ("R_sqrt", 0 * R), ("R_sqrt", R + nan),
           ("param", [np.inf]), ("gate", -1.0), ("gate", np.inf), ("reinit_scale", 0.0), ("reinit_scale", nan),
           ("std_max", np.r_[1.0, 0.0, 1, 1, 1]), ("std_max", nan), ("reject_limit", -1), ("gap_limit", -1),
           ("stuck_limit", -1)]
    assert cf.settings_check() is None
    for change in fine:
        keep = {k: cf.setting(k) for k in change}
        cf.configure(**change)
        assert cf.settings_check() is None, change
        cf.configure(**keep)
    for name, value in bad:
        keep = cf.setting(name)
        cf.configure(**{name: value})
        assert cf.settings_check() == name, (name, value)
        assert cf.step([0.1], [0.2]) == Status.BAD_SETTINGS
        cf.configure(**{name: keep})
    assert cf.step([0.1], [0.2]) == Status.OK and cf.since_update == 0


def test_reset_starts_from_the_given_state(sim):
    d = derive(build(), "ski")
    cf, py = load_c(d), PythonStepper(d)
    z0 = d.initial()["z"] + np.r_[2.0, -1.0, 0.1, 0, 0, 0, 0, 0]
    C0 = 0.5 * d.initial()["C"]
    for k in range(50):                                   # some history that the reset must clear
        cf.step([sim.delta[k]], [sim.phi[k]])
    cf.reset(z0, C0)
    py.reset(z0, C0)
    _close(cf.z, z0)
    _close(cf.C_post, C0)
    assert cf.since_update == 0 and not np.any(cf.mem)
    for k in range(100):
        assert cf.step([sim.delta[k]], [sim.phi[k]]) == py.step([sim.delta[k]], [sim.phi[k]])
        _close(cf.z_post, py.z_post)
    cf.reset()                                            # NULL: the declared values
    _close(cf.z, d.initial()["z"])
    _close(cf.C, d.initial()["C"])


def test_python_stepper_refuses_values_of_the_wrong_length(sim):
    """A u, y, z0 or C0 of the wrong length is refused by name; a one-element u on a two-input model
    was broadcast to both inputs and z0 of 3 entries on 4 states failed later inside CasADi."""
    m = Model("two_in", dt=0.01)
    x, v = m.state("x", std=1.0, process_std=0.01), m.state("v", std=1.0, process_std=0.01)
    a, b = m.input("a"), m.input("b")
    m.dynamics({x: v, v: a - b})
    m.output("x_meas", x, noise_std=0.1)
    d = derive(m, "ukf")
    for st in (PythonStepper(d), load_c(d)):
        with pytest.raises(ValueError, match=r"u has 1 value\(s\), the model 'two_in' 2 \(a, b\)"):
            st.step([0.5], [0.0])
        with pytest.raises(ValueError, match=r"y has 2 value\(s\), the model 'two_in' 1 \(x_meas\)"):
            st.step([0.5, 0.0], [0.0, 1.0])
        with pytest.raises(ValueError, match=r"z0 has shape \(3,\); the filter's state has 2 entries \(x, v\)"):
            st.reset(np.zeros(3))
        with pytest.raises(ValueError, match=r"C0 has shape \(1, 1\)"):
            st.reset(None, np.eye(1))
        assert st.step([0.5, 0.0], [0.0]) == Status.OK


MAIN = r"""#include <math.h>
#include <stdio.h>
#include "roll_d.h"
#include "roll_f.h"
int main(void)
{
    static roll_d_state d;
    static roll_f_state f;
    double z0[ROLL_D_N] = {0}, u[ROLL_D_NU], y[ROLL_D_NY];
    float uf[ROLL_F_NU], yf[ROLL_F_NY];
    int k, codes = 0;
    roll_d_init(&d);
    roll_f_init(&f);
    z0[ROLL_D_Z_THETA] = 1.5;
    roll_d_reset(&d, z0, NULL);
    d.settings.R_sqrt[0] = 0.2;                  /* retuned on the vehicle */
    f.settings.gate = 0;
    for (k = 0; k < 200; ++k) {
        u[ROLL_D_U_DELTA] = sin(0.05 * k);
        y[ROLL_D_Y_PHI] = 1.5 + 0.1 * k * ROLL_D_DT;
        uf[ROLL_F_U_DELTA] = (float)u[ROLL_D_U_DELTA];
        yf[ROLL_F_Y_PHI] = (float)y[ROLL_D_Y_PHI];
        codes += roll_d_step(&d, u, y) + roll_f_step(&f, uf, yf);
    }
    printf("%g %d %.6f %.6f %ld %d\n", ROLL_D_DT, codes, d.z_post[ROLL_D_Z_THETA],
           (double)f.z_post[ROLL_F_Z_THETA], d.reinits, ROLL_F_Z_W_THETA3);
    return 0;
}
"""


def test_two_prefixes_link_into_one_binary(tmp_path):
    """`skigen generate --prefix` twice (double, float) and a C main using the index macros,
    DT, reset and the settings of both."""
    for real, prefix in (("double", "roll_d"), ("float", "roll_f")):
        assert cli(["generate", "models.wingrock:model", "--filter", "ukf", "--real", real,
                    "--prefix", prefix, "--out", str(tmp_path / prefix)]) == 0
    (tmp_path / "main.c").write_text(MAIN)
    sources = sorted(tmp_path.glob("roll_*/*.c"))
    exe = tmp_path / "together"
    _run(["gcc", *(f for f in DEFAULT_FLAGS if not f.startswith("-O")), "-O1",
          f"-I{tmp_path / 'roll_d'}", f"-I{tmp_path / 'roll_f'}", tmp_path / "main.c", *sources, "-o", exe, "-lm"])
    dt, codes, theta_d, theta_f, reinits, w_theta3 = _run([exe]).split()
    assert float(dt) == 0.02 and int(codes) == 0 and int(reinits) == 0 and int(w_theta3) == 7
    ramp = 1.5 + 0.1 * 199 * 0.02                         # both follow the measured ramp (1.908, 1.870)
    assert abs(float(theta_d) - ramp) < 0.05 and abs(float(theta_f) - ramp) < 0.05


# ------------------------------------------------------------- several outputs, one of them stale

def _ship(dt=0.1):
    """Heading psi and yaw rate r of a ship, both measured; one unknown damping weight on r."""
    model = Model("ship", dt=dt, discretization="euler")
    psi = model.state("psi", "deg", "angle", std=5.0, process_std=0.01)
    r = model.state("r", "deg/s", "rate", std=1.0, process_std=0.01)
    delta = model.input("delta", "deg")
    model.dynamics({psi: r, r: -0.5 * r + 0.2 * delta})
    model.output("psi_m", psi, "deg", noise_std=1.0)
    model.output("r_m", r, "deg/s", noise_std=0.1)
    model.unknown(r, polynomial([r], 1), prior_variance=0.01)
    return model


def _ship_data(n=400, psi0=200.0, dt=0.1, wrap=False, seed=3):
    """A turning ship starting 200 deg from the declared heading (0); readings with noise, the
    heading optionally as a compass reads it, in (-180, 180]."""
    rng = np.random.default_rng(seed)
    delta = 2.0 * np.sin(0.05 * np.arange(n))
    psi, r = np.empty(n), np.empty(n)
    psi[0], r[0] = psi0, 0.5
    for k in range(n - 1):
        psi[k + 1], r[k + 1] = psi[k] + dt * r[k], r[k] + dt * (-0.5 * r[k] + 0.2 * delta[k])
    psi_m = psi + rng.normal(0, 1.0, n)
    if wrap:
        psi_m = (psi_m + 180.0) % 360.0 - 180.0
        psi = (psi + 180.0) % 360.0 - 180.0
    return delta[:, None], np.column_stack([psi_m, r + rng.normal(0, 0.1, n)]), psi


@pytest.mark.parametrize("wrap", [False, True])
@pytest.mark.parametrize("kind", ["ekf", "ski"])
def test_an_output_rejected_for_reject_limit_samples_restarts_while_another_is_used(kind, wrap):
    """The heading is 200 deg (or, as a compass reads it, -160 deg) from the declared one (std 5):
    every heading reading is gated while the rate gyro's are used. The heading's own run of
    rejections restarts the states at its 26th reading (reject_limit 25), onto it, and the
    heading then tracks; the Python stepper and the C agree code for code."""
    d, guard = derive(_ship(), kind), Guard()
    u, y, psi = _ship_data(wrap=wrap)
    c = load_c(d).run_many(u, y)
    res = run(d, Recording("ship", np.arange(len(u)) * 0.1, u, y, ("delta",), ("psi_m", "r_m")),
              show_progress=False)
    np.testing.assert_array_equal(res.code, c["code"])
    _close(res.mean, c["z_post"])
    code = c["code"]
    limit = guard.reject_limit
    np.testing.assert_array_equal(code[:limit], Status.OUTLIER_REJECTED)
    assert code[limit] == Status.REINITIALISED and np.sum(code == Status.REINITIALISED) == 1
    assert np.sum(code == Status.OUTLIER_REJECTED) == limit          # none gated after the restart
    err = c["z_post"][:, 0] - psi
    assert abs(err[limit - 1]) > 150 and c["std"][limit - 1, 0] < 5.1   # before: far off and sure
    assert c["std"][limit, 0] < 1.01                 # the restart took the heading reading (std 1) ungated
    # then it settles: measured max |error| 0.24 deg (0.21 SKI), 2.0 (1.8) of its std, from 50 samples on
    assert np.abs(err[limit + 50:]).max() < 0.3
    assert np.abs(err[limit + 50:] / c["std"][limit + 50:, 0]).max() < 2.5
    summary = res.summary().lines()
    assert any("1 recovered (states restarted)" in line for line in summary), summary


@pytest.mark.parametrize("backend", ["python", "c", "casadi"])
def test_a_restart_after_an_input_hole_is_reported(backend):
    """The states restart where the input is known again after a hole: that sample's status is
    'recovered' and the run's summary counts it, on every backend; the samples in the hole, whose
    input is not known, are 'bad_input' and use no reading."""
    import pandas as pd
    from skigen.recording import load_recording
    from skigen.runtime import restarts
    from tests.test_stream import small_model

    model = small_model()
    t = np.arange(500) * 0.02
    noise = np.random.default_rng(1).normal(0, 0.1, (2, len(t)))
    frame = pd.DataFrame({"t": t, "u": np.sin(t), "g": 0.0, "xm": noise[0], "vm": noise[1]})
    frame.loc[(frame.t > 3.0) & (frame.t < 5.0), "u"] = np.nan           # a 2 s input hole
    rec = load_recording(frame, model)
    (k,) = restarts(rec, model)
    res = run(derive(model, "ukf"), rec, backend=backend, show_progress=False)
    status = res.columns()["status"]
    assert status[k] == "recovered" and list(np.flatnonzero(status == "recovered")) == [k]
    inside = np.flatnonzero(status == "bad_input")
    assert rec.t[inside[0]] > 3.0 and inside[-1] == k - 1 and np.isnan(res.innovation[inside]).all()
    before = inside[0] - 1                                         # the last sample the input was known
    assert res.std[k, 1] > 3 * res.std[before, 1]                  # the restart: v's std jumps
    lines = res.summary().lines()
    assert (f"events: {len(inside)} bad input, first at t = {rec.t[inside[0]]:g} s; 1 recovered (states "
            f"restarted), first at t = {rec.t[k]:g} s") in lines, lines


def _duffing(noise: float, seed: int = 1, n: int = 3000, dt: float = 0.01, v3: float = 0.0):
    """A Duffing oscillator (ẍ = −4x − 0.3ẋ + u − 1.5x³ − v3·ẋ³, RK4 in 20 substeps) read with ``noise``,
    its model declaring the linear part and a cubic library on v̇."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    u = sum(a * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) for a, f in ((2, 0.13), (1.5, 0.31), (1, 0.57)))
    u = u + rng.uniform(-1.5, 1.5, n // 200 + 1)[(t / 2).astype(int)]
    f = lambda s, uu: np.array([s[1], -4 * s[0] - 0.3 * s[1] + uu - 1.5 * s[0] ** 3 - v3 * s[1] ** 3])
    X, x, h = np.zeros((n, 2)), np.zeros(2), dt / 20
    for k in range(n):
        X[k] = x
        for _ in range(20):
            k1 = f(x, u[k]); k2 = f(x + h / 2 * k1, u[k]); k3 = f(x + h / 2 * k2, u[k]); k4 = f(x + h * k3, u[k])
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    m = Model("duffing", dt=dt)
    xs = m.state("x", std=0.5, process_std=1e-5)
    v = m.state("v", std=0.5, process_std=1e-4)
    ui = m.input("u")
    m.dynamics({xs: v, v: -4 * xs - 0.3 * v + ui})
    m.output("pos", xs, noise_std=noise)
    m.unknown(v, polynomial([xs, v], 3))
    rec = Recording("duffing", t, u[:, None], (X[:, 0] + rng.normal(0, noise, n))[:, None], ("u",), ("pos",))
    return m, rec


def test_a_sigma_point_filter_that_overflows_says_where_it_evaluates_and_alpha_helps():
    """SKI on a cubic library under heavy noise (σ = 0.2 on a ±1.7 swing): at alpha = 1 its sigma
    points (±3.46σ of 12 states and weights) overflow v³ and the run restarts again and again; the
    summary says so and names alpha. At alpha = 0.3 the cubic weight comes out right, no step fails."""
    from skigen.derive import FilterOptions
    m, rec = _duffing(0.2)
    wide = run(derive(m, "ski"), rec, show_progress=False).summary()
    assert wide.events[Status.NUMERICAL_FAILURE] > 1000
    lines = wide.lines()
    assert any(line.startswith("why the first failed: the rk4 step of v is not finite at the prior mean") for line in lines)
    assert any(line.startswith("why steps may fail: the ski evaluates the model at ±3.46 standard deviations of "
                               "each of its 12") and "--alpha 0.3" in line for line in lines)
    near = run(derive(m, "ski", FilterOptions(alpha=0.3)), rec, show_progress=False)
    summary = near.summary()
    assert not summary.events[Status.NUMERICAL_FAILURE] and not any("why steps" in line for line in summary.lines())
    i = near.names.index("w_x3")
    assert abs(near.mean[-1, i] + 1.5) < 2 * near.std[-1, i] < 0.22
    from skigen.failure import nearer                # advice past the alpha tried: the next, not the same
    assert "--alpha 0.1, FilterOptions(alpha=0.1)" in nearer(near.filter) and "now 0.3" in nearer(near.filter)
    assert nearer(derive(m, "ski", FilterOptions(alpha=1e-3))).startswith("Smaller prior variances of the weights")


def _falling_tank(n: int = 400, dt: float = 0.05):
    """A tank draining through an orifice, ḣ = −0.5·√h (m, s), read by a level sensor (σ 2 mm):
    it empties at t = 8 s and sits at 0 for the rest of the recording."""
    t = np.arange(n) * dt
    h = np.maximum(np.sqrt(4.0) - 0.25 * t, 0.0) ** 2
    y = h + np.random.default_rng(0).normal(0, 2e-3, n)
    m = Model("tank", dt=dt, discretization="rk4")
    level = m.state("h", unit="m", initial=4.0, std=0.1, process_std=1e-4)
    m.dynamics({level: -0.5 * ca.sqrt(level)})
    m.output("level", level, unit="m", noise_std=2e-3)
    return m, Recording("tank", t, np.zeros((n, 0)), y[:, None], (), ("level",))


@pytest.mark.parametrize("backend", ["python", "c"])
def test_a_failed_step_names_the_equation_and_the_sigma_point(backend):
    """A square root of a state the sigma points take below zero (a tank at empty): the summary
    names the step of h and the point where it is not finite, from either backend, and the
    estimates before the failure are unchanged by the explanation (a snapshot, not a rerun)."""
    m, rec = _falling_tank()
    res = run(derive(m, "ukf"), rec, backend=backend, show_progress=False)
    first = np.flatnonzero(res.code == Status.NUMERICAL_FAILURE)[0]
    assert 7.0 < res.t[first] < 8.5                          # as the level reaches 0
    why = [line for line in res.summary().lines() if line.startswith("why the first failed: ")]
    assert len(why) == 1 and why[0].startswith("why the first failed: the rk4 step of h is not finite at the prior "
                                               "mean (h = ")
    assert 0 < float(why[0].split("(h = ")[1].split(")")[0]) < 1e-3 and "sqrt(fmax(x, 1e-9))" in why[0]
    parts = list(iter_run(derive(m, "ukf"), rec, backend=backend, show_progress=False, chunk=first - 5))
    np.testing.assert_array_equal(RunResult.concat(parts).mean, res.mean)    # explained mid-part: same run
    assert parts[1].failure == res.failure


def test_an_ekf_linearised_where_the_model_has_no_derivative_says_so():
    """An airspeed sqrt(vx² + vz²) measured on a glider at rest: the EKF's Jacobian is NaN there
    and every step fails; the summary names the derivative and the point, and that no reading
    was used (not that none was measured)."""
    n, dt = 200, 0.02
    m = Model("glider", dt=dt, discretization="rk4")
    vx, vz = m.state("vx", std=0.3, process_std=1e-2), m.state("vz", std=0.3, process_std=1e-2)
    ax = m.input("ax")
    m.dynamics({vx: ax - 0.1 * vx, vz: -0.1 * vz})
    m.output("airspeed", ca.sqrt(vx ** 2 + vz ** 2), noise_std=0.05)
    t = np.arange(n) * dt
    rec = Recording("glider", t, np.zeros((n, 1)), np.abs(np.random.default_rng(0).normal(0, 0.05, (n, 1))),
                    ("ax",), ("airspeed",))
    lines = run(derive(m, "ekf"), rec, show_progress=False).summary().lines()
    assert f"events: {n} rejected (non-finite), first at t = 0 s" in lines
    assert any(line.startswith("why the first failed: the EKF's derivative of output airspeed with respect to vx "
                               "is not finite at the prior mean (vx = 0, vz = 0)") for line in lines)
    assert f"no reading was used ({n} samples had one: each failed, was gated or stuck): no NIS" in lines


def test_weights_the_recording_fixes_only_together_are_said_with_their_combination():
    """The Duffing's cubic library plus sin(x), whose swing (±1.2) keeps it within a few percent of
    x − x³/6: the weights of x and sin(x) each read as uncertain (±0.6 at 2σ, one 'within 2σ of 0'),
    yet their combination is known to ±0.01. The summary names the pair with that combination;
    the true x³ weight with nothing beside it is not named."""
    import casadi as ca
    from skigen.library import term
    m, rec = _duffing(0.01)
    m.unknown(m.states[1].sym, [term("sinx", ca.sin(m.states[0].sym), key="sinx")])
    summary = run(derive(m, "ski"), rec, show_progress=False).summary()
    together = [line for line in summary.lines() if "move together" in line]
    pair = next(line for line in together if line.startswith("  w_x and w_sinx"))
    P, i, j = summary.cov, summary.filter.aug.names.index("w_x"), summary.filter.aug.names.index("w_sinx")
    r = P[i, j] / np.sqrt(P[i, i] * P[j, j])
    assert r < -0.99 and f"(correlation {r:+.5f})" in pair and np.sqrt(P[i, i]) > 0.1
    k = np.sqrt(P[j, j] / P[i, i])
    combo = np.sqrt(P[j, j] + k * k * P[i, i] + 2 * k * P[i, j])
    assert combo < 0.01 and f"= {summary.last[0][j] + k * summary.last[0][i]:+.4g} ± {2 * combo:.2g}, not each" in pair
    plain = run(derive(_duffing(0.01)[0], "ski"), rec, show_progress=False).summary()
    assert not any("move together" in line for line in plain.lines())


def test_a_small_term_far_from_zero_is_not_called_pruned_without_a_word():
    """A cubic damping of 0.01 beside the cubic spring's 1.5: ARD's display rule (prior std at least
    1 % of the largest) calls it pruned, though its weight is many σ from 0 (a user read a 49σ term
    as absent). The summary says so beside it; a truly pruned weight keeps the plain label."""
    m, rec = _duffing(0.01, v3=0.01)
    lines = run(derive(m, "ski"), rec, show_progress=False).summary().lines()
    v3 = next(line for line in lines if line.startswith("  w_v3 "))
    x3 = next(line for line in lines if line.startswith("  w_x3 "))
    w, two_sd = (float(v) for v in v3.split()[1:4:2])
    assert abs(w + 0.01) < 0.002 and "pruned, yet" in v3 and f"yet {abs(w) / (two_sd / 2):.0f}σ from 0" in v3, v3
    assert x3.endswith("kept")
    assert any(line.endswith("   pruned") for line in lines)


def test_weights_each_known_and_correlated_are_not_said_unknown_each():
    """A yaw model's damping and gain, correlated 0.9995, each known to 1.5 % (8.05 ± 0.12 from a
    prior std of 2): the summary said the recording fixes their combination 'not each'. Where each
    std is under half its prior's, it says the combination is known far better than either."""
    from models.wingrock import build
    from skigen.runtime import RunSummary
    summary = RunSummary(derive(build(), "ukf"))
    aug = summary.filter.aug
    i, j = aug.w_index[:2]
    sd = np.full(aug.n, 0.1)
    sd[[i, j]] = 0.01 * np.sqrt(np.diag(aug.P0)[[i, j]])
    cov = np.diag(sd ** 2)
    cov[i, j] = cov[j, i] = 0.9995 * sd[i] * sd[j]
    summary.cov, summary.last = cov, (np.ones(aug.n), sd, None)
    (pair,) = summary.together()
    assert "far better than either" in pair and "not each" not in pair, pair
    sd[[i, j]] = 0.8 * np.sqrt(np.diag(aug.P0)[[i, j]])              # each barely informed: not each
    cov = np.diag(sd ** 2)
    cov[i, j] = cov[j, i] = 0.9995 * sd[i] * sd[j]
    summary.cov, summary.last = cov, (np.ones(aug.n), sd, None)
    (pair,) = summary.together()
    assert "not each" in pair, pair
