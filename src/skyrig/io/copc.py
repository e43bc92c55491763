"""Cloud-optimised point clouds (COPC 1.0): a LAZ 1.4 file whose points are stored in an octree of independently
compressed nodes, so that web viewers (potree, plas.io, QGIS 3.32+) stream what they show.

Written with copc-lib (RockRobotic, BSD; ``copclib`` on PyPI), read back by any COPC reader (laspy's
``CopcReader`` in the tests).  The octree is skyrig's: the root cube holds every point; each node keeps one point
per cell of a ``grid``^3 grid over its cube (the first of a random order: an even sample at that level's spacing) and
hands the rest to its eight children, down to nodes of at most ``max_node_points`` points, which keep all theirs.
Every point is written exactly once.  Point record format 6 (7 with colour), coordinates scaled by ``scale`` in
the CRS's unit; the CRS as WKT in the file.  Written to a temporary name and renamed: never half-written.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyrig.errors import InputFormatError
from skyrig.io._text import PathLike

__all__ = ["write_copc", "copc_from_las", "copc_available"]


def copc_available() -> bool:
    """Whether copc-lib is installed (an optional dependency)."""
    try:
        import copclib  # noqa: F401
    except ImportError:
        return False
    return True


def _octree(xyz: NDArray[np.float64], centre: NDArray[np.float64], half: float, grid: int, max_node_points: int,
            seed: int) -> list[tuple[tuple[int, int, int, int], NDArray[np.int64]]]:
    """``[((d, x, y, z), point indices)]``: every point in exactly one node (module docstring)."""
    rng = np.random.default_rng(seed)
    todo = rng.permutation(len(xyz))
    lo = centre - half
    out: list[tuple[tuple[int, int, int, int], NDArray[np.int64]]] = []
    d = 0
    while len(todo):
        side = 2.0 * half / 2 ** d
        ijk = np.clip(np.floor((xyz[todo] - lo) / side).astype(np.int64), 0, 2 ** d - 1)
        key = (ijk[:, 0] * 2 ** d + ijk[:, 1]) * 2 ** d + ijk[:, 2]
        order = np.argsort(key, kind="stable")  # stable: the random order stays within a node
        todo, ijk, key = todo[order], ijk[order], key[order]
        starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        counts = np.diff(np.r_[starts, len(key)])
        small = np.repeat((counts <= max_node_points) | (d >= 20), counts)  # depth 20: sub-mm cells, stop
        # big nodes: one point per cell of the node's grid stays, the others go down a level
        cell = np.clip(np.floor((xyz[todo] - lo) / (side / grid)).astype(np.int64), 0, grid * 2 ** d - 1) % grid
        ckey = key * grid ** 3 + (cell[:, 0] * grid + cell[:, 1]) * grid + cell[:, 2]
        first = np.zeros(len(todo), bool)
        first[np.unique(ckey, return_index=True)[1]] = True
        stay = small | first
        for s, n in zip(starts, counts):
            sel = todo[s:s + n][stay[s:s + n]]
            if len(sel):
                i, j, k = ijk[s]
                out.append(((d, int(i), int(j), int(k)), sel))
        todo = todo[~stay]
        d += 1
    return out


def write_copc(path: PathLike, xyz: NDArray[np.float64], classification: NDArray[np.integer] | None = None,
               rgb: NDArray[np.integer] | None = None, wkt: str = "", *, scale: float = 0.001,
               max_node_points: int = 50_000, grid: int = 128, seed: int = 0) -> dict[str, Any]:
    """Write the points ``xyz`` (N, 3; the CRS's unit) with ASPRS ``classification`` (N,) and 16-bit ``rgb`` (N, 3)
    as a COPC file at ``path``; returns ``{"points", "nodes", "depth"}``.

    Raises
    ------
    InputFormatError
        Points that are not finite, a classification / colour of another length, or copc-lib not installed.
    """
    p = os.fspath(path)
    xyz = np.asarray(xyz, np.float64).reshape(-1, 3)
    n = len(xyz)
    if not n or not np.isfinite(xyz).all():
        raise InputFormatError("a COPC file needs at least one point and finite coordinates", p)
    for name, a in (("classification", classification), ("rgb", rgb)):
        if a is not None and len(a) != n:
            raise InputFormatError(f"{name} has {len(a)} rows for {n} points", p, field=name)
    try:
        import copclib as c
    except ImportError:
        raise InputFormatError("COPC output needs copc-lib: pip install copclib", p, field="copc") from None
    import laspy

    pf = 7 if rgb is not None else 6
    mn, mx = xyz.min(axis=0), xyz.max(axis=0)
    centre = (mn + mx) / 2.0
    half = float(max((mx - mn).max() / 2.0, 1.0) * 1.0001)
    offset = np.floor(mn)
    cfg = c.CopcConfigWriter(pf, c.Vector3(scale, scale, scale), c.Vector3(*offset.tolist()), wkt)
    cfg.copc_info.center_x, cfg.copc_info.center_y, cfg.copc_info.center_z = centre.tolist()
    cfg.copc_info.halfsize = half
    cfg.copc_info.spacing = 2.0 * half / grid
    cfg.las_header.min = c.Vector3(*mn.tolist())
    cfg.las_header.max = c.Vector3(*mx.tolist())
    hdr = laspy.LasHeader(point_format=pf, version="1.4")
    hdr.scales, hdr.offsets = np.full(3, scale), offset
    rec = laspy.ScaleAwarePointRecord.zeros(n, header=hdr)
    rec.x, rec.y, rec.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    if classification is not None:
        rec.classification = np.asarray(classification, np.uint8)
    if rgb is not None:
        q = np.asarray(rgb)
        rec.red, rec.green, rec.blue = q[:, 0], q[:, 1], q[:, 2]
    raw = rec.array
    nodes = _octree(xyz, centre, half, grid, max_node_points, seed)
    tmp = str(Path(p).with_name(f".{Path(p).name}.partial"))
    try:
        w = c.FileWriter(tmp, cfg)
        root = c.VoxelKey.RootKey()
        for (d, i, j, k), idx in nodes:
            data = np.ascontiguousarray(raw[np.sort(idx)]).view(np.int8).ravel()
            w.AddNode(c.VoxelKey(d, i, j, k), c.VectorChar(data), root)
        w.Close()
        os.replace(tmp, p)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return {"points": n, "nodes": len(nodes), "depth": max(k[0] for k, _ in nodes)}


def copc_from_las(src: PathLike, dst: PathLike, **kw: Any) -> dict[str, Any]:
    """A COPC copy of the LAS/LAZ ``src`` (coordinates, classification, colour when the point format has it, the
    CRS as WKT); ``kw`` as :func:`write_copc`."""
    import laspy

    las = laspy.read(os.fspath(src))
    crs = las.header.parse_crs()
    has_rgb = "red" in las.point_format.dimension_names
    rgb = np.c_[las.red, las.green, las.blue] if has_rgb else None
    return write_copc(dst, np.c_[las.x, las.y, las.z], np.asarray(las.classification), rgb,
                      crs.to_wkt() if crs is not None else "", scale=float(min(las.header.scales)), **kw)
