"""The adjusted tables of a bundle adjustment in the project CRS (``skyrig adjust``, ``skyrig adjust-uav``).

The adjustment runs in the block's tangential (local ENU) frame; what a user gets is in the project frame (a map
CRS with its vertical reference stated): every coordinate is carried rigorously (through ECEF, PROJ), every
sigma and residual vector turned into the project's axes (grid east, grid north, up) at its point.

Files (each CSV plain, with its side-cars ``NAME.csv.json`` / ``NAME.csvt`` / ``NAME.prj``,
:mod:`skyrig.io.table_meta`, so GDAL reads it as 3D points in the project CRS):

``eo.csv``
    adjusted exterior orientations (skyrig EO CSV, omega/phi/kappa in degrees, grid axes).
``points.csv``
    every adjusted point ``name, x, y, z, sx, sy, sz, role`` (role: tie, control, check).
``ground_control.csv``
    control and check points: adjusted ``x, y, z``, ``role``, the given ``given_x/y/z``, ``vx, vy, vz`` =
    adjusted minus given (control: residual; check: true error) and ``sx, sy, sz``.
``adjusted.gpkg``
    GeoPackage layers ``points`` (3D points), ``ground_residuals`` (3D lines from the given to the adjusted
    position of each control / check point), ``projection_centres`` (3D points with omega/phi/kappa), in the
    project CRS (a compound CRS for orthometric heights PROJ identifies).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyrig.geodesy.frame import WorldFrame
from skyrig.io._text import PathLike

__all__ = ["write_adjusted_tables", "sigmas_to"]


def sigmas_to(cov: NDArray[np.float64] | None, xyz: NDArray[np.float64], frame: WorldFrame,
              to: WorldFrame) -> NDArray[np.float64]:
    """``(N, 3)`` standard deviations along ``to``'s axes from ``(N, 3, 3)`` covariances in ``frame`` at ``xyz``
    (NaN rows stay NaN; ``cov`` None gives NaN)."""
    n = len(xyz)
    if cov is None or n == 0:
        return np.full((n, 3), np.nan)
    R = frame.axes_to(xyz, to)
    c = R @ cov @ np.swapaxes(R, -1, -2)
    return np.sqrt(np.clip(np.diagonal(c, axis1=1, axis2=2), 0, None))


def _determined_points(result: Any, role: np.ndarray) -> np.ndarray:
    """Mask of the points the adjustment determined: control / check points, and tie points with at least two image
    observations that data snooping did not reject.  A tie point left with fewer (its rays rejected as blunders)
    keeps stale coordinates the adjustment never checked: it is left out of points.csv and adjusted.gpkg (kept, with
    its observations, in the full solver tables), with a warning naming how many and the first."""
    b = result.block
    n = b.n_points
    active = np.ones(len(b.obs_point), bool)
    rej = [int(r.index) for r in getattr(result, "rejected", []) if r.group == "image"]
    if rej:
        active[np.asarray(rej, dtype=np.int64)] = False
    rays = np.bincount(np.asarray(b.obs_point, dtype=np.int64)[active], minlength=n)[:n]
    keep = (rays >= 2) | (role != "tie")
    if not keep.all():
        import warnings

        from skyrig.errors import PlausibilityWarning

        first = str(b.point_name[np.flatnonzero(~keep)[0]])
        warnings.warn(f"{int((~keep).sum())} tie point(s) kept fewer than two image observations after data "
                      f"snooping (first: {first}); left out of points.csv and adjusted.gpkg", PlausibilityWarning,
                      stacklevel=3)
    return keep


def write_adjusted_tables(outdir: PathLike, result: Any, frame: WorldFrame, project: WorldFrame,
                          eo_local: Any | None = None, gpkg: bool = True) -> dict[str, Path]:
    """Write the tables of the module docstring for an :class:`~skyrig.adjust.AdjustmentResult` whose block is in
    ``frame``, in ``project``; ``eo_local``: the images' adjusted orientations in ``frame`` (default: from the
    block).  Returns ``{"eo", "points", "ground_control", "gpkg"}`` paths (those written)."""
    from skyrig.adjust.frames import eo_from_block
    from skyrig.georef.observations import GroundPoints
    from skyrig.geometry.rotations import opk_from_matrix
    from skyrig.io.eo_csv import write_eo_csv
    from skyrig.io.points_csv import write_points_csv

    d = Path(outdir)
    out: dict[str, Path] = {}
    b, b0 = result.block, result.initial
    eo = (eo_local if eo_local is not None else eo_from_block(b, frame)).to_frame(project)
    write_eo_csv(eo, d / "eo.csv")
    out["eo"] = d / "eo.csv"
    xyz = frame.points_to(b.point_xyz, project) if b.n_points else np.zeros((0, 3))
    sig = sigmas_to(result.point_covariance() if b.n_points else None, b.point_xyz, frame, project)
    role = np.full(b.n_points, "tie", dtype=object)
    cp = np.asarray(b0.control_point, dtype=np.int64)
    chk = np.asarray(b0.control_check, dtype=bool)
    role[cp[~chk]] = "control"
    role[cp[chk]] = "check"
    role = role.astype(str)
    keep = _determined_points(result, role)
    write_points_csv(d / "points.csv", GroundPoints(b.point_name[keep], xyz[keep], project),
                     {"sx": sig[keep, 0], "sy": sig[keep, 1], "sz": sig[keep, 2], "role": role[keep]})
    out["points"] = d / "points.csv"
    given = frame.points_to(b0.control_xyz, project) if len(cp) else np.zeros((0, 3))
    v = xyz[cp] - given
    if len(cp):
        write_points_csv(d / "ground_control.csv", GroundPoints(b.point_name[cp], xyz[cp], project),
                         {"role": role[cp], "given_x": given[:, 0], "given_y": given[:, 1], "given_z": given[:, 2],
                          "vx": v[:, 0], "vy": v[:, 1], "vz": v[:, 2], "sx": sig[cp, 0], "sy": sig[cp, 1],
                          "sz": sig[cp, 2]})
        out["ground_control"] = d / "ground_control.csv"
    if gpkg and project.kind == "map":
        import shapely

        from skyrig.geodesy.statement import file_crs
        from skyrig.io.gpkg import write_gpkg

        o, p, k = opk_from_matrix(eo.rotation, unit="deg")
        layers: dict[str, Any] = {
            "points": (shapely.points(xyz[keep]), {"name": b.point_name[keep].astype(str), "role": role[keep],
                                                   "sx_m": sig[keep, 0], "sy_m": sig[keep, 1], "sz_m": sig[keep, 2]}),
            "projection_centres": (shapely.points(eo.centre), {"image": eo.image, "camera": eo.camera,
                                                               "omega_deg": o, "phi_deg": p, "kappa_deg": k}),
        }
        if len(cp):
            lines = shapely.linestrings(np.stack([given, xyz[cp]], axis=1))
            layers["ground_residuals"] = (lines, {
                "name": b.point_name[cp].astype(str), "role": role[cp], "vx_m": v[:, 0], "vy_m": v[:, 1],
                "vz_m": v[:, 2], "v3d_m": np.linalg.norm(v, axis=1)})
        write_gpkg(d / "adjusted.gpkg", layers, file_crs(project).full.to_wkt())
        out["gpkg"] = d / "adjusted.gpkg"
    return out
