"""When presses run the compiled kernels: ``compile="auto"`` (the default of ``PressConfig.compile``) resolved per
process from the work it will do, and the persistent compile cache that makes a second process's compile cheap.

A compile costs the process a fixed time before its first fused step, and each touch after it is cheaper than an
eager one; so it pays back only over enough touches in one process. Measured on the ``small`` preset's touches (a
31 x 31 x 5 pad on the 64 grid; one thread, the other core busy with a training run;
``benchmarks/speed/bench_compile_auto.py``):
eager 0.574 CPU-s per touch, compiled 0.324; the compile 124 CPU-s with an empty compile cache and 19 with a warm one;
no recompiles after the first objects. The break-even is then 495 touches cold and 76 warm; the thresholds below
round those up. Larger pads save more per touch, so they pay back sooner: the thresholds count touches of that pad,
and a touch of another pad counts :func:`touch_work` of them (its particles times its grid, as the steps of a press
to the same relative depth grow with the grid). The authors' 61 x 61 x 10 pad on the 128 grid counts 15.5: it
compiles from 33 touches cold (break-even measured 16) and 7 warm (1).

- **CPU with a C++ compiler:** ``"auto"`` compiles when the process presses at least :data:`AUTO_MIN_TOUCHES_COLD`
  touches, or :data:`AUTO_MIN_TOUCHES_WARM` when this version of the kernels is already in the compile cache (a
  marker file written after a process's first compiled step).
- **CUDA:** ``"auto"`` compiles when the process presses at least :data:`AUTO_MIN_TOUCHES_CUDA` reference touches
  (about 4,800 of the authors' pad). Measured on an H100 (``benchmarks/README.md``, 2026-11-27, code ``36d3123``;
  the paper scene at batch 64, ``bench_gpu.py``): the compiled loop 18.9 ms a touch against the eager loop's 37.3
  (2.29e8 against 1.16e8 particle-steps/s), its first call 86.6 s longer than a timed one (an empty compile cache): a
  break-even of 4,700 authors' touches. The warm cache's compile was not timed on a GPU, so CUDA keeps this one
  threshold. A generation job's workers press their share each (16 workers: ~340 touches of ``cls_paper`` each):
  eager; one process pressing a whole preset: compiled.
- A job that does not know its size (a single ``EIPSimulator.press``) resolves with the touches of that call: eager.

The compile cache: :func:`use_compile_cache` points inductor's ``TORCHINDUCTOR_CACHE_DIR`` at ``torch_compile/`` of
the data cache (unless the user set it) in a process about to compile; spawned worker processes inherit it.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import sys
from functools import cache
from pathlib import Path

import torch

__all__ = [
    "AUTO",
    "AUTO_MIN_TOUCHES_COLD",
    "AUTO_MIN_TOUCHES_CUDA",
    "AUTO_MIN_TOUCHES_WARM",
    "CACHE_ENV",
    "CACHE_SUBDIR",
    "check_compile_setting",
    "compile_cache_dir",
    "compile_cache_warm",
    "cpp_compiler",
    "mark_compile_cache_warm",
    "resolve_compile",
    "touch_work",
    "use_compile_cache",
]

log = logging.getLogger(__name__)

#: the setting that lets the job decide (``PressConfig.compile``'s default)
AUTO = "auto"
#: touches per process from which ``"auto"`` compiles with an empty compile cache (break-even 495 measured)
AUTO_MIN_TOUCHES_COLD = 500
#: the same with this version of the kernels already in the compile cache (break-even 76 measured)
AUTO_MIN_TOUCHES_WARM = 100
#: CUDA: reference touches per process from which ``"auto"`` compiles (H100: 86.6 s compile / 18.4 ms saved per
#: authors' touch = 4,700 authors' touches x 15.5 = 73,000 reference touches; the cache's warmth not measured there)
AUTO_MIN_TOUCHES_CUDA = 75_000
#: the reference touch of the thresholds: the ``small`` preset's 31 x 31 x 5 pad (particles) on the 64 grid
REF_PARTICLES, REF_GRID = 31 * 31 * 5, 64
#: inductor's cache folder variable (read by torch at each compile, so setting it before the first one is enough)
CACHE_ENV = "TORCHINDUCTOR_CACHE_DIR"
#: the compile cache's folder inside the data cache
CACHE_SUBDIR = "torch_compile"

_SOURCES = ("backend.py", "grid.py", "kernels.py", "scatter.py", "step.py", "../particle_contact.py")


def check_compile_setting(value: object, name: str) -> None:
    """TypeError naming ``name`` unless ``value`` is True, False or ``"auto"``."""
    if not (isinstance(value, bool) or value == AUTO):
        raise TypeError(f"{name} must be true, false or {AUTO!r}, got {type(value).__name__} ({value!r})")


@cache
def cpp_compiler() -> str | None:
    """Path of the C++ compiler inductor's CPU kernels need (``$CXX``, else ``c++``, ``g++``, ``clang++``), or None."""
    for name in (os.environ.get("CXX"), "c++", "g++", "clang++"):
        if name and (found := shutil.which(name)):
            return found
    return None


