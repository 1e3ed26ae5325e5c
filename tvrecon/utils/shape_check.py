"""One shape check for tensors and arrays: :func:`check_shape` raises the project's one-line message,
``"<name> must have shape (B, N, 3), got (2, 5)"``, when an input does not match its documented shape."""

from __future__ import annotations

from typing import Any

__all__ = ["check_shape"]


def _matches(shape: tuple[int, ...], spec: str) -> bool:
    dims = [d.strip() for d in spec.strip().strip("()").split(",") if d.strip()]
    if dims and dims[0] == "...":
        dims = dims[1:]
        ok = len(shape) >= len(dims)
        tail = shape[len(shape) - len(dims) :] if dims else ()
    else:
        ok = len(shape) == len(dims)
        tail = shape
    return ok and all(not d.isdigit() or int(d) == n for d, n in zip(dims, tail))


def check_shape(x: Any, spec: str, name: str) -> None:
    """Raise ``ValueError("{name} must have shape {spec}, got {shape}")`` unless ``x.shape`` matches ``spec``.

    ``spec`` is written as in the docstrings, e.g. ``"(B, N, 3)"``: a number must be that size, a name (``B``, ``h``)
    may be any size, and a leading ``...`` stands for any number of leading dimensions (``"(..., 3, H, W)"``).
    Documented alternatives are joined by ``or``: ``"(B, V, 3) or (V, 3)"`` accepts either.
    ``x``: a torch tensor or a numpy array.
    """
    shape = tuple(x.shape)
    if not any(_matches(shape, alt) for alt in spec.split(" or ")):
        raise ValueError(f"{name} must have shape {spec}, got {shape}")
