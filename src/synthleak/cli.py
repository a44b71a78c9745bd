"""Command-line interface: a thin layer over the Python API (every command is one function call)."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from synthleak.errors import SynthleakError
from synthleak.interrupt import Stopped, received_stop_signal, signal_name, stop_on_signals


def _cmd_objects(args: argparse.Namespace) -> None:
    from synthleak.assets.catalog import OBJECTS_COLUMNS, objects_cells, objects_rows, objects_title
    from synthleak.assets.library import by_role, load_library
    from synthleak.listing import print_rows

    library = load_library()
    if args.role:
        library = by_role(library, args.role)
    print_rows(OBJECTS_COLUMNS, objects_cells(library), json_out=args.json, title=objects_title(library),
               records=objects_rows(library))


PRESETS_COLUMNS = ("name", "extends", "description", "renderer", "tiers", "measured cost")


def _cmd_presets(args: argparse.Namespace) -> int:
    """List the presets; one that does not load is listed, then named on stderr, and the exit status is 2."""
    import dataclasses

    from synthleak.config import list_presets
    from synthleak.listing import print_rows
    from synthleak.paths import render_configs_dir

    presets = list_presets()
    rows = [[p.name, p.extends, f"error: {p.error}" if p.error else p.description or None, p.renderer,
             p.tiers or None, str(p.cost) if p.cost else None] for p in presets]
    print_rows(PRESETS_COLUMNS, rows, json_out=args.json, title=f"{len(presets)} presets in {render_configs_dir()}",
               records=[dataclasses.asdict(p) for p in presets])
    sys.stdout.flush()  # the listing before the errors, where both go to one terminal
    for p in presets:
        if p.error:
            print(f"synthleak {args.command}: error: {p.error}", file=sys.stderr)
    return 2 if any(p.error for p in presets) else 0


TIERS_COLUMNS = ("name", "features / matcher", "matching", "min inliers", "max keypoints", "PnP px", "pip extra")


def _cmd_tiers(args: argparse.Namespace) -> None:
    from synthleak.listing import print_rows
    from synthleak.localize.tiers import list_tiers

    def matching(t: dict) -> str:
        if t["learned_matcher"]:
            return f"score > {t['match_threshold']:g}, top-k retrieved"
        ratio = f"ratio {t['ratio']:g}" if 0 < t["ratio"] < 1 else "no ratio test"
        return ratio + (", mutual" if t["mutual"] else "")

    tiers = list_tiers(args.profile)
    rows = [[t["name"], t["description"] or None, matching(t), t["min_inliers"], t["max_keypoints"] or None,
             t["pnp_max_error_px"], "learned" if t["needs_torch"] else None] for t in tiers]
    print_rows(TIERS_COLUMNS, rows, json_out=args.json,
               title=f"localization feature tiers (least to most robust), server profile {args.profile}",
               records=tiers)


def _cmd_scenes(args: argparse.Namespace) -> None:
    from synthleak.config import load_config
    from synthleak.scene.generate import write_study_stages

    out = write_study_stages(load_config(args.config), Path(args.out), progress=not args.quiet)
    print(f"stages written to {out}")


def _cmd_render(args: argparse.Namespace) -> None:
    from synthleak.config import load_config
    from synthleak.render.pipeline import render_stages, write_manifest

    config = load_config(args.config)
    out = render_stages(config, Path(args.stages), Path(args.out), progress=not args.quiet)
    write_manifest(Path(args.out), config)
    print(f"dataset written to {out}")


def _cmd_generate(args: argparse.Namespace) -> None:
    from synthleak.config import load_config
    from synthleak.render.pipeline import generate

    out = generate(load_config(args.config), Path(args.out), progress=not args.quiet)
    print(f"dataset written to {out}")


def _cmd_import(args: argparse.Namespace) -> None:
    from synthleak.assets.importer import import_model

    model = import_model(Path(args.file), args.category, name=args.name, up=args.up, front=args.front,
                         units=args.units, height=args.height, scale=args.scale, symmetry=args.symmetry,
                         support=args.support, overwrite=args.overwrite)
    size = ", ".join(f"{s:.3f}" for s in model.size)
    print(f"imported {model.model_id} ({model.category}, size {size} m) into {Path(model.source).parent}")


def _cmd_show(args: argparse.Namespace) -> None:
    target = Path(args.path)
    if target.suffix.lower() in (".usd", ".usda", ".usdc", ".usdz"):
        from synthleak.inspect import plan_view

        out = plan_view(target, Path(args.out), Path(args.dataset) if args.dataset else None)
    else:
        from synthleak.inspect import contact_sheet

        out = contact_sheet(target, Path(args.out), sequence=args.sequence, frames=args.frames)
    print(f"wrote {out}")


def _study_config(config_name: str | None):
    from synthleak.config import StudyConfig, load_config

    return load_config(config_name) if config_name else StudyConfig(name="default")


def _defense(args: argparse.Namespace):
    from synthleak.localize.defense import DefensePolicy

    defense = _study_config(args.config).defense
    if args.defense:
        return DefensePolicy(min_fraction=defense.min_fraction, min_instances=defense.min_instances, enabled=True)
    return DefensePolicy.from_config(defense)


def _cmd_map(args: argparse.Namespace) -> None:
    from synthleak.localize.mapping import build_map

    out = build_map(Path(args.scene), args.tier, Path(args.out), _study_config(args.config).localize,
                    progress=not args.quiet)
    print(f"map written to {out}")


def _cmd_serve(args: argparse.Namespace) -> None:
    import uvicorn.server

    from synthleak.localize.server import serve

    # uvicorn shuts down gracefully on SIGINT and SIGTERM, then raises the signal again for our handler; have it
    # treat SIGHUP alike (raised inside its event loop, Stopped would end it with a traceback of the lifespan task)
    if hasattr(signal, "SIGHUP") and signal.SIGHUP not in uvicorn.server.HANDLED_SIGNALS:
        uvicorn.server.HANDLED_SIGNALS = (*uvicorn.server.HANDLED_SIGNALS, signal.SIGHUP)

    serve(Path(args.map), host=args.host, port=args.port, config=_study_config(args.config).localize,
          defense=_defense(args), decision_log=Path(args.decision_log) if args.decision_log else None,
          workers=args.workers)


def _cmd_export_maps(args: argparse.Namespace) -> None:
    from synthleak.study.export import export_maps

    print(f"wrote {export_maps(Path(args.study), Path(args.out), depth=not args.no_depth)}")


def _cmd_localize(args: argparse.Namespace) -> None:
    from synthleak.localize.images import InvalidImageError
    from synthleak.localize.localizer import Localizer
    from synthleak.localize.server import response_from_result

    localizer = Localizer.load(Path(args.map), _study_config(args.config).localize, defense=_defense(args))
    refused = []
    for image in args.images:
        try:
            result = localizer.localize(Path(image).read_bytes())
        except InvalidImageError as exc:  # the server would answer 400/413: this image only, the batch goes on
            refused.append(image)
            print(json.dumps({"image": image, "success": False, "error": " ".join(str(exc).split())}))
            continue
        extra = {"num_inliers": result.num_inliers,
                 "inlier_instance_counts": {str(k): v for k, v in sorted(result.inlier_instance_counts.items())}}
        print(json.dumps({"image": image, **response_from_result(result), **(extra if args.verbose else {})}))
    if refused:
        raise InvalidImageError(f"{len(refused)} of {len(args.images)} images refused: {', '.join(refused)}")


def _cmd_study(args: argparse.Namespace) -> None:
    from synthleak import study
    from synthleak.config import load_config
    from synthleak.executors import usable_cpus

    report = study.run_study(load_config(args.config), Path(args.out), force=args.force or [],
                             server_url=args.server, progress=not args.quiet, workers=args.workers or usable_cpus(),
                             executor=args.executor, address=args.address)
    print(f"report written to {report}")


def _cmd_report(args: argparse.Namespace) -> None:
    from synthleak.evaluate.results_page import (
        HEADLINE_COLUMNS,
        results_summary,
        write_readme_presets,
        write_results_page,
    )
    from synthleak.listing import print_rows

    if args.readme and not args.docs:
        raise ValueError("--readme: needs --docs (the README's presets table reads the pages' index)")
    if args.docs:
        page = write_results_page(Path(args.study), Path(args.docs))
        print(f"wrote {page}, {page.with_suffix('.json').name}, {page.stem}/ and index.json", file=sys.stderr)
        if args.readme:
            write_readme_presets(Path(args.readme), page.parent / "index.json")
            print(f"updated the presets table of {args.readme}", file=sys.stderr)
        summary = json.loads(page.with_suffix(".json").read_text())  # the summary the page was written from
    else:
        summary = results_summary(Path(args.study))
    headline = summary["headline"]
    print_rows(HEADLINE_COLUMNS, [[r[c] for c in HEADLINE_COLUMNS] for r in headline], json_out=args.json,
               title=f"{summary['config']}: presence and placement at 10°/0.25 m ({summary['aligner']})",
               records=headline)


TIERS_HELP = "{tiers}"
"""Placeholder in a help text for the registered feature tiers (:func:`tiers_help`)."""


def tiers_help() -> str:
    """The registered feature tiers, for ``--tier``'s help (read from ``synthleak.localize.tiers``)."""
    from synthleak.localize.tiers import TIERS

    torch = [name for name, tier in TIERS.items() if tier.needs_torch]
    extra = f" ({', '.join(torch)}: the [learned] extra, see README)" if torch else ""
    return f"feature tier: {', '.join(TIERS)}{extra}; `synthleak tiers` describes them"


