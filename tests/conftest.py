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


def grazing_ground_beams(roughness_in_data: bool, m: int = 20000, h: float = 5.0, range_sigma: float = 0.02,
                         roughness: float = 0.002, seed: int = 7):
    """Seeded laser ranges to level ground (z = 0) from ``h`` m above it at 10-80 deg depression: ``(range (m,),
    unit beams (m, 3))``, range noise ``range_sigma``; with ``roughness_in_data`` the surface's roughness too, along
    the beam (where a rough surface puts it).  Shared by the grazing-beam bias tests of the strip adjustment and of
    the joint laser factor."""
    import numpy as np

    rng = np.random.default_rng(seed)
    el = -np.radians(rng.uniform(10.0, 80.0, m))
    az = rng.uniform(0.0, 2 * np.pi, m)
    u = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    rho = h / -u[:, 2] + rng.normal(0.0, range_sigma, m)
    if roughness_in_data:
        rho += rng.normal(0.0, roughness, m) / -u[:, 2]
    return rho, u
