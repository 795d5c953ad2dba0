"""Time and peak memory of whole diagnoses (calibration, cross-validation, naming, joint refit,
what remains, report), one per case, each in its own process, with what it found.

    skigen bench diagnose [--json] [--no-silverbox]

Cases: the cart with an actuator lag and the quadrotor with ground effect, 10 000 samples each
(100 s at 100 Hz); and, when ../shared/data is present, the Silverbox standard training range
(65 062 samples) against its linear nominal (models/silverbox_greybox.py:linear).
"""
from __future__ import annotations

import resource
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from benchmarks.common import emit, parser

CASES = ("cart_lag", "quad_ground_effect")
SECONDS = 100.0     # 10 000 samples at 100 Hz
DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "silverbox_snls80mv.csv"


def _scenario(name: str) -> dict:
    from benchmarks.scenarios import one
    with tempfile.TemporaryDirectory() as tmp:
        r = one(name, Path(tmp), SECONDS, seed=1)
    return dict(samples=r["samples"], seconds=r["seconds"], found=r["found"], right=bool(r["right"]),
                peak_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)


def _silverbox(_: str) -> dict:
    from models import silverbox_greybox as G
    from skigen.diagnose import diagnose
    from skigen.recording import read_recording
    train = read_recording(DATA, ["V1"], ["V2"]).slice(*G.TRAIN)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        rep = diagnose(G.linear, train, tmp, show_progress=False)
    found = "; ".join(f"{f['effect']} on {f['equation']} {f['coefficient']:.4g}" + (f"±{f['std']:.2g}" if f['std'] is not None and f['std'] == f['std'] else "") for f in rep.findings)
    return dict(samples=len(train.t), seconds=time.perf_counter() - t0, found=found or "-",
                right=bool(rep.findings) and rep.findings[0]["effect"] == "cubic_stiffness",
                peak_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)


def main(argv=None) -> int:
    p = parser("diagnose", seeds=1)
    p.add_argument("--no-silverbox", action="store_true", help="skip the 65 062-sample laboratory case")
    args = p.parse_args(argv)
    jobs = [(name, _scenario) for name in CASES]
    if DATA.is_file() and not args.no_silverbox:
        jobs.append(("silverbox_training", _silverbox))
    report = {}
    for name, job in jobs:
        with ProcessPoolExecutor(max_workers=1) as pool:      # a fresh process: its own peak memory
            report[name] = pool.submit(job, name).result()
        print(f"{name}: {report[name]['seconds']:.1f} s", file=sys.stderr, flush=True)
    table = "\n".join(["Whole diagnoses on this machine (each in its own process)",
                       f"{'case':20s} {'samples':>8s} {'seconds':>8s} {'peak MB':>8s}  found"] +
                      [f"{k:20s} {v['samples']:8d} {v['seconds']:8.1f} {v['peak_mb']:8.0f}  {v['found']}"
                       for k, v in report.items()])
    return emit(report, args.json, table)


if __name__ == "__main__":
    sys.exit(main())
