"""Diagnose a model against a recording: detect, locate, name, model, show the fit improve.

    from skigen.diagnose import diagnose
    report = diagnose("models/cart.py", "flight.csv", "out/diag")
    report.mismatch_detected, report.findings, report.data      # report.json as a dict

The nominal model is the user's simulation (its declared unknown term, if
any, is left out); the recording is the truth. Steps, one module each:
:mod:`detect` (consistency of the nominal EKF), :mod:`locate` (outputs,
equations, windows, regime), :mod:`name` (catalog terms by SKI, structural
changes by likelihood), :mod:`evidence` (held-out log-likelihood per
finding), :mod:`correct` (the corrected model file and its C), :mod:`fit`
(before/after on validation), :mod:`report` and :mod:`figures`. The last
``validation`` fraction of the recording is never used to fit.
"""
from __future__ import annotations

import os
import sys
from time import perf_counter
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from ..derive import derive
from ..model import Model, ModelError
from ..recording import RecordingError
from . import catalog as C
from . import transform as T
from .correct import emit_filter, header_lines, write_model_file
from .detect import Consistency, consistency, normalised_innovations
from .errors import DiagnosisError
from .evidence import weigh
from .fastrun import run_fast
from .figures import diagnosis_figures, plot_residuals
from .fit import evaluate_fit
from .inputs import MIN_SAMPLES, check, load
from .locate import Location, locate
from .name import Correction, basis_rms, name_terms, refit
from .report import write_json, write_markdown

__all__ = ["diagnose", "Report", "DiagnosisError", "MIN_SAMPLES"]

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
    """One status line on a terminal: 'diagnose 12.3 s: SKI over the additive candidates'."""

    def __init__(self, show: bool, stream=sys.stderr):
        env = os.environ.get("SKIGEN_PROGRESS")
        tty = getattr(stream, "isatty", lambda: False)()
        self.on = show and (env == "1" or (env != "0" and tty))
        self.stream, self.t0, self.width = stream, perf_counter(), 0

    def __call__(self, label: str):
        if self.on:
            text = f"diagnose {perf_counter() - self.t0:5.1f} s: {label}"
            self.stream.write("\r" + text.ljust(self.width))
            self.stream.flush()
            self.width = len(text)

    def done(self):
        if self.on and self.width:
            self.stream.write("\n")
            self.stream.flush()


