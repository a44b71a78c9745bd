"""Wall time, CPU time and peak memory per stage of a whole study (``synthleak study`` end to end).

    python benchmarks/study.py ci-tiny --out /tmp/bench-ci-tiny                      # cold run, serial
    python benchmarks/study.py study-small-pyrender --out /tmp/b --workers 2 --fresh
    python benchmarks/study.py ci-tiny --out /tmp/b --workers 2 --executor ray      # local Ray

Prints two tables (format kept stable so runs can be compared in notes): per stage, and per unit of work
(ms of wall and CPU time per rendered frame, map image, localization, matched pair)::

    stage        wall_s    cpu_s  peak_rss_mib
    stages          ...
    unit                   stage         count   wall_ms    cpu_ms
    rendered frame         render          ...

``--from-json FILE --out STUDY`` prints the tables of an earlier run again (from its ``--json`` file and folder).

``stages`` (USD stage writing) and ``render`` (frames + BOP extras + manifest) split the study's render
stage; ``maps`` is feature extraction + matching + triangulation of every (tier, room) map; ``features``
the query images' features (once per tier; absent in older synthleak, where ``queries`` includes them);
``queries`` the localization queries (retrieval, matching, PnP); ``attack`` alignment (Alg. 1 / robust)
and scoring; ``sweep`` the variant-magnitude sweep (renders, queries and attack of the swept attackers);
``report`` tables and plots. ``cpu_s`` is user + system time of this process and all its descendants, live
(read from /proc) or finished (Ray workers are not descendants of the driver and are not counted).
``peak_rss_mib`` is the largest sum of resident memory over this process and all its descendants,
sampled every 0.1 s.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import resource
import shutil
import threading
import time
from pathlib import Path

ROWS = ("stages", "render", "maps", "features", "queries", "attack", "sweep", "report")


def _tree_stats(root: int) -> tuple[int, float]:
    """(resident bytes, CPU seconds) of ``root`` and all its live descendants (Linux /proc)."""
    children: dict[int, list[int]] = {}
    rss: dict[int, int] = {}
    cpu: dict[int, float] = {}
    tick = os.sysconf("SC_CLK_TCK")
    page = os.sysconf("SC_PAGE_SIZE")
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            with open(f"/proc/{entry.name}/stat") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        pid = int(entry.name)
        children.setdefault(int(fields[1]), []).append(pid)  # fields[1]: ppid
        rss[pid] = int(fields[21]) * page  # fields[21]: rss in pages
        cpu[pid] = (int(fields[11]) + int(fields[12])) / tick  # utime, stime
    total, seconds, todo = 0, 0.0, [root]
    while todo:
        pid = todo.pop()
        total += rss.get(pid, 0)
        if pid != root:
            seconds += cpu.get(pid, 0.0)
        todo += children.get(pid, [])
    return total, seconds


def _tree_rss_bytes(root: int) -> int:
    return _tree_stats(root)[0]


class MemorySampler:
    """Background sampler of the process tree's resident memory; ``take_peak()`` returns and resets."""

    def __init__(self, interval_s: float = 0.1) -> None:
        self.interval_s, self._peak, self._overall = interval_s, 0, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            value = _tree_rss_bytes(os.getpid())
            self._peak, self._overall = max(self._peak, value), max(self._overall, value)
            self._stop.wait(self.interval_s)

    def __enter__(self) -> MemorySampler:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()

    def take_peak(self) -> int:
        value = max(self._peak, _tree_rss_bytes(os.getpid()))
        self._peak = 0
        return value

    @property
    def overall(self) -> int:
        return self._overall


