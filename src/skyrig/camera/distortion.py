"""Lens distortion models: the common interface and the registry of model names.

Every model works on image coordinates **relative to the principal point, in millimetres**, in the
photogrammetric image system (x right, y up; see :mod:`skyrig.camera.frame`):

* ``distort(xy_ideal, focal_mm)``: ideal (pinhole, collinear) coordinates ``(N, 2)`` -> observed
  (distorted, as measured in the image) coordinates ``(N, 2)``.  This is the direction used by
  projection.
* ``undistort(xy_observed, focal_mm)``: the inverse, used to build viewing rays.

One of the two directions is a closed-form polynomial, the other is solved by Newton iteration to
``1e-12`` mm (which one depends on the model's convention: the Australis/Brown model is defined as a
correction of observed coordinates, the OpenCV model as a distortion of ideal ones).  ``focal_mm``
matters for models defined on normalised coordinates (OpenCV); mm-based models ignore it.

Parameters are exposed as a vector ``params`` ``(P,)`` ordered as ``param_names``; models are frozen
dataclasses whose field names are the parameter names.  Analytic Jacobians of the *projection*
direction are available for bundle adjustment:

* :meth:`Distortion.jacobian_ideal`  ``d(observed)/d(ideal)``    ``(N, 2, 2)``
* :meth:`Distortion.jacobian_params` ``d(observed)/d(params)``   ``(N, 2, P)``
* :meth:`Distortion.jacobian_focal`  ``d(observed)/d(focal_mm)`` ``(N, 2)`` (ideal held fixed)
* :meth:`Distortion.distort_with_jacobians` all of them in one pass.

A registry maps model names (``"none"``, ``"brown"``, ``"opencv"``, ``"opencv_rational"``...) to classes,
so file readers build models with :func:`distortion_from_dict` and never branch on the name::

    distortion_from_dict({"model": "brown", "k1": -1.2e-4, "p1": 3e-6})

New models register themselves with the :func:`register_distortion` class decorator.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from skyrig.errors import InputFormatError, SkyrigError

logger = logging.getLogger(__name__)

#: convergence threshold (mm) of the iterative direction of every model
NEWTON_TOL_MM = 1e-12
#: iteration cap of the Newton solvers
NEWTON_MAX_ITER = 50

_REGISTRY: dict[str, type["Distortion"]] = {}

D = TypeVar("D", bound="Distortion")


def register_distortion(cls: type[D]) -> type[D]:
    """Class decorator: make a :class:`Distortion` subclass available under ``cls.name``.

    Raises :class:`~skyrig.errors.SkyrigError` if another class already holds the name.
    """
    name = cls.name.lower()
    if name in _REGISTRY and _REGISTRY[name] is not cls:
        raise SkyrigError(f"distortion model name {name!r} is already registered by {_REGISTRY[name].__name__}")
    _REGISTRY[name] = cls
    return cls


def distortion_models() -> dict[str, type["Distortion"]]:
    """A copy of the registry: model name -> class."""
    return dict(_REGISTRY)


def distortion_class(model: str) -> type["Distortion"]:
    """The class registered under ``model`` (case-insensitive); InputFormatError if unknown."""
    try:
        return _REGISTRY[str(model).lower()]
    except KeyError:
        raise InputFormatError(
            f"unknown distortion model {model!r}; known: {', '.join(sorted(_REGISTRY))}", field="model"
        ) from None


def distortion_from_dict(data: Mapping[str, Any]) -> "Distortion":
    """Build a distortion model from ``{"model": name, <param>: value, ...}``.

    Missing parameters default to zero; unknown keys, non-numeric values and unknown models raise
    :class:`~skyrig.errors.InputFormatError` naming the field (readers add file and line).
    """
    if "model" not in data:
        raise InputFormatError("distortion entry has no 'model'", field="model")
    return distortion_class(str(data["model"])).from_dict(data)


def _inv2(m: NDArray[np.float64]) -> NDArray[np.float64]:
    """Closed-form inverses of 2x2 matrices ``(N, 2, 2)`` (much faster than np.linalg for tiny blocks)."""
    det = m[:, 0, 0] * m[:, 1, 1] - m[:, 0, 1] * m[:, 1, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_det = 1.0 / det
    out = np.empty_like(m)
    out[:, 0, 0] = m[:, 1, 1] * inv_det
    out[:, 1, 1] = m[:, 0, 0] * inv_det
    out[:, 0, 1] = -m[:, 0, 1] * inv_det
    out[:, 1, 0] = -m[:, 1, 0] * inv_det
    return out


def _solve2(m: NDArray[np.float64], r: NDArray[np.float64]) -> NDArray[np.float64]:
    """Solve ``m x = r`` for ``(N, 2, 2)`` matrices and ``(N, 2)`` right-hand sides."""
    det = m[:, 0, 0] * m[:, 1, 1] - m[:, 0, 1] * m[:, 1, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        x0 = (m[:, 1, 1] * r[:, 0] - m[:, 0, 1] * r[:, 1]) / det
        x1 = (m[:, 0, 0] * r[:, 1] - m[:, 1, 0] * r[:, 0]) / det
    return np.stack([x0, x1], axis=1)


def _as_points(xy: ArrayLike) -> tuple[NDArray[np.float64], tuple[int, ...]]:
    a = np.asarray(xy, dtype=np.float64)
    if a.shape[-1:] != (2,):
        raise ValueError(f"image coordinates must have shape (..., 2), got {a.shape}")
    return a.reshape(-1, 2), a.shape[:-1]


class Distortion:
    """Base class of lens distortion models (frozen dataclasses whose fields are the parameters).

    Subclasses set ``name`` and ``param_names`` and implement :meth:`distort_with_jacobians`; a model
    whose closed-form direction is the correction (observed -> ideal) may instead implement
    :meth:`_correct_with_jacobians` and inherit the Newton solver for projection (see
    :class:`CorrectionModel`).  The base class solves :meth:`undistort` by Newton iteration on
    :meth:`distort`.
    """

    name: ClassVar[str] = "base"
    param_names: ClassVar[tuple[str, ...]] = ()
    #: unit of each parameter (documentation, for reports)
    param_units: ClassVar[tuple[str, ...]] = ()
    #: model constants: dataclass fields that are part of the model's definition but never estimated
    #: (e.g. the radius of zero distortion R0 of a balanced radial model); written to and read from
    #: dictionaries with the parameters, kept by :meth:`with_params`, not in :attr:`params`
    constant_names: ClassVar[tuple[str, ...]] = ()

    # ------------------------------------------------------------------ parameters
    @property
    def params(self) -> NDArray[np.float64]:
        """Parameter vector ``(P,)`` in the order of ``param_names``."""
        return np.array([float(getattr(self, n)) for n in self.param_names], dtype=np.float64)

    @property
    def n_params(self) -> int:
        """Number of parameters P."""
        return len(self.param_names)

    def params_dict(self) -> dict[str, float]:
        """``{name: value}`` of the parameters."""
        return {n: float(getattr(self, n)) for n in self.param_names}

    def constants_dict(self) -> dict[str, float]:
        """``{name: value}`` of the model constants (empty for most models)."""
        return {n: float(getattr(self, n)) for n in self.constant_names}

    @classmethod
    def from_params(cls: type[D], params: ArrayLike) -> D:
        """A model from a vector ``(P,)`` ordered as ``param_names`` (constants at their defaults)."""
        p = np.asarray(params, dtype=np.float64).reshape(-1)
        if p.size != len(cls.param_names):
            raise ValueError(f"{cls.name}: expected {len(cls.param_names)} parameters, got {p.size}")
        return cls(**{n: float(v) for n, v in zip(cls.param_names, p)})  # type: ignore[call-arg]

    def with_params(self: D, params: ArrayLike) -> D:
        """A copy with the parameter vector ``(P,)`` replaced and the model constants kept."""
        p = np.asarray(params, dtype=np.float64).reshape(-1)
        if p.size != len(self.param_names):
            raise ValueError(f"{self.name}: expected {len(self.param_names)} parameters, got {p.size}")
        return dataclasses.replace(self, **{n: float(v) for n, v in zip(self.param_names, p)})  # type: ignore[type-var]

    def to_dict(self) -> dict[str, Any]:
        """``{"model": name, <constant>: value, ..., <param>: value, ...}`` for rig and camera files."""
        return {"model": self.name, **self.constants_dict(), **self.params_dict()}

    @classmethod
    def from_dict(cls: type[D], data: Mapping[str, Any]) -> D:
        """Inverse of :meth:`to_dict`; parameter keys are case-insensitive, missing ones are zero."""
        model = data.get("model", cls.name)
        if str(model).lower() != cls.name:
            raise InputFormatError(f"expected distortion model {cls.name!r}, got {model!r}", field="model")
        values: dict[str, float] = {}
        for key, value in data.items():
            if key == "model":
                continue
            k = str(key).lower()
            if k not in cls.param_names and k not in cls.constant_names:
                raise InputFormatError(
                    f"unknown parameter for distortion model {cls.name!r}; expected "
                    f"{', '.join(cls.constant_names + cls.param_names)}",
                    field=str(key),
                )
            try:
                v = float(value)
            except (TypeError, ValueError):
                raise InputFormatError(f"not a number: {value!r}", field=str(key)) from None
            if not np.isfinite(v):
                raise InputFormatError(f"not a finite number: {value!r}", field=str(key))
            values[k] = v
        return cls(**values)  # type: ignore[call-arg]

    # ------------------------------------------------------------------ mapping
    def distort_with_jacobians(
        self, xy_ideal: ArrayLike, focal_mm: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Observed coordinates and their Jacobians in one pass.

        Parameters
        ----------
        xy_ideal
            ``(N, 2)`` ideal image coordinates relative to the principal point, mm.
        focal_mm
            Principal distance, mm.

        Returns
        -------
        observed
            ``(N, 2)`` mm.
        d_ideal
            ``(N, 2, 2)`` ``d(observed)/d(ideal)``.
        d_params
            ``(N, 2, P)`` ``d(observed)/d(params)``.
        d_focal
            ``(N, 2)`` ``d(observed)/d(focal_mm)`` at fixed ideal coordinates (mm/mm).
        """
        raise NotImplementedError

    def distort(self, xy_ideal: ArrayLike, focal_mm: float) -> NDArray[np.float64]:
        """Ideal ``(N, 2)`` mm -> observed ``(N, 2)`` mm (relative to the principal point)."""
        xy, shape = _as_points(xy_ideal)
        return self.distort_with_jacobians(xy, focal_mm)[0].reshape(shape + (2,))

    def undistort(self, xy_observed: ArrayLike, focal_mm: float) -> NDArray[np.float64]:
        """Observed ``(N, 2)`` mm -> ideal ``(N, 2)`` mm; Newton iteration on :meth:`distort`.

        Points where the iteration does not converge (far outside the model's valid region) are NaN.
        """
        obs, shape = _as_points(xy_observed)
        x = obs.copy()
        active = np.isfinite(obs).all(axis=1)
        x[~active] = np.nan
        for _ in range(NEWTON_MAX_ITER):
            if not active.any():
                break
            idx = np.flatnonzero(active)
            f, J, _, _ = self.distort_with_jacobians(x[idx], focal_mm)
            step = _solve2(J, f - obs[idx])
            x[idx] -= step
            active[idx] = np.abs(step).max(axis=1) > NEWTON_TOL_MM  # NaN (singular) steps stop, as NaN
        if active.any():
            logger.debug("%s.undistort: %d points did not converge", self.name, int(active.sum()))
            x[active] = np.nan
        return x.reshape(shape + (2,))

    def jacobian_ideal(self, xy_ideal: ArrayLike, focal_mm: float) -> NDArray[np.float64]:
        """``d(observed)/d(ideal)`` ``(N, 2, 2)`` at ideal coordinates ``(N, 2)`` mm."""
        return self.distort_with_jacobians(_as_points(xy_ideal)[0], focal_mm)[1]

    def jacobian_params(self, xy_ideal: ArrayLike, focal_mm: float) -> NDArray[np.float64]:
        """``d(observed)/d(params)`` ``(N, 2, P)`` at ideal coordinates ``(N, 2)`` mm."""
        return self.distort_with_jacobians(_as_points(xy_ideal)[0], focal_mm)[2]

    def jacobian_focal(self, xy_ideal: ArrayLike, focal_mm: float) -> NDArray[np.float64]:
        """``d(observed)/d(focal_mm)`` ``(N, 2)`` at fixed ideal coordinates ``(N, 2)`` mm."""
        return self.distort_with_jacobians(_as_points(xy_ideal)[0], focal_mm)[3]


