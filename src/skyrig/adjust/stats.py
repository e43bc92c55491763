"""Precision and reliability: covariance, redundancy numbers, normalised residuals, data snooping,
variance components, and rank-deficiency / near-singularity diagnosis in words.

Notation (whitened observations, a-priori sigma0 = 1): for an observation row block ``o`` with Jacobian
``J_o`` and weight ``w`` (1, 0 when rejected, Huber weight in between), ``Q_xx`` the cofactor matrix of
the unknowns::

    H_o    = J_o Q_xx J_o^T                   cofactor of the adjusted observation
    Q_vv   = 1/w - H_o                        cofactor of the residual
    r_i    = 1 - w diag(H_o)                  redundancy number (sum over all rows = n - u)
    w_i    = v_i / sqrt(diag(Q_vv))           Baarda's normalised residual (N(0,1) without blunders)

``Q_xx`` is obtained from the Schur complement: ``Q_cc = S^-1``,
``Q_cp = -Q_cc W V^-1``, ``Q_pp = V^-1 + V^-1 W^T Q_cc W V^-1`` (only the 3x3 diagonal point blocks).
For a free network ``S^-1`` is replaced by the Moore-Penrose inverse ``S^+`` (inner constraints on the
station poses: minimum trace), computed in the Jacobi-scaled space and projected (:func:`_pinv_inner`).

A datum by inner constraints on object points (all, or a chosen set ``E``: minimum trace of their
covariance, as close-range programs define it) is the S-transformation of that cofactor matrix
(:func:`point_datum_covariance`): with ``G`` the similarity motions of *all* unknowns (poses, points)
and ``B`` its rows of the datum points (zero elsewhere), ``Q_E = S_E Q S_E^T``,
``S_E = I - G (B^T G)^-1 B^T``; any generalised inverse ``Q`` of ``N`` gives the same ``Q_E``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np
import scipy.linalg
import scipy.linalg.lapack
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.stats import norm

from skyrig.adjust.linalg import _blas_single_thread
from skyrig.adjust.model import Factor, Layout, Model, State
from skyrig.adjust.solver import (Normal, SingularError, assemble, inner_constraint_basis, point_inverses, schur_matrix,
                                  solve_reduced)
from skyrig.errors import ConfigError, GeometryError

__all__ = ["Covariance", "covariance", "row_cofactors", "critical_value", "describe_null_space",
           "correlation_warnings", "sidak_z", "GroupStats", "SelectedCovariance", "selected_covariance", "selected_from_dense",
           "chosen_unknowns", "similarity_basis", "point_datum_covariance", "PointPatternM"]


def critical_value(alpha: float) -> float:
    """Two-sided critical value of the standard normal distribution (alpha 0.001 -> 3.29)."""
    return float(norm.ppf(1.0 - alpha / 2.0))


def sidak_z(m: int, level: float = 0.95) -> float:
    """The ``|z|`` bound that ``m`` independent N(0, 1) draws all stay within with probability ``level`` (Sidak):
    ``Phi^-1((1 + level^(1/m)) / 2)`` (33 values at 95 %: 3.17).  For correlated Gaussian draws it is a conservative
    bound (Sidak's inequality): all of them stay within it with probability at least ``level``."""
    if m < 1 or not 0.0 < level < 1.0:
        raise ValueError(f"sidak_z: needs m >= 1 draws and a level in (0, 1), got m={m}, level={level}")
    return float(norm.ppf(0.5 + 0.5 * float(level) ** (1.0 / int(m))))


@dataclass
class Covariance:
    """Cofactors of the unknowns (multiply by sigma0^2 for the a-posteriori covariance).

    Attributes
    ----------
    Qcc
        ``(n_c, n_c)`` dense cofactor matrix of the reduced unknowns (columns: ``Layout.labels``).
    Qpp
        ``(n_p, 3, 3)`` cofactor blocks of the free points.
    M
        ``Q_cc W`` for the point/reduced cross terms: the dense ``(n_c, 3 n_p)`` array when it fits
        ``max_dense_products``, else a :class:`PointPatternM` holding it on the sparsity pattern of ``W``
        (the reduced columns each point's observations touch: all that redundancy numbers and normalised
        residuals need), or None.
    Vinv
        ``(n_p, 3, 3)`` inverse point blocks of the normal matrix.
    W
        ``(n_c, 3 n_p)`` sparse ``W = P^T Wb`` (reduced x point block of the normal matrix), or None: any
        cross cofactor ``Q_cp = -Q_cc W_p V_p^-1`` off ``M``'s pattern is ``Q_cc`` times a few of its columns.
    """

    Qcc: NDArray[np.float64]
    Qpp: NDArray[np.float64]
    Vinv: NDArray[np.float64]
    M: NDArray[np.float64] | None = None
    W: sp.csr_matrix | None = None

    def cross(self, points: NDArray[np.int64], rows: NDArray[np.int64] | None = None) -> NDArray[np.float64] | None:
        """``(m, k, 3)`` ``(Q_cc W)[rows, points' columns]`` (all reduced rows when ``rows`` is None) for free-point
        indices ``points``: sliced from a dense ``M``, else ``Q_cc[rows] W[:, cols]`` (None without ``W``)."""
        cols3 = (3 * np.asarray(points, np.int64)[:, None] + np.arange(3)[None, :]).reshape(-1)
        r = slice(None) if rows is None else np.asarray(rows, np.int64)
        if isinstance(self.M, np.ndarray):
            out = self.M[r][:, cols3]
        elif self.W is not None:
            out = np.asarray(self.W[:, cols3].T @ self.Qcc[r].T).T
        else:
            return None
        return out.reshape(out.shape[0], len(points), 3)


class PointPatternM:
    """``M = Q_cc W`` on the block pattern of ``W``: for each point ``p`` the rows ``R_p`` (reduced columns with a
    structural entry in ``W``'s columns of ``p``) and ``M[R_p, 3p:3p+3]``.

    Since ``W[:, p]`` is zero outside ``R_p``, ``M[R_p, p] = Q_cc[R_p, R_p] W[R_p, p]`` exactly: memory and work
    grow with ``sum |R_p|^2`` instead of ``n_c x 3 n_p`` (the dense product that made statistics above a few
    thousand images skip the image observations' normalised residuals).  The pattern is structural (block
    entries that happen to be zero included), so every column an observation of ``p`` has lies in ``R_p``.
    """

    def __init__(self, n_c: int, indptr: NDArray[np.int64], rows: NDArray[np.int64], wvals: NDArray[np.float64],
                 vals: NDArray[np.float64]) -> None:
        self.n_c, self.indptr, self.rows, self.wvals, self.vals = n_c, indptr, rows, wvals, vals
        self.entry_point = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))

    def gather(self, cols: NDArray[np.int64], point: NDArray[np.int64]) -> NDArray[np.float64]:
        """``(n, k, 3)`` ``M[cols[i, j], 3 point[i] : 3 point[i] + 3]`` for columns of the points' own
        observations (on the pattern by construction); ``cols`` entries ``>= n_c`` give 0."""
        out = np.zeros(cols.shape + (3,))
        if _pattern_gather(self.indptr, self.rows, self.vals, np.ascontiguousarray(cols, dtype=np.int64),
                           np.ascontiguousarray(point, dtype=np.int64), self.n_c, out):
            raise AssertionError("a cross cofactor off the observations' pattern was asked for")
        return out


