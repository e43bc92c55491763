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

Residuals are *computed minus observed*, divided by the a-priori sigma.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.block import AdjustConfig, BalCamera, Block
from skyrig.camera.frame import FrameCamera
from skyrig.camera.jacobians import project_camera_with_jacobians
from skyrig.geometry.rotations import matrix_from_rotvec, rotvec_from_matrix, skew

__all__ = ["Layout", "State", "Factor", "Model", "bal_project"]


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

    @classmethod
    def from_block(cls, b: Block) -> "State":
        return cls(b.station_rotation.copy(), b.station_centre.copy(), [c.intrinsics.copy() for c in b.cameras],
                   b.head_boresight.copy(), b.lever_arm.copy(), b.datum_shift.copy(),  # type: ignore[union-attr]
                   b.strip_shift.copy(), b.strip_drift.copy(), b.point_xyz.copy())  # type: ignore[union-attr]

    def copy(self) -> "State":
        return State(self.R.copy(), self.C.copy(), [v.copy() for v in self.intr], self.bore.copy(), self.lever.copy(),
                     self.shift.copy(), self.sshift.copy(), self.sdrift.copy(), self.X.copy())


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
        if cfg.points == "fixed":
            point = np.full(b.n_points, -1, np.int64)
        elif point_active is None:
            point = np.arange(b.n_points, dtype=np.int64)
        else:
            act = np.asarray(point_active, bool)
            point = np.where(act, np.cumsum(act) - 1, -1).astype(np.int64)
        return cls(pose, intr, bore, lever, shift, sshift, sdrift, point, n, int((point >= 0).sum()), labels)

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
        if self.n_p:
            out.X = s.X.copy()
            free = self.point >= 0
            out.X[free] += dp[self.point[free]]
        return out


