"""Per-phase time accounting of the dense chain (for ``bench/dense.py``): wall and CPU seconds by phase name.

The counters are per process and cost two clock reads per phase; :func:`reset` clears them, :func:`totals`
reads them.  Nothing in the products depends on them."""

from __future__ import annotations

import time
from collections import defaultdict
from contextlib import contextmanager
from typing import Iterator

_wall: dict[str, float] = defaultdict(float)
_cpu: dict[str, float] = defaultdict(float)


@contextmanager
def phase(name: str) -> Iterator[None]:
    """Add the wall and CPU (this process) seconds of the ``with`` body to phase ``name``."""
    w, c = time.perf_counter(), time.process_time()
    try:
        yield
    finally:
        _wall[name] += time.perf_counter() - w
        _cpu[name] += time.process_time() - c


def reset() -> None:
    _wall.clear()
    _cpu.clear()


def totals() -> dict[str, tuple[float, float]]:
    """Phase name -> (wall s, CPU s) since the last :func:`reset`."""
    return {k: (_wall[k], _cpu[k]) for k in _wall}
