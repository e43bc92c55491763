"""AdjustConfig in parts (issue 30 item 3): each part read where it is used; the flat keys of earlier releases
still read from a block file's ``adjustment`` section for one release, each with a warning naming its new key."""

from __future__ import annotations

import dataclasses
import json
import warnings

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import FLAT_KEYS, PARTS, ReliabilityOptions, SolverOptions, StatisticsOptions, Unknowns
from skyrig.adjust.synthetic import synthetic_block
from skyrig.errors import ConfigError
from skyrig.io.block_file import read_block, write_block


def test_every_flat_key_of_earlier_releases_names_one_field_of_one_part():
    targets = list(FLAT_KEYS.values())
    assert len(set(targets)) == len(targets)  # no two old keys on one field
    every = {(p, f.name) for p, cls in PARTS.items() for f in dataclasses.fields(cls)
             if (p, f.name) not in (("unknowns", "groups"), ("unknowns", "group_sigma"))}  # new in this release
    assert set(targets) == every  # and every field of the parts has its old key
    assert {f.name for f in dataclasses.fields(AdjustConfig)} == set(PARTS)  # the config is its parts, nothing flat


def test_old_block_file_keys_still_work_and_warn_with_the_new_key(tmp_path):
    block, _ = synthetic_block(seed=2, n_points=60)
    write_block(tmp_path / "block.json", block, AdjustConfig())
    man = json.loads((tmp_path / "block.json").read_text())
    man["adjustment"] = {"boresight": "free", "snooping_per_round": 3, "max_iterations": 9, "statistics": False,
                         "statistics_images": [str(block.image_name[0])]}
    (tmp_path / "block.json").write_text(json.dumps(man))
    with pytest.warns(DeprecationWarning) as rec:
        bf = read_block(tmp_path / "block.json")
    words = " ".join(str(w.message) for w in rec)
    for new in ("unknowns.boresight", "reliability.per_round", "solver.max_iterations", "statistics.compute",
                "statistics.images"):
        assert new in words, words
    cfg = bf.config
    assert cfg.unknowns.boresight == "free" and cfg.reliability.per_round == 3 and cfg.solver.max_iterations == 9
    assert cfg.statistics.compute is False and cfg.statistics.images == (str(block.image_name[0]),)
    assert {"unknowns.boresight", "reliability.per_round"} <= bf.adjustment_keys
    # written back, the section is in parts and reads without a warning
    write_block(tmp_path / "b2" / "block.json", bf.block, cfg)
    sec = json.loads((tmp_path / "b2" / "block.json").read_text())["adjustment"]
    assert sec == {"unknowns": {"boresight": "free"}, "solver": {"max_iterations": 9},
                   "reliability": {"per_round": 3},
                   "statistics": {"compute": False, "images": [str(block.image_name[0])]}}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_block(tmp_path / "b2" / "block.json").config == cfg


def test_unknown_and_mistyped_keys_name_the_part_and_field():
    with pytest.raises(ConfigError, match=r"solver\.max_iters"):
        AdjustConfig.from_dict({"solver": {"max_iters": 3}})
    with pytest.raises(ConfigError, match="no_such"):
        AdjustConfig.from_dict({"no_such": 1})
    with pytest.raises(ConfigError, match=r"reliability\.alpha.*float"):
        AdjustConfig.from_dict({"reliability": {"alpha": "0.1"}})
    with pytest.raises(ConfigError, match="per_round"):
        AdjustConfig(reliability=ReliabilityOptions(per_round=0))
    with pytest.raises(ConfigError, match="must be a SolverOptions"):
        AdjustConfig(solver=Unknowns())  # type: ignore[arg-type]


def test_the_parts_reach_the_adjustment():
    """Each part is read where it is used: the solver's iteration cap, the statistics switch, the unknowns."""
    b, truth = synthetic_block(seed=4, n_points=80, head_boresight=np.array([[2e-3, -1e-3, 1e-3]]))
    one = adjust(b, AdjustConfig(solver=SolverOptions(max_iterations=1), statistics=StatisticsOptions(compute=False)))
    assert one.info.iterations + one.info.unsuccessful <= 1 and one.covariance is None
    with pytest.warns(DeprecationWarning, match=r"unknowns\.boresight"):
        flat = AdjustConfig.from_flat({"boresight": "free"})
    parts = AdjustConfig(unknowns=Unknowns(boresight="free"))
    assert flat == parts
    r = adjust(b, parts)
    assert any(lab[0] == "boresight" for lab in r.layout.labels)
    err = np.abs(r.block.head_boresight - truth.head_boresight).max()
    assert err < 5e-4, err
