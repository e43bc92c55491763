"""An adjustment that starts at its own optimum (an adjusted block adjusted again, or points from a forward
intersection with fixed poses) ends converged at once with the same sigma0.

Regression: it used to report ``converged=False`` ("trust region collapsed", 0 iterations) - a correct result
flagged as a failure, which the CLI turns into exit status 1.
"""

from __future__ import annotations

import numpy as np

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.synthetic import synthetic_block


def test_adjusting_an_adjusted_block_converges_at_once() -> None:
    b, _ = synthetic_block(seed=3)
    first = adjust(b, AdjustConfig())
    assert first.info.converged
    again = adjust(first.block, AdjustConfig())
    assert again.info.converged, again.info.message
    assert again.info.iterations <= 2
    assert abs(again.sigma0 - first.sigma0) < 1e-6 * first.sigma0
    assert np.abs(again.block.point_xyz - first.block.point_xyz).max() < 1e-6
