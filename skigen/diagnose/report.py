"""report.json (the contract of design.md) and report.md (for a person)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..fit import plus_minus as _pm
from ..simulate import AMPLIFICATION

__all__ = ["write_json", "write_markdown", "finding_line", "behind", "lifted"]


def behind(tie: dict) -> str:
    """How far a tie is behind the finding: cross-validated, or in-sample with as many numbers."""
    if tie.get("in_sample"):
        return f"log-likelihood {tie['loglik_behind']:.1f} behind on the whole recording, with as many numbers"
    if tie["cv_loglik_behind"] < 0 and not tie.get("replaced"):    # a round's set scored under the finding's noise
        return (f"cross-validated log-likelihood {-tie['cv_loglik_behind']:.1f} ahead under the noise the finding "
                f"leaves (a round weighs its finalists each under the noise calibrated with it, and this set was "
                f"not one)")
    if tie["cv_loglik_behind"] < 0:              # what a revision replaced (with more numbers, if with others)
        return (f"cross-validated log-likelihood {-tie['cv_loglik_behind']:.1f} ahead"
                + (", with more numbers" if tie.get("with") else ""))
    return f"cross-validated log-likelihood {tie['cv_loglik_behind']:.1f} behind"


def _clean(x):
    """JSON-safe: NaN/inf become null, NumPy scalars plain numbers."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if hasattr(x, "item") and not isinstance(x, (str, bytes)):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def write_json(path, data: dict) -> Path:
    path = Path(path)
    path.write_text(json.dumps(_clean(data), indent=2) + "\n")
    return path


def where(f: dict) -> str:
    """'effect on equation' (or on the input a structural item acts on; 'effect of output (reads
    state)' for a sensor), and the input it acts through (report.json's finding or term item)."""
    if f["effect"] == "constant":
        places = f.get("written_in") or ([f["equation"]] if f.get("equation") else [])
        return f"the constant {f['input']}" + (f" (in {', '.join(places)})" if places else "")
    if f.get("output"):
        reads = f.get("reads") or f.get("equation")
        return f"{f['effect']} of {f['output']}" + (f" (reads {reads})" if reads else "")
    on = f.get("equation") or f.get("input")
    return f"{f['effect']} on {on}" + (f" through {f['through']}" if f.get("through") else "")


def finding_line(f: dict) -> str:
    """One finding in a line: effect, equation, term, coefficient ± std, evidence, free run without it."""
    free = f.get("free_run_without")
    std = f["std"]
    bar = f"± {std:.2g}" if std is not None and math.isfinite(std) else (
        "(a whole number of samples: no error bar)" if f["effect"] == "input_delay" else "(no error bar)")
    unit = f" {f['unit']}" if f.get("unit") not in (None, "", "1") and bar.startswith("±") else ""
    return (f"{where(f)}: {f['expression']}, coefficient {f['coefficient']:.6g}{unit} {bar}, "
            f"cross-validated evidence {f['evidence']:+.1f}, free run without it "
            f"{'diverges' if free is None or not math.isfinite(free) else format(free, '.3g')}"
            + "".join(f"; not told apart from {where(a)}: {a['expression']}, coefficient {a['coefficient']:.6g}"
                      f"{_together(a)}, explains the recording as well" for a in f.get("as_good", [])))


def lifted(data: dict) -> str | None:
    """What the joint refit corrected in the nominal's own terms (its lifted corrections, kept
    because the data want them), as a sentence; None when it corrected none."""
    refit = data.get("refit") or {}
    said = []
    for d in refit.get("lifted", []):
        p = (refit.get("parameters") or {}).get(d["parameter"])
        if p and p.get("std"):
            said.append(f"its {d['effect'].replace('_', ' ')} on `{d['equation']}` (`{d['formula']}`) by "
                        f"{p['value']:.4g} ± {p['std']:.2g} ({abs(p['value']) / p['std']:.1f} std from 0)")
    remains = (data.get("remaining") or {}).get("mismatch")
    return ("The joint refit corrects the nominal's own terms: " + "; ".join(said) + (
        " — its constants are off there, or the corrections make up for the mismatch that remains" if remains
        else " — its constants are off there") + " (refitted, not catalog findings; section 5)") if said else None


