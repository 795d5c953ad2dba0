"""Command line: ``skigen run | generate | fit | diagnose | batch | bench`` (also ``python -m skigen``)."""
from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path


from .derive import FILTERS
from .emit.c import AUTO_LOOPS_ABOVE_OPERATIONS, LOOPS_KINDS, STYLES
from .grid import clock
from .model import Model, ModelError
from .modelfile import ModelFileError, canonical_spec, load_model as _load_model
from .recording import RecordingError

__all__ = ["main", "load_model"]

BENCHMARKS = ("wingrock", "delay", "quadrotor", "consistency", "mukf", "speed", "footprint", "diagnose",
              "false_alarms", "fit", "logs", "batch", "faults")


class CliError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


def load_model(spec: str) -> Model:
    """A model from ``path/to/file.py`` (its ``model``) or ``package.module:attribute``."""
    try:
        return _load_model(spec)
    except ModelFileError as exc:
        raise CliError(str(exc)) from None


def _add_data_options(p: argparse.ArgumentParser) -> None:
    """The options of every command that reads DATA (see :func:`_read_options`)."""
    p.add_argument("--time", metavar="COLUMN", help="time column (default: t, time or timestamp; a ULog: timestamp, "
                   "or timestamp_sample where its topics have it)")
    p.add_argument("--time-unit", choices=["s", "ms", "us", "ns", "auto"], default="s",
                   help="unit of the time column (default s; auto decides from magnitude and spacing and "
                        "says what it chose); ULog stamps are always µs")
    p.add_argument("--map", action="append", default=[], metavar="NAME=COLUMN",
                   help="read model input/output NAME from COLUMN (repeatable); ULog columns are "
                        "topic.field, topic.field[i] or topic:instance.field")
    p.add_argument("--max-gap", type=float, default=1.0, metavar="SECONDS",
                   help="report spans longer than this (and 5 samples of the model's dt) without a sample of a "
                        "column (default 1 s)")


def _read_options(args) -> dict:
    """Keyword arguments of :func:`skigen.recording.load_recording` from :func:`_add_data_options`."""
    columns = {}
    for m in args.map:
        name, sep, column = m.partition("=")
        if not sep or not name.strip() or not column.strip():
            raise CliError(f"--map '{m}': expected NAME=COLUMN, e.g. --map z=vehicle_local_position.z")
        if name.strip() in columns:
            raise CliError(f"--map: '{name.strip()}' is mapped twice")
        columns[name.strip()] = column.strip()
    if not args.max_gap > 0:
        raise CliError(f"--max-gap must be positive, got {args.max_gap}")
    return dict(time=args.time, time_unit=args.time_unit, columns=columns or None, max_gap=args.max_gap)


def _derived(args, model):
    """The filter of ``skigen run`` and ``generate``: --filter with FilterOptions from --alpha and
    --second-order, and the --estimate parameters augmented into the state."""
    from .derive import FilterOptions, default_filter, derive
    args.filter = args.filter or default_filter(model)
    if not (0 < args.alpha <= 1):
        raise CliError(f"--alpha must be in (0, 1], got {args.alpha}")
    if args.second_order and args.filter != "ekf":
        raise CliError(f"--second-order is the EKF's (its prediction's second-order terms); --filter is {args.filter}")
    try:
        return derive(model, args.filter, FilterOptions(alpha=args.alpha, second_order=args.second_order),
                      estimate=args.estimate)
    except ValueError as exc:
        raise CliError(str(exc)) from None


def _add_filter_options(p) -> None:
    p.add_argument("--alpha", type=float, default=1.0,
                   help="sigma-point spread of the UKF kinds: the points sit at alpha·sqrt(n) standard deviations "
                        "of the n augmented states (default 1); smaller keeps a cubic or exponential term's "
                        "evaluations near the mean")
    p.add_argument("--second-order", action="store_true",
                   help="EKF: predict with the transition's second-order terms (honest error bars on a "
                        "strongly nonlinear term, where the first-order EKF is overconfident)")
    p.add_argument("--estimate", action="append", default=[], metavar="NAME",
                   help="a declared parameter to estimate online, augmented into the state with its std as "
                        "prior (repeatable)")


