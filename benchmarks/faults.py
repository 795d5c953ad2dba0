"""Fault injection on the WingRock filters: recovery after absurd readings, dropouts, a stuck
sensor and non-finite inputs (the policy of skigen/guard.py).

    skigen bench faults [--steps 1000000] [--filter ski] [--real double|float] [--backend c|python]

Per fault type one simulated closed-loop flight of ``--steps`` samples, the faults of that type
injected one after the other (each size in turn, FAULT_SPACING samples apart), the generated C
stepping through it (``--backend python``: the Python runner). A fault has recovered when, from
RECOVERY samples after its end until the next fault, the roll angle and rate are within their
normal error: the largest error of the same filter on the same flight without faults (after
CONVERGED samples), times NORMAL_MARGIN. The table gives, per type, the faults, the worst
recovery, the step codes and the weights' final error beside the fault-free run's.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FAULTS = {                      # type: sizes (sigma of the reading noise, or samples)
    "absurd": (1e3, 1e4, 1e5, 1e6),
    "dropout": (100, 1000, 10000),
    "stuck": (200, 1000, 3000),
    "nonfinite": (1, 100, 1000),
}
ABSURD_BURST = (1, 3, 10)       # consecutive absurd readings, in turn
FAULT_SPACING = 4000            # samples from the end of a fault to the start of the next
RECOVERY = 500                  # samples after a fault's end by which the estimate must be back
CONVERGED = 2000                # samples before the fault-free errors count as normal
NORMAL_MARGIN = 1.5


@dataclass
class Fault:
    kind: str
    size: float
    start: int
    end: int                    # first sample after the fault


def schedule(kind: str, n: int, first: int = CONVERGED) -> list[Fault]:
    """The faults of ``kind`` in a flight of n samples: each size in turn, FAULT_SPACING apart."""
    out, k, i = [], first, 0
    while True:
        size = FAULTS[kind][i % len(FAULTS[kind])]
        length = ABSURD_BURST[(i // len(FAULTS[kind])) % len(ABSURD_BURST)] if kind == "absurd" else int(size)
        if k + length + FAULT_SPACING > n:
            return out
        out.append(Fault(kind, size, k, k + length))
        k, i = k + length + FAULT_SPACING, i + 1


def inject(u, y, faults, noise_std: float):
    """Copies of the inputs u (N×nu) and readings y (N×ny) with the faults in them."""
    u, y = np.array(u, float), np.array(y, float)
    for j, f in enumerate(faults):
        span = slice(f.start, f.end)
        if f.kind == "absurd":
            y[span] = (-1) ** j * f.size * noise_std
        elif f.kind == "dropout":
            y[span] = np.nan
        elif f.kind == "stuck":
            y[span] = y[f.start - 1]
        elif f.kind == "nonfinite":          # NaN, +inf, -inf inputs in turn, and inf readings
            u[span] = (np.nan, np.inf, -np.inf)[j % 3]
            y[f.start:f.start + max(1, (f.end - f.start) // 2)] = np.inf
    return u, y


def normal_error(err, start: int = CONVERGED) -> np.ndarray:
    """The normal error bound per state: NORMAL_MARGIN times the largest fault-free error."""
    return NORMAL_MARGIN * np.nanmax(np.abs(err[start:]), axis=0)


def recovery(err, faults, bound) -> list[int | None]:
    """Per fault: samples after its end from which every state's |error| stays within ``bound``
    until the next fault (None: never, or not before RECOVERY samples ran out)."""
    out = []
    for f, nxt in zip(faults, faults[1:] + [None]):
        stop = nxt.start if nxt else len(err)
        bad = np.flatnonzero(~np.all(np.abs(err[f.end:stop]) <= bound, axis=1))
        k = 0 if bad.size == 0 else bad[-1] + 1
        out.append(k if k < stop - f.end else None)
    return out


def flight(steps: int, seed: int = 0):
    """A closed-loop WingRock flight of ``steps`` samples (square-wave reference)."""
    from models.wingrock_sim import simulate
    return simulate(seed=seed, duration=(steps - 1) * 0.02)


def run_filter(filt, u, y, backend: str = "c", real: str = "double", cache_dir=None) -> dict:
    """Posterior means and step codes over (u, y) with the default recovery policy."""
    if backend == "c":
        from skigen.emit.c import load_c
        out = load_c(filt, real, cache_dir=cache_dir).run_many(u, y)
        return dict(z=out["z_post"].astype(float), code=out["code"])
    from skigen.runtime import PythonStepper
    st, z, code = PythonStepper(filt), np.empty((len(u), filt.aug.n)), np.empty(len(u), int)
    for k in range(len(u)):
        code[k] = st.step(u[k], y[k])
        z[k] = st.z_post
    return dict(z=z, code=code)


def evaluate(sim, faults, faulty: dict, clean: dict) -> dict:
    """The recovery, codes and weight errors of a faulty run against the fault-free one."""
    from skigen.emit.c import Status
    truth = np.column_stack([sim.theta, sim.p])
    err, err0 = faulty["z"][:, :2] - truth, clean["z"][:, :2] - truth
    rec = recovery(err, faults, normal_error(err0))
    w_err = lambda z: float(np.abs(z[-1, 2:] - sim.weights).max())
    codes = np.bincount(faulty["code"], minlength=len(Status))
    return dict(faults=len(faults), recovered=sum(r is not None for r in rec),
                worst=max((r for r in rec if r is not None), default=None),
                nan=int(np.sum(~np.isfinite(faulty["z"]))), codes={s.name: int(codes[s]) for s in Status},
                weights_error=w_err(faulty["z"]), weights_error_clean=w_err(clean["z"]), recovery=rec)


def main(argv=None) -> int:
    import argparse
    import time

    from benchmarks.common import emit
    from models.wingrock import NOISE_STD, build
    from skigen import derive

    p = argparse.ArgumentParser(prog="skigen bench faults")
    p.add_argument("--steps", type=int, default=1_000_000, help="samples per fault type")
    p.add_argument("--filter", default="ski", choices=("ekf", "ukf", "ski"))
    p.add_argument("--real", default="double", choices=("double", "float"))
    p.add_argument("--backend", default="c", choices=("c", "python"))
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    filt = derive(build(), args.filter)
    t0 = time.perf_counter()
    sim = flight(args.steps)
    u, y = sim.delta[:, None], sim.phi[:, None]
    clean = run_filter(filt, u, y, args.backend, args.real)
    report = {}
    for kind in FAULTS:
        faults = schedule(kind, args.steps)
        fu, fy = inject(u, y, faults, NOISE_STD)
        report[kind] = evaluate(sim, faults, run_filter(filt, fu, fy, args.backend, args.real), clean)
    short = dict(OUTLIER_REJECTED="gated", SENSOR_STUCK="stuck", REINITIALISED="restart",
                 MEASUREMENT_SKIPPED="skipped", BAD_INPUT="bad_input", NUMERICAL_FAILURE="failed")
    rows = ["| fault (sizes) | faults | recovered within 500 | worst recovery (samples) | NaN | codes | "
            "weights max error (fault-free) |", "|---|---|---|---|---|---|---|"]
    for kind, r in report.items():
        sizes = ", ".join(f"{s:g}" for s in FAULTS[kind]) + (" σ" if kind == "absurd" else " samples")
        codes = ", ".join(f"{short[k]} {v}" for k, v in r["codes"].items() if v and k in short)
        rows.append(f"| {kind} ({sizes}) | {r['faults']} | {r['recovered']} | {r['worst']} | {r['nan']} | "
                    f"{codes} | {r['weights_error']:.3g} ({r['weights_error_clean']:.3g}) |")
    for r in report.values():
        r.pop("recovery")
    head = (f"WingRock {args.filter} ({args.backend}, {args.real}), {args.steps} steps per fault type, "
            f"{time.perf_counter() - t0:.0f} s")
    return emit(dict(filter=args.filter, real=args.real, backend=args.backend, steps=args.steps, faults=report),
                args.json, head + "\n" + "\n".join(rows))


if __name__ == "__main__":
    raise SystemExit(main())
