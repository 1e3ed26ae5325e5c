"""A worker that called die_with_parent ends when its parent is killed with SIGKILL (no orphan keeps the CPU)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

PARENT = textwrap.dedent(
    """
    import multiprocessing as mp, os, sys, threading, time
    from tvrecon.utils.process_lifetime import die_with_parent

    def child(parent, out, mode):
        if mode == "watchdog":  # called off the main thread: no signal handler, the watchdog thread
            t = threading.Thread(target=lambda: print(die_with_parent(parent, 0.2), file=open(out + ".how", "w")))
        else:
            t = threading.Thread(target=lambda: None)
            print(die_with_parent(parent), file=open(out + ".how", "w"))
        t.start(); t.join()
        open(out, "w").write(str(os.getpid()))
        time.sleep(120)

    if __name__ == "__main__":
        out, mode = sys.argv[1], sys.argv[2]
        p = mp.get_context("spawn").Process(target=child, args=(os.getpid(), out, mode))
        p.start()
        time.sleep(120)
    """
)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = Path(f"/proc/{pid}/stat")
    return not (stat.is_file() and stat.read_text().rsplit(") ", 1)[1].startswith("Z"))  # a zombie is gone


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="prctl and /proc are Linux's")
@pytest.mark.parametrize("mode", ["prctl", "watchdog"])
def test_worker_dies_with_its_killed_parent(tmp_path: Path, mode: str) -> None:
    script, out = tmp_path / "parent.py", tmp_path / "child.pid"
    script.write_text(PARENT)
    parent = subprocess.Popen([sys.executable, str(script), str(out), mode])
    try:
        deadline = time.time() + 120
        while not out.is_file() or not out.read_text():
            assert time.time() < deadline and parent.poll() is None, "the child did not start"
            time.sleep(0.2)
        child = int(out.read_text())
        assert Path(str(out) + ".how").read_text().strip() == mode
        assert _alive(child)
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=10)
        deadline = time.time() + 10
        while _alive(child) and time.time() < deadline:
            time.sleep(0.1)
        assert not _alive(child), f"worker {child} outlived its parent ({mode})"
    finally:
        parent.kill()
        if out.is_file() and out.read_text() and _alive(int(out.read_text())):
            os.kill(int(out.read_text()), signal.SIGKILL)


def test_a_thread_that_ends_does_not_end_the_worker(tmp_path: Path) -> None:
    """PR_SET_PDEATHSIG fires when the parent *thread* ends: a parent whose starting thread returned lives on, and so
    does its worker."""
    script = tmp_path / "threaded.py"
    script.write_text(
        textwrap.dedent(
            """
            import multiprocessing as mp, os, threading, time
            from tvrecon.utils.process_lifetime import die_with_parent

            def child(parent):
                die_with_parent(parent)
                time.sleep(3)
                print("child survived", flush=True)

            if __name__ == "__main__":
                procs = []
                t = threading.Thread(target=lambda: procs.append(
                    mp.get_context("spawn").Process(target=child, args=(os.getpid(),))) or procs[0].start())
                t.start(); t.join()  # the thread that started the child ends here
                procs[0].join()
                print("exit", procs[0].exitcode)
            """
        )
    )
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert "child survived" in done.stdout and "exit 0" in done.stdout, done.stderr[-2000:]


LOKY_JOB = textwrap.dedent(
    """
    import multiprocessing as mp, sys
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool
    from joblib.externals.loky.backend import context  # registers 'loky' as a start method, as a loky worker has
    from tvrecon.utils.process_lifetime import spawnable_start_method

    if __name__ == "__main__":
        mp.set_start_method("loky", force=True)  # what a joblib launcher's job runs under
        with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn")) as pool:
            if sys.argv[1] == "guarded":
                with spawnable_start_method():
                    fut = pool.submit(abs, -3)
            else:
                fut = pool.submit(abs, -3)
            try:
                print(fut.result(timeout=60))
            except BrokenProcessPool:
                print("broken")
        print(mp.get_start_method())
    """
)


@pytest.mark.parametrize(("mode", "answer"), [("guarded", "3"), ("bare", "broken")])
def test_a_pool_spawns_inside_a_joblib_job(tmp_path: Path, mode: str, answer: str) -> None:
    script = tmp_path / "job.py"
    script.write_text(LOKY_JOB)
    done = subprocess.run([sys.executable, str(script), mode], capture_output=True, text=True, timeout=120)
    assert done.stdout.split() == [answer, "loky"], done.stderr[-2000:]  # the job's start method is restored
