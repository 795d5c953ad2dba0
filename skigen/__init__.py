"""skigen: identification filters derived once from a CasADi model.

Declare a :class:`Model`, :func:`derive` its augmented EKF, square-root UKF
or SKI step, :func:`run` it over a recording or flight log (CSV, Parquet, ULog,
DataFrame) in Python or C, or emit it as C, and :func:`fit` its declared
parameters to recordings.
"""
from .model import Model, ModelError
from .derive import FilterOptions, derive
from .api import run
from .fit import FitError, fit      # the function; its module is skigen.fit (from skigen.fit import ...)

__all__ = ["Model", "ModelError", "FilterOptions", "FitError", "derive", "fit", "run"]
__version__ = "0.1.0"
