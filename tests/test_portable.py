"""Same seed, same bytes on any x86-64 CPU: the written output does not depend on the SIMD path numpy and
OpenBLAS take. One machine checks it by forcing numpy's baseline code (``NPY_DISABLE_CPU_FEATURES``: every
dispatched feature off, as on an older CPU) and another OpenBLAS kernel (``OPENBLAS_CORETYPE``) in a
subprocess, then comparing file hashes with the default path (``docs/determinism.md``)."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from synthleak.portable import POSE_STEP, simd_fallback_env, snap, snap_pose

DATA = Path(__file__).parent / "data"


def _hashes(folder: Path, root: Path | None = None) -> dict[str, str]:
    """sha256 per file below ``folder``; with ``root``, its path inside a file (map.json names its dataset)
    is replaced first, so two study folders compare by content."""
    def digest(path: Path) -> str:
        data = path.read_bytes()
        if root is not None:
            data = data.replace(str(root).encode(), b"ROOT")
        return hashlib.sha256(data).hexdigest()

    return {p.relative_to(folder).as_posix(): digest(p) for p in sorted(folder.rglob("*")) if p.is_file()}


def _run(code: str, env: dict[str, str] | None = None, timeout: float = 600) -> None:
    """Run ``code`` in a fresh interpreter (numpy reads its dispatch variables at import)."""
    full_env = {**os.environ, **(env or {})}
    done = subprocess.run([sys.executable, "-c", code], env=full_env, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, done.stderr[-3000:]


# ------------------------------------------------------------------------------------------ snapping


def test_snap_rounds_to_the_grid_and_drops_negative_zero():
    values = np.array([4.562422e-18, -4.5e-18, 0.1234564, 1.0 - 1e-12, -2.5e-7])
    out = snap(values, 1e-6)
    assert out.tolist() == [0.0, 0.0, 0.123456, 1.0, 0.0]
    assert not np.signbit(out).any()  # -2.5e-7 rounds to -0.0, written as 0.0
    # last-bit differences (what another SIMD path gives) land on the same grid value
    noisy = values * (1 + np.array([1, -1, 1, -1, 1]) * 2.0 ** -52)
    assert (snap(noisy, 1e-6) == out).all()


def test_snap_pose_keeps_a_rigid_pose():
    angle = 0.3
    pose = np.eye(4)
    pose[:2, :2] = [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
    pose[:3, 3] = [1.23456789012, -2.0, 1e-17]
    snapped = snap_pose(pose)
    assert np.abs(snapped - pose).max() <= POSE_STEP / 2
    assert snapped[3].tolist() == [0.0, 0.0, 0.0, 1.0] and snapped[2, 3] == 0.0


def test_the_fallback_env_turns_numpys_dispatch_off():
    env = simd_fallback_env()
    code = ("import numpy as np, json; from numpy._core import _multiarray_umath as m; "
            "print(json.dumps([k for k in m.__cpu_dispatch__ if m.__cpu_features__.get(k)]))")
    done = subprocess.run([sys.executable, "-c", code], env={**os.environ, **env}, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout) == []  # only the baseline is left
    assert env["OPENBLAS_CORETYPE"]


# ------------------------------------------------------------------------------------------ captures

CAPTURE = """
import hashlib, json, sys
import numpy as np
from synthleak.render.capture import capture
from synthleak.render.devices import draw_device
rng = np.random.default_rng(4)
linear = (rng.random((90, 120, 3)) ** 2 * 1.5).astype(np.float32)
depth = (1.0 + 3.0 * rng.random((90, 120))).astype(np.float32)
out = {}
for name in ("phone", "web-photo", "phone-low-light"):
    for seed in (1, 2):
        params = draw_device(name, seed)
        photo = capture(linear, params, seed, depth=depth)
        digest = hashlib.sha256(photo.rgb.tobytes()).hexdigest()
        out[f"{name}/{seed}"] = [digest, json.dumps(photo.record, sort_keys=True)]
