"""Input-delay identification (the SKI paper's Figs. 5–6).

The aileron gain is unknown and may act through any of the last 8 inputs;
the true plant applies δ[k−6] with gain 3. SKI names the delay by its largest
ARD prior variance; the gain error is |ŵ_6 − 3| / 3 at the end of the run.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from benchmarks.common import emit, parser, recording, spread, timed_run
from models import wingrock_delay
from models.wingrock_sim import L_TRUE, simulate
from skigen import FilterOptions, derive
from skigen.plots import plot_ard, plot_weights

PAPER = {"ski": 0.03, "aukf": 0.41}
PRIOR_VARIANCE = 1.0


def main(argv=None) -> int:
    p = parser("delay", seeds=20)
    p.add_argument("--prior-variance", type=float, default=PRIOR_VARIANCE, help="declared prior variance of every weight")
    args = p.parse_args(argv)
    options = FilterOptions(ard=args.ard)
    model = wingrock_delay.build(prior_variance=args.prior_variance)
    filters = {"ski": derive(model, "ski", options), "aukf": derive(model, "ukf", options)}
    d = wingrock_delay.TRUE_DELAY
    truth = np.eye(wingrock_delay.WINDOW)[d] * L_TRUE
    gain_err = {m: [] for m in filters}
    named = {m: [] for m in filters}
    others = []          # SKI: the largest other ARD variance relative to the true delay's
    for seed in range(args.seeds):
        sim = simulate(seed=seed, delay=d)
        runs = {m: timed_run(f, recording(sim))[0] for m, f in filters.items()}
        for m, res in runs.items():
            gain_err[m].append(abs(res.weights[-1, d] - L_TRUE) / L_TRUE)
            score = res.prior_var[-1] if m == "ski" else np.abs(res.weights[-1])
            named[m].append(int(np.argmax(score)))
        s = runs["ski"].prior_var[-1]
        others.append(float(np.delete(s, d).max() / s[d]))
        if seed == 0:
            out = Path(args.out)
            plot_weights(out / "delay_weights.png", sim.t, {m: (r.weights, r.weight_std) for m, r in runs.items()},
                         model.weight_names, truth, "delayed-gain weights, seed 0 (±2σ)")
            plot_ard(out / "delay_ard.png", model.weight_names, runs["ski"].prior_var[-1], highlight=d,
                     title=f"final ARD prior variances (true delay {d})")
    report = {m: dict(gain_relative_error=spread(gain_err[m])["median"], spread=spread(gain_err[m]),
                      delay=int(np.bincount(named[m]).argmax()),
                      delay_correct_fraction=float(np.mean(np.array(named[m]) == d)),
                      delay_rule="largest ARD prior variance" if m == "ski" else "largest |weight|")
              for m in filters}
    report["ski"].update(others_below_1pct_fraction=float(np.mean(np.array(others) < 0.01)),
                         others_max_relative=spread(others))
    report["settings"] = dict(true_delay=d, window=wingrock_delay.WINDOW, true_gain=L_TRUE, seeds=args.seeds,
                              weight_prior_variance=args.prior_variance, filter_options=options.asdict(),
                              Q_diag=np.diag(model.process_noise()).tolist(), R=model.measurement_noise().ravel().tolist())
    table = "\n".join([f"Delay experiment (true delay {d}, prior variance {args.prior_variance:g}, ARD {args.ard}, "
                        f"median over {args.seeds} seeds; SKI: other ARD variances < 1 % of delay {d}'s on "
                        f"{report['ski']['others_below_1pct_fraction']:.0%} of seeds)",
                       f"{'method':6s} {'gain rel. error':>16s} {'paper':>6s} {'named delay':>12s} {'correct':>8s}"] +
                      [f"{m:6s} {r['gain_relative_error']:16.3f} {PAPER[m]:6.2f} {r['delay']:12d} "
                       f"{r['delay_correct_fraction']:8.0%}" for m, r in report.items() if m in filters])
    return emit(report, args.json, table)


if __name__ == "__main__":
    sys.exit(main())
