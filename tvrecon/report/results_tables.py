"""The docs' tables, rendered from the files under ``results/``.

``python -m tvrecon.report.results_tables [--check] [--root results] [paths...]`` fills every block

    <!-- results:NAME -->
    ...
    <!-- /results:NAME -->

of ``README.md`` and ``docs/**/*.md`` (or of the Markdown files given) with what the renderer NAME makes of the
results; ``--check`` writes nothing, names each stale block and exits 1. Renderers (:data:`RENDERERS`):

- ``headline``: one line per paper table, the paper's figure beside ours, with a link to its page (the README);
- ``table1`` .. ``table4``: the paper's table with ours beside it, the seeds and spread, each row's command;
- ``table3_touches``: the Table 3 models run with two or more seeds, with refinement and the touch controls;
- ``table3_controls``: the touch controls at every touch count; ``table3_schedules``: the experiments trained at more
  than one number of epochs, each schedule's chamfer and wall time;
- ``benchmarks``: one line per benchmark and physics run of ``results/bench`` and ``results/physics``.

A run folder is ``results/<suite>/<run>/`` with ``metrics.json`` and ``manifest.json`` (``results/README.md``).
"""

from __future__ import annotations

import json
import os
import re
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tvrecon.report.method_rows import method_rows, touch_ratio
from tvrecon.report.paper_numbers import PAPER_TABLE2, PAPER_TABLE3, PAPER_TABLE4, PAPER_TABLE4_CLASSES
from tvrecon.report.paper_tables import (
    build_table1,
    build_table2_vs_paper,
    build_table3_vs_paper,
    build_table4_vs_paper,
    seed_groups,
)
from tvrecon.report.schedules import build_schedule_comparison, schedule_of
from tvrecon.report.seed_summary import build_controls_over_seeds, build_seed_summary
from tvrecon.report.table_format import PRETTY_NAMES, Table, fmt_mean_std
from tvrecon.utils.atomic import atomic_write_text

__all__ = [
    "MANIFEST_FIELDS",
    "RENDERERS",
    "Run",
    "fill_blocks",
    "find_blocks",
    "load_runs",
    "main",
    "render",
]

#: The fields every ``manifest.json`` has (``null`` where not recorded).
MANIFEST_FIELDS: tuple[str, ...] = ("command", "data_preset", "seed", "commit", "machine", "wall_s", "date")

BLOCK = re.compile(r"<!-- results:(?P<name>[\w-]+) -->\n(?P<body>.*?)<!-- /results:(?P=name) -->", re.S)
DEFAULT_ROOT = Path(__file__).resolve().parents[2] / "results"


@dataclass(frozen=True)
class Run:
    """One run folder: its path, ``metrics.json`` and ``manifest.json`` (the nearest one at or above the folder,
    inside its suite)."""

    path: Path
    metrics: dict[str, Any]
    manifest: dict[str, Any]

    def result(self) -> dict[str, Any]:
        """The metrics with what the tables need from the manifest: ``data_preset``, ``epochs`` (the command's
        ``trainer.max_epochs``), ``fixed_visual`` (the command freezes the visual path) and ``precision`` (the
        manifest's, else the command's ``trainer.precision``, else ``32-true``: runs before the bf16 default) and
        ``wall_s`` (the run's wall time)."""
        out = dict(self.metrics)
        command = str(self.manifest.get("command") or "")
        epochs = re.search(r"trainer\.max_epochs=(\d+)", command)
        out["data_preset"] = self.manifest.get("data_preset")
        out["epochs"] = int(epochs[1]) if epochs else None
        out["fixed_visual"] = "freeze=" in command
        precision = re.search(r"trainer\.precision=(\S+)", command)
        out["precision"] = self.manifest.get("precision") or (precision[1] if precision else "32-true")
        out.setdefault("seed", self.manifest.get("seed"))
        out["wall_s"] = self.manifest.get("wall_s")
        return out


