"""Rig files: round trips, the documented example, and errors that name file, line and field."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import skyrig.camera.distortion as distortion_module
from skyrig.camera import FrameCamera
from skyrig.errors import InputFormatError, SkyrigError
from skyrig.io.rig_file import read_rig, write_rig
from skyrig.rig import PRESETS, ActuatedHead, BoresightCurve, Head, Rig, mounting_from_rpy, preset

DOC = Path(__file__).resolve().parents[1] / "docs" / "formats" / "rig_file.md"
DEG = np.pi / 180.0


def _custom_rig() -> Rig:
    rng = np.random.default_rng(7)
    beta = np.arange(72) * 5 * DEG
    circles = np.stack([0.01 * np.sin(beta), 0.02 * np.cos(beta), 0.03 * np.sin(2 * beta)], 1)[None] * DEG
    circles = circles + rng.normal(0, 1e-3 * DEG, (5, 72, 3))
    curve = BoresightCurve.from_circles(beta, circles, interpolation="linear")
    cam = FrameCamera("cam-a", 4000, 3000, 0.0015425, 3.61, 0.011, -0.023)
    return Rig(
        "custom",
        [
            Head.from_angles("a", cam, (0.1, -0.2, 0.3), 1.5, -20.0, 170.0, (0.01, -0.02, 0.3)),
            # looking horizontally forward: pitch 90 deg (gimbal lock) -> written as a matrix
            Head("horizon", cam.with_(name="cam-b"), np.array([0.5, 0, 0]), mounting_from_rpy(0, 90, 0)),
            ActuatedHead.tumbling("t", cam.with_(name="cam-c"), 28.5, (0.0, 0.1, 0.05), (0.3, -0.2, 2.0),
                                  (0.004, 0.002, -0.01), curve, law="cardan"),
        ],
        antenna_lever_arm_m=np.array([0.02, 0.0, -0.45]),
        description="test rig: ünïcode & 'quotes'",
    )


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_presets_round_trip(tmp_path: Path, name: str) -> None:
    rig = preset(name)
    path = tmp_path / "rig.yaml"
    write_rig(rig, path)
    back = read_rig(path)
    assert back.isclose(rig, atol=1e-12)
    for h in rig:
        beta = np.linspace(0, 2 * np.pi, 7) if h.is_actuated else None
        assert back.head(h.name).body_from_camera(beta).rotation == pytest.approx(
            h.body_from_camera(beta).rotation, abs=1e-13)


def test_custom_rig_round_trip(tmp_path: Path) -> None:
    rig = _custom_rig()
    path = tmp_path / "sub" / "rig.yaml"
    write_rig(rig, path)
    text = path.read_text(encoding="utf-8")
    assert "mounting_matrix" in text and "format: skyrig-rig" in text and "version: 1" in text
    back = read_rig(path)
    assert back.isclose(rig, atol=1e-12)
    t0, t1 = rig.head("t"), back.head("t")
    assert isinstance(t1, ActuatedHead) and t1.law == "cardan" and t1.curve is not None
    beta = np.linspace(-1.0, 8.0, 50)
    assert t1.body_from_camera(beta).rotation == pytest.approx(t0.body_from_camera(beta).rotation, abs=1e-13)
    assert t1.curve.count is not None and np.all(t1.curve.count == 5)
    assert t1.curve.std_rad == pytest.approx(t0.curve.std_rad, abs=1e-13)  # type: ignore[union-attr]
    assert back.description == rig.description
    # writing again gives the same text; no temporary files are left behind
    write_rig(back, path)
    assert path.read_text(encoding="utf-8") == text
    assert [p.name for p in path.parent.iterdir()] == ["rig.yaml"]


def test_documented_example_reads(tmp_path: Path) -> None:
    blocks = re.findall(r"```yaml\n(.*?)```", DOC.read_text(encoding="utf-8"), flags=re.S)
    assert len(blocks) == 1
    path = tmp_path / "example.yaml"
    path.write_text(blocks[0], encoding="utf-8")
    rig = read_rig(path)
    assert rig.head_names == ["nadir", "oblique", "forward-oblique"]
    assert rig.antenna_lever_arm_m == pytest.approx([0.05, 0.0, -0.25])
    obl = rig.head("oblique")
    assert isinstance(obl, ActuatedHead) and obl.gamma_rad == pytest.approx(30 * DEG)
    assert obl.curve is not None and obl.curve(np.pi / 2) == pytest.approx(np.array([-0.004, 0.011, -0.05]) * DEG)
    assert rig.head("nadir").camera.pixel_size_mm == pytest.approx(0.0055)
    s = np.sin(45 * DEG)
    assert rig.head("forward-oblique").optical_axis() == pytest.approx([s, 0, s])


def test_failed_write_keeps_old_file(tmp_path: Path) -> None:
    path = tmp_path / "rig.yaml"
    write_rig(preset("uav-single"), path)
    before = path.read_text(encoding="utf-8")

    class Odd(distortion_module.Distortion):  # a model that cannot be serialised
        name = "odd"

    cam = FrameCamera("x", 10, 10, 0.01, 5.0, distortion=Odd())
    with pytest.raises(SkyrigError, match="cannot write distortion"):
        write_rig(Rig("bad", [Head("h", cam)]), path)
    assert path.read_text(encoding="utf-8") == before
    assert [p.name for p in tmp_path.iterdir()] == ["rig.yaml"]


GOOD = """\
format: skyrig-rig
version: 1
name: r
heads:
- name: nadir
  camera:
    name: c
    width_px: 100
    height_px: 80
    pixel_size_um: 5.5
    focal_mm: 35.0
  lever_arm_m: [0.0, 0.0, 0.0]
