"""Rigid bodies: colliders as signed distance functions (:mod:`.colliders`), their action on the grid nodes
(:mod:`.grid_contact`), and the mesh collider's distance, sign, region and voxelization."""

from tvrecon.sim.bodies.colliders import Collider, MeshCollider, PlaneCollider, SphereCollider

__all__ = ["Collider", "MeshCollider", "PlaneCollider", "SphereCollider"]
