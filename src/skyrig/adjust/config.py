"""How to adjust a block: :class:`AdjustConfig`, made of four small frozen parts, each read where it is used.

* :class:`Unknowns` (``cfg.unknowns``) - which unknowns are free, fixed or weighted (with their prior
  sigma) and how the datum is defined (what pycolmap calls the ``BundleAdjustmentConfig``);
* :class:`SolverOptions` (``cfg.solver``) - the Levenberg-Marquardt iterations, tolerances and robust loss
  (pycolmap's ``BundleAdjustmentOptions``);
* :class:`ReliabilityOptions` (``cfg.reliability``) - Baarda's data snooping and its stopping rules;
* :class:`StatisticsOptions` (``cfg.statistics``) - covariance, redundancy numbers and which unknowns'
  covariance is wanted.

Build one from its parts (``AdjustConfig(unknowns=Unknowns(boresight="free"),
reliability=ReliabilityOptions(snooping=True))``) and change a part with :meth:`AdjustConfig.with_unknowns`,
:meth:`~AdjustConfig.with_solver`, :meth:`~AdjustConfig.with_reliability` or
:meth:`~AdjustConfig.with_statistics`.  Each part checks its own fields.

A configuration file (the ``adjustment`` section of a block file) holds one mapping per part
(``{"unknowns": {"boresight": "free"}, "reliability": {"snooping": true}}``).  The flat keys of earlier
releases (``{"boresight": "free", "snooping": true}``, :data:`FLAT_KEYS`) are read for one more release with
a :class:`DeprecationWarning` that names the new key (:meth:`AdjustConfig.from_dict`,
:meth:`AdjustConfig.from_flat`).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass, field, fields, replace
from typing import Any, Literal, Mapping

from skyrig.errors import ConfigError

Mode = Literal["fixed", "free", "weighted"]
MODES = ("fixed", "free", "weighted")

__all__ = ["Mode", "MODES", "Unknowns", "SolverOptions", "ReliabilityOptions", "StatisticsOptions",
           "AdjustConfig", "PARTS", "FLAT_KEYS"]


@dataclass(frozen=True)
class Unknowns:
    """Which unknowns the adjustment estimates (fixed / free / weighted, with the prior sigma of weighted ones)
    and how the datum is defined (see :class:`AdjustConfig` for each field)."""

    poses: Mode = "free"  # station poses: free, fixed or weighted (prior = starting value)
    pose_sigma_m: float = 1.0  # prior sigma of weighted pose centres (m)
    pose_sigma_rad: float = 1e-3  # prior sigma of weighted pose rotations (rad)
    points: Literal["free", "fixed"] = "free"  # object points
    intrinsics: Mode = "fixed"  # interior orientation / additional parameters
    intrinsic_names: tuple[str, ...] | None = None  # which intrinsics take part (None = all)
    intrinsic_sigma: tuple[tuple[str, float], ...] = ()  # prior sigma per intrinsic name (weighted)
    lever_arm: Mode = "fixed"  # GNSS lever arm
    lever_arm_sigma_m: float = 0.1
    boresight: Mode = "fixed"  # boresight correction of each head
    boresight_sigma_rad: float = 0.01
    datum_shift: Mode = "fixed"  # GNSS datum shift
    datum_shift_sigma_m: float = 1.0
    strip_shift: Mode = "fixed"  # per-strip GNSS shift
    strip_shift_sigma_m: float = 1.0
    strip_drift: Mode = "fixed"  # per-strip GNSS drift
    strip_drift_sigma_m_s: float = 0.01
    datum: Literal["auto", "free", "none"] = "auto"  # from observations, inner constraints, or none
    inner_constraints: Literal["poses", "points"] = "poses"  # what a free network's constraints act on
    datum_points: tuple[str, ...] = ()  # the datum points of inner constraints on points (empty = all)
    actuator: Mode = "fixed"  # actuator offset and scale of actuated heads
    actuator_sigma: tuple[float, float] = (1e-3, 1e-3)  # (offset rad, scale)
    actuator_curve: Mode = "fixed"  # Fourier correction curve of actuated heads
    actuator_fourier_order: int = 0  # order N of that curve
    actuator_curve_sigma_rad: float = 1e-3
    image_grid: Mode = "fixed"  # node values of the correction grids in observations["image_grid"]
    groups: tuple[tuple[str, Mode], ...] = ()  # (name, mode) of parameter groups declared by factor modules
    group_sigma: tuple[tuple[str, tuple[float, ...]], ...] = ()  # (name, prior sigma per component) of those

    def group_mode(self, name: str) -> Mode:
        """The mode of a parameter group declared by a factor module (default ``"fixed"``)."""
        return dict(self.groups).get(name, "fixed")

    def group_prior_sigma(self, name: str) -> tuple[float, ...]:
        """The prior sigma per component of a ``"weighted"`` module-declared group (ConfigError when missing)."""
        sig = dict(self.group_sigma).get(name)
        if sig is None:
            raise ConfigError(f"unknowns.groups makes {name!r} weighted but unknowns.group_sigma has no sigma for it")
        return tuple(float(v) for v in sig)

    def __post_init__(self) -> None:
        if int(self.actuator_fourier_order) < 0:
            raise ConfigError(f"unknowns.actuator_fourier_order must be >= 0, got {self.actuator_fourier_order}")
        for name in ("poses", "intrinsics", "lever_arm", "boresight", "datum_shift", "strip_shift", "strip_drift",
                     "actuator", "actuator_curve", "image_grid"):
            if getattr(self, name) not in MODES:
                raise ConfigError(f"unknowns.{name} must be one of {MODES}, got {getattr(self, name)!r}")
        for name, mode in self.groups:
            if mode not in MODES:
                raise ConfigError(f"unknowns.groups[{name!r}] must be one of {MODES}, got {mode!r}")
        if self.points not in ("free", "fixed"):
            raise ConfigError(f"unknowns.points must be 'free' or 'fixed', got {self.points!r}")
        if self.datum not in ("auto", "free", "none"):
            raise ConfigError(f"unknowns.datum must be 'auto', 'free' or 'none', got {self.datum!r}")
        if self.inner_constraints not in ("poses", "points"):
            raise ConfigError(f"unknowns.inner_constraints must be 'poses' or 'points', got "
                             f"{self.inner_constraints!r}")
        if self.inner_constraints == "points" and self.datum != "free":
            raise ConfigError("unknowns.inner_constraints='points' needs datum='free' (inner constraints define "
                             f"a free network's datum), got datum={self.datum!r}")
        if self.datum_points and self.inner_constraints != "points":
            raise ConfigError("unknowns.datum_points is given but inner_constraints is not 'points' (the datum "
                             "points are only used by inner constraints on points)")


@dataclass(frozen=True)
class SolverOptions:
    """The optimiser (see :class:`AdjustConfig` for each field)."""

    max_iterations: int = 50  # Levenberg-Marquardt iterations
    function_tolerance: float = 1e-6  # stop: relative cost decrease (Ceres's definition)
    parameter_tolerance: float = 1e-8  # stop: relative step
    gradient_tolerance: float = 1e-10  # stop: max gradient
    robust: Literal["huber"] | None = None  # robust reweighting of image observations
    robust_k: float = 2.5  # Huber threshold in units of the observation's sigma

    def __post_init__(self) -> None:
        if self.robust not in (None, "huber"):
            raise ConfigError(f"solver.robust must be None or 'huber', got {self.robust!r}")


@dataclass(frozen=True)
class ReliabilityOptions:
    """Baarda's data snooping (see :class:`AdjustConfig` for each field)."""

    snooping: bool = False  # reject the largest normalised residual above the critical value, re-adjust
    alpha: float = 0.001  # significance level (two-sided)
    familywise: bool = True  # alpha for the whole block (Bonferroni) instead of per test
    max_rejections: int = 100  # cap on rejected observations (reaching it is a failure), at least
    max_share: float = 0.02  # ... or this share of the tested observations, whichever is larger
    max_group_share: float = 0.1  # largest share of a GNSS / IMU / control / distance group
    per_round: int = 1  # image observations rejected per round at most (non-adjacent local maxima)
    per_round_share: float = 0.0  # ... or this share of the tested observations, whichever is larger

    def __post_init__(self) -> None:
        if int(self.per_round) < 1:
            raise ConfigError(f"reliability.per_round must be >= 1, got {self.per_round!r}")
        if not 0.0 <= float(self.per_round_share) <= 1.0:
            raise ConfigError(f"reliability.per_round_share must be in [0, 1], got {self.per_round_share!r}")
        if not 0.0 <= float(self.max_share) <= 1.0:
            raise ConfigError(f"reliability.max_share must be in [0, 1], got {self.max_share!r}")
        if not 0.0 < float(self.max_group_share) <= 1.0:
            raise ConfigError(f"reliability.max_group_share must be in (0, 1], got {self.max_group_share!r}")


