"""Many logs on Dask distributed: ``skigen batch`` and :func:`batch`.

    from skigen.batch import batch
    result = batch("models/quadrotor_mukf.py", "flights/*.csv", "out/fleet", filter="mukf",
                   track=["theta", "phi"], workers=2)       # or scheduler="tcp://host:8786"
    result.rows, result.moved, result.summary_csv, result.figure

One Dask task per log (:func:`skigen.batch.task.run_log`, a module-level function
taking the model spec, the log's path and plain options, so that any worker can
import it). Locally a ``LocalCluster`` of single-threaded worker processes;
elsewhere any scheduler by address. Scheduling, retries after a lost worker and
transport are Dask's. A bad log is a ``failed`` row, never the end of the batch.
Logs whose ``DIR/<log>/done.json`` matches the current options, model and log are
not done again. The C backend is compiled once, here, into ``DIR/.build``; the
workers find it there by content hash.
"""
from __future__ import annotations

import glob as _glob
import hashlib
import json
import logging
import os
import shutil
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from ..fit import OPTIMISTIC, UNITS
from ..modelfile import canonical_spec
from ..progress import progress
from ..sources import printable
from .summary import moves, order_rows, plot_summary, unlike_the_fleet, write_summary
from .task import MARKER, log_digest, model_digest, quantity_names, run_log

__all__ = ["batch", "BatchError", "BatchResult", "MODES", "expand_logs", "log_names", "run_log"]

MODES = ("run", "fit", "diagnose")
UNLIKE_FLEET = "unlike the fleet"     # a note's opening: a log whose NIS stands far above the others'



class BatchError(ValueError):
    """A batch that cannot start: no log matches, a bad option, an unreachable scheduler."""


@dataclass
class BatchResult:
    """What :func:`batch` did; ``rows`` are summary.csv's, in fleet order."""

    out_dir: Path
    rows: list[dict]
    moved: list[dict]
    order: str
    summary_csv: Path
    figure: Path | None
    skipped: int            # logs already complete, not done again
    seconds: float
    workers: int
    counts: dict = field(default_factory=dict)

    def lines(self) -> list[str]:
        """What the command prints: counts, the failed logs, the moves."""
        c = self.counts
        out = [f"{len(self.rows)} logs: {c.get('ok', 0)} ok, {c.get('diverged', 0)} diverged, "
               f"{c.get('failed', 0)} failed ({self.skipped} already complete, not done again) in "
               f"{self.seconds:.1f} s on {self.workers} worker(s) -> {self.summary_csv}"]
        out += [f"  {r['status']}: {r['log']}: {r['message']}" for r in self.rows if r["status"] != "ok"]
        verdicts = {r["log"]: r.get("verdict") for r in self.rows}
        for m in self.moved:
            if m.get("back"):
                out.append(f"  back: {m['quantity']} at {m['log']}: {m['before']:.4g} -> {m['after']:.4g}, the level "
                           f"before {m['previous']} (z = {m['z']:.1f}): {m['previous']} alone moved")
                continue
            out.append(f"  moved: {m['quantity']} at {m['log']}: {m['before']:.4g} -> {m['after']:.4g} "
                       f"(z = {m['z']:.1f} > {m['threshold']:.2f})" + (
                           f"; its run is {verdicts[m['log']]}: its ± may be too small, the move false"
                           if verdicts.get(m["log"]) == "inconsistent" else ""))
        optimistic = [r["log"] for r in self.rows if any(str(n).startswith(OPTIMISTIC) for n in r.get("notes") or [])]
        if optimistic:
            out.append(f"  note: the fits of {_few(optimistic)} say their error bars are optimistic (output error, its "
                       f"free-run residuals beyond the declared sensor noise: a disturbance it does not model), so "
                       f"moves between them may be false; --method filter-error models the disturbance")
        for r in self.rows:
            if r["status"] == "ok" and (r.get("verdict") or "").startswith("no reading"):
                out.append(f"  {r['verdict']}: {r['log']}: its estimates are the declared priors; see "
                           f"{self.out_dir / r['log'] / 'summary.txt'}")
            elif r["status"] == "ok" and r.get("verdict") not in (None, "consistent"):
                out.append(f"  {r['verdict']}: {r['log']}: mean NIS {r.get('mean_nis') or float('nan'):.3g} (expected "
                           f"{r.get('nis_expected') or float('nan'):.3g}); see {self.out_dir / r['log'] / 'summary.txt'}")
            if r["status"] == "ok":
                out += [f"  {said}: {r['log']}: {n[len(said) + 2:]}" for n in r.get("notes") or []
                         for said in (UNITS, UNLIKE_FLEET) if str(n).startswith(f"{said}: ")]
            if r.get("mismatch") and r["status"] == "ok":
                out.append(f"  mismatch: {r['log']}: " + ("; ".join(r.get("findings") or []) or "nothing named")
                           + ("; a mismatch remains" if r.get("remains") else ""))
        if self.figure:
            out.append(f"figure: {self.figure} (logs ordered by {self.order})")
        return out


