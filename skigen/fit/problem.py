"""The likelihood of a model's free quantities given recordings, as one CasADi NLP.

The free quantities θ are the estimated parameters and unknown-term weights
(shared by every recording), the initial state of each recording (output
error: at every shooting node) and the log noise scales (filter error: one per
state equation with process noise, one per output). IPOPT works on scaled
variables ξ = θ / scale, the scale being part of the NLP's parameter (see
:func:`skigen.fit.fit` for how it is chosen), so parameters of very different
sizes are equally conditioned.

Both methods are a Gaussian likelihood of per-sample residuals e_k with
covariance S_k, −log L = ½ Σ (e_kᵀ S_k⁻¹ e_k + log det 2π S_k):

- output error: e_k = y_k − h(x_k) of the free-run simulation, S = R as
  declared (multiple shooting: one simulation per interval, continuity as
  equality constraints);
- filter error: e_k is the EKF innovation and S_k its covariance, with Q
  and R scaled per equation and per output.

A declared parameter std adds its prior ½ ((p − value)/std)². IPOPT gets the
Fisher-scoring (Gauss-Newton) Hessian J_ρᵀ J_ρ (plus, with multiple shooting,
the exact curvature of the continuity constraints) of whitened pseudo-residuals
ρ_k = [L̄⁻¹ e_k; vec(L̄⁻¹ S_k L̄⁻ᵀ)/√2] (L̄ the Cholesky factor of S_k, held
constant): positive semi-definite, exact in expectation, and a few forward
sweeps per iteration instead of a second-order sweep over the recording. The
same sweep gives the gradient, Jᵀ r (:func:`_pseudo_residuals`), so one
evaluation per iterate serves both (:class:`_LastPoint`).
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from types import SimpleNamespace

import casadi as ca
import numpy as np

from ..derive.augment import augment, memory_values, step_inputs
from ..derive.common import innovation_stats, masked_noise_factor
from ..derive.ekf import ekf_predict, ekf_update
from ..derive.linalg import chol, forward
from ..model import Model
from ..runtime import INLINE_BELOW

__all__ = ["METHODS", "Variables", "Problem", "build_problem", "data_matrix"]

METHODS = ("output-error", "filter-error")
LOG_SCALE_BOUND = 25.0      # noise scales stay within e^±25 of the declared variances


@dataclass
class Variables:
    """The free quantities in IPOPT's order: name, kind, scale, bounds (unscaled) and initial value."""

    names: list[str] = field(default_factory=list)
    kinds: list[str] = field(default_factory=list)     # parameter, weight, initial, noise
    scale: list[float] = field(default_factory=list)
    lower: list[float] = field(default_factory=list)
    upper: list[float] = field(default_factory=list)
    initial: list[float] = field(default_factory=list)
    prior_std: list[float | None] = field(default_factory=list)
    node: list[tuple | None] = field(default_factory=list)   # initial states: (state, recording, interval)

    def add(self, name, kind, scale, initial, lower=-np.inf, upper=np.inf, prior_std=None, node=None):
        self.names.append(name)
        self.kinds.append(kind)
        self.scale.append(float(scale))
        self.initial.append(float(initial))
        self.lower.append(float(lower))
        self.upper.append(float(upper))
        self.prior_std.append(prior_std)
        self.node.append(node)

    def __len__(self) -> int:
        return len(self.names)


@dataclass
class Problem:
    """The NLP and the functions the fit needs around it."""

    method: str
    variables: Variables
    solver_inputs: dict            # lbx, ubx, lbg, ubg, x0 (unscaled)
    nlp: dict                      # x (scaled), p = [scale; data; (filter error) each recording's
                                   #   start [x; vec P]], f, g (MX)
    residuals: ca.Function         # (ξ, data) → ρ (pseudo-residuals, one column per sample), nll per sample
    fisher: ca.Function            # (ξ, data) → J_ρ (rows: samples × residuals), prior precision
    predict: ca.Function           # (ξ, data) → predicted outputs, one column per sample
    filtered: ca.Function | None   # output error: (θ, data per recording) → the EKF's posterior state,
                                   #   one column per sample, recordings one after another
    lengths: list[int]             # samples per recording
    shooting: int                  # samples per shooting interval (output error)
    progress: object = None        # the solver's iteration callback
    decrement: ca.Function = None  # (ξ, data) → gradient of −log L, its Fisher information
    objective: ca.Function = None  # (ξ, data) → −log L (with the priors): the NLP's f alone


