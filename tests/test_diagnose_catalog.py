"""skigen diagnose names the catalog's structural effects that act outside the rate equations'
terms, on the systems the diagnosis was not developed on (scenarios in benchmarks/scenarios.py):

- tanks_sensor_sat: the upper level sensor's range ends (sensor_saturation, in the output equation);
- arm_backlash: a play between the commanded and the applied voltage (backlash);
- arm_frac_delay: a delay of 2.5 samples (fractional_delay: whole and fractional part searched);
- tanks_pump_limit: a pump that delivers at most 5 V, on an input that is never negative (the
  saturation's upper end alone: a limit symmetric about the input's median also clipped its low
  commands).

Each is asserted from report.json (named first, on its equation, its parameter near the truth,
nothing remaining) and from corrected_model.py: the file loads, states the effect where it acts
(the output expression, a play state, the input history) and its free run on the recording's
input follows the true noiseless response better than the nominal's.
"""
import numpy as np
import pandas as pd
import pytest

from benchmarks.scenarios import make
from models import motor_pendulum as arm, two_tanks as tanks
from tests.scenario_cache import diagnosis_cache
from skigen.modelfile import load_model
from skigen.simulate import free_run

SEED = 1
# parameter tolerances, in the parameter's unit; measured with seeds 1, 2, 3: bound 0.320, 0.320,
# 0.321 m (0.32), play 0.150, 0.152, 0.151 ± 0.005 V (0.15), delay 2.48, 2.46, 2.54 ± 0.09 samples (2.5)
TOLERANCE = {
    "tanks_sensor_sat": 3 * tanks.H_NOISE["h1_meas"],      # m: three noise std of one sample
    "arm_backlash": 0.015,                                  # V: about 3 std, a tenth of the play
    "arm_frac_delay": 0.25,                                 # samples: about 3 std, half the fraction
    "tanks_pump_limit": 0.15,                               # V: about 3 std (measured 4.97 ± 0.04)
}


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    return diagnosis_cache(tmp_path_factory, SEED)


@pytest.mark.parametrize("name", TOLERANCE)
def test_named_first_with_its_parameter(diagnosed, name):
    r = diagnosed(name)
    sc, d = r["scenario"], r["data"]
    assert d["mismatch_detected"] is True
    top = d["findings"][0] if d["findings"] else None
    assert top is not None and top["effect"] == sc.effect, d["findings"]
    assert sc.equation in top["equation"].split("+"), top
    assert abs(top["coefficient"] - sc.truth) < TOLERANCE[name], (top["coefficient"], top["std"], sc.truth)
    assert d["remaining"]["mismatch"] is False, d["remaining"]


def test_pump_limit_is_its_upper_end_alone(diagnosed):
    top = diagnosed("tanks_pump_limit")["data"]["findings"][0]
    assert top["expression"].startswith("min(u, "), top


def test_a_one_sided_input_saturates_at_one_end():
    from skigen.diagnose.catalog import structural_candidates
    from skigen.diagnose.transform import input_saturation
    heater = np.random.default_rng(2).uniform(0.0, 15.0, 500)
    sides = {c.side: c for c in structural_candidates(_echo(), ["x"], heater[:, None])
             if c.effect == "input_saturation"}
    assert set(sides) == {"upper", "lower"}
    assert min(sides["upper"].grid) < np.median(heater) < max(sides["upper"].grid)
    _, y = free_run(input_saturation(_echo(), "u", None, 11.0), heater)
    assert np.allclose(y[1:, 0], np.minimum(heater, 11.0)[:-1])
    both = np.random.default_rng(3).normal(size=500)
    (sym,) = [c for c in structural_candidates(_echo(), ["x"], both[:, None]) if c.effect == "input_saturation"]
    assert sym.side == ""
    # each grid ends where nothing is clipped, so that a limit passed only by the last commands
    # is bracketed: held levels 66.8, 72.1 and 74.7 W around a true 70 W were called not
    # identifiable (the best grid value the last), now named 69.96 ± 0.12 (user probe, a heater)
    assert (sides["upper"].grid[-1], sides["lower"].grid[0], sym.grid[-1]) == (heater.max(), heater.min(),
                                                                              np.abs(both).max())


def test_sensor_saturation_side_and_output(diagnosed):
    top = diagnosed("tanks_sensor_sat")["data"]["findings"][0]
    assert top["output"] == "h1_meas" and top["shape"]["side"] == "upper", top


def _noiseless(sc) -> np.ndarray:
    """The true output without noise: the tanks' levels clipped by the sensor, the arm's angle
    simulated again on the same voltage without process noise."""
    if sc.effect == "input_saturation":
        return sc.run.h1                 # the true level (with its process noise)
    if sc.system == "two_tanks":
        return np.minimum(sc.run.h1, sc.truth)
    quiet = arm.simulate(sc.run.V, effect=sc.effect, parameter=sc.truth, seed=SEED, noise=False)
    return quiet.theta


@pytest.mark.parametrize("name", TOLERANCE)
def test_corrected_model_file_states_and_reproduces_it(diagnosed, name):
    r = diagnosed(name)
    sc, d = r["scenario"], r["data"]
    corrected = load_model(d["corrected_model"])
    text = open(d["corrected_model"]).read()
    expected = {"sensor_saturation": "ca.fmin(h1", "backlash": "model.state('V_play'",
                "fractional_delay": "model.input_history(V, 3)", "input_saturation": "ca.fmin(u, "}[sc.effect]
    assert expected in text, text
    nominal = load_model(sc.model_file)
    truth = _noiseless(sc)
    rmse = {}
    for which, m in (("nominal", nominal), ("corrected", corrected)):
        _, y = free_run(m, np.column_stack(list(sc.inputs.values())))
        rmse[which] = float(np.sqrt(np.mean((y[:, 0] - truth) ** 2)))
    assert rmse["corrected"] < 0.5 * rmse["nominal"], rmse


# ------------------------------------------------------------------ the transformations themselves
def _echo(discretization="discrete"):
    """x[k+1] = u[k] (discrete) or ẋ = u − x: the plant's input made visible; y = x."""
    from skigen import Model
    m = Model("echo", dt=1.0, discretization=discretization)
    x = m.state("x", std=1.0)
    u = m.input("u")
    m.dynamics({x: u if discretization == "discrete" else u - x})
    m.output("y", x, noise_std=0.1)
    return m


def test_fractional_delay_weighs_the_two_neighbouring_samples():
    from skigen.diagnose.transform import fractional_delay
    u = np.random.default_rng(0).normal(size=40)
    _, y = free_run(fractional_delay(_echo(), "u", 2.25), u)
    k = np.arange(4, 40)
    assert np.allclose(y[k, 0], 0.75 * u[k - 3] + 0.25 * u[k - 4])


def test_backlash_is_the_play_operator_in_a_discrete_model():
    from skigen.diagnose.transform import backlash
    u = np.cumsum(np.random.default_rng(1).normal(size=60))
    _, y = free_run(backlash(_echo(), "u", 0.7), u)
    assert np.allclose(y[1:, 0], arm.play(u, 0.7)[:-1])


def test_a_discrete_actuator_lag_adds_no_delay_of_its_own():
    """In a discrete model the plant saw the lag state before its update, a sample late: a lag as
    short as nothing was a one-sample delay (a true 0.1 s lag at 50 Hz named 0.0725 s beside two
    corrections). It sees the updated state: a 1 ms lag at 1 s per sample is the input itself,
    and a 1 s lag the recursion u_act[k+1] = u_act[k] + (1 − e⁻¹)(u[k] − u_act[k])."""
    from skigen.diagnose.transform import actuator_lag
    u = np.random.default_rng(2).normal(size=30)
    _, y = free_run(actuator_lag(_echo(), "u", 1e-3), u)
    assert np.allclose(y[1:, 0], u[:-1])
    lagged, a = np.zeros(30), 1 - np.exp(-1.0)
    for k in range(29):
        lagged[k + 1] = lagged[k] + a * (u[k] - lagged[k])
    _, y = free_run(actuator_lag(_echo(), "u", 1.0), u)
    assert np.allclose(y[:, 0], lagged)


def test_backlash_rejects_a_width_that_is_not_positive():
    from skigen.diagnose.transform import backlash
    with pytest.raises(ValueError, match="input 'u'"):
        backlash(_echo(), "u", 0.0)


