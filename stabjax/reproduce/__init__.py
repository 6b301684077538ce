"""`stabjax reproduce NAME`: one module per paper, each with ``run(out_dir, quick=False)``."""
