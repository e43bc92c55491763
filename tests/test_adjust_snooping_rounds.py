"""Data snooping with several rejections per round (``AdjustConfig.reliability.per_round``).

Independent answer: the truth of a seeded simulation - which observations were given a blunder - and
Baarda's one-at-a-time snooping on the same block.  Several non-adjacent rejections per round must find
the same blunders (no good observation more) in fewer rounds, and end at the same solution.
"""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import ReliabilityOptions
from skyrig.adjust.synthetic import synthetic_block


@pytest.fixture(scope="module")
def blundered():  # type: ignore[no-untyped-def]
    b, _ = synthetic_block(seed=5, n_strips=3, n_per_strip=8, n_points=500)
    rng = np.random.default_rng(21)
    rays = np.bincount(b.obs_point, minlength=b.n_points)
    rich = np.flatnonzero(rays >= 5)  # a blunder is localisable where the point has rays to spare
    pts = rng.choice(rich, 14, replace=False)
    bad = []
    for k, p in enumerate(pts):
        obs = np.flatnonzero(b.obs_point == p)
        # two points carry two blunders each: one of them must wait for the next round
        bad += rng.choice(obs, 2 if k < 2 else 1, replace=False).tolist()
    bad = np.array(bad)
    b.obs_pixel[bad] += rng.choice([-1, 1], (bad.size, 2)) * rng.uniform(6, 10, (bad.size, 2))  # 12-20 sigma
    return b, bad


def _run(b, per_round, share=0.0):  # type: ignore[no-untyped-def]
    stages: list[str] = []
    res = adjust(b, AdjustConfig(reliability=ReliabilityOptions(snooping=True, per_round=per_round,
                                                                per_round_share=share)),
                 callback=lambda s, i, c: stages.append(s))
    return res, len(dict.fromkeys(stages))


def test_several_rejections_per_round_find_the_same_blunders_in_fewer_rounds(blundered):
    b, bad = blundered
    one, rounds_one = _run(b, 1)
    many, rounds_many = _run(b, 10)
    assert sorted(r.index for r in one.rejected) == sorted(bad.tolist())
    assert sorted(r.index for r in many.rejected) == sorted(bad.tolist())
    assert not one.failures and not many.failures
    assert rounds_one == bad.size + 1  # Baarda: one rejection per round, then the clean adjustment
    assert rounds_many <= 5, rounds_many
    # the same observations out -> the same least-squares solution (to far below its precision)
    sc = one.pose_sigma[:, :3]
    dc = np.abs(many.block.station_centre - one.block.station_centre) / sc
    sp = one.point_sigma
    dp = np.abs(many.block.point_xyz - one.block.point_xyz) / sp
    assert np.nanmax(dc) < 0.01 and np.nanmax(dp) < 0.01, (np.nanmax(dc), np.nanmax(dp))
    assert abs(many.sigma0 - one.sigma0) < 1e-3 * one.sigma0


def test_one_per_round_is_the_default_and_per_round_is_checked():
    assert AdjustConfig().reliability.per_round == 1
    assert AdjustConfig().reliability.per_round_share == 0.0
    with pytest.raises(ValueError, match="per_round"):
        AdjustConfig(reliability=ReliabilityOptions(per_round=0))
    with pytest.raises(ValueError, match="per_round_share"):
        AdjustConfig(reliability=ReliabilityOptions(per_round_share=1.5))


def test_a_share_of_the_observations_per_round_keeps_the_rounds_down_with_the_same_result(blundered):
    """A fixed cap per round makes the rounds grow with the blunders (16 here, 2 a round: at least 8 rounds); a
    share of the tested observations (1 %: about 40 a round here) grows with the block instead, and ends with the
    same rejections and sigma0 as the fixed cap (the same non-adjacent picks, only fewer rounds)."""
    b, bad = blundered
    fixed, rounds_fixed = _run(b, 2)
    share, rounds_share = _run(b, 2, 0.01)
    assert rounds_fixed >= bad.size // 2 + 1
    assert rounds_share <= 5 < rounds_fixed, (rounds_share, rounds_fixed)
    for r in (fixed, share):
        assert sorted(x.index for x in r.rejected) == sorted(bad.tolist()) and not r.failures
    assert abs(share.sigma0 - fixed.sigma0) < 1e-9 * fixed.sigma0


def test_a_gnss_blunder_is_rejected_alone_and_the_result_equals_baardas(blundered):
    """A GNSS blunder drags its station and inflates the residuals of its images: while it is above the
    critical value no image observation is rejected beside it, so no good ray of that station goes."""
    b = blundered[0].copy()
    bad = blundered[1]
    k = b.n_stations // 2
    j = int(np.flatnonzero(b.gnss_station == k)[0])
    b.gnss_xyz[j] += np.array([0.0, 0.0, 1.2])  # 24 sigma in height (sigma 0.05 m)
    one, _ = _run(b, 1)
    many, rounds = _run(b, 10)
    got = sorted((r.group, r.index) for r in many.rejected)
    assert got == sorted((r.group, r.index) for r in one.rejected)
    assert ("gnss", j) in got
    assert sorted(i for g, i in got if g == "image") == sorted(bad.tolist())
    assert rounds < len(got)


def test_block_refuses_a_snooping_round_size_below_one_naming_the_option(tmp_path):
    from skyrig.errors import OptionError
    from skyrig.pipeline.orientation import make_block

    with pytest.raises(OptionError, match="--snooping-per-round"):
        make_block(tmp_path / "b.json", [tmp_path / "m.csv"], eo=tmp_path / "eo.csv", cameras=[tmp_path / "c.yaml"],
                   snooping_per_round=0)