def _run(args) -> int:
    """``skigen run``. A CSV file is streamed: read a block at a time (pyarrow's streaming reader),
    laid on the grid, filtered and written before the next is read, so that memory does not grow
    with the file (a flight log of hours, a 200 MB CSV). The grid is the same as the whole-file
    reader's (:class:`skigen.grid.GridStream`); the notes come after the run instead of before.
    When a block holds something only the whole-file reader can name (a malformed row, time going
    backwards, a grid it cannot bound), the file is read whole, which names it. Parquet, ULog (read
    whole by their libraries) and the other commands (``diagnose`` and ``fit`` need the whole
    record) read the recording whole."""
    from .recording import TableWriter, load_recording, stream_recording
    from .runtime import RunSummary, iter_run, iter_run_stream
    from .sources import NotStreamable, is_csv

    model = load_model(args.model)
    options = _read_options(args)
    out, filt = Path(args.out), None
    if is_csv(args.data):
        grid = stream_recording(args.data, model, real=args.real, **options)
        filt = _derived(args, model)
        summary = RunSummary(filt)
        try:
            with TableWriter(out, background=True) as w:
                for part in iter_run_stream(filt, grid, backend=args.backend, real=args.real, guard=_guard(args)):
                    w.write(part.columns())
                    summary.add(part)
        except NotStreamable:
            pass                          # read whole below, which names the fault
        else:
            summary.holes, summary.notes = grid.holes, tuple(grid.notes)
            for line in grid.notes:
                print(line)
            return _ran(args, model, grid.n, grid.time(0), grid.time(grid.n - 1), summary)
    rec = load_recording(args.data, model, real=args.real, **options)
    for line in rec.notes:
        print(line)
    filt = filt or _derived(args, model)
    summary = RunSummary(filt)
    with TableWriter(out, background=True) as w:
        for part in iter_run(filt, rec, backend=args.backend, real=args.real, guard=_guard(args)):
            w.write(part.columns())
            summary.add(part)
    return _ran(args, model, len(rec.t), rec.t[0], rec.t[-1], summary)


def _guard(args):
    """The recovery policy of ``skigen run``: the default, with --std-scale."""
    from .guard import Guard
    if args.std_scale is None:
        return None
    try:
        return Guard(std_scale=args.std_scale)
    except ValueError as exc:
        raise CliError(f"--std-scale: {exc}") from None


def _ran(args, model, n, t0, t1, summary) -> int:
    from .emit.c import float_precision
    backend = args.backend + (f", {args.real}" if args.real != "double" else "")
    if args.real == "float" and args.backend == "c" and (why := float_precision(summary.filter)):
        print(f"note: {why}")
    print(f"{model.name} {args.filter} ({backend}): {n} samples of dt = {model.dt:g} s, "
          f"t = {clock(t0)}–{clock(t1)} s -> {args.out}")
    print("\n".join(summary.lines()))
    return 0


def _generate(args) -> int:
    from .emit.c import check_prefix, choose_style, emit_c, float_precision, left_over

    model = load_model(args.model)
    try:
        if args.prefix is not None:
            check_prefix(args.prefix)                # before the derivation, which may take a while
        filt = _derived(args, model)
        style = choose_style(filt, args.style)
        files = emit_c(filt, args.out, real=args.real, style=style, prefix=args.prefix)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    for f in files:
        print(f)
    if stale := left_over(files):
        print(f"note: {', '.join(p.name for p in stale)} in {files[0].parent} are not from this generation (another "
              f"--style or an earlier run): remove them before building the folder", file=sys.stderr)
    if args.real == "float" and (why := float_precision(filt)):
        print(f"note: {why}", file=sys.stderr)
    why = (f" (auto: {filt.tunable.n_instructions()} operations unrolled, looped above "
           f"{AUTO_LOOPS_ABOVE_OPERATIONS})" if args.style == "auto" and filt.kind in LOOPS_KINDS else "")
    print(f"kernel: {style}{why}", file=sys.stderr)
    return 0