def load_runs(suite: Path) -> list[Run]:
    """Every run below ``suite`` (a folder of ``results/``), in sorted path order.

    Raises:
        FileNotFoundError: ``suite`` does not exist, or a ``metrics.json`` has no ``manifest.json`` at or above it.
    """
    if not suite.is_dir():
        raise FileNotFoundError(f"{suite} does not exist: give --root the repository's results/ folder")
    runs = []
    for metrics in sorted(suite.rglob("metrics.json")):
        folder = metrics.parent
        while not (folder / "manifest.json").is_file():
            if folder == suite:
                raise FileNotFoundError(f"{metrics} has no manifest.json beside it or above it in {suite}")
            folder = folder.parent
        manifest = json.loads((folder / "manifest.json").read_text())
        runs.append(Run(metrics.parent, json.loads(metrics.read_text()), manifest))
    return runs


def _recon(root: Path) -> tuple[list[Run], list[dict[str, Any]]]:
    runs = [r for r in load_runs(root / "table3") if r.metrics.get("task") == "reconstruction"]
    return runs, [r.result() for r in runs]


def _seeds_phrase(manifests: Sequence[Mapping[str, Any]]) -> str:
    """``"seed 0"`` or ``"seeds 0, 1, 2"``."""
    seeds = ", ".join(str(m.get("seed")) for m in manifests)
    return f"seed{'s' * (len(manifests) > 1)} {seeds}"


def _group_commands(runs: Sequence[Run], results: Sequence[Mapping[str, Any]]) -> list[str]:
    """One line per Table 3/4 row: its label, data preset, seeds and command (``seed=<seed>`` for several seeds)."""
    run_of = {id(res): run for res, run in zip(results, runs)}
    lines = []
    for label, group in seed_groups(results):
        manifests = [run_of[id(r)].manifest for r in group]
        commands: list[str] = []
        for m in manifests:
            cmd = str(m.get("command") or "not recorded")
            cmd = re.sub(r"\bseed=\d+", "seed=<seed>", cmd) if len(group) > 1 else cmd
            if cmd not in commands:
                commands.append(cmd)
        preset = manifests[0].get("data_preset")
        lines.append(f"- {label} (`{preset}`, {_seeds_phrase(manifests)}): " + "; ".join(f"`{c}`" for c in commands))
    return lines


def render_table3(root: Path) -> str:
    runs, results = _recon(root)
    table = build_table3_vs_paper(results)
    return (
        table.to_markdown(compact=True)
        + "\nCommands (each row's runs; `<...>` a path of the machine that ran it):\n\n"
        + "\n".join(_group_commands(runs, results))
        + "\n"
    )


def render_table4(root: Path) -> str:
    _, results = _recon(root)
    return build_table4_vs_paper(results).to_markdown(compact=True)


def render_table3_touches(root: Path) -> str:
    _, results = _recon(root)
    return build_seed_summary(results).to_markdown(compact=True)


def render_table3_controls(root: Path) -> str:
    _, results = _recon(root)
    return build_controls_over_seeds(results).to_markdown(compact=True)


def render_table3_schedules(root: Path) -> str:
    _, results = _recon(root)
    return build_schedule_comparison(results).to_markdown(compact=True)


def _cls(root: Path) -> tuple[list[Run], list[Run]]:
    runs = load_runs(root / "table2")
    return [r for r in runs if r.metrics.get("task") == "classification"], [
        r for r in runs if r.metrics.get("task") == "classification_summary"
    ]


def render_table2(root: Path) -> str:
    runs, summaries = _cls(root)
    presets = sorted({str(r.manifest.get("data_preset")) for r in runs + summaries}, reverse=True)  # CPU preset first
    parts = []
    for preset in presets:
        mine = [r for r in runs if r.manifest.get("data_preset") == preset]
        rows = [row for s in summaries if s.manifest.get("data_preset") == preset for row in s.metrics["rows"]]
        table = build_table2_vs_paper(
            [r.result() for r in mine], rows, title=f"Table 2 on `{preset}`: accuracy (%), the paper and ours"
        )
        lines = []
        by_model: dict[str, list[Run]] = {}
        for r in mine:  # a model per touch count, or one for every count (it answers several)
            n = r.metrics.get("num_touches") if len(r.metrics["accuracy"]) == 1 else "every"
            by_model.setdefault(f"{r.metrics['name']}, {n} touches", []).append(r)
        for key, model_runs in by_model.items():
            name, touches = key.split(", ")
            seeds = _seeds_phrase([r.manifest for r in model_runs])
            cmd = str(model_runs[0].manifest.get("command"))
            cmd = re.sub(r"\bseed=\d+", "seed=<seed>", cmd) if len(model_runs) > 1 else cmd
            n = touches.split()[0]
            count = "one model for every number of touches" if n == "every" else f"{n} touch{'es' * (n != '1')}"
            lines.append(f"- {PRETTY_NAMES.get(name, name)}, {count} ({seeds}): `{cmd}`")
        for s in summaries:
            if s.manifest.get("data_preset") == preset:
                models = [str(r["model"]) for r in s.metrics["rows"] if not str(r["model"]).endswith("touches")]
                lines.append(f"- {'; '.join(models)} (and their controls): `{s.manifest.get('command')}`")
        parts.append(table.to_markdown(compact=True) + "\nCommands:\n\n" + "\n".join(lines) + "\n")
    return "\n".join(parts)


