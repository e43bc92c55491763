"""Issue 12: a datum by inner constraints on object points (all, or a chosen set), as close-range programs
define it, on the simulated close-range block of ``test_adjust_fixes_covariance`` (convergent images of a 3D
target field, self-calibration, one scale bar, ``datum="free"``).

Independent answers, computed here with numpy only:

* the covariance: the dense normal matrix ``N`` of *all* unknowns (poses, calibration, scale-bar end points,
  eliminated points) from the factors' Jacobians at the solution, its null space from an eigen-decomposition
  of the Jacobi-scaled matrix (not skyrig's similarity basis), and the constrained inverse from the bordered
  system ``[[N, C], [C^T, 0]]^-1`` with ``C`` the null-space rows of the datum points (not skyrig's
  S-transformation);
* the adjusted values: the datum points keep the centroid and orientation of their starting coordinates
  (the inner constraints ``B^T (X - X0) = 0``, checked directly as sums over the points);
* the truth: after a Helmert fit onto the true target field, the errors of the points agree with the
  reported sigmas (chi-square per coordinate).
"""

from __future__ import annotations

import numpy as np
import pytest

from skyrig.adjust import AdjustConfig, adjust
from skyrig.adjust.config import Unknowns
from skyrig.adjust.model import Model, State
from test_adjust_fixes_covariance import close_range_block


def dense_full_normal(res) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The dense normal matrix of all unknowns (reduced columns first, then 3 per eliminated point)."""
    model = Model(res.initial, res.config)
    state = State.from_block(res.block)
    lay = model.layout
    n = lay.n_c + 3 * lay.n_p
    N = np.zeros((n, n))
    for f in model.evaluate(state):
        w = f.weight if f.weight is not None else np.ones(len(f))
        m, dd = f.r.shape
        J = np.zeros((m, dd, n))
        ii = np.arange(m)
        if f.jc is not None and f.cols is not None:
            for k in range(f.cols.shape[1]):
                c = f.cols[:, k]
                on = c >= 0
                J[ii[on], :, c[on]] += f.jc[on, :, k]
        if f.jp is not None and f.point is not None:
            on = f.point >= 0
            for a in range(3):
                J[ii[on], :, lay.n_c + 3 * f.point[on] + a] += f.jp[on, :, a]
        Jw = (J * np.sqrt(w)[:, None, None]).reshape(m * dd, n)
        N += Jw.T @ Jw
    return 0.5 * (N + N.T)


def point_columns(lay, mask: np.ndarray) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Columns of the full unknown vector holding the coordinates of the points in ``mask``."""
    cols = []
    for k in np.flatnonzero(mask):
        if lay.point[k] >= 0:
            cols += (lay.n_c + 3 * lay.point[k] + np.arange(3)).tolist()
        elif lay.rpoint is not None and lay.rpoint[k, 0] >= 0:
            cols += lay.rpoint[k].tolist()
    return np.array(cols)


def bordered_reference(N: np.ndarray, datum_cols: np.ndarray, defect: int) -> np.ndarray:
    """Cofactors of the datum 'inner constraints on the coordinates ``datum_cols``': top-left block of the
    inverse of the bordered matrix, in the Jacobi-scaled space."""
    dsc = 1.0 / np.sqrt(np.diag(N))
    Ns = N * dsc[:, None] * dsc[None, :]
    ev, V = np.linalg.eigh(Ns)
    assert ev[defect - 1] < 1e-10 * ev[-1] < ev[defect], ev[: defect + 2]
    Z = V[:, :defect] * dsc[:, None]  # null space of N in parameter units
    B = np.zeros_like(Z)
    B[datum_cols] = Z[datum_cols]
    C, _ = np.linalg.qr(B * dsc[:, None])  # constraint B^T x = 0 on y = x / dsc
    n = len(N)
    K = np.zeros((n + defect, n + defect))
    K[:n, :n] = Ns
    K[:n, n:] = C
    K[n:, :n] = C.T
    Qs = np.linalg.inv(K)[:n, :n]
    Q = Qs * dsc[:, None] * dsc[None, :]
    return 0.5 * (Q + Q.T)


