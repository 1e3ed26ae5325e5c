"""``tvrecon.utils.freed_memory.keep_freed_memory``: with it, memory a step freed is reused by the next step instead of
being page-faulted in again (counted with ``getrusage``'s minor faults, in a fresh process each, since the setting is
for the whole process)."""

import platform
import subprocess
import sys

import pytest

from tvrecon.utils.freed_memory import MMAP_THRESHOLD_MAX, keep_freed_memory

# three 13 MB blocks a "step", as a paper step's (9, P) float32 state buffers: malloc'ed, written, freed, ten times
STEPS = """
import ctypes, resource, sys
from tvrecon.utils.freed_memory import keep_freed_memory
if sys.argv[1] == "keep":
    assert keep_freed_memory()
libc = ctypes.CDLL(None)
libc.malloc.restype, libc.malloc.argtypes, libc.free.argtypes = ctypes.c_void_p, [ctypes.c_size_t], [ctypes.c_void_p]
n = 9 * 372100 * 4
def step():
    blocks = [libc.malloc(n) for _ in range(3)]
    for b in blocks:
        ctypes.memset(b, 1, n)
    for b in blocks:
        libc.free(b)
for _ in range(3):  # glibc's dynamic thresholds settle in the first steps
    step()
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(10):
    step()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


def _faults(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", STEPS, mode], capture_output=True, text=True, check=True)
    return int(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_freed_step_buffers_are_reused_instead_of_faulted_in_again():
    plain, kept = _faults("plain"), _faults("keep")
    pages = 10 * 3 * 9 * 372100 * 4 // 4096  # what ten steps touch: ~32,700 pages of 4 KiB
    assert plain > pages // 2, f"glibc's defaults return the blocks between steps ({plain} faults; measured ~all)"
    assert kept < pages // 50, f"kept memory should not fault again: {kept} minor faults in 10 steps"


def test_thresholds_out_of_glibcs_range_are_refused():
    with pytest.raises(ValueError, match="mmap_threshold"):
        keep_freed_memory(mmap_threshold=MMAP_THRESHOLD_MAX + 1)
    with pytest.raises(ValueError, match="trim_threshold"):
        keep_freed_memory(trim_threshold=2**31)