- name: tumbler
  camera:
    name: c2
    width_px: 100
    height_px: 80
    pixel_size_um: 5.5
    focal_mm: 35.0
  actuator:
    type: tumbling
    gamma_deg: 30.0
"""


@pytest.mark.parametrize(
    "old, new, line, field, message",
    [
        ("    focal_mm: 35.0\n  lever", "    focl_mm: 35.0\n  lever", 11, "heads[0].camera.focl_mm", "unknown key"),
        ("    focal_mm: 35.0\n  lever", "    focal_mm: -35.0\n  lever", 11, "heads[0].camera.focal_mm", "positive"),
        ("    width_px: 100\n", "    width_px: wide\n", 8, "heads[0].camera.width_px", "integer"),
        ("  lever_arm_m: [0.0, 0.0, 0.0]", "  lever_arm_m: [0.0, 0.0]", 12, "heads[0].lever_arm_m", "shape"),
        ("version: 1", "version: 2", 2, "version", "unsupported version 2"),
        ("format: skyrig-rig", "format: other", 1, "format", "expected 'skyrig-rig'"),
        ("name: r\n", "name: r\ncolour: red\n", 4, "colour", "unknown key"),
        ("    type: tumbling", "    type: gimbal", 21, "heads[1].actuator.type", "unknown actuator type"),
        ("    gamma_deg: 30.0\n", "    gamma_deg: 30.0\n    law: linear\n", 23, "heads[1].actuator.law", "'paper'"),
        ("- name: tumbler", "- name: nadir", 13, "heads[1].name", "duplicate head name"),
        ("  lever_arm_m: [0.0, 0.0, 0.0]",
         "  lever_arm_m: [0.0, 0.0, 0.0]\n  mounting_matrix: [[1, 0, 0], [0, 1, 0], [0, 0, -1]]",
         5, "heads[0]", "not a proper rotation"),
    ],
)
def test_errors_name_file_line_field(tmp_path: Path, old: str, new: str, line: int, field: str, message: str) -> None:
    assert old in GOOD
    path = tmp_path / "bad.yaml"
    path.write_text(GOOD.replace(old, new, 1), encoding="utf-8")
    with pytest.raises(InputFormatError, match=re.escape(message)) as info:
        read_rig(path)
    err = info.value
    assert err.path == str(path)
    assert err.field == field
    assert err.line == line


def test_good_file_and_structural_errors(tmp_path: Path) -> None:
    path = tmp_path / "ok.yaml"
    path.write_text(GOOD, encoding="utf-8")
    rig = read_rig(path)
    assert rig.head("nadir").optical_axis() == pytest.approx([0, 0, 1])
    assert rig.head("tumbler").is_actuated
    for text, line in (("format: skyrig-rig\nversion: 1\nname: [unclosed\n", 4), ("- just\n- a list\n", 1)):
        path.write_text(text, encoding="utf-8")
        with pytest.raises(InputFormatError) as info:
            read_rig(path)
        assert info.value.path == str(path) and info.value.line == line
    with pytest.raises(InputFormatError, match="file not found"):
        read_rig(tmp_path / "missing.yaml")


def test_distortion_in_rig_file(tmp_path: Path) -> None:
    path = tmp_path / "d.yaml"
    text = GOOD.replace("    focal_mm: 35.0\n  lever",
                        "    focal_mm: 35.0\n    distortion: {model: no-such-model}\n  lever")
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputFormatError) as info:
        read_rig(path)
    assert info.value.field.startswith("heads[0].camera.distortion") and info.value.line == 12
    models = getattr(distortion_module, "distortion_models", None)
    if models is None or not hasattr(distortion_module, "distortion_from_dict"):
        pytest.skip("skyrig.camera.distortion has no registry yet: only the no-distortion case runs")
    # every registered model, with non-zero parameters, round-trips through the rig file
    n_models = 0
    for cls in models().values():
        names = getattr(cls, "param_names", ())
        model = cls.from_params(np.linspace(1e-5, 3e-5, len(names))) if names else cls()
        cam = FrameCamera("c", 100, 80, 0.005, 20.0, distortion=model)
        rig = Rig("d", [Head("h", cam)])
        write_rig(rig, path)
        back = read_rig(path).head("h").camera.distortion
        assert type(back) is type(model)
        xy = np.array([[1.0, -0.5], [0.2, 0.3]])
        assert back.distort(xy, 20.0) == pytest.approx(model.distort(xy, 20.0), abs=1e-15)
        n_models += 1
    assert n_models >= 2
