"""Checks of the derivation against outside oracles: finite differences, filterpy, the ARD identities."""
import casadi as ca
import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from models.wingrock import build
from models.wingrock_sim import simulate
from skigen import FilterOptions, derive
from skigen.derive import augment
from skigen.derive import ard
from skigen.recording import Recording
from skigen.reference import ard as ref_ard
from skigen.emit import Status
from skigen.runtime import run
from skigen.reference.wingrock import wingrock_f


def test_ekf_jacobians_equal_finite_differences():
    aug = augment(build())
    A = ca.Function("A", [aug.z, aug.u], [ca.jacobian(aug.f, aug.z)])
    F = ca.Function("F", [aug.z, aug.u], [aug.f])
    rng = np.random.default_rng(0)
    for _ in range(5):
        z = np.r_[rng.uniform(-6, 6), rng.uniform(-15, 15), 0.3 * rng.standard_normal(6)]
        u = rng.uniform(-5, 5)
        h = 1e-6 * np.maximum(1, np.abs(z))
        fd = np.column_stack([(np.array(F(z + h[j] * e, u)) - np.array(F(z - h[j] * e, u))).ravel() / (2 * h[j])
                              for j, e in enumerate(np.eye(8))])
        np.testing.assert_allclose(np.array(A(z, u)), fd, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("alpha, kappa", [(1.0, 0.0), (0.5, 0.0), (0.3, 1.0)])
def test_ukf_equals_filterpy(alpha, kappa):
    """Our square-root step = filterpy's UnscentedKalmanFilter with MerweScaledSigmaPoints."""
    d = derive(build(prior_variance=0.5), "ukf", FilterOptions(alpha=alpha, beta=2.0, kappa=kappa))
    aug = d.aug
    points = MerweScaledSigmaPoints(aug.n, alpha=alpha, beta=2.0, kappa=kappa)
    fp = UnscentedKalmanFilter(dim_x=aug.n, dim_z=1, dt=aug.model.dt, hx=lambda z: z[:1],
                               fx=lambda z, dt, delta: wingrock_f(z, delta), points=points)
    fp.x, fp.P, fp.Q, fp.R = aug.z0.copy(), aug.P0.copy(), aug.Q.copy(), aug.R.copy()
    st = d.initial()
    sim = simulate(seed=3)
    for k in range(200):
        y, delta = sim.phi[k], sim.delta[k]
        r = d.step(z=st["z"], C=st["C"], u=[delta], mem=st["mem"], y=[y], valid=[1.0])
        fp.sigmas_f = points.sigma_points(fp.x, fp.P)   # filterpy's update reuses sigmas_f: redraw
        fp.update(np.array([y]))
        np.testing.assert_allclose(np.array(r["z_post"]).ravel(), fp.x, rtol=1e-9, atol=1e-9)
        S = np.array(r["C_post"])
        np.testing.assert_allclose(S @ S.T, fp.P, rtol=1e-8, atol=1e-10)
        fp.predict(delta=delta)
        S = np.array(r["C_next"])
        np.testing.assert_allclose(np.array(r["z_next"]).ravel(), fp.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(S @ S.T, fp.P, rtol=1e-8, atol=1e-10)
        st = dict(z=np.array(r["z_next"]).ravel(), C=S, mem=st["mem"])


# ------------------------------------------------------------------ ARD on the CasADi side
m = 5
_s_new, _s_old, _mu = ca.SX.sym("s_new", m), ca.SX.sym("s_old", m), ca.SX.sym("mu", m)
_P = ca.SX.sym("P", m, m)
_Lw = ard.chol(_P)
LOSS = ca.Function("loss", [_s_new, _s_old, _mu, _P], [ard.ard_loss(_s_new, _s_old, _mu, _Lw)])
GRAD = ca.Function("grad", [_s_new, _s_old, _mu, _P], [ard.ard_grad(_s_new, _s_old, _mu, _Lw)])


def _regression(seed=0, n=40):
    """A Bayesian linear regression y = Φ w + v: prior N(0, diag(s)), posterior (μ, P), evidence."""
    rng = np.random.default_rng(seed)
    Phi = rng.standard_normal((n, m))
    w = np.array([1.5, 0, -0.7, 0, 0.2])
    r = 0.3
    y = Phi @ w + np.sqrt(r) * rng.standard_normal(n)
    s = rng.uniform(0.5, 2.0, m)
    P = np.linalg.inv(np.diag(1 / s) + Phi.T @ Phi / r)
    mu = P @ Phi.T @ y / r

    def log_evidence(sv):
        C = Phi @ np.diag(sv) @ Phi.T + r * np.eye(n)
        return -0.5 * (y @ np.linalg.solve(C, y) + np.linalg.slogdet(2 * np.pi * C)[1])
    return s, mu, P, log_evidence, rng


def test_casadi_ard_gradient_is_finite_difference_of_loss():
    s, mu, P, _, rng = _regression()
    xi = ref_ard.softplus_inv(s * rng.uniform(0.3, 3.0, m))
    g = np.array(GRAD(xi, s, mu, P)).ravel()
    L = lambda x: float(LOSS(ref_ard.softplus(x), s, mu, P))
    h = 1e-6
    fd = np.array([(L(xi + h * e) - L(xi - h * e)) / (2 * h) for e in np.eye(m)])
    np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(g, ref_ard.ard_grad(xi, s, mu, P), rtol=1e-10)


def test_casadi_ard_loss_difference_is_evidence_difference():
    s, mu, P, log_ev, rng = _regression(seed=1)
    s_new = s * rng.uniform(0.2, 5.0, m)
    dL = float(LOSS(s_new, s, mu, P)) - float(LOSS(s, s, mu, P))
    assert dL == pytest.approx(-log_ev(s_new) + log_ev(s), rel=1e-9, abs=1e-10)


def test_casadi_ard_gradient_at_fixed_prior_is_em_form():
    s, mu, P, _, _ = _regression(seed=2)
    xi = ref_ard.softplus_inv(s)
    em = ref_ard.sigmoid(xi) * (1 / (2 * s) - (np.diag(P) + mu ** 2) / (2 * s ** 2))
    np.testing.assert_allclose(np.array(GRAD(xi, s, mu, P)).ravel(), em, rtol=1e-10)


def test_casadi_ard_correction_is_posterior_from_scratch():
    s, mu, P, _, rng = _regression(seed=3)
    Phi_y = np.linalg.solve(P, mu)                       # Φᵀy / r, prior-free information vector
    info = np.linalg.inv(P) - np.diag(1 / s)             # Φᵀ Φ / r
    s_new = s * rng.uniform(0.2, 5.0, m)
    P_new = np.linalg.inv(info + np.diag(1 / s_new))
    z, Sz, sn, so = ca.SX.sym("z", m), ca.SX.sym("S", m, m), ca.SX.sym("sn", m), ca.SX.sym("so", m)
    corr = ca.Function("c", [z, Sz, sn, so], list(ard.ard_correct(z, Sz, range(m), sn, so)))
    m_c, S_c = (np.array(v) for v in corr(mu, np.linalg.cholesky(P), s_new, s))
    np.testing.assert_allclose(m_c.ravel(), P_new @ Phi_y, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(S_c @ S_c.T, P_new, rtol=1e-9, atol=1e-12)
    assert np.allclose(S_c, np.tril(S_c)) and np.all(np.diag(S_c) > 0)


def _sim_recording(seed):
    sim = simulate(seed=seed)
    return Recording("sim", sim.t, sim.delta[:, None], sim.phi[:, None], ("delta",), ("phi",))


def test_guard_keeps_ski_finite_where_widening_removes_information():
    """Random-walk weights + aggressive gradient ARD: unguarded the correction feeds back and
    diverges (ski-math.md §6): from k = 119 most steps are rejected as non-finite and the
    recovery restarts the states again and again (measured: 592 rejected, 23 restarts of 751);
    the eigenvalue guard keeps the filter bounded, every step OK. The EM update, whose
    correction is never fed back, stays bounded too (its widening guarded)."""
    model = build(prior_variance=1.0, weight_std=1e-3)
    aggressive = dict(ard="gradient", ard_steps=5, eta=1.0, max_step=5.0)
    rec = _sim_recording(0)
    bad = run(derive(model, "ski", FilterOptions(margin=-np.inf, **aggressive)), rec, show_progress=False)
    assert np.sum(bad.code == Status.NUMERICAL_FAILURE) > 300 and np.sum(bad.code == Status.REINITIALISED) > 10
    res = run(derive(model, "ski", FilterOptions(margin=0.9, **aggressive)), rec, show_progress=False)
    assert np.all(res.code == Status.OK)
    assert np.all(np.isfinite(res.mean)) and np.abs(res.weights).max() < 10
    em = run(derive(model, "ski"), rec, show_progress=False)
    assert np.all(em.code == Status.OK)
    assert np.all(np.isfinite(em.mean)) and np.abs(em.weights).max() < 10


def _damped(a):
    from skigen import Model
    m = Model("damped", dt=0.05)
    x = m.state("x", std=1.0, process_std=0.01)
    v = m.state("v", std=1.0, process_std=0.05)
    u = m.input("u")
    k = m.parameter("k", a, bounds=(0, 100))
    m.dynamics({x: v, v: -k * x - 0.3 * v * ca.fabs(v) + u})
    m.output("pos", x, noise_std=0.02)
    return m


@pytest.mark.parametrize("kind", ["ekf", "ukf"])
def test_a_filter_at_other_parameter_values_runs_as_one_derived_with_them(kind):
    """DerivedFilter.at shares the tunable step (no second derivation) and runs to the bit as
    the filter derived from the model declared with those values."""
    rng = np.random.default_rng(3)
    N = 300
    rec = Recording("d", np.arange(N) * 0.05, rng.normal(size=(N, 1)), 0.1 * rng.normal(size=(N, 1)), ("u",), ("pos",))
    base = derive(_damped(2.0), kind)
    moved = base.at(k=5.5)
    assert moved.tunable is base.tunable and moved.aug.model.parameter_named("k").value == 5.5
    assert base.aug.model.parameter_named("k").value == 2.0
    for backend in ("casadi", "python"):
        a = run(moved, rec, backend=backend, show_progress=False)
        b = run(derive(_damped(5.5), kind), rec, backend=backend, show_progress=False)
        np.testing.assert_array_equal(a.mean, b.mean)
        np.testing.assert_array_equal(a.loglik, b.loglik)
    assert not np.array_equal(run(base, rec, backend="casadi", show_progress=False).mean, a.mean)
    with pytest.raises(ValueError, match="no fixed parameter 'c' .fixed: k."):
        base.at(c=1.0)
