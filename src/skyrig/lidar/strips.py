"""LiDAR strip adjustment: scanner calibration and per-strip trajectory corrections from planar patches.

Overlapping strips of one laser flight see the same planar surfaces (ground, walls, the underside of a deck,
pillar faces).  Each such *patch* is a plane ``n . (X - c) = d`` (unit normal ``n``, patch centre ``c``); every laser
point of the patch is an observation ``r = n . (X(theta) - c) - d`` of the unknowns ``theta`` through the
georeferencing model (paper 002 eqs. 1-4, :mod:`skyrig.lidar.georef`), written in a local tangent (ENU) frame::

    rho   = (rho_rec - range_offset) / (1 + range_scale)                       range correction
    x_s   = rho u_s                                                            u_s: unit beam, scanner frame
    x_b   = lever_nominal + dlever + B_nominal expmap(boresight) x_s           body frame
    X     = P(t) + dp_k + dv_k (t - t_k) + expmap(da_k + dw_k (t - t_k)) R(t) x_b

with ``P(t)``, ``R(t)`` the recorded trajectory (local frame) at the pulse's own time, strip ``k`` and its reference
epoch ``t_k`` (middle of the strip's pulse times).  Unknowns: the scanner's boresight (3, rotation vector in the
scanner frame, the convention of :meth:`~skyrig.lidar.georef.ScannerMount.corrected`), lever-arm correction (3, body
frame, m), range offset (m) and range scale (dimensionless, reported in ppm) -- the *calibration* -- and per strip a
position offset and drift (local ENU, m and m/s) and an attitude offset and drift (rotation vector in the local frame,
rad and rad/s); the planes are nuisance unknowns.  Optional *control*: points of a reference cloud (a terrestrial
scan) on the same patches, fixed, with their own noise.

**Stochastic model.**  A point's residual has the variance propagated from range noise (along the beam), deflection
angle noise (across the beam in the scan plane), white trajectory noise (position and attitude) and a surface
roughness; the roughness is where the beam met the rough surface, an error of the measured range of sigma
``roughness / |n . beam|`` (at the patch's starting plane; beams within ~6 deg of their plane keep a part across it).
The Jacobians are evaluated at the *adjusted observations* (Gauss-Helmert: each point moved onto its plane, along its
beam for the range's and the roughness's shares of the residual; :func:`plane_residuals` ``linearise="adjusted"``;
with the roughness's share across the plane the laser-only strips-ci adjustment kept a range-scale bias of +1.2 to
+1.7 %, 6-8 sigmas, from its grazing beams): with
the Jacobians at the recorded points, the noise along a slanted beam enters the plane's tilt, the boresight, range
scale and attitude columns correlated with the residual, a bias of ``O(sigma^2)`` per point that does not average
out while the formal sigmas shrink with the number of points (20 seeds of the strips-ci flight: range scale z mean
+1.1, range offset -0.8, calibration z std 1.23 at the recorded points; mean 0.04, std 1.08 at the adjusted ones); the per-strip trajectory corrections are weighted with the trajectory's stated accuracy (zero-mean
priors), the calibration with wide priors centred on the nominal values.  Covariances are ``sigma0^2 N^-1``
(a-posteriori) or ``N^-1`` (a-priori).

**Determinability** (the rule of :mod:`skyrig.adjust.determinability`): a calibration parameter is determined when its
formal sigma is at most ``ratio_max`` x its prior sigma and its prior test ``|z| <= z_max``; otherwise it is held at its
prior (the adjustment is repeated without it) and the result says so in words with the geometry that would determine
it.  With per-strip attitude offsets free, a boresight is determined only by strips flown in different headings, a
lever arm only against the per-strip position offsets' accuracy: the rule says when a flight does not suffice.

**Memory** is bounded by the number of planes: patches are found from per-cell moments (counts, sums and second
moments per cell and strip, accumulated in chunks), and each patch keeps at most ``max_points_per_strip`` points per
strip (drawn at random) and the control points' moments only.  Each Gauss-Newton step reduces every patch to its
normal-equation blocks and eliminates the patch's plane at once (Schur complement): the reduced system has
``8 + 12 K`` unknowns for ``K`` strips whatever the number of points.

The residual and Jacobian functions (:func:`plane_residuals`) are written so that an ``adjust/factors`` module of a
joint laser-and-image adjustment can call them as they are.

Layer 2b: arrays in, arrays and dataclasses out.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from skyrig.adjust.determinability import (
    CONTRADICTS_PRIOR,
    DETERMINED,
    NOT_DETERMINABLE,
    OVERRULES_PRIOR,
    rule_words,
)
from skyrig.adjust.factors.lidar import control_gram, plane_basis, roughness_variances
from skyrig.errors import GeometryError, InputFormatError
from skyrig.georef.eo import WorldFrame
from skyrig.geometry.rotations import matrix_from_rotvec
from skyrig.lidar.georef import PulseGeoreferencer, ScannerMount
from skyrig.lidar.scanner import RawScan
from skyrig.trajectory.trajectory import Trajectory

logger = logging.getLogger(__name__)

__all__ = [
    "CALIBRATION_NAMES",
    "PatchOptions",
    "PlanarPatches",
    "StripModel",
    "StripAdjustmentResult",
    "adjust_line_offsets",
    "adjust_strips",
    "LineOffsetResult",
    "apply_strip_corrections",
    "find_planar_patches",
    "patch_discrepancies",
    "plane_residuals",
    "prepare_observations",
    "strip_parameter_names",
]

#: The calibration unknowns in order (rad, rad, rad, m, m, m, m, dimensionless).
CALIBRATION_NAMES = ("boresight_x", "boresight_y", "boresight_z", "lever_x", "lever_y", "lever_z", "range_offset",
                     "range_scale")
_STRIP_PARTS = ("dp_e", "dp_n", "dp_u", "dv_e", "dv_n", "dv_u", "da_e", "da_n", "da_u", "dw_e", "dw_n", "dw_u")
N_CAL = len(CALIBRATION_NAMES)
N_STRIP = len(_STRIP_PARTS)

_REMEDY = {
    "boresight": ("a boresight trades with the per-strip attitude offsets unless strips are flown in opposite (and "
                  "crossing) headings over surfaces of different orientations; tighter attitude accuracy or control "
                  "planes help"),
    "lever": ("a lever arm trades with the per-strip position offsets: fly strips in opposite headings, add control "
              "planes (a reference scan) or state a tighter trajectory position accuracy"),
    "range_offset": "a range offset needs surfaces seen from different directions (ground, walls and ceilings)",
    "range_scale": "a range scale needs the same surfaces at different ranges (strips at different distances)",
}


def strip_parameter_names(n_strips: int) -> tuple[str, ...]:
    """Names of all unknowns: the calibration, then ``strip<k>.<part>`` per strip."""
    return CALIBRATION_NAMES + tuple(f"strip{k}.{p}" for k in range(n_strips) for p in _STRIP_PARTS)


# ---------------------------------------------------------------------------------------------- configuration
@dataclass(frozen=True)
class StripModel:
    """The stochastic model and the priors of a strip adjustment (SI units; rotations in radians)."""

    range_sigma_m: float = 0.02  # range noise, one sigma
    scan_angle_sigma_rad: float = 0.0  # deflection-angle noise
    position_noise_m: float = 0.0  # white trajectory position noise (per axis)
    attitude_noise_rad: float = 0.0  # white trajectory attitude noise (per axis)
    roughness_m: float = 0.002  # surface roughness / non-planarity within a patch (also bounds the weight of grazing beams)
    control_sigma_m: float = 0.003  # noise of a control (reference cloud) point across its surface
    control_plane_sigma_m: float = 0.0  # common to a patch's control points (the reference's registration error)
    # priors of the calibration, centred on the nominal values
    boresight_sigma_rad: float = float(np.radians(1.0))
    lever_sigma_m: float = 0.10
    range_offset_sigma_m: float = 0.20
    range_scale_sigma: float = 5e-3
    # accuracy of the trajectory per strip (zero-mean priors of the corrections)
    strip_position_sigma_m: tuple[float, float, float] = (0.05, 0.05, 0.08)
    strip_position_drift_sigma_mps: tuple[float, float, float] = (0.001, 0.001, 0.001)
    strip_attitude_sigma_rad: tuple[float, float, float] = tuple(np.radians([0.03, 0.03, 0.08]))  # type: ignore[assignment]
    strip_attitude_drift_sigma_radps: tuple[float, float, float] = tuple(np.radians([3e-4, 3e-4, 8e-4]))  # type: ignore[assignment]

    def __post_init__(self) -> None:
        for name in ("range_sigma_m", "boresight_sigma_rad", "lever_sigma_m", "range_offset_sigma_m", "range_scale_sigma",
                     "control_sigma_m"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v > 0):
                raise InputFormatError(f"must be a positive number, got {v!r}", field=name)
        for name in ("scan_angle_sigma_rad", "position_noise_m", "attitude_noise_rad", "roughness_m",
                     "control_plane_sigma_m"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v >= 0):
                raise InputFormatError(f"must be a number >= 0, got {v!r}", field=name)
        for name in ("strip_position_sigma_m", "strip_position_drift_sigma_mps", "strip_attitude_sigma_rad",
                     "strip_attitude_drift_sigma_radps"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (3,) or not np.all(np.isfinite(v)) or np.any(v <= 0):
                raise InputFormatError(f"must be 3 positive numbers, got {v!r}", field=name)

    def prior_sigma(self, n_strips: int) -> NDArray[np.float64]:
        """``(8 + 12 K,)`` prior sigmas of all unknowns."""
        cal = [self.boresight_sigma_rad] * 3 + [self.lever_sigma_m] * 3 + [self.range_offset_sigma_m,
                                                                          self.range_scale_sigma]
        strip = np.concatenate([self.strip_position_sigma_m, self.strip_position_drift_sigma_mps,
                                self.strip_attitude_sigma_rad, self.strip_attitude_drift_sigma_radps])
        return np.concatenate([cal, np.tile(strip, n_strips)])


@dataclass(frozen=True)
class PatchOptions:
    """How planar patches are found (metres)."""

    cell_m: float = 1.0  # patch cells: cubes of this size
    min_points_per_strip: int = 30  # a strip takes part in a patch with at least this many points in the cell
    max_points_per_strip: int = 48  # points kept per strip and patch (at random)
    min_strips: int = 2  # strips that must see a patch
    max_strip_thickness_m: float = 0.05  # one strip's points: RMS distance from their own plane
    max_thickness_m: float = 0.30  # all strips together before adjustment (strip misalignment included)
    max_control_thickness_m: float = 0.02  # control points of a patch: RMS distance from their own plane
    min_extent_m: float = 0.15  # second-smallest spread: no lines
    max_normal_angle_deg: float = 10.0  # strips' own normals vs the patch normal
    max_patches: int = 4000  # at most this many (spread over the patch orientations)
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.cell_m > 0:
            raise InputFormatError(f"must be positive, got {self.cell_m!r}", field="cell_m")
        if self.min_strips < 1 or self.max_points_per_strip < 4 or self.min_points_per_strip < 4:
            raise InputFormatError("min_strips >= 1, min/max_points_per_strip >= 4", field="patch options")


# ---------------------------------------------------------------------------------------------- observations
@dataclass(frozen=True, eq=False)
class PlanarPatches:
    """Laser points on planar patches, reduced to what the adjustment needs (all in one local ENU frame).

    Attributes
    ----------
    frame
        The local frame of every coordinate here.
    centre, normal
        ``(P, 3)`` patch centres and starting unit normals.
    plane, strip
        ``(M,)`` patch and strip index of each kept point.
    dt_s
        ``(M,)`` pulse time minus its strip's reference epoch.
    range_m, beam_s, dbeam_s
        ``(M,)`` recorded ranges, ``(M, 3)`` unit beam directions in the scanner frame and their derivatives with
        respect to the deflection angle alpha.
    position, rotation
        ``(M, 3)`` recorded trajectory positions and ``(M, 3, 3)`` ``local_from_body`` at the pulse times.
    strip_epoch_s
        ``(K,)`` reference epochs of the strips (seconds, the scan's time system).
    strip_ids
        ``(K,)`` the strip ids of the input (index ``k`` here is ``strip_ids[k]`` there).
    control_count, control_sum, control_sum2
        Control points per patch: ``(P,)`` counts, ``(P, 3)`` sums and ``(P, 3, 3)`` second moments of ``y - c``.
    n_points_total
        Laser points of all strips that were searched.
    """

    frame: WorldFrame
    centre: NDArray[np.float64]
    normal: NDArray[np.float64]
    plane: NDArray[np.intp]
    strip: NDArray[np.intp]
    dt_s: NDArray[np.float64]
    range_m: NDArray[np.float64]
    beam_s: NDArray[np.float64]
    dbeam_s: NDArray[np.float64]
    position: NDArray[np.float64]
    rotation: NDArray[np.float64]
    strip_epoch_s: NDArray[np.float64]
    strip_ids: NDArray[np.int64]
    control_count: NDArray[np.float64]
    control_sum: NDArray[np.float64]
    control_sum2: NDArray[np.float64]
    n_points_total: int = 0

    @property
    def n_planes(self) -> int:
        return int(self.centre.shape[0])

    @property
    def n_strips(self) -> int:
        return int(self.strip_epoch_s.shape[0])

    def __len__(self) -> int:
        return int(self.plane.shape[0])


def _cell_keys(xyz: NDArray[np.float64], cell: float) -> NDArray[np.int64]:
    ijk = np.floor(xyz / cell).astype(np.int64) + (1 << 20)
    if np.any(ijk < 0) or np.any(ijk >= (1 << 21)):
        raise GeometryError(f"points span more than {(1 << 21) * cell:.0f} m from the frame origin: use a nearer frame")
    return ijk[:, 0] | (ijk[:, 1] << 21) | (ijk[:, 2] << 42)


def _moments(key: NDArray[np.intp], xyz: NDArray[np.float64], n: int, ref: NDArray[np.float64]
             ) -> tuple[NDArray, NDArray, NDArray]:
    """Counts ``(n,)``, sums ``(n, 3)`` and second moments ``(n, 3, 3)`` of ``xyz - ref[key]`` per key."""
    y = xyz - ref[key]
    cnt = np.bincount(key, minlength=n).astype(float)
    s1 = np.column_stack([np.bincount(key, y[:, j], minlength=n) for j in range(3)])
    s2 = np.empty((n, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            s2[:, a, b] = s2[:, b, a] = np.bincount(key, y[:, a] * y[:, b], minlength=n)
    return cnt, s1, s2


def _scatter(cnt: NDArray, s1: NDArray, s2: NDArray) -> NDArray[np.float64]:
    c = np.maximum(cnt, 1.0)[:, None]
    m = s1 / c
    return s2 / c[:, :, None] - m[:, :, None] * m[:, None, :]


def prepare_observations(
    scan: RawScan,
    trajectory: Trajectory,
    mount: ScannerMount,
    frame: WorldFrame,
    *,
    position: str = "cubic",
    chunk: int = 1_000_000,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Nominal georeferencing of every pulse into the local ``frame``: ``(N, 3)`` points and ``(N,)`` strip ids.

    Raises
    ------
    InputFormatError
        If ``frame`` is not a local tangent frame, or the scan has no strip ids.
    OutOfRangeError
        A pulse outside the trajectory's time span (named).
    """
    if frame.kind != "local":
        raise InputFormatError(f"the strip adjustment works in a local tangent frame, not {frame.kind!r}", field="frame")
    if scan.strip_id is None:
        raise InputFormatError("the raw scan has no strip ids (column 'strip'): say which flight line each pulse "
                               "belongs to", field="strip")
    geo = PulseGeoreferencer(trajectory, mount, position)
    geo._locate(scan.time_s)  # names the first pulse outside the trajectory before any work
    xyz = np.empty((len(scan), 3))
    for a in range(0, len(scan), chunk):
        sub = scan.subset(slice(a, a + chunk))
        xyz[a:a + chunk] = frame.from_ecef(geo.ecef(sub.time_s, sub.sensor_xyz()))
    return xyz, scan.strip_id


def find_planar_patches(
    scan: RawScan,
    trajectory: Trajectory,
    mount: ScannerMount,
    frame: WorldFrame,
    *,
    options: PatchOptions = PatchOptions(),
    control: ArrayLike | None = None,
    xyz: NDArray[np.float64] | None = None,
    position: str = "cubic",
) -> PlanarPatches:
    """Planar patches seen by at least ``options.min_strips`` strips, with their laser points reduced.

    Parameters
    ----------
    scan
        Raw pulses with strip ids (pulses with a negative strip id are left out).
    trajectory, mount
        The recorded navigation and the nominal mount.
    frame
        A local tangent frame (:meth:`WorldFrame.local`) near the flight: every coordinate of the result.
    options
        Cells and thresholds.
    control
        ``(R, 3)`` control points (a reference scan) in ``frame``, or None.
    xyz
        The nominal georeferenced points ``(N, 3)`` if already computed (:func:`prepare_observations`).

    Raises
    ------
    GeometryError
        When no patch is seen by enough strips.
    """
    if xyz is None:
        xyz, sid = prepare_observations(scan, trajectory, mount, frame, position=position)
    else:
        if scan.strip_id is None:
            raise InputFormatError("the raw scan has no strip ids (column 'strip')", field="strip")
        sid = scan.strip_id
    use = np.flatnonzero(sid >= 0)
    ids, strip_of = np.unique(sid[use], return_inverse=True)
    k_strips = len(ids)
    if k_strips < 1:
        raise GeometryError("no pulse belongs to a strip (all strip ids are negative)")
    tt = scan.time_s[use]
    epochs = np.array([(tt[strip_of == k].min() + tt[strip_of == k].max()) / 2 for k in range(k_strips)])
    keys = _cell_keys(xyz[use], options.cell_m)
    cells, cell_of = np.unique(keys, return_inverse=True)
    n_cells = len(cells)
    cs = cell_of * k_strips + strip_of
    corner = (((cells[:, None] >> np.array([0, 21, 42])) & ((1 << 21) - 1)) - (1 << 20)) * options.cell_m
    ref = corner + options.cell_m / 2
    cnt, s1, s2 = _moments(cs, xyz[use], n_cells * k_strips, np.repeat(ref, k_strips, axis=0))
    cnt = cnt.reshape(n_cells, k_strips)
    s1 = s1.reshape(n_cells, k_strips, 3)
    s2 = s2.reshape(n_cells, k_strips, 3, 3)
    seen = cnt >= options.min_points_per_strip
    cand = np.flatnonzero(seen.sum(axis=1) >= options.min_strips)
    if cand.size == 0:
        raise GeometryError(f"no {options.cell_m:g} m cell is seen by {options.min_strips} strips with "
                            f"{options.min_points_per_strip} points each: do the strips overlap?")
    # per strip planes
    sc = seen[cand]
    w_k, v_k = np.linalg.eigh(_scatter(cnt[cand].reshape(-1), s1[cand].reshape(-1, 3), s2[cand].reshape(-1, 3, 3)))
    w_k = w_k.reshape(len(cand), k_strips, 3)
    n_k = v_k[:, :, 0].reshape(len(cand), k_strips, 3)
    # all seeing strips together
    m = sc.astype(float)
    tot_c = np.einsum("ck,ck->c", cnt[cand], m)
    tot_1 = np.einsum("cki,ck->ci", s1[cand], m)
    tot_2 = np.einsum("ckij,ck->cij", s2[cand], m)
    w, v = np.linalg.eigh(_scatter(tot_c, tot_1, tot_2))
    nrm = v[:, :, 0]
    ok = (np.sqrt(np.maximum(w[:, 0], 0)) <= options.max_thickness_m) & (np.sqrt(w[:, 1]) >= options.min_extent_m)
    thin = np.sqrt(np.maximum(w_k[:, :, 0], 0)) <= options.max_strip_thickness_m
    wide = np.sqrt(np.maximum(w_k[:, :, 1], 0)) >= options.min_extent_m
    cosang = np.abs(np.einsum("cki,ci->ck", n_k, nrm))
    agree = cosang >= np.cos(np.radians(options.max_normal_angle_deg))
    good_strip = sc & thin & wide & agree
    ok &= good_strip.sum(axis=1) >= options.min_strips
    sel = np.flatnonzero(ok)
    if sel.size == 0:
        raise GeometryError("no planar patch is seen by enough strips (all candidate cells failed the planarity tests)")
    rng = np.random.default_rng(options.seed)
    if sel.size > options.max_patches:  # keep a spread of orientations: sample evenly within orientation classes
        cls = np.argmax(np.abs(nrm[sel]), axis=1) * 2 + (nrm[sel][np.arange(sel.size), np.argmax(np.abs(nrm[sel]), axis=1)] > 0)
        keep = []
        per = max(1, options.max_patches // max(1, len(np.unique(cls))))
        for c in np.unique(cls):
            idx = sel[cls == c]
            keep.append(idx if idx.size <= per else rng.choice(idx, per, replace=False))
        sel = np.sort(np.concatenate(keep))
    n_pl = sel.size
    centre = ref[cand[sel]] + tot_1[sel] / tot_c[sel][:, None]
    normal = nrm[sel]
    strip_ok = good_strip[sel]  # (P, K)
    # gather points: a patch is the square of side cell_m about its centre in its plane, +- max_thickness_m across
    # (not the cell: a surface on a cell boundary would keep the points on one side of it only, a biased half);
    # each point goes to the nearest patch centre
    tree = cKDTree(centre)
    e1p, e2p = plane_basis(normal)
    half = 0.4 * options.cell_m  # inside the cell whose planarity was tested (its centroid +- 0.4 cell)

    def assign(pts: NDArray[np.float64], origin: NDArray[np.float64] | None = None) -> NDArray[np.intp]:
        """Patch of each point (-1: none).  With the beams' ``origin``, the square is tested where the beam meets
        the patch plane, not at the measured point: range noise moves a point along its beam, and selecting by the
        noisy position would keep a biased share of the noise where a patch's square meets the edge of a strip's
        coverage (a range-scale-like bias)."""
        out = np.full(len(pts), -1, dtype=np.intp)
        for a0 in range(0, len(pts), 1_000_000):
            q = pts[a0:a0 + 1_000_000]
            d, j = tree.query(q, distance_upper_bound=half * np.sqrt(2) + options.max_thickness_m)
            ok = np.isfinite(d)
            j = np.where(ok, j, 0)
            y = q - centre[j]
            nj = normal[j]
            ok &= np.abs(np.einsum("ij,ij->i", y, nj)) <= options.max_thickness_m
            if origin is not None:
                o = origin[a0:a0 + 1_000_000]
                beam = q - o
                den = np.einsum("ij,ij->i", beam, nj)
                good = np.abs(den) > 1e-9 * np.einsum("ij,ij->i", beam, beam)
                f = np.where(good, np.einsum("ij,ij->i", centre[j] - o, nj) / np.where(good, den, 1.0), 1.0)
                y = o + f[:, None] * beam - centre[j]
                ok &= good
            ok &= (np.abs(np.einsum("ij,ij->i", y, e1p[j])) <= half) & (np.abs(np.einsum("ij,ij->i", y, e2p[j])) <= half)
            out[a0:a0 + 1_000_000] = np.where(ok, j, -1)
        return out

    # the scanner's origin at every pulse (nominal mount), chunked through the georeferencing kernel
    geo0 = PulseGeoreferencer(trajectory, mount, position)
    t_use = scan.time_s[use]
    origin = np.empty((len(use), 3))
    for a0 in range(0, len(use), 1_000_000):
        tt_ = t_use[a0:a0 + 1_000_000]
        origin[a0:a0 + 1_000_000] = frame.from_ecef(geo0.ecef(tt_, np.zeros((len(tt_), 3))))
    pl = assign(xyz[use], origin)
    del origin
    rows = np.flatnonzero(pl >= 0)
    pl = pl[rows]
    st = strip_of[rows]
    okr = strip_ok[pl, st]
    rows, pl, st = rows[okr], pl[okr], st[okr]
    # points off their own strip's plane in the patch (another surface at an edge, a stray return) are left out:
    # each (patch, strip) plane is fitted twice, keeping the points within 4 robust sigmas (median absolute distance)
    # of the first fit, then within 4 RMS of the second; groups thicker than max_strip_thickness_m are dropped
    x_r = xyz[use[rows]]
    grp = pl * k_strips + st
    n_grp = n_pl * k_strips
    ref_g = np.repeat(centre, k_strips, axis=0)
    keep = np.ones(len(rows), bool)
    for robust in (True, False):
        g_cnt, g_s1, g_s2 = _moments(grp[keep], x_r[keep], n_grp, ref_g)
        g_w, g_v = np.linalg.eigh(_scatter(g_cnt, g_s1, g_s2))
        dist = np.abs(np.einsum("ij,ij->i", x_r - centre[pl] - g_s1[grp] / np.maximum(g_cnt[grp], 1.0)[:, None],
                                g_v[grp, :, 0]))
        if robust:
            o = np.lexsort((np.where(keep, dist, np.inf), grp))
            first = np.searchsorted(grp[o], np.arange(n_grp))
            med = dist[o[np.minimum(first + np.maximum(g_cnt.astype(np.intp) // 2, 0), len(o) - 1)]]
            sig_g = 1.4826 * med
        else:
            sig_g = np.sqrt(np.maximum(g_w[:, 0], 0.0))
        keep &= dist <= np.maximum(4.0 * sig_g[grp], 0.005)
    g_cnt, g_s1, g_s2 = _moments(grp[keep], x_r[keep], n_grp, ref_g)
    g_w = np.linalg.eigvalsh(_scatter(g_cnt, g_s1, g_s2))
    g_ok = (g_cnt >= options.min_points_per_strip / 2) & (np.sqrt(np.maximum(g_w[:, 0], 0.0)) <= options.max_strip_thickness_m)
    okr = keep & g_ok[grp]
    # patches left with fewer than min_strips strips go
    p_ok = g_ok.reshape(n_pl, k_strips).sum(axis=1) >= options.min_strips
    okr &= p_ok[pl]
    if not p_ok.any():
        raise GeometryError("no planar patch is seen by enough strips after leaving out points off their planes")
    new_index = np.cumsum(p_ok) - 1
    pl = np.where(p_ok[pl], new_index[pl], -1)
    centre, normal = centre[p_ok], normal[p_ok]
    e1p, e2p = e1p[p_ok], e2p[p_ok]
    tree = cKDTree(centre)
    n_pl = int(p_ok.sum())
    rows, pl, st = rows[okr], pl[okr], st[okr]
    grp = pl * k_strips + st
    order = np.lexsort((rng.random(len(grp)), grp))
    g_sorted = grp[order]
    first = np.searchsorted(g_sorted, g_sorted, side="left")
    rank = np.arange(len(g_sorted)) - first
    pick = order[rank < options.max_points_per_strip]
    pick = np.sort(pick)  # pulse order (times must not decrease in a scan)
    rows, pl, st = rows[pick], pl[pick], st[pick]
    src = use[rows]
    # fixed data of the kept pulses: trajectory pose in the local frame, beam direction
    sub = scan.subset(src)
    geo = PulseGeoreferencer(trajectory, mount, position)
    p_e, r_e = geo.poses(sub.time_s)
    lfe = frame.tangent.ecef_from_local.T
    pos = frame.from_ecef(p_e)
    rot = lfe @ r_e
    ca, sa = np.cos(sub.alpha_rad), np.sin(sub.alpha_rad)
    if sub.beta_rad is None:
        beam = np.column_stack([ca, sa, np.zeros_like(ca)])
    else:
        cb, sb = np.cos(sub.beta_rad), np.sin(sub.beta_rad)
        beam = np.column_stack([cb * ca, cb * sa, sb])
    dbeam = np.column_stack([-beam[:, 1], beam[:, 0], np.zeros_like(ca)])
    # control points: moments per patch of the reference points in the patch's cell near its plane
    c_cnt, c_s1, c_s2 = np.zeros(n_pl), np.zeros((n_pl, 3)), np.zeros((n_pl, 3, 3))
    if control is not None:
        y = np.asarray(control, dtype=np.float64).reshape(-1, 3)
        yp = assign(y)
        yy = y[yp >= 0]
        yp = yp[yp >= 0]
        c_cnt, c_s1, c_s2 = _moments(yp, yy, n_pl, centre)
        # a patch takes control only where the reference points of its cell are one plane along the laser's
        # (a cell at an edge may hold reference points of a face the strips did not see)
        wc, vc = np.linalg.eigh(_scatter(c_cnt, c_s1, c_s2))
        flat = ((c_cnt >= 3) & (np.sqrt(np.maximum(wc[:, 0], 0)) <= options.max_control_thickness_m)
                & (np.abs(np.einsum("ij,ij->i", vc[:, :, 0], normal)) >= np.cos(np.radians(options.max_normal_angle_deg))))
        c_cnt, c_s1, c_s2 = c_cnt * flat, c_s1 * flat[:, None], c_s2 * flat[:, None, None]
    logger.info("strip patches: %d planes (%d with control), %d of %d laser points kept, %d strips", n_pl,
                int(np.sum(c_cnt >= 3)), len(src), len(use), k_strips)
    return PlanarPatches(frame, centre, normal, pl, st, sub.time_s - epochs[st], sub.range_m, beam, dbeam, pos, rot,
                         epochs, ids.astype(np.int64), c_cnt, c_s1, c_s2, len(use))


# ---------------------------------------------------------------------------------------------- residuals
def plane_residuals(
    patches: PlanarPatches,
    mount: ScannerMount,
    calibration: NDArray[np.float64],
    strips: NDArray[np.float64],
    normal: NDArray[np.float64],
    offset: NDArray[np.float64],
    model: StripModel,
    rows: NDArray[np.intp] | slice = slice(None),
    linearise: str = "observed",
) -> dict[str, NDArray[np.float64]]:
    """Point-to-plane residuals of laser points, their Jacobians and sigmas.

    Parameters
    ----------
    patches
        The observations.
    mount
        The nominal mount (``body_from_scanner``, ``lever_arm_m``).
    calibration
        ``(8,)`` current calibration (:data:`CALIBRATION_NAMES`).
    strips
        ``(K, 12)`` current strip corrections (dp, dv, da, dw; local ENU).
    normal, offset
        ``(P, 3)`` unit normals and ``(P,)`` plane offsets ``d`` (plane: ``n . (X - c) = d``).
    model
        The stochastic model.
    rows
        Subset of the points.
    linearise
        Where the Jacobians are evaluated: ``"observed"`` -- at the recorded range and angle (the exact derivatives
        of ``r``, what a finite difference gives); ``"adjusted"`` -- at the *adjusted observations* of the
        Gauss-Helmert model: the range, deflection angle, trajectory pose and surface each corrected by its share
        of the residual (share ``sigma_l^2 B_l / sigma^2``, ``B_l = dr/dl``), which puts the point on the plane.
        The noise of a laser point lies along its beam, not along the normal, so the recorded point's noise enters
        the Jacobians (the plane's tilt ``e . y``, the boresight's ``x_s``, the range scale's ``rho``, the
        attitude's ``w``) correlated with the residual: least squares with Jacobians at the observations is then
        biased by ``O(sigma^2)`` per point, a bias that does not shrink with the number of points while the
        formal sigmas do (errors-in-variables).  At the adjusted observations the normal equations are those of
        the maximum-likelihood (total least squares) solution, without that bias.

    Returns
    -------
    dict
        ``r`` ``(m,)`` residuals (m); ``J_cal`` ``(m, 8)``; ``J_strip`` ``(m, 12)`` (the point's own strip);
        ``J_plane`` ``(m, 3)`` (two tangent rotations of the normal along ``e1``, ``e2``, and ``d``); ``e1``, ``e2``
        ``(m, 3)``; ``sigma`` ``(m,)``; ``X`` ``(m, 3)`` the georeferenced points.
    """
    if linearise not in ("observed", "adjusted"):
        raise InputFormatError(f"linearise must be 'observed' or 'adjusted', not {linearise!r}", field="linearise")
    pl = patches.plane[rows]
    st = patches.strip[rows]
    dt = patches.dt_s[rows]
    rho_rec = patches.range_m[rows]
    u_s = patches.beam_s[rows]
    du_s = patches.dbeam_s[rows]
    b_cur = mount.body_from_scanner @ matrix_from_rotvec(calibration[0:3])
    lever = mount.lever_arm_m + calibration[3:6]
    r0, scale = calibration[6], calibration[7]
    sc = strips[st]
    rot_corr = matrix_from_rotvec(sc[:, 6:9] + dt[:, None] * sc[:, 9:12])
    r_full = rot_corr @ patches.rotation[rows]  # (m, 3, 3) corrected local_from_body
    p_full = patches.position[rows] + sc[:, 0:3] + dt[:, None] * sc[:, 3:6]
    n = normal[pl]
    n_b = np.einsum("nji,nj->ni", r_full, n)  # normal in the body frame
    n_s = n_b @ b_cur  # ... in the scanner frame
    g_s = np.einsum("ij,ij->i", n_s, u_s)  # n . beam (world)
    g_a = np.einsum("ij,ij->i", n_s, du_s)  # n . d beam / d alpha

    def georef(rho_obs: NDArray, u: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        rho_ = (rho_obs - r0) / (1.0 + scale)
        x_s_ = rho_[:, None] * u
        w_ = np.einsum("nij,nj->ni", r_full, x_s_ @ b_cur.T + lever)
        return rho_, x_s_, w_, p_full + w_

    rho, x_s, w, X_obs = georef(rho_rec, u_s)
    y = X_obs - patches.centre[pl]
    r = np.einsum("ij,ij->i", n, y) - offset[pl]
    wxn = np.cross(w, n)
    # variance: range along the beam, angle across it, trajectory noise, roughness (each sigma_l^2 B_l^2).  The
    # roughness is where the beam met the surface, off the plane: an error of the measured range, sigma roughness /
    # |B0| (B0 = n . beam at the patch's starting plane and the nominal mount and pose: a constant of the point, as
    # every observation's sigma); beams within ~6 deg of their plane (|B0| < 0.1) keep the rest of it across the
    # plane.  (With the roughness across the plane and the range left as measured, the range's deviation stays in
    # the range-scale, plane-tilt and boresight columns correlated with the residual -- an errors-in-variables bias
    # where the floor is most of a beam's variance, at grazing beams: strips-ci laser-only range scale +0.0127
    # (+6 sigma) on seeds 3 and 5.)  The split is :func:`skyrig.adjust.factors.lidar.roughness_variances`, the joint
    # laser factor's own.
    n_s0 = np.einsum("nji,nj->ni", patches.rotation[rows], patches.normal[pl]) @ mount.body_from_scanner
    rough_rng, rough_nrm = roughness_variances(model.roughness_m, np.einsum("ij,ij->i", n_s0, u_s))
    s2_rng = model.range_sigma_m ** 2 + rough_rng  # range noise and roughness, along the beam
    b_r = g_s / (1.0 + scale)  # d r / d recorded range
    v_rng = s2_rng * b_r ** 2
    v_ang = (model.scan_angle_sigma_rad * rho * g_a) ** 2
    v_att = model.attitude_noise_rad ** 2 * np.einsum("ij,ij->i", wxn, wxn)
    v_normal = model.position_noise_m ** 2 + rough_nrm
    var = v_rng + v_ang + v_att + v_normal
    if linearise == "adjusted":
        # adjusted observations: each error source takes its share of the residual (sigma_l^2 B_l / var); the
        # corrected point lies on the plane; the Jacobians below are evaluated there
        f = r / var
        rho_hat = rho_rec - f * s2_rng * b_r
        u_hat = u_s - (f * model.scan_angle_sigma_rad ** 2 * rho * g_a)[:, None] * du_s
        rho, x_s, w, X = georef(rho_hat, u_hat)
        X = X - (f * v_normal)[:, None] * n - np.cross((f * model.attitude_noise_rad ** 2)[:, None] * wxn, w)
        y = X - patches.centre[pl]
        wxn = np.cross(w, n)
        rho_rec = rho_hat
    J_cal = np.empty((len(r), N_CAL))
    J_cal[:, 0:3] = np.cross(x_s, n_s)
    J_cal[:, 3:6] = n_b
    g_j = g_s if linearise == "observed" else np.einsum("ij,ij->i", n_s, x_s) / np.where(rho != 0, rho, 1.0)
    J_cal[:, 6] = -g_j / (1.0 + scale)
    J_cal[:, 7] = -g_j * (rho_rec - r0) / (1.0 + scale) ** 2
    J_strip = np.empty((len(r), N_STRIP))
    J_strip[:, 0:3] = n
    J_strip[:, 3:6] = dt[:, None] * n
    J_strip[:, 6:9] = wxn
    J_strip[:, 9:12] = dt[:, None] * wxn
    e1, e2 = plane_basis(n)  # tangent basis of each normal
    J_plane = np.column_stack([np.einsum("ij,ij->i", e1, y), np.einsum("ij,ij->i", e2, y), -np.ones(len(r))])
    return {"r": r, "J_cal": J_cal, "J_strip": J_strip, "J_plane": J_plane, "e1": e1, "e2": e2,
            "sigma": np.sqrt(var), "X": X_obs}


def _control_blocks(p: PlanarPatches, normal: NDArray, offset: NDArray, model: StripModel
                    ) -> tuple[NDArray, NDArray, NDArray]:
    """Normal-equation blocks ``(P, 3, 3)``, right-hand sides ``(P, 3)`` and weighted squared residual sums ``(P,)``
    of the control points (from their moments; residual ``r = n . (y - c) - d``, derivatives ``[e1 . y, e2 . y,
    -1]``: :func:`skyrig.adjust.factors.lidar.control_gram`, the joint factor's own)."""
    G = control_gram(p.control_count, p.control_sum, p.control_sum2, p.centre, normal, p.centre, offset,
                     model.control_sigma_m, model.control_plane_sigma_m)
    return G[:, :3, :3], -G[:, :3, 3], G[:, 3, 3]


# ---------------------------------------------------------------------------------------------- result
@dataclass(frozen=True, eq=False)
class CalibrationVerdict:
    """Determinability of one calibration parameter (units of :data:`CALIBRATION_NAMES`)."""

    name: str
    prior: float
    prior_sigma: float
    estimate: float
    sigma: float
    formal_sigma: float
    ratio: float
    z_prior: float
    verdict: str
    held: bool
    correlations: dict[str, float] = field(default_factory=dict)

    def words(self) -> str:
        base = (f"{self.name}: estimate {self.estimate:.6g} +- {self.sigma:.2g}, prior {self.prior:.6g} +- "
                f"{self.prior_sigma:.2g} (formal sigma {self.ratio:.2f} x the prior's, prior test z = {self.z_prior:+.1f})")
        if self.verdict == DETERMINED:
            return base + ": determined by the strips"
        if self.verdict == OVERRULES_PRIOR:
            return base + ": overrules its prior (determined several times better than the prior, which it contradicts)"
        key = "boresight" if self.name.startswith("boresight") else "lever" if self.name.startswith("lever") else self.name
        return base + f": {self.verdict}; held at its prior. {_REMEDY[key][:1].upper() + _REMEDY[key][1:]}"


@dataclass(frozen=True, eq=False)
class StripAdjustmentResult:
    """A strip adjustment.

    Attributes
    ----------
    names
        All unknowns (:func:`strip_parameter_names`).
    value, sigma
        ``(u,)`` estimates and standard deviations (zero sigma: held).
    covariance, correlation
        ``(u, u)`` (rows and columns of held parameters are zero).
    calibration, calibration_sigma
        ``(8,)`` (:data:`CALIBRATION_NAMES`; range scale dimensionless).
    strips, strips_sigma
        ``(K, 12)`` per-strip corrections (dp m, dv m/s, da rad, dw rad/s; local ENU).
    strip_ids, strip_epoch_s
        ``(K,)`` input strip ids and reference epochs.
    verdicts
        Determinability of each calibration parameter (held ones have ``held``).
    mount
        The corrected mount (boresight and lever arm applied).
    sigma0
        Square root of the variance factor; ``redundancy`` its degrees of freedom.
    n_points, n_planes, n_control, iterations, rejected
        Laser points used, planes, control points, Gauss-Newton iterations, points rejected (|v| > 5 sigma).
    rms_before_m, rms_after_m
        RMS point-to-plane residuals of the laser points before (nominal; planes fitted) and after.
    normal, offset
        ``(P, 3)``, ``(P,)`` the adjusted planes.
    rule
        The determinability rule in words.
    covariance_kind
        ``"a-posteriori"`` (scaled by sigma0^2) or ``"a-priori"``.
    """

    names: tuple[str, ...]
    value: NDArray[np.float64]
    sigma: NDArray[np.float64]
    covariance: NDArray[np.float64]
    correlation: NDArray[np.float64]
    calibration: NDArray[np.float64]
    calibration_sigma: NDArray[np.float64]
    strips: NDArray[np.float64]
    strips_sigma: NDArray[np.float64]
    strip_ids: NDArray[np.int64]
    strip_epoch_s: NDArray[np.float64]
    verdicts: tuple[CalibrationVerdict, ...]
    mount: ScannerMount
    sigma0: float
    redundancy: int
    n_points: int
    n_planes: int
    n_control: int
    iterations: int
    rejected: int
    rms_before_m: float
    rms_after_m: float
    normal: NDArray[np.float64]
    offset: NDArray[np.float64]
    rule: str
    covariance_kind: str

    @property
    def held(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.verdicts if v.held)

    def get(self, name: str) -> tuple[float, float]:
        i = self.names.index(name)
        return float(self.value[i]), float(self.sigma[i])

    def to_dict(self) -> dict[str, Any]:
        cal = {n: {"value": float(v), "sigma": float(s)} for n, v, s in zip(CALIBRATION_NAMES, self.calibration,
                                                                            self.calibration_sigma)}
        return {
            "units": {"boresight": "rad (rotation vector in the scanner frame)", "lever": "m (body frame)",
                      "range_offset": "m", "range_scale": "dimensionless", "strips": "dp m, dv m/s, da rad, dw rad/s "
                      "(local ENU frame; dv, dw per second from the strip's epoch)"},
            "calibration": cal,
            "calibration_correlation": self.correlation[:N_CAL, :N_CAL].tolist(),
            "strips": [{"id": int(i), "epoch_s": float(e), **{p: float(v) for p, v in zip(_STRIP_PARTS, row)},
                        "sigma": {p: float(s) for p, s in zip(_STRIP_PARTS, srow)}}
                       for i, e, row, srow in zip(self.strip_ids, self.strip_epoch_s, self.strips, self.strips_sigma)],
            "verdicts": [{"name": v.name, "verdict": v.verdict, "held": v.held, "ratio": v.ratio, "z_prior": v.z_prior,
                          "words": v.words()} for v in self.verdicts],
            "rule": self.rule, "sigma0": self.sigma0, "redundancy": self.redundancy, "covariance": self.covariance_kind,
            "points": self.n_points, "planes": self.n_planes, "control_points": self.n_control,
            "iterations": self.iterations, "rejected": self.rejected,
            "rms_before_m": self.rms_before_m, "rms_after_m": self.rms_after_m,
        }


# ---------------------------------------------------------------------------------------------- solver
def _normal_equations(p: PlanarPatches, mount: ScannerMount, x: NDArray, normal: NDArray, offset: NDArray,
                      model: StripModel, active: NDArray[np.bool_], free: NDArray[np.bool_]
                      ) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, float, dict]:
    """Reduced normal equations (planes eliminated): ``N (u, u)``, ``b (u,)`` and the per-plane blocks."""
    k = p.n_strips
    u = N_CAL + N_STRIP * k
    res = plane_residuals(p, mount, x[:N_CAL], x[N_CAL:].reshape(k, N_STRIP), normal, offset, model,
                          linearise="adjusted")
    n_pl = p.n_planes
    # a plane left with fewer than 3 laser and control points (its points rejected) is held where it is
    dead = np.bincount(p.plane, active.astype(float), minlength=n_pl) + p.control_count < 3
    wt = np.where(active & ~dead[p.plane], 1.0 / res["sigma"], 0.0)
    rw = res["r"] * wt
    Jc = res["J_cal"] * wt[:, None]
    Js = res["J_strip"] * wt[:, None]
    Jp = res["J_plane"] * wt[:, None]
    # global blocks: calibration x calibration, calibration x own strip, strip x strip (one per strip)
    N = np.zeros((u, u))
    b = np.zeros(u)
    N[:N_CAL, :N_CAL] = Jc.T @ Jc
    b[:N_CAL] = -Jc.T @ rw
    for s in range(k):
        m = p.strip == s
        sl = slice(N_CAL + N_STRIP * s, N_CAL + N_STRIP * (s + 1))
        N[sl, sl] = Js[m].T @ Js[m]
        N[:N_CAL, sl] = Jc[m].T @ Js[m]
        N[sl, :N_CAL] = N[:N_CAL, sl].T
        b[sl] = -Js[m].T @ rw[m]
    # plane blocks
    Npp = np.zeros((n_pl, 3, 3))
    for a in range(3):
        for c in range(a, 3):
            Npp[:, a, c] = Npp[:, c, a] = np.bincount(p.plane, Jp[:, a] * Jp[:, c], minlength=n_pl)
    bp = -np.column_stack([np.bincount(p.plane, Jp[:, a] * rw, minlength=n_pl) for a in range(3)])
    cN, cb, crr = _control_blocks(p, normal, offset, model)
    Npp += cN
    bp += cb
    Npp[dead] = np.eye(3)
    bp[dead] = 0.0
    # plane x global: (P, 3, u) built from per-point products scattered by (plane, a, column)
    Npg = np.zeros((n_pl, 3, u))
    for a in range(3):
        Npg[:, a, :N_CAL] = np.column_stack([np.bincount(p.plane, Jp[:, a] * Jc[:, j], minlength=n_pl)
                                             for j in range(N_CAL)])
        for s in range(k):
            m = p.strip == s
            Npg[:, a, N_CAL + N_STRIP * s:N_CAL + N_STRIP * (s + 1)] = np.column_stack(
                [np.bincount(p.plane[m], Jp[m, a] * Js[m, j], minlength=n_pl) for j in range(N_STRIP)])
    Npp_inv = np.linalg.inv(Npp)
    T = Npp_inv @ Npg  # (P, 3, u)
    N -= np.einsum("pau,pav->uv", Npg, T)
    b -= np.einsum("pau,pa->u", T, bp)
    # priors (zero mean for the corrections, nominal for the calibration)
    ps = model.prior_sigma(k)
    N[np.diag_indices(u)] += 1.0 / ps**2
    b -= x / ps**2
    vtpv = float(np.sum(rw**2) + np.sum(crr) + np.sum((x / ps) ** 2))
    # held parameters: fixed (unit rows)
    fixed = ~free
    N[fixed, :] = 0.0
    N[:, fixed] = 0.0
    N[fixed, fixed] = 1.0
    b[fixed] = 0.0
    return N, b, Npp_inv, Npg, bp, vtpv, res


def _vtpv(p: PlanarPatches, mount: ScannerMount, x: NDArray, normal: NDArray, offset: NDArray, model: StripModel,
          active: NDArray[np.bool_]) -> float:
    """Weighted sum of squares (laser points, control points, priors) at ``x`` and the planes."""
    k = p.n_strips
    res = plane_residuals(p, mount, x[:N_CAL], x[N_CAL:].reshape(k, N_STRIP), normal, offset, model)
    z = np.where(active, res["r"] / res["sigma"], 0.0)
    crr = _control_blocks(p, normal, offset, model)[2]
    return float(np.sum(z**2) + np.sum(crr) + np.sum((x / model.prior_sigma(k)) ** 2))


def _solve(N: NDArray, b: NDArray) -> NDArray:
    d = np.sqrt(np.diag(N))
    try:
        return np.linalg.solve(N / d[:, None] / d[None, :], b / d) / d
    except np.linalg.LinAlgError:
        raise GeometryError("the strip adjustment's normal equations are singular") from None


def _run(p: PlanarPatches, mount: ScannerMount, model: StripModel, x0: NDArray, free: NDArray[np.bool_],
         iterations: int, reject_sigma: float, planes: tuple[NDArray, NDArray] | None = None) -> dict[str, Any]:
    normal = p.normal.copy() if planes is None else planes[0].copy()
    offset = np.zeros(p.n_planes) if planes is None else planes[1].copy()
    x = x0.copy()
    active = np.ones(len(p), bool)
    it = 0
    ps = model.prior_sigma(p.n_strips)

    def moved(x: NDArray, normal: NDArray, offset: NDArray, dx: NDArray, dpl: NDArray, f: float) -> tuple:
        e1, e2 = plane_basis(normal)
        nn = normal + f * (dpl[:, 0:1] * e1 + dpl[:, 1:2] * e2)
        return x + f * dx, nn / np.linalg.norm(nn, axis=1, keepdims=True), offset + f * dpl[:, 2]

    for it in range(1, iterations + 1):
        N, b, Npp_inv, Npg, bp, vtpv, res = _normal_equations(p, mount, x, normal, offset, model, active, free)
        dx = _solve(N, b)
        dpl = np.einsum("pab,pb->pa", Npp_inv, bp - np.einsum("pau,u->pa", Npg, dx))
        # the Gauss-Newton step in posterior sigmas (diagonal of N^-1; held unknowns have a unit diagonal, no step)
        step = float(np.max(np.abs(dx) / np.sqrt(np.maximum(np.diag(np.linalg.inv(N)), 1e-300))))
        # a step of more than a sigma that raises the weighted squares (a far, weakly determined start) is
        # shortened.  Within a sigma of the solution the full step is taken: there the weighted squares change by
        # about step^2 while their second-order terms (the renormalised plane normals, the sigmas that depend on
        # the unknowns) are of the same order, and a search that halved such steps crept to the solution by 1/64
        # of a step per iteration, ending at the iteration cap with a small step in sigmas that was no
        # convergence (strips-ci seed 1: 0.0107 -> 0.0099 sigmas over 9 iterations)
        f = 1.0
        for _ in range(6 if step > 1.0 else 0):
            trial = moved(x, normal, offset, dx, dpl, f)
            if _vtpv(p, mount, *trial, model, active) <= vtpv * (1 + 1e-9):
                break
            f *= 0.5
        x, normal, offset = moved(x, normal, offset, dx, dpl, f)
        logger.debug("strip adjustment iteration %d: step %.3g sigmas (%.3g taken), vtpv %.6g", it, step, f, vtpv)
        if 2 <= it <= 6 and reject_sigma > 0:  # rejections settle early; later ones would hold off convergence
            z = np.abs(res["r"]) / res["sigma"]
            newly = active & (z > reject_sigma)
            if newly.any():
                active &= ~newly
                continue
        if step < 0.01:
            break
    N, b, Npp_inv, Npg, bp, vtpv, res = _normal_equations(p, mount, x, normal, offset, model, active, free)
    return {"x": x, "N": N, "normal": normal, "offset": offset, "active": active, "vtpv": vtpv, "res": res,
            "iterations": it}


def adjust_strips(
    patches: PlanarPatches,
    mount: ScannerMount,
    *,
    model: StripModel = StripModel(),
    estimate: Sequence[str] = CALIBRATION_NAMES,
    iterations: int = 25,
    reject_sigma: float = 5.0,
    ratio_max: float = 0.5,
    z_max: float = 3.0,
    strong_ratio: float = 0.3,
    covariance: str = "a-posteriori",
) -> StripAdjustmentResult:
    """Adjust laser strips on planar patches: calibration and per-strip trajectory corrections.

    Parameters
    ----------
    patches
        From :func:`find_planar_patches`.
    mount
        The nominal scanner mount.
    model
        Stochastic model and priors.
    estimate
        Calibration unknowns to estimate (others held at their nominal value: zero correction).
    iterations
        Gauss-Newton iterations (at most).
    reject_sigma
        Points with a normalised residual above this are left out in the second to sixth iterations (0: never).
    ratio_max, z_max, strong_ratio
        The determinability rule (:mod:`skyrig.adjust.determinability`).
    covariance
        ``"a-posteriori"`` (scaled by sigma0^2) or ``"a-priori"``.

    Raises
    ------
    GeometryError
        Singular normal equations.
    """
    bad = [e for e in estimate if e not in CALIBRATION_NAMES]
    if bad:
        raise InputFormatError(f"unknown calibration parameters {bad}; choose from {list(CALIBRATION_NAMES)}",
                               field="estimate")
    if covariance not in ("a-posteriori", "a-priori"):
        raise InputFormatError(f"covariance must be 'a-posteriori' or 'a-priori', not {covariance!r}", field="covariance")
    k = patches.n_strips
    u = N_CAL + N_STRIP * k
    names = strip_parameter_names(k)
    free = np.ones(u, bool)
    free[:N_CAL] = [n in estimate for n in CALIBRATION_NAMES]
    ps = model.prior_sigma(k)
    x0 = np.zeros(u)
    # before: nominal parameters, planes fitted to the points (a run with everything held)
    before = _run(patches, mount, model, x0, np.zeros(u, bool), 3, 0.0)
    rms_before = float(np.sqrt(np.mean(before["res"]["r"] ** 2)))
    # a first solve with the range scale and the lever arm held: from the nominal start these trade with the planes
    # and the strip corrections far from the linear range, and a free start can end in a wrong (scaled) minimum
    stage = free.copy()
    stage[[CALIBRATION_NAMES.index(n) for n in ("range_scale", "lever_x", "lever_y", "lever_z")]] = False
    first = _run(patches, mount, model, x0, stage, iterations, reject_sigma)
    x0, planes0 = first["x"], (first["normal"], first["offset"])
    held: dict[str, CalibrationVerdict] = {}
    verdicts: list[CalibrationVerdict] = []
    out: dict[str, Any] = {}
    for _ in range(3):
        out = _run(patches, mount, model, np.where(free, x0, 0.0), free, iterations, reject_sigma, planes0)
        n_obs = int(out["active"].sum()) + int(np.sum(patches.control_count)) + int(free.sum())
        redundancy = n_obs - int(free.sum()) - 3 * patches.n_planes
        s0 = float(np.sqrt(out["vtpv"] / max(redundancy, 1)))
        Q = np.linalg.inv(out["N"])
        Q[~free, :] = 0.0
        Q[:, ~free] = 0.0
        verdicts = []
        for j, nm in enumerate(CALIBRATION_NAMES):
            if not free[j]:
                continue
            formal = float(np.sqrt(max(Q[j, j], 0.0)))
            ratio = formal / ps[j]
            z = float(out["x"][j] / np.sqrt(max(ps[j] ** 2 - formal**2, (0.05 * ps[j]) ** 2)))
            if ratio > ratio_max:
                verdict = NOT_DETERMINABLE
            elif abs(z) > z_max:
                verdict = CONTRADICTS_PRIOR if ratio > strong_ratio else OVERRULES_PRIOR
            else:
                verdict = DETERMINED
            sc = s0 if covariance == "a-posteriori" else 1.0
            corr = {CALIBRATION_NAMES[i]: float(Q[j, i] / np.sqrt(Q[j, j] * Q[i, i])) for i in range(N_CAL)
                    if i != j and free[i] and abs(Q[j, i]) >= 0.7 * np.sqrt(Q[j, j] * Q[i, i])}
            verdicts.append(CalibrationVerdict(nm, 0.0, float(ps[j]), float(out["x"][j]), sc * formal, formal,
                                               float(ratio), z, verdict, verdict in (NOT_DETERMINABLE, CONTRADICTS_PRIOR),
                                               corr))
        new = [v for v in verdicts if v.held]
        if not new:
            break
        for v in new:
            held[v.name] = v
            logger.warning("strip adjustment: %s", v.words())
            free[CALIBRATION_NAMES.index(v.name)] = False
    verdicts = [*held.values(), *[v for v in verdicts if not v.held]]
    verdicts.sort(key=lambda v: CALIBRATION_NAMES.index(v.name))
    x = out["x"]
    sc = s0**2 if covariance == "a-posteriori" else 1.0
    cov = sc * Q
    sig = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = np.where(np.outer(sig, sig) > 0, cov / np.outer(sig, sig), 0.0)
    cal = x[:N_CAL]
    mount_new = mount.corrected(dboresight_rad=cal[0:3], dlever_m=cal[3:6])
    act = out["active"]
    rms_after = float(np.sqrt(np.mean(out["res"]["r"][act] ** 2)))
    logger.info("strip adjustment: sigma0 %.3f, redundancy %d, %d planes, rms %.4f -> %.4f m", s0, redundancy,
                patches.n_planes, rms_before, rms_after)
    return StripAdjustmentResult(
        names, x, sig, cov, corr, cal.copy(), sig[:N_CAL].copy(), x[N_CAL:].reshape(k, N_STRIP).copy(),
        sig[N_CAL:].reshape(k, N_STRIP).copy(), patches.strip_ids, patches.strip_epoch_s, tuple(verdicts), mount_new,
        s0, int(redundancy), int(act.sum()), patches.n_planes, int(np.sum(patches.control_count)), int(out["iterations"]),
        int((~act).sum()), rms_before, rms_after, out["normal"], out["offset"],
        rule_words(ratio_max, z_max, strong_ratio), covariance)


# ---------------------------------------------------------------------------------------------- products
def patch_discrepancies(
    patches: PlanarPatches,
    mount: ScannerMount,
    model: StripModel,
    result: StripAdjustmentResult | None = None,
) -> dict[str, float]:
    """Strip-to-strip discrepancies on the patches: for every patch and pair of strips seeing it, the difference of
    the strips' mean distances from the patch plane (m), and that difference over its predicted noise.

    ``result`` None: the nominal parameters (planes fitted to all strips' points); otherwise the adjusted ones.
    Returns the RMS and the 95th percentile of the discrepancies, the RMS of the normalised ones (1 at the noise level),
    the predicted noise RMS, and the count of pairs.
    """
    k = patches.n_strips
    if result is None:
        out = _run(patches, mount, model, np.zeros(N_CAL + N_STRIP * k), np.zeros(N_CAL + N_STRIP * k, bool), 3, 0.0)
        r, s = out["res"]["r"], out["res"]["sigma"]
    else:
        res = plane_residuals(patches, mount, result.calibration, result.strips, result.normal, result.offset, model)
        r, s = res["r"], res["sigma"]
    g = patches.plane * k + patches.strip
    n_g = patches.n_planes * k
    cnt = np.bincount(g, minlength=n_g)
    mean = np.bincount(g, r, minlength=n_g) / np.maximum(cnt, 1)
    var = np.bincount(g, s**2, minlength=n_g) / np.maximum(cnt, 1) ** 2  # variance of the mean
    mean, var, cnt = mean.reshape(-1, k), var.reshape(-1, k), cnt.reshape(-1, k)
    d, z, pred = [], [], []
    for a in range(k):
        for b in range(a + 1, k):
            both = (cnt[:, a] > 0) & (cnt[:, b] > 0)
            dd = mean[both, a] - mean[both, b]
            vv = var[both, a] + var[both, b]
            d.append(dd)
            z.append(dd / np.sqrt(vv))
            pred.append(vv)
    dd, zz, pp = np.concatenate(d), np.concatenate(z), np.concatenate(pred)
    return {"pairs": int(dd.size), "rms_m": float(np.sqrt(np.mean(dd**2))),
            "p95_abs_m": float(np.percentile(np.abs(dd), 95)), "normalised_rms": float(np.sqrt(np.mean(zz**2))),
            "noise_rms_m": float(np.sqrt(np.mean(pp)))}


def apply_strip_corrections(
    scan: RawScan,
    trajectory: Trajectory,
    mount: ScannerMount,
    frame: WorldFrame,
    result: StripAdjustmentResult,
    *,
    position: str = "cubic",
    chunk: int = 400_000,
) -> NDArray[np.float64]:
    """Georeference every pulse with the adjusted calibration and strip corrections: ``(N, 3)`` in the local
    ``frame`` the adjustment used (pulses of strips the adjustment did not see, or with a negative strip id, get the
    calibration only).

    ``mount`` is the nominal mount the adjustment started from.
    """
    if scan.strip_id is None:
        raise InputFormatError("the raw scan has no strip ids (column 'strip')", field="strip")
    geo = PulseGeoreferencer(trajectory, mount, position)
    lfe = frame.tangent.ecef_from_local.T
    cal = result.calibration
    b_cur = mount.body_from_scanner @ matrix_from_rotvec(cal[0:3])
    lever = mount.lever_arm_m + cal[3:6]
    ids = np.asarray(result.strip_ids)  # sorted (np.unique)
    out = np.empty((len(scan), 3))
    for a in range(0, len(scan), chunk):
        sub = scan.subset(slice(a, a + chunk))
        p_e, r_e = geo.poses(sub.time_s)
        pos = frame.from_ecef(p_e)
        rot = lfe @ r_e
        u_s = sub.sensor_xyz() / np.maximum(sub.range_m, 1e-12)[:, None]
        rho = (sub.range_m - cal[6]) / (1.0 + cal[7])
        x_b = (rho[:, None] * u_s) @ b_cur.T + lever
        kk = np.clip(np.searchsorted(ids, sub.strip_id), 0, len(ids) - 1)
        kk = np.where(ids[kk] == sub.strip_id, kk, -1)
        sc = np.zeros((len(sub), N_STRIP))
        dt = np.zeros(len(sub))
        has = kk >= 0
        sc[has] = result.strips[kk[has]]
        dt[has] = sub.time_s[has] - result.strip_epoch_s[kk[has]]
        rot = matrix_from_rotvec(sc[:, 6:9] + dt[:, None] * sc[:, 9:12]) @ rot
        out[a:a + chunk] = pos + sc[:, 0:3] + dt[:, None] * sc[:, 3:6] + np.einsum("nij,nj->ni", rot, x_b)
    return out


# ---------------------------------------------------------------------------------------------- georeferenced clouds
@dataclass(frozen=True, eq=False)
class LineOffsetResult:
    """Per-flight-line offsets of a georeferenced cloud (no trajectory: :func:`adjust_line_offsets`).

    Attributes
    ----------
    line_ids
        ``(K,)`` the line ids (sorted).
    offset, sigma
        ``(K, 3)`` corrections to add to each line's points (m; zero where ``mode="vertical"`` for x, y) and their
        standard deviations (NaN: the line shares no patch with another line).
    mode, datum
        ``"vertical"`` or ``"3d"``; ``"mean"`` (corrections of the lines seen sum to zero) or ``"first"``.
    patches, pairs
        Patches seen by two or more lines; line pairs on them.
    sigma0
        Square root of the variance factor of the discrepancies.
    before, after
        Discrepancies on the patches (:func:`patch_discrepancies` keys: ``pairs``, ``rms_m``, ``p95_abs_m``,
        ``normalised_rms``, ``noise_rms_m``).
    rejected
        Patches left out as outliers (normalised residual > 4 after the first solve).
    """

    line_ids: NDArray[np.int64]
    offset: NDArray[np.float64]
    sigma: NDArray[np.float64]
    mode: str
    datum: str
    patches: int
    pairs: int
    sigma0: float
    before: dict[str, float]
    after: dict[str, float]
    rejected: int

    def to_dict(self) -> dict[str, Any]:
        return {"mode": self.mode, "datum": self.datum, "patches": self.patches, "pairs": self.pairs,
                "sigma0": self.sigma0, "rejected_patches": self.rejected,
                "units": "m, corrections added to the line's points (map axes x, y, height)",
                "lines": [{"id": int(i), "offset_m": [float(v) for v in o], "sigma_m": [float(v) for v in s]}
                          for i, o, s in zip(self.line_ids, self.offset, self.sigma)],
                "discrepancies_before": self.before, "discrepancies_after": self.after}


def adjust_line_offsets(
    xyz: ArrayLike,
    line: ArrayLike,
    *,
    cell_m: float = 4.0,
    mode: str = "vertical",
    datum: str = "mean",
    min_points: int = 5,
    max_thickness_m: float = 0.15,
    min_extent_m: float = 0.5,
    max_normal_angle_deg: float = 10.0,
) -> LineOffsetResult:
    """Per-line offsets of a georeferenced laser cloud from planar patches seen by overlapping lines.

    Without a trajectory (a delivered LAS/LAZ: points, no ranges, no scan angles, no poses) only a rigid shift per
    flight line can be estimated.  Each vertical column of ``cell_m`` (metric, map axes) holding a plane of at least
    ``min_points`` points of a line (RMS distance <= ``max_thickness_m``, second spread >= ``min_extent_m``) is a
    patch of that line; where two or more lines have a patch in the same column with normals within
    ``max_normal_angle_deg``, each line's centroid distance from the common plane is an observation
    ``n . (c_k + t_k) = d`` with the variance of its plane fit (RMS^2 / count).  The plane offsets ``d`` are
    eliminated; ``mode="vertical"`` estimates ``t_k = (0, 0, dz_k)`` (what near-horizontal patches determine),
    ``"3d"`` a full shift (needs walls and slopes).  The datum: corrections summing to zero over the lines seen
    (``"mean"``) or the first line fixed (``"first"``).  Patches with a normalised residual above 4 after a first
    solve are left out.

    Raises
    ------
    InputFormatError
        Bad shapes or options.
    GeometryError
        No patch seen by two lines.
    """
    p = np.asarray(xyz, dtype=np.float64)
    ln = np.asarray(line)
    if p.ndim != 2 or p.shape[1] != 3 or ln.shape != (len(p),):
        raise InputFormatError(f"xyz must be (N, 3) and line (N,), got {p.shape} and {ln.shape}", field="xyz")
    if mode not in ("vertical", "3d"):
        raise InputFormatError(f"mode must be 'vertical' or '3d', not {mode!r}", field="mode")
    if datum not in ("mean", "first"):
        raise InputFormatError(f"datum must be 'mean' or 'first', not {datum!r}", field="datum")
    if not cell_m > 0:
        raise InputFormatError(f"cell_m must be positive, got {cell_m!r}", field="cell_m")
    ids, li = np.unique(ln, return_inverse=True)
    k_lines = len(ids)
    origin = np.floor(p.min(axis=0)) if len(p) else np.zeros(3)
    q = p - origin
    cij = np.floor(q[:, :2] / cell_m).astype(np.int64)
    cells, ci = np.unique(cij, axis=0, return_inverse=True)
    ci = ci.ravel()
    n_g = len(cells) * k_lines
    g = ci * k_lines + li
    ref = np.repeat(np.column_stack([(cells + 0.5) * cell_m, np.zeros(len(cells))]), k_lines, axis=0)
    ref[:, 2] = np.repeat(np.bincount(ci, q[:, 2], minlength=len(cells)) / np.maximum(np.bincount(ci, minlength=len(cells)), 1), k_lines)
    cnt, s1, s2 = _moments(g, q, n_g, ref)
    w, v = np.linalg.eigh(_scatter(cnt, s1, s2))
    thick = np.sqrt(np.maximum(w[:, 0], 0.0))
    ok = (cnt >= min_points) & (thick <= max_thickness_m) & (np.sqrt(np.maximum(w[:, 1], 0.0)) >= min_extent_m)
    nrm = v[:, :, 0] * np.where(v[:, 2, 0] < 0, -1.0, 1.0)[:, None]
    cen = ref + s1 / np.maximum(cnt, 1.0)[:, None]
    var = np.maximum(w[:, 0], 1e-8) / np.maximum(cnt, 1.0)  # variance of the centroid across the plane
    ok = ok.reshape(-1, k_lines)
    nrm, cen, var = nrm.reshape(-1, k_lines, 3), cen.reshape(-1, k_lines, 3), var.reshape(-1, k_lines)
    # the patch normal: count-weighted mean of the lines' normals; lines disagreeing with it leave the patch
    cw = np.where(ok, cnt.reshape(-1, k_lines), 0.0)
    pn = np.einsum("ck,cki->ci", cw, nrm)
    pn /= np.maximum(np.linalg.norm(pn, axis=1, keepdims=True), 1e-12)
    ok &= np.abs(np.einsum("cki,ci->ck", nrm, pn)) >= np.cos(np.radians(max_normal_angle_deg))
    use = np.flatnonzero(ok.sum(axis=1) >= 2)
    if use.size == 0:
        raise GeometryError(f"no {cell_m:g} m column holds a plane of two flight lines: do the lines overlap?")
    pn, okp, cenp, varp = pn[use], ok[use], cen[use], var[use]
    rows = [(j, k) for j in range(len(use)) for k in range(k_lines) if okp[j, k]]
    pj = np.array([r[0] for r in rows])
    pk = np.array([r[1] for r in rows])
    obs = -np.einsum("ij,ij->i", pn[pj], cenp[pj, pk])  # n . t_k - d_j = -n . c_jk
    sig2 = varp[pj, pk]
    dims = [2] if mode == "vertical" else [0, 1, 2]
    nd = len(dims)
    seen = np.unique(pk)
    # unknowns: t of the lines seen (nd each), then d per patch; eliminated by solving the full (small) system
    col = {int(k): i for i, k in enumerate(seen)}
    n_t = nd * len(seen)
    n_u = n_t + len(use)
    A = np.zeros((len(rows), n_u))
    for a, d in enumerate(dims):
        A[np.arange(len(rows)), [col[int(k)] * nd + a for k in pk]] = pn[pj, d]
    A[np.arange(len(rows)), n_t + pj] = -1.0
    # datum: sum of the corrections zero (mean) or the first line's zero, as weighted constraint rows
    C = np.zeros((nd, n_u))
    for a in range(nd):
        if datum == "mean":
            C[a, [i * nd + a for i in range(len(seen))]] = 1.0
        else:
            C[a, a] = 1.0
    keep = np.ones(len(use), bool)
    res = np.zeros(len(rows))
    x = np.zeros(n_u)
    s0 = 1.0
    Q: NDArray[Any] = np.zeros((n_u, n_u))
    for _ in range(2):
        wr = np.where(keep[pj], 1.0 / sig2, 0.0)
        N = A.T @ (A * wr[:, None]) + 1e6 * (C.T @ C) / max(float(np.median(sig2)), 1e-12)
        dead = np.diag(N) == 0
        N[dead, dead] = 1.0
        Q = np.linalg.pinv(N)
        x = Q @ (A.T @ (wr * obs))
        res = A @ x - obs
        dof = max(int(np.sum(wr > 0)) - n_u + nd + int(dead.sum()), 1)
        s0 = float(np.sqrt(np.sum(wr * res**2) / dof))
        zp = np.abs(res) / np.sqrt(sig2) / max(s0, 1e-12)
        bad = np.bincount(pj, zp > 4.0, minlength=len(use)) > 0
        if not (bad & keep).any():
            break
        keep &= ~bad
    offset = np.zeros((k_lines, 3))
    sigma = np.full((k_lines, 3), np.nan)
    for k, i in col.items():
        offset[k, dims] = x[i * nd:(i + 1) * nd]
        sigma[k, dims] = s0 * np.sqrt(np.maximum(np.diag(Q)[i * nd:(i + 1) * nd], 0.0))
        sigma[k, [d for d in range(3) if d not in dims]] = 0.0

    def discrepancies(t: NDArray[np.float64]) -> dict[str, float]:
        d, z, pv = [], [], []
        for j in np.flatnonzero(keep):
            ks = np.flatnonzero(okp[j])
            for a in range(len(ks)):
                for b in range(a + 1, len(ks)):
                    ka, kb = ks[a], ks[b]
                    dd = float(pn[j] @ (cenp[j, kb] + t[kb] - cenp[j, ka] - t[ka]))
                    vv = float(varp[j, ka] + varp[j, kb])
                    d.append(dd)
                    z.append(dd / np.sqrt(vv))
                    pv.append(vv)
        da, za, pa = np.array(d), np.array(z), np.array(pv)
        if not da.size:
            return {"pairs": 0, "rms_m": float("nan"), "p95_abs_m": float("nan"), "normalised_rms": float("nan"),
                    "noise_rms_m": float("nan")}
        return {"pairs": int(da.size), "rms_m": float(np.sqrt(np.mean(da**2))),
                "p95_abs_m": float(np.percentile(np.abs(da), 95)), "normalised_rms": float(np.sqrt(np.mean(za**2))),
                "noise_rms_m": float(np.sqrt(np.mean(pa)))}

    before = discrepancies(np.zeros((k_lines, 3)))
    after = discrepancies(offset)
    logger.info("line offsets: %d lines, %d patches, %d pairs, discrepancy RMS %.4f -> %.4f m", k_lines,
                int(keep.sum()), before["pairs"], before["rms_m"], after["rms_m"])
    return LineOffsetResult(ids.astype(np.int64), offset, sigma, mode, datum, int(keep.sum()), int(before["pairs"]), s0,
                            before, after, int((~keep).sum()))