def version() -> str:
    """The installed distribution's version (``synthleak.__version__`` where synthleak is not installed)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as installed

    try:
        return installed("synthleak")
    except PackageNotFoundError:
        from synthleak import __version__

        return __version__


class _HelpFormatter(argparse.HelpFormatter):
    """Fills :data:`TIERS_HELP` in when help is printed, not when the parser is built (importing the tier
    registry imports the localization package: about a second)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = super()._get_help_string(action)
        return text.replace(TIERS_HELP, tiers_help()) if text and TIERS_HELP in text else text


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="synthleak", description=__doc__)
    parser.add_argument("--version", action="version", version=f"synthleak {version()}")
    sub = parser.add_subparsers(dest="command", required=True)

    def command(name: str, handler: Callable[[argparse.Namespace], int | None], help_text: str, more: str = ""):
        p = sub.add_parser(name, help=help_text, description=help_text + more, formatter_class=_HelpFormatter)
        p.set_defaults(handler=handler)
        p.add_argument("--quiet", action="store_true", help="no progress bars")
        return p

    listing = ("; a table on a terminal, else a header line and a line per row, tab-separated, values whole; "
               "--json: a JSON list, an object per row")
    p = command("objects", _cmd_objects, "list the object library's models", listing)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--role", choices=["furniture", "prop"], help="only the furniture or only the props")

    p = command("presets", _cmd_presets, "list the study configs of render_configs/ and their measured cost",
                f"{listing}. A config that does not load is listed with its error (exit status 2)")
    p.add_argument("--json", action="store_true", help="machine-readable output")

    p = command("tiers", _cmd_tiers, "list the localization feature tiers (map --tier, [localize] tiers)", listing)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--profile", default="strict", choices=("strict", "hloc"),
                   help="server profile ([localize] profile): strict, or hloc (HLoc's published defaults)")

    p = command("scenes", _cmd_scenes, "write the USD stages of a study (rooms + attacker setups)")
    p.add_argument("config", help="config path or name in render_configs/ (e.g. ci-tiny)")
    p.add_argument("--out", required=True, help="stages folder")

    p = command("render", _cmd_render, "render the sequences of already written stages")
    p.add_argument("config")
    p.add_argument("--stages", required=True,
                   help="folder written by `synthleak scenes`, a folder of USD stages, or one stage file")
    p.add_argument("--out", required=True, help="dataset folder")

    p = command("generate", _cmd_generate, "stages + renders in one go (resumable)")
    p.add_argument("config")
    p.add_argument("--out", required=True, help="dataset folder")

    p = command("import", _cmd_import, "add your own textured model (OBJ, GLB/glTF, PLY, USD/USDZ) to the library")
    p.add_argument("file")
    p.add_argument("--category", required=True)
    p.add_argument("--name", help="model id (default: from the file name)")
    p.add_argument("--up", default="z", choices=["z", "y", "+z", "+y", "-z", "-y", "x", "+x", "-x"],
                   help="the file's up axis")
    p.add_argument("--front", default=None,
                   help="the file's front axis (+y, +z, ...; negative: --front=-z); default: +z with --up y "
                        "(glTF faces +z), else +y")
    p.add_argument("--units", default="m", choices=["m", "cm", "mm", "in", "ft"])
    size = p.add_mutually_exclusive_group()
    size.add_argument("--height", type=float, help="scale uniformly to this height in metres")
    size.add_argument("--scale", type=float, help="uniform scale factor after unit conversion")
    p.add_argument("--symmetry", default="none", choices=["none", "2", "4", "z"])
    p.add_argument("--support", default="floor", choices=["floor", "wall", "ceiling", "surface"])
    p.add_argument("--overwrite", action="store_true", help="replace an imported model with the same id")

    p = command("show", _cmd_show, "contact sheet of a dataset, or a top-down plan of a USD stage")
    p.add_argument("path", help="a dataset / sequence folder, or a .usda stage")
    p.add_argument("--out", required=True, help="PNG to write")
    p.add_argument("--sequence", help="sequence inside the dataset, e.g. scenes/room_000")
    p.add_argument("--frames", type=int, default=4, help="frames sampled for the contact sheet")
    p.add_argument("--dataset", help="a sequence folder whose camera path the stage plan shows")

    p = command("map", _cmd_map, "build a localization map from a rendered scene sequence")
    p.add_argument("scene", help="a scene sequence folder, e.g. DATASET/scenes/room_000")
    p.add_argument("--tier", default="sift", help=TIERS_HELP)
    p.add_argument("--out", required=True, help="map folder")
    p.add_argument("--config", help="study config whose [localize] section to use")

    p = command("serve", _cmd_serve, "serve a map over HTTP on loopback (POST /localize, GET /health)",
                ". MAP may also be a folder of maps (a study's maps/, <server>/<room>/map.json): each is served at "
                "/<server>/<room>/localize and listed at GET /maps (docs/service-protocol.md)")
    p.add_argument("map", help="a map folder, or a folder of <server>/<room> maps (e.g. STUDY/maps)")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--config", help="study config whose [localize] and [defense] sections to use")
    p.add_argument("--defense", action="store_true", help="turn the query defense on (X, k from the config)")
    p.add_argument("--decision-log", help="JSONL file logging every defense decision with its counts")
    p.add_argument("--workers", type=int, default=None,
                   help="localizer processes answering queries in parallel (default: one per core, at most 8; "
                        "a folder of maps: this many per map, default 1)")

    p = command("export-maps", _cmd_export_maps,
                "write what an outside localization service needs to build a study's maps",
                ": per room the map frames' images, depth and COLMAP model with the ground-truth poses, and a "
                "manifest; no query frame, attacker file or instance mask (docs/service-protocol.md)")
    p.add_argument("study", help="a study folder whose render stage ran")
    p.add_argument("--out", required=True, help="the export folder (new, empty or an earlier export)")
    p.add_argument("--no-depth", action="store_true", help="leave out the map frames' ground-truth depth")

    p = command("localize", _cmd_localize, "localize images against a map (prints one JSON line each)")
    p.add_argument("map")
    p.add_argument("images", nargs="+")
    p.add_argument("--config", help="study config whose [localize] and [defense] sections to use")
    p.add_argument("--defense", action="store_true", help="turn the query defense on (X, k from the config)")
    p.add_argument("--verbose", action="store_true", help="also print inlier counts (server-side information)")

    p = command("report", _cmd_report, "a finished study's headline figures; --docs: its docs/results page",
                f"{listing}. --docs PAGE writes the page, its summary (PAGE.json) and figures (PAGE's stem folder) "
                "and records the preset's wall time in index.json beside it")
    p.add_argument("study", help="a finished study folder (synthleak study ... --out STUDY)")
    p.add_argument("--docs", metavar="PAGE", help="write the results page, e.g. docs/results/study-small.md")
    p.add_argument("--readme", metavar="README", help="also regenerate the presets table of this README")
    p.add_argument("--json", action="store_true", help="machine-readable output")

    p = command("study", _cmd_study, "run (or resume) a whole study: stages, renders, maps, attack, report")
    p.add_argument("config")
    p.add_argument("--out", required=True)
    p.add_argument("--force", action="append", metavar="STAGE",
                   help="redo a stage and the stages that read it: render (missing frames only), maps, features, "
                        "sfm, queries, attack, sweep, world-sweep, report (repeatable; sweep / world-sweep redo "
                        "every stage of their points)")
    p.add_argument("--server", metavar="URL",
                   help="attack running HTTP services instead of in-process localizers: one URL (a single map, or "
                        "a service listing its maps at GET /maps) or a template with {server} {tier} {room} "
                        "{room_index}, e.g. http://127.0.0.1:8000/{server}/{room} (docs/service-protocol.md)")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes for frames, maps and queries (default: the usable cores; 1: no pool)")
    p.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="where frames, maps and queries run: local processes or Ray tasks (pip install -e .[ray])")
    p.add_argument("--address", default=None,
                   help="Ray cluster to join (e.g. auto, ray://head:10001); default: start a local Ray")
    return parser


