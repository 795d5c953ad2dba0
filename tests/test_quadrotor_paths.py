"""The quadrotor spiral SKI: derived step = NumPy reference, generated C = Python."""
import numpy as np

from models import quadrotor_sim, quadrotor_spiral
from skigen import derive
from skigen.reference import filters as ref
from skigen.reference.quadrotor import spiral_f, spiral_h
from skigen.runtime import run
from tests import ski_settings


def test_spiral_ski_equals_reference_and_c():
    flight = quadrotor_sim.spiral(seed=2)
    rec = quadrotor_spiral.recording(flight).slice(0, 400)
    filt = derive(quadrotor_spiral.model, "ski")
    aug, o = filt.aug, filt.options
    st = filt.initial()
    ref_st = dict(z=st["z"], S=st["C"], s=st["s"])
    for k in range(len(rec.t)):
        u, y = rec.inputs[k], rec.outputs[k]
        valid = np.array([k % 9 != 4] * 3)
        r = {n: np.asarray(v) for n, v in filt.step(z=st["z"], C=st["C"], s=st["s"], u=u, mem=st["mem"],
                                                     y=np.where(valid, y, 0), valid=valid.astype(float)).items()}
        q = ref.ski_step(ref_st["z"], ref_st["S"], ref_st["s"], y, valid, lambda z: spiral_f(z, u), spiral_h,
                         aug.Q, aug.R, aug.w_index, o.alpha, o.beta, o.kappa, **ski_settings(filt))
        for ours, theirs in [(r["z_post"].ravel(), q["z_post"]), (r["C_next"], q["S"]), (r["s_next"].ravel(), q["s"])]:
            np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-9 * max(1.0, np.abs(theirs).max()))
        st = dict(z=r["z_next"].ravel(), C=r["C_next"], s=r["s_next"].ravel(), mem=st["mem"])
        ref_st = dict(z=q["z"], S=q["S"], s=q["s"])
    python = run(filt, rec, show_progress=False)
    c = run(filt, rec, backend="c", show_progress=False)
    np.testing.assert_array_equal(c.code, python.code)
    np.testing.assert_allclose(c.mean, python.mean, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(c.prior_var, python.prior_var, rtol=1e-9, atol=1e-15)
