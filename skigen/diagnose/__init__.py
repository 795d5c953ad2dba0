"""Diagnose a model against a recording: detect, locate, name, model, show the fit improve.

    from skigen.diagnose import diagnose
    report = diagnose("models/cart.py", "flight.csv", "out/diag")
    report.mismatch_detected, report.findings, report.data      # report.json as a dict

The nominal model is the user's simulation (its declared unknown term, if
any, is left out); the recording is the truth. Steps, one module each:
:mod:`calibrate` (noise and declared parameters by maximum likelihood),
:mod:`detect` (the verdict on the calibrated model, and what remains after
the correction), :mod:`locate` (outputs, equations, windows, regime),
:mod:`name` (catalog terms by SKI, structural changes by profile, each scored
by the blocked cross-validation of :mod:`cv`), :mod:`plausible` (signs and
identifiability), :mod:`evidence` (drop-one cross-validated log-likelihood per
finding), :mod:`correct` (the jointly refitted corrected model, its file and
its C), :mod:`fit` (before/after statistics), :mod:`suggest` (what the rest
follows), :mod:`report` and :mod:`figures`.
"""
from __future__ import annotations

import functools
import sys
from time import perf_counter
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np
from scipy import stats

from ..model import Model, ModelError, _complex
from ..progress import shown
from ..recording import RecordingError
from ..simulate import free_run
from ..start import DIFFUSE, recorded_start
from . import catalog as C
from . import transform as T
from .calibrate import calibrate
from .correct import emit_filter, header_lines, refit_jointly, write_model_file
from .cv import DEFAULT_BLOCKS, DEFAULT_FOLDS, Folds, ekf_run, fold_loglik
from .detect import (Consistency, consistency, drifting, judge, normalised_innovations, relation_break, remaining,
                     unexplained)
from .errors import DiagnosisError
from .evidence import weigh
from .figures import diagnosis_figures, plot_residuals
from .fit import DIVERGED, evaluate_fit, free_run_window, simulation_worth
from .inputs import MIN_SAMPLES, check, load, usable
from .locate import Location, locate
from .suggest import explain
from .name import (DELAYS, Correction, StartRejected, acts, basis_rms, beyond_parameters, focus_window,
                   name_terms, recalibrated, redelayed, shape_search)
from .plausible import screen, significant, term_item
from .name import refit as refit_terms
from .report import behind, where, write_json, write_markdown

__all__ = ["diagnose", "detect", "Report", "DiagnosisError", "MIN_SAMPLES"]

@dataclass
class Report:
    """What :func:`diagnose` found; ``data`` is report.json."""

    data: dict
    out_dir: Path
    consistency: Consistency
    location: Location | None = None
    correction: Correction | None = None
    corrected: Model | None = None
    files: list[Path] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def mismatch_detected(self) -> bool:
        return self.data["mismatch_detected"]

    @property
    def findings(self) -> list[dict]:
        return self.data["findings"]


class _Stages:
    """One status line on a terminal: 'diagnose 12.3 s: SKI over the additive candidates'; a line
    per stage where progress is forced onto a pipe or file (SKIGEN_PROGRESS=1)."""

    def __init__(self, show: bool, stream=sys.stderr):
        self.on, self.tty = show and shown(stream), getattr(stream, "isatty", lambda: False)()
        self.stream, self.t0, self.width = stream, perf_counter(), 0
        self.log: list[tuple[str, float]] = []           # (stage, start in s)

    def _write(self, text: str, stays: bool):
        if self.tty:
            self.stream.write("\r" + text.ljust(self.width) + ("\n" if stays else ""))
            self.width = 0 if stays else len(text)
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def __call__(self, label: str):
        self.log.append((label.split(":")[0], perf_counter() - self.t0))
        if self.on:
            self._write(f"diagnose {perf_counter() - self.t0:5.1f} s: {label}", False)

    def note(self, text: str):
        """A line that stays (a warning the user should read now, not only in the report)."""
        if self.on:
            self._write(f"diagnose: {text}", True)

    def seconds(self) -> dict:
        """Seconds spent per stage (stages of the same name summed)."""
        out: dict[str, float] = {}
        for (label, t), (_, t_next) in zip(self.log, self.log[1:]):
            out[label] = out.get(label, 0.0) + t_next - t
        return {k: round(v, 2) for k, v in out.items()}

    def done(self):
        if self.on and self.width:
            self.stream.write("\n")
            self.stream.flush()


