"""The project speaks of itself in the present tense: no work-period or tracker words in what a reader sees.

A result is stated with its command, data preset, seed, commit and machine; "session(s)" and "issue N" name neither.
Scanned: README.md and every Markdown file, docs/, configs/, tvrecon/, tests/, benchmarks/, examples/ (text files
tracked by git, or present when git is unavailable).

:data:`BEING_REWRITTEN` holds the paths that branches being merged beside this one rewrite or delete (the research
notebooks become notes pages, benchmarks/ is reorganised, its results move to results/). They are skipped while they
still hold the words; an entry whose path no longer holds any fails the test, so the list empties as those merges land
(and goes once empty)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PATTERN = re.compile(r"\bsessions?\b|\bissue #?[0-9]+", re.IGNORECASE)
FOLDERS = ("docs", "configs", "tvrecon", "tests", "benchmarks", "examples")
SUFFIXES = {".md", ".py", ".yaml", ".yml", ".sh", ".toml", ".txt", ".cfg", ".ini", ".json", ""}
#: path prefix -> who rewrites it
BEING_REWRITTEN = {
    "benchmarks/": "the benchmarks reorganisation (notes) and the results move (results)",
    "docs/cls-preset.md": "the notes pages",
    "docs/physics.md": "the notes pages",
    "docs/results-small.md": "the notes pages",
    "docs/table2-cpu.md": "the notes pages",
    "docs/table2-paper-touches.md": "the notes pages",
    "docs/table2-touch-poses.md": "the notes pages",
    "docs/table3-paper-touches.md": "the notes pages",
}


def _files() -> list[Path]:
    try:
        out = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT, capture_output=True,
                             text=True, check=True).stdout.split("\n")
        paths = [ROOT / p for p in out if p]
    except (OSError, subprocess.CalledProcessError):
        paths = [p for p in ROOT.rglob("*") if ".venv" not in p.parts and ".git" not in p.parts]
    keep = []
    for p in paths:
        rel = p.relative_to(ROOT)
        scanned = rel.suffix == ".md" or (rel.parts and rel.parts[0] in FOLDERS)
        if scanned and p.is_file() and p.suffix in SUFFIXES:
            keep.append(p)
    return keep


def test_pattern_finds_what_it_must() -> None:
    for text in ("the fourth session", "Sessions of 15 minutes", "see issue 24", "Issue #7 case 1"):
        assert PATTERN.search(text), text
    for text in ("open issues", "an issue of units", "sessionless", "issue-free"):
        assert not PATTERN.search(text), text


def _pending(rel: str) -> str | None:
    return next((prefix for prefix in BEING_REWRITTEN if rel.startswith(prefix)), None)


def test_no_history_words() -> None:
    hits, pending_hit = [], set()
    for path in _files():
        try:
            lines = path.read_text(encoding="utf-8").splitlines()
        except (UnicodeDecodeError, OSError):
            continue
        for number, line in enumerate(lines, 1):
            if PATTERN.search(line) and path.name != Path(__file__).name:
                rel = path.relative_to(ROOT).as_posix()
                if _pending(rel):
                    pending_hit.add(_pending(rel))
                else:
                    hits.append(f"{rel}:{number}: {line.strip()[:120]}")
    assert not hits, f"{len(hits)} lines name a work period or a tracker item:\n" + "\n".join(hits[:60])
    done = sorted(set(BEING_REWRITTEN) - pending_hit)
    assert not done, f"{done} hold no such words any more: remove them from BEING_REWRITTEN in {Path(__file__).name}"
