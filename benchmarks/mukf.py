"""Marginalised UKF (MUKF) against the full UKF: the LowLevelParticleFilters
tutorial's quadrotor (unknown, time-varying mass and drag), and SKI on the
MUKF core against SKI on the full UKF (WingRock and the delay model).

Quadrotor (models/quadrotor_mukf.py): truth = RK4 with mass 1 → 0.85 kg and
C_d 0.01 → 0.015 at 25 s, hover thrust + N(0, 0.1²), measurement noise 0.01,
50 s at 50 Hz; the tutorial's R1, R2, initial guess and P0 for every filter.
RMSE of m = 1/θ̂ and C_d = φ̂/θ̂ from sample 500 on (Julia's 1-based
``transient:end`` with transient = 500, i.e. 0-based index 499), median over
seeds. Filters: the full UKF on the RK4 model (the tutorial's), the MUKF on the
Euler model (the tutorial's; RK4 breaks the conditional linearity of θ and φ),
the MUKF on the "exact_position" model (Euler velocity, position integrated
exactly for the acceleration held over the sample — still conditionally
linear), and the full UKF on the Euler model (same model as the MUKF).

SKI cores (``ski_core_comparison``): WingRock (paper protocol, square-wave
reference, the prior of benchmarks/wingrock.py) and the delay model, truth RK4.
The MUKF needs the weights to stay affine after discretisation, which RK4
breaks; so both cores run on the Euler model and on "affine2" (RK4 for the
known dynamics, the unknown term integrated exactly with its basis frozen at
the known-dynamics midpoint — still affine in the weights). SKI on the RK4
model (full UKF only) is the reference row.

C time per step: the generated C (double, -O2) timed by the C loop of
``benchmarks.speed.build_c_bench``;
the fastest of 7 runs, the filters of a table taking turns (the machine is shared).
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np

from benchmarks import speed
from benchmarks.common import emit, parser, recording, spread
from models import quadrotor_mukf as quad
from models import wingrock, wingrock_delay
from models.wingrock_sim import L_TRUE, simulate as simulate_wingrock
from skigen import FilterOptions, Model, derive
from skigen.discretize import rk4
from skigen.library import abs_products, delayed_inputs, polynomial, term
from skigen.runtime import run

TRANSIENT = 499                  # 0-based first sample of the RMSE (the tutorial's sample 500)
TUTORIAL = {"mass_rmse": 0.0044, "drag_rmse": 0.000214}
QUAD_FILTERS = {                 # row: (discretisation, kind)
    "ukf": ("rk4", "ukf"),
    "mukf": ("euler", "mukf"),
    "mukf_exact_position": ("exact_position", "mukf"),
    "ukf_euler": ("euler", "ukf"),
}
OPTIONS = FilterOptions()
LATE = 5.0
ROUNDS = 7                       # C timing: fastest of this many interleaved runs


def _points(filt) -> int:
    return filt.partition.sigma_points if filt.partition is not None else 2 * filt.aug.n + 1


def _rmse(a, b) -> float:
    return float(np.sqrt(np.mean((a[TRANSIENT:] - b[TRANSIENT:]) ** 2)))


def quadrotor(seeds: int, work: Path, out: Path) -> dict:
    filters = {row: derive(quad.build(disc), kind, OPTIONS) for row, (disc, kind) in QUAD_FILTERS.items()}
    err = {row: {"mass": [], "drag": []} for row in filters}
    for seed in range(seeds):
        sim = quad.simulate(seed=seed)
        rec = sim.recording()
        est = {}
        for row, filt in filters.items():
            res = run(filt, rec, show_progress=False)
            theta, phi = res.mean[:, 6], res.mean[:, 7]
            est[row] = (1 / theta, phi / theta)
            err[row]["mass"].append(_rmse(est[row][0], sim.mass))
            err[row]["drag"].append(_rmse(est[row][1], sim.cd))
        if seed == 0:
            _figure(out / "mukf_quadrotor.png", sim, est)
        print(f"quadrotor seed {seed} done", file=sys.stderr)
    rec0 = quad.simulate(seed=0).recording()
    ns = speed.fastest_ns_per_step({row: speed.build_c_bench(f, rec0, "double", work) for row, f in filters.items()}, ROUNDS)
    report = {}
    for row, filt in filters.items():
        disc, kind = QUAD_FILTERS[row]
        report[row] = dict(mass_rmse=float(np.median(err[row]["mass"])), drag_rmse=float(np.median(err[row]["drag"])),
                           mass_rmse_spread=spread(err[row]["mass"]), drag_rmse_spread=spread(err[row]["drag"]),
                           sigma_points=_points(filt), c_ns_per_step=ns[row],
                           operations=filt.step.n_instructions(), kind=kind, discretization=disc,
                           linear_substate=filt.partition.linear_names if filt.partition else None)
    return report


def _figure(path: Path, sim, est):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    styles = {"ukf": ("tab:green", ":"), "mukf": ("tab:blue", "-"), "mukf_exact_position": ("tab:purple", "-."),
              "ukf_euler": ("tab:orange", "--")}
    for ax, i, truth, label in [(axes[0], 0, sim.mass, "mass (kg)"), (axes[1], 1, sim.cd, "C_d (kg/m)")]:
        ax.plot(sim.t, truth, "k--", lw=2, label="truth")
        for row, e in est.items():
            c, ls = styles.get(row, (None, "-"))
            ax.plot(sim.t, e[i], color=c, ls=ls, lw=1.4, alpha=0.8, label=row)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_ylim(0.8, 1.05)
    axes[1].set_ylim(0.005, 0.02)
    axes[0].legend(fontsize=8, ncol=3)
    axes[1].set_xlabel("time (s)")
    axes[0].set_title("Quadrotor mass and drag (seed 0): MUKF (7 points, Euler) vs UKF (17 points, RK4)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- SKI core comparison

def _euler(model, name):
    model.discretization, model.name = "euler", name
    return model


def _affine2(name, basis_fn, prior_variance, known=None):
    """WingRock-type model (θ̇ = p, ṗ = a) discretised to keep the weights affine given (θ, p),
    more accurately than Euler: the known dynamics by RK4, the unknown term Σ w_i φ_i integrated
    exactly (θ gets Ts²/2, p gets Ts) with its basis frozen at the midpoint of the known-dynamics
    step (a RK4 half step) — the tutorial's "treat A_n z_l as an input to an accurate integrator".
    Each basis term enters both equations with one shared weight (a direction)."""
    dt = wingrock.DT
    m = Model(name, dt=dt, discretization="discrete")
    theta = m.state("theta", unit="deg", role="angle", std=1.0, process_std=1e-4)
    p = m.state("p", unit="deg/s", role="rate", std=1.0, process_std=1e-3)
    delta = m.input("delta", unit="deg")
    x = ca.vertcat(theta, p)
    rhs = ca.vertcat(p, known(theta, p) if known else wingrock.GAIN * delta)
    f0 = lambda xi: ca.substitute(rhs, x, xi)
    x_next, x_mid = rk4(f0, x, dt), rk4(f0, x, dt / 2)
    m.dynamics({theta: x_next[0], p: x_next[1]})
    m.output("phi", theta, unit="deg", noise_std=wingrock.NOISE_STD)
    gain = ca.vertcat(dt ** 2 / 2, dt)
    m.unknown([theta, p], [term(t.name, gain * ca.substitute(t.expr, x, x_mid), key=t.key)
                           for t in basis_fn(m, theta, p, delta)], prior_variance=prior_variance)
    return m


def _wingrock_basis(m, theta, p, delta):
    return (polynomial([theta, p], 1) + abs_products([(theta, p), (p, p)])
            + [term("theta^3", theta ** 3, key="theta3")])


def _delay_basis(m, theta, p, delta):
    return delayed_inputs(m, delta, wingrock_delay.WINDOW)


def _delay_known(theta, p):
    """The known WingRock term of the delay model (Δ* with the true weights)."""
    return sum(w * b for w, b in zip(wingrock.W_TRUE, [1, theta, p, ca.fabs(theta) * p, ca.fabs(p) * p, theta ** 3]))


def ski_cores(seeds: int, work: Path) -> dict:
    """SKI with the full UKF core vs the MUKF core, WingRock and delay models, per discretisation."""
    wr_prior = wingrock.PRIOR_VARIANCE
    models = {
        "wingrock": {"rk4": wingrock.build(prior_variance=wr_prior),
                     "euler": _euler(wingrock.build(prior_variance=wr_prior), "wingrock_euler"),
                     "affine2": _affine2("wingrock_affine2", _wingrock_basis, wr_prior)},
        "delay": {"rk4": wingrock_delay.build(prior_variance=1.0),
                  "euler": _euler(wingrock_delay.build(prior_variance=1.0), "wingrock_delay_euler"),
                  "affine2": _affine2("wingrock_delay_affine2", _delay_basis, 1.0, known=_delay_known)}}
    out = {}
    for label, variants in models.items():
        filters = {"ski_rk4": derive(variants["rk4"], "ski", OPTIONS)}
        for disc in ("euler", "affine2"):
            filters[f"ski_{disc}"] = derive(variants[disc], "ski", OPTIONS)
            filters[f"ski_mukf_{disc}"] = derive(variants[disc], "ski_mukf", OPTIONS)
        stats = {m: {"a": [], "b": [], "c": []} for m in filters}
        delay = wingrock_delay.TRUE_DELAY if label == "delay" else 0
        for seed in range(seeds):
            sim = simulate_wingrock(seed=seed, delay=delay)
            rec = recording(sim)
            runs = {m: run(f, rec, show_progress=False) for m, f in filters.items()}
            for m, res in runs.items():
                if label == "wingrock":
                    e = np.linalg.norm(res.weights - wingrock.W_TRUE, axis=1)
                    stats[m]["a"].append(float(e.mean()))
                    stats[m]["b"].append(float(e[sim.t >= LATE].mean()))
                    stats[m]["c"].append(float(e[-1]))
                else:
                    stats[m]["a"].append(abs(res.weights[-1, delay] - L_TRUE) / L_TRUE)
                    stats[m]["b"].append(int(np.argmax(res.prior_var[-1])) == delay)
        rec0 = recording(simulate_wingrock(seed=0, delay=delay))
        ns = speed.fastest_ns_per_step({m: speed.build_c_bench(f, rec0, "double", work) for m, f in filters.items()}, ROUNDS)
        rows = {}
        for m, f in filters.items():
            r = dict(kind=f.kind, discretization=m.split("_")[-1], sigma_points=_points(f),
                     operations=f.step.n_instructions(), c_ns_per_step=ns[m])
            if label == "wingrock":
                r.update(mean_error=float(np.median(stats[m]["a"])), mean_error_after_5s=float(np.median(stats[m]["b"])),
                         final_error=float(np.median(stats[m]["c"])))
            else:
                r.update(gain_relative_error=float(np.median(stats[m]["a"])),
                         delay_correct_fraction=float(np.mean(stats[m]["b"])))
            rows[m] = r
        out[label] = rows
        print(f"{label} done", file=sys.stderr)
    return out


def main(argv=None) -> int:
    args = parser("mukf", seeds=5).parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        report = quadrotor(args.seeds, work, Path(args.out))
        report["ski_core_comparison"] = ski_cores(args.seeds, work)
    report["settings"] = dict(seeds=args.seeds, rmse_from_sample=TRANSIENT, tutorial=TUTORIAL,
                              filter_options=OPTIONS.asdict(), quadrotor_dt=quad.DT, duration_s=quad.DURATION,
                              R1_diag=[0.01] * 6 + [1e-4, 1e-6], R2_diag=[0.1] * 3 + [0.05] * 3,
                              x0=[0, 0, 0, 0, 0, 10, 1 / quad.M_GUESS, quad.CD_GUESS / quad.M_GUESS],
                              P0_diag=[0.5] * 3 + [1.0] * 3 + [0.01, 1e-4])
    return emit(report, args.json, _table(report))


def _table(r) -> str:
    rows = [f"Quadrotor, unknown mass and drag (tutorial: RMSE mass {TUTORIAL['mass_rmse']} kg, "
            f"drag {TUTORIAL['drag_rmse']} for both), median over {r['settings']['seeds']} seeds, RMSE from sample 500",
            f"{'filter':20s} {'model':>15s} {'points':>6s} {'mass RMSE':>10s} {'drag RMSE':>10s} {'C ns/step':>10s} {'ops':>7s}"]
    for row in QUAD_FILTERS:
        q = r[row]
        rows.append(f"{row:20s} {q['discretization']:>15s} {q['sigma_points']:6d} {q['mass_rmse']:10.4f} "
                    f"{q['drag_rmse']:10.6f} {q['c_ns_per_step']:10.0f} {q['operations']:7d}")
    c = r["ski_core_comparison"]
    w = c["wingrock"]
    rows += ["", "SKI core: full UKF (ski_*) vs MUKF (ski_mukf_*) per discretisation, WingRock (truth RK4), "
             "weight error ‖ŵ − w*‖ (median over seeds)",
             f"{'filter':18s} {'points':>6s} {'time-avg':>9s} {'t>5s':>7s} {'final':>7s} {'C ns/step':>10s} {'ops':>7s}"]
    rows += [f"{m:18s} {q['sigma_points']:6d} {q['mean_error']:9.3f} {q['mean_error_after_5s']:7.3f} "
             f"{q['final_error']:7.3f} {q['c_ns_per_step']:10.0f} {q['operations']:7d}" for m, q in w.items()]
    d = c["delay"]
    rows += ["", "SKI core on the delay model (m = 8): gain relative error, delay named by the largest ARD variance",
             f"{'filter':18s} {'points':>6s} {'gain err':>9s} {'delay ok':>9s} {'C ns/step':>10s} {'ops':>7s}"]
    rows += [f"{m:18s} {q['sigma_points']:6d} {q['gain_relative_error']:9.3f} {q['delay_correct_fraction']:9.0%} "
             f"{q['c_ns_per_step']:10.0f} {q['operations']:7d}" for m, q in d.items()]
    return "\n".join(rows)


if __name__ == "__main__":
    sys.exit(main())
