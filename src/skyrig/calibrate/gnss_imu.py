"""The ``uncalibrated-gnss-imu`` recipe: recovering the system calibration of a flight delivered with uncalibrated
GNSS/IMU data (paper 003, Redweik & Jacobsen, project "Southeast").

The flight came with antenna positions and attitudes whose antenna offset, boresight misalignment and datum were
unknown, and with poorly defined ground control in another projection with geoid heights.  The recipe
(:func:`calibrate_uncalibrated_gnss_imu`) follows the paper's sections 5 and 6:

1. **Frames harmonised** (5.1, Tab. 1): GNSS/IMU (any CRS, ellipsoidal heights), control (another projection,
   another scale, orthometric heights through a geoid) are transformed rigorously, through ECEF with PROJ, into one
   tangential (local ENU, Cartesian, unit scale) frame at the block (:func:`skyrig.adjust.frames.block_from_georef`);
   Tab. 1 lists what each data set used.
2. **Strips** are found from the event times and the IMU heading; the reference sub-block is the two central
   strips (flown in opposite directions) unless given.
3. **Antenna offset** (5.2, Tab. 2): a GNSS-supported AT of the reference sub-block with control and one shift per
   strip (``strip_shift`` free); the shifts ``GNSS - adjusted`` with their sigma form Tab. 2, and the
   flight-direction-dependent part of them is the antenna offset: ``s_k = D + A_k (dx, dy)`` with ``A_k`` the mean
   body-to-frame rotation of strip ``k`` (its x and y columns), solved by generalised least squares with the shifts'
   full covariance.  ``dz`` cannot be separated from the Z shift (it goes into the datum shift).  The whole flight's
   antenna lever arm is corrected by ``(dx, dy, 0)``.
4. **Reference orientation** (5.3, Tab. 3), two steps: (a) combined AT of the sub-block: GNSS (offset corrected),
   control, strip shifts and self-calibration (principal distance and principal point as *weighted* unknowns with
   a laboratory calibration's sigma: free, they are not separable from the strip shifts of a two-strip block, see
   ``SELF_CALIBRATION``); (b) its object points (with their sigma) as control of a conventional AT without GNSS
   (calibration fixed at (a)).  The orientations of (b) are the reference.
5. **Boresight misalignment and datum shift** (5.4, Tab. 4): per image the IMU attitude and the reference attitude
   (through the nominal mounting) are both expressed against *geographic* north at the projection centre (the
   tangential frame's north differs from the meridian there by the meridian convergence, computed per projection
   centre); their relative rotation in roll, pitch and yaw, and the difference of the projection centres (GNSS
   antenna reduced with the IMU attitude and the corrected lever arm, minus reference).  Mean = boresight
   misalignment and datum shift (GNSS frame minus control frame); RMS after bias correction.  Sigma of a mean:
   ``sqrt(RMS^2 / n + var(common part of the reference))``, the latter from the covariance of step 4a (the
   reference inherits its datum).
6. **Corrections applied to the whole flight**: calibrated rig (antenna lever arm, head boresight) and the GNSS
   positions without the datum shift: a corrected trajectory and the corrected EO (direct georeferencing).
7. **Evaluation** (section 6, Tab. 5 and 6) on the whole block, no control: spatial intersection with the
   corrected EO fixed, and integrated sensor orientation (ISO: image coordinates + corrected GNSS/IMU as
   observations), against two check sets: the ground points (all control and check points) and the object points
   of a combined adjustment of the whole block with GNSS positions and control (independent of the attitudes).
   Tab. 6: RMS of the attitude differences between corrected GNSS/IMU, ISO and combined adjustment.
8. **Y-parallax** (Tab. 7 and 8): per stereo model (consecutive images of a strip), the points it contains are
   intersected and their y-parallax in the normalised (epipolar) images at the principal distance (micrometres)
   is computed; RMS per model, for the corrected GNSS/IMU and the ISO orientations, in the tangential frame and
   in the national frame (the control's map projection with orthometric heights, used as if Cartesian, the way
   a stereo plotter in national coordinates does).

:func:`paper003_scenario` gives the simulated Southeast flight with paper 003's errors (Tab. 4 boresight, Tab. 4
datum shift, -0.75 m antenna offset, control with 0.6 m sigma in PT-TM06 with geoid heights, image sigma 5 um as
Tab. 3's sigma0) plus natural tie points; ``size="reduced"`` is a short block for tests.

Angles: radians inside, grads (gon) in the tables as the paper prints them.
"""

from __future__ import annotations

import html
import logging
from dataclasses import dataclass, replace
from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig._plain import plain
from skyrig.adjust.adjust import AdjustmentResult, adjust
from skyrig.adjust.block import AdjustConfig, Block
from skyrig.adjust.config import StatisticsOptions, Unknowns
from skyrig.adjust.frames import eo_from_block
from skyrig.adjust.rig_block import block_from_trajectory
from skyrig.calibrate.rig_calibration import CovarianceBlock, HeadCalibration, Provenance, RigCalibration
from skyrig.errors import CalibrationFailed, SkyrigError  # noqa: F401 - CalibrationFailed re-exported
from skyrig.geodesy.crs import ecef_to_geodetic
from skyrig.geodesy.local import ecef_from_ned_rotation
from skyrig.georef.direct import direct_georeference
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.georef.observations import GroundPoints, ImageMeasurements
from skyrig.geometry.rotations import matrix_from_rpy, rotvec_from_matrix, rpy_from_matrix
from skyrig.rig.camera_pose import antenna_from_body_origin, body_origin_from_antenna, world_from_camera
from skyrig.rig.rig import Rig
from skyrig.trajectory import CameraEvents, Trajectory

log = logging.getLogger(__name__)

__all__ = ["GON", "FlightData", "flight_data_from_survey", "GnssImuCalibration", "calibrate_uncalibrated_gnss_imu", "paper003_scenario",
           "find_strips", "y_parallax_models", "report_html", "format_tables"]

GON = np.pi / 200.0
MGON = GON / 1000.0
#: self-calibration of the reference AT (paper 003 5.3: "self calibration with additional parameters"): the
#: camera's intrinsics as weighted unknowns with these prior sigmas (mm; a laboratory calibration's accuracy).
#: Free (unweighted) they are not separable from the per-strip shifts of a two-strip block: a principal-point
#: shift moves the two opposite strips' projection centres across the track in opposite directions (in a
#: simulated test 1.2 m), which the strip shifts absorb, and the principal distance trades with the heights.
SELF_CALIBRATION = (("focal_mm", 0.005), ("ppx_mm", 0.005), ("ppy_mm", 0.005))


# ------------------------------------------------------------------------------------------------ inputs
@dataclass(frozen=True)
class FlightData:
    """What the recipe needs: the flight as recorded and the (poor) ground information.

    Attributes
    ----------
    trajectory, events, rig
        Recorded GNSS antenna positions + IMU attitudes, camera events, the nominal (uncalibrated) rig.
    measurements
        Image measurements of tie points and ground points (pixels).
    ground
        Ground points (any frame, e.g. a national projection with geoid heights); those named in
        ``control_names`` are control of the reference AT, all are check points of the evaluation.
    control_names
        Names of the ground points used as control in the reference sub-block (default: all).
    national
        The frame of the ground points (the "national system" of Tab. 8); default ``ground.frame``.
    trajectory_frame
        The frame the trajectory file stated (for Tab. 1 and for writing the corrected trajectory); default
        geographic WGS84 with ellipsoidal heights.
    """

    trajectory: Trajectory
    events: CameraEvents
    rig: Rig
    measurements: ImageMeasurements
    ground: GroundPoints
    control_names: tuple[str, ...] | None = None
    national: WorldFrame | None = None
    trajectory_frame: WorldFrame | None = None


