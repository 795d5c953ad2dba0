"""Grey-box fitting: a model's declared parameters, unknown-term weights, initial
states and (filter error) noise intensities from one or several recordings.

    result = fit(model, [recording, ...], method="output-error")
    result.parameters["k"]  # {"value", "std", "initial", "bounds"}
    result.model            # a copy of the model at the fitted values, std as prior

See :mod:`skigen.fit.problem` for the likelihood and :mod:`skigen.fit.uncertainty`
for the error bars.
"""
from __future__ import annotations

import contextlib
import copy
import functools
import itertools
import math
import os
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from time import perf_counter

import casadi as ca
import numpy as np
from scipy.optimize import minimize, minimize_scalar

from ..grid import clock
from ..model import Model, ModelError
from ..progress import note
from ..recording import Recording, load_recording, resolution
from ..start import recorded_start, vague_covariance, vague_start
from ..simulate import AMPLIFICATION, growth_rate, simulation_window
from .problem import LOG_SCALE_BOUND, METHODS, Problem, build_problem, data_matrix
from .uncertainty import covariance, recording_shifts, unidentified

__all__ = ["FitError", "NotIdentifiable", "FitResult", "fit", "METHODS"]

_IPOPT_WORDS = {
    "Solve_Succeeded": "converged",
    "Solved_To_Acceptable_Level": "converged to the acceptable tolerance",
    "Maximum_Iterations_Exceeded": "stopped at the iteration limit before converging (raise max_iter, "
                                   "or start nearer: are the declared values of the right order? A ridge "
                                   "of two constants the recordings hardly tell apart, an Arrhenius k0 "
                                   "and E, also takes many steps)",
    "Maximum_CpuTime_Exceeded": "ran out of time before converging",
    "Infeasible_Problem_Detected": "found the constraints infeasible (multiple shooting could not be "
                                   "made continuous: try longer shooting intervals)",
    "Restoration_Failed": "could not make progress (restoration failed): the likelihood may be flat "
                          "or not smooth near the start; check units and initial values",
    "Error_In_Step_Computation": "failed to compute a step (the problem is numerically singular)",
    "Invalid_Number_Detected": "met a non-finite value (the simulation diverges for some trial "
                               "parameters: add bounds, or use shorter shooting intervals)",
    "Solved_To_Negligible_Step": "converged: Fisher scoring puts the optimum within 0.02 standard errors "
                                 "of every estimate, or its last steps moved none by more",
    "Diverging_Iterates": "diverged (a parameter grew without bound: is it identifiable? add bounds)",
}


class FitError(ValueError):
    """A fit that cannot be done or did not succeed; the message says why and names the culprit."""


class NotIdentifiable(FitError):
    """The recordings cannot identify every quantity to estimate; the message names them, and
    ``lost`` says which, one sentence per set the data cannot tell apart."""

    def __init__(self, message: str, lost: list[str] = ()):
        super().__init__(message)
        self.lost = list(lost)


@dataclass
class FitResult:
    """What :func:`fit` found. Values in the model's units; std from the covariance."""

    method: str
    model: Model                              # the fitted model (parameters at their values, std as prior)
    parameters: dict                          # name → {value, std, initial, bounds}
    weights: dict                             # name → {value, std}
    initial_states: list[dict]                # per recording: state name → {value, std}
    noise: dict                               # method-dependent: residual std, or Q/R scales
    correlation: dict                         # {"names": [...], "matrix": [[...]]}
    recordings: list[dict]                    # per recording: file, rmse per output, loglik, samples
    converged: bool
    status: str
    iterations: int
    seconds: float
    objective: float
    covariance_note: str
    predictions: list[np.ndarray] = field(repr=False, default_factory=list)   # (N, ny) per recording
    notes: list[str] = field(default_factory=list)                            # what the fit decided on its own
    fitted_recordings: list[Recording] = field(repr=False, default_factory=list)   # as fitted (cut at input holes)

    def asdict(self) -> dict:
        """The fit.json contract."""
        return {k: getattr(self, k) for k in ("method", "parameters", "weights", "initial_states", "noise",
                                              "correlation", "recordings", "converged", "status",
                                              "iterations", "seconds", "objective", "covariance_note", "notes")}


_CACHE: dict = {}
SCORING_ITERATIONS = 50     # Fisher-scoring iterations before Newton (exact Hessian) takes over


def _problem(model, lengths, method, estimate, shooting, max_iter, tol=1e-8) -> Problem:
    key = (id(model), tuple(lengths), method, tuple(estimate), shooting, max_iter, tol,
           tuple((p.name, p.value, p.std, p.bounds) for p in model.parameters), tuple(model.x0),
           tuple(model.x_std))
    if key not in _CACHE:
        if len(_CACHE) > 16:
            _CACHE.clear()
        prob = build_problem(model, lengths, method, estimate, shooting)
        prob.progress = _Progress(prob.nlp["x"].shape[0], prob.nlp["g"].shape[0])
        nlp = {k: prob.nlp[k] for k in ("x", "p", "f", "g")}
        opts = {"print_time": False, "iteration_callback": prob.progress, "ipopt.print_level": 0,
                "ipopt.sb": "yes", "ipopt.tol": tol, "ipopt.mu_strategy": "adaptive",
                "ipopt.acceptable_tol": 100 * tol, "ipopt.acceptable_iter": 2,
                "ipopt.acceptable_obj_change_tol": 1e-12, "calc_lam_p": False, "no_nlp_grad": True,
                "show_eval_warnings": False}   # a trial point where the model overflows: IPOPT steps back
        scoring = ca.nlpsol("fit_scoring", "ipopt", nlp, {**opts, "hess_lag": prob.nlp["hess"], "grad_f": prob.nlp["grad"],
                                                          "ipopt.max_iter": min(max_iter, SCORING_ITERATIONS)})
        newton = lambda: ca.nlpsol("fit_newton", "ipopt", nlp, {**opts, "ipopt.max_iter": max_iter})
        solver = (scoring, functools.lru_cache(maxsize=1)(newton))
        jac_g = ca.Function("jac_g", [prob.nlp["x"], prob.nlp["p"]], [ca.jacobian(prob.nlp["g"], prob.nlp["x"])])
        _CACHE[key] = (prob, solver, jac_g, model)      # keep the model alive: its id is in the key
    return _CACHE[key][:3]


def _check_estimate(model: Model, estimate, notes: list[str]) -> list[str]:
    """The names to estimate (default: every parameter and weight), each checked; a declared
    parameter that enters no equation is refused when named, and held with a note by default."""
    known = model.parameter_names + model.weight_names
    names = known if estimate is None else list(dict.fromkeys(estimate))
    for n in names:
        if n not in known:
            raise ModelError(f"cannot estimate '{n}': model '{model.name}' has no parameter or weight of "
                             f"that name (parameters: {', '.join(model.parameter_names) or 'none'}; "
                             f"weights: {', '.join(model.weight_names) or 'none'})")
    exprs = ca.vertcat(*model.rhs.values(), *[v.sym for v in model.outputs],
                       *[ca.vec(t.expr) for _, _, t, _ in model.weights()])
    unused = [p.name for p in model.parameters if p.name in names and not ca.depends_on(exprs, p.sym)]
    if unused and estimate is not None:
        raise ModelError(f"cannot estimate {', '.join(map(repr, unused))}: declared in model '{model.name}' but "
                         f"used in no equation or output")
    if unused:
        notes.append(f"parameter(s) {', '.join(map(repr, unused))} used in no equation or output of "
                     f"'{model.name}': held at the declared value")
    return [n for n in names if n not in unused]


def _check_recording(model: Model, rec: Recording):
    from ..runtime import check_columns
    check_columns(model, rec)
    if not np.isfinite(rec.inputs).all():
        i = int(np.argwhere(~np.isfinite(rec.inputs))[0, 0])
        raise FitError(f"{rec.path}: input missing at t = {rec.t[i]:g} s; a fit needs every input")
    if not np.isfinite(rec.outputs).any():
        raise FitError(f"{rec.path}: no output is measured")
    if stuck := rec.stuck_output():
        raise FitError(stuck)


def _first_bad(values: np.ndarray, lengths: list[int], recs) -> str | None:
    bad = ~np.all(np.isfinite(values), axis=0)
    if not bad.any():
        return None
    k = int(np.argmax(bad))
    for r, n in enumerate(lengths):
        if k < n:
            return f"{recs[r].path} at t = {recs[r].t[k]:g} s (sample {k})"
        k -= n
    return "an unknown sample"


class _Progress(ca.Callback):
    """IPOPT's iterations as a line each, where progress is shown."""

    def __init__(self, nx: int, ng: int):
        ca.Callback.__init__(self)
        self.nx, self.ng = nx, ng
        self.start("fit")
        self.construct("fit_progress", {})

    def start(self, label: str | None, negligible=None):
        """negligible(ξ, recent iterates) → True where the remaining gain is negligible: IPOPT then stops."""
        self.label, self.iteration, self.t0 = label, 0, perf_counter()
        self.negligible, self.history, self.next_check, self.stopped = negligible, [], 0, False
        self.iterates = []

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        n = ca.nlpsol_out(i)
        if n == "f":
            return ca.Sparsity.scalar()
        if n in ("x", "lam_x"):
            return ca.Sparsity.dense(self.nx)
        if n in ("g", "lam_g"):
            return ca.Sparsity.dense(self.ng)
        return ca.Sparsity(0, 0)

    def eval(self, arg):
        f = float(arg[1])
        if self.label:
            note(f"{self.label}: iteration {self.iteration}, -log L {f:.7g} "
                 f"({perf_counter() - self.t0:.1f} s)")
        self.iteration += 1
        self.history.append(f)
        self.iterates = self.iterates[-STALL:] + [np.asarray(arg[0]).ravel()]
        if (self.negligible and len(self.history) > STALL and self.iteration >= self.next_check
                and self.history[-STALL - 1] - f < STALL_GAIN):
            self.next_check = self.iteration + STALL
            if self.negligible(self.iterates[-1], self.iterates):
                self.stopped = True
                return [1]
        return [0]


