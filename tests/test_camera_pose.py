"""The one composition of a camera's world pose (:mod:`skyrig.rig.camera_pose`).

Independent answers: :class:`skyrig.geometry.pose.Pose` composition (``world_from_body @ body_from_camera``,
a rigid-motion product written separately), and the camera centre as the lever-arm point carried into the
world by the body pose (``Pose.apply``).
"""

from __future__ import annotations

import numpy as np

from skyrig.geometry.pose import Pose
from skyrig.geometry.rotations import matrix_from_rotvec
from skyrig.rig import Rig, midas
from skyrig.rig.camera_pose import (
    antenna_from_body_origin,
    body_origin_from_antenna,
    camera_poses,
    head_mountings,
    world_from_camera,
)


def _random_poses(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    return matrix_from_rotvec(rng.normal(0, 1.0, (n, 3))), rng.normal(0, 1e5, (n, 3))


def test_world_from_camera_is_the_pose_product() -> None:
    rng = np.random.default_rng(4)
    Rb, ob = _random_poses(rng, 50)
    Rm, lever = matrix_from_rotvec(rng.normal(0, 1.0, (50, 3))), rng.normal(0, 2.0, (50, 3))
    R, C = world_from_camera(Rb, ob, Rm, lever)
    for k in range(50):
        ref = Pose(Rb[k], ob[k], "world", "body") @ Pose(Rm[k], lever[k], "body", "camera")
        assert np.abs(R[k] - ref.rotation).max() < 1e-14
        assert np.abs(C[k] - ref.translation).max() < 1e-8  # 1e5 m coordinates
        assert np.abs(C[k] - Pose(Rb[k], ob[k], "world", "body").apply(lever[k])).max() < 1e-8


def test_antenna_and_body_origin_are_inverse() -> None:
    rng = np.random.default_rng(5)
    Rb, ob = _random_poses(rng, 20)
    lever = np.array([0.05, -0.2, -1.3])
    ant = antenna_from_body_origin(Rb, ob, lever)
    assert np.allclose(np.linalg.norm(ant - ob, axis=1), np.linalg.norm(lever), rtol=0, atol=1e-9)
    assert np.abs(body_origin_from_antenna(Rb, ant, lever) - ob).max() < 1e-8


def test_camera_poses_of_a_rig_from_the_antenna() -> None:
    rng = np.random.default_rng(6)
    base = midas()  # published lever arms are zeros: give every head and the antenna one
    rig = Rig("levers", [h.with_(lever_arm_m=rng.normal(0, 0.5, 3)) for h in base], antenna_lever_arm_m=[0.05, 0.0, -1.3])
    n = len(rig.head_names)
    Rb, ob = _random_poses(rng, 1)
    Rb, ob = np.repeat(Rb, n, axis=0), np.repeat(ob, n, axis=0)
    heads = np.array(rig.head_names)
    ant = ob + Rb @ rig.antenna_lever_arm_m
    R, C, cams = camera_poses(rig, heads, np.full(n, np.nan), Rb, ant, reference="antenna")
    rot, lever, _ = head_mountings(rig, heads, np.full(n, np.nan))
    for k, h in enumerate(heads):
        head = rig.head(str(h))
        assert cams[k] == head.camera.name
        assert np.abs(rot[k] - head.mounting @ head.boresight).max() < 1e-15
        ref = Pose(Rb[k], ob[k], "world", "body") @ head.body_from_camera()
        assert np.abs(R[k] - ref.rotation).max() < 1e-14
        assert np.abs(C[k] - ref.translation).max() < 1e-8
        assert np.abs(lever[k] - head.lever_arm_m).max() == 0 and np.any(lever[k] != 0)
