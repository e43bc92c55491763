"""Compiled kernels of the orthophoto (numba): a depth buffer of the DSM surface seen from one image, and the
visibility test of surface points against it.

The DSM lattice, projected into an image, is drawn as two triangles per 2 x 2 cells (the surface a DSM
describes, walls included as steep triangles between eave and ground); every pixel centre inside a triangle
keeps the smallest depth.  A surface point is visible when its own depth is not behind the buffer's depth at its
pixel by more than a tolerance.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True)
def zbuffer(u, v, d, zb, u0, v0, max_px):  # pragma: no cover - compiled
    """Draw the projected lattice ``u, v`` (pixel col/row) with depths ``d`` (all ``(H, W)``, NaN = not drawn)
    into ``zb`` ``(h, w)`` whose pixel ``(0, 0)`` is image pixel ``(u0, v0)``.  Triangles wider than ``max_px``
    pixels on a side are skipped (the lattice wraps behind the camera or is far outside the image)."""
    H, W = u.shape
    h, w = zb.shape
    for r in range(H - 1):
        for c in range(W - 1):
            for t in range(2):
                if t == 0:
                    ra, ca, rb, cb, rc, cc = r, c, r, c + 1, r + 1, c
                else:
                    ra, ca, rb, cb, rc, cc = r + 1, c + 1, r + 1, c, r, c + 1
                ua, va, da = u[ra, ca], v[ra, ca], d[ra, ca]
                ub, vb, db = u[rb, cb], v[rb, cb], d[rb, cb]
                uc, vc, dc = u[rc, cc], v[rc, cc], d[rc, cc]
                if not (da > 0 and db > 0 and dc > 0):  # also false for NaN
                    continue
                umin = min(ua, min(ub, uc))
                umax = max(ua, max(ub, uc))
                vmin = min(va, min(vb, vc))
                vmax = max(va, max(vb, vc))
                if umax - umin > max_px or vmax - vmin > max_px:
                    continue
                x0 = max(int(math.ceil(umin)) - u0, 0)
                x1 = min(int(math.floor(umax)) - u0, w - 1)
                y0 = max(int(math.ceil(vmin)) - v0, 0)
                y1 = min(int(math.floor(vmax)) - v0, h - 1)
                if x0 > x1 or y0 > y1:
                    continue
                den = (vb - vc) * (ua - uc) + (uc - ub) * (va - vc)
                if abs(den) < 1e-12:
                    continue
                for y in range(y0, y1 + 1):
                    py = y + v0
                    for x in range(x0, x1 + 1):
                        px = x + u0
                        l1 = ((vb - vc) * (px - uc) + (uc - ub) * (py - vc)) / den
                        l2 = ((vc - va) * (px - uc) + (ua - uc) * (py - vc)) / den
                        l3 = 1.0 - l1 - l2
                        if l1 < -1e-9 or l2 < -1e-9 or l3 < -1e-9:
                            continue
                        z = l1 * da + l2 * db + l3 * dc
                        if z < zb[y, x]:
                            zb[y, x] = z


@numba.njit(cache=True)
def visible(u, v, d, tol, zb, u0, v0, out):  # pragma: no cover - compiled
    """``out = d <= zb(nearest pixel) + tol`` for points inside the buffer (False outside / NaN); 1-D arrays."""
    n = u.shape[0]
    uf, vf, df, tf, of = u, v, d, tol, out
    h, w = zb.shape
    for i in range(n):
        of[i] = False
        if not (df[i] > 0):
            continue
        x = int(math.floor(uf[i] + 0.5)) - u0
        y = int(math.floor(vf[i] + 0.5)) - v0
        if x < 0 or y < 0 or x >= w or y >= h:
            continue
        of[i] = df[i] <= zb[y, x] + tf[i]
