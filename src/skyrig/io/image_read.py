"""Reading images (JPEG / TIFF / PNG, 8 or 16 bit) and their EXIF GPS / DJI XMP metadata.

Pixels: column right, row down, origin at the centre of the top-left pixel (as everywhere in skyrig).

Metadata comes from Pillow's EXIF reader plus a small parser of the XMP packet that DJI drones embed in
the JPEG (``drone-dji:GimbalYawDegree`` ...); no external ``exiftool`` binary is needed.  Phone images
that carry a Mapillary JSON ``ImageDescription`` give a compass heading too.
"""

from __future__ import annotations

import json
import logging
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.errors import InputFormatError
from skyrig.io._text import PathLike

logger = logging.getLogger(__name__)

#: File name suffixes treated as images.
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".tif", ".tiff", ".png")

_XMP_ATTR = re.compile(rb'([A-Za-z0-9_-]+):([A-Za-z0-9_]+)\s*=\s*"([^"]*)"')
_XMP_ELEM = re.compile(rb"<([A-Za-z0-9_-]+):([A-Za-z0-9_]+)>([^<]*)</\1:\2>")


@dataclass(frozen=True)
class ImageMetadata:
    """What an image file says about itself.

    Attributes
    ----------
    name, path
        File name (the image's identifier in skyrig) and full path.
    width, height
        Size in pixels.
    bits
        Bits per sample (8 or 16).
    make, model
        Camera make and model (EXIF), '' when absent.
    lat_deg, lon_deg, alt_m
        EXIF GPS position (WGS84 degrees; altitude in metres as the camera wrote it, usually above mean sea
        level); None when absent.
    gimbal_ypr_deg, flight_ypr_deg
        DJI XMP gimbal and aircraft (yaw, pitch, roll) in degrees (yaw clockwise from north; gimbal pitch
        -90 looks straight down); None when absent.
    relative_alt_m
        DJI XMP altitude above the take-off point, metres; None when absent.
    heading_deg
        A compass heading of the camera (e.g. Mapillary JSON description), degrees clockwise from north.
    focal_mm, focal35_mm
        EXIF focal length and its 35 mm equivalent; None when absent.
    sensor_width_mm
        Sensor width derived from ``focal_mm`` and ``focal35_mm`` (36 mm frame width), or from the
        focal-plane resolution tags; None when unknown.
    focal_plane_width_mm
        Sensor width (long side) from EXIF ``FocalPlaneXResolution`` / ``FocalPlaneResolutionUnit`` alone; None when
        absent.
    time_s
        EXIF ``DateTimeOriginal`` (+ ``SubSecTimeOriginal``) as seconds of the POSIX epoch, the camera's clock read
        as UTC (no time zone: use differences between images only); None when absent or unreadable.
    """

    name: str
    path: str
    width: int
    height: int
    bits: int = 8
    make: str = ""
    model: str = ""
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float | None = None
    gimbal_ypr_deg: tuple[float, float, float] | None = None
    flight_ypr_deg: tuple[float, float, float] | None = None
    relative_alt_m: float | None = None
    heading_deg: float | None = None
    focal_mm: float | None = None
    focal35_mm: float | None = None
    sensor_width_mm: float | None = None
    focal_plane_width_mm: float | None = None
    xmp: dict[str, str] = field(default_factory=dict, repr=False)
    time_s: float | None = None

    @property
    def has_gps(self) -> bool:
        return self.lat_deg is not None and self.lon_deg is not None

    @property
    def focal_px(self) -> float | None:
        """Focal length in pixels from the EXIF tags (None when they do not allow it)."""
        if self.focal_mm and self.sensor_width_mm:
            return self.focal_mm / self.sensor_width_mm * max(self.width, self.height)
        if self.focal35_mm:
            return self.focal35_mm / 36.0 * max(self.width, self.height)
        return None


def _clean(text: object) -> str:
    return str(text).replace("\x00", "").strip() if text is not None else ""


