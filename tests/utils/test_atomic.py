"""The shared atomic writer: a failed write keeps the old file and leaves no temporary file behind."""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pytest  # noqa: E402

from tvrecon.utils.atomic import atomic_open, atomic_savefig, atomic_write_bytes, atomic_write_text  # noqa: E402


def test_write_replaces_and_keeps_usual_mode(tmp_path: Path) -> None:
    path = atomic_write_text(tmp_path / "sub" / "a.txt", "one")
    atomic_write_bytes(path, b"two")
    assert path.read_text() == "two"
    mask = os.umask(0)
    os.umask(mask)
    assert (path.stat().st_mode & 0o777) == (0o666 & ~mask)
    assert sorted(p.name for p in path.parent.iterdir()) == ["a.txt"]


def test_interrupted_write_keeps_old_file_and_no_temp(tmp_path: Path) -> None:
    path = atomic_write_text(tmp_path / "a.txt", "old")
    with pytest.raises(RuntimeError):
        with atomic_open(path, "w") as fh:
            fh.write("half")
            raise RuntimeError("interrupted")
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]


def test_savefig_writes_png(tmp_path: Path) -> None:
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    path = atomic_savefig(fig, tmp_path / "f.png", dpi=50)
    plt.close(fig)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_mode_is_rejected(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="mode must be 'wb' or 'w'"):
        with atomic_open(tmp_path / "a.txt", "a"):
            pass
