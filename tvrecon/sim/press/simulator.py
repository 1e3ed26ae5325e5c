"""The EIP press protocol (paper Algorithm 1): place a sensor pad against a mesh and press until a stop rule.

Coordinates. For every touch the simulation domain ``[0, 1)^3`` (``n_grid`` cells spanning ``domain_size`` world
units) is attached to the *sensor frame* (see :func:`tvrecon.sim.sensor.elastic_pad.sensor_frame`): domain x, y follow
the contact plane and domain -z is the press direction, so the pad is aligned with the grid whatever the world
direction. The domain point (0.5, 0.5, 0.5 + dx / 2) is the *touch point*: laterally the given ``position``, along the
press axis the highest point of the object under the pad's footprint (found by ray casting), so the pad starts
``gap`` cells in front of the first point it will touch. World <-> domain::

    u = R^T (w - origin) / domain_size + c        w = origin + R (u - c) domain_size,   c = (0.5, 0.5, 0.5 + dx / 2)

(the touch plane lies half-way between grid node planes, see :func:`tvrecon.sim.press.placement.touch_z`)

The concepts live in their own modules; this one holds the configuration and the public entry points:

- :mod:`tvrecon.sim.press.placement`: ray casts from the pad's footprint, reach, the default touch point, the data
  pipeline's reachability test (``pad_footprint``, ``pad_reachable``);
- :mod:`tvrecon.sim.press.stop_rules`: the ordered stop rules (travel limit, then the first configured of ``depth`` >
  ``force`` > ``threshold``, the terminal check of Algorithm 1, :func:`terminal_chamfer`); a ``depth`` raises
  ``max_depth`` to ``depth + 0.5`` when shorter (:func:`~tvrecon.sim.press.stop_rules.travel_for_depth`);
- :mod:`tvrecon.sim.press.loop`: the solver loop, each touch going approach -> press -> release -> done, and the
  :class:`TactileReading` it returns.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch
import trimesh
from torch import Tensor

from tvrecon.sim.mpm.compiled.policy import check_compile_setting
from tvrecon.sim.mpm.materials import p_wave_speed
from tvrecon.sim.mpm.state import MPMConfig, cfl_dt
from tvrecon.sim.press import placement
from tvrecon.sim.press.config import PressConfig
from tvrecon.sim.press.loop import PressLoop
from tvrecon.sim.press.reading import TactileReading
from tvrecon.sim.press.setup_pool import SetupPool
from tvrecon.sim.press.stop_rules import travel_for_depth
from tvrecon.sim.sensor.elastic_pad import SensorConfig, _scalar
from tvrecon.utils.config_utils import (
    check_instance,
    check_known_keys,
    field_names,
)
from tvrecon.utils.shape_check import check_shape

__all__ = ["EIPSimulator"]

#: the environment variable that once switched the fused kernels on; now ignored (``PressConfig.compile`` does it)
STALE_COMPILE_ENV = "TVRECON_COMPILE"


def _warn_stale_compile_env() -> None:
    """Warn (FutureWarning, shown once per process by the default filters) when ``TVRECON_COMPILE`` is set: nothing
    reads it any more, so a run that relies on it would silently press eager."""
    if STALE_COMPILE_ENV in os.environ:
        warnings.warn(
            f"the environment variable {STALE_COMPILE_ENV}={os.environ[STALE_COMPILE_ENV]!r} is no longer read: "
            "switch the fused solver kernels with the press config (press.compile=true, PressConfig(compile=True) or "
            "EIPSimulator(compile=True)) or `python -m tvrecon.data.generate ... compile=true`",
            FutureWarning,
            stacklevel=2,
        )


class EIPSimulator:
    """Press a sensor pad onto meshes with MLS-MPM and read the tactile images.

    Args:
        sensor: pad geometry and material (default :class:`SensorConfig`).
        press: press protocol (default :class:`PressConfig`).
        device: torch device of the simulation.
        compile: run the solver's no-grad steps with the fused ``torch.compile`` kernels (``MLSMPM(compile=True)``):
            None (default) -> ``press.compile``; True, False or ``"auto"`` replaces ``press.compile`` in this
            simulator's config (a call's ``compile=`` override still wins, as for every :class:`PressConfig` field).
            ``"auto"`` (``PressConfig``'s default) compiles a call of many touches on a CPU with a C++ compiler
            (:func:`tvrecon.sim.mpm.compiled.policy.resolve_compile`); a few touches stay eager. Readings equal the
            eager ones to float32 round-off and the data cache key does not change (see ``PressConfig.compile``).
            The environment variable ``TVRECON_COMPILE`` is no longer read (a warning says so when it is set).
        setup_threads: threads building a call's touches (frame, touch point, mesh collider: host work, about 0.1-0.3
            CPU-s a touch). None (default): the host's cores on a GPU, torch's thread count on the CPU. The
            placements, and so the readings, do not depend on it.
        setup_processes: N > 0 places a call's touches in N spawned worker processes instead
            (:mod:`tvrecon.sim.press.setup_pool`: one interpreter each, so the set-up's Python and GIL-holding parts
            run side by side; the colliders' tables are moved to ``device``). Started on the first call of two or
            more touches and kept for the simulator's life. 0 (default): threads. The same placements bit for bit.
    """

    def __init__(
        self,
        sensor: SensorConfig | None = None,
        press: PressConfig | None = None,
        device: torch.device | str = "cpu",
        compile: bool | str | None = None,
        setup_threads: int | None = None,
        setup_processes: int = 0,
    ) -> None:
        self.sensor = sensor if sensor is not None else SensorConfig()
        self.cfg = press if press is not None else PressConfig()
        check_instance(self.sensor, SensorConfig, "EIPSimulator sensor")
        check_instance(self.cfg, PressConfig, "EIPSimulator press")
        self.device = torch.device(device)
        if compile is not None:
            check_compile_setting(compile, "EIPSimulator compile")
            if compile != self.cfg.compile:
                self.cfg = dataclasses.replace(self.cfg, compile=compile)
        _warn_stale_compile_env()
        if setup_threads is not None and (
            isinstance(setup_threads, bool) or not isinstance(setup_threads, int) or setup_threads < 1
        ):
            raise ValueError(f"EIPSimulator setup_threads must be a positive int or None, got {setup_threads!r}")
        self.setup_threads = setup_threads
        if isinstance(setup_processes, bool) or not isinstance(setup_processes, int) or setup_processes < 0:
            raise ValueError(
                f"EIPSimulator setup_processes must be a whole number >= 0 (0: threads), got {setup_processes!r}"
            )
        self.setup_processes = setup_processes
        self._setup_pool: SetupPool | None = None

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_setup_pool"] = None  # worker processes do not travel; a copy starts its own
        return state

    def close(self) -> None:
        """Stop the set-up worker processes, if any (``setup_processes``; a later call starts them again)."""
        if self._setup_pool is not None:
            self._setup_pool.close()

    def _setup_workers(self, T: int) -> int:
        """Threads placing the T touches of one call (each touch's collider is built on the CPU: scipy, numpy and
        embree release the GIL for most of it). ``setup_threads`` when given; otherwise, on a GPU, the host's cores
        (the device waits for the host's set-up: it is most of a large batch's time), and on the CPU torch's thread
        budget (1 in ``generate``'s workers: one process per core)."""
        if self.setup_threads is not None:
            return max(1, min(T, self.setup_threads))
        if self.device.type == "cpu":
            return max(1, min(T, torch.get_num_threads()))
        return max(1, min(T, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1))

    @property
    def compile(self) -> bool | str:
        """Whether presses run the solver's fused kernels by default: ``cfg.compile``, True, False or ``"auto"`` (a
        call resolves it with its own touches: eager; a call may override it)."""
        return self.cfg.compile

    # ------------------------------------------------------------------ configuration
    def _configs(self, overrides: dict) -> tuple[SensorConfig, PressConfig]:
        """The sensor and press configs of one call: the simulator's with ``overrides``; a ``depth`` stop rule
        raises ``max_depth`` to ``depth + 0.5`` cells when shorter (:func:`travel_for_depth`)."""
        s_names, p_names = set(field_names(SensorConfig)), set(field_names(PressConfig))
        check_known_keys(overrides, s_names | p_names, "press")
        s = dataclasses.replace(self.sensor, **{k: v for k, v in overrides.items() if k in s_names})
        p = dataclasses.replace(self.cfg, **{k: v for k, v in overrides.items() if k in p_names})
        return s, travel_for_depth(p)

    @staticmethod
    def wave_speed(sensor: SensorConfig) -> float:
        """Elastic P-wave speed sqrt((lambda + 2 mu) / rho) in domain units / s."""
        return p_wave_speed(_scalar(sensor.E), _scalar(sensor.nu), float(sensor.rho))

    def _mpm_config(self, s: SensorConfig, p: PressConfig) -> MPMConfig:
        cfg = MPMConfig(
            n_grid=int(p.n_grid),
            dt=p.dt,
            E=s.E,
            nu=s.nu,
            rho=float(s.rho),
            friction=float(p.friction),
            damping=s.damping,
            contact=p.contact,
        )
        if cfg.dt is None:
            probe = MPMConfig(n_grid=int(p.n_grid), E=_scalar(s.E), nu=_scalar(s.nu), rho=float(s.rho))
            cfg.dt = float(cfl_dt(probe))
        return cfg

    # ------------------------------------------------------------------ scene set-up
    def _setup(self, mesh: trimesh.Trimesh, position, direction, s: SensorConfig, p: PressConfig):
        """One touch's :class:`~tvrecon.sim.press.placement.Placement` (frame, touch point, collider)."""
        return placement.place_touch(mesh, position, direction, s, p, self.device)

    # ------------------------------------------------------------------ public API
    def touch_position(self, mesh: trimesh.Trimesh, direction, **overrides) -> Tensor:
        """A touch point the pad reaches from outside along ``direction``: the placement when none is given.

        The pad's footprint (its contact-layer particles, in the press frame) is centred on the line along
        ``direction`` through the centre of the mesh's bounding box. A ray along ``direction`` from outside the
        bounding box through each footprint particle meets the object's first surface; the touch
        point is on the centre line at the highest of these hits (the first point the pad will touch), so the pad
        starts clear of the object however much the surface rises under it. When every ray misses (e.g. the hole
        of a torus), the footprint moves so that its most central particle is over the hit nearest the centre line
        among rays cast over the whole bounding box (:func:`tvrecon.sim.press.placement.touch_position`). (The data
        pipeline samples its own touches, see ``tvrecon.data.touches.policies``.)

        Args:
            mesh: object in world coordinates. direction: (3,) world press direction (into the object).
            **overrides: :class:`SensorConfig` / :class:`PressConfig` fields, as for :meth:`press` (the footprint
                follows the pad's resolution, spacing, ``n_grid`` and ``domain_size``).
        Returns:
            (3,) float32 world point to pass as ``position``.
        Raises:
            ValueError: no ray along ``direction`` meets the mesh (e.g. a flat plane pressed along itself).
        """
        s, p = self._configs(overrides)
        return placement.touch_position(mesh, direction, s, p)

    def press(self, mesh: trimesh.Trimesh, position, direction, **overrides) -> TactileReading:
        """Press the pad onto ``mesh`` at ``position`` along ``direction``.

        Args:
            mesh: object in world coordinates. Watertight, or open (an open box, a plane, a mesh with holes):
                an open mesh is solid behind the first surface the pad meets (``MeshCollider(from_above=True)``).
                A touch that travels past the surface found under the pad without feeling it (a part thinner
                than the grid resolves) warns (RuntimeWarning) instead of returning a silent miss.
            position: (3,) world point on or near the surface; None -> :meth:`touch_position` finds one.
            direction: (3,) world press direction, pointing into the object (any non-zero length).
            **overrides: any :class:`SensorConfig` or :class:`PressConfig` field for this call (E and nu may be
                0-dim tensors requiring grad, ``speed`` too: the image is differentiable w.r.t. them).
        Returns:
            the :class:`TactileReading`.
        """
        direction = placement.as_vec3(direction, "direction")  # a string or a bad shape is named here
        if position is not None:
            position = placement.as_vec3(position, "position")
        if position is None:
            position = self.touch_position(mesh, direction, **overrides)
            reading = self.press_batch([mesh], [position], [direction], **overrides)[0]
            if reading.steps == 0:  # the pad's rays met nothing at the touch point found for it
                raise ValueError(
                    f"the pad finds no surface under its footprint along the direction "
                    f"{np.asarray(direction, dtype=float).tolist()}: the object is thinner than the pad's particle "
                    "spacing seen along it (e.g. a sheet pressed on its edge). Choose another direction, give a "
                    "position, or raise n_grid"
                )
            return reading
        return self.press_batch([mesh], [position], [direction], **overrides)[0]

    def press_batch(
        self, meshes: Sequence[trimesh.Trimesh] | trimesh.Trimesh, positions, directions, **overrides
    ) -> list[TactileReading]:
        """Simulate T touches in one solver loop (one independent grid block per touch).

        Each touch stops at its own terminal condition and then leaves the loop; results equal T calls of
        :meth:`press` up to float round-off.

        Args:
            meshes: T meshes (or one mesh used for every touch), world coordinates.
            positions: (T, 3) world points. directions: (T, 3) world press directions.
        Returns:
            T :class:`TactileReading`.
        """
        s, p = self._configs(overrides)
        return self._run(self._place(meshes, positions, directions, s, p), s, p)

    def place_batch(
        self, meshes: Sequence[trimesh.Trimesh] | trimesh.Trimesh, positions, directions, **overrides
    ) -> list[placement.Placement]:
        """The set-up of :meth:`press_batch` alone: each touch's frame, touch point and collider (on the host, in
        ``setup_threads`` threads), for timing it or inspecting a touch before pressing. Same arguments."""
        s, p = self._configs(overrides)
        return self._place(meshes, positions, directions, s, p)

    def _place(self, meshes, positions, directions, s: SensorConfig, p: PressConfig) -> list[placement.Placement]:
        pos = placement.host_points(positions, "positions")  # the placement runs on the host: any device is copied
        dirs = placement.host_points(directions, "directions")
        check_shape(pos, "(T, 3)", "positions")
        if dirs.shape != pos.shape:
            raise ValueError(
                f"directions must have shape (T, 3) like positions {tuple(pos.shape)}, got {tuple(dirs.shape)}"
            )
        T = pos.shape[0]
        if isinstance(meshes, trimesh.Trimesh):
            meshes = [meshes] * T
        if len(meshes) != T:
            raise ValueError(f"expected {T} meshes (one per touch) or a single mesh, got {len(meshes)}")
        if self.setup_processes and T > 1:
            if self._setup_pool is None:
                self._setup_pool = SetupPool(self.setup_processes)
            return self._setup_pool.place(meshes, pos, dirs, s, p, self.device)
        workers = self._setup_workers(T)
        if workers == 1:
            return [self._setup(m, pos[t], dirs[t], s, p) for t, m in enumerate(meshes)]
        # independent touches: the same placements in the same order, built side by side
        with ThreadPoolExecutor(workers, thread_name_prefix="eip-setup") as pool:
            return list(pool.map(lambda t: self._setup(meshes[t], pos[t], dirs[t], s, p), range(T)))

    # ------------------------------------------------------------------ simulation loop
    def _run(self, touches: list[placement.Placement], s: SensorConfig, p: PressConfig) -> list[TactileReading]:
        """Step the placed touches together until each is done (:class:`~tvrecon.sim.press.loop.PressLoop`)."""
        mcfg = self._mpm_config(s, p)
        speed = p.speed if p.speed is not None else float(p.speed_fraction) * self.wave_speed(s)
        return PressLoop(s, p, mcfg, speed, self.device, compile=p.compile).run(touches)
