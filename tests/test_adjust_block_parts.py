"""The block in parts (issue 30): at most 12 fields, each observation type's rows its own data class, the flat
keywords routed to the parts (construction and ``dataclasses.replace``), the frame an object."""

from __future__ import annotations

import dataclasses
import typing

import numpy as np
import pytest

from skyrig.adjust.block import Block, BlockFrame
from skyrig.adjust.factors import observation_types
from skyrig.adjust.synthetic import synthetic_block
from skyrig.errors import BlockError
from skyrig.geodesy.frame import WorldFrame


@pytest.fixture(scope="module")
def block() -> Block:
    return synthetic_block(seed=2, n_strips=1, n_per_strip=3, n_points=12)[0]


def test_block_has_at_most_12_fields_none_optional(block: Block) -> None:
    fields = dataclasses.fields(block)
    assert len(fields) <= 12, [f.name for f in fields]
    hints = typing.get_type_hints(Block)
    for f in fields:
        assert type(None) not in typing.get_args(hints[f.name]), f.name  # nothing typed optional
        assert getattr(block, f.name) is not None, f.name


def test_each_builtin_type_owns_its_rows_in_observations(block: Block) -> None:
    for t in observation_types():
        if t.rows is not None:
            rows = block.observations[t.name]
            # the rows' class lives in the type's module (or in the module of the type it refines: the rolling-shutter
            # image type evaluates the image rows)
            assert isinstance(rows, t.rows) and type(rows).__module__ in {c.__module__ for c in type(t).__mro__}
            assert len(rows) == t.count(block)
    assert block.observations["gnss"].xyz is block.gnss_xyz  # the flat name reads the rows
    assert block.stations.centre is block.station_centre


def test_replace_with_flat_names_routes_to_parts_and_leaves_the_source_alone(block: Block) -> None:
    before = block.station_centre.copy(), block.gnss_sigma.copy()
    new = dataclasses.replace(block, station_centre=block.station_centre + 1.0, gnss_sigma=0.2)
    np.testing.assert_array_equal(new.station_centre, before[0] + 1.0)
    assert new.gnss_sigma.shape == before[1].shape and (new.gnss_sigma == 0.2).all()
    np.testing.assert_array_equal(block.station_centre, before[0])
    np.testing.assert_array_equal(block.gnss_sigma, before[1])
    assert new.stations is not block.stations and new.observations["gnss"] is not block.observations["gnss"]


def test_a_block_from_parts_without_a_builtin_types_rows_is_refused(block: Block) -> None:
    with pytest.raises(BlockError, match=r"\{\*\*block.observations"):
        dataclasses.replace(block, observations={})
    with pytest.raises(TypeError, match="stattion_name"):
        dataclasses.replace(block, stattion_name=block.station_name)  # a misspelt keyword is no silent default


def test_copy_is_deep_and_equal(block: Block) -> None:
    c = block.copy()
    for name in ("station_centre", "image_rotation", "head_boresight", "obs_pixel", "control_xyz", "imu_rotation"):
        a, b = getattr(block, name), getattr(c, name)
        assert a is not b
        np.testing.assert_array_equal(a, b)


def test_frame_is_an_object_taking_text_or_a_world_frame(block: Block) -> None:
    assert isinstance(block.frame, BlockFrame) and str(block.frame) == "synthetic local ENU"
    assert block.frame.world_frame() is None  # free words
    w = WorldFrame.local(52.5, 13.4, 40.0)
    b = dataclasses.replace(block, frame=w)
    assert b.frame.world is w and b.frame.text == w.describe()
    t = dataclasses.replace(block, frame=w.describe()).frame.world_frame()  # read back from its text
    assert t is not None and t.kind == "local"
    np.testing.assert_allclose(t.origin, w.origin, atol=1e-9)