def fit(model: Model, recordings, *, method: str = "output-error", estimate=None,
        shooting: int | None = None, max_iter: int = 200, tol: float = 1e-8,
        starts=None, show_progress: bool = True, time=None, time_unit: str = "s", columns=None,
        max_gap: float = 1.0, noise_from=None, noise_caps=None) -> FitResult:
    """Fit ``model`` to ``recordings`` (Recording objects, or paths and DataFrames read onto the
    model's grid with :func:`skigen.recording.load_recording`) by ``method``.

    estimate: names of parameters and weights to estimate (default: all of
    them); the rest stay at their declared values (weights at 0). shooting:
    output error only, samples per shooting interval (default: one simulation
    per recording; give a few hundred samples when a free run diverges). tol: IPOPT's
    convergence tolerance. starts: filter error only, per recording the filter's state before its
    first sample, (mean (nx,), covariance (nx, nx)), or None for the model's initial state and
    covariance — unless the recording rejects it (:mod:`skigen.start`: a log that begins in
    motion), then the declared mean with 100² times that covariance (a state further than 3 of
    those std off: where the recording starts), and a note (the default for
    every recording; ``initial_states`` gives where such a recording starts, smoothed by the
    fitted model); ``"declared"``: the model's initial state for every
    recording, untested. A recording cut from a longer one starts where a filter run over that one stood. time, time_unit, columns, max_gap: how to read recordings
    given as paths or DataFrames (see :func:`skigen.recording.load_recording`). noise_from:
    filter error only, another (Q, R) to start the noise from as well, the more likely optimum
    kept (a diagnosis gives the user's declared noise to a model that carries a calibrated one).
    noise_caps: filter error only, {state: variance} its process noise may not exceed; by default
    each kinematic identity ṗ = v (:meth:`Model.kinematic`), exact by definition, is held to the
    noise declared on it, in ``noise_from`` where given (freed, an altitude's noise took 2700× its
    declared variance from the vertical speed's on 5 of 12 hover flights of a right model, whose
    thrust's error bars then missed the truth by up to 4.5 of them); ``{}`` frees them. A state
    no output sees keeps its declared process noise (``noise["unseen"]``, and a note).
    """
    t0 = perf_counter()
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got '{method}'")
    model.check()
    if isinstance(recordings, (Recording, str, os.PathLike)) or hasattr(recordings, "columns"):   # one, or a DataFrame
        recordings = [recordings]
    read = dict(time=time, time_unit=time_unit, columns=columns, max_gap=max_gap)
    recs = [r if isinstance(r, Recording) else load_recording(r, model, **read) for r in recordings]
    names = [str(r.path) for r in recs]          # several DataFrames (or one file twice): told apart by place
    recs = [replace(r, path=f"{n} #{k + 1}") if names.count(n) > 1 else r for k, (r, n) in enumerate(zip(recs, names))]
    if not recs:
        raise FitError("no recording to fit")
    for rec in recs:
        _check_recording(model, rec)
    declared = isinstance(starts, str)
    if declared and starts != "declared":
        raise ValueError(f"starts must be a list or 'declared', got '{starts}'")
    twice, units = _repeated(recs), unit_notes(model, recs)
    with _said_with(units):
        recs, starts, notes = _usable(recs, None if declared else starts)
        notes = units + notes + twice
        estimate = _check_estimate(model, estimate, notes)
        if shooting is not None and (method != "output-error" or int(shooting) < 2):
            raise ValueError("shooting applies to output error and needs at least 2 samples per interval")
        lengths = [len(r.t) for r in recs]
        prob, solver, jac_g = _problem(model, lengths, method, estimate, shooting, max_iter, tol)
        V = prob.variables
        blocks = [data_matrix(model, r) for r in recs]
        data = np.concatenate([np.ravel(b, order="F") for b in blocks])
        if method == "filter-error":                 # the NLP's parameter: [scale; data; starts]
            tested = [None] * len(recs)
            data = np.r_[data, _starts(model, recs, starts, declared, notes, tested)]
        elif starts is not None or declared:
            raise ValueError("starts applies to filter error (output error estimates the initial states)")
        theta0 = np.array(prob.solver_inputs["x0"], float)
        if method == "output-error":
            X = _filtered_states(prob, theta0, blocks)
            theta0 = _initial_guess(model, prob, recs, theta0, X)
        nominal = np.array(V.scale)
        rho0, _ = (np.asarray(v) for v in prob.residuals(theta0 / nominal, np.r_[nominal, data]))
        where = _first_bad(rho0, lengths, recs)
        if where:
            why = model.unstable_step()
            hint = (f": {why}" if why else "; use shorter shooting intervals" if shooting else
                    "; give a shooting interval (shooting=... samples, --shooting) to fit it by multiple shooting")
            raise FitError(f"the simulation of '{model.name}' at the initial values diverges in {where}{hint}")
        if method == "output-error":
            _refuse_a_runaway_simulation(model, recs, X)
        declared_problem, weighted = (prob, solver, jac_g), False
        if method == "output-error" and np.nanmax(np.nanmean(rho0 ** 2, axis=1)) > STRAY:
            weighted = True                                     # a free run strays far beyond the sensor noise
            prob, solver, jac_g = _problem(_weighted_by_free_run(model, rho0), lengths, method, estimate, shooting,
                                           max_iter, tol)
            V = prob.variables
        scale, J0, prior = _scales(prob, theta0, data)
        p = np.r_[scale, data]
        unseen = [o for j, o in enumerate(model.output_names) if not any(np.isfinite(r.outputs[:, j]).any() for r in recs)]
        held = [V.names.index(f"R_scale_{o}") for o in unseen if f"R_scale_{o}" in V.names]
        if held:                                    # a never-measured output's noise: nothing to calibrate it on
            notes.append(f"output(s) {', '.join(map(repr, unseen))} never measured in these recordings: their noise "
                         f"is held at its declared value")
        with np.errstate(over="ignore", invalid="ignore"):
            dead = [i for i, k in enumerate(V.kinds) if k == "noise" and V.names[i].startswith("Q_scale_")
                    and i not in held and not np.any(J0[:, i]) and not prior.ravel()[i]]
        unseen_states = [V.names[i].removeprefix("Q_scale_") for i in dead]
        if dead:                                    # a state no output sees: its noise moves no prediction
            held += dead
            notes.append(unseen_noise_note(unseen_states))
        with np.errstate(over="ignore", invalid="ignore"):
            unseen_starts = [i for i, k in enumerate(V.kinds) if k == "initial" and not np.any(J0[:, i])
                             and not prior.ravel()[i]]
        if unseen_starts:                           # output error: a state no output sees starts anywhere
            held += unseen_starts
            notes.append(f"the initial value of {', '.join(sorted({V.names[i].split('@')[0] for i in unseen_starts}))} "
                         f"is held at the declared one: no output sees it")
        free = [i for i in range(len(V)) if i not in held]
        G = _dense(jac_g(theta0 / scale, p))
        lost = unidentified(J0[:, free], prior.ravel()[free], [V.names[i] for i in free], G[:, free])
        lost = [_acts_elsewhere(prob, theta0, scale, p, V, model, s) for s in lost]
        if lost and method != "output-error":
            raise _not_identifiable(model, lost)
        lower = _resolution_floor(model, V, recs, prob.solver_inputs["lbx"])
        inputs = dict(prob.solver_inputs, x0=np.maximum(theta0, lower) / scale, lbx=lower / scale,
                      ubx=prob.solver_inputs["ubx"] / scale, p=p)
        for i in held:
            inputs["lbx"][i] = inputs["ubx"][i] = inputs["x0"][i]
        if noise_caps is None:                     # the user's declared noise, where noise_from gives it
            q = np.diag(noise_from[0] if noise_from is not None else model.process_noise())
            noise_caps = {k: float(q[i]) for k in model.kinematic() if (i := model.state_names.index(k)) < len(q)
                          and q[i] > 0}
        for i, top in _capped(V, model, noise_caps):
            inputs["ubx"][i] = min(inputs["ubx"][i], top)
            inputs["x0"][i] = min(inputs["x0"][i], top)
        declared_noise = inputs["x0"]
        if method == "filter-error":
            inputs["x0"] = _noise_start(prob, inputs)
        if show_progress:
            note(f"fitting '{model.name}' by {method}: {len(V)} unknowns, {sum(lengths)} samples")
        negligible = None if prob.nlp["g"].shape[0] else functools.partial(_negligible_gain, prob, inputs)
        try:
            sol, stats = _solve(prob, solver, inputs, negligible, model.name if show_progress else None)
        except FitError:
            if lost:
                raise _not_identifiable(model, lost) from None
            raise
        if weighted and (polished := _polished(declared_problem, sol, scale, data, lower, inputs, show_progress,
                                               model.name)):
            (prob, solver, jac_g), scale, p, inputs, sol, more = polished
            V = prob.variables
            stats = dict(more, iter_count=stats["iter_count"] + more["iter_count"])
        robust = method == "output-error"      # simulation residuals may be coloured; innovations are white
        xi, rho, nll, C, info = _at_optimum(prob, jac_g, sol, inputs, lengths, robust)
        if lost:          # seen at the start only: the free run there may not move what tells them apart
            J, prior = info["J"], info["prior"]
            if again := unidentified(J[:, free], prior.ravel()[free], [V.names[i] for i in free],
                                     _dense(jac_g(xi, p))[:, free]):
                raise _not_identifiable(model, [_acts_elsewhere(prob, xi * scale, scale, p, V, model, s) for s in again])
            notes.append(f"output error: at the starting values the free run did not tell every quantity apart "
                         f"({'; '.join(lost)}); at the optimum it does")
        if method == "filter-error":
            for again in _noise_restarts(prob, model, inputs, declared_noise, sol, xi, C, noise_from):
                more, more_stats = _solve(prob, solver, again, negligible, model.name if show_progress else None)
                if float(more["f"]) < float(sol["f"]):
                    sol, stats = more, dict(more_stats, iter_count=stats["iter_count"] + more_stats["iter_count"])
                    xi, rho, nll, C, info = _at_optimum(prob, jac_g, sol, inputs, lengths, robust)
            if (again := _held_noise_start(prob, solver, inputs, declared_noise, xi, negligible)) is not None:
                more, more_stats = _solve(prob, solver, again, negligible, model.name if show_progress else None)
                if float(more["f"]) < float(sol["f"]) - HELD_GAIN:
                    notes.append(f"filter error: a second optimum, {float(sol['f']) - float(more['f']):.3g} nat more "
                                 f"likely, was reached from the parameters fitted with the declared noise held (the "
                                 f"first had given the process noise {np.exp(np.max(xi[_q_rows(prob)])):.3g}× its "
                                 f"declared variance)")
                    sol, stats = more, dict(more_stats, iter_count=stats["iter_count"] + more_stats["iter_count"])
                    xi, rho, nll, C, info = _at_optimum(prob, jac_g, sol, inputs, lengths, robust)
        status = stats["return_status"]
        value = xi * scale
        std = np.sqrt(np.clip(np.diag(C), 0, None)) * scale
        fisher_std = dict(zip(V.names, np.sqrt(np.clip(info["fisher_var"], 0, None)) * scale))
        C = C * np.outer(scale, scale)
        fitted_at = [i for i, k in enumerate(V.kinds) if k in ("parameter", "weight")
                     and V.names[i] in estimate]
        Y = np.asarray(prob.predict(xi, p)).T
        result = _result(model, prob, recs, lengths, method, estimate, value, std, C, fitted_at,
                         nll, Y, stats, status, perf_counter() - t0, float(sol["f"]), info, robust)
        if unseen_states:
            result.noise["unseen"] = unseen_states
        for i, side in _flat_sides(prob, xi, inputs, std / scale, info["information"], fitted_at).items():
            ({**result.parameters, **result.weights})[V.names[i]]["flat"] = side
        if method == "filter-error":
            fitted_start = _fitted_starts(result.model, recs, tested)
            back = [fs.consistent for fs in fitted_start if fs is not None]   # all: judged off at wrong values
            result.initial_states = [{} if rs is None or rs.consistent else
                                     {n: dict(value=float(v), std=float(s)) for n, v, s in zip(rs.names, rs.mean, rs.std)}
                                     for rs in fitted_start]
            for report, rec, Yr, rs in zip(result.recordings, recs, result.predictions, tested):
                if rs is not None and not rs.consistent:    # the head, where the filter learns the start, left out
                    e = rec.outputs[rs.head:] - Yr[rs.head:]
                    report.update(rmse={o: rms(e[:, j]) for j, o in enumerate(model.output_names)}, rmse_from=rs.head)
        result.notes = (notes + _unseen_notes(result) + _bound_notes(result.parameters) + _far_notes(result.parameters)
                        + _prior_notes(model, result.parameters, fisher_std)
                        + _correlated(result.correlation, {*result.parameters, *result.weights})
                        + _unequal_residuals(result.recordings, recs, result.predictions, model.output_names))
        driven = [n for n, q in zip(model.state_names, np.diag(model.process_noise())) if q > 0]
        if method == "filter-error" and not driven:
            result.notes.append(f"'{model.name}' declares no process noise on any state, so filter error calibrates "
                                f"none: it is output error through a filter, and process noise in the plant goes to "
                                f"the sensor noise and narrows the error bars. Declare a process_std on the states "
                                f"it drives to have it calibrated")
        if method == "filter-error":
            alone = functools.partial(_fitted_alone, model, estimate, noise_from, noise_caps)
            result.notes += (_absorbing(model, result.noise) + _trusting(result.noise)
                             + _following(result.model, recs, tested)
                             + _disagreeing(prob, xi, rho, info["J"], info["prior"], lengths, fitted_at, scale, recs,
                                            alone))
        if method == "output-error" and (params := list(result.parameters) + list(result.weights)):
            result.notes += _unexplained_residuals(model, recs, result.predictions, params)
        A = result.model.state_jacobian()         # a yaw damping 6.81 ± 0.045 for 8 under Euler, said nowhere
        if A is not None and (step := result.model.step_note([A], "with the fitted parameters")):
            result.notes.append(f"integration: {step} and fit again")
        result.fitted_recordings = recs
        if method == "filter-error" and back and all(back):
            again = fit(model, recs, method=method, estimate=estimate, max_iter=max_iter, tol=tol, starts="declared",
                        show_progress=show_progress, noise_from=noise_from, noise_caps=noise_caps)
            again.notes.append(f"filter error: the recordings' start, judged against the declared one at the starting "
                               f"values, agrees with it at the fitted ones: refitted from the declared start, "
                               f"{result.objective - again.objective:.3g} nat more likely")
            again.seconds += result.seconds
            return again
        return result


