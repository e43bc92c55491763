"""Seeded procedural worlds: smooth terrain, a small town (flat and gabled roofs, façades), ground texture.

The scene lives in a **local Cartesian frame** (``x`` east, ``y`` north, ``z`` up, metres): the
tangent-plane ENU frame :meth:`skyrig.georef.WorldFrame.local` at ``Scene.origin`` (lat, lon, h).
Rendering in this frame is rigorous (no map scale factor, no earth curvature approximation); map
coordinates of anything in the scene come from ``WorldFrame.to_ecef`` / ``from_ecef``.

The truth of the scene is analytic:

* **terrain** ``z = base + sum_k a_k sin(kx_k x + ky_k y + phase_k)`` (gentle: wavelengths >= 150 m);
* **buildings**: convex prisms (a rectangle of half sizes ``hl x hw`` turned by ``azimuth``; a flat roof,
  or a gabled roof with its ridge along the long axis); each is the intersection of 7 (gabled) or 6
  (flat) half-spaces, which makes ray casting exact;
* **ground texture** :meth:`Scene.ground_rgb`: multi-octave hashed value noise (non-repeating at every
  scale between ``texture_coarse_m`` and ``texture_fine_m``) on patches of land cover, plus roads;
* **façade texture rule** :meth:`Scene.facade_rgb`: per-building wall colour, a window grid
  (``window_spacing_m``) and hashed noise, a function of (building, along-wall coordinate, height);
* **stockpiles** (optional, :class:`Stockpiles`): truncated cones of material standing on the terrain (their
  height is added to it: part of the bare earth a DTM shows), of analytic volume ``pi h (R^2 + R r + r^2) / 3``
  above the natural ground;
* **signalised targets** (GCPs): a white disc of radius ``r`` (linear edge ramp of width ``r / 2``) in a black square of half side ``2.5 r``
  painted onto the ground texture, centred on ``(x, y, terrain(x, y))``; or **circular coded targets** (ring-coded,
  of the Schneider / AICON kind): a white centre dot of radius ``r``, a black gap to ``2 r``, a code ring from ``2 r``
  to ``3 r`` of ``N`` equal sectors (sector ``b``, from ``2 pi b / N`` counter-clockwise from east seen from above,
  white when bit ``b`` of the target's code is set), in a black square of half side ``4 r`` (every edge with the
  same ramp); or 2 x 2 chequers, or ArUco markers (:class:`Target`).

:func:`rasterize_dsm` and :func:`rasterize_orthophoto` sample the scene on grids (the files written
by a simulated project); the renderer uses the analytic scene.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import SkyrigError

_U32 = np.uint32


_C1, _C2, _C3 = _U32(374761393), _U32(668265263), _U32(1274126177)
_INV32 = 1.0 / 4294967296.0


def _mix(h: NDArray[np.uint32]) -> NDArray[np.float64]:
    """Final mixing of a 32-bit lattice hash to ``[0, 1)`` (in place on ``h``)."""
    h ^= h >> _U32(13)
    h *= _C3
    h ^= h >> _U32(16)
    return h * _INV32


def _hash2(ix: NDArray[np.int64], iy: NDArray[np.int64], seed: int) -> NDArray[np.float64]:
    """Deterministic hash of integer lattice points to ``[0, 1)`` (vectorised, 32-bit integer mixing).

    ``h = (ix * 374761393 + iy * 668265263 + seed * 2147483647) mod 2**32``, computed in wrapping uint32
    arithmetic (the same value as in 64-bit integers masked to 32 bits), then mixed."""
    with np.errstate(over="ignore"):
        h = np.asarray(ix).astype(_U32) * _C1
        h += np.asarray(iy).astype(_U32) * _C2
        h += _U32((seed * 2147483647) & 0xFFFFFFFF)
        return _mix(h)


def value_noise(x: NDArray[np.float64], y: NDArray[np.float64], scale_m: float, seed: int) -> NDArray[np.float64]:
    """Smooth value noise in ``[0, 1)`` with lattice spacing ``scale_m`` (smoothstep interpolation)."""
    u, v = x / scale_m, y / scale_m
    fx, fy = np.floor(u), np.floor(v)
    tx, ty = u - fx, v - fy
    tx = tx * tx * (3.0 - 2.0 * tx)
    ty = ty * ty * (3.0 - 2.0 * ty)
    with np.errstate(over="ignore"):
        # the four corner hashes share their products: (ix + 1) * C1 = ix * C1 + C1 (mod 2**32)
        hx = fx.astype(np.int64).astype(_U32) * _C1
        hy = fy.astype(np.int64).astype(_U32) * _C2
        hy += _U32((seed * 2147483647) & 0xFFFFFFFF)
        h00 = hx + hy
        a = _mix(h00.copy())
        h00 += _C1
        b = _mix(h00.copy())
        h00 += _C2
        d = _mix(h00.copy())
        h00 -= _C1
        c = _mix(h00)
    ab = a + (b - a) * tx
    return ab + ((c + (d - c) * tx) - ab) * ty


@dataclass(frozen=True)
class Buildings:
    """``B`` convex buildings (all arrays ``(B,)``, metres / radians).

    Attributes
    ----------
    cx, cy
        Footprint centre.
    hl, hw
        Half length (along ``azimuth``) and half width.
    azimuth_rad
        Direction of the long axis, counter-clockwise from the x (east) axis.
    base_z
        Bottom of the walls (below the terrain under the footprint).
    eave_z
        Height of the eaves (= roof height of a flat roof).
    ridge_z
        Ridge height; equal to ``eave_z`` for a flat roof.
    """

    cx: NDArray[np.float64]
    cy: NDArray[np.float64]
    hl: NDArray[np.float64]
    hw: NDArray[np.float64]
    azimuth_rad: NDArray[np.float64]
    base_z: NDArray[np.float64]
    eave_z: NDArray[np.float64]
    ridge_z: NDArray[np.float64]

    def __len__(self) -> int:
        return int(np.asarray(self.cx).shape[0])

    @property
    def gabled(self) -> NDArray[np.bool_]:
        return self.ridge_z > self.eave_z + 1e-9

    def planes(self, i: int) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
        """Half-spaces ``n . p <= d`` of building ``i``: normals ``(P, 3)``, offsets ``(P,)`` and face kinds
        ``(P,)`` (0 wall, 1 roof, 2 bottom)."""
        a = self.azimuth_rad[i]
        ux = np.array([np.cos(a), np.sin(a), 0.0])
        uy = np.array([-np.sin(a), np.cos(a), 0.0])
        c = np.array([self.cx[i], self.cy[i], 0.0])
        n = [ux, -ux, uy, -uy, np.array([0.0, 0.0, -1.0])]
        d = [ux @ c + self.hl[i], -ux @ c + self.hl[i], uy @ c + self.hw[i], -uy @ c + self.hw[i], -self.base_z[i]]
        kind = [0, 0, 0, 0, 2]
        if self.gabled[i]:
            rise = self.ridge_z[i] - self.eave_z[i]
            for s in (1.0, -1.0):  # planes through the ridge and the eave on side s
                nn = np.array([s * uy[0] * rise, s * uy[1] * rise, self.hw[i]])
                nn /= np.linalg.norm(nn)
                ridge_pt = c + np.array([0.0, 0.0, self.ridge_z[i]])
                n.append(nn)
                d.append(nn @ ridge_pt)
                kind.append(1)
        else:
            n.append(np.array([0.0, 0.0, 1.0]))
            d.append(self.eave_z[i])
            kind.append(1)
        return np.array(n), np.array(d), np.array(kind)

    def vertices(self, i: int) -> NDArray[np.float64]:
        """``(10, 3)`` points enclosing building ``i`` (footprint corners at base and eave, ridge ends)."""
        a = self.azimuth_rad[i]
        ux = np.array([np.cos(a), np.sin(a)])
        uy = np.array([-np.sin(a), np.cos(a)])
        c = np.array([self.cx[i], self.cy[i]])
        corners = [c + sx * self.hl[i] * ux + sy * self.hw[i] * uy for sx, sy in ((1, 1), (1, -1), (-1, -1), (-1, 1))]
        pts = [np.r_[p, self.base_z[i]] for p in corners] + [np.r_[p, self.eave_z[i]] for p in corners]
        pts += [np.r_[c + s * self.hl[i] * ux, self.ridge_z[i]] for s in (1, -1)]
        return np.array(pts)

    def top_height(self, x: NDArray[np.float64], y: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Roof height and building index at points (NaN / -1 where no building)."""
        z = np.full(np.shape(x), np.nan)
        idx = np.full(np.shape(x), -1, dtype=np.int64)
        for i in range(len(self)):
            a = self.azimuth_rad[i]
            dx, dy = x - self.cx[i], y - self.cy[i]
            u = dx * np.cos(a) + dy * np.sin(a)
            v = -dx * np.sin(a) + dy * np.cos(a)
            inside = (np.abs(u) <= self.hl[i]) & (np.abs(v) <= self.hw[i])
            roof = self.ridge_z[i] - (self.ridge_z[i] - self.eave_z[i]) * np.abs(v) / self.hw[i]
            better = inside & ~(z >= roof)
            z = np.where(better, roof, z)
            idx = np.where(better, i, idx)
        return z, idx


