"""Cache leftovers and exports: a killed writer's temporary file goes at the next job's start, an export compares
contents (not sizes), and an unwritable export folder is refused before any simulation."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tvrecon.data.cache.export import export_entries
from tvrecon.data.cache.housekeeping import remove_stale_tmp
from tvrecon.data.cache.store import SampleCache, cache_key
from tvrecon.utils.atomic import tmp_prefix, tmp_writer_gone
from tvrecon.utils.cli_errors import call_cli


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_the_temporary_file_of_a_killed_writer_goes_at_once(tmp_path: Path) -> None:
    mine = tmp_path / "ab" / f"{tmp_prefix('abcdef012345')}x1.tmp"
    dead = tmp_path / "cd" / f"{tmp_prefix('cdef01234567').replace(f'~{os.getpid()}~', f'~{_dead_pid()}~')}x2.tmp"
    other_host = tmp_path / "ef" / ".ef0123456789.~another-host~1~x3.tmp"
    for path in (mine, dead, other_host):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"half an entry")
    assert not tmp_writer_gone(mine.name) and tmp_writer_gone(dead.name) and not tmp_writer_gone(other_host.name)
    assert remove_stale_tmp(tmp_path, started=time.time()) == 1  # all three are fresh: only the dead writer's goes
    assert mine.is_file() and not dead.exists() and other_host.is_file()


class _Cached:
    """A dataset of three cached items (what export_entries reads)."""

    def __init__(self, root: Path) -> None:
        self.cache = SampleCache(root)
        for i in range(3):
            path = self.cache.path(cache_key(self.spec(i)))
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(bytes([i]) * 100)

    def spec(self, i: int) -> dict:
        return {"item": i}

    def __len__(self) -> int:
        return 3


def test_export_replaces_a_corrupt_copy_of_the_same_size(tmp_path: Path) -> None:
    ds = _Cached(tmp_path / "src")
    first = export_entries(ds, tmp_path / "dst")
    assert (first.copied, first.present, first.replaced) == (3, 0, 0)
    corrupt = SampleCache(tmp_path / "dst").path(cache_key(ds.spec(1)))
    corrupt.write_bytes(b"\xff" * 100)  # same size, other bytes
    again = export_entries(ds, tmp_path / "dst")
    assert (again.copied, again.present, again.replaced) == (1, 2, 1)
    assert corrupt.read_bytes() == bytes([1]) * 100


def test_an_unwritable_export_folder_is_refused_before_simulating(tmp_path: Path, monkeypatch, capsys) -> None:
    import tempfile

    from tvrecon.data import generate

    def read_only(*args, **kwargs):
        raise PermissionError(30, "Read-only file system")

    def no_simulation(*args, **kwargs):
        raise AssertionError("the data was generated before export= was checked")

    monkeypatch.setattr(tempfile, "TemporaryFile", read_only)  # root ignores chmod: refuse like a read-only mount
    monkeypatch.setattr(generate, "pregenerate_splits", no_simulation)
    args = ["preset=tiny", f"cache_dir={tmp_path / 'c'}", f"export={tmp_path / 'ro'}"]
    assert call_cli(generate.main, args, prog="generate") == 2
    err = capsys.readouterr().err.strip()
    want = f"export={tmp_path / 'ro'} is not writable (Read-only file system): choose a folder you can write to"
    assert err == f"generate: error: {want}"


@pytest.mark.parametrize("bad", ["FILE"])
def test_an_export_path_that_is_a_file_is_refused(tmp_path: Path, bad: str, capsys) -> None:
    from tvrecon.data import generate

    (tmp_path / bad).write_text("x")
    assert call_cli(generate.main, ["preset=tiny", f"export={tmp_path / bad}"], prog="generate") == 2
    assert "is a file: give a folder" in capsys.readouterr().err
