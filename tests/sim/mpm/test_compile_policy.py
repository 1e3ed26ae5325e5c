"""``compile="auto"`` (the fast path by default): who compiles, decided per process from its share of the
touches, the device, a C++ compiler and a warm compile cache; the compile cache under the data cache (the datasets'
side: ``tests/data/generation/test_compile_auto.py``).

Nothing is compiled here: the solver a press builds is caught after its construction (as in
``test_press_compile_config.py``).
"""

from __future__ import annotations

import os
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
import trimesh

from tvrecon.data.generation.pool import touches_per_process
from tvrecon.sim.mpm import MLSMPM
from tvrecon.sim.mpm.compiled import backend, policy
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.press import loop as press_loop
from tvrecon.sim.sensor.elastic_pad import SensorConfig


@pytest.fixture
def clean_policy(monkeypatch: pytest.MonkeyPatch, tmp_path: Path):
    """No compile cache variable, a C++ compiler, a fresh warm marker state."""
    monkeypatch.delenv(policy.CACHE_ENV, raising=False)
    monkeypatch.setattr(policy, "cpp_compiler", lambda: "/usr/bin/c++")
    monkeypatch.setattr(policy, "_MARKED", False)
    return tmp_path


def test_true_and_false_are_kept(clean_policy) -> None:
    assert policy.resolve_compile(True, 1) == (True, "as configured")
    assert policy.resolve_compile(False, 10**6)[0] is False
    with pytest.raises(TypeError, match="compile must be true, false or 'auto'"):
        policy.resolve_compile("yes", 1)  # type: ignore[arg-type]


def test_auto_compiles_a_large_cpu_job_only(clean_policy, monkeypatch: pytest.MonkeyPatch) -> None:
    cold = policy.AUTO_MIN_TOUCHES_COLD
    assert policy.resolve_compile("auto", cold)[0] is True
    on, why = policy.resolve_compile("auto", cold - 1)
    assert on is False and f"< {cold}" in why and "empty compile cache" in why
    assert policy.resolve_compile("auto", 10**6, "meta")[0] is False  # neither CPU nor CUDA: eager (not measured)
    monkeypatch.setattr(policy, "cpp_compiler", lambda: None)
    on, why = policy.resolve_compile("auto", 10**6)
    assert on is False and "no C++ compiler" in why


def test_auto_counts_a_larger_pad_as_more_touches(clean_policy) -> None:
    """The thresholds count touches of the small preset's pad; the authors' pad (61 x 61 x 10 on 128) saves ~30x more
    per touch (break-even 16 touches cold, measured), the demo's 19 x 19 x 3 on 40 ~7x less."""
    assert policy.touch_work(31 * 31 * 5, 64) == 1.0
    paper = policy.touch_work(61 * 61 * 10, 128)
    assert 15 < paper < 16
    on, why = policy.resolve_compile("auto", 40, work=paper)
    assert on is True and "40 touches x 15.5 = 620 small-pad touches" in why
    assert policy.resolve_compile("auto", 30, work=paper)[0] is False
    assert policy.resolve_compile("auto", 3000, work=policy.touch_work(19 * 19 * 3, 40))[0] is False  # tiny pads


def test_a_warm_compile_cache_lowers_the_threshold(clean_policy, monkeypatch: pytest.MonkeyPatch) -> None:
    root = clean_policy
    warm = policy.AUTO_MIN_TOUCHES_WARM
    assert policy.resolve_compile("auto", warm, cache_root=root)[0] is False  # nothing compiled there yet
    assert policy.compile_cache_dir(root) == root.resolve() / policy.CACHE_SUBDIR
    assert policy.use_compile_cache(root) == root.resolve() / policy.CACHE_SUBDIR
    assert os.environ[policy.CACHE_ENV] == str(root.resolve() / policy.CACHE_SUBDIR)
    policy.mark_compile_cache_warm()  # what the solver does after its first compiled step
    assert policy.compile_cache_warm()
    on, why = policy.resolve_compile("auto", warm, cache_root=root)
    assert on is True and "warm compile cache" in why
    assert policy.resolve_compile("auto", warm - 1, cache_root=root)[0] is False
    assert policy.resolve_compile("auto", warm, cache_root=root / "elsewhere")[0] is True  # the variable wins
    monkeypatch.delenv(policy.CACHE_ENV)
    assert not policy.compile_cache_warm(root / "elsewhere" / policy.CACHE_SUBDIR)


