"""Graph convolution against a naive loop, perceptual pooling at known pixels, deformer shapes."""

import pytest
import torch

from tvrecon.models.components.gcn import GraphConv, GResBlock, MeshDeformer, neighbour_matrix
from tvrecon.models.components.perceptual import PerceptualPooling


def test_graph_conv_matches_naive_sum_and_mean() -> None:
    edges = torch.tensor([[0, 1], [1, 2], [0, 2], [2, 3]])
    x = torch.randn(2, 4, 5)
    for aggregate in ("sum", "mean"):
        conv = GraphConv(5, 3, aggregate)
        got = conv(x, edges)
        W0, b, W1 = conv.self_linear.weight, conv.self_linear.bias, conv.neighbour_linear.weight
        for bi in range(2):
            for v in range(4):
                nbrs = [j for a, c in edges.tolist() for i, j in ((a, c), (c, a)) if i == v]
                acc = sum(W1 @ x[bi, n] for n in nbrs)
                if aggregate == "mean":
                    acc = acc / len(nbrs)
                ref = W0 @ x[bi, v] + b + acc
                assert torch.allclose(got[bi, v], ref, atol=1e-5)
    with pytest.raises(ValueError, match="aggregate"):
        GraphConv(5, 3, "max")
    assert GResBlock(5)(x, edges).shape == (2, 4, 5)


def test_perceptual_pooling_reads_the_projected_pixel() -> None:
    K = torch.tensor([[[10.0, 0, 7.5], [0, 10.0, 7.5], [0, 0, 1]]])
    # vertex projecting to image pixel (10.5, 2.5) -> feature pixel (x=5, y=1) of an 8 x 8 map of a 16 x 16 image
    z = 2.0
    verts = torch.tensor([[[(10.5 - 7.5) * z / 10, (2.5 - 7.5) * z / 10, z]]])
    f1 = torch.arange(2 * 8 * 8, dtype=torch.float32).reshape(1, 2, 8, 8)
    f2 = torch.arange(4 * 4, dtype=torch.float32).reshape(1, 1, 4, 4)
    out = PerceptualPooling()(verts, K, [f1, f2], (16, 16))
    assert out.shape == (1, 1, 3)
    assert out[0, 0, 0].item() == pytest.approx(f1[0, 0, 1, 5].item())
    assert out[0, 0, 1].item() == pytest.approx(f1[0, 1, 1, 5].item())
    # in the 4 x 4 map the point sits at (x=2.25, y=0.25): bilinear between (2,0),(3,0),(2,1),(3,1)
    g = f2[0, 0]
    ref = 0.75 * 0.75 * g[0, 2] + 0.75 * 0.25 * g[0, 3] + 0.25 * 0.75 * g[1, 2] + 0.25 * 0.25 * g[1, 3]
    assert out[0, 0, 2].item() == pytest.approx(ref.item(), rel=1e-5)


def test_mesh_deformer_shapes_and_starts_near_ellipsoid() -> None:
    deformer = MeshDeformer(feature_channels=[4, 8], hidden=16, num_blocks=1)
    feats = [torch.randn(2, 4, 8, 8), torch.randn(2, 8, 4, 4)]
    K = torch.tensor([[20.0, 0, 15.5], [0, 20.0, 15.5], [0, 0, 1]]).repeat(2, 1, 1)
    out = deformer(feats, K, (32, 32))
    assert [tuple(v.shape) for v in out["verts"]] == [(2, 156, 3), (2, 618, 3), (2, 2466, 3)]
    assert [tuple(f.shape) for f in out["faces"]] == [(308, 3), (1232, 3), (4928, 3)]
    assert [tuple(e.shape) for e in out["edges"]] == [(462, 2), (1848, 2), (7392, 2)]
    assert torch.equal(out["verts_before"][0][0], out["init_verts"][0])
    assert (out["verts"][0] - out["verts_before"][0]).abs().max() < 0.5
    out["verts"][-1].sum().backward()
    assert deformer.stages[0].conv_in.self_linear.weight.grad.abs().sum() > 0


