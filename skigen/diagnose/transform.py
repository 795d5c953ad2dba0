"""Build new models from a nominal one: copies, added terms and states, input substitutions.

Every function returns a new :class:`~skigen.Model` and leaves its argument
untouched. The symbols of the nominal model are reused, so expressions written
against the nominal model stay valid in the transformed one. These are also
the calls a corrected model file (written by the diagnosis) makes, so the
file reads as the nominal model plus a few named changes.
"""
from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
from scipy.linalg import block_diag

from ..derive.augment import memory_values as input_history
from ..model import Model, Variable

__all__ = ["copy_model", "constants", "symbols", "formula", "rate", "add_term", "add_state", "replace_input", "read",
           "input_delay", "fractional_delay", "actuator_lag", "input_saturation", "dead_zone", "smooth_dead_zone",
           "backlash", "output_offset", "output_gain", "output_saturation", "literals", "scale_constant",
           "with_disturbance", "memory_values", "load_model_file"]


def copy_model(model: Model, name: str | None = None, unknowns: bool = True) -> Model:
    """An independent copy (same symbols); ``unknowns=False`` drops the unknown term."""
    return dataclasses.replace(
        model, name=name or model.name, states=list(model.states), inputs=list(model.inputs),
        outputs=list(model.outputs), memory=list(model.memory), parameters=list(model.parameters),
        unknowns=[dataclasses.replace(b, terms=list(b.terms), prior_variance=b.prior_variance.copy(),
                                      process_std=b.process_std.copy()) for b in model.unknowns] if unknowns else [],
        x0=list(model.x0), x_std=list(model.x_std), q_std=list(model.q_std), r_std=list(model.r_std),
        rhs=dict(model.rhs), Q=None if model.Q is None else model.Q.copy(),
        R=None if model.R is None else model.R.copy(), P0=None if model.P0 is None else model.P0.copy())


def constants(model: Model) -> Model:
    """A copy whose declared parameters are constants at their values (in the dynamics, the
    outputs and the unknown term's basis): what the filters see, as a plain model."""
    if not model.parameters:
        return copy_model(model)
    m = copy_model(model)
    syms = ca.vertcat(*[p.sym for p in m.parameters])
    vals = ca.DM([p.value for p in m.parameters])
    sub = lambda e: ca.substitute(ca.SX(e), syms, vals)
    m.rhs = {k: sub(e) for k, e in m.rhs.items()}
    m.outputs = [dataclasses.replace(v, sym=sub(v.sym)) for v in m.outputs]
    for b in m.unknowns:
        b.terms = [dataclasses.replace(t, expr=sub(t.expr)) for t in b.terms]
    m.parameters = []
    return m


def symbols(model: Model) -> dict[str, ca.SX]:
    """Name → symbol of every state and input."""
    return {v.name: v.sym for v in model.states + model.inputs}


_FUNCS = {"tanh": ca.tanh, "exp": ca.exp, "log": ca.log, "sqrt": ca.sqrt, "abs": ca.fabs,
          "fabs": ca.fabs, "sin": ca.sin, "cos": ca.cos, "tan": ca.tan, "atan": ca.atan,
          "atan2": ca.atan2, "sign": ca.sign, "fmin": ca.fmin, "fmax": ca.fmax, "pi": np.pi}


def formula(model: Model, text: str) -> ca.SX:
    """A formula over the model's state and input names (with tanh, exp, abs, sign, …; ``**`` or
    ``^`` for a power) as SX: ``formula(model, "-tanh(v/0.005)")``."""
    names = symbols(model)
    try:
        power = text.strip().replace("^", "**")     # a power, as in MATLAB and on paper, binding as ** does
        value = eval(compile(power, "<formula>", "eval"), {"__builtins__": {}}, {**_FUNCS, **names})
    except NameError as exc:
        hint = ("; time is not a symbol of the model: declare an input for it (model.input('clock', unit='s')) "
                "and give the recording a 'clock' column holding the time" if exc.name in ("t", "time") else "")
        raise ValueError(f"formula '{text}': {exc} (known names: {', '.join(names)}){hint}") from None
    except SyntaxError as exc:
        raise ValueError(f"formula '{text}' is not an expression: {exc.msg}") from None
    except Exception as exc:                    # a function called wrongly, an operator on the wrong things
        raise ValueError(f"formula '{text}' cannot be evaluated: {str(exc).splitlines()[0]} (functions: "
                         f"{', '.join(k for k in _FUNCS if k != 'pi')}; ** or ^ for a power)") from None
    value = ca.SX(value)
    if value.shape != (1, 1):
        raise ValueError(f"formula '{text}' is not a scalar")
    return value


