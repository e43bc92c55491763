"""Block file version 1.1: covariance columns and the distances table; version 1 files still read."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skyrig.adjust.synthetic import synthetic_block
from skyrig.errors import InputFormatError
from skyrig.io.block_file import read_block, write_block


@pytest.fixture()
def block11():
    b, _ = synthetic_block(seed=4, n_strips=2, n_per_strip=4, n_points=60)
    rng = np.random.default_rng(0)
    n, k, g = b.n_observations, len(b.control_point), len(b.gnss_station)

    def spd(m, d, s):  # type: ignore[no-untyped-def]
        A = rng.normal(size=(m, d, d)) * s
        return A @ np.swapaxes(A, 1, 2) + np.eye(d) * s * s

    b.obs_cov_px2, b.control_cov_m2, b.gnss_cov_m2 = spd(n, 2, 0.5), spd(k, 3, 0.01), spd(g, 3, 0.05)
    b.distance_point = np.array([[0, 5], [3, 9]])
    b.distance_m = np.linalg.norm(b.point_xyz[[0, 3]] - b.point_xyz[[5, 9]], axis=1)
    b.distance_sigma_m = np.array([0.01, 0.02])
    b.__post_init__()
    return b


def test_round_trip_covariances_and_distances(block11, tmp_path):
    write_block(tmp_path / "b.json", block11)
    man = json.loads((tmp_path / "b.json").read_text())
    assert man["version"] == 1.1 and "distances" in man["tables"]
    got = read_block(tmp_path / "b.json").block
    for name in ("obs_cov_px2", "control_cov_m2", "gnss_cov_m2", "distance_m", "distance_sigma_m", "obs_sigma_px"):
        np.testing.assert_allclose(getattr(got, name), getattr(block11, name), rtol=1e-15, err_msg=name)
    np.testing.assert_array_equal(got.distance_point, block11.distance_point)


def test_without_new_features_version_1_is_written_and_read(tmp_path):
    b, _ = synthetic_block(seed=4, n_strips=2, n_per_strip=4, n_points=60)
    write_block(tmp_path / "b.json", b)
    man = json.loads((tmp_path / "b.json").read_text())
    assert man["version"] == 1  # old readers keep reading what needs no new feature
    got = read_block(tmp_path / "b.json").block
    assert got.obs_cov_px2 is None and got.n_distances == 0
    for v in (1.1, "1.1", 1.0):
        man["version"] = v
        (tmp_path / "b.json").write_text(json.dumps(man))
        read_block(tmp_path / "b.json")
    man["version"] = 2
    (tmp_path / "b.json").write_text(json.dumps(man))
    with pytest.raises(InputFormatError, match="unsupported version"):
        read_block(tmp_path / "b.json")


def test_control_covariance_may_replace_the_sigma_columns(block11, tmp_path):
    write_block(tmp_path / "b.json", block11)
    p = tmp_path / "b_control.csv"
    rows = [r.split(",") for r in p.read_text().splitlines()]
    drop = [rows[0].index(c) for c in ("sigma_X_m", "sigma_Y_m", "sigma_Z_m")]
    p.write_text("\n".join(",".join(c for k, c in enumerate(r) if k not in drop) for r in rows) + "\n")
    got = read_block(tmp_path / "b.json").block
    np.testing.assert_allclose(got.control_sigma, np.sqrt(np.diagonal(block11.control_cov_m2, axis1=1, axis2=2)))


def _edit(path, line, column, value):  # type: ignore[no-untyped-def]
    rows = [r.split(",") for r in path.read_text().splitlines()]
    rows[line - 1][rows[0].index(column)] = value
    path.write_text("\n".join(",".join(r) for r in rows) + "\n")


def test_errors_name_file_line_and_field(block11, tmp_path):
    write_block(tmp_path / "b.json", block11)
    obs = tmp_path / "b_observations.csv"
    good = obs.read_text()
    _edit(obs, 4, "cov_col_row_px2", "100")  # |rho| > 1: not positive definite
    with pytest.raises(InputFormatError, match="not positive definite") as e:
        read_block(tmp_path / "b.json")
    assert e.value.line == 4 and str(e.value.path).endswith("b_observations.csv")
    obs.write_text(good)
    rows = [r.split(",") for r in good.splitlines()]
    k = rows[0].index("cov_row_row_px2")
    obs.write_text("\n".join(",".join(c for j, c in enumerate(r) if j != k) for r in rows) + "\n")
    with pytest.raises(InputFormatError, match="come as a set") as e:
        read_block(tmp_path / "b.json")
    assert e.value.field == "cov_row_row_px2"
    obs.write_text(good)
    dist = tmp_path / "b_distances.csv"
    _edit(dist, 3, "point_b", "nosuchpoint")
    with pytest.raises(InputFormatError, match="unknown point") as e:
        read_block(tmp_path / "b.json")
    assert e.value.line == 3 and e.value.field == "point_b"
    _edit(dist, 3, "point_b", "p0")
    _edit(dist, 3, "point_a", "p0")
    with pytest.raises(InputFormatError, match="itself"):
        read_block(tmp_path / "b.json")


def test_actuated_heads_round_trip_with_rig_file(tmp_path):
    from skyrig.io.rig_file import write_rig
    from skyrig.rig.presets import macs_tumblecam

    rig = macs_tumblecam()
    beta = np.radians(45.0 * np.arange(8))
    b, _ = synthetic_block(seed=4, n_strips=2, n_per_strip=4, n_points=80, rig=rig, beta_rad=beta)
    b.actuator_correction = np.array([[0.0, 0.0], [1e-3, 2e-4]])
    with pytest.raises(ValueError, match="rig_file"):
        write_block(tmp_path / "b.json", b)
    write_rig(rig, tmp_path / "rig.yaml")
    write_block(tmp_path / "b.json", b, rig_file="rig.yaml")
    got = read_block(tmp_path / "b.json").block
    np.testing.assert_allclose(got.image_beta_rad, b.image_beta_rad, rtol=1e-14)
    np.testing.assert_allclose(got.actuator_correction, b.actuator_correction)
    assert [h is None for h in got.head_actuated] == [h is None for h in b.head_actuated]
    k = [h is not None for h in b.head_actuated].index(True)
    assert got.head_actuated[k].isclose(b.head_actuated[k])
    # an actuated image without its angle is named
    _edit(tmp_path / "b_images.csv", 3, "beta_deg", "nan")
    with pytest.raises(InputFormatError) as e:
        read_block(tmp_path / "b.json")
    assert e.value.line == 3 and e.value.field == "beta_deg"
