"""A number of the model off: one literal constant, wherever it is written, scaled by one factor.

The catalog's terms act on one equation each; a constant written in several (what drains the
upper tank fills the lower one; a damper acts on two masses and an accelerometer reads it) is one
number. Before, a tank's orifice 20 % larger than declared was named an input gain on h1, tied with
a bias; a quarter-car's damper (1600 for a declared 1200) an accelerometer gain, a mismatch left.
"""
import json

import casadi as ca
import numpy as np
import pandas as pd
import pytest

from models import two_tanks as tanks
from skigen import Model
from skigen.diagnose import diagnose
from skigen.diagnose import catalog as C
from skigen.diagnose import transform as T


def quarter_car() -> Model:
    m = Model("quarter_car", dt=0.001)
    zs, vs, zu, vu = (m.state(n) for n in ("zs", "vs", "zu", "vu"))
    fa = m.input("Fa")
    body = (-20000 * (zs - zu) - 1200 * (vs - vu) + fa) / 300
    m.dynamics({zs: vs, vs: body, zu: vu, vu: (20000 * (zs - zu) + 1200 * (vs - vu) - 150000 * zu - fa) / 40})
    m.output("acc_body", body, noise_std=0.1)
    m.output("defl", zs - zu + 0.5 * zs ** 2.5, noise_std=1e-3)
    return m


def test_a_constant_is_scaled_wherever_it_is_written_beside_the_same_thing():
    """literals: the numbers as written, each with what it stands beside (not 0 or 1 — CasADi
    keeps −20000 as one number — nor a power's exponent); scale_constant: the damper's
    1200·(vs − vu) in both equations and the accelerometer's formula, by a number or a symbol,
    nothing else touched; the candidates: each number beside the same thing in two places or more
    (the spring and the damper apart; the unsprung mass 40 and the tyre's 150000, written once,
    are a catalog term's)."""
    m = quarter_car()
    assert T.literals(m.rhs["vs"])[:2] == [(-20000.0, "*((zs-zu))"), (1200.0, "*((vs-vu))")]
    assert T.literals(m.outputs[1].sym) == [(0.5, "*(pow(zs,2.5))")]           # 2.5 is an exponent
    scaled = T.scale_constant(m, 1200, 4 / 3, "*((vs-vu))")
    x = ca.vertcat(*T.symbols(m).values())
    point = [0.01, 0.3, -0.02, -0.4, 50.0]
    rates = lambda model: ca.Function("f", [x], [ca.vertcat(*model.rhs.values(), *[v.sym for v in model.outputs])])(point)
    change = np.array(rates(scaled) - rates(m)).ravel()
    dv = 0.3 - (-0.4)                                                  # vs − vu
    np.testing.assert_allclose(change, [0, -400 * dv / 300, 0, 400 * dv / 40, -400 * dv / 300, 0], rtol=1e-12)
    assert not np.any(np.array(rates(T.scale_constant(m, 1200, 2, "*((zs-zu))")) - rates(m)))
    f = ca.SX.sym("f")
    assert ca.depends_on(T.scale_constant(m, 1200, f).outputs[0].sym, f)
    assert not ca.depends_on(T.scale_constant(m, 2.5, f).outputs[1].sym, f)
    cands = {c.target: c.equations for c in C.constant_candidates(m, ["vs", "vu"], ["acc_body"])}
    assert cands == {"1200·(vs-vu)": ("vs", "vu", "output acc_body"), "20000·(zs-zu)": ("vs", "vu", "output acc_body"),
                     "(…)/300": ("vs", "output acc_body")}


