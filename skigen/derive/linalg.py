"""Dense linear algebra written out element by element on SX matrices.

CasADi's own SX factorisations are generic; these are the few the filters
need, written so that the generated code is a flat sequence of scalar
operations (no pivoting, no branches but ``if_else``):
lower Cholesky, the R factor of a Householder QR, rank-one Cholesky
update/downdate, and triangular solves.
"""
from __future__ import annotations

import casadi as ca

__all__ = ["chol", "tria", "cholupdate", "forward", "backward", "spd_solve", "symmetrize"]


def _grid(A: ca.SX) -> list[list[ca.SX]]:
    return [[A[i, j] for j in range(A.shape[1])] for i in range(A.shape[0])]


def _matrix(rows: list[list[ca.SX]]) -> ca.SX:
    return ca.vertcat(*[ca.horzcat(*r) for r in rows])


def symmetrize(P: ca.SX) -> ca.SX:
    return (P + P.T) / 2


def chol(P: ca.SX) -> ca.SX:
    """Lower Cholesky factor L of a symmetric positive-definite P (P = L Lᵀ)."""
    n = P.shape[0]
    L = [[ca.SX(0)] * n for _ in range(n)]
    for j in range(n):
        d = P[j, j] - sum((L[j][k] ** 2 for k in range(j)), ca.SX(0))
        L[j][j] = ca.sqrt(d)
        for i in range(j + 1, n):
            L[i][j] = (P[i, j] - sum((L[i][k] * L[j][k] for k in range(j)), ca.SX(0))) / L[j][j]
    return _matrix(L)


def tria(M: ca.SX) -> ca.SX:
    """Lower-triangular S with positive diagonal and S Sᵀ = M Mᵀ.

    The transposed R factor of a Householder QR of Mᵀ (M is n × k, k ≥ n).
    """
    n, k = M.shape
    A = _grid(M.T)  # k × n
    for c in range(n):
        x = [A[r][c] for r in range(c, k)]
        norm2 = sum((xi ** 2 for xi in x), ca.SX(0))
        alpha = ca.sqrt(norm2)
        sign = ca.if_else(x[0] >= 0, 1, -1)
        v = [x[0] + sign * alpha] + x[1:]
        vtv = ca.if_else(norm2 > 0, 2 * alpha * (alpha + ca.fabs(x[0])), 1)
        for j in range(c + 1, n):
            tau = 2 * sum((vi * A[c + i][j] for i, vi in enumerate(v)), ca.SX(0)) / vtv
            for i, vi in enumerate(v):
                A[c + i][j] = A[c + i][j] - tau * vi
        # Row c of R is (−sign·alpha, A[c][c+1:]); flip it so the diagonal is +alpha.
        A[c][c] = alpha
        for j in range(c + 1, n):
            A[c][j] = -sign * A[c][j]
    return _matrix([[A[j][i] if j <= i else ca.SX(0) for j in range(n)] for i in range(n)])


def cholupdate(L: ca.SX, x: ca.SX, sign: float) -> ca.SX:
    """Lower factor of L Lᵀ + sign·x xᵀ (sign = +1 update, −1 downdate)."""
    n = L.shape[0]
    L = _grid(L)
    x = [x[i] for i in range(n)]
    for k in range(n):
        r = ca.sqrt(L[k][k] ** 2 + sign * x[k] ** 2)
        c = r / L[k][k]
        s = x[k] / L[k][k]
        L[k][k] = r
        for i in range(k + 1, n):
            L[i][k] = (L[i][k] + sign * s * x[i]) / c
            x[i] = c * x[i] - s * L[i][k]
    return _matrix(L)


def forward(L: ca.SX, B: ca.SX) -> ca.SX:
    """Solve L X = B for lower-triangular L."""
    n, m = B.shape
    X = [[None] * m for _ in range(n)]
    for j in range(m):
        for i in range(n):
            X[i][j] = (B[i, j] - sum((L[i, k] * X[k][j] for k in range(i)), ca.SX(0))) / L[i, i]
    return _matrix(X)


def backward(U: ca.SX, B: ca.SX) -> ca.SX:
    """Solve U X = B for upper-triangular U."""
    n, m = B.shape
    X = [[None] * m for _ in range(n)]
    for j in range(m):
        for i in reversed(range(n)):
            X[i][j] = (B[i, j] - sum((U[i, k] * X[k][j] for k in range(i + 1, n)), ca.SX(0))) / U[i, i]
    return _matrix(X)


def spd_solve(L: ca.SX, B: ca.SX) -> ca.SX:
    """Solve (L Lᵀ) X = B given the lower Cholesky factor L."""
    return backward(L.T, forward(L, B))
