"""Linear solvers of the reduced camera (Schur) system ``S x = b``: a fixed pattern, factorised many times.

:class:`ReducedSolver` is built once per adjustment from the CSR pattern of ``S`` (which does not change
between iterations) and then solves ``S x = b`` for new values at every damping.  The matrix it gets is
Jacobi-scaled (unit diagonal) by the caller.  Back ends, chosen by :func:`choose` (the reason is logged):

``dense``
    LAPACK Cholesky (``scipy.linalg.cho_factor``) on one BLAS thread: below ``dense_limit`` unknowns,
    where a sparse factorisation's bookkeeping costs more than the dense flops.
``cholmod``
    SuiteSparse CHOLMOD, supernodal, through ``cvxopt`` (whose manylinux wheel carries CHOLMOD and an
    optimised OpenBLAS).  The fill-reducing ordering is METIS nested dissection (``pymetis``) of the
    *compressed* graph (one node per set of columns with the same pattern: a camera's or a station's
    unknowns), else CHOLMOD's own AMD; the symbolic analysis (ordering, elimination tree, supernodes) is
    done once per adjustment, only the numeric factorisation runs per step.  A block-level symbolic
    factorisation (:func:`symbolic_fill`) predicts the factor's size and flops before any numeric work.
``splu``
    SuperLU (``scipy.sparse.linalg.splu``) in symmetric mode, the fallback when cvxopt is missing.
``pcg``
    Inexact: conjugate gradients on ``S`` (explicit, CSR) with the block Jacobi (Schur-Jacobi)
    preconditioner, stopped at a relative residual ``eta`` (Ceres's default 0.1 forcing).  Chosen when the
    predicted factor would exceed ``memory_limit`` bytes or ``flop_limit`` flops.

Measured on the generated BAL blocks of ``bench/bal.py`` (2 loaded cores, one factorisation of the
Jacobi-scaled ``S``): 1,000 cameras (9,000 unknowns, 1.6 M nonzeros): SuperLU 5.4 s, cholespy (CHOLMOD
on reference BLAS) 19 s, MKL PARDISO (pypardiso) 5.3 s, CHOLMOD/cvxopt with METIS 0.7 s numeric;
3,000 cameras (27,000 unknowns, 4.9 M nonzeros): SuperLU 21 s, CHOLMOD/cvxopt 3.5 s numeric.
scikit-sparse 0.5.0 has no wheels (source only, needs a system SuiteSparse) and pydiso none for
CPython 3.11, so neither installs with pip alone on a fresh machine.
"""

from __future__ import annotations

import contextlib
import logging
import os
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import scipy.linalg
import scipy.sparse as sp
from numpy.typing import NDArray

from skyrig.errors import ConfigError, NotPositiveDefinite  # noqa: F401 - NotPositiveDefinite re-exported

logger = logging.getLogger(__name__)

try:  # SuiteSparse CHOLMOD (supernodal, OpenBLAS) as the cvxopt wheels ship it
    from cvxopt import cholmod as _cholmod
    from cvxopt import matrix as _cvx_matrix
    from cvxopt import spmatrix as _cvx_spmatrix
except ImportError:  # pragma: no cover - depends on the environment
    _cholmod = None

try:  # METIS nested dissection
    import pymetis as _pymetis
except ImportError:  # pragma: no cover - depends on the environment
    _pymetis = None  # type: ignore[assignment]

HAVE_CVXOPT_CHOLMOD = _cholmod is not None
HAVE_METIS = _pymetis is not None

__all__ = ["ReducedSolver", "Symbolic", "choose", "symbolic_fill", "supervariables", "nested_dissection",
           "schur_pattern", "scatter_unit_pairs", "HAVE_CVXOPT_CHOLMOD", "HAVE_METIS", "NotPositiveDefinite"]

