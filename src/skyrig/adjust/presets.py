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

A preset is a *variant*, not a whole configuration: it decides the fields in its ``decides`` (how the
orientations and the GNSS datum shift enter) and supplies defaults for a few others (blunder detection);
everything else - the system-calibration groups freed with ``skyrig block --free`` (boresight, lever arm,
intrinsics, strip shifts, ...), sigmas, solver options - comes from the block file's ``adjustment``
section (:func:`merge_preset`).  Where the block file explicitly sets a field the preset decides to
another value, the preset's value is used and the conflict is returned in words.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Iterable

import numpy as np

from skyrig.adjust.block import AdjustConfig, Block
from skyrig.adjust.config import PARTS, ReliabilityOptions, Unknowns
from skyrig.errors import ConfigError

__all__ = ["Preset", "PRESETS", "apply_preset", "merge_preset"]


@dataclass(frozen=True)
class Preset:
    """A named adjustment variant: the configuration and what happens to the control points."""

    name: str
    title: str
    config: AdjustConfig
    all_check: bool = False
    datum_shift_needs_gnss: bool = True
    #: configuration fields (``part.field``) the variant decides (and why, for conflict messages); its other non-default
    #: fields are defaults that an explicit setting in the block file overrides
    decides: tuple[tuple[str, str], ...] = ()


PRESETS: dict[str, Preset] = {
    "ba-eo-control": Preset("ba-eo-control", "Bundle Adjustment + EO + Control",
                            AdjustConfig(unknowns=Unknowns(poses="free", datum_shift="free"),
                                         reliability=ReliabilityOptions(snooping=True)),
                            decides=(("unknowns.poses", "the GNSS/IMU orientations are refined by the adjustment"),
                                     ("unknowns.datum_shift", "the control points determine a GNSS block shift"))),
    "dg-control": Preset("dg-control", "Direct Geo Referencing + Control",
                         AdjustConfig(unknowns=Unknowns(poses="fixed")),
                         decides=(("unknowns.poses", "direct georeferencing holds the GNSS/IMU orientations"),)),
    "refine-eo-check": Preset("refine-eo-check", "Refine EO with Check Points",
                              AdjustConfig(unknowns=Unknowns(poses="free"),
                                           reliability=ReliabilityOptions(snooping=True)), all_check=True,
                              decides=(("unknowns.poses", "the GNSS/IMU orientations are refined by the adjustment"),
                                       ("unknowns.datum_shift", "every ground point is a check point, so nothing "
                                        "separates a GNSS datum shift from a translation of the block"))),
}


def merge_preset(name: str, base: AdjustConfig | None = None, explicit: Iterable[str] = (),
                 has_gnss: bool = True) -> tuple[AdjustConfig, list[str]]:
    """The configuration of preset ``name`` merged with a block file's configuration.

    Parameters
    ----------
    name
        A key of :data:`PRESETS` (:class:`~skyrig.errors.ConfigError` listing them otherwise).
    base
        The block file's configuration (default: :class:`AdjustConfig` defaults).
    explicit
        The fields the block file sets explicitly, as ``part.field`` (``BlockFile.adjustment_keys``).
    has_gnss
        Whether the block has GNSS observations (without them no datum shift is estimated).

    Returns
    -------
    config, conflicts
        ``base`` with the fields the preset decides replaced, the preset's other settings where the
        block file is silent; and one sentence per explicit field the preset overrode.
    """
    if name not in PRESETS:
        raise ConfigError(f"unknown preset {name!r}; known: {', '.join(PRESETS)}")
    p = PRESETS[name]
    base = base or AdjustConfig()
    explicit = set(explicit)
    pc = p.config if has_gnss or not p.datum_shift_needs_gnss else p.config.with_unknowns(datum_shift="fixed")
    decided = dict(p.decides)
    changes: dict[str, dict[str, object]] = {part: {} for part in PARTS}
    conflicts: list[str] = []
    for part in PARTS:
        for f in fields(getattr(pc, part)):
            k = f"{part}.{f.name}"
            pv, bv = getattr(getattr(pc, part), f.name), getattr(getattr(base, part), f.name)
            if k in decided:
                if k in explicit and bv != pv:
                    conflicts.append(f"preset {name!r} sets {k} = {pv!r} although the block file's adjustment section "
                                     f"says {bv!r}: {decided[k]} (edit the block file or choose another preset)")
                changes[part][f.name] = pv
            elif k not in explicit and pv != f.default:
                changes[part][f.name] = pv
    if not has_gnss and "unknowns.datum_shift" not in explicit:
        changes["unknowns"]["datum_shift"] = "fixed"
    return replace(base, **{part: replace(getattr(base, part), **c) for part, c in changes.items()}), conflicts


def apply_preset(block: Block, name: str, base: AdjustConfig | None = None, explicit: Iterable[str] = ()
                 ) -> tuple[Block, AdjustConfig]:
    """A copy of ``block`` with control roles set for preset ``name`` and its configuration.

    The configuration is :func:`merge_preset` of the preset with ``base`` (a block file's configuration,
    ``explicit`` its explicitly set fields; default: none); a GNSS datum shift is only estimated when the
    block has GNSS observations.  Unknown names raise
    :class:`~skyrig.errors.ConfigError` listing the presets.  (:func:`merge_preset` also returns the conflicts in
    words.)
    """
    cfg, _ = merge_preset(name, base, explicit, bool(len(block.gnss_station)))
    p = PRESETS[name]
    b = block.copy()
    if p.all_check:
        b.control_check = np.ones(len(b.control_point), bool)
    return b, cfg