RESUMABLE = ("study", "generate", "render")
"""Commands whose ``--out`` a rerun resumes (the stop message says so)."""
PRELOAD = ("study", "serve", "map", "localize")
"""Commands that import pycolmap anyway: it is imported before the stop handlers, which it would replace
(:func:`synthleak.interrupt.preload_native_handlers`); the others do not pay for the import."""


def _exit_on_sigterm(signum: int, frame: object) -> None:
    """A stop signal unwinds like Ctrl-C: worker pools are stopped, finished files stay, a rerun resumes."""
    raise Stopped(signum)


def _stopped(args: argparse.Namespace, signum: int) -> int:
    """Print the one line of a stopped command; its exit status, ``128 + signum``."""
    message = f"synthleak {args.command}: stopped by {signal_name(signum)}"
    if args.command in RESUMABLE and getattr(args, "out", None):
        message += f"; finished work is kept in {args.out}, rerun the same command to resume"
    print(message, file=sys.stderr)
    return 128 + signum


def _closed_pipe() -> int:
    """stdout's reader went away (``synthleak objects | head -1``): exit quietly, as a process killed by SIGPIPE
    would (``128 + SIGPIPE``); stdout goes to devnull so that the interpreter's last flush does not fail again."""
    with contextlib.suppress(OSError, ValueError):  # no file descriptor (captured stdout)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 128 + getattr(signal, "SIGPIPE", 13)


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; its exit status (a handler may return one; errors: 2 after one line on stderr). SIGTERM,
    SIGINT and SIGHUP stop it (:mod:`synthleak.interrupt`): its workers are ended, finished files stay, and it
    exits with ``128 + signum`` after one line on stderr. A closed stdout pipe ends it quietly
    (:func:`_closed_pipe`)."""
    args = build_parser().parse_args(argv)
    with stop_on_signals(preload=args.command in PRELOAD):
        try:
            status = args.handler(args)
            sys.stdout.flush()  # a closed pipe fails here, not in the interpreter's last flush
        except BaseException as exc:
            # Stopped, or what a library made of it (Ray turns a SystemExit raised in its calls into
            # SystemExit(1)), or the error of a worker killed by the same signal (sent to the process group)
            signum = exc.signum if isinstance(exc, Stopped) else received_stop_signal()
            if signum is None and isinstance(exc, KeyboardInterrupt):  # no handler of ours (not the main thread)
                signum = signal.SIGINT
            if signum is not None:
                return _stopped(args, signum)
            if isinstance(exc, BrokenPipeError):
                return _closed_pipe()
            if not isinstance(exc, (SynthleakError, ValueError, OSError)):
                raise
            message = " ".join(str(exc).split())  # our errors name the file and the field: one line
            print(f"synthleak {args.command}: error: {message}", file=sys.stderr)
            return 2
    return status or 0


if __name__ == "__main__":
    raise SystemExit(main())
