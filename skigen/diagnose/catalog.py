"""The physics catalog: commonly missing effects, instantiated from a model's roles and inputs.

Additive effects are basis terms φ(x, u) for the rate equation of a velocity
or rate state, written as formulas in the model's own names (``-tanh(v/0.005)``)
so that a person can read them and a corrected model file can restate them.
Where an input drives several equations (a force on a cart that also swings
its pendulum), friction, an offset and a gain error of what the input moves
are also offered *through* it: added to the input, they enter every equation
the input enters, φ·∂(rate)/∂u, as a force does.
Structural effects transform the model: the plant sees a delayed (by whole
samples or a fraction of one), lagged, saturated, dead-zoned or backlashed
version of an input, or a sensor reads its output offset, scaled or clipped;
each has one parameter searched over a grid.
"""
from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass, field
from typing import Callable

import casadi as ca
import numpy as np

from ..model import POSITION_ROLES, Model
from . import transform as T
from .source import to_python

__all__ = ["Additive", "Structural", "EFFECTS", "READINGS", "evaluate", "additive_candidates",
           "structural_candidates", "output_candidates", "user_candidates", "declared_candidates", "rate_equations",
           "pairs", "COULOMB_WIDTHS", "channel", "channel_candidates", "limit"]

VELOCITY_ROLES = ("velocity", "rate")
GROUND_EFFECT_HEIGHTS = (0.05, 0.1, 0.2, 0.4)   # m: about a rotor radius
LENGTH_UNITS = {"m": 1.0, "cm": 100.0, "mm": 1000.0, "ft": 1 / 0.3048, "": 1.0}

READINGS = {
    "bias": "a constant offset in the rate (a slope, a mis-trimmed actuator, a wrong weight or hover thrust)",
    "viscous_damping": "damping proportional to the rate (viscous friction, linear drag)",
    "quadratic_drag": "drag growing with the square of the speed (aerodynamic or hydrodynamic)",
    "cubic_damping": "damping growing with the cube of the rate (a ship's yaw damping after Norrbin, a "
                     "hardening damper)",
    "coulomb_friction": "dry (Coulomb) friction: a constant force opposing the motion",
    "cubic_stiffness": "a hardening spring: a restoring force growing with the cube of the displacement",
    "linear_stiffness": "a spring the model leaves out or misjudges: a restoring force proportional to the displacement",
    "physical_limit": "a state that cannot pass a bound (an end stop, a tank that overflows, a vehicle resting "
                      "on the ground): a stiff restoring rate beyond it",
    "input_gain": "the input acts more or less strongly than modelled (actuator gain, mass or inertia error)",
    "ground_effect": "extra thrust close to the ground, decaying with height",
    "input_delay": "the plant responds to the input a few samples late (transport or computation delay)",
    "actuator_lag": "the actuator follows its command with a first-order lag (on a plant linear in the "
                    "states, a first-order lag of the sensor reads the same)",
    "input_saturation": "the actuator cannot deliver more than a limit",
    "dead_zone": "small commands produce nothing (backlash, stiction in the actuator, an ESC dead band)",
    "fractional_delay": "the plant responds to the input a delay off the sample grid (a whole number of "
                        "samples and a fraction of one)",
    "backlash": "play between command and plant (gear backlash, hysteresis): after a reversal the command "
                "must cross the play before the plant sees it move",
    "sensor_offset": "a sensor that reads the quantity plus a constant (a misaligned vane, an encoder zeroed "
                     "away from its reference, a gyro's bias)",
    "sensor_gain": "a sensor that reads the quantity times a constant (a scale-factor or calibration error)",
    "sensor_saturation": "a sensor whose range ends at a bound: it reads the bound while the quantity "
                         "itself goes on",
    "constant": "a number of the model is off (a mass, a damper, a gain from a datasheet): every place it is "
                "written takes the same factor",
}
EFFECTS = tuple(READINGS)
# the same terms on an equation that is no velocity (a pressure, a temperature, a current, a charge)
LOSS_READINGS = {
    "bias": "a constant offset in the rate (a source or sink the model leaves out: a leak at a constant rate, "
            "a heat input, an offset)",
    "viscous_damping": "a loss proportional to the state (a leak, a heat loss, a resistance or conductance "
                       "the model misjudges)",
    "quadratic_drag": "a loss growing with the state times its magnitude (a turbulent flow or leak)",
    "cubic_damping": "a loss growing with the cube of the state",
    "coulomb_friction": "a constant loss opposing the sign of the state",
}


def evaluate(model: Model, formula: str) -> ca.SX:
    """A formula over the model's names as SX (see :func:`transform.formula`)."""
    return T.formula(model, formula)


