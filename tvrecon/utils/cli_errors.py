"""How every command line of the project fails: one line on stderr and an exit code a script can test.

Every entry point (``python -m tvrecon.sim``, ``tvrecon.data.generate``, ``tvrecon.data.preview``,
``tvrecon.report.tables``, ``train.py``, ``eval.py``, ``tvrecon.robot.pybullet.pick_place``) runs its ``main``
through this module:

- the project's own input checks (``ValueError``, ``TypeError``, a missing file, a Hydra/OmegaConf config error)
  end as ``<prog>: error: <message>`` on ONE line of stderr, exit status 2 (bad input);
- any other exception (a run that failed: a dead worker, a NaN loss, a full disk) ends the same way with the
  exception's type named and a pointer to ``--debug``, exit status 1; a command that resumes adds that the same
  command goes on from what was finished;
- Ctrl-C ends with ``<prog>: interrupted; rerun the same command to resume`` (or ``<prog>: interrupted`` where the
  command cannot resume), exit status 130 = 128 + SIGINT;
- ``--debug`` on the command line, or ``HYDRA_FULL_ERROR=1`` in the environment, keeps the full traceback.

The library functions keep raising their exceptions (tests and notebooks see them); only the ``__main__`` blocks
call :func:`run_cli` / :func:`run_hydra_cli`, and a Hydra task function is wrapped by :func:`hydra_task`.
This module imports nothing of tvrecon (bottom layer).
"""

from __future__ import annotations

import functools
import os
import shutil
import sys
import traceback
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, NoReturn

__all__ = [
    "argv_and_env",
    "EXIT_FAILED",
    "EXIT_INTERRUPTED",
    "EXIT_USAGE",
    "FAILED_RESUME_HINT",
    "RESUME_HINT",
    "call_cli",
    "cli_errors",
    "debug_requested",
    "exit_code",
    "hydra_task",
    "one_line",
    "remove_refused_run_dir",
    "run_cli",
    "run_hydra_cli",
]

EXIT_FAILED = 1  # the run started and failed
EXIT_USAGE = 2  # bad input (argparse's code too)
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as a shell reports a Ctrl-C
RESUME_HINT = "interrupted; rerun the same command to resume"
#: the end of a failed run's line (exit 1) in a command that resumes: what it finished is kept
FAILED_RESUME_HINT = "the work finished before the failure is kept: the same command resumes from it"
DEBUG_FLAG = "--debug"
DEBUG_HINT = f"rerun with {DEBUG_FLAG} (or HYDRA_FULL_ERROR=1) for the traceback"

#: exception types that mean "the input is wrong" (exit 2); OSErrors other than these are failed runs (exit 1)
USAGE_ERRORS: tuple[type[BaseException], ...] = (
    ValueError,
    TypeError,
    FileNotFoundError,
    FileExistsError,
    NotADirectoryError,
    IsADirectoryError,
    PermissionError,
)


def _env_true(name: str) -> bool:
    return os.environ.get(name, "").strip().lower() in ("1", "true", "yes")


def debug_requested(argv: Sequence[str] | None = None) -> bool:
    """True when the user asked for tracebacks: ``--debug`` in ``argv`` (default ``sys.argv``) or HYDRA_FULL_ERROR=1.

    ``TVRECON_DEBUG=1`` is the same request for runs that :func:`run_hydra_cli` started (it sets HYDRA_FULL_ERROR
    for its own use, so that variable no longer tells what the user asked for).
    """
    args = sys.argv[1:] if argv is None else argv
    if _env_true("TVRECON_DEBUG"):
        return True
    if _env_true("TVRECON_CLI_OWNS_HYDRA_ERRORS"):
        return DEBUG_FLAG in args
    return DEBUG_FLAG in args or _env_true("HYDRA_FULL_ERROR")


def _cause(err: BaseException) -> BaseException:
    """The error inside Hydra's ``InstantiationException`` ("Error in call to target ..."), else ``err``."""
    while type(err).__name__ == "InstantiationException" and err.__cause__ is not None:
        err = err.__cause__
    return err


def exit_code(err: BaseException) -> int:
    """2 for bad input (see ``USAGE_ERRORS``, Hydra/OmegaConf config errors), 130 for Ctrl-C, 1 otherwise."""
    err = _cause(err)
    if isinstance(err, KeyboardInterrupt):
        return EXIT_INTERRUPTED
    if isinstance(err, USAGE_ERRORS):
        return EXIT_USAGE
    if type(err).__module__.split(".")[0] in ("hydra", "omegaconf"):
        return EXIT_USAGE
    return EXIT_FAILED


