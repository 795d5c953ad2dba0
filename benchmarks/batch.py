"""skigen batch on Dask: 200 small logs with 1 and 2 local workers in the same run, against a plain
loop in one process; the overhead per log is what the batch adds to that loop.

    skigen bench batch [--logs 200] [--seconds 15] [--filter ukf] [--backend python]
                       [--scheduler tcp://host:8786 --dir /shared/path] [--json]

With --scheduler the batch runs on that cluster (whatever workers it has) instead of the local
1- and 2-worker clusters; --dir must then be a folder every worker sees at the same path.
"""
from __future__ import annotations

import logging
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.common import emit, parser

MODEL = "models.wingrock:model"


def write_logs(folder: Path, count: int, seconds: float) -> list[Path]:
    from models.wingrock_sim import simulate
    from skigen.recording import write_recording
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(count):
        sim = simulate(seed=i, duration=seconds)
        paths.append(folder / f"flight_{i:04d}.csv")
        write_recording(paths[-1], sim.t, {"delta": sim.delta}, {"phi": sim.phi})
    return paths


def plain_loop(paths, out: Path, filt: str, backend: str) -> tuple[float, int]:
    """(seconds to read, filter and write every log in this process one after the other, the
    number of logs whose filter diverged)."""
    import skigen
    from skigen.modelfile import load_model
    model = load_model(MODEL)
    out.mkdir(parents=True, exist_ok=True)
    t0, diverged = time.perf_counter(), 0
    for p in paths:
        skigen.run(model, p, filter=filt, backend=backend).write(out / f"{p.stem}.csv")
    return time.perf_counter() - t0, diverged


def timed_batch(paths, out: Path, filt: str, backend: str, workers=None, scheduler=None) -> dict:
    """Start the cluster (or connect), run the batch, close: its seconds, without and with the start."""
    from distributed import Client, LocalCluster
    from skigen.batch import batch
    t0 = time.perf_counter()
    if scheduler:
        cluster, client = None, Client(scheduler, timeout=10)
    else:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0",
                               silence_logs=logging.CRITICAL)
        client = Client(cluster)
    t1 = time.perf_counter()
    try:
        res = batch(MODEL, [str(p) for p in paths], out, filter=filt, backend=backend, client=client,
                    show_progress=False, figures=False)
        t2 = time.perf_counter()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    if res.counts.get("failed"):
        raise RuntimeError(f"batch: {res.counts['failed']} of {len(paths)} logs failed: "
                           + next(r["message"] for r in res.rows if r["status"] == "failed"))
    return dict(workers=res.workers, start_s=t1 - t0, batch_s=t2 - t1, diverged=res.counts.get("diverged", 0),
                task_s=sum(r["seconds"] for r in res.rows))


_BUSY = "import time\nt0 = time.perf_counter()\nx = 0\nfor i in range(6_000_000): x += i * i\nprint(time.perf_counter() - t0)"


def free_cores() -> float:
    """The cores this run really has (the machine is shared): 2 × (the time of a CPU-bound loop
    alone) / (its time with two copies side by side)."""
    import subprocess
    run = lambda: subprocess.Popen([sys.executable, "-c", _BUSY], stdout=subprocess.PIPE, text=True)
    alone = float(run().communicate()[0])
    pair = [run(), run()]
    both = max(float(p.communicate()[0]) for p in pair)
    return 2 * alone / both


def main(argv=None) -> int:
    p = parser("batch", seeds=1)
    p.add_argument("--logs", type=int, default=200)
    p.add_argument("--seconds", type=float, default=15.0, help="length of each log (s, 50 Hz; default 15)")
    p.add_argument("--filter", default="ukf")
    p.add_argument("--backend", default="python", choices=["python", "c"])
    p.add_argument("--scheduler", default=None, help="a Dask scheduler address instead of local clusters")
    p.add_argument("--dir", default=None, help="folder for the logs and outputs (default: a temporary one)")
    args = p.parse_args(argv)
    load = os.getloadavg()[0]            # the cores are shared: what else was running
    cores = free_cores()
    root = Path(args.dir) if args.dir else Path(tempfile.mkdtemp(prefix="skigen-bench-batch-"))
    try:
        paths = write_logs(root / "logs", args.logs, args.seconds)
        loop, diverged = plain_loop(paths, root / "loop", args.filter, args.backend)
        runs = ([timed_batch(paths, root / "remote", args.filter, args.backend, scheduler=args.scheduler)]
                if args.scheduler else
                [timed_batch(paths, root / f"w{n}", args.filter, args.backend, workers=n) for n in (1, 2)])
    finally:
        if not args.dir:
            shutil.rmtree(root, ignore_errors=True)
    n = args.logs
    base = runs[0]["batch_s"]
    for r in runs:
        r["ratio_to_first"] = r["batch_s"] / base
        r["ms_per_log"] = 1e3 * r["batch_s"] / n
    overhead = 1e3 * (runs[0]["batch_s"] * runs[0]["workers"] - loop) / n if runs[0]["workers"] == 1 else None
    report = dict(logs=n, samples_per_log=int(round(args.seconds / 0.02)) + 1, filter=args.filter,
                  backend=args.backend, cores=os.cpu_count(), plain_loop_s=loop, diverged=diverged,
                  load_average_before=load, free_cores_before=cores, runs=runs,
                  overhead_ms_per_log=overhead)
    lines = [f"skigen batch: {n} WingRock logs of {args.seconds:g} s ({report['samples_per_log']} samples), "
             f"{args.filter}, {args.backend} backend, {os.cpu_count()} cores ({diverged} logs diverge: a row "
             f"each, in the loop and the batch)",
             f"before the run: load average {load:.2f}; two CPU-bound processes side by side ran as on "
             f"{cores:.2f} free cores",
             f"{'':28s} {'wall s':>8s} {'ms/log':>8s} {'ratio':>6s} {'cluster start s':>16s}",
             f"{'plain loop, one process':28s} {loop:8.2f} {1e3 * loop / n:8.1f}"]
    for r in runs:
        label = f"batch, {r['workers']} worker{'s' if r['workers'] > 1 else ''}"
        lines.append(f"{label:28s} {r['batch_s']:8.2f} {r['ms_per_log']:8.1f} {r['ratio_to_first']:6.2f} "
                     f"{r['start_s']:16.2f}")
    if overhead is not None:
        lines.append(f"overhead per log (1 worker against the plain loop): {overhead:.1f} ms")
    return emit(report, args.json, "\n".join(lines))


if __name__ == "__main__":
    sys.exit(main())
