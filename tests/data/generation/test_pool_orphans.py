"""``kill -9`` of ``python -m tvrecon.data.generate`` leaves no worker behind (they held the CPU until their queue was
dry); a rerun resumes from the cache."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest


def _children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(") ", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(") ", 1)[1][0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc is Linux's")
def test_generate_workers_die_with_a_killed_parent(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "tvrecon.data.generate", "preset=tiny", "workers=2", f"cache_dir={tmp_path / 'c'}"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    parent = subprocess.Popen(cmd, cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers: list[int] = []
    try:
        deadline = time.time() + 240
        while len(workers) < 2 and time.time() < deadline and parent.poll() is None:
            time.sleep(0.5)
            workers = [p for p in _children(parent.pid) if b"spawn_main" in Path(f"/proc/{p}/cmdline").read_bytes()]
        assert len(workers) == 2, "the pool did not start two workers"
        time.sleep(3)  # past the initialiser: the workers are generating
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=10)
        # the exit runs between bytecodes: a worker inside a long torch call ends when that call returns (seconds on
        # an idle machine, longer on a loaded one), well before its queue of touches would be dry
        deadline = time.time() + 60
        while any(_alive(w) for w in workers) and time.time() < deadline:
            time.sleep(0.2)
        assert not any(_alive(w) for w in workers), "a generate worker outlived its killed parent"
    finally:
        parent.kill()
        for w in workers:
            if _alive(w):
                os.kill(w, signal.SIGKILL)