#: below this many unknowns: dense Cholesky
DENSE_LIMIT = 1500
#: a predicted Cholesky factor larger than this (bytes) makes "auto" choose PCG; default: a quarter
#: of the physical memory
MEMORY_LIMIT = None
#: a predicted factorisation above this many flops makes "auto" choose PCG (about a minute on one core)
FLOP_LIMIT = 3e12


def _blas_single_thread() -> contextlib.AbstractContextManager[Any]:
    """Context: BLAS on one thread (threadpoolctl when installed).  OpenBLAS's threads busy-wait for each
    other; on a loaded machine a small factorisation then takes 100x longer than on one thread."""
    global _TPC
    try:
        if _TPC is None:
            from threadpoolctl import ThreadpoolController

            _TPC = ThreadpoolController()
        return _TPC.limit(limits=1, user_api="blas")
    except Exception:  # pragma: no cover - threadpoolctl missing or failing
        return contextlib.nullcontext()


_TPC: Any = None


def _physical_memory() -> int:
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover
        return 8 << 30


def supervariables(indptr: NDArray[np.int64], indices: NDArray[np.int64]
                   ) -> tuple[NDArray[np.int64], sp.csr_matrix]:
    """Columns with identical patterns grouped: ``(node of each column (n,), node graph (CSR, no diagonal))``."""
    n = len(indptr) - 1
    lens = np.diff(indptr)
    # hash each row's pattern (two independent random projections of its column indices) then confirm
    rng = np.random.default_rng(12345)
    w1 = rng.integers(1, 2**61, n, dtype=np.int64)
    w2 = rng.integers(1, 2**61, n, dtype=np.int64)
    rows = np.repeat(np.arange(n), lens)
    h1 = np.zeros(n, np.int64)
    h2 = np.zeros(n, np.int64)
    with np.errstate(over="ignore"):
        np.add.at(h1, rows, w1[indices])
        np.add.at(h2, rows, w2[indices])
    key = np.stack([h1, h2, lens], axis=1)
    _, node = np.unique(key, axis=0, return_inverse=True)
    node = node.reshape(-1).astype(np.int64)
    m = int(node.max()) + 1 if n else 0
    Q = sp.csr_matrix((np.ones(n), (node, np.arange(n))), shape=(m, n))
    A = sp.csr_matrix((np.ones(len(indices)), indices, indptr), shape=(n, n))
    G = (Q @ A @ Q.T).tocsr()
    G.setdiag(0)
    G.eliminate_zeros()
    G.sort_indices()
    return node, G


def nested_dissection(G: sp.csr_matrix) -> NDArray[np.int64] | None:
    """METIS nested dissection order of a graph's nodes (``None`` without pymetis)."""
    if _pymetis is None or G.shape[0] < 3:
        return None
    adj = _pymetis.CSRAdjacency(G.indptr.astype(np.int64), G.indices.astype(np.int64))
    perm, _ = _pymetis.nested_dissection(adj)
    return np.asarray(perm, np.int64)


@dataclass
class Symbolic:
    """The block-level symbolic Cholesky factorisation in a node order."""

    n: int
    nodes: int
    order: NDArray[np.int64]  # scalar column order (a permutation of range(n))
    factor_nnz: float  # nonzeros of L (lower triangle incl. diagonal)
    flops: float  # of the numeric factorisation (sum over columns of colcount^2)
    ordering: str


