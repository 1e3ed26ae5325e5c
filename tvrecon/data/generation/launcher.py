"""``python -m tvrecon.data.generate --multirun ...``: the shards of generate as the jobs of a Hydra launcher.

The generate command line itself is not a Hydra app (its data overrides are composed into the preset by
:func:`tvrecon.data.presets.compose_preset`). With ``--multirun`` (or ``-m``) this module turns the same arguments
into a Hydra multirun of the small app ``configs/generate.yaml`` and hands it to whichever launcher the command names:

- ``preset``, ``splits``, ``workers``, ``shard`` (or ``--shard``) and ``compile`` are keys of that app, so they sweep
  (``shard=0/4,1/4,2/4,3/4`` is four jobs);
- ``hydra/...`` and ``hydra.*`` arguments go to Hydra (``hydra/launcher=joblib hydra.launcher.n_jobs=2``,
  ``hydra/launcher=submitit_slurm hydra.launcher.partition=gpu``);
- every other ``key=value`` is a data override, passed unchanged to every job (``data_overrides``), not swept.

Each job (:func:`run_job`) runs the single-process command (:func:`tvrecon.data.generate.main`) with its own values,
so it prints its progress and summary lines, skips cached items and writes the same cache entries. The job folders
(Hydra's config and log of each job) go to ``logs/generate/multirun/<time>/<job number>``.
"""

from __future__ import annotations

import importlib
import re
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf

from tvrecon.data.generation.args import OPTION_KEYS, parse_shard  # the app's keys: the command's own (swept)
from tvrecon.data.presets import PROJECT_ROOT, preset_names
from tvrecon.utils.cli_errors import argv_and_env

#: the single-process command a job runs (``tvrecon.data.generate.main``): argv -> its stats
Run = Callable[[list[str]], list[Any]]

__all__ = ["APP_CONFIG_DIR", "MULTIRUN_FLAGS", "hydra_arguments", "is_multirun", "job_arguments", "multirun", "run_job"]

#: the folder holding ``generate.yaml`` (the repository's ``configs/``)
APP_CONFIG_DIR = PROJECT_ROOT / "configs"
MULTIRUN_FLAGS = ("-m", "--multirun")
#: launchers that come from a plugin: the modules it needs (the plugin, the library it drives) and how to install it
_PLUGINS = {
    "joblib": (("hydra_plugins.hydra_joblib_launcher", "joblib"), "pip install hydra-joblib-launcher (dev extra)"),
    "submitit_slurm": (("hydra_plugins.hydra_submitit_launcher", "submitit"), "pip install -e '.[cluster]'"),
    "submitit_local": (("hydra_plugins.hydra_submitit_launcher", "submitit"), "pip install -e '.[cluster]'"),
}


def is_multirun(argv: Sequence[str]) -> bool:
    """True when the command line asks for a Hydra multirun (``-m`` or ``--multirun``)."""
    return any(a in MULTIRUN_FLAGS for a in argv)


