"""Discretisation of continuous dynamics dx/dt = f(x, ·) over one sample."""
from __future__ import annotations

from typing import Callable

import casadi as ca

__all__ = ["rk4", "euler", "discretize"]


def rk4(f: Callable[[ca.SX], ca.SX], x: ca.SX, h: float) -> ca.SX:
    """One classical Runge-Kutta step of length h (inputs held constant)."""
    k1 = f(x)
    k2 = f(x + h / 2 * k1)
    k3 = f(x + h / 2 * k2)
    k4 = f(x + h * k3)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def euler(f: Callable[[ca.SX], ca.SX], x: ca.SX, h: float) -> ca.SX:
    """One forward-Euler step of length h."""
    return x + h * f(x)


def discretize(rhs: ca.SX, x: ca.SX, dt: float, method: str, substeps: int = 1) -> ca.SX:
    """x[k+1] as an SX expression of x[k] (and whatever else ``rhs`` uses).

    rhs: dx/dt (or x[k+1] itself when method is ``"discrete"``).
    """
    if method == "discrete":
        return rhs
    step = {"rk4": rk4, "euler": euler}[method]
    one = step(lambda xi: ca.substitute(rhs, x, xi), x, dt / substeps)
    out = one
    for _ in range(substeps - 1):
        out = ca.substitute(one, x, out)
    return out
