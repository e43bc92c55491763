"""Camera priors from what the images carry: EXIF focal length, its 35-mm equivalent and focal-plane resolution,
vendor XMP calibrations (DJI ``CalibratedFocalLength`` / ``CalibratedOpticalCenterX/Y`` / ``DewarpData``; the
Pix4D camera tags that Parrot, MicaSense and senseFly write), and the sensor width of the camera model from a
maintained database.

The result is a :class:`CameraPrior`: the focal length and principal point in pixels of the stored image with a
stated sigma each (and OpenCV distortion where the vendor wrote one), its source in words, and the warnings met while
deriving it.  The adjustment takes it as weighted observations (``Unknowns(intrinsics="weighted")`` of ``AdjustConfig``: the
calibration prior rows of :mod:`skyrig.adjust.factors.calibration`); a calibrated camera or rig file from the user
wins over all of it (:func:`prior_from_camera`).

Sources, best first (the first that applies gives the value; the others are checked against it)
-----------------------------------------------------------------------------------------------
1. **Vendor calibration in XMP** -- DJI ``drone-dji:DewarpData`` (``date;fx,fy,cx,cy,k1,k2,p1,p2,k3``: focal
   lengths in pixels, principal point as an offset from the image centre in pixels, OpenCV distortion) or
   ``drone-dji:CalibratedFocalLength`` with ``CalibratedOpticalCenterX/Y`` (pixels, from the top-left corner);
   Pix4D's ``Camera:PerspectiveFocalLength`` (``Camera:PerspectiveFocalLengthUnits`` mm or px) and
   ``Camera:PrincipalPoint`` (mm from the top-left corner, x right, y down).  Sigma: 1 % of the focal length,
   0.5 % of the image width for the principal point: a factory calibration, good but not of this flight.
2. **EXIF FocalLength with the sensor width** of the camera from the database (``skyrig/data/sensor_data.json``,
   OpenSfM's, BSD-2; see its README) or from EXIF ``FocalPlaneXResolution`` / ``FocalPlaneResolutionUnit``:
   ``f_px = f_mm / sensor_width_mm * max(width, height)``.  Sigma 3 %: the EXIF value is the nominal focal length,
   rounded, and the sensor width a catalogue figure.
3. **EXIF FocalLengthIn35mmFilm** alone: ``f_px = f35 / 36 * max(width, height)`` (the 36-mm frame width; the
   CIPA diagonal rule and aspect-ratio crops change this by up to 10 %).  Sigma 10 %.
4. **Nothing**: ``f_px = 1.2 * max(width, height)`` (COLMAP's default guess), sigma 50 %, with a warning that names
   the missing fields and the remedy (a calibrated camera).

When two sources exist they are compared: a disagreement beyond what their sigmas allow (and beyond 12 % for the
35-mm value, whose convention is loose) is a warning naming the file and both fields -- never a silent choice.

The principal point prior is the image centre with sigma 2 % of the image width unless a vendor calibration gives
it; distortion priors are zero with the sigmas of :data:`DISTORTION_SIGMA` (loose: the block determines distortion
well when it has tie points across the frame).

Units: pixels of the stored image, origin at the centre of the top-left pixel (skyrig's convention), x right, y down.
"""

from __future__ import annotations

import functools
import json
import logging
import math
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources
from typing import Any

from skyrig.errors import ConfigError, InputFormatError

logger = logging.getLogger(__name__)

__all__ = ["CameraPrior", "camera_prior", "sensor_width_mm", "prior_from_camera", "DISTORTION_SIGMA",
           "SIGMA_VENDOR", "SIGMA_SENSOR", "SIGMA_35MM", "SIGMA_NONE"]

#: relative focal sigma of each source (see the module docstring)
SIGMA_VENDOR = 0.01
SIGMA_SENSOR = 0.03
SIGMA_35MM = 0.10
SIGMA_NONE = 0.5
#: principal point sigma as a share of the image's long side: vendor calibration / image centre
PP_SIGMA_VENDOR = 0.005
PP_SIGMA_CENTRE = 0.02
#: a-priori sigmas of OpenCV distortion coefficients (unitless, normalised image coordinates)
DISTORTION_SIGMA = {"k1": 1.0, "k2": 1.0, "k3": 1.0, "p1": 0.1, "p2": 0.1}
#: the 35-mm equivalent may differ this much from a sensor-width focal before it is called a contradiction
TOL_35MM = 0.12


