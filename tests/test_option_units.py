"""Issue 29: options given in a wrong but plausible-looking unit (``--gsd 5`` meaning centimetres, ``--height
120000`` meaning millimetres, a sigma in millimetres, an IMU sigma in arc seconds) are refused or warned about
while the command line is parsed, in one line naming the option, the value with its unit, the expected range and
the unit in which the number would be usual, with the value it would have there.

The independent answer is the unit conversion itself (the value the number has in the unit meant: 5 cm is
0.05 m) and the ranges of the things measured (a GSD of 5 m is a satellite's, not an aerial camera's)."""

from __future__ import annotations

import subprocess
import sys

import pytest
from click.testing import CliRunner

from skyrig.cli import main
from skyrig.errors import PlausibilityWarning


def _env() -> dict[str, str]:
    import os
    from pathlib import Path

    src = str(Path(__file__).resolve().parents[1] / "src")
    return {**os.environ, "PYTHONPATH": src + os.pathsep + os.environ.get("PYTHONPATH", "")}


def _invoke(*args: str):
    r = CliRunner().invoke(main, list(args))
    assert "Traceback" not in r.output, r.output
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    return r


@pytest.mark.parametrize("args, option, words", [
    (["adjust", "--gsd", "5", "nowhere.json"], "--gsd",
     "5 metres is not plausible as a ground sampling distance (expected 0.0001 to 2 metres); millimetres "
     "(0.005 metres) or centimetres (0.05 metres)?"),
    (["plan", "--height", "120000"], "--height",
     "120000 metres is not plausible as a flying height above ground (expected 1 to 20000 metres); millimetres "
     "(120 metres) or centimetres (1200 metres)?"),
    (["plan", "--gsd", "0.00003"], "--gsd", "not plausible as a ground sampling distance"),
    (["image-to-world", "--height", "45000"], "--height",
     "45000 metres is not plausible as a ground height (expected 0 to 9000 metres); millimetres (45 metres) or "
     "centimetres (450 metres)?"),
    (["match", "--terrain-height", "-12000"], "--terrain-height", "not plausible as a ground height"),
    (["block", "--gnss-sigma", "50,50,800"], "--gnss-sigma",
     "800 metres is not plausible as a GNSS position's standard deviation (expected 0 to 100 metres); "
     "millimetres (0.8 metres) or centimetres (8 metres)?"),
    (["block", "--control-sigma", "300"], "--control-sigma", "millimetres (0.3 metres)?"),
    (["block", "--image-sigma-px", "350"], "--image-sigma-px", "350 pixels is not plausible"),
    (["calibrate", "uncalibrated-gnss-imu", "--imu-sigma-deg", "180"], "--imu-sigma-deg",
     "180 degrees is not plausible as an attitude's standard deviation"),
    (["measure", "--eo-sigma", "150"], "--eo-sigma", "millimetres (0.15 metres)"),
    (["import", "colmap", "--sigma-px", "1000", "x", "-o", "y"], "--sigma-px", "not plausible"),
], ids=lambda v: v if isinstance(v, str) and v.startswith("--") else None)
def test_a_number_in_the_wrong_unit_is_refused_naming_the_option(args, option, words):
    r = _invoke(*args)
    assert r.exit_code == 2, r.output
    line = next(ln for ln in r.output.splitlines() if ln.startswith("Error:"))
    assert option in line and words in line, r.output


@pytest.mark.parametrize("args, option, words", [
    (["block", "--control-sigma", "20,20,30"], "--control-sigma",
     "20 metres is unusual as a ground point's standard deviation (expected 0 to 2 metres); millimetres "
     "(0.02 metres) or centimetres (0.2 metres)?"),
    (["block", "--imu-sigma-deg", "18,18,36"], "--imu-sigma-deg",
     "18 degrees is unusual as an attitude's standard deviation (expected 0 to 1 degrees); arc seconds "
     "(0.005 degrees) or milligon (0.0162 degrees)?"),
    (["block", "--gnss-sigma", "50"], "--gnss-sigma", "centimetres (0.5 metres)?"),
    (["calibrate", "uncalibrated-gnss-imu", "--image-sigma-um", "0.004"], "--image-sigma-um",
     "0.004 micrometres is unusual as an image measurement's standard deviation (expected 0.05 to 50 "
     "micrometres); millimetres (4 micrometres)?"),
    (["plan", "--gsd", "1.5"], "--gsd", "1.5 metres is unusual as a ground sampling distance"),
])
def test_an_unusual_number_is_warned_about_in_words(args, option, words):
    """Said as ``warning: OPTION: words`` (the CLI's display of a PlausibilityWarning); the command then stops on
    its missing inputs, as it would without the option."""
    r = _invoke(*args)
    said = [ln for ln in r.output.splitlines() if ln.startswith("warning:")]
    assert any(s.startswith(f"warning: {option}: ") and words in s for s in said), r.output


@pytest.mark.parametrize("option, value", [
    ("--gsd", "0.05"), ("--gsd", "0.002"), ("--height", "120"), ("--height", "3500"), ("--ground-height", "-400"),
    ("--ground-height", "4800")])
def test_plausible_values_pass_silently(option, value):
    """Usual values in the right unit: neither refused nor warned about (a plan needs its rig and area: it then
    stops on those, with no word about the option)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", PlausibilityWarning)
        r = _invoke("plan", option, value)
    assert option not in r.output, r.output


def test_the_command_line_shows_the_warning_as_one_line():
    """As a user sees it (a separate process): ``warning: --control-sigma: ...`` on one line of stderr."""
    code = "import sys; from skyrig.cli import main; sys.exit(main())"
    r = subprocess.run([sys.executable, "-c", code, "block", "--control-sigma", "15", "--crs", "EPSG:25832"],
                       capture_output=True, text=True, timeout=120, env=_env())
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("warning:")]
    assert lines == ["warning: --control-sigma: 15 metres is unusual as a ground point's standard deviation "
                     "(expected 0 to 2 metres); millimetres (0.015 metres) or centimetres (0.15 metres)?"], r.stderr
