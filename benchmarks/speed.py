"""Time per filter step: generated C (double, float), the Python callables,
and filterpy's UKF on the same augmented WingRock model, plus how the C SKI
step scales with the number of basis functions m (delayed-input windows), for
both kernel styles (unrolled, loops) and the one ``skigen generate`` picks.

C is timed by a small C program (the filter's own sources, -O2) that replays a
simulated flight many times; no Python is in the loop.
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.common import emit, parser, recording
from models import wingrock, wingrock_delay
from models.wingrock_sim import simulate
from skigen import derive
from skigen.emit.c import DEFAULT_FLAGS, choose_style, default_prefix, emit_c
from skigen.reference.wingrock import wingrock_f
from skigen.runtime import run

KINDS = ("ekf", "ukf", "ski")
SCALING_M = (6, 12, 24, 48)
LARGEST_UNROLLED = 24  # unrolled, m = 48 is ~3 M operations, ~69 MB of C: gcc takes >20 min and ~8 GB

HARNESS = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <time.h>
#include "%(prefix)s.h"
static const %(real)s U[%(n)d * %(nu)d] = {%(u)s};
static const %(real)s Y[%(n)d * %(ny)d] = {%(y)s};
int main(void) {
    static %(prefix)s_state st;
    struct timespec a, b;
    long reps = 1, k, r;
    double ns = 0;
    volatile %(real)s sink = 0;
    for (;;) {                                   /* grow until a run takes 0.2 s */
        clock_gettime(CLOCK_MONOTONIC, &a);
        for (r = 0; r < reps; ++r) {
            %(prefix)s_init(&st);
            for (k = 0; k < %(n)d; ++k) %(prefix)s_step(&st, &U[k * %(nu)d], &Y[k * %(ny)d]);
            sink += st.z_post[0];
        }
        clock_gettime(CLOCK_MONOTONIC, &b);
        ns = (b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec);
        if (ns > 2e8) break;
        reps *= 2;
    }
    printf("%%.3f\n", ns / ((double)reps * %(n)d));
    return sink != sink;
}
"""


def build_c_bench(filt, rec, real: str, work: Path, opt: str = "-O2", style: str = "auto") -> Path:
    """Compile the timing program of the generated C; it prints ns per step."""
    prefix = default_prefix(filt)
    out = work / f"{prefix}_{real}_{style}"
    files = emit_c(filt, out, real=real, style=style)
    fmt = lambda a: ", ".join(f"{v:.17g}" for v in np.ravel(a))
    (out / "bench.c").write_text(HARNESS % dict(prefix=prefix, real=real, n=len(rec.t), nu=rec.inputs.shape[1],
                                                ny=rec.outputs.shape[1], u=fmt(rec.inputs), y=fmt(rec.outputs)))
    exe = out / "bench"
    sources = [str(f) for f in files if f.suffix == ".c"] + [str(out / "bench.c")]
    flags = [f if not f.startswith("-O") else opt for f in DEFAULT_FLAGS]
    subprocess.run(["gcc", *flags, "-I", str(out), *sources, "-o", str(exe), "-lm"], check=True)
    return exe


def fastest_ns_per_step(programs: dict, rounds: int = 1) -> dict:
    """ns per step of each timing program: the fastest of ``rounds`` runs, the programs
    taking turns so that all see the same load of a shared machine."""
    best = {k: float("inf") for k in programs}
    for _ in range(rounds):
        for k, exe in programs.items():
            best[k] = min(best[k], float(subprocess.run([str(exe)], capture_output=True, text=True,
                                                        check=True).stdout))
    return best


def c_ns_per_step(filt, rec, real: str, work: Path, opt: str = "-O2", style: str = "auto",
                  rounds: int = 3) -> float:
    """Nanoseconds per step of the generated C, timed in C (the fastest of ``rounds`` runs)."""
    return fastest_ns_per_step({0: build_c_bench(filt, rec, real, work, opt, style)}, rounds)[0]


def python_us_per_step(filt, rec) -> float:
    t0 = time.perf_counter()
    run(filt, rec, show_progress=False)
    return 1e6 * (time.perf_counter() - t0) / len(rec.t)


