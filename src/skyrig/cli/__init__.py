"""Command-line interface: thin shims over library functions, one module per subcommand.

Commands are loaded lazily: :data:`COMMANDS` maps each command name to ``"module:attribute"`` and a one-line
help text, and a command's module (with its numpy / scipy / numba stack) is imported only when that command
runs or its own ``--help`` is asked, so that ``skyrig --help`` and ``skyrig --version`` start at once.
Adding a subcommand = one module with a click command + one line in :data:`COMMANDS`.

Global flags (``-v``/``--verbose``, ``-q``/``--quiet``) may stand anywhere on the line, before or after the
subcommand.
"""

from __future__ import annotations

import importlib
import logging
import os
import re
import signal
import sys
from typing import NamedTuple

# COLMAP (pycolmap) logs every feature extractor it creates through glog at INFO level; keep warnings and errors.
os.environ.setdefault("GLOG_minloglevel", "1")

import click

from skyrig import __version__
from skyrig.errors import SkyrigError, StopSignal, show_warnings_in_words


class CommandEntry(NamedTuple):
    """Where a subcommand lives and what ``skyrig --help`` says about it."""

    target: str  # "module:attribute" of the click command
    help: str  # one line, shown in the command list without importing the module


COMMANDS: dict[str, CommandEntry] = {
    "georef": CommandEntry("skyrig.cli.georef:command",
                           "Exterior orientation of every image from GNSS/IMU, lever arms, boresights and actuator angles."),
    "world-to-image": CommandEntry("skyrig.cli.world_to_image:command",
                                   "Project ground points into every image that sees them (or into measured pairs)."),
    "image-to-world": CommandEntry("skyrig.cli.image_to_world:command",
                                   "Ground coordinates of measured image points (DEM, height or intersection)."),
    "convert": CommandEntry("skyrig.cli.convert:command", "Convert an exterior-orientation file SRC into the file -o/--output."),
    "match": CommandEntry("skyrig.cli.match:command",
                          "Tie points for the images of PROJECT (resumable: rerun to continue an interrupted run)."),
    "block": CommandEntry("skyrig.cli.block:command",
                          "Assemble a block file from a trajectory + events + rig (or EO + cameras), measurements and control."),
    "adjust": CommandEntry("skyrig.cli.adjust:command",
                           "Adjust a block file and write the adjusted EO, points and report."),
    "calibrate": CommandEntry("skyrig.cli.calibrate:command", "Calibration recipes (camera: test-field calibration; lidar-camera: laser and images in one adjustment) -> calibrated rig file + report."),
    "adjust-uav": CommandEntry("skyrig.cli.uav:command",
                               "GNSS-supported adjustment of the UAV images of PROJECT (tie points from `skyrig match`)."),
    "dsm": CommandEntry("skyrig.cli.dsm:command",
                        "Dense matching: DSM (COG) and dense point cloud (LAZ) from oriented images"),
    "ortho": CommandEntry("skyrig.cli.ortho:command",
                          "True orthomosaic (COG) of oriented images on a DSM: occlusion, seamlines, balance, blend."),
    "terrain": CommandEntry("skyrig.cli.terrain:command",
                            "Terrain products: ground classification, DTM + nDSM, contours, cut/fill volumes."),
    "facades": CommandEntry("skyrig.cli.facades:command", "Façade textures and a textured 3D model (GLB, OBJ, viewer) of a DSM's buildings."),
    "plane-mosaic": CommandEntry("skyrig.cli.plane_mosaic:command",
                                 "Oriented images projected onto one plane and the offsets across its seams (Fig. 9 check)."),
    "rig": CommandEntry("skyrig.cli.rig:command",
                        "Write a rig file from a preset of a published system (midas, dlr-3k, ...) to edit."),
    "events": CommandEntry("skyrig.cli.events:command",
                           "Camera events CSV from a trigger log and one image folder per rig head."),
    "plan": CommandEntry("skyrig.cli.plan:command",
                         "Plan a flight for a rig over an area; write stations, footprints and strips."),
    "simulate": CommandEntry("skyrig.cli.simulate:command",
                             "Simulate SCENARIO (tumblecam, midas, 3k, southeast, uav-bridge-lidar) into the folder -o/--output."),
    "lidar": CommandEntry("skyrig.cli.lidar:command",
                          "Laser scanning: georeference raw scans, register and compare point clouds, adjust strips."),
    "transfer": CommandEntry("skyrig.cli.transfer:command",
                             "Oblique (tumbling-head) orientations from adjusted nadir orientations through the calibrated mounting."),
    "import": CommandEntry("skyrig.cli.exchange:import_command",
                           "Bring another program's project (COLMAP, OpenSfM, Metashape XML) in as a block file."),
    "export": CommandEntry("skyrig.cli.exchange:export_command",
                           "Write a block file in another program's format (COLMAP, OpenSfM, Metashape, MicMac)."),
    "export-gcp": CommandEntry("skyrig.cli.exchange:export_gcp_command",
                               "Write ground control / check points and their image marks as Pix4D GCP and marks files."),
    "init": CommandEntry("skyrig.cli.run:init_command", "Write a commented project.yaml for a flight folder (skyrig run runs it)."),
    "run": CommandEntry("skyrig.cli.run:run_command", "Run the stages of a project.yaml, each into its own folder (resumable)."),
    "measure": CommandEntry("skyrig.cli.measure:command",
                            "Measure control and check points in the images in a local web page (or --auto)."),
    "check": CommandEntry("skyrig.cli.check:command",
                          "Validate a project.yaml and every input it names without running a stage; name every problem."),
    "paper": CommandEntry("skyrig.cli.paper:command",
                          "Reproduce the tables and figures of the papers (000-004) into one folder with an index page."),
    "live": CommandEntry("skyrig.cli.live:command",
                         "Near-real-time DG, ortho and DSM tiles and online boresight of a flight as it is recorded."),
    "demo": CommandEntry("skyrig.cli.demo:command",
                         "Simulate a small MIDAS penta-rig flight, georeference it and check ground <-> image end to end."),
}

