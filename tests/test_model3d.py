"""Textured 3D models (issue 11): GLB / OBJ export of building blocks with façade textures, and the HTML viewer.

Inputs are the simulator's true town (``skyrig.simulate.world``) as building blocks in a map CRS and façade textures
painted from the scene's façade rule; answers are checked against independent ones:

* GLB vertices back in the map CRS through the recorded origin with a chain written here on pyproj alone
  (geodetic -> ECEF of the origin, the ENU rotation from its formula, ECEF -> map) within 1 mm;
* triangle windings against the building's inside (outward normals), stored normals against the cross products;
* texture coordinates: a wall point at a texel centre, carried through the GLB's UVs into its decoded PNG, has the
  colour the scene's façade rule gives at that point; a roof point at an orthophoto cell centre the ortho's colour;
* the viewer page in headless Chromium (skips without Chromium): triangles drawn = triangles in the model, the
  screenshot not blank;
* the glTF validator of the Khronos group (npm ``gltf-validator``; skips without node or the package).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from functools import lru_cache
from pathlib import Path

import numpy as np
import pyproj
import pytest

from skyrig.dense.buildings import BuildingBlock, FacadeTexture
from skyrig.dense.model import OrthoRaster, build_model, triangulate_polygon
from skyrig.errors import InputFormatError, SkyrigError
from skyrig.geodesy.frame import WorldFrame
from skyrig.io.gltf import accessor_array, glb_problems, read_glb, write_glb, write_obj
from skyrig.simulate.judge_model import facade_rule_at, judge_model, true_buildings, true_facade_textures
from skyrig.simulate.world import make_scene, rasterize_orthophoto

CRS = "EPSG:25832"
TEXEL = 0.1


@pytest.fixture(scope="module")
def town():
    scene = make_scene(7, (-120.0, -120.0, 120.0, 120.0), n_buildings=6)
    frame = WorldFrame.map(CRS)
    blocks = true_buildings(scene, frame)
    textures = true_facade_textures(scene, blocks, frame, TEXEL)
    return scene, frame, blocks, textures


@pytest.fixture(scope="module")
def glb(town, tmp_path_factory):
    scene, frame, blocks, textures = town
    model = build_model(blocks, textures, frame)
    path = tmp_path_factory.mktemp("glb") / "model.glb"
    side = write_glb(path, model)
    gltf, binary = read_glb(path)
    return model, path, side, gltf, binary


# ------------------------------------------------------------------ an independent way back to the map CRS
def _enu_rotation(lat_deg: float, lon_deg: float) -> np.ndarray:
    """ecef_from_enu: columns east, north, up at (lat, lon) (textbook formula)."""
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    e = [-np.sin(lo), np.cos(lo), 0.0]
    n = [-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)]
    u = [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)]
    return np.column_stack([e, n, u])


@lru_cache(maxsize=None)
def _transformer(src: str, dst: str) -> pyproj.Transformer:
    crs = {CRS: pyproj.CRS(CRS).to_3d()}
    return pyproj.Transformer.from_crs(crs.get(src, src), crs.get(dst, dst), always_xy=True)


def _gltf_to_map(p: np.ndarray, origin: dict) -> np.ndarray:
    enu = np.column_stack([p[:, 0], -p[:, 2], p[:, 1]])  # y-up (x east, y up, z south) -> ENU
    t = _transformer("EPSG:4979", "EPSG:4978")
    o = np.array(t.transform(origin["lon_deg"], origin["lat_deg"], origin["h_m"]))
    ecef = o + enu @ _enu_rotation(origin["lat_deg"], origin["lon_deg"]).T
    to_map = _transformer("EPSG:4978", CRS)
    return np.column_stack(to_map.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2]))


def _map_to_gltf(p: np.ndarray, origin: dict) -> np.ndarray:
    to_ecef = _transformer(CRS, "EPSG:4978")
    ecef = np.column_stack(to_ecef.transform(p[:, 0], p[:, 1], p[:, 2]))
    t = _transformer("EPSG:4979", "EPSG:4978")
    o = np.array(t.transform(origin["lon_deg"], origin["lat_deg"], origin["h_m"]))
    enu = (ecef - o) @ _enu_rotation(origin["lat_deg"], origin["lon_deg"])
    return np.column_stack([enu[:, 0], enu[:, 2], -enu[:, 1]])


def _primitives(gltf, binary):
    """(building id, primitive name, kind, positions, normals, uv or None, indices (M, 3), material) for all."""
    out = []
    for node in gltf["nodes"]:
        mesh = gltf["meshes"][node["mesh"]]
        for pr in mesh["primitives"]:
            at = pr["attributes"]
            out.append((node["extras"]["building"], pr["extras"]["name"], pr["extras"]["kind"],
                        accessor_array(gltf, binary, at["POSITION"]).astype(float),
                        accessor_array(gltf, binary, at["NORMAL"]).astype(float),
                        accessor_array(gltf, binary, at["TEXCOORD_0"]).astype(float) if "TEXCOORD_0" in at else None,
                        accessor_array(gltf, binary, pr["indices"]).reshape(-1, 3).astype(int),
                        gltf["materials"][pr["material"]]))
    return out


def _texture(gltf, binary, material) -> np.ndarray:
    import cv2

    tex = gltf["textures"][material["pbrMetallicRoughness"]["baseColorTexture"]["index"]]
    view = gltf["bufferViews"][gltf["images"][tex["source"]]["bufferView"]]
    data = np.frombuffer(binary, np.uint8, view["byteLength"], view["byteOffset"])
    return cv2.cvtColor(cv2.imdecode(data, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def _barycentric_uv(p: np.ndarray, pos: np.ndarray, tris: np.ndarray, uv: np.ndarray) -> np.ndarray | None:
    """UV at point p (3,) on the triangle mesh (None if on no triangle)."""
    for t in tris:
        a, b, c = pos[t]
        v0, v1, v2 = b - a, c - a, p - a
        d00, d01, d11 = v0 @ v0, v0 @ v1, v1 @ v1
        d20, d21 = v2 @ v0, v2 @ v1
        den = d00 * d11 - d01 * d01
        w1 = (d11 * d20 - d01 * d21) / den
        w2 = (d00 * d21 - d01 * d20) / den
        w0 = 1 - w1 - w2
        off = np.linalg.norm(w0 * a + w1 * b + w2 * c - p)
        if min(w0, w1, w2) >= -1e-6 and off < 1e-3:
            return w0 * uv[t[0]] + w1 * uv[t[1]] + w2 * uv[t[2]]
    return None


# ------------------------------------------------------------------ structure
def test_glb_structure_and_origin(town, glb):
    scene, frame, blocks, textures = town
    model, path, side, gltf, binary = glb
    assert glb_problems(path) == []
    assert path.stat().st_size % 4 == 0
    assert gltf["asset"]["version"] == "2.0"
    assert len(gltf["nodes"]) == len(blocks) == len(gltf["meshes"])
    assert [n["extras"]["building"] for n in gltf["nodes"]] == [b.id for b in blocks]
    # the origin statement: in the asset extras, the scene extras and the side-car, all equal
    assert gltf["asset"]["extras"]["skyrig"] == gltf["scenes"][0]["extras"] == side
    assert json.loads(Path(str(path) + ".json").read_text()) == side
    assert side["source_frame"] == frame.to_text() and "ellipsoidal" in side["vertical_reference"]
    assert pyproj.CRS.from_wkt(side["source_crs_wkt"]).to_2d() == pyproj.CRS(CRS)
    assert "y = up" in side["axes"]
    # 4 walls x 2 triangles + roof (2 flat / 4 gabled) + 2 gable ends x 1 per gabled house
    gabled = scene.buildings.gabled
    expect = sum(8 + (4 + 2 if g else 2) for g in gabled)
    assert model.n_triangles == expect == side["triangles"]
    textured = [m for m in gltf["materials"] if "baseColorTexture" in m["pbrMetallicRoughness"]]
    assert len(textured) == len(textures) == len(gltf["images"])


def test_glb_round_trip_to_map_crs_within_1mm(town, glb):
    """Every GLB vertex, taken back to the map CRS with pyproj through the recorded origin, is one of the blocks'
    corners (walls: footprint at ground and eaves; roofs: roof polygon vertices) within 1 mm, and every corner
    is found."""
    scene, frame, blocks, textures = town
    model, path, side, gltf, binary = glb
    origin = side["origin"]
    worst = 0.0
    by_id = {b.id: b for b in blocks}
    prims = _primitives(gltf, binary)
    for bid, b in by_id.items():
        fp = np.asarray(b.footprint)
        corners = np.vstack([np.column_stack([fp, np.full(len(fp), b.ground_z)]),
                             np.column_stack([fp, np.full(len(fp), b.eave_z)])] + [np.asarray(r) for r in b.roof])
        got = np.vstack([_gltf_to_map(p[3], origin) for p in prims if p[0] == bid])
        d = np.linalg.norm(got[:, None, :] - corners[None, :, :], axis=2)
        worst = max(worst, float(d.min(axis=1).max()))
        assert d.min(axis=1).max() < 1e-3, f"building {bid}: a vertex {d.min(axis=1).max() * 1000:.2f} mm off"
        assert d.min(axis=0).max() < 1e-3, f"building {bid}: a corner missing from the GLB"
    print(f"GLB round trip: worst vertex {worst * 1000:.3f} mm")
    # the recorded origin in the source frame is the origin itself
    np.testing.assert_allclose(_gltf_to_map(np.zeros((1, 3)), origin)[0], side["origin_in_source_frame"], atol=1e-3)


def test_windings_and_normals_point_outward(town, glb):
    scene, frame, blocks, textures = town
    model, path, side, gltf, binary = glb
    origin = side["origin"]
    for bid, name, kind, pos, nrm, uv, tris, mat in _primitives(gltf, binary):
        b = blocks[bid]
        fp = np.asarray(b.footprint)
        inside = np.r_[fp.mean(axis=0), 0.5 * (b.ground_z + b.eave_z)]
        centre = _map_to_gltf(inside[None], origin)[0]
        a, bb, c = pos[tris[:, 0]], pos[tris[:, 1]], pos[tris[:, 2]]
        fn = np.cross(bb - a, c - a)
        fn /= np.linalg.norm(fn, axis=1, keepdims=True)
        mid = (a + bb + c) / 3
        assert np.all(np.einsum("ij,ij->i", fn, mid - centre) > 0), f"building {bid} {name}: a triangle faces inwards"
        # stored normals equal the faces' normals
        for k in range(3):
            assert np.all(np.einsum("ij,ij->i", fn, nrm[tris[:, k]]) > 0.9999), f"building {bid} {name}: normal"
        if kind == "roof":
            assert np.all(fn[:, 1] > 0.3), "roof normals point up (glTF y)"
        else:
            assert np.all(np.abs(fn[:, 1]) < 1e-3), "wall normals are horizontal"


def test_facade_uv_convention_against_the_facade_rule(town, glb):
    """Wall points at texel centres: UV from the GLB -> pixel of the embedded PNG == the scene's façade colour there."""
    scene, frame, blocks, textures = town
    model, path, side, gltf, binary = glb
    origin = side["origin"]
    prims = {(p[0], p[1]): p for p in _primitives(gltf, binary)}
    rng = np.random.default_rng(5)
    checked = 0
    for tex in textures[::3]:
        f = tex.facade
        h, w = tex.rgb.shape[:2]
        bid, pos, uv, tris, mat = f.building, *[prims[(f.building, f"wall {f.index}")][k] for k in (3, 5, 6, 7)]
        img = _texture(gltf, binary, mat)
        assert img.shape[:2] == (h, w)
        c = np.asarray(f.corners)
        t = (c[1] - c[0])[:2] / f.width_m
        for _ in range(6):
            i, j = int(rng.integers(0, h)), int(rng.integers(0, w))
            s, z = (j + 0.5) * TEXEL, blocks[bid].eave_z - (i + 0.5) * TEXEL
            if s > f.width_m or z < blocks[bid].ground_z:
                continue  # the last texel row/column may hang over the wall
            p = np.array([[c[0, 0] + s * t[0], c[0, 1] + s * t[1], z]])
            q = _map_to_gltf(p, origin)[0]
            uvp = _barycentric_uv(q, pos, tris, uv)
            assert uvp is not None
            assert abs(uvp[0] * w - (j + 0.5)) < 2e-3 and abs(uvp[1] * h - (i + 0.5)) < 2e-3
            rule = facade_rule_at(scene, f, np.array([s]), np.array([z]), frame)[0]
            px = img[int(np.floor(uvp[1] * h)), int(np.floor(uvp[0] * w))]
            assert np.all(np.abs(px.astype(int) - np.round(rule * 255)) <= 1), (px, rule * 255)
            checked += 1
    assert checked > 20