def test_sensor_saturation_clips_only_the_output():
    from skigen.diagnose.transform import output_saturation
    u = np.linspace(0, 2, 20)
    states, y = free_run(output_saturation(_echo(), "y", 1.0, "upper"), u)
    assert np.allclose(y[:, 0], np.minimum(states[:, 0], 1.0)) and states[:, 0].max() > 1.5
    with pytest.raises(ValueError, match="no output 'z'"):
        output_saturation(_echo(), "z", 1.0, "upper")


def test_sensor_offset_and_gain_change_only_the_output():
    from skigen.diagnose.transform import output_gain, output_offset
    u = np.random.default_rng(4).normal(size=30)
    plain, _ = free_run(_echo(), u)
    for m, read in ((output_offset(_echo(), "y", -0.3), lambda x: x - 0.3),
                    (output_gain(_echo(), "y", 1.2), lambda x: 1.2 * x)):
        states, y = free_run(m, u)
        assert np.array_equal(states, plain) and np.allclose(y[:, 0], read(states[:, 0]))
    with pytest.raises(ValueError, match="output 'y': a sensor gain is positive"):
        output_gain(_echo(), "y", 0.0)


def test_sensor_candidates_scale_with_the_recorded_output():
    """The offset is searched on both sides of zero (never at it) in proportion to the output's
    RMS, so a level sensor in metres and a vane in radians get grids of their own size."""
    from skigen.diagnose.catalog import SENSOR_OFFSETS, output_candidates
    y = 0.25 + 0.01 * np.random.default_rng(5).normal(size=400)
    cands = {c.effect: c for c in output_candidates(_echo(), ["y"], y[:, None])}
    grid = np.array(cands["sensor_offset"].grid)
    rms = np.sqrt(np.mean(y ** 2))
    assert 0 not in grid and np.allclose(grid[grid > 0], np.array(SENSOR_OFFSETS) * rms, rtol=2e-3)  # 3 digits
    assert np.allclose(-grid[grid < 0][::-1], grid[grid > 0])
    assert cands["sensor_gain"].log and min(cands["sensor_gain"].grid) < 1 < max(cands["sensor_gain"].grid)


def test_a_width_whose_profile_has_no_maximum_is_not_identifiable():
    """A structural change's continuous parameter without a likelihood maximum in the searched
    range (no std) is not identifiable; a delay of whole samples is a choice and needs no std."""
    from skigen.diagnose import catalog as C, transform as T
    from skigen.diagnose.name import Correction
    from skigen.diagnose.plausible import screen
    sc = make("arm_backlash", 5.0, SEED)
    model, rec = T.constants(load_model(sc.model_file)), sc.recording()
    cands = C.structural_candidates(model, C.rate_equations(model), np.asarray(rec.inputs))
    dead = next(s for s in cands if s.effect == "dead_zone")
    delay = next(s for s in cands if s.effect == "input_delay")
    kept, rejected = screen(model, Correction([], [(dead, 0.08, np.nan), (delay, 1.0, np.nan)]), None, rec, 0.01)
    assert [s.effect for s, *_ in kept.structural] == ["input_delay"]
    assert [(r["effect"], r["equation"]) for r in rejected["not_identifiable"]] == [("dead_zone", "V")]
    kept, rejected = screen(model, Correction([], [(dead, 0.08, 0.004)]), None, rec, 0.01)
    assert len(kept.structural) == 1 and not rejected["not_identifiable"]


def test_a_user_candidate_that_cannot_be_read_is_named_with_what_it_may_use():
    from skigen.diagnose.catalog import user_candidates
    m = _echo()
    with pytest.raises(ValueError, match=r"formula 'tanh\(w\)': name 'w' is not defined \(known names: .*x.*u"):
        user_candidates(m, [("drag", "x", "tanh(w)")])
    with pytest.raises(ValueError, match=r"time is not a symbol of the model: declare an input for it"):
        user_candidates(m, [("drift", "x", "t * u")])
    with pytest.raises(ValueError, match=r"formula 'u \*' is not an expression"):
        user_candidates(m, [("gain", "x", "u *")])
    with pytest.raises(ValueError, match=r"candidate 'gain': no equation 'v' \(states: x\)"):
        user_candidates(m, [("gain", "v", "u")])
    with pytest.raises(ValueError, match=r"formula 'tanh\(x, 2\)' cannot be evaluated: .*\(functions: tanh, "):
        user_candidates(m, [("drag", "x", "tanh(x, 2)")])         # was a raw CasADi traceback


def test_a_caret_in_a_formula_is_a_power_binding_as_on_paper():
    """'-r^3' raised a TypeError traceback (Python's xor); a caret is now a power, and binds as one:
    2·x^2 + 1 is 2x² + 1, not Python's (2x) xor 3."""
    import casadi as ca
    from skigen.diagnose.catalog import user_candidates
    from skigen.diagnose.transform import formula
    m = _echo()
    x = m.states[0].sym
    f = ca.Function("f", [x], [formula(m, "2*x^2 + 1"), formula(m, "-x^3"), formula(m, "2^3^2")])
    assert [float(v) for v in f(3.0)] == [19.0, -27.0, 512.0]
    assert user_candidates(m, ["cubic:x:-x^3"])[0].formula == "-x^3"


@pytest.mark.parametrize("role", [None, "velocity"])
def test_the_rate_of_a_position_gets_friction_and_stiffness_whatever_its_declared_role(role):
    """A motor's speed ω with θ̇ = ω is a velocity by kinematics: a model that declares θ a position
    and leaves ω's role out gets the same candidates on ω as one that declares it (before, it got
    no damping, drag or friction, and a DC motor's Coulomb friction went unnamed)."""
    from skigen import Model
    from skigen.diagnose.catalog import additive_candidates
    m = Model("motor", dt=0.002, substeps=4)
    th = m.state("theta", unit="rad", role="position", std=0.01)
    om = m.state("omega", unit="rad/s", std=0.1, **({"role": role} if role else {}))
    i = m.state("i", unit="A", std=0.1)
    v = m.input("V", unit="V")
    m.dynamics({th: om, om: 500 * i - 2 * om, i: 1000 * v - 2000 * i - 50 * om})
    m.output("enc", th, noise_std=2e-3)
    effects = {c.effect for c in additive_candidates(m, ["omega"], {"omega": 10.0})}
    assert {"viscous_damping", "quadratic_drag", "coulomb_friction", "linear_stiffness", "cubic_stiffness"} <= effects
    assert {c.formula for c in additive_candidates(m, ["omega"], {"omega": 10.0}) if c.effect == "coulomb_friction"} \
        == {"-tanh(omega/0.05)", "-tanh(omega/0.2)", "-tanh(omega/0.8)"}


@pytest.mark.parametrize("role", [None, "angle"])
def test_a_state_whose_rate_adds_a_velocity_is_its_position_whatever_its_role(role):
    """An angle of attack α̇ = Zα·α + q + Zδ·δe declared without a role got no stiffness terms on q:
    a −60·α³ pitching moment came out as 'the constant 8·al × 1.162', a mismatch remaining; with
    role='angle' it was named 60.3 ± 0.7. α integrates q whatever its role."""
    from skigen import Model
    from skigen.diagnose.catalog import additive_candidates
    m = Model("pitch", dt=0.01)
    al = m.state("al", std=0.01, **({"role": role} if role else {}))
    q = m.state("q", std=0.01)
    de = m.input("de")
    m.dynamics({al: -1.2 * al + q + 0.1 * de, q: -4 * al - 1.5 * q - 8 * de})
    m.output("al_m", al, noise_std=1e-3)
    stiffness = {(c.effect, c.formula) for c in additive_candidates(m, ["q", "al"], {"q": 1.0, "al": 1.0})
                 if c.effect.endswith("stiffness")}
    assert stiffness == {("linear_stiffness", "-al"), ("cubic_stiffness", "-al**3")}, stiffness   # on q, in α only


