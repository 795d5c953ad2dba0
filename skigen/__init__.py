"""skigen: identification filters derived once from a CasADi model.

Declare a :class:`Model`, :func:`derive` its augmented EKF, square-root UKF
or SKI step, :func:`run` it over a recording or flight log (CSV, Parquet, ULog,
DataFrame) in Python or C, or emit it as C.
"""
from .model import Model, ModelError
from .derive import FilterOptions, derive
from .api import run

__all__ = ["Model", "ModelError", "FilterOptions", "derive", "run"]
__version__ = "0.1.0"
