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

The recipe's parts, one module each (every name importable from here as well): :mod:`~skyrig.calibrate.calqc_common`
(the input, one adjustment run, the calibration unknowns' labels), :mod:`~skyrig.calibrate.calqc_grid` (covariance
function, collocation grid, grid unknowns, the grid's uncertainty), :mod:`~skyrig.calibrate.calqc_design` (flight
geometry, separability, the design study), :mod:`~skyrig.calibrate.calqc_simulation` (the simulated flight and its
truth), :mod:`~skyrig.calibrate.calqc_judge` (errors against the truth) and :mod:`~skyrig.calibrate.calqc_report`
(text tables, HTML); this module runs the steps (:func:`calibrate_calqc`) and holds the result.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig._plain import plain
from skyrig.adjust.adjust import AdjustmentResult
from skyrig.adjust.block import AdjustConfig, Block
from skyrig.adjust.config import ReliabilityOptions, StatisticsOptions, Unknowns
from skyrig.adjust.presets import PRESETS, apply_preset
from skyrig.adjust.rig_block import block_from_trajectory
from skyrig.calibrate.calqc_common import (  # noqa: F401 - the recipe's parts, importable from here
    calqc_data_from_survey,
    CalqcData,
    IO_PARAMETERS,
    VARIANTS,
    _cal_labels,
    _drop_obs,
    _poseo,
    _rms,
    _run,
    _sigma_um,
)
from skyrig.calibrate.calqc_design import (  # noqa: F401 - the recipe's parts, importable from here
    CANDIDATE_FLIGHTS,
    design_study,
    flight_geometry,
    separability,
    virtual_flight,
    _multiple_correlation,
)
from skyrig.calibrate.calqc_grid import (  # noqa: F401 - the recipe's parts, importable from here
    apply_grids,
    bilinear_interpolation_variance,
    calibration_basis,
    CALIBRATION_FIELDS,
    calibration_part,
    collocation_grid,
    collocation_prior,
    CorrectionGrid,
    covariance_fit_spread,
    CovarianceFit,
    fit_covariance,
    grid_from_result,
    grid_hyperparameter_covariance,
    grid_nodes_for,
    grid_uncertainty,
    joint_grid_adjustment,
    random_field_deformation,
    wave_deformation,
    without_calibration_part,
)
from skyrig.calibrate.calqc_judge import normalised_errors, within_sigma_summary  # noqa: F401 - re-exported
from skyrig.calibrate.calqc_report import format_tables, report_html  # noqa: F401 - re-exported
from skyrig.calibrate.calqc_simulation import midas_calqc_scenario, ScenarioTruth  # noqa: F401 - re-exported
from skyrig.calibrate.rig_calibration import CovarianceBlock, HeadCalibration, Provenance, RigCalibration
from skyrig.errors import CalqcFailed, ConfigError  # noqa: F401 - CalqcFailed re-exported
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.rig.rig import Rig

log = logging.getLogger(__name__)


