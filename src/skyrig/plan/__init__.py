"""Layer 2: flight planning (strips, stations, footprints, GSD per head, overlaps, coverage, tumbling schedule)."""

from skyrig.plan.flight import (
    CoverageMap,
    FlightPlan,
    HeadGsd,
    OverlapStats,
    coverage_map,
    footprints,
    frame_from_body_rotation,
    gsd_per_head,
    head_footprint_extent,
    overlap_stats,
    plan_flight,
    reference_head,
    tumble_schedule,
)

__all__ = [
    "CoverageMap", "FlightPlan", "HeadGsd", "OverlapStats", "coverage_map", "footprints", "frame_from_body_rotation",
    "gsd_per_head", "head_footprint_extent", "overlap_stats", "plan_flight", "reference_head", "tumble_schedule",
]
