"""What a fit leaves behind: fit.json, fitted_model.py, report.md and figures."""
from __future__ import annotations

import datetime
import json
import os
from pathlib import Path

import numpy as np

from ..modelfile import is_module_spec
from ..simulate import AMPLIFICATION, free_run, growth_rate, simulation_window, windowed_free_run
from . import FitError, FitResult, fit, per_output, rms, value_text

__all__ = ["validate", "write_outputs"]


def validate(result: FitResult, recordings, init_samples: int = 50, declared=None) -> list[dict]:
    """Free-run simulation RMSE of the fitted model on held-out recordings.

    The initial state of each is estimated from its first ``init_samples``
    samples (parameters fixed), then the model runs free over the whole
    recording; the RMSE counts the samples after those. As in the fit, a stuck sensor's readings
    are left out and a recording is cut at its input holes
    (:meth:`~skigen.recording.Recording.usable`), each part validated. A model without weights
    whose free run amplifies state errors more than AMPLIFICATION-fold over the
    recording (open-loop unstable) is instead restarted from its EKF's state every
    window within which it does so AMPLIFICATION-fold (``window`` in seconds, else
    None). ``declared``: the model as declared, scored the same way (``rmse_declared``: what the
    fit changed on a recording it never saw). Returns one dict per recording (or part): file,
    samples, rmse per output, window, notes (stuck readings and input holes, on the recording's
    first part), the simulated outputs and the recording (part) itself.
    """
    model = result.model
    weights = [result.weights.get(n, {}).get("value", 0.0) for n in model.weight_names]
    out = []
    for rec, notes in _validation_parts(recordings):
        if len(rec.t) <= init_samples:
            raise FitError(f"{rec.path}: {len(rec.t)} samples to validate on; the first {init_samples} "
                           f"(--init-samples) estimate its initial state and the rest are scored: give a longer "
                           f"recording or fewer initial samples")
        n0 = init_samples
        window, Y = _simulated(model, weights, rec, n0)
        e = rec.outputs[n0:] - Y[n0:]
        out.append(dict(file=str(rec.path), samples=int(len(rec.t) - n0),
                        window=window * model.dt if window else None,
                        rmse={o: rms(e[:, j]) for j, o in enumerate(model.output_names)},
                        notes=notes, simulated=Y, recording=rec))
        if declared is not None:
            e = rec.outputs[n0:] - _simulated(declared, [0.0] * len(declared.weight_names), rec, n0)[1][n0:]
            out[-1]["rmse_declared"] = {o: rms(e[:, j]) for j, o in enumerate(model.output_names)}
    return out


def _simulated(model, weights, rec, n0: int):
    """(window in samples or None, outputs): ``model``'s free run over ``rec`` from the state its
    first ``n0`` samples give, or restarted from its EKF's (:func:`_windowed`)."""
    window, Y = (None, None) if model.weight_names else _windowed(model, rec, n0)
    if Y is None:
        head = fit(model, [rec.slice(0, max(n0, 2))], estimate=[], show_progress=False) \
            if not model.weight_names else None
        x0 = [head.initial_states[0][s]["value"] for s in model.state_names] if head else model.x0
        _, Y = free_run(model, rec.inputs, x0=x0, weights=weights)
    return window, Y


def _validation_parts(recordings):
    """(part, notes) of each recording's usable parts; the notes (its reading's, then what the
    validation did) on its first part: a short input gap held in a validation log was said on
    the terminal only, not in fit.json or report.md."""
    for r in recordings:
        parts, notes = r.usable()
        notes = r.said() + notes
        if r.input_holes:
            notes = notes + [r.hole_note(f"validated as {len(parts)} recordings")]
        for i, part in enumerate(parts):
            yield part, notes if i == 0 else []


def _windowed(model, rec, n0: int):
    """(window in samples, outputs) of free runs restarted from the EKF's state, when the
    model's free run amplifies state errors more than AMPLIFICATION-fold over ``rec``; else (None, None)."""
    from ..derive import derive
    from ..runtime import run
    states = run(derive(model, "ekf"), rec, backend="casadi", show_progress=False).mean[:, :len(model.states)]
    window = simulation_window(growth_rate(model, states, rec.inputs), model.dt, len(rec.t) - 1 - n0)
    if window >= len(rec.t) - 1 - n0:
        return None, None
    return window, windowed_free_run(model, states, rec.inputs, n0, window)


