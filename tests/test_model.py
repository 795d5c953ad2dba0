"""Model declaration: what it builds, and the errors that name the culprit."""
import re

import casadi as ca
import numpy as np
import pytest

from models.wingrock import build
from skigen import Model, ModelError
from skigen.derive import augment
from skigen.library import abs_products, delayed_inputs, polynomial, term


def small():
    m = Model("toy", dt=0.1)
    x = m.state("x", unit="m", role="position", std=1.0, process_std=0.01)
    v = m.state("v", unit="m/s", role="velocity", std=1.0, process_std=0.01)
    u = m.input("u", unit="N")
    m.dynamics({x: v, v: u})
    m.output("pos", x, unit="m", noise_std=0.1)
    return m, x, v, u


def test_wingrock_declaration():
    m = build()
    aug = augment(m)
    assert aug.names == ["theta", "p", "w_one", "w_theta", "w_p", "w_abs_theta_p", "w_abs_p_p", "w_theta3"]
    assert aug.shapes == dict(n=8, nx=2, nw=6, nu=1, ny=1, nmem=0)
    assert np.allclose(aug.P0, np.diag([1, 1, 1, 1, 1, 1, 1, 1]))


def test_polynomial_library_names():
    m, x, v, _ = small()
    names = [t.name for t in polynomial([x, v], 2)]
    assert names == ["1", "x", "v", "x^2", "x*v", "v^2"]
    assert [t.key for t in abs_products([(x, v)])] == ["abs_x_v"]


def test_delayed_inputs_become_memory():
    m, x, v, u = small()
    m.unknown(v, delayed_inputs(m, u, 4))
    aug = augment(m)
    assert aug.shapes["nmem"] == 3 and aug.shapes["nw"] == 4
    shift = ca.Function("shift", [aug.u, aug.mem], [aug.mem_next])
    assert np.allclose(np.array(shift(7.0, [1.0, 2.0, 3.0])).ravel(), [7.0, 1.0, 2.0])


def test_direction_term_shares_one_weight():
    m, x, v, u = small()
    m.unknown([x, v], [term("drag", ca.vertcat(0, -v))])
    m.unknown([x, v], [term("bias", 1.0)])
    assert m.weight_names == ["w_drag", "w_x_bias", "w_v_bias"]
    aug = augment(m)
    assert aug.names[2:] == ["w_drag", "w_x_bias", "w_v_bias"]
    m.unknown([v, x], [term("x", x)])              # a scalar term: its own weight in each equation, any order
    aug = augment(m)
    assert aug.names[5:] == ["w_v_x", "w_x_x"]
    rate = ca.Function("rate", [aug.z, aug.u], [ca.jacobian(aug.f[:2], aug.z)])   # ∂(x, v)[k+1]/∂z
    J = np.array(rate(np.r_[1.0, 0, 0, 0, 0, 0, 0], 0.0))      # at x = 1, v = 0, u = 0, dt = 0.1
    for k, (row, dt_share) in {3: (0, 1.0), 4: (1, 1.0), 5: (1, 1.0), 6: (0, 1.0)}.items():
        assert J[row, k] == pytest.approx(0.1 * dt_share, rel=0.01), aug.names[k]   # each in its own equation
    assert J[1, 6] == 0 and J[1, 3] == 0 and J[0, 5] > 0      # ẋ's don't reach v; v̇'s reach x through v


