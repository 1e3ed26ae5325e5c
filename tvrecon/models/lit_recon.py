"""LightningModule of tactile-visual mesh reconstruction (paper section 4.3, Tables 3 and 4).

Training: the ground-truth surface points and normals (world frame) are mapped to the camera frame with the
view's RT, the number of touches is drawn per sample (k ~ U{min_touches..max_touches}, later touches masked out;
the paper's "1 to 10 tactile images per iteration"; this is the only draw: the reconstruction data presets serve
all ``max_touches`` cached touches, so training sees k uniform rather than the smaller min of two draws; which
touches every path uses is summarised in :mod:`tvrecon.data.touch_select`), and the Pixel2Mesh loss terms of
every deformation stage are weighted by the ``loss_weights`` mapping and summed.
Each term is logged (progress bar) as ``train/<term>``.

Validation logs ``val/loss`` and ``val/chamfer`` (the x1e-3 metric with every available touch) and renders the
first validation sample (prediction vs ground truth) to ``<run>/renders/epoch_<n>.png`` each epoch.

Test: every batch is evaluated in the modes of the network (see :mod:`tvrecon.tables`):

- ``mode="fusion"``: ``"visual"`` (every touch masked out) and ``"tv@k"`` for k in ``eval_touches``;
- ``mode="visual_only"``: ``"visual"``;
- ``mode="tactile_only"``: ``"tactile@k"`` (the network blanks the view itself).

With ``touch_controls`` a model that reads touches is also tested with its most touches whose content is replaced
(the positions kept, so the same pixels receive an embedding): ``"<mode>:other"`` takes the tactile images and
directions of the next sample in the batch (another object; batches of one sample are skipped), ``"<mode>:blank"``
zero tactile images. A model that has learned to read the touches does worse in both than with its own.

"first k touches" means the k first valid touches of the sample (fewer if the sample has fewer; the mean number
actually used is reported per mode as ``touches``). Per mode it accumulates the mean chamfer (x1e-3), F-scores and
the per-class chamfer, exports one predicted mesh per class as ``.obj`` and one side-by-side render per class, and
stores the JSON-ready dict in :attr:`ReconstructionModule.test_results`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import lightning as L
import torch
from torch import Tensor, nn

from tvrecon.geometry import rotate_to_camera, world_to_camera
from tvrecon.losses.mesh import MeshLoss
from tvrecon.losses.metrics import chamfer_metric, fscore
from tvrecon.models.optim import configure_optimizers, lr_scaled_groups
from tvrecon.models.refine import refine_to_patches
from tvrecon.models.touch_geometry import patch_to_mesh_loss
from tvrecon.viz import export_obj, render_mesh_comparison

__all__ = ["TOUCH_CONTROLS", "ReconstructionModule", "gt_to_camera", "keep_first_touches"]

log = logging.getLogger(__name__)

MODALITY = {
    "fusion": "tactile_visual",
    "visual_only": "visual",
    "tactile_only": "tactile",
    "touch_geometry": "tactile_visual",  # tvrecon.models.touch_geometry (reads the contact patches)
}
PATCH_KEYS = ("patch_points", "patch_normals", "patch_mask")
TOUCH_CONTROLS = ("other", "blank")  # test modes with the touches' content replaced (touch_controls)


def gt_to_camera(points: Tensor, normals: Tensor, RT: Tensor) -> tuple[Tensor, Tensor]:
    """Map ground-truth surface points and normals from the world (object) frame to the camera frame.

    Args:
        points: (B, N, 3) float world points.
        normals: (B, N, 3) float world unit normals.
        RT: (B, 3, 4) float world->camera ``[R|t]``.

    Returns:
        points (B, N, 3) ``R x + t`` and normals (B, N, 3) ``R n``, float.
    """
    if points.dim() != 3 or points.shape[-1] != 3 or normals.shape != points.shape:
        raise ValueError(
            f"points and normals must both have shape (B, N, 3), got {tuple(points.shape)} and {tuple(normals.shape)}"
        )
    if RT.shape != (points.shape[0], 3, 4):
        raise ValueError(f"RT must have shape (B, 3, 4) with B={points.shape[0]}, got {tuple(RT.shape)}")
    return world_to_camera(points, RT), rotate_to_camera(normals, RT)


def keep_first_touches(touch_mask: Tensor, k: int | Tensor) -> Tensor:
    """Keep the first ``k`` valid touches of each sample.

    Args:
        touch_mask: (B, T) bool, True for real touches.
        k: touches to keep (0 masks every touch out): one int for the batch, or a (B,) integer tensor per sample.

    Returns:
        (B, T) bool mask with at most k (or k[b]) True per row.
    """
    if touch_mask.dim() != 2 or touch_mask.dtype != torch.bool:
        raise ValueError(f"touch_mask must be a (B, T) bool tensor, got {tuple(touch_mask.shape)} {touch_mask.dtype}")
    if isinstance(k, Tensor):
        if k.shape != (touch_mask.shape[0],) or k.is_floating_point() or k.dtype == torch.bool:
            raise ValueError(
                f"per-sample k must be a ({touch_mask.shape[0]},) integer tensor, got {tuple(k.shape)} {k.dtype}"
            )
        if bool((k < 0).any()):
            raise ValueError(f"k must be >= 0, got {k.tolist()}")
        limit = k.to(touch_mask.device).unsqueeze(1)  # (B, 1)
    else:
        if k < 0:
            raise ValueError(f"k must be >= 0, got {k}")
        limit = k
    rank = touch_mask.long().cumsum(dim=1)  # (B, T): 1-based index among valid touches
    return touch_mask & (rank <= limit)


class ReconstructionModule(L.LightningModule):
    """Trains and evaluates a :class:`~tvrecon.models.reconstructor.TactileVisualReconstructor`.

    Args:
        net: the built reconstruction network (its ``mode`` decides the evaluated modes).
        optimizer: partial optimizer (``_partial_: true``, e.g. AdamW), called with the parameters.
        scheduler: partial LR scheduler called with the optimizer (e.g. cosine), or None. Stepped per epoch.
        loss_weights: weight of each loss term (``chamfer``, ``normal``, ``edge``, ``laplacian``, ``move``;
            missing keys take :data:`tvrecon.losses.mesh.DEFAULT_WEIGHTS`, Pixel2Mesh's).
        stage_weights: factor of each deformation stage's loss (None = 1 for every stage).
        laplacian_stage_weights: extra factor of the Laplacian term per stage (Pixel2Mesh 0.2, 1, 1).
        move_from_stage: first deformation stage with the move term (Pixel2Mesh 1).
        min_touches, max_touches: range of the per-batch number of touches in training.
        eval_touches: touch counts of the test modes (Table 3 columns).
        metric_points: points sampled on each surface for the chamfer metric (1,000 in the paper).
        fscore_thresholds: distance thresholds of the F-scores (Pixel2Mesh tau = 0.01 and 2 tau).
        metric_seed: seed of the metric's surface sampling.
        class_names: label -> class name; None reads ``datamodule.library.classes`` at test time.
        name: experiment name stored in the results (row label of the tables).
        export: write one ``.obj`` and one render per class and mode at test time.
        render_every_n_epochs: period of the validation render (0 disables it).
        output_dir: folder for renders and meshes (None = the trainer's ``default_root_dir``).
        lr_scales: parameter name prefix -> learning-rate factor (e.g. ``{"net.fusion": 10}``); None = one lr.
        touch_controls: also test with the touches' content replaced (``:other``, ``:blank``; see module doc).
        refine: also test with test-time touch refinement (:mod:`tvrecon.models.refine`): ``"<mode>+refine"`` for
            every mode with touches, and ``"visual+refine@k"`` for a visual-only model (its no-touch prediction pulled
            onto the first k touches' contact patches). Needs the samples' ``patch_points`` / ``patch_mask``.
        refine_steps: Adam steps of the refinement.
        patch_loss_weight: weight of the training term pulling every stage's mesh through the used touches' contact
            patches (:func:`tvrecon.models.touch_geometry.patch_to_mesh_loss`), for networks that return ``touch``
            (the touch-geometry model); 0 disables it.
    """

    def __init__(
        self,
        net: nn.Module,
        optimizer: Callable[..., torch.optim.Optimizer],
        scheduler: Callable[..., Any] | None = None,
        loss_weights: Mapping[str, float] | None = None,
        stage_weights: Sequence[float] | None = None,
        laplacian_stage_weights: Sequence[float] = (0.2, 1.0, 1.0),
        move_from_stage: int = 1,
        min_touches: int = 1,
        max_touches: int = 10,
        eval_touches: Sequence[int] = (2, 5, 10),
        metric_points: int = 1000,
        fscore_thresholds: Sequence[float] = (0.01, 0.02),
        metric_seed: int = 0,
        class_names: Sequence[str] | None = None,
        name: str = "full",
        export: bool = True,
        render_every_n_epochs: int = 1,
        output_dir: str | None = None,
        lr_scales: Mapping[str, float] | None = None,
        touch_controls: bool = False,
        refine: bool = False,
        refine_steps: int = 40,
        patch_loss_weight: float = 0.0,
    ) -> None:
        super().__init__()
        # the network and the optimizer/scheduler factories stay out of the checkpoint's hparams: checkpoints then hold
        # plain data only and load with torch.load(weights_only=True); the model is rebuilt from the run's config
        self.save_hyperparameters(logger=False, ignore=["net", "optimizer", "scheduler"])
        self.optimizer_factory = optimizer
        self.scheduler_factory = scheduler
        if not 1 <= min_touches <= max_touches:
            raise ValueError(f"need 1 <= min_touches <= max_touches, got {min_touches} and {max_touches}")
        if any(int(k) < 1 for k in eval_touches):
            raise ValueError(f"eval_touches must be positive touch counts, got {list(eval_touches)}")
        self.net = net
        net_mode = str(getattr(net, "mode", "fusion"))
        if net_mode not in MODALITY:
            raise ValueError(f"net.mode must be one of {sorted(MODALITY)}, got {net_mode!r}")
        self.modality = MODALITY[net_mode]
        self.criterion = MeshLoss(
            weights=dict(loss_weights or {}),
            stage_weights=stage_weights,
            laplacian_stage_weights=laplacian_stage_weights,
            move_from_stage=move_from_stage,
        )
        self.eval_touches = sorted({int(k) for k in eval_touches})
        self.class_names = None if class_names is None else [str(c) for c in class_names]
        self.output_dir = output_dir
        self.test_results: dict[str, Any] | None = None
        self._val_sample: dict[str, Tensor] | None = None
        self._acc: dict[str, dict[str, Tensor]] = {}
        self._exported: set[tuple[str, int]] = set()

    # ------------------------------------------------------------------ forward and losses
    def forward(self, batch: Mapping[str, Tensor], touch_mask: Tensor | None) -> dict[str, list[Tensor]]:
        """Run the network on a batch with the given touch mask (None = no touch at all).

        Args:
            batch: collated sample dict (image (B,3,H,W), K (B,3,3), RT (B,3,4), tactile (B,T,3,h,w),
                positions (B,T,3), directions (B,T,3)).
            touch_mask: (B, T) bool, or None to run without any touch.
        Returns:
            the network's output dict (``verts`` per stage (B, V_s, 3) camera frame, ``faces`` (F_s, 3), ...).
        """
        if touch_mask is None or self.modality == "visual" or not bool(touch_mask.any()):
            if self.modality == "tactile":
                raise ValueError("the tactile_only model needs at least one touch")
            return self.net(batch["image"], batch["K"], batch["RT"])
        if getattr(self.net, "reads_patches", False):
            missing = [key for key in PATCH_KEYS if key not in batch]
            if missing:
                raise ValueError(
                    f"the {self.net.mode} model reads the touches' contact patches; the batch lacks {missing} "
                    "(ReconstructionDataset provides them)"
                )
            patches = {key: batch[key] for key in PATCH_KEYS}
        else:
            patches = {}
        return self.net(
            batch["image"],
            batch["K"],
            batch["RT"],
            batch["tactile"],
            batch["positions"],
            batch["directions"],
            touch_mask,
            **patches,
        )

    def compute_losses(self, out: Mapping[str, list[Tensor]], points: Tensor, normals: Tensor) -> dict[str, Tensor]:
        """Weighted loss terms summed over the deformation stages, plus their total ``loss``.

        Args:
            out: network output (per stage ``verts`` (B,V,3), ``verts_before`` (B,V,3), ``edges`` (E,2)).
            points: (B, N, 3) float camera-frame ground-truth points; normals: (B, N, 3) float.
        Returns:
            dict term -> 0-dim float tensor: the unweighted terms summed over stages (``chamfer``, ``normal``,
            ``edge``, ``laplacian``, ``move``), ``chamfer_final`` and ``loss`` (the weighted total).
        """
        return dict(self.criterion(out, points, normals))

    def _touch_counts(self, batch_size: int) -> Tensor:
        """(B,) int64 touch counts drawn uniformly in [min_touches, max_touches], one per sample."""
        lo, hi = int(self.hparams.min_touches), int(self.hparams.max_touches)
        return torch.randint(lo, hi + 1, (batch_size,))

    def training_step(self, batch: dict[str, Tensor], batch_idx: int) -> Tensor:
        points, normals = gt_to_camera(batch["points"], batch["normals"], batch["RT"])
        mask = None
        if self.modality != "visual":
            counts = self._touch_counts(len(batch["touch_mask"]))
            mask = keep_first_touches(batch["touch_mask"], counts)
        out = self(batch, mask)
        terms = self.compute_losses(out, points, normals)
        weight = float(self.hparams.get("patch_loss_weight", 0.0))
        if weight > 0 and out.get("touch") is not None:
            terms["patch"] = sum(patch_to_mesh_loss(v, out["touch"]) for v in out["verts"])
            terms["loss"] = terms["loss"] + weight * terms["patch"]
        B = points.shape[0]
        for key, value in terms.items():
            self.log(f"train/{key}", value, prog_bar=True, batch_size=B)
        return terms["loss"]

    def _full_mask(self, batch: Mapping[str, Tensor]) -> Tensor | None:
        if self.modality == "visual":
            return None
        return keep_first_touches(batch["touch_mask"], int(self.hparams.max_touches))

    def validation_step(self, batch: dict[str, Tensor], batch_idx: int) -> None:
        points, normals = gt_to_camera(batch["points"], batch["normals"], batch["RT"])
        out = self(batch, self._full_mask(batch))
        terms = self.compute_losses(out, points, normals)
        B = points.shape[0]
        self.log("val/loss", terms["loss"], prog_bar=True, batch_size=B, sync_dist=True)
        cd = self._metrics(out, points)["chamfer"]
        self.log("val/chamfer", cd.mean(), prog_bar=True, batch_size=B, sync_dist=True)
        if batch_idx == 0:
            self._val_sample = {
                "verts": out["verts"][-1][0].detach().cpu(),
                "faces": out["faces"][-1].detach().cpu(),
                "points": points[0].detach().cpu(),
                "image": batch["image"][0].detach().cpu(),
            }

    def on_validation_epoch_end(self) -> None:
        every = int(self.hparams.render_every_n_epochs)
        sample, self._val_sample = self._val_sample, None
        if sample is None or every <= 0 or self.trainer.sanity_checking or not self.trainer.is_global_zero:
            return
        if self.current_epoch % every != 0:
            return
        path = self._out_dir() / "renders" / f"epoch_{self.current_epoch:03d}.png"
        render_mesh_comparison(
            sample["verts"],
            sample["faces"],
            sample["points"],
            path,
            f"{self.hparams.name} epoch {self.current_epoch}",
            image=sample["image"],
        )

    # ------------------------------------------------------------------ metrics
    def _metrics(self, out: Mapping[str, list[Tensor]], points: Tensor) -> dict[str, Tensor]:
        """Chamfer x1e-3 (B,) and F-scores (B, len(thresholds)) of the last stage's mesh vs the GT points."""
        verts, faces = out["verts"][-1].detach(), out["faces"][-1]
        n, seed = int(self.hparams.metric_points), int(self.hparams.metric_seed)
        thresholds = [float(t) for t in self.hparams.fscore_thresholds]
        return {
            "chamfer": chamfer_metric(verts, faces, points, num_samples=n, seed=seed),
            "fscore": fscore(verts, faces, points, thresholds, num_samples=n, seed=seed) if thresholds else None,
        }

    def _modes(self) -> list[tuple[str, int]]:
        if self.modality == "visual":
            refined = [(f"visual+refine@{k}", k) for k in self.eval_touches] if self.hparams.get("refine") else []
            return [("visual", 0), *refined]
        prefix = "tactile" if self.modality == "tactile" else "tv"
        modes = [] if self.modality == "tactile" else [("visual", 0)]
        modes += [(f"{prefix}@{k}", k) for k in self.eval_touches]
        if self.hparams.get("touch_controls"):
            k = self.eval_touches[-1]
            modes += [(f"{prefix}@{k}:{control}", k) for control in TOUCH_CONTROLS]
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

    @staticmethod
    def control_batch(batch: Mapping[str, Tensor], control: str) -> dict[str, Tensor] | None:
        """The batch with its touches' content replaced (positions and masks kept), None if it cannot be.

        Args:
            batch: collated sample dict with ``tactile`` (B, T, 3, h, w) and ``directions`` (B, T, 3).
            control: ``"other"`` (the next sample's tactile images and directions; None for B = 1) or ``"blank"``
                (zero tactile images, own directions). The contact patches (``patch_*``, when present) follow the
                content: ``"other"`` takes the next sample's (its world points: the other object's surface), and
                ``"blank"`` has no contact point (a blank image is the pad at rest: nothing touched).
        """
        out = dict(batch)
        if control == "other":
            if batch["tactile"].shape[0] < 2:
                return None
            out["tactile"] = batch["tactile"].roll(-1, dims=0)
            out["directions"] = batch["directions"].roll(-1, dims=0)
            for key in PATCH_KEYS:
                if key in batch:
                    out[key] = batch[key].roll(-1, dims=0)
        elif control == "blank":
            out["tactile"] = torch.zeros_like(batch["tactile"])
            if "patch_mask" in batch:
                out["patch_mask"] = torch.zeros_like(batch["patch_mask"])
        else:
            raise ValueError(f"control must be one of {TOUCH_CONTROLS}, got {control!r}")
        return out

    def _names(self) -> list[str]:
        if self.class_names is not None:
            return self.class_names
        dm = getattr(self.trainer, "datamodule", None)
        library = getattr(dm, "library", None)
        classes = getattr(library, "classes", None)
        return [str(c) for c in classes] if classes is not None else []

    def _out_dir(self) -> Path:
        return Path(self.output_dir or self.trainer.default_root_dir)

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

    def configure_optimizers(self) -> Any:
        scales = self.hparams.get("lr_scales")
        params = (
            lr_scaled_groups(self.named_parameters(), self.optimizer_factory, scales)
            if scales
            else self.trainer.model.parameters()
        )
        return configure_optimizers(params, self.optimizer_factory, self.scheduler_factory)
