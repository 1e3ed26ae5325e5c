"""Atomic file writes shared by every layer: write a temporary file in the target folder, then ``os.replace``.

An interrupted run never leaves a half-written PNG, PLY, table or log behind: either the old file is still there or
the new one is complete. Temporary files get the mode ``open(path, "w")`` would give (mkstemp makes them 0600).
"""

from __future__ import annotations

import io
import os
import re
import socket
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

__all__ = [
    "atomic_open",
    "atomic_savefig",
    "atomic_write_bytes",
    "atomic_write_text",
    "default_file_mode",
    "tmp_prefix",
    "tmp_writer_gone",
]

#: ``~<host>~<pid>~`` in a temporary file's name: which process writes it (:func:`tmp_writer_gone`)
_WRITER = re.compile(r"~([A-Za-z0-9_.-]+)~(\d+)~")


def _host() -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", socket.gethostname()) or "host"


def tmp_prefix(name: str) -> str:
    """The prefix of a temporary file written for ``name``: ``.<name>.~<host>~<pid>~``, so that a cleanup can tell
    the file of a killed writer (:func:`tmp_writer_gone`) from one being written now."""
    return f".{name}.~{_host()}~{os.getpid()}~"


def tmp_writer_gone(name: str) -> bool:
    """True when the temporary file ``name`` (made with :func:`tmp_prefix`) was written by a process of this host that
    no longer runs (killed mid-write: the file is stale whatever its age). False when the writer may still run, runs
    on another host, or the name does not say (then only its age can tell)."""
    found = _WRITER.search(name)
    if found is None or found.group(1) != _host():
        return False
    pid = int(found.group(2))
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:  # e.g. EPERM: a process of another user runs with that pid
        return False
    return False


def default_file_mode() -> int:
    """``0o666`` minus the process umask: the mode a plain ``open(path, "w")`` would create."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


@contextmanager
def atomic_open(path: str | Path, mode: str = "wb", fsync: bool = False) -> Iterator[IO[Any]]:
    """Open a temporary file next to ``path``; on a clean exit it replaces ``path``, on an error it is removed.

    Args:
        path: destination file (its folder is created).
        mode: ``"wb"`` or ``"w"`` (text, UTF-8).
        fsync: flush the data to disk before the rename (for caches that must survive a power cut).
    """
    if mode not in ("wb", "w"):
        raise ValueError(f"atomic_open writes whole files: mode must be 'wb' or 'w', got {mode!r}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=tmp_prefix(path.name), suffix=".tmp")
    try:
        with os.fdopen(fd, mode, **({"encoding": "utf-8"} if mode == "w" else {})) as fh:
            yield fh
            if fsync:
                fh.flush()
                os.fsync(fh.fileno())
        os.chmod(tmp, default_file_mode())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_bytes(path: str | Path, data: bytes | str) -> Path:
    """Write ``data`` (bytes, or str encoded as UTF-8) to ``path`` atomically. Returns the path."""
    with atomic_open(path, "wb") as fh:
        fh.write(data if isinstance(data, bytes) else data.encode("utf-8"))
    return Path(path)


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (UTF-8). Returns the path."""
    return atomic_write_bytes(path, text)


def atomic_savefig(fig: Any, path: str | Path, **savefig_kwargs: Any) -> Path:
    """Save a matplotlib figure atomically; the format follows the suffix of ``path`` unless ``format=`` is given.

    Returns the path.
    """
    path = Path(path)
    savefig_kwargs.setdefault("format", path.suffix.lstrip(".") or "png")
    buf = io.BytesIO()
    fig.savefig(buf, **savefig_kwargs)
    return atomic_write_bytes(path, buf.getvalue())


def save_and_close(fig: Any, path: str | Path, dpi: int = 100) -> Path:
    """Save a pyplot figure atomically (tight bounding box) and close it (pyplot keeps every open figure alive)."""
    import matplotlib.pyplot as plt

    try:
        return atomic_savefig(fig, path, dpi=dpi, bbox_inches="tight")
    finally:
        plt.close(fig)
