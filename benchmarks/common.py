"""Shared pieces of the benchmarks: arguments, simulated recordings, timing."""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from skigen.derive import ARD_UPDATES
from skigen.recording import Recording
from skigen.runtime import run


def parser(name: str, seeds: int) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=f"skigen bench {name}")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of tables")
    p.add_argument("--seeds", type=int, default=seeds, help="noise seeds (median reported)")
    p.add_argument("--out", default="benchmarks/figures", help="folder for the figures")
    p.add_argument("--ard", choices=ARD_UPDATES, default="em",
                   help="SKI's ARD update: 'em' (default) or the paper's 'gradient'")
    return p


def recording(sim) -> Recording:
    """A simulated WingRock run as a recording (commanded δ in, measured φ out)."""
    return Recording("simulation", sim.t, sim.delta[:, None], sim.phi[:, None], ("delta",), ("phi",))


def timed_run(filt, rec):
    """(result, µs per step) of the Python backend."""
    t0 = time.perf_counter()
    res = run(filt, rec, show_progress=False)
    return res, 1e6 * (time.perf_counter() - t0) / len(rec.t)


def spread(values) -> dict:
    v = np.asarray(values, float)
    return dict(median=float(np.median(v)), p25=float(np.percentile(v, 25)), p75=float(np.percentile(v, 75)))


def emit(report: dict, as_json: bool, table: str) -> int:
    print(json.dumps(report, indent=1) if as_json else table)
    return 0
