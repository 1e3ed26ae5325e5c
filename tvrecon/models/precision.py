"""The training precision a machine runs fastest without losing the models' accuracy: ``trainer.precision: auto``.

``best_precision(accelerator)`` answers Lightning's ``precision`` string: ``bf16-mixed`` (autocast of the forward and
the losses to bfloat16; weights, gradients and the optimizer stay float32) on a CPU with native bfloat16 arithmetic
(``avx512_bf16`` or ``amx_bf16``) where bfloat16 also runs the step's dominant product faster (a probe of under a
second, :func:`cpu_bf16_is_faster`), and on a CUDA GPU that supports it; ``32-true`` everywhere else. The flag alone
does not decide it (``results/bench/train_step/``, one thread): on an AMD EPYC with avx512_bf16 the bf16 step is
1.9-2.1x the step of 487a852, on an Intel Xeon with avx512_bf16 and no AMX flags 0.9-1.04x, where float32 is
1.35-1.51x; a CPU without the flags emulates bfloat16 and gains nothing.
The configs call it through the OmegaConf resolver ``best_precision`` (``precision: ${best_precision:cpu}``), registered
when :mod:`tvrecon.models` is imported; ``trainer.precision=32-true`` (or any Lightning value) overrides it.
"""

from __future__ import annotations

import functools
import statistics
import time
from pathlib import Path

import torch
from omegaconf import OmegaConf

__all__ = ["ACCELERATORS", "best_precision", "cpu_bf16_is_faster", "cpu_has_native_bf16", "register_precision_resolver"]

ACCELERATORS = ("auto", "cpu", "gpu", "cuda", "mps", "tpu")
_BF16_FLAGS = ("avx512_bf16", "amx_bf16")


@functools.cache
def cpu_has_native_bf16(cpuinfo: str | Path = "/proc/cpuinfo") -> bool:
    """Whether the CPU computes in bfloat16 natively (x86 ``avx512_bf16`` / ``amx_bf16`` flags in ``cpuinfo``).

    False where ``cpuinfo`` cannot be read (other systems): the safe answer, float32.
    """
    try:
        text = Path(cpuinfo).read_text()
    except OSError:
        return False
    for line in text.splitlines():
        if line.startswith("flags"):
            flags = set(line.split(":", 1)[1].split())
            return any(flag in flags for flag in _BF16_FLAGS)
    return False


#: the probe's product: a graph convolution of the deformer's last stage (8 meshes of 2,466 vertices, 192 features)
PROBE_SHAPE = (8 * 2466, 192, 192)
#: bf16 is chosen where its probe time is at most this fraction of float32's (a margin for timing noise)
PROBE_MARGIN = 0.9


def _product_seconds(bf16: bool, shape: tuple[int, int, int], repeats: int) -> float:
    """Median seconds of forward and backward of an ``(m, k) @ (k, n)`` product, under bf16 autocast or in float32."""
    m, k, n = shape
    generator = torch.Generator().manual_seed(0)
    x = torch.randn(m, k, generator=generator, requires_grad=True)
    w = torch.randn(k, n, generator=generator, requires_grad=True)

    def step() -> None:
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            y = x @ w
        y.float().sum().backward()

    step()  # warm-up: the first call picks and builds the kernels
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        step()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


@functools.cache
def cpu_bf16_is_faster(shape: tuple[int, int, int] = PROBE_SHAPE, repeats: int = 3) -> bool:
    """Whether bfloat16 autocast runs a graph-convolution product (``shape`` = (m, k, n), forward and backward) in at
    most :data:`PROBE_MARGIN` of float32's time on this CPU, with torch's current threads: the deformer's products are
    most of a training step, so this decides the step's faster precision (about 0.5 s with the default shape)."""
    seconds = {bf16: _product_seconds(bf16, shape, repeats) for bf16 in (False, True)}
    return seconds[True] <= PROBE_MARGIN * seconds[False]


def best_precision(accelerator: str = "auto") -> str:
    """Lightning's ``precision`` for ``accelerator``: ``bf16-mixed`` where bfloat16 is native and faster, else
    ``32-true``.

    Args:
        accelerator: Lightning's accelerator (``auto``, ``cpu``, ``gpu``, ``cuda``, ``mps``, ``tpu``); ``auto`` means
            CUDA when a GPU is visible, else the CPU.
    """
    name = str(accelerator).lower()
    if name not in ACCELERATORS:
        raise ValueError(f"accelerator must be one of {ACCELERATORS}, got {accelerator!r}")
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name in ("gpu", "cuda"):
        return "bf16-mixed" if torch.cuda.is_available() and torch.cuda.is_bf16_supported() else "32-true"
    if name == "cpu":
        return "bf16-mixed" if cpu_has_native_bf16() and cpu_bf16_is_faster() else "32-true"
    return "32-true"


def register_precision_resolver() -> None:
    """Register ``${best_precision:<accelerator>}`` with OmegaConf (idempotent)."""
    if not OmegaConf.has_resolver("best_precision"):
        OmegaConf.register_new_resolver("best_precision", best_precision)
