"""Free-run simulation of a declared model (no measurements): the user's simulator."""
from __future__ import annotations

import casadi as ca
import numpy as np

from .derive.augment import augment, memory_values, step_inputs
from .model import Model

__all__ = ["AMPLIFICATION", "free_run", "free_run_noise", "growth_rate", "simulation_window", "windowed_free_run"]

AMPLIFICATION = 10.0    # a free run is scored over windows within which it amplifies a state error at most this much


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


def _declared(model: Model):
    """(augmented model, x[k+1] expression, y[k] expression, nx): the state step and the outputs
    with the weights and estimated parameters at their declared values."""
    aug = augment(model)
    nx = len(model.states)
    f, h = aug.f[:nx], aug.h
    if aug.z.shape[0] > nx:
        f, h = (ca.substitute(e, aug.z[nx:], ca.DM(aug.z0[nx:])) for e in (f, h))
    return aug, f, h, nx


def growth_rate(model: Model, states: np.ndarray, inputs: np.ndarray) -> float:
    """Largest Lyapunov exponent [1/s] of ``model``'s free run along a state trajectory
    (N × nx, e.g. a filter's estimate) driven by the recorded ``inputs`` (N × nu).

    Benettin's method on the step's Jacobian, each state in units of its spread along the
    trajectory; the rate is the slope of the log-amplification over the trajectory's second
    half (the first aligns the direction), so an integrator's polynomial drift counts as ≈ 0
    and an open-loop unstable plant flown in closed loop as its divergence rate. NaN if the
    trajectory is not finite."""
    states = np.asarray(states, float)
    N = len(states)
    if N < 4 or not np.isfinite(states).all():
        return float("nan")
    aug, f, _, nx = _declared(model)
    x = aug.z[:nx]
    J = ca.Function("J", [x, aug.u, aug.mem], [ca.jacobian(f, x)])
    U, M = step_inputs(model, inputs), memory_values(model, inputs)
    Js = np.asarray(J.map(N - 1)(states[:-1].T, U[:-1].T, M[:-1].T)).reshape(nx, N - 1, nx).transpose(1, 0, 2)
    spread = np.std(states, axis=0)
    d = np.where(spread > 0, spread, 1.0)
    Js = Js / d[None, :, None] * d[None, None, :]
    v, c = np.ones(nx) / np.sqrt(nx), np.zeros(N)
    for k in range(N - 1):
        v = Js[k] @ v
        g = np.linalg.norm(v)
        if not np.isfinite(g) or g == 0:
            return float("nan") if not np.isfinite(g) else -np.inf
        c[k + 1] = c[k] + np.log(g)
        v /= g
    half = np.arange(N // 2, N)
    return float(np.polyfit(half * model.dt, c[half], 1)[0])


def simulation_window(rate: float, dt: float, samples: int) -> int:
    """Samples per free-run window: where the free run amplifies state errors by more than
    AMPLIFICATION over ``samples``, the steps within which it does so by AMPLIFICATION (at least
    2); else the whole of it."""
    if not np.isfinite(rate) or rate <= 0 or rate * samples * dt <= np.log(AMPLIFICATION):
        return int(samples)
    return int(max(2, min(samples, np.floor(np.log(AMPLIFICATION) / (rate * dt)))))


def windowed_free_run(model: Model, states: np.ndarray, inputs: np.ndarray, k0: int, window: int) -> np.ndarray:
    """Outputs (N × ny) of free runs restarted every ``window`` steps from ``states`` (N × nx,
    e.g. a filter's estimate) at samples k0, k0 + window, …, each driven by the recorded
    ``inputs`` alone (NaN up to k0). A window of the whole record is one free run from k0."""
    aug, f, h, nx = _declared(model)
    F, H = (ca.Function(n, [aug.z[:nx], aug.u, aug.mem], [e]) for n, e in (("F", f), ("H", h)))
    N = len(states)
    out = np.full((N, len(model.outputs)), np.nan)
    n = N - 1 - k0
    if n <= 0:
        return out
    window = int(min(max(window, 1), n))
    U, M = step_inputs(model, inputs), memory_values(model, inputs)
    starts = np.arange(k0, N - 1, window)
    steps = starts[:, None] + np.arange(window)[None, :]           # the sample each step leaves
    inside = steps < N - 1
    steps = np.minimum(steps, N - 2).ravel()
    X = np.asarray(F.mapaccum("sim", window).map(len(starts))(
        np.asarray(states, float)[starts].T, U[steps].T, M[steps].T))
    X = X.reshape(nx, -1)[:, inside.ravel()]
    k = (steps.reshape(inside.shape)[inside] + 1)
    out[k] = np.asarray(H.map(len(k))(X, U[k].T, M[k].T)).T
    return out


def free_run_noise(model: Model, states: np.ndarray, inputs: np.ndarray, k0: int, window: int) -> np.ndarray:
    """The RMSE per output (ny,) that the model's own noise gives a free run of the right model, as
    :func:`windowed_free_run` scores it: each window starts from the state exactly known, the
    process noise Q (per sample) accumulates along the linearisation about ``states`` (N × nx),
    P_{k+1} = F_k P_k F_kᵀ + Q, and the reading adds R: RMSE² = mean over the scored samples
    of diag(H_k P_k H_kᵀ + R). An integrator's random walk makes it grow with the window."""
    aug, f, h, nx = _declared(model)
    x = aug.z[:nx]
    J = ca.Function("J", [x, aug.u, aug.mem], [ca.jacobian(f, x), ca.jacobian(h, x)])
    N, ny = len(states), len(model.outputs)
    n = N - 1 - k0
    if n <= 0:
        return np.full(ny, np.nan)
    U, M = step_inputs(model, inputs), memory_values(model, inputs)
    F, H = (np.asarray(a).reshape(r, N, nx).transpose(1, 0, 2)
            for a, r in zip(J.map(N)(np.asarray(states, float).T, U.T, M.T), (nx, ny)))
    Q, R = model.process_noise(), model.measurement_noise()
    window = int(min(max(window, 1), n))
    P, total = np.zeros((nx, nx)), np.zeros(ny)
    for k in range(k0, N - 1):
        if (k - k0) % window == 0:
            P = np.zeros((nx, nx))
        P = F[k] @ P @ F[k].T + Q
        total += np.einsum("ij,jk,ik->i", H[k + 1], P, H[k + 1])
    return np.sqrt(total / n + np.diag(R))
