"""Compact solid classes: cube, ball, torus and gear (the paper's example objects torus and gear among them)."""

from __future__ import annotations

import numpy as np
import trimesh
from shapely.geometry import Point, Polygon

from tvrecon.data.shapes.primitives import (
    box,
    extrude,
    lathe,
    sphere,
    uniform,
)
from tvrecon.data.shapes.registry import register


@register("cube")
def cube(rng: np.random.Generator) -> trimesh.Trimesh:
    """Box with nearly equal sides and randomly rounded edges (convex hull of eight corner balls)."""
    half = np.array([1.0, uniform(rng, 0.85, 1.0), uniform(rng, 0.85, 1.0)])
    rad = uniform(rng, 0.0, 0.2)
    if rad < 0.04:
        return box(2 * half)
    ball_pts = sphere(rad, subdivisions=2).vertices
    corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T * (half - rad)
    return trimesh.convex.convex_hull((corners[:, None, :] + ball_pts[None, :, :]).reshape(-1, 3))


@register("ball")
def ball(rng: np.random.Generator) -> trimesh.Trimesh:
    """Slightly squashed sphere (a ball), semi-axes within 10% of each other."""
    mesh = sphere(1.0, subdivisions=4)
    mesh.apply_scale([1.0, uniform(rng, 0.9, 1.0), uniform(rng, 0.88, 1.0)])
    return mesh


@register("torus")
def torus(rng: np.random.Generator) -> trimesh.Trimesh:
    """Ring torus with major radius 1, random tube radius and a slightly elliptic tube cross-section."""
    minor = uniform(rng, 0.2, 0.45)
    height = minor * uniform(rng, 0.8, 1.2)
    t = np.linspace(0.0, 2 * np.pi, 40)
    loop = np.stack([1.0 + minor * np.cos(t), height * np.sin(t)], axis=1)
    return lathe(loop, sections=64)


def gear_outline(n_teeth: int, r_tip: float, r_root: float, tip_frac: float, root_frac: float) -> Polygon:
    """Spur-gear outline polygon with trapezoidal teeth; fractions are of one tooth pitch."""
    pitch = 2 * np.pi / n_teeth
    flank = (1.0 - tip_frac - root_frac) / 2.0
    pts = []
    for i in range(n_teeth):
        a0 = i * pitch
        for frac, r in (
            (0.0, r_root),
            (root_frac, r_root),
            (root_frac + flank, r_tip),
            (root_frac + flank + tip_frac, r_tip),
        ):
            a = a0 + frac * pitch
            pts.append((r * np.cos(a), r * np.sin(a)))
    return Polygon(pts)


@register("gear")
def gear(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Spur gear: toothed disc with a bore, optional hub on one side and optional lightening holes."""
    n = int(rng.integers(8, 25))
    depth = uniform(rng, 0.12, 0.22) * (1.0 if n < 16 else 0.75)
    thickness = uniform(rng, 0.18, 0.45)
    outline = gear_outline(n, 1.0, 1.0 - depth, uniform(rng, 0.2, 0.35), uniform(rng, 0.25, 0.4))
    bore = uniform(rng, 0.1, 0.25)
    hub = rng.random() < 0.5
    holes = (not hub) and rng.random() < 0.6 and bore < 0.2
    shape = outline.difference(Point(0, 0).buffer(bore, 32))
    if holes:
        k = int(rng.integers(4, 7))
        ring_r = (bore + 1.0 - depth) / 2.0
        hole_r = min(0.55 * (1.0 - depth - bore) / 2.0, ring_r * np.sin(np.pi / k) * 0.6)
        for i in range(k):
            a = 2 * np.pi * i / k
            shape = shape.difference(Point(ring_r * np.cos(a), ring_r * np.sin(a)).buffer(hole_r, 24))
    parts = [extrude(shape, thickness)]
    if hub:
        hub_h = thickness * uniform(rng, 0.4, 0.9)
        hub_shape = Point(0, 0).buffer(bore + uniform(rng, 0.15, 0.3), 48).difference(Point(0, 0).buffer(bore, 32))
        parts.append(extrude(hub_shape, hub_h + thickness * 0.1, z_center=thickness / 2 + hub_h / 2 - thickness * 0.05))
    return parts