def test_a_two_written_in_two_equations_is_a_constant():
    """CasADi keeps 2·x as an operation of its own (OP_TWICE), not a number: a two-node thermal
    model's conductance G = 2 in G·(T1 − T2), 1.3× off, was no candidate, and was named a sensor
    gain of 0.77 with a bias and an input gain (G = 2.5 or 3 were named: × 1.3001). Now the 2 is a
    number as written, a candidate on both equations, and scaled where it stands."""
    m = Model("two_node", dt=2.0)
    T1, T2 = m.state("T1", initial=20.0), m.state("T2", initial=20.0)
    P = m.input("P")
    m.dynamics({T1: (P - 2.0 * (T1 - T2) - 0.5 * (T1 - 20)) / 200, T2: (2.0 * (T1 - T2) - (T2 - 20)) / 400})
    m.output("T1_meas", T1, noise_std=0.05)
    assert (2.0, "*((T1-T2))") in T.literals(m.rhs["T1"])
    cands = {c.target: c.equations for c in C.constant_candidates(m, ["T1", "T2"], [])}
    assert cands.get("2·(T1-T2)") == ("T1", "T2"), cands
    scaled = T.scale_constant(m, 2.0, 1.3, "*((T1-T2))")
    x = ca.vertcat(T1, T2, P)
    rates = lambda model: np.array(ca.Function("f", [x], [ca.vertcat(*model.rhs.values())])([30.0, 25.0, 10.0])).ravel()
    np.testing.assert_allclose(rates(scaled) - rates(m), [-0.6 * 5 / 200, 0.6 * 5 / 400], rtol=1e-12)


def test_an_orifice_off_in_both_levels_is_named_as_its_constant(tmp_path):
    """Two tanks whose upper orifice drains 1.2× what the model declares (400 s, 4000 samples):
    the constant a₁·√(2g), in h1 and h2, is named with its factor (measured 1.2005 ± 0.0057) and
    nothing remains."""
    run = tanks.simulate(tanks.pump_steps(400.0, seed=1), effect="orifice", seed=1)
    frame = pd.DataFrame({"t": run.t, "u": run.u, "h1_meas": run.h1_meas, "h2_meas": run.h2_meas})
    diagnose("models/two_tanks.py", frame, tmp_path, figures=False, emit=False, show_progress=False)
    d = json.loads((tmp_path / "report.json").read_text())
    (f,) = d["findings"]
    assert f["effect"] == "constant" and f["written_in"] == ["h1", "h2"] and f["equation"] == "h1+h2"
    assert f["input"] == "0.000221472·sqrt(h1)"                       # a₁·√(2g), as Python folded it
    assert abs(f["coefficient"] - 1.2) < min(4 * f["std"], 0.03 * 1.2), f
    assert not d["remaining"]["mismatch"]


def test_the_corrected_model_carries_a_constant_beside_a_term_through_an_input():
    """A constant found off and a term added to the input written beside it (a vehicle's 80000 on
    (δ − …) and a damping through δ): the corrected model's constant is a parameter its
    expressions use. (Applied after the input was rewritten, the constant no longer stood beside
    what it was found beside, and the file declared a parameter nothing used: a user's refit
    then failed, 'no effect on the likelihood'.)"""
    from skigen.diagnose.catalog import Additive
    from skigen.diagnose.correct import parametrised
    from skigen.diagnose.name import Correction
    m = quarter_car()
    (damper,) = [c for c in C.constant_candidates(m, ["vs", "vu"], ["acc_body"]) if c.target == "1200·(vs-vu)"]
    through = Additive("viscous_damping", "vs", "-vs", "damping", through="Fa")
    fitted, names, _ = parametrised(m, Correction([(through, 5.0, 0.1)], [(damper, 1.3, 0.01)]))
    assert set(names) == {"viscous_damping_vs_Fa", "constant_1200_vs_vu"}
    p = next(q.sym for q in fitted.parameters if q.name == "constant_1200_vs_vu")
    assert all(ca.depends_on(fitted.rhs[e], p) for e in ("vs", "vu")) and ca.depends_on(fitted.outputs[0].sym, p)