@dataclass(frozen=True)
class Additive:
    """coefficient × formula added to the rate of ``equation``."""

    effect: str
    equation: str
    formula: str
    reading: str
    variant: str = ""         # e.g. "h = 0.1 m": several variants of one effect compete
    expr: ca.SX | None = field(default=None, compare=False, repr=False)   # when not a formula
    shape: tuple = ()         # the variant's shape parameters, (("width", 0.01),) …
    sign: int = 0             # +1: only a positive coefficient is physical (friction, drag, a limit)
    parameter: str = ""       # a declared parameter's correction (∂rate/∂p), never a finding
    through: str = ""         # an input: the term is added to it and enters where it enters

    @property
    def key(self) -> tuple:
        """One term per (effect, equation, input it acts through) is adopted."""
        return self.effect, self.equation, self.through

    @property
    def group(self) -> tuple:
        """Variants of one another share it: its key and the non-numeric shape (a side)."""
        return self.key + tuple(v for _, v in self.shape if isinstance(v, str))

    @property
    def text(self) -> str:
        """The term as a person reads it: its formula, and the input it is added to (an input's own
        gain: the input times 1 + c)."""
        if self.through and self.formula == self.through:
            return f"{self.through}·(1 + c)"
        return f"{self.formula}, added to {self.through}" if self.through else self.formula

    def sx(self, model: Model) -> ca.SX:
        """φ as SX over ``model``'s symbols (for a term through an input, what is added to it)."""
        return self.expr if self.expr is not None else evaluate(model, self.formula)

    def contributions(self, model: Model) -> dict[str, ca.SX]:
        """{equation: its rate per unit coefficient}: φ on its equation, or, through input u,
        φ·∂(rate)/∂u on every equation u drives (the first-order effect of u → u + c·φ)."""
        phi = self.sx(model)
        if not self.through:
            return {self.equation: phi}
        return {e: phi * g for e, g in channel(model, self.through).items()}


def feedthrough(model: Model, u: str) -> dict[str, ca.SX]:
    """∂h/∂u of every output that reads input ``u`` directly (output units per unit of u)."""
    sym = T.symbols(model)[u]
    return {v.name: ca.jacobian(v.sym, sym) for v in model.outputs if ca.depends_on(v.sym, sym)}


def proportion(a, b, points: int = 4) -> float | None:
    """The constant k ≠ 0 with a = k·b (SX of one shape) at ``points`` random values of every
    symbol either holds, or None: an identity judged numerically."""
    a, b = ca.SX(a), ca.SX(b)
    z = ca.vertcat(*ca.symvar(ca.vertcat(ca.vec(a), ca.vec(b))))
    g = ca.Function("g", [z], [ca.vec(a), ca.vec(b)])
    rng = np.random.default_rng(0)
    pairs = [g(rng.normal(size=z.shape[0])) for _ in range(points)]
    a, b = (np.concatenate([np.array(p[i]).ravel() for p in pairs]) for i in (0, 1))
    big = np.argmax(np.abs(b))
    if not np.all(np.isfinite(a + b)) or b[big] == 0:
        return None
    k = a[big] / b[big]
    return float(k) if k != 0 and np.allclose(a, k * b, rtol=1e-9, atol=1e-12 * np.max(np.abs(a))) else None


def rate_readers(model: Model) -> dict[str, list[tuple[str, float]]]:
    """{equation: [(output, k)]}: the outputs written as k times that equation's rate plus inputs
    and constants (an accelerometer's formula repeating the dynamics): what is found missing in
    the rate, the sensor reads as well. Judged on the Jacobians in the states (:func:`proportion`)."""
    if model.discretization == "discrete":
        return {}
    x = ca.vertcat(*[v.sym for v in model.states])
    out = {}
    for e in model.state_names:
        for v in model.outputs:
            if ca.SX(v.sym).is_symbolic():            # a state read as it is, not a formula of the rate
                continue
            if k := proportion(ca.jacobian(v.sym, x), ca.jacobian(model.rhs[e], x)):
                out.setdefault(e, []).append((v.name, k))
    return out


def channel(model: Model, u: str) -> dict[str, ca.SX]:
    """∂(rate)/∂u of every state equation input ``u`` enters (rate units per unit of u)."""
    sym = T.symbols(model)[u]
    out = {}
    for e in model.state_names:
        if ca.depends_on(model.rhs[e], sym):
            g = ca.jacobian(model.rhs[e], sym)
            out[e] = g / model.dt if model.discretization == "discrete" else g
    return out


@dataclass(frozen=True)
class Structural:
    """A model transformation with one parameter searched over ``grid``, acting on ``input`` (or, for
    a sensor, on ``output``, clipped on ``side``); ``params``: how many numbers the search chooses
    (a fractional delay: its whole and its fractional part); ``coarser``: the nested simpler change
    it is replaced by when it is not significantly better (a fractional delay: the whole delay it
    rounds to)."""

    effect: str
    input: str
    parameter: str            # name of the parameter
    unit: str
    grid: tuple
    integer: bool
    log: bool                 # refine on a log scale
    build: Callable[[Model, float], Model]
    describe: Callable[[float], str]   # expression a person reads
    reading: str
    output: str = ""
    side: str = ""
    params: int = 1
    coarser: "Structural | None" = None
    refit: bool = True        # its value a parameter of the joint refit (not a whole delay, a fraction, a play)
    beyond: float = 0.0       # > 0: the grid goes on past an end that is best, its value times this
                              # (an offset, a lag, a width, a delay, a symmetric limit below its
                              # grid; past a recorded extreme it changes nothing)
    least: float = 0.0        # the grid does not go below this (a lag's time constant: the integration step)
    equations: tuple = ()     # a constant: where it is written (states' equations; 'output y' for an output)

    @property
    def target(self) -> str:
        """The input or output it acts on."""
        return self.output or self.input

    @property
    def key(self) -> tuple:
        """One change per (effect, signal, side) is adopted; a nested change shares its coarser one's."""
        return (self.coarser or self).effect, self.target, self.side