def skyrig_full_cofactors(res) -> np.ndarray:  # type: ignore[no-untyped-def]
    """skyrig's cofactors laid out like :func:`dense_full_normal` (point-point blocks: diagonal only, the
    off-diagonal ones are NaN - skyrig does not form them)."""
    lay, cov = res.layout, res.covariance
    n_c, n_p = lay.n_c, lay.n_p
    Q = np.full((n_c + 3 * n_p,) * 2, np.nan)
    Q[:n_c, :n_c] = cov.Qcc
    Qcp = -np.einsum("cpa,pab->cpb", cov.M.reshape(n_c, n_p, 3), cov.Vinv).reshape(n_c, 3 * n_p)
    Q[:n_c, n_c:] = Qcp
    Q[n_c:, :n_c] = Qcp.T
    for p in range(n_p):
        s = slice(n_c + 3 * p, n_c + 3 * p + 3)
        Q[s, s] = cov.Qpp[p]
    return Q


def check_point_datum(b, res, datum_points: tuple[str, ...] = ()) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """Compare ``res`` (an adjustment of ``b`` with inner constraints on ``datum_points``, empty = all)
    against the bordered dense reference; return the figures."""
    assert res.ok, res.failures
    lay = res.layout
    mask = np.ones(b.n_points, bool) if not datum_points else np.isin(b.point_name, datum_points)
    N = dense_full_normal(res)
    d = np.diag(N)
    assert d.max() / d.min() > 1e12  # the orders of magnitude of the issue
    Qref = bordered_reference(N, point_columns(lay, mask), 6)  # 7 similarity motions less the bar's scale
    Q = skyrig_full_cofactors(res)
    sd = np.sqrt(np.diag(Qref))
    known = np.isfinite(Q)
    rel = np.abs(Q - Qref)[known] / np.outer(sd, sd)[known]
    out = {"n_unknowns": float(len(N)), "diag_span": float(d.max() / d.min()), "max_rel_cov": float(rel.max()),
           "max_rel_var": float(np.max(np.abs(np.diag(Q) - np.diag(Qref)) / np.diag(Qref)))}
    assert out["max_rel_cov"] < 1e-6 and out["max_rel_var"] < 1e-6, out
    # the sigmas the user reads are those of the reference
    dq = np.diag(Qref)
    one = np.eye(b.n_points, dtype=bool)
    ref_ps = np.array([np.sqrt(dq[point_columns(lay, one[k])]) for k in range(b.n_points)]) * res.sigma0
    assert np.allclose(res.point_sigma, ref_ps, rtol=1e-6, atol=0)
    # the adjusted datum points satisfy the inner constraints against their starting coordinates
    X, X0 = res.block.point_xyz[mask], b.point_xyz[mask]
    c0 = X0.mean(axis=0)
    scale_m = np.sqrt(((X0 - c0) ** 2).sum(axis=1).mean())
    assert np.abs((X - X0).mean(axis=0)).max() < 1e-9 * scale_m
    assert np.abs(np.cross(X0 - c0, X - X0).sum(axis=0)).max() < 1e-9 * scale_m**2 * mask.sum()
    return out


@pytest.fixture(scope="module")
def runs():  # type: ignore[no-untyped-def]
    """The 24-image block adjusted in three datums: pose inner constraints, all points, 12 chosen points."""
    b = close_range_block(24)
    names = tuple(str(n) for n in b.point_name[::10])
    base = AdjustConfig(unknowns=Unknowns(datum="free", intrinsics="free"))
    cfgs = {"poses": base,
            "all": base.with_unknowns(inner_constraints="points").with_statistics(points=names[:3] + ("t1",),
                                                                                  images=("img0",)),
            "chosen": base.with_unknowns(inner_constraints="points", datum_points=names)}
    return b, names, {k: adjust(b, c) for k, c in cfgs.items()}


def test_inner_constraints_on_all_points_equal_the_bordered_dense_inverse(runs):  # type: ignore[no-untyped-def]
    b, _, res = runs
    out = check_point_datum(b, res["all"])
    assert out["n_unknowns"] > 500


