"""An inverted pendulum on a cart: open-loop unstable, flown in closed loop.

Nominal model (``model``; usable as ``skigen diagnose models/cart_pole.py …``):

    ẋ = v,   v̇ = (F − B·v + m·L·ω²·sin θ − m·g·sin θ·cos θ) / (M + m·sin²θ)
    θ̇ = ω,   ω̇ = (g·sin θ − v̇·cos θ) / L

θ = 0 upright; M = 1 kg, m = 0.2 kg, L = 0.5 m, B = 0.5 N s/m. Input the force F (N); outputs the
cart position ``x_meas`` (1 mm) and the angle ``th_meas`` (2 mrad). 100 Hz, RK4. Upright the
pendulum falls at √((M + m)·g / (M·L)) ≈ 4.9 s⁻¹: no free run of it follows a recording for
long. ``build(parameters=...)`` declares L, m and B as parameters at the given values.

:func:`simulate` balances the truth with an LQR on the measured states (velocities by filtered
differences) while the cart follows position steps and a multisine is added to the force; four
RK4 sub-steps per sample, process noise as the model declares it, so that with no ``delay`` the
nominal is right; ``delay``: the force reaches the cart this many samples late; ``friction``: a
Coulomb friction on the cart; ``cart``: a cart heavier or lighter than the model's.
"""
from dataclasses import dataclass

import casadi as ca
import numpy as np
from scipy.linalg import expm, solve_discrete_are

from skigen import Model

G, M, MP, L, B = 9.81, 1.0, 0.2, 0.5, 0.5   # m/s², kg, kg, m, N s/m
DT = 0.01                                   # s (100 Hz)
V_STD, W_STD = 1e-3, 2e-3                   # process noise per sample (m/s, rad/s)
X_NOISE, TH_NOISE = 1e-3, 2e-3              # sensors (m, rad)
FRICTION_WIDTH = 0.01                       # m/s: the smoothing of the cart's Coulomb friction


def build(name: str = "cart_pole", parameters: dict | None = None) -> Model:
    """The nominal model; ``parameters``: {"L", "m", "B"} declared as parameters at these values."""
    model = Model(name, dt=DT, discretization="rk4")
    x = model.state("x", unit="m", role="position", std=0.05, process_std=0.0)
    v = model.state("v", unit="m/s", role="velocity", std=0.05, process_std=V_STD)
    th = model.state("th", unit="rad", role="angle", std=0.05, process_std=0.0)
    w = model.state("w", unit="rad/s", role="rate", std=0.05, process_std=W_STD)
    F = model.input("F", unit="N")
    p = parameters or {}
    length = model.parameter("L", p["L"], unit="m", std=0.2, bounds=(0.05, 5.0)) if "L" in p else L
    mass = model.parameter("m", p["m"], unit="kg", std=0.1, bounds=(0.01, 5.0)) if "m" in p else MP
    damping = model.parameter("B", p["B"], unit="N s/m", std=0.3, bounds=(0.0, 10.0)) if "B" in p else B
    sn, cs = ca.sin(th), ca.cos(th)
    vdot = (F - damping * v + mass * length * w ** 2 * sn - mass * G * sn * cs) / (M + mass * sn ** 2)
    model.dynamics({x: v, v: vdot, th: w, w: (G * sn - vdot * cs) / length})
    model.output("x_meas", x, unit="m", noise_std=X_NOISE)
    model.output("th_meas", th, unit="rad", noise_std=TH_NOISE)
    return model


model = build()


def _lqr() -> np.ndarray:
    """Discrete LQR gain on (x − r, v, θ, ω) for the upright linearisation."""
    A = np.array([[0, 1, 0, 0], [0, -B / M, -MP * G / M, 0], [0, 0, 0, 1],
                  [0, B / (M * L), (M + MP) * G / (M * L), 0]])
    Bc = np.array([[0], [1 / M], [0], [-1 / (M * L)]])
    E = expm(np.block([[A, Bc], [np.zeros((1, 5))]]) * DT)
    Ad, Bd = E[:4, :4], E[:4, 4:]
    Q, R = np.diag([20.0, 1.0, 50.0, 1.0]), np.array([[0.1]])
    P = solve_discrete_are(Ad, Bd, Q, R)
    return np.linalg.solve(R + Bd.T @ P @ Bd, Bd.T @ P @ Ad).ravel()


def _rate(s: np.ndarray, force: float, friction: float = 0.0, cart: float = M) -> np.ndarray:
    x, v, th, w = s
    sn, cs = np.sin(th), np.cos(th)
    force = force - friction * np.tanh(v / FRICTION_WIDTH)
    vdot = (force - B * v + MP * L * w ** 2 * sn - MP * G * sn * cs) / (cart + MP * sn ** 2)
    return np.array([v, vdot, w, (G * sn - vdot * cs) / L])


@dataclass
class CartPoleRun:
    """One balancing run: recorded (t, F, x_meas, th_meas) and the true angle."""

    t: np.ndarray
    F: np.ndarray            # applied force command (recorded input), N
    x_meas: np.ndarray       # m
    th_meas: np.ndarray      # rad
    th: np.ndarray           # true angle, rad

    def columns(self) -> dict:
        return {"t": self.t, "F": self.F, "x_meas": self.x_meas, "th_meas": self.th_meas}


def simulate(seconds: float = 20.0, *, seed: int = 0, delay: int = 0, friction: float = 0.0, cart: float = M,
             substeps: int = 4) -> CartPoleRun:
    """The balancing run (see the module docstring); ``friction``: a Coulomb friction on the cart
    (N, smoothed as tanh(v / FRICTION_WIDTH)); ``cart``: the true cart mass (kg, the model's M = 1)."""
    rng = np.random.default_rng(seed)
    n, K, h = int(round(seconds / DT)), _lqr(), DT / substeps
    t = np.arange(n) * DT
    steps = np.array([0.0, 0.3, -0.2, 0.4, -0.3, 0.1, 0.0])[np.minimum((t // 3.5).astype(int), 6)]
    ref = np.zeros(n)
    for k in range(1, n):
        ref[k] = ref[k - 1] + DT / 0.3 * (steps[k] - ref[k - 1])
    freq, phase = np.linspace(0.2, 4.0, 10), rng.uniform(0, 2 * np.pi, 10)
    dither = 0.4 * np.sin(2 * np.pi * freq[None, :] * t[:, None] + phase[None, :]).sum(axis=1)
    s, vf, wf = np.array([0.0, 0.0, 0.03, 0.0]), 0.0, 0.0
    F, xm, thm, th = (np.empty(n) for _ in range(4))
    for k in range(n):
        th[k] = s[2]
        xm[k], thm[k] = s[0] + rng.normal(0, X_NOISE), s[2] + rng.normal(0, TH_NOISE)
        if k:
            a = DT / (0.02 + DT)
            vf += a * ((xm[k] - xm[k - 1]) / DT - vf)
            wf += a * ((thm[k] - thm[k - 1]) / DT - wf)
        F[k] = float(np.clip(-K @ [xm[k] - ref[k], vf, thm[k], wf] + dither[k], -40, 40))
        force = F[k - delay] if k >= delay else 0.0
        for _ in range(substeps):
            k1 = _rate(s, force, friction, cart)
            k2 = _rate(s + h / 2 * k1, force, friction, cart)
            k3 = _rate(s + h / 2 * k2, force, friction, cart)
            s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + _rate(s + h * k3, force, friction, cart))
        s[1] += rng.normal(0, V_STD)
        s[3] += rng.normal(0, W_STD)
    return CartPoleRun(t, F, xm, thm, th)
