"""Files published together stay together (issue 13, deliverable 4): a block file's tables and its manifest, a CSV
table and its side-cars.  A write killed between the two writes (a monkeypatched raise, or a child process that
SIGKILLs itself at that moment) must never be read back as a consistent pair: the readers refuse it or say so.

Independent answer: the files on disk (sizes, SHA-256 from hashlib, what the killed child had written) and the
block / EO each run wrote.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import textwrap
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from skyrig.adjust.synthetic import synthetic_block
from skyrig.errors import InputFormatError
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.geometry.rotations import matrix_from_opk
from skyrig.io import block_file
from skyrig.io.block_file import read_block, write_block, writing_marker
from skyrig.io.eo_csv import read_eo_csv, write_eo_csv
from skyrig.io.table_meta import SideCarMismatchWarning, meta_path


def _two_blocks():
    b1, _ = synthetic_block(seed=1, n_strips=2, n_per_strip=4, n_points=60)
    b2 = replace(b1, point_xyz=b1.point_xyz + np.array([5.0, -3.0, 2.0]))  # every points row differs
    return b1, b2


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def test_block_manifest_records_table_checksums(tmp_path):
    b1, _ = _two_blocks()
    write_block(tmp_path / "block.json", b1)
    man = json.loads((tmp_path / "block.json").read_text())
    assert set(man["checksums"]) == set(man["tables"])
    for k, name in man["tables"].items():
        f = tmp_path / name
        assert man["checksums"][k] == {"size": f.stat().st_size, "sha256": _sha(f)}
    assert not writing_marker(tmp_path / "block.json").exists()


def test_block_killed_before_manifest_is_refused(tmp_path, monkeypatch):
    """New tables, old block.json: the reader names the table and block.json instead of reading a mixed block."""
    b1, b2 = _two_blocks()
    p = tmp_path / "block.json"
    write_block(p, b1)
    old_manifest = p.read_bytes()
    real = block_file.atomic_write

    def dies_at_manifest(path, *a, **k):
        if Path(path) == p:
            raise KeyboardInterrupt("killed before the manifest")
        return real(path, *a, **k)

    monkeypatch.setattr(block_file, "atomic_write", dies_at_manifest)
    with pytest.raises(KeyboardInterrupt):
        write_block(p, b2)
    monkeypatch.undo()
    assert p.read_bytes() == old_manifest  # the previous manifest, next to new tables
    pts = tmp_path / "block_points.csv"
    assert json.loads(old_manifest)["checksums"]["points"]["sha256"] != _sha(pts)
    with pytest.raises(InputFormatError) as e:
        read_block(p)
    msg = str(e.value)
    assert e.value.path == str(pts) and "block.json" in msg and "interrupted" in msg
    write_block(p, b2)  # a complete rerun reads back as written
    np.testing.assert_allclose(read_block(p).block.point_xyz, b2.point_xyz, atol=1e-9)


def test_block_sigkill_child_between_tables_and_manifest(tmp_path):
    b1, b2 = _two_blocks()
    p = tmp_path / "block.json"
    write_block(p, b1)
    np.save(tmp_path / "shift.npy", b2.point_xyz - b1.point_xyz)
    script = textwrap.dedent(f"""
        import os, signal
        from dataclasses import replace
        from pathlib import Path
        import numpy as np
        from skyrig.adjust.synthetic import synthetic_block
        from skyrig.io import block_file
        b1, _ = synthetic_block(seed=1, n_strips=2, n_per_strip=4, n_points=60)
        b2 = replace(b1, point_xyz=b1.point_xyz + np.load({str(tmp_path / 'shift.npy')!r}))
        real = block_file.atomic_write
        target = Path({str(p)!r})
        def die(path, *a, **k):
            if Path(path) == target:
                os.kill(os.getpid(), signal.SIGKILL)
            return real(path, *a, **k)
        block_file.atomic_write = die
        block_file.write_block(target, b2)
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert r.returncode == -signal.SIGKILL, r.stderr
    assert writing_marker(p).exists()
    with pytest.raises(InputFormatError, match="interrupted") as e:
        read_block(p)
    assert "block.json" in str(e.value) and Path(e.value.path).name.startswith("block_")


def test_block_edited_table_reads_with_a_warning(tmp_path):
    """A table edited by hand after the manifest (no write in progress): read as it is, with a warning naming both."""
    b1, _ = _two_blocks()
    p = tmp_path / "block.json"
    write_block(p, b1)
    obs = tmp_path / "block_observations.csv"
    lines = obs.read_text().splitlines(keepends=True)
    obs.write_text("".join(lines[:-1]))  # one observation removed
    with pytest.warns(UserWarning, match="block_observations.csv.*block.json.*edited"):
        bf = read_block(p)
    assert bf.block.n_observations == b1.n_observations - 1


