"""The press protocol of paper Algorithm 1: its config (:mod:`.config`), where the pad goes (:mod:`.placement`), when
it stops (:mod:`.stop_rules`, paper eq. 12), the solver loop (:mod:`.loop`), what it returns (:mod:`.reading`) and
the public entry point :class:`EIPSimulator` (:mod:`.simulator`)."""

from tvrecon.sim.press.config import PressConfig
from tvrecon.sim.press.reading import TactileReading, reading_patch
from tvrecon.sim.press.simulator import EIPSimulator
from tvrecon.sim.press.stop_rules import terminal_chamfer

__all__ = ["EIPSimulator", "PressConfig", "TactileReading", "reading_patch", "terminal_chamfer"]
