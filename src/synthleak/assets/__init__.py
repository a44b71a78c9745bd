"""Object library: procedural textures, textured primitives, parametric furniture models and their variants.

Modules: :mod:`.mesh` (shared types), :mod:`.textures`, :mod:`.primitives`, :mod:`.builders`,
:mod:`.library` (``ObjectModel``, ``load_library``, ``get_model``), :mod:`.variants` (``variant``),
:mod:`.catalog` (listing). Conventions are in ``object_library/README.md``.
"""
