"""A recording that does not begin at the model's declared initial state (skigen.start).

The arm (models/motor_pendulum.py, declared at rest: θ 0 ± 0.02 rad, ω 0 ± 0.05 rad/s) swung
by a 4 V multisine; a recording cut 12 s in begins mid-swing (θ ≈ 0.6 rad, ω ≈ −4.3 rad/s).
Measured here: the smoothed start within 0.1 of its std of the truth; a filter-error fit from
the declared start calibrates the rate's process noise at 0.097 rad/s (truth 0.01), from the
vague start at 0.0091; the diagnosis of quadratic drag on that segment named nothing from the
declared start and names the drag, 0.144 ± 0.012 (truth 0.15), from the vague one.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from benchmarks.scenarios import ARM_FILE, _arm, _arm_multisine, make
from models import motor_pendulum as arm
from skigen.diagnose import diagnose
from skigen.fit import fit
from skigen.modelfile import load_model
from skigen.recording import Recording, load_recording
from skigen import Model
from skigen.start import MARGIN, recorded_start

CUT = 2400          # 12 s at 200 Hz


def _segment(effect, k=CUT, seed=1):
    sc = _arm("arm", effect, _arm_multisine(4.0), "", 30.0, seed)
    rec = Recording(f"arm from {sc.t[k]:g} s", sc.t[k:] - sc.t[k], np.c_[sc.inputs["V"]][k:],
                    np.c_[sc.outputs["theta_meas"]][k:], ("V",), ("theta_meas",))
    return rec, np.array([sc.run.theta[k], sc.run.omega[k]])


@pytest.fixture(scope="module")
def model():
    return load_model(ARM_FILE)


def test_the_state_a_recording_starts_in_is_estimated_and_the_declared_one_weighed(model):
    """At rest the declared start wins by the vague prior's Occam penalty, about nx ln 100 = 9.2
    nat (measured 8.9); mid-swing it loses by thousands, and the smoothed start is the truth's."""
    at_rest, _ = _segment(None, k=0)
    rs = recorded_start(model, at_rest)
    assert rs.consistent and -9.5 < rs.gain < -8
    mid, truth = _segment(None)
    rs = recorded_start(model, mid)
    assert not rs.consistent and rs.gain > 1000
    assert np.all(np.abs(rs.mean - truth) < 3 * rs.std), (rs.mean, truth, rs.std)
    note = rs.note(mid.path, "x")
    assert "omega -4.3" in note and "theta 0.65" in note and note.endswith("; x")


def test_a_model_error_does_not_move_a_right_start(tmp_path):
    """The quadrotor's ground effect, strongest at the start on the ground: over the whole
    recording the vague start predicted 110 nat better (the filters' innovations far beyond their
    noise amplify any difference); over the head the declared start wins (measured 7.6 nat)."""
    sc = make("quad_ground_effect")
    quad = load_model(sc.model_file)
    rs = recorded_start(quad, load_recording(sc.write_csv(tmp_path / "quad.csv"), quad))
    assert rs.consistent and rs.gain < -5


def test_a_filter_error_fit_starts_where_the_recording_does(model):
    """From the declared start the transient is put down to process noise (9.7x its truth); from
    the vague start it is 0.0091 (truth 0.01)."""
    mid, _ = _segment(None)
    fitted = fit(model, [mid], method="filter-error", show_progress=False)
    declared = fit(model, [mid], method="filter-error", starts="declared", show_progress=False)
    q = lambda r: r.noise["calibrated"]["process_std"]["omega"]
    assert q(fitted) == pytest.approx(0.01, rel=0.15)
    assert q(declared) > 5 * 0.01
    assert any("does not start at the model's initial state" in n for n in fitted.notes)
    start = fitted.initial_states[0]                                  # where it starts, by the model
    report = fitted.recordings[0]          # one-step RMSE without the head: 0.0017 rad, 0.011 with its 8 samples
    assert report["rmse_from"] == 8 and report["rmse"]["theta_meas"] < 1.5 * 0.0015
    assert start["omega"]["value"] == pytest.approx(-4.30, abs=3 * start["omega"]["std"])
    assert not any("initial state" in n for n in declared.notes)
    with pytest.raises(ValueError, match="starts must be a list or 'declared'"):
        fit(model, [mid], method="filter-error", starts="recorded", show_progress=False)