def diagnose(model, recording, out_dir, *, candidates=None, alpha: float = 0.01, folds: int = DEFAULT_FOLDS,
             validate=(), equations=None, figures: bool = True, emit: bool = True, refit: bool = True,
             show_progress: bool = True, time=None, time_unit: str = "s", columns=None,
             max_gap: float = 1.0, _judge_start=None) -> Report:
    """Diagnose ``model`` (a :class:`Model`, a model file or ``package.module:attribute``) against
    ``recording`` (a :class:`Recording`, a CSV, Parquet or ULog path, or a DataFrame); write report.json,
    report.md, figures and the corrected model into ``out_dir``.

    candidates: extra additive terms, ``(name, equation, formula)`` or ``"name:equation:formula"``,
    the formula in the model's state and input names (``"-tanh(v/0.001)"``). alpha: false-alarm
    rate of the whole decision. folds: folds of the blocked cross-validation (each DEFAULT_BLOCKS
    contiguous blocks dealt in turn). validate: further recordings, never fitted on, on which the
    nominal and corrected models are compared. equations: equations to test for a disturbance
    (default: the rate equations; kinematic identities ṗ = v are exact by definition). refit:
    refit the corrected model jointly with `skigen fit` (filter error). time, time_unit, columns,
    max_gap: how to read recordings given as paths or DataFrames (see
    :func:`skigen.recording.load_recording`).
    """
    t_start = perf_counter()
    stage = _Stages(show_progress)
    read = dict(time=time, time_unit=time_unit, columns=columns, max_gap=max_gap)
    try:
        user, spec, rec = load(model, recording, **read)
        rec, caveats = usable(rec)
        caveats = list(rec.notes) + caveats               # what reading it decided (a truncated log)
        nominal = T.copy_model(user, unknowns=False)
        check(nominal, rec, folds)
        nominal, moved = started(nominal, rec, "every filter of the diagnosis starts",
                                 "; the corrected model file declares the user's start", _judge_start)
        caveats += moved
        start_note = moved[0] if moved else None
        others = []
        for r in validate or []:
            other, more = usable(load(nominal, r, **read)[2])
            others.append(other)
            caveats += list(other.notes) + more
        user_cands = C.user_candidates(nominal, candidates) + C.declared_candidates(user)
        unknown = [e for e in equations or [] if e not in nominal.state_names]
        if unknown:
            raise DiagnosisError(f"equations {unknown} are not states of model '{nominal.name}' "
                                 f"(states: {', '.join(nominal.state_names)})")
    except (ModelError, RecordingError, DiagnosisError):
        raise
    except ValueError as exc:
        raise DiagnosisError(str(exc)) from None
    _refuse_a_diverging_step(nominal, rec)
    for line in caveats:
        stage.note(line)
    if units := unit_hints(nominal, rec):
        stage.note("; ".join(units))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    N = len(rec.t)
    cv = Folds.of(N, folds, DEFAULT_BLOCKS)

    stage("calibrating the noise")
    declared_run = ekf_run(T.constants(nominal), rec)
    declared, noise = calibrate(nominal, [rec])
    if noise.note:                              # a declared parameter on its bound, or held
        caveats.append(noise.note)
        stage.note(noise.note)
    calibrated = T.constants(declared)          # parameters at their values, for every test below
    user_noise = nominal.process_noise(), nominal.measurement_noise()     # every recalibration starts here too
    stage("testing the calibrated model")
    nominal_run = ekf_run(calibrated, rec)
    eqs = list(equations) if equations else C.rate_equations(nominal)
    verdict = judge(calibrated, rec, nominal_run, eqs, alpha)
    cons = verdict.consistency
    window = free_run_window(calibrated, rec, nominal_run)       # the nominal's: every model is compared on it
    before = evaluate_fit(calibrated, rec, run=nominal_run, window=window)
    if (t_gone := before.metrics["free_run_diverges_at"]) is not None:
        caveats.append(f"the nominal model's free run diverges at t = {t_gone:g} s (beyond {DIVERGED:g} times the "
                       f"recording's spread): its free-run errors are not compared")
        stage.note(caveats[-1])
    eps = normalised_innovations(nominal_run)
    data = {"mismatch_detected": verdict.mismatch, "notes": caveats, "noise": noise.asdict(),
            "diagnosed": {"samples": N, "start": float(rec.t[0]), "end": float(rec.t[-1])},   # s
            "consistency": dict(cons.asdict(), declared_noise=consistency(declared_run, nominal.output_names,
                                                                          alpha).asdict(),
                                disturbance_gain=verdict.gains, disturbance_threshold=verdict.threshold),
            "located": {"outputs": [], "equations": [], "windows": []}, "findings": [], "compensating": [],
            "not_identifiable": [],
            "fit": {"before": before.metrics, "after": None, "folds": None, "validation": _fit_note(folds),
                    "recordings": []},
            "remaining": {"mismatch": verdict.mismatch, "where": None}, "corrected_model": None}
    meta = dict(model=spec or user.name, recording=rec.path, samples=N, dt=nominal.dt, folds=folds,
                figures=[], kinematic=[])
    report = Report(data, out, cons)
    if units:
        data["remaining"]["units"] = units
    if not verdict.mismatch:
        if covers := noise_covers(declared, user_noise):
            data["remaining"]["noise_covers"] = covers
        data["candidates_not_named"] = [_candidate(c, "not tried: no significant mismatch to explain")
                                        for c in user_cands]
        data["fit"]["recordings"] = [_compared(calibrated, None, r, user, caveats) for r in others]
        data["validation_disagrees"] = _disagreeing(data["fit"]["recordings"], alpha)
        if figures:
            meta["figures"].append(plot_residuals(out / "residuals.png", rec.t, eps, nominal.output_names, [],
                                                  None, "normalised innovations of the calibrated nominal model"))
        return _finish(report, meta, t_start, stage)

    stage("locating the equations")
    meta["kinematic"] = [k for k in nominal.kinematic() if k not in eqs]
    loc = locate(calibrated, rec, nominal_run, cons, alpha, equations=eqs, tested=verdict.tested)
    report.location = loc
    data["located"] = loc.asdict()

    stage("naming: instantiating the catalog")
    scale = {n: float(np.sqrt(np.mean(loc.states[:, i] ** 2))) for i, n in enumerate(nominal.state_names)}
    rate_eqs = [e for e in loc.equations if e in C.rate_equations(nominal)] or C.rate_equations(nominal)
    catalog = (C.additive_candidates(calibrated, rate_eqs, scale, loc.states)
               + C.channel_candidates(calibrated, rate_eqs, scale, loc.states, np.asarray(rec.inputs)))
    additive = beyond_parameters(declared, rec, loc.states, catalog) + user_cands
    structural = (C.structural_candidates(calibrated, rate_eqs, np.asarray(rec.inputs))
                  + C.output_candidates(calibrated, loc.outputs or nominal.output_names, np.asarray(rec.outputs))
                  + C.constant_candidates(declared, rate_eqs, loc.outputs))    # the user's numbers, not
                                                                                # the parameters' calibrated values
    # the size of what is missing per equation: the slow disturbance located, or what the calibrated
    # process noise had to absorb (a fast effect a random walk cannot follow), whichever is larger
    q = np.sqrt(np.diag(calibrated.process_noise())) / (nominal.dt if nominal.discretization != "discrete" else 1)
    size = {e: max(float(np.sqrt(np.mean(loc.disturbance[e][0] ** 2))) if e in loc.disturbance else 0.0,
                   float(q[nominal.state_names.index(e)])) or loc.scales.get(e, 1.0)
            for e in {c.equation for c in additive}}
    before_naming = calibrated
    cv_before = fold_loglik(calibrated, rec, cv)      # the nominal as calibrated, as in the in-sample table
    try:
        corr, history, rms, size, calibrated = name_terms(
            calibrated, rec, cv, loc.equations, loc.states, size, additive, structural, alpha,
            progress=lambda s: stage(f"naming: {s}"),
            focus=focus_window(sum((d / np.maximum(sd, 1e-300)) ** 2 for d, sd in loc.disturbance.values())),
            parameters=C.parameter_terms(declared, rate_eqs), noise_from=user_noise,
            restartable=not start_note and _judge_start is None)
    except StartRejected as e:              # once, judged with the finding (_judge_start: model, label)
        stage.note(f"judged with {e.label}, the recording does not start at the model's initial state: "
                   "diagnosing again from a vague start")
        return diagnose(model, recording, out_dir, candidates=candidates, alpha=alpha, folds=folds, validate=validate,
                        equations=equations, figures=figures, emit=emit, refit=refit, show_progress=show_progress,
                        _judge_start=(e.model, e.label), **read)
    stage("searching the shapes")
    variants = {}
    for c in additive:
        variants.setdefault(c.group, []).append(c)
    rms.update({c: r for c, r in zip(additive, basis_rms(calibrated, rec, loc.states, additive))})
    corr, shapes = shape_search(calibrated, corr, variants, rec, rms, size)
    stage("weighing the findings (drop-one cross-validation)")
    corr, rejected = screen(calibrated, corr, loc.states, rec, alpha, shapes)
    if rejected["compensating"] or rejected["not_identifiable"]:
        corr = refit_terms(calibrated, corr, rec, rms, size)

    def noise_for(c):           # the noise a drop-one model calibrates to (weigh takes the better of it)
        return before_naming if c.empty else recalibrated(before_naming, c, rec, user_noise)
    corr, ev, cv_after = weigh(calibrated, corr, rec, cv, alpha, rms, size, noise_for)
    report.correction = corr
    meta["proposals"] = [f"round {i + 1}: best proposal {p.label} ({p.kind}), cross-validated log-likelihood "
                         f"gain {p.gain:+.1f}" + "".join(f"; {where(a)} set aside as compensating"
                                                          for a in p.set_aside)
                          + (f"; {p.note}" if p.note else "")
                          + "".join(f"; as good: {where(a)} (`{a['expression']}`), {behind(a)}" for a in p.as_good)
                          for i, p in enumerate(history)]
    stage("weighing the findings (drop-one free runs)")
    free_all, worth, free_noise = simulation_worth(calibrated, corr, rec, window)
    data["findings"] = _findings(nominal, corr, ev, shapes, worth)
    _as_good(data["findings"], history)
    data["free_run_with_all_findings"] = free_all
    _flag_one_step_only(data["findings"], free_all, free_noise)
    set_aside = [item for p in history for item in p.set_aside]
    data["compensating"] = _once(set_aside + rejected["compensating"])
    data["not_identifiable"] = rejected["not_identifiable"]
    data["candidates_not_named"] = _unnamed(user_cands, additive, data, calibrated, rec, loc.states)
    data["fit"]["folds"] = [{"spans": [list(s) for s in cv.spans(f, rec.t)], "loglik_before": float(cv_before[f]),
                             "loglik_after": float(cv_after[f])} for f in range(len(cv))]

    corrected = None
    if not corr.empty:
        stage("refitting the corrected model jointly (skigen fit)")
        # The user's parameters from their calibrated values, or, where the user declared a prior std,
        # from the user's values with that prior (the calibration's value and std came from this
        # recording, the missing physics uncorrected: as a prior they would count the data twice and
        # hold the refit at the compromise the calibration made — a fitted_model.py's Cf 76.9 ± 1.9
        # came out 69.5 ± 1.1 beside a delay found right), and the noise recalibrated while naming.
        noise = dict(Q=calibrated.process_noise(), R=calibrated.measurement_noise(), P0=declared.initial_covariance())
        base, anchored = T.copy_model(declared), T.copy_model(declared) if nominal.parameters else None
        base.set_parameters({p.name: p.value for p in nominal.parameters if p.std is not None},
                            std={p.name: p.std for p in nominal.parameters})
        for m in (base, anchored):
            if m is not None:
                m.covariances(**noise)
        joint = lambda c: refit_jointly(nominal, base, c, rec, loc.equations, refit, anchored, window, user_noise, alpha)
        corrected, names, notes, refit_info = joint(corr.without_parameters())
        for _ in range(DELAY_PASSES):        # the delay and the constants, searched in turn
            if (moved := _delays_refitted(declared, calibrated, corr, refit_info, rec, alpha, rms, size)) is corr:
                break
            stage("refitting with the delay searched again at the refitted constants")
            corr = report.correction = moved
            _redelay_findings(data["findings"], corr)
            corrected, names, notes, refit_info = joint(corr.without_parameters())
        data["refit"] = refit_info
        if "failed" in refit_info.get("note", ""):
            caveats.append(f"the joint refit: {refit_info['note'].strip()}")
        _update_findings(data["findings"], names, refit_info.get("parameters", {}), alpha)
        if unneeded := [f for f in data["findings"] if f.pop("refit_insignificant", False)]:
            stage("refitting without the findings the joint refit no longer needs")
            gone = [names[f["refit_parameter"] if f["kind"] == "structural" else f["parameter"]] for f in unneeded]
            again = joint(corr.without_parameters().without(*gone))
            if dropped := _not_needed(unneeded, gone, refit_info, again[3], alpha):
                corrected, names, notes, refit_info = again
                corr = report.correction = corr.without(*gone)
                data["findings"] = [f for f in data["findings"] if all(f is not u for u in unneeded)]
                data["not_identifiable"] += dropped
                data["refit"] = refit_info
                _update_findings(data["findings"], names, refit_info.get("parameters", {}), alpha)
        path = out / "corrected_model.py"
        head = header_lines(user.name, spec or "a model given in Python", rec.path, data["findings"])
        filed = _start_as(T.copy_model(corrected, f"{nominal.name}_corrected"), user)
        filed = report.corrected = write_model_file(path, filed, notes, header=head)
        if start_note and (rs := recorded_start(filed, rec)) is not None and rs.consistent:
            caveats[caveats.index(start_note)] += (
                "; judged with the corrected model, the recording starts at the declared state after all: "
                "the misfit at its start was what the findings explain")
        data["corrected_model"] = str(path)
        if emit:
            stage("emitting the corrected filter's C")
            meta["generated"] = [str(p) for p in emit_filter(filed, out / "generated")]
        corrected = _start_as(filed, nominal)                 # this recording's start, as every model above
        if not start_note:                    # the nominal's misfit hid a start the corrected model rejects
            corrected, moved = started(corrected, rec, "the fits of both models start",
                                       " (judged with the corrected model: the nominal's misfit had hidden it)")
            if moved:
                caveats += moved
                before = evaluate_fit(_start_as(before_naming, corrected), rec, window=window)
                data["fit"]["before"] = before.metrics
        stage("fit of the corrected model")
        after = evaluate_fit(corrected, rec, window=window)
        data["fit"]["after"] = after.metrics
        if worse := _worse(before.metrics, after.metrics):
            caveats.append(f"the corrected model free-runs worse than the nominal on {worse}: its findings improve "
                           "the one-step predictions, not the simulation; weigh them with care")
        w, regime = windows_where_it_acts(calibrated, after, rec, loc.equations, loc.states)
        if w:                                   # else the disturbance's (a delay whose rates were not compared)
            data["located"].update(windows=[[float(a), float(b)] for a, b in w], regime=regime or loc.regime,
                                   windows_from="where the found terms add at least 20 % of their 99th-percentile "
                                                "rate (along the corrected model's filtered trajectory)")
            loc.windows, loc.regime = w, regime or loc.regime
        else:
            data["located"]["windows_from"] = ("where the random-walk disturbance was significant (the found terms "
                                               "change no located rate measurably)")
        stage("testing what remains")
        data["remaining"] = remaining(T.constants(corrected), rec, after.run, eqs, alpha, out if figures else None,
                                      set(nominal.state_names + nominal.input_names), additive)
        if not data["remaining"]["mismatch"] and (covers := noise_covers(filed, user_noise)):
            data["remaining"]["noise_covers"] = covers
        if data["remaining"].get("figure"):
            meta["figures"].append(Path(data["remaining"].pop("figure")))
    else:
        after = None
        data["remaining"] = {"mismatch": True, "where": {"equations": loc.equations, "windows": data["located"]["windows"],
                                                          "regime": loc.regime},
                             "note": "no candidate explains the mismatch: it remains as detected"}
        if loc.equations and loc.equations[0] in loc.disturbance:     # what it follows: a candidate to try
            changed = functools.cache(lambda: relation_break(before_naming, rec, nominal_run, alpha))
            data["remaining"].update(explain(before_naming, rec, loc, out if figures else None, tried=additive,
                                             confirm=changed))
            data["remaining"].update(unexplained(data["remaining"], before_naming, rec, nominal_run, alpha, changed))
            if data["remaining"].get("figure"):
                meta["figures"].append(Path(data["remaining"].pop("figure")))
    _gain_ratios(nominal, data["findings"])
    if (at := data["remaining"].get("changes_at")) is not None and data["findings"]:
        back = data["remaining"].get("changes_back")
        when = f"at t = {at:.4g} s" + (f" and back at {back:.4g} s" if back is not None else "")
        caveats.append(f"the system changed {when} (what remains): the findings fit one model to the "
                       f"stretches before and after it, and may stand for the change rather than for missing "
                       f"physics; diagnose the stretches apart")
        for f in data["findings"]:
            _note(f, f"fitted across a change {when}: see the notes")
    if drifting(data["remaining"]) and data["findings"]:
        caveats.append("what remains drifts over time: the findings fit one model to a recording whose system or "
                       "sensors drift, and may stand for the drift rather than for missing physics")
        for f in data["findings"]:
            _note(f, "fitted across a drift in time: see the notes")
    if data["remaining"].get("mismatch") and (hint := _integration_hint(nominal)):
        data["remaining"]["integration"] = hint
    if units:
        data["remaining"]["units"] = units
    data["fit"]["recordings"] = [_compared(calibrated, corrected, r, user, caveats) for r in others]
    data["validation_disagrees"] = _disagreeing(data["fit"]["recordings"], alpha)
    for r, v in zip(others, data["fit"]["recordings"]):
        if v["after"] and (worse := _worse(v["before"], v["after"])):
            caveats.append(f"on the validation recording {r.path} the corrected model free-runs worse than the "
                           f"nominal ({worse}): it does not carry over to that recording; weigh the findings with care")
    if figures:
        stage("figures")
        meta["figures"] = diagnosis_figures(out, calibrated, rec, eps, loc, before, after, None) + meta["figures"]
    return _finish(report, meta, t_start, stage)


