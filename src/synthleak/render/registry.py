"""Render backends by name: ``get_renderer(config)``. Adding a backend is a module with a factory
``create_<name>_renderer(config) -> Renderer`` and one :func:`register_renderer` line here (``[render]
renderer`` in a config is checked against these names; ``docs/ARCHITECTURE.md``)."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from synthleak.errors import SynthleakError
from synthleak.plugins import resolve
from synthleak.render.base import Renderer

if TYPE_CHECKING:  # config validation reads this registry: no import of config at run time
    from synthleak.config import RenderConfig

RendererFactory = Callable[["RenderConfig"], Renderer]

INTEGRATORS = ("direct", "path")
"""``render.integrator``: direct lighting only, or a path tracer of ``max_depth`` (mitsuba, Blender)."""
FILTERS = ("box", "gaussian", "tent")
"""``render.filter``: mitsuba's pixel reconstruction filter."""
MITSUBA_VARIANTS = ("scalar_rgb", "llvm_ad_rgb")
"""``render.mitsuba_variant``: the mitsuba variants the backend supports (see ``mitsuba_backend``)."""

_FACTORIES: dict[str, RendererFactory | str] = {}
_INSTALL_HINTS: dict[str, str] = {}


class RendererUnavailable(SynthleakError, RuntimeError):
    """The requested backend is unknown or cannot be imported."""


def register_renderer(name: str, factory: RendererFactory | str, install_hint: str = "") -> None:
    """Make ``name`` available to :func:`get_renderer` (later registrations replace earlier ones).

    ``factory(config) -> Renderer``, or ``"package.module:function"``: the backend's module is imported only
    when the backend is asked for (:func:`synthleak.plugins.resolve`). ``install_hint`` is what the error
    says when it cannot be imported."""
    _FACTORIES[name] = factory
    if install_hint:
        _INSTALL_HINTS[name] = install_hint


register_renderer("mitsuba", "synthleak.render.mitsuba_backend:create_mitsuba_renderer",
                  "pip install 'mitsuba>=3.5' (variant scalar_rgb; llvm_ad_rgb also needs libLLVM >= 16)")
register_renderer("pyrender", "synthleak.render.pyrender_backend:create_pyrender_renderer",
                  "apt-get install libegl1 libgl1-mesa-dri; pip install -e '.[pyrender]'; PYOPENGL_PLATFORM=egl")
register_renderer("blender", "synthleak.render.blender_backend:create_blender_renderer",
                  "pip install -e '.[blender]' in a separate Python 3.11 venv (bpy pins numpy<2)")


def available_renderers() -> list[str]:
    """Registered backend names (registered does not guarantee importable)."""
    return sorted(_FACTORIES)


def get_renderer(config: RenderConfig) -> Renderer:
    """A fresh renderer for ``config.renderer``; a clear error for unknown or uninstalled backends."""
    name = config.renderer
    factory = _FACTORIES.get(name)
    if factory is None:
        raise RendererUnavailable(
            f"render.renderer: unknown backend {name!r}; available: {', '.join(available_renderers())}"
        )
    try:
        return resolve(factory)(config)
    except ImportError as exc:
        raise RendererUnavailable(
            f"render.renderer: backend {name!r} cannot run here ({exc}); install it with: "
            f"{_INSTALL_HINTS.get(name, 'see its documentation')}"
        ) from exc
