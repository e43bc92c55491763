"""The ``calqc`` recipe: boresight, datum shift and interior orientation of a multi-head rig from a boresight
flight, then the three adjustment variants and a correction grid (paper 004, Madani: MIDAS penta camera,
sections 2.3, 3 and Tab. 11).

The paper calibrated with Applanix CalQC in four steps (2.3); :func:`calibrate_calqc` runs them as bundle
adjustments of the whole flight (every head, every flying height; one station per exposure, GNSS and IMU as
weighted observations, heads' boresights free in every step):

====  ============================  ===========================  =================  =================
step  interior orientation (IO)     GNSS datum (block) shift     ground points      blunder detection
====  ============================  ===========================  =================  =================
1     unlocked (free)               none (fixed at zero)         full control       on
2     locked at step 1              estimated                    full control       on
3     unlocked, started at step 1   locked at step 2             full control       on
4     locked at step 3              locked at step 2             all check points   off
====  ============================  ===========================  =================  =================

The IO is the principal distance and principal point of every head's camera (``f, x_p, y_p``; the paper's
PPAC).  Done once, the steps stop short of the joint solution: step 1 puts the datum shift into the IO (a
principal-distance error and a vertical shift both move the heights), step 2 then fits a datum shift to that IO.
So steps 2 and 3 are repeated (``max_cycles``) until neither the datum shift nor the IO changes by more than
0.05 of its sigma (in the simulated MIDAS flight 3-6 cycles); a last adjustment with IO, boresights and datum shift
free together, started at the converged values, gives their joint covariance (a step's own covariance, with the
other group locked, would be too optimistic).  Those values and that covariance are what the calibrated rig file
receives (each head's boresight and IO with sigma and correlations, provenance with the statistics); step 4, with
all of them locked, shows how the corrected GNSS/IMU orientations (the paper's POSEO) fit the check points.

**Separability.**  After every step the correlations of the calibration unknowns (boresights, IO, datum shift)
are examined; a pair above ``separability_limit`` (default 0.95) is named, in words, with the flight that would
separate it, and the flight is described (flying heights, strip directions: :func:`flight_geometry`).  A
boresight and a GNSS datum shift displace the ground alike when every strip is flown in one direction at one
height (the boresight's displacement turns with the aircraft and grows with the height, the shift does neither);
a principal distance and a vertical shift when there is one height; a principal point and a boresight always
nearly (only the field-angle terms of the image and relief tell them apart): paper 004 had strips in one
direction and separated the boresight thanks to its two GSDs.

**Design study** (:func:`design_study`, in the report per head as ``inseparable_by_head``).  Pairs miss groups (a
principal point may be stood in for by a boresight and a datum shift together), and a correlation says nothing about
which flight would help.  So, from the joint adjustment's covariance, each calibration unknown's multiple correlation
with all the others; and for each flight this one lacks (the opposite direction, cross strips, a second height) the
same block with that flight added virtually (:func:`virtual_flight`: every station again, turned or raised, its
images observing every object point they see, exactly) and its covariance.  An unknown is named with the flight that
shrinks its sigma most beyond what the added observations alone would (by at least 1.25), or that brings its
multiple correlation below the limit; one whose multiple correlation stays above the limit with every flight tried
is named as inseparable by any flight (a principal point with the boresight about the other image axis: a
laboratory calibration or a lock separates them).  Simulated MIDAS flight, one direction, both heights, 600 px:
the datum shift X / Y (multiple correlation 0.79) named with the opposite direction, predicted 0.14 and sigma 19.9
mm; the flight really flown both ways gives 0.13 and 20.3 mm; forward / backward principal distance sigma gain
predicted 1.73 / 1.80, real 1.68 / 1.73 (tests/test_calibrate_calqc_design.py).

**Variants and Tab. 11.**  With the calibrated rig and the GNSS positions corrected by the datum shift (the
paper's POSEO), each flying height's block is adjusted in the three variants of :mod:`skyrig.adjust.presets`
(``ba-eo-control``, ``dg-control``, ``refine-eo-check``); Tab. 11 lists per variant and block: GSD, sigma0 in
micrometres, RMS at control and check points, RMS of the photo positions (GNSS residuals) and attitudes (IMU
residuals), and the GPS block shift.  The column "refine" is the lowest block again after the correction grid.

**Correction grid by least-squares collocation** (:class:`CorrectionGrid`, :func:`collocation_grid`).  The
image residuals of the joint adjustment of the whole flight are, per camera, observations ``l = s + n`` of a
smooth systematic image deformation ``s`` (signal) plus white noise ``n``.  The empirical covariance of the
residuals (pairs binned by distance on the image) is fitted by a Gaussian ``C(d) = C0 exp(-(d/L)^2)``; its value
at zero distance above ``C0`` is the noise variance (the nugget).  The signal is the field the grid holds -
bilinear between nodes over the image format, the node values ``g`` with the covariance ``C`` of that function -
and ``g`` is predicted from all residuals at once, ``g = C B^T (B C B^T + D)^-1 l`` (``B``: the bilinear weights of
the residuals' positions on the nodes), with its posterior error covariance; however sparse the residuals, every
node gets a prediction and a sigma (unlike a mean per cell).  The nodes are as dense as the fitted correlation
length needs (:func:`grid_nodes_for`: bilinear interpolation loses at most 1 % of the signal's variance; a
fixed 13-node grid lost a fifth of a wave of two periods across the format, and with it the nadir principal
point 1.5 sigma).  The grid is interpolated bilinearly and subtracted from the image coordinates.

The grid and the calibration are estimated together, by default **in one adjustment**
(``grid_method="joint"``, :func:`joint_grid_adjustment`): the node values of every camera's grid are unknowns of
the joint adjustment (IO, boresights, datum shift), added bilinearly to the projection of each observation
(:mod:`skyrig.adjust.factors.image_grid`), with the collocation prior as an observation - zero mean, the node
covariance from the covariance function fitted to the joint adjustment's residuals (:func:`collocation_prior`,
nodes by :func:`grid_nodes_for`).  The prior keeps the grid from taking what the IO and the boresights explain at no
cost, and the data put a deformation where it belongs even when other unknowns could absorb it in part: a smooth
field on the nadir images moves the tie points, and the obliques' principal distances follow - a share that never
appears in the nadir residuals, so no grid made from residuals can return it.  The covariance function is refitted
to the whole deformation (residuals plus estimated grid) and the adjustment repeated while it moves by more than
10 % (``max_grid_cycles``).  The adjustment's covariance holds the grid's uncertainty.  Measured noise-free
(bench/calqc.py --size reduced --noise-free --deformation-px 0.3 --no-variants --grid --no-design, errors in
a-priori sigma): forward / backward principal distance -0.02 / -0.03 (the residual-grid cycles below: -0.59 /
-0.62), every boresight within 0.13, the nadir principal distance +0.52 (the wave's IO-like part on the grid's
nodes); with noise, seed 1: 32 of 33 within 2 sigma, the nadir grid 0.028 px RMS off the injected wave.  Over 20
seeds (bench/calqc_seeds.py --seeds 20 --camera-width 1200 --tie-points 1500 --deformation-px 0.3 --grid): forward
/ backward focal means -0.22 / -0.16 (residual-grid cycles: -0.57 / -0.52); pooled mean -0.08, std 0.79.  The nadir
head's unknowns scatter with std 0.3-0.5 of their sigma: their covariance holds the grid's prior uncertainty (the
deformation as a random field), while the simulation repeats one fixed wave in every seed, so the seeds sample the
noise only; the other heads' std 0.85 is that of the recipe's default sigmas (looser than the simulated noise).

**The stated covariance against the truth** (bench/calqc_seeds.py --seeds 20 --camera-width 600 --tie-points 800
--deformation-px 0.05 --deformation random --grid --sigmas simulated): the nadir deformation drawn anew in every
seed from the simulation's own Gaussian covariance (0.05 px RMS, about half the image noise, correlation length
0.2 of the width: :func:`random_field_deformation`), the grid's covariance function fitted by the recipe.  Fitted
to the plain residuals, the covariance lost the deformation's long-wavelength part (the part the IO and boresight
take) - c0 0.0016-0.0022 px^2 and L 81-120 px for 0.0025 and 120 - so the prior, and with it the nadir sigmas, were
too small: 9 seeds, nadir chi-square / n 1.61 (p 0.006), 6 of 9 seeds within the family-wise bound.  Fitted to the
detrended field against the detrended model (:func:`fit_covariance` ``detrend_format``; c0 0.0021-0.0035, L
103-229), 20 seeds, 660 z: pooled mean +0.00, std 1.02, KS p 0.76, chi-square / n 1.03 (p 0.58), 94.7 % within 2
sigma; per head chi-square / n 0.92-1.17; per parameter over the seeds the smallest KS p 0.073 (Sidak-corrected for
33: 0.92); whitened by the joint covariance (independent N(0, 1) if the correlations are right too) std 1.06,
chi-square / n 1.11 (two-sided p 0.047: at most about 5 % optimistic, e.g. the fitted covariance parameters taken as
known).  All 33 within 2 sigma in 6 of 20 seeds (N(0, 1): 21 %), all within the family-wise 95 % bound (Sidak,
3.16) in 19 of 20 (:func:`within_sigma_summary`).  tests/test_calibrate_calqc_seeds.py asserts it at 400 px.
That optimism is the fitted covariance function taken as known: over 40 seeds (seeds 1-40, the same bench
command) the errors whitened by the joint covariance gave chi-square / n 1.090 (p 0.023) with the fitted function,
1.060 (p 0.13) with the simulation's true one (c0 0.0025 px^2, L 120 px) put in its place, and 1.054 without
deformation and grid; paired by seed, fitted minus true +0.030 +- 0.019, true minus no grid +0.007 +- 0.023, and the
nadir head's own z's chi-square / n 1.104 fitted, 1.002 true.  The fit is uncertain (over the seeds sd 0.31 in
log c0 and 0.23 in log L: a 600 x 400 format holds few patches of a 120 px field), and the calibration moves with it.
So :func:`grid_hyperparameter_covariance` adds that spread to the covariance, to first order (Kackar and Harville):
the change of the calibration unknowns per unit of log c0 and log L (two more adjustments) with the fit's bootstrap
covariance (:func:`covariance_fit_spread`, ``grid_fit_draws`` = 16 fits of fields drawn from the fitted function).
Measured (40 seeds, same command): whitened chi-square / n 1.076 (p 0.056; paired against the function taken as
known -0.015 +- 0.003), pooled z chi-square / n 1.022 (p 0.57), std 1.011, KS p 0.98; the nadir z's 1.004; per
kind boresight 1.022, IO 1.048, datum 0.892; the largest sigma raised by 1.1-58 % (median 7.5 %), the median sigma by
0.01 %; the recipe 21 s instead of 14 s per seed (seed 1).  Only about half of the whitened gap to the true function
closes (the rest, 0.016 +- 0.019, is not resolved by 40 seeds: the stated covariance itself varies with the fit).
Full size with the wave (bench/calqc.py --size full --deformation-px 0.3 --no-variants --grid --no-design): 32 of
33 within 2 sigma (backward principal point y -2.04), the nadir grid 0.058 px RMS off the wave.

``grid_method="cycles"`` is the earlier scheme: the grid by collocation of the residuals, freed of the fields the
calibration unknowns make (shifts, radial scale, rotation and the projective terms of tilts over the format:
:func:`without_calibration_part`), the joint adjustment repeated on the coordinates it corrects, and a new grid from
those residuals plus the grid, until the IO changes by less than 0.1 sigma (``max_grid_cycles``);
``grid_uncertainty_draws`` propagates the grid's posterior (:meth:`CorrectionGrid.sample`) into the calibration
covariance by antithetic Monte-Carlo pairs (:func:`grid_uncertainty`; 0.3 px nadir wave, 1200 px cameras, seed 1,
4 pairs: sigmas up by at most 9.7 %, median 1.3 %).  It converges slowly along the share the obliques absorb:
noise-free forward / backward principal distance -4.69 / -2.97 a-priori sigma without a grid, -0.59 / -0.62 after 4
cycles, -0.25 / -0.28 after 15 while the nadir, left and right principal distances drift to +0.34 / +0.35 / +0.26.
Either way the calibration values, their covariance and step 4 are those of the corrected coordinates; Tab. 11's
"refine" column is the lowest block again with the grid; sigma0 and the check-point RMS before and after are
reported.

:func:`midas_calqc_scenario` simulates the boresight flight (``skyrig.simulate`` scenario ``midas``: 2,000 ft and
4,000 ft, strips in alternating directions) with IO errors, a GNSS datum shift and optionally a smooth image
deformation injected; ``directions="one"`` keeps the strips of one direction only.
"""

