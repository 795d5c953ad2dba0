"""Grey-box fitting (skigen.fit): recovery, honest error bars, bias, input hold, errors.

Every number asserted here was measured (see the comments); tolerances sit near the
measurement, not far above it. The Monte-Carlo loops reuse one model object per system
and recording length, so the NLP is built once and only the data change.

Measured on the development machine (fixed seeds below):

- Duffing (FOH, position measured), 200 runs, output error: 2σ coverage k 0.955, d 0.93,
  k3 0.935, b 0.97 (300 runs: 0.95, 0.93, 0.95, 0.96).
- Pendulum with viscous and smooth Coulomb friction (ZOH), output error (200 runs):
  a 0.975, c 0.98, fc 0.98, b 0.965; filter error (50 runs): a 0.98, c 0.98, fc 0.96, b 0.96.
- Duffing, filter error, 1500 samples: k 0.96, d 0.92, k3 0.96, b 0.98 (see FE_SAMPLES).

Whole file: about 3 minutes on one core (the 1500-sample filter-error Duffing runs take 100 s).
"""
import dataclasses
import functools
import json
import re
import shutil
import sys

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from skigen import Model, ModelError
from skigen.derive import derive
from skigen.derive.augment import augment, step_inputs
from skigen.fit import FitError, NotIdentifiable, fit
from skigen.library import term
from skigen.recording import Recording, write_recording
from skigen.runtime import PythonStepper, run
from skigen.simulate import free_run

RUNS = 50            # Monte-Carlo runs per system, filter error
OE_RUNS = 200        # output error (a fit takes ~0.1 s): a coverage of 0.93 over 50 runs falls
                     # below 0.90 one time in eight by chance alone
COVERAGE = 0.90      # required share of 2σ intervals holding the truth (nominal 0.954)
# Filter error on the Duffing oscillator needs a longer record for honest error bars: with 500
# samples (~8 periods) the process-noise scale comes out 0.86 on average (the finite-sample low bias
# of a maximum-likelihood variance), the filter is overconfident and the errors are ~12 % larger
# than the inverse Fisher information says (coverage k 0.86, d 0.92, k3 0.86, b 0.88 on these
# seeds; 0.93-0.98 on 200 others; the sandwich or the observed information do no better). With
# 1500 samples the scale averages 0.98, error/std has std 0.96-1.07 and coverage is k 0.96,
# d 0.92, k3 0.96, b 0.98. README reports both.
FE_SAMPLES = {"duffing": 1500}


# ---------------------------------------------------------------------------- helpers

def simulate(model, U, x0, rng, q_std=None):
    """The model's own discrete step with a Gaussian kick of std ``q_std`` per sample on the
    state (process noise) and the declared measurement noise: x[k+1] = f(x[k], u) + w[k]."""
    aug = augment(model)
    nx = len(model.states)
    q = np.zeros(nx) if q_std is None else np.asarray(q_std, float)
    r = np.sqrt(np.diag(model.measurement_noise()))
    Us = np.asarray(step_inputs(model, U), float).reshape(len(U), -1)
    W = rng.normal(size=(len(Us), nx))                    # the kicks, drawn sample by sample
    w = ca.SX.sym("w", nx)
    step = ca.Function("step", [aug.z, ca.vertcat(aug.u, w)], [aug.f + q * w, aug.h])
    X_next, Y = (np.asarray(v).T for v in step.mapaccum("sim", len(Us))(np.asarray(x0, float), np.hstack([Us, W]).T))
    X = np.vstack([np.asarray(x0, float)[None, :], X_next[:-1]])
    return X, Y + r * rng.normal(size=Y.shape)


def recording(model, U, Y, path="sim"):
    U, Y = np.asarray(U, float).reshape(len(U), -1), np.asarray(Y, float).reshape(len(U), -1)
    return Recording(path, np.arange(len(U)) * model.dt, U, Y, tuple(model.input_names), tuple(model.output_names))


def smooth_noise(rng, N, width, gain):
    """Moving-average filtered white noise: unit-ish std times gain, band-limited by width samples."""
    w = rng.normal(size=N + 4 * width)
    return np.convolve(w, np.ones(width) / np.sqrt(width), "same")[2 * width:2 * width + N] * gain


def duffing(values, *, q=(0.0, 0.0), r=0.02, hold="foh", name="duffing"):
    """Hardening spring: y'' = -k y - d y' - k3 y³ + b u, position measured."""
    m = Model(name, dt=0.05, input_hold=hold)
    y = m.state("y", std=0.2, process_std=q[0])
    v = m.state("v", std=0.2, process_std=q[1])
    u = m.input("u")
    k, d, k3, b = (m.parameter(n, values[n]) for n in ("k", "d", "k3", "b"))
    m.dynamics({y: v, v: -k * y - d * v - k3 * y ** 3 + b * u})
    m.output("pos", y, noise_std=r)
    return m


def pendulum(values, *, q=(0.0, 0.0), r=0.01, name="pendulum", b_bounds=None, rate_std=None):
    """Pendulum with viscous and smooth Coulomb friction, angle (and with ``rate_std`` the rate)
    measured (ZOH input)."""
    m = Model(name, dt=0.04)
    th = m.state("theta", std=0.1, process_std=q[0])
    w = m.state("w", std=0.1, process_std=q[1])
    u = m.input("u")
    a = m.parameter("a", values["a"], bounds=(0, 100))
    c = m.parameter("c", values["c"], bounds=(0, 10))
    fc = m.parameter("fc", values["fc"], bounds=(0, 10))
    b = m.parameter("b", values["b"], bounds=b_bounds)
    m.dynamics({th: w, w: -a * ca.sin(th) - c * w - fc * ca.tanh(w / 0.05) + b * u})
    m.output("angle", th, noise_std=r)
    if rate_std:
        m.output("rate", w, noise_std=rate_std)
    return m


DUFFING = dict(k=4.0, d=0.5, k3=1.0, b=1.0)
DUFFING_START = dict(k=3.0, d=0.8, k3=0.5, b=1.3)
PENDULUM = dict(a=10.0, c=1.0, fc=0.5, b=2.0)
PENDULUM_START = dict(a=8.0, c=0.7, fc=0.3, b=1.5)

# system: (builder, truth, start, samples, seed base, excitation (width, gain), x0 std, filter-error process std)
SYSTEMS = {
    "duffing": (duffing, DUFFING, DUFFING_START, 500, 1000, (5, 3.0), 0.2, (0.0, 0.02)),
    "pendulum": (pendulum, PENDULUM, PENDULUM_START, 600, 2000, (8, 2.0), 0.1, (0.0, 0.03)),
}


def monte_carlo(system, method):
    """Fit RUNS (OE_RUNS) simulated recordings; returns {parameter: (errors, stds)} and the fits."""
    build, truth, start, N, seed, (width, gain), x0_std, q = SYSTEMS[system]
    N = FE_SAMPLES.get(system, N) if method == "filter-error" else N
    q = q if method == "filter-error" else (0.0, 0.0)
    plant, model = build(truth, q=q), build(start, q=q)
    errors = {n: [] for n in truth}
    stds = {n: [] for n in truth}
    fits = []
    runs = OE_RUNS if method == "output-error" else RUNS
    for i in range(runs):
        rng = np.random.default_rng(seed + i)
        U = smooth_noise(rng, N, width, gain)[:, None]
        _, Y = simulate(plant, U, rng.normal(size=2) * x0_std, rng, q_std=q)
        res = fit(model, [recording(model, U, Y)], method=method, show_progress=False)
        assert res.converged
        fits.append(res)
        for n in truth:
            errors[n].append(res.parameters[n]["value"] - truth[n])
            stds[n].append(res.parameters[n]["std"])
    return {n: (np.array(errors[n]), np.array(stds[n])) for n in truth}, fits


def coverage(stats):
    return {n: float(np.mean(np.abs(e) <= 2 * s)) for n, (e, s) in stats.items()}


# ------------------------------------------------------------ 1. Monte-Carlo coverage

@pytest.mark.parametrize("system", list(SYSTEMS))
def test_output_error_recovers_parameters_with_honest_error_bars(system):
    """Measurement noise only. Coverage measured over the 200 seeds: Duffing k 0.955, d 0.93,
    k3 0.935, b 0.97; pendulum a 0.975, c 0.98, fc 0.98, b 0.965."""
    stats, _ = monte_carlo(system, "output-error")
    cov = coverage(stats)
    print(system, "output error coverage", cov)
    for n, (e, s) in stats.items():
        # unbiased: the mean error within 3 standard errors of the Monte-Carlo mean
        assert abs(e.mean()) < 3 * e.std(ddof=1) / np.sqrt(len(e)), (n, e.mean())
        assert cov[n] >= COVERAGE, (system, n, cov)


@pytest.mark.parametrize("system", list(SYSTEMS))
def test_filter_error_recovers_parameters_and_noise_with_honest_error_bars(system):
    """Process noise in the truth (a Gaussian kick on the rate every sample). Coverage: see
    FE_SAMPLES; the calibrated R scale averages 1 within 0.05."""
    stats, fits = monte_carlo(system, "filter-error")
    cov = coverage(stats)
    print(system, "filter error coverage", cov)
    for n, (e, s) in stats.items():
        assert abs(e.mean()) < 3 * e.std(ddof=1) / np.sqrt(len(e)), (n, e.mean())
        assert cov[n] >= COVERAGE, (system, n, cov)
    # the declared noise is the truth: the calibrated measurement noise scale is ~1
    r_scale = np.array([next(v["value"] for k, v in f.noise["scales"].items() if k.startswith("R_")) for f in fits])
    assert abs(r_scale.mean() - 1) < 0.05


@pytest.mark.parametrize("n", [21, 16 * 3 + 5, 16 * 4])
def test_a_chained_recording_computes_what_the_step_by_step_accumulation_does(n):
    """The fit's NLP chains the EKF step over a recording by inlined blocks (problem._chained): its
    outputs, and their derivatives in the parameters and noise scales (what IPOPT's gradient and
    Fisher scoring see), equal mapaccum's step by step — with a partial last block and without any
    block. Measured: equal to the bit (the bound allows rounding in another order)."""
    from skigen.fit import problem as P
    model = pendulum(PENDULUM, q=(0.01, 0.03))
    aug, x, theta = P._plant(model, model.parameter_names)
    lam_q, lam_r = ca.SX.sym("lq", 2), ca.SX.sym("lr", 1)
    step = P._filter_error_step(model, aug, x, theta, lam_q, lam_r, [0, 1])
    rng = np.random.default_rng(4)
    U = smooth_noise(rng, n, 8, 2.0)[:, None]
    _, Y = simulate(model, U, np.array([0.1, 0.0]), rng, q_std=(0.01, 0.03))
    D = P.data_matrix(model, recording(model, U, Y))
    s0 = np.r_[model.x0, np.ravel(model.initial_covariance(), order="F")]
    th, lam = ca.MX.sym("th", theta.shape[0]), ca.MX.sym("lam", 3)
    point = [np.array(list(PENDULUM.values())), np.array([0.3, -0.2, 0.1])]
    for reference, chained in zip(step.mapaccum("f", n, [0], [0])(s0, D, th, lam),
                                  P._chained(step, n, "f")(s0, D, th, lam)):
        for a, b in [(reference, chained), *[(ca.jacobian(reference, v), ca.jacobian(chained, v)) for v in (th, lam)]]:
            a, b = (np.asarray(ca.Function("g", [th, lam], [e])(*point)) for e in (a, b))
            assert a.shape == b.shape
            assert np.max(np.abs(a - b)) <= 1e-14 * max(np.max(np.abs(a)), 1.0)


@pytest.mark.parametrize("method", ["filter-error", "output-error"])
def test_the_scoring_gradient_from_the_residual_jacobian_is_the_objectives_gradient(method):
    """IPOPT's gradient comes from the same forward sweep as the Fisher information, ∇f = Jᵀ r
    (problem._pseudo_residuals), not from a reverse sweep of f: it must equal f's own gradient,
    with missing samples, a declared prior and (output error) shooting intervals. Measured: within
    7e-16 of the largest entry (both methods, three points)."""
    from skigen.fit import problem as P
    model = pendulum(PENDULUM, q=(0.01, 0.03))
    model.parameters[0] = dataclasses.replace(model.parameters[0], std=2.0)     # a declared prior on a
    rng = np.random.default_rng(6)
    U = smooth_noise(rng, 150, 8, 2.0)[:, None]
    _, Y = simulate(model, U, np.array([0.1, 0.0]), rng, q_std=(0.01, 0.03))
    Y[40:47] = np.nan
    rec = recording(model, U, Y)
    prob = P.build_problem(model, [150], method, model.parameter_names, shooting=50 if method == "output-error" else None)
    xi, p = prob.nlp["x"], prob.nlp["p"]
    exact = ca.Function("g", [xi, p], [ca.gradient(prob.nlp["f"], xi)])
    data = np.ravel(P.data_matrix(model, rec), order="F")
    V = prob.variables
    for trial in range(3):
        point = np.array(V.initial) / np.array(V.scale) + 0.05 * rng.normal(size=len(V))
        start = np.r_[model.x0, np.ravel(model.initial_covariance(), order="F")] if method == "filter-error" else []
        args = (point, np.r_[V.scale, data, start])
        a, b = (np.asarray(v).ravel() for v in (exact(*args), prob.decrement(*args)[0]))
        assert np.max(np.abs(a - b)) <= 1e-14 * np.max(np.abs(a)), (trial, a, b)


