"""Dense linear algebra on SX matrices, a column or row at a time.

CasADi's own SX factorisations are generic; these are the few the filters
need, written so that the generated code is a flat sequence of scalar
operations (no pivoting, no branches but ``if_else``): lower Cholesky, the R
factor of a Householder QR, rank-one Cholesky update/downdate, and triangular
solves. Each works on whole columns or rows with SX matrix operations, so
CasADi (not Python) loops over the elements.
"""
from __future__ import annotations

import casadi as ca

__all__ = ["chol", "tria", "cholupdate", "forward", "backward", "spd_solve", "symmetrize"]


def symmetrize(P: ca.SX) -> ca.SX:
    return (P + P.T) / 2


def chol(P: ca.SX) -> ca.SX:
    """Lower Cholesky factor L of a symmetric positive-definite P (P = L Lᵀ)."""
    n = P.shape[0]
    L = ca.SX.zeros(n, n)
    for j in range(n):
        row = L[j, :j]
        L[j, j] = ca.sqrt(P[j, j] - ca.dot(row, row))
        if j + 1 < n:
            L[j + 1:, j] = (P[j + 1:, j] - L[j + 1:, :j] @ row.T) / L[j, j]
    return L


def tria(M: ca.SX) -> ca.SX:
    """Lower-triangular S with positive diagonal and S Sᵀ = M Mᵀ.

    The transposed R factor of a Householder QR of Mᵀ (M is n × k, k ≥ n).
    """
    n, k = M.shape
    A = M.T                                       # k × n, reflected column by column
    R = ca.SX.zeros(n, n)
    for c in range(n):
        x = A[c:, c]
        norm2 = ca.dot(x, x)
        alpha = ca.sqrt(norm2)
        sign = ca.if_else(x[0] >= 0, 1, -1)
        v = ca.vertcat(x[0] + sign * alpha, x[1:])
        vtv = ca.if_else(norm2 > 0, 2 * alpha * (alpha + ca.fabs(x[0])), 1)
        if c + 1 < n:
            tau = 2 * (v.T @ A[c:, c + 1:]) / vtv
            A[c:, c + 1:] = A[c:, c + 1:] - v @ tau
            # Row c of R is (−sign·alpha, A[c, c+1:]); flip it so the diagonal is +alpha.
            R[c, c + 1:] = -sign * A[c, c + 1:]
        R[c, c] = alpha
    return R.T


def cholupdate(L: ca.SX, x: ca.SX, sign: float) -> ca.SX:
    """Lower factor of L Lᵀ + sign·x xᵀ (sign = +1 update, −1 downdate)."""
    n = L.shape[0]
    L, x = ca.SX(L), ca.SX(x)
    for k in range(n):
        r = ca.sqrt(L[k, k] ** 2 + sign * x[k] ** 2)
        c = r / L[k, k]
        s = x[k] / L[k, k]
        L[k, k] = r
        if k + 1 < n:
            col = (L[k + 1:, k] + sign * s * x[k + 1:]) / c
            x[k + 1:] = c * x[k + 1:] - s * col
            L[k + 1:, k] = col
    return L


def forward(L: ca.SX, B: ca.SX) -> ca.SX:
    """Solve L X = B for lower-triangular L."""
    n = B.shape[0]
    X = ca.SX(B)
    for i in range(n):
        X[i, :] = (B[i, :] - L[i, :i] @ X[:i, :]) / L[i, i]
    return X


def backward(U: ca.SX, B: ca.SX) -> ca.SX:
    """Solve U X = B for upper-triangular U."""
    n = B.shape[0]
    X = ca.SX(B)
    for i in reversed(range(n)):
        X[i, :] = (B[i, :] - U[i, i + 1:] @ X[i + 1:, :]) / U[i, i]
    return X


def spd_solve(L: ca.SX, B: ca.SX) -> ca.SX:
    """Solve (L Lᵀ) X = B given the lower Cholesky factor L."""
    return backward(L.T, forward(L, B))