def rate(model: Model, expr) -> ca.SX:
    """A rate contribution (units of dx/dt) as it enters the model's right-hand side:
    itself for continuous models, times dt for ``discretization="discrete"``."""
    expr = ca.SX(expr)
    return expr * model.dt if model.discretization == "discrete" else expr


def add_term(model: Model, equation: str, coefficient: float, expr, name: str | None = None) -> Model:
    """dx_equation/dt += coefficient · expr (a known term; expr an SX or a formula string)."""
    m = copy_model(model, name)
    if equation not in m.rhs:
        raise ValueError(f"no equation '{equation}' in model '{model.name}' (states: {', '.join(m.state_names)})")
    expr = formula(m, expr) if isinstance(expr, str) else ca.SX(expr)
    m.rhs[equation] = m.rhs[equation] + rate(m, float(coefficient) * expr)
    return m


def add_state(model: Model, name: str, rhs, *, unit: str = "", role: str | None = None,
              initial: float = 0.0, std: float = 1.0, process_std: float = 0.0,
              sym: ca.SX | None = None) -> tuple[Model, ca.SX]:
    """A copy with one more state (its covariances extended block-diagonally); returns (model, symbol)."""
    m = copy_model(model)
    s = sym if sym is not None else ca.SX.sym(_unique(m, name))
    m.states.append(Variable(s.name(), s, unit, role))
    m.x0.append(float(initial))
    m.x_std.append(float(std))
    m.q_std.append(float(process_std))
    m.rhs[s.name()] = ca.SX(rhs(s) if callable(rhs) else rhs)
    if m.Q is not None:
        m.Q = block_diag(m.Q, [[process_std ** 2]])
    if m.P0 is not None:
        m.P0 = block_diag(m.P0, [[std ** 2]])
    return m, s


def _unique(model: Model, name: str) -> str:
    out, i = name, 2
    while out in model.names or out in [ca.SX(mm.sym).name() for mm in model.memory]:
        out, i = f"{name}{i}", i + 1
    return out


def _input(model: Model, u: str) -> ca.SX:
    for v in model.inputs:
        if v.name == u:
            return v.sym
    raise ValueError(f"model '{model.name}' has no input '{u}' (inputs: {', '.join(model.input_names)})")


def replace_input(model: Model, u: str, new, skip: tuple[str, ...] = ()) -> Model:
    """Every use of input ``u`` in the dynamics, in the outputs that read it directly (a
    feedthrough: a terminal voltage −R₀·I sees the current the cell sees) and in the unknown
    term's basis replaced by ``new``, except in the equations listed in ``skip``."""
    m = copy_model(model)
    sym, new = _input(m, u), ca.SX(new)
    m.rhs = {k: e if k in skip else ca.substitute(e, sym, new) for k, e in m.rhs.items()}
    m.outputs = [dataclasses.replace(v, sym=ca.substitute(ca.SX(v.sym), sym, new)) for v in m.outputs]
    for b in m.unknowns:   # candidate terms see what the plant sees
        b.terms = [dataclasses.replace(t, expr=ca.substitute(t.expr, sym, new)) for t in b.terms]
    return m


def input_delay(model: Model, u: str, samples: int) -> Model:
    """The plant sees u[k − samples] (exact memory carried by the filter)."""
    if int(samples) < 1:
        raise ValueError("an input delay needs at least one sample")
    return fractional_delay(model, u, int(samples))