@dataclass(frozen=True)
class CameraPrior:
    """What the images say about their camera, with sigmas.

    Attributes
    ----------
    width, height
        Image size in pixels.
    focal_px, focal_sigma_px
        Focal length (principal distance) and its sigma, pixels.
    pp_px, pp_sigma_px
        Principal point (column, row) in pixels (origin at the centre of the top-left pixel) and its sigma.
    pixel_size_mm
        Pixel pitch (mm) when the sensor width is known, else None.
    distortion
        OpenCV coefficients ``{k1, k2, p1, p2, k3}`` from a vendor calibration, else empty (zero prior).
    distortion_sigma
        Sigma of each distortion coefficient.
    source
        Where the focal length came from, in words (file field names and the database entry).
    warnings
        Contradictions and missing data met while deriving the prior, in words.
    """

    width: int
    height: int
    focal_px: float
    focal_sigma_px: float
    pp_px: tuple[float, float]
    pp_sigma_px: float
    pixel_size_mm: float | None = None
    distortion: dict[str, float] = field(default_factory=dict)
    distortion_sigma: dict[str, float] = field(default_factory=lambda: dict(DISTORTION_SIGMA))
    source: str = ""
    warnings: tuple[str, ...] = ()

    @property
    def focal_rel_sigma(self) -> float:
        return self.focal_sigma_px / self.focal_px

    def to_dict(self) -> dict[str, Any]:
        return {"focal_px": self.focal_px, "focal_sigma_px": self.focal_sigma_px, "pp_px": list(self.pp_px),
                "pp_sigma_px": self.pp_sigma_px, "pixel_size_mm": self.pixel_size_mm,
                "distortion": dict(self.distortion), "distortion_sigma": dict(self.distortion_sigma),
                "source": self.source, "warnings": list(self.warnings)}


@lru_cache(maxsize=1)
def _sensor_table() -> dict[str, float]:
    text = resources.files("skyrig").joinpath("data/sensor_data.json").read_text(encoding="utf-8")
    return {k.strip().lower(): float(v) for k, v in json.loads(text).items()}


def sensor_key(make: str, model: str) -> str:
    """The database key of a camera: ``"make model"`` in lower case, the make left out when the model already
    starts with it (EXIF often repeats it: ``Canon`` / ``Canon EOS 5D``)."""
    make, model = (make or "").strip(), (model or "").strip()
    if make and model.lower().startswith(make.lower()):
        return model.lower()
    return f"{make} {model}".strip().lower()


def sensor_width_mm(make: str, model: str) -> float | None:
    """Sensor width (mm, the long side) of a camera from the database, or None when it is not listed."""
    if not (make or model):
        return None
    table = _sensor_table()
    w = table.get(sensor_key(make, model))
    if w is None and model:
        w = table.get(model.strip().lower())
    return w if w is not None and w > 0 else None


def _floats(text: str, n: int, path: str, fld: str) -> list[float]:
    try:
        vals = [float(x) for x in text.replace(";", ",").split(",") if x.strip()]
    except ValueError:
        raise InputFormatError(f"XMP value {text!r} is not a list of numbers", path, None, fld) from None
    if len(vals) < n or not all(math.isfinite(v) for v in vals):
        raise InputFormatError(f"XMP value {text!r}: {n} finite numbers expected", path, None, fld)
    return vals


