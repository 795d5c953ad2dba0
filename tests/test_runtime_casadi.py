"""The casadi backend of skigen.runtime: the derived step chained by CasADi (mapaccum) over parts
of the recording, or called sample by sample when the step is too large to be worth chaining over
the part (runtime.CHAIN_BELOW), without the guard policy. Either way, where no step fails it equals
the python backend with Guard.off(), step for step, across parts, output dropouts and a restart
after an input hole; a part in which a step gives a non-finite number is redone by the python
backend with the default Guard.
"""
import numpy as np
import pytest

from models.wingrock import build
from models.wingrock_sim import simulate
from skigen import derive, runtime
from skigen.emit import Status
from skigen.grid import Hole
from skigen.guard import Guard
from skigen.recording import Recording
from skigen.runtime import RunResult, iter_run, run

FIELDS = ("mean", "std", "innovation", "innovation_var", "nis", "loglik", "prior_var", "final_cov")
TRACE = ("C_post", "z_next", "C_next", "mem")


@pytest.fixture(scope="module")
def rec():
    sim = simulate(seed=0, duration=4.0)
    phi = sim.phi.copy()
    phi[[10, 11, 50]] = np.nan          # output dropouts
    phi[120:150] = np.nan               # ... and a longer one, with the input unknown in its middle
    hole = Hole(float(sim.t[125]), float(sim.t[140]), ("delta", "phi"), inputs=True)
    return Recording("w", sim.t, sim.delta[:, None], phi[:, None], ("delta",), ("phi",), holes=(hole,))


def _scale(y) -> float:
    return 1e-10 * max([1.0] + list(np.abs(y[np.isfinite(y)])))


def _close(a: RunResult, b: RunResult, trace: bool):
    for f in FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        np.testing.assert_allclose(x, y, rtol=1e-10, atol=_scale(y), err_msg=f)
    np.testing.assert_array_equal(a.code, b.code)
    np.testing.assert_array_equal(a.measured, b.measured)
    if trace:
        for f in TRACE:
            y = getattr(b.trace, f)
            np.testing.assert_allclose(getattr(a.trace, f), y, rtol=1e-10, atol=_scale(y), err_msg=f)


@pytest.fixture(params=["chained", "direct"])
def mode(request, monkeypatch):
    monkeypatch.setattr(runtime, "CHAIN_BELOW", 10 ** 9 if request.param == "chained" else 0)
    return request.param


@pytest.mark.parametrize("kind", ["ekf", "ukf", "ski"])
def test_casadi_equals_python_without_the_guard(rec, kind, mode):
    filt = derive(build(), kind)
    init = filt.initial()
    init["z"] = init["z"] + 0.01           # a given starting state, as the diagnosis's cross-validation uses
    py = run(filt, rec, guard=Guard.off(), init=init, trace=True, show_progress=False)
    assert np.any(py.code == Status.MEASUREMENT_SKIPPED)
    one = run(filt, rec, backend="casadi", init=init, trace=True, show_progress=False)
    parts = RunResult.concat(list(iter_run(filt, rec, backend="casadi", init=init, trace=True, chunk=37,
                                           show_progress=False)))
    _close(one, py, trace=True)
    _close(parts, py, trace=True)
    # in the input hole the input is not known (predicted with the last known one, bad input), and
    # after it the physical states restart: without the hole the run differs from its start on
    plain = Recording("w", rec.t, rec.inputs, rec.outputs, rec.input_names, rec.output_names)
    other = run(filt, plain, backend="casadi", init=init, show_progress=False)
    k0 = int(np.searchsorted(rec.t, rec.holes[0].t0 + 1e-9, side="right"))
    k = int(np.searchsorted(rec.t, rec.holes[0].t1 - 1e-9))
    np.testing.assert_allclose(other.mean[:k0], one.mean[:k0], rtol=1e-12, atol=1e-12)
    assert np.all(one.code[k0:k] == Status.BAD_INPUT) and not np.any(other.code == Status.BAD_INPUT)
    assert not np.allclose(other.mean[k0 + 1], one.mean[k0 + 1]) and not np.allclose(other.std[k], one.std[k])


def test_a_non_finite_step_falls_back_to_the_guarded_python_part(rec, mode):
    filt = derive(build(), "ekf")
    y = rec.outputs.copy()
    y[170] = 1e200                       # its NIS overflows: the chain's numbers are not finite
    bad = Recording("w", rec.t, rec.inputs, y, rec.input_names, rec.output_names, holes=rec.holes)
    fast = RunResult.concat(list(iter_run(filt, bad, backend="casadi", chunk=50, show_progress=False)))
    assert fast.code[170] == Status.OUTLIER_REJECTED       # the default gate of the python part caught it
    guarded = run(filt, bad, show_progress=False)           # this clean flight has no other guard event
    _close(fast, guarded, trace=False)
    with pytest.raises(FloatingPointError, match="non-finite"):
        run(filt, bad, backend="casadi", strict=True, show_progress=False)


