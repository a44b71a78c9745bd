"""Map representations a localization server can store (``[localize] representation``).

* ``points``: the triangulated 3D points (``points.npz``, the COLMAP model in ``sfm/``), localized by RANSAC PnP;
* ``line-cloud``: each 3D point replaced by a 3D line through it with a uniformly random direction, the points
  never stored (Speciale et al., "Privacy Preserving Image-Based Localization", CVPR 2019), localized as a
  generalized relative pose problem (:mod:`synthleak.localize.line_cloud`);
* ``paired-point``: the points split into seeded random pairs, each pair replaced by the 3D line through both
  (Lee et al., "Paired-Point Lifting for Enhanced Privacy-Preserving Visual Localization", CVPR 2023), localized
  as a line cloud (:mod:`synthleak.localize.paired_points`).

Kept free of imports (the map store is imported when a map is read): the config validation reads
:func:`representation_names`.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from synthleak.localize.store import MapData

DEFAULT_REPRESENTATION = "points"

REPRESENTATIONS: dict[str, str] = {
    "points": "3D points + descriptors; RANSAC PnP (pycolmap)",
    "line-cloud": "random 3D lines through the points + descriptors (Speciale et al. CVPR 2019); RANSAC "
                  "generalized relative pose (p6L, PoseLib) + point-to-line refinement",
    "paired-point": "a 3D line through each random pair of points + both points' descriptors (Lee et al. CVPR "
                    "2023); solved as a line cloud",
}
"""The registered representations by name, with what each stores and solves, in words."""


def representation_names() -> list[str]:
    return list(REPRESENTATIONS)


def map_representation(meta: dict) -> str:
    """The representation a map was built with (``map.json``'s ``settings.representation``; absent: points)."""
    return meta.get("settings", {}).get("representation", DEFAULT_REPRESENTATION)


def read_represented_map(map_dir: Path, representation: str | list[str]) -> MapData:
    """The map at ``map_dir`` (:func:`~synthleak.localize.store.read_map`, or
    :func:`~synthleak.localize.line_cloud.read_line_map` for a line cloud). Raises :class:`MapError` when it was
    built under another representation than ``representation`` (a server's ``[localize] representation``, or
    one of a study's list of them)."""
    from synthleak.localize.store import MapError, read_map, read_map_meta

    map_dir = Path(map_dir)
    meta, _ = read_map_meta(map_dir)
    built = map_representation(meta)
    if built not in REPRESENTATIONS:
        raise MapError(f"{map_dir / 'map.json'}: field 'settings.representation' is {built!r} (known: "
                       f"{', '.join(REPRESENTATIONS)})")
    if built not in (representation if isinstance(representation, list | tuple) else [representation]):
        raise MapError(f"{map_dir / 'map.json'}: built with [localize] representation = {built!r}, but this "
                       f"server's config has representation = {representation!r}: serve it with a config of "
                       f"representation {built!r}, or rebuild the map")
    if built == "line-cloud":
        from synthleak.localize.line_cloud import read_line_map

        return read_line_map(map_dir)
    if built == "paired-point":
        from synthleak.localize.paired_points import read_paired_point_map

        return read_paired_point_map(map_dir)
    return read_map(map_dir)
