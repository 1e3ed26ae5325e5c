"""Single-view RGB rendering with known cameras.

A pinhole camera in the OpenCV convention looks at the object from a random point on a sphere; the view is
ray cast on the CPU with trimesh's Embree intersector (one primary ray per pixel centre) and shaded Lambert plus
ambient with a seeded object colour and light. Because every pixel is the exact first hit of the ray through
its centre, `project_points` (kornia) maps any rendered surface point back onto the pixel it was drawn in.

Conventions (OpenCV): camera frame x right, y down, z forward (depth); pixel (u, v) = (column, row) with pixel
centres at integer coordinates, so the image spans u in [-0.5, W - 0.5]. `RT = [R | t]` maps world to camera:
x_cam = R x_world + t.
"""

from __future__ import annotations

from dataclasses import dataclass

import kornia
import numpy as np
import torch
import trimesh
from torch import Tensor

from tvrecon.utils.geometry import check_mesh, world_to_camera
from tvrecon.utils.shape_check import check_shape

try:  # Embree (embreex) ray casts, much faster than the pure-python triangle intersector.
    from trimesh.ray.ray_pyembree import RayMeshIntersector as _Intersector
except ImportError:  # pragma: no cover - embreex is a declared dependency
    from trimesh.ray.ray_triangle import RayMeshIntersector as _Intersector

__all__ = ["Camera", "sample_camera", "render_view", "project_points", "ray_intersector"]


@dataclass
class Camera:
    """A pinhole camera (OpenCV convention).

    Attributes:
        K: (3, 3) float32 intrinsics; pixel centres at integer coordinates, u right, v down.
        RT: (3, 4) float32 world->camera extrinsics [R | t]; the camera looks along +z, y points down.
        width: image width W in pixels.
        height: image height H in pixels.
    """

    K: Tensor
    RT: Tensor
    width: int
    height: int

    def __post_init__(self) -> None:
        self.K = torch.as_tensor(self.K, dtype=torch.float32)
        self.RT = torch.as_tensor(self.RT, dtype=torch.float32)
        check_shape(self.K, "(3, 3)", "Camera.K")
        check_shape(self.RT, "(3, 4)", "Camera.RT")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"Camera width and height must be positive, got {self.width} x {self.height}")
        self.width, self.height = int(self.width), int(self.height)

    @property
    def center(self) -> Tensor:
        """(3,) float32 camera centre in world coordinates, -R^T t."""
        R, t = self.RT[:, :3], self.RT[:, 3]
        return -(R.T @ t)

    def pixel_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """World-space primary rays through every pixel centre.

        Returns:
            origins (H*W, 3) float64 (all the camera centre) and unit directions (H*W, 3) float64, row-major
            (ray index = v * W + u).
        """
        K = self.K.double().cpu().numpy()
        R = self.RT[:, :3].double().cpu().numpy()
        v, u = np.meshgrid(np.arange(self.height), np.arange(self.width), indexing="ij")
        pix = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1)  # (H*W, 3) homogeneous pixels
        d_cam = pix @ np.linalg.inv(K).T  # (H*W, 3), z = 1
        d_world = d_cam @ R  # R^T d for each row
        d_world /= np.linalg.norm(d_world, axis=1, keepdims=True)
        origins = np.broadcast_to(self.center.double().cpu().numpy(), d_world.shape).copy()
        return origins, d_world


