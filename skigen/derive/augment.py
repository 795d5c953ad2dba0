"""The augmented model z = [x; w]: discrete transition, observation, noises."""
from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np
from scipy.linalg import block_diag

from ..discretize import discretize
from ..model import Model, ModelError

__all__ = ["Augmented", "augment", "memory_values", "step_inputs"]


@dataclass(frozen=True)
class Augmented:
    """Symbols and expressions of the augmented model.

    z: [x; w; p] (n): states, unknown-term weights, estimated parameters.
    u: the step's inputs, u[k] (and u[k+1] after it for a first-order hold).
    mem: exact input history, f: z[k+1], h: y[k], mem_next: the shifted
    history. Declared parameters not estimated are constants at their value.
    Q, R, z0, P0 are numeric.
    """

    model: Model
    z: ca.SX
    u: ca.SX
    mem: ca.SX
    f: ca.SX
    h: ca.SX
    mem_next: ca.SX
    Q: np.ndarray
    R: np.ndarray
    z0: np.ndarray
    P0: np.ndarray
    s0: np.ndarray
    w_index: np.ndarray
    names: list[str]
    p_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    fixed: ca.SX = field(default_factory=lambda: ca.SX(0, 1))   # declared parameters not estimated
    fixed_values: np.ndarray = field(default_factory=lambda: np.zeros(0))
    f_free: ca.SX | None = None         # f and h before the fixed parameters took their values
    h_free: ca.SX | None = None
    Q_sqrt: ca.SX | None = None         # set in a tunable step: Q = Q_sqrt Q_sqrtᵀ, R = R_sqrt R_sqrtᵀ
    R_sqrt: ca.SX | None = None
    rates_jacobian: ca.Function | None = None   # (z, u, mem, fixed) → ∂(dx/dt)/∂x, continuous models

    @property
    def fixed_names(self) -> list[str]:
        return [self.fixed[i].name() for i in range(self.fixed.shape[0])]

    @property
    def u_names(self) -> list[str]:
        """Names of the step's inputs: the model's, then ``<name>_next`` for a first-order hold."""
        return [self.u[i].name() for i in range(self.u.shape[0])]

    @property
    def estimated(self) -> list[str]:
        """Names of the parameters augmented into the state."""
        return [self.names[i] for i in self.p_index]

    @property
    def n(self) -> int:
        return self.z.shape[0]

    @property
    def shapes(self) -> dict[str, int]:
        return dict(n=self.n, nx=len(self.model.states), nw=len(self.w_index),
                    nu=self.u.shape[0], ny=self.h.shape[0], nmem=self.mem.shape[0])


def augment(model: Model, estimate=(), *, online: bool = True) -> Augmented:
    """Build the augmented model once, after validating the declaration.

    estimate: names of declared parameters to augment into the state (after
    the weights), as random constants with their prior std (which ``online``
    filtering needs; an offline fit uses the symbols only).
    """
    model.check()
    estimated = [model.parameter_named(name) for name in dict.fromkeys(estimate)]
    for p in estimated:
        if online and p.std is None:
            raise ModelError(f"parameter '{p.name}' is estimated online but declares no std: "
                             f"give model.parameter('{p.name}', ..., std=...) its prior")
    x = ca.vertcat(*[v.sym for v in model.states])
    u = ca.vertcat(*[v.sym for v in model.inputs]) if model.inputs else ca.SX(0, 1)
    mem = ca.vertcat(*[m.sym for m in model.memory]) if model.memory else ca.SX(0, 1)
    weights = model.weights()
    w = ca.vertcat(*[ca.SX.sym(name) for name, *_ in weights]) if weights else ca.SX(0, 1)
    p_est = ca.vertcat(*[p.sym for p in estimated]) if estimated else ca.SX(0, 1)
    rhs = ca.vertcat(*[model.rhs[name] for name in model.state_names])
    rows = {name: i for i, name in enumerate(model.state_names)}
    for k, (_, eq, _, direction) in enumerate(weights):
        for j, row in enumerate(eq.split("+")):
            rhs[rows[row]] += w[k] * direction[j]
    inputs = {v.name: v.sym for v in model.inputs}
    lagged = {(m.source, m.lag): m.sym for m in model.memory}
    mem_next = ca.vertcat(*[inputs[m.source] if m.lag == 1 else lagged[(m.source, m.lag - 1)]
                            for m in model.memory]) if model.memory else ca.SX(0, 1)
    if model.input_hold == "foh":     # u[k+1] follows u[k]; a delayed input moves towards its successor
        u_next = ca.vertcat(*[ca.SX.sym(f"{v.name}_next") for v in model.inputs]) if model.inputs else ca.SX(0, 1)
        x_next = discretize(rhs, x, model.dt, model.discretization, model.substeps,
                            ca.vertcat(u, mem), ca.vertcat(u_next, mem_next))
        u_step = ca.vertcat(u, u_next)
    else:
        x_next, u_step = discretize(rhs, x, model.dt, model.discretization, model.substeps), u
    f = ca.vertcat(x_next, w, p_est)
    h = ca.vertcat(*[v.sym for v in model.outputs])
    fixed = [p for p in model.parameters if p not in estimated]
    f_free, h_free = f, h
    syms, values = ca.SX(0, 1), np.zeros(0)
    if fixed:
        syms, values = ca.vertcat(*[p.sym for p in fixed]), np.array([p.value for p in fixed], float)
        f, h = (ca.substitute(e, syms, ca.DM(values)) for e in (f, h))
    jac = None if model.discretization == "discrete" else ca.Function(
        "rates_jacobian", [ca.vertcat(x, w, p_est), u, mem, syms], [ca.jacobian(rhs, x)])
    s0 = model.prior_variances()
    nx, nw = len(model.states), len(weights)
    return Augmented(
        model=model, z=ca.vertcat(x, w, p_est), u=u_step, mem=mem, f=f, h=h, mem_next=mem_next,
        Q=block_diag(model.process_noise(), np.diag(np.square(model.weight_process_std())),
                     np.zeros((len(estimated), len(estimated)))),
        R=model.measurement_noise(),
        z0=np.concatenate([model.x0, np.zeros(nw), [p.value for p in estimated]]),
        P0=block_diag(model.initial_covariance(), np.diag(s0),
                      np.diag([(p.std or 0.0) ** 2 for p in estimated])),
        s0=s0, w_index=np.arange(nx, nx + nw),
        names=model.state_names + [name for name, *_ in weights] + [p.name for p in estimated],
        p_index=np.arange(nx + nw, nx + nw + len(estimated)), fixed=syms, fixed_values=values,
        f_free=f_free, h_free=h_free, rates_jacobian=jac)


def memory_values(model: Model, inputs) -> np.ndarray:
    """The model's input history at every sample of the recorded inputs (N × nu):
    u[k − lag] per remembered input, 0 before the start (as the filters begin)."""
    inputs = np.asarray(inputs, float).reshape(len(inputs), -1)
    N = len(inputs)
    out = np.zeros((N, len(model.memory)))
    for i, m in enumerate(model.memory):
        out[m.lag:, i] = inputs[:N - m.lag, model.input_names.index(m.source)]
    return out


def step_inputs(model: Model, inputs) -> np.ndarray:
    """The rows a filter step consumes, from the recorded inputs (N × nu): u[k] for a
    zero-order hold; [u[k], u[k+1]] for a first-order hold, the last input held."""
    inputs = np.asarray(inputs, float).reshape(len(inputs), -1)
    if model.input_hold != "foh":
        return inputs
    return np.hstack([inputs, np.vstack([inputs[1:], inputs[-1:]])])
