"""The lazy command table of ``skyrig``: every command listed without importing it, loaded on use,
a missing module a clean error, global flags anywhere. (Start-up speed is measured in bench/cli_startup.py.)"""

from __future__ import annotations

import importlib.util
import subprocess
import sys

import click
import pytest
from click.testing import CliRunner

from skyrig.cli import COMMANDS, CommandEntry, LazyGroup, hoist_global_flags, main

HEAVY = ("numpy", "scipy", "numba", "pyproj", "rasterio", "cv2", "pycolmap", "dask", "laspy", "rich", "skyrig.adjust",
         "skyrig.georef", "skyrig.io")

OLD_COMMANDS = {"georef", "world-to-image", "image-to-world", "convert", "match", "block", "adjust", "adjust-uav", "plan",
                "simulate", "lidar", "demo", "rig", "events"}


def _modules_after(args: list[str]) -> set[str]:
    code = ("import sys\nfrom skyrig.cli import main\n"
            f"try:\n    main({args!r})\nexcept SystemExit:\n    pass\n"
            "print('\\n'.join(sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    return set(out.split())


@pytest.mark.parametrize("args", [["--help"], ["--version"]])
def test_help_and_version_import_no_heavy_stack(args):
    mods = _modules_after(args)
    loaded = sorted(m for m in mods if any(m == h or m.startswith(h + ".") for h in HEAVY))
    assert loaded == []
    assert not any(m.startswith("skyrig.cli.") for m in mods)


def test_help_lists_every_command_including_dsm():
    res = CliRunner().invoke(main, ["--help"])
    assert res.exit_code == 0
    listed = {line.split()[0] for line in res.output.split("Commands:")[1].splitlines()
              if line.startswith("  ") and not line.startswith("   ")}
    assert OLD_COMMANDS | {"dsm"} <= listed
    assert "Dense matching: DSM (COG) and dense point cloud (LAZ) from oriented images" in " ".join(res.output.split())
    assert COMMANDS["dsm"].target == "skyrig.cli.dsm:command"


@pytest.mark.parametrize("name", sorted(OLD_COMMANDS))
def test_every_command_loads_and_has_its_name(name):
    module, _, attr = COMMANDS[name].target.partition(":")
    cmd = getattr(importlib.import_module(module), attr)
    assert isinstance(cmd, click.Command) and cmd.name == name
    res = CliRunner().invoke(main, [name, "--help"])
    assert res.exit_code == 0, res.output
    assert f"Usage: main {name}" in res.output or f"Usage: skyrig {name}" in res.output


def test_dsm_command_loads_or_fails_cleanly():
    res = CliRunner().invoke(main, ["dsm", "--help"])
    if importlib.util.find_spec("skyrig.cli.dsm") is None:
        assert res.exit_code == 1
        assert "command 'dsm' is not available" in res.output and "skyrig.cli.dsm" in res.output
        assert "Traceback" not in res.output
    else:
        assert res.exit_code == 0, res.output


def test_missing_module_and_missing_dependency_are_clean_errors():
    group = LazyGroup(name="t", lazy_commands={
        "ghost": CommandEntry("skyrig.cli.no_such_module:command", "a command whose module is absent"),
        "needs": CommandEntry("skyrig.cli.georef:no_such_attr", "a module without that command"),
    })
    runner = CliRunner()
    res = runner.invoke(group, ["ghost"])
    assert res.exit_code == 1 and "command 'ghost' is not available" in res.output
    assert isinstance(res.exception, SystemExit)
    res = runner.invoke(group, ["needs"])
    assert res.exit_code == 1 and "defines no click command 'no_such_attr'" in res.output
    help_res = runner.invoke(group, ["--help"])
    assert help_res.exit_code == 0 and "ghost" in help_res.output and "a command whose module is absent" in help_res.output


def test_hoist_global_flags():
    assert hoist_global_flags(["lidar", "georef", "--crs", "X", "-vv", "-q"]) == ["-vv", "-q", "lidar", "georef", "--crs", "X"]
    assert hoist_global_flags(["-v", "georef", "--verbose"]) == ["-v", "--verbose", "georef"]
    assert hoist_global_flags(["convert", "--", "-v"]) == ["convert", "--", "-v"]
    assert hoist_global_flags(["image-to-world", "--height", "-5"]) == ["image-to-world", "--height", "-5"]


@pytest.mark.parametrize("args, level", [
    (["-vv", "convert", "--help"], 10),
    (["convert", "--help", "-vv"], 10),
    (["convert", "-v", "--help"], 20),
    (["lidar", "georef", "--help", "--verbose"], 20),
    (["convert", "--help", "-q"], 40),
    (["convert", "--help"], 30),
])
def test_global_flags_anywhere(args, level):
    code = ("import logging\nfrom skyrig.cli import main\n"
            f"try:\n    main({args!r}, standalone_mode=False)\nexcept SystemExit:\n    pass\n"
            "print(logging.getLogger().level, logging.getLogger('numba').getEffectiveLevel())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    root, numba = out.split()[-2:]
    assert root == str(level)
    # skyrig's verbosity does not open numba's compiler debug log (thousands of lines per kernel)
    assert int(numba) == max(level, 30)
