"""How to adjust a block: four small frozen configurations and the :class:`AdjustConfig` facade over them.

* :class:`ParameterModes` - which unknowns are free, fixed or weighted (with their prior sigma) and how
  the datum is defined (what pycolmap calls the ``BundleAdjustmentConfig``);
* :class:`SolverOptions` - the Levenberg-Marquardt iterations, tolerances and robust loss (pycolmap's
  ``BundleAdjustmentOptions``);
* :class:`ReliabilityOptions` - Baarda's data snooping and its stopping rules;
* :class:`StatisticsOptions` - covariance, redundancy numbers and which unknowns' covariance is wanted.

:class:`AdjustConfig` keeps every option as one flat keyword (``AdjustConfig(boresight="free",
snooping=True)``, block files, presets, ``dataclasses.replace``); :attr:`AdjustConfig.parameter_modes`,
:attr:`~AdjustConfig.solver_options`, :attr:`~AdjustConfig.reliability_options` and
:attr:`~AdjustConfig.statistics_options` give the four parts, and :meth:`AdjustConfig.compose` builds one
from them.  The parts own their checks.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields, replace
from typing import Literal

from skyrig.errors import ConfigError

Mode = Literal["fixed", "free", "weighted"]
MODES = ("fixed", "free", "weighted")

__all__ = ["Mode", "MODES", "ParameterModes", "SolverOptions", "ReliabilityOptions", "StatisticsOptions",
           "AdjustConfig", "PARTS"]


@dataclass(frozen=True)
class ParameterModes:
    """Which unknowns the adjustment estimates, and the datum (see :class:`AdjustConfig` for each field)."""

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

    def __post_init__(self) -> None:
        if int(self.actuator_fourier_order) < 0:
            raise ConfigError(f"AdjustConfig.actuator_fourier_order must be >= 0, got {self.actuator_fourier_order}")
        for name in ("poses", "intrinsics", "lever_arm", "boresight", "datum_shift", "strip_shift", "strip_drift",
                     "actuator", "actuator_curve", "image_grid"):
            if getattr(self, name) not in MODES:
                raise ConfigError(f"AdjustConfig.{name} must be one of {MODES}, got {getattr(self, name)!r}")
        if self.points not in ("free", "fixed"):
            raise ConfigError(f"AdjustConfig.points must be 'free' or 'fixed', got {self.points!r}")
        if self.datum not in ("auto", "free", "none"):
            raise ConfigError(f"AdjustConfig.datum must be 'auto', 'free' or 'none', got {self.datum!r}")
        if self.inner_constraints not in ("poses", "points"):
            raise ConfigError(f"AdjustConfig.inner_constraints must be 'poses' or 'points', got "
                             f"{self.inner_constraints!r}")
        if self.inner_constraints == "points" and self.datum != "free":
            raise ConfigError("AdjustConfig.inner_constraints='points' needs datum='free' (inner constraints define "
                             f"a free network's datum), got datum={self.datum!r}")
        if self.datum_points and self.inner_constraints != "points":
            raise ConfigError("AdjustConfig.datum_points is given but inner_constraints is not 'points' (the datum "
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
            raise ConfigError(f"AdjustConfig.robust must be None or 'huber', got {self.robust!r}")


@dataclass(frozen=True)
class ReliabilityOptions:
    """Baarda's data snooping (see :class:`AdjustConfig` for each field)."""

    snooping: bool = False  # reject the largest normalised residual above the critical value, re-adjust
    snooping_alpha: float = 0.001  # significance level (two-sided)
    snooping_familywise: bool = True  # alpha for the whole block (Bonferroni) instead of per test
    max_rejections: int = 100  # cap on rejected observations (reaching it is a failure), at least
    snooping_max_share: float = 0.02  # ... or this share of the tested observations, whichever is larger
    snooping_max_group_share: float = 0.1  # largest share of a GNSS / IMU / control / distance group
    snooping_per_round: int = 1  # image observations rejected per round at most (non-adjacent local maxima)

    def __post_init__(self) -> None:
        if int(self.snooping_per_round) < 1:
            raise ConfigError(f"AdjustConfig.snooping_per_round must be >= 1, got {self.snooping_per_round!r}")
        if not 0.0 <= float(self.snooping_max_share) <= 1.0:
            raise ConfigError(f"AdjustConfig.snooping_max_share must be in [0, 1], got {self.snooping_max_share!r}")
        if not 0.0 < float(self.snooping_max_group_share) <= 1.0:
            raise ConfigError(f"AdjustConfig.snooping_max_group_share must be in (0, 1], got "
                             f"{self.snooping_max_group_share!r}")