from __future__ import annotations

import html
import logging
from functools import lru_cache
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig._plain import plain
from skyrig.adjust.adjust import AdjustmentResult, DatumDefectError, adjust
from skyrig.adjust.block import AdjustConfig, Block
from skyrig.adjust.factors.image_grid import GridSpec
from skyrig.adjust.presets import PRESETS, apply_preset
from skyrig.adjust.rig_block import block_from_trajectory
from skyrig.adjust.stats import sidak_z
from skyrig.calibrate.rig_calibration import CovarianceBlock, HeadCalibration, Provenance, RigCalibration
from skyrig.errors import CalqcFailed, ConfigError, SkyrigError  # noqa: F401 - CalqcFailed re-exported
from skyrig.georef.eo import WorldFrame
from skyrig.georef.observations import GroundPoints, ImageMeasurements
from skyrig.geometry.rotations import rotvec_from_matrix
from skyrig.rig.rig import Rig
from skyrig.trajectory import CameraEvents, Trajectory

log = logging.getLogger(__name__)

__all__ = ["IO_PARAMETERS", "CalqcData", "CalqcCalibration", "CalqcFailed", "CorrectionGrid", "calibrate_calqc",
           "within_sigma_summary", "normalised_errors", "random_field_deformation", "collocation_grid",
           "fit_covariance", "flight_geometry", "midas_calqc_scenario", "calqc_data_from_survey",
           "format_tables", "report_html", "separability", "without_calibration_part", "calibration_part",
           "grid_nodes_for", "collocation_prior", "joint_grid_adjustment", "covariance_fit_spread",
           "grid_hyperparameter_covariance"]

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


@dataclass(frozen=True)
class ScenarioTruth:
    """What :func:`midas_calqc_scenario` injected (for tests and benches)."""

    boresight_rotvec_rad: dict[str, NDArray[np.float64]]  # per head, camera frame (the adjustment's correction)
    intrinsics: dict[str, dict[str, float]]  # per head: focal_mm, ppx_mm, ppy_mm of the true camera
    datum_shift_m: NDArray[np.float64]  # GNSS minus control, local ENU
    deformation: Callable[[NDArray[np.float64], str], NDArray[np.float64]] | None  # (pixel, head) -> d pixel
    frame: WorldFrame
    survey: Any = None

    def simulated_sigmas(self) -> dict[str, object]:
        """The recipe's a-priori sigma options equal to the noise the simulation drew (GNSS E/N/U, IMU
        roll/pitch/yaw, control, image) instead of the recipe's defaults."""
        e = self.survey.spec.errors
        px_um = self.survey.rig_recorded.head("nadir").camera.pixel_size_mm * 1000.0
        return {"gnss_sigma_m": tuple(float(v) for v in e.gnss_noise_m),
                "imu_sigma_deg": tuple(float(np.degrees(v)) for v in e.imu_noise_rad),
                "control_sigma_m": tuple(float(v) for v in e.gcp_sigma_m),
                "image_sigma_um": float(e.measurement_sigma_px * px_um)}


def wave_deformation(amplitude_px: float, width: int, height: int) -> Callable[[NDArray[np.float64]], NDArray]:
    """A smooth image deformation without mean, linear or radial part (not absorbed by the IO or the
    orientation): ``dx = a sin(2 pi u) cos(pi v)``, ``dy = a cos(pi u) sin(2 pi v)`` with ``u, v`` in [-1, 1]."""

    def d(pix: NDArray[np.float64]) -> NDArray[np.float64]:
        u = 2.0 * pix[:, 0] / (width - 1) - 1.0
        v = 2.0 * pix[:, 1] / (height - 1) - 1.0
        return amplitude_px * np.column_stack([np.sin(2 * np.pi * u) * np.cos(np.pi * v),
                                               np.cos(np.pi * u) * np.sin(2 * np.pi * v)])
    return d


