"""Two cascaded water tanks fed by a pump: nominal model file and open-loop truth simulator.

Nominal model (``model``; usable as ``skigen diagnose models/two_tanks.py …``):

    ḣ₁ = (k_p·u − a₁·√(2g·h₁)) / A₁
    ḣ₂ = (a₁·√(2g·h₁) − a₂·√(2g·h₂)) / A₂

The pump (command u, V) fills the upper tank (level h₁, m); it drains through
an orifice a₁ into the lower tank (level h₂, m), which drains through a₂
(Torricelli outflow). A₁ = 0.012 m², A₂ = 0.018 m², a₁ = 5·10⁻⁵ m²,
a₂ = 6·10⁻⁵ m², k_p = 2·10⁻⁵ m³/(s·V). Both levels are measured (a pressure
sensor on the upper tank, ``h1_meas``, 2 mm; an ultrasonic one on the lower,
``h2_meas``, 2.5 mm). 10 Hz, RK4. Process noise (inflow turbulence, sloshing):
3·10⁻⁴ m per sample on each level. The levels stay above 2 cm for pump
commands above 2 V (√h is not differentiable at an empty tank).

:func:`simulate` runs the truth open loop on a pump command; the true plant may
add one effect the nominal model leaves out (``effect=``): the upper tank
overflows at its rim (a physical limit: h₁ cannot pass H, the excess spills to
the sump), the upper level sensor's range ends (it reads min(h₁, B): the level
itself goes on) or a float valve refills the lower tank from the mains with
hysteresis (opens below one level, closes above another: not in the catalog).
The truth is integrated with four RK4 sub-steps per sample, its process and
measurement noise drawn exactly as the model states them, so that with
``effect=None`` the nominal model is right.
"""
from dataclasses import dataclass

import casadi as ca
import numpy as np

from skigen import Model

A1, A2 = 0.012, 0.018              # m², tank cross-sections
a1, a2 = 5e-5, 6e-5                # m², orifices
KP = 2e-5                          # m³/(s·V), pump
G = 9.81                           # m/s²
DT = 0.1                           # s (10 Hz)
H_NOISE = {"h1_meas": 2e-3, "h2_meas": 2.5e-3}   # m
LEVEL_STD = {"h1": 3e-4, "h2": 3e-4}             # m per sample, process noise
INITIAL = (0.10, 0.07)             # m: levels at start (near equilibrium for u = 3.5 V)

EFFECTS = {   # name: (default parameter, what it means)
    "overflow": (0.30, "rim height H (m) of the upper tank: h₁ ≤ H, the excess spills to the sump"),
    "sensor_saturation": (0.32, "range end B (m) of the upper level sensor: it reads min(h₁, B) + noise"),
    "pump_limit": (5.0, "the pump delivers at most this command L (V): the plant sees min(u, L)"),
    "float_valve": (4e-5, "mains inflow q_v (m³/s) into the lower tank while a float valve is open: it "
                          "opens when h₂ < 0.08 m and closes when h₂ > 0.11 m; not in the catalog"),
    "orifice": (1.2, "the upper orifice is this many times the declared a₁: one number of the model, written "
                     "in both levels' equations (what drains the upper tank fills the lower)"),
}
VALVE_LEVELS = (0.08, 0.11)        # m: float valve opens below the first, closes above the second


def build(name: str = "two_tanks", *, process_scale: float = 1.0, measurement_scale: float = 1.0,
          parameters: dict | None = None) -> Model:
    """The nominal model; ``process_scale``/``measurement_scale`` multiply the declared noise std
    (for recordings diagnosed with mis-declared noise); ``parameters``: {"kp", "a1"} declared as
    parameters at these values (a grey box to refit)."""
    model = Model(name, dt=DT, discretization="rk4")
    h1 = model.state("h1", unit="m", role="position", initial=INITIAL[0], std=0.01,
                     process_std=process_scale * LEVEL_STD["h1"])
    h2 = model.state("h2", unit="m", role="position", initial=INITIAL[1], std=0.01,
                     process_std=process_scale * LEVEL_STD["h2"])
    u = model.input("u", unit="V")
    kp, orifice = ((model.parameter("kp", parameters["kp"], unit="m^3/(s V)", bounds=(0, 1)),
                    model.parameter("a1", parameters["a1"], unit="m^2", bounds=(0, 1)))
                   if parameters else (KP, a1))
    q1 = orifice * np.sqrt(2 * G) * ca.sqrt(h1)
    q2 = a2 * np.sqrt(2 * G) * ca.sqrt(h2)
    model.dynamics({h1: (kp * u - q1) / A1, h2: (q1 - q2) / A2})
    model.output("h1_meas", h1, unit="m", noise_std=measurement_scale * H_NOISE["h1_meas"])
    model.output("h2_meas", h2, unit="m", noise_std=measurement_scale * H_NOISE["h2_meas"])
    return model


