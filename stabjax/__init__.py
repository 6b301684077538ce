"""stabjax: batch stability explorer for rigid-body attitude control.

Float64 is switched on at import: the monoaxial instability (paper A) is algebraic
and invisible in float32 (docs/models/monoaxial.md, "Numerical notes").
"""
import os

os.environ.setdefault("EQX_ON_ERROR", "nan")  # solver errors become NaN + a status code, never an exception

import jax

jax.config.update("jax_enable_x64", True)


def _host_devices() -> None:
    """One JAX CPU device per core, so the fused engine (stabjax.fast) runs a loop per core.

    Only if the user has not chosen (``jax_num_cpu_devices``, ``XLA_FLAGS`` host device count,
    or ``STABJAX_CPU_DEVICES``; set that to 1 to switch this off) and JAX has not started its
    backends yet; jit'ed code still runs on device 0, so nothing else changes.
    """
    want = os.environ.get("STABJAX_CPU_DEVICES")
    if "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", ""):
        return
    try:
        if jax.config.jax_num_cpu_devices not in (-1, None) and want is None:
            return
        n = int(want) if want else len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        n = max(1, min(n, 64))
        if n > 1 or want:
            jax.config.update("jax_num_cpu_devices", n)
    except Exception:  # backends already initialised, or an older JAX without the option
        pass


_host_devices()

__version__ = "0.1.0"

from .errors import StabjaxError, ValidationError  # noqa: E402
from .registry import get_system, list_systems, register  # noqa: E402
from .params import Param, ParamSet  # noqa: E402
from .system import System  # noqa: E402
from .outcomes import Outcomes  # noqa: E402

__all__ = ["StabjaxError", "ValidationError", "get_system", "list_systems", "register", "Param", "ParamSet", "System",
           "Outcomes", "__version__"]
