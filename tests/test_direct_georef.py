"""Direct georeferencing: against independent compositions, the inverse, and bad input through the CLI."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from skyrig.cli import main
from skyrig.georef.direct import direct_georeference, inverse_georeference
from skyrig.georef.eo import WorldFrame
from skyrig.io.eo_csv import read_eo_csv
from skyrig.io.events_csv import write_events_csv
from skyrig.io.rig_file import write_rig
from skyrig.io.trajectory_csv import write_trajectory_csv
from skyrig.pipeline.demo import demo_flight, demo_rig, independent_eo, rotation_angle_deg
from skyrig.rig.boresight_curve import BoresightCurve
from skyrig.rig.presets import macs_tumblecam
from skyrig.rig.rig import ActuatedHead, Rig
from skyrig.trajectory.events import CameraEvents
from skyrig.trajectory.trajectory import Trajectory


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _tumble_flight(n=24):
    t = 1000.0 + np.arange(0, 60, 0.01)
    lat = 52.4 + (t - t[0]) * 4e-5
    lon = np.full_like(t, 13.1) + 1e-6 * np.sin(t)
    h = np.full_like(t, 150.0)
    traj = Trajectory.from_rpy(t, lat, lon, h, 2 * np.sin(0.5 * t), 3 + np.cos(0.3 * t), 10 + 0.5 * t - 500, unit="deg")
    te = np.repeat(1005.0 + np.arange(n) * 2.0 + 0.003, 2)
    heads = np.tile(["nadir", "oblique"], n)
    beta = np.where(heads == "oblique", np.radians(np.repeat(np.arange(n) * 37.0, 2)), np.nan)
    names = [f"{h}_{i // 2:03d}" for i, h in enumerate(heads)]
    ev = CameraEvents.create(te, heads, names, beta_rad=beta, exposure_id=np.repeat(np.arange(n), 2))
    return traj, ev


def test_tumbling_eo_from_cli_equals_nadir_eo_composed_with_paper_mounting(tmp_path):
    """Paper 000 section 3.4: oblique EO = nadir EO composed with the beta-dependent mounting.

    The mounting is written out here from eqs 1-3 (roll = sin(beta) gamma, pitch = cos(beta) gamma,
    yaw = 0 about the sensor-head axes) plus a boresight correction curve, with explicit matrices."""
    base = macs_tumblecam()
    beta_s = np.radians(np.arange(0, 360, 5.0))
    corr = np.column_stack([0.01 * np.sin(beta_s), 0.008 * np.cos(2 * beta_s), 0.005 * np.sin(beta_s + 1)]) * np.pi / 180
    curve = BoresightCurve(beta_s, corr, interpolation="linear")
    obl = base.heads["oblique"]
    rig = Rig("tc", [base.heads["nadir"].with_(lever_arm_m=np.array([0.02, 0.0, 0.05])),
                     obl.with_(curve=curve, lever_arm_m=np.array([0.05, 0.1, 0.08]))], antenna_lever_arm_m=np.array([0, 0, -0.3]))
    traj, ev = _tumble_flight()
    write_trajectory_csv(tmp_path / "t.csv", traj)
    write_events_csv(tmp_path / "e.csv", ev)
    write_rig(rig, tmp_path / "rig.yaml")
    r = CliRunner().invoke(main, ["georef", "--trajectory", str(tmp_path / "t.csv"), "--events", str(tmp_path / "e.csv"),
                                  "--rig", str(tmp_path / "rig.yaml"), "--crs", "EPSG:25833", "-o", str(tmp_path / "eo.csv")])
    assert r.exit_code == 0, r.output
    # compare in ECEF: grid axes at two centres 0.1 m apart differ by ~1e-6 deg (vertical deflection)
    eo = read_eo_csv(tmp_path / "eo.csv").to_frame(WorldFrame.ecef())
    idx = eo.index()
    gamma = np.radians(30.0)
    nadir_b = np.diag([1.0, -1.0, -1.0])
    for k in range(len(ev.time_s) // 2):
        n, o = idx[f"nadir_{k:03d}"], idx[f"oblique_{k:03d}"]
        beta = np.radians(k * 37.0) % (2 * np.pi)
        dr, dp, dy = (np.interp(beta, np.append(beta_s, 2 * np.pi), np.append(corr[:, j], corr[0, j])) for j in range(3))
        body_from_obl = _rz(dy) @ _ry(np.cos(beta) * gamma + dp) @ _rx(np.sin(beta) * gamma + dr) @ nadir_b
        world_from_body = eo.rotation[n] @ nadir_b.T
        expected = world_from_body @ body_from_obl
        assert rotation_angle_deg(eo.rotation[o][None], expected[None])[0] < 1e-8  # file keeps 1e-10 deg
        # projection centres differ by the lever-arm difference rotated into the world frame (file: 0.1 mm)
        d = world_from_body @ (np.array([0.05, 0.1, 0.08]) - np.array([0.02, 0.0, 0.05]))
        np.testing.assert_allclose(eo.centre[o] - eo.centre[n], d, atol=2e-4)


def test_demo_flight_matches_independent_composition():
    traj, ev = demo_flight()
    rig = demo_rig()
    eo = direct_georeference(traj, rig, ev, WorldFrame.map("EPSG:25832"))
    centres, rots = independent_eo(traj, ev, rig)
    np.testing.assert_allclose(eo.centre, centres, atol=1e-4)
    assert rotation_angle_deg(eo.rotation, rots).max() < 1e-5  # linear vs slerp interpolation at 50 Hz


@pytest.mark.parametrize("frame", [WorldFrame.ecef(), WorldFrame.map("EPSG:25832"), WorldFrame.local(52.3, 9.8, 50.0)])
def test_georef_then_inverse_returns_the_trajectory(frame):
    traj, ev = demo_flight()
    rig = demo_rig()
    eo = direct_georeference(traj, rig, ev, frame)
    states = inverse_georeference(eo, rig)
    s = traj.interpolate(ev.time_s)
    scale = np.linalg.norm(s.ecef, axis=1)
    assert np.max(np.linalg.norm(states.antenna_ecef - s.ecef, axis=1) / scale) < 1e-9 * 10
    assert np.abs(states.antenna_ecef - s.ecef).max() < 1e-5
    np.testing.assert_allclose(states.ned_from_body(at="antenna"), s.ned_from_body, atol=1e-9)


def _write_inputs(tmp_path):
    traj, ev = demo_flight()
    write_trajectory_csv(tmp_path / "t.csv", traj)
    write_events_csv(tmp_path / "e.csv", ev)
    write_rig(demo_rig(), tmp_path / "rig.yaml")
    return traj, ev


def test_event_outside_trajectory_names_file_line_field(tmp_path):
    traj, ev = _write_inputs(tmp_path)
    lines = (tmp_path / "e.csv").read_text().splitlines()
    k = next(i for i, l in enumerate(lines) if not l.startswith("#") and "," in l and not l.startswith("image"))
    parts = lines[k + 3].split(",")
    parts[1] = "%.3f" % (traj.time_s[-1] + 100.0)
    lines[k + 3] = ",".join(parts)
    (tmp_path / "e.csv").write_text("\n".join(lines) + "\n")
    r = CliRunner().invoke(main, ["georef", "--trajectory", str(tmp_path / "t.csv"), "--events", str(tmp_path / "e.csv"),
                                  "--rig", str(tmp_path / "rig.yaml"), "--crs", "EPSG:25832", "-o", str(tmp_path / "eo.csv")])
    assert r.exit_code == 2
    assert "e.csv" in r.output and f"line {k + 4}" in r.output and "'time'" in r.output
    assert not (tmp_path / "eo.csv").exists()


def test_unknown_crs_is_a_clear_error(tmp_path):
    _write_inputs(tmp_path)
    r = CliRunner().invoke(main, ["georef", "--trajectory", str(tmp_path / "t.csv"), "--events", str(tmp_path / "e.csv"),
                                  "--rig", str(tmp_path / "rig.yaml"), "--crs", "EPSG:0", "-o", str(tmp_path / "eo.csv")])
    assert r.exit_code == 2 and "unknown coordinate reference system" in r.output
