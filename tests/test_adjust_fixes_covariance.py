"""Issue 12: the free-network (inner-constraint) covariance is the Moore-Penrose inverse of the normal matrix.

A simulated close-range block: convergent images (several roll angles) of a 3D target field, self-calibration
of a Brown camera (focal, principal point, k1-k3, p1, p2, b1, b2 in millimetres: the normal matrix's diagonal
spans about 1e-3 .. 1e16), one scale bar, datum by inner constraints (``datum="free"``).

Independent answer, computed here from the factors' Jacobians at the solution (no skyrig solver code): the
dense normal matrix ``N = J^T J``, its Schur complement ``S`` onto the reduced unknowns, the null space of
``S`` from an eigen-decomposition (not skyrig's similarity basis), and ``S^+ = P D pinv(D S D) D P`` with
``numpy.linalg.pinv`` (``D`` Jacobi scaling, ``P`` the orthogonal projector onto the range of ``S``: equal to
the Moore-Penrose inverse of ``S`` for any generalised inverse between the projectors).  Also the four
Penrose conditions directly on skyrig's matrix, and the eliminated points' cofactor blocks against the dense
formula.
"""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig, Block, adjust
from skyrig.adjust.config import Unknowns
from skyrig.adjust.model import Model, State
from skyrig.camera.brown import BrownDistortion
from skyrig.camera.frame import FrameCamera

TRUE_CAM = FrameCamera.from_pixels("cam", 4000, 3000, 3600.0, 2004.0, 1496.0, pixel_size_mm=0.006,
                                   distortion=BrownDistortion(k1=-2e-4, k2=4e-7, k3=-1e-10, p1=5e-6, p2=-3e-6,
                                                              b1=1e-5, b2=-2e-5))


def close_range_block(n_images: int, seed: int = 0, n_targets: int = 120, sigma_px: float = 0.3) -> Block:
    """Convergent images (azimuth around, elevation 25-65 deg, roll 0/90/180/270 deg) at 3-4 m of targets in a
    2 m x 2 m x 0.8 m volume; one scale bar between two far targets; starting values slightly perturbed."""
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(-1, 1, n_targets), rng.uniform(-1, 1, n_targets), rng.uniform(0, 0.8, n_targets)])
    Rs, Cs = [], []
    for i in range(n_images):
        az = 2 * np.pi * (i + rng.uniform(-0.3, 0.3)) / n_images * 3  # three turns
        el = np.radians(rng.uniform(25, 65))
        dist = rng.uniform(3.0, 4.0)
        C = np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)]) * dist + [0, 0, 0.4]
        z = C - np.array([0, 0, 0.4]) + rng.normal(0, 0.05, 3)
        z /= np.linalg.norm(z)  # camera +z points away from the target (the camera looks along -z)
        x = np.cross([0, 0, 1.0], z)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        roll = np.pi / 2 * (i % 4)
        x, y = np.cos(roll) * x + np.sin(roll) * y, -np.sin(roll) * x + np.cos(roll) * y
        Rs.append(np.column_stack([x, y, z]))  # world_from_camera
        Cs.append(C)
    R, C = np.array(Rs), np.array(Cs)
    oi, op, px = [], [], []
    for i in range(n_images):
        pc = (X - C[i]) @ R[i]
        ok = pc[:, 2] < 0
        uv = np.full((n_targets, 2), np.nan)
        uv[ok] = TRUE_CAM.project_pixels(pc[ok])
        vis = np.flatnonzero(ok & TRUE_CAM.in_image(uv, margin_px=20.0))
        oi += [i] * vis.size
        op += vis.tolist()
        px.append(uv[vis])
    px_a = np.vstack(px) + rng.normal(0, sigma_px, (len(oi), 2))
    d = np.linalg.norm(X[:, None] - X[None], axis=2)
    a, b = np.unravel_index(np.argmax(d), d.shape)
    from skyrig.geometry.rotations import matrix_from_rotvec

    return Block(cameras=[TRUE_CAM], station_name=[f"st{i}" for i in range(n_images)],
                 station_rotation=R @ matrix_from_rotvec(rng.normal(0, 1e-3, (n_images, 3))),
                 station_centre=C + rng.normal(0, 5e-3, C.shape), image_name=[f"img{i}" for i in range(n_images)],
                 image_station=np.arange(n_images), image_camera=np.zeros(n_images, int),
                 point_name=[f"t{k}" for k in range(n_targets)], point_xyz=X + rng.normal(0, 5e-3, X.shape),
                 obs_image=np.array(oi), obs_point=np.array(op), obs_pixel=px_a, obs_sigma_px=sigma_px,
                 distance_point=[[a, b]], distance_m=[d[a, b] + rng.normal(0, 1e-4)], distance_sigma_m=1e-4,
                 frame="local object frame")


