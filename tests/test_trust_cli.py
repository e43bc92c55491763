"""Issue 29, the command line: warnings as one line of words; SIGTERM / Ctrl-C stop a run in words.

Run as a user would (a separate process), so that the process's own warning display and signal handling are what
is tested.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

SRC = str(Path(__file__).resolve().parents[1] / "src")


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}


def test_any_warning_is_one_line_of_words_without_source_lines(tmp_path):
    """Python's format shows the file and the source line of the warning (``/x/y.py:12: RuntimeWarning: ...`` and
    the code); the CLI prints ``warning: <words>`` on one line, whatever the warning's class."""
    script = tmp_path / "w.py"
    script.write_text(
        "import sys, warnings\n"
        "import click\n"
        "from skyrig.cli import main\n"
        "@main.command('warn-me')\n"
        "def warn_me():\n"
        "    warnings.warn('invalid value encountered\\nin divide', RuntimeWarning)\n"
        "    warnings.warn('a deprecated thing', DeprecationWarning)\n"
        "    import numpy as np\n"
        "    np.float64(1.0) / np.float64(0.0)\n"
        "main(['warn-me'])\n")
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=_env(), timeout=120)
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert lines, r.stderr
    assert all(ln.startswith("warning: ") for ln in lines), r.stderr
    assert "invalid value encountered in divide" in r.stderr and "divide by zero" in r.stderr, r.stderr
    assert ".py:" not in r.stderr and "warnings.warn(" not in r.stderr, r.stderr


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_signal_stops_a_run_naming_the_stage(tmp_path, sig):
    """A run stopped in its second stage: a message naming the stage and saying that the last complete outputs
    are intact; the first stage's folder still verifies, nothing of the second is published, exit 128 + signal."""
    (tmp_path / "in.txt").write_text("x")
    (tmp_path / "project.yaml").write_text("format: skyrig-project\nversion: 1\ncrs: EPSG:25832\ninputs:\n"
                                           "  control: in.txt\nstages:\n  quick: {}\n  sleepy: {}\n")
    script = tmp_path / "r.py"
    script.write_text(
        "import sys, time\n"
        "from skyrig.pipeline.run import Stage, register_stage\n"
        "def quick(ctx):\n"
        "    (ctx.out / 'q.txt').write_text('done')\n"
        "def sleepy(ctx):\n"
        "    (ctx.out / 'half.txt').write_text('half')\n"
        "    print('SLEEPING', file=sys.stderr, flush=True)\n"
        "    time.sleep(60)\n"
        "register_stage(Stage('quick', 'q', quick, provides={'q': 'q.txt'}, inputs=lambda p, o: [p.control]))\n"
        "register_stage(Stage('sleepy', 's', sleepy, requires=('q',)))\n"
        "from skyrig.cli import main\n"
        f"main(['run', {str(tmp_path / 'project.yaml')!r}])\n")
    p = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env=_env())
    t0 = time.time()
    err = ""
    while "SLEEPING" not in err and time.time() - t0 < 120:
        line = p.stderr.readline()
        if not line:
            break
        err += line
    assert "SLEEPING" in err, err
    p.send_signal(sig)
    out, rest = p.communicate(timeout=60)
    err += rest
    assert p.returncode == 128 + sig, (p.returncode, out, err)
    assert "Traceback" not in err, err
    msg = [ln for ln in err.splitlines() if ln.startswith("stopped")]
    assert len(msg) == 1, err
    assert "sleepy" in msg[0] and "last complete outputs are intact" in msg[0], msg
    assert ("SIGTERM" if sig == signal.SIGTERM else "SIGINT") in msg[0], msg
    from skyrig.io.stage import verify_folder

    assert verify_folder(tmp_path / "output" / "quick") == []
    assert not (tmp_path / "output" / "sleepy").exists()
    run = json.loads((tmp_path / "output" / "run.json").read_text())
    assert [s["status"] for s in run["stages"]] == ["done", "interrupted"]


def test_a_stage_warning_is_shown_in_words_and_kept_in_run_json(tmp_path):
    """Warnings said during a stage reach the report: ``run.json`` lists them under the stage (issue 29: warnings
    on stderr and in the report)."""
    (tmp_path / "in.txt").write_text("x")
    (tmp_path / "project.yaml").write_text("format: skyrig-project\nversion: 1\ncrs: EPSG:25832\ninputs:\n"
                                           "  control: in.txt\nstages:\n  warny: {}\n")
    script = tmp_path / "r.py"
    script.write_text(
        "import warnings\n"
        "from skyrig.errors import PlausibilityWarning\n"
        "from skyrig.pipeline.run import Stage, register_stage\n"
        "def warny(ctx):\n"
        "    warnings.warn('in.txt: a lever arm of 12 m is unusually long', PlausibilityWarning)\n"
        "    (ctx.out / 'w.txt').write_text('done')\n"
        "register_stage(Stage('warny', 'w', warny, provides={'w': 'w.txt'}, inputs=lambda p, o: [p.control]))\n"
        "from skyrig.cli import main\n"
        f"main(['run', {str(tmp_path / 'project.yaml')!r}])\n")
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=_env(), timeout=120)
    assert r.returncode == 0, r.stderr
    assert "warning: in.txt: a lever arm of 12 m is unusually long" in r.stderr, r.stderr
    run = json.loads((tmp_path / "output" / "run.json").read_text())
    assert run["stages"][0]["warnings"] == ["in.txt: a lever arm of 12 m is unusually long"], run


def test_a_stage_warning_is_a_note_in_its_report_html(tmp_path):
    """A stage that writes a report.html (adjust, adjust-uav) shows its warnings there too, once, as a warning
    note after the page's header; a warning the page already lists is not repeated."""
    (tmp_path / "in.txt").write_text("x")
    (tmp_path / "project.yaml").write_text("format: skyrig-project\nversion: 1\ncrs: EPSG:25832\ninputs:\n"
                                           "  control: in.txt\nstages:\n  paged: {}\n")
    script = tmp_path / "r.py"
    script.write_text(
        "import warnings\n"
        "from skyrig.errors import PlausibilityWarning\n"
        "from skyrig.pipeline.run import Stage, register_stage\n"
        "from skyrig.report.model import ReportData\n"
        "from skyrig.report.html import write_report\n"
        "def paged(ctx):\n"
        "    warnings.warn('in.txt: sigma 5 <m> is large', PlausibilityWarning)\n"
        "    warnings.warn('already on the page', PlausibilityWarning)\n"
        "    write_report(ctx.out / 'report.html', ReportData(title='t', software='s', created='c', warnings=['already on the page']))\n"
        "register_stage(Stage('paged', 'p', paged, provides={'r': 'report.html'}, inputs=lambda p, o: [p.control]))\n"
        "from skyrig.cli import main\n"
        f"main(['run', {str(tmp_path / 'project.yaml')!r}])\n")
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=_env(), timeout=120)
    assert r.returncode == 0, r.stderr
    page = (tmp_path / "output" / "paged" / "report.html").read_text()
    run = json.loads((tmp_path / "output" / "run.json").read_text())
    assert run["stages"][0]["warnings"] == ["in.txt: sigma 5 <m> is large", "already on the page"]
    box = page.split("id='stage-warnings'")[1].split("</div>")[0]
    assert "in.txt: sigma 5 &lt;m&gt; is large" in box and "already on the page" not in box, box
    assert page.count("already on the page") == 1
    assert page.index("</header>") < page.index("stage-warnings")
