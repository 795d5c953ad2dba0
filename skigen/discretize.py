"""Discretisation of continuous dynamics dx/dt = f(x, u) over one sample.

Inputs are held over the sample (zero-order hold) or, when their values at
the end of the sample are given, interpolated linearly (first-order hold):
u(k dt + τ dt) = u[k] + τ (u[k+1] − u[k]), τ ∈ [0, 1].
"""
from __future__ import annotations

from typing import Callable

import casadi as ca

__all__ = ["rk4", "euler", "discretize"]


def rk4(f: Callable[[ca.SX, float], ca.SX], x: ca.SX, h: float, t0: float = 0.0, dt: float = 1.0) -> ca.SX:
    """One classical Runge-Kutta step of length h; f(x, τ) with τ from t0 to t0 + dt."""
    k1 = f(x, t0)
    k2 = f(x + h / 2 * k1, t0 + dt / 2)
    k3 = f(x + h / 2 * k2, t0 + dt / 2)
    k4 = f(x + h * k3, t0 + dt)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def euler(f: Callable[[ca.SX, float], ca.SX], x: ca.SX, h: float, t0: float = 0.0, dt: float = 1.0) -> ca.SX:
    """One forward-Euler step of length h (f evaluated at τ = t0)."""
    return x + h * f(x, t0)


def discretize(rhs: ca.SX, x: ca.SX, dt: float, method: str, substeps: int = 1,
               held: ca.SX | None = None, held_next: ca.SX | None = None) -> ca.SX:
    """x[k+1] as an SX expression of x[k] (and whatever else ``rhs`` uses).

    rhs: dx/dt (or x[k+1] itself when method is ``"discrete"``). held,
    held_next: the input symbols in ``rhs`` and their values at the end of the
    sample, for a first-order hold (omit both for a zero-order hold).
    """
    if method == "discrete":
        return rhs
    step = {"rk4": rk4, "euler": euler}[method]
    if held is None or held.shape[0] == 0:
        one = step(lambda xi, tau: ca.substitute(rhs, x, xi), x, dt / substeps)
        out = one
        for _ in range(substeps - 1):
            out = ca.substitute(one, x, out)
        return out
    xu = ca.vertcat(x, held)
    f = lambda xi, tau: ca.substitute(rhs, xu, ca.vertcat(xi, held + tau * (held_next - held)))
    out = x
    for i in range(substeps):
        out = step(f, out, dt / substeps, i / substeps, 1 / substeps)
    return out
