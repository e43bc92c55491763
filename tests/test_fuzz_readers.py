"""Hypothesis fuzz of every text reader and of the main commands (issue 13): good files mutated the ways files
get damaged (a slice cut out, text typed in, a line doubled or moved, a number replaced by something else, the
file cut short, line endings and separators changed).  Whatever comes in, a reader either reads it or raises a
:class:`~skyrig.errors.SkyrigError` (never a TypeError, IndexError, KeyError, a PROJ or numpy error), and a command
exits 0, 1 or 2 without a traceback.  Bounded: a few dozen examples per reader, no deadline (the 2-core machine is
shared), the whole file in well under a minute.
"""

from __future__ import annotations

import re
import sys
import warnings
from pathlib import Path

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
import test_bad_input_readers as base  # noqa: E402

from skyrig.errors import SkyrigError  # noqa: E402

GOOD = {"eo": base.EO, "pts": base.PTS, "mes": base.MES, "traj": base.TRAJ, "events": base.EVENTS, "rig": base.RIG,
        "opk": base.OPK, "app": base.APP, "imes": base.IMES, "cam": base.CAM, "gcp": base.GCP, "geo": base.GEO,
        "raw": base.RAW}

NOISE = st.text(alphabet=st.sampled_from(list("0123456789.,;:-+eE#\t \"'\nxyz_nanifé\r\ufeff[]{}")), max_size=12)
NUMBERISH = st.sampled_from(["nan", "inf", "-inf", "1e309", "-0", "", " ", "1,5", "0x10", "1e-400", "9" * 30, "'3'",
                             "NaN", "1.2.3", "+", "e5", "\ufeff1"])


@st.composite
def damaged(draw: st.DrawFn, text: str) -> str:
    """``text`` after one to three kinds of damage."""
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["cut", "insert", "double", "swap", "number", "truncate", "crlf", "separator"]))
        n = len(text)
        if op == "cut" and n:
            i = draw(st.integers(0, n - 1))
            text = text[:i] + text[i + draw(st.integers(1, 20)):]
        elif op == "insert":
            i = draw(st.integers(0, n))
            text = text[:i] + draw(NOISE) + text[i:]
        elif op in ("double", "swap"):
            lines = text.splitlines(keepends=True)
            if lines:
                i = draw(st.integers(0, len(lines) - 1))
                j = draw(st.integers(0, len(lines) - 1))
                if op == "double":
                    lines.insert(j, lines[i])
                else:
                    lines[i], lines[j] = lines[j], lines[i]
                text = "".join(lines)
        elif op == "number":
            spans = [m.span() for m in re.finditer(r"-?\d+(\.\d+)?", text)]
            if spans:
                a, b = draw(st.sampled_from(spans))
                text = text[:a] + draw(NUMBERISH) + text[b:]
        elif op == "truncate" and n:
            text = text[:draw(st.integers(0, n - 1))]
        elif op == "crlf":
            text = text.replace("\n", "\r\n")
        elif op == "separator":
            text = text.replace(",", draw(st.sampled_from([";", "\t", " ", ", "])))
    return text


FUZZ = settings(max_examples=25, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@pytest.mark.parametrize("kind", sorted(GOOD))
def test_reader_fuzz(tmp_path, kind):
    read = base._reader(kind)
    path = tmp_path / base.FILE_NAME[kind]

    @FUZZ
    @given(text=damaged(GOOD[kind]))
    def check(text: str) -> None:
        path.write_bytes(text.encode("utf-8"))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                read(path)
            except SkyrigError as exc:
                msg = str(exc)
                assert msg and "Traceback" not in msg
                assert "np.float64" not in msg and "np.str_" not in msg, msg

    check()


def test_fuzz_bytes_never_crash_a_reader(tmp_path):
    """Arbitrary bytes (binary junk, other encodings) under every reader's file name."""

    @settings(max_examples=30, deadline=None, derandomize=True)
    @given(data=st.binary(max_size=200), kind=st.sampled_from(sorted(GOOD)))
    def check(data: bytes, kind: str) -> None:
        p = tmp_path / base.FILE_NAME[kind]
        p.write_bytes(data)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                base._reader(kind)(p)
            except SkyrigError:
                pass

    check()


@pytest.mark.parametrize("command", ["world-to-image", "georef"])
def test_command_fuzz_exit_status(tmp_path, command):
    """The main commands on damaged inputs: exit 0/1/2, never a traceback."""
    from click.testing import CliRunner

    from skyrig.cli import main

    sys.path.insert(0, str(Path(__file__).parent))
    import test_bad_input_cli as cli

    files = {"eo.csv": cli.EO, "gcp.csv": cli.PTS, "rig.yaml": cli.RIG, "traj.csv": cli.TRAJ, "events.csv": cli.EVENTS}
    targets = ["eo.csv", "gcp.csv", "rig.yaml"] if command == "world-to-image" else ["traj.csv", "events.csv", "rig.yaml"]
    for name, text in files.items():
        (tmp_path / name).write_text(text)

    @settings(max_examples=12, deadline=None, derandomize=True)
    @given(which=st.sampled_from(targets), data=st.data())
    def check(which: str, data: st.DataObject) -> None:
        for name, text in files.items():
            (tmp_path / name).write_bytes(text.encode())
        (tmp_path / which).write_bytes(data.draw(damaged(files[which])).encode())
        if command == "world-to-image":
            args = ["world-to-image", "--eo", "eo.csv", "--camera", "rig.yaml", "--points", "gcp.csv", "-o", "o.csv"]
        else:
            args = ["georef", "--trajectory", "traj.csv", "--events", "events.csv", "--rig", "rig.yaml", "--crs",
                    "EPSG:25832", "-o", "o.csv"]
        args = [str(tmp_path / a) if a.endswith((".csv", ".yaml")) else a for a in args]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = CliRunner().invoke(main, args)
        assert res.exit_code in (0, 1, 2), res.output
        assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
        assert "Traceback" not in res.output

    check()