@dataclass(frozen=True)
class StatisticsOptions:
    """Precision and reliability figures (see :class:`AdjustConfig` for each field)."""

    statistics: bool = True  # covariance, redundancy numbers, normalised residuals
    max_statistics_parameters: int = 6000  # size limit of the reduced system for the dense inverse
    statistics_images: tuple[str, ...] = ()  # images / stations whose pose covariance is wanted at any size
    statistics_points: tuple[str, ...] = ()  # points whose covariance is wanted at any size


#: the parts of :class:`AdjustConfig`, by the name of its accessor
PARTS = {"parameter_modes": ParameterModes, "solver_options": SolverOptions,
         "reliability_options": ReliabilityOptions, "statistics_options": StatisticsOptions}


def _part(cfg: "AdjustConfig", cls: type):  # type: ignore[no-untyped-def]
    return cls(**{f.name: getattr(cfg, f.name) for f in fields(cls)})


@dataclass(frozen=True)
class AdjustConfig:
    """How to adjust a block (frozen; unknown keys in a config file are an error): the facade over
    :class:`ParameterModes`, :class:`SolverOptions`, :class:`ReliabilityOptions` and
    :class:`StatisticsOptions` (every field of the parts, flat, with the same name and default).

    Attributes
    ----------
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
    max_iterations
        Levenberg-Marquardt iterations.
    function_tolerance, parameter_tolerance, gradient_tolerance
        Stop when the relative cost decrease, the relative step or the max gradient fall below these
        (Ceres's definitions).
    robust
        ``None`` or ``"huber"``: robust reweighting of image observations (Huber's weights).
    robust_k
        Huber threshold in units of the observation's sigma.
    snooping
        Run Baarda's data snooping: repeatedly reject the observation with the largest normalised
        residual above the critical value and re-adjust.
    snooping_alpha
        Significance level (two-sided), default 0.001.  With ``snooping_familywise`` (default) it is the
        probability of *any* false rejection in the block: each of the n tests uses ``alpha / n``
        (Bonferroni; n = 10,000 gives a critical value of 5.3); otherwise it is Baarda's per-test alpha0
        (0.001 -> 3.29, which rejects about one good observation per thousand tests).
    snooping_familywise
        See ``snooping_alpha``.
    max_rejections, snooping_max_share
        Cap on rejected observations: the larger of ``max_rejections`` (default 100) and ``snooping_max_share``
        (default 0.02) of the observations tested, so that a large block's cap grows with it.  Reaching it with observations still above the critical value is
        a failure of the adjustment (``AdjustmentResult.failures``): so many blunders mean a wrong model.
    snooping_max_group_share
        Largest share of a GNSS, IMU, control or distance group that data snooping may reject (at least
        3 observations): beyond it snooping stops and the result fails with a probable model error
        (uncalibrated boresight, lever arm, datum shift...) named in words.
    snooping_per_round
        Image observations rejected in one round at most (default 1: Baarda's one at a time).  Above 1,
        the round rejects the largest normalised residual and then every further image observation above
        the critical value that is the largest of its point and of its image among those above it and
        shares neither with a larger one (a blunder's residual spills into its point's other rays and
        weakly into its image; observations apart from it are tested as before).  Large blocks need one
        statistics pass per round, so this cuts their snooping time by the ratio.  While a GNSS / IMU /
        control / distance observation is above the critical value, rounds reject one observation.
    statistics
        Compute covariance, redundancy numbers and normalised residuals (costs one inverse of the
        reduced system; skipped above ``max_statistics_parameters``).
    max_statistics_parameters
        Size limit of the reduced system for full statistics.  Above it, only the covariance of chosen
        unknowns is computed (sparse solves with the factorised reduced system): every reduced unknown
        that is not a station pose (calibration, lever arm, boresight, shifts, actuator corrections,
        end points of distances) plus ``statistics_images`` and ``statistics_points``.
    statistics_images
        Image (or station) names whose pose covariance is wanted at any block size.
    statistics_points
        Point names whose covariance is wanted at any block size.
    actuator, actuator_sigma
        Mode of the actuator-angle correction of actuated heads (``offset`` rad and ``scale``: ``beta' =
        (1 + scale) beta + offset``) and its prior sigma ``(offset_rad, scale)`` for ``"weighted"``.
        Needs beta to vary over the head's images (a constant beta is reported as a datum defect).
    actuator_curve, actuator_fourier_order, actuator_curve_sigma_rad
        Mode, order N and prior sigma (rad) of the Fourier series of the periodic boresight curve
        (roll, pitch, yaw corrections, orders 1..N; the constant term is the head's boresight).  The
        first order in roll/pitch is the same motion as the actuator offset: estimate one of them.
    image_grid
        Mode of the node values of the block's correction grids (``observations["image_grid"]``,
        :mod:`skyrig.adjust.factors.image_grid`): ``"fixed"`` (default: applied as known corrections),
        ``"weighted"`` (unknowns with each grid's collocation prior ``cov_px2``) or ``"free"`` (no prior).
    """

    poses: Mode = "free"
    pose_sigma_m: float = 1.0
    pose_sigma_rad: float = 1e-3
    points: Literal["free", "fixed"] = "free"
    intrinsics: Mode = "fixed"
    intrinsic_names: tuple[str, ...] | None = None
    intrinsic_sigma: tuple[tuple[str, float], ...] = ()
    lever_arm: Mode = "fixed"
    lever_arm_sigma_m: float = 0.1
    boresight: Mode = "fixed"
    boresight_sigma_rad: float = 0.01
    datum_shift: Mode = "fixed"
    datum_shift_sigma_m: float = 1.0
    strip_shift: Mode = "fixed"
    strip_shift_sigma_m: float = 1.0
    strip_drift: Mode = "fixed"
    strip_drift_sigma_m_s: float = 0.01
    datum: Literal["auto", "free", "none"] = "auto"
    inner_constraints: Literal["poses", "points"] = "poses"
    datum_points: tuple[str, ...] = ()
    max_iterations: int = 50
    function_tolerance: float = 1e-6
    parameter_tolerance: float = 1e-8
    gradient_tolerance: float = 1e-10
    robust: Literal["huber"] | None = None
    robust_k: float = 2.5
    snooping: bool = False
    snooping_alpha: float = 0.001
    snooping_familywise: bool = True
    max_rejections: int = 100
    snooping_max_share: float = 0.02
    snooping_max_group_share: float = 0.1
    snooping_per_round: int = 1
    statistics: bool = True
    max_statistics_parameters: int = 6000
    statistics_images: tuple[str, ...] = ()
    statistics_points: tuple[str, ...] = ()
    actuator: Mode = "fixed"
    actuator_sigma: tuple[float, float] = (1e-3, 1e-3)
    actuator_curve: Mode = "fixed"
    actuator_fourier_order: int = 0
    actuator_curve_sigma_rad: float = 1e-3
    image_grid: Mode = "fixed"

    def __post_init__(self) -> None:
        for cls in PARTS.values():  # each part checks its own fields
            _part(self, cls)

    @property
    def parameter_modes(self) -> ParameterModes:
        """Which unknowns are free / fixed / weighted, and the datum."""
        return _part(self, ParameterModes)  # type: ignore[no-any-return]

    @property
    def solver_options(self) -> SolverOptions:
        """Iterations, tolerances, robust loss."""
        return _part(self, SolverOptions)  # type: ignore[no-any-return]

    @property
    def reliability_options(self) -> ReliabilityOptions:
        """Data snooping."""
        return _part(self, ReliabilityOptions)  # type: ignore[no-any-return]

    @property
    def statistics_options(self) -> StatisticsOptions:
        """Covariance and redundancy numbers."""
        return _part(self, StatisticsOptions)  # type: ignore[no-any-return]

    @classmethod
    def compose(cls, parameter_modes: ParameterModes | None = None, solver_options: SolverOptions | None = None,
                reliability_options: ReliabilityOptions | None = None,
                statistics_options: StatisticsOptions | None = None) -> "AdjustConfig":
        """An :class:`AdjustConfig` from its parts (defaults for the parts not given)."""
        kw: dict = {}
        for part in (parameter_modes or ParameterModes(), solver_options or SolverOptions(),
                     reliability_options or ReliabilityOptions(), statistics_options or StatisticsOptions()):
            kw.update({f.name: getattr(part, f.name) for f in fields(part)})
        return cls(**kw)

    def with_(self, **changes: object) -> "AdjustConfig":
        return replace(self, **changes)  # type: ignore[arg-type]

    @classmethod
    def from_dict(cls, data: dict, source: str = "config") -> "AdjustConfig":
        """Build from a mapping; unknown keys raise :class:`~skyrig.errors.ConfigError` naming them."""
        known = set(cls.__dataclass_fields__)
        bad = sorted(set(data) - known)
        if bad:
            raise ConfigError(f"{source}: unknown adjustment option(s) {bad}; known: {sorted(known)}")
        for key, v in data.items():  # the JSON type the default has (null, a text or a list is not a number...)
            want = cls.__dataclass_fields__[key].default
            if want is dataclasses.MISSING or want is None:
                continue
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
        d = dict(data)
        if "intrinsic_names" in d and d["intrinsic_names"] is not None:
            d["intrinsic_names"] = tuple(d["intrinsic_names"])
        if "actuator_sigma" in d:
            d["actuator_sigma"] = tuple(float(v) for v in d["actuator_sigma"])
        for key in ("statistics_images", "statistics_points", "datum_points"):
            if key in d:
                d[key] = tuple(str(v) for v in d[key])
        if "intrinsic_sigma" in d:
            v = d["intrinsic_sigma"]
            d["intrinsic_sigma"] = tuple(sorted(v.items())) if isinstance(v, dict) else tuple(map(tuple, v))
        return cls(**d)
