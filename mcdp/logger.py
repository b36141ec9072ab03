"""Training logs: TensorBoard scalars, six-camera image grids and the run's config as text, written by the
trainer only.

Example::

    log = TrainLogger(run_dir / "tensorboard")      # TrainLogger(None): logs nothing
    log.scalars({"train/loss": 0.1}, step)
    log.close()
"""
from __future__ import annotations

from pathlib import Path

import torch

from corelib.atomic import naming
from mcdp.visual import colorize_disparity


class TrainLogger:
    def __init__(self, folder: str | Path | None):
        self.writer = None
        self.folder = None if folder is None else Path(folder)
        if folder is not None:
            from torch.utils.tensorboard import SummaryWriter

            with naming(self.folder):
                self.writer = SummaryWriter(str(folder))

    def _named(self):
        """TensorBoard's writer thread reports a full disk without a file name: name the folder it writes."""
        return naming(self.folder)

    @property
    def enabled(self) -> bool:
        return self.writer is not None

    def scalars(self, values: dict, step: int) -> None:
        """Scalars by tag; tensors are detached; tags starting with "_" are internal and skipped."""
        if self.writer is None:
            return
        for k, v in values.items():
            if k.startswith("_") or (isinstance(v, torch.Tensor) and v.numel() != 1):
                continue
            with self._named():
                self.writer.add_scalar(k, float(v.detach()) if isinstance(v, torch.Tensor) else v, step)

    def text(self, tag: str, text: str, step: int) -> None:
        """``text`` (e.g. the resolved config YAML) under ``tag`` in TensorBoard's Text tab (markdown: indented
        four spaces, a code block, so YAML keeps its lines)."""
        if self.writer is not None:
            with self._named():
                self.writer.add_text(tag, "\n".join("    " + line for line in text.splitlines()), step)

    def images(self, batch, outputs: dict, step: int) -> None:
        """Rows: the rig's RGB at t, one colour-mapped disparity row per stage, then the masks
        (red: scene mask, green: pixels used by L_p: the step's ``outputs["used"]``, `mcdp.system`)."""
        if self.writer is None:
            return
        import torchvision

        N = batch.rgb.shape[1]
        rows = [batch.rgb[0, :, 1].float().cpu()]  # (N, 3, H, W)
        for stage in outputs["stages"]:
            disp = outputs["disp", stage, 0][:N].detach().float().cpu()
            rows.append(torch.from_numpy(colorize_disparity(disp[:, 0].numpy())).permute(0, 3, 1, 2).float() / 255)
        m = batch.mask[0].float().cpu()
        used = outputs["used"][:N].float().cpu()
        rows.append(torch.cat([m, used, m * 0], 1))
        grid = torchvision.utils.make_grid(torch.cat(rows, 0), nrow=N, padding=2)
        with self._named():
            self.writer.add_image("rig/rgb_depth_per_stage_masks", grid, step)

    def flush(self) -> None:
        if self.writer is not None:
            with self._named():
                self.writer.flush()

    def close(self) -> None:
        if self.writer is not None:
            writer, self.writer = self.writer, None
            with self._named():
                writer.close()
