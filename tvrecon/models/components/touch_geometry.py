"""Touch-geometry reconstruction (beyond the paper): every deformer vertex reads the 3D contact patches near it.

The paper's model uses a touch's 3D position only to choose the pixel its tactile embedding is added to, so the
depth that a single view lacks never reaches the mesh. Here each touch enters as what it measured: its contact patch
(:func:`tvrecon.sim.sensor.patch.contact_patch`, the pad's contact layer mapped back to world points and normals), in
the camera frame of the predicted mesh. At every deformation stage each vertex ``v`` gets, for a few length scales
``sigma``, the softmax-weighted (``exp(-|p - v|^2 / 2 sigma^2)``) mean offset to the patch points ``p``, their mean
normal and a contact density ``1 - exp(-sum_p w_vp)`` (:func:`touch_features`). The features are concatenated to the
Pixel2Mesh input ``g_v`` (paper eq. 13) and added, through a linear map each, before every G-ResNet block
(:class:`TouchDeformationBlock`). A training term pulls the surface through the patches
(:func:`patch_to_mesh_loss`, ``ReconstructionModule(patch_loss_weight=...)``).

No tactile ResNet: the patch is the tactile image itself, placed in 3D (position + R(direction) (lattice + image)),
so a training step costs about what the visual-only baseline's does. Any number of touches 0..10 per sample works:
padding and non-contact points are masked; with no contact point every feature is zero (the model then sees what a
visual-only model sees).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from tvrecon.losses.chamfer import nearest_neighbors
from tvrecon.models.components.backbone import ResNet18Backbone
from tvrecon.models.components.gcn import DeformationBlock, GraphInput, MeshDeformer, NeighbourOperator
from tvrecon.models.components.reconstructor import check_view
from tvrecon.utils.geometry import rotate_to_camera, world_to_camera
from tvrecon.utils.shape_check import check_shape

__all__ = [
    "TouchDeformationBlock",
    "TouchGeometryDeformer",
    "TouchGeometryReconstructor",
    "TouchPoints",
    "patch_to_mesh_loss",
    "select_patch_points",
    "touch_features",
]

FEATURES_PER_SCALE = 7  # mean offset (3), mean normal (3), contact density (1)


class TouchPoints(NamedTuple):
    """Contact points of a batch's touches, compacted and in one frame.

    points: (B, P, 3) float; normals: (B, P, 3) float unit; mask: (B, P) bool, True for a real contact point.
    """

    points: Tensor
    normals: Tensor
    mask: Tensor


def select_patch_points(
    points: Tensor, normals: Tensor, patch_mask: Tensor, touch_mask: Tensor | None = None, per_touch: int = 64
) -> TouchPoints:
    """Up to ``per_touch`` contact points of every used touch, spread evenly over its contact area.

    A 32x32 pad gives about 300 contact points per touch; a subset keeps the vertex-to-point search cheap (features
    are soft averages, so an even subset loses little). The points of each touch are taken in the pad's row-major
    order at even steps through its contact points.

    Args:
        points: (B, T, Q, 3) float contact-layer points (``patch_points``); normals: (B, T, Q, 3) float.
        patch_mask: (B, T, Q) bool, True where the pad is in contact.
        touch_mask: (B, T) bool, the touches to use (None = all).
        per_touch: points kept per touch (m).

    Returns:
        :class:`TouchPoints` with P = T * m.
    """
    check_shape(points, "(B, T, Q, 3)", "points")
    if normals.shape != points.shape:
        raise ValueError(f"normals must have the shape of points {tuple(points.shape)}, got {tuple(normals.shape)}")
    B, T, Q, _ = points.shape
    if patch_mask.shape != (B, T, Q) or patch_mask.dtype != torch.bool:
        raise ValueError(f"patch_mask must be a ({B}, {T}, {Q}) bool tensor, got {tuple(patch_mask.shape)}")
    if per_touch < 1:
        raise ValueError(f"per_touch must be >= 1, got {per_touch}")
    valid = patch_mask
    if touch_mask is not None:
        if touch_mask.shape != (B, T):
            raise ValueError(f"touch_mask must have shape ({B}, {T}), got {tuple(touch_mask.shape)}")
        valid = valid & touch_mask[:, :, None].to(torch.bool)
    m = min(int(per_touch), Q)
    order = torch.argsort(valid.to(torch.int8), dim=2, descending=True, stable=True)  # (B, T, Q): contact first
    count = valid.sum(2, keepdim=True)  # (B, T, 1)
    j = torch.arange(m, device=points.device)  # (m,)
    # even steps through the `count` contact points when there are more than m, else the first m (masked past count)
    spread = torch.div(j * count.clamp_min(m), m, rounding_mode="floor")  # (B, T, m)
    pick = torch.gather(order, 2, spread.clamp_max(Q - 1))  # (B, T, m) index into Q
    keep = j < count  # (B, T, m)

    def take(x: Tensor) -> Tensor:
        return torch.gather(x, 2, pick[..., None].expand(-1, -1, -1, 3)).reshape(B, T * m, 3)

    return TouchPoints(take(points), take(normals), keep.reshape(B, T * m))


def touch_features(verts: Tensor, touch: TouchPoints, sigmas: Sequence[float]) -> Tensor:
    """Per-vertex features of the contact points near each vertex, at several length scales.

    For each ``sigma``: with ``w_vp = exp(-|p - v|^2 / (2 sigma^2))`` over the real contact points p,
    the softmax-weighted mean offset ``sum_p a_vp (p - v)`` and normal ``sum_p a_vp n_p`` (``a_vp = w_vp / sum_p w_vp``,
    so a far vertex reads the offset to its nearest contact region) and the density ``1 - exp(-sum_p w_vp)``.
    Samples without contact points get zeros. No gradient flows to ``verts`` (the features are inputs).

    Args:
        verts: (B, V, 3) float vertices, same frame as ``touch``.
        touch: contact points (B, P, 3), normals (B, P, 3), mask (B, P).
        sigmas: length scales (object units; objects have max extent 1).

    Returns:
        (B, V, 7 * len(sigmas)) float, in verts' dtype.
    """
    check_shape(verts, "(B, V, 3)", "verts")
    B, V, _ = verts.shape
    if touch.points.shape[0] != B or touch.mask.shape != touch.points.shape[:2]:
        raise ValueError(
            f"touch points (B, P, 3) and mask (B, P) must match B={B}, got {tuple(touch.points.shape)} and "
            f"{tuple(touch.mask.shape)}"
        )
    if not sigmas or any(not float(s) > 0 for s in sigmas):
        raise ValueError(f"sigmas must be positive length scales, got {list(sigmas)}")
    with torch.no_grad(), torch.autocast(verts.device.type, enabled=False):  # distances need float32
        v = verts.detach().float()
        p = touch.points.detach().float()
        n = touch.normals.detach().float()
        mask = touch.mask[:, None, :]  # (B, 1, P)
        has = touch.mask.any(1)[:, None, None]  # (B, 1, 1)
        # |v - p|^2 = |v|^2 + |p|^2 - 2 v.p about the points' centre: one batched product, never a (B, V, P, 3) block
        real = touch.mask[..., None].float()  # (B, P, 1)
        centre = (p * real).sum(1, keepdim=True) / real.sum(1, keepdim=True).clamp_min(1.0)  # (B, 1, 3) real points
        vc, pc = v - centre, p - centre
        d2 = torch.baddbmm(pc.square().sum(-1)[:, None, :], vc, pc.transpose(1, 2), alpha=-2.0)  # (B, V, P)
        d2 = d2.add_(vc.square().sum(-1, keepdim=True)).clamp_min_(0.0)
        keep = mask | ~has  # (B, 1, P): the real points; every point where a sample has none (uniform junk, zeroed)
        out = []
        for sigma in sigmas:
            logits = (d2 * (-0.5 / float(sigma) ** 2)).masked_fill_(~keep, -math.inf)  # (B, V, P)
            top = logits.amax(dim=-1, keepdim=True)  # (B, V, 1)
            # float32 exp leaves its vectorised path below about -87 (about 6x slower on this work); terms that small
            # (under 2e-38 of the largest) are raised to exp(-87) and the masked points put back to exactly 0
            e = torch.exp((logits - top).clamp_min_(-87.0)).masked_fill_(~keep, 0.0)  # (B, V, P)
            total = e.sum(dim=-1, keepdim=True)  # (B, V, 1)
            a = e / total  # (B, V, P) the softmax over the points
            lse = top + torch.log(total)  # (B, V, 1) logsumexp of the logits
            offset = a @ p - v  # (B, V, 3)
            normal = a @ n  # (B, V, 3)
            density = 1.0 - torch.exp(-torch.exp(lse))  # (B, V, 1)
            out += [offset, normal, density.nan_to_num(0.0)]
        feats = torch.cat(out, dim=-1)  # (B, V, 7 S)
        feats = torch.where(has, feats, torch.zeros_like(feats))
    return feats.to(verts.dtype)


def patch_to_mesh_loss(verts: Tensor, touch: TouchPoints) -> Tensor:
    """Mean squared distance of every real contact point to its nearest predicted vertex (the surface must pass
    through the patches).

    Args:
        verts: (B, V, 3) float predicted vertices; touch: contact points in the same frame.

    Returns:
        0-dim float: the mean over the batch's contact points (0 when there is none).
    """
    m = touch.mask.to(verts.dtype)  # (B, P)
    if not bool(touch.mask.any()):
        return verts.sum() * 0.0
    dist, _ = nearest_neighbors(touch.points.to(verts.dtype), verts)  # (B, P)
    return (dist * m).sum() / m.sum()


class TouchDeformationBlock(DeformationBlock):
    """A Pixel2Mesh deformation block whose vertices also read touch features: concatenated to ``g_v`` and added
    (one linear map per G-ResNet block) before every G-ResNet block.

    Args:
        in_features: channels of ``g_v`` without the touch features.
        touch_channels: F, the touch feature channels.
        hidden, num_blocks, aggregate: as :class:`~tvrecon.models.components.gcn.DeformationBlock`.
    """

    def __init__(
        self, in_features: int, touch_channels: int, hidden: int = 192, num_blocks: int = 6, aggregate: str = "mean"
    ) -> None:
        super().__init__(in_features + touch_channels, hidden, num_blocks, aggregate)
        self.touch_in = nn.ModuleList([nn.Linear(touch_channels, hidden) for _ in range(num_blocks)])

    def forward(  # type: ignore[override]
        self, g: GraphInput, verts: Tensor, edges: Tensor, neighbours: Tensor | NeighbourOperator, touch: Tensor
    ) -> tuple[Tensor, Tensor]:
        """Args: g (B, V, C_in) float, or its parts (see :class:`~tvrecon.models.components.gcn.GraphConv`); verts
        (B, V, 3); edges (E, 2) int64; neighbours (B*V, B*V) sparse or a ``NeighbourOperator``; touch (B, V, F) float
        touch features.

        Returns: new vertices (B, V, 3) float and hidden features (B, V, hidden) float.
        """
        parts = [g] if isinstance(g, Tensor) else list(g)
        h = F.relu(self.conv_in([*parts, touch], edges, neighbours))
        for block, inject in zip(self.blocks, self.touch_in, strict=True):
            h = block(h + inject(touch), edges, neighbours)
        return verts + self.conv_out(h, edges, neighbours), h


class TouchGeometryDeformer(MeshDeformer):
    """:class:`~tvrecon.models.components.gcn.MeshDeformer` whose deformation blocks read the contact points near each
    vertex.

    Args:
        sigmas: length scales of :func:`touch_features` (object units).
        deformer_args: :class:`~tvrecon.models.components.gcn.MeshDeformer`'s arguments (feature_channels, hidden, ...).
    """

    reads_touch_points = True  # forward(features, K, image_size, touch: TouchPoints | None)

    def __init__(self, sigmas: Sequence[float] = (0.02, 0.08, 0.3), **deformer_args: Any) -> None:
        super().__init__(**deformer_args)
        if not sigmas or any(not float(s) > 0 for s in sigmas):
            raise ValueError(f"sigmas must be positive length scales, got {list(sigmas)}")
        self.sigmas = [float(s) for s in sigmas]
        self._touch: TouchPoints | None = None  # the contact points of the forward in progress
        touch_channels = FEATURES_PER_SCALE * len(self.sigmas)
        first = self.stages[0]  # the plain blocks MeshDeformer built: same widths, plus the touch inputs
        hidden, num_blocks = first.conv_in.self_linear.out_features, len(first.blocks)
        perceptual = first.conv_in.self_linear.in_features - 3
        self.stages = nn.ModuleList(
            [
                TouchDeformationBlock(
                    (hidden if s > 0 else 0) + 3 + perceptual, touch_channels, hidden, num_blocks, self.aggregate
                )
                for s in range(self.num_stages)
            ]
        )

    def forward(  # type: ignore[override]
        self,
        features: Sequence[Tensor],
        K: Tensor,
        image_size: tuple[int, int],
        touch: TouchPoints | None = None,
    ) -> dict[str, list[Tensor]]:
        """Deform the ellipsoid under the perceptual features and the touches' contact points.

        Args:
            features, K, image_size: as :meth:`MeshDeformer.forward`.
            touch: camera-frame contact points (B, P, 3) with normals and mask, or None (no touch).

        Returns:
            as :meth:`MeshDeformer.forward`.
        """
        if touch is None:
            B = K.shape[0]
            empty = K.new_zeros(B, 1, 3)
            touch = TouchPoints(empty, empty, torch.zeros(B, 1, dtype=torch.bool, device=K.device))
        self._touch = touch  # read by _deform during this forward only
        try:
            return super().forward(features, K, image_size)
        finally:
            self._touch = None

    def _deform(
        self, s: int, block: nn.Module, g: GraphInput, x: Tensor, edges: Tensor, neighbours: NeighbourOperator
    ) -> tuple[Tensor, Tensor]:
        """Block ``s`` with the touch features of its input vertices x (B, V_s, 3) (see :func:`touch_features`)."""
        assert self._touch is not None, "TouchGeometryDeformer._deform runs inside forward only"
        return block(g, x, edges, neighbours, touch_features(x, self._touch, self.sigmas))


class TouchGeometryReconstructor(nn.Module):
    """Visual ResNet-18 + a Pixel2Mesh deformer that reads the touches' contact patches (beyond the paper).

    Args:
        visual_backbone: visual branch (default: a randomly initialised ``ResNet18Backbone``).
        deformer: a :class:`TouchGeometryDeformer` (default: one with the visual channels) or a
            :class:`~tvrecon.models.components.touch_residual.TouchResidualDeformer` (touches as a correction of the
            Pixel2Mesh answer).
        tactile_backbone, fusion: must be None: this model has no tactile image branch (the keys exist so that the
            experiment config can null the paper model's entries).
        mode: ``"touch_geometry"``.
        per_touch: contact points kept per touch (:func:`select_patch_points`).
        view_pass: in training, also run the deformer on the same image features without any touch and return that
            mesh as ``out["visual"]``, which ``ReconstructionModule(visual_loss_weight=...)`` trains on every sample:
            one network that must answer a view alone as well as a view with touches (``experiment=
            touch_geometry_view_pass``). Costs a second deformer pass per step, not a second ResNet. Off in eval.
    """

    reads_patches = True
    uses_touches = True

    def __init__(
        self,
        visual_backbone: ResNet18Backbone | None = None,
        deformer: MeshDeformer | None = None,
        tactile_backbone: nn.Module | None = None,
        fusion: nn.Module | None = None,
        mode: str = "touch_geometry",
        per_touch: int = 64,
        view_pass: bool = False,
    ) -> None:
        super().__init__()
        if mode != "touch_geometry":
            raise ValueError(f"TouchGeometryReconstructor's mode is 'touch_geometry', got {mode!r}")
        if tactile_backbone is not None or fusion is not None:
            raise ValueError(
                "TouchGeometryReconstructor has no tactile branch: set model.net.tactile_backbone and "
                "model.net.fusion to null"
            )
        self.mode = mode
        self.per_touch = int(per_touch)
        self.view_pass = bool(view_pass)
        self.visual = visual_backbone if visual_backbone is not None else ResNet18Backbone()
        channels = list(self.visual.channels)
        self.deformer = deformer if deformer is not None else TouchGeometryDeformer(feature_channels=channels)
        if not getattr(self.deformer, "reads_touch_points", False):
            raise ValueError(
                "deformer must read touch points (a TouchGeometryDeformer or a TouchResidualDeformer), got "
                f"{type(self.deformer).__name__}"
            )
        if self.view_pass and not isinstance(self.deformer, TouchGeometryDeformer):
            raise ValueError(
                f"view_pass runs touch geometry's own deformer without touches; {type(self.deformer).__name__} has a "
                "visual path of its own (out['visual']): set view_pass=false"
            )

    def touch_points(
        self, RT: Tensor, patch_points: Tensor, patch_normals: Tensor, patch_mask: Tensor, touch_mask: Tensor | None
    ) -> TouchPoints:
        """Camera-frame contact points of the used touches.

        Args:
            RT: (B, 3, 4) float world->camera; patch_points, patch_normals: (B, T, Q, 3) float world;
            patch_mask: (B, T, Q) bool; touch_mask: (B, T) bool or None (all).
        """
        world = select_patch_points(patch_points, patch_normals, patch_mask, touch_mask, self.per_touch)
        return TouchPoints(world_to_camera(world.points, RT), rotate_to_camera(world.normals, RT), world.mask)

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
        """Reconstruct a mesh in camera coordinates.

        Args:
            image: (B, 3, H, W) float view; K: (B, 3, 3); RT: (B, 3, 4) world->camera.
            tactile, positions, directions: accepted for the common interface, not read (the patches hold them).
            touch_mask: (B, T) bool, the touches to use (None = all).
            patch_points, patch_normals: (B, T, Q, 3) float world contact layer; patch_mask: (B, T, Q) bool.
                All None = no touch.

        Returns:
            as :meth:`TactileVisualReconstructor.forward`, plus ``touch`` (camera-frame :class:`TouchPoints`, or None)
            for the patch training term; with ``view_pass`` in training also ``visual``: the no-touch answer's output
            dict on the same features.
        """
        image_size = check_view(image, K, RT)
        patches = (patch_points, patch_normals, patch_mask)
        if any(p is None for p in patches) and not all(p is None for p in patches):
            raise ValueError("give patch_points, patch_normals and patch_mask together (or none of them)")
        touch = None
        if patch_points is not None:
            assert patch_normals is not None and patch_mask is not None
            touch = self.touch_points(RT, patch_points, patch_normals, patch_mask, touch_mask)
        x = self.visual.stem(image)
        features = []
        for j in range(len(self.visual.stages)):
            x = self.visual.stage(j, x)
            features.append(x)
        out = self.deformer(features, K, image_size, touch)
        if self.view_pass and self.training and touch is not None and bool(touch.mask.any()):
            out["visual"] = self.deformer(features, K, image_size, None)  # type: ignore[assignment]
        out["features"] = features
        out["touch"] = touch  # type: ignore[assignment]
        return out
