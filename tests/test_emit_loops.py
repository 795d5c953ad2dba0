"""The looped C kernel against the NumPy reference, on models the WingRock tests do not
reach: several outputs with some missing (quadrotor spiral), exact input memory and
n = 50 (48 candidate delays, a model whose unrolled step is ~3 M operations)."""
import subprocess
import sys

import numpy as np
import pytest

from benchmarks.common import recording
from models import quadrotor_sim, quadrotor_spiral, wingrock_delay
from models.wingrock import W_TRUE
from models.wingrock_sim import simulate
from skigen import derive
from skigen.emit import Status, emit_c
from skigen.emit.c import AUTO_LOOPS_ABOVE_OPERATIONS, DEFAULT_FLAGS, choose_style, load_c, single_precision_options
from skigen.reference import filters as ref
from skigen.reference.quadrotor import spiral_f, spiral_h
from skigen.reference.wingrock import wingrock_delay_f, wingrock_h
from skigen.runtime import run
from tests import ski_settings

RTOL = 1e-9


def _close(ours, theirs, rtol=RTOL):
    theirs = np.asarray(theirs, float)
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=rtol * max(1.0, np.abs(theirs).max()))


def _ref_ski(filt, st, y, valid, f, h):
    aug, o = filt.aug, filt.options
    return ref.ski_step(st["z"], st["S"], st["s"], y, valid, f, h, aug.Q, aug.R, aug.w_index,
                        o.alpha, o.beta, o.kappa, **ski_settings(filt))


def _compare_to_reference(filt, inputs, outputs, valid, f_of, h, cache):
    """Two looped C filters against the reference SKI: one reseeded from the reference's prior
    every sample (per step), one left to run on its own (whole run)."""
    per_step = load_c(filt, style="loops", cache_dir=cache)
    whole = load_c(filt, style="loops", cache_dir=cache)
    init = filt.initial()
    st = dict(z=init["z"], S=init["C"], s=init["s"])
    for k in range(len(inputs)):
        y = np.where(valid[k], outputs[k], np.nan)
        per_step.set("z", st["z"]), per_step.set("C", st["S"]), per_step.set("s", st["s"])
        codes = {per_step.step(inputs[k], y), whole.step(inputs[k], y)}
        assert codes == {Status.OK if valid[k].all() else Status.MEASUREMENT_SKIPPED}
        q = _ref_ski(filt, st, outputs[k], valid[k], f_of(k), h)
        for cf in (per_step, whole):
            _close(cf.z_post, q["z_post"])
            _close(cf.z, q["z"])
            _close(cf.C, q["S"])
            _close(cf.s, q["s"])
        st = dict(z=q["z"], S=q["S"], s=q["s"])


def test_looped_spiral_ski_equals_reference(tmp_path):
    """Three outputs, each missing on its own schedule: the masked update of the loops."""
    rec = quadrotor_spiral.recording(quadrotor_sim.spiral(seed=2)).slice(0, 300)
    filt = derive(quadrotor_spiral.model, "ski")
    k = np.arange(len(rec.t))[:, None]
    valid = np.hstack([k % 9 != 4, k % 5 != 2, k % 9 != 4])
    _compare_to_reference(filt, rec.inputs, rec.outputs, valid,
                          lambda i: (lambda z: spiral_f(z, rec.inputs[i])), spiral_h, tmp_path)


def _delay_window(deltas, k, m):
    return [deltas[k - j] if k >= j else 0.0 for j in range(m)]


def test_looped_wide_delay_ski_equals_reference(tmp_path):
    """n = 50 with 48 delayed inputs carried as memory: the shipped looped filter's model."""
    sim = simulate(seed=3, delay=wingrock_delay.TRUE_DELAY, duration=3)
    filt = derive(wingrock_delay.wide, "ski")
    assert choose_style(filt) == "loops"
    m, deltas = filt.aug.shapes["nw"], sim.delta
    valid = (np.arange(len(sim.t)) % 7 != 3)[:, None]
    _compare_to_reference(filt, deltas[:, None], sim.phi[:, None], valid,
                          lambda k: (lambda z: wingrock_delay_f(z, _delay_window(deltas, k, m), W_TRUE)),
                          wingrock_h, tmp_path)


def test_looped_delay_ski_equals_python_runtime(tmp_path):
    """Input memory and the ARD through the looped kernel = the derived step via the runtime."""
    rec = recording(simulate(seed=1, delay=wingrock_delay.TRUE_DELAY))
    filt = derive(wingrock_delay.model, "ski")
    python = run(filt, rec, show_progress=False)
    c = load_c(filt, style="loops", cache_dir=tmp_path).run(rec.inputs, rec.outputs)
    _close(c["z_post"], python.mean)
    _close(c["std"], python.std)


