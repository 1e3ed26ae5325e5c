"""Touch policies: surface sampling, press-direction cones, visibility, batching into the simulator, resizing."""

import dataclasses

import numpy as np
import pytest
import torch
import trimesh

from tvrecon.data.touches.policies import (
    ConeTouchPolicy,
    Touches,
    cone_directions,
    make_touch_policy,
    resize_tactile,
    sample_touches,
    simulate_touches,
    visible_points,
)
from tvrecon.data.views import sample_camera
from tvrecon.sim.press.placement import pad_footprint, pad_reachable


@pytest.fixture(scope="module")
def torus() -> trimesh.Trimesh:
    return trimesh.creation.torus(major_radius=0.3, minor_radius=0.12)


def _angles_deg(a: torch.Tensor, b: torch.Tensor) -> np.ndarray:
    cos = (a.double() * b.double()).sum(1).clamp(-1, 1)
    return np.degrees(np.arccos(cos.numpy()))


def test_positions_on_surface_and_directions_in_cone(torus: trimesh.Trimesh) -> None:
    policy = ConeTouchPolicy(cone_deg=20.0)
    t = sample_touches(torus, 300, seed=1, policy=policy)
    pos, dirs, normals = t.positions, t.directions, t.normals
    assert pos.shape == (300, 3) and dirs.shape == (300, 3) and pos.dtype == torch.float32
    closest, dist, tri = trimesh.proximity.closest_point(torus, pos.numpy())
    assert dist.max() < 1e-5
    true_n = torch.as_tensor(torus.face_normals[tri], dtype=torch.float32)
    assert _angles_deg(normals, true_n).max() < 1.0  # same face up to ties at edges
    assert torch.allclose(dirs.norm(dim=1), torch.ones(300), atol=1e-5)
    ang = _angles_deg(dirs, -true_n)
    assert ang.max() <= 20.0 + 1.0 and ang.max() > 15.0  # fills the cone, never leaves it
    assert all(s in policy.strengths for s in t.strengths)


def test_zero_cone_is_inward_normal(torus: trimesh.Trimesh) -> None:
    t = sample_touches(torus, 50, seed=2, policy=ConeTouchPolicy(cone_deg=0.0))
    assert torch.allclose(t.directions, -t.normals, atol=1e-6)
    # inward: a small step along the direction goes inside the (watertight) torus
    inside = torus.contains((t.positions + 0.01 * t.directions).numpy())
    assert inside.all()


def test_cone_is_uniform_on_the_cap() -> None:
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(20000, 3))
    d = cone_directions(axes, 30.0, rng)
    cos = np.einsum("ij,ij->i", d, axes / np.linalg.norm(axes, axis=1, keepdims=True))
    assert cos.min() >= np.cos(np.deg2rad(30.0)) - 1e-9
    # uniform by solid angle: cos(theta) is uniform on [cos(30 deg), 1]
    assert cos.mean() == pytest.approx((1 + np.cos(np.deg2rad(30.0))) / 2, abs=3e-3)


def test_area_weighted_sampling() -> None:
    slab = trimesh.creation.box((1.0, 1.0, 0.1))
    pos = sample_touches(slab, 4000, seed=0).positions
    on_big_faces = (pos[:, 2].abs() > 0.05 - 1e-6).float().mean().item()
    assert on_big_faces == pytest.approx(2.0 / 2.4, abs=0.03)


def test_strengths_and_determinism(torus: trimesh.Trimesh) -> None:
    policy = ConeTouchPolicy(strengths=[{"depth": 2.0}, {"depth": 3.0}, {"force": 1.5}])
    a = sample_touches(torus, 200, seed=5, policy=policy)
    b = sample_touches(torus, 200, seed=5, policy=policy)
    c = sample_touches(torus, 200, seed=6, policy=policy)
    assert torch.equal(a.positions, b.positions) and torch.equal(a.directions, b.directions)
    assert a.strengths == b.strengths
    assert not torch.equal(a.positions, c.positions)
    assert {tuple(s.items()) for s in a.strengths} == {(("depth", 2.0),), (("depth", 3.0),), (("force", 1.5),)}


def _first_hit_is_point(mesh: trimesh.Trimesh, center: np.ndarray, p: np.ndarray) -> bool:
    d = (p - center) / np.linalg.norm(p - center)
    locs, _, _ = trimesh.ray.ray_triangle.RayMeshIntersector(mesh).intersects_location(center[None], d[None])
    first = locs[np.argmin(np.linalg.norm(locs - center, axis=1))]
    return bool(np.linalg.norm(first - p) < 1e-4)