def test_a_user_compile_cache_is_kept(clean_policy, monkeypatch: pytest.MonkeyPatch) -> None:
    mine = clean_policy / "mine"
    monkeypatch.setenv(policy.CACHE_ENV, str(mine))
    assert policy.use_compile_cache(clean_policy / "data") == mine
    assert os.environ[policy.CACHE_ENV] == str(mine)
    # torch's own default, which importing torch._dynamo writes into the variable, is not a user's choice
    from torch._inductor.runtime.cache_dir_utils import default_cache_dir

    monkeypatch.setenv(policy.CACHE_ENV, default_cache_dir())
    assert policy.use_compile_cache(clean_policy / "data") == clean_policy.resolve() / "data" / policy.CACHE_SUBDIR


def test_a_press_batch_resolves_auto_with_its_own_touches(clean_policy, monkeypatch: pytest.MonkeyPatch) -> None:
    """``EIPSimulator.press_batch`` with the default ``auto`` compiles when its call alone has enough touches."""
    monkeypatch.setattr(backend, "_KERNELS", SimpleNamespace(failed=False))  # stand-in kernels, never called
    monkeypatch.setattr(policy, "AUTO_MIN_TOUCHES_COLD", 2 * policy.touch_work(8 * 8 * 3, 32))  # two of its touches
    built: list[bool] = []

    class Caught(MLSMPM):
        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            built.append(self.compiled)
            raise RuntimeError("caught")

    monkeypatch.setattr(press_loop, "MLSMPM", Caught)
    sim = EIPSimulator(SensorConfig(resolution=(8, 8), layers=3), PressConfig(n_grid=32))
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    for positions in ([[0.0, 0.0, 0.3]], [[0.0, 0.0, 0.3], [0.05, 0.0, 0.3]]):
        with pytest.raises(RuntimeError, match="caught"):
            sim.press_batch(mesh, positions, [[0.0, 0.0, -1.0]] * len(positions))
    assert built == [False, True]  # one touch: eager; two (>= the patched threshold): compiled


def test_touches_per_process() -> None:
    assert touches_per_process(10, 1, 3) == 30
    assert touches_per_process(10, 3, 3) == 12  # the busiest process has 4 items
    assert touches_per_process(2, 4, 5) == 5


def test_auto_on_cuda_compiles_past_the_measured_break_even(clean_policy, monkeypatch: pytest.MonkeyPatch) -> None:
    """On CUDA the compile (86.6 s on an H100) pays back after ~4,700 touches of the authors' pad (18.4 ms saved per
    touch): a whole preset in one process compiles, a generate worker's share and a single batch do not. No C++
    compiler is needed there (triton)."""
    monkeypatch.setattr(policy, "cpp_compiler", lambda: None)
    paper = policy.touch_work(61 * 61 * 10, 128)
    need = policy.AUTO_MIN_TOUCHES_CUDA
    assert 4_500 < need / paper < 5_000
    on, why = policy.resolve_compile("auto", 7_700, "cuda", work=paper)  # cls_paper in one process
    assert on is True and "auto on cuda" in why and f">= {need}" in why
    assert policy.resolve_compile("auto", 344, "cuda", work=paper)[0] is False  # one of 16 workers' share
    assert policy.resolve_compile("auto", 1_024, torch.device("cuda", 0), work=paper)[0] is False  # one batch
    policy.mark_compile_cache_warm()  # the warm cache's compile was not timed on a GPU: the same threshold
    assert policy.resolve_compile("auto", 1_024, "cuda", cache_root=clean_policy, work=paper)[0] is False
