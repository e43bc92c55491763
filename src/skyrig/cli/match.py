"""``skyrig match PROJECT``: tie points for a folder of images, resumable and parallel (Dask).

PROJECT is a folder; images are taken from ``PROJECT/images`` if it exists, else from PROJECT itself, or from
one or more ``--images`` folders (e.g. one per rig head).  Results go to ``PROJECT/match`` (or ``-o/--output``):
``features/`` and ``matches/`` (resumable store), ``tie_points.csv`` (point,image,column,row; skyrig pixels),
``report.json`` and ``coverage.png``.  The work is :func:`skyrig.pipeline.match.match_images` (re-exported here).
"""

from __future__ import annotations

from pathlib import Path

import click

from skyrig.cli._types import GROUND_HEIGHT_M

from skyrig.errors import SkyrigError
from skyrig.match.features import FeatureConfig
from skyrig.pipeline.match import (  # noqa: F401  (the names this module always had)
    MatchRunResult, _approximate_orientations, _Call, _extract_one, _match_one, _run_dask, collect_images,
    match_images,
)


def _match_cmd_class() -> type[click.Command]:
    from skyrig.cli._common import with_old_spellings

    return with_old_spellings({"--out": "--output"})


MATCH_RESULTS = ("tie_points.csv", "report.json", "coverage.png")


def _is_stale_temp(rel: Path) -> bool:
    """A temporary file that a killed run left: the store's ``*.tmp.npz`` / ``config.tmp``, an atomic write's
    ``.NAME.*.tmp`` (a finished run has renamed all of its own)."""
    return rel.name.endswith((".tmp.npz", ".tmp"))


def write_match_manifest(out: Path, inputs: list[Path], options: dict) -> Path:
    """Write ``out/manifest.json`` (last, atomically): inputs, options, version and every output file with its
    size and SHA-256 - the results (:data:`MATCH_RESULTS` and their side-cars) and the resumable store
    (``config.json``, ``features/*.npz``, ``matches/*.npz``), so that :func:`skyrig.io.stage.verify_folder`
    checks the whole folder.  Temporary files a killed earlier run left in the store are removed first.  A run
    removes the manifest at its start, so a folder without one is an unfinished run."""
    import json
    import time

    from skyrig import __version__
    from skyrig.io._text import atomic_write
    from skyrig.io.stage import MANIFEST, describe_inputs, sha256_file

    files = []
    for f in sorted(out.rglob("*")):
        rel = f.relative_to(out)
        if not f.is_file() or rel.as_posix() == MANIFEST:
            continue
        if _is_stale_temp(rel):
            f.unlink()
            continue
        files.append({"path": rel.as_posix(), "size": f.stat().st_size, "sha256": sha256_file(f)})
    manifest = {"format": "skyrig-manifest", "version": 1, "stage": "match", "software": f"skyrig {__version__}",
                "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "inputs": describe_inputs(list(inputs)),
                "options": options, "files": files,
                "store": {"config.json": "settings of the stored results", "features/": "resumable feature store",
                          "matches/": "resumable match store"}}
    with atomic_write(out / MANIFEST) as fh:
        fh.write(json.dumps(manifest, indent=1, default=str) + "\n")
    return out / MANIFEST


@click.command("match", cls=_match_cmd_class())
@click.argument("project", type=click.Path(file_okay=False))
@click.option("--images", "image_dirs", multiple=True, type=click.Path(exists=True, file_okay=False),
              help="Image folder(s) (default PROJECT/images or PROJECT); repeat for one folder per head.")
@click.option("-o", "--output", "--out", "out", type=click.Path(file_okay=False),
              help="Output folder (default PROJECT/match); manifest.json written last (--out: deprecated spelling).")
@click.option("--pairs", "pair_mode", type=click.Choice(["auto", "guided", "gps", "exhaustive"]), default="auto",
              show_default=True)
@click.option("--method", type=click.Choice(["pycolmap", "opencv"]), default="pycolmap", show_default=True,
              help="SIFT implementation.")
@click.option("--max-size", type=int, default=1600, show_default=True, help="Detect on images downscaled to this.")
@click.option("--max-features", type=int, default=8000, show_default=True)
@click.option("--min-overlap", type=float, default=0.1, show_default=True, help="Guided pairs: footprint overlap.")
@click.option("--max-pairs-per-image", type=click.IntRange(min=0), default=12, show_default=True,
              help="Guided pairs: per-image budget (strongest overlaps; the block kept connected with its head and "
                   "strip links); 0 = every overlapping pair.")
@click.option("--neighbours", type=int, default=8, show_default=True, help="GPS pairs: nearest images.")
@click.option("--max-heading-diff", type=float, default=None,
              help="GPS pairs: drop pairs whose EXIF/XMP headings differ more (degrees; default: no filter).")
