"""``skyrig facades``: building blocks, façade textures and a textured 3D model (GLB, OBJ, HTML viewer)."""

from __future__ import annotations

import click

from skyrig.cli._common import eo_options


@click.command("facades")
@click.option("--dsm", "dsm_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="DSM (GeoTIFF / COG, e.g. skyrig dsm's dsm.tif) in a projected CRS: buildings, occlusions, output CRS.")
@eo_options
@click.option("--images", "images", multiple=True, required=True, type=click.Path(exists=True),
              help="Image folder or image file; repeat for several. Only images with an orientation are used.")
@click.option("--heads", default=None, help="Use only these rig heads / name parts (comma list, e.g. 'fwd,bwd,left,right').")
@click.option("--footprints", default=None, type=click.Path(exists=True, dir_okay=False),
              help="Building footprints (GeoPackage polygons, any CRS); default: extracted from the DSM.")
@click.option("--footprint-layer", default=None,
              help="Layer of --footprints (default: 'buildings', else the only polygon layer).")
@click.option("--footprint-eave", default=None, metavar="FIELD",
              help="Attribute of --footprints with each building's eave height in metres (see --footprint-heights), "
                   "used where the DSM has no heights (a cadastre's building beyond the DSM's coverage).")
@click.option("--footprint-ridge", default=None, metavar="FIELD",
              help="Attribute with the ridge height (same reference): a rectangle with a ridge gets a gabled roof, "
                   "ridge along its longer sides.")
@click.option("--footprint-heights", type=click.Choice(["above-ground", "absolute"]), default="above-ground",
              show_default=True,
              help="Reference of the footprint heights: above the ground at the footprint, or absolute in the DSM's "
                   "vertical reference.")
@click.option("--footprint-mode", type=click.Choice(["replace", "complete"]), default="replace", show_default=True,
              help="replace: the footprints are the buildings; complete: buildings extracted from the DSM, completed "
                   "by the footprints no extracted building overlaps (and replacing ones the DSM's border cut).")
@click.option("--refine-footprints", is_flag=True,
              help="Move the footprints' walls onto their feet as the obliques show them (a cadastre's outline is "
                   "decimetres off; default: kept as given).")
@click.option("--ortho", "ortho_path", default=None, type=click.Path(exists=True, dir_okay=False),
              help="RGB orthophoto (GeoTIFF / COG) to texture the roofs with; default: a flat roof colour.")
@click.option("--texel", type=float, default=None,
              help="Façade texel size in metres (default: the best image's footprint on each façade).")
@click.option("--max-images", type=int, default=3, show_default=True, help="Images blended into one façade at most.")
@click.option("--texture-format", type=click.Choice(["png", "jpeg"]), default="png", show_default=True,
              help="Format of the textures inside model.glb.")
@click.option("--no-refine", is_flag=True,
              help="Keep the walls where the DSM puts them (default: moved onto the roof outline seen in the images).")
@click.option("--no-feet", is_flag=True,
              help="Do not move walls onto their foot as the obliques show it (default: moved, after the roof outline).")
@click.option("--extend-dsm", "extend_dsm", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="DSM used beyond --dsm's surveyed area only (repeatable; e.g. `skyrig dsm --heads left` / `right`: "
                   "the obliques' own stereo coverage) for the buildings the obliques see there.")
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False), help="Output folder.")
def command(dsm_path, eo_path, eo_format, eo_crs, eo_geoid, eo_map_z_ground, camera_paths, images, heads, footprints,
            footprint_layer, footprint_eave, footprint_ridge, footprint_heights, footprint_mode, refine_footprints,
            ortho_path, texel, max_images, texture_format, no_refine, no_feet, extend_dsm, output) -> None:
    """Façade textures and a textured 3D model of the buildings of a DSM.

    Buildings come from the DSM (or --footprints: heights from the DSM, or from --footprint-eave where the DSM
    has none; --footprint-mode complete adds them to the DSM's buildings); every façade is textured from the
    oriented images that see it best (occlusions checked against the DSM); the model is written as binary glTF
    (model.glb, local ENU frame, y-up, its geographic origin recorded), OBJ + MTL + PNG, and a viewer page
    (viewer.html, opens from the file system), with buildings.gpkg and facades.json.
    """
    from skyrig.cli._common import load_cameras, load_eo
    from skyrig.cli.progress import tile_progress
    from skyrig.pipeline.facades import NoBuildingsError
    from skyrig.pipeline.products import make_facades

    eo = load_eo(eo_path, eo_format, eo_crs, eo_geoid, eo_map_z_ground)
    cameras = load_cameras(camera_paths)
    with tile_progress("façades") as progress:
        try:
            res = make_facades(eo, cameras, images, dsm_path, output, heads=heads, footprints=footprints,
                               ortho=ortho_path, texel=texel, max_images=max_images, texture_format=texture_format,
                               refine=not no_refine, feet=not no_feet, extend_dsm=extend_dsm,
                               inputs=[eo_path, *camera_paths], progress=progress,
                               footprint_layer=footprint_layer, footprint_eave=footprint_eave,
                               footprint_ridge=footprint_ridge, footprint_heights=footprint_heights,
                               footprint_mode=footprint_mode, refine_footprints=refine_footprints)
        except NoBuildingsError as exc:
            click.echo(f"error: {exc}", err=True)
            raise SystemExit(1) from None
    s = res.summary
    o = s["origin"]
    if s.get("footprints"):
        f = s["footprints"]
        click.echo(f"footprints ({f['mode']}): {f['used']} of {f['given']} used, {f['heights_from_attributes']} with "
                   f"heights from {f['eave_field']} ({f['height_reference']}), the others from the DSM")
    click.echo(f"{s['buildings']} buildings, {s['facades_seen']} of {s['facades']} façades textured "
               f"(median coverage {100 * (s['coverage_median'] or 0):.1f} %, texel {s['texel_median_m'] or 0:.3f} m), "
               f"{s['triangles']} triangles -> {res.outdir} (model origin {o['lat_deg']:.7f} {o['lon_deg']:.7f} "
               f"{o['h_m']:.2f} m; {s['vertical_reference']})")
