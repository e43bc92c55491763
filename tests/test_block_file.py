"""Block files (docs/formats/block.md): round trip of a synthetic block (the adjustment of the re-read
block equals the original's), and bad input naming file, line and field."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import ReliabilityOptions
from skyrig.adjust.synthetic import synthetic_block
from skyrig.errors import InputFormatError
from skyrig.io.block_file import read_block, write_block


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    block, truth = synthetic_block(seed=1, n_strips=2, n_per_strip=5, n_points=150)
    d = tmp_path_factory.mktemp("blk")
    write_block(d / "block.json", block, AdjustConfig(reliability=ReliabilityOptions(snooping=True)))
    return block, d


def test_round_trip_preserves_block_and_adjustment(written):
    block, d = written
    bf = read_block(d / "block.json")
    b = bf.block
    assert bf.config.reliability.snooping is True
    assert list(b.image_name) == list(block.image_name) and b.n_observations == block.n_observations
    np.testing.assert_allclose(b.station_rotation, block.station_rotation, atol=1e-12)
    np.testing.assert_allclose(b.obs_pixel, block.obs_pixel, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.gnss_sigma, block.gnss_sigma)
    np.testing.assert_allclose(b.imu_sigma_rad, block.imu_sigma_rad, rtol=1e-12)
    r0, r1 = adjust(block), adjust(b)
    np.testing.assert_allclose(r1.block.point_xyz, r0.block.point_xyz, atol=1e-6)
    assert r1.sigma0 == pytest.approx(r0.sigma0, rel=1e-6)


def _edit(d: Path, table: str, line: int, old: str, new: str) -> None:
    p = d / f"block_{table}.csv"
    lines = p.read_text().splitlines()
    assert old in lines[line - 1]
    lines[line - 1] = lines[line - 1].replace(old, new, 1)
    p.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("table,line,old,new,field,words", [
    ("observations", 3, "s0000_nadir", "nosuchimage", "image", "unknown image 'nosuchimage'"),
    ("observations", 2, ",", ",", "col_px", "not a finite number"),
    ("gnss", 1, "sigma_X_m", "sigma_X_mm", "sigma_X_mm", "wrong unit"),
    ("imu", 1, "omega_deg", "omega_rad", "omega_rad", "expected 'omega_deg'"),
])
def test_bad_tables_name_file_line_field(written, tmp_path, table, line, old, new, field, words):
    block, d = written
    for f in d.iterdir():
        (tmp_path / f.name).write_bytes(f.read_bytes())
    if field == "col_px":  # put a NaN in the first observation's column
        p = tmp_path / "block_observations.csv"
        lines = p.read_text().splitlines()
        parts = lines[1].split(",")
        parts[2] = "nan"
        lines[1] = ",".join(parts)
        p.write_text("\n".join(lines) + "\n")
    else:
        _edit(tmp_path, table, line, old, new)
    with pytest.raises(InputFormatError) as e:
        read_block(tmp_path / "block.json")
    assert e.value.path.endswith(f"block_{table}.csv") and e.value.line == line and e.value.field == field
    assert words in str(e.value)


def test_point_seen_once_and_implausible_sigma(written, tmp_path):
    block, d = written
    for f in d.iterdir():
        (tmp_path / f.name).write_bytes(f.read_bytes())
    p = tmp_path / "block_observations.csv"
    lines = p.read_text().splitlines()
    # drop all but one observation of a non-control point
    ctrl = set(block.point_name[block.control_point])
    name = next(n for n in block.point_name if n not in ctrl)
    rows = [i for i, l in enumerate(lines) if l.startswith(name + ",")]
    keep = [l for i, l in enumerate(lines) if i not in rows[1:]]
    p.write_text("\n".join(keep) + "\n")
    with pytest.raises(InputFormatError) as e:
        read_block(tmp_path / "block.json")
    assert "seen in only one image" in str(e.value) and e.value.field == "point"
    assert e.value.line == rows[0] + 1
    # sigma given in pixels but 5000: wrong units
    for f in d.iterdir():
        (tmp_path / f.name).write_bytes(f.read_bytes())
    p = tmp_path / "block_observations.csv"
    lines = p.read_text().splitlines()
    parts = lines[4].split(",")
    parts[4] = "5000"
    lines[4] = ",".join(parts)
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputFormatError, match="wrong units") as e:
        read_block(tmp_path / "block.json")
    assert e.value.line == 5 and e.value.field == "sigma_col_px"


def test_manifest_errors(written, tmp_path):
    block, d = written
    for f in d.iterdir():
        (tmp_path / f.name).write_bytes(f.read_bytes())
    man = json.loads((tmp_path / "block.json").read_text())
    man["version"] = 7
    (tmp_path / "block.json").write_text(json.dumps(man))
    with pytest.raises(InputFormatError, match="unsupported version"):
        read_block(tmp_path / "block.json")
    man["version"] = 1
    man["adjustment"] = {"no_such_option": 1}
    (tmp_path / "block.json").write_text(json.dumps(man))
    with pytest.raises(InputFormatError, match="no_such_option"):
        read_block(tmp_path / "block.json")