def test_window_edges_in_place(town, glb):
    """Whole texel rows through the windows of the widest façade, read from the GLB's embedded PNG, equal the
    scene's façade rule at the texel centres (every window edge in place), and the rule's windows are there."""
    scene, frame, blocks, textures = town
    model, path, side, gltf, binary = glb
    prims = {(p[0], p[1]): p for p in _primitives(gltf, binary)}
    tex = max(textures, key=lambda x: x.rgb.shape[1])
    f = tex.facade
    img = _texture(gltf, binary, prims[(f.building, f"wall {f.index}")][7]).astype(int)
    h, w = img.shape[:2]
    s = (np.arange(w) + 0.5) * TEXEL
    inside = s <= f.width_m
    rows_with_windows = 0
    for i in range(h):
        z = blocks[f.building].eave_z - (i + 0.5) * TEXEL
        if z < blocks[f.building].ground_z:
            continue
        rule = facade_rule_at(scene, f, s[inside], np.full(inside.sum(), z), frame)
        assert np.abs(img[i, inside] - np.round(rule * 255)).max() <= 1, f"texel row {i} differs from the rule"
        glass = np.abs(rule[:, 2] / np.maximum(rule[:, 0], 1e-9) - 1.25) < 1e-6  # glass is grey x (0.8, 0.9, 1.0)
        rows_with_windows += int(glass.sum() >= 3)
    assert rows_with_windows > 3


