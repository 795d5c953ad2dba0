"""Free-run simulation of a declared model (no measurements): the user's simulator."""
from __future__ import annotations

import casadi as ca
import numpy as np

from .derive.augment import augment, step_inputs
from .model import Model

__all__ = ["free_run"]


def free_run(model: Model, inputs: np.ndarray, x0=None, weights=None) -> tuple[np.ndarray, np.ndarray]:
    """Simulate the discrete model from x0 over the input rows (N × nu), with the
    model's input hold and its parameters at their values.

    weights: values of the unknown-term weights (zeros by default, i.e. the
    nominal model). Returns (states (N × nx), outputs (N × ny)) at the sample
    times, the first row being x0.
    """
    aug = augment(model)
    nx = len(model.states)
    z0 = np.concatenate([np.asarray(model.x0 if x0 is None else x0, float),
                         np.zeros(len(aug.w_index)) if weights is None else np.asarray(weights, float)])
    inputs = step_inputs(model, np.atleast_2d(np.asarray(inputs, float).T).T)
    N = len(inputs)
    state = ca.vertcat(aug.z, aug.mem)
    step = ca.Function("step", [state, aug.u], [ca.vertcat(aug.f, aug.mem_next)])
    out = ca.Function("out", [state, aug.u], [aug.h])
    traj = np.array(step.mapaccum(N - 1)(np.r_[z0, np.zeros(aug.mem.shape[0])], inputs[:-1].T)) if N > 1 else np.zeros((len(z0) + aug.mem.shape[0], 0))
    states = np.column_stack([np.r_[z0, np.zeros(aug.mem.shape[0])], traj])
    outputs = np.array(out.map(N)(states, inputs.T)).T
    return states[:nx].T, outputs
