"""Seeded, smooth, volume-preserving random deformation of a mesh (augmentation, paper Table 1 caption).

The mesh is carried along the flow of a random low-frequency *divergence-free* velocity field
``u(x) = sum_k (w_k x b_k) cos(w_k . x + phi_k)`` (the curl of a random Fourier vector potential) for unit time,
integrated with RK4. The flow of a smooth field is a diffeomorphism, so the surface cannot self-intersect, and a
divergence-free flow preserves volume exactly in the continuum (up to the flat-face discretization here). A mild
volume-preserving anisotropic scaling (product of the axis scales = 1) adds proportion changes. Large faces are
first refined (crack-free, manifold3d) so that flat sides bend smoothly instead of staying planar.
"""

from __future__ import annotations

import logging

import numpy as np
import trimesh

from tvrecon.data.shapes.primitives import refine

log = logging.getLogger(__name__)

MAX_FACES = 30_000  # refinement budget; beyond it the mesh is deformed as is


def _field(points: np.ndarray, freqs: np.ndarray, coefs: np.ndarray, phases: np.ndarray) -> np.ndarray:
    """Divergence-free velocity at ``points`` (N,3): sum_k coefs_k cos(freqs_k . x + phases_k); coefs_k _|_ freqs_k."""
    arg = points @ freqs.T + phases[None, :]  # (N, K)
    return np.cos(arg) @ coefs  # (N, 3)


def _refined(mesh: trimesh.Trimesh, max_edge: float) -> trimesh.Trimesh:
    """Copy of ``mesh`` with edges split down to ``max_edge`` (relaxed as needed to stay under MAX_FACES)."""
    if len(mesh.faces) >= MAX_FACES or float(mesh.edges_unique_length.max()) <= max_edge:
        return mesh.copy()
    for _ in range(6):
        try:
            out = refine(mesh, max_edge)
        except ValueError:  # not a clean manifold (e.g. a repaired user mesh): deform as is
            return mesh.copy()
        if len(out.faces) <= MAX_FACES:
            return out
        max_edge *= 1.5
    return mesh.copy()


def deform_mesh(
    mesh: trimesh.Trimesh,
    seed: int,
    strength: float = 0.1,
    modes: int = 4,
    steps: int = 8,
) -> trimesh.Trimesh:
    """Smooth random deformation of ``mesh``, deterministic in ``seed``.

    Args:
        mesh: input mesh (V vertices, F faces); watertight input gives watertight output (connectivity is kept,
            only vertices move, after an optional crack-free refinement of long edges).
        seed: non-negative int; the same seed gives the same deformation.
        strength: displacement scale as a fraction of the mesh's largest extent (0 = unchanged copy, 0.1 default,
            at most 0.5). Also sets the anisotropic scaling spread (log-std 0.5 * strength).
        modes: number of random Fourier modes (low frequency: 0.5 to 1.2 cycles across the object).
        steps: RK4 steps of the flow integration.

    Returns:
        A new trimesh (V' >= V vertices), not re-normalized: the caller re-centres / re-scales if needed.
    """
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError("deform_mesh expects a non-empty trimesh.Trimesh with faces")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed!r}")
    if not np.isfinite(strength) or not 0.0 <= strength <= 0.5:
        raise ValueError(f"strength must be in [0, 0.5] (fraction of the object size), got {strength}")
    if modes < 1 or steps < 1:
        raise ValueError(f"modes and steps must be >= 1, got {modes}, {steps}")
    if strength == 0.0:
        return mesh.copy()
    extent = float(np.max(mesh.extents))
    if not np.isfinite(extent) or extent <= 0:
        raise ValueError("cannot deform a mesh with zero or non-finite extent")
    rng = np.random.default_rng([int(seed), 7919])
    out = _refined(mesh, extent / 16.0)

    # random modes: direction uniform on the sphere, 0.5-1.2 cycles per object extent
    dirs = rng.normal(size=(modes, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    freqs = dirs * (2 * np.pi * rng.uniform(0.5, 1.2, size=(modes, 1)) / extent)
    coefs = np.cross(freqs, rng.normal(size=(modes, 3)))  # w x b: perpendicular to w -> divergence-free
    coefs *= strength * extent / np.abs(coefs).sum()  # bound on |u| and on the total displacement
    phases = rng.uniform(0.0, 2 * np.pi, size=modes)

    centre = out.bounds.mean(axis=0)
    x = np.asarray(out.vertices, dtype=np.float64) - centre
    h = 1.0 / steps
    for _ in range(steps):
        k1 = _field(x, freqs, coefs, phases)
        k2 = _field(x + 0.5 * h * k1, freqs, coefs, phases)
        k3 = _field(x + 0.5 * h * k2, freqs, coefs, phases)
        k4 = _field(x + h * k3, freqs, coefs, phases)
        x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)

    log_s = rng.normal(0.0, 0.5 * strength, size=3)
    x *= np.exp(log_s - log_s.mean())  # det = 1: volume-preserving
    return trimesh.Trimesh(x + centre, np.asarray(out.faces), process=False)
