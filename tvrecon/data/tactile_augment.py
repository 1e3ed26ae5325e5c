"""Physically valid tactile augmentation: the pad's in-plane orientation is arbitrary.

Image convention (:mod:`tvrecon.sim.sensor`, :class:`tvrecon.sim.press.reading.TactileReading`): a tactile image is
``(3, H, W)``, the contact-layer displacement in the sensor frame; channel 0 is the in-plane x displacement (local
``e_x``, along the columns j), channel 1 the in-plane y displacement (``e_y``, along the rows i), channel 2 the
normal displacement along ``e_z`` (a scalar under in-plane rotations; > 0 pushed into the pad). Pixel ``(i, j)``
sits at local ``x = (j - (W-1)/2) s``, ``y = (i - (H-1)/2) s``. The frame is right-handed, ``e_z = -direction``
points from the object to the hand, and ``e_x`` is the world x axis projected on the contact plane
(:func:`tvrecon.sim.sensor.elastic_pad.sensor_frame`): a convention, not physics. A touch with the pad turned about
``e_z`` is another valid touch of the same object, and its image is the original one with the pixel grid *and* the
(x, y) displacement vectors rotated together.

Mirroring (``x -> -x``: columns reversed, x shear negated) gives the touch of the mirror-image object, which is a
valid touch for an isotropic pad (the simulator's material and contact are reflection-symmetric); it is a valid
augmentation for classes closed under reflection (the procedural classes are, up to their random deformation).
"""

from __future__ import annotations

import operator
from collections.abc import Sequence

import torch
from torch import Tensor

from tvrecon.utils.shape_check import check_shape

__all__ = ["rotate_tactile", "orient_touches"]


def _check_images(images: Tensor, spec: str = "(..., 3, H, W)") -> None:
    if not isinstance(images, Tensor):
        raise TypeError(f"images must be a torch.Tensor, got {type(images).__name__}")
    check_shape(images, spec, "images")


def rotate_tactile(images: Tensor, k: int, mirror: bool = False) -> Tensor:
    """The tactile images of the same touches with the contact pattern mirrored, then turned k quarter turns.

    The pattern (and the object under the pad) is turned by ``k * 90`` degrees counter-clockwise about the pad's
    outward normal ``e_z`` (``e_x`` towards ``e_y``): the value at local (x, y) moves to ``(-y, x)`` for k = 1, and
    the in-plane displacement ``(u_x, u_y)`` becomes ``(-u_y, u_x)``; the normal channel only moves. ``mirror``
    first reflects ``x -> -x`` (columns reversed, ``u_x`` negated). Exact (a permutation and sign changes),
    differentiable, on any device and dtype.

    Args:
        images: (..., 3, H, W) float tactile images (channels x shear, y shear, normal).
        k: quarter turns, any integer (taken mod 4); odd k needs a square image (H == W).
        mirror: reflect ``x -> -x`` before turning.
    Returns:
        (..., 3, H, W) tensor like ``images`` (W, H swapped never happens: odd k needs H == W).
    """
    _check_images(images)
    if isinstance(k, bool):
        raise TypeError(f"k must be an integer number of quarter turns, got {k!r}")
    try:
        k = operator.index(k)  # int, numpy integer, 0-dim integer tensor
    except TypeError:
        raise TypeError(f"k must be an integer number of quarter turns, got {k!r}") from None
    k %= 4
    H, W = images.shape[-2:]
    if k % 2 and H != W:
        raise ValueError(f"a quarter turn needs square images, got H={H}, W={W} (use k = 0 or 2)")
    ux, uy, un = images.unbind(dim=-3)
    if mirror:
        ux, uy, un = -ux.flip(-1), uy.flip(-1), un.flip(-1)
    # vector part: (ux, uy) turned by k quarter turns
    ux, uy = ((ux, uy), (-uy, ux), (-ux, -uy), (uy, -ux))[k]
    out = torch.stack([ux, uy, un], dim=-3)
    # grid part: value at (x, y) moves to R(x, y); rows are y, columns are x, so a turn from x to y is rot90 over
    # dims (W, H): new[i, j] = old[W-1-j, i] for k = 1
    return torch.rot90(out, k, dims=(-1, -2))


def orient_touches(images: Tensor, k: Sequence[int] | Tensor, mirror: Sequence[bool] | Tensor) -> Tensor:
    """Apply :func:`rotate_tactile` to each touch with its own orientation.

    Args:
        images: (N, 3, H, W) float tactile images of N touches.
        k: (N,) integer quarter turns per touch.
        mirror: (N,) bool mirror flag per touch.
    Returns:
        (N, 3, H, W) tensor like ``images``.
    """
    _check_images(images, "(N, 3, H, W)")
    ks, ms = [int(v) for v in k], [bool(v) for v in mirror]
    if len(ks) != images.shape[0] or len(ms) != images.shape[0]:
        raise ValueError(f"need one k and one mirror per touch (N={images.shape[0]}), got {len(ks)} and {len(ms)}")
    if not ks:
        return images.clone()
    return torch.stack([rotate_tactile(img, kk, mm) for img, kk, mm in zip(images, ks, ms, strict=True)])
