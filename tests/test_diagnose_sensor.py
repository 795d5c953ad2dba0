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


def test_a_sensor_stuck_partway_and_an_input_hole_are_left_out_and_said(tmp_path):
    """A cart recording the nominal model explains, with its position sensor frozen for 2 s at
    36 s and the force unknown for 2 s at 12 s: the frozen readings are left out, the longest
    stretch between the input holes is diagnosed, the report says both, and no mismatch is
    found. Diagnosed as read (the frozen value and the held force taken as data) the mean NIS is
    130 and a mismatch is declared (measured)."""
    import numpy as np
    import pandas as pd
    from benchmarks.scenarios import make
    from skigen.diagnose import diagnose
    sc = make("cart_clean", seed=SEED)
    frame = pd.DataFrame({"t": sc.t, **sc.inputs, **sc.outputs})       # t, F, p_meas at 100 Hz
    frame.loc[3600:3800, "p_meas"] = frame.loc[3600, "p_meas"]
    frame.loc[1200:1400, "F"] = np.nan
    d = diagnose(sc.model_file, frame, tmp_path, show_progress=False, figures=False, emit=False).data
    assert not d["mismatch_detected"] and d["consistency"]["nis_mean"] < 1.1
    stuck, hole, moving = d["notes"]
    assert "output 'p_meas' holds one reading in 201 samples" in stuck and "from t = 36 to 38 s), far longer" in stuck
    assert "11.99–14.01 s (2.02 s) without F" in hole and "14.01–59.99 s (4599 of 6000 samples)" in hole
    assert "[14.01–59.99 s]: the recording does not start at the model's initial state" in moving   # the cart moves
    assert "Note: DataFrame: output 'p_meas' holds one reading" in (tmp_path / "report.md").read_text()


def test_an_output_hole_in_the_stretch_diagnosed_is_said():
    """Readings missing for 20 s of the 46 s diagnosed (44 %) (after a force hole) are said with their share;
    one before the force hole, outside the stretch, is not. A battery log whose voltage was
    missing for 87 % of it was reported as 'no significant mismatch' without a word."""
    import numpy as np
    import pandas as pd
    from benchmarks.scenarios import make
    from skigen.diagnose.inputs import load, usable
    sc = make("cart_clean", seed=SEED)
    frame = pd.DataFrame({"t": sc.t, **sc.inputs, **sc.outputs})
    frame.loc[1200:1400, "F"] = np.nan
    frame.loc[300:600, "p_meas"] = np.nan
    frame.loc[3000:5000, "p_meas"] = np.nan
    rec, notes = usable(load(sc.model_file, frame)[2])
    (said,) = [n for n in notes if n.startswith("readings missing")]
    assert said.endswith("29.99–50.01 s (20 s) without p_meas (44% of the recording)"), said


def _vertical():
    """A multirotor's vertical axis, its thrust gain and drags declared off (truth 20, 0.3, 0.05)."""
    from skigen import Model
    m = Model("vertical", dt=0.02, discretization="rk4")
    h = m.state("h", unit="m", role="altitude", std=1.0, process_std=1e-4)
    v = m.state("v", unit="m/s", role="velocity", std=0.5, process_std=5e-3)
    T = m.input("T")
    kT, c1 = m.parameter("kT", 18.0, bounds=(1.0, 100.0)), m.parameter("c1", 0.5, bounds=(0.0, 10.0))
    cd = m.parameter("cd", 0.02, bounds=(0.0, 5.0))
    m.dynamics({h: v, v: kT * T - 9.81 - c1 * v - cd * v * abs(v)})
    m.output("baro", h, unit="m", noise_std=0.15)
    m.output("vz", v, unit="m/s", noise_std=0.05)
    return m


