"""Sparse Levenberg-Marquardt with the Schur complement on object points.

Normal equations
----------------
With whitened residuals ``r`` and Jacobian ``J = [J_c  J_p]`` (reduced unknowns, points)::

    [ U   W ] [dc]     [g_c]        U = J_c^T J_c,  W = J_c^T J_p,  V = J_p^T J_p (3x3 blocks per point)
    [ W^T V ] [dp] = - [g_p]        g = J^T r

The points are eliminated: ``S = U - W V^-1 W^T``, ``S dc = -(g_c - W V^-1 g_p)``,
``dp = -V^-1 (g_p + W^T dc)``.  Image observations are grouped per unit (images with the same reduced
columns: a station when only poses are free) so that ``W`` is a block sparse (BSR) matrix with one
``k x 3`` block per (unit, point) and the product ``W V^-1 W^T`` runs in scipy's compiled BSR kernels; a
selection matrix maps each unit's ``k`` local columns to the global reduced columns (shared intrinsics,
boresights...).

Linear solver
-------------
``S`` (Jacobi-scaled) is factored densely (LAPACK Cholesky) up to a few hundred (``solve_reduced``) or
1500 (:class:`SchurEngine`) unknowns; above, :mod:`skyrig.adjust.linalg` chooses (reason logged and kept
in ``SolveInfo.linear_solver``): supernodal CHOLMOD through cvxopt with a METIS nested-dissection order
of the per-camera/station graph and the symbolic analysis done once per adjustment; SuperLU
(``scipy.sparse.linalg.splu``, symmetric mode, every pivot checked positive) when cvxopt is missing;
preconditioned conjugate gradients (Schur-Jacobi) when the predicted factor exceeds the memory or flop
limits.  CHOLMOD through ``cholespy`` (reference BLAS, 2x to 10x slower) stays selectable
(``method="cholespy"``).  A free network (``datum="free"``) adds inner constraints on the station poses
(``S + a G G^T``, G the 7 similarity motions of the poses) and always uses the dense path.

Compiled engine
---------------
:func:`levenberg_marquardt` runs on :class:`~skyrig.adjust.schur_engine.SchurEngine` (numba,
:mod:`skyrig.adjust.schur_engine`) when numba is installed: the reduced
system is accumulated per observation directly into a block pattern fixed for the whole solve, per
*unit* (the distinct reduced-column sets of the image rows: one per station when only poses are free,
so that all heads of a rig exposure share one 6 x 6 block), and trust-region retries reuse everything
but the damped point inverses and the Schur product.  :func:`assemble` / :func:`schur_matrix` (scipy
sparse BSR products) remain the reference path (``engine="scipy"``) and serve the statistics.

Damping follows Ceres: ``(A + diag(A)/radius) d = -g`` with the trust-region radius grown or shrunk
by the gain ratio.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.linalg
import scipy.sparse as sp
from numpy.typing import NDArray

from skyrig.adjust.model import Factor, Layout, Model, State
from skyrig.errors import ConfigError, SingularError  # noqa: F401 - SingularError re-exported

logger = logging.getLogger(__name__)

try:  # CHOLMOD on the reference BLAS (kept selectable: ``method="cholespy"``)
    import cholespy as _cholespy
except ImportError:  # pragma: no cover - depends on the environment
    _cholespy = None

from skyrig.adjust import linalg as _linalg
from skyrig.adjust.linalg import _blas_single_thread
from skyrig.adjust.schur_engine import (  # noqa: F401 - the compiled engine, re-exported
    _K, HAVE_NUMBA, SchurEngine, _numba, _predicted_decrease, _robust, _units, column_sets, set_normals)

#: the reduced solver of :func:`solve_reduced` when called with ``method="auto"`` (the statistics):
#: ``"auto"`` (dense up to 400 unknowns, CHOLMOD through cvxopt above, SuperLU without cvxopt) or a
#: method name
REDUCED_SOLVER = "auto"

__all__ = ["Normal", "SolveInfo", "SchurEngine", "assemble", "solve_reduced", "levenberg_marquardt", "SingularError",
           "inner_constraint_basis", "HAVE_CHOLMOD", "HAVE_NUMBA"]

HAVE_CHOLMOD = _linalg.HAVE_CVXOPT_CHOLMOD

DENSE_LIMIT = 4000


@dataclass
class Normal:
    """Normal equations at one state (see module docstring)."""

    cost: float
    gc: NDArray[np.float64]
    U: sp.csr_matrix
    V: NDArray[np.float64]
    gp: NDArray[np.float64]
    Wb: sp.bsr_matrix | None
    P: sp.csr_matrix | None

    @property
    def wb(self) -> sp.bsr_matrix:
        """``Wb`` of normal equations that have image rows (point coupling blocks)."""
        if self.Wb is None:
            raise ValueError("normal equations without image rows have no point coupling (Wb)")
        return self.Wb

    @property
    def p(self) -> sp.csr_matrix:
        """``P`` (unit columns -> reduced columns) of normal equations that have image rows."""
        if self.P is None:
            raise ValueError("normal equations without image rows have no unit selection (P)")
        return self.P


def factor_cost(factors: list[Factor], huber_k: float | None = None) -> float:
    return float(sum(_robust(f, huber_k)[1] for f in factors))


def assemble(factors: list[Factor], layout: Layout, image_group: NDArray[np.int64] | None,
             huber_k: float | None = None, chunk: int = 200_000) -> Normal:
    """Normal equations from factors.

    ``image_group`` ``(N,)`` is the image of each row of the ``"image"`` factor (rows of one image share
    their reduced columns); the image factor is the only one with both reduced columns and points.
    """
    n_c, n_p = layout.n_c, layout.n_p
    cost = 0.0
    gc = np.zeros(n_c)
    gp = np.zeros((n_p, 3))
    V = np.zeros((n_p, 3, 3))
    rows: list[NDArray] = []
    colsl: list[NDArray] = []
    vals: list[NDArray] = []
    Wb = P = None
    for f in factors:
        sw, c = _robust(f, huber_k)
        cost += c
        r = f.r * sw[:, None]
        if f.jp is not None and f.point is not None and _K is not None and n_p:
            _K["point_normals"](np.ascontiguousarray(f.point, np.int64), np.ascontiguousarray(f.jp),
                                np.ascontiguousarray(f.r), np.ascontiguousarray(sw * sw), V, gp)
        elif f.jp is not None and f.point is not None:
            has = f.point >= 0
            pt = np.where(has, f.point, 0)
            jp = f.jp * (sw * has)[:, None, None]
            jtj = np.einsum("nda,ndb->nab", jp, jp).reshape(-1, 9)
            for a in range(9):
                V.reshape(-1, 9)[:, a] += np.bincount(pt, weights=jtj[:, a], minlength=n_p)
            jtr = np.einsum("nda,nd->na", jp, r)
            for a in range(3):
                gp[:, a] += np.bincount(pt, weights=jtr[:, a], minlength=n_p)
        if f.jc is None or f.cols is None or f.cols.shape[1] == 0:
            continue
        if f.jp is not None and f.name == "image" and image_group is not None:
            Wb, P, U_img, g_img = _image_blocks(f, f.jc * sw[:, None, None], r, sw, layout, image_group, chunk)
            gc += g_img
            rows.append(U_img.row)
            colsl.append(U_img.col)
            vals.append(U_img.data)
            continue
        # one block per distinct column set (a laser plane's rows share theirs), rows a chunk at a time
        cols, srow = column_sets(f.cols)
        jtj, g = set_normals(f.jc, f.r, sw, srow, len(cols))
        valid = cols >= 0
        gc += np.bincount(cols[valid], weights=g[valid], minlength=n_c)
        ii = np.broadcast_to(cols[:, :, None], jtj.shape)
        jj = np.broadcast_to(cols[:, None, :], jtj.shape)
        m = (ii >= 0) & (jj >= 0)
        rows.append(ii[m])
        colsl.append(jj[m])
        vals.append(jtj[m])
    if rows:
        U = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(colsl))),
                          shape=(n_c, n_c)).tocsr()
    else:
        U = sp.csr_matrix((n_c, n_c))
    return Normal(cost, gc, U, V, gp, Wb, P)


def _image_blocks(f: Factor, jc: NDArray, r: NDArray, sw: NDArray, layout: Layout, group: NDArray[np.int64],
                  chunk: int):
    n_c, n_p = layout.n_c, layout.n_p
    n, d, k = jc.shape
    # one k x k block per unit (a station when only poses are free)
    gcols, group = _units(f.cols, group)  # type: ignore[arg-type]
    n_img = len(gcols)
    # U blocks and gradient per image
    Ub = np.zeros((n_img, k * k))
    gb = np.zeros((n_img, k))
    Wobs = None
    if _K is not None:  # compiled: U, g and the W block of every row in one pass (jc, r unscaled, w = sw^2)
        uo = np.argsort(group, kind="stable")
        uptr = np.zeros(n_img + 1, np.int64)
        uptr[1:] = np.cumsum(np.bincount(group, minlength=n_img))
        pt = np.ascontiguousarray(f.point, np.int64) if (f.point is not None and n_p) else np.full(n, -1, np.int64)
        jp0 = np.ascontiguousarray(f.jp) if (f.jp is not None and n_p) else np.zeros((n, d, 3))
        Wt = np.empty((n, 3, k))  # the kernel writes W transposed (its Schur layout)
        Ub3 = Ub.reshape(n_img, k, k)
        _K["unit_normals"](uptr, uo, np.ascontiguousarray(f.jc), jp0, np.ascontiguousarray(f.r),
                           np.ascontiguousarray(sw * sw), pt, Ub3, gb, Wt, np.arange(n, dtype=np.int64))
        Wobs = np.ascontiguousarray(np.swapaxes(Wt, 1, 2))
        del Wt
    for s0 in range(0, n if Wobs is None else 0, chunk):
        sl = slice(s0, s0 + chunk)
        jtj = np.einsum("nda,ndb->nab", jc[sl], jc[sl]).reshape(-1, k * k)
        jtr = np.einsum("nda,nd->na", jc[sl], r[sl])
        gi = group[sl]
        for a in range(k * k):
            Ub[:, a] += np.bincount(gi, weights=jtj[:, a], minlength=n_img)
        for a in range(k):
            gb[:, a] += np.bincount(gi, weights=jtr[:, a], minlength=n_img)
    # selection matrix: local column (image g, j) -> global column
    valid = gcols >= 0
    lr = (np.arange(n_img)[:, None] * k + np.arange(k)[None, :])[valid]
    P = sp.csr_matrix((np.ones(lr.size), (lr, gcols[valid])), shape=(n_img * k, n_c))
    gc = P.T @ gb.reshape(-1)
    # U as coo in global columns
    ii = np.broadcast_to(gcols[:, :, None], (n_img, k, k))
    jj = np.broadcast_to(gcols[:, None, :], (n_img, k, k))
    m = (ii >= 0) & (jj >= 0)
    U = sp.coo_matrix((Ub.reshape(n_img, k, k)[m], (ii[m], jj[m])), shape=(n_c, n_c))
    # W blocks (k x 3) per observation, sorted by image
    if n_p == 0 or f.point is None:
        return None, P, U, gc
    has = f.point >= 0
    order = np.flatnonzero(has)
    key = group[order] * n_p + f.point[order]
    srt = np.argsort(key, kind="stable")
    order, key = order[srt], key[srt]
    if Wobs is not None:
        blocks = Wobs[order]
    else:
        jp = f.jp[order] * sw[order, None, None]  # type: ignore[index]  # jc already carries the row scale; jp must too
        blocks = np.einsum("nda,ndb->nab", jc[order], jp)
    first = np.flatnonzero(np.concatenate([[True], key[1:] != key[:-1]])) if len(key) else np.zeros(0, np.int64)
    if len(first) < len(key):  # one point seen twice in one unit (two heads): sum the blocks
        blocks = np.add.reduceat(blocks, first, axis=0)
    key = key[first]
    unit = key // max(n_p, 1)
    indptr = np.zeros(n_img + 1, np.int64)
    indptr[1:] = np.cumsum(np.bincount(unit, minlength=n_img))
    Wb = sp.bsr_matrix((blocks, key - unit * n_p, indptr), shape=(n_img * k, n_p * 3))
    return Wb, P, U, gc


def inner_constraint_basis(state: State, layout: Layout) -> NDArray[np.float64]:
    """``(n_c, 7)`` similarity motions of the free station poses (translation, rotation, scale), unit columns.

    A rotation ``ω`` of the whole block about the pose centroid moves a centre by ``ω x (C - c0)`` and
    a right-perturbed rotation by ``dθ = R^T ω``; a scale ``μ`` moves a centre by ``μ (C - c0)``.
    """
    cols = layout.pose
    on = (cols >= 0).all(axis=1)
    G = np.zeros((layout.n_c, 7))
    if not on.any():
        return G
    c0 = state.C[on].mean(axis=0)

    def move(pos_cols: NDArray[np.int64], d: NDArray[np.float64]) -> None:
        """Translation and rotation columns of positions ``d (m, 3)`` (from ``c0``) at ``pos_cols (m, 3)``."""
        for a in range(3):
            G[pos_cols[:, a], a] = 1.0
            G[pos_cols, 3 + a] = np.cross(np.eye(3)[a], d)

    dC = state.C[on] - c0
    move(cols[on, :3], dC)
    for a in range(3):
        G[cols[on, 3:], 3 + a] = state.R[on, a, :]  # R^T e_a
    G[cols[on, :3], 6] = dC
    _group_motions(G, state, layout)
    if layout.has_rpoint:
        # points estimated in the reduced part (end points of distances) move with the block; the
        # distances fix the scale, so the scale is no null-space motion then
        red = (layout.rpoint_cols >= 0).all(axis=1)
        move(layout.rpoint_cols[red], state.X[red] - c0)
        G[:, 6] = 0.0
    nrm = np.linalg.norm(G, axis=0)
    nrm[nrm == 0] = 1.0
    return G / nrm


def _group_motions(G: NDArray[np.float64], state: State, layout: Layout) -> None:
    """The columns of ``G`` for the estimated parameter groups that move with the block (world-frame vectors such
    as a station's velocity: :meth:`~skyrig.adjust.factors.base.ParameterGroup.similarity_motion`)."""
    from skyrig.adjust.factors import parameter_groups

    for g in parameter_groups():
        cols = layout.groups.get(g.name)
        if cols is None or not (cols >= 0).any():
            continue
        m = g.similarity_motion(np.asarray(state.groups[g.name], float))
        if m is None:
            continue
        on = cols >= 0
        G[cols[on]] = m[on]


def _splu_spd(indptr: NDArray, indices: NDArray, data: NDArray, n: int, b: NDArray) -> NDArray[np.float64]:
    """Solve a Jacobi-scaled symmetric positive definite CSR system with SuperLU (symmetric mode, minimum
    degree ordering on ``A + A^T``, diagonal pivots); raises :class:`SingularError` unless every pivot is
    positive (``> 1e-14``: the scaled diagonal is 1, so smaller pivots mean a numerically singular matrix).

    SuperLU's supernodal kernels run on the BLAS scipy links (OpenBLAS), which makes it several times
    faster here than CHOLMOD as the cholespy wheel ships it (reference BLAS).
    """
    import scipy.sparse.linalg as spl

    A = sp.csc_matrix(sp.csr_matrix((data, indices, indptr), shape=(n, n)))  # symmetric: CSR == CSC^T
    try:
        lu = spl.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                      options={"SymmetricMode": True})
    except RuntimeError as e:
        raise SingularError(f"the reduced normal matrix is singular ({e})") from e
    piv = lu.U.diagonal()
    if not (piv.min(initial=1.0) > 1e-14) or np.any(lu.perm_r != lu.perm_c):
        raise SingularError("the reduced normal matrix is not positive definite "
                            f"(smallest pivot {piv.min(initial=1.0):.3g})")
    return lu.solve(b)



