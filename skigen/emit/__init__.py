"""Emitters of derived filters: portable C (:mod:`skigen.emit.c`)."""
from .c import CFilter, CompileError, Status, compile_shared, emit_c, load_c

__all__ = ["CFilter", "CompileError", "Status", "compile_shared", "emit_c", "load_c"]