def symbolic_fill(node: NDArray[np.int64], G: sp.csr_matrix, node_order: NDArray[np.int64]) -> tuple[float, float]:
    """Predicted ``(nnz(L), flops)`` of the Cholesky factor of a matrix whose compressed graph is ``G``
    (node sizes from ``node``), nodes eliminated in ``node_order``: the elimination tree on nodes, each
    node's structure the union of its later neighbours and its children's structures."""
    m = G.shape[0]
    size = np.bincount(node, minlength=m).astype(np.float64)
    rank = np.empty(m, np.int64)
    rank[node_order] = np.arange(m)
    Gp = G[node_order][:, node_order].tocsr()
    Gp.sort_indices()
    sizep = size[node_order]
    children: list[list[int]] = [[] for _ in range(m)]
    structs: list[NDArray[np.int64] | None] = [None] * m
    nnz = flops = 0.0
    for j in range(m):
        nb = Gp.indices[Gp.indptr[j]:Gp.indptr[j + 1]]
        parts = [nb[nb > j]]
        for c in children[j]:
            s = structs[c]
            parts.append(s[s > j])  # type: ignore[index, operator]
            structs[c] = None
        st = np.unique(np.concatenate(parts)) if len(parts) > 1 else parts[0]
        structs[j] = st
        if len(st):
            children[int(st[0])].append(j)
        below = float(sizep[st].sum())
        s = sizep[j]
        nnz += s * (s + 1) / 2 + s * below
        # column i of the diagonal block has (s - i) + below entries
        t = np.arange(s, 0, -1) + below
        flops += float((t * t).sum())
    return nnz, flops