def solve_reduced(S: sp.spmatrix, rhs: NDArray[np.float64], G: NDArray[np.float64] | None = None,
                  method: str = "auto") -> NDArray[np.float64]:
    """Solve the (symmetric positive definite) reduced system ``S x = rhs`` (``rhs`` ``(n,)`` or ``(n, m)``).

    Jacobi scaling, then CHOLMOD (cholespy), dense Cholesky or SuperLU (module docstring).  With ``G``
    (free network) ``S + a G G^T`` is solved densely.  Raises :class:`SingularError` when ``S`` is not
    positive definite.
    """
    n = S.shape[0]
    if n == 0:
        return np.zeros_like(rhs)
    d = S.diagonal()
    if np.any(d <= 0) or not np.all(np.isfinite(d)):
        raise SingularError(f"{int(np.sum(d <= 0))} reduced unknown(s) have no observations")
    s = 1.0 / np.sqrt(d)
    Ss = sp.csr_matrix(S.multiply(s[:, None]).multiply(s[None, :]))
    b = rhs * (s if rhs.ndim == 1 else s[:, None])
    if method == "auto":
        method = REDUCED_SOLVER
    if method == "auto":
        method = "dense" if (G is not None or n <= 400) else ("cholmod" if _linalg.HAVE_CVXOPT_CHOLMOD else "splu")
    try:
        if method == "dense":
            A = Ss.toarray()
            if G is not None:
                Gs = G / s[:, None]
                Gs /= np.linalg.norm(Gs, axis=0).clip(1e-300)
                A = A + Gs @ Gs.T
            with _blas_single_thread():
                c = scipy.linalg.cho_factor(A, lower=True, check_finite=False)
                x = scipy.linalg.cho_solve(c, b, check_finite=False)
        elif method == "cholespy":
            coo = Ss.tocoo()
            solver = _cholespy.CholeskySolverD(n, coo.row.astype(np.int32), coo.col.astype(np.int32),
                                               coo.data, _cholespy.MatrixType.COO)
            x = np.zeros_like(b)
            solver.solve(np.ascontiguousarray(b), x)
        elif method == "cholmod" and _linalg.HAVE_CVXOPT_CHOLMOD:
            Ss.sort_indices()
            x = _linalg.ReducedSolver(Ss.indptr, Ss.indices, "cholmod").solve(Ss.data, b)
        else:
            x = _splu_spd(Ss.indptr, Ss.indices, Ss.data, n, b)
    except _linalg.NotPositiveDefinite as e:
        raise SingularError(f"the reduced normal matrix is not positive definite ({e})") from e
    except (np.linalg.LinAlgError, ValueError, RuntimeError) as e:
        raise SingularError(f"the reduced normal matrix is not positive definite ({e})") from e
    if not np.all(np.isfinite(x)):
        raise SingularError("the reduced normal matrix is singular (non-finite solution)")
    return x * (s if x.ndim == 1 else s[:, None])


