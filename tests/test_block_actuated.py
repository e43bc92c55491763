"""``skyrig block`` / ``skyrig adjust`` on a rig with a tumbling (actuated) head (the macs-tumblecam preset).

Regression: ``skyrig block`` stopped with ``ValueError: write_block: the block has actuated heads; give rig_file``
(a traceback) on every rig with an actuated head; ``skyrig adjust`` did the same writing ``adjusted.json``.
Independent answer: the block file names the rig it was built from (read back by read_block to the same actuated
heads as the preset rig), and the adjusted block still reads.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from skyrig.cli import main
from skyrig.io.block_file import read_block
from skyrig.io.rig_file import read_rig
from skyrig.io.stage import verify_folder


@pytest.fixture(scope="module")
def tumble(tmp_path_factory):  # type: ignore[no-untyped-def]
    from skyrig.pipeline.simulate import simulate_scenario

    d = tmp_path_factory.mktemp("tumblecam")
    simulate_scenario("tumblecam", d / "sim", images=False)
    return d


def test_block_and_adjust_on_a_tumbling_head_rig(tumble) -> None:  # type: ignore[no-untyped-def]
    from skyrig.rig.presets import macs_tumblecam

    sim = tumble / "sim"
    rig = read_rig(sim / "rig.yaml")
    act = sorted(n for n, h in rig.heads.items() if h.is_actuated)
    assert act == sorted(n for n, h in macs_tumblecam().heads.items() if h.is_actuated) and act  # the preset rig
    out = tumble / "blk" / "block.json"
    r = CliRunner().invoke(main, ["block", "--trajectory", str(sim / "trajectory.csv"), "--events",
                                  str(sim / "events.csv"), "--rig", str(sim / "rig.yaml"), "--measurements",
                                  str(sim / "gcp" / "image_measurements.csv"), "--control",
                                  str(sim / "gcp" / "ground_points.csv"), "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert r.exception is None or isinstance(r.exception, SystemExit)
    man = json.loads(out.read_text())
    assert (out.parent / man["rig"]).resolve() == (sim / "rig.yaml").resolve()  # relative to the block file
    assert not Path(man["rig"]).is_absolute()
    bf = read_block(out)
    assert sorted(str(bf.block.head_name[k]) for k, h in enumerate(bf.block.head_actuated) if h is not None) == act
    r = CliRunner().invoke(main, ["adjust", str(out), "-o", str(tumble / "adj")])
    assert r.exit_code == 0, r.output
    assert verify_folder(tumble / "adj") == []
    adj = tumble / "adj" / "adjusted.json"
    assert (adj.parent / json.loads(adj.read_text())["rig"]).resolve() == (sim / "rig.yaml").resolve()
    assert read_block(adj).block.n_images == bf.block.n_images


def test_block_frees_the_actuator_and_its_curve(tumble) -> None:  # type: ignore[no-untyped-def]
    """``--free actuator,actuator-curve --fourier-order 3`` (paper 000's in-flight alternative to the lab curve) and
    ``--datum free-points --datum-points`` reach the block file's adjustment section as AdjustConfig reads it; the
    options are refused in words where they cannot apply (the recovery itself: tests/test_adjust_actuated.py)."""
    sim = tumble / "sim"
    base = ["block", "--trajectory", str(sim / "trajectory.csv"), "--events", str(sim / "events.csv"), "--rig",
            str(sim / "rig.yaml"), "--measurements", str(sim / "gcp" / "image_measurements.csv"), "--control",
            str(sim / "gcp" / "ground_points.csv")]
    out = tumble / "blk2" / "block.json"
    r = CliRunner().invoke(main, [*base, "--free", "actuator,actuator-curve,boresight", "--fourier-order", "3",
                                  "-o", str(out)])
    assert r.exit_code == 0, r.output
    cfg = read_block(out).config
    assert (cfg.unknowns.actuator, cfg.unknowns.actuator_curve, cfg.unknowns.actuator_fourier_order, cfg.unknowns.boresight) == ("free", "free", 3, "free")
    r = CliRunner().invoke(main, [*base, "--free", "actuator-curve", "-o", str(out)])
    assert r.exit_code == 0 and read_block(out).config.unknowns.actuator_fourier_order == 2, r.output  # the default order
    names = [ln.split(",")[0] for ln in (sim / "gcp" / "ground_points.csv").read_text().splitlines()
             if ln and ln[0] != "#"][1:4]
    free_net = base[:-2]  # no control: the datum from inner constraints on three of the points
    r = CliRunner().invoke(main, [*free_net, "--start-values-only", "--datum", "free-points", "--datum-points",
                                  ",".join(names), "-o", str(out)])
    assert r.exit_code == 0, r.output
    cfg = read_block(out).config
    assert (cfg.unknowns.datum, cfg.unknowns.inner_constraints, cfg.unknowns.datum_points) == ("free", "points", tuple(names))
    for extra, needle in ((["--fourier-order", "2"], "--fourier-order: goes with --free actuator-curve"),
                          (["--free", "actuator-curve", "--fourier-order", "0"], "--fourier-order"),
                          (["--datum-points", "a,b,c"], "--datum-points: goes with --datum free-points")):
        r = CliRunner().invoke(main, [*base, *extra, "-o", str(tumble / "blk3" / "block.json")])
        assert r.exit_code == 2 and needle in r.output, (extra, r.output)
