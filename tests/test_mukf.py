"""Marginalised UKF: partition detection, equality with the NumPy reference MUKF, the
Kalman filter on a linear-Gaussian model, SKI on the MUKF core, and the C backend."""
import casadi as ca
import numpy as np
import pytest

from models import quadrotor_mukf as quad
from models import wingrock
from skigen import FilterOptions, Model, ModelError, derive
from skigen.derive import augment, partition
from skigen.library import term
from skigen.recording import Recording
from skigen.reference import ard as ref_ard
from skigen.reference import mukf as ref
from skigen.reference.filters import chol
from skigen.runtime import run

RTOL = 1e-9
OPTIONS = [FilterOptions(), FilterOptions(alpha=0.5, kappa=0.0, ard="gradient", ard_steps=3, eta=0.5)]
IDS = ["alpha1_em", "alpha0.5_gradient"]          # alpha 0.5: negative Wm0 and Wc0 (downdates)
OUT = ("z_post", "C_post", "z_next", "C_next", "e", "Pyy", "nis", "loglik")
REF = dict(z_post="z_post", C_post="S_post", z_next="z", C_next="S", e="e", Pyy="Pyy", nis="nis", loglik="loglik")


def _close(a, b, rtol=RTOL):
    a, b = np.asarray(a, float), np.asarray(b, float).reshape(np.shape(a))
    np.testing.assert_allclose(a, b, rtol=0, atol=rtol * max(np.abs(b).max(initial=0), 1.0))


def _cas_step(d, st, u, y, valid):
    args = dict(z=st["z"], C=st["C"], u=u, mem=st["mem"], y=np.where(valid, y, 0.0), valid=valid.astype(float))
    if d.has_ard:
        args["s"] = st["s"]
    return {k: np.array(v) for k, v in d.step(**args).items()}


def _valid(k, ny):
    v = np.ones(ny, bool)
    if k % 7 == 3:
        v[::2] = False              # some outputs missing
    if k % 23 == 11:
        v[:] = False                # nothing measured
    return v


def _compare_run(d, ref_step, inputs, outputs, check=OUT):
    """Both paths side by side over the run, each fed its own previous output."""
    ours, theirs = d.initial(), d.initial()
    theirs = dict(z=theirs["z"], S=theirs["C"], s=theirs.get("s"))
    for k, (u, y) in enumerate(zip(inputs, outputs)):
        valid = _valid(k, len(y))
        r = _cas_step(d, ours, u, y, valid)
        q = ref_step(theirs, u, y, valid)
        for name in check:
            _close(r[name], q[REF[name]])
        if d.has_ard:
            _close(r["s_next"], q["s"])
        ours = dict(z=r["z_next"].ravel(), C=r["C_next"], mem=ours["mem"],
                    **({"s": r["s_next"].ravel()} if d.has_ard else {}))
        theirs = dict(z=q["z"], S=q["S"], s=q.get("s"))
    assert np.all(np.isfinite(ours["z"]))
    return ours


# ------------------------------------------------------------------ partition

def test_partition_of_the_tutorial_quadrotor():
    part = partition(augment(quad.build("euler")))
    assert part.nonlinear_names == ["v_x", "v_y", "v_z"]
    assert part.linear_names == ["x", "y", "z", "theta", "phi"]
    assert part.sigma_points == 7
    assert partition(augment(quad.build("exact_position"))).linear_names == ["x", "y", "z", "theta", "phi"]


def test_a_run_summary_says_what_the_mukf_marginalises():
    """The summary of an MUKF run opens with its split: the sigma-point states and the exact ones."""
    from skigen.runtime import RunSummary
    lines = RunSummary(derive(quad.build("euler"), "mukf")).lines()
    assert lines[:2] == ["mukf: z_n (sigma points, 7): v_x, v_y, v_z",
                         "mukf: z_l (exact, conditionally linear): x, y, z, theta, phi"]


def test_rk4_breaks_conditional_linearity():
    part = partition(augment(quad.build("rk4")))
    assert part.linear_names == ["x", "y", "z"]
    assert {"theta", "phi"} <= set(part.nonlinear_names)
    assert "theta" in part.reasons[part.names.index("theta")]
    assert "not affine" in part.describe()


def _pendulum():
    m = Model("pendulum", dt=0.01, discretization="euler")
    a = m.state("a", role="angle", std=0.1)
    b = m.state("b", role="rate", std=0.1)
    m.dynamics({a: b, b: -ca.sin(a) - 0.1 * b * ca.fabs(b)})
    m.output("a_m", a, noise_std=0.01)
    return m


