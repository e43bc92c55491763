"""Peer cross-check with pycolmap (COLMAP): reconstruct from skyrig's features and verified matches, and from
COLMAP's own extraction + matching, then compare camera centres after a similarity transform.

COLMAP needs a database file and image folder, so these functions work inside a caller-given scratch folder.
COLMAP's pixel origin is the top-left *corner* of the top-left pixel: skyrig pixels + 0.5.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from skyrig.match.features import Features
from skyrig.match.matching import PairMatches
from skyrig.errors import ConfigError

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReconstructionSummary:
    """What a COLMAP reconstruction oriented.

    Attributes
    ----------
    names
        ``(R,)`` names of the registered images.
    centres
        ``(R, 3)`` projection centres (arbitrary COLMAP frame).
    n_points
        3D points.
    reprojection_rms_px
        RMS of all reprojection residual components (per axis), pixels.
    mean_track_length
        Observations per 3D point.
    obs_per_image
        ``(R,)`` triangulated observations per registered image.
    components
        Registered images per reconstructed component, largest first.
    """

    names: NDArray[np.str_]
    centres: NDArray[np.float64]
    n_points: int
    reprojection_rms_px: float
    mean_track_length: float
    obs_per_image: NDArray[np.int64]
    #: Registered images of every reconstructed component (largest first); the rest describes the largest.
    components: tuple[int, ...] = ()
    #: COLMAP's cameras of the largest component as refined by its bundle adjustment: one dict per camera with
    #: ``model`` (e.g. ``"SIMPLE_RADIAL"``), ``width``, ``height`` and ``params`` (COLMAP's order, pixels; for
    #: SIMPLE_RADIAL ``f, cx, cy, k``)
    cameras: tuple[dict, ...] = ()


def _quiet() -> None:
    import pycolmap

    try:
        pycolmap.logging.minloglevel = 2  # type: ignore[attr-defined]
    except Exception:  # noqa: BLE001
        pass


def summarise(rec: object) -> ReconstructionSummary:
    """Names, centres, reprojection RMS of a ``pycolmap.Reconstruction``."""
    names, centres, nobs = [], [], []
    res = []
    for img in rec.images.values():  # type: ignore[attr-defined]
        if not img.has_pose:
            continue
        names.append(img.name)
        centres.append(np.asarray(img.projection_center()))
        cam = rec.cameras[img.camera_id]  # type: ignore[attr-defined]
        pts = [(p2.xy, rec.points3D[p2.point3D_id].xyz) for p2 in img.points2D if p2.has_point3D()]  # type: ignore[attr-defined]
        nobs.append(len(pts))
        if pts:
            xy = np.array([p[0] for p in pts])
            X = np.array([p[1] for p in pts])
            Xc = np.asarray(img.cam_from_world() * X) if callable(img.cam_from_world) else np.asarray(img.cam_from_world * X)
            proj = np.asarray(cam.img_from_cam(Xc))
            res.append(proj - xy)
    r = np.concatenate(res) if res else np.zeros((0, 2))
    npts = len(rec.points3D)  # type: ignore[attr-defined]
    cams = tuple({"model": str(getattr(c.model, "name", c.model)), "width": int(c.width), "height": int(c.height),
                  "params": [float(v) for v in np.asarray(c.params)]}
                 for _, c in sorted(rec.cameras.items()))  # type: ignore[attr-defined]
    return ReconstructionSummary(
        np.array(names, dtype=str), np.array(centres).reshape(-1, 3), npts,
        float(np.sqrt(np.mean(r**2))) if len(r) else float("nan"),
        float(np.sum(nobs) / max(npts, 1)), np.array(nobs, dtype=np.int64), cameras=cams,
    )


def _largest(recs: Mapping[int, object]) -> object | None:
    if not recs:
        return None
    return max(recs.values(), key=lambda r: r.num_reg_images())  # type: ignore[attr-defined]


def _reader_options(image_dir: str | Path, first: str, focal_px: float | None) -> object:
    import pycolmap

    opts = pycolmap.ImageReaderOptions()
    opts.camera_model = "SIMPLE_RADIAL"
    if focal_px is not None:
        from PIL import Image

        with Image.open(Path(image_dir) / first) as im:
            w, h = im.size
        opts.camera_params = f"{focal_px},{w / 2},{h / 2},0"
    return opts


def _result(recs: Mapping[int, object]) -> tuple[object | None, ReconstructionSummary | None]:
    from dataclasses import replace

    rec = _largest(recs)
    if rec is None:
        return None, None
    comps = tuple(sorted((r.num_reg_images() for r in recs.values()), reverse=True))  # type: ignore[attr-defined]
    return rec, replace(summarise(rec), components=comps)


def _mapping_options(seed: int = 0, init_min_tri_angle_deg: float = 4.0) -> object:
    import pycolmap

    opts = pycolmap.IncrementalPipelineOptions()
    opts.random_seed = seed
    opts.num_threads = 2
    # COLMAP's defaults (16 deg, forward motion 0.95) reject short forward-moving sequences (lund); used for both pipelines alike
    opts.mapper.init_min_tri_angle = init_min_tri_angle_deg
    opts.mapper.init_max_forward_motion = 0.995
    return opts


def _map(db_path: Path, image_dir: str | Path, out: Path, mapper: str) -> dict:
    import pycolmap

    if mapper == "incremental":
        return pycolmap.incremental_mapping(db_path, image_dir, out, options=_mapping_options())
    if mapper == "global":
        return pycolmap.global_mapping(db_path, image_dir, out)
    raise ConfigError(f"unknown mapper {mapper!r} (incremental or global)")


def reconstruct_from_matches(
    image_dir: str | Path, names: Sequence[str], features: Sequence[Features],
    pair_matches: Mapping[tuple[int, int], PairMatches], workdir: str | Path, single_camera: bool = True,
    focal_px: float | None = None, mapper: str = "incremental",
) -> tuple[object | None, ReconstructionSummary | None]:
    """Incremental (or ``mapper="global"``: GLOMAP) mapping (pycolmap) on a database filled with skyrig's keypoints and verified matches.

    ``focal_px`` (e.g. from EXIF) seeds COLMAP's SIMPLE_RADIAL camera; otherwise COLMAP guesses from EXIF or
    uses 1.2 x the image size.
    """
    import pycolmap

    _quiet()
    work = Path(workdir)
    work.mkdir(parents=True, exist_ok=True)
    db_path = work / "skyrig.db"
    if db_path.exists():
        db_path.unlink()
    mode = pycolmap.CameraMode.SINGLE if single_camera else pycolmap.CameraMode.AUTO
    pycolmap.Database.open(db_path).close()
    pycolmap.import_images(db_path, image_dir, camera_mode=mode, image_names=list(names),
                           options=_reader_options(image_dir, names[0], focal_px))
    db = pycolmap.Database.open(db_path)
    ids = {img.name: img.image_id for img in db.read_all_images()}
    img_by_id = {img.image_id: img for img in db.read_all_images()}
    cams = {c.camera_id: c for c in db.read_all_cameras()}
    name_idx = {n: k for k, n in enumerate(names)}
    tvg_opts = pycolmap.TwoViewGeometryOptions()
    tvg_opts.compute_relative_pose = True
    for name, f in zip(names, features):
        db.write_keypoints(ids[name], np.ascontiguousarray((f.xy + 0.5).astype(np.float32)))
    for (i, j), pm in pair_matches.items():
        if not pm.ok or len(pm) == 0:
            continue
        a, b = ids[names[i]], ids[names[j]]
        m = pm.matches
        if a > b:
            a, b, m = b, a, m[:, ::-1]
        m = np.ascontiguousarray(m.astype(np.uint32))
        db.write_matches(a, b, m)
        # the two-view model (E / F / H, relative pose) COLMAP's mapper needs for its initial pair, estimated by
        # COLMAP on skyrig's verified inliers only (it may drop a few of them, never add any)
        ia, ib = img_by_id[a], img_by_id[b]
        fa, fb = features[name_idx[ia.name]], features[name_idx[ib.name]]
        tvg = pycolmap.estimate_two_view_geometry(cams[ia.camera_id], fa.xy + 0.5, cams[ib.camera_id], fb.xy + 0.5, m,
                                                  tvg_opts)
        if tvg.config == pycolmap.TwoViewGeometryConfiguration.DEGENERATE or len(tvg.inlier_matches) < 15:
            tvg = pycolmap.TwoViewGeometry()
            tvg.config = pycolmap.TwoViewGeometryConfiguration.UNCALIBRATED
            tvg.inlier_matches = m
        db.write_two_view_geometry(a, b, tvg)
    db.close()
    out = work / "sparse_skyrig"
    out.mkdir(exist_ok=True)
    recs = _map(db_path, image_dir, out, mapper)
    return _result(recs)


def reconstruct_with_pycolmap(
    image_dir: str | Path, names: Sequence[str], workdir: str | Path, max_image_size: int = 1600,
    max_features: int = 8192, single_camera: bool = True, focal_px: float | None = None,
    mapper: str = "incremental",
) -> tuple[object | None, ReconstructionSummary | None]:
    """COLMAP's own pipeline (SIFT extraction, exhaustive matching, incremental mapping) on the same images."""
    import pycolmap

    _quiet()
    work = Path(workdir)
    work.mkdir(parents=True, exist_ok=True)
    db_path = work / "colmap.db"
    if db_path.exists():
        db_path.unlink()
    eo = pycolmap.FeatureExtractionOptions()
    eo.max_image_size = int(max_image_size)
    eo.sift.max_num_features = int(max_features)
    eo.use_gpu = False
    eo.num_threads = 2
    mode = pycolmap.CameraMode.SINGLE if single_camera else pycolmap.CameraMode.AUTO
    pycolmap.extract_features(db_path, image_dir, image_names=list(names), camera_mode=mode,
                              reader_options=_reader_options(image_dir, names[0], focal_px),
                              extraction_options=eo, device=pycolmap.Device.cpu)
    mo = pycolmap.FeatureMatchingOptions()
    mo.use_gpu = False
    mo.num_threads = 2
    pycolmap.match_exhaustive(db_path, matching_options=mo, device=pycolmap.Device.cpu)
    out = work / "sparse_colmap"
    out.mkdir(exist_ok=True)
    recs = _map(db_path, image_dir, out, mapper)
    return _result(recs)