def test_pose_datum_cross_cofactors_equal_the_bordered_dense_inverse(runs):  # type: ignore[no-untyped-def]
    """datum='free' with inner constraints on the poses: the Moore-Penrose inverse of the reduced normal matrix
    (poses, calibration, scale-bar end points) - i.e. the constraints on the reduced columns of the full normal
    matrix; every cofactor skyrig forms (reduced, reduced x point, point blocks) against the bordered inverse."""
    b, _, r = runs
    res = r["poses"]
    N = dense_full_normal(res)
    Qref = bordered_reference(N, np.arange(res.layout.n_c), 6)
    Q = skyrig_full_cofactors(res)
    sd = np.sqrt(np.diag(Qref))
    known = np.isfinite(Q)
    assert (np.abs(Q - Qref)[known] / np.outer(sd, sd)[known]).max() < 1e-6


def test_inner_constraints_on_chosen_points_and_minimum_trace(runs):  # type: ignore[no-untyped-def]
    b, names, r = runs
    check_point_datum(b, r["chosen"], names)
    # minimum trace: over the datum points, no other datum gives a smaller sum of variances (the pose datum and
    # the all-points datum are two others); over all points, the all-points datum beats the pose datum
    sig = {k: v.point_sigma for k, v in r.items()}
    sel = np.isin(b.point_name, names)
    tr = {k: float((s[sel] ** 2).sum()) for k, s in sig.items()}
    assert tr["chosen"] < tr["all"] and tr["chosen"] < tr["poses"], tr
    assert (sig["all"] ** 2).sum() < (sig["poses"] ** 2).sum()
    # datum-invariant quantities do not change: sigma0, redundancy, redundancy numbers, distances
    for k in ("all", "chosen"):
        assert r[k].sigma0 == pytest.approx(r["poses"].sigma0, rel=1e-6)
        assert r[k].redundancy == r["poses"].redundancy
        assert np.allclose(r[k].residuals["image"].redundancy, r["poses"].residuals["image"].redundancy, atol=1e-7)
        d = np.linalg.norm(r[k].block.point_xyz[3] - r[k].block.point_xyz[77])
        assert d == pytest.approx(np.linalg.norm(r["poses"].block.point_xyz[3] - r["poses"].block.point_xyz[77]),
                                  abs=1e-8)
    # the datum changes the covariance itself (the comparisons above are not vacuous)
    sp, sa = r["poses"].point_sigma, r["all"].point_sigma
    assert np.max(np.abs(sp - sa) / sa) > 0.1


def test_point_datum_errors_against_the_truth_are_consistent_with_the_sigmas(runs):  # type: ignore[no-untyped-def]
    b, _, r = runs
    res = r["all"]
    rng = np.random.default_rng(0)  # the true target field of close_range_block(seed=0)
    Xtrue = np.column_stack([rng.uniform(-1, 1, 120), rng.uniform(-1, 1, 120), rng.uniform(0, 0.8, 120)])
    # the datum is the starting coordinates' centroid/orientation: bring the truth into it (rigid fit)
    X = res.block.point_xyz
    mx, mt = X.mean(axis=0), Xtrue.mean(axis=0)
    U, _, Vt = np.linalg.svd((Xtrue - mt).T @ (X - mx))
    R = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt
    Xt = (Xtrue - mt) @ R + mx
    e = X - Xt
    chi2 = np.einsum("pa,pab,pb->p", e, np.linalg.inv(res.point_covariance()), e)
    # 120 points x 3 dof, minus the 6 fitted motions: mean about 2.95, a few percent scatter
    assert 2.4 < chi2.mean() < 3.6, chi2.mean()


