"""Recordings in which a missing effect is concealed, on five systems, and clean ones.

Each scenario flies a truth with one effect the nominal model file leaves out
(or, for the sensor rows, a clean flight whose one sensor column is miscalibrated;
for the clean rows, none: clean recordings, some diagnosed with mis-declared
noise, and pure noise) and says how the effect hides. The cart and the quadrotor
fly closed loops (and so does the pitch, models/short_period.py); the tanks and the arm (models/two_tanks.py,
models/motor_pendulum.py) run open loop and are the systems the diagnosis was not
developed on (tests/test_diagnose_unseen.py).

==================  ==========  ==================  =============================================
scenario            system      effect (equation)   how it hides
==================  ==========  ==================  =============================================
cart_coulomb        cart        coulomb_friction v  a tight PID keeps the tracking error as small
                                                    as without friction
cart_bias           cart        bias v              per sample it moves the cart 2000× less than
                                                    the encoder noise; the PID integrator cancels it
cart_cubic          cart        cubic_stiffness v   matters only during the large-amplitude moves
cart_dead_zone      cart        dead_zone v         the PID integrator pushes through the dead band
cart_lag            cart        actuator_lag v      only the unmeasured states see it: the motor
                                                    force and the velocity
quad_ground_effect  quadrotor   ground_effect vz    only below 0.3 m (take-off, landing); the
                                                    altitude loop hides it
cart_delay          cart        input_delay v       20 ms, hidden by the loop
cart_cogging        cart        (user) cogging v    outside the catalog: a user candidate names it
arm_drag_early      arm         quadratic_drag      ∝ ω²: large swings only in the first 40 % of
                                omega               the run; the second half's drag is 25× smaller
arm_drag_late       arm         quadratic_drag      large swings only in the last 15 % of the run
                                omega
tanks_overflow      tanks       physical_limit h1   the upper tank spills at its 0.30 m rim during
                                (upper, 0.30 m)     two pump bursts only (~8 % of the samples)
tanks_sensor_sat    tanks       sensor_saturation   the upper level sensor's range ends at 0.32 m
                                h1_meas (upper)     while the level rises on during the pump bursts
tanks_pump_limit    tanks       input_saturation u  the pump delivers at most 5 V; 30 % of the
                                (upper)             commands (2.5–6 V) are above it
arm_backlash        arm         backlash V          a ±0.15 V play between command and motor: only
                                                    felt after each reversal of the voltage
arm_frac_delay      arm         fractional_delay V  2.5 samples (12.5 ms): half a sample off the
                                                    grid of the integer delay
arm_detent          arm         (none) detent       outside the catalog, no candidate: a torque
                                omega               periodic in the angle (16 per turn)
tanks_float_valve   tanks       (none) float valve  outside the catalog, no candidate: a refill of
                                h2                  the lower tank with hysteresis (on < 0.08 m,
                                                    off > 0.11 m)
cart_clean          cart        none                the nominal model is right
quad_clean          quadrotor   none                the nominal model is right
tanks_clean         tanks       none                the nominal model is right
arm_clean           arm         none                the nominal model is right
tanks_q_x10         tanks       none                process noise declared 10× too large
tanks_r_x2_5        tanks       none                level-sensor noise declared 2.5× too large
arm_r_half          arm         none                encoder noise declared 2× too small
arm_noise_only      arm         none                pure noise: the encoder column is white noise
                                                    (0.3 rad) unrelated to the voltage
pitch_delay         pitch       input_delay de      30 ms; calibration widens the turbulence on q
                                                    until the innovations look white
pitch_cubic_grey    pitch       cubic_stiffness q   +80·α³ in the large manoeuvres only; the
                                                    nominal declares Mα, Mq, Mδ 30 % off
pitch_clean         pitch       none                the nominal model is right
pitch_vane_offset   pitch       sensor_offset       the α vane misaligned by 0.02 rad: a pitch-
                                alpha_vane          moment offset would also raise α
pitch_gyro_bias     pitch       sensor_offset       the gyro reads 0.01 rad/s high (two noise
                                q_gyro              std); a pitch-moment bias also raises q
pitch_vane_gain     pitch       sensor_gain         the vane reads 15 % high; a larger Mα would
                                alpha_vane          also change how q follows α
arm_encoder_offset  arm         sensor_offset       the encoder zeroed 0.05 rad away; a constant
                                theta_meas          torque would also shift the resting angle
tanks_level_offset  tanks       sensor_offset       the upper level reads 0.03 m high; a weaker
                                h1_meas             outflow would also raise it
==================  ==========  ==================  =============================================

Lengths (SECONDS): cart and quadrotor 60 s at 100 Hz; arm 30 s at 200 Hz (6000
samples; encoder 1.5 mrad, rate noise 10⁻² rad/s per sample); tanks 400 s at
10 Hz (4000 samples; level sensors 2 and 2.5 mm, 3·10⁻⁴ m per sample on each
level). Mis-declared models are module attributes here (``TANKS_PROCESS_X10``,
…), given to the diagnosis as ``benchmarks.scenarios:NAME``.

``make(name, seconds, seed)`` returns a :class:`Scenario` with the recording
columns, the truth and the windows where the effect is truly active;
``write_csv`` writes the recording for ``skigen diagnose``; ``one`` diagnoses one
scenario and compares what was found with the truth.
"""
from __future__ import annotations