def rate_equations(model: Model) -> list[str]:
    """States whose equation holds the forces: role velocity or rate, and every other whose
    equation is neither a pure kinematic identity (dx/dt = another state) nor 0 (a constant
    carried as a state). (A motor's current beside its speed of role rate was never tested: a
    driver gain 15 % low on the voltage was named as two sensor gains; nor an angle of attack of
    role angle, α̇ = Zα·α + q + Zδ·δe: a bias on it went unnamed, a step in time said instead.)"""
    names = set(model.state_names)
    return [v.name for v in model.states if v.role in VELOCITY_ROLES or not (
        (model.rhs[v.name].is_symbolic() and model.rhs[v.name].name() in names) or ca.SX(model.rhs[v.name]).is_zero())]


def pairs(model: Model, velocity: str) -> list[str]:
    """Position-type states whose equation depends on ``velocity``, and the states whose rate it is
    or adds (ẋ = v, or ẋ = v + …: a position whatever its declared role; an angle of attack α̇ =
    Zα·α + q declared without a role got no stiffness on q, and a −60·α³ moment was "the constant
    8·al × 1.162", a mismatch remaining)."""
    vs = T.symbols(model)[velocity]
    kinematic = driven(model, velocity)
    return [v.name for v in model.states
            if v.name in kinematic or v.role in POSITION_ROLES and ca.depends_on(model.rhs[v.name], vs)
            or v.name != velocity and ca.is_equal(ca.simplify(ca.jacobian(model.rhs[v.name], vs)), ca.SX(1))]


def driven(model: Model, velocity: str) -> list[str]:
    """States whose rate is exactly ``velocity`` (ẋ = v): the positions it drives kinematically."""
    v = T.symbols(model)[velocity]
    return [s.name for s in model.states if s.name != velocity and model.rhs[s.name].is_symbolic()
            and ca.is_equal(model.rhs[s.name], v)]


def summands(expr: ca.SX) -> list[ca.SX]:
    """The terms of a sum, each with its sign, through constant factors and divisors:
    (a − (b + c))/m → [a/m, −b/m, −c/m]."""
    if expr.is_constant() or expr.is_symbolic():
        return [expr]
    op, a = expr.op(), expr.dep(0)
    if op == ca.OP_ADD:
        return summands(a) + summands(expr.dep(1))
    if op == ca.OP_SUB:
        return summands(a) + [-e for e in summands(expr.dep(1))]
    if op == ca.OP_NEG:
        return [-e for e in summands(a)]
    if op == ca.OP_DIV and expr.dep(1).is_constant():
        return [e / expr.dep(1) for e in summands(a)]
    if op == ca.OP_MUL and (a.is_constant() or expr.dep(1).is_constant()):
        k, rest = (a, expr.dep(1)) if a.is_constant() else (expr.dep(1), a)
        return [k * e for e in summands(rest)]
    return [expr]


def input_term(model: Model, eq: str, u: str) -> Additive:
    """The input gain candidate of ``u`` on ``eq``: ``u`` itself where the rate is linear in u with a
    constant gain, else u's own terms of the rate, each less its value at u = 0 (a thrust k·pwm², a
    moment b·u·cos θ), which a thrust constant or an inertia error scales. The formula ``u`` where
    such a term is not finite at u = 0 (a 1/u) or reads an input history. A candidate beside u,
    not a variant of it: their coefficients are not of one scale (a shape search averaged them)."""
    plain = Additive("input_gain", eq, u, READINGS["input_gain"])
    sym = T.symbols(model)[u]
    if ca.jacobian(model.rhs[eq], sym).is_constant():
        return plain
    zero = lambda e: ca.substitute(e, sym, 0.0)
    share = sum((e if _vanishes(zero(e)) else e - zero(e) for e in summands(model.rhs[eq]) if ca.depends_on(e, sym)),
                ca.SX(0))
    share = share / model.dt if model.discretization == "discrete" else share
    if model.parameters:                                             # at the declared values
        share = ca.substitute(share, ca.vertcat(*[p.sym for p in model.parameters]),
                              ca.DM([p.value for p in model.parameters]))
    if {s.name() for s in ca.symvar(share)} - set(T.symbols(model)) or not _finite(share):
        return plain
    return Additive("input_gain", eq, to_python(share).replace("ca.", ""), READINGS["input_gain"], f"its {u} term",
                    expr=share, shape=(("gain on", f"{u}'s terms"),))      # its own group: not a variant of u


def _samples(expr: ca.SX, n: int = 4) -> np.ndarray:
    """``expr`` at ``n`` random values of its symbols."""
    z = ca.vertcat(*ca.symvar(expr))
    f = ca.Function("f", [z], [expr]).map(n)
    return np.asarray(f(np.random.default_rng(0).normal(size=(z.shape[0], n)))).ravel()