def _candidate(c, why: str) -> dict:
    return {"name": c.effect, "equation": c.equation, "formula": c.formula, "why": why}


def _unnamed(user_cands, additive, data: dict, model: Model, rec, states) -> list[dict]:
    """What became of each user (or declared) candidate that is not a finding nor listed as
    compensating or not identifiable: a restated catalog term, or not kept by the naming rounds."""
    from .name import restated, unfit_slope
    listed = {(f["effect"], f["equation"], f.get("through", "")) for key in ("findings", "compensating",
                                                                            "not_identifiable") for f in data[key]}
    unlisted = [i for i, c in enumerate(additive) if c in user_cands and c.key not in listed]
    same = restated(model, rec, states, additive) if unlisted else {}
    out = []
    for i in unlisted:
        c, twin = additive[i], additive[same[i]] if i in same else None
        whose = "" if twin is None else (f"your candidate {twin.effect}" if twin in user_cands
                                         else f"the catalog's {twin.effect}")
        out.append(_candidate(c, f"on this recording it is {whose} on {c.equation} (`{twin.text}`), judged "
                                 f"as that" if twin is not None else
                              f"not named: {why}" if (why := unfit_slope(model, rec, states, c)) else
                              "not named: no round adopted it (a round adopts its best proposal by "
                              "cross-validated gain, SKI's selection among all additive candidates or one "
                              "structural change; report.md lists the proposals)"))
    return out


