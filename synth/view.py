"""A Rerun recording (.rrd) of a dataset's rig: poses, pinhole cameras, images, depth, masks, points.

``synth view DATA [--seq S] [--frames A:B] --out rig.rrd`` writes one recording (open it with
``rerun rig.rrd`` or the Rerun web viewer). One timeline, ``time``: the dataset's ``timestamp_s``
(a duration from the sequence start). Entities (metres; the world frame z up, as the dataset's)::

    world                         ViewCoordinates RIGHT_HAND_Z_UP (static)
    world/trajectory              LineStrips3D: the sequence's ego positions (T_world_ego), logged at its start
    world/scene/static            Mesh3D: the world mesh (`synth.world_mesh`, world frame; vertex colours =
                                  texture mean x tint), logged at the sequence's start
    world/scene/<mover>           Mesh3D in the mover's frame (at the start) and Transform3D = T_world_obj per frame
    world/ego                     Transform3D = T_world_ego, per frame
    world/ego/body                Mesh3D: the ego body, ego frame (static)
    world/ego/points_gt           Points3D: ground-truth depth of every camera back-projected, ego frame
    world/ego/<CAM>               Transform3D = T_ego_cam and Pinhole(K, resolution, camera_xyz=RDF, image
                                  plane 1.5 m from the camera in the 3-D view) (static; cameras that fire at
                                  their own times: the Transform3D per frame, below)
    world/ego/<CAM>/rgb           EncodedImage: the dataset's PNG bytes, per frame
    world/ego/<CAM>/depth         DepthImage, float32 z-depth in metres (meter=1), 0 = no surface, per frame
    world/ego/<CAM>/ego_mask      SegmentationImage (static): 0 = ego body, 1 = scene
    world/ego/<CAM>/overlap       SegmentationImage per frame: bit 1 = seen by the camera's first neighbour,
                                  bit 2 = by its second (`synth.overlap.overlap_mask`, labels in the
                                  entity's AnnotationContext)
    world/lidar                   Points3D, world frame: the sample's LIDAR_TOP sweep (nuScenes datasets only)
    world/ego/<CAM>/semantic, flow   a dataset with labels: the class map and the forward flow's arrows
                                  (`synth.view_labels`); absent without labels

Cameras that fire at their own times (``rig.trigger``; a nuScenes dataroot whose cameras' ``sample_data``
times differ): each camera's rgb, depth, overlap and labels are logged at its own time (``camera_poses``), with
its Transform3D = its pose then in the ego frame of its frame (so under the frame's ``world/ego`` it stands
where it fired); the frame's ego pose, points and LiDAR stay at the frame's time. Played, the cameras update
one after the other as they fired; the back-projected points use each camera's own pose.

The meshes are the dataset's own (``<seq>/world_mesh.npz``, label kind ``mesh``: rendered with
``labels.mesh=true``); for a dataset without them the caller may pass a way to rebuild them (``synth view``
passes `synth.gltf_export.rebuilt_world_mesh`, which rebuilds the scene from the manifest's generator config;
this module never reads that config). A nuScenes dataroot gets no mesh. The recording carries its blueprint
(`synth.view_blueprint`: a 3-D world view beside the six cameras in a grid, masks hidden until toggled; a labels
tab with labels).

``K`` goes in unchanged: Rerun's pinhole puts pixel (0, 0)'s corner at the image origin and its
default principal point at (W/2, H/2), the +0.5 pixel-centre convention of rig.json. The recording is
written to a temporary name beside ``--out`` and renamed when whole (a full disk: one line naming
``--out``, exit 4, no temporary left); an existing ``--out`` is replaced only when it is an .rrd file. `mcdp.recording` adds predictions to the same layout.

Example::

    synth view data/tiny --seq seq_00000 --frames 0:4 --out rig.rrd && rerun rig.rrd
"""
from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np

from corelib.atomic import atomic_pipe
from corelib.readfile import open_file
from corelib.rundir import FolderError, check_output_file
from synth.extras import VIZ_INSTALL as INSTALL
from synth.overlap import neighbours_of, overlaps_by_neighbour
from synth.protocol import pixel_rays_at
from synth.label_kinds import label_kinds as label_table
from synth.view_labels import class_context

APP_ID = "mcdp_synth"
TIMELINE = "time"
RRD_MAGIC = b"RRF"  # every .rrd file starts with it (RRF0, RRF2, ...)
FRUSTUM_M = 1.5  # the cameras' image planes in the 3-D view, metres from the camera (a car-sized rig)


