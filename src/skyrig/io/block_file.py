"""skyrig block files (version 1.1): a JSON manifest plus CSV observation tables.

See ``docs/formats/block.md`` for the full description.  In short, ``block.json``::

    {"format": "skyrig-block", "version": 1.1,             (1 when no 1.1 feature is used)
     "frame": "local 43.64 4.57 1807.36",                   (the block's frame, WorldFrame text form)
     "crs": "EPSG:25832; heights: ellipsoidal",             (optional: the project frame of the results)
     "cameras": [{"name": ..., "width": ..., "height": ..., "focal_px": ..., "pp_col": ..., "pp_row": ...,
                  "distortion": {"model": "brown", "k1": ...}}],
     "heads": ["nadir", ...],                                   (optional)
     "lever_arm_m": [x, y, z],                                  (optional)
     "tables": {"stations": "stations.csv", "images": "images.csv", "points": "points.csv",
                "observations": "observations.csv", "control": "control.csv", "gnss": "gnss.csv",
                "imu": "imu.csv", "distances": "distances.csv"},  (control, gnss, imu, distances optional)
     "adjustment": {"unknowns": {...}, "solver": {...},         (optional: AdjustConfig.to_dict; flat
                    "reliability": {...}, "statistics": {...}}}  keys of earlier releases warn)

Every table is a CSV with a header of fixed column names that carry their units (``_m``, ``_deg``,
``_px``, ``_s``); a column in another unit (``omega_rad``) is an error naming the expected one.  Angles
are omega/phi/kappa in degrees (``Rx(omega) Ry(phi) Rz(kappa)``, ``world_from_station`` and
``station_from_camera``).  Errors name the file, the line and the field.

Version 1.1 adds optional full covariances (``cov_col_col_px2, cov_col_row_px2, cov_row_row_px2`` in
observations; ``cov_XX_m2 ... cov_ZZ_m2`` in control and gnss; ``cov_rx_rx_deg2 ... cov_rz_rz_deg2`` in
imu, the attitude error as a rotation vector about the station axes; each replacing the sigma
columns) and the ``distances`` table (scale bars).  Version 1 files are read unchanged; the writer writes version 1
whenever the block uses no 1.1 feature.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from skyrig.adjust.block import AdjustConfig, Block, BlockError
from skyrig.camera.aspect import camera_from_fx_fy, fx_fy_px
from skyrig.camera.distortion import distortion_from_dict
from skyrig.camera.frame import FrameCamera
from skyrig.errors import CRSError, ConfigError, InputFormatError
from skyrig.geodesy.frame import WorldFrame
from skyrig.geometry.rotations import matrix_from_opk, opk_from_matrix
from skyrig.io._text import atomic_write, float_column, no_cyclic_gc, parse_float, read_text

__all__ = ["read_block", "write_block", "FORMAT", "VERSION", "BlockFile"]

FORMAT = "skyrig-block"
#: the version written when a 1.1 feature is used (covariance columns, distances); 1 otherwise
VERSION = 1.1
#: versions this reader accepts
READ_VERSIONS = (1, 1.1)
PathLike = str | os.PathLike[str]

#: required and optional columns of every table
COLUMNS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "stations": (("name", "X_m", "Y_m", "Z_m", "omega_deg", "phi_deg", "kappa_deg"), ("time_s", "strip")),
    "images": (("name", "station", "camera"),
               ("head", "mount_omega_deg", "mount_phi_deg", "mount_kappa_deg", "offset_x_m", "offset_y_m",
                "offset_z_m", "beta_deg")),
    "points": (("name", "X_m", "Y_m", "Z_m"), ()),
    "observations": (("point", "image", "col_px", "row_px"),
                     ("sigma_col_px", "sigma_row_px", "cov_col_col_px2", "cov_col_row_px2", "cov_row_row_px2")),
    "control": (("point", "X_m", "Y_m", "Z_m", "sigma_X_m", "sigma_Y_m", "sigma_Z_m"),
                ("role", "cov_XX_m2", "cov_XY_m2", "cov_XZ_m2", "cov_YY_m2", "cov_YZ_m2", "cov_ZZ_m2")),
    "gnss": (("station", "X_m", "Y_m", "Z_m", "sigma_X_m", "sigma_Y_m", "sigma_Z_m"),
             ("cov_XX_m2", "cov_XY_m2", "cov_XZ_m2", "cov_YY_m2", "cov_YZ_m2", "cov_ZZ_m2")),
    "imu": (("station", "omega_deg", "phi_deg", "kappa_deg", "sigma_omega_deg", "sigma_phi_deg",
             "sigma_kappa_deg"),
            ("cov_rx_rx_deg2", "cov_rx_ry_deg2", "cov_rx_rz_deg2", "cov_ry_ry_deg2", "cov_ry_rz_deg2",
             "cov_rz_rz_deg2")),
    "distances": (("point_a", "point_b", "distance_m", "sigma_m"), ()),
}
#: covariance columns (upper triangle, row-major) that may replace required sigma columns
_COV2 = ("cov_col_col_px2", "cov_col_row_px2", "cov_row_row_px2")
_COV3 = ("cov_XX_m2", "cov_XY_m2", "cov_XZ_m2", "cov_YY_m2", "cov_YZ_m2", "cov_ZZ_m2")
_SIGMA3 = ("sigma_X_m", "sigma_Y_m", "sigma_Z_m")
#: IMU attitude covariance (deg², rotation vector about the station axes x, y, z), upper triangle
_COVR = ("cov_rx_rx_deg2", "cov_rx_ry_deg2", "cov_rx_rz_deg2", "cov_ry_ry_deg2", "cov_ry_rz_deg2", "cov_rz_rz_deg2")
_SIGMAR = ("sigma_omega_deg", "sigma_phi_deg", "sigma_kappa_deg")
#: plausibility limits on variances by the unit of the covariance columns
_VARIANCE_LIMITS = {"_px2": 1000.0**2, "_m2": 1000.0**2, "_deg2": 90.0**2}
_UNITS = ("_m", "_deg", "_px", "_s", "_rad", "_mm", "_gon", "_cm", "_arcsec", "_mrad", "_urad")
#: plausibility limits on sigmas (a sigma beyond these is almost surely in the wrong unit)
_SIGMA_LIMITS = {"_px": 1000.0, "_m": 1000.0, "_deg": 90.0}


class BlockFile:
    """A block read from disk with its manifest (``block``, ``config``, ``path``).

    ``adjustment_keys`` names the configuration fields (``part.field``) the file's ``adjustment`` section sets explicitly
    (the others are defaults), so that an adjustment preset can merge with them
    (:func:`skyrig.adjust.presets.merge_preset`).

    ``frame`` is the block's own (tangential) frame as data when the manifest's ``frame`` is a frame text
    (:meth:`skyrig.geodesy.WorldFrame.from_text`, also the older ``local ENU at lat ..`` description), else None;
    ``crs`` the project frame (manifest key ``crs``: the frame of the control / GNSS the block was built from, in
    which the adjusted results are written), or None in files without it.
    """

    def __init__(self, block: Block, config: AdjustConfig, path: Path,
                 adjustment_keys: frozenset[str] = frozenset(), frame: WorldFrame | None = None,
                 crs: WorldFrame | None = None) -> None:
        self.block = block
        self.config = config
        self.path = path
        self.adjustment_keys = adjustment_keys
        self.frame = frame
        self.crs = crs


def writing_marker(path: PathLike) -> Path:
    """The marker ``.NAME.writing`` that :func:`write_block` puts next to the manifest ``NAME`` while it writes the
    tables and removes once the manifest is in place: present, a write was interrupted."""
    p = Path(path)
    return p.with_name(f".{p.name}.writing")


def _verify_table(path: Path, kind: str, manifest: Path, want: Any) -> None:
    """Check a table against the size / SHA-256 the manifest's ``checksums`` records for it.

    A mismatch while the manifest's :func:`writing_marker` is there (a ``write_block`` interrupted between the
    tables and the manifest: new tables next to the previous manifest) is an error; without the marker the
    table was edited after the manifest was written, which is allowed, with a warning naming both files.
    """
    if not isinstance(want, dict) or not isinstance(want.get("sha256"), str) or not isinstance(want.get("size"), int):
        raise InputFormatError(f"checksums.{kind} must be {{\"size\": <bytes>, \"sha256\": <hex>}}", manifest, None,
                               f"checksums.{kind}")
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputFormatError(f"{kind} table named by {manifest.name} not found", path) from None
    except OSError as exc:
        raise InputFormatError(f"cannot be read ({exc.strerror or exc})", path) from None
    size, sha = len(data), hashlib.sha256(data).hexdigest()
    if size != want["size"] or sha != want["sha256"]:
        what = (f"{size} bytes, {manifest.name} records {want['size']}" if size != want["size"]
                else f"SHA-256 {sha[:12]}..., {manifest.name} records {want['sha256'][:12]}...")
        if writing_marker(manifest).exists():
            raise InputFormatError(
                f"the {kind} table does not match the checksum in '{manifest}' ({what}) and "
                f"{writing_marker(manifest).name} is there: a write of the block was interrupted between its tables "
                f"and {manifest.name} (written last), so table and manifest come from different runs; write the block "
                f"again", path, None, f"checksums.{kind}")
        warnings.warn(f"{path}: the {kind} table differs from the checksum in '{manifest}' ({what}): edited since "
                      f"{manifest.name} was written; read as it is", stacklevel=3)


class _Table:
    def __init__(self, path: Path, kind: str) -> None:
        with no_cyclic_gc():
            self._read(path, kind)

    def _read(self, path: Path, kind: str) -> None:
        self.path = path
        text = read_text(path)
        spaced = any(ch in text for ch in " \t\r\f\v")  # fields to strip (skyrig's own tables have none)
        rows = list(csv.reader(io.StringIO(text)))
        del text
        lines = [(i + 1, r) for i, r in enumerate(rows) if r and (not spaced or any(c.strip() for c in r))
                 and not r[0].lstrip().startswith("#")]
        if not spaced:  # rows of empty fields only (",,,") are blank lines too
            lines = [(i, r) for i, r in lines if any(r)]
        del rows
        if not lines:
            raise InputFormatError("empty table (no header)", path, 1)
        hl, header = lines[0]
        header = [h.strip() for h in header]
        required, optional = COLUMNS[kind]
        known = set(required) | set(optional)
        for h in header:
            if h not in known:
                stem = next((h[: -len(u)] for u in _UNITS if h.endswith(u)), None)
                expect = [k for k in known if stem is not None and k.startswith(stem + "_")]
                hint = f" (wrong unit? expected {expect[0]!r})" if expect else f"; known columns: {sorted(known)}"
                raise InputFormatError(f"unknown column {h!r}{hint}", path, hl, h)
        cov_cols = (_COV3 if kind in ("control", "gnss") else _COV2 if kind == "observations" else
                    _COVR if kind == "imu" else ())
        have_cov = [c for c in cov_cols if c in header]
        if have_cov and len(have_cov) != len(cov_cols):
            miss = next(c for c in cov_cols if c not in header)
            raise InputFormatError(f"covariance columns come as a set: {have_cov[0]!r} given without {miss!r}",
                                   path, hl, miss)
        for r in required:
            if r not in header and not (have_cov and r in _SIGMA3 + _SIGMAR):
                raise InputFormatError(f"missing required column {r!r}", path, hl, r)
        self.col = {h: k for k, h in enumerate(header)}
        body = lines[1:]
        for ln, r in body:
            if len(r) != len(header):
                raise InputFormatError(f"{len(r)} fields, header has {len(header)}", path, ln)
        self.lines = [ln for ln, _ in body]
        cols = list(zip(*(r for _, r in body))) if body else [() for _ in header]
        self.cols = [[c.strip() for c in col] if spaced else list(col) for col in cols]
        self.n = len(body)

    def __len__(self) -> int:
        return self.n

    def has(self, name: str) -> bool:
        return name in self.col

    def text(self, name: str, default: str = "") -> list[str]:
        if name not in self.col:
            return [default] * self.n
        out = self.cols[self.col[name]]
        if "" in out:
            raise InputFormatError("empty value", self.path, self.lines[out.index("")], name)
        return out

    def num(self, name: str, default: float | None = None, positive: bool = False) -> np.ndarray:
        if name not in self.col:
            return np.full(self.n, np.nan if default is None else default)
        v = float_column(self.cols[self.col[name]], self.path, self.lines, name)
        if positive:
            bad = np.flatnonzero(~(v > 0))
            if bad.size:
                raise InputFormatError(f"a standard deviation must be > 0, got {v[bad[0]]}", self.path,
                                       self.lines[bad[0]], name)
            lim = next((lim for u, lim in _SIGMA_LIMITS.items() if name.endswith(u)), None)
            if lim is not None:
                bad = np.flatnonzero(v > lim)
                if bad.size:
                    raise InputFormatError(f"sigma {v[bad[0]]} is implausibly large for unit "
                                           f"{name[name.rindex('_') + 1:]!r} (wrong units?)", self.path,
                                           self.lines[bad[0]], name)
        return v

    def cov(self) -> np.ndarray | None:
        """``(n, d, d)`` covariances from the ``cov_*`` columns (None when absent); must be positive definite."""
        names = (_COV3 if "cov_XX_m2" in self.col else _COV2 if "cov_col_col_px2" in self.col else
                 _COVR if "cov_rx_rx_deg2" in self.col else None)
        if names is None:
            return None
        d = 2 if names is _COV2 else 3
        iu = np.triu_indices(d)
        out = np.zeros((self.n, d, d))
        for nm, a, b in zip(names, *iu):
            out[:, a, b] = out[:, b, a] = self.num(nm)
        # one batched factorisation; the row loop below only runs to name the first offender
        try:
            ok = len(out) == 0 or bool(np.isfinite(np.linalg.cholesky(out)).all())
        except np.linalg.LinAlgError:
            ok = False
        unit = names[0][names[0].rindex("_"):]
        if ok and (len(out) == 0 or np.diagonal(out, axis1=1, axis2=2).max() <= _VARIANCE_LIMITS[unit]):
            return out
        for j in range(len(out)):
            diag_name = names[0] if not out[j, 0, 0] > 0 else names[-1]
            try:
                np.linalg.cholesky(out[j])
            except np.linalg.LinAlgError:
                raise InputFormatError(f"covariance {out[j].tolist()} is not positive definite", self.path,
                                       self.lines[j], diag_name) from None
            unit = names[0][names[0].rindex("_"):]
            if out[j].diagonal().max() > _VARIANCE_LIMITS[unit]:
                raise InputFormatError(f"variance {out[j].diagonal().max()} is implausibly large (wrong units? "
                                       f"variances are squared: {unit[1:]!r})", self.path, self.lines[j],
                                       names[0])
        return out

    def ref(self, name: str, index: dict[str, int], what: str) -> np.ndarray:
        vals = self.text(name)
        out = np.fromiter((index.get(v, -1) for v in vals), np.int64, self.n)
        if (out < 0).any():
            j = int(np.argmax(out < 0))
            raise InputFormatError(f"unknown {what} {vals[j]!r}", self.path, self.lines[j], name)
        return out

    def unique_names(self, name: str) -> list[str]:
        vals = self.text(name)
        if len(set(vals)) == len(vals):
            return vals
        seen: dict[str, int] = {}
        for ln, v in zip(self.lines, vals):
            if v in seen:
                raise InputFormatError(f"duplicate {name} {v!r} (first on line {seen[v]})", self.path, ln, name)
            seen[v] = ln
        return vals


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v))


def _check_manifest_types(man: dict, p: Path) -> None:
    """Each manifest key's JSON type (a null, a list or a text where a number is meant is a damaged manifest, not
    a default), before any value is used."""
    def need(ok: bool, key: str, what: str) -> None:
        if not ok:
            raise InputFormatError(f"must be {what}, got {json.dumps(man[key])[:60]}", p, None, key)

    if "frame" in man:
        need(isinstance(man["frame"], str), "frame", "a text (the block's frame)")
    if "crs" in man:
        need(man["crs"] is None or isinstance(man["crs"], str), "crs", "a CRS text or null")
    if "rig" in man:
        need(isinstance(man["rig"], str) and bool(man["rig"]), "rig", "the rig file's name")
    if "tables" in man:
        need(isinstance(man["tables"], dict) and all(isinstance(v, str) and v for v in man["tables"].values()),
             "tables", "a mapping {table: file name}")
    if "cameras" in man:
        need(isinstance(man["cameras"], list) and all(isinstance(c, dict) for c in man["cameras"]), "cameras",
             "a list of camera mappings")
    if "heads" in man:
        need(isinstance(man["heads"], list) and all(isinstance(h, str) and h for h in man["heads"]), "heads",
             "a list of head names")
    if "lever_arm_m" in man:
        v = man["lever_arm_m"]
        need(isinstance(v, list) and len(v) == 3 and all(map(_is_number, v)), "lever_arm_m",
             "[x, y, z] in metres (3 finite numbers)")
        from skyrig.io.plausibility import check_lever_arm

        check_lever_arm(v, p, None, "lever_arm_m")
    if "adjustment" in man:
        need(isinstance(man["adjustment"], dict), "adjustment", "a mapping of AdjustConfig parts ({} for the defaults)")
    if "actuator_correction" in man:
        v = man["actuator_correction"]
        need(isinstance(v, dict) and all(isinstance(c, list) and all(map(_is_number, c)) for c in v.values()),
             "actuator_correction", "a mapping {head: [coefficients]}")


def _camera(d: dict, path: Path, k: int) -> FrameCamera:
    field = f"cameras[{k}]"
    need = ("name", "width", "height", "focal_px", "pp_col", "pp_row")
    for key in need:
        if key not in d:
            raise InputFormatError(f"camera entry lacks {key!r}", path, None, f"{field}.{key}")
    extra = set(d) - set(need) - {"distortion", "pixel_size_mm"}
    if extra:
        raise InputFormatError(f"unknown camera key(s) {sorted(extra)}", path, None, field)
    for key in need[1:] + ("pixel_size_mm",):
        v = d.get(key, 0.001)
        if not (_is_number(v) or (key == "focal_px" and isinstance(v, list) and len(v) == 2
                                  and all(map(_is_number, v)))):
            raise InputFormatError(f"must be a finite number{' or [fx, fy]' * (key == 'focal_px')}, got "
                                   f"{json.dumps(v)[:60]}", path, None, f"{field}.{key}")
    if not isinstance(d["name"], str) or not d["name"]:
        raise InputFormatError(f"must be a name, got {json.dumps(d['name'])[:60]}", path, None, f"{field}.name")
    for key in ("width", "height"):
        if d[key] != int(d[key]) or not 0 < d[key] <= 10**6:
            raise InputFormatError(f"must be a whole number of pixels (1 to 1000000), got {d[key]!r}", path, None,
                                   f"{field}.{key}")
    for key, size in (("pp_col", "width"), ("pp_row", "height")):  # a principal point off the image
        if not -0.5 <= d[key] <= d[size] - 0.5:
            raise InputFormatError(f"principal point {d[key]!r} px is outside the image ({size} {d[size]} px)", path,
                                   None, f"{field}.{key}")
    for f in (d["focal_px"] if isinstance(d["focal_px"], list) else [d["focal_px"]]):
        size = max(d["width"], d["height"])  # fields of view over 174 deg or under 0.06 deg: no frame camera
        if not size / 20 <= f <= 1000 * size:
            raise InputFormatError(f"focal length {f!r} px is not plausible for a {d['width']} x {d['height']} px "
                                   "image (1/20 to 1000 x its size)", path, None, f"{field}.focal_px")
    if isinstance(d["focal_px"], list) and not 0.8 <= d["focal_px"][0] / d["focal_px"][1] <= 1.25:
        raise InputFormatError(f"fx / fy = {d['focal_px'][0] / d['focal_px'][1]:.4g} is not plausible (pixels are "
                               "square to within a few per cent)", path, None, f"{field}.focal_px")
    if not 1e-4 <= d.get("pixel_size_mm", 0.001) <= 1.0:
        raise InputFormatError(f"pixel size {d['pixel_size_mm']!r} mm is not plausible (0.1 um to 1 mm; "
                               "micrometres given as millimetres?)", path, None, f"{field}.pixel_size_mm")
    focal = d["focal_px"]
    if isinstance(focal, list):  # [fx, fy]: fx != fy is the Brown affinity b1 (skyrig.camera.aspect)
        if len(focal) != 2:
            raise InputFormatError(f"focal_px must be a number or [fx, fy], got {focal!r}", path, None,
                                   f"{field}.focal_px")
        fxy = focal
    else:
        fxy = [focal, focal]
    try:
        dist = distortion_from_dict(d["distortion"]) if "distortion" in d else None
        vals = [float(d[key]) for key in need[1:] if key != "focal_px"] + [float(d.get("pixel_size_mm", 0.001))]
        fx, fy = (float(v) for v in fxy)
    except (TypeError, ValueError) as e:
        raise InputFormatError(str(e), path, None, field) from None
    if not all(np.isfinite(vals + [fx, fy])):
        raise InputFormatError("non-finite camera value", path, None, field)
    try:
        return camera_from_fx_fy(str(d["name"]), int(vals[0]), int(vals[1]), fx, fy, vals[2], vals[3],
                                 pixel_size_mm=vals[4], distortion=dist)
    except ValueError as e:
        raise InputFormatError(str(e), path, None, f"{field}.focal_px") from None


def read_block(path: PathLike) -> BlockFile:
    """Read a block manifest and its tables.

    Returns
    -------
    BlockFile
        ``.block`` (validated :class:`~skyrig.adjust.block.Block`), ``.config`` (from the manifest's
        ``adjustment`` section, defaults otherwise), ``.path``.

    Raises
    ------
    InputFormatError
        Naming file, line and field: unknown image/station/point, NaN, a point seen once that is not
        control, a column in the wrong unit, an implausible sigma, an unknown manifest key.
    """
    p = Path(path)
    try:
        man = json.loads(read_text(p))
    except json.JSONDecodeError as e:
        raise InputFormatError(f"not valid JSON ({e.msg})", p, e.lineno) from None
    if not isinstance(man, dict) or man.get("format") != FORMAT:
        raise InputFormatError(f"not a {FORMAT} manifest (need \"format\": \"{FORMAT}\")", p, None, "format")
    ver = man.get("version")
    try:
        ok = not isinstance(ver, bool) and float(ver) in READ_VERSIONS  # type: ignore[arg-type]
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise InputFormatError(f"unsupported version {ver!r} (this skyrig reads {', '.join(map(str, READ_VERSIONS))})",
                               p, None, "version")
    known = {"format", "version", "frame", "crs", "cameras", "heads", "lever_arm_m", "tables", "adjustment", "rig",
             "actuator_correction", "checksums"}
    bad = sorted(set(man) - known)
    if bad:
        raise InputFormatError(f"unknown manifest key(s) {bad}", p, None, bad[0])
    _check_manifest_types(man, p)
    tables = man.get("tables") or {}
    bad = sorted(set(tables) - set(COLUMNS))
    if bad:
        raise InputFormatError(f"unknown table(s) {bad}; known: {sorted(COLUMNS)}", p, None, "tables")
    for t in ("stations", "images", "points", "observations"):
        if t not in tables:
            raise InputFormatError(f"manifest names no {t!r} table", p, None, "tables")
    cams = [_camera(d, p, k) for k, d in enumerate(man.get("cameras") or [])]
    if not cams:
        raise InputFormatError("no cameras", p, None, "cameras")
    cam_idx = {c.name: k for k, c in enumerate(cams)}
    if writing_marker(p).exists() and "checksums" not in man:
        raise InputFormatError(f"{writing_marker(p).name} is there: a write of the block was interrupted (its tables "
                               f"may be newer than {p.name}, which has no checksums to check them); write the block "
                               f"again", p)
    sums = man.get("checksums") or {}
    if not isinstance(sums, dict):
        raise InputFormatError("'checksums' must be a mapping {table: {size, sha256}}", p, None, "checksums")
    bad = sorted(set(sums) - set(tables))
    if bad:
        raise InputFormatError(f"checksums of table(s) {bad} that 'tables' does not name", p, None, "checksums")
    for k, v in tables.items():
        if k in sums:
            _verify_table(p.parent / v, k, p, sums[k])
    T = {k: _Table(p.parent / v, k) for k, v in tables.items()}

    st = T["stations"]
    st_names = st.unique_names("name")
    st_idx = {n: k for k, n in enumerate(st_names)}
    R = matrix_from_opk(st.num("omega_deg"), st.num("phi_deg"), st.num("kappa_deg"), unit="deg")
    C = np.column_stack([st.num(c) for c in ("X_m", "Y_m", "Z_m")])
    strip = np.array([int(v) for v in st.text("strip", "-1")]) if st.has("strip") else None
    im = T["images"]
    im_names = im.unique_names("name")
    im_idx = {n: k for k, n in enumerate(im_names)}
    heads = [str(h) for h in (man.get("heads") or [])]
    head_names = im.text("head", heads[0] if heads else "head0")
    if not heads:
        heads = sorted(set(head_names))
    head_idx = {h: k for k, h in enumerate(heads)}
    mount = (matrix_from_opk(im.num("mount_omega_deg", 0.0), im.num("mount_phi_deg", 0.0),
                             im.num("mount_kappa_deg", 0.0), unit="deg"))
    offset = np.column_stack([im.num(c, 0.0) for c in ("offset_x_m", "offset_y_m", "offset_z_m")])
    pt = T["points"]
    pt_names = pt.unique_names("name")
    pt_idx = {n: k for k, n in enumerate(pt_names)}
    ob = T["observations"]
    o_point = ob.ref("point", pt_idx, "point")
    o_image = ob.ref("image", im_idx, "image")
    sig = np.column_stack([ob.num("sigma_col_px", 1.0, True) if ob.has("sigma_col_px") else np.ones(len(ob)),
                           ob.num("sigma_row_px", 1.0, True) if ob.has("sigma_row_px") else np.ones(len(ob))])
    kw: dict[str, Any] = {}
    kw["obs_cov_px2"] = ob.cov()
    if "rig" in man:  # version 1.1: actuated heads from a rig file, beta per image
        from skyrig.io.rig_file import read_rig

        rig = read_rig(p.parent / str(man["rig"]))
        act = {n: h for n, h in rig.heads.items() if h.is_actuated}
        kw["head_actuated"] = [act.get(h) for h in heads]
        beta = np.full(len(im), np.nan)
        if im.has("beta_deg"):  # empty (or nan) for images of fixed heads
            for j, (ln, v) in enumerate(zip(im.lines, im.cols[im.col["beta_deg"]])):
                if v.strip().lower() not in ("", "nan"):
                    beta[j] = np.radians(parse_float(v, im.path, ln, "beta_deg"))
        for j, hn in enumerate(head_names):
            if hn in act and not np.isfinite(beta[j]):
                raise InputFormatError(f"image of the actuated head {hn!r} needs its actuator angle", im.path,
                                       im.lines[j], "beta_deg")
        kw["image_beta_rad"] = beta
        ac = man.get("actuator_correction") or {}
        bad = sorted(set(ac) - set(act))
        if bad:
            raise InputFormatError(f"actuator_correction names heads that are not actuated in the rig: {bad}", p, None,
                                   "actuator_correction")
        if ac:
            width = max(len(v) for v in ac.values())
            corr = np.zeros((len(heads), width))
            for hn, v in ac.items():
                corr[heads.index(hn), : len(v)] = np.asarray(v, float)
            kw["actuator_correction"] = corr
    elif im.has("beta_deg") or "actuator_correction" in man:
        raise InputFormatError("beta_deg / actuator_correction need the manifest key 'rig' (the actuated heads)", p,
                               None, "rig")

    def sig3(t: _Table) -> np.ndarray:
        if t.has("sigma_X_m") or t.cov() is None:
            return np.column_stack([t.num(x, positive=True) for x in _SIGMA3])
        return np.ones((len(t), 3))  # replaced by sqrt(diag(cov))
    ctrl_pts = np.zeros(0, np.int64)
    if "control" in T:
        c = T["control"]
        ctrl_pts = c.ref("point", pt_idx, "point")
        roles = c.text("role", "control")
        for ln, r in zip(c.lines, roles):
            if r not in ("control", "check"):
                raise InputFormatError(f"role must be 'control' or 'check', got {r!r}", c.path, ln, "role")
        kw.update(control_point=ctrl_pts, control_xyz=np.column_stack([c.num(x) for x in ("X_m", "Y_m", "Z_m")]),
                  control_sigma=sig3(c), control_cov_m2=c.cov(), control_check=np.array([r == "check" for r in roles]))
    if "gnss" in T:
        g = T["gnss"]
        kw.update(gnss_station=g.ref("station", st_idx, "station"),
                  gnss_xyz=np.column_stack([g.num(x) for x in ("X_m", "Y_m", "Z_m")]),
                  gnss_sigma=sig3(g), gnss_cov_m2=g.cov())
    if "imu" in T:
        u = T["imu"]
        ucov = u.cov()  # (1.1) deg² about the station axes -> rad²
        usig = (np.ones((len(u), 3)) if ucov is not None and not u.has("sigma_omega_deg")
                else np.radians(np.column_stack([u.num(x, positive=True) for x in _SIGMAR])))
        kw.update(imu_station=u.ref("station", st_idx, "station"),
                  imu_rotation=matrix_from_opk(u.num("omega_deg"), u.num("phi_deg"), u.num("kappa_deg"), unit="deg"),
                  imu_sigma_rad=usig, imu_cov_rad2=None if ucov is None else ucov * np.radians(1.0) ** 2)
    if "distances" in T:
        dt = T["distances"]
        dp = np.column_stack([dt.ref("point_a", pt_idx, "point"), dt.ref("point_b", pt_idx, "point")])
        dm = dt.num("distance_m")
        for j in range(len(dt)):
            if dp[j, 0] == dp[j, 1]:
                raise InputFormatError("a distance joins a point to itself", dt.path, dt.lines[j], "point_b")
            if not dm[j] > 0:
                raise InputFormatError(f"distance must be > 0, got {dm[j]}", dt.path, dt.lines[j], "distance_m")
        kw.update(distance_point=dp, distance_m=dm, distance_sigma_m=dt.num("sigma_m", positive=True))
    # a point seen once that is not control cannot be determined: name it where it is observed
    rays = np.bincount(o_point, minlength=len(pt_names))
    is_ctrl = np.zeros(len(pt_names), bool)
    if "control" in T:
        is_ctrl[ctrl_pts[~kw["control_check"]]] = True
    once = np.flatnonzero((rays < 2) & ~is_ctrl)
    if once.size:
        k = int(once[0])
        if rays[k] == 0:
            ln = pt.lines[k]
            raise InputFormatError(f"point {pt_names[k]!r} has no image observations and is not control "
                                   f"({once.size} such points)", pt.path, ln, "name")
        j = int(np.flatnonzero(o_point == k)[0])
        raise InputFormatError(f"point {pt_names[k]!r} is seen in only one image and is not control: it "
                               f"cannot be determined ({once.size} such points)", ob.path, ob.lines[j], "point")
    pair = o_image * len(pt_names) + o_point
    _, first, cnt = np.unique(pair, return_index=True, return_counts=True)
    if (cnt > 1).any():
        dup = np.flatnonzero(pair == pair[first[np.flatnonzero(cnt > 1)[0]]])
        raise InputFormatError(f"point {ob.text('point')[dup[1]]!r} measured twice in image "
                               f"{ob.text('image')[dup[1]]!r} (first on line {ob.lines[dup[0]]})", ob.path,
                               ob.lines[dup[1]], "point")
    try:
        block = Block(
            cameras=cams, station_name=np.array(st_names), station_rotation=R, station_centre=C,
            station_time=st.num("time_s", 0.0), station_strip=strip, image_name=np.array(im_names),
            image_station=im.ref("station", st_idx, "station"), image_camera=im.ref("camera", cam_idx, "camera"),
            image_head=np.array([head_idx[h] if h in head_idx else -1 for h in head_names]),
            head_name=np.array(heads), image_rotation=mount, image_offset=offset, point_name=np.array(pt_names),
            point_xyz=np.column_stack([pt.num(x) for x in ("X_m", "Y_m", "Z_m")]), obs_image=o_image,
            obs_point=o_point, obs_pixel=np.column_stack([ob.num("col_px"), ob.num("row_px")]), obs_sigma_px=sig,
            lever_arm=np.asarray(man.get("lever_arm_m", [0.0, 0.0, 0.0]), float), frame=str(man.get("frame", "")),
            **kw)
        bad = np.flatnonzero(block.image_head < 0)
        if bad.size:
            raise InputFormatError(f"unknown head {head_names[bad[0]]!r}; manifest heads: {heads}", im.path,
                                   im.lines[bad[0]], "head")
        block.validate()
    except BlockError as e:
        raise InputFormatError(str(e), p) from None
    section = man.get("adjustment") or {}
    if not isinstance(section, dict):
        raise InputFormatError(f"'adjustment' must be a mapping of AdjustConfig parts, not {type(section).__name__}",
                               p, None, "adjustment")
    try:
        cfg = AdjustConfig.from_dict(section, source=str(p))
    except (TypeError, ValueError) as e:
        raise InputFormatError(str(e), p, None, "adjustment") from None
    try:
        frame = WorldFrame.from_text(str(man.get("frame", "")), base=p.parent)
    except (CRSError, ValueError):
        frame = None  # a free-text description (files not written by skyrig): the block is adjusted all the same
    crs = None
    if man.get("crs") is not None:
        try:
            crs = WorldFrame.from_text(str(man["crs"]), base=p.parent)
        except (CRSError, ValueError) as e:
            raise InputFormatError(f"not a frame skyrig knows ({e})", p, None, "crs") from None
    return BlockFile(block, cfg, p, AdjustConfig.file_keys(section), frame, crs)


def _cells(col: Any) -> list[str]:
    """A column's cells as text: strings as they are, floats as ``repr`` (shortest round trip), the rest ``str``."""
    if isinstance(col, np.ndarray) and col.dtype.kind == "f":
        return [repr(x) for x in col.astype(np.float64).tolist()]
    if isinstance(col, np.ndarray) and col.dtype.kind in "iub":
        return [str(x) for x in col.tolist()]
    return [c if isinstance(c, str) else repr(float(c)) if isinstance(c, (float, np.floating)) else str(c) for c in col]


