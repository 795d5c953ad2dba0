"""Unbalanced disc: diagnose the viscous-only pendulum on the first 80 % of the record and score the
corrected model on the held-out last 20 % (`--validate`).

    python examples/diagnose_disc.py [DATA_DIR] [--out out/diagnose_disc]

The nominal is `models/unbalanced_disk_greybox.py:viscous` (ω0, γ, Ku declared as parameters, no
Coulomb friction). The held-out score is the report's free run over the last 20 % (7000 samples)
from the filtered state after its first 1 %, nominal against corrected.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from models import unbalanced_disk_greybox as G  # noqa: E402
from skigen.diagnose import diagnose  # noqa: E402
from skigen.diagnose.report import finding_line  # noqa: E402
from skigen.recording import read_recording  # noqa: E402


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("data", nargs="?", default=str(ROOT.parent / "shared" / "data"))
    p.add_argument("--out", default=str(ROOT / "out" / "diagnose_disc"))
    args = p.parse_args(argv)
    path = Path(args.data) / "unbalanced_disk.csv"
    if not path.is_file():
        sys.exit(f"{path} not found: pass the folder holding the unbalanced-disc recording")
    rec = read_recording(path, ["u"], ["th"])
    n = int(G.TRAIN_FRACTION * len(rec.t))
    rep = diagnose(G.viscous, rec.slice(0, n), args.out, validate=[rec.slice(n, None)])
    print(f"diagnosis: {rep.seconds:.1f} s; findings, the one a simulation needs most first:")
    for f in rep.findings:
        print(f"  {finding_line(f)}")
    held = rep.data["fit"]["recordings"][0]
    out = {"findings": rep.findings, "seconds": rep.seconds,
           "held_out_rad": {"nominal": held["before"]["free_run_rmse"]["th"],
                            "corrected": held["after"]["free_run_rmse"]["th"] if held["after"] else None}}
    print(f"held-out free-run RMSE (rad): nominal {out['held_out_rad']['nominal']:.4f}, "
          f"corrected {out['held_out_rad']['corrected'] or float('nan'):.4f}")
    return out


if __name__ == "__main__":
    main()
