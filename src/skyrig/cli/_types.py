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


# ------------------------------------------------------------------------ magnitudes: a plausible number, its unit
#: Other units a number in metres may have been written in (name, metres per unit).
_METRE_UNITS = (("millimetres", 0.001), ("centimetres", 0.01))
#: ... in degrees (name, degrees per unit).
_DEGREE_UNITS = (("arc seconds", 1.0 / 3600.0), ("milligon", 0.0009))


class Magnitude(Number):
    """A finite number in ``unit`` checked against what it measures (issue 29: a plausible number in a wrong unit).

    Outside ``refuse`` (lo, hi) it is refused while parsing; outside ``usual`` (lo, hi) a one-line warning is said
    (:class:`~skyrig.errors.PlausibilityWarning`, ``warning: ...``).  Either way the words name the option, the
    value with its unit, the expected range and the units among ``others`` ((name, ``unit`` per that unit)) in
    which the number would be usual: ``--gsd 5`` -> "5 metres is not plausible as a ground sampling distance
    (expected 0.0001 to 2 metres); centimetres (0.05 metres) or millimetres (0.005 metres)?"."""

    def __init__(self, what: str, unit: str, refuse: tuple[float, float], usual: tuple[float, float] | None = None,
                 others: tuple[tuple[str, float], ...] = (), *, nonnegative: bool = False) -> None:
        super().__init__(unit=unit, nonnegative=nonnegative)
        self.what, self.refuse, self.usual, self.others = what, refuse, usual or refuse, others

    def convert(self, value, param, ctx):  # noqa: ANN001, ANN201
        v = super().convert(value, param, ctx)
        problem = self.judge(v)
        if problem is not None and problem[0] == "refuse":
            self.fail(problem[1], param, ctx)
        if problem is not None:
            self.say(problem[1], param)
        return v

    def judge(self, v: float) -> tuple[str, str] | None:
        """``("refuse" | "warn", words)`` for ``v``, None when it is usual (0 passes where 0 is allowed)."""
        if v == 0 and self.nonnegative:
            return None
        for kind, (lo, hi) in (("refuse", self.refuse), ("warn", self.usual)):
            if lo <= abs(v) <= hi:
                continue
            fits = [f"{name} ({v * f:.6g} {self.unit})" for name, f in self.others
                    if self.usual[0] <= abs(v * f) <= self.usual[1]]
            hint = f"; {' or '.join(fits)}?" if fits else ""
            verb = "is not plausible" if kind == "refuse" else "is unusual"
            return kind, (f"{v:g} {self.unit} {verb} as {self.what} (expected {lo:g} to {hi:g} {self.unit}){hint}")
        return None

    @staticmethod
    def say(words: str, param) -> None:  # noqa: ANN001
        import warnings

        from skyrig.errors import PlausibilityWarning

        name = param.opts[0] if param is not None and getattr(param, "opts", None) else "option"
        warnings.warn(f"{name}: {words}", PlausibilityWarning, stacklevel=2)


class MagnitudeList(click.ParamType):
    """One number or comma-separated numbers (``"0.05,0.05,0.08"``: standard deviations per axis), each finite,
    non-negative number judged by a :class:`Magnitude`; the text is returned unchanged (the command parses it as
    before and refuses, in its words, what is not a number, not finite, negative or the wrong count)."""

    name = "numbers"

    def __init__(self, each: Magnitude) -> None:
        self.each = each

    def convert(self, value, param, ctx):  # noqa: ANN001, ANN201
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            self.each.convert(value, param, ctx)
            return value
        text = str(value)
        for part in text.replace(";", ",").split(","):
            try:
                v = float(part)
            except ValueError:
                continue  # not a number: the command's own parser says so (the sigma syntax, the count)
            if math.isfinite(v) and v >= 0:
                self.each.convert(v, param, ctx)
        return value


#: Ground sampling distance (m): a UAV's millimetres to a high aerial camera's metre.
GSD_M = Magnitude("a ground sampling distance", "metres", (1e-4, 2.0), (5e-4, 1.0), _METRE_UNITS)
#: Flying height above ground (m).
FLYING_HEIGHT_M = Magnitude("a flying height above ground", "metres", (1.0, 20_000.0), (5.0, 12_000.0),
                            _METRE_UNITS)
#: A terrain / plane height (m, ellipsoidal or orthometric): the Dead Sea to Everest with the geoid's range.
GROUND_HEIGHT_M = Magnitude("a ground height", "metres", (0.0, 9_000.0), None, _METRE_UNITS, nonnegative=False)
#: GNSS / projection-centre standard deviation (m): refused beyond 100 m, unusual beyond 10 m.
GNSS_SIGMA_M = MagnitudeList(Magnitude("a GNSS position's standard deviation", "metres", (0.0, 100.0), (0.0, 10.0),
                                       _METRE_UNITS, nonnegative=True))
#: Ground control standard deviation (m): refused beyond 100 m, unusual beyond 2 m.
CONTROL_SIGMA_M = MagnitudeList(Magnitude("a ground point's standard deviation", "metres", (0.0, 100.0), (0.0, 2.0),
                                          _METRE_UNITS, nonnegative=True))
#: Attitude (IMU) standard deviation (deg): refused beyond 90, unusual beyond 1 (an aerial IMU: 0.003-0.01).
IMU_SIGMA_DEG = MagnitudeList(Magnitude("an attitude's standard deviation", "degrees", (0.0, 90.0), (0.0, 1.0),
                                        _DEGREE_UNITS, nonnegative=True))
#: Image measurement standard deviation (px): refused beyond 100 px, unusual beyond 10 px.
PIXEL_SIGMA_PX = Magnitude("an image measurement's standard deviation", "pixels", (0.0, 100.0), (0.0, 10.0),
                           nonnegative=True)
#: Image measurement standard deviation (um on the sensor): refused beyond 1000 um, unusual outside 0.05-50 um.
PIXEL_SIGMA_UM = Magnitude("an image measurement's standard deviation", "micrometres", (1e-3, 1000.0), (0.05, 50.0),
                           (("millimetres", 1000.0),))
