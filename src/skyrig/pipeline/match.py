"""Tie points for a block of images on disk (the stage behind ``skyrig match``): resumable, parallel through
:class:`skyrig.pipeline.executor.Executor` (or Dask's local thread pool).

PROJECT is a folder; images are taken from ``PROJECT/images`` if it exists, else from PROJECT itself, or from
one or more ``--images`` folders (e.g. one per rig head).  Results go to ``PROJECT/match`` (or ``--out``):
``features/`` and ``matches/`` (resumable store), ``tie_points.csv`` (point,image,column,row; skyrig pixels),
``report.json`` and ``coverage.png``.

Pairs: ``guided`` (footprints from the images' own GPS + DJI gimbal attitudes, or ``--eo`` + ``--camera``),
``gps`` (nearest centres + heading), ``exhaustive``; ``auto`` picks guided when attitudes exist, else gps.
Guided pairs are kept to a per-image budget (``max_pairs_per_image``, default :data:`MAX_PAIRS_PER_IMAGE`;
0 / None = every overlapping pair) by :func:`skyrig.match.pairs.budget_pairs`: the strongest overlaps of each
image, a spanning tree that keeps the block connected, and every image's links to the other heads and to the
strips on both sides, so that the pairs grow linearly with the block.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.errors import InputFormatError, SkyrigError
from skyrig.georef.eo import ExteriorOrientations
from skyrig.io.image_read import (
    ImageMetadata, camera_from_metadata, list_images, orientations_from_metadata, read_image, read_image_metadata,
)
from skyrig.io.match_db import MatchDatabase
from skyrig.match.features import FeatureConfig, extract_features
from skyrig.match.matching import MatchConfig, PairMatches, match_pair
from skyrig.match.pairs import budget_pairs, exhaustive_pairs, footprint_pairs, gps_pairs, image_strips
from skyrig.match.report import coverage_image, tie_point_report
from skyrig.match.tracks import Tracks, build_tracks, thin_tracks, tracks_to_measurements

logger = logging.getLogger(__name__)

#: Default per-image pair budget of guided matching (:func:`skyrig.match.pairs.budget_pairs`).  On the grown
#: simulated MIDAS blocks (bench/run.py --grow; min_overlap 0.1) every overlapping pair gives 15 / 45 / 70 pairs
#: per image at 60 / 240 / 540 images; with 12, 10 / 13 / 13 (the kept head and strip links add a few above 12).
MAX_PAIRS_PER_IMAGE = 12


@dataclass
class MatchRunResult:
    """What :func:`match_images` produced."""

    names: list[str]
    skipped: dict[str, str]
    pairs: np.ndarray
    pair_mode: str
    pair_matches: dict[tuple[int, int], PairMatches]
    features: list
    tracks: Tracks
    thinned: Tracks
    report: dict
    timings_s: dict[str, float] = field(default_factory=dict)


def collect_images(folders: Sequence[str | Path]) -> tuple[list[ImageMetadata], dict[str, str]]:
    """Metadata of all images in the folders; unreadable images are skipped with a logged reason.

    Raises
    ------
    InputFormatError
        Two images share a name (the name is the image identifier), or no image is readable.
    """
    metas: list[ImageMetadata] = []
    skipped: dict[str, str] = {}
    seen: dict[str, str] = {}
    for folder in folders:
        for p in list_images(folder):
            if p.name in seen:
                raise InputFormatError(f"duplicate image name {p.name!r} (also {seen[p.name]}); image names must "
                                       "be unique across folders", p)
            seen[p.name] = str(p)
            try:
                metas.append(read_image_metadata(p))
            except InputFormatError as exc:
                logger.warning("skipping %s: %s", p, exc.reason)
                skipped[p.name] = exc.reason
    if not metas:
        raise InputFormatError("no readable images", ", ".join(str(f) for f in folders))
    return metas, skipped


def _extract_one(path: str, name: str, db_root: str, cfg: FeatureConfig, camera: FrameCamera | None = None,
                 world_from_camera: object = None, ground_height: float | None = None) -> str:
    db = MatchDatabase(db_root)
    if db.has_features(name):
        return "cached"
    try:
        img = read_image(path)
    except InputFormatError as exc:
        return f"skip: {exc.reason}"
    db.write_features(name, extract_features(img, cfg, camera, world_from_camera, ground_height))
    return "done"


def _seed_pair(a: str, b: str) -> None:
    """Seed the random generators matching draws from (FLANN's randomised trees use the C library's ``rand``,
    OpenCV's own RNG) from the pair's names: a pair's matches then do not depend on which pairs the process
    matched before, so a serial run, local worker processes and a cluster give the same tie points (measured:
    without it, 41 of 42 pairs of the midas-demo block differed between ``sync`` and ``processes``).  Dask's
    ``threads`` scheduler shares one ``rand`` among threads and stays order-dependent."""
    import ctypes
    import zlib

    import cv2

    seed = zlib.crc32(f"{a}\0{b}".encode())
    cv2.setRNGSeed(seed & 0x7FFFFFFF)
    try:
        ctypes.CDLL(None).srand(ctypes.c_uint(seed))
    except (OSError, AttributeError):  # pragma: no cover - no C library symbol table (not on Linux / macOS)
        pass


def _match_one(name_i: str, name_j: str, db_root: str, cfg: MatchConfig, cam_i: FrameCamera | None,
               pose_i: object, cam_j: FrameCamera | None, pose_j: object) -> str:
    """Match one pair.  The task carries its two images' own camera and pose only: a task holding the block's lists
    was pickled once per pair, memory ~ images x pairs in the process submitting them (``bench/run.py --grow 3
    --executor local``, 540 images: the match stage's peak 4,417 MiB)."""
    db = MatchDatabase(db_root)
    if db.has_matches(name_i, name_j):
        return "cached"
    f1, f2 = db.read_features(name_i), db.read_features(name_j)
    _seed_pair(name_i, name_j)
    pm = match_pair(f1, f2, cfg, cam_i, pose_i, cam_j, pose_j)
    db.write_matches(name_i, name_j, pm)
    return "done"


def _call(task: Callable[[], str]) -> str:
    return task()


def _run_dask(tasks: list[Callable[[], str]], scheduler: str, workers: int,
              progress: Callable[[int], None] | None) -> list[str]:
    """Run the tasks: ``"threads"`` on Dask's local thread pool; ``"sync"`` / ``"serial"`` in this process,
    ``"processes"`` / ``"local"`` on local worker processes and ``"tcp://..."`` on a ``dask.distributed``
    scheduler, all three through :class:`skyrig.pipeline.executor.Executor` (workers on other machines must see
    the match folder under the same path).  ``progress(k)`` is called with the number of tasks just finished."""
    if scheduler == "threads":
        import dask
        from dask.callbacks import Callback

        class _Tick(Callback):
            def _posttask(self, key, result, dsk, state, id):  # noqa: ANN001, A002
                if progress is not None and str(key).startswith("skyrig-task-"):
                    progress(1)

        delayed = [dask.delayed(t, pure=False)(dask_key_name=f"skyrig-task-{k}") for k, t in enumerate(tasks)]
        with _Tick():
            return list(dask.compute(*delayed, scheduler="threads", num_workers=workers))
    from skyrig.pipeline.executor import Executor

    if scheduler in ("sync", "serial"):
        kind, address = "serial", None
    elif scheduler in ("processes", "local"):
        kind, address = "local", None
    elif "://" in scheduler:
        kind, address = "scheduler", scheduler
    else:
        raise SkyrigError(f"unknown scheduler {scheduler!r} (threads, sync, processes or a tcp:// address)")
    state = {"done": 0}

    def tick(done: int, total: int) -> None:
        if progress is not None and done > state["done"]:
            progress(done - state["done"])
        state["done"] = done

    with Executor(kind, workers=workers if kind == "local" else None, scheduler=address) as ex:  # type: ignore[arg-type]
        return ex.map(_call, tasks, desc="match", progress=tick)


class _Call:
    """Picklable deferred call (for the processes scheduler)."""

    def __init__(self, fn: Callable, *args: object) -> None:
        self.fn, self.args = fn, args

    def __call__(self) -> str:
        return self.fn(*self.args)


def _approximate_orientations(
    metas: list[ImageMetadata], eo: ExteriorOrientations | None, cameras: dict[str, FrameCamera] | None,
    terrain_height: float | None,
) -> tuple[ExteriorOrientations | None, list[FrameCamera | None], dict[str, FrameCamera] | None, float | None,
           NDArray[np.float64] | None]:
    """Approximate orientations and cameras of ``metas``: from ``--eo`` + ``--camera``, or EXIF GPS + gimbal attitudes.

    Returns ``(eo, cams, cameras, terrain_height, heading_deg)``; ``eo`` is None when the images carry no attitude.
    """
    names = [m.name for m in metas]
    cams: list[FrameCamera | None] = [None] * len(metas)
    heading = None
    if eo is not None:
        idx = eo.index()
        missing = [n for n in names if n not in idx]
        if missing:
            raise InputFormatError(f"no exterior orientation for {len(missing)} images, e.g. {missing[0]!r}")
        eo = eo.subset(np.array([idx[n] for n in names]))
        if cameras is None:
            raise InputFormatError("orientations given without cameras", field="camera")
        from skyrig.pipeline.inputs import require_cameras

        require_cameras(eo, cameras)
        cams = [cameras[str(c)] for c in eo.camera]
        # no terrain height: fine for exhaustive pairs (the orientations still guide the matching); guided pairs
        # and the rectification of obliques need one (match_images says so when they are asked for)
    elif metas and all(m.has_gps for m in metas):
        mo = orientations_from_metadata(metas)
        heading = mo.heading_deg
        try:
            cams = [camera_from_metadata(m) for m in metas]
            cameras = {c.name: c for c in cams if c is not None}
        except InputFormatError as exc:
            logger.warning("no cameras from EXIF (%s): guided matching off", exc.reason)
        if np.all(np.isfinite(mo.eo.rotation)) and all(c is not None for c in cams):
            eo = ExteriorOrientations(mo.eo.image, np.array([c.name for c in cams]), mo.eo.centre, mo.eo.rotation,
                                      mo.eo.frame)
            if terrain_height is None:
                terrain_height = mo.ground_height
    return eo, cams, cameras, terrain_height, heading


def match_images(
    folders: Sequence[str | Path], out: str | Path, feature_config: FeatureConfig = FeatureConfig(),
    match_config: MatchConfig | None = None, pair_mode: str = "auto", eo: ExteriorOrientations | None = None,
    cameras: dict[str, FrameCamera] | None = None, terrain_height: float | None = None,
    min_overlap: float = 0.1, gps_neighbours: int = 8, scheduler: str = "threads", workers: int = 2,
    thin_per_cell: int = 0, overwrite: bool = False, progress: Callable[[str, int, int], None] | None = None,
    lsm: bool = False, max_heading_diff_deg: float | None = None,
    max_pairs_per_image: int | None = MAX_PAIRS_PER_IMAGE,
) -> MatchRunResult:
    """Feature extraction, pair selection, guided matching, tracks, tie-point file and report for a block.

    Parameters are as the CLI options.  ``progress(stage, done, total)`` is called as work completes.
    ``max_pairs_per_image``: per-image budget of guided pairs (module docstring; 0 / None = all).
    """
    import time

    t0 = time.perf_counter()
    out = Path(out)
    metas, skipped = collect_images(folders)
    names = [m.name for m in metas]
    if match_config is None:
        scale = max(max(m.width, m.height) for m in metas) / feature_config.max_size if feature_config.max_size else 1.0
        match_config = MatchConfig(threshold_scale=max(1.0, scale))
    cfg_json = {"features": asdict(feature_config), "matching": asdict(match_config)}
    db = MatchDatabase(out, cfg_json, overwrite=overwrite)

    def tick(stage: str, total: int) -> Callable[[int], None]:
        state = {"n": 0}

        def f(k: int) -> None:
            state["n"] += k
            if progress:
                progress(stage, state["n"], total)
        return f

    # Oblique images are detected on their ground-plane rectification when approximate orientations exist
    # (FeatureConfig.rectify); so orientations come first.
    eo_given, cameras_given, terrain_given = eo, cameras, terrain_height
    eo0, cams0, _, th0, _ = _approximate_orientations(metas, eo, cameras, terrain_height)
    rect = [(cams0[k], eo0.pose()[k], th0) if eo0 is not None and cams0[k] is not None and th0 is not None
            else (None, None, None) for k in range(len(metas))]
    tasks = [_Call(_extract_one, m.path, m.name, str(out), feature_config, *rect[k]) for k, m in enumerate(metas)]
    res = _run_dask(tasks, scheduler, workers, tick("features", len(tasks)))
    for m, r in zip(metas, res):
        if r.startswith("skip"):
            skipped[m.name] = r[6:]
            logger.warning("skipping %s: %s", m.path, r[6:])
    keep = [k for k, m in enumerate(metas) if m.name not in skipped]
    metas = [metas[k] for k in keep]
    names = [m.name for m in metas]
    t1 = time.perf_counter()

    # ---- approximate orientations and cameras (again, without the skipped images)
    eo, cams, cameras, terrain_height, heading = _approximate_orientations(metas, eo_given, cameras_given,
                                                                          terrain_given)
    poses: list = [None] * len(metas)
    mode = pair_mode
    n_candidates = None
    if max_pairs_per_image is not None and max_pairs_per_image < 0:
        raise InputFormatError(f"max_pairs_per_image must be >= 0 (0 = every pair), not {max_pairs_per_image}",
                               field="max_pairs_per_image")
    if mode == "auto":
        mode = "guided" if eo is not None and terrain_height is not None else (
            "gps" if all(m.has_gps for m in metas) else "exhaustive")
        if eo_given is not None and terrain_height is None:
            logger.warning("orientations given without a terrain height: %s pairs (--terrain-height gives guided "
                           "pairs from the image footprints)", mode)
    if mode == "guided":
        if eo is None or terrain_height is None:
            raise InputFormatError("guided pairs need orientations (GPS + gimbal attitudes or --eo) and a terrain "
                                   "height (--terrain-height or DJI RelativeAltitude)")
        pairs, overlap = footprint_pairs(eo, cameras or {}, terrain_height, min_overlap=min_overlap)
        n_candidates = len(pairs)
        if max_pairs_per_image:
            pairs = pairs[budget_pairs(pairs, overlap, len(eo), max_pairs_per_image, eo.camera, image_strips(eo))]
        poses = [eo.pose()[k] for k in range(len(eo))]
    elif mode == "gps":
        if not all(m.has_gps for m in metas):
            bad = next(m for m in metas if not m.has_gps)
            raise InputFormatError("gps pairs need EXIF GPS on every image", bad.path, None, "GPSLatitude")
        c = (eo.centre if eo is not None else orientations_from_metadata(metas).eo.centre)
        pairs = gps_pairs(c, k=gps_neighbours, heading_deg=heading, max_heading_diff_deg=max_heading_diff_deg)
        cams = [None] * len(metas)
    elif mode == "exhaustive":
        pairs = exhaustive_pairs(len(metas))
        if eo is not None:
            poses = [eo.pose()[k] for k in range(len(eo))]
    else:
        raise InputFormatError(f"unknown pair mode {pair_mode!r} (auto, guided, gps, exhaustive)", field="pairs")
    logger.info("%d images, %d pairs (%s)%s", len(names), len(pairs), mode,
                "" if n_candidates is None else f" of {n_candidates} overlapping, budget {max_pairs_per_image}")
    if not all(p is not None for p in poses):
        cams = [None] * len(metas)
        poses = [None] * len(metas)

    tasks = [_Call(_match_one, names[i], names[j], str(out), match_config, cams[i], poses[i], cams[j], poses[j])
             for i, j in pairs]
    _run_dask(tasks, scheduler, workers, tick("matches", len(tasks)))
    t2 = time.perf_counter()

    feats = [db.read_features(n) for n in names]
    pm = {(int(i), int(j)): db.read_matches(names[i], names[j]) for i, j in pairs}
    tracks = build_tracks([len(f) for f in feats], {k: v.matches for k, v in pm.items() if v.ok})
    xy = [f.xy for f in feats]
    sizes = [f.image_size for f in feats]
    thinned = thin_tracks(tracks, xy, sizes, per_cell=thin_per_cell) if thin_per_cell > 0 else tracks
    xy_obs = np.array([xy[i][f] for i, f in zip(thinned.image, thinned.feature)]).reshape(-1, 2)
    if lsm and thinned.n_tracks:
        from skyrig.match.lsm import refine_tracks

        paths = [m.path for m in metas]
        xy_obs, ok = refine_tracks(thinned.track, thinned.image, xy_obs,
                                   lambda i: read_image(paths[i]))
    report = tie_point_report(thinned, names, pm)
    if lsm:
        report["lsm_refined_fraction"] = float(ok.mean()) if thinned.n_tracks else 0.0
    report["pair_mode"] = mode
    if n_candidates is not None:
        report["pairs_overlapping"] = n_candidates
        report["max_pairs_per_image"] = max_pairs_per_image or 0
    report["skipped_images"] = skipped
    report["n_tracks_before_thinning"] = tracks.n_tracks

    from skyrig.io.points_csv import write_measurements_csv

    meas = tracks_to_measurements(thinned, xy, names)
    if lsm and thinned.n_tracks:  # same ordering as tracks_to_measurements
        order = np.lexsort((np.array([names[i] for i in thinned.image]), thinned.track))
        meas = type(meas)(meas.point, meas.image, xy_obs[order])
    write_measurements_csv(out / "tie_points.csv", meas)
    tmp = out / "report.json.tmp"
    tmp.write_text(json.dumps(report, indent=1))
    os.replace(tmp, out / "report.json")
    import cv2

    png = coverage_image(thinned, xy, sizes)
    tmp_png = out / "coverage.tmp.png"
    cv2.imwrite(str(tmp_png), png[..., ::-1])
    os.replace(tmp_png, out / "coverage.png")
    t3 = time.perf_counter()
    return MatchRunResult(names, skipped, pairs, mode, pm, feats, tracks, thinned, report,
                          {"features": t1 - t0, "matching": t2 - t1, "tracks_report": t3 - t2, "total": t3 - t0})
