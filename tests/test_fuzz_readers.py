"""Hypothesis fuzz of every text reader and of the main commands (issue 13): good files mutated the ways files
get damaged (a slice cut out, text typed in, a line doubled or moved, a number replaced by something else, the
file cut short, line endings and separators changed).  Whatever comes in, a reader either reads it or raises a
:class:`~skyrig.errors.SkyrigError` (never a TypeError, IndexError, KeyError, a PROJ or numpy error), and a command
exits 0, 1 or 2 without a traceback.  Bounded: 6 to 20 examples per reader or command, no deadline (the 2-core machine is
shared), the whole file in well under a minute.
"""

from __future__ import annotations

import re
import sys
import warnings
from pathlib import Path

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
import test_bad_input_readers as base  # noqa: E402

from skyrig.errors import SkyrigError  # noqa: E402

GOOD = {"eo": base.EO, "pts": base.PTS, "mes": base.MES, "traj": base.TRAJ, "events": base.EVENTS, "rig": base.RIG,
        "opk": base.OPK, "app": base.APP, "imes": base.IMES, "cam": base.CAM, "gcp": base.GCP, "geo": base.GEO,
        "raw": base.RAW}

NOISE = st.text(alphabet=st.sampled_from(list("0123456789.,;:-+eE#\t \"'\nxyz_nanifé\r\ufeff[]{}")), max_size=12)
NUMBERISH = st.sampled_from(["nan", "inf", "-inf", "1e309", "-0", "", " ", "1,5", "0x10", "1e-400", "9" * 30, "'3'",
                             "NaN", "1.2.3", "+", "e5", "\ufeff1"])


@st.composite
def damaged(draw: st.DrawFn, text: str) -> str:
    """``text`` after one to three kinds of damage."""
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["cut", "insert", "double", "swap", "number", "truncate", "crlf", "separator"]))
        n = len(text)
        if op == "cut" and n:
            i = draw(st.integers(0, n - 1))
            text = text[:i] + text[i + draw(st.integers(1, 20)):]
        elif op == "insert":
            i = draw(st.integers(0, n))
            text = text[:i] + draw(NOISE) + text[i:]
        elif op in ("double", "swap"):
            lines = text.splitlines(keepends=True)
            if lines:
                i = draw(st.integers(0, len(lines) - 1))
                j = draw(st.integers(0, len(lines) - 1))
                if op == "double":
                    lines.insert(j, lines[i])
                else:
                    lines[i], lines[j] = lines[j], lines[i]
                text = "".join(lines)
        elif op == "number":
            spans = [m.span() for m in re.finditer(r"-?\d+(\.\d+)?", text)]
            if spans:
                a, b = draw(st.sampled_from(spans))
                text = text[:a] + draw(NUMBERISH) + text[b:]
        elif op == "truncate" and n:
            text = text[:draw(st.integers(0, n - 1))]
        elif op == "crlf":
            text = text.replace("\n", "\r\n")
        elif op == "separator":
            text = text.replace(",", draw(st.sampled_from([";", "\t", " ", ", "])))
    return text