class StageTimer:
    """Accumulates wall, CPU (self + reaped children) and peak memory per named row."""

    def __init__(self, sampler: MemorySampler) -> None:
        self.sampler = sampler
        self.rows: dict[str, dict[str, float]] = {}
        self._stack: list[str] = []

    @staticmethod
    def _cpu() -> float:
        kids = resource.getrusage(resource.RUSAGE_CHILDREN)  # finished (reaped) descendants
        return time.process_time() + kids.ru_utime + kids.ru_stime + _tree_stats(os.getpid())[1]

    def wrap(self, name: str, fn):
        timer = self

        def wrapped(*args, **kwargs):
            if timer._stack:  # nested inside another timed row (e.g. sweep renders): count it there only
                return fn(*args, **kwargs)
            timer._stack.append(name)
            timer.sampler.take_peak()
            wall, cpu = time.perf_counter(), timer._cpu()
            try:
                return fn(*args, **kwargs)
            finally:
                row = timer.rows.setdefault(name, {"wall_s": 0.0, "cpu_s": 0.0, "peak_rss_mib": 0.0})
                row["wall_s"] += time.perf_counter() - wall
                row["cpu_s"] += timer._cpu() - cpu
                row["peak_rss_mib"] = max(row["peak_rss_mib"], timer.sampler.take_peak() / 2**20)
                timer._stack.pop()

        return wrapped


def instrument(timer: StageTimer) -> None:
    """Wrap the study's stages: the ``run`` of each stage class (a study package of stages), or the stage
    functions (older synthleak: module attributes looked up at call time). A world sweep's stages count in
    their own rows; a variant sweep's in ``sweep``."""
    import synthleak.render.pipeline as pipeline
    import synthleak.scene.generate as generate
    import synthleak.study as study

    generate.write_study_stages = timer.wrap("stages", generate.write_study_stages)
    pipeline.render_stages = timer.wrap("render", pipeline.render_stages)
    if hasattr(study, "STAGE_TYPES"):
        for cls in study.STAGE_TYPES:
            if cls.name in ROWS and cls.name != "render":  # render: split into the two rows above
                cls.run = timer.wrap(cls.name, cls.run)
        return
    for row, attr in (("maps", "stage_maps"), ("features", "stage_features"), ("queries", "stage_queries"),
                      ("attack", "stage_attack"), ("sweep", "stage_sweep"), ("report", "stage_report")):
        if hasattr(study, attr):  # older synthleak had no features stage
            setattr(study, attr, timer.wrap(row, getattr(study, attr)))


def format_table(rows: dict[str, dict[str, float]], total: dict[str, float]) -> str:
    lines = [f"{'stage':<10} {'wall_s':>9} {'cpu_s':>9} {'peak_rss_mib':>13}"]
    for name in ROWS:
        r = rows.get(name, {"wall_s": 0.0, "cpu_s": 0.0, "peak_rss_mib": 0.0})
        lines.append(f"{name:<10} {r['wall_s']:>9.1f} {r['cpu_s']:>9.1f} {r['peak_rss_mib']:>13.0f}")
    lines.append(f"{'total':<10} {total['wall_s']:>9.1f} {total['cpu_s']:>9.1f} {total['peak_rss_mib']:>13.0f}")
    return "\n".join(lines)


def unit_counts(out: Path) -> dict[str, int]:
    """How much work a finished study folder holds: frames rendered, map images (per tier and room, and per
    server), query images whose features were extracted, localizations and (query, map image) pairs matched."""
    frames = sum(1 for _ in out.glob("dataset/*/*/images/*.png"))
    tier_images: dict[tuple[str, str], int] = {}
    server_images = 0
    for meta_path in out.glob("maps/*/*/map.json"):
        meta = json.loads(meta_path.read_text())
        server_images += int(meta["num_images"])
        tier_images[(str(meta["tier"]), meta_path.parent.name)] = int(meta["num_images"])
    features = sum(1 for _ in out.glob("features/*/**/*.npz"))
    localizations = pairs = 0
    for log in out.glob("queries/*/*/queries.jsonl"):
        for line in log.read_text().splitlines():
            if line.strip():
                localizations += 1
                pairs += len(json.loads(line).get("retrieved", []))
    return {"frames": frames, "map_images_tier": sum(tier_images.values()), "map_images_server": server_images,
            "query_features": features, "localizations": localizations, "pairs": pairs}


