"""Rolling shutter (issue 28 item 3): the pose moves while a consumer-drone camera reads its rows out.

Model
-----
Row ``r`` (the measured pixel row, rows down, pixel centres at integers) of an image of ``rows`` rows is
exposed at ``t = (r - (rows - 1) / 2) * readout_s / rows`` seconds after the image's mid-exposure (its centre
row); the camera is then at ``C(t) = C + v t`` with ``world_from_camera(t) = expmap(w t) @ R``, so that the
camera-frame point is

    ``pc(t) = R^T expmap(-w t) (X - C - v t)``

with ``v`` the station's linear velocity (m/s, world frame) and ``w`` its angular velocity (rad/s, world
frame, the axis-angle rate).  The row time comes from the *measured* row (the standard first-order choice:
no iteration inside the adjustment; the projection's own row differs by the residual, a fraction of a pixel).

Unknowns (parameter groups declared here, :class:`~skyrig.adjust.factors.base.ParameterGroup`)
-----------------------------------------------------------------------------------------
* ``rs_motion``: ``(vx, vy, vz, wx, wy, wz)`` per station that holds an image of a rolling-shutter camera;
  starting values ``block.parameters["rs_motion"]`` (e.g. the GNSS trajectory's velocity), else zeros;
* ``rs_readout``: the readout time per rolling-shutter camera (s); starting value the data's ``readout_s``.

Both are ``"fixed"`` unless the configuration frees them (:func:`rolling_shutter_unknowns`).  The linear
velocity and the readout time only enter as their product ``v * readout``: the readout is determined through
a velocity prior (the GNSS trajectory's velocity) and its own prior (a camera's spec, e.g. 30 +- 20 ms).

Observations (the ``rolling_shutter`` type, data :class:`RollingShutter` in ``block.observations``)
-----------------------------------------------------------------------------------------------------
The data names the rolling-shutter cameras and carries the priors as observations with their own sigmas:
the readout time per camera (factor ``rolling_shutter:readout``), the linear velocity of stations
(``rolling_shutter:velocity``, from the GNSS trajectory) and a zero angular velocity with a loose sigma
(``rolling_shutter:angular``, a stabilised gimbal turns slowly).

Image rows
----------
The image observations of rolling-shutter cameras are evaluated here: this module registers
:class:`RollingShutterImage`, a subclass of the built-in image type under the same name ``"image"``, which
gives the built-in rows unchanged and, for the rows of rolling-shutter cameras, replaces the residual by the
projection at the row's pose and their Jacobians with respect to the station pose, the boresight, the
intrinsics and the point by those at the row's pose, with the columns of ``rs_motion`` and ``rs_readout``
appended.  (The derivatives with respect to actuator corrections and to reduced end points of distances stay
those of the mid-exposure pose, a relative error of ``|w t|``, under 1 % for a drone; the residuals are exact.)
Blocks without the ``rolling_shutter`` data are evaluated exactly as by the built-in type.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.factors import register, register_group
from skyrig.adjust.factors.base import (BalCamera, BlockError, Factor, ObservationType, ParameterGroup, check_finite,
                                        check_index, check_positive)
from skyrig.adjust.factors.image import Image, ImageCache
from skyrig.camera.jacobians import project_camera_with_jacobians
from skyrig.geometry.rotations import matrix_from_rotvec, skew

if TYPE_CHECKING:  # pragma: no cover
    from skyrig.adjust.block import Block
    from skyrig.adjust.config import Unknowns
    from skyrig.adjust.model import Model, State

__all__ = ["RollingShutter", "RollingShutterType", "RsMotion", "RsReadout", "RollingShutterImage",
           "rolling_shutter_unknowns", "row_time", "right_jacobian", "NAME", "MOTION", "READOUT"]

NAME = "rolling_shutter"
MOTION = "rs_motion"
READOUT = "rs_readout"


def row_time(row_px: NDArray[np.float64], rows: int, readout_s: NDArray[np.float64] | float) -> NDArray[np.float64]:
    """Exposure time (s) of pixel rows relative to the image's mid-exposure (its centre row ``(rows - 1) / 2``)."""
    return (np.asarray(row_px, float) - (rows - 1) / 2.0) / rows * readout_s


