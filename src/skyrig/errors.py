"""Exception hierarchy.

Every error skyrig raises on purpose derives from :class:`SkyrigError`; most also derive from
a builtin so that callers who catch ``ValueError`` keep working.  Errors about input files name
the file, the line and the field.
"""

from __future__ import annotations

from os import PathLike


class SkyrigError(Exception):
    """Root of all skyrig errors."""


class InputFormatError(SkyrigError, ValueError):
    """A file or record could not be understood.

    Parameters
    ----------
    message
        What is wrong, in words.
    path
        The file, if any.
    line
        1-based line number (or record number for binary files), if known.
    field
        The column / field name, if known.
    """

    def __init__(
        self,
        message: str,
        path: str | PathLike[str] | None = None,
        line: int | None = None,
        field: str | None = None,
    ) -> None:
        self.path = None if path is None else str(path)
        self.line = line
        self.field = field
        self.reason = message
        where = []
        if self.path is not None:
            where.append(self.path)
        if line is not None:
            where.append(f"line {line}")
        if field is not None:
            where.append(f"field '{field}'")
        prefix = ", ".join(where)
        super().__init__(f"{prefix}: {message}" if prefix else message)


class CRSError(SkyrigError, ValueError):
    """A coordinate reference system or a geoid grid is unknown or unusable."""


class UnitError(SkyrigError, ValueError):
    """An angle or length unit is unknown, or values cannot be in the stated unit."""


class FrameError(SkyrigError, ValueError):
    """Two transforms with mismatched frame names were composed."""


class OutOfRangeError(SkyrigError, ValueError):
    """A query lies outside the data's domain (e.g. an event outside a trajectory's time span)."""


class GeometryError(SkyrigError, ValueError):
    """Degenerate or impossible geometry (a ray parallel to a plane, a point behind the camera...)."""
