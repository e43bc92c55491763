"""Loaders shared by subcommands: EO files, cameras and ground points in any supported format.

Formats are chosen through registries keyed by name (``--eo-format``), or guessed from the file name.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import click
import numpy as np

from skyrig.camera.frame import FrameCamera
from skyrig.errors import InputFormatError
from skyrig.georef.eo import ExteriorOrientations, WorldFrame
from skyrig.georef.observations import GroundPoints, ImageMeasurements


def project_frame_option(crs: str | None, geoid: str | None) -> WorldFrame | None:
    """The project frame from ``--crs`` / ``--geoid`` (a compound CRS brings its geoid); None without ``--crs``."""
    if crs is None:
        if geoid is not None:
            raise click.UsageError("--geoid goes with --crs")
        return None
    from skyrig.errors import CRSError
    from skyrig.geodesy.statement import project_frame

    try:
        return project_frame(crs, geoid)
    except CRSError as e:
        raise click.BadParameter(str(e), param_hint="--crs") from None


def map_frame(crs: str | None, geoid: str | None, what: str, option: str = "--crs") -> WorldFrame:
    """The map frame of a file that states none, from the command-line ``option`` (named in the message)."""
    if not crs:
        raise click.UsageError(f"{what} needs {option} (the file does not say which CRS it is in)")
    return WorldFrame.map(crs, geoid)


def _eo_ign(path: str, crs: str | None, geoid: str | None, z_ground: float | None,
            option: str = "--eo-crs") -> ExteriorOrientations:
    from skyrig.io.ign import read_ign_opk

    eo = read_ign_opk(path, map_frame(crs, geoid, "an IGN OPK file", option))
    return eo if z_ground is None else eo.with_map_heights_reduced(z_ground)


def _eo_csv(path: str, crs: str | None, geoid: str | None, z_ground: float | None) -> ExteriorOrientations:
    from skyrig.io.eo_csv import read_eo_csv

    eo = read_eo_csv(path)
    return eo if z_ground is None else eo.with_map_heights_reduced(z_ground)


def _eo_geo_txt(path: str, crs: str | None, geoid: str | None, z_ground: float | None) -> ExteriorOrientations:
    import numpy as np

    from skyrig.io.odm import read_geo_txt, rotation_from_gimbal_ypr

    g = read_geo_txt(path, geoid)
    if g.ypr_deg is None:
        raise InputFormatError("geo.txt has no camera angles; it cannot give exterior orientations", path)
    rot = rotation_from_gimbal_ypr(g.frame, g.xyz, g.ypr_deg)
    return ExteriorOrientations(g.image, np.full(len(g.image), "camera"), g.xyz, rot, g.frame)


EO_READERS: dict[str, Callable[..., ExteriorOrientations]] = {
    "skyrig-csv": _eo_csv,
    "ign-opk": _eo_ign,
    "odm-geo": _eo_geo_txt,
}


def guess_eo_format(path: str) -> str:
    name = Path(path).name.lower()
    if name.endswith(".opk"):
        return "ign-opk"
    if name.startswith("geo") and name.endswith(".txt"):
        return "odm-geo"
    return "skyrig-csv"


def load_eo(path: str, fmt: str | None, crs: str | None, geoid: str | None, z_ground: float | None,
            crs_option: str = "--eo-crs") -> ExteriorOrientations:
    """An EO file in any format of :data:`EO_READERS`; ``crs_option`` is the option that gives the CRS of a file
    that states none (named in the message when it is missing: ``--eo-crs``, ``convert --from-crs``)."""
    fmt = fmt or guess_eo_format(path)
    if fmt not in EO_READERS:
        raise click.UsageError(f"unknown EO format {fmt!r}; known: {', '.join(EO_READERS)}")
    if EO_READERS[fmt] is _eo_ign:
        return _eo_ign(path, crs, geoid, z_ground, crs_option)
    return EO_READERS[fmt](path, crs, geoid, z_ground)


def load_cameras(paths: Sequence[str]) -> dict[str, FrameCamera]:
    """Cameras from IGN camera .txt files and/or skyrig rig files (YAML): :func:`skyrig.pipeline.inputs.load_cameras`."""
    from skyrig.pipeline.inputs import load_cameras as _load

    return _load(paths, "--camera")


def load_points(path: str, crs: str | None, heights: str, geoid: str | None, default_crs: str | None = None,
                option: str = "--points-crs") -> GroundPoints:
    """Ground points from IGN .app / _world.mes, ODM gcp_list.txt, or a skyrig points CSV.

    ``crs`` (with ``heights`` / ``geoid``) is the frame given on the command line by ``option``: a skyrig CSV that
    states its own frame must agree with it.  ``default_crs`` (ellipsoidal heights unless ``heights`` says
    orthometric) is used only for a file that states no frame (e.g. the EO's CRS); the file's statement wins.
    """
    name = Path(path).name.lower()
    g = geoid if heights == "orthometric" else None
    frame = None if crs is None else WorldFrame.map(crs, g)
    default = None if default_crs is None else WorldFrame.map(default_crs, g)
    if name.endswith((".app", ".mes")):
        from skyrig.io.ign import read_ign_ground_points

        use = frame or default
        return read_ign_ground_points(path, use if use else map_frame(crs, None, "an IGN point file", option))
    if name.startswith("gcp_list"):
        from skyrig.io.odm import read_gcp_list

        return read_gcp_list(path, g)[0]
    from skyrig.io.points_csv import read_points_csv

    return read_points_csv(path, frame, default, option)


def load_measurements(path: str) -> ImageMeasurements:
    """Image measurements from a skyrig CSV, an IGN .mes or an ODM gcp_list.txt."""
    return load_measurements_lines(path)[0]


def load_measurements_lines(path: str) -> tuple[ImageMeasurements, np.ndarray]:
    """:func:`load_measurements` and the ``(N,)`` 1-based line of each measurement in its file."""
    name = Path(path).name.lower()
    if name.endswith(".mes"):
        from skyrig.io.ign import read_ign_measurements_lines

        return read_ign_measurements_lines(path)
    if name.startswith("gcp_list"):
        from skyrig.io.odm import read_gcp_list_lines

        _, m, lines = read_gcp_list_lines(path)
        return m, lines
    from skyrig.io.points_csv import read_measurements_csv_lines

    return read_measurements_csv_lines(path)


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


def head_rows(eo: ExteriorOrientations, spec: str) -> tuple[list[str], list[np.ndarray]]:
    """The rows of ``eo`` per rig head / image-name part of a comma list: :func:`skyrig.pipeline.inputs.head_rows`."""
    from skyrig.pipeline.inputs import head_rows as _rows

    return _rows(eo, spec)


def select_heads(eo: ExteriorOrientations, spec: str | None, option: str = "--heads") -> ExteriorOrientations:
    """The orientations of some rig heads (all when ``spec`` is empty); no match is an error naming ``option``:
    :func:`skyrig.pipeline.inputs.select_heads`."""
    from skyrig.pipeline.inputs import select_heads as _select

    return _select(eo, spec, option)


def eo_options(f: Callable) -> Callable:
    """Options describing how to read an EO file."""
    opts = [
        click.option("--eo", "eo_path", required=True, type=click.Path(exists=True, dir_okay=False), help="Exterior orientation file (skyrig EO CSV, IGN .OPK, ODM geo.txt)."),
        click.option("--eo-format", type=click.Choice(sorted(EO_READERS)), default=None, help="EO file format (default: from the file name)."),
        click.option("--eo-crs", default=None, help="CRS of the EO file when it does not say (e.g. EPSG:2154 for IGN .OPK)."),
        click.option("--eo-geoid", default=None, help="Geoid grid (path or PROJ name) when EO heights are orthometric."),
        click.option("--eo-map-z-ground", type=float, default=None, help="Undo the linear alteration of projection-centre heights from an adjustment in map coordinates, with this mean ground height (m)."),
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
