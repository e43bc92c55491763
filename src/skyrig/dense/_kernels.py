"""Compiled kernels of the dense chain (numba).

Fusion: the points go into chunks of rows of their block of cells (:func:`_slot`: a bucket of ``tile x tile``
cells, filled chunk by chunk as the points come, so that a bucket's points lie together in memory), then per
bucket a counting sort by cell of the rows' indices and small sorts inside each cell (:func:`fuse_buckets`: the grid
and the voxel cloud of a cell from one read of its points).  The rules are those documented in
:mod:`skyrig.dense.fusion`; these kernels only make them O(N) in the number of points instead of several global
sorts.  Every result of a cell depends only on that cell's points (in their input order for ties), so a cell gets
the same value in any tiling.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, inline="always", error_model="numpy")
def _slot(bucket, tail, fill, chunk_bucket, nch, chunk):  # pragma: no cover - compiled
    """The next free row of ``bucket``: in its last chunk (``tail[bucket]``, ``fill[bucket]`` rows used), or in a
    new chunk of ``chunk`` rows (the next one of the pool, ``nch[0]`` in use; ``chunk_bucket`` records its bucket).
    A bucket's rows in the order of its chunks are its points in the order they came (the sorter reserves the pool's
    chunks before each batch)."""
    t = tail[bucket]
    if t < 0 or fill[bucket] == chunk:
        t = nch[0]
        nch[0] = t + 1
        chunk_bucket[t] = bucket
        tail[bucket] = t
        fill[bucket] = 0
    j = t * chunk + fill[bucket]
    fill[bucket] += 1
    return j


@numba.njit(cache=True, inline="always", error_model="numpy")
def _cell_of(xi, yi, zi, si, test_bounds, bounds, x0, y0, cell_m, H, W, ts, ntc):  # pragma: no cover - compiled
    """The flat cell index ``row * W + col`` of a point (``GridSpec.cell_of``), -1 for a point outside the grid,
    with a non-finite coordinate or a sigma ``si`` not > 0, or (``test_bounds``) outside ``bounds``
    ``(xmin, ymin, xmax, ymax)`` (``xmin <= x < xmax`` and ``ymin < y <= ymax`` are inside).  ``ts > 0``: the index
    in ``2**ts x 2**ts`` blocks of cells instead (:func:`tiled_cell`; ``ntc`` blocks along a row; shifts and masks,
    not divisions: a 64-bit division per point cost as much as the point's whole triangulation), so that a counting
    sort by it keeps nearby cells' points near each other in memory."""
    if not (np.isfinite(xi) and np.isfinite(yi) and np.isfinite(zi)):
        return -1
    if not si > 0:
        return -1
    if test_bounds and not (xi >= bounds[0] and xi < bounds[2] and yi > bounds[1] and yi <= bounds[3]):
        return -1
    col = np.floor((xi - x0) / cell_m)
    row = np.floor((y0 - yi) / cell_m)
    if col < 0 or col >= W or row < 0 or row >= H:
        return -1
    r, c = int(row), int(col)
    if ts > 0:
        msk = (1 << ts) - 1
        return (((r >> ts) * ntc + (c >> ts)) << (2 * ts)) | ((r & msk) << ts) | (c & msk)
    return r * W + c


@numba.njit(cache=True, error_model="numpy")
def take_points(xyz, sigma_h, pair, pair_const, sigma_3d, rgb, normal, o_xyz, o_sh, o_pair, o_s3, o_rgb, o_n, o_lc,
                tail, fill, chunk_bucket, nch, chunk, test_sigma, x0, y0, cell_m, H, W, ts, bounds
                ):  # pragma: no cover - compiled
    """Copy the points of a batch that have a cell (:func:`_cell_of`; ``test_sigma``: ``sigma_h`` must be > 0;
    ``bounds``: if not empty), in their order, into the rows :func:`_slot` gives in their cell's bucket of the point
    arrays ``o_*`` (``pair``, or ``pair_const`` when it is empty; the cloud's ``sigma_3d``, ``rgb``, ``normal`` when
    ``o_s3`` is not empty), their cell inside the bucket into ``o_lc`` (``ts > 0``): one pass over the batch.  ``o_xyz`` with one column takes the heights only (a grid without a cloud).  Returns
    the number of points taken."""
    n = xyz.shape[0]
    has_pair = pair.shape[0] > 0
    cloud = o_s3.shape[0] > 0
    test_bounds = bounds.shape[0] == 4
    ntc = (W + (1 << ts) - 1) >> ts
    s2 = 2 * ts
    m2 = (1 << s2) - 1
    k = 0
    for i in range(n):
        xi, yi, zi = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        q = _cell_of(xi, yi, zi, sigma_h[i] if test_sigma else 1.0, test_bounds, bounds, x0, y0, cell_m, H, W, ts,
                     ntc)
        if q < 0:
            continue
        j = _slot(q >> s2, tail, fill, chunk_bucket, nch, chunk)
        o_lc[j] = q & m2
        k += 1
        if o_xyz.shape[1] == 3:
            o_xyz[j, 0] = xi
            o_xyz[j, 1] = yi
            o_xyz[j, 2] = zi
        else:  # the grid alone reads only the height (the cell holds x, y)
            o_xyz[j, 0] = zi
        o_sh[j] = sigma_h[i]
        o_pair[j] = pair[i] if has_pair else pair_const
        if cloud:
            o_s3[j] = sigma_3d[i]
            for t in range(3):
                o_rgb[j, t] = rgb[i, t]
                o_n[j, t] = normal[i, t]
    return k


@numba.njit(cache=True, inline="always", error_model="numpy")
def tiled_cell(key, W, ts):  # pragma: no cover - compiled
    """The flat cell index ``row * W + col`` of a :func:`_cell_of` index in ``2**ts x 2**ts`` blocks (-1: a
    block's padding beyond the grid's last column)."""
    if ts <= 0:
        return key
    tile = 1 << ts
    ntc = (W + tile - 1) >> ts
    b = key >> (2 * ts)
    k = key & (tile * tile - 1)
    r = (b // ntc) * tile + (k >> ts)
    c = (b % ntc) * tile + (k & (tile - 1))
    return r * W + c if c < W else -1


@numba.njit(cache=True, error_model="numpy")
def fuse_buckets(lc, tail, fill, chunk_bucket, nch, chunk, pair, xyz, sigma_h, voxel_z_m, sigma_3d, rgb, normal, rot,
                 k_sigma, min_tol, min_support, min_ratio, max_range, do_grid, do_cloud, out_h, out_n, out_sp, out_s,
                 out_ch, out_cs, out_cn, o_xyz, o_rgb, o_n, o_sup, o_sig, W, ts, out_ch2, out_cs2,
                 out_cn2):  # pragma: no cover - compiled
    """Grid and/or voxel fusion of the points of a :class:`~skyrig.dense.fusion.CellSorter`: bucket ``b`` (the
    ``2**ts x 2**ts`` block of cells ``b``, blocks counted along the rows of a grid ``W`` cells wide, see
    :func:`_cell_of`) holds the rows of the chunks ``k`` with ``chunk_bucket[k] == b`` (``nch`` chunks of ``chunk``
    rows, the last one ``tail[b]`` filled to ``fill[b]``: :func:`_slot`), ``lc`` each row's cell inside its bucket.
    Bucket by bucket, a counting sort of its rows by cell (stable: a cell keeps its points in the order they came),
    then every cell from one read of its points.

    Grid (``do_grid``, see :func:`skyrig.dense.fusion.fuse_grid`): the points with ``sigma_h > 0``, heights
    ``xyz[:, -1]`` (``xyz`` may hold the heights alone, one column, when there is no cloud), gathered into scratch
    arrays sorted by (pair, height), stably (ties keep the input order); with
    ``max_range > 0`` a pair whose own heights in the cell span more than ``max_range`` gives the cell no height (it
    sees a wall or a depth edge inside the cell).  Writes the flat ``out_*`` arrays; ``out_ch``, ``out_cs``,
    ``out_cn``: for a cell whose pairs all agree but are fewer than ``min_support``, their precision-weighted mean,
    its sigma and their number (a candidate for the neighbour confirmation); for a cell rejected because its pairs
    split into exactly two camps (every pair agrees with the lowest or with the highest pair height, none with
    both), the lower camp there and the upper one in ``out_ch2``, ``out_cs2``, ``out_cn2`` (when given: size > 0).

    Cloud (``do_cloud``, see :func:`skyrig.dense.fusion.fuse_cloud`): every point of a cell grouped by its vertical
    voxel index ``floor(z / voxel_z_m)``; a voxel with points of at least ``min_support`` distinct pairs becomes one
    point (precision ``sigma_3d``); normals are rotated by ``rot`` (``(3, 3)``, in float64, rounded to float32)
    before they are averaged.  Writes ``o_*`` row by row (buckets in order, then cells, then voxels by height) and
    returns the number of rows written."""
    nb = tail.shape[0]
    t2 = 1 << (2 * ts)
    ntc = (W + (1 << ts) - 1) >> ts
    tmask = (1 << ts) - 1
    n_ch = nch[0]
    cstart = np.zeros(nb + 1, np.int64)  # the chunks by bucket, in the order they were taken (a counting sort)
    for k in range(n_ch):
        cstart[chunk_bucket[k] + 1] += 1
    for b in range(nb):
        cstart[b + 1] += cstart[b]
    corder = np.empty(n_ch, np.int64)
    cpos = cstart[:-1].copy()
    for k in range(n_ch):
        b = chunk_bucket[k]
        corder[cpos[b]] = k
        cpos[b] += 1
    maxb = 0
    for b in range(nb):
        if tail[b] >= 0:
            maxb = max(maxb, (cstart[b + 1] - cstart[b] - 1) * chunk + fill[b])
    order = np.empty(maxb, np.int64)
    cnt = np.empty(t2 + 1, np.int64)
    pos = np.empty(t2, np.int64)
    zc = xyz.shape[1] - 1  # the height's column (0 when the grid alone keeps only the heights)
    lp = np.empty(maxb, np.int64)  # scratch of a cell (at most a bucket's points)
    lh = np.empty(maxb)
    ls = np.empty(maxb)
    ph = np.empty(maxb)
    ps = np.empty(maxb)
    pw = np.empty(maxb)
    pi = np.empty(maxb, np.int64)
    dev = np.empty(maxb)
    lk = np.empty(maxb, np.int64)
    lpr = np.empty(maxb, np.int64)
    li = np.empty(maxb, np.int64)
    bp = np.empty(maxb, np.int64)  # the bucket's pairs, heights and height precisions in cell order
    bz = np.empty(maxb)
    bs = np.empty(maxb)
    bv = np.empty(maxb if do_cloud else 0, np.int64)  # the cloud's vertical voxel index of each, in cell order
    out = 0
    for b in range(nb):
        if tail[b] < 0:
            continue
        cnt[:] = 0
        for ci in range(cstart[b], cstart[b + 1]):
            k = corder[ci]
            r0 = k * chunk
            r1 = r0 + (fill[b] if k == tail[b] else chunk)
            for r in range(r0, r1):
                cnt[lc[r] + 1] += 1
        for q in range(t2):
            cnt[q + 1] += cnt[q]
            pos[q] = cnt[q]
        for ci in range(cstart[b], cstart[b + 1]):
            k = corder[ci]
            r0 = k * chunk
            r1 = r0 + (fill[b] if k == tail[b] else chunk)
            for r in range(r0, r1):  # reads the bucket's points in memory order (the cells' reads then hit the cache)
                q = lc[r]
                t = pos[q]
                order[t] = r
                bp[t] = pair[r]
                bz[t] = xyz[r, zc]
                bs[t] = sigma_h[r]
                if do_cloud:  # here, not in the cell's sort below: a division and a rounding whose latency, behind
                    # the sort's mispredicted branches, cost 0.015 CPU s on bench/dense.py --sizes 16's 7.0 M points
                    bv[t] = int(np.floor(xyz[r, 2] / voxel_z_m))
                pos[q] = t + 1
        br = (b // ntc) << ts  # the bucket's first row and column (tiled_cell, one division per bucket)
        bc = (b % ntc) << ts
        for lq in range(t2):
            a, e = cnt[lq], cnt[lq + 1]
            if a == e:
                continue
            cc = bc + (lq & tmask)
            cg = (br + (lq >> ts)) * W + cc if cc < W else -1
            if do_grid:
                m = 0
                for q in range(a, e):
                    if bs[q] > 0:
                        m = _insert_sorted(lp, lh, ls, m, bp[q], bz[q], bs[q])
                if m:
                    _grid_cell(cg, lp, lh, ls, m, k_sigma, min_tol, min_support, min_ratio, max_range, ph, ps, pw, pi,
                               dev, out_h, out_n, out_sp, out_s, out_ch, out_cs, out_cn, out_ch2, out_cs2, out_cn2)
            if do_cloud:
                mv = 0
                for q in range(a, e):
                    mv = _insert_sorted(lk, lpr, li, mv, bv[q], bp[q], order[q])
                out = _voxel_cell(lk, lpr, li, mv, xyz, sigma_3d, rgb, normal, rot, min_support, o_xyz, o_rgb, o_n,
                                  o_sup, o_sig, out)
    return out


@numba.njit(cache=True, inline="always", error_model="numpy")
def _insert_sorted(k1, k2, v, m, a, b, c):  # pragma: no cover - compiled
    """Insert the entry ``(a, b, c)`` into the first ``m`` entries of the scratch arrays ``k1, k2, v`` kept sorted
    by ``(k1, k2)``, after its equals (stable); returns ``m + 1``.  A cell's points by (pair, height) for the grid,
    by (height slice, pair) for the voxels."""
    j = m
    while j > 0 and (k1[j - 1] > a or (k1[j - 1] == a and k2[j - 1] > b)):
        k1[j] = k1[j - 1]
        k2[j] = k2[j - 1]
        v[j] = v[j - 1]
        j -= 1
    k1[j] = a
    k2[j] = b
    v[j] = c
    return m + 1


@numba.njit(cache=True, inline="always", error_model="numpy")
def _rank(v, n, q):  # pragma: no cover - compiled
    """Position of ``v[q]`` in the stable ascending order of ``v[:n]`` (ties by index): the number of values below
    it plus its equals before it.  Comparisons without branches: for the few pairs of a cell this is faster than an
    insertion sort, whose moves depend on the data."""
    x = v[q]
    r = 0
    for p in range(n):
        r += (v[p] < x) | ((v[p] == x) & (p < q))
    return r


@numba.njit(cache=True, inline="always", error_model="numpy")
def _grid_cell(c, lp, lh, ls, m, k_sigma, min_tol, min_support, min_ratio, max_range, ph, ps, pw, pi, dev,
               out_h, out_n, out_sp, out_s, out_ch, out_cs, out_cn, out_ch2, out_cs2, out_cn2):  # pragma: no cover
    """Fusion of one cell from its ``m`` points sorted by (pair, height) in ``lp, lh, ls`` (steps 1-3 of
    :mod:`skyrig.dense.fusion`); ``ph, ps, pw, pi, dev``: scratch."""
    # one height per pair: median of its points (sigma of the median point(s))
    k = 0
    i = 0
    while i < m:
        j = i
        while j < m and lp[j] == lp[i]:
            j += 1
        cnt = j - i
        if max_range > 0 and lh[j - 1] - lh[i] > max_range:
            i = j
            continue
        lo = i + (cnt - 1) // 2
        hi = i + cnt // 2
        ph[k] = 0.5 * (lh[lo] + lh[hi])
        ps[k] = 0.5 * (ls[lo] + ls[hi])
        pw[k] = 1.0 / (ps[k] * ps[k])
        k += 1
        i = j
    np_ = k
    if np_ == 0:
        return
    for q in range(np_):  # pi: pair heights' order, stable (ties by pair), from each height's rank
        pi[_rank(ph, np_, q)] = q
    # precision-weighted median
    tot = 0.0
    for q in range(np_):
        tot += pw[q]
    acc = 0.0
    med_i = pi[np_ - 1]
    for q in range(np_):
        acc += pw[pi[q]]
        if acc >= 0.5 * tot * (1 - 1e-12):
            med_i = pi[q]
            break
    med = ph[med_i]
    smed = ps[med_i]
    nsup = 0
    wsum = 0.0
    hsum = 0.0
    for q in range(np_):  # dev: 1 where the pair supports the median (pi keeps the heights' order)
        dev[q] = 0.0
        dq = abs(ph[q] - med)
        # within the least tolerance the pair supports whatever its sigma (no square root needed)
        if dq <= min_tol or dq <= k_sigma * np.sqrt(ps[q] * ps[q] + smed * smed):
            dev[q] = 1.0
            nsup += 1
            wsum += pw[q]
            hsum += pw[q] * ph[q]
    if nsup < min_support or nsup < min_ratio * np_:
        if nsup == np_:
            out_ch[c] = hsum / wsum
            out_cs[c] = 1.0 / np.sqrt(wsum)
            out_cn[c] = min(nsup, 32767)
        elif out_ch2.shape[0] > 0:
            _split_camps(c, ph, ps, pw, np_, k_sigma, min_tol, out_ch, out_cs, out_cn, out_ch2, out_cs2, out_cn2)
        return
    fused = hsum / wsum
    out_h[c] = fused
    out_n[c] = min(nsup, 32767)
    out_s[c] = 1.0 / np.sqrt(wsum)
    if nsup >= 2:  # the median absolute deviation: the supporting heights in ascending order (pi) into pw, whose
        # deviations from the fused height fall, then rise: the two middle ones by a merge outward from it
        t = 0
        below = 0
        for q in range(np_):
            i = pi[q]
            if dev[i] > 0:
                pw[t] = ph[i]
                below += pw[t] < fused
                t += 1
        lo_v = hi_v = 0.0
        a = below - 1
        b = below
        for r in range(nsup // 2 + 1):
            if b >= nsup or (a >= 0 and abs(pw[a] - fused) <= abs(pw[b] - fused)):
                v = abs(pw[a] - fused)
                a -= 1
            else:
                v = abs(pw[b] - fused)
                b += 1
            if r == (nsup - 1) // 2:
                lo_v = v
            hi_v = v
        out_sp[c] = 1.4826 * 0.5 * (lo_v + hi_v)
    else:
        out_sp[c] = np.nan


@numba.njit(cache=True, inline="always", error_model="numpy")
def _split_camps(c, ph, ps, pw, np_, k_sigma, min_tol, out_ch, out_cs, out_cn, out_ch2, out_cs2,
                 out_cn2):  # pragma: no cover - compiled
    """A rejected cell whose ``np_`` pair heights form exactly two camps: every pair agrees (the support tolerance)
    with the lowest pair height or with the highest one, and none with both.  Writes the lower camp's
    precision-weighted mean, its sigma and count to ``out_c*`` and the upper camp's to ``out_c*2``; nothing
    otherwise (a third height in between, e.g. of a wall, or camps that overlap)."""
    il = 0
    iu = 0
    for q in range(1, np_):
        if ph[q] < ph[il]:
            il = q
        if ph[q] > ph[iu]:
            iu = q
    nl = 0
    nu = 0
    wl = 0.0
    hl = 0.0
    wu = 0.0
    hu = 0.0
    for q in range(np_):
        a = abs(ph[q] - ph[il]) <= max(k_sigma * np.sqrt(ps[q] * ps[q] + ps[il] * ps[il]), min_tol)
        b = abs(ph[q] - ph[iu]) <= max(k_sigma * np.sqrt(ps[q] * ps[q] + ps[iu] * ps[iu]), min_tol)
        if a == b:
            return
        if a:
            nl += 1
            wl += pw[q]
            hl += pw[q] * ph[q]
        else:
            nu += 1
            wu += pw[q]
            hu += pw[q] * ph[q]
    out_ch[c] = hl / wl
    out_cs[c] = 1.0 / np.sqrt(wl)
    out_cn[c] = min(nl, 32767)
    out_ch2[c] = hu / wu
    out_cs2[c] = 1.0 / np.sqrt(wu)
    out_cn2[c] = min(nu, 32767)


@numba.njit(cache=True, inline="always", error_model="numpy")
def _voxel_cell(lk, lpr, li, m, xyz, sigma, rgb, normal, rot, min_support, o_xyz, o_rgb, o_n, o_sup, o_sig,
                out):  # pragma: no cover - compiled
    """The voxels of one cell from its ``m`` points sorted by (height slice, pair) (``lk, lpr``; ``li``: the
    points' indices); writes from row ``out`` on and returns the next free row."""
    i = 0
    while i < m:
        j = i
        while j < m and lk[j] == lk[i]:
            j += 1
        npairs = 0
        for q in range(i, j):
            if q == i or lpr[q] != lpr[q - 1]:
                npairs += 1
        if npairs >= min_support:
            wsum = 0.0
            sx = 0.0
            sy = 0.0
            sz = 0.0
            r0 = 0.0
            r1 = 0.0
            r2 = 0.0
            n0 = 0.0
            n1 = 0.0
            n2 = 0.0
            for q in range(i, j):
                p = li[q]
                s = max(np.float64(sigma[p]), 1e-9)
                w = 1.0 / (s * s)
                wsum += w
                sx += w * xyz[p, 0]
                sy += w * xyz[p, 1]
                sz += w * xyz[p, 2]
                r0 += rgb[p, 0]
                r1 += rgb[p, 1]
                r2 += rgb[p, 2]
                if normal[p, 0] == normal[p, 0]:  # not NaN
                    a0, a1, a2 = np.float64(normal[p, 0]), np.float64(normal[p, 1]), np.float64(normal[p, 2])
                    n0 += np.float32(rot[0, 0] * a0 + rot[0, 1] * a1 + rot[0, 2] * a2)
                    n1 += np.float32(rot[1, 0] * a0 + rot[1, 1] * a1 + rot[1, 2] * a2)
                    n2 += np.float32(rot[2, 0] * a0 + rot[2, 1] * a1 + rot[2, 2] * a2)
            cnt = j - i
            o_xyz[out, 0] = sx / wsum
            o_xyz[out, 1] = sy / wsum
            o_xyz[out, 2] = sz / wsum
            o_rgb[out, 0] = np.uint8(min(255.0, r0 / cnt + 0.5))
            o_rgb[out, 1] = np.uint8(min(255.0, r1 / cnt + 0.5))
            o_rgb[out, 2] = np.uint8(min(255.0, r2 / cnt + 0.5))
            nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
            if nn > 0:
                o_n[out, 0] = n0 / nn
                o_n[out, 1] = n1 / nn
                o_n[out, 2] = n2 / nn
            else:
                o_n[out, 0] = np.nan
                o_n[out, 1] = np.nan
                o_n[out, 2] = np.nan
            o_sup[out] = min(npairs, 32767)
            o_sig[out] = 1.0 / np.sqrt(wsum)
            out += 1
        i = j
    return out


@numba.njit(cache=True, error_model="numpy")
def triangulate_block(disp, u0, v0, f, B, R, C, sigma_px, cos_lim, colour):  # pragma: no cover - compiled
    """Points of every matched pixel of a rectified block (see :func:`skyrig.dense.stereo.block_points`).

    ``colour``: the block's left colour crop ``(H, W, C)`` (one channel: grey, given to all three).  Returns
    ``rows, cols, xyz (N, 3), normal (N, 3) float32, sigma_h, sigma_3d, rgb (N, 3) uint8`` for the pixels kept
    (positive disparity, surface not seen more grazing than ``acos(cos_lim)``); the intersection angle is
    :attr:`skyrig.dense.stereo.PairPoints.angle_deg`, on demand."""
    H, W = disp.shape
    fb = f * B
    fi = 1.0 / f  # a product, not a division per term (within an ulp of u * D / f)
    nmax = 0
    Dg = np.empty((H, W))  # depth of every matched pixel (one division each; neighbours reuse it)
    for r in range(H):
        for c in range(W):
            if disp[r, c] > 0:
                nmax += 1
                Dg[r, c] = fb / disp[r, c]
    rows = np.empty(nmax, np.int64)
    cols = np.empty(nmax, np.int64)
    xyz = np.empty((nmax, 3))
    nrm = np.empty((nmax, 3), np.float32)
    sh = np.empty(nmax, np.float32)
    s3 = np.empty(nmax, np.float32)
    rgb = np.empty((nmax, 3), np.uint8)
    nch = colour.shape[2]
    k = 0
    for r in range(H):
        for c in range(W):
            d = disp[r, c]
            if not d > 0:
                continue
            D = Dg[r, c]
            du = np.nan
            if 0 < c < W - 1 and disp[r, c - 1] > 0 and disp[r, c + 1] > 0:
                du = 0.5 * (Dg[r, c + 1] - Dg[r, c - 1])
            dv = np.nan
            if 0 < r < H - 1 and disp[r - 1, c] > 0 and disp[r + 1, c] > 0:
                dv = 0.5 * (Dg[r + 1, c] - Dg[r - 1, c])
            u = u0 + c
            v = v0 + r
            px = u * D * fi
            py = -v * D * fi
            pz = -D
            ax = (D + u * du) * fi
            ay = -v * du * fi
            az = -du
            bx = u * dv * fi
            by = -(D + v * dv) * fi
            bz = -dv
            nx = by * az - bz * ay
            ny = bz * ax - bx * az
            nz = bx * ay - by * ax
            nn = np.sqrt(nx * nx + ny * ny + nz * nz)
            rng = np.sqrt(px * px + py * py + pz * pz)
            cosi = -(nx * px + ny * py + nz * pz) / (nn * rng)
            if abs(cosi) < cos_lim:  # NaN (no neighbours) passes
                continue
            sg = 1.0 / nn
            if cosi < 0:
                sg = -sg
            rows[k] = r
            cols[k] = c
            for i in range(3):
                xyz[k, i] = C[i] + R[i, 0] * px + R[i, 1] * py + R[i, 2] * pz
                nrm[k, i] = (R[i, 0] * nx + R[i, 1] * ny + R[i, 2] * nz) * sg
            wz = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz
            s3[k] = rng / d * sigma_px
            sh[k] = abs(wz) / d * sigma_px
            for i in range(3):
                rgb[k, i] = colour[r, c, min(i, nch - 1)]
            k += 1
    return rows[:k], cols[:k], xyz[:k], nrm[:k], sh[:k], s3[:k], rgb[:k]


@numba.njit(cache=True, error_model="numpy")
def triangulate_take(disp, u0, v0, f, B, R, C, sigma_px, cos_lim, colour, wall_nz, half, min_count, flat_range,
                     m_c0, m_s, m_coef, m_offset, pair_const, o_xyz, o_sh, o_pair, o_s3, o_rgb, o_n, o_lc, tail, fill,
                     chunk_bucket, nch, chunk, x0, y0, cell_m, Hg, Wg, ts, bounds):  # pragma: no cover - compiled
    """:func:`triangulate_block`, the wall test of :func:`steep_points` (``wall_nz > 0``), the local -> map
    polynomial of :func:`poly_map` and :func:`take_points` (without a sigma test) in one pass over a block's
    pixels: each kept pixel's point goes straight into its bucket's rows (:func:`_slot`) of a :class:`~skyrig.dense.fusion.CellSorter`'s
    arrays, with no per-block point arrays in between; a pixel's normal, incidence and wall test are computed only when
    its point falls in a cell inside ``bounds`` (a block reaching several ground tiles is triangulated in each).  The same arithmetic in the same order as those kernels one after the other, so the same
    rows, bit for bit.  Returns the number of points taken."""
    H, W = disp.shape
    fb = f * B
    fi = 1.0 / f  # a product, not a division per term (within an ulp of u * D / f)
    nch_c = colour.shape[2]
    cloud = o_s3.shape[0] > 0
    test_bounds = bounds.shape[0] == 4
    ntc = (Wg + (1 << ts) - 1) >> ts
    s2 = 2 * ts
    m2 = (1 << s2) - 1
    nmax = 0
    Dg = np.empty((H, W))  # depth of every matched pixel (as triangulate_block)
    for r in range(H):
        for c in range(W):
            if disp[r, c] > 0:
                nmax += 1
                Dg[r, c] = fb / disp[r, c]
    # a band of BAND rows at a time into buffers (in the cache), then into the sorter bucket by bucket: a bucket's
    # points of the band go to its rows as one run (written straight from the pixels, each point went to another
    # of the tens of buckets a row crosses: 0.75 instead of 0.50 CPU s for the 16-image bench block's 7 M points)
    band = 16
    nbuf = band * W
    three = o_xyz.shape[1] == 3
    bxyz = np.empty((nbuf, 3 if three else 1))
    bsh = np.empty(nbuf, o_sh.dtype)
    bs3 = np.empty(nbuf if cloud else 0, o_s3.dtype)
    brgb = np.empty((nbuf if cloud else 0, 3), np.uint8)
    bn = np.empty((nbuf if cloud else 0, 3), np.float32)
    bcell = np.empty(nbuf, np.int64)
    rows = np.empty(nbuf if wall_nz > 0 else 0, np.int64)  # the pixels taken, for the wall test
    cols = np.empty(nbuf if wall_nz > 0 else 0, np.int64)
    nbk = tail.shape[0]
    bcnt = np.zeros(nbk, np.int64)
    boff = np.empty(nbk, np.int64)
    touched = np.empty(nbuf, np.int64)
    perm = np.empty(nbuf, np.int64)
    n = 0
    w = np.empty(3)
    q = np.empty(3)
    for rb in range(0, H, band):
        m = 0
        for r in range(rb, min(H, rb + band)):
            for c in range(W):
                d = disp[r, c]
                if not d > 0:
                    continue
                D = Dg[r, c]
                u = u0 + c
                v = v0 + r
                px = u * D * fi
                py = -v * D * fi
                pz = -D
                for i in range(3):
                    w[i] = C[i] + R[i, 0] * px + R[i, 1] * py + R[i, 2] * pz
                _poly_point(w, m_c0, m_s, m_coef, m_offset, q)
                cell = _cell_of(q[0], q[1], q[2], 1.0, test_bounds, bounds, x0, y0, cell_m, Hg, Wg, ts, ntc)
                if cell < 0:  # outside the tile: no normal, incidence or wall test needed
                    continue
                du = np.nan
                if 0 < c < W - 1 and disp[r, c - 1] > 0 and disp[r, c + 1] > 0:
                    du = 0.5 * (Dg[r, c + 1] - Dg[r, c - 1])
                dv = np.nan
                if 0 < r < H - 1 and disp[r - 1, c] > 0 and disp[r + 1, c] > 0:
                    dv = 0.5 * (Dg[r + 1, c] - Dg[r - 1, c])
                ax = (D + u * du) * fi
                ay = -v * du * fi
                az = -du
                bx = u * dv * fi
                by = -(D + v * dv) * fi
                bz = -dv
                nx = by * az - bz * ay
                ny = bz * ax - bx * az
                nz = bx * ay - by * ax
                nn = np.sqrt(nx * nx + ny * ny + nz * nz)
                rng = np.sqrt(px * px + py * py + pz * pz)
                cosi = -(nx * px + ny * py + nz * pz) / (nn * rng)
                if abs(cosi) < cos_lim:  # NaN (no neighbours) passes
                    continue
                sg = 1.0 / nn
                if cosi < 0:
                    sg = -sg
                wz = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz
                if wall_nz > 0:
                    rows[m] = r
                    cols[m] = c
                bcell[m] = cell
                if three:
                    bxyz[m, 0] = q[0]
                    bxyz[m, 1] = q[1]
                    bxyz[m, 2] = q[2]
                else:
                    bxyz[m, 0] = q[2]
                bsh[m] = abs(wz) / d * sigma_px
                if cloud:
                    bs3[m] = rng / d * sigma_px
                    for i in range(3):
                        bn[m, i] = (R[i, 0] * nx + R[i, 1] * ny + R[i, 2] * nz) * sg
                        brgb[m, i] = colour[r, c, min(i, nch_c - 1)]
                m += 1
        if m == 0:
            continue
        if wall_nz > 0:  # NaN: steep or sparse
            vz = steep_points(disp, rows[:m], cols[:m], u0, v0, f, B, R, half, min_count, flat_range)
            for k in range(m):
                if not vz[k] >= wall_nz:
                    bsh[k] = np.nan
        nt = 0  # the band's points grouped by bucket, each bucket's in their order (a counting sort)
        for k in range(m):
            bk = bcell[k] >> s2
            if bcnt[bk] == 0:
                touched[nt] = bk
                nt += 1
            bcnt[bk] += 1
        acc = 0
        for t in range(nt):
            bk = touched[t]
            boff[bk] = acc
            acc += bcnt[bk]
            bcnt[bk] = 0
        for k in range(m):
            bk = bcell[k] >> s2
            perm[boff[bk]] = k
            boff[bk] += 1
        p = 0
        for t in range(nt):  # each bucket's run into its chunks, chunk by chunk
            bk = touched[t]
            e = boff[bk]
            while p < e:
                j0 = _slot(bk, tail, fill, chunk_bucket, nch, chunk)  # the run's first row, then as many as fit
                take = min(e - p, chunk - fill[bk] + 1)
                fill[bk] += take - 1
                for kk in range(take):
                    k = perm[p + kk]
                    j = j0 + kk
                    o_lc[j] = bcell[k] & m2
                    for i in range(bxyz.shape[1]):
                        o_xyz[j, i] = bxyz[k, i]
                    o_sh[j] = bsh[k]
                    o_pair[j] = pair_const
                    if cloud:
                        o_s3[j] = bs3[k]
                        for i in range(3):
                            o_n[j, i] = bn[k, i]
                            o_rgb[j, i] = brgb[k, i]
                p += take
        n += m
    return n


@numba.njit(cache=True, inline="always", error_model="numpy")
def _poly_point(p, c0, s, coef, offset, out):  # pragma: no cover - compiled
    """One point ``p`` (3,) through the polynomial of :func:`poly_map`, into ``out`` (3,)."""
    x = (p[0] - c0[0]) / s[0]
    y = (p[1] - c0[1]) / s[1]
    z = (p[2] - c0[2]) / s[2]
    t = (1.0, x, y, z, x * x, x * y, y * y, x * z, y * z, z * z, x * x * x, x * x * y, x * y * y, y * y * y)
    for k in range(3):
        acc = offset[k]
        for j in range(14):
            acc += coef[j, k] * t[j]
        out[k] = acc


@numba.njit(cache=True, error_model="numpy")
def poly_map(xyz, c0, s, coef, offset):  # pragma: no cover - compiled
    """The polynomial of :class:`skyrig.dense.surface.FrameMap` (terms as ``FrameMap._terms``)."""
    n = xyz.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        x = (xyz[i, 0] - c0[0]) / s[0]
        y = (xyz[i, 1] - c0[1]) / s[1]
        z = (xyz[i, 2] - c0[2]) / s[2]
        t = (1.0, x, y, z, x * x, x * y, y * y, x * z, y * z, z * z, x * x * x, x * x * y, x * y * y, y * y * y)
        for k in range(3):
            acc = offset[k]
            for j in range(14):
                acc += coef[j, k] * t[j]
            out[i, k] = acc
    return out


@numba.njit(cache=True, error_model="numpy")
def lattice_maps(lat, step, width, height, cam_w, cam_h):  # pragma: no cover - compiled
    """``cv2.remap`` maps of a rectified crop from the exact mapping on a lattice every ``step`` pixels (see
    :meth:`skyrig.dense.rectify.Rectification.maps`): bilinear in float64 (along u first), -1e6 where the
    lattice is NaN, rounded to float32; and the mask of map positions inside the ``cam_w x cam_h`` image."""
    nv, nu = lat.shape[0], lat.shape[1]
    mx = np.empty((height, width), np.float32)
    my = np.empty((height, width), np.float32)
    inside = np.empty((height, width), np.bool_)
    iu = np.empty(width, np.int64)
    fu = np.empty(width)
    for c in range(width):
        cu = c / step
        k = min(int(cu), nu - 2)
        iu[c] = k
        fu[c] = cu - k
    ax = np.empty(width)  # the lattice rows above and below, interpolated along u (once per lattice row)
    bx = np.empty(width)
    ay = np.empty(width)
    by = np.empty(width)
    last = -1
    for r in range(height):
        cv = r / step
        iv = min(int(cv), nv - 2)
        fv = cv - iv
        if iv != last:
            for c in range(width):
                k = iu[c]
                f = fu[c]
                g = 1 - f
                ax[c] = lat[iv, k, 0] * g + lat[iv, k + 1, 0] * f
                bx[c] = lat[iv + 1, k, 0] * g + lat[iv + 1, k + 1, 0] * f
                ay[c] = lat[iv, k, 1] * g + lat[iv, k + 1, 1] * f
                by[c] = lat[iv + 1, k, 1] * g + lat[iv + 1, k + 1, 1] * f
            last = iv
        for c in range(width):
            px = ax[c] * (1 - fv) + bx[c] * fv
            py = ay[c] * (1 - fv) + by[c] * fv
            if not np.isfinite(px) or not np.isfinite(py):  # behind the camera (the lattice is NaN in pairs)
                px = -1e6 if not np.isfinite(px) else px
                py = -1e6 if not np.isfinite(py) else py
            x = np.float32(px)
            y = np.float32(py)
            mx[r, c] = x
            my[r, c] = y
            inside[r, c] = x >= 0 and x <= cam_w - 1 and y >= 0 and y <= cam_h - 1
    return mx, my, inside


@numba.njit(cache=True, error_model="numpy")
def check_disparities(d16, e16, valid_left, valid_right, tol, shift, full):  # pragma: no cover - compiled
    """Disparities of a matched crop (see :func:`skyrig.dense.sgm.match_crop`), float32, NaN = invalid.

    ``d16``: OpenCV's fixed-point left disparities of the crop's first ``d16.shape[1]`` columns (< 0:
    none); ``e16``: those of the right-based pass over the whole crop, already flipped back (``full``), whose
    value at the right pixel a left pixel matched (nearest) must agree within ``tol`` pixels; the left pixel
    and that right pixel must carry image content (``valid_left``, ``valid_right``).  ``shift`` is added back."""
    H, W = valid_left.shape
    Wd = d16.shape[1]
    out = np.empty((H, W), np.float32)
    out[:] = np.nan
    for r in range(H):
        for c in range(Wd):
            q = d16[r, c]
            if q < 0:
                continue
            d = np.float32(q) * np.float32(0.0625)
            jr = np.float32(c) - d
            if jr < 0:
                continue
            ji = int(np.rint(jr))
            if ji > W - 1:
                ji = W - 1
            if full:
                e = e16[r, ji]
                if e < 0 or not abs(np.float32(e) * np.float32(0.0625) - d) <= tol:
                    continue
            if not valid_left[r, c] or not valid_right[r, ji]:
                continue
            out[r, c] = d + np.float32(shift)
    return out


@numba.njit(cache=True, error_model="numpy")
def lr_band_rows(d, jump, c0, band):  # pragma: no cover - compiled
    """Rows of a crop whose right-based matching the banded left-right check runs (see
    :func:`skyrig.dense.sgm.match_crop`): every row of a band of ``band`` rows (bands counted from the crop's first
    row) in which some row has a depth edge: two finite disparities of ``d`` (NaN = none), consecutive along the row
    from column ``c0`` on (holes between them skipped: an occlusion leaves a hole between the two sides of an edge),
    that differ by more than ``jump`` pixels."""
    H, W = d.shape
    out = np.zeros(H, np.bool_)
    for r in range(H):
        have = False
        last = np.float32(0.0)
        for c in range(c0, W):
            v = d[r, c]
            if v == v:
                if have and abs(v - last) > jump:
                    b0 = (r // band) * band
                    for q in range(b0, min(H, b0 + band)):
                        out[q] = True
                    break
                have = True
                last = v
    return out


@numba.njit(cache=True, error_model="numpy")
def lr_band_cols(d, jump, c0, r0, r1, zone):  # pragma: no cover - compiled
    """Columns of a crop within ``zone`` pixels of a depth edge (as :func:`lr_band_rows` finds them: consecutive finite
    disparities of ``d`` from column ``c0`` on, holes skipped, that differ by more than ``jump``; the columns from
    the edge's left pixel to its right one) in any of the rows ``r0 .. r1 - 1``."""
    W = d.shape[1]
    out = np.zeros(W, np.bool_)
    for r in range(r0, r1):
        have = False
        last = np.float32(0.0)
        lc = 0
        for c in range(c0, W):
            v = d[r, c]
            if v == v:
                if have and abs(v - last) > jump:
                    for q in range(max(0, lc - zone), min(W, c + zone + 1)):
                        out[q] = True
                have = True
                last = v
                lc = c
    return out


@numba.njit(cache=True, error_model="numpy")
def lr_band_crops(d, rows, jump, c0, zone, n, context):  # pragma: no cover - compiled
    """The right-based matchings of the banded check on columns (``SgmConfig.lr_band_cols_px`` = ``zone`` > 0): for
    each run of banded ``rows``, the columns near its depth edges (:func:`lr_band_cols`), widened by ``n + zone`` on
    the left and on the right (a left pixel's right pixel lies up to ``n`` columns left of it, whose own matches up
    to ``n`` right of that, and the mirrored pass leaves the last ``n`` columns of its crop without result; ``zone``
    more of path on either side), overlapping spans merged.  Returns the crops ``(y0, r0, r1, ca, cb)`` (rows ``y0``
    = ``r0 - context`` (>= 0) .. ``r1``, columns ``ca .. cb``; rows ``r0 .. r1`` kept) and the mask of the pixels
    the second matching checks (banded rows, columns near an edge)."""
    H, W = d.shape
    full = np.zeros((H, W), np.bool_)
    crops = np.empty((64, 5), np.int64)
    span = np.empty(W, np.bool_)
    k = 0
    r0 = 0
    while r0 < H:
        if not rows[r0]:
            r0 += 1
            continue
        r1 = r0
        while r1 < H and rows[r1]:
            r1 += 1
        near = lr_band_cols(d, jump, c0, r0, r1, zone)
        span[:] = False
        for c in range(W):
            if near[c]:
                for r in range(r0, r1):
                    full[r, c] = True
                for q in range(max(0, c - n - zone), min(W, c + n + zone + 1)):
                    span[q] = True
        c = 0
        while c < W:
            if not span[c]:
                c += 1
                continue
            e = c
            while e < W and span[e]:
                e += 1
            if k == crops.shape[0]:
                more = np.empty((2 * k, 5), np.int64)
                more[:k] = crops
                crops = more
            crops[k, 0] = max(0, r0 - context)
            crops[k, 1] = r0
            crops[k, 2] = r1
            crops[k, 3] = c
            crops[k, 4] = e
            k += 1
            c = e
        r0 = r1
    return crops[:k], full


@numba.njit(cache=True, error_model="numpy")
def _smallest_eigvec_z(a00, a01, a02, a11, a12, a22):  # pragma: no cover - compiled
    """|z component| of the unit eigenvector of the smallest eigenvalue of a symmetric 3x3 matrix (closed-form
    eigenvalue, the eigenvector as the longest cross product of two rows of ``A - lambda I``); NaN if undefined."""
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    p2 = (a00 - q) ** 2 + (a11 - q) ** 2 + (a22 - q) ** 2 + 2.0 * p1
    if p2 <= 0.0:
        return np.nan
    p = np.sqrt(p2 / 6.0)
    b00, b11, b22 = (a00 - q) / p, (a11 - q) / p, (a22 - q) / p
    b01, b02, b12 = a01 / p, a02 / p, a12 / p
    r = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02))
    r = min(1.0, max(-1.0, r))
    lam = q + 2.0 * p * np.cos(np.arccos(r) / 3.0 + 2.0 * np.pi / 3.0)
    r0 = (a00 - lam, a01, a02)
    r1 = (a01, a11 - lam, a12)
    r2 = (a02, a12, a22 - lam)
    best = -1.0
    vz = np.nan
    for s in range(3):
        u = r0 if s < 2 else r1
        w = r1 if s == 0 else r2
        cx = u[1] * w[2] - u[2] * w[1]
        cy = u[2] * w[0] - u[0] * w[2]
        cz = u[0] * w[1] - u[1] * w[0]
        nn = cx * cx + cy * cy + cz * cz
        if nn > best:
            best = nn
            vz = abs(cz) / np.sqrt(nn) if nn > 0 else np.nan
    return vz


@numba.njit(cache=True, error_model="numpy")
def steep_points(disp, rows, cols, u0, v0, f, B, R, half, min_count, flat_range=0.0):  # pragma: no cover
    """For the pixels ``(rows, cols)`` of a block's disparities: the |vertical component| of the normal of the
    best-fitting plane (smallest principal axis) through the world points of the matched pixels in the
    ``(2 half + 1)^2`` window around each (NaN with fewer than ``min_count`` of them).  World frame of ``R``
    (``world_from_rect``), z up; the points relative to the left centre.  A window whose pixels are all matched
    with disparities within ``flat_range`` of each other is not fitted and reported as 1 (the caller's bound
    below which no window can be as steep as it tests for)."""
    H, W = disp.shape
    fb = f * B
    out = np.empty(rows.shape[0])
    # the window's extremes from its columns' (2 half + 1)-pixel extremes, each column's computed once per row it
    # is needed in (the pixels come row by row): 2 half + 1 reads a pixel instead of (2 half + 1)^2
    cmin = np.empty(W, disp.dtype)
    cmax = np.empty(W, disp.dtype)
    crow = np.full(W, -1, np.int64)
    for k in range(rows.shape[0]):
        r0, c0 = rows[k], cols[k]
        if flat_range > 0 and half <= r0 < H - half and half <= c0 < W - half:
            lo = np.inf
            hi = -np.inf
            for c in range(c0 - half, c0 + half + 1):
                if crow[c] != r0:
                    a = disp[r0 - half, c]
                    b = a
                    for r in range(r0 - half + 1, r0 + half + 1):
                        a = min(a, disp[r, c])
                        b = max(b, disp[r, c])
                    cmin[c] = a
                    cmax[c] = b
                    crow[c] = r0
                lo = min(lo, np.float64(cmin[c]))
                hi = max(hi, np.float64(cmax[c]))
            if lo > 0 and hi - lo <= flat_range:  # every pixel matched (> 0), all within flat_range
                out[k] = 1.0
                continue
        n = 0
        x0, y0, z0 = _world_offset(disp[r0, c0], r0, c0, u0, v0, f, fb, R)
        sx = sy = sz = sxx = sxy = sxz = syy = syz = szz = 0.0
        for r in range(max(0, r0 - half), min(H, r0 + half + 1)):
            for c in range(max(0, c0 - half), min(W, c0 + half + 1)):
                if disp[r, c] > 0:
                    xw, yw, zw = _world_offset(disp[r, c], r, c, u0, v0, f, fb, R)
                    x, y, z = xw - x0, yw - y0, zw - z0
                    n += 1
                    sx += x
                    sy += y
                    sz += z
                    sxx += x * x
                    sxy += x * y
                    sxz += x * z
                    syy += y * y
                    syz += y * z
                    szz += z * z
        if n < min_count:
            out[k] = np.nan
            continue
        mx, my, mz = sx / n, sy / n, sz / n
        out[k] = _smallest_eigvec_z(sxx / n - mx * mx, sxy / n - mx * my, sxz / n - mx * mz, syy / n - my * my,
                                    syz / n - my * mz, szz / n - mz * mz)
    return out


@numba.njit(cache=True, inline="always", error_model="numpy")
def _world_offset(d, r, c, u0, v0, f, fb, R):  # pragma: no cover - compiled
    """World offset from the left centre ``R p`` of the rectified pixel ``(r, c)`` of a block with disparity ``d``."""
    D = fb / d
    px, py, pz = (u0 + c) * D / f, -(v0 + r) * D / f, -D
    return (R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz, R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz,
            R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz)


@numba.njit(cache=True, error_model="numpy")
def confirm_cells(rr, cc, sp, height, sigma, cand_h, cand_s, cand2_h, cand2_s, r, k_sigma, min_tol,
                  two):  # pragma: no cover - compiled
    """Steps 4 and 5 of :mod:`skyrig.dense.fusion` (:func:`skyrig.dense.fusion.confirm_by_neighbours`) for the
    candidate cells ``(rr, cc)`` (``sp``: two-camp cells, decided only with ``two``) of whole grids, read only.
    Returns ``(hit, upper)``: the candidates kept, and among them those that take the upper camp.  The same float64
    arithmetic as the vectorised rule it replaces (the grids' float32 values widened, squared sigmas)."""
    H, W = height.shape
    n = rr.shape[0]
    hit = np.zeros(n, np.bool_)
    upper = np.zeros(n, np.bool_)
    for k in range(n):
        r0, c0 = rr[k], cc[k]
        split = sp[k]
        ch = np.float64(cand_h[r0, c0])
        cs2 = np.float64(cand_s[r0, c0]) ** 2
        uh = np.nan
        us2 = np.nan
        if split:
            uh = np.float64(cand2_h[r0, c0])
            us2 = np.float64(cand2_s[r0, c0]) ** 2
        undecided = split
        for ring in range(1, r + 1):
            n_lo = 0
            n_hi = 0
            for dr in range(-ring, ring + 1):
                for dc in range(-ring, ring + 1):
                    if max(abs(dr), abs(dc)) != ring:
                        continue
                    nr, nc = r0 + dr, c0 + dc
                    if nr < 0 or nr >= H or nc < 0 or nc >= W:
                        continue
                    nh = np.float64(height[nr, nc])
                    ns2 = np.float64(sigma[nr, nc]) ** 2
                    lo = abs(ch - nh) <= max(k_sigma * np.sqrt(cs2 + ns2), min_tol)
                    if lo and not split:
                        hit[k] = True
                    if two:
                        n_lo += lo
                        n_hi += abs(uh - nh) <= max(k_sigma * np.sqrt(us2 + ns2), min_tol)
            if two and undecided and n_lo != n_hi and (n_lo >= 2 * n_hi or n_hi >= 2 * n_lo):
                hit[k] = True
                upper[k] = n_hi > n_lo
                undecided = False
    return hit, upper
