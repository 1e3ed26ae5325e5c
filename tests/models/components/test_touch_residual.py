"""Touch geometry as a correction of Pixel2Mesh, and touch geometry's deformer on the Pixel2Mesh answer (beyond the
paper): with no touch each model is its visual path exactly, the untrained touch path changes nothing, the touched
loss does not reach a detached visual path, and a tiny batch is pulled onto its own patches only."""

from __future__ import annotations

import pytest
import torch
from test_touch_geometry import _camera, _patches, fit_patch_term

from tvrecon.models.components.gcn import MeshDeformer
from tvrecon.models.components.touch_cascade import TouchCascadeDeformer
from tvrecon.models.components.touch_geometry import TouchGeometryReconstructor, patch_to_mesh_loss
from tvrecon.models.components.touch_residual import TouchResidualDeformer

KINDS = ["residual", "cascade"]


def _net(seed: int = 0, detach_visual: bool = True, kind: str = "residual") -> TouchGeometryReconstructor:
    torch.manual_seed(seed)
    if kind == "cascade":  # the touch path takes the visual path's widths
        deformer = TouchCascadeDeformer(hidden=16, num_blocks=1, detach_visual=detach_visual)
    else:
        deformer = TouchResidualDeformer(
            hidden=16, num_blocks=1, touch_hidden=16, touch_blocks=1, detach_visual=detach_visual
        )
    return TouchGeometryReconstructor(deformer=deformer)


def _touch_inputs(B: int, T: int = 4, Q: int = 30, seed: int = 0, radius: float = 0.3) -> dict[str, torch.Tensor]:
    pts, nrm, pmask = _patches(B, T, Q, seed=seed, radius=radius)
    return {"patch_points": pts, "patch_normals": nrm, "patch_mask": pmask}


@pytest.mark.parametrize("kind", KINDS)
def test_visual_path_is_pixel2mesh_and_untrained_touch_path_changes_nothing(kind: str) -> None:
    B = 2
    net = _net(kind=kind).eval()
    K, RT = _camera(B)
    image = torch.rand(B, 3, 64, 64)
    plain = MeshDeformer(hidden=16, num_blocks=1)
    plain.load_state_dict({k: v for k, v in net.deformer.state_dict().items() if not k.startswith("touch_stages")})
    torch.manual_seed(0)  # the visual path is built first: its initial weights are the plain deformer's with that seed
    for k, v in MeshDeformer(hidden=16, num_blocks=1).state_dict().items():
        torch.testing.assert_close(v, plain.state_dict()[k], rtol=0, atol=0)
    with torch.no_grad():
        none = net(image, K, RT)
        touched = net(image, K, RT, **_touch_inputs(B))
        features = none["features"]
        reference = plain(features, K, (64, 64))
    for s in range(3):
        torch.testing.assert_close(none["verts"][s], reference["verts"][s], rtol=0, atol=0)  # no touch: Pixel2Mesh
        torch.testing.assert_close(touched["verts"][s], reference["verts"][s], rtol=0, atol=0)  # zero-init correction
        assert touched["visual"]["verts"][s] is not None
    assert none["visual"]["verts"][-1] is not None and none["touch"] is None


@pytest.mark.parametrize("kind", KINDS)
def test_trained_touch_path_moves_touched_samples_only(kind: str) -> None:
    B = 3
    net = _net(kind=kind)
    K, RT = _camera(B)
    image = torch.rand(B, 3, 64, 64)
    inputs = _touch_inputs(B)
    inputs["patch_mask"][2] = False  # sample 2 felt nothing
    with torch.no_grad():
        for p in net.deformer.touch_stages.parameters():
            p.add_(0.05 * torch.randn_like(p))
        out = net(image, K, RT, **inputs)
    visual = out["visual"]["verts"][-1]
    moved = (out["verts"][-1] - visual).abs().amax(dim=(1, 2))  # (B,)
    assert moved[0] > 1e-4 and moved[1] > 1e-4
    assert moved[2] == 0  # no contact point: exactly the visual answer
    for s in range(3):  # a stage's input is the visual input plus the correction carried in
        assert out["verts_before"][s].shape == out["verts"][s].shape


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("detach_visual", [True, False])
def test_touched_loss_reaches_the_visual_path_only_when_not_detached(detach_visual: bool, kind: str) -> None:
    B = 2
    net = _net(detach_visual=detach_visual, kind=kind)
    K, RT = _camera(B)
    with torch.no_grad():
        for block in net.deformer.touch_stages:  # a touch path that already moves the mesh
            block.conv_out.self_linear.weight.normal_(0, 0.01)
    out = net(torch.rand(B, 3, 64, 64), K, RT, **_touch_inputs(B))
    loss = sum(patch_to_mesh_loss(v, out["touch"]) for v in out["verts"])
    loss.backward()
    for block in net.deformer.touch_stages:
        grad = block.conv_in.self_linear.weight.grad
        assert grad is not None and grad.abs().sum() > 0
    visual_grad = net.deformer.stages[0].conv_in.self_linear.weight.grad
    reaches = visual_grad is not None and bool(visual_grad.abs().sum() > 0)
    assert reaches == (not detach_visual)
    grad = net.visual.stem[0].weight.grad
    assert (grad is not None and bool(grad.abs().sum() > 0)) == (not detach_visual)


@pytest.mark.parametrize("kind", KINDS)
def test_overfits_own_patches_and_misses_another_objects(kind: str) -> None:
    """A few Adam steps pull the touched mesh onto one object's patches; fed another object's patches (a smaller
    sphere, same image), the same network misses the first object's patches by much more."""
    net = _net(seed=1, kind=kind)
    K, RT = _camera(1)
    image = torch.rand(1, 3, 64, 64)
    own = _touch_inputs(1, T=6, Q=40, seed=3)
    other = _touch_inputs(1, T=6, Q=40, seed=4, radius=0.15)
    fit_patch_term(net, image, K, RT, own)
    with torch.no_grad():
        fit = net(image, K, RT, **own)
        swapped = net(image, K, RT, **other)
        own_loss = patch_to_mesh_loss(fit["verts"][-1], fit["touch"]).item()
        swapped_loss = patch_to_mesh_loss(swapped["verts"][-1], fit["touch"]).item()
        visual_loss = patch_to_mesh_loss(fit["visual"]["verts"][-1], fit["touch"]).item()
    assert own_loss < 2e-3
    assert swapped_loss > 3 * own_loss
    assert visual_loss > 3 * own_loss  # the correction, not the visual path, did the fitting


def test_cascade_touch_path_has_the_visual_paths_size_and_reads_both_hiddens() -> None:
    net = _net(kind="cascade")
    visual, touch = net.deformer.stages, net.deformer.touch_stages
    for s in range(3):
        assert touch[s].conv_in.self_linear.out_features == visual[s].conv_in.self_linear.out_features == 16
        assert len(touch[s].blocks) == len(visual[s].blocks) == 1
    # stage 0: h_visual + xyz + image; later stages also the touch path's own hidden of the stage before
    assert touch[1].conv_in.self_linear.in_features - touch[0].conv_in.self_linear.in_features == 16
    with pytest.raises(ValueError, match="touch_hidden"):
        TouchCascadeDeformer(touch_hidden=0)


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="sigmas"):
        TouchResidualDeformer(sigmas=[])
    with pytest.raises(ValueError, match="touch_hidden"):
        TouchResidualDeformer(touch_hidden=0)
    with pytest.raises(ValueError, match="read touch points"):
        TouchGeometryReconstructor(deformer=MeshDeformer(hidden=16, num_blocks=1))
