"""Every CLI command turns synthleak's errors into one line, `synthleak <cmd>: error: <file>: <field>: ...`, and a
non-zero exit status; no traceback. Run through the real CLI in a fresh process."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tiny_stages import write_config, write_cornell_box


def run_cli(*args: str, env: dict[str, str] | None = None, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "synthleak.cli", *args], capture_output=True, text=True,
                          env={**os.environ, **(env or {})}, cwd=cwd, timeout=300)


def assert_one_line_error(result: subprocess.CompletedProcess, command: str, *needles: str) -> str:
    """The process failed with exactly one stderr line naming ``needles``; returns that line."""
    assert result.returncode != 0, result
    assert "Traceback" not in result.stderr, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith(f"synthleak {command}: error: "), lines[0]
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def test_error_classes_share_one_base() -> None:
    from synthleak.config import ConfigError
    from synthleak.core.dataset import DatasetError
    from synthleak.core.usd_read import StageError as UsdStageError
    from synthleak.errors import StageError, SynthleakError
    from synthleak.executors import ExecutorError
    from synthleak.render.pipeline import StageError as PipelineStageError
    from synthleak.render.registry import RendererUnavailable
    from synthleak.scene.placement import PlacementError

    for cls, builtin in ((ConfigError, ValueError), (StageError, ValueError), (RendererUnavailable, RuntimeError),
                         (ExecutorError, RuntimeError), (PlacementError, RuntimeError), (DatasetError, ValueError)):
        assert issubclass(cls, SynthleakError) and issubclass(cls, builtin), cls
    assert PipelineStageError is UsdStageError is StageError


def test_stage_errors_are_one_line(tmp_path: Path) -> None:
    config = write_config(tmp_path / "tiny.toml")
    empty = tmp_path / "empty"
    empty.mkdir()
    result = run_cli("render", str(config), "--stages", str(empty), "--out", str(tmp_path / "out"), "--quiet")
    assert_one_line_error(result, "render", str(empty))
    corrupt = tmp_path / "corrupt.usda"
    corrupt.write_text("#usda 1.0\nthis is not a stage\n")
    result = run_cli("render", str(config), "--stages", str(corrupt), "--out", str(tmp_path / "out2"), "--quiet")
    assert_one_line_error(result, "render", str(corrupt))


def test_renderer_unavailable_is_one_line(tmp_path: Path) -> None:
    """The LLVM variant with no usable libLLVM: RendererUnavailable naming the field, serially and from workers."""
    stage = write_cornell_box(tmp_path / "box.usda", light="sphere")
    config = write_config(tmp_path / "llvm.toml", mitsuba_variant="llvm_ad_rgb")
    env = {"DRJIT_LIBLLVM_PATH": str(tmp_path / "no-such-libLLVM.so")}
    result = run_cli("render", str(config), "--stages", str(stage), "--out", str(tmp_path / "out"), "--quiet", env=env)
    assert_one_line_error(result, "render", "render.renderer", "DRJIT_LIBLLVM_PATH")


@pytest.mark.parametrize("command", ["scenes", "generate", "study", "render"])
def test_config_errors_are_one_line_for_every_command(tmp_path: Path, command: str) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('extends = "ci-tiny"\n[localize]\ntiers = ["siftt"]\n')
    extra = ["--stages", str(tmp_path)] if command == "render" else []
    result = run_cli(command, str(bad), "--out", str(tmp_path / "out"), *extra, "--quiet")
    assert_one_line_error(result, command, str(bad), "localize.tiers[0]", "siftt")
    assert not (tmp_path / "out").exists()  # refused before any work


def test_executor_error_is_one_line(tmp_path: Path) -> None:
    """A task that fails in a worker process: ExecutorError, one line naming the task and the cause."""
    config = tmp_path / "one.toml"
    config.write_text('extends = "ci-tiny"\nname = "one"\n[scenes]\nrooms = 1\nobjects_per_room = [1, 1]\n'
                      '[render]\nwidth = 64\nheight = 48\nscene_frames = 4\nattacker_frames = 2\nquery_every = 2\n'
                      'mitsuba_variant = "llvm_ad_rgb"\n')
    env = {"DRJIT_LIBLLVM_PATH": str(tmp_path / "no-such-libLLVM.so")}
    result = run_cli("study", str(config), "--out", str(tmp_path / "study"), "--workers", "2", "--quiet", env=env)
    assert_one_line_error(result, "study", "failed", "RendererUnavailable", "DRJIT_LIBLLVM_PATH")