def similarity_transform(src: NDArray, dst: NDArray) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares similarity ``dst ~ s R src + t`` (Umeyama 1991) for ``(N, 3)`` point sets, N >= 3."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if len(src) < 3:
        raise ValueError("a similarity transform needs at least 3 common points")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    cov = b.T @ a / len(src)
    U, S, Vt = np.linalg.svd(cov)
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1
    R = U @ D @ Vt
    var = np.mean(np.sum(a**2, axis=1))
    s = float(np.trace(np.diag(S) @ D) / var)
    t = mu_d - s * R @ mu_s
    return s, R, t


def compare_centres(
    a: ReconstructionSummary, b: ReconstructionSummary
) -> tuple[NDArray[np.str_], NDArray[np.float64], float]:
    """Centre differences of the images both oriented, after the similarity mapping ``a`` onto ``b``.

    Returns
    -------
    names, diff
        Common image names and ``(K, 3)`` differences ``s R a + t - b`` (units of ``b``).
    scale
        The similarity's scale.
    """
    common = sorted(set(a.names) & set(b.names))
    ia = {n: k for k, n in enumerate(a.names)}
    ib = {n: k for k, n in enumerate(b.names)}
    A = np.array([a.centres[ia[n]] for n in common])
    B = np.array([b.centres[ib[n]] for n in common])
    s, R, t = similarity_transform(A, B)
    return np.array(common, dtype=str), (s * A @ R.T + t) - B, s
