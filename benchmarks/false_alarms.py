"""False alarms of the diagnosis's decision on recordings where the model is right.

    skigen bench false_alarms [--runs 200] [--seconds 20] [--json]

Clean recordings of four systems (the cart and the aircraft's pitch in closed loop, the two tanks
and the motor-driven arm in open loop), each with its own noise seed, are judged by
:func:`skigen.diagnose.detect` (noise calibrated first, then whiteness, independence of the past
and the slowly varying disturbance test, α = 0.01 in all). Expected: about α of them flagged; the
table gives the count with its 95 % (Clopper–Pearson) interval.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from scipy import stats

from benchmarks.common import emit, parser
from benchmarks.scenarios import make
from skigen.diagnose import detect

SYSTEMS = ("cart_clean", "tanks_clean", "arm_clean", "pitch_clean")
ALPHA = 0.01


def main(argv=None) -> int:
    p = parser("false_alarms", seeds=1)
    p.add_argument("--runs", type=int, default=200, help="clean recordings in all (200)")
    p.add_argument("--seconds", type=float, default=None, help="length of each (default: the scenario's own)")
    args = p.parse_args(argv)
    flagged, t0 = {s: 0 for s in SYSTEMS}, time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.runs):
            name = SYSTEMS[i % len(SYSTEMS)]
            sc = make(name, args.seconds, seed=1000 + i)
            flagged[name] += bool(detect(sc.model_file, sc.write_csv(Path(tmp) / "r.csv"), alpha=ALPHA)["mismatch_detected"])
            print(f"\rfalse alarms: {sum(flagged.values())} in {i + 1} runs", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    n, k = args.runs, sum(flagged.values())
    lo = stats.beta.ppf(0.025, k, n - k + 1) if k else 0.0
    hi = stats.beta.ppf(0.975, k + 1, n - k) if k < n else 1.0
    report = dict(runs=n, false_alarms=k, rate=k / n, interval=[lo, hi], alpha=ALPHA, per_system=flagged,
                  seconds=time.perf_counter() - t0)
    table = (f"False alarms on clean recordings (α = {ALPHA}): {k} in {n} runs = {k / n:.3f} "
             f"(95 % interval {lo:.3f}–{hi:.3f}); per system " + ", ".join(f"{s} {v}" for s, v in flagged.items())
             + f"; {report['seconds']:.0f} s")
    return emit(report, args.json, table)


if __name__ == "__main__":
    sys.exit(main())
