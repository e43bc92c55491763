"""What a parsed project file is: :class:`Project` with its :class:`StageSpec` list and :class:`ExecutorSpec`, and
the :class:`Option` a stage declares.  The data only; :mod:`skyrig.pipeline.project` parses and checks a project file
into these (with the stage table of :mod:`skyrig.pipeline.run`, which itself needs these classes: keeping them here
keeps the imports one-way).  All are importable from :mod:`skyrig.pipeline.project` as before.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from skyrig.errors import InputFormatError

__all__ = ["Project", "StageSpec", "ExecutorSpec", "Option"]


@dataclass(frozen=True)
class Option:
    """One option of a stage: default, type and help (a registry entry's ``options`` maps names to these).

    ``kind``: ``"float"``, ``"int"``, ``"bool"``, ``"str"``, ``"file"`` (a path relative to the project file's
    folder; the file must exist when the project is loaded), ``"choice"`` (one of ``choices``), ``"floats"``
    (a list of ``n`` numbers, any length when ``n`` is None) or ``"strs"`` (a list of text).  ``None`` is
    accepted when ``nullable`` (the default is then often None = "decided by the stage")."""

    default: Any
    kind: str
    help: str
    choices: tuple[str, ...] = ()
    n: int | None = None
    nullable: bool = False
    positive: bool = False

    def check(self, value: Any) -> Any:
        """The value converted to its plain type; raises ``ValueError`` with the reason in words."""
        if value is None:
            if self.nullable:
                return None
            raise ValueError("must not be null")
        k = self.kind
        if k in ("float", "int"):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"expected a number, got {value!r}")
            if k == "int" and int(value) != value:
                raise ValueError(f"expected a whole number, got {value!r}")
            if self.positive and value <= 0:
                raise ValueError(f"must be positive, got {value!r}")
            return int(value) if k == "int" else float(value)
        if k == "bool":
            if not isinstance(value, bool):
                raise ValueError(f"expected true or false, got {value!r}")
            return value
        if k in ("str", "file"):
            if not isinstance(value, str) or not value.strip():
                raise ValueError(f"expected text, got {value!r}")
            return value
        if k == "choice":
            if value not in self.choices:
                raise ValueError(f"expected one of {', '.join(self.choices)}, got {value!r}")
            return value
        if k == "floats":
            if not isinstance(value, list) or any(isinstance(v, bool) or not isinstance(v, (int, float))
                                                  or not math.isfinite(v) for v in value):
                raise ValueError(f"expected a list of numbers, got {value!r}")
            if self.n is not None and len(value) != self.n:
                raise ValueError(f"expected {self.n} numbers, got {len(value)}")
            if self.positive and any(v <= 0 for v in value):
                raise ValueError(f"numbers must be positive, got {value!r}")
            return [float(v) for v in value]
        if k == "strs":
            if isinstance(value, str):
                value = [value]
            if not isinstance(value, list) or any(not isinstance(v, str) or not v.strip() for v in value):
                raise ValueError(f"expected a list of names, got {value!r}")
            if self.choices:
                bad = [v for v in value if v not in self.choices]
                if bad:
                    raise ValueError(f"unknown {bad[0]!r}; known: {', '.join(self.choices)}")
            return list(value)
        raise ValueError(f"option kind {k!r} unknown")  # pragma: no cover - a registry bug


@dataclass(frozen=True)
class StageSpec:
    """A stage as the project file lists it: its name, its options (defaults filled in) and the line."""

    name: str
    options: dict[str, Any]
    line: int | None = None


@dataclass(frozen=True)
class ExecutorSpec:
    """Where parallel work runs (:class:`skyrig.pipeline.executor.Executor`): ``auto`` / ``serial`` / ``local``,
    local worker processes, or a ``dask.distributed`` scheduler address.  Not part of a stage's fingerprint:
    every executor gives the same outputs."""

    kind: str = "auto"
    workers: int | None = None
    scheduler: str | None = None


@dataclass(frozen=True)
class Project:
    """A parsed, validated project file.  Paths are absolute; ``None`` / empty where the file gives none."""

    path: Path
    name: str
    crs: str | None  # None: an orientation without GNSS in its model frame (no product needs a map CRS)
    geoid: str | None
    output: Path
    images: tuple[Path, ...] = ()
    trajectory: Path | None = None
    events: Path | None = None
    rig: Path | None = None
    eo: Path | None = None
    cameras: tuple[Path, ...] = ()
    control: Path | None = None
    check: Path | None = None
    measurements: tuple[Path, ...] = ()
    executor: ExecutorSpec = ExecutorSpec()
    stages: tuple[StageSpec, ...] = ()
    lines: dict[str, int] = field(default_factory=dict)  # key path -> line, for error messages
    scale_bars: Path | None = None  # scale bars CSV from,to,length_m[,sigma_m] (orientation without GNSS)
    ties: Path | None = None  # tie points measured elsewhere (point,image,column,row) instead of a match stage
    laser: tuple[Path, ...] = ()  # laser data: a raw scan CSV (with strips) or georeferenced LAS/LAZ files

    @property
    def root(self) -> Path:
        """The folder of the project file (paths in it are relative to this)."""
        return self.path.parent

    def stage(self, name: str) -> StageSpec:
        """The stage ``name`` as listed (``KeyError`` if it is not)."""
        for s in self.stages:
            if s.name == name:
                return s
        raise KeyError(name)

    def error(self, message: str, key_path: str) -> InputFormatError:
        """An error naming this project file, the line of ``key_path`` (or its nearest parent) and the key path."""
        kp = key_path
        while kp and kp not in self.lines:
            kp = kp.rpartition(".")[0]
        return InputFormatError(message, self.path, self.lines.get(kp), key_path)
