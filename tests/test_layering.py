"""The package layers import downwards only: core/ below assets/, assets/ below scene/, scene/ below render/."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import synthleak

PACKAGE = Path(synthleak.__file__).parent


def imported_modules(path: Path) -> set[str]:
    """Absolute ``synthleak.*`` modules a file imports (module level and inside functions)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
    return {m for m in out if m.startswith("synthleak.")}


@pytest.mark.parametrize(
    ("layer", "forbidden"),
    [
        ("core", ("assets", "scene", "render", "localize", "attack", "evaluate", "study", "config", "cli")),
        ("scene", ("render", "localize", "attack", "evaluate", "study")),
        ("assets", ("scene",)),
    ],
)
def test_layer_imports_point_down(layer: str, forbidden: tuple[str, ...]) -> None:
    files = sorted((PACKAGE / layer).rglob("*.py"))
    assert files, layer
    upward = [
        f"{path.relative_to(PACKAGE)} imports {module}"
        for path in files
        for module in sorted(imported_modules(path))
        if module.split(".")[1] in forbidden
    ]
    assert upward == []


def test_the_check_sees_function_level_imports(tmp_path: Path) -> None:
    source = tmp_path / "m.py"
    source.write_text("def f():\n    from synthleak.render.base import Frame\n    import synthleak.scene.spec\n")
    assert imported_modules(source) == {"synthleak.render.base", "synthleak.scene.spec"}
