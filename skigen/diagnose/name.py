"""Name: which catalog (or user) terms explain the located mismatch, with what coefficients.

Greedy rounds, every proposal scored by blocked cross-validation
(:mod:`skigen.diagnose.cv`): its coefficients are fitted without the fold
each part of the recording is scored on.

1. additive candidates on the located equations compete jointly in one SKI run
   (priors scale-aware: each candidate alone could explain the smoothed
   disturbance twice over); a term is kept if |ŵ| > z·σ, z the two-sided normal
   quantile of α / (number of candidates), one variant per effect. The
   procedure is repeated without each fold and the fold scored with what it kept;
2. each structural candidate's parameter is chosen, per fold, on the grid
   point with the best log-likelihood over the other folds; the final value is
   refined on the whole recording;
3. a proposal passes if 2·(cross-validated gain) exceeds the χ² quantile
   1 − α/(number of candidates) for its number of parameters and, after the
   first round, adds at least 1 % of the gain so far. The best two that pass
   (the second only when its gain is at least half the first's: a close rival)
   are each adopted under the noise recalibrated with them (the nominal's
   calibration absorbed the missing physics as process noise, which blurs the
   difference between close candidates such as a delay and a lag) and the one
   with the higher cross-validated log-likelihood is kept; repeat (three
   rounds at most). A term whose refitted coefficient has a sign physics
   forbids (:func:`skigen.diagnose.plausible.compensating`) is not adopted: it
   is set aside as compensating, no later round is built on it, and when a
   round adopts nothing else the next one searches without it (an anti-drag
   chosen by SKI over the damping a heavier cart needs). A
   further change is kept only if it passes the rule
   :mod:`skigen.diagnose.evidence` applies to every finding, each model under
   the best of the noises calibrated with it, before it and before naming (its
   gain at proposal time was measured under the noise calibrated before it). A
   delay adopted in an earlier round is searched again after each later
   adoption (:func:`redelayed`).

Additive coefficients are then refitted jointly on the whole recording
(augmented EKF: linearised about the mean, it never evaluates the model at
sigma points far out in a broad prior); an effect with variants (a Coulomb smoothing
width, a ground-effect decay height, a limit) has its shape chosen by
likelihood, and the spread of the coefficient over the shapes the data do not
rule out is added to its std (:func:`shape_search`). The evidence of each
finding is weighed afterwards (:mod:`skigen.diagnose.evidence`).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
from scipy import stats
from scipy.optimize import minimize_scalar

from ..derive import FilterOptions, derive
from ..library import term
from ..model import Model
from ..recording import Recording
from ..runtime import parallel
from ..start import recorded_start
from . import catalog as C
from . import transform as T
from .catalog import Additive, Structural, feedthrough, rate_readers
from .cv import Folds, ekf_priors, fit_without, fits_without, fold_loglik, loglik
from .errors import DiagnosisError
from .plausible import compensating, forbidden_sign, significant, term_item

__all__ = ["Correction", "Proposal", "name_terms", "refit", "basis_rms", "distinct", "start_priors",
           "focus_window", "recalibrated", "significant", "best_cv_loglik"]

MAX_ROUNDS = 3
FINALISTS = 3      # proposals scored again, each under the noise calibrated with it
MIN_SHARE = 0.01   # a further change must add ≥ 1 % of the gain so far: below that it only
                   # absorbs the first one's approximation (grid resolution, smoothing)
RIVAL_SHARE = 0.5  # a finalist below half the best's gain is no close rival: it is not re-scored


@dataclass
class Correction:
    """Found terms: additive (candidate, coefficient, std) and structural (candidate, value, std),
    applied to the nominal model in that order (structural last: the plant sees the transformed
    input everywhere, including in the additive terms)."""

    additive: list[tuple[Additive, float, float]] = field(default_factory=list)
    structural: list[tuple[Structural, float, float]] = field(default_factory=list)

    def build(self, nominal: Model, name: str | None = None, unknown: list[Additive] | None = None,
              prior_variance=None, scales=None) -> Model:
        """The nominal with these terms; ``unknown`` terms left for a filter to estimate, each
        regressor divided by its ``scales`` entry (its weight's prior variance multiplied by its square)."""
        m = T.copy_model(nominal, name, unknowns=False)
        readers = rate_readers(nominal)
        for c, coef, _ in self.additive:            # through an input: its direction at the nominal
            for eq, e in c.contributions(nominal).items():
                m = T.add_term(m, eq, coef, e)
                for y, k in readers.get(eq, []) if not c.through else ():     # a sensor of that rate
                    m = T.read(m, y, lambda h, e=e, k=k: h + k * coef * e)
            for y, g in (feedthrough(nominal, c.through) if c.through else {}).items():
                m = T.read(m, y, lambda h, g=g: h + coef * c.sx(nominal) * g)
        if unknown:                                 # one block per candidate: weights in their order
            r = np.ones(len(unknown)) if scales is None else np.asarray(scales, float)
            prior = np.broadcast_to(np.asarray(prior_variance, float), (len(unknown),))
            for i, c in enumerate(unknown):         # a rate, as add_term's: × dt in a discrete model's next value
                eqs, e = zip(*c.contributions(nominal).items())
                m.unknown(list(eqs), [term(c.formula, T.rate(nominal, ca.vertcat(*e)) / r[i], key=f"c{i}")],
                          prior_variance=prior[i] * r[i] ** 2)
        for s, value, _ in self.structural:
            m = s.build(m, value)
        return m

    def without(self, *which) -> "Correction":
        return Correction([a for a in self.additive if not any(a[0] is w for w in which)],
                          [s for s in self.structural if not any(s[0] is w for w in which)])

    @property
    def found(self) -> list[tuple[Additive, float, float]]:
        """The additive terms that are findings (not a declared parameter's correction)."""
        return [a for a in self.additive if not a[0].parameter]

    def without_parameters(self) -> "Correction":
        return Correction(self.found, self.structural)

    @property
    def empty(self) -> bool:
        return not (self.found or self.structural)


@dataclass
class Proposal:
    kind: str
    gain: float               # cross-validated log-likelihood gain over the current correction
    params: int
    correction: Correction    # coefficients fitted on the whole recording
    label: str
    folds: np.ndarray | None = None     # per-fold cross-validated log-likelihood
    set_aside: list = field(default_factory=list)   # its terms not adopted as compensating (report items)
    note: str = ""
    adopted: list = field(default_factory=list)     # what it added, when adopted (report items)
    as_good: list = field(default_factory=list)     # another finalist the recording cannot tell from it
    tried: list = field(default_factory=list)       # additive: the swaps and simpler sets scored, (correction, folds)
    alternatives: list = field(default_factory=list)   # the corrections of its ties (as_good), whole
    rivals: list = field(default_factory=list)   # finalists behind it beyond a tie (within TIE_MARGIN), whole
    noise: Model | None = None          # a revision: the nominal with the noise calibrated under it


def basis_values(model: Model, rec: Recording, states: np.ndarray, cands: list[Additive],
                 equations=None) -> np.ndarray:
    """(m, N): each candidate's rate on its equation along the (smoothed) trajectory; with
    ``equations``, (m, len(equations)·N): its rate on each of them in turn (0 where it does not enter:
    a term through an input that, in a corrected model, drives its actuator's lag state only)."""
    x = ca.vertcat(*[v.sym for v in model.states])
    u = ca.vertcat(*[v.sym for v in model.inputs]) if model.inputs else ca.SX(0, 1)
    rates = [c.contributions(model) for c in cands]
    phi = ca.vertcat(*[r.get(c.equation, ca.SX(0)) for c, r in zip(cands, rates)] if equations is None else
                     [r.get(eq, ca.SX(0)) for r in rates for eq in equations])
    f = ca.Function("phi", [x, u], [phi]).map(len(rec.t))
    return np.asarray(f(states[:, :len(model.states)].T, rec.inputs.T)).reshape(len(cands), -1)


def unfit_slope(model: Model, rec: Recording, states: np.ndarray, c: Additive) -> str | None:
    """Where the EKF the naming fits with cannot use candidate ``c``: its rate finite and its
    derivative in a state not, along the trajectory or at the ends of the range a candidate is
    evaluated over (:func:`within_range`), with the inputs at their median; None where it can. A
    user's exact tank outflow −√max(h, 0) scored +383, then failed a fold (0·∞ below h = 0, which
    that range reaches) and was never named, "no candidate explains the mismatch"."""
    nx = len(model.states)
    x = ca.vertcat(*[v.sym for v in model.states])
    u = ca.vertcat(*[v.sym for v in model.inputs]) if model.inputs else ca.SX(0, 1)
    rate = c.contributions(model)[c.equation]
    f = ca.Function("slope", [x, u], [rate, ca.jacobian(rate, x)])
    X = states[:, :nx]
    lo, hi = X.min(axis=0), X.max(axis=0)
    pad = RANGE_MARGIN * (hi - lo)
    ends = np.repeat(np.median(X, axis=0)[None, :], 2 * nx, axis=0)
    ends[np.arange(nx), np.arange(nx)], ends[nx + np.arange(nx), np.arange(nx)] = lo - pad, hi + pad
    points = np.vstack([X, ends])
    um = np.median(rec.inputs, axis=0) if len(model.inputs) else np.zeros(0)
    U = np.vstack([rec.inputs, np.repeat(um[None, :], 2 * nx, axis=0)]) if len(model.inputs) else np.zeros((len(points), 0))
    with np.errstate(all="ignore"):
        value, slope = (np.asarray(v) for v in f.map(len(points))(points.T, U.T))
    finite = np.isfinite(slope.reshape(nx, -1, order="F"))
    bad = np.isfinite(value.ravel()) & ~finite.all(axis=0)
    if not bad.any():
        return None
    k = int(np.argmax(bad))
    i = int(np.argmax(~finite[:, k]))
    return (f"its derivative in {model.state_names[i]} is not finite at {model.state_names[i]} = {points[k, i]:.4g} "
            f"(where the naming evaluates it: the recorded range widened by {RANGE_MARGIN:.0%} each way), so the "
            f"EKF it is fitted with fails there; write it with a derivative defined there (sqrt(fmax(x, 1e-9)) "
            f"rather than sqrt(fmax(x, 0)))")


def basis_rms(model: Model, rec: Recording, states: np.ndarray, cands: list[Additive]) -> np.ndarray:
    with np.errstate(over="ignore"):          # a trajectory that runs away: inf, said by the steps that use it
        return np.sqrt(np.mean(basis_values(model, rec, states, cands) ** 2, axis=1)) + 1e-12


def restated(model: Model, rec: Recording, states: np.ndarray, cands: list[Additive]) -> dict[int, int]:
    """{i: j}: candidate i equals (up to scale, on this trajectory, in every equation it enters)
    the earlier candidate j, itself restating none — a user term that restates a catalog term."""
    vals = basis_values(model, rec, states, cands, model.state_names)
    with np.errstate(over="ignore", invalid="ignore"):
        unit = vals / (np.linalg.norm(vals, axis=1, keepdims=True) + 1e-300)
    keep, same = [], {}
    for i, c in enumerate(cands):
        j = next((j for j in keep if abs(unit[i] @ unit[j]) >= 0.9999), None)
        if j is None:
            keep.append(i)
        else:
            same[i] = j
    return same


def distinct(model: Model, rec: Recording, states: np.ndarray, cands: list[Additive]) -> list[Additive]:
    """Candidates without duplicates: one that :func:`restated` an earlier one is dropped."""
    same = restated(model, rec, states, cands)
    return [c for i, c in enumerate(cands) if i not in same]




def representatives(cands: list[Additive]) -> list[Additive]:
    """One variant per (effect, equation), the middle one: SKI chooses effects, :func:`shape_search`
    their shape."""
    groups: dict[tuple, list[Additive]] = {}
    for c in cands:
        groups.setdefault(c.group, []).append(c)
    return [_innermost(g) if dict(g[0].shape).get("side") else g[len(g) // 2] for g in groups.values()]


def _innermost(group: list[Additive]) -> Additive:
    """The limit variant that acts most often: the lowest upper bound, the highest lower one."""
    bound = lambda c: dict(c.shape)["bound"]
    return (min if dict(group[0].shape)["side"] == "upper" else max)(group, key=bound)


SKI_MAX_SAMPLES = 10_000


def focus_window(strength: np.ndarray, n: int = SKI_MAX_SAMPLES) -> tuple[int, int] | None:
    """The n contiguous samples where the located disturbance is strongest (``strength`` per
    sample, e.g. (d/σ)²), or None when the recording is not longer than n."""
    N = len(strength)
    if N <= n:
        return None
    c = np.concatenate([[0.0], np.cumsum(np.nan_to_num(strength))])
    a = int(np.argmax(c[n:] - c[:-n]))
    return a, a + n


def start_priors(model: Model, rec: Recording, folds: Folds) -> dict:
    """The priors of ``model``'s EKF at the folds' edges: where a fit without a fold restarts after the gap."""
    return ekf_priors(model, rec, folds.edges[1:-1])


def beyond_parameters(model: Model, rec: Recording, states: np.ndarray, cands: list[Additive]) -> list[Additive]:
    """Candidates a declared parameter cannot already produce: one whose term, along the trajectory,
    is proportional to ∂(rate)/∂p, in the equations it enters, for a declared parameter p (a linear
    stiffness where the model declares its stiffness k) is that parameter's job, not missing physics."""
    if not model.parameters or not cands:
        return cands
    x = ca.vertcat(*[v.sym for v in model.states])
    u = ca.vertcat(*[v.sym for v in model.inputs]) if model.inputs else ca.SX(0, 1)
    p = ca.vertcat(*[q.sym for q in model.parameters])
    values = np.array([q.value for q in model.parameters])
    fixed, N = T.constants(model), len(rec.t)
    entered = [list(c.contributions(fixed)) for c in cands]
    eqs = [e for e in model.state_names if any(e in es for es in entered)]
    J = ca.Function("J", [x, u, p], [ca.vertcat(*[ca.jacobian(model.rhs[e], p) for e in eqs])]).map(N)
    d = np.asarray(J(states[:, :len(model.states)].T, rec.inputs.T, np.tile(values, (N, 1)).T))
    P = len(model.parameters)                            # ∂rate/∂p per sample, then equations·N as vals
    slopes = d.reshape(len(eqs), N, P).transpose(2, 0, 1).reshape(P, -1)
    vals = basis_values(fixed, rec, states, cands, eqs)   # (candidates, equations·N), as the slopes
    keep = []
    for c, es, phi in zip(cands, entered, vals):
        on = np.repeat([e in es for e in eqs], N)          # the equations it enters
        d, phi = slopes[:, on], phi[on]
        with np.errstate(over="ignore", invalid="ignore"):
            cos = np.abs(d @ phi) / (np.linalg.norm(d, axis=1) * np.linalg.norm(phi) + 1e-300)
        if not np.any(cos > 0.999):
            keep.append(c)
    return keep


def _prior(cands, rms, size) -> np.ndarray:
    """ARD/EKF prior variance per candidate: alone, it could explain the disturbance twice over."""
    return np.array([(2.0 * size[c.equation] / rms[c]) ** 2 for c in cands])


def _estimating(known: "Correction", nominal: Model, cands, rms, size, prior=None) -> tuple[Model, np.ndarray]:
    """``known`` built with ``cands`` left for a filter to estimate, each regressor scaled so that
    its weight's default prior (:func:`_prior`) is 1: the term's RMS along the trajectory over twice
    the size of what is missing in its equation. The ARD step's speed and the filters' floors then
    do not depend on the units a formula happens to have (a user's term written 10¹⁰ too large was
    pruned at once). ``prior``: the weights' prior variances in the formulas' units (default
    :func:`_prior`). Returns the model and the scales (a weight estimated as w′ is w′ / scale in
    the formula's units)."""
    r = np.array([rms[c] / (2.0 * size[c.equation]) for c in cands])
    prior = _prior(cands, rms, size) if prior is None else prior
    return known.build(nominal, unknown=cands, prior_variance=prior, scales=r), r


def _kept(cands, w, sd, alpha: float, n_tests: int) -> list[tuple]:
    """(candidate, ŵ, σ) with |ŵ| > z·σ, the best variant per key (effect, equation, input)."""
    z_min = stats.norm.isf(alpha / (2 * n_tests))
    keep: dict[tuple, tuple] = {}
    for c, wi, si in zip(cands, w, sd):
        z = abs(wi) / max(si, 1e-300)
        if z > z_min and (keep.get(c.key) is None or z > keep[c.key][3]):
            keep[c.key] = (c, float(wi), float(si), z)
    return [k[:3] for k in keep.values()]


RANGE_MARGIN = 0.1     # × the span: how far beyond the recorded range a candidate is evaluated


def within_range(model: Model, states: np.ndarray) -> Model:
    """``model`` with each state in its unknown term's regressors held to the range the trajectory
    ``states`` (N, nx) covers, widened by RANGE_MARGIN of its span each way. The data say nothing
    of a term beyond that range, and the sigma points of a broad prior go far beyond it: there an
    anti-drag w·|w| or a softening −θ³ with a wrong-signed weight several σ out diverges within one
    step (a finite-time blow-up), and the whole selection with it."""
    m = T.copy_model(model)
    n = min(len(m.states), states.shape[1])       # the states a structural change adds are left free
    xs = ca.vertcat(*[v.sym for v in m.states[:n]])
    lo, hi = states[:, :n].min(axis=0), states[:, :n].max(axis=0)
    pad = RANGE_MARGIN * (hi - lo)
    held = ca.vertcat(*[ca.fmin(ca.fmax(xs[i], lo[i] - pad[i]), hi[i] + pad[i]) for i in range(xs.shape[0])])
    for b in m.unknowns:
        b.terms = [dataclasses.replace(t, expr=ca.substitute(t.expr, xs, held)) for t in b.terms]
    return m


def cv_loglik(nominal: Model, corr: Correction, rec: Recording, folds: Folds, rms: dict, size: dict) -> np.ndarray:
    """Per-fold log-likelihood of ``corr`` with its additive coefficients fitted without each fold."""
    if not corr.additive:
        return fold_loglik(corr.build(nominal), rec, folds)
    base = Correction([], corr.structural)
    cands = [a[0] for a in corr.additive]
    m, r = _estimating(base, nominal, cands, rms, size)
    try:            # where the filter estimating the terms stands: the model without them may stray
        start = start_priors(m, rec, folds)
    except (FloatingPointError, RuntimeError, np.linalg.LinAlgError):
        start = start_priors(base.build(nominal), rec, folds)

    def held_out(f, fitted) -> float:
        if isinstance(fitted, Exception):        # diverged
            return -np.inf
        w, sd = fitted[0] / r, fitted[1] / r
        fold_corr = Correction([(c, float(wi), float(si)) for c, wi, si in zip(cands, w, sd)], corr.structural)
        return fold_loglik(fold_corr.build(nominal), rec, folds)[f]
    return np.array(parallel(lambda a: held_out(*a), enumerate(fits_without(m, "ekf", rec, folds, start))))


def _additive(nominal, current: Correction, cands, rec, folds: Folds, rms, size, alpha,
              focus: tuple[int, int] | None = None, states: np.ndarray | None = None) -> Proposal | None:
    """The SKI proposal: the terms SKI keeps on the recording (or on its samples ``focus``),
    cross-validated with the current and kept terms' coefficients refitted without each fold."""
    m, r = _estimating(current, nominal, cands, rms, size)
    m = within_range(m, states) if states is not None else m
    piece = rec.slice(*focus) if focus else rec
    # The naming rule (z = |ŵ|/σ) was calibrated with the paper's gradient ARD; the EM update's
    # honest σ needs its own rule (not yet done), so the SKI selection keeps the gradient.
    w, sd = fit_without(m, "ski", piece, Folds.of(len(piece.t), 1), None, None, FilterOptions(ard="gradient"))
    w, sd = w / r, sd / r
    kept = _kept(cands, w, sd, alpha, len(cands))
    if not kept:
        return None
    new = Correction(current.additive + kept, current.structural)
    score = cv_loglik(nominal, new, rec, folds, rms, size)
    tried: list = []
    new, score = _swaps(nominal, current, new, score, cands, rec, folds, rms, size, states, tried)
    fewer, score = _simplest(nominal, current, new, score, cands, rec, folds, rms, size, states, alpha, tried)
    if fewer is not new:                  # what stands in for the set: swapped in turn
        fewer, score = _swaps(nominal, current, fewer, score, cands, rec, folds, rms, size, states, tried)
    new = fewer
    label = ", ".join(_where(c) for c, *_ in new.additive[len(current.additive):])
    proposal = Proposal("additive", 0.0, len(new.additive) - len(current.additive), new, label, score)
    proposal.as_good, proposal.alternatives = _ties(current, new, score, tried, alpha)
    proposal.tried = tried
    return proposal


def _ties(current: Correction, new: Correction, score, tried: list, alpha: float) -> tuple[list[dict], list]:
    """The terms of the corrections ``tried`` (swapped in, or simpler) that explain the recording as
    well as ``new`` with no more terms (cross-validated log-likelihood within what a finding must
    add), as report items with how far behind they are (a roll-damping change scored a quadratic
    drag 0.24 ahead of the true viscous damping, and was named without a word of it), and the
    corrections they come from. A set with a term whose sign physics forbids is no tie (an
    anti-drag was said "not told apart" from a heavier cart's damping)."""
    mine = added(current, new)
    out, seen, whole = [], {_said(a) for a in mine}, []
    for trial, trial_score in sorted(tried, key=lambda t: -np.sum(t[1])):
        behind = -_gain(trial_score, score)       # +inf where a fold cannot be scored
        if len(trial.additive) > len(new.additive) or not 0 <= behind < evidence_threshold(alpha) \
                or _unphysical(current, trial):
            continue
        theirs = added(current, trial)
        instead = [list(acts(a)) for a in mine if _said(a) not in {_said(b) for b in theirs}]
        if any(_said(item) not in seen for item in theirs):
            whole.append(trial)
        for item in _together(theirs, cv_loglik_behind=behind, instead_of=instead):
            if _said(item) not in seen:
                seen.add(_said(item))
                out.append(item)
    return out, whole


TIE_TRIALS = 6     # an additive proposal's best-scored alternatives scored again under the chosen's noise
TIE_MARGIN = 10    # × what a finding must add: an alternative this close under it is scored under its own


def _ties_under(nominal: Model, recal: Model, corr: Correction, new: Correction, chosen: Proposal, score,
                proposals, rec, folds, rms, size, alpha: float, noise_from=None) -> tuple[list[dict], list]:
    """The additive sets the round scored (each additive proposal and its swaps and simpler sets, the
    chosen's among them: a pendulum's quadratic drag and a viscous damping 0.1 apart under the
    nominal's noise were 600 nat apart each under its own, and said "not told apart")
    scored again under the noise the chosen finding left (``recal``), and those within TIE_MARGIN
    thresholds of it under the noise calibrated with them (the round's ``nominal`` recalibrated):
    ties, when within what a finding must add of the chosen correction ``new`` with no more terms
    — cross-validated, or, with as many numbers, in-sample (AIC's comparison; the folds' held-out
    coefficients cost two equivalent forms unequally). Under the noise calibrated on the nominal, a
    motor's torque constant 10 % low and an encoder gain of 0.9 (the same transfer function from
    rest) were scored apart by a process noise 20× the true one, and the gain was named alone; at
    20 % low, 4.9 behind cross-validated and 0.3 in-sample. Each set without the terms the chosen's
    adoption dropped as not significant (a Coulomb friction kept beside a linear pwm gain, then
    dropped, left the thrust's pwm² term with it as a pair of two, never compared). Returns (report
    items, the corrections they come from, and (how far behind, correction) for each set ahead of
    an additive chosen by what a finding must add: no tie, a better explanation; a structural
    chosen's are ties, as they were: it is no set of terms to swap)."""
    adopted = {_said(a) for a in chosen.adopted}
    said = adopted | {_said(a) for a in chosen.as_good}
    instead = [list(acts(a)) for a in chosen.adopted]
    mine = loglik(new.build(recal), rec)
    lost = _dropped(chosen, new)
    out, whole, ahead = [], [], []
    for p in proposals:
        if p.kind != "additive":
            continue
        best = sorted(p.tried, key=lambda t: -np.sum(t[1]))[:TIE_TRIALS]
        for trial in [p.correction] + [t for t, _ in best]:
            trial = trial.without(*lost)          # as the chosen's adoption left it
            items = added(corr, trial)            # another explanation: no more terms, none of the chosen's
            if not items or len(items) > len(chosen.adopted) or any(_said(a) in adopted for a in items) \
                    or all(_said(a) in said for a in items):
                continue
            trial = Correction(trial.additive, corr.structural)
            scored = _scored(recal, trial, rec, folds, rms, size)
            if scored is None or _unphysical(corr, scored[0]):
                continue
            behind = -_gain(scored[1], score)
            if evidence_threshold(alpha) <= behind < TIE_MARGIN * evidence_threshold(alpha):
                theirs = recalibrated(nominal, scored[0], rec, noise_from)
                again = _scored(theirs, trial, rec, folds, rms, size)
                if again is not None and np.sum(again[1]) > np.sum(scored[1]):
                    scored, behind = again, -_gain(again[1], score)
                in_sample = mine - loglik(scored[0].build(theirs), rec)
                if behind >= evidence_threshold(alpha) and len(items) == len(chosen.adopted) \
                        and in_sample < evidence_threshold(alpha):
                    said |= {_said(a) for a in items}
                    out += _together(added(corr, scored[0]), loglik_behind=float(in_sample), in_sample=True,
                                     instead_of=instead)
                    whole.append(scored[0])
                    continue
            if behind <= -evidence_threshold(alpha) and chosen.kind == "additive":
                ahead.append((behind, scored[0]))
            elif behind < evidence_threshold(alpha):
                said |= {_said(a) for a in items}
                out += _together(added(corr, scored[0]), cv_loglik_behind=behind, instead_of=instead)
                whole.append(scored[0])
    return out, whole, ahead


def _better(nominal: Model, corr: Correction, chosen: Proposal, ahead: list, score, rec, folds, rms, size,
            alpha: float, states, noise_from) -> tuple[Correction, Model, np.ndarray] | None:
    """The set of ``ahead`` (how far behind the chosen, its correction) furthest ahead, adopted under
    the noise it leaves (:func:`_adopt`), when it stays ahead of ``chosen`` (under its own) by what a
    finding must add: ``chosen`` then proposes it. A car's quadratic drag, scored 12.9 ahead of the
    cubic damping chosen under the noise before either, was said "not told apart" from it, which
    needed its viscous damping refitted 17 std off to match."""
    if not ahead:
        return None
    behind, correction = min(ahead, key=lambda a: a[0])
    label = ", ".join(_where(c) for c, *_ in correction.additive[len(corr.additive):])
    p = Proposal("additive", chosen.gain - behind, len(correction.additive) - len(corr.additive), correction, label)
    try:
        got = _adopt(nominal, corr, p, rec, rms, size, alpha, states, noise_from)
    except DiagnosisError:
        return None
    if got is None:
        return None
    again = cv_loglik(got[1], got[0], rec, folds, rms, size)
    if _gain(again, score) < evidence_threshold(alpha):
        return None
    chosen.note = (f"adopted as {label} instead: {_gain(again, score):.1f} ahead of it under the noise each leaves "
                   f"(cross-validated; the round's search ranked them under the noise before either)")
    chosen.tried = chosen.tried + [(chosen.correction, chosen.folds)]     # a tie now, or behind
    chosen.correction, chosen.gain = correction, chosen.gain + _gain(again, score)
    return got[0], got[1], again


def _unphysical(before: Correction, after: Correction) -> bool:
    """Whether a term ``after`` adds fits only with a sign physics forbids (an anti-drag): no tie."""
    return any(forbidden_sign(c, coef) for c, coef, _ in after.found[len(before.found):])


def _dropped(p: Proposal, adopted: Correction) -> list[Additive]:
    """The terms proposal ``p`` proposed that its adoption (``adopted``) dropped as not significant."""
    kept = {a[0] for a in adopted.additive}
    return [a[0] for a in p.correction.additive if a[0] not in kept]


def acts(item: dict) -> tuple:
    """What a report item acts on: (effect, its output, input or equation, what it acts through)."""
    return item["effect"], item.get("output") or item.get("input") or item["equation"], item.get("through", "")


def _said(item: dict) -> tuple:
    """A report item as the report states it: its effect, where, and expression."""
    return tuple(item.get(k) for k in ("effect", "equation", "input", "output", "through", "expression"))


def _where(c: Additive) -> str:
    return f"{c.effect} on {c.equation}" + (f" through {c.through}" if c.through else "")


SWAP_CORRELATION = 0.5


def _scored(nominal, trial: Correction, rec, folds, rms, size) -> tuple[Correction, np.ndarray] | None:
    """``trial`` with its additive coefficients refitted, and its per-fold cross-validated
    log-likelihood; None where its filter diverges."""
    try:
        trial = refit(nominal, trial, rec, rms, size)
        return trial, cv_loglik(nominal, trial, rec, folds, rms, size)
    except (FloatingPointError, RuntimeError, np.linalg.LinAlgError):
        return None


def _swaps(nominal, current: Correction, new: Correction, score, cands, rec, folds, rms, size, states,
           tried: list | None = None):
    """ARD keeps one of several terms that explain the same thing (a one-sided limit or a cubic
    spring for a hardening): each kept term is swapped for every other candidate on its equation
    whose values along the trajectory correlate with it (|r| > 0.5; a constant, with every term),
    and a swap is kept when the cross-validated log-likelihood rises. Every swap scored, and the
    correction it replaced, is appended to ``tried``."""
    n0 = len(current.additive)
    vals = dict(zip(cands, basis_values(nominal, rec, states, cands)))
    for i in range(n0, len(new.additive)):
        k = new.additive[i][0]
        for c in cands:
            if c.equation != k.equation or c.group == k.group or any(c.group == a[0].group for a in new.additive):
                continue
            constant = min(np.std(vals[k]), np.std(vals[c])) == 0       # a bias is tried against every term
            if not constant and abs(np.corrcoef(vals[k], vals[c])[0, 1]) < SWAP_CORRELATION:
                continue
            scored = _scored(nominal, Correction(new.additive[:i] + [(c, 0.0, 0.0)] + new.additive[i + 1:],
                                                 new.structural), rec, folds, rms, size)
            if scored is None:
                continue
            if np.sum(scored[1]) > np.sum(score):
                scored, (new, score) = (new, score), scored
            if tried is not None:
                tried.append(scored)
    return new, score


SIMPLER_CORRELATION = 0.95


def _simplest(nominal, current: Correction, new: Correction, score, cands, rec, folds, rms, size, states,
              alpha: float, tried: list | None = None):
    """Several terms ARD keeps on one equation may together draw what one other candidate, or
    one of them, draws alone (a viscous damping and a cubic damping for a quadratic drag seen
    over a narrow range of speeds; a cubic damping and a viscous one for a viscous one): each of
    them alone, and each other candidate whose values along the trajectory follow the kept terms'
    sum (|r| > SIMPLER_CORRELATION), replaces them when its cross-validated log-likelihood is
    within what a finding must add (:func:`evidence_threshold`) of theirs: fewer numbers for the
    same evidence. (On a closed-loop hover, where vz and pwm move together, ARD kept nine terms with
    weights of ±400 that cross-validated 59 nats below none of them; the missing thrust alone, 110
    above.) The best such replacement is kept; every one scored, and what it replaced, is
    appended to ``tried``."""
    n0 = len(current.additive)
    added = new.additive[n0:]
    eqs = [e for e in {a[0].equation for a in added} if sum(a[0].equation == e for a in added) > 1]
    if not eqs:
        return new, score
    vals = dict(zip(cands, basis_values(nominal, rec, states, cands)))
    best = None
    for eq in eqs:
        mine = [a for a in added if a[0].equation == eq]
        drawn = sum(coef * vals[c] for c, coef, _ in mine if c in vals)
        if np.ndim(drawn) == 0 or np.std(drawn) == 0:
            continue
        own = {a[0] for a in mine}
        for c in cands:
            if c.equation != eq or any(c.group == a[0].group for a in new.additive if a not in mine):
                continue
            if c not in own and (np.std(vals[c]) == 0 or abs(np.corrcoef(vals[c], drawn)[0, 1]) < SIMPLER_CORRELATION):
                continue
            scored = _scored(nominal, Correction(current.additive + [a for a in added if a[0].equation != eq]
                                                 + [(c, 0.0, 0.0)], new.structural), rec, folds, rms, size)
            if scored is not None and tried is not None:
                tried.append(scored)
            if scored is not None and np.sum(scored[1]) > np.sum(score) - evidence_threshold(alpha) and \
                    (best is None or np.sum(scored[1]) > np.sum(best[1])):
                best = scored
    if best is not None and tried is not None:
        tried.append((new, score))
    return best if best is not None else (new, score)


def _filters_of(base: Model, s: Structural):
    """v → the EKF of ``s.build(base, v)``. A continuous change (``s.refit``: a limit, a width, a time
    constant, a sensor's offset, gain or bound) is built and derived once, its value a declared
    parameter, and each v sets it (:meth:`DerivedFilter.at`: the steps differ in a constant and share
    one chain; ``s.refit`` promises that its build takes a parameter, as the joint refit's does); a
    whole or fractional delay or a play changes the model's structure and is built per v."""
    if not s.refit:
        return lambda v: derive(s.build(base, v), "ekf")
    m = T.copy_model(base)
    name = T._unique(m, f"{s.effect}_value")
    filt = derive(s.build(m, m.parameter(name, float(s.grid[0]))), "ekf")
    return lambda v: filt.at(**{name: float(v)})


EXTENSIONS = 3      # steps of Structural.beyond past the grid's end (an offset: to 27 × the output's RMS)
RESOLUTION = 2e-4   # relative: where a profile stops (on 3 significant digits, and to 2e-3, a gyro's
                    # gain of 1.08 ± 0.0004 came out 1.09, 25σ off, while a gain below 1 resolved to
                    # 0.1 %: the encoder's 1/1.08 won and an input gain made up for the rest)


def _value(v: float) -> float:
    """A profiled value, rounded well below :data:`RESOLUTION` (its evaluations are shared)."""
    return float(f"{float(v):.6g}")


def _structural(base: Model, s: Structural, rec: Recording, folds: Folds):
    """(value refined on the whole recording, its std, per-fold cross-validated log-likelihood):
    per fold, the value best on the other folds among the grid and the profile's points. (On the
    grid alone, a coarse one lost the refined value: a rudder stop at 0.347 rad for a true 0.349,
    whose grid of |δ|'s quantiles was 0.105, 0.570, 0.611 because the commands sat on their ±0.611
    limit, scored +28.5 instead of +107 and an input gain was named in its place.)"""
    table: dict[float, np.ndarray] = {}
    filt = _filters_of(base, s)

    def per_fold(v):
        v = float(round(v)) if s.integer else _value(v)
        if v not in table:
            try:
                table[v] = fold_loglik(filt(v), rec, folds)
            except ValueError:            # a parameter the transformation refuses
                table[v] = np.full(len(folds), -np.inf)
        return table[v]

    grid = list(s.grid)
    if s.integer:
        coarse = sorted({g for g in grid if g & (g - 1) == 0} | {grid[-1]})
        totals = [t.sum() for t in parallel(per_fold, coarse)]
        i = int(np.argmax(totals))
        grid = list(range(int(coarse[max(i - 1, 0)]), int(coarse[min(i + 1, len(coarse) - 1)]) + 1))
    parallel(per_fold, grid)
    _past_ends(lambda v: per_fold(v).sum(), s, {x: L.sum() for x, L in table.items()})
    value, _, std = _profile(lambda v: per_fold(v).sum(), s, np.array(sorted(table)))
    xs = np.array(sorted(table))                             # the grid and the profile's points
    L = np.array([table[x] for x in xs])                     # (values, folds)
    others = np.where(~np.eye(len(folds), dtype=bool), L[:, None, :], 0.0).sum(axis=2)   # no −inf − (−inf)
    cv = L[np.argmax(others, axis=0), np.arange(len(folds))]
    return value, std, cv


def _past_ends(total, s: Structural, seen: dict) -> None:
    """While an end of the values ``seen`` (value → ``total``, updated) is the best, the value past it,
    ``s.beyond`` times farther from 0 past the upper end and times nearer past the lower one (of a
    positive grid; an offset's lower end is negative: farther) (EXTENSIONS at most; none when
    ``s.beyond`` is 0)."""
    for _ in range(EXTENSIONS if s.beyond else 0):
        xs = sorted(seen)
        j = int(np.argmax([seen[x] for x in xs]))
        if 0 < j < len(xs) - 1:
            return
        x = xs[j] * s.beyond if (j > 0) == (xs[j] > 0) else xs[j] / s.beyond
        if s.least and abs(x) < s.least:          # below what the integration step resolves
            return
        seen[x] = total(x)


def _profile(total, s: Structural, evaluated) -> tuple[float, float, float]:
    """Best parameter by whole-recording log-likelihood ``total(v)`` (past the evaluated ends while
    one is best, :func:`_past_ends`): Brent's search between the best evaluated point's neighbours
    (log scale for scale parameters), or for a whole number the halving of the gaps beside the best
    down to its neighbours (a 25-sample delay, past the grid's 15, was named 30: nothing between
    was tried); std from the curvature (none for a whole number)."""
    seen = {float(x): total(x) for x in evaluated}
    _past_ends(total, s, seen)
    def bracket():
        xs = np.array(sorted(seen))
        ys = np.array([seen[x] for x in xs])
        return xs, ys, int(np.argmax(ys))
    xs, ys, j = bracket()
    while s.integer:
        between = {float(round((a + b) / 2)) for a, b in zip(xs[max(j - 1, 0):j + 1], xs[j:j + 2]) if b - a > 1}
        if not between:
            break
        seen.update({v: total(v) for v in between})
        xs, ys, j = bracket()
    if not s.integer and 0 < j < len(xs) - 1 and np.isfinite(ys[j]):
        to = (lambda x: np.log(x)) if s.log else (lambda x: x)
        back = (lambda x: float(np.exp(x))) if s.log else float
        def f(x):
            v = _value(back(x))
            seen[v] = total(v)
            return -seen[v]
        with np.errstate(invalid="ignore"):      # a refused value (−inf) is a golden-section step
            minimize_scalar(f, bounds=(to(xs[j - 1]), to(xs[j + 1])), method="bounded",
                            options={"xatol": RESOLUTION * (1 if s.log else abs(xs[j]))})
        xs, ys, j = bracket()
    std = np.nan                        # a whole number of samples is a choice, with no error bar
    if not s.integer and 0 < j < len(xs) - 1 and np.all(np.isfinite(ys[j - 1:j + 2])):
        x3 = np.log(xs[j - 1:j + 2]) if s.log else xs[j - 1:j + 2]
        a = np.polyfit(x3, ys[j - 1:j + 2], 2)[0]
        if a < 0:
            sd = np.sqrt(-1 / (2 * a))
            std = float(xs[j] * sd) if s.log else float(sd)
    return float(xs[j]), float(ys[j]), std


def refit(nominal: Model, corr: Correction, rec: Recording, rms: dict, size: dict) -> Correction:
    """Additive coefficients re-estimated jointly on the whole recording under the accepted
    structure (augmented EKF). Coefficients already estimated stay in the model as known
    terms and the filter estimates their corrections (prior std 3σ, at least 10 %): the sigma
    points then stay where the model has been seen to hold."""
    if not corr.additive:
        return corr
    cands = [a[0] for a in corr.additive]
    known = [(c, w, s) for c, w, s in corr.additive if w != 0 and np.isfinite(s) and s > 0]
    prior = None                         # the default: each term alone could explain it twice over
    if len(known) == len(cands):
        prior = np.array([max(3 * s, 0.1 * abs(w)) ** 2 for _, w, s in known])
    else:
        known = []
    m, r = _estimating(Correction(known, corr.structural), nominal, cands, rms, size, prior)
    try:
        w, sd = fit_without(m, "ekf", rec, Folds.of(len(rec.t), 1), None, None)
        w, sd = w / r, sd / r
    except (FloatingPointError, RuntimeError, ValueError, np.linalg.LinAlgError):
        if known:
            return corr                  # the filter diverged: keep the coefficients it started from
        raise
    start = [k[1] for k in known] or [0.0] * len(cands)
    return Correction([(c, float(w0 + wi), float(si)) for c, w0, wi, si in zip(cands, start, w, sd)], corr.structural)


def shape_search(nominal: Model, corr: Correction, variants: dict, rec: Recording, rms: dict,
                 size: dict) -> tuple[Correction, dict]:
    """For each additive finding with variants (same effect and equation, another shape), the
    variant with the best whole-recording log-likelihood after a joint refit; the coefficient's
    std gets the spread over the variants weighted by their likelihood (Bayesian model
    averaging over the shape). Returns the correction and {candidate: shape summary}; the summary's
    ``p_zero`` is the two-sided probability of a zero coefficient under that average (each shape's
    normal tail at zero, weighted by its likelihood): whether the term is needed at all, which the
    spread of its value over the shapes does not say."""
    shapes = {}
    for i, (c, _, _) in enumerate(list(corr.additive)):
        alts = variants.get(c.group, [])
        if len(alts) < 2:
            continue
        fits, lls = [], []
        for alt in alts:
            trial = Correction(corr.additive[:i] + [(alt, 0.0, 0.0)] + corr.additive[i + 1:], corr.structural)
            try:
                trial = refit(nominal, trial, rec, rms, size)
                ll = loglik(trial.build(nominal), rec)
            except (FloatingPointError, RuntimeError, np.linalg.LinAlgError):
                continue
            fits.append(trial)
            lls.append(ll)
        if not fits:
            continue
        lls = np.array(lls)
        weights = np.exp(lls - lls.max())
        weights /= weights.sum()
        best = fits[int(np.argmax(lls))]
        if c.effect in ("physical_limit", "coulomb_friction"):
            best = _refined(nominal, best, i, alts, lls.max(), rec, rms, size)
        coefs = np.array([t.additive[i][1] for t in fits])
        sds = np.array([t.additive[i][2] for t in fits])
        c_best, w_best, s_best = best.additive[i]
        spread = float(np.sqrt(np.sum(weights * (coefs - w_best) ** 2)))
        corr = Correction(corr.additive[:i] + [(c_best, w_best, float(np.hypot(s_best, spread)))]
                          + corr.additive[i + 1:], corr.structural)
        with np.errstate(divide="ignore", invalid="ignore"):
            tails = np.where(np.isfinite(sds) & (sds > 0), 2 * stats.norm.sf(np.abs(coefs) / sds), 1.0)
        shapes[c_best] = {"variant": c_best.variant, "coefficient_std_from_shape": spread,
                          "p_zero": float(np.sum(weights * tails)),
                          "tried": {a.variant: float(l) for a, l in zip(alts, lls - lls.max())}}
    return corr, shapes


def _refined(nominal: Model, best: Correction, i: int, alts: list[Additive], best_ll: float, rec: Recording,
             rms: dict, size: dict) -> Correction:
    """``best`` with the shape of its term ``i`` refined between the grid's neighbours of it — a
    limit's bound, or a Coulomb friction's width on a log scale (past the grid's end by its own
    step): a bounded scalar search on the whole recording's log-likelihood after a joint refit.
    A limit's grid is of the state's quantiles, and a wall between two of them was placed on one
    (0.0319 for a true 0.04, its coefficient 5σ low; refined after the rounds alone, 0.0328 beside a
    sensor offset a later round had found for the grid's bound: it is refined when adopted too,
    :func:`_shaped`); a friction's widths are 4× apart, and one of 0.01 m/s was taken at 0.0044,
    its coefficient 2.5σ low and "a mismatch remains"."""
    c = best.additive[i][0]
    if c.effect == "physical_limit":
        shape = dict(c.shape)
        grid = sorted({dict(a.shape)["bound"] for a in alts if dict(a.shape)["side"] == shape["side"]} | {shape["bound"]})
        k = grid.index(shape["bound"])
        lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
        unit = next(v.unit for v in nominal.states if v.name == shape["state"])
        make, to, back = (lambda b: C.limit(c.equation, shape["state"], shape["side"], b, unit)), float, float
    else:
        grid = sorted({dict(a.shape)["width"] for a in alts})
        k = grid.index(dict(c.shape)["width"])
        step = grid[1] / grid[0] if len(grid) > 1 else 4.0
        lo = grid[k - 1] if k > 0 else grid[0] / step
        hi = grid[k + 1] if k + 1 < len(grid) else grid[-1] * step
        make, to, back = (lambda w: C.coulomb_width(c, w)), np.log, np.exp
    if not lo < hi:
        return best
    tried = {}

    def minus_ll(v: float) -> float:
        cand = make(back(v))
        rms.setdefault(cand, rms[c])
        trial = Correction(best.additive[:i] + [(cand, 0.0, 0.0)] + best.additive[i + 1:], best.structural)
        try:
            trial = refit(nominal, trial, rec, rms, size)
            tried[v] = (loglik(trial.build(nominal), rec), trial)
        except (FloatingPointError, RuntimeError, np.linalg.LinAlgError):
            return np.inf
        return -tried[v][0] if np.isfinite(tried[v][0]) else np.inf

    a, b = to(lo), to(hi)
    minimize_scalar(minus_ll, bounds=(a, b), method="bounded", options={"xatol": 1e-3 * (b - a), "maxiter": 16})
    ll, refined = max(tried.values(), key=lambda t: t[0], default=(-np.inf, best))
    return refined if ll > best_ll else best


def name_terms(nominal: Model, rec: Recording, folds: Folds, equations: list[str], states: np.ndarray,
               disturbance_rms: dict[str, float], additive: list[Additive], structural: list[Structural],
               alpha: float = 0.01, progress=None, focus: tuple[int, int] | None = None,
               parameters: list[Additive] = (), noise_from=None,
               restartable: bool = False) -> tuple[Correction, list[Proposal], dict, dict, Model]:
    """See the module docstring. ``states``: smoothed nominal states (for candidate scales);
    ``disturbance_rms``: RMS of the located disturbance per equation (the missing rate's size);
    ``focus``: the samples [a, b) SKI selects on (all of them by default); ``parameters``: the
    declared parameters' corrections (:func:`catalog.parameter_terms`), refitted with every candidate;
    ``noise_from``: the user's declared (Q, R), a start of every recalibration (:func:`calibrate`);
    ``restartable``: a finalist whose filter fails from the declared start, which it rejects, raises
    :class:`StartRejected` (else it is not adopted).
    Returns (correction, proposals accepted or not, candidate RMS, per-equation sizes, ``nominal``
    with the noise recalibrated under the correction)."""
    tick = progress or (lambda label: None)
    size = {eq: disturbance_rms.get(eq, 1.0) for eq in {c.equation for c in [*additive, *parameters]}}
    variants = {}
    for c in additive:
        variants.setdefault(c.group, []).append(c)
    additive = representatives(distinct(nominal, rec, states, additive)) if additive else []
    every = additive + list(parameters)
    rms = dict(zip(every, basis_rms(nominal, rec, states, every))) if every else {}
    n_cands = max(1, len(additive) + len(structural))
    try:
        corr = refit(nominal, Correction([(c, 0.0, 0.0) for c in parameters]), rec, rms, size)
    except (FloatingPointError, RuntimeError, np.linalg.LinAlgError):
        corr = Correction()        # their corrections make the filter diverge: held as calibrated
    current = cv_loglik(nominal, corr, rec, folds, rms, size)
    first = nominal                        # as calibrated before anything was named
    history, aside, rounds = [], set(), []
    for _ in range(MAX_ROUNDS):
        proposals = []
        used = {a[0].key for a in corr.additive} | aside
        cands = [c for c in additive if c.key not in used]
        if cands:
            tick("SKI over the additive candidates, per fold")
            try:
                p = _additive(nominal, corr, cands, rec, folds, rms, size, alpha, focus, states)
            except (FloatingPointError, RuntimeError, np.linalg.LinAlgError):   # diverged: no proposal
                p = None
            if p is not None:
                proposals.append(p)
        done = {s[0].key for s in corr.structural}
        base = corr.build(nominal)
        for s in structural:
            if s.key in done:
                continue
            label = _label(s)
            tick(label)
            value, std, cv = _structural(base, s, rec, folds)
            proposals.append(Proposal("structural", 0.0, s.params,
                                      Correction(corr.additive, corr.structural + [(s, value, std)]), label, cv))
        if not proposals:
            break
        for p in proposals:
            p.gain = _gain(p.folds, current)
        ranked = sorted(proposals, key=lambda p: -p.gain)
        passing = [p for p in ranked[:FINALISTS] if 2 * p.gain > stats.chi2.ppf(1 - alpha / n_cands, p.params)
                   and not (history and p.gain < MIN_SHARE * sum(h.gain for h in history))
                   and p.gain >= RIVAL_SHARE * ranked[0].gain]
        history.append(ranked[0])
        adopted = []
        for p in passing:                  # each finalist under the noise it leaves, then the best
            tick(f"recalibrating the noise under {p.label}")
            try:
                got = _adopt(nominal, corr, p, rec, rms, size, alpha, states, noise_from)
            except DiagnosisError:         # no noise calibrates under it: not adopted
                got = None
            if got is not None and _gain(score := cv_loglik(got[1], got[0], rec, folds, rms, size), 0.0) > -np.inf:
                adopted.append(got + (score, p))
            elif got is not None and restartable and not first_start(built := got[0].build(got[1]), rec):
                raise StartRejected(built, p.label)
        if not adopted:                    # its terms compensating: the next round searches without them
            new_aside = {(a["effect"], a["equation"], a.get("through", "")) for p in passing for a in p.set_aside}
            if not new_aside - aside:
                break
            aside |= new_aside
            continue
        new, recal, score, chosen = max(adopted, key=lambda a: np.sum(a[2]))
        history[-1] = chosen
        for swapped in (False, True):
            chosen.adopted = added(corr, new)
            chosen.as_good, chosen.alternatives, chosen.rivals = [], [], []   # its swaps' ties were under the noise before it
            same = {_said(a) for a in chosen.adopted}
            for other, _, other_score, p in adopted:      # a finalist within what a finding must add: a tie
                behind = -_gain(other_score, score)
                if p is not chosen and behind < evidence_threshold(alpha):   # not the same change found twice
                    items = [a for a in _together(added(corr, other), cv_loglik_behind=behind) if _said(a) not in same]
                    chosen.as_good += items
                    chosen.alternatives += [other] if items else []
                elif p is not chosen and behind < TIE_MARGIN * evidence_threshold(alpha) and \
                        any(_said(item) not in same for item in added(corr, other)):
                    chosen.rivals.append(other)
            items, whole, ahead = _ties_under(nominal, recal, corr, new, chosen, score, proposals, rec, folds, rms,
                                              size, alpha, noise_from)
            chosen.as_good += items
            chosen.alternatives += whole
            if swapped or not (better := _better(nominal, corr, chosen, ahead, score, rec, folds, rms, size, alpha,
                                                 states, noise_from)):
                break
            new, recal, score = better
        if len(history) > 1:               # a further change: weighed as evidence.weigh would weigh it
            ev, total = _share((recal, nominal, first), corr, new, score, rec, folds, rms, size)
            if ev < max(evidence_threshold(alpha), MIN_SHARE * total):
                chosen.note = (f"not adopted: it adds {ev:+.1f} to the {total:+.1f} the correction gains "
                               f"(cross-validated, each model under the better of the noises calibrated)")
                break
        earlier = [e[0] for e in corr.structural]
        rounds.append((chosen, corr))
        fresh = {c.group for c, _, _ in new.additive} - {c.group for c, _, _ in corr.additive}
        corr, nominal, current = new, recal, score
        if shaped := _shaped(nominal, corr, fresh, variants, rec, states, rms, size):
            corr, current = shaped, cv_loglik(nominal, shaped, rec, folds, rms, size)
        if chosen.kind == "structural" and _label(corr.structural[-1][0]) != chosen.label:
            chosen.label += f", adopted as {_label(corr.structural[-1][0])}"   # a fractional delay, whole
        again = redelayed(nominal, corr, earlier, rec, alpha, rms, size)
        if again is not corr:
            corr, current = again, cv_loglik(nominal, again, rec, folds, rms, size)
    if revision := _revised(first, corr, current, rounds, rec, folds, rms, size, alpha, states, noise_from):
        history.append(revision)
        corr, nominal, current = revision.correction, revision.noise, revision.folds
    return corr, history, rms, size, nominal


def _shaped(nominal: Model, corr: Correction, groups: set, variants: dict, rec: Recording, states: np.ndarray,
            rms: dict, size: dict) -> Correction | None:
    """``corr`` with the shape of its terms of ``groups`` (just adopted) searched at once
    (:func:`shape_search`), or None when none has variants: a later round is weighed against the
    best shape, not the grid's middle one."""
    shaped = {g: variants[g] for g in groups if len(variants.get(g, ())) > 1}
    if not shaped:
        return None
    if alts := [a for g in shaped.values() for a in g if a not in rms]:
        rms.update(zip(alts, basis_rms(nominal, rec, states, alts)))
    return shape_search(nominal, corr, shaped, rec, rms, size)[0]


class StartRejected(Exception):
    """A finding whose filter fails under its own noise rejects the recording's declared start,
    which the nominal's misfit had covered: the diagnosis starts again from the vague prior,
    judged with ``model`` (the nominal with the finding ``label``)."""

    def __init__(self, model: Model, label: str):
        super().__init__(label)
        self.model, self.label = model, label


def first_start(model: Model, rec: Recording) -> bool:
    """Whether ``model`` takes ``rec``'s declared start (:func:`skigen.start.recorded_start`)."""
    rs = recorded_start(model, rec)
    return rs is None or rs.consistent


def _revised(first: Model, corr: Correction, current, rounds: list, rec, folds, rms, size, alpha: float,
             states: np.ndarray, noise_from=None) -> "Proposal | None":
    """The best of the rounds' ties and rivals, each in the correction it was scored in (without
    the terms its round's adoption dropped as not significant), under the noise calibrated with
    it: a tie without the later rounds' findings, a tie or a rival with those of them it still
    needs (:func:`_pruned`). Taken when it explains the recording within what a finding must add
    of the final correction ``current`` (cross-validated) with fewer numbers, or better with as
    many; none whose terms a round would set aside as compensating (an anti-drag 1.3 ahead of a
    heavier cart's damping constant replaced it, then was dropped, and the damping with it). A
    proposal whose ``noise`` is that model; None if there is none. (KT·pwm² 10 % low on a
    closed-loop hover: a rate offset was chosen over the thrust term, 0.6 ahead, and a lidar gain
    of 0.93 was named to make up the rest; the thrust term alone was 0.7 behind both. A wheel
    speed sensor reading 4 % high on a car whose GPS reads position: a GPS gain of 0.96 won the
    first round, 22 ahead, and needed a 4 % force gain and a drag change beside it; the wheel gain
    with the rolling resistance alone explains as well with two numbers fewer.)"""
    best, final = None, _numbers(corr)
    for (p, before), after in zip(rounds, [r[1] for r in rounds[1:]] + [corr]):
        lost = _dropped(p, after)
        later = [a for a in corr.additive if a[0] not in {b[0] for b in after.additive}] + \
                [s for s in corr.structural if s[0] not in {b[0] for b in after.structural}]
        trials = [alt.without(*lost) for alt in p.alternatives]
        trials += [_joined(alt.without(*lost), later) for alt in (p.alternatives + p.rivals) if later]
        for trial in trials:
            got = _pruned(first, trial, [t[0] for t in later if _in(t[0], trial)], rec, folds, rms, size,
                          alpha, current, noise_from)
            if got is None or any(compensating(got[0], c, coef, states, rec)
                                  for c, coef, _ in got[1][0].found[len(before.found):]):
                continue                       # a term a round would set aside is no revision
            short, fewer = -_gain(got[1][1], current), _numbers(got[1][0]) < final
            if (short < evidence_threshold(alpha) if fewer else short < 0 and _numbers(got[1][0]) == final) \
                    and (best is None or np.sum(got[1][1]) > np.sum(best[1][1])):
                best = (*got, short, before, after)
    if best is None:
        return None
    noise, (revised, score), short, before, after = best
    keys = lambda c: {k for k, _ in _keyed(before, c)}
    mine = [a for k, a in _keyed(before, revised) if k not in keys(corr)]
    replaced = [a for k, a in _keyed(before, after) if k not in keys(revised)]
    later = [a for k, a in _keyed(after, corr) if k not in keys(revised)]
    revision = Proposal("revision", -short, _numbers(revised) - final, revised,
                        ", ".join(map(_text, mine)) + " in place of " + ", ".join(map(_text, replaced))
                        + (", leaving out " + ", ".join(map(_text, later)) if later else ""), score)
    revision.noise, revision.adopted = noise, mine
    revision.note = ("a tie or rival of an earlier round" + (" that leaves later findings unneeded" if later else "")
                     + ": fewer numbers for the same evidence" if _numbers(revised) < final else
                     "a tie that explains the recording better under the noise calibrated with it")
    instead, others = [list(acts(b)) for b in mine], replaced + later
    revision.as_good = [a | {"cv_loglik_behind": -short, "instead_of": instead, "replaced": True,
                             "with": [_text(b) for b in others if b is not a]} for a in others
                        if -short < evidence_threshold(alpha)]           # what it replaced, if still a tie
    return revision


def _keyed(before: Correction, after: Correction) -> list[tuple]:
    """What ``after`` adds to ``before``: (candidate key, report item) per term."""
    terms = after.found[len(before.found):] + after.structural[len(before.structural):]
    return [(t[0].key, item) for t, item in zip(terms, added(before, after))]


def _numbers(corr: Correction) -> int:
    """The numbers a correction's findings choose (a declared parameter's correction not counted)."""
    return len(corr.found) + len(corr.structural)


def _in(term, corr: Correction) -> bool:
    return any(a[0] is term for a in corr.additive + corr.structural)


def _joined(alt: Correction, later: list) -> Correction:
    """``alt`` with the ``later`` terms (additive or structural, as in a correction) it lacks."""
    have = {id(a[0]) for a in alt.additive + alt.structural}
    more = [t for t in later if id(t[0]) not in have]
    return Correction(alt.additive + [t for t in more if isinstance(t[0], Additive)],
                      alt.structural + [t for t in more if not isinstance(t[0], Additive)])


def _pruned(first: Model, trial: Correction, optional: list, rec, folds, rms, size, alpha: float, current,
            noise_from=None) -> tuple[Model, tuple[Correction, np.ndarray]] | None:
    """``trial`` refitted under the noise calibrated with it, then without each ``optional`` term
    whose drop costs less than what a finding must add (cross-validated), the least needed first:
    (noise, (correction, per-fold log-likelihood)); None where its filter diverges, or where it is
    too far behind ``current`` (the final correction's per-fold log-likelihood) to be taken: beyond
    TIE_MARGIN thresholds under the first noise (the second moved a car's wheel gain by 16), or
    beyond one under the second (a drop does not raise it)."""
    try:                                       # its coefficients as the noise before naming has them
        trial = refit(first, trial, rec, rms, size)
    except (FloatingPointError, RuntimeError, np.linalg.LinAlgError):
        return None
    noise = recalibrated(first, trial, rec, noise_from)
    if (scored := _scored(noise, trial, rec, folds, rms, size)) is None or \
            -_gain(scored[1], current) >= TIE_MARGIN * evidence_threshold(alpha):
        return None
    again = recalibrated(first, scored[0], rec, noise_from)      # the noise under coefficients fitted with it
    if (rescored := _scored(again, scored[0], rec, folds, rms, size)) and np.sum(rescored[1]) > np.sum(scored[1]):
        noise, scored = again, rescored
    if -_gain(scored[1], current) >= evidence_threshold(alpha):
        return None
    optional = list(optional)
    while optional:
        drops = [(d, t) for t in optional if (d := _scored(noise, scored[0].without(t), rec, folds, rms, size))]
        if not drops:
            break
        drop, t = max(drops, key=lambda d: np.sum(d[0][1]))
        if -_gain(drop[1], scored[1]) >= evidence_threshold(alpha):
            break
        scored = drop
        optional.remove(t)
    return noise, scored


def _together(items: list[dict], **about) -> list[dict]:
    """The report items of one alternative explanation, each with ``about`` and, where it has
    several terms, the others (``with``): a speed sensor's offset ties with a bias on the speed and
    one on the current together (the state shifted by it), and was said to tie with each alone."""
    return [a | about | ({"with": [_text(b) for b in items if b is not a]} if len(items) > 1 else {}) for a in items]


def _text(item: dict) -> str:
    """A report item as the round labels say it: 'bias on vz (`1`)', 'sensor_gain of z_lidar (`0.951·z`)'."""
    effect, where, through = acts(item)
    return f"{effect} {'of' if item.get('output') or item.get('input') else 'on'} {where}" + (
        f" through {through}" if through else "") + f" (`{item['expression']}`)"


def added(before: Correction, after: Correction) -> list[dict]:
    """What ``after`` adds to ``before``, as report items (effect, equation or signal, expression,
    coefficient)."""
    terms = [{k: v for k, v in term_item(c, coef, std, "").items() if k != "note"}
             for c, coef, std in after.found[len(before.found):]]
    return terms + [{"effect": s.effect, **({"output": s.output} if s.output else {"input": s.input}),
                     **({"written_in": list(s.equations)} if s.equations else {}),
                     "expression": s.describe(value), "coefficient": value, "std": std}
                    for s, value, std in after.structural[len(before.structural):]]


def _gain(folds, current) -> float:
    """Cross-validated log-likelihood ``folds`` gains over ``current`` (per-fold arrays, or a number);
    −inf where it cannot be scored (a fold whose filter diverges under both: −inf − (−inf))."""
    with np.errstate(invalid="ignore"):
        g = float(np.sum(folds) - np.sum(current))
    return -np.inf if np.isnan(g) else g


def evidence_threshold(alpha: float) -> float:
    """The least drop-one cross-validated log-likelihood a finding must add: 0.5·χ²₁(1 − α)."""
    return 0.5 * stats.chi2.isf(alpha, 1)


def _share(noises: tuple, before: Correction, after: Correction, score: np.ndarray, rec: Recording,
           folds: Folds, rms: dict, size: dict) -> tuple[float, float]:
    """(what ``after`` adds to ``before``, what ``after`` adds to the declared parameters' corrections
    alone), cross-validated, each model under the best of ``noises`` (the nominal with the noise
    calibrated under ``after``, under ``before``, before naming; see :mod:`skigen.diagnose.evidence`);
    ``score`` is ``after``'s per-fold score under the first. Under ``after``'s noise alone the
    total was inflated (+11 243 where the in-sample gain was a few hundred) and a second effect
    adding +21 fell short of its 1 %."""
    base = Correction([a for a in after.additive if a[0].parameter])
    best = lambda corr, among: best_cv_loglik(among, corr, rec, folds, rms, size)
    full = max(float(np.sum(score)), best(after, noises[1:]))
    return full - best(before, noises), full - best(base, noises)


def best_cv_loglik(noises, corr: Correction, rec: Recording, folds: Folds, rms: dict, size: dict) -> float:
    """The summed cross-validated log-likelihood of ``corr`` under the best of ``noises`` (nominal
    models that differ in their calibrated noise): each model is weighed under the noise that
    serves it best among those calibrated (see :mod:`skigen.diagnose.evidence`)."""
    return max(float(np.sum(cv_loglik(n, corr, rec, folds, rms, size))) for n in noises)


def _label(s: Structural) -> str:
    if s.effect == "constant":
        return f"the constant {s.target}"
    return f"{s.effect} of {s.target}" + (f" ({s.side})" if s.side else "")


def _adopt(nominal: Model, corr: Correction, p: Proposal, rec: Recording, rms: dict, size: dict,
           alpha: float, states: np.ndarray, noise_from=None) -> tuple[Correction, Model] | None:
    """(the correction with proposal ``p`` adopted, the nominal with the noise recalibrated under it),
    or None when none of an additive proposal's terms survives an honest (EKF) refit with a sign
    physics allows (the others go to ``p.set_aside``)."""
    accepted = refit(nominal, p.correction, rec, rms, size)
    new_terms, weak = [], []
    for c, coef, std in accepted.additive[len(corr.additive):]:
        if not significant(coef, std, alpha):
            weak.append(c)
            continue
        if why := compensating(nominal, c, coef, states, rec):
            p.set_aside.append(term_item(c, coef, std, why))
        else:
            new_terms.append((c, coef, std))
    if weak and new_terms:           # said, or the round's line lists a term the correction lacks
        p.note = (f"{', '.join(_where(c) for c in weak)} not adopted: refitted with the others by the EKF, "
                  f"within {stats.norm.isf(alpha / 2):.2f} std of zero")
    if p.kind == "additive" and not new_terms:
        if not p.set_aside:          # said, or the report lists a gain of +146 and adopts nothing in silence
            n = len(accepted.additive) - len(corr.additive)
            p.note = (f"not adopted: refitted together by the EKF, none of its {n} term(s) is significant "
                      f"(within {stats.norm.isf(alpha / 2):.2f} std of zero): together they explain what none "
                      f"explains alone, a sign of physics outside the candidates")
        return None
    new = refit(nominal, Correction(accepted.additive[:len(corr.additive)] + new_terms, accepted.structural),
                rec, rms, size)
    nominal = recalibrated(nominal, new, rec, noise_from)
    if p.kind == "structural":             # its parameter again, under the noise it leaves
        before = new.structural[-1][:2]
        new = coarsened(nominal, reprofiled(nominal, new, rec), rec, alpha)
        if new.structural[-1][0] is not before[0] or not np.isclose(new.structural[-1][1], before[1], rtol=1e-3):
            nominal = recalibrated(nominal, new, rec, noise_from)
    return refit(nominal, new, rec, rms, size), nominal


def coarsened(nominal: Model, corr: Correction, rec: Recording, alpha: float) -> Correction:
    """The last structural change replaced by its coarser form at the rounded value (a fractional
    delay by the whole delay) unless it is significantly better on the whole recording:
    2·(log-likelihood gain) > the χ² quantile 1 − α for the one number it adds."""
    s, value, _ = corr.structural[-1]
    whole = float(round(value))
    if s.coarser is None or whole not in s.coarser.grid:
        return corr
    base = Correction(corr.additive, corr.structural[:-1]).build(nominal)
    gain = loglik(s.build(base, value), rec) - loglik(s.coarser.build(base, whole), rec)
    if 2 * gain > stats.chi2.ppf(1 - alpha, s.params - s.coarser.params):
        return corr
    return reprofiled(nominal, Correction(corr.additive, corr.structural[:-1] + [(s.coarser, whole, np.nan)]), rec)


DELAYS = ("input_delay", "fractional_delay")


def redelayed(nominal: Model, corr: Correction, earlier: list, rec: Recording, alpha: float, rms: dict,
              size: dict) -> Correction:
    """``corr`` with each delay of ``earlier`` (the structural changes adopted in earlier rounds)
    searched again given everything adopted since, and the additive coefficients refitted (``corr``
    itself when none moved). A delay chosen
    before a Coulomb friction took 2.6 samples for a true 3, half of what the friction left
    unexplained; a delay commutes with every other (time-invariant) change, so it is moved last
    and profiled there."""
    moved = corr
    for s, value, _ in corr.structural:
        if s.effect not in DELAYS or not any(s is e for e in earlier):
            continue
        rest = [e for e in moved.structural if e[0] is not s]
        trial = Correction(moved.additive, rest + [e for e in moved.structural if e[0] is s])
        trial = coarsened(nominal, reprofiled(nominal, trial, rec), rec, alpha)
        if not np.isclose(trial.structural[-1][1], value, rtol=1e-3) or trial.structural[-1][0] is not s:
            moved = trial
    return corr if moved is corr else refit(nominal, moved, rec, rms, size)


def reprofiled(nominal: Model, corr: Correction, rec: Recording) -> Correction:
    """The last structural change's parameter profiled again on the whole recording."""
    s, _, _ = corr.structural[-1]
    filt = _filters_of(Correction(corr.additive, corr.structural[:-1]).build(nominal), s)

    def total(v):
        try:
            return loglik(filt(v), rec)
        except ValueError:                # a parameter the transformation refuses
            return -np.inf
    grid = s.grid if not s.integer else range(int(min(s.grid)), int(max(s.grid)) + 1)
    value, _, std = _profile(total, s, [float(g) for g in grid])
    return Correction(corr.additive, corr.structural[:-1] + [(s, value, std)])


def recalibrated(nominal: Model, corr: Correction, rec: Recording, noise_from=None) -> Model:
    """``nominal`` with the noise the corrected model calibrates to: what the accepted terms
    explain is no longer left to the process noise (started from the user's declared noise
    ``noise_from`` as well: the nominal's calibration may sit where that was all process noise).
    Where the recording cannot tell the noises apart there (it explains so much that process and
    sensor noise trade off along a flat valley), the calibration starts again from ``noise_from``
    (a cart's friction, under the nominal's velocity noise 84× the declared std, was given a width
    5.5× the true one, for which a sensor gain then made up), and failing that too, the noise it
    was scored under is kept."""
    from .calibrate import NoiseNotIdentifiable, calibrate
    try:
        cal, _ = calibrate(corr.build(nominal), [rec], noise_from=noise_from)
    except NoiseNotIdentifiable:
        if noise_from is None:
            return nominal
        try:
            cal, _ = calibrate(corr.build(_with_noise(nominal, *noise_from)), [rec])
        except NoiseNotIdentifiable:
            return nominal
    nx = len(nominal.states)
    return _with_noise(nominal, cal.process_noise()[:nx, :nx], cal.measurement_noise())


def _with_noise(model: Model, Q, R) -> Model:
    """A copy of ``model`` with process noise ``Q`` and sensor noise ``R`` (its P₀ kept)."""
    m = T.copy_model(model)
    m.covariances(Q=Q, R=R, P0=model.initial_covariance())
    return m