def test_drag_is_named_on_a_recording_that_begins_mid_swing(model, tmp_path):
    """Held out: another flight (seed 2) cut mid-swing, each model started where it begins: the
    corrected model's free-run RMSE there is 0.15 of the nominal's (measured 0.018 and 0.120 rad)."""
    mid, _ = _segment("quadratic_drag")
    held = dataclasses.replace(_segment("quadratic_drag", seed=2)[0], path="held out")
    rep = diagnose(ARM_FILE, mid, tmp_path, show_progress=False, figures=False, emit=False, validate=[held])
    top = rep.findings[0]
    truth = arm.EFFECTS["quadratic_drag"][0]
    assert (top["effect"], top["equation"]) == ("quadratic_drag", "omega")
    assert abs(top["coefficient"] - truth) < 2 * top["std"]
    notes = [n for n in rep.data["notes"] if "does not start at the model's initial state" in n]
    assert [n.split(":")[0] for n in notes] == [mid.path, "held out"]
    held_out = rep.data["fit"]["recordings"][0]
    assert held_out["after"]["free_run_rmse"]["theta_meas"] < 0.2 * held_out["before"]["free_run_rmse"]["theta_meas"]
    assert "theta -0.2472 ± 0.0011 against 0 ± 0.02" in notes[1]                    # against the declared start
    assert "initial=0.0, std=0.05" in (tmp_path / "corrected_model.py").read_text()   # the declared start kept


def _spring(offset: float, n: int = 2000):
    """A mass-spring-damper at rest as declared (k 25, c 0.4 1/s, gain 2), driven by a 0.2–3 Hz
    multisine, its position read 1 mm noisy and ``offset`` m high: the model and a grey box of it."""
    rng, dt = np.random.default_rng(11), 0.01
    t = np.arange(n) * dt
    u = np.sin(2 * np.pi * np.geomspace(0.2, 3.0, 10)[:, None] * t + rng.uniform(0, 2 * np.pi, (10, 1))).sum(0)
    u *= (1 + 0.5 * np.sin(2 * np.pi * t / 40)) / np.abs(u).max()
    f = lambda x, uk: np.array([x[1], -25 * x[0] - 0.4 * x[1] + 2 * uk])
    x, X, noise = np.zeros(2), [], np.random.default_rng(3)
    for uk in u:
        X.append(x.copy())
        for _ in range(10):
            h = dt / 10
            k1 = f(x, uk); k2 = f(x + h / 2 * k1, uk); k3 = f(x + h / 2 * k2, uk); k4 = f(x + h * k3, uk)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x = x + [0, 2e-3 * noise.standard_normal()]
    y = np.array(X)[:, 0] + 1e-3 * rng.standard_normal(n) + offset
    rec = Recording("spring", t, u[:, None], y[:, None], ("u",), ("pos",))

    def grey(kind):
        m = Model(f"spring_{kind}", dt=dt, discretization="rk4")
        p = m.state("p", unit="m", std=0.005)
        v = m.state("v", unit="m/s", std=0.01, process_std=2e-3)
        force = m.input("u", unit="N")
        b = m.parameter("b", 0.0, unit="m/s^2") if kind == "bias" else 0
        m.dynamics({p: v, v: -25 * p - 0.4 * v + 2 * force + b})
        m.output("pos", p + (m.parameter("off", 0.0, unit="m") if kind == "offset" else 0), unit="m", noise_std=1e-3)
        return m
    return rec, grey


def test_a_sensor_offset_at_rest_keeps_the_declared_start():
    """Position read 20 mm high (4 declared std) on a spring at rest: the vague start predicts the
    head 0.51 nat better, short of the 3.3 it must win by (moved, the start took the offset, and a
    force bias was the better grey box). Kept, the offset's grey box is 8.3 nat ahead (measured)."""
    rec, grey = _spring(0.02)
    rs = recorded_start(grey(None), rec)
    assert rs.consistent and 0 < rs.gain < MARGIN
    ll = {k: fit(grey(k), [rec], method="filter-error", show_progress=False) for k in ("offset", "bias")}
    assert not any("initial state" in n for r in ll.values() for n in r.notes)
    assert ll["offset"].parameters["off"]["value"] == pytest.approx(0.02, abs=3 * ll["offset"].parameters["off"]["std"])
    assert ll["offset"].recordings[0]["loglik"] - ll["bias"].recordings[0]["loglik"] > 6
    assert ll["offset"].initial_states == [{}]                       # started where declared
    output_error = fit(grey("offset"), [rec], show_progress=False)    # the default method says what it leaves out
    assert any("the free-run residuals exceed the declared sensor noise (pos" in n for n in output_error.notes)
    assert not any("free-run residuals" in n for r in ll.values() for n in r.notes)


