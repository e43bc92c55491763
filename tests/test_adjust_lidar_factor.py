"""The LiDAR observation type of the adjustment (issue 34, ``skyrig.adjust.factors.lidar``).

A seeded, model-exact laser flight over a synthetic image block: three laser strips (different headings and
heights) see planar patches and the local planes of some of the block's tie points; every laser point is made from
a true surface point by inverting the georeferencing with the true scanner calibration and the true trajectory, and
the recorded trajectory carries per-strip offsets and drifts drawn from the priors' sigmas.  The adjustment of
images and laser together must find the injected scanner calibration within 3 predicted sigmas.  The Jacobians
are checked against finite differences, and the reduced rows of a plane against the plane's points with the plane
eliminated by an independent dense least-squares computation.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conftest import grazing_ground_beams
from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import Unknowns
from skyrig.adjust.factors.lidar import (LIDAR, NK, NS, SCANNER, SCANNER_COMPONENTS, STRIP, LidarPoints, control_gram,
                                         control_residuals, georeference, plane_basis,
                                         lidar_unknowns)
from skyrig.adjust.model import Model, State
from skyrig.adjust.synthetic import synthetic_block
from skyrig.errors import BlockError
from skyrig.geometry.rotations import matrix_from_rotvec

STRIP_SIGMA = np.array([0.03, 0.03, 0.05, 5e-4, 5e-4, 8e-4, 3e-4, 3e-4, 8e-4, 3e-6, 3e-6, 8e-6])
TRUE_SCANNER = np.array([0.004, -0.003, 0.005, 0.03, -0.04, 0.05, 0.04, 8e-4])
BODY_FROM_SCANNER = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # a proper rotation
LEVER = np.array([0.1, -0.02, 0.15])
RANGE_SIGMA = 0.02


def _strip_pose(k: int, t: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """True body position and world_from_body of strip ``k`` at times ``t`` (s from the strip's epoch)."""
    head = [0.0, np.pi, np.pi / 2][k]
    h = [300.0, 360.0, 330.0][k]
    u = np.array([np.cos(head), np.sin(head), 0.0])
    P = centre + np.array([0.0, 0.0, h]) + t[:, None] * 20.0 * u + np.array([[0.0, [0, 40, -30][k], 0.0]])
    yaw = head + 0.01 * np.sin(0.7 * t)
    rv = np.column_stack([0.02 * np.sin(0.9 * t), 0.015 * np.cos(0.5 * t), np.zeros_like(t)])
    Rz = matrix_from_rotvec(np.column_stack([np.zeros_like(t), np.zeros_like(t), yaw]))
    # body z down: x forward, y right
    flip = np.diag([1.0, -1.0, -1.0])
    return P, Rz @ matrix_from_rotvec(rv) @ flip


def _laser_on_plane(rng, X0, normal, k, n, centre, true_strip, epoch):
    """``n`` laser points of strip ``k`` on the plane ``(X0, normal)`` near ``X0``: recorded data of each."""
    a = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    uv = rng.uniform(-1.5, 1.5, (n, 2))
    X = X0 + uv[:, :1] * a + uv[:, 1:] * b
    # pulse times: when the strip passes near the point
    t = np.clip((X0[0] - centre[0]) * 0 + rng.uniform(-8.0, 8.0, n), -10, 10)
    P, R = _strip_pose(k, t, centre)
    Bt = BODY_FROM_SCANNER @ matrix_from_rotvec(TRUE_SCANNER[:3])
    xs = np.einsum("ji,nj->ni", Bt, np.einsum("nji,nj->ni", R, X - P) - (LEVER + TRUE_SCANNER[3:6]))
    rho = np.linalg.norm(xs, axis=1)
    beam = xs / rho[:, None]
    db = np.cross(beam, [0.0, 0.0, 1.0])
    db /= np.linalg.norm(db, axis=1)[:, None]
    rec = (1 + TRUE_SCANNER[7]) * rho + TRUE_SCANNER[6] + rng.normal(0.0, RANGE_SIGMA, n)
    # recorded trajectory: the true one with the strip's error (the corrections' negatives)
    s = true_strip[k]
    tau = t
    g = s[6:9] + s[9:12] * tau[:, None]
    P_rec = P - s[0:3] - s[3:6] * tau[:, None]
    R_rec = matrix_from_rotvec(-g) @ R
    return dict(time_s=epoch[k] + t, strip=np.full(n, k), range_m=rec, beam=beam, beam_dangle=db, position_m=P_rec,
                rotation=R_rec)


def _joint_block(seed: int = 4, n_patch: int = 30, n_tie: int = 15, per: int = 12, shift=(0.0, 0.0, 0.0),
                 planes: list | None = None):
    """The block, the truth and the true strip corrections; ``shift``: a position error common to all strips (the
    trajectory's absolute error) added to their corrections; ``planes``: a list given gets each plane's true
    ``(point, normal)``."""
    b, truth = synthetic_block(seed=seed, n_points=120, n_strips=2, n_per_strip=5)
    rng = np.random.default_rng(seed)
    centre = truth.point_xyz.mean(axis=0)
    epoch = np.array([1000.0, 1100.0, 1200.0])
    true_strip = rng.normal(0.0, 1.0, (3, 12)) * STRIP_SIGMA
    true_strip[:, 0:3] += np.asarray(shift, float)
    parts, plane_point, normals = [], [], []
    q = 0
    for j in range(n_patch + n_tie):
        tie = j >= n_patch
        if tie:
            pj = int(rng.integers(b.n_points))
            X0 = truth.point_xyz[pj]
        else:
            X0 = centre + np.array([*rng.uniform(-150, 150, 2), rng.uniform(-10, 10)])
        nrm = rng.normal(0.0, 1.0, 3)
        nrm[2] = abs(nrm[2]) + 1.0  # facing up-ish, within about 60 deg of the vertical
        nrm /= np.linalg.norm(nrm)
        for k in range(3):
            if tie and k == 2:
                continue  # tie planes: two strips
            d = _laser_on_plane(rng, X0, nrm, k, per, centre, true_strip, epoch)
            d["plane"] = np.full(per, q)
            parts.append(d)
            normals.append(np.broadcast_to(nrm, (per, 3)))
        plane_point.append(pj if tie else -1)
        if planes is not None:
            planes.append((X0, nrm))
        q += 1
    cat = {k_: np.concatenate([p[k_] for p in parts]) for k_ in parts[0]}
    lp = LidarPoints(**cat, plane_point=np.array(plane_point), strip_epoch_s=epoch, body_from_scanner=BODY_FROM_SCANNER,
                     lever_arm_m=LEVER, range_sigma_m=RANGE_SIGMA, roughness_m=0.001)
    # n . beam at the planes as found (here: the true planes; a fit of 12 noisy points per strip on a 3 m plane seen
    # from 300 m tilts by up to 40 deg, and a beam taken for steeper than it is loses its roughness floor)
    lp.incidence0 = np.einsum("ni,ni->n", np.concatenate(normals),
                              georeference(lp, TRUE_SCANNER, true_strip)["beam_w"])
    b = dataclasses.replace(b, observations={**b.observations, "lidar": lp})
    return b, truth, true_strip


@pytest.fixture(scope="module")
def joint():
    b, truth, true_strip = _joint_block()
    cfg = AdjustConfig(unknowns=lidar_unknowns(Unknowns(), strip_sigma=tuple(STRIP_SIGMA)))
    return b, truth, true_strip, cfg, adjust(b, cfg)


def test_images_and_laser_recover_the_scanner_within_predicted_sigmas(joint):
    b, truth, true_strip, cfg, r = joint
    assert r.ok, r.failures
    sig = r.sigma_reduced()
    s0 = r.sigma0
    est = r.block.parameters[SCANNER][0]
    sd = np.array([sig[(SCANNER, "scanner", c)] for c in SCANNER_COMPONENTS]) / s0  # a-priori sigmas
    z = (est - TRUE_SCANNER) / sd
    assert np.all(np.abs(z) < 3.0), dict(zip(SCANNER_COMPONENTS, np.round(z, 2)))
    assert 0.8 < s0 < 1.2
    # it can fail: the nominal values (zero corrections) are far outside the same bounds
    assert np.sum(np.abs(TRUE_SCANNER) > 3 * sd) >= 5
    zs = (r.block.parameters[STRIP] - true_strip) / np.array(
        [[sig[(STRIP, f"strip{k}", c)] for c in
          ("dp_x_m", "dp_y_m", "dp_z_m", "dv_x_m_s", "dv_y_m_s", "dv_z_m_s", "da_x_rad", "da_y_rad", "da_z_rad",
           "dw_x_rad_s", "dw_y_rad_s", "dw_z_rad_s")] for k in range(3)]) * s0
    assert np.all(np.abs(zs) < 4.0)
    # the image block is not pulled off: points stay at their GNSS-and-image precision
    assert np.abs(r.block.point_xyz - truth.point_xyz).max() < 1.0
    # the group's rows are per plane (at most one per unknown it touches, plus one), not per point
    lp = b.observations["lidar"]
    assert len(r.residuals["lidar"].residual) <= lp.n_planes * (NS + 3 * NK + 3 + 1)


def test_georeference_jacobians_match_finite_differences(joint):
    b, _, true_strip, _, _ = joint
    d = b.observations["lidar"]
    rows = np.arange(0, len(d), 7)
    g = georeference(d, TRUE_SCANNER, true_strip, jac=True, rows=rows)
    h = 1e-6
    for which, base, J in (("S", TRUE_SCANNER, g["JS"]), ("K", true_strip, g["JK"])):
        for c in range(base.shape[-1]):
            p, m = base.copy(), base.copy()
            p[..., c] += h
            m[..., c] -= h
            args_p = (p, true_strip) if which == "S" else (TRUE_SCANNER, p)
            args_m = (m, true_strip) if which == "S" else (TRUE_SCANNER, m)
            fd = (georeference(d, *args_p, rows=rows)["X"] - georeference(d, *args_m, rows=rows)["X"]) / (2 * h)
            scale = np.abs(J[:, :, c]).max() + 1e-12
            assert np.abs(fd - J[:, :, c]).max() < 1e-5 * scale, (which, c)


def test_reduced_rows_equal_the_points_with_the_plane_eliminated(joint):
    """Per plane, the square-root rows carry the normal equations and the sum of squares of the plane's points with
    the plane eliminated; checked against finite differences of the residuals and a dense elimination."""
    b, _, true_strip, cfg, _ = joint
    model = Model(b, cfg)
    s = State.from_block(b)
    s.groups[SCANNER] = TRUE_SCANNER[None] + 1e-3
    s.groups[STRIP] = true_strip * 0.5
    f = [x for x in model.evaluate(s, True) if x.name == "lidar"][0]
    d = b.observations["lidar"]
    lay = model.layout
    # the cost agrees between the per-plane rows and the residual-only evaluation
    f0 = [x for x in model.evaluate(s, False) if x.name == "lidar"][0]
    assert np.isclose((f.r**2).sum(), (f0.r**2).sum(), rtol=1e-9)
    assert len(f) + f.n_extra == len(f0) + f0.n_extra
    # gradient J^T r of the reduced rows vs a central difference of 1/2 |r|^2 (sigmas frozen by a zero range noise
    # and a nil roughness, an error of the range: white position noise only, so that the weights do not depend on
    # the unknowns)
    d2 = dataclasses.replace(d, range_sigma_m=0.0, roughness_m=1e-12, position_sigma_m=0.02)
    b2 = dataclasses.replace(b, observations={**b.observations, "lidar": d2})
    m2 = Model(b2, cfg)
    f2 = [x for x in m2.evaluate(s, True) if x.name == "lidar"][0]
    n_c = lay.n_c
    grad = np.zeros(n_c + 1)
    c = np.where(f2.cols >= 0, f2.cols, n_c)
    np.add.at(grad, c, f2.jc[:, 0, :] * f2.r[:, :1])
    cols = lay.groups[SCANNER][0]

    def cost(delta_col: int, hstep: float) -> float:
        s2 = s.copy()
        s2.groups[SCANNER] = s.groups[SCANNER].copy()
        s2.groups[SCANNER][0, delta_col] += hstep
        return 0.5 * float(sum((x.r**2).sum() for x in m2.evaluate(s2, False) if x.name == "lidar"))

    for j in range(NS):
        h = 1e-7 if j in (0, 1, 2, 7) else 1e-5
        fd = (cost(j, h) - cost(j, -h)) / (2 * h)
        assert np.isclose(grad[cols[j]], fd, rtol=2e-4, atol=1e-6 * abs(fd) + 1e-3), (j, grad[cols[j]], fd)
    # one plane by dense elimination: J_A^T (I - B B^+) J_A equals the rows' normal matrix
    p = 0
    idx = np.flatnonzero(d2.plane == p)
    geo = georeference(d2, s.groups[SCANNER][0], s.groups[STRIP], jac=True, rows=idx)
    n, cen, sig = LIDAR.planes(d2, georeference(d2, s.groups[SCANNER][0], s.groups[STRIP])["X"],
                               georeference(d2, s.groups[SCANNER][0], s.groups[STRIP]), np.zeros((d2.n_planes, 3)))
    A = np.einsum("i,nik->nk", n[p], geo["JS"]) / sig[idx, None]
    t1 = np.cross(n[p], [1.0, 0.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n[p], t1)
    dx = geo["X"] - cen[p]
    B = np.column_stack([dx @ t1, dx @ t2, -np.ones(len(idx))]) / sig[idx, None]
    P = np.eye(len(idx)) - B @ np.linalg.pinv(B)
    N_dense = A.T @ P @ A
    k = NS + NK * len(np.unique(d2.strip[idx]))
    first = np.arange(min(len(idx), 3 + k + 1) - 3)  # plane 0's rows come first (at most its points less 3)
    N_rows = f2.jc[first, 0, :NS].T @ f2.jc[first, 0, :NS]
    assert np.allclose(N_rows, N_dense, rtol=1e-8, atol=1e-8 * np.abs(N_dense).max())


def test_bad_laser_input_is_named():
    b, _, _ = _joint_block(n_patch=4, n_tie=0, per=5)
    d = b.observations["lidar"]
    mirror = BODY_FROM_SCANNER @ np.diag([1.0, 1.0, -1.0])
    with pytest.raises(BlockError, match="left-handed"):
        dataclasses.replace(b, observations={**b.observations, "lidar": dataclasses.replace(
            d, body_from_scanner=mirror)}).validate()
    with pytest.raises(BlockError, match="plane"):
        dataclasses.replace(b, observations={**b.observations, "lidar": dataclasses.replace(
            d, plane=np.where(d.plane == 0, 99, d.plane))}).validate()
    bad = dataclasses.replace(d, plane=np.where(d.plane == 1, 2, d.plane))  # plane 1 left empty
    with pytest.raises(BlockError, match="plane 1 has 0 points"):
        dataclasses.replace(b, observations={**b.observations, "lidar": bad}).validate()


def _rows_at(d, scanner, strips, rows, normal, centre, tilt=(0.0, 0.0)):
    """Whitened residuals of ``rows`` at a plane held fixed (normal tilted by ``tilt`` along the tangents)."""
    geo = georeference(d, scanner, strips, rows=rows)
    T = LIDAR.point_rows(d, geo, normal, centre, np.ones(len(rows)))["T"]
    n = normal + tilt[0] * T[:, 0] + tilt[1] * T[:, 1]
    n /= np.linalg.norm(n, axis=1)[:, None]
    return np.einsum("ni,ni->n", n, geo["X"] - centre) / LIDAR.point_sigma(d, geo, n)


def test_adjusted_jacobians_are_the_derivatives_of_the_whitened_residual(joint):
    """``linearise="adjusted"``: the per-point rows are the exact derivatives of ``r / sigma(unknowns, plane)``
    (every error source of the stochastic model on, a state off the truth so that the residuals are large); the
    ``"observed"`` rows (sigma frozen) are not."""
    b, _, true_strip, _, _ = joint
    d = dataclasses.replace(b.observations["lidar"], angle_sigma_rad=2e-3, attitude_sigma_rad=3e-4,
                            position_sigma_m=0.01)
    sc = TRUE_SCANNER + np.array([3e-3, -2e-3, 4e-3, 0.02, 0.01, -0.03, 0.05, 2e-3])
    st = true_strip * 0.5 + STRIP_SIGMA
    rows = np.arange(0, len(d), 11)
    geo = georeference(d, sc, st, jac=True, rows=rows)
    full = georeference(d, sc, st)
    normal, centre, _ = LIDAR.planes(d, full["X"], full, np.zeros((d.n_planes, 3)))
    nrm, cen = normal[d.plane[rows]], centre[d.plane[rows]] + 0.3 * normal[d.plane[rows]]  # residuals ~ 0.3 m
    sig = LIDAR.point_sigma(d, geo, nrm)
    pr = LIDAR.point_rows(d, geo, nrm, cen, sig)
    obs = LIDAR.point_rows(dataclasses.replace(d, linearise="observed"), geo, nrm, cen, sig)
    cases = [("AS", j, lambda h, j=j: (sc + h * np.eye(NS)[j], st, (0.0, 0.0))) for j in range(NS)]
    cases += [("AK", j, lambda h, j=j: (sc, st + h * np.eye(NK)[j][None], (0.0, 0.0))) for j in range(NK)]
    cases += [("B", j, lambda h, j=j: (sc, st, tuple(h * np.eye(2)[j]))) for j in range(2)]
    worst_obs = 0.0
    for key, j, at in cases:
        h = 1e-7 if key == "B" or (key == "AS" and j in (0, 1, 2, 7)) or (key == "AK" and j >= 6) else 1e-5
        fd = (_rows_at(d, *at(h)[:2], rows, nrm, cen, at(h)[2]) - _rows_at(d, *at(-h)[:2], rows, nrm, cen,
                                                                          at(-h)[2])) / (2 * h)
        scale = np.abs(fd).max() + 1e-12
        assert np.abs(pr[key][:, j] - fd).max() < 1e-5 * scale, (key, j)
        worst_obs = max(worst_obs, np.abs(obs[key][:, j] - fd).max() / scale)
    assert worst_obs > 1e-3  # the sigma's dependence on the unknowns is not negligible here


def test_adjusted_jacobians_are_those_at_the_adjusted_observations(joint):
    """Range noise and roughness (an error of the range, the rest across the plane at grazing beams): the
    ``"adjusted"`` rows at the recorded ranges equal the ``"observed"`` rows at the ranges of the Gauss-Helmert
    adjusted observations, built here independently (each range moved by its share ``sigma_r^2 B_r r / var`` of the
    residual, which puts the point on its plane)."""
    b, _, true_strip, _, _ = joint
    d = b.observations["lidar"]
    sc = TRUE_SCANNER + np.array([3e-3, -2e-3, 4e-3, 0.02, 0.01, -0.03, 0.05, 2e-3])
    st = true_strip * 0.5
    rows = np.arange(0, len(d), 5)
    rows = rows[d.plane_point[d.plane[rows]] < 0]  # patch planes (their centre is the points' centroid)
    geo = georeference(d, sc, st, jac=True, rows=rows)
    full = georeference(d, sc, st)
    normal, centre, _ = LIDAR.planes(d, full["X"], full, np.zeros((d.n_planes, 3)))
    nrm, cen = normal[d.plane[rows]], centre[d.plane[rows]]
    sig = LIDAR.point_sigma(d, geo, nrm)
    pr = LIDAR.point_rows(d, geo, nrm, cen, sig)
    r_m = pr["r"] * sig
    B_r = np.einsum("ni,ni->n", nrm, geo["beam_w"]) / (1.0 + sc[7])  # dr / d recorded range
    d_hat = dataclasses.replace(d, linearise="observed", range_m=d.range_m.copy())
    # the roughness: sigma roughness / |n0 . beam| along the range, the rest (grazing beams) across the plane
    b0 = np.maximum(np.abs(d.incidence(rows)), 0.1)
    s2_rng = d.range_sigma_m**2 + (d.roughness_m / b0) ** 2
    d_hat.range_m[rows] -= r_m / sig**2 * s2_rng * B_r
    geo_hat = georeference(d_hat, sc, st, jac=True, rows=rows)
    # what is left of the residual is the roughness's share across the plane (the surface's correction)
    r_hat = np.einsum("ni,ni->n", nrm, geo_hat["X"] - cen)
    assert np.allclose(r_hat, r_m * d.roughness_m**2 * (1 - (d.incidence(rows) / b0) ** 2) / sig**2, rtol=1e-6,
                       atol=1e-9)
    obs_hat = LIDAR.point_rows(d_hat, geo_hat, nrm, cen, sig)
    for key in ("AS", "AK"):
        scale = np.abs(pr[key]).max(axis=0) + 1e-12
        assert np.all(np.abs(pr[key] - obs_hat[key]).max(axis=0) <= 1e-6 * scale), key


@pytest.mark.parametrize("roughness_in_data", [False, True])
def test_joint_rows_uncorrelated_with_residuals_at_grazing_beams(roughness_in_data):
    """At the true parameters the joint factor's whitened rows must be uncorrelated with the whitened residuals (else
    the adjustment is biased: errors-in-variables).  Ground points seen from 5 m at 10-80 deg depression, range noise
    2 cm, the 2 mm roughness floor modelled as an error of the range (``roughness_variances``, the strip
    adjustment's model); the data's roughness absent or along the beam, where a rough surface puts it.  The
    statistic sum(a r) over its own spread is N(0, 1) when unbiased (the plane's offset column projected out):
    range offset, range scale and the plane's tilts here within 4 (range scale -0.3 / -0.3); with the roughness
    across the plane (the model before) the range scale came out -57 / -55; the recorded-point rows ("observed")
    beyond 20."""
    m, h, sr, rough = 20000, 5.0, 0.02, 0.002
    rho, u = grazing_ground_beams(roughness_in_data, m, h, sr, rough)
    d = LidarPoints(time_s=np.zeros(m), strip=np.zeros(m, np.int64), range_m=rho, beam=u,
                    beam_dangle=np.column_stack([-u[:, 1], u[:, 0], np.zeros(m)]), plane=np.zeros(m, np.int64),
                    position_m=np.tile([0.0, 0.0, h], (m, 1)), rotation=np.broadcast_to(np.eye(3), (m, 3, 3)),
                    plane_point=np.array([-1]), strip_epoch_s=np.zeros(1), body_from_scanner=np.eye(3),
                    lever_arm_m=np.zeros(3), range_sigma_m=sr, roughness_m=rough)
    d.normalise(None)  # type: ignore[arg-type]
    nrm, cen = np.tile([0.0, 0.0, 1.0], (m, 1)), np.zeros((m, 3))

    def stat(linearise: str) -> np.ndarray:
        dd = dataclasses.replace(d, linearise=linearise)
        geo = georeference(dd, np.zeros(NS), np.zeros((1, NK)), jac=True)
        pr = LIDAR.point_rows(dd, geo, nrm, cen, LIDAR.point_sigma(dd, geo, nrm))
        j = np.column_stack([pr["AS"][:, 6:8], pr["B"][:, :2]])
        off = pr["B"][:, 2]
        j = j - np.outer(off, off @ j) / (off @ off)  # the plane's offset column projected out (its reduced rows)
        g = j * pr["r"][:, None]
        return g.sum(axis=0) / np.sqrt((g**2).sum(axis=0))

    z = stat("adjusted")
    assert np.all(np.abs(z) < 4.0), np.round(z, 1)  # range offset, range scale, plane tilts
    assert abs(stat("observed")[1]) > 20.0  # the recorded-point rows: the bias this test can see


# ---------------------------------------------------------------------------------------------- control planes
#: the trajectory's absolute error common to the three strips (beyond what the strips' priors allow: what a
#: calibration without control keeps as a shift of the whole cloud)
COMMON_SHIFT = np.array([0.0, 0.0, -0.2])
CONTROL_SIGMA = 0.003


def _control_moments(planes, which, m: int = 200, seed: int = 11, blunder: dict | None = None):
    """Control points (a reference scan, noise ``CONTROL_SIGMA``) on the true planes ``which``: their moments about
    the planes' true points; ``blunder``: plane -> offset (m) along its normal."""
    rng = np.random.default_rng(seed)
    q = len(planes)
    cnt, s1, s2 = np.zeros(q), np.zeros((q, 3)), np.zeros((q, 3, 3))
    for j in which:
        X0, n = planes[j]
        t1, t2 = plane_basis(n[None])
        uv = rng.uniform(-1.5, 1.5, (m, 2))
        y = uv[:, :1] * t1 + uv[:, 1:] * t2 + (rng.normal(0.0, CONTROL_SIGMA, m) + (blunder or {}).get(j, 0.0))[:, None] * n
        cnt[j], s1[j], s2[j] = m, y.sum(axis=0), y.T @ y
    return dict(control_count=cnt, control_sum=s1, control_sum2=s2, control_ref=np.array([p[0] for p in planes]),
                control_sigma_m=CONTROL_SIGMA)


def _held_out_offset(r, lp, planes, held):
    """Mean signed distance of the adjusted laser points of the planes ``held`` from their true planes, and its
    predicted sigma (the adjustment's cofactors of the scanner and strips propagated, and the points' noise)."""
    from skyrig.calibrate.lidar_camera import _scanner_strip_cofactors

    rows = np.flatnonzero(np.isin(lp.plane, held))
    g = georeference(lp, r.block.parameters[SCANNER][0], r.block.parameters[STRIP], True, rows)
    n = np.array([planes[q][1] for q in lp.plane[rows]])
    d = np.einsum("ni,ni->n", n, g["X"] - np.array([planes[q][0] for q in lp.plane[rows]]))
    A = np.zeros((len(rows), NS + NK * lp.n_strips))
    A[:, :NS] = np.einsum("ni,nik->nk", n, g["JS"])
    JK = np.einsum("ni,nik->nk", n, g["JK"])
    for k in range(lp.n_strips):
        on = lp.strip[rows] == k
        A[on, NS + NK * k:NS + NK * (k + 1)] = JK[on]
    a = A.mean(axis=0)
    return float(d.mean()), float(np.sqrt(a @ _scanner_strip_cofactors(r, lp.n_strips) @ a + RANGE_SIGMA**2 / len(rows)))


@pytest.fixture(scope="module")
def controlled():
    """The laser strips with a common trajectory error (no tie planes: nothing but control ties the laser to the
    ground) adjusted without control and with control points on the even patches; the odd ones held out."""
    from skyrig.calibrate.lidar_camera import adjust_joint_block

    planes: list = []
    b, _, _ = _joint_block(seed=4, n_patch=30, n_tie=0, shift=COMMON_SHIFT, planes=planes)
    ctrl, held = np.arange(0, 30, 2), np.arange(1, 30, 2)
    cfg = AdjustConfig(unknowns=lidar_unknowns(Unknowns(), strip_sigma=tuple(STRIP_SIGMA)))
    lp = b.observations["lidar"]
    lpc = dataclasses.replace(lp, **_control_moments(planes, ctrl))
    bc = dataclasses.replace(b, observations={**b.observations, "lidar": lpc})
    return {"planes": planes, "held": held, "ctrl": ctrl, "cfg": cfg, "block": b, "block_c": bc,
            "free": adjust(b, cfg), "with": adjust_joint_block(bc, cfg)}


def test_control_removes_the_common_shift(controlled):
    c = controlled
    lp = c["block"].observations["lidar"]
    d0, s0 = _held_out_offset(c["free"], lp, c["planes"], c["held"])
    res, blk, snoop = c["with"]
    d1, s1 = _held_out_offset(res, blk.observations["lidar"], c["planes"], c["held"])
    assert abs(d0) > 3 * s0  # without control the cloud keeps the trajectory's common error (it can fail)
    assert abs(d1) < 3 * s1 and s1 < 0.2 * abs(d0), (d1, s1, d0)  # with control, on the planes held out: gone
    assert res.ok and 0.8 < res.sigma0 < 1.2 and snoop["control_rejected"] is None


def test_control_residuals_are_normalised(controlled):
    """Each control plane against the laser's own plane: Baarda's normalised residuals about N(0, 1) (15 planes:
    loose bounds), the residuals at the level of their predicted sigmas."""
    res, blk, snoop = controlled["with"]
    cr = snoop["control"]
    assert len(cr) == 15 and not cr.blunder.any()
    assert abs(np.mean(cr.z)) < 3.0 / np.sqrt(len(cr)) and 0.6 < np.std(cr.z) < 1.4, cr.z
    assert np.sqrt(np.mean(cr.residual_m**2)) < 2.0 * np.sqrt(np.mean(cr.sigma_m**2))
    # without the cofactors (the adjustment's explained share) the same residuals over a larger sigma
    raw = control_residuals(blk.observations["lidar"], res.block.parameters[SCANNER][0], res.block.parameters[STRIP])
    assert np.allclose(raw.residual_m, cr.residual_m) and np.all(raw.sigma_m >= cr.sigma_m)


def test_blundered_control_plane_is_flagged_and_left_out(controlled):
    """A control plane 6 cm off its surface (a moved object, a wrong reference) is the blunder, alone; without it
    the block keeps no shift on the planes held out."""
    from skyrig.calibrate.lidar_camera import adjust_joint_block

    c = controlled
    lp = c["block"].observations["lidar"]
    bad = int(c["ctrl"][3])
    lpb = dataclasses.replace(lp, **_control_moments(c["planes"], c["ctrl"], blunder={bad: 0.06}))
    res, blk, snoop = adjust_joint_block(dataclasses.replace(c["block"], observations={**c["block"].observations,
                                                                                        "lidar": lpb}), c["cfg"])
    rej = snoop["control_rejected"]
    assert rej is not None and rej.plane.tolist() == [bad] and abs(rej.z[0]) > 4.0
    assert len(snoop["control"]) == 14 and not snoop["control"].blunder.any()
    d1, s1 = _held_out_offset(res, blk.observations["lidar"], c["planes"], c["held"])
    assert abs(d1) < 3 * s1


def test_control_rows_carry_the_points_normal_equations():
    """``control_gram`` from moments equals the dense sums over the points, with a per-plane error too (generalised
    least squares, covariance ``s^2 I + s_p^2 1 1^T``); the joint factor's reduced rows agree with its cost."""
    rng = np.random.default_rng(3)
    n = np.array([0.3, -0.2, 0.93])
    n /= np.linalg.norm(n)
    t1, t2 = plane_basis(n[None])
    ref, c, off = np.array([1.0, 2.0, 3.0]), np.array([1.2, 1.9, 3.05]), 0.004
    y = ref + rng.normal(0.0, 1.0, (40, 3))
    J = np.column_stack([(y - c) @ t1[0], (y - c) @ t2[0], -np.ones(len(y)), (y - c) @ n - off])
    for sp in (0.0, 0.01):
        Cinv = np.linalg.inv(0.003**2 * np.eye(len(y)) + sp**2 * np.ones((len(y), len(y))))
        G = control_gram(np.array([len(y)]), (y - ref).sum(0)[None], ((y - ref).T @ (y - ref))[None], ref[None], n[None],
                         c[None], off, 0.003, sp)[0]
        assert np.allclose(G, J.T @ Cinv @ J, rtol=1e-9, atol=1e-9 * np.abs(G).max())


def test_reduced_rows_with_control_match_the_cost(controlled):
    c = controlled
    model = Model(c["block_c"], c["cfg"])
    s = State.from_block(c["block_c"])
    s.groups[SCANNER] = TRUE_SCANNER[None] + 1e-3
    f = [x for x in model.evaluate(s, True) if x.name == "lidar"][0]
    f0 = [x for x in model.evaluate(s, False) if x.name == "lidar"][0]
    assert np.isclose((f.r**2).sum(), (f0.r**2).sum(), rtol=1e-9)
    n_ctrl = int(c["block_c"].observations["lidar"].control_count.sum())
    assert len(f) + f.n_extra == len(f0) + f0.n_extra == len(c["block"].observations["lidar"]) + n_ctrl - 3 * 30


def test_bad_control_is_named(controlled):
    lp = controlled["block_c"].observations["lidar"]
    b = controlled["block"]
    with pytest.raises(BlockError, match="control_sigma_m"):
        dataclasses.replace(b, observations={**b.observations, "lidar": dataclasses.replace(
            lp, control_sigma_m=-0.01)}).validate()
    nan = lp.control_sum.copy()
    nan[0, 0] = np.nan
    with pytest.raises(BlockError, match="control_sum"):
        dataclasses.replace(b, observations={**b.observations, "lidar": dataclasses.replace(
            lp, control_sum=nan)}).validate()
