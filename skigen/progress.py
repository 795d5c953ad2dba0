"""A minimal terminal progress line, silent unless the stream is a terminal."""
from __future__ import annotations

import os
import sys
import time


def shown(stream=sys.stderr) -> bool:
    """True when progress goes to ``stream``: a terminal, or ``SKIGEN_PROGRESS=1``."""
    env = os.environ.get("SKIGEN_PROGRESS")
    tty = getattr(stream, "isatty", None)
    return env == "1" or (env != "0" and tty is not None and tty())


def note(text: str, stream=None) -> None:
    """One line about slow work ahead, where progress is shown (default: sys.stderr now)."""
    stream = stream or sys.stderr
    if shown(stream):
        print(text, file=stream, flush=True)


def progress(iterable, total, label, stream=sys.stderr, min_seconds=1.0):
    """Yield from ``iterable``, showing ``label: 45% (6750/15000) 1.2 s, eta 1.5 s``.

    The line is drawn only if ``stream.isatty()`` (``SKIGEN_PROGRESS=1`` forces it, as its last
    state only; ``=0`` disables it), only once the work has taken ``min_seconds``, at most
    ~10 times per second, and is finished with a newline at the end.
    """
    if not shown(stream):
        yield from iterable
        return

    t0 = time.perf_counter()
    last, width, done = -1.0, 0, 0
    tty = getattr(stream, "isatty", lambda: False)()     # elsewhere (forced): the last line only

    def draw(now, last_line=False):
        nonlocal width
        el = now - t0
        if total:
            eta = f"{el * (total - done) / done:.1f} s" if done else "?"
            text = f"{label}: {100 * done / total:3.0f}% ({done}/{total}) {el:.1f} s, eta {eta}"
        else:
            text = f"{label}: {done} {el:.1f} s"
        if tty or last_line:
            stream.write("\r" + text.ljust(width))
            stream.flush()
            width = len(text)

    try:
        for item in iterable:
            yield item
            done += 1
            now = time.perf_counter()
            if now - t0 >= min_seconds and now - last >= 0.1:
                draw(now)
                last = now
    finally:
        now = time.perf_counter()
        if width or now - t0 >= min_seconds:
            draw(now, last_line=True)
            stream.write("\n")
            stream.flush()