@click.option("--eo", "eo_path", type=click.Path(exists=True, dir_okay=False),
              help="Approximate EO file (skyrig EO CSV, IGN .OPK, ODM geo.txt).")
@click.option("--eo-format", type=click.Choice(["ign-opk", "odm-geo", "skyrig-csv"]), default=None,
              help="EO file format (default: from the file name).")
@click.option("--eo-crs", default=None, help="CRS of the EO file when it does not say (e.g. EPSG:2154 for IGN .OPK).")
@click.option("--eo-geoid", default=None, help="Geoid grid (path or PROJ name) when EO heights are orthometric.")
@click.option("--eo-map-z-ground", type=float, default=None,
              help="Undo the linear alteration of projection-centre heights (map-coordinate adjustment) with this "
                   "mean ground height (m).")
@click.option("--camera", "camera_paths", multiple=True, type=click.Path(exists=True, dir_okay=False))
@click.option("--terrain-height", type=GROUND_HEIGHT_M, help="Mean terrain height in the EO frame (guided pairs).")
@click.option("--thin", "thin_per_cell", type=int, default=0, show_default=True,
              help="Keep this many tracks per 8x8 image cell (0 = all).")
@click.option("--scheduler", default="threads", show_default=True,
              help="threads (Dask thread pool), processes (local Dask worker processes), sync (this process), or "
                   "the address of a dask.distributed scheduler (tcp://host:8786; workers must see the output "
                   "folder under the same path).")
@click.option("-j", "--workers", type=int, default=2, show_default=True)
@click.option("--overwrite", is_flag=True, help="Discard stored features and matches.")
@click.option("--lsm", is_flag=True, help="Refine tie points by least-squares matching (full resolution).")
def command(project: str, image_dirs: tuple[str, ...], out: str | None, pair_mode: str, method: str, max_size: int,
            max_features: int, min_overlap: float, neighbours: int, max_heading_diff: float | None, eo_path: str | None,
            eo_format: str | None, eo_crs: str | None, eo_geoid: str | None, eo_map_z_ground: float | None,
            camera_paths: tuple[str, ...],
            terrain_height: float | None, thin_per_cell: int, scheduler: str, workers: int, overwrite: bool,
            lsm: bool, max_pairs_per_image: int) -> None:
    """Tie points for the images of PROJECT (resumable: rerun to continue an interrupted run)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    proj = Path(project)
    folders = list(image_dirs) or [proj / "images" if (proj / "images").is_dir() else proj]
    eo = cameras = None
    if eo_path:
        from skyrig.cli._common import load_cameras, load_eo

        eo = load_eo(eo_path, eo_format, eo_crs, eo_geoid, eo_map_z_ground)
        cameras = load_cameras(camera_paths)
    out_dir = Path(out) if out else proj / "match"
    from skyrig.io.stage import MANIFEST

    if (out_dir / MANIFEST).is_file():  # this run's results replace the last: until its manifest, none
        (out_dir / MANIFEST).unlink()
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn()) as bar:
        ids: dict[str, object] = {}

        def progress(stage: str, done: int, total: int) -> None:
            if stage not in ids:
                ids[stage] = bar.add_task(stage, total=total)
            bar.update(ids[stage], completed=done)  # type: ignore[arg-type]

        try:
            r = match_images(folders, out_dir,
                             FeatureConfig(method=method, max_size=max_size, max_features=max_features),  # type: ignore[arg-type]
                             None, pair_mode, eo, cameras, terrain_height, min_overlap, neighbours, scheduler,
                             workers, thin_per_cell, overwrite, progress, lsm, max_heading_diff,
                             max_pairs_per_image=max_pairs_per_image)
        except SkyrigError:
            raise
    rep = r.report
    click.echo(f"{len(r.names)} images ({len(r.skipped)} skipped), {rep['pairs_matched']}/{rep['pairs_tried']} "
               f"pairs matched ({r.pair_mode}), {rep['n_tracks']} tie points, {rep['n_observations']} observations, "
               f"mean multiplicity {rep['mean_multiplicity']:.2f}")
    if rep["images_without_ties"]:
        click.echo(f"images without tie points: {', '.join(rep['images_without_ties'])}")
    from skyrig.io.image_read import list_images

    inputs = [Path(x) for f in folders for x in list_images(f)] + [Path(p) for p in (eo_path, *camera_paths) if p]
    options = {"project": str(proj), "images": [str(f) for f in folders], "output": str(out_dir), "pairs": pair_mode,
               "method": method, "max_size": max_size, "max_features": max_features, "min_overlap": min_overlap,
               "max_pairs_per_image": max_pairs_per_image, "neighbours": neighbours,
               "max_heading_diff": max_heading_diff, "eo": eo_path,
               "camera": list(camera_paths), "terrain_height": terrain_height, "thin": thin_per_cell, "lsm": lsm}
    write_match_manifest(out_dir, inputs, options)
