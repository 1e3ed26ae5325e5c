"""Datasets generated on the fly from (seed, index), cached per sample on disk.

Two torch datasets share one machinery (:class:`GeneratedDataset`): item ``i`` is an object of the
:class:`~tvrecon.data.shapes.ObjectLibrary` (class ``classes[i % C]``, instance ``instance_offset + i // C``), a
seeded set of touches simulated with the EIP simulator (all touches of an item in one ``press_batch`` call), and for
reconstruction a seeded view rendered with a random camera. Everything is derived from ``(seed, split, index)``
through ``numpy.random.SeedSequence``, and generation runs on one torch thread, so the same arguments give the same
dataset bit for bit, in any worker, on a cache hit or a miss.

What is cached (one ``.npz`` per item, see :mod:`tvrecon.data.cache`) is the *raw* generation result: tactile
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
import hashlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
import trimesh
from torch import Tensor
from torch.utils.data import Dataset

from tvrecon.config_utils import coerce_config
from tvrecon.data.cache import SampleCache
from tvrecon.data.render import render_view, sample_camera
from tvrecon.data.shapes import ObjectLibrary
from tvrecon.data.tactile_augment import orient_touches
from tvrecon.data.touch_select import TouchSelector
from tvrecon.data.touches import (
    Touches,
    TouchPolicy,
    make_touch_policy,
    resize_tactile,
    sample_touches,
    simulate_touches,
)
from tvrecon.sim.contact import contact_patch
from tvrecon.sim.press import EIPSimulator, PressConfig, SensorConfig

__all__ = [
    "RenderConfig",
    "GeneratedDataset",
    "ReconstructionDataset",
    "TactileClassificationDataset",
    "coerce_config",
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


def _pair(size: int | Sequence[int], name: str) -> tuple[int, int]:
    if isinstance(size, int | np.integer):
        size = (int(size), int(size))
    size = tuple(int(s) for s in size)
    if len(size) != 2 or min(size) < 1:
        raise ValueError(f"{name} must be an int or (h, w) with positive entries, got {size}")
    return size  # type: ignore[return-value]


def _split_code(split: str) -> int:
    """Stable 32-bit integer of a split name (python's hash() is salted per process)."""
    return int.from_bytes(hashlib.sha256(split.encode()).digest()[:4], "little")


class GeneratedDataset(Dataset):
    """Base of the generated datasets: object indexing, seeds, the simulator and the cache.

    Args:
        num_items: number of items (objects) in the dataset.
        classes: class names drawn round-robin (default: all classes of ``library``).
        split: object split of the library (``"train"``, ``"val"`` or ``"test"``: disjoint objects).
        seed: dataset seed; with ``split`` and the index it determines every random choice.
        library: the object library (default ``ObjectLibrary()``, the 35 procedural classes).
        instance_offset: first instance number used for each class.
        touches_per_item: touches simulated and cached per item (M).
        sensor, press: simulator configs (dataclass or mapping).
        touch: the touch policy: a :class:`~tvrecon.data.touches.TouchPolicy` or a mapping of its fields with an
            optional ``_target_`` (default :class:`~tvrecon.data.touches.ConeTouchPolicy`).
        tactile_size: model resolution (h, w) the tactile images are resized to on load.
        tactile_scale: divisor of the raw displacement (grid cells), see the module docstring.
        cache_dir: cache directory; ``None`` disables caching.
        sim_device: device of the simulator inside the workers (default: the simulator's default).
    """

    kind = "base"

    def __init__(
        self,
        num_items: int,
        classes: Sequence[str] | None = None,
        split: str = "train",
        seed: int = 0,
        library: ObjectLibrary | None = None,
        instance_offset: int = 0,
        touches_per_item: int = 10,
        sensor: SensorConfig | Mapping[str, Any] | None = None,
        press: PressConfig | Mapping[str, Any] | None = None,
        touch: TouchPolicy | Mapping[str, Any] | None = None,
        tactile_size: int | Sequence[int] = 224,
        tactile_scale: float = 1.0,
        cache_dir: str | Path | None = None,
        sim_device: str | torch.device | None = None,
    ) -> None:
        if int(num_items) < 1:
            raise ValueError(f"num_items must be >= 1, got {num_items}")
        if int(touches_per_item) < 1:
            raise ValueError(f"touches_per_item must be >= 1, got {touches_per_item}")
        if int(instance_offset) < 0:
            raise ValueError(f"instance_offset must be >= 0, got {instance_offset}")
        if not float(tactile_scale) > 0:
            raise ValueError(f"tactile_scale must be > 0 (grid cells per unit), got {tactile_scale}")
        self.library = library if library is not None else ObjectLibrary()
        self.classes = list(classes) if classes is not None else list(self.library.classes)
        if not self.classes:
            raise ValueError("classes is empty; give at least one class name")
        missing = [c for c in self.classes if c not in self.library.classes]
        if missing:
            raise ValueError(f"classes {missing} are not in the object library; available: {self.library.classes}")
        self.num_items = int(num_items)
        self.split = str(split)
        self.seed = int(seed)
        self.instance_offset = int(instance_offset)
        self.touches_per_item = int(touches_per_item)
        self.sensor = coerce_config(SensorConfig, sensor)
        self.press = coerce_config(PressConfig, press)
        self.touch = make_touch_policy(touch)
        self.tactile_size = _pair(tactile_size, "tactile_size")
        self.tactile_scale = float(tactile_scale)
        self.cache = SampleCache(cache_dir)
        self.sim_device = sim_device
        self._simulator: EIPSimulator | None = None

    # ----------------------------------------------------------------- indexing and seeds
    def __len__(self) -> int:
        return self.num_items

    def _check_index(self, index: int) -> int:
        index = int(index)
        if index < 0:
            index += self.num_items
        if not 0 <= index < self.num_items:
            raise IndexError(f"index {index} out of range for a dataset of {self.num_items} items")
        return index

    def object_of(self, index: int) -> tuple[str, int]:
        """(class name, instance number) of item ``index``."""
        index = self._check_index(index)
        n = len(self.classes)
        return self.classes[index % n], self.instance_offset + index // n

    def label_of(self, index: int) -> int:
        """Class label of item ``index``: the position of its class in ``library.classes``."""
        return self.library.label(self.object_of(index)[0])

    def seeds(self, index: int, n: int = 4) -> list[int]:
        """``n`` independent 32-bit seeds of item ``index`` (stream 0: touches, 1: view, 2: GT points, 3: load)."""
        ss = np.random.SeedSequence([self.seed, _split_code(self.split), self._check_index(index)])
        return [int(s) for s in ss.generate_state(n)]

    # ----------------------------------------------------------------- generation
    @property
    def simulator(self) -> EIPSimulator:
        """The per-process simulator (built lazily so datasets pickle cheaply into dataloader workers)."""
        if self._simulator is None:
            kwargs = {} if self.sim_device is None else {"device": self.sim_device}
            self._simulator = EIPSimulator(sensor=self.sensor, press=self.press, **kwargs)
        return self._simulator

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_simulator"] = None
        return state

    def mesh(self, index: int) -> trimesh.Trimesh:
        """The object mesh of item ``index`` (world coordinates, unit box, centred at 0)."""
        cls, instance = self.object_of(index)
        return self.library.get(cls, instance, self.split)

    def spec(self, index: int) -> dict[str, Any]:
        """Everything that determines the cached raw entry of item ``index`` (its cache key is a hash of this)."""
        cls, instance = self.object_of(index)
        return {
            "kind": self.kind,
            "mesh": self.library.params(cls, instance, self.split),
            "seeds": self.seeds(index)[:3],
            "touches": self.touches_per_item,
            "touch_policy": self.touch.cache_spec(),  # the default policy's key is unchanged by pluggability
            "sensor": self.sensor,
            "press": self.press,
        }

    def _simulate(self, mesh: trimesh.Trimesh, seed: int, camera: Any = None) -> dict[str, np.ndarray]:
        """Sample ``touches_per_item`` touches and simulate them in one batch.

        A touch the simulator cannot place (the pad would start inside a concave part, ~2% of random touches) is
        replaced by another seeded touch, see :meth:`_placeable_touches`.

        Returns arrays: tactile (M,3,Hs,Ws) float32 grid cells, positions (M,3), directions (M,3) float32,
        contact (M,) bool, depth (M,) float32.
        """
        M = self.touches_per_item
        touches = sample_touches(mesh, M, seed=seed, policy=self.touch, camera=camera, sim=self.simulator)
        try:
            readings = simulate_touches(self.simulator, mesh, touches, batch_size=M)
        except ValueError:
            touches = self._placeable_touches(mesh, touches, seed, camera)
            readings = simulate_touches(self.simulator, mesh, touches, batch_size=M)
        return {
            "tactile": torch.stack([r.image for r in readings]).float().cpu().numpy(),
            "positions": torch.stack([r.position for r in readings]).float().cpu().numpy(),
            "directions": torch.stack([r.direction for r in readings]).float().cpu().numpy(),
            "contact": np.array([bool(r.contact) for r in readings]),
            "depth": np.array([float(r.depth) for r in readings], dtype=np.float32),
        }

    def _placeable_touches(
        self, mesh: trimesh.Trimesh, touches: Touches, seed: int, camera: Any = None, attempts: int = 20
    ) -> Touches:
        """Replace the touches the simulator rejects with seeded re-draws (deterministic in ``seed``).

        Each touch is probed with a one-step press; a rejected touch ``t`` is re-drawn with seed
        ``SeedSequence([seed, t, attempt])`` until one is accepted. Raises ValueError when no attempt works.
        """
        out = {k: list(v) if isinstance(v, list) else v.clone() for k, v in touches._asdict().items()}

        def rejected(pos: Tensor, d: Tensor) -> str | None:
            try:
                self.simulator.press_batch(mesh, pos[None], d[None], max_steps=1)
            except ValueError as err:
                return str(err)
            return None

        for t in range(len(out["positions"])):
            why = rejected(out["positions"][t], out["directions"][t])
            attempt = 0
            while why is not None:
                attempt += 1
                if attempt > attempts:
                    raise ValueError(f"no placeable touch found for touch {t} after {attempts} re-draws: {why}")
                sub = int(np.random.SeedSequence([seed, t, attempt]).generate_state(1)[0])
                new = sample_touches(mesh, 1, seed=sub, policy=self.touch, camera=camera, sim=self.simulator)
                why = rejected(new.positions[0], new.directions[0])
                if why is None:
                    for k, v in new._asdict().items():
                        out[k][t] = v[0]
        return Touches(**out)

    def generate(self, index: int) -> dict[str, np.ndarray]:
        """Generate the raw entry of item ``index`` (no cache). Subclasses implement this."""
        raise NotImplementedError

    def raw(self, index: int) -> tuple[dict[str, np.ndarray], bool]:
        """The raw entry of item ``index`` from the cache, generated and stored on a miss. Returns (arrays, hit).

        The entry's ``label`` is replaced by the item's label in the current library: the cache key holds the class
        *name* (in the mesh params) but not the class list, so an entry cached before a class was added (e.g. a new
        user-mesh folder) stores an integer that may now name another class. Entries stay valid; their label is
        derived from the class name on every load.
        """
        index = self._check_index(index)
        arrays, hit = self.cache.get_or_create(self.spec(index), lambda: self._generate_single_thread(index))
        if "label" in arrays:
            arrays["label"] = np.asarray(self.label_of(index), dtype=np.int64)
        return arrays, hit

    def _generate_single_thread(self, index: int) -> dict[str, np.ndarray]:
        """:meth:`generate` with one torch thread: float reductions then do not depend on the process's thread
        count, so the main process, dataloader workers and ``generate`` pool workers produce the same bits."""
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            return self.generate(index)
        finally:
            torch.set_num_threads(threads)

    def is_cached(self, index: int) -> bool:
        """True when a (readable-looking) cache entry of item ``index`` exists."""
        from tvrecon.data.cache import cache_key

        return cache_key(self.spec(self._check_index(index))) in self.cache

    # ----------------------------------------------------------------- load-time processing
    def _tactile(self, raw: np.ndarray) -> Tensor:
        """(T,3,Hs,Ws) raw grid-cell images -> (T,3,h,w) float32 at the model resolution, divided by the scale."""
        images = torch.from_numpy(np.ascontiguousarray(raw)).float()
        if images.shape[0] == 0:
            return images.new_zeros((0, 3, *self.tactile_size))
        return resize_tactile(images, self.tactile_size) / self.tactile_scale


class ReconstructionDataset(GeneratedDataset):
    """Tactile-visual reconstruction samples: one view and T touches of one object, plus GT surface samples.

    Item ``i`` has ``touches_per_item = max_touches`` touches cached; the sample uses the first T of them with
    T drawn uniformly in ``[min_touches, max_touches]`` from ``(seed, split, i)``, or T = ``num_touches`` for every
    sample when that is set (evaluation with 2, 5, 10 touches: the first 2 touches are the same in all three, and
    the cache of the split is shared). Which touches every path uses is summarised in
    :mod:`tvrecon.data.touch_select`.

    Sample (``docs/batch-schema.md``):
        image (3,H,W) float32 [0,1]; K (3,3) float32; RT (3,4) float32 world->camera;
        tactile (max_touches,3,h,w) float32 (scaled grid cells, zeros where padded);
        positions (max_touches,3), directions (max_touches,3) float32 world (zeros where padded);
        touch_mask (max_touches,) bool (first T True); points (N,3), normals (N,3) float32 world, area-weighted
        seeded samples of the GT surface; label int64 (index into ``library.classes``);
        patch_points (max_touches,Hs*Ws,3), patch_normals (max_touches,Hs*Ws,3) float32 world and patch_mask
        (max_touches,Hs*Ws) bool: each touch's contact layer mapped back to 3D
        (:func:`tvrecon.sim.contact.contact_patch`, derived from the cached raw image, position and direction at
        the sensor's resolution Hs x Ws; no regeneration), the mask True where the pad was pushed in by more than
        0.1 cell (False on padded touches).

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
        """The seeded :class:`~tvrecon.data.render.Camera` of item ``index``."""
        r = self.render
        return sample_camera(self.seeds(index)[1], image_size=r.image_size, distance=r.distance, fov_deg=r.fov_deg)

    def generate(self, index: int) -> dict[str, np.ndarray]:
        index = self._check_index(index)
        touch_seed, view_seed, point_seed, _ = self.seeds(index)
        mesh = self.mesh(index)
        camera = self.camera(index)
        view = render_view(mesh, camera, seed=view_seed, ambient=self.render.ambient, background=self.render.background)
        points, faces = trimesh.sample.sample_surface(mesh, self.num_points, seed=point_seed)
        out = self._simulate(mesh, touch_seed, camera=camera)
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
            patch = contact_patch(
                torch.from_numpy(np.ascontiguousarray(raw["tactile"][:T])).float(),
                torch.from_numpy(raw["positions"][:T]),
                torch.from_numpy(raw["directions"][:T]),
                self.sensor,
                int(self.press.n_grid),
                float(self.press.domain_size),
            )
            points[:T], normals[:T], mask[:T] = patch.points, patch.normals, patch.mask
        return points, normals, mask


class TactileClassificationDataset(GeneratedDataset):
    """Tactile classification samples: N touches (different press directions) of one object and its class.

    Item ``i`` caches ``touches_per_object`` (M) touches; which N of them a sample shows is decided by a
    :class:`~tvrecon.data.touch_select.TouchSelector` (the one owner of that choice, see
    :mod:`tvrecon.data.touch_select`) from the item's load seed of ``(seed, split, i)``:

    - ``redraw_touches=True`` (the training split of :class:`~tvrecon.data.datamodule.ClassificationDataModule`):
      N touches drawn afresh at every epoch, in random order (paper section 4.2: "during each training iteration,
      we randomly choose N tactile images"); the epoch comes from :meth:`set_epoch`;
    - ``redraw_touches=False`` (default; validation and test): a fixed seeded subset, sorted, the same every epoch.

    ``rotate_touches=True`` (training draws only) also turns each touch's image by a random multiple of 90 degrees
    about the pad normal and mirrors it with probability 1/2, shear channels transformed with the grid
    (:func:`tvrecon.data.tactile_augment.rotate_tactile`; the pad's in-plane orientation is arbitrary). Positions and
    directions are left as they are. Needs square tactile images.

    Sample (``docs/batch-schema.md``): tactile (N,3,h,w) float32 (scaled grid cells), touch_mask (N,) bool (all
    True), positions (N,3), directions (N,3) float32 world, label int64.

    Args (in addition to :class:`GeneratedDataset`):
        num_objects: number of objects (items).
        touches_per_object: M touches simulated and cached per object.
        num_touches: N touches per sample (1 <= N <= M).
        redraw_touches: draw the N touches afresh per epoch (training) instead of a fixed subset.
        rotate_touches: random quarter turns and mirroring of each drawn touch (only with ``redraw_touches``).
    """

    kind = "classification"

    def __init__(
        self,
        num_objects: int,
        touches_per_object: int = 10,
        num_touches: int = 1,
        redraw_touches: bool = False,
        rotate_touches: bool = False,
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
        self.selector = TouchSelector(self.touches_per_item, self.num_touches, redraw=bool(redraw_touches))
        self.rotate_touches = bool(rotate_touches)
        if self.rotate_touches and self.tactile_size[0] != self.tactile_size[1]:
            raise ValueError(f"rotate_touches needs square tactile images, got tactile_size={self.tactile_size}")
        self.epoch = 0

    @property
    def redraw_touches(self) -> bool:
        """True when the touches of a sample change with the epoch (the training draw)."""
        return self.selector.redraw

    def set_epoch(self, epoch: int) -> None:
        """Set the epoch of the training draw (called by :func:`tvrecon.data.touch_select.set_loader_epoch`)."""
        if int(epoch) < 0:
            raise ValueError(f"epoch must be >= 0, got {epoch}")
        self.epoch = int(epoch)

    def generate(self, index: int) -> dict[str, np.ndarray]:
        index = self._check_index(index)
        out = self._simulate(self.mesh(index), self.seeds(index)[0])
        out["label"] = np.asarray(self.label_of(index), dtype=np.int64)
        return out

    def touch_indices(self, index: int, epoch: int | None = None) -> np.ndarray:
        """(N,) int64 indices of the cached touches item ``index`` uses at ``epoch`` (default: the current one)."""
        epoch = self.epoch if epoch is None else int(epoch)
        return self.selector.indices(self.seeds(index)[3], epoch)

    def __getitem__(self, index: int) -> dict[str, Tensor]:
        index = self._check_index(index)
        raw, _ = self.raw(index)
        sel = self.touch_indices(index)
        tactile = self._tactile(raw["tactile"][sel])
        if self.rotate_touches and self.redraw_touches:
            k, mirror = self.selector.orientations(self.seeds(index)[3], self.epoch)
            tactile = orient_touches(tactile, k, mirror)
        return {
            "tactile": tactile,
            "touch_mask": torch.ones(self.num_touches, dtype=torch.bool),
            "positions": torch.from_numpy(raw["positions"][sel]),
            "directions": torch.from_numpy(raw["directions"][sel]),
            "label": torch.tensor(int(raw["label"]), dtype=torch.int64),
        }
