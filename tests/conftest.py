"""Shared fixtures: one tiny end-to-end study, run once per test session and reused read-only."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import synthleak  # noqa: F401  (pins torch's numerics before a test module imports torch or kornia)

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


@pytest.fixture(scope="session")
def ci_tiny_study(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The `ci-tiny` study (stages, renders, maps, queries, attack, report) in a session temp folder.

    Tests must not modify it; copy it (``shutil.copytree``) to change anything."""
    from synthleak.config import load_config
    from synthleak.study import run_study

    out = tmp_path_factory.mktemp("ci_tiny_study")
    run_study(load_config("ci-tiny"), out, progress=False)
    return out