def test_a_misspecified_calibration_converges_faster_with_the_secant_correction(monkeypatch, tmp_path):
    """fit.problem._Secant (NL2SOL's structured secant update on the Fisher information). The
    quadrotor's nominal without its ground effect (2 000 samples, seed 1), noise scales only: its
    innovations are not white, the likelihood's curvature is not the Fisher information, and
    Fisher scoring alone overshoots at every iteration (measured: 12 iterations); with the
    correction 6, to the same optimum."""
    from benchmarks.scenarios import make
    from skigen.diagnose import load
    from skigen.diagnose import transform as T
    problem = sys.modules["skigen.fit.problem"]
    sc = make("quad_ground_effect", 20.0, 1)
    user, _, rec = load(sc.model_file, sc.write_csv(tmp_path / "quad.csv"))
    nominal = T.copy_model(user, unknowns=False)
    calibrate = lambda: fit(nominal, [rec], method="filter-error", estimate=[], show_progress=False)
    secant = calibrate()
    monkeypatch.setattr(problem._Secant, "eval", lambda self, arg: [np.zeros((self.n, self.n))])
    monkeypatch.setattr(sys.modules["skigen.fit"], "_CACHE", {})
    fisher = calibrate()
    assert secant.iterations <= 0.6 * fisher.iterations, (secant.iterations, fisher.iterations)   # 6 against 12
    assert abs(secant.objective - fisher.objective) < 1e-3
    for name, s in fisher.noise["scales"].items():
        assert abs(secant.noise["scales"][name]["value"] - s["value"]) < 0.02 * s["std"], name


def test_filter_error_on_a_noise_free_truth_stops_once_the_estimates_no_longer_move(monkeypatch):
    """A pendulum recorded without process noise (1500 samples, seed 0): every Q scale's optimum is
    0, where the likelihood is flat in its log. IPOPT's own test walked the log-scales towards
    e⁻²⁵ for 59 iterations; the fit stops at 41 (39 before the secant correction), once Fisher
    scoring puts the optimum within 0.02 standard errors of every estimate. Measured: the parameters agree with IPOPT's to 0.001 σ
    (seeds 1 and 2: 0.049 σ, 0.000 σ), and the Q scales come out at 0.02 σ or less of zero."""
    fit_module = sys.modules["skigen.fit"]
    plant, model = pendulum(PENDULUM, q=(0.01, 0.03)), pendulum(PENDULUM_START, q=(0.01, 0.03))
    rng = np.random.default_rng(0)
    U = smooth_noise(rng, 1500, 8, 2.0)[:, None]
    _, Y = simulate(plant, U, rng.normal(size=2) * 0.1, rng)
    rec = recording(model, U, Y)
    res = fit(model, [rec], method="filter-error", show_progress=False)
    monkeypatch.setattr(fit_module, "NEGLIGIBLE_MOVE", 0.0)
    tight = fit(model, [rec], method="filter-error", show_progress=False)
    assert res.status == "Solved_To_Negligible_Step"
    assert res.iterations <= 0.7 * tight.iterations, (res.iterations, tight.iterations)      # 41 against 59
    for name, p in tight.parameters.items():
        assert abs(res.parameters[name]["value"] - p["value"]) < 0.02 * p["std"], name
        assert res.parameters[name]["std"] == pytest.approx(p["std"], rel=0.01)
    for name, s in res.noise["scales"].items():
        if name.startswith("Q_"):
            assert s["value"] < 0.02 * s["std"], (name, s)
    r = res.noise["scales"]["R_scale_angle"]
    assert abs(r["value"] - 1) < 2 * r["std"]


def test_a_line_search_that_cannot_move_stops_the_fit_and_one_that_moves_does_not(monkeypatch):
    """Where IPOPT's line search halves its step dozens of times per iteration and gains nothing
    (a corrected model with a limit's kink: a ground-effect recalibration took 18 iterations and
    301 likelihood evaluations, 23 s, for the value it had after 4), the fit stops once the last
    three iterates moved every estimate by less than 0.02 standard errors. At the same point,
    far from the optimum (the start), iterates that moved by a standard error each do not stop
    it, nor does the start alone: the quadratic model's step there is not negligible."""
    fit_module = sys.modules["skigen.fit"]
    seen = []
    monkeypatch.setattr(fit_module, "_negligible_gain",
                        lambda prob, inputs, xi, recent=(): seen.append((prob, inputs)) or False)
    plant, model = pendulum(PENDULUM, q=(0.0, 0.03)), pendulum(PENDULUM_START, q=(0.0, 0.03))
    rng = np.random.default_rng(3)
    U = smooth_noise(rng, 600, 8, 2.0)[:, None]
    _, Y = simulate(plant, U, rng.normal(size=2) * 0.1, rng, q_std=np.array([0.0, 0.03]))
    fit(model, [recording(model, U, Y)], method="filter-error", show_progress=False)
    monkeypatch.undo()
    prob, inputs = seen[0]
    negligible = functools.partial(fit_module._negligible_gain, prob, inputs)
    x0 = np.asarray(inputs["x0"], float)
    g, H = (np.asarray(ca.DM(v)) for v in prob.decrement(x0, inputs["p"]))
    std = np.sqrt(np.diag(np.linalg.inv(H)))       # ξ units (the log scales' own, near the start)
    step = lambda k: [x0 + k * i * std for i in range(4)]
    assert not negligible(x0)
    assert negligible(x0, step(1e-3))
    assert not negligible(x0, step(1.0))


def slow_plant(a, b, q=0.0, r=0.02):
    """First-order lag x' = −a x + b u (dt = 1 s), x measured."""
    m = Model("slow", dt=1.0)
    x = m.state("x", std=0.1, process_std=q)
    u = m.input("u")
    A, B = m.parameter("a", a, bounds=(1e-5, 1)), m.parameter("b", b)
    m.dynamics({x: -A * x + B * u})
    m.output("y", x, noise_std=r)
    return m


