"""The quadrotor spiral model written by hand in NumPy for the reference filters.

Independent of CasADi and of skigen's declaration (complex-step safe): z =
[p (3), v (3), w (8)], u = [qw, qx, qy, qz, pwm]; v̇ = Σ wᵢ φᵢ + g with the
thrust polynomial along the body z axis and the two drag directions (linear
rotor drag in the rotor plane, quadratic drag along −v).
"""
import numpy as np

G = 9.81
DT = 0.02
PWM_CENTER, PWM_SCALE = 1500.0, 10.0


def _accel(v, w, u):
    qw, qx, qy, qz, pwm = u
    b3 = np.array([2 * (qx * qz + qw * qy), 2 * (qy * qz - qw * qx), 1 - 2 * (qx ** 2 + qy ** 2)])
    s = (pwm - PWM_CENTER) / PWM_SCALE
    speed = np.sqrt(v @ v + 1e-12)
    thrust = sum(w[k] * s ** k for k in range(6))
    rotor_plane_v = v - b3 * (b3 @ v)
    return thrust * b3 - w[6] * rotor_plane_v - w[7] * v * speed + np.array([0.0, 0.0, -G])


def spiral_f(z, u, dt=DT):
    """One RK4 step of the augmented spiral state."""
    w = z[6:]
    f = lambda x: np.concatenate([x[3:], _accel(x[3:], w, u)])
    x = z[:6]
    k1 = f(x)
    k2 = f(x + dt / 2 * k1)
    k3 = f(x + dt / 2 * k2)
    k4 = f(x + dt * k3)
    return np.concatenate([x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4), w])


def spiral_h(z):
    return z[:3]
