"""The main job end to end: declare WingRock, generate C, compile it, filter
simulated flight data in C and in Python, print the result table, write plots.

    python examples/demo.py --out out/demo        (what `make demo` runs)
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from models import wingrock
from models.wingrock_sim import simulate
from skigen import derive
from skigen.emit.c import emit_c, load_c
from skigen.plots import plot_ard, plot_weights
from skigen.recording import read_recording, write_recording
from skigen.runtime import run

FILTERS = {"aekf": "ekf", "aukf": "ukf", "ski": "ski"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/demo")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    out = Path(args.out)

    model = wingrock.build(prior_variance=wingrock.PRIOR_VARIANCE)
    print(f"1. declared '{model.name}': states {model.state_names}, input {model.input_names}, "
          f"output {model.output_names}, {len(model.weight_names)} candidate terms, dt = {model.dt} s")

    sim = simulate(seed=args.seed)
    data = out / "wingrock_flight.csv"
    write_recording(data, sim.t, {"delta": sim.delta}, {"phi": sim.phi})
    rec = read_recording(data, model.input_names, model.output_names)
    print(f"2. simulated a {sim.t[-1]:.0f} s closed-loop flight (PID, ±5 deg square wave) -> {data}")

    results, rows = {}, []
    for name, kind in FILTERS.items():
        filt = derive(model, kind)
        files = emit_c(filt, out / "c" / kind)
        load_c(filt)                                   # compile (cached by content hash)
        t0 = time.perf_counter()
        c_res = run(filt, rec, backend="c", show_progress=False)
        c_us = 1e6 * (time.perf_counter() - t0) / len(rec.t)
        t0 = time.perf_counter()
        py_res = run(filt, rec, show_progress=False)
        py_us = 1e6 * (time.perf_counter() - t0) / len(rec.t)
        gap = np.max(np.abs(c_res.mean - py_res.mean) / np.maximum(1.0, np.abs(py_res.mean)))
        err = np.linalg.norm(c_res.weights - wingrock.W_TRUE, axis=1)
        results[name] = c_res
        rows.append((name, err.mean(), err[-1], np.nanmean(c_res.nis), gap, c_us, py_us, len(files)))
    print(f"3. generated and compiled C for {', '.join(FILTERS)} in {out / 'c'}; ran C and Python on the flight\n")

    print(f"{'filter':6s} {'mean |w-w*|':>11s} {'final':>6s} {'mean NIS':>8s} {'|C - Py|':>9s} "
          f"{'C us/step*':>10s} {'Py us/step':>10s}")
    for name, mean_err, final_err, nis, gap, c_us, py_us, _ in rows:
        print(f"{name:6s} {mean_err:11.3f} {final_err:6.3f} {nis:8.2f} {gap:9.1e} {c_us:10.1f} {py_us:10.1f}")
    print("* C time includes Python's loop and a ctypes call per step; `skigen bench speed` times the step alone.\n")

    names = model.weight_names
    ski = results["ski"]
    print(f"{'weight':16s} {'truth':>8s} " + " ".join(f"{n:>8s}" for n in FILTERS) + f" {'SKI 2σ':>8s} {'ARD var':>9s}")
    for i, n in enumerate(names):
        print(f"{n:16s} {wingrock.W_TRUE[i]:8.4f} " +
              " ".join(f"{results[m].weights[-1, i]:8.4f}" for m in FILTERS) +
              f" {2 * ski.weight_std[-1, i]:8.4f} {ski.prior_var[-1, i]:9.2e}")

    figs = [plot_weights(out / "weights.png", sim.t, {m: (r.weights, r.weight_std) for m, r in results.items()},
                         names, wingrock.W_TRUE, "WingRock weight estimates from the generated C (±2σ)"),
            plot_ard(out / "ard_variances.png", names, ski.prior_var[-1])]
    print(f"\n4. plots: {', '.join(str(f) for f in figs)}")


if __name__ == "__main__":
    main()
