"""The ARD identities of docs/ski-math.md section 4, on the NumPy reference."""

import numpy as np
import pytest

from skigen.reference.ard import (ard_correct, ard_fixed_point, ard_grad, ard_loss, ard_optimise,
                                  ard_project, sigmoid, softplus, softplus_inv)

M, N, R_NOISE = 5, 40, 0.3**2


@pytest.fixture
def blr():
    """Bayesian linear regression y = Φ w + noise, prior w ~ N(0, diag(s))."""
    rng = np.random.default_rng(0)
    Phi = rng.normal(size=(N, M))
    w = np.array([1.0, 0.0, -0.5, 0.0, 0.2])
    y = Phi @ w + np.sqrt(R_NOISE) * rng.normal(size=N)
    s = rng.uniform(0.2, 2.0, M)
    s_new = s * np.exp(rng.normal(scale=0.7, size=M))
    return dict(Phi=Phi, y=y, s=s, s_new=s_new, rng=rng)


def posterior(Phi, y, s):
    """Exact posterior (μ, P) of w under prior variances s."""
    P = np.linalg.inv(Phi.T @ Phi / R_NOISE + np.diag(1.0 / s))
    return P @ Phi.T @ y / R_NOISE, P


def log_evidence(Phi, y, s):
    """Brute-force log p(y | s): y ~ N(0, Φ diag(s) Φᵀ + r I)."""
    C = Phi @ np.diag(s) @ Phi.T + R_NOISE * np.eye(len(y))
    return -0.5 * (y @ np.linalg.solve(C, y) + np.linalg.slogdet(2 * np.pi * C)[1])


def condition(P0, H, r, y):
    """Posterior of z ~ N(0, P0) given y = H z + N(0, r I), information form (no cancellation)."""
    P = np.linalg.inv(np.linalg.inv(P0) + H.T @ H / r)
    return P @ H.T @ y / r, P


def test_softplus_roundtrip():
    s = np.array([1e-8, 1e-3, 0.5, 3.0, 50.0, 1e3])
    np.testing.assert_allclose(softplus(softplus_inv(s)), s, rtol=1e-12)
    np.testing.assert_allclose(softplus_inv(1e3), 1e3, rtol=1e-15)


def test_grad_is_finite_difference_of_loss(blr):
    mu, P = posterior(blr["Phi"], blr["y"], blr["s"])
    xi = softplus_inv(blr["s_new"])
    g = ard_grad(xi, blr["s"], mu, P)
    h = 1e-5
    fd = [(ard_loss(softplus(xi + h * e), blr["s"], mu, P)
           - ard_loss(softplus(xi - h * e), blr["s"], mu, P)) / (2 * h) for e in np.eye(M)]
    np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-9)