def dense_normal(res) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    """``(S, Ncp, Npp)``: the dense normal matrix at the solution from the factors' Jacobians, reduced onto
    the reduced unknowns by a dense Schur complement (numpy only)."""
    model = Model(res.initial, res.config)
    state = State.from_block(res.block)
    lay = model.layout
    n_c, n_p = lay.n_c, lay.n_p
    rows = []
    for f in model.evaluate(state):
        w = np.sqrt(f.weight if f.weight is not None else np.ones(len(f)))
        n, dd = f.r.shape
        J = np.zeros((n, dd, n_c + 3 * n_p))
        ii = np.arange(n)
        if f.jc is not None and f.cols is not None:
            for k in range(f.cols.shape[1]):
                c = f.cols[:, k]
                on = c >= 0
                J[ii[on], :, c[on]] += f.jc[on, :, k]
        if f.jp is not None and f.point is not None:
            on = f.point >= 0
            for a in range(3):
                J[ii[on], :, n_c + 3 * f.point[on] + a] += f.jp[on, :, a]
        rows.append((J * w[:, None, None]).reshape(n * dd, -1))
    J = np.vstack(rows)
    N = J.T @ J
    Ncc, Ncp, Npp = N[:n_c, :n_c], N[:n_c, n_c:], N[n_c:, n_c:]
    S = Ncc - Ncp @ np.linalg.solve(Npp, Ncp.T)
    return 0.5 * (S + S.T), Ncp, Npp


def moore_penrose(S: np.ndarray, defect: int) -> tuple[np.ndarray, np.ndarray]:
    """``(S^+, P)`` with numpy: null space from the eigenvectors of the Jacobi-scaled matrix."""
    dsc = 1.0 / np.sqrt(np.diag(S))
    Ss = S * dsc[:, None] * dsc[None, :]
    ev, V = np.linalg.eigh(Ss)
    assert ev[defect - 1] < 1e-10 * ev[-1] < ev[defect], ev[: defect + 2]  # a clear datum defect
    Z, _ = np.linalg.qr(V[:, :defect] * dsc[:, None])  # null vectors of S in parameter units (S D v = 0)
    P = np.eye(len(S)) - Z @ Z.T
    X = np.linalg.pinv(Ss, rcond=1e-12, hermitian=True) * dsc[:, None] * dsc[None, :]
    Sp = P @ X @ P
    return 0.5 * (Sp + Sp.T), P


def check_block(n_images: int) -> dict[str, float]:
    b = close_range_block(n_images)
    res = adjust(b, AdjustConfig(unknowns=Unknowns(datum="free", intrinsics="free")))
    assert res.ok, res.failures
    Q = res.covariance.Qcc
    S, Ncp, Npp = dense_normal(res)
    d = np.diag(S)
    assert d.max() / d.min() > 1e12  # the diagonal spans the orders of magnitude of the issue
    Sp, P = moore_penrose(S, 6)  # 7 similarity motions less the scale of the bar
    out = {"n_c": float(len(Q)), "diag_span": float(d.max() / d.min())}
    # every variance and covariance (relative to the product of the sigmas) equals S^+
    sd = np.sqrt(np.diag(Sp))
    assert np.all(np.diag(Q) > 0)
    rel = np.abs(Q - Sp) / np.outer(sd, sd)
    out["max_rel_cov"] = float(rel.max())
    out["max_rel_var"] = float(np.max(np.abs(np.diag(Q) - np.diag(Sp)) / np.diag(Sp)))
    assert out["max_rel_cov"] < 1e-6 and out["max_rel_var"] < 1e-6, out
    # Penrose conditions on skyrig's matrix (scaled norms): S Q = P (symmetric), Q S Q = Q
    assert np.abs(S @ Q - P).max() < 1e-5
    Dq = Q / np.outer(sd, sd)
    assert np.abs((Q @ S @ Q) / np.outer(sd, sd) - Dq).max() < 1e-6
    # eliminated points: V^-1 + V^-1 W^T S^+ W V^-1 (dense) vs skyrig's 3x3 blocks
    Vi = np.linalg.inv(Npp)
    Qpp_ref = Vi + Vi @ Ncp.T @ Sp @ Ncp @ Vi
    lay = res.layout
    free = np.flatnonzero(lay.point >= 0)
    k = lay.point[free]
    ref = np.array([Qpp_ref[3 * j:3 * j + 3, 3 * j:3 * j + 3] for j in k])
    got = res.covariance.Qpp[k]
    s3 = np.sqrt(np.diagonal(ref, axis1=1, axis2=2))
    out["max_rel_point"] = float((np.abs(got - ref) / (s3[:, :, None] * s3[:, None, :])).max())
    assert out["max_rel_point"] < 1e-6, out
    # sigmas come out of the same matrix: no warnings about absurd correlations
    assert not any("correlated at" in w and "e+" in w for w in res.warnings)
    return out


def test_free_network_covariance_is_the_moore_penrose_inverse():
    check_block(24)


@pytest.mark.slow
def test_free_network_covariance_100_images():
    out = check_block(100)
    assert out["n_c"] >= 600
