"""The MUKF tutorial's quadrotor (LowLevelParticleFilters, "Joint state and
parameter estimation using MUKF"): unknown, time-varying mass and drag.

State z = [v_x, v_y, v_z, x, y, z, θ, φ] with θ = 1/m and φ = θ·C_d, inputs the
thrust forces [F_x, F_y, F_z] (N), measured [x, y, z, v_x, v_y, v_z]:

    v̇ = θ F − φ v∘|v| − g e_z,   ṗ = v,   θ̇ = 0,   φ̇ = 0   (random walks).

θ and φ are ordinary states here (random walks with the tutorial's process
noise), not SKI basis weights. Given the velocities the model is affine in
[x, y, z, θ, φ] in continuous time, but a discretisation may break that:

* ``"euler"`` (the tutorial's MUKF): z[k+1] = z + Ts ż keeps the conditional
  linearity — 3 nonlinear states, 7 sigma points;
* ``"rk4"`` (the tutorial's full UKF): the later RK4 stages evaluate the drag at
  velocities that already contain θ F and φ, so θ and φ enter through θ·φ, |v + Ts θ F/2| …
  and only the positions stay conditionally linear (a MUKF of it would need 11 points);
* ``"exact_position"``: Euler velocity, and the position integrated exactly for
  the acceleration held over the sample, p[k+1] = p + Ts v + Ts²/2 a — still
  affine in [p, θ, φ] given v, and second-order accurate in the position.

Filter settings are the tutorial's: R1 = diag(0.01 ×6, 1e-4, 1e-6) per sample,
R2 = diag(0.1 ×3, 0.05 ×3), initial guess m = 0.9 kg, C_d = 0.008, z = 10 m,
P0 = diag(0.5 ×3, 1 ×3, 0.01, 1e-4).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from skigen import Model
from skigen.recording import Recording

G = 9.81
DT = 0.02
DURATION = 50.0
M_GUESS, CD_GUESS = 0.9, 0.008
MEAS_STD = 0.01            # true measurement noise of the simulation
THRUST_STD = 0.1           # thrust variation around hover (N)
STATES = ("v_x", "v_y", "v_z", "x", "y", "z", "theta", "phi")
INPUTS = ("F_x", "F_y", "F_z")
OUTPUTS = ("x_m", "y_m", "z_m", "v_x_m", "v_y_m", "v_z_m")
DISCRETIZATIONS = ("euler", "rk4", "exact_position")


def build(discretization: str = "euler", name: str | None = None) -> Model:
    """The quadrotor with the tutorial's filter settings, discretised as asked."""
    if discretization not in DISCRETIZATIONS:
        raise ValueError(f"discretization must be one of {DISCRETIZATIONS}, got '{discretization}'")
    kind = "discrete" if discretization == "exact_position" else discretization
    model = Model(name or f"quadrotor_{discretization}", dt=DT, discretization=kind)
    theta0 = 1.0 / M_GUESS
    v = [model.state(n, unit="m/s", role="velocity", std=np.sqrt(0.5), process_std=0.1) for n in STATES[:3]]
    p = [model.state(n, unit="m", role="position", std=1.0, process_std=0.1,
                     initial=10.0 if n == "z" else 0.0) for n in STATES[3:6]]
    theta = model.state("theta", unit="1/kg", initial=theta0, std=0.1, process_std=0.01)
    phi = model.state("phi", unit="1/m", initial=theta0 * CD_GUESS, std=0.01, process_std=1e-3)
    F = [model.input(n, unit="N") for n in INPUTS]
    acc = [theta * F[i] - phi * v[i] * ca.fabs(v[i]) - (G if i == 2 else 0.0) for i in range(3)]
    if discretization == "exact_position":
        eqs = {v[i]: v[i] + DT * acc[i] for i in range(3)}
        eqs.update({p[i]: p[i] + DT * v[i] + DT ** 2 / 2 * acc[i] for i in range(3)})
        eqs.update({theta: theta, phi: phi})
    else:
        eqs = {v[i]: acc[i] for i in range(3)}
        eqs.update({p[i]: v[i] for i in range(3)})
        eqs.update({theta: 0, phi: 0})
    model.dynamics(eqs)
    for i in range(3):
        model.output(OUTPUTS[i], p[i], unit="m", noise_std=np.sqrt(0.1))
    for i in range(3):
        model.output(OUTPUTS[3 + i], v[i], unit="m/s", noise_std=np.sqrt(0.05))
    return model


model = build()                     # Euler: conditionally linear, for the MUKF
model_rk4 = build("rk4")           # RK4: the full UKF of the tutorial


@dataclass(frozen=True)
class Simulation:
    """One simulated flight: t (N,), F (N, 3) thrust, x (N, 8) true state, y (N, 6)
    measurements, mass (N,), cd (N,)."""

    t: np.ndarray
    F: np.ndarray
    x: np.ndarray
    y: np.ndarray
    mass: np.ndarray
    cd: np.ndarray

    def recording(self) -> Recording:
        return Recording("quadrotor simulation", self.t, self.F, self.y, INPUTS, OUTPUTS)


def true_parameters(t):
    """Mass 1 → 0.85 kg linearly until 25 s, then 0.85; C_d 0.01, 0.015 from 25 s."""
    t = np.asarray(t, float)
    return np.where(t < 25, 1.0 - 0.006 * t, 0.85), np.where(t < 25, 0.01, 0.015)


def _rk4(x, F, theta, cd, h):
    def rhs(s):
        v = s[:3]
        a = theta * (F - cd * v * np.abs(v)) - np.array([0.0, 0.0, G])
        return np.concatenate([a, v])
    k1 = rhs(x)
    k2 = rhs(x + h / 2 * k1)
    k3 = rhs(x + h / 2 * k2)
    k4 = rhs(x + h * k3)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def simulate(seed: int = 0, duration: float = DURATION, dt: float = DT) -> Simulation:
    """The tutorial's experiment: hover thrust m_nominal·g + N(0, 0.1²) on each axis, start at
    rest 10 m up, true dynamics one RK4 step per sample with the parameters of the sample
    held, measurements [x, y, z, v] + N(0, 0.01²)."""
    rng = np.random.default_rng(seed)
    t = np.arange(round(duration / dt) + 1) * dt
    N = len(t)
    F = G * 1.0 + THRUST_STD * rng.standard_normal((N, 3))
    mass, cd = true_parameters(t)
    theta = 1.0 / mass
    x = np.zeros((N, 8))
    x[0, :6] = [0, 0, 0, 0, 0, 10]
    for k in range(N - 1):
        x[k + 1, :6] = _rk4(x[k, :6], F[k], theta[k], cd[k], dt)
    x[:, 6], x[:, 7] = theta, theta * cd
    y = np.hstack([x[:, 3:6], x[:, 0:3]]) + MEAS_STD * rng.standard_normal((N, 6))
    return Simulation(t, F, x, y, mass, cd)