def test_correct_equals_posterior_from_scratch_pure_w(blr):
    mu, P = posterior(blr["Phi"], blr["y"], blr["s"])
    m2, P2 = ard_correct(mu, P, np.arange(M), blr["s_new"], blr["s"])
    mu_ref, P_ref = posterior(blr["Phi"], blr["y"], blr["s_new"])
    np.testing.assert_allclose(m2, mu_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(P2, P_ref, rtol=1e-9, atol=1e-12)


def test_correct_equals_posterior_from_scratch_augmented(blr):
    """z = [x; w] with x = A w + v (so P_zw is non-trivial); y = C x + Φ w + noise."""
    rng = blr["rng"]
    A, C = rng.normal(size=(2, M)), rng.normal(size=(N, 2))
    V = np.diag([0.1, 0.4])
    H = np.hstack([C, blr["Phi"]])
    y = H @ rng.normal(size=2 + M)
    w_idx = np.arange(2, 2 + M)

    def prior(s):
        S = np.diag(s)
        return np.block([[A @ S @ A.T + V, A @ S], [S @ A.T, S]])

    m, P = condition(prior(blr["s"]), H, R_NOISE, y)
    m_ref, P_ref = condition(prior(blr["s_new"]), H, R_NOISE, y)
    m2, P2 = ard_correct(m, P, w_idx, blr["s_new"], blr["s"])
    assert np.abs(P[:2, 2:]).max() > 1e-3
    np.testing.assert_allclose(m2, m_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(P2, P_ref, rtol=1e-9, atol=1e-12)


def test_loss_difference_is_log_evidence_difference(blr):
    Phi, y, s, s_new = blr["Phi"], blr["y"], blr["s"], blr["s_new"]
    mu, P = posterior(Phi, y, s)
    dL = ard_loss(s_new, s, mu, P) - ard_loss(s, s, mu, P)
    dE = -log_evidence(Phi, y, s_new) + log_evidence(Phi, y, s)
    np.testing.assert_allclose(dL, dE, rtol=1e-9)


def test_grad_at_current_prior_is_em_form(blr):
    s = blr["s"]
    mu, P = posterior(blr["Phi"], blr["y"], s)
    xi = softplus_inv(s)
    em = sigmoid(xi) * (0.5 / s - (np.diag(P) + mu**2) / (2 * s**2))
    np.testing.assert_allclose(ard_grad(xi, s, mu, P), em, rtol=1e-9, atol=1e-14)
    s_em = mu**2 + np.diag(P)           # the EM/MacKay fixed point zeroes the gradient
    np.testing.assert_allclose(ard_grad(softplus_inv(s_em), s_em, mu, P), 0.0, atol=1e-9)


def lam_min(s_new, s_old, Pww):
    L = np.linalg.cholesky(Pww)
    d = 1.0 / s_new - 1.0 / s_old
    return np.linalg.eigvalsh(np.eye(len(d)) + L.T @ (d[:, None] * L)).min()


def test_project_keeps_margin():
    """Posterior wider than the prior (nonlinear filter / process noise) and a widening proposal."""
    rng = np.random.default_rng(1)
    s_old = rng.uniform(0.5, 1.5, M)
    B = rng.normal(size=(M, M))
    Pww = 2.0 * np.diag(s_old) + 0.1 * B @ B.T
    s_prop = 10.0 * s_old
    margin, s_min, s_max = 0.2, 1e-6, 1e3
    assert lam_min(s_prop, s_old, Pww) < 0           # the unguarded proposal breaks PD
    s_g = ard_project(s_prop, s_old, Pww, margin, s_min, s_max)
    assert lam_min(s_g, s_old, Pww) >= margin - 1e-12
    assert np.all((s_g >= s_min) & (s_g <= s_max))
    s_g2 = ard_project(np.full(M, 1e9), s_old, 1e-6 * np.eye(M), margin, s_min, s_max)
    np.testing.assert_allclose(s_g2, s_max, rtol=1e-12)


def test_optimise(blr):
    s = blr["s"]
    mu, P = posterior(blr["Phi"], blr["y"], s)
    args = (mu, P, 0.5)
    kw = dict(margin=0.1, s_min=1e-6, s_max=1e3, max_step=1.0)
    np.testing.assert_array_equal(ard_optimise(s, *args, n_steps=0, **kw), s)
    s_new = ard_optimise(s, *args, n_steps=20, **kw)
    assert ard_loss(s_new, s, mu, P) < ard_loss(s, s, mu, P)


def _em_iterations(Phi, y, s0, n, s_floor=1e-4):
    """n EM updates on the posterior under the declared s0 (the filter's), as SKI does per sample."""
    m0, P0 = posterior(Phi, y, s0)
    s, trace = s0.copy(), [s0.copy()]
    for _ in range(n):
        m, s = ard_fixed_point(m0, P0, np.arange(M), s, s0, 0.9, s_floor, 1e12)
        trace.append(s)
    return m, np.array(trace)


def test_em_raises_the_evidence_to_a_stationary_point(blr):
    """EM never lowers the evidence; it converges (here off its floor) where the evidence's
    gradient vanishes, and the reported mean is the exact posterior mean under that prior."""
    Phi, y = blr["Phi"], blr["y"]
    m, trace = _em_iterations(Phi, y, blr["s"], 400)
    ev = [log_evidence(Phi, y, s) for s in trace]
    assert np.all(np.diff(ev) >= -1e-9) and ev[-1] > ev[0] + 1.0
    s = trace[-1]
    mu, P = posterior(Phi, y, s)
    np.testing.assert_allclose(m, mu, rtol=1e-9, atol=1e-12)
    assert np.all(s > 1e-3 * np.diag(P))                         # off the floor: interior
    np.testing.assert_allclose(ard_grad(softplus_inv(s), s, mu, P), 0.0, atol=1e-9)


def test_em_progress_does_not_depend_on_the_prior_scale(blr):
    """From declared priors 1 and 10⁴ the EM updates land on the same relevances within a few
    samples' worth of iterations; the softplus gradient barely moves the broad one."""
    Phi, y = blr["Phi"], blr["y"]
    _, narrow = _em_iterations(Phi, y, np.ones(M), 5)
    _, broad = _em_iterations(Phi, y, np.full(M, 1e4), 5)
    np.testing.assert_allclose(np.log(broad[-1]), np.log(narrow[-1]), atol=0.02)
    s = np.full(M, 1e4)
    mu, P = posterior(Phi, y, s)
    step = ard_optimise(s, mu, P, eta=0.3, n_steps=5, margin=0.9, s_min=1e-10, s_max=1e6, max_step=1.0)
    assert np.all(step > 0.99 * s)
