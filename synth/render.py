"""Render a dataset: sequences in parallel processes, deterministic shards, resumable.

Each sequence is independent and fully determined by ``(seed, sequence_index)``
(`numpy.random.SeedSequence([seed, index])`), so shard ``k/N`` (the sequences with
``index % N == k``) is identical whoever renders it, and shards rendered into one
folder (or merged with `synth.merge.merge_datasets`) give exactly the full dataset. A sequence
is written into ``<seq>.partial/`` and renamed when complete; a rerun skips complete
sequences. ``manifest.json`` is written last, once every sequence is present.

Example::

    summary = render_dataset(load_data_config("configs/data/tiny.yaml"), "data/tiny", workers=2)
"""
from __future__ import annotations

import math
import multiprocessing as mp
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np


from corelib import procs
from corelib.atomic import DiskFullError
from corelib.rundir import lock_folder
from corelib.version import code_version, warn_other_code
from scenes.model import Mesh, Scene
from scenes.textures import LAYER
from synth.config import DataConfig
from corelib.configlib import build_config, config_hash, config_to_dict
from corelib.hashing import sha256_file
from synth.files import OutputFolderError, frame_stem, read_json, write_depth_exr, write_json, write_png  # noqa: F401 (re-exported)
from synth.lens_image import render_camera
from synth.lighting import draw_sequence_lighting, frame_gains
from synth.manifest import (MARKER_DIR, RECORD, assign_splits, began_with, complete_sequences,  # noqa: F401
                            finalize, label_kinds, sequence_id)
from synth.photometry import SequencePhotometry
from synth.pipeline import FrameSink, LabelFrames, ScenePrefetch, build_sequence_scene
from synth.ego_body import ego_body_mesh
from synth.rig import Rig, build_rig
from synth.shutter import Shutter
from synth.trigger import CameraTimes

MAX_WORKERS = 256  # render processes on one machine (the sweep's `workers` has the same bound)


def make_rig(cfg: DataConfig) -> Rig:
    from synth.calibrate import geometric_rig

    return build_rig(geometric_rig(cfg), cfg.camera)  # overlap_target=pixels: the solved angle


def make_ego_mesh(cfg: DataConfig) -> Mesh:
    return ego_body_mesh(LAYER["car_paint"], LAYER["car_glass"], LAYER["tyre"], cfg.rig.camera_height_m)


# ----------------------------------------------------------------------------- worker side

_RENDERER = None
_RENDERER_KEY = None


def renderer_for(cfg: DataConfig):
    """This process's renderer for `cfg`'s image size and render settings (made once, remade when they change;
    a camera of its own size, ``rig.cameras.<CAM>.width``, is rendered into its own framebuffer of it).
    It limits numpy's BLAS to one thread in this process: with two, each 4x4 pose inverse waited for a core
    that llvmpipe and the writer threads held (2.7 ms against 3 us; docs/results/render_throughput.md)."""
    global _RENDERER, _RENDERER_KEY
    from threadpoolctl import threadpool_limits

    from synth.gl_backend import Renderer  # imported in the worker: OpenGL never crosses a fork

    key = (cfg.camera.width, cfg.camera.height, cfg.render.backend, cfg.render.shadow_map_size, cfg.rig.znear_m,
           cfg.rig.zfar_m)
    if _RENDERER is None or _RENDERER_KEY != key:
        threadpool_limits(limits=1, user_api="blas")  # for the process, not only this block (see above)
        if _RENDERER is not None:
            _RENDERER.close()
        _RENDERER = Renderer(cfg.camera.width, cfg.camera.height, backend=cfg.render.backend,
                             znear=cfg.rig.znear_m, zfar=cfg.rig.zfar_m, shadow_size=cfg.render.shadow_map_size)
        _RENDERER_KEY = key
    return _RENDERER


