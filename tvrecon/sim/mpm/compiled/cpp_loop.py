"""Building the compiled step's small C++ loops (:mod:`.scatter`'s P2G, :mod:`.gather`'s G2P) once per process with
inductor's own C++ toolchain and cache (``torch._inductor.codecache.CppCodeCache``: the compiler the compiled path
needs anyway)."""

from __future__ import annotations

import ctypes
import logging

from torch import Tensor

log = logging.getLogger(__name__)


def ptr(t: Tensor | None) -> ctypes.c_void_p:
    """A tensor's data pointer for a loop's ``const float*`` / ``int64_t*`` argument (null for None); the caller
    passes contiguous tensors of the dtype the loop reads."""
    return ctypes.c_void_p(None if t is None else t.data_ptr())


class CppLoop:
    """One C++ source and its ``int64_t``-returning function ``name`` (and ``also``: more such functions of the same
    source), built on first use; a failed build (no compiler, another torch) is logged once and leaves
    :meth:`library` None, so the caller keeps its other path (``fallback`` names it in the log line)."""

    def __init__(self, source: str, name: str, what: str, fallback: str, also: tuple[str, ...] = ()) -> None:
        self.source, self.name, self.what, self.fallback = source, name, what, fallback
        self.names = (name, *also)
        self._lib: object | None = None  # the loaded library, False after a failed build

    def library(self):
        if self._lib is None:
            try:
                from torch._inductor.codecache import CppCodeCache

                lib = CppCodeCache.load(self.source)
                for name in self.names:
                    getattr(lib, name).restype = ctypes.c_int64
                self._lib = lib
            except Exception as e:  # noqa: BLE001 - no compiler, another torch: the caller's other path stays
                why = f"{type(e).__name__}: {e}"
                log.warning("the %s could not be built (%s); using %s", self.what, why, self.fallback)
                self._lib = False
        return self._lib or None
