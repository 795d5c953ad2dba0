"""The NumPy reference filters against filterpy, a hand-written Kalman filter and themselves."""

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from skigen.reference.filters import (chol, ekf_step, jacobian_cs, merwe_weights,
                                      ski_step, ukf_step)

DT = 0.05


def pend_f(z):
    """Damped pendulum [θ, ω, c] with unknown damping c (a constant state); complex-step safe."""
    th, om, c = z
    return np.array([th + DT * om, om + DT * (-9.81 * np.sin(th) - c * om), c])


def pend_h(z):
    return np.array([np.sin(z[0]) + 0.1 * z[1]])


def pend_data(n_steps, rng):
    z, ys = np.array([1.0, 0.0, 0.4]), []
    for _ in range(n_steps):
        ys.append(pend_h(z) + 0.02 * rng.normal(size=1))
        z = pend_f(z) + np.array([0.0, 1e-3, 0.0]) * rng.normal(size=3)
    return np.array(ys)


Z0 = np.array([0.8, 0.1, 0.1])
P0 = np.diag([0.1, 0.1, 0.5])
Q = np.diag([1e-6, 1e-4, 1e-6])
R = np.array([[0.02**2]])
ALL = np.ones(1, bool)


@pytest.mark.parametrize("alpha, beta, kappa", [(1.0, 2.0, 0.0), (0.5, 2.0, 0.0), (1e-1, 2.0, 1.0)])
def test_ukf_equals_filterpy(alpha, beta, kappa):
    if alpha == 0.5:
        assert merwe_weights(3, alpha, beta, kappa)[1][0] < 0      # Wc0 < 0 is exercised
    ys = pend_data(50, np.random.default_rng(0))
    points = MerweScaledSigmaPoints(3, alpha, beta, kappa)
    fp = UnscentedKalmanFilter(3, 1, DT, hx=pend_h, fx=lambda x, dt: pend_f(x), points=points)
    fp.x, fp.P, fp.Q, fp.R = Z0.copy(), P0.copy(), Q, R
    z, S = Z0.copy(), chol(P0)
    for y in ys:
        out = ukf_step(z, S, y, ALL, pend_f, pend_h, Q, R, alpha, beta, kappa)
        fp.sigmas_f = points.sigma_points(fp.x, fp.P)             # redraw, as we do
        fp.update(y)
        close(out["z_post"], fp.x)
        close(out["S_post"] @ out["S_post"].T, fp.P)
        close(out["Pyy"], fp.S)
        close(out["e"], fp.y)
        fp.predict()
        z, S = out["z"], out["S"]
        close(z, fp.x)
        close(S @ S.T, fp.P)
        assert np.allclose(np.tril(S), S) and np.all(np.diag(S) > 0)


def close(a, b, rtol=1e-9):
    np.testing.assert_allclose(a, b, rtol=rtol, atol=rtol * np.abs(b).max())


def test_ekf_linear_equals_kalman_filter():
    rng = np.random.default_rng(1)
    n, ny = 4, 2
    A = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    C = rng.normal(size=(ny, n))
    Qm, Rm = 0.01 * np.eye(n), 0.1 * np.eye(ny)
    z, P = np.zeros(n), np.eye(n)
    zk, Pk = z.copy(), P.copy()
    for k in range(30):
        u = np.sin(0.3 * k)
        y = rng.normal(size=ny)
        out = ekf_step(z, P, y, np.ones(ny, bool), lambda x: A @ x + u, lambda x: C @ x, Qm, Rm)
        Syy = C @ Pk @ C.T + Rm
        K = Pk @ C.T @ np.linalg.inv(Syy)
        e = y - C @ zk
        zk, Pk = zk + K @ e, Pk - K @ C @ Pk
        close(out["z_post"], zk)
        close(out["P_post"], Pk)
        np.testing.assert_allclose(out["loglik"], -0.5 * (e @ np.linalg.solve(Syy, e)
                                   + np.linalg.slogdet(2 * np.pi * Syy)[1]), rtol=1e-9)
        zk, Pk = A @ zk + u, A @ Pk @ A.T + Qm
        z, P = out["z"], out["P"]
        close(z, zk)
        close(P, Pk)


