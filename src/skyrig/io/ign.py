"""IGN (Institut national de l'information géographique et forestière) aerial-triangulation files.

As found in the IGN aerial block (``../shared/data/ign-aerial-block``):

``*.OPK``
    A header line ``NOM X Y Z O P K CAMERA`` then one whitespace-separated line per image: name, projection
    centre X Y Z in the mapping CRS (Lambert-93 for that block), omega phi kappa in **degrees** with the
    omega-phi-kappa sequence in the map-grid frame, and the camera name.  The Z of IGN projection centres
    are altitudes from an adjustment made in map coordinates (see :mod:`skyrig.geodesy.mapheights`).
``*.mes``
    Image measurements ``point image column row`` (pixels, column right, row down); point names may be quoted.
``*_world.mes``
    Ground coordinates ``point X Y Z``.
``*.app``
    Ground control ``"name" type X Y Z``.
``Camera*.txt``
    ``key = value`` lines: ``Name``, ``PPAx``, ``PPAy`` (principal point, column and row in pixels),
    ``focal`` (pixels), ``width``, ``height``.
"""

from __future__ import annotations

import os

import numpy as np

from skyrig.camera.frame import FrameCamera
from skyrig.errors import InputFormatError
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.georef.observations import GroundPoints, ImageMeasurements
from skyrig.geometry.angles import check_plausible
from skyrig.io._text import read_text

PathLike = str | os.PathLike[str]


def _lines(path: PathLike) -> list[tuple[int, list[str]]]:
    text = read_text(path)
    out = []
    for i, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if s and not s.startswith("#"):
            out.append((i, s.split()))
    return out


