"""Issue 13, deliverable 5: every numba kernel a whole adjustment uses hits the on-disk cache in a second process.

(tests/test_adjust_fixes_cache.py checks the two image kernels alone.)  Independent evidence: numba's own
dispatcher statistics over every skyrig dispatcher that ran, in fresh interpreters sharing one empty
``NUMBA_CACHE_DIR``, and the number of cache files, which must not grow with a third process.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

pytest.importorskip("numba")

SCRIPT = r"""
import gc, json
from numba.core.registry import CPUDispatcher
from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.synthetic import synthetic_block

block, _ = synthetic_block(seed=1, n_points=120)
res = adjust(block, AdjustConfig())
used = {}
for o in gc.get_objects():
    if isinstance(o, CPUDispatcher) and o.py_func.__module__.startswith("skyrig"):
        h, m = sum(o.stats.cache_hits.values()), sum(o.stats.cache_misses.values())
        if h or m:
            used[o.py_func.__module__ + ":" + o.py_func.__qualname__] = [h, m]
print(json.dumps({"used": used, "converged": bool(res.info.converged)}))
"""


def _run(cache_dir: str) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _files(d: str) -> int:
    return sum(len(fs) for _, _, fs in os.walk(d))


@pytest.mark.slow  # three fresh interpreters, the first compiling the solver and image kernels (about 30 s)
def test_every_adjustment_kernel_loads_from_the_cache_in_a_second_process(tmp_path):
    cache = str(tmp_path / "numba-cache")
    first = _run(cache)
    assert first["converged"]
    assert len(first["used"]) >= 5, first  # the solver's kernels and the chain rule ran
    assert all(m >= 1 for _, m in first["used"].values())  # compiled and written
    n_files = _files(cache)
    second = _run(cache)
    # a kernel called only from inside another (linalg's _add_row, _find) is compiled through its dispatcher in the
    # first process and comes with its caller's cached code in the second: the second uses a subset, each loaded
    assert set(second["used"]) <= set(first["used"])
    callees = set(first["used"]) - set(second["used"])
    assert len(callees) <= 2 and all(k.startswith("skyrig.adjust.linalg:_") for k in callees), callees
    missed = {k: v for k, v in second["used"].items() if v[1] != 0 or v[0] < 1}
    assert missed == {}, missed  # every kernel loaded, none compiled
    _run(cache)
    assert _files(cache) == n_files  # no new cache entries pile up
