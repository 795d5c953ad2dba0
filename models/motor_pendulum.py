"""A pendulum arm on a DC motor: nominal model file and open-loop truth simulator.

Nominal model (``model``; usable as ``skigen diagnose models/motor_pendulum.py …``):

    θ̇ = ω
    ω̇ = −ω₀²·sin θ − b·ω + k·V,     ω₀² = 40 s⁻² (1.0 Hz), b = 0.6 s⁻¹, k = 6 rad/(s²·V)

State arm angle θ (rad from hanging down, role angle) and rate ω (rad/s, role
rate); input the motor voltage V (V), applied open loop (b lumps the bearing
and the motor's back-EMF). Only the encoder angle is measured (``theta_meas``,
1.5 mrad). 200 Hz, RK4. Process noise (torque ripple, air): 10⁻² rad/s per
sample on ω.

:func:`simulate` runs the truth on a voltage signal; the true arm may add one
effect the nominal model leaves out (``effect=``): aerodynamic (quadratic)
drag of the arm, −c·ω|ω|, a magnetic detent torque periodic in the angle,
−A·sin(N·θ) with N = 16 per revolution (not in the catalog), a play
(backlash) between the commanded and the applied voltage, or a delay of the
voltage off the sample grid (a continuous delay of the held voltage). The truth is
integrated with four RK4 sub-steps per sample, its process and measurement
noise drawn exactly as the model states them, so that with ``effect=None``
the nominal model is right.
"""
from dataclasses import dataclass

import casadi as ca
import numpy as np

from skigen import Model

W0SQ, B, K = 40.0, 0.6, 6.0        # s⁻², s⁻¹, rad/(s²·V)
DT = 0.005                         # s (200 Hz)
NOISE_STD = 1.5e-3                 # rad, encoder
RATE_STD = 1e-2                    # rad/s per sample, process noise on ω
DETENT_N = 16                      # detent periods per revolution

EFFECTS = {   # name: (default parameter, what it means)
    "quadratic_drag": (0.15, "aerodynamic drag c (1/rad): −c·ω|ω|"),
    "detent": (2.0, f"detent torque amplitude A (rad/s²): −A·sin({DETENT_N}·θ); not in the catalog"),
    "backlash": (0.15, "play half-width r (V): the motor sees p[k] = clip(p[k−1], V[k] − r, V[k] + r)"),
    "fractional_delay": (2.5, "delay d (samples) of the held voltage: the motor sees V(t − d·dt)"),
}


def build(name: str = "motor_pendulum", *, process_scale: float = 1.0, measurement_scale: float = 1.0) -> Model:
    """The nominal model; ``process_scale``/``measurement_scale`` multiply the declared noise std
    (for recordings diagnosed with mis-declared noise)."""
    model = Model(name, dt=DT, discretization="rk4")
    th = model.state("theta", unit="rad", role="angle", std=0.02)
    om = model.state("omega", unit="rad/s", role="rate", std=0.05, process_std=process_scale * RATE_STD)
    V = model.input("V", unit="V")
    model.dynamics({th: om, om: -W0SQ * ca.sin(th) - B * om + K * V})
    model.output("theta_meas", th, unit="rad", noise_std=measurement_scale * NOISE_STD)
    return model


model = build()


def multisine(duration: float, amplitude, f_lo: float = 0.3, f_hi: float = 3.0, count: int = 12,
              seed: int = 0) -> np.ndarray:
    """Voltage on the sample grid (V): ``count`` sines log-spaced over [f_lo, f_hi] Hz with random
    phases, scaled so that its peak is ``amplitude`` (a number, or a function of t for an envelope)."""
    rng = np.random.default_rng(700 + seed)
    t = np.arange(int(round(duration / DT))) * DT
    f = np.geomspace(f_lo, f_hi, count)
    s = np.sin(2 * np.pi * f[:, None] * t + rng.uniform(0, 2 * np.pi, count)[:, None]).sum(0)
    s /= np.abs(s).max()
    return s * (amplitude(t) if callable(amplitude) else amplitude)