def filterpy_us_per_step(aug, rec) -> float:
    """filterpy's UKF (Merwe points, same α, β, κ) on the augmented WingRock model in NumPy."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    ukf = UnscentedKalmanFilter(dim_x=aug.n, dim_z=1, dt=aug.model.dt, hx=lambda z: z[:1],
                                fx=lambda z, dt, delta: wingrock_f(z, delta),
                                points=MerweScaledSigmaPoints(aug.n, alpha=1.0, beta=2.0, kappa=0.0))
    ukf.x, ukf.P, ukf.Q, ukf.R = aug.z0.copy(), aug.P0.copy(), aug.Q.copy(), aug.R.copy()
    t0 = time.perf_counter()
    for u, y in zip(rec.inputs[:, 0], rec.outputs[:, 0]):
        ukf.update(np.array([y]))
        ukf.predict(delta=u)
    return 1e6 * (time.perf_counter() - t0) / len(rec.t)


def _scaling_row(m: int, rec, work: Path, largest_unrolled: int) -> dict:
    """C SKI ns/step for m delayed-input windows: both styles where built, and the default."""
    filt = derive(wingrock_delay.build(window=m, name=f"wingrock_delay{m}"), "ski")
    row = {"m": m, "n": filt.aug.n, "style": choose_style(filt), "unrolled_ns_per_step": None,
           "unrolled_operations": filt.step.n_instructions()}
    programs = {"loops": build_c_bench(filt, rec, "double", work, style="loops")}
    if m <= largest_unrolled:
        opt = "-O2" if m <= LARGEST_UNROLLED else "-O1"       # -O2 on millions of lines: hours
        programs["unrolled"] = build_c_bench(filt, rec, "double", work, opt, style="unrolled")
    row.update({f"{k}_ns_per_step": v for k, v in fastest_ns_per_step(programs, rounds=3).items()})
    row.update({f"{k}_c_bytes": sum(f.stat().st_size for f in exe.parent.glob(f"{default_prefix(filt)}*.[ch]"))
                for k, exe in programs.items()})
    if m > largest_unrolled:
        row["unrolled_not_built"] = (f"{row['unrolled_operations']} operations; "
                                     f"rerun with --largest-unrolled {m} to compile it")
    row["c_ns_per_step"] = row[f"{row['style']}_ns_per_step"]
    return row


def _scaling_figure(path: Path, scaling: list[dict]) -> Path:
    """ns per step and C source size of both kernel styles against the augmented-state size."""
    import matplotlib.pyplot as plt
    from skigen.plots import save_figure

    fig, (time_ax, size_ax) = plt.subplots(1, 2, figsize=(10, 3.8))
    for style, color in (("unrolled", "tab:orange"), ("loops", "tab:blue")):
        rows = [r for r in scaling if r.get(f"{style}_ns_per_step")]
        n = [r["n"] for r in rows]
        time_ax.loglog(n, [r[f"{style}_ns_per_step"] / 1e3 for r in rows], "o-", color=color, label=style)
        size_ax.loglog(n, [r[f"{style}_c_bytes"] / 1e3 for r in rows], "o-", color=color, label=style)
    for ax, label in ((time_ax, "C SKI step, µs (double, -O2)"), (size_ax, "C sources, kB")):
        ax.set_xticks([r["n"] for r in scaling], [str(r["n"]) for r in scaling])
        ax.minorticks_off()
        ax.set_xlabel("augmented state n (= m + 2)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    unbuilt = [r["n"] for r in scaling if not r.get("unrolled_ns_per_step")]
    if unbuilt:
        time_ax.set_title(f"unrolled not built at n = {', '.join(map(str, unbuilt))}", fontsize=9)
    return save_figure(fig, path)


def main(argv=None) -> int:
    p = parser("speed", seeds=1)
    p.add_argument("--largest-unrolled", type=int, default=LARGEST_UNROLLED,
                   help=f"largest m whose unrolled C is compiled ({LARGEST_UNROLLED}; m = 48 takes gcc "
                        "well over 20 minutes and ~8 GB)")
    args = p.parse_args(argv)
    rec = recording(simulate(seed=0))
    delay_rec = recording(simulate(seed=0, delay=wingrock_delay.TRUE_DELAY))
    model = wingrock.model
    filters = {k: derive(model, k) for k in KINDS}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        report = {"wingrock": {
            "c_double_ns_per_step": {k: c_ns_per_step(f, rec, "double", work) for k, f in filters.items()},
            "c_float_ns_per_step": {k: c_ns_per_step(f, rec, "float", work) for k, f in filters.items()},
            "c_double_loops_ns_per_step": {k: c_ns_per_step(filters[k], rec, "double", work, style="loops")
                                           for k in ("ukf", "ski")},
            "python_us_per_step": {k: python_us_per_step(f, rec) for k, f in filters.items()},
            "filterpy_ukf_us_per_step": filterpy_us_per_step(filters["ukf"].aug, rec)}}
        scaling = []
        for m in SCALING_M:
            scaling.append(_scaling_row(m, delay_rec, work, args.largest_unrolled))
            print(f"scaling m = {m} done", file=sys.stderr)
        report["scaling"] = scaling
    print(f"figure: {_scaling_figure(Path(args.out) / 'speed_scaling.png', scaling)}", file=sys.stderr)
    w = report["wingrock"]
    report["wingrock"]["c_ukf_speedup_over_filterpy"] = 1e3 * w["filterpy_ukf_us_per_step"] / w["c_double_ns_per_step"]["ukf"]
    loops = w["c_double_loops_ns_per_step"]
    rows = ["WingRock time per step (augmented state n = 8; C -O2 on this machine)",
            f"{'filter':6s} {'C double ns':>12s} {'C float ns':>11s} {'C loops ns':>11s} {'Python us':>10s}"]
    rows += [f"{k:6s} {w['c_double_ns_per_step'][k]:12.0f} {w['c_float_ns_per_step'][k]:11.0f} "
             f"{loops.get(k, float('nan')):11.0f} {w['python_us_per_step'][k]:10.1f}" for k in KINDS]
    rows += [f"filterpy UKF (NumPy): {w['filterpy_ukf_us_per_step']:.1f} us/step; "
             f"generated C UKF is {w['c_ukf_speedup_over_filterpy']:.0f}x faster",
             "", "C SKI step (double) vs number of basis functions m (delayed-input windows)",
             f"{'m':>4s} {'n':>4s} {'default ns':>11s} {'style':>9s} {'unrolled ns':>12s} {'loops ns':>10s} "
             f"{'unrolled ops':>13s}"]
    nan = float("nan")
    rows += [f"{s['m']:4d} {s['n']:4d} {s['c_ns_per_step']:11.0f} {s['style']:>9s} "
             f"{s['unrolled_ns_per_step'] or nan:12.0f} {s['loops_ns_per_step']:10.0f} {s['unrolled_operations']:13d}"
             for s in scaling]
    return emit(report, args.json, "\n".join(rows))


if __name__ == "__main__":
    sys.exit(main())
