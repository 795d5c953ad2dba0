"""Rauch–Tung–Striebel smoothing of an EKF run: the state given the whole recording.

The forward pass is the derived EKF (:func:`skigen.runtime.run`, backend
``casadi``, with ``trace=True``); the backward pass uses A_k = ∂F/∂z at the filtered mean,
from the augmented transition ``skigen.derive.augment(model).f``:

    G_k = P_k Aᵀ_k (P⁻_{k+1})⁻¹
    x̂ˢ_k = x̂_k + G_k (x̂ˢ_{k+1} − x̂⁻_{k+1}),   Pˢ_k = P_k + G_k (Pˢ_{k+1} − P⁻_{k+1}) Gᵀ_k
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from .derive.augment import step_inputs
from .derive import DerivedFilter
from .recording import Recording
from .runtime import RunResult, run

__all__ = ["Smoothed", "smooth"]


@dataclass
class Smoothed:
    run: RunResult     # the forward pass, with its trace
    mean: np.ndarray   # (N, n)
    std: np.ndarray    # (N, n)
    first: np.ndarray  # (n, n): the smoothed covariance at the first sample


def _jacobians(filt: DerivedFilter, res: RunResult, inputs: np.ndarray) -> np.ndarray:
    aug = filt.aug
    A = ca.Function("A", [aug.z, aug.u, aug.mem], [ca.densify(ca.jacobian(aug.f, aug.z))])
    N, n = res.trace.z_next.shape
    out = A.map(N)(res.mean.T, np.asarray(inputs, float).T, res.trace.mem.T)
    return np.asarray(out).reshape(n, N, n).transpose(1, 0, 2)


def smooth(filt: DerivedFilter, rec: Recording, init: dict | None = None) -> Smoothed:
    """EKF forward, RTS backward over the whole recording; init: the filter's start (as
    :func:`skigen.runtime.run`'s; default the declared one)."""
    if filt.kind != "ekf":
        raise ValueError("the smoother works on an EKF run")
    res = run(filt, rec, backend="casadi", trace=True, strict=True, show_progress=False, init=init)
    tr = res.trace
    A = _jacobians(filt, res, step_inputs(filt.aug.model, rec.inputs))
    x, P = res.mean, tr.C_post
    N, n = x.shape
    xs, Ps = x.copy(), P.copy()
    eye = 1e-12 * np.eye(n)
    for k in range(N - 2, -1, -1):
        Pp = tr.C_next[k] + eye
        G = np.linalg.solve(Pp, A[k] @ P[k]).T
        xs[k] = x[k] + G @ (xs[k + 1] - tr.z_next[k])
        Ps[k] = P[k] + G @ (Ps[k + 1] - tr.C_next[k]) @ G.T
    std = np.sqrt(np.clip(np.einsum("kii->ki", Ps), 0, None))
    return Smoothed(res, xs, std, Ps[0])