def _vendor(meta: Any) -> tuple[float, tuple[float, float] | None, dict[str, float], str] | None:
    """Focal (px), principal point (px) and distortion of a vendor calibration in XMP, or None."""
    xmp: dict[str, str] = getattr(meta, "xmp", {}) or {}
    W, H, path = meta.width, meta.height, meta.path
    cx0, cy0 = (W - 1) / 2.0, (H - 1) / 2.0
    dw = xmp.get("drone-dji:DewarpData")
    if dw:
        body = dw.split(";", 1)[1] if ";" in dw else dw
        v = _floats(body, 9, path, "drone-dji:DewarpData")
        fx, fy, dx, dy = v[:4]
        if fx <= 0 or fy <= 0:
            raise InputFormatError(f"XMP DewarpData focal lengths {fx}, {fy} are not positive", path, None,
                                   "drone-dji:DewarpData")
        dist = dict(zip(("k1", "k2", "p1", "p2", "k3"), v[4:9]))
        return 0.5 * (fx + fy), (cx0 + dx, cy0 + dy), dist, "DJI XMP DewarpData (factory calibration)"
    cf = xmp.get("drone-dji:CalibratedFocalLength")
    if cf:
        f = _floats(cf, 1, path, "drone-dji:CalibratedFocalLength")[0]
        if f <= 0:
            raise InputFormatError(f"XMP CalibratedFocalLength {f} is not positive", path, None,
                                   "drone-dji:CalibratedFocalLength")
        pp = None
        if "drone-dji:CalibratedOpticalCenterX" in xmp and "drone-dji:CalibratedOpticalCenterY" in xmp:
            pp = (_floats(xmp["drone-dji:CalibratedOpticalCenterX"], 1, path, "drone-dji:CalibratedOpticalCenterX")[0]
                  - 0.5,
                  _floats(xmp["drone-dji:CalibratedOpticalCenterY"], 1, path, "drone-dji:CalibratedOpticalCenterY")[0]
                  - 0.5)
        return f, pp, {}, "DJI XMP CalibratedFocalLength (factory calibration)"
    pf = xmp.get("Camera:PerspectiveFocalLength")
    if pf:
        f = _floats(pf, 1, path, "Camera:PerspectiveFocalLength")[0]
        units = xmp.get("Camera:PerspectiveFocalLengthUnits", "mm").strip().lower()
        pitch = None
        if units == "mm":
            sw = _sensor_width(meta)[0]
            if sw is None:
                return None  # a focal in mm with no pixel pitch: cannot be used
            pitch = sw / max(W, H)
            f = f / pitch
        elif units not in ("px", "pixel", "pixels"):
            raise InputFormatError(f"XMP PerspectiveFocalLengthUnits {units!r}: mm or px expected", path, None,
                                   "Camera:PerspectiveFocalLengthUnits")
        pp = None
        if "Camera:PrincipalPoint" in xmp and pitch is not None:
            x, y = _floats(xmp["Camera:PrincipalPoint"], 2, path, "Camera:PrincipalPoint")[:2]
            pp = (x / pitch - 0.5, y / pitch - 0.5)
        return f, pp, {}, "Pix4D camera XMP Camera:PerspectiveFocalLength (maker calibration)"
    return None


def _sensor_width(meta: Any) -> tuple[float | None, str]:
    """Sensor width (mm) from the database, else from the EXIF focal-plane resolution; and its source in words."""
    w = sensor_width_mm(getattr(meta, "make", ""), getattr(meta, "model", ""))
    if w is not None:
        return w, f"sensor width {w:g} mm of '{sensor_key(meta.make, meta.model)}' (OpenSfM sensor database)"
    fp = getattr(meta, "focal_plane_width_mm", None)
    if fp:
        return fp, f"sensor width {fp:.3f} mm from EXIF FocalPlaneXResolution"
    return None, ""


@functools.lru_cache(maxsize=512)
def _warn_once(text: str) -> None:
    """Log ``text`` once: a block's priors are read by more than one step of the same run (routing, the start
    camera, the GNSS block input), and the same warning printed twice reads like two problems.  The prior's
    ``warnings`` still carry every one of them into the report."""
    logger.warning(text)


