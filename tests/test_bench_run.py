"""bench/run.py's growth fit and tables on figures of known growth (no project is simulated or run)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest


@pytest.fixture(scope="module")
def bench_run():
    path = Path(__file__).resolve().parents[1] / "bench" / "run.py"
    spec = importlib.util.spec_from_file_location("skyrig_bench_run", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod


def _rows(ks, b_time, b_mem):
    rows = []
    for k in ks:
        n = 60 * k * k
        rows.append({"scenario": f"midas-dsm-x{k}-s0.25", "grow": k, "images": n, "megapixels": 0.1 * n,
                     "stages": [{"stage": "match", "stage_s": 0.5 * n ** b_time, "peak_mib": 3.0 * n ** b_mem,
                                 "children_peak_mib": 0, "exit": 0,
                                 "summary": {"pairs": 6 * n, "pairs_overlapping": 20 * n}},
                                {"stage": "adjust", "stage_s": 0.01 * n ** 2, "peak_mib": 100.0 + 0 * n,
                                 "children_peak_mib": 0, "exit": 0}]})
    return rows


def test_growth_exponents_and_projection_of_power_laws(bench_run):
    rows = _rows([1, 2, 3], 1.25, 0.5)
    g = bench_run._growth(rows, [1, 2, 3], 7)
    assert g["images_projected"] == 60 * 49
    assert g["stages"]["match"]["b_time"] == pytest.approx(1.25, abs=1e-9)
    assert g["stages"]["match"]["b_mem"] == pytest.approx(0.5, abs=1e-9)
    assert g["stages"]["adjust"]["b_time"] == pytest.approx(2.0, abs=1e-9)
    assert g["stages"]["adjust"]["b_mem"] == pytest.approx(0.0, abs=1e-9)
    # the projection continues the power law from the largest size
    assert g["stages"]["match"]["projected_s"] == pytest.approx(0.5 * 2940 ** 1.25, rel=1e-9)
    assert g["stages"]["adjust"]["projected_s"] == pytest.approx(0.01 * 2940 ** 2, rel=1e-9)


def test_tables_skip_a_failed_size_and_show_kept_of_overlapping_pairs(bench_run, capsys):
    rows = _rows([1, 2, 3], 1.0, 1.0)
    rows[2]["stages"][1]["exit"] = 1  # adjust of the largest size failed: it is not a complete size
    g = bench_run._print_tables(rows, 7)
    out = capsys.readouterr().out
    assert "360/1200" in out  # pairs kept / overlapping of the x1 block (60 images)
    assert g is not None and g["images_projected"] == int(round(240 * (7 / 2) ** 2))
    assert np.isfinite(g["stages"]["match"]["b_time"])
