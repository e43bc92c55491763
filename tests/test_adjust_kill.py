"""``skyrig adjust`` publishes its output folder as a set (issue 13: a killed run never leaves a mixed folder).

Independent answer: the folder's own manifest (written last, :func:`skyrig.io.stage.verify_folder` recomputes every
file's SHA-256) and the folder listing.  Two different blocks are adjusted in turn into the same folder so that
every output file differs between consecutive runs: a folder mixing two runs would disagree with its manifest.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from skyrig.io.stage import MANIFEST, clean_stale, stage_folder, verify_folder

SKYRIG = [str(Path(sys.executable).parent / "skyrig")]


def _blocks(tmp: Path) -> list[Path]:
    from skyrig.adjust.synthetic import synthetic_block
    from skyrig.geodesy.frame import WorldFrame
    from skyrig.io.block_file import write_block

    out = []
    for seed in (2, 3):
        b, _ = synthetic_block(seed=seed, n_strips=2, n_per_strip=6, n_points=120, n_control=6)
        b = replace(b, frame=WorldFrame.local(52.0 + seed * 0.01, 9.7, 100.0).to_text())  # EO/points/gpkg written too
        p = tmp / f"b{seed}" / "block.json"
        write_block(p, b)
        out.append(p)
    return out


def _strays(parent: Path, name: str) -> list[str]:
    """Entries next to the output folder other than the folder and the staging siblings of killed runs."""
    return [p.name for p in parent.iterdir() if p.name != name and not p.name.startswith(f".{name}.partial-")
            and not p.name.startswith(f".{name}.old-")]


def _run(block: Path, out: Path) -> subprocess.Popen:
    return subprocess.Popen([*SKYRIG, "adjust", str(block), "-o", str(out)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, env=dict(os.environ, NUMBA_CACHE_DIR=os.environ.get(
                                "NUMBA_CACHE_DIR", str(out.parent.parent / "numba"))))


@pytest.mark.slow  # 20 kills and reruns of a subprocess: ~2-4 min
def test_adjust_killed_at_20_random_moments_never_leaves_a_mixed_folder(tmp_path) -> None:
    blocks = _blocks(tmp_path)
    parent = tmp_path / "work"
    parent.mkdir()
    out = parent / "adj"
    t0 = time.perf_counter()
    p = _run(blocks[0], out)
    assert p.wait(timeout=300) == 0
    full = time.perf_counter() - t0  # one whole run, imports included
    assert verify_folder(out) == []
    rng = np.random.default_rng(13)
    # half the moments anywhere in a run, half in its last 40 % (adjustment done: writing, manifest, swap)
    moments = np.concatenate([rng.uniform(0.0, 1.0, 10), rng.uniform(0.6, 1.05, 10)]) * full
    rng.shuffle(moments)
    seen = {"absent": 0, "previous": 0, "new": 0, "partial_left": 0, "old_left": 0}
    for k, t in enumerate(moments):
        blk = blocks[(k + 1) % 2]
        before = json.loads((out / MANIFEST).read_text()) if out.exists() else None
        p = _run(blk, out)
        time.sleep(float(t))
        if p.poll() is None:
            p.send_signal(signal.SIGKILL)
        p.wait(timeout=60)
        assert _strays(parent, "adj") == [], f"kill {k} at {t:.2f} s"
        seen["partial_left"] += any(".partial-" in q.name for q in parent.iterdir())
        seen["old_left"] += any(".old-" in q.name for q in parent.iterdir())
        if not out.exists():
            seen["absent"] += 1
            continue
        assert verify_folder(out) == [], f"kill {k} at {t:.2f} s: {verify_folder(out)}"
        now = json.loads((out / MANIFEST).read_text())
        if before is not None and now == before:
            seen["previous"] += 1
        else:
            seen["new"] += 1
            assert now["options"]["block"] == str(blk)
    # the rerun after the last kill completes: stale staging folders gone, a complete folder in place
    p = _run(blocks[0], out)
    assert p.wait(timeout=300) == 0
    assert sorted(q.name for q in parent.iterdir()) == ["adj"]
    assert verify_folder(out) == []
    print(f"one run {full:.1f} s; after 20 kills: {seen}")


def test_clean_stale_removes_leftovers_and_restores_an_interrupted_swap(tmp_path) -> None:
    out = tmp_path / "adj"
    with stage_folder(out, stage="t", started=time.time()) as tmp:
        (tmp / "a.txt").write_text("first")
    # a run killed while staging, and one killed between the two renames of its swap
    partial = tmp_path / ".adj.partial-x1"
    partial.mkdir()
    (partial / "a.txt").write_text("half")
    old = tmp_path / ".adj.old-x2"
    old.mkdir()
    os.replace(out, old / "adj")
    later = tmp_path / ".adj.partial-x3"  # a sibling newer than the run: not touched
    past = time.time() - 1
    os.utime(partial, (past, past))
    os.utime(old, (past, past))
    removed = clean_stale(out, started=time.time() - 0.5)
    later.mkdir()
    assert sorted(p.name for p in removed) == [".adj.old-x2", ".adj.partial-x1"]
    assert (out / "a.txt").read_text() == "first" and verify_folder(out) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == [".adj.partial-x3", "adj"]


def test_clean_stale_removes_the_scratch_a_killed_stage_left_beside_its_staging_folder(tmp_path) -> None:
    # the dsm stage writes its tiles into a scratch folder named after the folder it writes into; in a project run
    # that is the staging folder, so a killed run leaves ``..dsm.partial-X.scratch-Y`` beside ``.dsm.partial-X``
    out = tmp_path / "dsm"
    staging = tmp_path / ".dsm.partial-x1"
    scratch = tmp_path / "..dsm.partial-x1.scratch-y1"
    other = tmp_path / "..ortho.partial-x2.scratch-y2"  # another stage's: not this one's to remove
    for d in (staging, scratch, other):
        d.mkdir()
        (d / "layers.tif").write_bytes(b"x")
        past = time.time() - 60
        os.utime(d, (past, past))
    newer = tmp_path / "..dsm.partial-x3.scratch-y3"  # a run's started after this one: not touched
    newer.mkdir()
    removed = clean_stale(out, started=time.time() - 30)
    assert sorted(p.name for p in removed) == ["..dsm.partial-x1.scratch-y1", ".dsm.partial-x1"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["..dsm.partial-x3.scratch-y3", "..ortho.partial-x2.scratch-y2"]


def test_adjust_publishes_a_manifest_and_a_failed_run_writes_nothing(tmp_path) -> None:
    from click.testing import CliRunner

    from skyrig.cli import main

    blocks = _blocks(tmp_path)
    out = tmp_path / "work" / "adj"
    stale = tmp_path / "work" / ".adj.partial-dead"
    stale.mkdir(parents=True)
    past = time.time() - 60
    os.utime(stale, (past, past))
    r = CliRunner().invoke(main, ["adjust", str(blocks[0]), "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert verify_folder(out) == [] and not stale.exists()
    m = json.loads((out / MANIFEST).read_text())
    assert m["stage"] == "adjust" and {"eo.csv", "points.csv", "report.html", "adjusted.json"} <= {
        f["path"] for f in m["files"]}
    assert any(i["path"].endswith("block.json") and len(i["sha256"]) == 64 for i in m["inputs"])
    # a failing run (no iterations allowed -> no convergence) leaves the previous folder as it was
    bad = json.loads(blocks[1].read_text())
    bad.setdefault("adjustment", {}).setdefault("solver", {})["max_iterations"] = 1
    bad["adjustment"]["solver"].update(function_tolerance=1e-300, parameter_tolerance=1e-300,
                                       gradient_tolerance=1e-300)
    bp = blocks[1].parent / "bad.json"
    bp.write_text(json.dumps(bad))
    r = CliRunner().invoke(main, ["adjust", str(bp), "-o", str(out)])
    if r.exit_code == 0:
        pytest.skip("could not make the adjustment fail with max_iterations = 1")
    assert r.exit_code == 1 and "nothing written" in r.output
    assert json.loads((out / MANIFEST).read_text()) == m and verify_folder(out) == []
    assert sorted(p.name for p in out.parent.iterdir()) == ["adj"]
