"""World frames: where coordinates live, as data with one text form.

A :class:`WorldFrame` is one of

* ``WorldFrame.ecef()``: geocentric WGS84 (EPSG:4978);
* ``WorldFrame.map(crs, geoid=None)``: a mapping CRS (projected or geographic) with ellipsoidal heights,
  or orthometric heights through a geoid grid (PROJ ``vgridshift``);
* ``WorldFrame.local(lat, lon, h)``: a local tangent plane ENU frame (the tangential frame of paper 003)
  with its origin at a geodetic position (WGS84, ellipsoidal height).

Text form
---------
Every skyrig format states a frame with :meth:`WorldFrame.to_text` and reads it back with
:meth:`WorldFrame.from_text` (one line, no parsing of descriptions elsewhere)::

    EPSG:4978                                                 ECEF
    local 43.640000000000 4.570000000000 1807.360000          local ENU frame at lat, lon (deg), h (m)
    EPSG:25832; heights: ellipsoidal                          map CRS, ellipsoidal heights
    EPSG:25832; heights: orthometric; geoid: egm96_15.gtx     map CRS, heights above a geoid grid

The CRS part is anything PROJ reads (EPSG code, WKT on one line, PROJ string).  :meth:`from_text` also reads
the older free-text forms skyrig wrote (``local ENU at lat .. lon .. h ..``, ``ECEF WGS84 (EPSG:4978)``,
``<name> [<crs>], ellipsoidal heights``).  Header-style formats (``# crs:``, ``# heights:``, ``# geoid:``)
use :meth:`fields` / :meth:`from_fields`, the same three parts under their keys.

>>> WorldFrame.from_text("EPSG:25832; heights: ellipsoidal") == WorldFrame.map("EPSG:25832")
True
>>> WorldFrame.from_text(WorldFrame.local(43.64, 4.57, 1807.36).to_text()).origin
(43.64, 4.57, 1807.36)
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import CRSError
from skyrig.geodesy.carried import carried_crs_at, is_local_text, parse_local_text
from skyrig.geodesy.crs import (Geoid, MapProjection, compound_geoid, crs_spec, ecef_to_geodetic, horizontal_crs,
                                resolve_crs)
from skyrig.geodesy.local import LocalTangentFrame, ecef_from_enu_rotation, grid_from_enu_rotation

__all__ = ["FrameKind", "WorldFrame", "local_frame_for"]

FrameKind = Literal["ecef", "map", "local"]

_NUM = r"([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)"
_OLD_LOCAL = re.compile(rf"^local ENU at lat {_NUM} lon {_NUM} h {_NUM}$")
_OLD_MAP = re.compile(r"^.*\[(?P<crs>.+)\], (?:ellipsoidal heights|orthometric heights \(geoid (?P<geoid>.+)\))$")


@dataclass(frozen=True)
class WorldFrame:
    """Where exterior orientations and ground points live.

    Attributes
    ----------
    kind
        ``"ecef"``, ``"map"`` or ``"local"``.
    crs
        For ``map``: the CRS as given by the user (EPSG code, WKT...).
    geoid
        For ``map``: geoid grid (path or PROJ name) if heights are orthometric, else None.
    origin
        For ``local``: (lat_deg, lon_deg, h) of the ENU origin.
    """

    kind: FrameKind
    crs: str | None = None
    geoid: str | None = None
    origin: tuple[float, float, float] | None = None

    @classmethod
    def ecef(cls) -> "WorldFrame":
        return cls("ecef")

    @classmethod
    def map(cls, crs: object, geoid: str | None = None) -> "WorldFrame":
        """A map frame; a compound CRS (``EPSG:25832+5773``) means what PROJ means by it: its horizontal CRS with
        heights above the geoid grid PROJ uses for its vertical CRS (refused when that grid is not installed), or above
        ``geoid`` when given (refused when PROJ ties that grid to another vertical CRS).  A local ENU frame's text
        ``local <lat> <lon> <h>`` gives the map frame of the CRS files carry for it
        (:func:`skyrig.geodesy.local_crs.carried_frame`: Local Orthographic at its origin, ellipsoidal heights)."""
        if is_local_text(crs):
            if geoid:
                raise CRSError("a local ENU frame has no geoid: its products carry WGS 84 ellipsoidal heights (give a "
                               "map CRS with the geoid for orthometric heights)")
            crs = crs_spec(carried_crs_at(*parse_local_text(str(crs))))
        c = resolve_crs(crs)  # validate early
        if c.is_compound:
            if geoid is None:
                frame = cls("map", crs=crs_spec(horizontal_crs(c)), geoid=compound_geoid(c))
                _check_against_proj(frame, c)
                return frame
            from skyrig.geodesy.geoid_db import vertical_crs_of_geoid

            given = vertical_crs_of_geoid(str(geoid))
            if given is not None and not given.equals(c.sub_crs_list[1]):
                raise CRSError(f"{c.name} states heights in {c.sub_crs_list[1].name}, but the geoid grid given "
                               f"({Path(str(geoid)).name}) is for {given.name}: give one of them")
            crs = crs_spec(horizontal_crs(c))
        if geoid is not None and (os.path.sep in str(geoid) or str(geoid).startswith(".")):
            geoid = str(Path(geoid).expanduser().resolve())  # a file: make the frame independent of the cwd
        return cls("map", crs=str(crs), geoid=geoid)

    @classmethod
    def local(cls, lat_deg: float, lon_deg: float, h: float) -> "WorldFrame":
        return cls("local", origin=(float(lat_deg), float(lon_deg), float(h)))

    # ----------------------------------------------------------------- text form
    @property
    def heights(self) -> str:
        """``"ellipsoidal"`` or ``"orthometric"`` (local and ECEF frames: ``"ellipsoidal"``; a local frame's z
        is the height above its tangent plane, not a height above the ellipsoid)."""
        return "orthometric" if self.kind == "map" and self.geoid else "ellipsoidal"

    def fields(self) -> dict[str, str]:
        """The frame as ``{"crs": ..., "heights": ..., "geoid": ...}`` (``geoid`` only for orthometric heights)
        for header-style formats; :meth:`from_fields` reads it back."""
        if self.kind == "ecef":
            return {"crs": "EPSG:4978", "heights": "ellipsoidal"}
        if self.kind == "local":
            return {"crs": "local %.12f %.12f %.6f" % self.origin, "heights": "ellipsoidal"}  # type: ignore[str-format]
        out = {"crs": str(self.crs), "heights": self.heights}
        if self.geoid:
            out["geoid"] = str(self.geoid)
        return out

    def to_text(self) -> str:
        """The one-line text form (module docstring) that :meth:`from_text` reads back."""
        f = self.fields()
        if self.kind != "map":
            return f["crs"]
        return "; ".join([f["crs"]] + [f"{k}: {f[k]}" for k in ("heights", "geoid") if k in f])

    @classmethod
    def from_fields(cls, crs: str, heights: str | None = None, geoid: str | None = None,
                    base: str | os.PathLike[str] | None = None) -> "WorldFrame":
        """A frame from its three parts (as in a file header); ``heights`` defaults to ellipsoidal.

        A relative geoid path (one with a folder part) is taken relative to ``base`` (the folder of the file
        that names it).  Raises :class:`CRSError` (also for a malformed local frame or heights word).
        """
        text = str(crs).strip()
        low = text.lower()
        if low.startswith("local"):
            return cls.local(*parse_local_text(text))
        if text.upper() in ("EPSG:4978", "ECEF"):
            return cls.ecef()
        heights = (heights or "ellipsoidal").strip().lower()
        if heights not in ("ellipsoidal", "orthometric"):
            raise CRSError(f"heights must be 'ellipsoidal' or 'orthometric', not {heights!r}")
        if heights == "orthometric" and not geoid:
            raise CRSError("orthometric heights need a geoid (grid file or PROJ grid name)")
        if geoid and base is not None and not Path(geoid).is_absolute() and ("/" in geoid or "\\" in geoid):
            geoid = str((Path(base) / geoid).resolve())
        return cls.map(text, geoid if heights == "orthometric" else None)

    @classmethod
    def from_text(cls, text: str, base: str | os.PathLike[str] | None = None) -> "WorldFrame":
        """Read :meth:`to_text` (and the older descriptions skyrig wrote, module docstring)."""
        s = str(text).strip()
        m = _OLD_LOCAL.match(s)
        if m:
            return cls.local(*(float(g) for g in m.groups()))
        if s.upper() in ("ECEF WGS84 (EPSG:4978)",):
            return cls.ecef()
        parts = [p.strip() for p in s.split(";")]
        keys: dict[str, str] = {}
        crs = parts[0]
        for k, p in enumerate(parts[1:], start=1):
            key, sep, val = p.partition(":")
            key = key.strip().lower()
            if not sep or key not in ("heights", "geoid"):
                raise CRSError(f"unknown part {p!r} in frame {s!r} (expected 'heights: ...', 'geoid: ...')")
            if key == "geoid":  # the geoid is last and may itself contain ';'
                keys["geoid"] = ";".join([val] + parts[k + 1:]).strip()
                break
            keys[key] = val.strip()
        if not keys:
            m = _OLD_MAP.match(s)
            if m:
                g = m.group("geoid")
                return cls.map(m.group("crs"), g)
        return cls.from_fields(crs, keys.get("heights"), keys.get("geoid"), base)

    def describe(self) -> str:
        """One line in words for reports (use :meth:`to_text` in files)."""
        if self.kind == "ecef":
            return "ECEF WGS84 (EPSG:4978)"
        if self.kind == "local":
            return "local ENU at lat %.9f lon %.9f h %.3f" % self.origin  # type: ignore[str-format]
        h = "ellipsoidal heights" if self.geoid is None else f"orthometric heights (geoid {self.geoid})"
        return f"{resolve_crs(self.crs).name} [{self.crs}], {h}"

    # ----------------------------------------------------------------- projections
    @property
    def projection(self) -> MapProjection:
        if self.kind != "map":
            raise CRSError(f"a {self.kind} frame has no map projection")
        return _projection(self.crs, self.geoid)

    @property
    def tangent(self) -> LocalTangentFrame:
        if self.kind != "local" or self.origin is None:
            raise CRSError(f"a {self.kind} frame is not a local tangent frame")
        return LocalTangentFrame(*self.origin, kind="enu")

    # ----------------------------------------------------------------- points
    def to_ecef(self, points: ArrayLike) -> NDArray[np.float64]:
        """Points ``(N, 3)`` of this frame to ECEF."""
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        if self.kind == "ecef":
            return p.copy()
        if self.kind == "local":
            return self.tangent.to_ecef(p)
        return self.projection.to_ecef(p)

    def from_ecef(self, xyz: ArrayLike) -> NDArray[np.float64]:
        """ECEF points ``(N, 3)`` to this frame."""
        p = np.atleast_2d(np.asarray(xyz, dtype=np.float64))
        if self.kind == "ecef":
            return p.copy()
        if self.kind == "local":
            return self.tangent.from_ecef(p)
        return self.projection.from_ecef(p)

    def points_to(self, points: ArrayLike, other: "WorldFrame") -> NDArray[np.float64]:
        """Points ``(N, 3)`` of this frame in ``other`` (through ECEF)."""
        if other == self:
            return np.atleast_2d(np.asarray(points, dtype=np.float64)).copy()
        return other.from_ecef(self.to_ecef(points))

    # ----------------------------------------------------------------- rotations
    def ecef_from_frame_rotation(self, points: ArrayLike) -> NDArray[np.float64]:
        """``ecef_from_<frame axes at each point>`` ``(N, 3, 3)`` for points ``(N, 3)`` of this frame."""
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        n = len(p)
        if self.kind == "ecef":
            return np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        if self.kind == "local":
            return np.broadcast_to(self.tangent.ecef_from_local, (n, 3, 3)).copy()
        proj = self.projection
        g = proj.to_geodetic(p)
        conv, _ = proj.factors(p)
        enu_from_grid = np.swapaxes(grid_from_enu_rotation(conv), -1, -2)
        return ecef_from_enu_rotation(g[:, 0], g[:, 1]) @ enu_from_grid

    def axes_to(self, points: ArrayLike, other: "WorldFrame") -> NDArray[np.float64]:
        """``other_from_this`` axis rotations ``(N, 3, 3)`` at points ``(N, 3)`` of this frame (for vectors and
        covariances: ``v_other = R @ v``, ``C_other = R @ C @ R.T``; map axes: grid east, grid north, up)."""
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        q = self.points_to(p, other)
        return np.swapaxes(other.ecef_from_frame_rotation(q), -1, -2) @ self.ecef_from_frame_rotation(p)


def _projection(crs: str | None, geoid: str | None) -> MapProjection:
    return _projection_cached(crs, geoid)


@lru_cache(maxsize=64)
def _projection_cached(crs: str | None, geoid: str | None) -> MapProjection:
    return MapProjection(resolve_crs(crs), None if geoid is None else Geoid(geoid))


def local_frame_for(points_ecef: ArrayLike) -> WorldFrame:
    """A local ENU frame at the mean of ECEF points projected to the ellipsoid (h = 0)."""
    p = np.atleast_2d(np.asarray(points_ecef, dtype=np.float64))
    lat, lon, _ = ecef_to_geodetic(p.mean(axis=0, keepdims=True))
    return WorldFrame.local(float(lat[0]), float(lon[0]), 0.0)


def _check_against_proj(frame: WorldFrame, crs: object) -> None:
    """A compound CRS's frame against PROJ's own transformation from WGS84 ellipsoidal heights, at the centre of
    the CRS's area of use: refused when they differ by more than 1 mm (a datum shift PROJ applies in height)."""
    import pyproj

    c = resolve_crs(crs)
    a = c.area_of_use
    if a is None:
        return
    lon, lat, h = (a.west + a.east) / 2, (a.south + a.north) / 2, 100.0
    if a.west > a.east:  # across the antimeridian
        lon = ((a.west + a.east + 360) / 2 + 180) % 360 - 180
    t = pyproj.Transformer.from_crs("EPSG:4979", c, always_xy=True)
    ref = np.array(t.transform(lon, lat, h), dtype=np.float64)
    try:
        got = frame.projection.from_geodetic([[lat, lon, h]])[0]
    except CRSError:  # the grid does not reach the centre of the area of use: nothing to compare there
        return
    if np.all(np.isfinite(ref)) and np.abs(got - ref).max() > 1e-3:
        raise CRSError(f"{c.name}: skyrig's heights through geoid {frame.geoid} differ from PROJ's transformation "
                       f"by {np.abs(got - ref).max():.3f} m at lat {lat:.3f} lon {lon:.3f}; give the horizontal CRS "
                       "and the geoid grid instead")
