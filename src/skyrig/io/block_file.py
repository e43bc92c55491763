"""skyrig block files (version 1): a JSON manifest plus CSV observation tables.

See ``docs/formats/block.md`` for the full description.  In short, ``block.json``::

    {"format": "skyrig-block", "version": 1,
     "frame": "local ENU at lat ... (free text)",
     "cameras": [{"name": ..., "width": ..., "height": ..., "focal_px": ..., "pp_col": ..., "pp_row": ...,
                  "distortion": {"model": "brown", "k1": ...}}],
     "heads": ["nadir", ...],                                   (optional)
     "lever_arm_m": [x, y, z],                                  (optional)
     "tables": {"stations": "stations.csv", "images": "images.csv", "points": "points.csv",
                "observations": "observations.csv", "control": "control.csv", "gnss": "gnss.csv",
                "imu": "imu.csv"},                              (control, gnss, imu optional)
     "adjustment": {<AdjustConfig fields>}}                     (optional)

Every table is a CSV with a header of fixed column names that carry their units (``_m``, ``_deg``,
``_px``, ``_s``); a column in another unit (``omega_rad``) is an error naming the expected one.  Angles
are omega/phi/kappa in degrees (``Rx(omega) Ry(phi) Rz(kappa)``, ``world_from_station`` and
``station_from_camera``).  Errors name the file, the line and the field.
"""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from skyrig.adjust.block import AdjustConfig, Block, BlockError
from skyrig.camera.distortion import distortion_from_dict
from skyrig.camera.frame import FrameCamera
from skyrig.errors import InputFormatError
from skyrig.geometry.rotations import matrix_from_opk, opk_from_matrix
from skyrig.io._text import atomic_write, parse_float, read_text

__all__ = ["read_block", "write_block", "FORMAT", "VERSION", "BlockFile"]

FORMAT = "skyrig-block"
VERSION = 1
PathLike = str | os.PathLike[str]

#: required and optional columns of every table
COLUMNS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "stations": (("name", "X_m", "Y_m", "Z_m", "omega_deg", "phi_deg", "kappa_deg"), ("time_s", "strip")),
    "images": (("name", "station", "camera"),
               ("head", "mount_omega_deg", "mount_phi_deg", "mount_kappa_deg", "offset_x_m", "offset_y_m",
                "offset_z_m")),
    "points": (("name", "X_m", "Y_m", "Z_m"), ()),
    "observations": (("point", "image", "col_px", "row_px"), ("sigma_col_px", "sigma_row_px")),
    "control": (("point", "X_m", "Y_m", "Z_m", "sigma_X_m", "sigma_Y_m", "sigma_Z_m"), ("role",)),
    "gnss": (("station", "X_m", "Y_m", "Z_m", "sigma_X_m", "sigma_Y_m", "sigma_Z_m"), ()),
    "imu": (("station", "omega_deg", "phi_deg", "kappa_deg", "sigma_omega_deg", "sigma_phi_deg",
             "sigma_kappa_deg"), ()),
}
_UNITS = ("_m", "_deg", "_px", "_s", "_rad", "_mm", "_gon", "_cm", "_arcsec", "_mrad", "_urad")
#: plausibility limits on sigmas (a sigma beyond these is almost surely in the wrong unit)
_SIGMA_LIMITS = {"_px": 1000.0, "_m": 1000.0, "_deg": 90.0}


class BlockFile:
    """A block read from disk with its manifest (``block``, ``config``, ``path``)."""

    def __init__(self, block: Block, config: AdjustConfig, path: Path) -> None:
        self.block = block
        self.config = config
        self.path = path


class _Table:
    def __init__(self, path: Path, kind: str) -> None:
        self.path = path
        text = read_text(path)
        rows = list(csv.reader(io.StringIO(text)))
        lines = [(i + 1, r) for i, r in enumerate(rows) if r and any(c.strip() for c in r)
                 and not r[0].lstrip().startswith("#")]
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
        for r in required:
            if r not in header:
                raise InputFormatError(f"missing required column {r!r}", path, hl, r)
        self.col = {h: k for k, h in enumerate(header)}
        self.lines = []
        self.rows = []
        for ln, r in lines[1:]:
            if len(r) != len(header):
                raise InputFormatError(f"{len(r)} fields, header has {len(header)}", path, ln)
            self.lines.append(ln)
            self.rows.append([c.strip() for c in r])

    def __len__(self) -> int:
        return len(self.rows)

    def has(self, name: str) -> bool:
        return name in self.col

    def text(self, name: str, default: str = "") -> list[str]:
        if name not in self.col:
            return [default] * len(self.rows)
        k = self.col[name]
        out = []
        for ln, r in zip(self.lines, self.rows):
            if r[k] == "":
                raise InputFormatError("empty value", self.path, ln, name)
            out.append(r[k])
        return out

    def num(self, name: str, default: float | None = None, positive: bool = False) -> np.ndarray:
        if name not in self.col:
            return np.full(len(self.rows), np.nan if default is None else default)
        k = self.col[name]
        v = np.array([parse_float(r[k], self.path, ln, name) for ln, r in zip(self.lines, self.rows)], float)
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

    def ref(self, name: str, index: dict[str, int], what: str) -> np.ndarray:
        out = np.empty(len(self.rows), np.int64)
        for j, (ln, v) in enumerate(zip(self.lines, self.text(name))):
            if v not in index:
                raise InputFormatError(f"unknown {what} {v!r}", self.path, ln, name)
            out[j] = index[v]
        return out

    def unique_names(self, name: str) -> list[str]:
        vals = self.text(name)
        seen: dict[str, int] = {}
        for ln, v in zip(self.lines, vals):
            if v in seen:
                raise InputFormatError(f"duplicate {name} {v!r} (first on line {seen[v]})", self.path, ln, name)
            seen[v] = ln
        return vals


