"""Scanner boresight, lever-arm and yaw-correction estimation against a reference cloud (paper 002 s. 3, 4.2).

The raw pulses are georeferenced with the current mount and heading correction; each point is paired
with a least-squares plane through its ``k`` nearest reference points (a TLS cloud, or any trusted
surface samples), and the point-to-plane residuals ``r = n . (X - c)`` are minimised by Gauss-Newton over

* ``"boresight"``: a small rotation ``d`` (rotation vector, radians) of the scanner in its own frame,
  ``body_from_scanner <- body_from_scanner @ expmap(d)``; ``dX/dd = -R_eb B [x_scs]x``;
* ``"yaw"``: a heading correction ``dpsi`` (radians), ``ned_from_body <- Rz(dpsi) ned_from_body``
  (paper 002's "rough correction term for the yaw angles"); ``dX/dpsi = down x (R_eb x_body)``;
* ``"lever"``: a lever-arm correction (metres, body frame); ``dX/dl = R_eb``.

Correspondences are recomputed every iteration (an ICP with the sensor model as the transformation),
residuals beyond ``max_distance`` and, after the first iteration, beyond 3 robust sigmas are left out.
The standard deviations come from ``s0^2 (A^T A)^-1`` with ``s0^2 = r^T r / (n - u)``: honest for
independent range noise; correlated errors of a real trajectory make them optimistic.

A heading correction and a boresight rotation about the scanner axis that is (nearly) vertical are the
same unknown when the platform flies level: such a pair is detected from the correlation matrix and
reported as a :class:`~skyrig.errors.GeometryError` rather than solved into noise.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from skyrig.errors import GeometryError, InputFormatError
from skyrig.geodesy.crs import ecef_to_geodetic
from skyrig.georef.eo import WorldFrame
from skyrig.lidar.georef import PulseGeoreferencer, ScannerMount, with_yaw_correction
from skyrig.lidar.scanner import RawScan
from skyrig.trajectory.trajectory import Trajectory

logger = logging.getLogger(__name__)

__all__ = ["BoresightResult", "estimate_boresight"]

_BLOCKS = {"boresight": ("boresight_x", "boresight_y", "boresight_z"), "yaw": ("yaw",),
           "lever": ("lever_x", "lever_y", "lever_z")}


@dataclass(frozen=True, eq=False)
class BoresightResult:
    """Estimated mount and heading corrections.

    Attributes
    ----------
    names
        Unknowns in order (``boresight_x/y/z`` rad, ``yaw`` rad, ``lever_x/y/z`` m).
    value, sigma
        ``(u,)`` total corrections relative to the input mount / heading and their standard deviations.
    covariance, correlation
        ``(u, u)``.
    mount
        The corrected mount.
    yaw_correction_rad
        Total heading correction (input plus estimate).
    rms_before_m, rms_after_m
        Point-to-plane RMS of the inliers before and after.
    n_points, iterations
        Inliers used in the last iteration; iterations run.
    """

    names: tuple[str, ...]
    value: NDArray[np.float64]
    sigma: NDArray[np.float64]
    covariance: NDArray[np.float64]
    correlation: NDArray[np.float64]
    mount: ScannerMount
    yaw_correction_rad: float
    rms_before_m: float
    rms_after_m: float
    n_points: int
    iterations: int

    def get(self, name: str) -> tuple[float, float]:
        """``(value, sigma)`` of one unknown."""
        i = self.names.index(name)
        return float(self.value[i]), float(self.sigma[i])


def _planes(tree: cKDTree, ref: NDArray[np.float64], x: NDArray[np.float64], k: int,
            max_distance: float) -> tuple[NDArray, NDArray, NDArray]:
    d, idx = tree.query(x, k=k, distance_upper_bound=max_distance)
    ok = np.isfinite(d).all(axis=1)
    nb = ref[np.where(ok[:, None], idx, 0)]
    c = nb.mean(axis=1)
    dev = nb - c[:, None, :]
    w, v = np.linalg.eigh(np.einsum("nki,nkj->nij", dev, dev))
    ok &= w[:, 1] > 1e-6 * np.maximum(w[:, 2], 1e-300)  # collinear neighbours: no plane
    return v[:, :, 0], c, ok


def estimate_boresight(
    scan: RawScan,
    trajectory: Trajectory,
    mount: ScannerMount,
    reference: ArrayLike,
    frame: WorldFrame,
    *,
    estimate: Sequence[str] = ("boresight",),
    yaw_correction_rad: float = 0.0,
    position: str = "cubic",
    k: int = 8,
    max_distance: float = 1.0,
    iterations: int = 15,
    max_points: int = 60_000,
    seed: int = 0,
    max_correlation: float = 0.995,
) -> BoresightResult:
    """Estimate boresight / heading / lever-arm corrections that fit the scan to a reference cloud.

    Parameters
    ----------
    scan
        Raw pulses.
    trajectory, mount
        Navigation and the nominal mount.
    reference
        ``(R, 3)`` reference points in ``frame``.
    frame
        Frame of the reference (ECEF, local ENU, or a map CRS: converted to ECEF internally).
    estimate
        Any of ``"boresight"``, ``"yaw"``, ``"lever"``.
    yaw_correction_rad
        Starting heading correction.
    position
        Position interpolation (``"cubic"`` / ``"linear"``).
    k, max_distance
        Reference neighbours per plane, and the largest point-to-reference distance used (metres).
    iterations, max_points, seed
        Gauss-Newton iterations; pulses sampled (at random, ``seed``) for the fit.
    max_correlation
        Above this absolute correlation two unknowns are declared inseparable.

    Raises
    ------
    GeometryError
        Too few usable points, or two unknowns that the data cannot separate.
    """
    blocks = list(dict.fromkeys(estimate))
    for b in blocks:
        if b not in _BLOCKS:
            raise InputFormatError(f"unknown unknown block {b!r}; choose from {sorted(_BLOCKS)}", field="estimate")
    names = tuple(n for b in blocks for n in _BLOCKS[b])
    u = len(names)
    ref = frame.to_ecef(np.asarray(reference, dtype=np.float64)) if frame.kind != "ecef" else np.asarray(reference, float)
    origin = ref.mean(axis=0)
    ref = ref - origin
    tree = cKDTree(ref)
    rng = np.random.default_rng(seed)
    rows = np.arange(len(scan)) if len(scan) <= max_points else np.sort(rng.choice(len(scan), max_points, replace=False))
    sub = scan.subset(rows)
    xs = sub.sensor_xyz()
    cur_mount, dyaw = mount, float(yaw_correction_rad)
    total = np.zeros(u)
    rms_before = np.nan
    thresh = max_distance
    for it in range(1, iterations + 1):
        traj = with_yaw_correction(trajectory, dyaw) if dyaw != 0 else trajectory
        geo = PulseGeoreferencer(traj, cur_mount, position)
        p, reb = geo.poses(sub.time_s)
        lever = geo._lever
        xb = xs @ cur_mount.body_from_scanner.T + lever
        w = np.einsum("nij,nj->ni", reb, xb)
        x = p + w - origin
        n, c, ok = _planes(tree, ref, x, k, max_distance)
        r = np.einsum("ij,ij->i", n, x - c)
        ok &= np.abs(r) <= thresh
        if ok.sum() < 10 * u:
            raise GeometryError(f"only {int(ok.sum())} scan points lie within {max_distance} m of the reference")
        if it == 1:
            rms_before = float(np.sqrt(np.mean(r[ok] ** 2)))
        cols = []
        nb = np.einsum("nji,nj->ni", reb, n)  # normal in the body frame
        for b in blocks:
            if b == "boresight":
                ns = nb @ cur_mount.body_from_scanner  # normal in the scanner frame
                cols.append(np.cross(xs, ns))
            elif b == "yaw":
                lat, lon, _ = ecef_to_geodetic(p)
                lat, lon = np.radians(np.asarray(lat).ravel()), np.radians(np.asarray(lon).ravel())
                down = -np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=1)
                cols.append(np.einsum("ij,ij->i", down, np.cross(w, n))[:, None])
            else:
                cols.append(nb)
        a = np.concatenate(cols, axis=1)[ok]
        rr = r[ok]
        nmat = a.T @ a
        try:
            delta = np.linalg.solve(nmat, -a.T @ rr)
        except np.linalg.LinAlgError:
            raise GeometryError(f"the unknowns {names} are not determined by this scan") from None
        total += delta
        off = 0
        for b in blocks:
            m = len(_BLOCKS[b])
            d = delta[off:off + m]
            if b == "boresight":
                cur_mount = cur_mount.corrected(dboresight_rad=d)
            elif b == "yaw":
                dyaw += float(d[0])
            else:
                cur_mount = cur_mount.corrected(dlever_m=d)
            off += m
        mad = 1.4826 * np.median(np.abs(rr - np.median(rr)))
        thresh = min(max_distance, max(3.0 * mad, 1e-4))
        logger.debug("boresight iteration %d: %d points, rms %.4f m, step %s", it, len(rr), np.sqrt(np.mean(rr**2)), delta)
        if np.max(np.abs(delta)) < 1e-9:
            break
    dof = max(len(rr) - u, 1)
    # residuals after the last step (linearised)
    res = rr + a @ delta
    s0sq = float(res @ res / dof)
    cov = s0sq * np.linalg.inv(nmat)
    sig = np.sqrt(np.diag(cov))
    corr = cov / np.outer(sig, sig)
    off = np.abs(corr - np.eye(u))
    if u > 1 and off.max() > max_correlation:
        i, j = np.unravel_index(np.argmax(off), off.shape)
        raise GeometryError(
            f"{names[i]} and {names[j]} cannot be separated by this scan (correlation {corr[i, j]:+.4f}); "
            "estimate one of them (e.g. yaw with boresight_x/y only) or fly with more attitude variation"
        )
    return BoresightResult(names, total, sig, cov, corr, cur_mount, dyaw, rms_before, float(np.sqrt(s0sq)),
                           int(len(rr)), it)