def test_an_accelerometer_whose_formula_repeats_the_dynamics_reads_what_is_found_there(tmp_path):
    """A mass on a spring and damper riding a shaker, its accelerometer's formula written as the
    rate's (a user's model): a Coulomb friction found on the rate is read by that sensor as well
    (catalog.rate_readers). Before, the sensor's formula did not follow, and its 8·zd was named
    off by 1.78 with a negative damping beside the friction. Named: the friction alone."""
    from skigen import Model
    rng = np.random.default_rng(7)
    dt, n = 0.002, 5000
    t = np.arange(n) * dt
    s = sum(np.sin(2 * np.pi * f * t + p) for f, p in zip((1.1, 1.9, 2.7, 3.3, 4.1, 5.3, 7.7, 9.1, 12.3, 14.9),
                                                           rng.uniform(0, 2 * np.pi, 10)))
    ab = 6.0 * s / np.max(np.abs(s))
    acc = lambda x: (-800 * x[0] - 8 * x[1] - 1.0 * np.tanh(x[1] / 0.001)) / 2
    x, X, h = np.zeros(2), np.zeros((n, 2)), dt / 20
    for k in range(n):
        X[k] = x
        f = lambda x: np.array([x[1], acc(x) - ab[k]])
        for _ in range(20):
            k1 = f(x); k2 = f(x + h / 2 * k1); k3 = f(x + h / 2 * k2); k4 = f(x + h * k3)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x = x + rng.normal(0, [1e-7, 1e-4])
    frame = pd.DataFrame({"t": t, "ab": ab, "z_lvdt": X[:, 0] + rng.normal(0, 1e-4, n),
                          "a_acc": np.array([acc(r) for r in X]) + rng.normal(0, 0.05, n)})
    m = Model("base", dt=dt, discretization="rk4")
    z = m.state("z", unit="m", role="position", std=1e-3, process_std=1e-7)
    zd = m.state("zd", unit="m/s", role="velocity", std=1e-2, process_std=1e-4)
    a = m.input("ab", unit="m/s^2")
    m.dynamics({z: zd, zd: (-800 * z - 8 * zd) / 2 - a})
    m.output("z_lvdt", z, unit="m", noise_std=1e-4)
    m.output("a_acc", (-800 * z - 8 * zd) / 2, unit="m/s^2", noise_std=0.05)
    assert C.rate_readers(m) == {"zd": [("a_acc", 1.0)]}
    d = diagnose(m, frame, tmp_path, figures=False, emit=False, show_progress=False).data
    (f,) = d["findings"]
    assert (f["effect"], f["equation"]) == ("coulomb_friction", "zd") and abs(f["coefficient"] - 0.5) < 0.03, f


