"""A stage's output folder published as a set: written in a staging folder, manifest last, renamed into place.

A killed run never leaves a folder whose files come from two runs: the previous folder stays as it was until
the new one is complete, then the two are swapped (rename) and the old one removed.  The manifest
(``manifest.json``) lists the inputs (path, size, SHA-256), the options, the software version, the date and
every output file with its size and SHA-256.

A run killed while staging leaves a ``.NAME.partial-*`` sibling (and the scratch a stage keeps beside its staging
folder, ``..NAME.partial-*.scratch-*``), one killed while swapping a ``.NAME.old-*`` sibling; the next run removes those older than itself (:func:`clean_stale`) and, when the kill fell between the
two renames of the swap (NAME absent, the previous complete folder inside ``.NAME.old-*``), puts the previous
folder back first.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

from skyrig.io._text import OutputPathError, PathLike, _blocking_reason, _umask

MANIFEST = "manifest.json"


def sha256_file(path: PathLike, chunk: int = 1 << 20) -> str:
    """Hex SHA-256 of a file."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while True:
            b = fh.read(chunk)
            if not b:
                return h.hexdigest()
            h.update(b)


def describe_inputs(paths: list[PathLike]) -> list[dict[str, Any]]:
    """``[{path, size, sha256}]`` of input files (folders: path only)."""
    out = []
    for p in paths:
        q = Path(p)
        if q.is_file():
            out.append({"path": str(q.resolve()), "size": q.stat().st_size, "sha256": sha256_file(q)})
        else:
            out.append({"path": str(q.resolve())})
    return out


def clean_stale(outdir: PathLike, started: float | None = None) -> list[Path]:
    """Remove the ``.NAME.partial-*`` / ``.NAME.old-*`` siblings of ``outdir`` last modified before ``started``
    (a Unix time; default now) - what killed runs left - and the scratch folders named after such a staging folder
    (``..NAME.partial-*``).  When ``outdir`` is absent and such an ``.old-*`` sibling
    holds the previously published folder (a run killed between the two renames of the swap), that folder is moved
    back to ``outdir`` first.  Returns the paths removed."""
    out = Path(outdir)
    if not out.parent.is_dir():
        return []
    t = time.time() if started is None else started
    stale = []
    for p in out.parent.iterdir():
        # a stage's scratch beside its staging folder is named after it: ``..NAME.partial-*.scratch-*`` (the dsm
        # stage's tiles, :func:`skyrig.pipeline.dense.run_dsm`)
        if not (p.name.startswith(f".{out.name}.partial-") or p.name.startswith(f".{out.name}.old-")
                or p.name.startswith(f"..{out.name}.partial-")):
            continue
        try:
            if p.is_dir() and not p.is_symlink() and p.stat().st_mtime < t:
                stale.append(p)
        except OSError:
            continue
    if not out.exists() and not out.is_symlink():
        olds = sorted((p for p in stale if ".old-" in p.name and (p / out.name / MANIFEST).is_file()),
                      key=lambda p: p.stat().st_mtime)
        if olds:
            os.replace(olds[-1] / out.name, out)
    for p in stale:
        shutil.rmtree(p, ignore_errors=True)
    return stale


@contextmanager
def stage_folder(outdir: PathLike, *, stage: str, inputs: list[dict[str, Any]] | None = None,
                 options: dict[str, Any] | None = None, started: float | None = None) -> Iterator[Path]:
    """Yield a staging folder next to ``outdir``; on success write the manifest and swap it into place.

    On any exception the staging folder is removed and ``outdir`` is left untouched.  First the stale siblings
    of killed runs older than ``started`` (the run's start, a Unix time; default now) go (:func:`clean_stale`).
    """
    from skyrig import __version__

    out = Path(outdir)
    why = _blocking_reason(out)
    if why:
        raise OutputPathError(why, out)
    if out.exists() and not out.is_dir():
        raise OutputPathError("is a file; give a folder", out)
    clean_stale(out, started)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
        os.chmod(tmp, 0o777 & ~_umask())
    except OSError as exc:
        raise OutputPathError(f"cannot create a folder next to it ({exc.strerror or exc})", out) from None
    t0 = time.time()
    try:
        yield tmp
        files = []
        for f in sorted(tmp.rglob("*")):
            if f.is_file() and f.name != MANIFEST:
                files.append({"path": str(f.relative_to(tmp)), "size": f.stat().st_size, "sha256": sha256_file(f)})
        manifest = {"format": "skyrig-manifest", "version": 1, "stage": stage, "software": f"skyrig {__version__}",
                    "created": time.strftime("%Y-%m-%dT%H:%M:%S%z", time.localtime(t0)),
                    "seconds": round(time.time() - t0, 3), "inputs": inputs or [], "options": options or {},
                    "files": files}
        (tmp / MANIFEST).write_text(json.dumps(manifest, indent=1, default=str) + "\n")
        old = None
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
            os.replace(out, old / out.name)
        os.replace(tmp, out)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def read_manifest(outdir: PathLike) -> dict[str, Any]:
    """The manifest of a published stage folder."""
    return json.loads((Path(outdir) / MANIFEST).read_text())


def verify_folder(outdir: PathLike) -> list[str]:
    """Problems of a published folder: files missing, changed or not in the manifest (empty = consistent)."""
    out = Path(outdir)
    if not (out / MANIFEST).is_file():
        return [f"{out}: no {MANIFEST}"]
    m = read_manifest(out)
    problems = []
    listed = set()
    for f in m["files"]:
        p = out / f["path"]
        listed.add(f["path"])
        if not p.is_file():
            problems.append(f"{f['path']}: missing")
        elif p.stat().st_size != f["size"] or sha256_file(p) != f["sha256"]:
            problems.append(f"{f['path']}: differs from the manifest")
    for p in out.rglob("*"):
        rel = str(p.relative_to(out))
        if p.is_file() and rel != MANIFEST and rel not in listed:
            problems.append(f"{rel}: not in the manifest")
    return problems
