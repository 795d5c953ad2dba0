"""Run a derived filter over a recording (the Python backend).

Every step is guarded like the generated C: a non-finite input skips the
sample, a non-finite measurement skips its update, and a step whose result
is not finite is rejected (the prior is kept). Many rejections in a row mean
the filter diverged, which is an error naming the time it began.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .derive import DerivedFilter
from .progress import progress
from .recording import Recording, write_table

__all__ = ["RunResult", "FilterDivergedError", "run", "STEP_OK", "STEP_SKIPPED", "STEP_BAD_INPUT",
           "STEP_REJECTED"]

STEP_OK, STEP_SKIPPED, STEP_BAD_INPUT, STEP_REJECTED = 0, 1, 2, 3
MAX_REJECTED_IN_A_ROW = 20


class FilterDivergedError(RuntimeError):
    """The filter produced non-finite results for many samples in a row."""


@dataclass
class RunResult:
    """Per-sample filter output. Arrays have one row per recording sample."""

    filter: DerivedFilter
    t: np.ndarray
    mean: np.ndarray          # (N, n) posterior mean of z = [x; w]
    std: np.ndarray           # (N, n) posterior standard deviation
    innovation: np.ndarray    # (N, ny), NaN where not measured
    innovation_var: np.ndarray  # (N, ny) diagonal of Pyy, NaN where not measured
    nis: np.ndarray           # (N,), NaN when nothing was measured
    loglik: np.ndarray        # (N,)
    prior_var: np.ndarray     # (N, nw) ARD prior variances (SKI), else empty
    code: np.ndarray          # (N,) STEP_* per sample
    final_cov: np.ndarray     # (n, n) last posterior covariance

    @property
    def names(self) -> list[str]:
        return self.filter.aug.names

    @property
    def weights(self) -> np.ndarray:
        return self.mean[:, self.filter.aug.w_index]

    @property
    def weight_std(self) -> np.ndarray:
        return self.std[:, self.filter.aug.w_index]

    def columns(self) -> dict[str, np.ndarray]:
        """The run-result table of the contract (design.md), in order."""
        aug = self.filter.aug
        cols = {"t": self.t}
        cols.update({n: self.mean[:, i] for i, n in enumerate(self.names)})
        cols.update({f"std_{n}": self.std[:, i] for i, n in enumerate(self.names)})
        cols.update({f"innov_{n}": self.innovation[:, i] for i, n in enumerate(aug.model.output_names)})
        cols.update(nis=self.nis, loglik=self.loglik)
        w_names = [self.names[i] for i in aug.w_index]
        cols.update({f"prior_var_{n}": self.prior_var[:, i] for i, n in enumerate(w_names)}
                    if self.prior_var.size else {})
        return cols

    def write(self, path) -> None:
        write_table(path, self.columns())


def _std(C: np.ndarray, square_root: bool) -> np.ndarray:
    return np.sqrt(np.sum(C * C, axis=1)) if square_root else np.sqrt(np.clip(np.diag(C), 0, None))


def run(filt: DerivedFilter, rec: Recording, *, show_progress: bool = True, label: str | None = None,
        state: dict | None = None) -> RunResult:
    """Filter the whole recording; returns the posterior at every sample."""
    aug = filt.aug
    model = aug.model
    if list(rec.input_names) != model.input_names or list(rec.output_names) != model.output_names:
        raise ValueError(f"{rec.path}: recording columns {list(rec.input_names) + list(rec.output_names)} "
                         f"do not match model '{model.name}' (inputs {model.input_names}, "
                         f"outputs {model.output_names})")
    N, n, ny = len(rec.t), aug.n, len(model.output_names)
    state = dict(state or filt.initial())
    out = {k: np.full(shape, np.nan) for k, shape in
           dict(mean=(N, n), std=(N, n), e=(N, ny), ev=(N, ny), nis=(N,), ll=(N,),
                s=(N, len(aug.w_index) if filt.kind == "ski" else 0)).items()}
    code = np.zeros(N, dtype=int)
    ski = filt.kind == "ski"
    rejected = 0
    C_post = state["C"]
    steps = progress(range(N), N, label or f"{model.name} {filt.kind}") if show_progress else range(N)
    for k in steps:
        u, y = rec.inputs[k], rec.outputs[k]
        valid = np.isfinite(y)
        if not np.all(np.isfinite(u)):
            code[k] = STEP_BAD_INPUT
            continue
        args = [state["z"], state["C"]] + ([state["s"]] if ski else []) + \
               [u, state["mem"], np.where(valid, y, 0.0), valid.astype(float)]
        res = [np.asarray(r) for r in filt.step(*args)]
        z_post, C_post_k, *rest = res
        s_next = rest.pop(0) if ski else None
        z_next, C_next, mem_next, e, Pyy, nis, ll = rest
        checked = [z_post, C_post_k, z_next, C_next] + ([s_next] if ski else [])
        if not all(np.all(np.isfinite(a)) for a in checked):
            code[k] = STEP_REJECTED
            rejected += 1
            if rejected >= MAX_REJECTED_IN_A_ROW:
                t0 = rec.t[k - rejected + 1]
                raise FilterDivergedError(
                    f"{rec.path}: the {filt.kind} filter of '{model.name}' diverged: {rejected} "
                    f"non-finite steps in a row from t = {t0:g} s (row {k - rejected + 3} of the file)")
            state["mem"] = mem_next.ravel()
            z_post, C_post_k = state["z"], state["C"]
            e = np.full(ny, np.nan)
        else:
            rejected = 0
            code[k] = STEP_OK if valid.all() else STEP_SKIPPED
            state.update(z=z_next.ravel(), C=C_next, mem=mem_next.ravel())
            if ski:
                state["s"] = s_next.ravel()
            e = np.where(valid, e.ravel(), np.nan)
            out["nis"][k], out["ll"][k] = (nis.item(), ll.item()) if valid.any() else (np.nan, 0.0)
            out["ev"][k] = np.where(valid, np.diag(Pyy), np.nan)
        out["mean"][k] = np.ravel(z_post)
        out["std"][k] = _std(C_post_k, filt.square_root)
        out["e"][k] = e
        if ski:
            out["s"][k] = state["s"]
        C_post = C_post_k
    final_cov = C_post @ C_post.T if filt.square_root else C_post
    return RunResult(filt, rec.t, out["mean"], out["std"], out["e"], out["ev"], out["nis"], out["ll"],
                     out["s"], code, final_cov)
