"""Bad inputs a user can make, file by file (issue 13): a table of named cases over every text reader.

Each case is a file a user could plausibly hand to skyrig (an Excel export with a BOM, a truncated copy, a
semicolon CSV, swapped columns, heights in millimetres, radians declared as degrees, a lever arm in
millimetres, a duplicated line, the wrong CRS code...) and the answer skyrig must give: an error naming
the file, the line and the field with the words that say what is wrong, a warning in words, or (for inputs
that are unusual but right: Windows line endings, a BOM, quoted names) a correct reading checked against
the values written into the file.

The good baseline files sit inside the areas of use of their CRSs (UTM 32N at 9 deg E 48.3 deg N,
Lambert-93 near Paris), so that every bad case differs from a good file by exactly one mistake.
"""

from __future__ import annotations

import re
import struct
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from skyrig.errors import InputFormatError, PlausibilityWarning, SkyrigError
from skyrig.georef.eo import WorldFrame

L93 = WorldFrame.map("EPSG:2154")
UTM = WorldFrame.map("EPSG:25832")

# --------------------------------------------------------------------------- good baselines
EO = """# skyrig-eo 1
# crs: EPSG:25832
# heights: ellipsoidal
# angles: deg
# convention: opk
image,camera,x,y,z,omega,phi,kappa
img1.tif,camera,500000.0,5350000.0,1200.0,0.1,-0.2,90.0
img2.tif,camera,500500.0,5350000.0,1200.0,0.1,-0.2,90.0
img3.tif,camera,501000.0,5350000.0,1200.0,0.1,-0.2,90.0
"""
PTS = """# crs: EPSG:25832
# heights: ellipsoidal
name,x,y,z
g1,500100.0,5350050.0,310.0
g2,500600.0,5349950.0,305.5
g3,500900.0,5350020.0,298.25
"""
MES = """point,image,column,row
g1,img1.tif,2010.5,1490.25
g2,img2.tif,1900.0,1600.0
g3,img3.tif,2100.0,1400.0
"""
TRAJ = """# skyrig-trajectory 1
# crs: EPSG:4979
# angles: deg
# time: gps-sow
time,lat,lon,h,roll,pitch,yaw
345600.000,48.30000,9.00000,1200.0,0.5,-1.2,87.3
345601.000,48.30000,9.00080,1200.1,0.5,-1.2,87.3
345602.000,48.30000,9.00160,1200.2,0.5,-1.2,87.3
"""
TRAJ_UTM = """# skyrig-trajectory 1
# crs: EPSG:32632
# angles: deg
# time: gps-sow
time,x,y,z,roll,pitch,yaw
345600.000,500000.0,5350000.0,1200.0,0.5,-1.2,87.3
345601.000,500060.0,5350000.0,1200.1,0.5,-1.2,87.3
345602.000,500120.0,5350000.0,1200.2,0.5,-1.2,87.3
"""
EVENTS = """# skyrig-events 1
# angles: deg
# time: gps-sow
image,time,head,beta,exposure
0001_nadir.jpg,345600.100000,nadir,,1
0001_oblique.jpg,345600.100000,oblique,-35.0,1
0002_nadir.jpg,345601.600000,nadir,,2
"""
RIG = """format: skyrig-rig
version: 1
name: uav-single
antenna_lever_arm_m: [0.0, 0.0, -0.1]
heads:
- name: camera
  camera:
    name: dji-fc300s
    width_px: 4000
    height_px: 3000
    pixel_size_um: 1.5425
    focal_mm: 3.61
    ppx_mm: 0.0
    ppy_mm: 0.0
    distortion: null
  lever_arm_m: [0.05, 0.0, 0.1]
  mounting_rpy_deg: [0.0, 0.0, 90.0]
  boresight_opk_deg: [0.0, 0.0, 0.0]
"""
OPK = ("NOM\tX\tY\tZ\tO\tP\tK\tCAMERA\n"
       "img_01     650000.000    6860000.000       2500.000     0.1     -0.2     90.0     cam1\n"
       "img_02     650500.000    6860000.000       2500.000     0.1     -0.2     90.0     cam1\n")
APP = '"1003" 13 650100.510 6860029.280 54.960\n"1005" 3 650470.940 6859965.400 52.630\n'
IMES = '"1003" img_01 2404.25 1478.17\n"1003" img_02 2412.2 1032.3\n"1005" img_01 2279.05 1437.27\n'
WMES = '"1003" 650100.510 6860029.280 54.960\n"1005" 650470.940 6859965.400 52.630\n'
CAM = "Name = cam1\nPPAx = 1999.5\nPPAy = 1499.5\nfocal = 4000\nwidth = 4000\nheight = 3000\n"
GCP = ("WGS84 UTM 32N\n"
       "500100.0 5350050.0 310.0 2010.5 1490.25 img1.jpg g1\n"
       "500100.0 5350050.0 310.0 1800.0 1300.00 img2.jpg g1\n"
       "500600.0 5349950.0 305.5 2200.0 1600.00 img2.jpg g2\n")
GEO = ("EPSG:4326\n"
       "img1.jpg 9.00000 48.30000 1200.0 87.3 -90.0 0.0\n"
       "img2.jpg 9.00080 48.30000 1200.1 87.3 -90.0 0.0\n")
RAW = """# skyrig-raw-scan 1
# angles: deg
# time: gps-sow
time,range,alpha,intensity
345600.008350,12.418,-134.875,1893
345600.008368,12.402,-134.625,1901
"""


def rep(text: str, old: str, new: str, count: int = 1) -> str:
    """``text`` with ``old`` replaced (``old`` must be there: a case that no longer differs is a broken case)."""
    assert old in text, f"{old!r} not in the baseline"
    return text.replace(old, new, count)


def line_of(text: str, needle: str) -> int:
    """1-based line of the first line containing ``needle``."""
    return next(i for i, s in enumerate(text.splitlines(), 1) if needle in s)


