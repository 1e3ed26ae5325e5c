"""The two generated datasets: tactile-visual reconstruction and tactile classification.

Both are :class:`~tvrecon.data.dataset_base.GeneratedDataset` (object indexing, seeds, simulator, per-item cache;
read its module docstring first). A reconstruction item adds a seeded view rendered with a random camera and GT surface
samples.

What is cached (one ``.npz`` per item, see :mod:`tvrecon.data.cache.store`) is the *raw* generation result: tactile
images at the sensor's resolution, in grid cells. What the dataset returns is derived on load: the number of
touches T, the tactile resizing to the model resolution (``resize_tactile``, kornia), the normalization and the
padding. Changing those never invalidates the cache; changing anything that goes into generation (mesh parameters,
touch policy, sensor / press / render configuration, number of GT points, ``CACHE_VERSION``) always does.

Tactile scale: returned tactile images are the contact-layer displacement in grid cells divided by
``tactile_scale`` (default 1.0, i.e. grid cells; channels x shear, y shear, z normal, z > 0 pushed into the pad).
With the default presses the normal channel peaks at about the indentation depth (one to a few cells), so the
values are O(1) without further normalization. Padded touches are all zeros.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
import trimesh
from torch import Tensor
from torch.utils.data import Dataset

from tvrecon.data.dataset_base import GeneratedDataset
from tvrecon.data.pose_augment import turn_about_up
from tvrecon.data.tactile_augment import orient_touches
from tvrecon.data.touches.select import TouchSelector
from tvrecon.data.views import render_view, sample_camera
from tvrecon.sim.sensor.patch import ContactPatch, contact_patch
from tvrecon.utils.config_utils import coerce_config

__all__ = [
    "RenderConfig",
    "EvalDraws",
    "ReconstructionDataset",
    "TactileClassificationDataset",
]


@dataclasses.dataclass
class RenderConfig:
    """Camera and shading of the single RGB view.

    Attributes:
        image_size: square image side H = W in pixels (224 in the paper).
        distance: camera distance from the object centre (objects fit [-0.5, 0.5]^3).
        fov_deg: full field of view in degrees.
        ambient: ambient light fraction in [0, 1].
        background: background grey level in [0, 1].
    """

    image_size: int = 224
    distance: float = 2.0
    fov_deg: float = 45.0
    ambient: float = 0.3
    background: float = 1.0


class ReconstructionDataset(GeneratedDataset):
    """Tactile-visual reconstruction samples: one view and T touches of one object, plus GT surface samples.

    Item ``i`` has ``touches_per_item = max_touches`` touches cached; the sample uses the first T of them with
    T drawn uniformly in ``[min_touches, max_touches]`` from ``(seed, split, i)``, or T = ``num_touches`` for every
    sample when that is set (evaluation with 2, 5, 10 touches: the first 2 touches are the same in all three, and
    the cache of the split is shared). Which touches every path uses is summarised in
    :mod:`tvrecon.data.touches.select`.

    Sample (``docs/reference/batch-schema.md``):
        image (3,H,W) float32 [0,1]; K (3,3) float32; RT (3,4) float32 world->camera;
        tactile (max_touches,3,h,w) float32 (scaled grid cells, zeros where padded);
        positions (max_touches,3), directions (max_touches,3) float32 world (zeros where padded);
        touch_mask (max_touches,) bool (first T True); points (N,3), normals (N,3) float32 world, area-weighted
        seeded samples of the GT surface; label int64 (index into ``library.classes``);
        patch_points (max_touches,Hs*Ws,3), patch_normals (max_touches,Hs*Ws,3) float32 world and patch_mask
        (max_touches,Hs*Ws) bool: each touch's contact layer mapped back to 3D
        (:func:`tvrecon.sim.sensor.patch.contact_patch`, derived from the cached raw image, position and direction at
        the sensor's resolution Hs x Ws; no regeneration), the mask True where the pad was pushed in by more than
        ``patch_min_push`` cells (default 0.1) and ``patch_min_push_fraction`` of the touch's deepest push (default 0;
        False on padded touches).

    Args (in addition to :class:`GeneratedDataset`):
        num_samples: number of samples (objects; one view each).
        min_touches, max_touches: range of T (1 <= min <= max); max_touches is also the padded length.
        num_touches: fixed T (None: random T per sample).
        num_points: N, GT surface samples.
        render: :class:`RenderConfig` or mapping.
    """

    kind = "reconstruction"

    def __init__(
        self,
        num_samples: int,
        min_touches: int = 1,
        max_touches: int = 10,
        num_touches: int | None = None,
        num_points: int = 2048,
        render: RenderConfig | Mapping[str, Any] | None = None,
        **kwargs: Any,
    ) -> None:
        if not 1 <= int(min_touches) <= int(max_touches):
            raise ValueError(f"need 1 <= min_touches <= max_touches, got {min_touches} and {max_touches}")
        if num_touches is not None and not 1 <= int(num_touches) <= int(max_touches):
            raise ValueError(f"num_touches must be None or in [1, max_touches={max_touches}], got {num_touches}")
        if int(num_points) < 1:
            raise ValueError(f"num_points must be >= 1, got {num_points}")
        if "touches_per_item" in kwargs:
            raise ValueError(
                "ReconstructionDataset caches max_touches touches per sample; do not pass touches_per_item"
            )
        super().__init__(num_items=num_samples, touches_per_item=int(max_touches), **kwargs)
        self.min_touches = int(min_touches)
        self.max_touches = int(max_touches)
        self.fixed_touches = None if num_touches is None else int(num_touches)
        self.num_points = int(num_points)
        self.render = coerce_config(RenderConfig, render)

    def spec(self, index: int) -> dict[str, Any]:
        spec = super().spec(index)
        spec.update({"render": self.render, "num_points": self.num_points})
        return spec

    def camera(self, index: int):
        """The seeded :class:`~tvrecon.data.views.Camera` of item ``index``."""
        r = self.render
        return sample_camera(self.seeds(index)[1], image_size=r.image_size, distance=r.distance, fov_deg=r.fov_deg)

    def generate(self, index: int) -> dict[str, np.ndarray]:
        index = self._check_index(index)
        touch_seed, view_seed, point_seed, _ = self.seeds(index)
        mesh = self.mesh(index)
        camera = self.camera(index)
        view = render_view(mesh, camera, seed=view_seed, ambient=self.render.ambient, background=self.render.background)
        points, faces = trimesh.sample.sample_surface(mesh, self.num_points, seed=point_seed)
        out = self._simulate(mesh, touch_seed, camera=camera, index=index)
        out.update(
            {
                "image": view["image"].float().numpy(),
                "K": camera.K.float().numpy(),
                "RT": camera.RT.float().numpy(),
                "points": np.asarray(points, dtype=np.float32),
                "normals": np.asarray(mesh.face_normals[faces], dtype=np.float32),
                "label": np.asarray(self.label_of(index), dtype=np.int64),
            }
        )
        return out

    def num_touches(self, index: int) -> int:
        """T of item ``index``: ``num_touches`` if set, else drawn in [min_touches, max_touches] from its load seed."""
        if self.fixed_touches is not None:
            return self.fixed_touches
        rng = np.random.default_rng(self.seeds(index)[3])
        return int(rng.integers(self.min_touches, self.max_touches + 1))

    def __getitem__(self, index: int) -> dict[str, Tensor]:
        index = self._check_index(index)
        raw, _ = self.raw(index)
        M, T = self.max_touches, self.num_touches(index)
        tactile = torch.zeros((M, 3, *self.tactile_size), dtype=torch.float32)
        tactile[:T] = self._tactile(raw["tactile"][:T])
        positions = torch.zeros((M, 3), dtype=torch.float32)
        directions = torch.zeros((M, 3), dtype=torch.float32)
        positions[:T] = torch.from_numpy(raw["positions"][:T])
        directions[:T] = torch.from_numpy(raw["directions"][:T])
        mask = torch.zeros(M, dtype=torch.bool)
        mask[:T] = True
        patch_points, patch_normals, patch_mask = self._patches(raw, T)
        return {
            "image": torch.from_numpy(raw["image"]),
            "K": torch.from_numpy(raw["K"]),
            "RT": torch.from_numpy(raw["RT"]),
            "tactile": tactile,
            "positions": positions,
            "directions": directions,
            "touch_mask": mask,
            "points": torch.from_numpy(raw["points"]),
            "normals": torch.from_numpy(raw["normals"]),
            "label": torch.tensor(int(raw["label"]), dtype=torch.int64),
            "patch_points": patch_points,
            "patch_normals": patch_normals,
            "patch_mask": patch_mask,
        }

    def _patches(self, raw: Mapping[str, np.ndarray], T: int) -> tuple[Tensor, Tensor, Tensor]:
        """Contact patches of the first T cached touches, padded to max_touches.

        Returns points (M, Hs*Ws, 3) float32, normals (M, Hs*Ws, 3) float32 world, mask (M, Hs*Ws) bool.
        """
        M = self.max_touches
        Hs, Ws = self.sensor.resolution
        points = torch.zeros((M, Hs * Ws, 3), dtype=torch.float32)
        normals = torch.zeros((M, Hs * Ws, 3), dtype=torch.float32)
        mask = torch.zeros((M, Hs * Ws), dtype=torch.bool)
        if T > 0:
            patch = _contact_patches(self, raw, np.arange(T))
            points[:T], normals[:T], mask[:T] = patch.points, patch.normals, patch.mask
        return points, normals, mask


def _contact_patches(dataset: GeneratedDataset, raw: Mapping[str, np.ndarray], sel: np.ndarray) -> ContactPatch:
    """Contact patches (:func:`tvrecon.sim.sensor.patch.contact_patch`) of the cached touches ``sel`` (T,) of an item.

    Returns points (T, Hs*Ws, 3) float32, normals (T, Hs*Ws, 3) float32 world, mask (T, Hs*Ws) bool.
    """
    return contact_patch(
        torch.from_numpy(np.ascontiguousarray(raw["tactile"][sel])).float(),
        torch.from_numpy(np.ascontiguousarray(raw["positions"][sel])),
        torch.from_numpy(np.ascontiguousarray(raw["directions"][sel])),
        dataset.sensor,
        int(dataset.press.n_grid),
        float(dataset.press.domain_size),
        min_push=dataset.patch_min_push,
        min_push_fraction=dataset.patch_min_push_fraction,
    )


class TactileClassificationDataset(GeneratedDataset):
    """Tactile classification samples: N touches (different press directions) of one object and its class.

    Item ``i`` caches ``touches_per_object`` (M) touches; which N of them a sample shows is decided by a
    :class:`~tvrecon.data.touches.select.TouchSelector` (the one owner of that choice, see
    :mod:`tvrecon.data.touches.select`) from the item's load seed of ``(seed, split, i)``:

    - ``redraw_touches=True`` (the training split of :class:`~tvrecon.data.datamodule.ClassificationDataModule`):
      N touches drawn afresh at every epoch, in random order (paper section 4.2: "during each training iteration,
      we randomly choose N tactile images"); the epoch comes from :meth:`set_epoch`;
    - ``redraw_touches=False`` (default; validation and test): a fixed seeded subset, sorted, the same every epoch.

    ``rotate_touches=True`` (training draws only) also turns each touch's image by a random multiple of 90 degrees
    about the pad normal and mirrors it with probability 1/2, shear channels transformed with the grid
    (:func:`tvrecon.data.tactile_augment.rotate_tactile`; the pad's in-plane orientation is arbitrary). Positions and
    directions are left as they are. Needs square tactile images.

    ``patches=True`` adds each touch's contact patch, the pad's contact layer mapped back to world points and
    normals (:func:`tvrecon.sim.sensor.patch.contact_patch`, from the raw image at the pad's resolution, so the image
    augmentation does not move it). ``rotate_pose=True`` (training draws only) turns the whole touch set, positions,
    directions and patches, by one random angle about the world's up axis per visit
    (:mod:`tvrecon.data.pose_augment`): the object's heading is then unknown to a model that reads touch poses.

    Sample (``docs/reference/batch-schema.md``): tactile (N,3,h,w) float32 (scaled grid cells), touch_mask (N,) bool
    (all True), positions (N,3), directions (N,3) float32 world, label int64; with ``patches``: patch_points (N,Q,3),
    patch_normals (N,Q,3) float32 world and patch_mask (N,Q) bool, Q = the pad's Hs*Ws.

    Args (in addition to :class:`GeneratedDataset`):
        num_objects: number of objects (items).
        touches_per_object: M touches simulated and cached per object.
        num_touches: N touches per sample (1 <= N <= M).
        redraw_touches: draw the N touches afresh per epoch (training) instead of a fixed subset.
        rotate_touches: random quarter turns and mirroring of each drawn touch (only with ``redraw_touches``).
        patches: add the touches' contact patches to every sample.
        rotate_pose: random turn of the touch set about +z per training visit (only with ``redraw_touches``).
        eval_draws: K fixed draws of N touches per object at evaluation (``redraw_touches=False``), served through
            :class:`EvalDraws` (``len`` = objects x K); 1 (default) = one sorted seeded subset per object.
    """

    kind = "classification"

    def __init__(
        self,
        num_objects: int,
        touches_per_object: int = 10,
        num_touches: int = 1,
        redraw_touches: bool = False,
        rotate_touches: bool = False,
        eval_draws: int = 1,
        patches: bool = False,
        rotate_pose: bool = False,
        **kwargs: Any,
    ) -> None:
        if not 1 <= int(num_touches) <= int(touches_per_object):
            raise ValueError(
                f"need 1 <= num_touches <= touches_per_object, got num_touches={num_touches}, "
                f"touches_per_object={touches_per_object}"
            )
        if "touches_per_item" in kwargs:
            raise ValueError("use touches_per_object, not touches_per_item, for TactileClassificationDataset")
        super().__init__(num_items=num_objects, touches_per_item=int(touches_per_object), **kwargs)
        self.num_touches = int(num_touches)
        self.selector = TouchSelector(
            self.touches_per_item, self.num_touches, redraw=bool(redraw_touches), eval_draws=int(eval_draws)
        )
        self.rotate_touches = bool(rotate_touches)
        if self.rotate_touches and self.tactile_size[0] != self.tactile_size[1]:
            raise ValueError(f"rotate_touches needs square tactile images, got tactile_size={self.tactile_size}")
        self.patches = bool(patches)
        self._memory_patches: dict[int, tuple[Tensor, Tensor, Tensor]] = {}
        self.rotate_pose = bool(rotate_pose)
        self.epoch = 0

    @property
    def redraw_touches(self) -> bool:
        """True when the touches of a sample change with the epoch (the training draw)."""
        return self.selector.redraw

    def set_epoch(self, epoch: int) -> None:
        """Set the epoch of the training draw (called by :func:`tvrecon.data.touches.select.set_loader_epoch`)."""
        if int(epoch) < 0:
            raise ValueError(f"epoch must be >= 0, got {epoch}")
        self.epoch = int(epoch)

    def generate(self, index: int) -> dict[str, np.ndarray]:
        index = self._check_index(index)
        out = self._simulate(self.mesh(index), self.seeds(index)[0], index=index)
        out["label"] = np.asarray(self.label_of(index), dtype=np.int64)
        return out

    def _item_patches(self, index: int, raw: Mapping[str, np.ndarray]) -> tuple[Tensor, Tensor, Tensor]:
        """Contact patches of all M cached touches of item ``index`` (points, normals (M, Q, 3), mask (M, Q)); kept
        per item with ``memory_cache`` (they are a function of the cached touches only)."""
        memo = self._memory_patches if self._memory is not None else None
        if memo is not None and index in memo:
            return memo[index]
        patch = _contact_patches(self, raw, np.arange(len(raw["positions"])))
        out = (patch.points, patch.normals, patch.mask)
        if memo is not None:
            memo[index] = out
        return out

    def touch_indices(self, index: int, epoch: int | None = None, draw: int = 0) -> np.ndarray:
        """(N,) int64 indices of the cached touches item ``index`` uses at ``epoch`` (default: the current one) in
        evaluation draw ``draw``."""
        epoch = self.epoch if epoch is None else int(epoch)
        return self.selector.indices(self.seeds(index)[3], epoch, draw)

    def __getitem__(self, index: int) -> dict[str, Tensor]:
        return self.sample(index)

    def sample(self, index: int, draw: int = 0) -> dict[str, Tensor]:
        """Item ``index`` with the touches of evaluation draw ``draw`` (0 in training); see the class docstring."""
        index = self._check_index(index)
        raw, _ = self.raw(index)
        sel = self.touch_indices(index, draw=draw)
        tactile = self._tactile(raw["tactile"][sel])
        if self.rotate_touches and self.redraw_touches:
            k, mirror = self.selector.orientations(self.seeds(index)[3], self.epoch)
            tactile = orient_touches(tactile, k, mirror)
        out = {
            "tactile": tactile,
            "touch_mask": torch.ones(self.num_touches, dtype=torch.bool),
            "positions": torch.from_numpy(raw["positions"][sel]),
            "directions": torch.from_numpy(raw["directions"][sel]),
            "label": torch.tensor(int(raw["label"]), dtype=torch.int64),
        }
        if self.patches:
            patch = self._item_patches(index, raw)
            out["patch_points"], out["patch_normals"], out["patch_mask"] = (x[sel] for x in patch)
        if self.rotate_pose and self.redraw_touches:
            angle = self.selector.yaw(self.seeds(index)[3], self.epoch)
            for key in ("positions", "directions", "patch_points", "patch_normals"):
                if key in out:
                    out[key] = turn_about_up(out[key], angle)
        return out


class EvalDraws(Dataset):
    """Every evaluation draw of a :class:`TactileClassificationDataset`: sample ``i`` is object ``i // K`` with its
    draw ``i % K`` (K = ``dataset.selector.draws``), so a test over it classifies each object K times.

    Args:
        dataset: the evaluation (non-redrawing) dataset; generation and the cache still go through it (per object).
    """

    def __init__(self, dataset: TactileClassificationDataset) -> None:
        if dataset.redraw_touches:
            raise ValueError("EvalDraws serves the fixed evaluation draws; the training split redraws every epoch")
        self.dataset = dataset
        self.draws = dataset.selector.draws

    def __len__(self) -> int:
        return len(self.dataset) * self.draws

    def __getitem__(self, index: int) -> dict[str, Tensor]:
        index = int(index)
        if not 0 <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} samples ({self.draws} draws per object)")
        return self.dataset.sample(index // self.draws, index % self.draws)