def test_a_velocity_sensor_offset_is_not_absorbed_by_the_kinematic_identity(tmp_path):
    """Altitude ḣ = v read by a barometer, v by a vertical-speed sensor 0.3 m/s high, the altitude's
    process noise declared 1e-4 m: the calibration may not give the kinematic identity more
    noise than declared, so the offset is named. Calibrated freely (a user's fleet log like
    this one), h took 284× its declared noise, baro and vz were reconciled by a wandering
    altitude, and nothing was named. The truth has no noise on h and the declared 5e-3 m/s on v."""
    import numpy as np
    import pandas as pd
    from skigen.diagnose import diagnose
    rng = np.random.default_rng(5)
    N, dt = 3001, 0.02
    t = np.arange(N) * dt
    s = np.sum(np.sin(2 * np.pi * rng.uniform(0.05, 1.0, 6)[:, None] * t + rng.uniform(0, 2 * np.pi, 6)[:, None]), 0)
    T = 9.81 / 20 + 0.06 * s / np.abs(s).max()
    acc = lambda v, u: 20 * u - 9.81 - 0.3 * v - 0.05 * v * abs(v)
    h, v = np.zeros(N), np.zeros(N)
    for k in range(N - 1):                         # Euler at dt/20, the noise once per sample
        hk, vk = h[k], v[k]
        for _ in range(20):
            hk, vk = hk + dt / 20 * vk, vk + dt / 20 * acc(vk, T[k])
        h[k + 1], v[k + 1] = hk, vk + 5e-3 * rng.normal()
    frame = pd.DataFrame({"t": t, "T": T, "baro": h + 0.15 * rng.normal(size=N),
                          "vz": v + 0.3 + 0.05 * rng.normal(size=N)})
    d = diagnose(_vertical(), frame, tmp_path, show_progress=False, figures=False, emit=False).data
    assert d["noise"]["calibrated"]["process_std"]["h"] <= 1e-4 * (1 + 1e-9), d["noise"]
    top = d["findings"][0] if d["findings"] else None
    assert top is not None and (top["effect"], top.get("output")) == ("sensor_offset", "vz"), d["findings"]
    assert abs(top["coefficient"] - 0.3) < 4 * top["std"] and abs(top["coefficient"] - 0.3) < 0.01, top
    assert d["remaining"]["mismatch"] is False, d["remaining"]


def _motor():
    """A DC motor (R 2 Ω, Kt = Ke = 0.05, gear 10, J 0.01, b 0.005) whose current sensor reads the
    armature current (u − Ke·N·ω)/R, and an encoder."""
    from skigen import Model
    m = Model("dcmotor", dt=0.005, discretization="rk4")
    th = m.state("theta", unit="rad", role="angle", std=0.01, process_std=1e-5)
    w = m.state("w", unit="rad/s", role="rate", std=0.1, process_std=2e-3)
    u = m.input("u", unit="V")
    i = (u - 0.5 * w) / 2.0
    m.dynamics({th: w, w: (0.5 * i - 0.005 * w) / 0.01})
    m.output("theta_meas", th, unit="rad", noise_std=2e-3)
    m.output("i_meas", i, unit="A", noise_std=0.02)
    return m


def test_a_start_blamed_for_a_sensor_gain_is_cleared_by_the_corrected_model(tmp_path):
    """A motor recorded from rest whose current sensor reads 15 % high: at its first samples (a
    5.4 V command: 0.4 A high, 20 noise std; seeds 2–5 start at lower commands and are not
    judged off) the nominal model reads the high current as a speed and the report said the
    recording does not start at the model's initial state. Judged again with the corrected
    model (the sensor gain found), the start is the declared one, and the note says so."""
    import numpy as np
    import pandas as pd
    from skigen.diagnose import diagnose
    rng = np.random.default_rng(1)                     # its first command, 5.4 V, reads 0.4 A high at once
    n, u, k = 2001, np.empty(2001), 0
    while k < n:
        h = rng.integers(20, 80)
        u[k:k + h], k = rng.uniform(-6, 6), k + h
    f = lambda x, v: np.array([x[1], (0.5 * (v - 0.5 * x[1]) / 2.0 - 0.005 * x[1]) / 0.01])
    x, rows = np.zeros(2), []
    for k in range(n):
        rows.append((k * 0.005, u[k], x[0] + 2e-3 * rng.standard_normal(),
                     1.15 * (u[k] - 0.5 * x[1]) / 2.0 + 0.02 * rng.standard_normal()))
        h = 0.005
        k1 = f(x, u[k]); k2 = f(x + h / 2 * k1, u[k]); k3 = f(x + h / 2 * k2, u[k]); k4 = f(x + h * k3, u[k])
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4) + np.array([1e-5, 2e-3]) * rng.standard_normal(2)
    frame = pd.DataFrame(rows, columns=["t", "u", "theta_meas", "i_meas"])
    d = diagnose(_motor(), frame, tmp_path, show_progress=False, figures=False, emit=False).data
    [gain] = d["findings"]
    assert (gain["effect"], gain["output"]) == ("sensor_gain", "i_meas") and abs(gain["coefficient"] - 1.15) < 0.01
    (start,) = [n for n in d["notes"] if "does not start at the model's initial state" in n]
    assert start.endswith("judged with the corrected model, the recording starts at the declared state after "
                          "all: the misfit at its start was what the findings explain"), start


