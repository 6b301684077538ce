"""The progress of a run: a live bar on a terminal (rich), plain periodic lines otherwise (a log, CI):
trajectories done, chunks done (resumed ones counted apart), rates, elapsed time and ETA."""
from __future__ import annotations

import time

from ..config import env_seconds


class Bar:
    """A live progress bar on a terminal (rich): trajectories done/total, chunks, rates, elapsed, ETA."""

    def __init__(self, total: int, name: str, chunks: int = 0):
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        self.progress = Progress(
            TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("traj"),
            TextColumn("{task.fields[rate]}"), TimeElapsedColumn(), TimeRemainingColumn(), transient=False,
        )
        self.t0 = time.perf_counter()
        self.progress.start()
        self.name, self.chunks, self.chunks_done, self.run = name, chunks, 0, 0
        self.task = self.progress.add_task(self._desc(), total=total, rate="")

    def _desc(self) -> str:
        from rich.markup import escape  # the description is read as markup: a name "[x]" must survive

        name = escape(self.name)
        return f"{name} ({self.chunks_done}/{self.chunks} chunks)" if self.chunks else name

    def update(self, k: int, steps: int = 0, chunks: int = 0, chunk_done: bool = False):
        """Advance by ``k`` trajectories; ``chunks``: resumed chunks (not counted in the rates)."""
        dt = max(time.perf_counter() - self.t0, 1e-9)
        self.chunks_done += chunks + int(chunk_done)
        if not chunks:
            self.run += k
        self.progress.update(self.task, advance=k, description=self._desc(),
                             rate=f"{self.run / dt:,.0f} traj/s {steps / dt:,.0f} traj-steps/s")

    def close(self):
        self.progress.stop()


def _clock(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


class Lines:
    """Progress as plain lines, for output that is not a terminal (a log file, CI).

    A live bar redraws one line with control codes; in a file it is cut off or repeated as
    garbage. This writes one complete line every ``interval`` seconds (and a last one when the
    sweep ends): done/total trajectories, percent, chunks, the rate of this run (resumed chunks
    excluded) and the ETA from that rate, so ``tail -f log`` and a CI log both read well.
    """

    def __init__(self, total: int, name: str, chunks: int = 0, *, interval: float | None = None, stream=None):
        import sys

        self.total, self.name, self.chunks = max(int(total), 1), name, chunks
        self.interval = env_seconds("STABJAX_PROGRESS_INTERVAL", 5.0) if interval is None else interval
        self.stream = stream if stream is not None else sys.stderr
        self.done = self.run = self.chunks_done = 0
        self.t0 = self.last = time.perf_counter()

    def line(self) -> str:
        dt = max(time.perf_counter() - self.t0, 1e-9)
        rate = self.run / dt
        left = self.total - self.done
        eta = _clock(left / rate) if rate > 0 else "?"
        chunks = f", {self.chunks_done}/{self.chunks} chunks" if self.chunks else ""
        return (f"{self.name}: {self.done:,}/{self.total:,} traj ({100 * self.done / self.total:.0f}%{chunks}), "
                f"{rate:,.0f} traj/s, elapsed {_clock(dt)}, ETA {eta}")

    def _emit(self):
        print(self.line(), file=self.stream, flush=True)
        self.last = time.perf_counter()

    def update(self, k: int, steps: int = 0, chunks: int = 0, chunk_done: bool = False):
        self.done = min(self.total, self.done + k)
        self.chunks_done += chunks + int(chunk_done)
        if not chunks:
            self.run += k
        if time.perf_counter() - self.last >= self.interval:
            self._emit()

    def close(self):
        self._emit()


def progress_bar(enabled: bool, total: int, name: str, chunks: int = 0):
    """A live bar on a terminal, plain periodic lines otherwise (see :class:`Lines`); None if disabled."""
    if not enabled:
        return None
    from rich.console import Console

    return Bar(total, name, chunks) if Console().is_terminal else Lines(total, name, chunks)