def test_a_number_written_once_in_an_output_formula_is_a_candidate(tmp_path):
    """A Li-ion cell (1-RC circuit) whose series resistance is 1.5× the 0.05 Ω written in its
    voltage, 3.5 + 0.7·soc − 0.05·I − v1, under current pulses: no catalog term stands in for a
    number of an output's formula, and the cell was named a voltage sensor of gain 1.5 (its state
    of charge driven to −0.63 to make up the rest; the free run worse). Now the constant, measured
    1.4995 ± 0.0005 (free run 0.097 → 0.002 V on the user's recording); the 3.5 added stays a sensor
    offset's."""
    rng = np.random.default_rng(21)
    n = 3000
    I = 1.0 + np.repeat(rng.choice([-1.0, -0.3, 0.3, 1.0], n // 50 + 1) * 3, 50)[:n]
    x, X = np.array([0.9, 0.0]), []
    f = lambda x, i: np.array([-i / 7200.0, -x[1] / 40.0 + i / 2000.0])
    for i in I:
        X.append(x)
        k1 = f(x, i); k2 = f(x + k1 / 2, i); k3 = f(x + k2 / 2, i); k4 = f(x + k3, i)
        x = x + (k1 + 2 * k2 + 2 * k3 + k4) / 6 + rng.normal(0, [1e-6, 1e-4])
    X = np.array(X)
    volts = 3.5 + 0.7 * X[:, 0] - 0.075 * I - X[:, 1] + rng.normal(0, 0.002, n)
    m = Model("cell", dt=1.0, discretization="rk4")
    soc = m.state("soc", unit="1", initial=0.9, std=0.01, process_std=1e-6)
    v1 = m.state("v1", unit="V", std=0.005, process_std=1e-4)
    cur = m.input("I", unit="A")
    m.dynamics({soc: -cur / 7200.0, v1: -v1 / 40.0 + cur / 2000.0})
    m.output("V_term", 3.5 + 0.7 * soc - 0.05 * cur - v1, unit="V", noise_std=0.002)
    assert {c.target for c in C.constant_candidates(m, [], ["V_term"])} == {"0.7·soc", "0.05·I"}
    frame = pd.DataFrame({"t": np.arange(n) * 1.0, "I": I, "V_term": volts})
    rep = diagnose(m, frame, tmp_path, figures=False, emit=False, show_progress=False)
    (top,) = rep.findings
    assert (top["effect"], top["input"]) == ("constant", "0.05·I"), rep.findings
    assert abs(top["coefficient"] - 1.5) < 4 * top["std"] < 0.01, top
    assert not rep.data["remaining"]["mismatch"]


def test_a_number_written_once_on_a_shape_of_the_states_is_a_candidate(tmp_path):
    """A pendulum whose g/L, written once as 19.62·sin θ, is 1.163× off (L 0.43 m for 0.5), under
    a chirp: a number written once in an equation was left to the catalog's terms, and the
    linear stiffness −3.03·θ was named, "consistent", 5σ from what sin θ gives it. A number that
    multiplies a shape of the states no catalog term draws is now a candidate: measured
    1.1632 ± 0.0017."""
    rng = np.random.default_rng(600)
    n, dt = 3000, 0.01
    t = np.arange(n) * dt
    u = 0.5 * np.sin(2 * np.pi * (0.1 * t + 1.4 * t ** 2 / (2 * t[-1])))
    f = lambda x, uk: np.array([x[1], -19.62 * 0.5 / 0.43 * np.sin(x[0]) - 0.3 * x[1] + 5 * uk])
    x, X = np.zeros(2), []
    for uk in u:
        X.append(x)
        k1 = f(x, uk); k2 = f(x + dt / 2 * k1, uk); k3 = f(x + dt / 2 * k2, uk); k4 = f(x + dt * k3, uk)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4) + [0, 0.005 * rng.standard_normal()]
    X = np.array(X) + rng.normal(0, [0.002, 0.01], (n, 2))
    m = Model("pendulum", dt=dt, discretization="rk4")
    th = m.state("th", unit="rad", role="angle", std=0.02)
    w = m.state("w", unit="rad/s", role="rate", std=0.05, process_std=0.005)
    torque = m.input("u", unit="N*m")
    m.dynamics({th: w, w: -19.62 * ca.sin(th) - 0.3 * w + 5.0 * torque})
    m.output("th_enc", th, unit="rad", noise_std=0.002)
    m.output("gyro_w", w, unit="rad/s", noise_std=0.01)
    assert [c.target for c in C.constant_candidates(m, ["w"], [])] == ["19.62·sin(th)"]   # not 0.3·w, 5·u
    frame = pd.DataFrame({"t": t, "u": u, "th_enc": X[:, 0], "gyro_w": X[:, 1]})
    rep = diagnose(m, frame, tmp_path, figures=False, emit=False, show_progress=False)
    top = rep.findings[0]
    assert (top["effect"], top["input"]) == ("constant", "19.62·sin(th)"), rep.findings
    assert abs(top["coefficient"] - 0.5 / 0.43) < 4 * top["std"] < 0.01, top
    assert not rep.data["remaining"]["mismatch"]


def _motor_frame(ke: float, kt: float, seed: int = 21):
    """A DC motor (R 2 Ω, L 0.1 H, J 0.01, Kt = Ke = 0.1 declared) under a voltage PRBS, 25 s at
    100 Hz, its current and speed measured; the plant's back-EMF constant ``ke`` and torque
    constant ``kt``. Returns the model and the recording."""
    m = Model("dcmotor", dt=0.01, discretization="rk4")
    i = m.state("i", unit="A", std=0.1, process_std=1e-3)
    w = m.state("w", unit="rad/s", std=0.5, process_std=1e-2)
    v = m.input("V", unit="V")
    m.dynamics({i: (v - 2.0 * i - 0.1 * w) / 0.1, w: 0.1 * i / 0.01})
    m.output("i_meas", i, unit="A", noise_std=0.05)
    m.output("omega_meas", w, unit="rad/s", noise_std=0.5)
    rng = np.random.default_rng(seed)
    n, dt, volts, k = 2500, 0.01, np.empty(2500), 0
    while k < n:
        hold = int(rng.uniform(0.4, 1.5) / dt)
        volts[k:k + hold], k = rng.choice([-12, -6, 0, 4, 8, 12]), k + hold
    f = lambda x, u: np.array([(u - 2 * x[0] - ke * x[1]) / 0.1, (kt * x[0]) / 0.01])
    x, X, h = np.zeros(2), np.empty((n, 2)), dt / 10
    for k in range(n):
        X[k] = x
        for _ in range(10):
            k1 = f(x, volts[k]); k2 = f(x + h / 2 * k1, volts[k]); k3 = f(x + h / 2 * k2, volts[k])
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + f(x + h * k3, volts[k]))
        x = x + rng.normal(0, [1e-3, 1e-2])
    return m, pd.DataFrame({"t": np.arange(n) * dt, "V": volts, "i_meas": X[:, 0] + rng.normal(0, 0.05, n),
                            "omega_meas": X[:, 1] + rng.normal(0, 0.5, n)})


