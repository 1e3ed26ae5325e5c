"""LightningModule of tactile-visual mesh reconstruction (paper section 4.3, Tables 3 and 4).

Training: the ground-truth surface points and normals (world frame) are mapped to the camera frame with the
view's RT, the number of touches is drawn per sample (k ~ U{min_touches..max_touches}, later touches masked out;
the paper's "1 to 10 tactile images per iteration"; the reconstruction data presets serve all ``max_touches``
cached touches, so this is the only draw; which touches every path uses is summarised in
:mod:`tvrecon.data.touches.select`), and the Pixel2Mesh loss terms of
every deformation stage are weighted by the ``loss_weights`` mapping and summed.
Each term is logged (progress bar) as ``train/<term>``.

Validation logs ``val/loss`` and ``val/chamfer`` (the x1e-3 metric with every available touch) and renders the
first validation sample (prediction vs ground truth) to ``<run>/renders/epoch_<n>.png`` each epoch.

Test: the protocol of :mod:`tvrecon.models.recon_protocol` (modes, touch controls, per-class sums, mesh export),
mixed in by :class:`ReconstructionTestProtocol`; results in :attr:`ReconstructionModule.test_results`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import lightning as L
import torch
from torch import Tensor, nn

from tvrecon.losses.mesh import MeshLoss
from tvrecon.losses.metrics import chamfer_metric, fscore
from tvrecon.models.components.touch_geometry import patch_to_mesh_loss
from tvrecon.models.finite_loss import check_finite_loss
from tvrecon.models.mesh_figures import render_mesh_comparison
from tvrecon.models.optim import configure_optimizers, lr_scaled_groups
from tvrecon.models.recon_batch import PATCH_KEYS, gt_to_camera, keep_first_touches
from tvrecon.models.recon_protocol import ReconstructionTestProtocol

__all__ = ["ReconstructionModule"]

log = logging.getLogger(__name__)

MODALITY = {
    "fusion": "tactile_visual",
    "visual_only": "visual",
    "tactile_only": "tactile",
    "touch_geometry": "tactile_visual",  # tvrecon.models.components.touch_geometry (reads the contact patches)
    "chart_based": "tactile_visual",  # tvrecon.models.components.chart_based (Smith et al. 2020)
    "chart_based_visual": "visual",
    "chart_based_tactile": "tactile",
}


class ReconstructionModule(ReconstructionTestProtocol, L.LightningModule):
    """Trains and evaluates a :class:`~tvrecon.models.components.reconstructor.TactileVisualReconstructor`.

    Args:
        net: the built reconstruction network (its ``mode`` decides the evaluated modes).
        optimizer: partial optimizer (``_partial_: true``, e.g. AdamW), called with the parameters.
        scheduler: partial LR scheduler called with the optimizer (e.g. cosine), or None. Stepped per epoch.
        loss_weights: weight of each loss term (``chamfer``, ``normal``, ``edge``, ``laplacian``, ``move``;
            missing keys take :data:`tvrecon.losses.mesh.DEFAULT_WEIGHTS`, Pixel2Mesh's).
        stage_weights: factor of each deformation stage's loss (None = 1 for every stage).
        laplacian_stage_weights: extra factor of the Laplacian term per stage (Pixel2Mesh 0.2, 1, 1).
        move_from_stage: first deformation stage with the move term (Pixel2Mesh 1).
        min_touches, max_touches: range of the per-sample number of touches in training; ``min_touches=0`` trains on
            some touch-free samples (the model must then also answer with no touch; not for ``tactile_only``).
        touch_free_share: probability that a training sample has no touch at all; the others draw their count in
            [max(1, min_touches), max_touches]. None: counts uniform in [min_touches, max_touches] (with
            ``min_touches=0`` a share of 1 / (max_touches + 1)). Not for ``tactile_only``.
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
            patches (:func:`tvrecon.models.components.touch_geometry.patch_to_mesh_loss`), for networks that return
            ``touch`` (the touch-geometry model); 0 disables it.
        visual_loss_weight: weight of the view-only answer's own loss (the Pixel2Mesh losses on ``out["visual"]``),
            for networks that return one (the touch-residual model); 0 disables it.
        criterion: the training loss, called ``criterion(out, points, normals)`` -> dict of terms with ``loss``;
            None = the Pixel2Mesh losses above (``loss_weights`` ...). The Chart-based method brings its own
            (:class:`tvrecon.losses.charts.ChartLoss`).
        channels_last: keep the network's 4-D weights (the ResNet branches' convolutions) in the ``channels_last``
            memory format, so the convolutions run in NHWC (the same function; on some CPUs and GPUs faster).
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
        touch_free_share: float | None = None,
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
        visual_loss_weight: float = 1.0,
        criterion: nn.Module | None = None,
        channels_last: bool = False,
    ) -> None:
        super().__init__()
        # the network and the optimizer/scheduler factories stay out of the checkpoint's hparams: checkpoints then hold
        # plain data only and load with torch.load(weights_only=True); the model is rebuilt from the run's config
        self.save_hyperparameters(logger=False, ignore=["net", "optimizer", "scheduler", "criterion"])
        self.optimizer_factory = optimizer
        self.scheduler_factory = scheduler
        if not 0 <= min_touches <= max_touches or max_touches < 1:
            raise ValueError(
                f"need 0 <= min_touches <= max_touches and max_touches >= 1, got {min_touches} and {max_touches}"
            )
        if any(int(k) < 1 for k in eval_touches):
            raise ValueError(f"eval_touches must be positive touch counts, got {list(eval_touches)}")
        self.net = net
        self.channels_last = bool(channels_last)
        if self.channels_last:
            self.net.to(memory_format=torch.channels_last)  # 4-D weights only; the convolutions follow the weights
        net_mode = str(getattr(net, "mode", "fusion"))
        if net_mode not in MODALITY:
            raise ValueError(f"net.mode must be one of {sorted(MODALITY)}, got {net_mode!r}")
        self.modality = MODALITY[net_mode]
        if self.modality == "tactile" and min_touches < 1:
            raise ValueError("the tactile_only model needs at least one touch per sample: set min_touches >= 1")
        if touch_free_share is not None:
            if not 0.0 <= float(touch_free_share) < 1.0:
                raise ValueError(f"touch_free_share must be in [0, 1), got {touch_free_share}")
            if self.modality == "tactile" and touch_free_share > 0:
                raise ValueError(
                    "the tactile_only model needs at least one touch per sample: set touch_free_share=null"
                )
        self.criterion = MeshLoss(
            weights=dict(loss_weights or {}),
            stage_weights=stage_weights,
            laplacian_stage_weights=laplacian_stage_weights,
            move_from_stage=move_from_stage,
        )
        if criterion is not None:  # a network with a loss of its own (the Chart-based method)
            self.criterion = criterion
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
            batch: collated sample dict (``docs/reference/batch-schema.md``): image (B,3,H,W), K (B,3,3), RT (B,3,4),
                tactile (B,T,3,h,w), positions (B,T,3), directions (B,T,3).
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
        """(B,) int64 touch counts, one per sample: uniform in [min_touches, max_touches], or, with a
        ``touch_free_share`` p, 0 with probability p and uniform in [max(1, min_touches), max_touches] otherwise."""
        lo, hi = int(self.hparams.min_touches), int(self.hparams.max_touches)
        share = self.hparams.get("touch_free_share")
        if share is None:
            return torch.randint(lo, hi + 1, (batch_size,))
        counts = torch.randint(max(1, lo), hi + 1, (batch_size,))
        return torch.where(torch.rand(batch_size) < float(share), torch.zeros_like(counts), counts)

    def training_mask(self, batch: Mapping[str, Tensor]) -> Tensor | None:
        """The touches a training step reads: (B, T) bool, each sample's first k valid touches with k drawn by
        :meth:`_touch_counts`; None for the visual-only model."""
        if self.modality == "visual":
            return None
        return keep_first_touches(batch["touch_mask"], self._touch_counts(len(batch["touch_mask"])))

    def training_step(self, batch: dict[str, Tensor], batch_idx: int) -> Tensor:
        points, normals = gt_to_camera(batch["points"], batch["normals"], batch["RT"])
        out = self(batch, self.training_mask(batch))
        terms = self.compute_losses(out, points, normals)
        weight = float(self.hparams.get("patch_loss_weight", 0.0))
        if weight > 0 and out.get("touch") is not None:
            terms["patch"] = sum(patch_to_mesh_loss(v, out["touch"]) for v in out["verts"])
            terms["loss"] = terms["loss"] + weight * terms["patch"]
        visual_weight = float(self.hparams.get("visual_loss_weight", 1.0))
        if visual_weight > 0 and out.get("visual") is not None:
            # networks whose view-only answer is a path of its own (touch_residual) train it on every sample
            terms["visual"] = self.compute_losses(out["visual"], points, normals)["loss"]
            terms["loss"] = terms["loss"] + visual_weight * terms["visual"]
        check_finite_loss(self, terms)  # a diverged run stops here, not with NaN results at the end
        B = points.shape[0]
        for key, value in terms.items():
            self.log(f"train/{key}", value, prog_bar=True, batch_size=B)
        return terms["loss"]

    def full_mask(self, batch: Mapping[str, Tensor]) -> Tensor | None:
        """The touches validation reads: (B, T) bool, each sample's first ``max_touches`` valid touches; None for
        the visual-only model."""
        if self.modality == "visual":
            return None
        return keep_first_touches(batch["touch_mask"], int(self.hparams.max_touches))

    def validation_step(self, batch: dict[str, Tensor], batch_idx: int) -> None:
        points, normals = gt_to_camera(batch["points"], batch["normals"], batch["RT"])
        out = self(batch, self.full_mask(batch))
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

    def _out_dir(self) -> Path:
        return Path(self.output_dir or self.trainer.default_root_dir)

    def configure_optimizers(self) -> Any:
        scales = self.hparams.get("lr_scales")
        params = (
            lr_scaled_groups(self.named_parameters(), self.optimizer_factory, scales)
            if scales
            else [p for p in self.trainer.model.parameters() if p.requires_grad]  # freeze= leaves some out
        )
        return configure_optimizers(params, self.optimizer_factory, self.scheduler_factory)
