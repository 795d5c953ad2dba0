"""Run a derived filter over a recording: in Python, through the generated C, or chained by CasADi.

The ``python`` and ``c`` backends step with the same guards and recovery policy
(those of the generated C, :mod:`skigen.guard`): a non-finite input is held at its
last finite value and that sample's readings are not used, a non-finite or stuck
measurement skips its update, an outlier fails the innovation gate and is not used,
a step whose result is not finite is rejected (prior kept), and after a run of
rejections, or at a reading rejected after a long gap, the physical states restart
from the measurement. A run never stops on bad data:
its summary reports these events.

The ``casadi`` backend (:class:`CasadiStepper`) chains the same derived step over
the recording by CasADi (``mapaccum``, 1024 samples a call): about 15× faster than
``python`` and without ``c``'s compile time. It runs the step *without* the
policy — no gate, no stuck-sensor test, no restart after rejections or a gap, no
bound on the prior std — so its innovations are the filter's own (what the
diagnosis scores); where nothing fails it equals ``python`` with
:meth:`Guard.off`. A part in which a step gives a non-finite number is redone by
the Python stepper with the default :class:`Guard`; a part in which an input is
not finite (an input hole) with :meth:`Guard.off`, whose bad-input rule a chain
cannot take.
The restarts after an input hole, the parts and the result are those of the
other backends.
"""
from __future__ import annotations

import copy
import hashlib
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from time import perf_counter

import numpy as np
from scipy import stats

from .derive import DerivedFilter, step_inputs
from .failure import explain, nearer, sigma_reach
from .emit.c import Status
from .grid import clock, first_known
from .guard import Guard, bound_std, reinit
from .model import Model
from .progress import note, progress
from .recording import Recording, write_table

__all__ = ["RunResult", "RunSummary", "Trace", "PythonStepper", "CasadiStepper", "Guard", "run", "iter_run",
           "iter_run_stream", "check_columns", "BACKENDS",
           "Status", "STATUS_WORDS"]

SLOW_DERIVATION_N = 80      # above this augmented-state size the symbolic step takes seconds: say so


STATUS_WORDS = ("measured", "partial", "predicted", "bad_input", "rejected", "gated", "stuck", "recovered")
_CODE_WORD = {Status.BAD_INPUT: 3, Status.NUMERICAL_FAILURE: 4, Status.OUTLIER_REJECTED: 5,
              Status.SENSOR_STUCK: 6, Status.REINITIALISED: 7}


def status_words(code: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """The step's status per sample: measured (every output), partial (some), predicted (none
    measured), bad_input (a non-finite input: predicted with its last finite value), rejected
    (non-finite result: prior kept),
    gated (an outlier not used), stuck (a stuck reading not used), recovered (states restarted)."""
    any_ = measured.any(axis=1) if measured.size else np.zeros(len(code), bool)
    i = np.where(code == Status.OK, 0, np.where(any_, 1, 2))
    for c, word in _CODE_WORD.items():
        i = np.where(code == c, word, i)
    return np.array(STATUS_WORDS, dtype=object)[i]


@dataclass
class Trace:
    """What a smoother or a restart needs besides the :class:`RunResult` (``run(..., trace=True)``):
    per sample k, the posterior covariance, the prior for k + 1 and the input memory used at k."""

    C_post: np.ndarray   # (N, n, n) covariance (EKF) or Cholesky factor (UKF, SKI)
    z_next: np.ndarray   # (N, n)
    C_next: np.ndarray   # (N, n, n)
    mem: np.ndarray      # (N, nmem)

    @classmethod
    def concat(cls, parts: list["Trace"]) -> "Trace":
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("C_post", "z_next", "C_next", "mem")))


@dataclass
class RunResult:
    """Per-sample filter output. Arrays have one row per sample of the model's grid."""

    filter: DerivedFilter
    t: np.ndarray
    mean: np.ndarray          # (N, n) posterior mean of z = [x; w]
    std: np.ndarray           # (N, n) posterior standard deviation
    innovation: np.ndarray    # (N, ny), NaN where not measured
    innovation_var: np.ndarray  # (N, ny) diagonal of Pyy, NaN where not measured
    nis: np.ndarray           # (N,), NaN when nothing was measured
    loglik: np.ndarray        # (N,)
    prior_var: np.ndarray     # (N, nw) ARD prior variances (SKI), else empty
    code: np.ndarray          # (N,) Status per sample
    final_cov: np.ndarray     # (n, n) last posterior covariance
    measured: np.ndarray | None = None   # (N, ny) True where the output was measured
    holes: tuple = ()         # grid.Hole of the recording
    notes: tuple = ()         # what reading the recording decided
    trace: Trace | None = None   # with run(..., trace=True)
    next_prior: tuple | None = None   # (z, C): the prior for the sample after the last (C as in Trace)
    gate: float = Guard.gate  # the innovation gate the run had, in std (0: none, as on the casadi backend)
    failure: str | None = None   # where the model is not finite at the first failed step (failure.explain)
    held: np.ndarray | None = None   # (N, n) True where the prior std was held at Guard's std_max (python, c)

    def __post_init__(self):
        if self.measured is None:
            self.measured = np.isfinite(self.innovation)

    @property
    def names(self) -> list[str]:
        return self.filter.aug.names

    @property
    def weights(self) -> np.ndarray:
        return self.mean[:, self.filter.aug.w_index]

    @property
    def weight_std(self) -> np.ndarray:
        return self.std[:, self.filter.aug.w_index]

    def columns(self) -> dict[str, np.ndarray]:
        """The run-result table of the contract (design.md), in order."""
        aug = self.filter.aug
        outs = aug.model.output_names
        cols = {"t": self.t}
        cols.update({n: self.mean[:, i] for i, n in enumerate(self.names)})
        cols.update({f"std_{n}": self.std[:, i] for i, n in enumerate(self.names)})
        cols.update({f"innov_{n}": self.innovation[:, i] for i, n in enumerate(outs)})
        cols.update(nis=self.nis, loglik=self.loglik, status=status_words(self.code, self.measured))
        cols.update({f"measured_{n}": self.measured[:, i].astype(np.int8) for i, n in enumerate(outs)})
        w_names = [self.names[i] for i in aug.w_index]
        cols.update({f"prior_var_{n}": self.prior_var[:, i] for i, n in enumerate(w_names)}
                    if self.prior_var.size else {})
        return cols

    def to_frame(self):
        """The result table as a pandas DataFrame (columns as in the result CSV)."""
        import pandas as pd
        return pd.DataFrame(self.columns())

    def write(self, path) -> None:
        write_table(path, self.columns())

    def summary(self) -> "RunSummary":
        return RunSummary(self.filter).add(self)

    @classmethod
    def concat(cls, parts: list["RunResult"]) -> "RunResult":
        """One result from consecutive parts of a run."""
        first, last = parts[0], parts[-1]
        cat = lambda name: np.concatenate([getattr(p, name) for p in parts])
        return cls(first.filter, cat("t"), cat("mean"), cat("std"), cat("innovation"), cat("innovation_var"),
                   cat("nis"), cat("loglik"), cat("prior_var"), cat("code"), last.final_cov, cat("measured"),
                   first.holes, first.notes,
                   Trace.concat([p.trace for p in parts]) if first.trace is not None else None, last.next_prior,
                   first.gate, next((p.failure for p in parts if p.failure), None),
                   cat("held") if all(p.held is not None for p in parts) else None)


EVENT_WORDS = {Status.OUTLIER_REJECTED: "gated (outlier not used)", Status.SENSOR_STUCK: "stuck reading",
               Status.BAD_INPUT: "bad input", Status.NUMERICAL_FAILURE: "rejected (non-finite)",
               Status.REINITIALISED: "recovered (states restarted)"}
EVENTS = tuple(EVENT_WORDS)         # the codes a run summary counts