def diagnose(model, recording, out_dir, *, candidates=None, alpha: float = 0.01, validation: float = 0.3,
             horizon: float = 1.0, equations=None, figures: bool = True, emit: bool = True,
             show_progress: bool = True, time=None, time_unit: str = "s", columns=None,
             max_gap: float = 1.0) -> Report:
    """Diagnose ``model`` (a :class:`Model`, a model file or ``package.module:attribute``) against
    ``recording`` (a :class:`Recording`, a CSV, Parquet or ULog path, or a DataFrame); write report.json, report.md, figures and
    the corrected model into ``out_dir``.

    candidates: extra additive terms, ``(name, equation, formula)`` — the formula in the model's
    state and input names (``"-tanh(v/0.001)"``). alpha: false-alarm rate of the whole decision.
    validation: held-out last fraction. horizon: free-run length (s) for the fit table.
    equations: equations to test for a disturbance (default: the rate equations; kinematic
    identities ṗ = v are exact by definition). time, time_unit, columns, max_gap: how to read
    ``recording`` when it is a path or a DataFrame (see :func:`skigen.recording.load_recording`).
    """
    t_start = perf_counter()
    stage = _Stages(show_progress)
    try:
        user, spec, rec = load(model, recording, time=time, time_unit=time_unit, columns=columns,
                               max_gap=max_gap)
        nominal = T.copy_model(user, unknowns=False)
        check(nominal, rec, validation)
        user_cands = C.user_candidates(nominal, candidates) + C.declared_candidates(user)
        unknown = [e for e in equations or [] if e not in nominal.state_names]
        if unknown:
            raise DiagnosisError(f"equations {unknown} are not states of model '{nominal.name}' "
                                 f"(states: {', '.join(nominal.state_names)})")
    except (ModelError, RecordingError, DiagnosisError):
        raise
    except ValueError as exc:
        raise DiagnosisError(str(exc)) from None
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    N = len(rec.t)
    n_fit = int((1 - validation) * N)
    t_val = float(rec.t[n_fit])

    stage("nominal filter")
    nominal_run = run_fast(derive(nominal, "ekf"), rec)
    cons = consistency(nominal_run, nominal.output_names, alpha)
    before = evaluate_fit(nominal, rec, n_fit, horizon, run=nominal_run)
    eps = normalised_innovations(nominal_run)
    fit_note = (f"t = {t_val:.2f}–{rec.t[-1]:.2f} s, samples {n_fit}–{N - 1} (the last {validation:.0%}): "
                f"no coefficient or parameter is fitted on it (it ranks the candidate changes and weighs "
                f"each finding); free runs of {horizon:g} s from the filtered state, restarted every {horizon:g} s")
    data = {"mismatch_detected": cons.mismatch, "consistency": cons.asdict(),
            "located": {"outputs": [], "equations": [], "windows": []}, "findings": [],
            "fit": {"before": before.metrics, "after": None, "validation": fit_note}, "corrected_model": None}
    meta = dict(model=spec or user.name, recording=rec.path, samples=N, n_fit=n_fit, dt=nominal.dt,
                horizon=horizon, figures=[], kinematic=[])
    report = Report(data, out, cons)
    if not cons.mismatch:
        if figures:
            meta["figures"].append(plot_residuals(out / "residuals.png", rec.t, eps, nominal.output_names, [],
                                                  t_val, "normalised innovations of the nominal model"))
        return _finish(report, meta, t_start, stage)

    stage("locating the equations")
    eqs = list(equations) if equations else C.rate_equations(nominal)
    meta["kinematic"] = [k for k in C.kinematic_equations(nominal) if k not in eqs]
    loc = locate(nominal, rec, n_fit, nominal_run, cons, alpha, equations=eqs)
    report.location = loc
    data["located"] = loc.asdict()

    stage("naming: instantiating the catalog")
    scale = {n: float(np.sqrt(np.mean(loc.states[:, i] ** 2))) for i, n in enumerate(nominal.state_names)}
    rate_eqs = [e for e in loc.equations if e in C.rate_equations(nominal)] or C.rate_equations(nominal)
    additive = C.additive_candidates(nominal, rate_eqs, scale)
    additive += user_cands
    structural = C.structural_candidates(nominal, rate_eqs, np.asarray(rec.inputs))
    size = {e: float(np.sqrt(np.mean(d ** 2))) for e, (d, _) in loc.disturbance.items()}
    for c in additive:
        size.setdefault(c.equation, loc.scales.get(c.equation, 1.0))
    corr, history = name_terms(nominal, rec, n_fit, loc.equations, loc.states, size, additive, structural,
                               alpha, progress=lambda s: stage(f"naming: {s}"))
    rms = dict(zip(additive, basis_rms(nominal, rec, loc.states, additive))) if additive else {}
    stage("weighing the findings on validation data")
    corr, ev = weigh(nominal, corr, rec, n_fit, alpha,
                     lambda c: refit(nominal, c, rec.slice(0, n_fit), rms, size))
    report.correction = corr
    meta["proposals"] = [f"round {i + 1}: best proposal {p.label} ({p.kind}), validation log-likelihood "
                         f"gain {p.gain:+.1f}" for i, p in enumerate(history)]
    data["findings"] = _findings(nominal, corr, ev)

    if not corr.empty:
        stage("writing the corrected model")
        path = out / "corrected_model.py"
        head = header_lines(user.name, spec or "a model given in Python", rec.path, data["findings"])
        corrected = write_model_file(path, nominal, corr, name=f"{nominal.name}_corrected", header=head)
        report.corrected = corrected
        data["corrected_model"] = str(path)
        if emit:
            stage("emitting the corrected filter's C")
            meta["generated"] = [str(p) for p in emit_filter(corrected, out / "generated")]
        stage("validation fit")
        after = evaluate_fit(corrected, rec, n_fit, horizon)
        data["fit"]["after"] = after.metrics
    else:
        after = None
    if figures:
        stage("figures")
        meta["figures"] = diagnosis_figures(out, nominal, rec, eps, loc, before, after, t_val)
    return _finish(report, meta, t_start, stage)


def _findings(nominal: Model, corr: Correction, ev: dict) -> list[dict]:
    out = []
    for c, coef, std in corr.additive:
        out.append({"effect": c.effect, "equation": c.equation, "expression": c.formula,
                    "coefficient": coef, "std": std, "evidence": ev[c], "kind": "additive",
                    "reading": c.reading + (f" ({c.variant})" if c.variant else "")})
    for s, value, std in corr.structural:
        eqs = [e for e in nominal.state_names
               if any(v.name == s.input and ca.depends_on(nominal.rhs[e], v.sym) for v in nominal.inputs)]
        out.append({"effect": s.effect, "equation": "+".join(eqs), "expression": s.describe(value),
                    "coefficient": value, "std": std, "evidence": ev[s], "kind": "structural",
                    "parameter": s.parameter, "unit": s.unit, "input": s.input, "reading": s.reading})
    return sorted(out, key=lambda f: -f["evidence"])


def _finish(report: Report, meta: dict, t_start: float, stage) -> Report:
    stage("report")
    report.seconds = perf_counter() - t_start
    meta["seconds"] = report.seconds
    out = report.out_dir
    report.files = [write_json(out / "report.json", report.data),
                    write_markdown(out / "report.md", report.data, meta)] + list(meta["figures"])
    if report.data["corrected_model"]:
        report.files.append(Path(report.data["corrected_model"]))
    stage.done()
    return report
