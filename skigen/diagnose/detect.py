"""Detect: is the nominal filter consistent with the recording?

Under a right model the normalised innovations ε = e/√Pyy are zero-mean,
unit-variance and white, so (a) the summed NIS over the recording is χ² with
as many degrees of freedom as measured values, and (b) per output, the mean of
ε and its autocorrelations at lags 1…L (taken about zero, the mean the model
predicts) are small: N·ε̄² + Ljung–Box(L) is χ²(L + 1). The false-alarm rate α
is split in two: α/2 for the NIS test (two-sided, α/4 per tail) and α/2 for
whiteness (Bonferroni over the outputs). A significant mismatch is an NIS
above its upper bound or non-white innovations; an NIS *below* its lower bound
means the stated noise is larger than the data show — reported, but no
missing physics can be named from it.

On a noise-calibrated model (:func:`judge`) a third property is tested: an innovation is
uncorrelated with anything known before it (Ljung, *System Identification*, §16.6, the test of
residuals against past inputs; Billings and Voon's nonlinear correlation tests). Calibration can
widen the process noise until a missing term's error looks white — a 30 ms delay or a cubic
moment then hides in Q — but the error still follows the state and the input that cause it.
:func:`past_regressors` are the catalog's additive shapes of every state's estimate and every
input one sample back, and each input's increment (a delay, a lag); N·R² of the normalised
innovations regressed on them is χ² with as many degrees of freedom as independent regressors.
"""
from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from ..runtime import RunResult

__all__ = ["Consistency", "consistency", "normalised_innovations", "whiteness", "lags_for",
           "past_regressors", "independence"]


@dataclass
class Consistency:
    nis_mean: float
    nis_expected: float
    nis_bounds: tuple[float, float]
    nis_pvalue: float
    whiteness_pvalue: float
    lags: int
    alpha: float
    samples: int
    mismatch: bool
    outputs: list[dict] = field(default_factory=list)   # per output: name, nis_mean, whiteness_pvalue
    note: str = ""
    independence_pvalue: float | None = None   # innovations against the past (judge only)
    regressors: int = 0
    measured: int = 0                          # samples with at least one reading used

    def asdict(self) -> dict:
        """The ``consistency`` object of report.json."""
        return {"nis_mean": self.nis_mean, "nis_expected": self.nis_expected,
                "whiteness_pvalue": self.whiteness_pvalue,
                "nis_bounds": list(self.nis_bounds), "nis_pvalue": self.nis_pvalue,
                "alpha": self.alpha, "lags": self.lags, "samples": self.samples, "measured_samples": self.measured,
                "outputs": self.outputs, "note": self.note,
                **({"independence_pvalue": self.independence_pvalue, "regressors": self.regressors}
                   if self.independence_pvalue is not None else {})}


def normalised_innovations(res: RunResult) -> np.ndarray:
    """ε = e / √diag(Pyy), NaN where not measured."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return res.innovation / np.sqrt(res.innovation_var)


def lags_for(n: int) -> int:
    return int(np.clip(n // 50, 5, 20))


def whiteness(eps: np.ndarray, lags: int) -> float:
    """p-value of N·ε̄² + Ljung–Box(lags) about zero mean, χ²(lags + 1), for one output."""
    ok = np.isfinite(eps)
    x = np.where(ok, eps, 0.0)
    n = int(ok.sum())
    if n <= lags + 1:
        return 1.0
    den = float(np.dot(x, x))
    r = np.array([np.dot(x[:-l], x[l:]) for l in range(1, lags + 1)]) / den
    q = n * (n + 2) * np.sum(r ** 2 / (n - np.arange(1, lags + 1)))
    q += n * (x.sum() / n) ** 2 / max(den / n, 1e-300)
    return float(stats.chi2.sf(q, lags + 1))


def past_regressors(model, run: RunResult, inputs: np.ndarray) -> np.ndarray:
    """(N, p) functions of what the filter knew before sample k, row k: for s, each state's
    posterior mean at k − 1 and each input at k − 1 (standardised over the recording), the
    catalog's additive shapes s, s·|s|, s³ and tanh(3s) (linear, drag, cubic, Coulomb); and each
    input's increment u[k−1] − u[k−2]. Row 0 is NaN."""
    cols = []
    for s in _signals(model, run, inputs):
        s = (s - np.nanmean(s)) / (np.nanstd(s) or 1.0)
        cols += [s, s * np.abs(s), s ** 3, np.tanh(3 * s)]
    cols += [np.r_[0.0, np.diff(u)] for u in inputs.T]
    Z = np.column_stack(cols)
    return np.vstack([np.full(Z.shape[1], np.nan), Z[:-1]])