def test_the_casadi_backend_takes_no_guard(rec):
    filt = derive(build(), "ekf")
    with pytest.raises(ValueError, match="without the guard policy"):
        run(filt, rec, backend="casadi", guard=Guard(gate=3.0), show_progress=False)
    with pytest.raises(ValueError, match="choose python, c, casadi"):
        run(filt, rec, backend="jax", show_progress=False)
    with pytest.raises(ValueError, match="init and trace"):
        run(filt, rec, backend="c", trace=True, show_progress=False)


@pytest.fixture
def fresh_chains(monkeypatch):
    monkeypatch.setattr(runtime, "CHAIN_BELOW", 10 ** 9)
    monkeypatch.setattr(runtime, "_CHAINS", {})
    monkeypatch.setattr(runtime, "_RUNS", {})
    monkeypatch.setattr(runtime, "_JIT", dict(runtime._JIT, works=True))


def _identical(a: RunResult, b: RunResult):
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
    for f in TRACE:
        np.testing.assert_array_equal(getattr(a.trace, f), getattr(b.trace, f), err_msg=f)


@pytest.mark.parametrize("kind", ["ekf", "ukf", "ski"])
def test_a_chain_is_compiled_once_its_runs_cost_a_compilation_and_gives_the_same_numbers(rec, kind, fresh_chains):
    """runtime._Chain: CasADi's VM until the seconds its runs took exceed a compilation's expected
    cost, then C compiled beside the runs (they go on in the VM meanwhile), with the VM's numbers
    to the bit (no fused multiply-add)."""
    filt = derive(build(), kind)
    vm = run(filt, rec, backend="casadi", trace=True, show_progress=False)
    chain = next(iter(runtime._CHAINS.values()))
    assert not chain.native and 0 < chain.spent < chain.cost      # 200 samples: far from paying for it
    vm_function = chain.f
    chain.cost = chain.spent                 # as if its runs had now cost a compilation
    runtime._RUNS.clear()
    _identical(run(filt, rec, backend="casadi", trace=True, show_progress=False), vm)   # compiling meanwhile
    assert chain.compiling is not None and not chain.native and chain.f is vm_function
    chain.wait()
    assert chain.native and chain.f is not vm_function
    runtime._RUNS.clear()
    _identical(run(filt, rec, backend="casadi", trace=True, show_progress=False), vm)


def test_without_a_working_compiler_the_chain_stays_in_the_vm(rec, fresh_chains, monkeypatch):
    monkeypatch.setattr(runtime, "JIT_FLAGS", ["-no-such-flag"])
    filt = derive(build(), "ekf")
    vm = run(filt, rec, backend="casadi", trace=True, show_progress=False)
    chain = next(iter(runtime._CHAINS.values()))
    vm_function, chain.cost = chain.f, 0.0
    runtime._RUNS.clear()
    _identical(run(filt, rec, backend="casadi", trace=True, show_progress=False), vm)
    chain.wait()
    runtime._RUNS.clear()
    _identical(run(filt, rec, backend="casadi", trace=True, show_progress=False), vm)
    assert chain.native and chain.f is vm_function and not runtime._JIT["works"]


def test_the_jit_directories_of_ended_processes_are_removed(monkeypatch, tmp_path):
    """A pool worker ends without its exit handlers: its JIT directory is removed by the next
    process that compiles; a live process's is kept."""
    import os
    import subprocess
    import tempfile
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setattr(runtime, "_JIT", {k: v for k, v in runtime._JIT.items() if k != "directory"})
    ended = subprocess.Popen(["true"])
    ended.wait()
    stale, alive = tmp_path / f"skigen-jit-{ended.pid}-abc", tmp_path / f"skigen-jit-{os.getppid()}-def"
    for d in (stale, alive):
        d.mkdir()
        (d / "chain.so").write_bytes(b"")
    mine = runtime._jit_directory()
    assert not stale.exists() and alive.exists()
    assert mine.startswith(str(tmp_path / f"skigen-jit-{os.getpid()}-")) and os.path.isdir(mine)


def test_parallel_tasks_evaluate_side_by_side_and_return_the_loops_results(monkeypatch):
    """runtime.parallel: the tasks' CasADi evaluations (runtime._call) overlap — two evaluations
    that each wait for the other both finish — while the rest of each task runs under one lock; the
    results come in the items' order; the first exception is raised."""
    import threading

    import casadi as ca
    monkeypatch.setattr(runtime, "THREADS", 2)
    meeting = threading.Barrier(2, timeout=10)

    class Meet(ca.Callback):
        def __init__(self):
            ca.Callback.__init__(self)
            self.construct("meet", {})

        def get_n_in(self):
            return 1

        def get_n_out(self):
            return 1

        def eval(self, arg):
            meeting.wait()              # the other task's evaluation is under way too, or this times out
            return [2 * arg[0]]
    meet = Meet()

    def task(x):
        out = np.empty(1)
        runtime._call(meet, [np.array([x])], [out])
        assert runtime._TASK.holds      # the lock is this task's again
        return float(out[0])
    assert runtime.parallel(task, [1.0, 2.0]) == [2.0, 4.0]
    with pytest.raises(ZeroDivisionError):
        runtime.parallel(lambda x: 1 / x, [1.0, 0.0, 2.0])