WORSE = 0.01   # a free-run RMSE larger by less than this share is as good (0.007065 → 0.007068 was "worse")


def _worse(before: dict, after: dict) -> str:
    """'y (0.1 → 0.2), …': the outputs whose free-run RMSE (in the ``free_run_rmse`` of the fit
    metrics ``after``) exceeds ``before``'s by WORSE of it and the one the model's noise gives a
    right model's free run (``free_run_noise``: within it, as under an integrator's random walk,
    which of two free runs strays less is chance), or ''."""
    b, a, noise = before["free_run_rmse"], after["free_run_rmse"], after.get("free_run_noise", {})
    return ", ".join(f"{k} ({b[k]:.4g} → {a[k]:.4g})" for k in a
                     if None not in (a[k], b.get(k)) and a[k] > (1 + WORSE) * b[k] and not a[k] <= (noise.get(k) or 0.0))


def started(model: Model, rec, who: str, then: str = "", judge=None) -> tuple[Model, list[str]]:
    """``model``, or where ``rec`` rejects its declared start (:func:`skigen.start.recorded_start`)
    a copy starting from the vague prior (:attr:`~skigen.start.RecordedStart.vague_mean`, DIFFUSE
    times the declared std), with a note saying how ``who`` starts, and ``then``. judge: (model,
    label) that judges the start instead (its first states those of ``model``)."""
    rs = recorded_start(judge[0] if judge else model, rec)
    if rs is None or rs.consistent:
        return model, []
    if judge:
        then = f" (judged with {judge[1]}: the nominal's misfit had hidden it)" + then
    vague = T.copy_model(model)
    vague.x0 = [float(v) for v in rs.vague_mean[:len(model.x0)]]
    vague.x_std = [DIFFUSE * s for s in model.x_std]
    vague.P0 = None if model.P0 is None else DIFFUSE ** 2 * model.P0
    return vague, [rs.note(rec.path, rs.starting(who) + then)]


