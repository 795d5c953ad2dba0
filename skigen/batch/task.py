"""One log, on a Dask worker: read it, run the filter (or fit, or diagnose), write its outputs.

:func:`run_log` is the task :func:`skigen.batch.batch` submits, one per log. It takes
plain arguments (the model spec, the log's path, the output folder, options), reloads
the model in the worker (cached per worker process) and never raises for a bad log:
it returns the log's summary row with status ``ok``, ``diverged`` or ``failed`` and
the one-line message. Outputs are written to a hidden temporary folder renamed to
``DIR/<log>/`` at the end; ``DIR/<log>/done.json`` (the row) marks a complete log.
"""
from __future__ import annotations

import hashlib
import importlib.util
import json
import math
import os
import shutil
import time
import traceback
import uuid
from pathlib import Path

import numpy as np

from ..modelfile import is_module_spec
from ..sources import printable

__all__ = ["run_log", "MARKER", "model_digest", "log_digest"]

MARKER = "done.json"
_MODELS: dict = {}      # per worker process: (spec, digest) -> Model
_FILTERS: dict = {}     # (spec, digest, kind, estimate) -> DerivedFilter (its step Function built once)


def _spec_file(spec: str) -> Path | None:
    if is_module_spec(spec):
        found = importlib.util.find_spec(spec.split(":", 1)[0])
        return Path(found.origin) if found and found.origin and Path(found.origin).is_file() else None
    return Path(spec) if Path(spec).is_file() else None


def model_digest(spec: str, model) -> str:
    """Hash of the model file's text (or of the spec, for a module not found as a file) and of what
    ``model``, loaded from it, declares — its transition and observation to the bit, noises,
    priors, initial state, parameters — so that a constant changed in a module the file imports
    counts too."""
    import casadi as ca

    from ..derive.augment import augment
    path = _spec_file(spec)
    digest = hashlib.sha256(path.read_bytes() if path else spec.encode())
    a = augment(model)
    digest.update(ca.Function("model", [a.z, a.u, a.mem], [a.f, a.h, a.mem_next]).serialize().encode())
    for v in (a.Q, a.R, a.P0, a.z0, a.s0, a.fixed_values):
        digest.update(np.ascontiguousarray(v, float).tobytes())
    digest.update(json.dumps([model.name, model.dt, a.names, [(p.name, p.value, p.std, list(p.bounds))
                                                              for p in model.parameters]]).encode())
    return digest.hexdigest()[:16]


def log_digest(path) -> str:
    """Size and modification time of a log: a changed log is done again ('missing': a log gone, or a
    link to nothing, whose row then fails naming it)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return "missing"
    return f"{st.st_size}-{st.st_mtime_ns}"


def _model(spec: str, digest: str):
    from ..modelfile import load_model
    key = (spec, digest)
    if key not in _MODELS:
        _MODELS[key] = load_model(spec)
    return _MODELS[key]


def _filter(spec: str, digest: str, kind: str, estimate: tuple):
    from ..derive import derive
    key = (spec, digest, kind, estimate)
    if key not in _FILTERS:
        _FILTERS[key] = derive(_model(spec, digest), kind, estimate=estimate)
    return _FILTERS[key]


def quantity_names(filt, track=()) -> list[str]:
    """What a run's summary row reports: the tracked states, the weights, the estimated parameters."""
    aug = filt.aug
    names = list(track) + [aug.names[i] for i in aug.w_index] + list(aug.estimated)
    return list(dict.fromkeys(names))


def _num(x):
    x = float(x)
    return x if math.isfinite(x) else None


