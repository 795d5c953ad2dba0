"""WingRock truth simulator (models/wingrock_sim.py) and the SINDy baseline."""

import numpy as np
import pytest

from models.wingrock_sim import (BASIS_NAMES, L_TRUE, W_TRUE, basis, simulate,
                                 square_wave_reference)
from skigen.baselines import sindy_time_history, sindy_weights

DELAY = 6
SEEDS = range(20)
STEP_TIMES = 0.5 + 2.5 * np.arange(6)
SETTLE = 1.5            # s excluded after each reference step
TRACK_RMS_BOUND = 0.5   # deg; measured max over seeds 0..19: 0.37 (d = 0), 0.40 (d = 6)
SINDY_CLEAN_TOL = 0.05  # ‖ŵ − w*‖ on noise-free data; measured 0.013


def _rk4(theta, p, u, dt, w, gain):
    """Independent (vectorised) classical RK4 step of the WingRock dynamics."""
    def f(x):
        th, pr = x
        phi = np.stack([np.ones_like(th), th, pr, np.abs(th) * pr, np.abs(pr) * pr, th ** 3])
        return np.stack([pr, gain * u + w @ phi])
    x = np.stack([theta, p])
    k1 = f(x)
    k2 = f(x + dt / 2 * k1)
    k3 = f(x + dt / 2 * k2)
    k4 = f(x + dt * k3)
    return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def _residual(run, u_applied):
    nxt = _rk4(run.theta[:-1], run.p[:-1], u_applied[:-1], run.dt, np.asarray(run.weights), run.gain)
    return np.max(np.abs(nxt - np.stack([run.theta[1:], run.p[1:]])))


def _shift(u, d):
    out = np.zeros_like(u)
    out[d:] = u[:len(u) - d]
    return out


def test_constants_and_basis():
    assert W_TRUE.tolist() == [0.8, 0.2314, 0.6918, -0.6245, 0.0095, 0.0214]
    assert L_TRUE == 3.0 and len(BASIS_NAMES) == 6
    th, p = np.array([[-2.0, 3.0]]), np.array([[1.5, -4.0]])
    B = basis(th, p)
    assert B.shape == (1, 2, 6)
    np.testing.assert_allclose(B[0, 0], [1, -2, 1.5, 3.0, 2.25, -8])
    np.testing.assert_allclose(B[0, 1], [1, 3, -4, -12, -16, 27])


def test_reference():
    assert square_wave_reference(0.0) == 0.0 and square_wave_reference(0.49) == 0.0
    assert square_wave_reference(0.5) == 5.0 and square_wave_reference(2.99) == 5.0
    assert square_wave_reference(3.0) == -5.0 and square_wave_reference(5.6) == 5.0
    r = square_wave_reference(np.arange(751) * 0.02)
    assert r.shape == (751,) and set(np.unique(r)) == {-5.0, 0.0, 5.0}


def test_record_layout_and_determinism():
    a, b, c = simulate(seed=3), simulate(seed=3), simulate(seed=4)
    assert len(a.t) == 751 and a.t[-1] == pytest.approx(15.0) and a.t[1] == pytest.approx(0.02)
    for name in ("t", "delta", "phi", "theta", "p", "reference"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.allclose(a.phi, c.phi) and not np.allclose(a.delta, c.delta)
    assert a.seed == 3 and a.delay == 0 and a.gain == 3.0 and a.noise_std == 0.1
    np.testing.assert_array_equal(a.weights, W_TRUE)
    # noise statistics of the measurement
    assert np.std(a.phi - a.theta) == pytest.approx(0.1, rel=0.15)



@pytest.mark.parametrize("noise_std", [0.0, 0.1])
def test_truth_satisfies_rk4_dynamics(noise_std):
    run = simulate(seed=5, noise_std=noise_std)
    assert _residual(run, run.delta) < 1e-12
    if noise_std == 0.0:
        np.testing.assert_array_equal(run.phi, run.theta)


def test_delay_applies_command_shifted_by_six():
    run = simulate(seed=2, delay=DELAY)
    assert run.delay == DELAY
    assert _residual(run, _shift(run.delta, DELAY)) < 1e-12
    for wrong in (0, 5, 7):
        assert _residual(run, _shift(run.delta, wrong)) > 1e-3
    np.testing.assert_array_equal(run.delta_applied, _shift(run.delta, DELAY))


def test_different_weights_and_gain_are_used():
    w = W_TRUE * np.array([1, 1, 0.5, 1, 1, 1])
    run = simulate(seed=0, weights=w, gain=2.5)
    assert _residual(run, run.delta) < 1e-12
    assert run.gain == 2.5 and np.allclose(run.weights, w)


@pytest.mark.parametrize("delay", [0, DELAY])
def test_tracking(delay):
    for seed in SEEDS:
        run = simulate(seed=seed, delay=delay)
        assert np.all(np.isfinite(run.theta)) and np.max(np.abs(run.theta)) < 15.0
        assert np.max(np.abs(run.delta)) <= 20.0
        since = np.min(np.where(run.t[:, None] >= STEP_TIMES - 1e-9,
                                run.t[:, None] - STEP_TIMES, np.inf), axis=1)
        settled = since > SETTLE
        rms = np.sqrt(np.mean((run.theta - run.reference)[settled] ** 2))
        assert rms < TRACK_RMS_BOUND, (seed, delay, rms)
        # modest overshoot on the 10-deg reference steps
        assert np.max(np.abs(run.theta)) < 7.0


def _clean(seed=0):
    run = simulate(seed=seed, noise_std=0.0)
    return run.t, run.delta, run.phi


def test_sindy_recovers_weights_on_noise_free_data():
    t, d, phi = _clean()
    w = sindy_weights(t, d, phi, gain=L_TRUE, differentiation="finite_difference",
                      input_alignment="centered")
    assert w.shape == (6,)
    assert np.linalg.norm(w - W_TRUE) < SINDY_CLEAN_TOL
    # the default (Savitzky-Golay smoothed) derivatives are biased on the
    # reference steps, but the estimate stays close (measured 0.59)
    assert np.linalg.norm(sindy_weights(t, d, phi) - W_TRUE) < 0.75


@pytest.mark.parametrize("wrong", ["theta^2 for theta^3", "drop |theta|*p", "gain 2.5"])
def test_sindy_wrong_model_fails_tolerance(wrong):
    t, d, phi = _clean()
    gain = 2.5 if wrong == "gain 2.5" else L_TRUE

    def wrong_basis(th, p):
        B = basis(th, p)
        if wrong == "theta^2 for theta^3":
            B[..., 5] = th ** 2
        elif wrong == "drop |theta|*p":
            B[..., 3] = 0.0
        return B

    w = sindy_weights(t, d, phi, gain=gain, basis_fn=wrong_basis,
                      differentiation="finite_difference", input_alignment="centered")
    assert np.linalg.norm(w - W_TRUE) > 4 * SINDY_CLEAN_TOL


def test_sindy_noisy_is_finite_and_time_history_shape():
    run = simulate(seed=1)
    w = sindy_weights(run.t, run.delta, run.phi)
    assert w.shape == (6,) and np.all(np.isfinite(w))
    times, W = sindy_time_history(run.t, run.delta, run.phi, gain=L_TRUE)
    np.testing.assert_allclose(times, np.arange(1, 16, dtype=float))
    assert W.shape == (15, 6) and np.all(np.isfinite(W))
    np.testing.assert_allclose(W[-1], w)  # the last prefix is the whole record
