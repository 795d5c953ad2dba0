"""Declaring a dynamics model with an unknown term, in CasADi symbols.

A model is built in a few calls; every symbol has a name and every error
names the symbol, equation or matrix at fault::

    model = Model("wingrock", dt=0.02, discretization="rk4")
    theta = model.state("theta", unit="deg", role="angle", std=1.0)
    p = model.state("p", unit="deg/s", role="rate", std=1.0)
    delta = model.input("delta", unit="deg")
    model.dynamics({theta: p, p: 3 * delta})
    model.output("phi", theta, unit="deg", noise_std=0.1)
    model.unknown("p", polynomial([theta, p], 1) + abs_products([(theta, p)]))
"""
from __future__ import annotations

import keyword
import sys
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .library import Term

__all__ = ["Model", "ModelError", "Parameter", "ROLES", "POSITION_ROLES", "DISCRETIZATIONS", "INPUT_HOLDS"]

ROLES = ("position", "velocity", "angle", "rate", "altitude")
POSITION_ROLES = ("position", "angle", "altitude")     # roles whose rate may be a declared state (ẋ = v)
DISCRETIZATIONS = ("rk4", "euler", "discrete")
INPUT_HOLDS = ("zoh", "foh")     # input held over the sample, or interpolated linearly to the next
C_KEYWORDS = frozenset("""auto break case char const continue default do double else enum extern float for goto
    if inline int long register restrict return short signed sizeof static struct switch typedef union unsigned
    void volatile while _Bool _Complex _Imaginary""".split())
# Names a declaration may not take: result-table columns, the diagnosis's formula functions and the
# names a written model file binds (a symbol named like them would overwrite or be shadowed).
RESERVED = frozenset("""t time timestamp nis loglik status measured code tanh exp log sqrt abs fabs sin cos tan
    atan atan2 sign fmin fmax pi model ca np Model Path load_model""".split())
RESERVED_PREFIXES = ("std_", "innov_", "measured_", "prior_var_", "w_")


class ModelError(ValueError):
    """A model declaration that cannot be used; the message names the culprit, ``where`` the
    (file, line) that declared it when known."""

    where: tuple[str, int] | None = None


def _caller() -> tuple[str, int]:
    """(file, line) of the call into the :class:`Model` method that calls this."""
    frame = sys._getframe(2)
    return frame.f_code.co_filename, frame.f_lineno


def function_name_problem(name: str) -> str | None:
    """Why ``name`` cannot begin CasADi Function names (skigen names them ``<name>_<suffix>``:
    CasADi's start with a letter and have no two underscores in a row), or None."""
    if not name[:1].isalpha():
        return "it does not start with a letter"
    if "__" in name:
        return "it has two underscores in a row"
    if name.endswith("_"):
        return "it ends with '_' (skigen appends '_<suffix>': two underscores in a row)"
    return None


@dataclass(frozen=True)
class Variable:
    """A named scalar symbol with its unit and, for states, a physical role."""

    name: str
    sym: ca.SX
    unit: str = ""
    role: str | None = None


@dataclass(frozen=True)
class Memory:
    """A deterministic delayed input: ``sym[k] = source[k - lag]``."""

    sym: ca.SX
    source: str
    lag: int


@dataclass(frozen=True)
class Parameter:
    """A constant the user is unsure of: its value, and optionally a prior std and bounds."""

    name: str
    sym: ca.SX
    value: float
    unit: str = ""
    std: float | None = None
    bounds: tuple[float, float] = (-np.inf, np.inf)


@dataclass
class UnknownBlock:
    """Weights of basis terms entering the listed state equations."""

    equations: tuple[str, ...]
    terms: list[Term]
    prior_variance: np.ndarray
    process_std: np.ndarray


