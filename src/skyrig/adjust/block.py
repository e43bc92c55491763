"""The data of a bundle block: observations, parameters and how each parameter group is treated.

Frames
------
Everything in a :class:`Block` is in **one Cartesian world frame** (normally the tangential / local
ENU frame of the block, :meth:`skyrig.georef.WorldFrame.local`; see ``docs/frames.md``), metres and
radians.  Map inputs are transformed into it before the adjustment and results back afterwards
(:mod:`skyrig.adjust.frames`).

Stations, images and heads
--------------------------
A *station* carries one pose unknown ``world_from_station = (R, C)``: a single image, or one platform
exposure of a rig (station = IMU body).  Each image belongs to a station and has a fixed
``station_from_camera`` rotation and offset (identity and zero for a single camera; the head's
``body_from_camera`` for a rig, possibly per image for an actuated head), and a *head* index whose
small boresight correction ``b`` (a rotation vector, camera frame) may be estimated::

    world_from_camera = R_station @ station_from_camera @ expmap(b_head)
    C_camera          = C_station + R_station @ offset

GNSS antenna positions observe ``C_station + R_station @ lever_arm + datum_shift + strip_shift[s]
+ strip_drift[s] * (t - t0[s])``; IMU attitudes observe ``R_station``.

Observation groups
------------------
A :class:`Block` is the geometry (stations, images, heads, cameras, points and the calibration values)
plus observation groups.  Each group belongs to one observation type of :mod:`skyrig.adjust.factors`
(one module each: image, control, GNSS, IMU, distance, ...), which normalises, checks, evaluates and
labels its rows; the block only loops over the registered types.  Every type keeps its rows in
``observations[name]``, an object of the type's own data class (``ImageRows``, ``GnssRows``... for the
built-in ones); the block's flat keywords and attributes of the built-in types (``obs_*``, ``control_*``,
``gnss_*``, ``imu_*``, ``distance_*``: the public API) read and write those rows.

Parameter groups
----------------
Each group of :class:`AdjustConfig` (its part :class:`~skyrig.adjust.config.Unknowns`) is ``"fixed"``,
``"free"`` or ``"weighted"`` (free with a prior equal to the starting value and the sigma given in the
config); solver, data snooping and statistics options are the config's other parts
(:mod:`skyrig.adjust.config`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, ClassVar, Generic, Sequence, TypeVar, overload

import numpy as np
from numpy.typing import NDArray

from skyrig.adjust.config import MODES, AdjustConfig, Mode
from skyrig.adjust.factors import image_type, observation_types, require_type
from skyrig.adjust.factors.base import BalCamera, BlockError, check_finite, check_index
from skyrig.camera.frame import FrameCamera
from skyrig.geodesy.frame import WorldFrame


__all__ = ["BalCamera", "Block", "BlockFrame", "Stations", "Images", "Heads", "Points", "Systematics", "AdjustConfig", "Mode", "MODES", "BlockError"]  # AdjustConfig: skyrig.adjust.config


CameraModel = FrameCamera | BalCamera
T = TypeVar("T")


def _arr(x: Any, shape_tail: tuple[int, ...], dtype: Any = np.float64, n: int | None = None) -> NDArray:
    a = np.asarray(x, dtype=dtype)
    if n is None:
        n = a.shape[0] if a.ndim else 0
    return a.reshape((n,) + tuple(shape_tail))


@dataclass
class Stations:
    """The pose unknowns: ``name (S,)``, ``rotation (S, 3, 3)`` ``world_from_station``, ``centre (S, 3)`` m,
    ``time (S,)`` s (for strip drift) and ``strip (S,)`` strip index (-1: none)."""

    name: NDArray[np.str_]
    rotation: NDArray[np.float64]
    centre: NDArray[np.float64]
    time: NDArray[np.float64]
    strip: NDArray[np.int64]


@dataclass
class Images:
    """The exposures: ``name (I,)``, indices ``station``, ``camera``, ``head`` ``(I,)``, ``rotation (I, 3, 3)``
    ``station_from_camera``, ``offset (I, 3)`` m in the station frame, ``beta_rad (I,)`` actuator angle (NaN
    for images of fixed heads)."""

    name: NDArray[np.str_]
    station: NDArray[np.int64]
    camera: NDArray[np.int64]
    head: NDArray[np.int64]
    rotation: NDArray[np.float64]
    offset: NDArray[np.float64]
    beta_rad: NDArray[np.float64]


@dataclass
class Heads:
    """Boresight-correction groups: ``name (H,)``, ``boresight (H, 3)`` rad, ``actuated`` (an
    :class:`~skyrig.rig.rig.ActuatedHead` or None per head) and ``actuator_correction (H, 2 + 6 N)``."""

    name: NDArray[np.str_]
    boresight: NDArray[np.float64]
    actuated: list[Any]
    actuator_correction: NDArray[np.float64]


@dataclass
class Points:
    """Object points: ``name (P,)``, ``xyz (P, 3)`` m (starting values)."""

    name: NDArray[np.str_]
    xyz: NDArray[np.float64]


@dataclass
class Systematics:
    """The GNSS systematic unknowns: ``lever_arm (3,)`` m in the station frame, ``datum_shift (3,)`` m,
    ``strip_shift (T, 3)`` m and ``strip_drift (T, 3)`` m/s per strip, ``strip_t0 (T,)`` s."""

    lever_arm: NDArray[np.float64]
    datum_shift: NDArray[np.float64]
    strip_shift: NDArray[np.float64]
    strip_drift: NDArray[np.float64]
    strip_t0: NDArray[np.float64]


@dataclass(frozen=True)
class BlockFrame:
    """The block's one Cartesian world frame: its words (``text``: reports, files; ``str(frame)``) and, when the
    block was built in a frame skyrig knows, that :class:`~skyrig.geodesy.frame.WorldFrame` (``world``).

    A block takes a ``BlockFrame``, a ``WorldFrame`` (text: its :meth:`~WorldFrame.describe`) or a text (a
    description skyrig may read back with :meth:`world_frame`, or free words such as "COLMAP model frame")."""

    text: str
    world: WorldFrame | None = None

    @classmethod
    def of(cls, frame: "BlockFrame | WorldFrame | str") -> "BlockFrame":
        if isinstance(frame, BlockFrame):
            return frame
        if isinstance(frame, WorldFrame):
            return cls(frame.describe(), frame)
        return cls(str(frame))

    def __str__(self) -> str:
        return self.text

    def world_frame(self) -> WorldFrame | None:
        """``world`` when given, else the frame read from ``text`` (None for free words)."""
        if self.world is not None:
            return self.world
        from skyrig.errors import CRSError

        try:
            return WorldFrame.from_text(self.text or "")
        except (CRSError, ValueError):
            return None


#: ``part -> (class, {Block keyword: attribute})``: where each flat keyword of the block lives
_PARTS: dict[str, tuple[type, dict[str, str]]] = {
    "stations": (Stations, {"station_name": "name", "station_rotation": "rotation", "station_centre": "centre",
                            "station_time": "time", "station_strip": "strip"}),
    "images": (Images, {"image_name": "name", "image_station": "station", "image_camera": "camera",
                        "image_head": "head", "image_rotation": "rotation", "image_offset": "offset",
                        "image_beta_rad": "beta_rad"}),
    "heads": (Heads, {"head_name": "name", "head_boresight": "boresight", "head_actuated": "actuated",
                      "actuator_correction": "actuator_correction"}),
    "points": (Points, {"point_name": "name", "point_xyz": "xyz"}),
    "systematics": (Systematics, {"lever_arm": "lever_arm", "datum_shift": "datum_shift",
                                  "strip_shift": "strip_shift", "strip_drift": "strip_drift", "strip_t0": "strip_t0"}),
}
_REQUIRED = ("station_name", "station_rotation", "station_centre", "image_name", "image_station", "image_camera",
             "point_name", "point_xyz")


class _In(Generic[T]):
    """A flat name of the block (``station_centre``, ``gnss_sigma``...): the attribute of one of its parts, or
    of one observation type's rows (``block.observations[type]``), read and written there."""

    def __init__(self, part: str, attr: str, rows: bool = False) -> None:
        self.part, self.attr, self.rows = part, attr, rows

    def _holder(self, obj: Any) -> Any:
        return obj.observations[self.part] if self.rows else getattr(obj, self.part)

    @overload
    def __get__(self, obj: None, owner: type) -> "_In[T]": ...

    @overload
    def __get__(self, obj: object, owner: type) -> T: ...

    def __get__(self, obj: Any, owner: Any = None) -> Any:
        if obj is None:
            return self
        return getattr(self._holder(obj), self.attr)

    def __set__(self, obj: Any, value: T) -> None:
        setattr(self._holder(obj), self.attr, value)