def _scale_of(value: float, std: float | None) -> float:
    return abs(value) if value != 0 else (std or 1.0)


def _plant(model: Model, estimate: list[str]):
    """x, θ = [weights; estimated parameters], the step's data symbols and f_x, h as SX."""
    aug = augment(model, [n for n in estimate if n in model.parameter_names], online=False)
    nx = len(model.states)
    x, theta = aug.z[:nx], aug.z[nx:]
    return aug, x, theta


def data_matrix(model: Model, rec) -> np.ndarray:
    """One column per sample: [step inputs; input history; y (0 where missing); valid (1/0)]."""
    Y = np.asarray(rec.outputs, float)
    valid = np.isfinite(Y)
    return np.hstack([step_inputs(model, rec.inputs), memory_values(model, rec.inputs),
                      np.where(valid, Y, 0.0), valid.astype(float)]).T


def _split_data(aug, d):
    nu, nmem, ny = aug.u.shape[0], aug.mem.shape[0], aug.h.shape[0]
    return d[:nu], d[nu:nu + nmem], d[nu + nmem:nu + nmem + ny], d[nu + nmem + ny:]


def _output_error_step(aug, x, theta):
    """(x, d, θ) → (x_next, ρ, nll, ŷ): one sample of the free-run simulation."""
    d = ca.SX.sym("d", aug.u.shape[0] + aug.mem.shape[0] + 2 * aug.h.shape[0])
    u, mem, y, valid = _split_data(aug, d)
    sub = lambda e: ca.substitute(e, ca.vertcat(aug.u, aug.mem), ca.vertcat(u, mem))
    y_hat = sub(aug.h)
    e = valid * (y - y_hat)
    Rf = masked_noise_factor(aug.R, valid)
    Lr = chol(Rf @ Rf.T)
    _, loglik = innovation_stats(Lr, e, valid)
    return ca.Function("oe_step", [x, d, theta], [sub(aug.f[:x.shape[0]]), forward(Lr, e), -loglik, y_hat])


def _filter_error_step(model, aug, x, theta, lam_q, lam_r, q_rows):
    """(s = [x; vec P], d, θ, λ) → (s_next, e, vec S, nll, ŷ, x_post): one EKF sample with scaled noise."""
    nx, ny = x.shape[0], aug.h.shape[0]
    d = ca.SX.sym("d", aug.u.shape[0] + aug.mem.shape[0] + 2 * ny)
    u, mem, y, valid = _split_data(aug, d)
    Dq = np.ones(nx, dtype=object)
    for j, row in enumerate(q_rows):
        Dq[row] = ca.exp(lam_q[j] / 2)
    Dq = ca.diag(ca.vertcat(*[ca.SX(v) for v in Dq]))
    Dr = ca.diag(ca.exp(lam_r / 2))
    Q0, R0 = model.process_noise(), model.measurement_noise()
    ext = ca.vertcat(aug.u, theta)
    plant = SimpleNamespace(z=x, u=ext, mem=aug.mem, f=aug.f[:nx], h=aug.h, n=nx,
                            Q=Dq @ ca.SX(Q0) @ Dq, R=Dr @ ca.SX(R0) @ Dr)
    P = ca.SX.sym("P", nx, nx)
    uth = ca.vertcat(u, theta)
    x_post, P_post, e, Pyy, Ly = ekf_update(plant, x, P, uth, mem, y, valid)
    x_next, P_next = ekf_predict(plant, x_post, P_post, uth, mem)
    _, loglik = innovation_stats(Ly, e, valid)
    y_hat = ca.substitute(aug.h, ca.vertcat(aug.u, aug.mem, x), ca.vertcat(u, mem, x))
    s = ca.vertcat(x, ca.vec(P))
    return ca.Function("fe_step", [s, d, theta, ca.vertcat(lam_q, lam_r)],
                       [ca.vertcat(x_next, ca.vec(P_next)), e, ca.vec(Pyy), -loglik, y_hat, x_post])