def _values(arg: str) -> list[str]:
    """The values of one ``key=value`` argument as Hydra sweeps them (``a,b`` and ``range(n)``; one value else)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    key = arg.split("=", 1)[0]
    try:
        override = OverridesParser.create().parse_overrides([arg])[0]
        if override.is_sweep_override():
            return [str(v) for v in override.sweep_string_iterator()]
        return [override.get_value_element_as_str()]
    except Exception as err:  # Hydra's parse errors, and glob()/interval() that need a config to expand
        raise ValueError(f"{key}: cannot read the values of {arg!r}; list them as a,b,c ({err})") from None


def _check_shards(arg: str) -> None:
    try:
        shards = [parse_shard(v) for v in _values(arg)]
    except ValueError as err:
        raise ValueError(f"{err}; with --multirun list one i/n per job: shard=0/4,1/4,2/4,3/4") from None
    if len(set(shards)) < len(shards):
        raise ValueError(f"a shard is listed twice in {arg!r}: two jobs would generate the same items")
    counts = sorted({n for _, n in shards})
    if len(counts) > 1:
        n = counts[-1]
        example = ",".join(f"{i}/{n}" for i in range(min(n, 4))) + (",..." if n > 4 else "")
        raise ValueError(f"the shards of one run must share their n, got {arg!r} (e.g. shard={example})")


def _check_presets(arg: str) -> None:
    for name in _values(arg):
        if name not in preset_names():
            raise ValueError(f"unknown data preset {name!r}; available: {preset_names()}")


def _check_launcher(arg: str) -> None:
    name = arg.split("=", 1)[1].strip()
    if name not in _PLUGINS:
        return
    modules, hint = _PLUGINS[name]
    try:  # imported, not only found: a plugin whose own library is missing (joblib) fails here, not in Hydra
        for module in modules:
            importlib.import_module(module)
    except ImportError as err:
        missing = f" ({err})" if str(err) else ""
        raise ValueError(f"hydra/launcher={name} needs Hydra's {name} launcher plugin{missing}: {hint}") from None


def _quote(text: str) -> str:
    """``text`` as a single-quoted Hydra override value (backslashes doubled only before a quote or at the end)."""
    text = re.sub(r"(\\*)'", lambda m: m.group(1) * 2 + "\\'", text)
    text = re.sub(r"(\\+)$", lambda m: m.group(1) * 2, text)
    return f"'{text}'"


def hydra_arguments(argv: Sequence[str], usage: str = "") -> list[str]:
    """The Hydra command line (for ``configs/generate.yaml``) of a generate ``--multirun`` command line.

    Raises:
        ValueError: an argument that is not ``key=value``, a bad shard or preset, a swept data override, a launcher
            whose plugin is not installed.
    """
    out = ["--multirun"]
    data: list[str] = []
    args = list(argv)
    while args:
        a = args.pop(0)
        if a in MULTIRUN_FLAGS:
            continue
        if a in ("-h", "--help"):
            print(usage)
            raise SystemExit(0)
        if a == "--shard":
            if not args:
                raise ValueError("--shard needs a value i/n")
            a = f"shard={args.pop(0)}"
        elif a.startswith("--shard="):
            a = "shard=" + a.split("=", 1)[1]
        if a.startswith("-") or ("=" not in a and not a.startswith("~")):
            raise ValueError(f"unexpected argument {a!r}; use key=value (see --help)")
        key = a.split("=", 1)[0].lstrip("+~")
        if key == "hydra" or key.startswith(("hydra.", "hydra/")):
            if key == "hydra/launcher" and "=" in a:
                _check_launcher(a)
            out.append(a)
        elif key in OPTION_KEYS:
            if key == "shard":
                _check_shards(a)
            elif key == "preset":
                _check_presets(a)
            out.append(a)
        else:
            if "=" in a and len(_values(a)) > 1:
                raise ValueError(
                    f"{a!r}: with --multirun only {', '.join(OPTION_KEYS)} can be swept; a data override is the same "
                    "for every job (run one multirun per value)"
                )
            data.append(a)
    out.append("data_overrides=[" + ",".join(_quote(d) for d in data) + "]")
    return out


def job_arguments(cfg: DictConfig) -> list[str]:
    """The single-process generate command line of one job of the multirun (its config ``cfg``)."""
    argv = [f"preset={cfg.preset}", f"shard={cfg.shard}"]
    if cfg.splits is not None:
        splits = cfg.splits
        argv.append("splits=" + (",".join(str(s) for s in splits) if isinstance(splits, ListConfig) else str(splits)))
    if cfg.workers is not None:
        argv.append(f"workers={cfg.workers}")
    if cfg.compile is not None:
        argv.append(f"compile={str(cfg.compile).lower()}")
    if cfg.get("export") is not None:
        argv.append(f"export={cfg.export}")
    overrides = OmegaConf.to_container(cfg.data_overrides, resolve=False)  # ${...} of a data override stays as typed
    return argv + [str(o) for o in overrides]  # type: ignore[union-attr]


@contextmanager
def _outside_hydra_job() -> Iterator[None]:
    """Hydra's global state set aside: :func:`~tvrecon.data.presets.compose_preset` initialises Hydra itself, which
    Hydra refuses inside a job ("GlobalHydra is already initialized"). Restored afterwards (the basic launcher runs the
    next job in this process)."""
    from hydra.core.global_hydra import GlobalHydra

    hydra = GlobalHydra.instance().hydra if GlobalHydra.instance().is_initialized() else None
    GlobalHydra.instance().clear()
    try:
        yield
    finally:
        GlobalHydra.instance().clear()
        if hydra is not None:
            GlobalHydra.instance().initialize(hydra)


def run_job(cfg: DictConfig, run: Run) -> list[Any]:
    """Hydra's task function: generate this job's shard with ``run``, the single-process command."""
    with _outside_hydra_job():
        return run(job_arguments(cfg))


def multirun(argv: Sequence[str], run: Run, usage: str = "") -> list[Any]:
    """Run a generate ``--multirun`` command line through Hydra; returns [] (each job prints its own stats).

    Hydra re-raises the error of the first failed job (``HYDRA_FULL_ERROR=1`` while it runs) after naming its
    overrides, so the command ends with one error line like every other one. ``sys.argv`` and the environment are
    restored afterwards; ``PROJECT_ROOT`` (the root of ``logs/generate/multirun``) defaults to the repository.
    """
    import hydra

    args = hydra_arguments(argv, usage)
    prog = sys.argv[0] if sys.argv else "generate"
    with argv_and_env([prog, *args], {"HYDRA_FULL_ERROR": "1"}, defaults={"PROJECT_ROOT": str(PROJECT_ROOT)}):
        app = hydra.main(version_base="1.3", config_path=str(APP_CONFIG_DIR), config_name="generate")(
            lambda cfg: run_job(cfg, run)
        )
        app()
    return []