def right_jacobian(phi: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(n, 3, 3)`` right Jacobian of SO(3) at rotation vectors ``phi (n, 3)``:
    ``expmap(phi + d) ~ expmap(phi) expmap(Jr(phi) d)``."""
    phi = np.asarray(phi, float).reshape(-1, 3)
    th = np.linalg.norm(phi, axis=1)
    K = skew(phi)
    small = th < 1e-5
    ths = np.where(small, 1.0, th)
    a = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    b = np.where(small, 1.0 / 6.0 - th**2 / 120.0, (ths - np.sin(ths)) / ths**3)
    return np.eye(3)[None] - a[:, None, None] * K + b[:, None, None] * (K @ K)


@dataclass
class RollingShutter:
    """Which cameras read out row by row, and the priors of their readout time and of the stations' motion.

    Attributes
    ----------
    cameras
        ``(Q,)`` names of the rolling-shutter cameras (``block.cameras[...].name``).
    readout_s, readout_sigma_s
        ``(Q,)`` prior readout time (first row to last row, s) and its sigma (s) per camera (a scalar is
        broadcast); the prior value is also the starting value.
    velocity_station, velocity_m_s, velocity_sigma_m_s
        ``(K,)`` station indices, ``(K, 3)`` their linear velocity (m/s, world frame, e.g. from the GNSS
        trajectory) and its sigma ``(K, 3)`` (m/s); empty = no velocity prior.
    angular_sigma_rad_s
        sigma (rad/s) of a zero angular velocity per rolling-shutter station; None = no such prior.
    velocity_between, velocity_dt_s
        Optional ``(K, 2)`` stations ``(a, b)`` and ``(K,)`` time span (s) per velocity prior: where ``a >= 0``
        the prior is the velocity from the block's own centres, ``v_k = (C_b - C_a) / dt + velocity_m_s`` (the
        centres are unknowns: a block without GNSS, whose frame and scale the prior must not fix; it moves with
        the block under a similarity); ``-1``: the fixed ``velocity_m_s`` (e.g. from a GNSS trajectory).
    """

    cameras: Any
    readout_s: Any = 0.03
    readout_sigma_s: Any = 0.02
    velocity_station: Any = field(default_factory=lambda: np.zeros(0, np.int64))
    velocity_m_s: Any = field(default_factory=lambda: np.zeros((0, 3)))
    velocity_sigma_m_s: Any = field(default_factory=lambda: np.zeros((0, 3)))
    angular_sigma_rad_s: float | None = None
    velocity_between: Any = None
    velocity_dt_s: Any = None
    #: ``(n, 1)`` sigma of the prior rows (filled by :meth:`normalise`; not used by VCE)
    sigma: Any = None

    def __len__(self) -> int:
        return len(self.cameras) + len(self.velocity_station)

    def normalise(self, block: "Block") -> None:
        self.cameras = np.asarray([str(c) for c in np.atleast_1d(self.cameras)], dtype=object)
        q = len(self.cameras)
        self.readout_s = np.broadcast_to(np.asarray(self.readout_s, float), (q,)).copy()
        self.readout_sigma_s = np.broadcast_to(np.asarray(self.readout_sigma_s, float), (q,)).copy()
        self.velocity_station = np.asarray(self.velocity_station, np.int64).reshape(-1)
        k = len(self.velocity_station)
        self.velocity_m_s = np.asarray(self.velocity_m_s, float).reshape(k, 3)
        self.velocity_sigma_m_s = np.broadcast_to(np.asarray(self.velocity_sigma_m_s, float), (k, 3)).copy()
        if self.velocity_between is None:
            self.velocity_between = np.full((k, 2), -1, np.int64)
            self.velocity_dt_s = np.ones(k)
        self.velocity_between = np.asarray(self.velocity_between, np.int64).reshape(k, 2)
        self.velocity_dt_s = np.broadcast_to(np.asarray(1.0 if self.velocity_dt_s is None else self.velocity_dt_s,
                                                        float), (k,)).copy()
        self.sigma = np.ones((len(self), 1))

    def validate(self, block: "Block") -> None:
        names = [c.name for c in block.cameras]
        for j, c in enumerate(self.cameras):
            if c not in names:
                raise BlockError(f"observations['{NAME}'].cameras[{j}] = {c!r} is not a camera of the block "
                                 f"(have {names})")
            if isinstance(block.cameras[names.index(c)], BalCamera):
                raise BlockError(f"observations['{NAME}'].cameras[{j}] = {c!r} is a BAL camera: the rolling "
                                 "shutter model needs a frame camera (its image height)")
        if len(set(self.cameras)) != len(self.cameras):
            raise BlockError(f"observations['{NAME}'].cameras names a camera twice: {list(self.cameras)}")
        check_finite(f"observations['{NAME}'].readout_s", self.readout_s)
        check_positive(f"observations['{NAME}'].readout_sigma_s", self.readout_sigma_s)
        check_index(f"observations['{NAME}'].velocity_station", self.velocity_station, block.n_stations, "station")
        check_finite(f"observations['{NAME}'].velocity_m_s", self.velocity_m_s)
        check_positive(f"observations['{NAME}'].velocity_sigma_m_s", self.velocity_sigma_m_s)
        rel = self.velocity_between[:, 0] >= 0
        if rel.any():
            check_index(f"observations['{NAME}'].velocity_between", self.velocity_between[rel], block.n_stations,
                        "station")
            check_positive(f"observations['{NAME}'].velocity_dt_s", self.velocity_dt_s[rel])
            same = np.flatnonzero(self.velocity_between[rel, 0] == self.velocity_between[rel, 1])
            if len(same):
                raise BlockError(f"observations['{NAME}'].velocity_between: a velocity between station "
                                 f"{int(self.velocity_between[rel][same[0], 0])} and itself")
        a = self.angular_sigma_rad_s
        if a is not None and not (np.isfinite(a) and a > 0):
            raise BlockError(f"observations['{NAME}'].angular_sigma_rad_s must be > 0 (a standard deviation) or "
                             f"None, got {a!r}")

    def camera_index(self, block: "Block") -> NDArray[np.int64]:
        """``(Q,)`` block camera index of each rolling-shutter camera."""
        names = [c.name for c in block.cameras]
        return np.array([names.index(c) for c in self.cameras], np.int64)


def _data(block: Any) -> RollingShutter | None:
    return block.observations.get(NAME)


def _rs_stations(block: Any) -> NDArray[np.int64]:
    """Stations holding at least one image of a rolling-shutter camera (sorted)."""
    d = _data(block)
    if d is None or not len(d.cameras):
        return np.zeros(0, np.int64)
    return np.unique(block.image_station[np.isin(block.image_camera, d.camera_index(block))]).astype(np.int64)


class RsMotion(ParameterGroup):
    """Linear and angular velocity of each station that holds a rolling-shutter image."""

    name = MOTION
    components = ("vx_m_s", "vy_m_s", "vz_m_s", "wx_rad_s", "wy_rad_s", "wz_rad_s")
    words = "station velocity during the rolling shutter's readout"

    def owners(self, block: Any) -> list[str]:
        return [str(block.station_name[k]) for k in _rs_stations(block)]

    def estimated(self, block: Any) -> bool:
        return _data(block) is not None

    def similarity_motion(self, values: NDArray[np.float64]) -> NDArray[np.float64]:
        """Both velocities are world-frame vectors: a rotation ``e_a`` of the block turns them (``e_a x v``), a
        scale stretches the linear one (``v``), a translation leaves them."""
        m = np.zeros(values.shape + (7,))
        for a in range(3):
            m[:, :3, 3 + a] = np.cross(np.eye(3)[a], values[:, :3])
            m[:, 3:, 3 + a] = np.cross(np.eye(3)[a], values[:, 3:])
        m[:, :3, 6] = values[:, :3]
        return m


class RsReadout(ParameterGroup):
    """Readout time (first to last row) of each rolling-shutter camera."""

    name = READOUT
    components = ("readout_s",)
    words = "rolling-shutter readout time"

    def owners(self, block: Any) -> list[str]:
        d = _data(block)
        return [] if d is None else [str(c) for c in d.cameras]

    def initial(self, block: Any) -> NDArray[np.float64]:
        d = _data(block)
        if d is not None and block.parameters.get(self.name) is None:
            return np.asarray(d.readout_s, float).reshape(-1, 1).copy()
        return super().initial(block)

    def estimated(self, block: Any) -> bool:
        return _data(block) is not None


class RollingShutterType(ObservationType):
    """The priors of the rolling-shutter unknowns (readout time, linear velocity, zero angular velocity)."""

    name = NAME
    words = "rolling-shutter prior"
    components = ("value",)
    units = "s, m/s, rad/s"
    order = 48.0
    snooped = False
    share_checked = False

    def count(self, block: "Block") -> int:
        d = _data(block)
        if d is None:
            return 0
        ang = len(_rs_stations(block)) if d.angular_sigma_rad_s is not None else 0
        return len(d.cameras) + len(d.velocity_station) + ang

    def evaluate(self, model: "Model", s: "State", jac: bool) -> list[Factor]:
        b, lay = model.block, model.layout
        d = _data(b)
        assert d is not None
        out = []
        q = len(d.cameras)
        # readout time: one row per camera
        sig = d.readout_sigma_s[:, None]
        f = Factor(f"{NAME}:readout", (s.groups[READOUT][:, :1] - d.readout_s[:, None]) / sig, sig,
                   weight=np.ones(q))
        if jac:
            f.cols = lay.groups[READOUT][:, :1].copy()
            f.jc = (1.0 / sig)[:, :, None]
        out.append(f)
        slot = np.full(b.n_stations, -1, np.int64)
        rs = _rs_stations(b)
        slot[rs] = np.arange(len(rs))
        if len(d.velocity_station):
            sl = slot[d.velocity_station]
            if (sl < 0).any():
                bad = int(d.velocity_station[np.flatnonzero(sl < 0)[0]])
                raise BlockError(f"observations['{NAME}'].velocity_station names station "
                                 f"{b.station_name[bad]!r}, which holds no rolling-shutter image")
            fixed, rel = _velocity_rows(d)
            if len(fixed):
                sg = d.velocity_sigma_m_s[fixed]
                f = Factor(f"{NAME}:velocity", (s.groups[MOTION][sl[fixed], :3] - d.velocity_m_s[fixed]) / sg, sg,
                           weight=np.ones(len(fixed)))
                if jac:
                    f.cols = lay.groups[MOTION][sl[fixed], :3].copy()
                    f.jc = np.zeros((len(fixed), 3, 3))
                    f.jc[:, [0, 1, 2], [0, 1, 2]] = 1.0 / sg
                out.append(f)
            if len(rel):
                out.append(_relative_velocity_factor(d, rel, sl, s, lay, jac))
        if d.angular_sigma_rad_s is not None and len(rs):
            sg = np.full((len(rs), 3), float(d.angular_sigma_rad_s))
            f = Factor(f"{NAME}:angular", s.groups[MOTION][:, 3:] / sg, sg,
                       weight=np.ones(len(rs)))
            if jac:
                f.cols = lay.groups[MOTION][:, 3:].copy()
                f.jc = np.zeros((len(rs), 3, 3))
                f.jc[:, [0, 1, 2], [0, 1, 2]] = 1.0 / sg
            out.append(f)
        return out

    def initial_weight(self, block: "Block") -> None:
        return None  # priors: no weights, not snooped

    def get_sigma(self, block: "Block") -> NDArray[np.float64]:
        return np.ones((self.count(block), 1))

    def set_sigma(self, block: "Block", value: NDArray[np.float64]) -> None:
        pass  # not estimated by variance components (vce_split None)

    def varying(self, model: "Model", factor: Factor) -> NDArray[np.bool_]:
        return np.asarray((factor.cols >= 0).any(axis=1), bool) if factor.cols is not None else np.zeros(len(factor),
                                                                                                          bool)

    def label(self, block: "Block", i: int) -> str:
        d = _data(block)
        assert d is not None  # (internal: only rows of the block's own rolling-shutter data are labelled)
        q, k = len(d.cameras), len(d.velocity_station)
        if i < q:
            return f"readout time prior of camera {d.cameras[i]}"
        if i < q + k:
            j = int(np.concatenate(_velocity_rows(d))[i - q])  # the factors' row order: fixed, then relative
            return f"velocity prior of station {block.station_name[d.velocity_station[j]]}"
        return f"angular velocity prior of station {block.station_name[_rs_stations(block)[i - q - k]]}"


def _velocity_rows(d: RollingShutter) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Rows of the velocity priors on a fixed velocity and on the block's own centres."""
    rel = d.velocity_between[:, 0] >= 0
    return np.flatnonzero(~rel), np.flatnonzero(rel)