def test_roof_texture_from_an_orthophoto(town, tmp_path):
    """Roof points at orthophoto cell centres: UV -> pixel of the roof texture == the orthophoto's cell."""
    scene, frame, blocks, textures = town
    cell = 0.4
    rgb, tr = rasterize_orthophoto(scene, cell)
    loc = WorldFrame.local(*scene.origin)
    ortho = OrthoRaster(rgb, tr[2], tr[5], cell, loc)
    model = build_model(blocks, textures, frame, roof_rgb_source=ortho)
    write_glb(tmp_path / "m.glb", model)
    gltf, binary = read_glb(tmp_path / "m.glb")
    assert glb_problems(tmp_path / "m.glb") == []
    side = gltf["asset"]["extras"]["skyrig"]
    b = scene.buildings
    xs = tr[2] + (np.arange(rgb.shape[1]) + 0.5) * cell
    ys = tr[5] - (np.arange(rgb.shape[0]) + 0.5) * cell
    checked = 0
    for bid, name, kind, pos, nrm, uv, tris, mat in _primitives(gltf, binary):
        if kind != "roof":
            continue
        img = _texture(gltf, binary, mat)
        cols = np.flatnonzero(np.abs(xs - b.cx[bid]) < 3)[::3]
        rows = np.flatnonzero(np.abs(ys - b.cy[bid]) < 3)[::3]
        rr, cc = (a.ravel() for a in np.meshgrid(rows, cols, indexing="ij"))
        z, idx = b.top_height(xs[cc], ys[rr])
        on = idx == bid
        p_map = loc.points_to(np.column_stack([xs[cc[on]], ys[rr[on]], z[on]]), frame)
        for q, r, c in zip(_map_to_gltf(p_map, side["origin"]), rr[on], cc[on]):
            uvp = _barycentric_uv(q, pos, tris, uv)
            assert uvp is not None
            px = img[int(np.floor(uvp[1] * img.shape[0])), int(np.floor(uvp[0] * img.shape[1]))]
            assert np.array_equal(px, rgb[r, c]), (bid, r, c)
            checked += 1
    assert checked > 20


