"""MicMac (IGN) orientations: ``Ori-*/Orientation-IMG.xml`` and the ``AutoCal*.xml`` calibrations, both ways.

Files (``docs/formats/micmac.md``)
----------------------------------
* **Calibration** (``Ori-X/AutoCal_Foc-8800_Cam-NAME.xml``)::

      <ExportAPERO><CalibrationInternConique><KnownConv>eConvApero_DistM2C</KnownConv><PP>x y</PP><F>f</F>
      <SzIm>w h</SzIm><CalibDistortion><ModRad><CDist>x y</CDist><CoeffDist>R3</CoeffDist>
      <CoeffDist>R5</CoeffDist>...</ModRad></CalibDistortion></CalibrationInternConique></ExportAPERO>

* **Orientation** (``Ori-X/Orientation-IMG.xml``)::

      <ExportAPERO><OrientationConique><OrIntImaM2C>identity</OrIntImaM2C><TypeProj>eProjStenope</TypeProj>
      <FileInterne>Ori-X/AutoCal...xml</FileInterne> (or an inline <Interne>) <Externe>
      <KnownConv>eConvApero_DistM2C</KnownConv><Centre>X Y Z</Centre><ParamRotation><CodageMatr>
      <L1>..</L1><L2>..</L2><L3>..</L3></CodageMatr></ParamRotation></Externe></OrientationConique></ExportAPERO>

Conventions (the ``eConvApero_DistM2C`` convention, the only one read)
-----------------------------------------------------------------------
* **Pose**: ``CodageMatr`` (rows ``L1 L2 L3``) is the rotation from camera to world and ``Centre`` the
  projection centre: ``X_world = R X_cam + C``, so ``X_cam = R^T (X_world - C)``.  MicMac's camera frame is
  x right, y down (image rows), z forward (towards the scene): skyrig's rotation is ``R F``,
  ``F = diag(1, -1, -1)``.
* **Projection and distortion** (in pixels): ideal ``U = PP + F (x/z, y/z)``; the radial model ``ModRad``
  (distortion "world to camera", from the ideal to the observed point, about its own centre ``CDist``)::

      d = U - CDist,  rho² = |d|²,  observed = CDist + (1 + R3 rho² + R5 rho⁴ + R7 rho⁶ + R9 rho⁸) d

  which is exactly skyrig's forward model (:mod:`skyrig.camera.forward`: distortion at the ideal point,
  centre apart from the principal point, R0 = 0) with ``xc_mm = (CDist_x - PP_x) p``, ``yc_mm = -(CDist_y -
  PP_y) p``, ``k_i = R_(2i+1) / p^(2i)`` (``p`` the pixel size in mm; MicMac has none, 0.001 is used: pixels do
  not depend on it).  Up to four coefficients (R3..R9) are read; more (non-zero), ``ModPhgrStd`` decentring /
  affinity terms, ``ModUnif`` / grid models, a non-identity ``OrIntImaM2C`` and other conventions are refused.
* **Pixels**: MicMac's image coordinates are taken with the origin at the top-left *corner* (the centre of the
  first pixel at 0.5, 0.5; evidence: MicMac's own tools put the principal point of an uncalibrated camera at
  ``SzIm / 2``), so skyrig pixels are MicMac's minus 0.5; ``pixel_origin="centre"`` reads them without the shift.
  This half pixel is the one convention here not checked against MicMac output (see docs/formats/micmac.md).
* **Units / CRS**: the world is the orientation folder's (a local frame, or the CRS the user gave MicMac with
  ``ChSys``; MicMac states none); metres.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.convert import exact_conversion
from skyrig.camera.distortion import NoDistortion
from skyrig.camera.forward import ForwardDistortion
from skyrig.camera.frame import FrameCamera
from skyrig.errors import InputFormatError, OptionError
from skyrig.geometry.pose import Pose
from skyrig.io._camera_fit import FIT_TOLERANCE_PX, fit_or_refuse
from skyrig.io._xml import XmlElement, floats_of as _floats, read_xml, write_xml as _write_tree

__all__ = ["MicmacOrientations", "read_micmac_calibration", "write_micmac_calibration", "read_micmac_orientation",
           "read_micmac_ori", "write_micmac_ori", "camera_from_micmac"]

F = np.diag([1.0, -1.0, -1.0])
CONV = "eConvApero_DistM2C"
PIXEL_MM = 0.001


def _shift(pixel_origin: str) -> float:
    if pixel_origin not in ("corner", "centre"):
        raise OptionError("pixel_origin", f"must be 'corner' or 'centre', got {pixel_origin!r}")
    return 0.5 if pixel_origin == "corner" else 0.0


@dataclass
class MicmacOrientations:
    """The images of an ``Ori-*`` folder: names, cameras (by calibration file name) and poses.

    Attributes
    ----------
    cameras
        ``{calibration name: FrameCamera}`` (the ``FileInterne`` name, or ``"<image>-interne"`` for an inline one).
    image_name, image_camera_id
        ``(I,)`` image names (from ``Orientation-<image>.xml``) and their calibration names.
    world_from_camera
        ``(I,)`` poses (skyrig camera frame) in the folder's world frame.
    """

    cameras: dict[str, FrameCamera]
    image_name: NDArray[np.str_]
    image_camera_id: NDArray[np.str_]
    world_from_camera: Pose


def _text(e: XmlElement, tag: str, path: Path) -> XmlElement:
    c = e.find(tag)
    if c is None:
        raise InputFormatError(f"<{e.tag}> has no <{tag}>", path, e.line, tag)
    return c


def _check_conv(e: XmlElement, path: Path) -> None:
    kc = e.find("KnownConv")
    if kc is not None and kc.text != CONV:
        raise InputFormatError(f"convention {kc.text!r} is not supported (only {CONV})", path, kc.line, "KnownConv")


def camera_from_micmac(cal: XmlElement, path: Path, name: str, pixel_origin: str = "corner") -> FrameCamera:
    """A :class:`FrameCamera` from a ``<CalibrationInternConique>`` (or inline ``<Interne>``) element."""
    half = _shift(pixel_origin)
    _check_conv(cal, path)
    pp = _floats(_text(cal, "PP", path), 2, path, "PP")
    f = _floats(_text(cal, "F", path), 1, path, "F")[0]
    if not f > 0:
        raise InputFormatError(f"focal length must be positive, got {f}", path, cal.find("F").line, "F")  # type: ignore[union-attr]
    sz = _floats(_text(cal, "SzIm", path), 2, path, "SzIm")
    if not (sz > 0).all() or np.any(sz != np.round(sz)):
        raise InputFormatError(f"image size must be two positive whole numbers, got {sz}", path,
                               cal.find("SzIm").line, "SzIm")  # type: ignore[union-attr]
    w, h = int(sz[0]), int(sz[1])
    dist = None
    for cd in cal.findall("CalibDistortion"):
        kinds = [c.tag for c in cd.children]
        if "ModRad" in kinds:
            mr = cd.find("ModRad")
        elif "ModPhgrStd" in kinds:
            ps = cd.find("ModPhgrStd")
            for k in ("P1", "P2", "b1", "b2"):
                e = ps.find(k)  # type: ignore[union-attr]
                if e is not None and float(e.text or 0) != 0.0:
                    raise InputFormatError(f"ModPhgrStd with {k} = {e.text} is not supported (only its radial part)",
                                           path, e.line, k)
            mr = _text(ps, "RadialePart", path)  # type: ignore[arg-type]
        else:
            raise InputFormatError(f"distortion model <{kinds[0] if kinds else '?'}> is not supported (ModRad, "
                                   "ModPhgrStd radial)", path, cd.line, kinds[0] if kinds else "CalibDistortion")
        coeffs = [_floats(c, 1, path, "CoeffDist")[0] for c in mr.findall("CoeffDist")]  # type: ignore[union-attr]
        cdist = _floats(_text(mr, "CDist", path), 2, path, "CDist")  # type: ignore[arg-type]
        if len(coeffs) > 4 and any(coeffs[4:]):
            raise InputFormatError(f"{len(coeffs)} radial coefficients; at most 4 (R3..R9) are supported", path,
                                   mr.line, "CoeffDist")  # type: ignore[union-attr]
        if not any(coeffs):
            continue
        if dist is not None:
            raise InputFormatError("more than one distortion model is composed; not supported", path, cd.line,
                                   "CalibDistortion")
        k = (coeffs + [0.0] * 4)[:4]
        p = PIXEL_MM
        dist = ForwardDistortion(xc_mm=(cdist[0] - pp[0]) * p, yc_mm=-(cdist[1] - pp[1]) * p,
                                 **{f"k{i + 1}": k[i] / p ** (2 * (i + 1)) for i in range(4)})
    return FrameCamera.from_pixels(name, w, h, f, pp[0] - half, pp[1] - half, pixel_size_mm=PIXEL_MM,
                                   distortion=dist if dist is not None else NoDistortion())


def read_micmac_calibration(path: str | PathLike[str], pixel_origin: str = "corner") -> FrameCamera:
    """Read an ``AutoCal*.xml`` (``<CalibrationInternConique>``): a camera named after the file."""
    p = Path(path)
    root = read_xml(p)
    cal = root if root.tag == "CalibrationInternConique" else root.find("CalibrationInternConique")
    if cal is None:
        raise InputFormatError("no <CalibrationInternConique> (not a MicMac calibration)", p, root.line)
    return camera_from_micmac(cal, p, p.stem, pixel_origin)


def read_micmac_orientation(path: str | PathLike[str], pixel_origin: str = "corner",
                            base: str | PathLike[str] | None = None) -> tuple[str, FrameCamera, str, Pose]:
    """Read one ``Orientation-IMG.xml``: ``(image name, camera, calibration name, world_from_camera)``.
    ``FileInterne`` is looked up relative to ``base`` (default: the folder above the Ori folder, MicMac's
    working directory), then beside the file."""
    p = Path(path)
    root = read_xml(p)
    oc = root if root.tag == "OrientationConique" else root.find("OrientationConique")
    if oc is None:
        raise InputFormatError("no <OrientationConique> (not a MicMac orientation)", p, root.line)
    tp = oc.find("TypeProj")
    if tp is not None and tp.text != "eProjStenope":
        raise InputFormatError(f"projection {tp.text!r} is not supported (eProjStenope)", p, tp.line, "TypeProj")
    aff = oc.find("OrIntImaM2C")
    if aff is not None:
        vals = [_floats(_text(aff, k, p), 2, p, k) for k in ("I00", "V10", "V01")]
        if not (np.allclose(vals[0], 0) and np.allclose(vals[1], [1, 0]) and np.allclose(vals[2], [0, 1])):
            raise InputFormatError("a non-identity OrIntImaM2C (scanned-image affinity) is not supported", p,
                                   aff.line, "OrIntImaM2C")
    image = p.stem[len("Orientation-"):] if p.stem.startswith("Orientation-") else p.stem
    inline = oc.find("Interne")
    if inline is not None:
        cal_name = f"{image}-interne"
        cam = camera_from_micmac(inline, p, cal_name, pixel_origin)
    else:
        fi = _text(oc, "FileInterne", p)
        rel = Path(fi.text)
        cands = [Path(base) / rel] if base is not None else []
        cands += [p.parent.parent / rel, p.parent / rel.name]
        hit = next((c for c in cands if c.is_file()), None)
        if hit is None:
            raise InputFormatError(f"calibration {fi.text!r} not found (looked in {', '.join(map(str, cands))})", p,
                                   fi.line, "FileInterne")
        cal_name = rel.name
        cam = read_micmac_calibration(hit, pixel_origin).with_(name=Path(rel.name).stem)
    ext = _text(oc, "Externe", p)
    _check_conv(ext, p)
    c = _floats(_text(ext, "Centre", p), 3, p, "Centre")
    cm = _text(_text(ext, "ParamRotation", p), "CodageMatr", p)
    R = np.array([_floats(_text(cm, k, p), 3, p, k) for k in ("L1", "L2", "L3")])
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
        raise InputFormatError("CodageMatr is not a rotation", p, cm.line, "CodageMatr")
    return image, cam, cal_name, Pose(R @ F, c, "world", "camera")


def read_micmac_ori(folder: str | PathLike[str], pixel_origin: str = "corner") -> MicmacOrientations:
    """Read every ``Orientation-*.xml`` of an ``Ori-*`` folder (sorted by name)."""
    d = Path(folder)
    files = sorted(d.glob("Orientation-*.xml"))
    if not files:
        raise InputFormatError("no Orientation-*.xml (not a MicMac Ori folder)", d)
    cams: dict[str, FrameCamera] = {}
    names, ids, R, C = [], [], [], []
    for f in files:
        img, cam, cal, pose = read_micmac_orientation(f, pixel_origin)
        if cal in cams and cams[cal] != cam:
            raise InputFormatError(f"calibration {cal!r} differs from the one read before", f, None, "FileInterne")
        cams[cal] = cam
        names.append(img)
        ids.append(cal)
        R.append(pose.rotation)
        C.append(pose.translation)
    return MicmacOrientations(cams, np.array(names, dtype=str), np.array(ids, dtype=str),
                              Pose(np.array(R), np.array(C), "world", "camera"))


# ---------------------------------------------------------------------------------------------- writers
def _micmac_numbers(camera: FrameCamera, half: float) -> tuple[list[float], float, list[float], list[float]]:
    """``(PP, F, CDist, [R3, R5, R7, R9])`` of a camera with no or the forward (R0 = 0, radial only) distortion."""
    d = camera.distortion
    if isinstance(d, ForwardDistortion):
        if d.r0_mm or any(getattr(d, k) for k in ("p1", "p2", "b1", "b2")):
            raise OptionError("fit_cameras", f"camera {camera.name!r}: MicMac's ModRad holds a forward model with "
                              "R0 = 0 and no decentring or affinity")
    elif not isinstance(d, NoDistortion):
        raise OptionError("fit_cameras", f"camera {camera.name!r}: MicMac's ModRad cannot hold the {d.name!r} "
                          "distortion exactly; convert it (skyrig convert --camera --to-model forward) or write "
                          "with fit_cameras=True")
    col, row = camera.principal_point_px
    pp = [col + half, row + half]
    p = camera.pixel_size_mm
    if isinstance(d, ForwardDistortion):
        cd = [pp[0] + d.xc_mm / p, pp[1] - d.yc_mm / p]
        ks = [d.k1 * p**2, d.k2 * p**4, d.k3 * p**6, d.k4 * p**8]
    else:
        cd, ks = list(pp), [0.0]
    return pp, camera.focal_px, cd, ks


def _calibration_element(parent: ET.Element | None, camera: FrameCamera, half: float) -> ET.Element:
    pp, f, cd, ks = _micmac_numbers(camera, half)
    e = ET.Element("CalibrationInternConique") if parent is None else ET.SubElement(parent, "CalibrationInternConique")
    ET.SubElement(e, "KnownConv").text = CONV
    ET.SubElement(e, "PP").text = f"{pp[0]!r} {pp[1]!r}"
    ET.SubElement(e, "F").text = repr(float(f))
    ET.SubElement(e, "SzIm").text = f"{camera.width} {camera.height}"
    mr = ET.SubElement(ET.SubElement(e, "CalibDistortion"), "ModRad")
    ET.SubElement(mr, "CDist").text = f"{float(cd[0])!r} {float(cd[1])!r}"
    for k in ks:
        ET.SubElement(mr, "CoeffDist").text = repr(float(k))
    return e


def _as_micmac(camera: FrameCamera, fit: bool, tolerance: float, reports: dict | None = None) -> FrameCamera:
    ex = exact_conversion(camera, "forward")
    cam = ex if ex is not None else camera
    try:
        _micmac_numbers(cam, 0.0)
        return cam
    except OptionError:
        if not fit:
            raise
    out, rep = fit_or_refuse(camera, ForwardDistortion(), tolerance, "MicMac", hold=("p1", "p2", "b1", "b2"))
    if reports is not None:
        reports[camera.name] = rep
    return out


def write_micmac_calibration(path: str | PathLike[str], camera: FrameCamera, pixel_origin: str = "corner",
                             fit_cameras: bool = False, fit_tolerance_px: float = FIT_TOLERANCE_PX) -> None:
    """Write ``camera`` as an ``AutoCal*.xml`` (atomically); see the module docstring for the model."""
    root = ET.Element("ExportAPERO")
    root.append(_calibration_element(None, _as_micmac(camera, fit_cameras, fit_tolerance_px), _shift(pixel_origin)))
    _write_tree(path, root)


def write_micmac_ori(folder: str | PathLike[str], ori: MicmacOrientations, pixel_origin: str = "corner",
                     fit_cameras: bool = False, fit_tolerance_px: float = FIT_TOLERANCE_PX,
                     reports: dict | None = None) -> list[Path]:
    """Write an ``Ori-*`` folder: ``AutoCal-<camera>.xml`` per camera and ``Orientation-<image>.xml`` per image
    (``FileInterne`` relative to the folder above, MicMac's working directory).  Returns the files written;
    ``reports`` (a dict) receives the fit report of each camera fitted (``fit_cameras``) by camera name."""
    d = Path(folder)
    half = _shift(pixel_origin)
    bad = [str(n) for n in ori.image_name if "/" in str(n) or "\\" in str(n) or not str(n).strip()]
    if bad:
        raise OptionError("image_name", f"image name {bad[0]!r}: MicMac's images are file names in its working "
                          "directory (no folder part); rename the images")
    out = []
    cal_files = {}
    for cid, cam in ori.cameras.items():
        name = str(cid) if str(cid).endswith(".xml") else f"AutoCal-{cid}.xml"
        root = ET.Element("ExportAPERO")
        root.append(_calibration_element(None, _as_micmac(cam, fit_cameras, fit_tolerance_px, reports), half))
        _write_tree(d / name, root)
        cal_files[cid] = name
        out.append(d / name)
    R = ori.world_from_camera.rotation.reshape(-1, 3, 3) @ F
    C = ori.world_from_camera.translation.reshape(-1, 3)
    for i, img in enumerate(ori.image_name):
        root = ET.Element("ExportAPERO")
        oc = ET.SubElement(root, "OrientationConique")
        aff = ET.SubElement(oc, "OrIntImaM2C")
        for k, v in (("I00", "0 0"), ("V10", "1 0"), ("V01", "0 1")):
            ET.SubElement(aff, k).text = v
        ET.SubElement(oc, "TypeProj").text = "eProjStenope"
        ET.SubElement(oc, "ZoneUtileInPixel").text = "true"
        ET.SubElement(oc, "FileInterne").text = f"{d.name}/{cal_files[str(ori.image_camera_id[i])]}"
        ET.SubElement(oc, "RelativeNameFI").text = "true"
        ext = ET.SubElement(oc, "Externe")
        ET.SubElement(ext, "Time").text = "0"
        ET.SubElement(ext, "KnownConv").text = CONV
        ET.SubElement(ext, "Centre").text = " ".join(repr(float(v)) for v in C[i])
        cm = ET.SubElement(ET.SubElement(ext, "ParamRotation"), "CodageMatr")
        for k, row in zip(("L1", "L2", "L3"), R[i]):
            ET.SubElement(cm, k).text = " ".join(repr(float(v)) for v in row)
        ET.SubElement(ET.SubElement(oc, "ConvOri"), "KnownConv").text = CONV
        _write_tree(d / f"Orientation-{img}.xml", root)
        out.append(d / f"Orientation-{img}.xml")
    return out