def _dense_neighbours(edges: torch.Tensor, V: int, aggregate: str) -> torch.Tensor:
    A = torch.zeros(V, V, dtype=torch.float64)
    for a, b in edges.tolist():
        A[a, b] += 1
        A[b, a] += 1
    if aggregate == "mean":
        A = A / A.sum(1, keepdim=True).clamp(min=1)
    return A


def test_neighbour_matrix_is_the_block_diagonal_adjacency() -> None:
    edges = torch.tensor([[0, 1], [1, 2], [0, 2], [2, 3]])  # vertex 4 is isolated
    for aggregate in ("sum", "mean"):
        A = _dense_neighbours(edges, 5, aggregate)
        got = neighbour_matrix(edges, 5, aggregate, batch_size=3)
        assert got.layout == torch.sparse_csr and got.shape == (15, 15)
        assert torch.allclose(got.to_dense().double(), torch.block_diag(A, A, A), atol=1e-7)
    with pytest.raises(ValueError, match=r"edges must index vertices in \[0, 3\)"):
        neighbour_matrix(edges, 3)
    with pytest.raises(ValueError, match=r"edges must have shape \(E, 2\)"):
        neighbour_matrix(edges.T, 5)
    with pytest.raises(ValueError, match="aggregate"):
        neighbour_matrix(edges, 5, "max")


def test_graph_conv_prebuilt_neighbours_and_gradients() -> None:
    """A prebuilt operator gives the same result; the sparse product's gradients pass gradcheck (float64)."""
    edges = torch.tensor([[0, 1], [1, 2], [0, 2], [2, 3], [3, 4]])
    conv = GraphConv(4, 3, "mean").double()
    x = torch.randn(2, 5, 4, dtype=torch.float64, requires_grad=True)
    prebuilt = neighbour_matrix(edges, 5, "mean", batch_size=2)
    assert torch.allclose(conv(x, edges), conv(x, edges, prebuilt), atol=1e-12)
    A = _dense_neighbours(edges, 5, "mean")
    ref = conv.self_linear(x) + A @ conv.neighbour_linear(x)
    assert torch.allclose(conv(x, edges), ref, atol=1e-7)
    assert torch.autograd.gradcheck(lambda t: conv(t, edges, prebuilt), (x,))
    with pytest.raises(ValueError, match=r"neighbours must have shape \(B\*V, B\*V\) = \(10, 10\)"):
        conv(x, edges, neighbour_matrix(edges, 5, "mean"))


def test_graph_conv_keeps_low_precision_dtype() -> None:
    edges = torch.tensor([[0, 1], [1, 2]])
    conv = GraphConv(4, 2).to(torch.bfloat16)
    out = conv(torch.randn(1, 3, 4, dtype=torch.bfloat16), edges)
    assert out.dtype == torch.bfloat16 and torch.isfinite(out.float()).all()


def test_mesh_deformer_reuses_its_neighbour_operators() -> None:
    deformer = MeshDeformer(feature_channels=[4], hidden=8, num_blocks=1)
    feats = [torch.randn(2, 4, 8, 8)]
    K = torch.tensor([[20.0, 0, 15.5], [0, 20.0, 15.5], [0, 0, 1]]).repeat(2, 1, 1)
    first = deformer(feats, K, (32, 32))["verts"][-1]
    cached = dict(deformer._neighbours)
    assert len(cached) == 3  # one per level for B = 2
    again = deformer(feats, K, (32, 32))["verts"][-1]
    assert all(deformer._neighbours[k] is v for k, v in cached.items()) and len(deformer._neighbours) == 3
    assert torch.equal(first, again)
    V = deformer.template.verts(2).shape[0]
    ref = neighbour_matrix(deformer.template.edges(2), V, "mean", 2).to_dense()
    op = cached[(2, 2, torch.device("cpu"))]
    assert torch.equal(op.matrix.to_dense(), ref) and torch.equal(op.transpose.to_dense(), ref.T)
