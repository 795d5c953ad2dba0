"""A recording that does not begin at the model's declared initial state (skigen.start).

The arm (models/motor_pendulum.py, declared at rest: θ 0 ± 0.02 rad, ω 0 ± 0.05 rad/s) swung
by a 4 V multisine; a recording cut 12 s in begins mid-swing (θ ≈ 0.6 rad, ω ≈ −4.3 rad/s).
Measured here: the smoothed start within 0.1 of its std of the truth; a filter-error fit from
the declared start calibrates the rate's process noise at 0.097 rad/s (truth 0.01), from the
recorded start at 0.0091; the diagnosis of quadratic drag on that segment named nothing from
the declared start and names the drag, 0.143 ± 0.012 (truth 0.15), from the recorded one.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from benchmarks.scenarios import ARM_FILE, _arm, _arm_multisine, make
from models import motor_pendulum as arm
from skigen.diagnose import diagnose
from skigen.fit import fit
from skigen.modelfile import load_model
from skigen.recording import Recording, load_recording
from skigen.start import recorded_start

CUT = 2400          # 12 s at 200 Hz


def _segment(effect, k=CUT, seed=1):
    sc = _arm("arm", effect, _arm_multisine(4.0), "", 30.0, seed)
    rec = Recording(f"arm from {sc.t[k]:g} s", sc.t[k:] - sc.t[k], np.c_[sc.inputs["V"]][k:],
                    np.c_[sc.outputs["theta_meas"]][k:], ("V",), ("theta_meas",))
    return rec, np.array([sc.run.theta[k], sc.run.omega[k]])


@pytest.fixture(scope="module")
def model():
    return load_model(ARM_FILE)


def test_the_state_a_recording_starts_in_is_estimated_and_the_declared_one_weighed(model):
    """At rest the declared start wins by the vague prior's Occam penalty, about nx ln 100 = 9.2
    nat (measured 8.9); mid-swing it loses by thousands, and the smoothed start is the truth's."""
    at_rest, _ = _segment(None, k=0)
    rs = recorded_start(model, at_rest)
    assert rs.consistent and -9.5 < rs.gain < -8
    mid, truth = _segment(None)
    rs = recorded_start(model, mid)
    assert not rs.consistent and rs.gain > 1000
    assert np.all(np.abs(rs.mean - truth) < 3 * rs.std), (rs.mean, truth, rs.std)
    note = rs.note(mid.path, "x")
    assert "omega -4.3" in note and "theta 0.65" in note and note.endswith("; x")


def test_a_model_error_does_not_move_a_right_start(tmp_path):
    """The quadrotor's ground effect, strongest at the start on the ground: over the whole
    recording the vague start predicted 110 nat better (the filters' innovations far beyond their
    noise amplify any difference); over the head the declared start wins (measured 7.6 nat)."""
    sc = make("quad_ground_effect")
    quad = load_model(sc.model_file)
    rs = recorded_start(quad, load_recording(sc.write_csv(tmp_path / "quad.csv"), quad))
    assert rs.consistent and rs.gain < -5


def test_a_filter_error_fit_starts_where_the_recording_does(model):
    """From the declared start the transient is put down to process noise (9.7x its truth)."""
    mid, _ = _segment(None)
    fitted = fit(model, [mid], method="filter-error", show_progress=False)
    declared = fit(model, [mid], method="filter-error", starts="declared", show_progress=False)
    q = lambda r: r.noise["calibrated"]["process_std"]["omega"]
    assert q(fitted) == pytest.approx(0.01, rel=0.15)
    assert q(declared) > 5 * 0.01
    assert any("does not start at the model's initial state" in n for n in fitted.notes)
    assert not any("initial state" in n for n in declared.notes)
    with pytest.raises(ValueError, match="starts must be a list or 'declared'"):
        fit(model, [mid], method="filter-error", starts="recorded", show_progress=False)


def test_drag_is_named_on_a_recording_that_begins_mid_swing(model, tmp_path):
    """Held out: another flight (seed 2) cut mid-swing, each model started where it begins: the
    corrected model's free-run RMSE there is 0.15 of the nominal's (measured 0.018 and 0.120 rad)."""
    mid, _ = _segment("quadratic_drag")
    held = dataclasses.replace(_segment("quadratic_drag", seed=2)[0], path="held out")
    rep = diagnose(ARM_FILE, mid, tmp_path, show_progress=False, figures=False, emit=False, validate=[held])
    top = rep.findings[0]
    truth = arm.EFFECTS["quadratic_drag"][0]
    assert (top["effect"], top["equation"]) == ("quadratic_drag", "omega")
    assert abs(top["coefficient"] - truth) < 2 * top["std"]
    notes = [n for n in rep.data["notes"] if "does not start at the model's initial state" in n]
    assert [n.split(":")[0] for n in notes] == [mid.path, "held out"]
    held_out = rep.data["fit"]["recordings"][0]
    assert held_out["after"]["free_run_rmse"]["theta_meas"] < 0.2 * held_out["before"]["free_run_rmse"]["theta_meas"]
    assert "theta -0.2472 ± 0.0011 against 0 ± 0.02" in notes[1]                    # against the declared start
    assert "initial=0.0, std=0.05" in (tmp_path / "corrected_model.py").read_text()   # the declared start kept
