"""The ``camera`` recipe: test-field (cage) calibration of one camera (paper 004, section 2.5).

Paper 004 calibrated the MIDAS cameras "using a 3D cage and multiple convergent images utilizing [the]
Australis model": about 78 retro-reflective targets, 30 images; "the object points and the camera exposure
stations (X_C, Y_C, Z_C) were fixed, and the image point coordinates (x, y) were weighted with the standard
deviation of 0.1 of a pixel.  The unknowns were the camera's rotation angles and the parameters of the
Australis model."

Sequence
--------
1. Starting values: for every image a direct linear transformation (DLT, at least 6 targets, distortion
   ignored) from the fixed targets gives the rotation (and, for free stations, the projection centre).
2. One self-calibrating bundle adjustment (:func:`skyrig.adjust.adjust`) with the targets **fixed** (not
   observations, not unknowns), image measurements weighted with ``image_sigma_px`` (0.1 px), the interior
   orientation of the chosen distortion model free (all its parameters, or a chosen subset), and per image:

   * ``stations="fixed"`` (the paper): the projection centre fixed at the given station, the rotation free
     (3 unknowns per image: every image is a station whose pose is held, with its own free rotation
     correction, the adjustment's per-head boresight);
   * ``stations="free"``: the whole pose free (6 unknowns per image).

3. The result: the calibrated camera, the a-posteriori covariance of the estimated intrinsics
   (``sigma0² Q``) and their correlations, sigma0, redundancy (``2 n - 3 I - u`` for fixed stations) and the
   image residual RMS (:class:`CameraCalibration`), ready for a calibrated rig file
   (:meth:`CameraCalibration.rig_calibration`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Literal, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.adjust import AdjustConfig, Block, adjust
from skyrig.adjust.config import SolverOptions, Unknowns
from skyrig.adjust.adjust import AdjustmentResult
from skyrig.calibrate.rig_calibration import CovarianceBlock, HeadCalibration, Provenance, RigCalibration
from skyrig.camera.distortion import Distortion, distortion_class
from skyrig.camera.frame import FrameCamera
from skyrig.errors import CalibrationError  # noqa: F401 - re-exported (defined in skyrig.errors)
from skyrig.rig.camera_pose import world_from_camera

logger = logging.getLogger(__name__)

__all__ = ["CameraCalibration", "CalibrationError", "calibrate_camera", "dlt_pose"]

#: from skyrig's camera frame (x right, y up, z back) to the computer-vision one (x right, y down, z forward)
_CV_FROM_CAMERA = np.diag([1.0, -1.0, -1.0])


@dataclass
class CameraCalibration:
    """Result of :func:`calibrate_camera`.

    Attributes
    ----------
    camera
        The calibrated camera.
    parameters
        ``(u,)`` names of the estimated intrinsics (:attr:`FrameCamera.intrinsic_names` order).
    covariance
        ``(u, u)`` a-posteriori covariance ``sigma0² Q`` of the estimated intrinsics (their units).
    cofactor
        ``(u, u)`` ``Q``: the covariance for ``sigma0 = 1`` (a-priori, image sigma as given).
    sigma0
        A-posteriori standard deviation of unit weight.
    redundancy, n_observations, n_unknowns
        Of the adjustment (scalar image coordinates with at least one unknown; fixed targets are no observations).
    residual_rms_px
        ``(2,)`` RMS of the image residuals in column and row, pixels.
    image_sigma_px
        The a-priori image sigma used.
    image_names, world_from_camera_rotation, camera_centre
        ``(I,)``, ``(I, 3, 3)``, ``(I, 3)`` the adjusted exterior orientations.
    stations
        ``"fixed"`` or ``"free"``.
    result
        The full :class:`~skyrig.adjust.adjust.AdjustmentResult`.
    """

    camera: FrameCamera
    parameters: tuple[str, ...]
    covariance: NDArray[np.float64]
    cofactor: NDArray[np.float64]
    sigma0: float
    redundancy: int
    n_observations: int
    n_unknowns: int
    residual_rms_px: NDArray[np.float64]
    image_sigma_px: float
    image_names: NDArray[np.str_]
    world_from_camera_rotation: NDArray[np.float64]
    camera_centre: NDArray[np.float64]
    stations: str
    result: AdjustmentResult | None = field(default=None, repr=False)

    @property
    def sigma(self) -> NDArray[np.float64]:
        """``(u,)`` a-posteriori sigma of the estimated intrinsics."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0, None))

    @property
    def correlation(self) -> NDArray[np.float64]:
        """``(u, u)`` correlations of the estimated intrinsics."""
        s = self.sigma
        with np.errstate(divide="ignore", invalid="ignore"):
            c = self.covariance / np.outer(s, s)
        c[~np.isfinite(c)] = 0.0
        np.fill_diagonal(c, 1.0)
        return c

    @property
    def values(self) -> NDArray[np.float64]:
        """``(u,)`` estimated values of :attr:`parameters`."""
        names = self.camera.intrinsic_names
        return self.camera.intrinsics[[names.index(n) for n in self.parameters]]

    def interior_block(self) -> CovarianceBlock:
        """The interior orientation's covariance block for a calibrated rig file."""
        return CovarianceBlock.from_covariance(self.parameters, self.covariance)

    def provenance(self, flight: str = "", date: str = "", notes: str = "") -> Provenance:
        """Provenance of this calibration: recipe ``camera``, the statistics, this skyrig's version."""
        from skyrig import __version__

        return Provenance("camera", flight, date, f"skyrig {__version__}", {
            "sigma0": float(self.sigma0), "redundancy": int(self.redundancy),
            "n_observations": int(self.n_observations), "n_unknowns": int(self.n_unknowns),
            "image_sigma_px": float(self.image_sigma_px), "residual_rms_col_px": float(self.residual_rms_px[0]),
            "residual_rms_row_px": float(self.residual_rms_px[1]), "n_images": int(len(self.image_names))},
            notes or f"test-field calibration, stations {self.stations}, targets fixed")

    def rig_calibration(self, head: str, flight: str = "", date: str = "", notes: str = "") -> RigCalibration:
        """A :class:`RigCalibration` holding this camera's interior block and provenance for ``head``."""
        prov = self.provenance(flight, date, notes)
        return RigCalibration({head: HeadCalibration(interior=self.interior_block(), provenance=prov)},
                              provenance=prov)

    def to_dict(self) -> dict[str, Any]:
        """The JSON report: values, sigma, correlations, statistics."""
        return {
            "recipe": "camera",
            "camera": {"name": self.camera.name, "model": self.camera.distortion.name,
                       "width_px": self.camera.width, "height_px": self.camera.height,
                       "pixel_size_mm": self.camera.pixel_size_mm,
                       "intrinsics": dict(zip(self.camera.intrinsic_names, self.camera.intrinsics.tolist())),
                       "constants": self.camera.distortion.constants_dict()},
            "estimated": [{"name": n, "value": float(v), "sigma": float(s)}
                          for n, v, s in zip(self.parameters, self.values, self.sigma)],
            "correlation": np.round(self.correlation, 6).tolist(),
            "sigma0": self.sigma0, "redundancy": self.redundancy, "n_observations": self.n_observations,
            "n_unknowns": self.n_unknowns, "image_sigma_px": self.image_sigma_px,
            "residual_rms_px": {"column": float(self.residual_rms_px[0]), "row": float(self.residual_rms_px[1])},
            "stations": self.stations, "n_images": len(self.image_names),
            "warnings": [] if self.result is None else list(self.result.warnings),
        }