model = build()


def nominal_rates(h1: float, h2: float, u: float) -> np.ndarray:
    """(ḣ₁, ḣ₂) of the nominal model (m/s)."""
    q1 = a1 * np.sqrt(2 * G * max(h1, 0.0))
    q2 = a2 * np.sqrt(2 * G * max(h2, 0.0))
    return np.array([(KP * u - q1) / A1, (q1 - q2) / A2])


def pump_steps(duration: float, levels=(2.5, 6.0), hold=(15.0, 45.0), seed: int = 0, bursts=()):
    """A pump command on the sample grid (V): random levels in ``levels`` held a random time in
    ``hold`` (s); ``bursts``: (t0, t1, volts) spans where it is overridden (e.g. to overflow)."""
    rng = np.random.default_rng(500 + seed)
    n = int(round(duration / DT))
    u = np.empty(n)
    k = 0
    while k < n:
        m = int(rng.uniform(*hold) / DT)
        u[k:k + m] = rng.uniform(*levels)
        k += m
    t = np.arange(n) * DT
    for t0, t1, volts in bursts:
        u[(t >= t0) & (t < t1)] = volts
    return u


@dataclass
class TankRun:
    """One open-loop run: recorded (t, u, h1_meas, h2_meas) and the truth behind it."""

    t: np.ndarray
    u: np.ndarray            # pump command (recorded input), V
    h1_meas: np.ndarray      # m
    h2_meas: np.ndarray      # m
    h1: np.ndarray           # true levels, m
    h2: np.ndarray
    effect_rate: np.ndarray  # (N, 2) level rates the nominal model misses (m/s): truth − nominal
    valve: np.ndarray        # True while the float valve is open
    effect: str | None
    parameter: float | None

    def inputs(self) -> dict:
        return {"u": self.u}

    def outputs(self) -> dict:
        return {"h1_meas": self.h1_meas, "h2_meas": self.h2_meas}


def simulate(pump, *, effect: str | None = None, parameter=None, seed: int = 0, substeps: int = 4) -> TankRun:
    """Open-loop run on the pump command ``pump`` (V, one value per sample) with the true
    plant's ``effect`` (see EFFECTS)."""
    if effect is not None and effect not in EFFECTS:
        raise ValueError(f"unknown effect '{effect}'; choose from {', '.join(EFFECTS)}")
    par = EFFECTS[effect][0] if effect and parameter is None else parameter
    u_all = np.asarray(pump, float)
    n = len(u_all)
    rng = np.random.default_rng(seed)
    w = np.column_stack([rng.normal(0.0, LEVEL_STD[s], n) for s in ("h1", "h2")])
    v = np.column_stack([rng.normal(0.0, H_NOISE[o], n) for o in ("h1_meas", "h2_meas")])
    rim = par if effect == "overflow" else np.inf

    def rates(x, u, valve_open):
        r = nominal_rates(x[0], x[1], u)
        if x[0] >= rim:
            r[0] = min(r[0], 0.0)                     # at the rim the inflow spills over
        if valve_open:
            r[1] += par / A2
        if effect == "orifice":
            extra = (par - 1.0) * a1 * np.sqrt(2 * G * max(x[0], 0.0))
            r += (-extra / A1, extra / A2)
        return r

    x = np.array(INITIAL, float)
    valve = False
    out = {k: np.empty(n) for k in ("h1", "h2", "valve")}
    missing = np.empty((n, 2))
    h = DT / substeps
    for k in range(n):
        u = min(u_all[k], par) if effect == "pump_limit" else u_all[k]
        if effect == "float_valve":
            valve = (x[1] < VALVE_LEVELS[0]) or (valve and x[1] <= VALVE_LEVELS[1])
        out["h1"][k], out["h2"][k], out["valve"][k] = x[0], x[1], valve
        missing[k] = rates(x, u, valve) - nominal_rates(x[0], x[1], u_all[k])
        for _ in range(substeps):
            k1 = rates(x, u, valve)
            k2 = rates(x + h / 2 * k1, u, valve)
            k3 = rates(x + h / 2 * k2, u, valve)
            k4 = rates(x + h * k3, u, valve)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            x[0] = min(x[0], rim)
        x = x + w[k]
        x[0] = min(x[0], rim)
    seen = np.minimum(out["h1"], par) if effect == "sensor_saturation" else out["h1"]
    y = np.column_stack([seen, out["h2"]]) + v
    return TankRun(np.arange(n) * DT, u_all, y[:, 0], y[:, 1], out["h1"], out["h2"], missing,
                   out["valve"].astype(bool), effect, None if par is None else float(par))
