"""Textured 3D models as binary glTF 2.0 (GLB) and as OBJ + MTL + PNG, with their geographic origin recorded.

Written by hand from the glTF 2.0 specification (Khronos): a 12-byte header, a JSON chunk (padded with spaces) and
a BIN chunk (padded with zeros), every chunk and buffer view 4-byte aligned.

Axes
----
glTF is **y-up**: a model's vertex ``(x, y, z)`` in the file is ``(east, up, -north)`` metres of the local ENU
frame :attr:`skyrig.dense.model.Model3D.local` (x east, y up, z south), which keeps right-handed triangles
counter-clockwise.  The frame's geographic origin (WGS84 latitude, longitude, ellipsoidal height), the source
CRS (WKT2 of the horizontal + vertical CRS), its vertical reference in words and the origin in source-CRS
coordinates are in ``asset.extras.skyrig`` and in the scene's ``extras``, and in a side-car JSON
(``<file>.json``, e.g. ``model.glb.json``).  To put a vertex back into the map CRS: ENU
``(x, -z, y)`` -> ECEF with the origin's ENU rotation -> the CRS (:func:`model_points_to_frame`).

Structure: one node and one mesh per building (name ``building <id>``), one primitive per wall / gable / roof with
its own material; façade and roof textures are embedded PNG (or JPEG) images.  The OBJ export uses the same y-up
axes (stated in the file's header comments), ``vt`` with ``v`` flipped (OBJ's origin is the bottom-left).
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from skyrig.errors import InputFormatError, SkyrigError
from skyrig.geodesy.frame import WorldFrame
from skyrig.io._text import PathLike, atomic_write, output_temp, publish

if TYPE_CHECKING:
    from skyrig.dense.model import Model3D

__all__ = ["write_glb", "read_glb", "glb_problems", "accessor_array", "write_obj", "model_points_to_frame",
           "enu_from_gltf", "gltf_from_enu", "model_sidecar", "GLB_MAGIC"]

GLB_MAGIC = 0x46546C67  # "glTF"
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942
_FLOAT, _UINT32, _UINT16 = 5126, 5125, 5123
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_CTYPE = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
AXES_TEXT = "glTF y-up: x = east, y = up, z = south (-north), metres of the local ENU frame at the origin"

# glTF axes from ENU: (e, n, u) -> (e, u, -n); a proper rotation (det +1), so windings are kept
_GLTF_FROM_ENU = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def gltf_from_enu(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """ENU ``(N, 3)`` -> glTF y-up axes."""
    return np.asarray(p, float) @ _GLTF_FROM_ENU.T


def enu_from_gltf(p: NDArray[np.float64]) -> NDArray[np.float64]:
    """glTF y-up axes ``(N, 3)`` -> ENU."""
    return np.asarray(p, float) @ _GLTF_FROM_ENU


def _encode_image(img: NDArray[np.uint8], fmt: str, jpeg_quality: int, max_px: int | None = None) -> tuple[bytes, str]:
    import cv2

    bgr = cv2.cvtColor(np.ascontiguousarray(img, dtype=np.uint8), cv2.COLOR_RGB2BGR)
    h, w = bgr.shape[:2]
    if max_px is not None and max(h, w) > max_px:  # UVs are relative: a smaller image covers the same surface
        f = max_px / max(h, w)
        bgr = cv2.resize(bgr, (max(1, round(w * f)), max(1, round(h * f))), interpolation=cv2.INTER_AREA)
    if fmt == "png":
        ok, buf = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, 6])
        mime = "image/png"
    elif fmt == "jpeg":
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        mime = "image/jpeg"
    else:
        raise SkyrigError(f"image format must be 'png' or 'jpeg', not {fmt!r}")
    if not ok:
        raise SkyrigError(f"cannot encode a {img.shape} texture as {fmt}")
    return buf.tobytes(), mime


def model_sidecar(model: Model3D) -> dict[str, Any]:
    """The geographic statement of a :class:`~skyrig.dense.model.Model3D` (side-car JSON and glTF extras)."""
    from skyrig.geodesy.statement import crs_statement

    lat, lon, h = model.origin_geodetic()
    wkt = None
    words = model.vertical_reference
    if model.source_frame.kind == "map":
        wkt, w = crs_statement(model.source_frame)
        words = words or w
    return {
        "format": "skyrig-3d-model", "version": 1,
        "axes": AXES_TEXT,
        "origin": {"lat_deg": lat, "lon_deg": lon, "h_m": h, "height": "WGS84 ellipsoidal height"},
        "local_frame": model.local.to_text(),
        "source_frame": model.source_frame.to_text(),
        "source_crs_wkt": wkt,
        "vertical_reference": words,
        "origin_in_source_frame": [float(v) for v in model.origin_source],
        "buildings": len(model.meshes),
        "triangles": model.n_triangles,
        "metadata": model.metadata,
    }


def _build_glb(model: Model3D, image_format: str, jpeg_quality: int, max_texture_px: int | None) -> bytes:
    from skyrig import __version__

    chunks: list[bytes] = []
    offset = 0
    views: list[dict] = []
    accessors: list[dict] = []

    def add_view(data: bytes, target: int | None) -> int:
        nonlocal offset
        pad = (-offset) % 4
        if pad:
            chunks.append(b"\0" * pad)
            offset += pad
        v: dict[str, Any] = {"buffer": 0, "byteOffset": offset, "byteLength": len(data)}
        if target is not None:
            v["target"] = target
        views.append(v)
        chunks.append(data)
        offset += len(data)
        return len(views) - 1

    def add_accessor(arr: NDArray, ctype: int, typ: str, target: int, minmax: bool) -> int:
        a = np.ascontiguousarray(arr, dtype=_CTYPE[ctype])
        acc: dict[str, Any] = {"bufferView": add_view(a.tobytes(), target), "byteOffset": 0, "componentType": ctype,
                               "count": int(a.shape[0]), "type": typ}
        if minmax:
            acc["min"] = [float(x) if ctype == _FLOAT else int(x) for x in a.reshape(len(a), -1).min(axis=0)]
            acc["max"] = [float(x) if ctype == _FLOAT else int(x) for x in a.reshape(len(a), -1).max(axis=0)]
        accessors.append(acc)
        return len(accessors) - 1

    images: list[dict] = []
    textures: list[dict] = []
    materials: list[dict] = []
    meshes: list[dict] = []
    nodes: list[dict] = []
    for bm in model.meshes:
        prims = []
        for part in bm.parts:
            pos = gltf_from_enu(part.positions).astype(np.float32)
            nrm = gltf_from_enu(part.normals).astype(np.float32)
            attrs = {"POSITION": add_accessor(pos, _FLOAT, "VEC3", _ARRAY_BUFFER, True),
                     "NORMAL": add_accessor(nrm, _FLOAT, "VEC3", _ARRAY_BUFFER, False)}
            mat: dict[str, Any] = {"name": f"b{bm.building} {part.name}",
                                   "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 1.0}}
            if part.image is not None and part.uv is not None:
                attrs["TEXCOORD_0"] = add_accessor(part.uv.astype(np.float32), _FLOAT, "VEC2", _ARRAY_BUFFER, False)
                data, mime = _encode_image(part.image, image_format, jpeg_quality, max_texture_px)
                images.append({"bufferView": add_view(data, None), "mimeType": mime,
                               "name": f"b{bm.building} {part.name}"})
                textures.append({"sampler": 0, "source": len(images) - 1})
                mat["pbrMetallicRoughness"]["baseColorTexture"] = {"index": len(textures) - 1, "texCoord": 0}
            else:
                mat["pbrMetallicRoughness"]["baseColorFactor"] = [float(c) for c in part.color] + [1.0]
            materials.append(mat)
            n = len(pos)
            ind = np.asarray(part.indices).reshape(-1)
            if ind.size and (ind.min() < 0 or ind.max() >= n):
                raise SkyrigError(f"building {bm.building} {part.name}: vertex index out of range")
            ctype = _UINT16 if n < 65535 else _UINT32
            prims.append({"attributes": attrs, "indices": add_accessor(ind, ctype, "SCALAR", _ELEMENT_ARRAY_BUFFER, True),
                          "material": len(materials) - 1, "mode": 4, "extras": {"kind": part.kind, "name": part.name}})
        meshes.append({"name": f"building {bm.building}", "primitives": prims})
        nodes.append({"name": f"building {bm.building}", "mesh": len(meshes) - 1,
                      "extras": {"building": bm.building, "source": bm.source}})
    pad = (-offset) % 4
    if pad:
        chunks.append(b"\0" * pad)
        offset += pad
    side = model_sidecar(model)
    gltf: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": f"skyrig {__version__}", "extras": {"skyrig": side}},
        "scene": 0,
        "scenes": [{"name": "buildings", "nodes": list(range(len(nodes))), "extras": side}],
        "nodes": nodes, "meshes": meshes, "materials": materials, "accessors": accessors, "bufferViews": views,
        "buffers": [{"byteLength": offset}],
    }
    if images:
        gltf["images"] = images
        gltf["textures"] = textures
        gltf["samplers"] = [{"magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071}]
    js = json.dumps(gltf, separators=(",", ":")).encode("utf-8")
    js += b" " * ((-len(js)) % 4)
    binary = b"".join(chunks)
    total = 12 + 8 + len(js) + 8 + len(binary)
    return b"".join([struct.pack("<III", GLB_MAGIC, 2, total), struct.pack("<II", len(js), _CHUNK_JSON), js,
                     struct.pack("<II", len(binary), _CHUNK_BIN), binary])


def write_glb(path: PathLike, model: Model3D, *, image_format: str = "png", jpeg_quality: int = 90,
              max_texture_px: int | None = 4096, sidecar: bool = True) -> dict[str, Any]:
    """Write a :class:`~skyrig.dense.model.Model3D` as a GLB file (temporary file, then renamed) and its side-car
    JSON ``<path>.json`` (the origin statement, :func:`model_sidecar`).

    Parameters
    ----------
    path
        Output ``.glb`` file.
    model
        The model (vertices in its local ENU frame).
    image_format
        ``"png"`` (lossless) or ``"jpeg"`` for the embedded textures.
    jpeg_quality
        JPEG quality 1-100.
    max_texture_px
        Textures larger than this on a side are reduced to it (area average) inside the GLB: WebGL
        implementations guarantee 4096 px only (None: keep every texture whole).
    sidecar
        Also write ``<path>.json``.

    Returns
    -------
    dict
        The side-car content (also recorded in the GLB's ``asset.extras.skyrig`` and scene ``extras``).
    """
    data = _build_glb(model, image_format, jpeg_quality, max_texture_px)
    p = Path(path)
    fd, tmp = output_temp(p, ".glb")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        publish(tmp, p)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    side = model_sidecar(model)
    if sidecar:
        with atomic_write(p.with_name(p.name + ".json")) as fh:
            fh.write(json.dumps(side, indent=1) + "\n")
    return side


# ------------------------------------------------------------------------------------------ reading / checking
def read_glb(path: PathLike) -> tuple[dict[str, Any], bytes]:
    """Read a GLB file: ``(gltf JSON as a dict, BIN chunk bytes)``.

    Raises
    ------
    InputFormatError
        Not a GLB 2.0 file, truncated, or chunks in the wrong order.
    """
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise InputFormatError(f"cannot read ({exc.strerror or exc})", p) from None
    if len(raw) < 20:
        raise InputFormatError(f"too short for a GLB file ({len(raw)} bytes)", p)
    magic, version, length = struct.unpack_from("<III", raw, 0)
    if magic != GLB_MAGIC:
        raise InputFormatError("not a binary glTF file (magic is not 'glTF')", p, field="magic")
    if version != 2:
        raise InputFormatError(f"glTF container version {version}, expected 2", p, field="version")
    if length != len(raw):
        raise InputFormatError(f"header length {length} but the file has {len(raw)} bytes (truncated?)", p, field="length")
    clen, ctype = struct.unpack_from("<II", raw, 12)
    if ctype != _CHUNK_JSON or 20 + clen > len(raw):
        raise InputFormatError("first chunk is not a complete JSON chunk", p, field="chunk 0")
    try:
        gltf = json.loads(raw[20:20 + clen].decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise InputFormatError(f"JSON chunk does not parse: {exc}", p, field="chunk 0") from None
    pos = 20 + clen
    binary = b""
    if pos < len(raw):
        if pos + 8 > len(raw):
            raise InputFormatError("truncated BIN chunk header", p, field="chunk 1")
        blen, btype = struct.unpack_from("<II", raw, pos)
        if btype != _CHUNK_BIN or pos + 8 + blen > len(raw):
            raise InputFormatError("second chunk is not a complete BIN chunk", p, field="chunk 1")
        binary = raw[pos + 8:pos + 8 + blen]
    return gltf, binary


def accessor_array(gltf: dict[str, Any], binary: bytes, index: int) -> NDArray:
    """The data of accessor ``index`` as a numpy array ``(count, components)`` (``(count,)`` for scalars)."""
    acc = gltf["accessors"][index]
    view = gltf["bufferViews"][acc["bufferView"]]
    dt = np.dtype(_CTYPE[acc["componentType"]])
    nc = _COMPONENTS[acc["type"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    stride = view.get("byteStride", 0)
    if stride and stride != nc * dt.itemsize:
        raw = np.frombuffer(binary, np.uint8, count=stride * (acc["count"] - 1) + nc * dt.itemsize, offset=start)
        rows = np.lib.stride_tricks.as_strided(raw, (acc["count"], nc * dt.itemsize), (stride, 1))
        a = np.ascontiguousarray(rows).view(dt).reshape(acc["count"], nc)
    else:
        a = np.frombuffer(binary, dt, count=acc["count"] * nc, offset=start).reshape(acc["count"], nc)
    return a[:, 0] if nc == 1 else a


def glb_problems(path: PathLike) -> list[str]:
    """What is wrong with a GLB file against the glTF 2.0 rules skyrig relies on (empty: nothing found).

    Checks: container header and chunk lengths and 4-byte alignment, buffer length, buffer views inside the
    buffer and 4-byte aligned, accessors inside their views and aligned to their component size, ``POSITION``
    min/max equal to the data, indices inside the vertex range, equal attribute counts per primitive, texture
    coordinates and normals finite, images whose bytes start with their MIME type's signature.
    """
    p = Path(path)
    out: list[str] = []
    try:
        gltf, binary = read_glb(p)
    except InputFormatError as exc:
        return [str(exc)]
    raw = p.read_bytes()
    clen = struct.unpack_from("<I", raw, 12)[0]
    if clen % 4:
        out.append(f"JSON chunk length {clen} is not a multiple of 4")
    if len(binary) % 4:
        out.append(f"BIN chunk length {len(binary)} is not a multiple of 4")
    if gltf.get("asset", {}).get("version") != "2.0":
        out.append("asset.version is not '2.0'")
    bufs = gltf.get("buffers", [])
    if len(bufs) != 1 or bufs[0].get("uri") is not None:
        out.append("expected one buffer (the BIN chunk) without uri")
    elif not (len(binary) - 3 <= bufs[0]["byteLength"] <= len(binary)):
        out.append(f"buffer byteLength {bufs[0]['byteLength']} does not match the BIN chunk ({len(binary)} bytes)")
    for i, v in enumerate(gltf.get("bufferViews", [])):
        o, n = v.get("byteOffset", 0), v["byteLength"]
        if o % 4:
            out.append(f"bufferView {i}: byteOffset {o} not 4-byte aligned")
        if o + n > len(binary):
            out.append(f"bufferView {i}: [{o}, {o + n}) beyond the buffer ({len(binary)} bytes)")
    for i, a in enumerate(gltf.get("accessors", [])):
        v = gltf["bufferViews"][a["bufferView"]]
        size = np.dtype(_CTYPE[a["componentType"]]).itemsize
        nc = _COMPONENTS[a["type"]]
        o = v.get("byteOffset", 0) + a.get("byteOffset", 0)
        if o % size:
            out.append(f"accessor {i}: offset {o} not aligned to its component size {size}")
        if a.get("byteOffset", 0) + a["count"] * nc * size > v["byteLength"]:
            out.append(f"accessor {i}: {a['count']} x {nc} x {size} bytes overrun bufferView {a['bufferView']}")
    for mi, m in enumerate(gltf.get("meshes", [])):
        for pi, pr in enumerate(m["primitives"]):
            where = f"mesh {mi} ({m.get('name')}) primitive {pi}"
            at = pr["attributes"]
            counts = {k: gltf["accessors"][ix]["count"] for k, ix in at.items()}
            if len(set(counts.values())) != 1:
                out.append(f"{where}: attribute counts differ {counts}")
            pos = accessor_array(gltf, binary, at["POSITION"])
            acc = gltf["accessors"][at["POSITION"]]
            if "min" not in acc or "max" not in acc:
                out.append(f"{where}: POSITION accessor without min/max")
            elif not (np.allclose(acc["min"], pos.min(axis=0), rtol=0, atol=1e-6 * (1 + np.abs(pos).max()))
                      and np.allclose(acc["max"], pos.max(axis=0), rtol=0, atol=1e-6 * (1 + np.abs(pos).max()))):
                out.append(f"{where}: POSITION min/max {acc['min']} {acc['max']} differ from the data")
            for k in ("NORMAL", "TEXCOORD_0"):
                if k in at and not np.all(np.isfinite(accessor_array(gltf, binary, at[k]))):
                    out.append(f"{where}: {k} not finite")
            if "NORMAL" in at:
                nn = np.linalg.norm(accessor_array(gltf, binary, at["NORMAL"]), axis=1)
                if np.any(np.abs(nn - 1) > 1e-3):
                    out.append(f"{where}: NORMAL not unit length")
            if "indices" in pr:
                ind = accessor_array(gltf, binary, pr["indices"])
                if ind.size % 3:
                    out.append(f"{where}: {ind.size} indices is not a whole number of triangles")
                if ind.size and int(ind.max()) >= len(pos):
                    out.append(f"{where}: index {int(ind.max())} >= vertex count {len(pos)}")
                if gltf["bufferViews"][gltf["accessors"][pr["indices"]]["bufferView"]].get("target") not in (None, _ELEMENT_ARRAY_BUFFER):
                    out.append(f"{where}: indices bufferView target is not ELEMENT_ARRAY_BUFFER")
    sig = {"image/png": b"\x89PNG\r\n\x1a\n", "image/jpeg": b"\xff\xd8\xff"}
    for i, im in enumerate(gltf.get("images", [])):
        v = gltf["bufferViews"][im["bufferView"]]
        head = binary[v.get("byteOffset", 0):v.get("byteOffset", 0) + 8]
        if im.get("mimeType") not in sig or not head.startswith(sig[im["mimeType"]]):
            out.append(f"image {i}: bytes do not match mimeType {im.get('mimeType')}")
    return out


def model_points_to_frame(points_gltf: NDArray[np.float64], gltf: dict[str, Any], frame: WorldFrame) -> NDArray[np.float64]:
    """Vertices ``(N, 3)`` read from a skyrig GLB (y-up axes) in ``frame``, through the origin recorded in
    ``asset.extras.skyrig``."""
    side = gltf.get("asset", {}).get("extras", {}).get("skyrig")
    if not side:
        raise InputFormatError("the glTF has no skyrig origin (asset.extras.skyrig)", field="asset.extras")
    o = side["origin"]
    loc = WorldFrame.local(o["lat_deg"], o["lon_deg"], o["h_m"])
    return loc.points_to(enu_from_gltf(np.asarray(points_gltf, float)), frame)


# ------------------------------------------------------------------------------------------ OBJ
def write_obj(path: PathLike, model: Model3D, *, texture_dir: str | None = None) -> list[Path]:
    """Write a model as Wavefront OBJ + MTL + PNG textures (same y-up local axes as the GLB, stated in the header).

    ``path`` is the ``.obj`` file; the material library is ``<stem>.mtl`` next to it and the textures go to
    ``texture_dir`` (default ``<stem>_textures``) relative to it.  Every file is written to a temporary name and
    renamed; the textures and the MTL first, the OBJ last.  Returns the files written.
    """
    import cv2

    p = Path(path)
    tdir_name = texture_dir or f"{p.stem}_textures"
    tdir = p.parent / tdir_name
    tdir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    side = model_sidecar(model)
    head = [f"# skyrig textured model: {side['buildings']} buildings, {side['triangles']} triangles",
            f"# axes: {AXES_TEXT}",
            "# origin: lat %.10f lon %.10f h %.4f (WGS84, ellipsoidal)" % (side['origin']['lat_deg'],
                                                                         side['origin']['lon_deg'], side['origin']['h_m']),
            f"# source frame: {side['source_frame']}",
            f"# vertical reference: {side['vertical_reference']}",
            "# origin in source frame: %.4f %.4f %.4f" % tuple(side["origin_in_source_frame"])]
    mtl = [f"# materials of {p.name}"]
    obj = head + [f"mtllib {p.stem}.mtl"]
    nv = nt = 0
    for bm in model.meshes:
        obj.append(f"o building_{bm.building}")
        for part in bm.parts:
            mname = f"b{bm.building}_{part.name.replace(' ', '_')}"
            mtl += [f"newmtl {mname}", "Ka 0 0 0", "Ks 0 0 0", "illum 1"]
            if part.image is not None and part.uv is not None:
                fname = f"{mname}.png"
                fd, tmp = output_temp(tdir / fname, ".png")
                os.close(fd)
                try:
                    if not cv2.imwrite(tmp, cv2.cvtColor(part.image, cv2.COLOR_RGB2BGR)):
                        raise SkyrigError(f"cannot write texture {tdir / fname}")
                    publish(tmp, tdir / fname)
                finally:
                    if os.path.exists(tmp):
                        os.unlink(tmp)
                written.append(tdir / fname)
                mtl += ["Kd 1 1 1", f"map_Kd {tdir_name}/{fname}"]
            else:
                mtl.append("Kd %.4f %.4f %.4f" % tuple(part.color))
            pos = gltf_from_enu(part.positions)
            nrm = gltf_from_enu(part.normals)
            obj.append(f"g {mname}")
            obj.append(f"usemtl {mname}")
            obj += ["v %.4f %.4f %.4f" % tuple(v) for v in pos]
            obj += ["vn %.6f %.6f %.6f" % tuple(v) for v in nrm]
            if part.uv is not None and part.image is not None:
                obj += ["vt %.6f %.6f" % (u, 1.0 - v) for u, v in part.uv]
                obj += ["f " + " ".join(f"{nv + k + 1}/{nt + k + 1}/{nv + k + 1}" for k in tri) for tri in part.indices]
                nt += len(part.uv)
            else:
                obj += ["f " + " ".join(f"{nv + k + 1}//{nv + k + 1}" for k in tri) for tri in part.indices]
            nv += len(pos)
    mtl_path = p.with_suffix(".mtl")
    with atomic_write(mtl_path) as fh:
        fh.write("\n".join(mtl) + "\n")
    written.append(mtl_path)
    with atomic_write(p) as fh:
        fh.write("\n".join(obj) + "\n")
    written.append(p)
    return written
