"""Bad inputs at the command line (issue 13): named cases over the commands, each with the exit status the rule
in docs/cli.md gives (0 ok, 1 a failed result, 2 a wrong command line or input), the words that name the file,
line, field or option, and never a traceback.  Cases that must work (a points file in another CRS than the EO,
Windows line endings with a BOM, old option spellings) are checked against an independent answer: PROJ's
conversion of the same points and the library's own projection.

A small consistent project is written once per module: a single-camera rig, three nadir images over UTM 32N
(ETRS89, 9 deg E, 48.3 deg N), three ground points, a GNSS/IMU trajectory and camera events.
"""

from __future__ import annotations

import csv
import json
import math
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyproj
import pytest
from click.testing import CliRunner

from skyrig.cli import main

EO = """# skyrig-eo 1
# crs: EPSG:25832
# heights: ellipsoidal
# angles: deg
# convention: opk
image,camera,x,y,z,omega,phi,kappa
img1.tif,camera,500000.0,5350000.0,1200.0,0.1,-0.2,90.0
img2.tif,camera,500300.0,5350000.0,1200.0,0.1,-0.2,90.0
img3.tif,camera,500600.0,5350000.0,1200.0,0.1,-0.2,90.0
"""
PTS_ROWS = [("g1", 500100.0, 5350050.0, 310.0), ("g2", 500300.0, 5349950.0, 305.5), ("g3", 500450.0, 5350020.0, 298.25)]
PTS = "# crs: EPSG:25832\n# heights: ellipsoidal\nname,x,y,z\n" + "".join(f"{n},{x},{y},{z}\n" for n, x, y, z in PTS_ROWS)
from test_bad_input_readers import RIG  # noqa: E402 - the same one-camera UAV rig file
TRAJ = ("# skyrig-trajectory 1\n# crs: EPSG:4979\n# angles: deg\n# time: gps-sow\ntime,lat,lon,h,roll,pitch,yaw\n"
        + "".join(f"{345600.0 + k:.3f},48.30000,{9.0 + 0.0008 * k:.5f},{1200.0 + 0.1 * k:.1f},0.5,-1.2,90.0\n"
                  for k in range(6)))
EVENTS = ("# skyrig-events 1\n# time: gps-sow\nimage,time,head,exposure\n"
          "e1.jpg,345601.100000,camera,1\ne2.jpg,345602.300000,camera,2\ne3.jpg,345603.500000,camera,3\n")