def test_an_input_that_drives_two_equations_is_offered_terms_added_to_it():
    """The force on a cart-pole drives v̇ and, through the coupling, ω̇: friction, offset and gain
    are also offered through F, entering both equations as ∂(rate)/∂F does (to first order exactly
    F → F + c·φ), each friction oriented so that a positive coefficient opposes the motion. The
    cart alone (F drives v̇ only) gets none."""
    import casadi as ca
    from models import cart, cart_pole
    from skigen.diagnose.catalog import channel_candidates
    m = cart_pole.model
    rng = np.random.default_rng(0)
    states = rng.normal(0, [0.2, 0.3, 0.05, 0.4], (200, 4))
    inputs = rng.normal(0, 2.0, (200, 1))
    cands = channel_candidates(m, ["v", "w"], {"v": 0.3, "w": 0.4}, states, inputs)
    assert {(c.effect, c.equation) for c in cands} == {
        ("bias", "v"), ("input_gain", "v"),
        *((e, q) for e in ("viscous_damping", "quadratic_drag", "coulomb_friction") for q in ("v", "w"))}
    assert all(c.through == "F" for c in cands)
    assert {c.effect: c.text for c in cands if c.effect in ("input_gain", "bias")} == {
        "input_gain": "F·(1 + c)", "bias": "1, added to F"}          # not "F, added to F"
    assert {c.formula for c in cands if c.effect == "coulomb_friction"} == {   # ∂v̇/∂F > 0, ∂ω̇/∂F < 0 upright
        "-tanh(v/0.0015)", "-tanh(v/0.006)", "-tanh(v/0.024)", "tanh(w/0.002)", "tanh(w/0.008)", "tanh(w/0.032)"}
    assert {c.formula for c in cands if c.effect == "viscous_damping"} == {"-v", "w"}
    # the contributions are the first-order change of the rates under F → F + ε·φ
    x, F = ca.vertcat(*[v.sym for v in m.states]), m.inputs[0].sym
    rhs = ca.vertcat(*[m.rhs[n] for n in m.state_names])
    for c in cands:
        phi, rates = c.sx(m), c.contributions(m)
        assert set(rates) == {"v", "w"}
        eps = 1e-6
        moved = ca.substitute(rhs, F, F + eps * phi)
        f = ca.Function("f", [x, F], [(moved - rhs) / eps, ca.vertcat(0, rates["v"], 0, rates["w"])])
        for k in range(0, 200, 40):
            finite, analytic = (np.asarray(a).ravel() for a in f(states[k], inputs[k]))
            assert np.allclose(finite, analytic, rtol=1e-5, atol=1e-9), (c.effect, finite, analytic)
    assert channel_candidates(cart.model, ["v"], {"v": 0.3}, states[:, :2], inputs) == []
    from skigen import Model        # ∂(rate)/∂u through an input history: not evaluable on the trajectory
    h = Model("history", dt=0.01)
    p, v, w, u = h.state("p", role="position"), h.state("v", role="velocity"), h.state("w", role="rate"), h.input("u")
    (u1,) = h.input_history(u, 1)
    h.dynamics({p: v, v: u * u1 - v, w: u - w})
    h.output("y", p, noise_std=0.1)
    assert channel_candidates(h, ["v", "w"], {"v": 1.0, "w": 1.0}, states[:, :3], inputs) == []


def test_a_term_added_to_an_input_reaches_the_outputs_that_read_it():
    """A cell's terminal voltage reads the current directly (−R₀·I): an offset of the current
    sensor moves both the charge and that voltage. A term through I enters the output as it
    enters the rates — exactly in the corrected model (I → I + c), to first order (∂h/∂I·c·φ)
    while naming — and a structural change of I (a saturation) does too. Before, the output kept
    the raw current and a user's 0.3 A current bias came with an invented 14.9 mV voltage-sensor
    offset (R₀ × 0.3 A) beside it."""
    from skigen import Model
    from skigen.diagnose import transform as T
    from skigen.diagnose.catalog import channel_candidates
    from skigen.diagnose.correct import parametrised
    from skigen.diagnose.name import Correction
    m = Model("cell", dt=1.0)
    soc, v1, cur = m.state("soc", initial=0.9, std=0.05), m.state("v1", std=0.01), m.input("I", unit="A")
    m.dynamics({soc: -cur / 9000.0, v1: -v1 / 30.0 + cur / 1000.0})
    m.output("v_term", 3.3 + 0.7 * soc - 0.05 * cur - v1, unit="V", noise_std=1e-3)
    rng = np.random.default_rng(3)
    current = rng.uniform(0.0, 4.0, (300, 1))
    states = np.c_[np.linspace(0.9, 0.8, 300), rng.normal(0, 0.05, 300)]
    (bias,) = [c for c in channel_candidates(m, ["soc", "v1"], {"soc": 1e-4, "v1": 1e-3}, states, current)
               if c.effect == "bias"]
    truth = T.replace_input(m, "I", cur + 0.3)
    for corrected in (Correction([(bias, 0.3, 0.01)]).build(m), parametrised(m, Correction([(bias, 0.3, 0.01)]))[0]):
        assert np.allclose(free_run(T.constants(corrected), current)[1], free_run(truth, current)[1], atol=1e-12)
    _, y = free_run(T.input_saturation(m, "I", None, 2.0), current)
    _, y_clipped = free_run(m, np.minimum(current, 2.0))
    assert np.allclose(y, y_clipped, atol=1e-12) and not np.allclose(y, free_run(m, current)[1])


def test_a_runaway_trajectory_names_no_numpy_warning():
    """Candidates' values along a trajectory that ran away (states 1e200): their RMS is inf and
    no RuntimeWarning reaches the user (seven did, from a fleet's diagnosis, without the log's name)."""
    import warnings
    from skigen.diagnose import catalog as C
    from skigen.diagnose import transform as T
    from skigen.diagnose.name import basis_rms, restated
    model = T.constants(arm.build())
    rec = make("arm_clean", 2.0, 1).recording()
    states = np.full((len(rec.t), 2), 1e200)
    cands = C.additive_candidates(model, ["omega"], {"theta": 1.0, "omega": 1.0}, states)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        rms = basis_rms(model, rec, states, cands)
        restated(model, rec, states, cands)
    assert np.isinf(rms).any()


def test_a_grid_goes_on_past_a_best_end():
    """_profile past the ends of a grid (Structural.beyond): a lag whose likelihood peaks at 45 s
    beyond a grid ending at 32 s, a width peaking at 0.5 below a grid starting at 0.92, an offset
    peaking at -2.4 beyond -1; without ``beyond`` the end is kept, with no std."""
    from skigen.diagnose.catalog import Structural
    from skigen.diagnose.name import _profile
    def grid(values, beyond, log=True):
        return Structural("x", "u", "p", "", tuple(values), False, log, None, None, "", beyond=beyond)
    for values, peak, beyond, log in (((1, 2, 4, 8, 16, 32), 45.0, 2.0, True),
                                      ((0.92, 1.15, 1.64, 2.36), 0.5, 1.5, True),
                                      ((-1.0, -0.3, 0.3, 1.0), -2.4, 3.0, False)):
        total = (lambda v, p=peak, log=log: -(np.log(v / p) if log else v - p) ** 2 * 50)
        value, _, std = _profile(total, grid(values, beyond, log), values)
        assert value == pytest.approx(peak, rel=0.01) and np.isfinite(std), (values, value, std)
        value, _, std = _profile(total, grid(values, 0.0, log), values)
        assert value in (min(values), max(values)) and np.isnan(std)


@pytest.mark.parametrize("peak", [25, 20, 17, 44])
def test_a_whole_number_past_the_grid_is_found_between_the_extensions(peak):
    """An input delay of 20 or 25 samples past a grid ending at 15: the extension tried 30 (and
    60) and a heat exchanger's 25-sample delay was named 30, nothing between tried; now the gaps
    beside the best are halved down to its neighbours, in a few evaluations."""
    from skigen.diagnose.catalog import Structural
    from skigen.diagnose.name import _profile
    s = Structural("input_delay", "u", "delay", "samples", tuple(range(1, 16)), True, False, None, None, "",
                   beyond=2.0)
    calls = []
    total = lambda v: calls.append(v) or -abs(v - peak)
    value, _, std = _profile(total, s, [1, 2, 4, 8, 15])
    assert value == peak and np.isnan(std) and len(calls) < 20


@pytest.mark.parametrize("peak", [0.9262, 1.0832, 2.4171, -0.0371])
def test_a_profile_resolves_a_sharp_peak_above_one_as_below(peak):
    """A gain known to 0.04 % (a gyro's 1.0832 ± 0.0004 from a precise encoder) is profiled to a
    fraction of its std, above 1 as below it, and so is an offset (not log-scaled); its std is
    the curvature's. (Rounded to 3 significant digits, 1.08 came out 1.09, 25σ off, while
    0.926 resolved.)"""
    from skigen.diagnose.catalog import SENSOR_GAINS, Structural
    from skigen.diagnose.name import _profile
    log = peak > 0
    sd = 4e-4 * abs(peak)
    values = SENSOR_GAINS if log else (-0.3, -0.1, -0.03, 0.03, 0.1, 0.3)
    s = Structural("sensor_gain", "", "gain", "", values, False, log, None, None, "", beyond=1.5)
    total = lambda v: -0.5 * ((v - peak) / sd) ** 2
    value, best, std = _profile(total, s, values)
    assert abs(value - peak) < 0.5 * sd and best > -0.125
    assert std == pytest.approx(sd, rel=0.1)


