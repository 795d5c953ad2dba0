"""Model: write the corrected model as a normal model file and regenerate its filter.

The file is a plain declaration (``Model(...)``, ``model.state(...)``,
``model.dynamics({...})``, ``model.output(...)``) of the nominal model with
the found terms, every expression written out in full precision: each rate
equation reads as the nominal right-hand side followed by one line per added
term, structural changes appear where the plant sees the input (a delayed
input from ``model.input_history``, a lag state, a clip or a dead zone).
The file is read back and checked to give the same model, then the C of its
EKF is emitted beside it.
"""
from __future__ import annotations

import datetime
import re
from pathlib import Path

import casadi as ca
import numpy as np
from scipy import stats

from ..derive import augment, derive
from ..model import Model
from . import catalog as C
from . import transform as T
from .calibrate import block_starts, blocks
from .name import Correction
from .source import to_python

__all__ = ["write_model_file", "same_model", "emit_filter", "parametrised", "liftable", "refit_jointly"]


def _split(expr: ca.SX, k: int):
    """(nominal part, [(sign, term)] × k) of nominal ± t1 ± … ± tk, or None if not of that shape
    (CasADi may have folded a + (−b) into a − b)."""
    parts = []
    for _ in range(k):
        if expr.is_symbolic() or expr.is_constant() or expr.op() not in (ca.OP_ADD, ca.OP_SUB):
            return None
        parts.insert(0, ("+" if expr.op() == ca.OP_ADD else "-", expr.dep(1)))
        expr = expr.dep(0)
    return expr, parts


def _value(x) -> str:
    x = float(x)
    return repr(x) if np.isfinite(x) else ("np.inf" if x > 0 else "-np.inf")


def _state_line(m: Model, i: int, note: str = "") -> str:
    v = m.states[i]
    args = [repr(v.name), f"unit={v.unit!r}"] + ([f"role={v.role!r}"] if v.role else [])
    args += [f"initial={_value(m.x0[i])}", f"std={_value(m.x_std[i])}", f"process_std={_value(m.q_std[i])}"]
    return f"{v.name} = model.state({', '.join(args)})" + (f"  # {note}" if note else "")


def _matrix(M) -> str:
    return "np.array(" + repr(np.asarray(M, float).tolist()) + ")"


def write_model_file(path, final: Model, added: dict, *, header: list[str]) -> Model:
    """Write ``final`` (the corrected model) to ``path``; ``added``: per equation, the comment of
    each term added to the nominal rate, in order, and per input, of each term added to it (the
    dynamics see the sum). Returns the model the file declares."""
    nominal_states = set(final.state_names[:len(final.state_names)])
    hold = f", input_hold={final.input_hold!r}" if final.input_hold != "zoh" else ""
    lines = ['"""' + header[0], ""] + header[1:] + ['"""', "import casadi as ca", "import numpy as np", "",
                                                    "from skigen import Model", "",
                                                    f"model = Model({final.name!r}, dt={_value(final.dt)}, "
                                                    f"discretization={final.discretization!r}, "
                                                    f"substeps={final.substeps}{hold})"]
    for p in final.parameters:
        args = [repr(p.name), _value(p.value), f"unit={p.unit!r}"]
        if p.std is not None:
            args.append(f"std={_value(p.std)}")
        if np.isfinite(p.bounds).any():
            args.append(f"bounds=({_value(p.bounds[0])}, {_value(p.bounds[1])})")
        lines.append(f"{p.name} = model.parameter({', '.join(args)})")
    for i, v in enumerate(final.states):
        lines.append(_state_line(final, i, "" if v.name in nominal_states else "added: the lagged actuator"))
    for v in final.inputs:
        note = "; ".join(added.get(v.name, []))
        lines.append(f"{v.name} = model.input({v.name!r}, unit={v.unit!r})"
                     + (f"  # the dynamics see {v.name} plus: {note}" if note else ""))
    lags: dict[str, int] = {}
    for mm in final.memory:
        lags[mm.source] = max(lags.get(mm.source, 0), mm.lag)
    for u, n in lags.items():
        names = [f"{u}_d{j}" for j in range(1, n + 1)]
        lines.append(f"{', '.join(names)}, = model.input_history({u}, {n})  # input history (delay)")
    lines.append("model.dynamics({")
    for eq in final.state_names:
        notes = added.get(eq, [])
        split = _split(final.rhs[eq], len(notes)) if notes else None
        if split is None:
            lines.append(f"    {eq}: {to_python(final.rhs[eq])},")
            continue
        base, parts = split
        lines.append(f"    {eq}: {to_python(base)}")
        for j, (note, (sign, part)) in enumerate(zip(notes, parts)):
            end = "," if j == len(notes) - 1 else ""
            text = to_python(part)
            if part.op() in (ca.OP_ADD, ca.OP_SUB):
                text = f"({text})" if sign == "-" else text
            elif text.startswith("-"):            # "- -0.8 * w" reads as "+ 0.8 * w"
                sign, text = ("+" if sign == "-" else "-"), text[1:]
            lines.append(f"        {sign} {text}{end}  # {note}")
    lines.append("})")
    for i, v in enumerate(final.outputs):
        noise = "None" if final.r_std[i] is None else _value(final.r_std[i])
        lines.append(f"model.output({v.name!r}, {to_python(v.sym)}, unit={v.unit!r}, noise_std={noise})")
    if any(M is not None for M in (final.Q, final.R, final.P0)):
        lines.append("model.covariances(" + ", ".join(f"{k}={_matrix(M) if M is not None else 'None'}"
                                                      for k, M in (("Q", final.Q), ("R", final.R), ("P0", final.P0))) + ")")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    from .transform import load_model_file
    written = load_model_file(str(path))
    same_model(final, written)
    return written


