"""A command that resumes says so when a run fails part-way (a killed launcher job), not only on Ctrl-C."""

from __future__ import annotations

from tvrecon.utils.cli_errors import FAILED_RESUME_HINT, call_cli


def _raise(err: BaseException):
    def main(argv: list[str]) -> int:
        raise err

    return main


def test_a_failed_run_of_a_resuming_command_says_the_same_command_resumes(capsys) -> None:
    assert call_cli(_raise(RuntimeError("a job died")), [], prog="prog", resume=True) == 1
    line = capsys.readouterr().err.strip()
    assert line.startswith("prog: error: RuntimeError: a job died (rerun with --debug")
    assert line.endswith(f"; {FAILED_RESUME_HINT}") and "\n" not in line


def test_bad_input_and_commands_that_do_not_resume_say_nothing_of_resuming(capsys) -> None:
    assert call_cli(_raise(ValueError("workers must be >= 1")), [], prog="prog", resume=True) == 2
    assert capsys.readouterr().err.strip() == "prog: error: workers must be >= 1"
    assert call_cli(_raise(RuntimeError("boom")), [], prog="prog") == 1
    assert "resume" not in capsys.readouterr().err


def test_a_message_that_already_says_how_to_resume_is_not_repeated(capsys) -> None:
    err = RuntimeError("a worker was killed; the same command goes on from the cached items")
    assert call_cli(_raise(err), [], prog="prog", resume=True) == 1
    assert FAILED_RESUME_HINT not in capsys.readouterr().err
