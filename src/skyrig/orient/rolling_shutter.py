"""Rolling shutter in the UAV GNSS-supported adjustment (issue 28 item 3): which cameras have one, and the
velocity prior of each station from the GNSS positions and the image times.

The model itself is :mod:`skyrig.adjust.factors.rolling_shutter`; this module decides whether
:func:`skyrig.orient.gnss_block.adjust_uav_block` uses it (``UavConfig.rolling_shutter``: ``"auto"`` = on for the
camera models known to read out row by row, :data:`KNOWN_ROLLING_SHUTTER`, and for phone cameras) and builds the
block's ``rolling_shutter`` data.  Layer 2b, arrays only.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.factors.rolling_shutter import MOTION, NAME, READOUT, RollingShutter

__all__ = ["KNOWN_ROLLING_SHUTTER", "PHONE_MAKES", "rolling_shutter_decision", "velocity_prior", "velocity_neighbours", "with_rolling_shutter",
           "rolling_shutter_summary"]

#: EXIF ``Model`` of drone cameras with an electronic rolling shutter (DJI's published specifications: Phantom 3
#: FC300S/X/C, Phantom 4 FC330, Mavic Pro FC220, Mavic Air FC2103, Mavic 2 Zoom FC2204 and Pro L1D-20c, Mavic Air 2
#: FC3170, Air 2S FC3411, Mini FC7203, Mini 2 FC7303, Mini 3 Pro FC3582).  Not in the list: the Phantom 4 Pro / RTK
#: (FC6310, FC6310R, FC6310S), whose mechanical leaf shutter exposes the frame at once.
KNOWN_ROLLING_SHUTTER = ("FC300S", "FC300X", "FC300C", "FC330", "FC220", "FC2103", "FC2204", "L1D-20C", "FC3170",
                         "FC3411", "FC7203", "FC7303", "FC3582")
#: sigma (m/s) of the zero velocity prior of a station without a velocity from the trajectory
UNKNOWN_SPEED_M_S = 20.0
#: EXIF ``Make`` of phone makers (every phone camera reads out row by row)
PHONE_MAKES = ("APPLE", "SAMSUNG", "GOOGLE", "HUAWEI", "XIAOMI", "ONEPLUS", "SONY MOBILE", "MOTOROLA", "OPPO", "HMD")


def rolling_shutter_decision(mode: str, make: str, model: str) -> tuple[bool, str]:
    """Whether the model is used (``mode`` "on", "off" or "auto") and why, in words."""
    if mode == "on":
        return True, "rolling shutter modelled (rolling_shutter: on)"
    if mode == "off":
        return False, "rolling shutter not modelled (rolling_shutter: off)"
    m, k = model.strip().upper(), make.strip().upper()
    if m in KNOWN_ROLLING_SHUTTER:
        return True, f"rolling shutter modelled: the {model} reads out row by row (rolling_shutter: auto)"
    if k in PHONE_MAKES or m.startswith("IPHONE"):
        return True, f"rolling shutter modelled: a phone camera ({make} {model}) (rolling_shutter: auto)"
    what = f"the camera {make} {model}".strip() if (make or model) else "the camera (no EXIF make / model)"
    return False, f"rolling shutter not modelled: {what} is not known to have one (rolling_shutter: auto)"


def velocity_neighbours(times_s: NDArray[np.float64] | None, n: int, max_gap_s: float = 30.0
                        ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """For each of ``n`` images, the images ``(a, b)`` whose positions give its velocity (its neighbours in time:
    central differences; one-sided at the ends and where one neighbour is more than 3 x farther in time than the
    other: a turn between strips) and ``dt = t_b - t_a``; ``(-1, -1)`` where the times are missing or the
    neighbours more than ``max_gap_s`` away."""
    pair = np.full((n, 2), -1, np.int64)
    span = np.full(n, np.nan)
    if times_s is None or n < 2:
        return pair, span
    t = np.asarray(times_s, float)
    ok = np.flatnonzero(np.isfinite(t))
    order = ok[np.argsort(t[ok], kind="stable")]
    for j, k in enumerate(order):
        a = order[max(j - 1, 0)]
        b = order[min(j + 1, len(order) - 1)]
        before, after = t[k] - t[a], t[b] - t[k]
        if a != k and b != k and before > 3 * after:  # a turn or a pause before: the next image only
            a = k
        elif a != k and b != k and after > 3 * before:
            b = k
        dt = t[b] - t[a]
        if a == b or dt <= 0 or dt > 2 * max_gap_s:
            continue
        pair[k] = a, b
        span[k] = dt
    return pair, span


def velocity_prior(gnss: NDArray[np.float64], times_s: NDArray[np.float64] | None, gnss_sigma_m: Any,
                   floor_m_s: float, max_gap_s: float = 30.0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Velocity ``(I, 3)`` m/s and its sigma ``(I, 3)`` of every image from the GNSS positions of its neighbours in
    time (:func:`velocity_neighbours`); NaN where the times are missing or the neighbours more than
    ``max_gap_s`` away.  Sigma: the GNSS noise over the time span, at least ``floor_m_s`` (turns, gusts, a
    whole-second clock)."""
    n = len(gnss)
    pair, dt = velocity_neighbours(times_s, n, max_gap_s)
    v = np.full((n, 3), np.nan)
    s = np.full((n, 3), np.nan)
    ok = pair[:, 0] >= 0
    g_sig = np.broadcast_to(np.asarray(gnss_sigma_m, float), (3,))
    v[ok] = (gnss[pair[ok, 1]] - gnss[pair[ok, 0]]) / dt[ok, None]
    s[ok] = np.maximum(np.sqrt(2.0) * g_sig / dt[ok, None], floor_m_s)
    return v, s