def one_line(text: str) -> str:
    """A possibly multi-line message as one line.

    A line ending in ``:`` followed by a list (Hydra's "Available options in 'experiment':" then one option per
    line) becomes ``header: a, b, c``; other lines are joined with ``; ``.
    """
    lines = [ln.strip() for ln in str(text).splitlines() if ln.strip()]
    if not lines:
        return ""
    out = lines[0]
    in_list = out.endswith(":")
    for ln in lines[1:]:
        if out.endswith(":"):
            out += " " + ln
            in_list = True
        elif in_list and not ln.endswith(":"):
            out += ", " + ln
        else:
            out += "; " + ln
            in_list = ln.endswith(":")
    return out


def _message(err: BaseException) -> str:
    err = _cause(err)  # `data.train.num_samples=2.5` names the field, not Hydra's call of the datamodule
    text = one_line(str(err))
    text = text.split("; Config search path:")[0]  # Hydra's search path after its list of options: noise here
    if isinstance(err, KeyError) and text.startswith(("'", '"')) and text.endswith(("'", '"')):
        text = text[1:-1]  # str(KeyError('x')) quotes its argument
    if exit_code(err) == EXIT_USAGE and text:
        return text
    name = type(err).__name__
    return f"{name}: {text} ({DEBUG_HINT})" if text else f"{name} ({DEBUG_HINT})"


class _CliExit(SystemExit):
    """The ``SystemExit`` :func:`cli_errors` raises after printing its line (told apart from a body's own exit)."""


@contextmanager
def cli_errors(prog: str, resume: bool = False, debug: bool | None = None) -> Iterator[None]:
    """Turn an exception of the body into one stderr line and ``SystemExit`` with :func:`exit_code`.

    Args:
        prog: the command as the user typed it (``python -m tvrecon.sim``), the prefix of the line.
        resume: the command resumes when rerun (Ctrl-C and a failed run then say so).
        debug: re-raise with the traceback instead (default: :func:`debug_requested`).
    Raises:
        SystemExit: with 2 (bad input), 1 (failed run) or 130 (Ctrl-C); ``SystemExit`` of the body passes through.
    """
    if debug is None:
        debug = debug_requested()
    try:
        yield
    except SystemExit:
        raise
    except KeyboardInterrupt:
        if debug:
            traceback.print_exc()
        print(f"{prog}: {RESUME_HINT if resume else 'interrupted'}", file=sys.stderr, flush=True)
        raise _CliExit(EXIT_INTERRUPTED) from None
    except Exception as err:
        if debug:
            raise
        text = _message(err)
        if resume and exit_code(err) == EXIT_FAILED and "same command" not in text:
            text += f"; {FAILED_RESUME_HINT}"  # a run that failed part-way (a killed job, a full disk) goes on
        print(f"{prog}: error: {text}", file=sys.stderr, flush=True)
        raise _CliExit(exit_code(err)) from None


def _strip_debug(argv: Sequence[str]) -> list[str]:
    return [a for a in argv if a != DEBUG_FLAG]


def call_cli(
    main: Callable[[list[str]], Any], argv: Sequence[str] | None = None, *, prog: str, resume: bool = False
) -> int:
    """Run an argparse-style ``main(argv)`` and return its exit status instead of exiting.

    ``main``'s int return value (else 0), or the code of the one-line error (2, 1, 130). ``--debug`` is taken out of
    ``argv`` before ``main`` sees it. A ``SystemExit`` raised by ``main`` itself (argparse) passes through.
    """
    args = list(sys.argv[1:] if argv is None else argv)
    try:
        with cli_errors(prog, resume=resume, debug=debug_requested(args)):
            rc = main(_strip_debug(args))
    except _CliExit as done:
        return int(done.code)  # type: ignore[arg-type]
    return rc if isinstance(rc, int) else 0


def run_cli(
    main: Callable[[list[str]], Any], argv: Sequence[str] | None = None, *, prog: str, resume: bool = False
) -> NoReturn:
    """:func:`call_cli`, then exit with its status (the ``if __name__ == "__main__"`` block of a command)."""
    sys.exit(call_cli(main, argv, prog=prog, resume=resume))


