"""The user's inputs to a diagnosis, loaded and checked: every problem is one clear sentence."""
from __future__ import annotations

import os

import numpy as np

from ..model import Model
from ..grid import clock
from ..recording import Recording, load_recording
from ..runtime import check_columns
from . import transform as T
from .errors import DiagnosisError

__all__ = ["MIN_SAMPLES", "load", "check", "usable"]

MIN_SAMPLES = 300          # ≥ 60 per fold of 5, and ≥ 5 Ljung–Box lags


def load(model, recording, **read) -> tuple[Model, str | None, Recording]:
    """(model, its file or module spec if any, recording) from objects, paths or a DataFrame;
    ``read``: options of :func:`skigen.recording.load_recording`."""
    if isinstance(model, (str, os.PathLike)):
        from ..modelfile import ModelFileError, canonical_spec
        spec = str(model)
        try:
            model = T.load_model_file(spec)
        except ModelFileError as exc:
            raise DiagnosisError(str(exc)) from None
        spec = canonical_spec(spec)
    elif isinstance(model, Model):
        spec = None
    else:
        raise DiagnosisError(f"expected a skigen.Model or a model file, got {type(model).__name__}")
    model.check()
    if not isinstance(recording, Recording):
        rec = load_recording(recording, model, **read)
    else:
        rec = recording
        try:
            check_columns(model, rec)
        except ValueError as exc:
            raise DiagnosisError(str(exc)) from None
    return model, spec, rec


def usable(rec: Recording) -> tuple[Recording, list[str]]:
    """``rec`` without a stuck sensor's readings (:meth:`Recording.unstuck`) and, where an input
    has holes, its longest stretch between them (a held input is not the input, and a diagnosis
    takes one recording), with a sentence per change."""
    parts, notes = rec.usable()
    longest = max(parts, key=len)
    if rec.input_holes:
        notes.append(rec.hole_note(f"diagnosed on the longest stretch between them, {clock(longest.t[0])}–"
                                   f"{clock(longest.t[-1])} s ({len(longest)} of {len(rec)} samples)"))
    span = longest.t[-1] - longest.t[0]
    quiet = [h for h in rec.holes if not h.inputs and h.t1 > longest.t[0] and h.t0 < longest.t[-1]]
    if quiet and span > 0:
        notes.append("readings missing for longer than the maximum gap, where the filters only predict and the "
                     "diagnosis sees nothing: " + "; ".join(f"{h} ({(min(h.t1, longest.t[-1]) - max(h.t0, longest.t[0])) / span:.0%} "
                                                             f"of the recording)" for h in quiet))
    return longest, notes


def check(model: Model, rec: Recording, folds: int):
    """Long enough to decide, sampled at the model's dt, every output measured often enough."""
    N = len(rec.t)
    if not 2 <= int(folds) <= 20:
        raise DiagnosisError(f"the cross-validation needs 2 to 20 folds, got {folds}")
    need = max(MIN_SAMPLES, 60 * int(folds))
    if N < need:
        raise DiagnosisError(
            f"{rec.path}: {N} samples ({N * model.dt:g} s at dt = {model.dt:g} s) are too few to decide; "
            f"the diagnosis needs at least {need} ({need * model.dt:g} s): 60 per fold of {folds}")
    if abs(rec.dt - model.dt) > 0.01 * model.dt:
        raise DiagnosisError(f"{rec.path}: samples are {rec.dt:g} s apart but model '{model.name}' has "
                             f"dt = {model.dt:g} s; resample the recording or declare the model's dt")
    if not np.isfinite(rec.inputs).all():
        k = int(np.argwhere(~np.isfinite(rec.inputs))[0, 0])
        raise DiagnosisError(f"{rec.path}: input missing at t = {rec.t[k]:g} s; the diagnosis needs every input")
    if stuck := rec.stuck_output():
        raise DiagnosisError(stuck)
    measured = np.isfinite(rec.outputs).sum(axis=0)
    if measured.min() < 0.5 * need:
        name = model.output_names[int(np.argmin(measured))]
        raise DiagnosisError(f"{rec.path}: output '{name}' is measured in only {int(measured.min())} samples; "
                             f"at least {need // 2} are needed to decide")
