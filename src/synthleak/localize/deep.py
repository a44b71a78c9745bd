"""torch/kornia tiers: ``kornia-sift`` and ``disk-lightglue``. Imported lazily; needs ``torch`` + ``kornia``.

Weights are never downloaded. ``disk-lightglue`` looks, in order, in an explicit ``weights_dir``,
``$SYNTHLEAK_WEIGHTS_DIR`` and ``torch.hub.get_dir()/checkpoints`` for

* DISK: ``depth-save.pth`` (``{"extractor": state_dict}`` as published, or a bare state_dict);
* LightGlue for DISK: ``disk_lightglue.pth`` (the LightGlue release file) or
  ``disk_lightglue_v0-1_arxiv-pth`` (the name kornia gives it in the torch hub cache).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from synthleak.errors import MissingDependencyError, SynthleakError
from synthleak.localize.features import Features

DISK_FILES = ("depth-save.pth",)
LIGHTGLUE_FILES = ("disk_lightglue.pth", "disk_lightglue_v0-1_arxiv-pth")
WEIGHTS_ENV = "SYNTHLEAK_WEIGHTS_DIR"
DISK_URL = "https://raw.githubusercontent.com/cvlab-epfl/disk/master/depth-save.pth"
LIGHTGLUE_URL = "https://github.com/cvg/LightGlue/releases/download/v0.1_arxiv/disk_lightglue.pth"


class WeightsNotFoundError(SynthleakError, FileNotFoundError):
    """Network weights are not on disk; the message lists the paths tried and how to get the files."""


def _torch():
    try:
        import kornia  # noqa: F401
        import torch
    except ImportError as exc:
        raise MissingDependencyError(
            "the kornia-sift and disk-lightglue tiers need torch and kornia: "
            "pip install torch==2.13.0 kornia (CPU build)"
        ) from exc
    torch.set_num_threads(max(1, min(4, os.cpu_count() or 1)))
    return torch


def weight_dirs(weights_dir: Path | None = None) -> list[Path]:
    """Where weights are looked for, in order."""
    dirs = [Path(weights_dir)] if weights_dir is not None else []
    if os.environ.get(WEIGHTS_ENV):
        dirs.append(Path(os.environ[WEIGHTS_ENV]))
    torch = _torch()
    dirs.append(Path(torch.hub.get_dir()) / "checkpoints")
    return dirs


def find_weights(names: tuple[str, ...], what: str, url: str, weights_dir: Path | None = None) -> Path:
    """The first existing ``dir/name``; otherwise :class:`WeightsNotFoundError` naming every path tried."""
    tried = [d / n for d in weight_dirs(weights_dir) for n in names]
    for path in tried:
        if path.is_file():
            return path
    raise WeightsNotFoundError(
        f"{what} weights not found; looked for: {', '.join(str(p) for p in tried)}. "
        f"Download {url} on a machine with network access and save it as {tried[0].parent / names[0]} "
        f"(or set ${WEIGHTS_ENV} to the folder holding it). Weights are never downloaded automatically."
    )


def _image_tensor(rgb: np.ndarray, grey: bool):
    torch = _torch()
    img = torch.from_numpy(np.array(rgb, dtype=np.uint8, copy=True)).float().div(255.0).permute(2, 0, 1)[None]
    if grey:
        img = (0.299 * img[:, :1] + 0.587 * img[:, 1:2] + 0.114 * img[:, 2:3])
    return img


class KorniaSiftExtractor:
    """kornia's classical SIFT (DoG + SIFT descriptor)."""

    def __init__(self, max_keypoints: int) -> None:
        _torch()
        from kornia.feature import SIFTFeature

        self._model = SIFTFeature(num_features=int(max_keypoints), upright=False).eval()

    def __call__(self, rgb: np.ndarray) -> Features:
        torch = _torch()
        with torch.inference_mode():
            lafs, _, descs = self._model(_image_tensor(rgb, grey=True))
        # kornia pads to num_features with all-zero frames at (0, 0) when it finds fewer (a blank image: none)
        found = lafs[0, :, :, :2].abs().flatten(1).sum(1).numpy() > 0
        kp = lafs[0, :, :, 2].double().numpy()[found] + 0.5
        return Features(kp, descs[0].float().numpy()[found])


