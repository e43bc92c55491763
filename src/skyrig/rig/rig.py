"""Camera rigs: a platform (IMU body) frame, camera heads with lever arms, mountings and boresight
misalignments, the GNSS antenna lever arm, and actuated (tumbling) heads.

Frames and formulas
-------------------
* **body** (the platform / IMU body frame): x forward, y right, z down.  ``ned_from_body`` comes from
  roll, pitch, yaw (:func:`skyrig.geometry.rotations.matrix_from_rpy`).  Lever arms are metres in
  this frame.
* **camera:<head>**: the photogrammetric camera frame of a head (x right in the image, y up in the
  image, z towards the viewer; the camera looks along -z; see :mod:`skyrig.camera.frame`).
* **standard nadir mount** :data:`NADIR_BODY_FROM_CAMERA` ``= diag(1, -1, -1)``: image x along the
  flight direction (body x), image y to the *left* of the track (-body y), camera z up (-body z), so the
  camera looks straight down.
* **view angles**: a fixed head's nominal mounting is given as roll, pitch, yaw of its view relative
  to the standard nadir mount, about the **body axes**::

      mounting = matrix_from_rpy(roll, pitch, yaw) @ NADIR_BODY_FROM_CAMERA
               = Rz(yaw) @ Ry(pitch) @ Rx(roll) @ NADIR_BODY_FROM_CAMERA

  i.e. first roll about body x, then pitch about body y, then yaw about body z (fixed axes).  The
  viewing direction of the head is ``mounting @ (0, 0, -1)``: positive pitch tilts the view
  **forward**, positive roll tilts it to the **left** (-y), yaw turns it about the body vertical.
* **boresight misalignment**: a small rotation applied on the camera side,
  ``body_from_camera = mounting @ boresight``, given as photogrammetric angles **omega, phi, kappa
  about the camera axes** x, y, z: ``boresight = Rx(omega) @ Ry(phi) @ Rz(kappa)``
  (:func:`~skyrig.geometry.rotations.matrix_from_opk`, sequence ``"opk"``); it maps coordinates in the
  true camera frame to the nominally mounted camera frame.
* **tumbling head** (paper 000, section 3.4): the oblique camera hangs in a gimbal in a *sensor
  head* frame ``head`` (body-like axes: x forward, y right, z down, tied to the body by
  ``body_from_head = mounting @ NADIR_BODY_FROM_CAMERA``; for MACS-TumbleCam the head frame is the
  body frame and ``mounting`` is the standard nadir mount, the same as the nadir camera's).  At
  actuator angle beta the camera's angular offsets about the head axes x, y, z are

      roll(beta) = sin(beta) * gamma,  pitch(beta) = cos(beta) * gamma,  yaw = 0   (paper 000, eqs 1-3)

  plus the beta-dependent boresight corrections ``(droll, dpitch, dyaw)(beta)`` of a
  :class:`~skyrig.rig.boresight_curve.BoresightCurve`, *added* to these angles.  Then::

      body_from_camera(beta) = body_from_head
                               @ matrix_from_rpy(roll(beta) + droll, pitch(beta) + dpitch, dyaw)
                               @ NADIR_BODY_FROM_CAMERA @ boresight

  With the conventions above beta = 0 looks forward and beta = 90 deg looks left (the view turns
  counter-clockwise seen from above as beta increases).  With yaw = 0 the image x axis stays in the
  vertical plane through the head's x axis for every beta: the footprint does not turn about the
  vertical ("no rotation about the optical axis", paper 000 section 3.2, Fig. 5).  The linear law of
  eqs 1-2 tilts the optical axis by exactly gamma at beta = 0, 90, 180, 270 deg and slightly less in
  between (29.6 deg at beta = 45 deg for gamma = 30 deg); ``law="cardan"`` instead uses
  ``roll = asin(sin(gamma) sin(beta))``, ``pitch = atan2(sin(gamma) cos(beta), cos(gamma))``, which
  put the axis exactly on the cone of half-angle gamma (the two agree to first order).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.camera.frame import FrameCamera
from skyrig.errors import GeometryError, HeadNotFoundError, SkyrigError  # noqa: F401 - HeadNotFoundError re-exported
from skyrig.geometry.angles import to_radians
from skyrig.geometry.pose import Pose
from skyrig.geometry.rotations import NADIR_BODY_FROM_CAMERA, matrix_from_opk, matrix_from_rpy, opk_from_matrix, rot_y, rot_z, rpy_from_matrix
from skyrig.rig.boresight_curve import BoresightCurve

TumbleLaw = Literal["paper", "cardan"]

#: ``body_from_camera`` of the standard nadir mount: image x forward, image y left, camera z up.
NADIR_BODY_FROM_CAMERA.setflags(write=False)  # defined in skyrig.geometry.rotations

#: Direction of view (the optical axis, pointing away from the camera) in the camera frame.
VIEW_DIRECTION_CAMERA: NDArray[np.float64] = np.array([0.0, 0.0, -1.0])
VIEW_DIRECTION_CAMERA.setflags(write=False)


# ---------------------------------------------------------------------- angle helpers
def mounting_from_rpy(roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike, unit: str = "deg") -> NDArray[np.float64]:
    """Nominal ``body_from_camera`` from view angles: ``matrix_from_rpy(roll, pitch, yaw) @ NADIR_BODY_FROM_CAMERA``.

    Parameters
    ----------
    roll, pitch, yaw
        View angles about the body axes x, y, z (scalars or ``(N,)``), in ``unit``.
    unit
        ``"deg"``, ``"rad"`` or ``"gon"``.

    Returns
    -------
    ndarray
        ``(3, 3)`` or ``(N, 3, 3)``.
    """
    return matrix_from_rpy(roll, pitch, yaw, unit=unit) @ NADIR_BODY_FROM_CAMERA


def rpy_from_mounting(mounting: ArrayLike, unit: str = "deg") -> tuple[NDArray[np.float64], ...]:
    """Inverse of :func:`mounting_from_rpy`: ``(roll, pitch, yaw)`` in ``unit`` (pitch in [-90, 90] deg)."""
    return rpy_from_matrix(np.asarray(mounting, dtype=np.float64) @ NADIR_BODY_FROM_CAMERA, unit=unit)


def oblique_mounting(azimuth: float, tilt: float, unit: str = "deg") -> NDArray[np.float64]:
    """Nominal ``body_from_camera`` of a camera tilted off nadir with its image upright.

    The view is tilted by ``tilt`` from nadir towards ``azimuth`` (0 = forward, 90 = right,
    clockwise seen from above, about body z); the image x axis stays horizontal and the image top
    (+y) points towards the far field (the horizon side).  ``tilt = 0`` gives a nadir camera with
    image x to the right and the image top forward::

        mounting = Rz(azimuth) @ Ry(tilt) @ Rz(90 deg) @ NADIR_BODY_FROM_CAMERA
    """
    a, t = to_radians(azimuth, unit), to_radians(tilt, unit)
    return rot_z(a) @ rot_y(t) @ rot_z(np.pi / 2.0) @ NADIR_BODY_FROM_CAMERA


def boresight_from_opk(omega: float, phi: float, kappa: float, unit: str = "deg") -> NDArray[np.float64]:
    """Boresight misalignment ``Rx(omega) @ Ry(phi) @ Rz(kappa)`` about the camera axes, angles in ``unit``."""
    return matrix_from_opk(omega, phi, kappa, unit=unit, sequence="opk")


def tumble_angles(
    beta_rad: ArrayLike, gamma_rad: float, law: TumbleLaw = "paper"
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Nominal (roll, pitch) of a tumbling camera about the sensor-head axes x, y (radians).

    Parameters
    ----------
    beta_rad
        Actuator angles ``(...)``, radians.
    gamma_rad
        Deflection (cone half-angle) of the oblique camera, radians (MACS-TumbleCam: 30 deg).
    law
        ``"paper"``: ``roll = sin(beta) gamma``, ``pitch = cos(beta) gamma`` (paper 000, eqs 1-2);
        ``"cardan"``: ``roll = asin(sin gamma sin beta)``, ``pitch = atan2(sin gamma cos beta, cos gamma)``
        (optical axis exactly on the cone).
    """
    b = np.asarray(beta_rad, dtype=np.float64)
    if law == "paper":
        return np.sin(b) * gamma_rad, np.cos(b) * gamma_rad
    if law == "cardan":
        sg = np.sin(gamma_rad)
        return np.arcsin(np.clip(sg * np.sin(b), -1.0, 1.0)), np.arctan2(sg * np.cos(b), np.cos(gamma_rad))
    raise SkyrigError(f"unknown tumbling law {law!r}; expected 'paper' or 'cardan'")