class ViewError(ValueError):
    """A bad --seq / --frames / --out, or the viz extra missing; the message says what is allowed."""


def import_rerun():
    """The `rerun` module, or ViewError naming the install command."""
    try:
        import rerun as rr
    except ImportError:
        raise ViewError(f"the Rerun recording needs the optional extra 'viz' (rerun-sdk): {INSTALL}") from None
    return rr


def parse_frames(text: str | None, n_frames: int, seq: str) -> range:
    """``A:B`` (half-open, either side may be empty) -> range of frames inside [0, n_frames); ViewError
    naming the valid range otherwise."""
    if text is None:
        return range(n_frames)
    parts = str(text).split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        a = int(parts[0]) if parts[0].strip() else 0
        b = int(parts[1]) if parts[1].strip() else n_frames
    except ValueError:
        raise ViewError(f"--frames {text!r} is not A:B (e.g. 0:{n_frames}); {seq} has frames 0..{n_frames - 1}") \
            from None
    if not 0 <= a < b <= n_frames:
        raise ViewError(f"--frames {text} is outside {seq}'s frames: A:B with 0 <= A < B <= {n_frames}")
    return range(a, b)


def pick_sequence(ds, seq: str | None) -> str:
    seqs = ds.sequences
    if seq is None:
        return seqs[0]
    if seq not in seqs:
        shown = ", ".join(seqs[:8]) + (f" (+{len(seqs) - 8} more)" if len(seqs) > 8 else "")
        raise ViewError(f"--seq {seq!r} is not a sequence of {ds.root}; it has {shown}")
    return seq


def _is_rrd(p: Path) -> bool:
    try:
        with open_file(p, kind="hashed", link_ok=True) as fh:  # never a FIFO's blocking read
            return fh.read(3) == RRD_MAGIC
    except (OSError, ValueError):  # ValueError: corelib.readfile.ReadRefused
        return False


def check_rrd_target(out: str | Path, flag: str = "--out") -> Path:
    """`out` may be written: an .rrd name, outside any dataset, new or a recording written before."""
    from synth.dataset import dataset_containing

    out = Path(out)
    if out.suffix != ".rrd":
        raise ViewError(f"{flag} {out}: a Rerun recording is named *.rrd")
    inside = dataset_containing(out)
    if inside is not None:
        raise FolderError(f"{flag} {out} is inside the dataset {inside}; nothing was written: write outside it")
    return check_output_file(out, _is_rrd, "Rerun recording (.rrd)", flag)


@contextmanager
def recording(out: Path, name: str, blueprint=None) -> Iterator[object]:
    """A RecordingStream saving into a temporary file beside `out` (with `blueprint` as its default layout),
    renamed onto `out` when the block ends without error (flushed and disconnected first); removed otherwise.
    Rerun writes into a pipe and our thread writes the file (`corelib.atomic.atomic_pipe`), so a full disk
    ends the block with `DiskFullError` naming `out` (exit 4) instead of hanging Rerun's flush."""
    rr = import_rerun()
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_pipe(out) as sink:  # Rerun's file sink hangs once a write fails: it writes into a pipe of ours
        rec = rr.RecordingStream(APP_ID, recording_id=name)
        rec.set_log_time_enabled(False)  # one timeline: the dataset's time (no wall clock, no tick)
        rec.set_log_tick_enabled(False)
        rec.save(sink, default_blueprint=blueprint)
        try:
            yield rec
            rec.flush()
        finally:
            rec.disconnect()


def blueprint_of(ds, seq: str, stages=(), labels: bool = False):
    """The recording's blueprint (`synth.view_blueprint.rig_blueprint`) for `ds`'s cameras, its 3-D eye behind
    the ego of `seq`'s first frame; `labels`: a labels tab when the dataset has semantic or flow labels."""
    import rerun.blueprint as rrb

    from synth.view_blueprint import rig_blueprint

    shown = label_kinds(ds, labels)
    return rig_blueprint(rrb, ds.cameras, RigRecorder.cam_path, stages, ds.ego(seq)[0]["T_world_ego"],
                         labels=tuple(k.name for k in label_table() if k.log is not None) if shown else ())


