"""Paper 000's laboratory set-up simulated (MACS-TumbleCam on a sensor head frame, a static reference camera, a textured
plane; 5 deg motor steps, circles), rendered exactly: the input of the ``tumbling-head`` recipe with its truth.

The MACS-TumbleCam rig (``skyrig.rig.presets.macs_tumblecam``, cameras scaled to ``width`` px) plus a static wide
reference camera on the sensor head, held still ``distance_m`` above a textured plane (multi-scale random texture,
3 mm cells).  The true tumbling mount carries a smooth boresight curve
(:func:`skyrig.simulate.errors.tumble_curve_samples`, the tumblecam scenario's amplitudes) and, per circle and
position, a repeat error drawn with paper 000 Tab. 2's mean repeatability (2 sigma -> 1 sigma).  Images are rendered exactly (every pixel's ray meets the plane, texture sampled
bilinearly, 1 DN noise).  :func:`render_reference_series` renders the reference camera at every exposure of the
session, optionally moved (a rotation from a given exposure on), for the reference camera's stability check.
(Moved here from ``bench/tumbling_lab.py``, which re-exports it and judges the recipe; it lives in ``calibrate``
as :mod:`~skyrig.calibrate.calqc_simulation` does, since ``simulate`` sits below ``calibrate``.)

Frames: the lab frame of :class:`skyrig.calibrate.tumbling.LabSetup` (ENU axes, metres); angles in radians.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["TAB2_MEAN_2SIGMA_DEG", "CURVE_AMP_RAD", "Lab", "make_texture", "render_plane", "lab_draws", "build_lab",
           "render_lab", "render_reference_series"]

#: paper 000 Tab. 2: mean repeatability (2 sigma) of roll, pitch, yaw, degrees
TAB2_MEAN_2SIGMA_DEG = (8.6e-3, 7.8e-3, 35.9e-3)
#: the tumblecam scenario's curve amplitudes (skyrig.simulate.scenarios), radians
CURVE_AMP_RAD = (0.05 * np.pi / 180, 0.05 * np.pi / 180, 0.1 * np.pi / 180)


@dataclass
class Lab:
    setup: Any  # LabSetup with the nominal rig
    rig_true: Any  # rig with the true curve
    true_curve: Any  # BoresightCurve
    beta_rad: np.ndarray  # (K,)
    true_rad: np.ndarray  # (C, K, 3) true corrections per circle (curve + repeat error)
    repeat_sigma_rad: np.ndarray  # (3,)
    texture: np.ndarray
    texture_cell_m: float
    texture_origin: np.ndarray  # (u, v) of texture pixel (0, 0)
    names: list[str]
    circles: list[str]
    betas: np.ndarray


def make_texture(size_m: float, cell_m: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Multi-scale random texture (uint8) covering ``size_m`` square, and the (u, v) of its top-left cell."""
    rng = np.random.default_rng(seed)
    n = int(np.ceil(size_m / cell_m))
    t = np.zeros((n, n), np.float32)
    for s, w in ((3.0, 1.0), (8.0, 1.5), (20.0, 1.0)):
        z = cv2.GaussianBlur(rng.normal(0, 1, (n, n)).astype(np.float32), (0, 0), s)
        t += w * z / z.std()
    t = 128 + 40 * t / t.std()
    return np.clip(t, 0, 255).astype(np.uint8), np.array([-size_m / 2, size_m / 2])


def render_plane(lab: Lab, camera: Any, rotation: np.ndarray, centre: np.ndarray, noise_dn: float, seed: int,
                 supersample: int = 1) -> np.ndarray:
    """Exact image of the textured plane: the rays of ``supersample`` x ``supersample`` points per pixel meet the
    plane, texture bilinear, averaged over the pixel (its area, as a sensor integrates)."""
    return _exposed(_plane_radiance(lab, camera, rotation, centre, supersample), noise_dn, seed)


def _plane_radiance(lab: Lab, camera: Any, rotation: np.ndarray, centre: np.ndarray, supersample: int
                    ) -> NDArray[np.float64]:
    """The noiseless grey values of :func:`render_plane` (float)."""
    plane = lab.setup.plane
    ss = int(supersample)
    u, v = np.meshgrid((np.arange(camera.width * ss) + 0.5) / ss - 0.5, (np.arange(camera.height * ss) + 0.5) / ss - 0.5)
    rays = camera.rays_from_pixels(np.c_[u.ravel(), v.ravel()]) @ rotation.T
    uv = plane.intersect(centre, rays)
    mx = ((uv[:, 0] - lab.texture_origin[0]) / lab.texture_cell_m).reshape(u.shape).astype(np.float32)
    my = ((lab.texture_origin[1] - uv[:, 1]) / lab.texture_cell_m).reshape(u.shape).astype(np.float32)
    g = cv2.remap(lab.texture, np.nan_to_num(mx, nan=-1), np.nan_to_num(my, nan=-1), cv2.INTER_LINEAR,
                  borderMode=cv2.BORDER_CONSTANT, borderValue=0).astype(np.float64)
    return g.reshape(camera.height, ss, camera.width, ss).mean(axis=(1, 3))


def _exposed(radiance: NDArray[np.float64], noise_dn: float, seed: int) -> NDArray[np.uint8]:
    """The grey values with ``noise_dn`` of noise (drawn from ``seed``), rounded to 8-bit RGB."""
    g = radiance.copy()
    g += np.random.default_rng(seed).normal(0, noise_dn, g.shape)
    g = np.clip(np.round(g), 0, 255).astype(np.uint8)
    return np.repeat(g[:, :, None], 3, axis=2)