@dataclass(frozen=True)
class Stockpiles:
    """``K`` stockpiles: truncated cones (a cone when the top radius is 0) standing on the natural terrain (all
    arrays ``(K,)``, metres).  The pile's height above the natural ground at horizontal distance ``d`` from its
    centre is ``h`` within the top radius ``r``, falls linearly to 0 at the toe radius ``R`` and is 0 beyond; the
    material above the natural ground is therefore exactly :meth:`volume` whatever the terrain under it.  Piles do
    not overlap (:meth:`height` takes the highest)."""

    cx: NDArray[np.float64]
    cy: NDArray[np.float64]
    radius_m: NDArray[np.float64]  # toe radius R
    top_radius_m: NDArray[np.float64]  # radius r of the flat top (0: a cone)
    height_m: NDArray[np.float64]

    @classmethod
    def of(cls, piles: ArrayLike) -> "Stockpiles":
        """From rows ``(cx, cy, R, r, h)``.

        Raises
        ------
        SkyrigError
            On a row that is not ``0 <= r < R``, ``h > 0``.
        """
        a = np.asarray(piles, dtype=np.float64).reshape(-1, 5)
        bad = ~((a[:, 3] >= 0) & (a[:, 3] < a[:, 2]) & (a[:, 4] > 0))
        if bad.any():
            raise SkyrigError(f"stockpile {int(np.flatnonzero(bad)[0])} {a[bad][0].tolist()}: (cx, cy, R, r, h) "
                              "needs 0 <= r < R and h > 0")
        return cls(*(a[:, k].copy() for k in range(5)))

    def __len__(self) -> int:
        return int(np.asarray(self.cx).shape[0])

    def volume(self) -> NDArray[np.float64]:
        """``(K,)`` volumes above the natural ground (m^3): ``pi h (R^2 + R r + r^2) / 3``."""
        R, r, h = self.radius_m, self.top_radius_m, self.height_m
        return np.pi * h * (R * R + R * r + r * r) / 3.0

    def _profile(self, i: int, x: NDArray[np.float64], y: NDArray[np.float64]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        d = np.hypot(x - self.cx[i], y - self.cy[i])
        R, r, h = self.radius_m[i], self.top_radius_m[i], self.height_m[i]
        return h * np.clip((R - d) / (R - r), 0.0, 1.0), d

    def height(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """Height of the piles above the natural ground at points (0 off every pile)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        z = np.zeros(np.broadcast(x, y).shape)
        for i in range(len(self)):
            z = np.maximum(z, self._profile(i, x, y)[0])
        return z

    def gradient(self, x: ArrayLike, y: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(dh/dx, dh/dy)`` of :meth:`height` (0 on the flat tops and off the piles)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        shape = np.broadcast(x, y).shape
        z, gx, gy = np.zeros(shape), np.zeros(shape), np.zeros(shape)
        for i in range(len(self)):
            h, d = self._profile(i, x, y)
            flank = (d > self.top_radius_m[i]) & (d < self.radius_m[i])
            s = -self.height_m[i] / (self.radius_m[i] - self.top_radius_m[i]) / np.maximum(d, 1e-12)
            top = h > z
            gx = np.where(top, np.where(flank, s * (x - self.cx[i]), 0.0), gx)
            gy = np.where(top, np.where(flank, s * (y - self.cy[i]), 0.0), gy)
            z = np.maximum(z, h)
        return gx, gy


#: kinds of signalised target the scene paints (module docstring)
TARGET_KINDS = ("disc", "coded", "chequer", "aruco")


@dataclass(frozen=True)
class Target:
    """Signalised ground targets (GCPs and check points): names ``(K,)``, centres ``(K, 3)`` (local frame, on the
    terrain) and size ``radius_m``; ``kind`` (:data:`TARGET_KINDS`):

    * ``"disc"``: a white disc of radius ``r`` on a black square of half side ``2.5 r``;
    * ``"coded"``: a circular coded target of ``code_bits`` sectors, ring code ``codes[k]`` (module docstring;
      black square of half side ``4 r``);
    * ``"chequer"``: a 2 x 2 chequer of half side ``2.5 r`` (white where east and north offsets have the same sign),
      its corner on the centre;
    * ``"aruco"``: ArUco marker ``codes[k]`` of OpenCV's ``DICT_4X4_250`` (6 x 6 cells with its black border) of side
      ``4 r``, its top towards north, on a white square of half side ``2 r`` plus one cell (the quiet zone);
      cell edges ramp over a quarter cell.

    Edges ramp linearly over ``r / 2`` (anti-aliasing: the renderer samples one ray per pixel)."""

    name: NDArray[np.str_]
    xyz: NDArray[np.float64]
    radius_m: float
    codes: NDArray[np.int64] | None = None
    code_bits: int = 12
    kind: str = "disc"

    @property
    def half_side_m(self) -> float:
        """Half side of the square the target is painted on."""
        r = self.radius_m
        return {"disc": 2.5 * r, "coded": 4.0 * r, "chequer": 2.5 * r, "aruco": 2.0 * r + 4.0 * r / 6.0}[self.kind]


def _marker_coverage(marker_id: int, u: NDArray[np.float64], v: NDArray[np.float64], ramp_cells: float = 0.25
                     ) -> NDArray[np.float64]:
    """White coverage of ArUco marker ``marker_id`` (``DICT_4X4_250``, 6 x 6 cells with the border, white
    outside) at cell coordinates ``u`` (right) and ``v`` (down) from its top-left corner: per axis the two cells
    either side of the nearest cell edge, blended by a linear ramp of ``ramp_cells`` (a partition of unity)."""
    import cv2

    bits = np.ones((8, 8))
    bits[1:7, 1:7] = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_250).generateImageMarker(marker_id, 6) > 127
    out = np.zeros(np.shape(u))
    bu, bv = np.round(u), np.round(v)
    au = np.clip((u - bu) / ramp_cells + 0.5, 0.0, 1.0)  # weight of the cell right of the edge
    av = np.clip((v - bv) / ramp_cells + 0.5, 0.0, 1.0)
    for du, wu in ((0, au), (-1, 1.0 - au)):
        for dv, wv in ((0, av), (-1, 1.0 - av)):
            i = np.clip(bv + dv + 1, 0, 7).astype(int)
            j = np.clip(bu + du + 1, 0, 7).astype(int)
            out += wu * wv * bits[i, j]
    return out


@dataclass(frozen=True)
class Scene:
    """A procedural scene in a local ENU frame (see the module docstring).

    Attributes
    ----------
    origin
        ``(lat_deg, lon_deg, h_m)`` of the local frame's origin (WGS84, ellipsoidal height).
    extent
        ``(xmin, ymin, xmax, ymax)`` of the modelled area, metres.
    seed
        Seed of every random choice and of the texture hashes.
    base_height_m
        Mean terrain height in the local frame (metres above the tangent plane).
    terrain_amp_m, terrain_kx, terrain_ky, terrain_phase
        ``(K,)`` sinusoid amplitudes (m), wave numbers (rad/m) and phases (rad).
    buildings
        The town.
    targets
        Signalised targets painted on the ground, or None.
    texture_fine_m, texture_coarse_m
        Finest and coarsest noise scales of the ground texture (metres).
    window_spacing_m
        Window grid spacing on façades (metres).
    sun
        ``(3,)`` unit vector towards the sun (Lambertian shading, the same for every view).
    stockpiles
        Piles of material on the terrain, or None (:meth:`terrain_height` includes them,
        :meth:`natural_ground_height` does not).
    """

    origin: tuple[float, float, float]
    extent: tuple[float, float, float, float]
    seed: int
    base_height_m: float
    terrain_amp_m: NDArray[np.float64]
    terrain_kx: NDArray[np.float64]
    terrain_ky: NDArray[np.float64]
    terrain_phase: NDArray[np.float64]
    buildings: Buildings
    targets: Target | None = None
    texture_fine_m: float = 0.05
    texture_coarse_m: float = 40.0
    window_spacing_m: float = 3.0
    sun: NDArray[np.float64] = field(default_factory=lambda: np.array([0.35, -0.45, 0.82]) / np.linalg.norm([0.35, -0.45, 0.82]))
    stockpiles: Stockpiles | None = None

    # ------------------------------------------------------------------ terrain
    def terrain_height(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """Terrain height ``z`` (metres, local frame) at ``x, y`` (any equal shapes): the bare earth, stockpiles
        included."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        z = np.full(np.broadcast(x, y).shape, self.base_height_m)
        for a, kx, ky, ph in zip(self.terrain_amp_m, self.terrain_kx, self.terrain_ky, self.terrain_phase):
            z = z + a * np.sin(kx * x + ky * y + ph)
        if self.stockpiles is not None:
            z = z + self.stockpiles.height(x, y)
        return z

    def natural_ground_height(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """The terrain without the stockpiles (what was there before they were tipped)."""
        z = self.terrain_height(x, y)
        return z if self.stockpiles is None else z - self.stockpiles.height(x, y)

    def terrain_gradient(self, x: ArrayLike, y: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(dz/dx, dz/dy)`` of the terrain."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        gx = np.zeros(np.broadcast(x, y).shape)
        gy = np.zeros_like(gx)
        for a, kx, ky, ph in zip(self.terrain_amp_m, self.terrain_kx, self.terrain_ky, self.terrain_phase):
            c = a * np.cos(kx * x + ky * y + ph)
            gx = gx + kx * c
            gy = gy + ky * c
        if self.stockpiles is not None:
            px, py = self.stockpiles.gradient(x, y)
            gx, gy = gx + px, gy + py
        return gx, gy

    @property
    def terrain_range(self) -> tuple[float, float]:
        """Bounds ``(zmin, zmax)`` of the terrain (conservative)."""
        s = float(np.sum(np.abs(self.terrain_amp_m)))
        top = self.base_height_m + s
        if self.stockpiles is not None and len(self.stockpiles):
            top += float(np.max(self.stockpiles.height_m))
        return self.base_height_m - s, top

    @property
    def top(self) -> float:
        """Highest point of the scene (terrain or roof)."""
        top = self.terrain_range[1]
        if len(self.buildings):
            top = max(top, float(np.max(self.buildings.ridge_z)))
        return top

    def surface_height(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """Digital surface model: the roof where there is a building, else the terrain."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        roof, _ = self.buildings.top_height(x, y)
        t = self.terrain_height(x, y)
        return np.where(np.isfinite(roof), np.fmax(roof, t), t)

    # ------------------------------------------------------------------ textures (values in [0, 1])
    def ground_rgb(self, x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        """Ground texture ``(N, 3)`` at points ``(N,)``: land-cover patches, roads, multi-octave noise, targets."""
        s = self.seed
        cover = value_noise(x, y, self.texture_coarse_m, s + 11)
        detail = np.zeros_like(x)
        amp, tot = 1.0, 0.0
        # at most 7 octaves, ending at the finest scale (coarser structure comes from the cover / hue fields)
        n_oct = int(min(7, max(1, np.floor(np.log2(self.texture_coarse_m / 2.0 / self.texture_fine_m)) + 1)))
        scale = self.texture_fine_m * 2.0 ** (n_oct - 1)
        k = 0
        while k < n_oct:
            detail += amp * value_noise(x, y, scale, s + 100 + k)
            tot += amp
            amp *= 0.72
            scale /= 2.0
            k += 1
        detail = detail / max(tot, 1e-9)
        sharp = value_noise(x, y, max(self.texture_fine_m * 3.0, 0.01), s + 7)  # speckle at the finest scale
        hue = value_noise(x, y, self.texture_coarse_m * 0.7, s + 23)
        # fields (base) and bare soil, channel by channel (no (N, 3) temporaries)
        base = (0.30 + 0.25 * hue, 0.42 + 0.12 * cover, 0.20 + 0.15 * (1 - hue))
        soil = (0.55 + 0.1 * hue, 0.45 + 0.05 * cover, 0.32 + 0.05 * hue)
        m = cover > 0.55
        fa = 0.55 + 0.9 * (detail - 0.5) + 0.5
        fb = 0.85 + 0.3 * sharp
        # roads: a grid of 6 m wide asphalt bands every 60 m (turned by 10 deg), with noise
        ca, sa = np.cos(0.17), np.sin(0.17)
        u, v = ca * x + sa * y, -sa * x + ca * y
        road = (np.abs(((u + 30.0) % 60.0) - 30.0) < 3.0) | (np.abs(((v + 30.0) % 60.0) - 30.0) < 3.0)
        asphalt = 0.30 + 0.25 * detail + 0.1 * sharp
        rgb = np.empty(np.shape(x) + (3,))
        for j in range(3):
            rgb[..., j] = np.where(road, asphalt, np.where(m, soil[j], base[j]) * fa * fb)
        if self.targets is not None:
            rgb = self._paint_targets(x, y, rgb)
        return np.clip(rgb, 0.0, 1.0, out=rgb)

    def target_intensity(self, x: NDArray[np.float64], y: NDArray[np.float64], k: int) -> tuple[NDArray, NDArray]:
        """Coverage ``(N,)`` in [0, 1] of target ``k``'s black square and white disc at ground points."""
        t = self.targets
        assert t is not None
        r = t.radius_m
        dx, dy = x - t.xyz[k, 0], y - t.xyz[k, 1]
        w = max(0.5 * r, 1e-3)  # anti-aliasing ramp (symmetric: keeps the centroid unbiased)
        ramp = lambda d: np.clip(d / w + 0.5, 0.0, 1.0)  # noqa: E731  coverage at signed distance d inside an edge
        sq = ramp(t.half_side_m - np.maximum(np.abs(dx), np.abs(dy)))
        if t.kind == "chequer":
            return sq, ramp(dx) * ramp(dy) + (1.0 - ramp(dx)) * (1.0 - ramp(dy))
        if t.kind == "aruco":
            return sq, _marker_coverage(int(t.codes[k]), (dx + 2.0 * r) / (4.0 * r / 6.0), (2.0 * r - dy) / (4.0 * r / 6.0))
        rho = np.hypot(dx, dy)
        disc = ramp(r - rho)
        if t.kind == "disc":
            return sq, disc
        n = int(t.code_bits)
        step = 2.0 * np.pi / n
        phi = np.mod(np.arctan2(dy, dx), 2.0 * np.pi)
        j = np.floor(phi / step + 0.5)  # the sector boundary nearest (at angle j step)
        bit = lambda i: ((int(t.codes[k]) >> np.mod(i, n).astype(np.int64)) & 1).astype(np.float64)  # noqa: E731
        # signed distance from the boundary's ray, positive into the sector counter-clockwise of it
        d = -np.sin(j * step) * dx + np.cos(j * step) * dy
        code = bit(j) * ramp(d) + bit(j - 1) * (1.0 - ramp(d))
        ring = ramp(rho - 2.0 * r) * ramp(3.0 * r - rho)
        return sq, np.maximum(disc, ring * code)

    def _paint_targets(self, x: NDArray, y: NDArray, rgb: NDArray) -> NDArray:
        t = self.targets
        assert t is not None
        reach = t.half_side_m * 1.5 + 1.0
        for k in range(len(t.name)):
            near = (np.abs(x - t.xyz[k, 0]) < reach) & (np.abs(y - t.xyz[k, 1]) < reach)
            if not np.any(near):
                continue
            sq, disc = self.target_intensity(x[near], y[near], k)
            val = 0.05 + 0.9 * disc
            rgb[near] = rgb[near] * (1 - sq[:, None]) + (sq * val)[:, None]
        return rgb

    def facade_rgb(self, building: NDArray[np.int64], u: NDArray[np.float64], z: NDArray[np.float64],
                   face: NDArray[np.int64]) -> NDArray[np.float64]:
        """Façade texture rule ``(N, 3)``: wall colour of the building, windows on a grid, hashed noise.

        ``u`` is the horizontal coordinate along the wall, ``z`` the height, ``face`` the wall index 0-3.
        """
        s = self.seed
        b = building.astype(np.int64)
        col = np.stack([_hash2(b, np.full_like(b, c), s + 31) for c in range(3)], axis=-1)
        wall = 0.45 + 0.4 * col
        sp = self.window_spacing_m
        zb = self.buildings.base_z[b]
        gu = (u % sp) / sp
        gz = ((z - zb - 0.8) % sp) / sp
        win = (gu > 0.3) & (gu < 0.7) & (gz > 0.35) & (gz < 0.8) & (z - zb > 1.5)
        noise = value_noise(u + 1000.0 * face, z + 1000.0 * b, 0.25, s + 41)
        fine = value_noise(u + 37.0 * face, z + 53.0 * b, 0.06, s + 43)
        rgb = wall * (0.8 + 0.3 * noise[:, None] + 0.15 * fine[:, None])
        glass = (0.12 + 0.25 * noise)[:, None] * np.array([0.8, 0.9, 1.0])
        return np.clip(np.where(win[:, None], glass, rgb), 0.0, 1.0)

    def roof_rgb(self, building: NDArray[np.int64], x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        """Roof texture ``(N, 3)``: per-building tile colour with noise."""
        s = self.seed
        b = building.astype(np.int64)
        col = np.stack([_hash2(b, np.full_like(b, c + 5), s + 61) for c in range(3)], axis=-1)
        roof = np.where((_hash2(b, b, s + 62) > 0.5)[:, None], np.array([0.55, 0.22, 0.15]), np.array([0.35, 0.35, 0.38]))
        roof = roof * (0.7 + 0.5 * col)
        n = value_noise(x, y, 0.5, s + 63) * 0.6 + value_noise(x, y, 0.12, s + 64) * 0.4
        return np.clip(roof * (0.75 + 0.5 * n[:, None]), 0.0, 1.0)


def make_scene(
    seed: int,
    extent: tuple[float, float, float, float],
    origin: tuple[float, float, float] = (52.3759, 9.7320, 0.0),
    base_height_m: float = 80.0,
    relief_m: float = 6.0,
    town: tuple[float, float, float, float] | None = None,
    n_buildings: int = 20,
    building_size_m: tuple[float, float] = (8.0, 25.0),
    texture_fine_m: float = 0.05,
    targets: tuple[ArrayLike, ArrayLike] | None = None,
    target_radius_m: float = 0.5,
    stockpiles: ArrayLike | None = None,
    target_codes: ArrayLike | None = None,
    code_bits: int = 12,
    target_kind: str | None = None,
) -> Scene:
    """A seeded scene: gentle terrain of total relief ``relief_m``, ``n_buildings`` houses in ``town``.

    Parameters
    ----------
    seed
        Random seed (the scene is a deterministic function of all arguments).
    extent
        ``(xmin, ymin, xmax, ymax)`` metres in the local frame.
    origin
        ``(lat, lon, h)`` of the local frame (default: Hannover).
    town
        Rectangle of the town; default the middle half of ``extent``.
    building_size_m
        Range of footprint side lengths.
    targets
        ``(names (K,), xy (K, 2))`` of signalised targets; their heights are put on the terrain; buildings
        are kept ``3 radius + 3 m`` away from them (coded targets: ``4 sqrt(2) radius + 3 m``).
    stockpiles
        Rows ``(cx, cy, R, r, h)`` of :class:`Stockpiles` standing on the terrain; buildings are kept 3 m away from
        their toes.  None (the default) leaves every other output of the scene unchanged.
    target_codes, code_bits, target_kind
        The targets' kind (:class:`Target`; default ``"coded"`` with ``target_codes``, else ``"disc"``) and ``(K,)``
        codes (ring codes of ``code_bits`` bits for ``"coded"``, marker ids for ``"aruco"``).
    """
    rng = np.random.default_rng(seed)
    xmin, ymin, xmax, ymax = extent
    if not (xmax > xmin and ymax > ymin):
        raise SkyrigError(f"scene extent {extent} is empty")
    k = 4
    wl = rng.uniform(150.0, 600.0, k)
    ang = rng.uniform(0, 2 * np.pi, k)
    amp = rng.uniform(0.5, 1.0, k)
    amp = amp / amp.sum() * relief_m / 2.0
    kx, ky = 2 * np.pi / wl * np.cos(ang), 2 * np.pi / wl * np.sin(ang)
    phase = rng.uniform(0, 2 * np.pi, k)
    piles = None if stockpiles is None else Stockpiles.of(stockpiles)
    proto = Scene(origin, extent, seed, base_height_m, amp, kx, ky, phase,
                  Buildings(*(np.zeros(0) for _ in range(8))), texture_fine_m=texture_fine_m, stockpiles=piles)
    if town is None:
        w, h = xmax - xmin, ymax - ymin
        town = (xmin + w / 4, ymin + h / 4, xmax - w / 4, ymax - h / 4)
    tx0, ty0, tx1, ty1 = town
    tg_xy = None if targets is None else np.asarray(targets[1], dtype=np.float64).reshape(-1, 2)
    # buildings kept 3 radii + 3 m from a target; a coded target's square (half side 4 r) by its half diagonal + 3 m
    clear_m = (3.0 if target_codes is None or target_kind not in (None, "coded") else 4.0 * np.sqrt(2.0)) \
        * target_radius_m + 3.0
    lo, hi = building_size_m
    b: dict[str, list[float]] = {k_: [] for k_ in ("cx", "cy", "hl", "hw", "az", "base", "eave", "ridge")}
    tries = 0
    while len(b["cx"]) < n_buildings and tries < 50 * max(n_buildings, 1):
        tries += 1
        L, W = rng.uniform(lo, hi), rng.uniform(lo, hi)
        L, W = max(L, W), min(L, W)
        cx, cy = rng.uniform(tx0, tx1), rng.uniform(ty0, ty1)
        az = 0.17 + rng.choice([0.0, np.pi / 2]) + rng.normal(0, 0.03)
        rad = 0.5 * np.hypot(L, W)
        if any(np.hypot(cx - ox, cy - oy) < rad + orad + 3.0 for ox, oy, orad in
               zip(b["cx"], b["cy"], [0.5 * np.hypot(2 * a, 2 * c) for a, c in zip(b["hl"], b["hw"])])):
            continue
        if tg_xy is not None and len(tg_xy) and np.min(np.hypot(tg_xy[:, 0] - cx, tg_xy[:, 1] - cy)) < rad + clear_m:
            continue
        if piles is not None and np.any(np.hypot(piles.cx - cx, piles.cy - cy) < rad + piles.radius_m + 3.0):
            continue
        corners_x = cx + np.array([-1, 1, 1, -1]) * rad
        corners_y = cy + np.array([-1, -1, 1, 1]) * rad
        tz = proto.terrain_height(corners_x, corners_y)
        ground = float(proto.terrain_height(cx, cy))
        eave = ground + rng.uniform(4.0, 14.0)
        gabled = rng.uniform() < 0.55
        ridge = eave + (rng.uniform(0.35, 0.7) * W / 2 if gabled else 0.0)
        for key, val in (("cx", cx), ("cy", cy), ("hl", L / 2), ("hw", W / 2), ("az", az),
                         ("base", float(tz.min()) - 2.0), ("eave", eave), ("ridge", ridge)):
            b[key].append(val)
    bld = Buildings(*(np.array(b[k_], dtype=np.float64) for k_ in ("cx", "cy", "hl", "hw", "az", "base", "eave", "ridge")))
    tgt = None
    if targets is not None:
        names = np.asarray(targets[0], dtype=str).reshape(-1)
        z = proto.terrain_height(tg_xy[:, 0], tg_xy[:, 1])
        codes = None if target_codes is None else np.asarray(target_codes, dtype=np.int64).reshape(-1)
        kind = target_kind or ("disc" if codes is None else "coded")
        if kind not in TARGET_KINDS:
            raise SkyrigError(f"target_kind {kind!r} is none of {', '.join(TARGET_KINDS)}")
        limit = {"coded": 2**code_bits, "aruco": 250}.get(kind)
        if limit is not None and (codes is None or len(codes) != len(names) or np.any(codes < 0) or np.any(codes >= limit)):
            raise SkyrigError(f"target_codes: {len(names)} codes in [0, {limit}) expected for {kind} targets")
        tgt = Target(names, np.column_stack([tg_xy, z]), float(target_radius_m), codes, int(code_bits), kind)
    return Scene(origin, extent, seed, base_height_m, amp, kx, ky, phase, bld, tgt, texture_fine_m=texture_fine_m,
                 texture_coarse_m=40.0, stockpiles=piles)


def grid_transform(extent: tuple[float, float, float, float], cell_m: float) -> tuple[tuple[float, ...], int, int]:
    """GDAL affine ``(a, b, c, d, e, f)`` (north-up) and ``(rows, cols)`` of a grid covering ``extent``."""
    xmin, ymin, xmax, ymax = extent
    cols = int(np.ceil((xmax - xmin) / cell_m))
    rows = int(np.ceil((ymax - ymin) / cell_m))
    return (cell_m, 0.0, xmin, 0.0, -cell_m, ymin + rows * cell_m), rows, cols


def _cell_centres(extent: tuple[float, float, float, float], cell_m: float) -> tuple[NDArray, NDArray, tuple]:
    tr, rows, cols = grid_transform(extent, cell_m)
    x = tr[2] + (np.arange(cols) + 0.5) * cell_m
    y = tr[5] - (np.arange(rows) + 0.5) * cell_m
    return np.meshgrid(x, y), tr  # type: ignore[return-value]


def rasterize_dsm(scene: Scene, cell_m: float) -> tuple[NDArray[np.float64], tuple[float, ...]]:
    """DSM ``(rows, cols)`` (surface heights at cell centres, local frame metres) and its affine transform."""
    (xx, yy), tr = _cell_centres(scene.extent, cell_m)
    return scene.surface_height(xx, yy), tr


def rasterize_orthophoto(scene: Scene, cell_m: float) -> tuple[NDArray[np.uint8], tuple[float, ...]]:
    """True orthophoto ``(rows, cols, 3)`` uint8 (ground or roof texture seen from above) and its transform."""
    (xx, yy), tr = _cell_centres(scene.extent, cell_m)
    x, y = xx.ravel(), yy.ravel()
    rgb = scene.ground_rgb(x, y)
    _, bidx = scene.buildings.top_height(x, y)
    on = bidx >= 0
    if np.any(on):
        rgb[on] = scene.roof_rgb(bidx[on], x[on], y[on])
    return (np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8).reshape(xx.shape + (3,)), tr


# ------------------------------------------------------------------------------------------ raster scenes
def _bilinear(grid: NDArray, x0: float, ytop: float, cell: float, x: NDArray[np.float64], y: NDArray[np.float64]
              ) -> tuple[NDArray, NDArray[np.float64], NDArray[np.float64], NDArray[np.intp], NDArray[np.intp]]:
    """Bilinear interpolation of a north-up grid of cell-centre values (clamped at the border).

    Returns the values and, for derivatives, the fractional offsets and the lower-left cell indices."""
    rows, cols = grid.shape[:2]
    u = np.clip((x - x0) / cell - 0.5, 0.0, cols - 1.000001)
    v = np.clip((ytop - y) / cell - 0.5, 0.0, rows - 1.000001)
    j = np.minimum(u.astype(np.intp), max(cols - 2, 0))
    i = np.minimum(v.astype(np.intp), max(rows - 2, 0))
    fu, fv = u - j, v - i
    j1 = np.minimum(j + 1, cols - 1)
    i1 = np.minimum(i + 1, rows - 1)
    if grid.ndim == 3:
        fu_, fv_ = fu[..., None], fv[..., None]
    else:
        fu_, fv_ = fu, fv
    top = grid[i, j] + (grid[i, j1] - grid[i, j]) * fu_
    bot = grid[i1, j] + (grid[i1, j1] - grid[i1, j]) * fu_
    return top + (bot - top) * fv_, fu, fv, i, j


@dataclass(frozen=True, eq=False)
class RasterScene(Scene):
    """A scene given by a DSM and an orthophoto on north-up grids of the local ENU frame (issue 3 item 2).

    The surface is the bilinear interpolation of the DSM's cell-centre heights (buildings included, as a
    2.5D surface: walls become steep faces one cell wide); its texture is the bilinearly interpolated
    orthophoto.  There are no separate buildings.  :func:`skyrig.simulate.render.cast_rays` marches along
    each ray in steps of half a DSM cell before refining the first crossing, so that the *first*
    intersection with a roof or wall is found.

    Attributes (besides :class:`Scene`'s)
    ----------
    dsm
        ``(R, C)`` heights (local frame, metres) at cell centres, row 0 the northernmost.
    dsm_x0, dsm_ytop, dsm_cell
        West edge, north edge and cell size of the DSM grid (metres).
    ortho
        ``(R', C', 3)`` colours in [0, 1] at cell centres.
    ortho_x0, ortho_ytop, ortho_cell
        Its grid.
    """

    dsm: NDArray[np.float64] | None = None
    dsm_x0: float = 0.0
    dsm_ytop: float = 0.0
    dsm_cell: float = 1.0
    ortho: NDArray[np.float32] | None = None
    ortho_x0: float = 0.0
    ortho_ytop: float = 0.0
    ortho_cell: float = 1.0

    @classmethod
    def from_grids(cls, origin: tuple[float, float, float], dsm: ArrayLike, dsm_x0: float, dsm_ytop: float,
                   dsm_cell: float, ortho: ArrayLike, ortho_x0: float, ortho_ytop: float, ortho_cell: float,
                   seed: int = 0, targets: "Target | None" = None) -> "RasterScene":
        """Build from grids; ``ortho`` may be uint8 (0-255) or float (0-1).

        Raises
        ------
        SkyrigError
            On non-finite DSM heights, wrong shapes or non-positive cells.
        """
        z = np.asarray(dsm, dtype=np.float64)
        o = np.asarray(ortho)
        o = o.astype(np.float32) / 255.0 if o.dtype == np.uint8 else o.astype(np.float32)
        if z.ndim != 2 or z.shape[0] < 2 or z.shape[1] < 2:
            raise SkyrigError(f"the DSM must be a 2-D grid of at least 2 x 2 cells, got {z.shape}")
        if not np.all(np.isfinite(z)):
            raise SkyrigError(f"the DSM has {int((~np.isfinite(z)).sum())} void (non-finite) cells: fill them first")
        if o.ndim != 3 or o.shape[2] != 3:
            raise SkyrigError(f"the orthophoto must be (rows, cols, 3), got {o.shape}")
        if dsm_cell <= 0 or ortho_cell <= 0:
            raise SkyrigError("cell sizes must be positive")
        extent = (dsm_x0, dsm_ytop - z.shape[0] * dsm_cell, dsm_x0 + z.shape[1] * dsm_cell, dsm_ytop)
        empty = np.zeros(0)
        return cls(tuple(map(float, origin)), extent, int(seed), float(z.mean()), empty, empty, empty, empty,
                   Buildings(empty, empty, empty, empty, empty, empty, empty, empty), targets,
                   dsm=z, dsm_x0=float(dsm_x0), dsm_ytop=float(dsm_ytop), dsm_cell=float(dsm_cell), ortho=o,
                   ortho_x0=float(ortho_x0), ortho_ytop=float(ortho_ytop), ortho_cell=float(ortho_cell))

    @property
    def march_step_m(self) -> float:
        """Horizontal step of the ray marching (half a DSM cell)."""
        return 0.5 * self.dsm_cell

    def terrain_height(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        return _bilinear(self.dsm, self.dsm_x0, self.dsm_ytop, self.dsm_cell, x, y)[0]

    def terrain_gradient(self, x: ArrayLike, y: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        g = self.dsm
        _, fu, fv, i, j = _bilinear(g, self.dsm_x0, self.dsm_ytop, self.dsm_cell, x, y)
        rows, cols = g.shape
        i1, j1 = np.minimum(i + 1, rows - 1), np.minimum(j + 1, cols - 1)
        dzdu = (g[i, j1] - g[i, j]) * (1 - fv) + (g[i1, j1] - g[i1, j]) * fv
        dzdv = (g[i1, j] - g[i, j]) * (1 - fu) + (g[i1, j1] - g[i, j1]) * fu
        return dzdu / self.dsm_cell, -dzdv / self.dsm_cell  # v grows southwards

    @property
    def terrain_range(self) -> tuple[float, float]:
        return float(self.dsm.min()), float(self.dsm.max())

    def surface_height(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        return self.terrain_height(x, y)

    def ground_rgb(self, x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        rgb = _bilinear(self.ortho, self.ortho_x0, self.ortho_ytop, self.ortho_cell, np.asarray(x, float),
                        np.asarray(y, float))[0].astype(np.float64)
        if self.targets is not None:
            rgb = self._paint_targets(np.asarray(x, float), np.asarray(y, float), rgb)
        return np.clip(rgb, 0.0, 1.0)
