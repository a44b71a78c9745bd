"""Render backends by name: ``get_renderer(config)``; other backends register themselves here."""

from __future__ import annotations

import importlib
from collections.abc import Callable

from synthleak.config import RenderConfig
from synthleak.errors import SynthleakError
from synthleak.render.base import Renderer

RendererFactory = Callable[[RenderConfig], Renderer]

INTEGRATORS = ("direct", "path")
"""``render.integrator``: direct lighting only, or a path tracer of ``max_depth`` (mitsuba, Blender)."""
FILTERS = ("box", "gaussian", "tent")
"""``render.filter``: mitsuba's pixel reconstruction filter."""
MITSUBA_VARIANTS = ("scalar_rgb", "llvm_ad_rgb")
"""``render.mitsuba_variant``: the mitsuba variants the backend supports (see ``mitsuba_backend``)."""

_FACTORIES: dict[str, RendererFactory] = {}
_INSTALL_HINTS: dict[str, str] = {
    "mitsuba": "pip install 'mitsuba>=3.5' (variant scalar_rgb; llvm_ad_rgb also needs libLLVM >= 16)",
    "pyrender": "apt-get install libegl1 libgl1-mesa-dri; pip install -e '.[pyrender]'; PYOPENGL_PLATFORM=egl",
    "blender": "pip install -e '.[blender]' in a separate Python 3.11 venv (bpy pins numpy<2)",
}


class RendererUnavailable(SynthleakError, RuntimeError):
    """The requested backend is unknown or cannot be imported."""


def register_renderer(name: str, factory: RendererFactory, install_hint: str = "") -> None:
    """Make ``name`` available to :func:`get_renderer` (later registrations replace earlier ones)."""
    _FACTORIES[name] = factory
    if install_hint:
        _INSTALL_HINTS[name] = install_hint


def _lazy(module: str, factory: str) -> RendererFactory:
    """A factory that imports ``module`` only when the backend is asked for."""

    def create(config: RenderConfig) -> Renderer:
        return getattr(importlib.import_module(module), factory)(config)

    return create


def _mitsuba(config: RenderConfig) -> Renderer:
    from synthleak.render.mitsuba_backend import MitsubaRenderer

    return MitsubaRenderer(
        spp=config.spp,
        integrator=config.integrator,
        max_depth=config.max_depth,
        filter=config.filter,
        variant=config.mitsuba_variant,
    )


register_renderer("mitsuba", _mitsuba)
register_renderer("pyrender", _lazy("synthleak.render.pyrender_backend", "create_pyrender_renderer"))
register_renderer("blender", _lazy("synthleak.render.blender_backend", "create_blender_renderer"))


def available_renderers() -> list[str]:
    """Registered backend names (registered does not guarantee importable)."""
    return sorted(_FACTORIES)


def get_renderer(config: RenderConfig) -> Renderer:
    """A fresh renderer for ``config.renderer``; a clear error for unknown or uninstalled backends."""
    name = config.renderer
    factory = _FACTORIES.get(name)
    if factory is None:
        hint = _INSTALL_HINTS.get(name)
        extra = f" (not yet available in this version; it would need: {hint})" if hint else ""
        raise RendererUnavailable(
            f"render.renderer: unknown backend {name!r}{extra}; available: {', '.join(available_renderers())}"
        )
    try:
        return factory(config)
    except ImportError as exc:
        raise RendererUnavailable(
            f"render.renderer: backend {name!r} cannot run here ({exc}); install it with: "
            f"{_INSTALL_HINTS.get(name, 'see its documentation')}"
        ) from exc
