"""Report tables of an adjustment as plain data (paper 004 Tables 2-11 layouts); no I/O.

:func:`adjustment_report` returns a JSON-ready dict:

``summary``
    sigma0, observations, unknowns, redundancy, iterations, convergence, wall time.
``groups``
    per observation group: count, redundancy, variance factor, residual RMS per axis.
``control`` / ``check``
    one row per point ``{point, VX, VY, VZ, VXYZ}`` (metres, adjusted minus given; for control
    points the residual, for check points the true error) and a ``stats`` row: RMS per axis in metres
    and GSD, max |V| per axis against ``limits_m``.
``orientation``
    RMS of the photo positions against GNSS and of the attitudes against the IMU (per axis; metres,
    degrees), the GNSS block shift (mean GNSS residual, and the estimated datum shift).
``images``
    per camera: observations, residual RMS column/row and max (px).
``distances``
    (blocks with distance observations) one row per distance ``{point_a, point_b, observed_m,
    adjusted_m, residual_m, sigma_m, normalised, redundancy, used}`` (residual = adjusted - observed;
    normalised: Baarda's w, redundancy: the redundancy number; NaN when statistics were skipped) and
    a ``stats`` row (n, RMS residual, max |w|).
``covariance``
    the a-posteriori covariance of the chosen unknowns (:func:`covariance_table`): every reduced unknown that
    is not a station pose plus ``statistics_images`` / ``statistics_points``, in the datum stated.
``rejected``, ``warnings``
    data snooping rejections and near-singularities in words.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.adjust import AdjustmentResult
from skyrig.adjust.model import pad_actuator

__all__ = ["adjustment_report", "point_table", "distance_table", "covariance_table", "datum_words"]


def _rms(a: NDArray[np.float64]) -> list[float]:
    return np.sqrt(np.mean(a**2, axis=0)).tolist() if len(a) else [float("nan")] * a.shape[1]


def point_table(names: NDArray[np.str_], v: NDArray[np.float64], gsd_m: float | None,
                limits_m: tuple[float, float, float] | None) -> dict[str, Any]:
    """Rows ``{point, VX, VY, VZ, VXYZ}`` and RMS / max statistics of differences ``v (N, 3)`` (m)."""
    rows = [dict(point=str(n), VX=float(a), VY=float(b), VZ=float(c), VXYZ=float(np.linalg.norm([a, b, c])))
            for n, (a, b, c) in zip(names, v)]
    rms = _rms(v)
    stats: dict[str, Any] = dict(n=len(v), rms_m=rms, rms_xyz_m=float(np.sqrt(np.mean((v**2).sum(1)))) if len(v)
                                 else float("nan"), max_abs_m=np.abs(v).max(axis=0).tolist() if len(v) else
                                 [float("nan")] * 3, mean_m=v.mean(axis=0).tolist() if len(v) else [float("nan")] * 3)
    if gsd_m:
        stats["rms_gsd"] = (np.asarray(rms) / gsd_m).tolist()
    if limits_m is not None:
        stats["limits_m"] = list(limits_m)
        stats["within_limits"] = bool(len(v) == 0 or np.all(np.abs(v) <= np.asarray(limits_m)))
    return dict(rows=rows, stats=stats)


def distance_table(result: AdjustmentResult) -> dict[str, Any]:
    """Residual table of the distance observations (scale bars) of ``result`` (see module docstring)."""
    b = result.block
    g = result.residuals.get("distance")
    n = b.n_distances
    nan = np.full(n, np.nan)
    v = g.residual[:, 0] if g is not None else nan
    w = g.normalised[:, 0] if g is not None and g.normalised is not None else nan
    rr = g.redundancy[:, 0] if g is not None and g.redundancy is not None else nan
    used = g.weight > 0 if g is not None else np.ones(n, bool)
    dp = b.distance_point
    adj = np.linalg.norm(b.point_xyz[dp[:, 0]] - b.point_xyz[dp[:, 1]], axis=1)
    rows = [dict(point_a=str(b.point_name[i]), point_b=str(b.point_name[j]), observed_m=float(o), adjusted_m=float(a),
                 residual_m=float(x), sigma_m=float(sg), normalised=float(wi), redundancy=float(ri), used=bool(u))
            for (i, j), o, a, x, sg, wi, ri, u in zip(dp, b.distance_m, adj, v, b.distance_sigma_m, w, rr, used)]
    stats = dict(n=int(used.sum()), rms_m=float(np.sqrt(np.mean(v[used] ** 2))) if used.any() else float("nan"),
                 max_abs_normalised=float(np.nanmax(np.abs(w[used]))) if used.any() and np.isfinite(w[used]).any()
                 else float("nan"))
    return dict(rows=rows, stats=stats)


def datum_words(result: AdjustmentResult) -> str:
    """The datum of ``result``'s adjusted values and covariance, in words."""
    cfg = result.config
    if cfg.unknowns.datum == "free" and cfg.unknowns.inner_constraints == "points":
        which = (f"{len(cfg.unknowns.datum_points)} chosen points" if cfg.unknowns.datum_points else "all estimated object points")
        kept = "centroid and orientation" if result.block.n_distances else "centroid, orientation and scale"
        return (f"inner constraints on {which} (free network: their {kept} are those of their starting "
                "coordinates; minimum trace of their covariance)")
    if cfg.unknowns.datum == "free":
        return "inner constraints on the station poses (free network: minimum norm of the pose corrections)"
    if cfg.unknowns.datum == "none":
        return "none (no covariance)"
    return "observations (control points and/or GNSS positions)"


