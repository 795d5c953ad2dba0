"""report.json (the contract of design.md) and report.md (for a person)."""
from __future__ import annotations

import json
import math
from pathlib import Path

__all__ = ["write_json", "write_markdown"]


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


def _fmt(x, spec=".4g"):
    return "–" if x is None else format(x, spec)


def write_markdown(path, data: dict, meta: dict) -> Path:
    """meta: model, recording, samples, alpha, figures, equations tested, timing, notes."""
    c, loc, fit = data["consistency"], data["located"], data["fit"]
    L = [f"# Diagnosis of `{meta['model']}` on `{meta['recording']}`", ""]
    verdict = "**A significant mismatch exists.**" if data["mismatch_detected"] else \
        "**No significant mismatch: the model explains the recording.**"
    L += [verdict, "",
          f"{meta['samples']} samples, dt = {meta['dt']:g} s. Validation segment: {fit['validation']}.", ""]
    L += ["## 1. Detect", "",
          f"The nominal model's EKF over the whole recording (false-alarm rate α = {c['alpha']:g}: α/2 for the "
          f"NIS test, two-sided, α/2 for whiteness):", "",
          "| test | value | expected under the model | verdict |", "|---|---|---|---|",
          f"| mean NIS | {c['nis_mean']:.4g} | {c['nis_expected']:.4g}, bounds [{c['nis_bounds'][0]:.4g}, "
          f"{c['nis_bounds'][1]:.4g}] | {'inconsistent' if c['nis_mean'] > c['nis_bounds'][1] else 'ok'} |",
          f"| whiteness (mean + Ljung–Box, {c['lags']} lags), p-value | {c['whiteness_pvalue']:.3g} | "
          f"≥ {c['alpha'] / 2:g} | {'not white' if c['whiteness_pvalue'] < c['alpha'] / 2 else 'ok'} |", ""]
    for o in c["outputs"]:
        L.append(f"- output `{o['name']}`: NIS {o['nis_mean']:.4g}, innovation mean {o['innovation_mean']:+.3g}σ, "
                 f"whiteness p = {o['whiteness_pvalue']:.3g}")
    if c.get("note"):
        L += ["", f"Note: {c['note']}."]
    L.append("")
    if not data["mismatch_detected"]:
        L += ["Nothing further to locate or name: no findings, no corrected model.", ""]
    else:
        L += ["## 2. Locate", "",
              f"- outputs that disagree: {', '.join(f'`{o}`' for o in loc['outputs'])}",
              f"- equation(s) that absorb the error: {', '.join(f'`{e}`' for e in loc['equations'])} "
              f"(random-walk disturbance per equation, log-likelihood gain on the fit segment: "
              + ", ".join(f"`{k}` {v:+.1f}" for k, v in loc.get("loglik_gain", {}).items()) + ")"]
        if meta.get("kinematic"):
            L.append(f"- kinematic equation(s) {', '.join(f'`{k}`' for k in meta['kinematic'])} "
                     "(the rate of a position is a declared state) are exact by definition and were not tested")
        w = loc["windows"]
        L.append(f"- significant in {len(w)} window(s): " +
                 (", ".join(f"{a:.2f}–{b:.2f} s" for a, b in w[:12]) + (" …" if len(w) > 12 else "") if w else "none"))
        L.append(f"- regime: {loc['regime'] or 'no single-feature regime: present throughout, or no simple rule'}")
        L += ["", "## 3. Name", ""]
        if data["findings"]:
            L += ["| effect | equation | term | coefficient ± std | evidence (validation log-lik. gain) |",
                  "|---|---|---|---|---|"]
            for f in data["findings"]:
                L.append(f"| {f['effect']} | `{f['equation']}` | `{f['expression']}` | "
                         f"{_fmt(f['coefficient'])} ± {_fmt(f['std'], '.2g')} {f.get('unit', '')} | "
                         f"{f['evidence']:+.1f} |")
            L.append("")
            for f in data["findings"]:
                L.append(f"- **{f['effect']}**: {f['reading']}.")
            L.append("")
        else:
            L += ["No catalog or user candidate explains the mismatch significantly; supply candidates "
                  "(`--candidate NAME:EQUATION:FORMULA`).", ""]
        for line in meta.get("proposals", []):
            L.append(f"- {line}")
        L += ["", "## 4. Model", ""]
        line = (f"Corrected model file: `{data['corrected_model']}`" if data["corrected_model"] else
                "No corrected model (nothing was named).")
        if meta.get("generated"):
            line += f"; its EKF in C: {', '.join(f'`{Path(p).name}`' for p in meta['generated'])} in " \
                    f"`{Path(meta['generated'][0]).parent}`."
        L.append(line)
        L += ["", "## 5. Fit on the validation segment", ""]
        b, a = fit["before"], fit["after"]
        if a:
            L += ["| | nominal | corrected |", "|---|---|---|",
                  f"| log-likelihood (sum) | {b['loglik']:.1f} | {a['loglik']:.1f} |",
                  f"| mean NIS | {b['nis_mean']:.3g} | {a['nis_mean']:.3g} |"]
            for k in b["innovation_rms"]:
                L.append(f"| innovation RMS `{k}` | {b['innovation_rms'][k]:.4g} | {a['innovation_rms'][k]:.4g} |")
            for k in b["free_run_rmse"]:
                L.append(f"| free-run RMSE `{k}` ({meta['horizon']:g} s) | {b['free_run_rmse'][k]:.4g} | "
                         f"{a['free_run_rmse'][k]:.4g} |")
            L.append("")
    if meta.get("figures"):
        L += ["## Figures", ""] + [f"![{Path(p).stem}]({Path(p).name})" for p in meta["figures"]] + [""]
    L.append(f"Diagnosis took {meta['seconds']:.1f} s.")
    path = Path(path)
    path.write_text("\n".join(L) + "\n")
    return path
