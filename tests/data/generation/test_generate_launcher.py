"""The shards of generate as the jobs of Hydra's launchers (``--multirun``, joblib locally).

The jobs together write exactly the cache entries of one process, skip what is cached, and bad spellings of a
multirun end in a ValueError that says what to write instead.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import OmegaConf
from tiny_press import TINY_PRESS

from tvrecon.data.generate import main
from tvrecon.data.generation.launcher import APP_CONFIG_DIR, hydra_arguments

ARGS = [  # 3 train items of 2 touches on a coarse grid (tests/data/generation/test_generate.py's preset)
    "preset=cls_tiny",
    "train.num_objects=3",
    "touches_per_object=2",
    *TINY_PRESS,
    "splits=train",
    "workers=1",
]
SUMMARY = re.compile(r"\[train shard (\d)/2\] (\d+) items in shard, (\d+) cached, (\d+) generated")


def _entries(cache: Path) -> list[str]:
    return sorted(p.relative_to(cache).as_posix() for p in cache.rglob("*") if p.is_file())


@pytest.mark.slow
def test_joblib_shards_write_what_one_process_writes_and_skip_the_cached(tmp_path: Path) -> None:
    pytest.importorskip("hydra_plugins.hydra_joblib_launcher", reason="needs hydra-joblib-launcher (the dev extra)")
    single, multi = tmp_path / "single", tmp_path / "multi"
    main([*ARGS, f"cache_dir={single}"])  # the reference: one process, every item
    expected = _entries(single)
    assert len(expected) == 3 and all(e.endswith(".npz") for e in expected)
    (multi / expected[0]).parent.mkdir(parents=True)
    shutil.copy(single / expected[0], multi / expected[0])  # one item cached already: its job skips it

    env = {k: v for k, v in os.environ.items() if k not in ("RANK", "LOCAL_RANK", "WORLD_SIZE")}
    cmd = [sys.executable, "-m", "tvrecon.data.generate", "--multirun", *ARGS, f"cache_dir={multi}", "shard=0/2,1/2"]
    cmd += ["hydra/launcher=joblib", "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={tmp_path / 'sweep'}"]
    proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-4000:]

    assert _entries(multi) == expected  # the same keys, nothing else (no temporary files)
    jobs = {int(m[0]): tuple(int(x) for x in m[1:]) for m in SUMMARY.findall(proc.stdout)}
    assert sorted(jobs) == [0, 1], proc.stdout  # a summary line per job
    assert (jobs[0][0], jobs[1][0]) == (2, 1)  # items 0, 2 and item 1
    assert sum(j[1] for j in jobs.values()) == 1 and sum(j[2] for j in jobs.values()) == 2
    assert {p.name for p in (tmp_path / "sweep").iterdir() if p.is_dir()} == {"0", "1"}  # Hydra's job folders


def test_multirun_arguments_reach_the_jobs_unchanged() -> None:
    data = ["sensor.resolution=[8,8]", "cache_dir=/tmp/a b", "x='y'", "+new.key=1", "back=\\x\\", "e=${oc.env:HOME}"]
    args = hydra_arguments(["-m", "preset=tiny", "--shard", "0/2,1/2", *data, "hydra/launcher=basic"])
    assert args[:4] == ["--multirun", "preset=tiny", "shard=0/2,1/2", "hydra/launcher=basic"]
    assert OverridesParser.create().parse_overrides([args[-1]])[0].value() == data
    sweep_dir = OmegaConf.load(APP_CONFIG_DIR / "generate.yaml").hydra.sweep
    assert "/logs/generate/multirun/" in OmegaConf.to_container(sweep_dir)["dir"]  # not the working directory


def test_a_job_gets_compile_as_its_press_config() -> None:
    """A multirun's `compile=true` reaches each job's command line, which makes it the data-config override
    `press.compile=true` (the job's worker processes get it with their datasets, not from the environment)."""
    from tvrecon.data.generate import _compile_override
    from tvrecon.data.generation.launcher import job_arguments

    app = OmegaConf.load(APP_CONFIG_DIR / "generate.yaml")
    for value, expected in ((True, ["press.compile=true"]), (False, ["press.compile=false"]), (None, [])):
        job = OmegaConf.create({k: app[k] for k in ("preset", "splits", "workers", "shard", "data_overrides")})
        job.compile, job.data_overrides = value, ["press.n_grid=32"]
        argv = job_arguments(job)
        opts = dict(a.split("=", 1) for a in argv if a.split("=", 1)[0] in ("preset", "shard", "compile"))
        assert _compile_override(opts, argv) == expected, argv


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["shard=0-4"], "list one i/n per job: shard=0/4,1/4"),
        (["shard=range(4)"], "list one i/n per job"),
        (["shard=0/4,1/4,1/4"], "listed twice"),
        (["shard=0/4,1/2"], "must share their n"),
        (["preset=tiny,nope"], "unknown data preset 'nope'"),
        (["train.num_samples=2,4"], "only preset, splits, workers, shard, compile, export can be swept"),
        (["tiny"], "key=value"),
    ],
)
def test_bad_multirun_arguments_say_what_to_write(argv: list[str], message: str) -> None:
    with pytest.raises(ValueError, match=re.escape(message)):
        main(["--multirun", *argv])


def test_launcher_settings_without_multirun_are_refused() -> None:
    with pytest.raises(ValueError, match="with --multirun only"):
        main(["preset=tiny", "hydra/launcher=joblib"])


@pytest.mark.skipif(
    importlib.util.find_spec("hydra_plugins.hydra_submitit_launcher") is not None, reason="submitit plugin installed"
)
def test_a_missing_launcher_plugin_names_the_extra_to_install() -> None:
    with pytest.raises(ValueError, match=re.escape("pip install -e '.[cluster]'")):
        main(["-m", "hydra/launcher=submitit_slurm", "hydra.launcher.partition=cpu"])