def _relative_velocity_factor(d: RollingShutter, rel: NDArray[np.int64], sl: NDArray[np.int64], s: "State",
                              lay: Any, jac: bool) -> Factor:
    """``(v_k - (C_b - C_a) / dt - velocity_m_s) / sigma`` of the rows ``rel``; columns: the velocity, ``C_a``,
    ``C_b``."""
    a, bb = d.velocity_between[rel, 0], d.velocity_between[rel, 1]
    dt = d.velocity_dt_s[rel][:, None]
    sg = d.velocity_sigma_m_s[rel]
    v = s.groups[MOTION][sl[rel], :3]
    r = (v - (s.C[bb] - s.C[a]) / dt - d.velocity_m_s[rel]) / sg
    f = Factor(f"{NAME}:velocity_from_centres", r, sg, weight=np.ones(len(rel)))
    if jac:
        f.cols = np.concatenate([lay.groups[MOTION][sl[rel], :3], lay.pose[a, :3], lay.pose[bb, :3]], axis=1)
        f.jc = np.zeros((len(rel), 3, 9))
        i3 = [0, 1, 2]
        f.jc[:, i3, i3] = 1.0 / sg
        f.jc[:, i3, [3, 4, 5]] = 1.0 / (dt * sg)
        f.jc[:, i3, [6, 7, 8]] = -1.0 / (dt * sg)
    return f


