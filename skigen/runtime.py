"""Run a derived filter over a recording, in Python or through the generated C.

Both backends step with the same guards (those of the generated C): a
non-finite input skips the sample (state unchanged), a non-finite
measurement skips its update, and a step whose result is not finite is
rejected, keeping the prior. Many rejections in a row mean the filter
diverged, which is an error naming the time it began.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .derive import DerivedFilter, step_inputs
from .emit.c import Status
from .progress import note, progress
from .recording import Recording, write_table

__all__ = ["RunResult", "FilterDivergedError", "PythonStepper", "run", "check_columns", "Status"]

MAX_REJECTED_IN_A_ROW = 20
SLOW_DERIVATION_N = 80      # above this augmented-state size the symbolic step takes seconds: say so


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
    code: np.ndarray          # (N,) Status per sample
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


class PythonStepper:
    """The derived step Function behind the generated C's interface and guards.

    Holds the filter state (z, C, s, mem) and, after each step, the posterior
    (z_post, C_post) and innovation statistics (e, Pyy, nis, loglik).
    """

    def __init__(self, filt: DerivedFilter):
        self.filt = filt
        self.init()

    def init(self) -> None:
        st = self.filt.initial()
        self.z, self.C, self.mem, self.s = st["z"], st["C"], st["mem"], st.get("s")
        self._reset_posterior()

    def _reset_posterior(self):
        ny = self.filt.aug.shapes["ny"]
        self.z_post, self.C_post = self.z, self.C
        self.e, self.Pyy, self.nis, self.loglik = np.zeros(ny), np.zeros((ny, ny)), 0.0, 0.0

    def step(self, u, y) -> int:
        """One sample; returns a :class:`Status` code."""
        u, y = np.asarray(u, float), np.asarray(y, float)
        if not np.all(np.isfinite(u)):
            return Status.BAD_INPUT
        valid = np.isfinite(y)
        ski = self.filt.has_ard
        args = [self.z, self.C] + ([self.s] if ski else []) + [u, self.mem, np.where(valid, y, 0.0),
                                                              valid.astype(float)]
        z_post, C_post, *rest = (np.asarray(r) for r in self.filt.step(*args))
        s_next = rest.pop(0).ravel() if ski else None
        z_next, C_next, mem_next, e, Pyy, nis, loglik = rest
        self.mem = mem_next.ravel()
        if not all(np.all(np.isfinite(a)) for a in [z_post, C_post, z_next, C_next] + ([s_next] if ski else [])):
            self._reset_posterior()
            return Status.NUMERICAL_FAILURE
        self.z_post, self.C_post, self.z, self.C = z_post.ravel(), C_post, z_next.ravel(), C_next
        self.e, self.Pyy, self.nis, self.loglik = e.ravel(), Pyy, nis.item(), loglik.item()
        if ski:
            self.s = s_next
        return Status.OK if valid.all() else Status.MEASUREMENT_SKIPPED

    def std(self) -> np.ndarray:
        """Posterior standard deviations."""
        C = self.C_post
        return np.sqrt(np.sum(C * C, axis=1)) if self.filt.square_root else np.sqrt(np.clip(np.diag(C), 0, None))


def check_columns(model, rec: Recording) -> None:
    """Raise ValueError unless the recording's inputs and outputs are the model's, in order."""
    have = list(rec.input_names) + list(rec.output_names)
    want = model.input_names + model.output_names
    if have != want:
        missing = [n for n in want if n not in have]
        extra = [n for n in have if n not in want]
        raise ValueError(
            f"{rec.path}: recording columns do not match model '{model.name}'"
            + (f"; missing {', '.join(repr(m) for m in missing)}" if missing else "")
            + (f"; not in the model {', '.join(repr(e) for e in extra)}" if extra else "")
            + f" (model inputs {model.input_names}, outputs {model.output_names})")


def run(filt: DerivedFilter, rec: Recording, *, backend: str = "python", real: str = "double",
        show_progress: bool = True, label: str | None = None, cache_dir=None) -> RunResult:
    """Filter the whole recording; returns the posterior at every sample.

    backend: ``"python"`` (the CasADi Function) or ``"c"`` (the generated C,
    compiled and cached on first use, in ``real`` precision).
    """
    aug, model = filt.aug, filt.aug.model
    check_columns(model, rec)
    if backend == "c":
        from .emit.c import load_c
        stepper = load_c(filt, real, cache_dir=cache_dir)
    elif backend == "python":
        if show_progress and "step" not in filt.__dict__ and aug.n > SLOW_DERIVATION_N:
            note(f"deriving the {filt.kind} step of '{model.name}' symbolically (n = {aug.n}: this "
                 f"takes a while; the C backend does not need it)")
        stepper = PythonStepper(filt)
    else:
        raise ValueError(f"unknown backend '{backend}'; choose python or c")
    N, n, ny, ski = len(rec.t), aug.n, len(model.output_names), filt.has_ard
    out = {k: np.full(shape, np.nan) for k, shape in
           dict(mean=(N, n), std=(N, n), e=(N, ny), ev=(N, ny), nis=(N,), ll=(N,),
                s=(N, len(aug.w_index) if ski else 0)).items()}
    code, rejected = np.zeros(N, dtype=int), 0
    inputs = step_inputs(model, rec.inputs)
    label = label or f"{model.name} {filt.kind} ({backend})"
    for k in progress(range(N), N, label) if show_progress else range(N):
        code[k] = c = stepper.step(inputs[k], rec.outputs[k])
        if c == Status.BAD_INPUT:
            continue
        rejected = rejected + 1 if c == Status.NUMERICAL_FAILURE else 0
        if rejected >= MAX_REJECTED_IN_A_ROW:
            raise FilterDivergedError(
                f"{rec.path}: the {filt.kind} filter of '{model.name}' diverged: {rejected} non-finite "
                f"steps in a row from t = {rec.t[k - rejected + 1]:g} s (row {k - rejected + 3} of the file)")
        out["mean"][k], out["std"][k] = stepper.z_post, stepper.std()
        if ski:
            out["s"][k] = stepper.s
        valid = np.isfinite(rec.outputs[k])
        if c != Status.NUMERICAL_FAILURE and valid.any():
            out["e"][k] = np.where(valid, stepper.e, np.nan)
            out["ev"][k] = np.where(valid, np.diag(stepper.Pyy), np.nan)
            out["nis"][k], out["ll"][k] = stepper.nis, stepper.loglik
        else:
            out["ll"][k] = 0.0
    C = np.asarray(stepper.C_post, float)
    return RunResult(filt, rec.t, out["mean"], out["std"], out["e"], out["ev"], out["nis"], out["ll"],
                     out["s"], code, C @ C.T if filt.square_root else C)
