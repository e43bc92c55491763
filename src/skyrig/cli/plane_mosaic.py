"""``skyrig plane-mosaic``: oriented images projected onto one plane from their orientations alone, with the
feature offsets across the seams (paper 000, Fig. 9: the check of a tumbling head's boresight curve)."""

from __future__ import annotations

import click

from skyrig.cli._types import GROUND_HEIGHT_M

from skyrig.cli._common import eo_options


@click.command("plane-mosaic")
@eo_options
@click.option("--images", "images", multiple=True, required=True, type=click.Path(exists=True),
              help="Image folder or image file; repeat for several. Only images with an orientation are used.")
@click.option("--heads", default=None, help="Use only these rig heads / name parts (comma list, e.g. 'tumbling,nadir').")
@click.option("--height", type=GROUND_HEIGHT_M, default=None,
              help="The horizontal plane at this height (m, in the EO file's heights) under the mean projection centre.")
@click.option("--plane", nargs=6, type=float, default=None, metavar="X Y Z NX NY NZ",
              help="Any plane: a point and its normal in the EO file's frame (e.g. a façade).")
@click.option("--resolution", type=float, default=None,
              help="Mosaic cell size in metres (default: the images' median GSD on the plane).")
@click.option("--window", type=int, default=64, show_default=True, help="Seam correlation window (mosaic pixels).")
@click.option("--max-offset", type=float, default=None,
              help="Fail (exit status 1, outputs kept) when a seam's offset exceeds this many mosaic pixels.")
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False), help="Output folder.")
def command(eo_path, eo_format, eo_crs, eo_geoid, eo_map_z_ground, camera_paths, images, heads, height, plane,
            resolution, window, max_offset, output) -> None:
    """Images projected onto one plane without any image matching, and how far features jump across the seams.

    Every cell of a grid on the plane is projected into every image with its orientation and camera model
    (distortion included); the image looking most directly at the cell colours it.  Along each seam the two images'
    projections are compared by phase correlation: correct orientations give offsets near zero, an error in one
    image's orientation shows as the offset of its seams (paper 000, Fig. 9).
    """
    from skyrig.cli._common import load_cameras, load_eo
    from skyrig.pipeline.products import make_plane_mosaic

    if max_offset is not None and not max_offset > 0:
        raise click.BadParameter("must be a positive number of pixels", param_hint="--max-offset")
    eo = load_eo(eo_path, eo_format, eo_crs, eo_geoid, eo_map_z_ground)
    cameras = load_cameras(camera_paths)
    s = make_plane_mosaic(eo, cameras, images, output, height=height, plane=plane, heads=heads,
                          resolution=resolution, window=window, inputs=[eo_path, *camera_paths])
    g = s["grid"]
    if s["seams_measured"]:
        offs = (f"seam offsets median {s['median_offset_px']:.2f} px, max {s['max_offset_px']:.2f} px "
                f"({s['seams_measured']} of {s['seams']} seams measured)")
    else:
        offs = f"no seam could be measured ({s['seams']} seams, too little texture or overlap)"
    click.echo(f"plane mosaic of {len(s['images'])} images: {g['cols']} x {g['rows']} cells of {g['cell_m']:.4f} m, "
               f"{100 * s['covered']:.1f} % covered; {offs} -> {output}")
    if max_offset is not None and s["max_offset_px"] is not None and s["max_offset_px"] > max_offset:
        click.echo(f"error: a seam offset of {s['max_offset_px']:.2f} px exceeds --max-offset {max_offset}", err=True)
        raise SystemExit(1)
