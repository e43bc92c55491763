"""Issue 12: a model error that data snooping does not show as blunders is still named in words.

Seeded simulations (``synthetic_block``): a 0.75 m GNSS datum shift (15 GNSS sigmas, paper 003's antenna
offset) spreads over all six control points (variance factor ~3.7 with redundancy 1.5: no single point stands
out); the group's chi-square test finds it and the warning names the datum shift and how to free it.  The same
blocks without the injected error give no such warning (5 seeds: the test's alpha is 0.001).
"""

from __future__ import annotations

import numpy as np

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import Unknowns
from skyrig.adjust.synthetic import synthetic_block


def test_datum_shift_between_gnss_and_control_is_named():
    b, tr = synthetic_block(seed=3, n_strips=2, n_per_strip=8, n_points=300, n_control=6,
                            datum_shift=np.array([0.0, 0.0, 0.75]))
    res = adjust(b, AdjustConfig())
    w = [x for x in res.warnings if "times worse than their sigmas" in x]
    assert len(w) == 1 and w[0].startswith("the control-point observations"), res.warnings
    assert "datum difference between GNSS and control" in w[0] and "--free datum-shift" in w[0]
    # freeing what the warning names removes it and recovers the injected shift within 3 sigma
    res = adjust(b, AdjustConfig(unknowns=Unknowns(datum_shift="free")))
    assert not any("times worse" in x for x in res.warnings)
    s = np.array([res.sigma_reduced()[("datum_shift", "gnss", c)] for c in "XYZ"])
    assert np.all(np.abs(res.block.datum_shift - tr.datum_shift) < 3 * s)


def test_no_model_error_warning_without_a_model_error():
    for seed in range(5):
        b, _ = synthetic_block(seed=seed, n_strips=2, n_per_strip=8, n_points=300, n_control=6)
        assert not any("times worse" in x for x in adjust(b, AdjustConfig()).warnings)