def _write_csv(path: Path, header: list[str], cols: list[Any]) -> dict[str, Any]:
    """Write one table (atomically); returns its ``{"size", "sha256"}`` for the manifest's ``checksums``."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    with no_cyclic_gc():
        w.writerows(zip(*(_cells(c) for c in cols)))
    data = buf.getvalue().encode("utf-8")
    with atomic_write(path, "wb") as fh:
        fh.write(data)
    return {"size": len(data), "sha256": hashlib.sha256(data).hexdigest()}


def write_block(path: PathLike, block: Block, config: AdjustConfig | None = None, rig_file: str | None = None,
                crs: WorldFrame | None = None) -> None:
    """Write ``block`` (frame cameras only) as a manifest ``path`` and CSV tables next to it (atomic per file).

    ``crs``: the project frame (the frame of the control / GNSS data), written as the manifest key ``crs``
    (:meth:`WorldFrame.to_text`): ``skyrig adjust`` writes its results there.  The manifest's ``frame`` is the
    block's frame text when ``block.frame`` is one (or an older description skyrig reads back).

    ``rig_file``: for a block with actuated heads, the rig file (path relative to the manifest) that
    defines them; written as the manifest key ``rig`` with the images' ``beta_deg`` and the adjusted
    ``actuator_correction``.  Required when the block has actuated heads.

    Published as a set: the marker :func:`writing_marker` first, then the tables, then the manifest with each
    table's size and SHA-256 (key ``checksums``), then the marker goes.  A write killed before the manifest
    leaves new tables next to the previous manifest with the marker: :func:`read_block` refuses them.
    """
    p = Path(path)
    stem = p.stem
    for c in block.cameras:
        if not isinstance(c, FrameCamera):
            raise ValueError("write_block supports FrameCamera cameras (use skyrig.io.bal for BAL blocks)")
    tables = {k: f"{stem}_{k}.csv" for k in ("stations", "images", "points", "observations")}
    sums: dict[str, dict[str, Any]] = {}  # size and SHA-256 of each table, in the manifest (written last)
    marker = writing_marker(p)
    with atomic_write(marker) as fh:  # until the manifest is in place: a kill in between is detectable
        fh.write(f"write_block of {p.name} in progress (pid {os.getpid()})\n")
    o, ph, k = opk_from_matrix(block.station_rotation, unit="deg")
    C = block.station_centre
    sums["stations"] = _write_csv(p.parent / tables["stations"], list(COLUMNS["stations"][0]) + ["time_s", "strip"],
               [block.station_name.tolist(), C[:, 0], C[:, 1], C[:, 2], o, ph, k, block.station_time,
                block.station_strip.tolist()])  # type: ignore[union-attr]
    mo, mp, mk = opk_from_matrix(block.image_rotation, unit="deg")
    off = block.image_offset
    actuated = [h is not None for h in block.head_actuated]  # type: ignore[union-attr]
    if any(actuated) and rig_file is None:
        raise ConfigError("write_block: the block has actuated heads; give rig_file (the rig defining them)")
    extra_h, extra_c = ([], []) if not any(actuated) else (
        ["beta_deg"], [["" if not np.isfinite(v) else repr(float(v)) for v in np.degrees(block.image_beta_rad)]])
    sums["images"] = _write_csv(p.parent / tables["images"], ["name", "station", "camera", "head", "mount_omega_deg",
                                             "mount_phi_deg", "mount_kappa_deg", "offset_x_m", "offset_y_m",
                                             "offset_z_m"] + extra_h,
               [block.image_name.tolist(), block.station_name[block.image_station].tolist(),
                [block.cameras[c].name for c in block.image_camera], block.head_name[block.image_head].tolist(),  # type: ignore[index]
                mo, mp, mk, off[:, 0], off[:, 1], off[:, 2]] + extra_c)  # type: ignore[index]
    X = block.point_xyz
    sums["points"] = _write_csv(p.parent / tables["points"], list(COLUMNS["points"][0]),
                                [block.point_name.tolist(), X[:, 0], X[:, 1], X[:, 2]])
    px, sg = block.obs_pixel, block.obs_sigma_px
    version: float = 1

    def cov_cols(cov: np.ndarray | None, names: tuple[str, ...]) -> tuple[list[str], list[Any]]:
        nonlocal version
        if cov is None:
            return [], []
        version = VERSION
        iu = np.triu_indices(cov.shape[1])
        return list(names), [cov[:, a, b] for a, b in zip(*iu)]

    h, c = cov_cols(block.obs_cov_px2, _COV2)
    sums["observations"] = _write_csv(p.parent / tables["observations"],
                                      ["point", "image", "col_px", "row_px", "sigma_col_px", "sigma_row_px"] + h, [block.point_name[block.obs_point].tolist(), block.image_name[block.obs_image].tolist(), px[:, 0],
                     px[:, 1], sg[:, 0], sg[:, 1]] + c)  # type: ignore[index]
    if len(block.control_point):  # type: ignore[arg-type]
        tables["control"] = f"{stem}_control.csv"
        cx, cs = block.control_xyz, block.control_sigma
        h, c = cov_cols(block.control_cov_m2, _COV3)
        sums["control"] = _write_csv(p.parent / tables["control"], list(COLUMNS["control"][0]) + ["role"] + h,
                   [block.point_name[block.control_point].tolist(), cx[:, 0], cx[:, 1], cx[:, 2], cs[:, 0],  # type: ignore[index]
                    cs[:, 1], cs[:, 2], ["check" if k else "control" for k in block.control_check]] + c)  # type: ignore[union-attr, index]
    if len(block.gnss_station):  # type: ignore[arg-type]
        tables["gnss"] = f"{stem}_gnss.csv"
        g, gs = block.gnss_xyz, block.gnss_sigma
        h, c = cov_cols(block.gnss_cov_m2, _COV3)
        sums["gnss"] = _write_csv(p.parent / tables["gnss"], list(COLUMNS["gnss"][0]) + h,
                   [block.station_name[block.gnss_station].tolist(), g[:, 0], g[:, 1], g[:, 2], gs[:, 0], gs[:, 1],  # type: ignore[index]
                    gs[:, 2]] + c)  # type: ignore[index]
    if len(block.imu_station):  # type: ignore[arg-type]
        tables["imu"] = f"{stem}_imu.csv"
        io_, ip, ik = opk_from_matrix(block.imu_rotation, unit="deg")
        s = np.degrees(block.imu_sigma_rad)
        ucov = getattr(block, "imu_cov_rad2", None)
        h, c = cov_cols(None if ucov is None else ucov * np.degrees(1.0) ** 2, _COVR)
        sums["imu"] = _write_csv(p.parent / tables["imu"], list(COLUMNS["imu"][0]) + h,
                   [block.station_name[block.imu_station].tolist(), io_, ip, ik, s[:, 0], s[:, 1], s[:, 2]] + c)  # type: ignore[index]
    if block.n_distances:
        version = VERSION
        tables["distances"] = f"{stem}_distances.csv"
        dp = block.distance_point
        sums["distances"] = _write_csv(p.parent / tables["distances"], list(COLUMNS["distances"][0]),
                   [block.point_name[dp[:, 0]].tolist(), block.point_name[dp[:, 1]].tolist(),  # type: ignore[index]
                    block.distance_m, block.distance_sigma_m])
    cams = []
    for c in block.cameras:
        col, row = c.principal_point_px
        fxy = fx_fy_px(c)  # a camera entered with fx != fy is written the same way
        d: dict[str, Any] = dict(name=c.name, width=c.width, height=c.height,
                                 focal_px=c.focal_px if fxy is None else list(fxy), pp_col=col, pp_row=row,
                                 pixel_size_mm=c.pixel_size_mm)
        if c.distortion.n_params and fxy is None:
            d["distortion"] = c.distortion.to_dict()
        cams.append(d)
    try:
        frame_text = WorldFrame.from_text(block.frame.text).to_text()  # the text's frame, as written before
    except (CRSError, ValueError):
        frame_text = block.frame.text
    man: dict[str, Any] = {"format": FORMAT, "version": version, "frame": frame_text, "cameras": cams,
                           "heads": block.head_name.tolist(), "lever_arm_m": block.lever_arm.tolist(),  # type: ignore[union-attr]
                           "tables": tables, "checksums": sums}
    if any(actuated):
        man["version"] = VERSION
        man["rig"] = str(rig_file)
        man["actuator_correction"] = {str(block.head_name[k]): block.actuator_correction[k].tolist()  # type: ignore[index]
                                      for k, a in enumerate(actuated) if a}
    if crs is not None:
        man["crs"] = crs.to_text()
    if config is not None:
        man["adjustment"] = config.to_dict()
    with atomic_write(p) as fh:
        json.dump(man, fh, indent=1)
        fh.write("\n")
    marker.unlink(missing_ok=True)
