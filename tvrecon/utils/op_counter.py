"""Count the aten ops and host syncs a piece of torch code dispatches (what a GPU pays as launches and stalls).

:class:`OpCounter` is a ``TorchDispatchMode``: every aten op dispatched inside it is counted by name, and the ones
whose result the host must wait for are counted again as syncs: ``_local_scalar_dense`` (``.item()``, ``float(t)``,
``bool(t)``), ``nonzero``, ``masked_select``, ``unique*``, ``repeat_interleave`` with tensor repeats, boolean-mask
indexing, and ``Tensor.tolist`` (a copy to the host that dispatches no aten op on the CPU). It runs on the CPU, so CI
guards the GPU shape of a loop without a GPU. :func:`per_step` turns two counted runs of a loop into counts per step.

A dispatch mode makes dynamo run ``torch.compile``'d code eagerly, so it counts the decomposition of a compiled
kernel, not what runs. :class:`ProfiledCounter` counts from a ``torch.profiler`` trace instead: the aten ops called at
the top level (eager code and a compiled graph's wrapper: its extern kernels; its allocations bypass the
dispatcher), plus one op per fused
inductor kernel call, which the trace shows only for code compiled with
``torch._inductor.config.cpp.enable_kernel_profile = True`` (CPU kernels; :func:`kernel_profile` sets it).
"""

from __future__ import annotations

import contextlib
import re
from collections import Counter
from collections.abc import Callable, Iterator
from typing import Any

import torch
from torch.utils._python_dispatch import TorchDispatchMode

__all__ = ["SYNC_OPS", "VIEW_OPS", "OpCounter", "ProfiledCounter", "StepCounts", "kernel_profile", "per_step"]

#: ops that only make a new view of existing memory: no kernel on a GPU
VIEW_OPS = frozenset(
    "view _unsafe_view alias as_strided slice select expand unsqueeze squeeze transpose t permute detach "
    "split unbind chunk narrow diagonal reshape unflatten".split()
)
#: ops whose result the host waits for
SYNC_OPS = frozenset(
    ("_local_scalar_dense", "nonzero", "masked_select", "unique", "_unique", "unique_dim", "unique_consecutive")
)


def _count_tolist(syncs: Counter[str]) -> Callable[..., Any]:
    """Make ``Tensor.tolist`` of a non-empty tensor count as a sync in ``syncs`` (a copy to the host that dispatches
    no aten op on the CPU); returns the original, to put back."""
    tolist = torch.Tensor.tolist

    def counted_tolist(t: torch.Tensor) -> Any:
        if t.numel():
            syncs["tolist"] += 1
        return tolist(t)

    torch.Tensor.tolist = counted_tolist  # type: ignore[method-assign]
    return tolist


class OpCounter(TorchDispatchMode):
    """Counts aten ops (by overload packet name) in ``ops`` and the host-syncing ones among them in ``syncs``."""

    def __init__(self) -> None:
        super().__init__()
        self.ops: Counter[str] = Counter()
        self.syncs: Counter[str] = Counter()
        self._tolist: Callable[..., Any] | None = None

    def __enter__(self) -> OpCounter:
        self._tolist = _count_tolist(self.syncs)
        return super().__enter__()

    def __exit__(self, *exc: object) -> None:
        torch.Tensor.tolist = self._tolist  # type: ignore[method-assign]
        super().__exit__(*exc)

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):  # noqa: ANN001, ANN204 (torch's signature)
        name = func.overloadpacket.__name__
        self.ops[name] += 1
        if name in SYNC_OPS:
            self.syncs[name] += 1
        elif name == "repeat_interleave" and len(args) > 1 and isinstance(args[1], torch.Tensor):
            self.syncs[name] += 1
        elif name == "index" and any(
            isinstance(i, torch.Tensor) and i.dtype == torch.bool for i in (args[1] if len(args) > 1 else ()) or ()
        ):
            self.syncs["index(bool mask)"] += 1
        return func(*args, **(kwargs or {}))