def _run(spec, digest, path, tmp: Path, opt: dict, row: dict) -> None:
    from ..fit import unit_notes
    from ..recording import TableWriter, load_recording
    from ..runtime import RunSummary, iter_run
    model = _model(spec, digest)
    filt = _filter(spec, digest, opt["filter"], tuple(opt["estimate"]))
    rec = load_recording(path, model, real=opt["real"], **opt["read"])
    row.update(samples=len(rec.t), duration_s=_num(rec.t[-1] - rec.t[0]), start=_num(rec.t[0]))
    summary = RunSummary(filt)
    with TableWriter(tmp / "result.csv") as out:
        for part in iter_run(filt, rec, backend=opt["backend"], real=opt["real"], show_progress=False,
                             cache_dir=opt["build"]):
            out.write(part.columns())
            summary.add(part)
    try:                                      # a log in km/h under a noise declared large runs 'conservative'
        units = unit_notes(model, [rec])
    except (ArithmeticError, RuntimeError, ValueError):     # a hint: its own failure fails no log's run
        units = []
    lines = list(rec.notes) + units + summary.lines()
    (tmp / "summary.txt").write_text("\n".join(lines) + "\n")
    row["notes"] = list(rec.notes) + units + summary.attention()
    names = filt.aug.names
    if summary.last is not None:
        mean, std = summary.last[0], summary.last[1]
        row["quantities"] = {q: [_num(mean[names.index(q)]), _num(std[names.index(q)])]
                             for q in quantity_names(filt, opt["track"])}
    if summary.nis_count:
        row["mean_nis"] = summary.nis_sum / summary.nis_count
        row["nis_expected"] = summary.expected_sum / summary.nis_count
        row["verdict"] = summary.verdict().partition(":")[0]
    else:            # the estimates are their priors: not a result to compare across the fleet
        row["verdict"] = "no reading used" if summary.present else "no reading"
    row["holes"] = len(rec.holes)


def _fit(spec, digest, path, tmp: Path, opt: dict, row: dict) -> None:
    from ..fit import fit, rms
    from ..fit.output import write_outputs
    from ..recording import load_recording
    model = _model(spec, digest)
    rec = load_recording(path, model, **opt["read"])
    row.update(samples=len(rec.t), duration_s=_num(rec.t[-1] - rec.t[0]), start=_num(rec.t[0]))
    result = fit(model, [rec], method=opt["method"], estimate=list(opt["estimate"]) or None,
                 show_progress=False)
    write_outputs(result, tmp, model_spec=spec, figures=opt["figures"])
    row["notes"] = list(result.notes)               # its holes among them, as `skigen fit` says them
    row["holes"] = len(rec.holes)
    row["quantities"] = {n: [_num(p["value"]), _num(p["std"])]
                         for n, p in {**result.parameters, **result.weights}.items()}
    row["rmse"] = {o: rms(np.concatenate([r.outputs[:, j] - Y[:, j] for r, Y in
                                          zip(result.fitted_recordings, result.predictions)]))
                   for j, o in enumerate(model.output_names)}


def per_measured(c: dict) -> tuple:
    """(mean NIS, its expectation) per sample measured, as a run's rows give them, from a diagnosis's
    ``consistency`` (per grid sample: a log at half the model's rate read half of a run's)."""
    per = c["samples"] / c["measured_samples"] if c.get("measured_samples") else np.nan
    return _num(c["nis_mean"] * per), _num(c["nis_expected"] * per)


def _finding_key(f: dict) -> str:
    """A finding's column in the fleet summary: effect@where[@through][@side] (a sensor's lower and
    upper saturation are two columns, not one overwriting the other)."""
    at = f.get("output") or (f["input"] if f["effect"] == "constant" else f["equation"])
    return "@".join([f["effect"], at] + [f[k] for k in ("through", "side") if f.get(k)])


