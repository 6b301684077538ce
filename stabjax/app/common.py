"""What the commands share: option declarations, usage checks (``--set``, integer lists), the output-path
check that refuses to lose a file, the readers that tell a previous result of ours from a user's file (the stamps
on figures and pages are :func:`stabjax.run.outputs.stamp_output`), and the consoles. What a command may write over is decided in
:mod:`stabjax.run.outputs`."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Optional

import typer

from rich.console import Console

from ..run import outputs as _outputs
from ..run.outputs import same_file_as_any  # noqa: F401 - the commands import it from here

class _Console(Console):
    """Rich's console without its 80 columns where the output is not a terminal (a pipe, a file, a CI log):
    there a line is never cut (soft wrap: "engine native" stays on the line of "wrote ...") and a table takes
    the width its rows need, up to ``WIDE`` columns; on a terminal (or with ``$COLUMNS``) its width."""

    WIDE = 240

    @property
    def size(self):
        size = Console.size.fget(self)
        if self._width is None and not self.is_terminal and not self._environ.get("COLUMNS"):
            from rich.console import ConsoleDimensions

            return ConsoleDimensions(max(size.width, self.WIDE), size.height)
        return size

    @size.setter
    def size(self, new_size):
        Console.size.fset(self, new_size)


console = _Console(soft_wrap=True)
err_console = _Console(stderr=True, soft_wrap=True)  # messages stay one line: greppable


SetOpt = typer.Option(None, "--set", "-s", help="parameter override NAME=VALUE (vectors as comma lists); repeatable")


def parse_sets(sets: Optional[list[str]]) -> dict[str, str]:
    from ..errors import ValidationError

    out = {}
    for item in sets or []:
        if "=" not in item:
            raise ValidationError("--set", f"expected NAME=VALUE, got {item!r}")
        k, v = (x.strip() for x in item.split("=", 1))
        if not k:
            raise ValidationError("--set", f"expected NAME=VALUE, got {item!r} (no name)")
        if k in out:
            raise ValidationError("--set", f"{k} is given twice ({out[k]!r} and {v!r})")
        out[k] = v
    return out


def int_list(text: str, field: str, lo: int = 1) -> list[int]:
    """A comma list of integers >= lo (``--sizes``)."""
    from .. import validate
    from ..errors import ValidationError

    items = [x.strip() for x in text.split(",") if x.strip()]
    if not items:
        raise ValidationError(field, f"expected a comma list of integers, got {text!r}")
    try:
        values = [int(x) for x in items]
    except ValueError:
        raise ValidationError(field, f"expected a comma list of integers, got {text!r}") from None
    return [validate.integer(v, field, lo=lo) for v in values]


ForceOpt = typer.Option(False, "--force", help="replace an existing output file that is not a previous result of "
                                                 "the same command (a result of the same spec is replaced anyway)")


RESULT_SUFFIXES, IMAGE_SUFFIXES = _outputs.RESULT_SUFFIXES, _outputs.IMAGE_SUFFIXES
check_output, result_spec = _outputs.check_output, _outputs.result_spec


def trajectory_system(path: Path) -> str | None:
    """The system of a trajectory written by ``stabjax simulate``, or None for any other file."""
    try:
        import xarray as xr

        with xr.open_dataset(path, engine="netcdf4") as ds:
            return str(ds.attrs["system"]) if "solver_ok" in ds.attrs and "system" in ds.attrs else None
    except Exception:  # noqa: BLE001
        return None


def open_result_file(file: Path):
    """The result a command shows (:func:`stabjax.present.kit.open_result`): a netCDF file or a finished
    sweep's store; anything else is refused naming ``file``."""
    from ..present.kit import open_result

    return open_result(file, field="file", partial=False)


def jsonable(x: Any):
    import numpy as np

    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return None if not np.isfinite(x) else float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def warn_changed_model(ds):
    """A result records its model file and the local modules it imports, with their hashes
    (:mod:`stabjax.plan.identity`); say so when one on disk has changed since."""
    from ..plan.identity import changed_sources

    for what in changed_sources(ds.attrs):
        err_console.print(f"warning: the model file {what} has changed since this result was computed",
                          style="yellow", markup=False)
