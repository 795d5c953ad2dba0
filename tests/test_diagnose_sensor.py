"""skigen diagnose tells a miscalibrated sensor from missing dynamics (scenarios in
benchmarks/scenarios.py, each a clean recording whose one sensor column reads gain·y + offset):

- arm_encoder_offset: the encoder zeroed 0.05 rad away (a constant torque on ω was named before
  the catalog had sensor effects: 1.946 ± 0.025 rad/s², nothing remaining);
- pitch_gyro_bias: the pitch gyro 0.01 rad/s high (a pitch-moment bias on q was named and a
  mismatch remained);
- pitch_vane_gain: the α vane 15 % high (a linear stiffness on q, −0.90, and a mismatch remained).

Each is named first, on the state its output reads, its value within about three std of the
truth, with nothing remaining, and corrected_model.py declares it as a parameter of that output.
"""
import pytest

from tests.scenario_cache import diagnosis_cache

SEED = 1
# measured on seed 1: 0.04918 ± 0.0006 rad, 0.00969 ± 0.00034 rad/s, 1.156 ± 0.008
TOLERANCE = {"arm_encoder_offset": 0.002, "pitch_gyro_bias": 0.001, "pitch_vane_gain": 0.025}
PARAMETER = {"arm_encoder_offset": "theta + sensor_offset_theta_meas",
             "pitch_gyro_bias": "q + sensor_offset_q_gyro",
             "pitch_vane_gain": "sensor_gain_alpha_vane * alpha"}


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    return diagnosis_cache(tmp_path_factory, SEED)


@pytest.mark.parametrize("name", TOLERANCE)
def test_the_sensor_is_named_not_the_dynamics(diagnosed, name):
    r = diagnosed(name)
    sc, d = r["scenario"], r["data"]
    assert d["mismatch_detected"] is True
    top = d["findings"][0] if d["findings"] else None
    assert top is not None and top["effect"] == sc.effect and top["equation"] == sc.equation, d["findings"]
    assert abs(top["coefficient"] - sc.truth) < TOLERANCE[name], (top["coefficient"], top["std"], sc.truth)
    assert len(d["findings"]) == 1 and d["remaining"]["mismatch"] is False, (d["findings"], d["remaining"])
    text = open(d["corrected_model"]).read()
    assert PARAMETER[name] in text, text
