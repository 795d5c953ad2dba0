"""Consistency of the posterior: normalised estimation error squared (NEES) on WingRock.

Closed-loop flights of the Table 1 protocol (square wave, 15 s, noise seeds 0 … N−1),
every filter with the Table 1 settings; 'aekf2' is the augmented EKF with the
second-order prediction (FilterOptions(second_order=True)). Per flight, the NEES of the states
eᵀ P_xx⁻¹ e (expected 2) and of the weights (expected 6) from each sample's
posterior mean and covariance, averaged over t ≥ 5 s; then the mean over flights.
A consistent filter's mean lies in the 95 % band of χ²(N·d)/N (d = 2 or 6):
above it the filter is overconfident, below it conservative.
"""
from __future__ import annotations

import sys

import numpy as np
from scipy.stats import chi2

from benchmarks.common import emit, parser
from benchmarks.wingrock import LATE
from models import wingrock
from models.wingrock_sim import simulate
from skigen import FilterOptions, derive
from skigen.runtime import PythonStepper

FILTERS = {"aekf": ("ekf", {}), "aekf2": ("ekf", dict(second_order=True)), "aukf": ("ukf", {}),
           "ski": ("ski", {}), "ski_gradient": ("ski", dict(ard="gradient"))}


def nees(filt, sim, late=LATE) -> tuple[float, float]:
    """Time-averaged NEES (states, weights) of one flight over t ≥ late."""
    st, nx = PythonStepper(filt), filt.aug.shapes["nx"]
    truth = np.c_[sim.theta, sim.p, np.tile(wingrock.W_TRUE, (len(sim.t), 1))]
    out = []
    for k in range(len(sim.t)):
        st.step([sim.delta[k]], [sim.phi[k]])
        if sim.t[k] >= late:
            P = st.C_post @ st.C_post.T if filt.square_root else st.C_post
            e = st.z_post - truth[k]
            out.append([e[b] @ np.linalg.solve(P[b, b], e[b]) for b in (np.s_[:nx], np.s_[nx:])])
    return tuple(np.mean(out, axis=0))


def band(flights: int, dof: int) -> tuple[float, float]:
    """95 % band of the mean over flights of a χ²(dof) NEES."""
    return chi2.ppf(0.025, flights * dof) / flights, chi2.ppf(0.975, flights * dof) / flights


def main(argv=None) -> int:
    p = parser("consistency", seeds=50)
    p.add_argument("--weight-walk", type=float, default=0.0, metavar="EPS",
                   help="give the filters (not the truth) random-walk weights, std EPS·√s₀ per sample "
                        "(default 0: the declared constant weights of Table 1)")
    args = p.parse_args(argv)
    model = wingrock.build(prior_variance=wingrock.PRIOR_VARIANCE,
                           weight_std=args.weight_walk * np.sqrt(wingrock.PRIOR_VARIANCE))
    filters = {m: derive(model, kind, FilterOptions(**opts)) for m, (kind, opts) in FILTERS.items()}
    per = {m: [] for m in filters}
    for seed in range(args.seeds):
        sim = simulate(seed=seed)
        for m, filt in filters.items():
            per[m].append(nees(filt, sim))
    bands = {"states": band(args.seeds, 2), "weights": band(args.seeds, 6)}
    report = {m: {part: dict(mean=float(np.mean(v[:, i])), median=float(np.median(v[:, i])),
                             max=float(np.max(v[:, i])),
                             inside=bool(bands[part][0] <= np.mean(v[:, i]) <= bands[part][1]))
                  for i, part in enumerate(bands)}
              for m, v in ((m, np.array(v)) for m, v in per.items())}
    report["settings"] = dict(flights=args.seeds, after_s=LATE, bands={k: list(v) for k, v in bands.items()},
                              expected={"states": 2, "weights": 6}, reference="square",
                              weight_walk=args.weight_walk)
    rows = [f"WingRock NEES after {LATE:g} s, mean over {args.seeds} flights "
            f"(states: expected 2, band [{bands['states'][0]:.2f}, {bands['states'][1]:.2f}]; "
            f"weights: expected 6, band [{bands['weights'][0]:.2f}, {bands['weights'][1]:.2f}])",
            f"{'filter':13s} {'states':>7s} {'weights':>8s} {'w median':>9s} {'w max':>7s}"]
    for m in filters:
        r = report[m]
        rows.append(f"{m:13s} {r['states']['mean']:7.2f} {r['weights']['mean']:8.2f} "
                    f"{r['weights']['median']:9.2f} {r['weights']['max']:7.1f}")
    return emit(report, args.json, "\n".join(rows))


if __name__ == "__main__":
    sys.exit(main())
