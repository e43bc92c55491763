"""``bench/tumbling_lab.py`` (paper 000's laboratory set-up simulated) loaded as a module for the tumbling tests."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[1]


def tumbling_lab() -> ModuleType:
    """The bench module (loaded once per process: ``sys.modules['tumbling_lab']``)."""
    if "tumbling_lab" in sys.modules:
        return sys.modules["tumbling_lab"]
    spec = importlib.util.spec_from_file_location("tumbling_lab", ROOT / "bench" / "tumbling_lab.py")
    mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules["tumbling_lab"] = mod
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod
