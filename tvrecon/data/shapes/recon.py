"""Builders of the paper's reconstruction classes (except cube and gear, in solids.py): bottle, bowl, can,
conditioner, fork, pepsi, spoon, scissors."""

from __future__ import annotations

import numpy as np
import trimesh
from shapely.geometry import LineString, Point, Polygon
from shapely.ops import unary_union

from tvrecon.data.shapes.primitives import (
    box,
    cylinder,
    difference,
    extrude,
    lathe,
    radial_profile,
    refine,
    rotation,
    smooth_curve,
    uniform,
    union,
    vessel,
)
from tvrecon.data.shapes.registry import register


@register("bottle")
def bottle(rng: np.random.Generator) -> trimesh.Trimesh:
    """Round bottle: body, smooth shoulder, neck with a lip ring, screw cap (all one lathe profile)."""
    body = uniform(rng, 2.0, 3.2)
    waist = uniform(rng, 0.88, 1.0)
    shoulder = uniform(rng, 0.5, 1.1)
    neck_r = uniform(rng, 0.28, 0.42)
    neck_h = uniform(rng, 0.35, 0.8)
    cap_h = uniform(rng, 0.25, 0.45)
    zs = body + shoulder
    knots_z = [0.0, 0.08, 0.25, body * 0.5, body, body + 0.55 * shoulder, zs, zs + neck_h * 0.6]
    knots_r = [0.9, 0.98, 1.0, waist, 1.0, 0.35 + 0.65 * neck_r + 0.1, neck_r, neck_r]
    z, r = smooth_curve(knots_z, knots_r, 60)
    lip_z = zs + neck_h * 0.6
    top = zs + neck_h + cap_h
    tail = np.array(
        [
            [neck_r * 1.15, lip_z],
            [neck_r * 1.15, lip_z + 0.06],
            [neck_r, lip_z + 0.06],
            [neck_r, zs + neck_h],
            [neck_r * 1.1, zs + neck_h],
            [neck_r * 1.1, top - 0.04],
            [neck_r * 1.06, top],
        ]
    )
    prof = radial_profile(np.concatenate([z, tail[:, 1]]), np.concatenate([r, tail[:, 0]]))
    return lathe(prof, sections=48)


