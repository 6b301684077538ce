"""Running a plan: the chunked runner, its resumable store and lock, the dataset layout, Dask, progress, signals, and the rules for what a command may write."""