class RunSummary:
    """What a run says at its end, gathered part by part: the weights' final values ± 2σ (SKI:
    which terms are kept), the holes, and the mean NIS against its expectation given the
    outputs actually measured (a consistent filter's NIS averages the number measured)."""

    KEEP = 0.01     # SKI keeps a term whose ARD prior std, relative to the declared one, is ≥ 1 % of the largest

    def __init__(self, filt: DerivedFilter):
        self.filter, self.samples, self.with_measurement = filt, 0, 0
        self.nis_sum, self.nis_count, self.expected_sum, self.last, self.t = 0.0, 0, 0.0, None, [np.nan, np.nan]
        self.holes, self.notes = (), ()
        self.events = {c: 0 for c in EVENTS}
        self.first = {c: None for c in EVENTS}       # the time of each event's first sample (s)
        self.per_output = np.zeros(len(filt.aug.model.output_names), int)   # samples where each reading was used
        self.gate, self.beyond, self.first_beyond = Guard.gate, 0, None   # ungated: readings used beyond Guard.gate
        self.present, self.failure = 0, None     # samples with a reading; why the first failed step failed
        self.held = np.zeros(filt.aug.n, int)     # samples whose prior std of each state was held at std_max
        self.cov = None                           # the last finite posterior covariance

    def add(self, part: RunResult) -> "RunSummary":
        ok, used = np.isfinite(part.nis), np.isfinite(part.innovation)     # a reading gated or stuck is not used
        self.samples += len(part.t)
        self.with_measurement += int(used.any(axis=1).sum()) if used.size else 0
        self.present += int(part.measured.any(axis=1).sum()) if part.measured.size else 0
        self.failure = self.failure or part.failure
        if part.held is not None:
            self.held += part.held.sum(axis=0)
        if used.size:
            self.per_output += used.sum(axis=0).astype(int)
        self.nis_sum += float(part.nis[ok].sum())
        self.nis_count += int(ok.sum())
        self.expected_sum += float(used[ok].sum())
        self.holes, self.notes, self.gate = part.holes, part.notes, part.gate
        if not part.gate:
            with np.errstate(invalid="ignore"):
                far = np.flatnonzero((np.abs(part.innovation) > Guard.gate * np.sqrt(part.innovation_var)).any(axis=1))
            self.beyond += len(far)
            if self.first_beyond is None and len(far):
                self.first_beyond = float(part.t[far[0]])
        for c in EVENTS:
            at = np.flatnonzero(part.code == c)
            self.events[c] += len(at)
            if self.first[c] is None and len(at):
                self.first[c] = float(part.t[at[0]])
        if len(part.t):
            self.t = [self.t[0] if self.samples > len(part.t) else float(part.t[0]), float(part.t[-1])]
            good = np.flatnonzero(np.isfinite(part.mean[:, 0]))
            if good.size:
                k = good[-1]
                self.last = (part.mean[k], part.std[k], part.prior_var[k] if part.prior_var.size else None)
            if np.all(np.isfinite(part.final_cov)):
                self.cov = part.final_cov
        return self

    TOGETHER = 0.99   # weights whose final posterior correlation is beyond this: one combination known
    INFORMED = 0.5    # ... each known too where its std is under this share of its prior's

    def together(self) -> list[str]:
        """Pairs of weights or estimated parameters the recording fixes only in combination (final
        posterior |correlation| > TOGETHER): each alone reads as uncertain, the combination is not."""
        aug = self.filter.aug
        idx = list(aug.w_index) + list(aug.p_index)
        if self.cov is None or len(idx) < 2:
            return []
        P = self.cov[np.ix_(idx, idx)]
        sd = np.sqrt(np.clip(np.diag(P), 0, None))
        with np.errstate(invalid="ignore", divide="ignore"):
            r = P / np.outer(sd, sd)
        out = []
        for a in range(len(idx)):
            for b in range(a):
                if abs(r[a, b]) > self.TOGETHER:
                    k = -np.sign(r[a, b]) * sd[a] / sd[b]        # w_a + k·w_b: the combination fixed
                    i, j = idx[a], idx[b]
                    comb = self.last[0][i] + k * self.last[0][j]
                    var = P[a, a] + k * k * P[b, b] + 2 * k * P[a, b]
                    each = max(sd[a] / np.sqrt(aug.P0[i, i]), sd[b] / np.sqrt(aug.P0[j, j])) < self.INFORMED
                    out.append(f"  {aug.names[j]} and {aug.names[i]} move together (correlation {r[a, b]:+.5f}): the "
                               f"recording fixes {aug.names[i]} {'+' if k >= 0 else '−'} {abs(k):.4g}·{aug.names[j]} = "
                               f"{comb:+.4g} ± {2 * np.sqrt(max(var, 0)):.2g}"
                               + (", far better than either (each within its ± 2σ above, a fraction of its prior's)"
                                  if each else ", not each (their terms are nearly one on this recording: another "
                                               "excitation, or one term fewer)"))
        return out

    def event_counts(self) -> list[str]:
        """'1067 gated (outlier not used)', … for every event counted."""
        return [f"{n} {EVENT_WORDS[c]}" for c, n in self.events.items() if n]

    def attention(self) -> list[str]:
        """What a person should look at, briefly: the holes and the events (and, in a run without
        a gate, the samples with a reading beyond the default gate that were used)."""
        return (([f"{len(self.holes)} hole(s)"] if self.holes else []) + self.event_counts()
                + ([f"{self.beyond} with a reading beyond {Guard.gate:g}σ used (no gate)"] if self.beyond else []))

    def kept(self) -> np.ndarray | None:
        """SKI: True for the weights whose term is kept; None for other filters. A variance the
        gradient update has driven to its bound ``s_min`` is pruned, whatever its declared scale."""
        if self.last is None or self.last[2] is None:
            return None
        s, opts = np.asarray(self.last[2], float), self.filter.options
        r = np.sqrt(s / self.filter.aug.s0)
        floored = s <= opts.s_min * (1 + 1e-9) if opts.ard == "gradient" else np.zeros(len(s), bool)
        return (r >= self.KEEP * r.max()) & ~floored

    def sigma_spread(self) -> str | None:
        """Where a sigma-point filter evaluates the model, and how to bring it nearer (None for
        the EKF): a wide prior through a cubic or exponential term overflows the step there, and
        a restart (at reinit_scale times the declared variance) widens it again."""
        filt = self.filter
        if filt.kind == "ekf":
            return None
        gamma, n = sigma_reach(filt)
        return (f"the {filt.kind} evaluates the model at ±{gamma:.3g} standard deviations of each of its {n} "
                f"sigma-point states and weights (alpha = {filt.options.alpha:g}): a cubic or exponential term "
                f"there can overflow the step, and each restart widens them again. {nearer(filt)}")

    def integration(self) -> str | None:
        """Where the integration step misplaces a mode of the dynamics at the final estimates (the
        rates' Jacobian at the last posterior mean and at the declared start's states with the
        final weights and parameters, inputs and history 0; :meth:`~skigen.model.Model.step_note`):
        the weights and parameters that set that mode absorb the step's error, beyond their ± 2σ,
        whatever the verdict below. A model whose damping is all in its unknown terms shows no mode
        at its declared start. None where the filter failed on more than REFUSED of the samples:
        its estimates are not the recording's (a mode at 2.9e58 /s was said)."""
        aug = self.filter.aug
        m = aug.model
        if aug.rates_jacobian is None or self.last is None or not np.isfinite(self.last[0]).all() or self.failing():
            return None
        start = np.r_[m.x0, self.last[0][len(m.states):]]
        jac = [np.asarray(aug.rates_jacobian(z, np.zeros(len(m.inputs)), np.zeros(len(m.memory)), aug.fixed_values),
                          float) for z in (self.last[0], start)]
        note = m.step_note(jac, "with the final estimates")
        return note and f"integration: {note}, whatever the verdict; run again"

    REFUSED = 0.05   # a filter that gates, or fails on, more than 1 in 20 samples with a reading is not following it

    def failing(self) -> bool:
        """Whether the filter failed on more than REFUSED of the samples with a reading: its
        estimates are then not the recording's."""
        return self.events[Status.NUMERICAL_FAILURE] > self.REFUSED * self.present

    def verdict(self) -> str:
        """The mean NIS against its two-sided 99 % band: a consistent filter's summed NIS is χ² with
        as many degrees of freedom as readings used (white innovations, each of unit variance).
        Where more than REFUSED of the samples with a reading were gated or failed, inconsistent
        whatever that NIS: it leaves out the readings that disagreed (a PWM command where the model
        wants a thrust fraction: 599 of 623 altimeter readings gated, "conservative" on the rest)."""
        dof = self.expected_sum
        lo, hi = (stats.chi2.ppf(q, dof) / dof for q in (0.005, 0.995))
        mean = self.nis_sum / self.expected_sum
        band = f"the 99 % band for {dof:.0f} readings is {lo:.3g}–{hi:.3g} times the expected"
        gated, failed = self.events[Status.OUTLIER_REJECTED], self.events[Status.NUMERICAL_FAILURE]
        if gated + failed > self.REFUSED * self.present:
            said = " and ".join(filter(None, (f"{gated} gated" if gated else "", f"{failed} failed" if failed else "")))
            return (f"inconsistent: of the {self.present} samples with a reading, {said} (more than 1 in "
                    f"{1 / self.REFUSED:.0f}): the filter is not following the recording, and the mean NIS of the "
                    f"readings it used ({mean:.3g} times their predicted variance) leaves out those that disagreed"
                    + ("; why the first step failed is said above" if failed and self.failure else "")
                    + ". Check the units and mapping of the inputs and outputs; `skigen diagnose` says where and "
                      "what is missing")
        if mean > hi:
            return (f"inconsistent: the innovations are {mean:.3g} times their predicted variance ({band}): the "
                    f"model or its declared noise does not explain the recording, and the ± 2σ above are too "
                    f"small" + (f"; the {gated} gated readings may be that mismatch, not outliers" if gated else "")
                    + ". `skigen diagnose` says where and what is missing; `skigen fit` calibrates the noise"
                    + ("; a first-order EKF's linearisation may be it: try --second-order or the UKF"
                       if self.filter.kind == "ekf" and not self.filter.options.second_order else ""))
        if mean < lo:
            estimated = self.filter.aug.n > len(self.filter.aug.model.states)
            return (f"conservative: the innovations are {mean:.3g} times their predicted variance ({band}): the "
                    f"declared noise is larger than the recording shows, and the states' ± 2σ above are wide"
                    + ("; the estimated parameters' and weights' are not vouched for: a process noise above the "
                       "true one makes the states they multiply noisy and can bias them beyond their ± 2σ (`skigen "
                       "fit --method filter-error` calibrates the noise with them)" if estimated else ""))
        return f"consistent: the innovations are {mean:.3g} times their predicted variance ({band})"

    PRIOR_Z = 3.0     # an estimated parameter this many prior std from its declared value is remarked

    def _odd(self, i: int) -> str:
        """What the parameter table says beside estimated parameter ``i``: outside its declared
        bounds (the filter does not hold them), or PRIOR_Z prior std from its declared value (a
        thrust in percent for a fraction: 0.196 for a declared 18 ± 5, said nowhere)."""
        p = self.filter.aug.model.parameter_named(self.filter.aug.names[i])
        value, (lo, hi) = self.last[0][i], p.bounds
        z = abs(value - p.value) / p.std if p.std else 0.0
        said = ([f"outside its bounds [{lo:g}, {hi:g}], which the online filter does not hold"]
                if not lo <= value <= hi else []) + ([f"{z:.1f} prior std from its declared {p.value:g}"]
                                                    if z > self.PRIOR_Z else [])
        ratio = value / p.value if p.value and value else np.nan
        if said and np.isfinite(ratio) and ratio < 0:
            said.append("of the opposite sign: check the sign conventions of the inputs and outputs")
        elif said and np.isfinite(ratio) and not 0.2 < ratio < 5:
            said.append(f"{ratio:.3g}× it: check the units and mapping")
        if not said and p.std and self.last[1][i] >= self.BARELY * p.std:      # as the weights' table says
            said.append(f"std {self.last[1][i] / p.std:.0%} of its prior's: the recording barely informed it "
                        f"(its term not excited?)")
        return "   " + "; ".join(said) if said else ""

    BARELY = 0.9      # an estimate whose std ends above this share of its prior's: the recording added little

    def _mark(self, i: int, kept: bool | None) -> str:
        """What the weight table says beside weight ``i``: never informed, or (SKI, ``kept`` not
        None) kept or pruned, with how far from 0 where the label alone misleads."""
        mean, std = self.last[0][i], self.last[1][i]
        if std >= 0.99 * np.sqrt(self.filter.aug.P0[i, i]):
            return "   its prior's std: " + ("the filter failed on most steps (below), not the recording's word"
                                              if self.failing() else
                                              "the recording never informed it (its term not excited?)")
        if kept is None:
            return ""
        z = abs(mean) / std if std > 0 else np.inf
        if not kept:
            return (f"   pruned, yet {z:.0f}σ from 0: a term small against the others, not absent (the rule "
                    f"compares prior stds across terms of different scales)") if z > 5 else "   pruned"
        return "   kept" if z > 2 else "   kept, within 2σ of 0"

    def held_line(self) -> str:
        """Which states' prior std the guard held at its bound, on how many samples, and what to do."""
        aug = self.filter.aug
        sd = np.sqrt(np.diag(aug.P0))
        held = ", ".join(f"{aug.names[i]} on {self.held[i]} (declared std {sd[i]:.3g})"
                         for i in np.flatnonzero(self.held))
        return (f"prior std held at its bound (std_scale × the declared std; 100 by default): {held} of "
                f"{self.samples} samples: there the filter is surer of the state than its model and the weights' "
                f"prior make it, and may gate readings it should use. A broad weight prior beside a tight state "
                f"std does this; raise the bound (--std-scale, Guard(std_scale=...)) or declare a larger std")

    def lines(self) -> list[str]:
        aug, out = self.filter.aug, []
        if self.filter.partition is not None:           # which states the MUKF marginalises
            out += [f"{self.filter.kind}: {line.strip()}" for line in self.filter.partition.describe().splitlines()[:2]]
        if self.holes:
            out.append(f"{len(self.holes)} hole(s) longer than the maximum gap:")
            out += [f"  {h}" for h in self.holes]
        else:
            out.append("no holes")
        if self.last is not None and len(aug.w_index):
            kept = self.kept()
            out.append("weight" + " " * 14 + "final ± 2σ" + ("   (SKI: kept?)" if kept is not None else ""))
            for j, i in enumerate(aug.w_index):
                mark = self._mark(i, None if kept is None else kept[j])
                out.append(f"  {aug.names[i]:16s} {self.last[0][i]:+.4g} ± {2 * self.last[1][i]:.2g}{mark}")
        if self.last is not None and len(aug.p_index):
            out.append("parameter" + " " * 11 + "final ± 2σ   (estimated online)")
            out += [f"  {aug.names[i]:16s} {self.last[0][i]:+.6g} ± {2 * self.last[1][i]:.2g}{self._odd(i)}"
                    for i in aug.p_index]
        if self.last is not None:
            out += self.together()
        if line := self.integration():
            out.append(line)
        if any(self.events.values()):
            out.append("events: " + "; ".join(f"{n} {EVENT_WORDS[c]}, first at t = {clock(self.first[c])} s"
                                              for c, n in self.events.items() if n))
            first = self.first[Status.OUTLIER_REJECTED]
            if first is not None and first <= self.t[0] + 0.5 * aug.model.dt:
                out.append("why the first readings may be gated: they disagree with the declared initial state "
                           "from the first sample on; the recording may start elsewhere (declare its initial "
                           "value, initial=, or a wider std=)")
            trouble = self.events[Status.NUMERICAL_FAILURE] or self.events[Status.REINITIALISED]
            if trouble and (why := aug.model.unstable_step()):
                out.append(f"why steps may fail: {why}")
            if self.events[Status.NUMERICAL_FAILURE]:
                if self.failure:
                    out.append(f"why the first failed: {self.failure}")
                if nearer(self.filter) not in (self.failure or "") and (spread := self.sigma_spread()):
                    out.append(f"why steps may fail: {spread}")
        elif self.gate:
            out.append("events: none (no outlier, stuck reading, bad input, rejection or restart)")
        if not self.gate:
            out.append("ungated run (the casadi backend, which neither gates nor tests for a stuck sensor "
                       "outside a part redone after a non-finite step; or a guard with gate 0): "
                       + (f"{self.beyond} sample(s) used a reading beyond {Guard.gate:g}σ of its prediction, "
                          f"which the default gate would not, first at t = {clock(self.first_beyond)} s"
                          if self.beyond else f"no reading was beyond {Guard.gate:g}σ of its prediction"))
        if self.held.any():
            out.append(self.held_line())
        if self.nis_count:
            expected = self.expected_sum / self.nis_count
            out.append(f"mean NIS {self.nis_sum / self.nis_count:.3f} (expected {expected:.3f}: the "
                       f"{len(aug.model.output_names)} output(s) used {expected:.3g} at a time on average, "
                       f"{self.with_measurement} of {self.samples} samples with a reading used)")
            out.append(self.verdict())
        elif self.present:
            out.append(f"no reading was used ({self.present} samples had one: each failed, was gated or "
                       f"stuck): no NIS")
        else:
            out.append("no sample was measured: no NIS")
        names = aug.model.output_names
        if self.samples and (self.per_output < self.samples).any():
            out.append("measured per output: " + ", ".join(f"{n} {m} of {self.samples}" for n, m in zip(names, self.per_output))
                       + " used (the rest empty, non-finite, gated or stuck)")
        return out