def run_hydra_cli(main: Callable[[], Any], *, prog: str, resume: bool = False) -> None:
    """Run a ``@hydra.main`` function as a command: returns when it succeeds, else one line and ``SystemExit``.

    Hydra prints config errors (``experiment=bogus``) and task errors with part of a traceback; here it is told to
    re-raise them (``HYDRA_FULL_ERROR=1`` while ``main`` runs) so that they end as one line like every other command.
    ``--debug`` is taken out of ``sys.argv`` (Hydra's parser would refuse it) and keeps the traceback. The
    environment and ``sys.argv`` are restored afterwards (an in-process caller, e.g. a test, sees no change).
    """
    debug = debug_requested()
    env = {"HYDRA_FULL_ERROR": "1", "TVRECON_CLI_OWNS_HYDRA_ERRORS": "1"}
    if debug:
        env["TVRECON_DEBUG"] = "1"
    argv = [sys.argv[0], *_strip_debug(sys.argv[1:])]
    with argv_and_env(argv, env, keep=("TVRECON_DEBUG",)), cli_errors(prog, resume=resume, debug=debug):
        main()


@contextmanager
def argv_and_env(
    argv: Sequence[str], env: dict[str, str], defaults: dict[str, str] | None = None, keep: Sequence[str] = ()
) -> Iterator[None]:
    """``sys.argv`` set to ``argv`` and the variables of ``env`` set (those of ``defaults`` only where unset) while the
    block runs; all of them, and the names in ``keep``, are restored afterwards (an in-process caller, e.g. a test,
    sees no change)."""
    names = {*env, *(defaults or {}), *keep}
    saved_argv, saved_env = sys.argv, {k: os.environ.get(k) for k in names}
    sys.argv = list(argv)
    os.environ.update(env)
    for key, value in (defaults or {}).items():
        os.environ.setdefault(key, value)
    try:
        yield
    finally:
        sys.argv = saved_argv
        for key, value in saved_env.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


#: what Hydra writes into a run folder before the task starts (besides the job's log)
HYDRA_RUN_FILES = frozenset({"config.yaml", "hydra.yaml", "overrides.yaml"})


def remove_refused_run_dir(run_dir: str | os.PathLike[str]) -> bool:
    """Delete the run folder Hydra made for a run that its input checks refused; True if it was deleted.

    Only a folder that holds nothing but Hydra's ``.hydra/`` files (:data:`HYDRA_RUN_FILES`) and empty ``*.log``
    files goes: that is all Hydra writes before the task runs, and a folder with anything else in it (a checkpoint,
    a metric, a log line of an earlier run resumed into the same folder) is kept as it is.
    """
    root = os.fspath(run_dir)
    if not os.path.isdir(root):
        return False
    for entry in os.scandir(root):
        if entry.name == ".hydra" and entry.is_dir(follow_symlinks=False):
            inner = list(os.scandir(entry.path))
            if any(e.name not in HYDRA_RUN_FILES or not e.is_file(follow_symlinks=False) for e in inner):
                return False
        elif not (entry.name.endswith(".log") and entry.is_file(follow_symlinks=False) and entry.stat().st_size == 0):
            return False
    shutil.rmtree(root)
    return True


def _hydra_output_dir() -> str | None:
    try:
        from hydra.core.hydra_config import HydraConfig

        return str(HydraConfig.get().runtime.output_dir) if HydraConfig.initialized() else None
    except Exception:  # no Hydra, or called outside a Hydra job
        return None


def hydra_task(prog: str, resume: bool = False) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Decorator for a Hydra task function (under ``@hydra.main``): its errors end as one line in a single run.

    Inside a run the exception becomes the one line and ``SystemExit`` (which Hydra passes through without its
    "Error executing job" banner); a run refused for bad input (exit 2) leaves no run folder behind when that folder
    holds only what Hydra wrote for it (:func:`remove_refused_run_dir`). In a multirun (``-m``) the exception is
    re-raised so that Hydra finishes the other jobs of the sweep first, as it does without this decorator.
    """

    def wrap(fn: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(fn)
        def task(*args: Any, **kwargs: Any) -> Any:
            if _in_multirun():
                return fn(*args, **kwargs)
            try:
                with cli_errors(prog, resume=resume):
                    return fn(*args, **kwargs)
            except _CliExit as done:
                run_dir = _hydra_output_dir()
                if done.code == EXIT_USAGE and run_dir is not None:
                    remove_refused_run_dir(run_dir)
                raise

        return task

    return wrap


def _in_multirun() -> bool:
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        return HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN
    except Exception:  # no Hydra, or called outside a Hydra job
        return False
