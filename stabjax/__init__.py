"""stabjax: batch stability explorer for rigid-body attitude control.

Importing stabjax changes no global setting of JAX. The command line and the documented entry
points (:func:`stabjax.sweep.run_spec`, :func:`stabjax.sweep.run_plan`,
:func:`stabjax.engine.simulate`, :func:`stabjax.engine.solve_batch`) call
:func:`stabjax.config.setup_jax` first, which switches float64 on (the monoaxial instability of
paper A is algebraic and invisible in float32; float64 is the only precision, and ``STABJAX_X64=0``
is refused). Code that builds JAX arrays for stabjax itself calls it first too.
"""
__version__ = "0.1.0"

from .config import setup_jax  # noqa: E402
from .errors import StabjaxError, ValidationError  # noqa: E402
from .registry import list_systems  # noqa: E402
from .models import register, resolve as get_system  # noqa: E402  (names, files, modules, entry points)
from .params import Param, ParamSet  # noqa: E402
from .system import System  # noqa: E402
from .outcomes import VERDICTS, Outcomes  # noqa: E402

__all__ = ["StabjaxError", "ValidationError", "get_system", "list_systems", "register", "setup_jax", "Param", "ParamSet",
           "System", "Outcomes", "VERDICTS", "__version__"]
