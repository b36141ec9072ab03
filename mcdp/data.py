"""Rig samples for training: one sequence frame t (with t-1, t+1) of every camera.

The batch a step trains on is a `mcdp.inputs.RigBatch` (its schema is there, the one place); a sample
holds the optional input fields its network declares (`mcdp.inputs.InputField`) and no other.

Images are resized with
area interpolation; K follows exactly (diag(sx, sy, 1) @ K, pixel centres at +0.5);
masks are resized with area interpolation and thresholded at 0.99, so a
pixel counts as scene only if (almost) all of it is scene.

Example::

    ds = synth.open.open_dataset("data/tiny")
    train = RigDataset(ds, "train", height=64, width=96)
    batch = collate([train[0], train[1]])   # a RigBatch
"""
from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np
import torch

from mcdp.camera import Lens
from mcdp.inputs import InputField, RigBatch, read_fields, stack
from mcdp.runs import RunError
from synth import camera

FRAME_OFFSETS = (-1, 0, 1)
#: how cross-camera warps treat cameras that fire at different times (`mcdp.config.ModelConfig.sync`)
SYNC_MODES = ("compensate", "assume")
#: which lens the run's warps go through (`mcdp.config.ModelConfig.lens`): each camera's own, or K as a pinhole's
LENS_MODES = ("rig", "pinhole")


def resize_rgb(img: np.ndarray, height: int, width: int) -> np.ndarray:
    """(h, w, 3) uint8 -> (height, width, 3) uint8 with area interpolation (identity if same size)."""
    if img.shape[:2] == (height, width):
        return img
    interp = cv2.INTER_AREA if (height < img.shape[0] and width < img.shape[1]) else cv2.INTER_LINEAR
    return cv2.resize(img, (width, height), interpolation=interp)


def resize_mask(mask: np.ndarray, height: int, width: int) -> np.ndarray:
    """(h, w) bool -> (height, width) bool: True only where >= 99 % of the area is scene."""
    if mask.shape == (height, width):
        return mask.astype(bool)
    m = cv2.resize(mask.astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)
    return m >= 0.99


def scaled_K(K: np.ndarray, src_hw: tuple[int, int], dst_hw: tuple[int, int]) -> np.ndarray:
    """Intrinsics of an image resized from src_hw to dst_hw: diag(sx, sy, 1) K (the camera table's
    `synth.camera.resized`, which keeps any distortion parameters as they are)."""
    sy = dst_hw[0] / src_hw[0]
    sx = dst_hw[1] / src_hw[1]
    return camera.resized(np.asarray(K, dtype=np.float64), sx, sy)


def neighbour_table(pairs: Sequence[Sequence[int]], n_cams: int) -> torch.Tensor:
    """(N, 2) int64 [left, right] neighbour index of every camera, -1 where there is none.

    ``pairs`` are the dataset's adjacent pairs (i, j) with j = i + 1 (mod N) in
    rig order (CAM_FRONT, CAM_FRONT_RIGHT, ...): j is i's right neighbour and i
    is j's left neighbour. A ring that does not close has one -1 per end.
    """
    tab = torch.full((n_cams, 2), -1, dtype=torch.long)
    for i, j in pairs:
        i, j = int(i), int(j)
        tab[i, 1] = j
        tab[j, 0] = i
    return tab


def directed_pairs(pairs: Sequence[Sequence[int]]) -> tuple[torch.Tensor, torch.Tensor]:
    """Every adjacent pair in both directions: (tgt (P,), src (P,)) int64."""
    tgt, src = [], []
    for i, j in pairs:
        tgt += [int(i), int(j)]
        src += [int(j), int(i)]
    return torch.tensor(tgt, dtype=torch.long), torch.tensor(src, dtype=torch.long)