class PythonStepper:
    """The derived step Function behind the generated C's interface, guards and recovery
    policy (:mod:`skigen.guard`, rule for rule as ``<prefix>_step``).

    Holds the filter state (z, C, s, mem), the counters of the policy and, after each step,
    the posterior (z_post, C_post), innovation statistics (e, Pyy, nis, loglik) and the
    outputs ``used``.
    """

    def __init__(self, filt: DerivedFilter, guard: Guard | None = None):
        self.filt = filt
        f = filt.step
        self._shapes = [(f.size2_out(i), f.size1_out(i)) for i in range(f.n_out())]   # transposed
        self.configure(guard or Guard())
        self.init()

    def configure(self, guard: Guard) -> None:
        """The recovery policy's settings (kept by :meth:`init` and :meth:`reset`)."""
        self.guard, self.std_max = guard, guard.std_max(self.filt.aug.P0)

    def init(self) -> None:
        self.reset()

    def reset(self, z0=None, C0=None) -> None:
        """Restart from (z0, C0) (None: the declared value); history and counters at 0.
        ValueError, the state unchanged, for a start the step cannot take (as the C reset)."""
        why = self.filt.start_refusal(z0, C0)
        if why:
            raise ValueError(f"reset refused: {why}; the state is unchanged")
        st = self.filt.initial()
        self.z = st["z"] if z0 is None else np.array(z0, float)
        self.C = st["C"] if C0 is None else np.array(C0, float)
        self.mem, self.s = st["mem"], st.get("s")
        self.u_held = np.zeros(self.filt.aug.shapes["nu"])
        self.held = np.zeros(self.filt.aug.n, bool)    # the states whose prior std the last step held at std_max
        ny = self.filt.aug.shapes["ny"]
        self.y_last, self.repeats = np.zeros(ny), np.zeros(ny, int)
        self.rejected, self.stuck = np.zeros(ny, int), np.zeros(ny, int)
        self.reject_run = np.zeros(ny, int)
        self.reinits = self.since_update = 0
        self._reset_posterior()

    def _reset_posterior(self):
        ny = self.filt.aug.shapes["ny"]
        self.z_post, self.C_post = self.z, self.C
        self.e, self.Pyy, self.nis, self.loglik = np.zeros(ny), np.zeros((ny, ny)), 0.0, 0.0
        self.used = np.zeros(ny)

    def _run(self, u, y, valid):
        """The derived step on the prior: (its results, whether every one is finite), through
        :func:`_call` (no DM conversions: the whole step 2× faster); CasADi reads and writes
        column-major, so a matrix enters as its transpose and leaves as one."""
        args = [self.z, np.asarray(self.C).T] + ([self.s] if self.filt.has_ard else []) + \
            [u, self.mem, np.where(valid, y, 0.0), valid.astype(float)]
        outs = [np.empty(shape) for shape in self._shapes]
        _call(self.filt.step, args, outs)
        return dict(zip(self.filt.names_out, (r.T for r in outs))), all(np.isfinite(r).all() for r in outs)

    def _present(self, y):
        """Which outputs are measured and not stuck; updates the stuck-sensor counters."""
        valid, code = np.isfinite(y), Status.OK if np.all(np.isfinite(y)) else Status.MEASUREMENT_SKIPPED
        for i in np.flatnonzero(valid):
            self.repeats[i] = self.repeats[i] + 1 if y[i] == self.y_last[i] else 0
            self.y_last[i] = y[i]
            if 0 < self.guard.stuck_limit <= self.repeats[i]:
                self.stuck[i] += 1
                valid[i], code = False, Status.SENSOR_STUCK
        return valid, code

    def step(self, u, y) -> int:
        """One sample; returns a :class:`Status` code."""
        g, aug = self.guard, self.filt.aug
        u, y = np.asarray(u, float).ravel(), np.asarray(y, float).ravel()
        if len(u) != aug.shapes["nu"] or len(y) != aug.shapes["ny"]:
            raise ValueError(self.filt.size_refusal(u, y))
        held = not np.all(np.isfinite(u))                       # a non-finite input: its last finite value
        self.u_held = u = np.where(np.isfinite(u), u, self.u_held)
        valid, code = self._present(np.full_like(y, np.nan) if held else y)   # held: predicted only
        seen, present = valid.copy(), valid.any()
        after_gap = present and 0 < g.gap_limit <= self.since_update
        recover = present and (seen & (0 < g.reject_limit <= self.reject_run)).any()  # refused reject_limit times
        if recover:
            self._restart()
        out, ok = self._run(u, y, valid)
        gated = np.zeros_like(valid)
        if not recover and g.gate > 0:
            v = np.diag(np.reshape(out["Pyy"], (len(y), len(y))))
            with np.errstate(invalid="ignore", over="ignore"):
                gated = valid & ~(np.abs(out["e"].ravel()) <= g.gate * np.sqrt(np.where(v > 0, v, 0)))
        if after_gap and not recover and (gated.any() or not ok):     # the prediction lost the vehicle
            recover = True
            self._restart()
            out, ok = self._run(u, y, valid)
        elif gated.any():
            self.rejected += gated
            valid = valid & ~gated
            out, ok = self._run(u, y, valid)
            code = Status.OUTLIER_REJECTED
        used = valid & ok
        self.reject_run = np.where(used, 0, self.reject_run + seen)
        self.since_update = 0 if used.any() else self.since_update + 1
        self.reinits += int(recover)
        self.mem = out["mem_next"].ravel()
        if not ok:
            self._reset_posterior()
            return Status.NUMERICAL_FAILURE
        self.z_post, self.C_post = out["z_post"].ravel(), out["C_post"]
        bounded = []
        self.z, self.C = out["z_next"].ravel(), bound_std(out["C_next"], self.std_max, self.filt.square_root, bounded)
        self.held = bounded[0]
        self.e, self.Pyy, self.nis, self.loglik = out["e"].ravel(), out["Pyy"], out["nis"].item(), out["loglik"].item()
        self.used = valid.astype(float)
        if self.filt.has_ard:
            self.s = out["s_next"].ravel()
        return Status.REINITIALISED if recover else Status.BAD_INPUT if held else code

    def snapshot(self) -> dict:
        """The filter's state and the policy's counters, for :meth:`restore`."""
        return copy.deepcopy({k: v for k, v in vars(self).items() if k != "filt"})

    def restore(self, snapshot: dict) -> None:
        vars(self).update(copy.deepcopy(snapshot))

    def _restart(self):
        """The physical states at their declared mean, reinit_scale times their declared covariance."""
        st = self.filt.initial()
        self.z, self.C = reinit(self.z, self.C, self.filt.aug.shapes["nx"], st["z"], st["C"],
                                self.guard.reinit_scale, self.filt.square_root)

    def std(self) -> np.ndarray:
        """Posterior standard deviations."""
        C = self.C_post
        return np.sqrt(np.sum(C * C, axis=1)) if self.filt.square_root else np.sqrt(np.clip(np.diag(C), 0, None))


