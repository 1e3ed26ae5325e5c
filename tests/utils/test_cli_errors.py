"""Every command fails in one stderr line with exit 2 (bad input), 1 (failed run), 130 (Ctrl-C).

The shared mechanism (``tvrecon.utils.cli_errors``) and the argparse-style commands; train.py / eval.py are in
``tests/train/test_cli_faults.py``, the robot in ``tests/robot/pybullet_engine/test_pick_place_inputs.py``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tvrecon.utils.cli_errors import RESUME_HINT, call_cli, cli_errors, exit_code, one_line, remove_refused_run_dir

ROOT = Path(__file__).resolve().parents[2]


def _one_error_line(err: str, prog: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith(f"{prog}: error: "), lines[0]
    return lines[0]


def test_one_line_joins_hydras_option_list() -> None:
    text = "In 'train': Could not find 'experiment/bogus'\n\nAvailable options in 'experiment':\n\tclassify\n\tfull\n"
    assert one_line(text) == (
        "In 'train': Could not find 'experiment/bogus'; Available options in 'experiment': classify, full"
    )
    assert one_line("a\nb") == "a; b" and one_line("") == ""


def test_exit_codes() -> None:
    from omegaconf.errors import ConfigKeyError

    assert exit_code(ValueError()) == exit_code(TypeError()) == exit_code(FileNotFoundError()) == 2
    assert exit_code(ConfigKeyError("x")) == 2
    assert exit_code(RuntimeError()) == exit_code(OSError(28, "No space left on device")) == 1
    assert exit_code(KeyboardInterrupt()) == 130


def _raise(exc: BaseException):
    def main(argv: list[str]) -> int:
        raise exc

    return main


@pytest.mark.parametrize(
    ("exc", "code", "text"),
    [
        (ValueError("--n-grid must be >= 16, got 8"), 2, "prog: error: --n-grid must be >= 16, got 8"),
        (TypeError("E must be a number, got '3'"), 2, "prog: error: E must be a number, got '3'"),
        (RuntimeError("the solver blew up"), 1, "prog: error: RuntimeError: the solver blew up (rerun with --debug"),
    ],
)
def test_call_cli_turns_an_error_into_one_line_and_a_code(exc, code, text, capsys) -> None:
    assert call_cli(_raise(exc), [], prog="prog") == code
    assert _one_error_line(capsys.readouterr().err, "prog").startswith(text)


def test_ctrl_c_exits_130_with_the_resume_hint_where_resume_exists(capsys) -> None:
    assert call_cli(_raise(KeyboardInterrupt()), [], prog="prog", resume=True) == 130
    assert capsys.readouterr().err.strip() == f"prog: {RESUME_HINT}"
    assert call_cli(_raise(KeyboardInterrupt()), [], prog="prog") == 130
    assert capsys.readouterr().err.strip() == "prog: interrupted"


def test_debug_flag_or_hydra_full_error_keeps_the_traceback(monkeypatch) -> None:
    seen = []

    def main(argv: list[str]) -> int:
        seen.append(argv)
        raise ValueError("bad")

    with pytest.raises(ValueError, match="bad"):
        call_cli(main, ["x", "--debug"], prog="prog")
    assert seen == [["x"]]  # --debug is not passed on to main's parser
    monkeypatch.setenv("HYDRA_FULL_ERROR", "1")
    with pytest.raises(ValueError, match="bad"):
        call_cli(main, [], prog="prog")
    with pytest.raises(ValueError), cli_errors("prog"):
        raise ValueError("bad")


def test_systemexit_and_return_codes_pass_through() -> None:
    assert call_cli(lambda argv: 3, [], prog="prog") == 3
    assert call_cli(lambda argv: None, [], prog="prog") == 0
    with pytest.raises(SystemExit) as exc:
        call_cli(_raise(SystemExit(2)), [], prog="prog")  # argparse's own exit
    assert exc.value.code == 2


@pytest.mark.slow  # two fresh interpreters importing torch: ~10-30 s on shared cores
def test_generate_command_bad_preset_is_one_line_exit_2_and_debug_shows_the_traceback() -> None:
    """A real process: the exit status and stderr a shell sees (before: a 30-line traceback above the message)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    env.pop("HYDRA_FULL_ERROR", None)
    cmd = [sys.executable, "-m", "tvrecon.data.generate", "preset=nope"]
    res = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    line = _one_error_line(res.stderr, "python -m tvrecon.data.generate")
    assert "unknown data preset 'nope'" in line and "'tiny'" in line
    res = subprocess.run([*cmd, "--debug"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 1 and "Traceback" in res.stderr and "unknown data preset 'nope'" in res.stderr


def test_generate_bad_counts_are_one_line(capsys) -> None:
    from tvrecon.data.generate import main

    prog = "python -m tvrecon.data.generate"
    for argv, text in [
        (["workers=0"], "workers must be a whole number >= 1 (leave it out for one per core), got 0"),
        (["workers=2.5"], "workers must be a whole number of processes, got '2.5'"),
        (["--shard", "3/2"], "0 <= i < n"),
        (["tiny"], "unexpected argument 'tiny'"),
    ]:
        assert call_cli(main, [*argv, "preset=tiny", "cache_dir=/nonexistent/never"], prog=prog) == 2, argv
        assert text in _one_error_line(capsys.readouterr().err, prog)


def test_press_cli_bad_threads_is_one_line(tmp_path: Path, capsys) -> None:
    from tvrecon.sim.__main__ import main

    assert main(["press", "--shape", "sphere", "--threads", "-2", "--out", str(tmp_path / "o")]) == 2
    line = _one_error_line(capsys.readouterr().err, "python -m tvrecon.sim")
    assert "--threads must be >= 0" in line and "got -2" in line


def test_preview_and_tables_are_one_line(tmp_path: Path, capsys) -> None:
    from tvrecon.data.preview import main as preview
    from tvrecon.report.tables import main as tables

    assert call_cli(preview, ["--out", str(tmp_path / "p.png"), "--shape", "nope"], prog="preview") == 2
    line = _one_error_line(capsys.readouterr().err, "preview")
    assert "is neither an object class nor an existing mesh file" in line
    (tmp_path / "run").mkdir()
    result = {"task": "reconstruction", "name": "visual_only", "modality": "visual"}
    result["modes"] = {"visual": {"chamfer": 13.5, "count": 4, "per_class": {}}}
    (tmp_path / "run" / "metrics.json").write_text(json.dumps(result))
    (tmp_path / "file").write_text("")
    assert call_cli(tables, [str(tmp_path / "run"), "--out", str(tmp_path / "file" / "t")], prog="tables") == 2
    assert str(tmp_path / "file") in _one_error_line(capsys.readouterr().err, "tables")


def test_generate_unwritable_cache_is_one_line(tmp_path: Path, capsys) -> None:
    from tvrecon.data.generate import main

    (tmp_path / "file").write_text("")
    prog = "python -m tvrecon.data.generate"
    argv = ["preset=tiny", "splits=val", "workers=1", f"cache_dir={tmp_path / 'file' / 'cache'}"]
    assert call_cli(main, argv, prog=prog) == 2
    assert "is read-only (Not a directory)" in _one_error_line(capsys.readouterr().err, prog)


def test_shapes_bad_options_are_one_line(tmp_path: Path, capsys) -> None:
    from tvrecon.data.shapes.__main__ import main as shapes

    prog = "python -m tvrecon.data.shapes"
    assert call_cli(shapes, ["--out", str(tmp_path), "--user-root", str(tmp_path / "missing")], prog=prog) == 2
    assert "is not a directory" in _one_error_line(capsys.readouterr().err, prog)
    assert call_cli(shapes, ["--out", str(tmp_path), "--deform", "3"], prog=prog) == 2
    assert "deform must be a strength in [0, 0.5]" in _one_error_line(capsys.readouterr().err, prog)



def test_shapes_without_out_writes_under_outputs(tmp_path: Path, monkeypatch, capsys) -> None:
    from tvrecon.data.shapes.__main__ import main as shapes

    monkeypatch.chdir(tmp_path)
    path = shapes(["--instances", "1", "--size", "16"])
    assert path.parent.parent == Path("outputs") / "shapes" and (tmp_path / path).stat().st_size > 1000
    assert f"outputs in {(tmp_path / path).parent}" in capsys.readouterr().out


def test_remove_refused_run_dir_takes_only_what_hydra_wrote(tmp_path: Path) -> None:
    def hydra_run(name: str) -> Path:
        run = tmp_path / name
        (run / ".hydra").mkdir(parents=True)
        for f in ("config.yaml", "hydra.yaml", "overrides.yaml"):
            (run / ".hydra" / f).write_text("x: 1\n")
        (run / "train.log").touch()
        return run

    assert remove_refused_run_dir(hydra_run("refused")) and not (tmp_path / "refused").exists()
    assert not remove_refused_run_dir(tmp_path / "absent")
    logged = hydra_run("logged")
    (logged / "train.log").write_text("an earlier run's line\n")
    ckpt = hydra_run("ckpt")
    (ckpt / "checkpoints").mkdir()
    extra = hydra_run("extra")
    (extra / ".hydra" / "notes.txt").write_text("mine")
    for kept in (logged, ckpt, extra):
        assert not remove_refused_run_dir(kept) and (kept / ".hydra" / "config.yaml").is_file()
