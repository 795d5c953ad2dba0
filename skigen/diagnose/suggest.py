"""What remains: the state or input that best explains a disturbance the catalog did not, and a
candidate term to try (``--candidate NAME:EQUATION:FORMULA``).

The smoothed disturbance d(t) of the located equation is regressed on simple
shapes of each state and input x along the filtered trajectory — x, x·|x|,
x³, tanh(x/s), and sin(2πx/L + φ) for periods L from a third of the range of x
down to 1/40 of it, 25 of them and the best refined between its neighbours, each at
the phase φ that fits best (three cycles at
least: one or two over the range are any smooth curve, and read as a period that is
not there; a road's grade every 400 m of a 3 km drive fell between the five periods
once tried) — each with an intercept, weighted by d's precision; the shape with
the largest weighted R² names the feature and the suggested formula. It is a
hint for a person, not a finding: it is not cross-validated. Below an R² of
``HINT_R2`` no shape of one state or input explains the leftover (coloured
noise, or dynamics of another order), and the report says so instead. A shape
that is a candidate the diagnosis already tried on that equation (|r| ≥ SAME
along the trajectory: x is the catalog's linear stiffness) is not suggested —
run, it was "judged as the catalog's" and the same suggestion came back — but
said, beside the best shape outside them. Where a single step in time explains it better than
any shape of a state or input (by STEP_MARGIN of R²: a tie at 0.48 was taken for a change), the
system changed during the recording (a battery that sags partway): that is said instead of a
candidate; where a straight line in time explains it at least as well as any step (one number
fewer), something drifts (a sensor's bias warming up), said as a drift, not as a change.
(HINT_R2 was 0.05: a cubic of a capacitor's voltage at R² 0.07 was suggested.) A
step or a shape that spans less than STEP_Z of the disturbance's std is not said: within its
band, d's R² is that of its noise.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.optimize import minimize_scalar

from .catalog import _num
from .locate import Location, features

__all__ = ["explain"]

HINT_R2 = 0.2       # a shape explaining less than a fifth of what remains is not worth suggesting
STEP_MARGIN = 0.1   # a step in time must explain this much more (R²) than any shape to be said
PULSE_MARGIN = 0.05 # a pulse (on, then off) must explain this much more (R²) than a step or a drift to be said
STEP_Z = 3.0        # a step in time or a shape must span this many of the disturbance's (median) std
SAME = 0.999        # |correlation| along the trajectory at which a shape is a candidate already tried
PERIODS = np.geomspace(3, 40, 25)   # cycles over a state's range: a road's grade every 400 m of 3 km


def _shapes(name: str, x: np.ndarray, d: np.ndarray, w: np.ndarray):
    """(formula, values) of each shape of feature ``name`` (a state or an input, not |x|); the
    periodic ones at PERIODS, each at the phase that fits ``d`` best (weights ``w``)."""
    s = float(np.std(x)) or 1.0
    yield name, x
    yield f"{name}*abs({name})", x * np.abs(x)
    yield f"{name}**3", x ** 3
    yield f"tanh({name}/{_num(0.05 * s)})", np.tanh(x / (0.05 * s))
    span = float(np.ptp(x)) or 1.0
    grid = list(span / PERIODS)
    fits = [_periodic(x, d, w, L) for L in grid]
    k = int(np.argmax([r2 for r2, _ in fits]))             # the best, refined between its neighbours
    lo, hi = grid[min(k + 1, len(grid) - 1)], grid[max(k - 1, 0)]
    best = minimize_scalar(lambda logL: -_periodic(x, d, w, np.exp(logL))[0], bounds=(np.log(lo), np.log(hi)),
                           method="bounded", options={"xatol": 1e-4})
    grid.append(float(np.exp(best.x)))
    fits.append(_periodic(x, d, w, grid[-1]))
    for L, (_, phase) in zip(grid, fits):
        shift = f" {'+' if phase > 0 else '-'} {_num(abs(phase))}" if phase else ""
        yield f"sin(2*pi*{name}/{_num(L)}{shift})", np.sin(2 * np.pi * x / L + phase)


def _periodic(x: np.ndarray, d: np.ndarray, w: np.ndarray, L: float) -> tuple[float, float]:
    """(weighted R², phase φ) of the best sin(2πx/L + φ) with an intercept for ``d``."""
    arg = 2 * np.pi * x / L
    r2, (_, a, b) = _r2(d, w, np.column_stack([np.sin(arg), np.cos(arg)]))
    return r2, float(np.arctan2(b, a))


def _step(t: np.ndarray, d: np.ndarray, sd: np.ndarray, w: np.ndarray, n: int = 40) -> tuple[float, float]:
    """(R², time): the best single step in time for ``d``: breakpoints at n quantiles from 5 % to
    95 % of the recording, then at every sample between the best one's neighbours. A step the
    smoother does not resolve (:func:`_resolved`) has R² −inf (0.56 for a step of 2·10⁻⁷ against a
    std of 9·10⁻⁴ on a pitch rate: "the system changed" was said of a time-invariant aircraft)."""
    grid = np.quantile(t, np.linspace(0.05, 0.95, n))

    def score(at):
        phi = (t > at).astype(float)
        r2, coef = _r2(d, w, phi)
        return (r2 if _resolved(coef, phi, sd) else -np.inf), float(at)
    best = max(map(score, grid))
    return max([best, *map(score, _between(t, grid, best[1]))])


def _between(t: np.ndarray, grid: np.ndarray, at: float) -> np.ndarray:
    """The samples of ``t`` strictly between the grid points either side of ``at``, a grid point."""
    k = int(np.searchsorted(grid, at))
    return t[(t > grid[max(k - 1, 0)]) & (t < grid[min(k + 1, len(grid) - 1)])]


def _pulse(t: np.ndarray, d: np.ndarray, sd: np.ndarray, w: np.ndarray, n: int = 40) -> tuple[float, tuple]:
    """(R², (on, off)): the best single pulse in time for ``d``, on and off at two of n quantiles from
    5 % to 95 % of the recording, each then refined to every sample between its neighbours; R² −inf
    where it is not resolved. A speed loop under a 15 rad/s² load from 14 to 26 s of 40 was told to
    try a sine of its PRBS input (R² 0.30)."""
    grid = np.quantile(t, np.linspace(0.05, 0.95, n))

    def score(a, b):
        phi = ((t > a) & (t <= b)).astype(float)
        r2, coef = _r2(d, w, phi)
        return (r2 if _resolved(coef, phi, sd) else -np.inf), (float(a), float(b))
    best = max((score(a, b) for i, a in enumerate(grid) for b in grid[i + 1:]), key=lambda s: s[0])
    for end in (0, 1):                       # each end to the sample, the other held
        near = _between(t, grid, best[1][end])
        near = near[np.unique(np.linspace(0, len(near) - 1, min(len(near), 4 * n)).astype(int))] if len(near) else near
        best = max([best, *(score(*((x, best[1][1]) if end == 0 else (best[1][0], x))) for x in near
                            if (x < best[1][1] if end == 0 else x > best[1][0]))], key=lambda s: s[0])
    return best


def _ramp(t: np.ndarray, d: np.ndarray, sd: np.ndarray, w: np.ndarray) -> tuple[float, float]:
    """(R², slope per s): a straight line in time for ``d``, R² −inf where it is not resolved (a
    sensor's bias drifting 1 K over 2 h was read as a step at 4197 s, R² 0.73: "the system changed")."""
    r2, coef = _r2(d, w, t)
    return (r2 if _resolved(coef, t, sd) else -np.inf), float(coef[1])


def _resolved(coef: np.ndarray, phi: np.ndarray, sd: np.ndarray) -> bool:
    """Whether the shape fitted (``coef`` on ``phi``) spans STEP_Z of the disturbance's median std:
    the R² of a disturbance within its band is that of its noise."""
    return abs(coef[1]) * float(np.ptp(phi)) >= STEP_Z * float(np.median(sd))


def _r2(d: np.ndarray, w: np.ndarray, phi: np.ndarray) -> tuple[float, np.ndarray]:
    """(weighted R², [intercept, coefficients]) of ``d`` on the shape(s) ``phi`` (one or columns)."""
    A = np.column_stack([np.ones(len(d)), phi]) * np.sqrt(w)[:, None]
    b = d * np.sqrt(w)
    coef, *_ = np.linalg.lstsq(A, b, rcond=None)
    res = b - A @ coef
    tot = b - np.sqrt(w) * np.average(d, weights=w)
    return float(1 - res @ res / max(tot @ tot, 1e-300)), coef


def _tried(model, rec, states, eq: str, tried) -> list[tuple[str, np.ndarray]]:
    """(effect, values along the trajectory) of the candidates ``tried`` on equation ``eq``."""
    from .name import basis_values
    mine = [c for c in tried or () if c.equation == eq]
    if not mine:
        return []
    try:
        values = basis_values(model, rec, states, mine)
    except (RuntimeError, ValueError):      # a candidate the corrected model cannot evaluate
        return []
    return [(c.effect, v) for c, v in zip(mine, values) if np.all(np.isfinite(v)) and np.std(v) > 0]


def _already(phi: np.ndarray, tried) -> str | None:
    """The effect of a tried candidate with the shape ``phi`` along the trajectory, or None."""
    for effect, v in tried:
        if abs(np.corrcoef(phi, v)[0, 1]) >= SAME:
            return effect
    return None


def explain(model, rec, loc: Location, out_dir=None, names=None, tried=None, confirm=None) -> dict:
    """{"explained_by", "r2", "suggested_candidate"[, "figure"]} for the first located equation;
    ``names``: the states and inputs a suggestion may use (the user's model's: a corrected model's
    own states, an actuator's lag, are not the user's to write a candidate in); ``tried``: the
    additive candidates the diagnosis tried, whose shapes are not suggested again; ``confirm``:
    called where a step in time explains the disturbance best, {} where the innovations do not
    confirm a change (:func:`~skigen.diagnose.detect.relation_break`): the smoothed disturbance is
    slow, and a time-invariant misfit that grows where the states go late in a recording steps in
    it too (a tank's unmodelled √h leak read "the system changed at t = 1071 s", R² 0.91)."""
    eq = loc.equations[0]
    d, sd = loc.disturbance[eq]
    w = 1.0 / np.maximum(sd, 1e-12 * (np.abs(d).max() + 1e-300)) ** 2
    w = w / w.mean()
    known = _tried(model, rec, loc.states, eq, tried)
    best = closest = (-np.inf, None, None, None, None)
    catalog = None
    for name, (x, _) in features(model, rec, loc.states).items():
        if name.startswith("|") or np.ptp(x) == 0 or (names is not None and name not in names):
            continue
        for formula, phi in _shapes(name, x, d, w):
            r2, coef = _r2(d, w, phi)
            if not _resolved(coef, phi, sd):
                continue
            if r2 > closest[0]:
                closest, catalog = (r2, name, formula, phi, coef), _already(phi, known)
            if r2 > best[0] and not _already(phi, known):
                best = (r2, name, formula, phi, coef)
    said = {}
    step_r2, at = _step(rec.t, d, sd, w) if rec is not None else (-np.inf, 0.0)
    ramp_r2, rate = _ramp(rec.t, d, sd, w) if rec is not None else (-np.inf, 0.0)
    pulse_r2, (on, off) = _pulse(rec.t, d, sd, w) if rec is not None else (-np.inf, (0.0, 0.0))
    pulse = pulse_r2 > max(step_r2, ramp_r2) + PULSE_MARGIN    # one number more than a step's: by a margin
    drift = not pulse and ramp_r2 >= step_r2                     # a straight line in time, one fewer
    timed = max(step_r2, ramp_r2, pulse_r2 if pulse else -np.inf)
    what = ("a drift in time" if drift else f"a pulse from t = {on:.4g} to {off:.4g} s" if pulse
            else f"a step at t = {at:.4g} s")
    if timed >= HINT_R2 and timed > max(best[0], closest[0]) + STEP_MARGIN and confirm is not None \
            and not confirm():
        said["unconfirmed_step"] = (f"{what} explains the disturbance in {eq} best (R² {timed:.2g}), but the "
                                    f"innovations follow the states and inputs as before it: not said as a "
                                    f"change (a misfit that grows where the states go late in the recording)")
    elif timed >= HINT_R2 and timed > max(best[0], closest[0]) + STEP_MARGIN:    # the system changed
        shape = f"the best shape of a state or input, {closest[2]}, {closest[0]:.2g}" if closest[2] else \
            "no shape of a state or input spans its band"
        if pulse:
            return {"explained_by": None, "r2": None, "suggested_candidate": None, "changes_at": on, "changes_back": off,
                    "note": f"what remains in {eq} acts only from t = {on:.4g} to {off:.4g} s: a pulse in time explains "
                            f"it best (R² {pulse_r2:.2g}; the best step {step_r2:.2g}; {shape}): something acted only "
                            f"then (a payload picked up and dropped, a fault that cleared); diagnose the stretches "
                            f"before, during and after it apart"}
        if drift:
            return {"explained_by": None, "r2": None, "suggested_candidate": None, "drifts": rate,
                    "note": f"what remains in {eq} drifts over time: a straight line in time explains it best (R² "
                            f"{ramp_r2:.2g}; the best step {step_r2:.2g}; {shape}): something "
                            f"drifts during the recording (a sensor's bias or gain warming up, wear, a leak), or "
                            f"a state slower than the recording that the model lacks (a second time constant), "
                            f"not a shape of the states and inputs; the catalog has neither, and the findings "
                            f"may stand for it"}
        return {"explained_by": None, "r2": None, "suggested_candidate": None, "changes_at": at,
                "note": f"what remains in {eq} changes over time: a step at t = {at:.4g} s explains it best (R² "
                        f"{step_r2:.2g}; a drift {ramp_r2:.2g}; {shape}): the system changed during the recording "
                        f"(a battery, a payload, a failure); diagnose the stretches before and after it apart"}
    if catalog and closest[0] >= HINT_R2:
        said["tried"] = (f"what remains in {eq} follows {closest[2]} best (R² {closest[0]:.2g}), the shape of the "
                         f"{catalog} the diagnosis tried there and did not adopt")
    r2, name, formula, phi, coef = best
    if name is None:
        return {"explained_by": None, "r2": None, "suggested_candidate": None, **said}
    if r2 < HINT_R2:
        return {"explained_by": None, "r2": r2, "suggested_candidate": None, **said,
                "note": f"no shape of one state or input{' outside the candidates tried' if 'tried' in said else ''} explains "
                        f"what remains in {eq} (best: {formula}, R² {r2:.2g}): coloured noise, or dynamics of "
                        f"another order"}
    out = {"explained_by": name, "r2": r2, "shape": formula,
           "suggested_candidate": f"remaining:{eq}:{formula}", **said}
    if out_dir is not None:
        out["figure"] = str(_plot(Path(out_dir) / "remaining.png", loc, eq, features(model, rec, loc.states)[name][0],
                                  name, d, sd, phi, coef, formula))
    return out


def _plot(path: Path, loc, eq, x, name, d, sd, phi, coef, formula) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from ..plots import save_figure
    fig, ax = plt.subplots(figsize=(6.5, 4))
    ax.errorbar(x, d, yerr=2 * sd, fmt=".", ms=1.5, lw=0.2, color="tab:orange", alpha=0.4,
                label="what remains: smoothed disturbance ±2σ")
    order = np.argsort(x)
    ax.plot(x[order], coef[0] + coef[1] * phi[order], color="k", lw=1, label=f"best shape: {formula}")
    ax.set_xlabel(name)
    ax.set_ylabel(f"d{eq}/dt left unexplained")
    ax.legend(fontsize=7)
    ax.set_title(f"the corrected model still misses something in {eq}: it follows {name}")
    return save_figure(fig, path, dpi=100)
