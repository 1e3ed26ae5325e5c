"""ResNet-18 backbone (cached weights only) and the ellipsoid / unpooling topology."""

import logging

import pytest
import torch
import trimesh

import tvrecon.models.components.backbone as backbone_mod
from tvrecon.models.components.backbone import ResNet18Backbone, cached_resnet18_weights_path, load_resnet18
from tvrecon.models.components.classifier import TactileClassifier
from tvrecon.models.components.ellipsoid import (
    EllipsoidTemplate,
    mesh_edges,
    unpool_faces,
    unpool_features,
    uv_ellipsoid,
)


def test_backbone_stage_shapes_and_touch_folding() -> None:
    net = ResNet18Backbone().eval()
    feats = net(torch.rand(2, 3, 64, 64))
    assert [tuple(f.shape) for f in feats] == [(2, 64, 16, 16), (2, 128, 8, 8), (2, 256, 4, 4), (2, 512, 2, 2)]
    tac = torch.rand(2, 3, 3, 32, 32)
    per_touch = net.forward_touches(tac)
    assert [tuple(f.shape) for f in per_touch][0] == (2, 3, 64, 8, 8)
    # shared weights: touch (1, 2) alone gives the same features as inside the folded batch
    alone = net(tac[1, 2][None])
    assert torch.allclose(alone[3][0], per_touch[3][1, 2], atol=1e-5)
    with pytest.raises(ValueError, match=r"x must have shape \(B, 3, H, W\), got \(2, 4, 32, 32\)"):
        net(torch.rand(2, 4, 32, 32))


def test_pretrained_without_cache_warns_once_and_never_downloads(tmp_path, monkeypatch, caplog) -> None:
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path))

    def no_download(*args, **kwargs):
        raise AssertionError("must not download")

    monkeypatch.setattr(torch.hub, "load_state_dict_from_url", no_download)
    monkeypatch.setattr(backbone_mod, "_warned_missing", False)
    with caplog.at_level(logging.WARNING, logger=backbone_mod.__name__):
        net = ResNet18Backbone(pretrained=True)
        ResNet18Backbone(pretrained=True)  # a second backbone (tactile branch) does not warn again
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "random initialisation" in warnings[0].getMessage()
    assert not net.pretrained_loaded


def test_pretrained_loads_cached_file_and_classifier_replicates_conv(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path))
    path = cached_resnet18_weights_path()
    assert path.startswith(str(tmp_path))
    reference, _ = load_resnet18(False)
    (tmp_path / "checkpoints").mkdir()
    torch.save(reference.state_dict(), path)
    net = ResNet18Backbone(pretrained=True)
    assert net.pretrained_loaded
    assert torch.equal(net.stem[0].weight, reference.conv1.weight)
    assert torch.equal(net.stages[3][1].conv2.weight, reference.layer4[1].conv2.weight)
    clf = TactileClassifier(num_classes=4, num_touches=5, pretrained=True)
    w = clf.net.conv1.weight
    assert w.shape == (64, 15, 7, 7)
    for n in range(5):
        assert torch.allclose(w[:, 3 * n : 3 * n + 3], reference.conv1.weight / 5)


def test_uv_ellipsoid_is_closed_outward_in_front_of_camera() -> None:
    verts, faces = uv_ellipsoid(radii=(0.3, 0.2, 0.1), distance=2.5)
    assert verts.shape == (156, 3) and faces.shape == (308, 3)
    mesh = trimesh.Trimesh(verts.numpy(), faces.numpy(), process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert mesh.euler_number == 2
    assert torch.allclose(verts.mean(0), torch.tensor([0.0, 0.0, 2.5]), atol=1e-5)
    assert torch.allclose(verts.max(0).values - verts.min(0).values, torch.tensor([0.6, 0.4, 0.2]), atol=0.02)
    with pytest.raises(ValueError, match="radii"):
        uv_ellipsoid(radii=(1.0, -1.0, 1.0))


def test_unpooling_156_618_2466_closed_meshes() -> None:
    t = EllipsoidTemplate(levels=3)
    counts = [t.verts(s).shape[0] for s in range(3)]
    assert counts == [156, 618, 2466]
    for s in range(3):
        v, f, e = t.verts(s), t.faces(s), t.edges(s)
        assert v.shape[0] - e.shape[0] + f.shape[0] == 2  # Euler characteristic
        mesh = trimesh.Trimesh(v.numpy(), f.numpy(), process=False)
        assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
        assert torch.equal(e, mesh_edges(f))
    parent = t.parent_edges(1)
    assert parent.shape == (462, 2)
    assert torch.allclose(t.verts(1)[156:], 0.5 * (t.verts(0)[parent[:, 0]] + t.verts(0)[parent[:, 1]]))


def test_unpool_single_triangle() -> None:
    faces = torch.tensor([[0, 1, 2]])
    new_faces, parent = unpool_faces(faces, 3)
    assert new_faces.shape == (4, 3) and parent.tolist() == [[0, 1], [0, 2], [1, 2]]
    x = torch.tensor([[[0.0, 0, 0], [2, 0, 0], [0, 2, 0]]])
    up = unpool_features(x, parent)
    assert up[0, 3:].tolist() == [[1.0, 0, 0], [0, 1, 0], [1, 1, 0]]
    # every small triangle keeps the original orientation (+z normal)
    p = up[0]
    n = torch.linalg.cross(p[new_faces[:, 1]] - p[new_faces[:, 0]], p[new_faces[:, 2]] - p[new_faces[:, 0]])
    assert (n[:, 2] > 0).all()