def test_the_fit_figure_counts_the_rms_as_the_report_does(monkeypatch):
    """A recording whose filter learns the start in its first 3 samples: the figure's RMS is the
    report's, from the end of that head, the head shaded and its spike off the residual's scale
    (the panel read 'RMS 1.576' beside a report's 0.05108); an output never measured says so
    ('RMS nan' and a numpy warning before)."""
    import warnings
    from skigen.fit import figures
    t = np.arange(200) * 0.01
    y = np.c_[np.r_[50.0, 0.1 * np.sin(np.arange(199))], np.full(200, np.nan)]
    rec = Recording("r.csv", t, np.zeros((200, 1)), y, ("u",), ("a", "b"))
    shown = {}
    monkeypatch.setattr(figures, "save_figure", lambda fig, path: shown.setdefault("fig", fig))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        figures.recording_figure("x.png", "fitted", rec, np.zeros((200, 2)), ["a", "b"], start=3)
    axes = shown["fig"].axes
    expected = np.sqrt(np.mean(y[3:, 0] ** 2))
    assert axes[1].get_title(loc="right") == f"RMS {expected:.4g} from t = 0.03 s"
    assert axes[1].get_ylim()[1] < 1.0 and axes[3].get_title(loc="right") == "never measured"


def _motor_far(n: int = 1200):
    """A DC motor (J ω' = 0.05 V − b ω − 0.005 tanh(ω/0.5), J 3e-4, b 1.2e-3) at 6 V, logged from
    θ ≈ 426 rad and ω ≈ 243 rad/s — 4·10⁴ and 2·10³ declared std from the declared rest — encoder
    2 mrad, tachometer 0.2 rad/s; the model declares b = 1e-3 (its steady speed 295 rad/s)."""
    import casadi as ca
    dt, rng = 0.005, np.random.default_rng(5)
    f = lambda x: np.array([x[1], (0.05 * 6.0 - 1.2e-3 * x[1] - 0.005 * np.tanh(x[1] / 0.5)) / 3e-4])
    x, X = np.array([425.85, 243.3]), []
    for _ in range(n):
        X.append(x.copy())
        k1 = f(x); k2 = f(x + dt / 2 * k1); k3 = f(x + dt / 2 * k2); k4 = f(x + dt * k3)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4) + [0, 1e-3 * rng.standard_normal()]
    X = np.array(X)
    y = X + rng.standard_normal(X.shape) * [2e-3, 0.2]
    rec = Recording("motor.csv", 2 + np.arange(n) * dt, np.full((n, 1), 6.0), y, ("V",), ("enc", "tach"))
    m = Model("motor", dt=dt, discretization="rk4")
    th = m.state("theta", unit="rad", std=0.01, process_std=1e-5)
    w = m.state("omega", unit="rad/s", std=0.1, process_std=1e-3)
    V = m.input("V", unit="V")
    b = m.parameter("b", 1e-3, unit="N m s", bounds=(0, 1))
    m.dynamics({th: w, w: (0.05 * V - b * w - 0.005 * ca.tanh(w / 0.5)) / 3e-4})
    m.output("enc", th, unit="rad", noise_std=2e-3)
    m.output("tach", w, unit="rad/s", noise_std=0.2)
    return m, rec, X[0]


def test_a_log_that_starts_ten_thousand_std_away_is_fitted_from_where_it_starts():
    """From the declared mean the first innovation (426 rad against the vague prior's 1 rad)
    outweighed the rest: the encoder's noise was fitted 6·10⁷× its declared variance and the
    start put at 235 rad, because the smoothed start scaled R by the head's dispersion (8·10⁵) and
    not the prior. Centred where the recording starts, the fit is the one from a start declared
    there (measured: encoder noise scale 1.05, θ's process noise 130 ± 100 where it was 7·10¹⁰,
    b within 1σ, the start within 1σ, ± 0.011 rad and 0.78 rad/s)."""
    m, rec, truth = _motor_far()
    rs = recorded_start(m, rec)
    assert not rs.consistent and np.all(np.abs(rs.mean - truth) < rs.std), (rs.mean, rs.std)
    res = fit(m, [rec], method="filter-error", show_progress=False)
    scale = res.noise["scales"]
    assert 0.85 < scale["R_scale_enc"]["value"] < 1.25 and scale["Q_scale_theta"]["value"] < 1e3, scale
    assert abs(res.parameters["b"]["value"] - 1.2e-3) < 3 * res.parameters["b"]["std"], res.parameters["b"]
    start = res.initial_states[0]
    for name, value, wide in zip(("theta", "omega"), truth, (0.03, 1.0)):   # by the fitted model: not
        assert abs(start[name]["value"] - value) < 3 * start[name]["std"] < 3 * wide, start  # 0.42 rad, 9.8 rad/s
