"""Short-period pitch dynamics of a fixed-wing aircraft: nominal model file and closed-loop truth.

Nominal model (``model``; usable as ``skigen diagnose models/short_period.py …``):

    α̇ = Zα·α + q + Zδ·δe
    q̇ = Mα·α + Mq·q + Mδ·δe,    Zα = −1.2 s⁻¹, Zδ = −0.1 s⁻¹, Mα = −8 s⁻², Mq = −2.5 s⁻¹, Mδ = −12 s⁻²

States angle of attack α (rad) and pitch rate q (rad/s); input the commanded elevator δe (rad): a
pilot's 3-2-1-1 and doublet sequence, small in the first half of the flight and large in the
second, plus a pitch damper δe += 0.1·q_gyro. Outputs: the rate gyro ``q_gyro`` (5 mrad/s, every
sample) and the vane ``alpha_vane`` (10 mrad, every other sample: blank cells between). 100 Hz,
RK4. Turbulence: 3·10⁻⁴ rad on α and 10⁻³ rad/s on q per sample. ``build(parameters=...)``
declares Mα, Mq and Mδ as parameters at the given values (a grey box to refit).

:func:`simulate` flies the truth (ten RK4 sub-steps per sample, the elevator held over the
sample, noise drawn as the model states it, so that with ``effect=None`` the nominal is right);
it may add one effect the nominal leaves out: a pitch break near stall, +M3·α³, felt only in the
large manoeuvres, an elevator that follows its command late (a delay of whole samples), or a
lift offset on α̇.
"""
from dataclasses import dataclass

import numpy as np

from skigen import Model

ZA, ZDE, MA, MQ, MDE = -1.2, -0.1, -8.0, -2.5, -12.0
DT = 0.01                          # s (100 Hz)
Q_NOISE, ALPHA_NOISE = 5e-3, 1e-2  # gyro (rad/s), vane (rad)
ALPHA_STD, Q_STD = 3e-4, 1e-3      # turbulence per sample (rad, rad/s)
DAMPER = 0.1                       # pitch damper gain (rad of elevator per rad/s)

EFFECTS = {   # name: (default parameter, what it means)
    "cubic_moment": (80.0, "pitch break M3 (s⁻² rad⁻²): q̇ += M3·α³"),
    "elevator_delay": (3, "the elevator follows its command this many samples late"),
    "lift_offset": (0.02, "a lift the nominal leaves out (rad/s): α̇ += b"),
}


def build(name: str = "short_period", parameters: dict | None = None) -> Model:
    """The nominal model; ``parameters``: {"Ma", "Mq", "Mde"} declared as parameters at these values."""
    model = Model(name, dt=DT, discretization="rk4")
    alpha = model.state("alpha", unit="rad", role="angle", std=0.05, process_std=ALPHA_STD)
    q = model.state("q", unit="rad/s", role="rate", std=0.1, process_std=Q_STD)
    de = model.input("de", unit="rad")
    Ma, Mq, Mde = ((model.parameter("Ma", parameters["Ma"], unit="1/s^2"),
                    model.parameter("Mq", parameters["Mq"], unit="1/s"),
                    model.parameter("Mde", parameters["Mde"], unit="1/s^2"))
                   if parameters else (MA, MQ, MDE))
    model.dynamics({alpha: ZA * alpha + q + ZDE * de, q: Ma * alpha + Mq * q + Mde * de})
    model.output("q_gyro", q, unit="rad/s", noise_std=Q_NOISE)
    model.output("alpha_vane", alpha, unit="rad", noise_std=ALPHA_NOISE)
    return model


model = build()


def pilot(seconds: float, seed: int = 0, small: float = 0.03, large: float = 0.15) -> np.ndarray:
    """The pilot's elevator (rad) on the sample grid: 3-2-1-1 sequences (0.3 s unit) and doublets
    (0.5 s halves) of alternating sign every 1.5–2.5 s, peaking at ``small`` in the first half of
    the flight and at ``large`` in the second."""
    rng = np.random.default_rng(500 + seed)
    t = np.arange(int(round(seconds / DT))) * DT
    de, start, k = np.zeros(len(t)), 1.0, 0
    while start < seconds - 3.5:
        size = (small if start < seconds / 2 else large) * rng.uniform(0.7, 1.0) * (-1) ** k
        pattern = [(0.5, 1), (0.5, -1)] if k % 3 == 2 else [(0.9, 1), (0.6, -1), (0.3, 1), (0.3, -1)]
        for width, sign in pattern:
            de[(t >= start) & (t < start + width)] = size * sign
            start += width
        start += rng.uniform(1.5, 2.5)
        k += 1
    return de


@dataclass
class PitchRun:
    """One flight: recorded (t, de, q_gyro, alpha_vane) and the truth behind it."""

    t: np.ndarray
    de: np.ndarray           # commanded elevator (recorded input), rad
    q_gyro: np.ndarray       # rad/s
    alpha_vane: np.ndarray   # rad, NaN on every other sample
    alpha: np.ndarray        # true angle of attack, rad
    q: np.ndarray            # true pitch rate, rad/s
    effect_acc: np.ndarray   # pitch acceleration the nominal model misses (rad/s²)

    def inputs(self) -> dict:
        return {"de": self.de}

    def outputs(self) -> dict:
        return {"q_gyro": self.q_gyro, "alpha_vane": self.alpha_vane}


def simulate(seconds: float = 60.0, *, effect: str | None = None, parameter=None, seed: int = 0,
             substeps: int = 10, large: float = 0.15) -> PitchRun:
    """Closed-loop flight (pilot plus pitch damper on the gyro) with the true aircraft's ``effect``;
    ``large``: the pilot's elevator in the second half (rad)."""
    if effect is not None and effect not in EFFECTS:
        raise ValueError(f"unknown effect '{effect}'; choose from {', '.join(EFFECTS)}")
    par = EFFECTS[effect][0] if effect and parameter is None else parameter
    stick = pilot(seconds, seed, large=large)
    n = len(stick)
    lag = int(par) if effect == "elevator_delay" else 0
    m3 = float(par) if effect == "cubic_moment" else 0.0
    lift = float(par) if effect == "lift_offset" else 0.0
    rng = np.random.default_rng(seed)
    gyro_noise, vane_noise = rng.normal(0.0, Q_NOISE, n), rng.normal(0.0, ALPHA_NOISE, n)
    turbulence = rng.normal(0.0, 1.0, (n, 2)) * [ALPHA_STD, Q_STD]

    def f(x, d):
        a, q = x
        return np.array([ZA * a + q + ZDE * d + lift, MA * a + MQ * q + MDE * d + m3 * a ** 3])

    x, h = np.zeros(2), DT / substeps
    de, alpha, q, acc, gyro = (np.empty(n) for _ in range(5))
    for k in range(n):
        alpha[k], q[k] = x
        gyro[k] = q[k] + gyro_noise[k]
        de[k] = stick[k] + DAMPER * gyro[k]
        seen = de[k - lag] if k >= lag else 0.0
        acc[k] = m3 * x[0] ** 3 + MDE * (seen - de[k])
        for _ in range(substeps):
            k1 = f(x, seen)
            k2 = f(x + h / 2 * k1, seen)
            k3 = f(x + h / 2 * k2, seen)
            k4 = f(x + h * k3, seen)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x = x + turbulence[k]
    vane = alpha + vane_noise
    vane[1::2] = np.nan
    return PitchRun(np.arange(n) * DT, de, gyro, vane, alpha, q, acc)
