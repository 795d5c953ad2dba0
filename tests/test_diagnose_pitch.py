"""skigen diagnose on a fifth system, the short-period pitch dynamics of an aircraft flown by a
pilot and a pitch damper (models/short_period.py; scenarios in benchmarks/scenarios.py), where
two things used to go wrong. Asserted from report.json:

- a 30 ms elevator delay: the noise calibration widens the turbulence on q until the innovations
  are white, so only the test of innovations against the past (detect.independence) sees it;
- a pitch break +80·α³ with Mα, Mq, Mδ declared 30 % off: the calibration bends Mα to absorb the
  break, and the joint refit, which took the calibration's std as its prior, stayed there (Mα
  −7.51, the break −55.7 instead of −8 and −80); it now keeps only the user's prior.
"""
import pytest

from models import short_period as pitch
from tests.scenario_cache import diagnosis_cache

SEED = 1


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    return diagnosis_cache(tmp_path_factory, SEED)


def test_the_delay_leaves_white_innovations_that_follow_the_elevator(diagnosed):
    c = diagnosed("pitch_delay")["data"]["consistency"]
    assert c["whiteness_pvalue"] > c["alpha"] / 3, c["whiteness_pvalue"]     # measured 0.21
    assert c["independence_pvalue"] < 1e-20, c["independence_pvalue"]        # measured 9e-120


def test_the_delay_is_named_in_whole_samples_and_nothing_remains(diagnosed):
    d = diagnosed("pitch_delay")["data"]
    top = d["findings"][0]
    assert top["effect"] == "input_delay" and round(top["coefficient"]) == pitch.EFFECTS["elevator_delay"][0]
    assert not d["remaining"]["mismatch"]
    before, after = (d["fit"][k]["free_run_rmse"]["q_gyro"] for k in ("before", "after"))
    assert after < before / 1.8, (before, after)                              # measured 0.0147 → 0.0070


def test_the_refit_of_the_grey_box_reaches_the_true_moments(diagnosed):
    d = diagnosed("pitch_cubic_grey")["data"]
    top = d["findings"][0]
    assert (top["effect"], top["equation"]) == ("cubic_stiffness", "q")
    fitted = {k: v["value"] for k, v in d["refit"]["parameters"].items()}
    # measured: Mα −8.13, break −95.5 ± 6.2, as a filter-error `skigen fit` of the true structure
    # on this seed (78.6 and 79.7 on seeds 2 and 3); with the calibration's std as prior the
    # refit stayed at −7.51 and −55.7
    assert abs(fitted["Ma"] - pitch.MA) < 0.2, fitted
    assert abs(fitted["cubic_stiffness_q"] + pitch.EFFECTS["cubic_moment"][0]) < 0.25 * 80, fitted
    assert not d["remaining"]["mismatch"]


def test_clean_flight_is_no_mismatch(diagnosed):
    d = diagnosed("pitch_clean")["data"]
    assert not d["mismatch_detected"] and not d["findings"]
    assert d["consistency"]["independence_pvalue"] > d["consistency"]["alpha"] / 3


def test_a_lift_offset_on_the_angle_of_attack_is_named_there(tmp_path):
    """α of role angle holds the lift, α̇ = Zα·α + q + Zδ·δe: only the identities ṗ = v are exact by
    definition, yet every equation of a position-type role went untested. A lift offset of 0.02
    rad/s on α̇ was "a step at t = 13 s" on q; it is a bias on α (measured 0.0208 ± 0.0006)."""
    from pathlib import Path
    from skigen.diagnose import diagnose
    from skigen.recording import write_recording
    flight = pitch.simulate(30.0, effect="lift_offset", seed=2)
    write_recording(tmp_path / "f.csv", flight.t, flight.inputs(), flight.outputs())
    rep = diagnose(str(Path(pitch.__file__)), tmp_path / "f.csv", tmp_path / "out", show_progress=False,
                   figures=False, emit=False)
    top = rep.findings[0]
    assert (top["effect"], top["equation"]) == ("bias", "alpha"), rep.findings
    assert abs(top["coefficient"] - 0.02) < 3 * top["std"] < 0.002, top
    assert not rep.data["remaining"]["mismatch"]

