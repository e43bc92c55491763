"""What the subcommands share: the readers of EO files, cameras, ground points and image measurements, the checks of
measurements against their images, the EO options, and one CLI vocabulary (sigmas, old spellings, ``-o``).

The readers are :mod:`skyrig.pipeline.inputs` (one implementation for the commands and the project runner); this
module re-exports them under the names the commands import and only adds what is command-line wording.  Their errors
are :class:`skyrig.errors.SkyrigError` naming the file, line and field, or the option as the command line spells it
(``--eo-crs``, ``--points-crs``, ``convert --from-crs``); the ``skyrig`` group prints them as ``error: ...`` and exits 2.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import click

from skyrig.cli._types import CRS_TEXT, GEOID, MAP_Z
import numpy as np

from skyrig.camera.frame import FrameCamera
from skyrig.errors import InputFormatError
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.georef.observations import ImageMeasurements
from skyrig.pipeline.inputs import EO_FORMATS as EO_READERS
from skyrig.pipeline.inputs import (head_rows, load_cameras, load_eo, load_measurements, load_measurements_lines,
                                    load_points, project_frame_of, select_heads)

__all__ = ["EO_READERS", "load_eo", "load_cameras", "load_points", "load_measurements", "load_measurements_lines",
           "head_rows", "select_heads", "project_frame_option", "check_measurements", "check_cameras", "eo_options",
           "parse_sigmas", "with_old_spellings", "output_or_positional"]


def project_frame_option(crs: str | None, geoid: str | None) -> WorldFrame | None:
    """The project frame from ``--crs`` / ``--geoid`` (a compound CRS brings its geoid); None without ``--crs``:
    :func:`skyrig.pipeline.inputs.project_frame_of` with the command-line spellings."""
    return project_frame_of(crs, geoid, "--crs", "--geoid")


def check_measurements(m: ImageMeasurements, lines: np.ndarray, path: str, eo: ExteriorOrientations,
                       cameras: Mapping[str, FrameCamera]) -> None:
    """Refuse measurements of an image without orientation, or far outside their image, naming file and line."""
    from skyrig.georef.ground import far_outside_image

    known = eo.index()
    for k, img in enumerate(m.image):
        if img not in known:
            raise InputFormatError(f"image {img!r} has no exterior orientation", path, int(lines[k]), "image")
    for c in np.unique([str(eo.camera[known[i]]) for i in np.unique(m.image)]):
        if c not in cameras:
            raise click.UsageError(f"camera {c!r} of the EO file is not defined by any --camera file "
                                   f"(known: {', '.join(sorted(cameras))})")
    far = far_outside_image(eo, cameras, m.image, m.pixel)
    if far.any():
        k = int(np.flatnonzero(far)[0])
        cam = cameras[str(eo.camera[known[m.image[k]]])]
        col, row = (float(v) for v in m.pixel[k])
        field = "column" if not -0.5 - cam.width <= col <= 2 * cam.width - 0.5 else "row"
        more = f" ({int(far.sum())} such measurements in all)" if far.sum() > 1 else ""
        raise InputFormatError(
            f"pixel ({col:.6g}, {row:.6g}) of point {str(m.point[k])!r} lies more than one image size outside image "
            f"{str(m.image[k])!r} ({cam.width} x {cam.height} px){more}", path, int(lines[k]), field)


def check_cameras(eo: ExteriorOrientations, cameras: Mapping[str, FrameCamera], eo_path: str) -> None:
    """Refuse an EO whose camera names no ``--camera`` file defines, naming the EO file, the first image and the
    cameras known."""
    missing = [i for i, c in enumerate(eo.camera) if str(c) not in cameras]
    if missing:
        k = missing[0]
        names = sorted({str(eo.camera[i]) for i in missing})
        raise InputFormatError(
            f"camera {names[0]!r} of image {str(eo.image[k])!r} is not defined by any --camera file (known: "
            f"{', '.join(sorted(cameras))}; {len(missing)} image(s) without a camera)", eo_path, None, "camera")


def eo_options(f: Callable) -> Callable:
    """Options describing how to read an EO file."""
    opts = [
        click.option("--eo", "eo_path", required=True, type=click.Path(exists=True, dir_okay=False), help="Exterior orientation file (skyrig EO CSV, IGN .OPK, ODM geo.txt)."),
        click.option("--eo-format", type=click.Choice(sorted(EO_READERS)), default=None, help="EO file format (default: from the file name)."),
        click.option("--eo-crs", type=CRS_TEXT, default=None, help="CRS of the EO file when it does not say (e.g. EPSG:2154 for IGN .OPK)."),
        click.option("--eo-geoid", type=GEOID, default=None, help="Geoid grid (path or PROJ name) when EO heights are orthometric."),
        click.option("--eo-map-z-ground", type=MAP_Z, default=None, help="Undo the linear alteration of projection-centre heights from an adjustment in map coordinates, with this mean ground height (m)."),
        click.option("--camera", "camera_paths", multiple=True, required=True, type=click.Path(exists=True, dir_okay=False), help="Camera file (IGN camera .txt or skyrig rig YAML); repeat for several."),
    ]
    for o in reversed(opts):
        f = o(f)
    return f


# ----------------------------------------------------------------------------------------- one CLI vocabulary
def parse_sigmas(text: str, n: int, option: str, names: str = "", positive: bool = False) -> tuple[float, ...]:
    """Standard deviations in the one sigma syntax: ``"0.05"`` (all axes) or ``n`` comma-separated numbers
    (``"0.05,0.05,0.08"``), each finite and >= 0 (> 0 with ``positive``: a sigma that becomes a weight); a clear
    :class:`click.BadParameter` naming ``option`` else.

    >>> parse_sigmas("2", 3, "--gnss-sigma")
    (2.0, 2.0, 2.0)
    >>> parse_sigmas("2, 2,4", 3, "--gnss-sigma")
    (2.0, 2.0, 4.0)
    """
    import math

    parts = [p.strip() for p in str(text).split(",")]
    what = f" ({names})" if names else ""
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        raise click.BadParameter(f"{text!r} is not one number or {n} comma-separated numbers{what}",
                                 param_hint=option) from None
    if len(vals) == 1:
        vals = vals * n
    if len(vals) != n:
        raise click.BadParameter(f"{text!r}: expected one number or {n} comma-separated numbers{what}, got "
                                 f"{len(vals)}", param_hint=option)
    if not all(math.isfinite(v) and (v > 0 if positive else v >= 0) for v in vals):
        raise click.BadParameter(f"{text!r}: standard deviations must be finite and {'> 0' if positive else '>= 0'}",
                                 param_hint=option)
    return vals


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def with_old_spellings(renamed: Mapping[str, str] | None = None,
                       spaced: Mapping[str, int] | None = None) -> type[click.Command]:
    """A click command class that still accepts a command's old option spellings and warns that they are
    deprecated (``warning: ... is deprecated; use ...`` on standard error), so that one vocabulary can be
    documented without breaking scripts.

    Parameters
    ----------
    renamed
        ``{old: new}`` option names (``{"--out": "--output"}``); ``--old=value`` works too.  The option may keep
        declaring the old name (hidden from nobody: click's messages then name the spelling the user typed).
    spaced
        ``{option: n}`` for options that now take comma text but once took ``n`` separate numbers
        (``--gnss-sigma 2 2 4`` becomes ``--gnss-sigma 2,2,4``).

    The spellings the user typed are kept in ``ctx.meta["skyrig.old_spellings"]`` (old -> new).
    """
    renamed = dict(renamed or {})
    spaced = dict(spaced or {})

    class _Command(click.Command):
        def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
            out: list[str] = []
            used: dict[str, str] = {}
            declared = {o for p in self.params for o in (*getattr(p, "opts", ()), *getattr(p, "secondary_opts", ()))}
            i = 0
            while i < len(args):
                tok = args[i]
                if tok == "--":
                    out.extend(args[i:])
                    break
                name, eq, value = tok.partition("=")
                if name in renamed:
                    used[name] = renamed[name]
                    if name not in declared:  # an old name the option no longer declares: spelt the new way
                        tok = renamed[name] + eq + value
                    name = renamed[name]
                n = spaced.get(name)
                if n and not eq and i + n < len(args) and all(_is_number(a) for a in args[i + 1:i + 1 + n]) \
                        and n > 1 and "," not in args[i + 1]:
                    used[f"{name} {' '.join(['N'] * n)}"] = f"{name} " + ",".join(["N"] * n)
                    out.extend([tok, ",".join(args[i + 1:i + 1 + n])])
                    i += 1 + n
                    continue
                out.append(tok)
                i += 1
            for old, new in used.items():
                click.echo(f"warning: {old} is deprecated; use {new}", err=True)
            ctx.meta["skyrig.old_spellings"] = used
            return super().parse_args(ctx, out)

    return _Command


def output_or_positional(output: str | None, positional: str | None, metavar: str, default: str | None = None) -> str:
    """The output path of a command that used to take it as a positional argument (``convert SRC DST``,
    ``simulate SCENARIO OUTDIR``, ``demo [OUTDIR]``): ``-o/--output`` is the one spelling (docs/cli.md); the
    positional form still works with a ``warning: ... is deprecated`` line on standard error.  Both at once is a
    usage error; neither gives ``default`` (a usage error naming ``-o/--output`` without one)."""
    if positional is not None and output is not None:
        raise click.UsageError(f"the output is given twice: -o/--output {output} and positional {metavar} "
                               f"{positional}; give -o/--output only")
    if positional is not None:
        click.echo(f"warning: the positional {metavar} is deprecated; use -o/--output {positional}", err=True)
        return positional
    if output is not None:
        return output
    if default is None:
        raise click.UsageError("missing option '-o' / '--output'")
    return default
