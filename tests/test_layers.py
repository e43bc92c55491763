"""The layers of DESIGN.md, checked by import-linter (the contracts in ``.importlinter``).

The real tree keeps them; a copy of it with one deliberate upward import, or one deliberate cycle, breaks them
(so the check can fail).  ``lint-imports`` runs in a subprocess on the package that the tests import.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import skyrig

pytest.importorskip("importlinter", reason="import-linter is a [dev] dependency (pip install -e '.[dev]')")

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / ".importlinter"
PACKAGE = Path(skyrig.__file__).resolve().parent


def _lint(src: Path, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``lint-imports`` on the ``skyrig`` package found under ``src`` (a folder holding ``skyrig/``)."""
    env = dict(os.environ, PYTHONPATH=str(src), NO_COLOR="1", COLUMNS="200")
    code = "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"
    return subprocess.run([sys.executable, "-c", code, "--config", str(CONFIG), "--no-cache"], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)


def test_contracts_hold_on_the_tree(tmp_path: Path) -> None:
    r = _lint(PACKAGE.parent, tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "2 kept, 0 broken" in r.stdout, r.stdout


def test_contracts_fail_on_an_upward_import_and_on_a_cycle(tmp_path: Path) -> None:
    src = tmp_path / "src"
    shutil.copytree(PACKAGE, src / "skyrig", ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "viewer", "data"))
    # layer 0 importing layer 3 (a lazy import counts: it runs when the function does)
    (src / "skyrig" / "geometry" / "_upward.py").write_text(
        "def f():\n    from skyrig.io import gpkg\n\n    return gpkg\n")
    # two modules of one package importing each other
    (src / "skyrig" / "camera" / "_cycle_a.py").write_text("from skyrig.camera import _cycle_b  # noqa\n")
    (src / "skyrig" / "camera" / "_cycle_b.py").write_text("def g():\n    from skyrig.camera import _cycle_a\n")
    r = _lint(src, tmp_path)
    assert r.returncode != 0, r.stdout
    assert "0 kept, 2 broken" in r.stdout, r.stdout
    assert "skyrig.geometry is not allowed to import skyrig.io" in r.stdout, r.stdout
    assert "skyrig.geometry._upward -> skyrig.io.gpkg" in r.stdout, r.stdout
    assert "No cycles are allowed in skyrig.camera" in r.stdout, r.stdout
