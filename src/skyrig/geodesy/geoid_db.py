"""Which vertical CRS a geoid grid file belongs to, from PROJ's database (``proj.db``): the lookup shared by
:mod:`skyrig.geodesy.frame` and :mod:`skyrig.geodesy.statement` (kept apart so that neither imports the other)."""

from __future__ import annotations

import os
import sqlite3
from functools import lru_cache
from pathlib import Path

import pyproj

__all__ = ["vertical_crs_of_geoid"]


def _proj_db() -> Path:
    dirs = [Path(d) for d in pyproj.datadir.get_data_dir().split(os.pathsep) if d]  # append_data_dir adds folders
    return next((d / "proj.db" for d in dirs if (d / "proj.db").is_file()), dirs[0] / "proj.db")


@lru_cache(maxsize=64)
def _vertical_code_of_grid(name: str) -> tuple[str, str] | None:
    """(auth, code) of the vertical CRS that PROJ's database ties to a geoid grid file name."""
    try:
        con = sqlite3.connect(f"file:{_proj_db()}?mode=ro", uri=True)
    except sqlite3.Error:  # pragma: no cover - PROJ without its database does not work at all
        return None
    try:
        low = name.lower()
        names = {low}
        for row in con.execute(
            "SELECT original_grid_name FROM grid_alternatives WHERE lower(original_grid_name)=? "
            "OR lower(proj_grid_name)=? OR lower(old_proj_grid_name)=?", (low, low, low)):
            names.add(row[0].lower())
        for gname in sorted(names):
            rows = con.execute(
                "SELECT g.target_crs_auth_name, g.target_crs_code FROM grid_transformation g "
                "JOIN vertical_crs v ON v.auth_name=g.target_crs_auth_name AND v.code=g.target_crs_code "
                "WHERE lower(g.grid_name)=? AND g.deprecated=0 ORDER BY g.auth_name, g.code", (gname,)).fetchall()
            if rows:
                return rows[0][0], rows[0][1]
        return None
    finally:
        con.close()


def vertical_crs_of_geoid(geoid: str) -> pyproj.CRS | None:
    """The vertical CRS of heights above a geoid grid, when PROJ's database identifies the grid.

    The grid's file name (``egm96_15.gtx``, ``us_nga_egm96_15.tif``, ``fr_ign_RAF20.tif``...) is looked up
    in PROJ's ``grid_alternatives`` and ``grid_transformation`` tables (``proj.db``).

    Examples
    --------
    >>> vertical_crs_of_geoid("egm96_15.gtx").to_epsg()
    5773
    >>> vertical_crs_of_geoid("no_such_grid.tif") is None
    True
    """
    code = _vertical_code_of_grid(Path(str(geoid)).name)
    if code is None:
        return None
    return pyproj.CRS.from_authority(*code)