import importlib.util
import time
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from models import cart, motor_pendulum as arm, short_period as pitch, two_tanks as tanks
from skigen.diagnose import diagnose
from skigen.modelfile import load_model
from skigen.recording import Recording, write_recording

ROOT = Path(__file__).resolve().parent.parent
CART_FILE = str(ROOT / "models" / "cart.py")
QUAD_FILE = str(ROOT / "models" / "diagnose_quadrotor.py")


def _quad():
    spec = importlib.util.spec_from_file_location("diagnose_quadrotor", QUAD_FILE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@dataclass
class Scenario:
    name: str
    system: str
    model_file: str
    effect: str | None           # the catalog (or user candidate) effect the truth adds
    equation: str | None         # the equation it enters
    truth: float | None          # its coefficient / parameter in the finding's units
    concealment: str             # how it hides
    t: np.ndarray
    inputs: dict
    outputs: dict
    effect_acc: np.ndarray       # the acceleration the nominal model misses
    active: np.ndarray           # samples where the effect truly matters
    run: object                  # the simulator's run (truth)
    candidates: tuple = ()       # user candidates to pass to the diagnosis
    side: str | None = None      # physical_limit: "upper" or "lower" (truth is the bound)
    noise_truth: dict | None = None   # the true noise, keyed as `skigen fit`'s noise dict
    misdeclared: str | None = None    # "process_std" or "measurement_std": declared wrong
    outside_catalog: bool = False     # no catalog term or candidate can name the effect

    def recording(self, path: str = "") -> Recording:
        return Recording(path or self.name, self.t, np.column_stack(list(self.inputs.values())),
                         np.column_stack(list(self.outputs.values())), tuple(self.inputs), tuple(self.outputs))

    def write_csv(self, path) -> Path:
        write_recording(path, self.t, self.inputs, self.outputs)
        return Path(path)


def _steps():
    return cart.smooth(cart.steps([0.2, -0.1, 0.3, 0.0, -0.25, 0.1], 2.0, 0.5))


def _cubic_reference(t):
    """Small steps (±0.1 m) most of the time; large moves (±0.6 m) from 20 to 28 s of every 28 s."""
    small = cart.steps([0.1, -0.05, 0.08, -0.1], 2.0)(t)
    large = cart.steps([0.6, -0.5, 0.55, -0.6], 2.0)(t)
    phase = np.mod(t, 28.0)
    return np.where((phase >= 20.0), large, small)


def _cart(name, effect, parameter, equation, truth, concealment, seconds, seed, reference=None,
          active_of=None, candidates=()) -> Scenario:
    ref = reference or _steps()
    run = cart.simulate(ref, seconds, effect=effect, parameter=parameter, seed=seed)
    a = np.abs(run.effect_acc)
    active = active_of(run) if active_of else (a > 0.2 * np.percentile(a, 99) if a.any() else a > 0)
    return Scenario(name, "cart", CART_FILE, effect, equation, truth, concealment, run.t, run.inputs(),
                    run.outputs(), run.effect_acc, active, run, tuple(candidates))


def _quadrotor(name, ground_effect, seconds, seed) -> Scenario:
    Q = _quad()
    run = Q.simulate(seconds, ground_effect=ground_effect, seed=seed)
    active = run.z < 0.3 if ground_effect else np.zeros(len(run.t), bool)
    return Scenario(name, "quadrotor", QUAD_FILE, "ground_effect" if ground_effect else None,
                    "vz" if ground_effect else None, Q.K_GE / Q.M if ground_effect else None,
                    "only below 0.3 m, during take-off and landing; the altitude loop hides it"
                    if ground_effect else "the nominal model is right",
                    run.t, run.inputs(), run.outputs(), run.effect_acc, active, run)


# ------------------------------------------------------------------ unseen systems: tanks and arm
ARM_FILE = str(ROOT / "models" / "motor_pendulum.py")
TANKS_FILE = str(ROOT / "models" / "two_tanks.py")
# the nominal models with mis-declared noise std, for `diagnose(MODEL_SPEC, …)` and the CLI
TANKS_PROCESS_X10 = tanks.build("two_tanks_q_x10", process_scale=10.0)
TANKS_MEASUREMENT_X2_5 = tanks.build("two_tanks_r_x2_5", measurement_scale=2.5)
ARM_MEASUREMENT_HALF = arm.build("motor_pendulum_r_half", measurement_scale=0.5)
TANKS_NOISE = {"process_std": dict(tanks.LEVEL_STD), "measurement_std": dict(tanks.H_NOISE)}
PITCH_FILE = str(ROOT / "models" / "short_period.py")
# the pitch grey box: Mα, Mq, Mδ declared as parameters, started 30 % off
PITCH_GREY = pitch.build("short_period_grey", parameters={"Ma": 0.7 * pitch.MA, "Mq": 1.3 * pitch.MQ,
                                                          "Mde": 0.7 * pitch.MDE})
ARM_NOISE = {"process_std": {"theta": 0.0, "omega": arm.RATE_STD}, "measurement_std": {"theta_meas": arm.NOISE_STD}}


def _strong(a: np.ndarray) -> np.ndarray:
    """Samples where |a| exceeds a fifth of its 99th percentile (none if a is zero)."""
    a = np.abs(a)
    return a > 0.2 * np.percentile(a, 99) if a.any() else a > 0


def _arm(name, effect, voltage, concealment, seconds, seed, *, truth=None, active_of=None,
         model_file=ARM_FILE, noise=None, misdeclared=None, outside=False) -> Scenario:
    run = arm.simulate(voltage(seconds, seed), effect=effect, seed=seed)
    active = active_of(run) if active_of else _strong(run.effect_acc)
    return Scenario(name, "motor_pendulum", model_file, effect, "omega" if effect else None, truth, concealment,
                    run.t, run.inputs(), run.outputs(), run.effect_acc, active, run,
                    noise_truth=noise, misdeclared=misdeclared, outside_catalog=outside)


def _tanks(name, effect, concealment, seconds, seed, *, equation=None, truth=None, bursts=(), levels=(2.5, 6.0),
           side=None, active_of=None, model_file=TANKS_FILE, noise=None, misdeclared=None,
           outside=False) -> Scenario:
    simulated = {"physical_limit": "overflow", "input_saturation": "pump_limit"}.get(effect, effect)
    pump = tanks.pump_steps(seconds, levels=levels, seed=seed, bursts=bursts)
    run = tanks.simulate(pump, effect=simulated, seed=seed)
    col = ["h1", "h2"].index(equation) if equation else 0
    acc = run.effect_rate[:, col]
    active = active_of(run) if active_of else acc != 0
    return Scenario(name, "two_tanks", model_file, effect, equation, truth, concealment, run.t, run.inputs(),
                    run.outputs(), acc, active, run, side=side, noise_truth=noise, misdeclared=misdeclared,
                    outside_catalog=outside)


def _pitch(name, effect, concealment, seconds, seed, *, model_file=PITCH_FILE, large=0.15) -> Scenario:
    run = pitch.simulate(seconds, effect=effect, seed=seed, large=large)
    found = {"cubic_moment": ("cubic_stiffness", -pitch.EFFECTS["cubic_moment"][0]),
             "elevator_delay": ("input_delay", pitch.EFFECTS["elevator_delay"][0])}.get(effect, (None, None))
    return Scenario(name, "short_period", model_file, found[0], "q" if effect else None, found[1], concealment,
                    run.t, run.inputs(), run.outputs(), run.effect_acc, _strong(run.effect_acc), run)


def _sensor(name, clean: str, output: str, concealment: str, seconds, seed, *, offset: float = 0.0,
            gain: float = 1.0) -> Scenario:
    """The scenario ``clean`` with the sensor of ``output`` reading gain·(its column) + offset: a
    miscalibrated sensor outside the loop (states and inputs unchanged; the noise scaled with the gain)."""
    clean = SCENARIOS[clean](seconds, seed)
    y = clean.outputs[output]
    read = gain * y + offset
    effect, truth = ("sensor_offset", offset) if offset else ("sensor_gain", gain)
    active = np.ones(len(y), bool) if offset else _strong(np.nan_to_num(read - y))
    model = load_model(clean.model_file)
    reads = next(v.sym for v in model.outputs if v.name == output)
    equation = "+".join(v.name for v in model.states if ca.depends_on(reads, v.sym))   # as the report says it
    return Scenario(name, clean.system, clean.model_file, effect, equation, truth, concealment, clean.t,
                    clean.inputs, {**clean.outputs, output: read}, np.zeros(len(y)), active, clean.run)


def _arm_noise_only(name, seconds, seed) -> Scenario:
    """The arm's voltage, and an encoder column of white noise (0.3 rad, the size of a swing)
    unrelated to it: nothing the model can explain."""
    clean = _arm(name, None, _arm_multisine(1.2), "", seconds, seed)
    rng = np.random.default_rng(9000 + seed)
    outputs = {"theta_meas": rng.normal(0.0, 0.3, len(clean.t))}
    return Scenario(name, "motor_pendulum", ARM_FILE, None, None, None,
                    "pure noise: the encoder column is white noise unrelated to the voltage",
                    clean.t, clean.inputs, outputs, np.zeros(len(clean.t)), np.zeros(len(clean.t), bool), None)


def _arm_multisine(first: float, second: float | None = None, switch: float = 0.4):
    """Voltage(seconds, seed): a 0.3–3 Hz multisine peaking at ``first`` V, then, when given,
    ``second`` V from the ``switch`` fraction of the run on (the swings ring down in ~5 s)."""
    def voltage(seconds, seed):
        env = first if second is None else (lambda t: np.where(t < switch * seconds, first, second))
        return arm.multisine(seconds, env, seed=seed)
    return voltage


def _overflow_bursts(seconds: float) -> list:
    """Pump at 7.5 V for 70 s twice (from a fifth and from three fifths of the run): the upper
    tank fills to its rim and spills."""
    return [(0.2 * seconds, 0.2 * seconds + 70.0, 7.5), (0.6 * seconds, 0.6 * seconds + 70.0, 7.5)]


UNSEEN = {
    "arm_drag_early": lambda s, seed: _arm(
        "arm_drag_early", "quadratic_drag", _arm_multisine(4.0, 0.15),
        "drag grows with ω²: large swings (4 V multisine) only in the first 40 %, then 0.15 V: "
        "in the second half the rate is 6× and the drag 25× smaller", s, seed, truth=arm.EFFECTS["quadratic_drag"][0]),
    "arm_drag_late": lambda s, seed: _arm(
        "arm_drag_late", "quadratic_drag", _arm_multisine(0.15, 4.0, switch=0.85),
        "drag grows with ω²: 0.15 V swings, then large ones (4 V) only in the last 15 %: one fold of "
        "contiguous five would hold all of them", s, seed, truth=arm.EFFECTS["quadratic_drag"][0]),
    "arm_detent": lambda s, seed: _arm(
        "arm_detent", "detent", lambda sec, sd: arm.chirp(sec, 1.0),
        f"a torque periodic in the angle ({arm.DETENT_N} per turn), outside the catalog and with no "
        "user candidate", s, seed, truth=arm.EFFECTS["detent"][0], outside=True),
    "arm_r_half": lambda s, seed: _arm(
        "arm_r_half", None, _arm_multisine(1.2), "clean; encoder noise declared 2× too small",
        s, seed, model_file="benchmarks.scenarios:ARM_MEASUREMENT_HALF", noise=ARM_NOISE,
        misdeclared="measurement_std"),
    "arm_noise_only": lambda s, seed: _arm_noise_only("arm_noise_only", s, seed),
    "arm_encoder_offset": lambda s, seed: _sensor(
        "arm_encoder_offset", "arm_clean", "theta_meas",
        "the encoder was zeroed 0.05 rad (2.9°) away from the hanging position; a constant torque "
        "on ω would also shift the resting angle", s, seed, offset=0.05),
    "tanks_level_offset": lambda s, seed: _sensor(
        "tanks_level_offset", "tanks_clean", "h1_meas",
        "the upper level sensor reads 0.03 m high; a bias on h1's rate or a weaker outflow would "
        "also raise the upper level", s, seed, offset=0.03),
    "tanks_overflow": lambda s, seed: _tanks(
        "tanks_overflow", "physical_limit",
        "the upper level rests on the rim only during two pump bursts (a few % of the samples); "
        "the level sensor's updates follow the flat top", s, seed, equation="h1",
        truth=tanks.EFFECTS["overflow"][0], side="upper", bursts=_overflow_bursts(s)),
    "tanks_sensor_sat": lambda s, seed: _tanks(
        "tanks_sensor_sat", "sensor_saturation",
        "the upper level sensor reads at most 0.32 m; during two pump bursts the level rises past it "
        "and only the lower tank's faster rise shows it", s, seed, equation="h1",
        truth=tanks.EFFECTS["sensor_saturation"][0], side="upper", bursts=_overflow_bursts(s),
        active_of=lambda r: r.h1 > tanks.EFFECTS["sensor_saturation"][0]),
    "tanks_pump_limit": lambda s, seed: _tanks(
        "tanks_pump_limit", "input_saturation",
        "the pump delivers at most 5 V: commands of 2.5–6 V, above it 30 % of the time, and the "
        "upper level settles lower than the nominal model says", s, seed, equation="h1",
        truth=tanks.EFFECTS["pump_limit"][0], side="upper"),
    "arm_backlash": lambda s, seed: _arm(
        "arm_backlash", "backlash", _arm_multisine(1.2),
        "a ±0.15 V play between command and motor (gear backlash as a hysteresis on the voltage): "
        "felt only after each reversal", s, seed, truth=arm.EFFECTS["backlash"][0]),
    "arm_frac_delay": lambda s, seed: _arm(
        "arm_frac_delay", "fractional_delay", lambda sec, sd: arm.multisine(sec, 2.0, f_hi=8.0, seed=sd),
        "the voltage (a 2 V multisine up to 8 Hz) acts 2.5 samples (12.5 ms) late: half a sample "
        "off the integer delay's grid",
        s, seed, truth=arm.EFFECTS["fractional_delay"][0]),
    "tanks_float_valve": lambda s, seed: _tanks(
        "tanks_float_valve", "float_valve",
        "a hysteretic refill of the lower tank (opens below 0.08 m, closes above 0.11 m): depends on "
        "the level's history, outside the catalog, no user candidate", s, seed, equation="h2",
        truth=tanks.EFFECTS["float_valve"][0] / tanks.A2, levels=(2.0, 4.5), active_of=lambda r: r.valve,
        outside=True),
    "tanks_q_x10": lambda s, seed: _tanks(
        "tanks_q_x10", None, "clean; process noise declared 10× too large", s, seed,
        model_file="benchmarks.scenarios:TANKS_PROCESS_X10", noise=TANKS_NOISE, misdeclared="process_std"),
    "tanks_r_x2_5": lambda s, seed: _tanks(
        "tanks_r_x2_5", None, "clean; level-sensor noise declared 2.5× too large", s, seed,
        model_file="benchmarks.scenarios:TANKS_MEASUREMENT_X2_5", noise=TANKS_NOISE,
        misdeclared="measurement_std"),
    "tanks_clean": lambda s, seed: _tanks("tanks_clean", None, "the nominal model is right", s, seed),
    "arm_clean": lambda s, seed: _arm("arm_clean", None, _arm_multisine(1.2), "the nominal model is right", s, seed),
    "pitch_delay": lambda s, seed: _pitch(
        "pitch_delay", "elevator_delay",
        "the elevator acts 30 ms late, the pilot's inputs at most 0.1 rad; the noise calibration widens "
        "the turbulence on q until the innovations look white, but they still follow the elevator",
        s, seed, large=0.1),
    "pitch_cubic_grey": lambda s, seed: _pitch(
        "pitch_cubic_grey", "cubic_moment",
        "a pitch break +80·α³ felt only in the large manoeuvres of the second half; the nominal "
        "declares Mα, Mq, Mδ 30 % off, and the calibration bends Mα to absorb the break", s, seed,
        model_file="benchmarks.scenarios:PITCH_GREY"),
    "pitch_clean": lambda s, seed: _pitch("pitch_clean", None, "the nominal model is right", s, seed),
    "pitch_vane_offset": lambda s, seed: _sensor(
        "pitch_vane_offset", "pitch_clean", "alpha_vane",
        "the α vane is misaligned by +0.02 rad (1.1°): its reading sits above the model's α, "
        "as a pitch-moment offset on q would also make it", s, seed, offset=0.02),
    "pitch_gyro_bias": lambda s, seed: _sensor(
        "pitch_gyro_bias", "pitch_clean", "q_gyro",
        "the pitch gyro reads 0.01 rad/s (0.6 °/s) high, twice its noise std; a pitch-moment "
        "bias would also raise q, and α with it", s, seed, offset=0.01),
    "pitch_vane_gain": lambda s, seed: _sensor(
        "pitch_vane_gain", "pitch_clean", "alpha_vane",
        "the α vane reads 15 % high (a local-flow upwash factor left out); a larger Mα would "
        "also change how q follows α", s, seed, gain=1.15),
}


SCENARIOS = {
    "cart_coulomb": lambda s, seed: _cart(
        "cart_coulomb", "coulomb_friction", 0.3, "v", 0.3 / cart.M,
        "a tight PID keeps the tracking error as small as without friction", s, seed),
    "cart_bias": lambda s, seed: _cart(
        "cart_bias", "bias", 0.01, "v", 0.01 / cart.M,
        "per sample it moves the cart b·dt²/2M = 5·10⁻⁷ m, 2000× below the encoder noise; "
        "the PID integrator cancels it", s, seed),
    "cart_cubic": lambda s, seed: _cart(
        "cart_cubic", "cubic_stiffness", 10.0, "v", 10.0 / cart.M,
        "matters only during the large-amplitude moves (|p| > 0.3 m)", s, seed, reference=cart.smooth(_cubic_reference),
        active_of=lambda r: np.abs(r.p) > 0.3),
    "cart_dead_zone": lambda s, seed: _cart(
        "cart_dead_zone", "dead_zone", 0.3, "v", 0.3,
        "the PID integrator pushes the command through the dead band", s, seed),
    "cart_lag": lambda s, seed: _cart(
        "cart_lag", "actuator_lag", 0.03, "v", 0.03,
        "only unmeasured states see it: the motor force and the velocity (the encoder reads position)",
        s, seed),
    "cart_delay": lambda s, seed: _cart(
        "cart_delay", "input_delay", 2, "v", 2, "20 ms of delay, hidden by the loop", s, seed),
    "quad_ground_effect": lambda s, seed: _quadrotor("quad_ground_effect", True, s, seed),
    "cart_cogging": lambda s, seed: _cart(
        "cart_cogging", "cogging", 0.2, "v", 0.2 / cart.M,
        "a force periodic in position (motor cogging), outside the catalog: needs a user candidate",
        s, seed, candidates=[("cogging", "v", f"-sin(2*pi*p/{cart.COGGING_PITCH})")]),
    "cart_clean": lambda s, seed: _cart("cart_clean", None, None, None, None, "the nominal model is right", s, seed),
    "quad_clean": lambda s, seed: _quadrotor("quad_clean", False, s, seed),
    **UNSEEN,
}


SECONDS = {   # default length per scenario (s); 60 s otherwise
    **{k: 30.0 for k in UNSEEN if k.startswith("arm_")},           # 6000 samples at 200 Hz
    **{k: 400.0 for k in UNSEEN if k.startswith("tanks_")},        # 4000 samples at 10 Hz
}


def make(name: str, seconds: float | None = None, seed: int = 1) -> Scenario:
    """The scenario ``name`` flown for ``seconds`` (default: SECONDS, else 60 s) with noise seed ``seed``."""
    return SCENARIOS[name](SECONDS.get(name, 60.0) if seconds is None else seconds, seed)


def overlap(windows, t: np.ndarray, active: np.ndarray) -> tuple[float, float]:
    """(recall, precision): the share of truly active time inside the located windows, and the
    share of the located windows' time where the effect is truly active."""
    located = np.zeros(len(t), bool)
    for a, b in windows:
        located |= (t >= a) & (t <= b)
    recall = float((located & active).sum() / max(active.sum(), 1))
    precision = float((located & active).sum() / max(located.sum(), 1))
    return recall, precision


def _right(sc: Scenario, d: dict) -> bool:
    """The report says what the truth is: the effect on top, on its equation, or a top finding the
    report says it cannot tell from the truth (``as_good``); outside the catalog, nothing named or a
    mismatch said to remain; clean, nothing named."""
    top = d["findings"][0] if d["findings"] else None
    if sc.outside_catalog:
        return top is None or bool(d.get("remaining", {}).get("mismatch"))
    if sc.effect:
        return top is not None and any(f["effect"] == sc.effect and sc.equation in f["equation"].split("+")
                                       for f in [top, *top.get("as_good", [])])
    return not d["findings"]


def one(name: str, out: Path, seconds: float | None, seed: int) -> dict:
    """Diagnose scenario ``name`` (recording and report under ``out``): timing, findings, truth."""
    sc = make(name, seconds, seed)
    csv = sc.write_csv(out / f"{name}.csv")
    t0 = time.perf_counter()
    rep = diagnose(sc.model_file, csv, out / name, candidates=list(sc.candidates), show_progress=False)
    dt = time.perf_counter() - t0
    d = rep.data
    rec, prec = overlap(d["located"]["windows"], sc.t, sc.active) if sc.effect else (float("nan"),) * 2
    fit = d["fit"]
    row = dict(name=name, samples=len(sc.t), seconds=dt, mismatch=d["mismatch_detected"],
               equations=",".join(d["located"]["equations"]), recall=rec, precision=prec,
               regime=d["located"].get("regime"), truth=f"{sc.effect or '-'} {sc.truth if sc.truth else ''}",
               found="; ".join(f"{f['effect']} on {f['equation']} {f['coefficient']:.4g}" + (f"±{f['std']:.2g}" if f['std'] is not None and f['std'] == f['std'] else "")
                               for f in d["findings"]) or "-",
               right=_right(sc, d),
               ll=(sum(f["loglik_before"] for f in fit["folds"]), sum(f["loglik_after"] for f in fit["folds"]))
               if fit.get("folds") else (fit["before"]["loglik"], None),
               remaining=d["remaining"]["mismatch"],
               rmse=(list(fit["before"]["free_run_rmse"].values())[0],
                     list(fit["after"]["free_run_rmse"].values())[0] if fit["after"] else None),
               concealment=sc.concealment)
    return row
