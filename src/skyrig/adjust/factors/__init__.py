"""Observation types of the adjustment, one module each (DESIGN.md convention 5).

Each module holds one observation type (:class:`~skyrig.adjust.factors.base.ObservationType`): its data,
residual and Jacobian, group name, sigma / covariance and report labels, and registers it here with
:func:`register`.  The built-in types are registered on import of this package:

=============  =========================================================================================
module         observation
=============  =========================================================================================
``image``      image coordinates of object points (frame and BAL cameras, rigs, actuated heads)
``control``    ground coordinates of control points (check points are compared, not used)
``gnss``       GNSS antenna positions (lever arm, datum shift, per-strip shift and drift)
``imu``        IMU attitudes of the stations
``distance``   distances between two object points (scale bars)
``prior``      priors on the station poses (``poses="weighted"``)
``calibration`` priors on the calibration unknowns (interior orientation, boresight, lever arm, datum
               and strip shifts, actuator offset / scale and correction curve) when ``"weighted"``
``image_grid`` the collocation prior of a camera's correction-grid node values (``image_grid="weighted"``;
               the grid's bilinear value is added to the projected pixel in ``image``)
=============  =========================================================================================

Adding an observation type is adding a module: subclass ``ObservationType``, keep the rows in a data
object stored as ``block.observations[name]``, and call :func:`register` at import (see
``tests/test_adjust_factor_registry.py`` for a levelled-height type defined outside the package).
"""

from __future__ import annotations

import importlib

from skyrig.adjust.factors.base import BlockError, Factor, ObservationType, any_on, whitening_matrices

__all__ = ["ObservationType", "Factor", "BlockError", "register", "unregister", "observation_types", "observation_type",
           "any_on", "whitening_matrices"]

_REGISTRY: dict[str, ObservationType] = {}
_SORTED: list[ObservationType] = []
#: the built-in types, imported on first use of the registry (their modules import the block and the
#: model, which import this package: loading them lazily keeps the imports one-way)
BUILTIN = ("image", "control", "gnss", "imu", "distance", "prior", "calibration")
_loaded = False


def _load_builtins() -> None:
    global _loaded
    if not _loaded:
        _loaded = True
        for m in BUILTIN:
            importlib.import_module(f"skyrig.adjust.factors.{m}")


def register(obs_type: ObservationType, replace: bool = False) -> ObservationType:
    """Register an observation type (an instance) under ``obs_type.name``; returns it.

    A second type with the same name is an error unless ``replace``.
    """
    name = obs_type.name
    if not name or ":" in name:
        raise ValueError(f"an observation type needs a group name without ':', got {name!r}")
    if name in _REGISTRY and not replace and _REGISTRY[name] is not obs_type:
        raise ValueError(f"observation type {name!r} is already registered ({type(_REGISTRY[name]).__module__})")
    _REGISTRY[name] = obs_type
    _SORTED[:] = sorted(_REGISTRY.values(), key=lambda t: t.order)  # stable: registration order on ties
    return obs_type


def unregister(name: str) -> None:
    """Remove a registered type (tests)."""
    _REGISTRY.pop(name, None)
    _SORTED[:] = sorted(_REGISTRY.values(), key=lambda t: t.order)


def observation_types() -> list[ObservationType]:
    """The registered types in evaluation order."""
    _load_builtins()
    return _SORTED


def observation_type(group: str) -> ObservationType | None:
    """The type of a group name (``"prior:pose"`` -> the ``prior`` type), None if unknown."""
    _load_builtins()
    t = _REGISTRY.get(group)
    if t is None and ":" in group:
        t = _REGISTRY.get(group.split(":", 1)[0])
    return t

