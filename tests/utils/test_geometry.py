import numpy as np
import pytest
import torch
import trimesh

from tvrecon.sim.sensor import sensor_frame
from tvrecon.utils.geometry import check_mesh, perpendicular_basis, rotate_to_camera, world_to_camera


def test_check_mesh_names_what_is_wrong() -> None:
    check_mesh(trimesh.creation.box())
    with pytest.raises(ValueError, match="object mesh must be a trimesh.Trimesh"):
        check_mesh(np.zeros((3, 3)), "object mesh")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="no faces .*non-empty"):
        check_mesh(trimesh.Trimesh())
    flat = trimesh.Trimesh(vertices=np.zeros((3, 3)), faces=[[0, 1, 2]], process=False)
    check_mesh(flat)
    with pytest.raises(ValueError, match="zero surface area"):
        check_mesh(flat, require_area=True)
    bad = trimesh.creation.box()
    bad.vertices[0] = [np.nan, 0.0, 0.0]
    with pytest.raises(ValueError, match="NaN"):
        check_mesh(bad)


def test_perpendicular_basis_is_right_handed_and_batched_like_single() -> None:
    rng = np.random.default_rng(0)
    d = rng.normal(size=(64, 3))
    d[:3] = np.eye(3)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    e1, e2 = perpendicular_basis(d)
    assert np.allclose(np.linalg.det(np.stack([e1, e2, d], axis=1)), 1.0)
    assert np.allclose(np.einsum("ij,ij->i", e1, d), 0.0) and np.allclose(np.linalg.norm(e2, axis=1), 1.0)
    for k in range(len(d)):
        one = perpendicular_basis(d[k])
        assert np.allclose(one[0], e1[k], atol=1e-15) and np.allclose(one[1], e2[k], atol=1e-15)
    # the pad frame picks the same helper axis but projects it: its e_x is -e2 of the press direction
    R = sensor_frame(torch.tensor(d[5], dtype=torch.float32)).double().numpy()
    assert np.allclose(R[:, 0], -e2[5], atol=1e-6)


def test_world_to_camera_batched_and_unbatched_agree() -> None:
    g = torch.Generator().manual_seed(0)
    R = torch.linalg.qr(torch.randn(2, 3, 3, generator=g))[0]
    RT = torch.cat([R, torch.randn(2, 3, 1, generator=g)], dim=2)
    p = torch.randn(2, 5, 3, generator=g)
    cam = world_to_camera(p, RT)
    assert torch.allclose(cam, p @ R.transpose(1, 2) + RT[:, None, :, 3], atol=1e-6)
    assert torch.equal(world_to_camera(p[1], RT[1]), cam[1])
    assert torch.allclose(rotate_to_camera(p, RT), p @ R.transpose(1, 2))
    assert world_to_camera(p[0].double(), RT[0]).dtype == torch.float64
    with pytest.raises(ValueError, match=r"RT must have shape \(3, 4\)"):
        world_to_camera(p[0], RT)
    with pytest.raises(ValueError, match=r"RT must have shape \(B, 3, 4\) with B=2"):
        world_to_camera(p, RT[:1])