def test_runs_on_threads_equal_the_runs_one_after_another(rec, monkeypatch):
    monkeypatch.setattr(runtime, "CHAIN_BELOW", 10 ** 9)
    filt = derive(build(), "ski")
    starts = []
    for shift in (0.0, 0.01, -0.02, 0.03):
        init = filt.initial()
        init["z"] = init["z"] + shift
        starts.append(init)
    go = lambda init: run(filt, rec, backend="casadi", init=init, trace=True, show_progress=False)
    monkeypatch.setattr(runtime, "THREADS", 1)
    alone = runtime.parallel(go, starts)
    monkeypatch.setattr(runtime, "THREADS", 2)
    runtime._RUNS.clear()
    for a, b in zip(runtime.parallel(go, starts), alone):
        _identical(a, b)


@pytest.mark.parametrize("backend", ["python", "casadi"])
def test_the_prior_after_a_part_is_the_traces(rec, backend):
    """RunResult.next_prior, the state a run stands in after a part (what the diagnosis restarts
    from, without keeping a trace), equals the trace's z_next, C_next at the part's last sample,
    before the restart after the input hole as well."""
    from skigen.diagnose.cv import ekf_priors
    model = build()
    filt = derive(model, "ekf")
    full = run(filt, rec, backend=backend, trace=True, show_progress=False)
    cuts = [37, 125, 126, 180]
    k = 0
    for part in iter_run(filt, rec, backend=backend, cuts=cuts, show_progress=False):
        k += len(part.t)
        np.testing.assert_array_equal(part.next_prior[0], full.trace.z_next[k - 1])
        np.testing.assert_array_equal(part.next_prior[1], full.trace.C_next[k - 1])
    if backend == "casadi":
        priors = ekf_priors(model, rec, [0, *cuts, len(rec.t)])
        assert sorted(priors) == cuts
        for c in cuts:
            np.testing.assert_array_equal(priors[c][1], full.trace.C_next[c - 1])


def test_an_ungated_run_says_so_and_counts_the_readings_a_gate_would_not_have_used(rec):
    """A reading 5 deg off (50 noise std) on the casadi backend, which has no gate: its summary
    said 'events: none (no outlier, …)' beside a mean NIS of 13 and spoilt weights; it now says
    the run was ungated and counts the samples that used a reading beyond the default gate (the
    outlier and the 8 its update threw off, measured). The python backend gates it; a clean casadi run
    says no reading was beyond."""
    filt = derive(build(), "ukf")
    bad = rec.outputs.copy()
    bad[180, 0] += 5.0
    spoiled = Recording("w", rec.t, rec.inputs, bad, ("delta",), ("phi",), holes=rec.holes)
    casadi = run(filt, spoiled, backend="casadi", show_progress=False).summary()
    (line,) = [s for s in casadi.lines() if s.startswith("ungated run")]
    beyond = int(line.split(": ")[1].split(" sample(s)")[0])
    assert beyond == 9 and f"first at t = {rec.t[180]:.6g} s" in line, line
    assert not any(s.startswith("events: none") for s in casadi.lines())
    assert f"{beyond} with a reading beyond 5σ used (no gate)" in casadi.attention()
    python = run(filt, spoiled, show_progress=False).summary()
    assert python.events[Status.OUTLIER_REJECTED] == 1 and not any("ungated" in s for s in python.lines())
    clean = run(filt, rec, backend="casadi", show_progress=False).summary().lines()
    assert any(s.endswith("no reading was beyond 5σ of its prediction") for s in clean), clean


def test_a_run_answered_from_the_cache_holds_the_same_input_through_a_hole(rec, fresh_chains):
    """The same run twice, cut where the input hole begins: the second's part before the hole
    comes from the run cache, and the hole then holds the last input known before it, as the
    python backend does (it held the zeros of a fresh stepper)."""
    filt = derive(build(), "ukf")
    k = int(np.searchsorted(rec.t, rec.holes[0].t0 + 1e-9, side="right"))     # the hole's first sample
    py = run(filt, rec, guard=Guard.off(), show_progress=False)
    for _ in range(2):
        again = RunResult.concat(list(iter_run(filt, rec, backend="casadi", cuts=[k], show_progress=False)))
        assert again.code[k] == Status.BAD_INPUT
        _close(again, py, trace=False)
