"""A progress line: redrawn in place on a terminal, written as lines where forced (SKIGEN_PROGRESS=1)."""
from __future__ import annotations

import os
import sys
import time


LINE_SECONDS = 2.0    # forced onto a pipe or file: a line at most this often


def shown(stream=None) -> bool:
    """True when progress goes to ``stream`` (default sys.stderr): a terminal, or ``SKIGEN_PROGRESS=1``."""
    stream = stream or sys.stderr
    env = os.environ.get("SKIGEN_PROGRESS")
    tty = getattr(stream, "isatty", None)
    return env == "1" or (env != "0" and tty is not None and tty())


def note(text: str, stream=None) -> None:
    """One line about slow work ahead, where progress is shown (default: sys.stderr now)."""
    stream = stream or sys.stderr
    if shown(stream):
        print(text, file=stream, flush=True)


def progress(iterable, total, label, stream=None, min_seconds=1.0, measure=None, unit=""):
    """Yield from ``iterable``, showing ``label: 45% (6750/15000) 1.2 s, eta 1.5 s`` on ``stream``
    (default sys.stderr). ``measure``: how much of ``total`` is done (in ``unit``; none: a share),
    where that is not the items yielded (a streamed file: the share of its time span laid out).

    On a terminal the line is redrawn in place, at most ~10 times per second, and finished with a
    newline. Forced onto a pipe or file (``SKIGEN_PROGRESS=1``) it is written as lines, at most one
    every LINE_SECONDS, and the last. ``SKIGEN_PROGRESS=0`` disables it. Nothing is shown before
    the work has taken ``min_seconds``.
    """
    stream = stream or sys.stderr
    if not shown(stream):
        yield from iterable
        return

    t0 = time.perf_counter()
    last, width, done, drawn = -1.0, 0, 0, None
    tty = getattr(stream, "isatty", lambda: False)()
    every = 0.1 if tty else LINE_SECONDS

    def draw(now):
        nonlocal width, drawn
        el = now - t0
        if total:
            part = measure() if measure else done
            eta = f"{el * (total - part) / part:.1f} s" if part else "?"
            amount = (f" ({part:.3g}/{total:.3g}{unit})" if unit else "") if measure else f" ({done}/{total})"
            text = f"{label}: {100 * part / total:3.0f}%{amount} {el:.1f} s, eta {eta}"
        else:
            text = f"{label}: {done} {el:.1f} s"
        stream.write("\r" + text.ljust(width) if tty else text + "\n")
        stream.flush()
        width, drawn = len(text), done

    try:
        for item in iterable:
            yield item
            done += 1
            now = time.perf_counter()
            if now - t0 >= min_seconds and now - last >= every:
                draw(now)
                last = now
    finally:
        now = time.perf_counter()
        if (width or now - t0 >= min_seconds) and drawn != done:
            draw(now)
        if tty and width:
            stream.write("\n")
            stream.flush()