def _sample(f, x, u, dt: float, sub: int):
    """The state one sample of ``dt`` after ``x``: RK4 in ``sub`` steps of f(x, u), u held."""
    h = dt / sub
    for _ in range(sub):
        k1 = f(x, u); k2 = f(x + h / 2 * k1, u); k3 = f(x + h / 2 * k2, u); k4 = f(x + h * k3, u)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def _motor(steps: int, coulomb: float, seed: int):
    """A DC motor θ̈ = −2θ̇ + 10V[k − steps] − coulomb·tanh(θ̇/0.01), three sines, 60 s at 100 Hz,
    encoder noise 2 mrad: (the nominal model without either effect, the recording)."""
    from skigen import Model
    from skigen.recording import Recording
    m = Model("motor", dt=0.01)
    th = m.state("theta", unit="rad", role="angle", std=0.1, process_std=1e-3)
    w = m.state("omega", unit="rad/s", role="rate", std=1.0, process_std=1e-2)
    V = m.input("V", unit="V")
    m.dynamics({th: w, w: -2.0 * w + 10.0 * V})
    m.output("theta_enc", th, unit="rad", noise_std=0.002)
    rng, N, dt = np.random.default_rng(seed), 6000, 0.01
    t = np.arange(N) * dt
    u = 1.5 * np.sin(2 * np.pi * 0.3 * t) + 0.8 * np.sin(2 * np.pi * 1.1 * t + 1) + 0.4 * np.sin(2 * np.pi * 2.7 * t)
    seen = np.r_[np.zeros(steps), u][:N]
    f = lambda x, v: np.array([x[1], -2.0 * x[1] + 10.0 * v - coulomb * np.tanh(x[1] / 0.01)])
    x, X = np.zeros(2), np.zeros((N, 2))
    for k in range(N):
        X[k] = x
        x = _sample(f, x, seen[k], dt, 10) + np.r_[0.0, 1e-3 * rng.normal()]
    return m, Recording("motor.csv", t, u[:, None], X[:, :1] + 0.002 * rng.normal(size=(N, 1)), ("V",), ("theta_enc",))


def test_a_delay_chosen_before_a_friction_is_searched_again(tmp_path):
    """Coulomb friction and a delay of 3 samples together (a user's motor): the first round takes
    the delay at 2.6 samples, half of what the missing friction leaves; once the friction is in,
    the delay is searched again (moved last: a delay commutes with every other change) and is 3,
    the friction 1.0 (it was 1.074 ± 0.024 beside the 2.6, and a mismatch remained)."""
    from skigen.diagnose import diagnose
    model, rec = _motor(3, 1.0, 24)
    d = diagnose(model, rec, tmp_path, show_progress=False, figures=False, emit=False).data
    found = {f["effect"]: f for f in d["findings"]}
    assert set(found) == {"coulomb_friction", "input_delay"}, d["findings"]
    assert found["input_delay"]["coefficient"] == 3
    friction = found["coulomb_friction"]
    assert abs(friction["coefficient"] - 1.0) < min(4 * friction["std"], 0.02), friction
    assert d["remaining"]["mismatch"] is False


def test_a_lag_on_an_input_that_reaches_the_rate_through_another_state_is_named(tmp_path):
    """A hot-air balloon (a user's): the burner Q heats the envelope T, whose lift drives the climb
    rate vz; the burner acts through a 20 s lag. The mismatch is located on vz, which Q reaches
    only through T: no delay or lag of Q was proposed, and nothing was named. Now the lag is,
    within 4 std of 20 s and 5 %, and nothing remains."""
    from skigen import Model
    from skigen.diagnose import diagnose
    from skigen.recording import Recording
    m = Model("balloon", dt=0.5, discretization="rk4")
    h = m.state("h", unit="m", role="position", std=1.0, process_std=0.001)
    vz = m.state("vz", unit="m/s", role="rate", std=0.1, process_std=0.005)
    T = m.state("T", unit="K", initial=50.0, std=0.5, process_std=0.02)
    Q = m.input("Q")
    m.dynamics({h: vz, vz: 0.01 * (T - 50.0) - 0.1 * vz, T: -T / 100.0 + 0.5 * Q})
    m.output("h_gps", h, unit="m", noise_std=0.5)
    m.output("T_env", T, unit="K", noise_std=0.3)
    rng, N, dt = np.random.default_rng(33), 2400, 0.5
    q, k = np.ones(N), 60
    while k < N:
        n = int(rng.integers(40, 161))
        q[k:k + n], k = rng.uniform(0.5, 1.5), k + n
    f = lambda x, u: np.array([x[1], 0.01 * (x[2] - 50) - 0.1 * x[1], -x[2] / 100 + 0.5 * x[3], (u - x[3]) / 20.0])
    x, X = np.array([0.0, 0.0, 50.0, 1.0]), np.zeros((N, 4))
    for j in range(N):
        X[j] = x
        x = _sample(f, x, q[j], dt, 20) + rng.normal(size=4) * [0.001, 0.005, 0.02, 0.0]
    y = np.c_[X[:, 0] + rng.normal(0, 0.5, N), X[:, 2] + rng.normal(0, 0.3, N)]
    rec = Recording("balloon.csv", np.arange(N) * dt, q[:, None], y, ("Q",), ("h_gps", "T_env"))
    d = diagnose(m, rec, tmp_path, show_progress=False, figures=False, emit=False).data
    top = d["findings"][0] if d["findings"] else None
    assert top is not None and (top["effect"], top.get("input")) == ("actuator_lag", "Q"), d["findings"]
    assert abs(top["coefficient"] - 20.0) < min(4 * top["std"], 1.0), top
    assert d["remaining"]["mismatch"] is False


def test_a_sharp_dead_zone_is_named_at_its_width(tmp_path):
    """A hydraulic actuator's sharp dead zone of 0.5 on a ±1 command (a user's): named 0.5167 ±
    0.0017 with 'a mismatch remains' while the model's corners were rounded over a tenth of the
    width; over a hundredth, within 4 std of 0.5 and consistent."""
    from skigen import Model
    from skigen.diagnose import diagnose
    from skigen.recording import Recording
    m = Model("hydro", dt=0.01, discretization="rk4")
    x = m.state("x", unit="m", role="position", std=0.01, process_std=1e-5)
    v = m.state("v", unit="m/s", role="rate", std=0.01, process_std=0.005)
    u = m.input("u", unit="V")
    m.dynamics({x: v, v: -25.0 * x - 3.0 * v + 25.0 * u})
    m.output("x_meas", x, unit="m", noise_std=0.002)
    rng, N, dt = np.random.default_rng(72), 5000, 0.01
    cmd, k = np.zeros(N), 0
    while k < N:
        n = int(rng.integers(30, 151))
        cmd[k:k + n], k = rng.uniform(-1, 1), k + n
    seen = np.sign(cmd) * np.maximum(np.abs(cmd) - 0.5, 0)
    f = lambda s, w: np.array([s[1], -25 * s[0] - 3 * s[1] + 25 * w])
    s, X = np.zeros(2), np.zeros((N, 2))
    for j in range(N):
        X[j] = s
        s = _sample(f, s, seen[j], dt, 20) + rng.normal(size=2) * [1e-5, 0.005]
    rec = Recording("hydro.csv", np.arange(N) * dt, cmd[:, None], X[:, :1] + rng.normal(0, 0.002, (N, 1)), ("u",), ("x_meas",))
    d = diagnose(m, rec, tmp_path, show_progress=False, figures=False, emit=False).data
    top = d["findings"][0] if d["findings"] else None
    assert top is not None and top["effect"] == "dead_zone", d["findings"]
    assert abs(top["coefficient"] - 0.5) < min(4 * top["std"], 0.005), top
    assert d["remaining"]["mismatch"] is False