def label_kinds(ds, labels: bool = True) -> set[str]:
    """The labels a recording of `ds` shows: the held kinds whose row logs itself (``log``: semantic, flow;
    `synth.label_kinds`), none unless `labels`."""
    return {k.name for k in label_table() if k.log is not None and k.name in ds.label_kinds} if labels else set()


def world_mesh_of(ds, seq: str, rebuild=None):
    """The world mesh of `ds`'s sequence `seq` (`synth.world_mesh.WorldMesh`): the one the dataset holds (label
    kind ``mesh``, written at render time), else ``rebuild(ds, seq)`` when the caller gives a way to rebuild it
    (`synth.gltf_export.rebuilt_world_mesh`, from the manifest's generator config: a dataset rendered without
    ``labels.mesh``), else None (no mesh in the recording)."""
    if ds.format == "synth" and "mesh" in ds.label_kinds:
        return ds.read_label("mesh", seq)
    return rebuild(ds, seq) if rebuild is not None else None


def mesh3d(rr, mesh):
    """A `synth.world_mesh.ColoredMesh` as rr.Mesh3D."""
    return rr.Mesh3D(vertex_positions=mesh.positions, triangle_indices=mesh.indices, vertex_normals=mesh.normals,
                     vertex_colors=mesh.colors)