def _signals(model, run: RunResult, inputs: np.ndarray) -> list[np.ndarray]:
    """Each state's posterior mean and each input, in the model's order (states, then inputs)."""
    return [run.mean[:, i] for i in range(len(model.states))] + list(np.asarray(inputs).T)


def _pieces(s: np.ndarray, knots: int) -> np.ndarray:
    """(N, knots − 1) piecewise-linear functions of ``s`` (hats at its quantiles, the first left
    out: the intercept spans it)."""
    at = np.unique(np.quantile(s, np.linspace(0, 1, knots)))
    return np.column_stack([np.interp(s, at, np.eye(len(at))[j]) for j in range(1, len(at))]) if len(at) > 1 \
        else np.zeros((len(s), 0))                      # a constant signal: nothing beyond the intercept


def _residual_ss(e: np.ndarray, X: np.ndarray) -> tuple[float, int]:
    """(residual sum of squares, rank) of ``e`` regressed on the columns of ``X``."""
    q = _basis(X)
    return float(e @ e - np.sum((q.T @ e) ** 2)), q.shape[1]


BREAKS = 57          # candidate times of a change, evenly in the recording's samples
BREAK_TRIM = 0.15    # ... between 15 % and 85 % of them (Andrews 1993): a stretch must have data
MOVES = 0.1          # a change is said where it moves how the innovations follow the past by this share of it


