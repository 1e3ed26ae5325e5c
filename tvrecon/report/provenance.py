"""Where a result was made: the machine and the commit, as the ``manifest.json`` of every ``results/`` run names them.

Used by ``python -m benchmarks.run`` and by :mod:`tvrecon.report.record_run`.
"""

from __future__ import annotations

import os
import platform
import subprocess
from pathlib import Path

import torch

from tvrecon.models.precision import cpu_has_native_bf16

__all__ = ["git_commit", "machine"]


def machine() -> str:
    """The CPU model, its core count and vector unit, and the GPU when torch sees one, e.g.
    ``AMD EPYC x2, AVX512 with bf16`` or ``AMD EPYC 7R13 x16, AVX2 + NVIDIA H100 80GB HBM3``.

    The vector unit (torch's CPU capability, and whether bfloat16 is native) decides the training precision
    (:mod:`tvrecon.models.precision`) and much of a CPU step's time, so a CPU result names it.
    """
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    unit = torch.backends.cpu.get_cpu_capability()
    name = f"{cpu} x{os.cpu_count()}, {unit}" + (" with bf16" if cpu_has_native_bf16() else "")
    if torch.cuda.is_available():
        name += f" + {torch.cuda.get_device_name(0)}"
    return name


def git_commit(where: str | Path = ".") -> str | None:
    """The short commit of the git work tree holding ``where``, ``-dirty`` when tracked files have changes; None
    outside a git checkout (or without git)."""
    try:
        rev = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=where, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"], cwd=where, capture_output=True, text=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return rev + ("-dirty" if dirty else "")
