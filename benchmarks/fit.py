"""Time of the Silverbox grey-box fit (65 062 samples, output error) beside a peer:
SciPy's least_squares (trust-region reflective, finite-difference Jacobian) on
the same simulation (skigen's free run, a CasADi mapaccum) from the same start.

    skigen bench fit [--json] [--data DIR] [--peer-evaluations N]

Both fit the Duffing grey box of models/silverbox_greybox.py (first-order
hold) on the standard training range; the table gives wall time, iterations
(simulations for the peer) and training RMSE. Needs ../shared/data.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from benchmarks.common import emit, parser
from models import silverbox_greybox as G
from skigen.fit import fit
from skigen.recording import read_recording
from skigen.simulate import free_run


def peer(model, rec, start: dict, max_nfev: int):
    """least_squares over (parameters, y0, v0) with the simulation as the residual."""
    names = model.parameter_names
    x0 = np.r_[[start[n] for n in names], 0.0, 0.0]
    scale = np.r_[[abs(start[n]) or 1.0 for n in names], 0.05, 50.0]
    scale[names.index("k3")] = 1e5

    def residual(z):
        model.set_parameters(dict(zip(names, z[:len(names)])))
        return free_run(model, rec.inputs, x0=z[len(names):])[1][:, 0] - rec.outputs[:, 0]

    t0 = time.perf_counter()
    sol = least_squares(residual, x0, x_scale=scale, max_nfev=max_nfev)   # nfev excludes the Jacobian's
    seconds = time.perf_counter() - t0
    model.set_parameters(start)
    return seconds, sol.nfev + sol.njev * len(x0), float(np.sqrt(np.mean(sol.fun ** 2)))


def main(argv=None) -> int:
    p = parser("fit", seeds=1)
    p.add_argument("--data", default=str(Path.cwd().parent / "shared" / "data"))
    p.add_argument("--peer-evaluations", type=int, default=200, help="simulations allowed to the peer (200)")
    args = p.parse_args(argv)
    path = Path(args.data) / "silverbox_snls80mv.csv"
    if not path.is_file():
        print(f"skigen bench fit: {path} not found (pass --data DIR with the Silverbox recordings)", file=sys.stderr)
        return 2
    train = read_recording(path, ["V1"], ["V2"]).slice(*G.TRAIN)
    model = G.build()
    start = {q.name: q.value for q in model.parameters}
    t0 = time.perf_counter()
    r = fit(model, [train], show_progress=False)
    ours = dict(seconds=time.perf_counter() - t0, iterations=r.iterations, rmse_mV=1e3 * r.recordings[0]["rmse"]["V2"],
                k3=r.parameters["k3"]["value"])
    s, nfev, rmse = peer(G.build(), train, start, args.peer_evaluations)
    theirs = dict(seconds=s, simulations=nfev, rmse_mV=1e3 * rmse)
    report = dict(samples=len(train.t), skigen=ours, scipy_least_squares=theirs)
    table = "\n".join([
        f"Silverbox Duffing grey box, output error, {len(train.t)} samples, this machine",
        f"{'method':34s} {'seconds':>8s} {'work':>16s} {'RMSE mV':>8s}",
        f"{'skigen fit (CasADi + IPOPT)':34s} {ours['seconds']:8.1f} {ours['iterations']:>6d} iterations {ours['rmse_mV']:8.3f}",
        f"{'scipy least_squares (FD Jacobian)':34s} {s:8.1f} {nfev:>5d} simulations {1e3 * rmse:8.3f}"])
    return emit(report, args.json, table)


if __name__ == "__main__":
    sys.exit(main())
