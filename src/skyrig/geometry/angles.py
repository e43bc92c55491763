"""Angle units: degrees, radians and gon (grad, 400 per turn).

Every public function that takes angles names the unit, either in its own name
(``*_deg``) or through a ``unit`` argument that is one of ``"deg"``, ``"rad"``, ``"gon"``.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import UnitError

AngleUnit = Literal["deg", "rad", "gon"]

_PER_RADIAN: dict[str, float] = {
    "rad": 1.0,
    "deg": 180.0 / np.pi,
    "gon": 200.0 / np.pi,
}
_ALIASES: dict[str, str] = {
    "rad": "rad", "radian": "rad", "radians": "rad",
    "deg": "deg", "degree": "deg", "degrees": "deg", "°": "deg",
    "gon": "gon", "grad": "gon", "grads": "gon", "gons": "gon",
}


def normalize_unit(unit: str) -> AngleUnit:
    """Return the canonical spelling (``deg``, ``rad``, ``gon``) of an angle unit name.

    Raises
    ------
    UnitError
        If the name is not an angle unit.
    """
    key = str(unit).strip().lower()
    if key not in _ALIASES:
        raise UnitError(f"unknown angle unit {unit!r}; expected one of deg, rad, gon")
    return _ALIASES[key]  # type: ignore[return-value]


def to_radians(values: ArrayLike, unit: str) -> NDArray[np.float64]:
    """Convert angles from ``unit`` to radians (vectorised)."""
    return np.asarray(values, dtype=np.float64) / _PER_RADIAN[normalize_unit(unit)]


def from_radians(values: ArrayLike, unit: str) -> NDArray[np.float64]:
    """Convert angles in radians to ``unit`` (vectorised)."""
    return np.asarray(values, dtype=np.float64) * _PER_RADIAN[normalize_unit(unit)]


def convert_angle(values: ArrayLike, src: str, dst: str) -> NDArray[np.float64]:
    """Convert angles between any two of deg, rad, gon."""
    return from_radians(to_radians(values, src), dst)


def wrap_pi(values: ArrayLike) -> NDArray[np.float64]:
    """Wrap radians into [-pi, pi)."""
    v = np.asarray(values, dtype=np.float64)
    return (v + np.pi) % (2.0 * np.pi) - np.pi


def check_plausible(values: ArrayLike, unit: str, limit_turns: float = 1.0) -> str | None:
    """Say why angles cannot be in ``unit``, or return None if they can.

    Angles above ``limit_turns`` full turns in magnitude are implausible for attitudes
    (e.g. values of 200 read as radians, or 0..400 gon read as degrees beyond 360).
    Used by readers to refuse, for example, degrees given where radians were declared.
    """
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        return None
    if not np.all(np.isfinite(v)):
        return "angle is not a finite number"
    turn = 2.0 * np.pi * _PER_RADIAN[normalize_unit(unit)]
    worst = float(np.max(np.abs(v)))
    if worst > limit_turns * turn:
        return f"angle {worst:g} exceeds {limit_turns:g} turn(s) ({limit_turns * turn:g} {unit}); wrong unit?"
    return None