# Global flags that may also follow the subcommand: -v, -vv, -q, -vq..., --verbose, --quiet.
_GLOBAL_FLAG = re.compile(r"^(-[vq]+|--verbose|--quiet)$")


def hoist_global_flags(args: list[str]) -> list[str]:
    """Move the global flags found anywhere on the line (up to a ``--``) to the front.

    No subcommand defines ``-v`` or ``-q`` of its own, so these tokens always mean the global flags.

    >>> hoist_global_flags(["georef", "--crs", "EPSG:25832", "-v", "-o", "eo.csv"])
    ['-v', 'georef', '--crs', 'EPSG:25832', '-o', 'eo.csv']
    """
    args = list(args)
    end = args.index("--") if "--" in args else len(args)
    flags = [a for a in args[:end] if _GLOBAL_FLAG.match(a)]
    rest = [a for a in args[:end] if not _GLOBAL_FLAG.match(a)]
    return flags + rest + args[end:]


class LazyGroup(click.Group):
    """A click group whose subcommands are imported on first use (see :data:`COMMANDS`)."""

    def __init__(self, *args, lazy_commands: dict[str, CommandEntry] | None = None, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.lazy_commands = dict(lazy_commands or {})

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(super().list_commands(ctx)) | set(self.lazy_commands))

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in self.commands:
            return self.commands[cmd_name]
        entry = self.lazy_commands.get(cmd_name)
        if entry is None:
            return None
        cmd = _load(cmd_name, entry.target)
        self.commands[cmd_name] = cmd  # loaded once per process
        return cmd

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The command list from the table's help texts, without importing any command module."""
        rows = []
        for name in self.list_commands(ctx):
            if name in self.lazy_commands and name not in self.commands:
                rows.append((name, self.lazy_commands[name].help))
            else:
                cmd = self.commands.get(name)
                if cmd is not None and not cmd.hidden:
                    rows.append((name, cmd.get_short_help_str(formatter.width)))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        if ctx.parent is None:
            args = hoist_global_flags(args)
            ctx.meta["skyrig.args"] = list(args)
        return super().parse_args(ctx, args)

    def invoke(self, ctx: click.Context):  # type: ignore[override]
        top = ctx.parent is None
        previous = _stop_on_sigterm() if top else None
        try:
            return super().invoke(ctx)
        except SkyrigError as exc:
            if getattr(exc, "option", "") is None and hasattr(exc, "with_option"):  # an output path: name its option
                found = option_for_path(ctx.meta.get("skyrig.args", []), exc.path)  # type: ignore[attr-defined]
                if found is not None:
                    exc = exc.with_option(*found)  # type: ignore[attr-defined]
            click.echo(f"error: {exc}", err=True)
            sys.exit(2)
        except KeyboardInterrupt as exc:
            if not top:
                raise
            signum = exc.signum if isinstance(exc, StopSignal) else signal.SIGINT
            name = "SIGINT (Ctrl-C)" if signum == signal.SIGINT else signal.Signals(signum).name
            stage = RUNNING[0]
            what = f"stage {stage}" if stage else f"skyrig {ctx.invoked_subcommand or ''}".strip()
            click.echo(f"stopped by {name} during {what}: it published nothing; the last complete outputs are "
                       "intact (files and stage folders are published whole or not at all); rerun to resume",
                       err=True)
            sys.exit(128 + int(signum))
        finally:
            if top:
                RUNNING[0] = None
                if previous is not None:
                    signal.signal(signal.SIGTERM, previous)


