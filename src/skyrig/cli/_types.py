"""Click parameter types that refuse a bad number while the command line is parsed, before any input is read:
NaN, infinities, a unit written after the number ("10cm"), and values out of the option's range."""

from __future__ import annotations

import math

import click


class Number(click.ParamType):
    """A finite float (``integer=True``: a whole number), ``> 0`` with ``positive``, ``>= 0`` with ``nonnegative``."""

    def __init__(self, *, integer: bool = False, positive: bool = False, nonnegative: bool = False,
                 unit: str = "", limit: float = math.inf) -> None:
        self.integer, self.positive, self.nonnegative, self.unit = integer, positive, nonnegative, unit
        self.limit = limit
        self.name = "integer" if integer else "number"

    def convert(self, value, param, ctx):  # noqa: ANN001, ANN201
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            v = value
        else:
            text = str(value).strip()
            try:
                v = int(text) if self.integer else float(text)
            except ValueError:
                unit = f" in {self.unit} (without a unit)" if self.unit else ""
                self.fail(f"{value!r} is not a{'' if self.integer else ' finite'} "
                          f"{'whole number' if self.integer else 'number'}{unit}", param, ctx)
        if not math.isfinite(v):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        if abs(v) > self.limit:
            self.fail(f"{value!r} is beyond +-{self.limit:g}{' ' + self.unit if self.unit else ''}", param, ctx)
        if self.positive and not v > 0:
            self.fail(f"{value!r} must be > 0", param, ctx)
        if self.nonnegative and not v >= 0:
            self.fail(f"{value!r} must be >= 0", param, ctx)
        return v


FINITE = Number()
POSITIVE = Number(positive=True)
NONNEGATIVE = Number(nonnegative=True)
POSITIVE_M = Number(positive=True, unit="metres")
POSITIVE_INT = Number(integer=True, positive=True)
#: A ground height in metres (map-coordinate adjustments): within +-10 km of the ellipsoid.
MAP_Z = Number(unit="metres", limit=10_000.0)


class CrsText(click.ParamType):
    """A CRS text PROJ knows (EPSG code, compound ``EPSG:h+v``, WKT, PROJ string) or a frame text skyrig writes
    (``ecef``, a local frame); checked while parsing, so that an unknown code is refused before inputs are read."""

    name = "crs"

    def convert(self, value, param, ctx):  # noqa: ANN001, ANN201
        text = str(value).strip()
        if not text:
            self.fail("an empty CRS (give an EPSG code such as EPSG:25832)", param, ctx)
        if text.lower() == "ecef":
            return value
        from pyproj import CRS
        from pyproj.exceptions import CRSError as ProjCRSError

        try:
            CRS.from_user_input(text)
            return value
        except ProjCRSError as exc:
            proj_words = str(exc).split("(Internal Proj Error:")[-1].strip(" )")
        from skyrig.geodesy.frame import WorldFrame

        try:
            WorldFrame.from_text(text)
            return value
        except Exception:  # noqa: BLE001 - any refusal of the skyrig frame parser: the PROJ words are the message
            self.fail(f"unknown coordinate reference system {text!r} ({proj_words})", param, ctx)


class GeoidText(click.ParamType):
    """A geoid grid: a PROJ grid name, or a path, which must then exist."""

    name = "geoid"

    def convert(self, value, param, ctx):  # noqa: ANN001, ANN201
        import os

        text = str(value).strip()
        if not text:
            self.fail("an empty geoid grid name", param, ctx)
        if (os.sep in text or "/" in text) and not os.path.exists(text):
            self.fail(f"geoid grid file {text!r} does not exist", param, ctx)
        return value


CRS_TEXT = CrsText()
GEOID = GeoidText()