def test_obj_export(town, glb, tmp_path):
    model = glb[0]
    files = write_obj(tmp_path / "model.obj", model)
    text = (tmp_path / "model.obj").read_text().splitlines()
    assert any("y = up" in line for line in text[:8]) and any("origin: lat" in line for line in text[:8])
    v = np.array([[float(x) for x in line.split()[1:]] for line in text if line.startswith("v ")])
    allpos = np.vstack([p.positions for m in model.meshes for p in m.parts])
    np.testing.assert_allclose(v, np.column_stack([allpos[:, 0], allpos[:, 2], -allpos[:, 1]]), atol=1e-4)
    faces = [line for line in text if line.startswith("f ")]
    assert len(faces) == model.n_triangles
    idx = np.array([int(tok.split("/")[0]) for f in faces for tok in f.split()[1:]])
    assert idx.min() == 1 and idx.max() == len(v)
    mtl = (tmp_path / "model.mtl").read_text()
    maps = [line.split(None, 1)[1] for line in mtl.splitlines() if line.startswith("map_Kd")]
    assert len(maps) == len(town[3]) and all((tmp_path / m).is_file() for m in maps)
    assert set(files) >= {tmp_path / "model.obj", tmp_path / "model.mtl"}
    # vt: v flipped (OBJ's origin bottom-left)
    vt = np.array([[float(x) for x in line.split()[1:]] for line in text if line.startswith("vt ")])
    uvs = np.vstack([p.uv for m in model.meshes for p in m.parts if p.uv is not None and p.image is not None])
    np.testing.assert_allclose(vt, np.column_stack([uvs[:, 0], 1 - uvs[:, 1]]), atol=1e-6)