def _rotation(value: ArrayLike, what: str) -> NDArray[np.float64]:
    r = np.array(value, dtype=np.float64)
    if r.shape != (3, 3) or not np.all(np.isfinite(r)):
        raise GeometryError(f"{what} must be a finite (3, 3) rotation matrix, got shape {r.shape}")
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
        raise GeometryError(f"{what} is not a proper rotation matrix (orthonormal, det +1)")
    r.setflags(write=False)
    return r


def _vector3(value: ArrayLike, what: str) -> NDArray[np.float64]:
    v = np.array(value, dtype=np.float64).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise GeometryError(f"{what} must be 3 finite numbers (metres, body frame)")
    v.setflags(write=False)
    return v


def _camera_isclose(a: FrameCamera, b: FrameCamera, rtol: float = 1e-12) -> bool:
    if (a.name, a.width, a.height) != (b.name, b.width, b.height):
        return False
    for k in ("pixel_size_mm", "focal_mm", "ppx_mm", "ppy_mm"):
        if not np.isclose(getattr(a, k), getattr(b, k), rtol=rtol, atol=1e-15):
            return False
    da, db = a.distortion, b.distortion
    if type(da) is not type(db):
        return False
    if hasattr(da, "to_dict"):
        return _plain_equal(da.to_dict(), db.to_dict(), rtol)
    try:
        return bool(da == db)
    except ValueError:  # dataclasses holding arrays
        return da is db


