"""Image coordinates of object points: the collinearity observations of the bundle.

Data (:class:`ImageRows` in ``block.observations['image']``;
the Block's keywords): ``obs_image (N,)``, ``obs_point (N,)``, ``obs_pixel (N, 2)`` px (column, row),
``obs_sigma_px (N, 2)`` px and optional ``obs_cov_px2 (N, 2, 2)`` px².  Residual: the projection of the
point through the image's camera (``world_from_camera = R_station @ station_from_camera @
expmap(boresight)``, the mounting of an actuated head from its actuator angle, see
:meth:`skyrig.adjust.model.Model.camera_poses`) minus the measurement, with the Jacobian with respect to
the station pose, the head's boresight, the camera's intrinsics, the actuator corrections, the end points
of distances estimated in the reduced part, and the (eliminated) point.

Two paths give the same values: numpy over the rows of each frame camera (the compiled chain rule of
:mod:`skyrig.adjust._image_kernels` when numba is there), and one compiled pass for blocks of BAL
cameras only.  The kernels are looked up in :mod:`skyrig.adjust.model` at call time (a test switches
them off there to compare with the numpy path).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.factors import register
from skyrig.adjust.factors.image_grid import bilinear_weights, grids_of
from skyrig.adjust.factors.base import (
    REQUIRED,
    BalCamera,
    BlockError,
    Factor,
    ObservationType,
    any_on,
    check_covariance,
    check_finite,
    check_index,
    check_positive,
    covariance_rows,
    rows_of,
    sigma_rows,
    whitening_matrices,
)
from skyrig.camera.frame import FrameCamera
from skyrig.camera.jacobians import project_camera_with_jacobians
from skyrig.geometry.rotations import matrix_from_rotvec, skew

if TYPE_CHECKING:  # pragma: no cover
    from skyrig.adjust.block import Block
    from skyrig.adjust.model import Model, State

_expmap = matrix_from_rotvec


def bal_project(
    points_camera: NDArray[np.float64], intr: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """BAL camera model, vectorised with one intrinsic vector per point.

    Parameters
    ----------
    points_camera
        ``(N, 3)`` camera-frame points (camera looks along -z).
    intr
        ``(N, 3)`` ``(f, k1, k2)`` per point.

    Returns
    -------
    uv
        ``(N, 2)`` image coordinates, pixels from the centre, x right, y up.
    d_pc, d_intr
        ``(N, 2, 3)`` and ``(N, 2, 3)`` Jacobians.
    """
    pc = points_camera
    f, k1, k2 = intr[:, 0], intr[:, 1], intr[:, 2]
    iz = -1.0 / pc[:, 2]
    p = pc[:, :2] * iz[:, None]
    r2 = (p * p).sum(axis=1)
    rad = 1.0 + r2 * (k1 + k2 * r2)
    uv = (f * rad)[:, None] * p
    n = len(pc)
    # d uv / d p = f (rad I + p (d rad / d p)^T), d rad / d p = 2 p (k1 + 2 k2 r2)
    drad = 2.0 * (k1 + 2.0 * k2 * r2)
    duv_dp = (f * rad)[:, None, None] * np.eye(2)[None] + (f * drad)[:, None, None] * p[:, :, None] * p[:, None, :]
    dp_dpc = np.zeros((n, 2, 3))
    dp_dpc[:, 0, 0] = iz
    dp_dpc[:, 1, 1] = iz
    dp_dpc[:, :, 2] = p * iz[:, None]  # p = -P/z  =>  dp/dz = P/z² = -p/z = p * iz
    d_pc = duv_dp @ dp_dpc
    d_intr = np.empty((n, 2, 3))
    d_intr[:, :, 0] = rad[:, None] * p
    d_intr[:, :, 1] = (f * r2)[:, None] * p
    d_intr[:, :, 2] = (f * r2 * r2)[:, None] * p
    return uv, d_pc, d_intr


@dataclass
class ImageCache:
    """Per-model constants of the image rows."""

    #: ``(N, 2, 2)`` whitening matrices of full covariances, or None
    W: NDArray[np.float64] | None
    #: reduced columns of the end points of distances seen in each row's image (``(N, 3 m)``), the rows
    #: that observe such a point, and the slot of each of those rows; None without such points
    red_cols: NDArray[np.int64] | None
    red_rows: NDArray[np.int64] | None
    red_idx: NDArray[np.int64] | None
    #: ``(C,)`` True for BAL cameras
    bal: NDArray[np.bool_]
    #: camera of each row, the rows of each frame camera, the rows of BAL cameras
    obs_cam: NDArray[np.int64]
    frame_groups: list
    bal_rows: NDArray[np.int64]
    #: columns of the compiled BAL path's rows (fixed for the model: set on first use)
    bal_cols: NDArray[np.int64] | None = None
    #: columns of the numpy path's rows and the point of each row (fixed for the model: set on first use,
    #: shared by the factors of every state)
    frame_cols: NDArray[np.int64] | None = None
    frame_point: NDArray[np.int64] | None = None
    #: correction grids (:mod:`skyrig.adjust.factors.image_grid`): per row the positions in ``State.grid`` of
    #: the x values of its cell's 4 nodes (y = x + 1; -1: the camera has no grid) and their bilinear weights at
    #: the measured pixel; None without grids
    grid_idx: NDArray[np.int64] | None = None
    grid_w: NDArray[np.float64] | None = None


#: rows per chunk of the camera-frame points (no (N, 3, 3) gather of the rotations)
_CHUNK = 1 << 16


def _camera_frame(Rc: NDArray[np.float64], Cc: NDArray[np.float64], X: NDArray[np.float64],
                  oi: NDArray[np.int64], op: NDArray[np.int64]) -> NDArray[np.float64]:
    """``pc[o] = Rc[oi[o]]^T (X[op[o]] - Cc[oi[o]])`` in chunks of rows."""
    n = len(oi)
    pc = np.empty((n, 3))
    for a in range(0, n, _CHUNK):
        o = oi[a:a + _CHUNK]
        pc[a:a + _CHUNK] = np.einsum("nji,nj->ni", Rc[o], X[op[a:a + _CHUNK]] - Cc[o])
    return pc


@dataclass
class ImageRows:
    """Image measurements of object points: the rows of the ``image`` type (``block.observations['image']``; the block's keywords
    ``obs_*`` route here).

    Attributes
    ----------
    image
        ``(N,)`` image index.
    point
        ``(N,)`` point index.
    pixel
        ``(N, 2)`` measured (column, row), px.
    sigma_px
        ``(N, 2)`` sigma, px.
    cov_px2
        optional ``(N, 2, 2)`` covariance, px².
    """

    image: NDArray[np.int64]
    point: NDArray[np.int64]
    pixel: NDArray[np.float64]
    sigma_px: NDArray[np.float64]
    cov_px2: NDArray[np.float64] | None = None

    def __len__(self) -> int:
        return len(self.image)


class Image(ObservationType):
    name = "image"
    words = "image"
    components = ("x", "y")
    units = "px"
    order = 0.0
    share_checked = False  # many image blunders are data snooping's normal work (its cap applies)
    hints = (("intrinsics", "an uncalibrated interior orientation"), ("boresight", "a boresight misalignment"))
    vce_split = ((0, 1),)
    sigma_field = "sigma_px"
    cov_field = "cov_px2"
    rows = ImageRows
    keywords = (('obs_image', 'image', REQUIRED), ('obs_point', 'point', REQUIRED), ('obs_pixel', 'pixel', REQUIRED), ('obs_sigma_px', 'sigma_px', 1.0), ('obs_cov_px2', 'cov_px2', None))

    def data(self, block: "Block") -> ImageRows:
        return block.observations[self.name]

    def count(self, block: "Block") -> int:
        return block.n_observations

    def normalise(self, block: "Block") -> None:
        d = self.data(block)
        d.image = np.asarray(d.image, dtype=np.int64).reshape(-1)
        n = len(d.image)
        d.point = rows_of(d.point, (), np.int64, n)
        d.pixel = rows_of(d.pixel, (2,), n=n)
        d.sigma_px = sigma_rows(d.sigma_px, n, 2)
        covariance_rows(d, "cov_px2", "sigma_px", n, 2, label="obs_cov_px2")

    def validate(self, block: "Block") -> None:
        d = self.data(block)
        check_index("obs_image", d.image, block.n_images, "image")
        check_index("obs_point", d.point, block.n_points, "point")
        check_finite("obs_pixel", d.pixel)
        check_finite("obs_sigma_px", d.sigma_px)
        check_positive("obs_sigma_px", d.sigma_px)
        check_covariance("obs_cov_px2", d.cov_px2)

    def validate_rays(self, block: "Block", controlled: NDArray[np.bool_]) -> None:
        """Every point needs two rays or control; no point measured twice in one image."""
        d = self.data(block)
        rays = np.bincount(d.point, minlength=block.n_points)
        bad = np.flatnonzero((rays < 2) & ~controlled)
        if bad.size:
            raise BlockError(
                f"point {str(block.point_name[bad[0]])!r} is seen in {rays[bad[0]]} image(s) and is not control: "
                f"it cannot be determined ({bad.size} such points); remove it or add observations"
            )
        pair = d.image * max(block.n_points, 1) + d.point
        u, c = np.unique(pair, return_counts=True)
        if (c > 1).any():
            k = u[c > 1][0]
            raise BlockError(f"point {str(block.point_name[k % block.n_points])!r} is measured more than once in "
                             f"image {str(block.image_name[k // block.n_points])!r}")

    def prepare(self, model: "Model") -> ImageCache:
        b, lay = model.block, model.layout
        d = self.data(b)
        W = None if d.cov_px2 is None else whitening_matrices(d.cov_px2)
        red_cols = red_rows = red_idx = None
        if lay.has_rpoint:
            rp = lay.rpoint_cols[d.point]
            rows = np.flatnonzero(rp[:, 0] >= 0)
            rows = rows[np.argsort(d.image[rows], kind="stable")]
            img = d.image[rows]
            first = np.searchsorted(img, img, side="left")
            rank = np.arange(len(rows)) - first
            m = int(rank.max()) + 1 if rows.size else 0
            img_cols = np.full((b.n_images, 3 * m), -1, np.int64)
            for c in range(3):
                img_cols[img, 3 * rank + c] = rp[rows, c]
            red_cols = img_cols[d.image]
            red_rows = rows
            red_idx = 3 * rank[:, None] + np.arange(3)[None, :]
        bal = np.array([isinstance(c, BalCamera) for c in b.cameras], bool)
        obs_cam = b.image_camera[d.image]
        groups = [(c, np.flatnonzero(obs_cam == c)) for c in range(len(b.cameras)) if not bal[c]]
        groups = [(c, idx) for c, idx in groups if idx.size]
        gi = gw = None
        grids = grids_of(b)
        if grids is not None:
            gi = np.full((b.n_observations, 4), -1, np.int64)
            gw = np.zeros((b.n_observations, 4))
            off = grids.offsets()
            cam_idx = {c.name: j for j, c in enumerate(b.cameras)}
            for k, g in enumerate(grids.grids):
                rows = np.flatnonzero(obs_cam == cam_idx[g.camera])
                if rows.size:
                    idx, w = bilinear_weights(g.x_px, g.y_px, d.pixel[rows])
                    gi[rows] = off[k] + 2 * idx
                    gw[rows] = w
        return ImageCache(W, red_cols, red_rows, red_idx, bal, obs_cam, groups, np.flatnonzero(bal[obs_cam]),
                          grid_idx=gi, grid_w=gw)

    def present(self, model: "Model") -> bool:
        return True  # always the first factor (possibly empty)

    def evaluate(self, model: "Model", s: "State", jac: bool) -> list[Factor]:
        return [self.evaluate_one(model, s, jac)]

    def evaluate_one(self, model: "Model", s: "State", jac: bool) -> Factor:
        """The image factor (its rows carry ``bad``: True where the point is behind or in the camera plane)."""
        kernels = sys.modules["skyrig.adjust.model"]
        bal_kernel, chain_kernel = kernels._BAL_KERNEL, kernels._CHAIN_KERNEL
        ic: ImageCache = model.cache[self.name]
        if (bal_kernel is not None and ic.bal.size and ic.bal.all() and model.block.n_observations
                and ic.W is None and ic.red_cols is None and ic.grid_idx is None):
            return self._bal(model, s, jac, bal_kernel)
        return self._numpy(model, s, jac, chain_kernel)

    def varying(self, model: "Model", factor: Factor) -> NDArray[np.bool_]:
        b, lay = model.block, model.layout
        d = self.data(b)
        img = (any_on(lay.pose)[b.image_station] | any_on(lay.bore)[b.image_head]
               | np.asarray((model._icols >= 0).any(axis=1), dtype=bool)[b.image_camera])
        if lay.act is not None:
            img |= any_on(lay.act)[b.image_head]
        out = img[d.image] | model.estimated_points()[d.point]
        ic = model.cache[self.name]
        if lay.grid is not None and ic.grid_idx is not None:
            gi = ic.grid_idx
            on = np.where(gi >= 0, lay.grid[np.maximum(gi, 0)] >= 0, False).any(axis=1)
            out = out | on
        return out

    def label(self, block: "Block", i: int) -> str:
        d = self.data(block)
        return f"point {block.point_name[d.point[i]]} in image {block.image_name[d.image[i]]}"

    @staticmethod
    def _project(model: "Model", s: "State", ic: ImageCache, pc: NDArray[np.float64], n: int, jac: bool
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, NDArray[np.float64] | None]:
        """Predicted pixels ``(N, 2)`` of the camera-frame points ``pc`` and, with ``jac``, their derivatives with
        respect to ``pc`` ``(N, 2, 3)`` and to the intrinsics ``(N, 2, m)`` (None when no intrinsics are free)."""
        pred = np.empty((n, 2))
        d_pc = np.empty((n, 2, 3)) if jac else None
        mmax = model._icols.shape[1]
        d_in = np.zeros((n, 2, mmax)) if (jac and model._intr_on) else None
        cams = model.cameras(s)
        for c, rows in ic.frame_groups:
            cam: FrameCamera = cams[c]
            for a in range(0, len(rows), _CHUNK):  # in chunks: the projection's temporaries stay small
                idx = rows[a:a + _CHUNK]
                px, dpc, din = project_camera_with_jacobians(cam, pc[idx])
                pred[idx] = px
                if d_pc is not None:
                    d_pc[idx] = dpc
                    if d_in is not None:
                        d_in[idx, :, : din.shape[2]] = din
                del px, dpc, din
        if ic.bal_rows.size:
            idx = ic.bal_rows
            intr = np.array([v for v in s.intr])[ic.obs_cam[idx]] if len(s.intr) else np.zeros((0, 3))
            uv, dpc, din = bal_project(pc[idx], intr)
            pred[idx] = uv
            if d_pc is not None:
                d_pc[idx] = dpc
                if d_in is not None:
                    d_in[idx, :, :3] = din
        return pred, d_pc, d_in

    def _numpy(self, model: "Model", s: "State", jac: bool, chain_kernel) -> Factor:
        """The numpy path (any camera model), the compiled chain rule when ``chain_kernel`` is given."""
        b, lay = model.block, model.layout
        d = self.data(b)
        ic = model.cache[self.name]
        n = b.n_observations
        Rc, Cc, M = model.camera_poses(s)
        oi = d.image
        pc = _camera_frame(Rc, Cc, s.X, oi, d.point)
        pred, d_pc, d_in = self._project(model, s, ic, pc, n, jac)
        grid_on = ic.grid_idx is not None and s.grid is not None
        if grid_on:  # the correction grids at the measured pixels (observed = projected + grid)
            _add_grid(pred, ic.grid_idx, ic.grid_w, s.grid)  # type: ignore[arg-type]
        grid_cols_on = grid_on and lay.grid is not None
        sig = d.sigma_px
        w = model.weights["image"]
        Wm = ic.W
        if Wm is None:
            r = (pred - d.pixel) / sig
        else:
            r = np.einsum("nij,nj->ni", Wm, pred - d.pixel)
        bad = np.asarray(~np.isfinite(r).all(axis=1), dtype=bool)
        if bad.any():
            r[bad] = 0.0  # behind the camera: reported by the solver
        f = Factor(self.name, r, sig, weight=w, whiten=Wm)
        f.bad = bad
        if not jac:
            return f
        isig = (1.0 / sig)[:, :, None]
        assert d_pc is not None  # (internal: _project gives the derivatives when jac)
        if Wm is None:  # whitened in place (same values as J * isig)
            d_pc *= isig
            dpc = d_pc
        else:
            dpc = Wm @ d_pc
        del d_pc
        dpc[bad] = 0.0
        if d_in is not None:
            d_in[bad] = 0.0  # (a point in the camera plane: NaN derivatives would poison the normals)
        st = b.image_station[oi]
        pose_on = bool((lay.pose >= 0).any())
        bore_on = bool(model._bore_on)
        # the Jacobian's column blocks, written into one preallocated (N, 2, k) array (no concatenation)
        red = ic.red_cols is not None and ic.red_cols.shape[1] > 0
        offs, o0 = _column_offsets(model, ic, d_in, pose_on, bore_on, red, grid_cols_on)
        jc = np.empty((n, dpc.shape[1], o0))  # (no column: not attached to the factor)
        jX = _chain_rule(model, s, oi, st, dpc, pc, Rc, M, jc, offs, pose_on, bore_on, chain_kernel)
        if d_in is not None:
            if Wm is None:
                np.multiply(d_in, isig, out=jc[:, :, offs["intr"]])
            else:
                jc[:, :, offs["intr"]] = Wm @ d_in
            del d_in
        if model._act_on:
            _, D = model.actuated_mounts(s, True)
            ia = model._img2act[oi]
            rows = np.flatnonzero(ia >= 0)
            ext = jc[:, :, offs["act"]]
            ext[...] = 0.0
            Rb = _expmap(s.bore[b.image_head[oi[rows]]])
            ext[rows] = (dpc[rows] @ skew(pc[rows])) @ np.swapaxes(Rb, 1, 2) @ D[ia[rows]]  # type: ignore[index]
        if red:
            ext = jc[:, :, offs["red"]]
            ext[...] = 0.0
            rows = ic.red_rows
            ext[rows[:, None, None], np.arange(2)[None, :, None], ic.red_idx[:, None, :]] = jX[rows]
        if grid_cols_on:  # d computed / d node values: the bilinear weights (x rows on x nodes, y on y)
            jg = np.zeros((n, 2, 8))
            jg[:, 0, :4] = ic.grid_w
            jg[:, 1, 4:] = ic.grid_w
            if Wm is None:
                jc[:, :, offs["grid"]] = jg * isig
            else:
                jc[:, :, offs["grid"]] = Wm @ jg
            jc[bad, :, offs["grid"]] = 0.0
        if o0:
            f.jc = jc
            if ic.frame_cols is None:  # the columns depend on the layout only
                ic.frame_cols = _frame_columns(model, ic, oi, st, offs, pose_on, bore_on, red, grid_cols_on)
            f.cols = ic.frame_cols
        if lay.n_p:
            if ic.frame_point is None:
                ic.frame_point = lay.point[d.point]
            f.point = ic.frame_point
            f.jp = jX
        return f

    def _bal(self, model: "Model", s: "State", jac: bool, bal_kernel) -> Factor:
        """:meth:`_numpy` for blocks of BAL cameras only, through the compiled kernel (same values)."""
        b, lay = model.block, model.layout
        d = self.data(b)
        ic = model.cache[self.name]
        n = b.n_observations
        Rc, Cc, M = model.camera_poses(s)
        intr = np.ascontiguousarray(np.array(s.intr, dtype=np.float64)[b.image_camera])
        pose_on = bool((lay.pose >= 0).any())
        widths = []
        if pose_on:
            widths.append(6)
        if model._bore_on:
            widths.append(3)
        if model._intr_on:
            widths.append(model._icols.shape[1])
        offs = np.concatenate([[0], np.cumsum(widths)]).astype(np.int64)
        k = int(offs[-1]) if jac else 0
        o_pose = int(offs[0]) if pose_on else -1
        o_bore = int(offs[int(pose_on)]) if model._bore_on else -1
        o_intr = int(offs[int(pose_on) + int(model._bore_on)]) if model._intr_on else -1
        r = np.empty((n, 2))
        bad = np.empty(n, np.bool_)
        jc = np.empty((n if jac else 0, 2, k))  # the kernel writes every column
        jp = np.empty((n if jac else 0, 2, 3))
        off = np.ascontiguousarray(b.image_offset, dtype=np.float64)
        bal_kernel(d.image, d.point, b.image_station, np.ascontiguousarray(Rc), np.ascontiguousarray(Cc),
                    np.ascontiguousarray(M), np.ascontiguousarray(s.R), off, bool(np.any(off)),
                    np.ascontiguousarray(s.X), intr, np.ascontiguousarray(d.pixel, dtype=np.float64),
                    np.ascontiguousarray(d.sigma_px, dtype=np.float64), jac, o_pose, o_bore, o_intr, r, bad, jc, jp)
        f = Factor(self.name, r, d.sigma_px, weight=model.weights["image"])
        f.bad = bad
        if not jac:
            return f
        if k:
            f.jc = jc
            if ic.bal_cols is None:
                colblocks = []
                if pose_on:
                    colblocks.append(lay.pose[b.image_station[d.image]])
                if model._bore_on:
                    colblocks.append(lay.bore[b.image_head[d.image]])
                if model._intr_on:
                    colblocks.append(model._icols[ic.obs_cam])
                ic.bal_cols = np.concatenate(colblocks, axis=1)
            f.cols = ic.bal_cols
        if lay.n_p:
            f.point = lay.point[d.point]
            f.jp = jp
        return f


IMAGE = register(Image())


def _add_grid(pred: NDArray[np.float64], gi: NDArray[np.int64], gw: NDArray[np.float64],
              grid: NDArray[np.float64]) -> None:
    """Add the correction grids at the measured pixels to the predictions (observed = projected + grid):
    ``gi`` ``(N, 4)`` the x node index of each bilinear corner (-1: none; y is the next unknown), ``gw`` its
    weights."""
    has = gi >= 0
    gx = grid[np.maximum(gi, 0)] * has
    gy = grid[np.maximum(gi, 0) + 1] * has
    pred[:, 0] += (gw * gx).sum(axis=1)
    pred[:, 1] += (gw * gy).sum(axis=1)


def _column_offsets(model: "Model", ic, d_in, pose_on: bool, bore_on: bool, red: bool,
                   grid_cols_on: bool) -> tuple[dict[str, slice], int]:
    """The slices of the image Jacobian's column blocks in one (N, 2, k) array, and k."""
    widths = []
    if pose_on:
        widths.append(("pose", 6))
    if bore_on:
        widths.append(("bore", 3))
    if d_in is not None:
        widths.append(("intr", d_in.shape[2]))
    if model._act_on:
        widths.append(("act", model._act_width))
    if red:
        widths.append(("red", ic.red_cols.shape[1]))
    if grid_cols_on:
        widths.append(("grid", 8))
    offs: dict[str, slice] = {}
    o0 = 0
    for name, wdt in widths:
        offs[name] = slice(o0, o0 + wdt)
        o0 += wdt
    return offs, o0


