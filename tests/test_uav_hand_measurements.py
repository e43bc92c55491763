"""Hand measurements of ground points are judged by their own limit, never by the tie points' outlier rules.

Found on the real OpenSfM berlin images (bench/real.py): the final outlier removal of the orientation without GNSS
cut every image measurement above 2 px (4 x the tie points' robust RMS), so two of five control points clicked 2.2 px
off lost a ray, fell out of the block, and the report listed three control points without a word; the check points
were 1.5 m RMS off instead of 0.5 m.  A click a few pixels off is an ordinary hand measurement; only one beyond
``hand_cut_px`` is cut as a blunder, and then it is named.
"""

from __future__ import annotations

import logging

import numpy as np

from test_uav_control import SIGMA, _checks_within_predicted
from test_uav_determinability import CROSS, _block


def _hand_tracks(inp, tracks, rng, noise_px):  # type: ignore[no-untyped-def]
    """New tracks 'G<k>': the observations of ``tracks`` clicked by hand (tie pixels + ``noise_px`` per axis)."""
    rows = [np.flatnonzero(inp.obs_track == t) for t in tracks]
    first = len(inp.track_name)
    new_t = np.concatenate([np.full(len(r), first + k) for k, r in enumerate(rows)])
    new_r = np.concatenate(rows)
    inp.track_name = np.append(inp.track_name, [f"G{k}" for k in range(len(tracks))])
    start = len(inp.obs_track)
    inp.obs_track = np.append(inp.obs_track, new_t)
    inp.obs_image = np.append(inp.obs_image, inp.obs_image[new_r])
    inp.obs_pixel = np.vstack([inp.obs_pixel, inp.obs_pixel[new_r] + rng.normal(0, noise_px, (len(new_r), 2))])
    return np.arange(first, first + len(tracks)), np.arange(start, len(inp.obs_track))


def test_no_gnss_block_keeps_hand_measurements_a_few_pixels_off_and_names_a_blunder(caplog):
    from skyrig.orient.incremental import OrientConfig, OrientInput, orient_incremental

    truth: dict = {}
    inp, _ = _block(CROSS, seed=31, focal_error=1.05, truth=truth)
    rng = np.random.default_rng(4)
    X = truth["X"]
    seen = np.bincount(inp.obs_track, minlength=len(inp.track_name))
    good = np.flatnonzero(seen >= 4)
    nodes = np.array([[x, y] for x in (-50.0, -25.0, 0.0, 25.0, 50.0) for y in (-35.0, 35.0)])
    ctrl = [int(good[np.argmin(np.linalg.norm(X[good, :2] - q, axis=1))]) for q in nodes]
    chk = [int(t) for t in rng.choice(np.setdiff1d(good, ctrl), 5, replace=False)]
    # clicks 1.5 px per axis: about 40 % of them beyond the tie points' 2 px limit of this block
    hand_t, hand_rows = _hand_tracks(inp, ctrl + chk, rng, 1.5)
    blunder = hand_rows[3]  # one click 40 px off
    inp.obs_pixel[blunder] += [40.0, -12.0]
    noise = rng.normal(0, 1, (10, 3)) * np.array([1.0, 1.0, 5.0])
    oi = OrientInput(inp.names, inp.camera, inp.obs_track, inp.obs_image, inp.obs_pixel, inp.track_name,
                     control_track=hand_t, control_xyz=np.vstack([X[ctrl] + noise, X[chk]]),
                     control_sigma=np.vstack([np.broadcast_to(SIGMA, (10, 3)), np.full((5, 3), 0.01)]),
                     control_check=np.r_[np.zeros(10, bool), np.ones(5, bool)])
    with caplog.at_level(logging.WARNING):
        res = orient_incremental(oi, OrientConfig(pixel_sigma_px=0.3))
    assert res.oriented.all() and res.adjustment.ok
    s = res.summary
    assert len(s["control_used"]) == 10 and len(s["check_used"]) == 5 and not s["control_left_out"]
    # every click but the blunder is in the final block
    b = res.adjustment.block
    names = set(inp.track_name[hand_t].tolist())
    in_block = int(np.isin(b.point_name[b.obs_point], list(names)).sum())
    assert in_block == len(hand_rows) - 1
    bl = f"{inp.track_name[inp.obs_track[blunder]]} in {inp.names[inp.obs_image[blunder]]}"
    assert list(s["hand_measurements_cut"]) == [bl]
    assert s["hand_measurements_cut"][bl] > 10.0
    assert any(bl.split(" in ")[0] in r.getMessage() and "blunder" in r.getMessage() for r in caplog.records)
    # the hand tracks are separate points: the check points' truth is that of the tie point they were clicked on
    _checks_within_predicted(res, inp.track_name, hand_t[10:], np.vstack([X, X[ctrl + chk]]))