def _fitted_starts(fitted: Model, recs, tested) -> list:
    """Each recording judged off the declared start (at the starting values) judged again by the
    fitted model: where it now starts, smoothed by that model (its noise calibrated: at the starting
    values a motor's start was ± 1.1 rad, by the fit ± 2 mrad), or consistent with the declared one —
    then the wrong values, not the recording, moved the start (an epidemic from β = 0.3 for 0.4
    was given a vague start and an initial S 4σ off the true one). None elsewhere."""
    return [None if rs is None or rs.consistent else recorded_start(fitted, rec) or rs
            for rs, rec in zip(tested, recs)]


ELSEWHERE = [2.0 ** -k for k in range(1, 11)] + [2.0 ** k for k in range(1, 11)]   # factors of a start tried


def _acts_elsewhere(prob: Problem, theta0, scale, p, V, model: Model, sentence: str) -> str:
    """``sentence`` ('X' has no effect on the likelihood) with, for a declared parameter that has
    an effect at another value within its bounds (its start times ELSEWHERE: halved, then
    doubled, ten times each), that value: a saturation limit started above every recorded command
    is unseen there and seen below."""
    name = sentence.split("'")[1] if sentence.endswith("has no effect on the likelihood") else None
    if name not in model.parameter_names or name not in V.names:
        return sentence
    i, (lo, hi) = V.names.index(name), model.parameter_named(name).bounds
    for k in ELSEWHERE:
        theta = theta0.copy()
        theta[i] = theta0[i] * k
        if not (lo is None or lo <= theta[i]) or not (hi is None or theta[i] <= hi) or theta[i] == theta0[i]:
            continue
        J, _ = fisher(prob, theta / scale, p, finite=False)
        if np.all(np.isfinite(J[:, i])) and np.any(J[:, i] != 0):
            return (f"{sentence} at {theta0[i]:.6g}, but it has at {theta[i]:.6g}: the recordings do not reach "
                    f"where it acts from there (a limit beyond every recorded command); start it within what "
                    f"the recordings reach")
    return sentence


def unseen_noise_note(states: list[str]) -> str:
    """The note on the states whose process noise filter error holds: no output sees them."""
    return (f"the process noise of {', '.join(states)} is held at its declared value: no output sees "
            f"{'it' if len(states) == 1 else 'them'}, and no recording can calibrate it")


SAID_SETS = 3      # sets that cannot be told apart said in a message; the rest counted (all in ``lost``)


def _not_identifiable(model: Model, lost: list[str]) -> NotIdentifiable:
    said = "; ".join(lost[:SAID_SETS]) + (f"; and {len(lost) - SAID_SETS} more such set(s)"
                                           if len(lost) > SAID_SETS else "")
    return NotIdentifiable(f"the recordings cannot identify every quantity of '{model.name}': " + said
                           + ". Hold some at their declared values (estimate only the others: estimate=[...] in "
                           "Python, --estimate NAME for each on the command line), give them a prior std, or "
                           "record richer excitation", lost)


AT_BOUND = 1e-3     # standard errors: an estimate this close to a bound sits on it, if also within
ON_BOUND = 1e-6     # × its size (at least 1): a std of 6.6e4 put 1.64 'on' a bound at 1e-5
VAGUE = 10.0        # a std this many times the value: the data hardly determine it
PRIOR_CONFLICT = 3.0   # stds of the shift a right prior allows: a shift beyond says they disagree
PRIOR_ONLY = 0.9       # a posterior std this share of the prior's or more: the recordings hardly inform it
COLOURED = 1.5         # output error: a reported std this many times the white one outweighs a prior


FAR = 10.0     # a parameter fitted this many times larger or smaller than its starting value: said


def _far_notes(parameters: dict) -> list[str]:
    """Declared parameters the fit moved FAR-fold or more from their declared values: a
    unit or scaling slip in what they multiply is likelier than a datasheet that far off (a PWM
    command in µs where the model wants a fraction put a thrust constant at 0.0084 for 18); not one
    the recordings hardly determine, within 2 std of its declared value (a drag 0.00136 ± 0.74 on
    a hover at constant throttle for a declared 0.3 was sent to check the units); nor one within 2
    std of zero, which says the effect is absent, not scaled (:func:`_bound_notes`)."""
    out = []
    for name, p in parameters.items():
        a, b = p["initial"], p["value"]
        if (a and b and np.isfinite(b) and max(abs(a / b), abs(b / a)) >= FAR and not abs(b - a) < 2 * p["std"]
                and not abs(b) < 2 * p["std"]):
            out.append(f"{name} = {b:.4g} ± {p['std']:.2g} for the {a:g} declared ({abs(b / a):.3g}×"
                       f"{', its sign flipped' if a * b < 0 else ''}): check the units of the inputs and outputs "
                       f"it acts through before reading the rest")
    return out


def _bound_notes(parameters: dict) -> list[str]:
    """A note per parameter that sits on a bound, whose 2σ interval is wider than its bounds, that
    is zero within its std where that is a tenth of its declared value or less (the effect is
    absent: a damping whose truth is 0), or whose std is VAGUE times its value (an infinite std has
    its own note, :func:`_unseen_notes`)."""
    notes = []
    for name, p in parameters.items():
        value, std, (lo, hi) = p["value"], p["std"], p["bounds"]
        if not np.isfinite(std):
            continue
        lo, hi = -np.inf if lo is None else lo, np.inf if hi is None else hi
        on = lambda b: abs(value - b) <= min(AT_BOUND * std, ON_BOUND * max(abs(value), abs(b), 1.0))
        side = "lower" if on(lo) else "upper" if on(hi) else None
        if side:
            notes.append(f"{name} = {value:.6g} ± {std:.2g} sits on its {side} bound {lo if side == 'lower' else hi:g}: "
                         f"the fit stopped there, where the best fit lies beyond the bound or the search met a "
                         f"local optimum on it, and its std is no confidence interval. Check the bound, start "
                         f"{name} elsewhere, or check whether the recordings excite it")
        elif 4 * std > hi - lo:
            notes.append(f"{name} = {value:.6g} ± {std:.2g}: its 2σ interval is wider than its bounds "
                         f"[{lo:g}, {hi:g}]; the data hardly determine it")
        elif abs(value) < std and VAGUE * std < abs(p.get("initial") or 0.0):
            notes.append(f"{name} = {value:.6g} ± {std:.2g} is zero within its std, {abs(p['initial']) / std:.3g} std "
                         f"from the {p['initial']:g} declared: what it sets is absent from the recordings or "
                         f"below what they resolve")
        elif std > VAGUE * abs(value):
            notes.append(f"{name} = {value:.6g} ± {std:.2g}: its std is {std / max(abs(value), 1e-300):.2g} times "
                         f"its value; the data hardly determine it")
    return notes


CORRELATED = 0.99   # |correlation| of two estimates above which the data see mostly a combination


FLAT = 0.1    # a side where −log L rises less than this share of what the error bar predicts is flat


