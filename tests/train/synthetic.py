"""Test-only datamodules of random tensors with the documented batch shapes (docs/reference/batch-schema.md).

Geometry is consistent: objects are spheres of random radius around the world origin, the camera sits at distance 2
on the -z side looking at the origin (RT = [I | (0, 0, 2)]), touches are surface points with inward directions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import lightning as L
import torch
from torch.utils.data import DataLoader, Dataset

CLASSES = ("bottle", "bowl", "can")


@dataclass
class _Library:
    classes: tuple[str, ...] = CLASSES


def _sphere(n: int, g: torch.Generator) -> torch.Tensor:
    x = torch.randn(n, 3, generator=g)
    return x / x.norm(dim=1, keepdim=True)


class SyntheticRecon(Dataset):
    """Reconstruction samples: image (3,H,W), K, RT, tactile (T,3,h,w), positions/directions (T,3), touch_mask (T,),
    points/normals (N,3) world, label, patch_points/patch_normals (T,Q,3) world and patch_mask (T,Q)."""

    def __init__(self, n: int, seed: int, image_size: int = 64, tactile_size: int = 16, touches: int = 10, points=256):
        self.n, self.seed, self.H, self.h, self.T, self.N = n, seed, image_size, tactile_size, touches, points

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        g = torch.Generator().manual_seed(self.seed * 1000 + i)
        radius = 0.2 + 0.2 * torch.rand((), generator=g)
        normals = _sphere(self.N, g)
        f = 0.5 * self.H / math.tan(math.radians(35.0) / 2)
        K = torch.tensor([[f, 0.0, (self.H - 1) / 2], [0.0, f, (self.H - 1) / 2], [0.0, 0.0, 1.0]])
        RT = torch.cat([torch.eye(3), torch.tensor([[0.0], [0.0], [2.0]])], dim=1)
        touch_dirs = _sphere(self.T, g)
        n_valid = 1 + i % self.T
        mask = torch.arange(self.T) < n_valid
        # contact patches: Q surface points around each touch (world), masked with their touch
        around = touch_dirs[:, None, :] + 0.1 * torch.randn(self.T, 8, 3, generator=g)  # (T, Q, 3)
        around = around / around.norm(dim=-1, keepdim=True)
        return {
            "image": torch.rand(3, self.H, self.H, generator=g),
            "K": K,
            "RT": RT,
            "tactile": torch.randn(self.T, 3, self.h, self.h, generator=g) * mask[:, None, None, None],
            "positions": touch_dirs * radius * mask[:, None],
            "directions": -touch_dirs * mask[:, None],
            "touch_mask": mask,
            "points": normals * radius,
            "normals": normals,
            "label": torch.tensor(i % len(CLASSES), dtype=torch.int64),
            "patch_points": around * radius * mask[:, None, None],
            "patch_normals": around * mask[:, None, None],
            "patch_mask": mask[:, None].expand(self.T, 8).clone(),
        }


class SyntheticClassification(Dataset):
    """Classification samples: tactile (N,3,h,w), touch_mask (N,), positions/directions (N,3), label."""

    def __init__(self, n: int, seed: int, num_touches: int = 2, tactile_size: int = 16, num_classes: int = 3):
        self.n, self.seed, self.N, self.h, self.C = n, seed, num_touches, tactile_size, num_classes

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        g = torch.Generator().manual_seed(self.seed * 1000 + i)
        label = i % self.C
        tactile = torch.randn(self.N, 3, self.h, self.h, generator=g) * 0.1 + label  # learnable by class
        return {
            "tactile": tactile,
            "touch_mask": torch.ones(self.N, dtype=torch.bool),
            "positions": torch.zeros(self.N, 3),
            "directions": torch.tensor([0.0, 0.0, -1.0]).expand(self.N, 3).clone(),
            "label": torch.tensor(label, dtype=torch.int64),
        }


class _Base(L.LightningDataModule):
    def __init__(self, batch_size: int = 2) -> None:
        super().__init__()
        self.batch_size = batch_size
        self.library = _Library()
        self.sets: dict[str, Dataset] = {}

    def _dl(self, name: str) -> DataLoader:
        return DataLoader(self.sets[name], batch_size=self.batch_size, shuffle=False)

    def train_dataloader(self) -> DataLoader:
        return self._dl("train")

    def val_dataloader(self) -> DataLoader:
        return self._dl("val")

    def test_dataloader(self) -> DataLoader:
        return self._dl("test")


class SyntheticReconDataModule(_Base):
    def __init__(self, batch_size: int = 2, n: int = 4, image_size: int = 64, tactile_size: int = 16) -> None:
        super().__init__(batch_size)
        self.sets = {s: SyntheticRecon(n, k, image_size, tactile_size) for k, s in enumerate(("train", "val", "test"))}


class SyntheticClassificationDataModule(_Base):
    def __init__(self, batch_size: int = 3, n: int = 6, num_touches: int = 2, tactile_size: int = 16) -> None:
        super().__init__(batch_size)
        self.sets = {
            s: SyntheticClassification(n, k, num_touches, tactile_size) for k, s in enumerate(("train", "val", "test"))
        }


class SigtermAtStep(L.Callback):
    """Test-only callback: the process sends itself SIGTERM after training batch ``step`` (global step count)."""

    def __init__(self, step: int = 1) -> None:
        self.step = step

    def on_train_batch_end(self, trainer: L.Trainer, *args: object) -> None:
        if trainer.global_step == self.step:
            import os
            import signal

            os.kill(os.getpid(), signal.SIGTERM)