def test_take_is_one_touch_of_the_batch(torus: trimesh.Trimesh) -> None:
    t = sample_touches(torus, 5, seed=3, policy=ConeTouchPolicy())
    for i in (0, 3, -1):
        one = t.take(i)
        assert one.positions.shape == one.directions.shape == one.normals.shape == (1, 3)
        assert torch.equal(one.positions[0], t.positions[i]) and torch.equal(one.directions[0], t.directions[i])
        assert torch.equal(one.normals[0], t.normals[i]) and one.strengths == [t.strengths[i]]
    with pytest.raises(IndexError, match="touch 5 of 5"):
        t.take(5)


def test_visible_only(torus: trimesh.Trimesh) -> None:
    cam = sample_camera(4, image_size=64)
    center = cam.center.double().numpy()
    t = sample_touches(torus, 12, seed=0, policy=ConeTouchPolicy(visible_only=True), camera=cam)
    for p in t.positions.double().numpy():
        assert _first_hit_is_point(torus, center, p)
    # the filter actually rejects something: plain samples include hidden points
    pts, faces = trimesh.sample.sample_surface(torus, 200, seed=0)
    vis = visible_points(torus, pts, torus.face_normals[faces], cam)
    assert 0 < vis.sum() < len(vis)
    for i in np.flatnonzero(~vis)[:10]:
        assert not _first_hit_is_point(torus, center, pts[i]) or torus.face_normals[faces[i]] @ (center - pts[i]) <= 0


def test_bad_inputs(torus: trimesh.Trimesh) -> None:
    with pytest.raises(ValueError, match="camera"):
        sample_touches(torus, 3, 0, ConeTouchPolicy(visible_only=True))
    with pytest.raises(ValueError, match="cone_deg"):
        ConeTouchPolicy(cone_deg=95.0)
    with pytest.raises(ValueError, match="strengths"):
        ConeTouchPolicy(strengths=[])
    with pytest.raises(ValueError, match="strengths"):
        ConeTouchPolicy(strengths={"depth": 2.0})
    with pytest.raises(ValueError, match="n "):
        sample_touches(torus, 0, 0)
    with pytest.raises(ValueError, match="no faces"):
        sample_touches(trimesh.Trimesh(), 3, 0)
    with pytest.raises(ValueError, match=r"image must have shape \(T, 3, h, w\) or \(3, h, w\), got \(2, 64, 64\)"):
        resize_tactile(torch.zeros(2, 64, 64))
    with pytest.raises(ValueError, match="missing key"):
        simulate_touches(None, torus, {"positions": torch.zeros(1, 3)})


def test_resize_tactile() -> None:
    x = torch.rand(4, 3, 64, 64)
    assert resize_tactile(x).shape == (4, 3, 224, 224)
    assert resize_tactile(x[0]).shape == (3, 224, 224)
    assert resize_tactile(x, size=(32, 48)).shape == (4, 3, 32, 48)
    assert resize_tactile(torch.rand(2, 3, 300, 300), 224).shape == (2, 3, 224, 224)
    assert torch.equal(resize_tactile(x, 64), x)  # at the model resolution already: returned exactly
    const = torch.full((1, 3, 64, 64), 0.7)
    assert torch.allclose(resize_tactile(const), torch.full((1, 3, 224, 224), 0.7), atol=1e-6)
    # a blob keeps its place and mass (area-normalised)
    blob = torch.zeros(1, 3, 64, 64)
    blob[:, 2, 20:30, 40:50] = 1.0
    big = resize_tactile(blob)
    assert big[0, 2].sum().item() / 224**2 == pytest.approx(blob[0, 2].sum().item() / 64**2, rel=0.02)
    v, u = torch.nonzero(big[0, 2] > 0.5, as_tuple=True)
    assert abs(v.float().mean().item() - 24.5 * 224 / 64 - 0.5 * (224 / 64 - 1)) < 1.0
    assert abs(u.float().mean().item() - 44.5 * 224 / 64 - 0.5 * (224 / 64 - 1)) < 1.0


class _RecordingSim:
    """Stands in for EIPSimulator to check batching: records each press_batch call, returns the touch index."""

    def __init__(self) -> None:
        self.calls: list[tuple[int, dict]] = []

    def press_batch(self, mesh, positions, directions, **overrides):
        self.calls.append((len(positions), overrides))
        return [(tuple(p.tolist()), dict(overrides)) for p in positions]