def _rational(v: object) -> float:
    return float(v)  # Pillow IFDRational / float / int


def _dms(v: object, ref: object, path: PathLike, tag: str) -> float:
    try:
        d, m, s = (_rational(x) for x in v)  # type: ignore[union-attr]
    except Exception as exc:  # noqa: BLE001
        raise InputFormatError(f"cannot read GPS {tag} {v!r} ({exc})", path, None, tag) from None
    val = d + m / 60.0 + s / 3600.0
    r = _clean(ref).upper()
    if r in ("S", "W"):
        val = -val
    if not math.isfinite(val):
        raise InputFormatError(f"GPS {tag} is not a number", path, None, tag)
    return val


def parse_xmp(data: bytes) -> dict[str, str]:
    """``prefix:Name -> value`` of every attribute / simple element in the first XMP packet of ``data``."""
    i = data.find(b"<x:xmpmeta")
    if i < 0:
        return {}
    j = data.find(b"</x:xmpmeta>", i)
    block = data[i : (j if j > 0 else i + 65536)]
    out: dict[str, str] = {}
    for rx in (_XMP_ATTR, _XMP_ELEM):
        for ns, key, val in rx.findall(block):
            out[f"{ns.decode()}:{key.decode()}"] = val.decode("utf-8", "replace").strip()
    return out


def _xmp_float(xmp: dict[str, str], key: str, path: PathLike) -> float | None:
    if key not in xmp:
        return None
    try:
        v = float(xmp[key])
    except ValueError:
        raise InputFormatError(f"XMP value {xmp[key]!r} is not a number", path, None, key) from None
    return v


def read_image_metadata(path: PathLike) -> ImageMetadata:
    """Read size, EXIF GPS / focal length and DJI XMP attitudes of one image.

    Raises
    ------
    InputFormatError
        The file is missing, not an image, or a metadata field cannot be parsed (naming the field).
    """
    from PIL import ExifTags, Image, UnidentifiedImageError

    p = Path(path)
    try:
        with Image.open(p) as im:
            width, height = im.size
            mode = im.mode
            exif = im.getexif()
            bits = 16 if mode in ("I;16", "I;16B", "I;16L", "I", "I;16N") else 8
            exif_ifd = dict(exif.get_ifd(0x8769))
            gps_ifd = dict(exif.get_ifd(0x8825))
    except FileNotFoundError:
        raise InputFormatError("image file not found", p) from None
    except (UnidentifiedImageError, OSError, SyntaxError) as exc:
        raise InputFormatError(f"not a readable image ({exc})", p) from None
    tags = {ExifTags.TAGS.get(k, k): v for k, v in exif.items()}
    tags.update({ExifTags.TAGS.get(k, k): v for k, v in exif_ifd.items()})
    gps = {ExifTags.GPSTAGS.get(k, k): v for k, v in gps_ifd.items()}

    lat = lon = alt = None
    if "GPSLatitude" in gps and "GPSLongitude" in gps:
        lat = _dms(gps["GPSLatitude"], gps.get("GPSLatitudeRef", "N"), p, "GPSLatitude")
        lon = _dms(gps["GPSLongitude"], gps.get("GPSLongitudeRef", "E"), p, "GPSLongitude")
        if not (-90 <= lat <= 90 and -180 <= lon <= 180):
            raise InputFormatError(f"GPS position {lat}, {lon} out of range", p, None, "GPSLatitude")
        if "GPSAltitude" in gps:
            alt = _rational(gps["GPSAltitude"])
            ref = gps.get("GPSAltitudeRef", b"\x00")
            if ref in (1, b"\x01", "1"):
                alt = -alt

    def num(tag: str) -> float | None:
        if tag not in tags:
            return None
        try:
            v = _rational(tags[tag])
        except (TypeError, ValueError, ZeroDivisionError):
            return None
        return v if math.isfinite(v) and v > 0 else None

    focal = num("FocalLength")
    f35 = num("FocalLengthIn35mmFilm")
    sensor_w = fp_w = None
    fpx, unit = num("FocalPlaneXResolution"), tags.get("FocalPlaneResolutionUnit")
    if fpx and unit in (2, 3, 4, 5):
        mm_per_unit = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}[int(unit)]
        fp_w = max(width, height) / fpx * mm_per_unit
    if focal and f35:
        sensor_w = focal * 36.0 / f35
    else:
        sensor_w = fp_w

    xmp: dict[str, str] = {}
    heading = None
    try:
        with open(p, "rb") as fh:
            head = fh.read(256 * 1024)
        xmp = parse_xmp(head)
    except OSError as exc:
        raise InputFormatError(f"cannot read file ({exc})", p) from None

    def ypr(kind: str) -> tuple[float, float, float] | None:
        vals = [_xmp_float(xmp, f"drone-dji:{kind}{a}Degree", p) for a in ("Yaw", "Pitch", "Roll")]
        return None if any(v is None for v in vals) else (vals[0], vals[1], vals[2])  # type: ignore[return-value]

    desc = _clean(tags.get("ImageDescription"))
    if desc.startswith("{"):
        try:
            h = json.loads(desc).get("MAPCompassHeading", {}).get("TrueHeading")
            heading = float(h) if h is not None else None
        except (ValueError, AttributeError, TypeError):
            heading = None
    gimbal = ypr("Gimbal")
    if gimbal is not None:
        heading = gimbal[0]

    return ImageMetadata(
        name=p.name, path=str(p), width=int(width), height=int(height), bits=bits,
        make=_clean(tags.get("Make")), model=_clean(tags.get("Model")),
        lat_deg=lat, lon_deg=lon, alt_m=alt,
        gimbal_ypr_deg=gimbal, flight_ypr_deg=ypr("Flight"),
        relative_alt_m=_xmp_float(xmp, "drone-dji:RelativeAltitude", p),
        heading_deg=heading, focal_mm=focal, focal35_mm=f35, sensor_width_mm=sensor_w,
        focal_plane_width_mm=fp_w, xmp=xmp, time_s=_exif_time(tags),
    )


