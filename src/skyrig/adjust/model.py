"""Residuals and analytic Jacobians of every observation of a :class:`~skyrig.adjust.block.Block`.

The unknowns are split in two parts:

* the **reduced** ("camera") part ``x_c``: station poses ``(dC, dθ)`` (6 per station, rotation
  perturbed on the right: ``R <- R @ expmap(dθ)``), intrinsics per camera, boresight corrections per
  head, GNSS lever arm, datum shift, per-strip shift and drift;
* the **point** part ``x_p``: 3 coordinates per free object point, eliminated by the Schur complement.

The model holds the unknowns (:class:`State`), their columns (:class:`Layout`) and the camera geometry
(:meth:`Model.camera_poses`, actuated mountings); the observations are the registered observation types
of :mod:`skyrig.adjust.factors`, one module each, which :meth:`Model.evaluate` loops over.

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
from typing import Any

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.block import AdjustConfig, Block
from skyrig.adjust.factors import BUILTIN, image_type, observation_type, observation_types, parameter_groups
from skyrig.adjust.factors.base import Factor, pad_actuator, whitening_matrices
from skyrig.adjust.factors.image import bal_project
from skyrig.geometry.rotations import matrix_from_rotvec, matrix_from_rpy, rotvec_from_matrix
from skyrig.rig.camera_pose import world_from_camera

__all__ = ["Layout", "State", "Factor", "Model", "bal_project", "whitening_matrices"]


def _grids_of(b: Block):
    from skyrig.adjust.factors.image_grid import grids_of

    return grids_of(b)


def _expmap(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return matrix_from_rotvec(v)


def _logmap(r: NDArray[np.float64]) -> NDArray[np.float64]:
    return rotvec_from_matrix(r)


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
    #: node values of the correction grids, flat (:meth:`skyrig.adjust.factors.image_grid.ImageGrids.values`);
    #: None without grids
    grid: NDArray[np.float64] | None = None
    #: values ``(n_owners, n_components)`` of the parameter groups factor modules declare, by name
    #: (:class:`~skyrig.adjust.factors.base.ParameterGroup`)
    groups: dict[str, NDArray[np.float64]] = field(default_factory=dict)

    @classmethod
    def from_block(cls, b: Block) -> "State":
        g = _grids_of(b)
        return cls(b.station_rotation.copy(), b.station_centre.copy(), [c.intrinsics.copy() for c in b.cameras],
                   b.head_boresight.copy(), b.lever_arm.copy(), b.datum_shift.copy(),
                   b.strip_shift.copy(), b.strip_drift.copy(), b.point_xyz.copy(),
                   None if b.actuator_correction is None else b.actuator_correction.copy(),
                   None if g is None else g.values(), {p.name: p.initial(b) for p in parameter_groups()})

    def copy(self) -> "State":
        return State(self.R.copy(), self.C.copy(), [v.copy() for v in self.intr], self.bore.copy(), self.lever.copy(),
                     self.shift.copy(), self.sshift.copy(), self.sdrift.copy(), self.X.copy(),
                     None if self.act is None else self.act.copy(), None if self.grid is None else self.grid.copy(),
                     {k: v.copy() for k, v in self.groups.items()})


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
    #: observations: a distance couples two points, which the Schur elimination of points cannot; the points
    #: other types name in :meth:`~skyrig.adjust.factors.base.ObservationType.reduced_points`);
    #: -1 for the others (eliminated or fixed).  None = no such points.
    rpoint: NDArray[np.int64] | None = None
    #: ``(H, 2 + 6 N)`` columns of the actuator corrections of actuated heads (-1: fixed / not actuated)
    act: NDArray[np.int64] | None = None
    #: columns of the correction grids' node values (flat, as ``State.grid``); None when not estimated
    grid: NDArray[np.int64] | None = None
    #: columns ``(n_owners, n_components)`` of the parameter groups factor modules declare, by name (-1: fixed)
    groups: dict[str, NDArray[np.int64]] = field(default_factory=dict)

    @classmethod
    def build(cls, b: Block, cfg: AdjustConfig, point_active: NDArray[np.bool_] | None = None) -> "Layout":
        """Columns for ``b`` under ``cfg``; points with ``point_active`` False are not estimated."""
        labels: list[tuple[str, str, str]] = []
        n = 0

        def take(count_shape: tuple[int, ...], on: bool, group: str, owners, comps) -> NDArray[np.int64]:
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

        pose = take((b.n_stations, 6), cfg.unknowns.poses != "fixed", "pose", b.station_name,
                    ("X", "Y", "Z", "rx", "ry", "rz"))
        intr: list[NDArray[np.int64]] = []
        for cam in b.cameras:
            names = cam.intrinsic_names
            cols = np.full(len(names), -1, np.int64)
            used = np.flatnonzero(b.image_camera == len(intr)).size > 0
            if cfg.unknowns.intrinsics != "fixed" and used:
                for j, nm in enumerate(names):
                    if cfg.unknowns.intrinsic_names is None or nm in cfg.unknowns.intrinsic_names:
                        cols[j] = n
                        labels.append(("intrinsics", cam.name, nm))
                        n += 1
            intr.append(cols)
        bore = take((len(b.head_name), 3), cfg.unknowns.boresight != "fixed", "boresight", b.head_name,
                    ("rx", "ry", "rz"))
        # groups that only some observation type determines (GNSS: lever arm, datum and strip shifts)
        observed = {p for t in observation_types() if t.parameters and t.count(b) > 0 for p in t.parameters}

        def on(group: str) -> bool:
            return getattr(cfg.unknowns, group) != "fixed" and group in observed

        lever = take((3,), on("lever_arm"), "lever_arm", ["antenna"], ("x", "y", "z"))
        shift = take((3,), on("datum_shift"), "datum_shift", ["gnss"], ("X", "Y", "Z"))
        strips = [f"strip{k}" for k in range(b.n_strips)]
        sshift = take((b.n_strips, 3), on("strip_shift"), "strip_shift", strips, ("X", "Y", "Z"))
        sdrift = take((b.n_strips, 3), on("strip_drift"), "strip_drift", strips, ("X", "Y", "Z"))
        width = 2 + 6 * int(cfg.unknowns.actuator_fourier_order)
        act_cols = np.full((len(b.head_name), width), -1, np.int64)
        fourier_names = [f"{cs}{k}_{ax}" for k in range(1, int(cfg.unknowns.actuator_fourier_order) + 1)
                         for cs in ("c", "s") for ax in ("roll", "pitch", "yaw")]
        for h, head in enumerate(b.head_actuated):
            if head is None or not np.any(b.image_head == h):
                continue
            for j, is_on, nm in ([(0, cfg.unknowns.actuator != "fixed", "beta_offset"), (1, cfg.unknowns.actuator != "fixed", "beta_scale")]
                              + [(2 + q, cfg.unknowns.actuator_curve != "fixed", fourier_names[q]) for q in range(width - 2)]):
                if is_on:
                    act_cols[h, j] = n
                    labels.append(("actuator" if j < 2 else "actuator_curve", str(b.head_name[h]), nm))
                    n += 1
        grid_cols = None
        grids = _grids_of(b)
        if grids is not None and cfg.unknowns.image_grid != "fixed":
            parts = []
            for g in grids.grids:
                grid_used = bool(np.isin(b.image_camera, [j for j, c in enumerate(b.cameras) if c.name == g.camera]).any())
                ny, nx = len(g.y_px), len(g.x_px)
                names = [f"{ax}{iy}_{ix}" for iy in range(ny) for ix in range(nx) for ax in "xy"]
                cols = np.full(2 * nx * ny, -1, np.int64)
                if grid_used:
                    cols = np.arange(n, n + cols.size, dtype=np.int64)
                    n += cols.size
                    labels.extend(("image_grid", g.camera, nm) for nm in names)
                parts.append(cols)
            grid_cols = np.concatenate(parts) if parts else np.zeros(0, np.int64)
        act = np.ones(b.n_points, bool) if point_active is None else np.asarray(point_active, bool).copy()
        rpoint = None
        wanted = [np.asarray(b.distance_point).reshape(-1)] if b.n_distances else []
        wanted += [np.asarray(rp, np.int64).reshape(-1) for t in observation_types() if t.count(b) > 0
                   and (rp := t.reduced_points(b)) is not None]
        if cfg.unknowns.points != "fixed" and wanted:
            red = np.zeros(b.n_points, bool)
            red[np.concatenate(wanted)] = True
            red &= act
            if red.any():
                rpoint = np.full((b.n_points, 3), -1, np.int64)
                rpoint[red] = take((int(red.sum()), 3), True, "point", b.point_name[red], ("X", "Y", "Z"))
                act &= ~red
        groups = {}
        for pg in parameter_groups():  # after the built-in groups: their columns stay where they were
            owners = pg.owners(b)
            groups[pg.name] = take((len(owners), len(pg.components)),
                                   cfg.unknowns.group_mode(pg.name) != "fixed" and pg.estimated(b), pg.name, owners,
                                   pg.components)
        if cfg.unknowns.points == "fixed":
            point = np.full(b.n_points, -1, np.int64)
        else:
            point = np.where(act, np.cumsum(act) - 1, -1).astype(np.int64)
        return cls(pose, intr, bore, lever, shift, sshift, sdrift, point, n, int((point >= 0).sum()), labels,
                   rpoint, act_cols, grid_cols, groups)

    @property
    def act_cols(self) -> NDArray[np.int64]:
        """``(H, 2 + 6 N)`` columns of the actuator corrections (``act``; all -1 when there are none)."""
        return self.act if self.act is not None else np.full((len(self.bore), 2), -1, np.int64)

    @property
    def rpoint_cols(self) -> NDArray[np.int64]:
        """``(P, 3)`` reduced columns of the points (``rpoint``; all -1 when there are none)."""
        return self.rpoint if self.rpoint is not None else np.full((len(self.point), 3), -1, np.int64)

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
        if self.grid is not None and s.grid is not None:
            out.grid = s.grid + step(self.grid)
        for pg in parameter_groups():
            gcols = self.groups.get(pg.name)
            if gcols is not None and (gcols >= 0).any():
                out.groups[pg.name] = pg.retract(s.groups[pg.name], step(gcols))
        if self.n_p or self.has_rpoint:
            out.X = s.X.copy()
        if self.n_p:
            free = self.point >= 0
            out.X[free] += dp[self.point[free]]
        if self.has_rpoint:
            red = (self.rpoint_cols >= 0).all(axis=1)
            out.X[red] += step(self.rpoint_cols[red])
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
        b = block
        lay = self.layout
        # intrinsic columns per observation, padded
        mmax = max([len(c) for c in self.layout.intr] + [0])
        icols = np.full((len(b.cameras), mmax), -1, np.int64)
        for j, c in enumerate(self.layout.intr):
            icols[j, : len(c)] = c
        self._icols = icols
        self._intr_on = bool((icols >= 0).any())
        self._bore_on = bool((self.layout.bore >= 0).any())
        # actuated heads: images whose mounting is computed from beta
        heads = b.head_actuated or [None] * len(b.head_name)
        is_act = np.array([heads[h] is not None for h in b.image_head], bool) if b.n_images else np.zeros(0, bool)
        self._act_images = np.flatnonzero(is_act)
        self._act_width = 2 + 6 * int(config.unknowns.actuator_fourier_order)
        self._act_on = lay.act is not None and bool((lay.act >= 0).any())
        if self._act_images.size:
            from skyrig.rig.rig import NADIR_BODY_FROM_CAMERA

            hi = b.image_head[self._act_images]
            eye = np.eye(3)
            self._act_B = np.array([heads[h].body_from_head if heads[h] is not None else eye for h in hi])
            self._act_K = np.array([NADIR_BODY_FROM_CAMERA @ heads[h].boresight for h in hi])
            self._img2act = np.full(b.n_images, -1, np.int64)
            self._img2act[self._act_images] = np.arange(self._act_images.size)

        #: the registered observation types (:mod:`skyrig.adjust.factors`), in evaluation order
        self.types = [t for t in observation_types() if t.present(self)]
        #: per observation type the weight of each row (robust reweighting; 0 = rejected by data snooping
        #: or not used, e.g. a check point), keyed by group name
        self.weights: dict[str, NDArray[np.float64]] = {}
        for t in observation_types():
            w = t.initial_weight(block)
            if w is not None:
                self.weights[t.name] = w
        #: per observation type its per-model constants (whitening matrices, index tables...)
        self.cache: dict[str, Any] = {t.name: t.prepare(self) for t in self.types}

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
        t = observation_type(f.name)
        return np.ones(len(f), bool) if t is None else t.varying(self, f)

    def estimated_points(self) -> NDArray[np.bool_]:
        """``(P,)`` True for the points estimated in this model (eliminated or in the reduced part)."""
        lay = self.layout
        pt = lay.point >= 0
        if lay.rpoint is not None:
            pt = pt | (lay.rpoint >= 0).any(axis=1)
        return pt

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
        beta = b.image_beta_rad[ai]
        A = pad_actuator(s.act, len(b.head_name), self._act_width)[hi]
        bp = (1.0 + A[:, 1]) * beta + A[:, 0]
        a = np.zeros((ai.size, 3))
        da = np.zeros((ai.size, 3))
        h = 1e-6
        for k in np.unique(hi):
            sel = hi == k
            head = b.head_actuated[k]
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
        R, C = world_from_camera(s.R[st], s.C[st], M, b.image_offset)  # station = platform pose, M its mounting
        return R, C, M

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, s: State, jacobians: bool = True) -> list[Factor]:
        """All factors at state ``s`` (residuals only when ``jacobians`` is False): the rows of every
        observation type present, in the registry's order (the image factor first)."""
        out: list[Factor] = []
        for t in self.types:
            fs = t.evaluate(self, s, jacobians)
            if jacobians and t.name not in _BUILTIN_NAMES:
                _check_rows(t.name, fs)
            out.extend(fs)
        return out

    def _image(self, s: State, jac: bool) -> Factor:
        """The image factor alone (:class:`skyrig.adjust.factors.image.Image`)."""
        return image_type().evaluate_one(self, s, jac)


