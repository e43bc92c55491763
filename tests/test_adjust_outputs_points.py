"""points.csv / adjusted.gpkg leave out tie points whose rays data snooping rejected down to fewer than two.

Regression: make demo's adjustment wrote two tie points at -1050 m (sigma NaN) into points.csv - points left with
one ray, rejected, keeping stale coordinates - and the dsm command then warned about implausible heights.
"""

from __future__ import annotations

import warnings
from types import SimpleNamespace

import numpy as np

from skyrig.errors import PlausibilityWarning
from skyrig.io.adjust_outputs import _determined_points


def _result(obs_point: list[int], rejected: list[tuple[str, int]], names: list[str]) -> SimpleNamespace:
    block = SimpleNamespace(n_points=len(names), obs_point=np.array(obs_point), point_name=np.array(names))
    return SimpleNamespace(block=block, rejected=[SimpleNamespace(group=g, index=i) for g, i in rejected])


def test_tie_points_left_with_one_ray_are_not_published() -> None:
    # point 0: 3 rays, 1 rejected -> 2 left (kept); point 1: 2 rays, 1 rejected -> 1 (dropped);
    # point 2: 2 rays, a GNSS rejection of index 4 must not count; point 3: control with one ray (kept)
    res = _result([0, 0, 0, 1, 1, 2, 2, 3], [("image", 1), ("image", 4), ("gnss", 5)], ["a", "b", "c", "g"])
    role = np.array(["tie", "tie", "tie", "control"])
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        keep = _determined_points(res, role)
    assert keep.tolist() == [True, False, True, True]
    assert len(w) == 1 and issubclass(w[0].category, PlausibilityWarning) and "first: b" in str(w[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing rejected: no warning
        assert _determined_points(_result([0, 0, 1, 1], [], ["a", "b"]), np.array(["tie", "tie"])).all()