BLOCK = 16     # steps inlined per block of a chained recording (see _chained)


def _chained(step: ca.Function, n: int, name: str) -> ca.Function:
    """What ``step.mapaccum(name, n, [0], [0])`` computes — the first input carried to the first
    output over n samples, the second input one column per sample, the others held — by blocks of
    BLOCK steps inlined into one SX Function, carried on by a mapaccum. Evaluating a step costs a
    call's overhead, and its derivatives an MX sweep, per sample; inside a block both are SX. The
    quadrotor's 10 000-sample noise calibration (16 iterations) takes 8.9 s instead of 14.3 s, the
    cart's 2.9 s instead of 5.6 s (8 steps a block: 3.5 s, 24: 3.5 s). A step of more than
    :data:`skigen.runtime.INLINE_BELOW` instructions, for which the call costs little and the
    inlined block much to build, is accumulated step by step."""
    if n < 2 * BLOCK or step.n_instructions() > INLINE_BELOW:
        return step.mapaccum(name, n, [0], [0])
    ins = [ca.SX.sym(f"i{j}", step.sparsity_in(j)) for j in range(step.n_in())]
    cols = ca.SX.sym("d", step.size1_in(1), BLOCK)
    cur, outs = ins[0], []
    for k in range(BLOCK):
        res = step(cur, cols[:, k], *ins[2:])
        cur = res[0]
        outs.append(res)
    block = ca.Function("block", [ins[0], cols, *ins[2:]], [cur] + [ca.horzcat(*o) for o in zip(*outs)])
    K, rest = divmod(n, BLOCK)
    args = [ca.MX.sym(f"a{j}", step.sparsity_in(j)) for j in range(step.n_in())]
    args[1] = ca.MX.sym("data", step.size1_in(1), n)
    res = block.mapaccum(name, K, [0], [0])(args[0], args[1][:, :K * BLOCK], *args[2:])[1:]
    if rest:
        tail = step.mapaccum(name, rest, [0], [0])(res[0][:, -1], args[1][:, K * BLOCK:], *args[2:])
        res = [ca.horzcat(a, b) for a, b in zip(res, tail)]
    return ca.Function(name, args, res)


def _pseudo_residuals(ny: int) -> ca.Function:
    """(e, vec S, vec L̄) → ρ = [L̄⁻¹ e; vec(L̄⁻¹ S L̄⁻ᵀ)/√2], whose Gram matrix is the Fisher
    information, and r = [L̄⁻¹ e; vec(I − L̄⁻¹ e eᵀ L̄⁻ᵀ)/√2], with which the gradient of
    ½ (eᵀ S⁻¹ e + log det S) is (∂ρ/∂θ)ᵀ r where L̄ = chol(S) (L̄ held constant)."""
    e, S, L = ca.SX.sym("e", ny), ca.SX.sym("S", ny * ny), ca.SX.sym("L", ny * ny)
    Lm, Sm = ca.reshape(L, ny, ny), ca.reshape(S, ny, ny)
    W, a = forward(Lm, forward(Lm, Sm).T), forward(Lm, e)
    return ca.Function("rho", [e, S, L], [ca.vertcat(a, ca.vec(W) / np.sqrt(2)),
                                          ca.vertcat(a, ca.vec(ca.DM.eye(ny) - a @ a.T) / np.sqrt(2))])


