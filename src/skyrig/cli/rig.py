"""``skyrig rig --preset NAME -o rig.yaml``: a rig file (docs/formats/rig_file.md) from a preset of a published
system (:mod:`skyrig.rig.presets`), to edit with one's own lever arms, boresights and calibrated cameras.

``--list`` prints the presets.  The presets' lever arms are zero (none is published): the command says so.
Written atomically.
"""

from __future__ import annotations

import click

__all__ = ["command"]


@click.command("rig")
@click.option("--preset", "name", default=None,
              help="Preset name (midas, midas-50, dlr-3k, macs-tumblecam, uav-single; see --list).")
@click.option("--list", "list_presets", is_flag=True, help="List the presets and exit.")
@click.option("-o", "--output", type=click.Path(dir_okay=False), default=None, help="Rig file (YAML) to write.")
def command(name: str | None, list_presets: bool, output: str | None) -> None:
    """Write a rig file from a preset of a published system (edit its lever arms and cameras)."""
    from skyrig.rig.presets import PRESETS, UnknownPresetError, preset

    if list_presets:
        for key in PRESETS:
            rig = preset(key)
            heads = ", ".join(f"{h.name} ({h.camera.focal_mm:g} mm, {h.camera.width} x {h.camera.height} px)"
                              for h in rig)
            click.echo(f"{key}: {heads}")
        return
    if name is None:
        raise click.UsageError("give --preset NAME (or --list)")
    if output is None:
        raise click.UsageError("missing option '-o' / '--output'")
    try:
        rig = preset(name)
    except UnknownPresetError as exc:
        raise click.BadParameter(str(exc), param_hint="--preset") from None
    from skyrig.io.rig_file import write_rig

    write_rig(rig, output)
    click.echo(f"wrote {output}: rig {rig.name!r} with {len(rig)} heads ({', '.join(h.name for h in rig)}); "
               "lever arms are zero in the preset (none is published): enter your surveyed values, and your "
               "calibrated cameras and boresights")