def _camera(d: dict, path: Path, k: int) -> FrameCamera:
    field = f"cameras[{k}]"
    need = ("name", "width", "height", "focal_px", "pp_col", "pp_row")
    for key in need:
        if key not in d:
            raise InputFormatError(f"camera entry lacks {key!r}", path, None, f"{field}.{key}")
    extra = set(d) - set(need) - {"distortion", "pixel_size_mm"}
    if extra:
        raise InputFormatError(f"unknown camera key(s) {sorted(extra)}", path, None, field)
    try:
        dist = distortion_from_dict(d["distortion"]) if "distortion" in d else None
        vals = [float(d[key]) for key in need[1:]] + [float(d.get("pixel_size_mm", 0.001))]
    except (TypeError, ValueError) as e:
        raise InputFormatError(str(e), path, None, field) from None
    if not all(np.isfinite(vals)):
        raise InputFormatError("non-finite camera value", path, None, field)
    return FrameCamera.from_pixels(str(d["name"]), int(vals[0]), int(vals[1]), vals[2], vals[3], vals[4],
                                   pixel_size_mm=vals[5], distortion=dist)


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
    if man.get("version") != VERSION:
        raise InputFormatError(f"unsupported version {man.get('version')!r} (this skyrig reads {VERSION})", p,
                               None, "version")
    known = {"format", "version", "frame", "cameras", "heads", "lever_arm_m", "tables", "adjustment"}
    bad = sorted(set(man) - known)
    if bad:
        raise InputFormatError(f"unknown manifest key(s) {bad}", p, None, bad[0])
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
    ctrl_pts = np.zeros(0, np.int64)
    if "control" in T:
        c = T["control"]
        ctrl_pts = c.ref("point", pt_idx, "point")
        roles = c.text("role", "control")
        for ln, r in zip(c.lines, roles):
            if r not in ("control", "check"):
                raise InputFormatError(f"role must be 'control' or 'check', got {r!r}", c.path, ln, "role")
        kw.update(control_point=ctrl_pts, control_xyz=np.column_stack([c.num(x) for x in ("X_m", "Y_m", "Z_m")]),
                  control_sigma=np.column_stack([c.num(x, positive=True) for x in ("sigma_X_m", "sigma_Y_m",
                                                                                   "sigma_Z_m")]),
                  control_check=np.array([r == "check" for r in roles]))
    if "gnss" in T:
        g = T["gnss"]
        kw.update(gnss_station=g.ref("station", st_idx, "station"),
                  gnss_xyz=np.column_stack([g.num(x) for x in ("X_m", "Y_m", "Z_m")]),
                  gnss_sigma=np.column_stack([g.num(x, positive=True) for x in ("sigma_X_m", "sigma_Y_m",
                                                                                "sigma_Z_m")]))
    if "imu" in T:
        u = T["imu"]
        kw.update(imu_station=u.ref("station", st_idx, "station"),
                  imu_rotation=matrix_from_opk(u.num("omega_deg"), u.num("phi_deg"), u.num("kappa_deg"), unit="deg"),
                  imu_sigma_rad=np.radians(np.column_stack([u.num(x, positive=True) for x in (
                      "sigma_omega_deg", "sigma_phi_deg", "sigma_kappa_deg")])))
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
    try:
        cfg = AdjustConfig.from_dict(man.get("adjustment") or {}, source=str(p))
    except (TypeError, ValueError) as e:
        raise InputFormatError(str(e), p, None, "adjustment") from None
    return BlockFile(block, cfg, p)


def _write_csv(path: Path, header: list[str], cols: list[Any]) -> None:
    n = len(cols[0]) if cols else 0
    with atomic_write(path, newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header)
        for i in range(n):
            w.writerow([c[i] if isinstance(c[i], str) else repr(float(c[i])) if isinstance(c[i], (float, np.floating))
                        else str(c[i]) for c in cols])


