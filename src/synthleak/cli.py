"""Command-line interface: a thin layer over the Python API (every command is one function call)."""

from __future__ import annotations

import argparse
import json
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from synthleak.errors import SynthleakError
from synthleak.interrupt import Stopped, received_stop_signal, signal_name, stop_on_signals


def _cmd_objects(args: argparse.Namespace) -> None:
    from rich.console import Console

    from synthleak.assets.catalog import objects_rows, objects_table
    from synthleak.assets.library import by_role, load_library

    library = load_library()
    if args.role:
        library = by_role(library, args.role)
    if args.json:
        print(json.dumps(objects_rows(library), indent=2))
    else:
        Console().print(objects_table(library))


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


TIERS_HELP = "{tiers}"
"""Placeholder in a help text for the registered feature tiers (:func:`tiers_help`)."""


def tiers_help() -> str:
    """The registered feature tiers, for ``--tier``'s help (read from ``synthleak.localize.tiers``)."""
    from synthleak.localize.tiers import TIERS

    torch = [name for name, tier in TIERS.items() if tier.needs_torch]
    extra = f" ({', '.join(torch)}: the [learned] extra, see README)" if torch else ""
    return f"feature tier: {', '.join(TIERS)}{extra}"


class _HelpFormatter(argparse.HelpFormatter):
    """Fills :data:`TIERS_HELP` in when help is printed, not when the parser is built (importing the tier
    registry imports the localization package: about a second)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = super()._get_help_string(action)
        return text.replace(TIERS_HELP, tiers_help()) if text and TIERS_HELP in text else text


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="synthleak", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    def command(name: str, handler: Callable[[argparse.Namespace], None], help_text: str):
        p = sub.add_parser(name, help=help_text, description=help_text, formatter_class=_HelpFormatter)
        p.set_defaults(handler=handler)
        p.add_argument("--quiet", action="store_true", help="no progress bars")
        return p

    p = command("objects", _cmd_objects, "list the object library's models")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--role", choices=["furniture", "prop"], help="only the furniture or only the props")

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

    p = command("serve", _cmd_serve, "serve a map over HTTP on loopback (POST /localize, GET /health)")
    p.add_argument("map")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--config", help="study config whose [localize] and [defense] sections to use")
    p.add_argument("--defense", action="store_true", help="turn the query defense on (X, k from the config)")
    p.add_argument("--decision-log", help="JSONL file logging every defense decision with its counts")
    p.add_argument("--workers", type=int, default=None,
                   help="localizer processes answering queries in parallel (default: one per core, at most 8)")

    p = command("localize", _cmd_localize, "localize images against a map (prints one JSON line each)")
    p.add_argument("map")
    p.add_argument("images", nargs="+")
    p.add_argument("--config", help="study config whose [localize] and [defense] sections to use")
    p.add_argument("--defense", action="store_true", help="turn the query defense on (X, k from the config)")
    p.add_argument("--verbose", action="store_true", help="also print inlier counts (server-side information)")

    p = command("study", _cmd_study, "run (or resume) a whole study: stages, renders, maps, attack, report")
    p.add_argument("config")
    p.add_argument("--out", required=True)
    p.add_argument("--force", action="append", metavar="STAGE",
                   help="redo a stage: render, maps, features, queries, attack, sweep, world-sweep, report "
                        "(repeatable; sweep / world-sweep redo every stage of their points)")
    p.add_argument("--server", help="attack a running HTTP server instead of in-process localizers")
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


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command. SIGTERM, SIGINT and SIGHUP stop it (:mod:`synthleak.interrupt`): its workers are
    ended, finished files stay, and it exits with ``128 + signum`` after one line on stderr."""
    args = build_parser().parse_args(argv)
    with stop_on_signals(preload=args.command in PRELOAD):
        try:
            args.handler(args)
        except BaseException as exc:
            # Stopped, or what a library made of it (Ray turns a SystemExit raised in its calls into
            # SystemExit(1)), or the error of a worker killed by the same signal (sent to the process group)
            signum = exc.signum if isinstance(exc, Stopped) else received_stop_signal()
            if signum is None and isinstance(exc, KeyboardInterrupt):  # no handler of ours (not the main thread)
                signum = signal.SIGINT
            if signum is not None:
                return _stopped(args, signum)
            if not isinstance(exc, (SynthleakError, ValueError, OSError)):
                raise
            message = " ".join(str(exc).split())  # our errors name the file and the field: one line
            print(f"synthleak {args.command}: error: {message}", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
