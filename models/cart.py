"""A cart on a rail: mass, spring and damper, pushed by a motor under a PID position loop.

Nominal model (what the engineer believes, ``model`` below):

    ṗ = v
    v̇ = (F − B v − K p) / M,     M = 1 kg, B = 0.5 N·s/m, K = 2 N/m

State position p (m, role position) and velocity v (m/s, role velocity); input
the commanded motor force F (N); only the encoder position is measured
(output ``p_meas``, noise 1 mm). 100 Hz, RK4. Process noise: white
acceleration, 3·10⁻⁴ m/s per sample on v.

:func:`simulate` flies the truth in closed loop: a PID on the measured
position tracks a reference; the true plant may add one effect the nominal
model leaves out (``effect=``): Coulomb friction, a hardening (cubic) spring,
a constant force bias, a motor dead zone, a first-order motor lag, an input
delay, or a motor cogging force (periodic in position: not in the catalog,
for user-supplied candidates). The truth is integrated with four RK4 sub-steps per sample, its
process and measurement noise drawn exactly as the model states them, so
that with ``effect=None`` the nominal model is right.
"""
from dataclasses import dataclass

import numpy as np

from skigen import Model

M, B, K = 1.0, 0.5, 2.0            # kg, N·s/m, N/m
DT = 0.01                          # s (100 Hz)
NOISE_STD = 1e-3                   # m, encoder noise
ACC_STD = 3e-4                     # m/s per sample, process noise on v
F_MAX = 30.0                       # N, controller output limit
PID = dict(kp=60.0, ki=40.0, kd=14.0, tf=0.01)   # N/m, N/(m·s), N·s/m, s (derivative filter)

EFFECTS = {   # name: (default parameter, what it means)
    "coulomb_friction": (1.0, "friction force F_c (N): −F_c·sign(v)"),
    "cubic_stiffness": (40.0, "hardening spring k₃ (N/m³): −k₃·p³"),
    "bias": (0.08, "constant force (N), e.g. a tilted rail"),
    "dead_zone": (0.6, "motor dead zone half-width (N)"),
    "actuator_lag": (0.04, "motor time constant (s)"),
    "input_delay": (3, "input delay (samples)"),
    "cogging": (0.2, "motor cogging force amplitude A (N): −A·sin(2π p / 0.05 m); not in the catalog"),
}
COGGING_PITCH = 0.05               # m


def build(name: str = "cart") -> Model:
    model = Model(name, dt=DT, discretization="rk4")
    p = model.state("p", unit="m", role="position", std=0.01, process_std=0.0)
    v = model.state("v", unit="m/s", role="velocity", std=0.01, process_std=ACC_STD)
    F = model.input("F", unit="N")
    model.dynamics({p: v, v: (F - B * v - K * p) / M})
    model.output("p_meas", p, unit="m", noise_std=NOISE_STD)
    return model


model = build()


def steps(levels, hold: float, t0: float = 0.0):
    """A reference holding each of ``levels`` (m) for ``hold`` seconds, from t0, then repeating."""
    levels = np.asarray(levels, float)

    def ref(t):
        k = np.floor((np.asarray(t) - t0) / hold).astype(int) % len(levels)
        return np.where(np.asarray(t) < t0, 0.0, levels[k])
    return ref


def smooth(ref, tau: float = 0.15, dt: float = DT):
    """The reference through a critically damped second-order prefilter (time constant tau),
    as a trajectory generator would shape it; returns r(t) on the sample grid."""
    def out(t):
        r = ref(t)
        x = np.zeros(2)
        y = np.empty_like(r)
        a = dt / tau
        for k, rk in enumerate(r):
            x[0] += a * (rk - x[0])
            x[1] += a * (x[0] - x[1])
            y[k] = x[1]
        return y
    return out


