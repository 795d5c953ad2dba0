"""The user's inputs to a diagnosis, loaded and checked: every problem is one clear sentence."""
from __future__ import annotations

import os

import numpy as np

from ..model import Model
from ..recording import Recording, load_recording
from ..runtime import check_columns
from . import transform as T
from .errors import DiagnosisError

__all__ = ["MIN_SAMPLES", "load", "check"]

MIN_SAMPLES = 300          # 210 to fit, 90 to validate, and ≥ 5 Ljung–Box lags


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
    if model.input_hold != "zoh":
        raise DiagnosisError(f"model '{model.name}' interpolates its inputs (input_hold='{model.input_hold}'); "
                             f"the diagnosis handles zero-order-hold models only so far")
    if model.parameters:
        raise DiagnosisError(f"model '{model.name}' declares parameters ({', '.join(model.parameter_names)}); "
                             f"the diagnosis takes them as constants only once `skigen fit` has fixed them: "
                             f"fit first, or declare them as numbers")
    if not isinstance(recording, Recording):
        rec = load_recording(recording, model, **read)
    else:
        rec = recording
        try:
            check_columns(model, rec)
        except ValueError as exc:
            raise DiagnosisError(str(exc)) from None
    return model, spec, rec


def check(model: Model, rec: Recording, validation: float):
    """Long enough to decide, sampled at the model's dt, every output measured often enough."""
    N = len(rec.t)
    if not 0.05 <= validation <= 0.5:
        raise DiagnosisError(f"validation fraction must be within [0.05, 0.5], got {validation}")
    need = max(MIN_SAMPLES, int(np.ceil(90 / validation)))
    if N < need:
        raise DiagnosisError(
            f"{rec.path}: {N} samples ({N * model.dt:g} s at dt = {model.dt:g} s) are too few to decide; "
            f"the diagnosis needs at least {need} ({need * model.dt:g} s): "
            f"{int((1 - validation) * need)} to fit and {need - int((1 - validation) * need)} to validate")
    if abs(rec.dt - model.dt) > 0.01 * model.dt:
        raise DiagnosisError(f"{rec.path}: samples are {rec.dt:g} s apart but model '{model.name}' has "
                             f"dt = {model.dt:g} s; resample the recording or declare the model's dt")
    measured = np.isfinite(rec.outputs).sum(axis=0)
    if measured.min() < 0.5 * need:
        name = model.output_names[int(np.argmin(measured))]
        raise DiagnosisError(f"{rec.path}: output '{name}' is measured in only {int(measured.min())} samples; "
                             f"at least {need // 2} are needed to decide")
