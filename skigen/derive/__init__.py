"""Derive, once and symbolically, every filter step of a model.

:func:`derive` returns a :class:`DerivedFilter` whose ``step`` is a CasADi
``Function`` (SX, dense outputs). One step at sample k takes the prior for k,
updates with y[k] (h at u[k]), runs ARD for SKI, and predicts to k+1 with u[k]:

    inputs : z (n), C (n×n), [s (nw), SKI only], u, mem, y, valid (1/0 per output)
    outputs: z_post, C_post, [s_next], z_next, C_next, mem_next, e, Pyy, nis, loglik

C is the covariance P for the EKF and its lower Cholesky factor S for the UKF
and SKI. The same Functions feed the Python callables and the C emitter.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..model import Model
from .augment import Augmented, augment
from .common import FilterOptions
from .ekf import ekf_predict, ekf_update
from .ski import ard_step
from .ukf import ukf_predict, ukf_update

__all__ = ["FILTERS", "DerivedFilter", "FilterOptions", "augment", "derive"]

FILTERS = ("ekf", "ukf", "ski")


@dataclass(frozen=True)
class DerivedFilter:
    """A filter derived for one model: its step Function and initial values."""

    kind: str
    aug: Augmented
    options: FilterOptions
    step: ca.Function

    @property
    def square_root(self) -> bool:
        return self.kind != "ekf"

    def initial(self) -> dict[str, np.ndarray]:
        """The filter state before the first sample: z, C (and s for SKI), mem."""
        C = np.linalg.cholesky(self.aug.P0) if self.square_root else self.aug.P0.copy()
        state = dict(z=self.aug.z0.copy(), C=C, mem=np.zeros(self.aug.mem.shape[0]))
        if self.kind == "ski":
            state["s"] = self.aug.s0.copy()
        return state


def derive(model: Model | Augmented, kind: str, options: FilterOptions | None = None) -> DerivedFilter:
    """Derive the step Function of filter ``kind`` ('ekf', 'ukf' or 'ski')."""
    if kind not in FILTERS:
        raise ValueError(f"unknown filter '{kind}'; choose one of {', '.join(FILTERS)}")
    aug = model if isinstance(model, Augmented) else augment(model)
    opts = options or FilterOptions()
    d = aug.shapes
    if kind == "ski" and d["nw"] == 0:
        raise ValueError(f"model '{aug.model.name}' declares no unknown term: SKI needs basis weights")
    z, C = ca.SX.sym("z", d["n"]), ca.SX.sym("C", d["n"], d["n"])
    s = ca.SX.sym("s", d["nw"])
    u, mem = ca.SX.sym("u", d["nu"]), ca.SX.sym("mem", d["nmem"])
    y, valid = ca.SX.sym("y", d["ny"]), ca.SX.sym("valid", d["ny"])
    # Bind the model's own symbols for u and mem to the step's inputs.
    aug_b = _rebind(aug, u, mem)
    if kind == "ekf":
        z_post, C_post, e, Pyy, Ly = ekf_update(aug_b, z, C, u, mem, y, valid)
        z_next, C_next = ekf_predict(aug_b, z_post, C_post, u, mem)
    else:
        z_post, C_post, e, Pyy, Ly = ukf_update(aug_b, opts, z, C, u, mem, y, valid)
        if kind == "ski":
            z_post, C_post, s_next = ard_step(aug_b, opts, z_post, C_post, s)
        z_next, C_next = ukf_predict(aug_b, opts, z_post, C_post, u, mem)
    from .common import innovation_stats
    nis, loglik = innovation_stats(Ly, e, valid)
    mem_next = ca.substitute(aug.mem_next, ca.vertcat(aug.u, aug.mem), ca.vertcat(u, mem))
    ins, outs = [z, C], [z_post, C_post]
    names_in, names_out = ["z", "C"], ["z_post", "C_post"]
    if kind == "ski":
        ins.append(s); outs.append(s_next); names_in.append("s"); names_out.append("s_next")
    ins += [u, mem, y, valid]
    names_in += ["u", "mem", "y", "valid"]
    outs += [z_next, C_next, mem_next, e, Pyy, nis, loglik]
    names_out += ["z_next", "C_next", "mem_next", "e", "Pyy", "nis", "loglik"]
    step = ca.Function(f"{aug.model.name}_{kind}_step", ins, [ca.densify(o) for o in outs],
                       names_in, names_out)
    return DerivedFilter(kind, aug, opts, step)


def _rebind(aug: Augmented, u: ca.SX, mem: ca.SX) -> Augmented:
    """The augmented model with its input and memory symbols replaced."""
    old, new = ca.vertcat(aug.u, aug.mem), ca.vertcat(u, mem)
    sub = lambda e: ca.substitute(e, old, new)
    return Augmented(**{**aug.__dict__, "u": u, "mem": mem, "f": sub(aug.f), "h": sub(aug.h),
                        "mem_next": sub(aug.mem_next)})
