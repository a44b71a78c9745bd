"""Library listing for ``synthleak objects [--json]``: JSON rows, table cells and a rich table."""

from __future__ import annotations

from typing import Any

from rich.table import Table

from synthleak.assets.model import MaterialSpec, ObjectModel
from synthleak.listing import rows_table


def objects_rows(library: dict[str, ObjectModel]) -> list[dict[str, Any]]:
    """One JSON-serialisable row per model, sorted by id."""
    rows = []
    for mid in sorted(library):
        m = library[mid]
        rows.append(
            {
                "id": m.model_id,
                "category": m.category,
                "role": m.role,
                "size": [round(s, 4) for s in m.size],
                "symmetry": m.symmetry,
                "support": m.support,
                "builder": m.builder,
                "params": {
                    k: {"default": r.default, "min": r.min, "max": r.max, "integer": r.integer}
                    for k, r in sorted(m.params.items())
                },
                "scale_range": list(m.scale_range),
                "colour_range": list(m.colour_range),
                # procedural textures name their kind; an imported model's parts carry image files
                "textures": {
                    k: v.kind if isinstance(v, MaterialSpec) else "imported" for k, v in sorted(m.textures.items())
                },
                "source": m.source,
            }
        )
    return rows


def _fmt(v: float, integer: bool) -> str:
    return str(int(v)) if integer else f"{v:g}"


OBJECTS_COLUMNS = ("id", "category", "role", "size x,y,z (m)", "sym", "support",
                   "shape params [min..max] (default)", "scale", "textures")
"""The columns of ``synthleak objects`` (table and tab-separated output)."""


def objects_title(library: dict[str, ObjectModel]) -> str:
    """The listing's title: how many models, furniture, props and categories."""
    n_props = sum(m.role == "prop" for m in library.values())
    return (f"object library ({len(library)} models: {len(library) - n_props} furniture, {n_props} props; "
            f"{len({m.category for m in library.values()})} categories)")


def objects_cells(library: dict[str, ObjectModel]) -> list[list[str]]:
    """One row of :data:`OBJECTS_COLUMNS` per model, sorted by id (shape parameters one per line)."""
    cells = []
    for row in objects_rows(library):
        params = "\n".join(
            f"{k} [{_fmt(p['min'], p['integer'])}..{_fmt(p['max'], p['integer'])}] "
            f"({_fmt(p['default'], p['integer'])})"
            for k, p in row["params"].items()
        )
        cells.append([
            row["id"],
            row["category"],
            row["role"],
            " x ".join(f"{s:.2f}" for s in row["size"]),
            row["symmetry"],
            row["support"],
            params or "-",
            f"{row['scale_range'][0]:g}..{row['scale_range'][1]:g}",
            ", ".join(sorted(set(row["textures"].values()))),
        ])
    return cells


def objects_table(library: dict[str, ObjectModel]) -> Table:
    """A rich table of the library (id, category, role, size, symmetry, support, parameter and scale ranges)."""
    return rows_table(OBJECTS_COLUMNS, objects_cells(library), objects_title(library))