def _plain_equal(x: Any, y: Any, rtol: float) -> bool:
    if isinstance(x, Mapping) and isinstance(y, Mapping):
        return x.keys() == y.keys() and all(_plain_equal(x[k], y[k], rtol) for k in x)
    if isinstance(x, str) or isinstance(y, str):
        return x == y
    try:
        ax, ay = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    except (TypeError, ValueError):
        return bool(x == y)
    return ax.shape == ay.shape and bool(np.allclose(ax, ay, rtol=rtol, atol=1e-15))


# ---------------------------------------------------------------------- heads
@dataclass(frozen=True, eq=False)
class Head:
    """A camera rigidly mounted on the platform.

    Attributes
    ----------
    name
        Head name, unique in its rig; the camera frame is called ``"camera:<name>"``.
    camera
        The head's camera model.
    lever_arm_m
        ``(3,)`` projection centre in the body frame, metres (x forward, y right, z down).
    mounting
        ``(3, 3)`` nominal ``body_from_camera`` (default: the standard nadir mount).  Build it from
        view angles with :func:`mounting_from_rpy` / :meth:`from_angles`.
    boresight
        ``(3, 3)`` small misalignment on the camera side (``nominal_camera_from_camera``), so that
        ``body_from_camera = mounting @ boresight``; see :func:`boresight_from_opk`.
    """

    name: str
    camera: FrameCamera
    lever_arm_m: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    mounting: NDArray[np.float64] = field(default_factory=lambda: NADIR_BODY_FROM_CAMERA.copy())
    boresight: NDArray[np.float64] = field(default_factory=lambda: np.eye(3))

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise SkyrigError(f"a head needs a non-empty name, got {self.name!r}")
        if not isinstance(self.camera, FrameCamera):
            raise SkyrigError(f"head {self.name!r}: camera must be a FrameCamera, got {type(self.camera).__name__}")
        object.__setattr__(self, "lever_arm_m", _vector3(self.lever_arm_m, f"head {self.name!r}: lever_arm_m"))
        object.__setattr__(self, "mounting", _rotation(self.mounting, f"head {self.name!r}: mounting"))
        object.__setattr__(self, "boresight", _rotation(self.boresight, f"head {self.name!r}: boresight"))

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_angles(
        cls,
        name: str,
        camera: FrameCamera,
        lever_arm_m: ArrayLike = (0.0, 0.0, 0.0),
        roll: float = 0.0,
        pitch: float = 0.0,
        yaw: float = 0.0,
        boresight_opk: ArrayLike = (0.0, 0.0, 0.0),
        unit: str = "deg",
    ) -> "Head":
        """A fixed head from view angles (roll, pitch, yaw about the body axes, see
        :func:`mounting_from_rpy`) and boresight angles (omega, phi, kappa about the camera axes),
        all in ``unit``."""
        o, p, k = np.asarray(boresight_opk, dtype=np.float64).reshape(3)
        mounting = mounting_from_rpy(roll, pitch, yaw, unit)
        return cls(name, camera, lever_arm_m, mounting, boresight_from_opk(o, p, k, unit))

    def with_(self, **changes: Any) -> "Head":
        """A copy with some fields changed."""
        return replace(self, **changes)

    # ------------------------------------------------------------------ queries
    @property
    def frame(self) -> str:
        """Frame name of this head's camera: ``"camera:<name>"``."""
        return f"camera:{self.name}"

    @property
    def is_actuated(self) -> bool:
        """Whether the mounting depends on an actuator angle."""
        return False

    def mounting_rpy(self, unit: str = "deg") -> tuple[float, float, float]:
        """View angles (roll, pitch, yaw) of :attr:`mounting` in ``unit`` (inverse of :func:`mounting_from_rpy`)."""
        r, p, y = rpy_from_mounting(self.mounting, unit)
        return float(r), float(p), float(y)

    def boresight_opk(self, unit: str = "deg") -> tuple[float, float, float]:
        """Boresight angles (omega, phi, kappa) about the camera axes in ``unit``."""
        o, p, k = opk_from_matrix(self.boresight, unit=unit, sequence="opk")
        return float(o), float(p), float(k)

    def body_from_camera_rotation(self, beta_rad: ArrayLike | None = None) -> NDArray[np.float64]:
        """``body_from_camera`` rotation: ``(3, 3)``, or ``(*beta.shape, 3, 3)`` when ``beta_rad`` is given
        (a fixed head repeats its constant rotation, so that callers can vectorise over all images)."""
        r = self.mounting @ self.boresight
        if beta_rad is None:
            return r
        b = np.asarray(beta_rad, dtype=np.float64)
        return np.broadcast_to(r, b.shape + (3, 3)).copy()

    def body_from_camera(self, beta_rad: ArrayLike | None = None) -> Pose:
        """``body_from_camera`` pose: rotation as :meth:`body_from_camera_rotation`, translation the lever arm.

        Parameters
        ----------
        beta_rad
            Actuator angle(s) in radians, scalar or ``(M,)``; required for actuated heads, optional
            (broadcast) for fixed heads.

        Returns
        -------
        Pose
            ``dst="body"``, ``src="camera:<name>"``; batched ``(M, 3, 3)`` / ``(M, 3)`` for ``(M,)`` beta.
        """
        r = self.body_from_camera_rotation(beta_rad)
        t = np.broadcast_to(self.lever_arm_m, r.shape[:-2] + (3,)).copy()
        return Pose(r, t, "body", self.frame)

    def optical_axis(self, beta_rad: ArrayLike | None = None) -> NDArray[np.float64]:
        """Unit viewing direction(s) in the body frame, ``(3,)`` or ``(M, 3)``."""
        return self.body_from_camera_rotation(beta_rad) @ VIEW_DIRECTION_CAMERA

    def isclose(self, other: "Head", atol: float = 1e-12) -> bool:
        """Equality up to ``atol`` on lever arms (m) and rotation matrix elements."""
        return (
            type(self) is type(other)
            and self.name == other.name
            and _camera_isclose(self.camera, other.camera)
            and bool(np.allclose(self.lever_arm_m, other.lever_arm_m, rtol=0, atol=atol))
            and bool(np.allclose(self.mounting, other.mounting, rtol=0, atol=atol))
            and bool(np.allclose(self.boresight, other.boresight, rtol=0, atol=atol))
        )


