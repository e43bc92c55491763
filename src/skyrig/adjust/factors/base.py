"""What every observation type of the adjustment provides (DESIGN.md convention 5).

An observation type is one module of :mod:`skyrig.adjust.factors` holding one instance of a subclass of
:class:`ObservationType`, registered with :func:`skyrig.adjust.factors.register`.  It owns

* its **data**: a data class of its module whose rows live in ``block.observations[name]`` of a
  :class:`~skyrig.adjust.block.Block` (the built-in types also take the block's flat keywords, ``gnss_xyz=``...,
  through :attr:`rows` / :attr:`keywords`), how they are normalised when the block is built
  (:meth:`normalise`) and checked (:meth:`validate`);
* its **residual and Jacobian**: :meth:`evaluate` returns whitened :class:`Factor` rows (computed minus
  observed, over sigma or whitened by a full covariance) with the Jacobian with respect to the reduced
  columns of :class:`~skyrig.adjust.model.Layout` and, for rows that touch one eliminated object point,
  with respect to that point;
* its **group name** (:attr:`name`: the key of ``AdjustmentResult.residuals`` / ``groups`` and of
  ``Rejection.group``), its **sigma / covariance** (:meth:`get_sigma`, :meth:`get_cov` and their setters,
  used by variance component estimation, with :attr:`vce_split`),
* its **report labels**: :attr:`words` (in sentences), :attr:`components` and :attr:`units` (columns of a
  residual table), :meth:`label` (one row in words), :attr:`hints` (which parameter groups to free when
  the group misfits).

The adjustment (:class:`~skyrig.adjust.model.Model`, :func:`~skyrig.adjust.adjust`, the statistics, data
snooping and variance components) only loops over the registered types: adding an observation type is
adding a module that registers one.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:  # pragma: no cover
    from skyrig.adjust.block import Block
    from skyrig.adjust.model import Model, State

from skyrig.errors import BlockError  # noqa: F401 - re-exported (defined in skyrig.errors)

__all__ = ["ObservationType", "ParameterGroup", "Factor", "BlockError", "BalCamera", "REQUIRED", "pad_actuator", "any_on", "whitening_matrices", "check_index", "check_finite",
           "check_positive", "check_covariance", "rows_of", "sigma_rows", "covariance_rows", "indexed_rows"]


@dataclass(frozen=True)
class BalCamera:
    """The camera model of the Bundle Adjustment in the Large (BAL) problems (Agarwal et al. 2010).

    ``p = -P_xy / P_z`` (camera looks along -z, y up as skyrig's camera frame),
    ``r = 1 + k1 |p|^2 + k2 |p|^4``, observation ``= f r p`` in pixels relative to the image centre
    (x right, y up).  Intrinsics vector ``(f, k1, k2)``.
    """

    name: str
    f: float
    k1: float = 0.0
    k2: float = 0.0

    @property
    def intrinsic_names(self) -> tuple[str, ...]:
        return ("f", "k1", "k2")

    @property
    def intrinsics(self) -> NDArray[np.float64]:
        return np.array([self.f, self.k1, self.k2])

    def with_intrinsics(self, v: NDArray[np.float64]) -> "BalCamera":
        return replace(self, f=float(v[0]), k1=float(v[1]), k2=float(v[2]))


#: default of a :attr:`ObservationType.keywords` entry that a block must be given
REQUIRED: Any = object()


def pad_actuator(a: NDArray[np.float64] | None, n_heads: int, width: int) -> NDArray[np.float64]:
    """Actuator corrections ``(H, width)``: ``a`` cut or padded with zeros (higher Fourier orders)."""
    out = np.zeros((n_heads, width))
    if a is not None and a.size:
        w = min(width, a.shape[1])
        out[:, :w] = a[:, :w]
    return out


def rows_of(x: Any, shape_tail: tuple[int, ...], dtype: Any = np.float64, n: int | None = None) -> NDArray:
    """``x`` as an array ``(n,) + shape_tail`` (n from ``x`` when not given)."""
    a = np.asarray(x, dtype=dtype)
    if n is None:
        n = a.shape[0] if a.ndim else 0
    return a.reshape((n,) + tuple(shape_tail))


def sigma_rows(sigma: Any, n: int, d: int | None) -> NDArray[np.float64]:
    """A scalar or per-row sigma broadcast to ``(n, d)`` (``(n,)`` when ``d`` is None), a copy."""
    shape = (n,) if d is None else (n, d)
    return np.broadcast_to(np.asarray(sigma, dtype=np.float64), shape).copy()


def covariance_rows(rows: Any, cov_field: str, sigma_field: str, n: int, d: int, label: str | None = None) -> None:
    """Check the optional full covariance ``(n, d, d)`` in field ``cov_field`` of ``rows`` (a type's rows or a
    block; ``label``: its name in the message, default ``cov_field``); when given, the per-axis sigma field
    becomes ``sqrt(diag)`` (for reports)."""
    cv = getattr(rows, cov_field)
    if cv is None:
        return
    cv = np.asarray(cv, dtype=np.float64)
    if cv.shape != (n, d, d):
        raise BlockError(f"{label or cov_field} must have shape ({n}, {d}, {d}), got {cv.shape}")
    setattr(rows, cov_field, cv.copy())
    with np.errstate(invalid="ignore"):
        setattr(rows, sigma_field, np.sqrt(np.diagonal(cv, axis1=1, axis2=2)).copy())


def indexed_rows(rows: Any, index: str, values: str, tail: tuple[int, ...], sigma: str, cov: str, label: str) -> int:
    """Normalise rows of one station or point each: the ``index`` field (None: no rows), the observed ``values``
    ``(n,) + tail``, the ``sigma`` ``(n, 3)`` and the optional covariance ``cov`` ``(n, 3, 3)`` (``label``: its name
    in messages); returns n."""
    if getattr(rows, index) is None:
        setattr(rows, index, np.zeros(0, np.int64))
        setattr(rows, values, np.zeros((0,) + tail))
    n = len(np.asarray(getattr(rows, index)).reshape(-1))
    setattr(rows, index, rows_of(getattr(rows, index), (), np.int64, n))
    setattr(rows, values, rows_of(getattr(rows, values), tail, n=n))
    setattr(rows, sigma, sigma_rows(getattr(rows, sigma), n, 3))
    covariance_rows(rows, cov, sigma, n, 3, label)
    return n


def check_index(name: str, idx: NDArray, n: int, what: str) -> None:
    """Every ``idx`` in ``[0, n)``, else :class:`BlockError` naming the first bad entry."""
    bad = np.flatnonzero((idx < 0) | (idx >= n))
    if bad.size:
        raise BlockError(f"{name}[{bad[0]}] = {idx[bad[0]]} names an unknown {what} (have {n})")


def check_finite(name: str, a: NDArray) -> None:
    bad = np.flatnonzero(~np.isfinite(a.reshape(len(a), -1)).all(axis=1)) if len(a) else np.zeros(0, np.int64)
    if len(bad):
        raise BlockError(f"{name}[{bad[0]}] is not finite: {a[bad[0]]}")


def check_positive(name: str, a: NDArray) -> None:
    bad = np.flatnonzero(~(a.reshape(len(a), -1) > 0).all(axis=1)) if len(a) else np.zeros(0, np.int64)
    if len(bad):
        raise BlockError(f"{name}[{bad[0]}] must be > 0 (a standard deviation), got {a[bad[0]]}")


def check_covariance(name: str, cv: NDArray | None) -> None:
    """A full covariance per row ``(n, d, d)`` must be finite, symmetric and positive definite."""
    if cv is None or not len(cv):
        return
    check_finite(name, cv)
    asym = np.abs(cv - np.swapaxes(cv, 1, 2)).max(axis=(1, 2)) > 1e-9 * np.abs(cv).max(axis=(1, 2))
    bad = np.flatnonzero(asym | ~(np.linalg.eigvalsh(0.5 * (cv + np.swapaxes(cv, 1, 2)))[:, 0] > 0))
    if bad.size:
        raise BlockError(f"{name}[{bad[0]}] is not a symmetric positive definite covariance: {cv[bad[0]].tolist()}")


def whitening_matrices(cov: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(n, d, d)`` upper Cholesky factors ``U`` of the inverse covariances, ``Σ^-1 = U^T U``.

    Parameters
    ----------
    cov
        ``(n, d, d)`` symmetric positive definite covariances (observation units squared).
    """
    if len(cov) == 0:
        return np.zeros(cov.shape)
    L = np.linalg.cholesky(np.linalg.inv(cov))
    return np.swapaxes(L, 1, 2).copy()


@dataclass
class Factor:
    """Whitened residuals and Jacobians of one observation group (see :mod:`skyrig.adjust.model`).

    Attributes
    ----------
    name
        The group name of the observation type (``"image"``, ``"control"``, ``"gnss"``, ``"imu"``,
        ``"distance"``, ``"prior:<group>"``...).
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
    whiten
        ``(n, d, d)`` whitening matrices of rows with a full covariance (residual = ``whiten @ v``), or
        None when the rows are whitened by ``sigma`` alone.
    """

    name: str
    r: NDArray[np.float64]
    sigma: NDArray[np.float64]
    jc: NDArray[np.float64] | None = None
    cols: NDArray[np.int64] | None = None
    point: NDArray[np.int64] | None = None
    jp: NDArray[np.float64] | None = None
    weight: NDArray[np.float64] | None = None
    whiten: NDArray[np.float64] | None = None
    #: ``(n,)`` rows that could not be evaluated (a point behind its camera...; image rows), None = none
    bad: NDArray[np.bool_] | None = None
    #: observations the rows stand for beyond their own count (a type that reduces many observations to a few
    #: square-root rows per nuisance group, e.g. the laser points of a plane; counted in the redundancy)
    n_extra: int = 0

    def unwhitened(self) -> NDArray[np.float64]:
        """``(n, d)`` residuals in observation units (computed minus observed)."""
        if self.whiten is not None:
            return np.asarray(np.linalg.solve(self.whiten, self.r[:, :, None])[:, :, 0], dtype=np.float64)
        return self.r * self.sigma

    def __len__(self) -> int:
        return len(self.r)


def any_on(cols: NDArray[np.int64]) -> NDArray[np.bool_]:
    """``(n,)`` True for the rows of a column table ``(n, ...)`` with at least one estimated column (>= 0)."""
    c = np.asarray(cols)
    return np.asarray((c >= 0).reshape(len(c), -1).any(axis=1), dtype=bool) if c.size else np.zeros(len(c), bool)


class ObservationType:
    """One observation type (see the module docstring); subclasses set the class attributes and override
    :meth:`count`, :meth:`evaluate`, :meth:`varying` and :meth:`label` at least."""

    #: group name: ``Factor.name`` of its rows (a type emitting several factors names them ``name:<part>``)
    name: ClassVar[str] = ""
    #: the group in words, in sentences ("GNSS observations ...")
    words: ClassVar[str] = ""
    #: report labels of the components of one row and their unit
    components: ClassVar[tuple[str, ...]] = ()
    units: ClassVar[str] = ""
    #: evaluation order (the order of the factors; the image factor comes first)
    order: ClassVar[float] = 50.0
    #: the group's residuals are tested by data snooping and rejected rows get weight 0
    snooped: ClassVar[bool] = True
    #: data snooping may reject at most ``snooping_max_group_share`` of this group (an implausible share
    #: means a model error, see :func:`skyrig.adjust.adjust`)
    share_checked: ClassVar[bool] = True
    #: ``(config parameter group, what it models in words)``: what to free when this group misfits
    hints: ClassVar[tuple[tuple[str, str], ...]] = ()
    #: parameter groups (``Unknowns`` field names) that only this kind of observation determines: they are
    #: estimated only when a block has rows of a type naming them (the GNSS lever arm, datum and strip shifts)
    parameters: ClassVar[tuple[str, ...]] = ()
    #: words for the datum this group fixes (a free network with such rows is an error); "" = none
    datum_words: ClassVar[str] = ""
    #: default axis sets of variance component estimation, None = not estimated for this group
    vce_split: ClassVar[tuple[tuple[int, ...], ...] | None] = None
    #: names of the fields of the type's data object (:meth:`data`) holding the group's sigma ``(n, d)`` and
    #: optional covariance ``(n, d, d)``; None: its attributes ``sigma`` / ``cov``
    sigma_field: ClassVar[str | None] = None
    cov_field: ClassVar[str | None] = None
    #: the class of the type's rows (a data class of the type's module, kept in ``block.observations[name]``)
    #: for the built-in types that a :class:`~skyrig.adjust.block.Block` also takes as its own keywords
    rows: ClassVar[type | None] = None
    #: ``(Block keyword, attribute of rows, default)`` of those keywords (``REQUIRED``: no default)
    keywords: ClassVar[tuple[tuple[str, str, Any], ...]] = ()

    def rows_from(self, given: Any, flat: dict[str, Any]) -> Any:
        """The rows object from a given one (copied, not shared) with ``flat`` keywords of the block (popped)
        overriding its attributes; from the keywords and defaults alone when ``given`` is None."""
        vals: dict[str, Any] = {}
        for kw, attr, default in self.keywords:
            if kw in flat:
                vals[attr] = flat.pop(kw)
            elif given is not None:
                vals[attr] = getattr(given, attr)
            elif default is REQUIRED:
                raise TypeError(f"Block() missing required argument {kw!r}")
            else:
                vals[attr] = default() if callable(default) else default
        assert self.rows is not None
        return self.rows(**vals)

    # ------------------------------------------------------------------ data
    def data(self, block: "Block") -> Any:
        """The type's data object in ``block.observations`` (None when absent)."""
        return block.observations.get(self.name)

    def count(self, block: "Block") -> int:
        """Number of rows of this type in ``block``."""
        d = self.data(block)
        return 0 if d is None else len(d)

    def tested_count(self, block: "Block") -> int:
        """Rows that take part in the adjustment (for the share of rejections)."""
        return self.count(block)

    def normalise(self, block: "Block") -> None:
        """Bring the type's data in ``block`` to canonical arrays (called by ``Block.__post_init__``)."""
        d = self.data(block)
        if d is not None and hasattr(d, "normalise"):
            d.normalise(block)

    def validate(self, block: "Block") -> None:
        """Raise :class:`~skyrig.adjust.block.BlockError` naming the first inconsistency of this type's data."""
        d = self.data(block)
        if d is not None and hasattr(d, "validate"):
            d.validate(block)

    def copy_data(self, data: Any) -> Any:
        """A deep copy of a data object (``Block.copy``)."""
        import copy

        return copy.deepcopy(data)

    def reduced_points(self, block: "Block") -> NDArray[np.int64] | None:
        """Indices of the object points whose rows of this type also touch reduced columns (a plane through a
        tie point observed by laser points, a distance's end points): the layout estimates them in the reduced
        part (``Layout.rpoint``); None = none."""
        return None

    def controlled_points(self, block: "Block") -> NDArray[np.bool_] | None:
        """``(P,)`` points this type determines without rays (control), None = none."""
        return None

    # ------------------------------------------------------------------ sigma / covariance
    def get_sigma(self, block: "Block") -> NDArray[np.float64]:
        d = self.data(block)
        if d is None:
            return np.zeros((0, len(self.components)))
        return getattr(d, self.sigma_field or "sigma")

    def set_sigma(self, block: "Block", value: NDArray[np.float64]) -> None:
        setattr(self.data(block), self.sigma_field or "sigma", value)

    def get_cov(self, block: "Block") -> NDArray[np.float64] | None:
        d = self.data(block)
        return None if d is None else getattr(d, self.cov_field or "cov", None)

    def set_cov(self, block: "Block", value: NDArray[np.float64] | None) -> None:
        setattr(self.data(block), self.cov_field or "cov", value)

    # ------------------------------------------------------------------ model
    def initial_weight(self, block: "Block") -> NDArray[np.float64] | None:
        """``(n,)`` starting weights (1; 0 for rows not used, e.g. check points); None: no weights."""
        return np.ones(self.count(block))

    def prepare(self, model: "Model") -> Any:
        """Per-model constants (whitening matrices, index tables), kept in ``model.cache[name]``."""
        return None

    def present(self, model: "Model") -> bool:
        """True when :meth:`evaluate` gives rows for ``model``."""
        return self.count(model.block) > 0

    def evaluate(self, model: "Model", state: "State", jac: bool) -> list["Factor"]:
        """Whitened residuals (and Jacobians when ``jac``) of the type's rows at ``state``.

        A row touches reduced columns (``cols``/``jc``) or one eliminated point (``point``/``jp``), not
        both: only the image rows couple cameras and eliminated points (the Schur structure is built from
        them); a point that such a row needs is estimated in the reduced part (``Layout.rpoint``)."""
        raise NotImplementedError

    def varying(self, model: "Model", factor: "Factor") -> NDArray[np.bool_]:
        """``(n,)`` rows of ``factor`` that depend on at least one unknown (the others are constants of
        the adjustment, not observations)."""
        return np.ones(len(factor), bool)

    def fixes_datum(self, model: "Model") -> bool:
        """True when the group's rows fix (part of) the datum (see :attr:`datum_words`)."""
        return bool(self.datum_words) and self.count(model.block) > 0

    # ------------------------------------------------------------------ reports
    def label(self, block: "Block", i: int) -> str:
        """Row ``i`` in words."""
        return f"{self.name}[{i}]"


class ParameterGroup:
    """Unknowns that an observation module declares for itself (a clock offset per station, a scanner's
    lever arm, boresight and range offset...), so that a new kind of unknown lands in the module that
    observes it.

    A group is a table ``(n_owners, len(components))`` of values: its starting values are
    ``block.parameters[name]`` (:meth:`initial`; zeros when the block has none), the adjusted ones are written
    back there in the result's block; its mode (``"fixed"``, ``"free"`` or ``"weighted"``) and prior sigma
    per component come from ``AdjustConfig.unknowns.groups`` / ``group_sigma``; its columns are
    ``model.layout.groups[name]`` (-1 = not estimated), its current values ``state.groups[name]``, its labels
    ``(name, owner, component)``.  Columns come after every built-in group's (the built-in layout is
    unchanged).  A ``"weighted"`` group gets the prior ``prior:<name>`` (``(current - start) / sigma``).

    Register an instance with :func:`skyrig.adjust.factors.register_group`; an observation type reads it in
    its :meth:`ObservationType.evaluate` (values ``state.groups[name]``, Jacobian columns
    ``model.layout.groups[name]``).
    """

    #: group name: key of ``block.parameters``, ``State.groups``, ``Layout.groups`` and of the config's modes
    name: ClassVar[str] = ""
    #: the names of one owner's components (columns), with their unit in the name (``dt_s``, ``x_m``)
    components: ClassVar[tuple[str, ...]] = ()
    #: what the group is, in words (reports, hints)
    words: ClassVar[str] = ""

    def owners(self, block: Any) -> list[str]:
        """Names of the group's owners (rows), e.g. the station names; default: one owner named after the group."""
        return [self.name]

    def initial(self, block: Any) -> NDArray[np.float64]:
        """``(n_owners, n_components)`` starting values: ``block.parameters[name]`` or zeros."""
        shape = (len(self.owners(block)), len(self.components))
        v = block.parameters.get(self.name)
        if v is None:
            return np.zeros(shape)
        v = np.asarray(v, dtype=np.float64)
        if v.shape != shape:
            raise BlockError(f"parameters[{self.name!r}] must have shape {shape}, got {v.shape}")
        return v.copy()

    def estimated(self, block: Any) -> bool:
        """Whether the block has what determines the group (default: always; e.g. rows of its observation type)."""
        return True

    def retract(self, value: NDArray[np.float64], step: NDArray[np.float64]) -> NDArray[np.float64]:
        """``value`` moved by the step ``(n_owners, n_components)`` (default additive; a rotation overrides)."""
        return value + step

    def similarity_motion(self, values: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """How the group's values move when the whole block is moved by a similarity (a free network's datum):
        ``(n_owners, n_components, 7)`` derivatives with respect to a translation (x, y, z), a small rotation
        about x, y, z and a scale, in the columns' order of
        :func:`skyrig.adjust.solver.inner_constraint_basis`; None (default): the values do not move (offsets in
        a body frame, times, scale factors)."""
        return None