def _reader(kind: str) -> Callable[[Path], object]:
    from skyrig.io.eo_csv import read_eo_csv
    from skyrig.io.events_csv import read_events_csv
    from skyrig.io.ign import read_ign_camera, read_ign_ground_points, read_ign_measurements, read_ign_opk
    from skyrig.io.odm import read_gcp_list, read_geo_txt
    from skyrig.io.points_csv import read_measurements_csv, read_points_csv
    from skyrig.io.raw_scan_csv import read_raw_scan_csv
    from skyrig.io.rig_file import read_rig
    from skyrig.io.trajectory_csv import read_trajectory_csv

    return {
        "eo": read_eo_csv, "pts": read_points_csv, "mes": read_measurements_csv, "traj": read_trajectory_csv,
        "events": read_events_csv, "rig": read_rig, "opk": lambda p: read_ign_opk(p, L93),
        "app": lambda p: read_ign_ground_points(p, L93), "imes": read_ign_measurements, "cam": read_ign_camera,
        "gcp": read_gcp_list, "geo": read_geo_txt, "raw": read_raw_scan_csv,
        "pts-utm": lambda p: read_points_csv(p, UTM, option="--points-crs"),
    }[kind]


FILE_NAME = {"eo": "eo.csv", "pts": "gcp.csv", "pts-utm": "gcp.csv", "mes": "mes.csv", "traj": "traj.csv",
             "events": "events.csv", "rig": "rig.yaml", "opk": "block.OPK", "app": "gcp.app", "imes": "t.mes",
             "cam": "Camera1.txt", "gcp": "gcp_list.txt", "geo": "geo.txt", "raw": "scan.csv"}


@dataclass(frozen=True)
class Bad:
    """A file that must be refused: InputFormatError naming the file, ``line`` and ``field``, with ``words``."""

    name: str
    kind: str
    text: str | bytes
    line: int | None
    field: str | None
    words: str


@dataclass(frozen=True)
class Warn:
    """A file that is read, with a PlausibilityWarning containing ``words``."""

    name: str
    kind: str
    text: str
    words: str


@dataclass(frozen=True)
class Good:
    """An unusual but right file: read, and ``check`` holds on what was read."""

    name: str
    kind: str
    text: str | bytes
    check: Callable[[object], bool]


def _eo_last(text: str) -> int:
    return len(text.splitlines())


