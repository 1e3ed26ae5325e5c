"""The graph network that deforms the vision charts around the fixed touch charts (Smith et al., NeurIPS 2020).

Every vertex of the chart graph (:mod:`tvrecon.models.components.charts`: vision charts, then the touch charts) reads
``[image features pooled at its projection, its position, a chart flag]`` (the flag is 2 on a vision chart, 1 on a touch
chart in use, 0 on one not in use, as the authors'). A stack of ``num_layers`` graph convolutions of their "0N-GCN"
form (:class:`ChartGraphConv`: one linear map, then a third of the channels averaged over the neighbourhood and the rest
kept) predicts a position update per vertex; the touch charts' updates are set to zero, so they stay where the touch
put them. The same network runs ``iterations`` times (3 as the authors), the image features pooled again at the moved
vertices before each pass.

Image features: the four stages of a ResNet-18 (:class:`~tvrecon.models.components.backbone.ResNet18Backbone`,
the backbone of this project's Pixel2Mesh) pooled bilinearly at each vertex's projection with
:class:`~tvrecon.models.components.gcn.PerceptualPooling` (the camera model of
:mod:`tvrecon.models.components.projection`). The authors use a small CNN of their own; the same backbone on both rows
of Table 3 keeps the comparison about the mesh model. Without an image (``use_image=False``, the tactile-only model)
the vertices read position and flag only.

Size: the authors' search ends at 15 to 25 layers of 150 to 300 channels; the default here, 20 layers of 192 channels
(the width of this project's G-ResNet) over 3 passes, costs a training step of the same order as the Pixel2Mesh
deformer's on ~1,900 vertices. Initialisation: He-normal weights for the ReLU layers and a last layer scaled by 0.01,
so that an untrained network stays close to the initial layout (the authors use a wide uniform initialisation).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from tvrecon.models.components.gcn import PerceptualPooling
from tvrecon.utils.shape_check import check_shape

__all__ = ["ChartDeformer", "ChartGraphConv", "VISION_FLAG"]

VISION_FLAG = 2.0  # chart flag of a vision-chart vertex (a touch chart in use: 1, not in use: 0)


class ChartGraphConv(nn.Module):
    """``y = x W + b``, then the first ``C_out // 3`` channels replaced by their mean over each vertex's neighbourhood.

    Args:
        in_features: C_in.
        out_features: C_out (>= 1; with fewer than 3 channels the first one is averaged).
    """

    def __init__(self, in_features: int, out_features: int) -> None:
        super().__init__()
        self.linear = nn.Linear(in_features, out_features)
        self.shared = max(1, out_features // 3)

    def forward(self, x: Tensor, adjacency: Tensor) -> Tensor:
        """Args: x (B, V, C_in) float; adjacency (B V, B V) sparse row-normalised (:func:`~tvrecon.models.components.
        charts.chart_adjacency`). Returns (B, V, C_out) float."""
        B, V, _ = x.shape
        y = self.linear(x)  # (B, V, C_out)
        k = self.shared
        head = y[..., :k].reshape(B * V, k)
        with torch.autocast(device_type=x.device.type, enabled=False):  # sparse products stay in float32
            mixed = (adjacency @ head.float()).to(y.dtype).reshape(B, V, k)
        return torch.cat([mixed, y[..., k:]], dim=-1)


class ChartDeformer(nn.Module):
    """The chart deformation network (see the module doc).

    Args:
        feature_channels: channels of the image stages pooled by every vertex (ignored without image).
        hidden: width of the graph convolutions.
        num_layers: graph convolutions per pass (>= 2).
        iterations: passes of the same network.
        use_image: whether vertices read image features.
    """

    def __init__(
        self,
        feature_channels: Sequence[int] = (64, 128, 256, 512),
        hidden: int = 192,
        num_layers: int = 20,
        iterations: int = 3,
        use_image: bool = True,
    ) -> None:
        super().__init__()
        if num_layers < 2 or iterations < 1 or hidden < 3:
            raise ValueError(
                f"need num_layers >= 2, iterations >= 1 and hidden >= 3, got {num_layers}, {iterations}, {hidden}"
            )
        self.use_image = bool(use_image)
        self.iterations = int(iterations)
        self.pool = PerceptualPooling()
        in_features = (int(sum(feature_channels)) if self.use_image else 0) + 3 + 1
        sizes = [in_features] + [hidden] * (num_layers - 1) + [3]
        self.layers = nn.ModuleList([ChartGraphConv(a, b) for a, b in zip(sizes[:-1], sizes[1:])])
        with torch.no_grad():
            for layer in self.layers[:-1]:
                nn.init.kaiming_normal_(layer.linear.weight, nonlinearity="relu")
                layer.linear.bias.zero_()
            self.layers[-1].linear.weight.mul_(0.01)
            self.layers[-1].linear.bias.zero_()

    def offsets(self, x: Tensor, adjacency: Tensor) -> Tensor:
        """One pass of the graph network: x (B, V, C_in) vertex features -> (B, V, 3) position updates."""
        for layer in self.layers[:-1]:
            x = F.relu(layer(x, adjacency))
        return self.layers[-1](x, adjacency)

    def forward(
        self,
        verts: Tensor,
        flags: Tensor,
        movable: Tensor,
        adjacency: Tensor,
        features: Sequence[Tensor] | None = None,
        K: Tensor | None = None,
        image_size: tuple[int, int] | None = None,
    ) -> list[Tensor]:
        """Deform the charts.

        Args:
            verts: (B, V, 3) float initial camera-frame vertices (vision charts, then touch charts).
            flags: (B, V) float chart flags (see the module doc).
            movable: (V,) or (B, V) bool, False for the vertices held fixed (the touch charts).
            adjacency: (B V, B V) sparse row-normalised chart graph.
            features: the image stages (B, C_j, h_j, w_j) (required with ``use_image``); K: (B, 3, 3) float
                intrinsics; image_size: (H, W) of the view.

        Returns:
            the vertices after each pass, ``iterations`` x (B, V, 3) float.
        """
        check_shape(verts, "(B, V, 3)", "verts")
        B, V, _ = verts.shape
        if flags.shape != (B, V):
            raise ValueError(f"flags must have shape ({B}, {V}), got {tuple(flags.shape)}")
        if adjacency.shape != (B * V, B * V):
            raise ValueError(f"adjacency must have shape ({B * V}, {B * V}), got {tuple(adjacency.shape)}")
        if self.use_image and (features is None or K is None or image_size is None):
            raise ValueError("the deformer reads image features: give features, K and image_size")
        keep = (movable if movable.dim() == 2 else movable[None].expand(B, -1))[..., None].to(torch.bool)  # (B, V, 1)
        flag = flags.to(verts.dtype)[..., None]  # (B, V, 1)
        out = []
        x = verts
        for _ in range(self.iterations):
            parts = [x, flag]
            if self.use_image:
                assert features is not None and K is not None and image_size is not None
                parts.insert(0, self.pool(x, K, features, image_size))  # (B, V, sum C_j)
            x = torch.where(keep, x + self.offsets(torch.cat(parts, dim=-1), adjacency), x)  # touch charts stay
            out.append(x)
        return out