def _exif_time(tags: dict) -> float | None:
    """``DateTimeOriginal`` (``YYYY:MM:DD HH:MM:SS``) plus ``SubSecTimeOriginal`` in seconds (read as UTC); None when
    absent or not a date (cameras write blanks or zeros when the clock was not set)."""
    import datetime as _dt

    raw = _clean(tags.get("DateTimeOriginal") or tags.get("DateTime"))
    try:
        t = _dt.datetime.strptime(raw[:19], "%Y:%m:%d %H:%M:%S").replace(tzinfo=_dt.timezone.utc).timestamp()
    except ValueError:
        return None
    sub = _clean(tags.get("SubsecTimeOriginal") or tags.get("SubSecTimeOriginal"))  # Pillow spells it Subsec
    if sub.isdigit():
        t += float("0." + sub)
    return t


def check_image_complete(path: PathLike) -> None:
    """Refuse a truncated or damaged JPEG, PNG or TIFF by name (OpenCV decodes a JPEG with a warning that names no
    file and grey rows where the data ends).  A JPEG that does not end with its end-of-image marker (trailing zeros
    allowed) is decoded once to be sure: data appended after the image (motion photos) is accepted.  A PNG must
    end with its IEND chunk; a TIFF's strips or tiles must lie within the file (their offsets and byte counts).
    Other formats: nothing.

    Raises
    ------
    InputFormatError
        Naming the file.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".png":
        return _check_png_complete(p)
    if suffix in (".tif", ".tiff"):
        return _check_tiff_complete(p)
    if suffix not in (".jpg", ".jpeg"):
        return
    try:
        with open(p, "rb") as fh:
            head = fh.read(3)
            fh.seek(0, 2)
            size = fh.tell()
            fh.seek(max(0, size - 4096))
            tail = fh.read()
    except OSError as exc:
        raise InputFormatError(f"cannot read the image ({exc.strerror or exc})", p) from None
    if head[:2] != b"\xff\xd8":
        raise InputFormatError("not a JPEG file (no start-of-image marker), or a truncated one", p)
    if tail.rstrip(b"\x00").endswith(b"\xff\xd9"):
        return
    from PIL import Image, ImageFile

    if getattr(ImageFile, "LOAD_TRUNCATED_IMAGES", False):
        raise InputFormatError(f"truncated JPEG: {size} bytes without an end-of-image marker", p)
    try:
        with Image.open(p) as im:
            im.load()
    except Exception as exc:  # PIL: OSError "image file is truncated", SyntaxError, ...
        raise InputFormatError(f"truncated or damaged JPEG ({exc})", p) from None


def _head_tail(p: Path, n: int = 16) -> tuple[bytes, bytes, int]:
    try:
        with open(p, "rb") as fh:
            head = fh.read(n)
            fh.seek(0, 2)
            size = fh.tell()
            fh.seek(max(0, size - n))
            return head, fh.read(), size
    except OSError as exc:
        raise InputFormatError(f"cannot read the image ({exc.strerror or exc})", p) from None


def _check_png_complete(p: Path) -> None:
    head, tail, size = _head_tail(p)
    if not head.startswith(b"\x89PNG\r\n\x1a\n"):
        raise InputFormatError("not a PNG file (no PNG signature), or a damaged one", p)
    if not tail.endswith(b"IEND\xaeB`\x82"):
        raise InputFormatError(f"truncated PNG: {size} bytes without its closing IEND chunk", p)


def _check_tiff_complete(p: Path) -> None:
    head, _, size = _head_tail(p)
    if head[:4] not in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
        raise InputFormatError("not a TIFF file (no TIFF header), or a damaged one", p)
    import warnings

    from PIL import Image

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # PIL's 'Corrupt EXIF data' of a cut file: said below in words
            with Image.open(p) as im:
                tags = im.tag_v2
                offsets = tags.get(324) or tags.get(273)  # TileOffsets, StripOffsets
                counts = tags.get(325) or tags.get(279)  # TileByteCounts, StripByteCounts
    except Exception as exc:  # PIL: a damaged directory
        raise InputFormatError(f"damaged TIFF ({exc})", p) from None
    if offsets is None or counts is None:
        return
    offsets = [offsets] if isinstance(offsets, int) else list(offsets)
    counts = [counts] if isinstance(counts, int) else list(counts)
    end = max((o + c for o, c in zip(offsets, counts) if c), default=0)
    if end > size:
        raise InputFormatError(f"truncated TIFF: its image data reaches byte {end}, the file has {size}", p)


def read_image(path: PathLike, gray: bool = True, max_size: int | None = None) -> NDArray:
    """Read pixels of a JPEG / TIFF / PNG image, keeping 8 or 16 bit depth.

    Parameters
    ----------
    path
        Image file.
    gray
        Convert colour to one channel (``(H, W)``); else ``(H, W, 3)`` in RGB order.
    max_size
        If given, downscale (area averaging) so that the longer side is at most this many pixels.

    Returns
    -------
    ``(H, W)`` or ``(H, W, 3)`` uint8 or uint16 array.
    """
    import cv2

    p = Path(path)
    if not p.is_file():
        raise InputFormatError("image file not found", p)
    check_image_complete(p)
    flags = cv2.IMREAD_ANYDEPTH | (cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_COLOR)
    img = cv2.imread(str(p), flags)
    if img is None:
        raise InputFormatError("not a readable image (OpenCV could not decode it)", p)
    if img.dtype not in (np.uint8, np.uint16):
        raise InputFormatError(f"unsupported sample type {img.dtype} (8 or 16 bit expected)", p)
    if not gray and img.ndim == 3:
        img = img[..., ::-1].copy()
    if max_size is not None and max(img.shape[:2]) > max_size:
        s = max_size / max(img.shape[:2])
        size = (max(1, round(img.shape[1] * s)), max(1, round(img.shape[0] * s)))
        img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
    return img


def list_images(folder: PathLike) -> list[Path]:
    """Image files (by suffix, case-insensitive) directly in ``folder``, sorted by name."""
    f = Path(folder)
    if not f.is_dir():
        raise InputFormatError("image folder not found", f)
    return sorted(q for q in f.iterdir() if q.is_file() and q.suffix.lower() in IMAGE_SUFFIXES)


def camera_from_metadata(meta: ImageMetadata, name: str | None = None) -> FrameCamera:
    """A distortion-free :class:`FrameCamera` from EXIF focal length (principal point at the centre).

    Raises
    ------
    InputFormatError
        The EXIF tags do not give a focal length in pixels.
    """
    f_px = meta.focal_px
    if f_px is None:
        raise InputFormatError("no usable focal length (FocalLength with FocalLengthIn35mmFilm or "
                               "FocalPlaneXResolution)", meta.path, None, "FocalLength")
    pix_mm = (meta.sensor_width_mm / max(meta.width, meta.height)) if meta.sensor_width_mm else 0.001
    return FrameCamera.from_pixels(name or (meta.model or "camera"), meta.width, meta.height, f_px,
                                   (meta.width - 1) / 2.0, (meta.height - 1) / 2.0, pixel_size_mm=pix_mm)


@dataclass(frozen=True)
class MetadataOrientations:
    """Approximate exterior orientations of images from their own metadata.

    Attributes
    ----------
    eo
        Orientations in a local ENU frame at the mean GPS position.  Rotations come from the DJI gimbal
        angles; images without them get NaN rotations (use :attr:`heading_deg`).
    heading_deg
        ``(N,)`` viewing heading (gimbal yaw or compass), NaN when unknown.
    ground_height
        Estimated terrain height in the ENU frame (from DJI ``RelativeAltitude``: height of the take-off
        point), or None.
    """

    eo: "object"
    heading_deg: NDArray[np.float64]
    ground_height: float | None


def orientations_from_metadata(metas: list[ImageMetadata]) -> MetadataOrientations:
    """Direct georeferencing from EXIF / XMP: GPS centres and DJI gimbal attitudes in local ENU.

    Raises
    ------
    InputFormatError
        An image has no GPS position (naming the image and the field).
    """
    from skyrig.geodesy.crs import geodetic_to_ecef
    from skyrig.georef.eo import ExteriorOrientations, WorldFrame
    from skyrig.io.odm import rotation_from_gimbal_ypr

    for m in metas:
        if not m.has_gps:
            raise InputFormatError("no EXIF GPS position", m.path, None, "GPSLatitude")
    llh = np.array([[m.lat_deg, m.lon_deg, m.alt_m if m.alt_m is not None else 0.0] for m in metas], dtype=float)
    frame = WorldFrame.local(*llh.mean(axis=0))
    centres = frame.from_ecef(geodetic_to_ecef(llh[:, 0], llh[:, 1], llh[:, 2]))
    rot = np.full((len(metas), 3, 3), np.nan)
    have = np.array([m.gimbal_ypr_deg is not None for m in metas])
    if have.any():
        ypr = np.array([m.gimbal_ypr_deg for m in metas if m.gimbal_ypr_deg is not None], dtype=float)
        rot[have] = rotation_from_gimbal_ypr(frame, centres[have], ypr)
    heading = np.array([np.nan if m.heading_deg is None else m.heading_deg for m in metas])
    rel = [c[2] - m.relative_alt_m for c, m in zip(centres, metas) if m.relative_alt_m is not None]
    ground = float(np.median(rel)) if rel else None
    eo = ExteriorOrientations(np.array([m.name for m in metas]), np.array([m.model or "camera" for m in metas]),
                              centres, rot, frame)
    return MetadataOrientations(eo, heading, ground)
