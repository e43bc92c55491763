"""Layer 0 geometry: angle units, rotation conventions, poses with named frames."""

from skyrig.geometry.angles import (
    AngleUnit,
    check_plausible,
    convert_angle,
    from_radians,
    normalize_unit,
    to_radians,
    wrap_pi,
)
from skyrig.geometry.pose import Pose
from skyrig.geometry.rotations import (
    ENU_FROM_NED,
    GIMBAL_FROM_CAMERA,
    NADIR_BODY_FROM_CAMERA,
    matrix_from_opk,
    matrix_from_quaternion,
    matrix_from_rotvec,
    matrix_from_rpy,
    opk_from_matrix,
    orthonormalize,
    quaternion_from_matrix,
    rot_x,
    rot_y,
    rot_z,
    rotvec_from_matrix,
    rpy_from_matrix,
    skew,
    slerp,
)

__all__ = [
    "AngleUnit", "check_plausible", "convert_angle", "from_radians", "normalize_unit", "to_radians", "wrap_pi",
    "Pose", "ENU_FROM_NED", "GIMBAL_FROM_CAMERA", "NADIR_BODY_FROM_CAMERA", "matrix_from_opk", "matrix_from_quaternion", "matrix_from_rotvec", "matrix_from_rpy",
    "opk_from_matrix", "orthonormalize", "quaternion_from_matrix", "rot_x", "rot_y", "rot_z", "rotvec_from_matrix",
    "rpy_from_matrix", "skew", "slerp",
]