def _num(path: PathLike, line: int, field: str, text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise InputFormatError(f"{text!r} is not a number", path, line, field) from None
    if not np.isfinite(v):
        raise InputFormatError(f"{text!r} is not a finite number", path, line, field)
    return v


def _truncated(path: PathLike, line: int, rows: list[tuple[int, list[str]]]) -> str:
    """A hint when the bad line is the file's last one and the file does not end with a newline."""
    if line != rows[-1][0]:
        return ""
    try:
        with open(path, "rb") as fh:
            fh.seek(-1, os.SEEK_END)
            ends_open = fh.read(1) not in (b"\n", b"\r")
    except OSError:
        return ""
    return " (the file ends in the middle of this line: truncated?)" if ends_open else " (last line: truncated?)"


def _name(s: str) -> str:
    return s.strip('"').strip("'")


def read_ign_opk(path: PathLike, frame: WorldFrame) -> ExteriorOrientations:
    """Read an IGN ``.OPK`` file into exterior orientations in ``frame`` (a map frame: CRS + geoid).

    Heights are returned as stored (with the linear alteration of a map adjustment, if any); use
    :meth:`ExteriorOrientations.with_map_heights_reduced` to undo it.
    """
    rows = _lines(path)
    if not rows:
        raise InputFormatError("empty OPK file", path)
    header = [h.upper() for h in rows[0][1]]
    expected = ["NOM", "X", "Y", "Z", "O", "P", "K", "CAMERA"]
    if header[: len(expected)] != expected:
        raise InputFormatError(f"header must be {' '.join(expected)}, got {' '.join(rows[0][1])}", path, rows[0][0])
    names, cams, vals = [], [], []
    fields = expected[1:7]
    seen: dict[str, int] = {}
    for line, f in rows[1:]:
        if len(f) != 8:
            raise InputFormatError(f"expected 8 fields, found {len(f)}" + _truncated(path, line, rows),
                                   path, line, expected[min(len(f), 7)])
        vals.append([_num(path, line, fields[j], f[j + 1]) for j in range(6)])
        if f[0] in seen:
            raise InputFormatError(f"image {f[0]!r} appears twice (first on line {seen[f[0]]})", path, line, "NOM")
        seen[f[0]] = line
        names.append(f[0])
        cams.append(f[7])
    if not names:
        raise InputFormatError("no image after the header line", path, rows[0][0])
    v = np.array(vals)
    for j, fld in enumerate(("O", "P", "K")):
        why = check_plausible(v[:, 3 + j], "deg")
        if why:
            bad = int(np.argmax(np.abs(v[:, 3 + j])))
            raise InputFormatError(why, path, rows[1 + bad][0], fld)
    from skyrig.io.plausibility import angle_readings, check_attitude_reading, check_coordinates

    lines = [r[0] for r in rows[1:]]
    check_coordinates(v[:, :3], frame, path, lines, "camera", ("X", "Y", "Z"))

    rotations_of = angle_readings(frame, v[:, :3], v[:, 3:6])
    check_attitude_reading(rotations_of, "deg", "opk", v[:, :3], path, lines, ("O", "P", "K"),
                           "an IGN .OPK file holds omega, phi, kappa in degrees: convert the angles, or give the "
                           "orientations as a skyrig EO CSV that declares them ('# angles: gon', '# convention: ypr')",
                           groups=cams, values=v[:, 3:6], frame=frame)
    rot = rotations_of("deg", "opk")
    return ExteriorOrientations(np.array(names), np.array(cams), v[:, :3], rot, frame)


def read_ign_camera(path: PathLike, pixel_size_mm: float = 0.001) -> FrameCamera:
    """Read an IGN camera ``.txt`` (focal and principal point in pixels, no distortion)."""
    values: dict[str, tuple[int, str]] = {}
    for line, f in _lines(path):
        joined = " ".join(f)
        if "=" not in joined:
            raise InputFormatError("expected 'key = value'", path, line)
        k, v = (s.strip() for s in joined.split("=", 1))
        values[k.lower()] = (line, v)
    for k in ("name", "ppax", "ppay", "focal", "width", "height"):
        if k not in values:
            raise InputFormatError("missing key", path, None, k)
    num = {k: _num(path, values[k][0], k, values[k][1]) for k in ("ppax", "ppay", "focal", "width", "height")}
    for k in ("focal", "width", "height"):
        if num[k] <= 0:
            raise InputFormatError(f"must be positive, got {values[k][1]!r}", path, values[k][0], k)
    for k in ("width", "height"):
        if num[k] != int(num[k]) or num[k] > 10**6:
            raise InputFormatError(f"must be a whole number of pixels (at most 1000000), got {values[k][1]!r}", path,
                                   values[k][0], k)
    for k, size in (("ppax", "width"), ("ppay", "height")):  # a principal point off the image: a wrong size or point
        if not -0.5 <= num[k] <= num[size] - 0.5:
            raise InputFormatError(f"principal point {values[k][1]!r} px is outside the image ({size} "
                                   f"{values[size][1]} px)", path, values[k][0], k)
    try:
        return FrameCamera.from_pixels(
            values["name"][1], int(num["width"]), int(num["height"]), num["focal"], num["ppax"], num["ppay"],
            pixel_size_mm)
    except ValueError as exc:  # any other value the camera model refuses
        raise InputFormatError(str(exc), path) from None


def read_ign_measurements(path: PathLike) -> ImageMeasurements:
    """Read image measurements ``point image column row`` (``.mes``)."""
    return read_ign_measurements_lines(path)[0]


def read_ign_measurements_lines(path: PathLike) -> tuple[ImageMeasurements, np.ndarray]:
    """:func:`read_ign_measurements` and the ``(N,)`` 1-based line number of each measurement (for messages)."""
    rows = _lines(path)
    if not rows:
        raise InputFormatError("no measurement in the file (expected lines 'point image column row')", path)
    pts, imgs, px, lines = [], [], [], []
    seen: dict[tuple[str, str], int] = {}
    for line, f in rows:
        if len(f) != 4:
            raise InputFormatError(f"expected 4 fields (point image column row), found {len(f)}"
                                   + _truncated(path, line, rows), path, line)
        key = (_name(f[0]), f[1])
        if key in seen:
            raise InputFormatError(f"point {key[0]!r} is measured twice in image {key[1]!r} (first on line "
                                   f"{seen[key]})", path, line, "point")
        seen[key] = line
        pts.append(key[0])
        imgs.append(f[1])
        px.append((_num(path, line, "column", f[2]), _num(path, line, "row", f[3])))
        lines.append(line)
    m = ImageMeasurements(np.array(pts, dtype=str), np.array(imgs, dtype=str), np.array(px).reshape(-1, 2))
    return m, np.array(lines, dtype=np.int64)


def read_ign_ground_points(path: PathLike, frame: WorldFrame) -> GroundPoints:
    """Read ground points: ``.app`` (``"name" type X Y Z``) or ``_world.mes`` (``name X Y Z``)."""
    rows = _lines(path)
    if not rows:
        raise InputFormatError("no point in the file (expected lines 'name [type] X Y Z')", path)
    width = len(rows[0][1])  # every line has the layout of the first: 5 fields (.app) or 4 (_world.mes)
    if width not in (4, 5):
        raise InputFormatError(f"expected 'name [type] X Y Z', found {width} fields", path, rows[0][0])
    layout = "name type X Y Z" if width == 5 else "name X Y Z"
    names, kinds, xyz = [], [], []
    seen: dict[str, int] = {}
    for line, f in rows:
        if len(f) != width:
            raise InputFormatError(f"expected {width} fields ({layout}, as on line {rows[0][0]}), found {len(f)}"
                                   + _truncated(path, line, rows), path, line)
        if width == 5:
            t = _num(path, line, "type", f[1])
            if t != int(t) or abs(t) > 2**31:
                raise InputFormatError(f"point type {f[1]!r} is not a small whole number", path, line, "type")
            kinds.append(int(t))
            f = [f[0]] + f[2:]
        name = _name(f[0])
        if name in seen:
            raise InputFormatError(f"point {name!r} appears twice (first on line {seen[name]})", path, line, "name")
        seen[name] = line
        names.append(name)
        xyz.append([_num(path, line, k, f[1 + j]) for j, k in enumerate("XYZ")])
    kind = np.array(kinds, dtype=np.int64) if width == 5 else None
    from skyrig.io.plausibility import check_coordinates

    check_coordinates(np.array(xyz).reshape(-1, 3), frame, path, [r[0] for r in rows], "ground", ("X", "Y", "Z"))
    return GroundPoints(np.array(names, dtype=str), np.array(xyz).reshape(-1, 3), frame, kind)


def write_ign_opk(path: PathLike, eo: ExteriorOrientations) -> None:
    """Write an IGN ``.OPK`` file (degrees, omega-phi-kappa in the frame's grid axes), atomically."""
    from skyrig.geometry.rotations import opk_from_matrix
    from skyrig.io._text import atomic_write

    o, p, k = opk_from_matrix(eo.rotation, unit="deg", sequence="opk")
    with atomic_write(path) as fh:
        fh.write("NOM\tX\tY\tZ\tO\tP\tK\tCAMERA\n")
        for i in range(len(eo)):
            c = eo.centre[i]
            fh.write(f"{eo.image[i]}     {c[0]:.3f}    {c[1]:.3f}       {c[2]:.3f}     {o[i]:.12f}     {p[i]:.12f}     {k[i]:.12f}     {eo.camera[i]}\n")
