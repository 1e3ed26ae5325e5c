"""The op counters: the dispatch-mode counter sees eager ops and syncs; the profiled counter sees what a compiled
function runs (its fused kernels), where the dispatch mode sees the eager decomposition."""

import torch

from tvrecon.utils.op_counter import FUSED_KERNEL, OpCounter, ProfiledCounter, kernel_profile, per_step


def _eager_loop(x: torch.Tensor, steps: int) -> int:
    for _ in range(steps):
        x = (x * 2.0 + 1.0).sin()
        if bool((x > 10).any()):  # one host sync per step
            break
    return steps


def test_both_counters_agree_on_eager_code() -> None:
    x = torch.rand(64)
    a, b = per_step(lambda n: _eager_loop(x, n or 9)), per_step(lambda n: _eager_loop(x, n or 9), ProfiledCounter)
    for c in (a, b):
        assert c["steps"] == 9
        assert c["syncs_per_step"] == 1.0, c["syncs_by_op"]  # bool(tensor) -> _local_scalar_dense
    # mul, add, sin, gt, any and the sync (the dispatch mode sees _local_scalar_dense, the trace its caller)
    assert a["launch_ops_per_step"] == b["launch_ops_per_step"] == 6.0, (a["top_ops"], b["top_ops"])


def test_the_profiled_counter_sees_a_compiled_function_as_its_fused_kernels() -> None:
    @torch.compile(dynamic=False)
    def step(x: torch.Tensor) -> torch.Tensor:
        return ((x * 2.0 + 1.0).sin() * x).cos() + x.exp()  # one fused elementwise kernel

    x = torch.rand(256)
    with kernel_profile():
        step(x)  # compile (with a profiler record per kernel call)

        def loop(n: int | None) -> int:
            y = x
            for _ in range(n or 7):
                y = step(y)
            return n or 7

        profiled = per_step(loop, ProfiledCounter)
        dispatched = per_step(loop, OpCounter)
    assert profiled["top_ops"].get(FUSED_KERNEL) == 1.0, profiled["top_ops"]
    assert profiled["launch_ops_per_step"] == 1.0, profiled["top_ops"]  # the wrapper allocates without the dispatcher
    # the dispatch mode runs the compiled code eagerly: every op of the decomposition
    assert dispatched["launch_ops_per_step"] >= 6.0, dispatched["top_ops"]