BAD: list[Bad] = [
    # ---- EO CSV
    Bad("eo-empty", "eo", "", 1, None, "first line must be '# skyrig-eo 1'"),
    Bad("eo-no-magic", "eo", EO.split("\n", 1)[1], 1, None, "first line must be"),
    Bad("eo-version-2", "eo", rep(EO, "skyrig-eo 1", "skyrig-eo 2"), 1, None, "unsupported skyrig-eo version '2'"),
    Bad("eo-missing-angles", "eo", rep(EO, "# angles: deg\n", ""), None, "angles", "missing header line"),
    Bad("eo-missing-crs", "eo", rep(EO, "# crs: EPSG:25832\n", ""), None, "crs", "missing header line"),
    Bad("eo-unknown-crs", "eo", rep(EO, "EPSG:25832", "EPSG:99999"), 2, "crs", "EPSG:99999"),
    Bad("eo-crs-typo", "eo", rep(EO, "EPSG:25832", "ESPG:25832"), 2, "crs", "ESPG:25832"),
    Bad("eo-angles-degrees-word", "eo", rep(EO, "angles: deg", "angles: degres"), 4, "angles", "degres"),
    Bad("eo-convention-xyz", "eo", rep(EO, "convention: opk", "convention: xyz"), 5, "convention",
        "convention must be opk, pok or ypr"),
    Bad("eo-orthometric-without-geoid", "eo", rep(EO, "heights: ellipsoidal", "heights: orthometric"), 2, "geoid",
        "orthometric heights need a '# geoid:' header line"),
    Bad("eo-unknown-geoid", "eo", rep(EO, "heights: ellipsoidal", "heights: orthometric\n# geoid: no_such_geoid.gtx"),
        2, "geoid", "no_such_geoid.gtx"),
    Bad("eo-heights-typo", "eo", rep(EO, "# heights:", "# hieghts:"), 3, "hieghts", "did you mean 'heights'?"),
    Bad("eo-geoid-typo", "eo", rep(EO, "# heights: ellipsoidal", "# heights: orthometric\n# geiod: egm96_15.gtx"), 4,
        "geiod", "did you mean 'geoid'?"),
    Bad("eo-height-singular-orthometric-no-geoid", "eo", rep(EO, "# heights: ellipsoidal", "# height: orthometric"), 2,
        "geoid", "orthometric heights need a '# geoid:' header line"),
    Bad("eo-heights-word", "eo", rep(EO, "heights: ellipsoidal", "heights: normal"), 2, "heights",
        "heights must be 'ellipsoidal' or 'orthometric'"),
    Bad("eo-no-header-row", "eo", EO.split("image,")[0], 5, None, "no column header row"),
    Bad("eo-header-only", "eo", EO.split("img1")[0], 6, None, "no data rows"),
    Bad("eo-semicolon", "eo", EO.replace(",", ";"), 6, "image;camera;x;y;z;omega;phi;kappa", "unknown column"),
    Bad("eo-unknown-column", "eo", rep(rep(EO, "kappa\n", "kappa,extra\n"), "90.0\n", "90.0,1\n", 3), 6, "extra",
        "unknown column 'extra'"),
    Bad("eo-missing-column", "eo", EO.replace(",kappa", "").replace(",90.0", ""), 6, "kappa", "missing column"),
    Bad("eo-short-row", "eo", rep(EO, "-0.2,90.0\nimg2", "-0.2\nimg2"), 7, None, "expected 8 fields, found 7"),
    Bad("eo-truncated", "eo", EO[:-12], 9, None, "expected 8 fields"),
    Bad("eo-decimal-comma", "eo", rep(EO, "1200.0,0.1", '"1200,0",0.1'), 7, "z", "'1200,0' is not a number"),
    Bad("eo-nan-x", "eo", rep(EO, "500500.0", "nan"), 8, "x", "not a finite number"),
    Bad("eo-inf-z", "eo", rep(EO, "1200.0,0.1,-0.2,90.0\nimg3", "inf,0.1,-0.2,90.0\nimg3"), 8, "z", "not a finite"),
    Bad("eo-empty-cell", "eo", rep(EO, "0.1,-0.2,90.0\nimg2", "0.1,,90.0\nimg2"), 7, "phi", "'' is not a number"),
    Bad("eo-radians-declared-gon", "eo", rep(EO, "90.0\nimg3", "900.0\nimg3"), 8, "kappa", "wrong unit?"),
    Bad("eo-degrees-declared-rad", "eo", rep(EO, "angles: deg", "angles: rad"), 7, "kappa", "wrong unit?"),
    Bad("eo-duplicate-image", "eo", EO + EO.splitlines()[-1] + "\n", 10, "image", "duplicate image 'img3.tif'"),
    Bad("eo-heights-mm", "eo", EO.replace("1200.0,", "1200000.0,"), 7, "z", "heights in millimetres (1200.000 m)"),
    Bad("eo-heights-cm", "eo", EO.replace("1200.0,", "120000.0,"), 7, "z", "or centimetres (1200.000 m)?"),
    Bad("eo-xy-swapped", "eo", "\n".join(
        ",".join([c[0], c[1], c[3], c[2], *c[4:]]) if c[0].startswith("img") else ",".join(c)
        for c in (ln.split(",") for ln in EO.splitlines())) + "\n", 7, "x", "are the columns x and y exchanged?"),
    Bad("eo-geographic-latlon-swapped", "eo", rep(EO, "EPSG:25832", "EPSG:4326").replace(
        "500000.0,5350000.0", "48.3,209.0").replace("500500.0,5350000.0", "48.3,209.01").replace(
        "501000.0,5350000.0", "48.3,209.02"), 7, "y", "latitude 209 beyond +-90"),
    Bad("eo-ecef-given-latlon", "eo", rep(EO, "EPSG:25832", "EPSG:4978").replace(
        "500000.0,5350000.0", "48.3,9.0").replace("500500.0,5350000.0", "48.3,9.01").replace(
        "501000.0,5350000.0", "48.3,9.02"), 7, "x", "not geocentric coordinates in metres"),
    Bad("eo-bad-exposure", "eo", rep(EO, "kappa\n", "kappa,exposure\n").replace("90.0\nimg2", "90.0,1\nimg2")
        .replace("90.0\nimg3", "90.0,2a\nimg3").replace("90.0\n", "90.0,3\n"), 8, "exposure",
        "exposure must be an integer"),
    Bad("eo-local-frame-bad", "eo", rep(EO, "EPSG:25832", "local 48.3 9.0"), 2, "crs", "expected 'local <lat_deg>"),
    Bad("eo-latin1", "eo", rep(EO, "img1.tif", "bild_ü.tif").encode("latin-1"), 7, None, "not a UTF-8 text file"),
    Bad("eo-is-binary", "eo", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe", 1, None, "not a UTF-8 text file"),
    # ---- points CSV
    Bad("pts-empty", "pts", "", 0, None, "no column header row"),
    Bad("pts-no-crs", "pts", PTS.split("\n", 2)[2], 1, "crs", "no '# crs:' header line"),
    Bad("pts-heights-without-crs", "pts", PTS.split("\n", 1)[1], 1, "heights", "'# heights:' without a '# crs:' line"),
    Bad("pts-heights-typo", "pts", rep(PTS, "# heights:", "# hieghts:"), 2, "hieghts", "did you mean 'heights'?"),
    Bad("pts-geoid-typo", "pts", rep(PTS, "# heights: ellipsoidal", "# heights: orthometric\n# goid: egm96_15.gtx"),
        3, "goid", "did you mean 'geoid'?"),
    Bad("pts-orthometric-no-geoid", "pts", rep(PTS, "ellipsoidal", "orthometric"), 1, "geoid",
        "orthometric heights need a '# geoid:' header line"),
    Bad("pts-unknown-crs", "pts", rep(PTS, "EPSG:25832", "EPSG:0"), 1, "crs", "EPSG:0"),
    Bad("pts-missing-z", "pts", "\n".join(ln.rsplit(",", 1)[0] for ln in PTS.splitlines()) + "\n", 3, "z",
        "missing column"),
    Bad("pts-unknown-column", "pts", rep(PTS, "name,x,y,z", "name,x,y,z,colour"), 3, "colour", "unknown column 'colour'"),
    Bad("pts-short-row", "pts", rep(PTS, ",305.5", ""), 5, None, "expected 4 fields, found 3"),
    Bad("pts-semicolon", "pts", PTS.replace(",", ";"), 3, "name", "missing column"),
    Bad("pts-tab-separated", "pts", PTS.replace(",", "\t"), 3, "name", "missing column"),
    Bad("pts-decimal-comma", "pts", rep(PTS, "305.5", '"305,5"'), 5, "z", "'305,5' is not a number"),
    Bad("pts-nan", "pts", rep(PTS, "298.25", "NaN"), 6, "z", "not a finite number"),
    Bad("pts-text-in-x", "pts", rep(PTS, "500600.0", "5OO6OO.0"), 5, "x", "is not a number"),
    Bad("pts-duplicate-name", "pts", PTS + "g2,500650.0,5349960.0,306.0\n", 7, "name",
        "point 'g2' appears twice (first on line 5)"),
    Bad("pts-empty-name", "pts", rep(PTS, "g3,", ","), 6, "name", "empty point name"),
    Bad("pts-heights-mm", "pts", PTS.replace(",310.0", ",310000.0").replace(",305.5", ",305500.0").replace(
        ",298.25", ",298250.0"), 4, "z", "heights in millimetres (310.000 m)"),
    Bad("pts-heights-feet-absurd", "pts", rep(PTS, ",310.0", ",31000.0"), 4, "z", "not plausible as a ground height"),
    Bad("pts-below-dead-sea", "pts", rep(PTS, ",310.0", ",-2500.0"), 4, "z", "not plausible as a ground height"),
    Bad("pts-xy-swapped", "pts", "\n".join(
        ",".join([c[0], c[2], c[1], c[3]]) if c[0].startswith("g") else ",".join(c)
        for c in (ln.split(",") for ln in PTS.splitlines())) + "\n", 4, "x", "x (easting) and y (northing) swapped"),
    Bad("pts-latlon-swapped", "pts", "# crs: EPSG:4326\nname,x,y,z\ng1,35.68,139.76,40\ng2,35.69,139.77,41\n", 3, "y",
        "longitude and latitude swapped"),
    Bad("pts-lat-beyond-90", "pts", "# crs: EPSG:4326\nname,x,y,z\ng1,9.0,98.3,310\n", 3, "y", "beyond +-90"),
    Bad("pts-other-crs-than-option", "pts-utm", rep(PTS, "EPSG:25832", "EPSG:2154").replace(
        "500100.0,5350050.0", "650100.0,6860050.0").replace("500600.0,5349950.0", "650600.0,6859950.0").replace(
        "500900.0,5350020.0", "650900.0,6860020.0"), 1, "crs", "but --points-crs says"),
    Bad("pts-sidecar-broken", "pts", PTS.split("\n", 2)[2], 1, None, "not valid JSON"),
    # ---- measurements CSV
    Bad("mes-empty", "mes", "", 0, None, "no column header row"),
    Bad("mes-missing-row-column", "mes", rep(MES, "point,image,column,row", "point,image,column,line"), 1, "row",
        "missing column"),
    Bad("mes-x-y-names", "mes", rep(MES, "point,image,column,row", "point,image,x_px,y_px"), 1, "column",
        "missing column"),
    Bad("mes-short-row", "mes", rep(MES, ",1600.0", ""), 3, None, "expected 4 fields, found 3"),
    Bad("mes-nan", "mes", rep(MES, "1600.0", "nan"), 3, "row", "not a finite number"),
    Bad("mes-duplicate-measurement", "mes", MES + "g2,img2.tif,1901.0,1601.0\n", 5, "point",
        "point 'g2' is measured twice in image 'img2.tif' (first on line 3)"),
    Bad("mes-empty-image", "mes", rep(MES, "img3.tif", ""), 4, "image", "empty image name"),
    Bad("mes-semicolon", "mes", MES.replace(",", ";"), 1, "point", "missing column"),
    # ---- trajectory CSV
    Bad("traj-empty", "traj", "", 1, "skyrig-trajectory", "empty file"),
    Bad("traj-no-magic", "traj", TRAJ.split("\n", 1)[1], 1, "skyrig-trajectory", "first line must be"),
    Bad("traj-unknown-key", "traj", rep(TRAJ, "# angles: deg", "# angle: deg"), 3, "angle", "unknown header key 'angle'"),
    Bad("traj-no-angles", "traj", rep(TRAJ, "# angles: deg\n", ""), 4, "angles", "header key 'angles'"),
    Bad("traj-key-twice", "traj", rep(TRAJ, "# time: gps-sow", "# time: gps-sow\n# time: gps-sow"), 5, "time",
        "repeated"),
    Bad("traj-unknown-time", "traj", rep(TRAJ, "gps-sow", "gpst"), 4, "time", "unknown time system 'gpst'"),
    Bad("traj-compound-crs", "traj", rep(TRAJ, "EPSG:4979", "EPSG:25832+5783"), 2, "crs", "give the horizontal CRS only"),
    Bad("traj-orthometric-no-geoid", "traj", rep(TRAJ, "# angles", "# height: orthometric\n# angles"), 3, "geoid",
        "orthometric heights need a 'geoid:' header"),
    Bad("traj-geoid-but-ellipsoidal", "traj", rep(TRAJ, "# angles", "# geoid: egm96_15.gtx\n# angles"), 3, "geoid",
        "a geoid is given but heights are declared ellipsoidal"),
    Bad("traj-unknown-geoid", "traj", rep(TRAJ, "# angles", "# height: orthometric\n# geoid: nowhere.gtx\n# angles"),
        4, "geoid", "nowhere.gtx"),
    Bad("traj-xyz-columns-geographic", "traj", rep(TRAJ, "time,lat,lon,h", "time,x,y,z"), 5, "x", "unknown column 'x'"),
    Bad("traj-one-record", "traj", TRAJ.rsplit("\n", 3)[0] + "\n", 6, None, "at least 2 records, found 1"),
    Bad("traj-time-decreasing", "traj", rep(TRAJ, "345602.000", "345600.500"), 8, "time", "345600.5"),
    Bad("traj-time-repeated", "traj", rep(TRAJ, "345601.000", "345600.000"), 7, "time", "345600"),
    Bad("traj-radians-declared", "traj", rep(TRAJ, "angles: deg", "angles: rad"), 6, "yaw", "declared 'angles: rad'"),
    Bad("traj-nan-roll", "traj", rep(TRAJ, "1200.1,0.5", "1200.1,nan"), 7, "roll", "not a finite number"),
    Bad("traj-short-row", "traj", rep(TRAJ, ",87.3\n345602", "\n345602"), 7, None, "expected 7 values, found 6"),
    Bad("traj-semicolon", "traj", TRAJ.replace(",", ";"), 5, "time;lat;lon;h;roll;pitch;yaw", "unknown column"),
    Bad("traj-lat-lon-swapped", "traj", TRAJ.replace("48.30000,9.00", "139.76000,35.68"), 6, "lat",
        "longitude and latitude swapped"),
    Bad("traj-heights-mm", "traj", TRAJ.replace(",1200.", ",1200000."), 6, "h", "heights in millimetres (1200.000 m)"),
    Bad("traj-utm-xy-swapped", "traj", TRAJ_UTM.replace("500000.0,5350000.0", "5350000.0,500000.0").replace(
        "500060.0,5350000.0", "5350000.0,500060.0").replace("500120.0,5350000.0", "5350000.0,500120.0"), 6, "x",
        "are the columns x and y exchanged?"),
    Bad("traj-negative-sigma", "traj", rep(rep(TRAJ, "yaw\n", "yaw,sx,sy,sz\n"), "87.3\n", "87.3,0.1,0.1,-0.2\n", 3),
        6, "sz", "standard deviation -0.2 is negative"),
    Bad("traj-partial-sigma-group", "traj", rep(rep(TRAJ, "yaw\n", "yaw,sx,sy\n"), "87.3\n", "87.3,0.1,0.1\n", 3),
        5, "sz", "columns sx, sy, sz go together"),
    Bad("traj-week-without-column", "traj", rep(TRAJ, "gps-sow", "gps-week-sow"), 5, "week",
        "required column 'week' is missing"),
    # ---- events CSV
    Bad("events-empty", "events", "", 1, "skyrig-events", "empty file"),
    Bad("events-no-head-column", "events", EVENTS.replace(",head", "").replace(",nadir", "").replace(",oblique", ""),
        4, "head", "required column 'head' is missing"),
    Bad("events-duplicate-image", "events", EVENTS + "0002_nadir.jpg,345602.100000,nadir,,3\n", 8, "image", "0002_nadir.jpg"),
    Bad("events-nan-beta", "events", rep(EVENTS, "-35.0", "nan"), 6, "beta", "not a finite number"),
    Bad("events-beta-no-unit", "events", rep(EVENTS, "# angles: deg\n", ""), 3, "angles", "angles"),
    Bad("events-beta-rad-declared", "events", rep(rep(EVENTS, "angles: deg", "angles: rad"), "-35.0", "-350.0"), 6,
        "beta", "declared 'angles: rad'"),
    Bad("events-exposure-text", "events", rep(EVENTS, ",,2\n", ",,two\n"), 7, "exposure", "'two' is not an integer"),
    Bad("events-exposure-huge", "events", rep(EVENTS, ",,2\n", ",,99999999999999999999999\n"), 7, "exposure",
        "too large"),  # found by the fuzz (was an OverflowError traceback)
    Bad("events-empty-head", "events", rep(EVENTS, ",nadir,,2", ",,,2"), 7, "head", "empty head name"),
    Bad("events-time-text", "events", rep(EVENTS, "345601.600000", "12:00:01.6"), 7, "time", "is not a number"),
    Bad("events-short-row", "events", rep(EVENTS, ",,2\n", ",2\n"), 7, None, "expected 5 values, found 4"),
    Bad("events-semicolon", "events", EVENTS.replace(",", ";"), 4, "image;time;head;beta;exposure", "unknown column"),
    # ---- rig file
    Bad("rig-empty", "rig", "", 1, None, "a rig file is a YAML mapping"),
    Bad("rig-not-yaml", "rig", "format: skyrig-rig\nheads: [\n", 3, None, "not valid YAML"),
    Bad("rig-tab-indent", "rig", rep(RIG, "  lever_arm_m", "\tlever_arm_m"), 16, None, "not valid YAML"),
    Bad("rig-wrong-format", "rig", rep(RIG, "skyrig-rig", "skyrig-eo"), 1, "format", "expected 'skyrig-rig'"),
    Bad("rig-no-heads", "rig", RIG.split("heads:")[0], 1, "heads", "missing key 'heads'"),
    Bad("rig-lever-arm-mm", "rig", rep(RIG, "[0.05, 0.0, 0.1]", "[50.0, 0.0, 100.0]"), 16, "heads[0].lever_arm_m",
        "millimetres (0.112 m) or centimetres (1.118 m)?"),
    Bad("rig-lever-arm-100m", "rig", rep(RIG, "[0.05, 0.0, 0.1]", "[100.0, 0.0, 0.0]"), 16, "heads[0].lever_arm_m",
        "lever arm of 100 m is not plausible"),
    Bad("rig-antenna-arm-cm", "rig", rep(RIG, "[0.0, 0.0, -0.1]", "[0.0, 0.0, -120.0]"), 4, "antenna_lever_arm_m",
        "centimetres (1.200 m)?"),
    Bad("rig-lever-two-values", "rig", rep(RIG, "[0.05, 0.0, 0.1]", "[0.05, 0.1]"), 16, "heads[0].lever_arm_m",
        "expected shape (3,)"),
    Bad("rig-lever-text", "rig", rep(RIG, "[0.05, 0.0, 0.1]", "'0.05 0 0.1'"), 16, "heads[0].lever_arm_m",
        "expected a list of numbers"),
    Bad("rig-negative-focal", "rig", rep(RIG, "focal_mm: 3.61", "focal_mm: -3.61"), 12, "heads[0].camera.focal_mm",
        "must be positive"),
    Bad("rig-focal-key-typo", "rig", rep(RIG, "focal_mm", "focal_length_mm"), 12, "heads[0].camera.focal_length_mm",
        "unknown key 'focal_length_mm'"),
    Bad("rig-duplicate-key", "rig", rep(RIG, "  lever_arm_m: [0.05, 0.0, 0.1]\n",
                                        "  lever_arm_m: [0.05, 0.0, 0.1]\n  lever_arm_m: [0.0, 0.0, 0.0]\n"), 17, None,
        "duplicate key 'lever_arm_m'"),
    Bad("rig-width-float", "rig", rep(RIG, "width_px: 4000", "width_px: 4000.5"), 9, "heads[0].camera.width_px",
        "expected a positive integer"),
    Bad("rig-nan-boresight", "rig", rep(RIG, "boresight_opk_deg: [0.0, 0.0, 0.0]", "boresight_opk_deg: [.nan, 0.0, 0.0]"),
        18, "heads[0].boresight_opk_deg", "values must be finite numbers"),
    # ---- IGN
    Bad("opk-empty", "opk", "", None, None, "empty OPK file"),
    Bad("opk-comma-separated", "opk", re.sub(r"[ \t]+", ",", OPK), 1, None, "header must be NOM X Y Z O P K CAMERA"),
    Bad("opk-missing-camera", "opk", OPK.replace("     cam1", ""), 2, "CAMERA", "expected 8 fields, found 7"),
    Bad("opk-decimal-comma", "opk", rep(OPK, "2500.000", "2500,000"), 2, "Z", "'2500,000' is not a number"),
    Bad("opk-gon-as-degrees", "opk", rep(OPK, "90.0     cam1", "400.5     cam1"), 2, "K", "wrong unit?"),
    Bad("opk-heights-mm", "opk", OPK.replace("2500.000", "2500000.000"), 2, "Z", "heights in millimetres (2500.000 m)"),
    Bad("opk-xy-swapped", "opk", OPK.replace("650000.000    6860000.000", "6860000.000    650000.000").replace(
        "650500.000    6860000.000", "6860000.000    650500.000"), 2, "X", "swapped"),
    Bad("app-xy-swapped", "app", APP.replace("650100.510 6860029.280", "6860029.280 650100.510").replace(
        "650470.940 6859965.400", "6859965.400 650470.940"), 1, "X", "swapped"),
    Bad("app-heights-mm", "app", APP.replace("54.960", "54960.0").replace("52.630", "52630.0"), 1, "Z",
        "heights in millimetres (54.960 m)"),
    Bad("app-type-text", "app", rep(APP, '" 13 ', '" GCP '), 1, "type", "'GCP' is not a number"),
    Bad("app-type-huge", "app", rep(APP, '" 13 ', '" 999999999999999999999999999999 '), 1, "type",
        "not a small whole number"),  # found by the fuzz (was an OverflowError traceback)
    Bad("app-type-fraction", "app", rep(APP, '" 13 ', '" 1.5 '), 1, "type", "not a small whole number"),
    Bad("imes-nan", "imes", rep(IMES, "1032.3", "nan"), 2, "row", "not a finite number"),
    Bad("imes-three-fields", "imes", rep(IMES, " 1032.3", ""), 2, None, "expected 4 fields"),
    Bad("wmes-heights-mm", "app", WMES.replace("54.960", "54960.0").replace("52.630", "52630.0"), 1, "Z",
        "millimetres"),
    Bad("cam-missing-focal", "cam", rep(CAM, "focal = 4000\n", ""), None, "focal", "missing key"),
    Bad("cam-colon-not-equals", "cam", rep(CAM, "focal = 4000", "focal: 4000"), 4, None, "expected 'key = value'"),
    Bad("cam-focal-text", "cam", rep(CAM, "focal = 4000", "focal = 4000px"), 4, "focal", "'4000px' is not a number"),
    Bad("cam-empty", "cam", "", None, "name", "missing key"),
    Bad("cam-focal-zero", "cam", rep(CAM, "focal = 4000", "focal = 000"), 4, "focal", "must be positive"),  # fuzz find
    Bad("cam-width-fraction", "cam", rep(CAM, "width = 4000", "width = 4000.5"), 5, "width", "whole number of pixels"),
    # ---- ODM
    Bad("gcp-empty", "gcp", "", 1, "projection", "the first line must name the projection"),
    Bad("gcp-no-projection-line", "gcp", GCP.split("\n", 1)[1], 1, "projection", "unknown coordinate reference system"),
    Bad("gcp-unknown-utm-zone", "gcp", rep(GCP, "WGS84 UTM 32N", "WGS84 UTM 32X"), 1, "projection",
        "unknown coordinate reference system"),
    Bad("gcp-five-fields", "gcp", rep(GCP, " img2.jpg g2", ""), 4, None, "expected at least 6 fields, found 5"),
    Bad("gcp-nan-z", "gcp", rep(GCP, "305.5", "nan"), 4, "geo_z", "not a finite number"),
    Bad("gcp-same-name-other-xyz", "gcp", GCP + "500101.5 5350050.0 310.0 1500.0 1200.0 img3.jpg g1\n", 5, "geo_x",
        "GCP 'g1' has other coordinates on line 2"),
    Bad("gcp-heights-mm", "gcp", GCP.replace("310.0", "310000.0").replace("305.5", "305500.0"), 2, "geo_z",
        "millimetres"),
    Bad("gcp-xy-swapped", "gcp", GCP.replace("500100.0 5350050.0", "5350050.0 500100.0").replace(
        "500600.0 5349950.0", "5349950.0 500600.0"), 2, "geo_x", "swapped"),
    Bad("gcp-wgs84-latlon-swapped", "gcp", "WGS84\n35.68 139.76 40.0 2010.5 1490.25 img1.jpg g1\n"
        "35.69 139.77 41.5 2200.0 1600.0 img2.jpg g2\n", 2, "geo_y", "longitude and latitude swapped"),
    Bad("geo-latlon-swapped", "geo", GEO.replace("9.00000 48.30000", "35.68 139.76").replace(
        "9.00080 48.30000", "35.68 139.77"), 2, "geo_y", "longitude and latitude swapped"),
    Bad("geo-duplicate-image", "geo", GEO + "img1.jpg 9.00160 48.30000 1200.2 87.3 -90.0 0.0\n", 4, "image_name",
        "image 'img1.jpg' appears twice (first on line 2)"),
    Bad("geo-two-fields", "geo", GEO + "img3.jpg 9.0016\n", 4, None, "expected at least 3 fields, found 2"),
    Bad("geo-altitude-mm", "geo", GEO.replace("1200.0", "1200000.0").replace("1200.1", "1200100.0"), 2, "geo_z",
        "millimetres"),
    # ---- raw laser scan
    Bad("raw-empty", "raw", "", 1, None, "skyrig-raw-scan"),
    Bad("raw-negative-range", "raw", rep(RAW, "12.402", "-12.402"), 6, "range", "range"),
    Bad("raw-time-decreasing", "raw", rep(RAW, "345600.008368", "345600.008300"), 6, "time", "time"),
    Bad("raw-nan-alpha", "raw", rep(RAW, "-134.625", "nan"), 6, "alpha", "finite"),
    # issue 29: every position far (> 5 deg) outside the stated CRS's area of use: refused, not a warning
    Bad("eo-utm-declared-lambert93", "eo", rep(EO, "EPSG:25832", "EPSG:2154"), 7, "x",
        "latitude 35.2778 deg in RGF93 v1 / Lambert-93 (EPSG:2154), used for France"),
    Bad("pts-gauss-krueger-without-zone-prefix", "pts", rep(PTS, "EPSG:25832", "EPSG:31467"), 4, "x",
        "outside that CRS's area of use"),
    Bad("traj-utm-declared-lambert93", "traj", rep(TRAJ_UTM, "EPSG:32632", "EPSG:2154"), 6, "x",
        "more than 5 deg outside"),
]

# a block in radians (strips both ways: kappa about 0 and pi) whose header says degrees
EO_RAD = EO.split("img1")[0] + "".join(
    f"img{k}.tif,camera,{500000.0 + 300 * (k % 3)},{5350000.0 + 400 * (k // 3)},1200.0,{0.002 * k:.3f},-0.004,"
    f"{0.01 if k // 3 % 2 == 0 else 3.13}\n" for k in range(6))
TRAJ_RAD = TRAJ.split("345600.000")[0] + "".join(
    f"{345600.0 + k:.3f},48.30000,{9.0 + 0.0008 * k:.5f},1200.0,0.01,-0.02,{1.57 if k < 3 else -1.57}\n"
    for k in range(6))

WARN: list[Warn] = [
    Warn("eo-radians-declared-degrees", "eo", EO_RAD, "radians meant?"),
    Warn("traj-radians-declared-degrees", "traj", TRAJ_RAD, "radians meant?"),
    Warn("eo-lambert93-3-deg-south-of-france", "eo", rep(rep(rep(EO.replace("5350000.0", "5653367.0"), "EPSG:25832",
                                                                "EPSG:2154"), "500000.0,", "700000.0,"), "500500.0,",
                                                        "700500.0,"), "outside the area of use of RGF93 v1 / Lambert-93"),
    Warn("rig-lever-arm-20m", "rig", rep(RIG, "[0.05, 0.0, 0.1]", "[20.0, 0.0, 0.0]"), "lever arm of 20 m is unusually long"),
]


def _close(a, b, tol=1e-9) -> bool:
    return bool(np.allclose(np.asarray(a, float), np.asarray(b, float), rtol=0, atol=tol))


GOOD: list[Good] = [
    Good("eo-degrees-steady-one-heading", "eo", EO_RAD.replace(",3.13\n", ",0.5\n"), lambda e: len(e) == 6),
    Good("eo-radians-declared-rad", "eo", rep(EO_RAD, "angles: deg", "angles: rad"), lambda e: len(e) == 6),
    Good("eo-windows-line-ends", "eo", EO.replace("\n", "\r\n"), lambda e: _close(e.centre[1], [500500, 5350000, 1200])),
    Good("eo-bom", "eo", "\ufeff" + EO, lambda e: e.image.tolist() == ["img1.tif", "img2.tif", "img3.tif"]),
    Good("eo-bom-crlf", "eo", ("\ufeff" + EO).replace("\n", "\r\n"), lambda e: len(e) == 3),
    Good("eo-blank-lines-and-trailing-spaces", "eo", EO.replace("\nimg2", "\n\n  \nimg2").replace("90.0\n", "90.0  \n"),
         lambda e: len(e) == 3 and _close(e.centre[2, 2], 1200.0)),
    Good("eo-quoted-names", "eo", rep(EO, "img1.tif,camera", '"img 1, left.tif",camera'),
         lambda e: e.image[0] == "img 1, left.tif"),
    Good("eo-no-trailing-newline", "eo", EO.rstrip("\n"), lambda e: len(e) == 3),
    Good("pts-crlf-bom", "pts", ("\ufeff" + PTS).replace("\n", "\r\n"), lambda g: _close(g.xyz[2], [500900, 5350020, 298.25])),
    Good("pts-height-singular-key", "pts", rep(PTS, "# heights:", "# height:"), lambda g: g.frame.heights == "ellipsoidal"),
    Good("pts-comment-line", "pts", "# ground control, survey of 2024-05-02\n" + PTS, lambda g: len(g) == 3),
    Good("pts-same-crs-as-option", "pts-utm", PTS, lambda g: _close(g.xyz[0], [500100, 5350050, 310])),
    Good("pts-no-crs-takes-option", "pts-utm", PTS.split("\n", 2)[2], lambda g: str(g.frame.crs) == "EPSG:25832"),
    Good("mes-crlf", "mes", MES.replace("\n", "\r\n"), lambda m: _close(m.pixel[0], [2010.5, 1490.25])),
    Good("traj-crlf-bom", "traj", ("\ufeff" + TRAJ).replace("\n", "\r\n"), lambda t: len(t.time_s) == 3),
    Good("traj-utm", "traj", TRAJ_UTM, lambda t: len(t.time_s) == 3),
    Good("events-crlf", "events", EVENTS.replace("\n", "\r\n"), lambda e: len(e) == 3),
    Good("rig-crlf-bom", "rig", ("\ufeff" + RIG).replace("\n", "\r\n"), lambda r: _close(r.heads["camera"].lever_arm_m, [0.05, 0, 0.1])),
    Good("opk-crlf", "opk", OPK.replace("\n", "\r\n"), lambda e: _close(e.centre[1], [650500, 6860000, 2500])),
    Good("app-bom", "app", "\ufeff" + APP, lambda g: g.name.tolist() == ["1003", "1005"]),
    Good("cam-crlf", "cam", CAM.replace("\n", "\r\n"), lambda c: c.width == 4000),
    Good("gcp-crlf", "gcp", GCP.replace("\n", "\r\n"), lambda r: len(r[0]) == 2 and len(r[1]) == 3),
    Good("geo-bom", "geo", "\ufeff" + GEO, lambda g: _close(g.xyz[1], [9.0008, 48.3, 1200.1])),
]


def _write(tmp_path: Path, kind: str, text: str | bytes) -> Path:
    p = tmp_path / FILE_NAME[kind]
    if isinstance(text, bytes):
        p.write_bytes(text)
    else:
        p.write_bytes(text.encode("utf-8"))  # no newline translation: CRLF cases stay CRLF
    return p


def _clean(msg: str) -> None:
    assert "Traceback" not in msg and "np." not in msg and "array(" not in msg and "float64" not in msg


@pytest.mark.parametrize("case", BAD, ids=[c.name for c in BAD])
def test_bad_file_is_refused_naming_file_line_field(tmp_path, case: Bad):
    p = _write(tmp_path, case.kind, case.text)
    if case.name == "pts-sidecar-broken":
        (tmp_path / "gcp.csv.json").write_text('{"format": "skyrig-table", ')
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PlausibilityWarning)
        with pytest.raises(InputFormatError) as ei:
            _reader(case.kind)(p)
    e = ei.value
    msg = str(e)
    assert Path(e.path).name.startswith(p.name), msg
    assert e.line == case.line, msg
    assert e.field == case.field, msg
    assert case.words in msg, msg
    _clean(msg)


