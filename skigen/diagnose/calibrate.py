"""Calibrate: the noise intensities the recording supports, before anything is judged.

A wrong noise guess (process noise declared 10× too large, measurement noise
2× too small) makes a right model's innovations coloured or too large or too
small: it must not read as missing physics. So the nominal model's noise is
re-estimated first, by maximum likelihood with :func:`skigen.fit`'s filter
error (one scale on Q per equation that has process noise, one on R per
output), together with the parameters the model declares (constants the user
is unsure of: getting them right is the model's job, not a finding; numbers
written into the model stay as they are), and every later test runs on the
calibrated model. Missing physics then shows as what
white noise cannot explain: innovations that are not white, a disturbance
that drifts slowly or depends on the state, the input or the regime.
A kinematic identity ṗ = v (:meth:`Model.kinematic`; :func:`skigen.fit` holds it) is exact by
definition: its process noise may fall below what the user declared on it,
never rise above (calibrated freely, a vertical-speed sensor reading 0.3 m/s
high was absorbed as 284× the altitude's declared noise, and nothing was named).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..fit import FitError, NotIdentifiable, _bound_notes, _far_notes, fit, unit_notes, unseen_noise_note
from ..model import Model
from ..recording import Recording
from .errors import DiagnosisError

__all__ = ["Noise", "NoiseNotIdentifiable", "calibrate"]


class NoiseNotIdentifiable(DiagnosisError):
    """The recording cannot tell some of the noises (or declared parameters) apart."""


@dataclass
class Noise:
    """Declared and calibrated noise std (``{"process_std": {state: …}, "measurement_std": {output: …}}``,
    per sample and in output units), the fitted scales (on the variances) ± std, and the seconds spent."""

    declared: dict
    calibrated: dict
    scales: dict
    seconds: float
    parameters: dict = None        # declared parameters fitted with the noise: {name: {declared, calibrated, std}}
    note: str = ""

    def asdict(self) -> dict:
        """The ``noise`` object of report.json."""
        return {"declared": self.declared, "calibrated": self.calibrated, "scales": self.scales,
                "parameters": self.parameters or {}, "note": self.note,
                "method": "maximum likelihood of the nominal EKF's innovations (skigen fit, filter error): "
                          "one scale on Q per equation with process noise, one on R per output, and the "
                          "model's declared parameters with them"}


MAX_SAMPLES = 10_000        # noise scales from more samples than this gain nothing worth the time
BLOCKS = 5


def blocks(rec: Recording, max_samples: int = MAX_SAMPLES, n: int = BLOCKS) -> list[Recording]:
    """``rec`` itself, or ``n`` contiguous blocks of max_samples/n samples spread evenly over it."""
    N = len(rec.t)
    if N <= max_samples:
        return [rec]
    size = max_samples // n
    return [rec.slice(int(a), int(a) + size) for a in np.linspace(0, N - size, n)]


def block_starts(model: Model, rec: Recording, pieces: list[Recording]) -> list | None:
    """Where ``model``'s EKF over the whole of ``rec`` stood before each of its ``pieces``
    (:func:`skigen.fit`'s ``starts``): a block cut from the middle of a swing, filtered from the
    model's initial state instead, begins with a transient its process noise must absorb. None for
    ``rec`` itself, or when that EKF fails (the blocks then start from the initial state)."""
    if len(pieces) == 1 and pieces[0] is rec:
        return None
    from .cv import ekf_priors
    at = [int(np.searchsorted(rec.t, p.t[0])) for p in pieces]
    try:
        prior = ekf_priors(model, rec, at)
    except (ValueError, ArithmeticError):          # FloatingPointError: the EKF diverged
        return None
    nx = len(model.states)
    return [None if a == 0 else (prior[a][0][:nx], prior[a][1][:nx, :nx]) for a in at]


def calibrate(model: Model, recs: list[Recording], show_progress: bool = False,
              max_samples: int = MAX_SAMPLES, noise_from=None) -> tuple[Model, Noise]:
    """(``model`` with its calibrated Q and R, the :class:`Noise` record). A recording longer than
    ``max_samples`` is calibrated on evenly spread blocks of it (:func:`blocks`), each started
    where the model's EKF over the whole recording stood (:func:`block_starts`). noise_from: the
    user's declared (Q, R), started from as well when ``model`` carries another noise (see
    :func:`skigen.fit.fit`)."""
    given, pieces = recs, [blocks(r, max_samples) for r in recs]
    starts = [s for r, b in zip(recs, pieces) for s in (block_starts(model, r, b) or [None] * len(b))]
    recs = [b for bs in pieces for b in bs]
    res, note = None, ""
    if model.parameters:               # the user's uncertain constants are the model's to fit, not findings
        try:
            res = fit(model, recs, method="filter-error", starts=starts, show_progress=show_progress,
                      noise_from=noise_from)
        except FitError as exc:
            note = f"declared parameters held at their values ({exc})"
    try:
        res = res or fit(model, recs, method="filter-error", estimate=[], starts=starts,
                         show_progress=show_progress, noise_from=noise_from)
    except NotIdentifiable as exc:     # the fit's advice (--estimate …) is not the diagnosis's to give
        units = unit_notes(model, given)
        more = f"; and {len(exc.lost) - 2} more such set(s)" if len(exc.lost) > 2 else ""
        raise NoiseNotIdentifiable("".join(u + ("" if u.endswith("?") else ".") + " " for u in units)
                                   + f"could not calibrate the noise of '{model.name}' on this recording: "
                                   + "; ".join(exc.lost[:2]) + more + ". Declare the noises you know (process_std, "
                                   "noise_std) nearer their size, or record richer excitation") from None
    except FitError as exc:
        raise DiagnosisError(f"could not calibrate the noise of '{model.name}' on this recording: {exc}") from None
    said = _bound_notes(res.parameters) + _far_notes(res.parameters)
    unseen = unseen_noise_note(res.noise["unseen"]) if res.noise.get("unseen") else ""
    note = "; ".join(filter(None, [note, *(f"calibrating the declared parameters: {n}" for n in said), unseen]))
    noise = res.noise
    params = {n: {"declared": p["initial"], "calibrated": p["value"], "std": p["std"]} for n, p in res.parameters.items()}
    return res.model, Noise(noise["declared"], noise["calibrated"], noise["scales"], res.seconds, params, note)
