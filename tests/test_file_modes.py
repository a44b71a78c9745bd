"""Written files get the mode the umask gives (a shared file system's other users can read a dataset), not the
0600 of the temporary files they were renamed from."""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest

from synthleak.atomic_io import atomic_write_bytes, atomic_write_text
from tiny_stages import write_cornell_box


@pytest.fixture(params=[0o022, 0o027])
def umask(request) -> Iterator[int]:
    before = os.umask(request.param)
    try:
        yield request.param
    finally:
        os.umask(before)


def _modes(root: Path) -> dict[str, int]:
    return {p.relative_to(root).as_posix(): stat.S_IMODE(p.stat().st_mode) for p in sorted(root.rglob("*"))}


def test_atomic_writes_follow_the_umask(tmp_path: Path, umask: int) -> None:
    atomic_write_bytes(tmp_path / "a.bin", b"x")
    atomic_write_text(tmp_path / "sub" / "b.txt", "y")
    assert _modes(tmp_path) == {"a.bin": 0o666 & ~umask, "sub": 0o777 & ~umask, "sub/b.txt": 0o666 & ~umask}
    atomic_write_bytes(tmp_path / "a.bin", b"again")  # a replaced file too
    assert stat.S_IMODE((tmp_path / "a.bin").stat().st_mode) == 0o666 & ~umask


def test_a_rendered_sequence_and_an_imported_model_are_readable_by_others(tmp_path: Path, umask: int) -> None:
    from synthleak.assets.importer import import_model
    from synthleak.config import RenderConfig, StudyConfig
    from synthleak.render.pipeline import render_sequence, write_manifest
    from test_import import _export, _library

    config = StudyConfig(name="modes", render=RenderConfig(width=32, height=24, spp=1, scene_frames=2, query_every=2))
    out = tmp_path / "dataset"
    render_sequence(write_cornell_box(tmp_path / "box.usda", light="sphere"), out / "scenes" / "box", config, "scene",
                    progress=False)
    write_manifest(out, config)
    lib = _library(tmp_path)
    import_model(_export(tmp_path, ".obj")[0], "chair", name="my_chair", up="y", front="-z", library_dir=lib)
    for root in (out, lib / "imported"):
        modes = _modes(root)
        assert len(modes) >= 4
        wrong = {name: oct(mode) for name, mode in modes.items()
                 if mode != (0o777 if (root / name).is_dir() else 0o666) & ~umask}
        assert not wrong, wrong