def _few(names: list[str], most: int = 5) -> str:
    return ", ".join(names[:most]) + (f" and {len(names) - most} more" if len(names) > most else "")


def expand_logs(patterns, outside: Path | None = None) -> list[Path]:
    """The files matching each glob (sorted; ``**`` recurses) or named plainly, in order, without
    duplicates (a broken link among them: its row fails, naming it; folders are not logs), and none
    below the folder ``outside`` (a batch's own results, when its output
    folder lies where the glob looks). A pattern that matches no file is an error naming it."""
    if isinstance(patterns, (str, os.PathLike)):
        patterns = [patterns]
    outside = None if outside is None else Path(outside).resolve()
    files: dict = {}
    for pat in patterns:
        if not isinstance(pat, (str, os.PathLike)):
            raise BatchError(f"logs: file names or globs, not a {type(pat).__name__} (a batch reads each log in "
                             f"its worker: write a DataFrame to a file first, e.g. df.to_parquet('flight.parquet'))")
        pat = str(pat)
        if _glob.has_magic(pat):
            found = sorted(p for p in _glob.glob(pat, recursive=True) if _a_log(Path(p)))
        else:
            found = [pat] if _a_log(Path(pat)) else []
        if outside is not None:
            found = [p for p in found if not Path(p).resolve().is_relative_to(outside)]
        if not found:
            raise BatchError(f"no log file matches '{pat}'")
        files.update(dict.fromkeys(Path(p).resolve() if Path(p).exists() else Path(p).absolute() for p in found))
    if not files:
        raise BatchError("no log given")
    return list(files)


def _a_log(p: Path) -> bool:
    """A file, or a link to one that is gone (its row fails, naming it); not a folder."""
    return p.is_file() or (p.is_symlink() and not p.exists())


def log_names(paths: list[Path]) -> list[str]:
    """Each log's folder name under DIR: its file stem, or, where two stems collide, its path
    from the logs' common folder with '/' as '__' (and its extension, where that still collides)."""
    stems = [p.stem for p in paths]
    if len(set(stems)) == len(stems):
        return stems
    root = Path(os.path.commonpath([str(p.parent) for p in paths]))
    names = [str(p.relative_to(root).with_suffix("")).replace(os.sep, "__") for p in paths]
    if len(set(names)) == len(names):
        return names
    return [str(p.relative_to(root)).replace(os.sep, "__") for p in paths]     # c.csv beside c.parquet


def _spec(model) -> str:
    from ..model import Model
    if isinstance(model, Model):
        raise BatchError("batch needs the model as a file path or package.module:attribute (each worker "
                         "loads it again), not a Model object")
    return canonical_spec(model)


def _fingerprint(options: dict, log: Path) -> str:
    keep = {k: v for k, v in options.items() if k not in ("build", "fingerprint")}
    text = json.dumps(keep, sort_keys=True, default=str) + log_digest(log)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def _complete(final: Path, fingerprint: str) -> dict | None:
    marker = final / MARKER
    try:
        row = json.loads(marker.read_text())
    except (OSError, ValueError):
        return None
    return row if row.get("fingerprint") == fingerprint else None


def _client(workers, scheduler, connect_timeout):
    """(client, cluster or None, number of workers)."""
    from distributed import Client, LocalCluster
    if scheduler:
        try:
            client = Client(scheduler, timeout=connect_timeout)
        except (OSError, TimeoutError, ValueError) as exc:
            msg = str(exc).strip().splitlines()
            raise BatchError(f"cannot connect to the Dask scheduler at '{scheduler}' "
                             f"({msg[0] if msg else type(exc).__name__})") from None
        return client, None, len(client.scheduler_info()["workers"])
    from dask.system import CPU_COUNT
    n = int(workers or CPU_COUNT)
    if n < 1:
        raise BatchError(f"workers must be at least 1, got {workers}")
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                           dashboard_address="127.0.0.1:0",   # a free port: None still takes 8787, and warns beside another batch
                           silence_logs=logging.CRITICAL)
    return Client(cluster), cluster, n