def flight_data_from_survey(survey: Any) -> FlightData:
    """The recorded flight of a simulated survey (:func:`skyrig.simulate.scenarios.build_survey`) as the recipe's
    input, in memory: what ``skyrig simulate`` writes (control in the scenario's GCP CRS with geoid heights)."""
    from skyrig.geodesy.geoid_grid import find_geoid

    spec = survey.spec
    geoid = find_geoid() if spec.gcp_geoid == "auto" else spec.gcp_geoid
    gframe = WorldFrame.map(spec.gcp_crs or spec.crs, geoid)
    xyz = gframe.from_ecef(survey.frame.to_ecef(survey.gcp_surveyed))
    meas = survey.image_measurements()
    return FlightData(survey.trajectory_recorded, survey.events_recorded, survey.rig_recorded, meas,
                      GroundPoints(survey.gcp_names, xyz, gframe),
                      tuple(str(n) for n in survey.gcp_names[~survey.gcp_is_check]), gframe, WorldFrame.map(spec.crs))


def paper003_scenario(size: str = "full", seed: int = 1, tie_points: int | None = None,
                      image_sigma_um: float = 5.06) -> Any:
    """The simulated Southeast flight (``skyrig.simulate`` scenario ``southeast``) with paper 003's errors.

    The scenario already injects Tab. 4's boresight misalignment and datum shift, the -0.75 m antenna offset and
    control with 0.6 m sigma in PT-TM06 with geoid heights; this adds natural tie points (the paper's AT had over
    2000 in the reference sub-block) and sets the image measurement sigma to Tab. 3's sigma0 (5 um, in pixels of
    the simulated camera).  ``size``: ``"full"`` (4 strips x 55 km, about 110 images), ``"reduced"`` (4 strips x
    14 km, the same camera and height: a test block) or ``"ci"`` (the scenario's CI size).
    """
    from skyrig.simulate.scenarios import scenario_spec

    if size not in ("full", "reduced", "ci"):
        raise SkyrigError(f"size must be 'full', 'reduced' or 'ci', not {size!r}")
    spec = scenario_spec("southeast", "ci" if size == "ci" else "full", seed)
    cam = spec.rig.head("camera").camera
    if size == "reduced":
        fl = replace(spec.flights[0], area=(-5000.0, -7000.0, 5000.0, 7000.0))
        spec = replace(spec, flights=(fl,), scene_extent=(-12000.0, -14000.0, 12000.0, 14000.0), n_buildings=20,
                       n_gcp=12, n_check=4)
    n_tie = tie_points if tie_points is not None else {"full": 11000, "reduced": 2000, "ci": 1500}[size]
    err = replace(spec.errors, tie_points=int(n_tie),
                  measurement_sigma_px=float(image_sigma_um) / (cam.pixel_size_mm * 1000.0))
    return replace(spec, errors=err)


# ------------------------------------------------------------------------------------------------ helpers
def find_strips(station_time: NDArray[np.float64], world_from_body: NDArray[np.float64],
                max_heading_change_deg: float = 30.0) -> NDArray[np.int64]:
    """Strip index per station: stations in time order, a new strip where the heading (body x in the frame's
    horizontal plane) turns by more than ``max_heading_change_deg`` or the time gap exceeds 3 median gaps."""
    t = np.asarray(station_time, float)
    order = np.argsort(t, kind="stable")
    x = world_from_body[order][:, :, 0]
    head = np.arctan2(x[:, 0], x[:, 1])
    gap = np.diff(t[order])
    med = float(np.median(gap)) if gap.size else 1.0
    turn = np.abs(np.angle(np.exp(1j * np.diff(head))))
    new = np.r_[True, (turn > np.radians(max_heading_change_deg)) | (gap > 3.0 * med)]
    strip_sorted = np.cumsum(new) - 1
    out = np.empty(len(t), np.int64)
    out[order] = strip_sorted
    return out


def _subset_block(block: Block, keep_station: NDArray[np.bool_], keep_control: bool = True) -> Block:
    """The block reduced to the given stations (images, observations, points seen from >= 2 stations or control)."""
    st_new = np.cumsum(keep_station) - 1
    img_keep = keep_station[block.image_station]
    img_new = np.cumsum(img_keep) - 1
    obs_keep = img_keep[block.obs_image]
    # points: >= 2 distinct stations
    pairs = np.unique(np.column_stack([block.obs_point[obs_keep], block.image_station[block.obs_image[obs_keep]]]),
                      axis=0)
    nst = np.bincount(pairs[:, 0], minlength=block.n_points) if len(pairs) else np.zeros(block.n_points, int)
    pt_keep = nst >= 2
    obs_keep &= pt_keep[block.obs_point]
    pt_new = np.cumsum(pt_keep) - 1
    c_keep = pt_keep[block.control_point] if keep_control else np.zeros(len(block.control_point), bool)
    g_keep = keep_station[block.gnss_station]
    m_keep = keep_station[block.imu_station]
    strips_used = np.unique(block.station_strip[keep_station])
    strips_used = strips_used[strips_used >= 0]
    strip_map = np.full(max(block.n_strips, 1), -1, np.int64)
    strip_map[strips_used] = np.arange(strips_used.size)
    ss = block.station_strip[keep_station]
    kw: dict[str, Any] = dict(
        station_name=block.station_name[keep_station], station_rotation=block.station_rotation[keep_station],
        station_centre=block.station_centre[keep_station], station_time=block.station_time[keep_station],
        station_strip=np.where(ss >= 0, strip_map[np.maximum(ss, 0)], -1),
        image_name=block.image_name[img_keep], image_station=st_new[block.image_station[img_keep]],
        image_camera=block.image_camera[img_keep], image_rotation=block.image_rotation[img_keep],
        image_offset=block.image_offset[img_keep], image_head=block.image_head[img_keep],
        image_beta_rad=block.image_beta_rad[img_keep],
        point_name=block.point_name[pt_keep], point_xyz=block.point_xyz[pt_keep],
        obs_image=img_new[block.obs_image[obs_keep]], obs_point=pt_new[block.obs_point[obs_keep]],
        obs_pixel=block.obs_pixel[obs_keep], obs_sigma_px=block.obs_sigma_px[obs_keep],
        obs_cov_px2=None if block.obs_cov_px2 is None else block.obs_cov_px2[obs_keep],
        control_point=pt_new[block.control_point[c_keep]], control_xyz=block.control_xyz[c_keep],
        control_sigma=block.control_sigma[c_keep], control_check=block.control_check[c_keep],
        control_cov_m2=None if block.control_cov_m2 is None else block.control_cov_m2[c_keep],
        gnss_station=st_new[block.gnss_station[g_keep]], gnss_xyz=block.gnss_xyz[g_keep],
        gnss_sigma=block.gnss_sigma[g_keep], gnss_cov_m2=None if block.gnss_cov_m2 is None else block.gnss_cov_m2[g_keep],
        imu_station=st_new[block.imu_station[m_keep]], imu_rotation=block.imu_rotation[m_keep],
        imu_sigma_rad=block.imu_sigma_rad[m_keep],
        imu_cov_rad2=None if block.imu_cov_rad2 is None else block.imu_cov_rad2[m_keep],
        strip_shift=None, strip_drift=None, strip_t0=None,
    )
    return replace(block, **kw)


def _without(block: Block, gnss: bool = False, imu: bool = False, control: bool = False) -> Block:
    kw: dict[str, Any] = {}
    if gnss:
        kw.update(gnss_station=None, gnss_xyz=None, gnss_sigma=0.05, gnss_cov_m2=None)
    if imu:
        kw.update(imu_station=None, imu_rotation=None, imu_sigma_rad=1e-4, imu_cov_rad2=None)
    if control:
        kw.update(control_point=None, control_xyz=None, control_sigma=0.01, control_check=None, control_cov_m2=None)
    return replace(block, **kw)