@pytest.mark.parametrize("mutate, message", [
    (lambda m, x, v, u: m.dynamics({"q": v}), "'q', which is not a declared state"),
    (lambda m, x, v, u: m.unknown("speed", [term("b", 1)]), "unknown term on equation 'speed'"),
    (lambda m, x, v, u: m.state("x"), "state 'x' is declared twice"),
    (lambda m, x, v, u: m.input("x"), "input 'x': the name is already a state's"),
    (lambda m, x, v, u: m.parameter("u", 1.0), "parameter 'u': the name is already an input's"),
    (lambda m, x, v, u: m.unknown(v, [term("z", x - x, key="z")]), "basis term 'z' (key 'z') on equation 'v' is "
                                                                 "identically 0"),
    (lambda m, x, v, u: m.state("x y"), "must be an identifier"),
    (lambda m, x, v, u: m.state("z", role="altitud"), "role must be one of"),
    (lambda m, x, v, u: m.output("w_meas", v), "output name 'w_meas' is reserved: it starts with 'w_', which names"),
    (lambda m, x, v, u: m.input("status"), "input name 'status' is reserved: a result column"),
    (lambda m, x, v, u: m.state("measured_y"), "state name 'measured_y' is reserved: it starts with 'measured_'"),
    (lambda m, x, v, u: m.state("double"), "state name 'double' is reserved: a C keyword"),
    (lambda m, x, v, u: m.unknown(v, [term("b", ca.vertcat(1, 2))]), "basis term 'b' has shape (2, 1)"),
    (lambda m, x, v, u: (m.unknown(v, [term("1", 1, key="one")]), m.unknown(v, [term("1", 1, key="one")])),
     "basis term '1' (key 'one') is declared twice on equation 'v'"),
    (lambda m, x, v, u: m.unknown(v, [term("x-y", x), term("x y", x ** 2)]),
     "basis terms 'x-y' and 'x y' on equation 'v' have the same key 'x_y'"),
    (lambda m, x, v, u: m.unknown(v, [term("", x, key="xx")]), "a basis term on equation 'v' (key 'xx') has an empty name"),
    (lambda m, x, v, u: m.unknown(v, [term("x cubed", x ** 3, key="x cubed")]),
     "basis term 'x cubed' has key 'x cubed'; a key must be an identifier"),
    (lambda m, x, v, u: m.unknown(v, [term("b", 1)], prior_variance=[1, 2]), "2 entries for 1 weights"),
    (lambda m, x, v, u: m.unknown(v, [term("b", 1)], prior_variance=-1), "prior_variance must be positive"),
])
def test_declaration_errors_name_the_culprit(mutate, message):
    m, x, v, u = small()
    with pytest.raises(ModelError, match=message.replace("(", r"\(").replace(")", r"\)")):
        mutate(m, x, v, u)
        m.check()


@pytest.mark.parametrize("mutate, message", [
    (lambda m, x, v, u: m.dynamics({v: u + ca.SX.sym("k")}), "dynamics of 'v' uses symbol 'k'"),
    (lambda m, x, v, u: m.unknown(v, [term("bad", ca.SX.sym("ghost"))]), "basis term 'bad' uses symbol 'ghost'"),
    (lambda m, x, v, u: m.dynamics({v: u - ca.SX.sym("x")}),       # another symbol of the state's name: CasADi said
     "dynamics of 'v' uses a symbol named 'x' that is not the model's 'x' (a second ca.SX.sym('x')"),   # 'free'
    (lambda m, x, v, u: m.output("vel2", ca.vertcat(v, v), noise_std=1), "output 'vel2' must be a scalar"),
    (lambda m, x, v, u: m.covariances(Q=np.eye(3)), "Q (process noise) has shape (3, 3); expected (2, 2)"),
    (lambda m, x, v, u: m.covariances(P0=[[1, 0.5], [0.4, 1]]), "P0 (initial covariance) is not symmetric"),
    (lambda m, x, v, u: m.covariances(P0=[[1, 2], [2, 1]]), "P0 (initial covariance) is not positive definite"),
    (lambda m, x, v, u: m.covariances(R=[[0.0]]), "R (measurement noise) is not positive definite"),
    (lambda m, x, v, u: m.covariances(Q=-np.eye(2)), "Q (process noise) is not positive semi-definite"),
    (lambda m, x, v, u: m.output("acc", v), "output 'acc' has no noise_std"),
    (lambda m, x, v, u: m.output("one", 0 * x + 1, noise_std=1), "output 'one' depends on no state or parameter "
                                                                  "(it is a constant)"),
    (lambda m, x, v, u: m.output("cmd", 2 * u, noise_std=1), "output 'cmd' depends on no state or parameter (it is a "
                                                             "function of the inputs alone)"),
    (lambda m, x, v, u: m.x_std.__setitem__(0, 0.0), "state(s) 'x' declare std=0 (an initial value known exactly)"),
])
def test_check_errors_name_the_culprit(mutate, message):
    m, x, v, u = small()
    mutate(m, x, v, u)
    with pytest.raises(ModelError, match=message.replace("(", r"\(").replace(")", r"\)")):
        m.check()


def test_missing_dynamics_named():
    m = Model("toy", dt=0.1)
    m.state("x")
    m.state("v")
    m.dynamics({"x": 0})
    m.output("y", 0, noise_std=1)
    with pytest.raises(ModelError, match="no dynamics for state\\(s\\) v"):
        m.check()


def test_bad_sample_time_and_discretization():
    with pytest.raises(ModelError, match="dt must be positive"):
        Model("toy", dt=0)
    with pytest.raises(ModelError, match="discretization must be one of"):
        Model("toy", dt=0.1, discretization="rk45")


