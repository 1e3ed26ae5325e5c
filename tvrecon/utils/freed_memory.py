"""Keeping freed memory in the process between solver steps (glibc's malloc), for jobs that press many touches.

A compiled press step on the CPU allocates ~100 MB of temporaries for the authors' pad (10 touches: 372,100
particles, each (9, P) float32 state buffer 13 MB) and frees them at the step's end. With glibc's default
dynamic thresholds the freed top of the heap is returned to the kernel (trimmed) after each step, and the next step
page-faults the same memory back in, zeroed: on this project's 2-core VM that was a third of the fused G2P's time
(25 ms a step against 15 ms on reused memory; ``benchmarks/README.md``, "The heap kept between steps").
:func:`keep_freed_memory` fixes the thresholds instead: blocks up to 32 MiB come from the heap, and up to 1 GiB of
freed heap stays in the process for the next step. The process's resident memory then stays at its peak (up to
that GiB) instead of falling between steps, which is why it is a job's choice and not something the simulator does
on import: :func:`tvrecon.data.generate.pregenerate_splits` calls it in every process that generates (``python -m
tvrecon.data.generate``, its workers, and a datamodule that makes its missing data before training).
"""

from __future__ import annotations

import ctypes
import logging
import platform
import sys

log = logging.getLogger(__name__)

__all__ = ["keep_freed_memory"]

# mallopt's parameters (glibc malloc.h)
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD_MAX = 32 << 20  # glibc's largest M_MMAP_THRESHOLD on 64-bit systems (HEAP_MAX_SIZE / 2)

_kept: tuple[int, int] | None = None


def keep_freed_memory(mmap_threshold: int = MMAP_THRESHOLD_MAX, trim_threshold: int = 1 << 30) -> bool:
    """Have glibc's malloc serve blocks up to ``mmap_threshold`` bytes from the heap and keep up to ``trim_threshold``
    bytes of freed heap in the process (``mallopt(M_MMAP_THRESHOLD)``, ``mallopt(M_TRIM_THRESHOLD)``), for the rest
    of the process. Returns whether the thresholds are set; False (and nothing changed) where the C library is not
    glibc (macOS, Windows, musl). Calling it again with the same values does nothing."""
    global _kept
    if not 0 < mmap_threshold <= MMAP_THRESHOLD_MAX:
        raise ValueError(f"mmap_threshold must be in (0, {MMAP_THRESHOLD_MAX}] bytes (glibc's), got {mmap_threshold}")
    if not 0 < trim_threshold < 2**31:
        raise ValueError(f"trim_threshold must be in (0, 2**31) bytes (mallopt takes an int), got {trim_threshold}")
    if _kept == (mmap_threshold, trim_threshold):
        return True
    if not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc":
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # pragma: no cover - glibc always has mallopt
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    if mallopt(M_MMAP_THRESHOLD, mmap_threshold) != 1 or mallopt(M_TRIM_THRESHOLD, trim_threshold) != 1:
        log.warning("glibc's mallopt refused the heap thresholds; freed memory is returned to the system as before")
        return False
    _kept = (mmap_threshold, trim_threshold)
    log.debug("malloc keeps up to %d MiB freed (blocks up to %d MiB)", trim_threshold >> 20, mmap_threshold >> 20)
    return True
