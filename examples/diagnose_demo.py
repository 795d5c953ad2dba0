"""Diagnose every concealed-effect scenario (and the clean ones), print what was found.

    python examples/diagnose_demo.py --out out/diagnose [--seconds S] [--only cart_lag ...]
    python examples/diagnose_demo.py --timing          # one 10 000-sample diagnosis, timed

For each scenario of ``benchmarks/scenarios.py`` it writes the
recording CSV, runs ``skigen diagnose`` (the Python function, as the CLI
does) into ``OUT/<scenario>/`` and prints: the verdict, the located equation,
window overlap with the truth, the finding against the truth, and the
cross-validated log-likelihood and free-run RMSE before and after.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.scenarios import SCENARIOS, one  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/diagnose")
    ap.add_argument("--seconds", type=float, default=None,
                    help="length of every recording (default: each scenario's own, benchmarks.scenarios.SECONDS)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--timing", action="store_true", help="time one 10 000-sample diagnosis per system")
    args = ap.parse_args()
    out = Path(args.out)
    names = args.only or list(SCENARIOS)
    if args.timing:
        names, args.seconds = ["cart_lag", "quad_ground_effect"], 100.0
    rows = []
    for name in names:
        rows.append(one(name, out, args.seconds, args.seed))
        r = rows[-1]
        print(f"{r['name']:19s} {r['samples']:6d} samples {r['seconds']:5.1f} s  mismatch={str(r['mismatch']):5s} "
              f"eq={r['equations'] or '-':3s} windows recall/precision {r['recall']:.2f}/{r['precision']:.2f}  "
              f"{'RIGHT' if r['right'] else 'WRONG'}", flush=True)
        print(f"    truth: {r['truth']}   found: {r['found']}")
        if r["rmse"][1] is not None:
            print(f"    cross-validated log-lik {r['ll'][0]:.0f} -> {r['ll'][1]:.0f}, free-run RMSE "
                  f"{r['rmse'][0]:.3g} -> {r['rmse'][1]:.3g}; regime: {r['regime']}; "
                  f"{'a mismatch remains' if r['remaining'] else 'nothing remains'}")
        print(f"    hidden: {r['concealment']}")
    print(f"\nreports in {out}/<scenario>/report.md")


if __name__ == "__main__":
    main()