def _vanishes(expr: ca.SX) -> bool:
    return bool(np.all(_samples(expr) == 0))


def _finite(expr: ca.SX) -> bool:
    return bool(np.all(np.isfinite(_samples(expr))))


def _inputs_of(model: Model, equation: str) -> list[str]:
    e = model.rhs[equation]
    return [v.name for v in model.inputs if ca.depends_on(e, v.sym)]


def _reaching(model: Model, equation: str) -> list[str]:
    """The inputs that drive ``equation`` directly or through the states it depends on, at any
    depth (a burner's heat reaches a balloon's climb rate through the envelope's temperature)."""
    seen, todo = set(), [equation]
    while todo:
        eq = todo.pop()
        if eq in seen:
            continue
        seen.add(eq)
        todo += [v.name for v in model.states if ca.depends_on(model.rhs[eq], v.sym)]
    return [u for u in model.input_names if any(u in _inputs_of(model, eq) for eq in seen)]


def _num(x: float) -> str:
    return f"{float(f'{x:.3g}'):g}"


COULOMB_WIDTHS = (0.005, 0.02, 0.08)         # × the RMS rate: the smoothing of sign(v)
LIMIT_QUANTILES = (0.8, 0.9, 0.95, 0.99)    # where a bound may sit, on the state's own distribution
SENSOR_QUANTILES = (0.7, 0.8, 0.9, 0.95, 0.99, 1.0)   # where a sensor's range may end (1: never reached)
SENSOR_OFFSETS = (0.003, 0.01, 0.03, 0.1, 0.3, 1.0)    # × the recorded output's RMS, both signs
SENSOR_GAINS = (0.8, 0.9, 0.95, 0.98, 1.02, 1.05, 1.1, 1.25)
# fractional delays (samples): quarter samples up to 4, then half samples like the integer delay's grid
FRACTIONAL_DELAYS = tuple(n + a for n in range(4) for a in (0.25, 0.5, 0.75)) + (5.5, 7.5, 10.5, 14.5)


def _limit_states(model: Model, eq: str) -> list[str]:
    """States a bound may stop through equation ``eq``: the positions it drives kinematically
    (ẋ = v), or the state itself when its equation is first order (a tank level)."""
    return driven(model, eq) or [eq]


def additive_candidates(model: Model, equations, scale: dict[str, float],
                        states: np.ndarray | None = None) -> list[Additive]:
    """Catalog terms for each listed rate equation. ``scale``: RMS of each state along the
    recording (the Coulomb smoothing widths are fractions of it); ``states`` (N, nx): the smoothed
    trajectory, where the bounds of a physical limit are searched."""
    units = {v.name: v.unit for v in model.states}
    out = []
    for eq in equations:
        moves = eq in [v.name for v in model.states if v.role in VELOCITY_ROLES] or bool(driven(model, eq))
        readings = READINGS if moves else READINGS | LOSS_READINGS      # a pressure's leak is no friction

        def add(effect, formula, variant="", shape=(), sign=0):
            out.append(Additive(effect, eq, formula, readings[effect], variant, shape=shape, sign=sign))
        add("bias", "1")
        rate_like = moves or not pairs(model, eq)      # the rate of a position: friction and drag act on it
        if rate_like:
            add("viscous_damping", f"-{eq}")
            add("quadratic_drag", f"-{eq}*abs({eq})", sign=1)
            add("cubic_damping", f"-{eq}**3", sign=1)
            for k in COULOMB_WIDTHS:
                w = _num(max(k * scale.get(eq, 1.0), 1e-12))
                add("coulomb_friction", f"-tanh({eq}/{w})", f"width {w} {units[eq]}".rstrip(),
                    (("width", float(w)),), sign=1)
        for q in pairs(model, eq):
            if q != eq:
                add("linear_stiffness", f"-{q}")
            add("cubic_stiffness", f"-{q}**3")
        if states is not None:
            for q in _limit_states(model, eq):
                x = states[:, model.state_names.index(q)]
                for side, qs in (("upper", LIMIT_QUANTILES), ("lower", [1 - a for a in LIMIT_QUANTILES])):
                    for b in sorted({float(_num(v)) for v in np.quantile(x, qs)}):
                        out.append(limit(eq, q, side, b, units[q]))
        for u in _inputs_of(model, eq):
            add("input_gain", u)
            if (term := input_term(model, eq, u)).expr is not None:
                out.append(term)
        alt = [q for q in pairs(model, eq) if next(v.role for v in model.states if v.name == q) == "altitude"]
        for z in alt:
            per_m = LENGTH_UNITS.get(units[z], 1.0)
            for u in _inputs_of(model, eq):
                for h in GROUND_EFFECT_HEIGHTS:
                    add("ground_effect", f"exp(-{z}/{_num(h * per_m)})*{u}", f"h = {_num(h * per_m)} {units[z]}",
                        (("height", float(_num(h * per_m))),))
    return out