def _start_as(model: Model, like: Model) -> Model:
    """A copy of ``model`` whose first states (those of ``like``) start as ``like``'s: mean and spread."""
    m, n = T.copy_model(model), len(like.x0)
    m.x0[:n], m.x_std[:n] = like.x0, like.x_std
    if m.P0 is not None or like.P0 is not None:
        P = m.initial_covariance().copy()
        P[:n, :n] = like.initial_covariance()
        m.P0 = P
    return m


def _compared(nominal: Model, corrected: Model | None, rec, user: Model, notes: list[str]) -> dict:
    """A held-out recording's statistics, nominal and corrected, on the nominal's free-run window;
    both started from ``user``'s declared start, or from the vague prior where the recording
    rejects it (:func:`started`, noted in ``notes``)."""
    nominal, moved = started(_start_as(nominal, user), rec, "both models start")
    notes += moved
    if corrected is not None:
        corrected = _start_as(corrected, nominal)
    before = evaluate_fit(nominal, rec)
    return {"before": before.metrics,
            "after": evaluate_fit(corrected, rec, window=before.window).metrics if corrected is not None else None}


DELAY_PASSES = 4     # delay, then constants, in turn: at most this many times
NOISE_COVERS = 100.0  # × a declared variance: a model consistent only with more says so (as skigen fit's note)


def noise_covers(model: Model, declared: tuple) -> list[str]:
    """The noises of ``model`` over NOISE_COVERS times their declared variance (``declared``: Q, R):
    a verdict of consistency that needs them rests on that noise. (A battery cell with a
    hysteresis voltage no candidate has was 'consistent' with the process noise on its state of
    charge at 4.6·10⁵ times its declared variance, said nowhere.)"""
    out = []
    for kind, names, mine, theirs in (("process noise on", model.state_names, model.process_noise(), declared[0]),
                                      ("sensor noise on", model.output_names, model.measurement_noise(), declared[1])):
        for name, a, b in zip(names, np.diag(mine), np.diag(theirs)):
            if b > 0 and a > NOISE_COVERS * b:
                out.append(f"the {kind} {name} at {a / b:.3g}× its declared variance (std {np.sqrt(a / b):.3g}×)")
    return out


def _delays_refitted(declared: Model, calibrated: Model, corr: Correction, refit_info: dict, rec, alpha: float,
                     rms: dict, size: dict) -> Correction:
    """``corr`` with its delays searched again at the declared parameters' refitted values (``corr``
    itself when none is declared, none moved, or there is no delay). A delay is searched while the
    parameters sit at the calibration's compromise, and the joint refit does not move it: a motor's
    delay of 3 samples beside its damping and gain declared from another fit came out 2.83, the
    refitted constants then 6–10σ off."""
    fitted = refit_info.get("parameters", {})
    values = {p.name: fitted[p.name]["value"] for p in declared.parameters if p.name in fitted}
    if not values or not any(s.effect in DELAYS for s, *_ in corr.structural):
        return corr
    at = T.constants(T.copy_model(declared).set_parameters(values))
    at.covariances(Q=calibrated.process_noise(), R=calibrated.measurement_noise(), P0=at.initial_covariance())
    plain = corr.without_parameters()
    again = redelayed(at, plain, [s for s, *_ in plain.structural], rec, alpha, rms, size)
    return corr if again is plain else Correction([a for a in corr.additive if a[0].parameter] + again.additive,
                                                  again.structural)


def _redelay_findings(findings: list[dict], corr: Correction) -> None:
    """The delay findings as ``corr`` now has them (effect, value, expression)."""
    delays = [(s, v, sd) for s, v, sd in corr.structural if s.effect in DELAYS]
    for f in findings:
        if f.get("kind") == "structural" and f["effect"] in DELAYS:
            s, v, sd = next((d for d in delays if d[0].input == f.get("input")), (None, None, None))
            if s is not None:
                f.update(effect=s.effect, coefficient=v, std=sd, expression=s.describe(v), reading=s.reading)


def _disagreeing(compared: list[dict], alpha: float) -> list[str]:
    """A sentence per held-out recording the final model (corrected, else nominal) does not explain:
    its summed NIS above the 1 − α quantile of χ² with one degree per reading (the diagnosed
    recording's verdict says nothing of another: a clean recording diagnosed, a Coulomb friction
    in the validation one at mean NIS 126, and the headline read 'no mismatch')."""
    out = []
    for c in compared:
        m, which = (c["after"], "corrected") if c["after"] else (c["before"], "nominal")
        bound = stats.chi2.isf(alpha, m["nis_dof"]) if m["nis_dof"] else np.inf
        if m["nis_sum"] > bound:
            out.append(f"{m['recording']}: the {which} model does not explain it (mean NIS "
                       f"{m['nis_sum'] / m['nis_dof']:.3g} per reading, above the χ² bound "
                       f"{bound / m['nis_dof']:.3g}: a mismatch there, or noise other than this recording's)")
    return out


def windows_where_it_acts(nominal: Model, after, rec, equations, states) -> tuple[list, str | None]:
    """Windows and regime where the correction matters: the corrected minus nominal rate of the
    located equations, or output expression (a clipped sensor), beyond 20 % of its 99th percentile."""
    from .figures import identified_output, identified_rate
    from .locate import features, regime_stump, windows_of
    active = np.zeros(len(rec.t), bool)
    changes = [identified_rate(nominal, after, rec, eq) for eq in equations]
    changes += [identified_output(nominal, after, rec, y) for y in nominal.output_names]
    for r in map(np.abs, changes):
        if np.isfinite(r).all() and r.max() > 0:
            active |= r > 0.2 * np.percentile(r, 99)
    return windows_of(rec.t, active, nominal.dt), regime_stump(features(nominal, rec, states), active)


