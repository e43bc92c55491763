"""Shared fixtures: locations of the real datasets in ../shared/data (tests skip when absent)."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = (ROOT / ".." / "shared" / "data").resolve()


def shared_path(*parts: str) -> Path:
    """Path under ../shared/data, or skip the test with a reason when it is absent."""
    p = SHARED_DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"real dataset not available: {p} (../shared/data is absent on a user's install)")
    return p


@pytest.fixture
def ign_dir() -> Path:
    return shared_path("ign-aerial-block")


@pytest.fixture
def egm96_grid() -> Path:
    return shared_path("geoid", "egm96_15.gtx")


@pytest.fixture
def raf20_grid() -> Path:
    return shared_path("ign-aerial-block", "dataset", "fr_ign_RAF20.tif")
