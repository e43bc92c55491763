"""Issue 29, second pass: command options under generated bad values (hypothesis through click's CliRunner).

For georef, dsm, adjust-uav, terrain dtm and convert: every numeric option gets negative, NaN, infinite, huge
values, a number with a unit ("10cm") and an empty string; every choice an unknown one; every path that must
exist a path that does not; CRS options an unknown code and an empty text.  The rule: exit status 2, the
option's name in the message, no traceback, and the refusal comes before any work (each call is given inputs it
would otherwise start on, and must return within a second or two).

Bounded in ``make test``; ``pytest -m fuzz -s`` runs every generated case and prints the counts by command.
"""

from __future__ import annotations

import sys
import time
from collections import Counter
from pathlib import Path

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from click.testing import CliRunner  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
import test_bad_input_readers as base  # noqa: E402

from skyrig.cli import main  # noqa: E402

NUMBERS = ["-1", "nan", "inf", "-inf", "1e300", "10cm", ""]
#: Values that are right for an option (a ground height may be negative): not generated for it.
VALID = {"--eo-map-z-ground": {"-1"}, "--from-map-z-ground": {"-1"}}


def _inputs(d: Path) -> dict[str, str]:
    files = {"traj": base.TRAJ, "events": base.EVENTS, "rig": base.RIG, "eo": base.EO, "pts": base.PTS}
    out = {}
    for k, text in files.items():
        p = d / base.FILE_NAME[k]
        p.write_text(text)
        out[k] = str(p)
    (d / "images").mkdir(exist_ok=True)
    (d / "cloud.laz").write_bytes(b"")
    (d / "project").mkdir(exist_ok=True)
    out.update(images=str(d / "images"), cloud=str(d / "cloud.laz"), project=str(d / "project"))
    return out


def commands(f: dict[str, str], out: str) -> dict[str, list[str]]:
    """Each command with inputs it would start on (the bad option comes first on the line)."""
    return {
        "georef": ["georef", "--trajectory", f["traj"], "--events", f["events"], "--rig", f["rig"], "--crs",
                   "EPSG:25832", "-o", out],
        "dsm": ["dsm", "--eo", f["eo"], "--camera", f["rig"], "--images", f["images"], "-o", out],
        "adjust-uav": ["adjust-uav", f["project"], "--images", f["images"], "-o", out],
        "terrain dtm": ["terrain", "dtm", f["cloud"], "-o", out],
        "convert": ["convert", f["eo"], out, "--to-format", "ign-opk"],
    }


def _command(path: str):
    import click

    ctx = click.Context(main)
    cmd = main
    for p in path.split():
        cmd = cmd.get_command(ctx, p)
    return cmd


def bad_values(cmd_path: str) -> list[tuple[str, str]]:
    """(option, bad value) for every option of the command that takes a value."""
    import click

    out = []
    for prm in _command(cmd_path).params:
        if not isinstance(prm, click.Option) or prm.is_flag:
            continue
        name = max(prm.opts, key=len)
        t = prm.type
        if isinstance(t, (click.types.FloatParamType, click.types.IntParamType)):
            vals = [v for v in NUMBERS if v not in VALID.get(name, set())]
        elif isinstance(t, click.Choice):
            vals = ["bogus"]
        elif isinstance(t, click.Path):
            vals = ["/nonexistent/skyrig-fuzz"] if t.exists else []
        elif "crs" in name:
            vals = ["EPSG:999999", ""]
        elif "sigma" in name:
            vals = ["-1", "nan", "a,b", ""]
        elif "geoid" in name:
            vals = ["/nonexistent/geoid.tif"]
        else:
            vals = []
        out += [(name, v) for v in vals]
    return out


CASES = [(c, o, v) for c in ("georef", "dsm", "adjust-uav", "terrain dtm", "convert") for o, v in bad_values(c)]


def check_option(tmp: Path, cmd: str, option: str, value: str) -> None:
    f = _inputs(tmp)
    args = commands(f, str(tmp / "out"))[cmd]
    k = len(cmd.split())
    args = args[:k] + [option, value] + args[k:]
    if option in args[k + 2:]:  # the base line sets it too: replace that value
        j = args.index(option, k + 2)
        del args[j:j + 2]
    t0 = time.perf_counter()
    res = CliRunner().invoke(main, args)
    took = time.perf_counter() - t0
    text = res.output
    assert res.exit_code == 2, (cmd, option, value, res.exit_code, text[-800:], res.exception)
    assert option in text or option.lstrip("-") in text, (cmd, option, value, text[-800:])
    assert "Traceback" not in text, text
    assert took < 5.0, (cmd, option, value, f"{took:.1f} s before refusing")


SHORT = settings(max_examples=12, deadline=None, derandomize=True,
                 suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def test_bad_option_values_refused_before_work(tmp_path):
    @SHORT
    @given(case=st.sampled_from(CASES))
    def check(case: tuple[str, str, str]) -> None:
        check_option(tmp_path, *case)

    check()


@pytest.mark.slow
@pytest.mark.fuzz
@pytest.mark.parametrize("case", CASES, ids=[f"{c}{o}={v}" for c, o, v in CASES])
def test_every_bad_option_value(tmp_path, case):
    check_option(tmp_path, *case)