def coulomb_width(c: Additive, width: float) -> Additive:
    """Coulomb friction ``c`` (``±tanh(q/w)``) with the smoothing width ``width``."""
    w = _num(width)
    unit = c.variant.split(" ", 2)[2] if c.variant.count(" ") >= 2 else ""
    return dataclasses.replace(c, formula=re.sub(r"tanh\((\w+)/[^)]*\)", rf"tanh(\1/{w})", c.formula),
                               variant=f"width {w} {unit}".rstrip(), shape=(("width", float(w)),))


def limit(eq: str, q: str, side: str, bound: float, unit: str = "") -> Additive:
    """The physical limit on ``eq`` of state ``q`` at ``bound`` on ``side`` ('upper': q ≤ bound)."""
    b = _num(bound)
    formula = f"-fmax({q} - {b}, 0)" if side == "upper" else f"fmax({b} - {q}, 0)"
    return Additive("physical_limit", eq, formula, READINGS["physical_limit"],
                    f"{q} {'≤' if side == 'upper' else '≥'} {b} {unit}".rstrip(),
                    shape=(("bound", float(b)), ("side", side), ("state", q)), sign=1)


CHANNEL_SIGN_SHARE = 0.95    # a velocity an input pushes one way on this share of the samples


def channel_candidates(model: Model, equations, scale: dict[str, float], states: np.ndarray,
                       inputs: np.ndarray) -> list[Additive]:
    """Terms added to each input that enters two or more state equations, one of them listed: an
    offset and a gain error of the input (reported on the first rate equation it enters), and the
    damping, drag and Coulomb friction of each velocity it drives (the force on a cart meets the
    cart's friction, and both reach the pendulum through the coupling). A friction's formula is
    oriented so that a positive coefficient opposes the motion, from the sign of ∂(rate)/∂u along
    the trajectory; a velocity the input pushes both ways gets none, and an input whose ∂(rate)/∂u
    depends on more than the states and inputs (an input history) none at all.
    ``states`` (N, nx), ``inputs`` (N, nu): the trajectory."""
    units = {v.name: v.unit for v in model.states}
    velocities = {v.name for v in model.states if v.role in VELOCITY_ROLES or driven(model, v.name)}
    x = ca.vertcat(*[v.sym for v in model.states])
    uu = ca.vertcat(*[v.sym for v in model.inputs])
    out = []
    for u in model.input_names:
        gains = channel(model, u)                  # in the states' order
        if len(gains) < 2 or not set(gains) & set(equations) or \
                {s.name() for g in gains.values() for s in ca.symvar(g)} - set(T.symbols(model)):
            continue

        def add(effect, eq, formula, variant="", shape=(), sign=0):
            out.append(Additive(effect, eq, formula, f"{READINGS[effect]}, where {u} acts", variant,
                                shape=shape, sign=sign, through=u))
        rates = rate_equations(model)              # an offset or a gain of u is reported on the first
        first = next((e for e in gains if e in rates), next(iter(gains)))     # rate equation u enters
        add("bias", first, "1")
        add("input_gain", first, u)
        for q in (e for e in gains if e in velocities):
            g = np.asarray(ca.Function("g", [x, uu], [gains[q]]).map(len(states))(
                states[:, :len(model.states)].T, inputs.T)).ravel()
            side = np.mean(g > 0)
            if CHANNEL_SIGN_SHARE > side > 1 - CHANNEL_SIGN_SHARE:
                continue
            minus = "-" if side >= CHANNEL_SIGN_SHARE else ""
            add("viscous_damping", q, f"{minus}{q}")
            add("quadratic_drag", q, f"{minus}{q}*abs({q})", sign=1)
            for k in COULOMB_WIDTHS:
                w = _num(max(k * scale.get(q, 1.0), 1e-12))
                add("coulomb_friction", q, f"{minus}tanh({q}/{w})", f"width {w} {units[q]}".rstrip(),
                    (("width", float(w)),), sign=1)
    return out


def user_candidates(model: Model, candidates) -> list[Additive]:
    """User candidates: (name, equation, formula) tuples, dicts with those keys, or
    'NAME:EQUATION:FORMULA' strings (as ``--candidate`` takes them)."""
    out = []
    for c in candidates or []:
        if isinstance(c, str):
            parts = [p.strip() for p in c.split(":", 2)]
        elif isinstance(c, dict):
            parts = [c.get(k) for k in ("name", "equation", "formula")]
        else:
            parts = list(c) if isinstance(c, (tuple, list)) else []
        if len(parts) != 3 or not all(isinstance(p, str) and p for p in parts):
            raise ValueError(f"candidate {c!r}: expected NAME:EQUATION:FORMULA, e.g. 'stiction:v:-tanh(v/0.001)' "
                             f"(in Python also a (name, equation, formula) tuple or a dict with those keys)")
        name, eq, formula = parts
        if eq not in model.state_names:
            raise ValueError(f"candidate '{name}': no equation '{eq}' (states: {', '.join(model.state_names)})")
        evaluate(model, formula)
        out.append(Additive(name, eq, formula, f"user-supplied candidate '{name}'"))
    return out