@dataclass(frozen=True, eq=False)
class ActuatedHead(Head):
    """A tumbling camera head whose mounting depends on an actuator angle beta (paper 000).

    ``mounting`` is the nominal ``body_from_camera`` of the *untilted* camera (gamma = 0); the sensor
    head frame is ``body_from_head = mounting @ NADIR_BODY_FROM_CAMERA`` (identity for the standard
    nadir mount).  See the module docstring for the formula.

    Attributes
    ----------
    gamma_rad
        Deflection of the oblique camera (cone half-angle), radians (MACS-TumbleCam: 30 deg).
    curve
        Beta-dependent boresight corrections ``(droll, dpitch, dyaw)`` added to the tumbling angles,
        or None for none.
    law
        ``"paper"`` (eqs 1-2 of paper 000, default) or ``"cardan"`` (exact cone); see :func:`tumble_angles`.
    """

    gamma_rad: float = 0.0
    curve: BoresightCurve | None = None
    law: TumbleLaw = "paper"

    def __post_init__(self) -> None:
        super().__post_init__()
        g = float(self.gamma_rad)
        if not np.isfinite(g) or abs(g) >= np.pi / 2:
            raise SkyrigError(f"head {self.name!r}: gamma_rad must be a finite angle below 90 deg, got {g}")
        object.__setattr__(self, "gamma_rad", g)
        if self.curve is not None and not isinstance(self.curve, BoresightCurve):
            raise SkyrigError(f"head {self.name!r}: curve must be a BoresightCurve or None")
        if self.law not in ("paper", "cardan"):
            raise SkyrigError(f"head {self.name!r}: unknown tumbling law {self.law!r}; expected 'paper' or 'cardan'")

    @classmethod
    def tumbling(
        cls,
        name: str,
        camera: FrameCamera,
        gamma: float,
        lever_arm_m: ArrayLike = (0.0, 0.0, 0.0),
        head_rpy: ArrayLike = (0.0, 0.0, 0.0),
        boresight_opk: ArrayLike = (0.0, 0.0, 0.0),
        curve: BoresightCurve | None = None,
        law: TumbleLaw = "paper",
        unit: str = "deg",
    ) -> "ActuatedHead":
        """A tumbling head from angles in ``unit``.

        Parameters
        ----------
        gamma
            Cone half-angle (deflection).
        head_rpy
            View angles of the untilted camera (= orientation of the sensor head frame in the body),
            as for :func:`mounting_from_rpy`; zeros: the head frame is the body frame.
        boresight_opk
            Constant camera-side boresight (omega, phi, kappa about the camera axes).
        """
        r, p, y = np.asarray(head_rpy, dtype=np.float64).reshape(3)
        o, ph, k = np.asarray(boresight_opk, dtype=np.float64).reshape(3)
        return cls(
            name,
            camera,
            lever_arm_m,
            mounting_from_rpy(r, p, y, unit),
            boresight_from_opk(o, ph, k, unit),
            float(to_radians(gamma, unit)),
            curve,
            law,
        )

    @property
    def is_actuated(self) -> bool:
        return True

    @property
    def body_from_head(self) -> NDArray[np.float64]:
        """``(3, 3)`` rotation of the sensor head frame (x forward, y right, z down) into the body."""
        return self.mounting @ NADIR_BODY_FROM_CAMERA

    def tilt_angles(self, beta_rad: ArrayLike) -> NDArray[np.float64]:
        """Corrected angular offsets ``(..., 3)`` (roll, pitch, yaw; radians) about the head axes at ``beta_rad``."""
        b = np.asarray(beta_rad, dtype=np.float64)
        roll, pitch = tumble_angles(b, self.gamma_rad, self.law)
        out = np.stack([roll, pitch, np.zeros_like(roll)], axis=-1)
        if self.curve is not None:
            out = out + self.curve(b)
        return out

    def head_from_camera_rotation(self, beta_rad: ArrayLike) -> NDArray[np.float64]:
        """``head_from_camera`` ``(..., 3, 3)``: ``matrix_from_rpy(tilt angles) @ NADIR @ boresight``."""
        a = self.tilt_angles(beta_rad)
        t = matrix_from_rpy(a[..., 0], a[..., 1], a[..., 2], unit="rad")
        return t @ NADIR_BODY_FROM_CAMERA @ self.boresight

    def body_from_camera_rotation(self, beta_rad: ArrayLike | None = None) -> NDArray[np.float64]:
        """``body_from_camera`` ``(..., 3, 3)`` at actuator angle(s) ``beta_rad`` (required)."""
        if beta_rad is None:
            raise SkyrigError(f"head {self.name!r} is actuated: body_from_camera needs the actuator angle beta")
        return self.body_from_head @ self.head_from_camera_rotation(beta_rad)

    def isclose(self, other: Head, atol: float = 1e-12) -> bool:
        if not (super().isclose(other, atol) and isinstance(other, ActuatedHead)):
            return False
        if self.law != other.law or abs(self.gamma_rad - other.gamma_rad) > atol:
            return False
        if (self.curve is None) != (other.curve is None):
            return False
        return self.curve is None or self.curve.isclose(other.curve, atol)  # type: ignore[arg-type]