def _unique_name(model: Model, name: str) -> str:
    name = re.sub(r"\W+", "_", name).strip("_")    # a constant's 0.002·v: constant_0_002_v
    taken = set(model.names) | set(model.parameter_names)
    out, i = name, 2
    while out in taken:
        out, i = f"{name}_{i}", i + 1
    return out


def parametrised(base: Model, corr: Correction, lift: list[C.Additive] = ()) -> tuple[Model, dict, dict]:
    """``base`` plus the correction, each additive coefficient a declared parameter (a physical
    sign as its bound), plus ``lift``: corrections of the nominal's own terms (:func:`liftable`),
    parameters starting at 0, and each structural change whose value is continuous (a
    limit, a width, a time constant, a sensor's bound) with that value a parameter. Returns (model,
    {parameter: finding candidate or None}, {equation: [comment per added term]})."""
    m = T.copy_model(base, unknowns=False)
    names, notes, added, readers = {}, {}, {}, C.rate_readers(base)
    first = [s for s in corr.structural if s[0].effect == "constant"]   # a number as written, before an
    for s, value, _ in first:                                           # input is rewritten around it
        m = s.build(m, _structural_parameter(m, s, value, names))
    for c, coef, std in corr.additive:
        name = _unique_name(m, "_".join(filter(None, (c.effect, c.equation, c.through))))
        p = m.parameter(name, float(coef), bounds=(0.0, np.inf) if c.sign > 0 and coef >= 0 else None)
        if c.through:                   # u → u + p·φ wherever u enters the dynamics
            added[c.through] = added.get(c.through, 0) + p * c.sx(m)
            notes.setdefault(c.through, []).append(f"{c.effect} on {c.equation}: + {name} × ({c.formula})")
        else:
            m.rhs[c.equation] = m.rhs[c.equation] + T.rate(m, p * c.sx(m))
            notes.setdefault(c.equation, []).append(f"{c.effect}: {name} × ({c.formula})")
            for y, k in readers.get(c.equation, []):            # a sensor of that rate reads it too
                m = T.read(m, y, lambda h, k=k, p=p, c=c: h + k * p * c.sx(m))
        names[name] = c
    for u, extra in added.items():
        m = T.replace_input(m, u, T.symbols(m)[u] + extra)
    for c in lift:
        name = _unique_name(m, f"{c.effect}_{c.equation}_correction")
        p = m.parameter(name, 0.0)
        m.rhs[c.equation] = m.rhs[c.equation] + T.rate(m, p * c.sx(m))
        names[name] = None
        notes.setdefault(c.equation, []).append(
            f"correction of the nominal {c.effect.replace('_', ' ')}: {name} × ({c.formula})")
    for s, value, _ in corr.structural:
        if s.effect != "constant":
            m = s.build(m, _structural_parameter(m, s, value, names))
    return m, names, notes


