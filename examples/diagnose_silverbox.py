"""Silverbox: diagnose the linear nominal on the standard training range, then score the corrected
model by free-run simulation on the three standard test sets.

    python examples/diagnose_silverbox.py [DATA_DIR] [--out out/diagnose_silverbox] [--samples N | --whole-file]

The nominal is the linear oscillator with first-order input hold and its constants declared as
parameters (`models/silverbox_greybox.py:linear`); the circuit is a Duffing oscillator. The
diagnosis should name `cubic_stiffness` first. Its corrected model (every constant refitted
jointly with the cubic term and the noise on spread blocks of the record) is simulated free on
the three test sets as written (initial state from the first 50 samples, as in
examples/silverbox_greybox.py), then once more after a user's output-error refit (`skigen fit`)
on the whole training range.
"""
from __future__ import annotations

import argparse
import sys
from types import SimpleNamespace
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from models import silverbox_greybox as G  # noqa: E402
from skigen.diagnose import diagnose  # noqa: E402
from skigen.diagnose.report import finding_line  # noqa: E402
from skigen.fit import fit  # noqa: E402
from skigen.fit.output import validate  # noqa: E402
from skigen.modelfile import load_model  # noqa: E402
from skigen.recording import read_recording  # noqa: E402


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("data", nargs="?", default=str(ROOT.parent / "shared" / "data"))
    p.add_argument("--out", default=str(ROOT / "out" / "diagnose_silverbox"))
    p.add_argument("--samples", type=int, default=None, help="first N samples of the training range only")
    p.add_argument("--whole-file", action="store_true", help="the whole SNLS80mV file as given (131 072 samples)")
    args = p.parse_args(argv)
    path = Path(args.data) / "silverbox_snls80mv.csv"
    if not path.is_file():
        sys.exit(f"{path} not found: pass the folder holding the Silverbox recordings")
    rec = read_recording(path, ["V1"], ["V2"])
    a, b = G.TRAIN
    train = rec if args.whole_file else rec.slice(a, b if args.samples is None else a + args.samples)
    rep = diagnose(G.linear, train, args.out)
    print(f"diagnosis: {rep.seconds:.1f} s; findings, the one a simulation needs most first:")
    for f in rep.findings:
        print(f"  {finding_line(f)}")
    out = {"findings": rep.findings, "seconds": rep.seconds}
    if rep.data["corrected_model"]:
        corrected = load_model(rep.data["corrected_model"])
        tests = {name: rec.slice(s, e) for name, (s, e) in G.TESTS.items()}
        as_written = validate(SimpleNamespace(model=corrected, weights={}), list(tests.values()))
        out["test_mV"] = {name: 1e3 * c["rmse"]["V2"] for name, c in zip(tests, as_written)}
        print("free-run RMSE of corrected_model.py as the diagnosis wrote it (mV): "
              + ", ".join(f"{k} {v:.2f}" for k, v in out["test_mV"].items()))
        r = fit(corrected, [train])
        refitted = validate(r, list(tests.values()))
        out["refit_test_mV"] = {name: 1e3 * c["rmse"]["V2"] for name, c in zip(tests, refitted)}
        print("... refitted by output error on the whole training range (skigen fit) (mV): "
              + ", ".join(f"{k} {v:.2f}" for k, v in out["refit_test_mV"].items()))
    return out


if __name__ == "__main__":
    main()
