"""What README.md and the docs pages name exists, and the README's user-path commands run.

- every dotted ``tvrecon.*`` name imports (the longest importable module, then ``getattr`` for the rest);
- every repository path (``tvrecon/...``, ``configs/...yaml``, ``docs/...``, ``train.py``; a glob: a match) exists;
- every config choice (``experiment=full``, ``data=paper_cpu``, ``preset=small``, ``trainer=gpu``, ...) is a file of
  its config group;
- every command in the README's "Three ways in" code blocks runs at a tiny size (:data:`TINY`), is run by
  ``tests/docs/test_examples.py`` (:data:`BY_EXAMPLES`), or is long (:data:`LONG`, composed but not run).
"""

from __future__ import annotations

import importlib
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

NAME = re.compile(r"\btvrecon(?:\.\w+)+")
PATH = re.compile(
    r"(?<![\w/.-])((?:tvrecon|configs|docs|examples|benchmarks|tests|results)/[\w./*-]*[\w/*]"
    r"|(?:train|eval)\.py\b|Makefile\b|pyproject\.toml\b|mkdocs\.yml\b)"
)
CHOICE = re.compile(r"(?<![\w./+~-])(experiment|data|preset|trainer|debug|hparams_search|model)=([\w,*()\[\]]+)")
GROUP_DIR = {"preset": "data"}


def _pages() -> list[Path]:
    return [ROOT / "README.md"] + sorted((ROOT / "docs").rglob("*.md"))


