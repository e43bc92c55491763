"""``skyrig convert SRC -o DST``: exterior orientations between formats, angle conventions, units and CRS.

``-o/--output`` names the file written, as for every single-file command (docs/cli.md); the older positional form
``skyrig convert SRC DST`` still works and warns that it is deprecated."""

from __future__ import annotations

import click

from skyrig.cli._common import EO_READERS, load_eo
from skyrig.georef.eo import WorldFrame
from skyrig.io.eo_csv import write_eo_csv


def _write_csv(eo, path, unit, convention):
    write_eo_csv(eo, path, unit=unit, convention=convention)


def _write_geo(eo, path, unit, convention):
    from skyrig.io.odm import write_geo_txt

    write_geo_txt(path, eo)


def _write_opk(eo, path, unit, convention):
    from skyrig.io.ign import write_ign_opk

    write_ign_opk(path, eo)


WRITERS = {"skyrig-csv": _write_csv, "odm-geo": _write_geo, "ign-opk": _write_opk}


@click.command("convert")
@click.argument("src", type=click.Path(exists=True, dir_okay=False))
@click.argument("dst", required=False, default=None, metavar="", type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None,
              help="EO file to write (the positional DST of older versions is deprecated).")
@click.option("--from-format", type=click.Choice(sorted(EO_READERS)), default=None, help="Input format (default: from the name).")
@click.option("--from-crs", default=None, help="CRS of the input when the file does not say.")
@click.option("--from-geoid", default=None, help="Geoid grid when input heights are orthometric.")
@click.option("--from-map-z-ground", type=float, default=None, help="Undo the linear alteration of input heights (map-coordinate adjustment) with this ground height.")
@click.option("--to-format", type=click.Choice(sorted(WRITERS)), default="skyrig-csv", show_default=True)
@click.option("--to-crs", default=None, help="Output CRS: EPSG code, WKT, PROJ string, 'ecef' (default: the input's).")
@click.option("--to-heights", type=click.Choice(["ellipsoidal", "orthometric"]), default=None, help="Output height reference (default: the input's).")
@click.option("--to-geoid", default=None, help="Geoid grid for orthometric output heights.")
@click.option("--to-angles", type=click.Choice(["deg", "rad", "gon"]), default="deg", show_default=True)
@click.option("--to-convention", type=click.Choice(["opk", "pok", "ypr"]), default="opk", show_default=True)
def command(src, dst, output, from_format, from_crs, from_geoid, from_map_z_ground, to_format, to_crs, to_heights, to_geoid,
            to_angles, to_convention) -> None:
    """Convert an exterior-orientation file SRC into the file -o/--output."""
    from skyrig.cli._common import output_or_positional

    dst = output_or_positional(output, dst, "DST")
    eo = load_eo(src, from_format, from_crs, from_geoid, from_map_z_ground, crs_option="--from-crs")
    if to_crs or to_heights or to_geoid:
        if to_crs and to_crs.lower() == "ecef":
            frame = WorldFrame.ecef()
        else:
            crs = to_crs or eo.frame.crs
            heights = to_heights or ("orthometric" if (to_geoid or eo.frame.geoid) else "ellipsoidal")
            geoid = (to_geoid or eo.frame.geoid) if heights == "orthometric" else None
            if heights == "orthometric" and not geoid:
                raise click.UsageError("orthometric output heights need --to-geoid")
            frame = WorldFrame.map(crs, geoid)
        eo = eo.to_frame(frame)
    WRITERS[to_format](eo, dst, to_angles, to_convention)
    click.echo(f"wrote {len(eo)} orientations ({eo.frame.describe()}, {to_convention} in {to_angles}) to {dst}")
