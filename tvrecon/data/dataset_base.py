"""The machinery of the generated datasets: item -> object, seeds, the simulator, the per-item cache.

:class:`GeneratedDataset` is the base of :class:`~tvrecon.data.task_datasets.ReconstructionDataset` and
:class:`~tvrecon.data.task_datasets.TactileClassificationDataset`: item ``i`` is an object of the
:class:`~tvrecon.data.shapes.ObjectLibrary` (class ``classes[i % C]``, instance ``instance_offset + i // C``) and a
seeded set of touches simulated with the EIP simulator (all touches of an item in one ``press_batch`` call).
Everything is derived from ``(seed, split, index)`` through ``numpy.random.SeedSequence``, and generation runs on one
torch thread, so the same arguments give the same dataset bit for bit, in any worker, on a cache hit or a miss.

What is cached (one ``.npz`` per item, see :mod:`tvrecon.data.cache.store`) is the *raw* generation result, keyed by
:meth:`GeneratedDataset.spec`; what a subclass returns is derived from it on load.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import multiprocessing as mp
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
import trimesh
from torch import Tensor
from torch.utils.data import Dataset

from tvrecon.data.cache.store import SampleCache, cache_key
from tvrecon.data.shapes import ObjectLibrary
from tvrecon.data.touches.policies import (
    Touches,
    TouchPolicy,
    make_touch_policy,
    resize_tactile,
    sample_touches,
    simulate_touches,
)
from tvrecon.sim.mpm.compiled.policy import resolve_compile, touch_work, use_compile_cache
from tvrecon.sim.mpm.state import MPMConfig, cfl_dt
from tvrecon.sim.press.config import PressConfig
from tvrecon.sim.press.simulator import EIPSimulator
from tvrecon.sim.sensor.elastic_pad import SensorConfig
from tvrecon.sim.sensor.patch import DEFAULT_MIN_PUSH
from tvrecon.utils.config_utils import coerce_config

__all__ = ["GeneratedDataset"]

log = logging.getLogger(__name__)


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
        touch: the touch policy: a :class:`~tvrecon.data.touches.policies.TouchPolicy` or a mapping of its fields
            with an optional ``_target_`` (default :class:`~tvrecon.data.touches.policies.ConeTouchPolicy`).
        tactile_size: model resolution (h, w) the tactile images are resized to on load.
        tactile_scale: divisor of the raw displacement (grid cells), see :mod:`tvrecon.data.task_datasets`.
        cache_dir: cache directory; ``None`` disables caching.
        sim_device: device of the simulator inside the workers (default: the simulator's default).
        patch_min_push: the contact test of the touches' contact patches
            (:func:`tvrecon.sim.sensor.patch.contact_patch`): a contact-layer point counts as touching where the pad
            was pushed in by more than this many cells. Applied on load, not part of the cache key.
        patch_min_push_fraction: in [0, 1): the contact test also asks for a push above this fraction of the touch's
            deepest push (drops the rim of a contact, which lies off the surface; keeps thin parts' shallow contacts).
        memory_cache: also keep every entry read in this process's memory (one copy per dataloader worker), so each
            item is read from disk once: for small tactile-only sets trained for many epochs, where reading an
            entry (~20 ms) costs more than the training step it feeds (the 5,500-image classification set is ~70 MB).
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
        memory_cache: bool = False,
        patch_min_push: float = DEFAULT_MIN_PUSH,
        patch_min_push_fraction: float = 0.0,
    ) -> None:
        if int(num_items) < 1:
            raise ValueError(f"num_items must be >= 1, got {num_items}")
        if int(touches_per_item) < 1:
            raise ValueError(f"touches_per_item must be >= 1, got {touches_per_item}")
        if int(instance_offset) < 0:
            raise ValueError(f"instance_offset must be >= 0, got {instance_offset}")
        if not float(tactile_scale) > 0:
            raise ValueError(f"tactile_scale must be > 0 (grid cells per unit), got {tactile_scale}")
        if not 0 <= float(patch_min_push) < float("inf"):
            raise ValueError(f"patch_min_push must be a finite number of cells >= 0, got {patch_min_push}")
        if not 0 <= float(patch_min_push_fraction) < 1:
            raise ValueError(f"patch_min_push_fraction must be in [0, 1), got {patch_min_push_fraction}")
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
        self.patch_min_push = float(patch_min_push)
        self.patch_min_push_fraction = float(patch_min_push_fraction)
        self.cache = SampleCache(cache_dir)
        self.sim_device = sim_device
        self._simulator: EIPSimulator | None = None
        self._memory: dict[int, dict[str, np.ndarray]] | None = {} if memory_cache else None

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
            kwargs: dict[str, Any] = {} if self.sim_device is None else {"device": self.sim_device}
            if mp.parent_process() is not None:
                # a worker of generate's pool or of a dataloader (one per core, torch at one thread): the set-up keeps
                # to the process's thread budget, also on a GPU, where the simulator's own default is every core
                kwargs["setup_threads"] = torch.get_num_threads()
            self._simulator = EIPSimulator(sensor=self.sensor, press=self.press, **kwargs)
        return self._simulator

    def plan_compile(self, touches: int) -> bool:
        """Settle ``press.compile`` for a process about to press ``touches`` of this dataset's touches.

        ``"auto"`` becomes True or False (:func:`~tvrecon.sim.mpm.compiled.policy.resolve_compile`: a CPU with a C++
        compiler and enough touches to pay back the compile); True or False stay. When compiling, the compile cache
        goes under the data cache (``<cache_dir>/torch_compile``) unless ``$TORCHINDUCTOR_CACHE_DIR`` is set, so the
        next process compiles from it. Call it before the dataset is pickled into worker processes.

        Returns:
            Whether this dataset's presses now run the compiled kernels.
        """
        root = self.cache.root if self.cache.enabled else None
        device = self.sim_device if self.sim_device is not None else "cpu"
        (h, w), layers = self.sensor.resolution, int(self.sensor.layers)
        work = touch_work(int(h) * int(w) * layers, int(self.press.n_grid))  # the pad's cost per touch
        on, why = resolve_compile(self.press.compile, int(touches), device, root, work=work)
        if on:
            use_compile_cache(root)
        if on != self.press.compile:
            self.press = dataclasses.replace(self.press, compile=on)
            self._simulator = None
        if why != "as configured":
            kernels = "compiled" if on else "eager"
            log.info("press.compile=auto for split %r: %s -> %s kernels", self.split, why, kernels)
        return on

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

    def _simulate(
        self, mesh: trimesh.Trimesh, seed: int, camera: Any = None, index: int | None = None
    ) -> dict[str, np.ndarray]:
        """Sample ``touches_per_item`` touches and simulate them in one batch.

        A touch the simulator cannot place (the pad would start inside a concave part, ~2% of random touches) is
        replaced by another seeded touch, see :meth:`_placeable_touches` (``index``: the item, named in its warning).

        Returns arrays: tactile (M,3,Hs,Ws) float32 grid cells, positions (M,3), directions (M,3) float32,
        contact (M,) bool, depth (M,) float32.
        """
        M = self.touches_per_item
        touches = sample_touches(mesh, M, seed=seed, policy=self.touch, camera=camera, sim=self.simulator)
        try:
            readings = self._simulate_stable(mesh, touches, index=index)
        except ValueError:
            touches = self._placeable_touches(mesh, touches, seed, camera, index=index)
            readings = self._simulate_stable(mesh, touches, index=index)
        return {
            "tactile": torch.stack([r.image for r in readings]).float().cpu().numpy(),
            "positions": torch.stack([r.position for r in readings]).float().cpu().numpy(),
            "directions": torch.stack([r.direction for r in readings]).float().cpu().numpy(),
            "contact": np.array([bool(r.contact) for r in readings]),
            "depth": np.array([float(r.depth) for r in readings], dtype=np.float32),
        }

    def _simulate_stable(
        self, mesh: trimesh.Trimesh, touches: Touches, halvings: int = 3, index: int | None = None
    ) -> list:
        """:func:`simulate_touches` of all touches in one batch; when the batch diverges (a rare contact of a part
        about a cell thick, e.g. a pear's stem pressed from the side at the CPU presets' step), each touch is pressed
        alone and one that diverges again is pressed with the time step halved, up to ``halvings`` times. A touch that
        diverges at every step with the particle contact (the shared_base mug's handle from the side on the authors'
        grid, ``cls_paper`` val item 45: the state blows up 72 steps in at every step size) is pressed once more with
        the grid contact (``contact="grid"``, the solver's default: the object acts on the grid nodes inside it), and
        a warning names it. Deterministic: the same touches take the same path on every run. Raises FloatingPointError
        when that diverges too."""
        try:
            return simulate_touches(self.simulator, mesh, touches, batch_size=len(touches.strengths))
        except FloatingPointError:
            pass
        p = self.simulator.cfg
        s = self.simulator.sensor
        dt = p.dt if p.dt is not None else float(cfl_dt(MPMConfig(n_grid=int(p.n_grid), E=s.E, nu=s.nu, rho=s.rho)))
        out = []
        for t in range(len(touches.strengths)):
            one = touches.take(t)
            tries = [{}] + [{"dt": dt / 2**k} for k in range(1, halvings + 1)]
            if p.contact != "grid":
                tries.append({"contact": "grid"})  # the last resort: the node contact, at the preset's step
            for k, change in enumerate(tries):
                try:
                    reading = simulate_touches(
                        self.simulator, mesh, one._replace(strengths=[{**one.strengths[0], **change}])
                    )
                    break
                except FloatingPointError:
                    if k == len(tries) - 1:
                        raise
            if "contact" in change:
                item = "" if index is None else " item {} ({}, instance {})".format(index, *self.object_of(index))
                direction = [round(float(v), 3) for v in one.directions[0]]
                log.warning(
                    "%s%s: touch %d (direction %s) diverged with the %s contact at every step down to dt / %d: pressed "
                    "with the grid contact instead", self.split, item, t, direction, p.contact, 2**halvings,
                )  # fmt: skip
            out.append(reading[0])
        return out

    def _placeable_touches(
        self,
        mesh: trimesh.Trimesh,
        touches: Touches,
        seed: int,
        camera: Any = None,
        attempts: int = 20,
        index: int | None = None,
    ) -> Touches:
        """Replace the touches the simulator rejects with seeded re-draws (deterministic in ``seed``).

        Each touch is probed with a one-step press; a rejected touch ``t`` is re-drawn with seed
        ``SeedSequence([seed, t, attempt])`` until one is accepted, and one warning names the item (``index``), how
        many touches were re-drawn and why the first was rejected: a re-drawn touch is a single draw of the policy,
        outside the structure of the object's others (the paper's sweep). Raises ValueError when no attempt works.
        """
        out = {k: list(v) if isinstance(v, list) else v.clone() for k, v in touches._asdict().items()}

        def rejected(pos: Tensor, d: Tensor) -> str | None:
            try:
                self.simulator.press_batch(mesh, pos[None], d[None], max_steps=1)
            except ValueError as err:
                return str(err)
            return None

        redrawn: dict[int, str] = {}  # touch -> why its first draw was rejected
        for t in range(len(out["positions"])):
            why = rejected(out["positions"][t], out["directions"][t])
            if why is not None:
                redrawn[t] = why
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
        if redrawn:  # a policy with structure (the paper's sweep) loses it for these touches: say so
            first = next(iter(redrawn.values()))
            cls, instance = self.object_of(index) if index is not None else ("", 0)
            what = "an object" if index is None else f"item {index} ({cls} {instance})"
            log.warning(
                "%s split, %s: %d of %d touches could not be placed and were re-drawn one by one by %s, outside "
                "the structure of the object's other touches; the first was rejected with: %s",
                self.split,
                what,
                len(redrawn),
                len(out["positions"]),
                type(self.touch).__name__,
                first,
            )
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
        if self._memory is not None and index in self._memory:
            return dict(self._memory[index]), True
        arrays, hit = self.cache.get_or_create(self.spec(index), lambda: self._generate_single_thread(index))
        self._check_finite_tactile(index, arrays)
        if "label" in arrays:
            arrays["label"] = np.asarray(self.label_of(index), dtype=np.int64)
        if self._memory is not None:
            self._memory[index] = dict(arrays)
        return arrays, hit

    def _check_finite_tactile(self, index: int, arrays: Mapping[str, np.ndarray]) -> None:
        """Refuse an entry whose tactile images hold NaN or inf, naming its cache file: a NaN loss many steps later
        named no entry, and the only way out was deleting the whole cache."""
        tactile = arrays.get("tactile")
        if tactile is None or bool(np.isfinite(tactile).all()):
            return
        name, instance = self.object_of(index)
        where = self.cache.path(cache_key(self.spec(index))) if self.cache.enabled else "(not cached)"
        raise ValueError(
            f"the tactile images of split {self.split!r} item {index} ({name}, instance {instance}) hold NaN or inf: "
            f"cache entry {where}. Delete that file (the next read simulates the item again), not the whole cache"
        )

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
        from tvrecon.data.cache.store import cache_key

        return cache_key(self.spec(self._check_index(index))) in self.cache

    # ----------------------------------------------------------------- load-time processing
    def _tactile(self, raw: np.ndarray) -> Tensor:
        """(T,3,Hs,Ws) raw grid-cell images -> (T,3,h,w) float32 at the model resolution, divided by the scale."""
        images = torch.from_numpy(np.ascontiguousarray(raw)).float()
        if images.shape[0] == 0:
            return images.new_zeros((0, 3, *self.tactile_size))
        return resize_tactile(images, self.tactile_size) / self.tactile_scale
