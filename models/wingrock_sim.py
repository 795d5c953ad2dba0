"""WingRock truth simulator (paper section 4.1, eqs. 30-32; units are DEGREES).

Plant
-----
    theta_dot = p
    p_dot     = L * delta_applied + Delta(theta, p),   Delta = w* . Phi(theta, p)
    Phi       = [1, theta, p, |theta| p, |p| p, theta^3]
    w*        = [0.8, 0.2314, 0.6918, -0.6245, 0.0095, 0.0214],  L = 3

Only the roll angle is measured: ``phi[k] = theta[k] + N(0, noise_std^2)``.
Sampled at 50 Hz (dt = 0.02 s) for 15 s; the record holds the samples
``t_k = k dt, k = 0 .. round(duration/dt)`` (751 samples for the defaults).
The truth is propagated with ONE classical RK4 step per sample, the applied
input held constant over the sample (zero-order hold) -- exactly the
discretisation used by the identification filters, so the model class is exact.
Initial state ``theta = p = 0``.

Delay variant: ``delta_applied[k] = delta[k - delay]`` (zero before the start);
the recorded ``delta`` column is always the *commanded* input.

Reference
---------
:func:`square_wave_reference`: 0 deg for t < 0.5 s, then a square wave
alternating +5 / -5 deg every 2.5 s (+5 on [0.5, 3), -5 on [3, 5.5), ...).

Controller
----------
Discrete PID at 50 Hz acting on the noisy measurement ``phi``:

    delta = Kp e + Ki/s e - Kd s / (1 + s/N) phi,     e = r - phi

i.e. proportional and integral on the error, derivative on the measurement
(no derivative kick at the reference steps) with a first-order filter,
N = 20 rad/s.  Gains (see :data:`PID_GAINS`): Kp = 2.5, Ki = 0.3, Kd = 1.4.
Both parts are built as continuous python-control transfer functions,
discretised with ``control.sample_system(..., dt, 'tustin')`` and converted to
state space ONCE (:func:`pid_matrices`); the simulation loop then steps the
extracted matrices in plain Python.  The command is saturated to +-20 deg, with
conditional integration (the integrator state is frozen while the command is
saturated and the error pushes further into saturation).

Tuning rationale: the open-loop plant linearised at the origin,
``theta'' = 0.6918 theta' + 0.2314 theta + 3 delta``, has poles at about +0.93
and -0.25 rad/s (unstable).  The gains were picked from a grid search that
minimised the settled tracking error over both delay variants, subject to
phase margins of the discrete loop (ZOH plant, Tustin PID, z^-d delay) of at
least ~12 deg at the origin and 35 deg about the +-5 deg operating point.
Resulting phase margins: d = 0: 46 deg (origin) / 83 deg (theta = 5 deg);
d = 6: 14 deg (origin) / 58 deg (theta = 5 deg) -- the small-angle margin is
limited by the 0.12 s delay acting on an unstable plant, while near +-5 deg the
term -0.6245 |theta| p adds a lot of damping.  Over noise seeds 0..199
(noise 0.1 deg) the closed loop stays within |theta| < 6 deg, overshoots a
10 deg reference step by < 1 deg, and the RMS of ``theta - r`` outside the
first 1.5 s after each reference step is < 0.42 deg (delay 0 and delay 6).
The +-20 deg saturation is touched briefly at the reference steps.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

W_TRUE = np.array([0.8, 0.2314, 0.6918, -0.6245, 0.0095, 0.0214])
L_TRUE = 3.0
BASIS_NAMES = ("1", "theta", "p", "|theta|*p", "|p|*p", "theta^3")

DT = 0.02
DELTA_MAX = 20.0  # deg, command saturation
PID_GAINS = {"Kp": 2.5, "Ki": 0.3, "Kd": 1.4, "N": 20.0}
REF_AMPLITUDE = 5.0  # deg
REF_START = 0.5  # s
REF_HALF_PERIOD = 2.5  # s


def basis(theta, p) -> np.ndarray:
    """Phi(theta, p) = [1, theta, p, |theta| p, |p| p, theta^3], shape (..., 6)."""
    theta = np.asarray(theta, dtype=float)
    p = np.asarray(p, dtype=float)
    theta, p = np.broadcast_arrays(theta, p)
    return np.stack(
        [np.ones_like(theta), theta, p, np.abs(theta) * p, np.abs(p) * p, theta**3],
        axis=-1,
    )


def square_wave_reference(t):
    """Roll reference in degrees: 0 for t < 0.5 s, then +5 / -5 deg alternating
    every 2.5 s (+5 on [0.5, 3.0), -5 on [3.0, 5.5), +5 on [5.5, 8.0), ...).

    Accepts a scalar or an array; returns a float or an array of the same shape.
    """
    t_arr = np.asarray(t, dtype=float)
    k = np.floor((t_arr - REF_START) / REF_HALF_PERIOD + 1e-9)
    r = np.where(t_arr < REF_START - 1e-9, 0.0,
                 np.where(k % 2 == 0, REF_AMPLITUDE, -REF_AMPLITUDE))
    if np.ndim(t) == 0:
        return float(r)
    return r


STAIRCASE_AMPLITUDES = np.array([5.0, -3.0, 4.0, -5.0, 2.0, -4.0, 5.0, -2.0, 3.0, -5.0, 4.0, -3.0])


def staircase_reference(t):
    """A richer roll reference (deg) for the excitation study: 0 for t < 0.2 s, then
    steps every 1.25 s through amplitudes between 2 and 5 deg of both signs."""
    t = np.asarray(t, dtype=float)
    k = np.clip(((t - 0.2) // 1.25).astype(int), 0, len(STAIRCASE_AMPLITUDES) - 1)
    return np.where(t < 0.2, 0.0, STAIRCASE_AMPLITUDES[k])


def pid_matrices(dt: float = DT, Kp: float = PID_GAINS["Kp"], Ki: float = PID_GAINS["Ki"],
                 Kd: float = PID_GAINS["Kd"], N: float = PID_GAINS["N"]):
    """Discrete PID (Tustin) as state-space matrices, built once with python-control.

    Inputs ``[e, phi]`` (error, measurement), output ``delta`` (unsaturated):
        delta = (Kp + Ki/s) e - Kd s/(1 + s/N) phi
    Returns ``(A, B, C, D, i_int)`` with ``x+ = A x + B [e, phi]``,
    ``delta = C x + D [e, phi]``; ``i_int`` is the index of the integrator state.
    """
    import control  # imported lazily: only needed once per simulate() call

    s = control.tf("s")
    pi = control.ss(control.sample_system(Kp + Ki / s, dt, "tustin"))
    der = control.ss(control.sample_system(-Kd * s / (1 + s / N), dt, "tustin"))
    n1, n2 = pi.nstates, der.nstates
    A = np.zeros((n1 + n2, n1 + n2))
    B = np.zeros((n1 + n2, 2))
    A[:n1, :n1] = pi.A
    A[n1:, n1:] = der.A
    B[:n1, 0:1] = pi.B
    B[n1:, 1:2] = der.B
    C = np.hstack([pi.C, der.C]).ravel()
    D = np.array([pi.D[0, 0], der.D[0, 0]])
    return A, B, C, D, 0


_PID_CACHE: dict = {}


def _cached_pid(dt: float):
    key = (float(dt), tuple(sorted(PID_GAINS.items())))
    if key not in _PID_CACHE:
        _PID_CACHE[key] = pid_matrices(dt, **PID_GAINS)
    return _PID_CACHE[key]


def rk4_step(theta: float, p: float, u: float, dt: float, w, gain: float):
    """One classical RK4 step of the WingRock dynamics with input u held constant."""
    w0, w1, w2, w3, w4, w5 = (float(v) for v in w)
    g = float(gain)

    def acc(th, pp):
        return g * u + w0 + w1 * th + w2 * pp + w3 * abs(th) * pp + w4 * abs(pp) * pp + w5 * th**3

    k1t, k1p = p, acc(theta, p)
    th2, p2 = theta + 0.5 * dt * k1t, p + 0.5 * dt * k1p
    k2t, k2p = p2, acc(th2, p2)
    th3, p3 = theta + 0.5 * dt * k2t, p + 0.5 * dt * k2p
    k3t, k3p = p3, acc(th3, p3)
    th4, p4 = theta + dt * k3t, p + dt * k3p
    k4t, k4p = p4, acc(th4, p4)
    return (theta + dt / 6.0 * (k1t + 2 * k2t + 2 * k3t + k4t),
            p + dt / 6.0 * (k1p + 2 * k2p + 2 * k3p + k4p))


@dataclass
class WingRockRun:
    """One closed-loop WingRock record (all angles in degrees, rates in deg/s).

    ``delta`` is the commanded input; the plant sees ``delta_applied``
    (``delta`` delayed by ``delay`` samples, zeros before the start) held over
    ``[t_k, t_{k+1})``.  ``phi`` is the noisy measurement, ``theta`` / ``p`` the
    true states at ``t``.
    """

    t: np.ndarray
    delta: np.ndarray
    phi: np.ndarray
    theta: np.ndarray
    p: np.ndarray
    reference: np.ndarray
    weights: np.ndarray
    gain: float
    delay: int
    noise_std: float
    seed: int
    dt: float = field(default=DT)

    @property
    def delta_applied(self) -> np.ndarray:
        return delayed(self.delta, self.delay)

    @property
    def n(self) -> int:
        return len(self.t)


def delayed(u: np.ndarray, d: int) -> np.ndarray:
    """u shifted by d samples, zeros before the start."""
    u = np.asarray(u, dtype=float)
    if d <= 0:
        return u.copy()
    out = np.zeros_like(u)
    out[d:] = u[:-d]
    return out


def simulate(seed: int = 0, duration: float = 15.0, dt: float = DT, noise_std: float = 0.1,
             weights=W_TRUE, gain: float = L_TRUE, delay: int = 0,
             reference=None) -> WingRockRun:
    """Closed-loop WingRock simulation, deterministic for a given seed.

    At sample k: measure ``phi[k] = theta[k] + v[k]``, compute the PID command
    ``delta[k]`` (saturated to +-20 deg), apply ``delta[k - delay]`` over
    ``[t_k, t_{k+1})`` with one RK4 step.
    """
    delay = int(delay)
    if delay < 0:
        raise ValueError("delay must be >= 0")
    n = int(round(duration / dt)) + 1
    t = np.arange(n) * dt
    rng = np.random.default_rng(seed)
    noise = rng.normal(0.0, noise_std, n) if noise_std > 0 else np.zeros(n)
    ref = (reference or square_wave_reference)(t)
    w = np.asarray(weights, dtype=float).copy()

    A, B, C, D, i_int = _cached_pid(dt)
    # plain-Python copies of the (tiny) controller matrices: faster than numpy per step
    A_l = A.tolist()
    B_l = B.tolist()
    C_l = C.tolist()
    D0, D1 = float(D[0]), float(D[1])
    nx = len(C_l)
    x = [0.0] * nx

    theta = np.empty(n)
    p = np.empty(n)
    phi = np.empty(n)
    delta = np.empty(n)
    th, pr = 0.0, 0.0
    noise_l = noise.tolist()
    ref_l = ref.tolist()
    for k in range(n):
        theta[k] = th
        p[k] = pr
        y = th + noise_l[k]
        phi[k] = y
        e = ref_l[k] - y
        u_unsat = sum(C_l[i] * x[i] for i in range(nx)) + D0 * e + D1 * y
        u = min(max(u_unsat, -DELTA_MAX), DELTA_MAX)
        delta[k] = u
        x_new = [sum(A_l[i][j] * x[j] for j in range(nx)) + B_l[i][0] * e + B_l[i][1] * y
                 for i in range(nx)]
        # conditional integration (anti-windup)
        if u != u_unsat and (u_unsat - u) * e > 0:
            x_new[i_int] = x[i_int]
        x = x_new
        u_app = delta[k - delay] if k >= delay else 0.0
        th, pr = rk4_step(th, pr, u_app, dt, w, gain)

    return WingRockRun(t=t, delta=delta, phi=phi, theta=theta, p=p, reference=ref,
                       weights=w, gain=float(gain), delay=delay, noise_std=float(noise_std),
                       seed=seed, dt=dt)