def render_table1(root: Path) -> str:
    from tvrecon.data.presets import compose_preset, split_sizes

    ours = {
        "classification": {p: split_sizes(compose_preset(p)) for p in ("cls_paper", "cls_paper_cpu")},
        "reconstruction": {p: split_sizes(compose_preset(p)) for p in ("paper", "paper_cpu")},
    }
    out = build_table1(ours).to_markdown(compact=True)
    header = ["Preset", "Split", "Objects", "Touches", "Touches that felt nothing", "Done after (s)"]
    rows, cmds = [], []
    for run in load_runs(root / "table1"):
        for split, s in run.metrics["splits"].items():
            rows.append(
                [
                    f"`{run.metrics['preset']}`",
                    split,
                    str(s["objects"]),
                    f"{s['touches']:,}",
                    str(s.get("without_contact", "-")),
                    f"{s['done_at_s']:.0f}",
                ]
            )
        m = run.manifest
        cmds.append(
            f"- `{m['command']}`: {m['wall_s'] / 60:.1f} min wall on {m['machine']} ({m['date']}, `{m['commit']}`)"
        )
    gen = Table("Generated whole", header, rows, ["Seconds from the start of the generate command."])
    return out + "\n" + gen.to_markdown(compact=True) + "\n" + "\n".join(cmds) + "\n"


def _bench_figure(suite: str, m: Mapping[str, Any]) -> str:
    """The line of a benchmark's metrics that the docs quote, by suite (other suites: their top-level numbers)."""
    if suite == "compile_auto":
        return f"{m['figures']['compiled_cpu_s_per_touch']:.3f} CPU-s a touch (marginal, compiled)"
    if suite == "press_ab":
        return (
            f"{m['old_over_new_median']:.2f}x the old code (median; {m['old_cpu_s_per_touch']} -> "
            f"{m['new_cpu_s_per_touch']} CPU-s a touch), {m['jobs'] - m['jobs_not_bit_identical']} of {m['jobs']} "
            "jobs bit-identical"
        )
    if suite == "taichi":
        r = m["median_ratio"]
        return (
            f"compiled {r['compiled_over_box_serial']:.2f}x, eager {r['eager_over_box_serial']:.2f}x the speed of "
            "Taichi's fastest CPU kernel (median of rounds)"
        )
    if suite == "gpu":
        return "; ".join(
            f"{x['mode']}, set-up {x['setup_processes'] or x['setup_threads']} "
            f"{'processes' if x['setup_processes'] else 'threads'}: {x['touches_per_s']:.1f} touches/s, loop "
            f"{x['loop_particle_steps_per_s']:.2e} particle-steps/s"
            for x in m["runs"]
        )
    if suite == "train_step":
        return (
            "; ".join(f"{x['mode']} {x['speedup_median']:.2f}x (minima {x['speedup_min']:.2f}x)" for x in m["modes"])
            + f" faster than the training step of {m['baseline']} (ratio of medians over repeats, {m['precision']})"
        )
    if suite == "collider_refine":
        r = m["results"]
        return "; ".join(
            f"table at 1/{64 * int(k)}: {v['felt']} of {v['touches']} touches felt, {v['cpu']:.1f} CPU-s"
            for k, v in r.items()
        )
    if suite == "cfl":
        f = m["factors"]
        return "; ".join(
            f"dt x{k}: {v['cpu_per_touch']:.2f} CPU-s a touch, image mean diff {v['image_mean_diff']:.3f} "
            f"cells, diverged {len(v['diverged'])}"
            for k, v in f.items()
        )
    if suite == "patch_rim":
        return "; ".join(
            f"{k}: off the surface {v['cloud_to_gt']}, not covered {v['gt_to_cloud']}, "
            f"{v['touches_without_a_point']} of {v['touches']} touches empty"
            for k, v in m["contact_tests"].items()
        )
    runs = m.get("runs")
    if suite == "suite" and isinstance(runs, Mapping):  # python -m benchmarks.run: one record per script
        return (
            "; ".join(
                f"{name} {r.get('wall_s', 0):.0f} s"
                + ("" if r.get("returncode") == 0 else f" (exit {r.get('returncode')})")
                for name, r in runs.items()
            )
            + " (each script's output in metrics.json)"
        )
    numbers = [f"{k} {v:.4g}" for k, v in m.items() if isinstance(v, (int, float)) and not isinstance(v, bool)]
    return ", ".join(numbers[:4]) or "see metrics.json"


