"""EIP tactile simulation: MLS-MPM in torch, sensor pad, press protocol (paper section 3).

Public names::

    MPMConfig, ParticleState, MLSMPM, cfl_dt           # the solver contract (mpm.py)
    SphereCollider, PlaneCollider, MeshCollider          # rigid colliders (colliders.py)
    SensorConfig, sensor_frame                           # the pad (sensor.py)
    PressConfig, TactileReading, EIPSimulator            # the press protocol, Algorithm 1 (press.py)
    terminal_chamfer                                     # its terminal check, paper eq. 12 (stop_rules.py)

The press protocol by concept: ``placement`` (where the pad goes), ``stop_rules`` (when it stops), ``press_run``
(the solver loop, each touch approach -> press -> release -> done); ``press`` ties them together.
    ContactPatch, contact_patch, reading_patch           # a touch mapped back to 3D world points (contact.py)

Sensor outputs beyond displacement live in their own modules: ``forces`` (per-taxel force field, also on every
reading as ``force_field``), ``markers`` (marker-displacement images), ``photometric`` (GelSight-style RGB).
"""

from tvrecon.sim.colliders import MeshCollider, PlaneCollider, SphereCollider
from tvrecon.sim.contact import ContactPatch, contact_patch, reading_patch
from tvrecon.sim.mpm import MLSMPM, MPMConfig, ParticleState, cfl_dt
from tvrecon.sim.press import EIPSimulator, PressConfig, TactileReading, chamfer_eq13, terminal_chamfer
from tvrecon.sim.sensor import SensorConfig, alpha_profile, pad_lattice, sensor_frame

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
    "chamfer_eq13",  # deprecated alias of terminal_chamfer
    "pad_lattice",
    "sensor_frame",
    "terminal_chamfer",
]
