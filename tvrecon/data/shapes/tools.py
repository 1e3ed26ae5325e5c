"""Tools and hardware: wrench, hammer, key, screwdriver, knife, bolt, nut, padlock, star, brick, banana."""

from __future__ import annotations

import numpy as np
import trimesh
from shapely import affinity
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry import box as sbox
from shapely.ops import unary_union

from tvrecon.data.shapes.primitives import (
    box,
    cylinder,
    difference,
    extrude,
    lathe,
    rotation,
    smooth_curve,
    tube,
    uniform,
)
from tvrecon.data.shapes.registry import register


def regular_polygon(n: int, radius: float, center: tuple[float, float] = (0.0, 0.0), phase: float = 0.0) -> Polygon:
    """Regular ``n``-gon with circumradius ``radius``."""
    a = phase + 2 * np.pi * np.arange(n) / n
    return Polygon(np.stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a)], axis=1))


@register("wrench")
def wrench(rng: np.random.Generator) -> trimesh.Trimesh:
    """Combination wrench in xy: flat handle, open jaw at one end, closed 12-point ring (or second jaw) at the other."""
    length = 1.0
    w = uniform(rng, 0.08, 0.12)
    rh = uniform(rng, 0.1, 0.14)
    jaw = rh * uniform(rng, 0.8, 1.0)
    tilt = np.deg2rad(uniform(rng, 10.0, 20.0))
    handle = LineString([(-length / 2, 0.0), (length / 2, 0.0)]).buffer(w / 2)
    head_a = Point(length / 2, 0.0).buffer(rh, 32)
    slot = affinity.rotate(sbox(0.0, -jaw / 2, rh * 2.5, jaw / 2), tilt, origin=(0, 0), use_radians=True)
    slot = affinity.translate(slot, length / 2 + rh * 0.05, 0.0)
    head_b = Point(-length / 2, 0.0).buffer(rh * uniform(rng, 0.9, 1.1), 32)
    if rng.random() < 0.7:  # 12-point box end
        cut_b = unary_union([regular_polygon(6, jaw * 0.55, (-length / 2, 0.0), p) for p in (0.0, np.pi / 6)])
    else:  # second, smaller open jaw
        slot_b = affinity.rotate(sbox(-rh * 2.5, -jaw * 0.4, 0.0, jaw * 0.4), -tilt, origin=(0, 0), use_radians=True)
        cut_b = affinity.translate(slot_b, -length / 2 - rh * 0.05, 0.0)
    # cut after the union so the handle does not fill the jaws; the opening rounds off knife-edge jaw tips
    outline = unary_union([handle, head_a, head_b]).difference(slot).difference(cut_b)
    outline = outline.buffer(-0.012).buffer(0.012)
    return extrude(outline, uniform(rng, 0.04, 0.055) * (length + 2 * rh))