def check_columns(model, rec: Recording) -> None:
    """Raise ValueError unless the recording's inputs and outputs are the model's, in order."""
    have = list(rec.input_names) + list(rec.output_names)
    want = model.input_names + model.output_names
    if have != want:
        missing = [n for n in want if n not in have]
        extra = [n for n in have if n not in want]
        raise ValueError(
            f"{rec.path}: recording columns do not match model '{model.name}'"
            + (f"; missing {', '.join(repr(m) for m in missing)}" if missing else "")
            + (f"; not in the model {', '.join(repr(e) for e in extra)}" if extra else "")
            + f" (model inputs {model.input_names}, outputs {model.output_names})")


BACKENDS = ("python", "c", "casadi")
CHUNK = {"python": 1_000, "c": 1 << 16, "casadi": 1 << 16}     # samples per part of a run


def _step_python(stepper: PythonStepper, inputs, outputs, trace: bool = False) -> dict[str, np.ndarray]:
    """The per-sample records of :meth:`CFilter.run_many`, from the Python step (with ``trace``
    also those of a :class:`Trace`)."""
    N, n, ny = len(inputs), stepper.filt.aug.n, outputs.shape[1]
    nw = len(stepper.filt.aug.w_index) if stepper.filt.has_ard else 0
    raw = dict(z_post=np.empty((N, n)), std=np.empty((N, n)), e=np.empty((N, ny)), pyy=np.empty((N, ny)),
               nis=np.empty(N), loglik=np.empty(N), s=np.empty((N, nw)), used=np.empty((N, ny)),
               code=np.empty(N, int), held=np.zeros((N, n), bool))
    if trace:
        raw.update(C_post=np.empty((N, n, n)), z_next=np.empty((N, n)), C_next=np.empty((N, n, n)),
                   mem=np.empty((N, len(stepper.mem))))
    for k in range(N):
        if trace:
            raw["mem"][k] = stepper.mem
        stepper.held = np.zeros(n, bool)
        raw["code"][k] = stepper.step(inputs[k], outputs[k])
        raw["held"][k] = stepper.held
        raw["z_post"][k], raw["std"][k] = stepper.z_post, stepper.std()
        raw["e"][k], raw["pyy"][k], raw["used"][k] = stepper.e, np.diag(stepper.Pyy), stepper.used
        raw["nis"][k], raw["loglik"][k] = stepper.nis, stepper.loglik
        if nw:
            raw["s"][k] = stepper.s
        if trace:
            raw["C_post"][k], raw["z_next"][k], raw["C_next"][k] = stepper.C_post, stepper.z, stepper.C
    return raw