def fractional_delay(model: Model, u: str, samples: float) -> Model:
    """The plant sees u delayed by ``samples`` = n + a (n whole, 0 ≤ a < 1):
    (1 − a)·u[k − n] + a·u[k − n − 1], the sample average of the held u delayed by (n + a)·dt."""
    if not samples > 0:
        raise ValueError(f"a delay of input '{u}' needs a positive number of samples, got {samples}")
    n = int(np.floor(samples))
    a = float(samples) - n
    m = copy_model(model)
    sym = _input(m, u)
    past = [sym] + m.input_history(sym, n + 1 if a > 0 else n)
    return replace_input(m, u, past[n] if a == 0 else (1 - a) * past[n] + a * past[n + 1])


def actuator_lag(model: Model, u: str, tau: float, initial: float = 0.0, std: float = 1.0) -> Model:
    """The plant sees a first-order lag of u with time constant tau (seconds): a new state
    ``<u>_act`` with d/dt u_act = (u − u_act)/tau, starting at ``initial``. In a discrete model
    u_act[k+1] = u_act[k] + (1 − e^(−dt/tau))·(u[k] − u_act[k]), and the plant's step k sees
    u_act[k+1], as a backlash's sees its play's new position: a lag as short as nothing is no lag
    (seeing u_act[k], it was a sample's delay, and a true 0.1 s lag was named 0.0725 s)."""
    tau = _number(tau)
    if not isinstance(tau, ca.SX) and not tau > 0:
        raise ValueError("an actuator lag needs a positive time constant")
    sym = ca.SX.sym(_unique(model, f"{u}_act"))
    uu = _input(model, u)
    if model.discretization == "discrete":
        rhs = sym + (1.0 - ca.exp(-model.dt / tau)) * (uu - sym)
        m = replace_input(model, u, rhs)
    else:
        m, rhs = replace_input(model, u, sym), (uu - sym) / tau
    m, _ = add_state(m, sym.name(), rhs, unit=_unit(m, u), initial=initial, std=std, sym=sym)
    return m


def _number(x):
    """A structural change's value: a number, or a declared parameter's symbol (refitted)."""
    return x if isinstance(x, ca.SX) else float(x)


def input_saturation(model: Model, u: str, low: float | None, high: float | None) -> Model:
    """The plant sees clip(u, low, high); a side given as None is not limited."""
    seen = _input(model, u)
    seen = seen if low is None else ca.fmax(seen, _number(low))
    return replace_input(model, u, seen if high is None else ca.fmin(seen, _number(high)))


def smooth_dead_zone(x, width: float, smooth: float):
    """sp(x − a) − sp(−x − a), sp(y) = ε log(1 + e^(y/ε)): zero inside ±a, x ∓ a outside,
    with corners rounded over about ε."""
    a, e = _number(width), _number(smooth)
    sp = lambda y: e * (ca.fmax(y / e, 0) + ca.log1p(ca.exp(-ca.fabs(y / e))))
    return sp(x - a) - sp(-x - a)


def dead_zone(model: Model, u: str, width: float, smooth: float | None = None) -> Model:
    """The plant sees nothing of u inside ±width and u ∓ width outside (smoothed over width/100)."""
    sym = _input(model, u)
    return replace_input(model, u, smooth_dead_zone(sym, width, smooth or width / 100))


