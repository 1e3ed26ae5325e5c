"""``PressConfig.compile``: the fused solver kernels as a plain press config field (issues 25 and 27).

Cheap: the solver a press builds is caught right after its construction (``MLSMPM.compiled`` says whether it would run
the fused kernels; ``torch.compile`` itself runs lazily at the first step, so nothing is compiled here).
"""

from __future__ import annotations

import dataclasses
import warnings
from types import SimpleNamespace

import pytest
import torch
import trimesh

from tvrecon.data.cache.store import cache_key
from tvrecon.sim.mpm import MLSMPM, MPMConfig
from tvrecon.sim.mpm.compiled import backend
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.press import loop as press_loop
from tvrecon.sim.sensor.elastic_pad import SensorConfig

SENSOR = SensorConfig(resolution=(8, 8), layers=3)
PRESS = PressConfig(n_grid=32)
MESH = trimesh.creation.icosphere(subdivisions=2, radius=0.3)


class _Built(Exception):
    """Stops a press right after its solver was built."""


@pytest.fixture
def solver_compiled(monkeypatch: pytest.MonkeyPatch):
    """A function pressing with ``sim`` (and per-call overrides) that returns whether the press's solver is compiled."""
    # kernels that have not failed (another test's failed compile would make every solver eager); a stand-in, as
    # building the real ones imports torch._dynamo (~20 s on a loaded CPU) and the caught solver never calls them
    monkeypatch.setattr(backend, "_KERNELS", SimpleNamespace(failed=False))
    monkeypatch.delenv("TVRECON_COMPILE", raising=False)
    built: list[MLSMPM] = []

    class Caught(MLSMPM):
        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            built.append(self)
            raise _Built

    monkeypatch.setattr(press_loop, "MLSMPM", Caught)

    def run(sim: EIPSimulator, **overrides) -> bool:
        with pytest.raises(_Built):
            sim.press(MESH, [0.0, 0.0, 0.3], [0.0, 0.0, -1.0], **overrides)
        return built.pop().compiled

    return run


def test_compile_is_a_press_field_outside_the_cache_key() -> None:
    assert PressConfig().compile == "auto"  # the job decides (tests/sim/mpm/test_compile_policy.py)
    on = dataclasses.replace(PRESS, compile=True)
    assert cache_key({"press": on, "sensor": SENSOR}) == cache_key({"press": PRESS, "sensor": SENSOR})
    assert cache_key({"press": PressConfig()}) == cache_key({"press": PressConfig(compile=True)})
    assert cache_key({"press": PressConfig(compile=False)}) == cache_key({"press": PressConfig(compile=True)})
    assert cache_key({"press": PressConfig(gap=0.5)}) != cache_key({"press": PressConfig()})  # other fields count
    with pytest.raises(TypeError, match="PressConfig.compile must be true, false or 'auto'"):
        PressConfig(compile="yes")  # type: ignore[arg-type]


def test_press_config_compile_gives_a_compiled_solver(solver_compiled) -> None:
    assert solver_compiled(EIPSimulator(SENSOR, dataclasses.replace(PRESS, compile=True)))
    assert not solver_compiled(EIPSimulator(SENSOR, PRESS))  # the default, auto, with one touch: eager


def test_explicit_compile_and_call_overrides(solver_compiled) -> None:
    on = dataclasses.replace(PRESS, compile=True)
    assert not solver_compiled(EIPSimulator(SENSOR, on, compile=False))  # an explicit bool wins over the config
    assert solver_compiled(EIPSimulator(SENSOR, PRESS, compile=True))
    assert EIPSimulator(SENSOR, PRESS, compile=True).cfg.compile is True and PRESS.compile == "auto"  # caller's kept
    assert solver_compiled(EIPSimulator(SENSOR, PRESS), compile=True)  # a call's override, as any PressConfig field
    assert not solver_compiled(EIPSimulator(SENSOR, on), compile=False)
    with pytest.raises(TypeError, match="EIPSimulator compile must be true, false or 'auto'"):
        EIPSimulator(SENSOR, PRESS, compile="1")  # type: ignore[arg-type]


def test_the_old_environment_variable_is_ignored_with_a_warning(monkeypatch: pytest.MonkeyPatch, solver_compiled):
    monkeypatch.setenv("TVRECON_COMPILE", "1")
    with pytest.warns(FutureWarning, match=r"TVRECON_COMPILE='1' is no longer read: .*press\.compile=true"):
        sim = EIPSimulator(SENSOR, PRESS)
    assert sim.compile == "auto" and not solver_compiled(sim)
    assert not MLSMPM(MPMConfig(n_grid=32)).compiled  # the solver does not read it either
    monkeypatch.delenv("TVRECON_COMPILE")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # unset: no warning
        EIPSimulator(SENSOR, PRESS)


def test_a_compile_config_changes_nothing_but_the_kernels(monkeypatch: pytest.MonkeyPatch) -> None:
    """With the kernels marked failed (as after a failed compile) a ``compile=True`` press runs the eager step and
    reads bit for bit what the default press reads: the field selects the kernels and nothing else (the readings of
    the real compiled kernels: tests/sim/mpm/test_mpm_compile.py, slow)."""
    monkeypatch.delenv("TVRECON_COMPILE", raising=False)
    monkeypatch.setattr(backend, "_KERNELS", SimpleNamespace(failed=True))
    pos, d = [0.0, 0.0, 0.3], [0.0, 0.0, -1.0]
    ref = EIPSimulator(SENSOR, PRESS).press(MESH, pos, d, max_steps=4)
    new = EIPSimulator(SENSOR, PRESS, compile=True).press(MESH, pos, d, max_steps=4)
    assert torch.equal(ref.image, new.image) and ref.steps == new.steps
