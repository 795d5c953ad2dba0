"""A ship's heading (first-order Nomoto model, K = 0.1, T = 10 s) under a PD autopilot whose
rudder commands reach ±35° while the rudder stops at ±15° or ±20°: a saturation behind a clipped
command, in closed loop, on a system none of the scenarios has. Before, the limit's grid of |δ|'s
quantiles collapsed onto the command's clip (0.105, 0.570, 0.611 rad), the cross-validation saw
only grid points, and the joint refit kept two insignificant corrections of the nominal's own
constants: the 20° stop was named as an input gain and a backlash, the 15° stop as 0.221 ± 0.019
after an input gain (truth 0.262). Each now names the stop alone, within its error bar. And
Norrbin's cubic yaw damping, which the catalog did not have."""
import numpy as np
import pandas as pd
import pytest

from skigen import Model
from skigen.diagnose import diagnose

K, T_N, DT = 0.1, 10.0, 0.1


def ship() -> Model:
    m = Model("ship", dt=DT, discretization="rk4")
    psi = m.state("psi", unit="rad", role="angle", std=0.02, process_std=1e-5)
    r = m.state("r", unit="rad/s", role="rate", std=0.005, process_std=2e-4)
    delta = m.input("delta", unit="rad")
    m.dynamics({psi: r, r: (K * delta - r) / T_N})
    m.output("psi_meas", psi, unit="rad", noise_std=0.0035)
    m.output("r_meas", r, unit="rad/s", noise_std=0.002)
    return m


def voyage(seed: int, stop_deg: float | None, seconds: float = 400.0, a3: float = 0.0) -> pd.DataFrame:
    """Heading steps of ±10–40° every 30–60 s, PD on the measured heading and rate, the command
    clipped at ±35° and the rudder at ±stop_deg, Norrbin's cubic yaw damping a3·r³ (s²/rad²) in
    the plant; RK4 at DT with the model's process noise."""
    rng = np.random.default_rng(seed)
    n = int(seconds / DT) + 1
    ref, k = np.zeros(n), 0
    while k < n:
        h = int(rng.integers(300, 600))
        ref[k:k + h] = np.deg2rad(rng.choice([-40, -25, -10, 10, 25, 40]))
        k += h
    stop = np.deg2rad(stop_deg) if stop_deg else np.inf
    f = lambda x, d: np.array([x[1], (K * d - x[1] - a3 * x[1] ** 3) / T_N])
    x, rows = np.zeros(2), []
    for k in range(n):
        y = x + np.array([0.0035, 0.002]) * rng.standard_normal(2)
        cmd = float(np.clip(2.0 * (ref[k] - y[0]) - 20.0 * y[1], -np.deg2rad(35), np.deg2rad(35)))
        rows.append((k * DT, cmd, *y))
        d = float(np.clip(cmd, -stop, stop))
        k1 = f(x, d); k2 = f(x + DT / 2 * k1, d); k3 = f(x + DT / 2 * k2, d); k4 = f(x + DT * k3, d)
        x = x + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4) + np.array([1e-5, 2e-4]) * rng.standard_normal(2)
    return pd.DataFrame(rows, columns=["t", "delta", "psi_meas", "r_meas"])


@pytest.mark.parametrize("seed, stop_deg", [(2, 20.0), (6, 15.0)])
def test_a_rudder_stop_behind_a_clipped_command_is_named_alone(tmp_path, seed, stop_deg):
    d = diagnose(ship(), voyage(seed, stop_deg), tmp_path, show_progress=False, figures=False, emit=False).data
    assert d["mismatch_detected"] and not d["remaining"]["mismatch"], d["remaining"]
    [stop] = d["findings"]
    assert stop["effect"] == "input_saturation", d["findings"]
    truth = np.deg2rad(stop_deg)
    assert abs(stop["coefficient"] - truth) < 2.5 * stop["std"] and stop["std"] < 0.01, (stop["coefficient"], stop["std"])


def test_a_clean_voyage_names_nothing(tmp_path):
    d = diagnose(ship(), voyage(3, None), tmp_path, show_progress=False, figures=False, emit=False).data
    assert not d["mismatch_detected"] and d["findings"] == []


def test_norrbin_s_cubic_yaw_damping_is_named_as_such(tmp_path):
    """The yaw damping of a ship grows with r³ (Norrbin: T ṙ + r + a₃ r³ = K δ, a₃ = 500 s²/rad²,
    so −50·r³ on ṙ). Without a cubic damping in the catalog it was named as a quadratic drag,
    2.47 ± 0.22, and called consistent; now cubic_damping, within its error bar of 50."""
    d = diagnose(ship(), voyage(7, None, a3=500.0), tmp_path, show_progress=False, figures=False, emit=False).data
    [damping] = d["findings"]
    assert (damping["effect"], damping["equation"]) == ("cubic_damping", "r"), d["findings"]
    assert abs(damping["coefficient"] - 50.0) < 2.5 * damping["std"] < 5.0, (damping["coefficient"], damping["std"])
    assert not d["remaining"]["mismatch"]
