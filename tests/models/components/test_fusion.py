"""Agg blocks and global-to-local placement: the embedding lands exactly in the k x k region at the projected pixel."""

import pytest
import torch

from tvrecon.models.components.fusion import (
    AggBlock,
    DirectionFFN,
    TactileVisualFusion,
    locate_touches,
    place_embeddings,
)
from tvrecon.models.components.projection import pixel_to_feature, project

H = W = 32  # image
h = w = 8  # feature map (stride 4)
F_ = 32.0  # focal length
C_ = 15.5  # principal point (centre of a 32 px image, pixel centres at integers)


def camera(B: int = 2) -> tuple[torch.Tensor, torch.Tensor]:
    K = torch.tensor([[F_, 0, C_], [0, F_, C_], [0, 0, 1]]).repeat(B, 1, 1)
    RT = torch.cat([torch.eye(3), torch.tensor([[0.0], [0.0], [2.0]])], dim=1).repeat(B, 1, 1)
    return K, RT


def world_point_for_feature_pixel(x: int, y: int) -> list[float]:
    """A world point (on z=0, depth 2) that projects to the centre of feature pixel (x, y)."""
    u, v = (x + 0.5) * (W / w) - 0.5, (y + 0.5) * (H / h) - 0.5
    return [(u - C_) * 2.0 / F_, (v - C_) * 2.0 / F_, 0.0]


def test_projection_convention() -> None:
    K, RT = camera(1)
    pts = torch.tensor([[world_point_for_feature_pixel(5, 2)]])
    uv = project(pts, K, RT)
    assert torch.allclose(uv, torch.tensor([[[21.5, 9.5]]]))
    assert torch.allclose(pixel_to_feature(uv, (H, W), (h, w)), torch.tensor([[[5.0, 2.0]]]))


@pytest.mark.parametrize("k", [1, 3, 5])
def test_embedding_fills_exactly_the_region(k: int) -> None:
    K, RT = camera(2)
    positions = torch.tensor([[world_point_for_feature_pixel(5, 2)], [world_point_for_feature_pixel(1, 1)]])
    placement = locate_touches(positions, K, RT, (H, W))
    assert placement.batch_index.tolist() == [0, 1]
    feature = torch.randn(2, 4, h, w)
    emb = torch.tensor([[1.0, 2.0, 3.0, 4.0], [10.0, 20.0, 30.0, 40.0]])
    out = place_embeddings(feature, emb, placement.batch_index, placement.uv, (H, W), region=k)
    diff = out - feature
    r = k // 2
    expected = torch.zeros(2, 4, h, w)
    for b, (cx, cy) in enumerate([(5, 2), (1, 1)]):
        for y in range(cy - r, cy + r + 1):
            for x in range(cx - r, cx + r + 1):
                if 0 <= x < w and 0 <= y < h:  # truncated at the border
                    expected[b, :, y, x] = emb[b]
    assert torch.allclose(diff, expected, atol=1e-6)
    assert (diff[0] != 0).any(dim=0).sum().item() == k * k  # the region at (5, 2) fits on the map


def test_region_truncated_at_border() -> None:
    feature = torch.zeros(1, 2, h, w)
    uv = torch.tensor([[-0.4, -0.4]])  # image corner pixel -> feature pixel (0, 0)
    out = place_embeddings(feature, torch.ones(1, 2), torch.tensor([0]), uv, (H, W), region=3)
    assert out[0, 0].sum().item() == 4.0  # 2 x 2 of the 3 x 3 region is on the map
    assert out[0, 0, :2, :2].eq(1).all()


def test_invisible_and_masked_touches_add_nothing_and_touches_add_up() -> None:
    K, RT = camera(1)
    centre = world_point_for_feature_pixel(4, 4)
    behind = [0.0, 0.0, -3.0]  # depth -1: behind the camera
    off_image = [5.0, 0.0, 0.0]  # projects far right of the image
    masked = world_point_for_feature_pixel(1, 6)
    positions = torch.tensor([[centre, centre, behind, off_image, masked]])
    mask = torch.tensor([[True, True, True, True, False]])
    placement = locate_touches(positions, K, RT, (H, W), mask)
    assert placement.touch_index.tolist() == [0, 1]
    feature = torch.zeros(1, 3, h, w)
    emb = torch.tensor([[1.0, 1.0, 1.0], [2.0, 2.0, 2.0]])
    out = place_embeddings(feature, emb, placement.batch_index, placement.uv, (H, W), region=3)
    assert out[0, :, 3:6, 3:6].eq(3.0).all()  # the two touches add up
    assert out.sum().item() == 3.0 * 9 * 3  # nothing anywhere else


def test_place_embeddings_validates() -> None:
    with pytest.raises(ValueError, match="odd positive"):
        place_embeddings(
            torch.zeros(1, 2, 4, 4), torch.zeros(1, 2), torch.zeros(1, dtype=torch.long), torch.zeros(1, 2), (8, 8), 2
        )
    with pytest.raises(ValueError, match=r"embedding \(N, 2\)"):
        place_embeddings(
            torch.zeros(1, 2, 4, 4), torch.zeros(1, 3), torch.zeros(1, dtype=torch.long), torch.zeros(1, 2), (8, 8)
        )
    with pytest.raises(ValueError, match=r"uv must have shape \(N, 2\), got \(1, 3\)"):
        place_embeddings(
            torch.zeros(1, 2, 4, 4), torch.zeros(1, 2), torch.zeros(1, dtype=torch.long), torch.zeros(1, 3), (8, 8)
        )
    with pytest.raises(ValueError, match=r"positions must have shape \(B, T, 3\), got \(2, 3\)"):
        locate_touches(torch.zeros(2, 3), *camera(1), (H, W))