def render_masks(cfg: DataConfig, rig: Rig) -> dict[str, np.ndarray]:
    """Self-occlusion masks: (H, W) uint8, 255 = scene, 0 = ego body; exact, from the ego mesh alone."""
    from synth.gl_backend import LightState

    r = renderer_for(cfg)
    tex = np.full((1, 4, 4, 3), 128, np.uint8)
    scene = Scene(Mesh.empty(), [], tex, ["flat"], np.eye(4)[None], "ego_only")
    r.load_scene(scene, make_ego_mesh(cfg))
    light = LightState((0, 0, 1), (1, 1, 1), (1, 1, 1), (1, 1, 1), (1, 1, 1), shadows=False)
    masks = {}
    for cam in rig.cameras:  # a lens other than pinhole: formed from its faces (synth.lens_image)
        out = render_camera(r, cam, cam.T_ego_cam, 0, light)
        masks[cam.name] = np.where(out["ego"], 0, 255).astype(np.uint8)
    return masks


def render_sequence(cfg_dict: dict, out_dir: str, index: int, progress_queue=None,
                    prefetch: ScenePrefetch | None = None) -> dict:
    """Render sequence `index` into `out_dir/<seq>/` (via `<seq>.partial/`); returns its record. Files and
    overlap counts are done on `synth.pipeline.FrameSink`'s threads; `prefetch` may hold the scene."""
    cfg = build_config(DataConfig, cfg_dict, "resolved config")
    rig = make_rig(cfg)
    seq = sequence_id(index)
    out = Path(out_dir)
    final, partial = out / seq, out / f"{seq}.partial"
    if partial.exists():
        shutil.rmtree(partial)
    partial.mkdir(parents=True)
    ss = np.random.SeedSequence([cfg.seed, index])
    _, light_ss, flicker_ss = ss.spawn(3)
    t0 = time.perf_counter()
    scene = (prefetch.take(index) if prefetch is not None else None) or build_sequence_scene(cfg, index)
    t_scene = time.perf_counter() - t0
    seq_light = draw_sequence_lighting(cfg.lighting, rig.names, np.random.default_rng(light_ss))
    flicker_rng = np.random.default_rng(flicker_ss)
    photo = SequencePhotometry.for_sequence(cfg, index, rig, seq_light)  # None: the renderer's bytes
    times = CameraTimes.for_sequence(cfg, rig, scene)  # None: every camera at the frame time
    shutter = Shutter.for_config(cfg)  # None: one render per image, at the camera's time
    from synth.files import read_png
    masks = {name: read_png(out / "masks" / f"{name}.png", gray=True) for name in rig.names}
    r = renderer_for(cfg)
    r.load_scene(scene, make_ego_mesh(cfg))
    if cfg.ego.appearance == "live":  # the body's clear coat reflects this sequence's world (synth.config.EgoConfig)
        body = make_ego_mesh(cfg).positions
        r.set_ego_appearance(True, LAYER["tyre"], (0.8, 0.0, cfg.rig.camera_height_m), cfg.ego.reflection_px,
                             (body.min(0), body.max(0)))
    for name in rig.names:
        (partial / name).mkdir()
    frames_json = []
    kinds = label_kinds(cfg)
    with FrameSink() as sink:
        labels = (LabelFrames(sink, scene, kinds, seq, partial, cfg.render.png_compression, make_ego_mesh(cfg))
                  if kinds else None)
        for f in range(cfg.dataset.frames):
            gains = frame_gains(seq_light, flicker_rng)
            T_world_ego = scene.T_world_ego[f]
            depths = {}
            for c, cam in enumerate(rig.cameras):
                x = f if times is None else times.frame_index(c, f)  # each camera at its own time
                T_world_cam = (T_world_ego if times is None else times.T_world_ego(c, f)) @ cam.T_ego_cam
                # a pinhole camera: one render (its bytes as ever); another lens: formed from pinhole faces
                if shutter is None:
                    res = render_camera(r, cam, T_world_cam, x, seq_light.light, gains[cam.name], labels=bool(kinds))
                else:  # several times per image (synth.shutter): the ego and the movers at each
                    res = shutter.render(lambda xs, cam=cam, g=gains[cam.name]: render_camera(
                        r, cam, scene.ego_pose_at(xs) @ cam.T_ego_cam, xs, seq_light.light, g,
                        labels=bool(kinds)), x, cam.height)
                stem = frame_stem(f)
                rgb = res["rgb"] if photo is None else photo.apply(c, cam, f, res["rgb"], res["depth"], gains[cam.name])
                sink.rgb(f"{seq}/{cam.name}/{stem}", partial / cam.name / stem, rgb, cfg.render.png_compression,
                         cfg.sensor.jpeg_quality)  # .png, or .jpg with sensor.jpeg_quality
                sink.exr(f"{seq}/{cam.name}/{stem}.depth.exr", partial / cam.name / f"{stem}.depth.exr",
                         res["depth"])
                depths[cam.name] = res["depth"]
                if labels is not None:
                    labels.add(cam, f, T_world_cam, res, x)
            sink.overlap(depths, masks, rig.cameras if times is None else times.cameras_at(f), rig.neighbours)
            frames_json.append({"frame": f, "timestamp_s": f / cfg.dataset.fps, "T_world_ego": T_world_ego.tolist(),
                                "lighting": {"camera_gain": {k: list(v) for k, v in gains.items()}},
                                **(photo.frame_record() if photo is not None else {}),
                                **(times.frame_record(f) if times is not None else {})})
            if progress_queue is not None:
                progress_queue.put(1)
        files, counts = sink.results()
    ego = {"sequence": seq, "index": index, "fps": cfg.dataset.fps, "scene": scene.info,
           "lighting": seq_light.to_json(), "frames": frames_json}
    write_json(partial / "ego.json", ego)
    files[f"{seq}/ego.json"] = sha256_file(partial / "ego.json")
    if labels is not None:
        files.update(labels.finish())  # a kind's per-sequence files (instances.json)
    record = {"sequence": seq, "index": index, "frames": cfg.dataset.frames, "files": files, "labels": kinds,
              "overlap_counts": counts, "scene": scene.info, "time_of_day": seq_light.time_of_day,
              "seconds": time.perf_counter() - t0, "scene_seconds": t_scene,
              **(photo.record() if photo is not None else {})}
    write_json(partial / RECORD, record)
    os.sync()  # every file of the sequence on disk before the rename seals it
    os.replace(partial, final)
    return record