UNITS = (("render", "frames", "rendered frame"), ("maps", "map_images_tier", "map image x tier"),
         ("maps", "map_images_server", "map image x server"), ("features", "query_features", "query image x tier"),
         ("queries", "localizations", "localization x server"), ("queries", "pairs", "matched pair"))
"""Unit-cost rows: the stage whose time is divided, the count it is divided by, the unit's name."""


def format_units(rows: dict[str, dict[str, float]], counts: dict[str, int]) -> str:
    """ms of wall and CPU time per unit of work (a stage's time over its count: comparable across commits that
    do the same work)."""
    lines = [f"{'unit':<22} {'stage':<9} {'count':>9} {'wall_ms':>9} {'cpu_ms':>9}"]
    for stage, key, unit in UNITS:
        r, n = rows.get(stage, {"wall_s": 0.0, "cpu_s": 0.0}), counts.get(key, 0)
        wall, cpu = (1e3 * r["wall_s"] / n, 1e3 * r["cpu_s"] / n) if n else (float("nan"), float("nan"))
        lines.append(f"{unit:<22} {stage:<9} {n:>9} {wall:>9.1f} {cpu:>9.1f}")
    return "\n".join(lines)


def cpu_model() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines() if Path("/proc/cpuinfo").is_file() else []:
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "unknown CPU"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("config", help="study config name or path (e.g. ci-tiny, study-small-pyrender)")
    parser.add_argument("--out", required=True, type=Path, help="study output folder")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--executor", default="local", choices=("local", "ray"))
    parser.add_argument("--address", default=None, help="Ray address (default: start a local Ray)")
    parser.add_argument("--fresh", action="store_true", help="delete --out first (a cold run)")
    parser.add_argument("--force", nargs="*", default=[], help="stages to redo")
    parser.add_argument("--json", type=Path, help="also write the figures as JSON here")
    parser.add_argument("--from-json", type=Path,
                        help="print the tables of an earlier run (its --json file; --out its study folder) instead")
    args = parser.parse_args()
    if args.from_json:
        saved = json.loads(args.from_json.read_text())
        print(f"# benchmarks/study.py {saved['config']} workers={saved['workers']} executor={saved['executor']} "
              f"(from {args.from_json})")
        print(format_table(saved["rows"], saved["total"]))
        print(format_units(saved["rows"], unit_counts(args.out)))
        return

    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    from synthleak.config import load_config
    from synthleak.errors import SynthleakError
    from synthleak.study import run_study

    try:  # before --fresh deletes anything: a misspelt config name costs no earlier run
        config = load_config(args.config)
    except SynthleakError as exc:
        parser.error(str(exc))
    if args.fresh and args.out.exists():
        shutil.rmtree(args.out)
    kwargs = {"force": args.force, "progress": False, "workers": args.workers}
    if "executor" in inspect.signature(run_study).parameters:  # older run_study had no executors
        kwargs |= {"executor": args.executor, "address": args.address}
    elif args.executor != "local":
        raise SystemExit("this synthleak has no --executor support")
    with MemorySampler() as sampler:
        timer = StageTimer(sampler)
        instrument(timer)
        wall, cpu = time.perf_counter(), timer._cpu()
        run_study(config, args.out, **kwargs)
        total = {"wall_s": time.perf_counter() - wall, "cpu_s": timer._cpu() - cpu,
                 "peak_rss_mib": max(sampler.overall, sampler.take_peak()) / 2**20}
    print(f"# benchmarks/study.py {config.name} workers={args.workers} executor={args.executor} "
          f"cpus={os.cpu_count()}")
    print(f"# {cpu_model()}")
    print(format_table(timer.rows, total))
    print(format_units(timer.rows, unit_counts(args.out)))
    if args.json:
        args.json.write_text(json.dumps({"config": config.name, "workers": args.workers, "executor": args.executor,
                                         "cpu": cpu_model(), "rows": timer.rows, "total": total,
                                         "units": unit_counts(args.out)}, indent=1))


if __name__ == "__main__":
    main()
