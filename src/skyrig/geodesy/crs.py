"""Coordinate reference systems through pyproj (PROJ): geodetic, ECEF, projected, heights and geoids.

Every CRS or geoid operation in skyrig goes through PROJ; nothing here re-derives a projection.

Heights
-------
``h`` is the ellipsoidal height, ``H`` the orthometric height (altitude) and ``N`` the geoid
undulation with ``h = H + N``.  A geoid grid is used through PROJ's own grid mechanism
(``+proj=vgridshift +grids=...``): pass either an absolute path to a grid file (``.gtx``, ``.tif``)
or the name of a grid installed where PROJ looks for grids (``PROJ_DATA``, the user-writable
directory, see https://proj.org/en/stable/resource_files.html).
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pyproj
from numpy.typing import ArrayLike, NDArray
from pyproj.exceptions import CRSError as _PyprojCRSError, ProjError

from skyrig.errors import CRSError
from skyrig.geodesy.carried import carried_crs_at, is_local_text, parse_local_text

HeightKind = Literal["ellipsoidal", "orthometric"]

#: Geographic 3D WGS84 (lat, lon in degrees, ellipsoidal height in metres).
WGS84_GEOGRAPHIC_3D = "EPSG:4979"
#: WGS84 geocentric (ECEF, metres).
WGS84_ECEF = "EPSG:4978"


def resolve_crs(spec: Any) -> pyproj.CRS:
    """A :class:`pyproj.CRS` from an EPSG code (``2154``, ``"EPSG:2154"``), WKT, PROJ string or CRS; a local ENU
    frame's text ``local <lat> <lon> <h>`` gives the CRS files carry for it (:mod:`skyrig.geodesy.carried`).

    Raises
    ------
    CRSError
        If PROJ does not know the CRS.
    """
    if isinstance(spec, pyproj.CRS):
        return spec
    if is_local_text(spec):
        return carried_crs_at(*parse_local_text(spec))
    try:
        if isinstance(spec, (int, np.integer)):
            return pyproj.CRS.from_epsg(int(spec))
        text = str(spec).strip()
        if text.isdigit():
            return pyproj.CRS.from_epsg(int(text))
        return pyproj.CRS.from_user_input(text)
    except (_PyprojCRSError, ProjError, ValueError, TypeError) as exc:
        raise CRSError(f"unknown coordinate reference system {spec!r}: {exc}") from None


@lru_cache(maxsize=256)
def _transformer(src: str, dst: str) -> pyproj.Transformer:
    return pyproj.Transformer.from_crs(src, dst, always_xy=True)


def transformer(src: Any, dst: Any) -> pyproj.Transformer:
    """Cached ``always_xy`` transformer between two CRS specs (x = easting/longitude first)."""
    return _transformer(resolve_crs(src).to_wkt(), resolve_crs(dst).to_wkt())


def _check_finite(tx: NDArray[np.float64], what: str) -> NDArray[np.float64]:
    if not np.all(np.isfinite(tx)):
        bad = int(np.argmax(~np.isfinite(tx).reshape(tx.shape[0], -1).all(axis=1))) if tx.ndim > 1 else 0
        raise CRSError(f"{what}: PROJ returned non-finite coordinates (first at index {bad}); point outside the CRS area?")
    return tx


def geodetic_to_ecef(lat_deg: ArrayLike, lon_deg: ArrayLike, h: ArrayLike) -> NDArray[np.float64]:
    """WGS84 geodetic (degrees, ellipsoidal metres) to ECEF ``(N, 3)`` metres."""
    t = transformer(WGS84_GEOGRAPHIC_3D, WGS84_ECEF)
    x, y, z = t.transform(np.asarray(lon_deg, float), np.asarray(lat_deg, float), np.asarray(h, float))
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def ecef_to_geodetic(xyz: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """ECEF ``(N, 3)`` to WGS84 ``(lat_deg, lon_deg, h)``."""
    p = np.asarray(xyz, dtype=np.float64)
    t = transformer(WGS84_ECEF, WGS84_GEOGRAPHIC_3D)
    lon, lat, h = t.transform(p[..., 0], p[..., 1], p[..., 2])
    return np.asarray(lat), np.asarray(lon), np.asarray(h)


@dataclass(frozen=True)
class Geoid:
    """A geoid undulation model ``N(lat, lon)`` backed by a PROJ vertical grid.

    Parameters
    ----------
    grid
        Absolute path of a grid file (``egm96_15.gtx``, ``fr_ign_RAF20.tif``...) or the name of a grid
        PROJ can find on its own search path.
    """

    grid: str

    def __post_init__(self) -> None:
        g = str(self.grid)
        if os.path.sep in g or g.startswith("."):
            p = Path(g).expanduser().resolve()
            if not p.is_file():
                raise CRSError(f"geoid grid file {g!r} does not exist")
            g = str(p)
        object.__setattr__(self, "grid", g)
        try:
            self._pipeline(1.0)
        except (ProjError, _PyprojCRSError) as exc:
            raise CRSError(f"PROJ cannot use geoid grid {self.grid!r}: {exc}") from None

    def _pipeline(self, multiplier: float) -> pyproj.Transformer:
        return _vgrid(self.grid, multiplier)

    def undulation(self, lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray[np.float64]:
        """Geoid undulation ``N`` in metres (``h = H + N``) at geographic positions (degrees)."""
        lat = np.asarray(lat_deg, dtype=np.float64)
        lon = np.asarray(lon_deg, dtype=np.float64)
        lat, lon = np.broadcast_arrays(lat, lon)
        t = self._pipeline(1.0)
        _, _, n = t.transform(lon, lat, np.zeros(lat.shape))
        n = np.asarray(n, dtype=np.float64)
        if not np.all(np.isfinite(n)) or np.any(np.abs(n) > 1e4):
            raise CRSError(f"geoid grid {self.grid!r} does not cover every requested position")
        return n

    def to_ellipsoidal(self, lat_deg: ArrayLike, lon_deg: ArrayLike, H: ArrayLike) -> NDArray[np.float64]:
        """``h = H + N``."""
        return np.asarray(H, dtype=np.float64) + self.undulation(lat_deg, lon_deg)

    def to_orthometric(self, lat_deg: ArrayLike, lon_deg: ArrayLike, h: ArrayLike) -> NDArray[np.float64]:
        """``H = h - N``."""
        return np.asarray(h, dtype=np.float64) - self.undulation(lat_deg, lon_deg)


@lru_cache(maxsize=32)
def _vgrid(grid: str, multiplier: float) -> pyproj.Transformer:
    # +proj=vgridshift applies z_out = z_in + multiplier * grid_value in the forward direction.
    # PROJ strings split on whitespace: a path with spaces must be double-quoted.
    value = f'"{grid}"' if any(c.isspace() for c in grid) else grid
    return pyproj.Transformer.from_pipeline(
        f"+proj=pipeline +step +proj=vgridshift +grids={value} +multiplier={multiplier}"
    )


def horizontal_crs(crs: pyproj.CRS) -> pyproj.CRS:
    """The 2D horizontal part of a CRS (a compound's first member, a 3D CRS made 2D)."""
    if crs.is_compound:
        return crs.sub_crs_list[0]
    if len(crs.axis_info) == 3 and not crs.is_geocentric:
        return crs.to_2d()
    return crs


def crs_spec(crs: pyproj.CRS) -> str:
    """``EPSG:n`` when PROJ identifies the CRS with full confidence, its WKT otherwise."""
    code = crs.to_epsg(min_confidence=100)
    return f"EPSG:{code}" if code is not None else crs.to_wkt()


def check_metric_projected(crs: Any, what: str) -> None:
    """Refuse a CRS that is not projected with both horizontal axes in metres, for ``what`` (e.g. ``"an
    orthomosaic"``): a geographic CRS has cells in degrees, a US-feet CRS (EPSG:6503) x/y in feet while skyrig's
    heights, cell sizes and sigmas are metres.

    >>> check_metric_projected("EPSG:25832", "a DSM")
    >>> check_metric_projected("EPSG:4326", "a DSM")
    Traceback (most recent call last):
    ...
    skyrig.errors.CRSError: WGS 84 (EPSG:4326) is a geographic CRS (degrees): a DSM needs a projected CRS in metres (e.g. the UTM zone)
    """
    c = horizontal_crs(resolve_crs(crs))
    code = c.to_epsg()
    name = f"{c.name}" + (f" (EPSG:{code})" if code else "")
    if c.is_geographic:
        raise CRSError(f"{name} is a geographic CRS (degrees): {what} needs a projected CRS in metres "
                       "(e.g. the UTM zone)")
    if not c.is_projected:
        raise CRSError(f"{name} is not a projected CRS: {what} needs a projected CRS in metres")
    units = {(a.unit_name or "").lower() for a in c.axis_info[:2]}
    if units != {"metre"}:
        raise CRSError(f"{name} has its x/y in {', '.join(sorted(units))}: {what} needs a projected CRS in metres "
                       "(skyrig's heights, cell sizes and precisions are metres); use the metric CRS of the same "
                       "datum and zone")


@lru_cache(maxsize=64)
def _compound_geoid(wkt: str) -> str:
    from pyproj.transformer import TransformerGroup

    crs = pyproj.CRS.from_wkt(wkt)
    name = crs.name
    with warnings.catch_warnings():  # "best transformation is not available": said below, in words
        warnings.simplefilter("ignore")
        tg = TransformerGroup(WGS84_GEOGRAPHIC_3D, crs, always_xy=True)
    ops = [(op.name, [g.short_name for g in op.grids], False, None) for op in tg.unavailable_operations]
    for t in tg.transformers:
        grids = [g for o in (t.operations or []) for g in o.grids]
        ops.append((t.description, [g.short_name for g in grids], True, grids))
    ops = [o for o in ops if "ballpark vertical" not in o[0].lower()]
    if not ops:
        raise CRSError(f"{name}: PROJ knows no transformation from ellipsoidal heights to its vertical CRS; "
                       "give the horizontal CRS and the geoid grid (--geoid / geoid:) instead")
    desc, names, available, grids = ops[0]  # PROJ's own preference
    if len(names) != 1:
        single = list(dict.fromkeys(f"{o[1][0]} ({o[0]})" for o in ops if len(o[1]) == 1))
        raise CRSError(f"{name}: PROJ's preferred transformation {desc!r} needs the grids {', '.join(names) or 'none'}; "
                       "skyrig takes a compound CRS whose heights come from one geoid grid: give the horizontal CRS "
                       "and the geoid grid you mean (--geoid / geoid:)"
                       + (f"; geoid grids PROJ knows for it: {'; '.join(single[:6])}" if single else ""))
    if not available:
        raise CRSError(f"{name}: the heights need PROJ's geoid grid {names[0]} ({desc}), which is not installed: put "
                       f"{names[0]} in a PROJ data folder ({pyproj.datadir.get_user_data_dir()} or $PROJ_DATA; it is "
                       f"at https://cdn.proj.org/{names[0]}) or give the horizontal CRS and a geoid grid file")
    g = grids[0]
    full = getattr(g, "full_name", "") or ""
    return names[0] if not full or Path(full).name == names[0] else full


def compound_geoid(crs: Any) -> str:
    """The geoid grid PROJ uses for the heights of a compound CRS (horizontal + vertical), from WGS84 ellipsoidal
    heights: PROJ's preferred transformation, which must be one vertical grid shift whose grid is installed.

    Returns the grid's PROJ name (or the file PROJ found under another name).

    Raises
    ------
    CRSError
        When the grid is not installed (the grid named) or the transformation is not one geoid grid.
    """
    c = resolve_crs(crs)
    if not c.is_compound:
        raise CRSError(f"{c.name} is not a compound CRS")
    return _compound_geoid(c.to_wkt())


@dataclass(frozen=True)
class MapProjection:
    """A mapping CRS (projected, or geographic) with its height reference.

    Parameters
    ----------
    crs
        Anything :func:`resolve_crs` accepts; its horizontal part is used (a compound CRS's vertical
        part is ignored in favour of ``geoid``).
    geoid
        Geoid model when heights in this frame are orthometric; ``None`` means heights are
        ellipsoidal (WGS84/GRS80; the two differ by at most 0.1 mm in height).
    """

    crs: pyproj.CRS
    geoid: Geoid | None = None
    _fwd: pyproj.Transformer = field(init=False, repr=False, compare=False)
    _inv: pyproj.Transformer = field(init=False, repr=False, compare=False)
    _to_base: pyproj.Transformer | None = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        crs = resolve_crs(self.crs)
        if crs.is_compound:
            crs = crs.sub_crs_list[0]
        if crs.is_geocentric:
            raise CRSError("a mapping frame must be projected or geographic, not geocentric")
        object.__setattr__(self, "crs", crs)
        src = pyproj.CRS.from_epsg(4326)
        object.__setattr__(self, "_fwd", pyproj.Transformer.from_crs(src, crs, always_xy=True))
        object.__setattr__(self, "_inv", pyproj.Transformer.from_crs(crs, src, always_xy=True))
        # map -> the CRS's own geographic CRS (no datum shift), which is what proj_factors expects
        base = None if crs.is_geographic else pyproj.Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True)
        object.__setattr__(self, "_to_base", base)

    @property
    def height_kind(self) -> HeightKind:
        return "ellipsoidal" if self.geoid is None else "orthometric"

    def to_geodetic(self, points: ArrayLike) -> NDArray[np.float64]:
        """Map coordinates ``(N, 3)`` (x, y, height in this frame) to ``(N, 3)`` (lat, lon deg, h ellipsoidal)."""
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        lon, lat = self._inv.transform(p[:, 0], p[:, 1])
        lat, lon = np.asarray(lat), np.asarray(lon)
        h = p[:, 2] if self.geoid is None else self.geoid.to_ellipsoidal(lat, lon, p[:, 2])
        return _check_finite(np.stack([lat, lon, h], axis=1), f"{self.crs.name} -> geodetic")

    def from_geodetic(self, llh: ArrayLike) -> NDArray[np.float64]:
        """``(N, 3)`` (lat, lon deg, h ellipsoidal) to map coordinates ``(N, 3)``."""
        g = np.atleast_2d(np.asarray(llh, dtype=np.float64))
        x, y = self._fwd.transform(g[:, 1], g[:, 0])
        z = g[:, 2] if self.geoid is None else self.geoid.to_orthometric(g[:, 0], g[:, 1], g[:, 2])
        return _check_finite(np.stack([np.asarray(x), np.asarray(y), z], axis=1), f"geodetic -> {self.crs.name}")

    def to_ecef(self, points: ArrayLike) -> NDArray[np.float64]:
        """Map coordinates ``(N, 3)`` to ECEF ``(N, 3)``."""
        g = self.to_geodetic(points)
        return geodetic_to_ecef(g[:, 0], g[:, 1], g[:, 2])

    def from_ecef(self, xyz: ArrayLike) -> NDArray[np.float64]:
        """ECEF ``(N, 3)`` to map coordinates ``(N, 3)``."""
        lat, lon, h = ecef_to_geodetic(np.atleast_2d(xyz))
        return self.from_geodetic(np.stack([lat, lon, h], axis=1))

    def factors(self, points: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Meridian convergence (radians) and point scale factor at map positions ``(N, 2+)``.

        The convergence ``gamma`` is the azimuth of grid north measured clockwise from geographic
        north (PROJ's ``meridian_convergence``); so ``grid_azimuth = true_azimuth - gamma`` and
        ``grid_from_enu = rot_z(gamma)``.  The scale factor is PROJ's meridional scale (equal to the
        parallel scale in a conformal projection).  For a geographic CRS both are 0 and 1.
        """
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        if self._to_base is None:
            return np.zeros(len(p)), np.ones(len(p))
        lon, lat = self._to_base.transform(p[:, 0], p[:, 1])
        return geodetic_factors(self.crs, np.asarray(lat), np.asarray(lon))


@lru_cache(maxsize=64)
def _proj(wkt: str) -> pyproj.Proj:
    return pyproj.Proj(pyproj.CRS.from_wkt(wkt))


def geodetic_factors(
    crs: Any, lat_deg: ArrayLike, lon_deg: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Meridian convergence (radians, see :meth:`MapProjection.factors`) and point scale factor of a
    projected CRS at geographic positions (degrees), from PROJ's ``proj_factors``.

    ``lat_deg`` and ``lon_deg`` are in the CRS's own geographic CRS (``crs.geodetic_crs``: RGF93 for
    Lambert-93, OSGB36 for the British National Grid...).  For CRSs on a WGS84 realisation (ETRS89,
    RGF93, GDA2020...) WGS84 positions may be passed; for older datums (OSGB36, ED50...) a ~100 m datum
    shift would change the convergence by a few arc seconds: use :meth:`MapProjection.factors`, which
    takes map coordinates.
    """
    c = resolve_crs(crs)
    f = _proj(c.to_wkt()).get_factors(np.asarray(lon_deg, float), np.asarray(lat_deg, float))
    conv = np.radians(np.asarray(f.meridian_convergence, dtype=np.float64))
    scale = np.asarray(f.meridional_scale, dtype=np.float64)
    return np.atleast_1d(conv), np.atleast_1d(scale)