def test_simulate_touches_batches_by_strength(torus: trimesh.Trimesh) -> None:
    policy = ConeTouchPolicy(strengths=[{"depth": 2.0}, {"threshold": 0.05}])
    t = sample_touches(torus, 21, seed=3, policy=policy)
    sim = _RecordingSim()
    out = simulate_touches(sim, torus, t, batch_size=4)
    assert len(out) == 21
    for i, (pos, strength) in enumerate(out):  # results come back in touch order with their own strength
        assert pos == tuple(t.positions[i].tolist()) and strength == t.strengths[i]
    assert all(n <= 4 for n, _ in sim.calls)
    n_depth = sum(s == {"depth": 2.0} for s in t.strengths)
    assert len(sim.calls) == -(-n_depth // 4) + -(-(21 - n_depth) // 4)


@pytest.mark.slow
def test_real_simulation_contact_images(one_thread) -> None:
    """Pressing a small sphere along -normal: contact happens, the pad is pushed in (z > 0) most at its centre
    (the contact patch of a sphere is a disk around the touch point), and a deeper press pushes further."""
    from tvrecon.sim.press import EIPSimulator, PressConfig
    from tvrecon.sim.sensor import SensorConfig

    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.12)
    policy = ConeTouchPolicy(cone_deg=0.0, strengths=[{"depth": 0.75}, {"depth": 1.5}])
    t = sample_touches(sphere, 2, seed=0, policy=policy)
    t = t._replace(strengths=[{"depth": 0.75}, {"depth": 1.5}])  # one of each
    sim = EIPSimulator(SensorConfig(resolution=(16, 16)), PressConfig(n_grid=64))
    readings = simulate_touches(sim, sphere, t, batch_size=2)
    assert len(readings) == 2
    centre_z = []
    for r, pos in zip(readings, t.positions):
        assert r.contact
        assert r.image.shape == (3, 16, 16)
        z = r.image[2]
        centre, corners = z[6:10, 6:10].mean(), torch.stack([z[0, 0], z[0, -1], z[-1, 0], z[-1, -1]]).mean()
        assert centre > 0.2 and centre > corners + 0.2
        assert z.min() > -0.05  # nothing is pulled out of the pad
        assert torch.dist(r.position, pos) < 0.05  # the reading sits where the touch was sampled
        centre_z.append(centre.item())
    assert readings[1].depth > readings[0].depth and centre_z[1] > centre_z[0]
    # resized for the model, the contact stays non-zero at the centre
    big = resize_tactile(torch.stack([r.image for r in readings]), 64)
    assert big.shape == (2, 3, 64, 64) and (big[:, 2, 28:36, 28:36] > 0.2).all()


def _groove() -> trimesh.Trimesh:
    """A slab with two walls on top leaving a 0.1-wide groove along y in the middle (x in [-0.05, 0.05])."""
    slab = trimesh.creation.box((1.0, 1.0, 0.2))
    walls = []
    for x in (-0.15, 0.15):
        w = trimesh.creation.box((0.2, 0.4, 0.3))
        w.apply_translation((x, 0.0, 0.25))
        walls.append(w)
    return trimesh.util.concatenate([slab, *walls])


def test_pad_reachable_rejects_grooves() -> None:
    mesh = _groove()
    down = np.array([[0.0, 0.0, -1.0]] * 3)
    pos = np.array([[0.0, 0.0, 0.1], [0.0, 0.42, 0.1], [0.0, -0.42, 0.1]])  # groove bottom, open slab top x2
    ok = pad_reachable(mesh, pos, down, width=0.3, clearance=0.05)
    assert ok.tolist() == [False, True, True]
    # a pad narrower than the groove fits
    assert pad_reachable(mesh, pos[:1], down[:1], width=0.08, clearance=0.05).tolist() == [True]