@pytest.mark.parametrize("case", WARN, ids=[c.name for c in WARN])
def test_unusual_file_is_read_with_a_warning_in_words(tmp_path, case: Warn):
    p = _write(tmp_path, case.kind, case.text)
    with pytest.warns(PlausibilityWarning) as rec:
        _reader(case.kind)(p)
    text = " | ".join(str(w.message) for w in rec)
    assert case.words in text and p.name in text, text
    _clean(text)


@pytest.mark.parametrize("case", GOOD, ids=[c.name for c in GOOD])
def test_unusual_but_right_file_is_read_right(tmp_path, case: Good):
    p = _write(tmp_path, case.kind, case.text)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PlausibilityWarning)  # a right file gets no warning either
        got = _reader(case.kind)(p)
    assert case.check(got)


def test_baselines_are_good(tmp_path):
    """Every bad case is one mistake away from a file that reads without a word."""
    for kind, text in (("eo", EO), ("pts", PTS), ("mes", MES), ("traj", TRAJ), ("events", EVENTS), ("rig", RIG),
                       ("opk", OPK), ("app", APP), ("imes", IMES), ("cam", CAM), ("gcp", GCP), ("geo", GEO),
                       ("raw", RAW)):
        with warnings.catch_warnings():
            warnings.simplefilter("error", PlausibilityWarning)
            _reader(kind)(_write(tmp_path, kind, text))


