"""Plain Python values for JSON: numpy scalars and arrays, nested in dicts / lists / tuples, as numbers and lists."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["plain"]


def plain(v: Any, nan_as_none: bool = False) -> Any:
    """``v`` with numpy scalars as Python numbers, arrays and tuples as lists, dict keys as strings; with
    ``nan_as_none`` also NaN / inf floats as None (JSON has no NaN)."""
    if isinstance(v, dict):
        return {str(k): plain(x, nan_as_none) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [plain(x, nan_as_none) for x in v]
    if isinstance(v, np.ndarray):
        return plain(v.tolist(), nan_as_none)
    if isinstance(v, np.generic):
        return plain(v.item(), nan_as_none)
    if nan_as_none and isinstance(v, float) and not np.isfinite(v):
        return None
    return v
