"""``skyrig simulate SCENARIO -o OUTDIR``: write a simulated project folder with its truth.

``-o/--output`` names the folder, as for every command whose output is a folder (docs/cli.md); the older
positional form ``skyrig simulate SCENARIO OUTDIR`` still works and warns that it is deprecated."""

from __future__ import annotations

import click

from skyrig.simulate.scenarios import SCENARIOS


@click.command("simulate")
@click.argument("scenario", type=click.Choice([*SCENARIOS, "midas-demo", "uav-bridge-camera"], case_sensitive=False))
@click.argument("outdir", required=False, default=None, metavar="", type=click.Path(file_okay=False))
@click.option("-o", "--output", type=click.Path(file_okay=False), default=None,
              help="Project folder to write (the positional OUTDIR of older versions is deprecated).")
@click.option("--size", type=click.Choice(["ci", "full"]), default="ci", show_default=True, help="CI size (small) or the papers' full size.")
@click.option("--seed", type=int, default=1, show_default=True, help="Random seed (the project is a deterministic function of it).")
@click.option("--workers", type=int, default=None, help="Processes rendering images (default: all cores).")
@click.option("--no-images", is_flag=True, help="Write everything but the images.")
def command(scenario: str, outdir: str | None, output: str | None, size: str, seed: int, workers: int | None, no_images: bool) -> None:
    """Simulate SCENARIO (tumblecam, midas, 3k, southeast, uav-bridge-lidar, uav-bridge-camera) into the folder -o/--output."""
    from skyrig.cli._common import output_or_positional
    from skyrig.pipeline.simulate import simulate_scenario

    outdir = output_or_positional(output, outdir, "OUTDIR")

    info = simulate_scenario(scenario, outdir, size=size, seed=seed, workers=workers, images=not no_images)
    if info.n_images == 0 and info.summary:
        click.echo(f"{scenario} ({size}, seed {seed}): {info.summary}, total {info.total_s:.1f} s -> {info.outdir}")
        return
    extra = f" ({info.summary})" if info.summary else ""
    click.echo(f"{scenario} ({size}, seed {seed}): {info.n_images} images, {info.megapixels:.1f} MP rendered in "
               f"{info.render_s:.1f} s, total {info.total_s:.1f} s{extra} -> {info.outdir}")
