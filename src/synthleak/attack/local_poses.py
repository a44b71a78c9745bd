"""The attacker's local poses of one orbit from the configured source (``attack.local_model``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from synthleak.attack.local_model import SfmLocalModel, cached_sfm_local_poses, oracle_local_poses

LOCAL_MODELS = ("oracle", "sfm")
"""``attack.local_model``: the attacker's local poses from ground truth, or from pycolmap SfM."""


def sfm_model(seq: Any, workdir: Path, seed: int) -> SfmLocalModel:
    """The attacker's SfM of its orbit ``seq`` (built once, then read from ``workdir``)."""
    target = seq.objects_by_id()[seq.target_instance_id]
    return cached_sfm_local_poses(seq, target.extents, workdir, seed=seed)


def attacker_local_poses(local_model: str, seq: Any, sfm_dir: Path, seed: int
                         ) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    """The attacker's local poses (``cam_from_object`` / ``cam_from_local``) and, for SfM (its workspace:
    ``sfm_dir``), the scoring-only ``object_from_local``."""
    if local_model == "oracle":
        return oracle_local_poses(seq), None
    if local_model == "sfm":
        model = sfm_model(seq, sfm_dir, seed)
        return dict(model.cam_from_local), model.object_from_local
    raise ValueError(f"attack.local_model: unknown value {local_model!r} ({', '.join(LOCAL_MODELS)})")
