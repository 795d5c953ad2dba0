"""Regenerate the checked-in C sources of the shipped models (``generated/``).

    python -m skigen.emit.shipped generated      (what `make generate` runs)

Each filter lands in ``generated/<model>_<kind>_<real>/`` in the default
('auto') kernel style; a test regenerates them into a temporary folder and
fails on any difference.
"""
from __future__ import annotations

import sys
from pathlib import Path

from ..derive import derive
from .c import emit_c

__all__ = ["SHIPPED", "generate_all"]

SHIPPED = {
    "models.wingrock:model": ("ekf", "ukf", "ski"),
    "models.wingrock_delay:model": ("ukf", "ski"),
    "models.wingrock_delay:wide": ("ukf", "ski"),       # n = 50: the looped kernel
    "models.quadrotor_spiral:model": ("ukf", "ski"),
    "models.quadrotor_vertical:model": ("ski",),
    "models.quadrotor_mukf:model": ("mukf",),
    "models.quadrotor_mukf:model_rk4": ("ukf",),
}
REALS = ("double", "float")


def _model(spec: str):
    from ..cli import load_model
    return load_model(spec)


def generate_all(out_dir) -> list[Path]:
    """Emit every shipped filter in double and float; returns the files written."""
    files = []
    for spec, kinds in SHIPPED.items():
        model = _model(spec)
        for kind in kinds:
            filt = derive(model, kind)
            for real in REALS:
                files += emit_c(filt, Path(out_dir) / f"{model.name}_{kind}_{real}", real=real)
    return files


if __name__ == "__main__":
    for f in generate_all(sys.argv[1] if len(sys.argv) > 1 else "generated"):
        print(f)