FUZZ = settings(max_examples=15, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@pytest.mark.parametrize("kind", sorted(GOOD))
def test_reader_fuzz(tmp_path, kind):
    read = base._reader(kind)
    path = tmp_path / base.FILE_NAME[kind]

    @settings(FUZZ, max_examples=6 if kind in ("gcp", "geo") else 15)  # these two ask PROJ about every damaged header
    @given(text=damaged(GOOD[kind]))
    def check(text: str) -> None:
        path.write_bytes(text.encode("utf-8"))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                read(path)
            except SkyrigError as exc:
                msg = str(exc)
                assert msg and "Traceback" not in msg
                assert "np.float64" not in msg and "np.str_" not in msg, msg

    check()


def test_fuzz_bytes_never_crash_a_reader(tmp_path):
    """Arbitrary bytes (binary junk, other encodings) under every reader's file name."""

    @settings(max_examples=20, deadline=None, derandomize=True)
    @given(data=st.binary(max_size=200), kind=st.sampled_from(sorted(GOOD)))
    def check(data: bytes, kind: str) -> None:
        p = tmp_path / base.FILE_NAME[kind]
        p.write_bytes(data)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                base._reader(kind)(p)
            except SkyrigError:
                pass

    check()


@pytest.mark.parametrize("command", ["world-to-image", "georef", "image-to-world", "convert"])
def test_command_fuzz_exit_status(tmp_path, command):
    """The main commands on damaged inputs: exit 0/1/2, never a traceback."""
    from click.testing import CliRunner

    from skyrig.cli import main

    sys.path.insert(0, str(Path(__file__).parent))
    import test_bad_input_cli as cli

    files = {"eo.csv": cli.EO, "gcp.csv": cli.PTS, "rig.yaml": cli.RIG, "traj.csv": cli.TRAJ, "events.csv": cli.EVENTS,
             "mes.csv": "point,image,column,row\ng1,img1.tif,2100.5,1400.25\ng1,img2.tif,1500.0,1420.0\n"
                        "g2,img2.tif,2000.0,1600.0\ng2,img3.tif,1300.0,1610.0\n"}
    targets = {"world-to-image": ["eo.csv", "gcp.csv", "rig.yaml"], "georef": ["traj.csv", "events.csv", "rig.yaml"],
               "image-to-world": ["eo.csv", "mes.csv", "rig.yaml"], "convert": ["eo.csv"]}[command]
    for name, text in files.items():
        (tmp_path / name).write_text(text)

    @settings(max_examples=6 if len(targets) > 1 else 4, deadline=None, derandomize=True)
    @given(which=st.sampled_from(targets), data=st.data())
    def check(which: str, data: st.DataObject) -> None:
        for name, text in files.items():
            (tmp_path / name).write_bytes(text.encode())
        (tmp_path / which).write_bytes(data.draw(damaged(files[which])).encode())
        args = {"world-to-image": ["world-to-image", "--eo", "eo.csv", "--camera", "rig.yaml", "--points", "gcp.csv",
                                   "-o", "o.csv"],
                "georef": ["georef", "--trajectory", "traj.csv", "--events", "events.csv", "--rig", "rig.yaml", "--crs",
                           "EPSG:25832", "-o", "o.csv"],
                "image-to-world": ["image-to-world", "--eo", "eo.csv", "--camera", "rig.yaml", "--measurements",
                                   "mes.csv", "--intersect", "-o", "o.csv"],
                "convert": ["convert", "eo.csv", "o.csv", "--to-crs", "EPSG:4326", "--to-angles", "gon"]}[command]
        args = [str(tmp_path / a) if a.endswith((".csv", ".yaml")) else a for a in args]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = CliRunner().invoke(main, args)
        assert res.exit_code in (0, 1, 2), res.output
        assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
        assert "Traceback" not in res.output

    check()


BAL = "1 2 2\n0 0 1.0 2.0\n0 1 -1.0 0.5\n0.01 0.02 0.03 0.1 0.2 -5 500 0 0\n1 2 3\n-1 0.5 2\n"
COLMAP_CAMERAS = "# Camera list\n1 SIMPLE_RADIAL 4000 3000 2340 2000 1500 0.01\n2 PINHOLE 640 480 500 500 320 240\n"


def _other_readers(tmp_path: Path) -> dict[str, tuple[str, str, object]]:
    """Readers of the other formats: ``{kind: (file name, good text, reader)}``; the side-car of a points table and
    a block file written by skyrig itself."""
    from skyrig.io.bal import read_bal
    from skyrig.io.block_file import read_block
    from skyrig.io.colmap_text import read_colmap_cameras
    from skyrig.io.points_csv import read_points_csv, write_points_csv

    good = tmp_path / "good"
    good.mkdir(exist_ok=True)
    write_points_csv(good / "pts.csv", read_points_csv(_write(good, "src.csv", base.PTS)))
    block = _good_block(good)
    return {
        "bal": ("problem.txt", BAL, read_bal),
        "colmap-cameras": ("cameras.txt", COLMAP_CAMERAS, read_colmap_cameras),
        "sidecar": ("pts.csv.json", (good / "pts.csv.json").read_text(), lambda p: read_points_csv(p.parent / "pts.csv")),
        "block": (block.name, block.read_text(), read_block),
        **_exchange_readers(),
    }


def _exchange_readers() -> dict[str, tuple[str, str, object]]:
    """Other programs' files (issue 33): Metashape calibration and cameras XML, OpenSfM, MicMac AutoCal."""
    from test_exchange_fuzz import _opensfm_text
    from test_metashape_io import _cal_xml, _cameras_xml
    from test_micmac_io import _autocal

    from skyrig.io.metashape import read_metashape_calibration, read_metashape_cameras
    from skyrig.io.micmac import read_micmac_calibration
    from skyrig.io.opensfm import read_opensfm

    return {
        "metashape-calibration": ("cal.xml", _cal_xml(), read_metashape_calibration),
        "metashape-cameras": ("cameras.xml", _cameras_xml(), read_metashape_cameras),
        "opensfm": ("reconstruction.json", _opensfm_text(), read_opensfm),
        "micmac-calibration": ("AutoCal.xml", _autocal(), read_micmac_calibration),
    }


def _write(d: Path, name: str, text: str) -> Path:
    (d / name).write_text(text)
    return d / name


def _good_block(d: Path) -> Path:
    """A block file from ``skyrig block`` on the CLI table's project (EO, cameras, measurements, control)."""
    from click.testing import CliRunner

    from skyrig.cli import main

    import test_bad_input_cli as cli

    for name, text in {"eo.csv": cli.EO, "gcp.csv": cli.PTS, "rig.yaml": cli.RIG}.items():
        _write(d, name, text)
    r = CliRunner().invoke(main, ["world-to-image", "--eo", str(d / "eo.csv"), "--camera", str(d / "rig.yaml"),
                                  "--points", str(d / "gcp.csv"), "-o", str(d / "px.csv")])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["block", "--eo", str(d / "eo.csv"), "--camera", str(d / "rig.yaml"), "--measurements",
                                  str(d / "px.csv"), "--control", str(d / "gcp.csv"), "-o", str(d / "block.json")])
    assert r.exit_code == 0, r.output
    return d / "block.json"


