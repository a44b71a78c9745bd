"""Deterministic seeding: every random choice flows from one root seed.

An independent seed is derived per stage and item by hashing ``(root_seed, *keys)`` with SHA-256, so
adding an item never shifts the random stream of another. Never use numpy's global RNG.
"""

from __future__ import annotations

import hashlib

import numpy as np


def derive_seed(root_seed: int, *keys: object) -> int:
    """A 63-bit seed derived from ``root_seed`` and any hashable-as-text keys."""
    text = "/".join([str(int(root_seed)), *(str(k) for k in keys)])
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], "little") & ((1 << 63) - 1)


def make_rng(root_seed: int, *keys: object) -> np.random.Generator:
    """A numpy Generator seeded from ``derive_seed(root_seed, *keys)``."""
    return np.random.default_rng(derive_seed(root_seed, *keys))