class CasadiStepper:
    """The derived step chained over a part of a recording by CasADi (``mapaccum``, :data:`PIECE`
    samples a call), behind :meth:`CFilter.run_many`'s interface, *without* the guard policy (see the module
    docstring). A part whose chain gives a non-finite number is redone by a :class:`PythonStepper`
    with the default :class:`Guard` from the same state, or, when ``strict``, raises
    FloatingPointError. Holds the filter state (z, C, s, mem) and the last posterior C_post.

    The chain takes the step's numeric constants (Q, R, the model's coefficients) as an input, so
    filters whose steps differ only in those numbers share one chain, built once (:data:`_CHAINS`)
    and compiled once its runs have cost what compiling it does (:class:`_Chain`)."""

    def __init__(self, filt: DerivedFilter, strict: bool = False, trace: bool = False):
        self.filt, self.strict, self.trace = filt, strict, trace
        st = filt.initial()
        self.z, self.C, self.mem, self.s = st["z"], st["C"], st["mem"], st.get("s")
        self.C_post = self.C
        self.u_held = np.zeros(filt.aug.shapes["nu"])    # the last finite value of each input (bad-input rule)
        self._key = self._chained = None

    def _chain(self):
        """The chain of this step's structure over :data:`PIECE` samples, and the step's constants."""
        if self._chained is None:
            shape, consts = structure(self.filt.step)
            self._key = (self.filt.kind, shape)
            if self._key not in _CHAINS:
                if len(_CHAINS) >= MAX_CHAINS:
                    del _CHAINS[next(iter(_CHAINS))]
                _CHAINS[self._key] = _Chain(self.filt, with_constants(self.filt.step))
            self._chained = _CHAINS[self._key], consts
        return self._chained

    def run_many(self, inputs, outputs) -> dict[str, np.ndarray]:
        N = len(inputs)
        U, Y = np.asarray(inputs, float).reshape(N, -1), np.asarray(outputs, float).reshape(N, -1)
        start = self.z, self.C, self.s, self.mem, self.C_post
        direct = self._chained is None and self.filt.step.n_instructions() > CHAIN_BELOW * N
        if not np.all(np.isfinite(U)):     # an input not known (a hole): its rule, and no other policy
            return self._fallback(U, Y, Guard.off())
        if N:                              # every input known: the last is what a hole holds
            self.u_held = U[-1].copy()
        key = None if direct else self._run_key(U, Y)
        if key in _RUNS:              # this very run was done before: its records and end state
            raw, (self.z, self.C, self.s, self.mem, self.C_post) = _RUNS[key]
            return {k: v.copy() for k, v in raw.items()}
        raws = [self._direct(U, Y)] if direct else [self._piece(U[a:a + PIECE], Y[a:a + PIECE])
                                                    for a in range(0, N, PIECE)]
        if any(r is None for r in raws):
            self.z, self.C, self.s, self.mem, self.C_post = start
            return self._fallback(U, Y)
        raw = {k: np.concatenate([r[k] for r in raws]) for k in raws[0]}
        if key is not None and sum(v.nbytes for v in raw.values()) <= MAX_RUN_BYTES:
            if len(_RUNS) >= MAX_RUNS:
                del _RUNS[next(iter(_RUNS))]
            _RUNS[key] = {k: v.copy() for k, v in raw.items()}, (self.z, self.C, self.s, self.mem, self.C_post)
        return raw

    def _run_key(self, U, Y) -> tuple:
        """What a chained run's results depend on: the step's structure and constants, the state, the data."""
        digest = hashlib.sha1()
        for a in (self._chain()[1], self.z, self.C, self.mem, U, Y) + ((self.s,) if self.filt.has_ard else ()):
            digest.update(np.ascontiguousarray(a, float).tobytes())
        return self._key, self.trace, U.shape, Y.shape, digest.digest()

    def _piece(self, U, Y) -> dict[str, np.ndarray] | None:
        """At most PIECE samples by one chain call (the rest of the chain predicts on); None where a
        number is not finite."""
        filt, ski = self.filt, self.filt.has_ard
        d, N, M = filt.aug.shapes, len(U), PIECE
        n = d["n"]
        valid = np.isfinite(Y)
        chain, consts = self._chain()
        pad = lambda a: np.concatenate([a, np.repeat(a[-1:], M - N, axis=0)])   # prediction-only steps after N
        V = np.zeros((M, d["ny"]))
        V[:N] = valid
        sizes = [n, d["ny"], d["ny"], 1, 1, d["nw"] if ski else 0, n, d["nmem"]]
        # CasADi reads and writes column-major matrices: a C-ordered array of the transposed shape
        args = [self.z, self.C.T] + ([self.s] if ski else []) + [self.mem, pad(U), pad(np.where(valid, Y, 0.0)), V, consts]
        rec, C_post, C_next, mem = np.empty((M, sum(sizes))), np.empty((M, n, n)), np.empty((M, n, n)), \
            np.empty((M, d["nmem"]))
        with np.errstate(all="ignore"):
            chain(args, [rec, C_post, C_next, mem])
        rec = rec[:N].T
        Cp, Cn = (np.ascontiguousarray(a[:N].transpose(0, 2, 1)) for a in (C_post, C_next))    # (N, n, n)
        if not (np.all(np.isfinite(rec)) and np.all(np.isfinite(Cp)) and np.all(np.isfinite(Cn))):
            return None
        z_post, e, pyy, nis, ll, s, z_next, mem_next = np.split(rec, np.cumsum(sizes))[:-1]
        self.z, self.C, self.mem, self.C_post = z_next[:, -1], Cn[-1], mem_next[:, -1], Cp[-1]
        std = np.sqrt(np.einsum("kij,kij->ki", Cp, Cp)) if filt.square_root else \
            np.sqrt(np.clip(np.einsum("kii->ki", Cp), 0, None))
        if ski:
            self.s = s[:, -1]
        raw = dict(z_post=z_post.T, std=std, e=e.T, pyy=pyy.T, nis=nis.ravel(), loglik=ll.ravel(), s=s.T,
                   used=valid.astype(float), code=np.where(valid.all(axis=1), Status.OK, Status.MEASUREMENT_SKIPPED))
        if self.trace:       # the prior for k + 1 and the input memory used at k
            raw.update(C_post=Cp, z_next=z_next.T, C_next=Cn, mem=mem[:N])
        return raw

    def _direct(self, U, Y) -> dict[str, np.ndarray] | None:
        """The part by one evaluation of the step per sample (see :data:`CHAIN_BELOW`), each reading
        the state the previous one wrote: the chain's numbers. None where a number is not finite."""
        filt, N, n = self.filt, len(U), self.filt.aug.shapes["n"]
        f, valid = filt.step, np.isfinite(Y)
        out = {name: np.empty((N, f.nnz_out(i))) for i, name in enumerate(filt.names_out)}
        rows = dict(u=U, y=np.where(valid, Y, 0.0), valid=valid.astype(float))
        carried = dict(z="z_next", C="C_next", s="s_next", mem="mem_next")
        # CasADi reads and writes column-major matrices: C enters as the C-ordered array of Cᵀ
        start = {k: np.ascontiguousarray(v, float).ravel() for k, v in
                 dict(z=self.z, C=np.asarray(self.C).T, s=self.s, mem=self.mem).items() if k in filt.names_in}
        buf, evaluate = f.buffer()
        with np.errstate(all="ignore"):
            for k in range(N):
                for i, name in enumerate(filt.names_in):
                    a = rows[name][k] if name in rows else start[name] if k == 0 else out[carried[name]][k - 1]
                    buf.set_arg(i, memoryview(a))
                for i, name in enumerate(filt.names_out):
                    buf.set_res(i, memoryview(out[name][k]))
                evaluate()
        if not all(np.all(np.isfinite(v)) for v in out.values()):
            return None
        Cp, Cn = (np.ascontiguousarray(out[k].reshape(N, n, n).transpose(0, 2, 1)) for k in ("C_post", "C_next"))
        self.z, self.C, self.mem, self.C_post = out["z_next"][-1], Cn[-1], out["mem_next"][-1], Cp[-1]
        if filt.has_ard:
            self.s = out["s_next"][-1]
        std = np.sqrt(np.einsum("kij,kij->ki", Cp, Cp)) if filt.square_root else \
            np.sqrt(np.clip(np.einsum("kii->ki", Cp), 0, None))
        ny = Y.shape[1]
        raw = dict(z_post=out["z_post"], std=std, e=out["e"], pyy=np.einsum("kii->ki", out["Pyy"].reshape(N, ny, ny)),
                   nis=out["nis"].ravel(), loglik=out["loglik"].ravel(),
                   s=out["s_next"] if filt.has_ard else np.empty((N, 0)), used=valid.astype(float),
                   code=np.where(valid.all(axis=1), Status.OK, Status.MEASUREMENT_SKIPPED))
        if self.trace:
            mem = np.vstack([start["mem"][None, :], out["mem_next"][:-1]])
            raw.update(C_post=Cp, z_next=out["z_next"], C_next=Cn, mem=mem)
        return raw

    def _fallback(self, U, Y, guard: Guard | None = None) -> dict[str, np.ndarray]:
        """The part again, by the Python stepper from the same state: with its guards (``guard``,
        default :class:`Guard`) after a non-finite number; with ``Guard.off()``, this backend's
        policy, where an input is not known (it predicts with the last known one and uses no
        reading: the bad-input rule, which a chain cannot take)."""
        if self.strict and guard is None:
            raise FloatingPointError(f"the {self.filt.kind} filter of '{self.filt.aug.model.name}' produced "
                                     f"non-finite numbers")
        py = PythonStepper(self.filt, guard)
        _start(py, dict(z=self.z, C=self.C, mem=self.mem, s=self.s))
        py.u_held = self.u_held.copy()
        raw = _step_python(py, U, Y, self.trace)
        self.z, self.C, self.mem, self.s, self.C_post = py.z, py.C, py.mem, py.s, py.C_post
        self.u_held = py.u_held
        return raw


PIECE_BLOCKS = (32, 32)     # a chain: 32 blocks of 32 unrolled steps, called once per PIECE samples
PIECE = PIECE_BLOCKS[0] * PIECE_BLOCKS[1]
_CHAINS: dict = {}          # (kind, step structure) → chain, shared by the filters of that structure
MAX_CHAINS = 64
_RUNS: dict = {}            # the last chained runs: key → (records, end state), see CasadiStepper._run_key
MAX_RUNS, MAX_RUN_BYTES = 16, 1 << 25     # runs kept, and the largest kept (32 MB)
# Building a chain costs about 20 µs per instruction of the step (structure, with_constants, the
# mapaccum) and is kept for the filters of the same structure; evaluating it saves about 10 µs per
# sample over evaluating the step sample by sample (CasadiStepper._direct), at the same speed
# otherwise. A run of N samples whose step has more than CHAIN_BELOW·N instructions and no chain
# yet is evaluated sample by sample (a SKI over 26 candidates, 674 558 instructions, over 1 200
# samples: 10 s instead of 22 s, 13 of them building the chain).
CHAIN_BELOW = 5
INLINE_BELOW = 2000    # instructions of a step inlined into its chain (see _block)


JIT_INSTRUCTIONS = 2000        # a compiled block holds about this many instructions: 1 to 8 steps
JIT_COMPILER = "gcc"           # any C compiler: the VM's numbers need only no contraction (below)
JIT_FLAGS = ["-Og", "-ffp-contract=off"]      # -O1's speed, built faster; no fused multiply-add: the VM's numbers
JIT_LARGEST = 50_000           # instructions of the largest step compiled
# whether compiling works (False once it failed: no C compiler), and what a compilation costs: about
# this many seconds plus this many per instruction of the block (the latter the running average)
_JIT = {"works": True, "seconds": 0.15, "per_instruction": 1e-4}