def dlt_pose(camera: FrameCamera, points_world: ArrayLike, pixels: ArrayLike
             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(world_from_camera rotation (3, 3), centre (3,))`` of one image by the direct linear transformation.

    At least 6 points not on one plane; lens distortion is ignored (starting values).  Raises
    :class:`CalibrationError` otherwise.
    """
    X = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    uv = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    n = len(X)
    if n < 6:
        raise CalibrationError(f"a DLT needs at least 6 targets, got {n}")
    # Hartley normalisation
    xm, xs = X.mean(axis=0), np.sqrt(np.mean(np.sum((X - X.mean(axis=0)) ** 2, axis=1)) / 3)
    um, us = uv.mean(axis=0), np.sqrt(np.mean(np.sum((uv - uv.mean(axis=0)) ** 2, axis=1)) / 2)
    Xn, un = (X - xm) / xs, (uv - um) / us
    A = np.zeros((2 * n, 12))
    Xh = np.column_stack([Xn, np.ones(n)])
    A[0::2, 0:4] = Xh
    A[0::2, 8:12] = -un[:, :1] * Xh
    A[1::2, 4:8] = Xh
    A[1::2, 8:12] = -un[:, 1:] * Xh
    _, sv, Vt = np.linalg.svd(A)
    if sv[-2] < 1e-10 * sv[0]:
        raise CalibrationError("the DLT is singular: the targets of an image lie on one plane or line")
    Pn = Vt[-1].reshape(3, 4)
    T = np.array([[1 / us, 0, -um[0] / us], [0, 1 / us, -um[1] / us], [0, 0, 1]])
    U = np.eye(4)
    U[:3, :3] /= xs
    U[:3, 3] = -xm / xs
    P = np.linalg.solve(T, Pn @ U)
    if np.median(np.column_stack([X, np.ones(n)]) @ P[2]) < 0:
        P = -P  # points in front: positive depth
    M = P[:, :3]
    from scipy.linalg import rq

    K, R = rq(M)
    D = np.diag(np.sign(np.diag(K)))
    K, R = K @ D, D @ R
    if np.linalg.det(R) < 0:
        raise CalibrationError("the DLT gives a mirrored camera (check the pixel convention of the measurements)")
    C = -np.linalg.solve(M, P[:, 3])
    return R.T @ _CV_FROM_CAMERA, C


def _observations(target_names: Sequence[str], target_xyz: ArrayLike, obs_image: Sequence[str],
                  obs_point: Sequence[str], obs_pixel: ArrayLike
                  ) -> tuple[NDArray[np.str_], NDArray[np.float64], NDArray[np.str_], NDArray[np.str_],
                             NDArray[np.float64], dict[str, int]]:
    """The targets and the measurements as arrays, checked (distinct targets, equal lengths, only known targets),
    and each target's row."""
    names = np.asarray(target_names, dtype=str).reshape(-1)
    xyz = np.asarray(target_xyz, dtype=np.float64).reshape(-1, 3)
    if len(names) != len(xyz) or len(set(names.tolist())) != len(names):
        raise CalibrationError("target names must be distinct, one per coordinate row")
    oi = np.asarray(obs_image, dtype=str).reshape(-1)
    op = np.asarray(obs_point, dtype=str).reshape(-1)
    px = np.asarray(obs_pixel, dtype=np.float64).reshape(-1, 2)
    if not (len(oi) == len(op) == len(px)):
        raise CalibrationError("obs_image, obs_point and obs_pixel differ in length")
    t_index = {n: k for k, n in enumerate(names.tolist())}
    unknown = sorted(set(op.tolist()) - set(t_index))
    if unknown:
        raise CalibrationError(f"{len(unknown)} measured point(s) are not targets, e.g. {unknown[:5]}")
    return names, xyz, oi, op, px, t_index


def _start_camera(camera: FrameCamera, model: str | Distortion | None, parameters: Sequence[str] | None
                  ) -> tuple[FrameCamera, Sequence[str]]:
    """The starting camera with the distortion model to calibrate, and the intrinsics to estimate (checked)."""
    if model is None:
        cam0 = camera
    elif isinstance(model, Distortion):
        cam0 = camera.with_(distortion=model)
    elif camera.distortion.name == str(model).lower():
        cam0 = camera
    else:
        cam0 = camera.with_(distortion=distortion_class(str(model))())
    if parameters is None:
        parameters = tuple(n for n in cam0.intrinsic_names if n not in ("xc_mm", "yc_mm"))
    bad = [n for n in parameters if n not in cam0.intrinsic_names]
    if bad:
        raise CalibrationError(f"{bad} are not intrinsics of a {cam0.distortion.name!r} camera "
                               f"({', '.join(cam0.intrinsic_names)})")
    return cam0, parameters


def _start_poses(cam0: FrameCamera, images: list[str], xyz: NDArray[np.float64], t_index: dict[str, int],
                 oi: NDArray[np.str_], op: NDArray[np.str_], px: NDArray[np.float64],
                 station_centres: dict[str, ArrayLike] | None, fixed: bool
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Starting rotations and centres of the images by DLT; with ``fixed`` stations the centres given."""
    R0 = np.empty((len(images), 3, 3))
    C0 = np.empty((len(images), 3))
    for i, img in enumerate(images):
        sel = oi == img
        try:
            R0[i], C0[i] = dlt_pose(cam0, xyz[[t_index[p] for p in op[sel]]], px[sel])
        except CalibrationError as exc:
            raise CalibrationError(f"image {img!r}: {exc}") from None
        if fixed:
            if station_centres is None or img not in station_centres:
                raise CalibrationError(f"stations are fixed but image {img!r} has no station centre")
            C0[i] = np.asarray(station_centres[img], dtype=np.float64).reshape(3)
    return R0, C0


def _intrinsics_cofactor(res: AdjustmentResult, camera_name: str, parameters: Sequence[str]) -> NDArray[np.float64]:
    """The cofactor block of the estimated intrinsics (symmetrised), from the full or the selected covariance."""
    lab = res.layout.labels
    cols = [lab.index(("intrinsics", camera_name, n)) for n in parameters]
    if res.covariance is not None:
        Q = res.covariance.Qcc[np.ix_(cols, cols)]
    elif res.selected is not None:
        sc = [res.selected.labels.index(("intrinsics", camera_name, n)) for n in parameters]
        Q = res.selected.Qcc[np.ix_(sc, sc)]
    else:
        raise CalibrationError("the adjustment gave no covariance of the intrinsics: " + "; ".join(res.warnings))
    return 0.5 * (Q + Q.T)


def calibrate_camera(
    camera: FrameCamera,
    target_names: Sequence[str],
    target_xyz: ArrayLike,
    obs_image: Sequence[str],
    obs_point: Sequence[str],
    obs_pixel: ArrayLike,
    *,
    model: str | Distortion | None = "brown",
    parameters: Sequence[str] | None = None,
    stations: Literal["fixed", "free"] = "fixed",
    station_centres: dict[str, ArrayLike] | None = None,
    image_sigma_px: float = 0.1,
    max_iterations: int = 50,
) -> CameraCalibration:
    """Test-field calibration of one camera (module docstring).

    Parameters
    ----------
    camera
        Starting camera (image size and pixel size are taken as known; focal length and principal point are
        starting values).
    target_names, target_xyz
        ``(T,)`` names and ``(T, 3)`` coordinates (m) of the fixed targets, in one Cartesian frame.
    obs_image, obs_point, obs_pixel
        ``(N,)`` image and target names and ``(N, 2)`` measured pixels (column, row).
    model
        Distortion model to calibrate: a registered name (started at zero unless the camera already has that
        model), a :class:`Distortion` instance (started at its values, constants kept), or None (the camera's).
    parameters
        Names of the intrinsics to estimate (:attr:`FrameCamera.intrinsic_names`); default all of the model
        except those of a forward model's distortion centre (inseparable from the principal point).
    stations
        ``"fixed"``: projection centres fixed at ``station_centres`` (rotations free); ``"free"``: poses free.
    station_centres
        Image name -> ``(3,)`` projection centre (m); required for fixed stations.
    image_sigma_px
        A-priori sigma of an image coordinate (default 0.1 px as in paper 004).
    max_iterations
        Of the adjustment.

    Raises
    ------
    CalibrationError
        Unknown targets or images, too few targets in an image, a missing station, an adjustment that did not
        converge or must not be trusted.
    """
    names, xyz, oi, op, px, t_index = _observations(target_names, target_xyz, obs_image, obs_point, obs_pixel)
    if stations not in ("fixed", "free"):
        raise CalibrationError(f"stations must be 'fixed' or 'free', got {stations!r}")
    cam0, parameters = _start_camera(camera, model, parameters)
    images = list(dict.fromkeys(oi.tolist()))
    I = len(images)
    R0, C0 = _start_poses(cam0, images, xyz, t_index, oi, op, px, station_centres if stations == "fixed" else None,
                          stations == "fixed")
    i_index = {n: k for k, n in enumerate(images)}
    obs_img = np.array([i_index[n] for n in oi.tolist()], np.int64)
    obs_pt = np.array([t_index[n] for n in op.tolist()], np.int64)
    fixed = stations == "fixed"
    block = Block(
        cameras=[cam0], station_name=np.array(images), station_rotation=R0, station_centre=C0,
        image_name=np.array(images), image_station=np.arange(I), image_camera=np.zeros(I, np.int64),
        image_head=np.arange(I) if fixed else np.zeros(I, np.int64),
        head_name=np.array(images) if fixed else np.array([cam0.name]),
        point_name=names, point_xyz=xyz, obs_image=obs_img, obs_point=obs_pt, obs_pixel=px,
        obs_sigma_px=float(image_sigma_px), frame="test-field frame",
    )
    # a point measured in fewer than two images is still determined (it is fixed); keep it out of the rank check
    cfg = AdjustConfig(unknowns=Unknowns(poses="fixed" if fixed else "free", boresight="free" if fixed else "fixed",
                                         points="fixed", intrinsics="free",
                                         intrinsic_names=tuple(parameters), datum="auto"),
                       solver=SolverOptions(max_iterations=max_iterations))
    res = adjust(block, cfg)
    if not res.ok:
        raise CalibrationError("the calibration adjustment must not be trusted: " + "; ".join(res.failures))
    Q = _intrinsics_cofactor(res, cam0.name, parameters)
    out = res.block
    cam = out.cameras[0]
    Rw, _ = world_from_camera(out.station_rotation[out.image_station], out.station_centre[out.image_station],
                              out.image_rotation, out.image_offset)
    if fixed:
        from skyrig.geometry.rotations import matrix_from_rotvec

        Rw = Rw @ matrix_from_rotvec(out.head_boresight[out.image_head])  # type: ignore[index]
    r = res.residuals["image"].residual if "image" in res.residuals else None
    rms = np.sqrt(np.mean(r**2, axis=0)) if r is not None and len(r) else np.full(2, np.nan)
    cal = CameraCalibration(cam, tuple(parameters), res.sigma0**2 * Q, Q, float(res.sigma0), int(res.redundancy),
                            int(res.n_observations), int(res.n_unknowns), np.asarray(rms, float),
                            float(image_sigma_px), np.array(images), Rw, out.station_centre.copy(), stations, res)
    logger.info("camera calibration: sigma0 %.3f, redundancy %d, residual RMS %.3f / %.3f px", cal.sigma0,
                cal.redundancy, rms[0], rms[1])
    return cal