class RigReader:
    """Reads rig images/masks of a `synth.dataset` dataset at a fixed size (no torch in the maths).

    Masks and intrinsics are computed once per camera. ``lens``: ``model.lens`` (``rig``: ``self.lens`` is the
    cameras' `mcdp.camera.Lens`, None for a pinhole rig; ``pinhole``: None, K kept as it is, refused for a camera
    of range depth).
    """

    def __init__(self, ds, height: int, width: int, cache_bytes: int = 256 * 2**20, sync: str = "compensate",
                 lens: str = "rig"):
        if sync not in SYNC_MODES:
            raise ValueError(f"model.sync must be one of {', '.join(SYNC_MODES)}, got {sync!r}")
        if lens not in LENS_MODES:
            raise ValueError(f"model.lens must be one of {', '.join(LENS_MODES)}, got {lens!r}")
        self.ds, self.sync = ds, sync
        self._poses: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.cache_bytes = int(cache_bytes)
        self._cache: dict[tuple[str, int], np.ndarray] = {}
        self._cached_bytes = 0
        self.height, self.width = int(height), int(width)
        self.cam_names = list(ds.camera_names)
        self.K = np.stack(
            [scaled_K(c.K, (c.height, c.width), (self.height, self.width)) for c in ds.cameras]
        ).astype(np.float32)  # (N, 3, 3)
        self.T_ego_cam = np.stack([np.asarray(c.T_ego_cam, dtype=np.float64) for c in ds.cameras]).astype(np.float32)
        self.lens = Lens.of_cameras(ds.cameras)  # None for a pinhole rig (a resize keeps every distortion parameter)
        if lens == "pinhole":  # the ablation: K as a pinhole's, the distortion dropped (z-depth rows only)
            ranged = [f"{c.name} ({c.intrinsics.model})" for c in ds.cameras
                      if camera.depth_kind(c.intrinsics) != "z_depth"]
            if ranged:
                raise RunError(f"model.lens=pinhole needs z-depth cameras; {', '.join(ranged)[:200]} store range "
                                 "depth, where z-depth does not exist (use model.lens=rig)")
            self.lens = None
        self.mask_full = [np.asarray(ds.mask(n), dtype=bool) for n in self.cam_names]  # dataset resolution
        self.mask = np.stack([resize_mask(m, self.height, self.width) for m in self.mask_full])[:, None].astype(
            np.float32
        )  # (N, 1, H, W)

    def camera_poses(self, seq: str) -> tuple[np.ndarray, np.ndarray]:
        """(F, N) each camera's timestamp_s and (F, N, 4, 4) float32 its pose at that time in the ego frame of its
        frame's time (`synth.dataset.Dataset.camera_poses`; a reader without it, or a synchronous rig: the frame's
        time and the static extrinsics ``T_ego_cam``)."""
        if seq not in self._poses:
            get = getattr(self.ds, "camera_poses", None)
            if get is None:
                F = self.ds.n_frames(seq)
                ts = np.repeat(np.asarray([e["timestamp_s"] for e in self.ds.ego(seq)], np.float64)[:, None],
                               len(self.cam_names), 1)
                self._poses[seq] = ts, np.repeat(self.T_ego_cam[None], F, 0)
            else:
                ts, T = get(seq)
                self._poses[seq] = ts, np.asarray(T).astype(np.float32)
        return self._poses[seq]

    def T_ego_cam_at(self, seq: str, frame: int) -> np.ndarray:
        """(N, 4, 4) float32 the camera poses every cross-camera warp of rig sample (seq, frame) uses: under
        ``model.sync=compensate`` each camera's own pose at its own trigger time (`camera_poses`), under
        ``assume`` the static rig extrinsics (as if the cameras fired together). Equal for synchronous data."""
        if self.sync == "assume":
            return self.T_ego_cam
        return self.camera_poses(seq)[1][frame]

    def rgb(self, seq: str, frame: int) -> np.ndarray:
        """(N, 3, H, W) float32 in [0, 1] of every camera at one frame.

        Decoded, resized frames are kept (as uint8) up to ``cache_bytes`` per process: a small
        dataset (the sweep's 64 sequences x 10 frames x 6 cameras at 96x64: 6 MB) is decoded once;
        a larger one fills the cache and reads the rest from disk each time.
        """
        key = (seq, int(frame))
        u8 = self._cache.get(key)
        if u8 is None:
            u8 = np.empty((len(self.cam_names), 3, self.height, self.width), dtype=np.uint8)
            for c, name in enumerate(self.cam_names):
                u8[c] = resize_rgb(self.ds.read_rgb(seq, name, frame), self.height, self.width).transpose(2, 0, 1)
            if self._cached_bytes + u8.nbytes <= self.cache_bytes:
                self._cache[key] = u8
                self._cached_bytes += u8.nbytes
        return u8.astype(np.float32) / 255.0