@dataclass
class CartRun:
    """One closed-loop run: recorded (t, F, p_meas) and the truth behind it."""

    t: np.ndarray
    F: np.ndarray            # commanded force (recorded input)
    p_meas: np.ndarray       # encoder (recorded output)
    p: np.ndarray            # true position
    v: np.ndarray            # true velocity
    force: np.ndarray        # force the cart actually felt from the motor
    effect_acc: np.ndarray   # acceleration of the hidden effect (m/s²): truth − nominal
    reference: np.ndarray
    effect: str | None
    parameter: float | None

    def inputs(self) -> dict:
        return {"F": self.F}

    def outputs(self) -> dict:
        return {"p_meas": self.p_meas}


def simulate(reference, duration: float, *, effect: str | None = None, parameter=None,
             seed: int = 0, substeps: int = 4) -> CartRun:
    """Closed-loop run of ``duration`` seconds tracking ``reference`` (a function of t, or an
    array on the sample grid) with the true plant's ``effect`` (see EFFECTS)."""
    if effect is not None and effect not in EFFECTS:
        raise ValueError(f"unknown effect '{effect}'; choose from {', '.join(EFFECTS)}")
    par = EFFECTS[effect][0] if effect and parameter is None else parameter
    n = int(round(duration / DT))
    t = np.arange(n) * DT
    r = np.asarray(reference(t) if callable(reference) else reference, float)
    rng = np.random.default_rng(seed)
    meas_noise = rng.normal(0.0, NOISE_STD, n)
    proc_noise = rng.normal(0.0, ACC_STD, n)
    kp, ki, kd, tf = PID["kp"], PID["ki"], PID["kd"], PID["tf"]
    delay = int(par) if effect == "input_delay" else 0

    def motor(u, act):
        """Force the motor applies for command u (act: lag state)."""
        if effect == "dead_zone":
            return np.sign(u) * max(abs(u) - par, 0.0)
        if effect == "actuator_lag":
            return act
        return u

    def rhs(x, u):
        p, v, act = x
        f = motor(u, act)
        a = (f - B * v - K * p) / M
        extra = 0.0
        if effect == "coulomb_friction":
            extra = -par * np.tanh(v / 2e-3) / M
        elif effect == "cubic_stiffness":
            extra = -par * p ** 3 / M
        elif effect == "bias":
            extra = par / M
        elif effect == "cogging":
            extra = -par * np.sin(2 * np.pi * p / COGGING_PITCH) / M
        dact = (u - act) / par if effect == "actuator_lag" else 0.0
        return np.array([v, a + extra, dact]), f, extra

    x = np.zeros(3)
    out = {k: np.empty(n) for k in ("F", "y", "p", "v", "force", "extra")}
    integ, dfilt, y_prev = 0.0, 0.0, 0.0
    history = [0.0] * (delay + 1)
    h = DT / substeps
    for k in range(n):
        y = x[0] + meas_noise[k]
        e = r[k] - y
        dfilt += (DT / (tf + DT)) * ((y - y_prev) / DT - dfilt) if k else 0.0
        y_prev = y
        u_raw = kp * e + ki * integ - kd * dfilt
        u = float(np.clip(u_raw, -F_MAX, F_MAX))
        if u == u_raw or u_raw * e < 0:
            integ += e * DT
        history = [u] + history[:-1]
        u_app = history[-1]
        out["F"][k], out["y"][k], out["p"][k], out["v"][k] = u, y, x[0], x[1]
        _, out["force"][k], out["extra"][k] = rhs(x, u_app)
        for _ in range(substeps):
            k1, _, _ = rhs(x, u_app)
            k2, _, _ = rhs(x + h / 2 * k1, u_app)
            k3, _, _ = rhs(x + h / 2 * k2, u_app)
            k4, _, _ = rhs(x + h * k3, u_app)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x[1] += proc_noise[k]
    # the hidden effect as an acceleration: truth minus what the nominal model predicts
    effect_acc = out["extra"] + (out["force"] - out["F"]) / M
    return CartRun(t, out["F"], out["y"], out["p"], out["v"], out["force"], effect_acc, r,
                   effect, None if par is None else float(par))