def _diagnose(args) -> int:
    from .diagnose import DiagnosisError, diagnose
    from .diagnose.detect import timed
    from .diagnose.report import finding_line, lifted, noise_covers_sentence, where

    try:
        report = diagnose(args.model, args.data, args.out, candidates=args.candidate, alpha=args.alpha,
                          folds=args.folds, validate=args.validate, figures=not args.no_figures,
                          **_read_options(args))
    except DiagnosisError as exc:
        raise CliError(str(exc)) from None
    d = report.data
    for hint in (d["remaining"] or {}).get("units", []):       # first: the findings may only make up for it
        print(f"check the units first: {hint}")
    for line in d["notes"]:
        print(f"note: {line}")
    c, cal = d["consistency"], d["noise"]["calibrated"]
    print("calibrated noise: " + ", ".join(f"{k} {v:.3g}" for kind in ("process_std", "measurement_std")
                                             for k, v in cal[kind].items() if v))
    if d["noise"].get("parameters"):
        print("calibrated parameters: " + ", ".join(f"{k} {p['calibrated']:.4g} ± {p['std']:.2g} (declared "
                                                    f"{p['declared']:.4g})" for k, p in d["noise"]["parameters"].items()))
    print(f"{'mismatch detected' if d['mismatch_detected'] else 'no significant mismatch'}: "
          f"whiteness p = {c['whiteness_pvalue']:.3g}, independence of the past p = "
          f"{c.get('independence_pvalue', 1.0):.3g}, slowly varying disturbance: log-likelihood gain "
          + ", ".join(f"on {k} {v:+.1f}" for k, v in c["disturbance_gain"].items())
          + f" (threshold {c['disturbance_threshold']:.1f})")
    unnamed = [f"candidate {c['name']} on {c['equation']}: {c['why']}" for c in d.get("candidates_not_named", [])]
    if not d["mismatch_detected"]:
        for line in unnamed:
            print(line)
    else:
        loc = d["located"]
        print(f"located: outputs {', '.join(loc['outputs'])}; equations {', '.join(loc['equations'])}; "
              f"{len(loc['windows'])} window(s); {loc.get('regime') or 'no single regime'}")
        for f in d["findings"]:
            print(f"finding: {finding_line(f)}")
        for f in d["compensating"] + d["not_identifiable"]:
            print(f"not a finding: {where(f)}: {f['note']}")
        if (own := lifted(d)) is not None:
            print("refit: " + own.replace("`", "").replace("section 5", "report.md"))
        for line in unnamed:
            print(line)
        if d["fit"]["after"]:
            b, a = d["fit"]["before"], d["fit"]["after"]
            span = f" (restarted every {b['free_run_window']:.3g} s)" if b.get("free_run_window") else ""
            both = [k for k in b["free_run_rmse"] if None not in (b["free_run_rmse"][k], a["free_run_rmse"][k])]
            print(f"log-likelihood {b['loglik']:.1f} -> {a['loglik']:.1f}" + (
                f", free-run RMSE{span} " + ", ".join(f"{k} {b['free_run_rmse'][k]:.4g} -> {a['free_run_rmse'][k]:.4g}"
                                                      for k in both) if both else ""))
        rem = d["remaining"]
        print("what remains: " + ("a mismatch remains" + (f"; {rem['tried']}" if rem.get("tried") else "")
                                  + (f"; it follows {rem['explained_by']}{' outside those' if rem.get('tried') else ''}: "
                                     f"try --candidate '{rem['suggested_candidate']}'" if rem.get("explained_by") else "")
                                  + (f"; {rem['note']}" if timed(rem) else "")
                                  + (f"; {rem['periodic']['note']}" if rem.get("periodic") else "")
                                  if rem["mismatch"] else "the corrected model is consistent"))
    if (d["remaining"] or {}).get("noise_covers"):
        print(f"consistent only with {noise_covers_sentence(d['remaining']['noise_covers'])}")
    for r in d["fit"].get("recordings", []):
        print(f"validation {Path(r['before']['recording']).name}: " + _held_out_line(r))
    for line in d.get("validation_disagrees", []):
        print(f"validation: {line}")
    if (d["remaining"] or {}).get("integration"):
        print(f"integration: {d['remaining']['integration']}")
    if d["corrected_model"]:
        print(f"corrected model: {d['corrected_model']}")
    print(f"report: {Path(args.out) / 'report.md'} ({report.seconds:.1f} s)")
    return 0


