"""Pose conventions: cam_from_world (OpenCV axes), world_from_cam, quaternions in COLMAP order."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from synthleak.geometry.poses import (
    camera_centre,
    check_pose,
    invert,
    look_at,
    make_pose,
    matrix_from_quat_wxyz,
    quat_wxyz_from_matrix,
    transform_points,
)


def test_look_at_puts_the_target_on_the_optical_axis_with_image_y_down():
    eye, target = np.array([1.0, -2.0, 1.6]), np.array([0.5, 1.0, 0.8])
    cam_from_world = look_at(eye, target)
    check_pose(cam_from_world)
    p = transform_points(cam_from_world, [target])[0]
    assert p[2] > 0 and np.allclose(p[:2], 0, atol=1e-12)  # straight ahead, +z forward
    above = transform_points(cam_from_world, [target + [0, 0, 0.5]])[0]
    assert above[1] < 0  # world up projects to image up (-y)
    assert np.allclose(camera_centre(cam_from_world), eye)


def test_invert_composes_to_identity():
    rng = np.random.default_rng(0)
    pose = make_pose(Rotation.random(random_state=1).as_matrix(), rng.normal(size=3))
    assert np.allclose(invert(pose) @ pose, np.eye(4), atol=1e-12)
    # a_from_c = a_from_b @ b_from_c
    other = make_pose(Rotation.random(random_state=2).as_matrix(), rng.normal(size=3))
    pts = rng.normal(size=(5, 3))
    assert np.allclose(transform_points(pose @ other, pts), transform_points(pose, transform_points(other, pts)))


def test_quaternion_is_colmap_order_with_positive_w():
    rot = Rotation.from_euler("xyz", [10, -20, 170], degrees=True).as_matrix()
    q = quat_wxyz_from_matrix(rot)
    assert q[0] >= 0
    assert np.allclose(matrix_from_quat_wxyz(q), rot)
    assert np.allclose(quat_wxyz_from_matrix(np.eye(3)), [1, 0, 0, 0])


@pytest.mark.parametrize("bad,match", [
    (np.full((4, 4), np.nan), "non-finite"),
    (np.diag([1.0, 1.0, -1.0, 1.0]), "not a proper rotation"),
    (np.eye(3), "4x4"),
])
def test_check_pose_rejects(bad, match):
    with pytest.raises(ValueError, match=match):
        check_pose(bad, "cam_from_world")