def batch(model, logs, out_dir, *, mode: str = "run", filter: str | None = None, backend: str = "python",
          real: str = "double", track=(), estimate=(), method: str = "output-error", figures: bool = True,
          time=None, time_unit: str = "s", columns=None, max_gap: float = 1.0, workers: int | None = None,
          scheduler: str | None = None, client=None, retries: int = 1, connect_timeout: float = 10.0,
          show_progress: bool = True) -> BatchResult:
    """Run ``model`` over every log of ``logs`` (globs or paths) on Dask; write ``out_dir``.

    mode: ``run`` (the ``filter`` over each log — default SKI where the model declares unknown
    terms, else the UKF — ``backend`` python or c), ``fit`` (output-error
    :func:`skigen.fit.fit` of each log) or ``diagnose``. track: states whose final value ± std
    join the summary (besides the weights and ``estimate``-d parameters). time, time_unit,
    columns, max_gap: how to read the logs (:func:`skigen.recording.load_recording`).
    workers: local worker processes (default: the machine's cores); scheduler: a Dask
    scheduler address instead (the logs and ``out_dir`` must be at the same paths on its
    workers); client: an existing ``distributed.Client`` (not closed). retries: Dask retries of
    a task whose worker was lost.
    """
    t0 = time_now()
    if mode not in MODES:
        raise BatchError(f"mode must be one of {', '.join(MODES)}, got '{mode}'")
    if backend not in ("python", "c"):
        raise BatchError(f"unknown backend '{backend}'; choose python or c")
    if scheduler and (workers or client):
        raise BatchError("give either a scheduler address or a number of local workers, not both")
    from ..modelfile import ModelFileError, load_model
    spec = _spec(model)
    try:
        m = load_model(spec)
    except ModelFileError as exc:
        raise BatchError(str(exc)) from None
    track, estimate = tuple(track or ()), tuple(estimate or ())
    for name in track:
        if name not in m.state_names:
            raise BatchError(f"--track '{name}': not a state of model '{m.name}' (states: "
                             f"{', '.join(m.state_names)})")
    out = Path(out_dir).resolve()
    paths = expand_logs(logs, outside=out)          # what to read, before what to run on it
    filt = None
    if mode == "run":
        from ..derive import default_filter, derive
        filter = filter or default_filter(m)
        try:
            filt = derive(m, filter, estimate=estimate)
        except ValueError as exc:
            raise BatchError(str(exc)) from None
        quantity_names(filt, track)
    names = log_names(paths)
    out.mkdir(parents=True, exist_ok=True)
    for stale in out.glob(".*.tmp-*"):          # left by a batch that was stopped
        shutil.rmtree(stale, ignore_errors=True)
    build = out / ".build"
    options = dict(spec=spec, digest=model_digest(spec, m), mode=mode, filter=filter, backend=backend, real=real,
                   build=str(build), track=list(track), estimate=list(estimate), method=method,
                   figures=bool(figures), read=dict(time=time, time_unit=time_unit, columns=columns,
                                                    max_gap=max_gap))
    rows, todo = {}, []
    for path, name in zip(paths, names):
        fp = _fingerprint(options, path)
        done = _complete(out / name, fp)
        if done is not None:
            rows[name] = done
        else:
            todo.append((path, name, dict(options, fingerprint=fp)))
    skipped = len(rows)
    n_workers = 0
    if todo:
        if filt is not None and backend == "c":     # compiled once, here; the workers load it by hash
            from ..emit.c import load_c
            load_c(filt, real, cache_dir=build)
        own = client is None
        if own:
            client, cluster, n_workers = _client(workers, scheduler, connect_timeout)
        else:
            cluster, n_workers = None, len(client.scheduler_info()["workers"])
        try:
            rows.update(_submit(client, todo, out, retries, show_progress))
        finally:
            if own:
                client.close()
                if cluster is not None:
                    cluster.close()
    ordered, order = order_rows([rows[n] for n in names])
    moved = moves(ordered)
    for log, x, median in unlike_the_fleet(ordered):
        row = next(r for r in ordered if r["log"] == log)
        row["notes"] = list(row.get("notes") or []) + [
            f"{UNLIKE_FLEET}: mean NIS {x:.3g}× the expected, {x / median:.3g}× the fleet's median {median:.3g}: its "
            f"readings disagree with the model far more than the others' (units, a sensor, another vehicle)"]
    csv_path = write_summary(out / "summary.csv", ordered, moved, mode)
    fig = plot_summary(out / "summary.png", ordered, moved, order, title=f"{m.name}: {mode}"
                       + (f" ({filter}, {backend})" if mode == "run" else "")) if figures else None
    counts = {s: sum(r["status"] == s for r in ordered) for s in ("ok", "diverged", "failed")}
    return BatchResult(out, ordered, moved, order, csv_path, fig, skipped, time_now() - t0, n_workers, counts)


def _submit(client, todo, out: Path, retries: int, show_progress: bool) -> dict:
    """Map :func:`run_log` over the logs; collect the rows as they complete."""
    from distributed import as_completed
    token = uuid.uuid4().hex[:8]           # fresh keys: a result deleted on disk is really done again
    futures = client.map(run_log, [o["spec"] for _, _, o in todo], [str(p) for p, _, _ in todo],
                         [str(out)] * len(todo), [n for _, n, _ in todo], [o for _, _, o in todo],
                         key=[f"skigen-batch-{n}-{token}" for _, n, _ in todo],
                         pure=False, retries=retries)
    which = {f.key: (path, name, o) for f, (path, name, o) in zip(futures, todo)}
    rows = {}
    done = as_completed(futures)
    try:
        for fut in (progress(done, len(futures), "batch: logs") if show_progress else done):
            path, name, o = which[fut.key]
            try:
                rows[name] = fut.result()
            except Exception as exc:  # the task itself failed (e.g. its worker died each time): a failed row
                msg = str(exc).strip().splitlines()
                rows[name] = dict(file=str(path), log=name, status="failed", quantities={}, findings=[],
                                  message=printable(f"{type(exc).__name__}: {msg[0] if msg else ''}".rstrip(": "), 300))
    except BaseException:
        client.cancel(futures)
        raise
    return rows


def time_now() -> float:
    return time.perf_counter()