def declared_candidates(model: Model) -> list[Additive]:
    """The basis terms of the model's own unknown term, one candidate per equation they enter
    (scalar terms only): the user already suspected them."""
    out = []
    for b in model.unknowns:
        for t in b.terms:
            if t.expr.shape == (1, 1):
                out += [Additive(t.name, eq, t.name, "a term the model declares as possibly missing", expr=t.expr)
                        for eq in b.equations]
    return out


def parameter_terms(model: Model, equations) -> list[Additive]:
    """∂(rate)/∂p at the declared values, for each declared parameter p of ``model`` that enters
    one of ``equations``: the linearised correction of p. It is estimated with every candidate, so
    that a constant that compensated for the missing physics (a stiffness that absorbed a hardening
    spring) can move back while the candidate is fitted and scored; it is never a finding."""
    if not model.parameters:
        return []
    syms = ca.vertcat(*[p.sym for p in model.parameters])
    values = ca.DM([p.value for p in model.parameters])
    out = []
    for eq in equations:
        for p in model.parameters:
            d = ca.substitute(ca.jacobian(model.rhs[eq], p.sym), syms, values)
            d = d / model.dt if model.discretization == "discrete" else d          # a rate (see T.rate)
            if not (d.is_constant() and float(ca.evalf(d)) == 0.0):
                out.append(Additive("parameter", eq, f"d{eq}/d{p.name}", f"correction of the declared {p.name}",
                                    expr=d, parameter=p.name))
    return out


GRID_RATIO = 1.5     # neighbours of a limit's or a width's grid at most this ratio apart (log scale)
GRID_STEPS = 8       # a one-sided limit's grid: no gap wider than its span over this


def filled(grid, log: bool) -> tuple:
    """A grid of quantiles with its gaps filled: on a log scale (positive values) no two neighbours
    more than GRID_RATIO apart, else none more than the span over GRID_STEPS. Quantiles collapse
    where a signal dwells: a rudder command clipped at ±0.611 rad for a third of the run gave
    |δ|'s grid 0.105, 0.570, 0.611, and a stop at 0.262 was never evaluated (0.221 was named, 2σ
    off, after an input gain)."""
    g = sorted(float(v) for v in grid)
    if len(g) < 2:
        return tuple(g)
    step = (g[-1] - g[0]) / GRID_STEPS
    out = [g[0]]
    for a, b in zip(g, g[1:]):
        if log and a > 0:
            k = int(np.ceil(np.log(b / a) / np.log(GRID_RATIO) - 1e-9))
            out += [float(a * (b / a) ** (i / k)) for i in range(1, k)]
        elif step > 0:
            k = int(np.ceil((b - a) / step - 1e-9))
            out += [float(a + (b - a) * i / k) for i in range(1, k)]
        out.append(b)
    return tuple(out)


def _saturations(u: str, unit: str, x: np.ndarray, both: bool) -> list[Structural]:
    """An input's saturation: symmetric about zero for an input of both signs (an elevator, a motor
    voltage), the limit searched over |u|'s upper quantiles; otherwise (a heater, a pump, a thrust,
    whose range has one end at rest) the upper or the lower end alone, searched over u's quantiles.
    Each grid ends at the input's extreme, a limit that clips nothing (the nominal): a limit
    passed by the last few commands alone lies between the last quantile and it, where the
    profile can bracket it (held levels 66.8, 72.1 and 74.7 W around a true 70 W were called
    not identifiable, the best grid value at the grid's end). The symmetric grid goes on below
    its first quantile while that end is best: a limit clipping more than 40 % of the commands
    (±1.0 or ±1.2 N of held levels in ±2 N) was "not identifiable", or named an input gain."""
    def grid(values, qs, end, log=False):
        return filled([float(q) for q in np.unique(np.r_[np.quantile(values, qs), end]) if q > 0 or not log], log)
    if both:
        limits = grid(np.abs(x), [0.6, 0.8, 0.9, 0.95, 0.99], np.abs(x).max(), log=True)
        return [Structural("input_saturation", u, "limit", unit, limits, False, True,
                           lambda m, a, u=u: T.input_saturation(m, u, -a, a),
                           lambda a, u=u: f"clip({u}, {_num(-a)}, {_num(a)})", READINGS["input_saturation"],
                           beyond=GRID_RATIO)] if limits else []
    upper, lower = grid(x, [0.25, 0.5, 0.75, 0.9, 0.97], x.max()), grid(x, [0.03, 0.1, 0.25, 0.5, 0.75], x.min())
    return [Structural("input_saturation", u, "limit", unit, upper, False, False,
                       lambda m, a, u=u: T.input_saturation(m, u, None, a),
                       lambda a, u=u: f"min({u}, {_num(a)})", READINGS["input_saturation"], side="upper"),
            Structural("input_saturation", u, "limit", unit, lower, False, False,
                       lambda m, a, u=u: T.input_saturation(m, u, a, None),
                       lambda a, u=u: f"max({u}, {_num(a)})", READINGS["input_saturation"], side="lower")]