def covariance_table(result: AdjustmentResult, max_unknowns: int = 2000) -> dict[str, Any] | None:
    """The a-posteriori covariance of the chosen unknowns of ``result`` as JSON-ready data (None without
    statistics).

    ``unknowns``: ``[{group, owner, component, value, sigma}]`` (units of the parameter: m, rad, the
    camera's intrinsic units); ``correlation``: their correlation matrix (rows in that order; left out above
    ``max_unknowns``); ``points``: ``[{point, xyz, sigma, covariance}]`` (m, m²) for the chosen points;
    ``cross_covariance``: ``(unknowns, points, 3)`` covariances between the two (left out above
    ``max_unknowns``).  ``sigma0`` scales the cofactors (``covariance = sigma0² Q``); ``datum`` says in which
    datum they hold.
    """
    sel = result.selected
    if sel is None:
        return None
    s0 = float(result.sigma0)
    b = result.block
    Q = sel.Qcc
    sd = np.sqrt(np.clip(np.diag(Q), 0, None))
    value = _reduced_values(result, sel.columns)
    out: dict[str, Any] = dict(datum=datum_words(result), sigma0=s0, method=sel.method, unknowns=[
        dict(group=g, owner=o, component=c, value=v, sigma=s0 * float(d))
        for (g, o, c), v, d in zip(sel.labels, value, sd)])
    if len(Q) <= max_unknowns:
        with np.errstate(divide="ignore", invalid="ignore"):
            R = np.where(np.outer(sd, sd) > 0, Q / np.outer(sd, sd), 0.0)
        out["correlation"] = np.round(R, 12).tolist()
    out["points"] = [dict(point=str(b.point_name[k]), xyz=b.point_xyz[k].tolist(),
                          sigma=(s0 * np.sqrt(np.clip(np.diag(q), 0, None))).tolist(), covariance=(s0**2 * q).tolist())
                     for k, q in zip(sel.points, sel.Qpp)]
    if len(sel.points) and len(Q) <= max_unknowns:
        out["cross_covariance"] = (s0**2 * sel.Qcp).tolist()
    return out


def _reduced_values(result: AdjustmentResult, columns: NDArray[np.int64]) -> list[float]:
    """Adjusted values of reduced columns (NaN where the layout does not say)."""
    lay, b = result.layout, result.block
    val = np.full(lay.n_c, np.nan)

    def put(cols: NDArray[np.int64], v: NDArray[np.float64]) -> None:
        cols, v = np.asarray(cols).reshape(-1), np.asarray(v, float).reshape(-1)
        on = cols >= 0
        val[cols[on]] = v[on]

    put(lay.pose[:, :3], b.station_centre)
    for k, cam in enumerate(b.cameras):
        if k < len(lay.intr):
            put(lay.intr[k], np.asarray(cam.intrinsics))
    put(lay.bore, b.head_boresight)
    put(lay.lever, b.lever_arm)
    put(lay.shift, b.datum_shift)
    put(lay.sshift, b.strip_shift)
    put(lay.sdrift, b.strip_drift)
    if lay.has_rpoint:
        put(lay.rpoint_cols, b.point_xyz)
    if lay.act is not None and b.actuator_correction is not None:
        put(lay.act, pad_actuator(b.actuator_correction, lay.act.shape[0], lay.act.shape[1]))
    return val[columns].tolist()


def _group_labels(group: str) -> dict[str, Any]:
    """The report labels of an observation group from its type (:mod:`skyrig.adjust.factors`)."""
    from skyrig.adjust.factors import observation_type

    t = observation_type(group)
    if t is None:
        return {}
    return dict(words=t.words, components=list(t.components), units=t.units)


