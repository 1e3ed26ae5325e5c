"""The project speaks of itself in the present tense: no work-period or tracker words in what a reader sees.

A result is stated with its command, data preset, seed, commit and machine; the words of a work period or a tracker
item name neither. Scanned: README.md and every Markdown file, docs/, configs/, tvrecon/, tests/, benchmarks/,
examples/ (text files tracked by git, or present when git is unavailable). The pattern is the one the project's
pre-stop check greps for.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# the words are split so that this file holds no line the pattern matches
_PERIOD, _TRACKER = "sess" + "ions?", "iss" + "ue"
PATTERN = re.compile(rf"\b{_PERIOD}\b|\b{_TRACKER} #?[0-9]+", re.IGNORECASE)
FOLDERS = ("docs", "configs", "tvrecon", "tests", "benchmarks", "examples")
SUFFIXES = {".md", ".py", ".yaml", ".yml", ".sh", ".toml", ".txt", ".cfg", ".ini", ".json", ""}


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
    word, item = "sess" + "ion", "Iss" + "ue"
    for text in (f"the fourth {word}", f"{word.capitalize()}s of 15 minutes", f"see {item.lower()} 24",
                 f"{item} #7 case 1"):
        assert PATTERN.search(text), text
    for text in (f"open {item.lower()}s", f"an {item.lower()} of units", f"{word}less", f"{item.lower()}-free"):
        assert not PATTERN.search(text), text


def test_no_history_words() -> None:
    hits = []
    for path in _files():
        try:
            lines = path.read_text(encoding="utf-8").splitlines()
        except (UnicodeDecodeError, OSError):
            continue
        rel = path.relative_to(ROOT).as_posix()
        hits += [f"{rel}:{n}: {line.strip()[:120]}" for n, line in enumerate(lines, 1) if PATTERN.search(line)]
    assert not hits, f"{len(hits)} lines name a work period or a tracker item:\n" + "\n".join(hits[:60])