class KorniaDescriptorMatcher:
    """kornia ``DescriptorMatcher`` in ``smnn`` mode (mutual NN + ratio ``th``)."""

    def __init__(self, ratio: float) -> None:
        _torch()
        from kornia.feature import DescriptorMatcher

        self._matcher = DescriptorMatcher("smnn", float(ratio))

    def __call__(self, a: Features, b: Features) -> np.ndarray:
        torch = _torch()
        if len(a) < 2 or len(b) < 2:
            return np.zeros((0, 2), np.int64)
        with torch.inference_mode():
            _, idx = self._matcher(torch.from_numpy(a.descriptors), torch.from_numpy(b.descriptors))
        return idx.numpy().astype(np.int64).reshape(-1, 2)


def load_disk(weights_dir: Path | None = None):
    """kornia DISK with local weights (eval mode)."""
    torch = _torch()
    from kornia.feature import DISK

    path = find_weights(DISK_FILES, "DISK", DISK_URL, weights_dir)
    state = torch.load(path, map_location="cpu", weights_only=True)
    model = DISK()
    model.load_state_dict(state.get("extractor", state))
    return model.eval()


def load_lightglue(weights_dir: Path | None = None):
    """kornia LightGlue configured for DISK, with local weights (eval mode)."""
    torch = _torch()
    from kornia.feature import LightGlue

    path = find_weights(LIGHTGLUE_FILES, "LightGlue (DISK)", LIGHTGLUE_URL, weights_dir)
    state = torch.load(path, map_location="cpu", weights_only=True)
    model = LightGlue(features=None, input_dim=128, weights=None)
    for i in range(model.conf.n_layers):  # the release file uses LightGlue's original key names
        state = {k.replace(f"self_attn.{i}", f"transformers.{i}.self_attn")
                  .replace(f"cross_attn.{i}", f"transformers.{i}.cross_attn"): v for k, v in state.items()}
    missing = model.load_state_dict(state, strict=False).missing_keys
    learned = [k for k in missing if k in dict(model.named_parameters())]
    if learned:
        raise WeightsNotFoundError(f"{path}: not LightGlue-for-DISK weights (missing {learned[:3]} ...)")
    return model.eval()


class DiskExtractor:
    """kornia DISK keypoints + 128-D descriptors (the image is padded to a multiple of 16)."""

    def __init__(self, max_keypoints: int, weights_dir: Path | None = None) -> None:
        self.max_keypoints = int(max_keypoints)
        self._model = load_disk(weights_dir)

    def __call__(self, rgb: np.ndarray) -> Features:
        torch = _torch()
        with torch.inference_mode():
            image = _image_tensor(rgb, grey=False)
            feats = self._model(image, n=self.max_keypoints, pad_if_not_divisible=True)[0]
        h, w = rgb.shape[:2]
        kp = feats.keypoints.double().numpy()
        keep = (kp[:, 0] < w) & (kp[:, 1] < h)
        return Features(kp[keep] + 0.5, feats.descriptors.float().numpy()[keep], False,
                        feats.detection_scores.float().numpy()[keep], image_size=(w, h))


class LightGlueMatcher:
    """LightGlue on two DISK feature sets (uses their image sizes to normalise keypoints)."""

    def __init__(self, weights_dir: Path | None = None) -> None:
        self._model = load_lightglue(weights_dir)

    def __call__(self, a: Features, b: Features) -> np.ndarray:
        torch = _torch()
        if len(a) < 2 or len(b) < 2:
            return np.zeros((0, 2), np.int64)

        def side(f: Features) -> dict:
            return {"keypoints": torch.from_numpy(f.keypoints - 0.5).float()[None],
                    "descriptors": torch.from_numpy(f.descriptors).float()[None],
                    "image_size": torch.tensor([f.image_size], dtype=torch.float32)}

        with torch.inference_mode():
            out = self._model({"image0": side(a), "image1": side(b)})
        return out["matches"][0].numpy().astype(np.int64).reshape(-1, 2)
