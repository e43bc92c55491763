"""The three adjustment variants of paper 004 (MIDAS blocks, Tables 2-11) as presets.

``ba-eo-control`` ("Bundle Adjustment + EO + Control")
    Bundle adjustment constraining the GNSS/IMU exterior orientation (weighted observations) and the
    control points, with a GNSS block shift; check points are reported.
``dg-control`` ("Direct Geo Referencing + Control")
    The GNSS/IMU orientations are held fixed (direct georeferencing); object points are intersected,
    control points enter with their sigma and together with the check points show the accuracy of
    direct georeferencing.
``refine-eo-check`` ("Refine POSEO with Check Points")
    The GNSS/IMU orientations are refined by the bundle adjustment (datum from GNSS alone: no block
    shift, which no control could separate from a translation); *all* ground points become check points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skyrig.adjust.block import AdjustConfig, Block

__all__ = ["Preset", "PRESETS", "apply_preset"]


@dataclass(frozen=True)
class Preset:
    """A named adjustment variant: the configuration and what happens to the control points."""

    name: str
    title: str
    config: AdjustConfig
    all_check: bool = False
    datum_shift_needs_gnss: bool = True


PRESETS: dict[str, Preset] = {
    "ba-eo-control": Preset("ba-eo-control", "Bundle Adjustment + EO + Control",
                            AdjustConfig(poses="free", datum_shift="free", snooping=True)),
    "dg-control": Preset("dg-control", "Direct Geo Referencing + Control", AdjustConfig(poses="fixed")),
    "refine-eo-check": Preset("refine-eo-check", "Refine EO with Check Points",
                              AdjustConfig(poses="free", snooping=True), all_check=True),
}


def apply_preset(block: Block, name: str, **overrides: object) -> tuple[Block, AdjustConfig]:
    """A copy of ``block`` with control roles set for preset ``name`` and its configuration.

    A GNSS datum shift is only estimated when the block has GNSS observations; ``overrides`` replace
    configuration fields.  Unknown names raise ``ValueError`` listing the presets.
    """
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; known: {', '.join(PRESETS)}")
    p = PRESETS[name]
    b = block.copy()
    cfg = p.config
    if p.all_check:
        b.control_check = np.ones(len(b.control_point), bool)  # type: ignore[arg-type]
    if not len(b.gnss_station):  # type: ignore[arg-type]
        cfg = cfg.with_(datum_shift="fixed")
    if overrides:
        cfg = cfg.with_(**overrides)
    return b, cfg