# ---------------------------------------------------------------------- rig
@dataclass(frozen=True, eq=False)
class Rig:
    """A platform carrying camera heads and a GNSS antenna.

    Attributes
    ----------
    name
        Rig name.
    heads
        Ordered mapping ``head name -> Head``, stored as a new dict (treat it as read-only); a sequence
        of heads is accepted and keyed by their names.
    antenna_lever_arm_m
        ``(3,)`` GNSS antenna phase centre in the body frame, metres.
    description
        Free text (where the figures come from, serial numbers...).
    """

    name: str
    heads: Mapping[str, Head]
    antenna_lever_arm_m: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    description: str = ""

    def __post_init__(self) -> None:
        items: list[tuple[str, Head]]
        if isinstance(self.heads, Mapping):
            items = list(self.heads.items())
        elif isinstance(self.heads, Sequence):
            items = [(h.name, h) for h in self.heads]
        else:
            raise SkyrigError("rig heads must be a mapping name -> Head or a sequence of Head")
        if not items:
            raise SkyrigError(f"rig {self.name!r} has no heads")
        out: dict[str, Head] = {}
        for key, h in items:
            if not isinstance(h, Head):
                raise SkyrigError(f"rig {self.name!r}: {key!r} is not a Head")
            if key != h.name:
                raise SkyrigError(f"rig {self.name!r}: head stored under {key!r} is named {h.name!r}")
            if key in out:
                raise SkyrigError(f"rig {self.name!r}: two heads named {key!r}")
            out[key] = h
        object.__setattr__(self, "heads", out)  # a plain dict (picklable for parallel stages); treat as read-only
        object.__setattr__(self, "antenna_lever_arm_m", _vector3(self.antenna_lever_arm_m, "antenna_lever_arm_m"))

    @property
    def head_names(self) -> list[str]:
        """Head names in rig order."""
        return list(self.heads)

    def head(self, name: str) -> Head:
        """The head called ``name``; raises :class:`HeadNotFoundError` (a ``KeyError``) listing the heads."""
        try:
            return self.heads[name]
        except KeyError:
            raise HeadNotFoundError(
                f"rig {self.name!r} has no head {name!r}; heads: {', '.join(self.heads)}"
            ) from None

    def __iter__(self) -> Iterator[Head]:
        return iter(self.heads.values())

    def __len__(self) -> int:
        return len(self.heads)

    def __contains__(self, name: object) -> bool:
        return name in self.heads

    def body_from_camera(self, head: str, beta_rad: ArrayLike | None = None) -> Pose:
        """Shortcut for ``rig.head(head).body_from_camera(beta_rad)``."""
        return self.head(head).body_from_camera(beta_rad)

    def antenna_to_camera_m(self, head: str) -> NDArray[np.float64]:
        """``(3,)`` vector from the GNSS antenna phase centre to the head's projection centre (body frame, m)."""
        return self.head(head).lever_arm_m - self.antenna_lever_arm_m

    def isclose(self, other: "Rig", atol: float = 1e-12) -> bool:
        """Equality up to ``atol`` on lengths (m) and rotation elements (as :meth:`Head.isclose`)."""
        return (
            isinstance(other, Rig)
            and self.name == other.name
            and self.description == other.description
            and self.head_names == other.head_names
            and bool(np.allclose(self.antenna_lever_arm_m, other.antenna_lever_arm_m, rtol=0, atol=atol))
            and all(a.isclose(b, atol) for a, b in zip(self, other))
        )