@dataclass(frozen=True)
class StatisticsOptions:
    """Precision and reliability figures (see :class:`AdjustConfig` for each field)."""

    compute: bool = True  # covariance, redundancy numbers, normalised residuals
    max_parameters: int = 6000  # size limit of the reduced system for the dense inverse
    images: tuple[str, ...] = ()  # images / stations whose pose covariance is wanted at any size
    points: tuple[str, ...] = ()  # points whose covariance is wanted at any size


#: the parts of :class:`AdjustConfig`, by attribute name
PARTS: dict[str, type] = {"unknowns": Unknowns, "solver": SolverOptions, "reliability": ReliabilityOptions,
                          "statistics": StatisticsOptions}

#: the flat keys of earlier releases (block files, ``AdjustConfig.from_flat``) -> ``(part, field)``
FLAT_KEYS: dict[str, tuple[str, str]] = {
    **{f.name: ("unknowns", f.name) for f in fields(Unknowns) if f.name not in ("groups", "group_sigma")},
    **{f.name: ("solver", f.name) for f in fields(SolverOptions)},
    "snooping": ("reliability", "snooping"), "snooping_alpha": ("reliability", "alpha"),
    "snooping_familywise": ("reliability", "familywise"), "max_rejections": ("reliability", "max_rejections"),
    "snooping_max_share": ("reliability", "max_share"),
    "snooping_max_group_share": ("reliability", "max_group_share"),
    "snooping_per_round": ("reliability", "per_round"),
    "snooping_per_round_share": ("reliability", "per_round_share"),
    "statistics": ("statistics", "compute"), "max_statistics_parameters": ("statistics", "max_parameters"),
    "statistics_images": ("statistics", "images"), "statistics_points": ("statistics", "points"),
}