@dataclass
class Factor:
    """Whitened residuals and Jacobians of one observation group (see module docstring).

    Attributes
    ----------
    name
        ``"image"``, ``"control"``, ``"gnss"``, ``"imu"`` or ``"prior:<group>"``.
    r
        ``(n, d)`` whitened residuals (computed minus observed, over sigma).
    jc, cols
        ``(n, d, k)`` Jacobian w.r.t. reduced columns ``cols (n, k)`` (-1 = none); None if k = 0.
    point, jp
        ``(n,)`` free-point index (-1 = none) and ``(n, d, 3)`` Jacobian; None if no point.
    sigma
        ``(n, d)`` a-priori sigma (for un-whitening).
    weight
        ``(n,)`` extra weight (robust reweighting; 0 = rejected).
    """

    name: str
    r: NDArray[np.float64]
    sigma: NDArray[np.float64]
    jc: NDArray[np.float64] | None = None
    cols: NDArray[np.int64] | None = None
    point: NDArray[np.int64] | None = None
    jp: NDArray[np.float64] | None = None
    weight: NDArray[np.float64] | None = None

    def __len__(self) -> int:
        return len(self.r)


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
        #: per image observation weight (robust reweighting, 0 = rejected by data snooping)
        self.obs_weight = np.ones(block.n_observations)
        self.control_weight = np.ones(len(block.control_point))  # type: ignore[arg-type]
        self.control_weight[block.control_check] = 0.0
        self.gnss_weight = np.ones(len(block.gnss_station))  # type: ignore[arg-type]
        self.imu_weight = np.ones(len(block.imu_station))  # type: ignore[arg-type]
        b = block
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

    # ------------------------------------------------------------------ cameras
    def cameras(self, s: State) -> list:
        return [c.with_intrinsics(v) for c, v in zip(self.block.cameras, s.intr)]

    def camera_poses(self, s: State) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """``world_from_camera`` rotation ``(I, 3, 3)``, centre ``(I, 3)`` and mount ``M (I, 3, 3)`` per image."""
        b = self.block
        st = b.image_station
        M = b.image_rotation
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
        if len(b.gnss_station):  # type: ignore[arg-type]
            out.append(self._gnss(s, jacobians))
        if len(b.imu_station):  # type: ignore[arg-type]
            out.append(self._imu(s, jacobians))
        out.extend(self._priors(s, jacobians))
        return out

    def _image(self, s: State, jac: bool) -> Factor:
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
        r = (pred - b.obs_pixel) / sig
        bad = ~np.isfinite(r).all(axis=1)
        if bad.any():
            r[bad] = 0.0  # behind the camera: reported by the solver
        f = Factor("image", r, sig, weight=w)
        f.bad = bad  # type: ignore[attr-defined]
        if not jac:
            return f
        isig = (1.0 / sig)[:, :, None]
        dpc = d_pc * isig  # type: ignore[operator]
        dpc[bad] = 0.0
        RoT = np.swapaxes(Ro, 1, 2)
        jX = dpc @ RoT
        blocks = []
        colblocks = []
        st = b.image_station[oi]
        if (lay.pose >= 0).any():
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
            blocks.append(dpc @ skew(pc))
            colblocks.append(lay.bore[b.image_head[oi]])
        if d_in is not None:
            blocks.append(d_in * isig)
            colblocks.append(self._icols[self._obs_cam])
        if blocks:
            f.jc = np.concatenate(blocks, axis=2)
            f.cols = np.concatenate(colblocks, axis=1)
        if lay.n_p:
            f.point = lay.point[b.obs_point]
            f.jp = jX
        return f

    def _control(self, s: State, jac: bool) -> Factor:
        b, lay = self.block, self.layout
        p = b.control_point
        sig = b.control_sigma
        r = (s.X[p] - b.control_xyz) / sig  # type: ignore[operator]
        f = Factor("control", r, sig, weight=self.control_weight)  # type: ignore[arg-type]
        if jac and lay.n_p:
            f.point = lay.point[p]
            f.jp = np.zeros((len(p), 3, 3))  # type: ignore[arg-type]
            f.jp[:, [0, 1, 2], [0, 1, 2]] = 1.0 / sig  # type: ignore[operator]
        return f

    def _gnss(self, s: State, jac: bool) -> Factor:
        b, lay = self.block, self.layout
        st = b.gnss_station
        R = s.R[st]
        strip = b.station_strip[st]
        has = strip >= 0
        sk = np.where(has, strip, 0)
        dt = np.where(has, b.station_time[st] - (b.strip_t0[sk] if b.n_strips else 0.0), 0.0)  # type: ignore[index]
        pred = s.C[st] + np.einsum("nij,j->ni", R, s.lever) + s.shift
        if b.n_strips:
            pred = pred + has[:, None] * (s.sshift[sk] + s.sdrift[sk] * dt[:, None])
        sig = b.gnss_sigma
        r = (pred - b.gnss_xyz) / sig  # type: ignore[operator]
        f = Factor("gnss", r, sig, weight=self.gnss_weight)  # type: ignore[arg-type]
        if not jac:
            return f
        n = len(st)  # type: ignore[arg-type]
        isig = (1.0 / sig)[:, :, None]  # type: ignore[operator]
        eye = np.broadcast_to(np.eye(3), (n, 3, 3))
        blocks = [np.concatenate([eye, -(R @ skew(s.lever))], axis=2), R, eye]
        cols = [lay.pose[st], np.broadcast_to(lay.lever, (n, 3)), np.broadcast_to(lay.shift, (n, 3))]
        if b.n_strips:
            neg = np.full(3, -1, np.int64)
            blocks += [eye, eye * dt[:, None, None]]
            cols += [np.where(has[:, None], lay.sshift[sk], neg), np.where(has[:, None], lay.sdrift[sk], neg)]
        f.jc = np.concatenate(blocks, axis=2) * isig
        f.cols = np.concatenate(cols, axis=1)
        return f

    def _imu(self, s: State, jac: bool) -> Factor:
        b, lay = self.block, self.layout
        st = b.imu_station
        e = _logmap(np.swapaxes(b.imu_rotation, 1, 2) @ s.R[st])  # type: ignore[arg-type]
        sig = b.imu_sigma_rad
        f = Factor("imu", e / sig, sig, weight=self.imu_weight)  # type: ignore[arg-type, operator]
        if not jac:
            return f
        n = len(st)  # type: ignore[arg-type]
        jinv = np.eye(3)[None] + 0.5 * skew(e)  # inverse right Jacobian of SO(3) to first order
        j = np.zeros((n, 3, 6))
        j[:, :, 3:] = jinv
        f.jc = j / sig[:, :, None]  # type: ignore[index]
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
        return out