def _held_out_line(r: dict) -> str:
    """A held-out recording's statistics, nominal -> corrected: mean NIS and free-run RMSE."""
    b, a = r["before"], r["after"] or {}
    arrow = lambda x, y: f"{x:.4g}" + (f" -> {y:.4g}" if y is not None else "")
    rmse = [f"{k} {arrow(v, (a.get('free_run_rmse') or {}).get(k))}" for k, v in b["free_run_rmse"].items()
            if v is not None]
    return f"mean NIS {arrow(b['nis_mean'], a.get('nis_mean'))}" + (f", free-run RMSE {', '.join(rmse)}" if rmse else "")


def _fit(args) -> int:
    from .fit import FitError, fit, plus_minus
    from .fit.output import per_output, validate, write_outputs
    from .recording import load_recording

    model = load_model(args.model)
    options = _read_options(args)
    recs, held_out = ([load_recording(p, model, **options) for p in paths] for paths in (args.data, args.validate))
    read = [n for rec in recs + held_out for n in rec.said()]
    for line in read:
        print(line)
    try:
        result = fit(model, recs, method=args.method, estimate=args.estimate or None,
                     shooting=args.shooting, max_iter=args.max_iter)
        checks = validate(result, held_out, init_samples=args.init_samples, declared=model)
    except FitError as exc:
        raise CliError(str(exc)) from None
    spec = canonical_spec(args.model)
    write_outputs(result, args.out, model_spec=spec, validation=checks,
                  figures=not args.no_figures)
    print(f"{model.name} fitted by {args.method}: {result.status.replace('_', ' ').lower()} in "
          f"{result.iterations} iterations ({result.seconds:.1f} s)")
    for name, p in {**result.parameters, **result.weights}.items():
        print(f"  {name:>12} = {plus_minus(p['value'], p['std'])}" + (f" {p['unit']}" if p.get("unit") else "")
              + (f" (flat {p['flat']} it: see the note)" if p.get("flat") else ""))
    for r in result.recordings + checks:
        kind = "validation" if r in checks else "fit"
        what = "one-step prediction RMSE" if kind == "fit" and args.method == "filter-error" else "free-run RMSE"
        span = (f" (free runs restarted every {r['window']:.3g} s)" if r.get("window") else
                f" (from sample {r['rmse_from']}: before it the filter learns where the recording starts)"
                if r.get("rmse_from") else "")
        print(f"  {kind} {Path(r['file']).name}: {what}{span} " + per_output(r["rmse"])
              + (f" (at the declared values: {per_output(r['rmse_declared'])})" if r.get("rmse_declared") else ""))
    for line in result.notes + [n for c in checks for n in c["notes"]]:
        if line not in read:                          # said as the recordings were read
            print(f"note: {line}")
    print(f"results: {Path(args.out) / 'fit.json'}, {Path(args.out) / 'report.md'}")
    return 0


def _batch(args) -> int:
    from .batch import BatchError, batch

    mode = "diagnose" if args.diagnose else "fit" if args.fit else "run"
    if args.workers is not None and args.workers < 1:
        raise CliError(f"--workers must be at least 1, got {args.workers}")
    try:
        result = batch(args.model, args.logs, args.out, mode=mode, filter=args.filter, backend=args.backend,
                       real=args.real, track=args.track, estimate=args.estimate, method=args.method,
                       figures=not args.no_figures, workers=args.workers, scheduler=args.scheduler,
                       **_read_options(args))
    except BatchError as exc:
        raise CliError(str(exc)) from None
    print("\n".join(result.lines()))
    return 0 if result.counts.get("ok", 0) == len(result.rows) else 1