def _flat_sides(prob: Problem, xi: np.ndarray, inputs: dict, std: np.ndarray, information: np.ndarray,
                at: list[int]) -> dict[int, str]:
    """{variable: 'above' or 'below'} for the estimates (indices ``at``, scaled ``std``) whose
    −log L, moved 2σ to that side within the bounds (the others held), rises less than FLAT of
    what their ``information`` (the Fisher information's diagonal at ``xi``) predicts: the data
    bound them from one side only (a limit just above the largest command has ±0.04 from the few
    samples it clips, and nothing above)."""
    p = inputs["p"]
    f0, out = float(prob.objective(xi, p)), {}
    for i in at:
        if not 0 < std[i] < np.inf:
            continue
        for side, sign in (("above", 1.0), ("below", -1.0)):
            moved = xi.copy()
            moved[i] = np.clip(xi[i] + sign * 2 * std[i], inputs["lbx"][i], inputs["ubx"][i])
            step = moved[i] - xi[i]
            if abs(step) > 0.5 * std[i] and float(prob.objective(moved, p)) - f0 < FLAT * 0.5 * step ** 2 * information[i]:
                out[i] = side
    return out


def _unseen_notes(result) -> list[str]:
    """A note per estimate the recordings do not see at all at its fitted value (std infinite),
    and per estimate they bound from one side only (:func:`_flat_sides`)."""
    estimates = {**result.parameters, **result.weights}
    return ([f"'{name}' has no effect on the likelihood at its fitted value {e['value']:.6g}: the recordings do not "
             f"determine it there (a limit the inputs never reach, a term that vanishes), so that value is where "
             f"the search stopped, not an estimate, and its std is infinite"
             for name, e in estimates.items() if not np.isfinite(e["std"])]
            + [f"{name} = {e['value']:.6g} ± {e['std']:.2g} is bounded from {'below' if e['flat'] == 'above' else 'above'} "
               f"only: the likelihood hardly changes {e['flat']} it (moved 2σ, it rises by less than a tenth of what "
               f"the error bar predicts), so the data say {name} {'≳' if e['flat'] == 'above' else '≲'} "
               f"{e['value']:.4g} and the ± holds on one side (a limit the inputs barely reach, a threshold "
               f"crossed by a few samples)"
               for name, e in estimates.items() if e.get("flat")])


def _correlated(correlation: dict, estimated: set) -> list[str]:
    """A note per pair of ``estimated`` parameters or weights correlated beyond CORRELATED: the
    recordings determine a combination better than either (a car's front stiffness and yaw
    inertia at 0.9965, each 44 % and 68 % uncertain, said nowhere)."""
    names, C = correlation["names"], np.asarray(correlation["matrix"], float)
    ours = [i for i, n in enumerate(names) if n in estimated]
    return [f"{names[i]} and {names[j]} are correlated {_near_one(C[i, j])}: the recordings determine a combination "
            f"of them far better than either, and their errors move together"
            for a, i in enumerate(ours) for j in ours[a + 1:] if abs(C[i, j]) > CORRELATED]


def _near_one(c: float) -> str:
    """A correlation with the digits that tell it from ±1 (0.99969 is '+0.99969', not '+1.000')."""
    gap = 1.0 - abs(c)
    digits = 3 if gap >= 1e-3 else min(12, 1 - int(np.floor(np.log10(max(gap, 1e-12)))))
    return f"{c:+.{digits}f}"


def _prior_notes(model: Model, parameters: dict, fisher_std: dict) -> list[str]:
    """A note per estimate whose shift from its declared prior the prior does not allow, and, in
    output error, per prior the recordings outweighed as if their residuals were white.

    With a Gaussian prior of std σ₀, the recordings alone know θ to f (white residuals: 1/f² = 1/σ²
    − 1/σ₀², σ the posterior std of the Fisher information, prior included) or to c·f (c = the
    reported std over σ: output error's coloured residuals); the estimate moves from θ₀ by
    K = σ₀²/(σ₀² + f²) of the way to where they put it, and a right prior allows a shift of std
    K·√(σ₀² + c²f²) (√(σ₀² − σ²) for c = 1: the prior-predictive check of a linear-Gaussian
    model). A shift beyond PRIOR_CONFLICT times that says the prior and the recordings disagree;
    the note gives where the recordings alone put θ, θ₀ + (θ − θ₀)/K ± c·f. (A tight prior
    a = 0.9 ± 0.0003 against data saying 0.994 ± 0.004 moved 1.8 prior std, 22 times what it
    allows, and was not said.)"""
    notes, conflicts = [], []
    for name, p in parameters.items():
        sd, sigma = model.parameter_named(name).std, fisher_std.get(name, 0.0)
        if sd and sigma >= PRIOR_ONLY * sd and abs(p["value"] - p["initial"]) < sd:
            notes.append(f"{name} = {p['value']:.6g} ± {p['std']:.2g}: the recordings add little to its declared "
                         f"prior {p['initial']:.6g} ± {sd:.2g} (its std with them is {sigma / sd:.0%} of the "
                         f"prior's): the estimate is mostly the prior")
        if not sd or not 0 < sigma < sd:
            continue
        f = 1 / np.sqrt(1 / sigma ** 2 - 1 / sd ** 2)
        c = max(p["std"] / sigma, 1.0)
        K = sd ** 2 / (sd ** 2 + f ** 2)
        shift, room = p["value"] - p["initial"], K * np.hypot(sd, c * f)
        if c > COLOURED:
            notes.append(f"{name}: output error weighed the recordings against its declared prior ± {sd:.2g} as if "
                         f"their residuals were white; coloured, they know {name} {c:.2g}× less well than that, "
                         f"so the prior counted too little (filter error weighs both as they are)")
        if abs(shift) > PRIOR_CONFLICT * room:
            conflicts.append(name)
            notes.append(f"{name} = {p['value']:.6g} ± {p['std']:.2g} lies {abs(shift) / sd:.2g} prior std from its "
                         f"declared prior {p['initial']:.6g} ± {sd:.2g}, {abs(shift) / room:.0f} times the shift the "
                         f"prior allows with these recordings (± {room:.2g}); the recordings alone put it near "
                         f"{p['initial'] + shift / K:.6g} ± {c * f:.2g}. The prior and the recordings disagree, and "
                         f"the estimate is a compromise of the two. Check the prior")
    if len(conflicts) > 1:        # (a motor's Ke, viscous and Coulomb friction: 0.083, −0.17, −4.95 for 0.1, 0, 0)
        notes.append(f"the priors of {', '.join(conflicts)} all disagree with the recordings: where the recordings "
                     f"alone put each is extrapolated for it alone, and does not hold for them together; "
                     f"a fit without those priors (no std) says where the recordings put them")
    return notes


def _solve(prob: Problem, solver, inputs: dict, negligible, label: str | None) -> tuple[dict, dict]:
    """(IPOPT's solution, its stats with the total iterations and the status): Fisher scoring,
    then Newton steps (exact Hessian) where scoring did not converge; a FitError if neither does."""
    scoring, newton = solver
    prob.progress.start(f"fit {label}" if label else None, negligible)
    prob.nlp["secant"].reset()
    sol = scoring(**inputs)
    stats = scoring.stats()
    iterations, status = stats["iter_count"], stats["return_status"]
    counted = f"{iterations} iterations"
    if prob.progress.stopped:
        status = NEGLIGIBLE_STATUS
    if status not in ("Solve_Succeeded", "Solved_To_Acceptable_Level", NEGLIGIBLE_STATUS):
        if label:
            note(f"fit {label}: Fisher scoring {_IPOPT_WORDS.get(status, status)}; continuing with "
                 f"Newton steps (exact Hessian)")
        sol = newton()(**dict(inputs, x0=sol["x"], lam_x0=sol["lam_x"], lam_g0=sol["lam_g"]))
        stats = newton().stats()
        counted = f"{iterations} iterations of Fisher scoring, then {stats['iter_count']} Newton steps"
        iterations, status = iterations + stats["iter_count"], stats["return_status"]
        if prob.progress.stopped:
            status = NEGLIGIBLE_STATUS
    if status not in ("Solve_Succeeded", "Solved_To_Acceptable_Level", NEGLIGIBLE_STATUS):
        raise FitError(f"IPOPT {_IPOPT_WORDS.get(status, status)} (status {status}, {counted})")
    return sol, dict(stats, iter_count=iterations, return_status=status)


