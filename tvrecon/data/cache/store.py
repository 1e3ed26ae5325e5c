"""Content-addressed on-disk cache of generated samples.

A sample is fully determined by a *spec*: a JSON-able mapping of everything that goes into it (mesh parameters,
touch policy and seeds, simulator / sensor / press configuration, render configuration, the generation code
version). Its key is the sha256 of the canonical JSON of that spec, so a changed configuration gives a different
key and a stale entry is never reused.

Layout: ``<root>/<key[:2]>/<key>.npz``. Each entry is an ``.npz`` of numpy arrays plus two bookkeeping arrays,
``__key__`` (the entry's own key) and ``__checksum__`` (sha256 over the names, dtypes, shapes and bytes of the data
arrays). Writes are atomic (temporary file in the same directory, then ``os.replace``), so an interrupted run never
leaves a half-written entry under a real key. A truncated or corrupt entry (unreadable zip, wrong key, checksum
mismatch) is reported with ``logging.warning`` naming the file, deleted, and reported as a miss so the caller
regenerates it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import os
import tempfile
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tvrecon.utils.atomic import default_file_mode, tmp_prefix
from tvrecon.utils.config_utils import omitted_from_key

log = logging.getLogger(__name__)

#: Bump whenever the code that turns a spec into a sample changes its output; part of every key.
#: 4: ``PressConfig`` defaults to particle contact and a threshold in 128-grid cells; both fields
#: stay out of the key at their defaults, so without the bump every default touch would differ under its old key.
#: 5: the paper's touches (``touch_sweep.PaperSweepTouchPolicy``, the presets' new default) and a touch that felt
#: nothing pressed again by the dataset; old entries are never read as new ones.
#: 6: the mesh collider's distance table measures every face of the 4 nearest *distinct* surface samples
#: (``sim.bodies.mesh_distance``): 1-4% of a touch's table nodes read up to 0.13 cells nearer (their true distance).
CACHE_VERSION = "tvrecon-data-6"

_KEY_FIELD = "__key__"
_CHECKSUM_FIELD = "__checksum__"


def _jsonable(obj: Any) -> Any:
    """Convert ``obj`` into plain JSON types (dict with str keys, list, str, int, float, bool, None).

    Dataclasses become dicts (without the fields marked ``config_utils.OMIT_IF_DEFAULT`` that hold their default, so
    a field added later leaves existing keys unchanged), tuples/sets become lists, numpy/torch scalars and arrays
    become (nested) lists, Paths become strings. Floats go through ``repr`` (shortest round-trip form, exact);
    non-finite floats are rejected.
    """
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {
            f.name: _jsonable(getattr(obj, f.name))
            for f in dataclasses.fields(obj)
            if not omitted_from_key(f, getattr(obj, f.name))
        }
    if isinstance(obj, Mapping):
        out = {}
        for k, v in obj.items():
            if not isinstance(k, str | int):
                raise ValueError(f"cache spec keys must be str or int, got {type(k).__name__} ({k!r})")
            out[str(k)] = _jsonable(v)
        return out
    if isinstance(obj, torch.Tensor):
        return _jsonable(obj.detach().cpu().numpy())
    if isinstance(obj, np.ndarray):
        return {"__ndarray__": str(obj.dtype), "shape": list(obj.shape), "data": _jsonable(obj.ravel().tolist())}
    if isinstance(obj, np.generic):
        return _jsonable(obj.item())
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, int):
        return obj
    if isinstance(obj, float):
        if not math.isfinite(obj):
            raise ValueError(f"cache spec contains a non-finite float ({obj}); specs must be finite")
        return obj
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, set | frozenset):
        return sorted((_jsonable(v) for v in obj), key=lambda v: json.dumps(v, sort_keys=True))
    # OmegaConf containers and other mappings/sequences
    try:
        from omegaconf import DictConfig, ListConfig, OmegaConf

        if isinstance(obj, DictConfig | ListConfig):
            return _jsonable(OmegaConf.to_container(obj, resolve=True))
    except ImportError:  # pragma: no cover - omegaconf is a hard dependency
        pass
    raise ValueError(f"cannot put an object of type {type(obj).__name__} into a cache spec; use plain data")


def canonical_json(spec: Any) -> str:
    """Canonical JSON text of ``spec``: sorted keys, no whitespace, exact floats (see :func:`_jsonable`)."""
    return json.dumps(_jsonable(spec), sort_keys=True, separators=(",", ":"), ensure_ascii=True)


def cache_key(spec: Any, version: str = CACHE_VERSION) -> str:
    """Hex sha256 (64 chars) of ``{"version": version, "spec": spec}`` in canonical JSON."""
    return hashlib.sha256(canonical_json({"version": version, "spec": spec}).encode("ascii")).hexdigest()


def _checksum(arrays: Mapping[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _to_numpy(name: str, value: Any) -> np.ndarray:
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().numpy()
    arr = np.asarray(value)
    if arr.dtype == object:
        raise ValueError(f"cache value {name!r} is not a numeric array (dtype=object); store tensors or numbers")
    return arr


class SampleCache:
    """Sharded ``.npz`` store addressed by spec hash.

    Args:
        root: cache directory (created on first write). ``None`` disables the cache: every ``get_or_create`` calls
            the generator and nothing is written.
        compress: write ``np.savez_compressed`` (default; tactile images are mostly zeros) or plain ``np.savez``.
    """

    def __init__(self, root: str | Path | None, compress: bool = True) -> None:
        self.root = None if root is None else Path(root).expanduser()
        self.compress = compress

    @property
    def enabled(self) -> bool:
        return self.root is not None

    def path(self, key: str) -> Path:
        """File of ``key``: ``root/key[:2]/key.npz``."""
        if self.root is None:
            raise ValueError("this SampleCache is disabled (root=None); give a cache directory to store entries")
        if len(key) < 3 or not all(c in "0123456789abcdef" for c in key):
            raise ValueError(f"cache key must be a lowercase hex digest, got {key!r}")
        return self.root / key[:2] / f"{key}.npz"

    def __contains__(self, key: str) -> bool:
        return self.root is not None and self.path(key).is_file()

    def load(self, key: str) -> dict[str, np.ndarray] | None:
        """Arrays stored under ``key``, or ``None`` on a miss.

        A corrupt entry (truncated file, bad zip, key or checksum mismatch) is logged with ``logging.warning``
        naming the file, deleted, and treated as a miss.
        """
        if self.root is None:
            return None
        path = self.path(key)
        if not path.is_file():
            return None
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {name: z[name] for name in z.files}
            stored_key = str(arrays.pop(_KEY_FIELD))
            stored_sum = str(arrays.pop(_CHECKSUM_FIELD))
        except PermissionError as err:
            # not corruption: another user's entry in a shared cache; never delete it
            msg = f"cache entry {path} cannot be read ({err}); fix its permissions or use another cache"
            raise ValueError(msg) from err
        except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zipfile.LargeZipFile) as err:
            self._discard(path, f"unreadable ({type(err).__name__}: {err})")
            return None
        if stored_key != key:
            self._discard(path, f"holds key {stored_key[:12]}..., expected {key[:12]}...")
            return None
        if _checksum(arrays) != stored_sum:
            self._discard(path, "checksum mismatch")
            return None
        return arrays

    def _discard(self, path: Path, why: str) -> None:
        log.warning("corrupt cache entry %s (%s); deleting it and regenerating", path, why)
        try:
            path.unlink()
        except FileNotFoundError:
            pass

    def check_writable(self, key: str) -> None:
        """Raise unless the entry of ``key`` could be stored: its shard folder exists or can be made, and takes a file.

        Called before a missing entry is generated (seconds to minutes of simulation), so a read-only cache is
        reported up front instead of after the work.

        Raises:
            ValueError: the cache is read-only (permissions, read-only file system, a file where a folder should be).
        """
        path = self.path(key)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, probe = tempfile.mkstemp(dir=path.parent, prefix=tmp_prefix("write-probe"), suffix=".tmp")
            os.close(fd)
            os.unlink(probe)
        except OSError as err:
            raise ValueError(
                f"cache {self.root} is read-only ({err.strerror or err}): entry {path.name} is missing and would be "
                f"generated but could not be stored. Make the cache writable, or set cache_dir to a folder you can "
                f"write to (copy the shared cache there to keep its entries)"
            ) from err

    def save(self, key: str, arrays: Mapping[str, Any]) -> Path:
        """Store ``arrays`` (name -> numpy array / tensor / number) under ``key`` atomically; return the file."""
        data = {}
        for name, value in arrays.items():
            if name in (_KEY_FIELD, _CHECKSUM_FIELD):
                raise ValueError(f"array name {name!r} is reserved by the cache")
            data[name] = _to_numpy(name, value)
        payload = dict(data)
        payload[_KEY_FIELD] = np.asarray(key)
        payload[_CHECKSUM_FIELD] = np.asarray(_checksum(data))
        path = self.path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=tmp_prefix(key[:12]), suffix=".tmp")  # names its writer
        try:
            with os.fdopen(fd, "wb") as f:
                (np.savez_compressed if self.compress else np.savez)(f, **payload)
                f.flush()
                os.fsync(f.fileno())
            os.chmod(tmp, default_file_mode())  # mkstemp makes 0600: give entries the umask's mode
            os.replace(tmp, path)
        except BaseException:
            try:
                os.unlink(tmp)
            except FileNotFoundError:
                pass
            raise
        return path

    def get_or_create(
        self, spec: Any, create: Callable[[], Mapping[str, Any]], version: str = CACHE_VERSION
    ) -> tuple[dict[str, np.ndarray], bool]:
        """Load the entry of ``spec`` or build it with ``create()`` and store it.

        Returns ``(arrays, hit)``; the arrays returned on a miss are read back exactly as they would be on a hit
        (same dtypes), so hit and miss give bit-identical samples.
        """
        key = cache_key(spec, version)
        cached = self.load(key)
        if cached is not None:
            return cached, True
        if self.root is not None:
            self.check_writable(key)
        arrays = {name: _to_numpy(name, v) for name, v in create().items()}
        if self.root is not None:
            self.save(key, arrays)
        return arrays, False

    def size_bytes(self) -> int:
        """Total size of the stored entries in bytes (0 for a disabled or empty cache)."""
        if self.root is None or not self.root.is_dir():
            return 0
        return sum(p.stat().st_size for p in self.root.glob("*/*.npz"))