def _bench(args) -> int:
    module = f"benchmarks.{args.name}"
    try:
        bench = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name in (module, "benchmarks"):
            raise CliError(f"no benchmark named '{args.name}' (choose one of {', '.join(BENCHMARKS)})") from None
        raise CliError(f"benchmark '{args.name}' failed to import: {exc}") from None
    except ImportError as exc:
        raise CliError(f"benchmark '{args.name}' failed to import: {exc}") from None
    return bench.main(args.rest + (["--json"] if args.json else []))


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="skigen", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run a filter over a recording")
    r.add_argument("model", help="model file (.py exposing `model`) or package.module:attribute")
    r.add_argument("data", help="recording: CSV, Parquet or PX4 ULog")
    r.add_argument("--filter", choices=FILTERS, default=None,
                   help="default: ski where the model declares unknown terms, else ukf")
    r.add_argument("--backend", choices=["python", "c", "casadi"], default="python",
                   help="python: step by step; c: the generated C; casadi: chained by CasADi, without the "
                        "gate, stuck-sensor test and restarts (raw innovations)")
    r.add_argument("--real", choices=["double", "float"], default="double", help="C backend precision")
    r.add_argument("--std-scale", type=float, default=None, metavar="K",
                   help="bound on each prior std, K times its declared initial std (default 100; inf: none)")
    r.add_argument("--out", required=True, help="result CSV")
    _add_filter_options(r)
    _add_data_options(r)
    r.set_defaults(func=_run, out_is="file")
    g = sub.add_parser("generate", help="emit the C library of a filter")
    g.add_argument("model")
    g.add_argument("--filter", choices=FILTERS, default=None,
                   help="default: ski where the model declares unknown terms, else ukf")
    g.add_argument("--real", choices=["double", "float"], default="double")
    g.add_argument("--style", choices=STYLES, default="auto",
                   help="kernel: 'unrolled' (flat scalar code, fastest for small models), 'loops' "
                        f"(filter algebra as loops; {', '.join(LOOPS_KINDS)}; small code at any size) or "
                        f"'auto' (loops above {AUTO_LOOPS_ABOVE_OPERATIONS} unrolled operations)")
    g.add_argument("--prefix", help="C prefix of every symbol and file (default <model>_<filter>): "
                                    "builds under different prefixes link into one binary")
    g.add_argument("--out", required=True, help="output directory")
    _add_filter_options(g)
    g.set_defaults(func=_generate, out_is="folder")
    d = sub.add_parser("diagnose", help="find, name and correct what the model misses in a recording")
    d.add_argument("model", help="model file (.py exposing `model`) or package.module:attribute")
    d.add_argument("data", help="recording: CSV, Parquet or PX4 ULog")
    d.add_argument("--out", required=True, help="output directory (report.json, report.md, figures, "
                                                "corrected_model.py, generated/)")
    d.add_argument("--candidate", action="append", default=[], metavar="NAME:EQUATION:FORMULA",
                   help="an extra additive candidate, e.g. 'stiction:v:-tanh(v/0.001)' (repeatable)")
    d.add_argument("--alpha", type=float, default=0.01, help="false-alarm rate of the decision (0.01)")
    d.add_argument("--folds", type=int, default=5, help="folds of the cross-validation (5), each three blocks of the recording dealt in turn")
    d.add_argument("--validate", action="append", default=[], metavar="DATA",
                   help="a further recording to compare the nominal and corrected models on, never fitted on "
                        "(repeatable)")
    d.add_argument("--no-figures", action="store_true", help="skip the figures")
    _add_data_options(d)
    d.set_defaults(func=_diagnose, out_is="folder")
    f = sub.add_parser("fit", help="fit a model's parameters, weights and initial states to recordings")
    f.add_argument("model", help="model file (.py exposing `model`) or package.module:attribute")
    f.add_argument("data", nargs="+", help="recording(s): CSV, Parquet or PX4 ULog")
    f.add_argument("--out", required=True, help="output directory (fit.json, fitted_model.py, report.md, figures)")
    f.add_argument("--method", choices=["output-error", "filter-error"], default="output-error",
                   help="output-error: free-run simulation error; filter-error: maximum likelihood of the "
                        "EKF innovations, also calibrating the noise (default output-error)")
    f.add_argument("--estimate", action="append", default=[], metavar="NAME",
                   help="a parameter or weight to estimate (repeatable; default: all of them)")
    f.add_argument("--validate", action="append", default=[], metavar="FILE",
                   help="a held-out recording scored by free-run simulation (repeatable)")
    f.add_argument("--shooting", type=int, default=None, metavar="SAMPLES",
                   help="output error by multiple shooting with intervals of this many samples "
                        "(for models whose free run diverges)")
    f.add_argument("--init-samples", type=int, default=50,
                   help="samples of a --validate recording used to estimate its initial state (50)")
    f.add_argument("--max-iter", type=int, default=200, help="IPOPT iteration limit (200)")
    f.add_argument("--no-figures", action="store_true", help="skip the figures")
    f.set_defaults(func=_fit, out_is="folder")
    _add_data_options(f)
    a = sub.add_parser("batch", help="run, fit or diagnose a model over many logs on Dask (local or a cluster)")
    a.add_argument("model", help="model file (.py exposing `model`) or package.module:attribute")
    a.add_argument("logs", nargs="+", metavar="GLOB", help="log files or globs (quote them: 'flights/*.ulg'; ** recurses)")
    a.add_argument("--out", required=True, help="output directory: DIR/<log>/ per log, DIR/summary.csv, DIR/summary.png")
    what = a.add_mutually_exclusive_group()
    what.add_argument("--filter", choices=FILTERS, default=None,
                      help="run this filter over each log (default: ski where the model declares unknown terms, else ukf)")
    what.add_argument("--fit", action="store_true", help="fit each log (skigen fit) instead of filtering it")
    what.add_argument("--diagnose", action="store_true", help="diagnose each log (skigen diagnose) instead")
    a.add_argument("--backend", choices=["python", "c"], default="python",
                   help="filter backend; c is compiled once into DIR/.build and shared by the workers")
    a.add_argument("--real", choices=["double", "float"], default="double", help="C backend precision")
    a.add_argument("--track", action="append", default=[], metavar="STATE",
                   help="a state whose final value ± std joins the summary, e.g. a mass carried as a "
                        "random-walk state (repeatable; weights and --estimate parameters always do); meant for "
                        "a state constant over a flight: one that moves within it moves between logs too")
    a.add_argument("--estimate", action="append", default=[], metavar="NAME",
                   help="a parameter to estimate (filter: augmented online; --fit: default all) (repeatable)")
    a.add_argument("--method", choices=["output-error", "filter-error"], default="output-error",
                   help="--fit method (default output-error)")
    a.add_argument("--no-figures", action="store_true", help="skip the per-log figures and summary.png")
    where = a.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, metavar="N",
                       help="local worker processes (default: the machine's cores)")
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="a running Dask scheduler, e.g. tcp://host:8786 (logs and DIR at the same paths on "
                            "every worker)")
    _add_data_options(a)
    a.set_defaults(func=_batch, out_is="folder")
    b = sub.add_parser("bench", help=f"print a benchmark table ({', '.join(BENCHMARKS)})")
    b.add_argument("name")
    b.add_argument("--json", action="store_true", help="print one JSON object")
    b.add_argument("rest", nargs=argparse.REMAINDER)
    b.set_defaults(func=_bench)
    return p


def _out_problem(given: str, kind: str) -> str | None:
    """Why ``--out`` cannot be written as a ``kind`` ("file" or "folder"), before any work: a run
    of 10⁶ rows into an existing folder failed only at its end, a folder that is a file said
    "[Errno 17] File exists"."""
    if given == "":                                    # '' wrote into the current folder without a word
        return "--out is empty: give the folder or file to write"
    out = Path(given)
    if kind == "file" and out.is_dir():
        return f"--out {out} is a folder; give the name of the CSV file to write"
    if kind == "folder" and out.exists() and not out.is_dir():
        return f"--out {out} is a file; give a folder to write into"
    up = next((p for p in out.parents if p.exists()), None)
    if up is not None and not up.is_dir():
        return f"--out {out}: {up} is a file, not a folder"
    return None


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if getattr(args, "out", None) is not None and (why := _out_problem(args.out, args.out_is)):
        print(f"skigen: error: {why}", file=sys.stderr)
        return 2
    try:
        return args.func(args)
    except (CliError, ModelError, RecordingError, OSError) as exc:
        print(f"skigen: error: {exc}", file=sys.stderr)
        return 2
    except (ValueError, RuntimeError) as exc:
        print(f"skigen: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("skigen: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