def _chain_rule(model: "Model", s: "State", oi, st, dpc, pc, Rc, M, jc, offs: dict[str, slice], pose_on: bool,
                bore_on: bool, chain_kernel):
    """d pixel / d point (returned) and the pose / boresight blocks of ``jc`` from d pixel / d camera-frame point;
    the compiled chain rule when ``chain_kernel`` is given (same values)."""
    b = model.block
    n = len(oi)
    if chain_kernel is not None and dpc.shape[1] == 2:  # compiled chain rule (same values)
        jX = np.empty((n, 2, 3))
        jpose = jc[:, :, offs["pose"]] if pose_on else np.empty((n, 2, 6))
        jthc = jc[:, :, offs["bore"]] if bore_on else np.empty((n, 2, 3))
        off_i = np.ascontiguousarray(b.image_offset, dtype=np.float64)
        chain_kernel(oi, b.image_station, np.ascontiguousarray(dpc), np.ascontiguousarray(pc),
                     np.ascontiguousarray(Rc), np.ascontiguousarray(M), np.ascontiguousarray(s.R), off_i,
                     bool(np.any(off_i)), jX, jpose, jthc)
    else:
        Ro = Rc[oi]
        jX = dpc @ np.swapaxes(Ro, 1, 2)
        del Ro
        if pose_on:
            jth_cam = dpc @ skew(pc)
            jpose = jc[:, :, offs["pose"]]
            jpose[:, :, :3] = -jX
            off = b.image_offset[oi]
            jth = jth_cam @ np.swapaxes(M[oi], 1, 2)
            if np.any(b.image_offset):
                jth = jth + (-jX) @ (-(s.R[st] @ skew(off)))
            jpose[:, :, 3:] = jth
            if bore_on:
                jc[:, :, offs["bore"]] = jth_cam
        elif bore_on:
            jc[:, :, offs["bore"]] = dpc @ skew(pc)
    return jX


