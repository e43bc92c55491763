"""Agisoft Metashape exchange: camera calibration XML and the cameras/markers XML export, both ways.

Files (``docs/formats/metashape.md``)
-------------------------------------
* **Camera calibration** (Tools > Camera Calibration > Export, "Agisoft Camera Calibration (*.xml)")::

      <calibration><projection>frame</projection><width>W</width><height>H</height><f>..</f><cx>..</cx>
      <cy>..</cy><b1/><b2/><k1/><k2/><k3/><k4/><p1/><p2/>[<p3/><p4/>]<date/></calibration>

* **Cameras** (File > Export > Export Cameras, "Agisoft XML"): ``<document version="1.x"><chunk>`` with
  ``<sensors>`` (``<sensor id label type="frame">`` holding ``<resolution>``, ``<property name="pixel_width">``
  (mm) and ``<calibration class="adjusted|initial">`` as above), ``<components>`` (each a ``<transform>``),
  ``<cameras>`` (``<camera id sensor_id component_id label>`` with a ``<transform>`` of 16 numbers, absent
  for a camera that is not aligned), ``<markers>`` (``<marker id label>`` with ``<reference x y z
  enabled>``), ``<frames><frame><markers><marker marker_id><location camera_id x y pinned>`` (marker
  measurements), ``<reference>`` (the CRS as WKT) and the chunk ``<transform>`` (``<rotation>`` 9,
  ``<translation>`` 3, ``<scale>`` 1).

Conventions
-----------
* **Camera model**: Metashape's frame model, exactly :class:`skyrig.camera.agisoft.AgisoftDistortion`
  (``b1 = B1 / f``, ``b2 = B2 / f``; P1, P2 in Metashape's order, which is OpenCV's p2, p1).  ``f``, ``cx``,
  ``cy``, ``B1``, ``B2`` are pixels; ``cx, cy`` are the principal point's offset from the image centre.
  ``p3``, ``p4`` other than zero, and types other than ``frame`` (fisheye, spherical, cylindrical, RPC) are
  refused.  The writer writes any camera whose model converts exactly (OpenCV, none:
  :func:`skyrig.camera.convert.exact_conversion`), else refuses it, or with ``fit_cameras=True`` fits the
  Agisoft model over the frame (residual reported, bounded by ``fit_tolerance_px``).
* **Pixels**: Metashape's image coordinates start at the top-left *corner* of the image (the centre of the
  first pixel is ``(0.5, 0.5)``): skyrig pixels (origin the centre of the first pixel) are Metashape's minus
  0.5 (marker locations; the principal point ``w/2 + cx`` is skyrig's ``(w-1)/2 + cx``).
* **Camera frame**: x right, y down, z forward (the camera looks along +z); skyrig's is x right, y up, z
  backwards: ``R_skyrig = R_metashape F``, ``F = diag(1, -1, -1)``.
* **Transforms**: a camera's ``<transform>`` is the 4 x 4 matrix (row by row) from camera coordinates to the
  chunk's internal coordinates; a component's and the chunk's ``<transform>`` are similarities
  (``scale * rotation``, ``translation``) from internal to world coordinates, applied in the order camera, then
  component, then chunk.  The world is **geocentric (ECEF, the CRS's datum)** when the chunk is referenced
  in a geographic or projected CRS (``<reference>`` is not a ``LOCAL_CS``): poses are then given in
  ``WorldFrame.ecef()`` and :meth:`MetashapeChunk.orientations` converts them to any frame.  With a local
  CRS, or no chunk transform, the world is the chunk's own frame (``frame`` None).  Units: metres.
* **Markers**: the reference coordinates are kept as written (in the chunk CRS: longitude, latitude,
  height for a geographic one); measurements become skyrig pixels.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from datetime import datetime, timezone
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.block import Block
from skyrig.camera.agisoft import AgisoftDistortion
from skyrig.camera.convert import exact_conversion
from skyrig.camera.frame import FrameCamera
from skyrig.errors import InputFormatError, OptionError
from skyrig.geodesy.frame import WorldFrame
from skyrig.georef.eo import ExteriorOrientations
from skyrig.geometry.pose import Pose
from skyrig.io._camera_fit import FIT_TOLERANCE_PX, fit_or_refuse
from skyrig.io._xml import XmlElement, finite_float as _float, floats_of as _floats, read_xml, write_xml as _write_tree

__all__ = ["MetashapeChunk", "read_metashape_calibration", "write_metashape_calibration", "read_metashape_cameras",
           "write_metashape_cameras", "camera_from_metashape", "metashape_calibration", "block_from_metashape",
           "metashape_from_block", "read_metashape_project", "MetashapeReference", "read_metashape_reference", "write_metashape_reference"]

F = np.diag([1.0, -1.0, -1.0])
HALF = 0.5  # Metashape pixel (corner origin) minus skyrig pixel
_CAL_KEYS = ("f", "cx", "cy", "b1", "b2", "k1", "k2", "k3", "k4", "p1", "p2", "p3", "p4")
#: document versions of the cameras export this reader was written for
KNOWN_VERSIONS = ("1.2.0", "1.3.0", "1.4.0", "1.5.0", "2.0.0")


@dataclass
class MetashapeChunk:
    """One chunk of a Metashape cameras export, in skyrig's conventions.

    Attributes
    ----------
    cameras
        ``{sensor id: FrameCamera}`` (named after the sensor label).
    image_name, image_camera_id
        ``(I,)`` labels and sensor ids of the aligned cameras (Metashape's "cameras" are skyrig's images).
    world_from_camera
        ``(I,)`` poses in ``frame`` (skyrig camera frame).
    frame
        ``WorldFrame.ecef()`` for a georeferenced chunk, else None (the chunk's own frame).
    crs_wkt
        The chunk's ``<reference>`` (WKT), or None.
    marker_name, marker_xyz, marker_enabled
        ``(M,)`` labels, ``(M, 3)`` reference coordinates in the chunk CRS (NaN when none), ``(M,)`` whether
        the reference is used.
    obs_image, obs_marker, obs_pixel
        Marker measurements: ``(N,)`` image index, ``(N,)`` marker index, ``(N, 2)`` skyrig pixels.
    fit_reports
        ``{sensor id: ConversionReport}`` of cameras a writer fitted.
    """

    cameras: dict[str, FrameCamera]
    image_name: NDArray[np.str_]
    image_camera_id: NDArray[np.str_]
    world_from_camera: Pose
    frame: WorldFrame | None = None
    crs_wkt: str | None = None
    marker_name: NDArray[np.str_] = field(default_factory=lambda: np.zeros(0, dtype=str))
    marker_xyz: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    marker_enabled: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))
    obs_image: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    obs_marker: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    obs_pixel: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    fit_reports: dict[str, Any] = field(default_factory=dict)

    def orientations(self, frame: WorldFrame | None = None) -> ExteriorOrientations:
        """The aligned cameras as :class:`ExteriorOrientations`, in ``frame`` (default: the chunk's own,
        which must then be georeferenced)."""
        if self.frame is None:
            raise OptionError("frame", "the chunk is not georeferenced (a local or no CRS): its orientations have "
                              "no world frame")
        eo = ExteriorOrientations(self.image_name, [self.cameras[c].name for c in self.image_camera_id],
                                  self.world_from_camera.translation, self.world_from_camera.rotation, self.frame)
        return eo if frame is None else eo.to_frame(frame)


# ---------------------------------------------------------------------------------------------- numbers
def _int_attr(e: XmlElement, key: str, path: Path) -> int:
    v = e.attrib.get(key)
    try:
        return int(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputFormatError(f"<{e.tag}> has no integer attribute {key!r} (got {v!r})", path, e.line, key) from None


# ---------------------------------------------------------------------------------------------- calibration
def camera_from_metashape(cal: XmlElement, path: Path, name: str = "metashape",
                          resolution: tuple[int, int] | None = None, pixel_size_mm: float = 0.001) -> FrameCamera:
    """A :class:`FrameCamera` from a ``<calibration>`` element (module docstring)."""
    proj = cal.find("projection")
    kind = (proj.text if proj is not None else cal.attrib.get("type", "frame")).lower()
    if kind != "frame":
        raise InputFormatError(f"camera type {kind!r} is not supported (only 'frame')", path,
                               proj.line if proj is not None else cal.line, "projection")
    if cal.find("fx") is not None:
        raise InputFormatError("an Agisoft Lens calibration (fx, fy, skew) is not supported: export it from "
                               "Metashape", path, cal.find("fx").line, "fx")  # type: ignore[union-attr]
    res = cal.find("resolution")
    if res is not None:
        w, h = _int_attr(res, "width", path), _int_attr(res, "height", path)
    elif cal.find("width") is not None and cal.find("height") is not None:
        w = int(_float(cal.find("width").text, path, cal.find("width").line, "width"))  # type: ignore[union-attr]
        h = int(_float(cal.find("height").text, path, cal.find("height").line, "height"))  # type: ignore[union-attr]
    elif resolution is not None:
        w, h = resolution
    else:
        raise InputFormatError("the calibration has no image size (<width>, <height> or <resolution>)", path,
                               cal.line, "width")
    if resolution is not None and (w, h) != tuple(resolution):
        raise InputFormatError(f"the calibration is for {w} x {h} px but its sensor is {resolution[0]} x "
                               f"{resolution[1]} px", path, cal.line, "resolution")
    v = {}
    for k in _CAL_KEYS:
        e = cal.find(k)
        v[k] = _float(e.text, path, e.line, k) if e is not None else 0.0
    if cal.find("f") is None:
        raise InputFormatError("the calibration has no <f>", path, cal.line, "f")
    if not v["f"] > 0:
        raise InputFormatError(f"focal length must be positive, got {v['f']}", path, cal.find("f").line, "f")  # type: ignore[union-attr]
    for k in ("p3", "p4"):
        if v[k]:
            raise InputFormatError(f"{k} = {v[k]} is not supported (higher-order decentring)", path,
                                   cal.find(k).line, k)  # type: ignore[union-attr]
    f = v["f"]
    d = AgisoftDistortion(v["k1"], v["k2"], v["k3"], v["k4"], v["p1"], v["p2"], v["b1"] / f, v["b2"] / f)
    return FrameCamera.from_pixels(name, w, h, f, (w - 1) / 2.0 + v["cx"], (h - 1) / 2.0 + v["cy"],
                                   pixel_size_mm=pixel_size_mm, distortion=d)


def _as_agisoft(camera: FrameCamera, fit: bool, tolerance: float, reports: dict[str, Any], key: str) -> FrameCamera:
    ex = exact_conversion(camera, "agisoft")
    if ex is not None:
        return ex
    if not fit:
        raise OptionError("fit_cameras", f"camera {camera.name!r}: Metashape's frame model cannot hold the "
                          f"{camera.distortion.name!r} distortion exactly; convert it first (skyrig convert "
                          "--camera) or write with fit_cameras=True")
    out, reports[key] = fit_or_refuse(camera, AgisoftDistortion(), tolerance, "Metashape")
    return out


def metashape_calibration(camera: FrameCamera) -> dict[str, float]:
    """``{f, cx, cy, b1, b2, k1..k4, p1, p2}`` of a camera with the ``agisoft`` distortion (Metashape's units)."""
    d = camera.distortion
    if not isinstance(d, AgisoftDistortion):
        raise OptionError("camera", f"camera {camera.name!r} has the {d.name!r} distortion, not 'agisoft'")
    f = camera.focal_px
    col, row = camera.principal_point_px
    return {"f": f, "cx": col - (camera.width - 1) / 2.0, "cy": row - (camera.height - 1) / 2.0, "b1": d.b1 * f,
            "b2": d.b2 * f, "k1": d.k1, "k2": d.k2, "k3": d.k3, "k4": d.k4, "p1": d.p1, "p2": d.p2}


def _calibration_xml(parent: ET.Element | None, camera: FrameCamera, sensor_style: bool) -> ET.Element:
    e = ET.Element("calibration") if parent is None else ET.SubElement(parent, "calibration")
    vals = metashape_calibration(camera)
    if sensor_style:
        e.set("type", "frame")
        e.set("class", "adjusted")
        ET.SubElement(e, "resolution", width=str(camera.width), height=str(camera.height))
    else:
        ET.SubElement(e, "projection").text = "frame"
        ET.SubElement(e, "width").text = str(camera.width)
        ET.SubElement(e, "height").text = str(camera.height)
    for k, v in vals.items():
        ET.SubElement(e, k).text = repr(float(v))
    if not sensor_style:
        ET.SubElement(e, "date").text = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    return e


def read_metashape_calibration(path: str | PathLike[str], name: str | None = None,
                               pixel_size_mm: float = 0.001) -> FrameCamera:
    """Read an Agisoft camera calibration XML: a :class:`FrameCamera` (named ``name`` or after the file)."""
    p = Path(path)
    root = read_xml(p)
    cal = root if root.tag == "calibration" else next(root.iter("calibration"), None)
    if cal is None:
        raise InputFormatError("no <calibration> element (not an Agisoft calibration file)", p, root.line)
    return camera_from_metashape(cal, p, name or p.stem, pixel_size_mm=pixel_size_mm)


def write_metashape_calibration(path: str | PathLike[str], camera: FrameCamera, fit_cameras: bool = False,
                                fit_tolerance_px: float = FIT_TOLERANCE_PX) -> Any:
    """Write ``camera`` as an Agisoft calibration XML (atomically).  Returns the fit report when the camera was
    fitted (``fit_cameras``), else None."""
    reports: dict[str, Any] = {}
    cam = _as_agisoft(camera, fit_cameras, fit_tolerance_px, reports, camera.name)
    _write_tree(path, _calibration_xml(None, cam, sensor_style=False))
    return reports.get(camera.name)


# ---------------------------------------------------------------------------------------------- cameras export
def _similarity(t: XmlElement | None, path: Path) -> NDArray[np.float64]:
    """4 x 4 matrix of a chunk / component ``<transform>`` (identity when absent)."""
    M = np.eye(4)
    if t is None:
        return M
    mat = t.find("matrix")
    if mat is not None:
        return _floats(mat, 16, path, "matrix").reshape(4, 4)
    rot, tr, sc = t.find("rotation"), t.find("translation"), t.find("scale")
    R = _floats(rot, 9, path, "rotation").reshape(3, 3) if rot is not None else np.eye(3)
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-6:
        raise InputFormatError("the rotation is not orthonormal", path, rot.line if rot is not None else t.line,
                               "rotation")
    s = _floats(sc, 1, path, "scale")[0] if sc is not None else 1.0
    M[:3, :3] = s * R
    M[:3, 3] = _floats(tr, 3, path, "translation") if tr is not None else 0.0
    return M


def read_metashape_cameras(path: str | PathLike[str], chunk: int = 0) -> MetashapeChunk:
    """Read a Metashape cameras export (``<document>``), chunk number ``chunk`` (0: the first)."""
    p = Path(path)
    root = read_xml(p)
    if root.tag != "document":
        raise InputFormatError(f"root element is <{root.tag}>, not <document> (not a Metashape cameras export)", p,
                               root.line)
    ver = root.attrib.get("version")
    if ver is not None and ver.split(".")[0] not in {v.split(".")[0] for v in KNOWN_VERSIONS}:
        raise InputFormatError(f"document version {ver} is not one this reader knows ({', '.join(KNOWN_VERSIONS)})",
                               p, root.line, "version")
    chunks = list(root.iter("chunk"))
    if len(chunks) <= chunk:
        raise InputFormatError(f"the document has {len(chunks)} chunk(s); chunk {chunk} asked for", p, root.line)
    ch = chunks[chunk]
    return _chunk_of(ch, p, [(p, fr) for fr in ch.findall("frames/frame")])


def _chunk_of(ch: XmlElement, p: Path, frames: list[tuple[Path, XmlElement]]) -> MetashapeChunk:
    """A ``<chunk>`` element (of a cameras export, or a project's ``chunk.zip``) and its frames (elements holding
    ``<markers>``, each with the file it comes from) in skyrig's conventions."""
    # sensors
    cams: dict[str, FrameCamera] = {}
    for s in ch.findall("sensors/sensor"):
        sid = str(_int_attr(s, "id", p))
        kind = s.attrib.get("type", "frame")
        if kind != "frame":
            raise InputFormatError(f"sensor {sid} has type {kind!r}; only 'frame' is supported", p, s.line, "type")
        res = s.find("resolution")
        size = (_int_attr(res, "width", p), _int_attr(res, "height", p)) if res is not None else None
        px = 0.001
        for prop in s.findall("property"):
            if prop.attrib.get("name") == "pixel_width" and prop.attrib.get("value"):
                px = _float(prop.attrib["value"], p, prop.line, "pixel_width")
        cals = s.findall("calibration")
        cal = next((c for c in cals if c.attrib.get("class") == "adjusted"), cals[0] if cals else None)
        if cal is None:
            raise InputFormatError(f"sensor {sid} has no <calibration>", p, s.line, "calibration")
        cams[sid] = camera_from_metashape(cal, p, s.attrib.get("label", f"sensor{sid}"), size,
                                          px if px > 0 else 0.001)
    comps = {str(_int_attr(c, "id", p)): _similarity(c.find("transform"), p) for c in ch.findall("components/component")}
    chunk_T = _similarity(ch.find("transform"), p)
    ref = ch.find("reference")
    crs_wkt = ref.text if ref is not None and ref.text else None
    geo = ch.find("transform") is not None and crs_wkt is not None and not crs_wkt.lstrip().upper().startswith(
        ("LOCAL_CS", "ENGCRS", "ENGINEERINGCRS"))
    names, sids, R, C, index = [], [], [], [], {}
    for c in ch.findall("cameras/camera") + [c for g in ch.findall("cameras/group") for c in g.findall("camera")]:
        cid = str(_int_attr(c, "id", p))
        t = c.find("transform")
        if t is None:
            continue  # not aligned
        sid = c.attrib.get("sensor_id")
        if sid not in cams:
            raise InputFormatError(f"camera {cid} names sensor {sid!r}, which is not among the sensors", p, c.line,
                                   "sensor_id")
        M = _floats(t, 16, p, "transform").reshape(4, 4)
        comp = c.attrib.get("component_id")
        if comp is not None and comp not in comps:
            raise InputFormatError(f"camera {cid} names component {comp!r}, which is not among the components", p,
                                   c.line, "component_id")
        W = chunk_T @ comps.get(comp, np.eye(4)) @ M  # type: ignore[arg-type]
        A = W[:3, :3]
        s = np.cbrt(np.linalg.det(A))
        if not s > 0:
            raise InputFormatError(f"camera {cid}: the transform is not a rotation", p, t.line, "transform")
        Rk = A / s
        if np.abs(Rk @ Rk.T - np.eye(3)).max() > 1e-6:
            raise InputFormatError(f"camera {cid}: the transform's rotation is not orthonormal", p, t.line,
                                   "transform")
        index[cid] = len(names)
        names.append(c.attrib.get("label", cid))
        sids.append(sid)
        R.append(Rk @ F)
        C.append(W[:3, 3])
    # markers and their measurements
    mnames, mxyz, men, mindex = [], [], [], {}
    for m in ch.findall("markers/marker"):
        mid = str(_int_attr(m, "id", p))
        r = m.find("reference")
        xyz = [np.nan] * 3
        en = False
        if r is not None:
            xyz = [_float(r.attrib[k], p, r.line, k) if k in r.attrib else np.nan for k in "xyz"]
            en = r.attrib.get("enabled", "true").lower() in ("true", "1")
        mindex[mid] = len(mnames)
        mnames.append(m.attrib.get("label", mid))
        mxyz.append(xyz)
        men.append(en)
    oi, om, opx = [], [], []
    for fp, fr in frames:
        for m in fr.findall("markers/marker"):
            mid = m.attrib.get("marker_id")
            if mid not in mindex:
                raise InputFormatError(f"measurement of unknown marker {mid!r}", fp, m.line, "marker_id")
            for loc in m.findall("location"):
                cid = loc.attrib.get("camera_id")
                if cid not in index:
                    continue  # a camera that is not aligned (or not in this chunk)
                oi.append(index[cid])
                om.append(mindex[mid])
                opx.append([_float(loc.attrib.get("x", ""), fp, loc.line, "x") - HALF,
                            _float(loc.attrib.get("y", ""), fp, loc.line, "y") - HALF])
    return MetashapeChunk(
        cams, np.array(names, dtype=str), np.array(sids, dtype=str),
        Pose(np.array(R).reshape(-1, 3, 3), np.array(C).reshape(-1, 3), "world", "camera"),
        WorldFrame.ecef() if geo else None, crs_wkt, np.array(mnames, dtype=str), np.array(mxyz).reshape(-1, 3),
        np.array(men, bool), np.array(oi, np.int64), np.array(om, np.int64), np.array(opx).reshape(-1, 2))


def _zip_xml(archive: Path, member: str = "doc.xml") -> tuple[Path, XmlElement]:
    """The XML ``member`` of the zip ``archive`` (messages name it ``ARCHIVE/doc.xml``)."""
    import zipfile

    where = archive / member
    try:
        with zipfile.ZipFile(archive) as z:
            data = z.read(member)
    except FileNotFoundError:
        raise InputFormatError("file not found (the project's .files folder is incomplete)", archive) from None
    except KeyError:
        raise InputFormatError(f"the archive holds no {member}", archive) from None
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise InputFormatError(f"not a readable zip archive ({exc})", archive) from None
    return where, read_xml(where, data)


def _archive_path(base: Path, rel: str | None, owner: Path, e: XmlElement) -> Path:
    """``base / rel`` for a ``path`` attribute of ``e`` (refused when absent or leaving ``base``)."""
    if not rel:
        raise InputFormatError("no path attribute", owner, e.line, "path")
    q = (base / rel).resolve()
    if base.resolve() not in q.parents:
        raise InputFormatError(f"path {rel!r} leads out of {base.name}", owner, e.line, "path")
    return q


def read_metashape_project(path: str | PathLike[str], chunk: int = 0) -> MetashapeChunk:
    """Read chunk number ``chunk`` (0: the first) of a Metashape project ``NAME.psx`` into the structures of
    :func:`read_metashape_cameras`.

    The project (Agisoft's documented layout, ``docs/formats/metashape.md``): ``NAME.psx`` is an XML
    ``<document version path="{projectname}.files/project.zip">``; ``project.zip``'s ``doc.xml`` lists the chunks
    (``<chunks><chunk id path="0/chunk.zip"/>``, paths relative to the ``.files`` folder); a ``chunk.zip``'s
    ``doc.xml`` is a ``<chunk>`` with the ``<sensors>``, ``<cameras>`` (also inside ``<group>``), ``<markers>``,
    ``<reference>`` and ``<transform>`` of the cameras export, and ``<frames><frame path="0/frame.zip"/>``
    (relative to the chunk's folder) whose ``doc.xml`` is a ``<frame>`` holding the marker measurements
    (``<markers><marker marker_id><location camera_id x y>``).  Same conventions as the cameras export.
    """
    p = Path(path)
    root = read_xml(p)
    if root.tag != "document":
        raise InputFormatError(f"root element is <{root.tag}>, not <document> (not a Metashape project)", p, root.line)
    ver = root.attrib.get("version")
    if ver is not None and ver.split(".")[0] not in {v.split(".")[0] for v in KNOWN_VERSIONS}:
        raise InputFormatError(f"document version {ver} is not one this reader knows ({', '.join(KNOWN_VERSIONS)})",
                               p, root.line, "version")
    rel = root.attrib.get("path", "{projectname}.files/project.zip").replace("{projectname}", p.stem)
    files = p.parent / rel.split("/")[0]
    proj_where, proj = _zip_xml(_archive_path(p.parent, rel, p, root))
    entries = proj.findall("chunks/chunk")
    if len(entries) <= chunk:
        raise InputFormatError(f"the project has {len(entries)} chunk(s); chunk {chunk} asked for", proj_where,
                               proj.line, "chunks")
    entry = entries[chunk]
    chunk_zip = _archive_path(files, entry.attrib.get("path"), proj_where, entry)
    where, ch = _zip_xml(chunk_zip)
    if ch.tag != "chunk":
        raise InputFormatError(f"root element is <{ch.tag}>, not <chunk>", where, ch.line)
    frames = []
    for fr in ch.findall("frames/frame"):
        fw, fe = _zip_xml(_archive_path(chunk_zip.parent, fr.attrib.get("path"), where, fr))
        frames.append((fw, fe))
    return _chunk_of(ch, where, frames)


def write_metashape_cameras(path: str | PathLike[str], chunk: MetashapeChunk, fit_cameras: bool = False,
                            fit_tolerance_px: float = FIT_TOLERANCE_PX) -> Path:
    """Write ``chunk`` as a Metashape cameras export (document version 1.5.0, atomically) that Metashape's
    Import Cameras reads: the chunk transform is the identity (camera transforms in world coordinates) and, for
    a georeferenced chunk (``frame`` ECEF), ``<reference>`` is ``crs_wkt`` or WGS 84."""
    if chunk.frame is not None and chunk.frame.kind != "ecef":
        raise OptionError("frame", f"Metashape's world is geocentric; the chunk is in {chunk.frame.describe()}: "
                          "convert the poses to ECEF first")
    doc = ET.Element("document", version="1.5.0")
    ch = ET.SubElement(doc, "chunk", label="skyrig", enabled="true")
    sensors = ET.SubElement(ch, "sensors", next_id=str(len(chunk.cameras)))
    sensor_ids = {}
    for k, (sid, cam) in enumerate(chunk.cameras.items()):
        sensor_ids[sid] = str(k)
        ag = _as_agisoft(cam, fit_cameras, fit_tolerance_px, chunk.fit_reports, sid)
        s = ET.SubElement(sensors, "sensor", id=str(k), label=cam.name, type="frame")
        ET.SubElement(s, "resolution", width=str(cam.width), height=str(cam.height))
        ET.SubElement(s, "property", name="pixel_width", value=repr(float(cam.pixel_size_mm)))
        ET.SubElement(s, "property", name="pixel_height", value=repr(float(cam.pixel_size_mm)))
        ET.SubElement(s, "property", name="focal_length", value=repr(float(cam.focal_mm)))
        _calibration_xml(s, ag, sensor_style=True)
    cams = ET.SubElement(ch, "cameras", next_id=str(len(chunk.image_name)))
    R = chunk.world_from_camera.rotation.reshape(-1, 3, 3) @ F
    C = chunk.world_from_camera.translation.reshape(-1, 3)
    for i, name in enumerate(chunk.image_name):
        c = ET.SubElement(cams, "camera", id=str(i), sensor_id=sensor_ids[str(chunk.image_camera_id[i])],
                          label=str(name))
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = R[i], C[i]
        ET.SubElement(c, "transform").text = " ".join(repr(float(v)) for v in M.ravel())
    if len(chunk.marker_name):
        mk = ET.SubElement(ch, "markers", next_id=str(len(chunk.marker_name)))
        for j, name in enumerate(chunk.marker_name):
            m = ET.SubElement(mk, "marker", id=str(j), label=str(name))
            if np.all(np.isfinite(chunk.marker_xyz[j])):
                ET.SubElement(m, "reference", **{k: repr(float(v)) for k, v in zip("xyz", chunk.marker_xyz[j])},
                              enabled="true" if chunk.marker_enabled[j] else "false")
        frames = ET.SubElement(ch, "frames", next_id="1")
        fm = ET.SubElement(ET.SubElement(frames, "frame", id="0"), "markers")
        for j in range(len(chunk.marker_name)):
            sel = np.flatnonzero(chunk.obs_marker == j)
            if not sel.size:
                continue
            m = ET.SubElement(fm, "marker", marker_id=str(j))
            for k in sel:
                x, y = chunk.obs_pixel[k] + HALF
                ET.SubElement(m, "location", camera_id=str(int(chunk.obs_image[k])), pinned="true",
                              x=repr(float(x)), y=repr(float(y)))
    if chunk.frame is not None:
        if chunk.crs_wkt:
            wkt = chunk.crs_wkt
        else:
            from pyproj import CRS

            wkt = CRS.from_epsg(4326).to_wkt("WKT1_GDAL")
        ET.SubElement(ch, "reference").text = wkt
        t = ET.SubElement(ch, "transform")
        ET.SubElement(t, "rotation", locked="true").text = "1 0 0 0 1 0 0 0 1"
        ET.SubElement(t, "translation", locked="true").text = "0 0 0"
        ET.SubElement(t, "scale", locked="true").text = "1"
    _write_tree(path, doc)
    return Path(path)


# ---------------------------------------------------------------------------------------------- blocks
def block_from_metashape(chunk: MetashapeChunk, sigma_px: float = 1.0, control_sigma_m: float = 0.01) -> Block:
    """An adjustment :class:`Block` of a chunk: one station per aligned camera, the sensors, the markers as
    points with their measurements, and the markers whose reference is enabled as control (sigma
    ``control_sigma_m`` per axis).

    The block's frame is the chunk's: ECEF for a georeferenced chunk (marker references are converted from the
    chunk CRS, heights taken as ellipsoidal), else the chunk's own.  A marker's starting position is its
    reference; a marker without one is triangulated from its rays (all its images must share one sensor), or
    refused."""
    from skyrig.orient.triangulation import triangulate_tracks

    sids = list(chunk.cameras)
    n_m = len(chunk.marker_name)
    xyz = chunk.marker_xyz.copy()
    has_ref = np.isfinite(xyz).all(axis=1)
    if chunk.frame is not None and has_ref.any():
        if not chunk.crs_wkt:
            raise OptionError("crs_wkt", "a georeferenced chunk without <reference>: the markers' CRS is unknown")
        xyz[has_ref] = WorldFrame.map(chunk.crs_wkt).to_ecef(xyz[has_ref])
    cam_of = np.array([sids.index(str(c)) for c in chunk.image_camera_id], np.int64)
    todo = np.flatnonzero(~has_ref)
    for j in todo:
        sel = np.flatnonzero(chunk.obs_marker == j)
        cams = np.unique(cam_of[chunk.obs_image[sel]])
        if sel.size < 2 or cams.size != 1:
            raise OptionError("markers", f"marker {chunk.marker_name[j]!r} has no reference and cannot be "
                              f"triangulated ({sel.size} measurements, {cams.size} sensors)")
        X, ok = triangulate_tracks(chunk.cameras[sids[int(cams[0])]], chunk.world_from_camera.rotation,
                                   chunk.world_from_camera.translation, np.zeros(sel.size, np.int64),
                                   chunk.obs_image[sel], chunk.obs_pixel[sel], 1, min_angle_deg=0.0)
        if not ok[0]:
            raise OptionError("markers", f"marker {chunk.marker_name[j]!r}: its rays do not intersect")
        xyz[j] = X[0]
    ctrl = np.flatnonzero(has_ref & chunk.marker_enabled)
    n_img = len(chunk.image_name)
    return Block(
        cameras=[chunk.cameras[s] for s in sids], station_name=chunk.image_name,
        station_rotation=chunk.world_from_camera.rotation, station_centre=chunk.world_from_camera.translation,
        image_name=chunk.image_name, image_station=np.arange(n_img), image_camera=cam_of, image_head=cam_of,
        head_name=np.array([chunk.cameras[s].name for s in sids]), point_name=chunk.marker_name,
        point_xyz=xyz.reshape(n_m, 3), obs_image=chunk.obs_image, obs_point=chunk.obs_marker,
        obs_pixel=chunk.obs_pixel, obs_sigma_px=sigma_px,
        control_point=ctrl if ctrl.size else None, control_xyz=xyz[ctrl] if ctrl.size else None,
        control_sigma=control_sigma_m,
        frame=chunk.frame if chunk.frame is not None else "Metashape chunk frame")


def metashape_from_block(block: Block) -> MetashapeChunk:
    """A :class:`MetashapeChunk` of ``block`` in the block's own frame (no CRS: write it as a local chunk):
    sensors = the block's cameras, cameras = its images, markers = its points with their measurements.  A
    marker's reference is the control coordinate (enabled) for a control point, and the point's current
    position (disabled: not used as control, but kept) otherwise; check points are written as disabled."""
    from skyrig.io.colmap import block_camera_poses

    ref = block.point_xyz.copy()
    enabled = np.zeros(len(block.point_name), bool)
    if block.control_point is not None and len(block.control_point):
        chk = (block.control_check if block.control_check is not None
               else np.zeros(len(block.control_point), bool))
        ref[block.control_point] = block.control_xyz
        enabled[block.control_point] = ~np.asarray(chk, bool)
    ids = [str(k) for k in range(len(block.cameras))]
    return MetashapeChunk(dict(zip(ids, block.cameras)), np.asarray(block.image_name, dtype=str),
                          np.array([ids[c] for c in block.image_camera]), block_camera_poses(block), None, None,
                          np.asarray(block.point_name, dtype=str), ref, enabled,
                          np.asarray(block.obs_image, np.int64), np.asarray(block.obs_point, np.int64),
                          np.asarray(block.obs_pixel, np.float64))


# ---------------------------------------------------------------------------------------------- reference CSV
@dataclass
class MetashapeReference:
    """Reference positions of a Metashape reference CSV (cameras or markers).

    Attributes
    ----------
    points
        Names and coordinates (:class:`~skyrig.georef.observations.GroundPoints`, in the frame given).
    accuracy
        ``(N, 3)`` accuracy (sigma) per axis in metres, NaN where the file has none.
    angles
        ``(N, 3)`` the ``a b c`` columns as written (degrees; Metashape's yaw, pitch, roll or omega, phi, kappa
        depending on the project's settings: not interpreted here), NaN where absent.
    """

    points: Any
    accuracy: NDArray[np.float64]
    angles: NDArray[np.float64]


#: column codes of Metashape's reference import (``Chunk.importReference(columns=...)``) that are read
REFERENCE_CODES = {"n": "label", "x": "x", "y": "y", "z": "z", "X": "accuracy x", "Y": "accuracy y",
                   "Z": "accuracy z", "a": "a", "b": "b", "c": "c", "|": "skip"}


def read_metashape_reference(path: str | PathLike[str], frame: WorldFrame, columns: str = "nxyz",
                             delimiter: str = ",") -> MetashapeReference:
    """Read a Metashape reference CSV (the camera or marker reference export, or a file made for its import):
    lines starting with ``#`` are comments; the columns are named by ``columns`` in Metashape's own codes (``n``
    label, ``x y z`` coordinates in ``frame`` -- longitude, latitude, height for a geographic CRS --, ``X Y Z``
    accuracies in metres, ``a b c`` the three angles, ``|`` a column to skip); a line with another number of
    columns is an error (a decimal comma would shift them).  A code given once for ``X``
    only (e.g. ``nxyzXZ``: horizontal then vertical accuracy) is used for x and y."""
    from skyrig.georef.observations import GroundPoints
    from skyrig.io._text import parse_float, read_text

    p = Path(path)
    bad = [c for c in columns if c not in REFERENCE_CODES]
    if bad or "n" not in columns or not {"x", "y", "z"} <= set(columns):
        raise OptionError("columns", f"{columns!r}: needs n, x, y, z; codes: "
                          + ", ".join(f"{k} {v}" for k, v in REFERENCE_CODES.items()))
    names, xyz, acc, ang = [], [], [], []
    for ln, s in enumerate(read_text(p).split("\n"), start=1):
        if not s.strip() or s.lstrip().startswith("#"):
            continue
        f = [v.strip() for v in (s.split(delimiter) if delimiter.strip() else s.split())]
        while len(f) > len(columns) and f[-1] == "":
            f.pop()  # trailing delimiters
        if len(f) != len(columns):
            raise InputFormatError(f"expected {len(columns)} columns ({columns}; '|' skips one), got {len(f)}", p,
                                   ln)
        row = dict(zip(columns, f))
        names.append(row["n"])
        xyz.append([parse_float(row[c], p, ln, c) for c in "xyz"])
        a = [parse_float(row[c], p, ln, c) if row.get(c, "") != "" else np.nan for c in "XYZ"]
        if "Y" not in columns:
            a[1] = a[0]
        acc.append(a)
        ang.append([parse_float(row[c], p, ln, c) if row.get(c, "") != "" else np.nan for c in "abc"])
    if not names:
        raise InputFormatError("no reference line", p)
    return MetashapeReference(GroundPoints(np.array(names), np.array(xyz), frame), np.array(acc), np.array(ang))


def write_metashape_reference(path: str | PathLike[str], ref: MetashapeReference) -> Path:
    """Write a reference CSV with the columns ``nxyzXYZ`` (and ``abc`` when any angle is known), a ``#`` header
    naming them: Metashape's Import Reference reads it with those column codes."""
    from skyrig.io._text import atomic_write

    pts = ref.points
    with_angles = bool(np.isfinite(ref.angles).any())
    cols = "nxyzXYZ" + ("abc" if with_angles else "")

    def num(v: float) -> str:
        return "" if not np.isfinite(v) else repr(float(v))

    with atomic_write(path) as fh:
        fh.write(f"# skyrig reference for Metashape ({pts.frame.describe()}); columns: {cols}\n")
        fh.write("#Label,X,Y,Z,Accuracy_X_(m),Accuracy_Y_(m),Accuracy_Z_(m)" + (",a,b,c" if with_angles else "")
                 + "\n")
        for i in range(len(pts)):
            vals = [*pts.xyz[i], *ref.accuracy[i]] + (list(ref.angles[i]) if with_angles else [])
            fh.write(",".join([str(pts.name[i])] + [num(v) for v in vals]) + "\n")
    return Path(path)