def _bicycle_with_delay(seed: int, seconds: float, delay: int):
    """A car's single-track lateral model at 20 m/s (a user's), Cf 80, Cr 90 kN/rad, Iz 2.5 t m², the
    steering 5 samples late, random steps of ±0.03 rad, process noise 2 (vy) and 1 (r) per sample:
    (t, delta, r_gyro, ay)."""
    U, M, A, B, dt = 20.0, 1.5, 1.2, 1.6, 0.01
    def rhs(x, d):
        ff, fr = 80.0 * (d - (x[0] + A * x[1]) / U), -90.0 * (x[0] - B * x[1]) / U
        vyd = (ff + fr) / M - U * x[1]
        return np.array([vyd, (A * ff - B * fr) / 2.5]), vyd
    rng = np.random.default_rng(seed)
    n = int(round(seconds / dt)) + 1
    u, i = np.zeros(n), 0
    while i < n:
        L = rng.integers(30, 150)
        u[i:i + L], i = 0.03 * rng.uniform(-1, 1), i + L
    ud, x, X, AY = np.r_[np.zeros(delay), u][:n], np.zeros(2), np.zeros((n, 2)), np.zeros(n)
    for k in range(n):
        X[k] = x
        AY[k] = rhs(x, ud[k])[1] + U * x[1]
        if k == n - 1:
            break
        w = 2.0 * rng.standard_normal(2) * [1.0, 0.5]
        x = _sample(lambda z, d: rhs(z, d)[0] + w, x, ud[k], dt, 20)
    return np.arange(n) * dt, u, X[:, 1] + 0.005 * rng.standard_normal(n), AY + 0.1 * rng.standard_normal(n)


def test_the_refit_keeps_the_user_s_prior_not_the_calibration_s_compromise(tmp_path):
    """A car model whose stiffnesses a previous fit knows (declared with its values and std, as a
    fitted_model.py declares them: Cf 76.9 ± 1.9, Cr 94.6 ± 4.8, Iz 2.41 ± 0.18), on a recording
    whose steering is 5 samples late: the calibration, the delay not yet named, bends them (Cf 54,
    Cr 58); once the delay is named, the joint refit is held by a prior centred on the user's
    values, not on that compromise (centred on it: Cf 69.5 ± 1.1, −9.5σ, Cr 74.5 ± 2.2, and
    'consistent')."""
    from skigen import Model
    from skigen.diagnose import diagnose
    from skigen.recording import Recording
    U, M, A, B = 20.0, 1.5, 1.2, 1.6
    m = Model("bicycle", dt=0.01, discretization="rk4", substeps=2)
    vy = m.state("vy", unit="m/s", role="rate", std=0.05, process_std=0.02)
    r = m.state("r", unit="rad/s", role="rate", std=0.01, process_std=0.01)
    delta = m.input("delta", unit="rad")
    Cf = m.parameter("Cf", 76.92, std=1.914, bounds=(1.0, 500.0))
    Cr = m.parameter("Cr", 94.58, std=4.844, bounds=(1.0, 500.0))
    Iz = m.parameter("Iz", 2.412, std=0.1826, bounds=(0.1, 20.0))
    ff, fr = Cf * (delta - (vy + A * r) / U), Cr * (-(vy - B * r) / U)
    vyd = (ff + fr) / M - U * r
    m.dynamics({vy: vyd, r: (A * ff - B * fr) / Iz})
    m.output("r_gyro", r, unit="rad/s", noise_std=0.005)
    m.output("ay", vyd + U * r, unit="m/s^2", noise_std=0.1)
    m.covariances(Q=np.diag([4.07e-4, 9.76e-5]), R=np.diag([2.29e-5, 9.64e-3]), P0=np.diag([0.0025, 1e-4]))
    t, u, gyro, ay = _bicycle_with_delay(12, 30.0, 5)
    rec = Recording("car.csv", t, u[:, None], np.c_[gyro, ay], ("delta",), ("r_gyro", "ay"))
    d = diagnose(m, rec, tmp_path, show_progress=False, figures=False, emit=False).data
    assert [f["effect"] for f in d["findings"]] == ["input_delay"] and d["findings"][0]["coefficient"] == 5, d["findings"]
    assert d["noise"]["parameters"]["Cf"]["calibrated"] < 65, d["noise"]["parameters"]    # the compromise
    for name, truth in (("Cf", 80.0), ("Cr", 90.0), ("Iz", 2.5)):
        p = d["refit"]["parameters"][name]
        assert abs(p["value"] - truth) < 3 * p["std"], (name, p)


def test_a_delay_is_searched_again_at_the_refitted_constants(tmp_path):
    """A motor whose damping and gain another fit knows (2.0 ± 0.05, 10 ± 0.2), its input 3 samples
    late: the delay is searched while the calibration holds the constants at its compromise, and
    came out 2.83 samples, the refitted constants then 6–10σ off and a mismatch left. Searched
    again at the refitted constants, in turn with them until it stays: 3, the constants right,
    nothing left."""
    from skigen import Model
    from skigen.diagnose import diagnose
    _, rec = _motor(3, 0.0, 7)
    m = Model("motor", dt=0.01)
    th = m.state("theta", unit="rad", role="angle", std=0.1, process_std=1e-3)
    w = m.state("omega", unit="rad/s", role="rate", std=1.0, process_std=1e-2)
    V = m.input("V", unit="V")
    c, g = m.parameter("c", 2.0, std=0.05), m.parameter("g", 10.0, std=0.2)
    m.dynamics({th: w, w: -c * w + g * V})
    m.output("theta_enc", th, unit="rad", noise_std=0.002)
    d = diagnose(m, rec, tmp_path, show_progress=False, figures=False, emit=False).data
    assert [(f["effect"], f["coefficient"]) for f in d["findings"]] == [("input_delay", 3.0)], d["findings"]
    for name, truth in (("c", 2.0), ("g", 10.0)):
        p = d["refit"]["parameters"][name]
        assert abs(p["value"] - truth) < 4 * p["std"], (name, p)
    assert d["remaining"]["mismatch"] is False


def test_grids_of_quantiles_have_their_gaps_filled():
    """|δ| of a command clipped at ±0.611 for a third of the run: its quantiles 0.105, 0.570, 0.611
    left a 5.4× gap in which a rudder stop went unseen; on a log scale no neighbours are now more
    than 1.5× apart, on a linear one no gap is wider than the span over 8, and the quantiles
    themselves stay in the grid."""
    from skigen.diagnose.catalog import GRID_RATIO, GRID_STEPS, filled
    g = filled([0.105, 0.570, 0.611], log=True)
    assert {0.105, 0.570, 0.611} <= set(g) and len(g) == 7
    assert np.all(np.diff(np.log(g)) <= np.log(GRID_RATIO) + 1e-12)
    lin = filled([-1.0, -0.9, 2.0], log=False)
    assert {-1.0, -0.9, 2.0} <= set(lin) and np.max(np.diff(lin)) <= 3.0 / GRID_STEPS + 1e-12
    assert filled([0.2, 0.25], log=True) == (0.2, 0.25) and filled([1.0], log=True) == (1.0,)


def test_a_sensor_finding_says_what_its_output_reads():
    """A current sensor reading (u − 0.05·ω)/1.2 had its gain labelled '(reads w)'; it now gives
    the output's formula, and a sensor of a state alone still names the state."""
    from skigen import Model
    from skigen.diagnose import _reads
    from skigen.diagnose.report import where
    m = Model("motor_i", dt=0.01)
    w, u = m.state("w"), m.input("u")
    m.dynamics({w: -w + u})
    m.output("i_meas", (u - 0.05 * w) / 1.2)
    m.output("speed", w)
    f = dict(effect="sensor_gain", output="i_meas", equation="w", reads=_reads(m, "i_meas"))
    assert where(f) == "sensor_gain of i_meas (reads ((u-(0.05*w))/1.2))"
    assert _reads(m, "speed") is None
    assert where(dict(effect="sensor_gain", output="speed", equation="w")) == "sensor_gain of speed (reads w)"


