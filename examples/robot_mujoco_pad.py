"""An EIP pad on a MuJoCo body: a pad lowered onto an object lying on the floor, read at every step.

    python examples/robot_mujoco_pad.py --object sphere --out outputs/mujoco_pad
    python examples/robot_mujoco_pad.py --object capsule --pad digit --steps 400

The pad is a box geom on a mocap body; ``tvrecon.robot.mujoco_sensor.TactileSensor`` turns it into a tactile sensor (as
TACTO's ``add_body`` does): at each step it reads MuJoCo's contacts of that geom and, when they change, presses the
touched geom's own surface with the EIP simulator, as deep as MuJoCo's overlap (``use_penetration=True``); with several
pads, ``sense_pads`` reads them all in one batched press (``docs/guides/robots.md``). Headless (``MUJOCO_GL=egl`` unless
set). Writes into ``--out``: ``tactile.png`` (the last reading's displacement), ``rgb.png`` (its GelSight-style image),
``force_N.csv`` (the normal force at each step) and ``summary.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")  # read once by mujoco at import: keep it headless

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from tvrecon.robot import PadConfig  # noqa: E402
from tvrecon.robot.mujoco.sensor import TactileSensor  # noqa: E402
from tvrecon.sim.plots import save_rgb_png, save_tactile_png  # noqa: E402
from tvrecon.utils.atomic import atomic_write_text  # noqa: E402
from tvrecon.utils.cli_errors import run_cli  # noqa: E402

#: MuJoCo geoms of the object, 1-2 cm across like a grasped part
OBJECTS = {
    "sphere": '<geom name="obj" type="sphere" size="0.012" mass="0.05"/>',
    "box": '<geom name="obj" type="box" size="0.012 0.012 0.012" mass="0.05"/>',
    "capsule": '<geom name="obj" type="capsule" size="0.008 0.015" euler="0 90 0" mass="0.05"/>',
}
#: half height of each object as it lies on the floor (metres)
HALF_HEIGHT = {"sphere": 0.012, "box": 0.012, "capsule": 0.008}

SCENE = """
<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <geom name="floor" type="plane" size="0.2 0.2 0.01"/>
    <body name="object" pos="0 0 0.03"><freejoint/>{object}</body>
    <body name="hand" mocap="true" pos="0 0 {start}">
      <geom name="pad" type="box" size="0.012 0.012 0.004" contype="1" conaffinity="1"/>
    </body>
  </worldbody>
</mujoco>
"""


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="robot_mujoco_pad.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--object", choices=sorted(OBJECTS), default="sphere")
    p.add_argument("--pad", default=None, help="real sensor preset (digit, tactip, ...); default: --resolution")
    p.add_argument("--resolution", type=int, default=16, help="tactile pixels a side of the default pad")
    p.add_argument("--n-grid", type=int, default=48, help="grid cells across the press domain")
    p.add_argument("--steps", type=int, default=300, help="simulation steps (the pad descends, then holds)")
    p.add_argument("--out", type=Path, default=None, help="output folder (default outputs/robot_mujoco_pad/<time>)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.steps < 10:
        raise ValueError(f"--steps must be >= 10 (the pad needs them to reach the object), got {args.steps}")
    start = 0.06
    model = mujoco.MjModel.from_xml_string(SCENE.format(object=OBJECTS[args.object], start=start))
    data = mujoco.MjData(model)
    pad = args.pad or PadConfig(resolution=(args.resolution, args.resolution), layers=3, pad_size=0.024,
                                n_grid=args.n_grid)
    sensor = TactileSensor(model, data, geom="pad", pad=pad, normal_axis=(0, 0, -1), up_axis=(1, 0, 0),
                           n_grid=args.n_grid, use_penetration=True)
    for _ in range(50):  # let the object settle on the floor
        mujoco.mj_step(model, data)
    top = float(data.geom("obj").xpos[2]) + HALF_HEIGHT[args.object]
    lowest = top - 0.003 + float(model.geom("pad").size[2])  # the pad's centre when its face is 3 mm in
    forces, reading = [], None
    for step in range(args.steps):
        frac = min(1.0, step / (0.7 * args.steps))  # descend over 70% of the steps, then hold
        data.mocap_pos[0] = [0.0, 0.0, start + (lowest - start) * frac]
        mujoco.mj_step(model, data)
        reading = sensor.sense()
        forces.append(float(reading.force))
    out = args.out or Path("outputs/robot_mujoco_pad") / time.strftime("%Y-%m-%d_%H-%M-%S")
    out.mkdir(parents=True, exist_ok=True)
    save_tactile_png(reading.image, out / "tactile.png", title=f"MuJoCo pad on a {args.object}")
    save_rgb_png(reading.rgb(), out / "rgb.png")
    atomic_write_text(out / "force_N.csv", "step,force_N\n" + "".join(f"{i},{f:.6g}\n" for i, f in enumerate(forces)))
    summary = {"object": args.object, "contact": bool(reading.contact), "force_N": forces[-1],
               "max_normal_cells": float(np.max(reading.image[2])), "presses": sensor.num_presses}
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=1) + "\n")
    print(f"{args.object}: contact {summary['contact']}, {forces[-1]:.3g} N, {sensor.num_presses} EIP presses -> {out}")
    return 0


if __name__ == "__main__":
    run_cli(main, prog="robot_mujoco_pad.py")
