"""Cost of the MuJoCo TactileSensor (issue 26 targets), measured against the EIP presses alone in the same run.

Scene: the can of the pick-and-place held between the gripper's two pads (``tvrecon.robot.mujoco.scene``), the
demo's pad (24x24x4 on n_grid 64) unless told otherwise. Rows:

- ``step, 2 pads in contact (new presses)``: ``mj_step`` + ``sense_pads(refresh=True)``: contacts read, both
  touches set up and pressed in one ``press_batch``, images resampled into the pad frames, patches;
- ``the two presses alone (press_batch)``: the same two touches through ``EIPSimulator.press_batch`` directly;
- ``the two presses alone (2 x press)``: the same two touches one after the other;
- ``step, 2 pads in contact (cached)``: the next steps, where the contact has not moved (no simulation);
- ``step, no contact``: the gripper open, ``mj_step`` + ``sense_pads``: rest readings (target < 5 ms).

Run: ``OMP_NUM_THREADS=1 python benchmarks/bench_mujoco_sensor.py [--repeats 3] [--resolution 24] [--n-grid 64]``.
Times are this process's CPU time (``time.process_time``), the presses taking turns, so other jobs on a shared
machine count less; the ratio (sensor step / presses alone) is the number to read.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from tvrecon.data.shapes import make_shape  # noqa: E402
from tvrecon.robot.mujoco.scene import MujocoScene  # noqa: E402
from tvrecon.robot.mujoco.sensor import TactileSensor  # noqa: E402
from tvrecon.robot.pad_config import PadConfig  # noqa: E402
from tvrecon.robot.pad_sensor import LazySimulator, sense_pads


def _time(fn, repeats: int) -> float:
    """Median CPU seconds of this process per call (not wall time: other jobs on a shared machine do not count)."""
    out = []
    for _ in range(repeats):
        t = time.process_time()
        fn()
        out.append(time.process_time() - t)
    return statistics.median(out)


def _interleaved(fns: dict, repeats: int) -> dict:
    """Median CPU seconds of each call, the calls taking turns so that a load change hits them alike."""
    out = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            out[k].append(_time(fn, 1))
    return {k: statistics.median(v) for k, v in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--resolution", type=int, default=24)
    ap.add_argument("--n-grid", type=int, default=64)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)

    scene = MujocoScene(make_shape("can", seed=0))
    pad = PadConfig(resolution=(args.resolution, args.resolution), n_grid=args.n_grid)
    sim = LazySimulator(pad)
    m, d = scene.model, scene.data
    pads = [
        TactileSensor(m, d, geom=f"{s}_pad", pad=pad, normal_axis=(0, -g, 0), up_axis=(0, 0, 1), simulator=sim)
        for s, g in (("left", 1), ("right", -1))
    ]

    # no contact: the gripper open above the can
    def free_step() -> None:
        mujoco_step()
        sense_pads(pads)

    def mujoco_step() -> None:
        scene.step()

    free = _time(free_step, 50 * args.repeats)
    mj = _time(mujoco_step, 50 * args.repeats)

    # grasp the can where it stands
    pos, _ = scene.object_pose()
    scene.command_hand(np.array([pos[0], pos[1], pos[2] + 0.1]), 0.0)
    scene.step(500)
    scene.command_hand(np.array([pos[0], pos[1], pos[2] + 0.003]), 0.0)
    scene.step(500)
    scene.grip(20.0)
    scene.step(400)
    if not all(r.contact for r in sense_pads(pads)):
        raise SystemExit("the pads do not both touch the can: the benchmark scene is broken")
    sense_pads(pads, refresh=True)  # warm-up (solver build)

    jobs = [p._measure(True)[1] for p in pads]

    def presses_batch() -> None:
        sim.press_batch(
            [j["mesh"] for j in jobs],
            torch.as_tensor(np.stack([j["position"] for j in jobs]), dtype=torch.float32),
            torch.as_tensor(np.stack([j["direction"] for j in jobs]), dtype=torch.float32),
            depth=jobs[0]["depth"] / pad.dx,
            threshold=None,
        )

    def presses_single() -> None:
        for j in jobs:
            sim.press(j["mesh"], j["position"], j["direction"], depth=j["depth"] / pad.dx, threshold=None)

    def contact_step() -> None:
        mujoco_step()
        sense_pads(pads, refresh=True)

    def cached_step() -> None:
        mujoco_step()
        sense_pads(pads)

    depths = {j["depth"] for j in jobs}
    t = _interleaved({"step": contact_step, "batch": presses_batch, "single": presses_single}, args.repeats)
    step_t, batch_t, single_t = t["step"], t["batch"], t["single"]
    cached_t = _time(cached_step, 50 * args.repeats)
    print(
        f"pad {args.resolution}x{args.resolution}x{pad.layers}, n_grid {args.n_grid}, {args.threads} thread(s), "
        f"press depths {sorted(round(x * 1e3, 3) for x in depths)} mm, median CPU time of {args.repeats}"
    )
    print("| row | ms | / presses alone (batch) |")
    print("|---|---|---|")
    for name, t in (
        ("step, 2 pads in contact (new presses)", step_t),
        ("the two presses alone (press_batch)", batch_t),
        ("the two presses alone (2 x press)", single_t),
        ("step, 2 pads in contact (cached)", cached_t),
        ("step, no contact", free),
        ("mj_step alone", mj),
    ):
        print(f"| {name} | {t * 1e3:.3f} | {t / batch_t:.3f} |")


if __name__ == "__main__":
    main()
