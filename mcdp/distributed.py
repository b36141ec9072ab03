"""Data-parallel training under ``torchrun`` (torch.distributed + DistributedDataParallel).

`Dist.from_env()` reads torchrun's environment (``WORLD_SIZE``, ``RANK``, ``LOCAL_RANK``); without
it (a plain ``mcdp train``) it is one process and every call is a no-op. With it, the process
group is created with gloo on CPU and nccl on CUDA (one GPU per local rank), and:

- ``train.batch_size`` is the GLOBAL batch: every rank takes its contiguous share of the same
  global batch of each step (`mcdp.data.StepBatchSampler`), so N ranks see exactly the samples
  one process would; gradients are averaged by DDP;
- rank 0 alone writes the run folder (checkpoints, config, logs, TensorBoard, progress bar);
- the divergence guard and validation agree across ranks (`any_true`, `sum_`).

Example::

    torchrun --standalone --nproc_per_node 2 -m mcdp train configs/train/tiny/mono2.yaml \\
        --data data/tiny --out runs/ddp train.batch_size=2 train.threads=1
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist

from corelib.configlib import ConfigError, env_int


#: the most processes WORLD_SIZE may ask for
MAX_WORLD = 1 << 16
#: what a malformed torchrun variable's error says to do
TORCHRUN = "torchrun sets it; unset WORLD_SIZE for one process"
#: what a RANK or LOCAL_RANK other than 0 in one process (WORLD_SIZE unset or 1) says to do
ALONE = "WORLD_SIZE is unset or 1, one process of rank 0; unset it, or start the processes with torchrun"


@dataclass
class Dist:
    world: int = 1
    rank: int = 0
    local_rank: int = 0
    started: bool = False

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def enabled(self) -> bool:
        return self.world > 1

    @staticmethod
    def from_env() -> "Dist":
        """torchrun's variables, checked before anything starts: a value that is not an integer in range (a
        rank outside the world too, also in one process: ``WORLD_SIZE=1 RANK=1``, ``LOCAL_RANK=abc``) or a missing
        rendezvous address is one ConfigError naming the variable."""
        world = env_int("WORLD_SIZE", 1, 1, MAX_WORLD, TORCHRUN)
        if world <= 1:  # one process, rank 0: another rank was meant to have peers, and would train alone
            env_int("RANK", 0, 0, 0, ALONE)
            env_int("LOCAL_RANK", 0, 0, 0, ALONE)
            return Dist()
        for name in ("MASTER_ADDR", "MASTER_PORT"):
            if not os.environ.get(name):
                raise ConfigError(f"environment variable {name} is not set, but WORLD_SIZE={world} asks for "
                                  f"{world} processes; start them with torchrun (it sets {name}), or unset WORLD_SIZE")
        env_int("MASTER_PORT", 0, 1, 65535, TORCHRUN)
        rank = env_int("RANK", 0, 0, world - 1, TORCHRUN)  # a rank outside the world would wait for ever
        return Dist(world, rank, env_int("LOCAL_RANK", 0, 0, world - 1, TORCHRUN))

    def start(self, device: torch.device) -> torch.device:
        """Join the process group (gloo on CPU, nccl on CUDA); the device this rank trains on."""
        if not self.enabled:
            return device
        if device.type == "cuda":
            device = torch.device("cuda", self.local_rank)
            torch.cuda.set_device(device)
        if not dist.is_initialized():
            dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
            self.started = True
        return device

    def any_true(self, flag: bool, device: torch.device) -> bool:
        """True on every rank when `flag` is True on any rank."""
        if not self.enabled:
            return bool(flag)
        t = torch.tensor([1.0 if flag else 0.0], device=device)
        dist.all_reduce(t, op=dist.ReduceOp.MAX)
        return bool(t.item() > 0)

    def sum_(self, values: list[float], device: torch.device) -> list[float]:
        """Element-wise sum over ranks."""
        if not self.enabled:
            return list(values)
        t = torch.tensor(values, dtype=torch.float64, device=device)
        dist.all_reduce(t)
        return t.tolist()

    def barrier(self) -> None:
        if self.enabled and dist.is_initialized():
            dist.barrier()

    def stop(self) -> None:
        if self.started and dist.is_initialized():
            dist.destroy_process_group()
            self.started = False