def write_outputs(result: FitResult, out_dir, *, model_spec: str | None = None,
                  validation: list[dict] = (), figures: bool = True) -> list[Path]:
    """Write ``fit.json``, ``fitted_model.py`` (when the model came from a file or module),
    ``report.md`` and the figures of the recordings as fitted to ``out_dir``; returns the paths
    written."""
    recordings = result.fitted_recordings
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    data = result.asdict()
    data["validation"] = [{k: v for k, v in d.items() if k not in ("simulated", "recording")} for d in validation]
    paths = [out / "fit.json"]
    paths[0].write_text(json.dumps(_finite(data), indent=2, allow_nan=False, default=_json) + "\n")
    if model_spec:
        paths.append(_write_model_file(out / "fitted_model.py", result, model_spec, recordings))
    if figures:
        from .figures import correlation_figure, recording_figure
        names = result.model.output_names
        for r, (rec, Y, got) in enumerate(zip(recordings, result.predictions, result.recordings)):
            paths.append(recording_figure(out / f"fit_{r}.png", f"fitted: {Path(rec.path).name}", rec, Y, names,
                                          start=got.get("rmse_from", 0)))
        for r, v in enumerate(validation):
            paths.append(recording_figure(out / f"validation_{r}.png", "validation (free run" + (
                                          f", restarted every {v['window']:.3g} s" if v.get("window") else "") + "): "
                                          f"{Path(v['recording'].path).name}", v["recording"], v["simulated"], names))
        if result.correlation["names"]:
            paths.append(correlation_figure(out / "correlation.png", result))
    paths.append(_write_report(out / "report.md", result, validation, [p.name for p in paths if p.suffix == ".png"]))
    return paths


def _finite(x):
    """``x`` with every non-finite float as None (null in JSON: an infinite std, an unseen correlation)."""
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    if isinstance(x, (float, np.floating)) and not np.isfinite(x):
        return None
    return x


def _json(x):
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    raise TypeError(f"cannot write {type(x).__name__} to JSON")


def _write_model_file(path: Path, result: FitResult, spec: str, recordings) -> Path:
    """A model file that loads the original declaration and sets the fitted values."""
    if is_module_spec(spec):
        where, find = repr(spec), []
    else:                       # beside this file as written, else where it was (this file moved alone)
        rel = os.path.relpath(Path(spec).resolve(), path.parent.resolve())
        find = [f"DECLARED = Path(__file__).resolve().parent / {rel!r}",
                f"DECLARED = DECLARED if DECLARED.is_file() else Path({str(Path(spec).resolve())!r})", ""]
        where = "str(DECLARED)"
    values = {n: v["value"] for n, v in result.parameters.items()}
    std = {n: v["std"] for n, v in result.parameters.items() if 0 < v["std"] < np.inf}
    files = ", ".join(Path(r.path).name for r in recordings)
    lines = ['"""' + f"{result.model.name}: fitted by `skigen fit` ({result.method}) on {files}, "
             f"{datetime.date.today().isoformat()}.", "",
             "The declaration is the original model file's; the parameters are set to their fitted",
             "values, with their standard deviations as the prior for the next fit."
             + (" The noise covariances are the calibrated ones." if "scales" in result.noise else ""),
             '"""', "from pathlib import Path", "", "import numpy as np  # noqa: F401", "",
             "from skigen.modelfile import load_model", "", *find,
             f"model = load_model({where})",
             f"model.set_parameters({_dict(values)},", f"                     std={_dict(std)})"]
    if "scales" in result.noise:
        M = result.model
        lines.append(f"model.covariances(Q=np.array({np.asarray(M.process_noise()).tolist()!r}),")
        lines.append(f"                  R=np.array({np.asarray(M.measurement_noise()).tolist()!r}),")
        lines.append(f"                  P0=np.array({np.asarray(M.initial_covariance()).tolist()!r}))")
    if result.weights:
        lines += ["", "# Fitted unknown-term weights (the filters start from 0; SKI/UKF estimate them):",
                  f"FITTED_WEIGHTS = {_dict({n: v['value'] for n, v in result.weights.items()})}"]
    path.write_text("\n".join(lines) + "\n")
    return path


def _dict(d: dict) -> str:
    return "{" + ", ".join(f"{k!r}: {float(v)!r}" for k, v in d.items()) + "}"


def _fmt(x: float | None) -> str:
    return "–" if x is None else f"{x:.6g}"


