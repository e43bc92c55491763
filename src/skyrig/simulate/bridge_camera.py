"""The ``uav-bridge-camera`` scenario (paper 002, section 5): a UAV frame camera flown along the bridge.

Everything here is pure computation in memory; :mod:`skyrig.pipeline.simulate` writes the files.

**The object** is the bridge of :mod:`skyrig.simulate.lidar` (:func:`~skyrig.simulate.lidar.make_bridge`,
ray-cast exactly by :meth:`~skyrig.simulate.lidar.BridgeScene.cast`), now with a **procedural texture**
(:class:`BridgeLook`) so that images of it can be matched densely:

* concrete faces: a per-box, per-face-direction base colour, slow stains (3 m value noise), board-formwork
  joints (horizontal every 0.9 m, vertical every 2.4 m) and multi-scale value noise (lattice spacings 1.6 m
  down to 6.6 mm, factor 2.5) in **world coordinates of the face** (bridge frame: ``(v, z)`` on faces
  across the axis, ``(u, z)`` on faces along it, ``(u, v)`` on horizontal faces);
* ground: grass and gravel patches (6 m noise) with the same multi-scale noise in ``(x, y)``;
* every octave (and each joint line) is **band-limited to the pixel footprint** on the surface, taken as
  the side of a square of the pixel's area there (``range * pixel angle / sqrt(|cos incidence|)``): an
  octave of lattice spacing ``s`` has full weight where the footprint is below ``s / 2`` and none above
  ``s``; a joint line is widened to the footprint with its contrast lowered to keep its integral.  One ray
  per pixel then shows the same object texture in every view (up to that blur) without aliasing, except
  for a little along the slope of surfaces seen at grazing incidence (far ground);
* shading: Lambertian under a fixed sun (``ambient + (1 - ambient) max(n . sun, 0)``) with cast shadows
  (a shadow ray per lit hit), sky gradient where nothing is hit, Gaussian sensor noise.

**The camera** is paper 002's AVT Prosilica GT3300C (3296 x 2472 px, 5.5 um) with its 20 mm lens and a
Brown distortion of a C-mount lens of that kind (about 0.8 % barrel in the corners, small decentring and
affinity; the values are an assumption, the paper publishes none).  CI size keeps the sensor and the lens
and bins the pixels 4 x 4: 824 x 618 px of 22 um (same field of view, same mm-based distortion).

**The flight** (paper 002: about 500 images with >= 80 % forward overlap, two flights alongside the
bridge): rows of exposures at ``distance_m`` (horizontal) from the deck side, at ``altitudes_m`` above
the ground, the camera looking across the bridge axis at the bridge, tilted down by ``tilt_deg``, image
x along the bridge (upright images: camera y is up).  Along a row the base is chosen so that the forward
overlap on the deck side is at least ``forward_overlap``; every exposure gets a small random position and
attitude jitter (a hovering multicopter).  CI size: the south side, two rows past the pillar at
u = 13.5 m (11 exposures a row, 22 images); full size: both sides of the whole bridge (4 rows of 60).

**Orientations**: :attr:`BridgeCameraSurvey.eo_true` (exact, local ENU frame) and
:attr:`BridgeCameraSurvey.eo_adjusted`, the truth perturbed at the level a bundle adjustment leaves
(``adjusted_sigma_m`` per axis on the projection centre, ``adjusted_sigma_deg`` per axis as a rotation
vector on the camera side: ``R_adjusted = R_true @ expmap(dr)``), independently per image, seeded.

**The reference** is a terrestrial scan of the imaged stretch, drawn by
:meth:`~skyrig.simulate.lidar.BridgeScene.sample_surfaces` exactly as in the ``uav-bridge-lidar`` scenario.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.brown import BrownDistortion
from skyrig.camera.frame import FrameCamera
from skyrig.errors import GeometryError, SkyrigError
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.geometry.pose import Pose
from skyrig.geometry.rotations import matrix_from_rotvec, rot_z
from skyrig.rig.rig import Head, Rig
from skyrig.simulate.lidar import GROUND, NO_HIT, BridgeScene, make_bridge
from skyrig.simulate.render import camera_rays
from skyrig.simulate.world import value_noise

__all__ = [
    "BRIDGE_CAMERA_SCENARIO",
    "BridgeCameraSpec",
    "BridgeCameraSurvey",
    "BridgeHits",
    "BridgeLook",
    "bridge_camera_spec",
    "build_bridge_camera_survey",
    "gt3300c_camera",
    "render_bridge_image",
    "shade_bridge",
]

BRIDGE_CAMERA_SCENARIO = "uav-bridge-camera"

_Vec = tuple[float, float, float]


# ---------------------------------------------------------------------------------------------- camera
def gt3300c_camera(binning: int = 1, name: str = "prosilica-gt3300c") -> FrameCamera:
    """Paper 002's AVT Prosilica GT3300C with a 20 mm lens, optionally binned ``binning x binning``.

    Sensor 3296 x 2472 px of 5.5 um (18.128 mm x 13.596 mm); principal distance 20.12 mm, principal point
    (0.042, -0.031) mm; Brown distortion K1 = 8e-5 mm^-2, K2 = -1.2e-7 mm^-4, P1 = 1.2e-5 mm^-1,
    P2 = -8e-6 mm^-1, B1 = 2e-5 (radial displacement about -0.094 mm, i.e. 0.8 % barrel, in the corners).
    Binning keeps the sensor size and all mm-based parameters (same field of view and distortion).
    """
    if binning < 1 or 3296 % binning or 2472 % binning:
        raise SkyrigError(f"binning must divide 3296 and 2472, got {binning}")
    return FrameCamera(name, 3296 // binning, 2472 // binning, 0.0055 * binning, 20.12, 0.042, -0.031,
                       BrownDistortion(k1=8.0e-5, k2=-1.2e-7, k3=0.0, p1=1.2e-5, p2=-8.0e-6, b1=2.0e-5, b2=0.0))


# ---------------------------------------------------------------------------------------------- look
@dataclass(frozen=True)
class BridgeLook:
    """Texture and light of the bridge scene (see the module docstring).

    Attributes
    ----------
    seed
        Seed of the texture hashes.
    octaves_m
        Lattice spacings of the value-noise octaves (metres), coarse to fine.
    octave_amplitude
        Amplitude of each octave on concrete (relative brightness, applied to ``noise - 0.5``).
    ground_octave_amplitude
        The same on the ground.
    stain_scale_m, stain_amplitude
        Slow brightness variation of concrete (lattice spacing, relative amplitude).
    joint_spacing_m
        Board-formwork joints on concrete: (horizontal lines every ..., vertical lines every ...) metres.
    joint_width_m, joint_darkness
        Width of a joint and its relative darkening.
    concrete_rgb, grass_rgb, gravel_rgb
        Base colours (linear 0..1).
    patch_scale_m
        Lattice spacing of the grass / gravel patches.
    sun_azimuth_deg, sun_elevation_deg
        Sun direction (azimuth clockwise from north, elevation above the horizon).
    ambient
        Share of the light that reaches faces turned away from the sun and shadows.
    shadows
        Cast shadows (one shadow ray per lit hit).
    sky_rgb_horizon, sky_rgb_zenith
        Sky colour at the horizon and at the zenith.
    """

    seed: int = 2
    octaves_m: tuple[float, ...] = (1.6, 0.64, 0.256, 0.1024, 0.04096, 0.016384, 0.0065536)
    octave_amplitude: tuple[float, ...] = (0.18, 0.22, 0.30, 0.42, 0.50, 0.50, 0.50)
    ground_octave_amplitude: tuple[float, ...] = (0.25, 0.30, 0.40, 0.50, 0.55, 0.55, 0.55)
    stain_scale_m: float = 3.0
    stain_amplitude: float = 0.35
    joint_spacing_m: tuple[float, float] = (0.9, 2.4)
    joint_width_m: float = 0.02
    joint_darkness: float = 0.45
    concrete_rgb: _Vec = (0.66, 0.64, 0.60)
    grass_rgb: _Vec = (0.30, 0.42, 0.17)
    gravel_rgb: _Vec = (0.55, 0.50, 0.42)
    patch_scale_m: float = 6.0
    sun_azimuth_deg: float = 150.0
    sun_elevation_deg: float = 40.0
    ambient: float = 0.4
    shadows: bool = True
    sky_rgb_horizon: _Vec = (0.80, 0.86, 0.94)
    sky_rgb_zenith: _Vec = (0.45, 0.62, 0.90)

    def __post_init__(self) -> None:
        if len(self.octaves_m) != len(self.octave_amplitude) or len(self.octaves_m) != len(self.ground_octave_amplitude):
            raise SkyrigError("octaves_m, octave_amplitude and ground_octave_amplitude must have the same length")
        if not 0.0 <= self.ambient <= 1.0:
            raise SkyrigError(f"ambient must be in [0, 1], got {self.ambient}")

    @property
    def sun(self) -> NDArray[np.float64]:
        """``(3,)`` unit vector towards the sun (local ENU)."""
        az, el = np.radians(self.sun_azimuth_deg), np.radians(self.sun_elevation_deg)
        return np.array([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)])

    def to_dict(self) -> dict[str, Any]:
        return {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v) for f in fields(self)}


def _band(scale_m: float, footprint: NDArray[np.float64]) -> NDArray[np.float64]:
    """Weight of an octave of lattice spacing ``scale_m`` at pixel footprints ``(N,)``: 1 below ``s / 2``,
    0 above ``s``, linear in between."""
    return np.clip(scale_m / footprint - 1.0, 0.0, 1.0)


def _noise_sum(a: NDArray, b: NDArray, footprint: NDArray, look: BridgeLook, amps: tuple[float, ...],
               seed: int) -> NDArray[np.float64]:
    """``(N,)`` band-limited sum of the value-noise octaves (zero mean) at face coordinates ``a, b``."""
    out = np.zeros(a.shape)
    for o, (s, amp) in enumerate(zip(look.octaves_m, amps)):
        w = _band(s, footprint)
        sel = np.flatnonzero(w > 0)
        if sel.size == 0:
            continue
        if sel.size == a.size:
            out += (amp * w) * (value_noise(a, b, s, seed * 31 + o) - 0.5)
        else:
            out[sel] += (amp * w[sel]) * (value_noise(a[sel], b[sel], s, seed * 31 + o) - 0.5)
    return out


def _joints(c: NDArray, spacing: float, look: BridgeLook, footprint: NDArray) -> NDArray[np.float64]:
    """``(N,)`` darkening in [0, 1) of joint lines at multiples of ``spacing`` (coordinate ``c``): a box
    profile of width ``joint_width_m`` widened to the footprint, contrast scaled to keep its integral."""
    d = np.abs(c / spacing - np.round(c / spacing)) * spacing  # distance to the nearest joint
    width = np.maximum(look.joint_width_m, footprint)
    inside = np.clip((width / 2 - d) / np.maximum(footprint, 1e-9) + 0.5, 0.0, 1.0)  # pixel coverage, soft edge
    return look.joint_darkness * (look.joint_width_m / width) * inside


def shade_bridge(scene: BridgeScene, look: BridgeLook, xyz: NDArray[np.float64], normal: NDArray[np.float64],
                 component: NDArray[np.intp], direction: NDArray[np.float64], footprint: NDArray[np.float64],
                 ) -> NDArray[np.float64]:
    """Colours of ray hits on the bridge scene.

    Parameters
    ----------
    scene, look
        The bridge and its texture / light.
    xyz, normal
        ``(N, 3)`` hit points and outward unit normals (local ENU, metres).
    component
        ``(N,)`` box index, :data:`~skyrig.simulate.lidar.GROUND` or :data:`~skyrig.simulate.lidar.NO_HIT` (sky).
    direction
        ``(N, 3)`` unit ray directions (for the sky colour).
    footprint
        ``(N,)`` pixel footprint on the surface (metres; band limit of the texture).

    Returns
    -------
    ``(N, 3)`` linear RGB in [0, 1] (texture x shading, without shadows: see :func:`render_bridge_image`).
    """
    n = len(component)
    rgb = np.empty((n, 3))
    sky = component == NO_HIT
    if np.any(sky):
        el = np.clip(direction[sky, 2], 0.0, 1.0)[:, None] ** 0.5
        rgb[sky] = (1 - el) * np.array(look.sky_rgb_horizon) + el * np.array(look.sky_rgb_zenith)
    lb = scene.local_from_bridge
    g = np.flatnonzero(component == GROUND)
    if g.size:
        x, y = xyz[g, 0], xyz[g, 1]
        f = footprint[g]
        m = value_noise(x, y, look.patch_scale_m, look.seed * 7 + 1)
        m = np.clip((m - 0.35) / 0.3, 0.0, 1.0)  # 0 grass .. 1 gravel
        base = (1 - m)[:, None] * np.array(look.grass_rgb) + m[:, None] * np.array(look.gravel_rgb)
        detail = _noise_sum(x, y, f, look, look.ground_octave_amplitude, look.seed * 7 + 2)
        tint = 0.12 * _band(0.3, f) * (value_noise(x, y, 0.3, look.seed * 7 + 3) - 0.5)  # grass / pebble colour
        rgb[g] = base * (1.0 + detail)[:, None]
        rgb[g, 1] *= 1.0 + tint
    b = np.flatnonzero(component >= 0)
    if b.size:
        uvz = xyz[b] @ lb  # bridge frame (u along the axis, v across, z up)
        nb = normal[b] @ lb
        ax = np.argmax(np.abs(nb), axis=1)  # 0: face across the axis, 1: along it, 2: horizontal
        sgn = np.take_along_axis(nb, ax[:, None], axis=1)[:, 0] > 0
        fcls = 2 * ax + sgn  # face direction class 0..5
        a = np.where(ax == 0, uvz[:, 1], uvz[:, 0])
        c = np.where(ax == 2, uvz[:, 1], uvz[:, 2])
        f = footprint[b]
        comp = component[b]
        seed = look.seed * 1009 + 13 * comp + fcls  # per box and face direction
        out = np.empty((b.size, 3))
        for s in np.unique(seed):
            k = np.flatnonzero(seed == s)
            ss = int(s)
            detail = _noise_sum(a[k], c[k], f[k], look, look.octave_amplitude, ss)
            stain = 1.0 + look.stain_amplitude * (value_noise(a[k], c[k], look.stain_scale_m, ss * 5 + 4) - 0.5)
            j = np.maximum(_joints(c[k], look.joint_spacing_m[0], look, f[k]),
                           _joints(a[k], look.joint_spacing_m[1], look, f[k]))
            tone = 0.9 + 0.2 * ((ss * 2654435761) % 1000) / 1000.0  # per face brightness
            out[k] = (np.array(look.concrete_rgb) * tone) * (stain * (1.0 + detail) * (1.0 - j))[:, None]
        rgb[b] = out
    hit = ~sky
    if np.any(hit):
        lam = np.clip(normal[hit] @ look.sun, 0.0, 1.0)
        rgb[hit] *= (look.ambient + (1.0 - look.ambient) * lam)[:, None]
    return np.clip(rgb, 0.0, 1.0, out=rgb)


# ---------------------------------------------------------------------------------------------- render
@dataclass(frozen=True)
class BridgeHits:
    """Per-pixel ray-casting results of one rendered image (row-major, ``(H, W)`` grids).

    Attributes
    ----------
    range_m
        ``(H, W)`` distance from the projection centre to the surface (inf: sky).
    xyz
        ``(H, W, 3)`` surface points (local ENU, NaN for the sky).
    normal
        ``(H, W, 3)`` outward unit normals (zeros for the sky).
    component
        ``(H, W)`` box index (``scene.boxes``), -1 ground, -2 sky.
    shadow
        ``(H, W)`` the point is in a cast shadow.
    """

    range_m: NDArray[np.float64]
    xyz: NDArray[np.float64]
    normal: NDArray[np.float64]
    component: NDArray[np.intp]
    shadow: NDArray[np.bool_]


_CORNER_SIGNS = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=np.float64)


def _corners(box: Any) -> NDArray[np.float64]:
    """``(8, 3)`` corners of a box (local ENU)."""
    return box.centre + (_CORNER_SIGNS * box.half_size) @ box.local_from_box.T


def _first_hits(scene: BridgeScene, origin: NDArray[np.float64], direction: NDArray[np.float64],
                candidates: list[NDArray[np.intp] | None], max_range: float = np.inf,
                ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.intp]]:
    """:meth:`BridgeScene.cast` with each box tested only on the rays that may meet it.

    ``origin`` and ``direction`` are ``(N, 3)``; ``candidates[k]`` holds the indices of the rays that may hit
    box ``k`` (None: all of them).  Same results as ``scene.cast`` if no ray outside a box's candidates hits
    it (the candidates are conservative bounds, see the callers)."""
    best, normal, comp = replace(scene, boxes=()).cast(origin, direction, max_range)  # the ground
    for k, idx in enumerate(candidates):
        if idx is not None and idx.size == 0:
            continue
        one = replace(scene, boxes=(scene.boxes[k],))
        o_k, d_k = (origin, direction) if idx is None else (origin[idx], direction[idx])
        t, nrm, c = one.cast(o_k, d_k, max_range)
        closer = (c == 0) & (t < (best if idx is None else best[idx]))
        sel = np.flatnonzero(closer) if idx is None else idx[closer]
        best[sel] = t[closer]
        normal[sel] = nrm[closer]
        comp[sel] = k
    return best, normal, comp


def _view_candidates(scene: BridgeScene, rays_c: NDArray[np.float64], r: NDArray[np.float64],
                     centre: NDArray[np.float64]) -> list[NDArray[np.intp] | None]:
    """Per box, the camera rays ``rays_c (N, 3)`` (camera frame) whose direction lies in the bounding
    rectangle of the box's corner directions (``P_x / -P_z``, ``P_y / -P_z``; a ray through a convex box
    points inside the cone of its corners); all rays (None) if a corner is not in front of the camera."""
    tx = rays_c[:, 0] / -rays_c[:, 2]
    ty = rays_c[:, 1] / -rays_c[:, 2]
    out: list[NDArray[np.intp] | None] = []
    for b in scene.boxes:
        p = (_corners(b) - centre) @ r  # camera frame
        depth = -p[:, 2]
        if np.any(depth <= 1e-9):
            out.append(None)
            continue
        qx, qy = p[:, 0] / depth, p[:, 1] / depth
        eps = 1e-9
        out.append(np.flatnonzero((tx >= qx.min() - eps) & (tx <= qx.max() + eps)
                                  & (ty >= qy.min() - eps) & (ty <= qy.max() + eps)))
    return out


def _sun_candidates(scene: BridgeScene, points: NDArray[np.float64], sun: NDArray[np.float64]
                    ) -> list[NDArray[np.intp] | None]:
    """Per box, the points ``(N, 3)`` whose ray towards the sun may meet it: within the box's bounding
    rectangle across the sun direction and not beyond the box along it."""
    a = np.cross(sun, [0.0, 0.0, 1.0] if abs(sun[2]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    frame = np.column_stack([a, np.cross(sun, a), sun])  # columns: across, across, along the sun
    q = points @ frame
    out: list[NDArray[np.intp] | None] = []
    for b in scene.boxes:
        c = _corners(b) @ frame
        lo, hi = c.min(axis=0) - 1e-9, c.max(axis=0) + 1e-9
        out.append(np.flatnonzero((q[:, 0] >= lo[0]) & (q[:, 0] <= hi[0]) & (q[:, 1] >= lo[1]) & (q[:, 1] <= hi[1])
                                  & (q[:, 2] <= hi[2])))
    return out


def render_bridge_image(
    scene: BridgeScene,
    look: BridgeLook,
    camera: FrameCamera,
    world_from_camera: Pose,
    noise_dn: float = 0.0,
    seed: int = 0,
    return_hits: bool = False,
    chunk_rays: int = 1 << 20,
) -> NDArray[np.uint8] | tuple[NDArray[np.uint8], BridgeHits]:
    """Render one image of the bridge by ray casting every pixel centre.

    Parameters
    ----------
    scene, look
        The bridge (local ENU frame) and its texture and light.
    camera
        Camera including distortion: the image is the *observed* (distorted) one; the ray of pixel
        ``(col, row)`` (centre of the top-left pixel = ``(0, 0)``) is :meth:`FrameCamera.rays_from_pixels`.
    world_from_camera
        Exterior orientation in the scene's local frame (single pose).
    noise_dn
        Standard deviation of additive Gaussian sensor noise (digital numbers, 0-255 scale).
    seed
        Seed of the noise.
    return_hits
        Also return the per-pixel :class:`BridgeHits`.
    chunk_rays
        Rays cast at a time (bounds the memory: about 0.5 kB per ray).

    Returns
    -------
    ``(H, W, 3)`` uint8 RGB image (and the hits).
    """
    rays_c = camera_rays(camera)  # (H*W, 3) camera frame, unit, cached per camera
    r = np.asarray(world_from_camera.rotation, dtype=np.float64).reshape(3, 3)
    o = np.asarray(world_from_camera.translation, dtype=np.float64).reshape(3)
    n = rays_c.shape[0]
    ipx = camera.pixel_size_mm / camera.focal_mm  # angular size of a pixel at the centre (rad)
    sun = look.sun
    rgb = np.empty((n, 3))
    keep = return_hits
    if keep:
        rng_all = np.empty(n)
        xyz_all = np.empty((n, 3))
        nrm_all = np.empty((n, 3))
        comp_all = np.empty(n, dtype=np.intp)
        shd_all = np.zeros(n, dtype=bool)
    for s in range(0, n, chunk_rays):
        e = min(n, s + chunk_rays)
        d = rays_c[s:e] @ r.T
        t, nrm, comp = _first_hits(scene, np.broadcast_to(o, d.shape), d, _view_candidates(scene, rays_c[s:e], r, o))
        hit = comp != NO_HIT
        xyz = np.full(d.shape, np.nan)
        xyz[hit] = o + t[hit, None] * d[hit]
        cosi = np.abs(np.einsum("ij,ij->i", d, nrm))
        with np.errstate(invalid="ignore"):
            fp = np.where(hit, t * ipx / np.sqrt(np.maximum(cosi, 0.01)), np.inf)  # side of the pixel's area
        col = shade_bridge(scene, look, xyz, nrm, comp, d, fp)
        shadow = np.zeros(e - s, dtype=bool)
        if look.shadows:
            lit = np.flatnonzero(hit & (nrm @ sun > 0))
            if lit.size:
                so = xyz[lit] + 1e-6 * nrm[lit]
                ts, _, _ = _first_hits(scene, so, np.broadcast_to(sun, so.shape),  # rays go up: no ground
                                       _sun_candidates(scene, so, sun))
                shadow[lit[np.isfinite(ts)]] = True
                sh = np.flatnonzero(shadow)
                lam = np.clip(nrm[sh] @ sun, 0.0, 1.0)
                col[sh] *= (look.ambient / (look.ambient + (1.0 - look.ambient) * lam))[:, None]
        rgb[s:e] = col
        if keep:
            rng_all[s:e] = t
            xyz_all[s:e] = xyz
            nrm_all[s:e] = nrm
            comp_all[s:e] = comp
            shd_all[s:e] = shadow
    rgb *= 255.0
    rgb += 0.5
    if noise_dn > 0:
        rgb += np.random.default_rng(seed).normal(0.0, noise_dn, rgb.shape)
    np.clip(rgb, 0, 255, out=rgb)
    img = rgb.astype(np.uint8).reshape(camera.height, camera.width, 3)
    if not keep:
        return img
    h, w = camera.height, camera.width
    return img, BridgeHits(rng_all.reshape(h, w), xyz_all.reshape(h, w, 3), nrm_all.reshape(h, w, 3),
                           comp_all.reshape(h, w), shd_all.reshape(h, w))


# ---------------------------------------------------------------------------------------------- spec
@dataclass(frozen=True)
class BridgeCameraSpec:
    """Everything the ``uav-bridge-camera`` scenario is a deterministic function of.

    Attributes
    ----------
    name, size, seed
        Scenario name, ``"ci"`` or ``"full"``, random seed.
    binning
        Pixel binning of the GT3300C (4 in CI size: 824 x 618 px; 1: 3296 x 2472 px).
    origin, crs
        (lat, lon, h) of the local ENU frame and the map CRS (ellipsoidal heights): those of ``uav-bridge-lidar``.
    bridge
        Keyword arguments of :func:`~skyrig.simulate.lidar.make_bridge`.
    look
        Texture and light.
    sides
        ``("south",)`` and/or ``"north"``: the sides flown (south: ``v < 0`` in the bridge frame).
    u_range_m
        ``(u_first, u_last)`` of the projection centres along the bridge axis (bridge frame, metres).
    distance_m
        Horizontal distance of the projection centres from the deck side face.
    altitudes_m
        Heights of the rows above the ground (one row of exposures per height and side).
    tilt_deg
        Downward tilt of the optical axis below the horizontal.
    forward_overlap
        Minimum forward overlap on the deck side face (paper 002: at least 80 %).
    speed_mps, row_change_s, t0_s
        Flight speed, time between rows, GPS seconds of week of the first exposure (exposure times only).
    jitter_m, jitter_deg
        Standard deviation of the random position (per axis) and attitude (rotation vector per camera
        axis) deviations of each exposure from the nominal one (true orientations).
    adjusted_sigma_m, adjusted_sigma_deg
        Standard deviations of the "adjusted-level" orientation errors (per axis; rotation vector on the
        camera side), drawn independently per image.
    noise_dn
        Image noise (digital numbers).
    reference_density_per_m2, reference_ground_density_per_m2, reference_noise_m
        The terrestrial reference scan (as in ``uav-bridge-lidar``).
    """

    name: str = BRIDGE_CAMERA_SCENARIO
    size: str = "ci"
    seed: int = 1
    binning: int = 4
    origin: tuple[float, float, float] = (51.0275, 13.7258, 150.0)
    crs: str = "EPSG:32633"
    bridge: dict[str, Any] = field(default_factory=dict)
    look: BridgeLook = field(default_factory=BridgeLook)
    sides: tuple[str, ...] = ("south",)
    u_range_m: tuple[float, float] = (27.0, 0.0)
    distance_m: float = 15.0
    altitudes_m: tuple[float, ...] = (4.0, 7.0)
    tilt_deg: float = 6.0
    forward_overlap: float = 0.8
    speed_mps: float = 1.5
    row_change_s: float = 10.0
    t0_s: float = 346_000.0
    jitter_m: _Vec = (0.10, 0.10, 0.08)
    jitter_deg: _Vec = (0.8, 0.8, 0.8)
    adjusted_sigma_m: float = 0.005
    adjusted_sigma_deg: float = 0.005
    noise_dn: float = 1.0
    reference_density_per_m2: float = 250.0
    reference_ground_density_per_m2: float = 60.0
    reference_noise_m: float = 0.003

    @property
    def camera(self) -> FrameCamera:
        """The camera (true interior orientation = the calibrated one written to ``rig.yaml``)."""
        return gt3300c_camera(self.binning)


def bridge_camera_spec(size: str = "ci", seed: int = 1) -> BridgeCameraSpec:
    """The ``uav-bridge-camera`` scenario in CI or full size (see the module docstring).

    CI: binning 4 (824 x 618 px), the south side, rows at 4 m and 7 m, u from 27 m to 0 m: 22 images.
    Full: full resolution (3296 x 2472 px), both sides, u from 80 m to -80 m: 240 images.
    """
    if size not in ("ci", "full"):
        raise SkyrigError(f"scenario size must be 'ci' or 'full', not {size!r}")
    if size == "ci":
        return BridgeCameraSpec(size="ci", seed=seed)
    return BridgeCameraSpec(size="full", seed=seed, binning=1, sides=("south", "north"), u_range_m=(80.0, -80.0),
                            reference_density_per_m2=200.0, reference_ground_density_per_m2=40.0)


# ---------------------------------------------------------------------------------------------- survey
@dataclass(frozen=True, eq=False)
class BridgeCameraSurvey:
    """A simulated UAV camera flight along the bridge, in memory (images rendered on demand).

    Attributes
    ----------
    spec, scene, frame
        The scenario, the bridge and the local ENU frame of the scene.
    camera, rig
        The camera and a one-head rig carrying it (head ``"camera"``, mounting: looking to the right of
        the body, tilted down; informative only, the orientations are per image).
    eo_true
        ``N`` true exterior orientations (local ENU frame, ``world_from_camera``), with exposure times.
    eo_adjusted
        The same perturbed at adjusted level (local ENU frame).
    adjusted_error_m, adjusted_error_rad
        ``(N, 3)`` the drawn centre errors (adjusted minus true, local ENU, m) and rotation errors
        (rotation vectors, camera frame, rad: ``R_adjusted = R_true @ expmap(error)``).
    reference_xyz, reference_normal
        ``(M, 3)`` the terrestrial reference scan (local ENU) and the true normals of its faces.
    flight
        Figures of the flight: rows, base, overlap, ground sample distance on the deck side.
    """

    spec: BridgeCameraSpec
    scene: BridgeScene
    frame: WorldFrame
    camera: FrameCamera
    rig: Rig
    eo_true: ExteriorOrientations
    eo_adjusted: ExteriorOrientations
    adjusted_error_m: NDArray[np.float64]
    adjusted_error_rad: NDArray[np.float64]
    reference_xyz: NDArray[np.float64]
    reference_normal: NDArray[np.float64]
    flight: dict[str, Any]

    def image_seed(self, k: int) -> int:
        """Seed of image ``k``'s sensor noise."""
        return self.spec.seed * 100_003 + k

    def render(self, k: int, return_hits: bool = False) -> NDArray[np.uint8] | tuple[NDArray[np.uint8], BridgeHits]:
        """Render image ``k`` with its true orientation (see :func:`render_bridge_image`)."""
        pose = Pose(self.eo_true.rotation[k], self.eo_true.centre[k], "world", "camera")
        return render_bridge_image(self.scene, self.spec.look, self.camera, pose, self.spec.noise_dn,
                                   self.image_seed(k), return_hits)