class RigDataset(torch.utils.data.Dataset):
    """Rig samples (seq, t) of one split with 1 <= t <= F-2 (t-1 and t+1 must exist).

    Args:
        ds: an opened `synth.dataset` dataset.
        split: 'train' | 'val' | 'test'.
        height, width: training size.
        fields: the optional inputs its network reads (`mcdp.inputs.InputField`; `mcdp.methods.fields_of` for a run):
            each sample holds these under ``fields`` and no other.
        sync: ``model.sync``: a sample's ``T_ego_cam`` is each camera's own pose at its own trigger time in the
            ego frame of the sample's frame time (``compensate``; the relative pose of two cameras then goes
            through the world, and the odometry of t -/+ 1 composes with it exactly for motion at a constant
            twist) or the static extrinsics (``assume``); equal for a synchronous rig. Each camera's timestamp:
            ``reader.camera_poses(seq)[0]``.
        lens: ``model.lens``: ``rig`` (a sample holds the cameras' lens, none for a pinhole rig) or ``pinhole``
            (no lens: every warp treats K as a pinhole's; `RigReader`).
    """

    def __init__(self, ds, split: str, height: int, width: int, fields: tuple[InputField, ...] = (),
                 sync: str = "compensate", lens: str = "rig"):
        self.reader = RigReader(ds, height, width, sync=sync, lens=lens)
        self.split = split
        self.fields = tuple(fields)
        self.seqs = list(ds.split(split))
        self.T_world_ego = {s: np.asarray(ds.T_world_ego(s), dtype=np.float64) for s in self.seqs}
        self.samples = [(k, t) for k, s in enumerate(self.seqs) for t in range(1, ds.n_frames(s) - 1)]

    def __len__(self) -> int:
        return len(self.samples)

    def __getitem__(self, idx: int) -> dict:
        k, t = self.samples[idx]
        seq = self.seqs[k]
        r = self.reader
        rgb = np.stack([r.rgb(seq, t + o) for o in FRAME_OFFSETS], axis=1)  # (N, 3 frames, 3, H, W)
        T = self.T_world_ego[seq][[t + o for o in FRAME_OFFSETS]].astype(np.float32)  # (3, 4, 4)
        item = {
            "rgb": torch.from_numpy(rgb),
            "K": torch.from_numpy(r.K),
            "T_ego_cam": torch.from_numpy(r.T_ego_cam_at(seq, t)),  # each camera's own pose (model.sync)
            "mask": torch.from_numpy(r.mask),
            "T_world_ego": torch.from_numpy(T),
            "seq_index": torch.tensor(k, dtype=torch.long),
            "frame": torch.tensor(t, dtype=torch.long),
            "fields": read_fields(self.fields, r, seq, t),
        }
        if r.lens is not None:
            item["lens"] = r.lens
        return item


def step_loader(train_set: RigDataset, tc, start: int, end: int, rank: int = 0, world: int = 1,
                pin: bool = False) -> torch.utils.data.DataLoader:
    """The batches of training steps [start, end) of ``train_set`` (this rank's share of each; `StepBatchSampler`:
    a pure function of the step), as ``tc`` (`mcdp.config.TrainConfig`: batch size, seed, workers) asks."""
    sampler = StepBatchSampler(len(train_set), tc.batch_size, tc.seed, start, end, rank=rank, world=world)
    return torch.utils.data.DataLoader(train_set, batch_sampler=sampler, collate_fn=collate, num_workers=tc.num_workers,
                                       pin_memory=pin, persistent_workers=False)


def collate(items: list[dict]) -> RigBatch:
    """Stack rig samples into a `mcdp.inputs.RigBatch`."""
    return stack(items)


class StepBatchSampler(torch.utils.data.Sampler):
    """Batches of sample indices as a pure function of (seed, step): exact resume for free.

    The sample stream is the concatenation of per-epoch permutations, epoch e
    drawn from ``torch.Generator().manual_seed(seed * 1_000_003 + e)``; step s
    takes stream positions [s * B, (s + 1) * B). Yields the batches of steps
    ``start_step .. end_step - 1``. With ``world`` > 1 (torchrun), rank r yields its contiguous
    share ``[r * B / world, (r + 1) * B / world)`` of each global batch B.
    """

    def __init__(self, n_samples: int, batch_size: int, seed: int, start_step: int, end_step: int,
                 rank: int = 0, world: int = 1):
        if n_samples <= 0:
            raise ValueError("the split has no rig samples (every sequence needs at least 3 frames)")
        if batch_size % world:
            raise ValueError(f"train.batch_size={batch_size} (the global batch) must be a multiple of the "
                             f"{world} ranks")
        self.n, self.B, self.seed = n_samples, batch_size, seed
        self.start, self.end = start_step, end_step
        self.rank, self.world = rank, world
        self._perm_cache: dict[int, torch.Tensor] = {}

    def _perm(self, epoch: int) -> torch.Tensor:
        if epoch not in self._perm_cache:
            g = torch.Generator().manual_seed(self.seed * 1_000_003 + epoch)
            self._perm_cache = {epoch: torch.randperm(self.n, generator=g)}
        return self._perm_cache[epoch]

    def batch(self, step: int) -> list[int]:
        out = []
        for pos in range(step * self.B, (step + 1) * self.B):
            out.append(int(self._perm(pos // self.n)[pos % self.n]))
        return out

    def __iter__(self):
        share = self.B // self.world
        for s in range(self.start, self.end):
            yield self.batch(s)[self.rank * share:(self.rank + 1) * share]

    def __len__(self) -> int:
        return max(0, self.end - self.start)
