"""Reading and filtering long logs: a 1 M-row CSV read onto the grid (whole), and the C UKF run by
``skigen run`` (which streams a CSV: memory independent of its length) over a 1 M-row CSV and
over a CSV of at least 200 MB, written as it is filtered; wall time, CPU time and peak memory of
each in a fresh interpreter, and the machine's load average before each.

    skigen bench logs [--rows-read 1000000] [--mb-run 200] [--json]
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.common import emit, parser

MODEL = "models.wingrock:model"
BLOCK = 200_000


def write_log(path: Path, rows: int | None = None, mb: float | None = None, seed: int = 0) -> int:
    """A WingRock-like CSV (t, delta, phi, and two columns the model does not use), in blocks of
    rows: ``rows`` of them, or as many as make ``mb`` megabytes. Returns the number of rows."""
    rng = np.random.default_rng(seed)
    a = 0
    with open(path, "w") as f:
        f.write("t,delta,phi,mode,temperature\n")
        while (rows is None or a < rows) and (mb is None or f.tell() < mb * 1e6):
            k = np.arange(a, a + BLOCK if rows is None else min(a + BLOCK, rows))
            delta = 3 * np.sin(0.7 * k * 0.02) + rng.normal(0, 0.1, len(k))
            phi = 5 * np.sin(0.7 * k * 0.02 - 1) + rng.normal(0, 0.1, len(k))
            temp = 20 + rng.normal(0, 1, len(k))
            f.write("".join(f"{kk * 0.02:.2f},{d:.9f},{p:.9f},AUTO,{tt:.4f}\n"
                            for kk, d, p, tt in zip(k, delta, phi, temp)))
            a += len(k)
    return a


def measured(code: str) -> dict:
    """Run ``code`` in a fresh interpreter: its printed seconds, its CPU seconds (all threads) and
    its peak memory (MB), with the load average (1 min) just before."""
    load = os.getloadavg()[0]
    r = subprocess.run([sys.executable, "-c", code + "\nimport resource, sys\nu = resource.getrusage("
                        "resource.RUSAGE_SELF)\nprint(u.ru_utime + u.ru_stime, u.ru_maxrss / 1024)"],
                       capture_output=True, text=True)
    if r.returncode:
        raise RuntimeError(r.stderr)
    lines = r.stdout.split()
    return dict(seconds=float(lines[-3]), cpu_seconds=float(lines[-2]), peak_mb=float(lines[-1]), load=load)


def _run_code(csv: Path, out: Path) -> str:
    return (f"import time, contextlib, io\nfrom skigen.cli import main\nt0 = time.perf_counter()\n"
            f"with contextlib.redirect_stdout(io.StringIO()):\n"
            f"    assert main(['run', '{MODEL}', '{csv}', '--filter', 'ukf', '--backend', 'c', '--out', '{out}']) == 0\n"
            f"print(time.perf_counter() - t0)")


def main(argv=None) -> int:
    p = parser("logs", seeds=1)
    p.add_argument("--rows-read", type=int, default=1_000_000)
    p.add_argument("--mb-run", type=float, default=200.0, help="size of the CSV filtered (MB, at least)")
    args = p.parse_args(argv)
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        read_csv, run_csv, out = Path(tmp) / "read.csv", Path(tmp) / "run.csv", Path(tmp) / "result.csv"
        n = write_log(read_csv, args.rows_read)
        rows["read"] = dict(rows=n, mb=read_csv.stat().st_size / 1e6, **measured(
            f"import time\nfrom skigen.cli import load_model\nfrom skigen.recording import load_recording\n"
            f"m = load_model('{MODEL}')\nt0 = time.perf_counter()\nload_recording('{read_csv}', m)\n"
            f"print(time.perf_counter() - t0)"))
        subprocess.run([sys.executable, "-c", f"from skigen.cli import load_model\nfrom skigen.derive import "
                        f"derive\nfrom skigen.emit.c import load_c\nload_c(derive(load_model('{MODEL}'), 'ukf'))"],
                       check=True)                          # compile (cached) outside the timings
        rows["run_short"] = dict(rows=n, mb=read_csv.stat().st_size / 1e6, **measured(_run_code(read_csv, out)),
                                 out_mb=out.stat().st_size / 1e6)
        read_csv.unlink()
        n = write_log(run_csv, mb=args.mb_run)
        rows["run"] = dict(rows=n, mb=run_csv.stat().st_size / 1e6, **measured(_run_code(run_csv, out)),
                           out_mb=out.stat().st_size / 1e6)
    line = lambda task, r: (f"{task:44s} {r['rows']:9d} {r['mb']:6.0f} {r['seconds']:8.2f} {r['cpu_seconds']:8.2f} "
                            f"{r['peak_mb']:8.0f} {r['load']:5.2f}")
    table = "\n".join([
        f"Long logs on this machine ({os.cpu_count()} cores; fresh interpreter each; CPU = all threads; "
        f"peak = maximum resident memory; load = 1-min load average before)",
        f"{'task':44s} {'rows':>9s} {'MB':>6s} {'seconds':>8s} {'CPU s':>8s} {'peak MB':>8s} {'load':>5s}",
        line("read a CSV onto the grid (load_recording)", rows["read"]),
        line("skigen run --filter ukf --backend c", rows["run_short"]),
        line("skigen run --filter ukf --backend c", rows["run"])])
    return emit(rows, args.json, table)


if __name__ == "__main__":
    sys.exit(main())