def test_complex_step_jacobian():
    def fun(z):
        a, b, c = z
        return np.array([np.sin(a) * b, np.exp(b) + c**2, a * np.sign(np.real(a)) * c, b**3])

    def jac(z):
        a, b, c = z
        return np.array([[np.cos(a) * b, np.sin(a), 0], [0, np.exp(b), 2 * c],
                         [np.sign(a) * c, 0, abs(a)], [0, 3 * b**2, 0]])

    for z in ([0.3, -1.2, 2.0], [-0.7, 0.5, -1.5]):
        np.testing.assert_allclose(jacobian_cs(fun, np.array(z)), jac(z), rtol=1e-12, atol=1e-14)
    J = jacobian_cs(lambda z: z[0] * z[1], np.array([2.0, 3.0]))     # scalar output -> (1, n)
    np.testing.assert_allclose(J, [[3.0, 2.0]], rtol=1e-14)


def ekf(z, S, y, valid, h, R):
    out = ekf_step(z, S @ S.T, y, valid, pend_f, h, Q, R)
    return out, out["P_post"]


def ukf(z, S, y, valid, h, R):
    out = ukf_step(z, S, y, valid, pend_f, h, Q, R, 1.0, 2.0, 0.0)
    return out, out["S_post"] @ out["S_post"].T


@pytest.mark.parametrize("step", [ekf, ukf])
def test_no_valid_output_means_no_update(step):
    S = chol(P0)
    out, P = step(Z0, S, np.array([1.0]), np.zeros(1, bool), pend_h, R)
    close(out["z_post"], Z0, 1e-14)
    close(P, P0, 1e-14)
    assert out["nis"] == 0 and out["loglik"] == 0
    np.testing.assert_array_equal(out["e"], 0.0)
    np.testing.assert_array_equal(out["Pyy"], np.eye(1))


def h2(z):
    return np.array([np.cos(z[1]) * z[0], pend_h(z)[0]])


@pytest.mark.parametrize("step", [ekf, ukf])
def test_invalid_output_is_dropped(step):
    S = chol(P0)
    R2 = np.array([[0.3, 0.01], [0.01, R[0, 0]]])
    y2 = np.array([5.0, 0.7])
    out2, P2 = step(Z0, S, y2, np.array([False, True]), h2, R2)
    out1, P1 = step(Z0, S, y2[1:], ALL, pend_h, R)
    close(out2["z_post"], out1["z_post"])
    close(P2, P1)
    close(out2["z"], out1["z"])
    assert out2["e"][0] == 0 and out2["e"][1] == out1["e"][0]
    np.testing.assert_array_equal(out2["Pyy"], [[1.0, 0.0], [0.0, out1["Pyy"][0, 0]]])
    assert out2["nis"] == pytest.approx(out1["nis"], rel=1e-12)
    assert out2["loglik"] == pytest.approx(out1["loglik"], rel=1e-12)


def test_ski_without_ard_steps_is_ukf():
    S = chol(P0)
    y = np.array([0.7])
    s = np.array([0.5])
    ard = dict(eta=0.1, n_steps=0, margin=0.1, s_min=1e-6, s_max=1e3, max_step=1.0)
    out_s = ski_step(Z0, S, s, y, ALL, pend_f, pend_h, Q, R, [2], 1.0, 2.0, 0.0, **ard)
    out_u = ukf_step(Z0, S, y, ALL, pend_f, pend_h, Q, R, 1.0, 2.0, 0.0)
    for key in out_u:
        close(out_s[key], out_u[key], 1e-14)
    np.testing.assert_array_equal(out_s["s"], s)
    ard["n_steps"] = 5
    out_a = ski_step(Z0, S, s, y, ALL, pend_f, pend_h, Q, R, [2], 1.0, 2.0, 0.0, **ard)
    assert out_a["s"][0] != s[0] and np.all(np.isfinite(out_a["S"]))