@register("hammer")
def hammer(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Claw hammer: handle along z, head along x with a round striking face and a curved, split claw."""
    hl = uniform(rng, 2.4, 3.4)
    hr = uniform(rng, 0.12, 0.17)
    size = uniform(rng, 0.24, 0.32)
    face_len = uniform(rng, 0.45, 0.65)
    claw_len = uniform(rng, 0.6, 0.9)
    handle = cylinder(hr, hl, center=[0.0, 0.0, hl / 2], sections=24)
    handle.apply_scale([1.3, 1.0, 1.0])
    z_head = hl + size * 0.6
    block = box([size * 1.2, size * 1.1, size * 1.3], center=[0.0, 0.0, z_head])
    face = cylinder(size * 0.55, face_len, center=[face_len / 2, 0.0, z_head], axis=[1.0, 0.0, 0.0], sections=32)
    # claw: a tapering curved profile in xz, extruded along y, then split by a V-slot
    s = np.linspace(0.0, 1.0, 20)
    cx = -claw_len * s
    cz = z_head - 0.35 * claw_len * s**2
    half = size * 0.6 * (1.0 - 0.75 * s)
    pts = np.concatenate([np.stack([cx, cz + half], 1), np.stack([cx, cz - half], 1)[::-1]])
    claw = extrude(Polygon(pts), size * 1.1)
    claw.apply_transform(rotation([1.0, 0.0, 0.0], np.pi / 2))
    slot = box([claw_len * 1.6, size * 0.3, size * 2.0], center=[-claw_len * 0.8 - size * 0.3, 0.0, z_head - 0.2])
    claw = difference(claw, [slot])
    return [handle, block, face, claw]


@register("key")
def key(rng: np.random.Generator) -> trimesh.Trimesh:
    """Flat key in xy: round or square bow with a ring hole, shoulder, blade with random bitting."""
    blade_len = uniform(rng, 0.55, 0.75)
    bw = uniform(rng, 0.12, 0.16)
    bow_r = uniform(rng, 0.2, 0.28)
    if rng.random() < 0.5:
        bow = Point(-bow_r, 0.0).buffer(bow_r, 40)
    else:
        bow = sbox(-2 * bow_r, -bow_r, 0.0, bow_r).buffer(0.05).buffer(-0.03)
    bow = bow.difference(Point(-bow_r * 1.45, 0.0).buffer(bow_r * 0.3, 24))
    shoulder = sbox(-0.02, -bw * 0.75, 0.06, bw * 0.75)
    n = int(rng.integers(4, 7))
    xs = np.linspace(0.1, blade_len - 0.06, n)
    depths = rng.uniform(0.15, 0.5, n) * bw
    teeth = [(0.0, -bw / 2)]
    for x, d in zip(xs, depths, strict=True):
        teeth += [(x - 0.03, -bw / 2), (x, -bw / 2 + d), (x + 0.03, -bw / 2)]
    blade_pts = [
        *teeth,
        (blade_len, -bw / 2 + bw * 0.3),
        (blade_len, bw / 2 - 0.02),
        (blade_len - 0.04, bw / 2),
        (0.0, bw / 2),
    ]
    blade = Polygon(blade_pts).buffer(0)
    outline = unary_union([bow, shoulder, blade])
    return extrude(outline, uniform(rng, 0.035, 0.045) * (blade_len + 2 * bow_r))


@register("screwdriver")
def screwdriver(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Screwdriver along z: fluted handle, round shaft, flat or cross tip."""
    hl = uniform(rng, 1.0, 1.4)
    hr = uniform(rng, 0.17, 0.24)
    sl = uniform(rng, 1.0, 1.8)
    sr = uniform(rng, 0.055, 0.075)
    zs = np.linspace(0.0, hl, 14)
    _, radii = smooth_curve([0.0, 0.1 * hl, 0.5 * hl, 0.9 * hl, hl], [hr * 0.7, hr, hr * 0.92, hr * 0.95, hr * 0.6], 14)
    handle = tube(np.stack([np.zeros_like(zs), np.zeros_like(zs), zs], 1), radii, sides=36, lobes=6, lobe_depth=0.08)
    shaft = cylinder(sr, sl + 0.1, center=[0.0, 0.0, hl + sl / 2 - 0.05], sections=20)
    tip_len = uniform(rng, 0.15, 0.25)
    if rng.random() < 0.5:  # flat blade: a wedge in xz, thick in y
        wedge = Polygon([(-sr, 0.0), (sr, 0.0), (sr * 1.1, tip_len), (-sr * 1.1, tip_len)])
        tip = extrude(wedge, sr * 1.2)
        tip.apply_transform(rotation([1.0, 0.0, 0.0], np.pi / 2))
    else:  # cross (Phillips) tip: cone
        tip = lathe(np.array([[0.0, 0.0], [sr, 0.0], [sr * 0.35, tip_len], [0.0, tip_len]]))
    tip.apply_translation([0.0, 0.0, hl + sl - 0.02])
    return [handle, shaft, tip]


@register("knife")
def knife(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Kitchen knife in xy: flat blade (straight edge, curved spine to the tip) and a thicker rounded handle."""
    bl = uniform(rng, 0.55, 0.7)
    bh = uniform(rng, 0.1, 0.16)
    hl = uniform(rng, 0.3, 0.4)
    x = np.linspace(0.0, bl, 30)
    spine = bh * np.sqrt(np.clip(1.0 - (x / bl) ** 3, 0.0, 1.0))
    edge_curve = 0.3 * bh * np.clip((x / bl - 0.6) / 0.4, 0.0, 1.0) ** 2
    pts = np.concatenate([np.stack([x, edge_curve], 1), np.stack([x, spine], 1)[::-1]])
    blade = extrude(Polygon(pts).buffer(0.01), uniform(rng, 0.03, 0.04))
    hw = bh * uniform(rng, 0.7, 0.9)
    grip = sbox(-hl, bh * 0.5 - hw / 2, 0.02, bh * 0.5 + hw / 2).buffer(hw * 0.3).buffer(-hw * 0.15)
    handle = extrude(grip, uniform(rng, 0.06, 0.08))
    return [blade, handle]


@register("bolt")
def bolt(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Hex bolt: hexagonal head and a threaded shank (ring threads)."""
    head_r = uniform(rng, 0.8, 1.0)
    head_h = uniform(rng, 0.45, 0.7)
    sr = uniform(rng, 0.42, 0.52)
    length = uniform(rng, 1.8, 3.5)
    pitch = uniform(rng, 0.16, 0.24)
    head = cylinder(head_r, head_h, center=[0.0, 0.0, head_h / 2], sections=6)
    z = np.arange(head_h - 0.05, head_h + length, pitch / 6)
    depth = uniform(rng, 0.06, 0.1)
    phase = np.arange(len(z)) % 6  # crest, crest, flank, root, root, flank (trapezoidal thread)
    r = np.where(phase < 2, sr, np.where((phase == 3) | (phase == 4), sr - depth, sr - depth / 2))
    r[: int(0.3 * length / pitch) * 6] = sr  # unthreaded part below the head
    r[-1] = sr - 0.1
    shank = lathe(np.concatenate([[[0.0, z[0]]], np.stack([r, z], 1), [[0.0, z[-1]]]]), sections=32)
    return [head, shank]


@register("nut")
def nut(rng: np.random.Generator) -> trimesh.Trimesh:
    """Hex nut with a round bore and chamfered corners."""
    r = 1.0
    h = uniform(rng, 0.5, 0.9)
    bore = uniform(rng, 0.4, 0.55)
    ring = regular_polygon(6, r).difference(Point(0, 0).buffer(bore, 40))
    body = extrude(ring, h)
    cham = uniform(rng, 0.08, 0.15)
    f = r * np.cos(np.pi / 6)  # across-flats radius
    cone = lathe(
        np.array(
            [
                [0.0, -h],
                [f + cham, -h],
                [r + 0.3, -h / 2 + cham * 1.5],
                [r + 0.3, h / 2 - cham * 1.5],
                [f + cham, h],
                [0.0, h],
            ]
        ),
        sections=48,
    )
    return trimesh.boolean.intersection([body, cone], engine="manifold")


@register("padlock")
def padlock(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Padlock: rounded body block and a U-shaped shackle (tube) entering its top."""
    bw = uniform(rng, 1.0, 1.4)
    bh = uniform(rng, 0.9, 1.3)
    bd = uniform(rng, 0.4, 0.6)
    rr = min(bw, bh) * 0.15
    body = extrude(sbox(-bw / 2, 0.0, bw / 2, bh).buffer(rr).buffer(-rr * 0.99), bd)
    body.apply_transform(rotation([1.0, 0.0, 0.0], np.pi / 2))  # block in xz, depth along y
    sr = uniform(rng, 0.07, 0.1)
    half = bw * uniform(rng, 0.28, 0.36)
    leg = uniform(rng, 0.25, 0.6)
    th = np.linspace(np.pi, 0.0, 24)
    arc = np.stack([half * np.cos(th), np.zeros_like(th), bh + leg + half * np.sin(th)], 1)
    left = np.stack([np.full(6, -half), np.zeros(6), np.linspace(bh - 0.15, bh + leg, 6)], 1)
    path = np.concatenate([left[:-1], arc, left[::-1][1:] * [-1, 1, 1]])
    shackle = tube(path, np.full(len(path), sr), sides=16)
    return [body, shackle]


def _star_mesh(n: int, r_out: float, r_in: float, thick: float, peak: float) -> trimesh.Trimesh:
    """Faceted toy star: star-polygon prism of ``thick`` with pyramids of height ``peak`` on both faces."""
    a = np.pi / 2 + np.pi * np.arange(2 * n) / n
    rad = np.where(np.arange(2 * n) % 2 == 0, r_out, r_in)
    ring = np.stack([rad * np.cos(a), rad * np.sin(a)], 1)
    m = len(ring)
    top = np.c_[ring, np.full(m, thick / 2)]
    bot = np.c_[ring, np.full(m, -thick / 2)]
    verts = np.concatenate([top, bot, [[0, 0, thick / 2 + peak], [0, 0, -thick / 2 - peak]]])
    i = np.arange(m)
    j = (i + 1) % m
    faces = np.concatenate(
        [
            np.stack([np.full(m, 2 * m), i, j], 1),
            np.stack([np.full(m, 2 * m + 1), m + j, m + i], 1),
            np.stack([i, m + i, m + j], 1),
            np.stack([i, m + j, j], 1),
        ]
    )
    mesh = trimesh.Trimesh(verts, faces, process=True)
    trimesh.repair.fix_normals(mesh)
    return mesh


@register("star")
def star(rng: np.random.Generator) -> trimesh.Trimesh:
    """Faceted 5- or 6-pointed toy star with bevelled faces."""
    n = int(rng.choice([5, 6]))
    return _star_mesh(n, 1.0, uniform(rng, 0.42, 0.55), uniform(rng, 0.12, 0.2), uniform(rng, 0.15, 0.3))


@register("brick")
def brick(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Toy building brick (studded block), 1x2 to 2x4 studs."""
    nx, ny = [(2, 2), (2, 3), (2, 4), (1, 4), (1, 3), (1, 2)][int(rng.integers(0, 6))]
    h = uniform(rng, 1.1, 1.3) if rng.random() < 0.7 else uniform(rng, 0.35, 0.45)
    pitch = uniform(rng, 0.95, 1.05)
    stud_r, stud_h = uniform(rng, 0.26, 0.32), uniform(rng, 0.15, 0.22)
    block = box([ny * pitch, nx * pitch, h], center=[0.0, 0.0, h / 2])
    parts = [block]
    for ix in range(nx):
        for iy in range(ny):
            c = [(iy - (ny - 1) / 2) * pitch, (ix - (nx - 1) / 2) * pitch, h + stud_h / 2 - 0.02]
            parts.append(cylinder(stud_r, stud_h, center=c, sections=24))
    return parts


@register("banana")
def banana(rng: np.random.Generator) -> trimesh.Trimesh:
    """Banana: curved ridged (five-lobed) tube tapering into a stalk at one end and a blunt tip at the other."""
    bend_r = uniform(rng, 1.8, 3.0)
    span = np.deg2rad(uniform(rng, 55.0, 85.0))
    rmax = uniform(rng, 0.28, 0.4)
    s = np.linspace(0.0, 1.0, 48)
    a = -span / 2 + span * s
    path = np.stack([bend_r * np.sin(a), np.zeros_like(s), -bend_r * np.cos(a)], 1)
    radius = rmax * np.clip(np.sin(np.pi * np.clip((s - 0.08) / 0.92, 0, 1)) ** 0.45, 0.0, None)
    radius = np.maximum(radius, np.where(s < 0.15, rmax * 0.3, rmax * 0.12))
    return tube(path, radius, sides=30, lobes=5, lobe_depth=0.06)
