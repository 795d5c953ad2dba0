"""The derived CasADi steps equal the independent NumPy reference, step by step and over runs."""
import numpy as np
import pytest

from models.wingrock import build
from skigen import FilterOptions, derive
from skigen.reference import filters as ref
from skigen.reference.wingrock import wingrock_f, wingrock_h
from tests import ski_settings

RTOL = 1e-9


def _inputs(n, seed=0):
    """A square-wave-plus-noise aileron sequence that keeps WingRock excited and bounded."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.02
    return 2.0 * np.sign(np.sin(2 * np.pi * t / 1.5)) + 0.5 * rng.standard_normal(n)


def _close(a, b, rtol=RTOL, scale=None):
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = np.abs(b).max(initial=1.0) if scale is None else scale
    np.testing.assert_allclose(a, b, rtol=0, atol=rtol * max(scale, 1.0))


def _ref_step(kind, d, state, delta, y, valid):
    aug, o = d.aug, d.options
    f = lambda z: wingrock_f(z, delta)
    if kind == "ekf":
        return ref.ekf_step(state["z"], state["C"], y, valid, f, wingrock_h, aug.Q, aug.R,
                            second_order=o.second_order)
    if kind == "ukf":
        return ref.ukf_step(state["z"], state["C"], y, valid, f, wingrock_h, aug.Q, aug.R,
                            o.alpha, o.beta, o.kappa)
    return ref.ski_step(state["z"], state["C"], state["s"], y, valid, f, wingrock_h, aug.Q, aug.R,
                        aug.w_index, o.alpha, o.beta, o.kappa, **ski_settings(d))


def _cas_step(d, state, delta, y, valid):
    args = dict(z=state["z"], C=state["C"], u=[delta], mem=state["mem"], y=y,
                valid=valid.astype(float))
    if d.kind == "ski":
        args["s"] = state["s"]
    return {k: np.array(v) for k, v in d.step(**args).items()}


OPTIONS = [FilterOptions(),
           FilterOptions(alpha=0.5, kappa=0.0, ard="gradient", ard_steps=3, eta=0.5)]
CASES = [(kind, o, RTOL) for o in OPTIONS for kind in ("ekf", "ukf", "ski")]
# the reference's Hessians are central differences (step 1e-6) of complex-step Jacobians
CASES.append(("ekf", FilterOptions(second_order=True), 1e-8))


@pytest.mark.parametrize("kind, opts, rtol", CASES,
                         ids=[f"{k}_{i}" for i, k in enumerate(c[0] for c in CASES)])
def test_whole_run_matches_reference(kind, opts, rtol):
    """Both paths run side by side, each fed its own previous output, over 300 samples."""
    _close = lambda a, b, scale=None: globals()["_close"](a, b, rtol, scale)
    d = derive(build(prior_variance=0.5), kind, opts)
    cov = "P" if kind == "ekf" else "S"
    rng = np.random.default_rng(1)
    deltas = _inputs(300)
    ours, theirs = d.initial(), d.initial()
    theta = 0.0
    for k, delta in enumerate(deltas):
        y = np.array([theta + 0.1 * rng.standard_normal()])
        valid = np.array([k % 7 != 3])               # some samples missing
        r = _cas_step(d, ours, delta, y, valid)
        q = _ref_step(kind, d, theirs, delta, y, valid)
        _close(r["z_post"].ravel(), q["z_post"])
        _close(r["C_post"], q[f"{cov}_post"])
        _close(r["z_next"].ravel(), q["z"])
        _close(r["C_next"], q[cov])
        _close(r["e"].ravel(), q["e"])
        _close(r["Pyy"], q["Pyy"])
        _close(r["nis"], q["nis"], scale=abs(q["nis"]))
        _close(r["loglik"], q["loglik"], scale=abs(q["loglik"]))
        if kind == "ski":
            _close(r["s_next"].ravel(), q["s"])
        ours = dict(z=r["z_next"].ravel(), C=r["C_next"], mem=ours["mem"],
                    **({"s": r["s_next"].ravel()} if kind == "ski" else {}))
        theirs = dict(z=q["z"], C=q[cov], mem=theirs["mem"], **({"s": q["s"]} if kind == "ski" else {}))
        theta = wingrock_f(np.r_[theta, 0.0, np.zeros(6)], delta)[0]   # a plausible next angle
    assert np.all(np.isfinite(ours["z"]))


@pytest.mark.parametrize("kind", ["ekf", "ukf", "ski"])
def test_missing_output_skips_update(kind):
    d = derive(build(), kind)
    st = d.initial()
    r = _cas_step(d, st, 1.0, np.array([5.0]), np.array([False]))
    _close(r["z_post"].ravel(), st["z"])
    assert r["nis"].item() == 0.0 and r["loglik"].item() == 0.0 and r["e"].item() == 0.0
