"""Where the data folders that ship with synthleak live (repository checkout or installed wheel)."""

from __future__ import annotations

import os
from pathlib import Path

_REPO_ROOT = Path(__file__).resolve().parents[2]
_PACKAGE_DATA = Path(__file__).resolve().parent / "_data"


def _data_dir(name: str, env_var: str) -> Path:
    if os.environ.get(env_var):
        return Path(os.environ[env_var])
    for base in (_REPO_ROOT, _PACKAGE_DATA):
        if (base / name).is_dir():
            return base / name
    raise FileNotFoundError(f"cannot find the '{name}' folder (set {env_var})")


def object_library_dir() -> Path:
    """Folder with the model definitions (``object_library/*.toml``); override with SYNTHLEAK_OBJECT_LIBRARY."""
    return _data_dir("object_library", "SYNTHLEAK_OBJECT_LIBRARY")


def render_configs_dir() -> Path:
    """Folder with the study/render configs (``render_configs/*.toml``)."""
    return _data_dir("render_configs", "SYNTHLEAK_RENDER_CONFIGS")


def scenes_usd_dir() -> Path:
    """Folder with room templates and example stages."""
    return _data_dir("scenes_usd", "SYNTHLEAK_SCENES_USD")


def results_index_path() -> Path:
    """``docs/results/index.json`` beside ``render_configs/``: the measured cost of the presets (may be absent)."""
    return render_configs_dir().parent / "docs" / "results" / "index.json"
