"""skigen: identification filters derived once from a CasADi model.

Declare a :class:`Model`, :func:`derive` its augmented EKF, square-root UKF
or SKI step, run it over a recording in Python or emit it as C.
"""
from .model import Model, ModelError
from .derive import FilterOptions, derive

__all__ = ["Model", "ModelError", "FilterOptions", "derive"]
__version__ = "0.1.0"
