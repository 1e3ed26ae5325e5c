"""How a touch is pressed: :class:`PressConfig`, the protocol of paper Algorithm 1 (grid, gap, speed, stop rule,
contact), checked on construction."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from tvrecon.sim.mpm.compiled.policy import AUTO, check_compile_setting
from tvrecon.sim.mpm.state import CONTACT_MODES
from tvrecon.sim.sensor.elastic_pad import _scalar
from tvrecon.utils.config_utils import NOT_IN_KEY, OMIT_IF_DEFAULT, check_number, check_whole

__all__ = ["DEFAULT_THRESHOLD", "MAX_COLLIDER_REFINE", "TERMINAL_MEASURES", "PressConfig"]

#: Default terminal threshold, in squared grid cells per contact-layer particle (see
#: :func:`tvrecon.sim.press.stop_rules.terminal_chamfer`).
DEFAULT_THRESHOLD = 0.05

#: Largest ``PressConfig.collider_refine``: the object's table grows as its cube (4 is 64x the grid's nodes).
MAX_COLLIDER_REFINE = 4

#: ``PressConfig.terminal``: what the terminal threshold is compared with (paper eq. 12 first, the default).
TERMINAL_MEASURES = ("chamfer", "displacement")


@dataclass
class PressConfig:
    """How a touch is simulated.

    Attributes:
        n_grid: grid cells across the domain (dx = 1 / n_grid in domain units).
        domain_size: world units spanned by the domain (the mesh is scaled by 1 / domain_size).
        gap: start gap between the contact layer and the object's highest point under the pad, in cells. With the
            default particle contact the pad touches when its particles reach the surface, so the hand first travels
            the gap (the first step touches only when ``gap`` is below one step's travel). The grid contact
            (``contact="grid"``) reaches the node plane 1.5 cells below the particles; with the touch plane half-way
            between node planes (``placement.touch_z``) the default 1.0 is the smallest gap that starts out of grid
            contact, and its first step already touches (no approach steps). Below 1.0 the pad starts in grid contact.
        speed: hand speed v_r in domain units / s; None -> ``speed_fraction`` * elastic (P-)wave speed.
        speed_fraction: fraction of the P-wave speed sqrt((lambda + 2 mu) / rho) used when ``speed`` is None.
        threshold: :func:`terminal_chamfer` threshold (squared cells per contact particle); the default stop rule.
        depth: stop at this indentation past first contact (cells); overrides ``force`` and ``threshold``. Raises
            ``max_depth`` to ``depth + 0.5`` for the call when shorter (``stop_rules.travel_for_depth``).
        force: stop when the normal contact force reaches this (simulation units); overrides ``threshold``.
        max_depth: the hand never travels more than ``gap + max_depth`` cells (also bounds the collider region and
            the reach); a longer ``depth`` raises it (see ``depth``).
        max_steps: hard step limit of the press phase; None -> the steps needed for ``gap + max_depth``.
        friction: Coulomb friction coefficient of the collider (on nodes or particles, per ``contact``).
        dt: time step; None -> CFL rule of the solver (``cfl_dt``).
        release_steps: after pressing, retract the hand at ``speed`` (back to its start) and hold, for this
            many steps in total; the reading then carries the ``residual`` image.
        record_every: record the tactile image and the pad particles every this many steps (0 = off).
        progress: show a tqdm progress bar over the steps.
        contact: where the rigid object acts on the pad (``MPMConfig.contact``, whose own default stays ``"grid"``):
            ``"particle"`` (default: the contact-layer particles, from when they reach the surface, whatever the
            object's offset from the node planes; :mod:`tvrecon.sim.mpm.particle_contact`; meets the Hertz exponent
            targets, docs/validation/physics.md) or ``"grid"`` (the grid nodes with sdf < 0; contact starts up to 1.5
            cells before the particles arrive; the earlier default).
        threshold_grid: the grid whose cells measure ``threshold``. An int N (default 128): squared cells of an
            N-cell grid, a fixed physical length (``domain_size / N`` world units); the terminal check compares the
            chamfer with ``threshold * (n_grid / N)^2``, so the default stops every grid where paper eq. 12 stops at
            the paper's ``n_grid`` 128 (at ``n_grid`` 64 the threshold is 1/4 of ``threshold`` in own cells, at 256
            4x). None: this press's ``n_grid`` (paper eq. 12 in the simulation's own cells, so the physical depth at
            the stop shrinks as ``n_grid`` grows; the earlier default).
        terminal: what ``threshold`` is compared with: ``"chamfer"`` (default: paper eq. 12, :func:`terminal_chamfer`)
            or ``"displacement"`` (beyond the paper: the same centred deformation with each particle matched to its
            own rest position, :func:`~tvrecon.sim.press.stop_rules.terminal_displacement`, ``DisplacementRule``). Eq.
            12's nearest neighbours stop seeing a sideways spread once it passes half the lattice spacing (a quarter
            cell), so on a face larger than the pad the chamfer stop comes deeper on finer grids (0.61 of the 256
            depth at 128); the displacement stop does not (0.98-0.99). Elsewhere the two agree
            (docs/notes/stop-depth.md).
        collider_refine: the object's signed-distance table (``MeshCollider``) is sampled ``collider_refine`` times
            finer than the grid (spacing ``dx / collider_refine``). The trilinear table cannot hold a part thinner
            than about one of its cells (both nodes astride a blade or a rod lie outside it, so the interpolated
            distance stays positive and the pad passes through): on the 64 grid of the CPU presets a spoon's bowl, a
            screwdriver's shaft or a pan's wall is felt in only some touches. 2 on the 64 grid samples the object
            as finely as the authors' 128 grid does, at the cost of a larger set-up table (8x the nodes); the pad,
            the grid and the steps are unchanged. The particle contact looks the table up at the particles; the grid
            contact interpolates it at the nodes (``grid_contact.collider_at_block``). Default 1 (the grid's own
            nodes, the earlier behaviour, out of the data cache key).
        compile: run the solver's no-grad steps with its fused ``torch.compile`` kernels (``MLSMPM(compile=True)``,
            :mod:`tvrecon.sim.mpm.compiled`). How a touch is computed, not what it is: the readings equal the eager
            ones to float32 round-off (1e-4 grid cells tested), so it never enters the data cache key
            (``config_utils.NOT_IN_KEY``) and a cache filled either way serves both. True, False or ``"auto"``
            (default): the job decides (:func:`tvrecon.sim.mpm.compiled.policy.resolve_compile`): ``generate`` and
            the datamodules compile on a CPU with a C++ compiler when a process presses enough touches to pay back its
            compile (500 touches of the ``small`` pad, or 100 with a warm compile cache; a touch of another pad counts
            as ``policy.touch_work``), and on CUDA past 75,000 of them (about 4,800 touches of the authors' pad, the
            break-even measured on an H100); a single press and small jobs stay eager. Steps that need autograd always
            run eager.

    The earlier default press (grid-node collider, threshold in the press's own cells) is
    ``PressConfig(contact="grid", threshold_grid=None)`` (CLI: ``--contact grid --threshold-grid 0``).
    ``contact``, ``threshold_grid`` and ``terminal`` were added after data was cached; at their defaults they stay out
    of the data cache key (``config_utils.OMIT_IF_DEFAULT``) and other values (``"grid"``, None, ``"displacement"``)
    enter it. Flipping the ``contact`` and ``threshold_grid`` defaults changed every default touch, so the data cache
    version was bumped with it (``tvrecon.data.cache.store.CACHE_VERSION``).
    """

    n_grid: int = 128
    domain_size: float = 1.0
    gap: float = 1.0
    speed: float | None = None
    speed_fraction: float = 0.1
    threshold: float | None = DEFAULT_THRESHOLD
    depth: float | None = None
    force: float | None = None
    max_depth: float = 4.0
    max_steps: int | None = None
    friction: float = 0.0
    dt: float | None = None
    release_steps: int = 0
    record_every: int = 0
    progress: bool = False
    contact: str = field(default="particle", metadata=OMIT_IF_DEFAULT)
    threshold_grid: int | None = field(default=128, metadata=OMIT_IF_DEFAULT)
    terminal: str = field(default="chamfer", metadata=OMIT_IF_DEFAULT)
    collider_refine: int = field(default=1, metadata=OMIT_IF_DEFAULT)
    compile: bool | str = field(default=AUTO, metadata=NOT_IN_KEY)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise ValueError (TypeError for a value of the wrong type) naming the bad field."""
        check_whole(self.n_grid, "PressConfig.n_grid")
        for name in ("max_steps", "release_steps", "record_every"):
            if getattr(self, name) is not None:
                check_whole(getattr(self, name), f"PressConfig.{name}")
        for name in ("domain_size", "gap", "speed_fraction", "max_depth", "friction"):
            check_number(getattr(self, name), f"PressConfig.{name}")
        for name in ("speed", "threshold", "depth", "force", "dt"):
            if getattr(self, name) is not None:
                check_number(getattr(self, name), f"PressConfig.{name}")
        if int(self.n_grid) < 16:
            raise ValueError(f"PressConfig.n_grid must be >= 16, got {self.n_grid}")
        if not (math.isfinite(float(self.domain_size)) and float(self.domain_size) > 0):
            raise ValueError(f"PressConfig.domain_size must be > 0 world units, got {self.domain_size}")
        if not float(self.gap) >= 0:
            raise ValueError(f"PressConfig.gap must be >= 0 cells, got {self.gap}")
        for name in ("speed", "threshold", "depth", "force", "dt"):
            val = getattr(self, name)
            if val is not None and not _scalar(val) > 0:
                raise ValueError(f"PressConfig.{name} must be > 0 or None, got {val}")
        if not (0 < float(self.speed_fraction) < 1):
            raise ValueError(f"PressConfig.speed_fraction must be in (0, 1), got {self.speed_fraction}")
        if not float(self.max_depth) > 0:
            raise ValueError(f"PressConfig.max_depth must be > 0 cells, got {self.max_depth}")
        if self.max_steps is not None and int(self.max_steps) < 1:
            raise ValueError(f"PressConfig.max_steps must be >= 1 or None, got {self.max_steps}")
        if int(self.release_steps) < 0 or int(self.record_every) < 0:
            raise ValueError("PressConfig.release_steps and record_every must be >= 0")
        if not float(self.friction) >= 0:
            raise ValueError(f"PressConfig.friction must be >= 0, got {self.friction}")
        if self.contact not in CONTACT_MODES:
            raise ValueError(f"PressConfig.contact must be one of {CONTACT_MODES}, got {self.contact!r}")
        tg = self.threshold_grid
        if tg is not None and not (isinstance(tg, int) and not isinstance(tg, bool) and tg > 0):
            raise ValueError(f"PressConfig.threshold_grid must be a positive int or None, got {self.threshold_grid!r}")
        check_compile_setting(self.compile, "PressConfig.compile")
        check_whole(self.collider_refine, "PressConfig.collider_refine")
        if not 1 <= int(self.collider_refine) <= MAX_COLLIDER_REFINE:
            raise ValueError(
                f"PressConfig.collider_refine must be a whole number in [1, {MAX_COLLIDER_REFINE}] (the object's table "
                f"is that many times finer than the grid), got {self.collider_refine}"
            )
        if self.terminal not in TERMINAL_MEASURES:
            raise ValueError(f"PressConfig.terminal must be one of {TERMINAL_MEASURES}, got {self.terminal!r}")
