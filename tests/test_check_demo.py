"""Issue 29: ``skyrig check`` on every project folder the demo writes (``skyrig demo``: the recorded flight of
``input/``, the simulated MIDAS flight of ``simulated/`` with rendered images, control and check points, the
TumbleCam circle of ``tumble_circle/``) reports nothing after ``skyrig init``; a copy damaged in several files at
once is refused with every damage named (file, line where there is one, and what is wrong) in one run.

The damages are the independent answer: each is made here (a cut image, a row with x and y swapped, a lever arm
multiplied by 1000) and each must be found, and nothing else."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.cli import main


def _run(*args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    assert "Traceback" not in r.output, r.output
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    return r


def _demo_input(root: Path) -> Path:
    from skyrig.pipeline.demo import build_demo_project

    build_demo_project(root)
    return root


def _demo_simulated(root: Path) -> Path:
    """What ``skyrig demo`` writes to ``simulated/`` (skyrig.pipeline.simulate.simulate_demo_project's flight)."""
    from skyrig.pipeline.simulate import write_project
    from skyrig.simulate.scenarios import build_survey, scenario_spec

    write_project(build_survey(scenario_spec("midas-dsm", "ci", 1)), root, 1)
    return root


def _demo_tumble(root: Path) -> Path:
    from skyrig.pipeline.demo import tumble_circle_demo

    tumble_circle_demo(root)
    # the demo's own results (two adjusted EO tables with their side-cars) are outputs, not inputs: left in the
    # folder, init finds two EO files and refuses to choose (issue 29)
    for p in root.glob("eo_*"):
        p.unlink()
    return root


def _cut(path: Path) -> str:
    b = path.read_bytes()
    path.write_bytes(b[: len(b) // 2])
    return path.name


def _lever_arm_in_mm(rig: Path) -> str:
    """The first non-zero lever arm of the rig file written in millimetres."""
    text = rig.read_text()
    for m in re.finditer(r"(lever_arm_m: \[)([^\]]+)\]", text):
        v = np.array([float(x) for x in m.group(2).split(",")])
        if np.linalg.norm(v) > 0.05:
            mm = ", ".join(f"{x * 1000:g}" for x in v)
            rig.write_text(text[: m.start()] + f"{m.group(1)}{mm}]" + text[m.end():])
            return "millimetres"
    raise AssertionError(f"no lever arm to damage in {rig}")


def _swap_xy(points: Path, row: int = 2) -> str:
    lines = points.read_text().splitlines()
    k = [i for i, ln in enumerate(lines) if ln and not ln.startswith("#")][row]
    name, x, y, *rest = lines[k].split(",")
    lines[k] = ",".join([name, y, x, *rest])
    points.write_text("\n".join(lines) + "\n")
    return f"line {k + 1}"


def _damage(folder: Path) -> list[tuple[str, str]]:
    """Damage every kind of input the folder has; ``[(file name, words the error must hold)]``."""
    expected = []
    for d in sorted(p for p in folder.iterdir() if p.is_dir() and p.name.startswith("images")):
        first = sorted(d.iterdir())[0]
        expected.append((first.name, f"truncated {'TIFF' if first.suffix == '.tif' else first.suffix[1:].upper()}"))
        _cut(first)
    rig = next(folder.rglob("rig.yaml"))
    expected.append((rig.name, _lever_arm_in_mm(rig)))
    pts = sorted(folder.rglob("ground_points.csv")) or sorted(folder.rglob("check_points.csv"))
    if pts:
        expected.append((pts[0].name, _swap_xy(pts[0])))
    return expected


def _check_clean_then_damaged(folder: Path, tmp_path: Path) -> None:
    r = _run("init", folder)
    assert r.exit_code == 0, r.output
    r = _run("check", folder)
    assert r.exit_code == 0 and r.output.startswith("ok: "), r.output
    assert "warning" not in r.output, r.output
    bad = tmp_path / "damaged"
    shutil.copytree(folder, bad)
    expected = _damage(bad)
    assert len(expected) >= 2
    r = _run("check", bad)
    assert r.exit_code == 2, r.output
    errors = [ln for ln in r.output.splitlines() if ln.startswith("error:")]
    for name, words in expected:
        assert any(name in e and words in e for e in errors), (name, words, r.output)
    assert len(errors) == len(expected), r.output  # nothing else: no error that only follows from another


def test_check_on_the_demo_input_project(tmp_path):
    _check_clean_then_damaged(_demo_input(tmp_path / "input"), tmp_path)


@pytest.mark.slow
def test_check_on_the_demo_simulated_flight(tmp_path):
    """60 rendered PNGs, 12 12-bit TIFFs, trajectory, events, rig, control / check points and their measurements
    (about 50 s to simulate)."""
    _check_clean_then_damaged(_demo_simulated(tmp_path / "simulated"), tmp_path)


@pytest.mark.slow
def test_check_on_the_demo_tumble_circle(tmp_path):
    """13 rendered PNGs and the calibrated TumbleCam rig, no GNSS (init: adjust-uav without GNSS)."""
    _check_clean_then_damaged(_demo_tumble(tmp_path / "tumble_circle"), tmp_path)


@pytest.mark.parametrize("ext", ["png", "tif", "jpg"])
def test_check_image_complete_refuses_cut_images(tmp_path, ext):
    """A cut PNG or TIFF was accepted by ``skyrig check`` (JPEG only); OpenCV reads the PNG as None later."""
    import cv2

    from skyrig.errors import InputFormatError
    from skyrig.io.image_read import check_image_complete

    a = (np.random.default_rng(0).random((120, 160, 3)) * 255).astype(np.uint8)
    f = tmp_path / f"a.{ext}"
    cv2.imwrite(str(f), a)
    check_image_complete(f)
    g = tmp_path / f"b.{ext}"
    g.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    with pytest.raises(InputFormatError, match=f"b.{ext}"):
        check_image_complete(g)


def test_check_image_complete_refuses_a_tiled_tiff_missing_its_last_tile(tmp_path):
    import rasterio

    from skyrig.errors import InputFormatError
    from skyrig.io.image_read import check_image_complete

    f = tmp_path / "t.tif"
    with rasterio.open(f, "w", driver="GTiff", width=256, height=192, count=1, dtype="uint16", tiled=True,
                       blockxsize=64, blockysize=64, compress="deflate") as ds:
        ds.write(np.arange(256 * 192, dtype="uint16").reshape(1, 192, 256))
    check_image_complete(f)
    g = tmp_path / "u.tif"
    g.write_bytes(f.read_bytes()[:-200])  # rasterio writes the directory first: the cut takes image data
    with pytest.raises(InputFormatError, match="truncated TIFF"):
        check_image_complete(g)