#: the name of one fused inductor CPU kernel call in a profiler trace (``graph_3_cpp_fused_add_mul_0``)
KERNEL_EVENT = re.compile(r"^graph_\d+_cpp_fused_")
#: the key under which :class:`ProfiledCounter` counts fused kernel calls in ``ops``
FUSED_KERNEL = "inductor_kernel"


@contextlib.contextmanager
def kernel_profile() -> Iterator[None]:
    """Compile CPU code inside this block with a profiler record per fused kernel call (what
    :class:`ProfiledCounter` counts); inductor keys its cache on the setting, so this is a compile of its own."""
    import torch._inductor.config as inductor_config

    with inductor_config.patch({"cpp.enable_kernel_profile": True}):
        yield


class ProfiledCounter:
    """What a piece of torch code runs, compiled kernels included, counted from a CPU ``torch.profiler`` trace.

    ``ops``: aten ops by name that were not called from inside another aten op (what eager code and a compiled
    graph's wrapper launch), plus ``inductor_kernel`` for each fused kernel call (seen only for code compiled under
    :func:`kernel_profile`); ``kernels``: those calls by kernel name. ``syncs``: the host-syncing ops of
    :data:`SYNC_OPS` at any depth (a boolean-mask ``index`` and a tensor-repeats ``repeat_interleave`` show their
    inner ``nonzero`` / ``_local_scalar_dense``) and ``Tensor.tolist``. Same interface as :class:`OpCounter` for
    :func:`per_step`.
    """

    def __init__(self) -> None:
        self.ops: Counter[str] = Counter()
        self.syncs: Counter[str] = Counter()
        self.kernels: Counter[str] = Counter()
        self._tolist: Callable[..., Any] | None = None
        self._profile: torch.profiler.profile | None = None

    def __enter__(self) -> ProfiledCounter:
        self._tolist = _count_tolist(self.syncs)
        self._profile = torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU])
        self._profile.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        assert self._profile is not None
        try:
            self._profile.__exit__(*exc)
        finally:
            torch.Tensor.tolist = self._tolist  # type: ignore[method-assign]
        for event in self._profile.events():
            name = event.name
            if KERNEL_EVENT.match(name):
                self.kernels[name] += 1
                self.ops[FUSED_KERNEL] += 1
            elif name.startswith("aten::"):
                op = name[len("aten::") :]
                if op in SYNC_OPS:
                    self.syncs[op] += 1
                if not _called_from_an_op(event):
                    self.ops[op] += 1


def _called_from_an_op(event: Any) -> bool:
    """Whether a profiler event ran inside an aten op (then its parent op is what was launched)."""
    parent = event.cpu_parent
    while parent is not None:
        if parent.name.startswith("aten::"):
            return True
        parent = parent.cpu_parent
    return False


class StepCounts(dict):
    """Per-step counts of a loop (a dict, for JSON): ``steps``, ``ops_per_step``, ``launch_ops_per_step`` (not
    views), ``syncs_per_step``, ``ops_outside_steps``, ``syncs_by_op`` and ``top_ops``."""


def per_step(run: Callable[[int | None], int], counter: type[OpCounter | ProfiledCounter] = OpCounter) -> StepCounts:
    """Ops and syncs per step of a loop: ``run(max_steps)`` runs it (None: to its end) and returns its step count.

    Per step = (the whole run - the run stopped after one step) / (its steps - 1): what is paid once per run (set-up,
    read-out) cancels. ``counter``: :class:`OpCounter` (eager code) or :class:`ProfiledCounter` (compiled code).
    """
    one = counter()
    with one:
        run(1)
    full = counter()
    with full:
        steps = run(None)
    n = max(steps - 1, 1)
    ops, syncs = full.ops - one.ops, full.syncs - one.syncs
    return StepCounts(
        steps=steps,
        ops_per_step=sum(ops.values()) / n,
        launch_ops_per_step=sum(v for k, v in ops.items() if k not in VIEW_OPS) / n,
        syncs_per_step=sum(syncs.values()) / n,
        ops_outside_steps=sum(one.ops.values()) - sum(ops.values()) / n,
        syncs_by_op={k: round(v / n, 2) for k, v in syncs.most_common()},
        top_ops={k: round(v / n, 1) for k, v in ops.most_common(8)},
    )
