"""stabjax: batch stability explorer for rigid-body attitude control.

Float64 is switched on at import: the monoaxial instability (paper A) is algebraic
and invisible in float32 (MODELS.md 0.4.1).
"""
import os

os.environ.setdefault("EQX_ON_ERROR", "nan")  # solver errors become NaN + a status code, never an exception

import jax

jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"

from .errors import StabjaxError, ValidationError  # noqa: E402
from .registry import get_system, list_systems  # noqa: E402

__all__ = ["StabjaxError", "ValidationError", "get_system", "list_systems", "__version__"]
