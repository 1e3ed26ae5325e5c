"""The package's imports point down its layers and never run in a circle.

Every ``import`` of every module of :mod:`tvrecon` is read with :mod:`ast`, wherever it stands: at module level, inside
a function, or under ``if TYPE_CHECKING:`` (a type-only import of a sibling still ties the two modules together).

Layers, bottom to top: ``utils < sim < data < losses, models < train, robot < report < entry points``. Entry points are
the command lines (``__main__`` modules), which may use any layer. Inside :mod:`tvrecon.sim` the rooms have their own
order: ``bodies < mpm < sensor < press``; the package's ``__init__``, its plots, CLI and physics checks sit on top of
them. Inside :mod:`tvrecon.robot` the engine-free core (the modules outside a room) sits below one room per physics
engine, and the engines' rooms never import each other. No module imports a command line's module (the datamodule
calls the worker pool, not ``python -m tvrecon.data.generate``).
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "tvrecon"

#: rank of each top-level room (equal ranks may import each other, as long as no cycle forms)
LAYERS = {"utils": 0, "sim": 1, "data": 2, "losses": 3, "models": 3, "train": 4, "robot": 4, "report": 5}
ENTRY = 6
#: the rooms of tvrecon.sim, bottom to top; the sim package itself (its __init__) and sim modules outside them sit above
SIM_ROOMS = {"bodies": 0, "mpm": 1, "sensor": 2, "press": 3}
#: the rooms of tvrecon.robot, one per physics engine, above the engine-free core and apart from each other
ROBOT_ROOMS = ("pybullet", "mujoco")
#: the command-line modules besides the ``__main__`` ones: entry points, imported by no module of the package
CLI_MODULES = (
    "tvrecon.data.generate",
    "tvrecon.data.preview",
    "tvrecon.data.touches.sweep_figure",
    "tvrecon.robot.pybullet.pick_place",
    "tvrecon.robot.mujoco.pick_place",
)


def modules() -> dict[str, Path]:
    """Dotted module name -> file, for every module of the package (a package is its ``__init__``)."""
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def imports(name: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The tvrecon modules that ``name`` imports anywhere in its file (resolved to the deepest module named)."""
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    targets: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                prefix = ".".join(base + ([node.module] if node.module else []))
            else:
                prefix = node.module or ""
            for alias in node.names:
                sub = f"{prefix}.{alias.name}"
                targets.add(sub if sub in known else prefix)
    out = set()
    for target in targets:
        while target not in known and "." in target:
            target = target.rsplit(".", 1)[0]
        if target in known and target != name and target.startswith("tvrecon"):
            out.add(target)
    return out


def graph() -> dict[str, set[str]]:
    known = modules()
    return {name: imports(name, path, known) for name, path in known.items()}


def rank(name: str) -> int:
    parts = name.split(".")
    if parts[-1] == "__main__":
        return ENTRY
    return LAYERS.get(parts[1], -1) if len(parts) > 1 else ENTRY


def sim_rank(name: str) -> int:
    """Rank of a tvrecon.sim module among the sim rooms (above them all when outside every room)."""
    parts = name.split(".")
    return SIM_ROOMS.get(parts[2], len(SIM_ROOMS)) if len(parts) > 2 else len(SIM_ROOMS)


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def upward(edges: dict[str, set[str]]) -> list[str]:
    """Edges from a lower layer up into a higher one (and, inside tvrecon.sim, from a lower room to a higher one)."""
    out = []
    for a, targets in edges.items():
        for b in targets:
            if rank(b) > rank(a):
                out.append(f"{a} -> {b}")
            elif a.startswith("tvrecon.sim.") and b.startswith("tvrecon.sim") and rank(a) == rank(b):
                if sim_rank(b) > sim_rank(a):
                    out.append(f"{a} -> {b}")
    return sorted(out)


def test_every_module_has_a_layer() -> None:
    assert [m for m in graph() if rank(m) < 0] == []


def test_no_import_cycles() -> None:
    assert cycles(graph()) == []


def test_imports_point_down() -> None:
    assert upward(graph()) == []


def robot_room(name: str) -> str | None:
    """The engine room of a tvrecon.robot module (None: the engine-free core)."""
    parts = name.split(".")
    return parts[2] if len(parts) > 2 and parts[1] == "robot" and parts[2] in ROBOT_ROOMS else None


def test_robot_core_and_engine_rooms_stay_apart() -> None:
    """The core imports no engine room, and an engine room imports no other engine's room."""
    wrong = [
        f"{a} -> {b}"
        for a, targets in graph().items()
        if a.startswith("tvrecon.robot")
        for b in targets
        if robot_room(b) is not None and robot_room(b) != robot_room(a)
    ]
    assert sorted(wrong) == []


def test_no_module_imports_a_command_line() -> None:
    known = modules()
    assert set(CLI_MODULES) <= set(known), "a command line moved: update CLI_MODULES"
    assert sorted(f"{a} -> {b}" for a, targets in graph().items() for b in targets if b in CLI_MODULES) == []


def test_only_init_files_re_export() -> None:
    """A module's ``__all__`` names only what the module defines; a package's ``__init__`` is the one place that hands
    names on from elsewhere, so each public object has one import path besides its package's."""
    wrong = []
    for name, path in modules().items():
        if path.name == "__init__.py":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        defined: set[str] = set()
        exported: list[str] = []
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                defined.add(node.name)
            elif isinstance(node, (ast.Assign, ast.AnnAssign)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                for target in targets:
                    defined.update(n.id for n in ast.walk(target) if isinstance(n, ast.Name))
                    if isinstance(target, ast.Name) and target.id == "__all__" and node.value is not None:
                        exported = [e.value for e in ast.walk(node.value) if isinstance(e, ast.Constant)]
            elif isinstance(node, (ast.If, ast.Try)):
                for sub in ast.walk(node):
                    if isinstance(sub, (ast.FunctionDef, ast.ClassDef)):
                        defined.add(sub.name)
                    elif isinstance(sub, ast.Assign):
                        defined.update(n.id for t in sub.targets for n in ast.walk(t) if isinstance(n, ast.Name))
        wrong += [f"{name}.{e}" for e in exported if e not in defined]
    assert wrong == []
