"""Python source of a CasADi SX expression, exact (constants in full precision).

``to_python(expr)`` gives text that evaluates back to the same expression when
the symbols' names are bound and ``ca`` is casadi, e.g.
``((F - 0.5 * v) - 2.0 * p) / 1.2 + 0.3021 * -ca.tanh(v / 0.00507)``.
Shared subexpressions are written out again where they are used.
"""
from __future__ import annotations

import casadi as ca

__all__ = ["to_python", "UnsupportedExpression"]


class UnsupportedExpression(ValueError):
    """An SX operation with no Python spelling here (the message names it)."""


_BINARY = {ca.OP_ADD: ("+", 1), ca.OP_SUB: ("-", 1), ca.OP_MUL: ("*", 2), ca.OP_DIV: ("/", 2)}
_CALL1 = {ca.OP_EXP: "exp", ca.OP_LOG: "log", ca.OP_SQRT: "sqrt", ca.OP_SIN: "sin", ca.OP_COS: "cos",
          ca.OP_TAN: "tan", ca.OP_ASIN: "asin", ca.OP_ACOS: "acos", ca.OP_ATAN: "atan",
          ca.OP_FLOOR: "floor", ca.OP_CEIL: "ceil", ca.OP_FABS: "fabs", ca.OP_SIGN: "sign",
          ca.OP_ERF: "erf", ca.OP_SINH: "sinh", ca.OP_COSH: "cosh", ca.OP_TANH: "tanh",
          ca.OP_ASINH: "asinh", ca.OP_ACOSH: "acosh", ca.OP_ATANH: "atanh", ca.OP_LOG1P: "log1p",
          ca.OP_EXPM1: "expm1", ca.OP_NOT: "logic_not"}
_CALL2 = {ca.OP_FMIN: "fmin", ca.OP_FMAX: "fmax", ca.OP_ATAN2: "atan2", ca.OP_FMOD: "fmod",
          ca.OP_COPYSIGN: "copysign", ca.OP_HYPOT: "hypot", ca.OP_POW: "power",
          ca.OP_CONSTPOW: "power", ca.OP_LT: "lt", ca.OP_LE: "le",
          ca.OP_EQ: "eq", ca.OP_NE: "ne", ca.OP_AND: "logic_and", ca.OP_OR: "logic_or"}
_ATOM = 5


def _p(text_prec, need: int, right: bool = False) -> str:
    text, prec = text_prec
    return f"({text})" if prec < need or (right and prec == need) else text


def _print(e: ca.SX) -> tuple[str, int]:
    if e.is_constant():
        v = float(e)
        return (repr(v), _ATOM) if v >= 0 else (repr(v), 3)
    if e.is_symbolic():
        return e.name(), _ATOM
    op = e.op()
    if op in _BINARY:
        sym, prec = _BINARY[op]
        a, b = _print(e.dep(0)), _print(e.dep(1))
        return f"{_p(a, prec)} {sym} {_p(b, prec, right=True)}", prec
    if op == ca.OP_NEG:
        return f"-{_p(_print(e.dep(0)), 3)}", 3
    if op == ca.OP_SQ:
        return f"{_p(_print(e.dep(0)), _ATOM)} ** 2", 4
    if op == ca.OP_TWICE:
        return f"2 * {_p(_print(e.dep(0)), 2)}", 2
    if op == ca.OP_INV:
        return f"1 / {_p(_print(e.dep(0)), 2, right=True)}", 2
    if op == ca.OP_IF_ELSE_ZERO:
        return f"ca.if_else({_print(e.dep(0))[0]}, {_print(e.dep(1))[0]}, 0)", _ATOM
    if op in _CALL1:
        return f"ca.{_CALL1[op]}({_print(e.dep(0))[0]})", _ATOM
    if op in _CALL2:
        return f"ca.{_CALL2[op]}({_print(e.dep(0))[0]}, {_print(e.dep(1))[0]})", _ATOM
    raise UnsupportedExpression(f"cannot write operation {op} of {e} as Python")


def to_python(expr) -> str:
    """Python source for a scalar SX expression (see the module docstring)."""
    expr = ca.SX(expr)
    if expr.shape != (1, 1):
        raise UnsupportedExpression(f"expected a scalar, got shape {expr.shape}")
    return _print(expr)[0]