class _Chain:
    """A step structure's chain (:func:`_block`, :func:`_chain_of`), evaluated by CasADi's virtual
    machine until the time spent there exceeds what compiling it is expected to cost; then its
    blocks (of up to :data:`JIT_INSTRUCTIONS`) are compiled by the C compiler beside the runs,
    which go on in the VM and switch to the native code at the first call after the compiler
    finished: about 1.4 ns an instruction against the VM's 8 (Silverbox's 246-instruction EKF,
    8 steps a block: 0.33 µs a sample against 1.9, compiled in 0.3 s). The rule is the ski-rental
    one: a structure run a few times never pays for a compilation, one run many times over a long
    recording pays for it once, and the total is at most about twice the better of never and at
    once (the compiler's time now on another core where there is one). The numbers are the VM's to
    the bit (tested)."""

    def __init__(self, filt: DerivedFilter, step):
        self.filt, self.step = filt, step
        n = step.n_instructions()
        self.block = 1 << int(np.clip(np.log2(JIT_INSTRUCTIONS / max(n, 1)), 0, 3))   # 1, 2, 4 or 8 steps
        self.f = _chain_of(_block(filt, step, PIECE_BLOCKS[0]), PIECE_BLOCKS[1])
        self.native, self.spent, self.compiling = False, 0.0, None     # spent: seconds its runs took in the VM
        self.cost = _JIT["seconds"] + _JIT["per_instruction"] * self.block * n if n <= JIT_LARGEST else np.inf

    def __call__(self, args: list, outs: list[np.ndarray]) -> None:
        if self.compiling is not None and self.compiling.done():
            self.wait()
        t0 = perf_counter()
        _call(self.f, args, outs)
        if not self.native and self.compiling is None:
            self.spent += perf_counter() - t0
            if self.spent > self.cost:
                self.compile()

    def compile(self) -> None:
        """Start compiling the chain's blocks beside the runs (the VM's code stays where that fails)."""
        if not _JIT["works"]:
            self.native = True                       # settled: never compiled
            return
        block = _block(self.filt, self.step, self.block, f"block{id(self)}")
        self.compiling = _background(_compile, _generate(block, _jit_directory()), block.name(),
                                     block.n_instructions())

    def wait(self) -> None:
        """Wait for the compiler, then evaluate the compiled blocks (or stay in the VM where it failed)."""
        if self.compiling is None:
            return
        library, name, per = self.compiling.result()
        self.compiling, self.native = None, True
        if library is None:
            _JIT["works"] = False
            return
        import casadi as ca
        _JIT["per_instruction"] = 0.8 * _JIT["per_instruction"] + 0.2 * per
        self.f = _chain_of(ca.external(name, str(library)), PIECE // self.block)


def _jit_directory() -> str:
    """This process's directory for the JIT's sources and libraries (not the user's working
    directory), removed at exit with its files (CasADi does not clean up after itself there), and
    those of processes that ended without running their exit handlers (pool workers) removed now."""
    if "directory" not in _JIT:
        import atexit
        import shutil
        import tempfile
        for old in Path(tempfile.gettempdir()).glob("skigen-jit-*-*"):
            pid = old.name.split("-")[2]
            if pid.isdigit() and not _alive(int(pid)):
                shutil.rmtree(old, ignore_errors=True)
        _JIT["directory"] = tempfile.mkdtemp(prefix=f"skigen-jit-{os.getpid()}-")
        atexit.register(shutil.rmtree, _JIT["directory"], True)
    return _JIT["directory"] + "/"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)               # signal 0: only asks whether the process exists
    except ProcessLookupError:
        return False
    except PermissionError:           # another user's process: it exists
        return True
    return True


def _call(f, args: list, outs: list[np.ndarray]) -> None:
    """Evaluate the CasADi Function ``f`` on NumPy arrays (no conversion), its results into ``outs``;
    beside the other threads of :func:`parallel`."""
    buf, evaluate = f.buffer()
    args = [np.ascontiguousarray(a, float) for a in args]        # alive until evaluated
    for i, a in enumerate(args):
        buf.set_arg(i, memoryview(a))
    for i, r in enumerate(outs):
        buf.set_res(i, memoryview(r))
    if getattr(_TASK, "holds", False):
        _ONE_AT_A_TIME.release()
        try:
            evaluate()
        finally:
            _ONE_AT_A_TIME.acquire()
    else:
        evaluate()


THREADS = min(4, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)
_ONE_AT_A_TIME = threading.Lock()
_TASK = threading.local()


def parallel(fn, items) -> list:
    """``[fn(x) for x in items]``, the items on up to :data:`THREADS` threads. CasADi releases the
    GIL while it evaluates, so the chains' evaluations (:func:`_call`) run side by side; everything
    else ``fn`` does — Python, and CasADi's symbolic operations, which are not thread-safe — runs
    one task at a time, under one lock. The results are the loop's (each task's numbers do not
    depend on the others'); the first exception raised is raised. Nested calls run as the loop."""
    items = list(items)
    if min(THREADS, len(items)) < 2 or getattr(_TASK, "holds", False):
        return [fn(x) for x in items]

    def task(x):
        with _ONE_AT_A_TIME:
            _TASK.holds = True
            try:
                return fn(x)
            finally:
                _TASK.holds = False
    from concurrent.futures import ThreadPoolExecutor
    pool = ThreadPoolExecutor(min(THREADS, len(items)), thread_name_prefix="skigen")
    try:
        return list(pool.map(task, items))
    finally:                        # after an exception (or ^C) the tasks not yet started are cancelled
        pool.shutdown(wait=True, cancel_futures=True)


def _block(filt: DerivedFilter, step, B: int, name: str = "block"):
    """``step`` (the derived step with its constants as a last input c) over B samples, inlined into
    one SX Function when it has at most :data:`INLINE_BELOW` instructions, else called (a call
    costs about 0.8 µs: the quadrotor's 208-instruction EKF takes 2.1 µs a sample inlined against
    2.9 µs called; the spiral's 39 000-instruction SKI the same 215 µs either way, and its chain
    builds in 1.3 s called against 2.2 s inlined). The step's constants are an input, not numbers,
    so none folds across steps: the block's numbers are the step's (tested against the python
    backend). (z, C, [s], mem, U, Y, valid, c) → the carried (z, C, [s], mem) and per step:
    [z_post; e; diag Pyy; nis; loglik; [s_next]; z_next; mem_next], C_post, C_next, mem."""
    import casadi as ca
    ski, d = filt.has_ard, filt.aug.shapes
    acc = [ca.SX.sym("z", d["n"]), ca.SX.sym("C", d["n"], d["n"])] + ([ca.SX.sym("s", d["nw"])] if ski else []) \
        + [ca.SX.sym("mem", d["nmem"])]
    U, Y, V = ca.SX.sym("u", d["nu"], B), ca.SX.sym("y", d["ny"], B), ca.SX.sym("valid", d["ny"], B)
    c = ca.SX.sym("c", step.size_in(step.n_in() - 1))
    cur, cols, inline = acc, [], step.n_instructions() <= INLINE_BELOW
    for k in range(B):
        z, C, *s, mem = cur
        out = dict(zip(filt.names_out, step.call([z, C, *s, U[:, k], mem, Y[:, k], V[:, k], c], inline, not inline)))
        Cp, Cn, sn = out["C_post"], out["C_next"], [out["s_next"]] if ski else []
        rec = ca.vertcat(out["z_post"], out["e"], ca.diag(out["Pyy"]), out["nis"], out["loglik"], *sn,
                         out["z_next"], out["mem_next"])
        cols.append([rec, Cp, Cn, mem])
        cur = [out["z_next"], Cn] + sn + [out["mem_next"]]
    return ca.Function(name, acc + [U, Y, V, c], cur + [ca.horzcat(*col) for col in zip(*cols)])


def _chain_of(block, blocks: int):
    """``block`` (:func:`_block`, or its compiled library) carried on over ``blocks`` blocks by a
    mapaccum: (z, C, [s], mem, U, Y, valid, c) → per step the block's records, C_post, C_next, mem."""
    import casadi as ca
    n_acc = block.n_in() - 4
    chain = block.mapaccum("chain", blocks, n_acc, {"base": -1})
    ins = [ca.MX.sym("acc", block.sparsity_in(i)) for i in range(n_acc)] + \
        [ca.MX.sym("in", block.size1_in(i), block.size2_in(i) * blocks) for i in range(n_acc, n_acc + 3)] + \
        [ca.MX.sym("c", block.sparsity_in(n_acc + 3))]
    return ca.Function("chain", ins, chain(*ins[:-1], ca.repmat(ins[-1], 1, blocks))[n_acc:])


def _generate(f, directory: str) -> Path:
    """The C source of the Function ``f`` written into ``directory`` (its name: f's)."""
    import casadi as ca
    cg = ca.CodeGenerator(f"{f.name()}.c")
    cg.add(f)
    return Path(cg.generate(directory))


def _compile_lock():
    """This process's compiler lock: one compilation at a time (a forked child makes its own, as
    its copy may be held)."""
    if _JIT.get("pid") != os.getpid():
        _JIT["lock"], _JIT["pid"] = threading.Lock(), os.getpid()
    return _JIT["lock"]


