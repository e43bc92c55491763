"""Test helper: the adjustment's linearised system assembled densely from its factors (an independent reference
for the solver engines' sparse / Schur assembly)."""

from __future__ import annotations

import numpy as np


def dense_system(factors, layout, row_weights=None):  # type: ignore[no-untyped-def]
    """``(J, r)``: every factor's Jacobian rows over all ``n_c + 3 n_p`` unknowns (camera-side columns from
    ``f.cols`` / ``f.jc``, point columns from ``f.point`` / ``f.jp``) and residuals, each row scaled by
    ``row_weights(f)`` (``(m,)``; default ``sqrt(f.weight)``, or 1 where a factor has no weight)."""
    n_c, n_p = layout.n_c, layout.n_p
    n = n_c + 3 * n_p
    Js, rs = [], []
    for f in factors:
        m, d = f.r.shape
        J = np.zeros((m, d, n))
        if f.jc is not None and f.cols is not None:
            for c in range(f.cols.shape[1]):
                on = f.cols[:, c] >= 0
                J[np.flatnonzero(on), :, f.cols[on, c]] += f.jc[on, :, c]
        if f.jp is not None and f.point is not None:
            on = f.point >= 0
            for a in range(3):
                J[np.flatnonzero(on), :, n_c + 3 * f.point[on] + a] += f.jp[on, :, a]
        if row_weights is not None:
            w = row_weights(f)
        else:
            w = np.sqrt(f.weight) if f.weight is not None else np.ones(m)
        Js.append((J * w[:, None, None]).reshape(m * d, n))
        rs.append((f.r * w[:, None]).reshape(-1))
    return np.concatenate(Js), np.concatenate(rs)
