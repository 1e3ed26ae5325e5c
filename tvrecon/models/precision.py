"""The training precision a machine runs fastest without losing the models' accuracy: ``trainer.precision: auto``.

``best_precision(accelerator)`` answers Lightning's ``precision`` string: ``bf16-mixed`` (autocast of the forward and
the losses to bfloat16; weights, gradients and the optimizer stay float32) on a CPU with native bfloat16 arithmetic
(``avx512_bf16`` or ``amx_bf16``: the convolutions and graph-conv products run about twice as fast) and on a CUDA GPU
that supports it; ``32-true`` everywhere else (a CPU without those instructions emulates bfloat16 and gains nothing).
The configs call it through the OmegaConf resolver ``best_precision`` (``precision: ${best_precision:cpu}``), registered
when :mod:`tvrecon.models` is imported; ``trainer.precision=32-true`` (or any Lightning value) overrides it.
"""

from __future__ import annotations

import functools
from pathlib import Path

import torch
from omegaconf import OmegaConf

__all__ = ["ACCELERATORS", "best_precision", "cpu_has_native_bf16", "register_precision_resolver"]

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


def best_precision(accelerator: str = "auto") -> str:
    """Lightning's ``precision`` for ``accelerator``: ``bf16-mixed`` where bfloat16 is native, else ``32-true``.

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
        return "bf16-mixed" if cpu_has_native_bf16() else "32-true"
    return "32-true"


def register_precision_resolver() -> None:
    """Register ``${best_precision:<accelerator>}`` with OmegaConf (idempotent)."""
    if not OmegaConf.has_resolver("best_precision"):
        OmegaConf.register_new_resolver("best_precision", best_precision)
