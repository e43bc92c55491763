"""What a calibration adds to a rig: per head, the uncertainty of its lever arm, boresight, interior orientation and
actuator curve (each a :class:`CovarianceBlock`: sigma and correlations), and where the figures come from
(:class:`Provenance`: flight, date, recipe, statistics, software version).

The calibrated *values* live in the :class:`~skyrig.rig.rig.Rig` itself (a head's camera, lever arm, boresight and
actuator curve); a :class:`RigCalibration` travels next to it and is written into the rig file
(``docs/formats/rig_file.md``, key ``calibration``) by :func:`skyrig.io.rig_file.write_rig` and read back by
:func:`skyrig.io.rig_file.read_calibrated_rig`.  Plain data, no numerics beyond numpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import SkyrigError

__all__ = ["CovarianceBlock", "Provenance", "HeadCalibration", "RigCalibration", "LEVER_ARM_PARAMETERS",
           "BORESIGHT_PARAMETERS"]

#: parameter names of a lever-arm block (body frame, metres)
LEVER_ARM_PARAMETERS = ("x", "y", "z")
#: parameter names of a boresight block (about the camera axes, degrees)
BORESIGHT_PARAMETERS = ("omega", "phi", "kappa")


@dataclass(frozen=True, eq=False)
class CovarianceBlock:
    """Sigma and correlations of a group of parameters (a covariance block).

    Attributes
    ----------
    parameters
        ``(P,)`` parameter names (units: those of the group, e.g. the camera's intrinsic names for an
        interior orientation).
    sigma
        ``(P,)`` standard deviations, >= 0, in the parameters' units.
    correlation
        ``(P, P)`` symmetric, unit diagonal, entries in [-1, 1].
    values
        ``(P,)`` optional estimated values (for groups whose values the rig does not hold, e.g. actuator
        offset, scale and Fourier terms of an in-flight curve).
    """

    parameters: tuple[str, ...]
    sigma: NDArray[np.float64]
    correlation: NDArray[np.float64]
    values: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        names = tuple(str(n) for n in self.parameters)
        p = len(names)
        if p == 0 or len(set(names)) != p:
            raise SkyrigError(f"a covariance block needs distinct parameter names, got {list(names)}")
        s = np.asarray(self.sigma, dtype=np.float64).reshape(-1)
        if s.shape != (p,) or not np.all(np.isfinite(s)) or np.any(s < 0):
            raise SkyrigError(f"sigma must be {p} finite numbers >= 0, got {s.tolist()}")
        c = np.asarray(self.correlation, dtype=np.float64)
        if c.shape != (p, p) or not np.all(np.isfinite(c)):
            raise SkyrigError(f"correlation must be a finite {p} x {p} matrix, got shape {c.shape}")
        if np.abs(c - c.T).max() > 1e-9 or np.abs(np.diag(c) - 1).max() > 1e-9 or np.abs(c).max() > 1 + 1e-9:
            raise SkyrigError("correlation must be symmetric with a unit diagonal and entries in [-1, 1]")
        if np.linalg.eigvalsh(0.5 * (c + c.T))[0] < -1e-8:
            raise SkyrigError("correlation is not positive semi-definite")
        v = None
        if self.values is not None:
            v = np.asarray(self.values, dtype=np.float64).reshape(-1)
            if v.shape != (p,) or not np.all(np.isfinite(v)):
                raise SkyrigError(f"values must be {p} finite numbers")
        object.__setattr__(self, "parameters", names)
        object.__setattr__(self, "sigma", s)
        object.__setattr__(self, "correlation", 0.5 * (c + c.T))
        object.__setattr__(self, "values", v)

    @classmethod
    def from_covariance(cls, parameters: Sequence[str], covariance: ArrayLike,
                        values: ArrayLike | None = None) -> "CovarianceBlock":
        """From a ``(P, P)`` covariance matrix (a zero variance gives zero correlations)."""
        cv = np.asarray(covariance, dtype=np.float64)
        cv = 0.5 * (cv + cv.T)
        s = np.sqrt(np.clip(np.diag(cv), 0, None))
        with np.errstate(divide="ignore", invalid="ignore"):
            corr = cv / np.outer(s, s)
        corr[~np.isfinite(corr)] = 0.0
        corr = np.clip(corr, -1.0, 1.0)
        np.fill_diagonal(corr, 1.0)
        return cls(tuple(parameters), s, corr, None if values is None else np.asarray(values, dtype=np.float64))

    @property
    def covariance(self) -> NDArray[np.float64]:
        """``(P, P)`` covariance ``diag(sigma) R diag(sigma)``."""
        return self.correlation * np.outer(self.sigma, self.sigma)

    def sigma_of(self, name: str) -> float:
        """The sigma of the parameter called ``name``."""
        return float(self.sigma[self.parameters.index(name)])

    def isclose(self, other: "CovarianceBlock", rtol: float = 1e-12) -> bool:
        def close(a: Any, b: Any) -> bool:
            return (a is None and b is None) or (a is not None and b is not None
                                                 and bool(np.allclose(a, b, rtol=rtol, atol=0)))
        return (self.parameters == other.parameters and close(self.sigma, other.sigma)
                and bool(np.allclose(self.correlation, other.correlation, rtol=0, atol=1e-12))
                and close(self.values, other.values))


@dataclass(frozen=True)
class Provenance:
    """Where a calibration comes from.

    Attributes
    ----------
    recipe
        The calibration recipe (``skyrig calibrate RECIPE``, e.g. ``camera``) or the program that made it.
    flight
        Flight, session or data set (free text).
    date
        Date of the data (ISO 8601 text, e.g. ``2011-05-12``).
    software
        Program and version that computed it (e.g. ``skyrig 0.9.0``).
    statistics
        Numbers of the adjustment: ``sigma0``, ``redundancy``, ``n_observations``, ``n_unknowns``,
        ``image_sigma_px``, ``residual_rms_px``...
    notes
        Free text.
    """

    recipe: str
    flight: str = ""
    date: str = ""
    software: str = ""
    statistics: Mapping[str, float] = field(default_factory=dict)
    notes: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.recipe, str) or not self.recipe.strip():
            raise SkyrigError("provenance needs a recipe")
        stats = {}
        for k, v in dict(self.statistics).items():
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v):
                raise SkyrigError(f"provenance statistic {k!r} must be a finite number, got {v!r}")
            stats[str(k)] = int(v) if isinstance(v, (int, np.integer)) else float(v)
        object.__setattr__(self, "statistics", stats)


@dataclass(frozen=True)
class HeadCalibration:
    """The uncertainty and provenance of one head's calibrated values (any group may be absent).

    ``lever_arm_m``: parameters ``x, y, z`` (m, body frame); ``boresight_opk_deg``: ``omega, phi, kappa`` (deg,
    camera axes); ``interior``: names of the camera's intrinsics (:attr:`FrameCamera.intrinsic_names`, their own
    units); ``actuator``: names chosen by the recipe (e.g. ``offset_deg``, ``scale``, Fourier terms), with values.
    """

    lever_arm_m: CovarianceBlock | None = None
    boresight_opk_deg: CovarianceBlock | None = None
    interior: CovarianceBlock | None = None
    actuator: CovarianceBlock | None = None
    provenance: Provenance | None = None

    def __post_init__(self) -> None:
        for name, fixed in (("lever_arm_m", LEVER_ARM_PARAMETERS), ("boresight_opk_deg", BORESIGHT_PARAMETERS)):
            b = getattr(self, name)
            if b is not None and b.parameters != fixed:
                raise SkyrigError(f"{name} block must have parameters {list(fixed)}, got {list(b.parameters)}")
        if self.actuator is not None and self.actuator.values is None:
            raise SkyrigError("the actuator block needs values (the rig does not hold them)")

    @property
    def groups(self) -> dict[str, CovarianceBlock]:
        """The blocks present, by key."""
        return {k: getattr(self, k) for k in ("lever_arm_m", "boresight_opk_deg", "interior", "actuator")
                if getattr(self, k) is not None}


@dataclass(frozen=True)
class RigCalibration:
    """Calibration data of a rig: per head (by name), the antenna lever arm's block, and the provenance of all."""

    heads: Mapping[str, HeadCalibration] = field(default_factory=dict)
    antenna_lever_arm_m: CovarianceBlock | None = None
    provenance: Provenance | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "heads", dict(self.heads))
        b = self.antenna_lever_arm_m
        if b is not None and b.parameters != LEVER_ARM_PARAMETERS:
            raise SkyrigError(f"antenna_lever_arm_m block must have parameters {list(LEVER_ARM_PARAMETERS)}")