@pytest.fixture(scope="module")
def proj(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("cli_bad")
    for name, text in {"eo.csv": EO, "gcp.csv": PTS, "rig.yaml": RIG, "traj.csv": TRAJ, "events.csv": EVENTS}.items():
        (d / name).write_bytes(text.encode())
    res = CliRunner().invoke(main, ["world-to-image", "--eo", str(d / "eo.csv"), "--camera", str(d / "rig.yaml"),
                                    "--points", str(d / "gcp.csv"), "-o", str(d / "truth_px.csv")])
    assert res.exit_code == 0, res.output
    return d


def run(*args: str) -> SimpleNamespace:
    res = CliRunner().invoke(main, [str(a) for a in args])
    out = res.output + (res.stderr if hasattr(res, "stderr") and res.stderr not in res.output else "")
    return SimpleNamespace(code=res.exit_code, out=out, exc=res.exception)


def pixels(path: Path) -> dict[tuple[str, str], tuple[float, float]]:
    with open(path, newline="") as fh:
        rows = [r for r in csv.reader(ln for ln in fh if not ln.startswith("#"))]
    h = rows[0]
    return {(r[h.index("point")], r[h.index("image")]): (float(r[h.index("column")]), float(r[h.index("row")]))
            for r in rows[1:]}


def write(d: Path, name: str, text: str | bytes) -> Path:
    p = d / name
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    return p


def no_traceback(r: SimpleNamespace) -> None:
    assert "Traceback" not in r.out and "np.float64" not in r.out, r.out
    assert r.exc is None or isinstance(r.exc, SystemExit), repr(r.exc)


# --------------------------------------------------------------------------- world-to-image: the points file's CRS
def _points_in(crs: str, heights_note: str = "") -> str:
    t = pyproj.Transformer.from_crs("EPSG:25832", crs, always_xy=True)
    rows = []
    for n, x, y, z in PTS_ROWS:
        u, v = t.transform(x, y)
        rows.append(f"{n},{u:.10f},{v:.10f},{z}\n")
    return f"# crs: {crs}\n# heights: ellipsoidal\n{heights_note}name,x,y,z\n" + "".join(rows)


@pytest.mark.parametrize("crs", ["EPSG:4258", "EPSG:4326", "EPSG:3035", "EPSG:32632"],
                         ids=["etrs89-geographic", "wgs84-geographic", "laea-europe", "wgs84-utm32"])
def test_w2i_points_file_in_another_crs_than_the_eo(proj, tmp_path, crs):
    """The points file's own CRS header is used (was: the EO's CRS silently, 140 px off or 0 points)."""
    p = write(tmp_path, "pts.csv", _points_in(crs))
    r = run("world-to-image", "--eo", proj / "eo.csv", "--camera", proj / "rig.yaml", "--points", p,
            "-o", tmp_path / "px.csv")
    assert r.code == 0, r.out
    no_traceback(r)
    got, truth = pixels(tmp_path / "px.csv"), pixels(proj / "truth_px.csv")
    assert got.keys() == truth.keys() and len(truth) == 9
    # PROJ round trip at 1e-10 deg / 0.1 mm -> far below 0.01 px at this scale (0.4 m per pixel)
    assert max(max(abs(a - b) for a, b in zip(got[k], truth[k])) for k in truth) < 0.01


def test_w2i_points_without_crs_take_the_eo_crs(proj, tmp_path):
    p = write(tmp_path, "pts.csv", PTS.split("\n", 2)[2])
    r = run("world-to-image", "--eo", proj / "eo.csv", "--camera", proj / "rig.yaml", "--points", p,
            "-o", tmp_path / "px.csv")
    assert r.code == 0, r.out
    assert pixels(tmp_path / "px.csv") == pixels(proj / "truth_px.csv")


def test_w2i_points_match_the_library(proj):
    """The truth file itself is the library's projection (world_to_image) of the points: independent of the CLI."""
    from skyrig.cli._common import load_cameras
    from skyrig.georef.ground import world_to_image
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.points_csv import read_points_csv

    eo, g, cams = read_eo_csv(proj / "eo.csv"), read_points_csv(proj / "gcp.csv"), load_cameras([str(proj / "rig.yaml")])
    truth = pixels(proj / "truth_px.csv")
    for (pt, im), px in truth.items():
        k = list(g.name).index(pt)
        lib = world_to_image(eo, cams, np.array([im]), g.xyz[k:k + 1], g.frame)[0]
        assert np.allclose(lib, px, atol=0.001)


def test_w2i_crlf_bom_files_work(proj, tmp_path):
    eo = write(tmp_path, "eo.csv", ("\ufeff" + EO).replace("\n", "\r\n"))
    pts = write(tmp_path, "pts.csv", ("\ufeff" + PTS).replace("\n", "\r\n"))
    rig = write(tmp_path, "rig.yaml", ("\ufeff" + RIG).replace("\n", "\r\n"))
    r = run("world-to-image", "--eo", eo, "--camera", rig, "--points", pts, "-o", tmp_path / "px.csv")
    assert r.code == 0, r.out
    assert pixels(tmp_path / "px.csv") == pixels(proj / "truth_px.csv")


# --------------------------------------------------------------------------- the table
# (name, command line with {p} = project folder and {t} = this case's folder, files to write {name: text},
#  expected exit status, words that must appear)
def _rep(text: str, old: str, new: str) -> str:
    assert old in text
    return text.replace(old, new)


def _png() -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", (np.random.default_rng(0).random((40, 60)) * 255).astype(np.uint8))
    return buf.tobytes()


_PNG = _png()
W2I = ["world-to-image", "--eo", "{p}/eo.csv", "--camera", "{p}/rig.yaml"]
GEO = ["georef", "--trajectory", "{p}/traj.csv", "--events", "{p}/events.csv", "--rig", "{p}/rig.yaml"]
CASES = [
    ("w2i-points-crs-contradicts-option", W2I + ["--points", "{p}/gcp.csv", "--points-crs", "EPSG:2154", "-o",
                                                  "{t}/o.csv"], {}, 2, ["gcp.csv", "line 1", "but --points-crs says"]),
    ("w2i-points-heights-mm", W2I + ["--points", "{t}/g.csv", "-o", "{t}/o.csv"],
     {"g.csv": PTS.replace(",310.0", ",310000.0").replace(",305.5", ",305500.0").replace(",298.25", ",298250.0")}, 2,
     ["g.csv", "line 4", "field 'z'", "millimetres (310.000 m)"]),
    ("w2i-points-xy-swapped", W2I + ["--points", "{t}/g.csv", "-o", "{t}/o.csv"],
     {"g.csv": "# crs: EPSG:25832\nname,x,y,z\n" + "".join(f"{n},{y},{x},{z}\n" for n, x, y, z in PTS_ROWS)}, 2,
     ["g.csv", "line 3", "swapped"]),
    ("w2i-points-duplicate", W2I + ["--points", "{t}/g.csv", "-o", "{t}/o.csv"], {"g.csv": PTS + "g1,500100,5350050,310\n"},
     2, ["g.csv", "line 7", "'g1' appears twice"]),
    ("w2i-points-typo-header", W2I + ["--points", "{t}/g.csv", "-o", "{t}/o.csv"],
     {"g.csv": _rep(PTS, "# heights:", "# hieghts:")}, 2, ["g.csv", "line 2", "did you mean 'heights'"]),
    ("w2i-points-latlon-swapped-far-away", W2I + ["--points", "{t}/g.csv", "-o", "{t}/o.csv"],
     {"g.csv": "# crs: EPSG:4326\nname,x,y,z\ng1,48.3,9.0,310\ng2,48.301,9.001,305\n"}, 2,
     ["g.csv", "none of the 2 points falls in any of the 3 images", "km from the projection centres"]),
    ("w2i-eo-missing-file", ["world-to-image", "--eo", "{t}/nope.csv", "--camera", "{p}/rig.yaml", "--points",
                             "{p}/gcp.csv", "-o", "{t}/o.csv"], {}, 2, ["--eo", "nope.csv", "does not exist"]),
    ("w2i-eo-duplicate-image", ["world-to-image", "--eo", "{t}/eo.csv", "--camera", "{p}/rig.yaml", "--points",
                                "{p}/gcp.csv", "-o", "{t}/o.csv"], {"eo.csv": EO + EO.splitlines()[-1] + "\n"}, 2,
     ["eo.csv", "line 10", "duplicate image 'img3.tif'"]),
    ("w2i-eo-heights-mm", ["world-to-image", "--eo", "{t}/eo.csv", "--camera", "{p}/rig.yaml", "--points",
                           "{p}/gcp.csv", "-o", "{t}/o.csv"], {"eo.csv": EO.replace("1200.0,", "1200000.0,")}, 2,
     ["eo.csv", "line 7", "millimetres (1200.000 m)"]),
    ("w2i-eo-degrees-as-radians", ["world-to-image", "--eo", "{t}/eo.csv", "--camera", "{p}/rig.yaml", "--points",
                                   "{p}/gcp.csv", "-o", "{t}/o.csv"], {"eo.csv": _rep(EO, "angles: deg", "angles: rad")},
     2, ["eo.csv", "line 7", "kappa", "wrong unit?"]),
    ("w2i-camera-not-in-rig", ["world-to-image", "--eo", "{t}/eo.csv", "--camera", "{p}/rig.yaml", "--points",
                               "{p}/gcp.csv", "-o", "{t}/o.csv"], {"eo.csv": EO.replace(".tif,camera,", ".tif,nadir,")}, 2,
     ["camera 'nadir'", "not defined by any --camera"]),
    ("w2i-rig-lever-arm-mm", ["world-to-image", "--eo", "{p}/eo.csv", "--camera", "{t}/rig.yaml", "--points",
                              "{p}/gcp.csv", "-o", "{t}/o.csv"], {"rig.yaml": _rep(RIG, "[0.05, 0.0, 0.1]", "[50, 0, 100]")},
     2, ["rig.yaml", "line 16", "heads[0].lever_arm_m", "millimetres (0.112 m)"]),
    ("w2i-output-is-a-folder", W2I + ["--points", "{p}/gcp.csv", "-o", "{t}"], {}, 2, ["-o", "is a directory"]),
    ("w2i-output-under-a-file", W2I + ["--points", "{p}/gcp.csv", "-o", "{p}/gcp.csv/o.csv"], {}, 2,
     ["-o", "gcp.csv' is a file, not a folder"]),
    ("w2i-measurements-semicolon", W2I + ["--points", "{p}/gcp.csv", "--measurements", "{t}/m.csv", "-o", "{t}/o.csv"],
     {"m.csv": "point;image;column;row\ng1;img1.tif;1;2\n"}, 2, ["m.csv", "line 1", "field 'point'", "missing column"]),
    ("w2i-ign-opk-without-crs", ["world-to-image", "--eo", "{t}/a.OPK", "--camera", "{p}/rig.yaml", "--points",
                                 "{p}/gcp.csv", "-o", "{t}/o.csv"],
     {"a.OPK": "NOM X Y Z O P K CAMERA\nimg1 650000 6860000 2500 0 0 0 camera\n"}, 2,
     ["an IGN OPK file needs --eo-crs"]),
    ("w2i-eo-crs-unknown", ["world-to-image", "--eo", "{t}/a.OPK", "--eo-crs", "EPSG:99999", "--camera", "{p}/rig.yaml",
                            "--points", "{p}/gcp.csv", "-o", "{t}/o.csv"],
     {"a.OPK": "NOM X Y Z O P K CAMERA\nimg1 650000 6860000 2500 0 0 0 camera\n"}, 2, ["EPSG:99999"]),
    ("w2i-empty-eo", ["world-to-image", "--eo", "{t}/eo.csv", "--camera", "{p}/rig.yaml", "--points", "{p}/gcp.csv",
                      "-o", "{t}/o.csv"], {"eo.csv": ""}, 2, ["eo.csv", "line 1", "first line must be"]),
    ("w2i-latin1-eo", ["world-to-image", "--eo", "{t}/eo.csv", "--camera", "{p}/rig.yaml", "--points", "{p}/gcp.csv",
                       "-o", "{t}/o.csv"], {"eo.csv": EO.replace("img1", "bild_ä").encode("latin-1")}, 2,
     ["eo.csv", "not a UTF-8 text file"]),
    # ---- georef
    ("georef-unknown-crs", GEO + ["--crs", "EPSG:99999", "-o", "{t}/eo.csv"], {}, 2, ["EPSG:99999"]),
    ("georef-orthometric-without-geoid", GEO + ["--crs", "EPSG:25832", "--heights", "orthometric", "-o", "{t}/eo.csv"],
     {}, 2, ["geoid"]),
    ("georef-head-not-in-rig", ["georef", "--trajectory", "{p}/traj.csv", "--events", "{t}/ev.csv", "--rig",
                                "{p}/rig.yaml", "--crs", "EPSG:25832", "-o", "{t}/eo.csv"],
     {"ev.csv": EVENTS.replace(",camera,", ",nadir,")}, 2, ["nadir"]),
    ("georef-event-after-trajectory", ["georef", "--trajectory", "{p}/traj.csv", "--events", "{t}/ev.csv", "--rig",
                                       "{p}/rig.yaml", "--crs", "EPSG:25832", "-o", "{t}/eo.csv"],
     {"ev.csv": EVENTS.replace("345603.500000", "345700.500000")}, 2, ["ev.csv", "line 6"]),
    ("georef-rig-antenna-arm-cm", ["georef", "--trajectory", "{p}/traj.csv", "--events", "{p}/events.csv", "--rig",
                                   "{t}/rig.yaml", "--crs", "EPSG:25832", "-o", "{t}/eo.csv"],
     {"rig.yaml": _rep(RIG, "[0.0, 0.0, -0.1]", "[0.0, 0.0, -120.0]")}, 2,
     ["rig.yaml", "line 4", "antenna_lever_arm_m", "centimetres (1.200 m)"]),
    ("georef-trajectory-heights-mm", ["georef", "--trajectory", "{t}/traj.csv", "--events", "{p}/events.csv", "--rig",
                                      "{p}/rig.yaml", "--crs", "EPSG:25832", "-o", "{t}/eo.csv"],
     {"traj.csv": TRAJ.replace(",1200.", ",1200000.")}, 2, ["traj.csv", "line 6", "field 'h'", "millimetres"]),
    ("georef-trajectory-latlon-swapped", ["georef", "--trajectory", "{t}/traj.csv", "--events", "{p}/events.csv",
                                          "--rig", "{p}/rig.yaml", "--crs", "EPSG:25832", "-o", "{t}/eo.csv"],
     {"traj.csv": TRAJ.replace(",48.30000,9.00", ",139.76000,35.00")}, 2, ["traj.csv", "line 6", "swapped"]),
    ("georef-events-utc-trajectory-gps", ["georef", "--trajectory", "{p}/traj.csv", "--events", "{t}/ev.csv", "--rig",
                                          "{p}/rig.yaml", "--crs", "EPSG:25832", "-o", "{t}/eo.csv"],
     {"ev.csv": EVENTS.replace("gps-sow", "utc-sod")}, 2, ["ev.csv", "'utc-sod' but the trajectory is in 'gps-sow'"]),
    ("georef-events-semicolon", ["georef", "--trajectory", "{p}/traj.csv", "--events", "{t}/ev.csv", "--rig",
                                 "{p}/rig.yaml", "--crs", "EPSG:25832", "-o", "{t}/eo.csv"],
     {"ev.csv": EVENTS.replace(",", ";")}, 2, ["ev.csv", "line 3", "unknown column"]),
    ("georef-rig-is-json", ["georef", "--trajectory", "{p}/traj.csv", "--events", "{p}/events.csv", "--rig",
                            "{t}/rig.yaml", "--crs", "EPSG:25832", "-o", "{t}/eo.csv"],
     {"rig.yaml": '{"format": "skyrig-rig", "version": 1}'}, 2, ["rig.yaml", "missing key"]),
    # ---- convert
    ("convert-unknown-to-crs", ["convert", "{p}/eo.csv", "{t}/out.csv", "--to-crs", "EPSG:123456"], {}, 2,
     ["EPSG:123456"]),
    ("convert-opk-needs-crs", ["convert", "{t}/a.OPK", "{t}/out.csv"],
     {"a.OPK": "NOM X Y Z O P K CAMERA\nimg1 650000 6860000 2500 0 0 0 camera\n"}, 2, ["needs --from-crs"]),
    ("convert-bad-source", ["convert", "{t}/eo.csv", "{t}/out.csv"], {"eo.csv": EO[:-20]}, 2,
     ["eo.csv", "line 9", "expected 8 fields"]),
    # ---- block / image-to-world / plan / simulate / global
    ("block-unknown-free-group", ["block", "--eo", "{p}/eo.csv", "--camera", "{p}/rig.yaml", "--measurements",
                                  "{p}/truth_px.csv", "--free", "boresite", "-o", "{t}/b.json"], {}, 2, ["boresite"]),
    ("block-gnss-sigma-text", ["block", "--eo", "{p}/eo.csv", "--camera", "{p}/rig.yaml", "--measurements",
                               "{p}/truth_px.csv", "--gnss-sigma", "5cm", "-o", "{t}/b.json"], {}, 2, ["--gnss-sigma"]),
    ("block-control-heights-mm", ["block", "--eo", "{p}/eo.csv", "--camera", "{p}/rig.yaml", "--measurements",
                                  "{p}/truth_px.csv", "--control", "{t}/g.csv", "-o", "{t}/b.json"],
     {"g.csv": PTS.replace(",310.0", ",310000.0").replace(",305.5", ",305500.0").replace(",298.25", ",298250.0")}, 2,
     ["g.csv", "line 4", "millimetres"]),
    ("block-ign-app-needs-points-crs", ["block", "--trajectory", "{p}/traj.csv", "--events", "{p}/events.csv",
                                        "--rig", "{p}/rig.yaml", "--measurements", "{t}/m.csv", "--control",
                                        "{t}/g.app", "-o", "{t}/b.json"],
     {"m.csv": "point,image,column,row\ng1,e1.jpg,10,20\n", "g.app": '"g1" 13 500100.0 5350050.0 310.0\n'}, 2,
     ["an IGN point file needs --points-crs"]),
    ("block-eo-opk-needs-eo-crs", ["block", "--eo", "{t}/a.OPK", "--camera", "{p}/rig.yaml", "--measurements",
                                   "{p}/truth_px.csv", "-o", "{t}/b.json"],
     {"a.OPK": "NOM X Y Z O P K CAMERA\nimg1 650000 6860000 2500 0 0 0 camera\n"}, 2, ["needs --eo-crs"]),
    ("match-eo-opk-needs-eo-crs", ["match", "{t}", "--eo", "{t}/a.OPK", "--camera", "{p}/rig.yaml", "-o", "{t}/m"],
     {"a.OPK": "NOM X Y Z O P K CAMERA\nimg1 650000 6860000 2500 0 0 0 camera\n", "img1.png": b""}, 2,
     ["needs --eo-crs"]),
    ("i2w-unknown-output-crs", ["image-to-world", "--eo", "{p}/eo.csv", "--camera", "{p}/rig.yaml", "--measurements",
                                "{p}/truth_px.csv", "--intersect", "--crs", "EPSG:0", "-o", "{t}/g.csv"], {}, 2,
     ["EPSG:0"]),
    ("i2w-dem-is-text", ["image-to-world", "--eo", "{p}/eo.csv", "--camera", "{p}/rig.yaml", "--measurements",
                         "{p}/truth_px.csv", "--dem", "{t}/dem.tif", "-o", "{t}/g.csv"], {"dem.tif": "not a raster\n"},
     2, ["dem.tif"]),
    ("i2w-measurement-unknown-image", ["image-to-world", "--eo", "{p}/eo.csv", "--camera", "{p}/rig.yaml",
                                       "--measurements", "{t}/m.csv", "--height", "300", "-o", "{t}/g.csv"],
     {"m.csv": "point,image,column,row\ng1,img9.tif,100,200\n"}, 2, ["m.csv", "line 2", "'img9.tif' has no exterior"]),
    ("match-no-images", ["match", "{t}"], {"notes.txt": "no images here\n"}, 2, ["no readable images"]),
    ("match-duplicate-image-names", ["match", "{t}", "--images", "{t}/a", "--images", "{t}/b"],
     {"a/im0.png": _PNG, "b/im0.png": _PNG}, 2, ["duplicate image name 'im0.png'", "unique across folders"]),
    ("match-eo-without-camera", ["match", "{t}", "--eo", "{p}/eo.csv"], {"images/im0.png": _PNG}, 2,
     ["--camera: no camera given"]),
    ("match-png-that-is-text", ["match", "{t}"], {"images/im0.png": "not an image\n"}, 2, ["no readable images"]),
    ("dsm-images-not-found", ["dsm", "--eo", "{p}/eo.csv", "--camera", "{p}/rig.yaml", "--images", "{t}/imgs",
                              "--height-range", "200", "400", "-o", "{t}/dsm"], {"imgs/other.tif": _PNG}, 2,
     ["img1.tif", "not found"]),
    ("dsm-no-height-range", ["dsm", "--eo", "{p}/eo.csv", "--camera", "{p}/rig.yaml", "--images", "{t}", "-o",
                             "{t}/dsm"], {}, 2, ["--height-range"]),
    ("simulate-unknown-scenario", ["simulate", "midsa", "{t}/sim"], {}, 2, ["midsa"]),
    ("unknown-command", ["georeference"], {}, 2, ["No such command"]),
]


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_cli_bad_input(proj, tmp_path, case):
    name, args, files, code, words = case
    for fname, text in files.items():
        write(tmp_path, fname, text)
    argv = [a.replace("{p}", str(proj)).replace("{t}", str(tmp_path)) for a in args]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = run(*argv)
    assert r.code == code, r.out
    for w in words:
        assert w in r.out, (w, r.out)
    no_traceback(r)
    if code != 0:
        assert not (tmp_path / "o.csv").exists() and not (tmp_path / "eo.csv.json").exists() or "eo.csv" in files


def test_cli_warns_in_words_for_a_long_lever_arm(proj, tmp_path):
    rig = write(tmp_path, "rig.yaml", _rep(RIG, "[0.05, 0.0, 0.1]", "[20.0, 0.0, 0.0]"))
    r = run("world-to-image", "--eo", proj / "eo.csv", "--camera", rig, "--points", proj / "gcp.csv", "-o",
            tmp_path / "o.csv")
    assert r.code == 0, r.out
    assert "warning: " in r.out and "lever arm of 20 m is unusually long" in r.out and "rig.yaml" in r.out
    no_traceback(r)


# --------------------------------------------------------------------------- adjust-uav / match: spellings, manifests
def _fake_adjust_uav(seen: dict):
    def fake(images, match, out, cfg, pycolmap_dir=None, **kw):
        seen["gnss"] = tuple(cfg.gnss_sigma_m)
        out = Path(out)
        (out / "eo.csv").write_text("eo\n")
        (out / "report.json").write_text("{}")
        rep = {"uav": dict(oriented=3, images=3, tie_points=40, reprojection_rms_px=0.4, sigma0=1.0,
                           gnss_fit_rms_enu_m=[1.0, 1.0, 2.0], not_oriented=[], attitude_check={}, total_wall_s=0.1)}
        adj = SimpleNamespace(info=SimpleNamespace(converged=True, message="", iterations=3), sigma0=1.0,
                              redundancy=10, failures=[])
        return SimpleNamespace(adjustment=adj), rep
    return fake


@pytest.fixture()
def uav_proj(tmp_path, monkeypatch):
    seen: dict = {}
    monkeypatch.setattr("skyrig.pipeline.uav.adjust_uav", _fake_adjust_uav(seen))
    p = tmp_path / "proj"
    (p / "match").mkdir(parents=True)
    (p / "match" / "tie_points.csv").write_text("point,image,column,row\n")
    (p / "images").mkdir()
    return p, seen


@pytest.mark.parametrize("args, gnss, warned", [
    (["--gnss-sigma", "2,2,4"], (2.0, 2.0, 4.0), None),
    (["--gnss-sigma", "3"], (3.0, 3.0, 3.0), None),
    (["--gnss-sigma", "1.5", "1.5", "3"], (1.5, 1.5, 3.0), "--gnss-sigma N N N is deprecated"),
    (["--out", "{o}"], (2.0, 2.0, 4.0), "--out is deprecated; use --output"),
    (["--output", "{o}"], (2.0, 2.0, 4.0), None),
    (["-o", "{o}"], (2.0, 2.0, 4.0), None),
], ids=["comma", "one-value", "old-three-numbers", "old-out", "output", "o"])
def test_adjust_uav_one_spelling_old_ones_warned(uav_proj, tmp_path, args, gnss, warned):
    p, seen = uav_proj
    o = tmp_path / "res"
    r = run("adjust-uav", p, *[a.replace("{o}", str(o)) for a in args])
    assert r.code == 0, r.out
    assert seen["gnss"] == gnss
    assert (warned in r.out) if warned else ("deprecated" not in r.out), r.out
    folder = o if any("{o}" in a for a in args) else p / "adjust-uav"
    from skyrig.io.stage import read_manifest, verify_folder

    assert verify_folder(folder) == []
    m = read_manifest(folder)
    assert m["stage"] == "adjust-uav" and list(m["options"]["gnss_sigma_m"]) == list(gnss)
    assert {f["path"] for f in m["files"]} == {"eo.csv", "report.json"}
    assert any(i["path"].endswith("tie_points.csv") and "sha256" in i for i in m["inputs"])


@pytest.mark.parametrize("value, words", [("2,2", "got 2"), ("2,-1,3", "finite and >= 0"), ("two", "not one number"),
                                          ("nan", "finite and >= 0")])
def test_adjust_uav_bad_sigma(uav_proj, value, words):
    p, seen = uav_proj
    r = run("adjust-uav", p, "--gnss-sigma", value)
    assert r.code == 2 and "--gnss-sigma" in r.out and words in r.out, r.out
    assert "gnss" not in seen and not (p / "adjust-uav").exists()
    no_traceback(r)


def test_adjust_uav_config_not_json(uav_proj, tmp_path):
    p, _ = uav_proj
    cfg = write(tmp_path, "cfg.json", '{"gnss_sigma_m": [1, 1, 2],\n "focal_prior_rel": }\n')
    r = run("adjust-uav", p, "--config", cfg)
    assert r.code == 2 and "cfg.json" in r.out and "line 2" in r.out, r.out
    no_traceback(r)


def test_match_output_spelling_and_manifest(tmp_path):
    """A real (small) match: -o/--output, --out warned as deprecated, manifest.json last with the results'
    checksums (checked against the files)."""
    import cv2

    from skyrig.io.stage import sha256_file

    rng = np.random.default_rng(1)
    big = cv2.GaussianBlur((rng.random((420, 700)) * 255).astype(np.uint8), (0, 0), 2)
    big = cv2.normalize(big, None, 0, 255, cv2.NORM_MINMAX)
    (tmp_path / "images").mkdir()
    for k, x in enumerate([0, 120, 240]):
        cv2.imwrite(str(tmp_path / "images" / f"im{k}.png"), big[10:410, x:x + 400])
    out = tmp_path / "m"
    r = run("match", tmp_path, "--pairs", "exhaustive", "--method", "opencv", "--max-features", "800", "--out", out,
            "-j", "1", "--scheduler", "sync")
    assert r.code == 0, r.out
    assert "--out is deprecated; use --output" in r.out
    m = json.loads((out / "manifest.json").read_text())
    assert m["stage"] == "match" and {f["path"] for f in m["files"]} >= {"tie_points.csv", "report.json"}
    for f in m["files"]:
        assert sha256_file(out / f["path"]) == f["sha256"]
    assert len(m["inputs"]) == 3 and m["options"]["pairs"] == "exhaustive"
    # every output is listed, the resumable store included (issue 13: the manifest omitted features/, matches/)
    from skyrig.io.stage import verify_folder

    paths = {f["path"] for f in m["files"]}
    assert {f"features/im{k}.png.npz" for k in range(3)} <= paths and any(p.startswith("matches/") for p in paths)
    assert verify_folder(out) == []
    # a temporary file a killed run left in the store is not an output: the resumed run removes it
    (out / "features" / "im0.png.npz.x1y2.tmp.npz").write_bytes(b"partial")
    r = run("match", tmp_path, "--pairs", "exhaustive", "--method", "opencv", "--max-features", "800", "-o", out,
            "-j", "1", "--scheduler", "sync")
    assert r.code == 0 and "deprecated" not in r.out, r.out
    assert verify_folder(out) == [] and not (out / "features" / "im0.png.npz.x1y2.tmp.npz").exists()


RIG_400 = """format: skyrig-rig
version: 1
name: test
antenna_lever_arm_m: [0, 0, 0]
heads:
- name: cam
  camera: {name: cam, width_px: 400, height_px: 400, pixel_size_um: 10.0, focal_mm: 4.0, ppx_mm: 0.0, ppy_mm: 0.0,
           distortion: null}
  lever_arm_m: [0, 0, 0]
  mounting_rpy_deg: [0, 0, 0]
  boresight_opk_deg: [0, 0, 0]
"""


def test_match_eo_without_terrain_height_for_exhaustive_pairs(tmp_path):
    """Issue 13: `match --eo` assumed aerial images - it refused to run without --terrain-height even for exhaustive
    pairs.  Three crops 120 px apart of one texture = a nadir camera (400 px focal) 100 m above a plane, moved 30 m
    east per image: exhaustive pairs with these orientations give ties that intersect on the plane (z = 0) with
    ~0 px residuals; guided pairs without a terrain height are a clear error (exit 2)."""
    import cv2

    from skyrig.cli._common import load_cameras
    from skyrig.georef.eo import ExteriorOrientations, WorldFrame
    from skyrig.georef.ground import forward_intersection
    from skyrig.io.eo_csv import write_eo_csv
    from skyrig.io.points_csv import read_measurements_csv

    rng = np.random.default_rng(1)
    big = cv2.GaussianBlur((rng.random((420, 700)) * 255).astype(np.uint8), (0, 0), 2)
    big = cv2.normalize(big, None, 0, 255, cv2.NORM_MINMAX)
    (tmp_path / "images").mkdir()
    for k, x in enumerate([0, 120, 240]):
        cv2.imwrite(str(tmp_path / "images" / f"im{k}.png"), big[10:410, x:x + 400])
    eo = ExteriorOrientations(np.array([f"im{k}.png" for k in range(3)]), np.array(["cam"] * 3),
                              np.array([[500000.0 + 30 * k, 5800000.0, 100.0] for k in range(3)]),
                              np.broadcast_to(np.eye(3), (3, 3, 3)).copy(), WorldFrame.map("EPSG:25832"))
    write_eo_csv(eo, tmp_path / "eo.csv")
    write(tmp_path, "rig.yaml", RIG_400)
    common = ["--eo", tmp_path / "eo.csv", "--camera", tmp_path / "rig.yaml", "--method", "opencv", "--max-features",
              "800", "-j", "1", "--scheduler", "sync"]
    r = run("match", tmp_path, "--pairs", "guided", *common, "-o", tmp_path / "g")
    assert r.code == 2 and "terrain height" in r.out and "--terrain-height" in r.out, r.out
    no_traceback(r)
    r = run("match", tmp_path, "--pairs", "exhaustive", *common, "-o", tmp_path / "m")
    assert r.code == 0, r.out
    t = read_measurements_csv(tmp_path / "m" / "tie_points.csv")
    res = forward_intersection(eo, load_cameras([str(tmp_path / "rig.yaml")]), t.point, t.image, t.pixel, eo.frame)
    rad = np.hypot(res.residual_px[:, 0], res.residual_px[:, 1])
    assert len(res.point) > 100 and np.nanmedian(rad) < 0.05
    assert abs(np.nanmedian(res.xyz[:, 2])) < 0.05  # the plane the crops show, 100 m below the cameras


def test_parse_sigmas_and_old_spellings_units():
    import click

    from skyrig.cli._common import parse_sigmas

    assert parse_sigmas("0.05,0.05,0.08", 3, "--x") == (0.05, 0.05, 0.08)
    for bad in ("", "1,2,3,4", "inf", "-1"):
        with pytest.raises(click.BadParameter):
            parse_sigmas(bad, 3, "--x")
    assert math.isclose(parse_sigmas(" 7 ", 2, "--x")[1], 7.0)


def test_table_size():
    """The issue asks for >= 150 named bad-input cases; this file and test_bad_input_readers.py together."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("_readers", Path(__file__).with_name("test_bad_input_readers.py"))
    mod = importlib.util.module_from_spec(spec)
    import sys

    sys.modules["_readers"] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    n = len(mod.BAD) + len(mod.WARN) + len(mod.GOOD) + len(CASES) + 4 + 6 + 4
    assert n >= 150


def test_lidar_georef_geographic_crs_keeps_millimetres(tmp_path):
    """`skyrig lidar georef --crs EPSG:4326` wrote LAS with a 0.001 scale on degrees (points up to 68 m off, exit
    0); now the degree axes get 1e-8 deg.  Checked against the same pulses written in ECEF, converted by PROJ."""
    import laspy

    raw = ("# skyrig-raw-scan 1\n# angles: deg\n# time: gps-sow\ntime,range,alpha,intensity\n"
           "345601.508350,12.418,-134.875,1893\n345601.508368,12.402,-134.625,1901\n345602.2,30.0,-100.0,10\n")
    write(tmp_path, "scan.csv", raw)
    write(tmp_path, "traj.csv", TRAJ)
    for crs, name in (("EPSG:4326", "geo.las"), ("ecef", "ecef.las")):
        r = run("lidar", "georef", "--scan", tmp_path / "scan.csv", "--trajectory", tmp_path / "traj.csv", "--crs", crs,
                "-o", tmp_path / name)
        assert r.code == 0, r.out
    g, e = laspy.read(tmp_path / "geo.las"), laspy.read(tmp_path / "ecef.las")
    lon, lat, h = pyproj.Transformer.from_crs(4978, 4979, always_xy=True).transform(
        np.asarray(e.x), np.asarray(e.y), np.asarray(e.z))
    assert np.abs(np.asarray(g.x) - lon).max() < 2e-8 and np.abs(np.asarray(g.y) - lat).max() < 2e-8
    assert np.abs(np.asarray(g.z) - h).max() < 0.002


def test_las_writer_refuses_a_coarse_scale_on_degrees(tmp_path):
    from skyrig.errors import InputFormatError
    from skyrig.io.laz import write_las

    with pytest.raises(InputFormatError) as ei:
        write_las(tmp_path / "x.las", np.array([[9.0, 48.3, 300.0]]), "EPSG:4326", scale=0.001)
    assert "x.las" in str(ei.value) and "111 m on the ground" in str(ei.value)
