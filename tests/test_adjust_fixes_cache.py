"""Issue 13: the compiled image kernels hit numba's on-disk cache in a second process.

Independent evidence (no timing): numba's own dispatcher statistics (``stats.cache_hits`` /
``stats.cache_misses``) in two fresh interpreters sharing one empty ``NUMBA_CACHE_DIR``, and the number of
cache files, which must not grow when a third process runs.  (Before the fix the kernels were closures that
captured a jitted helper; the helper pickles with a per-process identity, so every process missed and
wrote another cache entry.)
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

pytest.importorskip("numba")

SCRIPT = r"""
import json
import numpy as np
from skyrig.adjust.model import _BAL_KERNEL, _CHAIN_KERNEL
n, ni = 4, 2
oi = np.array([0, 1, 0, 1]); ist = np.array([0, 1])
R = np.broadcast_to(np.eye(3), (ni, 3, 3)).copy(); off = np.zeros((ni, 3))
pc = np.array([[0.1, 0.2, -5.0]] * n); dpc = np.ones((n, 2, 3))
out = (np.empty((n, 2, 3)), np.empty((n, 2, 6)), np.empty((n, 2, 3)))
_CHAIN_KERNEL(oi, ist, dpc, pc, R, R, R, off, False, *out)
X = np.array([[0.0, 0.0, -5.0]] * n); C = np.zeros((ni, 3)); intr = np.array([[100.0, 0.0, 0.0]] * ni)
pix = np.zeros((n, 2)); sig = np.ones((n, 2))
r = np.empty((n, 2)); bad = np.empty(n, np.bool_); jc = np.empty((n, 2, 6)); jp = np.empty((n, 2, 3))
_BAL_KERNEL(oi, np.arange(n), ist, R, C, R, R, off, False, X, intr, pix, sig, True, 0, -1, -1, r, bad, jc, jp)
print(json.dumps({k: [sum(d.stats.cache_hits.values()), sum(d.stats.cache_misses.values())]
                  for k, d in (("chain", _CHAIN_KERNEL), ("bal", _BAL_KERNEL))}))
"""


def _run(cache_dir: str) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _files(d: str) -> int:
    return sum(len(fs) for _, _, fs in os.walk(d))


@pytest.mark.slow  # two fresh interpreters, one compiling the parallel kernels (about 14 s)
def test_image_kernels_load_from_the_cache_in_a_second_process(tmp_path):
    cache = str(tmp_path / "numba-cache")
    first = _run(cache)
    assert first["chain"][1] == 1 and first["bal"][1] == 1  # compiled (and written) once
    n_files = _files(cache)
    assert n_files > 0
    second = _run(cache)
    assert second == {"chain": [1, 0], "bal": [1, 0]}, second  # loaded, not compiled
    _run(cache)
    assert _files(cache) == n_files  # no new cache entries pile up
