"""Damaged exchange files (issue 33): COLMAP binary models either read or raise a skyrig error naming a file,
never a bare Python exception (struct.error, IndexError, ...).  The text formats (Metashape, OpenSfM, MicMac) are
fuzzed with the other readers in test_fuzz_readers.py."""

from __future__ import annotations

import json
import warnings

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from skyrig.errors import SkyrigError  # noqa: E402


def _opensfm_text() -> str:
    cam = {"projection_type": "brown", "width": 400, "height": 300, "focal_x": 0.9, "focal_y": 0.9, "c_x": 0.01,
           "c_y": -0.01, "k1": -0.1, "k2": 0.01, "p1": 0.001, "p2": 0.0, "k3": 0.0}
    shots = {f"im{k}.jpg": {"rotation": [0.1 * k, 0.2, 0.0], "translation": [k, 0.0, 5.0], "camera": "c"}
             for k in range(2)}
    pts = {"1": {"coordinates": [0.5, 0.25, 1.0], "color": [1, 2, 3]}}
    rec = {"cameras": {"c": cam}, "shots": shots, "points": pts,
           "reference_lla": {"latitude": 52.5, "longitude": 13.4, "altitude": 40.0}}
    return json.dumps([rec], indent=1)


@pytest.mark.parametrize("which", ["cameras.bin", "images.bin", "points3D.bin"])
def test_colmap_binary_fuzz(tmp_path, which):
    from test_colmap_io import _model

    from skyrig.io.colmap_folder import write_colmap
    from skyrig.io.colmap_binary import read_colmap_binary

    write_colmap(tmp_path, _model(seed=9, noise_px=0.0))
    good = (tmp_path / which).read_bytes()

    @settings(max_examples=15, deadline=None, derandomize=True)
    @given(cut=st.integers(0, len(good)), junk=st.binary(max_size=24), where=st.integers(0, len(good)))
    def check(cut: int, junk: bytes, where: int) -> None:
        data = good[:cut]
        data = data[:where] + junk + data[where:]
        (tmp_path / which).write_bytes(data)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                read_colmap_binary(tmp_path)
            except SkyrigError as exc:
                assert ".bin" in str(exc), str(exc)  # names the file (a damaged one can break a check in another)

    check()