@dataclass
class Model:
    """A discrete-time state-space model with an unknown linear-in-weights term.

    dt: sample time (s). discretization: ``"rk4"`` or ``"euler"`` for
    continuous dynamics (dx/dt), ``"discrete"`` when :meth:`dynamics` gives
    x[k+1] directly. substeps: integration steps per sample. input_hold:
    ``"zoh"`` holds each input over the sample; ``"foh"`` interpolates it
    linearly from u[k] to u[k+1] (the filter step then takes both, see
    :func:`skigen.derive.step_inputs`).
    """

    name: str
    dt: float
    discretization: str = "rk4"
    substeps: int = 1
    input_hold: str = "zoh"
    states: list[Variable] = field(default_factory=list)
    inputs: list[Variable] = field(default_factory=list)
    outputs: list[Variable] = field(default_factory=list)
    memory: list[Memory] = field(default_factory=list)
    parameters: list[Parameter] = field(default_factory=list)
    unknowns: list[UnknownBlock] = field(default_factory=list)
    x0: list[float] = field(default_factory=list)
    x_std: list[float] = field(default_factory=list)
    q_std: list[float] = field(default_factory=list)
    r_std: list[float | None] = field(default_factory=list)
    rhs: dict[str, ca.SX] = field(default_factory=dict)
    Q: np.ndarray | None = None
    R: np.ndarray | None = None
    P0: np.ndarray | None = None
    sites: dict = field(default_factory=dict, repr=False, compare=False)   # what → (file, line) declaring it

    def __post_init__(self):
        if not (isinstance(self.name, str) and self.name.isidentifier() and self.name.isascii()
                and self.name not in C_KEYWORDS):
            raise ModelError(f"model name {self.name!r} must be an ASCII identifier (letters, digits, _; "
                             f"not starting with a digit, not a C keyword): it prefixes the generated C")
        why = function_name_problem(self.name)
        if why:
            raise ModelError(f"model name '{self.name}' cannot name CasADi Functions: {why}; CasADi's start "
                             f"with a letter and have no two underscores in a row ('{self.name}_ekf_step'); "
                             f"choose another")
        if not (isinstance(self.dt, (int, float)) and np.isfinite(self.dt) and self.dt > 0):
            raise ModelError(f"model '{self.name}': sample time dt must be positive, got {self.dt}")
        if self.discretization not in DISCRETIZATIONS:
            raise ModelError(f"model '{self.name}': discretization must be one of "
                             f"{DISCRETIZATIONS}, got '{self.discretization}'")
        if self.input_hold not in INPUT_HOLDS:
            raise ModelError(f"model '{self.name}': input_hold must be one of {INPUT_HOLDS}, "
                             f"got '{self.input_hold}'")
        if self.input_hold == "foh" and self.discretization == "discrete":
            raise ModelError(f"model '{self.name}': input_hold='foh' interpolates inputs within the "
                             f"sample, which needs continuous dynamics (rk4 or euler), not 'discrete'")
        if not (isinstance(self.substeps, int) and not isinstance(self.substeps, bool) and self.substeps >= 1):
            raise ModelError(f"model '{self.name}': substeps must be a positive integer, "
                             f"got {self.substeps!r}")

    # ----------------------------------------------------------- declaration
    def _fresh(self, name: str, what: str) -> ca.SX:
        if not (isinstance(name, str) and name.isidentifier() and name.isascii()):
            raise ModelError(f"{what} name {name!r} must be an identifier (ASCII letters, digits, _; not "
                             f"starting with a digit): it names C symbols and result columns")
        prefix = next((p for p in RESERVED_PREFIXES if name.startswith(p)), None)
        why = ("a C keyword" if name in C_KEYWORDS else "a Python keyword" if keyword.iskeyword(name) else
               "a result column or a formula function" if name in RESERVED else
               f"it starts with '{prefix}', which names result columns ({', '.join(RESERVED_PREFIXES)} are taken)"
               if prefix else None)
        if why:
            raise ModelError(f"{what} name '{name}' is reserved: {why}; choose another")
        if name in self.names:
            taken = next(kind for kind, names in (("state", self.state_names), ("input", self.input_names),
                                                  ("output", self.output_names), ("parameter", self.parameter_names))
                         if name in names)
            raise ModelError(f"{what} '{name}' is declared twice" if taken == what else
                             f"{what} '{name}': the name is already {'an' if taken[0] in 'aeiou' else 'a'} "
                             f"{taken}'s; choose another")
        return ca.SX.sym(name)

    def state(self, name: str, unit: str = "", role: str | None = None, *,
              initial: float = 0.0, std: float = 1.0, process_std: float = 0.0) -> ca.SX:
        """Declare a state; returns its symbol. std: initial standard deviation,
        process_std: process-noise standard deviation per sample (state units)."""
        if role is not None and role not in ROLES:
            raise ModelError(f"state '{name}': role must be one of {ROLES}, got '{role}'")
        sym = self._fresh(name, "state")
        initial = _finite(initial, f"state '{name}': initial")
        std = _non_negative(std, f"state '{name}': std")
        process_std = _non_negative(process_std, f"state '{name}': process_std")
        self.states.append(Variable(name, sym, unit, role))
        self.sites[f"state '{name}'"] = _caller()
        self.x0.append(initial)
        self.x_std.append(std)
        self.q_std.append(process_std)
        return sym

    def input(self, name: str, unit: str = "") -> ca.SX:
        """Declare an input (known, measured every sample); returns its symbol."""
        sym = self._fresh(name, "input")
        self.inputs.append(Variable(name, sym, unit))
        return sym

    def parameter(self, name: str, value: float, *, unit: str = "", std: float | None = None,
                  bounds: tuple[float, float] | None = None) -> ca.SX:
        """Declare a constant the user is unsure of; returns its symbol, usable in the
        dynamics, outputs and basis terms. value: its current value (units ``unit``);
        std: prior standard deviation; bounds: (low, high), either may be ±inf.
        Filters use the current value unless asked to estimate it
        (``derive(..., estimate=[name])``); ``skigen fit`` estimates it offline."""
        value = _finite(value, f"parameter '{name}': value")
        if std is not None:
            std = _finite(std, f"parameter '{name}': std")
            if std <= 0:
                raise ModelError(f"parameter '{name}': std must be positive, got {std}")
        lo, hi = (-np.inf, np.inf) if bounds is None else _bounds(bounds, name)
        if not lo <= value <= hi:
            raise ModelError(f"parameter '{name}': value {value} is outside its bounds [{lo}, {hi}]")
        sym = self._fresh(name, "parameter")
        self.parameters.append(Parameter(name, sym, value, unit, std, (lo, hi)))
        return sym

    def set_parameters(self, values: dict[str, float], std: dict[str, float] | None = None) -> "Model":
        """Change parameters' values (and prior std) in place, by name; returns the model."""
        std = std or {}
        for key in list(values) + list(std):
            self.parameter_named(key)
        for i, p in enumerate(self.parameters):
            if p.name in values or p.name in std:
                value = _finite(values.get(p.name, p.value), f"parameter '{p.name}': value")
                if not p.bounds[0] <= value <= p.bounds[1]:
                    raise ModelError(f"parameter '{p.name}': value {value} is outside its bounds "
                                     f"[{p.bounds[0]}, {p.bounds[1]}]")
                s = std.get(p.name, p.std)
                if s is not None and not (np.isfinite(s) and s > 0):
                    raise ModelError(f"parameter '{p.name}': std must be positive and finite, got {s}")
                self.parameters[i] = Parameter(p.name, p.sym, value, p.unit,
                                               None if s is None else float(s), p.bounds)
        return self

    def parameter_named(self, name: str) -> Parameter:
        """The declared parameter ``name``; ModelError naming the known ones otherwise."""
        for p in self.parameters:
            if p.name == name:
                return p
        raise ModelError(f"model '{self.name}' has no parameter '{name}' (parameters: "
                         f"{', '.join(self.parameter_names) or 'none'})")

    def output(self, name: str, expr, unit: str = "", *, noise_std: float | None = None):
        """Declare a measured output y = h(x, u) with its noise standard deviation."""
        self._fresh(name, "output")
        if noise_std is not None:
            noise_std = _non_negative(noise_std, f"output '{name}': noise_std")
        try:
            expr = ca.SX(expr)
        except (NotImplementedError, TypeError, RuntimeError):
            raise ModelError(f"output '{name}': expected a CasADi expression or a number, got {expr!r}") from None
        self.outputs.append(Variable(name, expr, unit))
        self.sites[f"output '{name}'"] = _caller()
        self.r_std.append(noise_std)

    def dynamics(self, equations: dict):
        """State equations keyed by state symbol or name: dx/dt, or x[k+1]
        when ``discretization="discrete"``."""
        for key, expr in equations.items():
            name = key if isinstance(key, str) else _sym_name(key)
            if name not in self.state_names:
                raise ModelError(f"dynamics given for '{name}', which is not a declared state "
                                 f"(states: {', '.join(self.state_names)})")
            self.rhs[name] = ca.SX(expr)
            self.sites[f"dynamics of '{name}'"] = _caller()

    def input_history(self, u: ca.SX, length: int) -> list[ca.SX]:
        """Symbols for u[k-1], …, u[k-length]: exact memory carried by the filter."""
        name = _sym_name(u)
        if name not in self.input_names:
            raise ModelError(f"input history asked for '{name}', which is not a declared input")
        have = {(m.source, m.lag): m.sym for m in self.memory}
        out = []
        for lag in range(1, length + 1):
            if (name, lag) not in have:
                have[(name, lag)] = ca.SX.sym(f"{name}_d{lag}")
                self.memory.append(Memory(have[(name, lag)], name, lag))
            out.append(have[(name, lag)])
        return out

    def unknown(self, equations, basis: list[Term], *, prior_variance=1.0, process_std=0.0):
        """Add the unknown term Σ w_i φ_i to the given state equation(s).

        A scalar term gets one weight per equation; a term whose expression
        has one entry per equation is a direction and gets one shared weight.
        prior_variance: initial ARD prior variance of each weight (scalar or
        one per weight); process_std: random-walk std of the weights per sample.
        """
        if isinstance(equations, (str, ca.SX)):
            equations = [equations]
        equations = tuple(e if isinstance(e, str) else _sym_name(e) for e in equations)
        for eq in equations:
            if eq not in self.state_names:
                raise ModelError(f"unknown term on equation '{eq}', which is not a declared state "
                                 f"(states: {', '.join(self.state_names)})")
        for t in basis:
            if not (isinstance(t.key, str) and t.key.isidentifier() and t.key.isascii()):
                raise ModelError(f"basis term '{t.name}' has key {t.key!r}; a key must be an identifier (ASCII "
                                 f"letters, digits, _): it names the weight's C symbols and result columns")
            if t.expr.shape not in ((1, 1), (len(equations), 1)):
                raise ModelError(f"basis term '{t.name}' has shape {t.expr.shape}; expected a scalar "
                                 f"or a column of {len(equations)} (one per equation)")
        site = _caller()
        self.sites.update({f"{kind} '{t.name}'": site for t in basis for kind in ("term", "basis term")})
        count = sum(len(equations) if t.expr.shape == (1, 1) and len(equations) > 1 else 1
                    for t in basis)
        self.unknowns.append(UnknownBlock(equations, list(basis),
                                          _per_weight(prior_variance, count, "prior_variance"),
                                          _per_weight(process_std, count, "process_std")))

    def covariances(self, *, Q=None, R=None, P0=None):
        """Override the diagonal noise and initial covariances with full matrices
        (Q, P0 over the physical states; R over the outputs)."""
        self.Q, self.R, self.P0 = (None if M is None else np.atleast_2d(np.asarray(M, float))
                                   for M in (Q, R, P0))

    # ---------------------------------------------------------------- views
    @property
    def names(self) -> list[str]:
        return self.state_names + self.input_names + [v.name for v in self.outputs] + self.parameter_names

    @property
    def parameter_names(self) -> list[str]:
        return [p.name for p in self.parameters]

    @property
    def state_names(self) -> list[str]:
        return [v.name for v in self.states]

    @property
    def input_names(self) -> list[str]:
        return [v.name for v in self.inputs]

    @property
    def output_names(self) -> list[str]:
        return [v.name for v in self.outputs]

    def weights(self) -> list[tuple[str, str, Term, ca.SX]]:
        """(weight name, its equation (a direction's: joined by '+'), term, the term's expression there) per weight.

        A weight is named ``w_<term key>``, or ``w_<equation>_<term key>`` where
        the same term enters several equations with separate weights.
        """
        out = []
        for b in self.unknowns:
            for t in b.terms:
                if t.expr.shape == (1, 1) and len(b.equations) > 1:
                    out += [(eq, t, t.expr) for eq in b.equations]     # one weight per equation
                else:
                    out.append(("+".join(b.equations), t, t.expr))
        keys = [t.key for _, t, _ in out]
        return [(f"w_{t.key}" if keys.count(t.key) == 1 else f"w_{eq.replace('+', '_')}_{t.key}", eq, t, d)
                for eq, t, d in out]

    @property
    def weight_names(self) -> list[str]:
        return [w[0] for w in self.weights()]

    # ------------------------------------------------------------ validation
    def check(self) -> "Model":
        """Validate the declaration; raise :class:`ModelError` naming the problem (and, as its
        ``where``, the line that declared it: a model file's loader says the line)."""
        try:
            return self._check()
        except ModelError as exc:
            culprit, missing = str(exc), "no dynamics for state(s) "
            if culprit.startswith(missing):                  # the first state without an equation
                culprit = f"state '{culprit[len(missing):].split(',')[0]}'"
            exc.where = exc.where or next((site for what, site in self.sites.items() if culprit.startswith(what)), None)
            raise

    def _check(self) -> "Model":
        if not self.states:
            raise ModelError(f"model '{self.name}' declares no states")
        if not self.outputs:
            raise ModelError(f"model '{self.name}' declares no outputs")
        missing = [n for n in self.state_names if n not in self.rhs]
        if missing:
            raise ModelError(f"no dynamics for state(s) {', '.join(missing)}")
        known = {ca.SX(v.sym).element_hash(): v.name for v in self.states + self.inputs + self.parameters}
        known |= {ca.SX(m.sym).element_hash(): _sym_name(m.sym) for m in self.memory}
        for name, expr in self.rhs.items():
            _check_scalar(expr, f"dynamics of '{name}'")
            _check_symbols(expr, known, f"dynamics of '{name}'")
        informative = ca.vertcat(*[v.sym for v in self.states] + [p.sym for p in self.parameters])
        for v in self.outputs:
            _check_scalar(v.sym, f"output '{v.name}'")
            _check_symbols(v.sym, known, f"output '{v.name}'")
            if not ca.depends_on(v.sym, informative):
                raise ModelError(f"output '{v.name}' depends on no state or parameter (it is "
                                 f"{'a constant' if ca.SX(v.sym).is_constant() else 'a function of the inputs alone'}): "
                                 f"its readings cannot tell the filter anything; write what the sensor reads")
        names = {}
        for wname, eq, t, _ in self.weights():
            if not t.name.strip():
                raise ModelError(f"a basis term on equation '{eq}' (key '{t.key}') has an empty name: name it "
                                 f"(the name labels its weight in the summaries and the generated C)")
            _check_symbols(t.expr, known, f"basis term '{t.name}'")
            if ca.SX(t.expr).is_zero():
                raise ModelError(f"basis term '{t.name}' (key '{t.key}') on equation '{eq}' is identically 0: "
                                 f"its weight could have no effect")
            if wname in names:
                raise ModelError(f"basis term '{t.name}' (key '{t.key}') is declared twice on equation '{eq}': "
                                 f"each term enters an equation once" if names[wname] == t.name else
                                 f"basis terms '{names[wname]}' and '{t.name}' on equation '{eq}' have the same "
                                 f"key '{t.key}' (their names written as identifiers): give one its own "
                                 f"(term(name, expr, key=...))")
            names[wname] = t.name
        clash = set(names) & set(self.names)
        if clash:
            raise ModelError(f"weight name(s) {', '.join(sorted(clash))} collide with a declared name")
        self._check_proportional_terms()
        self._check_finite_at_start()
        if self.P0 is None and (known := [n for n, s in zip(self.state_names, self.x_std) if s == 0]):
            raise ModelError(f"state(s) {', '.join(map(repr, known))} declare std=0 (an initial value known "
                             f"exactly): the filters factor the initial covariance and need it positive; give a "
                             f"small std (say 1e-6 of the state's scale)")
        _check_covariance(self.process_noise(), "Q (process noise)", self.state_names, definite=False)
        _check_covariance(self.measurement_noise(), "R (measurement noise)", self.output_names)
        _check_covariance(self.initial_covariance(), "P0 (initial covariance)", self.state_names)
        return self

    def _check_proportional_terms(self):
        """No two scalar basis terms on one equation are one expression times a constant (x and 2·x,
        a term declared twice under two keys): their weights could not be told apart, and each would
        be reported within its error bar of 0. Judged on the expressions (constant factors,
        divisors and signs set aside), so that two saturations of different widths, alike at most
        values, are not taken for one."""
        groups: dict[str, list] = {}
        for w in self.weights():
            if w[3].shape == (1, 1):
                groups.setdefault(w[1], []).append((w, *_factored(ca.SX(w[3]))))
        for eq, ws in groups.items():
            for i, ((wi, _, ti, _), ki, ci) in enumerate(ws):
                for (wj, _, tj, _), kj, cj in ws[:i]:
                    if ca.is_equal(ci, cj, 64):
                        raise ModelError(f"basis terms '{tj.name}' and '{ti.name}' on equation '{eq}' are "
                                         f"proportional ('{ti.name}' = {ki / kj:.6g} × '{tj.name}'): their weights "
                                         f"{wj} and {wi} cannot be told apart; keep one")

    def _check_finite_at_start(self):
        """Every equation and output is finite at the declared initial state (inputs, history 0)."""
        syms = [v.sym for v in self.states + self.inputs] + [m.sym for m in self.memory] + [p.sym for p in self.parameters]
        values = list(self.x0) + [0.0] * (len(self.inputs) + len(self.memory)) + [p.value for p in self.parameters]
        exprs = [(f"dynamics of '{n}'", self.rhs[n]) for n in self.state_names] + \
                [(f"output '{v.name}'", v.sym) for v in self.outputs] + \
                [(f"term '{t.name}' of the unknown on {', '.join(map(repr, b.equations))}", e)
                 for b in self.unknowns for t in b.terms for e in ca.vertsplit(ca.vec(t.expr))]
        f = ca.Function("at_start", [ca.vertcat(*syms)], [ca.vertcat(*[e for _, e in exprs])])
        out = np.asarray(f(values)).ravel()
        for (what, _), v in zip(exprs, out):
            if not np.isfinite(v):
                raise ModelError(f"{what} is {v} at the declared initial state (inputs 0): a non-finite "
                                 f"constant, or an expression undefined there")

    def kinematic(self) -> list[str]:
        """The states whose equation is a kinematic identity dx/dt = v (x of a position, angle or
        altitude role, v a declared state): exact by definition, their process noise a numerical
        allowance, not a disturbance."""
        names = set(self.state_names)
        return [v.name for v in self.states if v.role in POSITION_ROLES
                and self.rhs[v.name].is_symbolic() and self.rhs[v.name].name() in names]

    def unstable_step(self) -> str | None:
        """Why a run diverges when the integration step amplifies a mode the dynamics damp (the
        state Jacobian at the declared initial state, inputs and history 0), with the fewest
        substeps that damp it; None when no mode is amplified. A local, linear reading: a steep
        but saturating term (a narrow tanh) is amplified there without any run diverging, so it
        explains a divergence seen, it does not refuse a model."""
        lam = self._damped_modes()
        if lam is None:
            return None
        amplified = lambda n: np.abs(_step_gain(self.discretization, lam * self.dt / n)) > 1 + 1e-9
        now = lam[amplified(self.substeps)]
        if not now.size:
            return None
        worst = now[np.argmax(np.abs(now))]
        lo, n = self.substeps, 2 * self.substeps          # the fewest substeps that damp it: double, then bisect
        while amplified(n).any():
            lo, n = n, 2 * n
        while n - lo > 1:
            lo, n = ((lo + n) // 2, n) if amplified((lo + n) // 2).any() else (lo, (lo + n) // 2)
        return (f"model '{self.name}': its {self.discretization} step of {self.dt / self.substeps:g} s amplifies "
                f"a mode the dynamics damp (eigenvalue {_complex(worst)} /s of the state Jacobian at the declared "
                f"initial state, time constant {1 / abs(worst.real):.3g} s). Give substeps={n} or more, or a "
                f"shorter dt")

    def step_error(self) -> tuple[float, complex, int] | None:
        """The integration's largest relative error over one step among the damped modes,
        |R(λh) − e^(λh)| / e^(Re λh) (the state Jacobian at the declared initial state), that
        mode's eigenvalue λ (1/s), and the fewest substeps (doubling) that bring it below 0.1 %;
        None for a discrete model or one without damped modes."""
        lam = self._damped_modes()
        if lam is None or not lam.size:
            return None
        z = lambda n: lam * self.dt / n
        err = lambda n: np.abs(_step_gain(self.discretization, z(n)) - np.exp(z(n))) / np.exp(np.maximum(z(n).real, -700))
        n = self.substeps
        while err(n).max() > 1e-3 and n < 10 ** 6:
            n *= 2
        return float(err(self.substeps).max()), complex(lam[np.argmax(err(self.substeps))]), n

    def step_note(self, jacobians, where: str) -> str | None:
        """What the integration step does to the mode of the rates' Jacobians ``jacobians`` (1/s,
        taken ``where``) it misplaces most, when by MODE_OFF of its damping or more
        (:func:`mode_error`), and the substeps that bring it under a quarter of that (the
        Jacobians are of estimates the step biased: a yaw damping fitted 6.8 for 8 under Euler
        asked for 2 substeps, which gave 7.4 and asked for 4); None otherwise or for a discrete
        model."""
        if self.discretization == "discrete":
            return None
        said = [(e, A) for A in jacobians if (e := mode_error(np.asarray(A, float), self.discretization,
                                                               self.dt / self.substeps)) is not None]
        if not said or (worst := max(said, key=lambda s: s[0][0]))[0][0] < MODE_OFF:
            return None
        (_, lam, step), A = worst
        n = self.substeps
        while n < 4096 and mode_error(A, self.discretization, self.dt / n)[0] >= MODE_OFF / 4:
            n *= 2
        what = f"decay rate {-lam.real:.3g} → {-step.real:.3g} /s" + (
            f", frequency {abs(lam.imag):.4g} → {abs(step.imag):.4g} rad/s" if lam.imag else "")
        return (f"the {self.discretization} step of {self.dt / self.substeps:g} s moves the mode at {_complex(lam)} /s "
                f"(the rates' Jacobian {where}) to {_complex(step)} /s ({what}): what sets that mode may absorb the "
                f"step's error, beyond its ± 2σ; " + _finer(self.discretization, n))

    def state_jacobian(self) -> np.ndarray | None:
        """∂(dx/dt)/∂x at the declared initial state, parameters at their values, inputs and
        history 0 (1/s); None for a discrete model or one not finite there."""
        if self.discretization == "discrete":
            return None
        x = ca.vertcat(*[v.sym for v in self.states])
        syms = [v.sym for v in self.inputs] + [m.sym for m in self.memory] + [p.sym for p in self.parameters]
        values = [0.0] * (len(self.inputs) + len(self.memory)) + [p.value for p in self.parameters]
        jac = ca.jacobian(ca.vertcat(*[self.rhs[n] for n in self.state_names]), x)
        A = np.asarray(ca.Function("state_jacobian", [x, ca.vertcat(*syms)], [jac])(self.x0, values))
        return A if np.isfinite(A).all() else None

    def _damped_modes(self) -> np.ndarray | None:
        """Eigenvalues with negative real part of the state Jacobian at the declared initial state
        (inputs, history 0); None for a discrete model or a Jacobian not finite there."""
        A = self.state_jacobian()
        if A is None:
            return None
        lam = np.linalg.eigvals(A)
        return lam[lam.real < 0]

    def process_noise(self) -> np.ndarray:
        """Q over the physical states, per sample (state units²)."""
        return self.Q if self.Q is not None else np.diag(np.square(self.q_std))

    def measurement_noise(self) -> np.ndarray:
        """R over the outputs (output units²)."""
        if self.R is not None:
            return self.R
        for v, s in zip(self.outputs, self.r_std):
            if s is None:
                raise ModelError(f"output '{v.name}' has no noise_std and no R was given")
        return np.diag(np.square(np.asarray(self.r_std, float)))

    def initial_covariance(self) -> np.ndarray:
        """P0 over the physical states (state units²)."""
        return self.P0 if self.P0 is not None else np.diag(np.square(self.x_std))

    def prior_variances(self) -> np.ndarray:
        """Initial ARD prior variance of every weight."""
        return np.concatenate([b.prior_variance for b in self.unknowns]) if self.unknowns else np.zeros(0)

    def weight_process_std(self) -> np.ndarray:
        return np.concatenate([b.process_std for b in self.unknowns]) if self.unknowns else np.zeros(0)


def _sym_name(s) -> str:
    s = ca.SX(s)
    if not (s.shape == (1, 1) and s.is_symbolic()):
        raise ModelError(f"expected a declared symbol, got expression {s}")
    return s.name()


def _finite(value, what: str) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ModelError(f"{what} must be a number, got {value!r}") from None
    if not np.isfinite(value):
        raise ModelError(f"{what} must be finite, got {value}")
    return value


def _non_negative(value, what: str) -> float:
    value = _finite(value, what)
    if value < 0:
        raise ModelError(f"{what} must be non-negative (a standard deviation), got {value}")
    return value


def _bounds(bounds, name: str) -> tuple[float, float]:
    try:
        lo, hi = (float(b) for b in bounds)
    except (TypeError, ValueError):
        raise ModelError(f"parameter '{name}': bounds must be (low, high), got {bounds!r}") from None
    if np.isnan(lo) or np.isnan(hi) or not lo < hi:
        raise ModelError(f"parameter '{name}': bounds must satisfy low < high, got ({lo}, {hi})")
    return lo, hi


def _per_weight(value, count: int, what: str) -> np.ndarray:
    arr = np.broadcast_to(np.asarray(value, float), (count,)) if np.ndim(value) == 0 else np.asarray(value, float)
    if arr.shape != (count,):
        raise ModelError(f"{what} has {arr.size} entries for {count} weights")
    if what == "prior_variance" and not np.all(arr > 0):
        raise ModelError(f"prior_variance must be positive, got {arr}")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ModelError(f"{what} must be finite and non-negative, got {arr}")
    return arr.copy()


def _complex(z) -> str:
    return f"{z.real:.4g}" if z.imag == 0 else f"{z.real:.4g} ± {abs(z.imag):.4g}j"


def _step_gain(method: str, z):
    """The integrator's amplification of a linear mode over one step, z = λ·h."""
    return 1 + z if method == "euler" else 1 + z + z ** 2 / 2 + z ** 3 / 6 + z ** 4 / 24


MODE_OFF = 0.01    # a step that moves a mode by this share of its damping misplaces it (a yaw damping
                   # fitted 5σ low under Euler with 4 substeps was 3.6 % off, under the 0.1 once used)
LIGHT = 0.05       # ... a lightly damped mode's damping counted as at least this share of |λ|


def _finer(method: str, substeps: int) -> str:
    """What makes the step ``method`` finer: RK4 (unless it is already), or ``substeps``
    (under 4096), or a shorter dt."""
    ways = ([] if method == "rk4" else ['discretization="rk4"']) + ([f"substeps={substeps}"] if substeps < 4096 else [])
    return "use " + " or ".join(ways) if ways else "use a shorter dt"


STILL = 1e-9     # |λ|·h: a mode that moves less of itself per step no step misplaces (and a free
                 # integrator's 0 computes as ±1e-14 /s, whose 'error' the note was then about)


def mode_error(A: np.ndarray, method: str, h: float) -> tuple[float, complex, complex] | None:
    """(error, λ, λ_step) of the mode of the continuous Jacobian ``A`` (1/s) that a ``method`` step
    of ``h`` s misplaces most: λ_step = log R(λh)/h is the rate the step gives the mode, and the
    error is |λ_step − λ| over max(|Re λ|, LIGHT·|λ|), as a share of the mode's damping (an Euler
    step adds ω²h/2 to a lightly damped mode's decay, which an identified damping term absorbs:
    a pendulum's −0.10 read −0.154 at 100 Hz). None without modes (beyond STILL); inf where R(λh) ≤ 0."""
    if not np.isfinite(A).all():
        return None
    lam = np.linalg.eigvals(A)
    lam = lam[np.abs(lam) * h > STILL]
    if not lam.size:
        return None
    gain = _step_gain(method, lam * h)
    with np.errstate(divide="ignore", invalid="ignore"):
        step = np.where(np.abs(gain) > 0, np.log(gain.astype(complex)) / h, -np.inf)
        err = np.where(np.isfinite(step), np.abs(step - lam) / np.maximum(np.abs(lam.real), LIGHT * np.abs(lam)),
                       np.inf)
    k = int(np.argmax(err))
    return float(err[k]), complex(lam[k]), complex(step[k])


def _check_scalar(expr: ca.SX, what: str):
    if expr.shape != (1, 1):
        raise ModelError(f"{what} must be a scalar, got shape {expr.shape}")


def _check_symbols(expr: ca.SX, known: dict[int, str], what: str):
    """ModelError where ``expr`` uses a symbol that is not one of ``known`` ({element hash: name}):
    by identity, not name (a second ``ca.SX.sym("beta")`` beside the state beta passed, and CasADi
    then stopped the run: "variables [beta] are free")."""
    names = set(known.values())
    for s in ca.symvar(expr):
        if s.element_hash() in known:
            continue
        if s.name() in names:
            raise ModelError(f"{what} uses a symbol named '{s.name()}' that is not the model's '{s.name()}' (a "
                             f"second ca.SX.sym('{s.name()}'), or another model's): use the symbol the model's "
                             f"declaration returned")
        raise ModelError(f"{what} uses symbol '{s.name()}', which is not a declared state, "
                         f"input, parameter or input history")


def _factored(e: ca.SX) -> tuple[float, ca.SX]:
    """(k, core) with e = k·core: constant factors, divisors and signs taken out of ``e``."""
    k = 1.0
    while not (e.is_constant() or e.is_symbolic()):
        op = e.op()
        if op in (ca.OP_NEG, ca.OP_TWICE):
            k, e = (-k if op == ca.OP_NEG else 2 * k), e.dep(0)
        elif op == ca.OP_MUL and e.dep(0).is_constant():
            k, e = k * float(e.dep(0)), e.dep(1)
        elif op in (ca.OP_MUL, ca.OP_DIV) and e.dep(1).is_constant():
            k, e = (k * float(e.dep(1)) if op == ca.OP_MUL else k / float(e.dep(1))), e.dep(0)
        else:
            break
    if e.is_constant():
        return k * float(e), ca.SX(1)
    return k, e


def _check_covariance(M: np.ndarray, what: str, labels: list[str], definite: bool = True):
    n = len(labels)
    if M.shape != (n, n):
        raise ModelError(f"{what} has shape {M.shape}; expected ({n}, {n}) for {', '.join(labels)}")
    if not np.all(np.isfinite(M)):
        raise ModelError(f"{what} has non-finite entries")
    asym = np.abs(M - M.T)
    if asym.max(initial=0) > 1e-12 * max(1.0, np.abs(M).max()):
        i, j = np.unravel_index(asym.argmax(), asym.shape)
        raise ModelError(f"{what} is not symmetric: entry ({labels[i]}, {labels[j]}) = {M[i, j]} "
                         f"but ({labels[j]}, {labels[i]}) = {M[j, i]}")
    eig, vec = np.linalg.eigh(M)
    floor = 0.0 if not definite else 1e-300
    if eig[0] < -1e-12 * max(1.0, eig[-1]) or (definite and eig[0] <= floor):
        worst = labels[int(np.abs(vec[:, 0]).argmax())]
        kind = "positive definite" if definite else "positive semi-definite"
        raise ModelError(f"{what} is not {kind}: smallest eigenvalue {eig[0]:.3g}, "
                         f"mostly along '{worst}'")