def lab_draws(positions: int, circles: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The lab's random draws: the true curve's 72 samples (positions, corrections) and the repeat errors in units of
    their sigma, ``(circles, positions, 3)`` independent N(0, 1)."""
    from skyrig.simulate.errors import tumble_curve_samples

    rng = np.random.default_rng(seed)
    b72, c72 = tumble_curve_samples(CURVE_AMP_RAD, rng)
    return b72, c72, rng.normal(0.0, 1.0, (circles, positions, 3))


def build_lab(positions: int = 12, circles: int = 3, width: int = 480, distance_m: float = 3.0, seed: int = 1,
              repeat_sigma_deg: tuple[float, float, float] | None = None, ref_factor: int = 4) -> Lab:
    from skyrig.calibrate.tumbling import LabSetup
    from skyrig.camera.frame import FrameCamera
    from skyrig.rig.boresight_curve import BoresightCurve
    from skyrig.rig.presets import macs_tumblecam
    from skyrig.rig.rig import Head, Rig
    from skyrig.simulate.scenarios import ci_camera

    base = macs_tumblecam()
    heads = [h.with_(camera=ci_camera(h.camera, width)) for h in base]
    # the reference: a wide static camera on the sensor head frame, covering every oblique footprint
    ref_w = ref_factor * width
    ref = FrameCamera("lab-reference", ref_w, ref_w, 0.005, 0.005 * ref_w / 2 / np.tan(np.radians(56.0)))
    heads.append(Head("reference", ref, np.array([0.0, 0.15, 0.0])))
    rig = Rig("macs-tumblecam-lab", heads, description="MACS-TumbleCam + static reference camera (laboratory)")
    # the true curve (72 positions, smooth) and per-circle repeat errors
    b72, c72, draws = lab_draws(positions, circles, seed)
    true_curve = BoresightCurve(b72, c72)
    beta = np.arange(positions) * 2 * np.pi / positions
    rep = np.radians(np.asarray(repeat_sigma_deg if repeat_sigma_deg is not None
                                else np.asarray(TAB2_MEAN_2SIGMA_DEG) / 2.0))
    true = true_curve(beta)[None] + draws * rep
    rig_true = replace(rig, heads={n: (h.with_(curve=true_curve) if h.is_actuated else h) for n, h in rig.heads.items()})
    setup = LabSetup(rig, "oblique", "reference", distance_m)
    tex, origin = make_texture(2 * distance_m * np.tan(np.radians(60.0)) + 0.5, 0.003, seed + 100)
    names = [f"c{c + 1}_b{int(round(np.degrees(b) * 10)):04d}_oblique.png" for c in range(circles) for b in beta]
    circ = [f"{c + 1}" for c in range(circles) for _ in beta]
    betas = np.tile(beta, circles)
    return Lab(setup, rig_true, true_curve, beta, true, rep, tex, 0.003, origin, names, circ, betas)


def render_lab(lab: Lab, noise_dn: float = 1.0, supersample: int = 1) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Tumbling images by name (true orientation: nominal + the circle's true correction) and the reference image."""
    cam = lab.setup.rig.head(lab.setup.head).camera
    out = {}
    k_pos = lab.beta_rad.size
    for i, (n, b) in enumerate(zip(lab.names, lab.betas)):
        c, k = divmod(i, k_pos)
        r, ctr = lab.setup.tumbling_orientation(b, lab.true_rad[c, k])
        out[n] = render_plane(lab, cam, r, ctr, noise_dn, seed=i, supersample=supersample)
    rr, rc = lab.setup.reference_orientation()
    ref = render_plane(lab, lab.setup.rig.head(lab.setup.reference_head).camera, rr, rc, noise_dn, seed=10_000,
                       supersample=supersample)
    return out, ref


def render_reference_series(lab: Lab, noise_dn: float = 1.0, moved_from: int | None = None,
                            rotation_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
                            ) -> tuple[list[str], list[NDArray[np.uint8]]]:
    """The static reference camera's image at every exposure of the session (one per tumbling image, in the order
    of ``lab.names``), each with its own 1 DN noise: names ``<tumbling image>_reference.png`` and images.

    ``moved_from``: from this exposure on the reference camera is turned by ``rotation_rad`` (a rotation vector in
    the camera frame, radians: x, y tilt the view across the image rows / columns, z turns it about the optical
    axis), as if knocked during the session; None: it stays still (the paper's finding)."""
    from skyrig.geometry.rotations import matrix_from_rotvec

    cam = lab.setup.rig.head(lab.setup.reference_head).camera
    rr, rc = lab.setup.reference_orientation()
    still = _plane_radiance(lab, cam, rr, rc, 1)  # the geometry once per orientation, the noise per exposure
    moved = None
    if moved_from is not None:
        moved = _plane_radiance(lab, cam, rr @ matrix_from_rotvec(np.asarray(rotation_rad, dtype=np.float64)), rc, 1)
    names, images = [], []
    for i, n in enumerate(lab.names):
        g = moved if moved is not None and i >= int(moved_from or 0) else still
        names.append(n.replace("_oblique.png", "_reference.png"))
        images.append(_exposed(g, noise_dn, seed=20_000 + i))
    return names, images
