"""Provenance of a study folder: ``<study>/run.json`` records each invocation of :func:`run_study` on it.

Each entry: when it ran, the source commit, the config and its content key, the machine (CPU model, cores),
the workers, the wall time and the seconds of each stage. A results page (:mod:`synthleak.evaluate.results_page`)
states where its figures came from with it; the wall time "from an empty folder" is the sum over the entries
(an interrupted and resumed study counts both parts). An invocation is recorded when it starts and updated after
each stage, so one that is killed keeps the stages it finished (``finished`` false); ``started_empty`` says
whether it found an empty folder. The file is outside ``results/``, whose bytes do not depend on the machine.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import synthleak
from synthleak.atomic_io import atomic_write_text
from synthleak.cache import cache_key
from synthleak.config import StudyConfig, config_to_dict

RUN_RECORD = "run.json"
"""The record's name inside a study folder."""


SIMD_FLAGS = {"avx512f": "AVX-512", "avx2": "AVX2", "avx512_vnni": "VNNI", "avx_vnni": "VNNI", "amx_int8": "AMX"}
"""``/proc/cpuinfo`` flags worth naming beside the model: those that pick other kernels (docs/determinism.md)."""


def cpu_model() -> str:
    """The CPU's model name, family/model numbers and SIMD level (``/proc/cpuinfo`` on Linux; e.g. ``Intel(R)
    Xeon(R) Processor (family 6 model 167; AVX-512, VNNI, AMX)``), else ``platform.processor()``."""
    try:
        fields: dict[str, str] = {}
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if not key.strip():
                break  # the first processor's block is enough
            fields.setdefault(key.strip(), value.strip())
    except OSError:
        fields = {}
    if "model name" not in fields:
        return platform.processor() or "unknown CPU"
    flags = set(fields.get("flags", "").split())
    simd = list(dict.fromkeys(name for flag, name in SIMD_FLAGS.items() if flag in flags))
    if "AVX-512" in simd and "AVX2" in simd:
        simd.remove("AVX2")
    numbers = f"family {fields.get('cpu family', '?')} model {fields.get('model', '?')}"
    return f"{' '.join(fields['model name'].split())} ({numbers}; {', '.join(simd) or 'no AVX2'})"


def source_commit() -> str | None:
    """The short commit of the git checkout synthleak runs from (``+dirty`` with uncommitted changes to tracked
    files), or None when it is not a checkout or git is missing."""
    root = Path(synthleak.__file__).resolve().parents[2]
    try:
        commit = subprocess.run(["git", "rev-parse", "--short=7", "HEAD"], cwd=root, capture_output=True,
                                text=True, timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return f"{commit}+dirty" if dirty else commit or None


def config_key(config: StudyConfig) -> str:
    """The config's content key: the first 12 hex digits of the SHA-256 of its canonical JSON."""
    return cache_key(config_to_dict(config))[:12]


def read_run_record(study: Path) -> list[dict[str, Any]]:
    """The invocations recorded in ``study/run.json``, oldest first ([] when there is none)."""
    path = Path(study) / RUN_RECORD
    if not path.is_file():
        return []
    try:
        runs = json.loads(path.read_text())["runs"]
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not a synthleak run record ({exc})") from exc
    return list(runs)


FOLDER_BOOKKEEPING = frozenset({RUN_RECORD, ".study.lock"})
"""Files that do not make a study folder non-empty."""


def start_run(study: Path, config: StudyConfig, workers: int, executor: str) -> int:
    """Record an invocation starting now in ``study/run.json`` (``finished`` false); returns its index there."""
    study = Path(study)
    empty = not any(p.name not in FOLDER_BOOKKEEPING for p in study.iterdir()) if study.is_dir() else True
    entry = {
        "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "wall_s": 0.0,
        "stage_s": {},
        "finished": False,
        "started_empty": empty,
        "commit": source_commit(),
        "version": synthleak.__version__,
        "config": config.name,
        "config_key": config_key(config),
        "config_dict": config_to_dict(config),
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "workers": workers,
        "executor": executor,
    }
    runs = [*read_run_record(study), entry]
    atomic_write_text(study / RUN_RECORD, json.dumps({"runs": runs}, indent=1) + "\n")
    return len(runs) - 1


def update_run(study: Path, index: int, started: float, timings: Mapping[str, float],
               finished: bool = False) -> dict[str, Any]:
    """Update entry ``index`` of ``study/run.json`` (``started``: the invocation's ``time.time()`` at start)
    with its wall time so far, its stage seconds and whether it finished; returns the entry."""
    runs = read_run_record(study)
    entry = runs[index]
    entry.update(wall_s=round(time.time() - started, 1), stage_s=dict(timings), finished=finished)
    atomic_write_text(Path(study) / RUN_RECORD, json.dumps({"runs": runs}, indent=1) + "\n")
    return entry