def with_rolling_shutter(block: Any, camera_name: str, v: NDArray[np.float64], v_sigma: NDArray[np.float64],
                         readout_s: float, readout_sigma_s: float, angular_sigma_rad_s: float | None,
                         between: NDArray[np.int64] | None = None, dt_s: NDArray[np.float64] | None = None) -> Any:
    """``block`` (one station per image, in the order of ``v``) with the ``rolling_shutter`` data: every station's
    velocity prior where known (the starting velocity), else zero with a sigma of :data:`UNKNOWN_SPEED_M_S` (a
    drone's top speed: the velocity is then the images' alone), the readout prior, the angular prior.
    ``between`` / ``dt_s`` (:func:`velocity_neighbours`, a block without GNSS): where given, the prior is the
    velocity from the block's own centres of the two stations (``v`` is then only the starting value)."""
    have = np.isfinite(v).all(axis=1) & np.isfinite(v_sigma).all(axis=1)
    vp = np.where(have[:, None], v, 0.0)
    vs = np.where(have[:, None], v_sigma, UNKNOWN_SPEED_M_S)
    rel: dict[str, Any] = {}
    if between is not None:
        pair = np.where(have[:, None], np.asarray(between, np.int64), -1)
        rel = dict(velocity_between=pair, velocity_dt_s=np.where(pair[:, 0] >= 0, dt_s, 1.0),
                   velocity_m_s=np.where((pair[:, 0] >= 0)[:, None], 0.0, vp))
    rs = RollingShutter(cameras=[camera_name], readout_s=readout_s, readout_sigma_s=readout_sigma_s,
                        velocity_station=np.arange(len(v)), velocity_m_s=rel.pop("velocity_m_s", vp),
                        velocity_sigma_m_s=vs, angular_sigma_rad_s=angular_sigma_rad_s, **rel)
    start = np.zeros((block.n_stations, 6))
    start[:, :3] = vp
    obs = dict(block.observations)
    obs[NAME] = rs
    params = dict(block.parameters)
    params[MOTION] = start
    return dataclasses.replace(block, observations=obs, parameters=params)


def rolling_shutter_summary(res: Any, on: bool, words: str) -> dict[str, Any]:
    """The report's rolling-shutter figures: whether it was modelled and why, the readout time's estimate, formal
    sigma and prior, the stations with a velocity prior and the median speed and angular rate estimated."""
    out: dict[str, Any] = {"modelled": bool(on), "why": words}
    d = res.block.observations.get(NAME)
    if not on or d is None:
        return out
    cam = str(d.cameras[0])
    ro = float(res.block.parameters[READOUT][0, 0])
    try:
        sig = float(res.sigma_reduced().get((READOUT, cam, "readout_s"), float("nan")))
    except Exception:  # noqa: BLE001 - statistics not computed
        sig = float("nan")
    m = np.asarray(res.block.parameters[MOTION], float)
    held = READOUT not in dict(res.config.unknowns.groups) or res.config.unknowns.group_mode(READOUT) == "fixed"
    if held:
        sig = float("nan")
        out["readout_held"] = "readout time held at its prior (estimate_readout: false)"
    out.update(readout_s=ro, readout_sigma_s=sig, readout_prior_s=float(d.readout_s[0]),
               readout_prior_sigma_s=float(d.readout_sigma_s[0]),
               velocity_priors=int((d.velocity_sigma_m_s < UNKNOWN_SPEED_M_S).all(axis=1).sum()),
               median_speed_m_s=float(np.median(np.linalg.norm(m[:, :3], axis=1))) if len(m) else float("nan"),
               median_angular_rate_rad_s=float(np.median(np.linalg.norm(m[:, 3:], axis=1))) if len(m) else float("nan"))
    if not out["velocity_priors"]:
        out["note"] = ("no velocity prior (no image times): the readout time stays at its prior; the velocities "
                       "absorb the shutter's motion")
    return out
