"""Convert a camera between distortion models: a least-squares fit over the whole frame, with its residual.

Method
------
A dense grid of *observed* pixels covering the whole frame, edges and corners included
(``grid = (columns, rows)`` points, default 61 x 41), is turned into viewing rays with the source camera
(:meth:`FrameCamera.rays_from_pixels`).  The target camera (the target distortion model, plus the
principal distance and principal point unless held) is fitted by Gauss-Newton so that it projects those
rays back onto the same pixels::

    minimise  sum_i | target.project_pixels(ray_i) - pixel_i |²      (pixels)

with the analytic Jacobians of :func:`skyrig.camera.jacobians.project_camera_with_jacobians`; the normal
equations are solved on Jacobi-scaled columns by a minimum-norm least-squares solve, so a parameter the grid
cannot determine (e.g. a distortion centre together with decentring) does not break the fit.  Model
constants (the forward model's ``r0_mm``) are taken from the target instance and never fitted.

The residual is reported in pixels: RMS (of the 2D error length) and maximum over the grid, and per
region of the normalised radius ``rho = |pixel - image centre| / half diagonal`` (default
``centre`` rho < 0.5, ``middle`` 0.5 <= rho < 0.8, ``edge`` rho >= 0.8: the corners).  A conversion between
two models that span different functions cannot be exact: the residual says by how much the converted camera
departs from the source, where.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from skyrig.camera.distortion import Distortion, distortion_class
from skyrig.camera.frame import FrameCamera
from skyrig.camera.jacobians import project_camera_with_jacobians

logger = logging.getLogger(__name__)

__all__ = ["ConversionReport", "RegionResidual", "compare_cameras", "convert_camera", "exact_conversion", "frame_grid",
           "DEFAULT_REGIONS"]

#: ``(name, rho_from, rho_to)`` regions of the normalised radius (half diagonal = 1)
DEFAULT_REGIONS: tuple[tuple[str, float, float], ...] = (("centre", 0.0, 0.5), ("middle", 0.5, 0.8),
                                                         ("edge", 0.8, np.inf))


@dataclass(frozen=True)
class RegionResidual:
    """Residual of one region of the frame (pixels)."""

    name: str
    rho_from: float
    rho_to: float
    n_points: int
    rms_px: float
    max_px: float


@dataclass(frozen=True)
class ConversionReport:
    """How well one camera reproduces another over the frame.

    Attributes
    ----------
    source_model, target_model
        Distortion model names.
    n_points
        Grid points used.
    rms_px, max_px
        RMS and maximum of the 2D pixel difference over the grid.
    regions
        The same per region of the normalised radius.
    fitted
        Names of the fitted intrinsics (empty for :func:`compare_cameras`).
    iterations, converged
        Gauss-Newton record.
    """

    source_model: str
    target_model: str
    n_points: int
    rms_px: float
    max_px: float
    regions: tuple[RegionResidual, ...]
    fitted: tuple[str, ...] = ()
    iterations: int = 0
    converged: bool = True

    def region(self, name: str) -> RegionResidual:
        """The region called ``name``."""
        for r in self.regions:
            if r.name == name:
                return r
        raise KeyError(f"no region {name!r}; regions: {', '.join(r.name for r in self.regions)}")

    def to_dict(self) -> dict[str, Any]:
        """Plain data (JSON reports)."""
        d = asdict(self)
        d["regions"] = [dict(asdict(r), rho_to=None if not np.isfinite(r.rho_to) else r.rho_to) for r in self.regions]
        d["fitted"] = list(self.fitted)
        return d


def frame_grid(camera: FrameCamera, grid: tuple[int, int] = (61, 41)) -> NDArray[np.float64]:
    """``(nc * nr, 2)`` pixels on a regular grid spanning the whole frame, outer pixel edges included."""
    nc, nr = int(grid[0]), int(grid[1])
    if nc < 2 or nr < 2:
        raise ValueError(f"grid must have at least 2 x 2 points, got {grid}")
    cols = np.linspace(-0.5, camera.width - 0.5, nc)
    rows = np.linspace(-0.5, camera.height - 0.5, nr)
    cc, rr = np.meshgrid(cols, rows)
    return np.column_stack([cc.ravel(), rr.ravel()])


def _normalised_radius(camera: FrameCamera, pixels: NDArray[np.float64]) -> NDArray[np.float64]:
    centre = np.array([(camera.width - 1) / 2.0, (camera.height - 1) / 2.0])
    half_diag = 0.5 * np.hypot(camera.width, camera.height)
    return np.linalg.norm(pixels - centre, axis=1) / half_diag


def _report(source: FrameCamera, target: FrameCamera, pixels: NDArray[np.float64], err: NDArray[np.float64],
            regions: Sequence[tuple[str, float, float]], fitted: tuple[str, ...], iterations: int,
            converged: bool) -> ConversionReport:
    e = np.linalg.norm(err, axis=1)
    rho = _normalised_radius(source, pixels)
    regs = []
    for name, lo, hi in regions:
        sel = (rho >= lo) & (rho < hi)
        es = e[sel]
        regs.append(RegionResidual(str(name), float(lo), float(hi), int(sel.sum()),
                                   float(np.sqrt(np.mean(es**2))) if es.size else float("nan"),
                                   float(es.max()) if es.size else float("nan")))
    return ConversionReport(source.distortion.name, target.distortion.name, int(len(e)),
                            float(np.sqrt(np.mean(e**2))), float(e.max()), tuple(regs), fitted, iterations, converged)


def _rays(camera: FrameCamera, pixels: NDArray[np.float64]) -> NDArray[np.float64]:
    rays = camera.rays_from_pixels(pixels)
    if not np.all(np.isfinite(rays)):
        bad = int((~np.isfinite(rays).all(axis=1)).sum())
        raise ValueError(f"camera {camera.name!r}: {bad} grid pixels have no ray (the distortion model does not "
                         "invert there)")
    return rays


def compare_cameras(reference: FrameCamera, other: FrameCamera, grid: tuple[int, int] = (61, 41),
                    regions: Sequence[tuple[str, float, float]] = DEFAULT_REGIONS) -> ConversionReport:
    """Pixel difference of ``other`` from ``reference``: rays of ``reference``'s grid projected with ``other``.

    Both cameras must have the same image size.
    """
    if (reference.width, reference.height) != (other.width, other.height):
        raise ValueError("compare_cameras: the cameras have different image sizes")
    px = frame_grid(reference, grid)
    err = other.project_pixels(_rays(reference, px)) - px
    return _report(reference, other, px, err, regions, (), 0, True)


def convert_camera(
    camera: FrameCamera,
    target_model: str | Distortion,
    *,
    fit: Sequence[str] = ("focal_mm", "ppx_mm", "ppy_mm"),
    hold: Sequence[str] = (),
    grid: tuple[int, int] = (61, 41),
    regions: Sequence[tuple[str, float, float]] = DEFAULT_REGIONS,
    max_iterations: int = 50,
    tolerance: float = 1e-9,
) -> tuple[FrameCamera, ConversionReport]:
    """Fit ``target_model`` to ``camera`` over the whole frame (module docstring).

    Parameters
    ----------
    camera
        The source camera (any registered distortion model).
    target_model
        A registered model name (start from zeros) or a :class:`Distortion` instance (start from its
        parameters; its constants, e.g. the forward model's ``r0_mm``, are kept).
    fit
        Which of ``focal_mm``, ``ppx_mm``, ``ppy_mm`` are fitted with the distortion parameters (default all
        three: a balanced radial model differs from an unbalanced one by a principal distance, and a
        distortion centre or decentring by a principal point shift).
    hold
        Names of target distortion parameters held at their starting values (e.g. ``("xc_mm", "yc_mm")``).
    grid
        ``(columns, rows)`` of the pixel grid over the frame.
    regions
        ``(name, rho_from, rho_to)`` regions of the normalised radius for the report.
    max_iterations, tolerance
        Gauss-Newton stop: at most this many steps, or when the largest step, scaled by its column's norm
        (so in pixels over the grid), is below ``tolerance``.

    Returns
    -------
    camera, report
        The converted camera (same name, size and pixel size) and its residual against the source.
    """
    start = distortion_class(target_model)() if isinstance(target_model, str) else target_model
    if not isinstance(start, Distortion):
        raise TypeError(f"target_model must be a model name or a Distortion, got {type(target_model).__name__}")
    target = camera.with_(distortion=start)
    names = target.intrinsic_names
    bad = [n for n in fit if n not in ("focal_mm", "ppx_mm", "ppy_mm")]
    if bad:
        raise ValueError(f"fit: unknown intrinsics {bad}; choose from focal_mm, ppx_mm, ppy_mm")
    bad = [n for n in hold if n not in start.param_names]
    if bad:
        raise ValueError(f"hold: {bad} are not parameters of model {start.name!r} ({', '.join(start.param_names)})")
    cols = np.array([j for j, n in enumerate(names)
                     if (n in fit) or (j >= 3 and n not in hold)], dtype=np.int64)
    px = frame_grid(camera, grid)
    pc = _rays(camera, px)  # unit rays: camera-frame points at 1 m
    x = target.intrinsics.copy()
    converged = False
    it = 0
    for it in range(1, max_iterations + 1):
        cam = target.with_intrinsics(x)
        proj, _, d_intr = project_camera_with_jacobians(cam, pc)
        r = (proj - px).reshape(-1)
        J = d_intr[:, :, cols].reshape(-1, cols.size)
        if not (np.all(np.isfinite(r)) and np.all(np.isfinite(J))):
            raise ValueError(f"convert_camera: the {start.name!r} model cannot be evaluated over the frame "
                             "(projection not finite); start from closer values")
        scale = np.linalg.norm(J, axis=0)
        scale[scale == 0] = 1.0
        step = np.linalg.lstsq(J / scale, -r, rcond=1e-12)[0]
        x[cols] += step / scale
        if np.max(np.abs(step)) < tolerance:
            converged = True
            break
    out = target.with_intrinsics(x)
    err = out.project_pixels(pc) - px
    if not converged:
        logger.warning("convert_camera %s -> %s: no convergence after %d iterations", camera.distortion.name,
                       start.name, max_iterations)
    rep = _report(camera, out, px, err, regions, tuple(names[c] for c in cols), it, converged)
    logger.info("convert_camera %s -> %s: RMS %.4f px, max %.4f px", rep.source_model, rep.target_model, rep.rms_px,
                rep.max_px)
    return out, rep


def exact_conversion(camera: FrameCamera, target_model: str) -> FrameCamera | None:
    """``camera`` with its distortion expressed *exactly* in ``target_model`` (same principal distance and point),
    or None when the two models do not hold the same function (then fit with :func:`convert_camera`).

    Exact pairs: a model to itself; no distortion to any model (zero coefficients); ``opencv`` <->
    ``opencv_rational`` (k4 = k5 = k6 = 0); ``opencv`` <-> ``agisoft`` with K4 = B1 = B2 = 0 (Agisoft's P1, P2
    are OpenCV's p2, p1: :mod:`skyrig.camera.agisoft`); ``opencv_rational`` -> ``agisoft`` when k4..k6 = 0;
    ``forward`` (radial only: distortion centre at the principal point, R0 = 0, K4 = P1 = P2 = B1 = B2 = 0) <->
    ``opencv`` (p1 = p2 = 0) with ``k_i = K_i c^(2i)`` (``c`` the principal distance in mm: the forward model's
    radius is in mm, OpenCV's normalised), e.g. a MicMac ``ModRad`` whose centre is the principal point.
    """
    from skyrig.camera.distortion import NoDistortion

    d = camera.distortion
    cls = distortion_class(target_model)
    target = cls.name
    if d.name == target:
        return camera
    if isinstance(d, NoDistortion):
        return camera.with_(distortion=cls())
    v = d.params_dict()
    if target == "none":
        return camera.with_(distortion=NoDistortion()) if not np.any(d.params) else None
    if d.name in ("opencv", "opencv_rational") and any(v.get(k, 0.0) for k in ("k4", "k5", "k6")):
        return None
    if d.name in ("opencv", "opencv_rational"):
        if target in ("opencv", "opencv_rational"):
            return camera.with_(distortion=cls(**{k: v[k] for k in ("k1", "k2", "p1", "p2", "k3")}))
        if target == "agisoft":
            return camera.with_(distortion=cls(k1=v["k1"], k2=v["k2"], k3=v["k3"], p1=v["p2"], p2=v["p1"]))
    c2 = camera.focal_mm ** 2
    if d.name == "forward" and target in ("opencv", "opencv_rational", "agisoft"):
        if any(v[k] for k in ("xc_mm", "yc_mm", "k4", "p1", "p2", "b1", "b2")) or d.constants_dict()["r0_mm"]:
            return None
        ks = {"k1": v["k1"] * c2, "k2": v["k2"] * c2**2, "k3": v["k3"] * c2**3}
        return camera.with_(distortion=cls(**ks))
    if target == "forward" and d.name in ("opencv", "opencv_rational", "agisoft"):
        if any(v.get(k, 0.0) for k in ("p1", "p2", "k4", "k5", "k6", "b1", "b2")):
            return None
        return camera.with_(distortion=cls(k1=v["k1"] / c2, k2=v["k2"] / c2**2, k3=v["k3"] / c2**3))
    if d.name == "agisoft" and target in ("opencv", "opencv_rational"):
        if v["k4"] or v["b1"] or v["b2"]:
            return None
        return camera.with_(distortion=cls(k1=v["k1"], k2=v["k2"], k3=v["k3"], p1=v["p2"], p2=v["p1"]))
    return None
