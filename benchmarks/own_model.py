"""Frames/s of BatchedMujocoEnv on a model of one's own against the bare ``mujoco.batch`` physics, interleaved.

``python benchmarks/own_model.py [--num-envs 64] [--repeats 5] [--seconds 1.0] [--output runs/own_model]``

The model is the shipped quadruped (``torchtasks.envs.models.model_path("quadruped")``: 12 position actuators,
contacts, an IMU), declared as a legged robot's policy observes it: joint positions around the "home" keyframe, joint
velocities, the torso's projected gravity and its linear and angular velocity in its own frame, the foot touch
sensors and the last action (48 values), with the torso height and velocity as task state, actions as position
targets around "home" (``Actions(scale=0.5, offset="home")``), resets to "home" with joint noise. In every repeat,
back to back so each ratio compares numbers taken under the same load:

- ``floor_batch``: ``Batch.step(nstep=4)`` of the env's own batch after writing precomputed controls into its bound
  ``ctrl`` rows: the physics alone (the floor).
- ``env``: a ``torchrl.collectors.Collector`` with uniform random actions over the env alone (no transforms): the
  env (its control map, substeps, every reading, resets) and TorchRL's per-step machinery.
- ``env_step_stage``: the same with ``stage="step"`` (readings as ``mj_step`` leaves ``MjData``): what taking the
  readings at the returned state costs.

Results: medians over the repeats, the ratio the median of per-repeat ratios, in ``<output>/results.json`` and
``<output>/results.md`` with the machine's load average before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torchrl.collectors import Collector

from torchtasks.bench.collector import uniform_policy
from torchtasks.envs import BatchedMujocoEnv, readings
from torchtasks.envs.models import model_path
from torchtasks.envs.mujoco_declaration import Actions, Noise, Resets

FRAME_SKIP = 4
LEGS = ("FL", "FR", "RL", "RR")


def quadruped_env(num_envs: int, stage: str = "velocity", seed: int = 0) -> BatchedMujocoEnv:
    """The benchmark's declaration of the shipped quadruped."""
    return BatchedMujocoEnv(
        model_path("quadruped"),
        num_envs,
        observation={
            "observation": [
                readings.joint_pos(
                    *(f"{leg}_{part}_joint" for leg in LEGS for part in ("hip", "thigh", "calf")), relative_to="home"
                ),
                readings.joint_vel(*(f"{leg}_{part}_joint" for leg in LEGS for part in ("hip", "thigh", "calf"))),
                readings.projected_gravity("torso"),
                readings.body_lin_vel("torso", frame="local"),
                readings.body_ang_vel("torso", frame="local"),
                *(readings.sensor(f"{leg}_touch") for leg in LEGS),
                readings.last_action(),
            ]
        },
        state={"height": readings.body_pos("torso", index=2), "velocity": readings.body_lin_vel("torso")},
        actions=Actions(scale=0.5, offset="home"),
        resets=Resets(keyframe="home", qvel_noise=Noise("normal", 0.1)),
        frame_skip=FRAME_SKIP,
        stage=stage,  # type: ignore[arg-type]
        seed=seed,
    )


def floor_batch(num_envs: int, seconds: float) -> float:
    """Frames/s of ``ctrl = action`` + ``Batch.step(nstep=4)`` on the env's own batch."""
    env = quadruped_env(num_envs)
    env.reset()
    batch, model = env.batch, env.model
    low, high = model.actuator_ctrlrange.T
    steps = 50
    actions = np.random.default_rng(0).uniform(low, high, size=(steps, num_envs, model.nu))
    ctrl = batch.bind("ctrl")
    frames, elapsed = 0, 0.0
    while elapsed < seconds:
        started = time.perf_counter()
        for action in actions:
            ctrl[:] = action
            batch.step(None, FRAME_SKIP)
        elapsed += time.perf_counter() - started
        frames += steps * num_envs
    env.close()
    return frames / elapsed


def env_collector(num_envs: int, seconds: float, stage: str) -> float:
    """Frames/s of a Collector with uniform random actions over the env alone."""
    env = quadruped_env(num_envs, stage)
    collector = Collector(env, uniform_policy(env), frames_per_batch=num_envs * 50, total_frames=-1)
    iterator = iter(collector)
    next(iterator)  # start-up, not timed
    frames, elapsed = 0, 0.0
    while elapsed < seconds:
        started = time.perf_counter()
        batch = next(iterator)
        elapsed += time.perf_counter() - started
        frames += batch.numel()
    collector.shutdown()
    env.close()
    return frames / elapsed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=1.0, help="time per measurement (%(default)s s)")
    parser.add_argument("--output", type=Path, default=Path("runs/own_model"))
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    rows: dict[str, list[float]] = {"floor_batch": [], "env": [], "env_step_stage": []}
    for repeat in range(args.repeats):
        rows["floor_batch"].append(floor_batch(args.num_envs, args.seconds))
        rows["env"].append(env_collector(args.num_envs, args.seconds, "velocity"))
        rows["env_step_stage"].append(env_collector(args.num_envs, args.seconds, "step"))
        print(f"repeat {repeat + 1}/{args.repeats}: " + ", ".join(f"{k} {v[-1]:,.0f}" for k, v in rows.items()))
    ratios = {
        key: statistics.median(value / floor for value, floor in zip(rows[key], rows["floor_batch"], strict=True))
        for key in ("env", "env_step_stage")
    }
    result: dict[str, Any] = {
        "command": "python benchmarks/own_model.py " + " ".join(argv or []),
        "num_envs": args.num_envs,
        "frames_per_second": rows,
        "median_frames_per_second": {key: statistics.median(value) for key, value in rows.items()},
        "ratio_to_floor": ratios,
        "load_average_before": load_before,
        "load_average_after": os.getloadavg(),
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "machine": platform.processor() or platform.machine(),
        "threads": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
    }
    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / "results.json").write_text(json.dumps(result, indent=2))
    medians = result["median_frames_per_second"]
    table = [
        f"Shipped quadruped x{args.num_envs}, {args.repeats} repeats, {result['date']}, load "
        f"{load_before[0]:.1f} -> {result['load_average_after'][0]:.1f}",
        "",
        "| variant | frames/s (median) | ratio to the Batch.step floor |",
        "|---|---|---|",
        f"| floor_batch (Batch.step, physics alone) | {medians['floor_batch']:,.0f} | 1.00 |",
        f"| env (stage='velocity'), Collector | {medians['env']:,.0f} | {ratios['env']:.2f} |",
        f"| env (stage='step'), Collector | {medians['env_step_stage']:,.0f} | {ratios['env_step_stage']:.2f} |",
    ]
    (args.output / "results.md").write_text("\n".join(table) + "\n")
    print("\n".join(table))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