def test_no_linear_part_is_a_clear_error():
    with pytest.raises(ModelError, match=r"no conditionally linear substate.*a: .*depends on a.*b: .*depends on b"):
        derive(_pendulum(), "mukf")


def test_cross_terms_count():
    """f = a·b is affine in a and in b, not in both: exactly one of them is linear."""
    m = Model("bilinear", dt=0.1, discretization="discrete")
    a, b = m.state("a"), m.state("b")
    m.dynamics({a: a * b, b: b})
    m.output("a_m", a, noise_std=0.1)
    assert len(partition(augment(m)).linear) == 1
    assert partition(augment(m), ["a"]).linear_names == ["a"]
    with pytest.raises(ModelError, match="'a' and 'b' cannot both"):
        partition(augment(m), ["a", "b"])


def test_user_override():
    model = quad.build("euler")
    d = derive(model, "mukf", linear=["theta", "phi"])
    assert d.partition.linear_names == ["theta", "phi"] and d.partition.sigma_points == 13
    with pytest.raises(ModelError, match="'v_x' cannot be in the linear substate: .*depends on v_x"):
        derive(model, "mukf", linear=["x", "v_x"])
    with pytest.raises(ModelError, match=r"linear=\[\] leaves the MUKF nothing to marginalise"):
        derive(model, "mukf", linear=[])
    with pytest.raises(ModelError, match="not states or weights"):
        derive(model, "mukf", linear=["mass"])
    with pytest.raises(ValueError, match="has none"):
        derive(model, "ukf", linear=["x"])
    # the overridden filter equals the reference with that split
    sim = quad.simulate(seed=2, duration=1.0)
    _compare_run(d, _quad_ref(d, [0, 1, 2, 3, 4, 5], [6, 7]), sim.F, sim.y)


# ------------------------------------------------------------------ MUKF vs reference

def _quad_affine(F):
    """The tutorial's Euler quadrotor written as d(v) + A(v) z_l, c(v) + C(v) z_l (z_l = [p, θ, φ])."""
    dt, g = quad.DT, quad.G

    def d(v):
        return np.concatenate([v - dt * g * np.array([0, 0, 1.0]), dt * v, [0.0, 0.0]])

    def A(v):
        M = np.zeros((8, 5))
        M[:3, 3], M[:3, 4] = dt * F, -dt * v * np.abs(v)
        M[3:] = np.eye(5)
        return M
    return d, A, (lambda v: np.r_[0, 0, 0, v]), (lambda v: np.vstack([np.eye(3, 5), np.zeros((3, 5))]))


def _quad_ref(d, nl, ll):
    """Reference step on the quadrotor for the split (nl, ll), via f/h closures."""
    aug, o = d.aug, d.options

    def step(st, F, y, valid):
        dd, A, c, C = _quad_affine(F)
        f = lambda z: dd(z[:3]) + A(z[:3]) @ z[3:]
        h = lambda z: c(z[:3]) + C(z[:3]) @ z[3:]
        fns = ref.affine_from_closures(f, h, nl, ll, 8)
        return ref.mukf_step(st["z"], st["S"], y, valid, nl, ll, *fns, aug.Q, aug.R, o.alpha, o.beta, o.kappa)
    return step


@pytest.mark.parametrize("opts", OPTIONS, ids=IDS)
def test_quadrotor_whole_run_matches_reference(opts):
    d = derive(quad.build("euler"), "mukf", opts)
    aug = d.aug
    sim = quad.simulate(seed=1, duration=6.0)

    def step(st, F, y, valid):
        return ref.mukf_step(st["z"], st["S"], y, valid, [0, 1, 2], [3, 4, 5, 6, 7], *_quad_affine(F),
                             aug.Q, aug.R, opts.alpha, opts.beta, opts.kappa)
    _compare_run(d, step, sim.F, sim.y)


def _general_model():
    """Nonlinear output with a z_n-dependent C, linear state declared first (z_n not leading)."""
    m = Model("cl_general", dt=0.05, discretization="euler")
    c = m.state("c", std=0.5, process_std=0.01)
    a = m.state("a", role="angle", initial=0.3, std=0.3, process_std=0.01)
    b = m.state("b", std=0.5, process_std=0.02)
    u = m.input("u")
    m.dynamics({c: a + 0.5 * c, a: b, b: -ca.sin(a) - 0.1 * b * ca.fabs(b) + u})
    m.output("y1", ca.sin(a) + c * ca.cos(a), noise_std=0.05)
    m.output("y2", b, noise_std=0.05)
    m.unknown(b, [term("u", u), term("b|b|", b * ca.fabs(b), key="bb")], prior_variance=0.5,
              process_std=1e-3)
    return m