def adjustment_report(result: AdjustmentResult, gsd_m: float | None = None,
                      limits_m: tuple[float, float, float] | None = None,
                      check_xyz: NDArray[np.float64] | None = None,
                      frames: tuple[Any, Any] | None = None) -> dict[str, Any]:
    """All report tables of ``result`` (module docstring).

    Parameters
    ----------
    gsd_m
        Ground sampling distance for RMS in GSD units.
    limits_m
        Maximum allowed |V| per axis for control/check tables.
    check_xyz
        Optional ``(K, 3)`` given coordinates for the block's control rows (default ``control_xyz``).
    frames
        ``(block_frame, project_frame)`` (:class:`skyrig.geodesy.WorldFrame`): the control / check tables are
        then adjusted minus given in the project CRS (grid east, grid north, height as stated), and the summary
        states the project frame (``frame``, ``vertical``) and the frame the adjustment ran in (``adjusted_in``).
    """
    b, b0 = result.block, result.initial
    info = result.info
    out: dict[str, Any] = {
        "summary": dict(frame=b.frame.text, sigma0=result.sigma0, observations=result.n_observations,
                        unknowns=result.n_unknowns, redundancy=result.redundancy, iterations=info.iterations,
                        converged=info.converged, message=info.message, wall_s=info.wall_s,
                        initial_cost=info.initial_cost, final_cost=info.final_cost, images=b.n_images,
                        stations=b.n_stations, points=b.n_points, image_observations=b.n_observations),
        "groups": {g: dict(n=s.n_rows, redundancy=s.redundancy, variance_factor=s.sigma0, rms=s.rms,
                           **_group_labels(g))
                   for g, s in result.groups.items()},
    }
    given = b0.control_xyz if check_xyz is None else np.asarray(check_xyz, float)
    cp = b0.control_point
    if frames is not None and len(cp):
        f, to = frames
        v = f.points_to(b.point_xyz[cp], to) - f.points_to(given, to)
    else:
        v = b.point_xyz[cp] - given
    if frames is not None:
        from skyrig.geodesy.statement import crs_statement

        f, to = frames
        out["summary"]["adjusted_in"] = f.to_text()
        out["summary"]["frame"] = to.to_text()
        out["summary"]["vertical"] = crs_statement(to)[1]
    chk = b0.control_check
    out["control"] = point_table(b.point_name[cp[~chk]], v[~chk], gsd_m, limits_m)
    out["check"] = point_table(b.point_name[cp[chk]], v[chk], gsd_m, limits_m)
    orient: dict[str, Any] = {}
    if "gnss" in result.residuals:
        r = result.residuals["gnss"].residual
        orient["gnss_rms_m"] = _rms(r)
        orient["gnss_block_shift_m"] = (-r.mean(axis=0)).tolist()  # mean (GNSS - adjusted)
        orient["gnss_n"] = len(r)
    orient["datum_shift_m"] = b.datum_shift.tolist()
    orient["lever_arm_m"] = b.lever_arm.tolist()
    if "imu" in result.residuals:
        r = np.degrees(result.residuals["imu"].residual)
        orient["imu_rms_deg"] = _rms(r)
        orient["imu_mean_deg"] = r.mean(axis=0).tolist()
    orient["boresight_deg"] = {str(h): np.degrees(v).tolist() for h, v in zip(b.head_name, b.head_boresight)}
    orient["cameras"] = {c.name: dict(zip(c.intrinsic_names, np.asarray(c.intrinsics).tolist())) for c in b.cameras}
    sr = result.sigma_reduced()
    if sr:
        orient["sigma"] = {" ".join(k): v for k, v in sr.items() if k[0] != "pose"}
        ps = result.pose_sigma
        if ps is not None and np.isfinite(ps).any():
            orient["pose_sigma_rms"] = dict(centre_m=np.sqrt(np.nanmean(ps[:, :3] ** 2, axis=0)).tolist(),
                                            rotation_deg=np.degrees(np.sqrt(np.nanmean(ps[:, 3:] ** 2, axis=0))).tolist())
    out["orientation"] = orient
    img = result.residuals["image"]
    cams = {}
    cam_of_obs = b.image_camera[b.obs_image]
    act = img.weight > 0
    for k, c in enumerate(b.cameras):
        sel = (cam_of_obs == k) & act
        if not sel.any():
            continue
        r = img.residual[sel]
        cams[c.name] = dict(n=int(sel.sum()), rms_px=_rms(r), max_abs_px=np.abs(r).max(axis=0).tolist())
    out["images"] = cams
    if b0.n_distances:
        out["distances"] = distance_table(result)
    cov = covariance_table(result, max_unknowns=500)
    if cov is not None:
        out["covariance"] = cov
    out["summary"]["datum"] = datum_words(result)
    out["rejected"] = [dict(group=r.group, index=r.index, label=r.label, normalised_residual=r.normalised_residual)
                       for r in result.rejected]
    out["warnings"] = list(result.warnings)
    return out