def test_block_without_checksums_still_reads(tmp_path):
    """Block files from older skyrig versions (or written by hand) have no 'checksums': read silently."""
    b1, _ = _two_blocks()
    p = tmp_path / "block.json"
    write_block(p, b1)
    man = json.loads(p.read_text())
    del man["checksums"]
    p.write_text(json.dumps(man))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        bf = read_block(p)
    np.testing.assert_allclose(bf.block.point_xyz, b1.point_xyz, atol=1e-9)


def test_block_bad_checksum_entry_names_the_field(tmp_path):
    b1, _ = _two_blocks()
    p = tmp_path / "block.json"
    write_block(p, b1)
    man = json.loads(p.read_text())
    man["checksums"]["points"] = "abc"
    p.write_text(json.dumps(man))
    with pytest.raises(InputFormatError) as e:
        read_block(p)
    assert e.value.field == "checksums.points" and e.value.path == str(p)


def _eo(shift=0.0, frame=None):
    rng = np.random.default_rng(3)
    n = 4
    c = np.column_stack([rng.uniform(5e5, 5.1e5, n), rng.uniform(5.7e6, 5.71e6, n), rng.uniform(800, 1200, n)])
    r = matrix_from_opk(rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(-180, 180, n), unit="deg")
    return ExteriorOrientations([f"i{k}.tif" for k in range(n)], ["nadir"] * n, c + shift, r,
                                frame or WorldFrame.map("EPSG:25832"))


def test_sidecar_records_table_checksum(tmp_path):
    p = tmp_path / "eo.csv"
    write_eo_csv(_eo(), p)
    meta = json.loads(meta_path(p).read_text())
    assert meta["table_size"] == p.stat().st_size and meta["table_sha256"] == _sha(p)


def test_sigkill_between_table_and_sidecars_never_pairs_new_table_with_old_crs(tmp_path):
    """Run 1 in EPSG:25832, run 2 (killed after eo.csv, before its side-cars) in EPSG:25833: the new table must not
    be read in run 1's CRS (its .csv.json and .prj are gone, so the reader asks for them; GDAL gets no .prj)."""
    p = tmp_path / "eo.csv"
    write_eo_csv(_eo(), p)
    assert (tmp_path / "eo.prj").exists() and "25832" in json.loads(meta_path(p).read_text())["frame"]
    old_table = p.read_bytes()
    script = textwrap.dedent(f"""
        import os, signal
        import numpy as np
        from skyrig.georef.eo import ExteriorOrientations, WorldFrame
        from skyrig.io import eo_csv
        def die(*a, **k):
            os.kill(os.getpid(), signal.SIGKILL)
        eo_csv.write_table_meta = die
        c = np.array([[4.0e5 + k, 5.70e6, 900.0] for k in range(3)])
        eo = ExteriorOrientations(["a", "b", "c"], ["nadir"] * 3, c, np.stack([np.eye(3)] * 3),
                                  WorldFrame.map("EPSG:25833"))
        eo_csv.write_eo_csv(eo, {str(p)!r})
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert r.returncode == -signal.SIGKILL, r.stderr
    assert p.read_bytes() != old_table  # the new table is in place ...
    assert not meta_path(p).exists() and not (tmp_path / "eo.prj").exists()  # ... without the old statement
    with pytest.raises(InputFormatError, match="side-car"):
        read_eo_csv(p)


def test_sidecar_of_another_table_version_warns_naming_both(tmp_path):
    """A table changed after its side-cars (edited, or written by a program that left them): a clear warning."""
    p = tmp_path / "eo.csv"
    write_eo_csv(_eo(), p)
    text = p.read_text().splitlines(keepends=True)
    p.write_text("".join(text[:-1]))  # one image removed by hand
    with pytest.warns(SideCarMismatchWarning, match=r"eo\.csv.*eo\.csv\.json"):
        eo = read_eo_csv(p)
    assert len(eo) == 3


def test_older_sidecar_without_checksum_reads_with_a_warning(tmp_path):
    p = tmp_path / "eo.csv"
    write_eo_csv(_eo(), p)
    m = meta_path(p)
    meta = json.loads(m.read_text())
    for k in ("table_sha256", "table_size", "table_file"):
        meta.pop(k)
    m.write_text(json.dumps(meta))
    with pytest.warns(UserWarning, match="older skyrig"):
        eo = read_eo_csv(p)
    np.testing.assert_allclose(eo.centre, _eo().centre, atol=1e-4)


def test_foreign_prj_next_to_a_plain_csv_is_left_alone(tmp_path):
    """Only skyrig's own side-cars are retired when a table is replaced."""
    from skyrig.io._text import atomic_write

    p = tmp_path / "t.csv"
    (tmp_path / "t.prj").write_text("GEOGCS[...]\n")
    with atomic_write(p) as fh:
        fh.write("a,b\n1,2\n")
    assert (tmp_path / "t.prj").exists()
    assert os.path.getsize(p) == 8