def _general_fh(u, dt=0.05):
    def f(z):
        c, a, b, w1, w2 = z
        return np.array([c + dt * (a + 0.5 * c), a + dt * b,
                         b + dt * (-np.sin(a) - 0.1 * b * abs(b) + u + w1 * u + w2 * b * abs(b)), w1, w2])
    h = lambda z: np.array([np.sin(z[1]) + z[0] * np.cos(z[1]), z[2]])
    return f, h


@pytest.mark.parametrize("opts", OPTIONS, ids=IDS)
def test_general_model_matches_reference(opts):
    d = derive(_general_model(), "mukf", opts)
    assert d.partition.nonlinear_names == ["a", "b"]
    assert d.partition.linear_names == ["c", "w_u", "w_bb"]
    aug, nl, ll = d.aug, [1, 2], [0, 3, 4]
    rng = np.random.default_rng(3)
    us = np.sin(np.arange(200) * 0.1) + 0.3 * rng.standard_normal(200)
    x, ys = np.array([0.0, 0.3, 0.0, 0.4, -0.2]), []
    for u in us:
        ys.append(_general_fh(u)[1](x) + 0.05 * rng.standard_normal(2))
        x = _general_fh(u)[0](x)

    def step(st, u, y, valid):
        fns = ref.affine_from_closures(*_general_fh(u[0]), nl, ll, 5)
        return ref.mukf_step(st["z"], st["S"], y, valid, nl, ll, *fns, aug.Q, aug.R, opts.alpha, opts.beta, opts.kappa)
    _compare_run(d, step, us[:, None], np.array(ys))


# ------------------------------------------------------------------ linear-Gaussian: exactly the KF

def _linear_model():
    m = Model("linear", dt=0.1, discretization="euler")
    pos = m.state("pos", std=1.0, process_std=0.01)
    vel = m.state("vel", std=1.0, process_std=0.05)
    u = m.input("u")
    m.dynamics({pos: vel, vel: -0.5 * pos - 0.2 * vel + u})
    m.output("pos_m", pos, noise_std=0.1)
    m.output("mix_m", vel + 0.3 * pos, noise_std=0.2)
    m.unknown(vel, [term("u", u)], prior_variance=1.0, process_std=1e-3)   # affine in the weight given u
    return m


def _kalman(z, P, u, y, valid, Q, R, dt=0.1):
    H = np.array([[1.0, 0, 0], [0.3, 1, 0]])
    v = np.flatnonzero(valid)
    if len(v):
        Hv, Rv = H[v], R[np.ix_(v, v)]
        Syy = Hv @ P @ Hv.T + Rv
        K = np.linalg.solve(Syy, Hv @ P).T
        z, P = z + K @ (y[v] - Hv @ z), P - K @ Syy @ K.T
    F = np.eye(3) + dt * np.array([[0, 1, 0], [-0.5, -0.2, u], [0, 0, 0]])
    Bu = dt * np.array([0, u, 0])
    return z, P, F @ z + Bu, F @ P @ F.T + Q


@pytest.mark.parametrize("linear", [None, ["vel", "w_u"]], ids=["auto", "sigma_points_over_pos"])
def test_linear_gaussian_model_is_the_kalman_filter(linear):
    d = derive(_linear_model(), "mukf", linear=linear)
    assert len(d.partition.nonlinear) == (0 if linear is None else 1)
    rng = np.random.default_rng(4)
    st = d.initial()
    z, P = d.aug.z0, d.aug.P0
    for k in range(150):
        u, y, valid = np.sin(0.2 * k), rng.standard_normal(2), _valid(k, 2)
        r = _cas_step(d, st, [u], y, valid)
        z_post, P_post, z, P = _kalman(z, P, u, y, valid, d.aug.Q, d.aug.R)
        _close(r["z_post"], z_post)
        _close(r["C_post"] @ r["C_post"].T, P_post)
        _close(r["z_next"], z)
        _close(r["C_next"] @ r["C_next"].T, P)
        st = dict(z=r["z_next"].ravel(), C=r["C_next"], mem=st["mem"])


# ------------------------------------------------------------------ SKI on the MUKF core

def _wingrock_euler(prior_variance=0.5):
    m = wingrock.build(prior_variance=prior_variance, name="wingrock_euler")
    m.discretization = "euler"
    return m