def _structural_parameter(m: Model, s, value: float, names: dict):
    """A structural change's value: a declared parameter of ``m`` where it is refitted (``names``
    records it), else the number."""
    if not s.refit:
        return value
    name = _unique_name(m, "_".join(filter(None, (s.effect, s.target, s.side))))
    names[name] = s
    return m.parameter(name, float(value), unit=s.unit, bounds=(0.0, np.inf) if s.log else None)   # log: positive


def liftable(nominal: Model, corr: Correction, equations) -> list[C.Additive]:
    """The nominal's own terms on the located equations — stiffness of the positions an equation
    drives, its damping, each input's term (:func:`catalog.input_term`) — when the nominal has
    them, declares no parameters, and no finding already covers them: their constants are
    refitted with the findings."""
    if nominal.parameters:
        return []
    found = {(c.effect, c.equation) for c, *_ in corr.additive}
    syms = T.symbols(nominal)
    out = []
    for eq in equations:
        own = lambda effect, formula: C.Additive(effect, eq, formula, C.READINGS[effect])
        terms = [(q, own("linear_stiffness", f"-{q}")) for q in C.pairs(nominal, eq) if q != eq]
        terms += [(eq, own("viscous_damping", f"-{eq}"))]
        terms += [(u, C.input_term(nominal, eq, u)) for u in nominal.input_names]
        for var, c in terms:
            if (c.effect, eq) not in found and ca.depends_on(nominal.rhs[eq], syms[var]) and \
                    not _constant_covers(nominal, corr, eq, c.sx(nominal)):
                out.append(c)
    return out


def _constant_covers(nominal: Model, corr: Correction, eq: str, term: ca.SX) -> bool:
    """Whether a constant found off already moves ``eq`` along ``term`` (its rate's derivative in
    the constant's factor proportional to it, at random states and inputs): a viscous damping
    lifted beside a damping constant found off makes the two one number the refit cannot split."""
    f = ca.SX.sym("f")
    return any(C.proportion(ca.substitute(ca.jacobian(s.build(nominal, f).rhs[eq], f), f, 1.0), term) is not None
               for s, _, _ in corr.structural if s.effect == "constant" and eq in s.equations)


def refit_jointly(nominal: Model, calibrated: Model, corr: Correction, rec, equations,
                  enabled: bool = True, anchored: Model | None = None,
                  window: int | None = None, noise_from=None, alpha: float = 0.01) -> tuple[Model, dict, dict, dict]:
    """The corrected model refitted by `skigen fit` (filter error): the nominal's declared
    parameters, the found coefficients, the lifted linear corrections and the noise, jointly.
    ``anchored``: ``calibrated`` with the calibration's std as the parameters' prior, tried when
    the refit without it does not converge (the prior comes from the same recording: it steadies
    a rough likelihood, and its error bars count the data twice, which the note says).
    ``window``: the free-run window the polish compares on (fit.free_run_window). ``noise_from``:
    the user's declared (Q, R), started from as well (:func:`skigen.fit.fit`). The lifted
    corrections stay only when the data want them: where each is within the z of ``alpha`` std of
    zero, the refit without them is taken unless the likelihood-ratio test (χ² at 1 − ``alpha``,
    as many degrees as corrections) rejects it. (A ship's rudder stop, 0.257 ± 0.006 rad in the
    search for a true 0.262, came out 0.221 ± 0.019 beside a damping and a gain correction of
    2.2 and 2.0 std: three free numbers where the data support one.)
    Returns (fitted model, {parameter: candidate}, comments per equation, what the refit did)."""
    from ..fit import FitError, NotIdentifiable, fit
    lift = liftable(nominal, corr, equations)
    tries = [(calibrated, a) for a in ([lift, []] if lift else [[]])] + ([(anchored, [])] if anchored else [])
    pieces = blocks(rec)
    info = {"method": "filter-error", "lifted": [], "note": "" if len(pieces) == 1 else
            f"on {len(pieces)} blocks of {len(pieces[0].t)} samples spread over the recording, each started "
            f"where the EKF over the whole recording stood. "}
    for start, attempt in tries:
        model, names, notes = parametrised(start, corr, attempt)
        if not enabled:
            info["note"] = "not refitted (refit=False): coefficients from the cross-validated search"
            return model, names, notes, info
        try:
            res = fit(model, pieces, method="filter-error", starts=block_starts(model, rec, pieces),
                      show_progress=False, noise_from=noise_from)
        except FitError as exc:          # the fit's advice (--estimate …) is not the diagnosis's to give
            why = "; ".join(exc.lost) if isinstance(exc, NotIdentifiable) else str(exc)
            info["note"] += (f"joint refit with {_own_terms(attempt) if attempt else 'the findings alone'}"
                             + (", the calibration's std as prior," if start is anchored else "")
                             + f" failed: {why}. ")
            continue
        if weak := _weak_lifts(res, names, attempt, alpha):
            keep = [c for c in attempt if c not in weak]
            plain = parametrised(start, corr, keep)
            try:
                fewer = fit(plain[0], pieces, method="filter-error", starts=block_starts(plain[0], rec, pieces),
                            show_progress=False, noise_from=noise_from)
            except FitError:
                fewer = None
            lr = 2 * (fewer.objective - res.objective) if fewer is not None else np.inf
            if lr < stats.chi2.ppf(1 - alpha, len(weak)):
                info["note"] += (f"the refit's corrections of {_own_terms(weak)}, each within "
                                 f"{_lift_z(attempt, alpha):.2f} std of zero and together not significant "
                                 f"(likelihood ratio {lr:.2f}), left out. ")
                res, (model, names, notes), attempt = fewer, plain, keep
        if start is anchored:
            info["note"] += ("refitted with the calibration's std as the declared parameters' prior: their "
                             "error bars count this recording twice. ")
        info.update(parameters=res.parameters, noise=res.noise.get("scales"), converged=res.converged,
                    loglik=-res.objective,
                    seconds=res.seconds, iterations=res.iterations,
                    lifted=[dict(effect=c.effect, equation=c.equation, formula=c.formula, parameter=n)
                            for c, n in zip(attempt, [n for n, c in names.items() if c is None])])
        return _polished(res.model, rec, pieces, names, notes, info, window)
    info["note"] += "coefficients from the cross-validated search"
    model, names, notes = parametrised(calibrated, corr, [])
    return _polished(model, rec, pieces, names, notes, info, window)


