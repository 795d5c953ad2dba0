"""Locate: which outputs disagree, which equations absorb the error, when, and in what regime.

Per equation j a random-walk disturbance d_j (units of dx_j/dt) is added to
the (noise-calibrated) nominal model, its step size chosen by the recording's
log-likelihood,
and an EKF + RTS smoother estimates it over the whole recording. The
equation whose disturbance buys the most likelihood absorbs the error (a
second one joins if it adds significantly on top). Kinematic identities
(ṗ = v) are exact by definition and are not tested unless asked. The windows
are where the smoothed disturbance is beyond 3σ, or where, over half a second,
the disturbance model predicts the data significantly better than the nominal
one (a fast-varying effect a random walk cannot follow sample by sample); the
regime is the one-feature rule
(a decision stump on the smoothed states and the inputs) that best separates
those samples from the rest. Once a correction is found, the diagnosis
replaces both by where the found terms act (``diagnose.windows_where_it_acts``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np
from scipy import stats

from ..derive import derive
from ..model import Model
from ..recording import Recording
from .detect import Consistency, normalised_innovations, whiteness
from . import transform as T
from ..smoother import smooth
from .cv import loglik
from .transform import with_disturbance

__all__ = ["Location", "locate", "rate_scales", "windows_of", "regime_stump", "disturbance_gains",
           "disturbance_threshold", "features"]

GRID = 10.0 ** np.arange(-6.0, -0.5, 1.0)    # disturbance step per sample, × the equation's rate scale
Z_WINDOW = 3.0


@dataclass
class Location:
    outputs: list[str]
    equations: list[str]
    gains: dict[str, float]              # fit log-likelihood gain of a disturbance per equation
    steps: dict[str, float]              # chosen random-walk step per sample
    windows: list[tuple[float, float]]
    regime: str | None
    disturbance: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # eq → (d̂, σ)
    states: np.ndarray | None = None     # smoothed nominal states (N, nx)
    active: np.ndarray | None = None     # samples where a disturbance is significant
    scales: dict[str, float] = field(default_factory=dict)

    def asdict(self) -> dict:
        return {"outputs": self.outputs, "equations": self.equations,
                "windows": [[float(a), float(b)] for a, b in self.windows],
                "regime": self.regime, "loglik_gain": self.gains}


def rate_scales(model: Model, rec: Recording, states: np.ndarray) -> dict[str, float]:
    """RMS of each equation's rate (dx/dt) along the filtered nominal trajectory."""
    x = ca.vertcat(*[v.sym for v in model.states])
    u = ca.vertcat(*[v.sym for v in model.inputs]) if model.inputs else ca.SX(0, 1)
    mem = ca.vertcat(*[m.sym for m in model.memory]) if model.memory else ca.SX(0, 1)
    rhs = ca.vertcat(*[model.rhs[n] for n in model.state_names])
    if model.discretization == "discrete":
        rhs = (rhs - x) / model.dt
    f = ca.Function("rate", [x, u, mem], [rhs]).map(len(rec.t))
    memv = T.memory_values(model, rec)
    r = np.asarray(f(states[:, :len(model.states)].T, rec.inputs.T, memv.T)).T
    rms = np.sqrt(np.mean(r ** 2, axis=0))
    floor = max(1e-9, 1e-6 * float(rms.max(initial=0)))
    return {n: float(max(s, floor)) for n, s in zip(model.state_names, rms)}