def test_output_error_error_bars_hold_when_process_noise_drifts_through_a_slow_plant():
    """Output error on a lag of time constant 100 samples whose state is kicked every sample
    (stationary std 0.07 against a sensor of 0.02): the simulation residuals drift for
    hundreds of samples under white sensor noise. 40 runs of 3000 samples, steps every 150 s.
    Measured: empirical / stated std a 1.19, b 1.19, 2σ coverage 0.875 and 0.975 (with the
    Newey–West estimate and Andrews' AR(1) bandwidth, which the white part cuts short:
    1.46 and 1.39, coverage 0.825 and 0.825)."""
    truth = dict(a=0.01, b=0.01)
    plant, model = slow_plant(**truth, q=0.01), slow_plant(0.013, 0.008)
    err, std = [], []
    for i in range(40):
        rng = np.random.default_rng(100 + i)
        U = np.repeat(rng.choice([-1.0, 1.0], size=3000 // 150 + 1), 150)[:3000, None]
        _, Y = simulate(plant, U, np.zeros(1), rng, q_std=np.array([0.01]))
        res = fit(model, [recording(model, U, Y)], method="output-error", show_progress=False)
        err.append([res.parameters[n]["value"] - truth[n] for n in truth])
        std.append([res.parameters[n]["std"] for n in truth])
    err, std = np.array(err), np.array(std)
    ratio, cover = err.std(axis=0) / std.mean(axis=0), (np.abs(err) <= 2 * std).mean(axis=0)
    print("empirical / stated std", ratio, "coverage", cover)
    assert (ratio < 1.3).all() and (cover >= 0.85).all()
    assert "autoregressive" in res.covariance_note


def test_scores_covariance_follows_a_slow_drift_under_white_noise():
    """B = Var(Σ J_kᵀ ρ_k) against its exact value Jᵀ Σ J for residuals that are an AR(1) drift
    (φ = 0.995) under 10× stronger white noise, 20 realisations of 6000 samples. Measured:
    estimate / exact 0.70 (sensitivity a sine of period 1500) and 1.10 (a square wave of period
    700), std 0.21 and 0.23; the white-noise Fisher information is 49 and 17 times too small, and
    Newey–West with Andrews' bandwidth gave 0.07 and 0.19. White residuals: AR order 0, B = JᵀJ."""
    from scipy.linalg import toeplitz
    from scipy.signal import lfilter
    from skigen.fit.uncertainty import coloured_score_covariance
    N, phi = 6000, 0.995
    t = np.arange(N)
    J = np.c_[np.sin(2 * np.pi * t / 1500), 0.5 * np.sign(np.sin(2 * np.pi * t / 700))][:, None, :]
    acov = 0.05 ** 2 * phi ** t / (1 - phi ** 2)
    acov[0] += 1.0
    exact = np.diag(J[:, 0].T @ toeplitz(acov) @ J[:, 0])
    ratios = []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        rho = lfilter([1], [1, -phi], 0.05 * rng.normal(size=N)) + rng.normal(size=N)
        ratios.append(np.diag(coloured_score_covariance(J, rho[:, None])[0]) / exact)
    mean = np.mean(ratios, axis=0)
    print("estimate / exact", mean)
    assert 0.55 < mean[0] < 0.85 and 0.95 < mean[1] < 1.25
    white = np.random.default_rng(0).normal(size=(N, 1))
    B, orders = coloured_score_covariance(J, white)
    assert orders == [0]
    np.testing.assert_allclose(B, J[:, 0].T @ J[:, 0] * np.mean(white ** 2), rtol=1e-9)


# ------------------------------------------------------------------------- 2. bias

def test_filter_error_is_unbiased_in_closed_loop_where_output_error_is_not():
    """A mass-spring-damper under proportional feedback of its noisy measured position,
    u = r − Kp·y, with process noise: the simulated output of output error is correlated
    with the input through the loop, so its gain b is biased (measured over 20 runs:
    mean error −0.145, 5.4 standard errors); filter error's innovations are not (|t| ≤ 1.1)."""
    truth, Kp, q, N, runs = dict(k=2.0, d=0.4, b=1.0), 2.0, 0.05, 600, 20

    def msd(values):
        m = Model("msd", dt=0.05)
        x = m.state("x", std=0.1)
        v = m.state("v", std=0.1, process_std=q)
        u = m.input("u")
        k, d, b = (m.parameter(n, values[n]) for n in ("k", "d", "b"))
        m.dynamics({x: v, v: -k * x - d * v + b * u})
        m.output("pos", x, noise_std=0.02)
        return m

    plant, model = msd(truth), msd(dict(k=1.5, d=0.6, b=1.3))
    aug = augment(plant)
    F = ca.Function("f", [aug.z, aug.u], [aug.f])
    errors = {m: {n: [] for n in truth} for m in ("output-error", "filter-error")}
    for i in range(runs):
        rng = np.random.default_rng(3000 + i)
        ref = smooth_noise(rng, N, 10, 1.0)
        x, U, Y = rng.normal(size=2) * 0.1, np.zeros(N), np.zeros(N)
        for k in range(N):
            Y[k] = x[0] + 0.02 * rng.normal()
            U[k] = ref[k] - Kp * Y[k]
            x = np.asarray(F(x, U[k])).ravel() + np.array([0.0, q]) * rng.normal(size=2)
        rec = recording(model, U, Y)
        for method in errors:
            res = fit(model, [rec], method=method, show_progress=False)
            for n in truth:
                errors[method][n].append(res.parameters[n]["value"] - truth[n])
    t = {m: {n: np.mean(e) / (np.std(e, ddof=1) / np.sqrt(runs)) for n, e in d.items()} for m, d in errors.items()}
    print("t statistics of the mean error", t)
    assert t["output-error"]["b"] < -3                              # measured −5.4
    assert np.mean(errors["output-error"]["b"]) < -0.08             # measured −0.145 (15 % low)
    for n in truth:
        assert abs(t["filter-error"][n]) < 3, (n, t["filter-error"])
    assert abs(np.mean(errors["filter-error"]["b"])) < 0.03          # measured −0.013


# ------------------------------------------------------------------- 3. input hold

def test_first_order_hold_matches_a_smooth_input_and_recovers_parameters():
    """A linear oscillator driven by a sum of sines below 0.3 Hz, sampled at 10 Hz, against
    solve_ivp of the continuous system. Measured: free-run RMSE ZOH 0.066, FOH 0.0019
    (ratio 34); fitted ZOH k +7.2σ, d −3.9σ, b +1.6σ off; FOH within 1.6σ. (The σ is the
    sandwich under an AR model of the residuals, which are the hold's model error, coloured;
    with the Newey–West estimate and Andrews' bandwidth: k +11σ, d −8σ, b +4.8σ.)"""
    truth, dt, N = dict(k=4.0, d=0.4, b=2.0), 0.1, 400

    def osc(values, hold):
        m = Model(f"osc_{hold}", dt=dt, input_hold=hold, substeps=4)
        y = m.state("y", std=0.1)
        v = m.state("v", std=0.1)
        u = m.input("u")
        k, d, b = (m.parameter(n, values[n]) for n in ("k", "d", "b"))
        m.dynamics({y: v, v: -k * y - d * v + b * u})
        m.output("pos", y, noise_std=0.01)
        return m

    rng = np.random.default_rng(7)
    freqs, phase = np.linspace(0.03, 0.3, 10), rng.uniform(0, 2 * np.pi, 10)
    u_of = lambda t: np.sum(np.sin(2 * np.pi * np.outer(np.atleast_1d(t), freqs) + phase), axis=1) / 3
    t = np.arange(N) * dt
    sol = solve_ivp(lambda s, x: [x[1], -truth["k"] * x[0] - truth["d"] * x[1] + truth["b"] * u_of(s)[0]],
                    (0, t[-1]), [0.0, 0.0], t_eval=t, rtol=1e-10, atol=1e-12, max_step=dt / 10)
    U, y_true = u_of(t)[:, None], sol.y[0]
    rmse = {h: float(np.sqrt(np.mean((free_run(osc(truth, h), U, x0=[0, 0])[1][:, 0] - y_true) ** 2)))
            for h in ("zoh", "foh")}
    print("free-run RMSE against the continuous truth", rmse)
    assert rmse["foh"] < 0.003                                       # measured 0.0019
    assert rmse["zoh"] / rmse["foh"] > 25                            # measured 34
    rec = recording(osc(truth, "foh"), U, y_true + 0.01 * rng.normal(size=N))
    z = {}
    for hold in ("zoh", "foh"):
        res = fit(osc(dict(k=3.0, d=0.6, b=1.5), hold), [rec], show_progress=False)
        z[hold] = {n: (p["value"] - truth[n]) / p["std"] for n, p in res.parameters.items()}
    print("fitted error in std", z)
    assert max(abs(v) for v in z["zoh"].values()) > 6               # measured 7.2 (k)
    assert sum(abs(v) > 3 for v in z["zoh"].values()) == 2           # k and d biased
    assert max(abs(v) for v in z["foh"].values()) < 2.5              # measured 1.6 (d)


def test_output_error_does_not_depend_on_the_size_of_a_declared_r():
    """A filter-error calibration can leave R at 10⁻²⁰ (it trusts the sensor and calls the model
    error process noise); output error must give the same fit from such a model. Measured: with
    R = 10⁻²⁰ and no reweighing IPOPT stops at its iteration limit (on Silverbox: "search direction
    becomes too small"); reweighed,
    the estimates equal those with the declared R to 1e-9."""
    rng = np.random.default_rng(3)
    U = smooth_noise(rng, 500, 5, 3.0)[:, None]
    _, Y = simulate(duffing(DUFFING), U, [0.1, 0.0], rng)
    rec = recording(duffing(DUFFING), U, Y)
    fits = {}
    for R in (None, 1e-20):
        m = duffing(DUFFING_START)
        if R:
            m.covariances(R=np.array([[R]]))
        fits[R] = fit(m, [rec], show_progress=False)
    for n, p in fits[None].parameters.items():
        assert fits[1e-20].parameters[n]["value"] == pytest.approx(p["value"], rel=1e-9, abs=1e-12)
        assert fits[1e-20].parameters[n]["std"] == pytest.approx(p["std"], rel=1e-6)
    assert fits[1e-20].model.measurement_noise()[0, 0] == 1e-20          # the fitted model keeps its R


# -------------------------------------------------------------- 4. online vs offline

def test_online_estimate_matches_the_offline_fit():
    """The UKF estimating k and b online over a recording ends where filter error puts them,
    within their combined std. Measured: k online 3.9948 ± 0.029, offline 3.9950 ± 0.031;
    b online 0.99415 ± 0.0085, offline 0.99397 ± 0.0088."""
    truth = dict(k=4.0, d=0.5, k3=1.0, b=1.0)
    q = (0.0, 0.02)
    plant = duffing(truth, q=q)
    model = duffing(dict(k=3.5, d=0.5, k3=1.0, b=1.2), q=q, name="duffing_online")
    model.set_parameters({}, std={"k": 1.0, "b": 0.5})
    rng = np.random.default_rng(11)
    N = 800
    U = smooth_noise(rng, N, 5, 3.0)[:, None]
    _, Y = simulate(plant, U, rng.normal(size=2) * 0.2, rng, q_std=q)
    rec = recording(model, U, Y)
    off = fit(model, [rec], method="filter-error", estimate=["k", "b"], show_progress=False)
    on = run(derive(model, "ukf", estimate=["k", "b"]), rec, show_progress=False)
    for n in ("k", "b"):
        i = on.names.index(n)
        online, online_std = on.mean[-1, i], on.std[-1, i]
        p = off.parameters[n]
        print(n, "online", online, "±", online_std, "offline", p["value"], "±", p["std"])
        assert abs(online - p["value"]) <= 2 * np.hypot(online_std, p["std"])
        assert abs(online - p["value"]) <= 0.25 * p["std"]           # measured 0.01 (k), 0.02 (b)
        assert abs(p["value"] - truth[n]) <= 3 * p["std"]
        assert 0.5 < online_std / p["std"] < 2
        assert f"  {n:16s} {online:+.6g} ± {2 * online_std:.2g}" in on.summary().lines()   # the run says it


# ------------------------------------------------------------- 5. C step with FOH

def test_c_step_with_first_order_hold_equals_the_python_step():
    if shutil.which("gcc") is None:
        pytest.skip("gcc not installed: apt-get install -y gcc")
    from skigen.emit.c import load_c
    model = duffing(DUFFING, q=(0.0, 0.02), name="duffing_foh_c")
    filt = derive(model, "ukf")
    assert filt.aug.u_names == ["u", "u_next"]
    rng = np.random.default_rng(5)
    N = 200
    U = smooth_noise(rng, N, 5, 3.0)[:, None]
    _, Y = simulate(model, U, [0.1, 0.0], rng, q_std=(0.0, 0.02))
    steps = step_inputs(model, U)
    c, py = load_c(filt, "double"), PythonStepper(filt)
    worst = 0.0
    for k in range(N):
        y = [np.nan] if k % 9 == 4 else Y[k]                          # some samples not measured
        assert c.step(steps[k], y) == py.step(steps[k], y)
        worst = max(worst, float(np.max(np.abs(c.get("z_post") - py.z_post))))
        np.testing.assert_allclose(c.get("z_post"), py.z_post, rtol=0, atol=1e-9)
    # the hold matters: stepping with [u[k], u[k]] (a zero-order hold) gives another estimate
    py_zoh = PythonStepper(filt)
    for k in range(N):
        py_zoh.step(np.r_[U[k], U[k]], Y[k])
    assert np.max(np.abs(py_zoh.z_post - py.z_post)) > 1e-4
    print("max |z_post C - Python|", worst)


# ----------------------------------------------------------------------- 6. errors

def _linear(name="lin", **kw):
    m = Model(name, dt=0.05, **kw)
    y = m.state("y", std=0.2)
    v = m.state("v", std=0.2)
    u = m.input("u")
    return m, y, v, u


def test_a_bad_filter_start_is_named():
    """fit(starts=...) takes per recording (mean, covariance) or None; a wrong size, a non-finite
    number or a start for output error is refused, naming the recording and the states."""
    model = pendulum(PENDULUM)
    rng = np.random.default_rng(8)
    U = smooth_noise(rng, 100, 8, 2.0)[:, None]
    _, Y = simulate(model, U, np.array([0.1, 0.0]), rng)
    rec = recording(model, U, Y, path="swing.csv")
    for starts in ([(np.zeros(3), np.eye(2))], [(np.zeros(2), np.full((2, 2), np.nan))], [None, None]):
        with pytest.raises(ValueError, match="swing.csv.*theta, w|2 given for 1 recordings"):
            fit(model, [rec], method="filter-error", starts=starts, show_progress=False)
    with pytest.raises(ValueError, match="starts applies to filter error"):
        fit(model, [rec], method="output-error", starts=[None], show_progress=False)
    free = fit(model, [rec], method="filter-error", starts=[None], estimate=[], show_progress=False)
    same = fit(model, [rec], method="filter-error", estimate=[], show_progress=False)
    assert free.noise["scales"] == same.noise["scales"]          # None: the model's own start


def test_parameter_declaration_errors_name_the_parameter():
    m, y, v, u = _linear()
    with pytest.raises(ModelError, match="'stiff'.*finite"):
        m.parameter("stiff", float("nan"))
    with pytest.raises(ModelError, match="'stiff'.*finite"):
        m.parameter("stiff", float("inf"))
    with pytest.raises(ModelError, match="'stiff'.*outside its bounds"):
        m.parameter("stiff", -1.0, bounds=(0, 10))
    with pytest.raises(ModelError, match="'stiff'.*std must be positive"):
        m.parameter("stiff", 1.0, std=-0.1)
    k = m.parameter("k", 4.0, bounds=(0, 10))
    m.dynamics({y: v, v: -k * y + u})
    m.output("pos", y, noise_std=0.01)
    with pytest.raises(ModelError, match="'k'.*outside its bounds"):
        m.set_parameters({"k": 11.0})
    with pytest.raises(ModelError, match="'k'.*std must be positive"):
        m.set_parameters({}, std={"k": -1.0})
    with pytest.raises(ModelError, match="no parameter 'spring'.*parameters: k"):
        m.set_parameters({"spring": 1.0})
    rng = np.random.default_rng(0)
    rec = recording(m, rng.normal(size=(50, 1)), rng.normal(size=(50, 1)))
    with pytest.raises(ModelError, match="cannot estimate 'spring'.*parameters: k"):
        fit(m, [rec], estimate=["spring"], show_progress=False)
    with pytest.raises(ModelError, match="'spring'"):
        derive(m, "ukf", estimate=["spring"])
    with pytest.raises(ModelError, match="'k' is estimated online but declares no std"):
        derive(m, "ukf", estimate=["k"])


def test_foh_needs_continuous_dynamics():
    with pytest.raises(ModelError, match="input_hold='foh'.*'discrete'"):
        Model("d", dt=0.1, discretization="discrete", input_hold="foh")
    with pytest.raises(ModelError, match="input_hold must be one of"):
        Model("d", dt=0.1, input_hold="spline")


def _excited(model, seed=0, N=300):
    rng = np.random.default_rng(seed)
    U = smooth_noise(rng, N, 5, 1.0)[:, None]
    _, Y = free_run(model, U)
    return recording(model, U, Y + 0.01 * rng.normal(size=Y.shape))


@pytest.mark.parametrize("method", ["output-error", "filter-error"])
def test_unidentifiable_parameters_are_named(method):
    m, y, v, u = _linear(f"product_{method[0]}e")
    a, b, k = m.parameter("a", 2.0), m.parameter("b", 0.5), m.parameter("k", 4.0)
    m.dynamics({y: v, v: -k * y - 0.5 * v + a * b * u})         # only the product a·b is seen
    m.output("pos", y, noise_std=0.01)
    with pytest.raises(NotIdentifiable, match=r"'a', 'b' cannot be told apart|'b', 'a' cannot be told apart") as info:
        fit(m, [_excited(m)], method=method, show_progress=False)
    assert len(info.value.lost) == 1 and "cannot be told apart" in info.value.lost[0]   # without the advice
    res = fit(m, [_excited(m)], method=method, estimate=["a", "k"], show_progress=False)   # b fixed: fine
    assert abs(res.parameters["a"]["value"] - 2.0) < 4 * res.parameters["a"]["std"]

    m, y, v, u = _linear(f"unused_{method[0]}e")
    k = m.parameter("k", 4.0)
    m.parameter("c", 1.0)
    m.dynamics({y: v, v: -k * y - 0.5 * v + u})                  # c appears nowhere
    m.output("pos", y, noise_std=0.01)                           # held, and said (it was refused)
    assert list(fit(m, [_excited(m)], method=method, show_progress=False).parameters) == ["k"]


def test_a_start_whose_free_run_cannot_tell_weights_apart_is_not_refused_when_the_data_can():
    """A rate whose acceleration is all unknown (1, u, |v|v), every weight starting at 0: the free run
    at the start is a constant rate, along which |v|v is the constant term, so the check at the
    starting values said 'cannot be told apart' and output error refused a recording that
    identifies both (a fixed-wing roll channel; filter error fitted it). The check is redone at
    the optimum: the fit goes on and recovers the truth, with a note."""
    m = Model("roll_rate", dt=0.05)
    v, u = m.state("v", std=0.5), m.input("u")
    m.dynamics({v: 0 * v})
    m.output("gyro", v, noise_std=0.02)
    m.unknown(v, [term("one", 1 + 0 * v, key="one"), term("u", u), term("vv", ca.fabs(v) * v)])
    truth = Model("roll_truth", dt=0.05)
    vt, ut = truth.state("v", std=0.5), truth.input("u")
    truth.dynamics({vt: 0.5 + 3.0 * ut - 0.8 * ca.fabs(vt) * vt})
    truth.output("gyro", vt, noise_std=0.02)
    rec = _excited(truth, N=600)
    res = fit(m, [rec], method="output-error", show_progress=False)
    for name, value in {"w_one": 0.5, "w_u": 3.0, "w_vv": -0.8}.items():
        w = res.weights[name]
        assert abs(w["value"] - value) < 4 * w["std"] < 0.1, (name, w)
    assert any(n.startswith("output error: at the starting values the free run did not tell") for n in res.notes)



def test_an_initial_state_no_output_sees_is_held():
    """A motor and its load with the shaft spring left out: the load's angle enters no output,
    and output error refused the fit ('thl@0' has no effect on the likelihood), advising
    --estimate, which takes no initial state. That start is held, with a note, as filter error
    holds such a state's noise."""
    m, y, v, u = _linear("unseen")
    angle = m.state("angle", std=0.2)
    k = m.parameter("k", 3.0)
    m.dynamics({y: v, v: -k * y - 0.5 * v + u, angle: v})
    m.output("pos", y, noise_std=0.01)
    truth, yt, vt, ut = _linear("unseen_truth")
    truth.dynamics({yt: vt, vt: -4.0 * yt - 0.5 * vt + ut})
    truth.output("pos", yt, noise_std=0.01)
    res = fit(m, [_excited(truth, N=400)], method="output-error", show_progress=False)
    assert abs(res.parameters["k"]["value"] - 4.0) < 3 * res.parameters["k"]["std"] < 0.02, res.parameters["k"]
    assert "the initial value of angle is held at the declared one: no output sees it" in res.notes

def test_a_stuck_output_is_named_not_fitted():
    m, y, v, u = _linear("stuck")
    k = m.parameter("k", 4.0)
    m.dynamics({y: v, v: -k * y - 0.5 * v + u})
    m.output("pos", y, noise_std=0.01)
    rec = _excited(m, N=400)
    stuck = dataclasses.replace(rec, outputs=np.where(np.isfinite(rec.outputs), 0.0, np.nan))
    with pytest.raises(FitError, match=r"output 'pos' reads 0 in all \d+ samples .* stuck or disconnected"):
        fit(m, [stuck], show_progress=False)


def _pendulum_frame(rng, N=600):
    """A simulated pendulum flight (PENDULUM) as a DataFrame: t, u, angle."""
    import pandas as pd
    plant = pendulum(PENDULUM)
    U = smooth_noise(rng, N, 8, 2.0)
    _, Y = simulate(plant, U[:, None], np.array([0.1, 0.0]), rng)
    return pd.DataFrame(dict(t=np.arange(N) * plant.dt, u=U, angle=Y[:, 0]))


def _heater(gain):
    """Heater and thermal mass: dT/dt = (−(T − 20) + K·P)/60, T measured (std 0.05 °C) every 0.5 s."""
    m = Model("heater", dt=0.5)
    T = m.state("T", unit="degC", initial=20.0, std=1.0, process_std=0.005)
    P = m.input("P", unit="W")
    K = m.parameter("K", gain, unit="degC/W", std=0.2)
    m.dynamics({T: (-(T - 20.0) + K * P) / 60.0})
    m.output("T_meas", T, unit="degC", noise_std=0.05)
    return m


@pytest.mark.parametrize("restart", ["both", "moved", "held", None])
def test_filter_error_leaves_the_noise_basin_of_a_wrong_start(monkeypatch, restart):
    """K declared 0.35 for a true 0.5: at the start its error is process noise, and scoring keeps
    that basin after K has moved to its value (measured with both restarts switched off: sensor
    noise 3.9e-5 °C for 0.05, process noise 0.071 for 0.005, K ± 0.0025, 911 nats short). The
    noise started again from the declared values at the estimates ("moved"), or the parameters
    fitted with the declared noise held ("held"), is more likely: the fit goes on from there
    (measured: 0.0500, 0.0049, K 0.49978 ± 0.00018)."""
    fitting = sys.modules["skigen.fit"]
    monkeypatch.setattr(fitting, "MOVED", fitting.MOVED if restart in ("both", "moved") else np.inf)
    monkeypatch.setattr(fitting, "HELD_JUMP", fitting.HELD_JUMP if restart in ("both", "held") else np.inf)
    rng = np.random.default_rng(1)
    hold = rng.integers(60, 240, 40)
    P = np.repeat(rng.uniform(0, 100, 40), hold)[:3000]
    X, Y = simulate(_heater(0.5), P[:, None], np.array([20.0]), rng, q_std=(0.005,))
    res = fit(_heater(0.35), [recording(_heater(0.35), P, Y)], method="filter-error", show_progress=False)
    cal = res.noise["calibrated"]
    if restart is not None:
        assert cal["measurement_std"]["T_meas"] == pytest.approx(0.05, rel=0.05)
        assert cal["process_std"]["T"] == pytest.approx(0.005, rel=0.15)
        assert abs(res.parameters["K"]["value"] - 0.5) < 3 * res.parameters["K"]["std"] < 0.002
    else:
        assert cal["measurement_std"]["T_meas"] < 0.01


def test_a_parameter_fitted_far_from_its_starting_value_is_said():
    """A heater's power logged in mW where the model wants W: K came out 0.0015 for the 0.5
    declared (its prior 0.5 ± 0.2 holding it above the 0.0005 the data want), with no note (the diagnosis said it; the fit did not). A fit that moves a
    parameter 10× or more says so and points at the units; one that does not says nothing."""
    rng = np.random.default_rng(2)
    P = np.repeat(rng.uniform(0, 100, 30), 100)
    _, Y = simulate(_heater(0.5), P[:, None], np.array([20.0]), rng, q_std=(0.005,))
    for power, far in ((P, False), (1000 * P, True)):
        res = fit(_heater(0.5), [recording(_heater(0.5), power, Y)], show_progress=False)
        said = [n for n in res.notes if n.startswith("K = ") and "check the units" in n]
        assert bool(said) == far, res.notes
    assert res.parameters["K"]["value"] < 0.05 and "for the 0.5 declared (0.00" in said[0], said
    assert said[0].endswith("×): check the units of the inputs and outputs it acts through before reading the rest")
    from skigen.fit import _far_notes              # hardly determined: no unit is blamed for it
    assert _far_notes({"cd": dict(initial=0.3, value=0.00136, std=0.74)}) == []
    assert _far_notes({"cd": dict(initial=0.3, value=0.00136, std=0.0001)}) != []
    assert _far_notes({"cd": dict(initial=0.3, value=0.00136, std=0.001)}) == []     # zero within 2 std: absent


def test_a_parameter_used_nowhere_is_held_by_default_and_refused_when_named():
    """A declared parameter no equation uses blocked the whole fit with "'g' has no effect on the
    likelihood ... record richer excitation": it is held with a note saying why, and refused by
    name when asked for."""
    rng = np.random.default_rng(2)
    P = np.repeat(rng.uniform(0, 100, 10), 100)
    _, Y = simulate(_heater(0.5), P[:, None], np.array([20.0]), rng, q_std=(0.005,))
    m = _heater(0.4)
    m.parameter("g", 2.0, unit="1")
    res = fit(m, [recording(m, P, Y)], show_progress=False)
    assert list(res.parameters) == ["K"] and abs(res.parameters["K"]["value"] - 0.5) < 0.005      # measured 0.4993
    assert "parameter(s) 'g' used in no equation or output of 'heater': held at the declared value" in res.notes
    with pytest.raises(ModelError, match="cannot estimate 'g': declared in model 'heater' but used in no equation"):
        fit(m, [recording(m, P, Y)], estimate=["K", "g"], show_progress=False)


def test_an_input_hole_cuts_the_recording_into_parts_fitted_apart():
    """An input without a sample for longer than max_gap is not its held value: the fit takes the
    stretches on either side as two recordings (each with its own initial state), says so, and
    recovers the truth within 3σ. Fitting through the hole on the held input instead leaves a
    free run 24× the sensor noise off the recording (RMSE 0.245 against 0.010 rad) and every
    estimate but a off by more than 50σ of the honest fit (b 1.59, fc 1.77; measured)."""
    from skigen.recording import load_recording
    frame = _pendulum_frame(np.random.default_rng(5))
    frame.loc[200:299, "u"] = np.nan                               # 4 s (100 samples) without u
    model = pendulum(PENDULUM_START)
    rec = load_recording(frame, model)
    assert [(p.t[0], p.t[-1]) for p in rec.input_parts()] == [(rec.t[0], rec.t[199]), (rec.t[300], rec.t[-1])]
    res = fit(model, [rec], show_progress=False)
    assert [r["samples"] for r in res.recordings] == [200, 300] and len(res.initial_states) == 2
    assert len(res.notes) == 1 and "fitted as 2 recordings, 0–7.96 s, 12–23.96 s" in res.notes[0]
    for n, p in res.parameters.items():
        assert abs(p["value"] - PENDULUM[n]) < 3 * p["std"], (n, p)
    (held,) = fit(model, [dataclasses.replace(rec, holes=())], show_progress=False).recordings
    assert held["rmse"]["angle"] > 10 * max(r["rmse"]["angle"] for r in res.recordings), held


def test_an_output_hole_is_said_with_its_share_of_the_recording():
    """The angle missing for 4 s of 24: the fit goes through (the input is known) and says where it
    saw nothing, as `skigen run` and a diagnosis do (before, not a word)."""
    from skigen.recording import load_recording
    frame = _pendulum_frame(np.random.default_rng(5))
    frame.loc[200:299, "angle"] = np.nan
    model = pendulum(PENDULUM_START)
    res = fit(model, [load_recording(frame, model)], show_progress=False)
    (note,) = [n for n in res.notes if "output hole" in n]
    assert "output hole(s) longer than max_gap = 1 s, 17% of the recording: 7.96–12 s (4.04 s) without angle" in note
    for n, p in res.parameters.items():
        assert abs(p["value"] - PENDULUM[n]) < 3 * p["std"], (n, p)


def test_several_dataframes_are_told_apart_by_place():
    """Two pendulum flights given as DataFrames: each recording of the result is named by its
    place (both were 'DataFrame'); a file given once keeps its name."""
    model = pendulum(PENDULUM_START)
    res = fit(model, [_pendulum_frame(np.random.default_rng(k), N=300) for k in (10, 11)], show_progress=False)
    assert [r["file"] for r in res.recordings] == ["DataFrame #1", "DataFrame #2"]
    assert [str(r.path) for r in res.fitted_recordings] == ["DataFrame #1", "DataFrame #2"]
    assert not any("residuals on angle differ" in n for n in res.notes)


def test_a_joint_fit_says_when_the_recordings_residuals_differ():
    """Two pendulum flights, the second read with 4× more noise: one sensor noise serves both,
    and the fit says so, naming the two (said of none when they are alike, above)."""
    model = pendulum(PENDULUM_START)
    a, b = (_pendulum_frame(np.random.default_rng(k), N=300) for k in (10, 11))
    b["angle"] += np.random.default_rng(3).normal(0, 0.04, len(b))          # the declared 0.01, and 0.041
    res = fit(model, [a, b], show_progress=False)
    (said,) = [n for n in res.notes if "residuals on angle differ" in n]
    lo, hi = (float(x) for x in re.search(r"next, ([0-9.e-]+) \(DataFrame #1\) to ([0-9.e-]+) \(DataFrame #2\)",
                                           said).groups())
    assert abs(lo / 0.01 - 1) < 0.1 and abs(hi / np.hypot(0.01, 0.04) - 1) < 0.1, said



def test_recordings_whose_free_runs_drift_apart_are_not_said_to_differ():
    """Output error on two runs of a damped cart, 6 s and 60 s, kicked on its velocity (0.02 m/s
    per sample): the longer free run drifts further (RMSE 0.020 and 0.43 m, measured) with the
    same 1 mm encoder, and the fit said the recordings' residuals differ 22-fold. Their second
    differences do not (that of a flight read with 4× more noise, above, does)."""
    def cart(c):
        m = Model("drift", dt=0.05)
        p, v = m.state("p", std=0.01), m.state("v", std=0.01, process_std=0.02)
        m.dynamics({p: v, v: -m.parameter("c", c) * v + m.input("u")})
        m.output("pos", p, noise_std=0.001)
        return m
    rng = np.random.default_rng(4)
    recs = []
    for N in (120, 1200):
        U = smooth_noise(rng, N, 10, 1.0)[:, None]
        recs.append(recording(cart(0.5), U, simulate(cart(0.5), U, np.zeros(2), rng, q_std=[0.0, 0.02])[1], f"r{N}"))
    res = fit(cart(0.3), recs, method="output-error", show_progress=False)
    rmse = [r["rmse"]["pos"] for r in res.recordings]
    assert rmse[1] > 10 * rmse[0], rmse
    assert not any("differ" in n for n in res.notes), res.notes

def test_a_recording_in_other_units_is_said():
    """A fleet's roll angle logged in degrees was fitted to RMSE 8.9 (0.01 on the others) under the
    note every healthy flight gets; the declared model's free run times 180/π is the recording: said,
    naming it, and of no other."""
    model = pendulum(PENDULUM)
    a, b = (_pendulum_frame(np.random.default_rng(k), N=300) for k in (10, 11))
    b["angle"] = np.degrees(b["angle"])
    with pytest.raises(FitError, match=r"diverges|amplifies") as exc:          # a pendulum in degrees: chaotic
        fit(model, [a, b], show_progress=False)
    said = str(exc.value).rpartition(" (check the units: ")[2]
    assert said.endswith("is the recording in degrees where the model declares radians? (DataFrame #2))"), said
    assert float(said.split(" is ")[1].split("×")[0]) == pytest.approx(180 / np.pi, rel=0.01)
    b["angle"] = np.radians(b["angle"]) * 1.02                                   # within 3 % of no unit
    assert not [n for n in fit(model, [a, b], show_progress=False).notes if "units" in n]
    m, y, v, u = _linear()                       # the velocity read in mm/s, the position in m: fitted, and said
    k = m.parameter("k", 4.0)
    m.dynamics({y: v, v: -k * y - 0.5 * v + u})
    m.output("pos", y, noise_std=0.01)
    m.output("vel", v, noise_std=0.01)
    rec = _excited(m)
    rec = dataclasses.replace(rec, outputs=rec.outputs * [1.0, 1000.0])
    res = fit(m, rec, show_progress=False)
    assert [n for n in res.notes if "units" in n] == [
        f"check the units: output 'vel' is {res.notes[0].split(' is ')[1].split('×')[0]}× the nominal free run: "
        f"is the recording in a unit 1000× smaller (mm for m, mV for V)?"], res.notes
    assert res.parameters["k"]["value"] == pytest.approx(4.0, rel=0.05)


def _fleet(seed, odd=None, q=(0.0, 0.05)):
    """Four pendulum flights with process noise; flight ``odd`` of a stiffer pendulum (a 13 for 10)."""
    out = []
    for k in range(4):
        plant = pendulum(dict(PENDULUM, a=13.0) if k == odd else PENDULUM, q=q)
        rng = np.random.default_rng(1000 * seed + k)
        U = smooth_noise(rng, 400, 8, 2.0)[:, None]
        _, Y = simulate(plant, U, np.array([0.1, 0.0]), rng, q_std=np.array(q) * np.sqrt(plant.dt))
        out.append(recording(plant, U, Y, path=f"flight{k}.csv"))
    return out


def test_a_recording_of_another_vehicle_is_named_by_filter_error():
    """Three flights and one of another vehicle (Lp −6 for −4) were fitted together to Lp −3.2 ± 0.06,
    neither's, with no word of which flight disagreed. Each flight's own values, a step from the
    pooled fit, are compared pair by pair, and where they differ, each flight fitted alone: the
    stiffer pendulum's flight is named with its own value, and fleets of one pendulum are not (none
    of 60 at this level; 2 at 0.01, scratch run)."""
    model = pendulum(PENDULUM_START, q=(0.0, 0.05))
    res = fit(model, _fleet(0, odd=3), method="filter-error", show_progress=False)
    (said,) = [n for n in res.notes if "disagree" in n]
    assert said.startswith("filter error: recordings disagree with most others") and "flight3.csv" in said
    assert not any(f"flight{k}.csv" in said for k in range(3)), said
    a = float(re.search(r"flight3.csv \(fitted alone: a ≈ ([0-9.]+)", said).group(1))
    assert 12.5 < a < 13.5 and res.parameters["a"]["value"] < 11.5, (a, res.parameters["a"])  # 13; the pool near 10
    for seed in range(3):
        res = fit(model, _fleet(seed), method="filter-error", show_progress=False)
        assert not [n for n in res.notes if "disagree" in n], (seed, res.notes)


def _motor(Kt=0.4, b=0.03, R=2.5):
    """A DC motor, speed and current measured; its torque constant, friction and resistance declared."""
    m = Model("motor", dt=0.005)
    w, i = m.state("w", std=0.2, process_std=0.02), m.state("i", std=0.1, process_std=0.005)
    Kt, b, R = (m.parameter(n, v, bounds=(1e-3, 50.0)) for n, v in (("Kt", Kt), ("b", b), ("R", R)))
    m.dynamics({w: (Kt * i - b * w) / 0.01, i: (m.input("V") - R * i - Kt * w) / 0.05})
    m.output("speed_m", w, noise_std=0.05)
    m.output("cur_m", i, noise_std=0.02)
    return m


def test_the_recording_that_disagrees_is_named_alone():
    """Four motor runs, the third of a motor whose torque constant is 0.6 for 0.5: the pooled fit
    (0.524) pulled every run's step off its own, and all four were said to disagree. Where the steps
    disagree, each run is fitted alone, and only the third is named, with its own value; the pool's
    sensor noise, 7·10⁻⁸ of the declared, is said too."""
    recs = []
    for k, (N, Kt) in enumerate(((2000, 0.5), (500, 0.5), (2000, 0.6), (1500, 0.5))):
        rng = np.random.default_rng(k)
        U = np.repeat(rng.uniform(-12, 12, N // 100 + 1), 100)[:N, None]
        plant = _motor(Kt, 0.05, 2.0)
        recs.append(recording(plant, U, simulate(plant, U, np.zeros(2), rng, q_std=np.array([0.02, 0.005]))[1],
                              path=f"motor{k}.csv"))
    res = fit(_motor(), recs, method="filter-error", show_progress=False)
    (said,) = [n for n in res.notes if "on the parameters (each recording" in n]
    assert said.startswith("filter error: recordings disagree with most others") and "motor2.csv" in said, said
    assert not any(f"motor{k}.csv" in said for k in (0, 1, 3)), said
    Kt = float(re.search(r"motor2.csv \(fitted alone: Kt ≈ ([0-9.]+)", said).group(1))
    assert abs(Kt - 0.6) < 0.005 and abs(res.parameters["Kt"]["value"] - 0.524) < 0.01, (Kt, res.parameters["Kt"])
    assert any(n.startswith("filter error: the sensor noise on speed_m ") for n in res.notes), res.notes

def test_a_run_that_starts_spinning_draws_no_false_notes():
    """Two runs of a right motor model, the second found spinning (12 rad/s, 3 A; declared 0 ± 0.2
    and 0 ± 0.1): the fit starts it from the vague prior and gets the constants, but its innovations
    were judged 'not white' from the declared start, and its residuals '2.1-fold' the other's over
    the head where the filter learns the start. Both are judged as the fit ran it: no such note."""
    recs = []
    for k, x0 in enumerate(([0.0, 0.0], [12.0, 3.0])):
        rng = np.random.default_rng(10 + k)
        U = np.repeat(rng.uniform(-12, 12, 21), 100)[:2000, None]
        plant = _motor(0.5, 0.05, 2.0)
        recs.append(recording(plant, U, simulate(plant, U, np.array(x0), rng, q_std=np.array([0.02, 0.005]))[1],
                              path=f"run{k}.csv"))
    res = fit(_motor(), recs, method="filter-error", show_progress=False)
    assert any("run1.csv: the recording does not start at the model's initial state" in n for n in res.notes)
    assert not [n for n in res.notes if "not white" in n or "differ" in n], res.notes
    for name, truth in (("Kt", 0.5), ("b", 0.05), ("R", 2.0)):
        p = res.parameters[name]
        assert abs(p["value"] - truth) < 3 * p["std"], (name, p)


def test_validation_leaves_out_a_stuck_sensor_and_cuts_at_input_holes():
    """A held-out recording is read as the fit reads its own: the readings of a sensor stuck for
    2 s are left out of the RMSE (counted, the frozen angle scores 0.477 rad against 0.0104 without
    it; measured) and a 2 s input hole cuts it into two parts, each started from its own first samples; both
    are said. The declared values are scored there too: what the fit changed on a recording it
    never saw (the CLI gave the fitted model's RMSE alone)."""
    from skigen.fit.output import validate
    from skigen.recording import load_recording
    model = pendulum(PENDULUM_START)
    res = fit(model, [_pendulum_frame(np.random.default_rng(8))], show_progress=False)
    frame = _pendulum_frame(np.random.default_rng(9))
    (clean,) = validate(res, [load_recording(frame, model)], declared=model)
    assert clean["rmse_declared"]["angle"] > 20 * clean["rmse"]["angle"]    # 0.279 for 0.0103: the fit's worth there
    frame.loc[300:399, "angle"] = frame.loc[300, "angle"]
    frame.loc[480:529, "u"] = np.nan
    checks = validate(res, [load_recording(frame, model)])
    assert [c["samples"] for c in checks] == [480 - 50, 600 - 530 - 50]
    assert checks[0]["rmse"]["angle"] == pytest.approx(clean["rmse"]["angle"], rel=0.03)
    assert [len(c["notes"]) for c in checks] == [2, 0]
    assert "stuck sensor" in checks[0]["notes"][0] and "validated as 2 recordings" in checks[0]["notes"][1]
    clean = _pendulum_frame(np.random.default_rng(9))           # and what reading it said (on the terminal only)
    rec = load_recording(clean.iloc[np.r_[0:10, 9:len(clean)]], model)            # one stamp twice
    (check,) = validate(res, [rec])
    assert rec.notes and check["notes"] == rec.said(), (rec.notes, check["notes"])


def test_an_estimate_on_its_bound_is_named():
    """The input gain b bounded below the truth (2) sits on the bound: its std is no interval,
    and the result says so; the other estimates are inside theirs. (The DataFrame is read with
    the options of skigen run: a time column in ms, an input under another name.)"""
    frame = _pendulum_frame(np.random.default_rng(6)).rename(columns={"t": "time_ms", "u": "torque"})
    frame["time_ms"] *= 1000
    model = pendulum(PENDULUM_START, b_bounds=(0.0, 1.5))
    res = fit(model, [frame], show_progress=False, time="time_ms", time_unit="ms", columns={"u": "torque"})
    assert res.parameters["b"]["value"] == pytest.approx(1.5, abs=1e-6)
    bound, residuals = res.notes              # the bound leaves the free run short of the data, and says so
    assert bound.startswith("b = 1.5 ± ") and "sits on its upper bound 1.5" in bound
    assert residuals.startswith("output error: the free-run residuals exceed the declared sensor noise (angle")


def test_strongly_correlated_estimates_are_said():
    """Estimates correlated beyond 0.99 are named in pairs (a car's Cf and Cr at 0.9965 were not);
    noise scales are not estimates a user reads, and are left out."""
    from skigen.fit import _correlated
    corr = dict(names=["Cf", "Cr", "Iz", "Q_scale_vy", "Q_scale_r"],
                matrix=[[1, 0.9965, 0.90, 0, 0], [0.9965, 1, 0.8997, 0, 0], [0.90, 0.8997, 1, 0, 0],
                        [0, 0, 0, 1, -0.995], [0, 0, 0, -0.995, 1]])
    (said,) = _correlated(corr, {"Cf", "Cr", "Iz"})
    assert said.startswith("Cf and Cr are correlated +0.997: the recordings determine a combination")


def test_a_value_is_printed_to_its_std_s_second_digit():
    """The fit's command line printed 'Cf = 78.5037 ± 1.2'; it prints as the diagnosis does."""
    from skigen.fit import plus_minus
    assert plus_minus(78.5037, 1.2) == "78.5 ± 1.2"
    assert plus_minus(0.300634, 0.00097) == "0.30063 ± 0.00097" and plus_minus(2399.812, 0.6) == "2399.81 ± 0.6"
    assert plus_minus(2.9999957e-4, 2.6e-8) == "0.000300000 ± 2.6e-08"       # not '0.0003 ± 2.6e-08'
    assert plus_minus(5.0, float("nan")) == "5 (no error bar)"


def test_a_vague_estimate_is_not_said_to_sit_on_a_bound():
    """Measured on a motor held at one steady state: J = 1.64 ± 6.6e4 above its bound 1e-5 was said
    to 'sit on its lower bound' (within 1e-3 std of it); it is far from it, and vague. An estimate
    at its bound, 1e-9 above 0, still sits on it."""
    from skigen.fit import _bound_notes
    J, = _bound_notes({"J": dict(value=1.63956, std=6.6e4, bounds=(1e-5, None))})
    assert "sits on" not in J and "its std is 4e+04 times its value" in J
    cd, = _bound_notes({"cd": dict(value=4.8e-10, std=0.04, bounds=(0.0, 5.0))})
    assert "sits on its lower bound 0" in cd
    assert _bound_notes({"R": dict(value=3.87, std=0.95, bounds=(0.01, None))}) == []


def test_derivatives_that_are_not_finite_are_a_fit_error_not_a_crash():
    """A discrete model's joint refit in a diagnosis met 7 188 of 7 200 rows of J non-finite and
    NumPy's eigh stopped the run ("Eigenvalues did not converge"); a FitError the diagnosis catches
    and says instead."""
    import types
    from skigen.fit import FitError, fisher
    J = np.ones((4, 2))
    J[1, 0] = np.nan
    prob = types.SimpleNamespace(fisher=lambda xi, data: (J, np.zeros(2)))
    with pytest.raises(FitError, match=r"not finite at the values found \(1 of 4 residuals\)"):
        fisher(prob, np.zeros(2), None)
    assert np.array_equal(fisher(types.SimpleNamespace(fisher=lambda xi, data: (np.eye(2), np.ones(2))),
                                 np.zeros(2), None)[0], np.eye(2))


def test_a_parameter_fitted_to_zero_is_said_absent_not_vague_nor_a_unit_slip():
    """A damping whose truth is 0 (declared 0.3, bounds [0, ∞)) came out 3.6e-6 ± 6.8e-5, and the
    fit said 'the data hardly determine it' and 'check the units': it is determined 4 400× more
    tightly than the declared value, and a value at zero says the effect is absent, not scaled."""
    from skigen.fit import _bound_notes, _far_notes
    c = dict(value=3.63153e-06, std=6.8e-05, initial=0.3, bounds=(0.0, None))
    said, = _bound_notes({"c": c})
    assert said == ("c = 3.63153e-06 ± 6.8e-05 is zero within its std, 4.41e+03 std from the 0.3 declared: what "
                    "it sets is absent from the recordings or below what they resolve")
    assert _far_notes({"c": c}) == []
    vague, = _bound_notes({"c": c | dict(std=0.2)})                  # no tighter than what was declared
    assert "the data hardly determine it" in vague


def test_an_output_never_measured_has_no_rmse(tmp_path):
    """fit.json stays valid JSON: an output without a single reading has RMSE null."""
    from skigen.fit.output import write_outputs
    frame = _pendulum_frame(np.random.default_rng(7), N=300).assign(rate=np.nan)
    model = pendulum(PENDULUM_START, rate_std=0.05)
    res = fit(model, [frame], show_progress=False)
    write_outputs(res, tmp_path, figures=False)
    (r,) = json.loads((tmp_path / "fit.json").read_text())["recordings"]
    assert r["rmse"]["rate"] is None and 0.005 < r["rmse"]["angle"] < 0.015
    assert "rate not measured" in (tmp_path / "report.md").read_text()


def test_diverging_simulation_names_the_time():
    stable, y, v, u = _linear("stable")
    k, d = stable.parameter("k", 4.0), stable.parameter("d", 0.5)
    stable.dynamics({y: v, v: -k * y - d * v + u})
    stable.output("pos", y, noise_std=0.01)
    rec = _excited(stable, N=400)
    unstable, y, v, u = _linear("unstable")
    k, d = unstable.parameter("k", 4.0), unstable.parameter("d", -40.0)    # negative damping: overflows
    unstable.dynamics({y: v, v: -k * y - d * v + u})
    unstable.output("pos", y, noise_std=0.01)
    with pytest.raises(FitError, match=r"'unstable' at the initial values diverges in sim at t = [0-9.]+ s "
                                       r"\(sample [0-9]+\).*shooting"):
        fit(unstable, [rec], show_progress=False)


# ---------------------------------------------------------------------------- CLI

MODEL_FILE = '''
from skigen import Model
model = Model("spring", dt=0.05, input_hold="foh")
y = model.state("y", std=0.2)
v = model.state("v", std=0.2)
u = model.input("u")
k = model.parameter("k", 3.0, unit="1/s^2", bounds=(0, 50))
d = model.parameter("d", 0.8, unit="1/s")
b = model.parameter("b", 1.3)
model.dynamics({y: v, v: -k * y - d * v + b * u})
model.output("pos", y, noise_std=0.01)
'''


@pytest.mark.parametrize("method", ["output-error", "filter-error"])
def test_cli_fit_writes_the_contract_and_a_loadable_fitted_model(tmp_path, method, capsys):
    from skigen.cli import main
    from skigen.modelfile import load_model
    spec = tmp_path / "spring.py"
    spec.write_text(MODEL_FILE)
    model = load_model(spec)
    truth = dict(k=4.0, d=0.5, b=1.0)
    plant = load_model(spec).set_parameters(truth)
    files = []
    for i, N in enumerate((400, 300)):
        rng = np.random.default_rng(40 + i)
        U = smooth_noise(rng, N, 5, 2.0)
        _, Y = free_run(plant, U[:, None])
        files.append(tmp_path / f"run{i}.csv")
        write_recording(files[-1], np.arange(N) * model.dt, {"u": U}, {"pos": Y[:, 0] + 0.01 * rng.normal(size=N)})
    out = tmp_path / "out"
    assert main(["fit", str(spec), str(files[0]), "--out", str(out), "--method", method,
                 "--validate", str(files[1]), "--no-figures"]) == 0
    data = json.loads((out / "fit.json").read_text())
    for key in ("parameters", "noise", "correlation", "recordings", "method", "converged", "iterations"):
        assert key in data, key
    assert data["method"] == method and data["converged"] is True and data["iterations"] > 0
    assert set(data["parameters"]) == {"k", "d", "b"}
    for n, p in data["parameters"].items():
        assert {"value", "std", "initial", "bounds"} <= set(p)
        assert p["initial"] == model.parameter_named(n).value
        assert abs(p["value"] - truth[n]) < 4 * p["std"], (n, p)
    assert data["parameters"]["k"]["bounds"] == [0.0, 50.0] and data["parameters"]["d"]["bounds"] == [None, None]
    assert data["correlation"]["names"][:3] == ["k", "d", "b"]
    C = np.array(data["correlation"]["matrix"])
    assert np.allclose(np.diag(C), 1) and np.allclose(C, C.T)
    (r,) = data["recordings"]
    assert r["file"] == str(files[0]) and {"rmse", "loglik"} <= set(r) and r["samples"] == 400
    assert 0.008 < r["rmse"]["pos"] < 0.012 if method == "output-error" else r["rmse"]["pos"] > 0
    assert data["validation"][0]["rmse"]["pos"] < 0.02
    if method == "filter-error":
        assert {"scales", "calibrated"} <= set(data["noise"])
        assert "R_scale_pos" in data["noise"]["scales"]
    else:
        assert "residual_std" in data["noise"]
    moved = tmp_path / "a" / "b" / "fitted_model.py"         # the file alone, moved: it still finds its model
    moved.parent.mkdir(parents=True)
    moved.write_text((out / "fitted_model.py").read_text())
    for path in (out / "fitted_model.py", moved):
        fitted = load_model(path)
        for n, p in data["parameters"].items():
            q = fitted.parameter_named(n)
            assert q.value == p["value"] and q.std == pytest.approx(p["std"])
    assert "fitted by" in capsys.readouterr().out
    assert (out / "report.md").exists()


def test_an_overflowing_information_is_not_read_and_not_warned_about():
    """A start whose filter diverges gives Jacobians of 1e200: their information overflows; the
    identifiability check reads nothing from it and numpy's overflow warning stays off the terminal."""
    import warnings
    from skigen.fit.uncertainty import unidentified
    J = np.array([[1e200, 1.0], [1e200, 2.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert unidentified(J, np.zeros(2), ["a", "b"]) == []
        assert unidentified(np.array([[1.0, 2.0], [2.0, 4.0]]), np.zeros(2), ["a", "b"])[0].startswith("'a', 'b' cannot")


def _predator_prey(a, g, d=0.02, b=0.1):
    """A stocked predator–prey pair (logistic prey, capacity 50), prey and predators counted."""
    m = Model("predprey", dt=0.1, discretization="rk4", substeps=2)
    x, y, u = m.state("prey", initial=25.0, std=2.0), m.state("pred", initial=5.0, std=1.0), m.input("stock")
    A, B, D, G = (m.parameter(n, v, bounds=(0, 10)) for n, v in (("a", a), ("b", b), ("d", d), ("g", g)))
    m.dynamics({x: A * x * (1 - x / 50.0) - B * x * y + u, y: D * x * y - G * y})
    m.output("prey_count", x, noise_std=0.3)
    m.output("pred_count", y, noise_std=0.1)
    return m


def _stocked_recording():
    """The predator–prey truth (a = 1, b = 0.1, d = 0.02, g = 0.5) under a user's multisine stocking."""
    rng, t = np.random.default_rng(1000), np.arange(2000) * 0.1
    s = np.sum(np.sin(2 * np.pi * np.linspace(0.05, 0.5, 20)[:, None] * t + rng.uniform(0, 2 * np.pi, 20)[:, None]), 0)
    u = np.clip(2.0 + 2.0 * s / np.std(s), 0, None)[:, None]
    truth = _predator_prey(1.0, 0.5)
    _, Y = free_run(truth, u)
    return recording(truth, u, Y + np.random.default_rng(0).normal(0, [0.3, 0.1], Y.shape))


def test_a_prior_the_data_contradict_and_a_filter_without_process_noise_are_said():
    """A prior a = 0.9 ± 0.005 against a truth of 1 gives a compromise 0.957 (measured), which the
    result now names; and a filter-error fit of a model without process noise says that it
    calibrates none (a user's plant noise went to the sensors and 4 of 4 parameters were 3σ off)."""
    rec = _stocked_recording()
    m = _predator_prey(0.9, 0.5).set_parameters({}, std={"a": 0.005})
    res = fit(m, [rec], method="filter-error", show_progress=False)
    assert res.parameters["a"]["value"] > 0.9 + 3 * 0.005
    assert any(n.startswith("a = ") and "prior std from its declared prior 0.9 ± 0.005" in n for n in res.notes)
    assert any("declares no process noise on any state, so filter error calibrates none" in n for n in res.notes)
    assert not any("prior" in n for n in fit(_predator_prey(1.0, 0.5), [rec], show_progress=False).notes)


@pytest.mark.parametrize("method", ["output-error", "filter-error"])
def test_a_tight_prior_the_data_contradict_is_said_with_where_the_data_alone_put_it(method):
    """a = 0.9 ± 0.0003 against a truth of 1 (the data alone: 0.994 ± 0.004) moves only 1.8–2
    prior std, so 'more than 3 prior std' never said it; the shift is 23–24 times the √(σ₀² − σ²)
    a right prior allows (measured), and the note says where the recordings alone put a
    (0.9867, measured). The same tight prior at the truth is not said (shift 1.3 of it)."""
    rec = _stocked_recording()
    res = fit(_predator_prey(0.9, 0.5).set_parameters({}, std={"a": 0.0003}), [rec], method=method,
              show_progress=False)
    (note,) = [n for n in res.notes if "disagree" in n]
    assert abs(res.parameters["a"]["value"] - 0.9) < 3 * 0.0003
    times, alone = re.search(r"(\d+) times the shift .* put it near ([\d.]+)", note).groups()
    assert 20 <= int(times) <= 27 and 0.98 < float(alone) < 1.0, note
    right = fit(_predator_prey(1.0, 0.5).set_parameters({}, std={"a": 0.0003}), [rec], method=method,
                show_progress=False)
    assert not any("disagree" in n for n in right.notes), right.notes        # its prior, said as such
    assert any(n.startswith("a = ") and "the recordings add little to its declared prior 1 ± 0.0003" in n
               for n in right.notes), right.notes


def test_several_priors_the_data_contradict_say_their_extrapolations_do_not_hold_together():
    """a and g both held by tight priors away from the truth: each note says where the recordings
    alone put its parameter, extrapolated for it alone (a motor's back-EMF, viscous and Coulomb
    friction, all off, were put at 0.083, −0.17 and −4.95 for 0.1, 0 and 0), and a note says those
    do not hold together, and how to see where the recordings put them."""
    res = fit(_predator_prey(0.9, 0.45).set_parameters({}, std={"a": 0.0003, "g": 0.0003}), [_stocked_recording()],
              method="filter-error", show_progress=False)
    assert sum("The prior and the recordings disagree" in n for n in res.notes) == 2, res.notes
    assert any(n.startswith("the priors of a, g all disagree with the recordings") and "a fit without those "
               "priors (no std)" in n for n in res.notes), res.notes
    one = fit(_predator_prey(0.9, 0.5).set_parameters({}, std={"a": 0.0003}), [_stocked_recording()],
              method="filter-error", show_progress=False)
    assert not any("all disagree" in n for n in one.notes)


def test_an_estimate_stopped_a_rounding_error_past_its_bound_is_held_on_it():
    """Started 9× and 20× from the truth (a = 1, g = 0.5; bounds [0, 10]) the search stops on the
    upper bounds, IPOPT a rounding error beyond one (g = 10.000000000000002): the fit ended in
    'value … is outside its bounds' and wrote nothing. The estimates are now held on the bounds,
    and the note says the fit stopped there (here a local optimum: from the truth's side the same
    recording gives a = 1)."""
    rec = _stocked_recording()
    res = fit(_predator_prey(9.0, 9.99), [rec], show_progress=False)
    assert [res.parameters[n]["value"] for n in ("a", "g")] == [10.0, 10.0]
    assert sum("sits on its upper bound 10: the fit stopped there" in n for n in res.notes) == 2, res.notes
    assert fit(_predator_prey(9.0, 5.0), [rec], show_progress=False).parameters["a"]["value"] == pytest.approx(1, abs=0.02)


def test_a_reading_note_names_its_file_among_several(tmp_path):
    """Two logs fitted together, the second without its rate gyro: the note says which file
    ("output 'rate' (column 'rate') has no value" did not)."""
    truth = dict(a=9.0, c=0.3, fc=0.5, b=2.0)
    plant = pendulum(truth, q=(0.0, 0.02), rate_std=0.02)
    paths = []
    for seed in (1, 2):
        rng = np.random.default_rng(seed)
        U = smooth_noise(rng, 600, 5, 1.0)[:, None]
        _, Y = simulate(plant, U, [0.3, 0.0], rng, q_std=(0.0, 0.02))
        rec = recording(plant, U, Y)
        outputs = {"angle": rec.outputs[:, 0], "rate": rec.outputs[:, 1] * (np.nan if seed == 2 else 1)}
        paths.append(tmp_path / f"log{seed}.csv")
        write_recording(paths[-1], rec.t, {"u": U[:, 0]}, outputs)
    res = fit(plant, paths, method="filter-error", show_progress=False)
    assert any(n.startswith(f"{paths[1]}: output 'rate'") and "never measured" in n for n in res.notes), res.notes


def test_a_noise_that_covers_a_missing_effect_is_said():
    """A pendulum fitted by filter error with its stiffness held at 4 (truth 9) and its Coulomb
    friction at 0 (truth 1.5): the process noise on w takes up what is missing (over 100× its
    declared variance), with the damping free or not, and the fit says so (a
    user's car model without its steering delay gave Cf 5.6 ± 2.1 for 80, 'solved', 779× the
    declared process noise, said nowhere). With the model right, nothing is said."""
    truth = dict(a=9.0, c=0.3, fc=1.5, b=2.0)
    rng = np.random.default_rng(4)
    U = smooth_noise(rng, 1500, 5, 3.0)[:, None]
    plant = pendulum(truth, q=(0.0, 0.02))
    _, Y = simulate(plant, U, [0.3, 0.0], rng, q_std=(0.0, 0.02))
    rec, wrong = recording(plant, U, Y), pendulum(dict(truth, fc=0.0, a=4.0), q=(0.0, 0.02))
    for estimate in (["b"], ["c", "b"]):
        res = fit(wrong, [rec], method="filter-error", estimate=estimate, show_progress=False)
        said = [n for n in res.notes if "the model misses something that noise now covers" in n]
        assert len(said) == 1 and "noise on w" in said[0] and "× its declared variance" in said[0], res.notes
    right = fit(pendulum(truth, q=(0.0, 0.02)), [rec], method="filter-error", show_progress=False)
    assert not any("the model misses something" in n for n in right.notes), right.notes


def _reactor(k0, E, g):
    """A stirred tank with first-order Arrhenius kinetics: C, T; heater u; k0 exp(−E/T)."""
    m = Model("reactor", dt=1.0, discretization="rk4", substeps=2)
    C = m.state("C", unit="mol/L", initial=0.4, std=0.05, process_std=1e-3)
    T = m.state("T", unit="K", initial=345.0, std=2.0, process_std=0.02)
    u = m.input("u")
    k0p = m.parameter("k0", k0, unit="1/s", bounds=(1e2, 1e10))
    Ep = m.parameter("E", E, unit="K", bounds=(1000.0, 20000.0))
    gp = m.parameter("g", g, unit="K/s", bounds=(0.0, 1.0))
    r = k0p * ca.exp(-Ep / T) * C
    m.dynamics({C: (1.0 - C) / 60.0 - r, T: (330.0 - T) / 60.0 + 5.0 * r + gp * u})
    m.output("C_meas", C, unit="mol/L", noise_std=0.01)
    m.output("T_meas", T, unit="K", noise_std=0.2)
    return m


def _reactor_recording(seed=111, N=1500):
    """Heater steps held 150 s, RK4 with 4 substeps, process noise per sample (a user's simulator)."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.choice([0, 2, 4, 6, 8, 10], size=N // 150), 150)[:N].astype(float)
    f = lambda x, v: np.array([(1.0 - x[0]) / 60.0 - 1e6 * np.exp(-6000.0 / x[1]) * x[0],
                               (330.0 - x[1]) / 60.0 + 5.0 * 1e6 * np.exp(-6000.0 / x[1]) * x[0] + 0.05 * v])
    x, X, h = np.array([0.4, 345.0]), np.empty((N, 2)), 0.25
    for k in range(N):
        X[k] = x
        for _ in range(4):
            k1 = f(x, u[k]); k2 = f(x + h / 2 * k1, u[k]); k3 = f(x + h / 2 * k2, u[k]); k4 = f(x + h * k3, u[k])
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x = x + rng.normal(0, 1, 2) * [1e-3, 0.02]
    Y = X + rng.normal(0, 1, X.shape) * [0.01, 0.2]
    return Recording("reactor", np.arange(N) * 1.0, u[:, None], Y, ("u",), ("C_meas", "T_meas"))


def test_a_filter_error_optimum_whose_process_noise_covers_wrong_parameters_is_left():
    """A user's Arrhenius reactor fitted by filter error from k0 = 3e5, E = 5800 (truth 1e6, 6000)
    stopped 'solved' at E = 8762 ± 240 (11σ off), the process noise on C at 22.7× its declared
    variance covering the misfit, 224 nat less likely than the optimum near the truth; the restart
    with the declared noise held fired only beyond 100×. From 10× on it now reaches the truth's
    optimum (measured: E 6076 ± 49), and says so."""
    res = fit(_reactor(3e5, 5800.0, 0.07), [_reactor_recording()], method="filter-error", show_progress=False)
    E = res.parameters["E"]
    assert abs(E["value"] - 6000.0) < 3 * E["std"] < 200.0, E
    assert any(n.startswith("filter error: a second optimum") for n in res.notes), res.notes


def test_a_noise_scale_the_data_do_not_place_is_not_said_to_cover_something():
    """A battery's state-of-charge noise came out 289 ± 783 times its declared variance: the note
    said the model misses something there, where the data do not place that noise at all. A scale
    is said only when its logarithm is more than 2 std above log 100."""
    from skigen.fit import _surely_above
    assert not _surely_above(dict(value=289.0, std=783.0), 100.0)
    assert _surely_above(dict(value=779.0, std=80.0), 100.0) and not _surely_above(dict(value=90.0, std=1.0), 100.0)
    assert _surely_above(dict(value=150.0, std=None), 100.0)


def test_an_output_never_measured_has_its_noise_held():
    """Filter error on a pendulum whose rate gyro recorded nothing: its noise scale cannot be
    calibrated, and the fit used to refuse ("'R_scale_rate' has no effect on the likelihood ... --estimate
    NAME", which cannot name it); it is held at the declared value, said in a note, and the
    parameters come from the angle."""
    truth = dict(a=9.0, c=0.3, fc=0.5, b=2.0)
    plant = pendulum(truth, q=(0.0, 0.02), rate_std=0.02)
    rng = np.random.default_rng(5)
    U = smooth_noise(rng, 1500, 5, 1.0)[:, None]
    _, Y = simulate(plant, U, [0.3, 0.0], rng, q_std=(0.0, 0.02))
    Y[:, 1] = np.nan
    res = fit(pendulum(dict(a=8.0, c=0.4, fc=0.4, b=1.8), q=(0.0, 0.02), rate_std=0.02), [recording(plant, U, Y)],
              method="filter-error", show_progress=False)
    assert any("'rate' never measured in these recordings: their noise is held" in n for n in res.notes)
    assert res.noise["calibrated"]["measurement_std"]["rate"] == pytest.approx(0.02)
    for n, v in truth.items():
        assert abs(res.parameters[n]["value"] - v) < 3 * res.parameters[n]["std"], (n, res.parameters[n])


def test_filter_error_leaves_a_basin_where_process_noise_explains_wrong_parameters():
    """A DC motor's single 6 V step from rest (exact ZOH simulation, no process noise), its
    constants declared 20–25 % off: filter error stopped where 4317× the speed's declared process
    noise covered L = 0.0037 ± 3.5e-6 H (truth 0.05: −13 000σ), 'solved', 150 nat less likely than
    the optimum by the truth. Restarted from the parameters fitted with the noise held, it reaches
    that optimum and says so."""
    from scipy.linalg import expm
    truth = dict(R=2.0, L=0.05, Kt=0.1, J=0.01, b=0.005)
    dt, n = 0.005, 2001
    A = np.array([[-truth["R"] / truth["L"], -truth["Kt"] / truth["L"]], [truth["Kt"] / truth["J"], -truth["b"] / truth["J"]]])
    M = expm(np.block([[A, np.array([[1 / truth["L"]], [0.0]])], [np.zeros((1, 3))]]) * dt)
    x = np.zeros((n, 2))
    for k in range(n - 1):
        x[k + 1] = M[:2, :2] @ x[k] + M[:2, 2] * 6.0
    y = x + np.random.default_rng(22).standard_normal((n, 2)) * np.array([0.02, 0.05])
    m = Model("dcmotor", dt=dt, discretization="rk4")
    i, w = m.state("i", unit="A", std=0.5, process_std=1e-4), m.state("w", unit="rad/s", std=0.5, process_std=1e-4)
    V = m.input("V", unit="V")
    R, L = m.parameter("R", 2.5, bounds=(0, 100)), m.parameter("L", 0.04, bounds=(1e-4, 10))
    Kt, J = m.parameter("Kt", 0.12, bounds=(0, 10)), m.parameter("J", 0.008, bounds=(1e-5, 10))
    b = m.parameter("b", 0.004, bounds=(0, 10))
    m.dynamics({i: (V - R * i - Kt * w) / L, w: (Kt * i - b * w) / J})
    m.output("cur", i, noise_std=0.02)
    m.output("spd", w, noise_std=0.05)
    rec = Recording("step.csv", np.arange(n) * dt, np.full((n, 1), 6.0), y, ("V",), ("cur", "spd"))
    res = fit(m, [rec], method="filter-error", show_progress=False)
    for name, value in truth.items():
        p = res.parameters[name]
        assert abs(p["value"] - value) < 4 * p["std"], (name, p)
    assert any("a second optimum" in n for n in res.notes), res.notes


def test_a_correlation_near_one_is_printed_with_the_digits_that_tell_it_from_one():
    """k0 and E of an Arrhenius rate, correlated 0.99969, read '+1.000'."""
    from skigen.fit import _near_one
    assert [_near_one(c) for c in (0.99969, -0.9965, 0.5)] == ["+0.99969", "-0.997", "+0.500"]


def test_an_iteration_limit_counts_each_method_s_iterations():
    """'250 iterations' for --max-iter 200 read as a miscount: the error now says how many of Fisher
    scoring and how many Newton steps, each at most the limit."""
    m, y, v, u = _linear("limited")
    k, c = m.parameter("k", 0.5), m.parameter("c", 3.0)
    m.dynamics({y: v, v: -k * y - c * v + u})
    m.output("pos", y, noise_std=0.01)
    truth = _linear("limited_truth")[0]
    ty, tv = truth.states[0].sym, truth.states[1].sym
    truth.dynamics({ty: tv, tv: -4.0 * ty - 0.5 * tv + truth.inputs[0].sym})
    truth.output("pos", ty, noise_std=0.01)
    with pytest.raises(FitError, match=r"stopped at the iteration limit .*\(status Maximum_Iterations_Exceeded, "
                                       r"2 iterations of Fisher scoring, then 2 Newton steps\)"):
        fit(m, [_excited(truth)], max_iter=2, show_progress=False)


def test_output_error_s_log_likelihood_does_not_depend_on_the_start():
    """A start whose free run strays beyond 100 noise std is searched with the outputs weighted by
    its residuals, and the reported log-likelihood was the weighted one: the same fit read +243.3
    from one start and −388.6 from another (an epidemic model). It is now that of the declared
    sensor noise, from any start (here the far start strays 202 noise std)."""
    def spring(k, c, name):
        m, y, v, u = _linear(name)
        kp, cp = m.parameter("k", k), m.parameter("c", c)
        m.dynamics({y: v, v: -kp * y - cp * v + u})
        m.output("pos", y, noise_std=0.001)
        return m
    rec = _excited(spring(4.0, 0.5, "spring_truth"))
    near, far = (fit(spring(k, c, f"spring_{i}"), [rec], show_progress=False)
                 for i, (k, c) in enumerate([(4.0, 0.5), (0.5, 3.0)]))
    assert far.parameters["k"]["value"] == pytest.approx(near.parameters["k"]["value"], rel=1e-6)
    assert far.recordings[0]["loglik"] == pytest.approx(near.recordings[0]["loglik"], abs=1e-3)


def _epidemic(beta, gamma):
    """SIR with an intervention u, its prevalence surveyed in log units (5 % noise)."""
    m = Model("sir", dt=1.0, discretization="rk4", substeps=4)
    S, I = m.state("S", initial=0.998, std=0.01), m.state("I", initial=2e-3, std=5e-4)
    u = m.input("u")
    b, g = m.parameter("beta", beta, bounds=(0.0, 5.0)), m.parameter("gamma", gamma, bounds=(1e-3, 2.0))
    m.dynamics({S: -b * (1 - u) * S * I, I: b * (1 - u) * S * I - g * I})
    m.output("logI", ca.log(I), noise_std=0.05)
    return m


def test_a_start_judged_off_at_wrong_starting_values_is_judged_again_at_the_fit():
    """An epidemic recorded from exactly the declared S0, I0, fitted by filter error from β = 0.3,
    γ = 0.05 (truth 0.4, 0.1): at those values the recording 'did not start at the model's initial
    state', the filter started vague, and the fit gave S0 = 0.82 ± 0.044 and error bars 1.5× wide.
    At the fitted values the start agrees, and the fit is redone from it (measured: 9.1 nat more
    likely, ± 0.0025 and ± 0.0005 as from a start at the truth)."""
    U = np.zeros(150)
    U[20:60] = 0.6
    _, Y = free_run(_epidemic(0.4, 0.1), U[:, None])
    rec = recording(_epidemic(0.4, 0.1), U, Y + np.random.default_rng(0).normal(0, 0.05, Y.shape))
    res = fit(_epidemic(0.3, 0.05), [rec], method="filter-error", show_progress=False)
    near = fit(_epidemic(0.4, 0.1), [rec], method="filter-error", show_progress=False)
    assert any("agrees with it at the fitted ones: refitted from the declared start" in n for n in res.notes)
    for name in ("beta", "gamma"):
        assert res.parameters[name]["std"] == pytest.approx(near.parameters[name]["std"], rel=0.05)
    assert res.initial_states == [{}] and res.objective == pytest.approx(near.objective, abs=0.01)


def test_output_error_s_prior_note_counts_the_coloured_residuals():
    """A building's a2 (prior 4e-5 ± 1e-6, truth 5e-5) by output error under process noise: the
    recordings know it to ± 1.27e-6 (the sandwich), the white Fisher information claims ± 2e-7.
    The note said 'the recordings alone put it near 5.187e-05 ± 2e-07'; it now gives the
    coloured ± and says the prior counted too little. With white residuals (c = 1) the shift's
    allowance is √(σ₀² − σ²), as before."""
    from skigen.fit import _prior_notes
    m = Model("room", dt=60.0)
    m.parameter("a2", 4e-5, std=1e-6)
    sigma = 1 / np.sqrt(1 / 2e-7 ** 2 + 1 / 1e-6 ** 2)            # white posterior std, prior included
    coloured = _prior_notes(m, {"a2": dict(value=5.139e-5, std=1.2e-6, initial=4e-5)}, {"a2": sigma})
    assert len(coloured) == 2 and "as if their residuals were white" in coloured[0]
    assert "the recordings alone put it near 5.18" in coloured[1] and "± 1.2e-06." in coloured[1], coloured
    (white,) = _prior_notes(m, {"a2": dict(value=4.963e-5, std=sigma, initial=4e-5)}, {"a2": sigma})
    assert f"(± {np.sqrt(1e-12 - sigma ** 2):.2g})" in white and "± 2e-07." in white, white


def _rudder_spec(path, start: float):
    path.write_text("import casadi as ca\nfrom skigen import Model\n"
                    "model = Model('rudder', dt=0.1, discretization='rk4')\n"
                    "r = model.state('r', std=0.1, process_std=0.0)\n"
                    "d = model.input('d')\n"
                    "K, T = model.parameter('K', 0.2, bounds=(0, 10)), model.parameter('T', 3.0, bounds=(0.1, 100))\n"
                    f"dmax = model.parameter('dmax', {start}, bounds=(1, 90))\n"
                    "model.dynamics({r: (K * ca.fmin(ca.fmax(d, -dmax), dmax) - r) / T})\n"
                    "model.output('r_meas', r, noise_std=0.01)\n")
    return path


@pytest.mark.parametrize("start", [9.0, 9.9])
def test_a_limit_the_inputs_never_reach_is_not_given_a_two_sided_error_bar(tmp_path, capsys, start):
    """A rudder limit (truth 30) started inside the commands (±9.97 at most), which never reach
    it. From 9.0 the fit stops at the largest command, 9.969 ± 0.038 from the one block it clips:
    the likelihood is flat above, and the fit says the data bound it from below only. From 9.9 it
    stops above every command, where nothing is seen: its std is infinite (the pseudo-inverse
    gave 0, and the CLI crashed writing −inf correlations), null in fit.json, with a note. The
    other estimates keep their error bars, which cover the truth, and no side of theirs is flat."""
    from skigen.cli import main
    from skigen.modelfile import load_model
    spec = _rudder_spec(tmp_path / "rudder.py", start)
    plant = load_model(spec).set_parameters(dict(K=0.1, T=2.0, dmax=30.0))
    rng = np.random.default_rng(3)
    N = 600
    U = np.repeat(rng.uniform(-10, 10, N // 20), 20)
    _, Y = free_run(plant, U[:, None])
    data = tmp_path / "rudder.csv"
    write_recording(data, np.arange(N) * 0.1, {"d": U}, {"r_meas": Y[:, 0] + 0.01 * rng.normal(size=N)})
    out = tmp_path / "out"
    assert main(["fit", str(spec), str(data), "--out", str(out), "--no-figures"]) == 0
    fitted = json.loads((out / "fit.json").read_text())
    p = fitted["parameters"]
    for name, truth in (("K", 0.1), ("T", 2.0)):
        assert 0 < p[name]["std"] and abs(p[name]["value"] - truth) < 3 * p[name]["std"], (name, p[name])
        assert "flat" not in p[name]
    printed = capsys.readouterr().out
    if start == 9.0:
        assert p["dmax"]["value"] == pytest.approx(np.abs(U).max(), abs=0.005) and p["dmax"]["flat"] == "above"
        assert "(flat above it: see the note)" in printed
        assert re.search(r"dmax = 9\.96\d+ ± 0\.038 is bounded from below only", printed)
    else:
        assert p["dmax"]["std"] is None and p["dmax"]["value"] > np.abs(U).max()
        row = fitted["correlation"]["names"].index("dmax")
        assert all(c is None for c in fitted["correlation"]["matrix"][row])
        assert "(no error bar)" in printed and "'dmax' has no effect on the likelihood at its fitted value" in printed
        assert "± inf" not in printed


def test_an_input_logged_only_when_it_changes_is_said_with_how_to_hold_it(tmp_path):
    """A rudder logged on 6 rows of a 300-row log: the stretches between its holes held a few
    samples, fitted with only a note listing holes; the note now says how few and how to hold the
    input. A stretch shorter than its filter's head drew its figure past its end (IndexError)."""
    import pandas as pd
    from skigen.fit.figures import recording_figure
    from skigen.recording import load_recording
    m, y, v, u = _linear("sparse")
    m.dynamics({y: v, v: -4 * y - 0.5 * v + u})
    m.output("pos", y, noise_std=0.01)
    t = np.arange(300) * 0.05
    frame = pd.DataFrame({"t": t, "u": np.nan, "pos": np.sin(t)})
    frame.loc[[0, 1, 60, 140, 141, 250], "u"] = [0.0, 0.0, 1.0, -1.0, -1.0, 0.5]
    rec = load_recording(frame, m)
    note = rec.hole_note("fitted as parts")
    kept = sum(len(p.t) for p in rec.input_parts())
    assert kept < 10 and f"those stretches hold {kept} of the 300 samples" in note
    assert "with a max_gap longer than its longest hole, 5.45 s (--max-gap SECONDS" in note
    part = rec.input_parts()[0]
    path = recording_figure(tmp_path / "f.png", "part", part, part.outputs, ["pos"], start=5)
    assert path.exists()


def test_a_limit_started_beyond_every_command_is_refused_with_where_it_acts(tmp_path):
    """A rudder limit started at 40 with commands within ±10 has no effect there: the refusal said
    'record richer excitation', though from a start of 9 the recording identifies the others and
    bounds the limit. It now says the limit acts at 5 (halved three times) and to start it there."""
    from skigen.modelfile import load_model
    spec = _rudder_spec(tmp_path / "rudder.py", 40.0)
    plant = load_model(spec).set_parameters(dict(K=0.1, T=2.0, dmax=8.0))
    rng = np.random.default_rng(3)
    U = np.repeat(rng.uniform(-10, 10, 30), 20)
    _, Y = free_run(plant, U[:, None])
    rec = recording(plant, U[:, None], Y + 0.01 * rng.normal(size=Y.shape))
    with pytest.raises(NotIdentifiable, match="'dmax' has no effect on the likelihood at 40, but it has at 5: the "
                                              "recordings do not reach where it acts from there"):
        fit(load_model(spec), [rec], method="filter-error")


def test_a_sensor_noise_ten_times_its_declared_variance_is_said():
    """A speed logged in rpm for a model in rad/s: the gain takes 9.55× and the sensor noise 91× its
    declared variance, under the process noise's 100× — said nowhere. A sensor's noise is said
    from 10× its declared variance; the same recording in rad/s says nothing."""
    m, y, v, u = _linear("rpm")
    b = m.parameter("b", 1.0)
    m.dynamics({y: v, v: -4 * y - 0.5 * v + b * u})
    m.output("pos", y, noise_std=0.01)
    rng = np.random.default_rng(5)
    U = smooth_noise(rng, 600, 5, 2.0)[:, None]
    _, Y = free_run(m, U)
    clean = Y + 0.01 * rng.normal(size=Y.shape)
    for factor, said in ((60 / (2 * np.pi), True), (1.0, False)):
        res = fit(m, [recording(m, U, factor * clean)], method="filter-error", show_progress=False)
        notes = [n for n in res.notes if n.startswith("the sensor noise on pos")]
        assert bool(notes) == said, res.notes
        if said:
            assert "or a recording is in other units than the model" in notes[0]
            assert res.parameters["b"]["value"] == pytest.approx(factor, rel=0.02)


def test_a_recording_passed_twice_is_said():
    """The same log passed twice (one re-exported with epoch stamps) halved the variances in silence
    (k ± 0.070 against ± 0.098)."""
    m, y, v, u = _linear("twice")
    k = m.parameter("k", 3.0)
    m.dynamics({y: v, v: -k * y - 0.5 * v + u})
    m.output("pos", y, noise_std=0.01)
    rng = np.random.default_rng(2)
    U = smooth_noise(rng, 300, 5, 2.0)[:, None]
    _, Y = free_run(m, U)
    rec = recording(m, U, Y + 0.01 * rng.normal(size=Y.shape))
    again = dataclasses.replace(rec, t=rec.t + 1.7e9, path="epoch.csv")
    res = fit(m, [rec, again], show_progress=False)
    assert any(n.startswith("epoch.csv holds the same inputs and readings as sim: fitted twice") for n in res.notes)
    other = recording(m, U, Y + 0.01 * rng.normal(size=Y.shape), path="other")
    assert not any("holds the same" in n for n in fit(m, [rec, other], show_progress=False).notes)


def _hover(kt0: float, cd_std=None, cd_bounds=(0.0, 5.0), h_noise: float = 0.0):
    """A quadcopter's altitude (h' = v, v' = kT·u − g − cd·v; a barometer, 0.1 m) and 40 s of it at
    50 Hz under an open-loop throttle (truth kT 15, cd 0.4, no process noise); the model starts kT
    at ``kt0``, cd at 0.3."""
    m = Model("hover", dt=0.02, discretization="rk4")
    h = m.state("h", unit="m", role="position", std=0.5, process_std=1e-4)
    v = m.state("v", unit="m/s", role="velocity", std=0.5, process_std=0.01)
    u = m.input("u")
    kt = m.parameter("kT", kt0, bounds=(1.0, 50.0))
    cd = m.parameter("cd", 0.3, bounds=cd_bounds, **({} if cd_std is None else {"std": cd_std}))
    m.dynamics({h: v, v: kt * u - 9.81 - cd * v})
    m.output("baro", h, unit="m", noise_std=0.1)
    t = np.arange(2001) * 0.02
    throttle = 0.654 + 0.05 * np.sin(0.7 * t) + 0.03 * np.sign(np.sin(2.1 * t))
    f = lambda x, uk: np.array([x[1], 15 * uk - 9.81 - 0.4 * x[1]])
    x, hs, walk = np.zeros(2), np.empty(len(t)), np.random.default_rng(3).normal(0, h_noise, len(t))
    for k, uk in enumerate(throttle):
        hs[k] = x[0]
        k1 = f(x, uk); k2 = f(x + 0.01 * k1, uk); k3 = f(x + 0.01 * k2, uk)
        x = x + 0.02 / 6 * (k1 + 2 * k2 + 2 * k3 + f(x + 0.02 * k3, uk)) + [walk[k], 0.0]
    baro = hs + np.random.default_rng(10).normal(0, 0.1, len(t))
    import pandas as pd
    return m, pd.DataFrame({"t": t, "u": throttle, "baro": baro})


@pytest.mark.parametrize("cd_std, cd_bounds", [(0.2, (0.0, 5.0)), (None, (0.0, 0.3))])
def test_output_error_from_a_far_start_weighs_a_prior_or_a_bound_as_declared(cd_std, cd_bounds):
    """kT started at 13 for 15: the free run strays 1000 noise std and output error searches under
    R scaled to its residuals, which shrank the recordings' part of the objective: a drag prior of
    0.3 ± 0.2, which the recordings outweigh 10⁴ times, held cd at 0.302 ± 0.2 (the prior's own
    std), and a bound at 0.3 stopped the search at 0.277 inside it. The weighted optimum is now
    polished under the declared R: 0.3980 ± 0.0017 as without the prior (or from kT = 15.2), and
    0.300 on the bound, said."""
    m, frame = _hover(13.0, cd_std, cd_bounds)
    res = fit(m, frame, show_progress=False)
    cd = res.parameters["cd"]
    if cd_std is not None:
        near, _ = _hover(15.2, cd_std, cd_bounds)
        assert abs(cd["value"] - 0.4) < 3 * cd["std"] < 0.006, cd
        assert cd["value"] == pytest.approx(fit(near, frame, show_progress=False).parameters["cd"]["value"], abs=1e-4)
    else:
        assert cd["value"] == pytest.approx(0.3, abs=1e-6), cd
        assert any(n.startswith("cd = 0.3 ± ") and "sits on its upper bound 0.3" in n for n in res.notes), res.notes


def test_a_message_of_many_sets_not_told_apart_says_three_and_counts_the_rest():
    """A joint refit that failed with seven such sets wrote a note of 2 600 characters on one line;
    the message says three and counts the rest, ``lost`` keeps them all."""
    from skigen.fit import _not_identifiable
    lost = [f"'p{k}', 'q{k}' cannot be told apart" for k in range(7)]
    exc = _not_identifiable(Model("m", dt=0.1), lost)
    assert "'p2', 'q2' cannot be told apart; and 4 more such set(s). Hold some" in str(exc)
    assert "'p3'" not in str(exc) and exc.lost == lost


def test_filter_error_holds_a_kinematic_identity_to_its_declared_noise():
    """h' = v is exact by definition: by default filter error caps its process noise at the declared
    variance (an altitude's took 2700× it from the vertical speed's on 5 of 12 hover flights of a
    right model, said as 'the model misses something', the thrust's error bars then 4.5 of them off);
    noise_caps={} frees it. Here the plant's h does wander (0.01 m a sample for a declared 1e-4)."""
    m, frame = _hover(15.0, 0.2, h_noise=0.01)
    capped = fit(m, frame, method="filter-error", show_progress=False)
    assert capped.noise["scales"]["Q_scale_h"]["value"] <= 1 + 1e-6
    free = fit(m, frame, method="filter-error", show_progress=False, noise_caps={})
    assert free.noise["scales"]["Q_scale_h"]["value"] > 4                # measured 8.1


def test_an_estimate_the_recordings_hardly_inform_says_it_is_mostly_its_prior():
    """A drag with a prior 0.3 ± 0.2 came out 0.302 ± 0.2 and read as a fitted value (the recordings
    had been weighed too little; README's output-error polish): where the posterior std is 90 % of
    the prior's or more and the estimate near its prior, a note says so; a well-informed one not."""
    from skigen.fit import _prior_notes
    m = Model("m", dt=0.1)
    m.parameter("cd", 0.3, std=0.2)
    weak = _prior_notes(m, {"cd": dict(initial=0.3, value=0.302, std=0.195)}, {"cd": 0.19})
    assert weak == ["cd = 0.302 ± 0.2: the recordings add little to its declared prior 0.3 ± 0.2 (its std with "
                    "them is 95% of the prior's): the estimate is mostly the prior"], weak
    assert _prior_notes(m, {"cd": dict(initial=0.3, value=0.398, std=0.002)}, {"cd": 0.002}) == []


@pytest.mark.parametrize("delay", [0, 3])
def test_filter_error_says_when_the_fitted_models_innovations_follow_the_past(delay):
    """A pitch grey box whose elevator acts 40 ms late: filter error calibrated the pitch rate's
    process noise at 13× its declared variance (under the noise's note), Mq and Mδ came out 14σ
    and 15σ off, 'solved', and no note. The fitted model's innovations are tested as the
    diagnosis tests a calibrated model's; without the delay nothing is said."""
    m = Model("servo", dt=0.02, discretization="rk4")
    x, v = m.state("x", std=0.01, process_std=1e-4), m.state("v", std=0.01, process_std=1e-3)
    u = m.input("u")
    k, c, b = (m.parameter(n, val, std=s) for n, val, s in (("k", 6.0, 2.0), ("c", 1.0, 0.5), ("b", 8.0, 3.0)))
    m.dynamics({x: v, v: -k * x - c * v + b * u})
    m.output("x_meas", x, noise_std=0.002)
    rng, n, dt = np.random.default_rng(3), 3000, 0.02
    cmd = np.repeat(rng.choice([-1.0, 1.0], n // 25) * rng.uniform(0.2, 1.0, n // 25), 25)
    late = np.r_[np.zeros(delay), cmd[:n - delay]]
    s, rows = np.zeros(2), []
    for j in range(n):
        rows.append(s[0])
        f = lambda z: np.array([z[1], -9.0 * z[0] - 1.2 * z[1] + 10.0 * late[j]])
        k1 = f(s); k2 = f(s + dt / 2 * k1); k3 = f(s + dt / 2 * k2)
        s = s + dt / 6 * (k1 + 2 * k2 + 2 * k3 + f(s + dt * k3)) + np.array([1e-4, 1e-3]) * rng.standard_normal(2)
    rec = Recording("servo.csv", np.arange(n) * dt, cmd[:, None], (np.array(rows) + 0.002 * rng.standard_normal(n))[:, None],
                    ("u",), ("x_meas",))
    res = fit(m, [rec], method="filter-error", show_progress=False)
    said = [note for note in res.notes if "innovations of x_meas" in note]
    assert bool(said) == bool(delay), res.notes
    if delay:
        assert "follow the states and inputs before them" in said[0] and "skigen diagnose" in said[0]


@pytest.mark.parametrize("discretization", ["euler", "rk4"])
def test_fit_says_when_the_integration_step_biases_the_fitted_parameters(discretization):
    """A yaw model, ṙ = −c·r + b·u at dt = 0.05 s under Euler: c came out 6.81 ± 0.045 for 8 (26σ)
    with only a correlation note. The fitted model's modes are checked as the run summary checks
    them; RK4 at the same step is silent."""
    m = Model("yaw", dt=0.05, discretization=discretization)
    psi, r = m.state("psi", std=0.01, process_std=1e-4), m.state("r", std=0.01, process_std=1e-3)
    u = m.input("u")
    c, b = m.parameter("c", 6.0, std=2.0), m.parameter("b", 60.0, std=20.0)
    m.dynamics({psi: r, r: -c * r + b * u})
    m.output("psi_meas", psi, noise_std=0.002)
    rng, n, dt = np.random.default_rng(4), 1200, 0.05
    cmd = np.repeat(rng.uniform(-0.05, 0.05, n // 2), 2)               # 0.1 s holds: the transients tell c
    sol = solve_ivp(lambda t, x: [x[1], -8.0 * x[1] + 80.0 * cmd[min(int(t / dt), n - 1)]], (0, n * dt), [0, 0],
                    t_eval=np.arange(n) * dt, max_step=dt / 20, rtol=1e-9, atol=1e-12)
    rec = Recording("yaw.csv", sol.t, cmd[:, None], (sol.y[0] + 0.002 * rng.standard_normal(n))[:, None],
                    ("u",), ("psi_meas",))
    res = fit(m, [rec], show_progress=False)
    said = [note for note in res.notes if note.startswith("integration:")]
    if discretization == "rk4":
        assert not said and abs(res.parameters["c"]["value"] - 8) < 3 * res.parameters["c"]["std"], res.notes
        return
    c = res.parameters["c"]
    assert 8 - c["value"] > 3 * c["std"] and len(said) == 1, (c, res.notes)      # 7.76 ± 0.062 measured
    assert "the euler step of 0.05 s moves the mode at" in said[0] and 'use discretization="rk4"' in said[0]