def _point_pattern(N: Normal, n_c: int, n_p: int, W: sp.csr_matrix | None = None
                   ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
    """Per point the reduced columns its observations touch (the *structural* block pattern of
    ``W = P^T Wb``, exact zeros included): ``indptr (n_p+1)``, ``rows`` (sorted per point) and ``W``'s values
    there ``(nnz, 3)``; ``W``: that product when the caller has it."""
    Wb = N.wb
    if isinstance(Wb, sp.bsr_matrix) and Wb.blocksize[1] == 3 and Wb.shape[1] == 3 * n_p:
        P = sp.csr_matrix(N.p)
        k = Wb.blocksize[0]
        blk_row = np.repeat(np.arange(len(Wb.indptr) - 1, dtype=np.int64), np.diff(Wb.indptr))
        order = np.argsort(Wb.indices, kind="stable").astype(np.int64)
        pptr = np.zeros(n_p + 1, np.int64)
        np.cumsum(np.bincount(Wb.indices, minlength=n_p), out=pptr[1:])
        unit_nnz = np.diff(P.indptr).reshape(-1, k).sum(axis=1) if P.shape[0] else np.zeros(0, np.int64)
        cap = int(unit_nnz[blk_row].sum()) if len(blk_row) else 0
        indptr = np.zeros(n_p + 1, np.int64)
        rows = np.zeros(cap, np.int64)
        wv = np.zeros((cap, 3))
        _pattern_build(pptr, order, blk_row, np.ascontiguousarray(Wb.data, dtype=np.float64), k,
                       P.indptr.astype(np.int64), P.indices.astype(np.int64), P.data.astype(np.float64), n_c,
                       indptr, rows, wv)
        return indptr, rows[:indptr[-1]].copy(), wv[:indptr[-1]].copy()
    Wb = N.wb.tocoo()  # every stored block entry, zeros included
    Pc = abs(N.p).tocsc()  # (unit columns, n_c)
    ones = sp.csr_matrix((np.ones(len(Wb.data)), (Wb.row, Wb.col)), shape=Wb.shape)
    S = sp.csc_matrix(Pc.T @ ones)  # positive entries: no cancellation
    S.sort_indices()
    # a point's three columns share their structure (full k x 3 blocks): its pattern is the column 3 p
    cnt = np.diff(S.indptr)[0::3].astype(np.int64)
    first = np.repeat(S.indptr[:-1][0::3].astype(np.int64), cnt)
    within = np.arange(int(cnt.sum()), dtype=np.int64) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    key_s = np.repeat(np.arange(n_p, dtype=np.int64), cnt) * (n_c + 1) + S.indices[first + within]
    Wfull = sp.csr_matrix(N.p.T @ N.wb.tocsr() if W is None else W)
    Wfull.sum_duplicates()  # canonical: one entry per (row, column)
    Wfull = Wfull.tocoo()
    key_w = (Wfull.col // 3).astype(np.int64) * (n_c + 1) + Wfull.row
    wv = np.zeros((len(key_s), 3))
    pos = np.searchsorted(key_s, key_w)
    if len(key_w) and not np.all(key_s[np.minimum(pos, len(key_s) - 1)] == key_w):
        raise AssertionError("W has entries outside its structural pattern")
    wv[pos, Wfull.col % 3] = Wfull.data
    indptr = np.zeros(n_p + 1, np.int64)
    np.cumsum(np.bincount(key_s // (n_c + 1), minlength=n_p), out=indptr[1:])
    return indptr, (key_s % (n_c + 1)).astype(np.int64), wv


@numba.njit(cache=True, nogil=True, parallel=True)
def _pattern_kernel(Q, indptr, rows, wv, vals, WtM):  # type: ignore[no-untyped-def]
    """numba kernel of :func:`_pattern_products` (one point at a time, parallel over points)."""
    for p in numba.prange(len(indptr) - 1):
        a, b = indptr[p], indptr[p + 1]
        for i in range(a, b):
            ri = rows[i]
            a0 = 0.0
            a1 = 0.0
            a2 = 0.0
            for j in range(a, b):
                q = Q[ri, rows[j]]
                a0 += q * wv[j, 0]
                a1 += q * wv[j, 1]
                a2 += q * wv[j, 2]
            vals[i, 0] = a0
            vals[i, 1] = a1
            vals[i, 2] = a2
        for c in range(3):
            for e in range(3):
                acc = 0.0
                for i in range(a, b):
                    acc += wv[i, c] * vals[i, e]
                WtM[p, c, e] = acc



@numba.njit(cache=True, nogil=True)
def _pattern_build(pptr, order, blk_row, data, k, pind, pcol, pval, n_c, indptr, rows, wv):  # type: ignore[no-untyped-def]
    """numba builder of :func:`_point_pattern` from ``Wb``'s blocks and ``P``'s rows."""
    slot = np.full(n_c, -1, np.int64)
    tmp_c = np.empty(n_c, np.int64)
    tmp_v = np.zeros((n_c, 3))
    out = 0
    for p in range(len(pptr) - 1):
        m = 0
        for t in range(pptr[p], pptr[p + 1]):
            blk = order[t]
            u = blk_row[blk]
            for a in range(k):
                r = u * k + a
                for e in range(pind[r], pind[r + 1]):
                    c = pcol[e]
                    if slot[c] < 0:
                        slot[c] = m
                        tmp_c[m] = c
                        tmp_v[m, 0] = 0.0
                        tmp_v[m, 1] = 0.0
                        tmp_v[m, 2] = 0.0
                        m += 1
                    j = slot[c]
                    for b in range(3):
                        tmp_v[j, b] += pval[e] * data[blk, a, b]
        srt = np.argsort(tmp_c[:m])
        for i in range(m):
            j = srt[i]
            rows[out + i] = tmp_c[j]
            wv[out + i, 0] = tmp_v[j, 0]
            wv[out + i, 1] = tmp_v[j, 1]
            wv[out + i, 2] = tmp_v[j, 2]
            slot[tmp_c[j]] = -1
        out += m
        indptr[p + 1] = out



@numba.njit(cache=True, nogil=True)
def _pattern_gather(indptr, rows, vals, cols, point, n_c, out):  # type: ignore[no-untyped-def]
    """numba lookup of :meth:`PointPatternM.gather` (a binary search in each point's sorted rows)."""
    missing = False
    for i in range(cols.shape[0]):
        a0, b0 = indptr[point[i]], indptr[point[i] + 1]
        for j in range(cols.shape[1]):
            c = cols[i, j]
            if c >= n_c or c < 0:
                continue
            lo, hi = a0, b0
            while lo < hi:
                mid = (lo + hi) // 2
                if rows[mid] < c:
                    lo = mid + 1
                else:
                    hi = mid
            if lo < b0 and rows[lo] == c:
                out[i, j, 0] = vals[lo, 0]
                out[i, j, 1] = vals[lo, 1]
                out[i, j, 2] = vals[lo, 2]
            else:
                missing = True
    return missing



@numba.njit(cache=True, nogil=True)
def _schur_kernel(S, indptr, rows, wv, Vinv):  # type: ignore[no-untyped-def]
    """numba ``S -= W_p V_p^-1 W_p^T`` for every point on its pattern (dense ``S``, in place)."""
    t = np.empty((S.shape[0], 3))
    for p in range(len(indptr) - 1):
        a, b = indptr[p], indptr[p + 1]
        for i in range(a, b):
            for c in range(3):
                t[i - a, c] = wv[i, 0] * Vinv[p, 0, c] + wv[i, 1] * Vinv[p, 1, c] + wv[i, 2] * Vinv[p, 2, c]
        for i in range(a, b):
            ri = rows[i]
            t0, t1, t2 = t[i - a, 0], t[i - a, 1], t[i - a, 2]
            for j in range(a, b):
                S[ri, rows[j]] -= t0 * wv[j, 0] + t1 * wv[j, 1] + t2 * wv[j, 2]



@numba.njit(cache=True, nogil=True, parallel=True)
def _row_kernel(Q, cols, jc, H):  # type: ignore[no-untyped-def]
    """numba ``H[i, d] += J_c[i, d] Q_cc[cols_i, cols_i] J_c[i, d]^T`` (columns ``>= n_c``: none)."""
    n_c = Q.shape[0]
    for i in numba.prange(cols.shape[0]):
        for d in range(jc.shape[1]):
            acc = 0.0
            for k in range(cols.shape[1]):
                ck = cols[i, k]
                if ck >= n_c:
                    continue
                v = 0.0
                for m in range(cols.shape[1]):
                    cm = cols[i, m]
                    if cm < n_c:
                        v += Q[ck, cm] * jc[i, d, m]
                acc += jc[i, d, k] * v
            H[i, d] += acc



def _pattern_products(Q: NDArray[np.float64], indptr: NDArray[np.int64], rows: NDArray[np.int64],
                      wv: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``M[R_p, p] = Q[R_p, R_p] W[R_p, p]`` for every point ``(nnz, 3)`` and ``W_p^T M_p`` ``(n_p, 3, 3)``
    (:func:`_pattern_kernel`, one point at a time)."""
    vals = np.zeros_like(wv)
    WtM = np.zeros((len(indptr) - 1, 3, 3))
    _pattern_kernel(np.ascontiguousarray(Q), indptr.astype(np.int64), rows.astype(np.int64), np.ascontiguousarray(wv),
                    vals, WtM)
    return vals, WtM


def _spd_inverse(A: NDArray[np.float64], what: str) -> NDArray[np.float64]:
    """Inverse of the symmetric positive definite ``A`` from its Cholesky factor (LAPACK ``potrf`` + ``potri``:
    a third of the work of inverting the factor and multiplying, the same numbers to rounding; BLAS on one
    thread); raises
    :class:`SingularError` with ``what`` when ``A`` is not positive definite."""
    n = A.shape[0]
    if n == 0:
        return np.zeros((0, 0))
    with _blas_single_thread():  # OpenBLAS threads busy-wait for each other on a loaded machine
        c, info = scipy.linalg.lapack.dpotrf(A, lower=1, clean=0, overwrite_a=0)
        if info != 0:
            raise SingularError(f"{what}: leading minor {info} not positive definite" if info > 0
                                else f"{what}: LAPACK potrf argument {-info}")
        X, info = scipy.linalg.lapack.dpotri(c, lower=1, overwrite_c=1)
    if info != 0:
        raise SingularError(f"{what}: zero pivot {info}")
    il = np.triu_indices(n, 1)
    X[il] = X.T[il]  # potri fills the lower triangle
    return X


def _pinv_inner(S: NDArray[np.float64], G: NDArray[np.float64]) -> NDArray[np.float64]:
    """Moore-Penrose inverse of the symmetric positive semi-definite ``S`` whose null space is spanned by
    the columns of ``G`` (the inner-constraint / minimum-trace cofactor matrix), scale-robustly.

    The diagonal of a normal matrix spans many orders of magnitude (1e-3 .. 1e16 with distortion terms in
    millimetres), so ``S + q q^T`` with an orthonormal ``q`` in parameter units loses every digit of the
    small entries.  Instead, in the Jacobi-scaled space ``S_s = D S D`` (``D = diag(S)^-1/2``), whose null
    space is spanned by ``D^-1 G``, with ``H`` an orthonormal basis of it::

        X = D (S_s + H H^T)^-1 D            a generalised inverse of S  (S X S = S)
        S^+ = P X P,  P = I - q q^T          q: orthonormal basis of G (in parameter units)

    (for symmetric ``S`` and any generalised inverse ``X``, ``P X P = S^+ S X S S^+ = S^+``: the projector
    onto the range of ``S`` removes the datum part).  Raises :class:`SingularError` when ``S`` has a
    rank defect beyond the span of ``G``.
    """
    n = S.shape[0]
    G = G[:, np.linalg.norm(G, axis=0) > 0]
    d = np.diag(S).copy()
    if np.any(~(d > 0)):
        raise SingularError("unknowns without observations")
    sc = 1.0 / np.sqrt(d)
    if G.shape[1] == 0:
        H = np.zeros((n, 0))
    else:
        H, _ = np.linalg.qr(G / sc[:, None])
    A = S * sc[:, None] * sc[None, :] + H @ H.T
    X = _spd_inverse(A, "the normal matrix is singular beyond the datum defect") * sc[:, None] * sc[None, :]
    if G.shape[1] == 0:
        return X
    q, _ = np.linalg.qr(G)
    Xq = X @ q
    Q = X - Xq @ q.T - q @ Xq.T + q @ (q.T @ Xq) @ q.T
    return 0.5 * (Q + Q.T)


def covariance(N: Normal, layout: Layout, state: State, free_datum: bool = False,
               max_dense_products: int = 2_000_000) -> Covariance:
    """Cofactor matrices at the solution (see module docstring).  Raises :class:`SingularError`.

    ``M = Q_cc W`` is dense only up to ``max_dense_products`` entries; above, it is kept on ``W``'s block pattern
    (:class:`PointPatternM`: work ``sum_p |R_p|^2`` instead of ``n_c x 3 n_p``, which grew with the square of the
    block) and ``W`` is kept for the few cross cofactors off the pattern a caller asks for (:meth:`Covariance.cross`).
    """
    n_p, n_c = layout.n_p, layout.n_c
    pattern = None
    if n_p and N.Wb is not None:
        # the dense S = U - W V^-1 W^T straight from W's point pattern (which M needs anyway): the same work as
        # the sparse product's, without building the sparse reduced matrix first
        Vinv = point_inverses(N.V)
        pattern = _point_pattern(N, n_c, n_p)
        Sd = N.U.toarray()
        _schur_kernel(Sd, *pattern, np.ascontiguousarray(Vinv))
        ip, rows, wv = pattern
        e_p = np.repeat(np.arange(n_p, dtype=np.int64), np.diff(ip))
        Wfull = sp.csr_matrix((wv.reshape(-1), (np.repeat(rows, 3), (3 * e_p[:, None] + np.arange(3)).reshape(-1))),
                              shape=(n_c, 3 * n_p))
    else:
        S, _, Vinv = schur_matrix(N, 0.0)
        Sd = S.toarray()
        Wfull = sp.csr_matrix(N.p.T @ N.wb.tocsr()) if n_p and N.Wb is not None else None
    if free_datum:
        Q = _pinv_inner(Sd, inner_constraint_basis(state, layout))
    else:
        d = np.diag(Sd).copy()
        if np.any(d <= 0):
            raise SingularError("unknowns without observations")
        sc = 1.0 / np.sqrt(d)
        Q = _spd_inverse(Sd * sc[:, None] * sc[None, :], "the normal matrix is singular") * sc[:, None] * sc[None, :]
    Qpp = Vinv.copy()
    M = None
    if Wfull is not None:
        if Q.shape[0] * 3 * n_p <= max_dense_products:
            M = np.asarray(Wfull.T @ Q).T  # Q_cc W  (n_c, 3 n_p)
            Wc = Wfull.tocsc()
            WtM = np.zeros((n_p, 3, 3))
            for a in range(3):
                for b in range(3):
                    WtM[:, a, b] = np.asarray(Wc[:, a::3].multiply(M[:, b::3]).sum(axis=0)).reshape(-1)
            Qpp = Vinv + Vinv @ WtM @ Vinv
        else:  # M on W's block pattern only (what the image observations' cofactors need)
            indptr, rows, wv = pattern if pattern is not None else _point_pattern(N, Q.shape[0], n_p, Wfull)
            vals, WtM = _pattern_products(Q, indptr, rows, wv)
            Qpp = Vinv + Vinv @ WtM @ Vinv
            M = PointPatternM(Q.shape[0], indptr, rows, wv, vals)  # type: ignore[assignment]
    return Covariance(Q, Qpp, Vinv, M, Wfull)


def similarity_basis(state: State, layout: Layout, scale: bool
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Similarity motions of every estimated pose and point: ``(Gc (n_c, d), Gp (n_p, 3, d))``.

    Columns: translation along X, Y, Z, rotation about X, Y, Z (about the centroid of the estimated
    points, or of the poses without points) and, with ``scale``, a scale change; each column of unit norm
    over ``Gc`` and ``Gp`` together.  A world rotation ``w`` moves a position ``x`` by ``w x (x - c0)``
    and a right-perturbed camera rotation by ``R^T w``.
    """
    d = 7 if scale else 6
    Gc = np.zeros((layout.n_c, d))
    Gp = np.zeros((layout.n_p, 3, d))
    pts = np.flatnonzero(layout.point >= 0)
    red = np.flatnonzero((layout.rpoint_cols >= 0).all(axis=1)) if layout.has_rpoint else np.zeros(0, np.int64)
    pose_on = np.flatnonzero((layout.pose >= 0).all(axis=1))
    allp = np.concatenate([pts, red])
    c0 = state.X[allp].mean(axis=0) if allp.size else (state.C[pose_on].mean(axis=0) if pose_on.size
                                                        else np.zeros(3))
    E = np.eye(3)

    def motions(x: NDArray[np.float64]) -> NDArray[np.float64]:
        """``(m, 3, d)`` moves of positions ``x (m, 3)``."""
        dx = x - c0
        out = np.zeros((len(x), 3, d))
        out[:, :, :3] = E[None]
        for a in range(3):
            out[:, :, 3 + a] = np.cross(E[a], dx)
        if scale:
            out[:, :, 6] = dx
        return out

    if pose_on.size:
        pc = layout.pose[pose_on]
        mc = motions(state.C[pose_on])
        for a in range(3):
            Gc[pc[:, a]] = mc[:, a]
            Gc[pc[:, 3 + a], 3:6] = state.R[pose_on][:, :, a]  # (R^T e_b)_a = R[b, a]
    if red.size:
        mr = motions(state.X[red])
        rc = layout.rpoint_cols[red]
        for a in range(3):
            Gc[rc[:, a]] = mr[:, a]
    if pts.size:
        Gp[layout.point[pts]] = motions(state.X[pts])
    nrm = np.sqrt((Gc**2).sum(axis=0) + (Gp**2).sum(axis=(0, 1)))
    nrm[nrm == 0] = 1.0
    return Gc / nrm, Gp / nrm


def point_datum_covariance(cov: Covariance, N: Normal, layout: Layout, state: State,
                           datum_points: NDArray[np.bool_]) -> Covariance:
    """The cofactors of a free network re-expressed in the datum of inner constraints on the object
    points ``datum_points`` (``(P,)`` mask over the block's points; estimated ones only count).

    S-transformation (module docstring) of the full cofactor matrix that ``cov`` represents
    (``Q_cc``, ``Q_cp = -Q_cc W V^-1``, ``Q_pp = V^-1 + V^-1 W^T Q_cc W V^-1``), evaluated in blocks: the
    returned :class:`Covariance` keeps that representation (``M`` is ``-Q_cp V`` per point, so that the
    cross terms read back as before).  Raises :class:`~skyrig.errors.GeometryError` when the chosen points do
    not fix the datum (fewer than 3, or all on one line).
    """
    scale = not layout.has_rpoint
    Gc, Gp = similarity_basis(state, layout, scale)
    d = Gc.shape[1]
    n_c, n_p = layout.n_c, layout.n_p
    chosen = np.asarray(datum_points, bool)
    sel_p = np.zeros(n_p, bool)
    on = layout.point >= 0
    sel_p[layout.point[on & chosen]] = True
    Bc = np.zeros_like(Gc)
    n_red = 0
    if layout.has_rpoint:
        red = (layout.rpoint_cols >= 0).all(axis=1) & chosen
        rc = layout.rpoint_cols[red].reshape(-1)
        Bc[rc] = Gc[rc]
        n_red = int(red.sum())
    Bp = Gp * sel_p[:, None, None]
    if int(sel_p.sum()) + n_red < 3:
        raise GeometryError(f"inner constraints on {int(sel_p.sum()) + n_red} estimated point(s) cannot fix the datum "
                         "(at least 3 points, not on one line)")
    Q = cov.Qcc
    Vinv = cov.Vinv
    if n_p:
        W = sp.csr_matrix(N.p.T @ N.wb.tocsr())  # (n_c, 3 n_p)
        Y = np.einsum("pab,pbd->pad", Vinv, Bp).reshape(3 * n_p, d)  # V^-1 B_p
        F = Bc.T - np.asarray(W @ Y).T  # (d, n_c): B_c^T - B_p^T V^-1 W^T
    else:
        W = None
        F = Bc.T.copy()
    BQc = F @ Q  # (d, n_c) = (B^T Q) reduced columns
    BtG = Bc.T @ Gc + np.einsum("pad,pae->de", Bp, Gp)
    BQB = BQc @ Bc
    if n_p:
        FM = np.asarray((W.T @ BQc.T)).T.reshape(d, n_p, 3).transpose(1, 0, 2)  # (n_p, d, 3)
        BQp = np.einsum("pda,pab->pdb", np.swapaxes(Bp, 1, 2) - FM, Vinv)  # (B^T Q) point columns
        BQB = BQB + np.einsum("pda,pae->de", BQp, Bp)
    sv = np.linalg.svd(BtG, compute_uv=False)
    if not sv[-1] > 1e-8 * sv[0]:
        raise GeometryError("the chosen datum points do not fix the datum (on one line, or too few): inner "
                         "constraints on them leave a rotation undetermined")
    K = np.linalg.inv(BtG)
    TQc = K @ BQc  # (d, n_c)
    Z = K @ BQB @ K.T
    GcZ = Gc @ Z
    A = Gc @ TQc
    Qcc = Q - A - A.T + GcZ @ Gc.T
    Qcc = 0.5 * (Qcc + Qcc.T)
    Qpp = cov.Qpp
    M = cov.M
    if n_p:
        TQp = np.einsum("de,pea->pda", K, BQp)  # (n_p, d, 3)
        GT = Gp @ TQp  # (n_p, 3, 3)
        Qpp = cov.Qpp - GT - np.swapaxes(GT, 1, 2) + Gp @ Z @ np.swapaxes(Gp, 1, 2)
        Qpp = 0.5 * (Qpp + np.swapaxes(Qpp, 1, 2))
        if isinstance(M, PointPatternM):  # the same update on the pattern's entries (point e_p, row e_c)
            e_p, e_c = M.entry_point, M.rows
            D = (np.einsum("ed,eda->ea", Gc[e_c], TQp[e_p]) + np.einsum("de,ead->ea", TQc[:, e_c], Gp[e_p])
                 - np.einsum("ed,ead->ea", GcZ[e_c], Gp[e_p]))
            M = PointPatternM(n_c, M.indptr, M.rows, M.wvals, M.vals + np.einsum("ea,eab->eb", D, N.V[e_p]))
        elif M is not None:
            # Q'_cp = Q_cp - Gc TQp - TQc^T Gp^T + Gc Z Gp^T, and M' = -Q'_cp V
            D = (np.einsum("cd,pda->cpa", Gc, TQp) + np.einsum("dc,pad->cpa", TQc, Gp)
                 - np.einsum("cd,pad->cpa", GcZ, Gp))
            M = M + np.einsum("cpa,pab->cpb", D, N.V).reshape(n_c, 3 * n_p)
    return Covariance(Qcc, Qpp, Vinv, M, cov.W)


@dataclass
class SelectedCovariance:
    """Cofactors of *chosen* unknowns (multiply by sigma0² for the a-posteriori covariance).

    Attributes
    ----------
    labels
        ``(group, owner, component)`` of the chosen reduced columns.
    columns
        ``(m,)`` their indices among the reduced unknowns.
    Qcc
        ``(m, m)`` cofactors of the chosen reduced unknowns.
    points
        ``(k,)`` indices (into the block's points) of the chosen eliminated points.
    Qpp
        ``(k, 3, 3)`` their cofactor blocks.
    Qcp
        ``(m, k, 3)`` cross cofactors chosen reduced unknowns x chosen points.
    method
        ``"dense inverse"`` or ``"sparse solves"`` (factorised reduced system, one solve per chosen column).
    """

    labels: list[tuple[str, str, str]]
    columns: NDArray[np.int64]
    Qcc: NDArray[np.float64]
    points: NDArray[np.int64]
    Qpp: NDArray[np.float64]
    Qcp: NDArray[np.float64]
    method: str

    def sigma(self, sigma0: float) -> dict[tuple[str, str, str], float]:
        """A-posteriori sigma of every chosen reduced unknown."""
        return dict(zip(self.labels, (sigma0 * np.sqrt(np.clip(np.diag(self.Qcc), 0, None))).tolist()))


def chosen_unknowns(model: Model, images: tuple[str, ...] = (), points: tuple[str, ...] = ()
                    ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Reduced columns and eliminated points whose covariance is wanted.

    Always every reduced column that is not a station pose (calibration, lever arm, boresight, shifts,
    actuator corrections, end points of distances); plus the pose columns of the stations of
    ``images`` (image or station names) and the coordinates of ``points`` (point names).  Unknown names
    raise :class:`~skyrig.errors.ConfigError`.
    """
    b, lay = model.block, model.layout
    cols = [j for j, (g, _, _) in enumerate(lay.labels) if g != "pose"]
    st_of = {str(n): int(b.image_station[k]) for k, n in enumerate(b.image_name)}
    st_of.update({str(n): k for k, n in enumerate(b.station_name)})
    bad = [n for n in images if n not in st_of]
    if bad:
        raise ConfigError(f"statistics_images names unknown images/stations {bad[:5]}")
    for n in images:
        cols.extend(int(c) for c in lay.pose[st_of[n]] if c >= 0)
    pidx = {str(n): k for k, n in enumerate(b.point_name)}
    bad = [n for n in points if n not in pidx]
    if bad:
        raise ConfigError(f"statistics_points names unknown points {bad[:5]}")
    pts = []
    for n in points:
        k = pidx[n]
        if lay.point[k] >= 0:
            pts.append(k)
        elif lay.rpoint is not None and lay.rpoint[k, 0] >= 0:
            cols.extend(int(c) for c in lay.rpoint[k])
    return np.unique(np.array(cols, np.int64)), np.unique(np.array(pts, np.int64))


def selected_from_dense(cov: Covariance, layout: Layout, columns: NDArray[np.int64],
                        points: NDArray[np.int64]) -> SelectedCovariance | None:
    """The chosen cofactors sliced from a full :class:`Covariance` (None if its cross terms are missing)."""
    pi = layout.point[points]
    Qcp = np.zeros((len(columns), len(points), 3))
    if len(points):
        QcW = cov.cross(pi, columns)  # (m, k, 3)
        if QcW is None:
            return None
        Qcp = -np.einsum("mka,kab->mkb", QcW, cov.Vinv[pi])
    return SelectedCovariance([layout.labels[j] for j in columns], columns, cov.Qcc[np.ix_(columns, columns)],
                              points, cov.Qpp[pi], Qcp, "dense inverse")


def selected_covariance(N: Normal, layout: Layout, columns: NDArray[np.int64], points: NDArray[np.int64]
                        ) -> SelectedCovariance:
    """Cofactors of chosen unknowns at any block size, without the dense inverse.

    The reduced system ``S`` is factorised once (sparse Cholesky / SuperLU, :func:`solve_reduced`)
    and solved only for the chosen columns: ``Q_cc[:, j] = S^-1 e_j``; for a chosen point ``p`` with
    ``W_p`` its ``(n_c, 3)`` block of ``W``: ``Y_p = S^-1 W_p``, ``Q_pp = V_p^-1 + V_p^-1 W_p^T Y_p V_p^-1``
    and ``Q_cp = -Y_p V_p^-1``.  Memory: ``n_c x (m + 3 k)`` doubles.  Datum by observations only (not a
    free network).  Raises :class:`SingularError`.
    """
    S, _, Vinv = schur_matrix(N, 0.0)
    n_c = layout.n_c
    m, k = len(columns), len(points)
    pi = layout.point[points]
    rhs = np.zeros((n_c, m + 3 * k))
    rhs[columns, np.arange(m)] = 1.0
    Wk = np.zeros((0, 0))  # (no chosen point)
    if k:
        cols3 = (3 * pi[:, None] + np.arange(3)[None, :]).reshape(-1)
        # the (n_c, 3 k) columns of W = P^T Wb of the chosen points (sliced before the product)
        Wk = np.asarray(N.p.T @ N.wb.tocsc()[:, cols3].toarray())
        rhs[:, m:] = Wk
    X = solve_reduced(S, rhs) if n_c else rhs
    Qcc = X[columns, :m]
    Qcc = 0.5 * (Qcc + Qcc.T)
    Qpp = np.zeros((k, 3, 3))
    Qcp = np.zeros((m, k, 3))
    if k:
        Y = X[:, m:].reshape(n_c, k, 3)
        Wp = Wk.reshape(n_c, k, 3)
        WtY = np.einsum("nka,nkb->kab", Wp, Y)
        Vi = Vinv[pi]
        Qpp = Vi + Vi @ WtY @ Vi
        Qcp = -np.einsum("mka,kab->mkb", Y[columns], Vi)
    return SelectedCovariance([layout.labels[j] for j in columns], columns, Qcc, points, Qpp, Qcp, "sparse solves")


def row_cofactors(f: Factor, cov: Covariance) -> NDArray[np.float64] | None:
    """``diag(H_o)`` ``(n, d)`` for the *unweighted* whitened rows of a factor (None if not computable)."""
    n, d = f.r.shape
    H = np.zeros((n, d))
    Q = cov.Qcc
    n_c = Q.shape[0]
    if f.jc is not None and f.cols is not None and f.cols.shape[1]:
        _row_kernel(np.ascontiguousarray(Q), np.ascontiguousarray(np.where(f.cols >= 0, f.cols, n_c), dtype=np.int64),
                    np.ascontiguousarray(f.jc, dtype=np.float64), H)
    if f.jp is not None and f.point is not None:
        has = f.point >= 0
        p = np.where(has, f.point, 0)
        jp = f.jp * has[:, None, None]
        H += np.einsum("nda,nab,ndb->nd", jp, cov.Qpp[p], jp)
        if f.jc is not None and f.cols is not None and f.cols.shape[1]:
            if cov.M is None:
                return None
            c = np.where(f.cols >= 0, f.cols, n_c)
            if isinstance(cov.M, PointPatternM):
                QcW = np.zeros((n, c.shape[1], 3))
                QcW[has] = cov.M.gather(c[has], p[has])
            else:
                Me = np.vstack([cov.M, np.zeros((1, cov.M.shape[1]))])
                cols3 = 3 * p[:, None] + np.arange(3)[None, :]
                QcW = Me[c[:, :, None], cols3[:, None, :]]  # (n, k, 3) = (Q_cc W)[cols, point]
            Qcp = -QcW @ cov.Vinv[p]
            H += 2.0 * np.einsum("ndk,nka,nda->nd", f.jc, Qcp, jp)
    return H


@dataclass
class GroupStats:
    """Per observation group: count, redundancy, variance component and residual RMS (observation units)."""

    name: str
    n_rows: int
    n_scalar: int
    redundancy: float
    sigma0: float
    rms: list[float] = field(default_factory=list)


# ---------------------------------------------------------------------- rank deficiency in words
_MOTIONS = ("translation along X", "translation along Y", "translation along Z", "rotation about X",
            "rotation about Y", "rotation about Z", "scale")


def describe_null_space(model: Model, state: State, max_size: int = 6000) -> list[str]:
    """Words for the singular directions of the reduced normal matrix at ``state`` (empty if regular)."""
    lay = model.layout
    N = assemble(model.evaluate(state), lay, model.block.obs_image)
    S, _, _ = schur_matrix(N, 0.0)
    n = S.shape[0]
    if n == 0:
        return []
    d = S.diagonal()
    out: list[str] = []
    zero = np.flatnonzero(d <= 0)
    for j in zero[:10]:
        g, o, c = lay.labels[j]
        out.append(f"{g} {o} {c} has no observations (nothing determines it)")
    if zero.size > 10:
        out.append(f"... and {zero.size - 10} more unknowns without observations")
    if zero.size:
        return out
    if n > max_size:
        return [f"the reduced normal matrix ({n} unknowns) is singular; too large for an eigen-analysis"]
    sc = 1.0 / np.sqrt(d)
    A = S.toarray() * sc[:, None] * sc[None, :]
    ev, vec = np.linalg.eigh(A)
    tol = max(ev[-1], 1.0) * 1e-10
    null = np.flatnonzero(ev <= tol)
    if null.size == 0:
        return []
    out.append(f"the normal equations are rank deficient by {null.size}")
    G = inner_constraint_basis(state, lay)
    vecs = vec[:, null] * sc[:, None]  # back to parameter units
    if np.any(G):
        # how much of the null space each similarity motion explains
        Gn = G / np.linalg.norm(G, axis=0).clip(1e-300)
        qn, _ = np.linalg.qr(vecs)
        expl = np.linalg.norm(qn.T @ Gn, axis=0)
        free = [m for m, e in zip(_MOTIONS, expl) if e > 0.9]
        # a rotation or scale about another point than the centroid is the motion plus a translation:
        # null directions inside the span of the motions name their rotation/scale parts
        on = np.linalg.norm(Gn, axis=0) > 0
        coef, *_ = np.linalg.lstsq(Gn[:, on], qn, rcond=None)
        inside = np.linalg.norm(qn - Gn[:, on] @ coef, axis=0) < 0.1
        if inside.any():
            mags = np.zeros(7)
            mags[on] = np.linalg.norm(coef[:, inside], axis=1)
            for j in range(3, 7):
                if _MOTIONS[j] not in free and mags[j] > 0.3 * mags.max():
                    free.append(_MOTIONS[j] + " (about some point)")
        if free:
            out.append("the datum is not defined: the block can move by " + ", ".join(free)
                       + " without changing any observation (add control points, GNSS positions, or use "
                       "datum='free' for inner constraints)")
            null_rest = null.size - len(free)
        else:
            null_rest = null.size
    else:
        null_rest = null.size
    if null_rest > 0:
        # name the groups involved in the remaining singular directions
        for v in vec[:, null].T[: max(1, null_rest)]:
            big = np.argsort(-np.abs(v))[:4]
            names = [" ".join(lay.labels[j]) for j in big if abs(v[j]) > 0.1]
            if names:
                out.append("these unknowns cannot be separated: " + ", ".join(names))
    return out


def correlation_warnings(cov: Covariance, layout: Layout, limit: float = 0.98, max_items: int = 20) -> list[str]:
    """Words for pairs of reduced unknowns of *different* groups correlated above ``limit`` (and ill-conditioning)."""
    Q = cov.Qcc
    if Q.size == 0:
        return []
    sd = np.sqrt(np.clip(np.diag(Q), 1e-300, None))
    Rm = Q / sd[:, None] / sd[None, :]
    groups = np.array([g for g, _, _ in layout.labels])
    owners = np.array([o for _, o, _ in layout.labels])
    # pose-pose correlations within a station are common and uninteresting; report across groups
    # and for the global groups (lever arm, boresight, shifts, intrinsics) among themselves
    glob = groups != "pose"
    out: list[str] = []
    idx = np.flatnonzero(glob)
    if idx.size == 0:
        return out
    sub = np.abs(Rm[np.ix_(idx, np.arange(len(Q)))])
    for a_i, a in enumerate(idx):
        sub[a_i, a] = 0.0
        same = (groups == groups[a]) & (owners == owners[a])
        sub[a_i, same] = 0.0
    pairs = np.argwhere(sub > limit)
    seen = set()
    for a_i, b in pairs:
        a = idx[a_i]
        key = tuple(sorted((a, b)))
        if key in seen:
            continue
        seen.add(key)
        if groups[b] == "pose":
            # a global unknown correlated with a pose: summarise per group
            pass
        out.append(f"{' '.join(layout.labels[a])} and {' '.join(layout.labels[b])} are correlated at "
                   f"{Rm[a, b]:+.3f}: this block cannot separate them (near-singular)")
        if len(out) >= max_items:
            break
    return out