def _best_step(nominal: Model, eqs, scales, fit: Recording, ll0: float) -> tuple[list[float], float]:
    """Random-walk steps (one per equation, a common multiple of each scale) maximising the
    fit log-likelihood: a decade grid, then a parabola in log step around the best."""
    def ll(f):
        m, _ = with_disturbance(nominal, eqs, [f * scales[e] for e in eqs], [scales[e] for e in eqs])
        return loglik(m, fit)
    vals = [ll(f) for f in GRID]
    i = int(np.argmax(vals))
    best_f, best = GRID[i], vals[i]
    if 0 < i < len(GRID) - 1:
        y0, y1, y2 = vals[i - 1], vals[i], vals[i + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            shift = 0.5 * (y0 - y2) / den          # in decades
            f = GRID[i] * 10.0 ** float(np.clip(shift, -0.5, 0.5))
            v = ll(f)
            if v > best:
                best_f, best = f, v
    return [best_f * scales[e] for e in eqs], best - ll0


def windows_of(t: np.ndarray, active: np.ndarray, dt: float) -> list[tuple[float, float]]:
    """Runs of True in ``active`` as [t0, t1]: gaps under max(0.5 s, 1 % of the recording) closed,
    runs under max(0.2 s, 10 samples of ``dt``) dropped."""
    merge, shortest = max(0.5, 0.01 * (t[-1] - t[0])), max(0.2, 10 * dt)
    runs, start = [], None
    for k, a in enumerate(active):
        if a and start is None:
            start = k
        if not a and start is not None:
            runs.append([start, k - 1])
            start = None
    if start is not None:
        runs.append([start, len(active) - 1])
    merged = []
    for r in runs:
        if merged and t[r[0]] - t[merged[-1][1]] <= merge:
            merged[-1][1] = r[1]
        else:
            merged.append(r)
    return [(float(t[a]), float(t[b])) for a, b in merged if t[b] - t[a] >= shortest]


def _local_gain(gain: np.ndarray, dt: float, alpha: float, seconds: float = 0.5) -> np.ndarray:
    """Samples inside a window (``seconds`` long, centred) over which the disturbance model's
    summed predictive log-likelihood gain passes a likelihood-ratio test with one parameter at
    α / (number of windows)."""
    w = max(25, int(round(seconds / dt)))
    if len(gain) < w:
        return np.zeros(len(gain), bool)
    c = np.concatenate([[0.0], np.cumsum(gain)])
    moving = c[w:] - c[:-w]                      # sum over samples [k, k + w)
    hit = moving > 0.5 * stats.chi2.isf(alpha * w / len(gain), 1)
    out = np.zeros(len(gain), bool)
    for k in np.flatnonzero(hit):
        out[k:k + w] = True
    return out


def regime_stump(features: dict[str, tuple[np.ndarray, str]], active: np.ndarray,
                 min_j: float = 0.5) -> str | None:
    """'when |v| > 0.31 m/s': the single threshold rule with the best Youden J (TPR − FPR)
    for the active samples, or None if none reaches ``min_j`` or the effect is (nearly) always
    or never active."""
    frac = active.mean()
    if not 0.02 < frac < 0.95:
        return None
    best = (min_j, None)
    for name, (x, unit) in features.items():
        for q in np.unique(np.percentile(x, np.arange(2, 99, 2))):
            for above in (True, False):
                pred = x > q if above else x < q
                j = pred[active].mean() - pred[~active].mean()
                if j > best[0]:
                    best = (j, f"when {name} {'>' if above else '<'} {q:.3g}{' ' + unit if unit not in ('', '1', '-') else ''}")
    return best[1]


def features(model: Model, rec: Recording, states: np.ndarray) -> dict:
    out = {}
    for i, v in enumerate(model.states):
        out[v.name] = (states[:, i], v.unit)
        out[f"|{v.name}|"] = (np.abs(states[:, i]), v.unit)
    for i, v in enumerate(model.inputs):
        out[v.name] = (rec.inputs[:, i], v.unit)
        out[f"|{v.name}|"] = (np.abs(rec.inputs[:, i]), v.unit)
    return out


def _outputs(nominal_run, names, alpha: float, cons: Consistency) -> list[str]:
    """Outputs whose own NIS, whiteness or independence test rejects at α/(3·ny) (two-sided NIS)."""
    eps = normalised_innovations(nominal_run)
    ny, flagged, pvals = len(names), [], []
    for i, name in enumerate(names):
        e = eps[:, i][np.isfinite(eps[:, i])]
        sf = stats.chi2.sf(np.sum(e ** 2), len(e))
        p = min(2 * min(sf, 1 - sf), whiteness(eps[:, i], cons.lags),
                cons.outputs[i].get("independence_pvalue", 1.0) if i < len(cons.outputs) else 1.0)
        pvals.append(p)
        if p < alpha / (3 * ny):
            flagged.append(name)
    return flagged or [names[int(np.argmin(pvals))]]


def disturbance_gains(nominal: Model, rec: Recording, nominal_run, equations) -> tuple[dict, dict, dict]:
    """Per equation: the log-likelihood gain of the best random-walk disturbance over the whole
    recording, its step per sample, and the equation's rate scale."""
    scales = rate_scales(nominal, rec, nominal_run.mean)
    ll0 = float(np.sum(nominal_run.loglik))
    steps, gains = {}, {}
    for e in equations:
        (steps[e],), gains[e] = _best_step(nominal, [e], scales, rec, ll0)
    return gains, steps, scales


def disturbance_threshold(alpha: float, n_equations: int) -> float:
    """Log-likelihood gain a disturbance needs: 0.5·χ²₂(1 − α/n), two parameters (step and
    start), Bonferroni over the equations."""
    return 0.5 * stats.chi2.ppf(1 - alpha / max(1, n_equations), 2)


def locate(nominal: Model, rec: Recording, nominal_run, cons: Consistency, alpha: float = 0.01,
           equations=None, tested=None) -> Location:
    """See the module docstring. ``nominal_run``: the nominal EKF over the whole recording;
    ``tested``: :func:`disturbance_gains` already computed for ``equations``."""
    eqs = list(equations or nominal.state_names)
    gains, steps, scales = tested or disturbance_gains(nominal, rec, nominal_run, eqs)
    ll0 = float(np.sum(nominal_run.loglik))
    threshold = disturbance_threshold(alpha, len(eqs))
    order = sorted(eqs, key=lambda e: -gains[e])
    chosen = [order[0]] if gains[order[0]] > threshold else []
    for e in order[1:]:
        if chosen and gains[e] > threshold:
            m, _ = with_disturbance(nominal, chosen + [e], [steps[c] for c in chosen + [e]],
                                    [scales[c] for c in chosen + [e]])
            if loglik(m, rec) - ll0 - gains[chosen[0]] > threshold:
                chosen.append(e)
    if not chosen:
        chosen = [order[0]]
    m, dnames = with_disturbance(nominal, chosen, [steps[c] for c in chosen], [scales[c] for c in chosen])
    sm = smooth(derive(m, "ekf"), rec)
    nx = len(nominal.states)
    dist, active = {}, np.zeros(len(rec.t), bool)
    for e, dn in zip(chosen, dnames):
        i = m.state_names.index(dn)
        d, s = sm.mean[:, i], sm.std[:, i]
        dist[e] = (d, s)
        active |= np.abs(d) > Z_WINDOW * np.maximum(s, 1e-300)
    significant = active.copy()
    active |= _local_gain(sm.run.loglik - nominal_run.loglik, nominal.dt, alpha)
    windows = windows_of(rec.t, active, nominal.dt)
    regime = regime_stump(features(nominal, rec, sm.mean[:, :nx]),
                          significant if significant.mean() > 0.02 else active)
    return Location(_outputs(nominal_run, nominal.output_names, alpha, cons), chosen, gains, steps,
                    windows, regime, dist, sm.mean[:, :nx], active, scales)