def build_problem(model: Model, lengths: list[int], method: str, estimate: list[str],
                  shooting: int | None = None) -> Problem:
    """The NLP for recordings of the given lengths (their data enter as the NLP's parameter)."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got '{method}'")
    aug, x, theta = _plant(model, estimate)
    nx, ny = x.shape[0], aug.h.shape[0]
    nd = aug.u.shape[0] + aug.mem.shape[0] + 2 * ny
    theta_names = aug.names[nx:]
    V = Variables()
    weight_var = dict(zip(model.weight_names, model.prior_variances()))
    for name in theta_names:
        if name in weight_var:
            V.add(name, "weight", np.sqrt(weight_var[name]), 0.0)
        else:
            p = model.parameter_named(name)
            V.add(name, "parameter", _scale_of(p.value, p.std), p.value, *p.bounds, prior_std=p.std)
    free = [name in estimate for name in theta_names]
    fixed_weights = [i for i, n in enumerate(theta_names) if not free[i]]   # weights not estimated stay 0
    n_theta = len(theta_names)

    data = [ca.MX.sym(f"data{r}", nd, n) for r, n in enumerate(lengths)]
    g, rho_all, weights_all, nll_all, yhat_all, starts = [], [], [], [], [], []
    q_rows = [i for i in range(nx) if model.process_noise()[i, i] > 0]
    lam_q, lam_r = ca.SX.sym("lam_q", len(q_rows)), ca.SX.sym("lam_r", ny)
    ekf = _filter_error_step(model, aug, x, theta, lam_q, lam_r, q_rows)
    s0 = ca.DM(np.r_[model.x0, np.ravel(model.initial_covariance(), order="F")])
    th_sym = ca.MX.sym("theta", n_theta)
    filtered = ca.Function("filtered", [th_sym, *data], [ca.horzcat(*[
        _chained(ekf, n, "filter")(s0, d, th_sym, 0)[5] for n, d in zip(lengths, data)])]) \
        if method == "output-error" else None
    if method == "output-error":
        step = _output_error_step(aug, x, theta)
        M = shooting or max(lengths)
        for r, n in enumerate(lengths):
            K = int(np.ceil(n / M))
            for j in range(K):
                for i, v in enumerate(model.states):
                    V.add(f"{v.name}@{r}" + (f"#{j}" if K > 1 else ""), "initial",
                          model.x_std[i] or 1.0, model.x0[i], node=(v.name, r, j))
        xi, sc = ca.MX.sym("xi", len(V)), ca.MX.sym("scale", len(V))
        th = xi[:n_theta] * sc[:n_theta]
        offset = n_theta
        for r, n in enumerate(lengths):
            K = int(np.ceil(n / M))
            X0 = ca.reshape(xi[offset:offset + K * nx] * sc[offset:offset + K * nx], nx, K)
            offset += K * nx
            D = ca.horzcat(data[r], ca.repmat(ca.vertcat(data[r][:-2 * ny, -1], ca.DM.zeros(2 * ny)),
                                               1, K * M - n)) if K * M > n else data[r]
            sim = _chained(step, M, "sim").map(K, "thread", 2)
            X_next, rho, nll, y_hat = sim(X0, D, th)
            X_end = X_next[:, M - 1::M]                  # the state after each interval's last sample
            g += [X0[:, 1:] - X_end[:, :-1]] if K > 1 else []
            rho_all.append(rho[:, :n])
            weights_all.append(rho[:, :n])          # −log L = ½ ρᵀρ + const: its gradient is Jᵀρ
            nll_all.append(nll[:, :n])
            yhat_all.append(y_hat[:, :n])
    else:
        for i in q_rows:
            V.add(f"Q_scale_{model.state_names[i]}", "noise", 1.0, 0.0, -LOG_SCALE_BOUND, LOG_SCALE_BOUND)
        for name in model.output_names:
            V.add(f"R_scale_{name}", "noise", 1.0, 0.0, -LOG_SCALE_BOUND, LOG_SCALE_BOUND)
        xi, sc = ca.MX.sym("xi", len(V)), ca.MX.sym("scale", len(V))
        th = xi[:n_theta] * sc[:n_theta]
        lam = xi[n_theta:] * sc[n_theta:]
        starts = [ca.MX.sym(f"start{r}", s0.shape[0]) for r in range(len(lengths))]
        rho_fn, chol_fn = _pseudo_residuals(ny), _chol_function(ny)
        for r, n in enumerate(lengths):
            _, e, S, nll, y_hat, _ = _chained(ekf, n, "filter")(starts[r], data[r], th, lam)
            L = ca.stop_diff(chol_fn.map(n)(S), 1)
            rho_r, weights_r = rho_fn.map(n)(e, S, L)
            rho_all.append(rho_r)
            weights_all.append(weights_r)
            nll_all.append(nll)
            yhat_all.append(y_hat)
    rho, nll = ca.horzcat(*rho_all), ca.horzcat(*nll_all)
    prior_idx = [i for i, s in enumerate(V.prior_std) if s is not None]
    prior_sd = ca.DM([V.prior_std[i] for i in prior_idx])
    prior_res = (xi[prior_idx] * sc[prior_idx] - ca.DM([V.initial[i] for i in prior_idx])) / prior_sd \
        if prior_idx else ca.MX(0, 1)
    f = ca.sum2(nll) + 0.5 * ca.sumsqr(prior_res)
    p = ca.vertcat(sc, *[ca.vec(d) for d in data], *starts)          # starts: filter error only
    gg = ca.vertcat(*[ca.vec(c) for c in g]) if g else ca.MX(0, 1)
    J = ca.jacobian(ca.vec(rho), xi)
    prior_prec, prior_grad = ca.MX.zeros(len(V)), ca.MX.zeros(len(V))
    for j, i in enumerate(prior_idx):
        prior_prec[i] = (sc[i] / prior_sd[j]) ** 2
        prior_grad[i] = prior_res[j] * sc[i] / prior_sd[j]
    fisher = ca.mtimes(J.T, J) + ca.diag(prior_prec)
    scores = ca.Function("scores", [xi, p], [f, ca.mtimes(J.T, ca.vec(ca.horzcat(*weights_all))) + prior_grad, fisher])
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", gg.shape[0])
    cached = _LastPoint(scores)              # IPOPT asks for the gradient, then the Hessian, at each iterate
    f_at, grad_at, fisher_at = cached(xi, p)
    secant = _Secant(len(V), _damping(V))
    curvature = lam_f * (fisher_at + secant(xi, f_at, grad_at, fisher_at) + ca.diag(_damping(V)))
    if gg.shape[0]:      # the constraints' own curvature: multiple shooting needs it to converge
        curvature += ca.hessian(ca.dot(lam_g, gg), xi)[0]
    hess = ca.Function("nlp_hess_l", [xi, p, lam_f, lam_g], [ca.triu(curvature)],
                       ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])
    grad = ca.Function("nlp_grad_f", [xi, p], [f_at, grad_at], ["x", "p"], ["f", "grad_f_x"])
    decrement = ca.Function("decrement", [xi, p], [grad_at, fisher_at])
    lbx, ubx = np.array(V.lower), np.array(V.upper)
    for i in fixed_weights:
        lbx[i] = ubx[i] = 0.0
    inputs = dict(lbx=lbx, ubx=ubx, lbg=np.zeros(gg.shape[0]), ubg=np.zeros(gg.shape[0]), x0=np.array(V.initial))
    return Problem(method, V, inputs, dict(x=xi, p=p, f=f, g=gg, hess=hess, grad=grad, cached=cached, secant=secant),
                   ca.Function("residuals", [xi, p], [rho, nll]),
                   ca.Function("fisher", [xi, p], [J, prior_prec]),
                   ca.Function("predict", [xi, p], [ca.horzcat(*yhat_all)]),
                   filtered, list(lengths), shooting or max(lengths), decrement=decrement,
                   objective=ca.Function("objective", [xi, p], [f]))


class _LastPoint(ca.Callback):
    """``f`` — (ξ, p) → the objective, its gradient Jᵀ r and the Fisher information, from one
    forward sweep of J — evaluated once per point: IPOPT's gradient and Hessian at an iterate and
    the negligible-step test share it. (A reverse sweep for the gradient alone cost about 6
    evaluations of the objective, J about 10: the quadrotor's 10 000-sample calibration.)"""

    def __init__(self, f: ca.Function):
        ca.Callback.__init__(self)
        self.f, self.last = f, (None, None)
        self.construct("last_point", {})

    def get_n_in(self):
        return self.f.n_in()

    def get_n_out(self):
        return self.f.n_out()

    def get_sparsity_in(self, i):
        return self.f.sparsity_in(i)

    def get_sparsity_out(self, i):
        return self.f.sparsity_out(i)

    def eval(self, arg):
        key = tuple(hashlib.sha1(np.asarray(a, float).tobytes()).digest() for a in arg)
        last = self.last                     # one tuple: a reader never sees a key with another's value
        if last[0] != key:
            last = self.last = key, self.f(*arg)
        return last[1]


class _Secant(ca.Callback):
    """(ξ, −log L, gradient, Fisher information F) at IPOPT's iterate → S, the structured secant
    correction of Dennis, Gay and Welsch's NL2SOL (ACM TOMS 7, 1981): F + S is the Hessian model.

    Fisher scoring converges linearly where the model does not hold (a nominal that misses physics:
    its innovations are not white, and the likelihood's curvature is not the Fisher information):
    the quadrotor's misspecified calibration overshoots by 0.64 of the remaining distance at every
    iteration. S learns the missing curvature from successive gradients: with s = ξ⁺ − ξ and
    y = g⁺ − g, it satisfies (F⁺ + S⁺) s = y with the least change of S (sized down first by
    min(1, |sᵀy♯| / |sᵀSs|), y♯ = y − F⁺s). As in NL2SOL, the next step uses F + S only where it
    predicted the last step's decrease of −log L better than F alone, and F + S positive definite;
    a pair with yᵀs ≤ 0 leaves S as it is. :meth:`reset` before each solve."""

    def __init__(self, n: int, damping: ca.DM):
        ca.Callback.__init__(self)
        self.n, self.damping = n, np.diag(np.asarray(damping, float).ravel())
        self.reset()
        self.construct("secant", {})

    def reset(self):
        self.S, self.last = np.zeros((self.n, self.n)), None

    def get_n_in(self):
        return 4

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(*((self.n, 1), (1, 1), (self.n, 1), (self.n, self.n))[i])

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(self.n, self.n)

    def eval(self, arg):
        xi, f, g, F = (np.asarray(a, float) for a in arg)
        xi, f, g = xi.ravel(), float(f.ravel()[0]), g.ravel()
        augmented = False
        if self.last is not None:
            x0, f0, g0, F0 = self.last
            s, y = xi - x0, g - g0
            ys = float(y @ s)
            if ys > 0 and np.isfinite(f) and np.all(np.isfinite(y)):
                change = lambda H: f0 + g0 @ s + 0.5 * s @ (H + self.damping) @ s - f    # predicted − actual
                augmented = abs(change(F0 + self.S)) < abs(change(F0))
                S, y_sharp = self.S, y - F @ s
                sSs = float(s @ S @ s)
                if sSs != 0:
                    S = S * min(1.0, abs(float(s @ y_sharp)) / abs(sSs))
                v = y_sharp - S @ s
                self.S = S + (np.outer(v, y) + np.outer(y, v)) / ys - float(v @ s) * np.outer(y, y) / ys ** 2
        self.last = xi, f, g, F
        return [self.S if augmented and _positive_definite(F + self.S + self.damping) else np.zeros_like(F)]


def _positive_definite(H: np.ndarray) -> bool:
    try:
        np.linalg.cholesky(H)
    except np.linalg.LinAlgError:
        return False
    return True


NOISE_DAMPING = 0.5     # curvature added to each log noise scale: one sample's Fisher information about
                        # its own log-variance. Where the recordings do not resolve a scale (a noise-free
                        # truth drives Q towards 0, where the likelihood is flat) its Fisher information
                        # vanishes, and an undamped scoring step along it is so long that the line search
                        # cuts every other variable's step with it.


def _damping(V: Variables) -> ca.DM:
    return ca.DM([NOISE_DAMPING if k == "noise" else 0.0 for k in V.kinds])


def _chol_function(ny: int) -> ca.Function:
    S = ca.SX.sym("S", ny * ny)
    return ca.Function("chol", [S], [ca.vec(chol(ca.reshape(S, ny, ny)))])
