"""``python -m tvrecon.data.shapes [--out DIR] [--instances 3]``: contact sheet PNG of every object class.

Without ``--out`` the sheet goes to ``outputs/shapes/<time>/``, like every command of the project.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from tvrecon.data.shapes.library import SPLITS, ObjectLibrary
from tvrecon.data.shapes.sheet import contact_sheet
from tvrecon.utils.output_dir import announce, output_dir


def main(argv: list[str] | None = None) -> Path:
    """Parse arguments, build ``instances`` objects per class from an ObjectLibrary and write the sheet."""
    parser = argparse.ArgumentParser(prog="python -m tvrecon.data.shapes", description=__doc__)
    parser.add_argument("--out", type=Path, default=None, help="output folder (default outputs/shapes/<time>)")
    parser.add_argument("--instances", type=int, default=3, help="instances per class (default 3)")
    parser.add_argument("--deform", type=float, default=0.0, help="deformation strength (default 0: raw shapes)")
    parser.add_argument("--user-root", type=Path, default=None, help="folder of user meshes, one subfolder per class")
    parser.add_argument("--split", choices=SPLITS, default="train")
    parser.add_argument("--size", type=int, default=160, help="tile size in pixels")
    parser.add_argument("--columns", type=int, default=5)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    lib = ObjectLibrary(user_root=args.user_root, deform=args.deform)
    path = contact_sheet(
        lambda cls, i: lib.get(cls, i, args.split),
        lib.classes,
        output_dir(args.out, "shapes") / "shapes_contact_sheet.png",
        instances=args.instances,
        size=args.size,
        columns=args.columns,
    )
    announce(path.parent)
    return path


if __name__ == "__main__":
    from tvrecon.utils.cli_errors import run_cli

    run_cli(main, prog="python -m tvrecon.data.shapes")  # errors: one line, exit 2 / 1 / 130