class CorrectionModel(Distortion):
    """Base of models defined as a correction of *observed* coordinates: ``ideal = g(observed)``.

    Subclasses implement :meth:`_correct_with_jacobians` (closed form).  :meth:`undistort` is then
    ``g`` itself and :meth:`distort` solves ``g(observed) = ideal`` by Newton iteration; the
    Jacobians of :meth:`distort` follow from the implicit function theorem:
    ``d(obs)/d(ideal) = G^-1`` and ``d(obs)/d(p) = -G^-1 dg/dp`` with ``G = dg/d(obs)``.
    """

    def _correct_with_jacobians(
        self, xy_observed: NDArray[np.float64], focal_mm: float, with_params: bool = True
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """``(ideal (N,2), dg/dobs (N,2,2), dg/dparams (N,2,P), dg/dfocal (N,2))``.

        With ``with_params=False`` the last two may be left empty (used inside Newton iterations).
        """
        raise NotImplementedError

    def undistort(self, xy_observed: ArrayLike, focal_mm: float) -> NDArray[np.float64]:
        obs, shape = _as_points(xy_observed)
        return self._correct_with_jacobians(obs, focal_mm)[0].reshape(shape + (2,))

    def distort_with_jacobians(
        self, xy_ideal: ArrayLike, focal_mm: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        ideal, _ = _as_points(xy_ideal)
        # first-order start: observed ~ ideal - correction(ideal)
        x = 2.0 * ideal - self._correct_with_jacobians(ideal, focal_mm, False)[0]
        active = np.isfinite(x).all(axis=1)
        x[~active] = np.nan
        for _ in range(NEWTON_MAX_ITER):
            if not active.any():
                break
            idx = np.flatnonzero(active)
            g, G, _, _ = self._correct_with_jacobians(x[idx], focal_mm, False)
            step = _solve2(G, g - ideal[idx])
            x[idx] -= step
            active[idx] = np.abs(step).max(axis=1) > NEWTON_TOL_MM  # NaN (singular) steps stop, as NaN
        if active.any():
            logger.debug("%s.distort: %d points did not converge", self.name, int(active.sum()))
            x[active] = np.nan
        _, G, Gp, Gf = self._correct_with_jacobians(x, focal_mm)
        Ginv = _inv2(G)
        d_params = -(Ginv @ Gp)
        d_focal = -np.einsum("nij,nj->ni", Ginv, Gf)
        return x, Ginv, d_params, d_focal


@register_distortion
@dataclass(frozen=True)
class NoDistortion(Distortion):
    """The identity: an ideal pinhole (no parameters)."""

    name: ClassVar[str] = "none"

    def distort_with_jacobians(
        self, xy_ideal: ArrayLike, focal_mm: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        xy, _ = _as_points(xy_ideal)
        n = xy.shape[0]
        return xy.copy(), np.broadcast_to(np.eye(2), (n, 2, 2)).copy(), np.zeros((n, 2, 0)), np.zeros((n, 2))

    def distort(self, xy_ideal: ArrayLike, focal_mm: float) -> NDArray[np.float64]:
        return np.array(xy_ideal, dtype=np.float64)

    def undistort(self, xy_observed: ArrayLike, focal_mm: float) -> NDArray[np.float64]:
        return np.array(xy_observed, dtype=np.float64)


def _fields_are_params(cls: type[Distortion]) -> None:
    """Sanity check used by the tests: dataclass fields == constant_names + param_names."""
    names = tuple(f.name for f in dataclasses.fields(cls))  # type: ignore[arg-type]
    if sorted(names) != sorted(cls.constant_names + cls.param_names):
        raise SkyrigError(f"{cls.__name__}: fields {names} differ from param_names {cls.param_names}")