def structural_candidates(model: Model, equations, inputs: np.ndarray) -> list[Structural]:
    """Delay, lag, saturation and dead zone of every input that drives a listed equation, directly
    or through other states (:func:`_reaching`: a burner's delay reaches the climb rate through the
    envelope's temperature, and was never proposed). ``inputs``: the recorded inputs (N, nu), for
    the grids of limits and widths."""
    dt = model.dt
    used = sorted({u for eq in equations for u in _reaching(model, eq)}, key=model.input_names.index)
    out = []
    for u in used:
        x = inputs[:, model.input_names.index(u)]
        unit = next(v.unit for v in model.inputs if v.name == u)
        both = np.mean(x > 0) > 0.1 and np.mean(x < 0) > 0.1
        centre = 0.0 if both else float(np.median(x))
        dev = np.abs(x - centre)
        first = float(x[0])

        whole = Structural(
            "input_delay", u, "delay", "samples", tuple(range(1, 16)), True, False,
            lambda m, d, u=u: T.input_delay(m, u, int(round(d))),
            lambda d, u=u: f"{u}[k-{int(round(d))}] ({int(round(d)) * dt:g} s)", READINGS["input_delay"],
            refit=False, beyond=2.0)
        out.append(whole)
        out.append(Structural(
            "actuator_lag", u, "tau", "s", tuple(dt * 2.0 ** np.arange(0, 6)), False, True,
            lambda m, tau, u=u, first=first, s=float(np.std(x)) + 1e-9:
                T.actuator_lag(m, u, tau, initial=first, std=s),
            lambda tau, u=u: f"{u} through 1/(τs + 1), τ = {_num(tau)} s", READINGS["actuator_lag"], beyond=2.0,
            least=dt / model.substeps))
        out += _saturations(u, unit, x, both)
        widths = filled([float(q) for q in np.unique(np.quantile(dev, [0.05, 0.1, 0.2, 0.3, 0.45])) if q > 0], True)
        if both and widths:
            out.append(Structural(
                "dead_zone", u, "width", unit, widths, False, True,
                lambda m, a, u=u: T.dead_zone(m, u, a),
                lambda a, u=u: f"deadzone({u}, ±{_num(a)})", READINGS["dead_zone"], beyond=1.5))
        if widths:
            out.append(Structural(
                "backlash", u, "width", unit, widths, False, True,
                lambda m, a, u=u, first=first: T.backlash(m, u, a, initial=first),
                lambda a, u=u: f"play({u}, ±{_num(a)})", READINGS["backlash"], refit=False, beyond=1.5))
        out.append(Structural(
            "fractional_delay", u, "delay", "samples", FRACTIONAL_DELAYS, False, False,
            lambda m, d, u=u: T.fractional_delay(m, u, d),
            lambda d, u=u: _describe_fraction(u, d, dt), READINGS["fractional_delay"], params=2, coarser=whole,
            refit=False))
    return out


def _describe_fraction(u: str, samples: float, dt: float) -> str:
    """(1 − a)·u[k−n] + a·u[k−n−1] for a delay of n + a samples."""
    n = int(np.floor(samples))
    a = float(_num(samples - n))
    now = f"{u}[k-{n}]" if n else f"{u}[k]"
    return f"{_num(1 - a)}·{now} + {_num(a)}·{u}[k-{n + 1}] ({_num(samples * dt)} s)"


CONSTANT_FACTORS = (0.5, 0.67, 0.8, 0.9, 0.95, 0.98, 1.02, 1.05, 1.1, 1.25, 1.5, 2.0)


def constant_candidates(model: Model, equations, outputs) -> list[Structural]:
    """Per number written in a listed equation's right-hand side or a listed output's formula,
    beside the same thing in at least two of the model's equations and outputs (a damper's
    1200·(vs − vu) acting on two masses and read by an accelerometer), that number off by a
    factor (CONSTANT_FACTORS, log scale, on past an end while it is best) wherever it is written
    so. Not 0 or ±1, nor a power's exponent; a number and its negative are one; the same number
    beside something else is another (a pendulum's length 0.5 and its cart's damping 0.5). Written
    once in an equation, a catalog term on it stands in for it — unless it is the factor of a shape
    of the states (:func:`_shaped`: a pendulum's g/L on sin θ, 1.16× off, was named a linear
    stiffness, 5σ from what the truth gives it); in an output's formula, only a sensor's offset can,
    for a number added (a cell's R0 in 3.5 + 0.7·soc − 0.05·I − v1, 1.5×, was named as a sensor
    gain of 1.5, the state of charge driven to −0.63 to make up the rest). Declared parameters are
    the calibration's, not candidates."""
    places = {("", e): T.literals(model.rhs[e]) for e in model.state_names}
    places |= {("output ", v.name): T.literals(v.sym) for v in model.outputs}
    wanted = {("", e) for e in equations} | {("output ", y) for y in outputs}
    keys = sorted({(abs(c), where) for place in wanted for c, where in places[place] if abs(c) not in (0.0, 1.0)})
    out = []
    for c, where in keys:
        written = tuple(kind + name for (kind, name), lits in places.items()
                        if any(np.isclose(abs(x), c, rtol=1e-12, atol=0) and w == where for x, w in lits))
        if len(written) < 2 and _stood_in(model, written[0], where):
            continue
        text = _num(c) if float(_num(c)) == c else f"{c:.6g}"
        out.append(Structural(
            "constant", _written(text, where), "factor", "", CONSTANT_FACTORS, False, True,
            lambda m, f, c=c, where=where: T.scale_constant(m, c, f, where),
            lambda f, c=c, text=text: f"{text} × {f:.4g} = {c * f:.4g}", READINGS["constant"],
            beyond=2.0, equations=written))
    return out


