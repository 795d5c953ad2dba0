"""WingRock written by hand in NumPy for the reference filters (complex-step safe).

Independent of CasADi and of skigen's declaration: the WingRock equations
are typed in again here so that the oracle shares nothing with the derivation.
"""
import numpy as np

DT = 0.02
GAIN = 3.0


def _abs(x):
    return x * np.sign(np.real(x))


def wingrock_rhs(x, w, delta):
    theta, p = x
    phi = np.array([1.0 + 0 * theta, theta, p, _abs(theta) * p, _abs(p) * p, theta ** 3], dtype=object)
    return np.array([p, GAIN * delta + sum(wi * fi for wi, fi in zip(w, phi))])


def wingrock_f(z, delta, dt=DT):
    """One RK4 step of the augmented WingRock state z = [theta, p, w(6)]."""
    x, w = z[:2], z[2:]
    f = lambda xi: wingrock_rhs(xi, w, delta)
    k1 = f(x)
    k2 = f(x + dt / 2 * k1)
    k3 = f(x + dt / 2 * k2)
    k4 = f(x + dt * k3)
    return np.concatenate([x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4), w]).astype(z.dtype)


def wingrock_h(z):
    return z[:1]


def wingrock_delay_f(z, inputs, known, dt=DT):
    """One RK4 step of the delay model's z = [theta, p, w(m)]: the roll acceleration is
    Σ_j w_j δ[k−j] + Σ known_i φ_i(θ, p); ``inputs`` = δ[k], δ[k−1], …, δ[k−m+1]."""
    x, w = z[:2], z[2:]
    drive = sum(wj * dj for wj, dj in zip(w, inputs))
    f = lambda xi: wingrock_rhs(xi, known, 0.0) + np.array([0.0, drive], dtype=object)
    k1 = f(x)
    k2 = f(x + dt / 2 * k1)
    k3 = f(x + dt / 2 * k2)
    k4 = f(x + dt * k3)
    return np.concatenate([x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4), w]).astype(z.dtype)
