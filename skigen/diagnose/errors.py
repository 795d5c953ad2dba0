"""The one error a user of the diagnosis meets: a message, never a traceback."""
from __future__ import annotations

__all__ = ["DiagnosisError"]


class DiagnosisError(ValueError):
    """The model or the recording cannot be diagnosed; the message says why and what is needed."""
