"""A touch mapped back to 3D: the contact patch in world coordinates.

A tactile image is the contact-layer displacement in the sensor frame with the hand translation removed (see
:class:`tvrecon.sim.press.reading.TactileReading`), and the reading's ``position`` is the world point of the centre of
the rest contact layer moved with the hand. Contact-layer particle ``(i, j)`` at the reading is therefore::

    world_ij = position + R(direction) @ (lattice_ij + image_ij) * dx * domain_size

with ``R`` the sensor frame (:func:`tvrecon.sim.sensor.elastic_pad.sensor_frame`, rebuilt from the stored direction),
``lattice_ij`` the pad's rest contact layer in cells (:func:`tvrecon.sim.sensor.elastic_pad.pad_lattice`) and
``dx = 1 / n_grid``. Nothing else is needed, so the patch is derived from what the data cache stores (image,
position, direction) without simulating again.

Where the pad was pushed in (normal channel above ``min_push`` cells) the contact layer lies on the object's surface
(the rigid collider stops the grid there), so those points are samples of the surface; their normals are the
deformed layer's normals, pointing out of the object (towards the hand, the local +z).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from tvrecon.sim.sensor.elastic_pad import SensorConfig, pad_lattice, sensor_frame
from tvrecon.utils.shape_check import check_shape

__all__ = ["ContactPatch", "contact_patch"]

#: Default contact test: the contact layer counts as touching where it was pushed in by more than this (cells).
DEFAULT_MIN_PUSH = 0.1


@dataclass
class ContactPatch:
    """Contact-layer points of one or more touches in world coordinates.

    Attributes:
        points: (..., H*W, 3) float32 world positions of the contact-layer particles, row-major over (H, W).
        normals: (..., H*W, 3) float32 unit normals of the deformed contact layer, pointing out of the object.
        mask: (..., H*W) bool, True where the layer was pushed in by more than ``min_push`` cells (in contact).
    """

    points: Tensor
    normals: Tensor
    mask: Tensor


def _layer_normals(points: Tensor) -> Tensor:
    """(T, H, W, 3) grid of points -> (T, H, W, 3) unit normals ``d/dj x d/di`` (central differences)."""
    d_i = torch.gradient(points, dim=1)[0]  # along H: the local y axis at rest
    d_j = torch.gradient(points, dim=2)[0]  # along W: the local x axis at rest
    n = torch.linalg.cross(d_j, d_i, dim=-1)  # e_x x e_y = e_z at rest: out of the object, towards the hand
    return n / torch.linalg.vector_norm(n, dim=-1, keepdim=True).clamp_min(1e-12)


def contact_patch(
    image: Tensor,
    position: Tensor,
    direction: Tensor,
    sensor: SensorConfig,
    n_grid: int,
    domain_size: float = 1.0,
    min_push: float = DEFAULT_MIN_PUSH,
    min_push_fraction: float = 0.0,
) -> ContactPatch:
    """Contact points, normals and contact mask of touches, from their tactile images.

    Args:
        image: (3, H, W) or (T, 3, H, W) float tactile images in grid cells (channels x shear, y shear, z normal,
            z > 0 pushed into the pad), at the sensor's resolution.
        position: (3,) or (T, 3) float world reading positions (``TactileReading.position``).
        direction: (3,) or (T, 3) float world press directions (non-zero).
        sensor: the pad that produced the images (its resolution and spacing).
        n_grid: grid cells across the simulation domain (``PressConfig.n_grid``).
        domain_size: world units spanned by the domain (``PressConfig.domain_size``).
        min_push: contact threshold on the normal channel, in cells.
        min_push_fraction: in [0, 1): also require a push above this fraction of the touch's deepest push. The rim of
            a contact, barely pushed in, lies off the surface (the pad there is dragged in by its neighbours, not
            stopped by the object); a threshold relative to each touch keeps the shallow contacts of thin parts, which
            an absolute one would drop.

    Returns:
        :class:`ContactPatch` with points/normals (H*W, 3) or (T, H*W, 3) float32 and mask (H*W,) or (T, H*W).
    """
    H, W = sensor.resolution
    check_shape(image, "(3, H, W) or (T, 3, H, W)", "image")
    if tuple(image.shape[-2:]) != (H, W):
        raise ValueError(f"image must be at the sensor's resolution ({H}, {W}), got {tuple(image.shape)}")
    single = image.dim() == 3
    images = image[None] if single else image
    pos = torch.as_tensor(position, dtype=torch.float32)
    dirs = torch.as_tensor(direction, dtype=torch.float32)
    check_shape(pos, "(3,) or (T, 3)", "position")
    check_shape(dirs, "(3,) or (T, 3)", "direction")
    pos = pos[None] if pos.dim() == 1 else pos
    dirs = dirs[None] if dirs.dim() == 1 else dirs
    T = images.shape[0]
    if pos.shape[0] != T or dirs.shape[0] != T:
        raise ValueError(
            f"position and direction must have shape ({T}, 3) like the images, got {tuple(pos.shape)} and "
            f"{tuple(dirs.shape)}"
        )
    if not 0.0 <= float(min_push_fraction) < 1.0:
        raise ValueError(f"min_push_fraction must be in [0, 1), got {min_push_fraction}")
    if int(n_grid) < 1 or not float(domain_size) > 0:
        raise ValueError(f"n_grid must be >= 1 and domain_size > 0, got {n_grid} and {domain_size}")
    if not bool(torch.isfinite(images).all()):
        raise ValueError("image has NaN or infinite values: the tactile image is corrupt; regenerate it")
    dev = images.device
    images = images.to(torch.float32)
    frames = torch.stack([sensor_frame(d) for d in dirs.cpu()]).to(dev)  # (T, 3, 3), raises on a zero direction
    lattice = pad_lattice(sensor, device=dev)[: H * W]  # (HW, 3) rest contact layer, cells
    local = lattice[None] + images.flatten(2).transpose(1, 2)  # (T, HW, 3) sensor frame, cells
    scale = float(domain_size) / int(n_grid)
    points = pos.to(dev)[:, None, :] + scale * local @ frames.transpose(1, 2)  # (T, HW, 3) world: R @ local
    normals = _layer_normals(points.view(T, H, W, 3)).reshape(T, H * W, 3)
    push = images[:, 2].flatten(1)  # (T, HW) cells pushed in
    threshold = (float(min_push_fraction) * push.amax(1, keepdim=True)).clamp_min(float(min_push))  # (T, 1)
    mask = push > threshold  # (T, HW)
    if single:
        return ContactPatch(points[0], normals[0], mask[0])
    return ContactPatch(points, normals, mask)