def test_covariance_of_chosen_unknowns_is_exported_in_the_point_datum(runs, tmp_path):  # type: ignore[no-untyped-def]
    import json

    from skyrig.adjust.report import adjustment_report
    from skyrig.io.report_html import write_report_json

    b, names, r = runs
    res = r["all"]
    write_report_json(tmp_path / "report.json", adjustment_report(res))
    rep = json.loads((tmp_path / "report.json").read_text())
    assert "inner constraints on all estimated object points" in rep["summary"]["datum"]
    cov = rep["covariance"]
    assert cov["datum"] == rep["summary"]["datum"]
    # against the bordered dense reference of the full normal matrix, scaled by sigma0^2
    lay = res.layout
    N = dense_full_normal(res)
    Qref = bordered_reference(N, point_columns(lay, np.ones(b.n_points, bool)), 6) * res.sigma0**2
    want = names[:3] + ("t1",)
    assert [p["point"] for p in cov["points"]] == sorted(want, key=lambda n: int(n[1:]))
    pidx = {str(n): k for k, n in enumerate(b.point_name)}
    one = np.eye(b.n_points, dtype=bool)
    for p in cov["points"]:
        c = point_columns(lay, one[pidx[p["point"]]])
        ref = Qref[np.ix_(c, c)]
        assert np.allclose(p["covariance"], ref, rtol=1e-6, atol=1e-6 * np.sqrt(np.outer(np.diag(ref), np.diag(ref))).max())
        assert np.allclose(p["xyz"], res.block.point_xyz[pidx[p["point"]]])
    # every calibration unknown and the chosen image's pose; sigmas and correlations from the reference
    lab = [(u["group"], u["owner"], u["component"]) for u in cov["unknowns"]]
    assert sum(g == "intrinsics" for g, _, _ in lab) == len(b.cameras[0].intrinsic_names)
    assert sum(g == "pose" for g, _, _ in lab) == 6 and all(o == "st0" for g, o, _ in lab if g == "pose")
    cols = np.array([lay.labels.index(t) for t in lab])
    sref = np.sqrt(np.diag(Qref)[cols])
    assert np.allclose([u["sigma"] for u in cov["unknowns"]], sref, rtol=1e-6)
    Rref = Qref[np.ix_(cols, cols)] / np.outer(sref, sref)
    assert np.abs(np.array(cov["correlation"]) - Rref).max() < 1e-6
    intr = {c: u["value"] for (g, _, c), u in zip(lab, cov["unknowns"]) if g == "intrinsics"}
    cam = res.block.cameras[0]
    assert intr == pytest.approx(dict(zip(cam.intrinsic_names, np.asarray(cam.intrinsics).tolist())))
    # cross covariance of the chosen unknowns with the chosen points
    X = np.array(cov["cross_covariance"])
    for j, p in enumerate(cov["points"]):
        c = point_columns(lay, one[pidx[p["point"]]])
        ref = Qref[np.ix_(cols, c)]
        assert np.abs(X[:, j] - ref).max() < 1e-6 * np.outer(sref, np.sqrt(np.diag(Qref)[c])).max()


def test_datum_point_errors_are_named():
    b = close_range_block(8, n_targets=40)
    with pytest.raises(ValueError, match="unknown points"):
        adjust(b, AdjustConfig(unknowns=Unknowns(datum="free", inner_constraints="points", datum_points=("nope",))))
    with pytest.raises(ValueError, match="at least 3"):
        adjust(b, AdjustConfig(unknowns=Unknowns(datum="free", inner_constraints="points",
                                                 datum_points=("t1", "t2"))))
    with pytest.raises(ValueError, match="needs datum='free'"):
        AdjustConfig(unknowns=Unknowns(inner_constraints="points"))
    with pytest.raises(ValueError, match="datum_points"):
        AdjustConfig(unknowns=Unknowns(datum="free", datum_points=("t1", "t2", "t3")))


@pytest.mark.slow
def test_point_datum_100_images():
    b = close_range_block(100)
    out = check_point_datum(b, adjust(b, AdjustConfig(unknowns=Unknowns(datum="free", intrinsics="free",
                                                                        inner_constraints="points"))))
    print(out)
    assert out["n_unknowns"] >= 900


def test_free_datum_on_a_block_whose_observations_fix_the_datum_is_refused():
    """datum='free' on a block with control and GNSS used to run 50 iterations without converging, with
    the redundancy off by 7; now refused in words (the motions the observations fix, what to use)."""
    from skyrig.adjust import BlockError
    from skyrig.adjust.synthetic import synthetic_block

    b, _ = synthetic_block(seed=1, n_points=80)
    with pytest.raises(BlockError) as e:
        adjust(b, AdjustConfig(unknowns=Unknowns(datum="free")))
    msg = str(e.value)
    assert "control points" in msg and "GNSS positions" in msg and "translation along X" in msg
    assert "datum='auto'" in msg
    assert adjust(b, AdjustConfig()).ok  # the same block with its own datum is fine
