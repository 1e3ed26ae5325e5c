"""A generate worker killed by ``kill -9`` (as the OOM killer would) stops the run at once.

``multiprocessing.Pool`` waited forever for the dead worker's result; the pool now reports it and the command exits
1 with one line naming the signal and how to resume.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tvrecon.utils.cli_errors import RESUME_HINT

ROOT = Path(__file__).resolve().parents[3]
ARGS = [
    "preset=cls_tiny",
    "train.num_objects=4",
    "touches_per_object=2",
    "sensor.resolution=[8,8]",
    "sensor.layers=3",
    "press.n_grid=32",
    "press.max_depth=1.5",
    "touch.depth_fractions=[0.1]",
]


def _workers(pid: int) -> list[int]:
    """The pool's worker processes among the children of ``pid`` (not multiprocessing's resource tracker)."""
    found = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        for child in (task / "children").read_text().split():
            try:
                cmd = Path(f"/proc/{child}/cmdline").read_bytes().replace(b"\0", b" ")
            except OSError:
                continue
            if b"spawn_main" in cmd and b"resource_tracker" not in cmd:
                found.append(int(child))
    return found


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc to find the worker processes")
def test_a_worker_killed_by_sigkill_stops_the_pool_naming_the_signal(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "tvrecon.data.generate", *ARGS, f"cache_dir={tmp_path}", "workers=2", "splits=train"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        workers: list[int] = []
        while len(workers) < 2 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
            workers = _workers(proc.pid)
        assert len(workers) == 2, f"no pool workers seen (exit {proc.poll()})"
        os.kill(workers[0], signal.SIGKILL)
        killed_at = time.monotonic()
        _, err = proc.communicate(timeout=60)  # before: the run hung here until killed from outside
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert time.monotonic() - killed_at < 30
    assert proc.returncode == 1
    lines = [ln for ln in err.splitlines() if "error:" in ln]
    assert len(lines) == 1, err
    assert lines[0].startswith("python -m tvrecon.data.generate: error: WorkerDied: a generate worker process")
    assert f"(pid {workers[0]})" in lines[0] and "killed by SIGKILL" in lines[0] and RESUME_HINT in lines[0]
    assert all(not Path(f"/proc/{w}").exists() or _zombie(w) for w in workers)  # no worker outlives the run


def _terminal_sigint() -> None:
    """In the child before exec: SIGINT at its default and unblocked, as a foreground command of a terminal has it (in
    the whole suite the pytest process was seen to hand its children SIGINT ignored, and the Ctrl-C never arrived)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(") ")[1].startswith("Z")
    except OSError:
        return True


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc to find the worker processes")
def test_ctrl_c_with_workers_exits_130_with_the_resume_hint_in_one_line(tmp_path: Path) -> None:
    """Ctrl-C reaches the whole process group (as from a terminal): one line, exit 130, no worker tracebacks."""
    cmd = [sys.executable, "-m", "tvrecon.data.generate", *ARGS, f"cache_dir={tmp_path}", "workers=2", "splits=train"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        cmd,
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=_terminal_sigint,  # as a terminal starts it, whatever an earlier test left in this process
    )
    try:
        deadline = time.monotonic() + 120
        workers: list[int] = []
        while len(workers) < 2 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
            workers = _workers(proc.pid)
        assert len(workers) == 2, f"no pool workers seen (exit {proc.poll()})"
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == f"python -m tvrecon.data.generate: {RESUME_HINT}"
    assert "Traceback" not in err and "KeyboardInterrupt" not in err


class _Exited:
    """A finished worker process as :func:`tvrecon.data.generation.pool._dead_worker_message` reads it."""

    def __init__(self, pid: int, exitcode: int) -> None:
        self.pid, self.exitcode = pid, exitcode

    def join(self, timeout: float | None = None) -> None:
        pass


def test_the_message_names_the_killed_worker_before_one_that_failed_as_the_pool_broke() -> None:
    from tvrecon.data.generation.pool import _dead_worker_message

    # listed first: a survivor that exited with an error as the pool's queues closed under it, then the one SIGTERMed
    procs = [_Exited(11, 1), _Exited(12, -signal.SIGTERM), _Exited(13, -signal.SIGKILL)]
    msg = _dead_worker_message(procs, "train")  # type: ignore[arg-type]
    assert "(pid 13) of split 'train' was killed by SIGKILL" in msg and RESUME_HINT in msg
    assert "(pid 11) of split 'train' exited with status 1" in _dead_worker_message(procs[:2], "train")  # type: ignore[arg-type]
    assert "(pid 12) of split 'train' was killed by SIGTERM" in _dead_worker_message(procs[1:2], "train")  # type: ignore[arg-type]
    # a survivor that died of another signal as the pool broke (seen on a clean-clone run): SIGKILL,
    # which only comes from outside, is the one named
    procs = [_Exited(21, -signal.SIGSEGV), _Exited(22, -signal.SIGKILL)]
    assert "(pid 22) of split 'train' was killed by SIGKILL" in _dead_worker_message(procs, "train")  # type: ignore[arg-type]
    assert "(pid 21) of split 'train' was killed by SIGSEGV" in _dead_worker_message(procs[:1], "train")  # type: ignore[arg-type]