def _background(fn, *args):
    """``fn(*args)`` on a daemon thread, one at a time per process (a Future)."""
    from concurrent.futures import Future
    future, lock = Future(), _compile_lock()

    def work():
        with lock:
            try:
                future.set_result(fn(*args))
            except BaseException as exc:       # handed to whoever waits for it
                future.set_exception(exc)
    threading.Thread(target=work, name="skigen-jit", daemon=True).start()
    return future


def _compile(source: Path, name: str, instructions: int) -> tuple:
    """(the shared library built from ``source``, or None where the compiler fails; the function's
    name; the seconds the compilation took per instruction beyond its fixed cost)."""
    import subprocess
    library, t0 = source.with_suffix(".so"), perf_counter()
    try:
        ok = subprocess.run([JIT_COMPILER, *JIT_FLAGS, "-fPIC", "-shared", str(source), "-o", str(library), "-lm"],
                            capture_output=True).returncode == 0
    except OSError:
        ok = False
    per = max(perf_counter() - t0 - _JIT["seconds"], 0.0) / max(instructions, 1)
    return (library if ok else None), name, per


def structure(f) -> tuple[tuple, np.ndarray]:
    """An SX Function's algorithm without its numeric constants (hashable: equal for Functions that
    differ only in them) and the constants, in the order of :func:`with_constants`'s input."""
    import casadi as ca
    key, consts = [tuple(f.size_in(i)) for i in range(f.n_in())], []
    for k in range(f.n_instructions()):
        op = f.instruction_id(k)
        key += [op, *f.instruction_input(k), -1, *f.instruction_output(k)]
        if op == ca.OP_CONST:
            consts.append(f.instruction_constant(k))
    return tuple(key), np.array(consts)


def with_constants(f):
    """The SX Function ``f`` with its numeric constants as a last input ``c``: the same operations in
    the same order, so it returns f's values to the bit given :func:`structure`'s constants."""
    import casadi as ca
    ins = [ca.SX.sym(f.name_in(i), f.sparsity_in(i)) for i in range(f.n_in())]
    n = f.n_instructions()
    c = ca.SX.sym("c", sum(f.instruction_id(k) == ca.OP_CONST for k in range(n)))
    outs = [[None] * f.nnz_out(i) for i in range(f.n_out())]
    work, j = {}, 0
    for k in range(n):
        op, a, r = f.instruction_id(k), f.instruction_input(k), f.instruction_output(k)
        if op == ca.OP_CONST:
            work[r[0]], j = c[j], j + 1
        elif op == ca.OP_INPUT:
            work[r[0]] = ins[a[0]].nz[a[1]]
        elif op == ca.OP_OUTPUT:
            outs[r[0]][r[1]] = work[a[0]]
        elif len(a) == 1:
            work[r[0]] = ca.SX.unary(op, work[a[0]])
        else:
            work[r[0]] = ca.SX.binary(op, work[a[0]], work[a[1]])
    return ca.Function(f.name(), ins + [c], [ca.SX(f.sparsity_out(i), ca.vertcat(*o) if o else ca.SX(0, 1))
                                                  for i, o in enumerate(outs)],
                       [f.name_in(i) for i in range(f.n_in())] + ["c"], f.name_out())


def _start(stepper, init: dict) -> None:
    """Set the filter state before the first sample: z, C, mem and (SKI) s."""
    why = stepper.filt.start_refusal(init["z"], init["C"])
    if why:
        raise ValueError(f"init refused: {why}")
    stepper.z, stepper.C = np.array(init["z"], float).ravel(), np.array(init["C"], float)
    stepper.mem = np.array(init["mem"], float).ravel()
    if stepper.filt.has_ard and init.get("s") is not None:
        stepper.s = np.array(init["s"], float).ravel()
    stepper.z_post, stepper.C_post = stepper.z, stepper.C


def _part(filt, t, outputs, raw, holes=(), notes=()) -> RunResult:
    """A RunResult from the raw records of a part: NaN where nothing was used."""
    code = np.asarray(raw["code"], int)
    valid = np.isfinite(outputs)
    used = np.asarray(raw["used"]) != 0
    update = used.any(axis=1)
    f = lambda a, mask: np.where(mask, np.asarray(a, float), np.nan)
    mean, std = np.asarray(raw["z_post"], float), np.asarray(raw["std"], float)
    e, ev = f(raw["e"], used), f(raw["pyy"], used)
    nis = f(raw["nis"], update)
    ll = np.where(update, raw["loglik"], 0.0)
    s = np.asarray(raw["s"], float) if filt.has_ard else np.zeros((len(t), 0))
    trace = Trace(*(np.asarray(raw[k], float) for k in ("C_post", "z_next", "C_next", "mem"))) \
        if "C_next" in raw else None
    return RunResult(filt, t, mean, std, e, ev, nis, ll, s, code, np.full((filt.aug.n,) * 2, np.nan),
                     valid, holes, notes, trace, held=raw.get("held"))


def _steps(filt, stepper, backend, pieces, again, holes=(), notes=(), strict=False, trace=False, gate=Guard.gate):
    """Step over ``pieces`` (grid index of the first sample, t, step inputs, outputs), restarting the
    states before a piece whose first index is in ``again`` (that sample's code: REINITIALISED, as
    the policy's restart, unless the step failed); a RunResult per piece, ``gate`` its gate."""
    explained = False
    for a, t, u, y in pieces:
        restart = a in again and a > 0
        if restart:
            forget_states(stepper, filt)
        start = stepper.snapshot() if not explained and hasattr(stepper, "snapshot") else None
        raw = _step_python(stepper, u, y, trace) if backend == "python" else stepper.run_many(u, y)
        if restart and raw["code"][0] != Status.NUMERICAL_FAILURE:
            raw["code"][0] = Status.REINITIALISED
        if strict and np.any(np.asarray(raw["code"]) == Status.NUMERICAL_FAILURE):
            raise FloatingPointError(f"the {filt.kind} filter of '{filt.aug.model.name}' produced non-finite "
                                     f"numbers at t = {clock(t[np.argmax(raw['code'] == Status.NUMERICAL_FAILURE)])} s")
        part = _part(filt, t, y, raw, holes, notes)
        part.gate = gate
        if start is not None and (failed := np.flatnonzero(part.code == Status.NUMERICAL_FAILURE)).size:
            part.failure, explained = _explain(filt, stepper, backend, start, failed[0], u, y), True
        C = np.asarray(stepper.C_post, float)
        part.final_cov = C @ C.T if filt.square_root else C
        part.next_prior = np.array(stepper.z, float).ravel(), np.array(stepper.C, float)
        yield part


def _explain(filt: DerivedFilter, stepper, backend: str, start, k: int, u, y) -> str | None:
    """:func:`failure.explain` for sample ``k`` of a part that began at state ``start`` (a
    snapshot): the part is stepped again up to it, for the prior, the input history and the held
    input the failed step had; the stepper is left as it was."""
    end = stepper.snapshot()
    stepper.restore(start)
    if k:
        _step_python(stepper, u[:k], y[:k]) if backend == "python" else stepper.run_many(u[:k], y[:k])
    uk = np.array(u[k], float).ravel()
    held = np.ravel(stepper.u_held)
    uk[:len(held)] = np.where(np.isfinite(uk[:len(held)]), uk[:len(held)], held)
    uk = np.nan_to_num(uk)
    py = stepper if backend == "python" else PythonStepper(filt)
    for name in ("z", "C", "mem", "s"):
        if hasattr(stepper, name) and hasattr(py, name):
            setattr(py, name, np.array(getattr(stepper, name), float))
    prior = (py.z.ravel(), py.C)
    out, _ = py._run(uk, np.nan_to_num(y[k]), np.isfinite(y[k]))       # the posterior it predicted from
    post = out["z_post"].ravel(), out["C_post"]
    finite = all(np.all(np.isfinite(a)) for a in post)
    why = explain(filt, prior, post if finite else None, uk, np.ravel(py.mem))
    stepper.restore(end)
    return why


RESTART_SCALE = Guard.reinit_scale   # after an input hole: this times the declared covariance, as a recovery


def restarts(rec: Recording, model: Model) -> list[int]:
    """Grid samples at which an input is known again after a hole in it (:func:`grid.first_known`)."""
    ks = {int(first_known(h.t1 - rec.t[0], model.dt, model.input_hold)) for h in rec.input_holes}
    return sorted(k for k in ks if 0 < k < len(rec.t))


def held_through(t: np.ndarray, k: np.ndarray, holes, dt: float, hold: str) -> np.ndarray:
    """True at the grid samples ``k`` (times ``t``, s) inside an input hole (t0, t1), up to the one
    at which the input is known again (:func:`restarts`): the held value is not the input there, so
    the step gets a non-finite input and the policy's bad-input rule predicts with the last known
    one and uses no reading (an update under a wrong input teaches it to the weights: an aileron
    unknown for 1.5 s moved its effectiveness by 2.4σ, the gyro fused against the held command).
    ``dt``, ``hold``: the model's step and input hold; k counts from the grid's first sample."""
    out = np.zeros(len(t), bool)
    tol, first = 1e-6 * dt, (t[0] - dt * k[0]) if len(t) else 0.0
    for t0, t1 in holes:
        out |= (t > t0 + tol) & (k < first_known(t1 - first, dt, hold))
    return out