def backlash(model: Model, u: str, width: float, initial: float = 0.0) -> Model:
    """The plant sees u through a play of ±width (same unit as u; gear backlash, a hysteresis):
    clip(p, u − width, u + width), p a new state ``<u>_play``, the play's last position, which
    follows that output: at once in a discrete or Euler model, with a time constant of half an
    integration step in an RK4 one. The output is exact while p has caught up (within a sample:
    RK4 closes two thirds of the gap per step); the band is not smoothed (a smoothed one would let
    the play creep while it rests)."""
    if not width > 0:
        raise ValueError(f"a backlash on input '{u}' needs a positive width, got {width}")
    sym = ca.SX.sym(_unique(model, f"{u}_play"))
    x, a = _input(model, u), float(width)
    seen = ca.fmin(ca.fmax(sym, x - a), x + a)
    m = replace_input(model, u, seen)
    h = m.dt / m.substeps
    rhs = {"discrete": seen, "euler": (seen - sym) / h}.get(m.discretization, (seen - sym) / (0.5 * h))
    m, _ = add_state(m, sym.name(), rhs, unit=_unit(m, u), initial=initial, std=a, sym=sym)
    return m


def output_offset(model: Model, y: str, offset: float) -> Model:
    """The sensor of output ``y`` reads its expression plus ``offset`` (output unit): a misaligned
    vane, an encoder zeroed away from its reference, a gyro's bias."""
    return read(model, y, lambda h: h + _number(offset))


def output_gain(model: Model, y: str, gain: float) -> Model:
    """The sensor of output ``y`` reads ``gain`` (> 0) times its expression: a scale-factor error."""
    if not isinstance(gain, ca.SX) and not float(gain) > 0:
        raise ValueError(f"output '{y}': a sensor gain is positive, got {gain}")
    return read(model, y, lambda h: _number(gain) * h)


def output_saturation(model: Model, y: str, bound: float, side: str) -> Model:
    """The sensor of output ``y`` reads no more than ``bound`` (side "upper") or no less ("lower"),
    in the output's unit: its expression clipped, the quantity itself unbounded."""
    if side not in ("upper", "lower"):
        raise ValueError(f"output '{y}': a saturation side is 'upper' or 'lower', got {side!r}")
    clip = ca.fmin if side == "upper" else ca.fmax
    return read(model, y, lambda h: clip(h, _number(bound)))


def read(model: Model, y: str, reading) -> Model:
    """A copy whose output ``y`` reads ``reading(h)`` instead of its expression h."""
    m = copy_model(model)
    i = next((j for j, v in enumerate(m.outputs) if v.name == y), None)
    if i is None:
        raise ValueError(f"model '{model.name}' has no output '{y}' (outputs: {', '.join(m.output_names)})")
    m.outputs[i] = dataclasses.replace(m.outputs[i], sym=ca.SX(reading(ca.SX(m.outputs[i].sym))))
    return m


def _unit(model: Model, u: str) -> str:
    return next(v.unit for v in model.inputs if v.name == u)


EXPONENTS = (ca.OP_POW, ca.OP_CONSTPOW)        # their second operand is a power, not a constant of the plant


def _replay(expr: ca.SX, swap) -> ca.SX:
    """``expr`` rebuilt operation by operation, each use of a literal constant c by a binary
    operation replaced by ``swap(c, context)`` (kept where that returns None); ``context``: what
    the constant multiplies, divides or is added to in that use (:func:`_context`). Uses are
    replaced one by one: CasADi keeps one node for equal constants, and a motor's inductance 0.1
    dividing di/dt and its back-EMF constant 0.1 on ω there are two numbers of the model. The
    constants are those CasADi keeps as written, and the 2 of 2·x, which it keeps as an operation
    (a conductance G = 2 in G·(T1 − T2) was invisible); a power's exponent is none of them."""
    expr = ca.SX(expr)
    syms = ca.symvar(expr)
    f = ca.Function("f", syms, [expr])
    n = f.n_instructions()
    ops, ins, outs = ([g(k) for k in range(n)] for g in (f.instruction_id, f.instruction_input, f.instruction_output))

    def run(change):
        work, last = {}, {}                          # register → its value, and the instruction that wrote it
        for k in range(n):
            op, a, b = ops[k], ins[k], outs[k]
            if op == ca.OP_CONST:
                work[b[0]] = ca.SX(f.instruction_constant(k))
            elif op == ca.OP_INPUT:
                work[b[0]] = syms[a[0]]
            elif op == ca.OP_OUTPUT:
                return work[a[0]]
            elif len(a) == 2 and a[1] >= 0:
                args = [work[a[0]], work[a[1]]]
                for slot, r in enumerate(a[:2]):     # each use of a constant, and beside what
                    if ops[last[r]] == ca.OP_CONST and (new := change(k, slot, f.instruction_constant(last[r]),
                                                                      args[1 - slot])) is not None:
                        args[slot] = ca.SX(new)
                work[b[0]] = ca.SX.binary(op, *args)
            elif op == ca.OP_TWICE:                  # 2·x: CasADi keeps the 2 in the operation
                new = change(k, 0, 2.0, work[a[0]])
                work[b[0]] = ca.SX.unary(op, work[a[0]]) if new is None else ca.SX(new) * work[a[0]]
            else:
                work[b[0]] = ca.SX.unary(op, work[a[0]])
            last[b[0]] = k
        return expr                                  # a constant expression: nothing to replay
    contexts = {}

    def seen(k, slot, value, other):
        contexts[k, slot] = _context(ca.OP_MUL if ops[k] == ca.OP_TWICE else ops[k], slot, other)
    run(seen)
    return run(lambda k, slot, value, other: None if contexts[k, slot] is None else swap(value, contexts[k, slot]))


