"""BAL problem files: reader against the published initial cost, writer round trip, skyrig's solver on a
BAL problem (cost decrease) and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import shared_path
from skyrig.adjust import AdjustConfig
from skyrig.adjust.config import Unknowns
from skyrig.adjust.model import Model, State
from skyrig.adjust.solver import factor_cost, levenberg_marquardt
from skyrig.errors import InputFormatError
from skyrig.io.bal import read_bal, write_bal


def _cost(block):
    m = Model(block, AdjustConfig(unknowns=Unknowns(intrinsics="free", datum="none")))
    return m, factor_cost(m.evaluate(State.from_block(block), jacobians=False))


def test_problem_49_initial_cost_matches_published_value():
    # Ceres's bundle_adjuster reports initial cost 8.509125e+05 for problem-49-7776-pre (0.5 sum r^2)
    b = read_bal(shared_path("bal", "problem-49-7776-pre.txt"))
    assert (b.n_images, b.n_points, b.n_observations) == (49, 7776, 31843)
    _, c = _cost(b)
    assert c == pytest.approx(8.509125e05, rel=1e-6)


def test_write_read_round_trip(tmp_path):
    b = read_bal(shared_path("bal", "problem-49-7776-pre.txt"))
    out = tmp_path / "p.txt"
    write_bal(out, b)
    b2 = read_bal(out)
    np.testing.assert_allclose(b2.point_xyz, b.point_xyz)
    np.testing.assert_allclose(b2.station_centre, b.station_centre, rtol=1e-12, atol=1e-9)
    assert _cost(b2)[1] == pytest.approx(_cost(b)[1], rel=1e-12)


def test_solver_reduces_bal_cost_on_a_subproblem():
    b = read_bal(shared_path("bal", "problem-49-7776-pre.txt"))
    m, c0 = _cost(b)
    s, info = levenberg_marquardt(m, State.from_block(b), max_iterations=5)
    # the published Ceres run reaches about 1.3e4 after ~30 iterations; 5 iterations cut the cost by > 10x
    assert info.final_cost < c0 / 10


@pytest.mark.parametrize(
    "text, needle",
    [
        ("1 2\n", "line 1"),
        ("1 1 1\n0 5 1.0 2.0\n" + "0\n" * 12, "point_index"),
        ("1 1 1\n0 0 1.0 2.0\n" + "0\n" * 11, "expected 12"),
    ],
)
def test_bad_bal_files(tmp_path, text, needle):
    p = tmp_path / "bad.txt"
    p.write_text(text)
    with pytest.raises(InputFormatError, match=needle):
        read_bal(p)
