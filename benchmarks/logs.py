"""Reading and filtering long logs: a 1 M-row CSV read onto the grid, and the C UKF over a
~200 MB CSV (3.8 M rows) written as it is filtered, with the peak memory of each.

    skigen bench logs [--rows-read 1000000] [--rows-run 3800000] [--json]
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.common import emit, parser

MODEL = "models.wingrock:model"


def write_log(path: Path, rows: int, seed: int = 0) -> int:
    """A WingRock-like CSV (t, delta, phi, and two columns the model does not use), in blocks."""
    rng = np.random.default_rng(seed)
    with open(path, "w") as f:
        f.write("t,delta,phi,mode,temperature\n")
        for a in range(0, rows, 200_000):
            k = np.arange(a, min(a + 200_000, rows))
            delta = 3 * np.sin(0.7 * k * 0.02) + rng.normal(0, 0.1, len(k))
            phi = 5 * np.sin(0.7 * k * 0.02 - 1) + rng.normal(0, 0.1, len(k))
            temp = 20 + rng.normal(0, 1, len(k))
            f.write("".join(f"{kk * 0.02:.2f},{d:.9f},{p:.9f},AUTO,{tt:.4f}\n"
                            for kk, d, p, tt in zip(k, delta, phi, temp)))
    return path.stat().st_size


def measured(code: str) -> dict:
    """Run ``code`` in a fresh interpreter: its printed seconds and its peak memory (MB)."""
    r = subprocess.run([sys.executable, "-c", code + "\nimport resource, sys\nprint(resource.getrusage("
                        "resource.RUSAGE_SELF).ru_maxrss / 1024)"], capture_output=True, text=True)
    if r.returncode:
        raise RuntimeError(r.stderr)
    lines = r.stdout.split()
    return dict(seconds=float(lines[-2]), peak_mb=float(lines[-1]))


def main(argv=None) -> int:
    p = parser("logs", seeds=1)
    p.add_argument("--rows-read", type=int, default=1_000_000)
    p.add_argument("--rows-run", type=int, default=3_800_000)
    args = p.parse_args(argv)
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        read_csv, run_csv = Path(tmp) / "read.csv", Path(tmp) / "run.csv"
        size = write_log(read_csv, args.rows_read)
        rows["read"] = dict(rows=args.rows_read, mb=size / 1e6, **measured(
            f"import time\nfrom skigen.cli import load_model\nfrom skigen.recording import load_recording\n"
            f"m = load_model('{MODEL}')\nt0 = time.perf_counter()\nload_recording('{read_csv}', m)\n"
            f"print(time.perf_counter() - t0)"))
        read_csv.unlink()
        size = write_log(run_csv, args.rows_run)
        rows["run"] = dict(rows=args.rows_run, mb=size / 1e6, **measured(
            f"import time\nfrom skigen.cli import main\nt0 = time.perf_counter()\n"
            f"assert main(['run', '{MODEL}', '{run_csv}', '--filter', 'ukf', '--backend', 'c', '--out', "
            f"'{Path(tmp) / 'result.csv'}']) == 0\nprint(time.perf_counter() - t0)"))
    table = "\n".join([
        "Long logs on this machine (fresh interpreter each; peak = maximum resident memory)",
        f"{'task':44s} {'rows':>9s} {'MB':>6s} {'seconds':>8s} {'peak MB':>8s}",
        f"{'read a CSV onto the grid (load_recording)':44s} {rows['read']['rows']:9d} {rows['read']['mb']:6.0f} "
        f"{rows['read']['seconds']:8.2f} {rows['read']['peak_mb']:8.0f}",
        f"{'skigen run --filter ukf --backend c':44s} {rows['run']['rows']:9d} {rows['run']['mb']:6.0f} "
        f"{rows['run']['seconds']:8.2f} {rows['run']['peak_mb']:8.0f}"])
    return emit(rows, args.json, table)


if __name__ == "__main__":
    sys.exit(main())