class ReducedSolver:
    """Solves ``A x = b`` for a fixed CSR pattern of a symmetric positive definite ``A`` (values given per
    call, Jacobi-scaled: unit diagonal); see the module docstring for the back ends.

    ``method``: ``"auto"`` (:func:`choose`), ``"dense"``, ``"cholmod"``, ``"splu"``, ``"pcg"``.
    """

    def __init__(self, indptr: NDArray[np.int64], indices: NDArray[np.int64], method: str = "auto",
                 dense_limit: int = DENSE_LIMIT, blocks: NDArray[np.int64] | None = None,
                 memory_limit: float | None = None, flop_limit: float | None = None) -> None:
        if method not in ("auto", "dense", "cholmod", "splu", "pcg", "cholespy"):
            raise ConfigError(f"linear solver must be auto, dense, cholmod, splu, pcg or cholespy, got {method!r}")
        self.indptr = np.asarray(indptr, np.int64)
        self.indices = np.asarray(indices, np.int64)
        self.n = n = len(self.indptr) - 1
        self.rows = np.repeat(np.arange(n, dtype=np.int64), np.diff(self.indptr))
        self.symbolic: Symbolic | None = None
        self.blocks = blocks
        self.method, self.reason = choose(self, method, dense_limit, memory_limit, flop_limit)
        logger.info("reduced system: %s (%s)", self.method, self.reason)
        self._F = None
        self._M = None
        self.pcg_iterations: list[int] = []

    # ---------------------------------------------------------------------------- analysis
    def analyse(self) -> Symbolic:
        """Block-level ordering and symbolic factorisation (cached)."""
        if self.symbolic is None:
            node, G = supervariables(self.indptr, self.indices)
            norder = nested_dissection(G)
            name = "METIS nested dissection"
            if norder is None:
                name = "natural (no pymetis)"
                norder = np.arange(G.shape[0], dtype=np.int64)
            nnz, flops = symbolic_fill(node, G, norder)
            rank = np.empty(len(norder), np.int64)
            rank[norder] = np.arange(len(norder))
            order = np.argsort(rank[node], kind="stable")
            self.symbolic = Symbolic(self.n, G.shape[0], order, nnz, flops, name)
        return self.symbolic

    # ---------------------------------------------------------------------------- solve
    def solve(self, vals: NDArray[np.float64], b: NDArray[np.float64], eta: float = 0.1) -> NDArray[np.float64]:
        """``x`` of ``A x = b`` (``b`` ``(n,)`` or ``(n, m)``), ``A`` the pattern with ``vals``; raises
        :class:`NotPositiveDefinite`.  ``eta``: PCG's relative residual."""
        m = self.method
        if m == "dense":
            return self._dense(vals, b)
        if m == "cholmod":
            return self._cholmod(vals, b)
        if m == "pcg":
            return self._pcg(vals, b, eta)
        if m == "cholespy":
            import cholespy

            s = cholespy.CholeskySolverD(self.n, self.indptr.astype(np.int32), self.indices.astype(np.int32),
                                         np.ascontiguousarray(vals), cholespy.MatrixType.CSR)
            x = np.zeros_like(b)
            s.solve(np.ascontiguousarray(b), x)
            return x
        return self._splu(vals, b)

    def _dense(self, vals: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
        A = np.zeros((self.n, self.n))
        A[self.rows, self.indices] = vals
        try:
            with _blas_single_thread():
                c = scipy.linalg.cho_factor(A, lower=True, check_finite=False)
                return scipy.linalg.cho_solve(c, b, check_finite=False)
        except np.linalg.LinAlgError as e:
            raise NotPositiveDefinite(str(e)) from e

    def _splu(self, vals: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
        import scipy.sparse.linalg as spl

        A = sp.csc_matrix(sp.csr_matrix((vals, self.indices, self.indptr), shape=(self.n, self.n)))
        try:
            lu = spl.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        except RuntimeError as e:
            raise NotPositiveDefinite(str(e)) from e
        piv = lu.U.diagonal()
        if not (piv.min(initial=1.0) > 1e-14) or np.any(lu.perm_r != lu.perm_c):
            raise NotPositiveDefinite(f"smallest pivot {piv.min(initial=1.0):.3g}")
        return lu.solve(b)

    def _cholmod(self, vals: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
        if self._M is None:
            sym = self.analyse()
            # lower triangle in column-major order == upper triangle of the CSR rows
            self._upper = np.flatnonzero(self.indices >= self.rows)
            r, c = self.indices[self._upper], self.rows[self._upper]  # (row >= col): lower triangle
            self._M = _cvx_spmatrix(_cvx_matrix(np.ones(len(r))), _cvx_matrix(r), _cvx_matrix(c), (self.n, self.n))
            self._F = _cholmod.symbolic(self._M, uplo="L", p=_cvx_matrix(sym.order))
        self._M.V = _cvx_matrix(np.ascontiguousarray(vals[self._upper]))  # type: ignore[attr-defined]
        try:
            _cholmod.numeric(self._M, self._F)
        except ArithmeticError as e:
            raise NotPositiveDefinite(str(e)) from e
        d = np.asarray(_cholmod.diag(self._F)).reshape(-1)
        if not (d.min(initial=1.0) ** 2 > 1e-14):
            raise NotPositiveDefinite(f"smallest pivot {d.min(initial=1.0) ** 2:.3g}")
        B = _cvx_matrix(np.asfortranarray(b, dtype=np.float64))
        _cholmod.solve(self._F, B)
        return np.asarray(B).reshape(b.shape)

    def _pcg(self, vals: NDArray[np.float64], b: NDArray[np.float64], eta: float) -> NDArray[np.float64]:
        """Conjugate gradients with the block Jacobi preconditioner (the diagonal blocks of ``A`` on the
        compressed nodes: a camera's or a station's unknowns), stopped at ``|A x - b| <= eta |b|``."""
        if b.ndim == 2:
            return np.column_stack([self._pcg(vals, b[:, j], min(eta, 1e-10)) for j in range(b.shape[1])])
        A = sp.csr_matrix((vals, self.indices, self.indptr), shape=(self.n, self.n))
        if self._M is None:  # node blocks (once): block of each column, position in it, the in-block entries
            node, _ = supervariables(self.indptr, self.indices)
            sizes = np.bincount(node)
            order = np.argsort(node, kind="stable")
            loc = np.empty(self.n, np.int64)
            loc[order] = np.arange(self.n) - np.repeat(np.concatenate([[0], np.cumsum(sizes)[:-1]]), sizes)
            inblk = np.flatnonzero(node[self.rows] == node[self.indices])
            self._pc = (node, loc, inblk, int(sizes.max()), sizes)
            self._M = True  # type: ignore[assignment]
        node, loc, inblk, smax, sizes = self._pc
        blk = np.zeros((len(sizes), smax, smax))
        blk[node[self.rows[inblk]], loc[self.rows[inblk]], loc[self.indices[inblk]]] = vals[inblk]
        pad = np.arange(smax)[None, :] >= sizes[:, None]
        blk[np.nonzero(pad)[0], np.nonzero(pad)[1], np.nonzero(pad)[1]] = 1.0
        try:
            Minv = np.linalg.inv(blk)
        except np.linalg.LinAlgError as e:
            raise NotPositiveDefinite(str(e)) from e
        Minv = Minv[node]  # (n, smax, smax): the row of the block inverse of each column
        rowsel = Minv[np.arange(self.n), loc]  # (n, smax)
        # z[i] = sum_j Minv[node i][loc i, loc j] r[j] over the columns j of i's block
        members = np.full((len(sizes), smax), -1, np.int64)
        members[node, loc] = np.arange(self.n)
        mem_i = members[node]  # (n, smax)
        valid = mem_i >= 0
        mem_i = np.where(valid, mem_i, 0)
        rowsel = np.where(valid, rowsel, 0.0)

        def prec(r: NDArray[np.float64]) -> NDArray[np.float64]:
            return (rowsel * r[mem_i]).sum(axis=1)

        x = np.zeros_like(b)
        r = b.copy()
        z = prec(r)
        p = z.copy()
        rz = float(r @ z)
        nb = float(np.linalg.norm(b))
        it = 0
        for it in range(1, max(50, 5 * int(np.sqrt(self.n))) + 1):
            q = A @ p
            pq = float(p @ q)
            if not pq > 0:
                raise NotPositiveDefinite("PCG: non-positive curvature")
            a = rz / pq
            x += a * p
            r -= a * q
            if np.linalg.norm(r) <= eta * nb:
                break
            z = prec(r)
            rz_new = float(r @ z)
            p = z + (rz_new / rz) * p
            rz = rz_new
        self.pcg_iterations.append(it)
        return x


# ---------------------------------------------------------------------------- pattern of S, lean
# The reduced matrix S of the Schur engine (skyrig.adjust.schur_engine.SchurEngine) is the sum of k x k blocks
# of unit pairs (a unit: a set of reduced columns shared by image rows, ``ucols[u]``, -1 padded), of the
# blocks of the other factors' column sets, and the diagonal.  Building its CSR pattern by listing every
# block entry (pairs x k^2 keys, twice with the mirrors, then sorting) and keeping an int64 map per entry
# costs ~20 bytes per entry (~2 kB per image observation for a penta rig with free boresights, 28 GiB at
# 10,000 exposures); here the pattern is built row by row with a marker array (memory: the pattern) and
# the unit-pair blocks are scattered by a binary search in their CSR row instead of a stored map.

try:
    import numba as _numba
except ImportError:  # pragma: no cover - numba is a dependency
    _numba = None  # type: ignore[assignment]


def _jit(f):  # module-level kernels: a kernel calling another is cached only when both are module globals
    return _numba.njit(cache=True, nogil=True)(f) if _numba is not None else f


@_jit
def _row_sets(n_c, ucols, adj_ptr, adj, cu_ptr, cu, groups, cg_ptr, cg, fill, indptr, indices):  # pragma: no cover
    # fill=False: count the entries of each row into indptr[r + 1]; fill=True: write them (sorted)
    mark = np.full(n_c, -1, np.int64)
    k = ucols.shape[1]
    kg = groups.shape[1]
    for r in range(n_c):
        n = 0
        base = indptr[r] if fill else 0
        mark[r] = r
        if fill:
            indices[base] = r
        n += 1
        for ii in range(cu_ptr[r], cu_ptr[r + 1]):
            u = cu[ii]
            for jj in range(adj_ptr[u], adj_ptr[u + 1]):
                v = adj[jj]
                for j in range(k):
                    c = ucols[v, j]
                    if c >= 0 and mark[c] != r:
                        mark[c] = r
                        if fill:
                            indices[base + n] = c
                        n += 1
        for ii in range(cg_ptr[r], cg_ptr[r + 1]):
            g = cg[ii]
            for j in range(kg):
                c = groups[g, j]
                if c >= 0 and mark[c] != r:
                    mark[c] = r
                    if fill:
                        indices[base + n] = c
                    n += 1
        if fill:
            indices[base:base + n] = np.sort(indices[base:base + n])
        else:
            indptr[r + 1] = n

@_jit
def _find(indptr, indices, i, j):  # pragma: no cover - compiled
    lo = indptr[i]
    hi = indptr[i + 1]
    while lo < hi:
        mid = (lo + hi) >> 1
        if indices[mid] < j:
            lo = mid + 1
        else:
            hi = mid
    return lo

@_jit
def _add_row(indptr, indices, r, cols, vals, dst):  # pragma: no cover - compiled
    # dst[(r, cols[j])] += vals[j]; the columns of a unit mostly run consecutively, so the next entry
    # is tried before a binary search
    p = -1
    end = indptr[r + 1]
    for j in range(len(cols)):
        c = cols[j]
        if c < 0:
            continue
        if p >= 0 and p + 1 < end and indices[p + 1] == c:
            p += 1
        else:
            p = _find(indptr, indices, r, c)
        dst[p] += vals[j]

@_jit
def _scatter_pairs(blocks, row_ptr, col_idx, ucols, indptr, indices, dst):  # pragma: no cover - compiled
    n_u = len(row_ptr) - 1
    k = ucols.shape[1]
    col = np.empty(k)
    for u in range(n_u):
        for q in range(row_ptr[u], row_ptr[u + 1]):
            v = col_idx[q]
            for i in range(k):
                r = ucols[u, i]
                if r >= 0:
                    _add_row(indptr, indices, r, ucols[v], blocks[q, i], dst)
            if v != u:  # the mirror block: row ucols[v, j] gets column j of the block
                for j in range(k):
                    r = ucols[v, j]
                    if r >= 0:
                        for i in range(k):
                            col[i] = blocks[q, i, j]
                        _add_row(indptr, indices, r, ucols[u], col, dst)


_PK = dict(row_sets=_row_sets, scatter_pairs=_scatter_pairs) if _numba is not None else None


def _csr_of_lists(owner: NDArray[np.int64], item: NDArray[np.int64], n: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """CSR (ptr, items) of ``item`` grouped by ``owner`` in ``range(n)`` (stable)."""
    o = np.argsort(owner, kind="stable")
    ptr = np.zeros(n + 1, np.int64)
    ptr[1:] = np.cumsum(np.bincount(owner, minlength=n))
    return ptr, np.ascontiguousarray(item[o], np.int64)


def schur_pattern(n_c: int, ucols: NDArray[np.int64], row_ptr: NDArray[np.int64], col_idx: NDArray[np.int64],
                  other_cols: Sequence[NDArray[np.int64]] = ()) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """CSR pattern ``(indptr, indices)`` (sorted rows, full symmetric, diagonal included) of the reduced
    matrix: the ``k x k`` blocks ``ucols[u] x ucols[v]`` of the unit pairs (``row_ptr``/``col_idx``: the
    upper block pattern, ``v >= u``) and their mirrors, the blocks ``cols x cols`` of every row of the
    other factors' column sets ``other_cols`` (each ``(m, kf)``), and the diagonal; negative columns are
    left out.  The same set of entries as sorting all block keys, in memory of the order of the pattern."""
    ucols = np.ascontiguousarray(ucols, np.int64)
    if ucols.ndim != 2:
        ucols = ucols.reshape(len(row_ptr) - 1, -1)
    n_u, k = ucols.shape
    ua = np.repeat(np.arange(n_u, dtype=np.int64), np.diff(row_ptr))
    ub = np.asarray(col_idx, np.int64)
    off = ua != ub
    adj_ptr, adj = _csr_of_lists(np.concatenate([ua, ub[off]]), np.concatenate([ub, ua[off]]), n_u)
    del ua, ub, off
    cu_u = np.repeat(np.arange(n_u, dtype=np.int64), k)
    cu_c = ucols.reshape(-1)
    v = cu_c >= 0
    cu_ptr, cu = _csr_of_lists(cu_c[v], cu_u[v], n_c)
    kg = max([c.shape[1] for c in other_cols if c.ndim == 2 and len(c)] + [1])
    groups = np.full((sum(len(c) for c in other_cols), kg), -1, np.int64)
    g0 = 0
    for c in other_cols:
        if len(c):
            groups[g0:g0 + len(c), :c.shape[1]] = c
            g0 += len(c)
    gi = np.repeat(np.arange(len(groups), dtype=np.int64), kg)
    gc = groups.reshape(-1)
    v = gc >= 0
    cg_ptr, cg = _csr_of_lists(gc[v], gi[v], n_c)
    indptr = np.zeros(n_c + 1, np.int64)
    _PK["row_sets"](n_c, ucols, adj_ptr, adj, cu_ptr, cu, groups, cg_ptr, cg, False, indptr, np.zeros(0, np.int64))
    indptr = np.cumsum(indptr)
    indices = np.empty(int(indptr[-1]), np.int64)
    _PK["row_sets"](n_c, ucols, adj_ptr, adj, cu_ptr, cu, groups, cg_ptr, cg, True, indptr, indices)
    return indptr, indices


def scatter_unit_pairs(blocks: NDArray[np.float64], row_ptr: NDArray[np.int64], col_idx: NDArray[np.int64],
                       ucols: NDArray[np.int64], indptr: NDArray[np.int64], indices: NDArray[np.int64],
                       dst: NDArray[np.float64]) -> None:
    """``dst`` (CSR values of the pattern ``indptr``/``indices``) ``+=`` the unit-pair blocks
    ``blocks[q]`` ``(k, k)`` at ``ucols[u] x ucols[col_idx[q]]`` and their mirrors (``u != v``), found by
    a binary search in the CSR row (no stored per-entry map)."""
    _PK["scatter_pairs"](np.ascontiguousarray(blocks).reshape(len(col_idx), ucols.shape[1], ucols.shape[1]),
                         row_ptr, col_idx, np.ascontiguousarray(ucols, np.int64), indptr, indices, dst)


def choose(rs: ReducedSolver, method: str, dense_limit: int, memory_limit: float | None,
           flop_limit: float | None) -> tuple[str, str]:
    """The back end for ``method="auto"`` and the reason, in words."""
    n = rs.n
    if method != "auto":
        if method == "cholmod" and not HAVE_CVXOPT_CHOLMOD:
            return "splu", "CHOLMOD asked for but cvxopt is not installed: SuperLU"
        return method, "asked for"
    if n <= dense_limit:
        return "dense", f"{n} unknowns <= {dense_limit}: dense Cholesky"
    sym = rs.analyse()
    mem = memory_limit if memory_limit is not None else (MEMORY_LIMIT or _physical_memory() / 4)
    fl = flop_limit if flop_limit is not None else FLOP_LIMIT
    what = (f"{n} unknowns in {sym.nodes} blocks, {sym.ordering}: predicted factor {sym.factor_nnz / 1e6:.1f} M "
            f"nonzeros ({sym.factor_nnz * 8 / 2**20:.0f} MiB), {sym.flops / 1e9:.1f} GFlop")
    if sym.factor_nnz * 8 * 2.5 > mem or sym.flops > fl:  # SuperLU keeps L and U (and CHOLMOD workspace)
        return "pcg", what + f" above the limits ({mem / 2**30:.1f} GiB, {fl / 1e9:.0f} GFlop): PCG (Schur-Jacobi)"
    if HAVE_CVXOPT_CHOLMOD:
        return "cholmod", what + ": supernodal CHOLMOD (cvxopt)"
    return "splu", what + ": SuperLU (cvxopt not installed, no CHOLMOD)"
