"""The measuring session behind ``skyrig measure``: ground points, where the orientations predict them in the
images, sub-pixel refinement of a click, intersection of the measured rays, residuals, and the measurements file.

Everything the page does is a method of :class:`MeasureSession` returning plain JSON-able data, so that it is
tested without a browser (:mod:`skyrig.web.server` only routes requests to it).

Geometry (in a local ENU frame at the block, :func:`skyrig.geodesy.frame.local_frame_for`):

* **prediction** of a ground point in an image: the camera model (distortion included) through the current
  orientation (DG or adjusted).  Its 2 x 2 covariance propagates the orientation's and the point's standard
  deviations through the analytic Jacobians (:func:`skyrig.camera.jacobians.project_with_jacobians`):
  ``J_pose diag(s_C^2 (3), s_att^2 (3)) J_pose^T + J_X s_X^2 J_X^T`` (:class:`Sigmas`; EO files carry no sigmas,
  so they are stated: defaults for direct georeferencing, smaller values for adjusted orientations);
* **view quality** (the order images are listed in): ``(1 - 0.5 r) cos(i)`` with ``r`` the distance from the
  image centre over the half diagonal and ``i`` the angle of the ray from the vertical;
* **one measurement**: the point of its ray nearest the surveyed point, projected into the other images (the
  measurement fixes the direction, the surveyed point only the depth: the orientation's and the surveyed point's
  errors across the ray drop out), shown with the ground prediction's ellipse;
* **intersection** once a point is measured in two or more images: weighted least squares (each measurement
  weighted by ``(s_px^2 I + J_pose S_pose J_pose^T)^-1``, its own precision plus its orientation's), started
  from :func:`skyrig.georef.ground.forward_intersection`; the other images are predicted again from the
  intersected point with its covariance; each measurement's residual is standardised by its redundancy
  (``Q_vv = Q_ll - A Q_XX A^T``, per axis) and flagged beyond 3 sigma.  A measurement is also compared with
  the prediction from the surveyed coordinates (Mahalanobis distance with the prediction's and the
  measurement's covariance), flagged beyond 3.

The file (``point,image,column,row`` + ``method,refined,sigma_px,operator,time_utc``,
``docs/formats/points_csv.md``) is written whole after every change (temporary file, then renamed) with its
side-car ``NAME.csv.json`` recording the orientation and point files; a lock file ``NAME.csv.lock`` keeps a second
session off the same file.
"""

from __future__ import annotations

import datetime as _dt
import getpass
import json
import math
import os
import socket
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.camera.jacobians import project_with_jacobians
from skyrig.errors import InputFormatError, SessionLockedError
from skyrig.georef.eo import ExteriorOrientations, local_frame_for
from skyrig.georef.observations import GroundPoints, ImageMeasurements
from skyrig.geometry.pose import Pose

__all__ = ["Sigmas", "Record", "PointTarget", "MeasureSession", "METHODS"]

#: How a position was found: a plain click, a disc target's centre, a corner's saddle point, least-squares
#: matching against an image measured before, a target detected automatically, or read from the file.
METHODS = ("click", "target", "corner", "lsm", "detected", "aruco", "coded")
_PROPOSE = ("target", "corner", "aruco", "coded", "lsm", "click")  # refinements the page may ask for (besides "auto")
TARGET_KINDS = ("aruco", "coded", "chequer", "disc")  # automatic target kinds, in the order tried (skyrig.match.targets)
_KIND_METHOD = {"disc": "target", "chequer": "corner", "aruco": "aruco", "coded": "coded"}
_HALF = 24  # refinement window half size, pixels
_TEMPLATE_HALF = 12  # half width of the matching template in the image searched, pixels (a 25 x 25 template)
_ANCHORS = 3  # a proposal by matching looks at the point's measurements in at most this many images (best views)
#: the largest search radius a proposal may be asked for, pixels (a window of 2 x (24 + 200) px around the click)
MAX_SEARCH_PX = 200.0


