"""Camera events: when each head of a rig exposed an image, and at which actuator angle.

A multi-head rig fires several heads for one *platform exposure*; their events share an
``exposure_id``.  Heads on an actuator (a rotating or tilting mount) record the actuator angle
``beta`` at the exposure; fixed heads have ``beta = NaN``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import EventOutOfSpanError, InputFormatError  # noqa: F401 - EventOutOfSpanError re-exported
from skyrig.trajectory.trajectory import PositionMethod, Trajectory, TrajectorySample

__all__ = ["CameraEvents", "EventOutOfSpanError", "check_events_in_span", "interpolate_events"]


@dataclass(frozen=True, eq=False)
class CameraEvents:
    """``M`` camera events.

    Attributes
    ----------
    time_s
        ``(M,)`` exposure times in seconds, in ``time_system``.
    head
        ``(M,)`` str: name of the camera head that took the image.
    image_name
        ``(M,)`` str: image identifier (unique).
    beta_rad
        ``(M,)`` actuator angle in radians at the exposure; NaN for fixed heads.
    exposure_id
        ``(M,)`` int: events of different heads from one platform exposure share an id.
    time_system
        Time scale name; must match the trajectory's (see :class:`~skyrig.trajectory.Trajectory`).
    source
        File the events were read from, if any (used in error messages).
    source_line
        ``(M,)`` int: 1-based line of each event in ``source``, if read from a file.
    """

    time_s: NDArray[np.float64]
    head: NDArray[np.str_]
    image_name: NDArray[np.str_]
    beta_rad: NDArray[np.float64]
    exposure_id: NDArray[np.int64]
    time_system: str = "gps-sow"
    source: str | None = None
    source_line: NDArray[np.int64] | None = None

    def __post_init__(self) -> None:
        t = np.array(self.time_s, dtype=np.float64).reshape(-1)
        m = t.shape[0]

        def where(k: int) -> dict:
            line = None if self.source_line is None else int(np.asarray(self.source_line)[k])
            return {"path": self.source, "line": line}

        if not np.all(np.isfinite(t)):
            k = int(np.argmax(~np.isfinite(t)))
            raise InputFormatError(f"event time at index {k} is not finite", field="time", **where(k))
        head = np.array(self.head, dtype=str).reshape(-1)
        name = np.array(self.image_name, dtype=str).reshape(-1)
        beta = np.array(self.beta_rad, dtype=np.float64).reshape(-1)
        expo = np.array(self.exposure_id).reshape(-1)
        lines = None if self.source_line is None else np.array(self.source_line, dtype=np.int64).reshape(-1)
        for fname, a in (("head", head), ("image", name), ("beta", beta), ("exposure", expo),
                         ("source_line", lines)):
            if a is not None and a.shape[0] != m:
                raise InputFormatError(f"{a.shape[0]} values for {m} events", field=fname)
        if expo.size and not np.issubdtype(expo.dtype, np.integer):
            raise InputFormatError("exposure ids must be integers", field="exposure")
        if np.any(np.isinf(beta)):
            k = int(np.argmax(np.isinf(beta)))
            raise InputFormatError(f"actuator angle at index {k} is infinite", field="beta", **where(k))
        _, first = np.unique(name, return_index=True)
        if first.size < m:
            repeated = np.ones(m, bool)
            repeated[first] = False
            k = int(np.argmax(repeated))  # first event (in input order) repeating an earlier name
            raise InputFormatError(f"duplicate image name {name[k]!r}", field="image", **where(k))
        for n, a in (("time_s", t), ("head", head), ("image_name", name), ("beta_rad", beta),
                     ("exposure_id", expo.astype(np.int64)), ("source_line", lines)):
            if a is not None:
                a.setflags(write=False)
            object.__setattr__(self, n, a)

    @classmethod
    def create(
        cls,
        time_s: ArrayLike,
        head: ArrayLike,
        image_name: ArrayLike,
        beta_rad: ArrayLike | None = None,
        exposure_id: ArrayLike | None = None,
        time_system: str = "gps-sow",
        source: str | None = None,
        source_line: ArrayLike | None = None,
    ) -> "CameraEvents":
        """Events with defaults: ``beta_rad`` all NaN (fixed heads) and, when ``exposure_id`` is None,
        one exposure per distinct time stamp (events with exactly equal times share an id, numbered
        0, 1, ... in time order)."""
        t = np.asarray(time_s, dtype=np.float64).reshape(-1)
        beta = np.full(t.shape, np.nan) if beta_rad is None else beta_rad
        if exposure_id is None:
            _, exposure_id = np.unique(t, return_inverse=True)
        return cls(t, np.asarray(head), np.asarray(image_name), np.asarray(beta, dtype=np.float64),
                   np.asarray(exposure_id), time_system, source, None if source_line is None
                   else np.asarray(source_line))

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def heads(self) -> list[str]:
        """Distinct head names, sorted."""
        return sorted(set(self.head.tolist()))

    def subset(self, index: ArrayLike) -> "CameraEvents":
        """The events selected by an integer index array or a boolean mask ``(M,)``."""
        idx = np.asarray(index)
        return CameraEvents(
            self.time_s[idx], self.head[idx], self.image_name[idx], self.beta_rad[idx], self.exposure_id[idx],
            self.time_system, self.source, None if self.source_line is None else self.source_line[idx],
        )

    def for_head(self, head: str) -> "CameraEvents":
        """The events of one head."""
        return self.subset(self.head == head)


def check_events_in_span(events: CameraEvents, trajectory: Trajectory) -> None:
    """Check that all events lie within the trajectory's time span and use its time system.

    Raises
    ------
    EventOutOfSpanError
        Naming the events file, the line of the first event outside the span, and field ``time``.
    InputFormatError
        If the time systems differ (field ``time``).
    """
    if events.time_system != trajectory.time_system:
        raise InputFormatError(
            f"events are in time system {events.time_system!r} but the trajectory is in "
            f"{trajectory.time_system!r}", path=events.source, field="time",
        )
    t0, t1 = trajectory.span
    bad = ~((events.time_s >= t0) & (events.time_s <= t1))
    if np.any(bad):
        k = int(np.argmax(bad))
        line = None if events.source_line is None else int(events.source_line[k])
        raise EventOutOfSpanError(
            f"event {k} (image {events.image_name[k]!r}) at time {events.time_s[k]!r} is outside the "
            f"trajectory's time span [{t0!r}, {t1!r}]", path=events.source, line=line, field="time",
        )


def interpolate_events(
    trajectory: Trajectory, events: CameraEvents, position: PositionMethod = "cubic"
) -> TrajectorySample:
    """The trajectory interpolated at every event time (see :meth:`Trajectory.interpolate`).

    Raises
    ------
    EventOutOfSpanError
        For an event outside the trajectory's span (names file, line and ``time``).
    """
    check_events_in_span(events, trajectory)
    return trajectory.interpolate(events.time_s, position=position)
