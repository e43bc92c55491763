"""Compiled (numba) kernels of :meth:`skyrig.adjust.model.Model._image`: the BAL path and the chain rule.

Module-level functions on purpose: numba's on-disk cache keys a function by its qualified name, its
bytecode *and its closure variables*; the kernels used to be created inside a factory function that
they captured the jitted ``pose_chain`` from, and a dispatcher pickles with a per-process identity,
so the cache key changed in every process (a recompilation of about 3 s per process and a new cache
file each time).  Here ``pose_chain`` is a module global, which is not part of the key.

Imported only when numba is installed (:mod:`skyrig.adjust.model` falls back to numpy otherwise).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["pose_chain", "bal_rows", "chain"]


@numba.njit(inline="always")
def pose_chain(q0, q1, q2, P0, P1, P2, i, ist, Rc, M, Rst, off, has_off):  # pragma: no cover - compiled
    """One row ``q = d (whitened px) / d (camera-frame point P)`` of image ``i`` through the pose:
    ``jX = q Rc^T`` (point), ``jth_cam = q skew(P)`` (camera-frame rotation, boresight) and the station
    rotation ``jth = jth_cam M^T + jX R_st skew(off)`` (the second term for a head offset from the
    station); the station centre's row is ``-jX``."""
    jx0 = q0 * Rc[i, 0, 0] + q1 * Rc[i, 0, 1] + q2 * Rc[i, 0, 2]
    jx1 = q0 * Rc[i, 1, 0] + q1 * Rc[i, 1, 1] + q2 * Rc[i, 1, 2]
    jx2 = q0 * Rc[i, 2, 0] + q1 * Rc[i, 2, 1] + q2 * Rc[i, 2, 2]
    t0 = q1 * P2 - q2 * P1
    t1 = q2 * P0 - q0 * P2
    t2 = q0 * P1 - q1 * P0
    v0 = t0 * M[i, 0, 0] + t1 * M[i, 0, 1] + t2 * M[i, 0, 2]
    v1 = t0 * M[i, 1, 0] + t1 * M[i, 1, 1] + t2 * M[i, 1, 2]
    v2 = t0 * M[i, 2, 0] + t1 * M[i, 2, 1] + t2 * M[i, 2, 2]
    if has_off:
        st = ist[i]
        # y = jX R_st, then y skew(off) = off x y (as a row): (y1 o2 - y2 o1, y2 o0 - y0 o2, ...)
        y0 = jx0 * Rst[st, 0, 0] + jx1 * Rst[st, 1, 0] + jx2 * Rst[st, 2, 0]
        y1 = jx0 * Rst[st, 0, 1] + jx1 * Rst[st, 1, 1] + jx2 * Rst[st, 2, 1]
        y2 = jx0 * Rst[st, 0, 2] + jx1 * Rst[st, 1, 2] + jx2 * Rst[st, 2, 2]
        v0 += y1 * off[i, 2] - y2 * off[i, 1]
        v1 += y2 * off[i, 0] - y0 * off[i, 2]
        v2 += y0 * off[i, 1] - y1 * off[i, 0]
    return jx0, jx1, jx2, t0, t1, t2, v0, v1, v2

