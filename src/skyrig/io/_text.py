"""Helpers shared by the text readers and writers: header parsing, numbers with file/line/field errors,
atomic writes."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

import numpy as np

from skyrig.errors import InputFormatError

PathLike = str | os.PathLike[str]


def read_text(path: PathLike) -> str:
    """The whole of a UTF-8 text file; a leading byte-order mark (as Excel writes) is dropped.

    Every skyrig text reader opens its file through this function.
    """
    p = Path(path)
    try:
        return p.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputFormatError("file not found", p) from None
    except IsADirectoryError:
        raise InputFormatError("is a folder, not a file", p) from None
    except PermissionError:
        raise InputFormatError("cannot be read (permission denied)", p) from None
    except UnicodeDecodeError as exc:
        raise InputFormatError(f"not a UTF-8 text file ({exc.reason})", p) from None


def parse_float(text: str, path: PathLike, line: int, field: str) -> float:
    """A finite float, or an InputFormatError naming file, line and field."""
    try:
        v = float(text)
    except ValueError:
        raise InputFormatError(f"{text.strip()!r} is not a number", path, line, field) from None
    if not np.isfinite(v):
        raise InputFormatError(f"{text.strip()!r} is not a finite number", path, line, field)
    return v


@contextmanager
def atomic_write(path: PathLike, mode: str = "w", newline: str | None = None) -> Iterator[IO]:
    """Write to a temporary file next to ``path`` and rename it into place only on success."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    try:
        kwargs = {} if "b" in mode else {"encoding": "utf-8", "newline": newline}
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
        os.replace(tmp, p)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
