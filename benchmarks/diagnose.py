"""Time of a whole diagnosis of a 10 000-sample recording (detect, locate, name,
corrected model, report), one per system, with what it found.

    skigen bench diagnose [--json]
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from benchmarks.common import emit, parser
from benchmarks.scenarios import one

CASES = ("cart_lag", "quad_ground_effect")
SECONDS = 100.0     # 10 000 samples at 100 Hz


def main(argv=None) -> int:
    args = parser("diagnose", seeds=1).parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        rows = {name: one(name, Path(tmp), SECONDS, seed=1) for name in CASES}
    report = {name: dict(samples=r["samples"], seconds=r["seconds"], found=r["found"], right=r["right"])
              for name, r in rows.items()}
    table = "\n".join(["Diagnosis of a 10 000-sample recording on this machine",
                       f"{'scenario':20s} {'samples':>8s} {'seconds':>8s}  found"] +
                      [f"{k:20s} {v['samples']:8d} {v['seconds']:8.1f}  {v['found']}" for k, v in report.items()])
    return emit(report, args.json, table)


if __name__ == "__main__":
    sys.exit(main())