def test_agg_block_shapes_and_direction_product() -> None:
    agg = AggBlock(16, 8).eval()
    x = torch.randn(3, 16, 5, 5)
    d = torch.randn(3, 8)
    base = agg(x)
    assert base.shape == (3, 8)
    assert torch.allclose(agg(x, d), base * d)
    # GAP: only the spatial mean matters
    assert torch.allclose(agg(x.mean(dim=(2, 3), keepdim=True).expand_as(x).contiguous()), base, atol=1e-5)
    nogap = AggBlock(16, 8, use_gap=False).eval()
    assert nogap(x, d).shape == (3, 8, 5, 5)
    # train mode with a single touch (1x1 after GAP) still works
    AggBlock(16, 8).train()(torch.randn(1, 16, 4, 4))
    assert DirectionFFN(32, 512)(torch.randn(5, 3)).shape == (5, 512)


def _fusion_inputs(n_touch_visible: bool = True):
    K, RT = camera(2)
    pos = torch.tensor([[world_point_for_feature_pixel(2, 3)], [world_point_for_feature_pixel(6, 6)]])
    mask = torch.tensor([[True], [False]])
    placement = locate_touches(pos, K, RT, (H, W), mask)
    tactile = [torch.randn(1, c, s, s) for c, s in zip((64, 128, 256, 512), (4, 2, 1, 1))]
    return placement, tactile


def test_dense_and_single_stage_fusion() -> None:
    dense = TactileVisualFusion(zero_init=False)
    single = TactileVisualFusion(single_stage=True, zero_init=False)
    assert len(dense.aggs) == 16 and len(single.aggs) == 4
    assert sorted(single.pairs) == [(0, 0), (1, 1), (2, 2), (3, 3)]
    placement, tactile = _fusion_inputs()
    dir_emb = dense.embed_directions(torch.tensor([[0.0, 0.0, 1.0]]))
    visual = torch.randn(2, 128, h, w)
    dense.eval()
    out = dense(1, visual, tactile, dir_emb, placement, (H, W))
    diff = (out - visual).abs().sum(1)
    changed = diff > 0
    assert changed[0, 2:5, 1:4].all() and changed.sum().item() <= 9  # only the 3x3 region of sample 0
    assert not changed[1].any()  # sample 1's touch is masked
    # dense: the stage receives the sum of 4 Agg embeddings
    expected = sum(dense.aggs[f"t{i}_v1"](tactile[i], dir_emb[:, :128]) for i in range(4))
    assert torch.allclose(out[0, :, 3, 2] - visual[0, :, 3, 2], expected[0], atol=1e-5)


def test_no_gap_fuses_whole_map_and_no_direction() -> None:
    fusion = TactileVisualFusion(use_gap=False, use_direction=False, zero_init=False).eval()
    assert fusion.direction_ffn is None and fusion.embed_directions(torch.randn(1, 3)) is None
    placement, tactile = _fusion_inputs()
    visual = torch.randn(2, 64, h, w)
    out = fusion(0, visual, tactile, None, placement, (H, W))
    assert ((out - visual)[0].abs().sum(0) > 0).float().mean() > 0.5  # spread over the whole map
    assert torch.equal(out[1], visual[1])


def test_fusion_validates() -> None:
    with pytest.raises(ValueError, match="odd positive"):
        TactileVisualFusion(region=4)
    placement, tactile = _fusion_inputs()
    with pytest.raises(ValueError, match=r"visual stage 0 must have shape \(B, 64, h, w\), got \(2, 32, "):
        TactileVisualFusion()(0, torch.randn(2, 32, h, w), tactile, None, placement, (H, W))


def test_touch_depth_extension() -> None:
    """locate_touches reports camera depth; with touch_depth the FFN reads it (same direction, other depth -> other
    embedding), without it depth is ignored; touch_depth needs the direction FFN."""
    K, RT = camera(1)
    near = world_point_for_feature_pixel(3, 3)
    far = [near[0] * 1.5, near[1] * 1.5, 1.0]  # same pixel, one unit farther (camera at z = -2 looks along +z)
    placement = locate_touches(torch.tensor([[near, far]]), K, RT, (H, W))
    assert torch.allclose(placement.depth, torch.tensor([2.0, 3.0]))
    assert torch.equal(placement.uv[0], placement.uv[1])
    dirs = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    with_depth = TactileVisualFusion(touch_depth=True)
    emb = with_depth.embed_directions(dirs, placement.depth)
    assert emb.shape == (2, 512) and not torch.allclose(emb[0], emb[1])
    emb.sum().backward()
    assert with_depth.direction_ffn.net[0].weight.grad[:, 3].abs().sum() > 0  # the depth column learns
    plain = TactileVisualFusion()
    assert torch.equal(*plain.embed_directions(dirs, placement.depth))
    with pytest.raises(ValueError, match=r"with_depth needs depth of shape \(N,\) = \(2,\)"):
        with_depth.embed_directions(dirs)
    with pytest.raises(ValueError, match="needs use_direction=True"):
        TactileVisualFusion(use_direction=False, touch_depth=True)