def test_a_weak_motor_and_an_encoder_gain_are_said_to_be_the_same_on_a_position_log(tmp_path):
    """A gear motor whose torque constant is 20 % low, its angle read by an encoder: from rest,
    θ = 0.8·θ_nominal exactly, so an encoder gain of 0.8 and an input gain of −0.2·K/J on ω are the
    same model. Under the noise calibrated on the nominal (process noise 20× the true one) the
    alternative was scored 13 behind and never said; at 0.8, the end of the gain's grid, nothing
    was named. Now one is named and the other is its tie, both values right (measured: 0.80013 ±
    0.00022, −9.9935 ± 0.011 for 0.8 and −10; 0.42 behind on the whole recording)."""
    import numpy as np
    import pandas as pd
    from skigen import Model
    from skigen.diagnose import diagnose
    J, K, B = 0.01, 0.5, 0.55
    m = Model("gearmotor", dt=0.005, discretization="rk4")
    th = m.state("theta", unit="rad", role="angle", std=0.01)
    w = m.state("w", unit="rad/s", role="rate", std=0.1, process_std=0.01)
    V = m.input("V", unit="V")
    m.dynamics({th: w, w: (K * V - B * w) / J})
    m.output("enc", th, unit="rad", noise_std=5e-4)
    rng = np.random.default_rng(2828)
    n, dt = 3000, 0.005
    volts, k = np.empty(n), 0
    while k < n:
        hold = int(rng.uniform(0.05, 0.4) / dt)
        volts[k:k + hold], k = rng.uniform(-6, 6), k + hold
    f = lambda x, u: np.array([x[1], (0.8 * K * u - B * x[1]) / J])
    x, angle = np.zeros(2), np.empty(n)
    for k in range(n):
        angle[k] = x[0]
        k1 = f(x, volts[k]); k2 = f(x + dt / 2 * k1, volts[k]); k3 = f(x + dt / 2 * k2, volts[k])
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + f(x + dt * k3, volts[k]))
        x[1] += rng.normal(0, 0.01)
    frame = pd.DataFrame({"t": np.arange(n) * dt, "V": volts, "enc": angle + rng.normal(0, 4.4e-4, n)})
    d = diagnose(m, frame, tmp_path, show_progress=False, figures=False, emit=False).data
    (found,) = d["findings"]
    (tie,) = found.get("as_good", [])
    pair = {found["effect"]: found, tie["effect"]: tie}
    assert set(pair) == {"sensor_gain", "input_gain"}, d["findings"]
    g, u = pair["sensor_gain"], pair["input_gain"]
    assert abs(g["coefficient"] - 0.8) < 3 * g["std"] < 0.002 and abs(u["coefficient"] + 10) < 3 * u["std"] < 0.05
    assert d["remaining"]["mismatch"] is False
    # The nominal's calibration put the encoder at ~1e-6 rad for 5e-4: the report says it is no statement
    # about the sensor (a user read the table as one).
    text = (tmp_path / "report.md").read_text()
    assert "The calibration puts the noise of enc (" in text and "against 0.0005) far below the declared" in text



def _car(wheel_gain: float, gps_gain: float, seed: int = 4):
    """A 1500 kg car on a speed loop (PI on the wheel speed) through ten 30 s steps of 8–28 m/s, 300 s
    at 10 Hz, with a rolling resistance of 0.012·g the model lacks: the model (x, v; F in N) and the
    recording of the force, the wheel speed (wheel_gain·v, 0.05 m/s noise) and GPS position
    (gps_gain·x, 2 m noise)."""
    import numpy as np
    import pandas as pd
    from skigen import Model
    m = Model("car", dt=0.1, discretization="rk4")
    x = m.state("x", unit="m", role="position", std=1.0)
    v = m.state("v", unit="m/s", role="velocity", initial=10.0, std=0.5, process_std=0.01)
    F = m.input("F", unit="N")
    m.dynamics({x: v, v: F / 1500.0 - 2.8e-4 * v * v})
    m.output("v_wheel", v, unit="m/s", noise_std=0.05)
    m.output("x_gps", x, unit="m", noise_std=2.0)
    rng = np.random.default_rng(seed)
    n, dt = 3000, 0.1
    ref = np.repeat([10, 20, 15, 25, 8, 18, 28, 12, 22, 16], 300)
    f = lambda s, u: np.array([s[1], u / 1500 - 2.8e-4 * s[1] ** 2 - 0.012 * 9.81])
    s, integral, rows = np.array([0.0, 10.0]), 0.0, np.empty((n, 3))
    for k in range(n):
        wheel = wheel_gain * s[1] + rng.normal(0, 0.05)
        integral += (ref[k] - wheel) * dt
        force = np.clip(1500 * (0.4 * (ref[k] - wheel) + 0.04 * integral), -4000, 4000)
        rows[k] = force, wheel, gps_gain * s[0] + rng.normal(0, 2.0)
        for _ in range(4):
            h = dt / 4
            k1 = f(s, force); k2 = f(s + h / 2 * k1, force); k3 = f(s + h / 2 * k2, force)
            s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + f(s + h * k3, force))
        s[1] += rng.normal(0, 0.01)
    return m, pd.DataFrame({"t": np.arange(n) * dt, "F": rows[:, 0], "v_wheel": rows[:, 1], "x_gps": rows[:, 2]})