def point_inverses(V: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(n_p, 3, 3)`` inverses of the point blocks; :class:`SingularError` (``.points``: the free-point indices)
    when a point is not determined by its observations."""
    if not len(V):
        return np.zeros((0, 3, 3))
    try:
        return np.linalg.inv(V)
    except np.linalg.LinAlgError:
        ev = np.linalg.eigvalsh(V)
        bad = np.flatnonzero(~(ev[:, 0] > 1e-12 * np.abs(ev[:, -1]).clip(1e-300)))
        err = SingularError(f"{bad.size} object point(s) not determined by their observations")
        err.points = bad  # free-point indices
        raise err from None


def schur_matrix(N: Normal, lam: float = 0.0, diag_min: float = 1e-6):
    """``S``, its right-hand side and the damped inverse point blocks for damping ``lam``."""
    n_p = N.V.shape[0]
    U = N.U
    V = N.V
    if lam > 0:
        du = np.clip(U.diagonal(), diag_min, None)
        U = U + sp.diags(lam * du)
        dv = np.clip(np.diagonal(V, axis1=1, axis2=2), diag_min, None)
        V = V + lam * dv[:, :, None] * np.eye(3)[None]
    Vinv = point_inverses(V)
    S = U
    rhs = -N.gc.copy()
    if N.Wb is not None and n_p:
        Vb = sp.bsr_matrix((Vinv, np.arange(n_p), np.arange(n_p + 1)), shape=(3 * n_p, 3 * n_p))
        WV = N.Wb @ Vb
        T = (WV @ N.wb.T).tocsr()
        S = (U - N.p.T @ T @ N.P).tocsr()
        rhs = rhs + N.p.T @ (WV @ N.gp.reshape(-1))
    return sp.csr_matrix(S), rhs, Vinv


def back_substitute(N: Normal, Vinv: NDArray[np.float64], dc: NDArray[np.float64]) -> NDArray[np.float64]:
    """Point steps ``(n_p, 3)`` from the reduced step."""
    t = N.gp.reshape(-1).copy()
    if N.Wb is not None and len(Vinv):
        t += N.wb.T @ (N.p @ dc)
    return -np.einsum("pij,pj->pi", Vinv, t.reshape(-1, 3))


@dataclass
class SolveInfo:
    """What the optimiser did.

    ``iterations`` counts accepted steps; ``unsuccessful`` the rejected trust-region trials (Ceres's
    "iterations" are the sum of both); ``linearizations`` the Jacobian evaluations.
    """

    iterations: int = 0
    initial_cost: float = float("nan")
    final_cost: float = float("nan")
    converged: bool = False
    message: str = ""
    wall_s: float = 0.0
    history: list[tuple[int, float, float]] = field(default_factory=list)
    unsuccessful: int = 0
    engine: str = ""
    #: the reduced system's solver and why it was chosen (:mod:`skyrig.adjust.linalg`)
    linear_solver: str = ""


class _ScipyEngine:
    """The reference path: :func:`assemble`, :func:`schur_matrix`, :func:`solve_reduced`."""

    def __init__(self, layout: Layout, image_group: NDArray[np.int64]) -> None:
        self.layout, self.group = layout, image_group

    def linearize(self, factors: list[Factor], huber_k: float | None = None) -> float:
        self.N = assemble(factors, self.layout, self.group, huber_k)
        return self.N.cost

    def gradient_max(self) -> float:
        N = self.N
        return float(max(np.abs(N.gc).max(initial=0.0), np.abs(N.gp).max(initial=0.0)))

    def solve(self, lam: float, G: NDArray[np.float64] | None = None
              ) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        N = self.N
        S, rhs, Vinv = schur_matrix(N, lam)
        dc = solve_reduced(S, rhs, G)
        dp = back_substitute(N, Vinv, dc) if self.layout.n_p else np.zeros((0, 3))
        return dc, dp, _predicted_decrease(lam, N.U.diagonal(), N.V, N.gc, N.gp, dc, dp, 1e-6)


def levenberg_marquardt(
    model: Model,
    state: State,
    max_iterations: int = 50,
    function_tolerance: float = 1e-6,
    parameter_tolerance: float = 1e-8,
    gradient_tolerance: float = 1e-10,
    huber_k: float | None = None,
    free_datum: bool = False,
    callback: Callable[[int, float, float], None] | None = None,
    initial_radius: float = 1e4,
    engine: str = "auto",
    linear_solver: str | None = None,
    engine_at_start: "SchurEngine | None" = None,
) -> tuple[State, SolveInfo]:
    """Minimise ``0.5 * sum(rho(|r|^2))`` over the model's unknowns starting from ``state``.

    Trust-region Levenberg-Marquardt as Ceres's: ``(A + D / radius) d = -g`` with ``D = diag(A)``
    clipped below at 1e-6, a step accepted when its gain ratio exceeds ``MIN_RELATIVE_DECREASE`` (1e-3),
    radius grown by ``1 / max(1/3, 1 - (2 rho - 1)^3)`` after a successful step and divided by a doubling
    factor after a rejected one.  Stops as Ceres does, testing every trial step before its quality:
    relative cost change (either sign) below ``function_tolerance``, relative step below
    ``parameter_tolerance``, or max gradient below ``gradient_tolerance``; such a final trial is kept
    only when it lowers the cost.  ``engine``: ``"numba"`` (:class:`SchurEngine`), ``"scipy"`` (the sparse
    matrix reference path) or ``"auto"`` (numba when installed).  ``linear_solver``: the numba engine's
    reduced solver (``"auto"``, ``"dense"``, ``"cholmod"``, ``"splu"``, ``"pcg"``...; default
    :data:`LINEAR_SOLVER`), dense below :data:`ENGINE_DENSE_LIMIT` unknowns when ``"auto"``.
    ``engine_at_start``: a :class:`SchurEngine` of this model already linearised at ``state`` without
    robust weights (:func:`skyrig.adjust.adjust.check_datum`'s); used instead of a first evaluation and
    linearisation when the numba engine runs without ``huber_k`` (same values).
    """
    if engine == "auto":
        engine = "numba" if HAVE_NUMBA else "scipy"
    threads = None
    if HAVE_NUMBA and model.block.n_observations < SERIAL_BELOW:
        # small blocks: the compiled kernels' parallel regions cost more in thread hand-offs than they save
        threads = _numba.get_num_threads()
        _numba.set_num_threads(1)
    try:
        return _levenberg_marquardt(model, state, max_iterations, function_tolerance, parameter_tolerance,
                                    gradient_tolerance, huber_k, free_datum, callback, initial_radius, engine,
                                    linear_solver or LINEAR_SOLVER, engine_at_start)
    finally:
        if threads is not None:
            _numba.set_num_threads(threads)


#: the compiled engine's reduced solver (see :class:`SchurEngine`) and its dense size limit
LINEAR_SOLVER = "auto"
ENGINE_DENSE_LIMIT = 1500

#: a trial step is accepted when its gain ratio (actual / predicted decrease) exceeds this (Ceres's
#: ``min_relative_decrease``)
MIN_RELATIVE_DECREASE = 1e-3

#: below this many image observations the compiled kernels run on one thread
SERIAL_BELOW = 100_000


def _levenberg_marquardt(model: Model, state: State, max_iterations: int, function_tolerance: float,
                         parameter_tolerance: float, gradient_tolerance: float, huber_k: float | None,
                         free_datum: bool, callback: Callable[[int, float, float], None] | None,
                         initial_radius: float, engine: str, linear_solver: str,
                         engine_at_start: "SchurEngine | None" = None) -> tuple[State, SolveInfo]:
    t0 = time.perf_counter()
    lay = model.layout
    info = SolveInfo()
    group = model.block.obs_image
    prepared = engine_at_start if (engine == "numba" and huber_k is None and engine_at_start is not None
                                   and engine_at_start.layout is lay) else None
    factors = model.evaluate(state) if prepared is None else []
    if prepared is not None:
        SchurEngine._check_solver(linear_solver)
        eng: SchurEngine | _ScipyEngine = prepared
        if (prepared.dense_limit, prepared.linear_solver) != (ENGINE_DENSE_LIMIT, linear_solver):
            prepared._rs = None  # (a reduced solver the datum check set up for other settings)
        prepared.dense_limit, prepared.linear_solver = ENGINE_DENSE_LIMIT, linear_solver
    elif engine == "numba":
        eng = SchurEngine(factors, lay, group, dense_limit=ENGINE_DENSE_LIMIT, linear_solver=linear_solver)
    elif engine == "scipy":
        eng = _ScipyEngine(lay, group)
    else:
        raise ConfigError(f"engine must be 'auto', 'numba' or 'scipy', got {engine!r}")
    info.engine = engine
    cost = eng.linearize(factors, huber_k) if prepared is None else prepared.cost
    del factors  # the engine keeps what it needs: the Jacobians go
    info.initial_cost = cost
    radius = initial_radius
    nu = 2.0
    for it in range(1, max_iterations + 1):
        if eng.gradient_max() <= gradient_tolerance:
            info.converged, info.message = True, "gradient tolerance reached"
            break
        G = inner_constraint_basis(state, lay) if free_datum else None
        accepted = False
        stop = ""
        while not accepted:
            lam = 1.0 / radius
            try:
                dc, dp, pred = eng.solve(lam, G)
            except SingularError:
                radius /= 4.0
                info.unsuccessful += 1
                if radius < 1e-12:
                    raise
                continue
            new = lay.apply(state, dc, dp)
            # the Jacobians at the candidate are needed anyway when it is accepted (most steps)
            new_factors = []  # a rejected candidate's Jacobians go before the next are computed
            new_factors = model.evaluate(new, jacobians=True)
            new_cost = factor_cost(new_factors, huber_k)
            rho = (cost - new_cost) / pred if pred > 0 else -1.0
            # Ceres's order: the candidate's step size and cost change are tested before its quality, so
            # that a rejected step which changes the cost by less than the tolerance ends the solve
            # instead of shrinking the trust region for further trials
            step_norm = np.sqrt((dc * dc).sum() + (dp * dp).sum())
            x_norm = np.sqrt((state.C * state.C).sum() + (state.X * state.X).sum())
            if step_norm <= parameter_tolerance * (x_norm + parameter_tolerance):
                stop = "parameter tolerance reached"
            elif np.isfinite(new_cost) and abs(cost - new_cost) <= function_tolerance * max(cost, 1e-300):
                stop = "function tolerance reached"
            if np.isfinite(new_cost) and (rho > MIN_RELATIVE_DECREASE or (stop and new_cost < cost)):
                accepted = True
                radius = radius / max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                radius = min(radius, 1e16)
                nu = 2.0
            else:
                info.unsuccessful += 1
                if stop:
                    break
                radius /= nu
                nu *= 2.0
                if radius < 1e-32:
                    info.message = "trust region collapsed"
                    break
        if accepted:
            state, cost = new, new_cost
            info.history.append((it, cost, 1.0 / radius))
            info.iterations = it
            if callback is not None:
                callback(it, cost, 1.0 / radius)
            logger.debug("iteration %d cost %.9e radius %.3g", it, cost, radius)
        if stop:
            info.converged, info.message = True, stop
            break
        if not accepted:
            break
        cost = eng.linearize(new_factors, huber_k)
        new_factors = []
    else:
        info.message = "maximum number of iterations reached"
    info.final_cost = cost
    rs = getattr(eng, "_rs", None)
    info.linear_solver = f"{rs.method} ({rs.reason})" if rs is not None else \
        ("dense" if engine == "numba" else "solve_reduced")
    info.wall_s = time.perf_counter() - t0
    return state, info