def search_radius(value: object, name: str = "search_px") -> float:
    """``value`` as a search radius in pixels: a real number (not a boolean, not a string) in
    ``[0, MAX_SEARCH_PX]``; else ValueError naming ``name``, the value and the bounds."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number of pixels in [0, {MAX_SEARCH_PX:g}], not {value!r}")
    v = float(value)
    if not (math.isfinite(v) and 0.0 <= v <= MAX_SEARCH_PX):
        raise ValueError(f"{name} = {value!r} px is outside [0, {MAX_SEARCH_PX:g}] px")
    return v


@dataclass(frozen=True)
class Sigmas:
    """Standard deviations the predictions assume (one value per axis)."""

    position_m: float = 0.10  # projection centre, metres (direct georeferencing: GNSS + lever arm)
    attitude_deg: float = 0.01  # orientation angles, degrees (IMU + boresight)
    point_m: float = 0.02  # surveyed ground point, metres
    pixel: float = 0.5  # a measurement without a refinement's own sigma (a click), pixels


@dataclass(frozen=True)
class PointTarget:
    """What the points file says is painted at a ground point (``docs/formats/points_csv.md``): ``code`` the ring
    code of a circular coded target (any rotation; None: not known to be a coded target), ``radius_m`` the target's
    radius in metres (a coded target's centre dot; NaN: not known)."""

    code: int | None = None
    radius_m: float = float("nan")


@dataclass
class Record:
    """One measurement of a point in an image."""

    point: str
    image: str
    xy: NDArray[np.float64]  # (2,) column, row
    method: str
    refined: bool
    sigma_px: float
    operator: str
    time_utc: str


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def _num(v: float, nd: int = 3) -> float | None:
    """A JSON number (None for NaN / inf)."""
    v = float(v)
    return round(v, nd) if math.isfinite(v) else None


def _ellipse(cov: NDArray) -> dict:
    """1-sigma ellipse of a 2 x 2 covariance: semi-axes (px) and the major axis' angle (deg, from the column
    axis towards the row axis)."""
    if not np.all(np.isfinite(cov)):
        return {"a": None, "b": None, "angle_deg": None}
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    return {"a": _num(math.sqrt(max(w[1], 0.0))), "b": _num(math.sqrt(max(w[0], 0.0))),
            "angle_deg": _num(math.degrees(math.atan2(v[1, 1], v[0, 1])), 2)}


class MeasureSession:
    """A measuring session over one block (module docstring).

    Parameters
    ----------
    eo, cameras
        The current orientations and their cameras.
    points
        Ground points (control and check).
    roles
        ``{name: "control" | "check"}`` (points not named: control).
    image_files
        ``{image name: file}``; an image without a file is listed but cannot be opened.
    output
        The measurements CSV (read first when it exists: the session continues where the last one stopped).
    sigmas
        What the predictions assume (:class:`Sigmas`).
    operator
        Who measures (default: the login name).
    sources
        ``{"eo": ..., "points": [...]}`` file names for the side-car.
    lock
        Take the lock file (a second session on the same file raises :class:`SessionLockedError`).
    target_kinds
        The targets that ``"auto"`` refinement and :meth:`detect` look for, in this order (:data:`TARGET_KINDS`:
        ArUco / AprilTag markers, circular coded targets, 2 x 2 chequer corners, discs); empty: none.
    adjustment
        The control / check residuals of the adjustment whose orientations these are
        (:func:`skyrig.web.inputs.adjustment_residuals`), shown with the points.
    point_targets
        ``{point: PointTarget}``: the coded targets' codes and the targets' sizes (points not named: nothing known).
        A point with a code is a coded target: only a coded target is looked for around it (a disc centroid of a
        coded target is pulled by its ring, a marker "read" in its ring is false), a coded target of another code
        is refused, and so is the target refinement where its dot is predicted smaller than
        :data:`~skyrig.match.targets.CODED_MIN_RADIUS_PX` (its code cannot be read there; needs ``radius_m``).
    """

    def __init__(self, eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], points: GroundPoints,
                 roles: Mapping[str, str], image_files: Mapping[str, str | os.PathLike], output: str | os.PathLike,
                 sigmas: Sigmas = Sigmas(), operator: str | None = None, sources: Mapping | None = None,
                 lock: bool = True, adjustment: Mapping[str, dict] | None = None,
                 target_kinds: tuple[str, ...] = TARGET_KINDS,
                 point_targets: Mapping[str, PointTarget] | None = None) -> None:
        self.frame_local = local_frame_for(eo.frame.to_ecef(eo.centre))
        self.eo = eo
        self.eo_l = eo.to_frame(self.frame_local)
        self.cameras = dict(cameras)
        missing = sorted({str(c) for c in eo.camera} - set(self.cameras))
        if missing:
            raise InputFormatError(f"camera {missing[0]!r} of the orientations is not defined (known: "
                                   f"{', '.join(sorted(self.cameras))})", field="camera")
        self.points = points
        self.xyz_l = self.frame_local.from_ecef(points.frame.to_ecef(points.xyz)) if len(points) else np.zeros((0, 3))
        self.roles = {str(n): str(roles.get(str(n), "control")) for n in points.name}
        self.pidx = points.index()
        self.iidx = eo.index()
        self.files = {str(k): Path(v) for k, v in image_files.items()}
        self.output = Path(output)
        self.sigmas = sigmas
        self.operator = operator or _login()
        bad = sorted(set(target_kinds) - set(TARGET_KINDS))
        if bad:
            raise ValueError(f"unknown target kind {bad[0]!r} ({', '.join(TARGET_KINDS)})")
        self.target_kinds = tuple(target_kinds)
        self.sources = dict(sources or {})
        self.adjustment = {str(k): dict(v) for k, v in (adjustment or {}).items()}
        self.point_targets = {str(k): v for k, v in (point_targets or {}).items()}
        unknown = sorted(set(self.point_targets) - {str(n) for n in points.name})
        if unknown:
            raise ValueError(f"target of {unknown[0]!r}, which is not among the ground points")
        self.records: dict[tuple[str, str], Record] = {}
        self._lock = threading.RLock()
        self._windows: dict[str, object] = {}
        self._pyramids: dict[str, object] = {}
        self._closed = False
        self._cache: Path | None = None  # tiled copies of large JPEG / PNG files (display only), removed on close
        self._groups = [(self.cameras[str(c)], np.flatnonzero(self.eo_l.camera == c)) for c in np.unique(eo.camera)]
        self._size = np.array([[self.cameras[str(c)].width, self.cameras[str(c)].height] for c in self.eo_l.camera],
                              dtype=np.float64).reshape(-1, 2)  # (N, 2) width, height of every image
        s = sigmas
        self._pose_cov = np.diag([s.position_m**2] * 3 + [math.radians(s.attitude_deg) ** 2] * 3)
        self.lockfile = self.output.with_name(self.output.name + ".lock")
        self._locked = False
        if self.output.exists():
            self._load()
        if lock:
            self._take_lock()

    # ------------------------------------------------------------------------------------------- file + lock
    def _load(self) -> None:
        from skyrig.io.points_csv import read_measurements_table

        m, lines, prov = read_measurements_table(self.output)
        for k in range(len(m)):
            p, i = str(m.point[k]), str(m.image[k])
            if p not in self.pidx:
                raise InputFormatError(
                    f"point {p!r} is not among the {len(self.points)} ground points ({self._src('points')}): a "
                    f"measurements file of another project? Nothing was changed; give another --output",
                    self.output, int(lines[k]), "point")
            if i not in self.iidx:
                raise InputFormatError(
                    f"image {i!r} has no orientation in {self._src('eo')}: a measurements file of another project? "
                    f"Nothing was changed; give another --output", self.output, int(lines[k]), "image")
            get = (lambda c, d: prov[c][k] if c in prov and prov[c][k] != "" else d)  # noqa: E731
            try:
                sig = float(get("sigma_px", "nan"))
            except ValueError:
                raise InputFormatError(f"not a number: {prov['sigma_px'][k]!r}", self.output, int(lines[k]),
                                       "sigma_px") from None
            method = get("method", "file")
            self.records[p, i] = Record(p, i, m.pixel[k].copy(), method, get("refined", "no") == "yes", sig,
                                        get("operator", ""), get("time_utc", ""))

    def _src(self, key: str) -> str:
        v = self.sources.get(key)
        return ", ".join(map(str, v)) if isinstance(v, (list, tuple)) else str(v) if v else "the inputs"

    def _take_lock(self) -> None:
        from skyrig.errors import OutputPathError

        info = {"pid": os.getpid(), "host": socket.gethostname(), "operator": self.operator, "started": _now()}
        try:
            self.output.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputPathError(f"cannot create the folder ({exc.strerror or exc})", self.output.parent) from None
        for _ in range(2):
            try:
                fd = os.open(self.lockfile, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                try:
                    held = json.loads(self.lockfile.read_text(encoding="utf-8"))
                except (OSError, ValueError):
                    held = {}
                if held.get("host") == info["host"] and isinstance(held.get("pid"), int) and not _alive(held["pid"]):
                    self.lockfile.unlink(missing_ok=True)  # left by a session that died: take it over
                    continue
                raise SessionLockedError(
                    f"{self.output} is being measured by another session (pid {held.get('pid', '?')} on "
                    f"{held.get('host', '?')}, {held.get('operator', '?')}, since {held.get('started', '?')}; "
                    f"lock file {self.lockfile}): close that one first, or delete the lock file if it is gone") from None
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                json.dump(info, fh)
            self._locked = True
            return

    def close(self) -> None:
        """Give the lock file back and close the image files."""
        with self._lock:
            self._closed = True
            for p in self._pyramids.values():
                p.close()  # type: ignore[attr-defined]
            for w in self._windows.values():
                w.close()  # type: ignore[attr-defined]
            self._windows.clear()
            self._pyramids.clear()
            if self._cache is not None:
                import shutil

                shutil.rmtree(self._cache, ignore_errors=True)
                self._cache = None
            if self._locked:
                self.lockfile.unlink(missing_ok=True)
                self._locked = False

    def save(self) -> None:
        """Write the measurements file and its side-car (atomically, the side-car last)."""
        from skyrig.io.points_csv import MEASUREMENT_PROVENANCE, write_measurements_csv
        from skyrig.io.table_meta import write_table_meta

        with self._lock:
            recs = [self.records[k] for k in sorted(self.records)]
            m = ImageMeasurements(np.array([r.point for r in recs], dtype=str), np.array([r.image for r in recs], dtype=str),
                                  np.array([r.xy for r in recs]).reshape(-1, 2))
            prov = {"method": [r.method for r in recs], "refined": ["yes" if r.refined else "no" for r in recs],
                    "sigma_px": ["" if not math.isfinite(r.sigma_px) else "%.3f" % r.sigma_px for r in recs],
                    "operator": [r.operator for r in recs], "time_utc": [r.time_utc for r in recs]}
            self.output.parent.mkdir(parents=True, exist_ok=True)
            write_measurements_csv(self.output, m, header_lines=(), provenance=prov)
            cols = {"point": {"type": "String"}, "image": {"type": "String"},
                    "column": {"type": "Real", "unit": "pixel", "axis": "right, origin at the centre of the top-left pixel"},
                    "row": {"type": "Real", "unit": "pixel", "axis": "down"}}
            cols.update({c: {"type": "Real", "unit": "pixel"} if c == "sigma_px" else {"type": "String"}
                         for c in MEASUREMENT_PROVENANCE})
            write_table_meta(self.output, None, cols, "skyrig-measurements 1", {
                "written_by": "skyrig measure", "orientations": self._src("eo"), "points": self._src("points"),
                "methods": "click: as clicked; target: disc-target centre; corner: corner saddle point; aruco: "
                           "ArUco / AprilTag marker centre; coded: circular coded target centre; lsm: "
                           "least-squares matching to an image measured before; detected: target found automatically"})

    # ------------------------------------------------------------------------------------------- geometry
    def _project(self, xyz: NDArray, rows: NDArray | None = None) -> tuple[NDArray, NDArray, NDArray]:
        """Pixels ``(N, 2)``, pose Jacobians ``(N, 2, 6)`` and point Jacobians ``(N, 2, 3)`` of one local point in
        the images ``rows`` (default all)."""
        n = len(self.eo_l)
        rows = np.arange(n) if rows is None else np.asarray(rows, dtype=np.int64)
        px = np.full((len(rows), 2), np.nan)
        jp = np.full((len(rows), 2, 6), np.nan)
        jx = np.full((len(rows), 2, 3), np.nan)
        where = np.full(n, -1)
        where[rows] = np.arange(len(rows))
        for cam, sel in self._groups:
            sel = sel[where[sel] >= 0]
            if not len(sel):
                continue
            pose = Pose(self.eo_l.rotation[sel], self.eo_l.centre[sel], "world", "camera")
            with np.errstate(invalid="ignore", divide="ignore"):
                pix, jac = project_with_jacobians(cam, pose, np.repeat(xyz[None], len(sel), 0), want=("point", "pose"))
            px[where[sel]], jp[where[sel]], jx[where[sel]] = pix, jac["pose"], jac["point"]
        return px, jp, jx

    def _pose_part(self, jp: NDArray) -> NDArray:
        return np.einsum("nij,jk,nlk->nil", jp, self._pose_cov, jp)

    def _quality(self, rows: NDArray, px: NDArray, xyz: NDArray) -> NDArray:
        size = self._size[rows]
        half = 0.5 * np.hypot(size[:, 0], size[:, 1])
        rr = np.hypot(px[:, 0] - (size[:, 0] - 1) / 2.0, px[:, 1] - (size[:, 1] - 1) / 2.0) / half
        d = xyz - self.eo_l.centre[rows]
        cos_i = np.maximum(-d[:, 2] / np.maximum(np.linalg.norm(d, axis=1), 1e-9), 0.0)
        with np.errstate(invalid="ignore"):
            return np.nan_to_num((1.0 - 0.5 * np.minimum(rr, 1.0)) * cos_i)

    def _inside(self, rows: NDArray, px: NDArray) -> NDArray[np.bool_]:
        size = self._size[rows]
        with np.errstate(invalid="ignore"):
            return (np.all(np.isfinite(px), axis=1) & (px[:, 0] >= -0.5) & (px[:, 1] >= -0.5)
                    & (px[:, 0] <= size[:, 0] - 0.5) & (px[:, 1] <= size[:, 1] - 0.5))

    def _intersect(self, recs: list[Record]) -> dict | None:
        """Weighted intersection of a point's measurements (module docstring); None with fewer than two."""
        from skyrig.georef.ground import forward_intersection

        if len(recs) < 2:
            return None
        rows = np.array([self.iidx[r.image] for r in recs])
        obs = np.array([r.xy for r in recs])
        sig = np.array([r.sigma_px if math.isfinite(r.sigma_px) and r.sigma_px > 0 else self.sigmas.pixel for r in recs])
        fi = forward_intersection(self.eo_l, self.cameras, [recs[0].point] * len(recs), [r.image for r in recs], obs,
                                  self.frame_local)
        X = fi.xyz[0]
        if not np.all(np.isfinite(X)):
            return None
        for _ in range(5):
            px, jp, jx = self._project(X, rows)
            W = np.linalg.inv(sig[:, None, None] ** 2 * np.eye(2) + self._pose_part(jp))
            N = np.einsum("nki,nkl,nlj->ij", jx, W, jx)
            g = np.einsum("nki,nkl,nl->i", jx, W, obs - px)
            try:
                dX = np.linalg.solve(N, g)
            except np.linalg.LinAlgError:
                return None
            X = X + dX
            if np.max(np.abs(dX)) < 1e-6:
                break
        px, jp, jx = self._project(X, rows)
        Qxx = np.linalg.inv(N)
        Qll = sig[:, None, None] ** 2 * np.eye(2) + self._pose_part(jp)
        Qvv = Qll - np.einsum("nij,jk,nlk->nil", jx, Qxx, jx)
        v = obs - px
        with np.errstate(invalid="ignore", divide="ignore"):
            w = v / np.sqrt(np.clip(np.stack([Qvv[:, 0, 0], Qvv[:, 1, 1]], 1), 1e-12, None))
        red = len(recs) * 2 - 3
        w[:] = w if red > 0 else np.nan
        return {"xyz_local": X, "cov": Qxx, "residual": v, "standardised": w}

    # ------------------------------------------------------------------------------------------- API
    def points_summary(self) -> list[dict]:
        """Every ground point: name, role, coordinates, how many images predict it and how many measure it."""
        out = []
        with self._lock:
            for k, name in enumerate(self.points.name):
                n = str(name)
                px, _, _ = self._project(self.xyz_l[k])
                seen = int(self._inside(np.arange(len(px)), px).sum())
                st = self.point_state(n, with_predictions=False)
                out.append({"name": n, "role": self.roles[n], "x": float(self.points.xyz[k, 0]),
                            "y": float(self.points.xyz[k, 1]), "z": float(self.points.xyz[k, 2]), "predicted_in": seen,
                            "measured_in": len(st["measurements"]), "flagged": st["flagged"],
                            "adjustment": self._adjusted(n), **self._target_words(n)})
        return out

    def _target_words(self, point: str) -> dict:
        t = self.point_targets.get(point, PointTarget())
        return {"code": t.code, "target_radius_m": _num(t.radius_m, 4)}

    def _target_px(self, point: str, jx: NDArray) -> NDArray:
        """The target's radius in pixels (``(N,)``, NaN where its size is not known) in the images whose point
        Jacobians (local ENU) are ``jx`` ``(N, 2, 3)``: the radius of the circle of the same area as the target's
        image, the target lying level (``r sqrt(|det d(col, row) / d(E, N)|)``)."""
        r = self.point_targets.get(point, PointTarget()).radius_m
        with np.errstate(invalid="ignore"):
            return r * np.sqrt(np.abs(np.linalg.det(jx[:, :, :2])))

    def _coded_refusal(self, point: str, image: str) -> str | None:
        """Why the target refinement of a coded ``point`` is refused in ``image`` (its dot predicted too small to
        read), else None."""
        from skyrig.match.targets import CODED_MIN_RADIUS_PX

        t = self.point_targets.get(point)
        if t is None or t.code is None or not math.isfinite(t.radius_m):
            return None
        _, _, jx = self._project(self.xyz_l[self.pidx[point]], np.array([self.iidx[image]]))
        r_px = float(self._target_px(point, jx)[0])
        if not r_px < CODED_MIN_RADIUS_PX:
            return None
        return (f"{point}'s coded target (dot radius {t.radius_m:g} m) is predicted {r_px:.1f} px in {image}, below "
                f"the {CODED_MIN_RADIUS_PX:g} px its code can be read at: no target fit here (a disc fit would centre "
                f"on dot and ring together, about a pixel off); measure it where it is larger")

    def _code_refusal(self, point: str, code: int) -> str | None:
        """Why a coded target read with ``code`` is refused as ``point`` (the point's code differs), else None."""
        from skyrig.match.targets import rotation_code

        t = self.point_targets.get(point)
        if t is None or t.code is None or rotation_code(t.code) == code:
            return None
        return (f"coded target {code} read here, but {point}'s code is {_code_words(t.code)} (points file): another "
                f"target, or a misread")

    def _adjusted(self, point: str) -> dict | None:
        a = self.adjustment.get(point)
        if a is None:
            return None
        return {"role": a.get("role"), "v_m": [_num(v, 4) for v in a["v_m"]], "v3d_m": _num(a["v3d_m"], 4),
                "sigma_m": [_num(v, 4) for v in a.get("sigma_m", [])]}

    def _ray_point(self, rec: Record, X: NDArray) -> NDArray | None:
        """The point of ``rec``'s ray (local frame) nearest the surveyed point ``X``: the measurement fixes the
        direction, the surveyed point only the depth; None where it lies behind the camera."""
        row = self.iidx[rec.image]
        cam = self.cameras[str(self.eo_l.camera[row])]
        with np.errstate(invalid="ignore"):
            d = self.eo_l.rotation[row] @ cam.rays_from_pixels(rec.xy[None])[0]
        C = self.eo_l.centre[row]
        t = float((X - C) @ d) / float(d @ d) if np.all(np.isfinite(d)) else float("nan")
        return C + t * d if math.isfinite(t) and t > 0 else None

    def _recs(self, point: str) -> list[Record]:
        return [r for (p, _), r in sorted(self.records.items()) if p == point]

    def point_state(self, point: str, with_predictions: bool = True) -> dict:
        """A point's predictions (sorted by view quality), measurements with residuals, and intersection.

        Each prediction has ``ground`` (from the surveyed point), ``intersection`` (two or more measurements) or
        ``ray`` (one measurement: the point of its ray nearest the surveyed point, projected; the ground
        prediction's ellipse, a conservative bound)."""
        if point not in self.pidx:
            raise KeyError(f"no ground point {point!r}")
        with self._lock:
            k = self.pidx[point]
            X = self.xyz_l[k]
            recs = self._recs(point)
            inter = self._intersect(recs)
            px_g, jp_g, jx_g = self._project(X)
            cov_g = self._pose_part(jp_g) + self.sigmas.point_m**2 * np.einsum("nij,nkj->nik", jx_g, jx_g)
            meas_rows = {self.iidx[r.image] for r in recs}
            if inter is not None:
                px_i, jp_i, jx_i = self._project(inter["xyz_local"])
                cov_i = self._pose_part(jp_i) + np.einsum("nij,jk,nlk->nil", jx_i, inter["cov"], jx_i)
            ray = self._ray_point(recs[0], X) if len(recs) == 1 else None
            if ray is not None:
                px_r, _, _ = self._project(ray)
            rows = np.arange(len(self.eo_l))
            shown = self._inside(rows, px_g) | np.isin(rows, list(meas_rows))
            if inter is not None:
                shown |= self._inside(rows, px_i)
            rows = rows[shown]
            qual = self._quality(rows, px_g[rows], X)
            order = np.argsort(-qual, kind="stable")
            measurements = []
            flagged = False
            for j, r in enumerate(recs):
                row = self.iidx[r.image]
                sig = r.sigma_px if math.isfinite(r.sigma_px) and r.sigma_px > 0 else self.sigmas.pixel
                d = r.xy - px_g[row]
                C = cov_g[row] + sig**2 * np.eye(2)
                with np.errstate(invalid="ignore"):
                    maha = float(np.sqrt(d @ np.linalg.solve(C, d))) if np.all(np.isfinite(d)) else float("nan")
                e = {"image": r.image, "column": _num(r.xy[0]), "row": _num(r.xy[1]), "method": r.method,
                     "refined": r.refined, "sigma_px": _num(r.sigma_px), "operator": r.operator, "time_utc": r.time_utc,
                     "vs_ground": {"dcolumn": _num(d[0]), "drow": _num(d[1]), "mahalanobis": _num(maha, 2),
                                   "flag": bool(maha > 3.0)}}
                if inter is not None:
                    v, w = inter["residual"][j], inter["standardised"][j]
                    fl = bool(np.nanmax(np.abs(w), initial=0.0) > 3.0) if np.any(np.isfinite(w)) else False
                    e["vs_intersection"] = {"dcolumn": _num(v[0]), "drow": _num(v[1]), "w_column": _num(w[0], 2),
                                            "w_row": _num(w[1], 2), "flag": fl}
                e["flag"] = e["vs_ground"]["flag"] or bool(e.get("vs_intersection", {}).get("flag", False))
                flagged |= e["flag"]
                measurements.append(e)
            state: dict = {"point": point, "role": self.roles[point], "measurements": measurements, "flagged": flagged,
                           "xyz": [float(v) for v in self.points.xyz[k]], "frame": self.points.frame.describe(),
                           "adjustment": self._adjusted(point), **self._target_words(point)}
            if inter is not None:
                xyz = self.points.frame.from_ecef(self.frame_local.to_ecef(inter["xyz_local"][None]))[0]
                dl = inter["xyz_local"] - X
                state["intersection"] = {"xyz": [float(v) for v in xyz], "n_images": len(recs),
                                         "sigma_m": [_num(math.sqrt(max(inter["cov"][i, i], 0.0)), 4) for i in range(3)],
                                         "minus_ground_enu_m": [_num(v, 4) for v in dl]}
            if not with_predictions:
                return state
            preds = []
            r_px = self._target_px(point, jx_g)
            for j in order:
                row = int(rows[j])
                name = str(self.eo_l.image[row])
                cam = self.cameras[str(self.eo_l.camera[row])]
                f = self.files.get(name)
                p = {"image": name, "index": row, "camera": str(self.eo_l.camera[row]), "width": cam.width,
                     "height": cam.height, "quality": _num(qual[j]), "measured": row in meas_rows,
                     "file": bool(f is not None and f.is_file()), "target_px": _num(r_px[row], 2),
                     "ground": {"column": _num(px_g[row, 0]), "row": _num(px_g[row, 1]), **_ellipse(cov_g[row]),
                                "inside": bool(self._inside(np.array([row]), px_g[row:row + 1])[0])}}
                if inter is not None:
                    p["intersection"] = {"column": _num(px_i[row, 0]), "row": _num(px_i[row, 1]), **_ellipse(cov_i[row])}
                if ray is not None:
                    p["ray"] = {"column": _num(px_r[row, 0]), "row": _num(px_r[row, 1]), **_ellipse(cov_g[row])}
                preds.append(p)
            state["predictions"] = preds
            if not preds:
                state["note"] = (f"{point} falls in none of the {len(self.eo_l)} images (as the orientations predict "
                                 f"it)")
            return state

    # ------------------------------------------------------------------------------------------- pixels
    def windows(self, image: str):
        """The :class:`~skyrig.io.image_windows.ImageWindows` of an image (opened once)."""
        from skyrig.io.image_windows import ImageWindows

        if image not in self.iidx:
            raise KeyError(f"no image {image!r} in the orientations")
        with self._lock:
            if self._closed:
                raise InputFormatError("the measuring session is closed")
            w = self._windows.get(image)
            if w is None:
                f = self.files.get(image)
                if f is None:
                    raise InputFormatError(f"image {image!r} is in the orientations but no image folder holds a file "
                                           f"of that name", field="image")
                w = ImageWindows(f)
                cam = self.cameras[str(self.eo_l.camera[self.iidx[image]])]
                if (w.width, w.height) != (cam.width, cam.height):
                    raise InputFormatError(f"image is {w.width} x {w.height} px, its camera "
                                           f"{cam.name!r} {cam.width} x {cam.height} px", f)
                self._windows[image] = w
            return w

    def pyramid(self, image: str):
        """The deep-zoom :class:`~skyrig.web.tiles.TilePyramid` of an image."""
        from skyrig.web.tiles import TilePyramid

        w = self.windows(image)
        with self._lock:
            if self._closed:
                raise InputFormatError("the measuring session is closed")
            p = self._pyramids.get(image)
            if p is None:
                if self._cache is None:
                    import tempfile

                    self._cache = Path(tempfile.mkdtemp(prefix="skyrig-measure-"))
                p = self._pyramids[image] = TilePyramid(w, copy_to=str(self._cache / f"{self.iidx[image]}.tif"))
                p.prepare()
            return p

    def prefetch(self, point: str, n: int = 2) -> None:
        """Open the ``n`` best images of a point's list (their pyramids: a large JPEG / PNG starts its tiled copy
        in the background), so that the first full-resolution tile of an image the user will likely open is quick."""
        try:
            preds = self.point_state(point)["predictions"]
        except KeyError:
            return
        for p in [p for p in preds if p["file"]][:n]:
            try:
                self.pyramid(p["image"])
            except (InputFormatError, OSError):
                pass  # the page reports it when the user opens the image

    def propose(self, point: str, image: str, column: float, row: float, method: str = "auto",
                search_px: float = 0.0) -> dict:
        """Refine a click (column, row) in ``image`` to the exact position of ``point``.

        ``method``: ``"auto"`` (a target of :attr:`target_kinds` near the click, else least-squares matching
        against the best image measured before, else the click), ``"target"`` (disc), ``"corner"`` (the saddle
        point nearest the click), ``"aruco"``, ``"coded"``, ``"lsm"`` or ``"click"`` (no refinement).  Returns the proposed
        ``column``, ``row``, ``method``, ``refined``, ``sigma_px``, a ``note`` on what was tried and ``refused``:
        None, or why the target refinement was refused for this point in this image (a coded point,
        :class:`PointTarget`: its dot predicted too small to read, a coded target of another code read, or a disc /
        corner / marker fit asked for; ``auto`` then still tries the least-squares matching, except after a wrong code,
        the others give the click).
        ``search_px``: how far from the click a target (``auto``, ``target``, ``aruco``: at least 12 px) and the
        least-squares matching (a cross-correlation search first) look; the page sends the 95 % prediction ellipse's
        major semi-axis unless the user sets one; 0: a target within 12 px, LSM from the click.  A number in
        ``[0, MAX_SEARCH_PX]`` (:func:`search_radius`), else ValueError.  The proposal echoes it (``search_px``).
        """
        from skyrig.match.targets import corner_centre, rotation_code

        if point not in self.pidx:
            raise KeyError(f"no ground point {point!r}")
        if method not in ("auto", *_PROPOSE):
            raise ValueError(f"unknown method {method!r} (auto, {', '.join(_PROPOSE)})")
        search = search_radius(search_px)
        click = np.array([float(column), float(row)])
        notes = []
        out = None
        code = self.point_targets.get(point, PointTarget()).code
        refused, wrong_code = None, False
        if code is not None and method in ("target", "corner", "aruco"):
            refused = (f"{point} is coded target {_code_words(code)} (points file): a "
                       f"{ {'target': 'disc', 'corner': 'corner', 'aruco': 'marker'}[method]} fit would not find its "
                       f"centre (refine with auto, coded or lsm)")
        elif method in ("auto", "coded"):
            refused = self._coded_refusal(point, image)
        if method not in ("click", "lsm") and refused is None:
            reach = max(12.0, search)  # a target's search: detect_target's default at least
            if method == "corner":
                win, (c0, r0) = self.windows(image).around(click[0], click[1], _HALF + int(math.ceil(reach - 12.0)))
                f = corner_centre(win, click - [c0, r0])
                if f.ok:
                    out = self._proposal(f.xy + [c0, r0], "corner", True, self.sigmas.pixel / 5.0,
                                         "corner saddle point")
                else:
                    notes.append(f"corner: {f.note}")
            else:
                kinds = self.target_kinds if method == "auto" else ("disc" if method == "target" else method,)
                f, words, kind, refused = self._find_target(point, image, click, reach, kinds)
                wrong_code = refused is not None  # another target under the click: no matching from it either
                if f.ok and refused is None:
                    out = self._proposal(f.xy, _KIND_METHOD[kind] if method == "auto" else method, True,
                                         f.sigma_px, words)
                elif not f.ok:
                    notes.append(f.note)
        if out is None and method in ("auto", "lsm") and not wrong_code:
            got = self._lsm(point, image, click, search)
            if isinstance(got, dict):
                out = got
            else:
                notes.append(f"lsm: {got}")
        if out is None:
            out = self._proposal(click, "click", False, self.sigmas.pixel, "; ".join(notes) or "as clicked")
        out["search_px"] = _num(search, 1)
        out["refused"] = refused
        return out

    def _find_target(self, point: str, image: str, xy: NDArray, reach: float, kinds: tuple[str, ...]) -> tuple:
        """The target of ``kinds`` whose centre lies within ``reach`` of ``xy`` in ``image``
        (:func:`~skyrig.match.targets.detect_target`, in a window of ``reach + 12`` px, at least 24, around ``xy``):
        its fit (image pixels), words, kind and None; for a coded point (:class:`PointTarget`) only a coded target
        (if ``kinds`` has it), and why it is refused when its code is not the point's (else None).

        A coded target's ring and ground reach 4 dot radii: the window is widened to hold them where the dot's
        size is predicted (``radius_m``); where it is not, a disc found (possibly the dot of a coded target whose
        ring the window cut) is looked at again as a coded target in a window wide enough for its radius."""
        from dataclasses import replace

        from skyrig.match.targets import TargetFit, coded_centre, detect_target

        def look(half: float) -> tuple[NDArray, NDArray]:
            win, o = self.windows(image).around(xy[0], xy[1], int(math.ceil(min(half, MAX_SEARCH_PX + _HALF))))
            return win, np.asarray(o, dtype=np.float64)

        def coded_of(half: float) -> tuple:
            win, o = look(half)
            c = coded_centre(win, xy - o, search_px=reach)
            return (None, "") if c is None else (replace(c.fit, xy=c.fit.xy + o), c.words, c.code)

        t = self.point_targets.get(point, PointTarget())
        half = max(reach + 12.0, float(_HALF))
        if "coded" in kinds and math.isfinite(t.radius_m):
            _, _, jx = self._project(self.xyz_l[self.pidx[point]], np.array([self.iidx[image]]))
            r_px = float(self._target_px(point, jx)[0])
            if math.isfinite(r_px):
                half = max(half, reach + 4.5 * r_px + 3.0)
        if t.code is None:
            win, o = look(half)
            f, words, kind = detect_target(win, xy - o, search_px=reach, kinds=kinds)
            wide = reach + 4.5 * f.radius_px + 3.0 if kind == "disc" else 0.0
            if "coded" in kinds and wide > half:  # the dot of a coded target whose ring the window cut?
                got = coded_of(wide)
                if got[0] is not None:
                    return got[0], got[1], "coded", None
            return (replace(f, xy=f.xy + o), words, kind, None)
        got = coded_of(half) if "coded" in kinds else (None, "")
        if got[0] is None:
            return (TargetFit(np.asarray(xy, dtype=np.float64), False, float("nan"), float("nan"), 0.0,
                              "coded: no coded target" if "coded" in kinds else "coded targets not looked for"),
                    "", "", None)
        return got[0], got[1], "coded", self._code_refusal(point, got[2])

    @staticmethod
    def _proposal(xy: NDArray, method: str, refined: bool, sigma: float, note: str) -> dict:
        return {"column": _num(xy[0]), "row": _num(xy[1]), "method": method, "refined": refined,
                "sigma_px": _num(sigma), "note": note}

    def _lsm(self, point: str, image: str, click: NDArray, search_px: float = 0.0) -> dict | str:
        """The point's homologue near the click by its appearance in the images it is measured in (the
        :data:`_ANCHORS` best views): from each, :func:`skyrig.match.propagate.propagate_point` (the template
        around the measurement warped by the local map between the two views that planes through the point induce:
        level ground, the plane facing both cameras, the vertical plane facing them,
        :func:`~skyrig.match.propagate.plane_maps`; or the identity), searched by normalised cross-correlation
        within ``search_px`` of the click, refined by least-squares matching with an affine model, the best
        correlation winning.  A match is refused below a correlation of 0.85 (0.7 without a search: least-squares
        matching from the click) and where the correlation has a second peak within 0.03 of the best (a repeated
        pattern).  The proposal is the mean of the matches found (each measurement's own error enters its match:
        the mean averages them), its sigma the larger of the formal one and the matches' spread over sqrt(n)."""
        from skyrig.match.propagate import plane_maps, propagate_point

        others = [r for r in self._recs(point) if r.image != image and self.files.get(r.image) is not None]
        if not others:
            return "no other image measured yet"
        X = self.xyz_l[self.pidx[point]]
        rows = np.array([self.iidx[r.image] for r in others] + [self.iidx[image]])
        px, _, jx = self._project(X, rows)
        order = np.argsort(-self._quality(rows[:-1], px[:-1], X), kind="stable")[:_ANCHORS]
        h = _TEMPLATE_HALF
        found, refusals = [], []
        for k in order:
            ref = others[int(k)]
            maps = plane_maps(jx[k], jx[-1], X - self.eo_l.centre[rows[k]], X - self.eo_l.centre[rows[-1]])
            # windows wide enough for the template under the largest scale either way
            grow_a = max([np.linalg.norm(np.linalg.inv(M), 2) for M in maps.values()] + [1.0])
            grow_b = max([np.linalg.norm(M, 2) for M in maps.values()] + [1.0])
            half_a = int(min(max(2 * _HALF, math.ceil(h * grow_a) + 4), MAX_SEARCH_PX))
            half_b = int(min(max(_HALF, math.ceil(h * grow_b) + 4), MAX_SEARCH_PX)) + int(math.ceil(search_px))
            w1, (a0, b0) = self.windows(ref.image).around(ref.xy[0], ref.xy[1], half_a)
            w2, (c0, d0) = self.windows(image).around(click[0], click[1], half_b)
            got = propagate_point(w1, ref.xy - [a0, b0], w2, click - [c0, d0], search_px, maps, half_size=h,
                                  min_correlation=0.85 if search_px > 0 else 0.7, ambiguity=0.03,
                                  lsm_shift_px=3.0 if search_px > 0 else 8.0)
            if got.ok:
                found.append((ref.image, got.xy + [c0, d0], got))
            else:
                refusals.append(f"against {ref.image}: {got.note}")
        if not found:
            return "; ".join(refusals)
        xy = np.mean([f[1] for f in found], axis=0)
        sig = math.sqrt(sum(f[2].sigma_px ** 2 for f in found)) / len(found)
        spread = float(np.sqrt(np.mean([np.sum((f[1] - xy) ** 2) for f in found]) / 2.0))
        if len(found) > 1:
            sig = max(sig, spread / math.sqrt(len(found)))
        words = "; ".join(f"to {f[0]}: {f[2].note}" for f in found)
        if len(found) > 1:
            words = f"mean of {len(found)} (spread {spread:.2f} px): {words}"
        return self._proposal(xy, "lsm", True, float(max(sig, 0.02)), f"least-squares matching {words}"
                              + "".join(f"; {r}" for r in refusals))

    # ------------------------------------------------------------------------------------------- changes
    def accept(self, point: str, image: str, column: float, row: float, method: str = "click", refined: bool = False,
               sigma_px: float | None = None) -> dict:
        """Store (or replace) the measurement of ``point`` in ``image``, save the file, and return the point's
        new state (:meth:`point_state`)."""
        if point not in self.pidx:
            raise KeyError(f"no ground point {point!r}")
        if image not in self.iidx:
            raise KeyError(f"no image {image!r} in the orientations")
        if method not in METHODS:
            raise ValueError(f"unknown method {method!r} ({', '.join(METHODS)})")
        xy = np.array([float(column), float(row)])
        cam = self.cameras[str(self.eo_l.camera[self.iidx[image]])]
        if not (np.all(np.isfinite(xy)) and cam.in_image(xy)):
            raise ValueError(f"({column}, {row}) lies outside image {image!r} ({cam.width} x {cam.height} px)")
        sig = float("nan") if sigma_px is None else float(sigma_px)
        with self._lock:
            self.records[point, image] = Record(point, image, xy, method, bool(refined), sig, self.operator, _now())
            self.save()
            return self.point_state(point)

    def delete(self, point: str, image: str) -> dict:
        """Remove the measurement of ``point`` in ``image`` (if any), save, return the point's state."""
        with self._lock:
            if self.records.pop((point, image), None) is not None:
                self.save()
            return self.point_state(point)

    def detect(self, point: str, search_sigma: float = 3.0, accept: bool = False) -> dict:
        """Look for a target (:attr:`target_kinds`; of a coded point, :class:`PointTarget`, only a coded target of
        its code) around the point's prediction (by intersection, else along the one measured ray, else from the
        surveyed point) in every image predicted to see it (within ``search_sigma`` times
        the prediction ellipse's major semi-axis, at least 6 px); the proposals found, stored as ``detected`` when
        ``accept``, and the images passed over with the reason.  Returns ``{"found": [proposal + "image"],
        "skipped": [{"image", "reason"}]}``.

        Passed over (``skipped``): a coded point's image where its dot is predicted too small to read, or where a
        coded target of another code is found.  Passed over silently: a target closer to the frame's edge than
        its surround (2.5 radii of a disc, 4 of a coded target's dot) plus 3 px (its background is cut: measure
        it by hand); so is a chequer corner or marker centre closer than 8 px."""
        st = self.point_state(point)
        found, skipped = [], []
        for p in st["predictions"]:
            if not p["file"] or p["measured"] or not p["ground"]["inside"]:
                continue
            g = p.get("intersection") or p.get("ray") or p["ground"]
            if g["column"] is None:
                continue
            why = self._coded_refusal(point, p["image"])
            if why is not None:
                skipped.append({"image": p["image"], "reason": why})
                continue
            reach = min(max(6.0, search_sigma * (g["a"] or 0.0)), MAX_SEARCH_PX)
            f, words, kind, why = self._find_target(point, p["image"], np.array([g["column"], g["row"]]), reach,
                                                    self.target_kinds)
            if why is not None:
                skipped.append({"image": p["image"], "reason": why})
                continue
            if not f.ok:
                continue
            xy = f.xy
            edge = min(xy[0] + 0.5, xy[1] + 0.5, p["width"] - 0.5 - xy[0], p["height"] - 0.5 - xy[1])
            surround = 4.0 if kind == "coded" else 2.5  # radii: a coded target's black ground, a disc's square
            if edge < (surround * f.radius_px + 3.0 if np.isfinite(f.radius_px) else 8.0):
                continue  # the target's surround is cut by the frame: no proposal
            prop = self._proposal(xy, "detected", True, f.sigma_px, words)
            prop["image"] = p["image"]
            found.append(prop)
            if accept:
                with self._lock:
                    self.records[point, p["image"]] = Record(point, p["image"], xy, "detected", True, f.sigma_px,
                                                             self.operator, _now())
        if accept and found:
            self.save()
        return {"found": found, "skipped": skipped}


def _code_words(code: int) -> str:
    """A ring code as the points file gives it and, when that is not its smallest rotation, the code a reading
    names."""
    from skyrig.match.targets import rotation_code

    rc = rotation_code(code)
    return str(code) if rc == code else f"{code} (read as {rc}, its smallest rotation)"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _login() -> str:
    try:
        return getpass.getuser()
    except (KeyError, OSError):
        return "unknown"