def _resolves(name: str) -> bool:
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ModuleNotFoundError as err:
            if err.name is not None and not ".".join(parts[:i]).startswith(err.name):
                raise  # the module exists but one of its own imports is missing: a real error
            continue
        for attr in parts[i:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


def _mentions(pattern: re.Pattern, group: int = 0) -> dict[str, set[str]]:
    found: dict[str, set[str]] = {}
    for page in _pages():
        for m in pattern.finditer(page.read_text(encoding="utf-8")):
            found.setdefault(m.group(group), set()).add(page.relative_to(ROOT).as_posix())
    return found


def test_dotted_names_resolve() -> None:
    problems = []
    for name, pages in sorted(_mentions(NAME).items()):
        if not _resolves(name):
            problems.append(f"{name} (in {', '.join(sorted(pages))}) does not resolve")
    assert not problems, "\n".join(problems)


def test_repository_paths_exist() -> None:
    problems = []
    for path, pages in sorted(_mentions(PATH).items()):
        ok = any(ROOT.glob(path.rstrip("/"))) if "*" in path else (ROOT / path).exists()  # a glob: one match
        if not ok:
            problems.append(f"{path} (in {', '.join(sorted(pages))}) does not exist")
    assert not problems, "\n".join(problems)


def test_config_choices_exist() -> None:
    problems = []
    for page in _pages():
        for m in CHOICE.finditer(page.read_text(encoding="utf-8")):
            group, value = m.group(1), m.group(2)
            if value.startswith("glob(") or "<" in value:
                continue
            folder = ROOT / "configs" / GROUP_DIR.get(group, group)
            for choice in value.split(","):
                ok = (folder / f"{choice}.yaml").is_file()
                if choice and not ok:
                    where = page.relative_to(ROOT)
                    problems.append(f"{group}={choice} in {where}: no configs/{folder.name}/{choice}.yaml")
    assert not problems, "\n".join(sorted(set(problems)))


def test_the_checks_can_fail() -> None:
    assert _resolves("tvrecon.sim.EIPSimulator.press") and not _resolves("tvrecon.sim.EIPSimulator.pres")
    assert not _resolves("tvrecon.sim.press_run")
    assert PATH.findall("see `configs/data/small.yaml` and train.py") == ["configs/data/small.yaml", "train.py"]
    assert PATH.findall("(`configs/experiment/classify*`)") == ["configs/experiment/classify*"]
    assert CHOICE.findall("train.py experiment=full,visual_only data.x=1") == [("experiment", "full,visual_only")]


# ------------------------------------------------------------------ the Python snippets

#: pages whose Python snippets run as they are (the others need a file of the reader's, e.g. a MuJoCo model)
RUNNABLE_SNIPPETS = (
    "docs/guides/simulator.md",
    "docs/guides/sensor-outputs.md",
    "docs/reference/simulator-contract.md",
)


def _snippets(page: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", page.read_text(encoding="utf-8"), re.S)


def test_snippets_use_no_undefined_names(tmp_path: Path) -> None:
    """Every Python snippet of README and docs passes ``ruff --select F821,F811`` (no undefined name)."""
    files = []
    for page in _pages():
        for i, code in enumerate(_snippets(page)):
            files.append(tmp_path / f"{page.stem}_{i}.py")
            files[-1].write_text(code)
    assert files, "no Python snippet found"
    ruff = [sys.executable, "-m", "ruff", "check", "--no-cache", "--isolated", "--select", "F821,F811"]
    done = subprocess.run([*ruff, *map(str, files)], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout[-3000:]


@pytest.mark.slow
@pytest.mark.parametrize("page", RUNNABLE_SNIPPETS)
def test_snippets_run(page: str, one_thread) -> None:
    for code in _snippets(ROOT / page):
        exec(compile(code, f"{page} snippet", "exec"), {"__name__": "snippet"})


# ------------------------------------------------------------------ the README's user-path commands

#: placeholders of the README's commands -> what the tiny run uses instead ({tmp}: the test's folder)
PLACEHOLDERS = {"part.stl": "{tmp}/part.stl", "outputs/": "{tmp}/outputs/"}

#: command (as the README writes it, without its comment) -> arguments appended for a tiny run
TINY: dict[str, list[str]] = {
    ".venv/bin/python examples/press_my_mesh.py part.stl --units mm --sensor digit --out outputs/my_press":
        ["--n-grid", "48"],
    ".venv/bin/python -m tvrecon.sim press --shape part.stl --sensor digit --outputs force markers rgb --out "
    "outputs/press": ["--n-grid", "32", "--resolution", "8", "--layers", "3", "--frames", "1", "--ply", "0",
                      "--threads", "1"],
    ".venv/bin/python examples/robot_mujoco_pad.py --object sphere --out outputs/mujoco_pad":
        ["--steps", "60", "--resolution", "8", "--n-grid", "32"],
}

#: commands that test_examples.py runs at a tiny size
BY_EXAMPLES = {"examples/reproduce_table3.sh --tiny"}

#: commands too long for CI -> the Hydra config they compose (checked: their overrides exist), or None
LONG: dict[str, str | None] = {
    ".venv/bin/python -m tvrecon.data.generate preset=paper_cpu": None,
    ".venv/bin/python train.py experiment=full data=paper_cpu": "train",
    ".venv/bin/python train.py -m experiment=full,visual_only,tactile_only,no_gap,no_direction,region_1x1,region_5x5,"
    "single_stage data=paper trainer=gpu": "train",
    ".venv/bin/python train.py -m experiment=chart_based,chart_based_visual,chart_based_tactile,full,visual_only,"
    "tactile_only data=paper_cpu seed=42,43": "train",
    ".venv/bin/python eval.py run_dir=logs/train/multiruns/<time>": None,
    ".venv/bin/python train.py -m experiment=classify_paper_cpu data.library.protocol=shared_base "
    "model.num_touches=1,2,4,6,8,10 seed=0,1,2": "train",
    ".venv/bin/python train.py experiment=full data=small data.library.user_root=my_meshes "
    "'data.train.classes=[bottle,can,mypart]'": "train",
    ".venv/bin/python -m tvrecon.robot.pybullet.pick_place object=can": None,
    ".venv/bin/python -m tvrecon.robot.mujoco.pick_place object=duck": None,
}


def _readme_commands() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("## Three ways in", 1)[1].split("\n## ", 1)[0]
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", section, re.S):
        for line in block.splitlines():
            line = line.split(" #", 1)[0].strip()
            if line:
                commands.append(line)
    return commands


def test_every_readme_command_is_listed() -> None:
    commands = _readme_commands()
    assert len(commands) >= 8, commands
    unlisted = [c for c in commands if c not in TINY and c not in BY_EXAMPLES and c not in LONG]
    assert not unlisted, "README commands in none of TINY / BY_EXAMPLES / LONG:\n" + "\n".join(unlisted)
    gone = [c for c in [*TINY, *BY_EXAMPLES, *LONG] if c not in commands]
    assert not gone, "listed here but no longer in the README:\n" + "\n".join(gone)


def _first_values(overrides: list[str]) -> list[str]:
    """A sweep's overrides as one job's: the first value of each comma list (``-m`` dropped)."""
    out = []
    for o in overrides:
        if o == "-m" or "=" not in o:
            continue
        key, value = o.split("=", 1)
        out.append(f"{key}={value.split(',')[0]}" if "," in value and not value.startswith("[") else o)
    return out


@pytest.mark.parametrize("command", sorted(LONG))
def test_long_commands_compose(command: str) -> None:
    """A long command's module resolves; a Hydra command's overrides compose into its config."""
    argv = shlex.split(command)
    if argv[1] == "-m":
        module = argv[2]
        assert _resolves(module), module
        return
    assert (ROOT / argv[1]).is_file(), argv[1]
    if LONG[command] is None:
        return
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    config = LONG[command]
    overrides = _first_values(argv[2:])
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(ROOT / "configs"), version_base="1.3"):
        compose(config_name=config, overrides=overrides)


def _docs_train_commands() -> list[str]:
    """``train.py`` command lines of the docs pages' bash blocks (one line each, placeholders left out)."""
    commands = set()
    for page in _pages():
        for block in re.findall(r"```bash\n(.*?)```", page.read_text(encoding="utf-8"), re.S):
            for line in block.replace("\\\n", " ").splitlines():
                line = line.split(" #", 1)[0].strip()
                if re.match(r"(\.venv/bin/)?python train\.py ", line) and "<" not in line:
                    commands.add(line)
    return sorted(commands)


@pytest.mark.parametrize("command", _docs_train_commands())
def test_docs_train_commands_compose(command: str) -> None:
    """Every ``train.py`` command of the docs composes: its experiment, data preset and overridden keys exist."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    overrides = [o for o in _first_values(shlex.split(command)[2:]) if not o.startswith("hydra")]
    overrides = [o for o in overrides if "glob(" not in o]
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(ROOT / "configs"), version_base="1.3"):
        compose(config_name="train", overrides=overrides)


@pytest.mark.slow
@pytest.mark.parametrize("command,extra", sorted(TINY.items()))
def test_tiny_commands_run(command: str, extra: list[str], tmp_path: Path) -> None:
    import trimesh

    part = trimesh.creation.icosphere(subdivisions=3, radius=20.0)  # a 40 mm ball, in millimetres
    part.apply_translation((0.0, 0.0, 20.0))
    part.export(tmp_path / "part.stl")
    for placeholder, value in PLACEHOLDERS.items():
        command = command.replace(placeholder, value.format(tmp=tmp_path))
    argv = shlex.split(command)
    argv[0] = sys.executable
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    done = subprocess.run([*argv, *extra], cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    assert any((tmp_path / "outputs").rglob("*.png")), "the command wrote no picture"