def _look_at_rotation(forward: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(3, 3) world->camera rotation whose rows are the camera x (right), y (down), z (forward) axes."""
    z = forward / np.linalg.norm(forward)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-3:  # looking (almost) straight along `up`: any perpendicular up works
        x = np.cross(z, np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)  # points "down" in the image
    return np.stack([x, y, z], axis=0)


def sample_camera(seed: int, image_size: int = 224, distance: float = 2.0, fov_deg: float = 35.0) -> Camera:
    """A camera at a random point on a sphere around the origin, looking at the origin.

    The viewpoint is uniform on the sphere of radius `distance` (seeded); the world +z axis is the image's
    "up" unless the view is (nearly) vertical, where another perpendicular is used.

    Args:
        seed: RNG seed; the same seed gives the same camera.
        image_size: square image side W = H in pixels.
        distance: distance of the camera centre from the origin (world units; objects fit [-0.5, 0.5]^3).
        fov_deg: full field of view in degrees (horizontal = vertical).

    Returns:
        Camera with K (3, 3) and RT (3, 4) float32.
    """
    if int(image_size) < 1:
        raise ValueError(f"image_size must be a positive integer, got {image_size}")
    if not distance > 0:
        raise ValueError(f"distance must be > 0, got {distance}")
    if not 0 < fov_deg < 180:
        raise ValueError(f"fov_deg must be in (0, 180), got {fov_deg}")
    rng = np.random.default_rng(seed)
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    center = distance * d
    R = _look_at_rotation(-center, np.array([0.0, 0.0, 1.0]))
    t = -R @ center
    f = 0.5 * image_size / np.tan(np.deg2rad(fov_deg) / 2)
    c = (image_size - 1) / 2.0  # pixel centres at integer coordinates
    K = np.array([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]])
    RT = np.concatenate([R, t[:, None]], axis=1)
    return Camera(
        K=torch.tensor(K, dtype=torch.float32),
        RT=torch.tensor(RT, dtype=torch.float32),
        width=image_size,
        height=image_size,
    )


def ray_intersector(mesh: trimesh.Trimesh):
    """The Embree ray intersector for `mesh` (cached on the mesh by trimesh when Embree is its default)."""
    if isinstance(mesh.ray, _Intersector):
        return mesh.ray
    return _Intersector(mesh)


def _shading_normals(mesh: trimesh.Trimesh, tri: np.ndarray, points: np.ndarray, crease_deg: float = 30.0):
    """(n, 3) unit shading normals at `points` (n, 3) on faces `tri` (n,): barycentric blend of the corner
    vertex normals, using the face normal at corners where the surface bends more than `crease_deg`."""
    face_n = mesh.face_normals[tri]  # (n, 3)
    corners = mesh.faces[tri]  # (n, 3) vertex ids
    corner_n = mesh.vertex_normals[corners]  # (n, 3 corners, 3)
    sharp = np.einsum("nkj,nj->nk", corner_n, face_n) < np.cos(np.deg2rad(crease_deg))  # (n, 3)
    corner_n = np.where(sharp[..., None], face_n[:, None, :], corner_n)
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[tri], points)  # (n, 3)
    n = np.einsum("nk,nkj->nj", bary, corner_n)
    return n / np.clip(np.linalg.norm(n, axis=1, keepdims=True), 1e-12, None)


def _random_colour(rng: np.random.Generator) -> np.ndarray:
    """(3,) RGB in [0, 1]: random hue, medium-to-high saturation and value (readable on a light background)."""
    import colorsys

    h, s, v = rng.uniform(0, 1), rng.uniform(0.35, 0.85), rng.uniform(0.55, 0.95)
    return np.array(colorsys.hsv_to_rgb(h, s, v))


def render_view(
    mesh: trimesh.Trimesh,
    camera: Camera,
    seed: int = 0,
    ambient: float = 0.3,
    background: float = 1.0,
    smooth: bool = True,
) -> dict[str, Tensor]:
    """Ray cast a shaded view of `mesh` seen by `camera`.

    Shading: `colour * (ambient + (1 - ambient) * max(0, n . l))` with a seeded random object colour and a seeded
    light direction on the camera's side of the object; faces are two-sided (normals flipped towards the
    camera). Background pixels take the constant grey `background`.

    Args:
        mesh: triangle mesh in world coordinates.
        camera: the view (K, RT, width W, height H).
        seed: seeds the object colour and the light direction.
        ambient: ambient light fraction in [0, 1].
        background: background intensity in [0, 1].
        smooth: interpolate vertex normals across faces (creases sharper than 30 degrees stay sharp); False
            shades each face flat.

    Returns:
        dict with "image" (3, H, W) float32 in [0, 1], "depth" (H, W) float32 camera-frame z of the first hit
        (0 = background), "mask" (H, W) bool (True where the object is).
    """
    check_mesh(mesh)
    if not isinstance(camera, Camera):
        raise ValueError(f"camera must be a tvrecon.data.views.Camera, got {type(camera).__name__}")
    if not 0.0 <= ambient <= 1.0 or not 0.0 <= background <= 1.0:
        raise ValueError(f"ambient and background must be in [0, 1], got {ambient} and {background}")
    H, W = camera.height, camera.width
    origins, dirs = camera.pixel_rays()
    tri, ray, loc = ray_intersector(mesh).intersects_id(origins, dirs, multiple_hits=False, return_locations=True)
    R = camera.RT[:, :3].double().numpy()
    t = camera.RT[:, 3].double().numpy()
    z = loc @ R[2] + t[2]  # camera-frame depth of each hit
    front = z > 0  # hits behind the camera (camera inside the object) are not drawn
    tri, ray, z = tri[front], ray[front], z[front]

    rng = np.random.default_rng(seed)
    colour = _random_colour(rng)
    view_dir = -R[2]  # from the object towards the camera
    side = rng.normal(size=3)
    side -= (side @ view_dir) * view_dir
    side /= np.linalg.norm(side)
    tilt = np.deg2rad(rng.uniform(15.0, 55.0))  # light comes from the camera's side, tilted in a random direction
    light = np.cos(tilt) * view_dir + np.sin(tilt) * side

    normals = _shading_normals(mesh, tri, loc[front]) if smooth else mesh.face_normals[tri]  # (n_hit, 3)
    flip = np.einsum("ij,ij->i", normals, dirs[ray]) > 0  # back faces: shade as seen from the camera
    normals = np.where(flip[:, None], -normals, normals)
    lambert = np.clip(normals @ light, 0.0, None)
    shade = ambient + (1.0 - ambient) * lambert  # (n_hit,)

    image = np.full((H * W, 3), background, dtype=np.float32)
    image[ray] = np.clip(shade[:, None] * colour[None], 0.0, 1.0)
    depth = np.zeros(H * W, dtype=np.float32)
    depth[ray] = z
    mask = np.zeros(H * W, dtype=bool)
    mask[ray] = True
    return {
        "image": torch.from_numpy(image.reshape(H, W, 3).transpose(2, 0, 1).copy()),
        "depth": torch.from_numpy(depth.reshape(H, W)),
        "mask": torch.from_numpy(mask.reshape(H, W)),
    }


def project_points(points: Tensor, K: Tensor, RT: Tensor) -> Tensor:
    """Project world points to pixel coordinates with kornia (OpenCV convention, pixel centres at integers).

    Args:
        points: (N, 3) float world coordinates.
        K: (3, 3) intrinsics.
        RT: (3, 4) world->camera [R | t].

    Returns:
        (N, 2) pixel coordinates (u, v) = (column, row), dtype and device of `points`. Points behind the camera
        are not flagged: check `world_to_camera(points, RT)[:, 2] > 0` where that matters.
    """
    K, points = torch.as_tensor(K), torch.as_tensor(points)
    check_shape(points, "(N, 3)", "points")
    check_shape(K, "(3, 3)", "K")
    cam = world_to_camera(points, RT)  # (N, 3)
    return kornia.geometry.camera.project_points(cam, K.to(device=cam.device, dtype=cam.dtype))
