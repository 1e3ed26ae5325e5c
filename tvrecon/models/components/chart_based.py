"""The Chart-based method (Smith et al., "3D Shape Reconstruction from Vision and Touch", NeurIPS 2020), the other row
of the paper's Table 3, on this project's data.

Pipeline (written from their paper and code, ``facebookresearch/3D-Vision-and-Touch``):

1. every touch in use becomes a touch chart, a 5 x 5 sheet of its local surface placed with the sensor's known pose
   (:mod:`tvrecon.models.components.touch_charts`), held fixed;
2. the vision charts start as a closed sphere-like layout (:class:`~tvrecon.models.components.charts.ChartTemplate`),
   and the touch charts join their graph (:func:`~tvrecon.models.components.charts.chart_adjacency`);
3. a graph network reading image features at the vertices' projections deforms the vision charts around the touch
   charts in 3 passes (:class:`~tvrecon.models.components.chart_deformer.ChartDeformer`);
4. the loss is the chamfer distance between points sampled on all charts and the ground truth
   (:class:`tvrecon.losses.charts.ChartLoss`), plus the touch-chart loss for a predicted touch chart.

Touch-chart source (``touch_chart``): ``"patch"`` takes the exact contact patch of each touch (the batch's
``patch_points`` / ``patch_mask``, from :func:`tvrecon.sim.sensor.patch.contact_patch`); ``"predicted"`` predicts it
from the tactile image with a U-Net trained by the authors' touch-chart loss against the exact patch
(``experiment=chart_based_predicted``). ``experiment=chart_based`` uses ``"patch"``: the authors' touch branch is
trained separately and reproduces the local surface closely on their simulator, and on ours the exact patch is that
surface; with it, the row measures the method's global part (charts and graph network) on the same local geometry
that touch geometry reads, and it trains no image network per touch.

Modes, one model class as in the authors' paper (they train one model per input): ``"chart_based"`` (view and touches;
with no touch the vision charts alone, Table 3's Visual cell of a model that reads touches), ``"chart_based_visual"``
(never reads touches; as in the authors' code its charts are not joined along their seams, see
:func:`~tvrecon.models.components.charts.chart_adjacency`) and ``"chart_based_tactile"`` (no image: the vertices read
positions and flags only).

Output (:meth:`ChartBasedReconstructor.forward`): the other reconstructors' dict, one entry per pass. Vertices are the
vision charts' and then T touch charts' (``T`` the batch's touch slots, 0 without touches); a touch chart not in use
(masked out, or without contact) is collapsed onto the first vision vertex, so its faces have no area and no metric or
sampled loss sees it.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from tvrecon.losses.charts import touch_chart_loss
from tvrecon.models.components.backbone import ResNet18Backbone
from tvrecon.models.components.chart_deformer import VISION_FLAG, ChartDeformer
from tvrecon.models.components.charts import ChartTemplate, chart_adjacency
from tvrecon.models.components.ellipsoid import mesh_edges
from tvrecon.models.components.reconstructor import check_view
from tvrecon.models.components.touch_charts import TouchChartPredictor, fit_touch_charts
from tvrecon.utils.geometry import world_to_camera
from tvrecon.utils.shape_check import check_shape

__all__ = ["CHART_MODES", "TOUCH_CHART_SOURCES", "ChartBasedReconstructor"]

CHART_MODES = ("chart_based", "chart_based_visual", "chart_based_tactile")
TOUCH_CHART_SOURCES = ("patch", "predicted")


class ChartBasedReconstructor(nn.Module):
    """Vision charts deformed around fixed touch charts by a graph network (see the module doc).

    Args:
        visual_backbone: image branch (default a randomly initialised ``ResNet18Backbone``); not kept in
            ``chart_based_tactile`` mode.
        chart_deformer: the graph network (default a :class:`ChartDeformer` with the backbone's channels; it must read
            no image in ``chart_based_tactile`` mode).
        template: the chart layout (default :class:`ChartTemplate`).
        touch_predictor: the touch branch of the ``"predicted"`` source (default :class:`TouchChartPredictor`).
        mode: one of :data:`CHART_MODES`.
        touch_chart: ``"patch"`` or ``"predicted"``.
        deformer, tactile_backbone, fusion: must be None (the keys of the Pixel2Mesh model's config, nulled by the
            experiment config).
    """

    reads_patches = True

    def __init__(
        self,
        visual_backbone: ResNet18Backbone | None = None,
        chart_deformer: ChartDeformer | None = None,
        template: ChartTemplate | None = None,
        touch_predictor: TouchChartPredictor | None = None,
        mode: str = "chart_based",
        touch_chart: str = "patch",
        deformer: nn.Module | None = None,
        tactile_backbone: nn.Module | None = None,
        fusion: nn.Module | None = None,
    ) -> None:
        super().__init__()
        if mode not in CHART_MODES:
            raise ValueError(f"mode must be one of {CHART_MODES}, got {mode!r}")
        if touch_chart not in TOUCH_CHART_SOURCES:
            raise ValueError(f"touch_chart must be one of {TOUCH_CHART_SOURCES}, got {touch_chart!r}")
        if deformer is not None or tactile_backbone is not None or fusion is not None:
            raise ValueError(
                "ChartBasedReconstructor takes its graph network as chart_deformer and has no tactile branch: set "
                "model.net.deformer, model.net.tactile_backbone and model.net.fusion to null"
            )
        self.mode = mode
        self.touch_chart = touch_chart
        self.uses_touches = mode != "chart_based_visual"
        self.uses_image = mode != "chart_based_tactile"
        self.visual: ResNet18Backbone | None = None
        if self.uses_image:
            self.visual = visual_backbone if visual_backbone is not None else ResNet18Backbone()
        if chart_deformer is None:
            channels = self.visual.channels if self.visual is not None else ()
            chart_deformer = ChartDeformer(feature_channels=channels, use_image=self.uses_image)
        if chart_deformer.use_image != self.uses_image:
            raise ValueError(
                f"mode {mode!r} {'reads' if self.uses_image else 'has no'} image: set chart_deformer.use_image="
                f"{str(self.uses_image).lower()}"
            )
        self.chart_deformer = chart_deformer
        self.template = template if template is not None else ChartTemplate()
        self.touch_predictor: TouchChartPredictor | None = None
        if self.uses_touches and touch_chart == "predicted":
            self.touch_predictor = touch_predictor if touch_predictor is not None else TouchChartPredictor()
        self._edges: dict[tuple[int, torch.device], Tensor] = {}

    def _faces_edges(self, touches: int) -> tuple[Tensor, Tensor]:
        faces = self.template.faces_with_touches(touches)
        key = (touches, faces.device)
        if key not in self._edges:
            self._edges[key] = mesh_edges(faces)
        return faces, self._edges[key]

    def touch_charts(
        self,
        tactile: Tensor | None,
        positions: Tensor,
        directions: Tensor,
        touch_mask: Tensor,
        patch_points: Tensor | None,
        patch_mask: Tensor | None,
    ) -> tuple[Tensor, Tensor, Tensor | None]:
        """World touch charts of the touches in use.

        Args:
            tactile: (B, T, 3, h, w) float (read by the ``"predicted"`` source); positions, directions: (B, T, 3) float
                world sensor poses; touch_mask: (B, T) bool, the touches to use.
            patch_points: (B, T, Q, 3) float world exact contact layer; patch_mask: (B, T, Q) bool (required by the
                ``"patch"`` source; the ``"predicted"`` source trains on them when given).

        Returns:
            charts (B, T, Vt, 3) float world (no gradient), used (B, T) bool (in use and with contact) and the
            touch-chart loss (0-dim, ``"predicted"`` with patches only; else None).
        """
        B, T = touch_mask.shape
        size = self.template.touch_size
        idx = torch.nonzero(touch_mask.reshape(-1), as_tuple=True)[0]  # (N,) touches in use
        origins, dirs = positions.reshape(B * T, 3)[idx], directions.reshape(B * T, 3)[idx]
        loss = None
        if self.touch_chart == "patch":
            if patch_points is None or patch_mask is None:
                raise ValueError("touch_chart='patch' reads the contact patches: give patch_points and patch_mask")
            points = patch_points.flatten(0, 1)[idx]
            mask = patch_mask.flatten(0, 1)[idx]
        else:
            assert self.touch_predictor is not None
            if tactile is None:
                raise ValueError("touch_chart='predicted' reads the tactile images: give tactile (B, T, 3, h, w)")
            check_shape(tactile, "(B, T, 3, h, w)", "tactile")
            points, mask = self.touch_predictor(tactile.flatten(0, 1)[idx], origins, dirs)
            if patch_points is not None and patch_mask is not None:
                loss = touch_chart_loss(points, mask, patch_points.flatten(0, 1)[idx], patch_mask.flatten(0, 1)[idx])
        charts, ok = fit_touch_charts(points.detach(), mask, origins, dirs, size)  # held fixed: no gradient
        full = charts.new_zeros(B * T, size * size, 3)
        full[idx] = charts
        used = torch.zeros(B * T, dtype=torch.bool, device=touch_mask.device)
        used[idx] = ok
        return full.reshape(B, T, size * size, 3), used.reshape(B, T), loss

    def forward(
        self,
        image: Tensor,
        K: Tensor,
        RT: Tensor,
        tactile: Tensor | None = None,
        positions: Tensor | None = None,
        directions: Tensor | None = None,
        touch_mask: Tensor | None = None,
        patch_points: Tensor | None = None,
        patch_normals: Tensor | None = None,
        patch_mask: Tensor | None = None,
    ) -> dict[str, list[Tensor]]:
        """Reconstruct the surface as charts in camera coordinates.

        Args:
            image: (B, 3, H, W) float view (not read in ``chart_based_tactile`` mode); K: (B, 3, 3); RT: (B, 3, 4)
                world->camera.
            tactile: (B, T, 3, h, w) float tactile images or None (no touch); positions, directions: (B, T, 3) float
                world sensor poses; touch_mask: (B, T) bool, the touches to use (None = all).
            patch_points, patch_normals: (B, T, Q, 3) float world contact layer; patch_mask: (B, T, Q) bool.

        Returns:
            per pass p (lists of ``iterations``): ``verts`` (B, V, 3) float camera frame (V = Vv + T Vt),
            ``verts_before`` (B, V, 3) the pass's input, ``faces`` (F, 3) int64, ``edges`` (E, 2) int64, ``init_verts``
            (V, 3) the initial layout (touch slots at its centre); and ``features`` (the image stages, empty without
            image), ``touch_charts`` (B, T, Vt, 3) camera frame and ``touch_used`` (B, T) bool (None without touches),
            ``touch_chart_loss`` (0-dim, the ``"predicted"`` source with patches only).
        """
        image_size = check_view(image, K, RT)
        B = image.shape[0]
        has_touch = self.uses_touches and (tactile is not None or patch_points is not None)
        if self.mode == "chart_based_tactile" and not has_touch:
            raise ValueError("chart_based_tactile mode needs touches (tactile, positions, directions, patches)")
        features: list[Tensor] = []
        if self.visual is not None:
            x = self.visual.stem(image)
            for j in range(len(self.visual.stages)):
                x = self.visual.stage(j, x)
                features.append(x)

        template = self.template
        Vv, Vt = template.verts.shape[0], template.touch_verts
        vision = template.verts.to(image.dtype)[None].expand(B, -1, -1)  # (B, Vv, 3)
        charts = used = loss = None
        T = 0
        if has_touch:
            if positions is None or directions is None:
                raise ValueError("positions (B, T, 3) and directions (B, T, 3) are required with touches")
            check_shape(positions, "(B, T, 3)", "positions")
            check_shape(directions, "(B, T, 3)", "directions")
            T = positions.shape[1]
            mask = torch.ones(B, T, dtype=torch.bool, device=image.device) if touch_mask is None else touch_mask
            if mask.shape != (B, T):
                raise ValueError(f"touch_mask must have shape ({B}, {T}), got {tuple(mask.shape)}")
            world, used, loss = self.touch_charts(tactile, positions, directions, mask.bool(), patch_points, patch_mask)
            charts = world_to_camera(world.reshape(B, T * Vt, 3), RT).to(image.dtype).reshape(B, T, Vt, 3)
            centre = template.verts.mean(0).to(image.dtype)
            slots = torch.where(used[..., None, None], charts, centre)  # (B, T, Vt, 3): unused at the centre
            verts0 = torch.cat([vision, slots.reshape(B, T * Vt, 3)], dim=1)
            flags = torch.cat([vision.new_full((B, Vv), VISION_FLAG), used.to(image.dtype).repeat_interleave(Vt, 1)], 1)
        else:
            verts0 = vision
            flags = vision.new_full((B, Vv), VISION_FLAG)
        movable = torch.arange(Vv + T * Vt, device=image.device) < Vv  # (V,)
        adjacency = chart_adjacency(template, used, B, seams=self.uses_touches)  # the authors' graphs (see there)
        passes = self.chart_deformer(verts0, flags, movable, adjacency, features or None, K, image_size)
        if used is not None:  # collapse the touch charts not in use onto the first vision vertex: no area
            hold = used.repeat_interleave(Vt, 1)[..., None]  # (B, T Vt, 1)
            passes = [torch.cat([p[:, :Vv], torch.where(hold, p[:, Vv:], p[:, :1])], dim=1) for p in passes]
        faces, edges = self._faces_edges(T)
        n = len(passes)
        init = torch.cat([template.verts, template.verts.mean(0, keepdim=True).expand(T * Vt, 3)]).to(image.dtype)
        out: dict[str, list[Tensor]] = {
            "verts": passes,
            "verts_before": [verts0, *passes[:-1]],
            "faces": [faces] * n,
            "edges": [edges] * n,
            "init_verts": [init] * n,
        }
        out["features"] = features
        out["touch_charts"] = charts  # type: ignore[assignment]
        out["touch_used"] = used  # type: ignore[assignment]
        if loss is not None:
            out["touch_chart_loss"] = loss  # type: ignore[assignment]
        return out