json.dump(out, open(sys.argv[1], "w"))
"""


def test_photographs_are_the_same_bytes_on_an_older_cpu(tmp_path):
    """The capture model (exposure metering, colour matrices, noise, demosaic, white balance, tone curve, JPEG,
    defocus, vignetting) gives the same photo and record bytes with numpy's, OpenCV's and OpenBLAS's SIMD
    paths off: auto-exposure metered by a BLAS product gave another ISO in the 7th digit, so other photos."""
    script = tmp_path / "capture.py"
    script.write_text(CAPTURE)
    for name, env in (("default", None), ("fallback", simd_fallback_env(opencv_baseline=True))):
        done = subprocess.run([sys.executable, str(script), str(tmp_path / f"{name}.json")],
                              env={**os.environ, **(env or {})}, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-3000:]
    default = json.loads((tmp_path / "default.json").read_text())
    fallback = json.loads((tmp_path / "fallback.json").read_text())
    assert len(default) == 6
    for key in default:
        assert default[key][1] == fallback[key][1], key  # ISO, gains, noise: the same floats
        assert default[key][0] == fallback[key][0], key  # and the same pixels


# ------------------------------------------------------------------------------------------ stages


STAGES = """
import sys
from pathlib import Path
from synthleak.config import load_config
from synthleak.scene.generate import write_study_stages
write_study_stages(load_config("ci-tiny"), Path(sys.argv[1]) if len(sys.argv) > 1 else Path({out!r}), progress=False)
"""


def test_stages_are_the_same_bytes_on_the_baseline_simd_path(tmp_path):
    """The hard-world ci-tiny stages (meshes with sin/cos profiles, rotated parts, placements): the default
    dispatch and numpy's baseline with another OpenBLAS kernel write the same files."""
    default, fallback = tmp_path / "default", tmp_path / "fallback"
    _run(STAGES.format(out=str(default)))
    _run(STAGES.format(out=str(fallback)), simd_fallback_env())
    assert _hashes(default) == _hashes(fallback)


CLEAN_STAGES = """
import dataclasses, json
from pathlib import Path
from synthleak.config import load_config
from synthleak.scene.generate import write_study_stages
expected = json.loads(Path({data!r}).read_text())
config = load_config("ci-tiny")
config = dataclasses.replace(config, scenes=dataclasses.replace(
    config.scenes, models=expected["models"], material_sharing=0.0, distractors=(0, 0), clutter=0.0,
    layout="scatter"))
write_study_stages(config, Path({out!r}), progress=False)
"""


def test_pinned_stage_hashes_hold_on_the_baseline_simd_path(tmp_path):
    """The hashes ``test_hard_world.py`` pins (measured on an AVX-512 host) with numpy's baseline code and
    another OpenBLAS kernel, as on an AVX2 host."""
    expected = json.loads((DATA / "ci-tiny-clean-stages.json").read_text())
    _run(CLEAN_STAGES.format(data=str(DATA / "ci-tiny-clean-stages.json"), out=str(tmp_path)), simd_fallback_env())
    assert _hashes(tmp_path) == expected["files"]


# ------------------------------------------------------------------------------------------ the study


STUDY = """
from pathlib import Path
from synthleak.config import load_config
from synthleak.study import run_study
run_study(load_config("ci-tiny"), Path({out!r}), progress=False)
"""

SEEDED_OUTPUTS = ("dataset", "maps", "queries", "results")
"""Study folders whose bytes the seed alone decides (timings and the report's machine line excepted)."""


@pytest.mark.slow
def test_a_study_gives_the_same_bytes_on_the_baseline_simd_path(ci_tiny_study, tmp_path):
    """ci-tiny end to end (stages, mitsuba renders, SIFT features, maps with their vocabulary, PnP queries,
    attack results) on numpy's baseline path with another OpenBLAS kernel: the same files as the session's
    ci-tiny study on the default path."""
    _run(STUDY.format(out=str(tmp_path)), simd_fallback_env(), timeout=1800)
    for name in SEEDED_OUTPUTS:
        if not (ci_tiny_study / name).exists():
            continue
        assert _hashes(tmp_path / name, tmp_path) == _hashes(ci_tiny_study / name, ci_tiny_study), name