def fisher(prob: Problem, xi, data, finite: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(J, prior precision) of the pseudo-residuals at the scaled unknowns ``xi``; with ``finite``, a
    FitError where J is not finite (a discrete model whose refit wandered where its states overflow:
    NumPy's eigh stopped the diagnosis with "Eigenvalues did not converge"). Away from the values
    found (a start, a probe elsewhere) a J not finite is the caller's to weigh: ``finite=False``."""
    J, prior = (np.asarray(ca.DM(v)) for v in prob.fisher(xi, data))
    if finite and not np.all(np.isfinite(J)):
        bad = int(np.sum(~np.all(np.isfinite(J), axis=1)))
        raise FitError(f"the likelihood's derivatives are not finite at the values found ({bad} of {J.shape[0]} "
                       f"residuals): the model overflows or divides by zero near them, and no error bar can be "
                       f"given; check its stability there, or bound the parameters that take it there")
    return J, prior


def _at_optimum(prob: Problem, jac_g, sol: dict, inputs: dict, lengths, robust: bool):
    """(the solution within its bounds, the residuals, −log L per sample, the covariance of the
    scaled unknowns, its info, with ``information``: the Fisher information's diagonal, and ``J``,
    ``prior``: :func:`fisher` there, for the checks that follow) at IPOPT's solution."""
    xi = np.clip(np.asarray(sol["x"]).ravel(), inputs["lbx"], inputs["ubx"])   # IPOPT may overstep a bound by ~1e-8
    p = inputs["p"]
    rho, nll = (np.asarray(v) for v in prob.residuals(xi, p))
    J, prior = fisher(prob, xi, p)
    C, info = covariance(J, rho if robust else None, lengths, prior.ravel(), _dense(jac_g(xi, p)))
    info["information"] = np.sum(J * J, axis=0) + prior.ravel()
    info["J"], info["prior"] = J, prior
    return xi, rho, nll, C, info


MOVED = 3.0     # standard errors: estimates that moved this far from their start had the noise start of others
OTHER_NOISE = 2.0   # e-folds of a variance: a noise to start from as well differs from the declared one by more


def _noise_restarts(prob: Problem, model: Model, inputs: dict, declared: np.ndarray, sol: dict, xi: np.ndarray,
                    C: np.ndarray, noise_from=None):
    """Filter error: IPOPT's starts to try after the optimum ``sol``, each with the estimates found
    and the noise started (:func:`_noise_start`) from the declared noise when the estimates moved
    more than MOVED standard errors from their start, and from ``noise_from`` (Q, R) where it
    differs from the declared noise by more than OTHER_NOISE e-folds; yielded only while already
    more likely than ``sol``. The likelihood of the noise has two basins where the model misses
    something at the start — its error on the process noise, or on the sensors — and the
    optimum stays in the first it meets: a parameter declared 30 % off, or a nominal missing a
    saturation whose calibration a corrected model inherits, left a heater's sensor noise near 0
    (3.9e-5 for 0.05 °C, 900–1200 nats short), which a diagnosis read as a mismatch."""
    V = prob.variables
    noise = [i for i, k in enumerate(V.kinds) if k == "noise"]
    est = [i for i, k in enumerate(V.kinds) if k in ("parameter", "weight")]
    starts = []
    std = np.sqrt(np.clip(np.diag(C)[est], 1e-300, None))
    if est and np.any(np.abs(xi[est] - np.asarray(inputs["x0"])[est]) > MOVED * std):
        starts.append(np.asarray(declared)[noise])
    if noise_from is not None:
        shift = _noise_shift(V, model, noise, *noise_from)
        if np.any(np.abs(shift) > OTHER_NOISE):
            starts.append(np.asarray(declared)[noise] + shift)
    for start in starts:
        x = xi.copy()
        x[noise] = np.clip(start, np.asarray(inputs["lbx"])[noise], np.asarray(inputs["ubx"])[noise])
        x = _noise_start(prob, dict(inputs, x0=x))
        if float(prob.objective(x, inputs["p"])) < float(sol["f"]):
            yield dict(inputs, x0=x)


def _capped(V, model: Model, caps: dict) -> list[tuple[int, float]]:
    """(index in V, upper bound of its log scale) of each Q scale ``caps`` bounds: the log of the
    cap over the model's declared variance."""
    q = dict(zip(model.state_names, np.diag(model.process_noise())))
    return [(V.names.index(f"Q_scale_{n}"), float(np.log(max(cap, 1e-300) / q[n])))
            for n, cap in caps.items() if f"Q_scale_{n}" in V.names and q[n] > 0]


UNEQUAL = 2.0       # residual RMS of one output this many times larger on one recording than another: said


def _repeated(recs: list[Recording]) -> list[str]:
    """A note per recording whose inputs and readings are, value for value, an earlier one's
    (the same log passed twice, or re-exported with other time stamps): fitted twice, it counts
    its evidence twice and the error bars shrink by √2."""
    seen, out = {}, []
    for r in recs:
        key = (r.inputs.shape, r.outputs.shape, np.nan_to_num(r.inputs, nan=np.inf).tobytes(),
               np.nan_to_num(r.outputs, nan=np.inf).tobytes())
        if key in seen:
            out.append(f"{r.path} holds the same inputs and readings as {seen[key]}: fitted twice, it counts the "
                       f"same evidence twice and the error bars are √2 too narrow; give it once")
        else:
            seen[key] = r.path
    return out


def _unequal_residuals(reports: list[dict], recs, predictions, outputs, least: int = 50) -> list[str]:
    """A note per output whose residuals' noise differs UNEQUAL-fold or more between recordings (of
    at least ``least`` readings): one noise per output serves them all (a fleet's flights at 0.005
    and 0.03 rad were fitted one 0.014 in silence), so the fit weighs them alike and its error bars
    are those of that one noise. The noise is the RMS of the residuals' second differences over
    √6 (white noise's), not their RMS: a free run drifts under process noise, more the longer the
    recording, and the drift's increments are stationary where it kicks the output's rate (a
    flight cut by a gap read 4.2-fold, 0.0038 to 0.016 rad, its encoder's noise 0.001 rad in both;
    a cart's two runs 22-fold)."""
    out = []
    for j, o in enumerate(outputs):
        seen = []
        for report, rec, Y in zip(reports, recs, predictions):
            head = report.get("rmse_from") or 0           # where a filter learnt a recording's start
            e = rec.outputs[head:, j] - Y[head:, j]
            if len(d := np.diff(e[np.isfinite(e)], 2)) >= least:
                seen.append((float(np.sqrt(np.mean(d ** 2) / 6)), report["file"]))
        if len(seen) > 1 and max(seen)[0] >= UNEQUAL * min(seen)[0]:
            (lo, a), (hi, b) = min(seen), max(seen)
            out.append(f"the recordings' residuals on {o} differ {hi / lo:.2g}-fold from one reading to the next, "
                       f"{lo:.3g} ({Path(a).name}) to {hi:.3g} ({Path(b).name}) (the RMS of their second differences "
                       f"over √6: the noise, not a drift): one noise per output is fitted to them all, which weighs them "
                       f"alike, and the error bars are those of that one noise; fit them one by one (skigen batch "
                       f"--fit) to see each")
    return out


UNITS = "check the units"     # a note's opening: an output read in other units than the model's
OPTIMISTIC = "output error: the free-run residuals exceed the declared sensor noise"   # a note's opening


def _unexplained_residuals(model: Model, recs, predictions, params, alpha: float = 0.01) -> list[str]:
    """Output error: a note when the free-run residuals exceed what the declared sensor noise can
    explain (their summed squares over its variance above the 1 − α quantile of χ² with one degree
    per reading): a disturbance or a model error the free run does not follow, under which the
    error bars are optimistic. (Said of any model that declared process noise, it was also said on
    clean recordings whose coverage was right; not said of one that declared none, whose 2σ
    intervals held the truth on 75–80 % of seeds under a disturbance force.)"""
    from scipy.stats import chi2
    e = np.concatenate([r.outputs - Y for r, Y in zip(recs, predictions)])
    r2 = np.diag(model.measurement_noise())
    out = []
    for j, name in enumerate(model.output_names):
        ej = e[:, j][np.isfinite(e[:, j])]
        if len(ej) and r2[j] > 0 and np.sum(ej ** 2) / r2[j] > chi2.isf(alpha, len(ej)):
            out.append(f"{name} {np.sqrt(np.mean(ej ** 2) / r2[j]):.3g}×")
    if not out:
        return []
    return [f"{OPTIMISTIC} ({', '.join(out)} its std): "
            f"a disturbance or a model error the free run does not follow, under which the error bars of "
            f"{', '.join(params)} are optimistic (2–7× too narrow in the coverage checks measured, the coloured "
            f"residuals' covariance notwithstanding); filter error (--method filter-error, a process_std "
            f"declared where the disturbance acts) models a disturbance. Or the search stopped in a local "
            f"optimum: a fit from other starting values tells"]


def _absorbing(model: Model, noise: dict) -> list[str]:
    """Filter error: a note where a process noise came out over exp(NOISE_JUMP) times its declared
    variance, or a sensor's over exp(SENSOR_JUMP) — the model misses something that noise covers,
    and the constants are those the model explains the recordings best with it (a car model without
    its steering delay: Cf 5.6 ± 2.1 for 80 with 779× the declared process noise on vy, 'solved',
    said nowhere). A sensor's noise is a datasheet's number, a process noise a guess: a speed
    logged in rpm for a model in rad/s came out at 90× its sensor's declared variance, the motor
    constant 10× low, under the process noise's threshold."""
    kinds = {"Q_scale_": "process noise", "R_scale_": "sensor noise"}
    level = {"Q_scale_": np.exp(NOISE_JUMP), "R_scale_": np.exp(SENSOR_JUMP)}
    big = [f"the {kinds[n[:8]]} on {n[8:]} {v['value']:.3g}× its declared variance"
           for n, v in noise.get("scales", {}).items() if n[:8] in kinds and _surely_above(v, level[n[:8]])]
    if not big:
        return []
    return [f"{'; '.join(big)}: the model misses something that noise now covers (or the noise was declared far "
            f"too small, or a recording is in other units than the model, or the search stopped in a local optimum whose misfit the noise covers: a fit from "
            f"other starting values tells), and the constants are those that explain the recordings best "
            f"beside it (`skigen diagnose` says what is missing)"]


def _trusting(noise: dict) -> list[str]:
    """Filter error: a note where a sensor's noise came out surely below exp(−SENSOR_JUMP) of its
    declared variance (2 std above the value still below): the filter takes those readings as
    nearly exact and the process noise covers the misfit (four motors, one with another torque
    constant, had both sensors' noise at 6·10⁻⁸ of the datasheet's, the process noise 14× and 58×,
    said nowhere)."""
    level = np.exp(-SENSOR_JUMP)
    low = [f"{n[8:]} {v['value']:.2g}× its declared variance (at most {v['value'] + 2 * v['std']:.2g}×)"
           for n, v in noise.get("scales", {}).items() if n.startswith("R_scale_") and v.get("std") is not None
           and np.isfinite(v["std"]) and v["value"] + 2 * v["std"] < level]
    if not low:
        return []
    return [f"filter error: the sensor noise on {'; '.join(low)}: the filter takes the readings as nearly exact and "
            f"the process noise covers the misfit, which a model error or recordings that disagree leave (or the "
            f"sensor noise was declared far too large)"]


FOLLOWING = 0.01    # false-alarm rate of the test of the fitted model's innovations against the past


def _following(fitted: Model, recs, tested) -> list[str]:
    """Filter error: a note where the fitted model's innovations are not white or follow the
    states and inputs before them (the diagnosis's tests on a calibrated model, Bonferroni over
    the outputs, the recordings and the two tests, at FOLLOWING; a recording's head where its
    filter learnt the start left out). A pitch model missing a 40 ms elevator delay had its
    process noise calibrated at 13× its declared variance, under the noise's note, and Mq and Mδ
    came out 14σ and 15σ off, 'solved', no note. A recording the fit started from the vague prior is
    run from it too (from the declared start, a motor found spinning at 12 rad/s was 'not white')."""
    from ..diagnose.cv import ekf_run
    from ..diagnose.detect import independence, lags_for, normalised_innovations, past_regressors, whiteness
    tests = 2 * len(fitted.output_names) * len(recs)
    said = []
    for rec, rs in zip(recs, tested):
        judged = rs is not None and not rs.consistent        # run from the start the fit gave it
        filt, init = vague_start(fitted, rs) if judged else (fitted, None)
        run = ekf_run(filt, rec, init=init)
        head = rs.head if judged else 0
        eps, Z = normalised_innovations(run)[head:], past_regressors(fitted, run, rec.inputs)[head:]
        for i, name in enumerate(fitted.output_names):
            p = min(whiteness(eps[:, i], lags_for(len(eps))), independence(eps[:, i], Z)[0]) * tests
            if p < FOLLOWING:
                said.append(f"{name} (p = {p:.2g}{f', {rec.path}' if len(recs) > 1 else ''})")
    if not said:
        return []
    return [f"filter error: the fitted model's innovations of {', '.join(said)} are not white or follow the states "
            f"and inputs before them, as a right model's do not: the model misses something (a delay, a term) that "
            f"the calibrated noise covers, the parameters are those that explain the recordings best beside it, "
            f"and their error bars assume a right model (`skigen diagnose` says what is missing)"]


DISAGREE = 1e-3   # false-alarm rate of a pair of recordings said to differ (one step from the pooled fit: at 0.01
                  # four recordings of a right pendulum model were said to disagree in 2 fleets of 60)


def _disagreeing(prob: Problem, xi: np.ndarray, rho: np.ndarray, J: np.ndarray, prior: np.ndarray, lengths,
                 cols: list[int], scale: np.ndarray, recs, alone=None) -> list[str]:
    """Filter error: a note naming each recording whose own parameters differ from most of the
    others' (a pair differs where χ² of their difference is beyond DISAGREE, Bonferroni over the
    pairs). Screened by each recording's step from the pooled fit
    (:func:`~skigen.fit.uncertainty.recording_shifts`), and where that finds a disagreement,
    confirmed by ``alone(recording, names)``, the recording fitted alone ((values, covariance) of
    the variables ``cols``, or None): a step from a pooled fit one odd motor had pulled 0.016 off
    pointed the three others 0.02 apart too, and all four were named. Three flights and one of
    another vehicle (Lp −6 for −4) were fitted to Lp −3.2 ± 0.06, neither's, with no word of which
    flight disagreed. ``rho``, ``J``, ``prior``: the pseudo-residuals and :func:`fisher` at ``xi``
    (:func:`_at_optimum`)."""
    if len(recs) < 2 or not cols:
        return []
    rho = np.asarray(rho)
    ny = int(round((np.sqrt(1 + 4 * rho.shape[0]) - 1) / 2))        # n_rho = ny + ny²
    a = rho[:ny]
    outer = (np.eye(ny)[:, :, None] - a[:, None, :] * a[None, :, :]).reshape(ny * ny, -1) / np.sqrt(2)
    w = np.vstack([a, outer]).T.ravel()      # the gradient's residuals: −log L's gradient is Jᵀw
    own = [((xi[cols] + d) * scale[cols], C * np.outer(scale[cols], scale[cols]))
           for d, C in recording_shifts(J, w, lengths, prior.ravel(), cols)]
    names, how = [prob.variables.names[c] for c in cols], "a step from the pooled fit points it at "
    if (odd := _odd(own)) and alone is not None and None not in (fitted := [alone(rec, names) for rec in recs]):
        own, how, odd = fitted, "fitted alone: ", _odd(fitted)
    if not odd:
        return []
    said = "; ".join(f"{Path(str(recs[r].path)).name} ({how}" + ", ".join(f"{n} ≈ {v:.3g}" for n, v in
                                                                         zip(names, own[r][0])) + ")" for r in odd)
    pooled = ", ".join(f"{n} = {v:.4g}" for n, v in zip(names, xi[cols] * scale[cols]))
    return [f"filter error: {'the recordings disagree' if len(odd) == len(recs) else 'recordings disagree with most others'}"
            f" on the parameters (each recording's own values against each other's, at {DISAGREE:g} over the "
            f"pairs): {said}, against the pooled {pooled}: another vehicle, load or configuration, or a model "
            f"error each recording's excitation weighs its own way? The pooled values stand for none of them; "
            f"fit them one by one (skigen batch --fit) to see each"]


def _odd(own: list[tuple[np.ndarray, np.ndarray]]) -> list[int]:
    """The recordings whose values ((value, covariance) each) differ from more than half of the
    others': χ² of a pair's difference beyond DISAGREE, Bonferroni over the pairs."""
    from scipy.stats import chi2
    pairs = len(own) * (len(own) - 1) // 2
    apart = np.zeros(len(own), int)
    for r, s in itertools.combinations(range(len(own)), 2):
        d, C = own[r][0] - own[s][0], own[r][1] + own[s][1]
        dof = np.linalg.matrix_rank(C, hermitian=True, tol=1e-10 * max(np.abs(C).max(), 1e-300))
        if dof and chi2.sf(float(d @ np.linalg.pinv(C, hermitian=True, rcond=1e-10) @ d), dof) * pairs < DISAGREE:
            apart[[r, s]] += 1
    return [r for r in range(len(own)) if apart[r] > (len(own) - 1) / 2]


def _fitted_alone(model: Model, estimate, noise_from, noise_caps, rec: Recording, names: list[str]):
    """(values, covariance) of ``names`` in ``rec`` fitted alone by filter error from ``model``'s
    declared values and noise (from the pooled fit's, whose sensor noise the odd recording had
    pulled to 10⁻⁸ of the declared, one motor's came out 0.523 for 0.600), or None where it fails."""
    try:
        res = fit(model, [rec], method="filter-error", estimate=estimate, show_progress=False,
                  noise_from=noise_from, noise_caps=noise_caps)
    except FitError:
        return None
    values = {**res.parameters, **res.weights}
    if any(n not in values or n not in res.correlation["names"] for n in names):
        return None
    order = [res.correlation["names"].index(n) for n in names]
    std = np.array([values[n]["std"] for n in names])
    corr = np.asarray(res.correlation["matrix"], float)[np.ix_(order, order)]
    return np.array([values[n]["value"] for n in names]), corr * np.outer(std, std)


def _surely_above(scale: dict, level: float) -> bool:
    """A noise scale (value, std) above ``level`` by more than 2 std of its logarithm (std/value):
    289 ± 783 says nothing about where the noise is, and is not said."""
    v, sd = scale["value"], scale.get("std")
    spread = 2 * sd / v if sd is not None and np.isfinite(sd) and v > 0 else 0.0
    return v > 0 and np.log(v) - spread > np.log(level)


NOISE_JUMP = np.log(100.0)   # a noise scale (log variance) this far above the declared one: it absorbed something
SENSOR_JUMP = np.log(10.0)   # a sensor's (its std 3.2× the datasheet's)
HELD_GAIN = 1.0              # nat: a second optimum must be this much more likely to replace the first
HELD_JUMP = np.log(10.0)     # a process noise this far above the declared one: the parameters are refitted with it held


def _q_rows(prob: Problem) -> list[int]:
    return [i for i, n in enumerate(prob.variables.names) if n.startswith("Q_scale_")]


def _held_noise_start(prob: Problem, solver, inputs: dict, declared: np.ndarray, xi: np.ndarray, negligible):
    """Filter error: where the optimum gave some equation's process noise more than HELD_JUMP
    e-folds over its declared variance and there are parameters to estimate, IPOPT's start from
    the parameters fitted with the declared noise held, the noise then free (None otherwise). The
    likelihood has a basin where the process noise explains what wrong parameters leave: a motor's
    single step from rest gave L 0.0037 ± 3.5e-6 H for 0.05 (−13 000σ) with 4317× the speed's
    declared noise, 150 nat less likely than the optimum near the truth."""
    V = prob.variables
    noise = [i for i, k in enumerate(V.kinds) if k == "noise"]
    est = [i for i, k in enumerate(V.kinds) if k in ("parameter", "weight")]
    q = _q_rows(prob)
    if not est or not q or np.max(xi[q] - np.asarray(declared)[q]) <= HELD_JUMP:
        return None
    held = dict(inputs, x0=np.array(declared, float), lbx=np.array(inputs["lbx"], float),
                ubx=np.array(inputs["ubx"], float))
    held["lbx"][noise] = held["ubx"][noise] = held["x0"][noise] = np.asarray(declared)[noise]
    try:
        first, _ = _solve(prob, solver, held, negligible, None)
    except FitError:
        return None
    x = np.clip(np.asarray(first["x"]).ravel(), inputs["lbx"], inputs["ubx"])
    x[noise] = np.asarray(declared)[noise]
    return dict(inputs, x0=_noise_start(prob, dict(inputs, x0=x)))


def _noise_shift(V, model: Model, noise: list[int], Q, R) -> np.ndarray:
    """Per noise scale of ``V``, the log of (Q, R)'s variance over the model's declared one (0 where
    either is 0)."""
    ours = {**dict(zip(model.state_names, np.diag(model.process_noise()))),
            **dict(zip(model.output_names, np.diag(model.measurement_noise())))}
    theirs = {**dict(zip(model.state_names, np.diag(np.asarray(Q, float)))),
              **dict(zip(model.output_names, np.diag(np.asarray(R, float))))}
    target = [V.names[i].split("_", 2)[2] for i in noise]
    return np.array([np.log(theirs[n] / ours[n]) if ours[n] > 0 and theirs[n] > 0 else 0.0 for n in target])


@contextlib.contextmanager
def _said_with(units: list[str]):
    """A fit that fails on a recording in other units says so beside its reason (a pendulum's angle
    in degrees was refused as chaotic)."""
    try:
        yield
    except FitError as exc:
        if not units:
            raise
        exc.args = (f"{exc} ({'; '.join(units)})", *exc.args[1:])
        raise


def unit_notes(model: Model, recs: list[Recording]) -> list[str]:
    """A note per output read in other units than the model's (the declared model's free run times a
    unit conversion, :func:`~skigen.diagnose.unit_hints`): a roll angle logged in degrees was fitted
    to RMSE 8.9 (0.01 on its fleet) under the usual note on optimistic error bars."""
    from ..diagnose import unit_hints
    return [f"{UNITS}: {hint}" + (f" ({rec.path})" if len(recs) > 1 else "")
            for rec in recs for hint in unit_hints(model, rec)]


def _usable(recs: list[Recording], starts) -> tuple[list[Recording], list | None, list[str]]:
    """Each recording without a stuck sensor's readings (:meth:`Recording.unstuck`) and cut at its
    input holes (:meth:`Recording.input_parts`: a held input is not the input), ``starts`` for the
    parts (a later part starts from the model's initial state), and a note per change."""
    if starts is not None and len(starts) != len(recs):
        raise ValueError(f"starts: {len(starts)} given for {len(recs)} recordings")
    parts, part_starts, notes = [], [], []
    for rec, start in zip(recs, [None] * len(recs) if starts is None else starts):
        cut, stuck = rec.usable()
        notes += rec.said() + stuck
        if rec.input_holes:
            notes.append(rec.hole_note(f"fitted as {len(cut)} recordings, "
                                       + ", ".join(f"{clock(p.t[0])}–{clock(p.t[-1])} s" for p in cut)))
        if blind := [h for h in rec.holes if not h.inputs]:
            span = rec.t[-1] - rec.t[0] + rec.dt if len(rec.t) else 0.0
            notes.append(f"{rec.path}: output hole(s) longer than max_gap = {rec.max_gap:g} s, "
                         f"{sum(h.t1 - h.t0 for h in blind) / max(span, 1e-300):.0%} of the recording: "
                         + "; ".join(map(str, blind[:5])) + (f"; … {len(blind) - 5} more" if len(blind) > 5 else "")
                         + ": there the fit follows what the other outputs read, or nothing")
        parts += cut
        part_starts += [start] + [None] * (len(cut) - 1)
    return parts, None if starts is None else part_starts, notes


def _starts(model: Model, recs: list[Recording], starts, declared: bool, notes: list[str],
            tested: list) -> np.ndarray:
    """Each recording's filter start [x; vec P] (see :func:`fit`'s ``starts``), checked; a note for
    each recording that starts from the vague prior, and in ``tested`` each recording's
    :class:`~skigen.start.RecordedStart` (None where not tested)."""
    nx = len(model.states)
    starts = [None] * len(recs) if starts is None else list(starts)
    if len(starts) != len(recs):
        raise ValueError(f"starts: {len(starts)} given for {len(recs)} recordings")
    out = []
    for r, (rec, st) in enumerate(zip(recs, starts)):
        x, P = (model.x0, model.initial_covariance()) if st is None else (np.asarray(v, float) for v in st)
        if st is None and not declared:
            tested[r] = rs = recorded_start(model, rec)
            if rs is not None and not rs.consistent:
                x, P = rs.vague_mean, vague_covariance(model)
                notes.append(rs.note(rec.path, rs.starting("its filter starts")))
        if np.shape(x) != (nx,) or np.shape(P) != (nx, nx) or not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
            raise ValueError(f"starts for '{rec.path}': a finite mean of {nx} states ({', '.join(model.state_names)}) "
                             f"and a {nx}×{nx} covariance are needed")
        out.append(np.r_[x, np.ravel(P, order="F")])
    return np.concatenate(out)


STALL, STALL_GAIN = 3, 0.01    # iterations whose summed gain in −log L (nat) below STALL_GAIN triggers the check below
NEGLIGIBLE_MOVE = 0.02         # standard errors: what a step to the optimum must stay under to be left out
NEGLIGIBLE_STATUS = "Solved_To_Negligible_Step"


def _negligible_gain(prob: Problem, inputs: dict, xi: np.ndarray, recent=()) -> bool:
    """Whether the fit has nothing left worth a step, in one of two ways, measured against the
    inverse Fisher information (the fit's own error bars) in every estimate:

    - Fisher scoring puts the optimum within the bounds less than NEGLIGIBLE_MOVE of a standard
      error from ``xi`` (the bounded quadratic model's step);
    - or the line search cannot follow that model: the ``recent`` iterates (the last STALL + 1,
      which gained less than STALL_GAIN together) each moved every estimate by less than
      NEGLIGIBLE_MOVE of a standard error. IPOPT then halves its step dozens of times per
      iteration (a likelihood with kinks, or rounding in a sum of 10⁴ terms) for no gain.

    The noise scales enter as variances s = e^λ, not as their logs: the likelihood is smooth in s
    down to s = 0 (a Q scale's information is constant there and vanishes in λ), so the quadratic
    model holds where IPOPT's test, a gradient near 0, takes dozens of iterations that walk an
    unresolved log-scale towards its bound by less than 10⁻⁴ nat each."""
    g, H = (np.asarray(ca.DM(v)).astype(float) for v in prob.decrement(xi, inputs["p"]))
    g = g.ravel()
    if not (np.all(np.isfinite(g)) and np.all(np.isfinite(H))):
        return False
    V, sc = prob.variables, np.asarray(inputs["p"][:len(xi)], float)
    lo, hi = np.asarray(inputs["lbx"], float) - xi, np.asarray(inputs["ubx"], float) - xi
    dxi_ds = np.ones(len(xi))                   # ξ's change per unit of the quadratic model's coordinate
    for i, kind in enumerate(V.kinds):
        if kind == "noise":
            lam = xi[i] * sc[i]
            dxi_ds[i] = 1 / (sc[i] * np.exp(lam))
            lo[i], hi[i] = (np.exp(np.clip(b * sc[i] + lam, -700, 700)) - np.exp(lam) for b in (lo[i], hi[i]))
    g, H = g * dxi_ds, H * np.outer(dxi_ds, dxi_ds)
    d = np.sqrt(np.where(np.diag(H) > 0, np.diag(H), 1.0))
    g, H, lo, hi = g / d, H / np.outer(d, d), lo * d, hi * d
    std = np.sqrt(np.clip(np.diag(np.linalg.pinv(H, hermitian=True)), 0, None))
    moved = [np.abs(b - a) / dxi_ds * d for a, b in zip(recent[:-1], recent[1:])]
    if len(moved) >= STALL and all(np.all(m <= NEGLIGIBLE_MOVE * std) for m in moved):
        return True
    quadratic = lambda z: (g @ z + 0.5 * z @ H @ z, g + H @ z)
    step = minimize(quadratic, np.zeros(len(g)), jac=True, method="L-BFGS-B",
                    bounds=[(a if np.isfinite(a) else None, b if np.isfinite(b) else None) for a, b in zip(lo, hi)]).x
    moves = np.abs(step) > NEGLIGIBLE_MOVE * std
    return not moves.any()


STRAY = 1e4        # output error reweighs when the start's free run strays 100 noise std from the data


def _free_run_loglik(e: np.ndarray, R: np.ndarray) -> float:
    """Output error's log-likelihood of free-run residuals ``e`` (samples × outputs, NaN where not
    measured) under the declared sensor noise R: the same whatever weights IPOPT searched with
    (with the start's free-run weights of :func:`_weighted_by_free_run`, the same fit from two
    starts read +243.3 and −388.6)."""
    r = np.diag(np.asarray(R, float))
    ok = np.isfinite(e)
    terms = np.where(ok, e ** 2 / r + np.log(2 * np.pi * r), 0.0)
    return float(-0.5 * np.sum(terms))


def _polished(declared: tuple, sol: dict, scale: np.ndarray, data: np.ndarray, lower: np.ndarray, inputs: dict,
              show_progress: bool, label: str):
    """Output error searched under the start's free-run weights (:func:`_weighted_by_free_run`),
    solved again from its optimum under the declared R where the free run there no longer strays:
    the weights shrink the recordings' part of the objective, and a prior or a bound's barrier
    then outweighs them (a drag 0.398 ± 0.002 alone came out 0.302 ± 0.2, its prior's mean and
    std, and one bounded at 0.3 stopped at 0.277 inside it). ((prob, solver, jac_g), scale, p,
    inputs, solution, stats), or None where it still strays or the search fails (the weighted
    optimum stands)."""
    prob, solver, jac_g = declared
    xi = np.asarray(sol["x"], float).ravel() * scale
    nominal = np.array(prob.variables.scale)
    rho, _ = (np.asarray(v) for v in prob.residuals(xi / nominal, np.r_[nominal, data]))
    if not np.nanmax(np.nanmean(rho ** 2, axis=1)) <= STRAY:
        return None
    scale, _, _ = _scales(prob, xi, data)
    p = np.r_[scale, data]
    again = dict(prob.solver_inputs, x0=np.clip(xi, lower, prob.solver_inputs["ubx"]) / scale, lbx=lower / scale,
                 ubx=prob.solver_inputs["ubx"] / scale, p=p)
    fixed = inputs["lbx"] == inputs["ubx"]                 # what the first search held, held again
    again["lbx"][fixed] = again["ubx"][fixed] = again["x0"][fixed]
    negligible = None if prob.nlp["g"].shape[0] else functools.partial(_negligible_gain, prob, again)
    try:
        solved, stats = _solve(prob, solver, again, negligible, label if show_progress else None)
    except FitError:
        return None
    return (prob, solver, jac_g), scale, p, again, solved, stats


def _weighted_by_free_run(model: Model, rho0: np.ndarray) -> Model:
    """``model`` with R scaled per output to the mean square of its free-run residual at the start.

    Output error's estimate does not depend on R's size (one output) but IPOPT does: a filter's
    R (say 10⁻²⁴ V² from a filter-error calibration) against a free run off by a millivolt makes
    an objective of 10²⁰ that IPOPT cannot resolve. The mean squares are those of the whitened
    residuals ``rho0`` (outputs × samples); the fitted model keeps the declared R."""
    d = np.sqrt(np.maximum(np.nanmean(rho0 ** 2, axis=1), 1.0))
    weighted = copy.copy(model)
    weighted.R = model.measurement_noise() * np.outer(d, d)
    return weighted


def _scales(prob: Problem, theta0: np.ndarray, data: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IPOPT's unit of each unknown: its magnitude, or where it starts at 0, one standard
    error as the Fisher information at the start sees it; and that information in those units
    (J_ρ and the prior precision at θ0: ∂ρ/∂ξ scales with the unit, the precision with its square)."""
    V = prob.variables
    nominal = np.array(V.scale)
    J, prior = fisher(prob, theta0 / nominal, np.r_[nominal, data], finite=False)
    with np.errstate(over="ignore"):         # a start whose filter diverges: its information is no unit
        info = np.sum(J * J, axis=0) + prior.ravel()
    scale = nominal.copy()
    for i, kind in enumerate(V.kinds):
        if kind in ("parameter", "weight") and theta0[i] == 0 and np.isfinite(info[i]) and info[i] > 0:
            scale[i] = nominal[i] / np.sqrt(info[i])
    ratio = scale / nominal
    return scale, J * ratio, prior * ratio.reshape(prior.shape) ** 2


def _noise_start(prob: Problem, inputs: dict) -> np.ndarray:
    """IPOPT's start with the log scales of R, then of Q, then of R again each shifted together to
    the likelihood's best at the starting parameters (:func:`_best_shift`).

    Fisher scoring in a log-variance λ steps by r − 1 where r = ē²/S is the innovations' excess:
    from a start whose innovations are 20× their predicted variance, λ overshoots by ~20 e-folds
    and comes back one e-fold per iteration. The search moves it by log r instead."""
    V, x = prob.variables, np.array(inputs["x0"], float)
    lo, hi = np.asarray(inputs["lbx"], float), np.asarray(inputs["ubx"], float)

    def nll(rows, shift):
        y = x.copy()
        y[rows] = np.clip(x[rows] + shift, lo[rows], hi[rows])
        v = float(prob.objective(y, inputs["p"]))
        return v if np.isfinite(v) else np.inf

    groups = [[i for i, n in enumerate(V.names) if V.kinds[i] == "noise" and n.startswith(g)]
              for g in ("R_scale_", "Q_scale_", "R_scale_")]
    at_x = None
    for rows in filter(None, groups):
        shift, at_x = _best_shift(functools.partial(nll, rows), LOG_SCALE_BOUND, at_x)
        x[rows] = np.clip(x[rows] + shift, lo[rows], hi[rows])
    return x


def _best_shift(f, bound: float, f0: float | None = None, xatol: float = 0.5) -> tuple[float, float]:
    """(s, f(s)) near the minimum of ``f`` over [−bound, bound]: from 0 (where f is ``f0`` if
    known), steps of 1, 2, 4, … e-folds downhill until f rises, then Brent's bounded search in
    that bracket to ``xatol``. A start better than 0 is never given up for a worse one."""
    seen = {0.0: f(0.0) if f0 is None else f0}
    at = lambda s: seen[s] if s in seen else seen.setdefault(s, f(s))
    step = 1.0 if at(1.0) < seen[0.0] else -1.0
    a, b, c = -step, 0.0, step
    while at(c) < at(b) and abs(c) < bound:      # b is the best so far: march on until f rises
        a, b, c = b, c, float(np.clip(2 * c, -bound, bound))
    if at(b) <= min(at(a), at(c)):
        minimize_scalar(lambda s: at(float(s)), bounds=(min(a, c), max(a, c)), method="bounded",
                        options=dict(xatol=xatol))
    s = min(seen, key=seen.get)
    return s, seen[s]


def _dense(M) -> np.ndarray:
    return np.asarray(ca.DM(M).full()) if M is not None else None


def _filtered_states(prob: Problem, theta0, data_blocks) -> np.ndarray:
    """The model's EKF posterior states at the starting values (states × samples of all recordings)."""
    n_theta = sum(k in ("parameter", "weight") for k in prob.variables.kinds)
    return np.asarray(prob.filtered(theta0[:n_theta], *data_blocks))


def _refuse_a_runaway_simulation(model: Model, recs, X: np.ndarray) -> None:
    """Output error fits one free run per recording (shooting intervals only split it: their
    continuity constraints join them again). Where the free run amplifies a state error more than
    AMPLIFICATION-fold over a recording (along the EKF's states at the starting values: an
    open-loop unstable plant flown in closed loop), no simulation follows the recording and the
    fit would return the constants of a plant that does not diverge; refused, pointing to filter
    error, or to starting values that make a stable plant unstable."""
    starts = np.cumsum([0] + [len(r.t) for r in recs])
    for r, rec in enumerate(recs):
        rate = growth_rate(model, X[:, starts[r]:starts[r + 1]].T, rec.inputs)
        if simulation_window(rate, model.dt, len(rec.t)) < len(rec.t):
            raise FitError(
                f"output error cannot fit '{model.name}' to {rec.path}: along the recording its free run "
                f"amplifies a state error {AMPLIFICATION:g}-fold every {np.log(AMPLIFICATION) / rate:.3g} s "
                f"(largest Lyapunov exponent {rate:.3g}/s at the starting values), so no simulation follows "
                f"the recording and shooting intervals do not help (their continuity constraints join them "
                f"into one simulation). If the plant is open-loop unstable, flown in closed loop, fit it by "
                f"filter error (method='filter-error', --method filter-error); if it is stable, start from "
                f"values that make the model stable")


def _initial_guess(model: Model, prob: Problem, recs, theta0, X: np.ndarray):
    """Initial states (at every shooting node) from the model's EKF at the starting values
    (``X``, states × samples): its posterior state at each node's sample, where the filter stays finite."""
    V, out = prob.variables, theta0.copy()
    starts = np.cumsum([0] + [len(r.t) for r in recs])
    for i, node in enumerate(V.node):
        if node is not None:
            state, r, j = node
            value = X[model.state_names.index(state), starts[r] + j * prob.shooting]
            if np.isfinite(value):
                out[i] = value
    return out


def _result(model, prob, recs, lengths, method, estimate, value, std, C, fitted_at, nll, Y,
            stats, status, seconds, objective, info, robust) -> FitResult:
    V = prob.variables
    fitted = copy.copy(model)
    fitted.parameters = list(model.parameters)
    params, weights = {}, {}
    for i, name in enumerate(V.names):
        if V.kinds[i] == "parameter" and name in estimate:
            p = model.parameter_named(name)
            v = float(np.clip(value[i], *p.bounds))     # IPOPT may stop a rounding error past a bound
            params[name] = dict(value=v, std=float(std[i]), initial=p.value,
                                bounds=[_num(b) for b in p.bounds], unit=p.unit)
        elif V.kinds[i] == "weight" and name in estimate:
            weights[name] = dict(value=float(value[i]), std=float(std[i]))
    if params:
        fitted.set_parameters({n: v["value"] for n, v in params.items()},
                              std={n: v["std"] for n, v in params.items() if 0 < v["std"] < np.inf})
    init = [dict() for _ in recs]
    for i, node in enumerate(V.node):
        if node is not None and node[2] == 0:            # the state at each recording's first sample
            state, r, _ = node
            init[r][state] = dict(value=float(value[i]), std=float(std[i]))
    noise = _noise(model, V, value, std, Y, recs, method)
    if noise.get("Q") is not None:
        fitted.covariances(Q=noise.pop("Q"), R=noise.pop("R"), P0=model.initial_covariance())
    else:
        noise.pop("Q", None), noise.pop("R", None)
    corr_idx = fitted_at + [i for i, k in enumerate(V.kinds) if k == "noise"]
    sub = C[np.ix_(corr_idx, corr_idx)]
    d = np.sqrt(np.clip(np.diag(sub), 1e-300, None))
    with np.errstate(invalid="ignore"):            # an unseen estimate: NaN, written as null
        corr = sub / np.outer(d, d)
    reports, start, predictions = [], 0, []
    for r, (rec, n) in enumerate(zip(recs, lengths)):
        e = rec.outputs - Y[start:start + n]
        predictions.append(Y[start:start + n])
        reports.append(dict(file=str(rec.path), samples=int(n),
                            rmse={o: rms(e[:, j]) for j, o in enumerate(model.output_names)},
                            loglik=_free_run_loglik(e, model.measurement_noise()) if method == "output-error"
                            else float(-np.sum(nll[:, start:start + n]))))
        start += n
    note_text = ("sandwich covariance: the inverse Fisher information around the scores' covariance under "
                 "an autoregressive model of the simulation residuals (orders by AIC, per recording and output: "
                 + "; ".join(", ".join(map(str, o)) for o in info["ar_orders"]) + ")"
                 if robust else "inverse Fisher information of the innovations' likelihood")
    return FitResult(method, fitted, params, weights, init, noise,
                     dict(names=[V.names[i] for i in corr_idx],
                          matrix=[[_num(c) for c in row] for row in corr]),
                     reports, True, status, int(stats["iter_count"]), seconds, objective, note_text, predictions)


def rms(e: np.ndarray) -> float | None:
    """Root mean square of the finite values of ``e``; None where there is none (never measured)."""
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e ** 2))) if e.size else None


