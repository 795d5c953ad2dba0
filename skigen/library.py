"""Candidate basis libraries for the unknown term Δ(x, u) = Σ w_i φ_i(x, u).

A :class:`Term` is a named CasADi expression. Libraries are plain lists of
terms, so they concatenate with ``+`` and users add their own with
:func:`term`.
"""
from __future__ import annotations

import itertools
import re
from dataclasses import dataclass

import casadi as ca

__all__ = ["Term", "term", "constant", "polynomial", "abs_products", "delayed_inputs"]


@dataclass(frozen=True)
class Term:
    """One candidate basis function.

    name: how a person reads it (``"|theta|*p"``); key: an identifier used in
    weight names, CSV columns and C symbols (``"abs_theta_p"``); expr: a scalar
    SX, or a column SX with one entry per equation the term enters (a
    direction, e.g. drag along −v).
    """

    name: str
    key: str
    expr: ca.SX


def _key(name: str) -> str:
    key = re.sub(r"\W+", "_", name.replace("|", "abs_").replace("^", "")).strip("_")
    return key or "term"


def term(name: str, expr, key: str | None = None) -> Term:
    """A user-supplied candidate with a readable name and an expression."""
    return Term(name, key or _key(name), ca.SX(expr))


def constant() -> list[Term]:
    """The constant term (a bias)."""
    return [Term("1", "one", ca.SX(1))]


def _name(s: ca.SX) -> str:
    if not s.is_symbolic():
        raise TypeError(f"library terms need plain symbols, got expression {s}")
    return s.name()


def polynomial(symbols, degree: int, constant_term: bool = True) -> list[Term]:
    """All monomials of the given symbols up to ``degree`` (graded order)."""
    symbols = list(symbols)
    out = constant() if constant_term else []
    for d in range(1, degree + 1):
        for combo in itertools.combinations_with_replacement(range(len(symbols)), d):
            counts = [combo.count(i) for i in range(len(symbols))]
            parts = [(_name(symbols[i]), c) for i, c in enumerate(counts) if c]
            name = "*".join(n if c == 1 else f"{n}^{c}" for n, c in parts)
            key = "_".join(n if c == 1 else f"{n}{c}" for n, c in parts)
            expr = ca.SX(1)
            for i, c in enumerate(counts):
                if c:
                    expr = expr * symbols[i] ** c
            out.append(Term(name, key, expr))
    return out


def abs_products(pairs) -> list[Term]:
    """Products with an absolute value, ``|a|·b`` for each ``(a, b)`` pair."""
    out = []
    for a, b in pairs:
        na, nb = _name(a), _name(b)
        out.append(Term(f"|{na}|*{nb}", f"abs_{na}_{nb}", ca.fabs(a) * b))
    return out


def delayed_inputs(model, u: ca.SX, window: int) -> list[Term]:
    """Terms ``u[k], u[k-1], …, u[k-window+1]`` for a declared input ``u``.

    The model carries the past inputs as deterministic memory (shifted every
    sample, exact, with no covariance), so the window adds no filter state.
    """
    history = model.input_history(u, window - 1)
    name = _name(u)
    terms = [Term(f"{name}[k]", f"{name}_d0", u)]
    terms += [Term(f"{name}[k-{j}]", f"{name}_d{j}", h) for j, h in enumerate(history, 1)]
    return terms
