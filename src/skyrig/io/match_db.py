"""Resumable storage of features and pair matches: one ``.npz`` per image and per pair, written atomically.

Layout under the database folder::

    config.json                 feature/matching settings the stored results were made with
    features/<image>.npz        xy, scale, angle_deg, descriptors, image_size
    matches/<image1>__<image2>.npz   matches, F, n_putative, guided, reason

A file only appears once complete (temp file + ``os.replace``), so an interrupted run loses nothing already
written and a restart skips it.  A rejected pair is stored too (with its reason), so it is not retried.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np

from skyrig.errors import InputFormatError
from skyrig.io._text import PathLike
from skyrig.match.features import Features
from skyrig.match.matching import PairMatches


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


def _atomic_savez(path: Path, **arrays: object) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp.npz", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)  # type: ignore[arg-type]
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


class MatchDatabase:
    """Folder of per-image features and per-pair matches (see module doc).

    Parameters
    ----------
    root
        Database folder (created).
    config
        JSON-able settings; if the folder already holds results made with different settings, a
        :class:`InputFormatError` says so (use ``overwrite=True`` to start afresh).
    overwrite
        Delete stored results first.
    """

    def __init__(self, root: PathLike, config: dict | None = None, overwrite: bool = False) -> None:
        self.root = Path(root)
        (self.root / "features").mkdir(parents=True, exist_ok=True)
        (self.root / "matches").mkdir(parents=True, exist_ok=True)
        cfg_path = self.root / "config.json"
        if overwrite:
            for sub in ("features", "matches"):
                for f in (self.root / sub).glob("*.npz"):
                    f.unlink()
            if cfg_path.exists():
                cfg_path.unlink()
        if config is not None:
            text = json.dumps(config, sort_keys=True, indent=1, default=str)
            if cfg_path.exists():
                old = cfg_path.read_text()
                if json.loads(old) != json.loads(text):
                    raise InputFormatError("stored matches were made with other settings; "
                                           "rerun with --overwrite (or another output folder)", cfg_path)
            else:
                tmp = cfg_path.with_suffix(".tmp")
                tmp.write_text(text)
                os.replace(tmp, cfg_path)

    # ------------------------------------------------------------ features
    def feature_path(self, image: str) -> Path:
        return self.root / "features" / f"{_safe(image)}.npz"

    def has_features(self, image: str) -> bool:
        return self.feature_path(image).is_file()

    def write_features(self, image: str, f: Features) -> None:
        _atomic_savez(self.feature_path(image), xy=f.xy, scale=f.scale, angle_deg=f.angle_deg,
                      descriptors=f.descriptors, image_size=np.array(f.image_size))

    def read_features(self, image: str) -> Features:
        p = self.feature_path(image)
        try:
            with np.load(p) as z:
                return Features(z["xy"], z["scale"], z["angle_deg"], z["descriptors"],
                                (int(z["image_size"][0]), int(z["image_size"][1])))
        except FileNotFoundError:
            raise InputFormatError("no stored features", p) from None
        except (OSError, KeyError, ValueError) as exc:
            raise InputFormatError(f"damaged feature file ({exc}); delete it to recompute", p) from None

    # ------------------------------------------------------------ matches
    def match_path(self, image1: str, image2: str) -> Path:
        return self.root / "matches" / f"{_safe(image1)}__{_safe(image2)}.npz"

    def has_matches(self, image1: str, image2: str) -> bool:
        return self.match_path(image1, image2).is_file()

    def write_matches(self, image1: str, image2: str, m: PairMatches) -> None:
        _atomic_savez(self.match_path(image1, image2), matches=m.matches, F=m.F, n_putative=m.n_putative,
                      guided=m.guided, reason=np.array(m.reason))

    def read_matches(self, image1: str, image2: str) -> PairMatches:
        p = self.match_path(image1, image2)
        try:
            with np.load(p) as z:
                return PairMatches(z["matches"].astype(np.int64), z["F"], int(z["n_putative"]), bool(z["guided"]),
                                   str(z["reason"]))
        except FileNotFoundError:
            raise InputFormatError("no stored matches", p) from None
        except (OSError, KeyError, ValueError) as exc:
            raise InputFormatError(f"damaged match file ({exc}); delete it to recompute", p) from None
