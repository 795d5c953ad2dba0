"""WingRock identification, the SKI paper's Table 1 protocol.

SINDy (pysindy, derivatives by numerical differentiation of the measured
angle), the augmented EKF, the augmented UKF and SKI on the same simulated
recordings, with identical Q, R, initial values and priors. Mean error = the
time average over the run of ‖ŵ(t) − w*‖, median over noise seeds.
"""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks.common import emit, parser, recording, spread, timed_run
from models import wingrock
from models.wingrock_sim import simulate, square_wave_reference, staircase_reference
from skigen import FilterOptions, derive
from skigen.baselines import sindy_time_history
from skigen.plots import plot_ard, plot_weights

LATE = 5.0   # s: errors after the first two reference steps, once the weights are identifiable
PAPER = {"sindy": 11.45, "aekf": 5.85, "aekf2": float("nan"), "aukf": 0.95, "ski": 0.15}
FILTERS = {"aekf": "ekf", "aekf2": "ekf", "aukf": "ukf", "ski": "ski"}     # aekf2: second-order prediction
REFERENCES = {"square": square_wave_reference, "staircase": staircase_reference}


def settings(ard: str = "em") -> dict:
    m = wingrock.build(prior_variance=wingrock.PRIOR_VARIANCE)
    options = FilterOptions(ard=ard)
    return dict(model=m, options=options, report=dict(
        dt=m.dt, duration_s=15.0, noise_std_deg=wingrock.NOISE_STD, discretization=m.discretization,
        Q_diag=np.diag(m.process_noise()).tolist(), R=m.measurement_noise().ravel().tolist(),
        x0=m.x0, P0_diag=np.diag(m.initial_covariance()).tolist(),
        weight_prior_mean=0.0, weight_prior_variance=m.prior_variances().tolist(),
        prior_rule=f"std_i = {wingrock.PRIOR_ACCEL} deg/s^2 / rms(phi_i), rms = {wingrock.BASIS_RMS.tolist()}",
        filter_options=options.asdict(), sindy="pysindy STLSQ on Savitzky-Golay (SmoothedFiniteDifference) derivatives of phi, "
        "refitted every 1 s on the data so far", weights_true=wingrock.W_TRUE.tolist()))


def main(argv=None) -> int:
    p = parser("wingrock", seeds=20)
    p.add_argument("--reference", choices=REFERENCES, default="square",
                   help="roll reference: the paper's square wave, or a richer staircase")
    args = p.parse_args(argv)
    cfg = settings(args.ard)
    filters = {name: derive(cfg["model"], kind, replace(cfg["options"], second_order=name == "aekf2"))
               for name, kind in FILTERS.items()}
    names = cfg["model"].weight_names
    methods = ["sindy", *FILTERS]
    errors, late, final = ({m: [] for m in methods} for _ in range(3))
    speed = {m: [] for m in FILTERS}
    corr = {m: [] for m in FILTERS}
    for seed in range(args.seeds):
        sim = simulate(seed=seed, reference=REFERENCES[args.reference])
        rec = recording(sim)
        times, W = sindy_time_history(sim.t, sim.delta, sim.phi, gain=wingrock.GAIN)
        estimates = {"sindy": _hold(sim.t, times, W)[0]}
        runs = {}
        for name, filt in filters.items():
            runs[name], us = timed_run(filt, rec)
            estimates[name] = runs[name].weights
            speed[name].append(us)
            corr[name].append(_correlation(runs[name], names.index("w_p"), names.index("w_abs_p_p")))
        for name, est in estimates.items():
            err = np.linalg.norm(est - wingrock.W_TRUE, axis=1)
            errors[name].append(float(err.mean()))
            late[name].append(float(err[sim.t >= LATE].mean()))
            final[name].append(float(err[-1]))
        if seed == 0:
            _figures(Path(args.out), sim, runs, (times, W), names, args.reference)
        print(f"seed {seed}: " + ", ".join(f"{m} {v[-1]:.3f}" for m, v in errors.items()),
              file=sys.stderr)
    report = dict(methods={m: dict(mean_error=spread(v)["median"], spread=spread(v),
                                   mean_error_after_5s=float(np.median(late[m])), final_error=float(np.median(final[m])),
                           **({"us_per_step": float(np.median(speed[m])),
                                       "corr_w_p_w_abs_p_p": float(np.median(corr[m]))} if m in speed else {}))
                           for m, v in errors.items()},
                  settings=dict(cfg["report"], seeds=args.seeds, reference=args.reference))
    return emit(report, args.json, _table(report, args.seeds))


def _correlation(res, i, j):
    P = res.final_cov[np.ix_(res.filter.aug.w_index, res.filter.aug.w_index)]
    return P[i, j] / np.sqrt(P[i, i] * P[j, j])


def _figures(out, sim, runs, sindy, names, reference):
    est = {"sindy": _hold(sim.t, *sindy),
           **{m: (r.weights, r.weight_std) for m, r in runs.items() if m != "aekf2"}}    # the paper's four
    plot_weights(out / f"wingrock_{reference}_weights.png", sim.t, est, names, wingrock.W_TRUE,
                 f"WingRock weight estimates ({reference} reference, seed 0, ±2σ)")
    plot_ard(out / f"wingrock_{reference}_ard.png", names, runs["ski"].prior_var[-1],
             title="WingRock: final ARD prior variances")


def _hold(t, times, W):
    """SINDy's estimate held between refits; before the first fit the prior mean 0."""
    idx = np.searchsorted(times, t, side="right") - 1
    return np.where(idx[:, None] >= 0, W[np.clip(idx, 0, None)], 0.0), None


def _table(report, seeds) -> str:
    rows = [f"WingRock ({report['settings']['reference']} reference): weight error ‖ŵ − w*‖, "
            f"median over {seeds} seeds; Python time per step",
            f"{'method':7s} {'time-avg':>8s} {'[p25, p75]':>13s} {'paper':>6s} {'t>5s':>6s} {'final':>6s} "
            f"{'us/step':>8s} {'corr(w_p,w_|p|p)':>17s}"]
    nan = float("nan")
    for m, r in report["methods"].items():
        s = r["spread"]
        band = f"[{s['p25']:.2f}, {s['p75']:.2f}]"
        rows.append(f"{m:7s} {r['mean_error']:8.3f} {band:>13s} {PAPER[m]:6.2f} "
                    f"{r.get('mean_error_after_5s', nan):6.3f} {r.get('final_error', nan):6.3f} "
                    f"{r.get('us_per_step', nan):8.1f} {r.get('corr_w_p_w_abs_p_p', nan):17.2f}")
    return "\n".join(rows)


if __name__ == "__main__":
    sys.exit(main())
