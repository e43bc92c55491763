"""The ``calqc`` boresight flight simulated (``skyrig.simulate`` scenario ``midas``) with the errors paper 004
calibrates (IO, GNSS datum shift, an optional image deformation) and their truth.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.calibrate.calqc_common import CalqcData, calqc_data_from_survey
from skyrig.calibrate.calqc_grid import random_field_deformation, wave_deformation
from skyrig.errors import SkyrigError
from skyrig.geometry.rotations import rotvec_from_matrix
from skyrig.georef.eo import WorldFrame

__all__ = ["ScenarioTruth", "midas_calqc_scenario"]


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


def _midas_spec(size: str, seed: int, camera_width_px: int | None):
    """The MIDAS scenario's spec: ``"full"`` as published, ``"reduced"`` a smaller block of narrower cameras;
    ``camera_width_px`` cameras of that width with the same field of view."""
    from skyrig.simulate.scenarios import FlightSpec, ci_camera, scenario_spec

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
    return spec


def _kept_strips(data: CalqcData, survey, spec, directions: str, heights: str) -> CalqcData:
    """``data`` of the strips flown in the first strip's direction (``directions="one"``) and / or of the lower
    flight only (``heights="low"``)."""
    n_low = spec.flights[0].n_strips
    st_keep = {}
    for i in range(len(survey.plan)):
        same = float(np.cos(survey.plan.heading_rad[i] - survey.plan.heading_rad[0])) > 0
        low = int(survey.plan.strip[i]) < n_low
        st_keep[i + 1] = (same or directions == "both") and (low or heights == "both")
    keep = {str(n) for n, x in zip(survey.events_recorded.image_name, survey.events_recorded.exposure_id)
            if st_keep[int(x)]}
    return data.subset_images(sorted(keep))


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
    from skyrig.simulate.scenarios import build_survey

    if size not in ("full", "reduced"):
        raise SkyrigError(f"size must be 'full' or 'reduced', not {size!r}")
    if heights not in ("both", "low"):
        raise SkyrigError(f"heights must be 'both' or 'low', not {heights!r}")
    if directions not in ("both", "one"):
        raise SkyrigError(f"directions must be 'both' or 'one', not {directions!r}")
    spec = _midas_spec(size, seed, camera_width_px)
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
        data = _kept_strips(data, survey, spec, directions, heights)
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