def value_text(v: float | None, fmt: str = ".4g") -> str:
    """``v`` formatted, or 'not measured' for None (an output without a reading)."""
    return "not measured" if v is None else f"{v:{fmt}}"


def plus_minus(value, std) -> str:
    """value ± std, the value to the std's second digit (at least 4 significant): 2399.81 ± 0.6;
    the value alone, 'no error bar', where the std is not a finite number (not identifiable)."""
    text = lambda x, spec=".4g": "–" if x is None else format(x, spec)
    if value is not None and math.isfinite(value) and (std is None or not math.isfinite(std)):
        return f"{text(value)} (no error bar)"
    if value is None or std is None or not (math.isfinite(value) and math.isfinite(std)) or value == 0 or std <= 0:
        return f"{text(value)} ± {text(std, '.2g')}"
    digits = math.floor(math.log10(abs(value))) - math.floor(math.log10(std)) + 2
    plain = format(value, f".{min(max(digits, 4), 15)}g")
    if len(re.sub(r"^[-0.]+|e.*$|\.", "", plain)) < digits:   # zeros the std resolves are digits:
        plain = format(value, f"#.{min(digits, 15)}g").rstrip(".")   # 0.000300000 ± 2.6e-08, not 0.0003
    return f"{plain} ± {text(std, '.2g')}"