# ------------------------------------------------------------------ polygons, other shapes, bad input
def test_concave_footprint_and_triangulation(tmp_path):
    l_shape = np.array([[0, 0], [20, 0], [20, 8], [8, 8], [8, 18], [0, 18.0]])
    tris = triangulate_polygon(l_shape)
    a, b, c = l_shape[tris[:, 0]], l_shape[tris[:, 1]], l_shape[tris[:, 2]]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    assert np.all(cross > 0) and np.isclose(cross.sum() / 2, 20 * 8 + 8 * 10)
    assert len(triangulate_polygon(l_shape[::-1])) == 4  # clockwise input: same area, ccw triangles
    frame = WorldFrame.map(CRS)
    fp = l_shape + np.array([550000.0, 5800000.0])
    blk = BuildingBlock(0, fp, 60.0, 70.0, (np.column_stack([fp, np.full(6, 70.0)]),), "test")
    model = build_model([blk], [], frame, roof_rgb_source=(0.2, 0.2, 0.2))
    write_glb(tmp_path / "l.glb", model)
    assert glb_problems(tmp_path / "l.glb") == []
    roof = [p for p in model.meshes[0].parts if p.kind == "roof"][0]
    assert roof.n_triangles == 4 and np.all(roof.normals[:, 2] > 0.999) and roof.image is None
    with pytest.raises(SkyrigError):
        triangulate_polygon(np.array([[0, 0], [1, 1], [2, 2.0]]))