@numba.njit(cache=True, nogil=True, parallel=True)
def bal_rows(oi, op, ist, Rc, Cc, M, Rst, off, has_off, X, intr, pix, sig, jac, o_pose, o_bore, o_intr,
             r, bad, jc, jp):  # pragma: no cover - compiled
    n = len(oi)
    for o in numba.prange(n):
        i = oi[o]
        p = op[o]
        dx = X[p, 0] - Cc[i, 0]
        dy = X[p, 1] - Cc[i, 1]
        dz = X[p, 2] - Cc[i, 2]
        P0 = Rc[i, 0, 0] * dx + Rc[i, 1, 0] * dy + Rc[i, 2, 0] * dz
        P1 = Rc[i, 0, 1] * dx + Rc[i, 1, 1] * dy + Rc[i, 2, 1] * dz
        P2 = Rc[i, 0, 2] * dx + Rc[i, 1, 2] * dy + Rc[i, 2, 2] * dz
        f = intr[i, 0]
        k1 = intr[i, 1]
        k2 = intr[i, 2]
        iz = -1.0 / P2
        p0 = P0 * iz
        p1 = P1 * iz
        r2 = p0 * p0 + p1 * p1
        rad = 1.0 + r2 * (k1 + k2 * r2)
        s0 = sig[o, 0]
        s1 = sig[o, 1]
        e0 = (f * rad * p0 - pix[o, 0]) / s0
        e1 = (f * rad * p1 - pix[o, 1]) / s1
        isbad = not (np.isfinite(e0) and np.isfinite(e1))
        bad[o] = isbad
        if isbad:
            e0 = 0.0
            e1 = 0.0
        r[o, 0] = e0
        r[o, 1] = e1
        if not jac:
            continue
        # d uv / d p = f (rad I + drad p p^T);  d p / d P: iz on the diagonal, p * iz in the last column
        drad = 2.0 * (k1 + 2.0 * k2 * r2)
        a00 = f * rad + f * drad * p0 * p0
        a01 = f * drad * p0 * p1
        a11 = f * rad + f * drad * p1 * p1
        d00 = a00 * iz / s0
        d01 = a01 * iz / s0
        d02 = (a00 * p0 + a01 * p1) * iz / s0
        d10 = a01 * iz / s1
        d11 = a11 * iz / s1
        d12 = (a01 * p0 + a11 * p1) * iz / s1
        if isbad:
            d00 = d01 = d02 = d10 = d11 = d12 = 0.0
        for e in range(2):
            if e == 0:
                q0, q1, q2, se, pe = d00, d01, d02, s0, p0
            else:
                q0, q1, q2, se, pe = d10, d11, d12, s1, p1
            jx0, jx1, jx2, t0, t1, t2, v0, v1, v2 = pose_chain(q0, q1, q2, P0, P1, P2, i, ist, Rc, M, Rst, off,
                                                              has_off)
            jp[o, e, 0] = jx0
            jp[o, e, 1] = jx1
            jp[o, e, 2] = jx2
            if o_pose >= 0:
                jc[o, e, o_pose + 0] = -jx0
                jc[o, e, o_pose + 1] = -jx1
                jc[o, e, o_pose + 2] = -jx2
                jc[o, e, o_pose + 3] = v0
                jc[o, e, o_pose + 4] = v1
                jc[o, e, o_pose + 5] = v2
            if o_bore >= 0:
                jc[o, e, o_bore + 0] = t0
                jc[o, e, o_bore + 1] = t1
                jc[o, e, o_bore + 2] = t2
            if o_intr >= 0:
                if isbad:
                    jc[o, e, o_intr + 0] = 0.0
                    jc[o, e, o_intr + 1] = 0.0
                    jc[o, e, o_intr + 2] = 0.0
                else:
                    jc[o, e, o_intr + 0] = rad * pe / se
                    jc[o, e, o_intr + 1] = f * r2 * pe / se
                    jc[o, e, o_intr + 2] = f * r2 * r2 * pe / se

@numba.njit(cache=True, nogil=True, parallel=True)
def chain(oi, ist, dpc, pc, Rc, M, Rst, off, has_off, jX, jpose, jthc):  # pragma: no cover - compiled
    # jX = dpc Rc^T; jth_cam = dpc skew(pc); jpose = [-jX, jth_cam M^T + jX R_st skew(off)]
    for o in numba.prange(len(oi)):
        i = oi[o]
        P0 = pc[o, 0]
        P1 = pc[o, 1]
        P2 = pc[o, 2]
        for e in range(2):
            q0 = dpc[o, e, 0]
            q1 = dpc[o, e, 1]
            q2 = dpc[o, e, 2]
            jx0, jx1, jx2, t0, t1, t2, v0, v1, v2 = pose_chain(q0, q1, q2, P0, P1, P2, i, ist, Rc, M, Rst, off,
                                                              has_off)
            jX[o, e, 0] = jx0
            jX[o, e, 1] = jx1
            jX[o, e, 2] = jx2
            jthc[o, e, 0] = t0
            jthc[o, e, 1] = t1
            jthc[o, e, 2] = t2
            jpose[o, e, 0] = -jx0
            jpose[o, e, 1] = -jx1
            jpose[o, e, 2] = -jx2
            jpose[o, e, 3] = v0
            jpose[o, e, 4] = v1
            jpose[o, e, 5] = v2
