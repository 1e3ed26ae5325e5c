"""Test protocol of tactile-visual mesh reconstruction (paper Tables 3 and 4), mixed into
:class:`~tvrecon.models.lit_recon.ReconstructionModule`.

Every test batch is evaluated in the modes of the network (see :mod:`tvrecon.report.tables`):

- ``mode="fusion"``: ``"visual"`` (every touch masked out) and ``"tv@k"`` for k in ``eval_touches``;
- ``mode="visual_only"``: ``"visual"``;
- ``mode="tactile_only"``: ``"tactile@k"`` (the network blanks the view itself).

With ``touch_controls`` a model that reads touches is also tested at every touch count with the touches' content
replaced (the positions kept, so the same pixels receive an embedding): ``"<mode>:other"`` takes the tactile images and
directions of the next sample in the batch (another object; batches of one sample are skipped), ``"<mode>:blank"``
zero tactile images. A model that has learned to read the touches does worse in both than with its own.

"first k touches" means the k first valid touches of the sample (fewer if the sample has fewer; the mean number
actually used is reported per mode as ``touches``). Per mode it accumulates the mean chamfer (x1e-3), F-scores and
the per-class chamfer, exports one predicted mesh per class as ``.obj`` and one side-by-side render per class, and
stores the JSON-ready dict in :attr:`ReconstructionModule.test_results`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor

from tvrecon.models.class_names import datamodule_class_names
from tvrecon.models.mesh_figures import export_obj, render_mesh_comparison
from tvrecon.models.recon_batch import TOUCH_CONTROLS, control_batch, gt_to_camera, keep_first_touches
from tvrecon.models.refine import refine_to_patches
from tvrecon.utils.geometry import world_to_camera

__all__ = ["ReconstructionTestProtocol"]


class ReconstructionTestProtocol:
    """The test hooks of :class:`~tvrecon.models.lit_recon.ReconstructionModule` (a mixin of LightningModule hooks).

    The host module provides ``modality``, ``eval_touches``, ``class_names``, ``hparams`` (``refine``,
    ``refine_steps``, ``touch_controls``, ``export``, ``fscore_thresholds``, ``name``), its forward
    ``self(batch, touch_mask)``, ``_metrics(out, points)`` and ``_out_dir()``. Results land in ``test_results``.
    """

    test_results: dict[str, Any] | None
    _acc: dict[str, dict[str, Tensor]]
    _exported: set[tuple[str, int]]

    def _modes(self) -> list[tuple[str, int]]:
        """(mode name, touches) of every test mode of this network (see the module doc)."""
        if self.modality == "visual":
            refined = [(f"visual+refine@{k}", k) for k in self.eval_touches] if self.hparams.get("refine") else []
            return [("visual", 0), *refined]
        prefix = "tactile" if self.modality == "tactile" else "tv"
        modes = [] if self.modality == "tactile" else [("visual", 0)]
        modes += [(f"{prefix}@{k}", k) for k in self.eval_touches]
        if self.hparams.get("touch_controls"):
            modes += [(f"{prefix}@{k}:{control}", k) for k in self.eval_touches for control in TOUCH_CONTROLS]
        if self.hparams.get("refine"):
            modes += [(f"{prefix}@{k}+refine", k) for k in self.eval_touches]
        return modes

    def refined(self, out: Mapping[str, list[Tensor]], batch: Mapping[str, Tensor], mask: Tensor) -> dict:
        """The output with its last stage's vertices pulled onto the contact patches of the touches in ``mask``.

        Args:
            out: network output (camera-frame ``verts`` per stage, ``edges`` per stage).
            batch: collated samples with ``patch_points`` (B, T, Q, 3) world and ``patch_mask`` (B, T, Q) bool, and RT.
            mask: (B, T) bool, the touches to use.
        """
        if "patch_points" not in batch or "patch_mask" not in batch:
            raise ValueError(
                "refine needs the samples' contact patches (patch_points, patch_mask): use the datasets "
                "of tvrecon.data (ReconstructionDataset exposes them)"
            )
        B, T, Q, _ = batch["patch_points"].shape
        points = world_to_camera(batch["patch_points"].reshape(B, T * Q, 3), batch["RT"])  # (B, T*Q, 3)
        valid = (batch["patch_mask"] & mask[:, :, None]).reshape(B, T * Q)  # (B, T*Q)
        # keep the contact points only (padded per sample): the nearest-vertex search then costs what they cost
        n = max(int(valid.sum(1).max()), 1)
        order = torch.argsort(valid.to(torch.int8), dim=1, descending=True, stable=True)[:, :n]  # (B, n)
        points = torch.gather(points, 1, order[..., None].expand(-1, -1, 3))
        valid = torch.gather(valid, 1, order)
        result = dict(out)
        result["verts"] = list(out["verts"])
        result["verts"][-1] = refine_to_patches(
            out["verts"][-1], out["edges"][-1], points, valid, steps=int(self.hparams.get("refine_steps", 40))
        )
        return result

    control_batch = staticmethod(control_batch)

    def _names(self) -> list[str]:
        if self.class_names is not None:
            return self.class_names
        return datamodule_class_names(self.trainer)

    def on_test_epoch_start(self) -> None:
        n_cls = max(len(self._names()), 1)
        thresholds = list(self.hparams.fscore_thresholds)
        self._acc = {
            mode: {
                "chamfer": torch.zeros((), dtype=torch.float64, device=self.device),
                "count": torch.zeros((), dtype=torch.float64, device=self.device),
                "touches": torch.zeros((), dtype=torch.float64, device=self.device),
                "fscore": torch.zeros(len(thresholds), dtype=torch.float64, device=self.device),
                "class_sum": torch.zeros(n_cls, dtype=torch.float64, device=self.device),
                "class_count": torch.zeros(n_cls, dtype=torch.float64, device=self.device),
            }
            for mode, _ in self._modes()
        }
        self._exported = set()

    def test_step(self, batch: dict[str, Tensor], batch_idx: int) -> None:
        points, _ = gt_to_camera(batch["points"], batch["normals"], batch["RT"])
        labels = batch["label"].long()
        outputs: dict[tuple[str, int], dict[str, list[Tensor]]] = {}  # (control, touches fed) -> network output
        for mode, k in self._modes():
            mask = None if k == 0 else keep_first_touches(batch["touch_mask"], k)
            control = mode.partition(":")[2]
            inputs = self.control_batch(batch, control) if control else batch
            if inputs is None:
                continue
            # a refined mode reuses its unrefined mode's prediction ("visual+refine@k": the no-touch one, k touches)
            fed = 0 if mode.startswith("visual") else k
            if (control, fed) not in outputs:
                outputs[(control, fed)] = self(inputs, None if fed == 0 else mask)
            out = outputs[(control, fed)]
            if "+refine" in mode:
                assert mask is not None
                out = self.refined(out, batch, mask)
            metrics = self._metrics(out, points)
            cd = metrics["chamfer"].double()  # (B,)
            acc = self._acc[mode]
            acc["chamfer"] += cd.sum()
            acc["count"] += cd.numel()
            acc["touches"] += 0 if mask is None else mask.sum()
            if metrics["fscore"] is not None:
                acc["fscore"] += metrics["fscore"].double().sum(0)
            n_cls = acc["class_sum"].numel()
            if int(labels.max()) >= n_cls:
                raise ValueError(f"label {int(labels.max())} outside the {n_cls} known classes; pass class_names")
            acc["class_sum"].index_add_(0, labels, cd)
            acc["class_count"].index_add_(0, labels, torch.ones_like(cd))
            if self.hparams.export and not control:
                self._export(mode, out, points, labels, batch["image"])
            self.log(f"test/chamfer_{mode}", cd.mean(), batch_size=cd.numel(), sync_dist=True)

    def _export(
        self, mode: str, out: Mapping[str, list[Tensor]], points: Tensor, labels: Tensor, image: Tensor
    ) -> None:
        names = self._names()
        for b, label in enumerate(labels.tolist()):
            if (mode, label) in self._exported:
                continue
            self._exported.add((mode, label))
            cls = names[label] if label < len(names) else str(label)
            tag = f"{cls}_{mode.replace('@', '')}"
            verts, faces = out["verts"][-1][b].detach().cpu(), out["faces"][-1].detach().cpu()
            export_obj(verts, faces, self._out_dir() / "meshes" / f"{tag}.obj")
            render_mesh_comparison(
                verts,
                faces,
                points[b].detach().cpu(),
                self._out_dir() / "renders" / f"test_{tag}.png",
                f"{self.hparams.name} {cls} ({mode})",
                image=image[b].detach().cpu(),
            )

    def on_test_epoch_end(self) -> None:
        names = self._names()
        thresholds = [float(t) for t in self.hparams.fscore_thresholds]
        modes: dict[str, Any] = {}
        reduce = self.trainer.strategy.reduce
        for mode, k in self._modes():
            acc = {key: reduce(value, reduce_op="sum") for key, value in self._acc[mode].items()}
            count = float(acc["count"])
            if count == 0:
                continue
            per_class = {}
            for c in range(acc["class_sum"].numel()):
                if float(acc["class_count"][c]) > 0:
                    name = names[c] if c < len(names) else str(c)
                    per_class[name] = float(acc["class_sum"][c] / acc["class_count"][c])
            entry = {
                "chamfer": float(acc["chamfer"]) / count,
                "count": int(count),
                "touches": float(acc["touches"]) / count,
                "requested_touches": k,
                "per_class": per_class,
            }
            for i, t in enumerate(thresholds):
                entry[f"fscore@{t:g}"] = float(acc["fscore"][i]) / count
            modes[mode] = entry
        self.test_results = {
            "task": "reconstruction",
            "name": str(self.hparams.name),
            "modality": self.modality,
            "modes": modes,
        }
