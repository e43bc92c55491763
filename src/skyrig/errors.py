"""Exception hierarchy.

Every error skyrig raises on purpose derives from :class:`SkyrigError`; most also derive from
a builtin so that callers who catch ``ValueError`` keep working.  Errors about input files name
the file, the line and the field.
"""

from __future__ import annotations

import re
from os import PathLike
from typing import Any


_NUMPY_REPR = re.compile(r"np\.(?:float|int|uint|complex)\d*\(([^()]*)\)|np\.(?:str_|bytes_|bool_?)\(([^()]*)\)")


def plain_numbers(text: str) -> str:
    """``text`` without numpy reprs: ``np.float64(1.5)`` -> ``1.5``, ``np.str_('a')`` -> ``'a'`` (messages are
    for people; NumPy 2 writes its scalar types into every ``{value!r}``).

    >>> plain_numbers("time np.float64(345600.5) after np.str_('img1')")
    "time 345600.5 after 'img1'"
    """
    return _NUMPY_REPR.sub(lambda m: m.group(1) if m.group(1) is not None else m.group(2), text)


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
        message = plain_numbers(message)
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


class OutputPathError(SkyrigError, OSError):
    """An output file or folder cannot be written where the user asked (a path under a regular file, a folder
    where a file is expected, no permission...).

    ``path`` is the output as given; ``option`` the command-line option that named it, when known (the CLI
    fills it in from the command line when a library function raised the error).
    """

    def __init__(self, reason: str, path: str | PathLike[str], option: str | None = None) -> None:
        self.path = str(path)
        self.reason = reason
        self.option = option
        super().__init__(self._text())

    def _text(self) -> str:
        where = f"{self.option} {self.path}" if self.option else f"output {self.path}"
        return f"{where}: {self.reason}"

    def with_option(self, option: str, given: str | None = None) -> OutputPathError:
        """The same error naming the option (and the value given to it, when the path lies inside it)."""
        err = OutputPathError(self.reason, self.path, option)
        if given is not None and given != self.path:
            err = OutputPathError(f"{self.reason} (writing {self.path})", given, option)
        return err

    def __str__(self) -> str:
        return self._text()


class ConfigError(SkyrigError, ValueError):
    """A library option is unusable: a field of a configuration dataclass or an argument of a library function
    (an unknown method name, a value out of its range, options that contradict each other); the message names
    it and says what is accepted.  :class:`OptionError` is the same for an option as the user spells it."""


class OptionError(ConfigError):
    """An option's value is unusable (a command-line option or a project-file stage option): ``option`` names it as
    the caller spells it (``--heads``, ``stages.dsm.heads``)."""

    def __init__(self, option: str, reason: str) -> None:
        self.option = option
        self.reason = plain_numbers(reason)
        super().__init__(f"{option}: {self.reason}")


class SessionLockedError(SkyrigError, RuntimeError):
    """A file is held by another running program (e.g. a second ``skyrig measure`` on the same measurements file):
    the message names the lock file and its holder."""


class StopSignal(KeyboardInterrupt):
    """SIGTERM (or another stop signal) while a command runs: raised like Ctrl-C's KeyboardInterrupt, so that
    atomic writers and stage folders clean up the same way; ``signum`` says which signal."""

    def __init__(self, signum: int) -> None:
        self.signum = int(signum)
        super().__init__(f"stopped by signal {self.signum}")


class PlausibilityWarning(UserWarning):
    """Input that is possible but unusual enough to be a mistake (positions outside the CRS's area of use, a
    lever arm of more than 10 m...); see :mod:`skyrig.io.plausibility`.  The CLI prints it as ``warning: ...``."""


# ------------------------------------------------------------------ the errors of the packages' modules
# (each importable from its old module as well)


# raised in skyrig.adjust.factors.base
class BlockError(SkyrigError, ValueError):
    """A block is inconsistent (an observation naming an unknown image, a NaN, a point seen once...)."""


# raised in skyrig.adjust.solver
class SingularError(SkyrigError, ArithmeticError):
    """The normal equations are singular (datum defect, unobservable parameter); ``points``: the free-point
    indices that are not determined, when that is the reason (else None)."""

    points: Any = None


# raised in skyrig.adjust.adjust
class DatumDefectError(SingularError):
    """The block is rank deficient; ``reasons`` says why in words."""

    def __init__(self, reasons: list[str]) -> None:
        self.reasons = reasons
        super().__init__("; ".join(reasons) if reasons else "the normal equations are singular")


# raised in skyrig.adjust.linalg
class NotPositiveDefinite(SkyrigError, ArithmeticError):
    """The (scaled) reduced matrix is not numerically positive definite."""


# raised in skyrig.rig.presets
class UnknownPresetError(SkyrigError, KeyError):
    """No preset of that name (a ``KeyError`` and a :class:`~skyrig.errors.SkyrigError`)."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


# raised in skyrig.rig.rig
class HeadNotFoundError(SkyrigError, KeyError):
    """A rig has no head of the requested name (the message lists the heads it has)."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


