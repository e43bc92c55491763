"""One progress display for the commands: a transient bar on standard error that follows ``progress(done, total)``
callbacks (the tiles of a dense / ortho / façade run, the pairs of a matching run)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = ["tile_progress"]


@contextmanager
def tile_progress(label: str) -> Iterator[Callable[[int, int], None]]:
    """``with tile_progress("dense tiles") as progress: run(..., progress=progress)``."""
    from rich.console import Console
    from rich.progress import Progress

    with Progress(console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task(label, total=None)

        def progress(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        yield progress
