"""The simulated terrestrial reference (TLS) of the strip flights against the true surface.

Independent answers: the bridge's analytic surface (the ground plane's height, the boxes' faces) at the reference
points, a scan line of the widest strip ray-cast against the scene (:meth:`BridgeScene.cast`, independent of the
reference's face sampling) for the ground the laser sees, and the bench's plane-model C2C of exact surface points
against the reference, which must measure the reference's own noise and not its sampling spacing (the full
``strips`` flight's reference of 8 ground points/m^2 gave the true laser points 157 mm RMS on the ground).
"""

from __future__ import annotations

import numpy as np

from skyrig.lidar.compare import cloud_to_cloud
from skyrig.lidar.scanner import sensor_from_polar
from skyrig.simulate.lidar import GROUND, make_bridge, reference_reach_m, strip_scenario_spec


def _surface_distance(xyz: np.ndarray, boxes) -> np.ndarray:
    """Distance of each point to the nearest box surface (inside or outside)."""
    best = np.full(len(xyz), np.inf)
    for b in boxes:
        q = np.abs((xyz - b.centre) @ b.local_from_box) - b.half_size
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
        d = np.where(np.all(q <= 0, axis=1), -q.max(axis=1), outside)
        best = np.minimum(best, d)
    return best


def test_strip_flight_reference_is_on_the_true_surface_covers_the_laser_ground_and_supports_the_c2c():
    spec = strip_scenario_spec("strips", 1)
    scene = make_bridge(**spec.bridge)
    lb = scene.local_from_bridge
    rv = scene.width_m / 2 + reference_reach_m(spec)
    # the widest strip (15 m from the side, 4.5 m high; the fifth: south side, flown westward): one level scan line
    dist, alt = max(spec.strip_layout)
    fwd = lb @ np.array([-1.0, 0.0, 0.0])
    down = np.array([0.0, 0.0, -1.0])
    local_from_body = np.column_stack([fwd, np.cross(down, fwd), down])
    mount = spec.true_mount()
    pos = lb @ np.array([0.0, -(scene.width_m / 2 + dist), 0.0]) + [0.0, 0.0, alt]
    alpha = np.radians(np.arange(-135.0, 135.0, 0.25))
    beams = sensor_from_polar(np.ones_like(alpha), alpha) @ (local_from_body @ mount.body_from_scanner).T
    origin = np.broadcast_to(pos + local_from_body @ mount.lever_arm_m, beams.shape)
    rng_m, _, comp = scene.cast(origin, beams, spec.scanner.range_max_m)
    ground_v = ((origin + rng_m[:, None] * beams)[comp == GROUND] @ lb)[:, 1]
    assert ground_v.size > 100
    # the laser's ground ends inside the reference's ground, 1 m to spare for the flight's roll wobble
    assert np.abs(ground_v).max() + 1.0 < rv

    # the reference around a pillar (u = 13.5 m), as the flight's TLS: points on the analytic surface
    u_range = (6.0, 21.0)
    ref, nrm = scene.sample_surfaces(np.random.default_rng(5), spec.reference_density_per_m2,
                                     spec.reference_ground_density_per_m2, spec.reference_noise_m, u_range, (-rv, rv))
    sig = spec.reference_noise_m
    ground = (nrm[:, 2] == 1.0) & (ref[:, 2] < 0.5)
    assert ground.sum() > 1000 and (~ground).sum() > 1000
    assert np.abs(ref[ground, 2] - scene.ground_z).max() < 5 * sig
    assert _surface_distance(ref[~ground], scene.boxes).max() < 5 * sig

    # exact surface points (no noise) against it with the bench's comparison (plane of 10 neighbours within 0.5 m):
    # the reference's noise (3 mm), averaged by the plane, not its spacing
    true_pts, _ = scene.sample_surfaces(np.random.default_rng(6), 10.0, 10.0, 0.0, (7.0, 20.0), (-rv + 1, rv - 1))
    c2c = cloud_to_cloud(true_pts, ref, model="plane", k=10, max_distance=0.5)
    d = c2c.distance_m
    on_ground = true_pts[:, 2] < 1e-9
    assert np.isfinite(d).all() and c2c.n_fallback == 0
    open_ground = on_ground & (_surface_distance(true_pts, scene.boxes) > 0.6)  # no pillar point among the neighbours
    assert np.sqrt(np.mean(d[open_ground] ** 2)) < sig
    assert np.median(d[~on_ground]) < sig