def render_benchmarks(root: Path) -> str:
    rows = []
    for group in ("bench", "physics"):
        base = root / group
        if not base.is_dir():
            continue
        for run in load_runs(base):
            suite = run.path.relative_to(base).parts[0]
            m = run.manifest
            rows.append(
                [
                    f"{group}/{suite}",
                    run.path.name,
                    _bench_figure(suite, run.metrics),
                    f"`{m['command']}`",
                    f"{m['machine']}, {m['date']}, `{m['commit']}`",
                ]
            )
    table = Table(
        "Benchmarks and physics checks",
        ["Suite", "Run", "Figure", "Command", "Machine, date, commit"],
        rows,
        ["Each row is a folder results/<suite>/<run>/ (metrics.json, the script's output, manifest.json)."],
    )
    return table.to_markdown(compact=True)


def _n_seeds(n: int) -> str:
    return f"{n} seed{'s' * (n != 1)}"


def render_headline(root: Path) -> str:
    """One line per paper table: the paper's figure, ours (with its data preset and seeds), the page."""
    from tvrecon.data.presets import TABLE1, compose_preset, split_sizes

    lines = ["| Table | The paper | Ours | Page |", "|---|---|---|---|"]
    gen = load_runs(root / "table1")
    if gen:
        g = gen[0]
        touches = sum(s["touches"] for s in g.metrics["splits"].values())
        train, test = TABLE1["reconstruction"]["train"], TABLE1["reconstruction"]["test"]
        table1 = TABLE1["reconstruction"].items()
        ours = {p: split_sizes(compose_preset(p)) for p in ("paper", "paper_cpu")}
        same = [p for p, sizes in ours.items() if all(sizes.get(split) == size for split, size in table1)]
        sizes = f"the same split sizes in {', '.join(f'`{p}`' for p in same)}; " if same else ""
        lines.append(
            f"| 1: the data | reconstruction: {train.tactile:,} / {test.tactile:,} tactile images, {train.visual} / "
            f"{test.visual} views (train / test) | {sizes}`{g.metrics['preset']}` "
            f"generated whole, {touches:,} touches, in {g.manifest['wall_s'] / 60:.0f} min on "
            f"{', '.join(g.manifest['machine'].split(', ')[:2])} | [table1](docs/reproduce/table1.md) |"
        )
    runs, _ = _cls(root)
    best: tuple[float, str] | None = None
    groups: dict[tuple[str, str], list[float]] = {}
    for r in runs:
        if str(r.metrics["name"]).startswith("classify_paper_cpu") and "10" in r.metrics["accuracy"]:
            groups.setdefault((str(r.metrics["name"]), str(r.manifest["data_preset"])), []).append(
                100 * float(r.metrics["accuracy"]["10"])
            )
    for (name, preset), values in groups.items():
        cell = (
            f"{fmt_mean_std(values, 1)}% ({PRETTY_NAMES.get(name, name).lower()}, `{preset}`, {_n_seeds(len(values))})"
        )
        if best is None or sum(values) / len(values) > best[0]:
            best = (sum(values) / len(values), cell)
    if best:
        lines.append(
            f"| 2: classification, 10 touches | {PAPER_TABLE2[10][0]} +- {PAPER_TABLE2[10][1]}% | {best[1]} | "
            "[table2](docs/reproduce/table2.md) |"
        )
    _, results = _recon(root)
    # every model at the schedule (epochs, precision) of the paper's model's row with the most seeds
    by_name: dict[str, list[list[Mapping[str, Any]]]] = {}
    for _, runs_ in seed_groups(results):
        if not runs_[0].get("fixed_visual"):
            by_name.setdefault(str(runs_[0]["name"]), []).append(runs_)
    headline_schedule = schedule_of(max(by_name.get("full", [[{}]]), key=len)[0])
    groups3 = {
        name: next(g for g in groups if schedule_of(g[0]) == headline_schedule)
        for name, groups in by_name.items()
        if any(schedule_of(g[0]) == headline_schedule for g in groups)
    }
    paper = PAPER_TABLE3["Ours (the paper's fusion model)"]
    if "visual_only" in groups3 and "full" in groups3:
        vis = [r["modes"]["visual"]["chamfer"] for r in groups3["visual_only"]]
        full = [r["modes"]["tv@10"]["chamfer"] for r in groups3["full"]]
        ratio = (sum(full) / len(full)) / (sum(vis) / len(vis))
        preset = groups3["full"][0].get("data_preset")
        paper_cell = (
            f"Pixel2Mesh {paper['visual']}, the paper's model with 10 touches {paper['tv@10']} "
            f"({paper['tv@10'] / paper['visual']:.2f}x)"
        )
        line = (
            f"Pixel2Mesh {fmt_mean_std(vis)} ({_n_seeds(len(vis))}), the paper's model {fmt_mean_std(full)} "
            f"({ratio:.2f}x, {_n_seeds(len(full))})"
        )
        if "touch_geometry" in groups3:
            tg = [r["modes"]["tv@10"]["chamfer"] for r in groups3["touch_geometry"]]
            line += f"; touch geometry {fmt_mean_std(tg)} ({(sum(tg) / len(tg)) / (sum(vis) / len(vis)):.2f}x)"
        schedule = headline_schedule
        chart = [m for m in method_rows(results) if m.method.tactile_visual == "chart_based" and m.schedule == schedule]
        chart_ratio = touch_ratio(chart[0], 10) if chart else None
        if chart_ratio is not None:
            tv = [r["modes"]["tv@10"]["chamfer"] for r in chart[0].tactile_visual]
            own = "its own no-touch answer" if chart[0].visual_from_touch_model else "its visual-only model"
            line += (
                f"; Chart-based {fmt_mean_std(tv)} ({(sum(tv) / len(tv)) / (sum(vis) / len(vis)):.2f}x Pixel2Mesh, "
                f"{chart_ratio[0]:.2f}x {own}, {_n_seeds(len(tv))})"
            )
            chart_paper = PAPER_TABLE3["Chart-based (Smith et al. 2020)"]
            paper_cell += f"; Chart-based {chart_paper['tv@10']} ({chart_paper['tv@10'] / chart_paper['visual']:.2f}x)"
        line = f"| 3: reconstruction, chamfer x1e-3 | {paper_cell} | {line}"
        lines.append(
            line + f"; `{preset}`, {groups3['full'][0].get('epochs')} epochs | [table3](docs/reproduce/table3.md) |"
        )
        per_class = [r["modes"]["tv@10"].get("per_class", {}) for r in groups3["full"]]
        classes = [c for c in per_class[0] if all(c in p for p in per_class)]
        means = {c: sum(p[c] for p in per_class) / len(per_class) for c in classes}
        averages = [sum(p[c] for c in classes) / len(classes) for p in per_class]
        best_c, worst_c = min(means, key=means.get), max(means, key=means.get)
        paper4 = dict(zip(PAPER_TABLE4_CLASSES, PAPER_TABLE4["full"]))
        p_best, p_worst = min(paper4, key=paper4.get), max(paper4, key=paper4.get)
        lines.append(
            f"| 4: per class, 10 touches | the paper's model: average {PAPER_TABLE4['full'][-1]}, {p_best} "
            f"{paper4[p_best]} to {p_worst} {paper4[p_worst]} | the paper's model: average "
            f"{fmt_mean_std(averages)}, {best_c} {means[best_c]:.2f} to {worst_c} {means[worst_c]:.2f} "
            f"(means over {_n_seeds(len(per_class))}) | [table4](docs/reproduce/table4.md) |"
        )
    return "\n".join(lines) + "\n"