__all__ = ["IO_PARAMETERS", "CalqcData", "CalqcCalibration", "CalqcFailed", "CorrectionGrid", "calibrate_calqc",
           "within_sigma_summary", "normalised_errors", "random_field_deformation", "collocation_grid",
           "fit_covariance", "flight_geometry", "midas_calqc_scenario", "calqc_data_from_survey",
           "format_tables", "report_html", "separability", "without_calibration_part", "calibration_part",
           "grid_nodes_for", "collocation_prior", "joint_grid_adjustment", "covariance_fit_spread",
           "grid_hyperparameter_covariance", "poseo"]


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
    #: the corrected exterior orientation of every image (the paper's POSEO, :func:`poseo`), in :attr:`frame`
    poseo: ExteriorOrientations | None = None

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
    row = {"step": step, "io": cfg.unknowns.intrinsics, "datum_shift": cfg.unknowns.datum_shift, "control": int(ctrl.sum()),
           "check": int((~ctrl).sum()), "blunder_detection": bool(cfg.reliability.snooping), "sigma0": res.sigma0,
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
    fixed_poses = res.config.unknowns.poses == "fixed"
    col["rms_photo_position_m"] = None if fixed_poses or g is None else _rms(np.asarray(g.residual))
    col["rms_photo_attitude_deg"] = None if fixed_poses or m is None else np.degrees(_rms(np.asarray(m.residual))).tolist()
    col["gps_block_shift_m"] = b.datum_shift.tolist() if res.config.unknowns.datum_shift != "fixed" else None
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
    build = _Builder(gnss_sigma_m, tuple(float(np.radians(v)) for v in imu_sigma_deg), control_sigma_m,
                     float(image_sigma_um) / (rig.head(rig.head_names[0]).camera.pixel_size_mm * 1000.0))
    block0, frame = build(data, rig, data.check_names, None)
    geom = flight_geometry(block0)
    io_names = tuple(io_parameters)
    journal = _Journal(geom, separability_limit)
    r2, r3, b3, cams, bs, cycles = _steps_1_to_3(block0, io_names, max_cycles, journal)
    bj, cfgj, rj = _joint_adjustment(block0, cams, bs, r2, r3, io_names, journal)
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
        if grid_method == "joint":
            rj, grids, grid_cov, grid_cycles, grid_change = _grid_joint(
                bj, rj, cfgj, io_names, journal, nodes_x=grid_nodes, max_cycles=max_grid_cycles,
                min_signal_fraction=grid_min_signal_fraction,
                cameras=None if grid_heads is None else [rig.head(h).camera.name for h in grid_heads],
                fit_draws=grid_fit_draws, uncertainty_draws=grid_uncertainty_draws)
        else:
            rj, grids, grid_cov, grid_cycles, grid_change = _grid_cycles(
                bj, rj, cfgj, io_names, journal, nodes_x=grid_nodes, max_cycles=max_grid_cycles,
                uncertainty_draws=grid_uncertainty_draws)
        block0 = apply_grids(block0, grids)
    b4, r4 = _step_4(block0, rj, journal)

    # calibration values and covariance: the joint adjustment at the converged steps 2-3 (plus, when asked, the
    # correction grid's posterior uncertainty propagated into them)
    labels, cov = _cal_labels(rj)
    grid_stats: dict[str, float] = {}
    if grid_cov is not None:
        cov, grid_stats = _with_grid_uncertainty(cov, grid_cov, grid_method, grid_fit_draws, grid_uncertainty_draws)
    bore, interior, datum, datum_cov = _calibration_blocks(rj, rig, io_names, labels, cov)
    rig_cal = _calibrated_rig(rig, bore, interior)

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
        table11, effect = _table11(data, rig_cal, build, frame, datum, geom, grids if grid else None)
    return CalqcCalibration(rig, rig_cal, frame, bore, interior, datum, datum_cov, journal.steps, table11, grids,
                            effect, journal.inseparable, geom, stats, design_res, journal.notes, list(labels), cov,
                            poseo(data, rig_cal, datum, frame))


def poseo(data: CalqcData, rig_cal: Rig, datum_shift_m: NDArray[np.float64], frame: WorldFrame
          ) -> ExteriorOrientations:
    """The paper's POSEO (2.3: "CalQC ... arrives at the final POSEO data"): the exterior orientation of every
    image by direct georeferencing (:func:`~skyrig.georef.direct.direct_georeference`) of the events with the
    calibrated rig (boresights, IO) and the GNSS/IMU trajectory freed of the estimated datum shift (GNSS minus
    control, local ENU of ``frame``), in ``frame``."""
    from skyrig.calibrate.gnss_imu import _shift_trajectory
    from skyrig.georef.direct import direct_georeference

    traj = _shift_trajectory(data.trajectory, frame, -np.asarray(datum_shift_m, dtype=np.float64))
    return direct_georeference(traj, rig_cal, data.events, frame)


#: the calibration unknowns of every step: the heads' boresights free, statistics on (Model's redundancy numbers)
_CAL_BASE = AdjustConfig(unknowns=Unknowns(boresight="free"))  # every calibration step: boresights free


@dataclass(frozen=True)
class _Builder:
    """Rig blocks of the flight (:func:`block_from_trajectory`) with the recipe's sigmas."""

    gnss_sigma_m: tuple[float, float, float]
    imu_sigma_rad: tuple[float, ...]
    control_sigma_m: tuple[float, float, float]
    sigma_px: float

    def __call__(self, d: CalqcData, r: Rig, check: Sequence[str], frame: WorldFrame | None
                 ) -> tuple[Block, WorldFrame]:
        return block_from_trajectory(d.trajectory, r, d.events, d.measurements, d.ground,
                                     gnss_sigma_m=self.gnss_sigma_m, imu_sigma_rad=self.imu_sigma_rad,
                                     control_sigma_m=self.control_sigma_m, check_points=tuple(check),
                                     sigma_px=self.sigma_px, frame=frame)


@dataclass
class _Journal:
    """What the recipe reports as it goes: a row per adjustment, the pairs of unknowns it cannot separate (each
    once, with the first step that showed it) and notes on what it did differently from the plain steps."""

    geom: dict[str, Any]
    limit: float
    steps: list[dict[str, Any]] = field(default_factory=list)
    inseparable: list[dict[str, Any]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def record(self, step: str, res: AdjustmentResult, blk: Block, cfg: AdjustConfig) -> None:
        self.steps.append(_step_row(step, res, blk, cfg))
        for e in separability(res, self.geom, self.limit):
            e = {**e, "step": step}
            if not any(x["text"] == e["text"] for x in self.inseparable):
                self.inseparable.append(e)


def _steps_1_to_3(block0: Block, io_names: tuple[str, ...], max_cycles: int, journal: _Journal
                  ) -> tuple[AdjustmentResult, AdjustmentResult, Block, list[Any], NDArray[np.float64], int]:
    """Step 1, then steps 2 and 3 repeated until the datum shift and the IO stop changing: the last step 2 and
    step 3 results, step 3's block, the cameras and boresights of step 3 and the number of cycles."""
    # step 1: IO unlocked, no datum shift, full control, blunder detection
    cfg1 = _CAL_BASE.with_unknowns(intrinsics="free", intrinsic_names=io_names).with_reliability(snooping=True)
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
        journal.notes.append(f"step 1: {exc}; repeated without blunder detection (the datum shift is step 2's)")
        cfg1 = cfg1.with_reliability(snooping=False)
        r1 = _run(block0, cfg1, "step 1 (IO unlocked, no datum shift, no blunder detection)")
    journal.record("1", r1, block0, cfg1)
    # steps 2 and 3, repeated until the datum shift and the IO stop changing (a stepwise recipe converges
    # to the joint solution only by repetition: step 1 absorbs the datum shift into the IO)
    cams, bs = list(r1.block.cameras), r1.block.head_boresight.copy()
    prev_io = np.concatenate([c.intrinsics for c in cams])
    prev_d = np.zeros(3)
    for cycle in range(max_cycles):
        tag = "" if cycle == 0 else f" (repeat {cycle})"
        b2 = replace(block0, cameras=cams, head_boresight=bs)
        cfg2 = _CAL_BASE.with_unknowns(datum_shift="free").with_reliability(snooping=True)
        r2 = _run(b2, cfg2, "step 2 (IO locked, datum shift)" + tag)
        journal.record("2" + tag, r2, b2, cfg2)
        b3 = replace(block0, cameras=cams, head_boresight=r2.block.head_boresight.copy(),
                     datum_shift=r2.block.datum_shift.copy())
        cfg3 = _CAL_BASE.with_unknowns(intrinsics="free", intrinsic_names=io_names).with_reliability(snooping=True)
        r3 = _run(b3, cfg3, "step 3 (IO unlocked, datum shift locked)" + tag)
        journal.record("3" + tag, r3, b3, cfg3)
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
    return r2, r3, b3, cams, bs, cycle + 1


def _joint_adjustment(block0: Block, cams: list[Any], bs: NDArray[np.float64], r2: AdjustmentResult,
                      r3: AdjustmentResult, io_names: tuple[str, ...], journal: _Journal
                      ) -> tuple[Block, AdjustConfig, AdjustmentResult]:
    """The joint covariance of IO, boresights and datum shift at the converged values (no blunder detection: the
    observations are those of the last step 3): its block, configuration and result."""
    bj = replace(block0, cameras=cams, head_boresight=bs, datum_shift=r2.block.datum_shift.copy())
    rej = [r.index for r in r3.rejected if r.group == "image"]
    if rej:
        w = np.ones(bj.n_observations, bool)
        w[rej] = False
        bj = _drop_obs(bj, w)
    cfgj = _CAL_BASE.with_unknowns(intrinsics="free", intrinsic_names=io_names, datum_shift="free")
    rj = _run(bj, cfgj, "joint covariance (IO, boresights, datum shift)")
    journal.record("joint", rj, bj, cfgj)
    return bj, cfgj, rj


def _io_sigma(r: AdjustmentResult, io_names: tuple[str, ...]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The IO values of every camera and their sigmas in ``r``."""
    lab, cv = _cal_labels(r)
    ix = [k for k, q in enumerate(lab) if q[0] == "intrinsics"]
    vals = np.concatenate([[dict(zip(c.intrinsic_names, c.intrinsics))[n] for n in io_names]
                           for c in r.block.cameras])
    return vals, np.sqrt(np.diag(cv)[ix])


def _grid_joint(bj: Block, rj: AdjustmentResult, cfgj: AdjustConfig, io_names: tuple[str, ...], journal: _Journal,
                *, nodes_x: int | None, max_cycles: int, min_signal_fraction: float, cameras: list[str] | None,
                fit_draws: int, uncertainty_draws: int
                ) -> tuple[AdjustmentResult, dict[str, CorrectionGrid], NDArray[np.float64] | None, int, float]:
    """``grid_method="joint"``: the grids' node values as unknowns of the joint adjustment
    (:func:`joint_grid_adjustment`), the fitted covariance function's uncertainty propagated when asked.  Returns
    the joint result, the grids, the added calibration covariance (or None), the grid cycles and how far the grid
    moved the IO."""
    grid_cov = None
    io_before, s_before = _io_sigma(rj, io_names)
    bjg = replace(bj, cameras=list(rj.block.cameras), head_boresight=rj.block.head_boresight.copy(),
                  datum_shift=rj.block.datum_shift.copy())
    rj, grids, grid_cycles = joint_grid_adjustment(bjg, rj, cfgj, nodes_x=nodes_x, max_cycles=max_cycles,
                                                   min_signal_fraction=min_signal_fraction, cameras=cameras)
    if grids:  # (no camera with a signal worth a grid: the joint adjustment stands)
        journal.record("joint + grid unknowns", rj, rj.block, cfgj.with_unknowns(image_grid="weighted"))
    io_after, _ = _io_sigma(rj, io_names)
    # how far the grid moved the IO, in the IO's sigma without the grid (not a convergence measure here)
    grid_change = float(np.max(np.abs(io_after - io_before) / s_before)) if s_before.size else 0.0
    if grids and fit_draws > 0:
        grid_cov, spreads = grid_hyperparameter_covariance(rj, grids, cfgj, int(fit_draws))
        for k, sp in spreads.items():
            log.info("calqc grid %s: fitted covariance function's spread sd(log c0) %.2f, sd(log L) %.2f "
                     "(%d bootstrap fits), propagated into the calibration covariance", k,
                     np.sqrt(sp[0][0]), np.sqrt(sp[1][1]), fit_draws)
    if uncertainty_draws > 0:
        journal.notes.append("grid_uncertainty_draws ignored: the joint adjustment's covariance holds the grids' "
                             "uncertainty")
    return rj, grids, grid_cov, grid_cycles, grid_change


def _grid_cycles(bj: Block, rj: AdjustmentResult, cfgj: AdjustConfig, io_names: tuple[str, ...], journal: _Journal,
                 *, nodes_x: int | None, max_cycles: int, uncertainty_draws: int
                 ) -> tuple[AdjustmentResult, dict[str, CorrectionGrid], NDArray[np.float64] | None, int, float]:
    """``grid_method="cycles"``: grids by collocation of the residuals alternating with the joint adjustment on
    the corrected coordinates until the IO changes by less than 0.1 sigma; the grids' posterior propagated by
    ``uncertainty_draws`` pairs.  Returns as :func:`_grid_joint`."""
    grids: dict[str, CorrectionGrid] = {}
    grid_cov = None
    grid_cycles = 0
    grid_change = 0.0
    for grid_cycles in range(1, max_cycles + 1):
        grids = grid_from_result(rj, base=grids, calibration_free=True, nodes_x=nodes_x)
        bg = apply_grids(replace(bj, cameras=list(rj.block.cameras), head_boresight=rj.block.head_boresight.copy(),
                                 datum_shift=rj.block.datum_shift.copy()), grids)
        io_before, _ = _io_sigma(rj, io_names)
        rj = _run(bg, cfgj, f"joint (IO, boresights, datum shift) with the correction grid, cycle {grid_cycles}")
        journal.record(f"joint + grid {grid_cycles}", rj, bg, cfgj)
        io_after, s_io = _io_sigma(rj, io_names)
        change = float(np.max(np.abs(io_after - io_before) / s_io)) if s_io.size else 0.0
        log.info("calqc grid cycle %d: largest IO change %.2f sigma", grid_cycles, change)
        grid_change = change
        if change < 0.1:
            break
    if grid_change >= 0.1:
        log.warning("calqc: the correction grid and the IO still moved %.2f sigma in the last of %d cycles; the "
                    "IO may keep part of the image deformation (raise max_grid_cycles)", grid_change, grid_cycles)
    if uncertainty_draws > 0 and grids:
        grid_cov = grid_uncertainty(replace(bj, cameras=list(rj.block.cameras),
                                            head_boresight=rj.block.head_boresight.copy(),
                                            datum_shift=rj.block.datum_shift.copy()), rj, grids, cfgj,
                                    uncertainty_draws)
    return rj, grids, grid_cov, grid_cycles, grid_change


def _step_4(block0: Block, rj: AdjustmentResult, journal: _Journal) -> tuple[Block, AdjustmentResult]:
    """Step 4: IO locked (step 3), datum locked (step 2), every ground point a check point, no blunder detection."""
    b4 = replace(block0, cameras=list(rj.block.cameras), head_boresight=rj.block.head_boresight.copy(),
                 datum_shift=rj.block.datum_shift.copy(), control_check=np.ones(len(block0.control_point), bool))
    cfg4 = _CAL_BASE
    r4 = _run(b4, cfg4, "step 4 (IO and datum locked, check points, no blunder detection)")
    journal.record("4", r4, b4, cfg4)
    return b4, r4


def _with_grid_uncertainty(cov: NDArray[np.float64], grid_cov: NDArray[np.float64], grid_method: str,
                           grid_fit_draws: int, grid_uncertainty_draws: int
                           ) -> tuple[NDArray[np.float64], dict[str, float]]:
    """The calibration covariance plus the correction grid's uncertainty, and how much it raised the sigmas."""
    ratio = np.sqrt(np.diag(cov) + np.diag(grid_cov)) / np.sqrt(np.diag(cov))
    grid_stats = {("grid_fit_draws" if grid_method == "joint" else "grid_uncertainty_draws"):
                  float(grid_fit_draws if grid_method == "joint" else grid_uncertainty_draws),
                  "grid_sigma_ratio_max": float(ratio.max()), "grid_sigma_ratio_median": float(np.median(ratio))}
    log.info("calqc: the correction grid's uncertainty raises the calibration sigmas by up to %.1f %% "
             "(median %.2f %%)", 100 * (ratio.max() - 1), 100 * (np.median(ratio) - 1))
    return cov + grid_cov, grid_stats


def _calibration_blocks(rj: AdjustmentResult, rig: Rig, io_names: tuple[str, ...],
                        labels: list[tuple[str, str, str]], cov: NDArray[np.float64]
                        ) -> tuple[dict[str, tuple[NDArray, NDArray]],
                                   dict[str, tuple[tuple[str, ...], NDArray, NDArray]], NDArray, NDArray]:
    """Each head's boresight and IO with their covariance blocks, and the datum shift with its covariance."""
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
    return bore, interior, rj.block.datum_shift.copy(), cov[np.ix_(dix, dix)]


def _calibrated_rig(rig: Rig, bore: dict[str, tuple[NDArray, NDArray]],
                    interior: dict[str, tuple[tuple[str, ...], NDArray, NDArray]]) -> Rig:
    """The rig with the calibrated boresights and IO."""
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
    return Rig(rig.name, heads, rig.antenna_lever_arm_m,
               (rig.description + " | " if rig.description else "") + "calibrated by skyrig calibrate calqc")


def _table11(data: CalqcData, rig_cal: Rig, build: _Builder, frame: WorldFrame, datum: NDArray[np.float64],
             geom: dict[str, Any], grids: dict[str, CorrectionGrid] | None
             ) -> tuple[dict[str, Any], dict[str, Any]]:
    """The three variants per flying height with the calibrated rig (Tab. 11) and, with ``grids``, the lowest block
    refined by them and the grid's effect there (sigma0, check and control RMS before and after)."""
    table11: dict[str, Any] = {"variants": {}, "blocks": []}
    effect: dict[str, Any] = {}
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
    if grids is not None and blocks:
        name0, bl0, gsd0 = blocks[0]
        base_cfg = AdjustConfig(reliability=ReliabilityOptions(snooping=True),
                                statistics=StatisticsOptions(compute=True))
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
            base_cfg = AdjustConfig(reliability=ReliabilityOptions(snooping=True),
                                    statistics=StatisticsOptions(compute=True))
            bb, cfg = apply_preset(bl, v, base_cfg)
            if v == "dg-control":
                cfg = cfg.with_reliability(snooping=False)
            r = _run(bb, cfg, f"{v} {name}")
            cols[name] = _variant_column(r, bb, gsd, v)
        table11["variants"][v] = {"title": PRESETS[v].title, "columns": cols}
    return table11, effect
