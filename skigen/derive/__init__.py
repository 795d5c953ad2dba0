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

import copy
from dataclasses import dataclass, replace
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
    def tunable(self) -> ca.Function:
        """The step with the run-time settings as further inputs (the generated C's kernel):
        the lower-triangular factors ``Q_sqrt`` (n×n, Q = Q_sqrt Q_sqrtᵀ) and ``R_sqrt`` (ny×ny,
        R = R_sqrt R_sqrtᵀ; their upper triangles are ignored) and ``param``, the declared
        parameters not estimated (:attr:`Augmented.fixed_names`)."""
        return _step(self)

    @cached_property
    def step(self) -> ca.Function:
        """The step Function (see the module docstring) at the declared Q, R and parameters."""
        t = self.tunable
        ins = [ca.SX.sym(name, t.size_in(i)) for i, name in enumerate(self.names_in)]
        return ca.Function(t.name(), ins, t.call(ins + [ca.DM(v) for v in self.settings().values()]),
                           self.names_in, self.names_out)

    def at(self, **values: float) -> "DerivedFilter":
        """The filter of the same model with declared parameters it does not estimate at other
        ``values`` (name=value): the tunable step is shared, not derived again, and the steps
        differ only in constants, so chained runs share one chain (:mod:`skigen.runtime`)."""
        aug, names = self.aug, self.aug.fixed_names
        unknown = [n for n in values if n not in names]
        if unknown:
            raise ValueError(f"model '{aug.model.name}' has no fixed parameter {', '.join(map(repr, unknown))} "
                             f"(fixed: {', '.join(names) or 'none'})")
        model = copy.copy(aug.model)
        model.parameters = list(aug.model.parameters)
        model.set_parameters(values)
        fixed = np.array([values.get(n, v) for n, v in zip(names, aug.fixed_values)], float)
        f, h = (ca.substitute(_or(free, e), aug.fixed, ca.DM(fixed))
                for free, e in ((aug.f_free, aug.f), (aug.h_free, aug.h)))
        new = replace(self, aug=replace(aug, model=model, fixed_values=fixed, f=f, h=h))
        new.__dict__["tunable"] = self.tunable            # a cached_property: the shared derivation
        return new

    def settings(self) -> dict[str, np.ndarray]:
        """The declared values of the tunable step's settings: the lower Cholesky factors Q_sqrt
        (zero columns where Q is singular) and R_sqrt, and param."""
        from ..guard import chol_psd
        return dict(Q_sqrt=chol_psd(self.aug.Q), R_sqrt=np.linalg.cholesky(self.aug.R),
                    param=self.aug.fixed_values.copy())

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

    def size_refusal(self, u, y) -> str | None:
        """Why a step cannot take input u and readings y (1-D): a length not the model's; None when it can."""
        m = self.aug.model
        return "; ".join(f"step: {what} has {len(v)} value(s), the model '{m.name}' {len(names)} ({', '.join(names)})"
                         for what, v, names in (("u", u, m.input_names), ("y", y, m.output_names))
                         if len(v) != len(names)) or None

    def start_refusal(self, z, C) -> str | None:
        """Why the step cannot start from mean z and C (P, or its lower factor S), as
        ``<prefix>_reset`` refuses it; None when it can. Either may be None (the declared one)."""
        n = self.aug.n
        if z is not None and np.shape(z) not in ((n,), (n, 1)):
            return f"z0 has shape {np.shape(z)}; the filter's state has {n} entries ({', '.join(self.aug.names)})"
        if z is not None and not np.all(np.isfinite(z)):
            return "z0 has a non-finite entry"
        if C is None:
            return None
        C = np.asarray(C, float)
        if C.shape != (n, n):
            return f"C0 has shape {C.shape}; the filter's state needs ({n}, {n})"
        tol, d = 100 * np.finfo(float).eps, np.diag(C)
        r = np.sqrt(np.where(d > 0, d, 1.0))          # P scaled to unit diagonal (a 0 row stays 0)
        if self.square_root:
            if not np.all(np.isfinite(C)) or np.any(d < 0) or np.any(np.triu(C, 1)):
                return "C0 is not a lower Cholesky factor S: an entry non-finite, negative on the diagonal or non-zero above it"
        elif not (np.all(np.isfinite(C)) and np.all(d >= 0) and np.all(np.abs(C - C.T) <= tol * np.sqrt(np.outer(d, d)))
                  and np.linalg.eigvalsh(C / np.outer(r, r)).min() >= -tol * len(C)):
            return ("C0 is not a covariance P: an entry non-finite or negative on the diagonal, or it is not "
                    "symmetric positive semi-definite")
        from .ski import bounded_by_prior
        if self.has_ard and bounded_by_prior(self.aug, self.options):
            w = self.aug.w_index
            P = C[w] @ C[w].T if self.square_root else C[np.ix_(w, w)]
            if np.linalg.eigvalsh(np.diag(self.aug.s0) - P).min() < -100 * np.finfo(float).eps * self.aug.s0.max():
                return ("C0's weight block is not within the ARD prior, P_ww <= diag(s0) (the EM update's "
                        "bound: updates only shrink P_ww): start from a saved posterior's weight rows, or scale them down")
        return None

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
        raise ValueError(f"model '{aug.model.name}' declares no unknown term: SKI needs basis weights "
                         f"(model.unknown(...)); the EKF or UKF runs the model as declared, and estimates its "
                         f"parameters online with estimate=")
    part = partition(aug, linear) if kind in MUKF_KINDS else None
    return DerivedFilter(kind, aug, opts, part)


