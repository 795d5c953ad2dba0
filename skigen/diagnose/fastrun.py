"""Run a derived filter over a whole recording in one CasADi call (``mapaccum``).

The per-sample step is the same derived Function that :func:`skigen.runtime.run`
calls, chained by CasADi's virtual machine instead of a Python loop — about
15× faster than the Python backend and free of the C backend's compile time,
which matters when the diagnosis runs dozens of candidate models. If a step
produces a non-finite number the run is redone by :func:`skigen.runtime.run`,
whose guards (reject the step, keep the prior) then apply.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..derive import DerivedFilter, derive
from ..derive.augment import step_inputs
from ..emit.c import Status
from ..model import Model
from ..recording import Recording
from ..runtime import RunResult, check_columns, run

__all__ = ["Trace", "run_fast", "loglik"]


@dataclass
class Trace:
    """What a smoother needs besides the :class:`RunResult`: per sample k, the posterior
    covariance, the prior for k + 1 and the input memory used at k."""

    result: RunResult
    C_post: np.ndarray   # (N, n, n) covariance (EKF) or Cholesky factor (UKF, SKI)
    z_next: np.ndarray   # (N, n)
    C_next: np.ndarray   # (N, n, n)
    mem: np.ndarray      # (N, nmem)


def _chain(filt: DerivedFilter, N: int) -> tuple[ca.Function, int]:
    """The step chained over at least N samples, as a mapaccum of B fully unrolled steps repeated
    ⌈N/B⌉ times (B ≈ √N: built ~10× faster than one long mapaccum); returns it and its length."""
    d, ski = filt.aug.shapes, filt.has_ard
    z, C = ca.MX.sym("z", d["n"]), ca.MX.sym("C", d["n"], d["n"])
    s, mem = ca.MX.sym("s", d["nw"]), ca.MX.sym("mem", d["nmem"])
    u, y, valid = ca.MX.sym("u", d["nu"]), ca.MX.sym("y", d["ny"]), ca.MX.sym("valid", d["ny"])
    out = filt.step(*([z, C] + ([s] if ski else []) + [u, mem, y, valid]))
    if ski:
        z_post, C_post, s_next, z_next, C_next, mem_next, e, Pyy, nis, ll = out
        acc_in, acc_out = [z, C, s, mem], [z_next, C_next, s_next, mem_next]
    else:
        z_post, C_post, z_next, C_next, mem_next, e, Pyy, nis, ll = out
        acc_in, acc_out = [z, C, mem], [z_next, C_next, mem_next]
    g = ca.Function("chain_step", acc_in + [u, y, valid],
                    acc_out + [z_post, C_post, e, ca.diag(Pyy), nis, ll, mem] + ([s_next] if ski else []))
    B = max(1, int(np.ceil(np.sqrt(N))))
    blocks = int(np.ceil(N / B))
    inner = g.mapaccum("block", B, len(acc_in), {"base": -1})
    return inner.mapaccum("chain", blocks, len(acc_in), {"base": -1}), B * blocks


def _blocks(a, N: int, n: int) -> np.ndarray:
    """(n, n·N) horizontally stacked blocks → (N, n, n)."""
    return np.asarray(a).reshape(n, N, n).transpose(1, 0, 2)


def run_fast(filt: DerivedFilter, rec: Recording, *, trace: bool = False, init: dict | None = None):
    """Filter ``rec``; returns a :class:`RunResult` (or a :class:`Trace` when ``trace``).
    init: the filter state before the first sample (default :meth:`DerivedFilter.initial`)."""
    aug, model = filt.aug, filt.aug.model
    check_columns(model, rec)
    N, d, ski = len(rec.t), aug.shapes, filt.has_ard
    n = d["n"]
    given, init = init is not None, init or filt.initial()
    Y = np.asarray(rec.outputs, float)
    valid = np.isfinite(Y)
    chain, M = _chain(filt, N)
    pad = lambda a: np.vstack([a, np.repeat(a[-1:], M - N, axis=0)]).T     # prediction-only steps after N
    args = [init["z"], init["C"]] + ([init["s"]] if ski else []) + [init["mem"]]
    args += [pad(step_inputs(model, np.asarray(rec.inputs, float))), pad(np.where(valid, Y, 0.0)), pad(np.zeros_like(Y))]
    args[-1][:, :N] = valid.T
    with np.errstate(all="ignore"):
        out = [np.asarray(o)[:, :N * (o.shape[1] // M)] for o in chain(*args)]
    k0 = 4 if ski else 3
    z_post, C_post, e, ev, nis, ll, mem = out[k0:k0 + 7]
    arrays = [out[0], out[1], z_post, C_post, e, ev, nis, ll] + ([out[k0 + 7]] if ski else [])
    if not all(np.all(np.isfinite(a)) for a in arrays) or not np.all(np.isfinite(rec.inputs)):
        if trace or given:
            raise FloatingPointError(f"the {filt.kind} filter of '{model.name}' produced non-finite numbers")
        return run(filt, rec, show_progress=False)
    Cp = _blocks(C_post, N, n)
    std = np.sqrt(np.einsum("kij,kij->ki", Cp, Cp)) if filt.square_root else \
        np.sqrt(np.clip(np.einsum("kii->ki", Cp), 0, None))
    any_valid = valid.any(axis=1)
    res = RunResult(
        filt, rec.t, z_post.T.copy(), std, np.where(valid, e.T, np.nan), np.where(valid, ev.T, np.nan),
        np.where(any_valid, nis.ravel(), np.nan), np.where(any_valid, ll.ravel(), 0.0),
        out[k0 + 7].T.copy() if ski else np.zeros((N, 0)),
        np.where(valid.all(axis=1), Status.OK, Status.MEASUREMENT_SKIPPED).astype(int),
        Cp[-1] @ Cp[-1].T if filt.square_root else Cp[-1].copy())
    if not trace:
        return res
    # out[0], out[1] hold the accumulated values *after* each step: the prior for k + 1.
    return Trace(res, Cp, out[0].T.copy(), _blocks(out[1], N, n), mem.T.copy())


def loglik(model: Model, rec: Recording, start: int = 0) -> float:
    """Summed predictive log-likelihood of the model's EKF over ``rec`` from sample ``start``
    on (the filter runs from the beginning); −inf if it diverges."""
    try:
        return float(np.sum(run_fast(derive(model, "ekf"), rec).loglik[start:]))
    except (FloatingPointError, RuntimeError):
        return -np.inf