_BUILTIN_NAMES = frozenset(BUILTIN)  # the built-in types (their modules are named after them)


def _check_rows(name: str, factors: list[Factor]) -> None:
    """A row of a (non-built-in) observation type may touch reduced columns or one eliminated point, not both:
    the solver builds the point-camera coupling from the image rows only (use the reduced part for such
    points, as distances do, ``Layout.rpoint``)."""
    for f in factors:
        if f.point is None or f.cols is None or f.jc is None or not len(f):
            continue
        both = (f.point >= 0) & (f.cols >= 0).reshape(len(f), -1).any(axis=1)
        if both.any():
            raise ValueError(f"observation type {name!r}: row {int(np.flatnonzero(both)[0])} of factor {f.name!r} "
                             "touches both reduced columns and an eliminated point; only image rows may")


# ---------------------------------------------------------------------------------------------------
# Compiled path of Model._image for blocks whose cameras are all BAL cameras (same results as the numpy
# path; one pass over the observations instead of a dozen (n, 2, 3) temporaries), and the chain rule of
# the frame-camera path: module-level kernels in skyrig.adjust._image_kernels (so that numba's on-disk
# cache hits in every process); None without numba.
try:
    from skyrig.adjust._image_kernels import bal_rows as _BAL_KERNEL, chain as _CHAIN_KERNEL
except ImportError:  # pragma: no cover - depends on the environment
    _BAL_KERNEL = _CHAIN_KERNEL = None  # type: ignore[assignment]