@dataclass
class RollingShutterCache(ImageCache):
    """The built-in image cache plus the rolling-shutter rows: ``rs_rows (n,)``, their time factor ``u (n,)``
    (``t = u * readout``), camera slot ``rs_cam (n,)`` in ``rs_readout`` and station slot ``rs_st (n,)`` in
    ``rs_motion``; ``rs_cols`` the appended columns of every image row ``(N, 7)`` (-1: none)."""

    rs_rows: NDArray[np.int64] | None = None
    rs_u: NDArray[np.float64] | None = None
    rs_cam: NDArray[np.int64] | None = None
    rs_st: NDArray[np.int64] | None = None
    rs_cols: NDArray[np.int64] | None = None
    rs_on: bool = False
    rs_all_cols: NDArray[np.int64] | None = None


class RollingShutterImage(Image):
    """The image observation type, with the rows of rolling-shutter cameras projected at their row's pose."""

    def prepare(self, model: "Model") -> ImageCache:
        ic = super().prepare(model)
        b, lay = model.block, model.layout
        d = _data(b)
        if d is None or not len(d.cameras):
            return ic
        cam_idx = d.camera_index(b)
        cam_slot = np.full(len(b.cameras), -1, np.int64)
        cam_slot[cam_idx] = np.arange(len(cam_idx))
        st_slot = np.full(b.n_stations, -1, np.int64)
        rs = _rs_stations(b)
        st_slot[rs] = np.arange(len(rs))
        oc = b.image_camera[b.obs_image]
        rows = np.flatnonzero(cam_slot[oc] >= 0)
        heights = np.array([getattr(c, "height", 0) for c in b.cameras], float)
        h = heights[oc[rows]]
        u = (b.obs_pixel[rows, 1] - (h - 1) / 2.0) / h
        cols = np.full((b.n_observations, 7), -1, np.int64)
        mc, rc = lay.groups[MOTION], lay.groups[READOUT]
        st = st_slot[b.image_station[b.obs_image[rows]]]
        cols[rows, :6] = mc[st]
        cols[rows, 6] = rc[cam_slot[oc[rows]], 0]
        kw = {f: getattr(ic, f) for f in ImageCache.__dataclass_fields__}
        return RollingShutterCache(**kw, rs_rows=rows, rs_u=u, rs_cam=cam_slot[oc[rows]], rs_st=st,
                                   rs_cols=cols, rs_on=bool((cols >= 0).any()))

    def evaluate_one(self, model: "Model", s: "State", jac: bool) -> Factor:
        f = super().evaluate_one(model, s, jac)
        ic = model.cache[self.name]
        if not isinstance(ic, RollingShutterCache) or ic.rs_rows is None or not ic.rs_rows.size:
            return f
        return self._rolling(model, s, jac, ic, f)

    def _rolling(self, model: "Model", s: "State", jac: bool, ic: RollingShutterCache, f: Factor) -> Factor:
        b, lay = model.block, model.layout
        rows = ic.rs_rows
        assert rows is not None and ic.rs_u is not None and ic.rs_cam is not None and ic.rs_st is not None
        n = len(rows)
        Rc, Cc, M = model.camera_poses(s)
        oi = b.obs_image[rows]
        t = ic.rs_u * s.groups[READOUT][ic.rs_cam, 0]
        mot = s.groups[MOTION][ic.rs_st]
        v, w = mot[:, :3], mot[:, 3:]
        E = matrix_from_rotvec(w * t[:, None])  # world_from_camera(t) = E @ Rc
        A = E @ Rc[oi]
        Yp = s.X[b.obs_point[rows]] - Cc[oi] - v * t[:, None]
        pc_rs = np.einsum("nji,nj->ni", A, Yp)
        pc_0 = np.einsum("nji,nj->ni", Rc[oi], s.X[b.obs_point[rows]] - Cc[oi])
        cams = model.cameras(s)
        oc = b.image_camera[oi]
        pred_rs, pred_0 = np.empty((n, 2)), np.empty((n, 2))
        D = np.empty((n, 2, 3))
        mmax = model._icols.shape[1]
        d_in = np.zeros((n, 2, mmax)) if (jac and model._intr_on) else None
        for c in np.unique(oc):
            k = np.flatnonzero(oc == c)
            px, dpc, din = project_camera_with_jacobians(cams[c], pc_rs[k])
            pred_rs[k], D[k] = px, dpc
            if d_in is not None:
                d_in[k, :, :din.shape[2]] = din
            pred_0[k] = project_camera_with_jacobians(cams[c], pc_0[k])[0]
        Wm = ic.W

        def whiten(J: NDArray[np.float64]) -> NDArray[np.float64]:
            if Wm is None:
                return J / b.obs_sigma_px[rows][:, :, None]
            return Wm[rows] @ J

        dr = whiten((pred_rs - pred_0)[:, :, None])[:, :, 0]
        ok = np.asarray(np.isfinite(dr).all(axis=1), dtype=bool)
        if f.bad is not None:
            ok &= ~f.bad[rows]
        f.r[rows[ok]] += dr[ok]
        if f.bad is not None:
            f.bad[rows[~ok]] = True
            f.r[rows[~ok]] = 0.0
        if not jac:
            return f
        Dw = whiten(D)
        Dw[~ok] = 0.0
        jX = Dw @ np.swapaxes(A, 1, 2)  # d / d point
        pose_on = bool((lay.pose >= 0).any())
        o = 0
        if f.jc is not None:
            jc = f.jc
            if pose_on:
                jth = Dw @ skew(pc_rs) @ np.swapaxes(M[oi], 1, 2)
                off = b.image_offset[oi]
                if np.any(off):
                    jth = jth + jX @ (s.R[b.image_station[oi]] @ skew(off))
                jc[rows, :, 0:3] = -jX
                jc[rows, :, 3:6] = jth
                o = 6
            if model._bore_on:
                jc[rows, :, o:o + 3] = Dw @ skew(pc_rs)
                o += 3
            if d_in is not None:
                jc[rows, :, o:o + mmax] = whiten(d_in) * ok[:, None, None]
        if f.jp is not None:
            f.jp[rows] = jX
        if not ic.rs_on:
            return f
        # the appended columns: d / d v, d / d w, d / d readout
        jr = np.zeros((b.n_observations, 2, 7))
        jr[rows, :, 0:3] = -t[:, None, None] * jX
        Jr = right_jacobian(-w * t[:, None])
        jr[rows, :, 3:6] = t[:, None, None] * (jX @ skew(Yp) @ Jr)
        jr[rows, :, 6] = ic.rs_u[:, None] * np.einsum("nij,nj->ni", jX, np.cross(Yp, w) - v)
        if f.jc is None:
            f.jc, f.cols = jr, ic.rs_cols
        else:
            f.jc = np.concatenate([f.jc, jr], axis=2)
            if ic.rs_all_cols is None:  # the columns depend on the layout only
                ic.rs_all_cols = np.concatenate([f.cols, ic.rs_cols], axis=1)
            f.cols = ic.rs_all_cols
        return f


def rolling_shutter_unknowns(unknowns: "Unknowns", motion: str = "free", readout: str = "free") -> "Unknowns":
    """``unknowns`` with the rolling-shutter groups' modes set (their priors are the ``rolling_shutter``
    observations, so ``"free"`` is the usual choice; ``"fixed"`` keeps them at their starting values)."""
    from dataclasses import replace

    groups: tuple[Any, ...] = tuple((n, m) for n, m in unknowns.groups if n not in (MOTION, READOUT))
    return replace(unknowns, groups=groups + ((MOTION, motion), (READOUT, readout)))


register(RollingShutterType())
register(RollingShutterImage(), replace=True)
register_group(RsMotion())
register_group(RsReadout())
