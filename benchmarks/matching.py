"""Milliseconds per matched image pair for the binary matcher's backends (and the float matcher beside them).

    python benchmarks/matching.py                       # ORB-, AKAZE- and SIFT-sized pairs, 2048 query keypoints
    python benchmarks/matching.py --query 2048 --map 900 --repeats 50
    python benchmarks/matching.py --docs docs/scaling.md   # also writes the table into the page's block

A localization matches its query against the top-k retrieved map images (40 by default), one pair each:
this is 50-80 % of a query's CPU time. Binary descriptors match through an exact +-1 product, as int8 through
``torch._int_mm`` or as float32 through BLAS (``synthleak.localize.matching.HAMMING_BACKENDS``); the table
gives both and checks that their matches are identical, and below it the backend ``auto`` chose on this machine
with its probe's timings. The threads are capped at 1, as in a study's workers. Random descriptors: the cost
depends on the sizes only.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from functools import partial

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402
from rich.console import Console  # noqa: E402
from rich.table import Table  # noqa: E402

from synthleak.localize.features import Features  # noqa: E402
from synthleak.localize.matching import (  # noqa: E402
    HAMMING_BACKEND_ENV,
    PROBE_SHAPE,
    TORCH_MARGIN,
    _backend_from_env,
    _match_binary,
    auto_backend,
    backend_products,
    match_features,
    probe_timings,
)
from synthleak.localize.tiers import Tier, get_tier  # noqa: E402

SIZES = {"orb": ("binary", 32), "akaze": ("binary", 61), "sift": ("float", 128)}
"""Tier: descriptor kind and bytes (binary) or floats per descriptor; the ratio test and mutual check are
the tier's own (``synthleak.localize.tiers``)."""


def _ms(fn: Callable[[], object], repeats: int) -> float:
    fn()  # warm-up (imports, allocations)
    start = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - start) / repeats * 1e3


def _binary(a: np.ndarray, b: np.ndarray, tier: Tier, backend: str) -> np.ndarray:
    return _match_binary(a, b, tier.ratio, tier.mutual, backend)


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--query", type=_positive, default=2048, help="query keypoints")
    parser.add_argument("--map", type=_positive, default=900, help="keypoints with a 3D point in the map image")
    parser.add_argument("--repeats", type=_positive, default=30)
    parser.add_argument("--docs", metavar="PAGE", help="write the table into PAGE's block 'matching'")
    args = parser.parse_args()
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:
        pass
    backends = list(backend_products())  # numpy, and torch where its _int_mm runs on CPU
    rng = np.random.default_rng(0)
    table = Table(title=f"ms per image pair: {args.query} query x {args.map} map descriptors, 1 thread")
    for column in ("tier", "backend", "ms / pair", "ms / query at top 40", "matches", "same matches"):
        table.add_column(column, justify="right")
    for name, (kind, width) in SIZES.items():
        tier = get_tier(name)
        if kind == "binary":
            a = rng.integers(0, 256, (args.query, width), dtype=np.uint8)
            b = np.concatenate([a[: args.map // 2], rng.integers(0, 256, (args.map - args.map // 2, width),
                                                                 dtype=np.uint8)])
            reference = None
            for backend in backends:
                run = partial(_binary, a, b, tier, backend)
                ms, matches = _ms(run, args.repeats), run()
                reference = matches if reference is None else reference
                table.add_row(name, backend, f"{ms:.2f}", f"{40 * ms:.0f}", str(len(matches)),
                              str(np.array_equal(matches, reference)))
        else:
            a = rng.random((args.query, width), dtype=np.float32)
            b = np.concatenate([a[: args.map // 2], rng.random((args.map - args.map // 2, width), np.float32)])
            query, image = (Features(np.zeros((len(d), 2)), d) for d in (a, b))
            ms = _ms(partial(match_features, query, image, tier.ratio, tier.mutual), args.repeats)
            table.add_row(name, "numpy (float32)", f"{ms:.2f}", f"{40 * ms:.0f}", "", "")
    console = Console()
    console.print(table)
    rows_a, rows_b, num_bytes = PROBE_SHAPE
    start = time.perf_counter()
    timings = probe_timings()
    probe_s = time.perf_counter() - start
    probe = ", ".join(f"{name} {seconds * 1e3:.3f} ms" for name, seconds in timings.items())
    source = f" (from {HAMMING_BACKEND_ENV})" if _backend_from_env() != "auto" else ""
    auto = (f"auto -> {auto_backend()}{source}; probe ({rows_a} x {rows_b} rows of {8 * num_bytes} bits, min "
            f"per product, {probe_s * 1e3:.0f} ms in all): {probe}; torch needs >= {TORCH_MARGIN}x numpy's speed")
    console.print(auto)
    if args.docs:
        from synthleak.evaluate.doc_blocks import rich_table_markdown, write_benchmark_block

        write_benchmark_block(args.docs, "matching", f"{table.title}:\n\n{rich_table_markdown(table)}\n\n{auto}")


if __name__ == "__main__":
    main()
