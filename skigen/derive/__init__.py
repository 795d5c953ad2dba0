"""Derive, once and symbolically, every filter step of a model.

:func:`derive` returns a :class:`DerivedFilter` whose ``step`` is a CasADi
``Function`` (SX, dense outputs). One step at sample k takes the prior for k,
updates with y[k] (h at u[k]), runs ARD for SKI, and predicts to k+1 with u[k]
(with a first-order hold, u is [u[k]; u[k+1]]: see :func:`step_inputs`):

    inputs : z (n), C (n×n), [s (nw), SKI kinds only], u, mem, y, valid (1/0 per output)
    outputs: z_post, C_post, [s_next], z_next, C_next, mem_next, e, Pyy, nis, loglik

C is the covariance P for the EKF and its lower Cholesky factor S for every
other kind. 'mukf' is the marginalised square-root UKF (sigma points over the
substate z_n only, the conditionally linear z_l integrated exactly; see
mukf.py), 'ski_mukf' SKI with the MUKF core (MUKF update, ARD, MUKF predict).
The same Functions feed the Python callables and the C emitter. ``step`` is
built on first use: the looped C emitter needs only the model's functions.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np

from ..model import Model
from .augment import Augmented, augment, step_inputs
from .common import ARD_UPDATES, FilterOptions, innovation_stats
from .ekf import ekf_predict, ekf_update
from .mukf import Partition, mukf_predict, mukf_update, partition
from .ski import ard_step
from .ukf import ukf_predict, ukf_update

__all__ = ["ARD_UPDATES", "FILTERS", "SKI_KINDS", "MUKF_KINDS", "DerivedFilter", "FilterOptions", "Partition",
           "augment", "derive", "partition", "step_inputs"]

FILTERS = ("ekf", "ukf", "ski", "mukf", "ski_mukf")
SKI_KINDS = ("ski", "ski_mukf")      # steps with the ARD prior variances s as input and output
MUKF_KINDS = ("mukf", "ski_mukf")    # marginalised UKF core


@dataclass(frozen=True)
class DerivedFilter:
    """A filter derived for one model: its step Function and initial values."""

    kind: str
    aug: Augmented
    options: FilterOptions
    partition: Partition | None = None     # MUKF kinds: the z_n / z_l split

    @cached_property
    def step(self) -> ca.Function:
        """The step Function (see the module docstring), derived on first use."""
        return _step(self)

    @property
    def names_in(self) -> list[str]:
        return ["z", "C"] + (["s"] if self.has_ard else []) + ["u", "mem", "y", "valid"]

    @property
    def names_out(self) -> list[str]:
        return (["z_post", "C_post"] + (["s_next"] if self.has_ard else [])
                + ["z_next", "C_next", "mem_next", "e", "Pyy", "nis", "loglik"])

    @property
    def square_root(self) -> bool:
        return self.kind != "ekf"

    @property
    def has_ard(self) -> bool:
        """True when the step carries the ARD prior variances s (SKI kinds)."""
        return self.kind in SKI_KINDS

    def initial(self) -> dict[str, np.ndarray]:
        """The filter state before the first sample: z, C (and s for SKI), mem."""
        C = np.linalg.cholesky(self.aug.P0) if self.square_root else self.aug.P0.copy()
        state = dict(z=self.aug.z0.copy(), C=C, mem=np.zeros(self.aug.mem.shape[0]))
        if self.has_ard:
            state["s"] = self.aug.s0.copy()
        return state


def derive(model: Model | Augmented, kind: str, options: FilterOptions | None = None, *,
           linear=None, estimate=()) -> DerivedFilter:
    """Derive the step Function of filter ``kind`` (one of :data:`FILTERS`).

    linear: MUKF kinds only, the names of the states/weights to treat as the
    conditionally linear substate z_l (default: the largest one detected).
    estimate: names of declared parameters to estimate online, augmented into
    the state after the weights (the others stay constants at their value).
    """
    if kind not in FILTERS:
        raise ValueError(f"unknown filter '{kind}'; choose one of {', '.join(FILTERS)}")
    if linear is not None and kind not in MUKF_KINDS:
        raise ValueError(f"'linear' chooses the MUKF's linear substate; filter '{kind}' has none")
    if isinstance(model, Augmented) and estimate:
        raise ValueError("estimate= applies to a Model; this one is already augmented")
    aug = model if isinstance(model, Augmented) else augment(model, estimate)
    opts = options or FilterOptions()
    d = aug.shapes
    if kind in SKI_KINDS and d["nw"] == 0:
        raise ValueError(f"model '{aug.model.name}' declares no unknown term: SKI needs basis weights")
    part = partition(aug, linear) if kind in MUKF_KINDS else None
    return DerivedFilter(kind, aug, opts, part)


def _step(filt: DerivedFilter) -> ca.Function:
    """Build the step Function of ``filt`` symbolically."""
    kind, aug, opts, part = filt.kind, filt.aug, filt.options, filt.partition
    d = aug.shapes
    z, C = ca.SX.sym("z", d["n"]), ca.SX.sym("C", d["n"], d["n"])
    s = ca.SX.sym("s", d["nw"])
    u, mem = ca.SX.sym("u", d["nu"]), ca.SX.sym("mem", d["nmem"])
    y, valid = ca.SX.sym("y", d["ny"]), ca.SX.sym("valid", d["ny"])
    # Bind the model's own symbols for u and mem to the step's inputs.
    aug_b = _rebind(aug, u, mem)
    if kind == "ekf":
        z_post, C_post, e, Pyy, Ly = ekf_update(aug_b, z, C, u, mem, y, valid)
        z_next, C_next = ekf_predict(aug_b, z_post, C_post, u, mem)
    elif part is not None:
        z_post, C_post, e, Pyy, Ly = mukf_update(aug_b, part, opts, z, C, u, mem, y, valid)
        z_carry, C_carry = z_post, C_post
        if kind == "ski_mukf":
            z_post, C_post, s_next, z_carry, C_carry = ard_step(aug_b, opts, z_post, C_post, s)
        z_next, C_next = mukf_predict(aug_b, part, opts, z_carry, C_carry, u, mem)
    else:
        z_post, C_post, e, Pyy, Ly = ukf_update(aug_b, opts, z, C, u, mem, y, valid)
        z_carry, C_carry = z_post, C_post
        if kind == "ski":
            z_post, C_post, s_next, z_carry, C_carry = ard_step(aug_b, opts, z_post, C_post, s)
        z_next, C_next = ukf_predict(aug_b, opts, z_carry, C_carry, u, mem)
    nis, loglik = innovation_stats(Ly, e, valid)
    mem_next = ca.substitute(aug.mem_next, ca.vertcat(aug.u, aug.mem), ca.vertcat(u, mem))
    values = dict(z=z, C=C, s=s, u=u, mem=mem, y=y, valid=valid, z_post=z_post, C_post=C_post,
                  z_next=z_next, C_next=C_next, mem_next=mem_next, e=e, Pyy=Pyy, nis=nis, loglik=loglik)
    if filt.has_ard:
        values["s_next"] = s_next
    return ca.Function(f"{aug.model.name}_{kind}_step", [values[k] for k in filt.names_in],
                       [ca.densify(values[k]) for k in filt.names_out], filt.names_in, filt.names_out)


def _rebind(aug: Augmented, u: ca.SX, mem: ca.SX) -> Augmented:
    """The augmented model with its input and memory symbols replaced."""
    old, new = ca.vertcat(aug.u, aug.mem), ca.vertcat(u, mem)
    sub = lambda e: ca.substitute(e, old, new)
    return Augmented(**{**aug.__dict__, "u": u, "mem": mem, "f": sub(aug.f), "h": sub(aug.h),
                        "mem_next": sub(aug.mem_next)})
