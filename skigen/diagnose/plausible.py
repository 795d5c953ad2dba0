"""Screen the named terms: a finding needs a coefficient the recording pins down and a sign
physics allows.

- *Not identifiable*: the coefficient's std is not finite, or the coefficient is within
  z·std of zero (z the two-sided normal quantile of α): the recording cannot tell it
  from nothing; the report says which signal would need more excitation. For a term
  searched over shapes the test is its probability of a zero coefficient averaged over
  the shapes (below α: identifiable); the spread of its value over the shapes is in its
  std, but says how large it is, not whether it is there. A structural
  change's parameter (a dead zone's width, a lag's time constant) is not identifiable
  when its likelihood profile has no maximum inside the searched range (no std); a
  delay of whole samples is a choice among them and needs none.
- *Compensating*: friction, drag and a physical limit only ever oppose the motion
  (a positive coefficient on their restoring form), and the total damping of an
  equation cannot be negative: a term that only helps with the impossible sign is
  compensating for something else (another missing effect, a wrong constant) and is
  reported as such, not as a finding.

The same sign rule is applied when :mod:`name` adopts a proposal
(:func:`compensating`), so that later rounds are never built on a term physics forbids.
"""
from __future__ import annotations

import re

import casadi as ca
import numpy as np
from scipy import stats

from ..model import Model
from ..recording import Recording

__all__ = ["screen", "nominal_damping", "compensating", "forbidden_sign", "significant", "term_item"]


def significant(coef: float, std: float, alpha: float) -> bool:
    """|coef| beyond z·std of 0, z the two-sided (1 − alpha) normal quantile; never with a std
    that is not finite and positive."""
    return bool(np.isfinite(std) and std > 0 and abs(coef) > stats.norm.isf(alpha / 2) * std)


def nominal_damping(model: Model, eq: str, states: np.ndarray, rec: Recording, rate=None) -> float:
    """−∂(rate of eq)/∂eq, the median along the trajectory (1/s): the damping the model already has,
    or, given ``rate`` (an added term's rate on eq), the damping that term adds per unit coefficient."""
    x = ca.vertcat(*[v.sym for v in model.states])
    u = ca.vertcat(*[v.sym for v in model.inputs]) if model.inputs else ca.SX(0, 1)
    me = model.state_names.index(eq)
    J = ca.jacobian(model.rhs[eq] if rate is None else rate, x[me])
    f = ca.Function("J", [x, u] + [p.sym for p in model.parameters], [J])
    vals = np.asarray(f.map(len(rec.t))(states[:, :len(model.states)].T, rec.inputs.T,
                                        *[p.value for p in model.parameters])).ravel()
    if model.discretization == "discrete" and rate is None:
        vals = (vals - 1.0) / model.dt
    return float(-np.median(vals))


def _signals(formula: str, model: Model) -> list[str]:
    names = set(model.state_names + model.input_names)
    return [n for n in dict.fromkeys(re.findall(r"[A-Za-z_]\w*", formula)) if n in names]


def term_item(c, coef: float, std: float, note: str) -> dict:
    """An additive term as report.json lists one that is not a finding (compensating, not identifiable)."""
    return {"effect": c.effect, "equation": c.equation, "expression": c.text, "coefficient": coef,
            "std": std, "note": note} | ({"through": c.through} if c.through else {})


def forbidden_sign(c, coef: float) -> bool:
    """Whether additive term ``c`` fits with a sign physics forbids (a drag that pushes the motion)."""
    return c.sign > 0 and coef < 0


def compensating(model: Model, c, coef: float, states: np.ndarray, rec: Recording) -> str | None:
    """Why additive term ``c`` at ``coef`` is compensating for something else, or None: a sign
    physics forbids, or a viscous damping that makes the equation's total damping negative."""
    if forbidden_sign(c, coef):
        return ("fits only with a sign physics forbids (it would push the motion instead of opposing it): "
                "compensating for something else")
    if c.effect == "viscous_damping":
        own = nominal_damping(model, c.equation, states, rec, c.contributions(model)[c.equation]) \
            if c.through else 1.0
        if coef * own + nominal_damping(model, c.equation, states, rec) < 0:
            return "would make the total damping negative: compensating for something else"
    return None


def screen(model: Model, corr, states: np.ndarray, rec: Recording, alpha: float,
           shapes: dict | None = None) -> tuple:
    """(the correction without implausible terms, {"compensating": [...], "not_identifiable": [...]}).
    ``shapes``: :func:`name.shape_search`'s summaries (their ``p_zero``)."""
    z, shapes = stats.norm.isf(alpha / 2), shapes or {}
    kept, comp, lost = [], [], []
    for c, coef, std in corr.additive:
        if c.parameter:                  # a declared parameter's correction: not judged
            kept.append((c, coef, std))
        elif not (shapes[c]["p_zero"] < alpha if c in shapes else significant(coef, std, alpha)):
            sig = _signals(c.formula, model) or [c.equation]
            why = (f"probability {shapes[c]['p_zero']:.2g} of a zero coefficient over its shapes" if c in shapes
                   else f"|coefficient| < {z:.2f} std")
            lost.append(term_item(c, coef, std, f"not identifiable from this recording ({why}): "
                                                f"excite {', '.join(sig)} over a wider range or for longer"))
        elif (why := compensating(model, c, coef, states, rec)) is not None:
            comp.append(term_item(c, coef, std, why))
        else:
            kept.append((c, coef, std))
    structural = []
    for s, value, std in corr.structural:
        if s.integer or np.isfinite(std):      # a whole number of samples is a choice, not a measurement
            structural.append((s, value, std))
            continue
        if min(s.grid) < value < max(s.grid):
            note = (f"not identifiable from this recording (the likelihood of its {s.parameter} has no maximum "
                    f"inside the range searched): excite {s.target} over a wider range")
        else:
            note = (f"not identifiable from this recording (its likelihood is best at an end of the range "
                    f"searched, {s.parameter} {value:.4g}, and may go on rising past it)")
        lost.append({"effect": s.effect, "equation": s.target, "expression": s.describe(value),
                     "coefficient": value, "std": std, "note": note})
    return type(corr)(kept, structural), {"compensating": comp, "not_identifiable": lost}
