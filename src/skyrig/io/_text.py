"""Helpers shared by the text readers and writers: header parsing, numbers with file/line/field errors,
atomic writes."""

from __future__ import annotations

import gc
import os
import re
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

import numpy as np

from skyrig.errors import InputFormatError, OutputPathError

PathLike = str | os.PathLike[str]

__all__ = ["OutputPathError", "PathLike", "atomic_write", "check_output_dir", "output_temp", "float_column", "no_cyclic_gc",
           "parse_float", "publish", "read_text", "retire_side_cars"]  # OutputPathError lives in skyrig.errors; re-exported here where it was first defined


def read_text(path: PathLike) -> str:
    """The whole of a UTF-8 text file; a leading byte-order mark (as Excel writes) is dropped.

    Every skyrig text reader opens its file through this function.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise InputFormatError("file not found", p) from None
    except IsADirectoryError:
        raise InputFormatError("is a folder, not a file", p) from None
    except PermissionError:
        raise InputFormatError("cannot be read (permission denied)", p) from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise InputFormatError(f"not a UTF-8 text file ({exc.reason}, byte {data[exc.start:exc.start + 1]!r})", p,
                               line) from None
    nul = text.find("\x00")
    if nul >= 0:  # a name or number with a NUL in it would be read as another one: a damaged (or binary) file
        raise InputFormatError("NUL byte: a damaged or binary file, not text", p, text.count("\n", 0, nul) + 1)
    ctl = _CONTROL.search(text)
    if ctl:  # a control byte in a name would make it another name (and \x0b, \x0c, \x1c-\x1e split lines)
        raise InputFormatError(f"control character {ctl.group()!r} (byte {ctl.start() + 1}): a damaged or binary "
                               "file, not text", p, text.count("\n", 0, ctl.start()) + 1)
    return text.replace("\r\n", "\n").replace("\r", "\n")


#: Control characters no skyrig text file holds (tab, line feed and carriage return are allowed).
_CONTROL = re.compile("[\x01-\x08\x0b\x0c\x0e-\x1f\x7f]")


def parse_float(text: str, path: PathLike, line: int, field: str) -> float:
    """A finite float, or an InputFormatError naming file, line and field."""
    try:
        v = float(text)
    except ValueError:
        raise InputFormatError(f"{text.strip()!r} is not a number", path, line, field) from None
    if not np.isfinite(v):
        raise InputFormatError(f"{text.strip()!r} is not a finite number", path, line, field)
    return v


def float_column(values: list[str], path: PathLike, lines: list[int], field: str) -> np.ndarray:
    """A column of finite floats in one numpy conversion, or :func:`parse_float`'s error for its first bad value
    (naming file, line and field)."""
    try:
        a = np.array(values, dtype=np.float64)
    except ValueError:
        a = None
    if a is not None and (a.size == 0 or np.isfinite(a).all()):
        return a
    for v, line in zip(values, lines):  # find the first offender for the message
        parse_float(v, path, line, field)
    raise AssertionError(f"{path}: numpy refused column {field!r} but every value parsed")  # pragma: no cover


@contextmanager
def no_cyclic_gc() -> Iterator[None]:
    """The cyclic garbage collector off for a block: readers building millions of row lists and name tuples (no
    cycles among them) would otherwise have them rescanned again and again (4x the parse time at 1.5 million
    rows)."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _blocking_reason(p: Path) -> str | None:
    """Why no file or folder can be created at ``p`` (None when nothing is in the way)."""
    for anc in reversed(p.parents):
        if anc.exists() and not anc.is_dir():
            return f"'{anc}' is a file, not a folder"
    return None


def check_output_dir(path: PathLike, create: bool = True) -> Path:
    """Make sure ``path`` is, or can be created as, a folder (and create it unless ``create`` is False).

    Raises :class:`OutputPathError` naming the path.
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise OutputPathError("is a file, not a folder", p)
    why = _blocking_reason(p)
    if why:
        raise OutputPathError(why, p)
    if not create:
        return p
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputPathError(f"cannot create the folder ({exc.strerror or exc})", p) from None
    return p


def output_temp(path: PathLike, suffix: str = ".tmp") -> tuple[int, str]:
    """A temporary file ``(fd, name)`` next to output ``path``, to be renamed onto it when complete.

    The parent folders are created. Every atomic writer starts here, so that an output path that cannot be
    written is one clear :class:`OutputPathError` naming the path (never a traceback about the temporary file).
    The file gets the permissions a plainly created file would get (0666 less the umask), not ``mkstemp``'s 0600.
    """
    p = Path(path)
    if p.is_dir():
        raise OutputPathError("is a folder; give a file name", p)
    why = _blocking_reason(p)
    if why:
        raise OutputPathError(why, p)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=suffix, dir=p.parent)
    except PermissionError:
        raise OutputPathError(f"no permission to write in the folder '{p.parent}'", p) from None
    except OSError as exc:
        raise OutputPathError(f"cannot be written ({exc.strerror or exc})", p) from None
    try:
        os.fchmod(fd, 0o666 & ~_umask())
    except OSError:  # pragma: no cover - a file system without permissions
        pass
    return fd, tmp


def _umask() -> int:
    """The process umask, read without the thread-unsafe set-and-restore of ``os.umask`` where Linux allows."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def retire_side_cars(path: PathLike) -> None:
    """Remove the side-cars (``NAME.csv.json``, ``NAME.prj``, ``NAME.csvt``) of the table ``NAME.csv`` when its
    ``NAME.csv.json`` is a skyrig table statement: called just before a new table replaces ``path``, so that a run
    killed before it writes the new side-cars never leaves the new table described by the previous ones."""
    p = Path(path)
    if p.suffix.lower() != ".csv":
        return
    side = [p.with_name(p.name + ".json"), p.with_suffix(".prj"), p.with_suffix(".csvt")]
    try:
        head = side[0].read_bytes()[:4096] if side[0].is_file() else b""
    except OSError:
        return
    if b'"skyrig-table"' not in head:
        return  # no skyrig side-car: a .prj / .csvt next to a foreign CSV is not skyrig's to remove
    for s in side:
        try:
            s.unlink()
        except FileNotFoundError:
            pass
        except OSError as exc:
            raise OutputPathError(f"cannot remove the previous side-car '{s.name}' ({exc.strerror or exc})", p) from None


def publish(tmp: PathLike, path: PathLike) -> None:
    """Rename a complete temporary file onto ``path`` (see :func:`output_temp`).

    A table ``NAME.csv`` loses its skyrig side-cars first (:func:`retire_side_cars`); the writer writes the new
    ones after it (:func:`skyrig.io.table_meta.write_table_meta`).
    """
    retire_side_cars(path)
    try:
        os.replace(tmp, path)
    except OSError as exc:
        raise OutputPathError(f"cannot be replaced ({exc.strerror or exc})", path) from None


@contextmanager
def atomic_write(path: PathLike, mode: str = "w", newline: str | None = None) -> Iterator[IO]:
    """Write to a temporary file next to ``path`` and rename it into place only on success.

    Raises :class:`OutputPathError` when ``path`` cannot be written (see :func:`output_temp`).
    """
    p = Path(path)
    fd, tmp = output_temp(p)
    try:
        kwargs = {} if "b" in mode else {"encoding": "utf-8", "newline": newline}
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
        publish(tmp, p)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
