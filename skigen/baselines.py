"""Batch baselines: the SKI paper's SINDy comparison (section 4.1, Table 1).

SINDy for a second-order system whose angle alone is measured:

1. numerical differentiation of the measured angle ``phi`` with pysindy:
   ``p_hat = D(phi)`` and ``pdot_hat = D(p_hat)``.  The default ``D`` is
   ``ps.SmoothedFiniteDifference`` with its default smoother (Savitzky-Golay,
   window 11 samples, polynomial order 3) followed by a second-order central
   finite difference (one-sided at the ends); ``differentiation=
   "finite_difference"`` uses plain ``ps.FiniteDifference`` (order 2), with
   ``pdot_hat`` taken directly as the 3-point second difference of ``phi``
   (``FiniteDifference(d=2)``); any pysindy differentiation object may be passed
   instead (it is applied twice).
2. target ``y = pdot_hat - gain * delta`` (the known input term removed);
3. sparse regression with pysindy's ``STLSQ`` of ``y`` on the library
   ``basis_fn(phi, p_hat)`` (default: the WingRock library
   ``[1, theta, p, |theta| p, |p| p, theta^3]``).

``input_alignment``: with a zero-order-hold input, a central difference at
``t_k`` averages the acceleration over ``[t_{k-1}, t_{k+1}]``, which is driven
by ``delta[k-1]`` and ``delta[k]``.  ``"sample"`` (default, the plain SINDy
formulation) subtracts ``gain * delta[k]``; ``"centered"`` subtracts
``gain * (delta[k-1] + delta[k]) / 2``, which makes plain finite differences
on noise-free data essentially exact.

On noisy data the error is dominated by the differentiation noise and by the
near-collinearity of ``p`` and ``|p| p`` (and of ``theta`` and ``theta^3``).
"""
from __future__ import annotations

import warnings
from typing import Callable

import numpy as np
import pysindy as ps

__all__ = ["wingrock_basis", "sindy_weights", "sindy_time_history", "estimate_derivatives"]

DEFAULT_THRESHOLD = 0.005   # below the smallest true WingRock weight (0.0095)
DEFAULT_ALPHA = 0.05        # STLSQ ridge weight (pysindy's default)


def wingrock_basis(theta, p) -> np.ndarray:
    """[1, theta, p, |theta| p, |p| p, theta^3], shape (..., 6)."""
    theta = np.asarray(theta, dtype=float)
    p = np.asarray(p, dtype=float)
    return np.stack([np.ones_like(theta), theta, p, np.abs(theta) * p, np.abs(p) * p, theta**3],
                    axis=-1)


def _differentiator(spec):
    if spec == "smoothed":
        # fresh dict: pysindy mutates smoother_kws in place
        return ps.SmoothedFiniteDifference(smoother_kws={"window_length": 11, "polyorder": 3})
    if spec == "finite_difference":
        return ps.FiniteDifference(order=2, d=1)
    if isinstance(spec, ps.BaseDifferentiation):
        return spec
    raise ValueError(f"unknown differentiation {spec!r}")


def estimate_derivatives(t, phi, differentiation="smoothed"):
    """(p_hat, pdot_hat): first and second time derivatives of the measured angle."""
    t = np.asarray(t, dtype=float)
    phi = np.asarray(phi, dtype=float)
    diff = _differentiator(differentiation)
    p_hat = np.ravel(diff(phi.reshape(-1, 1), t))
    if differentiation == "finite_difference":
        pdot_hat = np.ravel(ps.FiniteDifference(order=2, d=2)(phi.reshape(-1, 1), t))
    else:
        pdot_hat = np.ravel(_differentiator(differentiation)(p_hat.reshape(-1, 1), t))
    return p_hat, pdot_hat


def sindy_weights(t, delta, phi, gain: float = 3.0, basis_fn: Callable = wingrock_basis,
                  threshold: float = DEFAULT_THRESHOLD, alpha: float = DEFAULT_ALPHA,
                  differentiation="smoothed", input_alignment: str = "sample",
                  basis_uses_input: bool = False) -> np.ndarray:
    """SINDy estimate of the weights of ``pdot = gain * delta + w . basis_fn(theta, p)``.

    Parameters
    ----------
    t, delta, phi : 1-D arrays of equal length (time, commanded input, measured angle).
    gain : known input gain subtracted from the acceleration (0 if unknown).
    basis_fn : ``basis_fn(theta, p) -> (n, m)``; or, with ``basis_uses_input=True``,
        ``basis_fn(theta, p, delta) -> (n, m)`` (e.g. delayed-input candidates).
    threshold, alpha : ``ps.STLSQ`` sparsity threshold and ridge weight.
    differentiation : ``"smoothed"`` (default), ``"finite_difference"`` or a pysindy
        differentiation object (see the module docstring).
    input_alignment : ``"sample"`` or ``"centered"`` (see the module docstring).

    Returns the weight vector (m,), in the order of ``basis_fn``'s columns.
    """
    t = np.asarray(t, dtype=float)
    delta = np.asarray(delta, dtype=float).ravel()
    phi = np.asarray(phi, dtype=float).ravel()
    if not (len(t) == len(delta) == len(phi)):
        raise ValueError("t, delta and phi must have the same length")
    p_hat, pdot_hat = estimate_derivatives(t, phi, differentiation)
    if input_alignment == "sample":
        u = delta
    elif input_alignment == "centered":
        u = 0.5 * (delta + np.concatenate([[0.0], delta[:-1]]))
    else:
        raise ValueError(f"unknown input_alignment {input_alignment!r}")
    y = pdot_hat - gain * u
    theta_lib = basis_fn(phi, p_hat, delta) if basis_uses_input else basis_fn(phi, p_hat)
    theta_lib = np.asarray(theta_lib, dtype=float)
    opt = ps.STLSQ(threshold=threshold, alpha=alpha)
    with warnings.catch_warnings():
        # STLSQ warns when it eliminates every term or hits max_iter; the
        # returned vector is still the answer of the baseline.
        warnings.simplefilter("ignore")
        opt.fit(theta_lib, y)
    return np.asarray(opt.coef_, dtype=float).ravel()


def sindy_time_history(t, delta, phi, gain: float = 3.0, n_windows: int = 15,
                       period: float | None = None, **kwargs):
    """SINDy refitted on growing prefixes of the record (causally: the derivatives
    of each prefix are computed from that prefix alone).

    The fit times are ``t[0] + period * j, j = 1..n_windows`` (``period`` defaults
    to the record length / ``n_windows``, i.e. 1 s for 15 s); each fit uses the
    samples with ``t <= fit time``.  Returns ``(times, W)`` with ``W`` of shape
    ``(n_windows, m)``; ``W[j]`` holds from ``times[j]`` until the next refit.
    Extra keyword arguments go to :func:`sindy_weights`.
    """
    t = np.asarray(t, dtype=float)
    delta = np.asarray(delta, dtype=float).ravel()
    phi = np.asarray(phi, dtype=float).ravel()
    if period is None:
        period = (t[-1] - t[0]) / n_windows
    dt = float(np.median(np.diff(t)))
    times = t[0] + period * np.arange(1, n_windows + 1)
    W = []
    for tj in times:
        n = int(np.searchsorted(t, tj + 1e-9 * dt, side="right"))
        W.append(sindy_weights(t[:n], delta[:n], phi[:n], gain=gain, **kwargs))
    return times, np.array(W)