def _pool_init() -> None:
    # quieter workers; each builds its own renderer lazily
    os.environ.setdefault("PYTHONWARNINGS", "ignore")


# ----------------------------------------------------------------------------- driver

def parse_shard(text: str | None) -> tuple[int, int]:
    if text is None:
        return 0, 1
    try:
        k, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise ValueError(f"--shard must be K/N with integers 0 <= K < N, got {text!r}") from None
    if n < 1 or not 0 <= k < n:
        raise ValueError(f"--shard must be K/N with integers 0 <= K < N, got {text!r}")
    return k, n


def prepare_output(cfg: DataConfig, out: Path) -> None:
    """Check that `out` is empty or a (partial) render of this same config; else raise, writing nothing."""
    marker = out / MARKER_DIR / "config.json"
    if out.exists() and not out.is_dir():
        raise OutputFolderError(f"output {out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not marker.is_file():
            raise OutputFolderError(
                f"output folder {out} is not empty and holds no synth dataset; choose an empty or new folder")
        prev = read_json(marker)
        if prev.get("config_hash") != config_hash(cfg):
            from corelib.configlib import diff_configs
            keys = diff_configs(prev.get("config", {}), config_to_dict(cfg))
            raise OutputFolderError(
                f"output folder {out} holds another dataset (differs in: {', '.join(keys) or 'config hash'}); "
                "choose another --out or render with the same config to resume")
    out.mkdir(parents=True, exist_ok=True)
    (out / MARKER_DIR).mkdir(exist_ok=True)
    # the code that began the render stays the record: a resume (or a rerun over a complete one) by other code
    # does not make the sequences already written its own (a render begun before it was recorded: None)
    code = began_with(out) if marker.is_file() else code_version()
    write_json(marker, {"config": config_to_dict(cfg), "config_hash": config_hash(cfg), "seed": cfg.seed,
                        "code_version": code})


def _write_static(cfg: DataConfig, out: Path, rig: Rig) -> None:
    write_json(out / "rig.json", rig.to_json())
    (out / "masks").mkdir(exist_ok=True)
    masks = render_masks(cfg, rig)
    for name, m in masks.items():
        write_png(out / "masks" / f"{name}.png", m, cfg.render.png_compression)


def render_dataset(cfg: DataConfig, out: str | Path, workers: int = 1, shard: tuple[int, int] = (0, 1),
                   engine: str = "local", progress: bool = True, log=print) -> dict:
    """Render (the shard of) a dataset into `out`; resume-safe. Returns a summary dict.

    ``engine="local"``: `workers` spawned processes; ``"ray"``: one Ray task per sequence on the
    Ray of `corelib.cluster.ray_session` (`workers` is not used; Ray schedules). Both write
    the same files (the manifest's ``files`` hashes are equal).
    """
    out = Path(out)
    k, N = shard
    if not 1 <= workers <= MAX_WORKERS:
        raise ValueError(f"--workers must be in [1, {MAX_WORKERS}], got {workers}")
    if engine not in ("local", "ray"):
        raise ValueError(f"--engine must be local or ray, got {engine!r}")
    if engine == "ray":
        from corelib.cluster import import_ray
        import_ray()  # Ray missing: one line, before anything is written
    rig = make_rig(cfg)  # validates geometry before anything is written
    from synth.gl_backend import select_backend
    backend = select_backend(cfg.render.backend)
    prepare_output(cfg, out)
    warn_other_code(f"the render in {out}", began_with(out), lambda line: log(f"synth render: {line}"))
    lock = lock_folder(out, f"{MARKER_DIR}/lock")  # a second writer of `out` is refused, naming the pid
    try:
        return _render_into(cfg, out, rig, backend, workers, (k, N), engine, progress, log)
    finally:
        lock.release()


def _render_into(cfg: DataConfig, out: Path, rig: Rig, backend: str, workers: int, shard: tuple[int, int],
                 engine: str, progress: bool, log) -> dict:
    k, N = shard
    t0 = time.perf_counter()
    n = cfg.dataset.sequences
    done = set(complete_sequences(out, n))
    todo = [i for i in range(n) if i % N == k and i not in done]
    prefetch = ScenePrefetch(cfg) if engine == "local" and (workers == 1 or len(todo) <= 1) else None
    if prefetch is not None and todo:  # the first scene builds while the masks render
        prefetch.start(todo[0])
    if not (out / "rig.json").is_file() or not all((out / "masks" / f"{n}.png").is_file() for n in rig.names):
        _write_static(cfg, out, rig)
    for p in out.glob("*.partial"):
        shutil.rmtree(p)
    skipped = len([i for i in range(n) if i % N == k]) - len(todo)
    cfg_dict = config_to_dict(cfg)
    log(f"synth render: {len(todo)} sequence(s) to render, {skipped} already complete, shard {k}/{N}, "
        f"backend {backend}, " + ("Ray tasks" if engine == "ray" else f"{workers} worker(s)")
        + f", {rig.size_text()}")
    frames_total = len(todo) * cfg.dataset.frames
    bar = None
    if progress and frames_total:
        from corelib.progress import progress_bar
        bar = progress_bar(total=frames_total, unit="rig-frame", desc="render", file=sys.stderr)
    records = []
    if engine == "ray":
        records = _render_ray(cfg_dict, out, todo, bar) if todo else []
    elif workers == 1 or len(todo) <= 1:
        q = _BarQueue(bar)
        try:
            for pos, i in enumerate(todo):
                if pos + 1 < len(todo):  # the next scene builds while this sequence renders
                    prefetch.start(todo[pos + 1])
                records.append(render_sequence(cfg_dict, str(out), i, q, prefetch))
        finally:
            prefetch.close()
    else:
        records = _render_pool(cfg_dict, out, todo, workers, cfg.dataset.frames, bar)
    if bar is not None:
        bar.close()
    elapsed = time.perf_counter() - t0
    manifest = finalize(cfg, out, rig)
    rig_frames = len(records) * cfg.dataset.frames
    summary = {"rendered_sequences": len(records), "skipped_sequences": skipped, "rig_frames": rig_frames,
               "seconds": elapsed, "rig_frames_per_s": rig_frames / elapsed if elapsed > 0 else math.nan,
               "complete": manifest is not None, "backend": backend}
    if manifest is not None:
        summary["overlap"] = manifest["overlap"]
        summary["splits"] = {k2: len(v) for k2, v in manifest["splits"].items()}
        summary["families"] = manifest["families"]
    return summary


def _render_pool(cfg_dict: dict, out: Path, todo: list[int], workers: int, frames: int, bar) -> list[dict]:
    """The sequences `todo` in `workers` spawned processes; returns their records. A worker that dies
    (kill -9, the OOM killer) ends the render with `corelib.procs.WorkerLost` naming the sequences not
    finished (their ``.partial`` folders are removed by the rerun, which renders them again)."""
    import queue
    from concurrent.futures.process import BrokenProcessPool

    ctx = mp.get_context("spawn")
    with procs.manager(ctx) as manager:  # the manager and the workers die with this process
        q = manager.Queue()
        with procs.executor(ctx, min(workers, len(todo)), _pool_init) as pool:
            futures = {pool.submit(render_sequence, cfg_dict, str(out), i, q): i for i in todo}
            pending = len(todo) * frames
            while pending:
                try:
                    q.get(timeout=0.5)
                except queue.Empty:  # a task that failed (or a dead worker) sends no more frames
                    if any(f.done() and f.exception() is not None for f in futures):
                        break
                    continue
                pending -= 1
                if bar is not None:
                    bar.update(1)
            records, lost, error = [], [], None
            for f, i in futures.items():
                try:
                    records.append(f.result())
                except BrokenProcessPool:
                    lost.append(sequence_id(i))
                except Exception as exc:  # noqa: BLE001 - raised once the others are done
                    error = error or exc
    if lost:
        raise procs.lost_workers("synth render", lost, "sequence(s)")
    if error is not None:
        raise error
    return records


class _BarQueue:
    def __init__(self, bar) -> None:
        self.bar = bar

    def put(self, n: int) -> None:
        if self.bar is not None:
            self.bar.update(n)


def _render_ray(cfg_dict: dict, out: Path, todo: list[int], bar) -> list[dict]:
    """Every sequence as one Ray task (1 CPU), Ray schedules; returns their records.

    A task that fails is rerun once (``max_retries=1``: a crashed worker; ``retry_exceptions``:
    an exception, e.g. a full disk), safe since a sequence is written into ``<seq>.partial/``
    and renamed when whole; the others finish before the failures are raised, named.
    ``max_calls=1``: a worker process renders one sequence and exits, so no process that loaded
    Mesa's llvmpipe is reused for a sweep's training task (torch imported after it segfaults).
    """
    from corelib.cluster import error_line, ray_session

    with ray_session() as ray:
        task = ray.remote(num_cpus=1, max_retries=1, retry_exceptions=True, max_calls=1)(render_sequence)
        futures = {task.options(name=f"render {sequence_id(i)}").remote(cfg_dict, str(out), i, None): i for i in todo}
        records, failed = [], []
        while futures:
            ready, _ = ray.wait(list(futures), num_returns=1)
            for f in ready:
                i = futures.pop(f)
                try:
                    records.append(ray.get(f))
                except ray.exceptions.RayError as exc:
                    failed.append(f"{sequence_id(i)}: {error_line(exc)}")
                if bar is not None:
                    bar.update(cfg_dict["dataset"]["frames"])
    if failed:
        if any("no space left on device" in f for f in failed):
            raise DiskFullError(out)
        raise RuntimeError(f"{len(failed)} sequence(s) of {out} failed twice on Ray: " + "; ".join(failed))
    return records