def _context(op: int, slot: int, other) -> str | None:
    """What a constant stands beside in one use, as text ('*((vs-vu))'; a sum's '+(…)'; another
    operation's code and the constant's operand slot, '4.1(…)' for a divisor); None where it is a
    power's exponent."""
    if op in EXPONENTS and slot == 1:
        return None
    sign = {ca.OP_MUL: "*", ca.OP_ADD: "+", ca.OP_SUB: "+"}.get(op) or f"{op}.{slot}"   # commuting: no slot
    return f"{sign}({other})"


def literals(expr) -> list[tuple[float, str]]:
    """The literal constants of ``expr`` as written, each with what it stands beside (not a
    power's exponent)."""
    seen = []
    _replay(expr, lambda c, where: seen.append((c, where)))
    return seen


def scale_constant(model: Model, value: float, factor, context: str | None = None) -> Model:
    """A copy in which every literal constant of magnitude ``value`` (standing beside ``context``,
    when given, as :func:`literals` says: a damper's 1200·(vs − vu), not a spring's 1200·(zs − zu))
    in the dynamics and the outputs (in two equations and an accelerometer's formula, whichever
    its sign) is ``factor`` times itself: one number of the model off."""
    m = copy_model(model)

    def same(c, where):
        hit = np.isclose(abs(c), abs(value), rtol=1e-12, atol=0) and context in (None, where)
        return c * _number(factor) if hit else None
    m.rhs = {k: _replay(e, same) for k, e in m.rhs.items()}
    m.outputs = [dataclasses.replace(v, sym=_replay(v.sym, same)) for v in m.outputs]
    return m


def with_disturbance(model: Model, equations, process_std, std) -> tuple[Model, list[str]]:
    """The model with a random-walk disturbance d_j added to each listed equation
    (in units of dx_j/dt); returns it and the disturbance state names."""
    m, names = copy_model(model, unknowns=False), []
    for eq, q, s in zip(equations, np.broadcast_to(process_std, (len(equations),)),
                        np.broadcast_to(std, (len(equations),))):
        d = ca.SX.sym(_unique(m, f"d_{eq}"))
        m.rhs[eq] = m.rhs[eq] + rate(m, d)
        m, _ = add_state(m, d.name(), d if m.discretization == "discrete" else 0,
                         initial=0.0, std=float(s), process_std=float(q), sym=d)
        names.append(d.name())
    return m, names


def memory_values(model: Model, rec) -> np.ndarray:
    """The model's input history at every sample of a recording: u[k − lag] (0 before the start)."""
    return input_history(model, rec.inputs)


def load_model_file(spec: str) -> Model:
    """The ``model`` of a model file, or ``package.module:attribute`` (as the CLI reads them)."""
    from ..modelfile import load_model
    return load_model(spec)
