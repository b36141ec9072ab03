"""The work of rendering that is not rendering, moved off the GL thread: file writes, checksums,
overlap counts and the next sequence's scene.

The renderer owns one GL context and draws on the calling thread; while llvmpipe rasterises the
next camera, a small thread pool encodes and writes the previous ones (cv2's PNG and JPEG encoders, zlib
inside OpenEXR, hashlib and file I/O run without the GIL) and counts the z-tested overlap of the
previous rig frame. Every file is still written whole (a temporary name, then a rename), with the
same bytes as when written inline, and the results are collected in submission order, so the
record's ``files`` (and the manifest) list the same hashes in the same order.

Example::

    with FrameSink() as sink:
        sink.rgb("seq/CAM/000000", path_stem, rgb, compression=3, jpeg_quality=None)   # .png (or .jpg)
        sink.exr("seq/CAM/000000.depth.exr", path_exr, depth)
        sink.overlap(depths, masks, rig.cameras, rig.neighbours)
        files, counts = sink.results()
"""
from __future__ import annotations

import hashlib
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from corelib.atomic import atomic_write_bytes
from corelib.hashing import sha256_file
from scenes.model import Mesh, Scene
from synth.config import DataConfig
from synth.files import RGB_SUFFIXES, encode_jpeg, encode_png, frame_stem, write_depth_exr, write_flow_exr, write_json
from synth.label_kinds import LabelFile, label_kinds, write_sequence_files
from synth.overlap import overlap_fraction_counts

WRITE_THREADS = 2
MAX_PENDING = 40  # tasks in flight before `submit` waits (about three rig frames of six cameras)


def _image_task(path: Path, rgb: np.ndarray, compression: int, jpeg_quality: int | None = None) -> str:
    data = encode_png(rgb, compression) if jpeg_quality is None else encode_jpeg(rgb, jpeg_quality)
    # per-file fsync is skipped inside the .partial folder; one sync seals it (render_sequence)
    atomic_write_bytes(path, data, fsync=False)
    return hashlib.sha256(data).hexdigest()


def _exr_task(path: Path, depth: np.ndarray) -> str:
    write_depth_exr(path, depth, fsync=False)
    return sha256_file(path)


def _flow_task(keys: tuple[str, str], paths: tuple[Path, Path], compression: int, args: tuple) -> dict[str, str]:
    from synth.labels import forward_flow

    flow, valid = forward_flow(*args)
    write_flow_exr(paths[0], flow, fsync=False)
    return {keys[0]: sha256_file(paths[0]),
            keys[1]: _image_task(paths[1], np.where(valid, 255, 0).astype(np.uint8), compression)}


def rgb_suffix(jpeg_quality: int | None) -> str:
    """The suffix of an RGB image written with ``sensor.jpeg_quality`` = `jpeg_quality` (None: PNG)."""
    return RGB_SUFFIXES["png" if jpeg_quality is None else "jpeg"]


class FrameSink:
    """A bounded thread pool for one sequence's files and overlap counts, collected in order."""

    def __init__(self, threads: int = WRITE_THREADS, max_pending: int = MAX_PENDING) -> None:
        self._pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="synth-write")
        self._max_pending = max_pending
        self._pending: deque[Future] = deque()
        self._files: list[tuple[str | None, Future]] = []  # key None: the task returns {key: sha256}
        self._counts: list[Future] = []

    def _submit(self, fn, *args) -> Future:
        while len(self._pending) >= self._max_pending:
            self._pending.popleft().result()  # raises a task's error (a full disk) here, on the GL thread
        fut = self._pool.submit(fn, *args)
        self._pending.append(fut)
        return fut

    def png(self, key: str, path: Path, rgb: np.ndarray, compression: int) -> None:
        self._files.append((key, self._submit(_image_task, path, rgb, compression)))

    def rgb(self, key: str, path: Path, rgb: np.ndarray, compression: int, jpeg_quality: int | None) -> None:
        """A camera's RGB image: `key` and `path` without their suffix, which the format gives (`rgb_suffix`):
        PNG at `compression`, or JPEG at `jpeg_quality` (``sensor.jpeg_quality``) when set."""
        suffix = rgb_suffix(jpeg_quality)
        self._files.append((key + suffix, self._submit(_image_task, path.with_name(path.name + suffix), rgb,
                                                       compression, jpeg_quality)))

    def exr(self, key: str, path: Path, depth: np.ndarray) -> None:
        self._files.append((key, self._submit(_exr_task, path, depth)))

    def flow(self, keys: tuple[str, str], paths: tuple[Path, Path], compression: int, args: tuple) -> None:
        """Forward flow (`synth.labels.forward_flow(*args)`) and its validity, written to `paths`."""
        self._files.append((None, self._submit(_flow_task, keys, paths, compression, args)))

    def overlap(self, depths: dict, masks: dict, cameras: list, neighbours) -> None:
        self._counts.append(self._submit(overlap_fraction_counts, dict(depths), masks, cameras, neighbours))

    def results(self) -> tuple[dict[str, str], dict[str, list[int]]]:
        """Wait for every task: ({key: sha256} in submission order, overlap counts summed over frames)."""
        files: dict[str, str] = {}
        for key, fut in self._files:
            files.update(fut.result() if key is None else {key: fut.result()})
        counts: dict[str, list[int]] = {}
        for fut in self._counts:
            for k, (n_valid, n_in) in fut.result().items():
                c = counts.setdefault(k, [0, 0])
                c[0] += n_valid
                c[1] += n_in
        return files, counts

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> "FrameSink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass(frozen=True)
class RenderedFrame:
    """One rendered camera-frame as a label kind's writer sees it (`synth.label_kinds.LabelKind.write`)."""

    cam: object  # the `synth.rig.CameraSpec`
    frame: int
    T_world_cam: np.ndarray
    res: dict  # the renderer's read-back: depth, ego, layer, instance
    inst: np.ndarray  # (H, W) uint16 object ids (`synth.labels.instance_map`)
    x: float = 0.0  # its continuous frame index: `frame`, or its own trigger time (`synth.trigger`)