# raised in skyrig.trajectory.events
class EventOutOfSpanError(InputFormatError, OutOfRangeError):
    """An event lies outside the trajectory's time span (names the events file, line and ``time``).

    Both an :class:`~skyrig.errors.InputFormatError` (it has ``path``, ``line``, ``field``) and an
    :class:`~skyrig.errors.OutOfRangeError`.
    """


# raised in skyrig.georef.transfer
class TransferError(SkyrigError, ValueError):
    """An oblique orientation cannot be transferred (no adjusted nadir exposure near it, unknown image...)."""


# raised in skyrig.orient.gnss_block
class UavAdjustError(SkyrigError, ValueError):
    """The UAV block cannot be oriented (no seed, too few tie points...); the message says why."""


# raised in skyrig.orient.incremental
class OrientError(UavAdjustError):
    """The block cannot be oriented without GNSS (no start pair, datum not determinable...); the message says
    why."""


# raised in skyrig.calibrate.camera
class CalibrationError(SkyrigError, ValueError):
    """A calibration cannot be computed or must not be trusted (the message says why)."""


# raised in skyrig.calibrate.gnss_imu
class CalibrationFailed(SkyrigError):
    """An adjustment of the recipe did not converge or cannot be trusted."""


# raised in skyrig.calibrate.calqc
class CalqcFailed(SkyrigError):
    """A step of the recipe did not converge or its result cannot be trusted."""


# raised in skyrig.calibrate.tumbling_reference
class ReferenceCameraMoved(CalibrationError):
    """The laboratory's static reference camera moved during the session: its images do not block-match in place
    (paper 000, 3.4: the recipe compares every tumbling image with one reference image, so the camera must not move)."""


# raised in skyrig.dense.ortho
class EmptyMosaicError(SkyrigError):
    """The stage ran but no image sees the surface (a failed result, not a bad input)."""


# raised in skyrig.io.trajectory_csv
class ImplausibleAngleError(InputFormatError, UnitError):
    """Angle values that cannot be in the unit the file declares (e.g. 250 declared as radians).

    Both an :class:`~skyrig.errors.InputFormatError` (``path``, ``line``, ``field``) and a
    :class:`~skyrig.errors.UnitError`.
    """


# issued in skyrig.io.table_meta
class SideCarMismatchWarning(UserWarning):
    """A table's side-car was written for another version of the table (an edit since, or another writer)."""


# raised in skyrig.pipeline.executor
class TaskError(SkyrigError, RuntimeError):
    """A task failed; the message names the item (and ``desc``), the original exception is the cause.

    Attributes
    ----------
    index
        Position of the failing item in the list given to :meth:`Executor.map`.
    item
        The failing item.
    """

    def __init__(self, message: str, index: int, item: object) -> None:
        super().__init__(message)
        self.index = index
        self.item = item


# raised in skyrig.pipeline.run
class StageError(SkyrigError, RuntimeError):
    """A stage failed.  ``exit_code`` is 2 for bad input, 1 for a failed run; ``stage`` names the stage."""

    def __init__(self, stage: str, message: str, exit_code: int = 1) -> None:
        super().__init__(f"stage {stage}: {message}")
        self.stage = stage
        self.reason = message
        self.exit_code = exit_code


# raised in skyrig.pipeline.facades
class NoBuildingsError(SkyrigError):
    """The stage ran but found nothing to model (no building in the DSM / footprints): a failed result."""


# raised in skyrig.web.tiles
class TileNotFound(SkyrigError, LookupError):
    """A tile outside the image's pyramid."""


def show_warnings_in_words() -> None:
    """Print every warning as one ``warning: message`` line on standard error, without Python's file and source
    line: :class:`PlausibilityWarning` as its words, any other with its class and the package it came from
    (``warning: invalid value encountered in divide (RuntimeWarning, numpy)``)."""
    import sys
    import warnings

    previous = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):  # type: ignore[no-untyped-def]
        words = " ".join(str(message).split())
        if not (isinstance(category, type) and issubclass(category, PlausibilityWarning)):
            where = _package_of(str(filename))
            words += f" ({getattr(category, '__name__', 'warning')}{', ' + where if where else ''})"
        try:
            print(f"warning: {words}", file=file or sys.stderr)
        except (OSError, ValueError):  # a closed stream: nothing to tell
            pass

    if getattr(previous, "_skyrig", False):
        return
    show._skyrig = True  # type: ignore[attr-defined]
    warnings.showwarning = show


def _package_of(filename: str) -> str:
    """The top-level package a source file belongs to (``.../site-packages/numpy/x.py`` -> ``numpy``), or ''."""
    parts = filename.replace("\\", "/").split("/")
    for key in ("site-packages", "dist-packages", "src"):
        if key in parts and parts.index(key) + 1 < len(parts) - 1:
            return parts[parts.index(key) + 1]
    return ""
