"""Worker processes that die with their parent: no orphan keeps the CPU after ``kill -9`` of the process that
started it.

A pool's own shutdown stops its workers on Ctrl-C, SIGTERM or an error, but a parent killed by SIGKILL (``kill -9``,
the OOM killer) runs no code: its spawned workers are reparented and go on generating until their queue is dry.
:func:`die_with_parent`, called first in a worker's initialiser, asks the kernel for a signal when the parent dies
(``prctl(PR_SET_PDEATHSIG)`` on Linux) and exits the worker on it; elsewhere a daemon thread watches the parent's pid.

The kernel sends that signal when the *thread* that started the worker ends, which need not be the whole parent (a
pool started from a thread that returns): the handler exits only when the worker was reparented, i.e. the parent
process is gone, so SIGUSR1 is asked for rather than SIGTERM (whose default action would end a worker whose parent
lives on). :func:`spawnable_start_method` lets a pool spawn its workers from inside a joblib launcher's job. The
module imports nothing of tvrecon (bottom layer).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["PR_SET_PDEATHSIG", "die_with_parent", "spawnable_start_method"]

#: the prctl option of <linux/prctl.h>: the signal the calling process gets when its parent dies
PR_SET_PDEATHSIG = 1
#: how often the watchdog thread (no prctl) looks at the parent, seconds
WATCH_INTERVAL_S = 1.0


def _prctl_parent_death_signal(signum: int) -> bool:
    """``prctl(PR_SET_PDEATHSIG, signum)``; False where there is no prctl (not Linux) or the call failed."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, int(signum), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _exit_if_orphan(parent_pid: int) -> None:
    if os.getppid() != parent_pid:  # reparented: the parent is gone
        os._exit(128 + signal.SIGTERM)


def _watch_parent(parent_pid: int, interval_s: float) -> None:
    while True:
        if os.getppid() != parent_pid:  # reparented: the parent is gone
            os._exit(128 + signal.SIGTERM)
        time.sleep(interval_s)


def die_with_parent(parent_pid: int, interval_s: float = WATCH_INTERVAL_S) -> str:
    """Make the calling process (a pool worker) end when the process ``parent_pid`` that started it dies.

    Args:
        parent_pid: the pid of the parent, as the parent saw it (``os.getpid()`` there, passed in the initialiser's
            arguments): a parent that died before this call is noticed too.
        interval_s: how often the watchdog thread looks (where there is no prctl).
    Returns:
        ``"prctl"`` (the kernel signals the worker) or ``"watchdog"`` (a daemon thread exits it).
    """
    how = "watchdog"
    in_main = threading.current_thread() is threading.main_thread()  # Python signal handlers live in the main thread
    if in_main and hasattr(signal, "SIGUSR1"):
        signal.signal(signal.SIGUSR1, lambda signum, frame: _exit_if_orphan(parent_pid))
        if _prctl_parent_death_signal(signal.SIGUSR1):
            how = "prctl"
        else:
            signal.signal(signal.SIGUSR1, signal.SIG_DFL)
    _exit_if_orphan(parent_pid)  # the parent died before the request took effect
    if how == "watchdog":
        threading.Thread(target=_watch_parent, args=(parent_pid, interval_s), daemon=True, name="parent-watch").start()
    return how


@contextmanager
def spawnable_start_method() -> Iterator[None]:
    """While the block spawns processes, a default start method the spawned children can set up.

    A spawned child first sets the parent's *default* start method (``multiprocessing.get_start_method()``), even
    when the pool uses its own context. Inside a joblib (loky) launcher job that method is ``'loky'``, which a fresh
    child does not know: every worker of a pool started there died with "cannot find context for 'loky'". Such a
    method is replaced by ``'spawn'`` for the block and restored after it.
    """
    method = mp.get_start_method(allow_none=True)
    if method is None or method in mp.get_all_start_methods():
        yield
        return
    mp.set_start_method("spawn", force=True)
    try:
        yield
    finally:
        mp.set_start_method(method, force=True)
