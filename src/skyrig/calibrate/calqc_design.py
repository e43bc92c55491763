"""The ``calqc`` design study: the flight's geometry (heights, directions), which calibration unknowns it cannot
separate and why in words, and which added flight (virtual: another height, direction or a cross strip) would
separate them (:mod:`skyrig.calibrate.calqc` module docstring).
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.adjust import AdjustmentResult, adjust
from skyrig.adjust.block import AdjustConfig, Block
from skyrig.calibrate.calqc_common import _cal_labels
from skyrig.errors import SkyrigError

log = logging.getLogger("skyrig.calibrate.calqc")  # the recipe's log, whichever part writes

__all__ = ["flight_geometry", "separability", "CANDIDATE_FLIGHTS", "virtual_flight", "design_study"]


def flight_geometry(block: Block, height_gap: float = 0.25) -> dict[str, Any]:
    """Flying heights (clusters of station heights above the points' median) and strip directions (headings
    of the stations' body x axis, folded to 0..180 to find opposite pairs) of a rig block."""
    z = block.station_centre[:, 2] - float(np.median(block.point_xyz[:, 2]))
    order = np.argsort(z)
    zs = z[order]
    cut = np.flatnonzero(np.diff(zs) > height_gap * np.maximum(zs[:-1], 1.0))
    level = np.zeros(len(z), np.int64)
    level[order] = np.searchsorted(cut, np.arange(len(z)), side="left")
    heights = [float(np.median(z[level == k])) for k in range(level.max() + 1)]
    x = block.station_rotation[:, :, 0]
    head = np.degrees(np.arctan2(x[:, 0], x[:, 1])) % 360.0
    # group headings into 30-degree sectors
    sectors = sorted({int(((h + 15.0) % 360.0) // 30.0) for h in head})
    dirs = [float(s * 30.0) for s in sectors]
    opposite = any(((a + 180.0) % 360.0) in dirs for a in dirs)
    return {"heights_m": heights, "station_level": level, "headings_deg": dirs, "opposite_directions": bool(opposite),
            "heading_per_station_deg": head}


def _words(lab: tuple[str, str, str]) -> str:
    g, o, c = lab
    if g == "boresight":
        return f"boresight {o} {c}"
    if g == "intrinsics":
        return {"focal_mm": f"principal distance of {o}", "ppx_mm": f"principal point x of {o}",
                "ppy_mm": f"principal point y of {o}"}.get(c, f"{c} of {o}")
    if g == "datum_shift":
        return f"GNSS datum shift {c}"
    return f"{g} {o} {c}"


def _separating_flight(a: tuple[str, str, str], b: tuple[str, str, str], geom: Mapping[str, Any]) -> str:
    kinds = {a[0], b[0]}
    comps = {a[2], b[2]}
    n_h = len(geom["heights_m"])
    opp = geom["opposite_directions"]
    if kinds == {"boresight", "datum_shift"} or kinds == {"lever_arm", "datum_shift"}:
        want = []
        if not opp:
            want.append("strips flown in the opposite direction (a boresight or lever arm turns with the aircraft, "
                        "a datum shift does not)")
        if n_h < 2 and "lever_arm" not in kinds:
            want.append("a second flying height (the ground displacement of a boresight grows with the height, that "
                        "of a datum shift does not)")
        return " or ".join(want) or "more ground control across the block"
    if kinds == {"intrinsics", "datum_shift"} and "focal_mm" in comps:
        return ("a second flying height (a principal-distance error scales the heights, a vertical shift does not)"
                if n_h < 2 else "more relief or ground control at other heights")
    if kinds == {"intrinsics", "boresight"} or kinds == {"intrinsics"}:
        return ("no flight pattern separates them fully (both turn with the camera); strips in the opposite direction "
                "at a second height, relief and points across the whole image format help; or lock the principal "
                "point at a laboratory (cage) calibration")
    if kinds == {"boresight"}:
        return "strips in the opposite direction and cross strips"
    return "strips in the opposite direction at a second flying height"


def separability(res: AdjustmentResult, geom: Mapping[str, Any], limit: float = 0.95) -> list[dict[str, Any]]:
    """Pairs of calibration unknowns correlated beyond ``limit`` (|r|), each named in words with the flight
    that would separate it (see the module docstring)."""
    labels, cov = _cal_labels(res)
    s = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        R = cov / np.outer(s, s)
    out = []
    for i in range(len(labels)):
        for j in range(i + 1, len(labels)):
            r = float(R[i, j])
            if np.isfinite(r) and abs(r) >= limit:
                a, b = labels[i], labels[j]
                out.append({"unknowns": [list(a), list(b)], "correlation": r,
                            "text": f"{_words(a)} and {_words(b)} are inseparable in this flight (correlation {r:+.3f})",
                            "separating_flight": _separating_flight(a, b, geom)})
    out.sort(key=lambda e: -abs(e["correlation"]))
    return out


# ------------------------------------------------------------------------------------------------ design study
#: flights a design study can add to the flown one (:func:`virtual_flight`), with what each is in words
CANDIDATE_FLIGHTS = {
    "opposite-direction": "every strip flown again in the opposite direction",
    "cross-strips": "every strip flown again at right angles (cross strips)",
    "second-height": "every strip flown again at twice the height above ground",
}


def _rot_z(a: float) -> NDArray[np.float64]:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def virtual_flight(block: Block, kind: str, margin_px: float = -2.0) -> Block:
    """The block plus a virtual flight of the same rig (``kind`` one of :data:`CANDIDATE_FLIGHTS`): every station
    again, turned 180 deg (``opposite-direction``) or 90 deg (``cross-strips``) about the vertical, or at twice its
    height above the points' median (``second-height``); each new image observes every object point that projects
    into its format in front of it (the current values of all unknowns, so its observations are exact), its
    station has GNSS and IMU observations like the flown ones (same sigmas).  Its covariance is the design's: what
    the calibration unknowns' precision and correlations would be had that flight been flown too
    (:func:`design_study`)."""
    from skyrig.adjust.model import Model, State

    if kind not in CANDIDATE_FLIGHTS:
        raise SkyrigError(f"virtual flight {kind!r}: expected one of {sorted(CANDIDATE_FLIGHTS)}")
    b = block
    S, nI = b.n_stations, b.n_images
    R = b.station_rotation.copy()
    C = b.station_centre.copy()
    if kind == "second-height":
        g = float(np.median(b.point_xyz[:, 2]))
        C[:, 2] = g + 2.0 * (C[:, 2] - g)
    else:
        R = np.einsum("ij,sjk->sik", _rot_z(np.pi if kind == "opposite-direction" else 0.5 * np.pi), R)
    # the new images: one per flown image, on the new station (the adjustment's own image poses of the moved stations)
    moved = State.from_block(b)
    moved.R, moved.C = R, C
    Rw, Cw, _ = Model(b, AdjustConfig()).camera_poses(moved)
    sig = np.asarray(b.obs_sigma_px, float)
    sig_cam = {}
    for ci in range(len(b.cameras)):
        sel = b.image_camera[b.obs_image] == ci
        sig_cam[ci] = (np.median(sig[sel], axis=0) if sig.ndim and sel.any() else
                       (np.full(2, float(sig)) if not sig.ndim else np.median(sig.reshape(-1, 2), axis=0)))
    oi, op, ox, os_ = [], [], [], []
    for i in range(nI):
        cam = b.cameras[b.image_camera[i]]
        pc = (b.point_xyz - Cw[i]) @ Rw[i]
        front = pc[:, 2] < 0
        if not front.any():
            continue
        idx = np.flatnonzero(front)
        px = cam.project_pixels(pc[idx])
        ok = np.all(np.isfinite(px), axis=1) & cam.in_image(px, margin_px)
        if not ok.any():
            continue
        idx = idx[ok]
        oi.append(np.full(idx.size, nI + i))
        op.append(idx)
        ox.append(px[ok])
        os_.append(np.broadcast_to(sig_cam[int(b.image_camera[i])], (idx.size, 2)))
    if not oi:
        raise SkyrigError(f"virtual flight {kind!r}: no object point projects into any of its images")
    n_new = sum(len(x) for x in oi)
    kw: dict[str, Any] = {}
    kw["obs_image"] = np.concatenate([b.obs_image, *oi])
    kw["obs_point"] = np.concatenate([b.obs_point, *op])
    kw["obs_pixel"] = np.concatenate([b.obs_pixel, *ox])
    new_sig = np.concatenate(os_)
    kw["obs_sigma_px"] = (np.concatenate([sig, new_sig]) if sig.ndim == 2 else
                          np.concatenate([np.broadcast_to(sig, (b.n_observations, 2)), new_sig]))
    if b.obs_cov_px2 is not None:
        kw["obs_cov_px2"] = np.concatenate([b.obs_cov_px2, new_sig[:, :, None] ** 2 * np.eye(2)])
    kw["station_name"] = np.concatenate([b.station_name, np.char.add(b.station_name.astype(str), f"~{kind}")])
    kw["station_rotation"] = np.concatenate([b.station_rotation, R])
    kw["station_centre"] = np.concatenate([b.station_centre, C])
    kw["station_time"] = np.concatenate([b.station_time, b.station_time])
    kw["station_strip"] = np.concatenate([b.station_strip, np.full(S, -1, np.int64)])
    kw["strip_t0"] = b.strip_t0
    kw["image_name"] = np.concatenate([b.image_name, np.char.add(b.image_name.astype(str), f"~{kind}")])
    for f in ("image_camera", "image_rotation", "image_offset", "image_head", "image_beta_rad"):
        kw[f] = np.concatenate([getattr(b, f), getattr(b, f)])
    kw["image_station"] = np.concatenate([b.image_station, b.image_station + S])
    if b.gnss_station is not None and len(b.gnss_station):
        gs = b.gnss_station
        kw["gnss_station"] = np.concatenate([gs, gs + S])
        kw["gnss_xyz"] = np.concatenate([b.gnss_xyz, C[gs] + R[gs] @ b.lever_arm + b.datum_shift])
        for f in ("gnss_sigma", "gnss_cov_m2"):
            v = getattr(b, f, None)
            if v is not None and np.ndim(v) and len(v) == len(gs):
                kw[f] = np.concatenate([v, v])
    if b.imu_station is not None and len(b.imu_station):
        ms = b.imu_station
        kw["imu_station"] = np.concatenate([ms, ms + S])
        kw["imu_rotation"] = np.concatenate([b.imu_rotation, R[ms]])
        for f in ("imu_sigma_rad", "imu_cov_rad2"):
            v = getattr(b, f, None)
            if v is not None and np.ndim(v) and len(v) == len(ms):
                kw[f] = np.concatenate([v, v])
    log.debug("virtual flight %s: %d stations, %d images, %d observations", kind, S, nI, n_new)
    return replace(b, **kw)


def _multiple_correlation(cov: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Correlation matrix and, per unknown, its multiple correlation with all the others
    (``sqrt(1 - 1 / (R^-1)_ii)``: how well the others together can stand in for it)."""
    s = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    R = cov / np.outer(s, s)
    Ri = np.linalg.pinv(R, hermitian=True)
    rho = np.sqrt(np.clip(1.0 - 1.0 / np.maximum(np.diag(Ri), 1.0), 0.0, 1.0))
    return R, rho


def _owner(lab: tuple[str, str, str]) -> str:
    return lab[1] if lab[0] in ("boresight", "intrinsics") else {"datum_shift": "GNSS"}.get(lab[0], lab[0])


def design_study(res: AdjustmentResult, geom: Mapping[str, Any], cfg: AdjustConfig, limit: float = 0.95,
                 excess_limit: float = 1.25, flights: Sequence[str] | None = None) -> dict[str, Any]:
    """Which calibration unknowns this flight cannot separate, per head, and which flight would separate them.

    From the adjustment's covariance of the calibration unknowns (boresights, IO, datum shift): each unknown's
    multiple correlation ``rho`` with all the others together (a group, not only a pair, can stand in for it) and
    its partners (the unknowns it correlates with most).  For each flight this one lacks (:data:`CANDIDATE_FLIGHTS`:
    the opposite direction when every strip is flown one way, cross strips when no two headings are at right
    angles, a second height when there is one; or ``flights``) the design with that flight added
    (:func:`virtual_flight`) gives every unknown's ``rho`` and sigma again.  More observations alone shrink every
    sigma by ``sqrt(n_with / n_flown)`` (``n``: image observations); the **excess gain** of a flight for an unknown
    is its sigma ratio beyond that.  An unknown is named

    * *separated by a flight* when a candidate's excess gain is at least ``excess_limit`` (the flight shrinks its
      sigma by a quarter more than its added observations alone would: it resolves a correlation this flight
      leaves), or when its ``rho`` exceeds ``limit`` here and not with a candidate; the flight named is the one with
      the largest excess gain;
    * *inseparable in every flight tried* when its ``rho`` exceeds ``limit`` here and with every candidate (e.g. a
      principal point and the boresight rotation about the other image axis: both shift the image; only a
      laboratory calibration or a lock separates them)."""
    labels, cov = _cal_labels(res)
    R, rho = _multiple_correlation(cov)
    sig = np.sqrt(np.diag(cov))
    b = res.block
    cam_head = {}
    for i in range(b.n_images):
        cam_head.setdefault(b.cameras[int(b.image_camera[i])].name, str(b.head_name[int(b.image_head[i])]))
    if flights is None:
        heads = [float(h) for h in geom["headings_deg"]]
        right = any(any(abs(((a - c) % 180.0) - 90.0) < 20.0 for c in heads) for a in heads)
        flights = [k for k, lack in (("opposite-direction", not geom["opposite_directions"]),
                                     ("cross-strips", not right), ("second-height", len(geom["heights_m"]) < 2)) if lack]
    s0 = float(res.sigma0)
    cand: dict[str, dict[str, Any]] = {}
    for k in flights:
        vb = virtual_flight(b, k)
        vr = adjust(vb, cfg.with_reliability(snooping=False).with_solver(max_iterations=1).with_statistics(compute=True))
        lv, cv = _cal_labels(vr)
        if s0 > 0 and vr.sigma0 > 0:  # the design's cofactors at the flown flight's variance factor
            cv = cv / vr.sigma0 ** 2 * s0 ** 2
        pos = {lab: j for j, lab in enumerate(lv)}
        ix = [pos[lab] for lab in labels]
        cv = cv[np.ix_(ix, ix)]
        _, rv = _multiple_correlation(cv)
        more = float(np.sqrt(vb.n_observations / b.n_observations))
        cand[k] = {"flight": CANDIDATE_FLIGHTS[k], "rho": rv, "sigma": np.sqrt(np.diag(cv)), "data_gain": more,
                   "images_added": int(vb.n_images - b.n_images),
                   "observations_added": int(vb.n_observations - b.n_observations)}

    def head_of(lab: tuple[str, str, str]) -> str:
        if lab[0] == "intrinsics":
            return cam_head.get(lab[1], lab[1])
        return lab[1] if lab[0] == "boresight" else {"datum_shift": "GNSS"}.get(lab[0], lab[0])

    named, structural = [], []
    for i, lab in enumerate(labels):
        gain = {k: float(sig[i] / c["sigma"][i]) for k, c in cand.items()}
        excess = {k: gain[k] / c["data_gain"] for k, c in cand.items()}
        r = R[i].copy()
        r[i] = 0.0
        order = np.argsort(-np.abs(r))
        partners = [{"unknown": list(labels[j]), "words": _words(labels[j]), "correlation": float(r[j])}
                    for j in order[:3] if abs(r[j]) >= 0.5] or [
            {"unknown": list(labels[order[0]]), "words": _words(labels[order[0]]), "correlation": float(r[order[0]])}]
        with_txt = ", ".join(f"{p['words']} r {p['correlation']:+.3f}" for p in partners)
        entry = {"head": head_of(lab), "unknown": list(lab), "words": _words(lab), "sigma": float(sig[i]),
                 "multiple_correlation": float(rho[i]), "partners": partners,
                 "with_flight": {k: {"multiple_correlation": float(c["rho"][i]), "sigma": float(c["sigma"][i]),
                                     "sigma_gain": gain[k], "excess_gain": excess[k]} for k, c in cand.items()}}
        lowered = [k for k in cand if rho[i] > limit and cand[k]["rho"][i] <= limit]
        if cand and (max(excess.values()) >= excess_limit or lowered):
            best = max(excess, key=lambda k: excess[k])
            c = cand[best]
            entry.update(kind="separated by a flight", separating_flight=best, text=(
                f"{_words(lab)}: sigma {sig[i]:.3g}, multiple correlation {rho[i]:.3f} (with {with_txt}); "
                f"{c['flight']} ({best}) would shrink its sigma {gain[best]:.2f} times ({excess[best]:.2f} beyond its "
                f"added observations) and its multiple correlation to {c['rho'][i]:.3f}"))
            named.append(entry)
        elif rho[i] > limit:
            tried = ", ".join(f"{k} {cand[k]['rho'][i]:.3f}" for k in cand) or "no flight tried"
            entry.update(kind="inseparable in every flight tried", separating_flight=None, text=(
                f"{_words(lab)}: multiple correlation {rho[i]:.3f} (with {with_txt}), still above {limit} with "
                f"{tried}: a laboratory (cage) calibration or locking it separates it, no flight pattern"))
            structural.append(entry)
    by_head: dict[str, list[dict[str, Any]]] = {}
    for e in named + structural:
        by_head.setdefault(e["head"], []).append(e)
    return {"limit": limit, "excess_limit": excess_limit, "labels": [list(lab) for lab in labels],
            "correlation": R.tolist(),
            "flights_tried": {k: {"flight": c["flight"], "images_added": c["images_added"],
                                  "observations_added": c["observations_added"], "data_gain": c["data_gain"]}
                              for k, c in cand.items()},
            "unknowns": [{"unknown": list(lab), "head": head_of(lab), "sigma": float(sig[i]),
                          "multiple_correlation": float(rho[i]),
                          "with_flight": {k: {"multiple_correlation": float(c["rho"][i]), "sigma": float(c["sigma"][i])}
                                          for k, c in cand.items()}} for i, lab in enumerate(labels)],
            "by_head": by_head}
