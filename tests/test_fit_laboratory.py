"""The grey boxes on laboratory data: the Silverbox Duffing fit of README (skips
without ../shared/data)."""
from pathlib import Path

import numpy as np
import pytest

from models import silverbox_greybox as G
from skigen.fit import fit
from skigen.fit.output import validate
from skigen.recording import read_recording

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason=f"laboratory recordings not found in {DATA} (../shared/data)")


def test_silverbox_duffing_foh_simulates_arrow_full_within_1_2_mV():
    rec = read_recording(DATA / "silverbox_snls80mv.csv", ["V1"], ["V2"])
    result = fit(G.build(), [rec.slice(*G.TRAIN)], show_progress=False)
    assert result.converged and result.iterations < 20
    k3 = result.parameters["k3"]
    assert 7.0e5 < k3["value"] < 7.6e5 and 0 < k3["std"] < 0.01 * k3["value"]    # measured 731 763 ± 1 600
    assert result.recordings[0]["rmse"]["V2"] < 1.1e-3                            # measured 1.03 mV
    tests = {name: rec.slice(a, b) for name, (a, b) in G.TESTS.items()}
    rmse = {name: c["rmse"]["V2"] for name, c in zip(tests, validate(result, list(tests.values())))}
    assert rmse["arrow full"] < 1.2e-3                                           # measured 1.14 mV
    assert rmse["arrow no extrapolation"] < 0.95e-3                              # measured 0.87 mV
    assert rmse["multisine"] < 1.1e-3                                            # measured 1.03 mV
    assert np.isfinite(result.correlation["matrix"]).all()