def default_filter(model: Model) -> str:
    """The filter a run takes when none is named: SKI where ``model`` declares unknown terms (its
    basis weights), else the UKF (the model as declared)."""
    return "ski" if model.unknowns else "ukf"


def _step(filt: DerivedFilter) -> ca.Function:
    """Build the tunable step Function of ``filt`` symbolically."""
    kind, aug, opts, part = filt.kind, filt.aug, filt.options, filt.partition
    d = aug.shapes
    z, C = ca.SX.sym("z", d["n"]), ca.SX.sym("C", d["n"], d["n"])
    s = ca.SX.sym("s", d["nw"])
    u_in, mem = ca.SX.sym("u", d["nu"]), ca.SX.sym("mem", d["nmem"])
    y, valid = ca.SX.sym("y", d["ny"]), ca.SX.sym("valid", d["ny"])
    Q_sqrt, R_sqrt = ca.SX.sym("Q_sqrt", d["n"], d["n"]), ca.SX.sym("R_sqrt", d["ny"], d["ny"])
    lower = dict(Q_sqrt=ca.tril(Q_sqrt), R_sqrt=ca.tril(R_sqrt))      # upper triangles ignored
    param = ca.SX.sym("param", aug.fixed.shape[0])
    # Bind the model's own symbols for u, mem and the fixed parameters to the step's inputs; the
    # parameters ride along the inputs (u = [u; param]) through every filter's model calls.
    u = ca.vertcat(u_in, param)
    aug_b = _rebind(aug, u_in, mem, param, lower["Q_sqrt"], lower["R_sqrt"])
    if kind == "ekf":
        z_post, C_post, e, Pyy, Ly = ekf_update(aug_b, z, C, u, mem, y, valid)
        z_next, C_next = ekf_predict(aug_b, z_post, C_post, u, mem, opts.second_order)
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
    mem_next = ca.substitute(aug.mem_next, ca.vertcat(aug.u, aug.mem), ca.vertcat(u_in, mem))
    values = dict(z=z, C=C, s=s, u=u_in, mem=mem, y=y, valid=valid, z_post=z_post, C_post=C_post,
                  z_next=z_next, C_next=C_next, mem_next=mem_next, e=e, Pyy=Pyy, nis=nis, loglik=loglik,
                  Q_sqrt=Q_sqrt, R_sqrt=R_sqrt, param=param)
    if filt.has_ard:
        values["s_next"] = s_next
    names_in = filt.names_in + list(TUNABLE)
    return ca.Function(f"{aug.model.name}_{kind}_step", [values[k] for k in names_in],
                       [ca.densify(values[k]) for k in filt.names_out], names_in, filt.names_out)


TUNABLE = ("Q_sqrt", "R_sqrt", "param")     # the tunable step's inputs after the step's own


def _rebind(aug: Augmented, u, mem, param, Q_sqrt, R_sqrt) -> Augmented:
    """The augmented model on the step's symbols: inputs [u; param], memory, noise factors."""
    old, new = ca.vertcat(aug.u, aug.mem, aug.fixed), ca.vertcat(u, mem, param)
    sub = lambda e: ca.substitute(e, old, new)
    return Augmented(**{**aug.__dict__, "u": ca.vertcat(u, param), "mem": mem, "f": sub(_or(aug.f_free, aug.f)),
                        "h": sub(_or(aug.h_free, aug.h)), "mem_next": sub(aug.mem_next), "Q_sqrt": Q_sqrt, "R_sqrt": R_sqrt})


def _or(a, b):
    return b if a is None else a