def test_clipped_building_border_edges_are_cut_faces_not_walls(tmp_path):
    """A building cut by the DSM's border (BuildingBlock.border_edges): its edges on the border are where the known
    part ends; the model draws them as untextured "cut" faces in their own colour, never as textured walls."""
    from skyrig.dense.model import CUT_RGB, DEFAULT_WALL_RGB

    frame = WorldFrame.map(CRS)
    fp = np.array([[0, 0], [20, 0], [20, 10], [0, 10.0]]) + np.array([550000.0, 5800000.0])
    # gabled along x: the gable triangles stand on edges 1 (east, on the border) and 3 (west)
    a, b = fp[0] + [0, 5.0], fp[1] + [0, 5.0]
    roofs = (np.array([[*fp[0], 70.0], [*fp[1], 70.0], [*b, 74.0], [*a, 74.0]]),
             np.array([[*a, 74.0], [*b, 74.0], [*fp[2], 70.0], [*fp[3], 70.0]]))
    blk = BuildingBlock(0, fp, 60.0, 70.0, roofs, "dsm", clipped=True, border_edges=(1,))
    tex = FacadeTexture(blk.facades()[0], np.full((10, 20, 3), 200, np.uint8), np.ones((10, 20), bool), 1.0, ("x",))
    model = build_model([blk], [tex], frame, roof_rgb_source=(0.2, 0.2, 0.2))
    parts = {p.name: p for p in model.meshes[0].parts}
    assert parts["cut 1"].kind == "cut" and parts["cut 1"].image is None and parts["cut 1"].color == CUT_RGB
    assert parts["cut gable 1"].kind == "cut" and parts["cut gable 1"].color == CUT_RGB
    assert parts["gable 3"].kind == "gable" and parts["gable 3"].color == DEFAULT_WALL_RGB
    assert parts["wall 0"].kind == "wall" and parts["wall 0"].image is not None
    assert sum(p.kind == "wall" for p in parts.values()) == 3
    write_glb(tmp_path / "cut.glb", model)
    assert glb_problems(tmp_path / "cut.glb") == []
    # a texture made for a border edge is refused in words
    bad = FacadeTexture(blk.facades()[1], np.zeros((10, 10, 3), np.uint8), np.ones((10, 10), bool), 1.0, ("x",))
    with pytest.raises(SkyrigError, match="border"):
        build_model([blk], [bad], frame)


def test_bad_inputs(town, glb, tmp_path):
    scene, frame, blocks, textures = town
    path = glb[1]
    cut = tmp_path / "cut.glb"
    cut.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(InputFormatError, match="cut.glb.*truncated"):
        read_glb(cut)
    (tmp_path / "x.glb").write_bytes(b"not a glb file at all")
    with pytest.raises(InputFormatError, match="magic"):
        read_glb(tmp_path / "x.glb")
    t = textures[0]
    foreign = FacadeTexture(t.facade.__class__(99, 0, t.facade.corners), t.rgb, t.valid, t.texel_m)
    with pytest.raises(SkyrigError, match="building 99"):
        build_model(blocks, [foreign], frame)
    other = FacadeTexture(t.facade.__class__(t.facade.building, 0, t.facade.corners + 5.0), t.rgb, t.valid, t.texel_m)
    with pytest.raises(SkyrigError, match="another wall"):
        build_model(blocks, [other], frame)
    with pytest.raises(SkyrigError, match="no buildings"):
        build_model([], [], frame)


def test_judge_model_against_known_offsets(town):
    """Truth vs itself is exact; a block moved by a known offset and raised by a known height shows them."""
    scene, frame, blocks, textures = town
    r0 = judge_model(blocks, frame, scene)
    assert r0["found"] == len(blocks) and r0["missed"] == 0 and r0["extra"] == 0
    assert r0["corner_rms_m"] < 1e-3 and abs(r0["eave_bias_m"]) < 1e-3 and r0["ridge_rms_m"] < 1e-3
    # blocks moved 0.6 m east and raised 1.5 m in the scene's own frame: every corner is 0.6 m from its true place
    loc = WorldFrame.local(*scene.origin)
    moved = []
    for b in true_buildings(scene):
        fp = b.footprint + np.array([0.6, 0.0])
        roof = tuple(np.asarray(r) + np.array([0.6, 0.0, 1.5]) for r in b.roof)
        moved.append(BuildingBlock(b.id, fp, b.ground_z, b.eave_z + 1.5, roof))
    r1 = judge_model(moved, loc, scene)
    assert 0.0 < r1["corner_rms_m"] <= 0.6 + 1e-9  # distance to the moved outline: at most the shift
    assert r1["corner_vertex_rms_m"] == pytest.approx(0.6, abs=1e-9)
    assert r1["eave_bias_m"] == pytest.approx(1.5, abs=1e-9) and r1["ridge_rms_m"] == pytest.approx(1.5, abs=1e-9)