def _copied(v: Any) -> Any:
    return v.copy() if isinstance(v, np.ndarray) else (list(v) if isinstance(v, list) else v)


class Block:
    """Observations and parameter values of a bundle block (all in one Cartesian world frame).

    The block is its parts: ``cameras`` (camera models, images refer to them by index), ``stations``
    (:class:`Stations`), ``images`` (:class:`Images`), ``heads`` (:class:`Heads`), ``points``
    (:class:`Points`), ``systematics`` (:class:`Systematics`), ``observations`` (the rows of each
    observation type by group name: the built-in types' data classes ``ImageRows``, ``ControlRows``,
    ``GnssRows``, ``ImuRows``, ``DistanceRows`` of :mod:`skyrig.adjust.factors` and any registered type's
    own), ``parameters`` and ``frame``.  It is built from the parts or from the flat keywords below (each
    routed to its part; ``dataclasses.replace(block, station_centre=...)`` works alike), and the flat names
    are attributes reading and writing the parts.

    Flat keywords
    -------------
    station_name, station_rotation, station_centre
        ``(S,)``, ``(S, 3, 3)`` ``world_from_station``, ``(S, 3)`` metres: pose unknowns.
    station_time
        ``(S,)`` seconds (for strip drift), default zeros.
    station_strip
        ``(S,)`` strip index per station (-1: none), for per-strip GNSS shift and drift.
    image_name, image_station, image_camera, image_head
        ``(I,)`` names and indices into stations, cameras and heads.
    image_rotation, image_offset
        ``(I, 3, 3)`` ``station_from_camera`` and ``(I, 3)`` camera offset in the station frame (m).
    head_name
        ``(H,)`` names of heads (boresight-correction groups).
    point_name, point_xyz
        ``(P,)``, ``(P, 3)`` object points (starting values), metres.
    obs_image, obs_point, obs_pixel, obs_sigma_px
        Image measurements ``(N,)``, ``(N,)``, ``(N, 2)`` (column, row) px, ``(N, 2)`` px.
    control_point, control_xyz, control_sigma, control_check
        Ground coordinates of control points ``(K,)``, ``(K, 3)``, ``(K, 3)`` metres per axis, and
        ``(K,)`` bool: True for a *check* point (not used in the adjustment, compared afterwards).
    gnss_station, gnss_xyz, gnss_sigma
        GNSS antenna positions ``(G,)``, ``(G, 3)``, ``(G, 3)`` metres.
    imu_station, imu_rotation, imu_sigma_rad
        IMU attitudes ``world_from_station`` ``(M,)``, ``(M, 3, 3)``, ``(M, 3)`` rad (about the station axes).
    lever_arm
        ``(3,)`` GNSS antenna in the station frame, metres.
    head_boresight
        ``(H, 3)`` boresight corrections (rotation vectors, camera frame), rad.
    datum_shift, strip_shift, strip_drift
        ``(3,)`` GNSS datum shift, ``(T, 3)`` per-strip shifts (m), ``(T, 3)`` drifts (m/s).
    strip_t0
        ``(T,)`` reference time of each strip's drift (s).
    frame
        The world frame (:class:`BlockFrame`; given as one, as a ``WorldFrame`` or as its description).
    obs_cov_px2, control_cov_m2, gnss_cov_m2, imu_cov_rad2
        Optional full covariance per observation: ``(N, 2, 2)`` px² (column, row), ``(K, 3, 3)`` and
        ``(G, 3, 3)`` m² (X, Y, Z), ``(M, 3, 3)`` rad² of the IMU attitude error as a rotation vector
        about the station axes (x, y, z; the same components as ``imu_sigma_rad``: ``R_imu^T R_station
        = expmap(e)``).  When given it replaces the per-axis sigma of that group (which is then set to
        ``sqrt(diag)`` for reports); the model whitens each row with the Cholesky factor of the inverse
        covariance (:mod:`skyrig.adjust.model`).
    distance_point, distance_m, distance_sigma_m
        Distance observations (scale bars): ``(D, 2)`` point indices, ``(D,)`` observed distances and
        ``(D,)`` sigma (m).  Their end points are estimated in the reduced part of the unknowns.
    image_beta_rad
        ``(I,)`` actuator angle beta of each exposure (radians; NaN for images of fixed heads).
    head_actuated
        ``(H,)`` :class:`~skyrig.rig.rig.ActuatedHead` of each actuated head, None for fixed heads.
        The mounting ``station_from_camera`` of an image of an actuated head is computed from its
        beta (``image_rotation`` is then only the nominal value, for reports)::

            beta' = (1 + scale) beta + offset
            a     = tilt_angles(beta') + sum_n c_n cos(n beta') + s_n sin(n beta')   (roll, pitch, yaw)
            station_from_camera = body_from_head @ Rz(a_yaw) Ry(a_pitch) Rx(a_roll) @ NADIR @ boresight

        (paper 000 eqs 1-2, :meth:`ActuatedHead.tilt_angles` with its calibrated curve), followed by the
        head's boresight correction ``expmap(head_boresight)`` like any head.
    observations
        Rows of the observation types, ``{group name: data object}`` (the data object is the type's own,
        see :class:`~skyrig.adjust.factors.base.ObservationType`); a name no registered type owns is a
        :class:`BlockError`.  A block built from its parts (``dataclasses.replace``) takes every type's rows
        from here: to add a type's rows pass ``{**block.observations, name: rows}``.
    parameters
        Values ``(n_owners, n_components)`` of the parameter groups that factor modules declare, by group
        name (:class:`~skyrig.adjust.factors.base.ParameterGroup`): starting values here, adjusted values in
        the result's block; a group absent here starts at zero.
    actuator_correction
        ``(H, 2 + 6 N)`` correction of each actuated head: ``[offset_rad, scale]`` then, for ``n = 1..N``,
        the Fourier coefficients ``[c_roll, c_pitch, c_yaw, s_roll, s_pitch, s_yaw]`` (rad); default zeros.
    """

    #: a data class at run time (``dataclass(init=False)`` below: fields, repr, ``dataclasses.replace``); to the
    #: type checker a class with its own ``__init__``, so ``replace(block, station_centre=...)`` with the flat
    #: keywords checks as it did before the parts
    __dataclass_fields__: ClassVar[dict[str, Any]]
    cameras: list[Any]
    stations: Stations
    images: Images
    heads: Heads
    points: Points
    systematics: Systematics
    observations: dict[str, Any]
    parameters: dict[str, NDArray[np.float64]]
    frame: BlockFrame

    station_name = _In[NDArray[np.str_]]("stations", "name")
    station_rotation = _In[NDArray[np.float64]]("stations", "rotation")
    station_centre = _In[NDArray[np.float64]]("stations", "centre")
    station_time = _In[NDArray[np.float64]]("stations", "time")
    station_strip = _In[NDArray[np.int64]]("stations", "strip")
    image_name = _In[NDArray[np.str_]]("images", "name")
    image_station = _In[NDArray[np.int64]]("images", "station")
    image_camera = _In[NDArray[np.int64]]("images", "camera")
    image_head = _In[NDArray[np.int64]]("images", "head")
    image_rotation = _In[NDArray[np.float64]]("images", "rotation")
    image_offset = _In[NDArray[np.float64]]("images", "offset")
    image_beta_rad = _In[NDArray[np.float64]]("images", "beta_rad")
    head_name = _In[NDArray[np.str_]]("heads", "name")
    head_boresight = _In[NDArray[np.float64]]("heads", "boresight")
    head_actuated = _In[list[Any]]("heads", "actuated")
    actuator_correction = _In[NDArray[np.float64]]("heads", "actuator_correction")
    point_name = _In[NDArray[np.str_]]("points", "name")
    point_xyz = _In[NDArray[np.float64]]("points", "xyz")
    lever_arm = _In[NDArray[np.float64]]("systematics", "lever_arm")
    datum_shift = _In[NDArray[np.float64]]("systematics", "datum_shift")
    strip_shift = _In[NDArray[np.float64]]("systematics", "strip_shift")
    strip_drift = _In[NDArray[np.float64]]("systematics", "strip_drift")
    strip_t0 = _In[NDArray[np.float64]]("systematics", "strip_t0")
    obs_image = _In[NDArray[np.int64]]("image", "image", rows=True)
    obs_point = _In[NDArray[np.int64]]("image", "point", rows=True)
    obs_pixel = _In[NDArray[np.float64]]("image", "pixel", rows=True)
    obs_sigma_px = _In[NDArray[np.float64]]("image", "sigma_px", rows=True)
    obs_cov_px2 = _In[NDArray[np.float64] | None]("image", "cov_px2", rows=True)
    control_point = _In[NDArray[np.int64]]("control", "point", rows=True)
    control_xyz = _In[NDArray[np.float64]]("control", "xyz", rows=True)
    control_sigma = _In[NDArray[np.float64]]("control", "sigma", rows=True)
    control_check = _In[NDArray[np.bool_]]("control", "check", rows=True)
    control_cov_m2 = _In[NDArray[np.float64] | None]("control", "cov_m2", rows=True)
    gnss_station = _In[NDArray[np.int64]]("gnss", "station", rows=True)
    gnss_xyz = _In[NDArray[np.float64]]("gnss", "xyz", rows=True)
    gnss_sigma = _In[NDArray[np.float64]]("gnss", "sigma", rows=True)
    gnss_cov_m2 = _In[NDArray[np.float64] | None]("gnss", "cov_m2", rows=True)
    imu_station = _In[NDArray[np.int64]]("imu", "station", rows=True)
    imu_rotation = _In[NDArray[np.float64]]("imu", "rotation", rows=True)
    imu_sigma_rad = _In[NDArray[np.float64]]("imu", "sigma_rad", rows=True)
    imu_cov_rad2 = _In[NDArray[np.float64] | None]("imu", "cov_rad2", rows=True)
    distance_point = _In[NDArray[np.int64]]("distance", "point", rows=True)
    distance_m = _In[NDArray[np.float64]]("distance", "m", rows=True)
    distance_sigma_m = _In[NDArray[np.float64]]("distance", "sigma_m", rows=True)

    def __init__(self, cameras: list[Any], stations: Stations | None = None, images: Images | None = None,
                 heads: Heads | None = None, points: Points | None = None, systematics: Systematics | None = None,
                 observations: dict[str, Any] | None = None, parameters: dict[str, Any] | None = None,
                 frame: BlockFrame | WorldFrame | str = "local Cartesian frame", **flat: Any) -> None:
        given: dict[str, Any] = dict(stations=stations, images=images, heads=heads, points=points,
                                     systematics=systematics)
        self.cameras = cameras
        for pname, (cls, names) in _PARTS.items():
            part = given[pname]
            vals: dict[str, Any] = {}
            for kw, attr in names.items():
                if kw in flat:
                    vals[attr] = flat.pop(kw)
                elif part is not None:
                    vals[attr] = getattr(part, attr)
                elif kw in _REQUIRED:
                    raise TypeError(f"Block() missing required argument {kw!r}")
                else:
                    vals[attr] = np.zeros(3) if kw in ("lever_arm", "datum_shift") else None
            setattr(self, pname, cls(**vals))  # a new part: the given one is never written to
        self.observations = dict(observations or {})
        unknown = sorted(set(self.observations) - {t.name for t in observation_types()})
        if unknown:
            raise BlockError(f"observations holds unknown observation type(s) {unknown}: register them "
                             "(skyrig.adjust.factors.register) before building the block")
        from_parts = any(p is not None for p in given.values())
        for ot in observation_types():
            if ot.rows is None:
                continue
            rows = self.observations.get(ot.name)
            if rows is None and from_parts and not any(kw in flat for kw, _, _ in ot.keywords):
                raise BlockError(f"observations lacks the rows of the built-in type {ot.name!r}: a block built from "
                                 "its parts takes every type's rows from observations (pass "
                                 "{**block.observations, name: rows} to add a type's rows)")
            self.observations[ot.name] = ot.rows_from(rows, flat)
        if flat:
            raise TypeError(f"Block() got unexpected keyword argument(s) {sorted(flat)}")
        self.parameters = dict(parameters or {})
        self.frame = BlockFrame.of(frame)
        self.__post_init__()

    def __post_init__(self) -> None:
        """Bring every part and each type's rows to canonical arrays (at construction; again after fields were set)."""
        self.station_name = np.asarray(self.station_name, dtype=str).reshape(-1)
        s = len(self.station_name)
        self.station_rotation = _arr(self.station_rotation, (3, 3), n=s)
        self.station_centre = _arr(self.station_centre, (3,), n=s)
        self.image_name = np.asarray(self.image_name, dtype=str).reshape(-1)
        i = len(self.image_name)
        self.image_station = _arr(self.image_station, (), np.int64, i)
        self.image_camera = _arr(self.image_camera, (), np.int64, i)
        self.image_rotation = (np.broadcast_to(np.eye(3), (i, 3, 3)).copy() if self.image_rotation is None
                               else _arr(self.image_rotation, (3, 3), n=i))
        self.image_offset = np.zeros((i, 3)) if self.image_offset is None else _arr(self.image_offset, (3,), n=i)
        self.image_head = np.zeros(i, np.int64) if self.image_head is None else _arr(self.image_head, (), np.int64, i)
        nh = int(self.image_head.max()) + 1 if i else 1
        if self.head_name is None:
            self.head_name = np.array([f"head{k}" for k in range(nh)])
        self.head_name = np.asarray(self.head_name, dtype=str).reshape(-1)
        h = len(self.head_name)
        self.head_boresight = np.zeros((h, 3)) if self.head_boresight is None else _arr(self.head_boresight, (3,), n=h)
        self.station_time = np.zeros(s) if self.station_time is None else _arr(self.station_time, (), n=s)
        self.station_strip = (np.full(s, -1, np.int64) if self.station_strip is None
                              else _arr(self.station_strip, (), np.int64, s))
        t = int(self.station_strip.max()) + 1 if s else 0
        self.strip_shift = np.zeros((t, 3)) if self.strip_shift is None else _arr(self.strip_shift, (3,), n=t)
        self.strip_drift = np.zeros((t, 3)) if self.strip_drift is None else _arr(self.strip_drift, (3,), n=t)
        if self.strip_t0 is None:
            t0 = np.zeros(t)
            for k in range(t):
                sel = self.station_strip == k
                t0[k] = self.station_time[sel].mean() if sel.any() else 0.0
            self.strip_t0 = t0
        self.strip_t0 = _arr(self.strip_t0, (), n=t)
        self.point_name = np.asarray(self.point_name, dtype=str).reshape(-1)
        p = len(self.point_name)
        self.point_xyz = _arr(self.point_xyz, (3,), n=p)
        self.lever_arm = np.asarray(self.lever_arm, dtype=np.float64).reshape(3)
        self.datum_shift = np.asarray(self.datum_shift, dtype=np.float64).reshape(3)
        h = len(self.head_name)
        if self.head_actuated is None:
            self.head_actuated = [None] * h
        self.head_actuated = list(self.head_actuated)
        if len(self.head_actuated) != h:
            raise BlockError(f"head_actuated has {len(self.head_actuated)} entries for {h} heads")
        self.image_beta_rad = (np.full(i, np.nan) if self.image_beta_rad is None
                               else _arr(self.image_beta_rad, (), n=i).copy())
        ac = np.zeros((h, 2)) if self.actuator_correction is None else np.asarray(self.actuator_correction, float)
        if ac.ndim != 2 or ac.shape[0] != h or ac.shape[1] < 2 or (ac.shape[1] - 2) % 6:
            raise BlockError(f"actuator_correction must have shape ({h}, 2 + 6 N), got {ac.shape}")
        self.actuator_correction = ac.copy()
        self.parameters = {str(k): np.asarray(v, dtype=np.float64) for k, v in self.parameters.items()}
        # the observation groups: each type brings its rows to canonical arrays
        for ot in observation_types():
            ot.normalise(self)

    # ------------------------------------------------------------------ sizes
    @property
    def n_stations(self) -> int:
        return len(self.station_name)

    @property
    def n_images(self) -> int:
        return len(self.image_name)

    @property
    def n_points(self) -> int:
        return len(self.point_name)

    @property
    def n_observations(self) -> int:
        return len(self.obs_image)

    @property
    def n_distances(self) -> int:
        return len(self.distance_point)

    @property
    def n_strips(self) -> int:
        return len(self.strip_t0)

    def copy(self) -> "Block":
        """A deep copy of the arrays (cameras are immutable)."""
        parts = {p: type(getattr(self, p))(**{f.name: _copied(getattr(getattr(self, p), f.name))
                                              for f in fields(getattr(self, p))}) for p in _PARTS}
        return Block(cameras=list(self.cameras), **parts,
                     observations={k: require_type(k).copy_data(v) for k, v in self.observations.items()},
                     parameters={k: np.array(v, dtype=np.float64) for k, v in self.parameters.items()},
                     frame=self.frame)

    # ------------------------------------------------------------------ checks
    def validate(self) -> None:
        """Raise :class:`BlockError` naming the first inconsistency found (indices, NaN, sigma, rays): the
        geometry here, then each observation type's rows (:meth:`ObservationType.validate`)."""
        check_index("image_station", self.image_station, self.n_stations, "station")
        check_index("image_camera", self.image_camera, len(self.cameras), "camera")
        check_index("image_head", self.image_head, len(self.head_name), "head")
        for name in ("station_rotation", "station_centre", "point_xyz", "image_rotation", "image_offset"):
            check_finite(name, getattr(self, name))
        types = observation_types()
        for t in types:
            t.validate(self)
        act_img = np.array([self.head_actuated[k] is not None for k in self.image_head], bool)
        bad = np.flatnonzero(act_img & ~np.isfinite(self.image_beta_rad))
        if bad.size:
            raise BlockError(f"image {str(self.image_name[bad[0]])!r} belongs to the actuated head "
                             f"{str(self.head_name[self.image_head[bad[0]]])!r} but has no actuator angle (image_beta_rad)")
        check_finite("actuator_correction", self.actuator_correction)
        det = np.linalg.det(self.station_rotation) if self.n_stations else np.ones(0)
        bad = np.flatnonzero(np.abs(det - 1) > 1e-6)
        if bad.size:
            raise BlockError(f"station_rotation[{bad[0]}] is not a rotation (det {det[bad[0]]:.6f})")
        # every point needs two rays or control
        ctrl = np.zeros(self.n_points, bool)
        for t in types:
            c = t.controlled_points(self)
            if c is not None:
                ctrl |= c
        image_type().validate_rays(self, ctrl)


dataclass(init=False)(Block)


def sequence_index(names: Sequence[str]) -> dict[str, int]:
    return {str(n): i for i, n in enumerate(names)}
