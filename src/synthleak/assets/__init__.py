"""Object library: procedural textures, textured primitives, parametric furniture models and their variants.

Modules, bottom up: :mod:`.mesh` (shared types), :mod:`.textures`, :mod:`.primitives`, :mod:`.model`
(``ObjectModel``, its typed material slots, the builder registry), :mod:`.materials` (shared SKUs),
:mod:`.builders` (the parametric builders and ``imported``; :mod:`.import_store` holds the imported files),
:mod:`.library` (``load_library``, ``get_model``, ``build_model``), :mod:`.variants` (``variant``),
:mod:`.catalog` (listing), :mod:`.importer` (``synthleak import``). Conventions are in ``object_library/README.md``.
"""