def _own_terms(lifted: list) -> str:
    """The nominal's own terms a joint refit corrects (:func:`liftable`), in words: "the nominal's
    own viscous damping on `wl` and input gain on `wm` (refitted with the findings)"."""
    said = [f"{c.effect.replace('_', ' ')} on `{c.equation}`" for c in lifted]
    return (f"the nominal's own {', '.join(said[:-1]) + ' and ' if len(said) > 1 else ''}{said[-1]} "
            f"(its constants refitted with the findings: the model declares no parameters)")


def _lift_z(attempt: list, alpha: float) -> float:
    """How many std from zero a lifted correction must be: two-sided ``alpha``, Bonferroni over them."""
    return float(stats.norm.isf(alpha / (2 * max(len(attempt), 1))))


def _weak_lifts(res, names: dict, attempt: list, alpha: float) -> list:
    """The lifted corrections (``attempt``, in the order of their parameters, those without a
    candidate in ``names``) within :func:`_lift_z` std of zero. (A pendulum's exact nominal beside a
    gyro's gain had its stiffness, damping and input gain corrected by 3.0, 0.3 and 2.9 std: kept,
    all three, because one passed 2.58.)"""
    lifted = [n for n, c in names.items() if c is None]
    z = _lift_z(attempt, alpha)
    return [c for c, n in zip(attempt, lifted)
            if n in res.parameters and abs(res.parameters[n]["value"]) < z * res.parameters[n]["std"]]


def _polished(fitted: Model, rec, pieces, names, notes, info, window=None):
    """refit_jointly's result, with the output-error polish on a long recording."""
    if len(pieces) > 1:
        fitted, info["output_error"] = polish_for_simulation(fitted, rec, pieces, window)
        if info["output_error"].get("adopted"):
            info["parameters"] = info["output_error"]["parameters"]
            info["method"] += ", polished by output-error"
    return fitted, names, notes, info


