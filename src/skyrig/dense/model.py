"""Textured 3D building models: building blocks + façade textures -> triangle meshes in a local ENU frame.

:func:`build_model` turns :class:`~skyrig.dense.buildings.BuildingBlock` prisms (in the frame of the DSM they came
from, usually a map CRS) and their :class:`~skyrig.dense.buildings.FacadeTexture` images into one
:class:`BuildingMesh` per building: walls (one textured quad per façade, gable ends above the eaves), roofs from
:attr:`BuildingBlock.roof` (textured from an orthophoto when one is given, else a flat colour).

Frames
------
Vertex positions are in a **local ENU frame** (``x`` east, ``y`` north, ``z`` up, metres): the tangent plane at the
model origin (:attr:`Model3D.local`, ``WorldFrame.local(lat, lon, h)``, WGS84 ellipsoidal ``h``).  Every vertex
is converted from the source frame by PROJ through ECEF (:meth:`WorldFrame.points_to`), so the conversion is
rigorous (map scale factor, meridian convergence and geoid included).  File writers
(:mod:`skyrig.io.gltf`) turn this into glTF's y-up axes.

Winding and normals
-------------------
Triangles are counter-clockwise seen from outside; the face normal ``(b - a) x (c - a)`` points out of the
building (walls: :attr:`Facade.normal`; roofs: upwards).

Texture coordinates
-------------------
``uv`` follows glTF: ``(0, 0)`` is the top-left corner of the image's first pixel, ``u`` to the right, ``v``
down; pixel ``(row i, column j)`` covers ``[j, j + 1] / W`` x ``[i, i + 1] / H``.  For a façade texture
(:class:`FacadeTexture` convention: row 0 at ``eave_z``, column 0 at the start corner, texel size ``texel_m``) a
wall point at distance ``s`` from the start corner along the wall and height ``z`` gets
``u = s / (W texel_m)``, ``v = (eave_z - z) / (H texel_m)``, so its texel centre ``(j + 0.5, i + 0.5) texel_m``
maps to pixel ``(i, j)``'s centre.  A texture whose façade reaches up to the roof line (a gable end's wall,
:attr:`Facade.outline`) has row 0 at the top of its rectangle (``corners[3, 2]`` for ``eave_z``) and is drawn over
the whole wall polygon: the gable triangle is then part of the textured wall, not a separate flat-coloured piece.
For a roof textured from an orthophoto, ``uv`` is the vertex' position in the cropped orthophoto (its CRS) divided
by the crop's size.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.dense.buildings import BuildingBlock, Facade, FacadeTexture
from skyrig.errors import SkyrigError
from skyrig.geodesy.crs import ecef_to_geodetic
from skyrig.geodesy.frame import WorldFrame

__all__ = ["OrthoRaster", "MeshPart", "BuildingMesh", "Model3D", "build_model", "model_origin", "triangulate_polygon",
           "DEFAULT_ROOF_RGB", "DEFAULT_WALL_RGB", "srgb_to_linear"]

DEFAULT_ROOF_RGB = (0.34, 0.11, 0.07)  # flat roof colour (linear RGB in [0, 1], glTF baseColorFactor) without orthophoto
DEFAULT_WALL_RGB = (0.60, 0.57, 0.50)  # flat wall colour (linear RGB) for a façade without texture
CUT_RGB = (0.80, 0.80, 0.80)  # flat colour (linear RGB) of a clipped building's cut faces (on the DSM's border)


def srgb_to_linear(c: NDArray[np.float64]) -> NDArray[np.float64]:
    """sRGB values in [0, 1] -> linear RGB (IEC 61966-2-1), as glTF colour factors are linear."""
    c = np.asarray(c, float)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


@dataclass(frozen=True)
class OrthoRaster:
    """An RGB orthophoto on a north-up grid (e.g. read from ``ortho.tif``).

    Attributes
    ----------
    rgb
        ``(R, C, 3)`` uint8, row 0 the northernmost.
    x0, y_top
        West and north edges of the grid (its CRS, metres).
    cell_m
        Cell size (square cells).
    frame
        The grid's frame (its CRS; heights are not used).
    valid
        ``(R, C)`` bool, cells with a colour (None: all).
    """

    rgb: NDArray[np.uint8]
    x0: float
    y_top: float
    cell_m: float
    frame: WorldFrame
    valid: NDArray[np.bool_] | None = None


@dataclass(frozen=True)
class MeshPart:
    """One primitive: triangles with one material.

    Attributes
    ----------
    name
        ``"wall 3"``, ``"gable 1"``, ``"roof"`` ...
    kind
        ``"wall"``, ``"gable"``, ``"roof"``, or ``"cut"`` for the faces of a clipped building on the DSM's border
        (:attr:`~skyrig.dense.buildings.BuildingBlock.border_edges`: where the known part of the building ends, not
        a wall; untextured, :data:`CUT_RGB`).
    positions
        ``(N, 3)`` float64 local ENU metres.
    normals
        ``(N, 3)`` unit outward normals (flat shading: one per face, repeated on its vertices).
    indices
        ``(M, 3)`` int vertex indices, counter-clockwise seen from outside.
    uv
        ``(N, 2)`` texture coordinates (module docstring), or None for a flat colour.
    image
        ``(H, W, 3)`` uint8 texture (row 0 at the top), or None.
    color
        ``(3,)`` base colour, linear RGB in [0, 1] (glTF ``baseColorFactor``; ones when textured).
    facade
        ``(building, index)`` of the façade for walls, else None.
    """

    name: str
    kind: str
    positions: NDArray[np.float64]
    normals: NDArray[np.float64]
    indices: NDArray[np.int64]
    uv: NDArray[np.float64] | None = None
    image: NDArray[np.uint8] | None = None
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    facade: tuple[int, int] | None = None

    @property
    def n_triangles(self) -> int:
        return int(len(self.indices))


@dataclass(frozen=True)
class BuildingMesh:
    """The mesh of one building: its parts (walls, gables, roof)."""

    building: int
    parts: tuple[MeshPart, ...]
    source: str = "dsm"

    @property
    def n_triangles(self) -> int:
        return sum(p.n_triangles for p in self.parts)


@dataclass(frozen=True)
class Model3D:
    """A textured model of buildings in a local ENU frame.

    Attributes
    ----------
    meshes
        One per building.
    local
        ``WorldFrame.local(lat, lon, h)``: the frame of every vertex (x east, y north, z up, metres).
    source_frame
        The frame the buildings came in (a map CRS with its height reference).
    origin_source
        ``(3,)`` the local origin in ``source_frame`` coordinates.
    vertical_reference
        The source heights' reference in words (``skyrig.geodesy.statement.crs_statement``).
    metadata
        Free-form (counts, texel size ...), written into files' extras.
    """

    meshes: tuple[BuildingMesh, ...]
    local: WorldFrame
    source_frame: WorldFrame
    origin_source: NDArray[np.float64]
    vertical_reference: str = ""
    metadata: dict = field(default_factory=dict)

    @property
    def n_triangles(self) -> int:
        return sum(m.n_triangles for m in self.meshes)

    def origin_geodetic(self) -> tuple[float, float, float]:
        """``(lat_deg, lon_deg, h_m)`` of the local origin (WGS84, ellipsoidal height)."""
        assert self.local.origin is not None
        return self.local.origin


# ------------------------------------------------------------------------------------------ geometry helpers
def triangulate_polygon(xy: NDArray[np.float64]) -> NDArray[np.int64]:
    """Triangles ``(K - 2, 3)`` of a simple polygon ``(K, 2)`` (counter-clockwise or not), as vertex indices,
    each counter-clockwise in ``xy`` (ear clipping; convex and concave polygons, no holes).

    Raises
    ------
    SkyrigError
        If the polygon has fewer than 3 vertices or no ear can be cut (self-intersecting).

    >>> triangulate_polygon(np.array([[0., 0.], [1., 0.], [1., 1.], [0., 1.]])).tolist()
    [[3, 0, 1], [1, 2, 3]]
    """
    p = np.asarray(xy, dtype=np.float64)
    k = len(p)
    if k < 3:
        raise SkyrigError(f"a polygon needs at least 3 vertices, got {k}")
    area2 = float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))
    if abs(area2) < 1e-12:
        raise SkyrigError("degenerate polygon (zero area)")
    idx = list(range(k)) if area2 > 0 else list(range(k))[::-1]
    tris: list[list[int]] = []

    def cross(a: int, b: int, c: int) -> float:
        return float((p[b, 0] - p[a, 0]) * (p[c, 1] - p[a, 1]) - (p[b, 1] - p[a, 1]) * (p[c, 0] - p[a, 0]))

    guard = 0
    while len(idx) > 3:
        n = len(idx)
        cut = False
        for m in range(n):
            a, b, c = idx[(m - 1) % n], idx[m], idx[(m + 1) % n]
            if cross(a, b, c) <= 1e-12 * abs(area2):
                continue  # reflex or collinear vertex
            inside = False
            for q in idx:
                if q in (a, b, c):
                    continue
                if cross(a, b, q) >= 0 and cross(b, c, q) >= 0 and cross(c, a, q) >= 0:
                    inside = True
                    break
            if not inside:
                tris.append([a, b, c])
                del idx[m]
                cut = True
                break
        if not cut:  # only collinear vertices left on some side: drop one that adds no area
            for m in range(n):
                a, b, c = idx[(m - 1) % n], idx[m], idx[(m + 1) % n]
                if abs(cross(a, b, c)) <= 1e-12 * abs(area2):
                    del idx[m]
                    cut = True
                    break
        guard += 1
        if not cut or guard > 4 * k:
            raise SkyrigError("cannot triangulate the polygon (self-intersecting?)")
    tris.append(idx)
    return np.array(tris, dtype=np.int64)


def model_origin(buildings: Sequence[BuildingBlock], frame: WorldFrame) -> WorldFrame:
    """The local ENU frame of a model: at the centre of the buildings' bounding box, at their lowest ground
    height (converted to WGS84 latitude, longitude and ellipsoidal height)."""
    if not buildings:
        raise SkyrigError("no buildings to build a model of")
    xy = np.vstack([np.asarray(b.footprint, float)[:, :2] for b in buildings])
    z = min(float(b.ground_z) for b in buildings)
    c = np.array([[0.5 * (xy[:, 0].min() + xy[:, 0].max()), 0.5 * (xy[:, 1].min() + xy[:, 1].max()), z]])
    lat, lon, h = ecef_to_geodetic(frame.to_ecef(c))
    return WorldFrame.local(float(np.ravel(lat)[0]), float(np.ravel(lon)[0]), float(np.ravel(h)[0]))


def _flat_normal(p: NDArray[np.float64], tris: NDArray[np.int64]) -> NDArray[np.float64]:
    """Area-weighted mean face normal of triangles (unit)."""
    a, b, c = p[tris[:, 0]], p[tris[:, 1]], p[tris[:, 2]]
    n = np.cross(b - a, c - a).sum(axis=0)
    return n / np.linalg.norm(n)


def _fill_invalid(tex: FacadeTexture) -> NDArray[np.uint8]:
    """The texture with texels no image saw set to the mean colour of the seen ones (grey if none)."""
    rgb = np.array(tex.rgb, dtype=np.uint8, copy=True)
    valid = np.asarray(tex.valid, bool)
    if valid.shape != rgb.shape[:2]:
        raise SkyrigError(f"façade {tex.facade.building}/{tex.facade.index}: valid mask {valid.shape} does not "
                          f"match the texture {rgb.shape[:2]}")
    if not valid.all():
        fill = rgb[valid].mean(axis=0) if valid.any() else np.array([160.0, 160.0, 160.0])
        rgb[~valid] = np.round(fill).astype(np.uint8)
    return rgb


# ------------------------------------------------------------------------------------------ parts
_ToLocal = Callable[[NDArray[np.float64]], NDArray[np.float64]]


def _wall_part(f: Facade, tex: FacadeTexture | None, to_local: _ToLocal, eave_z: float) -> MeshPart:
    c = np.asarray(f.corners, dtype=np.float64)
    pos = to_local(c)
    tris = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    if f.on_border:
        # a clipped building's edge on the DSM's border is where the known part ends, not a wall: a cut face,
        # untextured, in its own colour (kind "cut")
        if tex is not None:
            raise SkyrigError(f"façade texture {f.building}/{f.index}: that edge lies on the DSM's border (a cut, "
                              "not a wall)")
        nrm = _flat_normal(pos, tris)
        return MeshPart(f"cut {f.index}", "cut", pos, np.tile(nrm, (4, 1)), tris, None, None, CUT_RGB,
                        (f.building, f.index))
    if tex is None:
        nrm = _flat_normal(pos, tris)
        return MeshPart(f"wall {f.index}", "wall", pos, np.tile(nrm, (4, 1)), tris, None, None, DEFAULT_WALL_RGB,
                        (f.building, f.index))
    h, w = tex.rgb.shape[:2]
    if tex.texel_m <= 0 or h == 0 or w == 0:
        raise SkyrigError(f"façade {f.building}/{f.index}: empty texture or texel size {tex.texel_m}")
    d = (c[1] - c[0])[:2]
    length = float(np.linalg.norm(d))
    t = d / length
    top = eave_z
    ol = tex.facade.outline
    if ol is not None:
        # the wall up to the roof line (a gable end): the outline polygon, row 0 of the texture at its apex
        ol = np.asarray(ol, float)
        top = float(tex.facade.corners[3, 2])
        ring = np.column_stack([c[0, 0] + ol[:, 0] * t[0], c[0, 1] + ol[:, 0] * t[1], ol[:, 1]])
        tris = triangulate_polygon(ol)  # counter-clockwise in (s, z) = seen from outside
        pos = to_local(ring)
        s, z = ol[:, 0], ol[:, 1]
    else:
        s = (c[:, :2] - c[0, :2]) @ t  # along-wall distance of each corner (0, L, L, 0)
        z = c[:, 2]
    uv = np.column_stack([s / (w * tex.texel_m), (top - z) / (h * tex.texel_m)])
    nrm = _flat_normal(pos, tris)
    return MeshPart(f"wall {f.index}", "wall", pos, np.tile(nrm, (len(pos), 1)), tris, uv, _fill_invalid(tex),
                    (1.0, 1.0, 1.0), (f.building, f.index))


def _gable_parts(b: BuildingBlock, to_local: _ToLocal, colours: dict[int, tuple[float, float, float]],
                 skip: frozenset[int] = frozenset()) -> list[MeshPart]:
    """Wall pieces above the eaves (gable ends): for each footprint edge (but those in ``skip``: walls already
    drawn up to the roof line), the roof vertices above ``eave_z`` that lie in the edge's vertical plane close the
    wall up to the roof."""
    if not b.roof:
        return []
    roof_pts = np.vstack([np.asarray(r, float) for r in b.roof])
    high = roof_pts[roof_pts[:, 2] > b.eave_z + 1e-3]
    if not len(high):
        return []
    out = []
    fp = np.asarray(b.footprint, float)
    for i in range(len(fp)):
        if i in skip:
            continue
        a, e = fp[i], fp[(i + 1) % len(fp)]
        d = e - a
        length = float(np.linalg.norm(d))
        t = d / length
        nrm = np.array([t[1], -t[0]])
        off = (high[:, :2] - a) @ nrm
        s = (high[:, :2] - a) @ t
        on = (np.abs(off) < 0.02 + 1e-3 * length) & (s > -1e-3) & (s < length + 1e-3)
        if not on.any():
            continue
        top = high[on]
        top_s = s[on]
        order = np.argsort(-top_s)  # from the end back to the start: counter-clockwise seen from outside
        # unique by along-wall position
        keep, seen = [], []
        for k in order:
            if all(abs(top_s[k] - q) > 1e-3 for q in seen):
                keep.append(k)
                seen.append(top_s[k])
        ring = np.vstack([[a[0], a[1], b.eave_z], [e[0], e[1], b.eave_z], top[keep]])
        ring_sz = np.column_stack([np.r_[0.0, length, top_s[keep]], ring[:, 2]])
        tris = triangulate_polygon(ring_sz)  # counter-clockwise in (s, z) = seen from outside
        pos = to_local(ring)
        nrm3 = _flat_normal(pos, tris)
        cut = i in b.border_edges
        out.append(MeshPart(f"cut gable {i}" if cut else f"gable {i}", "cut" if cut else "gable", pos,
                            np.tile(nrm3, (len(pos), 1)), tris, None, None,
                            CUT_RGB if cut else colours.get(i, DEFAULT_WALL_RGB), (b.id, i)))
    return out


def _roof_part(b: BuildingBlock, to_local: _ToLocal, ortho: OrthoRaster | None, roof_rgb: tuple[float, float, float],
               source_frame: WorldFrame) -> MeshPart:
    polys = [np.asarray(r, float) for r in b.roof] if b.roof else [
        np.column_stack([np.asarray(b.footprint, float), np.full(len(b.footprint), b.eave_z)])]
    pts, tris = [], []
    n0 = 0
    for poly in polys:
        if poly.ndim != 2 or poly.shape[1] != 3 or len(poly) < 3:
            raise SkyrigError(f"building {b.id}: a roof polygon must be (K >= 3, 3), got {poly.shape}")
        t = triangulate_polygon(poly[:, :2])  # counter-clockwise from above: normals up (outward)
        pts.append(poly)
        tris.append(t + n0)
        n0 += len(poly)
    p_src = np.vstack(pts)
    pos = to_local(p_src)
    idx = np.vstack(tris)
    # per-polygon flat normals
    nrm = np.empty_like(pos)
    n0 = 0
    for poly, t in zip(pts, tris):
        nrm[n0:n0 + len(poly)] = _flat_normal(pos, t)
        n0 += len(poly)
    if ortho is None:
        return MeshPart("roof", "roof", pos, nrm, idx, None, None, roof_rgb, None)
    q = p_src if ortho.frame == source_frame else source_frame.points_to(p_src, ortho.frame)
    col = (q[:, 0] - ortho.x0) / ortho.cell_m
    row = (ortho.y_top - q[:, 1]) / ortho.cell_m
    rows, cols = ortho.rgb.shape[:2]
    c0, c1 = int(np.floor(col.min())) - 1, int(np.ceil(col.max())) + 1
    r0, r1 = int(np.floor(row.min())) - 1, int(np.ceil(row.max())) + 1
    if c1 <= 0 or r1 <= 0 or c0 >= cols or r0 >= rows:
        return MeshPart("roof", "roof", pos, nrm, idx, None, None, roof_rgb, None)
    c0c, c1c, r0c, r1c = max(c0, 0), min(c1, cols), max(r0, 0), min(r1, rows)
    img = np.zeros((r1 - r0, c1 - c0, 3), np.uint8)
    fill = np.round(np.clip(np.where(np.asarray(roof_rgb) <= 0.0031308, 12.92 * np.asarray(roof_rgb),
                                     1.055 * np.asarray(roof_rgb) ** (1 / 2.4) - 0.055), 0, 1) * 255).astype(np.uint8)
    img[:] = fill
    img[r0c - r0:r1c - r0, c0c - c0:c1c - c0] = ortho.rgb[r0c:r1c, c0c:c1c]
    if ortho.valid is not None:
        bad = np.ones(img.shape[:2], bool)
        bad[r0c - r0:r1c - r0, c0c - c0:c1c - c0] = ~np.asarray(ortho.valid[r0c:r1c, c0c:c1c], bool)
        img[bad] = fill
    uv = np.column_stack([(col - c0) / (c1 - c0), (row - r0) / (r1 - r0)])
    return MeshPart("roof", "roof", pos, nrm, idx, uv, img, (1.0, 1.0, 1.0), None)


def build_model(buildings: Sequence[BuildingBlock], textures: Sequence[FacadeTexture], frame: WorldFrame, *,
                roof_rgb_source: OrthoRaster | tuple[float, float, float] | None = None,
                local: WorldFrame | None = None, vertical_reference: str = "") -> Model3D:
    """Triangle meshes of buildings with their façade textures, in a local ENU frame.

    Parameters
    ----------
    buildings
        Building blocks in ``frame`` (metres).
    textures
        Façade textures (any subset of the façades; a façade without one gets a flat colour).  Matched by
        ``(facade.building, facade.index)``.
    frame
        The buildings' frame (a map CRS with its heights, or a local frame).
    roof_rgb_source
        An :class:`OrthoRaster` to texture the roofs from (true orthophoto, any CRS: vertices are converted),
        or a flat roof colour ``(r, g, b)``, linear RGB in [0, 1] (default :data:`DEFAULT_ROOF_RGB`).
    local
        The local ENU frame of the vertices (default :func:`model_origin`).
    vertical_reference
        The source heights' reference in words (default from ``frame``).

    Returns
    -------
    Model3D

    Raises
    ------
    SkyrigError
        No buildings, a texture for a façade that is not among the buildings', degenerate polygons.
    """
    from skyrig.geodesy.statement import crs_statement

    if not buildings:
        raise SkyrigError("no buildings to build a model of")
    loc = local if local is not None else model_origin(buildings, frame)
    if loc.kind != "local":
        raise SkyrigError(f"the model frame must be a local ENU frame, not {loc.kind}")
    ortho = roof_rgb_source if isinstance(roof_rgb_source, OrthoRaster) else None
    roof_rgb = DEFAULT_ROOF_RGB if roof_rgb_source is None or ortho is not None else tuple(map(float, roof_rgb_source))
    if len(roof_rgb) != 3:
        raise SkyrigError(f"roof colour must be (r, g, b), got {roof_rgb_source!r}")
    by_facade: dict[tuple[int, int], FacadeTexture] = {}
    ids = {b.id for b in buildings}
    for t in textures:
        key = (int(t.facade.building), int(t.facade.index))
        if key[0] not in ids:
            raise SkyrigError(f"a façade texture names building {key[0]}, which is not among the buildings")
        by_facade[key] = t

    def to_local(p: NDArray[np.float64]) -> NDArray[np.float64]:
        return frame.points_to(np.asarray(p, float), loc)

    meshes = []
    for b in buildings:
        parts: list[MeshPart] = []
        wall_colour: dict[int, tuple[float, float, float]] = {}
        to_roof: set[int] = set()
        roof_walls = {g.index: g for g in b.facades(to_roof=True) if g.outline is not None}
        for f in b.facades():
            tex = by_facade.get((b.id, f.index))
            if tex is not None:
                # a texture of the wall to the eaves, or of the wall up to the roof line (a gable end's: its
                # rectangle's top at or above the apex, its outline the wall's)
                tc = np.asarray(tex.facade.corners, float)
                if tex.facade.outline is None:
                    same = tc.shape == (4, 3) and np.allclose(tc, f.corners, rtol=0.0, atol=1e-6)
                else:
                    ref = roof_walls.get(f.index)
                    same = (ref is not None and tc.shape == (4, 3) and np.allclose(tc[:2], f.corners[:2], rtol=0.0, atol=1e-6)
                            and np.allclose(tc[2:, :2], f.corners[2:, :2], rtol=0.0, atol=1e-6)
                            and tc[3, 2] >= ref.corners[3, 2] - 1e-6
                            and np.shape(tex.facade.outline) == np.shape(ref.outline)
                            and np.allclose(tex.facade.outline, ref.outline, rtol=0.0, atol=1e-6))
                    to_roof.add(f.index)
                if not same:
                    raise SkyrigError(f"façade texture {b.id}/{f.index} was made for another wall (corners differ)")
            part = _wall_part(f, tex, to_local, b.eave_z)
            parts.append(part)
            wall_colour[f.index] = (tuple(float(v) for v in srgb_to_linear(part.image.reshape(-1, 3).mean(axis=0) / 255.0))
                                    if part.image is not None else DEFAULT_WALL_RGB)
        parts.extend(_gable_parts(b, to_local, wall_colour, frozenset(to_roof)))
        parts.append(_roof_part(b, to_local, ortho, roof_rgb, frame))
        meshes.append(BuildingMesh(int(b.id), tuple(parts), b.source))
    origin_src = loc.points_to(np.zeros((1, 3)), frame)[0]
    vref = vertical_reference or crs_statement(frame)[1]
    meta = {"buildings": len(meshes), "facades_textured": sum(1 for m in meshes for p in m.parts
                                                               if p.kind == "wall" and p.image is not None),
            "roofs": "orthophoto" if ortho is not None else "flat colour"}
    return Model3D(tuple(meshes), loc, frame, origin_src, vref, meta)
