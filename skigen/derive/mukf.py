"""Marginalised (Rao-Blackwellised) square-root UKF, symbolic (Morelande & Moran, 2007).

For an augmented model that is affine in a substate z_l given the rest z_n,

    f(z) = d(z_n, u) + A(z_n, u) z_l,     h(z) = c(z_n, u) + C(z_n, u) z_l,

sigma points are drawn over z_n only (2·n_n + 1 of them) and the z_l part is
integrated exactly, given each point, from the joint Gaussian. With the prior
(m, P) written in [z_n; z_l] order with lower factor

    T = [[T_nn, 0], [T_ln, T_ll]],  T_nn T_nnᵀ = P_nn,  T_ll T_llᵀ = P_l|n = P_ll − P_ln P_nn⁻¹ P_nl,

the sigma point χ_i = m_n ± γ T_nn[:, j] has the conditional mean
m_l|i = m_l + P_ln P_nn⁻¹ (χ_i − m_n) = m_l ± γ T_ln[:, j], i.e. the full-state
point ζ_i = m ± γ T[:, j] (j < n_n), and the conditional covariance P_l|n (the
same for every point). With B_i = A(χ_i) T_ll, D_i = C(χ_i) T_ll (Jacobians of
f, h w.r.t. z_l, which do not depend on z_l), E_l the embedding of z_l in z:

    predict:  μ_i = f(ζ_i),   m⁻ = Σ Wm_i μ_i,
              P⁻ = Σ Wc_i (μ_i − m⁻)(μ_i − m⁻)ᵀ + Σ Wm_i B_i B_iᵀ + Q
    update:   η_i = h(ζ_i),   ŷ = Σ Wm_i η_i,
              Pyy = Σ Wc_i (η_i − ŷ)(η_i − ŷ)ᵀ + Σ Wm_i D_i D_iᵀ + R
              Pzy = Σ Wc_i (ζ_i − m)(η_i − ŷ)ᵀ + E_l T_ll (Σ Wm_i D_i)ᵀ
              K = Pzy Pyy⁻¹,  m⁺ = m + K (y − ŷ),  P⁺ = P − K Pyy Kᵀ

(the law of total covariance: the spread of the conditional means with the
covariance weights Wc, the mean of the conditional covariances with the mean
weights Wm). Everything is held as the lower Cholesky factor S of the full P
in the model's own state order: T = tria(S[order, :]), the covariances by one
QR of the stacked square roots plus rank-one updates/downdates for Wc_0 and a
negative Wm_0, and P⁺ by the rank-ny downdate of S, as in the square-root UKF.

Two exact shortcuts keep the generated code small: Σ Wm_i B_i B_iᵀ is written
B̄ B̄ᵀ + Σ Wm_i ΔB_i ΔB_iᵀ (B̄ = Σ Wm_i B_i; ΔB_i is zero outside the entries of
A that vary with z_n, so it takes a few columns, not n_l per point); and when h
is affine in the whole z the update needs no sigma point (the Merwe points
reproduce the mean and covariance of z_n exactly, so the marginalised update
is then the Kalman update whatever the split).

The conditional linearity is detected from the derived f and h
(:func:`partition`); the discretisation must keep it (Euler does, RK4 does not).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ..model import ModelError
from .common import measurement_factor, process_factor
from .linalg import cholupdate, tria
from .ukf import gain_update, merwe_weights

__all__ = ["Partition", "partition", "mukf_weights", "mukf_update", "mukf_predict"]

_EXACT_SEARCH_MAX = 40   # candidate components up to which the largest linear set is searched exactly


@dataclass(frozen=True)
class Partition:
    """The split of the augmented state z into z_n (sigma points) and z_l (exact).

    nonlinear, linear: indices into z, each in increasing order. reasons: for
    every component of z_n, why it cannot be in z_l (empty when it was put in
    z_n by the user's choice only).
    """

    names: tuple[str, ...]
    nonlinear: tuple[int, ...]
    linear: tuple[int, ...]
    reasons: dict = field(default_factory=dict)

    @property
    def nonlinear_names(self) -> list[str]:
        return [self.names[i] for i in self.nonlinear]

    @property
    def linear_names(self) -> list[str]:
        return [self.names[i] for i in self.linear]

    @property
    def sigma_points(self) -> int:
        return 2 * len(self.nonlinear) + 1

    def describe(self) -> str:
        lines = [f"z_n (sigma points, {self.sigma_points}): {', '.join(self.nonlinear_names) or '-'}",
                 f"z_l (exact, conditionally linear): {', '.join(self.linear_names) or '-'}"]
        lines += [f"  {self.names[i]}: {self.reasons[i]}" for i in self.nonlinear if self.reasons.get(i)]
        return "\n".join(lines)


def _dependence(aug):
    """For every component j of z: the components k such that ∂[f; h]/∂z_j depends on z_k,
    and for each such k a readable 'where' (the first row of f or h in which it happens)."""
    rows = ca.vertcat(aug.f, aug.h)
    row_names = [f"{nm}[k+1]" for nm in aug.names] + [f"output '{v.name}'" for v in aug.model.outputs]
    J = ca.jacobian(rows, aug.z)
    n = aug.n
    deps: list[dict[int, str]] = []
    for j in range(n):
        col = J[:, j]
        found = {}
        if col.nnz() and not col.is_constant():
            for k in range(n):
                if ca.depends_on(col, aug.z[k]):
                    r = next(r for r in range(rows.shape[0]) if ca.depends_on(J[r, j], aug.z[k]))
                    found[k] = row_names[r]
        deps.append(found)
    # Mixed second derivatives are symmetric; make the structural test symmetric too.
    for j in range(n):
        for k in list(deps[j]):
            deps[k].setdefault(j, deps[j][k])
    return deps


def _largest_independent(nodes, adj):
    """A largest subset of ``nodes`` with no two members adjacent (exact branch and bound;
    greedy by smallest degree beyond _EXACT_SEARCH_MAX connected candidates)."""
    nodes = frozenset(nodes)
    if sum(1 for v in nodes if adj[v] & nodes) > _EXACT_SEARCH_MAX:
        chosen, left = [], set(nodes)
        while left:
            v = min(left, key=lambda x: (len(adj[x] & left), x))
            chosen.append(v)
            left -= {v} | adj[v]
        return sorted(chosen)
    best: list[int] = []

    def search(cand: frozenset, chosen: list[int]):
        nonlocal best
        if len(chosen) + len(cand) <= len(best):
            return
        v = max(cand, key=lambda x: (len(adj[x] & cand), -x), default=None)
        if v is None or not adj[v] & cand:          # what is left is independent
            best = chosen + sorted(cand)
            return
        search(cand - {v} - adj[v], chosen + [v])    # v in z_l
        search(cand - {v}, chosen)                   # v in z_n

    search(nodes, [])
    return sorted(best)


def partition(aug, linear=None) -> Partition:
    """Split z into z_n and the largest conditionally linear z_l (or the user's ``linear`` names).

    Rule: z_l is admissible iff the Jacobian of [f; h] w.r.t. z_l does not depend on
    any component of z_l — f and h are then jointly affine in z_l given z_n. A
    component whose own Jacobian column depends on itself is never linear; two
    components whose mixed second derivative is not zero (a cross term such as
    z_j z_k) cannot both be linear; among the rest the largest admissible set is
    chosen (exactly, by branch and bound). Raises ModelError naming the reasons when
    no component is conditionally linear, or when ``linear`` is not admissible.
    """
    deps = _dependence(aug)
    names, n = tuple(aug.names), aug.n
    self_nl = {j for j in range(n) if j in deps[j]}
    adj = {j: set(deps[j]) - {j} for j in range(n)}
    if linear is None:
        cand = [j for j in range(n) if j not in self_nl]
        lin = _largest_independent(cand, adj)
    else:
        linear = [linear] if isinstance(linear, str) else list(linear)
        if not linear:
            raise ModelError(f"model '{aug.model.name}': linear=[] leaves the MUKF nothing to marginalise: "
                             f"name at least one state (None: the largest conditionally linear substate)")
        unknown = [nm for nm in linear if nm not in names]
        if unknown:
            raise ModelError(f"model '{aug.model.name}': linear substate names {unknown} are not states "
                             f"or weights (have: {', '.join(names)})")
        lin = sorted({names.index(nm) for nm in linear})
        for j in lin:
            if j in self_nl:
                raise ModelError(f"model '{aug.model.name}': '{names[j]}' cannot be in the linear substate: "
                                 f"{_why(names, j, j, deps)}")
            clash = sorted(adj[j] & set(lin))
            if clash:
                raise ModelError(f"model '{aug.model.name}': '{names[j]}' and '{names[clash[0]]}' cannot both be "
                                 f"in the linear substate: {_why(names, j, clash[0], deps)}")
    lin_set = set(lin)
    reasons = {}
    for j in range(n):
        if j in lin_set:
            continue
        if j in self_nl:
            reasons[j] = _why(names, j, j, deps)
        elif adj[j] & lin_set:
            reasons[j] = _why(names, j, min(adj[j] & lin_set), deps)
        else:
            reasons[j] = ""
    part = Partition(names, tuple(j for j in range(n) if j not in lin_set), tuple(lin), reasons)
    if not lin:
        why = "; ".join(f"{names[j]}: {reasons[j] or 'not chosen'}" for j in range(n))
        raise ModelError(f"model '{aug.model.name}' has no conditionally linear substate, so the MUKF "
                         f"has nothing to marginalise (use 'ukf'/'ski'): {why}. A component is linear when "
                         f"the Jacobian of f and h with respect to the linear block does not depend on "
                         f"that block; an RK4 discretisation usually breaks this, Euler keeps it.")
    return part


def _why(names, j, k, deps) -> str:
    where = deps[j][k]
    if j == k:
        return f"d {where}/d {names[j]} depends on {names[j]} (not affine in it)"
    return f"d {where}/d {names[j]} depends on {names[k]} (a cross term {names[j]}·{names[k]})"


def mukf_weights(n_n: int, opts):
    """(Wm, Wc, gamma) over the nonlinear substate; one point of weight 1 when it is empty."""
    if n_n == 0:
        return np.ones(1), np.ones(1), 0.0
    return merwe_weights(n_n, opts.alpha, opts.beta, opts.kappa)


def _conditional(part, z, S, gamma):
    """Full-state points ζ_i, the embedded conditional factor L = E_l T_ll and T_ll."""
    order = list(part.nonlinear) + list(part.linear)
    n, nn = len(order), len(part.nonlinear)
    T = S if order == list(range(n)) else tria(S[order, :])
    U = ca.SX.zeros(n, n)
    U[order, :] = T                                    # rows back to the model's order
    cols = [U[:, j] for j in range(nn)]
    points = [z] + [z + gamma * c for c in cols] + [z - gamma * c for c in cols]
    return points, U[:, nn:], T[nn:, nn:]


def _factor(devs, Mbar, dpos, dneg, extra, Wc):
    """Lower factor of Σ Wc_i dev_i dev_iᵀ + Mbar Mbarᵀ + dpos dposᵀ − dneg dnegᵀ + extra extraᵀ.

    Wc_i > 0 for i ≥ 1; Wc_0 enters as a rank-one update (downdate when negative),
    dneg (from a negative Wm_0) as rank-one downdates.
    """
    cols = [np.sqrt(Wc[i]) * devs[i] for i in range(1, len(devs))]
    S = tria(ca.horzcat(*cols, Mbar, dpos, extra))
    if len(devs) > 1 and Wc[0] != 0:
        S = cholupdate(S, np.sqrt(abs(Wc[0])) * devs[0], float(np.sign(Wc[0])))
    for j in range(dneg.shape[1]):
        S = cholupdate(S, dneg[:, j], -1.0)
    return S


def _varying(aug, part, expr):
    """Mask of the entries of ∂expr/∂z_l that depend on z_n (the others are the same at every point)."""
    J = ca.jacobian(expr, aug.z[list(part.linear)])
    zn = aug.z[list(part.nonlinear)] if part.nonlinear else None
    return np.array([[zn is not None and ca.depends_on(J[r, c], zn) for c in range(J.shape[1])]
                     for r in range(J.shape[0])], dtype=bool).reshape(J.shape)


def _conditional_terms(Gs, mask, Wm, Tll):
    """Σ Wm_i G_i P_l|n G_iᵀ in square-root pieces, G_i = ∂g/∂z_l at point i.

    With Ḡ = Σ Wm_i G_i and ΔG_i = G_i − Ḡ (Σ Wm_i ΔG_i = 0, so the cross terms vanish):
    Σ Wm_i G_i P_l|n G_iᵀ = Ḡ T_ll (Ḡ T_ll)ᵀ + Σ Wm_i ΔG_i P_l|n ΔG_iᵀ. ΔG_i is zero outside
    the entries that vary with z_n — rows W, columns V — so the second sum is a |W|×|W|
    block: Σ_i Wm_i ΔG_i[W, V] R_V (…)ᵀ with R_V R_Vᵀ = P_l|n[V, V], whose factor one QR
    over the points compresses to |W| columns. Returns (Ḡ T_ll, dpos, dneg), dpos dposᵀ the
    positive-weight part and dneg dnegᵀ the part of a negative Wm_0 (both n_rows × ·)."""
    nr = Gs[0].shape[0]
    Gbar = ca.SX(Gs[0])
    rows, cols = np.nonzero(mask)
    for r, c in zip(rows, cols):
        Gbar[r, c] = sum((w * G[r, c] for w, G in zip(Wm, Gs)), ca.SX(0))
    W, V = sorted(set(rows.tolist())), sorted(set(cols.tolist()))
    empty = ca.SX.zeros(nr, 0)
    if not V:
        return Gbar @ Tll, empty, empty
    R_V = tria(Tll[V, :])

    def block(G, w):
        D = ca.SX.zeros(len(W), len(V))
        for r, c in zip(rows, cols):
            D[W.index(r), V.index(c)] = G[r, c] - Gbar[r, c]
        return np.sqrt(abs(w)) * D @ R_V

    def embed(M):
        if M.shape[1] > len(W):                  # compress to |W| columns
            M = tria(M)
        E = ca.SX.zeros(nr, M.shape[1])
        E[W, :] = M
        return E

    pos = [block(G, w) for G, w in zip(Gs, Wm) if w > 0]
    neg = [block(G, w) for G, w in zip(Gs, Wm) if w < 0]
    return (Gbar @ Tll, embed(ca.horzcat(*pos)) if pos else empty,
            embed(ca.horzcat(*neg)) if neg else empty)


def _functions(aug, part):
    """[f, ∂f/∂z_l](z, u, mem) and [h, ∂h/∂z_l](z, u, mem)."""
    args = [aug.z, aug.u, aug.mem]
    zl = aug.z[list(part.linear)]
    return (ca.Function("Fl", args, [aug.f, ca.jacobian(aug.f, zl)]),
            ca.Function("Hl", args, [aug.h, ca.jacobian(aug.h, zl)]))


def _update_partition(aug, part):
    """The split used by the update: when h is affine in the whole z (its Jacobian is
    constant), no sigma point is needed — the marginalised update with any split then
    equals the exact linear (Kalman) update, since the points reproduce the mean and
    covariance of z_n exactly; otherwise the filter's split."""
    if not ca.depends_on(ca.jacobian(aug.h, aug.z), aug.z):
        return Partition(part.names, (), tuple(range(aug.n)), {})
    return part


def mukf_update(aug, part, opts, z, S, u, mem, y, valid):
    """Measurement update. Returns z⁺, S⁺, e, Pyy, Sy (as ukf_update)."""
    S = ca.tril(S)                        # a lower factor by contract: its upper zeros are structural
    part = _update_partition(aug, part)
    _, H = _functions(aug, part)
    Wm, Wc, gamma = mukf_weights(len(part.nonlinear), opts)
    X, L, Tll = _conditional(part, z, S, gamma)
    V = ca.diag(valid)
    Y, Cs = [], []
    for x in X:
        hx, Cx = H(x, u, mem)
        Y.append(valid * hx)
        Cs.append(V @ Cx)
    y_hat = sum((w * yi for w, yi in zip(Wm, Y)), ca.SX.zeros(aug.h.shape[0]))
    dY = [yi - y_hat for yi in Y]
    CT, dpos, dneg = _conditional_terms(Cs, _varying(aug, part, aug.h), Wm, Tll)
    Sy = _factor(dY, CT, dpos, dneg, measurement_factor(aug, valid), Wc)
    Pzy = L @ CT.T
    for w, x, d in zip(Wc[1:], X[1:], dY[1:]):
        Pzy += w * (x - z) @ d.T
    return gain_update(z, S, Sy, Pzy, valid * y - y_hat)


def mukf_predict(aug, part, opts, z, S, u, mem):
    """Time update. Returns z⁻, S⁻."""
    S = ca.tril(S)
    F, _ = _functions(aug, part)
    Wm, Wc, gamma = mukf_weights(len(part.nonlinear), opts)
    X, _, Tll = _conditional(part, z, S, gamma)
    M, As = [], []
    for x in X:
        fx, Ax = F(x, u, mem)
        M.append(fx)
        As.append(Ax)
    z_next = sum((w * m for w, m in zip(Wm, M)), ca.SX.zeros(aug.n))
    AT, dpos, dneg = _conditional_terms(As, _varying(aug, part, aug.f), Wm, Tll)
    S_next = _factor([m - z_next for m in M], AT, dpos, dneg, process_factor(aug), Wc)
    return z_next, S_next
