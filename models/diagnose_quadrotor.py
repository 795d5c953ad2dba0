"""A vertical quadrotor for the diagnosis examples: model file and closed-loop simulator.

Nominal model (``model``; usable as ``skigen diagnose models/diagnose_quadrotor.py …``):

    ż = v_z,    v̇_z = T / M − g,      M = 1.2 kg, g = 9.81 m/s²

State altitude z (m, role altitude) and vertical speed v_z (m/s, role
velocity); input the collective thrust T (N) the autopilot commands; outputs a
downward rangefinder (``z_meas``, 5 mm) and the vertical speed of a visual
odometry (``vz_meas``, 0.02 m/s). 100 Hz, RK4; process noise 10⁻³ m/s per
sample on v_z (turbulence).

:func:`simulate` flies the truth: an altitude PID (with thrust feed-forward
M·g) follows a schedule of take-offs, hovers and landings; the real vehicle
gets extra thrust near the ground, T·(1 + K_GE·e^(−z/H_GE)) with K_GE = 0.25,
H_GE = 0.1 m — ground effect, which the nominal model leaves out. It matters
only below about 0.3 m, i.e. during take-off and landing, and the altitude
loop hides it: the tracking error stays within a few millimetres.
"""
from dataclasses import dataclass

import numpy as np

from skigen import Model

M, G = 1.2, 9.81                 # kg, m/s²
DT = 0.01                        # s
Z_NOISE, VZ_NOISE = 0.005, 0.02  # m, m/s
ACC_STD = 1e-3                   # m/s per sample
K_GE, H_GE = 0.25, 0.1           # ground effect: gain, height scale (m)
PID = dict(kp=25.0, ki=10.0, kd=9.0)
T_MAX = 30.0                     # N


def build(name: str = "quad_z") -> Model:
    model = Model(name, dt=DT, discretization="rk4")
    z = model.state("z", unit="m", role="altitude", initial=0.08, std=0.01)
    vz = model.state("vz", unit="m/s", role="velocity", std=0.01, process_std=ACC_STD)
    T = model.input("T", unit="N")
    model.dynamics({z: vz, vz: T / M - G})
    model.output("z_meas", z, unit="m", noise_std=Z_NOISE)
    model.output("vz_meas", vz, unit="m/s", noise_std=VZ_NOISE)
    return model


model = build()


def schedule(duration: float, dt: float = DT, low: float = 0.08, high: float = 1.2, seed: int = 0):
    """Altitude reference: repeated cycles of a short hold just above the pad, a take-off,
    a hover with small steps, a landing. Returns (r, ṙ) on the sample grid."""
    rng = np.random.default_rng(1000 + seed)
    n = int(round(duration / dt))
    r = np.empty(n)
    k = 0
    while k < n:
        top = high + rng.uniform(-0.3, 0.3)
        legs = [(low, 1.0), (top, 2.5), (top + 0.2, 2.0), (top - 0.2, 2.0), (low, 2.5)]
        for level, hold in legs:
            m = int(hold / dt)
            r[k:k + m] = level
            k += m
            if k >= n:
                break
    r = r[:n]
    # a critically damped prefilter (0.35 s) shapes the steps into smooth climbs and descents
    out, x1, x2 = np.empty(n), low, low
    a = dt / 0.35
    for i in range(n):
        x1 += a * (r[i] - x1)
        x2 += a * (x1 - x2)
        out[i] = x2
    return out, np.gradient(out, dt)


@dataclass
class QuadRun:
    t: np.ndarray
    T: np.ndarray          # commanded thrust (recorded input)
    z_meas: np.ndarray
    vz_meas: np.ndarray
    z: np.ndarray
    vz: np.ndarray
    effect_acc: np.ndarray  # acceleration the nominal model misses (m/s²)
    reference: np.ndarray
    ground_effect: bool

    def inputs(self) -> dict:
        return {"T": self.T}

    def outputs(self) -> dict:
        return {"z_meas": self.z_meas, "vz_meas": self.vz_meas}


def simulate(duration: float, *, ground_effect: bool = True, seed: int = 0, substeps: int = 4) -> QuadRun:
    """Closed-loop vertical flight of ``duration`` seconds (see the module docstring)."""
    n = int(round(duration / DT))
    t = np.arange(n) * DT
    r, rdot = schedule(duration, seed=seed)
    rng = np.random.default_rng(seed)
    nz, nv, w = rng.normal(0, Z_NOISE, n), rng.normal(0, VZ_NOISE, n), rng.normal(0, ACC_STD, n)

    def acc(z, thrust):
        gain = 1 + K_GE * np.exp(-z / H_GE) if ground_effect else 1.0
        return thrust * gain / M - G

    x = np.array([0.08, 0.0])
    out = {k: np.empty(n) for k in ("T", "zm", "vm", "z", "vz", "eff")}
    integ = 0.0
    h = DT / substeps
    for k in range(n):
        zm, vm = x[0] + nz[k], x[1] + nv[k]
        e = r[k] - zm
        a_cmd = PID["kp"] * e + PID["ki"] * integ + PID["kd"] * (rdot[k] - vm)
        u_raw = M * (G + a_cmd)
        u = float(np.clip(u_raw, 0.0, T_MAX))
        if u == u_raw:
            integ += e * DT
        out["T"][k], out["zm"][k], out["vm"][k], out["z"][k], out["vz"][k] = u, zm, vm, x[0], x[1]
        out["eff"][k] = acc(x[0], u) - (u / M - G)
        f = lambda s: np.array([s[1], acc(s[0], u)])
        for _ in range(substeps):
            k1 = f(x)
            k2 = f(x + h / 2 * k1)
            k3 = f(x + h / 2 * k2)
            k4 = f(x + h * k3)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x[1] += w[k]
    return QuadRun(t, out["T"], out["zm"], out["vm"], out["z"], out["vz"], out["eff"], r, ground_effect)