def _update_findings(findings: list[dict], names: dict, fitted: dict, alpha: float) -> None:
    """The refitted values in the findings (the cross-validated search's kept as cv_coefficient and
    cv_std from the first refit on); the std keeps the shape search's share. A finding whose
    refitted coefficient is no longer significant is marked."""
    by_target = {(c.effect, c.target, c.side): (n, c) for n, c in names.items() if isinstance(c, C.Structural)}
    by_term = {c.key + (c.text,): n for n, c in names.items() if c is not None and not isinstance(c, C.Structural)}
    for f in findings:
        if f["kind"] == "structural":
            n, s = by_target.get((f["effect"], f.get("output") or f.get("input"), f.get("side", "")), (None, None))
            if n in fitted:
                f.setdefault("cv_coefficient", f["coefficient"]), f.setdefault("cv_std", f["std"])
                f["coefficient"], f["std"] = fitted[n]["value"], fitted[n]["std"]
                f["expression"], f["refit_parameter"] = s.describe(f["coefficient"]), n
                if s.parameter in f.get("shape", {}):          # one value in the row, the refitted one
                    f["shape"][s.parameter] = f["coefficient"]
                no_effect = NO_EFFECT.get(s.effect)
                if no_effect is not None and f["std"] and not significant(f["coefficient"] - no_effect, f["std"], alpha):
                    f["refit_insignificant"] = True             # a sensor's gain of 1, offset of 0: no change
            continue
        n = by_term.get((f["effect"], f["equation"], f.get("through", ""), f["expression"]))
        if n not in fitted:
            continue
        spread = f.get("shape_search", {}).get("coefficient_std_from_shape", 0.0)
        f.setdefault("cv_coefficient", f["coefficient"]), f.setdefault("cv_std", f["std"])
        f["coefficient"] = fitted[n]["value"]
        std = fitted[n]["std"]
        f["std"] = float(np.hypot(std, spread)) if std is not None and np.isfinite(std) else std
        f["parameter"] = n
        if std is not None and not significant(f["coefficient"], std, alpha):   # needed at all, in its shape
            f["refit_insignificant"] = True


def _not_needed(unneeded: list[dict], terms: list, full: dict, fewer: dict, alpha: float) -> list[dict]:
    """The findings ``unneeded`` (each within the z of ``alpha`` std of zero after the joint refit
    ``full``; ``terms`` their candidates) as not-identifiable items, when the refit without them, ``fewer``, is not significantly
    less likely (2·Δ log-likelihood below the χ² quantile 1 − α for as many coefficients); else []
    (each then keeps a note)."""
    drop = full.get("loglik", np.nan) - fewer.get("loglik", np.nan)
    z = stats.norm.isf(alpha / 2)
    if not 2 * drop < stats.chi2.ppf(1 - alpha, len(unneeded)):
        for f in unneeded:
            _note(f, f"after the joint refit its coefficient is within {z:.2f} std of {_no_effect(f)} (cross-validated: "
                     f"{f['cv_coefficient']:.4g} ± {f['cv_std']:.2g}), but the refit without it is "
                     + (f"{drop:.1f} less likely" if np.isfinite(drop) else "not comparable"))
        return []
    return [_item(c, f, f"not needed: after the joint refit its coefficient is within {z:.2f} std of "
                        f"{_no_effect(f)} (cross-validated before it: {f['cv_coefficient']:.4g} ± {f['cv_std']:.2g}) "
                        f"and the refit without it is as likely ({-drop:+.1f} log-likelihood): the refitted "
                        f"constants take over what it explained; {_kept_as(f, fewer)}") for f, c in zip(unneeded, terms)]


NO_EFFECT = {"sensor_gain": 1.0, "sensor_offset": 0.0, "constant": 1.0}   # a structural value that changes nothing


def _no_effect(f: dict) -> str:
    """The value at which a finding changes nothing: zero, or a sensor gain's 1."""
    return "1" if f.get("kind") == "structural" and NO_EFFECT.get(f["effect"]) == 1.0 else "zero"   # a factor


def _item(c, f: dict, note: str) -> dict:
    """A finding as a report item that is not one (an additive term's, or a structural change's)."""
    if isinstance(c, C.Structural):
        return {"effect": c.effect, "equation": f["equation"], "expression": f["expression"],
                "coefficient": f["coefficient"], "std": f["std"], "note": note} | (
                    {"output": c.output} if c.output else {"input": c.input})
    return term_item(c, f["coefficient"], f["std"], note)


def _kept_as(finding: dict, refit: dict) -> str:
    """Where a finding not needed went: out of the corrected model, or, where that refit corrects
    the nominal's own term of the same kind (a lifted correction), into that correction."""
    effect, eq = finding["effect"], finding["equation"]
    own = next((d for d in refit.get("lifted", []) if (d["effect"], d["equation"]) == (effect, eq)), None)
    if own is None:
        return "left out of the corrected model"
    name = own["parameter"]
    p = refit.get("parameters", {}).get(name)
    value = f" ({name} = {p['value']:.4g} ± {p['std']:.2g})" if p else ""
    return (f"not a finding: the corrected model refits the nominal's own {effect.replace('_', ' ')} on "
            f"{eq} instead{value}")


def _flag_one_step_only(findings: list[dict], free_all: float, noise: float = 0.0) -> None:
    """A finding without which the corrected model simulates the recording better gets a note:
    it earns its evidence one step ahead, and a simulation is better off without it — where the
    free run with it is beyond what the model's own noise gives a right model's (``noise``, as
    :func:`_worse`): within it, which of two free runs strays less is chance (a gyro's true bias
    drew the note, 0.38 against 0.33 under a noise-alone 0.5)."""
    for f in findings:
        if f["free_run_without"] < free_all and not free_all <= noise:
            _note(f, f"the free run is better without it ({f['free_run_without']:.3g} of the output's spread, "
                     f"{free_all:.3g} with it): it helps the one-step prediction, not a simulation")


def _once(items: list[dict]) -> list[dict]:
    """Report items one per term (effect, equation, through), the last said of each, in the order
    first said: a tank's anti-drag set aside in two rounds was listed, and printed, twice."""
    return list({(a["effect"], a["equation"], a.get("through", "")): a for a in items}.values())


RATIO_EFFECTS = ("input_gain", "viscous_damping", "linear_stiffness")   # linear in one signal: said as a ratio