def _run(block: Block, cfg: AdjustConfig, what: str) -> AdjustmentResult:
    res = adjust(block, cfg)
    if not res.info.converged:
        raise CalibrationFailed(f"{what}: the adjustment did not converge ({res.info})")
    if not res.ok:
        raise CalibrationFailed(f"{what}: " + "; ".join(res.failures))
    log.info("%s: sigma0 %.3f, %d observations, redundancy %d", what, res.sigma0, res.n_observations, res.redundancy)
    return res


def _selected(res: AdjustmentResult, group: str) -> tuple[list[tuple[str, str, str]], NDArray[np.float64]]:
    """Labels and a-posteriori covariance (sigma0^2 Q) of the chosen unknowns of one group."""
    sel = res.selected
    if sel is None:
        raise CalibrationFailed(f"no covariance of the {group} unknowns was computed")
    idx = [k for k, lab in enumerate(sel.labels) if lab[0] == group]
    return [sel.labels[k] for k in idx], res.sigma0**2 * sel.Qcc[np.ix_(idx, idx)]


def _image_sigma_um(block: Block, sigma0: float) -> float:
    cam = block.cameras[0]
    return float(sigma0 * np.median(block.obs_sigma_px) * cam.pixel_size_mm * 1000.0)


def _ned_from_frame(frame: WorldFrame, centre: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """``ned_from_frame`` rotations at the points and the meridian convergence (rad: azimuth of the frame's north
    axis clockwise from geographic north, PROJ's sign convention)."""
    ecef = frame.to_ecef(centre)
    lat, lon, _ = ecef_to_geodetic(ecef)
    ned_from_ecef = np.swapaxes(ecef_from_ned_rotation(lat, lon), -1, -2)
    R = ned_from_ecef @ frame.ecef_from_frame_rotation(centre)
    north_axis = R[:, :, 1]  # the frame's y (north) axis in NED
    conv = np.arctan2(north_axis[:, 1], north_axis[:, 0])  # its azimuth from geographic north
    return R, conv


def _grid_convergence(frame: WorldFrame, national: WorldFrame, centre: NDArray[np.float64]) -> dict[str, float]:
    """Min / max meridian convergence of the national map projection at the projection centres (gon): what
    turns the national EO's kappa (grid north) into the IMU's yaw (geographic north)."""
    if national.kind != "map":
        return {"min": 0.0, "max": 0.0}
    conv, _ = national.projection.factors(frame.points_to(centre, national))
    return {"min": float(np.min(conv) / GON), "max": float(np.max(conv) / GON)}


def _rms(a: NDArray[np.float64], axis: int = 0) -> NDArray[np.float64]:
    return np.sqrt(np.mean(np.square(a), axis=axis)) if a.size else np.full(a.shape[1:], np.nan)


# ------------------------------------------------------------------------------------------------ y-parallax
def y_parallax_models(eo: ExteriorOrientations, cameras: dict, measurements: ImageMeasurements,
                      strip_of_image: dict[str, int], min_points: int = 6) -> list[dict[str, Any]]:
    """RMS y-parallax per stereo model (consecutive images of a strip), micrometres.

    Both images' rays of every point measured in the two are rotated into a common normalised (epipolar) frame:
    x along the base, z the mean viewing direction made orthogonal to the base; the y-parallax is
    ``c (y1/z1 - y2/z2)`` at the principal distance ``c`` of the first image.  The frame of ``eo`` is used as if
    Cartesian (so a map frame shows the distortion a plotter in map coordinates sees)."""
    idx = eo.index()
    by_image: dict[str, dict[str, NDArray]] = {}
    for i in np.unique(measurements.image):
        sel = measurements.image == i
        by_image[str(i)] = {str(p): measurements.pixel[k] for p, k in zip(measurements.point[sel], np.flatnonzero(sel))}
    strips: dict[int, list[tuple[float, str]]] = {}
    for name, s in strip_of_image.items():
        if name in idx and name in by_image:
            t = eo.time_s[idx[name]] if eo.time_s is not None else idx[name]
            strips.setdefault(int(s), []).append((float(t), name))
    out = []
    for s in sorted(strips):
        seq = [n for _, n in sorted(strips[s])]
        for a, b in zip(seq[:-1], seq[1:]):
            common = sorted(set(by_image[a]) & set(by_image[b]))
            if len(common) < min_points:
                continue
            ia, ib = idx[a], idx[b]
            ca, cb = cameras[str(eo.camera[ia])], cameras[str(eo.camera[ib])]
            pa = np.array([by_image[a][p] for p in common])
            pb = np.array([by_image[b][p] for p in common])
            da = eo.rotation[ia] @ ca.rays_from_pixels(pa).T  # (3, n) world directions
            db = eo.rotation[ib] @ cb.rays_from_pixels(pb).T
            base = eo.centre[ib] - eo.centre[ia]
            ex = base / np.linalg.norm(base)
            view = -(eo.rotation[ia][:, 2] + eo.rotation[ib][:, 2])  # camera looks along -z
            ez = view - ex * (view @ ex)
            ez /= np.linalg.norm(ez)
            ey = np.cross(ez, ex)
            Rn = np.vstack([ex, ey, ez])  # normalised_from_world
            na, nb = Rn @ da, Rn @ db
            c_um = ca.focal_mm * 1000.0
            py = c_um * (na[1] / na[2] - nb[1] / nb[2])
            out.append({"strip": int(s), "left": a, "right": b, "points": len(common),
                        "rms_um": float(np.sqrt(np.mean(py**2))), "max_um": float(np.max(np.abs(py)))})
    return out


# ------------------------------------------------------------------------------------------------ result
@dataclass
class GnssImuCalibration:
    """Everything the recipe produced (see the module docstring); :meth:`to_dict` is the JSON report."""

    rig_in: Rig
    rig: Rig
    head: str
    frame: WorldFrame
    national: WorldFrame
    boresight_rpy_rad: NDArray[np.float64]
    boresight_cov_rad2: NDArray[np.float64]
    datum_shift_m: NDArray[np.float64]
    datum_shift_cov_m2: NDArray[np.float64]
    antenna_offset_m: NDArray[np.float64]
    antenna_offset_cov_m2: NDArray[np.float64]
    trajectory_corrected: Trajectory
    eo_corrected: ExteriorOrientations
    eo_iso: ExteriorOrientations
    eo_reference: ExteriorOrientations
    tables: dict[str, Any]
    gsd_m: float
    n_images: int
    reference_strips: tuple[int, ...]
    statistics: dict[str, float]

    def rig_calibration(self, flight: str = "", date: str = "", software: str = "",
                        previous: RigCalibration | None = None) -> RigCalibration:
        """Boresight (omega, phi, kappa about the camera axes, deg) and antenna lever arm blocks, provenance."""
        h = self.rig.head(self.head)
        M = h.mounting
        cov_cam = M.T @ self.boresight_cov_rad2 @ M  # body roll/pitch/yaw -> camera axes (small angles)
        opk = np.degrees(np.array(h.boresight_opk(unit="rad")))
        bore = CovarianceBlock.from_covariance(("omega", "phi", "kappa"), cov_cam * (180.0 / np.pi) ** 2)
        lev_cov = np.zeros((3, 3))
        lev_cov[:2, :2] = self.antenna_offset_cov_m2
        lev_cov[2, 2] = self.datum_shift_cov_m2[2, 2]  # dz: not separable from the Z datum shift
        ant = CovarianceBlock.from_covariance(("x", "y", "z"), lev_cov)
        prov = Provenance("uncalibrated-gnss-imu", flight, date, software, dict(self.statistics),
                          notes=("paper 003 recipe; boresight = mean IMU vs two-step reference orientation in roll/"
                                 "pitch/yaw; antenna x/y from per-strip projection-centre shifts; antenna z is not "
                                 "separable from the datum shift Z (its sigma is that of the Z shift); datum shift "
                                 f"(GNSS minus control, tangential ENU) {np.round(self.datum_shift_m, 3).tolist()} m "
                                 "is applied to the corrected trajectory, not to the rig; boresight opk "
                                 f"{np.round(opk, 6).tolist()} deg"))
        heads = dict(previous.heads) if previous is not None else {}
        old = heads.get(self.head, HeadCalibration())
        heads[self.head] = HeadCalibration(old.lever_arm_m, bore, old.interior, old.actuator, prov)
        return RigCalibration(heads, ant, prov)

    def to_dict(self) -> dict[str, Any]:
        """The JSON report: the result with sigmas, statistics and the paper's tables (plain numbers)."""
        sb = np.sqrt(np.diag(self.boresight_cov_rad2))
        sd = np.sqrt(np.diag(self.datum_shift_cov_m2))
        sa = np.sqrt(np.diag(self.antenna_offset_cov_m2))
        return _plain({
            "recipe": "uncalibrated-gnss-imu", "paper": "003 (Redweik & Jacobsen)",
            "frame": self.frame.describe(), "national_frame": self.national.describe(),
            "images": self.n_images, "gsd_m": self.gsd_m, "reference_strips": [s + 1 for s in self.reference_strips],
            "result": {
                "boresight_misalignment_gon": {"roll": self.boresight_rpy_rad[0] / GON, "pitch": self.boresight_rpy_rad[1] / GON,
                                               "yaw": self.boresight_rpy_rad[2] / GON},
                "boresight_sigma_gon": dict(zip(("roll", "pitch", "yaw"), (sb / GON).tolist())),
                "datum_shift_m": dict(zip("XYZ", self.datum_shift_m.tolist())),
                "datum_shift_sigma_m": dict(zip("XYZ", sd.tolist())),
                "antenna_offset_m": dict(zip(("dx", "dy"), self.antenna_offset_m.tolist())),
                "antenna_offset_sigma_m": dict(zip(("dx", "dy"), sa.tolist())),
                "antenna_lever_arm_m": self.rig.antenna_lever_arm_m.tolist(),
                "head_boresight_opk_deg": list(self.rig.head(self.head).boresight_opk(unit="deg")),
            },
            "statistics": dict(self.statistics),
            "tables": self.tables,
        })


_plain = plain


# ------------------------------------------------------------------------------------------------ the recipe
def calibrate_uncalibrated_gnss_imu(
    data: FlightData,
    *,
    reference_strips: Sequence[int] | None = None,
    head: str | None = None,
    image_sigma_um: float = 5.0,
    gnss_sigma_m: tuple[float, float, float] = (0.3, 0.3, 0.3),
    imu_sigma_gon: tuple[float, float, float] = (0.008 / 0.9, 0.008 / 0.9, 0.015 / 0.9),
    control_sigma_m: tuple[float, float, float] = (0.6, 0.6, 0.6),
    self_calibration: Sequence[tuple[str, float]] = SELF_CALIBRATION,
    y_parallax_min_points: int = 6,
) -> GnssImuCalibration:
    """Run the paper-003 recipe (module docstring) on one flight.

    Parameters
    ----------
    reference_strips
        0-based strip indices of the reference sub-block (default: the two central strips).
    image_sigma_um
        A-priori sigma of an image coordinate (micrometres in the image).
    gnss_sigma_m, imu_sigma_gon, control_sigma_m
        A-priori sigma of the antenna positions (paper: +-30 cm), IMU attitudes roll/pitch/yaw (grads; default
        the POS/AV 410's 0.008 / 0.008 / 0.015 deg) and control points (paper: about 0.6 m).
    self_calibration
        ``(name, prior sigma)`` of the intrinsics estimated as weighted unknowns in the reference step 1 and the
        combined adjustment (empty: none).  They are reported (Tab. 3), not written into the rig: the paper's
        corrections are the antenna offset, the boresight and the datum shift.
    """
    rig = data.rig
    if head is None:
        if len(rig) != 1:
            raise SkyrigError(f"the rig has {len(rig)} heads ({', '.join(rig.head_names)}): name the head")
        head = rig.head_names[0]
    cam = rig.head(head).camera
    sigma_px = image_sigma_um / (cam.pixel_size_mm * 1000.0)
    national = data.national or data.ground.frame
    control_names = tuple(data.control_names) if data.control_names is not None else tuple(data.ground.name.tolist())
    check_all = tuple(str(n) for n in data.ground.name)
    imu_sig = tuple(float(v) * GON for v in imu_sigma_gon)

    def build(r: Rig, traj: Trajectory, frame: WorldFrame | None) -> tuple[Block, WorldFrame]:
        return block_from_trajectory(traj, r, data.events, data.measurements, data.ground,
                                     gnss_sigma_m=gnss_sigma_m, imu_sigma_rad=imu_sig, control_sigma_m=control_sigma_m,
                                     check_points=tuple(n for n in check_all if n not in control_names),
                                     sigma_px=sigma_px, frame=frame)

    block0, frame = build(rig, data.trajectory, None)
    strips = find_strips(block0.station_time, block0.station_rotation)
    block0 = replace(block0, station_strip=strips, strip_shift=None, strip_drift=None, strip_t0=None)
    n_strips = int(strips.max()) + 1
    ref, headings = _reference_strips(block0, strips, n_strips, reference_strips)
    stats: dict[str, float] = {"images": float(block0.n_images), "strips": float(n_strips)}
    tables: dict[str, Any] = {}
    tables["table1_frames"] = _table1(data, frame, national)
    gsd = float(cam.gsd(float(np.median(block0.station_centre[:, 2] - np.median(block0.point_xyz[:, 2])))))
    ref_sorted = sorted(ref)
    offset, offset_cov = _step1_antenna_offset(block0, np.isin(strips, ref), ref_sorted, headings, tables)
    rig1 = replace(rig, antenna_lever_arm_m=rig.antenna_lever_arm_m + np.r_[offset, 0.0])
    blk1, r_b1, r_b2, ref_eo, sc_unknowns = _step2_reference(build, rig1, data.trajectory, frame, ref, cam,
                                                       self_calibration, tables, stats)
    b_mean, bore_cov, x_mean, datum_cov, n = _step3_misalignment(blk1, r_b1, r_b2, rig1, frame, national, tables)
    # ---- step 4: corrections applied to the whole flight
    h = rig1.head(head)
    M = h.mounting
    Rb = matrix_from_rpy(*b_mean, unit="rad")
    new_bore = M.T @ Rb @ M @ h.boresight
    rig_cal = Rig(rig.name, [hh.with_(boresight=new_bore) if hh.name == head else hh for hh in rig1],
                  rig1.antenna_lever_arm_m, (rig.description + " | " if rig.description else "")
                  + "calibrated by skyrig calibrate uncalibrated-gnss-imu")
    traj_c = _shift_trajectory(data.trajectory, frame, -x_mean)
    eo_c = direct_georeference(traj_c, rig_cal, data.events, frame)
    blk_c, r_iso, eo_dir, eo_iso, t5 = _step5_evaluation(build, rig_cal, traj_c, frame, data, sc_unknowns, tables)
    _step6_y_parallax(blk_c, eo_dir, eo_iso, r_iso, data, national, y_parallax_min_points, tables)
    stats.update({"sigma0_spatial_intersection_um": t5["spatial_intersection"]["sigma0_um"],
                  "sigma0_iso_um": t5["integrated_sensor_orientation"]["sigma0_um"],
                  "reference_images": float(n)})
    return GnssImuCalibration(rig, rig_cal, head, frame, national, b_mean, bore_cov, x_mean, datum_cov, offset,
                              offset_cov, traj_c, eo_c, eo_iso, ref_eo, tables, gsd, block0.n_images, tuple(ref_sorted), stats)


def _reference_strips(block0: Block, strips: NDArray[np.int64], n_strips: int,
                      reference_strips: Sequence[int] | None) -> tuple[tuple[int, ...], dict[int, float]]:
    """The reference sub-block's strips (default the two central ones; they must include opposite directions) and
    every strip's heading (degrees)."""
    if reference_strips is None:
        if n_strips < 2:
            raise SkyrigError("one strip only: the recipe needs (at least) two strips flown in opposite directions")
        mid = n_strips // 2
        reference_strips = (mid - 1, mid)
    ref = tuple(int(s) for s in reference_strips)
    if any(s < 0 or s >= n_strips for s in ref) or len(set(ref)) < 2:
        raise SkyrigError(f"reference strips {[s + 1 for s in ref]}: need two or more of the {n_strips} strips")
    headings = {}
    for s in range(n_strips):
        x = block0.station_rotation[strips == s][:, :, 0].mean(axis=0)
        headings[s] = float(np.degrees(np.arctan2(x[0], x[1])) % 360.0)
    hd = np.array([headings[s] for s in ref])
    if np.max(np.abs(np.angle(np.exp(1j * np.radians(hd - hd[0]))))) < np.radians(150):
        raise SkyrigError(f"reference strips {[s + 1 for s in ref]} are all flown in one direction (headings "
                          f"{np.round(hd, 1).tolist()} deg): the antenna offset and the boresight need strips in "
                          "opposite directions")
    return ref, headings


def _step1_antenna_offset(block0: Block, in_ref: NDArray[np.bool_], ref_sorted: list[int], headings: dict[int, float],
                          tables: dict[str, Any]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Step 1 (5.2, Tab. 2): GNSS-supported AT of the reference sub-block with control and a shift per strip; the
    antenna offset (dx, dy in the body) from the shifts of strips in opposite directions, with its covariance.
    Fills ``tables`` (Tab. 2, the antenna offset)."""
    sub = _subset_block(block0, in_ref)
    sub_g = _without(sub, imu=True)
    cfg_a = AdjustConfig(unknowns=Unknowns(strip_shift="free"),
                         statistics=StatisticsOptions(images=tuple(sub_g.station_name.tolist())))
    r_a = _run(sub_g, cfg_a, "AT(GNSS) with strip shifts")
    labels, cov_s = _selected(r_a, "strip_shift")
    shifts = r_a.block.strip_shift
    t2 = []
    ba = r_a.block
    d_img = ba.gnss_xyz - antenna_from_body_origin(ba.station_rotation[ba.gnss_station],
                                                   ba.station_centre[ba.gnss_station], ba.lever_arm)
    for k, s in enumerate(ref_sorted):
        sig = np.sqrt(np.diag(cov_s[3 * k:3 * k + 3, 3 * k:3 * k + 3]))
        dk = d_img[ba.station_strip[ba.gnss_station] == k]
        t2.append({"strip": s + 1, "heading_deg": headings[s], "shift_m": shifts[k].tolist(), "sigma_m": sig.tolist(),
                   "scatter_m": dk.std(axis=0, ddof=1).tolist() if len(dk) > 1 else [float("nan")] * 3,
                   "images": int(len(dk))})
    tables["table2_strip_shifts"] = {"rows": t2, "sigma0_um": _image_sigma_um(sub_g, r_a.sigma0),
                                     "definition": "GNSS antenna minus adjusted (tangential frame E, N, U): the strip's shift "
                                                   "unknown with its sigma (SX SY SZ), and the standard deviation of "
                                                   "the per-image differences in the strip"}
    # antenna offset from the shifts: s_k = D + A_k (dx, dy)
    A = []
    for k, s in enumerate(ref_sorted):
        Rk = r_a.block.station_rotation[r_a.block.station_strip == k].mean(axis=0)
        for ax in range(3):
            a = np.zeros(5)
            a[ax] = 1.0
            a[3:] = Rk[ax, :2]
            A.append(a)
    A = np.array(A)
    y = shifts[: len(ref_sorted)].reshape(-1)
    W = np.linalg.inv(cov_s)
    N = A.T @ W @ A
    Ninv = np.linalg.inv(N)
    xhat = Ninv @ A.T @ W @ y
    v = A @ xhat - y
    red = len(y) - 5
    offset = xhat[3:]
    offset_cov = Ninv[3:, 3:]
    tables["antenna_offset"] = {"dx_m": float(offset[0]), "dy_m": float(offset[1]),
                                "sigma_m": np.sqrt(np.diag(offset_cov)).tolist(),
                                "shift_common_m": xhat[:3].tolist(), "redundancy": red,
                                "chi2": float(v @ W @ v),
                                "note": "dz is not separable from the Z shift; it goes into the datum shift"}
    return offset, offset_cov


def _step2_reference(build: Callable[[Rig, Trajectory, WorldFrame | None], tuple[Block, WorldFrame]], rig1: Rig,
                     trajectory: Trajectory, frame: WorldFrame, ref: tuple[int, ...], cam: Any,
                     self_calibration: Sequence[tuple[str, float]], tables: dict[str, Any], stats: dict[str, float]
                     ) -> tuple[Block, AdjustmentResult, AdjustmentResult, ExteriorOrientations, Unknowns]:
    """Step 2 (5.3, Tab. 3): the two-step reference orientation of the reference strips with the corrected antenna
    offset: AT(GNSS) with self-calibration and strip shifts, then an AT without GNSS on its points as control.
    Returns the whole flight's block, both results, the reference orientations and the self-calibration options;
    fills Tab. 3."""
    blk1, _ = build(rig1, trajectory, frame)
    blk1 = replace(blk1, station_strip=find_strips(blk1.station_time, blk1.station_rotation), strip_shift=None,
                   strip_drift=None, strip_t0=None)
    sub1 = _without(_subset_block(blk1, np.isin(blk1.station_strip, ref)), imu=True)
    sc_names = tuple(n for n, _ in self_calibration)
    sc_unknowns = Unknowns(intrinsics="weighted", intrinsic_names=sc_names,
                           intrinsic_sigma=tuple((n, float(v)) for n, v in self_calibration)) if sc_names else Unknowns()
    cfg_b1 = AdjustConfig(unknowns=replace(sc_unknowns, strip_shift="free"),
                          statistics=StatisticsOptions(images=tuple(sub1.station_name.tolist())))
    r_b1 = _run(sub1, cfg_b1, "reference step 1: AT(GNSS) with self-calibration and strip shifts")
    b1 = r_b1.block
    psig = r_b1.point_sigma
    if psig is None or not np.isfinite(psig).all():
        raise CalibrationFailed("reference step 1: no point sigma (the covariance was not computed)")
    sub2 = replace(_without(b1, gnss=True), control_point=np.arange(b1.n_points), control_xyz=b1.point_xyz.copy(),
                   control_sigma=np.maximum(psig, 1e-3), control_check=np.zeros(b1.n_points, bool), control_cov_m2=None,
                   strip_shift=None, strip_drift=None, strip_t0=None)
    r_b2 = _run(sub2, AdjustConfig(), "reference step 2: AT without GNSS, step-1 points as control")
    ref_eo = eo_from_block(r_b2.block, frame)
    tables["table3_reference"] = [
        _t3_row("1. AT(GNSS)", r_a_like=r_b1, block=sub1),
        _t3_row("2. AT", r_a_like=r_b2, block=sub2),
    ]
    stats.update({"sigma0_step1_um": _image_sigma_um(sub1, r_b1.sigma0),
                  "sigma0_step2_um": _image_sigma_um(sub2, r_b2.sigma0)})
    if sc_names:
        lab, cov_i = _selected(r_b1, "intrinsics")
        cam1 = r_b1.block.cameras[0]
        vals = dict(zip(cam1.intrinsic_names, cam1.intrinsics))
        tables["table3_self_calibration"] = [
            {"parameter": l[2], "value": float(vals[l[2]]), "start": float(dict(zip(cam.intrinsic_names, cam.intrinsics))[l[2]]),
             "sigma": float(np.sqrt(cov_i[k, k])), "prior_sigma": float(dict(self_calibration)[l[2]])}
            for k, l in enumerate(lab)]
    return blk1, r_b1, r_b2, ref_eo, sc_unknowns


def _step3_misalignment(blk1: Block, r_b1: AdjustmentResult, r_b2: AdjustmentResult, rig1: Rig, frame: WorldFrame,
                        national: WorldFrame, tables: dict[str, Any]
                        ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                                   int]:
    """Step 3 (5.4, Tab. 4): the recorded IMU against the reference in roll / pitch / yaw, the GNSS-derived against
    the reference projection centres: the boresight misalignment and the datum shift (means) with their
    covariances, and the number of reference images.  Fills Tab. 4."""
    st = r_b2.block
    names = st.station_name
    full_idx = {str(n): k for k, n in enumerate(blk1.station_name)}
    rows_full = np.array([full_idx[str(n)] for n in names])
    imu_row = {int(k): j for j, k in enumerate(blk1.imu_station)}
    gnss_row = {int(k): j for j, k in enumerate(blk1.gnss_station)}
    missing = [str(names[j]) for j, k in enumerate(rows_full) if int(k) not in imu_row or int(k) not in gnss_row]
    if missing:
        raise CalibrationFailed(f"no GNSS/IMU record for {missing[0]} ({len(missing)} reference stations)")
    R_imu = blk1.imu_rotation[[imu_row[int(k)] for k in rows_full]]  # world_from_body recorded
    R_ref_body = st.station_rotation  # world_from_body of the reference (nominal mounting, zero boresight)
    first = np.searchsorted(st.image_station, np.arange(st.n_stations))  # the reference image of each station
    _, C_ref = world_from_camera(st.station_rotation, st.station_centre, st.image_rotation[first],
                                 st.image_offset[first])
    ned, conv = _ned_from_frame(frame, C_ref)
    ned_imu = ned @ R_imu
    ned_ref = ned @ R_ref_body
    rel = np.swapaxes(ned_imu, 1, 2) @ ned_ref  # R_rpy(b) = R_imu^T R_ref (body axes)
    d_rpy = np.column_stack(rpy_from_matrix(rel, unit="rad"))
    g = blk1.gnss_xyz[[gnss_row[int(k)] for k in rows_full]]
    C_gnss = body_origin_from_antenna(R_imu, g, rig1.antenna_lever_arm_m)
    d_xyz = C_gnss - C_ref
    b_mean = d_rpy.mean(axis=0)
    log.debug("per station d_xyz %s\n d_rpy(mgon) %s\n strips %s", np.round(d_xyz, 3), np.round(d_rpy / MGON, 2),
              st.station_strip)
    x_mean = d_xyz.mean(axis=0)
    n = len(names)
    rms_b = _rms(d_rpy - b_mean)
    rms_x = _rms(d_xyz - x_mean)
    # common part of the reference (its datum, inherited from step 1): covariance of the mean pose of step 1
    cov_mean = _mean_pose_covariance(r_b1, names)
    bore_cov = np.diag(rms_b**2 / n) + cov_mean[3:, 3:]
    datum_cov = np.diag(rms_x**2 / n) + cov_mean[:3, :3]
    tables["table4_misalignment"] = {
        "misalignment": {"pitch_gon": b_mean[1] / GON, "roll_gon": b_mean[0] / GON, "yaw_gon": b_mean[2] / GON,
                         "X_m": x_mean[0], "Y_m": x_mean[1], "Z_m": x_mean[2]},
        "sigma": {"pitch_gon": np.sqrt(bore_cov[1, 1]) / GON, "roll_gon": np.sqrt(bore_cov[0, 0]) / GON,
                  "yaw_gon": np.sqrt(bore_cov[2, 2]) / GON, "X_m": np.sqrt(datum_cov[0, 0]),
                  "Y_m": np.sqrt(datum_cov[1, 1]), "Z_m": np.sqrt(datum_cov[2, 2])},
        "rms_after_bias": {"pitch_gon": rms_b[1] / GON, "roll_gon": rms_b[0] / GON, "yaw_gon": rms_b[2] / GON,
                           "X_m": rms_x[0], "Y_m": rms_x[1], "Z_m": rms_x[2]},
        "images": n,
        "meridian_convergence_gon": {"min": float(conv.min() / GON), "max": float(conv.max() / GON)},
        "grid_convergence_national_gon": _grid_convergence(frame, national, C_ref),
        "definition": "IMU vs reference: roll, pitch, yaw of R_imu^T R_ref against geographic north at each "
                      "projection centre; X Y Z: GNSS-derived minus reference projection centre (tangential frame)",
    }
    return b_mean, bore_cov, x_mean, datum_cov, n


def _step5_evaluation(build: Callable[[Rig, Trajectory, WorldFrame | None], tuple[Block, WorldFrame]], rig_cal: Rig,
                      traj_c: Trajectory, frame: WorldFrame, data: FlightData, sc_unknowns: Unknowns,
                      tables: dict[str, Any]
                      ) -> tuple[Block, AdjustmentResult, ExteriorOrientations, ExteriorOrientations, dict[str, Any]]:
    """Step 5 (section 6, Tab. 5, 6): the corrected flight evaluated on the whole block: the combined adjustment
    (GNSS, control, strip shifts, self-calibration, no IMU), spatial intersection with the corrected direct
    orientation and integrated sensor orientation (no control), against the ground points and each other.
    Returns the corrected block, the ISO result, the direct and ISO orientations and Tab. 5; fills Tab. 5, 6."""
    blk_c, _ = build(rig_cal, traj_c, frame)
    blk_c = replace(blk_c, station_strip=find_strips(blk_c.station_time, blk_c.station_rotation), strip_shift=None,
                    strip_drift=None, strip_t0=None)
    # combined adjustment of the whole block: GNSS positions + control + strip shifts + self-calibration, no IMU
    comb_b = _without(blk_c, imu=True)
    r_comb = _run(comb_b, AdjustConfig(unknowns=replace(sc_unknowns, strip_shift="free"),
                                               statistics=StatisticsOptions(compute=False)), "combined adjustment (whole block, GNSS positions)")
    # spatial intersection: corrected direct orientation fixed
    # (the block's points are the least-squares forward intersection with the corrected EO: its starting values)
    si_pts, si_sigma0 = _spatial_intersection(blk_c)
    # integrated sensor orientation: image coordinates + corrected GNSS/IMU, no control
    iso_b = replace(blk_c, control_check=np.ones(len(blk_c.control_point), bool))
    r_iso = _run(iso_b, AdjustConfig(statistics=StatisticsOptions(compute=False)), "integrated sensor orientation")
    ground_local = frame.from_ecef(data.ground.frame.to_ecef(data.ground.xyz))
    gidx = {str(nm): k for k, nm in enumerate(data.ground.name)}
    comb_pts = {str(nm): r_comb.block.point_xyz[k] for k, nm in enumerate(r_comb.block.point_name) if str(nm) not in gidx}
    t5 = {}
    iso_pts = {str(nm): r_iso.block.point_xyz[k] for k, nm in enumerate(r_iso.block.point_name)}
    for label, pts, s0 in (("spatial_intersection", si_pts, si_sigma0),
                           ("integrated_sensor_orientation", iso_pts, r_iso.sigma0)):
        dg = np.array([pts[nm] - ground_local[gidx[nm]] for nm in pts if nm in gidx])
        dc = np.array([pts[nm] - comb_pts[nm] for nm in pts if nm in comb_pts])
        t5[label] = {"sigma0_um": _image_sigma_um(blk_c, s0),
                     "ground_points": {"n": len(dg), "rms_m": _rms(dg).tolist()},
                     "combined_adjustment_points": {"n": len(dc), "rms_m": _rms(dc).tolist()}}
    tables["table5_check_points"] = t5
    eo_iso = eo_from_block(r_iso.block, frame)
    eo_comb = eo_from_block(r_comb.block, frame)
    eo_dir = eo_from_block(blk_c, frame)
    tables["table6_attitudes"] = {
        "corrected_gnss_imu-combined": _opk_rms(eo_dir, eo_comb),
        "iso-combined": _opk_rms(eo_iso, eo_comb),
        "iso-corrected_gnss_imu": _opk_rms(eo_iso, eo_dir),
        "images": len(eo_iso),
    }
    return blk_c, r_iso, eo_dir, eo_iso, t5


def _step6_y_parallax(blk_c: Block, eo_dir: ExteriorOrientations, eo_iso: ExteriorOrientations,
                      r_iso: AdjustmentResult, data: FlightData, national: WorldFrame, min_points: int,
                      tables: dict[str, Any]) -> None:
    """Step 6 (Tab. 7, 8): y-parallax per stereo model of the corrected direct and the ISO orientations, in the
    tangential and the national frame.  Fills Tab. 7, 8 and the models."""
    strip_of_image = {str(nm): int(blk_c.station_strip[blk_c.image_station[k]]) for k, nm in enumerate(blk_c.image_name)}
    eo_dir_t = replace(eo_dir, time_s=blk_c.station_time[blk_c.image_station])
    eo_iso_t = replace(eo_iso, time_s=blk_c.station_time[blk_c.image_station])
    cams = {c.name: c for c in r_iso.block.cameras}
    cams_nat = cams
    t8 = {}
    models_by = {}
    for fname, fr in (("tangential", None), ("national", national)):
        for oname, e in (("corrected_gnss_imu", eo_dir_t), ("integrated_sensor_orientation", eo_iso_t)):
            ee = e if fr is None else e.to_frame(fr)
            mods = y_parallax_models(ee, cams if fr is None else cams_nat, data.measurements, strip_of_image,
                                     min_points)
            r = np.array([m["rms_um"] for m in mods])
            t8[f"{fname}/{oname}"] = {"models": len(mods), "over_10um": int((r > 10).sum()),
                                      "over_20um": int((r > 20).sum()), "max_rms_um": float(r.max()) if r.size else None,
                                      "mean_rms_um": float(r.mean()) if r.size else None}
            models_by[f"{fname}/{oname}"] = mods
    npts = np.array([m["points"] for m in models_by["tangential/corrected_gnss_imu"]])
    tables["table7_points_per_model"] = {"bins": ["10-30", "31-50", "51-70", ">70", "<10"],
                                         "models": [int(((npts >= 10) & (npts <= 30)).sum()),
                                                    int(((npts >= 31) & (npts <= 50)).sum()),
                                                    int(((npts >= 51) & (npts <= 70)).sum()), int((npts > 70).sum()),
                                                    int((npts < 10).sum())]}
    tables["table8_y_parallax"] = t8
    tables["y_parallax_models"] = models_by


def _spatial_intersection(block: Block) -> tuple[dict[str, NDArray[np.float64]], float]:
    """Points of the block (its starting values: the least-squares forward intersection with its orientations,
    :func:`skyrig.georef.ground.forward_intersection`) and the sigma0 of their image residuals with the
    orientations fixed (redundancy ``2 n_obs - 3 n_points``)."""
    from skyrig.adjust.model import Model, State

    b = _without(block, gnss=True, imu=True, control=True)
    f = next(f for f in Model(b, AdjustConfig(unknowns=Unknowns(poses="fixed"))).evaluate(State.from_block(b), jacobians=False)
             if f.name == "image")
    red = 2 * b.n_observations - 3 * b.n_points
    if red <= 0:
        raise CalibrationFailed("spatial intersection: no redundancy")
    s0 = float(np.sqrt(np.sum(np.square(f.r)) / red))
    return {str(nm): b.point_xyz[k] for k, nm in enumerate(b.point_name)}, s0


def _t3_row(label: str, r_a_like: AdjustmentResult, block: Block) -> dict[str, Any]:
    res = r_a_like
    row: dict[str, Any] = {"step": label, "ground_points": int((~block.control_check).sum()),
                           "gnss_points": int(len(block.gnss_station)),
                           "sigma0_um": _image_sigma_um(block, res.sigma0)}
    b = res.block
    use = ~b.control_check
    if use.any():
        row["rms_ground_m"] = _rms(b.point_xyz[b.control_point[use]] - b.control_xyz[use]).tolist()
    gr = res.residuals.get("gnss")
    if gr is not None and len(gr.residual):
        row["rms_gnss_m"] = _rms(np.asarray(gr.residual)).tolist()
    return row


def _mean_pose_covariance(res: AdjustmentResult, station_names: NDArray[np.str_]) -> NDArray[np.float64]:
    """``(6, 6)`` covariance of the mean station pose (X Y Z, body rx ry rz) over the named stations."""
    sel = res.selected
    if sel is None:
        raise CalibrationFailed("no pose covariance from reference step 1")
    pos = {lab: k for k, lab in enumerate(sel.labels)}
    comps = ("X", "Y", "Z", "rx", "ry", "rz")
    J = np.zeros((6, len(sel.labels)))
    for nm in station_names:
        for c, comp in enumerate(comps):
            k = pos.get(("pose", str(nm), comp))
            if k is None:
                raise CalibrationFailed(f"no covariance of station {nm!r}")
            J[c, k] += 1.0 / len(station_names)
    return res.sigma0**2 * (J @ sel.Qcc @ J.T)


def _opk_rms(a: ExteriorOrientations, b: ExteriorOrientations) -> dict[str, float]:
    """RMS of the attitude differences as rotations about the camera axes (omega, phi, kappa), grads."""
    ib = b.index()
    rows = [(k, ib[str(n)]) for k, n in enumerate(a.image) if str(n) in ib]
    ka = np.array([r[0] for r in rows])
    kb = np.array([r[1] for r in rows])
    d = rotvec_from_matrix(np.swapaxes(b.rotation[kb], 1, 2) @ a.rotation[ka])
    r = _rms(d) / GON
    return {"S_phi_gon": float(r[1]), "S_omega_gon": float(r[0]), "S_kappa_gon": float(r[2])}


def _shift_trajectory(traj: Trajectory, frame: WorldFrame, shift_local: NDArray[np.float64]) -> Trajectory:
    """The trajectory with its positions moved by a constant vector of the tangential frame."""
    from skyrig.geodesy.crs import geodetic_to_ecef

    ecef = geodetic_to_ecef(traj.lat_deg, traj.lon_deg, traj.h_m)
    ecef = ecef + frame.tangent.ecef_from_local @ np.asarray(shift_local, float)
    lat, lon, h = ecef_to_geodetic(ecef)
    return Trajectory(traj.time_s, lat, lon, h, traj.ned_from_body_q, time_system=traj.time_system,
                      reference=traj.reference)


def _table1(data: FlightData, frame: WorldFrame, national: WorldFrame) -> list[dict[str, str]]:
    """Tab. 1: the coordinate definitions of the data sets and the common frame."""
    import pyproj

    def describe(fr: WorldFrame, what: str, heights: str | None = None) -> dict[str, str]:
        row = {"data_set": what, "frame": fr.describe()}
        if fr.kind == "map":
            crs = pyproj.CRS.from_user_input(fr.crs)
            row["projection"] = crs.name
            try:
                params = {p.name: p.value for p in crs.coordinate_operation.params}  # type: ignore[union-attr]
                for key, lab in (("Longitude of natural origin", "central_meridian_deg"),
                                 ("Scale factor at natural origin", "scale_at_central_meridian"),
                                 ("False easting", "false_easting_m"), ("False northing", "false_northing_m")):
                    if key in params:
                        row[lab] = f"{params[key]:g}"
            except Exception:  # pragma: no cover - geographic CRS
                pass
            row["ellipsoid"] = crs.ellipsoid.name if crs.ellipsoid else ""
        row["heights"] = heights or fr.heights
        return row

    return [describe(data.trajectory_frame or WorldFrame.map("EPSG:4979"), "GNSS/IMU (trajectory)", "ellipsoidal"),
            describe(data.ground.frame, "ground control"),
            describe(frame, "common tangential frame (adjustments)", "ellipsoidal (Cartesian ENU)")]


# ------------------------------------------------------------------------------------------------ reports
def format_tables(result: dict[str, Any]) -> str:
    """The tables as plain text (what ``skyrig calibrate uncalibrated-gnss-imu`` prints)."""
    t = result["tables"]
    out = []
    out.append("Tab. 1: coordinate definitions")
    for r in t["table1_frames"]:
        out.append("  " + "; ".join(f"{k}: {v}" for k, v in r.items()))
    out.append("Tab. 2: shift in projection centres (GNSS minus bundle adjustment, mean per strip) [m]")
    out.append(f"  {'strip':>6} {'head':>6} {'X':>8} {'Y':>8} {'Z':>8} {'SX':>7} {'SY':>7} {'SZ':>7}   std of the "
               "per-image differences X Y Z")
    for r in t["table2_strip_shifts"]["rows"]:
        out.append(f"  {r['strip']:>6} {r['heading_deg']:6.0f} " + " ".join(f"{v:8.3f}" for v in r["shift_m"]) + " "
                   + " ".join(f"{v:7.3f}" for v in r["sigma_m"]) + "   "
                   + " ".join(f"{v:6.3f}" for v in r["scatter_m"]))
    a = t["antenna_offset"]
    out.append(f"  antenna offset (flight-direction dependent part): dx {a['dx_m']:.3f} +- {a['sigma_m'][0]:.3f} m, "
               f"dy {a['dy_m']:.3f} +- {a['sigma_m'][1]:.3f} m")
    out.append("Tab. 3: reference orientation steps")
    for r in t["table3_reference"]:
        out.append(f"  {r['step']:<14} ground {r['ground_points']:>5}  GNSS {r['gnss_points']:>4}  sigma0 "
                   f"{r['sigma0_um']:.2f} um  RMS ground {np.round(r.get('rms_ground_m', []), 3).tolist()}  RMS GNSS "
                   f"{np.round(r.get('rms_gnss_m', []), 3).tolist()}")
    m = t["table4_misalignment"]
    out.append(f"Tab. 4: angle and coordinate differences ({m['images']} images)")
    out.append(f"  {'':<22} {'pitch[gon]':>11} {'roll[gon]':>11} {'yaw[gon]':>11} {'X[m]':>8} {'Y[m]':>8} {'Z[m]':>8}")
    for key, lab in (("misalignment", "misalignment"), ("sigma", "sigma of the mean"),
                     ("rms_after_bias", "RMS after bias corr.")):
        r = m[key]
        out.append(f"  {lab:<22} {r['pitch_gon']:11.5f} {r['roll_gon']:11.5f} {r['yaw_gon']:11.5f} {r['X_m']:8.3f} "
                   f"{r['Y_m']:8.3f} {r['Z_m']:8.3f}")
    gc = m.get("grid_convergence_national_gon", {"min": float("nan"), "max": float("nan")})
    out.append(f"  meridian convergence: tangential frame {m['meridian_convergence_gon']['min']:.4f} .. "
               f"{m['meridian_convergence_gon']['max']:.4f} gon, national grid {gc['min']:.4f} .. {gc['max']:.4f} gon")
    out.append("Tab. 5: RMS differences at check points [m] (SX SY SZ)")
    for k, r in t["table5_check_points"].items():
        out.append(f"  {k} (sigma0 {r['sigma0_um']:.2f} um): ground points ({r['ground_points']['n']}) "
                   f"{np.round(r['ground_points']['rms_m'], 3).tolist()}; combined-adjustment points "
                   f"({r['combined_adjustment_points']['n']}) {np.round(r['combined_adjustment_points']['rms_m'], 3).tolist()}")
    r6 = t["table6_attitudes"]
    out.append(f"Tab. 6: RMS of attitude differences [gon] ({r6['images']} images)  S_phi S_omega S_kappa")
    for k in ("corrected_gnss_imu-combined", "iso-combined", "iso-corrected_gnss_imu"):
        v = r6[k]
        out.append(f"  {k:<30} {v['S_phi_gon']:.4f} {v['S_omega_gon']:.4f} {v['S_kappa_gon']:.4f}")
    t7 = t["table7_points_per_model"]
    out.append("Tab. 7: points per model  " + "  ".join(f"{b}: {n}" for b, n in zip(t7["bins"], t7["models"])))
    out.append("Tab. 8: models with RMS y-parallax  > 10 um  > 20 um  (max)")
    for k, v in t["table8_y_parallax"].items():
        out.append(f"  {k:<45} {v['over_10um']:>4} {v['over_20um']:>4}   ({v['max_rms_um'] or float('nan'):.1f} um of "
                   f"{v['models']} models)")
    return "\n".join(out)


def report_html(result: dict[str, Any]) -> str:
    """A self-contained HTML page with the tables."""
    esc = html.escape
    text = format_tables(result)
    res = result["result"]
    items = [(f"boresight misalignment {k} [gon]", res["boresight_misalignment_gon"][k], res["boresight_sigma_gon"][k], 5)
             for k in ("roll", "pitch", "yaw")]
    items += [(f"datum shift {k} (GNSS minus control) [m]", res["datum_shift_m"][k], res["datum_shift_sigma_m"][k], 3)
              for k in "XYZ"]
    items += [(f"antenna offset {k} [m]", res["antenna_offset_m"][k], res["antenna_offset_sigma_m"][k], 3)
              for k in ("dx", "dy")]
    rows = "".join(f"<tr><td>{esc(n)}</td><td>{v:.{d}f}</td><td>&plusmn; {s:.{d}f}</td></tr>" for n, v, s, d in items)
    rows += (f"<tr><td>calibrated antenna lever arm [m]</td><td colspan=2>"
             f"{esc(str(np.round(res['antenna_lever_arm_m'], 3).tolist()))}</td></tr>"
             f"<tr><td>calibrated head boresight omega, phi, kappa [deg]</td><td colspan=2>"
             f"{esc(str(np.round(res['head_boresight_opk_deg'], 6).tolist()))}</td></tr>")
    return ("<!doctype html><meta charset='utf-8'><title>uncalibrated-gnss-imu calibration</title>"
            "<h1>GNSS/IMU system calibration (paper 003 recipe)</h1>"
            f"<p>{result['images']} images, GSD {result['gsd_m']:.3f} m, reference strips "
            f"{esc(str(result['reference_strips']))}, frame {esc(result['frame'])}</p>"
            f"<h2>Result</h2><table border=1><tr><th>quantity</th><th>value</th><th>sigma</th></tr>{rows}</table><h2>Tables</h2><pre>{esc(text)}</pre>")