def test_looped_ski_with_random_walk_weights_equals_python_runtime(tmp_path):
    """A noise factor with zero columns (θ has no process noise) beside non-zero ones (the
    weights walk): the looped QR leaves out only the zero ones."""
    filt = derive(wingrock_delay.build(process_std=(0.0, 1e-3), weight_std=1e-3, name="walk"), "ski")
    assert np.sum(np.abs(filt.aug.Q[filt.aug.w_index][:, filt.aug.w_index])) > 0 and filt.aug.Q[0, 0] == 0
    rec = recording(simulate(seed=4, delay=wingrock_delay.TRUE_DELAY, duration=4))
    python = run(filt, rec, show_progress=False)
    c = load_c(filt, style="loops", cache_dir=tmp_path).run(rec.inputs, rec.outputs)
    _close(c["z_post"], python.mean)
    _close(c["std"], python.std)


def test_style_choice_and_errors(tmp_path):
    small, wide = derive(wingrock_delay.model, "ski"), derive(wingrock_delay.wide, "ski")
    assert choose_style(small) == "unrolled" and choose_style(wide) == "loops"
    spiral = derive(quadrotor_spiral.model, "ukf")          # n = 14, but 28 800 operations unrolled
    assert spiral.tunable.n_instructions() > AUTO_LOOPS_ABOVE_OPERATIONS >= small.tunable.n_instructions()
    assert choose_style(spiral) == "loops" and choose_style(spiral, "unrolled") == "unrolled"
    assert choose_style(derive(wingrock_delay.wide, "ekf")) == "unrolled"      # no looped EKF
    with pytest.raises(ValueError, match="style 'unrolled'"):
        choose_style(derive(wingrock_delay.model, "ekf"), "loops")
    with pytest.raises(ValueError, match="style must be one of"):
        choose_style(small, "fast")
    r = subprocess.run([sys.executable, "-m", "skigen", "generate", "models.wingrock:model", "--filter", "ukf",
                        "--out", str(tmp_path / "ukf")], capture_output=True, text=True)
    assert r.returncode == 0 and "kernel: unrolled (auto: 6109 operations unrolled, looped above 20000)" in r.stderr
    r = subprocess.run([sys.executable, "-m", "skigen", "generate", "models.wingrock:model", "--filter", "ekf",
                        "--style", "loops", "--out", str(tmp_path)], capture_output=True, text=True)
    assert r.returncode == 2 and "style 'unrolled'" in r.stderr and "Traceback" not in r.stderr


def test_looped_code_stays_small(tmp_path):
    """n = 50: kilobytes of C where the unrolled step would be ~69 MB. Measured 116 335 B: the
    looped EM kernel 25.4 kB, the model's functions 28.1 kB, the API 57.8 kB (its declared C0 and
    Q_sqrt0, n² literals each, are 27.6 kB of it; the 48 weights' index macros saying what each
    multiplies, 2 kB; 100 321 B before the recovery policy's and ARD's later code), and each
    file's macros that keep its names its own in a unity build, 4.9 kB (111 390 B before)."""
    files = emit_c(derive(wingrock_delay.wide, "ski"), tmp_path)
    assert sum(p.stat().st_size for p in files) < 120_000


def test_looped_float_ski_at_n50_tracks_double():
    """Float SKI with 48 candidate delays (EM's floor raised to FLOAT_S_FLOOR) stays within 2 %
    of a posterior standard deviation of double with that floor (measured: 0.75 %), is never
    rejected, and both pick the true delay (6)."""
    filt = derive(wingrock_delay.wide, "ski")
    rec = recording(simulate(seed=1, delay=wingrock_delay.TRUE_DELAY))
    double = run(single_precision_options(filt), rec, backend="c", show_progress=False)
    single = run(filt, rec, backend="c", real="float", show_progress=False)
    assert np.all(single.code == Status.OK) and np.all(double.code == Status.OK)
    assert np.max(np.abs(single.mean - double.mean) / double.std) < 0.02
    w = filt.aug.w_index
    for result in (double, single):
        assert np.argmax(np.abs(result.mean[-1, w])) == wingrock_delay.TRUE_DELAY


def test_model_headers_of_a_double_and_a_float_build_live_in_one_file(tmp_path):
    """CasADi's headers defined casadi_real with #ifndef and had no include guard: a file including
    a double and a float build's model headers gave the float functions double prototypes. They
    now name their types and are guarded (each included twice here), under -Werror."""
    filt = derive(wingrock_delay.model, "ukf")
    emit_c(filt, tmp_path / "d", real="double", prefix="dbl", style="loops")
    emit_c(filt, tmp_path / "f", real="float", prefix="flt", style="loops")
    main = tmp_path / "main.c"
    main.write_text('#include "dbl_model.h"\n#include "flt_model.h"\n#include "dbl_model.h"\n#include "flt_model.h"\n'
                    '#include "dbl_kernel.h"\n#include "flt_kernel.h"\n'
                    "int main(void) {\n  const double* ad[4] = {0}; double* rd[1] = {0};\n"
                    "  const float* af[4] = {0}; float* rf[1] = {0};\n"
                    "  return dbl_model_h(ad, rd, 0, 0, 0) + flt_model_h(af, rf, 0, 0, 0);\n}\n")
    r = subprocess.run(["gcc", *DEFAULT_FLAGS, "-c", str(main), "-I", str(tmp_path / "d"), "-I", str(tmp_path / "f"),
                        "-o", str(tmp_path / "main.o")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "define casadi_real" not in (tmp_path / "f" / "flt_model.h").read_text()
