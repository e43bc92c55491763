"""Exception hierarchy.

Every error skyrig raises on purpose derives from :class:`SkyrigError`; most also derive from
a builtin so that callers who catch ``ValueError`` keep working.  Errors about input files name
the file, the line and the field.
"""

from __future__ import annotations

import re
from os import PathLike


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


class OptionError(SkyrigError, ValueError):
    """An option's value is unusable (a command-line option or a project-file stage option): ``option`` names it as
    the caller spells it (``--heads``, ``stages.dsm.heads``)."""

    def __init__(self, option: str, reason: str) -> None:
        self.option = option
        self.reason = plain_numbers(reason)
        super().__init__(f"{option}: {self.reason}")


class StopSignal(KeyboardInterrupt):
    """SIGTERM (or another stop signal) while a command runs: raised like Ctrl-C's KeyboardInterrupt, so that
    atomic writers and stage folders clean up the same way; ``signum`` says which signal."""

    def __init__(self, signum: int) -> None:
        self.signum = int(signum)
        super().__init__(f"stopped by signal {self.signum}")


class PlausibilityWarning(UserWarning):
    """Input that is possible but unusual enough to be a mistake (positions outside the CRS's area of use, a
    lever arm of more than 10 m...); see :mod:`skyrig.io.plausibility`.  The CLI prints it as ``warning: ...``."""


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