#: Registered renderers: block name -> function of the results root returning the block's Markdown.
RENDERERS: dict[str, Callable[[Path], str]] = {
    "headline": render_headline,
    "table1": render_table1,
    "table2": render_table2,
    "table3": render_table3,
    "table3_touches": render_table3_touches,
    "table3_controls": render_table3_controls,
    "table3_schedules": render_table3_schedules,
    "table4": render_table4,
    "benchmarks": render_benchmarks,
}


def render(name: str, root: Path = DEFAULT_ROOT, page: Path | None = None) -> str:
    """The Markdown of block ``name`` (a key of :data:`RENDERERS`) from the results under ``root``; its links into
    ``docs/`` are made relative to ``page`` (the Markdown file that holds the block; default: the repository root)."""
    if name not in RENDERERS:
        raise ValueError(f"unknown results block {name!r}: known are {', '.join(RENDERERS)}")
    text = RENDERERS[name](root)
    if page is not None:
        repo, here = root.resolve().parent, page.resolve().parent
        text = re.sub(
            r"\]\(docs/([^)]+)\)", lambda m: f"]({Path(os.path.relpath(repo / 'docs' / m[1], here)).as_posix()})", text
        )
    return text


def find_blocks(text: str) -> list[tuple[str, str]]:
    """The ``(name, body)`` of every results block in ``text``, in order."""
    return [(m["name"], m["body"]) for m in BLOCK.finditer(text)]