@pytest.mark.slow
def test_sim_aware_sampling_is_accepted_by_the_simulator(one_thread) -> None:
    """With sim=..., touches on a gear (holes, teeth) are all placeable by the simulator; without, many are not."""
    from tvrecon.data.shapes import make_shape
    from tvrecon.sim.press import EIPSimulator, PressConfig
    from tvrecon.sim.sensor import SensorConfig

    gear = make_shape("gear", seed=0)
    sim = EIPSimulator(SensorConfig(resolution=(32, 32)), PressConfig(n_grid=64))
    width, clearance = pad_footprint(sim.sensor, sim.cfg)
    assert width == pytest.approx(2 * np.hypot(7.75, 7.75) / 64) and clearance > 0
    t = sample_touches(gear, 4, seed=0, policy=ConeTouchPolicy(cone_deg=10.0), sim=sim)
    for p, d in zip(t.positions, t.directions):
        sim.press_batch(gear, p[None], d[None], max_steps=1)  # raises ValueError if the pad cannot be placed
    plain = sample_touches(gear, 200, seed=0, policy=ConeTouchPolicy(cone_deg=10.0))
    ok = pad_reachable(gear, plain.positions.numpy(), plain.directions.numpy(), width, clearance)
    assert 0.05 < 1 - ok.mean() < 0.95  # the filter matters on this object


def test_visible_touches_land_on_the_rendered_object() -> None:
    """Integration with the object library and the renderer: visible touches project onto object pixels whose
    rendered depth matches the touch's camera-frame depth."""
    from tvrecon.data.shapes import make_shape
    from tvrecon.data.views import project_points, render_view
    from tvrecon.utils.geometry import world_to_camera

    mug = make_shape("mug", seed=3)
    cam = sample_camera(2, image_size=160)
    view = render_view(mug, cam, seed=0)
    t = sample_touches(mug, 40, seed=1, policy=ConeTouchPolicy(visible_only=True), camera=cam)
    uv = project_points(t.positions, cam.K, cam.RT).round().long()
    z = world_to_camera(t.positions, cam.RT)[:, 2]
    assert view["mask"][uv[:, 1], uv[:, 0]].all()
    err = (view["depth"][uv[:, 1], uv[:, 0]] - z).abs()
    assert err.median() < 0.01 and (err < 0.03).float().mean() > 0.9


def test_policy_sample_is_sample_touches_with_a_seeded_rng(torus: trimesh.Trimesh) -> None:
    policy = ConeTouchPolicy(cone_deg=10.0)
    a = sample_touches(torus, 7, seed=3, policy=policy)
    b = policy.sample(torus, 7, np.random.default_rng(3))
    assert isinstance(a, Touches) and a._fields == ("positions", "directions", "normals", "strengths")
    assert all(torch.equal(x, y) for x, y in zip(a[:3], b[:3], strict=True)) and a.strengths == b.strengths


@dataclasses.dataclass
class _AlongNormal(ConeTouchPolicy):
    """A policy other than the default: the default's points, pressed exactly along the inward normal."""

    def sample(self, mesh, n, rng, camera=None, sim=None) -> Touches:
        points, normals, _ = self._candidates(mesh, n, n, rng, camera, sim)
        return self._touches(points[:n], normals[:n], -normals[:n], rng)


def test_make_touch_policy_and_cache_spec(torus: trimesh.Trimesh) -> None:
    default = make_touch_policy(None)
    assert default == ConeTouchPolicy() and make_touch_policy(default) is default
    # the default's cache spec is its fields only: the touch_policy entry of samples cached before policies existed
    fields = {"cone_deg": 15.0, "strengths": default.strengths, "visible_only": False, "oversample": 8}
    assert default.cache_spec() == fields
    target = "tvrecon.data.touches.policies.ConeTouchPolicy"
    assert make_touch_policy({"_target_": target, "cone_deg": 15}).cache_spec() == fields  # int cone: same policy
    other = make_touch_policy({"_target_": f"{__name__}._AlongNormal", "cone_deg": 15.0})
    assert isinstance(other, _AlongNormal)
    assert other.cache_spec() == {"_target_": f"{__name__}._AlongNormal", **fields}  # another class: another key
    t = sample_touches(torus, 20, seed=0, policy=other)
    assert torch.allclose(t.directions, -t.normals, atol=1e-6)
    with pytest.raises(ValueError, match=r"unknown touch \(ConeTouchPolicy\) option\(s\) \['cone'\]"):
        make_touch_policy({"cone": 15.0})
    with pytest.raises(ValueError, match="names no importable class"):
        make_touch_policy({"_target_": "tvrecon.data.touches.policies.NoSuchPolicy"})
    with pytest.raises(ValueError, match="is not a TouchPolicy dataclass"):
        make_touch_policy({"_target_": "tvrecon.data.touches.policies.Touches"})