def _gain_ratios(nominal: Model, findings: list[dict]) -> None:
    """A linear finding said as a ratio to the declared dependence it corrects, beside the term
    added: where the term is k·s for one state or input s and the declared rate's (a discrete
    model's next value's) derivative b in s is a nonzero constant, (b + c·k)/b; on an input's own
    terms, 1 + the coefficient (an elevator at 80 %: "input_gain on q: de, 2.42" left the user to
    work out −12 → −9.58). A ratio below zero by 2 std says the sign is the other way (a rudder
    logged with the opposite sign read "× −0.995 as strongly", a damping declared +0.5 "0.997").
    A term added through an input is not a ratio of the equation's own dependence: not said."""
    discrete = nominal.discretization == "discrete"
    scale, per = (nominal.dt, " per step") if discrete else (1.0, "")
    for f in findings:
        own = 0.0
        if f["effect"] not in RATIO_EFFECTS or f.get("kind") != "additive" or f.get("through"):
            continue
        if f["effect"] == "input_gain" and f["expression"] not in nominal.input_names:
            ratio, std, name, said = 1 + f["coefficient"], f["std"], None, "its terms scaled"
        elif (linear := _linear_in_one(nominal, f["expression"])) is None:
            continue
        else:
            name, k = linear
            d = ca.jacobian(nominal.rhs[f["equation"]], T.symbols(nominal)[name])
            own = float(discrete and name == f["equation"])      # x[k+1] = x[k] + dt·(rate): the identity is no rate
            if not d.is_constant() or not (b := (float(ca.evalf(d)) - own) / scale):
                continue
            ratio, std = (b + f["coefficient"] * k) / b, f["std"] * abs(k / b)
            said = f"{b * scale + own:.4g} → {(b + f['coefficient'] * k) * scale + own:.4g}{per} per unit of {name}"
        f["ratio"], f["ratio_std"] = ratio, std
        what = ("the input acts" if f["effect"] == "input_gain" else
                f"{f['equation']}'s {'rate' if not discrete else 'change per step' if own else 'next value'} "
                f"follows {name}")
        flipped = (f": the other sign; check the sign convention of {name or 'the input'} in the model and the "
                   f"recording") if ratio + 2 * std < 0 else ""
        _note(f, f"{what} × {ratio:.4g} ± {std:.2g} as strongly as declared ({said}){flipped}")


def _linear_in_one(nominal: Model, expression: str) -> tuple[str, float] | None:
    """(name, k) where ``expression`` is k·s for one state or input s and a constant k; else None."""
    phi = T.formula(nominal, expression)
    names = [n for n, v in T.symbols(nominal).items() if ca.depends_on(phi, v)]
    if len(names) != 1:
        return None
    s = T.symbols(nominal)[names[0]]
    k = ca.jacobian(phi, s)
    if not k.is_constant() or not ca.is_equal(ca.simplify(phi - k * s), ca.SX(0), 3):
        return None
    return names[0], float(ca.evalf(k))


def _note(finding: dict, text: str) -> None:
    finding["note"] = "; ".join(filter(None, [finding.get("note"), text]))


def _integration_hint(nominal: Model) -> str | None:
    """Where a mismatch remains, whether the integration step itself may be it: more than 1 % error
    per step on the fastest damped mode."""
    e = nominal.step_error()
    if e is None or e[0] < 0.01:
        return None
    err, lam, n = e
    return (f"the {nominal.discretization} step of {nominal.dt / nominal.substeps:g} s misses the mode of "
            f"eigenvalue {_complex(lam)} /s by {f'{100 * err:.3g} %' if err < 1 else 'more than 100 %'} per step: the mismatch may be the integration's; "
            f"try substeps={n} (below 0.1 %)")


CONVERSIONS = {180 / np.pi: "degrees where the model declares radians", np.pi / 180: "radians where the model declares degrees",
               1e3: "a unit 1000× smaller (mm for m, mV for V)", 1e-3: "a unit 1000× larger (m for mm, kV for V)",
               1e2: "a unit 100× smaller (cm for m, % for a fraction)", 1e-2: "a unit 100× larger (a fraction for %)",
               3.6: "km/h where the model declares m/s", 1 / 3.6: "m/s where the model declares km/h",
               1 / 0.3048: "feet where the model declares metres", 0.3048: "metres where the model declares feet",
               30 / np.pi: "rpm where the model declares rad/s", np.pi / 30: "rad/s where the model declares rpm"}


def unit_hints(nominal: Model, rec) -> list[str]:
    """Outputs whose recording is the nominal free run times a unit conversion (within 3 %, the scaled
    free run explaining at least 90 % of what the unscaled one leaves and of the recording's own
    variance, offsets allowed): a log in degrees against a model in radians, say. Hints only: the
    diagnosis goes on. (A closed loop's free run that drifts 86 m off a 3 m climb is matched by some
    small scale, 0.0098 once, and was taken for a unit 100× larger.)"""
    with np.errstate(all="ignore"):        # a free run that escapes to overflow is no scaled copy
        _, Y = free_run(T.constants(nominal), rec.inputs)
        return [hint for j in range(len(nominal.output_names))
                if (hint := _unit_hint(nominal, j, np.asarray(rec.outputs)[:, j], Y[:, j]))]


def _unit_hint(nominal: Model, j: int, y: np.ndarray, yhat: np.ndarray) -> str | None:
    ok = np.isfinite(y) & np.isfinite(yhat)
    if ok.sum() < 10 or np.std(yhat[ok]) == 0:
        return None
    y, yhat = y[ok] - y[ok].mean(), yhat[ok] - yhat[ok].mean()
    a = float(yhat @ y / (yhat @ yhat))
    unscaled, scaled = np.mean((y - yhat) ** 2), np.mean((y - a * yhat) ** 2)
    factor = min(CONVERSIONS, key=lambda f: abs(np.log(a / f)) if a > 0 else np.inf)
    if not (a > 0 and abs(np.log(a / factor)) < 0.03 and scaled < 0.1 * min(unscaled, np.mean(y ** 2))):
        return None
    out = nominal.outputs[j]
    return (f"output '{out.name}'{f' [{out.unit}]' if out.unit else ''} is {a:.4g}× the nominal free run: "
            f"is the recording in {CONVERSIONS[factor]}?")