def camera_prior(meta: Any, *, focal_sigma_rel: float | None = None) -> CameraPrior:
    """The camera prior of an image (:class:`skyrig.io.image_read.ImageMetadata`); see the module docstring.

    Parameters
    ----------
    meta
        The image's metadata.
    focal_sigma_rel
        Override of the focal length's relative sigma (> 0); None: the source's.

    Raises
    ------
    InputFormatError
        A vendor XMP field that cannot be read (naming the file and field).
    ConfigError
        A focal sigma that is not positive (naming ``focal_prior_rel``).
    """
    if focal_sigma_rel is not None and not (math.isfinite(focal_sigma_rel) and focal_sigma_rel > 0):
        raise ConfigError(f"focal_prior_rel: the focal prior's sigma {focal_sigma_rel!r} must be a positive number "
                          "(relative, e.g. 0.03 for 3 %)")
    W, H = int(meta.width), int(meta.height)
    long_side = max(W, H)
    centre = ((W - 1) / 2.0, (H - 1) / 2.0)
    warnings: list[str] = []
    sw, sw_src = _sensor_width(meta)
    f_mm = getattr(meta, "focal_mm", None)
    f35 = getattr(meta, "focal35_mm", None)
    f_sensor = f_mm / sw * long_side if (f_mm and sw) else None
    f_35 = f35 / 36.0 * long_side if f35 else None
    pixel = sw / long_side if sw else None
    vendor = _vendor(meta)
    pp, pp_sig, dist = centre, PP_SIGMA_CENTRE * long_side, {}
    if vendor is not None:
        f, vpp, dist, source = vendor
        rel = SIGMA_VENDOR
        if vpp is not None:
            pp, pp_sig = vpp, PP_SIGMA_VENDOR * long_side
    elif f_sensor is not None:
        f, rel = f_sensor, SIGMA_SENSOR
        source = f"EXIF FocalLength {f_mm:g} mm with the {sw_src}"
    elif f_35 is not None:
        f, rel = f_35, SIGMA_35MM
        source = f"EXIF FocalLengthIn35mmFilm {f35:g} mm (36-mm frame width)"
        if f_mm:
            warnings.append(f"{meta.path}: camera '{sensor_key(meta.make, meta.model) or '(no make/model)'}' is "
                            "not in the sensor database and EXIF has no focal-plane resolution: the focal length "
                            f"comes from FocalLengthIn35mmFilm ({f35:g} mm) with a 10 % sigma; give a calibrated "
                            "camera (rig file) for a better prior")
    else:
        f, rel = 1.2 * long_side, SIGMA_NONE
        source = "no focal length in the image metadata: 1.2 x the image's long side (COLMAP's guess)"
        warnings.append(f"{meta.path}: no usable focal length (EXIF FocalLength with a known sensor, "
                        "FocalLengthIn35mmFilm, or a vendor XMP calibration): the focal prior is 1.2 x the image "
                        f"width ({f:.0f} px) with a 50 % sigma; give a calibrated camera (rig file) if you have one")
    # cross-checks: never a silent choice between disagreeing fields
    if vendor is not None and f_sensor is not None and abs(f_sensor / f - 1) > 3 * SIGMA_SENSOR:
        warnings.append(f"{meta.path}: {source} gives {f:.0f} px but EXIF FocalLength {f_mm:g} mm with the "
                        f"{sw_src} gives {f_sensor:.0f} px ({100 * (f_sensor / f - 1):+.1f} %); the vendor "
                        "calibration is used")
    best_other = f if vendor is not None else f_sensor
    if f_35 is not None and best_other is not None and abs(f_35 / best_other - 1) > TOL_35MM:
        warnings.append(f"{meta.path}: EXIF FocalLengthIn35mmFilm {f35:g} mm gives {f_35:.0f} px but {source} "
                        f"gives {best_other:.0f} px ({100 * (f_35 / best_other - 1):+.1f} %): contradictory EXIF; "
                        "the 35-mm value is not used")
    if focal_sigma_rel is not None:
        rel = focal_sigma_rel
    for w in warnings:
        _warn_once(w)
    return CameraPrior(W, H, float(f), float(rel * f), (float(pp[0]), float(pp[1])), float(pp_sig), pixel,
                       dict(dist), dict(DISTORTION_SIGMA), source, tuple(warnings))


def prior_from_camera(camera: Any, source: str, focal_sigma_rel: float = 0.002, pp_sigma_px: float = 2.0
                      ) -> CameraPrior:
    """The prior of a calibrated camera given by the user (a rig file or camera file): it wins over the images'
    metadata; tight default sigmas (0.2 % focal, 2 px principal point)."""
    px = camera.pixel_size_mm
    f = camera.focal_px
    pp = camera.principal_point_px
    return CameraPrior(int(camera.width), int(camera.height), float(f), float(focal_sigma_rel * f),
                       (float(pp[0]), float(pp[1])), float(pp_sigma_px), float(px), {}, dict(DISTORTION_SIGMA),
                       source, ())