def _roll(lp: float, seed: int, seconds: float = 20.0, dt: float = 0.01):
    """A roll axis φ̇ = p, ṗ = Lp·p + 20·δa (exact ZOH, 0.01 rad/s per sample on p) flown with
    3-2-1-1 aileron inputs, φ and p read with 0.01 and 0.02: (model declaring Lp = −4, frame)."""
    from scipy.linalg import expm
    from skigen import Model
    t = np.arange(int(round(seconds / dt)) + 1) * dt
    u = np.zeros_like(t)
    for start in np.arange(1.0, t[-1] - 3.2, 4.0):
        s = start
        for n, sign in ((3, 1), (2, -1), (1, 1), (1, -1)):
            u[(t >= s) & (t < s + 0.4 * n)] = 0.08 * sign
            s += 0.4 * n
    E = expm(np.block([[np.array([[0, 1], [0, lp]]), np.array([[0], [20.0]])], [np.zeros((1, 3))]]) * dt)
    rng = np.random.default_rng(seed + 1000)
    X, x = np.zeros((len(t), 2)), np.zeros(2)
    for k in range(len(t)):
        X[k] = x
        x = E[:2, :2] @ x + E[:2, 2] * u[k]
        x[1] += 0.01 * rng.standard_normal()
    noise = np.random.default_rng(seed)
    frame = pd.DataFrame({"t": t, "da": u, "phi_meas": X[:, 0] + 0.01 * noise.standard_normal(len(t)),
                          "gyro_p": X[:, 1] + 0.02 * noise.standard_normal(len(t))})
    m = Model("roll", dt=dt, discretization="rk4")
    phi = m.state("phi", unit="rad", role="angle", std=0.05, process_std=1e-4)
    p = m.state("p", unit="rad/s", role="rate", std=0.05, process_std=0.01)
    da = m.input("da", unit="rad")
    m.dynamics({phi: p, p: -4.0 * p + 20.0 * da})
    m.output("phi_meas", phi, unit="rad", noise_std=0.01)
    m.output("gyro_p", p, unit="rad/s", noise_std=0.02)
    return m, frame


def test_a_kept_term_alone_replaces_the_terms_kept_with_it_and_a_tie_is_said(tmp_path):
    """A roll damping Lp of −6.5 for a declared −4 (a user's damaged airframe, seed 12): ARD keeps a
    cubic damping and a Coulomb friction, the swaps make it cubic + viscous, and the viscous damping
    alone explains as much (it was never tried alone: quadratic drag, 10.3 ± 0.66, was named).
    Named: viscous damping 2.39 ± 0.15 (2.5), not told apart from a quadratic drag in its place."""
    from skigen.diagnose import diagnose
    m, frame = _roll(-6.5, 12)
    d = diagnose(m, frame, tmp_path, figures=False, emit=False, show_progress=False).data
    (f,) = d["findings"]
    assert (f["effect"], f["equation"]) == ("viscous_damping", "p") and abs(f["coefficient"] - 2.5) < 2 * f["std"], f
    assert [(a["effect"], a["instead_of"]) for a in f["as_good"]] == [("quadratic_drag", [["viscous_damping", "p", ""]])]
    assert not d["remaining"]["mismatch"]


def test_an_input_entering_nonlinearly_has_a_gain_on_its_own_terms():
    """The input gain candidate scales what the input adds to the rate: u itself where the gain is
    constant; else each of u's terms less its value at u = 0 (a thrust k·pwm², a moment b·δ·cos θ,
    (pwm + 1)² − 1); u where such a term is infinite at 0; in a discrete model, per second."""
    import casadi as ca
    from skigen import Model
    from skigen.diagnose import transform as T
    from skigen.diagnose.catalog import input_term
    for disc in ("rk4", "discrete"):
        m = Model("entry", dt=0.02, discretization=disc)
        th = m.state("th", std=1.0, process_std=1e-3)
        v = m.state("v", role="velocity", std=1.0, process_std=1e-3)
        pwm, d, a, w = m.input("pwm"), m.input("d"), m.input("a"), m.input("w")
        m.dynamics({th: v, v: 39.24 * pwm ** 2 - 9.81 - 0.3 * v + 2 * d * ca.cos(th) + (a + 1) ** 2 + 3 * w + 1 / w})
        m.output("y", th, noise_std=0.1)
        per = 1 / 0.02 if disc == "discrete" else 1.0
        at = {"th": 0.4, "v": -1.0, "pwm": 0.5, "d": 0.3, "a": 2.0, "w": 5.0}
        value = lambda c: float(ca.Function("f", [T.symbols(m)[k] for k in at], [c.sx(m)])(*at.values()))
        expected = {"pwm": 39.24 * 0.25, "d": 2 * 0.3 * np.cos(0.4), "a": 9.0 - 1.0}
        for u, e in expected.items():
            c = input_term(m, "v", u)
            assert (c.effect, c.equation, c.variant, c.shape) == ("input_gain", "v", f"its {u} term", (("gain on", f"{u}'s terms"),))
            assert value(c) == pytest.approx(per * e, rel=1e-12), (u, c.formula)
        assert (input_term(m, "v", "w").formula, input_term(m, "v", "w").expr) == ("w", None)
    prop = Model("prop", dt=0.02)                       # a sum over a mass: the input's own term, not f − f(0)
    v = prop.state("v", role="velocity", std=1.0, process_std=1e-3)
    n = prop.input("n")
    prop.dynamics({v: (10.0 * n * ca.fabs(n) - 5.0 * v * ca.fabs(v)) / 50.0})
    prop.output("y", v, noise_std=0.1)
    assert input_term(prop, "v", "n").formula == "10.0 * n * fabs(n) / 50.0"
    lin = Model("lin", dt=0.02)
    x = lin.state("x", std=1.0, process_std=1e-3)
    u = lin.input("u")
    lin.dynamics({x: -x + 4 * u})
    lin.output("y", x, noise_std=0.1)
    assert (input_term(lin, "x", "u").formula, input_term(lin, "x", "u").variant) == ("u", "")


