"""Render USD stages into the dataset layout of docs/DATASET.md; resumable and deterministic.

A frame is complete when its RGB, depth and instance files all exist (each is written atomically), so an
interrupted run picks up where it stopped and finishes with the same bytes as an uninterrupted one.
Sequence metadata (COLMAP, BOP, objects.json, split.json) is written before a sequence's frames (a rerun
with another config or seed is refused instead of mixing frames) and ``manifest.json`` (sha256 of every
file) last: its presence marks a finished dataset.

Frames whose capture profile (``[render] capture_map`` / ``capture_genuine`` / ``capture_attacker``) is not
``ideal`` are photographed (:func:`photograph`, docs/renderers.md "Photographic capture") before they are
written; their records go to the sequence's ``capture.json``. ``ideal`` frames keep the backend's bytes.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
from rich.progress import Progress

from synthleak.atomic_io import atomic_write_bytes
from synthleak.cache import MARKER
from synthleak.config import StudyConfig, config_to_dict
from synthleak.core.dataset import BOP_DEPTH_SCALE, RENDER_TWINS, encode_png, frame_complete, frame_name, read_index
from synthleak.core.types import Camera, RenderScene
from synthleak.errors import StageError
from synthleak.executors import Executor, LocalExecutor, chunks
from synthleak.portable import snap_pose
from synthleak.render.base import Frame
from synthleak.render.bop_full import write_bop_extras
from synthleak.render.capture import capture, gamma22_to_linear, output_camera, srgb8_to_linear
from synthleak.render.dataset import (
    atomic_write_json,
    check_capture_plan,
    check_existing_plan,
    clean_temp_files,
    make_split,
    merge_capture_records,
    to_object_frame,
    write_bop_rgb,
    write_capture_record,
    write_frame,
    write_sequence_metadata,
)
from synthleak.render.devices import draw_device
from synthleak.render.distortion import raycast_camera
from synthleak.render.furniture_views import closeup_views, furniture_walkthrough
from synthleak.render.light_conditions import (
    LIGHTING_RECORDS,
    SAME,
    check_lighting_plan,
    lighting_kinds,
    lighting_record,
    lit_scene,
)
from synthleak.render.lighting import with_default_light
from synthleak.render.registry import get_renderer
from synthleak.render.trajectories import WALKTHROUGHS, orbit, walkthrough
from synthleak.seeding import derive_seed, make_rng

MANIFEST = "manifest.json"
PACKAGES = (
    "synthleak",
    "numpy",
    "scipy",
    "trimesh",
    "embreex",
    "mitsuba",
    "pycolmap",
    "usd-core",
    "opencv-python-headless",
    "pillow",
    "rich",
)


def load_stage(scene_path: Path) -> RenderScene:
    """``read_render_scene`` with errors that name the stage file."""
    scene_path = Path(scene_path)
    if not scene_path.is_file():
        raise StageError(f"{scene_path}: stage file does not exist")
    try:
        from synthleak.core.usd_read import read_render_scene
    except ImportError as exc:
        raise StageError(f"{scene_path}: cannot read stages, synthleak.core.usd_read unavailable ({exc})") from exc
    try:
        return read_render_scene(scene_path)
    except Exception as exc:  # noqa: BLE001 - any reader failure becomes a clear, file-named error
        raise StageError(f"{scene_path}: cannot read stage: {type(exc).__name__}: {exc}") from exc


def plan_poses(scene: RenderScene, config: StudyConfig, kind: str, name: str) -> list:
    """The sequence's ``cam_from_world`` poses in the stage world (deterministic in seed and name).

    Scene sequences follow ``render.walkthrough`` (the ``furniture`` tour falls back to the ``loop`` in a room
    without furniture); their close-ups are planned separately (:func:`plan_closeups`)."""
    rng = make_rng(config.seed, "trajectory", name)
    rc = config.render
    if kind == "scene":
        if rc.walkthrough not in WALKTHROUGHS:
            raise ValueError(f"render.walkthrough: {rc.walkthrough!r} is not one of {WALKTHROUGHS}")
        poses = None
        if rc.walkthrough == "furniture":
            poses = furniture_walkthrough(scene, rc.scene_frames, rng, rc.hfov_deg, rc.height / rc.width)
        return poses if poses is not None else walkthrough(scene, rc.scene_frames, rng)
    if kind == "attacker":
        if scene.target_instance_id is None:
            raise StageError(f"{scene.source or name}: attacker stage has no target_instance_id")
        target = scene.instances.get(scene.target_instance_id)
        if target is None or not np.any(np.asarray(target.extents) > 0):
            raise StageError(f"{scene.source or name}: synthleak:targetInstanceId {scene.target_instance_id} is "
                             f"{'not an instance' if target is None else 'an instance without geometry'} of the stage")
        return orbit(
            scene,
            scene.target_instance_id,
            rc.attacker_frames,
            rng,
            hfov_deg=rc.hfov_deg,
            aspect=rc.height / rc.width,
        )
    raise ValueError(f"kind must be 'scene' or 'attacker', got {kind!r}")


def plan_closeups(scene: RenderScene, config: StudyConfig, name: str, queries: list[str]) -> dict[str, np.ndarray]:
    """Frame name -> close-up ``cam_from_world`` for ``render.genuine_closeup_fraction`` of the query frames
    (drawn from their own random stream, so the walk-through does not change with the fraction)."""
    fraction = config.render.genuine_closeup_fraction
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"render.genuine_closeup_fraction must be in [0, 1], got {fraction}")
    count = int(round(fraction * len(queries)))
    if count == 0:
        return {}
    rng = make_rng(config.seed, "closeups", name)
    chosen = sorted(queries[i] for i in rng.choice(len(queries), size=count, replace=False))
    rc = config.render
    poses = closeup_views(scene, count, rng, rc.hfov_deg, rc.height / rc.width)
    return dict(zip(chosen, poses, strict=False))


FRAMES_PER_TASK = 25
"""Frames per render task: a worker prepares the renderer once per task (and reuses it for the next task
of the same sequence), so tasks are long enough to amortise ``prepare`` and short enough to balance."""


@dataclass
class SequenceJob:
    """One sequence to render: its stage (a USD path, or an in-memory scene) and where it goes."""

    stage: Path | RenderScene
    out_dir: Path
    kind: str
    name: str = ""

    def __post_init__(self) -> None:
        self.out_dir = Path(self.out_dir)
        self.name = self.name or self.out_dir.name

    def scene(self) -> RenderScene:
        """The stage as a render scene; a stage with no light at all gets the default light (and a warning)."""
        return with_default_light(self.stage if isinstance(self.stage, RenderScene) else load_stage(self.stage))


@dataclass
class FrameTask:
    """Frames ``indices`` (with their ``cam_from_world`` poses and capture profiles) of one sequence, for one
    worker. ``profiles`` is empty when every frame of the sequence is ``ideal`` (no capture records)."""

    job: SequenceJob
    config: StudyConfig
    indices: list[int]
    poses: list[np.ndarray]
    profiles: list[str] = field(default_factory=list)
    lighting: list[str] = field(default_factory=list)
    """Per frame the capture kind whose lighting condition lights it (``""``: the stage's lights); empty when
    every frame of the sequence has the stage's lights."""
    twins: list[int] = field(default_factory=list)
    """Indices whose render is kept beside the photo (:func:`twin_indices`)."""


def twin_indices(profiles: list[str], frames: list[str], split: dict[str, list[str]] | None) -> list[int]:
    """The first photographed frame of each kind of capture in the sequence (mapping frames, genuine queries;
    an attacker orbit has one kind), in frame order."""
    query = set(split["query"]) if split else set()
    first: dict[tuple[str, bool], int] = {}
    for i, (profile, frame) in enumerate(zip(profiles, frames, strict=True)):
        if profile != IDEAL:
            first.setdefault((profile, frame in query), i)
    return sorted(first.values())


# ------------------------------------------------------------------------------------------ photographic capture
IDEAL = "ideal"
"""The capture profile that keeps the renderer's own 8-bit encoding (no capture model runs)."""


def capture_profiles(config: StudyConfig, kind: str, frames: list[str], split: dict[str, list[str]] | None
                     ) -> list[str]:
    """The capture profile of each frame: ``render.capture_attacker`` for an attacker sequence; in a scene
    sequence ``render.capture_genuine`` for the held-out queries of ``split`` (close-ups included) and
    ``render.capture_map`` for the mapping frames."""
    rc = config.render
    if kind == "attacker":
        return [rc.capture_attacker] * len(frames)
    query = set((split or {}).get("query", []))
    return [rc.capture_genuine if f in query else rc.capture_map for f in frames]


def linear_radiance(frame: Frame, renderer: Any) -> np.ndarray:
    """The frame's linear radiance: the backend's own (mitsuba, Blender), else its 8-bit ``rgb`` decoded by the
    backend's ``rgb_encoding`` (pyrender: gamma 2.2, :func:`synthleak.render.capture.gamma22_to_linear`)."""
    if frame.linear is not None:
        return frame.linear
    encoding = getattr(renderer, "rgb_encoding", "srgb")
    if encoding == "gamma2.2":
        return gamma22_to_linear(frame.rgb)
    if encoding == "srgb":
        return srgb8_to_linear(frame.rgb)
    raise ValueError(f"renderer {getattr(renderer, 'name', renderer)!r}: unknown rgb_encoding {encoding!r}")


def frame_cameras(config: StudyConfig, name: str, profiles: list[str], camera: Camera) -> list[Camera] | None:
    """Each frame's camera (the photo's: :func:`synthleak.render.capture.output_camera` of the frame's drawn
    device, the same draw :func:`photograph` makes), or ``None`` when every frame keeps the render's ``camera``
    (then the dataset's single camera is written as before)."""
    cameras = [camera if profile == IDEAL else
               output_camera(camera, draw_device(profile, derive_seed(config.seed, "capture-device", name, i)))
               for i, profile in enumerate(profiles)]
    return cameras if any(c != camera for c in cameras) else None


def _worker_gt(job: SequenceJob, renderer: Any) -> Any:
    """The exact-GT ray caster of the prepared scene (the backend's own where it has one), for the cameras of
    distorted or resized photos; cached with the worker's renderer."""
    if "gt" not in _WORKER_RENDERER:
        from synthleak.render.raycast import RaycastGT

        gt = getattr(renderer, "_gt", None)
        _WORKER_RENDERER["gt"] = gt if isinstance(gt, RaycastGT) else RaycastGT(job.scene().meshes)
    return _WORKER_RENDERER["gt"]


def photograph(frame: Frame, renderer: Any, profile: str, root_seed: int, sequence: str, index: int,
               *, camera: Camera | None = None, cam_from_world: np.ndarray | None = None, gt: Any = None,
               ) -> tuple[Frame, dict[str, Any]]:
    """Frame ``index`` of ``sequence`` photographed with capture ``profile``: the device drawn from
    ``derive_seed(root_seed, "capture-device", sequence, index)`` (:func:`synthleak.render.devices.draw_device`),
    the sensor noise from ``derive_seed(root_seed, "capture-noise", sequence, index)``, the GT depth for
    defocus. Returns the frame with the photo as ``rgb`` and the record.

    Lens distortion and resize change the camera (:func:`synthleak.render.capture.output_camera`, what
    :func:`frame_cameras` writes): with the render's ``camera``, the frame's world ``cam_from_world`` and the
    scene's ray caster ``gt`` (:class:`synthleak.render.raycast.RaycastGT`) the depth and instance ids are ray
    cast again for the photo's camera (exact GT of every photo pixel centre); without them both effects are
    dropped (``record["geometry_skipped"]``) and depth and ids stay the render's. JPEG is encoded and decoded
    back into the frame's pixels (the dataset keeps PNG files)."""
    device_seed = derive_seed(root_seed, "capture-device", sequence, index)
    noise_seed = derive_seed(root_seed, "capture-noise", sequence, index)
    drawn = draw_device(profile, device_seed)
    geometric = camera is not None and cam_from_world is not None and gt is not None
    params = drawn if geometric else replace(drawn, resize=None, distortion=None)
    out_camera = output_camera(camera, params) if geometric else None
    photo = capture(linear_radiance(frame, renderer), params, noise_seed, depth=frame.depth, camera=camera)
    record = {**photo.record, "device_seed": device_seed}
    if out_camera is not None and out_camera != camera:
        depth, instance = raycast_camera(gt, out_camera, cam_from_world)
        frame = replace(frame, depth=depth, instance=instance)
    elif drawn.is_geometric and not geometric:
        record["geometry_skipped"] = True  # the profile distorts or resizes; this call has no camera / GT for it
    if photo.rgb.shape[:2] != frame.depth.shape:
        raise RuntimeError(f"capture profile {profile!r}: photo {photo.rgb.shape} but ground truth {frame.depth.shape}")
    return replace(frame, rgb=photo.rgb, linear=None), record


_WORKER_RENDERER: dict[str, Any] = {}
"""The renderers prepared by the last task in this process (one scene at a time, to bound memory): one per
lighting condition of that scene (``renderers``: label -> renderer, ``""``: the stage's lights)."""


def _prepared_renderer(job: SequenceJob, config: StudyConfig, lighting: str = ""):
    if isinstance(job.stage, RenderScene):
        source: Any = id(job.stage)
    else:  # a stage rewritten in place (forced re-staging) must be prepared again
        stat = Path(job.stage).stat()
        source = (str(job.stage), stat.st_mtime_ns, stat.st_size)
    key = repr((source, config_to_dict(config)["render"]))
    if _WORKER_RENDERER.get("key") != key:
        _WORKER_RENDERER.clear()
        _WORKER_RENDERER.update(key=key, renderers={})
    renderers = _WORKER_RENDERER["renderers"]
    if lighting not in renderers:
        renderer = get_renderer(config.render)
        renderer.prepare(lit_scene(job.scene(), lighting, config.seed, job.name))
        renderers[lighting] = renderer
    return renderers[lighting]


def render_frame_task(task: FrameTask) -> int:
    """Render and write frames of one sequence (a worker task; frame ``i`` is seeded by its index only,
    so the bytes do not depend on which worker renders it or what it rendered before)."""
    rc = task.config.render
    camera = Camera.from_hfov(rc.width, rc.height, rc.hfov_deg)
    profiles = task.profiles or [IDEAL] * len(task.indices)
    lighting = task.lighting or [""] * len(task.indices)
    for i, pose, profile, light in zip(task.indices, task.poses, profiles, lighting, strict=True):
        renderer = _prepared_renderer(task.job, task.config, light)
        frame = renderer.render(camera, pose, derive_seed(task.config.seed, "render", task.job.name, i))
        if profile != IDEAL:
            if i in task.twins:
                atomic_write_bytes(task.job.out_dir / RENDER_TWINS / frame_name(i), encode_png(frame.rgb))
            frame, record = photograph(frame, renderer, profile, task.config.seed, task.job.name, i, camera=camera,
                                       cam_from_world=pose, gt=_worker_gt(task.job, renderer))
            write_capture_record(task.job.out_dir, frame_name(i), record)
        elif task.profiles:  # a photographed sequence records every frame, its ideal ones too
            write_capture_record(task.job.out_dir, frame_name(i), {"profile": IDEAL, "effects": []})
        write_frame(task.job.out_dir, frame_name(i), frame)
    return len(task.indices)


def bop_extras_task(job: SequenceJob) -> str:
    """``write_bop_extras`` of one finished sequence (a worker task)."""
    write_bop_extras(job.out_dir, job.scene(), depth_scale=BOP_DEPTH_SCALE)
    return job.name


def plan_sequence(job: SequenceJob, config: StudyConfig, scene: RenderScene | None = None) -> list[FrameTask]:
    """Write the sequence's plan (poses, cameras, objects, split) and return its frames still to render."""
    scene = scene or job.scene()
    out_dir, kind, name = job.out_dir, job.kind, job.name
    rc = config.render
    camera = Camera.from_hfov(rc.width, rc.height, rc.hfov_deg)
    poses = plan_poses(scene, config, kind, name)
    frames = [frame_name(i) for i in range(len(poses))]
    split = None
    if kind == "scene":
        split = make_split(frames, rc.query_every)
        closeups = plan_closeups(scene, config, name, split["query"])
        poses = [closeups.get(f, p) for f, p in zip(frames, poses, strict=True)]
        if closeups:
            split["closeup"] = sorted(closeups)
    poses = [snap_pose(p) for p in poses]  # the rendered poses are the written ones, on every CPU
    if kind == "attacker":
        stored_poses, instances = to_object_frame(poses, scene.instances, scene.target_instance_id)
    else:
        stored_poses, instances = poses, [scene.instances[i] for i in sorted(scene.instances)]
    profiles = capture_profiles(config, kind, frames, split)
    cameras = frame_cameras(config, name, profiles, camera)  # distorted / resized photos: their own cameras
    check_capture_plan(out_dir, frames, profiles)  # first: another profile also changes the cameras
    check_existing_plan(out_dir, camera, frames, stored_poses, cameras)
    lighting = lighting_kinds(rc, kind, frames, split)
    lights = lighting_record(scene, lighting, frames, config.seed, name)
    check_lighting_plan(out_dir, lights, any(frame_complete(out_dir, f) for f in frames))
    out_dir.mkdir(parents=True, exist_ok=True)
    clean_temp_files(out_dir)
    if lights is not None:  # each frame's lighting condition, with the conditions drawn
        atomic_write_json(out_dir / LIGHTING_RECORDS, lights)
    # the plan (poses, cameras, objects) first: a resumed run with another config is refused above
    write_sequence_metadata(
        out_dir,
        camera=camera,
        frames=frames,
        poses=stored_poses,
        instances=instances,
        frame="object" if kind == "attacker" else "world",
        target_instance_id=scene.target_instance_id if kind == "attacker" else None,
        split=split,
        cameras=cameras,
    )
    todo = [i for i in range(len(frames)) if not frame_complete(out_dir, frames[i])]
    photographed = any(p != IDEAL for p in profiles)
    twins = twin_indices(profiles, frames, split)
    return [FrameTask(job, config, idx, [poses[i] for i in idx], [profiles[i] for i in idx] if photographed else [],
                      [lighting[i] for i in idx] if lights is not None else [], [i for i in idx if i in twins])
            for idx in chunks(todo, FRAMES_PER_TASK)]


def plan_sequence_task(item: tuple[SequenceJob, StudyConfig]) -> list[FrameTask]:
    """:func:`plan_sequence` of one sequence (a worker task: sequences are planned in parallel)."""
    return plan_sequence(*item)


def render_sequences(
    jobs: list[SequenceJob], config: StudyConfig, executor: Executor | None = None, progress: bool = True
) -> list[Path]:
    """Render every sequence of ``jobs`` (skipping complete frames), then their BOP extras.

    Frames of all sequences are spread over ``executor``'s workers in chunks; the files are the same
    bytes whatever the executor and its number of workers."""
    executor = executor or LocalExecutor(1)
    # planned in the workers (each frame's lens camera is a bisection: serial planning kept one core idle)
    plans = executor.map(plan_sequence_task, [(job, config) for job in jobs], "plan sequences", progress)
    tasks: list[FrameTask] = [task for plan in plans for task in plan]
    executor.map(render_frame_task, tasks, "render frames", progress)
    _WORKER_RENDERER.clear()  # the serial path renders in this process: free the last scene
    for job in jobs:  # the BOP scene folder's rgb/ (hard links: cheap, so also without the extras)
        merge_capture_records(job.out_dir)
        write_bop_rgb(job.out_dir)
    if config.render.bop_extras:
        started = {id(t.job) for t in tasks}
        extras = [job for job in jobs
                  if id(job) in started or not (job.out_dir / "bop" / "scene_gt_info.json").is_file()]
        executor.map(bop_extras_task, extras, "BOP extras", progress)
    return [job.out_dir for job in jobs]


def render_scene_sequence(
    scene: RenderScene,
    out_dir: Path,
    config: StudyConfig,
    kind: str,
    name: str | None = None,
    progress: bool | Progress = True,
    executor: Executor | None = None,
) -> Path:
    """Render one in-memory scene as a sequence folder (skipping complete frames), then its metadata."""
    job = SequenceJob(scene, Path(out_dir), kind, name or Path(out_dir).name)
    return render_sequences([job], config, executor, progress=bool(progress))[0]


def render_sequence(
    scene_path: Path, out_dir: Path, config: StudyConfig, kind: str, progress: bool | Progress = True,
    executor: Executor | None = None,
) -> Path:
    """Render the stage at ``scene_path`` into ``out_dir`` (``kind``: ``scene`` or ``attacker``)."""
    job = SequenceJob(Path(scene_path), Path(out_dir), kind)
    return render_sequences([job], config, executor, progress=bool(progress))[0]


STAGE_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")
"""File name suffixes of USD stages."""


def _root_layer(path: Path) -> Any:
    """The root layer of the stage file at ``path`` (no composition); a StageError naming the file otherwise."""
    from pxr import Sdf

    try:
        layer = Sdf.Layer.FindOrOpen(str(path))
    except Exception as exc:  # noqa: BLE001 - pxr raises Tf.ErrorException with a multi-line message
        raise StageError(f"{path}: cannot read stage: {' '.join(str(exc).split())}") from exc
    if layer is None:
        raise StageError(f"{path}: cannot read stage")
    return layer


def _stage_kind(path: Path) -> str:
    """``attacker`` for a stage whose root layer names a target instance (``synthleak:targetInstanceId`` >= 0 in
    its customLayerData, as `synthleak scenes` writes attacker setups), else ``scene``."""
    layer = _root_layer(path)
    target = dict(layer.customLayerData or {}).get("synthleak:targetInstanceId", -1)
    return "attacker" if target is not None and int(target) >= 0 else "scene"


def root_stages(folder: Path) -> list[Path]:
    """The stage files directly in ``folder`` that no other stage there uses as a sublayer, reference or payload
    (those are parts of a stage, not stages to render), sorted by name."""
    files = sorted(p for p in Path(folder).iterdir() if p.is_file() and p.suffix.lower() in STAGE_SUFFIXES)
    used: set[Path] = set()
    for path in files:
        layer = _root_layer(path)
        used |= {Path(layer.ComputeAbsolutePath(dep)).resolve() for dep in layer.GetCompositionAssetDependencies()}
    return [p for p in files if p.resolve() not in used]


def stage_jobs(stages: Path, out_dir: Path) -> list[SequenceJob]:
    """The sequences of ``stages``: the rooms (``out_dir/scenes/<room>``) and attacker objects
    (``out_dir/attackers/<id>``) of ``stages/index.json`` as `synthleak scenes` writes it; else, for stages
    written by other tools, one stage file or every root stage of a folder (:func:`root_stages`), each a
    sequence named after its file: an attacker sequence (``out_dir/attackers/<stem>``) when the stage names a
    target instance, a scene sequence (``out_dir/scenes/<stem>``) otherwise."""
    stages, out_dir = Path(stages), Path(out_dir)
    if stages.is_dir() and (stages / "index.json").is_file():
        index = read_index(stages)
        jobs = [(stages / r["stage"], out_dir / "scenes" / r["name"], "scene") for r in index["rooms"]]
        jobs += [(stages / a["stage"], out_dir / "attackers" / a["id"], "attacker")
                 for a in index["attacker_objects"]]
        missing = [str(stage) for stage, _, _ in jobs if not stage.is_file()]
        if missing:
            raise StageError(f"{stages / 'index.json'}: stage files do not exist: {', '.join(missing)}")
        return [SequenceJob(stage, seq_dir, kind) for stage, seq_dir, kind in jobs]
    if stages.is_file():
        if stages.suffix.lower() not in STAGE_SUFFIXES:
            raise StageError(f"{stages}: not a USD stage (expected {', '.join(STAGE_SUFFIXES)}) or a stage folder")
        files = [stages]
    elif stages.is_dir():
        files = root_stages(stages)
        if not files:
            raise StageError(f"{stages}: no index.json and no USD stage ({', '.join(STAGE_SUFFIXES)}) in the folder")
    else:
        raise StageError(f"{stages}: no such stage file or folder")
    stems = [p.stem for p in files]
    clashes = sorted({s for s in stems if stems.count(s) > 1})
    if clashes:
        raise StageError(f"{stages}: several stage files are named {clashes[0]!r} (sequences are named after files)")
    jobs = []
    for path in files:
        kind = _stage_kind(path)
        jobs.append(SequenceJob(path, out_dir / ("attackers" if kind == "attacker" else "scenes") / path.stem, kind))
    return jobs


def render_stages(config: StudyConfig, stages_dir: Path, out_dir: Path, progress: bool = True,
                  executor: Executor | None = None) -> Path:
    """Render every sequence of ``stages_dir`` (:func:`stage_jobs`: a folder written by `synthleak scenes`, a
    folder of stages written by other tools, or one stage file), then write ``out_dir/manifest.json``."""
    out_dir = Path(out_dir)
    render_sequences(stage_jobs(Path(stages_dir), out_dir), config, executor, progress)
    write_manifest(out_dir, config)
    return out_dir


def generate(config: StudyConfig, out_dir: Path, progress: bool = True, executor: Executor | None = None) -> Path:
    """Stages (``out_dir/stages``) and their renders in one go; resumable."""
    from synthleak.scene.generate import write_study_stages

    out_dir = Path(out_dir)
    written = Path(write_study_stages(config, out_dir / "stages", progress=progress))
    stages_dir = written.parent if written.is_file() else written  # index.json path or its folder
    return render_stages(config, stages_dir, out_dir, progress, executor)


def _versions() -> dict[str, str | None]:
    found: dict[str, str | None] = {}
    for name in PACKAGES:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = None
    return found


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def write_manifest(out_dir: Path, config: StudyConfig) -> Path:
    """``manifest.json``: config, seed, package versions and the sha256 of every other file (sorted); with a capture
profile other than ``ideal`` also ``capture``: the profile of map, genuine and attacker frames."""
    out_dir = Path(out_dir)
    clean_temp_files(out_dir)
    # cache markers (synthleak.cache) are bookkeeping of the study, not dataset content
    files = sorted(p for p in out_dir.rglob("*") if p.is_file() and p.name not in (MANIFEST, MARKER))
    manifest: dict[str, Any] = {
        "config": config_to_dict(config),
        "seed": config.seed,
        "packages": _versions(),
        "files": {p.relative_to(out_dir).as_posix(): sha256_file(p) for p in files},
    }
    rc = config.render
    if rc.photographed:  # an all-ideal manifest keeps the bytes it had before capture
        manifest["capture"] = rc.captures
    lighting = {"map": rc.light_map, "genuine": rc.light_genuine, "attacker": rc.light_attacker}
    if any(v != SAME for v in lighting.values()):  # likewise: an all-"same" manifest is unchanged
        manifest["lighting"] = lighting
    atomic_write_json(out_dir / MANIFEST, manifest)
    return out_dir / MANIFEST
