"""Command-line interface: thin shims over library functions, one module per subcommand."""

from __future__ import annotations

import logging
import os
import sys

# COLMAP (pycolmap) logs every feature extractor it creates through glog at INFO level; keep warnings and errors.
os.environ.setdefault("GLOG_minloglevel", "1")

import click

from skyrig import __version__
from skyrig.errors import SkyrigError


class _Group(click.Group):
    def invoke(self, ctx: click.Context):  # type: ignore[override]
        try:
            return super().invoke(ctx)
        except SkyrigError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(2)


@click.group(cls=_Group)
@click.version_option(__version__, prog_name="skyrig")
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug).")
def main(verbose: int) -> None:
    """skyrig: aerial and UAV photogrammetry for multi-head camera rigs with GNSS/IMU."""
    level = logging.WARNING - 10 * min(verbose, 2)
    try:
        from rich.logging import RichHandler

        handler: logging.Handler = RichHandler(show_path=False)
    except ImportError:  # pragma: no cover
        handler = logging.StreamHandler()
    logging.basicConfig(level=level, handlers=[handler], format="%(message)s")


def _register() -> None:
    from skyrig.cli import (adjust, block, convert, demo, georef, image_to_world, lidar, match, plan, simulate, uav,
                            world_to_image)

    for mod in (georef, world_to_image, image_to_world, convert, match, block, adjust, uav, plan, simulate, lidar, demo):
        main.add_command(mod.command)


_register()
