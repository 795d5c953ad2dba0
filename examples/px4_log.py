"""The vertical channel of a PX4 flight log through a filter, straight from the ULog file.

    python examples/px4_log.py [--log ../shared/data/px4_sitl_takeoff.ulg] [--out out/px4]

Model (50 Hz grid; the log's topics come at their own rates, 10-20 Hz): altitude h (m,
up) and climb rate v, driven by the mean of the four motor commands T (0-1,
``actuator_motors.control[0..3]``, 10 Hz, held), v' = w_one + w_thrust·T while airborne;
measured: the barometric altitude (``vehicle_air_data.baro_alt_meter``, 20 Hz) minus its
value at take-off. The augmented UKF estimates h, v and the two weights (hover thrust =
-w_one/w_thrust). The figure compares h with the log's own position estimate (EKF2's
``vehicle_local_position``, -z), which fuses GPS, baro and IMU.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import skigen  # noqa: E402
from skigen.library import term  # noqa: E402
from skigen.recording import load_recording  # noqa: E402

LOG = Path(__file__).resolve().parents[2] / "shared" / "data" / "px4_sitl_takeoff.ulg"
COLUMNS = {**{f"m{i}": f"actuator_motors.control[{i}]" for i in range(4)},
           "baro": "vehicle_air_data.baro_alt_meter"}


def vertical_model(baro0: float) -> skigen.Model:
    m = skigen.Model("px4_vertical", dt=0.02, discretization="rk4")
    h = m.state("h", unit="m", role="altitude", std=0.3, process_std=1e-3)
    v = m.state("v", unit="m/s", role="velocity", std=0.1, process_std=2e-2)
    motors = [m.input(f"m{i}") for i in range(4)]
    thrust = sum(motors) / 4
    m.dynamics({h: v, v: 0 * v})
    m.output("baro", h + baro0, unit="m", noise_std=0.15)
    m.unknown(v, [term("1", 1 + 0 * thrust, key="one"), term("thrust", thrust)], prior_variance=400.0)
    return m


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", default=str(LOG))
    ap.add_argument("--out", default="out/px4")
    args = ap.parse_args()
    probe = load_recording(args.log, vertical_model(0.0), columns=COLUMNS)
    thrust = probe.inputs.mean(axis=1)
    k0 = int(np.argmax(thrust > 0.3))                 # take-off: the motors spin up
    k1 = len(thrust) - int(np.argmax(thrust[::-1] > 0.3))
    baro0 = float(np.nanmedian(probe.outputs[max(k0 - 100, 0):k0, 0]))
    model = vertical_model(baro0)
    rec = load_recording(args.log, model, columns=COLUMNS).slice(k0, k1)
    res = skigen.runtime.run(skigen.derive(model, "ukf"), rec, show_progress=False)
    print(f"{args.log}: {len(rec.t)} grid samples from t = {rec.t[0]:.2f} to {rec.t[-1]:.2f} s (airborne); "
          f"{int(rec.measured.sum())} baro samples")
    print("\n".join(res.summary().lines()))
    w = res.weights[-1]
    hover = load_recording(args.log, _position_model(), columns={"u": "actuator_motors.control[0]",
                                                                 "z": "hover_thrust_estimate.hover_thrust"})
    print(f"hover thrust -w_one/w_thrust = {-w[0] / w[1]:.3f} (PX4's own hover thrust estimate at the end: "
          f"{hover.outputs[hover.measured[:, 0], 0][-1]:.3f})")

    ekf2 = load_recording(args.log, _position_model(), columns={"u": "actuator_motors.control[0]",
                                                                "z": "vehicle_local_position.z"})
    z = np.interp(rec.t, ekf2.t[ekf2.measured[:, 0]], -ekf2.outputs[ekf2.measured[:, 0], 0])
    z -= np.interp(rec.t[0], rec.t, z)
    rms = float(np.sqrt(np.mean((res.mean[:, 0] - z) ** 2)))
    print(f"altitude: RMS difference from the log's own estimate (EKF2, -z, shifted to 0 at take-off) "
          f"{rms:.3f} m over the flight")
    _figure(Path(args.out), rec, res, z, baro0)


def _position_model() -> skigen.Model:
    m = skigen.Model("ekf2_z", dt=0.02)
    x = m.state("x")
    m.input("u")
    m.dynamics({x: 0 * x})
    m.output("z", x)
    return m


def _figure(out: Path, rec, res, z, baro0) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    t = rec.t - rec.t[0]
    ax[0].plot(t, rec.outputs[:, 0] - baro0, ".", ms=3, color="0.6", label="baro altitude (measured)")
    ax[0].plot(t, res.mean[:, 0], label="UKF h")
    ax[0].fill_between(t, res.mean[:, 0] - 2 * res.std[:, 0], res.mean[:, 0] + 2 * res.std[:, 0], alpha=0.3)
    ax[0].plot(t, z, "--", label="log's estimate (EKF2 -z)")
    ax[0].set_ylabel("altitude (m)")
    ax[0].legend(fontsize=8)
    ax[1].plot(t, res.mean[:, 1], label="UKF v")
    ax[1].set_ylabel("climb rate (m/s)")
    for j, name in enumerate(["w_one", "w_thrust"]):
        i = 2 + j
        ax[2].plot(t, res.mean[:, i], label=name)
        ax[2].fill_between(t, res.mean[:, i] - 2 * res.std[:, i], res.mean[:, i] + 2 * res.std[:, i], alpha=0.2)
    ax[2].set_ylabel("weights (m/s²)")
    ax[2].set_xlabel("time since take-off (s)")
    ax[2].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "px4_vertical.png", dpi=120)
    print(f"figure: {out / 'px4_vertical.png'}")


if __name__ == "__main__":
    main()