def polish_for_simulation(fitted: Model, rec, pieces, window: int | None = None) -> tuple[Model, dict]:
    """The joint refit (or the cross-validated coefficients, when it failed) polished by output error
    for simulation, when that simulates better.

    Filter error gives the parameters of the best one-step predictor; when the model is only
    approximate (a real circuit, a real disc), its process noise absorbs part of the dynamics and
    the parameters that simulate best differ. So the parameters are refitted by output error on
    the same ``pieces`` (no prior from the filter-error fit: it saw the same data), the noise is
    recalibrated with them, and they are kept when the free run over the whole recording — most
    of it outside the pieces — has the lower RMSE (relative to each output's spread). Returns
    (model, what was done)."""
    from ..fit import FitError, fit
    from .fit import evaluate_fit
    names = [p.name for p in fitted.parameters]
    start = T.copy_model(fitted).set_parameters({}, std={n: None for n in names})
    spread = np.nanstd(rec.outputs, axis=0) + 1e-12
    score = lambda m: float(np.sum(np.array(list(evaluate_fit(m, rec, window=window).metrics["free_run_rmse"].values()),
                                            dtype=float) / spread))
    try:
        res = fit(start, pieces, method="output-error", estimate=names, show_progress=False)
        polished = fit(res.model, pieces, method="filter-error", estimate=[],
                       starts=block_starts(res.model, rec, pieces), show_progress=False).model
        before, after = score(fitted), score(polished)
    except (FitError, TypeError, ValueError) as exc:
        return fitted, {"adopted": False, "note": f"output-error polish failed: {exc}"}
    info = {"adopted": bool(np.isfinite(after) and not after >= before), "free_run_before": before,
            "free_run_after": after, "parameters": res.parameters, "seconds": res.seconds,
            "note": "free-run RMSE over the whole recording, summed over outputs in units of each "
                    "output's spread: filter-error parameters (before) against output-error (after)"}
    return (polished if info["adopted"] else fitted), info


def same_model(a: Model, b: Model, points: int = 16, tol: float = 1e-9) -> None:
    """Raise if two models differ in names, sizes, noises, or (at random points) their
    transition and observation."""
    A, B = augment(a), augment(b)
    if A.names != B.names or A.shapes != B.shapes or [m.sym.name() for m in a.memory] != [m.sym.name() for m in b.memory]:
        raise AssertionError(f"written model differs: {A.names} vs {B.names}")
    for x, y, what in ((A.Q, B.Q, "Q"), (A.R, B.R, "R"), (A.P0, B.P0, "P0"), (A.z0, B.z0, "x0")):
        if not np.allclose(x, y, rtol=1e-12, atol=0):
            raise AssertionError(f"written model differs in {what}")
    rng = np.random.default_rng(0)
    d = A.shapes
    for Aug_a, Aug_b in ((A.f, B.f), (A.h, B.h)):
        fa = ca.Function("fa", [A.z, A.u, A.mem], [Aug_a])
        fb = ca.Function("fb", [B.z, B.u, B.mem], [Aug_b])
        for _ in range(points):
            args = [rng.normal(size=d["n"]) * 0.5, rng.normal(size=d["nu"]) * 2, rng.normal(size=d["nmem"]) * 2]
            va, vb = np.asarray(fa(*args)), np.asarray(fb(*args))
            if not np.allclose(va, vb, rtol=tol, atol=tol, equal_nan=True):
                raise AssertionError("written model differs in its dynamics or outputs")


def emit_filter(model: Model, out_dir) -> list[Path]:
    """The C of the corrected model's EKF (``skigen generate MODEL --filter ekf``)."""
    from ..emit.c import emit_c
    return emit_c(derive(model, "ekf"), out_dir)


def header_lines(nominal_name: str, source: str, recording: str, findings) -> list[str]:
    """The docstring of a corrected model file."""
    out = [f"Corrected model: '{nominal_name}' plus what `skigen diagnose` found in {recording}.",
           f"Written by skigen diagnose on {datetime.date.today().isoformat()} from {source}; the nominal",
           "dynamics are unchanged, the found terms are added with their identified coefficients as known",
           "dynamics (the nominal unknown term, if any, is left out). Findings (validation log-likelihood gain):"]
    for f in findings:
        bar = f"± {f['std']:.2g}" if f["std"] is not None and np.isfinite(f["std"]) else "(no error bar)"
        out.append(f"  - {f['effect']} on {f['equation']}: {f['expression']}, coefficient "
                   f"{f['coefficient']:.6g} {bar} (+{f['evidence']:.1f})")
    out += ["Use it as any model file: skigen run THIS_FILE DATA.csv --filter ekf --out result.csv;",
            "skigen generate THIS_FILE --filter ekf --out DIR."]
    return out
