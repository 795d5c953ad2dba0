"""Command line: ``skigen run | generate | bench`` (also ``python -m skigen``)."""
from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys
from pathlib import Path

import numpy as np

from .derive import FILTERS
from .model import Model, ModelError
from .recording import RecordingError

__all__ = ["main", "load_model"]


class CliError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


def load_model(spec: str) -> Model:
    """A model from ``path/to/file.py`` (its ``model``) or ``package.module:attribute``."""
    if ":" in spec and not Path(spec).exists():
        module_name, attr = spec.split(":", 1)
        try:
            module = importlib.import_module(module_name)
        except ImportError as exc:
            raise CliError(f"cannot import model module '{module_name}': {exc}") from None
    else:
        path, attr = Path(spec), "model"
        if not path.is_file():
            raise CliError(f"model file '{spec}' not found (give a .py file or package.module:attribute)")
        module_spec = importlib.util.spec_from_file_location(f"skigen_user_model_{path.stem}", path)
        module = importlib.util.module_from_spec(module_spec)
        try:
            module_spec.loader.exec_module(module)
        except ModelError:
            raise
        except Exception as exc:  # the user's file failed to run: say where, briefly
            raise CliError(f"model file '{spec}' failed to load: {type(exc).__name__}: {exc}") from None
    model = getattr(module, attr, None)
    if not isinstance(model, Model):
        raise CliError(f"'{spec}' defines no skigen.Model named '{attr}'")
    return model.check()


def _run(args) -> int:
    from .derive import derive
    from .recording import read_recording
    from .runtime import run

    model = load_model(args.model)
    rec = read_recording(args.data, model.input_names, model.output_names)
    filt = derive(model, args.filter)
    result = run(filt, rec, backend=args.backend, real=args.real)
    result.write(args.out)
    print(f"{model.name} {args.filter} ({args.backend}): {len(rec.t)} samples -> {args.out}; "
          f"mean NIS {np.nanmean(result.nis):.3f} (expected about {len(model.output_names)})")
    return 0


def _generate(args) -> int:
    from .derive import derive
    from .emit.c import emit_c

    model = load_model(args.model)
    files = emit_c(derive(model, args.filter), args.out, real=args.real)
    for f in files:
        print(f)
    return 0


def _bench(args) -> int:
    try:
        bench = importlib.import_module(f"benchmarks.{args.name}")
    except ModuleNotFoundError:
        raise CliError(f"no benchmark named '{args.name}'") from None
    return bench.main(args.rest + (["--json"] if args.json else []))


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="skigen", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run a filter over a recording")
    r.add_argument("model", help="model file (.py exposing `model`) or package.module:attribute")
    r.add_argument("data", help="recording CSV: t, inputs, outputs")
    r.add_argument("--filter", choices=FILTERS, default="ski")
    r.add_argument("--backend", choices=["python", "c"], default="python")
    r.add_argument("--real", choices=["double", "float"], default="double", help="C backend precision")
    r.add_argument("--out", required=True, help="result CSV")
    r.set_defaults(func=_run)
    g = sub.add_parser("generate", help="emit the C library of a filter")
    g.add_argument("model")
    g.add_argument("--filter", choices=FILTERS, default="ski")
    g.add_argument("--real", choices=["double", "float"], default="double")
    g.add_argument("--out", required=True, help="output directory")
    g.set_defaults(func=_generate)
    b = sub.add_parser("bench", help="print a benchmark table (wingrock, delay, speed, footprint)")
    b.add_argument("name")
    b.add_argument("--json", action="store_true", help="print one JSON object")
    b.add_argument("rest", nargs=argparse.REMAINDER)
    b.set_defaults(func=_bench)
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        return args.func(args)
    except (CliError, ModelError, RecordingError, OSError) as exc:
        print(f"skigen: error: {exc}", file=sys.stderr)
        return 2
    except (ValueError, RuntimeError) as exc:
        print(f"skigen: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