def _refuse_a_diverging_step(nominal: Model, rec) -> None:
    """A nominal whose free run on the recording's inputs diverges because its step is too long
    for a fast mode is refused with the substeps it needs, rather than diagnosed on overflows."""
    why = nominal.unstable_step()
    if why is None:
        return
    with np.errstate(all="ignore"):
        states, _ = free_run(T.constants(nominal), rec.inputs)
        diverged = ~np.isfinite(states).all(axis=1) | (np.abs(states).max(axis=1) >= 1e150)
    if diverged.any():
        i = int(np.argmax(diverged))
        raise DiagnosisError(f"the free run of '{nominal.name}' on the recording's inputs diverges "
                             f"(t = {rec.t[i]:g} s): {why}")


def detect(model, recording, *, alpha: float = 0.01, equations=None, **read) -> dict:
    """The first two steps alone — calibrate the noise, then judge — for a quick verdict:
    {"mismatch_detected", "noise", "consistency"} as in report.json."""
    user, _, rec = load(model, recording, **read)
    nominal = T.copy_model(user, unknowns=False)
    declared, noise = calibrate(nominal, [rec])
    calibrated = T.constants(declared)
    run = ekf_run(calibrated, rec)
    v = judge(calibrated, rec, run, list(equations) if equations else C.rate_equations(nominal), alpha)
    return {"mismatch_detected": v.mismatch, "noise": noise.asdict(),
            "consistency": dict(v.consistency.asdict(), disturbance_gain=v.gains, disturbance_threshold=v.threshold)}


def _fit_note(folds: int) -> str:
    return (f"blocked cross-validation over {folds} folds, each {DEFAULT_BLOCKS} contiguous blocks dealt in turn "
            f"(fewer in a short recording): each fold is scored with coefficients "
            f"fitted on the other folds (fit.folds); fit.before and fit.after are the whole recording, "
            f"the corrected model fitted on all of it; fit.recordings are the --validate recordings, "
            f"never fitted on, both models there with the noise calibrated on this recording")


def _findings(nominal: Model, corr: Correction, ev: dict, shapes: dict, worth: dict) -> list[dict]:
    """The findings, most needed by a simulation first (the free run without it worst), then by evidence."""
    out = []
    for c, coef, std in corr.found:
        f = {"effect": c.effect, "equation": c.equation, "expression": c.text, "coefficient": coef, "std": std, "evidence": ev[c], "free_run_without": worth[c], "kind": "additive",
             "reading": c.reading + (f" ({c.variant})" if c.variant else "")}
        if c.through:
            f["through"] = c.through
        if c.effect in UNITLESS_BASIS and (unit := _rate_unit(nominal, c.equation)):
            f["unit"] = unit
        if c.shape:
            f["shape"] = dict(c.shape)
        if c in shapes:
            f["shape_search"] = shapes[c]
        out.append(f)
    for s, value, std in corr.structural:
        f = {"effect": s.effect, "equation": "+".join(_acted_on(nominal, s)), "expression": s.describe(value),
             "coefficient": value, "std": std, "evidence": ev[s], "free_run_without": worth[s], "kind": "structural",
             "parameter": s.parameter, "unit": s.unit, "reading": s.reading}
        f.update({"output": s.output, "shape": {s.parameter: value, **({"side": s.side} if s.side else {}),
                                                "output": s.output}}
                 if s.output else {"input": s.input})
        if s.output and (reads := _reads(nominal, s.output)):
            f["reads"] = reads
        if s.side:
            f["side"] = s.side
        if s.effect == "constant":
            f["written_in"] = list(s.equations)
        out.append(f)
    return sorted(out, key=lambda f: (-f["free_run_without"], -f["evidence"]))


UNITLESS_BASIS = ("bias", "coulomb_friction")     # a term whose coefficient is in its rate's unit


def _rate_unit(nominal: Model, eq: str) -> str:
    """The unit of ``eq``'s rate, its state's per second, "rad/s" → "rad/s²" (a Coulomb friction's
    0.99 on a load's rate was read as a torque, in N·m); a discrete model's term is a rate too,
    added times dt (:func:`transform.rate`)."""
    unit = next(v.unit for v in nominal.states if v.name == eq)
    if not unit:
        return unit
    return unit[:-2] + "/s²" if unit.endswith("/s") else f"{unit}/s"


def _as_good(findings: list[dict], history) -> None:
    """Each finding that a naming round adopted over a finalist explaining the recording as well
    (cross-validated log-likelihood within what a finding must add) lists it under ``as_good``: the
    recording cannot tell them apart (a constant force on a linear spring and an offset of its
    position sensor). A tie that acts as another finding does is that finding, not a tie (a heater's
    saturation at 90.3 W was said not told apart from the finding beside it, a saturation at 92.8)."""
    found = {acts(f) for f in findings}
    for p in history:
        adopted = {acts(a) for a in p.adopted}
        for f in findings:
            if p.as_good and acts(f) in adopted:          # a tie said of the finding it would replace,
                ties = [a for a in p.as_good if ("instead_of" not in a or list(acts(f)) in a["instead_of"])
                        and (a["effect"], a["expression"]) != (f["effect"], f["expression"])   # not itself
                        and acts(a) not in found - {acts(f)}]
                if ties:
                    f["as_good"] = ties


def _reads(nominal: Model, output: str) -> str | None:
    """What an output reads, where it is not a state alone (a current (u − k·ω)/R): its formula."""
    expr = ca.SX(next(v.sym for v in nominal.outputs if v.name == output))
    if expr.is_symbolic():
        return None
    return str(expr)


def _acted_on(nominal: Model, s) -> list[str]:
    """The equations a structural change acts through: those its input drives, or, for a sensor,
    the states its output reads."""
    if s.output:
        expr = next(v.sym for v in nominal.outputs if v.name == s.output)
        return [v.name for v in nominal.states if ca.depends_on(expr, v.sym)]
    if s.equations:                                    # a constant: where it is written
        return [e for e in s.equations if e in nominal.state_names]
    return [e for e in nominal.state_names
            if any(v.name == s.input and ca.depends_on(nominal.rhs[e], v.sym) for v in nominal.inputs)]


def _finish(report: Report, meta: dict, t_start: float, stage) -> Report:
    stage("report")
    report.seconds = perf_counter() - t_start
    meta["seconds"] = report.seconds
    report.data["seconds_per_stage"] = stage.seconds()
    out = report.out_dir
    report.files = [write_json(out / "report.json", report.data),
                    write_markdown(out / "report.md", report.data, meta)] + list(meta["figures"])
    if report.data["corrected_model"]:
        report.files.append(Path(report.data["corrected_model"]))
    stage.done()
    return report
