import os

os.environ.setdefault("MPLBACKEND", "Agg")

import stabjax  # noqa: E402

stabjax.setup_jax()  # float64, EQX_ON_ERROR=nan, one CPU device per core: before any test builds arrays