def write_block(path: PathLike, block: Block, config: AdjustConfig | None = None) -> None:
    """Write ``block`` (frame cameras only) as a manifest ``path`` and CSV tables next to it (atomic per file)."""
    p = Path(path)
    stem = p.stem
    for c in block.cameras:
        if not isinstance(c, FrameCamera):
            raise ValueError("write_block supports FrameCamera cameras (use skyrig.io.bal for BAL blocks)")
    tables = {k: f"{stem}_{k}.csv" for k in ("stations", "images", "points", "observations")}
    o, ph, k = opk_from_matrix(block.station_rotation, unit="deg")
    C = block.station_centre
    _write_csv(p.parent / tables["stations"], list(COLUMNS["stations"][0]) + ["time_s", "strip"],
               [block.station_name.tolist(), C[:, 0], C[:, 1], C[:, 2], o, ph, k, block.station_time,
                block.station_strip.tolist()])  # type: ignore[union-attr]
    mo, mp, mk = opk_from_matrix(block.image_rotation, unit="deg")
    off = block.image_offset
    _write_csv(p.parent / tables["images"], ["name", "station", "camera", "head", "mount_omega_deg",
                                             "mount_phi_deg", "mount_kappa_deg", "offset_x_m", "offset_y_m",
                                             "offset_z_m"],
               [block.image_name.tolist(), block.station_name[block.image_station].tolist(),
                [block.cameras[c].name for c in block.image_camera], block.head_name[block.image_head].tolist(),  # type: ignore[index]
                mo, mp, mk, off[:, 0], off[:, 1], off[:, 2]])  # type: ignore[index]
    X = block.point_xyz
    _write_csv(p.parent / tables["points"], list(COLUMNS["points"][0]), [block.point_name.tolist(), X[:, 0], X[:, 1],
                                                                         X[:, 2]])
    px, sg = block.obs_pixel, block.obs_sigma_px
    _write_csv(p.parent / tables["observations"], ["point", "image", "col_px", "row_px", "sigma_col_px", "sigma_row_px"],
               [block.point_name[block.obs_point].tolist(), block.image_name[block.obs_image].tolist(), px[:, 0],
                px[:, 1], sg[:, 0], sg[:, 1]])  # type: ignore[index]
    if len(block.control_point):  # type: ignore[arg-type]
        tables["control"] = f"{stem}_control.csv"
        cx, cs = block.control_xyz, block.control_sigma
        _write_csv(p.parent / tables["control"], list(COLUMNS["control"][0]) + ["role"],
                   [block.point_name[block.control_point].tolist(), cx[:, 0], cx[:, 1], cx[:, 2], cs[:, 0],  # type: ignore[index]
                    cs[:, 1], cs[:, 2], ["check" if c else "control" for c in block.control_check]])  # type: ignore[union-attr, index]
    if len(block.gnss_station):  # type: ignore[arg-type]
        tables["gnss"] = f"{stem}_gnss.csv"
        g, gs = block.gnss_xyz, block.gnss_sigma
        _write_csv(p.parent / tables["gnss"], list(COLUMNS["gnss"][0]),
                   [block.station_name[block.gnss_station].tolist(), g[:, 0], g[:, 1], g[:, 2], gs[:, 0], gs[:, 1],  # type: ignore[index]
                    gs[:, 2]])  # type: ignore[index]
    if len(block.imu_station):  # type: ignore[arg-type]
        tables["imu"] = f"{stem}_imu.csv"
        io_, ip, ik = opk_from_matrix(block.imu_rotation, unit="deg")
        s = np.degrees(block.imu_sigma_rad)
        _write_csv(p.parent / tables["imu"], list(COLUMNS["imu"][0]),
                   [block.station_name[block.imu_station].tolist(), io_, ip, ik, s[:, 0], s[:, 1], s[:, 2]])  # type: ignore[index]
    cams = []
    for c in block.cameras:
        col, row = c.principal_point_px
        d: dict[str, Any] = dict(name=c.name, width=c.width, height=c.height, focal_px=c.focal_px, pp_col=col,
                                 pp_row=row, pixel_size_mm=c.pixel_size_mm)
        if c.distortion.n_params:
            d["distortion"] = c.distortion.to_dict()
        cams.append(d)
    man: dict[str, Any] = {"format": FORMAT, "version": VERSION, "frame": block.frame, "cameras": cams,
                           "heads": block.head_name.tolist(), "lever_arm_m": block.lever_arm.tolist(),  # type: ignore[union-attr]
                           "tables": tables}
    if config is not None:
        man["adjustment"] = {k: (list(map(list, v)) if k == "intrinsic_sigma" else v)
                             for k, v in config.__dict__.items() if v != AdjustConfig.__dataclass_fields__[k].default}
    with atomic_write(p) as fh:
        json.dump(man, fh, indent=1)
        fh.write("\n")
