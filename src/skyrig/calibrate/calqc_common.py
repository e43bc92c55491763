"""The ``calqc`` recipe's input (:class:`CalqcData`) and the helpers its parts share: one adjustment run with
its failure in words, RMS and sigma in micrometres, the calibration unknowns' labels and covariance.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.adjust import AdjustmentResult, DatumDefectError, adjust
from skyrig.adjust.block import AdjustConfig, Block
from skyrig.errors import CalqcFailed
from skyrig.georef.observations import GroundPoints, ImageMeasurements
from skyrig.rig.rig import Rig
from skyrig.trajectory import CameraEvents, Trajectory

log = logging.getLogger("skyrig.calibrate.calqc")  # the recipe's log, whichever part writes

__all__ = ["IO_PARAMETERS", "VARIANTS", "CalqcData", "calqc_data_from_survey"]


#: the interior orientation CalQC unlocks: principal distance and principal point (PPAC)
IO_PARAMETERS = ("focal_mm", "ppx_mm", "ppy_mm")


VARIANTS = ("ba-eo-control", "dg-control", "refine-eo-check")


# ------------------------------------------------------------------------------------------------ inputs
@dataclass(frozen=True)
class CalqcData:
    """The boresight flight as recorded: trajectory (GNSS antenna + IMU), events, nominal rig, image
    measurements (tie and ground points, pixels) and ground points (any frame); ``check_names`` are the ground
    points kept as check points in every step but the last (where all are)."""

    trajectory: Trajectory
    events: CameraEvents
    rig: Rig
    measurements: ImageMeasurements
    ground: GroundPoints
    check_names: tuple[str, ...] = ()

    def subset_images(self, keep: Callable[[NDArray[np.str_]], NDArray[np.bool_]] | Sequence[str]) -> "CalqcData":
        """The data restricted to some images (a set of names, or a predicate on the events' image names)."""
        names = np.asarray(self.events.image_name).astype(str)
        mask = keep(names) if callable(keep) else np.isin(names, np.asarray(list(keep), dtype=str))
        ev = self.events.subset(np.flatnonzero(mask))
        m = np.isin(self.measurements.image, names[mask])
        meas = ImageMeasurements(self.measurements.point[m], self.measurements.image[m], self.measurements.pixel[m])
        return replace(self, events=ev, measurements=meas)


def calqc_data_from_survey(survey: Any) -> CalqcData:
    """A simulated survey (:func:`skyrig.simulate.scenarios.build_survey`) as the recipe's input (in memory)."""
    meas = survey.image_measurements()
    ground = GroundPoints(survey.gcp_names, survey.gcp_surveyed, survey.frame)
    return CalqcData(survey.trajectory_recorded, survey.events_recorded, survey.rig_recorded, meas, ground,
                     tuple(str(n) for n in survey.gcp_names[survey.gcp_is_check]))


def _cal_values(r: AdjustmentResult, labels: Sequence[tuple[str, str, str]]) -> NDArray[np.float64]:
    """The values of the calibration unknowns ``labels`` (the ``_cal_labels`` order) in an adjustment's block."""
    b = r.block
    out = []
    for g, o, c in labels:
        if g == "boresight":
            out.append(b.head_boresight[list(b.head_name).index(o)]["rx ry rz".split().index(c)])
        elif g == "intrinsics":
            cam = next(cm for cm in b.cameras if cm.name == o)
            out.append(dict(zip(cam.intrinsic_names, cam.intrinsics))[c])
        elif g == "datum_shift":
            out.append(b.datum_shift["XYZ".index(c)])
        else:
            out.append(b.lever_arm["XYZ".index(c)])
    return np.array(out, float)


# ------------------------------------------------------------------------------------------------ helpers
def _run(block: Block, cfg: AdjustConfig, what: str) -> AdjustmentResult:
    try:
        res = adjust(block, cfg)
    except DatumDefectError as exc:
        raise CalqcFailed(f"{what}: the unknowns are not determined by this flight: {exc}") from None
    if not res.ok:
        raise CalqcFailed(f"{what}: " + "; ".join(res.failures))
    log.info("%s: sigma0 %.3f, redundancy %d, %d rejected", what, res.sigma0, res.redundancy, len(res.rejected))
    return res


def _rms(a: NDArray[np.float64]) -> list[float]:
    a = np.asarray(a, float)
    return np.sqrt(np.mean(np.square(a), axis=0)).tolist() if a.size else [float("nan")] * 3


def _sigma_um(block: Block, sigma0: float) -> float:
    cams = block.cameras
    px_um = float(np.median([c.pixel_size_mm for c in cams])) * 1000.0
    return float(sigma0 * np.median(block.obs_sigma_px) * px_um)


def _cal_labels(res: AdjustmentResult) -> tuple[list[tuple[str, str, str]], NDArray[np.float64]]:
    """Labels and a-posteriori covariance of the calibration unknowns (boresight, intrinsics, datum shift)."""
    sel = res.selected
    if sel is None:
        raise CalqcFailed("no covariance of the calibration unknowns was computed")
    idx = [k for k, lab in enumerate(sel.labels) if lab[0] in ("boresight", "intrinsics", "datum_shift", "lever_arm")]
    return [tuple(sel.labels[k]) for k in idx], res.sigma0**2 * sel.Qcc[np.ix_(idx, idx)]


def _drop_obs(block: Block, keep: NDArray[np.bool_]) -> Block:
    """The block without the image observations not in ``keep``."""
    kw: dict[str, Any] = dict(obs_image=block.obs_image[keep], obs_point=block.obs_point[keep],
                              obs_pixel=block.obs_pixel[keep], obs_sigma_px=block.obs_sigma_px[keep])
    if block.obs_cov_px2 is not None:
        kw["obs_cov_px2"] = block.obs_cov_px2[keep]
    return replace(block, **kw)


def _poseo(block: Block, datum: NDArray[np.float64]) -> Block:
    """The block with the GNSS positions (and the stations' starting centres) freed of the datum shift."""
    return replace(block, gnss_xyz=block.gnss_xyz - datum, station_centre=block.station_centre - datum)