def _hover(kt_scale: float, seed: int, seconds: float = 50.0, dt: float = 0.02):
    """A quadrotor's height loop: v̇z = KT·pwm²/M − g, KT = 47.088 N, M = 1.2 kg (hover at pwm 0.5),
    flown by a PID through altitude steps between 0.8 and 3 m with the true KT times ``kt_scale``;
    a lidar reads z with 0.02 m. Returns (model declaring the nominal KT, frame)."""
    from skigen import Model
    kt, mass, g = 47.088, 1.2, 9.81
    rng = np.random.default_rng(seed)
    n = int(round(seconds / dt))
    levels = rng.uniform(0.8, 3.0, size=n // 200 + 1)
    ref = levels[np.arange(n) // 200]
    f = lambda x, u: np.array([x[1], kt_scale * kt * u * u / mass - g])
    x, integral, rows = np.array([1.0, 0.0]), 0.0, []
    for k in range(n):
        z = x[0] + 0.02 * rng.standard_normal()
        integral += (ref[k] - z) * dt
        pwm = float(np.clip(0.5 + 0.3 * (ref[k] - z) + 0.1 * integral - 0.3 * x[1], 0.2, 0.85))
        rows.append((k * dt, pwm, z))
        for _ in range(4):                                  # RK4 at dt/4
            h = dt / 4
            k1 = f(x, pwm); k2 = f(x + h / 2 * k1, pwm); k3 = f(x + h / 2 * k2, pwm); k4 = f(x + h * k3, pwm)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x = x + rng.normal(0, [1e-4, 5e-3])
    m = Model("hover", dt=dt, discretization="rk4")
    z = m.state("z", unit="m", role="altitude", initial=1.0, std=0.05, process_std=1e-4)
    vz = m.state("vz", unit="m/s", role="velocity", std=0.05, process_std=5e-3)
    pwm = m.input("pwm", unit="1")
    m.dynamics({z: vz, vz: kt * pwm ** 2 / mass - g})
    m.output("z_lidar", z, unit="m", noise_std=0.02)
    return m, pd.DataFrame(rows, columns=["t", "pwm", "z_lidar"])


@pytest.mark.parametrize("seed", [3, 5])
def test_a_thrust_constant_off_on_a_squared_command_is_named_on_the_command_s_term(tmp_path, seed):
    """KT 10 % low (a sagging battery) in v̇z = KT·pwm²/M − g, flown in closed loop: the input gain on
    the pwm term, −0.1 of it, is named alone and nothing remains (measured −0.0999 ± 0.0005 and
    −0.0994 ± 0.0005). The loop holds pwm near hover, so a rate offset and a linear gain on pwm
    explain nearly as much. On seed 3 the pwm term wins its round; on seed 5 the search ranks an
    offset (and a Coulomb friction) first under the noise before either, and the pwm term, 36.6
    ahead of them under the noise each leaves, is adopted in their place (before, a lidar gain of
    0.895 was named next to make up the rest, until the revision found the pwm term alone and said
    the offset and the gain as ties). Before the pwm term was a candidate, ARD kept nine terms that
    cross-validated below none of them, and a lidar gain was named."""
    from skigen.diagnose import diagnose
    m, frame = _hover(0.9, seed)
    d = diagnose(m, frame, tmp_path, figures=False, emit=False, show_progress=False).data
    (f,) = d["findings"]
    assert (f["effect"], f["equation"], f["expression"]) == ("input_gain", "vz", "47.088 * pwm ** 2 / 1.2"), f
    assert abs(f["coefficient"] + 0.1) < 3 * f["std"] < 0.003, f
    assert not d["remaining"]["mismatch"]
    if seed == 5:
        assert not f.get("as_good"), f["as_good"]
        assert "adopted as input_gain on vz instead" in (tmp_path / "report.md").read_text()


def test_an_input_gain_on_a_state_without_a_role_beside_a_rate_is_named(tmp_path):
    """A DC motor, L·di/dt = g·V − R·i − Ke·ω, J·dω/dt = Kt·i − B·ω, its speed declared with role
    rate and its current with none; the driver delivers 0.85 of the commanded voltage. Only the
    rate-role equation was tested before, and several findings were named (a user's motor: two
    sensor gains, 0.85 on the current and 0.90 on the speed, and "a mismatch remains"); the
    current's equation is a rate equation too: the input gain on i, −0.15/L = −15 per volt, is
    named alone and nothing remains (measured −14.983 ± 0.018)."""
    from skigen import Model
    from skigen.diagnose import diagnose
    R, L, KT, KE, J, B, dt = 1.0, 0.01, 0.05, 0.05, 0.001, 1e-4, 0.002
    rng = np.random.default_rng(4)
    n = 2500
    volts = np.repeat(rng.uniform(-8, 8, n // 100 + 1), 100)[:n] + 2 * np.sin(2 * np.pi * 3.0 * np.arange(n) * dt)
    f = lambda x, v, g: np.array([(g * v - R * x[0] - KE * x[1]) / L, (KT * x[0] - B * x[1]) / J])
    x, X = np.zeros(2), np.zeros((n, 2))
    for k in range(n):
        X[k] = x
        h = dt / 8
        for _ in range(8):
            k1 = f(x, volts[k], 0.85); k2 = f(x + h / 2 * k1, volts[k], 0.85)
            k3 = f(x + h / 2 * k2, volts[k], 0.85); k4 = f(x + h * k3, volts[k], 0.85)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x = x + rng.normal(0, [0.003, 0.03])
    m = Model("motor", dt=dt, discretization="rk4", substeps=2)
    i = m.state("i", unit="A", std=0.1, process_std=0.003)
    w = m.state("w", unit="rad/s", role="rate", std=1.0, process_std=0.03)
    V = m.input("V", unit="V")
    m.dynamics({i: (V - R * i - KE * w) / L, w: (KT * i - B * w) / J})
    m.output("i_meas", i, unit="A", noise_std=0.03)
    m.output("speed", w, unit="rad/s", noise_std=0.5)
    frame = pd.DataFrame({"t": np.arange(n) * dt, "V": volts, "i_meas": X[:, 0] + rng.normal(0, 0.03, n),
                          "speed": X[:, 1] + rng.normal(0, 0.5, n)})
    d = diagnose(m, frame, tmp_path, figures=False, emit=False, show_progress=False).data
    (f,) = d["findings"]
    assert (f["effect"], f["equation"], f["expression"]) == ("input_gain", "i", "V"), d["findings"]
    assert abs(f["coefficient"] + 15) < 3 * f["std"] < 0.3, f
    assert not d["remaining"]["mismatch"]


def test_a_limit_s_bound_is_refined_between_its_grid_of_quantiles():
    """A soft wall (40 per metre) at x = 0.7 that a mass on a spring pushes into now and then: the
    candidates' bounds are quantiles of x (0.43, 0.51, 0.59, 0.79); the shape search now refines the
    best one between its neighbours on the recording's likelihood (before, 0.588 was kept; a user's
    wall at 0.04 stayed on the 0.0319 quantile, its stiffness 5σ low). The refined bound is within
    0.01 of the wall, and its stiffness within 3 std of the truth."""
    from skigen import Model
    from skigen.diagnose.catalog import additive_candidates
    from skigen.diagnose.name import Correction, basis_rms, refit, shape_search
    dt, n, rng = 0.01, 3000, np.random.default_rng(7)
    t = np.arange(n) * dt
    force = 1.4 * np.sin(2 * np.pi * 0.3 * t) + 0.4 * np.sin(2 * np.pi * 1.1 * t)
    f = lambda s, u: np.array([s[1], u - s[0] - 0.4 * s[1] - 40.0 * max(s[0] - 0.7, 0.0)])
    X, x = np.zeros((n, 2)), np.zeros(2)
    for k in range(n):
        X[k] = x
        for _ in range(10):
            h = dt / 10
            k1 = f(x, force[k]); k2 = f(x + h / 2 * k1, force[k]); k3 = f(x + h / 2 * k2, force[k]); k4 = f(x + h * k3, force[k])
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x[1] += 1e-3 * rng.standard_normal()
    m = Model("wall", dt=dt)
    xs = m.state("x", unit="m", role="position", std=0.01, process_std=1e-5)
    v = m.state("v", unit="m/s", role="velocity", std=0.01, process_std=1e-3)
    u = m.input("F", unit="N")
    m.dynamics({xs: v, v: u - xs - 0.4 * v})
    m.output("x_meas", xs, unit="m", noise_std=0.002)
    from skigen.recording import Recording
    rec = Recording("wall", t, force[:, None], (X[:, 0] + 0.002 * rng.standard_normal(n))[:, None], ("F",), ("x_meas",))
    limits = [c for c in additive_candidates(m, ["v"], {"v": 1.0}, X) if c.effect == "physical_limit"
              and dict(c.shape)["side"] == "upper"]
    grid = [dict(c.shape)["bound"] for c in limits]
    assert not any(abs(b - 0.7) < 0.01 for b in grid), grid
    rms = dict(zip(limits, basis_rms(m, rec, X, limits)))
    size = {"v": 1.0}
    start = min(limits, key=lambda c: abs(dict(c.shape)["bound"] - 0.7))
    corr = refit(m, Correction([(start, 0.0, 0.0)]), rec, rms, size)
    got, _ = shape_search(m, corr, {start.group: limits}, rec, rms, size)
    c, k, sd = got.additive[0]
    bound = dict(c.shape)["bound"]
    assert abs(bound - 0.7) < 0.01 and abs(bound - 0.7) < min(abs(b - 0.7) for b in grid), (bound, grid)
    assert abs(k - 40) < 3 * sd, (k, sd)


def test_a_coulomb_friction_s_width_is_refined_between_the_grid_s(tmp_path):
    """A mass-spring (no roles) with a dry friction 1.5·tanh(v/0.01) under a PRBS force: the widths
    tried are 4× apart and the grid's nearest took 0.019, 1.642 ± 0.020 (7σ high; on a user's
    recording 0.0044, 1.316 ± 0.073 and "a mismatch remains"). The width is now refined between
    its neighbours, as a limit's bound is (measured: 0.0114, 1.504 ± 0.068, consistent; the
    user's: 0.0077, 1.38 ± 0.12); coulomb_width rebuilds the term."""
    from skigen import Model
    from skigen.diagnose import diagnose
    from skigen.diagnose.catalog import Additive, coulomb_width
    c = Additive("coulomb_friction", "v", "-tanh(v/0.02)", "", "width 0.02 m/s", shape=(("width", 0.02),), sign=1)
    moved = coulomb_width(c, 0.0123456)
    assert (moved.formula, moved.variant, moved.shape) == ("-tanh(v/0.0123)", "width 0.0123 m/s", (("width", 0.0123),))
    rng = np.random.default_rng(52)
    n, dt = 4000, 0.01
    F = np.concatenate([np.full(rng.integers(30, 151), rng.choice([-4.0, -2.0, 0.0, 2.0, 4.0])) for _ in range(60)])[:n]
    f = lambda x, u: np.array([x[1], -40 * x[0] - 0.8 * x[1] + u - 1.5 * np.tanh(x[1] / 0.01)])
    x, X = np.zeros(2), []
    for u in F:
        X.append(x)
        for _ in range(4):                         # the truth's friction is stiff: RK4 at dt/4
            h = dt / 4
            k1 = f(x, u); k2 = f(x + h / 2 * k1, u); k3 = f(x + h / 2 * k2, u); k4 = f(x + h * k3, u)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x = x + [1e-6, 5e-3] * rng.standard_normal(2)
    m = Model("springmass", dt=dt, discretization="rk4")
    p = m.state("x", unit="m", std=0.01, process_std=1e-6)
    v = m.state("v", unit="m/s", std=0.05, process_std=5e-3)
    force = m.input("F", unit="N")
    m.dynamics({p: v, v: -40.0 * p - 0.8 * v + 1.0 * force})
    m.output("x_meas", p, unit="m", noise_std=2e-3)
    frame = pd.DataFrame({"t": np.arange(n) * dt, "F": F, "x_meas": np.array(X)[:, 0] + 2e-3 * rng.standard_normal(n)})
    rep = diagnose(m, frame, tmp_path, figures=False, emit=False, show_progress=False)
    top = rep.findings[0]
    assert top["effect"] == "coulomb_friction" and abs(top["coefficient"] - 1.5) < 3 * top["std"], rep.findings
    width = float(top["expression"].split("/")[1].rstrip(")"))
    assert 0.007 < width < 0.015 and not rep.data["remaining"]["mismatch"], (width, rep.data["remaining"])


def test_terms_on_an_equation_that_is_no_velocity_read_as_losses():
    """A hydraulic leak on a pressure's equation was named "viscous_damping ... viscous friction,
    linear drag": the engineer was pointed at a bearing. On an equation that is no velocity (and
    drives no position) the same terms read as losses; on a velocity, as friction and drag."""
    from skigen import Model
    from skigen.diagnose.catalog import additive_candidates
    m = Model("actuator", dt=0.01)
    y, v, p = m.state("y", unit="m"), m.state("v", unit="m/s"), m.state("p", unit="bar")
    u = m.input("u")
    m.dynamics({y: v, v: 2.0 * p - 0.5 * v, p: 10.0 * u - 3.0 * v})
    reading = {(c.equation, c.effect): c.reading for c in additive_candidates(m, ["v", "p"], {"v": 1.0, "p": 1.0})}
    assert reading[("p", "viscous_damping")].startswith("a loss proportional to the state (a leak")
    assert reading[("v", "viscous_damping")].startswith("damping proportional to the rate (viscous friction")
    assert reading[("p", "coulomb_friction")] == "a constant loss opposing the sign of the state"


def test_a_third_finalist_rescored_under_its_own_noise_can_win(tmp_path):
    """A servo valve with a dead band of ±0.1 on its command (steps of −0.5…0.5 held 0.1–0.6 s):
    under the nominal's noise the dead zone at its right width scored third, behind a position
    sensor gain of 0.70 and a set of four additive terms; only the two best were scored again
    under the noise each leaves, and a sensor gain of 0.72 with a Coulomb friction and a negative
    damping were named, "a mismatch remains". Three finalists now: the dead zone, 0.0998 ±
    0.0003, consistent (measured)."""
    from skigen import Model
    from skigen.diagnose import diagnose
    m = Model("valve", dt=0.01, discretization="rk4")
    x = m.state("x", unit="m", role="position", std=0.002, process_std=1e-5)
    v = m.state("v", unit="m/s", role="velocity", std=0.01, process_std=5e-4)
    u = m.input("u")
    m.dynamics({x: v, v: (0.2 * u - v) / 0.05})
    m.output("x_lvdt", x, unit="m", noise_std=2e-4)
    rng, n, dt = np.random.default_rng(51), 4000, 0.01
    cmd, k = np.empty(n), 0
    while k < n:
        hold = max(int(rng.uniform(0.1, 0.6) / dt), 1)
        cmd[k:k + hold], k = rng.choice(np.linspace(-0.5, 0.5, 11)), k + hold
    acting = np.sign(cmd) * np.maximum(np.abs(cmd) - 0.1, 0)
    f = lambda s, a: np.array([s[1], (0.2 * a - s[1]) / 0.05])
    s, pos = np.zeros(2), np.empty(n)
    for k in range(n):
        pos[k] = s[0]
        k1 = f(s, acting[k]); k2 = f(s + dt / 2 * k1, acting[k]); k3 = f(s + dt / 2 * k2, acting[k])
        s = s + dt / 6 * (k1 + 2 * k2 + 2 * k3 + f(s + dt * k3, acting[k])) + rng.normal(0, [1e-5, 5e-4])
    frame = pd.DataFrame({"t": np.arange(n) * dt, "u": cmd, "x_lvdt": pos + rng.normal(0, 2e-4, n)})
    d = diagnose(m, frame, tmp_path, show_progress=False, figures=False, emit=False).data
    [zone] = d["findings"]
    assert zone["effect"] == "dead_zone" and abs(zone["coefficient"] - 0.1) < 3 * zone["std"] < 0.002, zone
    assert d["remaining"]["mismatch"] is False


def test_a_swap_tied_only_under_the_nominals_noise_is_no_tie(tmp_path):
    """A pendulum's quadratic drag (0.4, PRBS torque): SKI's swap to a viscous damping scored 0.1
    behind under the noise calibrated on the nominal (its process noise covering the missing drag),
    and the report said the two were 'not told apart'; each under its own noise the damping is
    600 nat behind (it needs 106× the declared process noise). The chosen's swaps are judged again
    under the noise it leaves."""
    import casadi as ca
    from skigen import Model
    from skigen.diagnose import diagnose
    rng, dt, n = np.random.default_rng(102), 0.01, 4000
    tau, k = np.zeros(n), 0
    while k < n:
        hold = max(1, int(rng.exponential(0.8) / dt))
        tau[k:k + hold], k = rng.choice([-2, -1, 0, 1, 2]), k + hold
    f = lambda x, u: np.array([x[1], -19.62 * np.sin(x[0]) - 0.3 * x[1] + 5.0 * u - 0.4 * x[1] * abs(x[1])])
    x, angle, h = np.zeros(2), np.empty(n), dt / 20
    for j in range(n):
        angle[j] = x[0]
        for _ in range(20):
            k1 = f(x, tau[j]); k2 = f(x + h / 2 * k1, tau[j]); k3 = f(x + h / 2 * k2, tau[j])
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + f(x + h * k3, tau[j]))
        x = x + rng.normal(size=2) * np.array([1e-5, 2e-3])
    frame = pd.DataFrame({"t": np.arange(n) * dt, "tau": tau, "theta_meas": angle + 0.002 * rng.normal(size=n)})
    m = Model("pendulum", dt=dt, discretization="rk4")
    th = m.state("theta", unit="rad", role="angle", std=0.05, process_std=1e-5)
    w = m.state("omega", unit="rad/s", role="rate", std=0.05, process_std=2e-3)
    u = m.input("tau", unit="N m")
    m.dynamics({th: w, w: -19.62 * ca.sin(th) - 0.3 * w + 5.0 * u})
    m.output("theta_meas", th, unit="rad", noise_std=0.002)
    d = diagnose(m, frame, tmp_path, show_progress=False, figures=False, emit=False).data
    (f,) = d["findings"]
    assert f["effect"] == "quadratic_drag" and abs(f["coefficient"] - 0.4) < 3 * f["std"], f
    assert not f.get("as_good"), f["as_good"]


def test_a_candidate_estimated_in_a_discrete_model_is_a_rate_as_when_it_is_added():
    """A discrete model's unknown term enters its next value as it is, while a found term is added
    as a rate (× dt): the coefficients SKI and the EKF estimated were per step and were then added
    per second, 20× too small at dt = 0.05 (a boat's drag 0.6 /m was named a cubic damping, a dead
    zone and an input gain; 0.599 ± 0.0008 now). Estimated at the same coefficient, both step alike."""
    import casadi as ca
    from skigen import Model
    from skigen.derive.augment import augment
    from skigen.diagnose import transform as T
    from skigen.diagnose.catalog import Additive
    from skigen.diagnose.name import Correction
    m = Model("surge", dt=0.05, discretization="discrete")
    p, v, u = m.state("p", std=0.1, process_std=1e-6), m.state("v", std=0.1, process_std=0.002), m.input("u")
    m.dynamics({p: p + 0.05 * v, v: 0.98 * v + 0.05 * u})
    m.output("p_gps", p, noise_std=0.02)
    drag = Additive("quadratic_drag", "v", "-v*abs(v)", "", sign=1)
    aug = augment(Correction().build(m, unknown=[drag], prior_variance=1.0, scales=[0.5]))
    estimated = ca.Function("f", [aug.z, aug.u], [aug.f])
    added = T.add_term(m, "v", 0.6, "-v*abs(v)")
    step = ca.Function("f", [ca.vertcat(p, v), u], [ca.vertcat(*[added.rhs[n] for n in added.state_names])])
    z, x = np.array([0.3, 1.7, 0.6 * 0.5]), np.array([0.3, 1.7])            # the weight in units of 1/scale
    assert np.allclose(np.asarray(estimated(z, 0.4)).ravel()[:2], np.asarray(step(x, 0.4)).ravel())
