"""Why a filter step gave non-finite numbers: the model evaluated where the filter evaluates it.

A step fails when the observation (at the prior) or the transition (from the posterior the update
gives) is not finite at a point the filter uses: the mean (every filter), the derivatives there
(the EKF), or the sigma points, z ± γ times each column of the factor (the UKF kinds). Naming the
equation and the point tells a user what to change (a square root of a state the spread takes
below zero, a norm differentiated at zero), where a generic hint about overflows would not.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from .guard import chol_psd

__all__ = ["sigma_reach", "nearer", "explain"]


def sigma_reach(filt) -> tuple[float, int]:
    """(γ, n): a sigma-point filter evaluates the model at ±γ standard deviations of its n
    sigma-point states (the MUKF's nonlinear ones)."""
    o = filt.options
    n = len(filt.partition.nonlinear) if filt.partition is not None else len(filt.aug.names)
    return o.alpha * np.sqrt(n + o.kappa), n


def nearer(filt) -> str:
    """How to bring a sigma-point filter's points nearer: the next smaller alpha of 0.3, 0.1, 0.03, …
    10⁻³ and where they would sit, or smaller prior variances of the weights."""
    o, (_, n) = filt.options, sigma_reach(filt)
    a = next((a for a in (0.3, 0.1, 0.03, 0.01, 0.003, 0.001) if a < o.alpha), o.alpha)
    if a >= o.alpha:                       # alpha as small as it usefully goes: the prior it is
        return "Smaller prior variances of the weights (prior_variance) or initial stds of the states bring them nearer"
    return (f"A smaller alpha (--alpha {a:g}, FilterOptions(alpha={a:g}): ±{a * np.sqrt(n + o.kappa):.3g}; now "
            f"{o.alpha:g}) or smaller prior variances of the weights bring them nearer")


def _point(names, z, nx) -> str:
    return ", ".join(f"{names[i]} = {z[i]:.4g}" for i in range(nx))


def explain(filt, prior, posterior, u, mem) -> str | None:
    """Where the model is not finite for a step: the observation at the ``prior`` (mean, and factor
    S or covariance P as the filter keeps it), the transition at the ``posterior`` it predicts from
    (None: not computed), under step inputs ``u`` and input history ``mem``; None when both are
    finite everywhere the filter looks."""
    aug = filt.aug
    nx, names, outputs = aug.shapes["nx"], aug.names, aug.model.output_names
    fh = ca.Function("fh", [aug.z, aug.u, aug.mem], [aug.f, aug.h])
    jac = ca.Function("J", [aug.z, aug.u, aug.mem], [ca.jacobian(aug.f, aug.z), ca.jacobian(aug.h, aug.z)])
    rows = ([f"the {aug.model.discretization} step of {n}" for n in names], [f"output {n}" for n in outputs])
    gamma, _ = sigma_reach(filt)

    def undefined(point) -> str | None:
        bad = [r[i] for r, v in zip(rows, fh(point, u, mem)) for i in np.flatnonzero(~np.isfinite(np.array(v).ravel()))]
        if not bad:
            return None
        more = f" (and {len(bad) - 2} more)" if len(bad) > 2 else ""
        return " and ".join(bad[:2]) + more + (" are" if len(bad) > 1 else " is")

    for which, pair in (("prior", prior), ("posterior", posterior)):
        if pair is None:
            continue
        z, C = np.asarray(pair[0], float).ravel(), np.asarray(pair[1], float)
        at_mean = f"the {which} mean ({_point(names, z, nx)})"
        if what := undefined(z):
            return (f"{what} not finite at {at_mean}: a term there, or within the step from it, overflows (a "
                    f"cubic or exponential of a state far out) or is undefined (a square root, logarithm or "
                    f"division: write it to be defined there, e.g. sqrt(fmax(x, 1e-9)): a floor above 0, where its derivative is finite)")
        if filt.kind == "ekf":
            for J, r in zip(jac(z, u, mem), rows):
                i, j = np.nonzero(~np.isfinite(np.array(J, float)))
                if len(i):
                    return (f"the EKF's derivative of {r[i[0]]} with respect to {names[j[0]]} is not finite at "
                            f"{at_mean}: a term without a derivative there (a square root or norm at 0) fails "
                            f"every step linearised at it. Start the states away from it (initial=) or write "
                            f"the term so that it is differentiable there")
            continue
        for point in _sigma_points(filt, z, C, gamma):
            if what := undefined(point):
                return (f"{what} not finite at one of the {filt.kind}'s sigma points ({_point(names, point, nx)}), "
                        f"{gamma:.3g} standard deviations from {at_mean}: a term there overflows (a cubic or "
                        f"exponential far out) or is undefined (a square root, logarithm or division). The model "
                        f"must be finite wherever the points reach. {nearer(filt)}; a term written to be defined "
                        f"there (sqrt(fmax(x, 1e-9)), a floor above 0) cannot fail")
    return None


def _sigma_points(filt, z, C, gamma):
    """z ± γ times each column of the factor (the MUKF's: of its nonlinear states only)."""
    S = C if filt.square_root else chol_psd(C)
    if filt.partition is not None:
        keep = np.zeros(len(z), bool)
        keep[list(filt.partition.nonlinear)] = True
        S = chol_psd(S @ S.T * np.outer(keep, keep))
    for j in np.flatnonzero(np.any(S != 0, axis=0)):
        yield z - gamma * S[:, j]
        yield z + gamma * S[:, j]