def _acts_on(f: dict) -> str:
    """A finding's place in the table: the equation, a sensor's output and what it reads, or the
    equations and outputs a constant is written in."""
    if f.get("output"):
        return f"`{f['output']}` (reads `{f.get('reads') or f['equation']}`)"
    if f["effect"] == "constant" and f.get("written_in"):
        return ", ".join(f"`{p}`" for p in f["written_in"])
    return f"`{f['equation']}`"


def _together(tie: dict) -> str:
    """A tie that is one of several terms explaining as well together (a revision's): the others."""
    return f", together with {', '.join(tie['with'])}" if tie.get("with") else ""


def remaining_why(rem: dict, alpha: float) -> str:
    """What says a mismatch remains, in words: the corrected model's tests that failed (each at
    α/3, as :func:`~skigen.diagnose.detect.judge` splits it), and where
    only the one-step tests did, that what is left changes faster than a slow disturbance (a short
    period's unmodelled sin(60α) left "A mismatch remains in `q`." and nothing more)."""
    failed = [f"its innovations are not white (p = {rem['whiteness_pvalue']:.2g})"] \
        if rem.get("whiteness_pvalue", 1.0) < alpha / 3 else []
    if (p := rem.get("independence_pvalue")) is not None and p < alpha / 3:
        failed.append(f"they follow the states and inputs before them (p = {p:.2g})")
    gains, threshold = rem.get("disturbance_gain") or {}, rem.get("disturbance_threshold", np.inf)
    slow = {e: g for e, g in gains.items() if g > threshold}
    if slow:
        failed.append("a slowly varying disturbance is significant on " + ", ".join(
            f"`{e}` (log-likelihood gain {g:+.1f}, threshold {threshold:.1f})" for e, g in slow.items()))
    if not failed:
        return ""
    return ("Judged on the corrected model: " + "; ".join(failed) + "." + (
        " No slowly varying disturbance is significant: what is left changes from sample to sample (a delay, a "
        "fast mode, a term the candidates lack), not slowly." if gains and not slow else ""))


def _fmt(x, spec=".4g"):
    return "–" if x is None else format(x, spec)


def _noise_table(noise: dict) -> list[str]:
    d, c = noise["declared"], noise["calibrated"]
    L = ["| noise std | declared | calibrated |", "|---|---|---|"]
    for kind, label in (("process_std", "process, per sample"), ("measurement_std", "measurement")):
        for k, v in d[kind].items():
            if v or c[kind][k]:
                L.append(f"| {label} `{k}` | {v:.4g} | {c[kind][k]:.4g} |")
    for k, p in (noise.get("parameters") or {}).items():
        L.append(f"| parameter `{k}` (fitted with the noise) | {_fmt(p['declared'])} | "
                 f"{_pm(p['calibrated'], p['std'])} |")
    return L


SENSOR_BELOW = 0.1    # a calibrated sensor std below this share of the declared one is said


def _sensors_below(noise: dict) -> str:
    """'the noise of enc (1.3e-06 against 0.0005)', … for the sensors calibrated below SENSOR_BELOW
    of their declared std; '' when none is."""
    d, c = noise["declared"]["measurement_std"], noise["calibrated"]["measurement_std"]
    low = [f"{k} ({c[k]:.2g} against {v:.2g})" for k, v in d.items() if v and c.get(k) is not None and c[k] < SENSOR_BELOW * v]
    return ("the noise of " + ", ".join(low)) if low else ""


def _metrics_table(rows: list[tuple[str, dict, dict | None]]) -> list[str]:
    """rows: (label, before metrics, after metrics or None)."""
    L = ["| recording | | nominal | corrected |", "|---|---|---|---|"]
    for label, b, a in rows:
        get = lambda m, k, sub=None: None if m is None else (m[k][sub] if sub else m[k])
        L.append(f"| {label} | log-likelihood | {b['loglik']:.1f} | {_fmt(get(a, 'loglik'), '.1f')} |")
        L.append(f"| | mean NIS | {b['nis_mean']:.3g} | {_fmt(get(a, 'nis_mean'), '.3g')} |")
        for k in b["innovation_rms"]:
            L.append(f"| | innovation RMS `{k}` | {b['innovation_rms'][k]:.4g} | "
                     f"{_fmt(get(a, 'innovation_rms', k))} |")
        for k in b["free_run_rmse"]:
            L.append(f"| | free-run RMSE `{k}` ({_free_run_span(b)}) | "
                     f"{_fmt(b['free_run_rmse'][k])} | {_fmt(get(a, 'free_run_rmse', k))} |")
            if "free_run_noise" in b:
                L.append(f"| | free-run RMSE `{k}` the model's noise alone gives | {_fmt(b['free_run_noise'][k])} | "
                         f"{_fmt(get(a, 'free_run_noise', k))} |")
    return L


