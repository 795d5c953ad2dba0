"""One call from a model and data to a result: ``skigen.run(model, data)``."""
from __future__ import annotations

from .derive import derive
from .model import Model
from .recording import Recording, load_recording
from .runtime import RunResult
from .runtime import run as _run

__all__ = ["run"]


def run(model: Model, data, *, filter: str = "ukf", backend: str = "python", columns=None, time=None,
        time_unit: str = "s", max_gap: float = 1.0, real: str = "double",
        show_progress: bool = True, guard=None, options=None, estimate=()) -> RunResult:
    """Run ``model``'s ``filter`` over ``data`` on the model's grid.

    data: a CSV, Parquet or PX4 ULog path, a pandas DataFrame (a time column, or a numeric or
    datetime index), or a :class:`~skigen.recording.Recording` already on the model's grid (a
    window of one: ``load_recording(path, model).slice(a, b)``). columns: model input/output
    name -> column. time: the time column (default t, time or timestamp). time_unit: s, ms, us,
    ns or auto. max_gap: seconds without a sample reported as a hole (``result.holes``). backend:
    python, c (``real`` double or float) or casadi (no guard policy: see :mod:`skigen.runtime`).
    guard: outlier gate and recovery settings (a :class:`skigen.guard.Guard`; default its defaults).
    options: the filter's :class:`~skigen.derive.FilterOptions` (sigma-point alpha, second-order EKF, ARD).
    estimate: declared parameters estimated online, augmented into the state with their std as
    prior (``skigen run --estimate``).
    show_progress: a progress line on stderr, where progress is shown (a terminal, or
    ``SKIGEN_PROGRESS=1``), as :func:`skigen.fit.fit` and the commands.
    Returns a :class:`~skigen.runtime.RunResult`; ``.to_frame()`` gives a DataFrame.
    """
    model.check()
    rec = data if isinstance(data, Recording) else load_recording(
        data, model, time=time, time_unit=time_unit, columns=columns, max_gap=max_gap, real=real)
    return _run(derive(model, filter, options, estimate=estimate), rec, backend=backend, real=real,
                show_progress=show_progress, guard=guard)