def relation_break(model, rec, run: RunResult, alpha: float) -> dict:
    """{"changes_at", "note", "break"} where how an output's innovations follow the past changes
    at one time: Chow's F of the regression on :func:`past_regressors` (with an intercept) split at
    t, at BREAKS times, Bonferroni over them and the outputs. A gain that drops partway (an
    elevator 20 % weaker from 50 s of 80) is fitted as its average, and what it leaves follows the
    input with one sign before and the other after, which a slowly varying disturbance cannot
    follow. A time-invariant misfit also splits where the excitation changes (a detent on an arm
    driven by a chirp: p = 0.008 at 25 s), so the split is tested beyond a time-invariant
    alternative as large as itself: piecewise-linear functions of each state and input with as many
    new columns in all as the split adds (then 2.1, and 5·10⁻¹⁸ for the elevator). The signal whose
    split alone gains most names where.

    {} when no change is significant; where it moves how the innovations follow the past by less
    than MOVES of how they follow it throughout (its share of their variance below MOVES² of that
    relation's): a misfit's best fit moves that little with the excitation and the sample, and a
    change so small cannot be what the findings stand for (Silverbox's 65 062 samples split at
    98.6 s with p = 10⁻⁵: a share of 0.05 % beside 46 % followed throughout, a move of 3 %; a
    servo's gain drop: 29 % beside 4 %).

    {"relation_drifts", "note"} where a straight line in time of the relation explains it as well
    as the best split (as many columns): a mass falling as fuel burns was "changes at 34.5 s".
    {"relation_moves", "note"} where, beyond that first change, the relation splits again
    (Bonferroni over the times): F treats the innovations as independent, and where they follow
    each other (a tachometer behind a lag the model lacks: lag-one correlation 0.89) any split is
    'significant' (that one at 10, 23.5 or 27 s by the seed, p = 10⁻¹¹¹) and so is a second; a
    system that changes throughout does the same. Neither is said as a change in time."""
    eps, Z = normalised_innovations(run), past_regressors(model, run, rec.inputs)
    signals = list(model.state_names) + list(model.input_names)
    past = [np.r_[np.nan, s[:-1]] for s in _signals(model, run, rec.inputs)]
    knots = -(-(Z.shape[1] + 1) // len(signals)) + 2
    group = np.r_[np.repeat(np.arange(len(signals)), 4), len(model.state_names) + np.arange(len(model.input_names))]
    best, tests = None, BREAKS * len(model.output_names)
    for i, name in enumerate(model.output_names):
        ok = np.isfinite(eps[:, i]) & np.all(np.isfinite(Z), axis=1)
        X = np.column_stack([np.ones(int(ok.sum())), Z[ok]])
        alt = np.column_stack([X, *(_pieces(s[ok], knots) for s in past)])
        split = _best_split(eps[ok, i], X, alt, rec.t[ok])
        if split and (best is None or split.rank < best.rank):
            best = dataclasses.replace(split, output=name, raw=eps[ok, i], X=X, alt=alt, t=rec.t[ok])
    if best is None or best.rank[0] + np.log(tests) >= np.log(alpha):
        return {}
    after = (best.t > best.at)[:, None]
    total = float(np.sum((best.raw - best.raw.mean()) ** 2))
    stepped = _residual_ss(best.e, best.out(best.X * after))[0]
    change = (float(best.e @ best.e) - stepped) / total
    throughout = 1.0 - _residual_ss(best.raw, best.X)[0] / total
    if change < MOVES ** 2 * throughout:
        return {}
    span = (best.t - best.t.mean()) / np.ptp(best.t)
    drifted, drift_dof = _residual_ss(best.e, best.out(best.X * span[:, None]))
    drift = drifted <= stepped
    first = best.X * (span[:, None] if drift else after)
    again = _best_split(best.raw, best.X, np.column_stack([best.alt, first]), best.t)
    if again and again.rank[0] + np.log(BREAKS) < np.log(alpha):
        times = sorted({best.at, again.at}) if not drift else [again.at]
        how = ("a drift, then a change at " if drift else "changes at ") + " and ".join(f"{a:.4g}" for a in times)
        return {"relation_moves": {"output": best.output, "at": times, "drift": drift, "share": change,
                                   "share_throughout": throughout},
                "note": f"how the innovations of {best.output} follow the states and inputs moves throughout the "
                        f"recording ({how} s, each significant beyond the other): not one change. Innovations that "
                        f"follow each other in time (a misfit slower than a sample: a sensor's lag, a drift) do this, "
                        f"as does a system that changes throughout"}
    e, X, out = best.e, best.X, best.out
    most = min(signals, key=lambda g: _residual_ss(e, out(first[:, 1:][:, group == signals.index(g)]))[0])
    if drift:
        rss, dof = drifted, drift_dof
        F = (float(e @ e) - rss) / dof / (rss / (len(e) - best.alt.shape[1] - dof))
        p = min(1.0, float(stats.f.sf(F, dof, len(e) - best.alt.shape[1] - dof)) * len(model.output_names))
        note = (f"how the innovations of {best.output} follow the states and inputs drifts over the recording, most in "
                f"how they follow {most}: a straight line in time of that relation explains it as well as any one "
                f"change (F = {F:.3g} on {dof} regressors, p = {p:.2g}): the system changes gradually during the "
                f"recording (fuel burning, a battery draining, heating, wear), and the findings fit its average")
        return {"relation_drifts": {"output": best.output, "F": float(F), "dof": int(dof), "pvalue": p, "signal": most,
                                    "share": change, "share_throughout": throughout}, "note": note}
    p = min(1.0, float(np.exp(best.rank[0])) * tests)
    note = (f"how the innovations of {best.output} follow the states and inputs changes at t = {best.at:.4g} s, most "
            f"in how they follow {most} (Chow's F = {best.F:.3g} on {best.dof} regressors beyond a time-invariant "
            f"alternative as large, p = {p:.2g} over {BREAKS} times and the outputs): the system changed during the "
            f"recording (a gain, a friction, a failure); diagnose the stretches before and after it apart")
    return {"changes_at": best.at, "note": note,
            "break": {"output": best.output, "at": best.at, "F": best.F, "dof": best.dof, "pvalue": p,
                      "signal": most, "share": change, "share_throughout": throughout}}


@dataclass(frozen=True)
class _Split:
    rank: tuple          # (log p, −F): a large change's p underflows, even in logs
    at: float            # s: the relation differs after this time
    F: float
    dof: int
    e: np.ndarray        # the innovations beyond the time-invariant alternative
    out: object          # M ↦ M beyond that alternative
    output: str = ""
    raw: np.ndarray = None
    X: np.ndarray = None
    alt: np.ndarray = None
    t: np.ndarray = None


def _best_split(eps: np.ndarray, X: np.ndarray, alt: np.ndarray, t: np.ndarray) -> _Split | None:
    """The time among BREAKS (within BREAK_TRIM of either end) where splitting the regression of
    ``eps`` on ``X`` gains most beyond ``alt``; None on too few samples."""
    q = _basis(alt)
    if len(t) < 4 * (q.shape[1] + X.shape[1]):
        return None
    out = lambda M: M - q @ (q.T @ M)
    e, best = out(eps), None
    for at in t[np.linspace(BREAK_TRIM * len(t), (1 - BREAK_TRIM) * len(t), BREAKS).astype(int)]:
        rss, dof = _residual_ss(e, out(X * (t > at)[:, None]))
        rest = len(t) - q.shape[1] - dof
        if dof and rss > 0:
            F = (float(e @ e) - rss) / dof / (rss / rest)
            rank = (float(stats.f.logsf(F, dof, rest)), -F)
            if best is None or rank < best.rank:
                best = _Split(rank, float(at), float(F), int(dof), e, out)
    return best


def _basis(X: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the columns of ``X`` (rank-revealing by QR's diagonal)."""
    q, r = np.linalg.qr(X)
    d = np.abs(np.diag(r))
    return q[:, d > 1e-8 * max(d.max(), 1e-300)]


def independence(eps: np.ndarray, Z: np.ndarray) -> tuple[float, int]:
    """(p-value, degrees of freedom) of N·R² of one output's normalised innovations regressed on
    ``Z`` (columns centred, about zero mean), χ²(rank Z), where both are finite."""
    ok = np.isfinite(eps) & np.all(np.isfinite(Z), axis=1)
    if ok.sum() <= 2 * Z.shape[1]:
        return 1.0, 0
    e, z = eps[ok], Z[ok] - Z[ok].mean(axis=0)
    q = _basis(z)
    stat = len(e) * float(np.sum((q.T @ e) ** 2)) / max(float(np.dot(e, e)), 1e-300)
    return float(stats.chi2.sf(stat, q.shape[1])), q.shape[1]


PEAK_NEIGHBOURS = 20   # frequencies each side whose mean sets the local spectral level


def periodic(eps: np.ndarray, dt: float) -> tuple[float, float, float]:
    """(period in s, p-value, share of the variance) of the strongest spectral line of one output's
    normalised innovations, against the local level of their spectrum (an ordinate over the mean of
    the PEAK_NEIGHBOURS each side, F(2, 4·PEAK_NEIGHBOURS) where the spectrum is smooth there),
    Bonferroni over the frequencies; periods of three cycles at least over the recording. A
    mismatch's innovations are coloured, so the white-noise null of Fisher's test would call any
    slow drift periodic; a line stands above its neighbours."""
    e = np.where(np.isfinite(eps), eps, 0.0)
    e = e - e.mean()
    n = len(e)
    power = np.abs(np.fft.rfft(e)) ** 2
    k = np.arange(len(power))
    usable = np.flatnonzero((k >= 3) & (k < len(power) - 1))
    if len(usable) < 2 * PEAK_NEIGHBOURS + 1 or not power[usable].sum() > 0:
        return float("nan"), 1.0, 0.0
    around = [np.r_[power[max(j - PEAK_NEIGHBOURS, 1):j - 1], power[j + 2:j + PEAK_NEIGHBOURS + 1]] for j in usable]
    ratio = power[usable] / np.maximum([a.mean() for a in around], 1e-300)
    i = int(np.argmax(ratio))
    j = usable[i]
    share = float(power[j - 1:j + 2].sum() / power[1:].sum())        # the line and its two neighbours
    p = stats.f.sf(ratio[i], 2, 2 * len(around[i]))                  # an ordinate over its neighbours' mean
    return float(n * dt / j), float(min(1.0, len(usable) * p)), share


def consistency(res: RunResult, output_names, alpha: float = 0.01) -> Consistency:
    """The two tests on a nominal run (see the module docstring)."""
    eps = normalised_innovations(res)
    valid = np.isfinite(eps)
    dof = int(valid.sum())
    N = len(res.t)
    nis_sum = float(np.nansum(res.nis))
    lo, hi = stats.chi2.ppf([alpha / 4, 1 - alpha / 4], dof)
    cdf = stats.chi2.cdf(nis_sum, dof)
    p_nis = float(min(1.0, 2 * min(cdf, stats.chi2.sf(nis_sum, dof))))
    lags = lags_for(N)
    per = []
    for i, name in enumerate(output_names):
        p = whiteness(eps[:, i], lags)
        per.append({"name": name, "nis_mean": float(np.nanmean(eps[:, i] ** 2)), "whiteness_pvalue": p,
                    "innovation_mean": float(np.nanmean(eps[:, i]))})
    p_white = float(min(1.0, len(per) * min(o["whiteness_pvalue"] for o in per)))
    too_big = nis_sum > hi
    too_small = nis_sum < lo
    mismatch = bool(too_big or p_white < alpha / 2)
    note = ""
    if too_small and not mismatch:
        note = ("NIS below its lower bound: the model states more noise than the data show "
                "(a noise-tuning issue, not missing physics)")
    return Consistency(nis_sum / N, dof / N, (lo / N, hi / N), p_nis, p_white, lags, alpha, N, mismatch, per, note,
                       measured=int(valid.any(axis=1).sum()))


TESTS = 3     # whiteness, independence of the past, slowly varying disturbance: α/3 each


@dataclass
class Verdict:
    """The decision on a calibrated model: its consistency, the disturbance test, the verdict."""

    consistency: Consistency
    gains: dict                 # equation → log-likelihood gain of a random-walk disturbance
    threshold: float
    tested: tuple               # (gains, steps, scales) for :func:`locate`
    mismatch: bool


def judge(model, rec, run: RunResult, equations, alpha: float = 0.01) -> Verdict:
    """Mismatch on a noise-calibrated model, α split in three: its innovations are not white
    (Bonferroni over the outputs), they follow the past (:func:`independence`, Bonferroni over the
    outputs), or a slowly varying disturbance on some equation buys significant likelihood
    (Bonferroni over the equations). The NIS is reported but not tested: calibration makes its
    mean match by construction."""
    from .locate import disturbance_gains, disturbance_threshold
    cons = consistency(run, model.output_names, alpha)
    eps, Z = normalised_innovations(run), past_regressors(model, run, rec.inputs)
    for i, o in enumerate(cons.outputs):
        o["independence_pvalue"], cons.regressors = independence(eps[:, i], Z)
    cons.independence_pvalue = float(min(1.0, len(cons.outputs) * min(o["independence_pvalue"] for o in cons.outputs)))
    tested = disturbance_gains(model, rec, run, equations)
    threshold = disturbance_threshold(alpha / TESTS, len(equations))
    white = cons.whiteness_pvalue >= alpha / TESTS
    free = cons.independence_pvalue >= alpha / TESTS
    drift = max(tested[0].values(), default=-np.inf) > threshold
    cons.mismatch = bool(not white or not free or drift)
    cons.note = ("judged on the calibrated model: "
                 + ("innovations not white" if not white else "innovations white")
                 + ("; they follow the state or input before them" if not free else "; uncorrelated with the past")
                 + ("; a slowly varying disturbance is significant" if drift else "; no significant slowly varying disturbance"))
    return Verdict(cons, {k: float(v) for k, v in tested[0].items()}, float(threshold), tested, cons.mismatch)


def remaining(model, rec, run: RunResult, equations, alpha: float, out_dir=None, names=None, tried=None) -> dict:
    """After correction: is the corrected (refitted, noise-calibrated) model consistent? If not,
    where, in which regime, the state or input that best explains what is left (a figure), and a
    candidate to try (in ``names``, the user's states and inputs; not one of ``tried``)."""
    from .locate import locate
    from .suggest import explain
    v = judge(model, rec, run, equations, alpha)
    out = {"mismatch": v.mismatch, "whiteness_pvalue": v.consistency.whiteness_pvalue,
           "independence_pvalue": v.consistency.independence_pvalue,
           "disturbance_gain": v.gains, "disturbance_threshold": v.threshold, "where": None}
    if not v.mismatch:
        return out
    loc = locate(model, rec, run, v.consistency, alpha, equations=equations, tested=v.tested)
    out["where"] = {"equations": loc.equations, "windows": [[float(a), float(b)] for a, b in loc.windows],
                    "regime": loc.regime}
    changed = functools.cache(lambda: relation_break(model, rec, run, alpha))
    out.update(explain(model, rec, loc, out_dir, names, tried, confirm=changed))
    return out | unexplained(out, model, rec, run, alpha, changed)


def timed(said: dict) -> bool:
    """Whether what remains was said to change in time (a step, a drift; :func:`~skigen.diagnose.suggest.explain`)."""
    return said.get("changes_at") is not None or drifting(said)


def drifting(said: dict) -> bool:
    """Whether what remains was said to drift in time (its disturbance, or how the innovations follow the past)."""
    return said.get("drifts") is not None or said.get("relation_drifts") is not None


def unexplained(said: dict, model, rec, run: RunResult, alpha: float, changed=None) -> dict:
    """Where no shape of a state or input explains what remains, nor a step in time: a change in
    how the innovations follow the past (:func:`relation_break`, or ``changed()`` where the step's
    confirmation computed it already), else a spectral line (:func:`periodic_line`); {} otherwise."""
    if said.get("explained_by") or timed(said):
        return {}
    return ((changed or (lambda: relation_break(model, rec, run, alpha)))()
            or periodic_line(said, run, model.output_names, model.dt, alpha))


def periodic_line(said: dict, run: RunResult, outputs, dt: float, alpha: float) -> dict:
    """{"periodic": {output, period, pvalue, share, note}} where what remains has no shape of a
    state or input (nor a step in time) and an output's innovations carry a spectral line
    (:func:`periodic`, at α over the outputs): a disturbance periodic in time the model has no
    input for (waves at 9 s on a ship's yaw left "a mismatch remains" and nothing else); {}
    otherwise."""
    if said.get("explained_by") or timed(said):
        return {}
    eps = normalised_innovations(run)
    lines = [(name, *periodic(eps[:, i], dt)) for i, name in enumerate(outputs)]
    lines = [x for x in lines if x[2] < alpha / len(outputs)]
    if not lines:
        return {}
    name, period, p, share = max(lines, key=lambda x: x[3])
    note = (f"the innovations of {name} carry a line at a period of {period:.3g} s ({1 / period:.3g} Hz; "
            f"{100 * share:.2g} % of their variance, p = {p:.2g} against their spectrum's local level): a disturbance "
            f"periodic in time the model has no input for (waves, a vibration, an imbalance, mains hum at 50 or "
            f"60 Hz), or an oscillation it misses")
    return {"periodic": {"output": name, "period": period, "pvalue": p, "share": share, "note": note}}
