"""Sparse Levenberg-Marquardt with the Schur complement on object points.

Normal equations
----------------
With whitened residuals ``r`` and Jacobian ``J = [J_c  J_p]`` (reduced unknowns, points)::

    [ U   W ] [dc]     [g_c]        U = J_c^T J_c,  W = J_c^T J_p,  V = J_p^T J_p (3x3 blocks per point)
    [ W^T V ] [dp] = - [g_p]        g = J^T r

The points are eliminated: ``S = U - W V^-1 W^T``, ``S dc = -(g_c - W V^-1 g_p)``,
``dp = -V^-1 (g_p + W^T dc)``.  Image observations are grouped per image so that ``W`` is a block
sparse (BSR) matrix with one ``k x 3`` block per (image, point) and the product ``W V^-1 W^T`` runs in
scipy's compiled BSR kernels; a selection matrix maps each image's ``k`` local columns to the global
reduced columns (shared intrinsics, boresights...).

Linear solver
-------------
``S`` (Jacobi-scaled) is factored with CHOLMOD through ``cholespy`` (pip wheel; supernodal sparse
Cholesky with fill-reducing ordering).  Without ``cholespy`` it falls back to a dense Cholesky
(scipy.linalg) up to 4000 unknowns and to SuperLU (``scipy.sparse.linalg.splu``) above, which is
slower but exact.  A free network (``datum="free"``) adds inner constraints on the station poses
(``S + a G G^T``, G the 7 similarity motions of the poses) and always uses the dense path.

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
from skyrig.errors import SkyrigError

logger = logging.getLogger(__name__)

try:  # optional fast sparse Cholesky (CHOLMOD)
    import cholespy as _cholespy
except ImportError:  # pragma: no cover - depends on the environment
    _cholespy = None

__all__ = ["Normal", "SolveInfo", "assemble", "solve_reduced", "levenberg_marquardt", "SingularError",
           "inner_constraint_basis", "HAVE_CHOLMOD"]

HAVE_CHOLMOD = _cholespy is not None
DENSE_LIMIT = 4000


class SingularError(SkyrigError, ArithmeticError):
    """The normal equations are singular (datum defect, unobservable parameter)."""


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


def _robust(f: Factor, k: float | None) -> tuple[NDArray[np.float64], float]:
    """Row scale sqrt(w) and the cost of a factor (Huber on the whitened row norm when k is given)."""
    w = np.ones(len(f)) if f.weight is None else f.weight
    s = (f.r * f.r).sum(axis=1)
    if k is None or f.name != "image":
        return np.sqrt(w), 0.5 * float((w * s).sum())
    root = np.sqrt(s)
    rho = np.where(root <= k, s, 2.0 * k * root - k * k)
    dr = np.where(root <= k, 1.0, k / np.maximum(root, 1e-300))
    return np.sqrt(w * dr), 0.5 * float((w * rho).sum())


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
        if f.jp is not None and f.point is not None:
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
        jc = f.jc * sw[:, None, None]
        k = jc.shape[2]
        if f.jp is not None and f.name == "image" and image_group is not None:
            Wb, P, U_img, g_img = _image_blocks(f, jc, r, sw, layout, image_group, chunk)
            gc += g_img
            rows.append(U_img.row)
            colsl.append(U_img.col)
            vals.append(U_img.data)
            continue
        cols = f.cols
        valid = cols >= 0
        g = np.einsum("ndk,nd->nk", jc, r)
        gc += np.bincount(cols[valid], weights=g[valid], minlength=n_c)
        jtj = np.einsum("nda,ndb->nab", jc, jc)
        ii = np.broadcast_to(cols[:, :, None], jtj.shape)
        jj = np.broadcast_to(cols[:, None, :], jtj.shape)
        m = (ii >= 0) & (jj >= 0)
        rows.append(ii[m])
        colsl.append(jj[m])
        vals.append(jtj[m])
        del k
    if rows:
        U = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(colsl))),
                          shape=(n_c, n_c)).tocsr()
    else:
        U = sp.csr_matrix((n_c, n_c))
    return Normal(cost, gc, U, V, gp, Wb, P)


def _image_blocks(f: Factor, jc: NDArray, r: NDArray, sw: NDArray, layout: Layout, group: NDArray[np.int64],
                  chunk: int):  # type: ignore[no-untyped-def]
    n_c, n_p = layout.n_c, layout.n_p
    n, d, k = jc.shape
    n_img = int(group.max()) + 1 if n else 0
    # columns of each image (rows of one image share them)
    gcols = np.full((n_img, k), -1, np.int64)
    gcols[group] = f.cols
    # U blocks and gradient per image
    Ub = np.zeros((n_img, k * k))
    gb = np.zeros((n_img, k))
    for s0 in range(0, n, chunk):
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
    order = order[np.argsort(group[order], kind="stable")]
    jp = f.jp[order] * sw[order, None, None]  # jc already carries the row scale; jp must too
    jcs = jc[order]
    blocks = np.einsum("nda,ndb->nab", jcs, jp)
    indptr = np.zeros(n_img + 1, np.int64)
    indptr[1:] = np.cumsum(np.bincount(group[order], minlength=n_img))
    Wb = sp.bsr_matrix((blocks, f.point[order], indptr), shape=(n_img * k, n_p * 3))
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
    C = state.C[on]
    c0 = C.mean(axis=0)
    dC = C - c0
    R = state.R[on]
    for a in range(3):
        e = np.zeros(3)
        e[a] = 1.0
        G[cols[on, a], a] = 1.0
        rot_c = np.cross(e, dC)
        for b in range(3):
            G[cols[on, b], 3 + a] = rot_c[:, b]
        th = np.einsum("nji,j->ni", R, e)
        for b in range(3):
            G[cols[on, 3 + b], 3 + a] = th[:, b]
    for b in range(3):
        G[cols[on, b], 6] = dC[:, b]
    nrm = np.linalg.norm(G, axis=0)
    nrm[nrm == 0] = 1.0
    return G / nrm


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
        method = "dense" if (G is not None or n <= 400 or not HAVE_CHOLMOD and n <= DENSE_LIMIT) else (
            "cholmod" if HAVE_CHOLMOD else "splu")
    try:
        if method == "dense":
            A = Ss.toarray()
            if G is not None:
                Gs = G / s[:, None]
                Gs /= np.linalg.norm(Gs, axis=0).clip(1e-300)
                A = A + Gs @ Gs.T
            c = scipy.linalg.cho_factor(A, lower=True, check_finite=False)
            x = scipy.linalg.cho_solve(c, b, check_finite=False)
        elif method == "cholmod":
            coo = Ss.tocoo()
            solver = _cholespy.CholeskySolverD(n, coo.row.astype(np.int32), coo.col.astype(np.int32),  # type: ignore[union-attr]
                                               coo.data, _cholespy.MatrixType.COO)  # type: ignore[union-attr]
            x = np.zeros_like(b)
            solver.solve(np.ascontiguousarray(b), x)
        else:
            import scipy.sparse.linalg as spl

            lu = spl.splu(Ss.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                          options={"SymmetricMode": True})
            x = lu.solve(b)
    except (np.linalg.LinAlgError, ValueError, RuntimeError) as e:
        raise SingularError(f"the reduced normal matrix is not positive definite ({e})") from e
    if not np.all(np.isfinite(x)):
        raise SingularError("the reduced normal matrix is singular (non-finite solution)")
    return x * (s if x.ndim == 1 else s[:, None])


def schur_matrix(N: Normal, lam: float = 0.0, diag_min: float = 1e-6):  # type: ignore[no-untyped-def]
    """``S``, its right-hand side and the damped inverse point blocks for damping ``lam``."""
    n_p = N.V.shape[0]
    U = N.U
    V = N.V
    if lam > 0:
        du = np.clip(U.diagonal(), diag_min, None)
        U = U + sp.diags(lam * du)
        dv = np.clip(np.diagonal(V, axis1=1, axis2=2), diag_min, None)
        V = V + lam * dv[:, :, None] * np.eye(3)[None]
    if n_p:
        Vinv = np.linalg.inv(V)
    else:
        Vinv = np.zeros((0, 3, 3))
    S = U
    rhs = -N.gc.copy()
    if N.Wb is not None and n_p:
        Vb = sp.bsr_matrix((Vinv, np.arange(n_p), np.arange(n_p + 1)), shape=(3 * n_p, 3 * n_p))
        WV = N.Wb @ Vb
        T = (WV @ N.Wb.T).tocsr()
        S = (U - N.P.T @ T @ N.P).tocsr()  # type: ignore[union-attr]
        rhs = rhs + N.P.T @ (WV @ N.gp.reshape(-1))  # type: ignore[union-attr]
    return sp.csr_matrix(S), rhs, Vinv


def back_substitute(N: Normal, Vinv: NDArray[np.float64], dc: NDArray[np.float64]) -> NDArray[np.float64]:
    """Point steps ``(n_p, 3)`` from the reduced step."""
    t = N.gp.reshape(-1).copy()
    if N.Wb is not None and len(Vinv):
        t += N.Wb.T @ (N.P @ dc)  # type: ignore[union-attr]
    return -np.einsum("pij,pj->pi", Vinv, t.reshape(-1, 3))


@dataclass
class SolveInfo:
    """What the optimiser did."""

    iterations: int = 0
    initial_cost: float = float("nan")
    final_cost: float = float("nan")
    converged: bool = False
    message: str = ""
    wall_s: float = 0.0
    history: list[tuple[int, float, float]] = field(default_factory=list)


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
) -> tuple[State, SolveInfo]:
    """Minimise ``0.5 * sum(rho(|r|^2))`` over the model's unknowns starting from ``state``.

    Stops as Ceres does: relative cost decrease below ``function_tolerance``, relative step below
    ``parameter_tolerance``, or max gradient below ``gradient_tolerance``.
    """
    t0 = time.perf_counter()
    lay = model.layout
    info = SolveInfo()
    group = model.block.obs_image
    factors = model.evaluate(state)
    N = assemble(factors, lay, group, huber_k)
    info.initial_cost = N.cost
    radius = initial_radius
    nu = 2.0
    cost = N.cost
    for it in range(1, max_iterations + 1):
        gmax = max(np.abs(N.gc).max(initial=0.0), np.abs(N.gp).max(initial=0.0))
        if gmax <= gradient_tolerance:
            info.converged, info.message = True, "gradient tolerance reached"
            break
        G = inner_constraint_basis(state, lay) if free_datum else None
        accepted = False
        while not accepted:
            S, rhs, Vinv = schur_matrix(N, 1.0 / radius)
            try:
                dc = solve_reduced(S, rhs, G)
            except SingularError:
                radius /= 4.0
                if radius < 1e-12:
                    raise
                continue
            dp = back_substitute(N, Vinv, dc) if lay.n_p else np.zeros((0, 3))
            new = lay.apply(state, dc, dp)
            new_factors = model.evaluate(new, jacobians=False)
            new_cost = factor_cost(new_factors, huber_k)
            # predicted decrease of the linear model: 0.5 d^T (lam D d - g)  (with (A + lam D) d = -g)
            du = np.clip(N.U.diagonal(), 1e-6, None)
            dv = np.clip(np.diagonal(N.V, axis1=1, axis2=2), 1e-6, None).reshape(-1)
            lam = 1.0 / radius
            dpf = dp.reshape(-1)
            pred = 0.5 * (lam * (du * dc * dc).sum() + lam * (dv * dpf * dpf).sum()
                          - (N.gc * dc).sum() - (N.gp.reshape(-1) * dpf).sum())
            rho = (cost - new_cost) / pred if pred > 0 else -1.0
            if np.isfinite(new_cost) and rho > 0:
                accepted = True
                radius = radius / max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                radius = min(radius, 1e16)
                nu = 2.0
            else:
                radius /= nu
                nu *= 2.0
                if radius < 1e-32:
                    info.message = "trust region collapsed"
                    break
        if not accepted:
            break
        step_norm = np.sqrt((dc * dc).sum() + (dp * dp).sum())
        x_norm = np.sqrt((state.C * state.C).sum() + (state.X * state.X).sum())
        dcost = cost - new_cost
        state, cost = new, new_cost
        info.history.append((it, cost, 1.0 / radius))
        info.iterations = it
        if callback is not None:
            callback(it, cost, 1.0 / radius)
        logger.debug("iteration %d cost %.9e radius %.3g", it, cost, radius)
        if dcost <= function_tolerance * max(cost, 1e-300) or step_norm <= parameter_tolerance * (x_norm + parameter_tolerance):
            info.converged, info.message = True, "function tolerance reached" if dcost <= function_tolerance * cost else "parameter tolerance reached"
            break
        factors = model.evaluate(state)
        N = assemble(factors, lay, group, huber_k)
        cost = N.cost
    else:
        info.message = "maximum number of iterations reached"
    info.final_cost = cost
    info.wall_s = time.perf_counter() - t0
    return state, info