def _frame_columns(model: "Model", ic, oi, st, offs: dict[str, slice], pose_on: bool, bore_on: bool, red: bool,
                   grid_cols_on: bool):
    """The image Jacobian's unknown columns (-1: none), in the order of :func:`_column_offsets`."""
    b, lay = model.block, model.layout
    n = len(oi)
    colblocks = []
    if pose_on:
        colblocks.append(lay.pose[st])
    if bore_on:
        colblocks.append(lay.bore[b.image_head[oi]])
    if "intr" in offs:
        colblocks.append(model._icols[ic.obs_cam])
    if model._act_on:
        cols = np.full((n, model._act_width), -1, np.int64)
        ia = model._img2act[oi]
        rows = np.flatnonzero(ia >= 0)
        cols[rows] = model.layout.act_cols[b.image_head[oi[rows]]]
        colblocks.append(cols)
    if red:
        colblocks.append(ic.red_cols)
    lgrid = lay.grid
    if grid_cols_on and lgrid is not None:
        gi = ic.grid_idx
        has = gi >= 0
        gc = np.where(has, lgrid[np.maximum(gi, 0)], -1)
        gcy = np.where(has, lgrid[np.maximum(gi, 0) + 1], -1)
        colblocks.append(np.concatenate([gc, gcy], axis=1))
    return np.concatenate(colblocks, axis=1)
