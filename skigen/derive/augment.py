"""The augmented model z = [x; w]: discrete transition, observation, noises."""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
from scipy.linalg import block_diag

from ..discretize import discretize
from ..model import Model

__all__ = ["Augmented", "augment"]


@dataclass(frozen=True)
class Augmented:
    """Symbols and expressions of the augmented model.

    z: [x; w] (n), u: inputs, mem: exact input history, f: z[k+1],
    h: y[k], mem_next: the shifted history. Q, R, z0, P0 are numeric.
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

    @property
    def n(self) -> int:
        return self.z.shape[0]

    @property
    def shapes(self) -> dict[str, int]:
        return dict(n=self.n, nx=len(self.model.states), nw=len(self.w_index),
                    nu=self.u.shape[0], ny=self.h.shape[0], nmem=self.mem.shape[0])


def augment(model: Model) -> Augmented:
    """Build the augmented model once, after validating the declaration."""
    model.check()
    x = ca.vertcat(*[v.sym for v in model.states])
    u = ca.vertcat(*[v.sym for v in model.inputs]) if model.inputs else ca.SX(0, 1)
    mem = ca.vertcat(*[m.sym for m in model.memory]) if model.memory else ca.SX(0, 1)
    weights = model.weights()
    w = ca.vertcat(*[ca.SX.sym(name) for name, *_ in weights]) if weights else ca.SX(0, 1)
    rhs = ca.vertcat(*[model.rhs[name] for name in model.state_names])
    rows = {name: i for i, name in enumerate(model.state_names)}
    for k, (_, eq, _, direction) in enumerate(weights):
        for j, row in enumerate(eq.split("+")):
            rhs[rows[row]] += w[k] * direction[j]
    f = ca.vertcat(discretize(rhs, x, model.dt, model.discretization, model.substeps), w)
    h = ca.vertcat(*[v.sym for v in model.outputs])
    inputs = {v.name: v.sym for v in model.inputs}
    lagged = {(m.source, m.lag): m.sym for m in model.memory}
    mem_next = ca.vertcat(*[inputs[m.source] if m.lag == 1 else lagged[(m.source, m.lag - 1)]
                            for m in model.memory]) if model.memory else ca.SX(0, 1)
    s0 = model.prior_variances()
    return Augmented(
        model=model, z=ca.vertcat(x, w), u=u, mem=mem, f=f, h=h, mem_next=mem_next,
        Q=block_diag(model.process_noise(), np.diag(np.square(model.weight_process_std()))),
        R=model.measurement_noise(),
        z0=np.concatenate([model.x0, np.zeros(len(weights))]),
        P0=block_diag(model.initial_covariance(), np.diag(s0)),
        s0=s0, w_index=np.arange(len(model.states), len(model.states) + len(weights)),
        names=model.state_names + [name for name, *_ in weights])