@pytest.mark.parametrize("kind", ["bal", "colmap-cameras", "sidecar", "block", "metashape-calibration",
                                  "metashape-cameras", "opensfm", "micmac-calibration"])
def test_other_reader_fuzz(tmp_path, kind):
    name, good, read = _other_readers(tmp_path)[kind]
    d = tmp_path / "good" if kind in ("sidecar", "block") else tmp_path
    path = d / name
    read(_write(d, name, good))  # the good file reads

    @settings(max_examples=12, deadline=None, derandomize=True)
    @given(text=damaged(good))
    def check(text: str) -> None:
        path.write_bytes(text.encode("utf-8"))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                read(path)
            except SkyrigError as exc:
                assert "np.float64" not in str(exc), str(exc)

    check()


def test_sbet_fuzz(tmp_path):
    """SBET: any byte string is either whole 136-byte records that read, or an error naming the file."""
    import struct

    from skyrig.io.sbet import read_sbet

    rec = [struct.pack("<17d", 345600.0 + k, 0.843, 0.157, 1200.0, 1, 0, 0, 0.01, -0.02, 1.5, 0.0, 0, 0, 0, 0, 0, 0)
           for k in range(3)]
    p = tmp_path / "traj.out"

    @settings(max_examples=15, deadline=None, derandomize=True)
    @given(cut=st.integers(0, 3 * 136), junk=st.binary(max_size=40), where=st.integers(0, 3 * 136))
    def check(cut: int, junk: bytes, where: int) -> None:
        data = b"".join(rec)[:cut]
        data = data[:where] + junk + data[where:]
        p.write_bytes(data)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                read_sbet(p)
            except SkyrigError as exc:
                assert "traj.out" in str(exc), str(exc)

    check()
