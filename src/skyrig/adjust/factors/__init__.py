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
``rolling_shutter`` the rolling-shutter cameras and the priors of their readout time and of the stations'
               velocities; registers the groups ``rs_motion`` / ``rs_readout`` and re-registers ``image``
               (a subclass) so that rolling-shutter rows are projected at their row's pose
=============  =========================================================================================

How to add an observation type
------------------------------
One new module (plus its tests), nothing else in skyrig changes:

1. a data class with the rows as required arrays (``__len__``; checked once in the type's
   :meth:`~ObservationType.normalise` / :meth:`~ObservationType.validate`), stored by the caller as
   ``block.observations[name]`` (``dataclasses.replace(block, observations={**block.observations, name: rows})``);
2. a subclass of :class:`ObservationType` with its group name, words, components and units, and
   :meth:`~ObservationType.evaluate`: whitened residuals and the Jacobian on the reduced columns of
   ``model.layout`` (``pose``, ``intr``, ``groups[...]``...) and/or one eliminated point;
3. ``register(MyType())`` at import of the module (a module outside the package imports it before building
   blocks).

How to add unknowns of one's own (a parameter group)
----------------------------------------------------
A module that needs new unknowns (a rolling-shutter line delay per station, a laser scanner's lever arm,
boresight and range offset, a new prior's hyper-parameter...) declares them in the same file: a subclass of
:class:`~skyrig.adjust.factors.base.ParameterGroup` (name, components with units, owners, start values from
``block.parameters[name]``, :meth:`~ParameterGroup.retract` for a non-additive update) registered with
:func:`register_group`.  The adjustment then gives it columns (``model.layout.groups[name]``, labels
``(name, owner, component)``), current values (``state.groups[name]``), a prior ``prior:<name>`` when the
configuration weights it, its covariance in the statistics, and its adjusted values in the result's
``block.parameters[name]``.  Its mode and prior sigma are configuration: ``AdjustConfig(unknowns=Unknowns(
groups=((name, "free"),), group_sigma=((name, (0.01,)),)))`` (block files: ``{"unknowns": {"groups":
{name: "weighted"}, "group_sigma": {name: [0.01]}}}``).

Examples outside the package: ``tests/test_adjust_factor_registry.py`` (a levelled-height type) and
``tests/test_adjust_parameter_group.py`` (a barometric altimeter with its own offset unknown).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from skyrig.adjust.factors.base import (BlockError, Factor, ObservationType, ParameterGroup, any_on,
                                        whitening_matrices)

__all__ = ["ObservationType", "ParameterGroup", "Factor", "BlockError", "register", "unregister", "observation_types",
           "observation_type", "require_type", "image_type", "register_group", "unregister_group", "parameter_groups", "any_on", "whitening_matrices"]

if TYPE_CHECKING:  # pragma: no cover
    from skyrig.adjust.factors.image import Image

_REGISTRY: dict[str, ObservationType] = {}
_GROUPS: dict[str, ParameterGroup] = {}
_SORTED: list[ObservationType] = []
#: the built-in types, imported on first use of the registry (their modules import the block and the
#: model, which import this package: loading them lazily keeps the imports one-way)
BUILTIN = ("image", "control", "gnss", "imu", "distance", "prior", "calibration", "rolling_shutter")
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


def register_group(group: ParameterGroup, replace: bool = False) -> ParameterGroup:
    """Register a parameter group (an instance, see :class:`ParameterGroup`) under ``group.name``; returns it.

    The name must not be one of the built-in groups (``Unknowns`` fields) or taken by another group unless
    ``replace``."""
    from skyrig.adjust.config import Unknowns

    name = group.name
    if not name or ":" in name or name in Unknowns.__dataclass_fields__:
        raise ValueError(f"a parameter group needs a new name without ':', got {name!r}")
    if name in _GROUPS and not replace and _GROUPS[name] is not group:
        raise ValueError(f"parameter group {name!r} is already registered ({type(_GROUPS[name]).__module__})")
    if not group.components:
        raise ValueError(f"parameter group {name!r} has no components")
    _GROUPS[name] = group
    return group


def unregister_group(name: str) -> None:
    """Remove a registered parameter group (tests)."""
    _GROUPS.pop(name, None)


def parameter_groups() -> list[ParameterGroup]:
    """The registered parameter groups, in registration order (their columns follow the built-in ones)."""
    _load_builtins()
    return list(_GROUPS.values())


def observation_types() -> list[ObservationType]:
    """The registered types in evaluation order."""
    _load_builtins()
    return _SORTED


def require_type(group: str) -> ObservationType:
    """The type of a group name (:func:`observation_type`); :class:`BlockError` when no type owns it."""
    t = observation_type(group)
    if t is None:
        raise BlockError(f"no observation type owns the group {group!r} (registered: {sorted(_REGISTRY)})")
    return t


def image_type() -> "Image":
    """The built-in image observation type (its own methods: rays per point, the image factor alone)."""
    from skyrig.adjust.factors.image import IMAGE

    return IMAGE  # type: ignore[return-value]


def observation_type(group: str) -> ObservationType | None:
    """The type of a group name (``"prior:pose"`` -> the ``prior`` type), None if unknown."""
    _load_builtins()
    t = _REGISTRY.get(group)
    if t is None and ":" in group:
        t = _REGISTRY.get(group.split(":", 1)[0])
    return t