def chirp(duration: float, amplitude: float, f_lo: float = 0.2, f_hi: float = 2.5, period: float = 20.0):
    """Repeated linear chirps from f_lo to f_hi Hz over ``period`` s (V)."""
    t = np.arange(int(round(duration / DT))) * DT
    tau = np.mod(t, period)
    return amplitude * np.sin(2 * np.pi * (f_lo * tau + (f_hi - f_lo) * tau ** 2 / (2 * period)))


def play(V: np.ndarray, r: float) -> np.ndarray:
    """The play (backlash) operator on the sample grid: p[k] = clip(p[k−1], V[k] − r, V[k] + r), p[−1] = 0 (V)."""
    p, prev = np.empty(len(V)), 0.0
    for k, v in enumerate(V):
        prev = p[k] = min(max(prev, v - r), v + r)
    return p


def applied_voltage(V: np.ndarray, effect: str | None, par, substeps: int) -> np.ndarray:
    """(n, substeps): the voltage the motor sees during each integration sub-step: V itself, its play,
    or V held and delayed by ``par`` samples (read at each sub-step's middle; 0 before the start)."""
    n = len(V)
    if effect == "backlash":
        V = play(V, par)
    if effect != "fractional_delay":
        return np.repeat(V[:, None], substeps, axis=1)
    mid = np.arange(n)[:, None] + (np.arange(substeps) + 0.5) / substeps - par
    idx = np.floor(mid).astype(int)
    return np.where(idx >= 0, V[np.clip(idx, 0, n - 1)], 0.0)


@dataclass
class ArmRun:
    """One open-loop run: recorded (t, V, theta_meas) and the truth behind it."""

    t: np.ndarray
    V: np.ndarray            # motor voltage (recorded input)
    theta_meas: np.ndarray   # encoder (recorded output), rad
    theta: np.ndarray        # true angle, rad
    omega: np.ndarray        # true rate, rad/s
    effect_acc: np.ndarray   # angular acceleration the nominal model misses (rad/s²)
    effect: str | None
    parameter: float | None

    def inputs(self) -> dict:
        return {"V": self.V}

    def outputs(self) -> dict:
        return {"theta_meas": self.theta_meas}


def simulate(voltage, *, effect: str | None = None, parameter=None, seed: int = 0, substeps: int = 4,
             noise: bool = True) -> ArmRun:
    """Open-loop run on ``voltage`` (V, one value per sample) with the true arm's ``effect``;
    ``noise=False``: without process and encoder noise."""
    if effect is not None and effect not in EFFECTS:
        raise ValueError(f"unknown effect '{effect}'; choose from {', '.join(EFFECTS)}")
    par = EFFECTS[effect][0] if effect and parameter is None else parameter
    V = np.asarray(voltage, float)
    n = len(V)
    seen = applied_voltage(V, effect, par, substeps)
    rng = np.random.default_rng(seed)
    meas, proc = rng.normal(0.0, NOISE_STD, n), rng.normal(0.0, RATE_STD, n)
    if not noise:
        meas, proc = np.zeros(n), np.zeros(n)

    def extra(th, om):
        if effect == "quadratic_drag":
            return -par * om * abs(om)
        if effect == "detent":
            return -par * np.sin(DETENT_N * th)
        return 0.0

    def f(x, v):
        return np.array([x[1], -W0SQ * np.sin(x[0]) - B * x[1] + K * v + extra(*x)])

    x = np.zeros(2)
    th, om, acc = np.empty(n), np.empty(n), np.empty(n)
    h = DT / substeps
    for k in range(n):
        th[k], om[k] = x[0], x[1]
        acc[k] = extra(*x) + K * (seen[k].mean() - V[k])
        for v in seen[k]:
            k1 = f(x, v)
            k2 = f(x + h / 2 * k1, v)
            k3 = f(x + h / 2 * k2, v)
            k4 = f(x + h * k3, v)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x[1] += proc[k]
    return ArmRun(np.arange(n) * DT, V, th + meas, th, om, acc, effect, None if par is None else float(par))
