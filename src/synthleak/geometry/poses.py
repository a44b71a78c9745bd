"""Pose conventions, named once and used everywhere.

All poses are 4x4 homogeneous matrices acting on column vectors, float64, metres.

* ``a_from_b`` maps a point expressed in frame *b* into frame *a*: ``p_a = a_from_b @ p_b``.
  Composition reads right to left: ``a_from_c = a_from_b @ b_from_c``.
* ``cam_from_world`` is COLMAP's / OpenCV's world-to-camera pose (the paper's ``[R|t]``):
  camera axes are +x right, +y down, +z forward (optical axis).
* ``world_from_cam`` is its inverse; its translation is the camera centre in the world.
* ``scene_from_object`` / ``world_from_object`` place an object's canonical frame in a scene.
* ``cam_from_object`` is the pose attacker sequences store: the photographed object's canonical frame plays the
  world (its inverse ``object_from_cam`` places the camera in the object frame).

Quaternions are ``[qw, qx, qy, qz]`` (COLMAP order), scipy's Rotation is used underneath.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation


def make_pose(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """4x4 pose from a 3x3 rotation and a 3-vector translation."""
    pose = np.eye(4)
    pose[:3, :3] = np.asarray(rotation, dtype=np.float64)
    pose[:3, 3] = np.asarray(translation, dtype=np.float64).reshape(3)
    return pose


def invert(pose: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 pose (exact transpose formula, not a general inverse)."""
    rot = pose[:3, :3]
    return make_pose(rot.T, -rot.T @ pose[:3, 3])


def transform_points(a_from_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Map (N, 3) points from frame b to frame a."""
    points_b = np.asarray(points_b, dtype=np.float64)
    return points_b @ a_from_b[:3, :3].T + a_from_b[:3, 3]


def camera_centre(cam_from_world: np.ndarray) -> np.ndarray:
    """Camera centre in world coordinates, ``-R^T t``."""
    return -cam_from_world[:3, :3].T @ cam_from_world[:3, 3]


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """``cam_from_world`` of an OpenCV camera at ``eye`` looking at ``target`` with world ``up`` roughly up."""
    eye = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye
    forward /= np.linalg.norm(forward)
    up = np.asarray(up, dtype=np.float64)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:  # looking straight along up: pick any right vector
        right = np.cross(forward, [1.0, 0.0, 0.0] if abs(forward[0]) < 0.9 else [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    world_from_cam = make_pose(np.stack([right, down, forward], axis=1), eye)
    return invert(world_from_cam)


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """Angle of a rotation matrix in degrees: ``atan2(sin, cos)`` from its skew part and trace, accurate near 0
    (``arccos`` of the trace turns a last-bit difference, say another CPU's, into 1e-6 degrees there)."""
    return float(rotation_angles_deg(np.asarray(rotation, dtype=np.float64)))


def rotation_angles_deg(rotations: np.ndarray) -> np.ndarray:
    """Angles in degrees of a stack (..., 3, 3) of rotation matrices (see :func:`rotation_angle_deg`)."""
    r = np.asarray(rotations, dtype=np.float64)
    sx, sy, sz = r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]
    sin2 = np.sqrt(sx * sx + sy * sy + sz * sz)  # 2 sin(angle)
    cos2 = r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2] - 1.0  # 2 cos(angle)
    return np.degrees(np.arctan2(sin2, cos2))


SYMMETRIES = ("none", "2", "4", "z")
"""An object's symmetry about its canonical +z axis: none, 2- or 4-fold turns, or any turn (``z``)."""


def _rotation_of(matrix: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(matrix, dtype=np.float64)
    if arr.shape not in ((3, 3), (4, 4)):
        raise ValueError(f"{name}: expected a 3x3 rotation or 4x4 pose, got shape {arr.shape}")
    return arr[:3, :3]


def rotation_error_deg(r_a: np.ndarray, r_b: np.ndarray, symmetry: str = "none") -> float:
    """Angle of ``r_a r_bᵀ`` in degrees, modulo an object's symmetry about its +z axis (``r_b`` placing it).

    Accepts 3x3 rotations or 4x4 poses, whose rotation blocks are used as they are (divide a similarity's
    scale out first: :func:`synthleak.evaluate.metrics.rotation_block`). ``"none"``: the angle of
    ``r_a r_bᵀ``. ``"2"`` / ``"4"``: the minimum over the n-fold turns ``Rz(k 360/n)`` of the object frame
    (``r_b Rz`` looks identical). ``"z"`` (continuous symmetry): any turn about z is free, so the error is the
    angle between the two +z axes (the tilt).
    """
    r_a, r_b = _rotation_of(r_a, "r_a"), _rotation_of(r_b, "r_b")
    if symmetry == "none":
        return rotation_angle_deg(r_a @ r_b.T)
    if symmetry in ("2", "4"):
        n = int(symmetry)
        angles = np.array([[360.0 * k / n] for k in range(n)])
        turns = Rotation.from_euler("z", angles, degrees=True).as_matrix()
        return min(rotation_angle_deg(r_a @ (r_b @ turn).T) for turn in turns)
    if symmetry == "z":
        cos = float(np.clip(r_a[:, 2] @ r_b[:, 2], -1.0, 1.0))
        return math.degrees(math.acos(cos))
    raise ValueError(f"symmetry: unknown value {symmetry!r} (expected one of {SYMMETRIES})")


def quat_wxyz_from_matrix(rotation: np.ndarray) -> np.ndarray:
    """COLMAP-order quaternion ``[qw, qx, qy, qz]`` with qw >= 0."""
    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    q = np.array([w, x, y, z])
    return q if q[0] >= 0 else -q


def matrix_from_quat_wxyz(q: np.ndarray) -> np.ndarray:
    """Rotation matrix from a COLMAP-order quaternion ``[qw, qx, qy, qz]``."""
    w, x, y, z = np.asarray(q, dtype=np.float64)
    return Rotation.from_quat([x, y, z, w]).as_matrix()


def check_pose(pose: np.ndarray, name: str = "pose", tol: float = 1e-6) -> np.ndarray:
    """Validate a rigid 4x4 pose: finite, orthonormal rotation with det +1, last row [0 0 0 1]."""
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (4, 4):
        raise ValueError(f"{name}: expected a 4x4 matrix, got shape {pose.shape}")
    if not np.all(np.isfinite(pose)):
        raise ValueError(f"{name}: pose has non-finite entries")
    rot = pose[:3, :3]
    if np.abs(rot @ rot.T - np.eye(3)).max() > tol or abs(np.linalg.det(rot) - 1.0) > tol:
        raise ValueError(f"{name}: rotation block is not a proper rotation")
    if np.abs(pose[3] - [0, 0, 0, 1]).max() > tol:
        raise ValueError(f"{name}: last row is not [0, 0, 0, 1]")
    return pose
