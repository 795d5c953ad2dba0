"""Diagnose the laboratory recordings of ../shared/data against their nominal models.

    python examples/diagnose_real.py --out out/diagnose_real [--samples 10000]

- Silverbox (models/silverbox_greybox.py:linear, a linear oscillator with its
  constants declared as parameters, first-order input hold): the circuit is a
  Duffing oscillator; the missing physics is a cubic stiffness. Segment: the start of
  the standard training range [40650, 105712) of silverbox_snls80mv.csv.
- Unbalanced disc (models/unbalanced_disk_greybox.py:viscous, a viscous-only
  pendulum, constants declared as parameters): the missing physics is Coulomb friction, Fc ≈ 6.06 rad/s² in the literature
  (gym-unbalanced-disk). Segment: the start of unbalanced_disk.csv.

Real data are not simulations: beside the expected effect the diagnosis also
reports what else the nominal model gets wrong, each with its evidence.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from skigen.modelfile import load_model  # noqa: E402
from skigen.diagnose import diagnose  # noqa: E402
from skigen.diagnose.report import finding_line  # noqa: E402
from skigen.recording import read_recording, write_recording  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
CASES = {   # name: (model file, data file, first sample, expected effect)
    "silverbox": ("models.silverbox_greybox:linear", "silverbox_snls80mv.csv", 40650, "cubic_stiffness"),
    "unbalanced_disk": ("models.unbalanced_disk_greybox:viscous", "unbalanced_disk.csv", 0, "coulomb_friction"),
}


def segment(name: str, out: Path, samples: int) -> Path:
    """The case's recording segment as its own CSV (time from 0)."""
    model_file, data, start, _ = CASES[name]
    model = load_model(model_file)
    rec = read_recording(DATA / data, model.input_names, model.output_names).slice(start, start + samples)
    path = out / f"{name}.csv"
    write_recording(path, rec.t - rec.t[0], {n: rec.inputs[:, i] for i, n in enumerate(rec.input_names)},
                    {n: rec.outputs[:, i] for i, n in enumerate(rec.output_names)})
    return path


def run(name: str, out: Path, samples: int, show_progress: bool = True):
    out.mkdir(parents=True, exist_ok=True)
    return diagnose(CASES[name][0], segment(name, out, samples), out / name,
                    show_progress=show_progress)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/diagnose_real")
    ap.add_argument("--samples", type=int, default=10000)
    args = ap.parse_args()
    if not DATA.is_dir():
        sys.exit(f"no laboratory data in {DATA}")
    for name, (_, _, _, expected) in CASES.items():
        rep = run(name, Path(args.out), args.samples)
        fit = rep.data["fit"]
        print(f"{name}: expected {expected}; {rep.seconds:.1f} s")
        for f in rep.findings:
            print(f"  {finding_line(f)}")
        if fit["after"]:
            k = next(iter(fit["before"]["free_run_rmse"]))
            print(f"  validation: NIS {fit['before']['nis_mean']:.3g} -> {fit['after']['nis_mean']:.3g}, "
                  f"free-run RMSE {k} {fit['before']['free_run_rmse'][k]:.4g} -> {fit['after']['free_run_rmse'][k]:.4g}")


if __name__ == "__main__":
    main()
