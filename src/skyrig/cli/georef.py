"""``skyrig georef``: direct georeferencing (placeholder until rig/trajectory land)."""
import click


@click.command("georef")
def command() -> None:
    """Exterior orientation of every image from trajectory + events + rig."""
    raise click.UsageError("not yet available")
