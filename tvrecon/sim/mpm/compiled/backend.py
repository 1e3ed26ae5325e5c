"""The compiled backend of :class:`tvrecon.sim.mpm.solver.MLSMPM`: its kernels (:mod:`.kernels`, :mod:`.grid`'s
``grid_collide`` and the particle contact's passes) wrapped once per process in ``torch.compile``, and the failure that
sends the solver back to its eager step."""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable

import torch
from torch import Tensor

from tvrecon.sim.bodies.mesh_stack import near_blocks
from tvrecon.sim.mpm.compiled.grid import grid_collide
from tvrecon.sim.mpm.compiled.kernels import (
    block_index,
    g2p_update,
    p2g_contrib,
    polar_fixed,
    share_force,
    stencil_base,
)
from tvrecon.sim.mpm.free_flight import free_of_mesh
from tvrecon.sim.mpm.particle_contact import contact_passes, mesh_contact

__all__ = ["CompileFailed", "CompiledKernels", "compiled_kernels"]

log = logging.getLogger(__name__)

# per kernel, the dimension(s) of each positional argument that vary (the particle, node, candidate or scene count;
# None: not a tensor or fixed). Only these are marked dynamic: ``dynamic=True`` would also make the 3s and 9s
# symbolic, and inductor then emits scalar (unvectorized) loops with symbolic strides.
_DYN_DIMS: dict[str, tuple[int | tuple[int, ...] | None, ...]] = {
    "stencil": (1,),
    "index": (1, 1),
    "polar": (1,),
    "p2g": (1, 1, 1, 1, 1, 0, 0, None, None),
    "grid": (0, None, None, 0, 1),
    "g2p": (0, None, 0, 1, 1, 1, 0, 1),
    "share": (0, None, 0, 1, 0),
    "contact": (0, 0, 1, 0, 0, 0, 0, 0, 0),
    "near": ((0, 1), 0, 0, 0, 0),
    "mesh_contact": (0, 0, 0, 1, None, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0),  # cand, scene: 5, 6
    "free_contact": (0, 0, 0, 0, 0, 0, 0, 0, None),  # x, v, cand, scene, then the stacked tables
}


#: inductor options of the kernels: no bounds check on the indirect loads of ``g2p_update`` (its node indices are
#: inside the block by construction of ``grid.block_layout``: base .. base + 2 on every axis).
_OPTIONS = {"assert_indirect_indexing": False}


class CompiledKernels:
    """The per-particle functions of :mod:`.kernels`, :func:`tvrecon.sim.mpm.compiled.grid.grid_collide` wrapped in
    ``torch.compile`` with dynamic particle / node counts (they vary from step to step and press to press; the 3x3
    sizes stay static).

    ``kernels(name, *args)`` calls one; the first failure (no C++ compiler, an inductor error) is logged, warned once,
    marks the kernels failed (:func:`compiled_kernels` then returns None) and raises :class:`CompileFailed` so that
    the solver falls back to its eager step for good.
    """

    failed = False

    def __init__(self) -> None:
        self._fns: dict[str, Callable] = {
            name: torch.compile(f, options=_OPTIONS)
            for name, f in (
                ("stencil", stencil_base),
                ("index", block_index),
                ("polar", polar_fixed),
                ("p2g", p2g_contrib),
                ("grid", grid_collide),
                ("g2p", g2p_update),
                ("share", share_force),
                ("contact", contact_passes),
                ("near", near_blocks),
                ("mesh_contact", mesh_contact),
                ("free_contact", free_of_mesh),
            )
        }

    def __call__(self, name: str, *args):
        try:
            for a, dims in zip(args, _DYN_DIMS[name]):
                if dims is None or not isinstance(a, Tensor):
                    continue
                for d in (dims,) if isinstance(dims, int) else dims:
                    if a.dim() > d:
                        torch._dynamo.maybe_mark_dynamic(a, d)
            return self._fns[name](*args)
        except Exception as e:  # noqa: BLE001 - any compile/runtime failure -> eager fallback
            msg = f"torch.compile of the MLS-MPM kernel {name!r} failed ({type(e).__name__}: {e}); using the eager step"
            log.warning(msg)
            warnings.warn(msg, RuntimeWarning, stacklevel=3)
            self.failed = True
            raise CompileFailed(msg) from e


_KERNELS: CompiledKernels | None = None


def compiled_kernels() -> CompiledKernels | None:
    """The process-wide compiled kernels (one set, so every solver and press shares the compiled code), or None
    once compiling has failed."""
    global _KERNELS
    if _KERNELS is None:
        _KERNELS = CompiledKernels()
    return None if _KERNELS.failed else _KERNELS


class CompileFailed(RuntimeError):
    """A compiled kernel could not be built or run; the solver goes on with its eager step."""