def _camera_in_bridge(side: str, tilt_rad: float) -> NDArray[np.float64]:
    """``(3, 3)`` nominal ``bridge_from_camera``: looking across the axis at the bridge, tilted down,
    image x along the axis (+u on the south side), camera y up."""
    s, c = np.sin(tilt_rad), np.cos(tilt_rad)
    south = np.array([[1.0, 0.0, 0.0], [0.0, s, -c], [0.0, c, s]])  # columns: camera x, y, z
    if side == "south":
        return south
    if side == "north":
        return rot_z(np.pi) @ south
    raise SkyrigError(f"sides must be 'south' or 'north', not {side!r}")


def _body_from_camera(tilt_rad: float) -> NDArray[np.float64]:
    """Nominal mounting for a body flying with the bridge on its right (x forward, y right, z down)."""
    s, c = np.sin(tilt_rad), np.cos(tilt_rad)
    return np.array([[-1.0, 0.0, 0.0], [0.0, s, -c], [0.0, -c, -s]])


def build_bridge_camera_survey(spec: BridgeCameraSpec) -> BridgeCameraSurvey:
    """Simulate the flight in memory: bridge, camera, true and adjusted-level orientations, reference scan.

    Deterministic for a given ``spec`` (its seed).  Images are rendered by :meth:`BridgeCameraSurvey.render`.

    Raises
    ------
    SkyrigError
        On an invalid spec (overlap outside (0, 1), unknown side, no rows).
    GeometryError
        If a projection centre is inside the bridge or below the ground.
    """
    if not 0.0 < spec.forward_overlap < 1.0:
        raise SkyrigError(f"forward_overlap must be in (0, 1), got {spec.forward_overlap}")
    if not spec.altitudes_m or not spec.sides:
        raise SkyrigError("need at least one side and one altitude")
    rng = np.random.default_rng(spec.seed)
    scene = make_bridge(**spec.bridge)
    frame = WorldFrame.local(*spec.origin)
    cam = spec.camera
    tilt = np.radians(spec.tilt_deg)
    lb = scene.local_from_bridge
    # base: the footprint on the deck side along the optical axis, times (1 - overlap)
    depth = spec.distance_m / np.cos(tilt)
    footprint = depth * cam.sensor_size_mm[0] / cam.focal_mm
    u0, u1 = spec.u_range_m
    length = abs(u1 - u0)
    n_per_row = int(np.ceil(length / ((1.0 - spec.forward_overlap) * footprint) - 1e-9)) + 1
    base = length / max(n_per_row - 1, 1)
    names, centres, rots, times = [], [], [], []
    t = spec.t0_s
    row_info = []
    r_index = 0
    for side in spec.sides:
        v = (scene.width_m / 2 + spec.distance_m) * (-1.0 if side == "south" else 1.0)
        b_from_c = _camera_in_bridge(side, tilt)
        for alt in spec.altitudes_m:
            us = np.linspace(u0, u1, n_per_row) if r_index % 2 == 0 else np.linspace(u1, u0, n_per_row)
            row_info.append({"side": side, "altitude_m": float(alt), "u_from_m": float(us[0]), "u_to_m": float(us[-1]),
                             "images": int(n_per_row)})
            for k, u in enumerate(us):
                names.append(f"{side}_r{len(row_info)}_{k:03d}.png")
                centres.append(lb @ np.array([u, v, scene.ground_z + alt]))
                rots.append(lb @ b_from_c)
                times.append(t)
                t += base / spec.speed_mps
            t += spec.row_change_s
            r_index += 1
    n = len(names)
    centre = np.array(centres) + rng.normal(0.0, 1.0, (n, 3)) * np.asarray(spec.jitter_m)
    jit = rng.normal(0.0, 1.0, (n, 3)) * np.radians(spec.jitter_deg)
    rotation = np.array(rots) @ matrix_from_rotvec(jit)
    for k in range(n):
        if centre[k, 2] <= scene.ground_z or any(bx.contains(centre[k:k + 1], 0.0)[0] for bx in scene.boxes):
            raise GeometryError(f"projection centre of {names[k]} is below the ground or inside the bridge")
    eo_true = ExteriorOrientations(np.array(names), cam.name, centre, rotation, frame, time_s=np.array(times),
                                   head=np.full(n, "camera"), exposure=np.arange(n))
    # adjusted-level orientations: an independent stream, so the truth does not change with the sigmas
    arng = np.random.default_rng([spec.seed, 3])
    de = arng.normal(0.0, spec.adjusted_sigma_m, (n, 3))
    dr = arng.normal(0.0, np.radians(spec.adjusted_sigma_deg), (n, 3))
    eo_adj = ExteriorOrientations(eo_true.image, eo_true.camera, centre + de, rotation @ matrix_from_rotvec(dr), frame,
                                  time_s=eo_true.time_s, head=eo_true.head, exposure=eo_true.exposure)
    rig = Rig("adfex-uav-camera", [Head("camera", cam, mounting=_body_from_camera(tilt))],
              description="paper 002 (ADFEX): AVT Prosilica GT3300C with a 20 mm lens looking sideways at the bridge, "
                          f"tilted {spec.tilt_deg:g} deg down; simulated calibration (skyrig uav-bridge-camera)")
    # the terrestrial reference of the imaged stretch (same generator as uav-bridge-lidar)
    half_view = 0.5 * footprint + 8.0
    u_ref = (min(u0, u1) - half_view, max(u0, u1) + half_view)
    rv = scene.width_m / 2 + spec.distance_m + 8.0
    ref, ref_n = scene.sample_surfaces(np.random.default_rng([spec.seed, 2]), spec.reference_density_per_m2,
                                       spec.reference_ground_density_per_m2, spec.reference_noise_m, u_ref, (-rv, rv))
    gsd = depth * cam.pixel_size_mm / cam.focal_mm
    flight = {"rows": row_info, "images_per_row": int(n_per_row), "base_m": float(base),
              "footprint_on_deck_side_m": float(footprint), "forward_overlap_on_deck_side": float(1.0 - base / footprint),
              "distance_to_deck_side_m": float(spec.distance_m), "depth_along_axis_m": float(depth),
              "gsd_on_deck_side_m": float(gsd), "base_to_depth": float(base / depth),
              "tilt_deg": float(spec.tilt_deg), "reference_u_range_m": [float(v) for v in u_ref]}
    return BridgeCameraSurvey(spec, scene, frame, cam, rig, eo_true, eo_adj, de, dr, ref, ref_n, flight)