def per_output(values: dict, fmt: str = ".4g") -> str:
    """'current 0.0213, speed not measured': a value per output, None as not measured."""
    return ", ".join(f"{o} {value_text(v, fmt)}" for o, v in values.items())


def _num(x: float):
    return None if not np.isfinite(x) else float(x)


def _resolution_floor(model, V, recs, lower) -> np.ndarray:
    """``lower`` with each output's R scale bounded below by its sensor's resolution: the
    measurement noise variance stays at least q²/12 (the error of rounding to a step q)."""
    lower = np.array(lower, float)
    R0 = np.diag(model.measurement_noise())
    for j, name in enumerate(model.output_names):
        q = min(resolution(rec.outputs[:, j]) for rec in recs)
        if f"R_scale_{name}" in V.names and q > 0 and R0[j] > 0:
            i = V.names.index(f"R_scale_{name}")
            lower[i] = min(max(lower[i], np.log(q ** 2 / 12 / R0[j])), LOG_SCALE_BOUND)
    return lower


def _noise(model, V, value, std, Y, recs, method) -> dict:
    """Output error: the residual std per output against the declared one; filter error: the fitted
    Q and R scales (value ± std of the scale, not of its log) and the fitted Q and R."""
    out = {}
    declared = np.sqrt(np.diag(model.measurement_noise()))
    if method == "output-error":
        res = np.concatenate([rec.outputs for rec in recs]) - Y
        out["residual_std"] = {o: rms(res[:, j]) for j, o in enumerate(model.output_names)}
        out["declared_std"] = {o: float(declared[j]) for j, o in enumerate(model.output_names)}
        return out
    q = np.ones(len(model.states))
    r = np.ones(len(model.output_names))
    scales = {}
    for i, name in enumerate(V.names):
        if V.kinds[i] != "noise":
            continue
        s = float(np.exp(value[i]))
        scales[name] = dict(value=s, std=float(s * std[i]))
        target = name.split("_", 2)[2]
        if name.startswith("Q_"):
            q[model.state_names.index(target)] = s
        else:
            r[model.output_names.index(target)] = s
    Dq, Dr = np.diag(np.sqrt(q)), np.diag(np.sqrt(r))
    Q, R = Dq @ model.process_noise() @ Dq, Dr @ model.measurement_noise() @ Dr
    out["scales"] = scales
    out["declared"] = dict(process_std=dict(zip(model.state_names, np.sqrt(np.diag(model.process_noise())).tolist())),
                           measurement_std=dict(zip(model.output_names, declared.tolist())))
    out["calibrated"] = dict(process_std=dict(zip(model.state_names, np.sqrt(np.diag(Q)).tolist())),
                             measurement_std=dict(zip(model.output_names, np.sqrt(np.diag(R)).tolist())))
    out["Q"], out["R"] = Q, R
    return out
