"""EIP tactile simulation: MLS-MPM in torch, sensor pad, press protocol (paper section 3).

Rooms, bottom to top (each imports only the ones below it)::

    bodies/   SphereCollider, PlaneCollider, MeshCollider   rigid colliders, grid contact, mesh sdf / sign / voxels
    mpm/      MPMConfig, ParticleState, MLSMPM, cfl_dt      the solver contract; particle contact; compiled backend
    sensor/   SensorConfig, sensor_frame, ContactPatch      the pad, presets, contact patch, forces, markers, RGB
    press/    PressConfig, TactileReading, EIPSimulator     Algorithm 1: placement, stop rules (eq. 12), the loop

``plots`` draws readings; ``python -m tvrecon.sim`` is the press CLI.
"""

from tvrecon.sim.bodies import MeshCollider, PlaneCollider, SphereCollider
from tvrecon.sim.mpm.solver import MLSMPM
from tvrecon.sim.mpm.state import MPMConfig, ParticleState, cfl_dt
from tvrecon.sim.press.config import PressConfig
from tvrecon.sim.press.reading import TactileReading, reading_patch
from tvrecon.sim.press.simulator import EIPSimulator
from tvrecon.sim.press.stop_rules import terminal_chamfer
from tvrecon.sim.sensor.elastic_pad import SensorConfig, alpha_profile, pad_lattice, sensor_frame
from tvrecon.sim.sensor.patch import ContactPatch, contact_patch

__all__ = [
    "ContactPatch",
    "contact_patch",
    "reading_patch",
    "MLSMPM",
    "EIPSimulator",
    "MPMConfig",
    "MeshCollider",
    "ParticleState",
    "PlaneCollider",
    "PressConfig",
    "SensorConfig",
    "SphereCollider",
    "TactileReading",
    "alpha_profile",
    "cfl_dt",
    "pad_lattice",
    "sensor_frame",
    "terminal_chamfer",
]
