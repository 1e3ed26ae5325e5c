"""``python -m benchmarks.run`` (``make bench``): one JSON keyed by machine, torch version and commit."""

from __future__ import annotations

import json

import pytest
import torch

from benchmarks import run


def test_key_names_machine_torch_and_commit():
    info = {"machine": "AMD EPYC 7R13 x2 + NVIDIA H100 80GB", "torch": "2.14.1+cu130", "commit": "487a852-dirty"}
    k = run.key(info)
    assert k == "AMD-EPYC-7R13-x2-NVIDIA-H100-80GB_torch-2.14.1-cu130_487a852-dirty"
    assert run.key({**info, "commit": None}).endswith("_nocommit")


def test_suite_names_speed_scripts():
    for name in run.SUITE:
        assert (run.ROOT / "benchmarks" / "speed" / f"{name}.py").is_file(), name
    assert run.JSON_OUT <= set(run.SUITE) and run.THREADED <= set(run.SUITE)


def test_unknown_script_and_bad_threads_exit_2(tmp_path, capsys):
    assert run.main(["--only", "bench_nothing", "--out", str(tmp_path)]) == 2
    assert "not in the suite" in capsys.readouterr().err
    assert run.main(["--threads", "0", "--out", str(tmp_path)]) == 2
    assert not list(tmp_path.iterdir())


def test_run_writes_one_json(tmp_path, monkeypatch):
    """A two-step solver run: one folder named by the key, its metrics (the key's fields, the script's output) and
    its manifest."""
    monkeypatch.setitem(run.SUITE, "bench_sim", ["--steps", "2", "--repeats", "1", "--skip-reference"])
    assert run.main(["--only", "bench_sim", "--out", str(tmp_path)]) == 0
    (folder,) = tmp_path.iterdir()
    assert sorted(p.name for p in folder.iterdir()) == ["manifest.json", "metrics.json"]
    data = json.loads((folder / "metrics.json").read_text())
    assert folder.name == run.key(data)
    manifest = json.loads((folder / "manifest.json").read_text())
    assert set(manifest) == {"command", "data_preset", "seed", "commit", "machine", "wall_s", "date"}
    assert manifest["command"] == f"python -m benchmarks.run --only bench_sim --out {tmp_path}"
    assert manifest["machine"] == data["machine"] and manifest["wall_s"] >= r_wall(data)
    assert data["torch"] == torch.__version__ and data["machine"] and data["threads"] == 1
    r = data["runs"]["bench_sim"]
    assert r["returncode"] == 0 and r["wall_s"] > 0
    assert r["command"].startswith("python -m benchmarks.speed.bench_sim --steps 2")
    assert any("particle-steps/s" in line for line in r["stdout"])


def r_wall(data: dict) -> float:
    return sum(r["wall_s"] for r in data["runs"].values()) - 1.0  # the suite's wall time holds every script's


def test_missing_script_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match="benchmarks/speed/bench_gone.py"):
        run.run_script("bench_gone", [], 1, tmp_path)
