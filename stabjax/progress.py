"""The progress bar of a run (rich): trajectories done, chunks done (resumed ones counted apart), rates."""
from __future__ import annotations

import time


class Bar:
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


def progress_bar(enabled: bool, total: int, name: str, chunks: int = 0):
    return Bar(total, name, chunks) if enabled else None