class LabelFrames:
    """A sequence's label files, fed one rendered camera-frame at a time: each kind of `kinds` (a row of
    `synth.label_kinds`) writes through `png` / `flow_pair` / `json`; forward flow t -> t+1 once t+1 is rendered."""

    def __init__(self, sink: FrameSink, scene: Scene, kinds: list[str], seq: str, folder: Path,
                 compression: int, ego: Mesh | None = None) -> None:
        from scenes.labels import instance_classes

        self.sink, self.scene, self.kinds, self.seq, self.folder = sink, scene, kinds, seq, folder
        self.ego = ego  # the ego body (`synth.render.make_ego_mesh`), for the world mesh kind
        self.compression = compression
        self.classes = instance_classes(scene)
        self.mover_T = {scene.mover_instance(k): m.T_world_obj for k, m in enumerate(scene.movers)}
        self.mover_ids = np.array(sorted(self.mover_T), np.int32)
        self._prev: dict[str, tuple] = {}

    def _file(self, lf: LabelFile, cam: str | None = None, frame: int | None = None) -> tuple[str, Path]:
        rel = lf.rel(self.seq, cam, frame)
        return rel, self.folder / rel.split("/", 1)[1]

    def png(self, lf: LabelFile, f: RenderedFrame, img: np.ndarray) -> None:
        """`img` as label file `lf` of camera-frame `f` (a PNG, written off the GL thread)."""
        self.sink.png(*self._file(lf, f.cam.name, f.frame), img, self.compression)

    def flow_pair(self, f: RenderedFrame, flow: LabelFile, valid: LabelFile) -> None:
        """The forward flow (and its validity) of `f`'s camera from the frame before `f` to `f`."""
        from synth.labels import mover_motion

        name, depth = f.cam.name, f.res["depth"]
        prev = self._prev.get(name)
        x = f.x
        if prev is not None:
            (d0, i0, e0, T0, x0), f0 = prev, f.frame - 1
            (k0, p0), (k1, p1) = self._file(flow, name, f0), self._file(valid, name, f0)
            lens = f.cam.K if f.cam.model == "pinhole" else f.cam.intrinsics  # flow through the camera's lens
            args = (d0, i0, e0, lens, T0, f.T_world_cam, mover_motion(self.mover_T, x0, x), depth, f.inst)
            self.sink.flow((k0, k1), (p0, p1), self.compression, args)
        self._prev[name] = (depth, f.inst, f.res["ego"], f.T_world_cam, x)

    def json(self, lf: LabelFile, doc) -> dict[str, str]:
        """The sequence's file `lf` holding `doc`, written now: {relative path: sha256}."""
        key, path = self._file(lf)
        write_json(path, doc)
        return {key: sha256_file(path)}

    def file(self, lf: LabelFile, data: bytes) -> dict[str, str]:
        """The sequence's file `lf` holding `data`, written now: {relative path: sha256}."""
        key, path = self._file(lf)
        atomic_write_bytes(path, data)
        return {key: sha256_file(path)}

    def add(self, cam, frame: int, T_world_cam: np.ndarray, res: dict, x: float | None = None) -> None:
        """One camera-frame's labels; `x`: its continuous frame index (its own trigger time, `synth.trigger`;
        None: `frame`), so its flow to the next frame moves the movers between the camera's two times."""
        from synth.labels import instance_map

        f = RenderedFrame(cam, frame, T_world_cam, res, instance_map(res["instance"], res["ego"], res["depth"]),
                          frame if x is None else x)
        for kind in label_kinds():
            if kind.name in self.kinds:
                kind.write(self, f)

    def finish(self) -> dict[str, str]:
        """The kinds' per-sequence files, written once every frame is: {relative path: sha256}."""
        return write_sequence_files(self, self.kinds)


def build_sequence_scene(cfg: DataConfig, index: int) -> Scene:
    """The scene of sequence `index`: a function of the config and `(seed, index)` only (the first of
    the three seed sequences `render_sequence` spawns)."""
    from scenes import build_scene

    scene_ss = np.random.SeedSequence([cfg.seed, index]).spawn(3)[0]
    return build_scene(cfg.scene, cfg.dataset.frames, cfg.dataset.fps, np.random.default_rng(scene_ss))


class ScenePrefetch:
    """Builds sequences' scenes on one background thread, ahead of the renderer that needs them.

    A scene depends only on the config and `(seed, index)`, so one built early is the same arrays as
    one built when needed. `take(index)` returns the scene (waiting for it), or None when it was
    never started (the caller builds it inline)."""

    def __init__(self, cfg: DataConfig) -> None:
        self._cfg = cfg
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="synth-scene")
        self._futures: dict[int, Future] = {}

    def start(self, index: int) -> None:
        if index not in self._futures:
            self._futures[index] = self._pool.submit(build_sequence_scene, self._cfg, index)

    def take(self, index: int) -> Scene | None:
        fut = self._futures.pop(index, None)
        return None if fut is None else fut.result()

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)