def _check_json_type(source: str, key: str, want: Any, v: Any) -> None:
    """A value read from a file must have the JSON type of the field's default (null, a text or a list is
    not a number...)."""
    if want is dataclasses.MISSING or want is None:
        return
    if isinstance(want, bool):
        ok = isinstance(v, bool)
    elif isinstance(want, (int, float)):
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    elif isinstance(want, str):
        ok = isinstance(v, str)
    elif isinstance(want, tuple):
        ok = isinstance(v, (list, tuple, dict))
    else:
        ok = True
    if not ok:
        raise ConfigError(f"{source}: adjustment option {key!r} must be {type(want).__name__} like its "
                          f"default {want!r}, got {v!r}")


def _file_value(part: str, key: str, v: Any) -> Any:
    """A field's value from its JSON form (lists -> tuples)."""
    if key in ("intrinsic_names",) and v is not None:
        return tuple(v)
    if key == "actuator_sigma":
        return tuple(float(x) for x in v)
    if (part, key) in (("statistics", "images"), ("statistics", "points"), ("unknowns", "datum_points")):
        return tuple(str(x) for x in v)
    if key == "intrinsic_sigma":
        return tuple(sorted(v.items())) if isinstance(v, dict) else tuple(map(tuple, v))
    if (part, key) == ("unknowns", "groups"):
        return tuple(sorted(v.items())) if isinstance(v, dict) else tuple(map(tuple, v))
    if (part, key) == ("unknowns", "group_sigma"):
        items = v.items() if isinstance(v, dict) else v
        return tuple(sorted((str(k), tuple(float(x) for x in sig)) for k, sig in items))
    return v


def _json_value(key: str, v: Any) -> Any:
    """A field's value as JSON (tuples -> lists)."""
    if key == "intrinsic_sigma":
        return [list(x) for x in v]
    if key in ("groups", "group_sigma"):
        return {k: (list(x) if isinstance(x, tuple) else x) for k, x in v}
    return list(v) if isinstance(v, tuple) else v


