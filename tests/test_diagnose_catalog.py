"""skigen diagnose names the catalog's structural effects that act outside the rate equations'
terms, on the systems the diagnosis was not developed on (scenarios in benchmarks/scenarios.py):

- tanks_sensor_sat: the upper level sensor's range ends (sensor_saturation, in the output equation);
- arm_backlash: a play between the commanded and the applied voltage (backlash);
- arm_frac_delay: a delay of 2.25 samples (fractional_delay: whole and fractional part searched).

Each is asserted from report.json (named first, on its equation, its parameter near the truth,
nothing remaining) and from corrected_model.py: the file loads, states the effect where it acts
(the output expression, a play state, the input history) and its free run on the recording's
input follows the true noiseless response better than the nominal's.
"""
import numpy as np
import pytest

from benchmarks.scenarios import make
from models import motor_pendulum as arm, two_tanks as tanks
from skigen.diagnose import diagnose
from skigen.modelfile import load_model
from skigen.simulate import free_run

SEED = 1
# parameter tolerances, in the parameter's unit, about 3× the error measured with seed 1
TOLERANCE = {
    "tanks_sensor_sat": 3 * tanks.H_NOISE["h1_meas"],      # m: three noise std of one sample
    "arm_backlash": 0.03,                                   # V, of a 0.15 V play
    "arm_frac_delay": 0.25,                                 # samples, of 2.25: below a quarter sample
}


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    cache = {}

    def get(name):
        if name not in cache:
            sc = make(name, seed=SEED)
            d = tmp_path_factory.mktemp(name)
            try:
                rep = diagnose(sc.model_file, sc.write_csv(d / f"{name}.csv"), d / "out", show_progress=False,
                               figures=False, emit=False)
                cache[name] = dict(scenario=sc, data=rep.data)
            except Exception as exc:          # a diagnosis that fails fails every test of it, once
                cache[name] = exc
        if isinstance(cache[name], Exception):
            raise cache[name]
        return cache[name]
    return get


@pytest.mark.parametrize("name", TOLERANCE)
def test_named_first_with_its_parameter(diagnosed, name):
    r = diagnosed(name)
    sc, d = r["scenario"], r["data"]
    assert d["mismatch_detected"] is True
    top = d["findings"][0] if d["findings"] else None
    assert top is not None and top["effect"] == sc.effect, d["findings"]
    assert sc.equation in top["equation"].split("+"), top
    assert abs(top["coefficient"] - sc.truth) < TOLERANCE[name], (top["coefficient"], top["std"], sc.truth)
    assert d["remaining"]["mismatch"] is False, d["remaining"]


def test_sensor_saturation_side_and_output(diagnosed):
    top = diagnosed("tanks_sensor_sat")["data"]["findings"][0]
    assert top["output"] == "h1_meas" and top["shape"]["side"] == "upper", top


def _noiseless(sc) -> np.ndarray:
    """The true output without noise: the tanks' levels clipped by the sensor, the arm's angle
    simulated again on the same voltage without process noise."""
    if sc.system == "two_tanks":
        return np.minimum(sc.run.h1, sc.truth)
    quiet = arm.simulate(sc.run.V, effect=sc.effect, parameter=sc.truth, seed=SEED, noise=False)
    return quiet.theta


@pytest.mark.parametrize("name", TOLERANCE)
def test_corrected_model_file_states_and_reproduces_it(diagnosed, name):
    r = diagnosed(name)
    sc, d = r["scenario"], r["data"]
    corrected = load_model(d["corrected_model"])
    text = open(d["corrected_model"]).read()
    expected = {"sensor_saturation": "ca.fmin(h1", "backlash": "model.state('V_play'",
                "fractional_delay": "model.input_history(V, 3)"}[sc.effect]
    assert expected in text, text
    nominal = load_model(sc.model_file)
    truth = _noiseless(sc)
    rmse = {}
    for which, m in (("nominal", nominal), ("corrected", corrected)):
        _, y = free_run(m, np.column_stack(list(sc.inputs.values())))
        rmse[which] = float(np.sqrt(np.mean((y[:, 0] - truth) ** 2)))
    assert rmse["corrected"] < 0.5 * rmse["nominal"], rmse
