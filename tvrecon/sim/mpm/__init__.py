"""The MLS-MPM solver (paper eq. 5-11; the simulator contract): its config and particle state (:mod:`.state`), the
block grid (:mod:`.block_grid`), materials (:mod:`.materials`), the particle contact (:mod:`.particle_contact`), the
solver (:mod:`.solver`), its naive twin (:mod:`.reference`) and its compiled backend (:mod:`.compiled`)."""

from tvrecon.sim.mpm.solver import MLSMPM
from tvrecon.sim.mpm.state import CONTACT_MODES, MPMConfig, ParticleState, cfl_dt

__all__ = ["CONTACT_MODES", "MLSMPM", "MPMConfig", "ParticleState", "cfl_dt"]
