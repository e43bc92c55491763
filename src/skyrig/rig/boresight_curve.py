"""Actuator-angle-dependent boresight corrections (paper 000, section 3.4 and Fig. 8 / Tab. 2).

The tumbling camera of MACS-TumbleCam is calibrated at discrete actuator positions (72 positions,
5 deg apart, repeated for 5 full circles).  At each position the calibration gives small angular
corrections ``(droll, dpitch, dyaw)`` that are *added* to the nominal tumbling angles.  The
repeated circles are averaged into one mean curve; the standard deviation about that mean curve at
every position is the repeatability (paper 000, Tab. 2, which quotes it as 2 sigma).

:class:`BoresightCurve` holds the mean curve and interpolates it periodically in the actuator
angle beta (period 2 pi), vectorised over any array of beta.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicSpline

from skyrig.errors import SkyrigError

Interpolation = Literal["cubic", "linear"]

#: The three correction axes, in column order.
AXES: tuple[str, str, str] = ("droll", "dpitch", "dyaw")

_TWO_PI = 2.0 * np.pi


def wrap_2pi(beta_rad: ArrayLike) -> NDArray[np.float64]:
    """Wrap angles (radians) into ``[0, 2 pi)``."""
    b = np.asarray(beta_rad, dtype=np.float64) % _TWO_PI
    # values like -1e-17 wrap to 2 pi exactly in floating point; fold them back to 0
    return np.where(b >= _TWO_PI, 0.0, b)


@dataclass(frozen=True)
class Repeatability:
    """Repeatability of a curve averaged from repeated circles, per axis (droll, dpitch, dyaw).

    Attributes
    ----------
    mean_std_rad
        ``(3,)`` mean over positions of the per-position standard deviation (radians, 1 sigma).
    max_std_rad
        ``(3,)`` largest per-position standard deviation (radians, 1 sigma).
    beta_at_max_rad
        ``(3,)`` actuator angle (radians) of the position with the largest standard deviation.
    """

    mean_std_rad: NDArray[np.float64]
    max_std_rad: NDArray[np.float64]
    beta_at_max_rad: NDArray[np.float64]

    def as_table_deg(self, k_sigma: float = 2.0) -> dict[str, tuple[float, float]]:
        """``{axis: (mean, max)}`` in degrees scaled to ``k_sigma`` (paper 000 Tab. 2 uses 2 sigma)."""
        s = k_sigma * 180.0 / np.pi
        return {a: (float(self.mean_std_rad[i] * s), float(self.max_std_rad[i] * s)) for i, a in enumerate(AXES)}


@dataclass(frozen=True, eq=False)
class BoresightCurve:
    """Mean boresight correction curve over the actuator angle, interpolated periodically.

    Attributes
    ----------
    beta_rad
        ``(K,)`` actuator positions in radians, wrapped to ``[0, 2 pi)`` and sorted on construction.
    corrections_rad
        ``(K, 3)`` mean corrections ``(droll, dpitch, dyaw)`` in radians at those positions.
    std_rad
        ``(K, 3)`` 1-sigma repeatability at each position (sample standard deviation about the mean
        curve, ``ddof=1``), or None if the curve was not averaged from repeated circles.  NaN where a
        position was measured only once.
    count
        ``(K,)`` number of repeated measurements averaged at each position, or None.
    interpolation
        ``"cubic"``: periodic cubic spline (``scipy.interpolate.CubicSpline``, ``bc_type="periodic"``);
        ``"linear"``: periodic piecewise-linear.  A cubic curve needs at least 3 positions.
    """

    beta_rad: NDArray[np.float64]
    corrections_rad: NDArray[np.float64]
    std_rad: NDArray[np.float64] | None = None
    count: NDArray[np.int64] | None = None
    interpolation: Interpolation = "cubic"
    _spline: CubicSpline | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        b = np.asarray(self.beta_rad, dtype=np.float64).reshape(-1)
        c = np.asarray(self.corrections_rad, dtype=np.float64)
        if c.shape != (b.size, 3):
            raise SkyrigError(f"boresight curve: corrections must have shape ({b.size}, 3), got {c.shape}")
        if b.size == 0:
            raise SkyrigError("boresight curve: needs at least one actuator position")
        if not (np.all(np.isfinite(b)) and np.all(np.isfinite(c))):
            raise SkyrigError("boresight curve: positions and corrections must be finite numbers")
        if self.interpolation not in ("cubic", "linear"):
            raise SkyrigError(f"boresight curve: unknown interpolation {self.interpolation!r}; use 'cubic' or 'linear'")
        b = wrap_2pi(b)
        order = np.argsort(b, kind="stable")
        b, c = b[order], c[order]
        gaps = np.diff(np.concatenate([b, [b[0] + _TWO_PI]]))
        if b.size > 1 and np.min(gaps) < 1e-9:
            raise SkyrigError("boresight curve: two actuator positions coincide (modulo 2 pi); average them first")
        std = None
        if self.std_rad is not None:
            std = np.asarray(self.std_rad, dtype=np.float64)
            if std.shape != (b.size, 3):
                raise SkyrigError(f"boresight curve: std must have shape ({b.size}, 3), got {std.shape}")
            std = std[order]
        cnt = None
        if self.count is not None:
            cnt = np.asarray(self.count, dtype=np.int64).reshape(-1)
            if cnt.shape != (b.size,):
                raise SkyrigError(f"boresight curve: count must have shape ({b.size},), got {cnt.shape}")
            cnt = cnt[order]
        if self.interpolation == "cubic" and b.size < 3:
            raise SkyrigError("boresight curve: cubic periodic interpolation needs at least 3 positions")
        for name, arr in (("beta_rad", b), ("corrections_rad", c), ("std_rad", std), ("count", cnt)):
            if arr is not None:
                arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if self.interpolation == "cubic":
            x = np.concatenate([b, [b[0] + _TWO_PI]])
            y = np.concatenate([c, c[:1]], axis=0)
            object.__setattr__(self, "_spline", CubicSpline(x, y, axis=0, bc_type="periodic"))

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_samples(
        cls,
        beta_rad: ArrayLike,
        corrections_rad: ArrayLike,
        interpolation: Interpolation = "cubic",
        tolerance_rad: float = 1e-6,
    ) -> "BoresightCurve":
        """Average repeated measurements taken at the same actuator positions into a mean curve.

        Parameters
        ----------
        beta_rad
            ``(N,)`` actuator angle of every measurement, radians (any range; 0 and 2 pi are the
            same position).
        corrections_rad
            ``(N, 3)`` measured corrections ``(droll, dpitch, dyaw)``, radians.
        interpolation
            See the class attributes.
        tolerance_rad
            Measurements whose wrapped angles differ by less than this are the same position.

        Returns
        -------
        BoresightCurve
            With the per-position mean, the sample standard deviation (``ddof=1``; NaN for a
            position measured once) and the count.
        """
        b = wrap_2pi(np.asarray(beta_rad, dtype=np.float64).reshape(-1))
        c = np.asarray(corrections_rad, dtype=np.float64)
        if c.shape != (b.size, 3):
            raise SkyrigError(f"boresight curve: corrections must have shape ({b.size}, 3), got {c.shape}")
        if b.size == 0:
            raise SkyrigError("boresight curve: no samples")
        order = np.argsort(b, kind="stable")
        bs, cs = b[order], c[order]
        new_group = np.concatenate([[True], np.diff(bs) > tolerance_rad])
        gid = np.cumsum(new_group) - 1
        # samples just below 2 pi belong to the group at 0
        if gid[-1] > 0 and (bs[0] + _TWO_PI - bs[-1]) <= tolerance_rad:
            gid[gid == gid[-1]] = 0
        n_groups = int(gid.max()) + 1
        count = np.bincount(gid, minlength=n_groups)
        mean = np.stack([np.bincount(gid, weights=cs[:, k], minlength=n_groups) for k in range(3)], axis=1)
        mean /= count[:, None]
        resid = cs - mean[gid]
        ss = np.stack([np.bincount(gid, weights=resid[:, k] ** 2, minlength=n_groups) for k in range(3)], axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            std = np.where(count[:, None] > 1, np.sqrt(ss / np.maximum(count[:, None] - 1, 1)), np.nan)
        # representative angle per group: the first member (positions agree within tolerance)
        _, first = np.unique(gid, return_index=True)
        return cls(bs[first], mean, std, count, interpolation)

    @classmethod
    def from_circles(
        cls, beta_rad: ArrayLike, corrections_rad: ArrayLike, interpolation: Interpolation = "cubic"
    ) -> "BoresightCurve":
        """Mean curve from ``C`` repeated full circles measured at the same ``K`` positions.

        Parameters
        ----------
        beta_rad
            ``(K,)`` actuator positions, radians (e.g. 72 positions 5 deg apart).
        corrections_rad
            ``(C, K, 3)`` corrections ``(droll, dpitch, dyaw)`` of each circle, radians
            (paper 000: C = 5, K = 72).
        """
        b = np.asarray(beta_rad, dtype=np.float64).reshape(-1)
        c = np.asarray(corrections_rad, dtype=np.float64)
        if c.ndim != 3 or c.shape[1:] != (b.size, 3):
            raise SkyrigError(f"boresight curve: corrections must have shape (C, {b.size}, 3), got {c.shape}")
        return cls.from_samples(np.tile(b, c.shape[0]), c.reshape(-1, 3), interpolation)

    # ------------------------------------------------------------------ evaluation
    def __call__(self, beta_rad: ArrayLike) -> NDArray[np.float64]:
        """Interpolated corrections ``(..., 3)`` (droll, dpitch, dyaw; radians) at actuator angles
        ``beta_rad`` of shape ``(...)`` (radians, any range: wrapped modulo 2 pi)."""
        b = wrap_2pi(beta_rad)
        if self.beta_rad.size == 1:
            return np.broadcast_to(self.corrections_rad[0], b.shape + (3,)).copy()
        if self._spline is not None:
            # the spline is defined on [beta_0, beta_0 + 2 pi]
            x = self.beta_rad[0] + (b - self.beta_rad[0]) % _TWO_PI
            return np.asarray(self._spline(x), dtype=np.float64)
        flat = b.reshape(-1)
        out = np.stack(
            [np.interp(flat, self.beta_rad, self.corrections_rad[:, k], period=_TWO_PI) for k in range(3)], axis=-1
        )
        return out.reshape(b.shape + (3,))

    def repeatability(self) -> Repeatability:
        """Per-axis repeatability (1 sigma): mean and maximum over positions of the per-position std.

        Raises
        ------
        SkyrigError
            If the curve was not averaged from repeated measurements.
        """
        if self.std_rad is None or not np.any(np.isfinite(self.std_rad)):
            raise SkyrigError("boresight curve has no repeatability: it was not averaged from repeated circles")
        s = self.std_rad
        idx = np.nanargmax(s, axis=0)
        return Repeatability(np.nanmean(s, axis=0), np.nanmax(s, axis=0), self.beta_rad[idx])

    def isclose(self, other: "BoresightCurve", atol_rad: float = 1e-12) -> bool:
        """Whether two curves have the same positions, corrections, std, counts and interpolation."""
        if not isinstance(other, BoresightCurve) or self.interpolation != other.interpolation:
            return False
        if self.beta_rad.shape != other.beta_rad.shape:
            return False
        ok = np.allclose(self.beta_rad, other.beta_rad, rtol=0, atol=atol_rad) and np.allclose(
            self.corrections_rad, other.corrections_rad, rtol=0, atol=atol_rad
        )
        if (self.std_rad is None) != (other.std_rad is None) or (self.count is None) != (other.count is None):
            return False
        if self.std_rad is not None and other.std_rad is not None:
            ok = ok and np.allclose(self.std_rad, other.std_rad, rtol=0, atol=atol_rad, equal_nan=True)
        if self.count is not None and other.count is not None:
            ok = ok and np.array_equal(self.count, other.count)
        return bool(ok)
