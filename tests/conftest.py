import os

os.environ.setdefault("EQX_ON_ERROR", "nan")
os.environ.setdefault("MPLBACKEND", "Agg")

import stabjax  # noqa: E402,F401  (enables float64 before any test builds arrays)