@pytest.mark.parametrize("wheel, gps", [(1.04, 1.0), (1.0, 0.96)])
def test_of_two_sensors_of_one_motion_the_one_off_is_named(tmp_path, wheel, gps):
    """A wheel speed sensor reading 4 % high beside a GPS position: a GPS gain of 1/1.04 with a
    4 % force gain and a drag change is the same model in other units, and it won the first round
    (22 ahead: the noise calibrated on the nominal favours it). Four numbers where two do: the
    revision now tries each round's rivals with the later findings they still need, and the wheel
    gain with the rolling resistance alone explains the recording better (measured: 1.04002 ±
    6.2e-05, bias −0.1172 ± 0.0018 for −0.1177). With the GPS the one off (0.96), its gain is
    named and the wheel is left alone."""
    from skigen.diagnose import diagnose
    m, frame = _car(wheel, gps)
    d = diagnose(m, frame, tmp_path, show_progress=False, figures=False, emit=False).data
    found = {(f["effect"], f.get("output") or f["equation"]): f for f in d["findings"]}
    gain = found.pop(("sensor_gain", "v_wheel" if wheel != 1 else "x_gps"))
    assert abs(gain["coefficient"] - (wheel if wheel != 1 else gps)) < 3 * gain["std"], gain
    (bias,) = found.values()
    assert bias["effect"] == "bias" and abs(bias["coefficient"] + 0.012 * 9.81) < 3 * bias["std"], bias
    assert d["remaining"]["mismatch"] is False
    table = (tmp_path / "report.md").read_text()          # a sensor acts on its output, not on an equation
    sensor = "| sensor_gain | `v_wheel` (reads `v`) |" if wheel != 1 else "| sensor_gain | `x_gps` (reads `x`) |"
    assert sensor in table, table
    assert "| bias | `v` |" in table


