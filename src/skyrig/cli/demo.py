"""``skyrig demo``: direct demoerencing (placeholder until rig/trajectory land)."""
import click


@click.command("demo")
def command() -> None:
    """Exterior orientation of every image from trajectory + events + rig."""
    raise click.UsageError("not yet available")
