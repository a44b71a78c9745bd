"""The pose on the wire: an in-process study logs the bits an HTTP client decodes from the service's answer."""

import json

import numpy as np
from scipy.spatial.transform import Rotation

from synthleak.evaluate.query_log import query_line
from synthleak.geometry.poses import make_pose
from synthleak.localize.client import HttpLocalizationResult
from synthleak.localize.localizer import LocalizationResult
from synthleak.localize.server import response_from_result
from synthleak.localize.wire_pose import as_served, decode_pose

ITEM = {"frame": "000000.png", "genuine": True, "attacker_object": None, "_image": "x.png"}


def _poses(n: int = 300) -> list[np.ndarray]:
    rng = np.random.default_rng(7)
    rotations = Rotation.random(n, random_state=11).as_matrix()
    return [make_pose(r, rng.uniform(-3, 3, 3)) for r in rotations]


def test_the_quaternion_round_trip_is_not_lossless_so_the_log_needs_it():
    changed = [p for p in _poses() if not np.array_equal(as_served(p), p)]
    assert len(changed) > 10  # about one pose in ten changes in its last bits
    assert max(np.abs(as_served(p) - p).max() for p in changed) < 1e-14


def test_in_process_log_equals_the_pose_a_client_decodes_from_the_served_json():
    for pose in _poses():
        in_process = json.loads(query_line(ITEM, "sift", "room_000", LocalizationResult(True, pose), None,
                                           remote=False))
        answer = json.loads(json.dumps(response_from_result(LocalizationResult(True, pose))))  # what travels
        received = HttpLocalizationResult(True, decode_pose(answer["cam_from_world"]))
        over_http = json.loads(query_line(ITEM, "sift", "room_000", received, None, remote=True, served=True))
        assert in_process["cam_from_world"] == over_http["cam_from_world"]


def test_a_pose_that_came_over_http_is_logged_as_received():
    for pose in _poses(50):
        received = decode_pose(json.loads(json.dumps(response_from_result(LocalizationResult(True, pose))))[
            "cam_from_world"])
        line = json.loads(query_line(ITEM, "sift", "room_000", HttpLocalizationResult(True, received), None,
                                     remote=True, served=True))
        assert line["cam_from_world"] == received.tolist()
