"""Household classes: mug, cup, plate, wineglass, pan, ladle, pear, egg, mushroom, pawn, pencil, dumbbell."""

from __future__ import annotations

import numpy as np
import trimesh

from tvrecon.data.shapes.primitives import (
    cylinder,
    difference,
    lathe,
    radial_profile,
    rotation,
    smooth_curve,
    sphere,
    tube,
    uniform,
    union,
    vessel,
)
from tvrecon.data.shapes.registry import register


def cup_profile(r_bottom: float, r_top: float, height: float, corner: float, n: int = 40) -> tuple[np.ndarray, ...]:
    """Outer profile (r, z) of a flat-bottomed vessel with a rounded bottom corner and a straight (flared) wall."""
    th = np.linspace(-np.pi / 2, 0.0, 10)
    arc_r = r_bottom - corner + corner * np.cos(th)
    arc_z = corner + corner * np.sin(th)
    wall_z = np.linspace(corner, height, n)[1:]
    wall_r = r_bottom + (r_top - r_bottom) * (wall_z - corner) / (height - corner)
    r = np.concatenate([[0.0, (r_bottom - corner) * 0.5], arc_r, wall_r])
    z = np.concatenate([[0.0, 0.0], arc_z, wall_z])
    return r, z


def rim_ring(radius: float, height: float, tube_r: float) -> trimesh.Trimesh:
    """Rolled rim: a torus of tube radius ``tube_r`` around the z axis at (``radius``, ``height``)."""
    t = np.linspace(0.0, 2 * np.pi, 20)
    return lathe(np.stack([radius + tube_r * np.cos(t), height + tube_r * np.sin(t)], axis=1), sections=48)


@register("mug")
def mug(rng: np.random.Generator) -> trimesh.Trimesh:
    """Cylindrical mug with a C-shaped handle (tube) on the side; the cavity is cut after adding the handle."""
    height = uniform(rng, 1.5, 2.4)
    top = uniform(rng, 1.0, 1.08)
    t = uniform(rng, 0.08, 0.11)
    shell, cavity = vessel(*cup_profile(1.0, top, height, 0.15), t)
    ax, az = uniform(rng, 0.45, 0.7), height * uniform(rng, 0.28, 0.4)
    zc = height * uniform(rng, 0.45, 0.55)
    th = np.linspace(-np.pi / 2, np.pi / 2, 30)
    path = np.stack([0.95 + ax * np.cos(th), np.zeros_like(th), zc + az * np.sin(th)], axis=1)
    handle = tube(path, np.full(len(th), uniform(rng, 0.09, 0.13)), sides=20)
    # trim the handle ends poking into the cup (the cavity is shrunk 1% to avoid coincident surfaces)
    cavity.apply_scale([0.99, 0.99, 1.0])
    return union([shell, difference(handle, [cavity])])