def backproject(depth: np.ndarray, K, T_ego_cam: np.ndarray, keep: np.ndarray,
                stride: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ego-frame points of the pixels of `depth` ((H, W) depth, m, of the camera's depth kind) with `keep` and
    depth > 0, every `stride`-th row and column: ((M, 3) float32 metres, rows (M,), cols (M,)). Pixel centres at
    +0.5. `K`: a pinhole K or a `synth.camera.Intrinsics` (any lens row: its rays, z = 1 or unit by its kind)."""
    H, W = depth.shape
    v, u = np.mgrid[0:H:stride, 0:W:stride]
    z = depth[v, u]
    ok = keep[v, u] & (z > 0)
    v, u, z = v[ok], u[ok], z[ok].astype(np.float64)
    X = pixel_rays_at(K, u, v) * z
    if not np.isfinite(X).all():  # a lens pixel without a ray (its depth is 0 when written by synth)
        fin = np.isfinite(X).all(0)
        X, v, u = X[:, fin], v[fin], u[fin]
    T = np.asarray(T_ego_cam, np.float64)
    return (T[:3, :3] @ X + T[:3, 3:4]).T.astype(np.float32), v, u


class RigRecorder:
    """Logs one sequence of a dataset into a RecordingStream (layout: module docstring)."""

    def __init__(self, rr, rec, ds, seq: str, point_stride: int = 2, time_offset_s: float = 0.0,
                 labels: bool = False, rebuild=None) -> None:
        if point_stride < 1:
            raise ViewError(f"--point-stride {point_stride} must be >= 1")
        self.rr, self.rec, self.ds, self.seq = rr, rec, ds, seq
        self.stride, self.offset = int(point_stride), float(time_offset_s)
        self.ego = ds.ego(seq)
        self.names = list(ds.camera_names)
        self.nbrs = dict(zip(self.names, neighbours_of(ds.neighbours, len(self.names))))
        self.lidar = ds.lidar_points_world if ds.format == "nuscenes" else None  # a dataroot's LiDAR sweeps
        self.rebuild = rebuild  # the world mesh of a dataset without one (`world_mesh_of`)
        self.world = None  # the `synth.world_mesh.WorldMesh` once `log_sequence` read it
        self.rgb: dict[str, np.ndarray] = {}  # the last logged frame's images, per camera
        self.labels = label_kinds(ds, labels)  # shown labels (`synth.view_labels`)
        self.times, self.poses = own_times(ds, seq)  # None, None: the cameras fire at the frame's time

    @staticmethod
    def cam_path(name: str) -> str:
        return f"world/ego/{name}"

    def log_static(self) -> None:
        rr, rec = self.rr, self.rec
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for c, cam in enumerate(self.ds.cameras):
            path = self.cam_path(cam.name)
            T = np.asarray(cam.T_ego_cam, np.float64)
            if self.times is None:  # else per frame at the camera's own time (`log_frame`)
                rec.log(path, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=True)
            # Rerun's camera is a pinhole: a lens camera's K draws its frustum (its images are its own, distorted)
            rec.log(path, rr.Pinhole(image_from_camera=np.asarray(cam.K, np.float64),
                                     resolution=[cam.width, cam.height], camera_xyz=rr.ViewCoordinates.RDF,
                                     image_plane_distance=FRUSTUM_M),
                    static=True)
            rec.log(f"{path}/ego_mask", rr.AnnotationContext([(0, "ego body", (200, 40, 40)), (1, "scene", (0, 0, 0))]),
                    static=True)
            rec.log(f"{path}/ego_mask", rr.SegmentationImage(np.asarray(self.ds.mask(cam.name), np.uint8)),
                    static=True)
            labels = [(0, "seen by no neighbour", (0, 0, 0))]
            for b, j in enumerate(self.nbrs[cam.name][:2]):
                labels.append((1 << b, f"seen by {self.names[j]}", [(40, 120, 255), (255, 160, 0)][b]))
            if len(self.nbrs[cam.name]) >= 2:
                labels.append((3, "seen by both neighbours", (200, 60, 220)))
            rec.log(f"{path}/overlap", rr.AnnotationContext(labels), static=True)
            for kind in sorted(self.labels):
                rec.log(f"{path}/{kind}", class_context(rr, self.ds.classes), static=True)

    def log_sequence(self, ego_body: bool = True) -> None:
        """At the sequence's start: its trajectory, the world mesh and the movers' meshes (synth datasets),
        and (`ego_body`: once per recording) the ego body."""
        rr, rec = self.rr, self.rec
        self.set_frame(0)
        T = np.asarray([np.asarray(e["T_world_ego"], np.float64) for e in self.ego])
        rec.log("world/trajectory", rr.LineStrips3D([T[:, :3, 3]], colors=(255, 220, 0), radii=0.08,
                                                    labels=[self.seq]))
        self.world = world_mesh_of(self.ds, self.seq, self.rebuild)
        if self.world is None:
            return
        rec.log("world/scene/static", mesh3d(rr, self.world.static))
        for name, mesh, T_world_obj in self.world.movers:
            rec.log(f"world/scene/{name}", mesh3d(rr, mesh))
            T0 = np.asarray(T_world_obj[0], np.float64)
            rec.log(f"world/scene/{name}", rr.Transform3D(translation=T0[:3, 3], mat3x3=T0[:3, :3]))
        if ego_body:
            rec.log("world/ego/body", mesh3d(rr, self.world.ego), static=True)

    def set_frame(self, frame: int) -> float:
        t = self.offset + float(self.ego[frame].get("timestamp_s", frame / self.ds.fps))
        self.rec.set_time(TIMELINE, duration=t)
        return t

    def set_camera_time(self, frame: int, c: int) -> None:
        """Camera `c`'s own time at `frame` with its pose then (cameras that fire at their own times); else as is."""
        if self.times is None:
            return
        self.rec.set_time(TIMELINE, duration=self.offset + float(self.times[frame, c]))
        T = self.poses[frame, c]
        self.rec.log(self.cam_path(self.ds.cameras[c].name), self.rr.Transform3D(translation=T[:3, 3],
                                                                                  mat3x3=T[:3, :3]))

    def poses_at(self, frame: int) -> list[np.ndarray]:
        """Each camera's pose in the ego frame of `frame`'s time: its own, when the cameras fire apart."""
        return [c.T_ego_cam for c in self.ds.cameras] if self.poses is None else list(self.poses[frame])

    def log_frame(self, frame: int) -> dict[str, np.ndarray]:
        """Log frame `frame` (sets the time; each camera's at its own when they fire apart); returns the
        ground-truth depth per camera. Ends at the frame's time."""
        rr, rec, ds = self.rr, self.rec, self.ds
        self.set_frame(frame)
        T_we = np.asarray(self.ego[frame]["T_world_ego"], np.float64)
        rec.log("world/ego", rr.Transform3D(translation=T_we[:3, 3], mat3x3=T_we[:3, :3]))
        for name, _, T_world_obj in (self.world.movers if self.world else ()):
            T = np.asarray(T_world_obj[frame], np.float64)
            rec.log(f"world/scene/{name}", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        depths, pts, cols = {}, [], []
        self.rgb = {}
        Ts = self.poses_at(frame)
        for c, cam in enumerate(ds.cameras):
            path = self.cam_path(cam.name)
            self.set_camera_time(frame, c)
            rgb = ds.read_rgb(self.seq, cam.name, frame)  # checked: size, readable
            self.rgb[cam.name] = rgb
            src = ds.rgb_path(self.seq, cam.name, frame)
            media = {".png": "image/png", ".jpg": "image/jpeg"}.get(src.suffix)  # the file as it is stored
            if media and ds.format == "synth":
                rec.log(f"{path}/rgb", rr.EncodedImage(contents=ds.read_bytes(src), media_type=media))
            else:
                rec.log(f"{path}/rgb", rr.Image(rgb))
            self._log_labels(path, cam.name, frame)
            depth = ds.read_depth(self.seq, cam.name, frame) if ds.has_depth else None
            if depth is None:
                continue
            depths[cam.name] = depth
            rec.log(f"{path}/depth", rr.DepthImage(depth, meter=1.0))
            p, v, u = backproject(depth, cam.intrinsics, Ts[c], np.asarray(ds.mask(cam.name), bool), self.stride)
            pts.append(p)
            cols.append(rgb[v, u])
        if depths:
            cams = list(ds.cameras)
            dl, Ks = [depths[c.name] for c in cams], [c.intrinsics for c in cams]  # any lens row
            masks = [ds.mask(c.name) for c in cams]
            for c, cam in enumerate(cams):
                code = np.zeros((cam.height, cam.width), np.uint8)
                for b, ov in enumerate(overlaps_by_neighbour(c, dl, Ks, Ts, masks, self.nbrs[cam.name][:2])):
                    code |= ov.astype(np.uint8) << b
                if self.times is not None:
                    rec.set_time(TIMELINE, duration=self.offset + float(self.times[frame, c]))
                rec.log(f"{self.cam_path(cam.name)}/overlap", rr.SegmentationImage(code))
        self.set_frame(frame)  # the frame's points, each camera's at its own pose: in the ego frame of its time
        if pts:
            rec.log("world/ego/points_gt", rr.Points3D(np.concatenate(pts), colors=np.concatenate(cols), radii=0.05))
        if self.lidar is not None:
            rec.log("world/lidar", rr.Points3D(np.asarray(self.lidar(self.seq, frame), np.float32), radii=0.05,
                                               colors=(255, 255, 255)))
        return depths

    def _log_labels(self, path: str, cam: str, frame: int) -> None:
        """The camera-frame's class map and flow arrows (`synth.view_labels`), where the dataset has them."""
        shown: dict = {}  # each kind's logged value, in table order (the flow arrows take the classes' colours)
        for kind in label_table():
            if kind.name in self.labels:
                shown[kind.name] = kind.log(self.rr, self.rec, path, self.ds, self.seq, cam, frame, shown)


def own_times(ds, seq: str) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(F, N) each camera's timestamp_s and (F, N, 4, 4) its pose in its frame's ego frame (the reader's
    ``camera_poses``) when some camera of `seq` fires off its frame's time; (None, None) otherwise."""
    get = getattr(ds, "camera_poses", None)
    if get is None:
        return None, None
    ts, T = get(seq)
    frame_ts = np.asarray([float(e.get("timestamp_s", f / ds.fps)) for f, e in enumerate(ds.ego(seq))])
    return (None, None) if np.array_equal(ts, np.repeat(frame_ts[:, None], ts.shape[1], 1)) else (ts, T)


def record_rig(dataset: str | Path, out: str | Path, seq: str | None = None, frames: str | None = None,
               point_stride: int = 2, rebuild=None) -> dict:
    """Write the recording of one sequence (all its frames, or `frames` ``A:B``) to `out` (`rebuild`: the world
    mesh of a dataset that holds none, `world_mesh_of`); returns a summary (sequence, frames, bytes, seconds)."""
    import time

    from synth.open import open_dataset

    out = check_rrd_target(out)
    rr = import_rerun()
    ds = open_dataset(dataset)
    seq = pick_sequence(ds, seq)
    rng = parse_frames(frames, ds.n_frames(seq), seq)
    t0 = time.perf_counter()
    with recording(out, f"{seq}", blueprint_of(ds, seq, labels=True)) as rec:
        r = RigRecorder(rr, rec, ds, seq, point_stride, labels=True, rebuild=rebuild)
        r.log_static()
        r.log_sequence()
        for f in rng:
            r.log_frame(f)
    n = len(rng)
    size = out.stat().st_size
    return {"out": str(out), "sequence": seq, "frames": [rng.start, rng.stop], "rig_frames": n, "bytes": size,
            "bytes_per_rig_frame": size / n, "seconds": time.perf_counter() - t0}