# ------------------------------------------------------------------ external checkers
def _validator_dir() -> Path | None:
    env = os.environ.get("SKYRIG_GLTF_VALIDATOR")
    if env and (Path(env) / "package.json").is_file():
        return Path(env)
    npm = shutil.which("npm")
    if npm:
        try:
            root = subprocess.run([npm, "root", "-g"], capture_output=True, text=True, timeout=20).stdout.strip()
        except (OSError, subprocess.TimeoutExpired):
            return None
        if root and (Path(root) / "gltf-validator" / "package.json").is_file():
            return Path(root) / "gltf-validator"
    return None


def test_khronos_gltf_validator(glb, tmp_path):
    node = shutil.which("node")
    vdir = _validator_dir()
    if node is None or vdir is None:
        pytest.skip("the Khronos glTF validator is not installed (node + npm package 'gltf-validator'; "
                    "set SKYRIG_GLTF_VALIDATOR to its folder after `npm install gltf-validator`)")
    script = tmp_path / "validate.js"
    script.write_text(
        "const v = require(process.argv[2]); const fs = require('fs');\n"
        "v.validateBytes(new Uint8Array(fs.readFileSync(process.argv[3])))"
        ".then(r => { console.log(JSON.stringify(r.issues)); })"
        ".catch(e => { console.error(e); process.exit(2); });\n")
    res = subprocess.run([node, str(script), str(vdir), str(glb[1])], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    issues = json.loads(res.stdout)
    print("glTF validator:", {k: issues[k] for k in ("numErrors", "numWarnings", "numInfos", "numHints")})
    assert issues["numErrors"] == 0, [m for m in issues["messages"] if m["severity"] == 0][:5]
    assert issues["numWarnings"] == 0, [m for m in issues["messages"] if m["severity"] == 1][:5]


def test_viewer_in_headless_chromium(glb, tmp_path):
    from skyrig.report.viewer import chromium_check, find_chromium, write_viewer

    if find_chromium() is None:
        pytest.skip("no Chromium / Chrome installed: the viewer page is not checked")
    model, path = glb[0], glb[1]
    page = write_viewer(tmp_path / "viewer.html", path, title="test town")
    assert "file://" not in page.read_text()[:2000]
    state = chromium_check(page, screenshot=tmp_path / "shot.png", timeout_s=120)
    assert "error" not in state, state
    assert state["loaded"] == "1"
    assert int(state["triangles"]) == model.n_triangles
    assert int(state["meshes"]) == sum(len(m.parts) for m in model.meshes)
    assert int(state["textured"]) == sum(1 for m in model.meshes for p in m.parts if p.image is not None)
    assert float(state["drawnFraction"]) > 0.02
    import cv2

    shot = cv2.imread(str(tmp_path / "shot.png"))
    assert shot is not None and shot.shape[0] > 300
    bg = np.array([0xEE, 0xE6, 0xDD])  # BGR of the page background
    differs = np.abs(shot.astype(int) - bg).sum(axis=2) > 24
    assert differs.mean() > 0.05, "the screenshot is (almost) blank"


def test_glb_round_trip_with_orthometric_heights(egm96_grid, tmp_path):
    """Blocks with EGM96 heights: GLB vertices back through the recorded origin (ellipsoidal) and a PROJ pipeline
    written here (UTM inverse, vgridshift with the grid, geocentric) land on the blocks' corners within 1 mm; the
    side-car states the orthometric reference and a compound CRS."""
    scene = make_scene(3, (-80.0, -80.0, 80.0, 80.0), n_buildings=2)
    frame = WorldFrame.map(CRS, str(egm96_grid))
    blocks = true_buildings(scene, frame)
    model = build_model(blocks, [], frame)
    side = write_glb(tmp_path / "o.glb", model)
    assert "orthometric" in side["vertical_reference"] and pyproj.CRS.from_wkt(side["source_crs_wkt"]).is_compound
    gltf, binary = read_glb(tmp_path / "o.glb")
    pipe = pyproj.Transformer.from_pipeline(
        f"+proj=pipeline +step +inv +proj=utm +zone=32 +ellps=GRS80 +step +proj=vgridshift +grids={egm96_grid} "
        "+multiplier=1 +step +proj=cart +ellps=WGS84")
    o = side["origin"]
    t = _transformer("EPSG:4979", "EPSG:4978")
    oe = np.array(t.transform(o["lon_deg"], o["lat_deg"], o["h_m"]))
    for bid, name, kind, pos, *_ in _primitives(gltf, binary):
        b = blocks[bid]
        fp = np.asarray(b.footprint)
        corners = np.vstack([np.column_stack([fp, np.full(len(fp), b.ground_z)]),
                             np.column_stack([fp, np.full(len(fp), b.eave_z)])] + [np.asarray(r) for r in b.roof])
        enu = np.column_stack([pos[:, 0], -pos[:, 2], pos[:, 1]])
        ecef = oe + enu @ _enu_rotation(o["lat_deg"], o["lon_deg"]).T
        back = np.column_stack(pipe.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2], direction="INVERSE"))
        d = np.linalg.norm(back[:, None] - corners[None], axis=2).min(axis=1)
        assert d.max() < 1e-3, f"building {bid} {name}: {d.max() * 1000:.2f} mm"
    # the origin's ellipsoidal height is its orthometric height plus the EGM96 undulation (about +43 m here)
    assert 35.0 < o["h_m"] - side["origin_in_source_frame"][2] < 50.0


