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
