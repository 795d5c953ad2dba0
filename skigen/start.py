"""The state a recording starts in, when the model's declared initial state does not fit it.

A recording cut from a longer one, or a log that begins in flight, starts where the
declared initial state (often "at rest") is not: a filter started there spends its
first samples on a transient that its process noise must absorb, and a noise
calibration or a filter-error fit inflates Q to explain it. The declared start is
weighed against not knowing the start, over the recording's head: the EKF's
log-likelihood from the declared mean and covariance P₀ against that from the same
mean with DIFFUSE² P₀ (the Bayes factor of the two priors: a declared start that
holds wins by about nx·ln DIFFUSE nats, the vague prior's Occam penalty, and loses
by MARGIN with probability below P(χ²_nx > 2 nx ln DIFFUSE), 10⁻⁴ for nx = 2). The head ends
where the vague-prior filter knows every state as well as the declared prior did
(its std at most the declared one, or twice its own final std): later samples say
nothing more about the start, and a model error there would weigh on both filters
through innovations far larger than their noise (a quadrotor's ground effect: 110 nat
over its first second for a start that was right). For the same reason both filters
of the head run with Q and R times the dispersion, the vague filter's mean NIS per
measured output over the whole recording, where it exceeds 1 (the quasi-likelihood's
correction for a model or noise the data overrun: an encoder column of white noise
0.3 rad against a declared 1.5 mrad moved its start by 75 nat without it).

The declared start is kept unless the vague one is more likely by MARGIN nat, the
0.5·χ²₁(0.99) a diagnosis asks of a finding (a Bayes factor of 27): a start is the
user's declaration, and in a recording's first samples a sensor offset or a model
error can look like another start (a position sensor reading 20 mm high on a
mass-spring at rest moved its start by 0.4 nat, and a force bias was named instead
of the offset). Where the declared start loses, filters start from a vague prior,
the declared mean with DIFFUSE² P₀: they learn the start from the data as they go,
where a point estimate would be fixed by the nominal model for every later candidate
(an ambient temperature with a 300 s time constant, smoothed over the head with a
loss the model leaves out, was 17 of its std off). A state that starts beyond BEYOND
of the vague std from the declared mean starts where the recording does (its first
innovation would outweigh the rest: a motor log starting at 426 rad, 4·10⁴ declared
std away, had its encoder noise fitted at 6·10⁷× its variance). The vague
filter over the head smoothed back to the first sample (:mod:`skigen.smoother`), with
P₀, Q and R in their declared ratio, says where the recording starts; the dispersion
widens only its std (scaling R alone let the vague prior pull that start to 235 rad).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
from scipy import stats

from .derive import derive
from .model import Model
from .recording import Recording
from .runtime import run
from .smoother import smooth

__all__ = ["DIFFUSE", "MARGIN", "RecordedStart", "recorded_start", "vague_covariance"]

DIFFUSE = 100.0     # the declared initial std widened this much: the start "not known"
MARGIN = 0.5 * float(stats.chi2.isf(0.01, 1))    # nat the vague start must win by (3.3)
BEYOND = 3.0        # vague std: a state the recording starts further than this from declared starts there
_FAILED = (FloatingPointError, ArithmeticError, ValueError, RuntimeError, np.linalg.LinAlgError)


@dataclass(frozen=True)
class RecordedStart:
    """The smoothed state at a recording's first sample and how much better than the declared
    start it predicts the recording."""

    names: tuple
    mean: np.ndarray        # (nx,) the state at the first sample, from the data
    std: np.ndarray         # (nx,) its smoothed standard deviation
    declared: np.ndarray    # (nx,) the model's initial state
    declared_std: np.ndarray
    gain: float             # nat: log-likelihood of the head from the vague start minus from the declared
    head: int               # samples weighed: until the vague start knows every state as well as declared
    dispersion: float       # the vague filter's mean NIS per measured output over the whole recording

    @property
    def consistent(self) -> bool:
        return self.gain <= MARGIN

    @property
    def vague_mean(self) -> np.ndarray:
        """The vague prior's mean: the declared one, but where the recording starts for each state
        beyond BEYOND of the vague prior's std from it (its first innovation would outweigh the rest
        of the recording; nearer, the declared mean keeps a nonlinear model in its domain)."""
        far = np.abs(self.mean - self.declared) > BEYOND * DIFFUSE * self.declared_std
        return np.where(far, self.mean, self.declared)

    def starting(self, who: str) -> str:
        """'<who> start(s) from the declared mean with 100× the declared std', and which states start
        where the recording does (:attr:`vague_mean`)."""
        moved = [n for n, a, b in zip(self.names, self.vague_mean, self.declared) if a != b]
        return (f"{who} from the declared mean with {DIFFUSE:g}× the declared std"
                + (f" ({', '.join(moved)} where the recording starts, beyond {BEYOND:g} of that std)" if moved else ""))

    def note(self, path: str, what: str) -> str:
        """A sentence naming the states furthest off the declared start, ending in ``what``."""
        z = np.abs(self.mean - self.declared) / np.hypot(self.declared_std, self.std).clip(1e-300)
        off = [i for i in np.argsort(-z) if z[i] > 2] or [int(np.argmax(z))]
        said = ", ".join(f"{self.names[i]} {self.mean[i]:.4g} ± {self.std[i]:.2g} against {self.declared[i]:.4g} "
                         f"± {self.declared_std[i]:.2g}" for i in off)
        gain = "the declared start diverges" if np.isinf(self.gain) else f"{self.gain:.3g} nat"
        return (f"{path}: the recording does not start at the model's initial state ({said} declared): a start "
                f"{DIFFUSE:g}× as uncertain predicts its first {self.head} samples better ({gain}; {MARGIN:.1f} "
                f"needed); {what}")


def recorded_start(model: Model, rec: Recording) -> RecordedStart | None:
    """``rec``'s start weighed against ``model``'s declared one over its head (see the module);
    None when the vague-prior EKF or its smoother fails (the declared start then stands)."""
    nx = len(model.states)
    declared_std = np.sqrt(np.diag(model.initial_covariance()))
    try:
        filt, vague = _vague(model)
        whole = run(filt, rec, backend="casadi", strict=True, show_progress=False, init=vague)
        std = whole.std[:, :nx]
        settled = np.all(std <= np.maximum(declared_std, 2 * std[-1]), axis=1)
        head = rec.slice(0, max(int(np.argmax(settled)) if settled.any() else len(rec.t) - 1, 1) + 1)
        dispersion = np.nansum(whole.nis) / max(int(np.isfinite(rec.outputs).sum()), 1)
        where = smooth(filt, head, vague)       # the start's mean as the data say: P₀, Q, R in their
        if dispersion > 1:                      # declared ratio (the dispersion scales only its spread)
            filt, vague = _vague(_noise_times(model, dispersion))
        sm = smooth(filt, head, vague) if dispersion > 1 else where
    except _FAILED:
        return None
    x, P = where.mean[0, :nx], max(dispersion, 1.0) * where.first[:nx, :nx]
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
        return None
    try:
        declared = np.sum(run(filt, head, backend="casadi", strict=True, show_progress=False).loglik)
    except _FAILED:
        declared = -np.inf
    return RecordedStart(tuple(model.state_names), x, np.sqrt(np.clip(np.diag(P), 0, None)),
                         np.asarray(model.x0, float), declared_std, float(np.sum(sm.run.loglik) - declared),
                         len(head.t), float(dispersion))


def vague_covariance(model: Model) -> np.ndarray:
    """The vague start's covariance: DIFFUSE² times the declared P₀ (state units²)."""
    return DIFFUSE ** 2 * model.initial_covariance()


def _vague(model: Model) -> tuple:
    """(the EKF of ``model``, its start with DIFFUSE times the declared initial std)."""
    filt = derive(model, "ekf")
    nx = len(model.states)
    vague = filt.initial()
    vague["C"] = vague["C"].copy()
    vague["C"][:nx, :nx] = vague_covariance(model)                     # the EKF carries P
    return filt, vague


def vague_start(model: Model, rs: RecordedStart) -> tuple:
    """(the EKF of ``model``, the vague start a fit gave a recording judged off the declared one:
    :attr:`RecordedStart.vague_mean`, DIFFUSE times the declared std)."""
    filt, init = _vague(model)
    init["z"] = np.array(init["z"], float)
    init["z"][:len(model.states)] = rs.vague_mean
    return filt, init


def _noise_times(model: Model, factor: float) -> Model:
    """A copy of ``model`` with Q and R times ``factor`` (P₀ kept)."""
    scaled = copy.copy(model)
    scaled.covariances(Q=factor * model.process_noise(), R=factor * model.measurement_noise(),
                       P0=model.initial_covariance())
    return scaled