def test_large_textures_are_reduced_in_the_glb(town, tmp_path):
    scene, frame, blocks, textures = town
    t = textures[0]
    big = FacadeTexture(t.facade, np.repeat(np.repeat(t.rgb, 8, axis=0), 8, axis=1),
                        np.ones((t.rgb.shape[0] * 8, t.rgb.shape[1] * 8), bool), t.texel_m / 8)
    model = build_model(blocks, [big], frame)
    write_glb(tmp_path / "big.glb", model, max_texture_px=512)
    gltf, binary = read_glb(tmp_path / "big.glb")
    img = _texture(gltf, binary, [m for m in gltf["materials"] if "baseColorTexture" in m["pbrMetallicRoughness"]][0])
    assert max(img.shape[:2]) == 512 < 8 * max(t.rgb.shape[:2])
    assert glb_problems(tmp_path / "big.glb") == []


@pytest.mark.slow
def test_viewer_without_inlined_model_loads_model_glb_over_http(glb, tmp_path):
    """``write_viewer(path, None)``: the page fetches ``model.glb`` next to it (served here by http.server)."""
    import functools
    import http.server
    import threading

    from skyrig.report.viewer import chromium_check, find_chromium, write_viewer

    if find_chromium() is None:
        pytest.skip("no Chromium / Chrome installed: the viewer page is not checked")
    shutil.copy(glb[1], tmp_path / "model.glb")
    write_viewer(tmp_path / "index.html", None)
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(tmp_path))
    handler.log_message = lambda *a, **k: None
    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    th = threading.Thread(target=srv.serve_forever, daemon=True)
    th.start()
    try:
        state = chromium_check(f"http://127.0.0.1:{srv.server_address[1]}/index.html", timeout_s=120)
    finally:
        srv.shutdown()
        srv.server_close()
    assert state.get("loaded") == "1" and int(state["triangles"]) == glb[0].n_triangles, state