def forget_states(stepper, filt: DerivedFilter) -> None:
    """The input was unknown for a while: the physical states restart from RESTART_SCALE times
    their declared covariance (mean kept; the recovery policy's widening, so that the first
    readings after the hole pass the gate where the states have moved) and lose their correlation
    with the weights and parameters, which keep what they learnt. (At 1 times, a motor whose
    speed moved 16 declared std in a 1.5 s hole had its next 25 readings gated.)"""
    nx, square_root = len(filt.aug.model.states), filt.square_root
    C = np.asarray(stepper.C, float)
    P = C @ C.T if square_root else C.copy()
    P[:nx, :] = 0.0
    P[:, :nx] = 0.0
    P[:nx, :nx] = RESTART_SCALE * filt.aug.P0[:nx, :nx]
    new = np.linalg.cholesky(P) if square_root else P
    if hasattr(stepper, "set"):
        stepper.set("C", new)
    else:
        stepper.C = new


def _stepper(filt, backend, real, show_progress, cache_dir, guard=None, init=None, strict=False, trace=False):
    aug, model = filt.aug, filt.aug.model
    if real != "double" and backend != "c":
        raise ValueError(f"real='{real}' is the precision of the generated C: give backend 'c' (the "
                         f"{backend} backend computes in double)")
    if backend == "c" and (init is not None or trace):
        raise ValueError("init and trace need backend 'python' or 'casadi'")
    if backend == "casadi":
        if guard is not None:
            raise ValueError("backend 'casadi' runs the derived step without the guard policy (no gate, "
                             "stuck-sensor test, restart or std bound): give no guard, or use backend "
                             "'python' or 'c' for a guarded run")
        stepper = CasadiStepper(filt, strict, trace)
    elif backend == "c":
        from .emit.c import load_c
        cf = load_c(filt, real, cache_dir=cache_dir)
        if guard is not None:
            cf.configure(guard)
        return cf
    elif backend == "python":
        if show_progress and "step" not in filt.__dict__ and aug.n > SLOW_DERIVATION_N:
            note(f"deriving the {filt.kind} step of '{model.name}' symbolically (n = {aug.n}: this "
                 f"takes a while; the C backend does not need it)")
        stepper = PythonStepper(filt, guard)
    else:
        raise ValueError(f"unknown backend '{backend}'; choose {', '.join(BACKENDS)}")
    if init is not None:
        _start(stepper, init)
    return stepper


def iter_run(filt: DerivedFilter, rec: Recording, *, backend: str = "python", real: str = "double",
             show_progress: bool = True, label: str | None = None, cache_dir=None, chunk: int | None = None,
             guard: Guard | None = None, init: dict | None = None, strict: bool = False, trace: bool = False,
             cuts=()):
    """:func:`run` part by part: yields a RunResult per ``chunk`` samples, so that a long
    recording can be written as it is filtered. Each part's ``final_cov`` is the posterior
    covariance at its end (the last part's is the run's). cuts: further samples where a part ends."""
    model = filt.aug.model
    check_columns(model, rec)
    stepper = _stepper(filt, backend, real, show_progress, cache_dir, guard, init, strict, trace)
    inputs, N = step_inputs(model, rec.inputs), len(rec.t)
    stale = held_through(rec.t, np.arange(N), [(h.t0, h.t1) for h in rec.input_holes], model.dt, model.input_hold)
    if stale.any():
        inputs = np.array(inputs, float)
        inputs[stale] = np.nan
    chunk = chunk or CHUNK[backend]
    again = set(restarts(rec, model))
    bounds = sorted(set(range(0, N, chunk)) | again | {k for k in cuts if 0 < k < N}) + [N]
    label = label or f"{model.name} {filt.kind} ({backend})"
    parts = list(zip(bounds[:-1], bounds[1:]))
    pieces = ((a, rec.t[a:b], inputs[a:b], rec.outputs[a:b]) for a, b in
              (progress(parts, len(parts), f"{label}, {N} samples in parts") if show_progress else parts))
    yield from _steps(filt, stepper, backend, pieces, again, rec.holes, rec.notes, strict, trace,
                      _gate(backend, guard))


def _stream_pieces(grid, foh: bool, chunk: int):
    """(first grid index, t, step inputs, outputs) from a GridStream's blocks, at most ``chunk``
    samples each and cut where the states restart. A first-order hold steps with [u[k], u[k+1]]:
    the last sample of a block waits for the first of the next (the last of all holds its input)."""
    held = None
    for blk in grid:
        if held is not None:
            blk = type(blk)(held.k0, np.concatenate([held.t, blk.t]), np.concatenate([held.inputs, blk.inputs]),
                            np.concatenate([held.outputs, blk.outputs]))
            held = None
        if foh:
            m = len(blk.t) - 1
            u = np.hstack([blk.inputs[:m], blk.inputs[1:]])
            held = type(blk)(blk.k0 + m, blk.t[m:], blk.inputs[m:], blk.outputs[m:])
        else:
            m, u = len(blk.t), blk.inputs
        yield from _cut(grid, blk.k0, blk.t[:m], u, blk.outputs[:m], chunk)
    if held is not None:
        yield from _cut(grid, held.k0, held.t, np.hstack([held.inputs, held.inputs]), held.outputs, chunk)


def _cut(grid, k0, t, u, y, chunk):
    m = len(t)
    holes = [(a + grid.origin, b + grid.origin) for (a, b), names in grid.spans.items()
             if any(n in grid.input_names for n in names)]
    if holes:
        u = np.array(u, float)
        u[held_through(t, k0 + np.arange(m), holes, grid.dt, grid.hold)] = np.nan
    cuts = sorted({0, m} | set(range(0, m, chunk)) | {k - k0 for k in grid.restarts if k0 < k < k0 + m})
    for a, b in zip(cuts[:-1], cuts[1:]):
        yield k0 + a, t[a:b], u[a:b], y[a:b]


def iter_run_stream(filt: DerivedFilter, grid, *, backend: str = "python", real: str = "double",
                    show_progress: bool = True, label: str | None = None, cache_dir=None,
                    chunk: int | None = None, guard: Guard | None = None):
    """:func:`iter_run` over a :class:`~skigen.grid.GridStream` (a CSV file read block by block):
    the same parts, sample for sample, while memory holds a block and not the recording. The
    parts carry no holes or notes: ``grid.holes`` and ``grid.notes`` are complete at the end."""
    model = filt.aug.model
    want = (tuple(model.input_names), tuple(model.output_names))
    if (grid.input_names, grid.output_names) != want:
        raise ValueError(f"{grid.stream.source}: the stream reads {grid.input_names + grid.output_names}, "
                         f"model '{model.name}' has {want[0] + want[1]}")
    stepper = _stepper(filt, backend, real, show_progress, cache_dir, guard)
    chunk = chunk or CHUNK[backend]
    label = label or f"{model.name} {filt.kind} ({backend})"
    pieces = _stream_pieces(grid, model.input_hold == "foh", chunk)
    if show_progress:
        pieces = _streamed(pieces, grid, f"{label}, streamed")
    yield from _steps(filt, stepper, backend, pieces, grid.restarts, gate=_gate(backend, guard))


def _streamed(pieces, grid, label: str):
    """``pieces`` with a progress line: the share of the file's time span (its first and last stamps,
    read first) that the pieces have reached; without those stamps, the pieces counted."""
    stamps = grid.stream.stamps() if hasattr(grid.stream, "stamps") else None
    if stamps is None:
        return progress(pieces, None, label)
    reached = [0.0]

    def share() -> float:              # the pieces' times are the file's, in seconds
        if grid.scale is None:
            return 0.0
        return float(np.clip((reached[0] - stamps[0] * grid.scale) / ((stamps[1] - stamps[0]) * grid.scale), 0, 1))

    def walk():
        for piece in pieces:
            reached[0] = float(piece[1][-1]) if len(piece[1]) else reached[0]
            yield piece
    return progress(walk(), 1.0, label, measure=share)


def _gate(backend: str, guard: Guard | None) -> float:
    """The innovation gate a run has, in std: none on the casadi backend."""
    return 0.0 if backend == "casadi" else (guard or Guard()).gate


def run(filt: DerivedFilter, rec: Recording, *, backend: str = "python", real: str = "double",
        show_progress: bool = True, label: str | None = None, cache_dir=None,
        guard: Guard | None = None, init: dict | None = None, strict: bool = False,
        trace: bool = False) -> RunResult:
    """Filter the whole recording; returns the posterior at every sample.

    backend: ``"python"`` (the CasADi Function, stepped sample by sample), ``"c"``
    (the generated C, compiled and cached on first use, in ``real`` precision) or
    ``"casadi"`` (the Function chained over the recording by CasADi, without the
    guard policy: see the module docstring). guard: the recovery policy's settings
    (default :class:`~skigen.guard.Guard`; not with ``casadi``). init: the filter
    state before the first sample, a dict like :meth:`DerivedFilter.initial`'s
    (``python`` and ``casadi``). strict: a step that gives a non-finite number
    raises FloatingPointError instead of being rejected. trace: also record the
    per-sample covariances (:class:`Trace`, ``python`` and ``casadi``).
    """
    return RunResult.concat(list(iter_run(filt, rec, backend=backend, real=real, show_progress=show_progress,
                                          label=label, cache_dir=cache_dir, guard=guard, init=init,
                                          strict=strict, trace=trace)))