def _user_cache_dir() -> str | None:
    """``$TORCHINDUCTOR_CACHE_DIR`` unless it is torch's own default, which importing ``torch._dynamo`` writes there
    (Lightning imports it), so that the variable alone does not tell a user's choice."""
    value = os.environ.get(CACHE_ENV)
    if value is None:
        return None
    # torch sets the variable from this module only: when it is not loaded, the value is the user's. Never imported
    # here: importing it loads torch._inductor and triton into an eager press, and triton loaded after a MuJoCo EGL
    # context ends the process with SIGSEGV
    utils = sys.modules.get("torch._inductor.runtime.cache_dir_utils")
    if utils is None:
        return value
    return None if os.path.abspath(value) == os.path.abspath(utils.default_cache_dir()) else value


def compile_cache_dir(root: str | Path | None = None) -> Path | None:
    """The compile cache folder a compile would use: ``$TORCHINDUCTOR_CACHE_DIR`` when a user set it, else
    ``root/torch_compile``, else torch's default (None when that is not set yet)."""
    if (user := _user_cache_dir()) is not None:
        return Path(user)
    if root is not None:
        return Path(root).expanduser().resolve() / CACHE_SUBDIR
    return Path(os.environ[CACHE_ENV]) if CACHE_ENV in os.environ else None


def use_compile_cache(root: str | Path | None) -> Path | None:
    """Point the compile cache at ``root/torch_compile`` unless a user set ``$TORCHINDUCTOR_CACHE_DIR`` (call it when
    this process is about to compile: the variable stays set for the process and the workers it spawns).

    Returns:
        The compile cache folder in use (None: torch's own default, ``root`` being None).
    """
    folder = compile_cache_dir(root)
    if folder is not None:
        os.environ[CACHE_ENV] = str(folder)
    return folder


@cache
def _kernels_version() -> str:
    """A digest of torch's version and the compiled kernels' sources: another version compiles anew."""
    here = Path(__file__).resolve().parent
    h = hashlib.sha1(torch.__version__.encode())
    for rel in _SOURCES:
        h.update((here / rel).read_bytes())
    return h.hexdigest()[:16]


def _marker(folder: Path | None = None) -> Path | None:
    folder = folder if folder is not None else compile_cache_dir()
    return folder / f"tvrecon-kernels-{_kernels_version()}.warm" if folder is not None else None


def compile_cache_warm(folder: Path | None = None) -> bool:
    """Whether this version of the kernels has compiled once into the compile cache ``folder`` (default: the one
    ``$TORCHINDUCTOR_CACHE_DIR`` names)."""
    marker = _marker(folder)
    return marker is not None and marker.is_file()


_MARKED = False


def mark_compile_cache_warm() -> None:
    """Record that this version of the kernels is in the compile cache (after a process's first compiled step)."""
    global _MARKED
    if _MARKED:
        return
    _MARKED = True
    marker = _marker()
    if marker is None:
        return
    try:
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.touch()
    except OSError as err:  # a read-only cache: the next process just takes the cold threshold
        log.debug("could not mark the compile cache warm (%s)", err)


def touch_work(particles: int, n_grid: int) -> float:
    """What one touch of a pad of ``particles`` on an ``n_grid`` grid costs, in touches of the thresholds' reference
    pad (31 x 31 x 5 on 64): the particles times the grid (the steps of a press to a given share of the object)."""
    return (int(particles) * int(n_grid)) / (REF_PARTICLES * REF_GRID)


def resolve_compile(
    setting: bool | str,
    touches: int,
    device: str | torch.device = "cpu",
    cache_root: str | Path | None = None,
    work: float = 1.0,
) -> tuple[bool, str]:
    """Whether a process that presses ``touches`` touches on ``device`` runs the compiled kernels.

    Args:
        setting: True / False (kept as given) or ``"auto"``.
        touches: the touches this process will press (its share of the job).
        device: the simulation device.
        cache_root: the data cache, whose compile cache (:func:`compile_cache_dir`) may already be warm.
        work: what one of these touches costs in reference touches (:func:`touch_work`; 1: the reference pad).
    Returns:
        ``(compile, why)``: the decision and a short reason for the log.
    """
    check_compile_setting(setting, "compile")
    if isinstance(setting, bool):
        return setting, "as configured"
    dev = torch.device(device)
    counted = touches * float(work)
    what = f"{touches} touches"
    if work != 1.0:
        what += f" x {float(work):.3g} = {counted:.0f} small-pad touches"
    if dev.type == "cuda":
        need = AUTO_MIN_TOUCHES_CUDA
        if counted >= need:
            return True, f"auto on cuda: {what} in this process >= {need} (the compile's break-even on an H100)"
        return False, f"auto on cuda: {what} in this process < {need} (the compile's break-even on an H100)"
    if dev.type != "cpu":
        return False, f"auto on {dev.type}: the eager step (the compiled one was not measured there)"
    if cpp_compiler() is None:
        return False, "auto: no C++ compiler found (set $CXX or install g++)"
    warm = compile_cache_warm(compile_cache_dir(cache_root))
    need = AUTO_MIN_TOUCHES_WARM if warm else AUTO_MIN_TOUCHES_COLD
    cache_state = "warm" if warm else "empty"
    if counted >= need:
        return True, f"auto: {what} in this process >= {need} ({cache_state} compile cache)"
    return False, f"auto: {what} in this process < {need} ({cache_state} compile cache)"