def _write_report(path: Path, result: FitResult, validation, figures) -> Path:
    r = result
    lines = [f"# Fit of `{r.model.name}` by {r.method}", "",
             f"IPOPT {r.status.replace('_', ' ').lower()} in {r.iterations} iterations, {r.seconds:.1f} s; "
             f"log-likelihood {-r.objective:.6g} (less its constant term).", ""]
    if r.parameters or r.weights:
        lines += ["| quantity | unit | initial | fitted | std | 2σ interval | bounds |", "|---|---|---|---|---|---|---|"]
        for name, p in r.parameters.items():
            lo, hi = p["value"] - 2 * p["std"], p["value"] + 2 * p["std"]
            lines.append(f"| {name} | {p['unit']} | {_fmt(p['initial'])} | {_fmt(p['value'])} | {p['std']:.2g} | "
                         f"[{lo:.6g}, {hi:.6g}] | [{_fmt(p['bounds'][0])}, {_fmt(p['bounds'][1])}] |")
        for name, w in r.weights.items():
            lines.append(f"| {name} | | 0 | {_fmt(w['value'])} | {w['std']:.2g} | "
                         f"[{w['value'] - 2 * w['std']:.6g}, {w['value'] + 2 * w['std']:.6g}] | |")
        lines += ["", f"Standard deviations: {r.covariance_note}.", ""]
    if r.notes:
        lines += ["## Notes", ""] + [f"- {n}." for n in r.notes] + [""]
    names, C = r.correlation["names"], np.array(r.correlation["matrix"], float)
    strong = [(names[i], names[j], C[i, j]) for i in range(len(names)) for j in range(i) if abs(C[i, j]) > 0.9]
    if strong:
        lines += ["Strongly correlated estimates (|r| > 0.9): "
                  + "; ".join(f"{a} and {b} ({c:+.3f})" for a, b, c in strong) + ".", ""]
    if "scales" in r.noise:
        lines += ["## Noise", "", "| quantity | declared std | calibrated std | scale on the variance |",
                  "|---|---|---|---|"]
        dec, cal = r.noise["declared"], r.noise["calibrated"]
        for kind, group in (("process_std", "Q"), ("measurement_std", "R")):
            for name in dec[kind]:
                s = r.noise["scales"].get(f"{group}_scale_{name}")
                lines.append(f"| {group} {name} | {dec[kind][name]:.3g} | {cal[kind][name]:.3g} | "
                             + (f"{s['value']:.3g} ± {s['std']:.2g} |" if s else "fixed (declared 0) |"))
        lines.append("")
    else:
        lines += ["Residual std per output: " + ", ".join(
            f"{o} {value_text(v)} (declared {r.noise['declared_std'][o]:.4g})"
            for o, v in r.noise["residual_std"].items()), ""]
    lines += ["## Recordings", "", "| file | samples | RMSE | log-likelihood |", "|---|---|---|---|"]
    for rec in r.recordings:
        lines.append(f"| {Path(rec['file']).name} | {rec['samples']} | "
                     + per_output(rec["rmse"]) + f" | {rec['loglik']:.6g} |")
    kind = "free-run simulation" if r.method == "output-error" else "one-step prediction (innovation)"
    lines += ["", f"RMSE of the {kind} on the fitted recordings"
              + ("; where a recording does not start at the model's initial state, from the sample where the "
                 "filter knows its start (`rmse_from`)" if any(rec.get("rmse_from") for rec in r.recordings) else "")
              + ".", ""]
    if validation:
        lines += ["## Validation (free-run simulation from the first samples' initial state, or restarted from "
                  "the EKF's state where the model amplifies errors, see the last column)", "",
                  "| file | samples scored | RMSE | at the declared values | free run |", "|---|---|---|---|---|"]
        for v in validation:
            lines.append(f"| {Path(v['file']).name} | {v['samples']} | "
                         + per_output(v["rmse"]) + " | " + (per_output(v["rmse_declared"]) if "rmse_declared" in v
                                                            else "–") + " | "
                         + (f"restarted from the EKF's state every {v['window']:.3g} s: the model amplifies a "
                            f"state error {AMPLIFICATION:g}-fold within that" if v.get("window") else "whole recording")
                         + " |")
        lines += [""] + [f"- {n}." for v in validation for n in v.get("notes", [])] + [""]
    lines += [f"![{f}]({f})" for f in figures]
    path.write_text("\n".join(lines) + "\n")
    return path
