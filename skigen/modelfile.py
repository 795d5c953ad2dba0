"""Load a model declared in a Python file (its ``model``) or at ``package.module:attribute``."""
from __future__ import annotations

import importlib
import importlib.util
import sys
from pathlib import Path

from .model import Model, ModelError

__all__ = ["ModelFileError", "canonical_spec", "is_module_spec", "load_model"]


class ModelFileError(ValueError):
    """A model file that cannot be found, imported or does not define a model."""


def is_module_spec(spec) -> bool:
    """True for ``package.module:attribute``, False for a path (which may itself hold a colon)."""
    return ":" in str(spec) and not Path(spec).exists()


def canonical_spec(spec) -> str:
    """The spec as another process should see it: an existing file's absolute path, else as given."""
    spec = str(spec)
    return str(Path(spec).resolve()) if not is_module_spec(spec) and Path(spec).exists() else spec


def load_model(spec: str) -> Model:
    """A checked model from ``path/to/file.py`` (its ``model``) or ``package.module:attribute``."""
    spec = str(spec)
    if is_module_spec(spec):
        module_name, attr = spec.split(":", 1)
        if str(Path.cwd()) not in sys.path and "" not in sys.path:    # as `python -m` would find it
            sys.path.append(str(Path.cwd()))
        try:
            module = importlib.import_module(module_name)
        except ImportError as exc:
            raise ModelFileError(f"cannot import model module '{module_name}': {exc}") from None
    else:
        path, attr = Path(spec), "model"
        if not path.is_file():
            raise ModelFileError(f"model file '{spec}' not found (give a .py file or package.module:attribute)")
        name, root = _module_name(path)
        if root not in sys.path:    # its own imports resolve as when Python runs it (relative ones from its package)
            sys.path.insert(0, root)
        module_spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(module_spec)
        sys.modules[module_spec.name] = module      # dataclasses and pickling look it up
        try:
            module_spec.loader.exec_module(module)
        except ModelError as exc:
            raise ModelError(f"model file '{spec}'{_line_in(exc, path)}: {exc}") from None
        except Exception as exc:  # the user's file failed to run: say where, briefly
            raise ModelFileError(f"model file '{spec}' failed to load{_line_in(exc, path)}: "
                                 f"{type(exc).__name__}: {exc.msg if isinstance(exc, SyntaxError) else exc}") from None
    model = getattr(module, attr, None)
    if not isinstance(model, Model):
        raise ModelFileError(f"'{spec}' defines no skigen.Model named '{attr}'")
    try:
        return model.check()
    except ModelError as exc:             # the line that declared what the check refused
        file = getattr(module, "__file__", None)
        if exc.where and file and Path(exc.where[0]).resolve() == Path(file).resolve():
            raise ModelError(f"model file '{spec}', line {exc.where[1]}: {exc}") from None
        raise


def _module_name(path: Path) -> tuple[str, str | None]:
    """(the module name a model file is executed under, the directory its imports resolve from):
    ``models.quadrotor_vertical`` and the directory above ``models`` for a file in a package (a
    directory with ``__init__.py``), so that its relative imports work; else a private name and
    the file's own directory (a sibling module imports, as when Python runs the file)."""
    parts, d = [path.stem], path.resolve().parent
    while (d / "__init__.py").is_file():
        parts.insert(0, d.name)
        d = d.parent
    return (".".join(parts) if len(parts) > 1 else f"skigen_user_model_{path.stem}"), str(d)


def _line_in(exc: BaseException, path: Path) -> str:
    """', line N' of the last frame of ``exc``'s traceback in the file ``path`` (a syntax error's
    own line), or ''."""
    if isinstance(exc, SyntaxError) and exc.lineno:
        return f", line {exc.lineno}"
    target, line, tb = path.resolve(), None, exc.__traceback__
    while tb is not None:
        if Path(tb.tb_frame.f_code.co_filename).resolve() == target:
            line = tb.tb_lineno
        tb = tb.tb_next
    return f", line {line}" if line else ""