@register("bowl")
def bowl(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Open bowl: elliptic-arc wall with a flat bottom and a foot ring, wall >= 3.5% of the diameter."""
    flat = uniform(rng, 0.2, 0.45)
    depth = uniform(rng, 0.45, 0.85)
    phi_max = np.deg2rad(uniform(rng, 70.0, 90.0))
    phi = np.linspace(0.0, phi_max, 60)
    r = np.concatenate([[0.0], flat + (1.0 - flat) * np.sin(phi) / np.sin(phi_max)])
    z = np.concatenate([[0.0], depth * (1.0 - np.cos(phi))])
    shell, _ = vessel(r, z, uniform(rng, 0.075, 0.1))
    parts = [shell]
    if rng.random() < 0.7:
        ring = np.array([[flat * 0.75, 0.02], [flat * 0.75, -0.07], [flat * 1.0, -0.07], [flat * 1.05, 0.02]])
        parts.append(lathe(np.concatenate([ring, ring[:1]]), sections=48))
    return parts


@register("can")
def can(rng: np.random.Generator) -> trimesh.Trimesh:
    """Tin can: straight cylinder with rolled rims, recessed lids and optional stiffening beads."""
    height = uniform(rng, 1.2, 2.6)
    z = np.linspace(0.06, height - 0.06, 100)
    r = np.ones_like(z)
    for c in (0.06, height - 0.06):
        r += 0.035 * np.exp(-(((z - c) / 0.04) ** 2))
    n_beads = int(rng.integers(0, 7))
    bead_depth = uniform(rng, 0.02, 0.04)
    for c in np.linspace(0.2 * height, 0.8 * height, n_beads):
        r -= bead_depth * np.exp(-(((z - c) / 0.045) ** 2))
    recess = uniform(rng, 0.03, 0.07)
    lid_r = uniform(rng, 0.86, 0.92)
    prof = np.concatenate(
        [
            [[0.0, recess], [lid_r, recess], [lid_r + 0.02, 0.0], [1.03, 0.0]],
            np.stack([r, z], axis=1),
            [[1.03, height], [lid_r + 0.02, height], [lid_r, height - recess], [0.0, height - recess]],
        ]
    )
    return lathe(prof, sections=48)


@register("pepsi")
def pepsi(rng: np.random.Generator) -> trimesh.Trimesh:
    """Soda can: tall, tapered bottom with a concave dome and standing ring, necked top with a rim and recessed lid."""
    height = uniform(rng, 3.2, 3.9)
    neck = uniform(rng, 0.76, 0.86)
    foot = uniform(rng, 0.62, 0.74)
    bottom_taper = uniform(rng, 0.18, 0.3)
    top_taper = uniform(rng, 0.3, 0.5)
    z, r = smooth_curve(
        [0.0, bottom_taper * 0.5, bottom_taper, height - top_taper - 0.1, height - top_taper * 0.45, height - 0.08],
        [foot, 0.5 * (foot + 1.0) + 0.05, 1.0, 1.0, 0.5 * (1.0 + neck), neck],
        90,
    )
    dome = uniform(rng, 0.12, 0.25)
    prof = np.concatenate(
        [
            [[0.0, dome], [foot * 0.6, dome * 0.7], [foot * 0.92, 0.02]],
            np.stack([r, z], axis=1),
            [[neck + 0.03, height - 0.05], [neck + 0.03, height], [neck - 0.08, height], [neck - 0.1, height - 0.08]],
            [[0.0, height - 0.08]],
        ]
    )
    return lathe(prof, sections=48)


@register("conditioner")
def conditioner(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Shampoo/conditioner bottle: oval-section body tapering to a flip-top cap; sometimes standing on its cap."""
    body = uniform(rng, 2.4, 3.4)
    belly = uniform(rng, 0.92, 1.08)
    top_r = uniform(rng, 0.42, 0.55)
    oval = uniform(rng, 0.45, 0.7)
    z, r = smooth_curve(
        [0.0, 0.06, 0.3, body * 0.55, body * 0.88, body],
        [0.85, 0.96, 1.0, belly, 0.5 * (belly + top_r) + 0.08, top_r],
        100,
    )
    shell = lathe(radial_profile(z, r), sections=48)
    shell.apply_scale([1.0, oval, 1.0])
    cap_h = uniform(rng, 0.35, 0.6)
    cap_r = top_r * uniform(rng, 1.0, 1.15)
    cz, cr = smooth_curve([0.0, cap_h * 0.7, cap_h], [cap_r, cap_r, cap_r * 0.8], 20)
    cap = lathe(radial_profile(cz + body - 0.05, cr), sections=48)
    cap.apply_scale([1.0, max(oval * 1.2, 0.6), 1.0])
    parts = [shell, cap]
    if rng.random() < 0.5:  # flip-top hinge lid ridge
        parts.append(box([cap_r * 0.5, 0.08, 0.08], center=[cap_r * 0.7, 0.0, body - 0.05 + cap_h * 0.9]))
    if rng.random() < 0.35:  # "tottle": stored upside down on its cap
        for p in parts:
            p.apply_transform(rotation([1.0, 0.0, 0.0], np.pi))
    return parts


def _handle_polygon(length: float, w_end: float, w_neck: float, n: int = 40) -> Polygon:
    """Utensil handle along +x from 0 to ``length``: widest near the end, narrowing to ``w_neck``."""
    x = np.linspace(0.0, length, n)
    t = x / length
    half = 0.5 * (w_neck + (w_end - w_neck) * np.sin(np.pi * np.clip(1.1 * (1.0 - t), 0, 1) / 2.0) ** 0.8)
    pts = np.concatenate([np.stack([x, half], 1), np.stack([x, -half], 1)[::-1]])
    return Polygon(pts).buffer(w_end * 0.15).buffer(-w_end * 0.1)


def _bend(mesh: trimesh.Trimesh, fn, max_edge: float) -> trimesh.Trimesh:
    """Subdivide so long faces follow, then displace z by ``fn(x)``."""
    out = refine(mesh, max_edge)
    out.vertices[:, 2] += fn(out.vertices[:, 0])
    return out


@register("fork")
def fork(rng: np.random.Generator) -> trimesh.Trimesh:
    """Table fork lying in xy: tapered handle, widening head, 3-4 tines (width >= 3%, thickness >= 3.5% of length)."""
    lh = uniform(rng, 0.5, 0.62)
    neck = uniform(rng, 0.04, 0.055)
    head_len = uniform(rng, 0.08, 0.12)
    n = int(rng.integers(3, 5))
    w = uniform(rng, 0.032, 0.042)
    gap = uniform(rng, 0.018, 0.03)
    width = n * w + (n - 1) * gap
    tine_len = uniform(rng, 0.15, 0.23)
    thick = uniform(rng, 0.035, 0.045)
    x0 = lh + head_len
    head = Polygon(
        [
            (lh - 0.02, neck / 2),
            (lh + head_len * 0.5, width * 0.42),
            (x0 + 0.01, width / 2),
            (x0 + 0.01, -width / 2),
            (lh + head_len * 0.5, -width * 0.42),
            (lh - 0.02, -neck / 2),
        ]
    ).buffer(0.008)
    tines = [
        LineString([(x0 - 0.01, y), (x0 + tine_len - w / 2, y)]).buffer(w / 2, quad_segs=8)
        for y in -width / 2 + w / 2 + np.arange(n) * (w + gap)
    ]
    outline = unary_union([_handle_polygon(lh, uniform(rng, 0.07, 0.1), neck), head, *tines])
    flat = extrude(outline, thick)
    bend = uniform(rng, 0.0, 0.06)
    return _bend(flat, lambda x: bend * np.tanh((x - lh) / 0.12), max_edge=0.03)


@register("spoon")
def spoon(rng: np.random.Generator) -> trimesh.Trimesh:
    """Spoon: rising handle and an ellipsoidal half-shell bowl with real wall thickness."""
    lh = uniform(rng, 0.5, 0.65)
    a = uniform(rng, 0.11, 0.16)
    b = uniform(rng, 0.065, 0.095)
    c = uniform(rng, 0.03, 0.055)
    t = uniform(rng, 0.035, 0.045)
    cx = lh + a - 0.01
    phi = np.linspace(-np.pi / 2, 0.0, 16)
    outer = lathe(np.concatenate([np.stack([np.cos(phi), np.sin(phi)], 1), [[0.0, 0.0]]]), sections=40)
    outer.apply_scale([a, b, c + t])  # lower half-ellipsoid with a flat top at z = 0
    phi = np.linspace(-np.pi / 2, np.pi / 2, 24)
    inner = lathe(np.stack([np.cos(phi), np.sin(phi)], 1), sections=40)
    inner.apply_scale([a - t, b - t, c])
    bowl_ = difference(outer, [inner])
    bowl_.apply_translation([cx, 0.0, 0.0])
    handle = extrude(_handle_polygon(lh + 0.02, uniform(rng, 0.06, 0.09), uniform(rng, 0.03, 0.045)), t, -t / 2)
    mesh = union([bowl_, handle])
    rise = uniform(rng, 0.03, 0.1)
    return _bend(mesh, lambda x: rise * np.clip((lh - x) / lh, 0.0, 1.0) ** 1.5, max_edge=0.03)


@register("scissors")
def scissors(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Scissors: two levers (blade, shank, finger ring) in two overlapping layers, crossing at a pivot screw."""
    lb = uniform(rng, 0.9, 1.3)
    lh = uniform(rng, 0.45, 0.65)
    w0 = uniform(rng, 0.12, 0.17)
    wt = uniform(rng, 0.05, 0.07)
    opening = np.deg2rad(uniform(rng, 4.0, 30.0))
    ro = uniform(rng, 0.15, 0.21)
    ri = ro - uniform(rng, 0.055, 0.075)
    total = lb + lh + 2 * ro
    t = total * uniform(rng, 0.032, 0.04)
    shank_w = uniform(rng, 0.06, 0.08)
    parts = []
    for layer, sign in enumerate((1.0, -1.0)):
        ang = sign * opening / 2
        x = np.linspace(-0.1, lb, 30)
        half = 0.5 * (wt + (w0 - wt) * np.clip(1.0 - x / lb, 0.0, 1.0) ** 0.8)
        blade = Polygon(np.concatenate([np.stack([x, half], 1), np.stack([x, -half], 1)[::-1]])).buffer(0.015)
        blade = trimesh.transformations.transform_points(
            np.c_[np.asarray(blade.exterior.coords), np.zeros(len(blade.exterior.coords))],
            rotation([0.0, 0.0, 1.0], ang),
        )[:, :2]
        ring_c = np.array([-lh, -sign * (ro + 0.03 + lh * np.sin(opening / 2))])
        elbow = np.array([-0.3 * lh * np.cos(ang), -0.3 * lh * np.sin(ang)])
        shank = LineString([(0.0, 0.0), tuple(elbow), tuple(ring_c)]).buffer(shank_w / 2)
        lever = unary_union([Polygon(blade), Point(0, 0).buffer(w0 * 0.55), shank, Point(ring_c).buffer(ro, 32)])
        lever = lever.difference(Point(ring_c).buffer(ri, 32))
        parts.append(extrude(lever, t, z_center=layer * 0.85 * t))
    parts.append(cylinder(w0 * 0.3, 1.9 * t, center=[0.0, 0.0, 0.42 * t], sections=24))
    return parts