def _fit_rows(fit: dict) -> list[tuple[str, dict, dict | None]]:
    """The Fit table's rows: this recording, then each --validate recording."""
    return ([("this recording (in-sample)", fit["before"], fit["after"])]
            + [(Path(v["before"]["recording"]).name, v["before"], v["after"]) for v in fit.get("recordings", [])])


def _candidate_lines(data: dict) -> list[str]:
    return [f"- Your candidate {c['name']} on `{c['equation']}` (`{c['formula']}`): {c['why']}."
            for c in data.get("candidates_not_named", [])]


def _free_run_span(metrics: dict) -> str:
    """What a free-run RMSE covers: the whole record, or windows restarted from the filter's state."""
    w = metrics.get("free_run_window")
    if not w:
        return f"whole record from t = {metrics['free_run_from']:.3g} s"
    return (f"from t = {metrics['free_run_from']:.3g} s, restarted from the filter's state every {w:.3g} s: "
            f"the nominal model amplifies a state error {AMPLIFICATION:g}-fold within that, no longer run "
            f"of it follows the recording")


def noise_covers_sentence(covers: list[str]) -> str:
    """What a consistent verdict rests on, when a calibrated noise is far above the declared one."""
    return ("; ".join(covers) + ": the recording cannot tell a noise declared that much too small from physics "
            "the model misses hiding in that noise; if the declared noise is right, something is missing there "
            "(skigen fit notes the same)")


