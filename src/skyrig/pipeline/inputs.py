"""What the library-level commands (:mod:`skyrig.pipeline`) read from the user's files and options, without a
command-line layer: cameras from camera / rig files and the images of some rig heads.

The CLI (:mod:`skyrig.cli`) and the project runner (:mod:`skyrig.pipeline.run`) both call these, so that a
``skyrig dsm`` and a project's ``dsm`` stage read their inputs the same way.  Errors are
:class:`skyrig.errors.SkyrigError` (bad input, exit status 2) naming the option as the caller spells it.
"""

from __future__ import annotations

from collections.abc import Sequence
from os import PathLike

import numpy as np

from skyrig.camera.frame import FrameCamera
from skyrig.errors import OptionError
from skyrig.georef.eo import ExteriorOrientations

__all__ = ["load_cameras", "head_rows", "select_heads"]


def load_cameras(paths: Sequence[str | PathLike[str]], option: str = "--camera") -> dict[str, FrameCamera]:
    """Cameras by name from IGN camera ``.txt`` files and/or skyrig rig files (YAML; every head is known by its
    head name and by its camera's name)."""
    out: dict[str, FrameCamera] = {}
    for p in map(str, paths):
        if p.lower().endswith((".yaml", ".yml")):
            from skyrig.io.rig_file import read_rig

            rig = read_rig(p)
            for name, head in rig.heads.items():
                out[name] = head.camera
                out[head.camera.name] = head.camera
        else:
            from skyrig.io.ign import read_ign_camera

            cam = read_ign_camera(p)
            out[cam.name] = cam
    if not out:
        raise OptionError(option, "no camera given")
    return out


def head_rows(eo: ExteriorOrientations, spec: str | Sequence[str]) -> tuple[list[str], list[np.ndarray]]:
    """For rig heads / image-name parts (a comma list or a sequence): the names and, per name, the rows of ``eo``
    that match (the image's head is the name, or its file name contains it)."""
    parts = spec.split(",") if isinstance(spec, str) else list(spec)
    want = [h.strip() for h in parts if h.strip()]
    return want, [np.flatnonzero([(eo.head is not None and str(eo.head[i]) == w) or w in str(n)
                                  for i, n in enumerate(eo.image)]) for w in want]


def select_heads(eo: ExteriorOrientations, spec: str | Sequence[str] | None,
                 option: str = "--heads") -> ExteriorOrientations:
    """The orientations of the images of some rig heads (see :func:`head_rows`); all when ``spec`` is empty.  A
    spec that matches no image is an :class:`OptionError` naming ``option``."""
    if not spec:
        return eo
    _, rows = head_rows(eo, spec)
    sel = np.unique(np.concatenate(rows)) if rows else np.zeros(0, int)
    if len(sel) == 0:
        text = spec if isinstance(spec, str) else ",".join(spec)
        raise OptionError(option, f"{text}: no image of the EO file matches")
    return eo.subset(sel)