@register("cup")
def cup(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Tapered drinking cup (tumbler / paper cup), open top, optional rolled rim, no handle."""
    height = uniform(rng, 1.8, 2.8)
    bottom = uniform(rng, 0.6, 0.8)
    t = uniform(rng, 0.07, 0.1)
    shell, _ = vessel(*cup_profile(bottom, 1.0, height, 0.1), t)
    parts = [shell]
    if rng.random() < 0.5:
        parts.append(rim_ring(1.0 - t * 0.3, height - t * 0.4, t * 0.8))
    return parts


@register("plate")
def plate(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Dinner plate: flat well, curved brim, foot ring; thickness >= 3% of the diameter."""
    flat = uniform(rng, 0.45, 0.65)
    h = uniform(rng, 0.12, 0.2)
    t = uniform(rng, 0.065, 0.08)
    s = np.linspace(0.0, 1.0, 30)
    r = np.concatenate([[0.0], flat + (1.0 - flat) * s])
    z = np.concatenate([[0.0], h * (1.0 - (1.0 - s) ** 2) * (0.7 + 0.3 * s)])
    shell, _ = vessel(r, z, t)
    ring = np.array([[flat * 0.8, 0.02], [flat * 0.8, -0.05], [flat * 0.95, -0.05], [flat, 0.02], [flat * 0.8, 0.02]])
    return [shell, lathe(ring, sections=64)]


@register("wineglass")
def wineglass(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Stemmed glass: tulip bowl (open top), stem, foot disc."""
    depth = uniform(rng, 1.0, 1.6)
    extra = uniform(rng, 0.0, 0.6)
    phi = np.linspace(0.0, np.pi / 2, 40)
    r = np.concatenate([np.sin(phi), [1.0]])
    z = np.concatenate([depth * (1.0 - np.cos(phi)), [depth + extra + 1e-3]])
    shell, _ = vessel(r, z, uniform(rng, 0.12, 0.15))
    stem_h = uniform(rng, 1.0, 2.0)
    stem_r = uniform(rng, 0.08, 0.12)
    foot_r = uniform(rng, 0.6, 0.9)
    shell.apply_translation([0.0, 0.0, stem_h])
    stem = cylinder(stem_r, stem_h + 0.1, center=[0.0, 0.0, stem_h / 2])
    zf, rf = smooth_curve([0.0, 0.13, 0.22, 0.38], [foot_r, foot_r, foot_r * 0.4, stem_r], 12)
    foot = lathe(radial_profile(zf, rf), sections=48)
    return [shell, stem, foot]


@register("pan")
def pan(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Frying pan: shallow flared vessel and a long, slightly rising handle."""
    top = uniform(rng, 1.12, 1.3)
    height = uniform(rng, 0.35, 0.5)
    t = uniform(rng, 0.13, 0.15)
    shell, _ = vessel(*cup_profile(1.0, top, height, 0.16), t)
    length = uniform(rng, 1.4, 2.0)
    rise = uniform(rng, 0.1, 0.5)
    s = np.linspace(0.0, 1.0, 12)
    path = np.stack([top - 0.1 + length * s, np.zeros_like(s), height * 0.75 + rise * s], axis=1)
    handle = tube(path, np.full(len(s), uniform(rng, 0.1, 0.14)), sides=16)
    handle.apply_scale([1.0, 1.3, 1.0])
    return [shell, handle]


@register("ladle")
def ladle(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Ladle: hemispherical bowl and a long handle rising steeply, hooked at the end."""
    depth = uniform(rng, 0.6, 0.9)
    phi = np.linspace(0.0, np.pi / 2, 40)
    shell, _ = vessel(np.sin(phi), depth * (1.0 - np.cos(phi)), uniform(rng, 0.12, 0.14))
    length = uniform(rng, 2.8, 3.6)
    angle = np.deg2rad(uniform(rng, 50.0, 70.0))
    s = np.linspace(0.0, 1.0, 40)
    hook = uniform(rng, 0.2, 0.4)
    x = 0.92 + length * s * np.cos(angle) + hook * np.clip((s - 0.85) / 0.15, 0, 1) ** 2
    z = depth - 0.05 + length * s * np.sin(angle) - hook * 0.5 * np.clip((s - 0.85) / 0.15, 0, 1) ** 2
    handle = tube(np.stack([x, np.zeros_like(s), z], axis=1), np.full(len(s), uniform(rng, 0.09, 0.12)), sides=16)
    return [shell, handle]


@register("pear")
def pear(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Pear: soft union of a large lower and a small upper sphere (concave neck), with a short tilted stem."""
    r2 = uniform(rng, 0.45, 0.65)
    z2 = uniform(rng, 1.6, 2.0)
    top = z2 + r2
    u = np.linspace(0.0, np.pi, 60)
    z = top * (1.0 - np.cos(u)) / 2.0  # denser samples near both poles
    r1 = np.sqrt(np.clip(1.0 - (z - 1.0) ** 2, 0.0, None))
    rr2 = np.sqrt(np.clip(r2**2 - (z - z2) ** 2, 0.0, None))
    k = uniform(rng, 3.0, 5.0)
    r = (r1**k + rr2**k) ** (1.0 / k)
    r[0] = r[-1] = 0.0
    body = lathe(np.stack([r, z], axis=1), sections=48)
    stem = cylinder(0.05, 0.5, center=[0.0, 0.0, top + 0.15], sections=12)
    tilt = uniform(rng, -0.4, 0.4)
    stem.apply_transform(trimesh.transformations.rotation_matrix(tilt, [1.0, 0.0, 0.0], [0.0, 0.0, top - 0.05]))
    return [body, stem]


@register("egg")
def egg(rng: np.random.Generator) -> trimesh.Trimesh:
    """Egg: surface of revolution with one blunt and one pointed end."""
    b = uniform(rng, 0.68, 0.8)
    k = uniform(rng, 0.1, 0.22)
    th = np.linspace(0.0, np.pi, 60)
    z = -np.cos(th)
    r = b * np.sin(th) * (1.0 - k * z)
    r[0] = r[-1] = 0.0
    return lathe(np.stack([r, z], axis=1), sections=48)


@register("mushroom")
def mushroom(rng: np.random.Generator) -> trimesh.Trimesh:
    """Mushroom: tapered stem and a domed cap with an overhanging rim (one lathe profile)."""
    hs = uniform(rng, 0.8, 1.4)
    rs0, rs1 = uniform(rng, 0.28, 0.42), uniform(rng, 0.2, 0.3)
    rc = uniform(rng, 0.9, 1.25)
    hc = uniform(rng, 0.45, 0.9)
    rim = uniform(rng, 0.12, 0.22)
    phi = np.linspace(0.0, np.pi / 2, 30)
    dome = np.stack([rc * np.cos(phi), hs + rim + hc * np.sin(phi)], axis=1)
    prof = np.concatenate(
        [
            [[0.0, 0.0], [rs0 * 0.9, 0.0], [rs0, 0.05]],
            [[rs1, hs], [rc * 0.85, hs + 0.02], [rc * 0.98, hs + rim * 0.4]],
            dome,
        ]
    )
    prof[-1, 0] = 0.0
    return lathe(prof, sections=48)


@register("pawn")
def pawn(rng: np.random.Generator) -> trimesh.Trimesh:
    """Chess pawn: base with a bevel, tapered body, collar and a ball head."""
    base = uniform(rng, 0.9, 1.1)
    body_h = uniform(rng, 0.9, 1.4)
    neck = uniform(rng, 0.25, 0.35)
    head = uniform(rng, 0.38, 0.48)
    z_c = 0.35 + body_h + 0.12
    start = -np.arccos(neck * 0.8 / head)  # the head arc starts where its radius equals the collar's top radius
    angles = np.linspace(start, np.pi / 2, 20)
    z_head = z_c + 0.08 - head * np.sin(start)  # sphere centre: arc start sits just above the collar
    head_pts = np.stack([head * np.cos(angles), z_head + head * np.sin(angles)], axis=1)
    zb, rb = smooth_curve([0.35, 0.35 + body_h * 0.5, 0.35 + body_h], [base * 0.7, neck * 1.35, neck], 16)
    prof = np.concatenate(
        [
            [[0.0, 0.0], [base, 0.0], [base, 0.12], [base * 0.88, 0.2], [base * 0.75, 0.28]],
            np.stack([rb, zb], axis=1),
            [[neck + 0.22, z_c - 0.06], [neck + 0.22, z_c], [neck * 0.8, z_c + 0.06]],
            head_pts,
        ]
    )
    prof[-1, 0] = 0.0
    return lathe(prof, sections=48)


@register("pencil")
def pencil(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Hexagonal pencil along z: sharpened conical tip, metal ferrule and eraser."""
    r = 0.35
    length = uniform(rng, 5.0, 8.0)
    tip = uniform(rng, 0.8, 1.2)
    body = cylinder(r, length, center=[0.0, 0.0, length / 2], sections=6)
    body.apply_transform(rotation([0.0, 0.0, 1.0], uniform(rng, 0.0, np.pi / 3)))
    cone = lathe(np.array([[0.0, -tip], [0.06, -tip + 0.02], [r * 1.02, 0.0], [r * 1.02, 0.05], [0.0, 0.05]]))
    ferrule = cylinder(r * 0.98, 0.45, center=[0.0, 0.0, length + 0.2], sections=32)
    eraser = cylinder(r * 0.9, 0.4, center=[0.0, 0.0, length + 0.6], sections=32)
    return [body, cone, ferrule, eraser] if rng.random() < 0.7 else [body, cone]


@register("dumbbell")
def dumbbell(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Dumbbell along x: a bar and two weights (round discs, hexagonal plates or balls)."""
    bar_r = uniform(rng, 0.16, 0.24)
    gap = uniform(rng, 1.0, 1.6)
    kind = int(rng.integers(0, 3))
    wr = uniform(rng, 0.6, 0.9)
    ww = uniform(rng, 0.4, 0.7)
    parts = [cylinder(bar_r, gap + 2 * ww, axis=[1.0, 0.0, 0.0], sections=24)]
    for sgn in (-1.0, 1.0):
        c = [sgn * (gap / 2 + ww / 2), 0.0, 0.0]
        if kind == 2:
            parts.append(sphere(wr * 0.8, center=c, subdivisions=3))
        else:
            parts.append(cylinder(wr, ww, center=c, axis=[1.0, 0.0, 0.0], sections=6 if kind == 1 else 40))
    return parts