def test_one_use_of_a_number_written_twice_is_a_candidate_on_a_bare_state(tmp_path):
    """A motor declared with L = Ke = 0.1, (V − 2i − 0.1ω)/0.1: CasADi keeps one node for both
    numbers, so the back-EMF constant could only be scaled with the inductance, and a number on a
    bare state was taken as a catalog term's (none draws ω in di/dt): a back-EMF 1.2× off was
    named a speed sensor gain of 0.83 with a Coulomb friction. Each use of a number is now its
    own, and one on another state than the equation's own (or a position it pairs with) a
    candidate; the torque constant on i in dω/dt too."""
    m, _ = _motor_frame(0.1, 0.1)
    assert T.literals(m.rhs["i"]) == [(2.0, "*(i)"), (0.1, "*(w)"), (0.1, "4.1(((V-(2.*i))-(0.1*w)))")]
    assert sorted(c.target for c in C.constant_candidates(m, ["i", "w"], [])) == ["0.1·i", "0.1·w"]
    scaled = T.scale_constant(m, 0.1, 1.2, "*(w)")
    assert str(scaled.rhs["i"]) == "(((V-(2.*i))-(0.12*w))/0.1)"


@pytest.mark.parametrize("ke, kt, target", [(0.12, 0.1, "0.1·w"), (0.1, 0.085, "0.1·i")])
def test_a_motor_constant_off_is_named_not_a_sensor_gain(tmp_path, ke, kt, target):
    """The motor's back-EMF constant 1.2× off (0.12), or its torque constant 0.85× (0.085): the
    number is named with its factor and nothing else (measured: 1.2007 ± 0.0009, 0.8511 ± 0.0008;
    before, an input gain and a negative damping on i, and nothing, each with a mismatch left)."""
    m, frame = _motor_frame(ke, kt)
    rep = diagnose(m, frame, tmp_path, figures=False, emit=False, show_progress=False)
    (top,) = rep.findings
    assert (top["effect"], top["input"]) == ("constant", target), rep.findings
    truth = ke / 0.1 if target == "0.1·w" else kt / 0.1
    assert abs(top["coefficient"] - truth) < 3 * top["std"] < 0.01, top
    assert not rep.data["remaining"]["mismatch"]
