"""How far the cheetah-run preset's episode starts are from dm_control's for the same drawn pose.

dm_control's cheetah reset draws the limited joints, then runs 200 physics steps with zero controls whose first
step finishes a step begun for the default pose (an ``mj_step2`` on the forward results of ``qpos0``); the preset's
reset step ``SettleFromDefaultStep(200)`` does the same. This script resets the preset's ``--envs`` envs (``seed``
0), replays each env's draw from its generator, checks that dm_control's settling written in plain MuJoCo 4.0.0 (the
forward pass of ``qpos0``, the draw, ``mj_step2``, ``mj_step`` x 199, ``mj_step1``) gives the preset's start bit for
bit, hands the same draws to dm_control's own ``initialize_episode`` in the reference venv, and reports the largest
``|qpos|`` difference of the settled starts (MuJoCo 4.0.0 against 3.17.0), and for scale that of a plain
``mj_step`` x 200 from the drawn pose (the settling without dm_control's first step). Run from the repository root,
with the reference venv built::

    python docs/_scripts/cheetah_settling.py --output docs/_generated

Writes ``cheetah_settling.json`` into ``--output``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from torchtasks.envs.control_suite import control_suite_base_env
from torchtasks.envs.control_suite.reference import HOW_TO_BUILD, reference_python

#: runs in the reference venv: dm_control's cheetah reset, with each draw given instead of drawn
DM_CONTROL_RESETS = """
import json, sys
import numpy as np
from dm_control import suite

draws = np.array(json.load(sys.stdin))
env = suite.load("cheetah", "run", task_kwargs={"random": 0})


class GivenDraw:  # the task's generator, answering its one uniform(lower, upper) call with the given draw
    def __init__(self, value):
        self.value = value

    def uniform(self, low, high):
        assert np.shape(low) == self.value.shape
        return self.value


starts = []
for draw in draws:
    env.task._random = GivenDraw(draw)
    env.reset()
    starts.append(env.physics.data.qpos.tolist())
print(json.dumps(starts))
"""


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", default="runs/cheetah_settling", help="folder of cheetah_settling.json")
    args = parser.parse_args(argv)
    python = reference_python()
    if python is None:
        raise SystemExit(f"no dm_control reference: {HOW_TO_BUILD}")

    env = control_suite_base_env("cheetah-run", args.envs, seed=args.seed)
    env.reset()
    ours = np.array(env.batch.bind("qpos"))
    model = env.model
    env.close()

    # each env's draw, replayed from its generator (spawned from the seed as the env spawns them)
    limited = np.flatnonzero(model.jnt_limited)
    columns = model.jnt_qposadr[limited]
    low, high = model.jnt_range[limited].T
    children = np.random.SeedSequence(args.seed).spawn(args.envs)
    draws = np.array([np.random.Generator(np.random.PCG64(child)).uniform(low, high) for child in children])
    data = mujoco.MjData(model)
    for i, draw in enumerate(draws):  # dm_control's settling in plain MuJoCo 4.0.0 is the preset's, bit for bit
        mujoco.mj_resetData(model, data)
        mujoco.mj_forward(model, data)
        data.qpos[columns] = draw
        mujoco.mj_step2(model, data)
        mujoco.mj_step(model, data, 199)
        mujoco.mj_step1(model, data)
        if not np.array_equal(data.qpos, ours[i]):
            raise AssertionError(f"env {i}: dm_control's settling in MuJoCo 4.0.0 does not give the preset's start")

    environment = {key: value for key, value in os.environ.items() if key not in ("PYTHONPATH", "PYTHONHOME")}
    environment["MUJOCO_GL"] = "disable"
    reply = subprocess.run(
        [python, "-c", DM_CONTROL_RESETS],
        input=json.dumps(draws.tolist()),
        capture_output=True,
        text=True,
        env=environment,
        check=True,
    )
    theirs = np.array(json.loads(reply.stdout))
    difference = np.abs(ours - theirs).max(axis=1)
    # for scale: the settling without dm_control's first step (200 plain mj_step from the drawn pose)
    plain = np.empty_like(ours)
    for i, draw in enumerate(draws):
        mujoco.mj_resetData(model, data)
        data.qpos[columns] = draw
        mujoco.mj_step(model, data, 200)
        mujoco.mj_step1(model, data)
        plain[i] = data.qpos
    without_first_step = np.abs(plain - theirs).max(axis=1)
    results = {
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "command": " ".join(["python", "docs/_scripts/cheetah_settling.py", *(sys.argv[1:] if argv is None else argv)]),
        "envs": args.envs,
        "seed": args.seed,
        # 6 significant digits: a JSON of full-length floats reads like commit hashes
        "largest_qpos_difference": float(f"{difference.max():.6g}"),
        "median_qpos_difference": float(f"{np.median(difference):.6g}"),
        "largest_qpos_difference_without_the_first_step": float(f"{without_first_step.max():.6g}"),
        "median_qpos_difference_without_the_first_step": float(f"{np.median(without_first_step):.6g}"),
        "mujoco": mujoco.__version__,
    }
    folder = Path(args.output)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "cheetah_settling.json").write_text(json.dumps(results, indent=1) + "\n")
    print(json.dumps(results, indent=1))
    return results


if __name__ == "__main__":
    main()
