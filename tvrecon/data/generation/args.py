"""The arguments of ``python -m tvrecon.data.generate`` that are the command's own (shared by the single-process
command and its ``--multirun`` launcher, :mod:`tvrecon.data.generation.launcher`)."""

from __future__ import annotations

__all__ = ["OPTION_KEYS", "parse_shard", "parse_splits"]

#: the ``key=value`` arguments of the command itself; every other one is an override of the data config
OPTION_KEYS = ("preset", "splits", "workers", "shard", "compile", "export")


def parse_shard(text: str) -> tuple[int, int]:
    """``"i/n"`` -> (i, n) with 0 <= i < n; ValueError otherwise."""
    try:
        i, n = (int(s) for s in str(text).split("/"))
    except ValueError:
        raise ValueError(f"shard must look like i/n (e.g. 0/4), got {text!r}") from None
    if not (n >= 1 and 0 <= i < n):
        raise ValueError(f"shard i/n needs n >= 1 and 0 <= i < n, got {text!r}")
    return i, n


def parse_splits(text: str, available: list[str]) -> list[str]:
    """``"train,test"`` or ``"[train,test]"`` (Hydra's list syntax, as ``configs/generate.yaml`` writes a list that is
    not a sweep) -> ``["train", "test"]``, in the order given, each one of ``available``; ValueError naming the
    configured splits otherwise."""
    names = [s.strip().strip("'\"") for s in str(text).strip().removeprefix("[").removesuffix("]").split(",")]
    names = [s for s in names if s]
    unknown = [s for s in names if s not in available]
    if not names or unknown:
        raise ValueError(
            f"splits={text!r}: {'no split named' if not names else 'unknown split ' + ', '.join(map(repr, unknown))}; "
            f"this preset has {', '.join(available)} (give them comma-separated, e.g. splits={','.join(available[:2])})"
        )
    return names