def _slope_frame(seed: int, noise_seed: int):
    """A mass (1 kg) on a spring (20 N/m, damping 0.5 N·s/m) on a 10° slope with a quadratic drag
    0.8·v·|v| the model lacks, under a 0.1 → 2 Hz chirp of ±8 N repeated, recorded from its second
    chirp (30 s at 100 Hz, starting in motion): the model (x, v; F) and the recording."""
    import numpy as np
    import pandas as pd
    from skigen import Model
    g = 9.81 * np.sin(np.radians(10))
    m = Model("slope", dt=0.01, discretization="rk4")
    x = m.state("x", unit="m", role="position", std=0.01, process_std=1e-6)
    v = m.state("v", unit="m/s", role="velocity", std=0.01, process_std=1e-3)
    F = m.input("F", unit="N")
    m.dynamics({x: v, v: F - 20 * x - 0.5 * v - g})
    m.output("x_meas", x, unit="m", noise_std=0.005)
    rng, noise = np.random.default_rng(seed), np.random.default_rng(noise_seed)
    n, dt = 6000, 0.01
    tt = np.arange(n) * dt % 30
    force = 8 * np.sin(2 * np.pi * (0.1 * tt + 1.9 / 60 * tt ** 2))
    f = lambda s, u: np.array([s[1], u - 20 * s[0] - 0.5 * s[1] - 0.8 * s[1] * abs(s[1]) - g])
    s, pos, h = np.zeros(2), np.empty(n), dt / 5
    for k in range(n):
        pos[k] = s[0]
        for _ in range(5):
            k1 = f(s, force[k]); k2 = f(s + h / 2 * k1, force[k]); k3 = f(s + h / 2 * k2, force[k])
            s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + f(s + h * k3, force[k]))
        s = s + rng.normal(0, [0, 1e-3])
    frame = pd.DataFrame({"t": np.arange(n) * dt, "F": force, "x_meas": pos + noise.normal(0, 0.005, n)})
    return m, frame[n // 2:]


def test_a_start_the_nominal_misfit_hid_is_judged_with_the_corrected_model(tmp_path):
    """The mass on a slope recorded in motion (x −0.09 m, v 0.7 m/s against a declared rest, std
    0.01): the nominal's misfit (process noise 70× the true one) covered the start and it was
    taken as declared; the drag, under the tight noise it leaves, then failed on the folds from
    that start and nothing was named ('a mismatch remains'). Judged with the drag, the start is
    rejected and the diagnosis runs again from the vague prior, saying why (measured: 0.7996 ±
    0.0011, log-likelihood 10922 → 11618, consistent; 0.7983–0.8006 on four other seeds, each
    rejected so)."""
    from skigen.diagnose import diagnose
    m, frame = _slope_frame(31, 99)
    d = diagnose(m, frame, tmp_path, show_progress=False, figures=False, emit=False).data
    [drag] = d["findings"]
    assert drag["effect"] == "quadratic_drag" and abs(drag["coefficient"] - 0.8) < 3 * drag["std"] < 0.004, drag
    (start,) = [n for n in d["notes"] if "does not start at the model's initial state" in n]
    assert "every filter of the diagnosis starts from the declared mean with 100× the declared std (judged " \
           "with quadratic_drag on v: the nominal's misfit had hidden it)" in start, start
    assert d["fit"]["after"]["loglik"] > d["fit"]["before"]["loglik"] and d["remaining"]["mismatch"] is False


def test_a_state_no_output_sees_keeps_its_declared_noise_and_the_diagnosis_runs(tmp_path):
    """A car's position, integrated from its speed and read by no sensor, with a wheel speed sensor
    5 % high and an accelerometer: the calibration could not tell its process noise from 0 and
    the diagnosis stopped ("'Q_scale_x' has no effect on the likelihood … --estimate NAME", an
    option diagnose does not have; `skigen fit --method filter-error` refused the same). That
    noise is now held at its declared value, said, and the wheel gain named (measured 1.0474 ±
    0.0022)."""
    import numpy as np
    import pandas as pd
    from skigen import Model
    from skigen.diagnose import diagnose
    m = Model("car", dt=0.02, discretization="rk4")
    x = m.state("x", unit="m", role="position", std=0.5, process_std=1e-4)
    v = m.state("v", unit="m/s", role="velocity", initial=5.0, std=0.5, process_std=0.01)
    a = m.input("a_cmd", unit="m/s^2")
    m.dynamics({x: v, v: a - 0.05 * v})
    m.output("wheel_v", v, unit="m/s", noise_std=0.05)
    m.output("imu_ax", a - 0.05 * v, unit="m/s^2", noise_std=0.1)
    rng, n, dt = np.random.default_rng(41), 4000, 0.02
    ref, k = np.empty(n), 0
    while k < n:
        hold = int(rng.uniform(4, 10) / dt)
        ref[k:k + hold], k = rng.uniform(5, 20), k + hold
    speed, integral, rows = 5.0, 0.0, np.empty((n, 3))
    decay = np.exp(-0.05 * dt)
    for k in range(n):
        wheel = 1.05 * speed + 0.05 * rng.standard_normal()
        integral += (ref[k] - wheel) * dt
        u = np.clip(0.8 * (ref[k] - wheel) + 0.2 * integral, -3, 3)
        rows[k] = u, wheel, u - 0.05 * speed + 0.1 * rng.standard_normal()
        speed = decay * speed + (1 - decay) / 0.05 * u + 0.01 * rng.standard_normal()
    frame = pd.DataFrame({"t": np.arange(n) * dt, "a_cmd": rows[:, 0], "wheel_v": rows[:, 1], "imu_ax": rows[:, 2]})
    from skigen.fit import fit
    held = fit(m, frame, method="filter-error", show_progress=False)        # skigen fit holds it too
    assert "the process noise of x is held at its declared value: no output sees it, and no recording can " \
           "calibrate it" in held.notes and held.noise["scales"]["Q_scale_x"]["value"] == 1.0
    d = diagnose(m, frame, tmp_path, show_progress=False, figures=False, emit=False).data
    assert any("the process noise of x is held at its declared value: no output sees it" in n for n in d["notes"])
    assert d["noise"]["calibrated"]["process_std"]["x"] == 1e-4
    [gain] = d["findings"]
    assert (gain["effect"], gain["output"]) == ("sensor_gain", "wheel_v")
    assert abs(gain["coefficient"] - 1.05) < 3 * gain["std"], gain