def _stood_in(model: Model, place: str, where: str) -> bool:
    """Whether a number written once, at ``place`` beside ``where``, has a stand-in: a catalog term
    on its equation, unless it is the factor of a shape of the states (:func:`_shaped`) or of a
    bare state no catalog term of that equation draws (not its own, nor a position it pairs with:
    a motor's back-EMF constant on ω in di/dt, 1.2× off, was named a speed sensor's gain of 0.83);
    in an output's formula, a sensor offset for a number added, and nothing for any other."""
    if place.startswith("output "):
        return where.startswith("+")
    op, other = _beside(where)
    if op == "*" and other in model.state_names and other != place and other not in pairs(model, place):
        return False
    return not _shaped(where, model.input_names)


def _beside(where: str) -> tuple[str, str]:
    """A constant's use (:func:`transform.literals`) as (operation, what it stands beside)."""
    op, _, rest = where.partition("(")
    return op, rest[:-1]


def _shaped(where: str, inputs) -> bool:
    """Whether a number stands as the factor of a shape of the states no catalog term draws: not a
    bare state (a damping, a stiffness) nor anything of an input (its gain on its own terms)."""
    op, other = _beside(where)
    return op == "*" and not re.fullmatch(r"\w+", other) and \
        not any(re.search(rf"\b{re.escape(u)}\b", other) for u in inputs)


def _written(text: str, where: str, most: int = 24) -> str:
    """How a constant reads where it is written: '1200·(vs-vu)', '(…)/300', '0.5 + x'."""
    op, _, rest = where.split(" ")[0].partition("(")
    other = rest[:-1]
    other = other if len(other) <= most else "(…)"
    return {"*": f"{text}·{other}", "+": f"{other} ± {text}", f"{ca.OP_DIV}.1": f"{other}/{text}",
            f"{ca.OP_DIV}.0": f"{text}/{other}"}.get(op, text)


def _factor(text: str) -> str:
    """``text`` as a factor: in parentheses unless a name or a call."""
    return text if re.fullmatch(r"[\w.]+(\(.*\))?", text) else f"({text})"


def output_candidates(model: Model, outputs, recorded: np.ndarray) -> list[Structural]:
    """Per listed output, what its sensor may do: read an offset (searched over ± SENSOR_OFFSETS ×
    the recorded output's RMS, and on by threes past the largest while that is best: a speed
    hovering about 0 has an RMS below its sensor's offset), a gain (SENSOR_GAINS, on a log scale, on
    past an end that is best by its largest factor: a motor 20 % weak read as an encoder's 0.8), or saturate, upper and lower
    (the bound over the recorded output's quantiles SENSOR_QUANTILES, its extremes included).
    ``recorded``: (N, ny)."""
    out = []
    for y in outputs:
        j = model.output_names.index(y)
        x = recorded[:, j][np.isfinite(recorded[:, j])]
        if len(x) < 2:                   # never measured: no range to search
            continue
        unit = model.outputs[j].unit
        h = str(model.outputs[j].sym)           # what the sensor reads: "p + 0.02" reads as the sensor's, not a
        h = h if len(h) <= 24 else y            # correction to the reading "p_gyro + 0.02" was taken for
        size = float(np.sqrt(np.mean(x ** 2)))
        if size > 0:
            offsets = tuple(sorted(float(_num(sign * k * size)) for k in SENSOR_OFFSETS for sign in (-1, 1)))
            out.append(Structural(
                "sensor_offset", "", "offset", unit, offsets, False, False,
                lambda m, b, y=y: T.output_offset(m, y, b), lambda b, h=h: f"{h} {'-' if b < 0 else '+'} {_num(abs(b))}",
                READINGS["sensor_offset"], output=y, beyond=3.0))
        out.append(Structural(
            "sensor_gain", "", "gain", "", SENSOR_GAINS, False, True,
            lambda m, g, y=y: T.output_gain(m, y, g), lambda g, h=h: f"{_num(g)}·{_factor(h)}",
            READINGS["sensor_gain"], output=y, beyond=SENSOR_GAINS[-1]))
        for side, qs in (("upper", SENSOR_QUANTILES), ("lower", [1 - a for a in SENSOR_QUANTILES])):
            grid = tuple(sorted({float(_num(v)) for v in np.quantile(x, qs)}))
            out.append(Structural(
                "sensor_saturation", "", "bound", unit, grid, False, False,
                lambda m, b, y=y, side=side: T.output_saturation(m, y, b, side),
                lambda b, h=h, side=side: f"{'fmin' if side == 'upper' else 'fmax'}({h}, {_num(b)})",
                READINGS["sensor_saturation"], output=y, side=side))
    return out