#: The stage a command is running (``skyrig run`` sets it), for the message when a signal stops it.
RUNNING: list[str | None] = [None]


def _stop_on_sigterm():  # type: ignore[no-untyped-def]
    """SIGTERM raises :class:`StopSignal` (a KeyboardInterrupt: every atomic writer and stage folder cleans up as
    for Ctrl-C); returns the previous handler (None outside the main thread)."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        return None

    def handler(signum, frame):  # type: ignore[no-untyped-def]
        raise StopSignal(signum)

    return signal.signal(signal.SIGTERM, handler)


def option_for_path(args: list[str], path: str) -> tuple[str, str] | None:
    """The option (or "argument") of the command line whose value is ``path`` or a folder containing it.

    >>> option_for_path(["georef", "--crs", "EPSG:25832", "-o", "out/eo.csv"], "out/eo.csv")
    ('-o', 'out/eo.csv')
    >>> option_for_path(["adjust-uav", "P", "--out=res"], "res/eo.csv")
    ('--out', 'res')
    """
    target = os.path.abspath(path)

    def holds(value: str) -> bool:
        v = os.path.abspath(value)
        return target == v or target.startswith(v.rstrip(os.sep) + os.sep)

    best: tuple[str, str] | None = None
    for i, tok in enumerate(args):
        if tok == "--":
            break
        if tok.startswith("-") and "=" in tok:
            opt, value = tok.split("=", 1)
        elif tok.startswith("-") and i + 1 < len(args):
            opt, value = tok, args[i + 1]
        elif not tok.startswith("-") and (i == 0 or not args[i - 1].startswith("-")):
            opt, value = "argument", tok
        else:
            continue
        if value and holds(value) and (best is None or len(value) > len(best[1])):
            best = (opt, value)
    return best


def _load(name: str, target: str) -> click.Command:
    """Import ``module:attribute`` for command ``name``; a missing module is a clean error, not a traceback."""
    module_name, _, attr = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        missing = exc.name or str(exc)
        if missing == module_name or module_name.startswith(missing + "."):
            raise click.ClickException(
                f"command '{name}' is not available in this installation (module {module_name} is missing)"
            ) from None
        raise click.ClickException(
            f"command '{name}' needs the Python package '{missing.split('.')[0]}', which is not installed"
        ) from None
    cmd = getattr(module, attr, None)
    if not isinstance(cmd, click.Command):
        raise click.ClickException(f"command '{name}': {module_name} defines no click command '{attr}'")
    return cmd


def _configure_logging(verbose: int, quiet: int) -> None:
    level = min(max(logging.WARNING - 10 * verbose + 10 * quiet, logging.DEBUG), logging.CRITICAL)
    try:
        from rich.logging import RichHandler

        handler: logging.Handler = RichHandler(show_path=False)
    except ImportError:  # pragma: no cover
        handler = logging.StreamHandler()
    logging.basicConfig(level=level, handlers=[handler], format="%(message)s")
    # -v / -vv are for skyrig's own messages: libraries that log their internals at INFO / DEBUG (numba's bytecode
    # dumps run to thousands of lines per compiled kernel, exifread lists every tag) stay at warnings
    for name in _CHATTY_LIBRARIES:
        logging.getLogger(name).setLevel(max(level, logging.WARNING))


#: third-party loggers kept at WARNING under -v / -vv
_CHATTY_LIBRARIES = ("numba", "exifread", "matplotlib", "PIL", "fiona", "rasterio", "urllib3", "asyncio")


@click.group(cls=LazyGroup, lazy_commands=COMMANDS)
@click.version_option(__version__, prog_name="skyrig")
@click.option("-v", "--verbose", count=True,
              help="More log output (-v info, -vv debug); anywhere on the line.")
@click.option("-q", "--quiet", count=True, help="Less log output (-q errors only); anywhere on the line.")
def main(verbose: int, quiet: int) -> None:
    """skyrig: aerial and UAV photogrammetry for multi-head camera rigs with GNSS/IMU."""
    _configure_logging(verbose, quiet)
    show_warnings_in_words()  # plausibility warnings as "warning: ..." lines (skyrig.io.plausibility)