def test_euler_and_discrete_match_by_hand():
    for method in ("euler", "discrete"):
        m = Model("toy", dt=0.1, discretization=method)
        x = m.state("x", std=1)
        u = m.input("u")
        m.dynamics({x: -2 * x + u})
        m.output("y", x, noise_std=1)
        aug = augment(m)
        f = ca.Function("f", [aug.z, aug.u], [aug.f])
        expected = 1.0 + 0.1 * (-2 + 3) if method == "euler" else -2 + 3
        assert float(f(1.0, 3.0)) == pytest.approx(expected, rel=1e-15)


@pytest.mark.parametrize("name, why", [("my__ship", "it has two underscores in a row"),
                                       ("_ship", "it does not start with a letter"),
                                       ("ship_", "it ends with '_'")])
def test_a_model_name_casadi_cannot_use_is_refused_at_declaration(name, why):
    """CasADi's Function names start with a letter and have no two underscores in a row; the
    model name prefixes them (`<model>_<filter>_step`), so it is refused where it is given."""
    with pytest.raises(ModelError, match=f"model name '{name}' cannot name CasADi Functions: {why}"):
        Model(name, dt=0.1)
    Model("my_ship2", dt=0.1)


@pytest.mark.parametrize("body, line, said", [
    ("x = m.state('x')\nv = m.state('v')\nm.dynamics({x: v})\nm.output('y', x, noise_std=0.1)\n", 6,
     "no dynamics for state(s) v"),
    ("x = m.state('x')\nc = ca.SX.sym('c')\nm.dynamics({x: -c * x})\nm.output('y', x, noise_std=0.1)\n", 7,
     "dynamics of 'x' uses symbol 'c'"),
    ("x = m.state('x', initial=0.0)\nm.dynamics({x: -x})\nm.output('y', x, noise_std=0.1)\n"
     "m.unknown(x, [term('inv', 1 / x)])\n", 8, "term 'inv' of the unknown on 'x' is inf"),
])
def test_a_model_file_the_check_refuses_names_the_line(tmp_path, body, line, said):
    """Errors found when the loaded model is checked (no dynamics for a state, an undeclared
    symbol, a term not finite at the start) named the symbol but not the line; they name the line
    that declared it, as errors raised while the file runs do."""
    from skigen.modelfile import load_model
    path = tmp_path / "bad.py"
    path.write_text("import casadi as ca\nfrom skigen import Model\nfrom skigen.library import term\n"
                    "m = Model('bad', dt=0.1)\n".replace("m = Model", "model = m = Model") + body)
    with pytest.raises(ModelError, match=rf"model file '.*bad.py', line {line}: {re.escape(said)}"):
        load_model(str(path))


@pytest.mark.parametrize("method", ["euler", "rk4"])
def test_the_step_note_offers_what_makes_the_step_finer(method):
    """A roll model already on RK4 was told 'use discretization="rk4" or substeps=8'; the note
    offers RK4 only to a model not on it, and substeps where they are enough."""
    m = Model("fast", dt=0.01, discretization=method)
    x = m.state("x", std=1.0)
    m.dynamics({x: -200.0 * x})
    m.output("y", x, noise_std=0.1)
    note = m.step_note([np.array([[-200.0]])], "here")
    assert note is not None and ('discretization="rk4" or substeps=' in note) == (method == "euler"), note
    assert re.search(r"; use (discretization=\"rk4\" or )?substeps=\d+$", note), note
    assert m.step_note([np.array([[-1e9]])], "here").endswith(
        "use a shorter dt" if method == "rk4" else 'use discretization="rk4"')


def test_a_free_integrator_draws_no_step_note():
    """A motor driving a load through a shaft: the drive's free rotation is a mode at 0, computed
    as −7.7e-15 /s, and every fit of the right model was told the RK4 step of 5 ms moved it to 0
    and to 'use a shorter dt'. A mode that moves less than STILL of itself per step is left out."""
    Jm, Jl, k, c, b = 0.01, 0.05, 5.0, 0.02, 0.1
    A = np.array([[0, 1, 0, 0], [-k / Jm, -(b + c) / Jm, k / Jm, c / Jm], [0, 0, 0, 1],
                  [k / Jl, c / Jl, -k / Jl, -c / Jl]])
    m = Model("flex", dt=0.005, discretization="rk4")
    x = m.state("x", std=1.0)
    m.dynamics({x: -x})
    m.output("y", x, noise_std=0.1)
    assert m.step_note([A], "here") is None
    assert Model("flex", dt=0.05, discretization="euler").step_note([A], "here") is not None   # its 23.6 rad/s mode