@dataclass(frozen=True)
class AdjustConfig:
    """How to adjust a block (frozen; unknown keys in a configuration file are an error): four parts.

    Attributes
    ----------
    unknowns
        :class:`Unknowns`: what is estimated and the datum.
    solver
        :class:`SolverOptions`: iterations, tolerances, robust loss.
    reliability
        :class:`ReliabilityOptions`: data snooping.
    statistics
        :class:`StatisticsOptions`: covariance and redundancy numbers.

    The fields of the parts (those without a part name are fields of ``unknowns``):

        poses
            Station poses: ``"free"`` (default), ``"fixed"`` or ``"weighted"`` (prior = starting value).
        pose_sigma_m, pose_sigma_rad
            Prior sigma of weighted poses (centre metres, rotation radians).
        points
            Object points: ``"free"`` (default) or ``"fixed"``.
        intrinsics
            ``"fixed"`` (default), ``"free"`` or ``"weighted"``: interior orientation / additional parameters.
        intrinsic_names
            Which intrinsics take part when not fixed (names of the camera's ``intrinsic_names``);
            None = all.  Others stay fixed.
        intrinsic_sigma
            Prior sigma per intrinsic name for ``"weighted"`` (units of the parameter).
        lever_arm, boresight, datum_shift, strip_shift, strip_drift
            Mode of these groups (default fixed).
        lever_arm_sigma_m, boresight_sigma_rad, datum_shift_sigma_m, strip_shift_sigma_m, strip_drift_sigma_m_s
            Prior sigma for ``"weighted"``.
        datum
            ``"auto"`` (control and/or GNSS, whatever the block has), or ``"free"``: inner constraints on
            the station poses (minimum norm of the pose corrections; 7-parameter similarity), or
            ``"none"``: no datum at all, the Levenberg-Marquardt damping picks one solution among the
            equivalent ones (as Ceres does for BAL problems); no rank check, no covariance.
        inner_constraints
            With ``datum="free"``: ``"poses"`` (default; minimum norm of the station pose corrections and of the
            scale-bar end points, which are estimated with them: the Moore-Penrose inverse of the reduced normal
            matrix) or
            ``"points"``: inner constraints on the object points, as close-range programs define the datum -
            the adjusted points keep the centroid, orientation (and, without a scale bar, the scale) of their
            starting coordinates (a Helmert fit of the adjusted onto the starting points, applied to the whole
            block), and the covariance is that of minimum trace over the datum points (an S-transformation).
        datum_points
            Names of the datum points for ``inner_constraints="points"`` (at least 3, not on one line);
            empty = every estimated point.
        solver.max_iterations
            Levenberg-Marquardt iterations.
        solver.function_tolerance, solver.parameter_tolerance, solver.gradient_tolerance
            Stop when the relative cost decrease, the relative step or the max gradient fall below these
            (Ceres's definitions).
        solver.robust
            ``None`` or ``"huber"``: robust reweighting of image observations (Huber's weights).
        solver.robust_k
            Huber threshold in units of the observation's sigma.
        reliability.snooping
            Run Baarda's data snooping: repeatedly reject the observation with the largest normalised
            residual above the critical value and re-adjust.
        reliability.alpha
            Significance level (two-sided), default 0.001.  With ``familywise`` (default) it is the
            probability of *any* false rejection in the block: each of the n tests uses ``alpha / n``
            (Bonferroni; n = 10,000 gives a critical value of 5.3); otherwise it is Baarda's per-test alpha0
            (0.001 -> 3.29, which rejects about one good observation per thousand tests).
        reliability.familywise
            See ``alpha``.
        reliability.max_rejections, reliability.max_share
            Cap on rejected observations: the larger of ``max_rejections`` (default 100) and ``max_share``
            (default 0.02) of the observations tested, so that a large block's cap grows with it.  Reaching it with observations still above the critical value is
            a failure of the adjustment (``AdjustmentResult.failures``): so many blunders mean a wrong model.
        reliability.max_group_share
            Largest share of a GNSS, IMU, control or distance group that data snooping may reject (at least
            3 observations): beyond it snooping stops and the result fails with a probable model error
            (uncalibrated boresight, lever arm, datum shift...) named in words.
        reliability.per_round
            Image observations rejected in one round at most (default 1: Baarda's one at a time).  Above 1,
            the round rejects the largest normalised residual and then every further image observation above
            the critical value that is the largest of its point and of its image among those above it and
            shares neither with a larger one (a blunder's residual spills into its point's other rays and
            weakly into its image; observations apart from it are tested as before).  Large blocks need one
            statistics pass per round, so this cuts their snooping time by the ratio.  While a GNSS / IMU /
            control / distance observation is above the critical value, rounds reject one observation.
        reliability.per_round_share
            With it the round's cap is the larger of ``per_round`` and this share of the tested observations
            (default 0: ``per_round`` alone), so that a large block's cap grows with it as its blunders do: with a
            fixed cap the rounds, each a statistics pass over the whole block, grow with the block (the 540-image
            midas-dsm growth run of issue 35: 19 solver iterations over its rounds against 10 at 240 images).
        statistics.compute
            Compute covariance, redundancy numbers and normalised residuals (costs one inverse of the
            reduced system; skipped above ``max_parameters``).
        statistics.max_parameters
            Size limit of the reduced system for full statistics.  Above it, only the covariance of chosen
            unknowns is computed (sparse solves with the factorised reduced system): every reduced unknown
            that is not a station pose (calibration, lever arm, boresight, shifts, actuator corrections,
            end points of distances) plus ``images`` and ``points``.
        statistics.images
            Image (or station) names whose pose covariance is wanted at any block size.
        statistics.points
            Point names whose covariance is wanted at any block size.
        actuator, actuator_sigma
            Mode of the actuator-angle correction of actuated heads (``offset`` rad and ``scale``: ``beta' =
            (1 + scale) beta + offset``) and its prior sigma ``(offset_rad, scale)`` for ``"weighted"``.
            Needs beta to vary over the head's images (a constant beta is reported as a datum defect).
        actuator_curve, actuator_fourier_order, actuator_curve_sigma_rad
            Mode, order N and prior sigma (rad) of the Fourier series of the periodic boresight curve
            (roll, pitch, yaw corrections, orders 1..N; the constant term is the head's boresight).  The
            first order in roll/pitch is the same motion as the actuator offset: estimate one of them.
        groups, group_sigma
            Mode and prior sigma (one per component) of the parameter groups that factor modules declare
            (:class:`~skyrig.adjust.factors.base.ParameterGroup`), by group name; absent = ``"fixed"``.
        image_grid
            Mode of the node values of the block's correction grids (``observations["image_grid"]``,
            :mod:`skyrig.adjust.factors.image_grid`): ``"fixed"`` (default: applied as known corrections),
            ``"weighted"`` (unknowns with each grid's collocation prior ``cov_px2``) or ``"free"`` (no prior).
    """

    unknowns: Unknowns = field(default_factory=Unknowns)
    solver: SolverOptions = field(default_factory=SolverOptions)
    reliability: ReliabilityOptions = field(default_factory=ReliabilityOptions)
    statistics: StatisticsOptions = field(default_factory=StatisticsOptions)

    def __post_init__(self) -> None:
        for name, cls in PARTS.items():
            if not isinstance(getattr(self, name), cls):
                raise ConfigError(f"AdjustConfig.{name} must be a {cls.__name__}, got {type(getattr(self, name)).__name__}")

    # ------------------------------------------------------------------ changed copies
    def with_unknowns(self, **changes: Any) -> "AdjustConfig":
        """A copy with fields of :attr:`unknowns` changed."""
        return replace(self, unknowns=replace(self.unknowns, **changes))

    def with_solver(self, **changes: Any) -> "AdjustConfig":
        """A copy with fields of :attr:`solver` changed."""
        return replace(self, solver=replace(self.solver, **changes))

    def with_reliability(self, **changes: Any) -> "AdjustConfig":
        """A copy with fields of :attr:`reliability` changed."""
        return replace(self, reliability=replace(self.reliability, **changes))

    def with_statistics(self, **changes: Any) -> "AdjustConfig":
        """A copy with fields of :attr:`statistics` changed."""
        return replace(self, statistics=replace(self.statistics, **changes))

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict[str, dict[str, Any]]:
        """The fields that differ from their default, one mapping per part (JSON types; :meth:`from_dict`)."""
        out: dict[str, dict[str, Any]] = {}
        for name in PARTS:
            part = getattr(self, name)
            d = {f.name: _json_value(f.name, getattr(part, f.name)) for f in fields(part)
                 if getattr(part, f.name) != f.default}
            if d:
                out[name] = d
        return out

    def keys(self) -> frozenset[str]:
        """``part.field`` of every field that differs from its default."""
        return frozenset(f"{p}.{k}" for p, d in self.to_dict().items() for k in d)

    @staticmethod
    def file_keys(data: Mapping[str, Any]) -> frozenset[str]:
        """``part.field`` of every field a configuration mapping sets (flat keys of earlier releases
        included, see :data:`FLAT_KEYS`)."""
        out: set[str] = set()
        for k, v in data.items():
            if k in PARTS and isinstance(v, Mapping):
                out.update(f"{k}.{f}" for f in v)
            elif k in FLAT_KEYS:
                out.add(".".join(FLAT_KEYS[k]))
        return frozenset(out)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str = "config") -> "AdjustConfig":
        """Build from a mapping of parts (``{"unknowns": {...}, "solver": {...}, ...}``); unknown keys raise
        :class:`~skyrig.errors.ConfigError` naming them.  A flat key of earlier releases (:data:`FLAT_KEYS`)
        still works, with a :class:`DeprecationWarning` naming its new key."""
        parts: dict[str, dict[str, Any]] = {name: {} for name in PARTS}
        bad = []
        for key, v in data.items():
            if key in PARTS and (isinstance(v, Mapping) or key not in FLAT_KEYS):
                if not isinstance(v, Mapping):
                    raise ConfigError(f"{source}: adjustment part {key!r} must be a mapping of its fields, got {v!r}")
                parts[key].update(v)
            elif key in FLAT_KEYS:  # ("statistics": true/false is the flat key of statistics.compute)
                part, name = FLAT_KEYS[key]
                warnings.warn(f"{source}: adjustment option {key!r} is deprecated, write {part}.{name} "
                              f"(\"{part}\": {{\"{name}\": ...}}); the flat key goes in the next release",
                              DeprecationWarning, stacklevel=2)
                parts[part][name] = v
            else:
                bad.append(key)
        if bad:
            raise ConfigError(f"{source}: unknown adjustment option(s) {sorted(bad)}; the parts are "
                              f"{sorted(PARTS)}")
        built = {}
        for name, cls_ in PARTS.items():
            known = {f.name: f for f in fields(cls_)}
            unknown = sorted(set(parts[name]) - set(known))
            if unknown:
                raise ConfigError(f"{source}: unknown adjustment option(s) {[f'{name}.{k}' for k in unknown]}; "
                                  f"known in {name}: {sorted(known)}")
            kw = {}
            for k, v in parts[name].items():
                _check_json_type(source, f"{name}.{k}", known[k].default, v)
                kw[k] = _file_value(name, k, v)
            built[name] = cls_(**kw)
        return cls(**built)

    @classmethod
    def from_flat(cls, flat: Mapping[str, Any]) -> "AdjustConfig":
        """The configuration from the flat keyword names of earlier releases (:data:`FLAT_KEYS`, e.g.
        ``{"boresight": "free", "snooping": True}``): deprecated, one :class:`DeprecationWarning` naming the
        new keys; write the parts instead."""
        parts: dict[str, dict[str, Any]] = {name: {} for name in PARTS}
        bad = sorted(set(flat) - set(FLAT_KEYS))
        if bad:
            raise ConfigError(f"unknown adjustment option(s) {bad}; known: {sorted(FLAT_KEYS)}")
        for k, v in flat.items():
            part, name = FLAT_KEYS[k]
            parts[part][name] = v
        if flat:
            warnings.warn("flat AdjustConfig options are deprecated: write "
                          + ", ".join(f"{FLAT_KEYS[k][0]}.{FLAT_KEYS[k][1]}" for k in flat), DeprecationWarning,
                          stacklevel=2)
        return cls(**{name: PARTS[name](**kw) for name, kw in parts.items()})
