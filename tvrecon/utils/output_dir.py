"""Where a command line writes: ``--out`` when given, else ``outputs/<tool>/<time>/`` under the current folder.

Every CLI of the project follows this one convention and prints the folder at the end (:func:`announce`), so that a
run never scatters files into the current folder (the repository, often) and a second run never mixes its files
with the first's. This module imports nothing of tvrecon (bottom layer).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

__all__ = ["OUTPUTS", "announce", "check_writable_dir", "default_output_dir", "output_dir"]

#: the folder, under the current one, that holds every tool's runs without --out (ignored by git)
OUTPUTS = Path("outputs")


def default_output_dir(tool: str, now: float | None = None) -> Path:
    """``outputs/<tool>/<YYYY-mm-dd_HH-MM-SS>``, a new name for each second; ``_2``, ``_3``, ... when that exists."""
    stamp = time.strftime("%Y-%m-%d_%H-%M-%S", time.localtime(time.time() if now is None else now))
    out = OUTPUTS / tool / stamp
    k = 2
    while out.exists():
        out = OUTPUTS / tool / f"{stamp}_{k}"
        k += 1
    return out


def output_dir(out: str | Path | None, tool: str) -> Path:
    """``out`` (``--out``) when given, else :func:`default_output_dir` of ``tool``; not created here."""
    return Path(out).expanduser() if out not in (None, "") else default_output_dir(tool)


def announce(out: str | Path) -> str:
    """Print (and return) the line that ends every CLI run: where its files are."""
    line = f"outputs in {Path(out).resolve()}"
    print(line, flush=True)
    return line


def check_writable_dir(path: str | Path, what: str) -> Path:
    """Create folder ``path`` and check that a file can be written in it, before any work is done for it.

    Raises:
        ValueError: naming ``what`` (e.g. ``export=``) and the path: it is a file, lies under a file, or cannot be
            written (permissions, a read-only file system, a full quota).
    """
    folder = Path(path).expanduser()
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{what}{folder} is a file: give a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):  # the real test: permissions, read-only file systems, quotas
            pass
    except (FileExistsError, NotADirectoryError) as err:
        raise ValueError(f"{what}{folder} cannot be a folder: a part of its path is a file ({err})") from err
    except OSError as err:
        raise ValueError(
            f"{what}{folder} is not writable ({err.strerror or err}): choose a folder you can write to"
        ) from err
    return folder
