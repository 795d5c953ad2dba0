"""Quadrotor thrust and drag selection (the SKI paper, sections 4.2 and 4.3).

Spiral climb (50 Hz, 60 s, position measured): SKI and the augmented UKF on
the candidates 1, pwm, …, pwm⁵ (thrust along body z, centred/standardised
PWM) and drag_lin (−v in the rotor plane), drag_quad (−v‖v‖); the truth is 1,
pwm, drag_lin. Vertical sinusoid (100 Hz, 40 s, height measured): candidates
1, u, …, u⁵ of the raw PWM as the normalised actuator output u; the truth is
linear (rotor drag does not act along the rotor axis). A what-if flies the
vertical sinusoid with an axial drag −0.3 v_z, which the paper's basis cannot
represent, on that basis and with the candidate drag_lin (−v_z) added.
Both filters use identical settings (`settings` in the JSON output).

Selection rules (stated, identical across seeds):
- SKI: term i is selected when its final ARD prior still allows it a
  contribution sqrt(s_i)·rms(φ_i) of at least 1 % of the largest such
  value over the terms (rms(φ_i) = RMS of the candidate over the flight; the
  product is an acceleration, so the terms are compared in one unit).
- AUKF (no ARD): term i is selected when it is significant, |ŵ_i| > 2σ_i,
  and its contribution |ŵ_i|·rms(φ_i) is at least 1 % of the largest — the
  same 1 % floor on the same acceleration scale. (At its fixed point ARD's
  variance is ŵ_i² + σ_i², so the SKI rule is the AUKF rule's magnitude test
  with the data-driven prior in place of the posterior.) The same rule applied
  to SKI's posterior is reported as `significant`; SKI's rule applied to the
  AUKF with ŵ_i² + σ_i² in place of the ARD variance as `selected_by_ski_rule`.
Model error = sqrt(Δwᵀ G Δw), G = mean over the flight of Φᵀ Φ on the true
states: the RMS acceleration error of the identified term over the flight
(m/s²; insensitive to how collinear candidates share a contribution).
Wander = the largest, over terms, standard deviation of ŵ_i(t)·rms(φ_i) in
the second half of the flight (m/s²): how much the estimates still move.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from benchmarks.common import emit, parser, timed_run
from models import quadrotor_sim as qs
from models import quadrotor_spiral as spiral_model
from models import quadrotor_vertical as vertical_model
from skigen import FilterOptions, derive
from skigen.plots import plot_ard, plot_weights

OPTIONS = FilterOptions()
FILTERS = {"ski": "ski", "aukf": "ukf"}
FLOOR = 0.01          # selection floor: 1 % of the largest contribution


def select_ski(prior_var, rms, names) -> list[str]:
    c = np.sqrt(prior_var) * rms
    return [n for n, ci in zip(names, c) if ci >= FLOOR * c.max()]


def select_significant(w, sd, rms, names) -> list[str]:
    c = np.abs(w) * rms
    return [n for n, wi, si, ci in zip(names, w, sd, c) if abs(wi) > 2 * si and ci >= FLOOR * c.max()]


def gram(phi) -> np.ndarray:
    """G = mean_k Φ_kᵀ Φ_k for Φ_k (m, 3) or (m,): the model-error metric."""
    phi = phi if phi.ndim == 3 else phi[:, :, None]
    return np.einsum("kid,kjd->ij", phi, phi) / len(phi)


def model_error(W, truth, G) -> np.ndarray:
    dW = np.atleast_2d(W) - truth
    return np.sqrt(np.maximum(np.einsum("ki,ij,kj->k", dW, G, dW), 0))


def _experiment(model, flights, recording, phi_of, names, truth, rms, expected, figures=None, options=OPTIONS):
    """Run SKI and the AUKF on each flight; per-method summaries over seeds."""
    filters = {m: derive(model, kind, options) for m, kind in FILTERS.items()}
    per = {m: dict(W=[], S=[], s=[], selected=[], significant=[], by_ard_rule=[], err=[], err_avg=[],
                   wander=[], us=[])
           for m in filters}
    for i, flight in enumerate(flights):
        rec = recording(flight)
        G = gram(phi_of(flight))
        half = flight.t >= flight.t[-1] / 2
        runs = {}
        for m, filt in filters.items():
            res, us = timed_run(filt, rec)
            runs[m] = res
            W, S = res.weights, res.weight_std
            d = per[m]
            d["W"].append(W[-1]); d["S"].append(S[-1]); d["us"].append(us)
            d["s"].append(res.prior_var[-1] if m == "ski" else W[-1] ** 2 + S[-1] ** 2)
            d["selected"].append(select_ski(res.prior_var[-1], rms, names) if m == "ski"
                                 else select_significant(W[-1], S[-1], rms, names))
            d["significant"].append(select_significant(W[-1], S[-1], rms, names))
            d["by_ard_rule"].append(select_ski(d["s"][-1], rms, names))
            err = model_error(W, truth, G)
            d["err"].append(float(err[-1])); d["err_avg"].append(float(err.mean()))
            d["wander"].append(float(np.max(np.std(W[half] * rms, axis=0))))
        if i == 0 and figures is not None:
            figures(flight, runs)
        print(f"  seed {i}: " + "; ".join(f"{m} {per[m]['selected'][-1]}" for m in filters), file=sys.stderr)
    out = {}
    for m, d in per.items():
        sel = d["selected"]
        counts = {n: sum(n in s for s in sel) for n in names}
        majority = [n for n in names if counts[n] > len(sel) / 2]
        out[m] = dict(
            selected=majority,
            selected_seed0=sel[0],
            selection_counts=counts,
            exact_selection_fraction=float(np.mean([set(s) == set(expected) for s in sel])),
            weights=dict(zip(names, np.median(d["W"], axis=0).tolist())),
            weight_std=dict(zip(names, np.median(d["S"], axis=0).tolist())),
            model_error_final=float(np.median(d["err"])),
            model_error_time_avg=float(np.median(d["err_avg"])),
            wander_second_half=float(np.median(d["wander"])),
            us_per_step=float(np.median(d["us"])),
            selection_rule=("sqrt(ARD variance)*rms >= 1% of max" if m == "ski"
                            else "|w| > 2 sd and |w|*rms >= 1% of max"))
        if m == "ski":
            out[m]["ard_variances"] = dict(zip(names, np.median(d["s"], axis=0).tolist()))
            out[m]["significant"] = [n for n in names
                                     if sum(n in s for s in d["significant"]) > len(sel) / 2]
        else:
            out[m]["ard_equivalent_variances"] = dict(zip(names, np.median(d["s"], axis=0).tolist()))
            out[m]["selected_by_ski_rule"] = [n for n in names
                                              if sum(n in s for s in d["by_ard_rule"]) > len(sel) / 2]
    out["weights_true"] = dict(zip(names, np.asarray(truth, float).tolist()))
    out["expected"] = list(expected)
    return out


def spiral_phi(flight):
    return spiral_model.basis_values(flight.vel, flight.quat, flight.pwm)


def vertical_phi(offset, scale, drag=False):
    def phi(flight):
        u = (flight.pwm - offset) / scale
        powers = u[:, None] ** np.arange(vertical_model.DEGREE + 1)
        return np.c_[powers, -flight.vel[:, 2]] if drag else powers
    return phi


def main(argv=None) -> int:
    p = parser("quadrotor", seeds=10)
    p.add_argument("--gust", type=float, default=qs.GUST_STD,
                   help="std of the simulator's gust acceleration, m/s² (0.02 by default)")
    p.add_argument("--accel", type=float, default=spiral_model.PRIOR_ACCEL,
                   help="scale-aware prior: each candidate may contribute about this many m/s² (1 by default)")
    args = p.parse_args(argv)
    options = FilterOptions(ard=args.ard)
    out = Path(args.out)
    gust_kw = dict(gust_std=args.gust)
    seeds = range(args.seeds)

    # ---------------------------------------------------------------- spiral
    names = spiral_model.TERMS
    sm = spiral_model.build(prior_variance=(args.accel / spiral_model.BASIS_RMS) ** 2)

    def spiral_figures(flight, runs):
        plot_weights(out / "quadrotor_spiral_weights.png", flight.t,
                     {m: (r.weights, r.weight_std) for m, r in runs.items()}, names, spiral_model.W_TRUE,
                     "quadrotor spiral: weight estimates (seed 0, ±2σ)")
        plot_ard(out / "quadrotor_spiral_ard.png", names, runs["ski"].prior_var[-1],
                 title="quadrotor spiral: final ARD prior variances (weight units²)")

    print("spiral", file=sys.stderr)
    report = _experiment(sm, [qs.spiral(s, **gust_kw) for s in seeds], spiral_model.recording, spiral_phi,
                         names, spiral_model.W_TRUE, spiral_model.BASIS_RMS, spiral_model.TRUE_TERMS,
                         spiral_figures, options)
    spiral_truth = {k: report.pop(k) for k in ("weights_true", "expected")}

    # -------------------------------------------------------------- vertical
    vnames = vertical_model.TERMS
    vm = vertical_model.build(prior_variance=(args.accel / vertical_model.BASIS_RMS) ** 2)
    flights = [qs.vertical(s, **gust_kw) for s in seeds]

    def vertical_figures(flight, runs):
        plot_weights(out / "quadrotor_vertical_weights.png", flight.t,
                     {m: (r.weights, r.weight_std) for m, r in runs.items()}, vnames, vertical_model.W_TRUE,
                     "quadrotor vertical (u = (pwm − 1000 µs)/1000 µs): weights (seed 0, ±2σ)")
        plot_ard(out / "quadrotor_vertical_ard.png", vnames, runs["ski"].prior_var[-1],
                 highlight=vnames.index(vertical_model.TRUE_TERM),
                 title="quadrotor vertical: final ARD prior variances")

    print("vertical", file=sys.stderr)
    vertical = _experiment(vm, flights, vertical_model.recording,
                           vertical_phi(vertical_model.PWM_OFFSET, vertical_model.PWM_RANGE), vnames,
                           vertical_model.W_TRUE, vertical_model.BASIS_RMS, [vertical_model.TRUE_TERM],
                           vertical_figures, options)
    for m in FILTERS:
        v = vertical[m]["ard_variances"] if m == "ski" else vertical[m]["ard_equivalent_variances"]
        c = np.sqrt(list(v.values())) * vertical_model.BASIS_RMS
        vertical[m]["dominant"] = vnames[int(np.argmax(c))]

    # Pure scale u = pwm / 1000 µs (no offset): the thrust line a_T = c (pwm − 1000 µs) then has
    # a constant −2g in this basis, and near hover a single monomial can match value and slope.
    rms_ms = vertical_model.basis_rms(flights[0].pwm, 0.0)
    vm_ms = vertical_model.build(prior_variance=(args.accel / rms_ms) ** 2, pwm_offset=0.0,
                                 name="quadrotor_vertical_ms")
    print("vertical, u = pwm / 1000", file=sys.stderr)
    pure = _experiment(vm_ms, flights, vertical_model.recording, vertical_phi(0.0, vertical_model.PWM_RANGE),
                       vnames, vertical_model.w_true(0.0), rms_ms, [vertical_model.TRUE_TERM, "1"], options=options)
    for m in FILTERS:
        v = pure[m]["ard_variances"] if m == "ski" else pure[m]["ard_equivalent_variances"]
        pure[m]["dominant"] = vnames[int(np.argmax(np.sqrt(list(v.values())) * rms_ms))]
    vertical["pure_scale_ms"] = dict(_block(pure), basis_rms=rms_ms.tolist(), scaling="u = pwm / 1000 us")

    # What-if: an axial drag −0.3 v_z (thrust falling with the climb rate), which the paper's basis
    # cannot represent, on that basis and with a candidate of its own.
    axial = [qs.vertical(s, axial_drag=qs.DRAG_LIN, **gust_kw) for s in seeds]
    print("vertical with axial drag, the paper's basis", file=sys.stderr)
    paper = _experiment(vm, axial, vertical_model.recording,
                        vertical_phi(vertical_model.PWM_OFFSET, vertical_model.PWM_RANGE), vnames,
                        vertical_model.W_TRUE, vertical_model.BASIS_RMS, [vertical_model.TRUE_TERM],
                        options=options)
    dnames = vnames + ["drag_lin"]
    drms = np.r_[vertical_model.BASIS_RMS, vertical_model.DRAG_RMS]
    vm_drag = vertical_model.build(prior_variance=(args.accel / drms) ** 2, drag=True,
                                   name="quadrotor_vertical_drag")
    print("vertical with axial drag, with the drag candidate", file=sys.stderr)
    drag = _experiment(vm_drag, axial, vertical_model.recording,
                       vertical_phi(vertical_model.PWM_OFFSET, vertical_model.PWM_RANGE, drag=True), dnames,
                       np.r_[vertical_model.W_TRUE, qs.DRAG_LIN], drms, [vertical_model.TRUE_TERM, "drag_lin"],
                       options=options)
    vertical["axial_drag"] = dict(axial_drag=qs.DRAG_LIN, paper_basis=_block(paper),
                                  with_drag_candidate=dict(_block(drag), basis_rms=drms.tolist()))
    report["vertical"] = vertical
    report["settings"] = dict(
        seeds=args.seeds, filter_options=options.asdict(), figures=str(out),
        statistics="selected = terms selected on more than half of the seeds; weights, variances, errors = "
                   "medians over seeds",
        spiral=dict(_model_settings(sm, spiral_model.BASIS_RMS, args.accel), **spiral_truth,
                    pwm_center_us=spiral_model.PWM_CENTER, pwm_scale_us=spiral_model.PWM_SCALE,
                    flight=qs.SPIRAL),
        vertical=dict(_model_settings(vm, vertical_model.BASIS_RMS, args.accel),
                      pwm_offset_us=vertical_model.PWM_OFFSET, pwm_range_us=vertical_model.PWM_RANGE,
                      flight=qs.VERTICAL),
        simulator=dict(thrust_gain=qs.THRUST_GAIN, pwm_zero_thrust_us=qs.PWM_MIN, pwm_hover_us=qs.PWM_HOVER,
                       drag_lin_rotor_plane=qs.DRAG_LIN, drag_quad=0.0, att_tau_s=qs.ATT_TAU, gust_std=args.gust,
                       gust_tau_s=qs.GUST_TAU, noise_std_m=qs.NOISE_STD),
        selection=dict(ski="sqrt(final ARD variance_i) * rms_i >= 1% of the largest over the terms",
                       aukf="|w_i| > 2 sd_i and |w_i| * rms_i >= 1% of the largest over the terms"))
    return emit(report, args.json, _table(report))


def _block(res) -> dict:
    return dict(ski=res["ski"], aukf=res["aukf"], weights_true=res["weights_true"])


def _model_settings(model, rms, accel) -> dict:
    return dict(dt=model.dt, discretization=model.discretization,
                Q_diag=np.diag(model.process_noise()).tolist(), R_diag=np.diag(model.measurement_noise()).tolist(),
                x0=model.x0, P0_diag=np.diag(model.initial_covariance()).tolist(),
                weight_prior_mean=0.0, weight_prior_variance=model.prior_variances().tolist(),
                prior_rule=f"std_i = {accel} m/s^2 / rms(phi_i), rms = {np.asarray(rms).tolist()}",
                weight_process_std=0.0)


def _table(report) -> str:
    seeds = report["settings"]["seeds"]
    rows = []

    def block(title, res, names, truth):
        rows.append(title)
        rows.append(f"{'term':10s} {'truth':>8s} " + " ".join(f"{m + ' w':>9s} {'sel':>4s}" for m in FILTERS)
                    + f" {'SKI ARD var':>12s}")
        for n in names:
            cells = []
            for m in FILTERS:
                cells.append(f"{res[m]['weights'][n]:9.4f} {res[m]['selection_counts'][n]:>4d}")
            rows.append(f"{n:10s} {truth[n]:8.4f} " + " ".join(cells) + f" {res['ski']['ard_variances'][n]:12.3g}")
        for m in FILTERS:
            r = res[m]
            extra = (f"; by SKI's rule on w²+σ²: {r['selected_by_ski_rule']}" if "selected_by_ski_rule" in r
                     else f"; significant (|w| > 2σ): {r['significant']}")
            rows.append(f"  {m:5s} selected {r['selected']}{extra}")
            rows.append(f"        exact on {r['exact_selection_fraction']:.0%} of seeds; "
                        f"model error final {r['model_error_final']:.3f} m/s², time-avg {r['model_error_time_avg']:.3f}; "
                        f"wander {r['wander_second_half']:.4f} m/s²; {r['us_per_step']:.0f} us/step")
        rows.append("")

    block(f"Quadrotor spiral (median over {seeds} seeds; 'sel' = seeds on which the term is selected)",
          report, spiral_model.TERMS, report["settings"]["spiral"]["weights_true"])
    v = report["vertical"]
    block("Quadrotor vertical, u = (pwm - 1000 us) / 1000 us", v, vertical_model.TERMS, v["weights_true"])
    rows.append(f"  dominant term: SKI {v['ski']['dominant']}, AUKF {v['aukf']['dominant']}")
    pure = v["pure_scale_ms"]
    block("Quadrotor vertical, pure scale u = pwm / 1000 us", pure, vertical_model.TERMS, pure["weights_true"])
    rows.append(f"  dominant term: SKI {pure['ski']['dominant']}, AUKF {pure['aukf']['dominant']}")
    a = v["axial_drag"]
    block(f"Quadrotor vertical with an axial drag -{a['axial_drag']} v_z, the paper's basis", a["paper_basis"],
          vertical_model.TERMS, a["paper_basis"]["weights_true"])
    d = a["with_drag_candidate"]
    block(f"Quadrotor vertical with an axial drag -{a['axial_drag']} v_z, with the candidate drag_lin (-v_z)",
          d, vertical_model.TERMS + ["drag_lin"], d["weights_true"])
    return "\n".join(rows)


if __name__ == "__main__":
    sys.exit(main())
