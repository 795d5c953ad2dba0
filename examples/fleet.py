"""A fleet of 100 flights of the MUKF tutorial's quadrotor on Dask: the mass drifts from flight
to flight, the drag steps up at one flight; `skigen batch` flags that flight.

    python examples/fleet.py [--flights 100] [--step-at 60] [--workers N | --scheduler tcp://host:8786]

Each flight (20 s at 50 Hz) is simulated as in ``models/quadrotor_mukf.py`` (hover thrust
plus noise on each axis, one RK4 step per sample, measured position and velocity) with its
own constant mass and drag coefficient: the mass falls from 1.00 to 0.85 kg over the fleet
(about 1.5 g per flight, e.g. wear or a lighter battery), C_d is 0.010 until flight
``--step-at`` and 0.015 from it (a damaged propeller guard, say). Each log is a CSV stamped in
calendar time (one flight a day) under a random name, so the fleet is ordered by its time
stamps, not by file name.

The model is the tutorial's (θ = 1/m and φ = θ·C_d carried as random-walk states, MUKF, Euler),
with the random walk of θ and φ 100× smaller than the tutorial's: within one flight they are
constant, and the tutorial's walk (made for a mass that changes during the flight) would
forget them within seconds. The batch runs the generated C of the MUKF (compiled once) over
every log and tracks θ and φ; ``out/fleet/summary.csv`` and ``summary.png`` are the fleet view.
"""
from __future__ import annotations

import argparse
import datetime
import hashlib
import sys
from pathlib import Path

import numpy as np

from models import quadrotor_mukf as Q

WALK_SCALE = 0.01          # θ, φ random-walk std relative to the tutorial's


def fleet_model():
    model = Q.build(name="quadrotor_fleet")
    q = np.array(model.process_noise(), float)
    q[6, 6] *= WALK_SCALE ** 2
    q[7, 7] *= WALK_SCALE ** 2
    model.covariances(Q=q, R=model.measurement_noise(), P0=model.initial_covariance())
    return model


model = fleet_model()      # what `skigen batch examples/fleet.py ...` (and each Dask worker) loads


def truth(flights: int, step_at: int):
    """(mass, C_d) of each flight."""
    k = np.arange(flights)
    mass = 1.0 - 0.15 * k / max(flights - 1, 1)
    cd = np.where(k < step_at, 0.010, 0.015)
    return mass, cd


def simulate_flight(seed: int, mass: float, cd: float, duration: float = 20.0, dt: float = Q.DT):
    """The tutorial's experiment with this flight's constant mass and drag: (t, F, y)."""
    rng = np.random.default_rng(seed)
    t = np.arange(round(duration / dt) + 1) * dt
    F = Q.G * 1.0 + Q.THRUST_STD * rng.standard_normal((len(t), 3))
    x = np.zeros((len(t), 6))
    x[0] = [0, 0, 0, 0, 0, 10]
    for k in range(len(t) - 1):
        x[k + 1] = Q._rk4(x[k], F[k], 1.0 / mass, cd, dt)
    y = np.hstack([x[:, 3:6], x[:, 0:3]]) + Q.MEAS_STD * rng.standard_normal((len(t), 6))
    return t, F, y


def write_fleet(folder: Path, flights: int, step_at: int) -> list[Path]:
    """One CSV per flight, stamped in epoch seconds (a flight a day from 2025-03-01 09:00 UTC),
    under a name that does not tell the order."""
    from skigen.recording import write_recording
    folder.mkdir(parents=True, exist_ok=True)
    start = datetime.datetime(2025, 3, 1, 9, tzinfo=datetime.timezone.utc).timestamp()
    mass, cd = truth(flights, step_at)
    paths = []
    for k in range(flights):
        t, F, y = simulate_flight(1000 + k, mass[k], cd[k])
        name = "log_" + hashlib.sha1(f"flight {k}".encode()).hexdigest()[:8] + ".csv"
        write_recording(folder / name, start + 86400.0 * k + t, dict(zip(Q.INPUTS, F.T)), dict(zip(Q.OUTPUTS, y.T)))
        paths.append(folder / name)
    return paths


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--flights", type=int, default=100)
    p.add_argument("--step-at", type=int, default=60, help="first flight (0-based) with the larger drag")
    p.add_argument("--out", default="out/fleet")
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--scheduler", default=None)
    args = p.parse_args(argv)
    from skigen.batch import batch

    out = Path(args.out)
    paths = write_fleet(out / "logs", args.flights, args.step_at)
    flight_of = {pth.stem: k for k, pth in enumerate(paths)}
    res = batch(__file__, str(out / "logs" / "*.csv"), out / "batch", filter="mukf", backend="c",
                track=["theta", "phi"], workers=args.workers, scheduler=args.scheduler)
    print("\n".join(res.lines()))

    mass, cd = truth(args.flights, args.step_at)
    ok = [r for r in res.rows if r["status"] == "ok"]
    k = np.array([flight_of[r["log"]] for r in ok])
    theta = np.array([r["quantities"]["theta"][0] for r in ok])
    phi = np.array([r["quantities"]["phi"][0] for r in ok])
    print(f"\nlogs ordered by {res.order}: flight numbers in that order increasing: {bool(np.all(np.diff(k) > 0))}")
    print(f"{'flight':>6} {'log':>12} {'m (kg)':>8} {'true':>6} {'C_d':>7} {'true':>6}  moved")
    at = {m["log"]: m["quantity"] for m in res.moved}
    for i in sorted({0, 1, args.step_at - 2, args.step_at - 1, args.step_at, args.step_at + 1, len(ok) - 1}):
        if 0 <= i < len(ok):
            r = ok[i]
            print(f"{k[i]:6d} {r['log']:>12} {1 / theta[i]:8.4f} {mass[k[i]]:6.3f} {phi[i] / theta[i]:7.4f} "
                  f"{cd[k[i]]:6.3f}  {at.get(r['log'], '')}")
    slope, icpt = np.polyfit(k, 1 / theta, 1)
    print(f"mass trend: {icpt:.4f} kg at flight 0, {1000 * slope:+.3f} g per flight (true 1.0000 kg, "
          f"{-150 / max(args.flights - 1, 1):+.3f} g per flight); largest error "
          f"{1000 * np.max(np.abs(1 / theta - mass[k])):.1f} g")
    flagged = [(m["quantity"], flight_of[m["log"]]) for m in res.moved]
    print(f"moved significantly: {', '.join(f'{q} at flight {f}' for q, f in flagged) or 'nothing'} "
          f"(the drag steps up at flight {args.step_at})")
    print(f"summary: {res.summary_csv}\nfigure:  {res.figure}")
    return 0 if flagged == [("phi", args.step_at)] else 1


if __name__ == "__main__":
    sys.exit(main())
