"""A peer orientation of the same correspondences: COLMAP's incremental mapper (pycolmap) run on skyrig's tie-point
tracks (layer 2b; writes only into the given work folder).

Used where the images themselves do not exist (a simulated close-range set whose tie points are projections plus
noise) or where the comparison must isolate the orientation from the matching: both programs see exactly the same
image measurements.  The tracks are written into a COLMAP database as one keypoint per observation, every pair of
images sharing tracks gets the matches of those tracks, COLMAP estimates each pair's two-view geometry on them
(``pycolmap.estimate_two_view_geometry``: its RANSAC may drop mismatches, never adds a match) and its incremental
mapper orients the block.  The images are blank placeholders of the camera's size (COLMAP's image reader needs
files; nothing reads their pixels).

The camera: COLMAP's ``OPENCV`` model (fx, fy, cx, cy, k1, k2, p1, p2) started from the same camera skyrig starts
from, focal length, principal point and distortion refined by COLMAP's bundle adjustment.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.orient.triangulation import _SKYRIG_FROM_CV
from skyrig.errors import ConfigError

__all__ = ["PeerOrientation", "compare_on_same_tracks", "pycolmap_from_tracks", "centre_differences_in_sigma"]


@dataclass
class PeerOrientation:
    """pycolmap's orientation of the images it registered (its largest model), in its own frame and scale.

    Attributes
    ----------
    names
        ``(K,)`` registered images.
    R, C
        ``(K, 3, 3)`` ``world_from_camera`` in skyrig's camera axes and ``(K, 3)`` projection centres.
    focal_px
        COLMAP's refined focal length (mean of fx and fy).
    summary
        Registered images, models, 3D points, mean reprojection error, options used, wall time.
    """

    names: NDArray[np.str_]
    R: NDArray[np.float64]
    C: NDArray[np.float64]
    focal_px: float
    summary: dict[str, Any]


def _pairs_of_tracks(obs_track: NDArray, obs_image: NDArray) -> dict[tuple[int, int], NDArray[np.int64]]:
    """``{(i, j): (M, 2) observation rows}`` for every image pair (i < j) sharing tracks (one row per track)."""
    order = np.lexsort((obs_image, obs_track))
    t, im = obs_track[order], obs_image[order]
    start = np.r_[0, np.flatnonzero(np.diff(t)) + 1]
    end = np.r_[start[1:], len(t)]
    out: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for s, e in zip(start.tolist(), end.tolist()):
        for a in range(s, e):
            for b in range(a + 1, e):
                if im[a] != im[b]:
                    key = (int(im[a]), int(im[b])) if im[a] < im[b] else (int(im[b]), int(im[a]))
                    pair = (int(order[a]), int(order[b])) if im[a] < im[b] else (int(order[b]), int(order[a]))
                    out.setdefault(key, []).append(pair)
    return {k: np.asarray(v, np.int64) for k, v in out.items()}


def pycolmap_from_tracks(names: NDArray, camera: FrameCamera, obs_track: NDArray, obs_image: NDArray,
                         obs_pixel: NDArray, workdir: str | Path, seed: int = 0, min_matches: int = 15,
                         init_min_tri_angle_deg: float = 4.0, camera_model: str = "OPENCV",
                         refine_principal_point: bool = True, refine_extra_params: bool = True,
                         mapper_options: dict[str, Any] | None = None) -> PeerOrientation | None:
    """Orient the images with pycolmap's incremental mapper from the given tracks (module docstring).

    Parameters
    ----------
    names, camera
        ``(I,)`` image names and the start camera (one for all images; OpenCV or no distortion).
    obs_track, obs_image, obs_pixel
        Observations ``(N,)``, ``(N,)``, ``(N, 2)`` in skyrig pixels (origin at the centre of the top-left pixel;
        COLMAP's is at its corner: +0.5 px).
    workdir
        Folder for the database, placeholder images and COLMAP's model (created; its database is replaced).
    min_matches
        Pairs with fewer common tracks are not written.
    camera_model, refine_principal_point
        COLMAP's camera: ``"OPENCV"`` (fx, fy, cx, cy, k1, k2, p1, p2; for a calibrated-lens model like the
        simulation's) or ``"SIMPLE_RADIAL"`` (f, cx, cy, k; COLMAP's default, for a phone whose EXIF focal length is
        far off: a free fx, fy, principal point and four distortion terms then diverge on the first pair);
        principal point refined or kept (COLMAP's default keeps it).
    refine_extra_params
        Distortion refined by COLMAP's bundle adjustment (its default); False keeps the start's.
    mapper_options
        Attributes of ``IncrementalPipelineOptions.mapper`` to change from COLMAP's defaults (e.g.
        ``{"abs_pose_min_num_inliers": 15}``), recorded in the summary.

    Returns
    -------
    PeerOrientation or None when COLMAP registered no model.
    """
    import time

    import pycolmap
    from PIL import Image

    from skyrig.match.colmap_check import _quiet

    _quiet()
    t0 = time.perf_counter()
    names = np.asarray(names, dtype=str)
    obs_track = np.asarray(obs_track, np.int64)
    obs_image = np.asarray(obs_image, np.int64)
    obs_pixel = np.asarray(obs_pixel, float).reshape(-1, 2)
    work = Path(workdir)
    img_dir = work / "images"
    img_dir.mkdir(parents=True, exist_ok=True)
    w, h = int(camera.width), int(camera.height)
    blank = Image.new("L", (w, h))
    files = [f"{k:06d}.png" for k in range(len(names))]  # placeholders: any image name works
    for fn in files:
        if not (img_dir / fn).exists():
            blank.save(img_dir / fn)
    db_path = work / "tracks.db"
    if db_path.exists():
        db_path.unlink()
    f = camera.focal_px
    cx, cy = np.asarray(camera.principal_point_px, float) + 0.5
    dist = np.zeros(4)
    par = getattr(camera.distortion, "params", None)
    if par is not None:
        par = np.asarray(par, float)
        dist[:min(4, len(par))] = par[:4]
    opts = pycolmap.ImageReaderOptions()
    opts.camera_model = camera_model
    if camera_model == "OPENCV":
        start = (f, f, cx, cy, *dist)
    elif camera_model == "SIMPLE_RADIAL":
        start = (f, cx, cy, dist[0])
    else:
        raise ConfigError(f"camera_model {camera_model!r}: OPENCV or SIMPLE_RADIAL")
    opts.camera_params = ",".join(f"{v:.10g}" for v in start)
    pycolmap.Database.open(db_path).close()
    pycolmap.import_images(db_path, img_dir, camera_mode=pycolmap.CameraMode.SINGLE, image_names=files,
                           options=opts)
    db = pycolmap.Database.open(db_path)
    ids = {img.name: img.image_id for img in db.read_all_images()}
    cams = {c.camera_id: c for c in db.read_all_cameras()}
    cam = next(iter(cams.values()))
    # keypoint index of each observation within its image
    kp_index = np.zeros(len(obs_track), np.int64)
    kps: list[NDArray] = []
    for k in range(len(names)):
        rows = np.flatnonzero(obs_image == k)
        kp_index[rows] = np.arange(len(rows))
        kps.append(obs_pixel[rows] + 0.5)
        db.write_keypoints(ids[files[k]], np.ascontiguousarray(kps[-1].astype(np.float32)))
    tvg_opts = pycolmap.TwoViewGeometryOptions()
    tvg_opts.compute_relative_pose = True
    n_pairs = n_verified = 0
    for (i, j), rows in _pairs_of_tracks(obs_track, obs_image).items():
        if len(rows) < min_matches:
            continue
        a, b = ids[files[i]], ids[files[j]]
        m = np.column_stack([kp_index[rows[:, 0]], kp_index[rows[:, 1]]])
        if a > b:
            a, b, m = b, a, m[:, ::-1]
            ka, kb = kps[j], kps[i]
        else:
            ka, kb = kps[i], kps[j]
        m = np.ascontiguousarray(m.astype(np.uint32))
        db.write_matches(a, b, m)
        n_pairs += 1
        tvg = pycolmap.estimate_two_view_geometry(cam, ka, cam, kb, m, tvg_opts)
        if tvg.config == pycolmap.TwoViewGeometryConfiguration.DEGENERATE or len(tvg.inlier_matches) < min_matches:
            continue
        db.write_two_view_geometry(a, b, tvg)
        n_verified += 1
    db.close()
    out = work / "sparse"
    out.mkdir(exist_ok=True)
    mo = pycolmap.IncrementalPipelineOptions()
    mo.random_seed = seed
    mo.num_threads = 2
    mo.mapper.init_min_tri_angle = init_min_tri_angle_deg
    # as skyrig.match.colmap_check's image-based run: COLMAP's default (0.95) refuses the start pairs of a walk
    mo.mapper.init_max_forward_motion = 0.995
    mo.ba_refine_focal_length = True
    mo.ba_refine_principal_point = bool(refine_principal_point)
    mo.ba_refine_extra_params = bool(refine_extra_params)
    for key, val in (mapper_options or {}).items():
        if not hasattr(mo.mapper, key):
            raise ConfigError(f"mapper_options: COLMAP's mapper has no option {key!r}")
        setattr(mo.mapper, key, val)
    recs = pycolmap.incremental_mapping(db_path, img_dir, out, options=mo)
    if not recs:
        return None
    rec = max(recs.values(), key=lambda r: r.num_reg_images())
    reg = sorted(((int(im.name[:6]), im) for im in rec.images.values() if im.has_pose), key=lambda x: x[0])
    nm = np.array([names[k] for k, _ in reg], dtype=str)
    R = np.zeros((len(reg), 3, 3))
    C = np.zeros((len(reg), 3))
    for q, (_, im) in enumerate(reg):
        cfw = im.cam_from_world()
        Rcw = np.asarray(cfw.rotation.matrix())
        R[q] = Rcw.T @ _SKYRIG_FROM_CV
        C[q] = np.asarray(im.projection_center())
    c = next(iter(rec.cameras.values()))
    pp = np.asarray(c.params, float)
    summary = {
        "registered": int(len(reg)), "models": sorted((int(r.num_reg_images()) for r in recs.values()), reverse=True),
        "points": int(rec.num_points3D()), "mean_reprojection_error_px": float(rec.compute_mean_reprojection_error()),
        "pairs_written": n_pairs, "pairs_verified": n_verified, "camera_model": camera_model,
        "camera_params": pp.tolist(), "wall_s": time.perf_counter() - t0,
        "options": {"init_min_tri_angle_deg": init_min_tri_angle_deg, "seed": seed,
                    "refine": "focal length" + (", principal point" if refine_principal_point else "")
                              + (", distortion" if refine_extra_params else ""),
                    "mapper": dict(mapper_options or {})},
    }
    return PeerOrientation(nm, R, C, float(0.5 * (pp[0] + pp[1]) if camera_model == "OPENCV" else pp[0]), summary)


def centre_differences_in_sigma(result: Any, cmp: dict[str, Any]) -> dict[str, Any]:
    """``cmp`` (:func:`skyrig.orient.similarity.compare_with_reconstruction`: per image the length of the centre
    difference after the similarity, in ``result``'s frame and units) with the differences in units of ``result``'s
    predicted sigma added: per image ``|d| / |sigma|`` (``sigma``: the adjustment's predicted standard deviations of
    the projection centre, x, y, z), ``normalised_rms`` and ``normalised_max`` over the common images, and
    ``sigma_rms_m`` (RMS of ``|sigma|``).  Unchanged when the adjustment has no covariance.

    The similarity absorbs the datum (translation, rotation, scale), so a difference between two estimates of the same
    measurements is expected well below 1 sigma; one of several sigma says the two programs reached different
    geometries (a local minimum, a wrong camera model)."""
    adj = getattr(result, "adjustment", None)
    ps = None if adj is None else adj.pose_sigma
    per = cmp.get("per_image_m")
    if ps is None or not per:
        return cmp
    b = adj.block
    sig = {str(b.image_name[k]): float(np.linalg.norm(ps[b.image_station[k], :3])) for k in range(b.n_images)}
    names = [n for n in per if n in sig and np.isfinite(sig[n]) and sig[n] > 0]
    if not names:
        return cmp
    z = np.array([per[n] / sig[n] for n in names])
    s = np.array([sig[n] for n in names])
    return dict(cmp, normalised_rms=float(np.sqrt(np.mean(z ** 2))), normalised_max=float(z.max()),
                sigma_rms_m=float(np.sqrt(np.mean(s ** 2))),
                per_image_sigma={n: float(v) for n, v in zip(names, z)})


def compare_on_same_tracks(result: Any, inp: Any, workdir: str | Path, seed: int = 0, camera_model: str = "OPENCV",
                           refine_principal_point: bool = True) -> dict[str, Any]:
    """pycolmap on the tie points an orientation used (:func:`pycolmap_from_tracks` with ``inp``'s names, start
    camera and observations: an :class:`~skyrig.orient.incremental.OrientInput` or a
    :class:`~skyrig.orient.gnss_block.UavBlockInput`), compared with ``result`` (a
    :class:`~skyrig.orient.gnss_block.UavResult`) by camera centres after a similarity
    (:func:`skyrig.orient.similarity.compare_with_reconstruction`; with ``inp``'s approximate positions or GNSS also
    both fitted onto them), the differences also in units of ``result``'s predicted sigma
    (:func:`centre_differences_in_sigma`).  The dict has the keys of the image-based comparison (``registered``,
    ``points``, ``wall_s``, ``centre_differences``) so that reports read alike, and ``input: "tracks"``; for a set
    without image files (a simulated or measured set of image coordinates only: ``skyrig adjust-uav
    --compare-pycolmap --pycolmap-input tracks``), or to compare the orientation alone, without the matching."""
    from skyrig.orient.similarity import compare_with_reconstruction

    peer = pycolmap_from_tracks(inp.names, inp.camera, inp.obs_track, inp.obs_image, inp.obs_pixel, workdir, seed,
                                camera_model=camera_model, refine_principal_point=refine_principal_point)
    out: dict[str, Any] = {"input": "tracks", "mapper": "incremental, on skyrig's tie points (same measurements)",
                           "camera_model": camera_model}
    if peer is None:
        return dict(out, registered=0)
    out.update(registered=int(len(peer.names)), points=peer.summary["points"],
               mean_reprojection_error_px=peer.summary["mean_reprojection_error_px"], focal_px=peer.focal_px,
               wall_s=peer.summary["wall_s"])
    if len(peer.names) >= 3:
        positions = getattr(inp, "positions", None)
        if positions is None:
            positions = getattr(inp, "gnss", None)
        out["centre_differences"] = centre_differences_in_sigma(
            result, compare_with_reconstruction(result, peer.names, peer.C, positions))
    return out
