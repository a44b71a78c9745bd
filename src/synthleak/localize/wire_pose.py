"""A returned pose as the service protocol carries it (docs/service-protocol.md): ``cam_from_world`` as a
COLMAP-order unit quaternion ``[qw, qx, qy, qz]`` and a translation, JSON numbers that round-trip exactly.

The quaternion is not a lossless code for a rotation matrix in floating point: matrix -> quaternion -> matrix
changes about one query in ten in the last bit or two. So an in-process study logs :func:`as_served` of its
localizer's pose, the matrix an HTTP client decodes from the same answer, and a study against ``synthleak serve``
gives the in-process results bytes (the attack's classifier can turn a last-bit difference into a 1e-4 score).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from synthleak.geometry.poses import make_pose, matrix_from_quat_wxyz, quat_wxyz_from_matrix


def encode_pose(cam_from_world: np.ndarray) -> dict[str, list[float]]:
    """The protocol's ``cam_from_world`` object of a 4x4 (or 3x4) pose."""
    pose = np.asarray(cam_from_world, dtype=np.float64)
    return {"rotation": [float(x) for x in quat_wxyz_from_matrix(pose[:3, :3])],
            "translation": [float(x) for x in pose[:3, 3]]}


def decode_pose(message: Mapping[str, object]) -> np.ndarray:
    """The 4x4 ``cam_from_world`` of the protocol's object (what a client gets)."""
    return make_pose(matrix_from_quat_wxyz(message["rotation"]), message["translation"])


def as_served(cam_from_world: np.ndarray) -> np.ndarray:
    """The pose a client of the service receives for ``cam_from_world``: :func:`decode_pose` of its
    :func:`encode_pose`."""
    return decode_pose(encode_pose(cam_from_world))