@lru_cache(maxsize=4)
def _field_factor(amplitude_px: float, length_px: float, width: int, height: int, h: float
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The lattice of :func:`random_field_deformation` and a square root of the field's covariance on it."""
    xs = np.arange(-h, width - 1 + 2 * h, h)
    ys = np.arange(-h, height - 1 + 2 * h, h)
    gx, gy = np.meshgrid(xs, ys)
    nodes = np.column_stack([gx.ravel(), gy.ravel()])
    C = _gauss(np.linalg.norm(nodes[:, None, :] - nodes[None, :, :], axis=2), amplitude_px ** 2, length_px)
    lam, V = np.linalg.eigh(C)
    return xs, ys, V * np.sqrt(np.clip(lam, 0.0, None))


def random_field_deformation(amplitude_px: float, length_px: float, width: int, height: int,
                             rng: np.random.Generator, spacing_px: float | None = None
                             ) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
    """A draw of a smooth random image deformation: each component an independent zero-mean Gaussian field with
    the covariance ``amplitude^2 exp(-(d / length)^2)`` (the simulation's own; the recipe fits its covariance
    function from the residuals and is not told this one).  Drawn exactly (eigen-decomposition of the covariance)
    on a lattice ``spacing_px`` apart (default ``length / 6``) reaching one spacing beyond the format, and
    interpolated bicubically in between (for that spacing the interpolation error is far below 1 % of the field)."""
    from scipy.interpolate import RectBivariateSpline

    h = float(spacing_px) if spacing_px else float(length_px) / 6.0
    xs, ys, F = _field_factor(float(amplitude_px), float(length_px), int(width), int(height), h)
    vals = F @ rng.standard_normal((F.shape[1], 2))
    spl = [RectBivariateSpline(ys, xs, vals[:, c].reshape(len(ys), len(xs)), kx=3, ky=3) for c in range(2)]

    def d(pix: NDArray[np.float64]) -> NDArray[np.float64]:
        pix = np.asarray(pix, float)
        return np.column_stack([s(pix[:, 1], pix[:, 0], grid=False) for s in spl])
    return d


def midas_calqc_scenario(size: str = "full", seed: int = 1, *, directions: str = "both", tie_points: int | None = None,
                         io_error: Mapping[str, tuple[float, float, float]] | None = None,
                         datum_shift_m: tuple[float, float, float] = (0.25, -0.15, 0.2),
                         deformation_px: float = 0.0, deformation_heads: Sequence[str] = ("nadir",),
                         deformation: str = "wave", deformation_length: float = 0.2,
                         camera_width_px: int | None = None,
                         image_noise_um: float = 3.84, heights: str = "both",
                         error_overrides: Mapping[str, Any] | None = None) -> tuple[CalqcData, ScenarioTruth]:
    """The simulated MIDAS boresight flight (scenario ``midas``: strips at 2,000 ft and 4,000 ft, alternating
    directions; the scenario's head boresights and lever arms) with IO errors and a GNSS datum shift injected.

    ``size``: ``"full"`` (paper's cameras, 6 + 3 strips over 2.4 km) or ``"reduced"`` (a test block: 3 + 2
    strips over 1 km, cameras of ``camera_width_px`` (default 1200) pixels with the same field of view).
    ``directions="one"``: only the strips flown in the first strip's direction are kept; ``heights="low"``: only
    the lower flight.  ``io_error``: per head
    ``(d focal, d ppx, d ppy)`` mm, true minus recorded (default: a few micrometres per head).
    ``image_noise_um``: simulated image noise (paper 004's estimated sigma: 3.8 um).  ``deformation_px``: amplitude of a smooth image deformation (:func:`wave_deformation`) of the
    ``deformation_heads`` (0: none): ``deformation="wave"`` the same fixed wave in every seed
    (:func:`wave_deformation`), ``"random"`` a new draw per seed and head of a Gaussian random field
    (:func:`random_field_deformation`, RMS ``deformation_px`` per component, correlation length
    ``deformation_length`` times the camera's width), so that over seeds the deformation is a random field as the
    grid's prior assumes.  The IO errors and the deformation are applied to the simulated image
    measurements exactly (pixel -> ray with the recorded camera -> pixel with the true camera, plus the field).
    """
    from skyrig.simulate.scenarios import FlightSpec, build_survey, ci_camera, scenario_spec

    if size not in ("full", "reduced"):
        raise SkyrigError(f"size must be 'full' or 'reduced', not {size!r}")
    if heights not in ("both", "low"):
        raise SkyrigError(f"heights must be 'both' or 'low', not {heights!r}")
    if directions not in ("both", "one"):
        raise SkyrigError(f"directions must be 'both' or 'one', not {directions!r}")
    spec = scenario_spec("midas", "full", seed)
    if size == "reduced":
        w = int(camera_width_px or 1200)
        rig = replace(spec.rig, heads={n: h.with_(camera=ci_camera(h.camera, w)) for n, h in spec.rig.heads.items()})
        fls = (FlightSpec(609.6, 3, (-500, -500, 500, 500), speed_mps=60.0, forward_overlap=0.6),
               FlightSpec(1219.2, 2, (-500, -500, 500, 500), direction_deg=180.0, speed_mps=60.0))
        spec = replace(spec, rig=rig, flights=fls, scene_extent=(-2500, -2500, 2500, 2500), n_buildings=40,
                       n_gcp=12, n_check=4)
    elif camera_width_px:
        rig = replace(spec.rig, heads={n: h.with_(camera=ci_camera(h.camera, int(camera_width_px)))
                                       for n, h in spec.rig.heads.items()})
        spec = replace(spec, rig=rig)
    cam_px_um = {n: h.camera.pixel_size_mm * 1000.0 for n, h in spec.rig.heads.items()}
    n_tie = tie_points if tie_points is not None else (3000 if size == "full" else 1500)
    err = replace(spec.errors, tie_points=int(n_tie), datum_shift_m=tuple(float(v) for v in datum_shift_m),
                  gcp_sigma_m=(0.02, 0.02, 0.03), measurement_sigma_px=float(image_noise_um / cam_px_um["nadir"]))
    if error_overrides:  # e.g. noise-free GNSS / IMU / control for diagnosing a model mismatch
        err = replace(err, **dict(error_overrides))
    spec = replace(spec, errors=err)
    survey = build_survey(spec)
    if io_error is None:
        io_error = {"nadir": (0.012, 0.006, -0.008), "forward": (-0.015, 0.01, 0.005), "backward": (0.01, -0.006, 0.012),
                    "left": (0.008, 0.009, -0.007), "right": (-0.01, -0.008, 0.006)}
    rig_rec = survey.rig_recorded
    true_cams = {}
    for h in rig_rec:
        d = io_error.get(h.name, (0.0, 0.0, 0.0))
        c = h.camera
        true_cams[h.name] = c.with_(focal_mm=c.focal_mm + d[0], ppx_mm=c.ppx_mm + d[1], ppy_mm=c.ppy_mm + d[2])
    head_of = {str(n): str(h) for n, h in zip(survey.events_true.image_name, survey.events_true.head)}
    if deformation not in ("wave", "random"):
        raise SkyrigError(f"deformation must be 'wave' or 'random', not {deformation!r}")
    defs = {}
    drng = np.random.default_rng([int(seed), 4004])  # its own stream: the other draws stay those of the seed
    for hn in deformation_heads:
        if deformation_px > 0:
            c = rig_rec.head(hn).camera
            defs[hn] = (wave_deformation(deformation_px, c.width, c.height) if deformation == "wave" else
                        random_field_deformation(deformation_px, deformation_length * c.width, c.width, c.height,
                                                 drng))

    def distort(obs: dict[str, Any]) -> dict[str, Any]:
        img = np.asarray(obs["image"]).astype(str)
        heads = np.array([head_of[i] for i in img])
        pt = np.asarray(obs["pixel_true"], float)
        noise = np.asarray(obs["pixel"], float) - pt
        new = pt.copy()
        for h in rig_rec:
            sel = heads == h.name
            if not sel.any():
                continue
            rays = h.camera.rays_from_pixels(pt[sel])  # the recorded camera made pixel_true
            new[sel] = true_cams[h.name].project_pixels(rays)
            if h.name in defs:
                new[sel] += defs[h.name](new[sel])
        return {**obs, "pixel_true": new, "pixel": new + noise}

    survey = replace(survey, measurements=distort(survey.measurements),
                     tie_points=None if survey.tie_points is None else distort(survey.tie_points))
    data = calqc_data_from_survey(survey)
    if directions == "one" or heights == "low":
        n_low = spec.flights[0].n_strips
        st_keep = {}
        for i in range(len(survey.plan)):
            same = float(np.cos(survey.plan.heading_rad[i] - survey.plan.heading_rad[0])) > 0
            low = int(survey.plan.strip[i]) < n_low
            st_keep[i + 1] = (same or directions == "both") and (low or heights == "both")
        keep = {str(n) for n, x in zip(survey.events_recorded.image_name, survey.events_recorded.exposure_id)
                if st_keep[int(x)]}
        data = data.subset_images(sorted(keep))
    bore = {}
    for h in rig_rec:
        bt = survey.rig_true.head(h.name).boresight
        bore[h.name] = rotvec_from_matrix(h.boresight.T @ bt)
    intr = {n: {"focal_mm": c.focal_mm, "ppx_mm": c.ppx_mm, "ppy_mm": c.ppy_mm} for n, c in true_cams.items()}
    dfun: Callable[[NDArray[np.float64], str], NDArray[np.float64]] | None = None
    if defs:
        def _dfun(pix: NDArray[np.float64], head: str) -> NDArray[np.float64]:
            return defs[head](pix) if head in defs else np.zeros_like(pix)
        dfun = _dfun
    return data, ScenarioTruth(bore, intr, np.asarray(datum_shift_m, float), dfun, survey.frame, survey)


# ------------------------------------------------------------------------------------------------ collocation
def _gauss(d: NDArray[np.float64], c0: float, L: float) -> NDArray[np.float64]:
    return c0 * np.exp(-np.square(d / L))


@dataclass(frozen=True)
class CovarianceFit:
    """The fitted covariance function of a residual field: ``C(d) = c0 exp(-(d/L)^2)`` (signal, px^2 per
    component, ``L`` px) plus a nugget (white-noise variance, px^2); and the empirical bins it was fitted to."""

    c0: float
    length_px: float
    nugget: float
    bins_px: NDArray[np.float64]
    empirical: NDArray[np.float64]
    pairs: NDArray[np.int64]
    variance: float
    # how much better the signal explains the binned covariance than the nugget alone: the decrease of the bins'
    # chi-square (each bin's mean product with its white-noise standard error variance / sqrt(2 pairs)); NaN where
    # not computed (only the detrended fit does)
    significance: float = float("nan")

    def __call__(self, d: NDArray[np.float64]) -> NDArray[np.float64]:
        return _gauss(d, self.c0, self.length_px)


def calibration_basis(pix: NDArray[np.float64], width: int, height: int) -> NDArray[np.float64]:
    """The fields a camera's calibration unknowns make over its format, at ``pix (N, 2)``: ``(2N, 6)``, the x
    components of the N points then their y components, in the order of :data:`CALIBRATION_FIELDS` (shifts, radial
    scale, rotation and the two tilt terms, as :func:`without_calibration_part` removes them from a grid)."""
    cx, cy = 0.5 * (width - 1.0), 0.5 * (height - 1.0)
    scale = max(float(np.hypot(cx, cy)), 1.0)
    return _calibration_fields((np.asarray(pix, float)[:, 0] - cx) / scale, (np.asarray(pix, float)[:, 1] - cy) / scale)


def _calibration_fields(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(2N, 6)`` the calibration fields at centred, scaled coordinates ``x, y (N,)``: shifts (principal point),
    radial scale (principal distance), rotation (kappa), and the projective terms of a rotation about the image x and
    y axes (boresight omega, phi: dx, dy = (f + x^2/f, xy/f) and (xy/f, f + y^2/f)); x components then y."""
    one, zero = np.ones(len(x)), np.zeros(len(x))
    return np.column_stack([np.r_[one, zero], np.r_[zero, one], np.r_[x, y], np.r_[-y, x],
                            np.r_[x * x, x * y], np.r_[x * y, y * y]])


class _DetrendedModel:
    """For a unit-variance Gaussian field of correlation length ``L``, observed at ``xy`` and freed of its
    calibration part by least squares there (:func:`calibration_basis`): the expected empirical covariance in the
    distance bins ``edges`` (both components pooled as :func:`fit_covariance` pools them) and at zero distance
    (:meth:`__call__`).  The geometry is set up once; each length costs a few ``(m, m)`` products."""

    def __init__(self, xy: NDArray[np.float64], width: int, height: int, edges: NDArray[np.float64]) -> None:
        m = len(xy)
        Q, _ = np.linalg.qr(calibration_basis(xy, width, height))
        self.Qx, self.Qy = Q[:m], Q[m:]
        self.iu = np.triu_indices(m, 1)
        self.D = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=2)
        k = np.searchsorted(edges, self.D[self.iu], side="right") - 1
        self.inb = (k >= 0) & (k < len(edges) - 1)
        self.k = k[self.inb]
        self.nb = len(edges) - 1
        self.cnt = np.maximum(np.bincount(self.k, minlength=self.nb), 1)

    def __call__(self, L: float) -> tuple[NDArray[np.float64], float]:
        Qx, Qy = self.Qx, self.Qy
        C = _gauss(self.D, 1.0, float(L))
        CQx, CQy = C @ Qx, C @ Qy
        M = Qx.T @ CQx + Qy.T @ CQy
        # (I - P) blockdiag(C, C) (I - P), P = Q Q^T: the mean of its x-x and y-y blocks
        A = C - (Qx @ CQx.T + Qy @ CQy.T) + 0.5 * (Qx @ M @ Qx.T + Qy @ M @ Qy.T)  # (symmetric: QC^T = CQ^T)
        a = A[self.iu][self.inb]
        return np.bincount(self.k, weights=a, minlength=self.nb) / self.cnt, float(np.mean(np.diag(A)))


def fit_covariance(xy: NDArray[np.float64], v: NDArray[np.float64], max_distance: float, n_bins: int = 24,
                   max_points: int = 2500, seed: int = 0, detrend_format: tuple[int, int] | None = None,
                   model_points: int = 300) -> CovarianceFit:
    """Empirical covariance of a 2-vector field ``v`` at positions ``xy`` (mean removed; both components pooled),
    in ``n_bins`` distance bins up to ``max_distance``, fitted by a Gaussian plus a nugget (weighted by the
    number of pairs per bin; bins up to the first zero crossing of the empirical covariance).  Above ``max_points``
    positions a random subset estimates it.

    ``detrend_format=(width, height)``: the field is a residual field from which the calibration unknowns took
    their part (shifts, radial scale, rotation, tilts over that format), so it is freed of exactly that part by
    least squares, and the Gaussian is fitted to what such a detrended field's empirical covariance is expected
    to be (:class:`_DetrendedModel` on ``model_points`` of the positions), in every bin, its negative lobe
    included.  Without it a field's long-wavelength part, the part that goes into the IO and boresight, is missing
    from the residuals, and the fit returns too small a signal variance and correlation length (simulated MIDAS
    flight, 600 px, Gaussian nadir field of 0.05 px and 120 px: 0.0016-0.0022 px^2 and 81-120 px instead of 0.0025
    and 120), which makes the grid's prior, and with it the IO and boresight sigmas, too optimistic."""
    from scipy.optimize import curve_fit, minimize_scalar
    from scipy.spatial import cKDTree

    xy = np.asarray(xy, float)
    v = np.asarray(v, float) - np.mean(v, axis=0)
    if detrend_format is not None:
        B = calibration_basis(xy, *detrend_format)
        vv = np.r_[v[:, 0], v[:, 1]]
        vv = vv - B @ np.linalg.lstsq(B, vv, rcond=None)[0]
        v = np.column_stack([vv[:len(xy)], vv[len(xy):]])
    if len(xy) > max_points:
        sel = np.random.default_rng(seed).choice(len(xy), max_points, replace=False)
        xy, v = xy[sel], v[sel]
    var = float(np.mean(np.sum(v * v, axis=1)) / 2.0)
    edges = np.linspace(0.0, max_distance, n_bins + 1)
    pairs = cKDTree(xy).query_pairs(max_distance, output_type="ndarray")
    emp = np.full(n_bins, np.nan)
    cnt = np.zeros(n_bins, np.int64)
    if len(pairs):
        d = np.linalg.norm(xy[pairs[:, 0]] - xy[pairs[:, 1]], axis=1)
        prod = np.sum(v[pairs[:, 0]] * v[pairs[:, 1]], axis=1) / 2.0
        k = np.clip(np.searchsorted(edges, d, side="right") - 1, 0, n_bins - 1)
        cnt = np.bincount(k, minlength=n_bins)
        s = np.bincount(k, weights=prod, minlength=n_bins)
        emp = np.where(cnt > 0, s / np.maximum(cnt, 1), np.nan)
    centres = 0.5 * (edges[:-1] + edges[1:])
    ok = cnt >= 10
    if detrend_format is not None:
        sub = np.random.default_rng(seed + 1).choice(len(xy), min(len(xy), int(model_points)), replace=False)
        lo, hi = np.log(edges[1] * 0.5), np.log(2.0 * max_distance)
        wgt = np.where(ok, cnt, 0).astype(float)
        e0 = np.where(ok, emp, 0.0)

        model = _DetrendedModel(xy[sub], detrend_format[0], detrend_format[1], edges)

        def best(logL: float) -> tuple[float, float, float]:
            mk, z0 = model(float(np.exp(logL)))
            den = float(np.sum(wgt * mk * mk))
            c = float(np.clip(np.sum(wgt * e0 * mk) / den, 0.0, var / max(z0, 1e-9))) if den > 0 else 0.0
            return float(np.sum(wgt * (e0 - c * mk) ** 2)), c, z0

        grid_l = np.linspace(lo, hi, 25)
        costs = [best(g)[0] for g in grid_l]
        j = int(np.argmin(costs))
        r = minimize_scalar(lambda g: best(g)[0], bounds=(grid_l[max(j - 1, 0)], grid_l[min(j + 1, 24)]),
                            method="bounded", options={"xatol": 1e-3})
        cost, c0, z0 = best(float(r.x))
        L = float(np.exp(r.x))
        nugget = max(var - c0 * z0, 1e-6 * max(var, 1e-12))
        # the fit's weights are the pair counts; a bin's mean product of white noise has the standard error
        # var / sqrt(2 n) (two components), so the chi-square decrease is (sum w e^2 - cost) * 2 / var^2
        signif = float((np.sum(wgt * e0 * e0) - cost) * 2.0 / max(var, 1e-300) ** 2)
        return CovarianceFit(c0, L, nugget, centres, emp, cnt, var, signif)
    nonpos = np.flatnonzero(ok & ~(emp > 0))
    if nonpos.size:  # fit up to the first zero crossing (an oscillating field is not Gaussian beyond it)
        ok &= np.arange(n_bins) < max(int(nonpos[0]), 3)
    c0, L = 0.0, max_distance / 4.0
    if ok.sum() >= 3 and np.nanmax(emp[ok]) > 0:
        try:
            p, _ = curve_fit(_gauss, centres[ok], emp[ok], p0=(max(float(emp[ok][0]), 1e-12), max_distance / 4.0),
                             sigma=1.0 / np.sqrt(cnt[ok]), bounds=([0.0, edges[1] * 0.5], [max(var, 1e-12),
                                                                                          4.0 * max_distance]))
            c0, L = float(p[0]), float(p[1])
        except (RuntimeError, ValueError):  # pragma: no cover - no signal to fit
            c0 = 0.0
    nugget = max(var - c0, 1e-6 * max(var, 1e-12))
    return CovarianceFit(c0, L, nugget, centres, emp, cnt, var)


@dataclass(frozen=True)
class CorrectionGrid:
    """A correction grid of one camera: nodes over the image format (pixels) with the predicted systematic
    image error (``(ny, nx, 2)`` px, observed minus true) and its sigma (``(ny, nx)`` px per component).
    :meth:`correct` subtracts the bilinearly interpolated grid from pixel coordinates."""

    camera: str
    x_px: NDArray[np.float64]
    y_px: NDArray[np.float64]
    value_px: NDArray[np.float64]
    sigma_px: NDArray[np.float64]
    covariance: CovarianceFit
    n_residuals: int
    posterior_factor: NDArray[np.float64] | None = None  # F, node-value posterior covariance F F^T per component

    def sample(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """A draw of the grid's error from its posterior (``(ny, nx, 2)`` px; zero without a signal)."""
        if self.posterior_factor is None:
            return np.zeros_like(self.value_px)
        z = rng.standard_normal((self.posterior_factor.shape[1], 2))
        return (self.posterior_factor @ z).reshape(self.value_px.shape)

    def at(self, pix: NDArray[np.float64]) -> NDArray[np.float64]:
        """The grid interpolated at ``(N, 2)`` pixels (bilinear; clamped at the format's edges)."""
        from scipy.interpolate import RegularGridInterpolator

        p = np.column_stack([np.clip(pix[:, 1], self.y_px[0], self.y_px[-1]),
                             np.clip(pix[:, 0], self.x_px[0], self.x_px[-1])])
        out = np.empty((len(pix), 2))
        for c in range(2):
            out[:, c] = RegularGridInterpolator((self.y_px, self.x_px), self.value_px[:, :, c])(p)
        return out

    def correct(self, pix: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(pix, float) - self.at(np.asarray(pix, float))

    def to_dict(self) -> dict[str, Any]:
        cf = self.covariance
        return {"camera": self.camera, "nodes_x_px": self.x_px.tolist(), "nodes_y_px": self.y_px.tolist(),
                "correction_px": self.value_px.tolist(), "sigma_px": self.sigma_px.tolist(),
                "residuals": self.n_residuals,
                "covariance": {"function": "gaussian c0 exp(-(d/L)^2) + nugget", "c0_px2": cf.c0,
                               "length_px": cf.length_px, "nugget_px2": cf.nugget, "variance_px2": cf.variance,
                               "bins_px": cf.bins_px.tolist(),
                               "empirical_px2": [None if not np.isfinite(e) else float(e) for e in cf.empirical],
                               "pairs": cf.pairs.tolist()},
                "max_correction_px": float(np.max(np.linalg.norm(self.value_px, axis=2))),
                "mean_sigma_px": float(np.mean(self.sigma_px))}


def bilinear_interpolation_variance(cov: CovarianceFit, hx: float, hy: float) -> float:
    """Variance (px^2 per component) of the error of bilinear interpolation of a signal with covariance ``cov``
    from nodes ``hx`` by ``hy`` px apart, at a cell centre (the worst point): ``C0 - 2 w^T c + w^T C w`` with the
    four weights 1/4."""
    r = float(np.hypot(hx, hy)) / 2.0
    cc = [cov(np.array([r]))[0]] * 4
    d = [0.0, hx, hy, float(np.hypot(hx, hy))]  # corner-to-corner distances: itself, along x, along y, diagonal
    cw = cov(np.array(d))
    ww = (4 * cw[0] + 4 * cw[1] + 4 * cw[2] + 4 * cw[3]) / 16.0
    return float(max(cov.c0 - 2.0 * 0.25 * float(np.sum(cc)) + ww, 0.0))


def grid_nodes_for(cov: CovarianceFit, width: int, height: int, max_fraction: float = 0.01,
                   min_nodes: int = 5, max_nodes: int = 61) -> int:
    """The number of grid nodes across the format (``nodes_x``) such that bilinear interpolation between the
    nodes loses at most ``max_fraction`` of the signal's variance at the worst point (a cell centre), by the fitted
    covariance (:func:`bilinear_interpolation_variance`): a grid too coarse for the signal's correlation length
    cannot hold it, and what it cannot hold stays in the coordinates (and in whatever unknowns it resembles).  A
    loss below ``max_fraction`` of one coordinate's noise variance (the nugget) is accepted too: a weak signal (or a
    covariance fitted to noise) needs no fine grid.  No signal: 13 nodes."""
    if not cov.c0 > 0:
        return 13
    tol = max_fraction * max(cov.c0, cov.nugget)
    for n in range(max(int(min_nodes), 2), int(max_nodes) + 1):
        ny = max(2, int(round(n * height / width)))
        hx, hy = (width - 1.0) / (n - 1), (height - 1.0) / (ny - 1)
        if bilinear_interpolation_variance(cov, hx, hy) <= tol:
            return n
    return int(max_nodes)


def _bilinear_design(xs: NDArray[np.float64], ys: NDArray[np.float64], pix: NDArray[np.float64]) -> Any:
    """Sparse ``(N, ny * nx)`` matrix of the bilinear weights of each position on the nodes (row-major, y then
    x; positions clamped to the format)."""
    from scipy.sparse import csr_matrix

    from skyrig.adjust.factors.image_grid import bilinear_weights

    idx, w = bilinear_weights(xs, ys, pix)
    nx, ny = len(xs), len(ys)
    rows = np.repeat(np.arange(len(pix)), 4)
    cols = idx.ravel()
    w = w.ravel()
    return csr_matrix((w, (rows, cols)), shape=(len(pix), nx * ny))


def collocation_grid(camera: str, width: int, height: int, pix: NDArray[np.float64], error: NDArray[np.float64],
                     nodes_x: int | None = None, nodes_y: int | None = None,
                     cov: CovarianceFit | None = None) -> CorrectionGrid:
    """Least-squares collocation of a residual field onto a grid (module docstring).

    ``pix`` ``(N, 2)`` image positions, ``error`` ``(N, 2)`` observed systematic error samples (e.g. observed
    minus computed image coordinates, px).  The signal is the field the grid holds - bilinear between its nodes,
    the node values a Gaussian process with the covariance function ``cov`` (default: fitted,
    :func:`fit_covariance`, up to half the format's diagonal) - and the node values are its prediction from all
    samples at once: ``g = C B^T (B C B^T + D)^-1 l`` with ``B`` the bilinear weights of the samples on the nodes,
    ``C`` the covariance of the nodes and ``D`` the nugget, computed in the nodes' space (``C = L L^T``,
    ``g = L (I + L^T B^T B L / nugget)^-1 L^T B^T l / nugget``), with the posterior sigma of every node.  Being the
    field that is applied (not a prediction at the nodes interpolated afterwards), it leaves in the coordinates
    only what a grid of that spacing cannot hold; ``nodes_x`` (default :func:`grid_nodes_for`: fine enough for the
    fitted correlation length) sets the spacing.  The mean of ``error`` is the trend (added back)."""
    pix = np.asarray(pix, float)
    error = np.asarray(error, float)
    if len(pix) < 10:
        raise SkyrigError(f"camera {camera!r}: {len(pix)} residuals, too few for a correction grid")
    diag = float(np.hypot(width, height))
    if cov is None:
        cov = fit_covariance(pix, error, 0.5 * diag)
    nx = int(nodes_x) if nodes_x else grid_nodes_for(cov, width, height)
    mean = error.mean(axis=0)
    l = error - mean
    ny = nodes_y or max(2, int(round(nx * height / width)))
    xs = np.linspace(0.0, width - 1.0, nx)
    ys = np.linspace(0.0, height - 1.0, ny)
    gx, gy = np.meshgrid(xs, ys)
    nodes = np.column_stack([gx.ravel(), gy.ravel()])
    val = np.zeros((len(nodes), 2))
    var = np.full(len(nodes), cov.c0)
    if cov.c0 > 0:
        Cn = cov(np.linalg.norm(nodes[:, None, :] - nodes[None, :, :], axis=2))
        lam, V = np.linalg.eigh(Cn)
        keep = lam > 1e-10 * lam.max()  # a square root of the node covariance without its null directions
        Lh = V[:, keep] * np.sqrt(lam[keep])
        B = _bilinear_design(xs, ys, pix)
        BL = np.asarray(B @ Lh)
        S = np.eye(Lh.shape[1]) + (BL.T @ BL) / cov.nugget
        from scipy.linalg import cho_factor, cho_solve

        cf = cho_factor(S)
        val = Lh @ cho_solve(cf, BL.T @ l / cov.nugget)
        var = np.sum(Lh * cho_solve(cf, Lh.T).T, axis=1)
        from scipy.linalg import solve_triangular

        # posterior covariance of the node values (per component) = F F^T, F = Lh U^-1 (S = U^T U)
        factor = solve_triangular(np.triu(cf[0]) if not cf[1] else np.tril(cf[0]).T, Lh.T, trans="T", lower=False).T
    else:
        factor = None
    val += mean
    return CorrectionGrid(camera, xs, ys, val.reshape(ny, nx, 2),
                          np.sqrt(np.clip(var, 0.0, None)).reshape(ny, nx), cov, len(pix), factor)


def without_calibration_part(g: CorrectionGrid) -> CorrectionGrid:
    """The grid less its least-squares fit, over the nodes (uniform over the format), of the fields the
    calibration's own unknowns make: a shift in x and in y (principal point; boresight omega / phi), a radial
    scale about the format's centre (principal distance), a rotation about it (boresight kappa) and the projective
    terms of a rotation about the image axes (boresight omega / phi beside the principal point).

    The grid and those unknowns see the image residuals alike; without this a grid estimated from the residuals of
    an adjustment whose IO (or boresight) has absorbed part of a deformation keeps that part out of the grid for
    good, and the IO keeps its bias.  With it the grid holds only what the IO and the boresights cannot, and an
    IO estimated from coordinates corrected by the grid is free of the deformation's share (for a deformation
    without those parts on the format, e.g. :func:`wave_deformation`)."""
    coef, basis = _calibration_fit(g)
    v = np.r_[g.value_px[:, :, 0].ravel(), g.value_px[:, :, 1].ravel()]
    r = v - basis @ coef
    n = v.size // 2
    val = np.stack([r[:n].reshape(g.value_px.shape[:2]), r[n:].reshape(g.value_px.shape[:2])], axis=-1)
    return replace(g, value_px=val)


#: the fields of :func:`without_calibration_part`, in the order of :func:`calibration_part`'s coefficients
CALIBRATION_FIELDS = ("shift_x_px", "shift_y_px", "radial_scale", "rotation_rad", "tilt_about_y", "tilt_about_x")


def _calibration_fit(g: CorrectionGrid) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    gx, gy = np.meshgrid(g.x_px, g.y_px)
    cx, cy = 0.5 * (g.x_px[0] + g.x_px[-1]), 0.5 * (g.y_px[0] + g.y_px[-1])
    scale = max(float(np.hypot(cx, cy)), 1.0)  # one scale for x and y: the radial and rotation fields are isotropic
    basis = _calibration_fields((gx.ravel() - cx) / scale, (gy.ravel() - cy) / scale)
    v = np.r_[g.value_px[:, :, 0].ravel(), g.value_px[:, :, 1].ravel()]
    coef, *_ = np.linalg.lstsq(basis, v, rcond=None)
    return coef, basis


def calibration_part(g: CorrectionGrid) -> dict[str, float]:
    """The least-squares coefficients, over the grid's nodes, of the fields :func:`without_calibration_part`
    removes: shifts (px), radial scale (relative: a principal-distance change of ``f`` times it), rotation (rad)
    and the two tilt terms (px at the half diagonal)."""
    coef, _ = _calibration_fit(g)
    cx, cy = 0.5 * (g.x_px[0] + g.x_px[-1]), 0.5 * (g.y_px[0] + g.y_px[-1])
    scale = max(float(np.hypot(cx, cy)), 1.0)
    phys = coef.copy()
    phys[2] /= scale
    phys[3] /= scale
    return dict(zip(CALIBRATION_FIELDS, phys.tolist()))


def grid_from_result(res: AdjustmentResult, base: Mapping[str, CorrectionGrid] | None = None,
                     calibration_free: bool = False, **kw: Any) -> dict[str, CorrectionGrid]:
    """Per camera, the collocation grid of an adjustment's image residuals (observed minus computed).

    ``base``: grids the adjustment's coordinates were already corrected by; their values at the observations are
    added back, so the result is the whole deformation, not an increment (its sigma then describes the whole).
    ``calibration_free``: remove the part the calibration unknowns make (:func:`without_calibration_part`)."""
    b = res.block
    gr = res.residuals["image"]
    use = (gr.weight > 0) if gr.weight.ndim == 1 else (gr.weight > 0).all(axis=-1)
    out = {}
    cam_of_obs = b.image_camera[b.obs_image]
    for ci, cam in enumerate(b.cameras):
        sel = use & (cam_of_obs == ci)
        if sel.sum() < 10:
            continue
        err = -np.asarray(gr.residual)[sel]
        if base is not None and cam.name in base:
            err = err + base[cam.name].at(b.obs_pixel[sel])
        g = collocation_grid(cam.name, cam.width, cam.height, b.obs_pixel[sel], err, **kw)
        out[cam.name] = without_calibration_part(g) if calibration_free else g
    return out


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


def grid_uncertainty(block: Block, res: AdjustmentResult, grids: Mapping[str, CorrectionGrid], cfg: AdjustConfig,
                     draws: int = 8, seed: int = 0) -> NDArray[np.float64]:
    """The correction grids' posterior uncertainty propagated into the calibration unknowns (Monte Carlo).

    ``block``: the uncorrected block at the adjusted values of ``res`` (the joint adjustment on the coordinates the
    ``grids`` correct).  ``draws`` antithetic pairs: each grid plus and minus a draw from its posterior (the node
    values' full posterior covariance, :meth:`CorrectionGrid.sample`, less its calibration-like part as the grid
    itself), the joint adjustment again, and half the difference of the calibration unknowns; their mean outer
    product is the covariance to add to the adjustment's (the ``_cal_labels`` order of ``res``)."""
    rng = np.random.default_rng(seed)
    labels, _ = _cal_labels(res)

    cfg = cfg.with_(snooping=False, statistics=False)
    acc = np.zeros((len(labels), len(labels)))
    for _ in range(int(draws)):
        d = {k: without_calibration_part(replace(g, value_px=g.sample(rng))).value_px for k, g in grids.items()}
        pair = []
        for sign in (1.0, -1.0):
            gk = {k: replace(g, value_px=g.value_px + sign * d[k]) for k, g in grids.items()}
            pair.append(_cal_values(adjust(apply_grids(block, gk), cfg), labels))
        dv = 0.5 * (pair[0] - pair[1])
        acc += np.outer(dv, dv)
    return acc / max(int(draws), 1)


def covariance_fit_spread(xy: NDArray[np.float64], cov: CovarianceFit, width: int, height: int, draws: int = 16,
                          seed: int = 0) -> NDArray[np.float64]:
    """The sampling covariance of a detrended covariance fit (:func:`fit_covariance` with ``detrend_format``) in
    ``(log c0, log L)``, by parametric bootstrap: ``draws`` fields drawn from the fitted function itself
    (:func:`random_field_deformation`: the Gaussian signal, plus the nugget as white noise) at the positions ``xy``
    the fit used, each fitted again the same way.  Most of the spread is the field's own: a format only a few
    correlation lengths across holds few independent patches of it (600 x 400 px, L 120 px: sd of log c0 about
    0.3-0.45, of log L about 0.2)."""
    rng = np.random.default_rng([int(seed), 1207])
    max_d = 0.5 * float(np.hypot(width, height))
    # the lattice of the draw no finer than about 1500 nodes (its eigen-decomposition), however short the length
    spacing = max(cov.length_px / 6.0, float(np.sqrt(width * height / 1500.0)))
    out = []
    for _ in range(int(draws)):
        f = random_field_deformation(float(np.sqrt(cov.c0)), cov.length_px, width, height, rng, spacing)
        v = f(xy) + np.sqrt(max(cov.nugget, 0.0)) * rng.standard_normal((len(xy), 2))
        cf = fit_covariance(xy, v, max_d, detrend_format=(width, height))
        out.append([np.log(max(cf.c0, 1e-3 * cov.c0) / cov.c0), np.log(cf.length_px / cov.length_px)])
    return np.atleast_2d(np.cov(np.asarray(out).T))


def grid_hyperparameter_covariance(res: AdjustmentResult, grids: Mapping[str, CorrectionGrid], cfg: AdjustConfig,
                                   draws: int = 16, step: float = 0.1, seed: int = 0
                                   ) -> tuple[NDArray[np.float64], dict[str, list[list[float]]]]:
    """What the calibration covariance of the joint grid adjustment (:func:`joint_grid_adjustment`) omits: its
    collocation prior uses the covariance function fitted from the data as if it were known.  The estimated
    calibration unknowns move with the fitted signal variance ``c0`` and correlation length ``L``; to first order
    (Kackar and Harville 1984, estimated variance components) their covariance gains ``J S J^T``: ``J`` the change of
    the unknowns per unit of ``log c0`` and ``log L`` (the adjustment again with each one changed by ``step``, from
    its converged values), ``S`` the fit's sampling covariance in those (:func:`covariance_fit_spread`, ``draws``
    bootstrap fits at the positions of the camera's residuals), summed over the grids' cameras.

    ``res``: the joint adjustment with the grids' node values as unknowns; ``grids``: its grids.  Returns the
    covariance to add (the ``_cal_labels`` order of ``res``) and, per camera, ``S``."""
    from skyrig.adjust.factors.image_grid import ImageGrids

    labels, _ = _cal_labels(res)
    est = res.block.observations.get("image_grid")
    out = np.zeros((len(labels), len(labels)))
    spreads: dict[str, list[list[float]]] = {}
    if est is None or not grids:
        return out, spreads
    cfg_v = cfg.with_(image_grid="weighted", snooping=False, statistics=False)
    v0 = _cal_values(res, labels)
    sel_of = _grid_residuals(res)
    names = [c.name for c in res.block.cameras]
    for g in est.grids:
        cg = grids.get(g.camera)
        if cg is None:
            continue
        ci = names.index(g.camera)
        cam = res.block.cameras[ci]
        cf = cg.covariance
        S = covariance_fit_spread(res.block.obs_pixel[sel_of[ci][0]], cf, cam.width, cam.height, draws, seed + ci)
        J = []
        for dc, dl in ((step, 0.0), (0.0, step)):
            cf2 = replace(cf, c0=cf.c0 * float(np.exp(dc)), length_px=cf.length_px * float(np.exp(dl)))
            specs = []
            for h in est.grids:
                if h.camera == g.camera:  # the same nodes, the prior of the changed function
                    sp = collocation_prior(h.camera, cam.width, cam.height, cf2, nodes_x=len(h.x_px))
                    sp.value_px = h.value_px.copy()
                    specs.append(sp)
                else:
                    specs.append(h)
            blk = replace(res.block, observations={**res.block.observations, "image_grid": ImageGrids(specs)})
            J.append((_cal_values(_run(blk, cfg_v, f"grid prior of {g.camera} changed"), labels) - v0) / step)
        Jm = np.column_stack(J)
        out += Jm @ S @ Jm.T
        spreads[g.camera] = S.tolist()
    return out, spreads


def collocation_prior(camera: str, width: int, height: int, cov: CovarianceFit, nodes_x: int | None = None,
                      max_fraction: float = 0.01) -> GridSpec:
    """The correction grid of a camera as unknowns of the adjustment: its nodes (``nodes_x`` across, default
    :func:`grid_nodes_for`, the spacing least-squares collocation would use) and the collocation prior of the node
    values (zero mean; covariance ``C(d)`` of the fitted function at the node distances, plus ``max_fraction`` of
    ``c0`` on the diagonal: what bilinear interpolation between nodes of that spacing loses at most, which also keeps
    the prior's inverse bounded), for :mod:`skyrig.adjust.factors.image_grid`."""
    nx = int(nodes_x) if nodes_x else grid_nodes_for(cov, width, height, max_fraction)
    ny = max(2, int(round(nx * height / width)))
    xs = np.linspace(0.0, width - 1.0, nx)
    ys = np.linspace(0.0, height - 1.0, ny)
    gx, gy = np.meshgrid(xs, ys)
    nodes = np.column_stack([gx.ravel(), gy.ravel()])
    C = cov(np.linalg.norm(nodes[:, None, :] - nodes[None, :, :], axis=2))
    C = C + max_fraction * cov.c0 * np.eye(len(nodes))
    return GridSpec(camera, xs, ys, np.zeros((ny, nx, 2)), C)


def _grid_residuals(res: AdjustmentResult) -> dict[int, tuple[NDArray[np.bool_], NDArray[np.float64]]]:
    """Per camera index, the rows used and the whole systematic error at them (observed minus computed, plus the
    correction grid the adjustment already estimated or applied there)."""
    b = res.block
    gr = res.residuals["image"]
    use = (gr.weight > 0) if gr.weight.ndim == 1 else (gr.weight > 0).all(axis=-1)
    err = -np.asarray(gr.residual, float)
    grids = b.observations.get("image_grid")
    cam_of_obs = b.image_camera[b.obs_image]
    names = [c.name for c in b.cameras]
    if grids is not None:
        for g in grids.grids:
            ci = names.index(g.camera)
            sel = cam_of_obs == ci
            err[sel] += CorrectionGrid(g.camera, g.x_px, g.y_px, g.value_px, np.zeros(g.value_px.shape[:2]),
                                       None, 0).at(b.obs_pixel[sel])  # type: ignore[arg-type]
    return {ci: (use & (cam_of_obs == ci), err) for ci in range(len(b.cameras))}


def joint_grid_adjustment(block: Block, res: AdjustmentResult, cfg: AdjustConfig, nodes_x: int | None = None,
                          max_cycles: int = 3, what: str = "joint (IO, boresights, datum shift) with correction grids",
                          min_signal_fraction: float = 0.05, min_signal_chi2: float = 25.0,
                          cameras: Sequence[str] | None = None
                          ) -> tuple[AdjustmentResult, dict[str, CorrectionGrid], int]:
    """The correction grids estimated *in* the adjustment, together with the calibration (module docstring).

    ``block``: the block at the values of ``res`` (an adjustment without grids, e.g. the joint one); ``cfg`` its
    configuration.  Per camera, the residuals of ``res`` give the covariance function (:func:`fit_covariance`) and
    from it the nodes and the collocation prior (:func:`collocation_prior`); the block is adjusted with the node
    values as unknowns (``image_grid="weighted"``).  The covariance function is fitted again to the whole
    deformation (the new residuals plus the estimated grid) and the adjustment repeated while its signal variance or
    correlation length moves by more than 10 % (``max_cycles`` adjustments at most).  Returns the adjustment (its
    covariance holds the grids' uncertainty), the grids (values and posterior sigma from it) and the cycles run.

    ``min_signal_fraction``: a camera whose fitted signal variance is below this fraction of its noise variance gets
    no grid.  A covariance fitted to noise can show a weak signal with a correlation length of a few pixels, and
    :func:`grid_nodes_for` then asks for thousands of nodes (simulated MIDAS flight, 1200 px, seed 2: a 52 x 35 grid
    for a forward-camera "signal" of 1.4 % of the noise variance with a 15 px correlation length), which costs time
    and changes nothing: without those grids the recipe ran 77 s instead of 695 s, the nadir grid and the IO the same
    to 0.06 sigma).  Default 5 % (a signal RMS under 0.22 of the noise sigma); 0 gives every camera with a fitted
    signal its grid.  A camera whose fitted correlation length is under the width of the first distance bin gets
    no grid either: the fit then rests on that one bin's excess over the nugget (simulated MIDAS flight, 600 px,
    random nadir field, seed 2: forward camera c0 10 % of the noise, L 7.5 px = half a bin, the first bin 2 standard
    errors above zero and the others at zero), is not resolved from noise, and would ask for the most nodes
    (61 across).  Nor does a camera whose fitted signal lowers the chi-square of the binned covariance (against
    the nugget alone, white-noise standard errors) by less than ``min_signal_chi2`` (default 25, i.e. a 5-sigma
    signal; 400 px, seed 1: an oblique "signal" at L 12 px passed the two rules above and cost minutes).
    ``cameras``: the camera names that may get a grid (default: every camera)."""
    from skyrig.adjust.factors.image_grid import ImageGrids

    cfg_g = cfg.with_(image_grid="weighted")
    b0 = block
    fits: dict[str, CovarianceFit] = {}
    r, cycles = res, 0
    for cycles in range(1, int(max_cycles) + 1):
        rb = r.block
        specs = []
        new_fits = {}
        prev = rb.observations.get("image_grid")
        prev_by = {g.camera: g for g in prev.grids} if prev is not None else {}
        for ci, (sel, err) in _grid_residuals(r).items():
            cam = rb.cameras[ci]
            if sel.sum() < 10 or (cameras is not None and cam.name not in cameras):
                continue
            max_d = 0.5 * float(np.hypot(cam.width, cam.height))
            # (the residuals lack the part of the deformation the IO and boresight took: fitted as detrended)
            cf = fit_covariance(rb.obs_pixel[sel], err[sel], max_d, detrend_format=(cam.width, cam.height))
            if not cf.c0 > 0 or cf.c0 < min_signal_fraction * cf.nugget:
                continue
            if cf.significance < min_signal_chi2:
                # pairs share points, so the bins are not independent; the bar is set far above noise's values
                log.info("calqc grid %s: no grid (the fitted signal, c0 %.2g px^2, L %.0f px, lowers the binned "
                         "covariance's chi-square by only %.1f < %.0f: not told from noise)", cam.name, cf.c0,
                         cf.length_px, cf.significance, min_signal_chi2)
                continue
            if cf.length_px < max_d / len(cf.bins_px):
                # a correlation length under the first distance bin: only that bin's excess over the nugget carries
                # the "signal" (the fit sits at its lower bound), which is not resolved and is as likely noise
                log.info("calqc grid %s: no grid (fitted correlation length %.1f px under the %.1f px distance bin; "
                         "c0 %.2g px^2 is not resolved from the noise)", cam.name, cf.length_px,
                         max_d / len(cf.bins_px), cf.c0)
                continue
            new_fits[cam.name] = cf
            spec = collocation_prior(cam.name, cam.width, cam.height, cf, nodes_x)
            old = prev_by.get(cam.name)
            if old is not None and old.value_px.shape == spec.value_px.shape:
                spec.value_px = old.value_px.copy()  # the same nodes: start from the last estimate
            specs.append(spec)
        if not specs:
            return r, {}, cycles - 1
        moved = (not fits or set(fits) != set(new_fits) or any(
            abs(new_fits[k].c0 / fits[k].c0 - 1) > 0.1 or abs(new_fits[k].length_px / fits[k].length_px - 1) > 0.1
            for k in new_fits))
        if not moved:
            cycles -= 1
            break
        fits = new_fits
        bg = replace(b0, cameras=list(rb.cameras), head_boresight=rb.head_boresight.copy(),
                     datum_shift=rb.datum_shift.copy(), lever_arm=rb.lever_arm.copy(),
                     observations={**b0.observations, "image_grid": ImageGrids(specs)})
        r = _run(bg, cfg_g, f"{what}, cycle {cycles}")
        for k, cf in fits.items():
            log.info("calqc grid %s: c0 %.4f px^2, L %.0f px, nugget %.4f px^2", k, cf.c0, cf.length_px, cf.nugget)
    grids: dict[str, CorrectionGrid] = {}
    est = r.block.observations.get("image_grid")
    if est is not None and r.covariance is not None:
        lab = r.layout.labels
        pos = {q: j for j, q in enumerate(lab)}
        Q = r.covariance.Qcc * r.sigma0 ** 2
        for g in est.grids:
            ny, nx = g.value_px.shape[:2]
            ix = [pos[("image_grid", g.camera, f"x{iy}_{jx}")] for iy in range(ny) for jx in range(nx)]
            Qx = Q[np.ix_(ix, ix)]
            lam, V = np.linalg.eigh(0.5 * (Qx + Qx.T))
            factor = V * np.sqrt(np.clip(lam, 0.0, None))
            ci = [c.name for c in r.block.cameras].index(g.camera)
            n_obs = int(np.sum(r.block.image_camera[r.block.obs_image] == ci))
            # the posterior sigma and factor of the x values (the prior is the same for y; their posteriors differ
            # only by the observations' geometry)
            grids[g.camera] = CorrectionGrid(g.camera, g.x_px, g.y_px, g.value_px.copy(),
                                             np.sqrt(np.clip(np.diag(Qx), 0.0, None)).reshape(ny, nx),
                                             fits[g.camera], n_obs, factor)
    return r, grids, cycles


def apply_grids(block: Block, grids: Mapping[str, CorrectionGrid]) -> Block:
    """The block with each camera's image coordinates corrected by its grid."""
    px = block.obs_pixel.copy()
    cam_of_obs = block.image_camera[block.obs_image]
    for ci, cam in enumerate(block.cameras):
        g = grids.get(cam.name)
        sel = cam_of_obs == ci
        if g is not None and sel.any():
            px[sel] = g.correct(px[sel])
    return replace(block, obs_pixel=px)


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
        vr = adjust(vb, cfg.with_(snooping=False, max_iterations=1, statistics=True))
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


# ------------------------------------------------------------------------------------------------ result
@dataclass
class CalqcCalibration:
    """The recipe's result (module docstring); :meth:`to_dict` is the JSON report."""

    rig_in: Rig
    rig: Rig
    frame: WorldFrame
    boresight: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]]  # head -> rotvec (rad, camera), cov
    interior: dict[str, tuple[tuple[str, ...], NDArray[np.float64], NDArray[np.float64]]]  # head -> names, vals, cov
    datum_shift_m: NDArray[np.float64]
    datum_shift_cov_m2: NDArray[np.float64]
    steps: list[dict[str, Any]]
    table11: dict[str, Any]
    grids: dict[str, CorrectionGrid]
    grid_effect: dict[str, Any]
    inseparable: list[dict[str, Any]]
    geometry: dict[str, Any]
    statistics: dict[str, float] = field(default_factory=dict)
    design: dict[str, Any] = field(default_factory=dict)  # :func:`design_study` of the joint adjustment
    notes: list[str] = field(default_factory=list)  # what the recipe did differently from the plain steps, and why
    # the joint covariance of every calibration unknown (boresights, IO, datum shift), labels (group, owner, name):
    # the blocks above are its parts; a simulation whitens its errors with it (bench/calqc_seeds.py)
    covariance_labels: list[tuple[str, str, str]] = field(default_factory=list)
    covariance: NDArray[np.float64] | None = None

    def rig_calibration(self, flight: str = "", date: str = "", software: str = "",
                        previous: RigCalibration | None = None) -> RigCalibration:
        """Each head's boresight (omega, phi, kappa about the camera axes, deg) and IO block with provenance."""
        prov = Provenance("calqc", flight, date, software, dict(self.statistics),
                          notes=("paper 004 recipe (CalQC four steps, steps 2-3 repeated to convergence); boresight and "
                                 "interior orientation with their joint covariance (IO, boresights and datum shift "
                                 "free together at the converged values); GNSS datum shift (GNSS "
                                 f"minus control, local ENU) {np.round(self.datum_shift_m, 3).tolist()} m is not part "
                                 "of the rig"))
        heads = dict(previous.heads) if previous is not None else {}
        for h in self.rig.head_names:
            old = heads.get(h, HeadCalibration())
            bore = io = None
            if h in self.boresight:
                _, cov = self.boresight[h]
                bore = CovarianceBlock.from_covariance(("omega", "phi", "kappa"), cov * (180.0 / np.pi) ** 2)
            if h in self.interior:
                names, vals, cov = self.interior[h]
                io = CovarianceBlock.from_covariance(names, cov)
            heads[h] = HeadCalibration(old.lever_arm_m, bore or old.boresight_opk_deg, io or old.interior,
                                       old.actuator, prov)
        return RigCalibration(heads, previous.antenna_lever_arm_m if previous is not None else None, prov)

    def to_dict(self) -> dict[str, Any]:
        res = {"boresight": {}, "interior_orientation": {}}
        for h, (v, cov) in self.boresight.items():
            res["boresight"][h] = {"rotvec_mdeg": (np.degrees(v) * 1000).tolist(),
                                   "sigma_mdeg": (np.degrees(np.sqrt(np.diag(cov))) * 1000).tolist(),
                                   "axes": "camera x, y, z (rotation vector of the correction)",
                                   "opk_deg": list(self.rig.head(h).boresight_opk(unit="deg"))}
        for h, (names, v, cov) in self.interior.items():
            res["interior_orientation"][h] = {n: {"value_mm": float(x), "sigma_mm": float(np.sqrt(cov[k, k])),
                                                  "start_mm": float(dict(zip(self.rig_in.head(h).camera.intrinsic_names,
                                                                             self.rig_in.head(h).camera.intrinsics))[n])}
                                              for k, (n, x) in enumerate(zip(names, v))}
        res["datum_shift_m"] = self.datum_shift_m.tolist()
        res["datum_shift_sigma_m"] = np.sqrt(np.diag(self.datum_shift_cov_m2)).tolist()
        geom = {k: v for k, v in self.geometry.items() if k not in ("station_level", "heading_per_station_deg")}
        return _plain({"recipe": "calqc", "paper": "004 (Madani, MIDAS)", "frame": self.frame.describe(),
                       "flight": geom, "result": res, "steps": self.steps, "inseparable": self.inseparable,
                       "inseparable_by_head": self.design, "notes": list(self.notes),
                       "table11": self.table11, "correction_grid": {k: g.to_dict() for k, g in self.grids.items()},
                       "correction_grid_effect": self.grid_effect, "statistics": self.statistics})


def _plain(v: Any) -> Any:
    return plain(v, nan_as_none=True)


# ------------------------------------------------------------------------------------------------ the recipe
def _step_row(step: str, res: AdjustmentResult, block: Block, cfg: AdjustConfig) -> dict[str, Any]:
    b = res.block
    ctrl = ~b.control_check
    d = b.point_xyz[b.control_point] - b.control_xyz
    row = {"step": step, "io": cfg.intrinsics, "datum_shift": cfg.datum_shift, "control": int(ctrl.sum()),
           "check": int((~ctrl).sum()), "blunder_detection": bool(cfg.snooping), "sigma0": res.sigma0,
           "sigma_um": _sigma_um(block, res.sigma0), "redundancy": res.redundancy, "rejected": len(res.rejected),
           "rms_control_m": _rms(d[ctrl]), "rms_check_m": _rms(d[~ctrl]),
           "datum_shift_m": b.datum_shift.tolist()}
    return row


def _variant_column(res: AdjustmentResult, block: Block, gsd_m: float, variant: str) -> dict[str, Any]:
    b = res.block
    ctrl = ~b.control_check
    d = b.point_xyz[b.control_point] - b.control_xyz
    col: dict[str, Any] = {"gsd_cm": 100.0 * gsd_m, "sigma_um": _sigma_um(block, res.sigma0), "sigma0": res.sigma0,
                           "rms_control_m": _rms(d[ctrl]) if ctrl.any() else None,
                           "rms_check_m": _rms(d[~ctrl]) if (~ctrl).any() else None,
                           "images": int(block.n_images), "control": int(ctrl.sum()), "check": int((~ctrl).sum())}
    g = res.residuals.get("gnss")
    m = res.residuals.get("imu")
    fixed_poses = res.config.poses == "fixed"
    col["rms_photo_position_m"] = None if fixed_poses or g is None else _rms(np.asarray(g.residual))
    col["rms_photo_attitude_deg"] = None if fixed_poses or m is None else np.degrees(_rms(np.asarray(m.residual))).tolist()
    col["gps_block_shift_m"] = b.datum_shift.tolist() if res.config.datum_shift != "fixed" else None
    return col


def calibrate_calqc(
    data: CalqcData,
    *,
    image_sigma_um: float = 4.0,
    gnss_sigma_m: tuple[float, float, float] = (0.05, 0.05, 0.05),
    imu_sigma_deg: tuple[float, float, float] = (0.003, 0.003, 0.006),
    control_sigma_m: tuple[float, float, float] = (0.05, 0.05, 0.05),
    io_parameters: Sequence[str] = IO_PARAMETERS,
    separability_limit: float = 0.95,
    max_cycles: int = 10,
    grid_nodes: int | None = None,
    grid: bool = True,
    variants: bool = True,
    max_grid_cycles: int = 4,
    grid_uncertainty_draws: int = 0,
    design: bool = True,
    grid_method: str = "joint",
    grid_min_signal_fraction: float = 0.05,
    grid_heads: Sequence[str] | None = None,
    grid_fit_draws: int = 16,
) -> CalqcCalibration:
    """Run the paper-004 recipe (module docstring) on a boresight flight.

    ``image_sigma_um``: a-priori sigma of an image coordinate (paper 004: 4 um, 0.6 px of 6.4 um).  The
    GNSS, IMU and control sigmas are those of the data (paper: 5 cm, and 0.05 deg for its IMU attitudes).
    Raises :class:`CalqcFailed` when a step fails; an inseparable pair of unknowns is not a failure of the step
    (it is reported in ``inseparable``) unless the normal equations are singular.

    ``grid_method``: ``"joint"`` (default) estimates the correction grids' node values in the adjustment with their
    collocation prior (:func:`joint_grid_adjustment`; its covariance holds the grids' uncertainty, so
    ``grid_uncertainty_draws`` is not needed and ignored); ``"cycles"`` the earlier scheme, grids by collocation of
    the residuals alternating with the joint adjustment (``max_grid_cycles``).  ``grid_min_signal_fraction``: see
    :func:`joint_grid_adjustment`.  ``grid_heads``: the heads that may get a grid with ``grid_method="joint"``
    (default every head whose residuals show a signal).  ``grid_fit_draws``: with ``grid_method="joint"`` and a
    grid, the uncertainty of the grid's fitted covariance function (``grid_fit_draws`` bootstrap fits) is propagated
    into the calibration covariance (:func:`grid_hyperparameter_covariance`); 0: the function is taken as known."""
    if grid_method not in ("joint", "cycles"):
        raise ConfigError(f"calibrate_calqc: grid_method must be 'joint' or 'cycles', got {grid_method!r}")
    rig = data.rig
    sig_px = float(image_sigma_um) / (rig.head(rig.head_names[0]).camera.pixel_size_mm * 1000.0)
    imu_sig = tuple(float(np.radians(v)) for v in imu_sigma_deg)

    def build(d: CalqcData, r: Rig, check: Sequence[str], frame: WorldFrame | None) -> tuple[Block, WorldFrame]:
        return block_from_trajectory(d.trajectory, r, d.events, d.measurements, d.ground, gnss_sigma_m=gnss_sigma_m,
                                     imu_sigma_rad=imu_sig, control_sigma_m=control_sigma_m,
                                     check_points=tuple(check), sigma_px=sig_px, frame=frame)

    block0, frame = build(data, rig, data.check_names, None)
    geom = flight_geometry(block0)
    io_names = tuple(io_parameters)
    cal_common = dict(boresight="free", statistics=True)
    steps: list[dict[str, Any]] = []
    inseparable: list[dict[str, Any]] = []
    notes: list[str] = []

    def record(step: str, res: AdjustmentResult, blk: Block, cfg: AdjustConfig) -> None:
        steps.append(_step_row(step, res, blk, cfg))
        for e in separability(res, geom, separability_limit):
            e = {**e, "step": step}
            if not any(x["text"] == e["text"] for x in inseparable):
                inseparable.append(e)

    # step 1: IO unlocked, no datum shift, full control, blunder detection
    cfg1 = AdjustConfig(intrinsics="free", intrinsic_names=io_names, datum_shift="fixed", snooping=True, **cal_common)
    try:
        r1 = _run(block0, cfg1, "step 1 (IO unlocked, no datum shift)")
    except CalqcFailed as exc:
        # step 1 has no datum shift by design: with precise control and a GNSS datum shift, data snooping rightly
        # calls the control-point misfit a model error and stops.  Step 1 only gives the IO its start (its
        # rejections are not carried on; steps 2-3 estimate the shift with their own snooping), so it is run again
        # without blunder detection and the stop is kept in the report.
        if "snooping stopped" not in str(exc):
            raise
        log.warning("calqc step 1: %s; step 1 repeated without blunder detection (step 2 estimates the datum shift)",
                    exc)
        notes.append(f"step 1: {exc}; repeated without blunder detection (the datum shift is step 2's)")
        cfg1 = cfg1.with_(snooping=False)
        r1 = _run(block0, cfg1, "step 1 (IO unlocked, no datum shift, no blunder detection)")
    record("1", r1, block0, cfg1)
    # steps 2 and 3, repeated until the datum shift and the IO stop changing (a stepwise recipe converges
    # to the joint solution only by repetition: step 1 absorbs the datum shift into the IO)
    cams, bs = list(r1.block.cameras), r1.block.head_boresight.copy()
    prev_io = np.concatenate([c.intrinsics for c in cams])
    prev_d = np.zeros(3)
    for cycle in range(max_cycles):
        tag = "" if cycle == 0 else f" (repeat {cycle})"
        b2 = replace(block0, cameras=cams, head_boresight=bs)
        cfg2 = AdjustConfig(datum_shift="free", snooping=True, **cal_common)
        r2 = _run(b2, cfg2, "step 2 (IO locked, datum shift)" + tag)
        record("2" + tag, r2, b2, cfg2)
        b3 = replace(block0, cameras=cams, head_boresight=r2.block.head_boresight.copy(),
                     datum_shift=r2.block.datum_shift.copy())
        cfg3 = AdjustConfig(intrinsics="free", intrinsic_names=io_names, datum_shift="fixed", snooping=True,
                            **cal_common)
        r3 = _run(b3, cfg3, "step 3 (IO unlocked, datum shift locked)" + tag)
        record("3" + tag, r3, b3, cfg3)
        cams, bs = list(r3.block.cameras), r3.block.head_boresight.copy()
        io = np.concatenate([c.intrinsics for c in cams])
        l3, c3 = _cal_labels(r3)
        l2, c2 = _cal_labels(r2)
        s_io = np.sqrt(np.diag(c3)[[k for k, lab in enumerate(l3) if lab[0] == "intrinsics"]])
        s_d = np.sqrt(np.diag(c2)[[l2.index(("datum_shift", "gnss", a)) for a in "XYZ"]])
        free_io = np.concatenate([[n in io_names for n in c.intrinsic_names] for c in cams])
        change = max(float(np.max(np.abs(io - prev_io)[free_io] / s_io)) if s_io.size else 0.0,
                     float(np.max(np.abs(r2.block.datum_shift - prev_d) / s_d)))
        prev_io, prev_d = io, r2.block.datum_shift.copy()
        log.info("calqc cycle %d: largest change %.2f sigma", cycle + 1, change)
        if change < 0.05:
            break
    cycles = cycle + 1
    # the joint covariance of IO, boresights and datum shift at the converged values (no blunder detection: the
    # observations are those of the last step 3)
    bj = replace(block0, cameras=cams, head_boresight=bs, datum_shift=r2.block.datum_shift.copy())
    rej = [r.index for r in r3.rejected if r.group == "image"]
    if rej:
        w = np.ones(bj.n_observations, bool)
        w[rej] = False
        bj = _drop_obs(bj, w)
    cfgj = AdjustConfig(intrinsics="free", intrinsic_names=io_names, datum_shift="free", **cal_common)
    rj = _run(bj, cfgj, "joint covariance (IO, boresights, datum shift)")
    record("joint", rj, bj, cfgj)
    # which unknowns this flight cannot separate, per head, and the flight that would (design study)
    design_res = design_study(rj, geom, cfgj, separability_limit) if design else {}
    # the correction grid and the calibration together: the grid from the joint adjustment's residuals (the whole
    # flight, every camera; without the part the IO and boresights make), the joint adjustment again on the
    # coordinates the grid corrects, until the IO stops changing (module docstring)
    grids: dict[str, CorrectionGrid] = {}
    grid_cov: NDArray[np.float64] | None = None
    grid_cycles = 0
    grid_change = 0.0
    if grid:
        def io_sigma(r: AdjustmentResult) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
            lab, cv = _cal_labels(r)
            ix = [k for k, q in enumerate(lab) if q[0] == "intrinsics"]
            vals = np.concatenate([[dict(zip(c.intrinsic_names, c.intrinsics))[n] for n in io_names]
                                   for c in r.block.cameras])
            return vals, np.sqrt(np.diag(cv)[ix])

        if grid_method == "joint":
            io_before, s_before = io_sigma(rj)
            bjg = replace(bj, cameras=list(rj.block.cameras), head_boresight=rj.block.head_boresight.copy(),
                          datum_shift=rj.block.datum_shift.copy())
            rj, grids, grid_cycles = joint_grid_adjustment(bjg, rj, cfgj, nodes_x=grid_nodes,
                                                           max_cycles=max_grid_cycles,
                                                           min_signal_fraction=grid_min_signal_fraction,
                                                           cameras=None if grid_heads is None else
                                                           [rig.head(h).camera.name for h in grid_heads])
            if grids:  # (no camera with a signal worth a grid: the joint adjustment stands)
                record("joint + grid unknowns", rj, rj.block, cfgj.with_(image_grid="weighted"))
            io_after, _ = io_sigma(rj)
            # how far the grid moved the IO, in the IO's sigma without the grid (not a convergence measure here)
            grid_change = float(np.max(np.abs(io_after - io_before) / s_before)) if s_before.size else 0.0
            if grids and grid_fit_draws > 0:
                grid_cov, spreads = grid_hyperparameter_covariance(rj, grids, cfgj, int(grid_fit_draws))
                for k, sp in spreads.items():
                    log.info("calqc grid %s: fitted covariance function's spread sd(log c0) %.2f, sd(log L) %.2f "
                             "(%d bootstrap fits), propagated into the calibration covariance", k,
                             np.sqrt(sp[0][0]), np.sqrt(sp[1][1]), grid_fit_draws)
            if grid_uncertainty_draws > 0:
                notes.append("grid_uncertainty_draws ignored: the joint adjustment's covariance holds the grids' "
                             "uncertainty")
        for grid_cycles in (range(1, max_grid_cycles + 1) if grid_method == "cycles" else ()):
            grids = grid_from_result(rj, base=grids, calibration_free=True, nodes_x=grid_nodes)
            bg = apply_grids(replace(bj, cameras=list(rj.block.cameras), head_boresight=rj.block.head_boresight.copy(),
                                     datum_shift=rj.block.datum_shift.copy()), grids)
            io_before, _ = io_sigma(rj)
            rj = _run(bg, cfgj, f"joint (IO, boresights, datum shift) with the correction grid, cycle {grid_cycles}")
            record(f"joint + grid {grid_cycles}", rj, bg, cfgj)
            io_after, s_io = io_sigma(rj)
            change = float(np.max(np.abs(io_after - io_before) / s_io)) if s_io.size else 0.0
            log.info("calqc grid cycle %d: largest IO change %.2f sigma", grid_cycles, change)
            grid_change = change
            if change < 0.1:
                break
        if grid_method == "cycles" and grid_change >= 0.1:
            log.warning("calqc: the correction grid and the IO still moved %.2f sigma in the last of %d cycles; the "
                        "IO may keep part of the image deformation (raise max_grid_cycles)", grid_change, grid_cycles)
        if grid_method == "cycles" and grid_uncertainty_draws > 0 and grids:
            grid_cov = grid_uncertainty(replace(bj, cameras=list(rj.block.cameras),
                                                head_boresight=rj.block.head_boresight.copy(),
                                                datum_shift=rj.block.datum_shift.copy()), rj, grids, cfgj,
                                        grid_uncertainty_draws)
        block0 = apply_grids(block0, grids)
    # step 4: IO locked (step 3), datum locked (step 2), every ground point a check point, no blunder detection
    b4 = replace(block0, cameras=list(rj.block.cameras), head_boresight=rj.block.head_boresight.copy(),
                 datum_shift=rj.block.datum_shift.copy(), control_check=np.ones(len(block0.control_point), bool))
    cfg4 = AdjustConfig(datum_shift="fixed", snooping=False, **cal_common)
    r4 = _run(b4, cfg4, "step 4 (IO and datum locked, check points, no blunder detection)")
    record("4", r4, b4, cfg4)

    # calibration values and covariance: the joint adjustment at the converged steps 2-3 (plus, when asked, the
    # correction grid's posterior uncertainty propagated into them)
    labels, cov = _cal_labels(rj)
    grid_stats: dict[str, float] = {}
    if grid_cov is not None:
        ratio = np.sqrt(np.diag(cov) + np.diag(grid_cov)) / np.sqrt(np.diag(cov))
        grid_stats = {("grid_fit_draws" if grid_method == "joint" else "grid_uncertainty_draws"):
                      float(grid_fit_draws if grid_method == "joint" else grid_uncertainty_draws),
                      "grid_sigma_ratio_max": float(ratio.max()), "grid_sigma_ratio_median": float(np.median(ratio))}
        log.info("calqc: the correction grid's uncertainty raises the calibration sigmas by up to %.1f %% "
                 "(median %.2f %%)", 100 * (ratio.max() - 1), 100 * (np.median(ratio) - 1))
        cov = cov + grid_cov
    pos = {lab: k for k, lab in enumerate(labels)}
    bore: dict[str, tuple[NDArray, NDArray]] = {}
    for hi, h in enumerate(rj.block.head_name):
        ix = [pos.get(("boresight", str(h), c)) for c in ("rx", "ry", "rz")]
        if any(i is None for i in ix):
            continue
        bore[str(h)] = (rj.block.head_boresight[hi].copy(), cov[np.ix_(ix, ix)])
    interior: dict[str, tuple[tuple[str, ...], NDArray, NDArray]] = {}
    cam_by_name = {c.name: c for c in rj.block.cameras}
    for h in rig:
        c = cam_by_name.get(h.camera.name)
        if c is None:
            continue
        ix = [pos.get(("intrinsics", c.name, n)) for n in io_names]
        if any(i is None for i in ix):
            continue
        vals = np.array([dict(zip(c.intrinsic_names, c.intrinsics))[n] for n in io_names])
        interior[h.name] = (io_names, vals, cov[np.ix_(ix, ix)])
    dix = [labels.index(("datum_shift", "gnss", a)) for a in "XYZ"]
    datum = rj.block.datum_shift.copy()
    datum_cov = cov[np.ix_(dix, dix)]

    # the calibrated rig
    heads = []
    for h in rig:
        new = h
        if h.name in bore:
            from skyrig.geometry.rotations import matrix_from_rotvec

            new = new.with_(boresight=h.boresight @ matrix_from_rotvec(bore[h.name][0]))
        if h.name in interior:
            names, vals, _ = interior[h.name]
            new = new.with_(camera=new.camera.with_(**dict(zip(names, vals.tolist()))))
        heads.append(new)
    rig_cal = Rig(rig.name, heads, rig.antenna_lever_arm_m,
                  (rig.description + " | " if rig.description else "") + "calibrated by skyrig calibrate calqc")

    stats = {"images": float(block0.n_images), "stations": float(block0.n_stations),
             "observations": float(block0.n_observations), "sigma0_step3": float(r3.sigma0),
             "sigma_um_step3": _sigma_um(b3, r3.sigma0), "redundancy_step3": float(r3.redundancy),
             "sigma_um_step4": _sigma_um(b4, r4.sigma0), "cycles_steps_2_3": float(cycles),
             "sigma0_joint": float(rj.sigma0), "flying_heights": float(len(geom["heights_m"])),
             "opposite_directions": float(geom["opposite_directions"]), "grid_cycles": float(grid_cycles),
             "grid_unknowns_in_adjustment": float(bool(grid) and grid_method == "joint"),
             "grid_last_io_change_sigma": float(grid_change), **grid_stats}


    # the three variants per flying height (Tab. 11), correction grid on the lowest block
    table11: dict[str, Any] = {"variants": {}, "blocks": []}
    effect: dict[str, Any] = {}
    if variants:
        blk_c, _ = build(data, rig_cal, data.check_names, frame)
        blk_c = _poseo(blk_c, datum)
        level = flight_geometry(blk_c)["station_level"]
        blocks = []
        for lev, hgt in enumerate(geom["heights_m"]):
            keep = level == lev
            if keep.sum() < 2:
                continue
            names = set(blk_c.image_name[keep[blk_c.image_station]].tolist())
            sub = data.subset_images(sorted(names))
            bl, _ = build(sub, rig_cal, data.check_names, frame)
            bl = _poseo(bl, datum)
            nadir_cam = rig_cal.head(rig_cal.head_names[0]).camera
            blocks.append((f"{hgt:.0f} m", bl, float(nadir_cam.gsd(hgt))))
        run_blocks = list(blocks)
        if grid and blocks:
            name0, bl0, gsd0 = blocks[0]
            base_cfg = AdjustConfig(snooping=True, statistics=True)
            bb, cfg = apply_preset(bl0, "ba-eo-control", base_cfg)
            before = _run(bb, cfg, f"ba-eo-control {name0}")
            bl_g = apply_grids(bl0, grids)
            after = _run(apply_grids(bb, grids), cfg, f"ba-eo-control {name0} with correction grid")
            for lab, r in (("before", before), ("after", after)):
                b = r.block
                dd = b.point_xyz[b.control_point] - b.control_xyz
                effect[lab] = {"sigma0": r.sigma0, "sigma_um": _sigma_um(bl0, r.sigma0),
                               "rms_check_m": _rms(dd[b.control_check]), "rms_control_m": _rms(dd[~b.control_check])}
            effect["block"] = name0
            run_blocks.insert(1, (f"{name0} refined (grid)", bl_g, gsd0))
        table11["blocks"] = [n for n, _, _ in run_blocks]
        for v in VARIANTS:
            cols = {}
            for name, bl, gsd in run_blocks:
                base_cfg = AdjustConfig(snooping=True, statistics=True)
                bb, cfg = apply_preset(bl, v, base_cfg)
                if v == "dg-control":
                    cfg = cfg.with_(snooping=False)
                r = _run(bb, cfg, f"{v} {name}")
                cols[name] = _variant_column(r, bb, gsd, v)
            table11["variants"][v] = {"title": PRESETS[v].title, "columns": cols}
    return CalqcCalibration(rig, rig_cal, frame, bore, interior, datum, datum_cov, steps, table11, grids, effect,
                            inseparable, geom, stats, design_res, notes, list(labels), cov)


def normalised_errors(cal: "CalqcCalibration", truth: ScenarioTruth) -> tuple[dict[str, float], NDArray[np.float64]]:
    """A simulation's calibration errors against its truth (:func:`midas_calqc_scenario`): per parameter
    ``(estimate - truth) / sigma`` (every head's boresight rx, ry, rz and IO, the datum shift X, Y, Z), and the same
    errors whitened by their joint covariance (``L^-1 e`` with ``L L^T`` the covariance of all of them, in the order
    of :attr:`CalqcCalibration.covariance_labels`): for honest sigmas and correlations the latter are independent
    N(0, 1) values, so their pooled distribution tests the covariance itself, while the per-parameter values of
    one run are correlated with each other."""
    z: dict[str, float] = {}
    for h, (v, cov) in cal.boresight.items():
        for a, x in zip(("rx", "ry", "rz"), (v - truth.boresight_rotvec_rad[h]) / np.sqrt(np.diag(cov))):
            z[f"boresight {h} {a}"] = float(x)
    for h, (names, v, cov) in cal.interior.items():
        tv = np.array([truth.intrinsics[h][n] for n in names])
        for n, x in zip(names, (v - tv) / np.sqrt(np.diag(cov))):
            z[f"IO {h} {n}"] = float(x)
    for a, x in zip("XYZ", (cal.datum_shift_m - truth.datum_shift_m) / np.sqrt(np.diag(cal.datum_shift_cov_m2))):
        z[f"datum shift {a}"] = float(x)
    if cal.covariance is None:
        raise ValueError("normalised_errors: the calibration carries no joint covariance")
    e, keep = [], []
    head_of_cam = {h.camera.name: h.name for h in cal.rig_in}
    for k, (g, o, c) in enumerate(cal.covariance_labels):
        if g == "boresight":
            i = ("rx", "ry", "rz").index(c)
            e.append(cal.boresight[o][0][i] - truth.boresight_rotvec_rad[o][i])
        elif g == "intrinsics":
            names, v, _ = cal.interior[head_of_cam[o]]
            e.append(v[list(names).index(c)] - truth.intrinsics[head_of_cam[o]][c])
        elif g == "datum_shift":
            i = "XYZ".index(c)
            e.append(cal.datum_shift_m[i] - truth.datum_shift_m[i])
        else:
            continue
        keep.append(k)
    cv = np.asarray(cal.covariance)[np.ix_(keep, keep)]
    return z, np.linalg.solve(np.linalg.cholesky(cv), np.asarray(e, float))


def within_sigma_summary(z: Sequence[float] | NDArray[np.float64], k: float = 2.0,
                         level: float = 0.95) -> dict[str, Any]:
    """How a set of normalised errors ``(estimate - truth) / sigma`` (a simulation's, where the truth is known)
    stands against two readings of "within ``k`` sigma": the literal count within ``k``, with the count expected of
    N(0, 1) values and the chance that all of them are (``0.954 ** 33 = 0.21`` for 33 parameters at 2 sigma); and
    the family-wise test, every ``|z|`` within the Sidak bound for that many parameters at ``level``
    (:func:`skyrig.adjust.stats.sidak_z`)."""
    from scipy.stats import norm

    a = np.abs(np.asarray(z, float).ravel())
    p1 = float(2.0 * norm.cdf(k) - 1.0)
    b = sidak_z(max(a.size, 1), level)
    return {"n": int(a.size), "k_sigma": float(k), "within_k": int(np.sum(a <= k)), "expected_within_k": a.size * p1,
            "probability_all_within_k": p1 ** a.size, "max_abs_z": float(a.max()) if a.size else 0.0,
            "family_wise_level": float(level), "family_wise_bound": b, "within_family_wise_bound": bool(np.all(a <= b))}


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


# ------------------------------------------------------------------------------------------------ reports
def _f(v: Any, fmt: str) -> str:
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, fmt)


def format_tables(report: Mapping[str, Any]) -> str:
    """The steps, the calibration, the separability and Tab. 11 as plain text (what the CLI prints)."""
    out = []
    fl = report["flight"]
    out.append(f"flight: heights {[round(h) for h in fl['heights_m']]} m above ground, headings "
               f"{fl['headings_deg']} deg, opposite directions: {'yes' if fl['opposite_directions'] else 'no'}")
    out.append("CalQC steps  IO        datum   ctrl check snoop  sigma[um] rejected  RMS control XYZ [m]   RMS check XYZ [m]")
    for s in report["steps"]:
        out.append(f"  {s['step']:<10} {s['io']:<9} {s['datum_shift']:<7} {s['control']:>4} {s['check']:>5} "
                   f"{'on' if s['blunder_detection'] else 'off':>5} {s['sigma_um']:10.2f} {s['rejected']:>8}  "
                   + " ".join(_f(x, "6.3f") for x in s["rms_control_m"]) + "  "
                   + " ".join(_f(x, "6.3f") for x in s["rms_check_m"]))
    for n in report.get("notes") or []:
        out.append(f"  note: {n}")
    r = report["result"]
    out.append("boresight corrections (rotation vector about the camera axes, 1/1000 deg, +- sigma):")
    for h, b in r["boresight"].items():
        out.append(f"  {h:<10} " + "  ".join(f"{v:8.2f} +- {s:5.2f}" for v, s in zip(b["rotvec_mdeg"], b["sigma_mdeg"])))
    out.append("interior orientation [mm] (start -> adjusted +- sigma):")
    for h, io in r["interior_orientation"].items():
        out.append(f"  {h:<10} " + "  ".join(f"{n} {e['start_mm']:.4f} -> {e['value_mm']:.4f} +- {e['sigma_mm']:.4f}"
                                             for n, e in io.items()))
    out.append("GNSS datum shift (GNSS minus control) [m]: " + ", ".join(
        f"{a} {v:.3f} +- {s:.3f}" for a, v, s in zip("XYZ", r["datum_shift_m"], r["datum_shift_sigma_m"])))
    if report["inseparable"]:
        out.append("INSEPARABLE in this flight:")
        for e in report["inseparable"]:
            out.append(f"  step {e['step']}: {e['text']}; would be separated by {e['separating_flight']}")
    else:
        out.append("all calibration unknowns separable (no correlation above the limit)")
    ds = report.get("inseparable_by_head") or {}
    if ds:
        tried = ", ".join(f"{k} (+{v['images_added']} images)" for k, v in ds["flights_tried"].items()) or "none"
        out.append(f"design study (flights added virtually: {tried}; named: an excess sigma gain >= "
                   f"{ds['excess_limit']} or a multiple correlation > {ds['limit']}):")
        if not ds["by_head"]:
            out.append("  every calibration unknown separable in this flight")
        for h, es in ds["by_head"].items():
            out.append(f"  {h}:")
            for e in es:
                out.append(f"    {'[any flight] ' if e['separating_flight'] is None else ''}{e['text']}")
    t = report["table11"]
    if t.get("variants"):
        blocks = t["blocks"]
        out.append("Tab. 11: bundle adjustment results")
        for v, vd in t["variants"].items():
            out.append(f"  {vd['title']}")
            out.append("    " + f"{'':<22}" + "".join(f"{b:>24}" for b in blocks))
            cols = [vd["columns"][b] for b in blocks]
            out.append("    " + f"{'GSD (cm)':<22}" + "".join(f"{_f(c['gsd_cm'], '.1f'):>24}" for c in cols))
            out.append("    " + f"{'Sigma (um)':<22}" + "".join(f"{_f(c['sigma_um'], '.2f'):>24}" for c in cols))
            for key, lab, fmt in (("rms_control_m", "RMS Control {} (m)", ".3f"), ("rms_check_m", "RMS Check {} (m)", ".3f"),
                                  ("rms_photo_position_m", "RMS Photo Pos. {} (m)", ".3f"),
                                  ("rms_photo_attitude_deg", "RMS Photo Att. {} (d)", ".4f"),
                                  ("gps_block_shift_m", "GPS Block Shift {} (m)", ".3f")):
                for k, a in enumerate("XYZ"):
                    out.append("    " + f"{lab.format(a):<22}" + "".join(
                        f"{_f(None if c[key] is None else c[key][k], fmt):>24}" for c in cols))
    ge = report.get("correction_grid_effect") or {}
    if ge:
        out.append("correction grid (least-squares collocation of the whole flight's residuals, estimated with the IO; "
                   f"its effect on block {ge['block']}):")
        for k, g in report["correction_grid"].items():
            cv = g["covariance"]
            out.append(f"  {k}: {g['residuals']} residuals, signal {np.sqrt(cv['c0_px2']):.3f} px, correlation length "
                       f"{cv['length_px']:.0f} px, noise {np.sqrt(cv['nugget_px2']):.3f} px, max correction "
                       f"{g['max_correction_px']:.3f} px (mean sigma {g['mean_sigma_px']:.3f} px)")
        for lab in ("before", "after"):
            e = ge[lab]
            out.append(f"  {lab:<6}: sigma {e['sigma_um']:.3f} um, RMS check XYZ " + " ".join(_f(x, ".3f") for x in e["rms_check_m"]))
    return "\n".join(out)


def report_html(report: Mapping[str, Any]) -> str:
    """A self-contained HTML page with the tables."""
    return ("<!doctype html><meta charset='utf-8'><title>calqc calibration</title>"
            "<h1>System calibration of a multi-head rig (paper 004 CalQC recipe)</h1>"
            f"<p>frame {html.escape(str(report['frame']))}</p><pre>{html.escape(format_tables(report))}</pre>")
