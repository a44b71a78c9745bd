"""One attack: match local and server poses by frame name and align them with a registered aligner."""

from __future__ import annotations

import inspect
from collections.abc import Mapping

import numpy as np

from synthleak.attack.align import Alignment, get_aligner


def run_attack(
    local_poses: Mapping[str, np.ndarray],
    server_poses: Mapping[str, np.ndarray | None],
    aligner: str,
    delta_r_deg: float,
    delta_t_m: float,
    n_sent: int | None = None,
    ups: tuple[np.ndarray, np.ndarray | None] | None = None,
) -> Alignment:
    """Align the attacker's local poses (``cam_from_object`` or ``cam_from_local``) with the server's
    ``cam_from_scene`` for the frames the server localized.

    ``server_poses`` maps every sent frame to its pose, or None / absence when not localized. ``n_sent``
    (the paper's N) defaults to the number of frames with a local pose, which is what the attacker sends.
    Frames are processed in sorted name order, so the result does not depend on dict order. ``ups``: the
    local model's and the scene's up directions (:mod:`synthleak.attack.gravity`), given to the aligners that
    take them (``local_up`` / ``scene_up`` keywords: ``upright``).
    """
    names = sorted(n for n in local_poses if server_poses.get(n) is not None)
    extra = sorted(n for n in server_poses if server_poses[n] is not None and n not in local_poses)
    if extra:
        raise ValueError(f"server_poses: frames without a local pose: {extra[:5]}")
    n_total = len(local_poses) if n_sent is None else int(n_sent)
    local = np.array([local_poses[n] for n in names], dtype=np.float64).reshape(-1, 4, 4)
    server = np.array([server_poses[n] for n in names], dtype=np.float64).reshape(-1, 4, 4)
    align = get_aligner(aligner)
    if ups is not None and takes_up_directions(aligner):
        return align(local, server, delta_r_deg, delta_t_m, n_total=n_total, local_up=ups[0], scene_up=ups[1])
    return align(local, server, delta_r_deg, delta_t_m, n_total=n_total)


def takes_up_directions(aligner: str) -> bool:
    """Whether the registered aligner ``aligner`` takes the ``local_up`` / ``scene_up`` keywords (``upright``)."""
    return "scene_up" in inspect.signature(get_aligner(aligner)).parameters