def _diagnose(spec, digest, path, tmp: Path, final: Path, opt: dict, row: dict) -> None:
    from ..diagnose import diagnose
    from ..diagnose.report import where
    from ..fit import UNITS
    from ..recording import load_recording
    model = _model(spec, digest)
    rec = load_recording(path, model, **opt["read"])
    row.update(samples=len(rec.t), duration_s=_num(rec.t[-1] - rec.t[0]), start=_num(rec.t[0]))
    report = diagnose(spec, rec, tmp, figures=opt["figures"], show_progress=False)
    for f in ("report.json", "report.md"):     # the report names its files: where they will be
        p = tmp / f
        if p.exists():
            p.write_text(p.read_text().replace(str(tmp), str(final)))
    d = report.data
    span = d["diagnosed"]                      # the longest stretch between input holes
    row.update(samples=span["samples"], duration_s=_num(span["end"] - span["start"]), start=_num(span["start"]))
    row["notes"] = ([f"{UNITS}: {u}" for u in d["remaining"].get("units", [])] + d["notes"]
                    + [f"consistent only with {c}" for c in d["remaining"].get("noise_covers", [])])
    row["mean_nis"], row["nis_expected"] = per_measured(d["consistency"])
    row["mismatch"] = bool(d["mismatch_detected"])
    row["remains"] = bool(d["remaining"].get("mismatch"))
    row["findings"] = [f"{where(f)} ({f['coefficient']:.4g}"
                       + (f" ± {f['std']:.2g})" if f.get("std") is not None and np.isfinite(f["std"]) else ")")
                       + "".join(f", or {where(a)} ({a['coefficient']:.4g})" for a in f.get("as_good", []))
                       for f in d["findings"]]
    row["quantities"] = {_finding_key(f): [_num(f["coefficient"]), _num(f["std"]) if f.get("std") is not None else None]
                         for f in d["findings"]}
    row["quantities"].update({name: [_num(p["calibrated"]), _num(p["std"])]    # the declared constants, calibrated
                              for name, p in d["noise"].get("parameters", {}).items()})


def _one_line(exc: BaseException) -> str:
    """The error's first line (printable, at most 300 characters); an unexpected kind of error (not a ValueError, RuntimeError or
    OSError, which name what is wrong) is prefixed by its type."""
    lines = str(exc).strip().splitlines()
    text = printable(lines[0], 300) if lines else ""
    if isinstance(exc, (ValueError, RuntimeError, OSError)) and text:
        return text
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def run_log(spec: str, path: str, out_dir: str, name: str, options: dict) -> dict:
    """Process one log; returns its summary row (never raises for a bad log).

    options: mode (run, fit, diagnose), filter, backend, real, build (C cache dir), read (the
    keyword arguments of :func:`skigen.recording.load_recording`), track, estimate, method,
    figures, digest (the model's), fingerprint (written to the marker).
    """
    t0 = time.perf_counter()
    out = Path(out_dir)
    final = out / name
    tmp = out / f".{name}.tmp-{uuid.uuid4().hex[:8]}"
    tmp.mkdir(parents=True)
    row = dict(file=str(path), log=name, status="ok", message="", samples=None, duration_s=None, start=None,
               seconds=None, mean_nis=None, nis_expected=None, verdict=None, quantities={}, findings=[], mismatch=None,
               fingerprint=options["fingerprint"])
    spec, digest, mode = options["spec"], options["digest"], options["mode"]
    from .. import runtime
    threads, runtime.THREADS = runtime.THREADS, 1      # the batch's worker processes share out the cores
    try:
        if mode == "run":
            _run(spec, digest, path, tmp, options, row)
        elif mode == "fit":
            _fit(spec, digest, path, tmp, options, row)
        elif mode == "diagnose":
            _diagnose(spec, digest, path, tmp, final, options, row)
        else:
            raise ValueError(f"unknown batch mode '{mode}'")
    except Exception as exc:   # a bad log is a row, never the end of the batch
        row.update(status="failed", message=_one_line(exc))
        (tmp / "error.txt").write_text(traceback.format_exc())
    finally:
        runtime.THREADS = threads
    row["seconds"] = time.perf_counter() - t0
    if row["status"] != "failed":
        (tmp / MARKER).write_text(json.dumps(row, indent=1, default=_json) + "\n")
    if final.exists():
        shutil.rmtree(final)
    os.replace(tmp, final)
    return row


def _json(x):
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    raise TypeError(f"cannot write {type(x).__name__} to JSON")