def test_skyrig_points_output_with_an_outlier_is_read_with_a_warning(tmp_path):
    """Adjusted points skyrig wrote (side-car) may hold a wild tie point: warned, not refused; a unit error (every
    height) still is."""
    from skyrig.io.points_csv import read_points_csv, write_points_csv
    from skyrig.georef.observations import GroundPoints

    xyz = np.array([[500100.0, 5350050.0, 310.0], [500600.0, 5349950.0, 25000.0], [500900.0, 5350020.0, 298.25]])
    write_points_csv(tmp_path / "points.csv", GroundPoints(np.array(["t1", "t2", "t3"]), xyz, UTM))
    with pytest.warns(PlausibilityWarning, match="1 of 3 heights not plausible"):
        g = read_points_csv(tmp_path / "points.csv")
    assert np.array_equal(g.xyz, xyz)
    xyz[1, 2] = 305.5
    write_points_csv(tmp_path / "points.csv", GroundPoints(np.array(["t1", "t2", "t3"]), xyz * [1, 1, 1000], UTM))
    with pytest.raises(InputFormatError, match=r"millimetres \(310.000 m\)"):
        read_points_csv(tmp_path / "points.csv")


def test_binary_readers_name_the_file(tmp_path):
    """SBET and BAL: a truncated or text file is a clear error naming the file (record / line)."""
    from skyrig.io.bal import read_bal
    from skyrig.io.sbet import read_sbet

    sbet = tmp_path / "traj.out"
    sbet.write_bytes(struct.pack("<17d", *range(17)) + b"\x00" * 50)
    with pytest.raises(SkyrigError) as ei:
        read_sbet(sbet)
    assert "traj.out" in str(ei.value) and "136" in str(ei.value)
    bal = tmp_path / "problem.txt"
    bal.write_text("2 3 4\n0 0 1.0 2.0\n")
    with pytest.raises(InputFormatError) as ei:
        read_bal(bal)
    assert "problem.txt" in str(ei.value)