def fill_blocks(
    text: str, root: Path = DEFAULT_ROOT, page: Path | None = None, cache: dict[tuple[str, str], str] | None = None
) -> str:
    """``text`` (the content of ``page``) with every results block's body replaced by its render; ``cache`` keeps
    each render across pages."""
    cache = {} if cache is None else cache

    def body(m: re.Match[str]) -> str:
        name = m["name"]
        key = (name, str(page.resolve().parent) if page is not None else "")
        if key not in cache:
            cache[key] = render(name, root, page)
        return f"<!-- results:{name} -->\n{cache[key]}<!-- /results:{name} -->"

    return BLOCK.sub(body, text)


def default_paths(repo: Path) -> list[Path]:
    """README.md and every Markdown file under docs/ of the repository ``repo``."""
    return [p for p in [repo / "README.md", *sorted((repo / "docs").rglob("*.md"))] if p.is_file()]


def main(argv: Sequence[str] | None = None) -> int:
    """Fill (or with ``--check`` compare) the results blocks of the Markdown files; exit 1 when a block is stale."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m tvrecon.report.results_tables", description=main.__doc__)
    parser.add_argument("paths", nargs="*", type=Path, help="Markdown files (default: README.md and docs/**/*.md)")
    parser.add_argument("--root", type=Path, default=DEFAULT_ROOT, help="the results folder (default: results/)")
    parser.add_argument("--check", action="store_true", help="write nothing; name each stale block and exit 1")
    args = parser.parse_args(argv)
    paths = args.paths or default_paths(args.root.resolve().parent)
    cache: dict[tuple[str, str], str] = {}
    stale = []
    for path in paths:
        text = path.read_text()
        try:
            new = fill_blocks(text, args.root, path, cache)
        except (ValueError, FileNotFoundError, KeyError) as err:
            parser.error(f"{path}: {err}")
        if new == text:
            continue
        names = [n for (n, old), (_, fresh) in zip(find_blocks(text), find_blocks(new)) if old != fresh]
        if args.check:
            stale += [f"{path}: results:{n}" for n in names]
        else:
            atomic_write_text(path, new)
            print(f"{path}: rendered {', '.join(names)}")
    if stale:
        print("stale results blocks (run python -m tvrecon.report.results_tables):\n  " + "\n  ".join(stale))
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