def write_markdown(path, data: dict, meta: dict) -> Path:
    """meta: model, recording, samples, dt, folds, figures, kinematic, proposals, generated, seconds."""
    c, loc, fit, rem = data["consistency"], data["located"], data["fit"], data["remaining"]
    L = [f"# Diagnosis of `{meta['model']}` on `{meta['recording']}`", ""]
    if not data["mismatch_detected"]:
        verdict = "**No significant mismatch: the model, with calibrated noise, explains the recording.**"
    elif rem.get("mismatch"):
        verdict = ("**A significant mismatch exists, and a mismatch remains after the correction.**"
                   if data["findings"] else "**A significant mismatch exists; no candidate explains it.**")
    else:
        verdict = "**A significant mismatch exists; the corrected model explains it.**"
    L += [verdict, ""]
    if rem.get("units"):
        L += ["**Check the units first** — the findings below may only be making up for them: "
              + "; ".join(rem["units"]), ""]
    L += [f"**A validation recording disagrees** — {line}.\n" for line in data.get("validation_disagrees", [])]
    if rem.get("noise_covers"):
        L += [f"**Consistent only with noise far above the declared** — {noise_covers_sentence(rem['noise_covers'])}.", ""]
    L += [f"{meta['samples']} samples, dt = {meta['dt']:g} s. {fit['validation']}.", ""]
    L += [f"Note: {n}." for n in data["notes"]] + [""] * bool(data["notes"])
    L += ["## 1. Calibrate the noise", "", data["noise"]["method"] + ":", ""] + _noise_table(data["noise"]) + [""]
    if data.get("mismatch_detected") and (low := _sensors_below(data["noise"])):
        L += [f"The calibration puts {low} far below the declared: on a model that misses something the filter "
              f"follows the readings and leaves the misfit to the process noise, so these are not statements "
              f"about the sensors (the corrected model's noise is in section 5's refit).", ""]
    dn = c.get("declared_noise")
    if dn:
        L += [f"With the declared noise the mean NIS is {dn['nis_mean']:.4g} (expected {dn['nis_expected']:.4g}) "
              f"and the whiteness p-value {dn['whiteness_pvalue']:.3g}: the noise guess alone decides nothing "
              f"below.", ""]
    L += ["## 2. Detect (on the calibrated model)", "",
          f"False-alarm rate α = {c['alpha']:g}: α/3 for whiteness (Bonferroni over outputs), α/3 for "
          f"innovations that follow the state or input before them (Bonferroni over outputs), α/3 for a "
          f"slowly varying disturbance (Bonferroni over equations).", "",
          "| test | value | threshold | verdict |", "|---|---|---|---|",
          f"| whiteness (mean + Ljung–Box, {c['lags']} lags), p-value | {c['whiteness_pvalue']:.3g} | "
          f"≥ {c['alpha'] / 3:.3g} | {'not white' if c['whiteness_pvalue'] < c['alpha'] / 3 else 'ok'} |",
          f"| independence of the past (N·R² on {c.get('regressors', 0)} functions of the states and inputs "
          f"one sample back), p-value | {c.get('independence_pvalue', 1.0):.3g} | ≥ {c['alpha'] / 3:.3g} | "
          f"{'follows the past' if c.get('independence_pvalue', 1.0) < c['alpha'] / 3 else 'ok'} |"]
    for eq, g in c.get("disturbance_gain", {}).items():
        L.append(f"| random-walk disturbance on `{eq}`, log-likelihood gain | {g:+.1f} | "
                 f"{c['disturbance_threshold']:.1f} | {'significant' if g > c['disturbance_threshold'] else 'ok'} |")
    L.append(f"| mean NIS (not tested: calibrated) | {c['nis_mean']:.4g} | – | – |")
    L.append("")
    if not data["mismatch_detected"]:
        L += ["Nothing further to locate or name: no findings, no corrected model.", ""]
        L += _candidate_lines(data) + ["", "## Fit", ""] + _metrics_table(_fit_rows(fit)) + [""]
    else:
        L += ["## 3. Locate", "",
              f"- outputs that disagree: {', '.join(f'`{o}`' for o in loc['outputs'])}",
              f"- equation(s) that absorb the error: {', '.join(f'`{e}`' for e in loc['equations'])}"]
        if meta.get("kinematic"):
            L.append(f"- kinematic equation(s) {', '.join(f'`{k}`' for k in meta['kinematic'])} "
                     "(the rate of a position is a declared state) are exact by definition and were not tested")
        w = loc["windows"]
        L.append(f"- significant in {len(w)} window(s): " +
                 (", ".join(f"{a:.2f}–{b:.2f} s" for a, b in w[:12]) + (" …" if len(w) > 12 else "") if w else "none"))
        L.append(f"- regime: {loc['regime'] or 'no single-feature regime: present throughout, or no simple rule'}")
        L += ["", "## 4. Name", ""]
        if data["findings"]:
            L += ["Evidence: the cross-validated log-likelihood each finding adds given the others (drop-one; "
                  "the findings' evidences need not add up). Free run without it: the free-run "
                  "RMSE, over the output's spread and averaged over the outputs, of the model as named, without "
                  f"this one finding (with all of them: {_fmt(data.get('free_run_with_all_findings'), '.3g')}), "
                  "its coefficients as the naming fitted them, before the joint refit that gives those in the "
                  "table and the corrected model (section 6 says how that one free-runs); "
                  "the findings are listed by it, the one a simulation needs most first: one step ahead a "
                  "delay or a sensor effect can carry more evidence than a force the simulation cannot do without.",
                  "", "| effect | acts on | term | coefficient ± std | shape | evidence | free run without it |",
                  "|---|---|---|---|---|---|---|"]
            for f in data["findings"]:
                shape = ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                                  for k, v in f.get("shape", {}).items() if k != "state") or "–"
                L.append(f"| {f['effect']} | {_acts_on(f)} | `{f['expression']}` | "
                         f"{_pm(f['coefficient'], f['std'])} {'' if f.get('unit') in (None, '1') else f['unit']} | {shape} | "
                         f"{f['evidence']:+.1f} | {_fmt(f.get('free_run_without'), '.3g')} |")
            L.append("")
            for f in data["findings"]:
                L.append(f"- **{f['effect']}**: {f['reading']}." + (f" *Note: {f['note']}.*" if f.get("note") else ""))
                for a in f.get("as_good", []):
                    L.append(f"  **Not told apart** from {where(a)} (`{a['expression']}`, "
                             f"{_pm(a['coefficient'], a['std'])}){_together(a)}: it explains the recording "
                             f"as well ({behind(a)}, less than a finding must add); another recording, or a "
                             f"measurement of one of them, decides.")
            L.append("")
        else:
            L += ["No catalog or user candidate explains the mismatch significantly.", ""]
        if (own := lifted(data)) is not None:
            L += [own + ".", ""]
        for key, title in (("compensating", "Compensating, not findings"), ("not_identifiable", "Not identifiable")):
            for f in data.get(key, []):
                heading = "Not needed" if f["note"].startswith("not needed") else title   # left out by the refit
                L.append(f"- {heading}: {f['effect']} on `{f['equation']}` (`{f['expression']}`, "
                         f"{_pm(f['coefficient'], f['std'])}): {f['note']}.")
        L += _candidate_lines(data)
        for line in meta.get("proposals", []):
            L.append(f"- {line}")
        L += ["", "## 5. Model", ""]
        line = (f"Corrected model file: `{data['corrected_model']}`, its coefficients declared as parameters at "
                f"their fitted values ± std" if data["corrected_model"] else "No corrected model (nothing was named).")
        if meta.get("generated"):
            line += f"; its EKF in C: {', '.join(f'`{Path(p).name}`' for p in meta['generated'])} in " \
                    f"`{Path(meta['generated'][0]).parent}`."
        L.append(line)
        r = data.get("refit")
        if r:
            L += ["", f"Refit ({r['method']}, jointly with the noise): {r.get('note') or 'converged'}"]
            for n, p in (r.get("parameters") or {}).items():
                L.append(f"- `{n}` = {_pm(p['value'], p['std'])} (from {_fmt(p['initial'])})")
        L += ["", "## 6. Fit", ""]
        L += _metrics_table(_fit_rows(fit)) + [""]
        if fit.get("folds"):
            L += ["Cross-validated log-likelihood per fold (coefficients fitted without the fold):", "",
                  "| fold | nominal | corrected |", "|---|---|---|"]
            for f in fit["folds"]:
                spans = ", ".join(f"{a:.2f}–{b:.2f}" for a, b in f["spans"])
                L.append(f"| {spans} s | {f['loglik_before']:.1f} | "
                         f"{f['loglik_after']:.1f} |")
            L.append("")
        L += ["## 7. What remains", ""]
        if not rem.get("mismatch"):
            L.append("The corrected model, refitted with calibrated noise, is consistent with the recording"
                     + (f", but only with {noise_covers_sentence(rem['noise_covers'])}." if rem.get("noise_covers") else "."))
        else:
            at = rem.get("where") or {}
            L.append("**A mismatch remains** " + (f"in `{'`, `'.join(at.get('equations', []))}`" if at else "")
                     + (f", {at['regime']}" if at.get("regime") else "") + "."
                     + (f" {why}" if (why := remaining_why(rem, c["alpha"])) else ""))
            if rem.get("tried"):
                L.append(rem["tried"] + ".")
            if rem.get("unconfirmed_step"):
                L.append(rem["unconfirmed_step"][0].upper() + rem["unconfirmed_step"][1:] + ".")
            if rem.get("explained_by"):
                L.append(f"What is left follows `{rem['explained_by']}` best{' outside those candidates' if rem.get('tried') else ''} (weighted R² {rem['r2']:.2f} for "
                         f"`{rem['shape']}`); to test it: `--candidate '{rem['suggested_candidate']}'`.")
            if rem.get("note"):
                L.append(rem["note"] + ".")
            if rem.get("periodic"):
                L.append(rem["periodic"]["note"][0].upper() + rem["periodic"]["note"][1:] + ".")
            if rem.get("integration"):
                L.append(f"Integration: {rem['integration']}.")
        L.append("")
    if meta.get("figures"):
        L += ["## Figures", ""] + [f"![{Path(p).stem}]({Path(p).name})" for p in meta["figures"]] + [""]
    L.append(f"Diagnosis took {meta['seconds']:.1f} s.")
    path = Path(path)
    path.write_text("\n".join(L) + "\n")
    return path