def test_case_names_are_unique():
    names = [c.name for c in BAD] + [c.name for c in WARN] + [c.name for c in GOOD]
    assert len(names) == len(set(names))


def _dem_file(path: Path, heights: np.ndarray, crs: str | None = "EPSG:25832", nodata: float | None = None) -> Path:
    import rasterio
    from affine import Affine

    prof = dict(driver="GTiff", width=heights.shape[1], height=heights.shape[0], count=1, dtype="float32",
                transform=Affine(10.0, 0.0, 500000.0, 0.0, -10.0, 5350200.0))
    if crs:
        prof["crs"] = crs
    if nodata is not None:
        prof["nodata"] = nodata
    with rasterio.open(path, "w", **prof) as ds:
        ds.write(heights.astype(np.float32), 1)
    return path


_H = 300.0 + np.add.outer(np.arange(20.0), np.arange(30.0)) * 0.25  # a tilted plane, 20 x 30 cells


@pytest.mark.parametrize("name, heights, kw, crs, words, field", [
    ("dem-band-2", _H, {"band": 2}, "EPSG:25832", "band 2 does not exist (the raster has 1)", "band"),
    ("dem-no-crs", _H, {}, None, "raster has no CRS", "crs"),
    ("dem-other-crs-given", _H, {"crs": "EPSG:2154"}, "EPSG:25832", "not in the CRS given (EPSG:2154)", "crs"),
    ("dem-heights-cm", _H * 100, {}, "EPSG:25832", "centimetres", "height"),
    ("dem-heights-mm", _H * 1000, {}, "EPSG:25832", "millimetres", "height"),
], ids=lambda v: v if isinstance(v, str) and v.startswith("dem-") else "")
def test_bad_dem(tmp_path, name, heights, kw, crs, words, field):
    from skyrig.io.dem import read_dem

    p = _dem_file(tmp_path / "dem.tif", heights, crs)
    with pytest.raises(InputFormatError) as ei:
        read_dem(p, **kw)
    assert ei.value.path == str(p) and ei.value.field == field and words in str(ei.value), str(ei.value)


def test_dem_undeclared_nodata_left_out_with_a_warning(tmp_path):
    from skyrig.io.dem import read_dem

    h = _H.copy()
    h[:3, :4] = -9999.0
    with pytest.warns(PlausibilityWarning, match="12 cells hold -9999"):
        dem = read_dem(_dem_file(tmp_path / "dem.tif", h))
    assert np.isnan(dem.heights[:3, :4]).all() and np.allclose(dem.heights[3:], _H[3:].astype(np.float32))


def test_dem_declared_nodata_and_same_crs_read_silently(tmp_path):
    from skyrig.io.dem import read_dem

    h = _H.copy()
    h[0, 0] = -9999.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", PlausibilityWarning)
        dem = read_dem(_dem_file(tmp_path / "dem.tif", h, nodata=-9999.0), crs="EPSG:25832")
    assert np.isnan(dem.heights[0, 0]) and dem.heights[5, 7] == np.float32(_H[5, 7])
