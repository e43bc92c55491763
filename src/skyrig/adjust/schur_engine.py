"""The compiled Schur-complement engine of :func:`skyrig.adjust.solver.levenberg_marquardt` (numba).

The reduced camera system is accumulated per observation directly into a block pattern fixed for the
whole solve, per *unit* (the distinct reduced-column sets of the image rows), and trust-region retries
reuse everything but the damped point inverses and the Schur product (see the section comment below and
:mod:`skyrig.adjust.solver` for the normal equations).  The scipy path of :mod:`skyrig.adjust.solver`
(:func:`~skyrig.adjust.solver.assemble`, :func:`~skyrig.adjust.solver.schur_matrix`) stays the reference.
"""

from __future__ import annotations


import numpy as np
import scipy.linalg
import scipy.sparse as sp
from numpy.typing import NDArray

from skyrig.adjust import linalg as _linalg
from skyrig.adjust.linalg import _blas_single_thread
from skyrig.adjust.model import Factor, Layout
from skyrig.errors import ConfigError, SingularError


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


def _units(cols: NDArray[np.int64], group: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Units of image rows: ``(ucols (U, k), unit of each row (n,))``, the distinct reduced-column sets.

    Rows of one image (``group``) share their columns ``cols (n, k)``; images with the same columns (the
    heads of one rig exposure when only poses are free) are merged into one unit.
    """
    n_img = int(group.max()) + 1 if len(group) else 0
    gcols = np.full((n_img, cols.shape[1]), -1, np.int64)
    gcols[group] = cols
    if not np.array_equal(gcols[group], cols):  # rows of one image differ (per-row columns: correction-grid
        ucols, row_unit = np.unique(cols, axis=0, return_inverse=True)  # nodes): a unit per distinct column set
        return ucols, row_unit.reshape(-1).astype(np.int64)
    ucols, img_unit = np.unique(gcols, axis=0, return_inverse=True)
    return ucols, img_unit.reshape(-1)[group].astype(np.int64)


def _predicted_decrease(lam: float, diag_u: NDArray[np.float64], V: NDArray[np.float64], gc: NDArray[np.float64],
                        gp: NDArray[np.float64], dc: NDArray[np.float64], dp: NDArray[np.float64],
                        diag_min: float) -> float:
    """Decrease of the linear model by the step solving ``(A + lam D) d = -g``: ``0.5 d^T (lam D d - g)``,
    ``D`` the diagonal of ``A`` (``diag_u`` of ``U``, the diagonals of the point blocks ``V``) clipped below
    at ``diag_min``."""
    du = np.clip(diag_u, diag_min, None)
    dv = np.clip(np.diagonal(V, axis1=1, axis2=2), diag_min, None).reshape(-1)
    dpf = dp.reshape(-1)
    return float(0.5 * (lam * (du * dc * dc).sum() + lam * (dv * dpf * dpf).sum()
                        - (gc * dc).sum() - (gp.reshape(-1) * dpf).sum()))


#: entries of the per-row products ``J^T J`` formed at once by :func:`set_normals` (32 MB of float64)
SET_CHUNK_ENTRIES = 4_000_000


def column_sets(cols: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The distinct column sets of a factor's rows: ``(set_cols (G, kf), set_of_row (n,))``.

    Rows that share their columns (the square-root rows of one laser plane, :mod:`skyrig.adjust.factors.lidar`)
    share one ``kf x kf`` block of the normal equations: kept per set, not per row, the normals' memory is that of
    the sets (planes), whatever the rows (points)."""
    cols = np.asarray(cols, np.int64)
    if len(cols) == 0:
        return np.zeros((0, cols.shape[1]), np.int64), np.zeros(0, np.int64)
    sc, inv = np.unique(cols, axis=0, return_inverse=True)
    return np.ascontiguousarray(sc, np.int64), np.asarray(inv, np.int64).reshape(-1)


def set_normals(jc: NDArray[np.float64], r: NDArray[np.float64], sw: NDArray[np.float64],
                set_of_row: NDArray[np.int64], n_sets: int, chunk_entries: int = SET_CHUNK_ENTRIES
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(J^T J (G, kf, kf), J^T r (G, kf))`` of the rows ``jc (n, d, kf)``, ``r (n, d)`` scaled by ``sw (n,)``,
    summed per column set (:func:`column_sets`).  Sets of many rows (a laser plane's): one product of the set's
    stacked rows each, no per-row ``kf x kf`` product; else the rows in set order (stable: each set's rows in their
    own order), ``chunk_entries / kf^2`` at a time.  The memory is the sets' blocks and one set or chunk."""
    n, d, kf = jc.shape
    kk = kf * kf
    order = np.argsort(set_of_row, kind="stable")
    if n >= 4 * n_sets:
        JtJ3 = np.zeros((n_sets, kf, kf))
        g = np.zeros((n_sets, kf))
        ptr = np.concatenate([[0], np.cumsum(np.bincount(set_of_row, minlength=n_sets))])
        for s_ in np.flatnonzero(np.diff(ptr)):
            o = order[ptr[s_]:ptr[s_ + 1]]
            A = (jc[o] * sw[o, None, None]).reshape(-1, kf)
            JtJ3[s_] = A.T @ A
            g[s_] = A.T @ (r[o] * sw[o, None]).reshape(-1)
        return JtJ3, g
    JtJ = np.zeros((n_sets, kk))
    g = np.zeros((n_sets, kf))
    step = max(1, chunk_entries // max(1, kk, d * kf))
    for s0 in range(0, n, step):
        o = order[s0:s0 + step]
        s = set_of_row[o]
        lo, hi = int(s[0]), int(s[-1]) + 1
        loc = s - lo
        j = jc[o] * sw[o, None, None]
        rw = r[o] * sw[o, None]
        JtJ[lo:hi] += np.bincount((loc[:, None] * kk + np.arange(kk)).reshape(-1),
                                  np.einsum("nda,ndb->nab", j, j).reshape(-1), (hi - lo) * kk).reshape(hi - lo, kk)
        g[lo:hi] += np.bincount((loc[:, None] * kf + np.arange(kf)).reshape(-1),
                                np.einsum("ndk,nd->nk", j, rw).reshape(-1), (hi - lo) * kf).reshape(hi - lo, kf)
    return JtJ.reshape(n_sets, kf, kf), g

# ============================================================================ compiled Schur engine
# The levenberg_marquardt loop builds the reduced camera system directly from per-observation blocks:
# rows of the "image" factor are grouped into *units* (the distinct sets of reduced columns: a station
# when only poses are free, so that all heads of a rig exposure share one block; an image when each
# head has its own boresight or camera columns), the point blocks are eliminated point by point and the
# k x k unit-pair blocks ``-sum_p W_ap V_p^-1 W_bp^T`` are accumulated in place (numba, parallel over
# unit rows, each thread writing only its own row) into a block pattern computed once per solve.  The
# global sparse pattern of ``S`` and the maps from unit blocks and from the other factors to it are
# symbolic too; only the values change between iterations and trust-region retries.

try:  # numba is a dependency; the scipy path above stays as the reference and the fallback
    import numba as _numba
except ImportError:  # pragma: no cover - depends on the environment
    _numba = None  # type: ignore[assignment]

HAVE_NUMBA = _numba is not None


def _make_kernels():
    if _numba is None:  # pragma: no cover
        return None
    njit, prange = _numba.njit, _numba.prange

    @njit(cache=True, nogil=True)
    def point_normals(pt, jp, r, w, V, gp):  # pragma: no cover - compiled
        n, d = r.shape
        for o in range(n):
            p = pt[o]
            if p < 0 or w[o] == 0.0:
                continue
            wo = w[o]
            for a in range(3):
                s = 0.0
                for e in range(d):
                    s += jp[o, e, a] * r[o, e]
                gp[p, a] += wo * s
                for b in range(3):
                    s = 0.0
                    for e in range(d):
                        s += jp[o, e, a] * jp[o, e, b]
                    V[p, a, b] += wo * s

    @njit(cache=True, nogil=True, parallel=True)
    def unit_normals(unit_ptr, unit_obs, jc, jp, r, w, pt, Uu, gu, W, wpos):  # pragma: no cover - compiled
        # W[wpos[o]]: the k x 3 block of row o, stored transposed (3, k) so that the Schur product's inner
        # loop runs over contiguous memory (W kept once, in the order the Schur product reads it)
        d = jc.shape[1]
        k = jc.shape[2]
        n_u = len(unit_ptr) - 1
        for u in prange(n_u):
            for ii in range(unit_ptr[u], unit_ptr[u + 1]):
                o = unit_obs[ii]
                wo = w[o]
                for a in range(k):
                    s = 0.0
                    for e in range(d):
                        s += jc[o, e, a] * r[o, e]
                    gu[u, a] += wo * s
                    for b in range(a, k):
                        s = 0.0
                        for e in range(d):
                            s += jc[o, e, a] * jc[o, e, b]
                        Uu[u, a, b] += wo * s
                    if pt[o] >= 0:
                        for b in range(3):
                            s = 0.0
                            for e in range(d):
                                s += jc[o, e, a] * jp[o, e, b]
                            W[wpos[o], b, a] = wo * s
            for a in range(k):
                for b in range(a):
                    Uu[u, a, b] = Uu[u, b, a]

    @njit(cache=True, nogil=True, parallel=True)
    def damped_inverse(V, lam, diag_min, Vinv):  # pragma: no cover - compiled
        n = V.shape[0]
        bad = 0
        for p in prange(n):
            a00 = V[p, 0, 0] + lam * max(V[p, 0, 0], diag_min)
            a11 = V[p, 1, 1] + lam * max(V[p, 1, 1], diag_min)
            a22 = V[p, 2, 2] + lam * max(V[p, 2, 2], diag_min)
            a01 = V[p, 0, 1]
            a02 = V[p, 0, 2]
            a12 = V[p, 1, 2]
            c00 = a11 * a22 - a12 * a12
            c01 = a02 * a12 - a01 * a22
            c02 = a01 * a12 - a02 * a11
            det = a00 * c00 + a01 * c01 + a02 * c02
            if not (det > 0.0) or not np.isfinite(det):
                bad += 1
                det = np.inf
            i = 1.0 / det
            Vinv[p, 0, 0] = c00 * i
            Vinv[p, 0, 1] = c01 * i
            Vinv[p, 0, 2] = c02 * i
            Vinv[p, 1, 0] = c01 * i
            Vinv[p, 1, 1] = (a00 * a22 - a02 * a02) * i
            Vinv[p, 1, 2] = (a01 * a02 - a00 * a12) * i
            Vinv[p, 2, 0] = c02 * i
            Vinv[p, 2, 1] = (a01 * a02 - a00 * a12) * i
            Vinv[p, 2, 2] = (a00 * a11 - a01 * a01) * i
        return bad

    @njit(cache=True, nogil=True, parallel=True)
    def schur(unit_ptr, unit_obs, obs_unit, pt, pt_ptr, upt, wpos, Wp, Vinv, gp, row_ptr, col_idx,
              out, rhs_u, n_chunks):  # pragma: no cover - compiled
        # Wp, upt: W blocks and units of the rows in point order (pt_obs), read sequentially per point;
        # wpos: the position of a row in that order
        n_u = len(unit_ptr) - 1
        k = Wp.shape[2]
        # each chunk (thread) takes every n_chunks-th unit row (balance) and keeps a dense column -> slot
        # map of the row it works on
        for c in prange(n_chunks):
            T = np.empty((k, 3))
            slot = np.full(n_u, -1, np.int64)
            for u in range(c, n_u, n_chunks):
                r0 = row_ptr[u]
                r1 = row_ptr[u + 1]
                for q in range(r0, r1):
                    slot[col_idx[q]] = q
                for ii in range(unit_ptr[u], unit_ptr[u + 1]):
                    a = unit_obs[ii]
                    p = pt[a]
                    if p < 0:
                        continue
                    wa = wpos[a]
                    for i in range(k):
                        for cc in range(3):
                            T[i, cc] = Wp[wa, 0, i] * Vinv[p, 0, cc] + Wp[wa, 1, i] * Vinv[p, 1, cc] + Wp[wa, 2, i] * Vinv[p, 2, cc]
                        rhs_u[u, i] += T[i, 0] * gp[p, 0] + T[i, 1] * gp[p, 1] + T[i, 2] * gp[p, 2]
                    for jj in range(pt_ptr[p], pt_ptr[p + 1]):
                        ub = upt[jj]
                        if ub < u:
                            continue
                        q = slot[ub]
                        for i in range(k):
                            t0 = T[i, 0]
                            t1 = T[i, 1]
                            t2 = T[i, 2]
                            for j in range(k):
                                out[q, i, j] -= t0 * Wp[jj, 0, j] + t1 * Wp[jj, 1, j] + t2 * Wp[jj, 2, j]
                for q in range(r0, r1):
                    slot[col_idx[q]] = -1

    @njit(cache=True, nogil=True)
    def scatter(vals, map_a, map_b, dst):  # pragma: no cover - compiled
        for e in range(len(vals)):
            m = map_a[e]
            if m >= 0:
                dst[m] += vals[e]
            m = map_b[e]
            if m >= 0:
                dst[m] += vals[e]

    @njit(cache=True, nogil=True, parallel=True)
    def back_substitute(pt_ptr, upt, Wp, dcu, Vinv, gp, dp):  # pragma: no cover - compiled
        n_p = len(pt_ptr) - 1
        k = Wp.shape[2]
        for p in prange(n_p):
            t0 = gp[p, 0]
            t1 = gp[p, 1]
            t2 = gp[p, 2]
            for jj in range(pt_ptr[p], pt_ptr[p + 1]):
                u = upt[jj]
                for i in range(k):
                    x = dcu[u, i]
                    t0 += Wp[jj, 0, i] * x
                    t1 += Wp[jj, 1, i] * x
                    t2 += Wp[jj, 2, i] * x
            for c in range(3):
                dp[p, c] = -(Vinv[p, c, 0] * t0 + Vinv[p, c, 1] * t1 + Vinv[p, c, 2] * t2)

    @njit(cache=True, nogil=True)
    def pair_pattern(unit_ptr, unit_obs, pt, pt_ptr, pt_obs, obs_unit):  # pragma: no cover - compiled
        n_u = len(unit_ptr) - 1
        mark = np.full(n_u, -1, np.int64)
        row_ptr = np.zeros(n_u + 1, np.int64)
        cap = 1024
        cols = np.empty(cap, np.int64)
        n = 0
        for u in range(n_u):
            start = n
            if mark[u] != u:  # the diagonal block is always there
                mark[u] = u
                if n == cap:
                    cap *= 2
                    cols = np.concatenate((cols, np.empty(cap - n, np.int64)))
                cols[n] = u
                n += 1
            for ii in range(unit_ptr[u], unit_ptr[u + 1]):
                p = pt[unit_obs[ii]]
                if p < 0:
                    continue
                for jj in range(pt_ptr[p], pt_ptr[p + 1]):
                    ub = obs_unit[pt_obs[jj]]
                    if ub >= u and mark[ub] != u:
                        mark[ub] = u
                        if n == cap:
                            cap *= 2
                            cols = np.concatenate((cols, np.empty(cap - n, np.int64)))
                        cols[n] = ub
                        n += 1
            cols[start:n] = np.sort(cols[start:n])
            row_ptr[u + 1] = n
        return row_ptr, cols[:n].copy()

    @njit(cache=True, nogil=True, parallel=True)
    def csr_positions(indptr, indices, r, c, out):  # pragma: no cover - compiled
        # position of entry (r[e], c[e]) in a CSR pattern with sorted rows; -1 where r or c is negative
        for e in prange(len(r)):
            i = r[e]
            j = c[e]
            if i < 0 or j < 0:
                out[e] = -1
                continue
            lo = indptr[i]
            hi = indptr[i + 1]
            while lo < hi:
                mid = (lo + hi) >> 1
                if indices[mid] < j:
                    lo = mid + 1
                else:
                    hi = mid
            out[e] = lo

    return dict(point_normals=point_normals, unit_normals=unit_normals, damped_inverse=damped_inverse,
                schur=schur, scatter=scatter, back_substitute=back_substitute, pair_pattern=pair_pattern,
                csr_positions=csr_positions)


_K = _make_kernels()


def _csr_pattern(keys: NDArray[np.int64], n: int) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Sorted unique keys ``row * n + col`` -> (keys, indptr, indices)."""
    keys = np.sort(keys)
    keys = keys[np.concatenate([[True], keys[1:] != keys[:-1]])] if len(keys) else keys
    rows = keys // max(n, 1)
    indptr = np.zeros(n + 1, np.int64)
    indptr[1:] = np.cumsum(np.bincount(rows, minlength=n))
    return keys, indptr, keys - rows * n


class SchurEngine:
    """Reduced camera system of a :class:`Model` with a fixed sparsity pattern (see the section comment).

    ``linearize(factors)`` takes the factors of one state (with Jacobians); ``solve(lam)`` returns the
    damped step ``(dc (n_c,), dp (n_p, 3), predicted cost decrease)`` of ``(A + lam D) d = -g``,
    ``D = diag(A)`` clipped below at ``diag_min`` (Ceres's Levenberg-Marquardt); it may be called several
    times per linearisation (trust-region retries) and reuses everything that does not depend on ``lam``.
    """

    def __init__(self, factors: list[Factor], layout: Layout, image_group: NDArray[np.int64],
                 diag_min: float = 1e-6, dense_limit: int = 1500, linear_solver: str = "auto") -> None:
        if _K is None:  # pragma: no cover
            raise RuntimeError("SchurEngine needs numba")
        self._check_solver(linear_solver)
        self._rs: _linalg.ReducedSolver | None = None
        #: PCG's relative residual (Ceres's eta)
        self.eta = 0.1
        self.layout, self.diag_min, self.dense_limit = layout, diag_min, dense_limit
        #: "auto" (dense Cholesky up to ``dense_limit`` unknowns, above :func:`skyrig.adjust.linalg.choose`:
        #: CHOLMOD, SuperLU without cvxopt, PCG when the factor would not fit), "dense", "splu", "cholmod",
        #: "cholespy", "pcg"
        self.linear_solver = linear_solver
        n_c, n_p = layout.n_c, layout.n_p
        self.n_c, self.n_p = n_c, n_p
        img = next((f for f in factors if f.name == "image"), None)
        self._img_index = None if img is None else factors.index(img)
        has_jc = img is not None and img.jc is not None and img.cols is not None and img.cols.shape[1] > 0
        # ---- units: distinct column sets of the image rows (rows of one image share their columns)
        n_obs = len(img) if img is not None else 0
        if has_jc:
            ucols, self.obs_unit = _units(img.cols, image_group)  # type: ignore[arg-type, union-attr]
            self.k = ucols.shape[1]
        else:
            ucols, self.obs_unit, self.k = np.zeros((0, 0), np.int64), np.zeros(n_obs, np.int64), 0
        k = self.k
        self.ucols = ucols
        n_u = len(ucols)
        self.n_u = n_u
        pt = img.point if (img is not None and img.point is not None and n_p) else np.full(n_obs, -1, np.int64)
        self.pt = np.ascontiguousarray(pt, np.int64)
        with_pt = np.flatnonzero(self.pt >= 0) if has_jc else np.zeros(0, np.int64)
        order = with_pt[np.argsort(self.pt[with_pt], kind="stable")]
        self.pt_ptr = np.zeros(n_p + 1, np.int64)
        self.pt_ptr[1:] = np.cumsum(np.bincount(self.pt[order], minlength=n_p))
        self.pt_obs = order
        uorder = np.argsort(self.obs_unit, kind="stable") if has_jc else np.zeros(0, np.int64)
        self.unit_ptr = np.zeros(n_u + 1, np.int64)
        self.unit_ptr[1:] = np.cumsum(np.bincount(self.obs_unit, minlength=n_u)) if has_jc else 0
        self.unit_obs = uorder
        self.upt = self.obs_unit[self.pt_obs]  # unit of each row in point order
        self.wpos = np.full(n_obs, -1, np.int64)  # position of each row in point order (its W block)
        self.wpos[self.pt_obs] = np.arange(len(self.pt_obs))
        # ---- unit-pair block pattern (upper triangle incl. diagonal)
        if has_jc:
            self.row_ptr, self.col_idx = _K["pair_pattern"](self.unit_ptr, self.unit_obs, self.pt, self.pt_ptr,
                                                            self.pt_obs, self.obs_unit)
            self.diag_slot = self.row_ptr[:-1].copy()  # rows start with their diagonal block (sorted, ub >= u)
            ua = np.repeat(np.arange(n_u), np.diff(self.row_ptr))
            ub = self.col_idx
        else:
            self.row_ptr, self.col_idx = np.zeros(n_u + 1, np.int64), np.zeros(0, np.int64)
            self.diag_slot, ua, ub = np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
        # ---- global pattern of S: unit blocks (and mirrors), other factors, the diagonal (built row by
        # row, no per-entry keys or maps: skyrig.adjust.linalg.schur_pattern)
        # (the other factors by their distinct column sets: one block per set, not per row)
        oth_cols = [(i, *column_sets(f.cols)) for i, f in enumerate(factors)
                    if i != self._img_index and f.jc is not None and f.cols is not None and f.cols.shape[1] > 0]
        self.indptr, self.indices = _linalg.schur_pattern(n_c, ucols if has_jc else np.zeros((0, 0), np.int64),
                                                          self.row_ptr, self.col_idx, [c for _, c, _ in oth_cols])
        self.nnz = len(self.indices)

        def pos(r_: NDArray[np.int64], c_: NDArray[np.int64]) -> NDArray[np.int64]:
            # a binary search within each entry's CSR row (short rows, in cache) instead of over all keys
            out = np.empty(len(r_), np.int64)
            _K["csr_positions"](self.indptr, self.indices, np.ascontiguousarray(r_), np.ascontiguousarray(c_), out)
            return out

        #: per other factor: its column sets, the set of each row, the positions of each set's block in the pattern
        self.others: list[tuple[int, tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]]] = []
        for i, c, srow in oth_cols:
            kf = c.shape[1]
            self.others.append((i, (c, srow, pos(np.broadcast_to(c[:, :, None], (len(c), kf, kf)).reshape(-1),
                                                 np.broadcast_to(c[:, None, :], (len(c), kf, kf)).reshape(-1)))))
        diag = np.arange(n_c, dtype=np.int64)
        self.diagpos = pos(diag, diag)
        self.rows = np.repeat(np.arange(n_c, dtype=np.int64), np.diff(self.indptr))
        # the entries of each unit's diagonal block (for U of the image factor)
        self._diag_map = pos(np.broadcast_to(ucols[:, :, None], (n_u, k, k)).reshape(-1),
                             np.broadcast_to(ucols[:, None, :], (n_u, k, k)).reshape(-1)) if has_jc \
            else np.zeros(0, np.int64)

    @staticmethod
    def _check_solver(linear_solver: str) -> None:
        if linear_solver not in ("auto", "dense", "splu", "cholmod", "cholespy", "pcg"):
            raise ConfigError(f"linear_solver must be auto, dense, splu, cholmod, cholespy or pcg, got {linear_solver!r}")

    # ------------------------------------------------------------------ per linearisation
    def linearize(self, factors: list[Factor], huber_k: float | None = None) -> float:
        """Take the factors (with Jacobians) of the current state; returns the cost."""
        n_c, n_p, k = self.n_c, self.n_p, self.k
        cost = 0.0
        U0 = np.zeros(self.nnz)
        gc = np.zeros(n_c)
        V = np.zeros((n_p, 3, 3))
        gp = np.zeros((n_p, 3))
        if not hasattr(self, "Wp"):
            self.Wp = np.zeros((0, 3, k))
        oth = dict(self.others)
        for i, f in enumerate(factors):
            sw, c = _robust(f, huber_k)
            cost += c
            w = np.ascontiguousarray(sw * sw)
            r = np.ascontiguousarray(f.r)
            jp = None
            if f.jp is not None and f.point is not None and n_p:
                jp = np.ascontiguousarray(f.jp)
                _K["point_normals"](np.ascontiguousarray(f.point, np.int64), jp, r, w, V, gp)
            if i == self._img_index:
                if k == 0:
                    continue
                jc = np.ascontiguousarray(f.jc)
                Uu = np.zeros((self.n_u, k, k))
                gu = np.zeros((self.n_u, k))
                if self.Wp.shape != (len(self.pt_obs), 3, k):  # kept between linearisations: written in full
                    self.Wp = np.empty((len(self.pt_obs), 3, k))  # point order: the Schur product reads them so
                _K["unit_normals"](self.unit_ptr, self.unit_obs, jc, jp if jp is not None else np.zeros((len(f), r.shape[1], 3)),
                                   r, w, self.pt, Uu, gu, self.Wp, self.wpos)
                m = self._diag_map
                v = m >= 0
                U0 += np.bincount(m[v], weights=Uu.reshape(-1)[v], minlength=self.nnz)
                cv = self.ucols >= 0
                gc += np.bincount(self.ucols[cv], weights=gu[cv], minlength=n_c)
                continue
            if i not in oth:
                continue
            if f.jc is None or f.cols is None:  # (a row touching no reduced column: nothing to add)
                continue
            sc, srow, m = oth[i]
            if len(srow) != len(f):
                raise RuntimeError(f"factor {f.name!r} has {len(f)} rows, the engine was built for {len(srow)}")
            jtj, g = set_normals(f.jc, r, sw, srow, len(sc))
            valid = sc >= 0
            gc += np.bincount(sc[valid], weights=g[valid], minlength=n_c)
            v = m >= 0
            U0 += np.bincount(m[v], weights=jtj.reshape(-1)[v], minlength=self.nnz)
        self.cost, self.U0, self.gc, self.V, self.gp = cost, U0, gc, V, gp
        self.diagU = U0[self.diagpos]
        return cost

    def gradient_max(self) -> float:
        return float(max(np.abs(self.gc).max(initial=0.0), np.abs(self.gp).max(initial=0.0)))

    # ------------------------------------------------------------------ per damping
    def reduced_system(self, lam: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """CSR values of the damped ``S`` (pattern ``indptr``/``indices``), its right-hand side, ``V^-1``."""
        n_p, k = self.n_p, self.k
        Vinv = np.empty((n_p, 3, 3))
        if n_p and _K["damped_inverse"](self.V, lam, self.diag_min, Vinv):
            raise SingularError("a point's normal block is singular (fewer than two rays and no control)")
        S = self.U0.copy()
        S[self.diagpos] += lam * np.clip(self.diagU, self.diag_min, None)
        rhs = -self.gc.copy()
        if k and n_p and len(self.Wp):
            blocks = np.zeros((len(self.col_idx), k, k))
            rhs_u = np.zeros((self.n_u, k))
            _K["schur"](self.unit_ptr, self.unit_obs, self.obs_unit, self.pt, self.pt_ptr, self.upt, self.wpos, self.Wp,
                        Vinv, self.gp, self.row_ptr, self.col_idx, blocks, rhs_u, 8 * _numba.get_num_threads())
            _linalg.scatter_unit_pairs(blocks, self.row_ptr, self.col_idx, self.ucols, self.indptr, self.indices, S)
            cv = self.ucols >= 0
            rhs += np.bincount(self.ucols[cv], weights=rhs_u[cv], minlength=self.n_c)
        return S, rhs, Vinv

    def solve(self, lam: float, G: NDArray[np.float64] | None = None
              ) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        """Damped step ``(dc, dp, predicted decrease)``; raises :class:`SingularError`."""
        n_c, n_p = self.n_c, self.n_p
        S, rhs, Vinv = self.reduced_system(lam)
        dc = self._solve_csr(S, rhs, G) if n_c else np.zeros(0)
        dp = np.zeros((n_p, 3))
        if n_p:
            dcu = np.where(self.ucols >= 0, np.concatenate([dc, [0.0]])[self.ucols], 0.0) if self.k else \
                np.zeros((self.n_u, 0))
            Wp = self.Wp if len(self.Wp) else np.zeros((0, 3, self.k))
            _K["back_substitute"](self.pt_ptr, self.upt, Wp, np.ascontiguousarray(dcu), Vinv, self.gp, dp)
        pred = _predicted_decrease(lam, self.diagU, self.V, self.gc, self.gp, dc, dp, self.diag_min)
        if self._rs is not None and self._rs.method == "pcg" and n_c:
            # inexact: (A + lam D) d = -g + e, e = (S dc - rhs, 0) (dp is exact given dc); the model
            # decrease is the exact-step formula less 0.5 d.e
            Sm = sp.csr_matrix((S, self.indices, self.indptr), shape=(n_c, n_c))
            pred -= 0.5 * float(dc @ (Sm @ dc - rhs))
        return dc, dp, pred

    def _solve_csr(self, data: NDArray[np.float64], rhs: NDArray[np.float64],
                   G: NDArray[np.float64] | None) -> NDArray[np.float64]:
        n = self.n_c
        d = data[self.diagpos]
        if np.any(d <= 0) or not np.all(np.isfinite(d)):
            raise SingularError(f"{int(np.sum(d <= 0))} reduced unknown(s) have no observations")
        s = 1.0 / np.sqrt(d)
        vals = data * s[self.rows] * s[self.indices]
        b = rhs * s
        method = self.linear_solver
        if method == "auto" and (G is not None or n <= self.dense_limit):
            method = "dense"
        try:
            if method == "dense" or G is not None:
                A = np.zeros((n, n))
                A[self.rows, self.indices] = vals
                if G is not None:
                    Gs = G / s[:, None]
                    Gs /= np.linalg.norm(Gs, axis=0).clip(1e-300)
                    A += Gs @ Gs.T
                with _blas_single_thread():
                    c = scipy.linalg.cho_factor(A, lower=True, check_finite=False)
                    x = scipy.linalg.cho_solve(c, b, check_finite=False)
            else:
                if self._rs is None:
                    self._rs = _linalg.ReducedSolver(self.indptr, self.indices, method, dense_limit=self.dense_limit)
                x = self._rs.solve(vals, b, eta=self.eta)
        except _linalg.NotPositiveDefinite as e:
            raise SingularError(f"the reduced normal matrix is not positive definite ({e})") from e
        except (np.linalg.LinAlgError, ValueError, RuntimeError) as e:
            raise SingularError(f"the reduced normal matrix is not positive definite ({e})") from e
        if not np.all(np.isfinite(x)):
            raise SingularError("the reduced normal matrix is singular (non-finite solution)")
        return x * s


