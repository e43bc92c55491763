"""Residuals and analytic Jacobians of every observation of a :class:`~skyrig.adjust.block.Block`.

The unknowns are split in two parts:

* the **reduced** ("camera") part ``x_c``: station poses ``(dC, dθ)`` (6 per station, rotation
  perturbed on the right: ``R <- R @ expmap(dθ)``), intrinsics per camera, boresight corrections per
  head, GNSS lever arm, datum shift, per-strip shift and drift;
* the **point** part ``x_p``: 3 coordinates per free object point, eliminated by the Schur complement.

Every observation group becomes a :class:`Factor`: whitened residuals ``(n, d)`` (residual / sigma),
the Jacobian ``(n, d, k)`` with respect to ``k`` reduced columns per row (column indices ``(n, k)``,
-1 = not estimated) and, for rows that involve an object point, the Jacobian ``(n, d, 3)`` with
respect to that point.  All of it is computed with vectorised numpy over the rows; the only Python
loop is over the (few) frame cameras.

Residuals are *computed minus observed*, divided by the a-priori sigma.  Where a group carries a full
covariance ``Σ`` per row (image ``(2, 2)``, control, GNSS and IMU ``(3, 3)``), the row is whitened instead by
``W = U``, the upper Cholesky factor of the inverse covariance (``Σ^-1 = U^T U``): residual ``W v`` and
Jacobian ``W J``, so that ``|W v|^2 = v^T Σ^-1 v``; the solver and the statistics see independent unit
rows either way (the factor keeps ``W`` in ``whiten`` to un-whiten residuals for reports).

Distance observations (scale bars) couple two object points; since the Schur elimination needs every
row to touch at most one eliminated point, the end points of distances are estimated in the reduced
part (``Layout.rpoint``): their image rows carry the point Jacobian among the reduced columns.  As rows
of one image must share their reduced columns, each image's rows get one 3-column slot per reduced
point seen in that image (zero for the other rows).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.block import AdjustConfig, BalCamera, Block
from skyrig.adjust.factors import observation_type, observation_types
from skyrig.adjust.factors.base import Factor, whitening_matrices
from skyrig.camera.frame import FrameCamera
from skyrig.camera.jacobians import project_camera_with_jacobians
from skyrig.geometry.rotations import matrix_from_rotvec, matrix_from_rpy, rotvec_from_matrix, skew

__all__ = ["Layout", "State", "Factor", "Model", "bal_project", "whitening_matrices"]


def _expmap(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return matrix_from_rotvec(v)


def _logmap(r: NDArray[np.float64]) -> NDArray[np.float64]:
    return rotvec_from_matrix(r)


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
class State:
    """Current values of all unknowns (a copy; the block keeps the starting values)."""

    R: NDArray[np.float64]
    C: NDArray[np.float64]
    intr: list[NDArray[np.float64]]
    bore: NDArray[np.float64]
    lever: NDArray[np.float64]
    shift: NDArray[np.float64]
    sshift: NDArray[np.float64]
    sdrift: NDArray[np.float64]
    X: NDArray[np.float64]
    #: ``(H, 2 + 6 N)`` actuator corrections of actuated heads (see ``Block.actuator_correction``)
    act: NDArray[np.float64] | None = None

    @classmethod
    def from_block(cls, b: Block) -> "State":
        return cls(b.station_rotation.copy(), b.station_centre.copy(), [c.intrinsics.copy() for c in b.cameras],
                   b.head_boresight.copy(), b.lever_arm.copy(), b.datum_shift.copy(),  # type: ignore[union-attr]
                   b.strip_shift.copy(), b.strip_drift.copy(), b.point_xyz.copy(),  # type: ignore[union-attr]
                   None if b.actuator_correction is None else b.actuator_correction.copy())

    def copy(self) -> "State":
        return State(self.R.copy(), self.C.copy(), [v.copy() for v in self.intr], self.bore.copy(), self.lever.copy(),
                     self.shift.copy(), self.sshift.copy(), self.sdrift.copy(), self.X.copy(),
                     None if self.act is None else self.act.copy())


def pad_actuator(a: NDArray[np.float64] | None, n_heads: int, width: int) -> NDArray[np.float64]:
    """Actuator corrections ``(H, width)``: ``a`` cut or padded with zeros (higher Fourier orders)."""
    out = np.zeros((n_heads, width))
    if a is not None and a.size:
        w = min(width, a.shape[1])
        out[:, :w] = a[:, :w]
    return out


@dataclass
class Layout:
    """Column indices of the reduced unknowns and indices of the free points.

    ``-1`` marks a fixed (not estimated) parameter.  ``labels`` names every reduced column as
    ``(group, owner, component)``.
    """

    pose: NDArray[np.int64]
    intr: list[NDArray[np.int64]]
    bore: NDArray[np.int64]
    lever: NDArray[np.int64]
    shift: NDArray[np.int64]
    sshift: NDArray[np.int64]
    sdrift: NDArray[np.int64]
    point: NDArray[np.int64]
    n_c: int
    n_p: int
    labels: list[tuple[str, str, str]] = field(default_factory=list)
    #: ``(P, 3)`` reduced columns of the points estimated in the reduced part (end points of distance
    #: observations: a distance couples two points, which the Schur elimination of points cannot);
    #: -1 for the others (eliminated or fixed).  None = no such points.
    rpoint: NDArray[np.int64] | None = None
    #: ``(H, 2 + 6 N)`` columns of the actuator corrections of actuated heads (-1: fixed / not actuated)
    act: NDArray[np.int64] | None = None

    @classmethod
    def build(cls, b: Block, cfg: AdjustConfig, point_active: NDArray[np.bool_] | None = None) -> "Layout":
        """Columns for ``b`` under ``cfg``; points with ``point_active`` False are not estimated."""
        labels: list[tuple[str, str, str]] = []
        n = 0

        def take(count_shape: tuple[int, ...], on: bool, group: str, owners, comps) -> NDArray[np.int64]:  # type: ignore[no-untyped-def]
            nonlocal n
            size = int(np.prod(count_shape))
            if not on or size == 0:
                return np.full(count_shape, -1, np.int64)
            idx = np.arange(n, n + size, dtype=np.int64).reshape(count_shape)
            n += size
            for o in owners:
                for c in comps:
                    labels.append((group, str(o), c))
            return idx

        pose = take((b.n_stations, 6), cfg.poses != "fixed", "pose", b.station_name,
                    ("X", "Y", "Z", "rx", "ry", "rz"))
        intr = []
        for cam in b.cameras:
            names = cam.intrinsic_names
            cols = np.full(len(names), -1, np.int64)
            used = np.flatnonzero(b.image_camera == len(intr)).size > 0
            if cfg.intrinsics != "fixed" and used:
                for j, nm in enumerate(names):
                    if cfg.intrinsic_names is None or nm in cfg.intrinsic_names:
                        cols[j] = n
                        labels.append(("intrinsics", cam.name, nm))
                        n += 1
            intr.append(cols)
        bore = take((len(b.head_name), 3), cfg.boresight != "fixed", "boresight", b.head_name,  # type: ignore[arg-type]
                    ("rx", "ry", "rz"))
        has_gnss = len(b.gnss_station) > 0  # type: ignore[arg-type]
        lever = take((3,), cfg.lever_arm != "fixed" and has_gnss, "lever_arm", ["antenna"], ("x", "y", "z"))
        shift = take((3,), cfg.datum_shift != "fixed" and has_gnss, "datum_shift", ["gnss"], ("X", "Y", "Z"))
        strips = [f"strip{k}" for k in range(b.n_strips)]
        sshift = take((b.n_strips, 3), cfg.strip_shift != "fixed" and has_gnss, "strip_shift", strips,
                      ("X", "Y", "Z"))
        sdrift = take((b.n_strips, 3), cfg.strip_drift != "fixed" and has_gnss, "strip_drift", strips,
                      ("X", "Y", "Z"))
        width = 2 + 6 * int(cfg.actuator_fourier_order)
        act_cols = np.full((len(b.head_name), width), -1, np.int64)  # type: ignore[arg-type]
        fourier_names = [f"{cs}{k}_{ax}" for k in range(1, int(cfg.actuator_fourier_order) + 1)
                         for cs in ("c", "s") for ax in ("roll", "pitch", "yaw")]
        for h, head in enumerate(b.head_actuated):  # type: ignore[arg-type]
            if head is None or not np.any(b.image_head == h):
                continue
            for j, on, nm in ([(0, cfg.actuator != "fixed", "beta_offset"), (1, cfg.actuator != "fixed", "beta_scale")]
                              + [(2 + q, cfg.actuator_curve != "fixed", fourier_names[q]) for q in range(width - 2)]):
                if on:
                    act_cols[h, j] = n
                    labels.append(("actuator" if j < 2 else "actuator_curve", str(b.head_name[h]), nm))  # type: ignore[index]
                    n += 1
        act = np.ones(b.n_points, bool) if point_active is None else np.asarray(point_active, bool).copy()
        rpoint = None
        if cfg.points != "fixed" and b.n_distances:
            red = np.zeros(b.n_points, bool)
            red[np.asarray(b.distance_point).reshape(-1)] = True
            red &= act
            if red.any():
                rpoint = np.full((b.n_points, 3), -1, np.int64)
                rpoint[red] = take((int(red.sum()), 3), True, "point", b.point_name[red], ("X", "Y", "Z"))
                act &= ~red
        if cfg.points == "fixed":
            point = np.full(b.n_points, -1, np.int64)
        else:
            point = np.where(act, np.cumsum(act) - 1, -1).astype(np.int64)
        return cls(pose, intr, bore, lever, shift, sshift, sdrift, point, n, int((point >= 0).sum()), labels,
                   rpoint, act_cols)

    @property
    def has_rpoint(self) -> bool:
        """True when some points are estimated in the reduced part (see ``rpoint``)."""
        return self.rpoint is not None and bool((self.rpoint >= 0).any())

    def apply(self, s: State, dc: NDArray[np.float64], dp: NDArray[np.float64]) -> State:
        """A new state with the reduced step ``dc (n_c,)`` and point step ``dp (n_p, 3)`` applied."""
        out = s.copy()
        ext = np.concatenate([dc, [0.0]])  # index -1 -> 0 step

        def step(cols: NDArray[np.int64]) -> NDArray[np.float64]:
            return ext[cols]

        d = step(self.pose)
        out.C = s.C + d[:, :3]
        out.R = s.R @ _expmap(d[:, 3:])
        for j, cols in enumerate(self.intr):
            out.intr[j] = s.intr[j] + step(cols)
        if (self.bore >= 0).any():
            out.bore = _logmap(_expmap(s.bore) @ _expmap(step(self.bore)))
        out.lever = s.lever + step(self.lever)
        out.shift = s.shift + step(self.shift)
        out.sshift = s.sshift + step(self.sshift)
        out.sdrift = s.sdrift + step(self.sdrift)
        if self.act is not None and (self.act >= 0).any():
            out.act = pad_actuator(s.act, self.act.shape[0], self.act.shape[1]) + step(self.act)
        if self.n_p or self.has_rpoint:
            out.X = s.X.copy()
        if self.n_p:
            free = self.point >= 0
            out.X[free] += dp[self.point[free]]
        if self.has_rpoint:
            red = (self.rpoint >= 0).all(axis=1)  # type: ignore[operator]
            out.X[red] += step(self.rpoint[red])  # type: ignore[index]
        return out


class Model:
    """Evaluates all factors of a block for a given :class:`State`.

    Parameters
    ----------
    block, config
        The block and the adjustment configuration.
    """

    def __init__(self, block: Block, config: AdjustConfig, point_active: NDArray[np.bool_] | None = None) -> None:
        self.block = block
        self.config = config
        #: points still estimated (data snooping drops a point left with fewer than two rays)
        self.point_active = np.ones(block.n_points, bool) if point_active is None else np.asarray(point_active, bool)
        self.layout = Layout.build(block, config, self.point_active)
        self.initial = State.from_block(block)
        #: the registered observation types (:mod:`skyrig.adjust.factors`), in evaluation order
        self.types = observation_types()
        #: per observation type the weight of each row (robust reweighting; 0 = rejected by data snooping
        #: or not used, e.g. a check point), keyed by group name
        self.weights: dict[str, NDArray[np.float64]] = {}
        self.weights["image"] = np.ones(block.n_observations)
        self.weights["control"] = np.ones(len(block.control_point))  # type: ignore[arg-type]
        self.weights["control"][block.control_check] = 0.0
        self.weights["imu"] = np.ones(len(block.imu_station))  # type: ignore[arg-type]
        self.weights["distance"] = np.ones(block.n_distances)
        for t in self.types:
            if t.name not in self.weights:
                w = t.initial_weight(block)
                if w is not None:
                    self.weights[t.name] = w
        b = block
        self._obs_W = None if b.obs_cov_px2 is None else whitening_matrices(b.obs_cov_px2)
        self._ctrl_W = None if b.control_cov_m2 is None else whitening_matrices(b.control_cov_m2)
        self._imu_W = None if b.imu_cov_rad2 is None else whitening_matrices(b.imu_cov_rad2)
        lay = self.layout
        self._red_cols = self._red_rows = self._red_idx = None
        self._bal_cols = None  # columns of the compiled BAL path's rows (fixed for the model: set once)
        if lay.has_rpoint:
            rp = lay.rpoint[b.obs_point]  # type: ignore[index]
            rows = np.flatnonzero(rp[:, 0] >= 0)
            rows = rows[np.argsort(b.obs_image[rows], kind="stable")]
            img = b.obs_image[rows]
            first = np.searchsorted(img, img, side="left")
            rank = np.arange(len(rows)) - first
            m = int(rank.max()) + 1 if rows.size else 0
            img_cols = np.full((b.n_images, 3 * m), -1, np.int64)
            for c in range(3):
                img_cols[img, 3 * rank + c] = rp[rows, c]
            self._red_cols = img_cols[b.obs_image]
            self._red_rows = rows
            self._red_idx = 3 * rank[:, None] + np.arange(3)[None, :]
        self._bal = np.array([isinstance(c, BalCamera) for c in b.cameras], bool)
        obs_cam = b.image_camera[b.obs_image]
        self._obs_cam = obs_cam
        self._frame_groups = [(c, np.flatnonzero(obs_cam == c)) for c in range(len(b.cameras)) if not self._bal[c]]
        self._frame_groups = [(c, idx) for c, idx in self._frame_groups if idx.size]
        self._bal_rows = np.flatnonzero(self._bal[obs_cam])
        # intrinsic columns per observation, padded
        mmax = max([len(c) for c in self.layout.intr] + [0])
        icols = np.full((len(b.cameras), mmax), -1, np.int64)
        for j, c in enumerate(self.layout.intr):
            icols[j, : len(c)] = c
        self._icols = icols
        self._intr_on = bool((icols >= 0).any())
        self._bore_on = bool((self.layout.bore >= 0).any())
        # actuated heads: images whose mounting is computed from beta
        heads = b.head_actuated or [None] * len(b.head_name)  # type: ignore[arg-type]
        is_act = np.array([heads[h] is not None for h in b.image_head], bool) if b.n_images else np.zeros(0, bool)
        self._act_images = np.flatnonzero(is_act)
        self._act_width = 2 + 6 * int(config.actuator_fourier_order)
        self._act_on = lay.act is not None and bool((lay.act >= 0).any())
        if self._act_images.size:
            from skyrig.rig.rig import NADIR_BODY_FROM_CAMERA

            hi = b.image_head[self._act_images]
            eye = np.eye(3)
            self._act_B = np.array([heads[h].body_from_head if heads[h] is not None else eye for h in hi])
            self._act_K = np.array([NADIR_BODY_FROM_CAMERA @ heads[h].boresight for h in hi])
            self._img2act = np.full(b.n_images, -1, np.int64)
            self._img2act[self._act_images] = np.arange(self._act_images.size)

        #: per observation type its per-model constants (whitening matrices, index tables...)
        self.cache: dict[str, object] = {t.name: t.prepare(self) for t in self.types if t.name == "gnss"}

    # ------------------------------------------------------------------ weights (by group name)
    obs_weight = property(lambda self: self.weights["image"], lambda self, v: self.weights.__setitem__("image", v),
                          doc="``(N,)`` weight of each image observation")
    control_weight = property(lambda self: self.weights["control"],
                              lambda self, v: self.weights.__setitem__("control", v))
    gnss_weight = property(lambda self: self.weights["gnss"], lambda self, v: self.weights.__setitem__("gnss", v))
    imu_weight = property(lambda self: self.weights["imu"], lambda self, v: self.weights.__setitem__("imu", v))
    distance_weight = property(lambda self: self.weights["distance"],
                               lambda self, v: self.weights.__setitem__("distance", v))

    def varying_rows(self, f: "Factor") -> NDArray[np.bool_]:
        """``(n,)`` True for the rows of factor ``f`` (of this model) that depend on at least one unknown.

        A row whose every parameter is fixed (a control point with ``points="fixed"``, the GNSS position
        or IMU attitude of a fixed pose with no free lever arm / shift...) is a constant of this
        adjustment, not an observation: it must not count in the redundancy or in sigma0.
        """
        b, lay = self.block, self.layout

        def any_on(cols: NDArray[np.int64]) -> NDArray[np.bool_]:
            c = np.asarray(cols)
            return (c >= 0).reshape(len(c), -1).any(axis=1) if c.size else np.zeros(len(c), bool)

        name = f.name
        t = observation_type(name)
        if t is not None and name == "gnss":
            return t.varying(self, f)
        rp = lay.rpoint if lay.rpoint is not None else np.full((b.n_points, 3), -1, np.int64)
        pt = (lay.point >= 0) | (rp >= 0).any(axis=1)
        if name == "image":
            img = (any_on(lay.pose)[b.image_station] | any_on(lay.bore)[b.image_head]
                   | (self._icols >= 0).any(axis=1)[b.image_camera])
            if lay.act is not None:
                img |= any_on(lay.act)[b.image_head]
            return img[b.obs_image] | pt[b.obs_point]
        if name == "control":
            return pt[b.control_point]
        if name == "gnss":
            st = b.gnss_station
            on = any_on(lay.pose)[st] | bool((lay.lever >= 0).any() or (lay.shift >= 0).any())
            if b.n_strips:
                strip = b.station_strip[st]
                on |= (strip >= 0) & (any_on(lay.sshift) | any_on(lay.sdrift))[np.where(strip >= 0, strip, 0)]
            return on
        if name == "imu":
            return any_on(lay.pose)[b.imu_station]
        if name == "distance":
            return (rp >= 0).any(axis=1)[b.distance_point].any(axis=1)
        return np.ones(len(f), bool)  # priors act on free unknowns

    # ------------------------------------------------------------------ cameras
    def cameras(self, s: State) -> list:
        return [c.with_intrinsics(v) for c, v in zip(self.block.cameras, s.intr)]

    def actuated_mounts(self, s: State, jacobian: bool = False
                        ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        """Mountings ``station_from_camera`` ``(A, 3, 3)`` of the images of actuated heads from their beta.

        With ``jacobian``: also ``(A, 3, W)``, the derivative of the mounting with respect to the
        actuator corrections of the image's head, as a rotation vector in the camera frame (before the
        head's boresight correction): ``M(θ + dθ) = M(θ) expmap(D dθ)``.  The derivative of the
        nominal tilt law (and of a calibrated curve) with respect to beta is a central difference
        (step 1e-6 rad); everything else is analytic.
        """
        b = self.block
        ai = self._act_images
        hi = b.image_head[ai]
        beta = b.image_beta_rad[ai]  # type: ignore[index]
        A = pad_actuator(s.act, len(b.head_name), self._act_width)[hi]  # type: ignore[arg-type]
        bp = (1.0 + A[:, 1]) * beta + A[:, 0]
        a = np.zeros((ai.size, 3))
        da = np.zeros((ai.size, 3))
        h = 1e-6
        for k in np.unique(hi):
            sel = hi == k
            head = b.head_actuated[k]  # type: ignore[index]
            a[sel] = head.tilt_angles(bp[sel])
            if jacobian:
                da[sel] = (head.tilt_angles(bp[sel] + h) - head.tilt_angles(bp[sel] - h)) / (2 * h)
        n_f = (self._act_width - 2) // 6
        for q in range(1, n_f + 1):
            c = A[:, 2 + 6 * (q - 1): 5 + 6 * (q - 1)]
            sn = A[:, 5 + 6 * (q - 1): 8 + 6 * (q - 1)]
            cq, sq = np.cos(q * bp)[:, None], np.sin(q * bp)[:, None]
            a += c * cq + sn * sq
            da += q * (-c * sq + sn * cq)
        T = matrix_from_rpy(a[:, 0], a[:, 1], a[:, 2])
        M = self._act_B @ T @ self._act_K
        if not jacobian:
            return M, None
        # right Jacobian of Rz(y) Ry(p) Rx(r): T(a + da) = T(a) expmap(Jr da)
        cr, sr, cp, sp = np.cos(a[:, 0]), np.sin(a[:, 0]), np.cos(a[:, 1]), np.sin(a[:, 1])
        Jr = np.zeros((ai.size, 3, 3))
        Jr[:, 0, 0] = 1.0
        Jr[:, 1, 1], Jr[:, 2, 1] = cr, -sr
        Jr[:, 0, 2], Jr[:, 1, 2], Jr[:, 2, 2] = -sp, sr * cp, cr * cp
        dadt = np.zeros((ai.size, 3, self._act_width))
        dadt[:, :, 0] = da
        dadt[:, :, 1] = da * beta[:, None]
        for q in range(1, n_f + 1):
            for j in range(3):
                dadt[:, j, 2 + 6 * (q - 1) + j] = np.cos(q * bp)
                dadt[:, j, 5 + 6 * (q - 1) + j] = np.sin(q * bp)
        D = np.swapaxes(self._act_K, 1, 2) @ Jr @ dadt
        return M, D

    def camera_poses(self, s: State) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """``world_from_camera`` rotation ``(I, 3, 3)``, centre ``(I, 3)`` and mount ``M (I, 3, 3)`` per image."""
        b = self.block
        st = b.image_station
        M = b.image_rotation
        if self._act_images.size:
            M = M.copy()
            M[self._act_images] = self.actuated_mounts(s)[0]
        if self._bore_on or np.any(s.bore):
            M = M @ _expmap(s.bore[b.image_head])
        Rs = s.R[st]
        return Rs @ M, s.C[st] + np.einsum("nij,nj->ni", Rs, b.image_offset), M

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, s: State, jacobians: bool = True) -> list[Factor]:
        """All factors at state ``s`` (residuals only when ``jacobians`` is False)."""
        out = [self._image(s, jacobians)]
        b = self.block
        if len(b.control_point):  # type: ignore[arg-type]
            out.append(self._control(s, jacobians))
        t = observation_type("gnss")
        if t.present(self):  # type: ignore[union-attr]
            out.extend(t.evaluate(self, s, jacobians))  # type: ignore[union-attr]
        if len(b.imu_station):  # type: ignore[arg-type]
            out.append(self._imu(s, jacobians))
        if b.n_distances:
            out.append(self._distance(s, jacobians))
        out.extend(self._priors(s, jacobians))
        return out

    def _image(self, s: State, jac: bool) -> Factor:
        if (_BAL_KERNEL is not None and self._bal.size and self._bal.all() and self.block.n_observations
                and self._obs_W is None and self._red_cols is None):
            return self._image_bal(s, jac)
        b, lay = self.block, self.layout
        n = b.n_observations
        Rc, Cc, M = self.camera_poses(s)
        oi = b.obs_image
        X = s.X[b.obs_point]
        Ro = Rc[oi]
        pc = np.einsum("nji,nj->ni", Ro, X - Cc[oi])
        pred = np.empty((n, 2))
        d_pc = np.empty((n, 2, 3)) if jac else None
        mmax = self._icols.shape[1]
        d_in = np.zeros((n, 2, mmax)) if (jac and self._intr_on) else None
        cams = self.cameras(s)
        for c, idx in self._frame_groups:
            cam: FrameCamera = cams[c]
            px, dpc, din = project_camera_with_jacobians(cam, pc[idx])
            pred[idx] = px
            if jac:
                d_pc[idx] = dpc  # type: ignore[index]
                if d_in is not None:
                    d_in[idx, :, : din.shape[2]] = din
        if self._bal_rows.size:
            idx = self._bal_rows
            intr = np.array([v for v in s.intr])[self._obs_cam[idx]] if len(s.intr) else np.zeros((0, 3))
            uv, dpc, din = bal_project(pc[idx], intr)
            pred[idx] = uv
            if jac:
                d_pc[idx] = dpc  # type: ignore[index]
                if d_in is not None:
                    d_in[idx, :, :3] = din
        sig = b.obs_sigma_px
        w = self.obs_weight
        Wm = self._obs_W
        if Wm is None:
            r = (pred - b.obs_pixel) / sig
        else:
            r = np.einsum("nij,nj->ni", Wm, pred - b.obs_pixel)
        bad = ~np.isfinite(r).all(axis=1)
        if bad.any():
            r[bad] = 0.0  # behind the camera: reported by the solver
        f = Factor("image", r, sig, weight=w, whiten=Wm)
        f.bad = bad  # type: ignore[attr-defined]
        if not jac:
            return f
        isig = (1.0 / sig)[:, :, None]

        def wh(J: NDArray[np.float64]) -> NDArray[np.float64]:
            return J * isig if Wm is None else Wm @ J

        dpc = wh(d_pc)  # type: ignore[arg-type]
        dpc[bad] = 0.0
        if d_in is not None:
            d_in[bad] = 0.0  # (a point in the camera plane: NaN derivatives would poison the normals)
        chain = None
        if _CHAIN_KERNEL is not None and dpc.shape[1] == 2:  # compiled chain rule (same values)
            chain = (np.empty((n, 2, 3)), np.empty((n, 2, 6)), np.empty((n, 2, 3)))
            off_i = np.ascontiguousarray(b.image_offset, dtype=np.float64)
            _CHAIN_KERNEL(oi, b.image_station, np.ascontiguousarray(dpc), np.ascontiguousarray(pc),
                          np.ascontiguousarray(Rc), np.ascontiguousarray(M), np.ascontiguousarray(s.R), off_i,
                          bool(np.any(off_i)), *chain)
            jX = chain[0]
        else:
            RoT = np.swapaxes(Ro, 1, 2)
            jX = dpc @ RoT
        blocks = []
        colblocks = []
        st = b.image_station[oi]
        if (lay.pose >= 0).any() and chain is not None:
            jth_cam, jpose = chain[2], chain[1]
            blocks.append(jpose)
            colblocks.append(lay.pose[st])
            if self._bore_on:
                blocks.append(jth_cam)
                colblocks.append(lay.bore[b.image_head[oi]])
        elif (lay.pose >= 0).any():
            jth_cam = dpc @ skew(pc)
            Mo = M[oi]
            jpose = np.empty((n, 2, 6))
            jpose[:, :, :3] = -jX
            off = b.image_offset[oi]
            jth = jth_cam @ np.swapaxes(Mo, 1, 2)
            if np.any(b.image_offset):
                jth = jth + (-jX) @ (-(s.R[st] @ skew(off)))
            jpose[:, :, 3:] = jth
            blocks.append(jpose)
            colblocks.append(lay.pose[st])
            if self._bore_on:
                blocks.append(jth_cam)
                colblocks.append(lay.bore[b.image_head[oi]])
        elif self._bore_on:
            blocks.append(dpc @ skew(pc) if chain is None else chain[2])
            colblocks.append(lay.bore[b.image_head[oi]])
        if d_in is not None:
            blocks.append(wh(d_in))
            colblocks.append(self._icols[self._obs_cam])
        if self._act_on:
            _, D = self.actuated_mounts(s, True)
            ia = self._img2act[oi]
            rows = np.flatnonzero(ia >= 0)
            ext = np.zeros((n, 2, self._act_width))
            Rb = _expmap(s.bore[b.image_head[oi[rows]]])
            ext[rows] = (dpc[rows] @ skew(pc[rows])) @ np.swapaxes(Rb, 1, 2) @ D[ia[rows]]  # type: ignore[index]
            cols = np.full((n, self._act_width), -1, np.int64)
            cols[rows] = self.layout.act[b.image_head[oi[rows]]]  # type: ignore[index]
            blocks.append(ext)
            colblocks.append(cols)
        if self._red_cols is not None and self._red_cols.shape[1]:
            ext = np.zeros((n, 2, self._red_cols.shape[1]))
            rows = self._red_rows
            ext[rows[:, None, None], np.arange(2)[None, :, None], self._red_idx[:, None, :]] = jX[rows]  # type: ignore[index]
            blocks.append(ext)
            colblocks.append(self._red_cols)
        if blocks:
            f.jc = np.concatenate(blocks, axis=2)
            f.cols = np.concatenate(colblocks, axis=1)
        if lay.n_p:
            f.point = lay.point[b.obs_point]
            f.jp = jX
        return f

    def _image_bal(self, s: State, jac: bool) -> Factor:
        """:meth:`_image` for blocks of BAL cameras only, through the compiled kernel (same values)."""
        b, lay = self.block, self.layout
        n = b.n_observations
        Rc, Cc, M = self.camera_poses(s)
        intr = np.ascontiguousarray(np.array(s.intr, dtype=np.float64)[b.image_camera])
        pose_on = bool((lay.pose >= 0).any())
        widths = []
        if pose_on:
            widths.append(6)
        if self._bore_on:
            widths.append(3)
        if self._intr_on:
            widths.append(self._icols.shape[1])
        offs = np.concatenate([[0], np.cumsum(widths)]).astype(np.int64)
        k = int(offs[-1]) if jac else 0
        o_pose = int(offs[0]) if pose_on else -1
        o_bore = int(offs[int(pose_on)]) if self._bore_on else -1
        o_intr = int(offs[int(pose_on) + int(self._bore_on)]) if self._intr_on else -1
        r = np.empty((n, 2))
        bad = np.empty(n, np.bool_)
        jc = np.empty((n if jac else 0, 2, k))  # the kernel writes every column
        jp = np.empty((n if jac else 0, 2, 3))
        off = np.ascontiguousarray(b.image_offset, dtype=np.float64)
        _BAL_KERNEL(b.obs_image, b.obs_point, b.image_station, np.ascontiguousarray(Rc), np.ascontiguousarray(Cc),
                    np.ascontiguousarray(M), np.ascontiguousarray(s.R), off, bool(np.any(off)),
                    np.ascontiguousarray(s.X), intr, np.ascontiguousarray(b.obs_pixel, dtype=np.float64),
                    np.ascontiguousarray(b.obs_sigma_px, dtype=np.float64), jac, o_pose, o_bore, o_intr, r, bad, jc, jp)
        f = Factor("image", r, b.obs_sigma_px, weight=self.obs_weight)
        f.bad = bad  # type: ignore[attr-defined]
        if not jac:
            return f
        if k:
            f.jc = jc
            if self._bal_cols is None:
                colblocks = []
                if pose_on:
                    colblocks.append(lay.pose[b.image_station[b.obs_image]])
                if self._bore_on:
                    colblocks.append(lay.bore[b.image_head[b.obs_image]])
                if self._intr_on:
                    colblocks.append(self._icols[self._obs_cam])
                self._bal_cols = np.concatenate(colblocks, axis=1)
            f.cols = self._bal_cols
        if lay.n_p:
            f.point = lay.point[b.obs_point]
            f.jp = jp
        return f

    def _control(self, s: State, jac: bool) -> Factor:
        b, lay = self.block, self.layout
        p = b.control_point
        sig = b.control_sigma
        Wm = self._ctrl_W
        if Wm is None:
            r = (s.X[p] - b.control_xyz) / sig  # type: ignore[operator]
            J = np.zeros((len(p), 3, 3))  # type: ignore[arg-type]
            J[:, [0, 1, 2], [0, 1, 2]] = 1.0 / sig  # type: ignore[operator]
        else:
            r = np.einsum("nij,nj->ni", Wm, s.X[p] - b.control_xyz)  # type: ignore[index]
            J = Wm
        f = Factor("control", r, sig, weight=self.control_weight, whiten=Wm)  # type: ignore[arg-type]
        if jac and lay.n_p:
            f.point = lay.point[p]
            f.jp = J
        if jac and lay.has_rpoint:
            f.jc = J
            f.cols = lay.rpoint[p]  # type: ignore[index]
        return f

    def _distance(self, s: State, jac: bool) -> Factor:
        """Distances between two object points (scale bars): ``|X_a - X_b| - d``, one row each."""
        b, lay = self.block, self.layout
        a, c = b.distance_point[:, 0], b.distance_point[:, 1]  # type: ignore[index]
        dx = s.X[a] - s.X[c]
        L = np.linalg.norm(dx, axis=1)
        sig = b.distance_sigma_m[:, None]  # type: ignore[index]
        f = Factor("distance", ((L - b.distance_m) / sig[:, 0])[:, None], sig,  # type: ignore[operator]
                   weight=self.distance_weight)
        if not jac:
            return f
        u = dx / np.where(L > 0, L, 1.0)[:, None]
        rp = lay.rpoint if lay.rpoint is not None else np.full((b.n_points, 3), -1, np.int64)
        f.jc = (np.concatenate([u, -u], axis=1) / sig)[:, None, :]
        f.cols = np.concatenate([rp[a], rp[c]], axis=1)
        return f

    def _imu(self, s: State, jac: bool) -> Factor:
        b, lay = self.block, self.layout
        st = b.imu_station
        e = _logmap(np.swapaxes(b.imu_rotation, 1, 2) @ s.R[st])  # type: ignore[arg-type]
        sig = b.imu_sigma_rad
        Wm = self._imu_W  # full 3x3 covariance about the station axes (Block.imu_cov_rad2), or None
        r = e / sig if Wm is None else np.einsum("nij,nj->ni", Wm, e)  # type: ignore[operator]
        f = Factor("imu", r, sig, weight=self.imu_weight, whiten=Wm)  # type: ignore[arg-type]
        if not jac:
            return f
        n = len(st)  # type: ignore[arg-type]
        jinv = np.eye(3)[None] + 0.5 * skew(e)  # inverse right Jacobian of SO(3) to first order
        j = np.zeros((n, 3, 6))
        j[:, :, 3:] = jinv
        f.jc = j / sig[:, :, None] if Wm is None else Wm @ j  # type: ignore[index]
        f.cols = lay.pose[st]
        return f

    def _priors(self, s: State, jac: bool) -> list[Factor]:
        cfg, lay, s0, b = self.config, self.layout, self.initial, self.block
        out: list[Factor] = []

        def prior(name: str, diff: NDArray, cols: NDArray, sigma: NDArray) -> None:
            diff = diff.reshape(-1, cols.shape[-1]) if diff.ndim == 1 else diff
            cols2 = cols.reshape(diff.shape)
            sig = np.broadcast_to(sigma, diff.shape).astype(np.float64)
            f = Factor(f"prior:{name}", diff / sig, sig, weight=np.ones(len(diff)))
            if jac:
                k = diff.shape[1]
                j = np.zeros((len(diff), k, k))
                j[:, np.arange(k), np.arange(k)] = 1.0 / sig
                f.jc, f.cols = j, cols2
            out.append(f)

        if cfg.poses == "weighted":
            d = np.concatenate([s.C - s0.C, _logmap(np.swapaxes(s0.R, 1, 2) @ s.R)], axis=1)
            prior("pose", d, lay.pose, np.array([cfg.pose_sigma_m] * 3 + [cfg.pose_sigma_rad] * 3))
        if cfg.intrinsics == "weighted":
            sig_of = dict(cfg.intrinsic_sigma)
            for j, cam in enumerate(b.cameras):
                on = lay.intr[j] >= 0
                if not on.any():
                    continue
                names = [n for n, o in zip(cam.intrinsic_names, on) if o]
                missing = [n for n in names if n not in sig_of]
                if missing:
                    raise ValueError(f"intrinsics are 'weighted' but intrinsic_sigma lacks {missing}")
                prior(f"intrinsics:{cam.name}", (s.intr[j] - s0.intr[j])[on][None], lay.intr[j][on][None],
                      np.array([sig_of[n] for n in names]))
        for grp, cur, ini, cols, sig in (
            ("boresight", s.bore, s0.bore, lay.bore, cfg.boresight_sigma_rad),
            ("lever_arm", s.lever, s0.lever, lay.lever, cfg.lever_arm_sigma_m),
            ("datum_shift", s.shift, s0.shift, lay.shift, cfg.datum_shift_sigma_m),
            ("strip_shift", s.sshift, s0.sshift, lay.sshift, cfg.strip_shift_sigma_m),
            ("strip_drift", s.sdrift, s0.sdrift, lay.sdrift, cfg.strip_drift_sigma_m_s),
        ):
            if getattr(cfg, grp) == "weighted" and (cols >= 0).any():
                prior(grp, (cur - ini).reshape(-1, 3), cols.reshape(-1, 3), np.array(sig))
        if lay.act is not None and (lay.act >= 0).any():
            H, W = lay.act.shape
            d = pad_actuator(s.act, H, W) - pad_actuator(s0.act, H, W)
            on = (lay.act[:, :2] >= 0).all(axis=1)
            if cfg.actuator == "weighted" and on.any():
                prior("actuator", d[on, :2], lay.act[on, :2], np.array(cfg.actuator_sigma, float))
            on = (lay.act[:, 2:] >= 0).all(axis=1) & (W > 2)
            if cfg.actuator_curve == "weighted" and on.any():
                prior("actuator_curve", d[on, 2:], lay.act[on, 2:], np.array(cfg.actuator_curve_sigma_rad))
        return out


# ---------------------------------------------------------------------------------------------------
# Compiled path of Model._image for blocks whose cameras are all BAL cameras (same results as the numpy
# path; one pass over the observations instead of a dozen (n, 2, 3) temporaries), and the chain rule of
# the frame-camera path: module-level kernels in skyrig.adjust._image_kernels (so that numba's on-disk
# cache hits in every process); None without numba.
try:
    from skyrig.adjust._image_kernels import bal_rows as _BAL_KERNEL, chain as _CHAIN_KERNEL
except ImportError:  # pragma: no cover - depends on the environment
    _BAL_KERNEL = _CHAIN_KERNEL = None