def _wingrock_affine(delta, dt=wingrock.DT):
    """Euler WingRock: z_n = [θ, p], z_l = w; f = d + A w, h = θ."""
    def basis(x):
        th, p = x
        return np.array([1.0, th, p, abs(th) * p, abs(p) * p, th ** 3])

    d = lambda x: np.r_[x[0] + dt * x[1], x[1] + dt * wingrock.GAIN * delta, np.zeros(6)]
    A = lambda x: np.vstack([np.zeros(6), dt * basis(x), np.eye(6)])
    return d, A, (lambda x: x[:1]), (lambda x: np.zeros((1, 6)))


@pytest.mark.parametrize("opts", OPTIONS, ids=IDS)
def test_ski_mukf_matches_reference_composition(opts):
    """MUKF update → ARD (skigen.reference.ard) → MUKF predict, in NumPy."""
    d = derive(_wingrock_euler(), "ski_mukf", opts)
    assert d.partition.nonlinear_names == ["theta", "p"]
    aug, o = d.aug, opts
    nl, ll, w = [0, 1], list(range(2, 8)), aug.w_index
    rng = np.random.default_rng(5)
    deltas = 2.0 * np.sign(np.sin(2 * np.pi * np.arange(300) * 0.02 / 1.5)) + 0.5 * rng.standard_normal(300)
    x, ys = np.zeros(8), []
    x[2:] = wingrock.W_TRUE
    for delta in deltas:
        ys.append(x[:1] + 0.1 * rng.standard_normal(1))
        dd, A, _, _ = _wingrock_affine(delta)
        x = dd(x[:2]) + A(x[:2]) @ x[2:]

    def step(st, u, y, valid):
        dd, A, c, C = _wingrock_affine(u[0])
        upd, P = ref.mukf_update(st["z"], st["S"], y, valid, nl, ll, c, C, aug.R, o.alpha, o.beta, o.kappa)
        z = upd["z_post"]
        if o.ard == "gradient":
            s = ref_ard.ard_optimise(st["s"], z[w], P[np.ix_(w, w)], o.eta, o.ard_steps, o.margin,
                                     o.s_min, o.s_max, o.max_step, o.backtracks)
            z_report, P = ref_ard.ard_correct(z, P, w, s, st["s"])
            z = z_report
        else:
            z_report, s = ref_ard.ard_fixed_point(z, P, w, st["s"], aug.s0, o.margin, o.s_floor, o.s_max)
        z_pred, S_pred = ref.mukf_predict(z, P, nl, ll, dd, A, aug.Q, o.alpha, o.beta, o.kappa)
        d_rep = z_report - z                 # EM: reported about its mean (0 for gradient)
        return dict(z_post=z_report, S_post=chol(P + np.outer(d_rep, d_rep)), z=z_pred, S=S_pred, s=s,
                    e=upd["e"], Pyy=upd["Pyy"], nis=upd["nis"], loglik=upd["loglik"])
    _compare_run(d, step, deltas[:, None], np.array(ys))


# ------------------------------------------------------------------ C backend

@pytest.mark.parametrize("kind,model", [("mukf", lambda: quad.build("euler")), ("ski_mukf", _wingrock_euler)],
                         ids=["mukf_quadrotor", "ski_mukf_wingrock"])
def test_c_backend_equals_python(kind, model, tmp_path):
    filt = derive(model(), kind)
    if kind == "mukf":
        sim = quad.simulate(seed=3, duration=8.0)
        y = sim.y.copy()
        y[::9, 1] = np.nan
        y[::31, :] = np.nan
        rec = Recording("sim", sim.t, sim.F, y, quad.INPUTS, quad.OUTPUTS)
    else:
        from models.wingrock_sim import simulate
        sim = simulate(seed=0)
        phi = sim.phi.copy()
        phi[::13] = np.nan
        rec = Recording("sim", sim.t, sim.delta[:, None], phi[:, None], ("delta",), ("phi",))
    py = run(filt, rec, backend="python", show_progress=False)
    c = run(filt, rec, backend="c", show_progress=False, cache_dir=tmp_path)
    assert (py.code == c.code).all()
    for a, b in [(c.mean, py.mean), (c.std, py.std), (c.innovation, py.innovation), (c.nis, py.nis),
                 (c.loglik, py.loglik), (c.prior_var, py.prior_var)]:
        np.testing.assert_allclose(a, b, rtol=0, atol=RTOL * max(np.nanmax(np.abs(b), initial=0), 1.0))
