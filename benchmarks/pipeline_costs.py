"""Where a Collector step over BatchedMujocoEnv goes: the same pipeline with and without the task's parts.

``python benchmarks/pipeline_costs.py [--cases HalfCheetah-v5:64 Hopper-v5:64] [--repeats 3] [--steps 1000]
[--output runs/pipeline_costs]``

For every case, four pipelines are timed back to back in each repeat (medians reported), each a
``torchrl.collectors.Collector`` (one torch thread, the uniform random policy of
``benchmarks/batched_mujoco.py``, the first batch not timed) over ``BatchedMujocoEnv(env_id, N,
num_threads=2)`` with:

- ``counters``: ``StepCounter(1000)`` + ``RewardSum()`` (no task: nothing ends an episode but the time limit);
- ``task``: ``StepCounter(1000)`` + ``TaskTransform(locomotion_task(env_id))`` + ``RewardSum()`` (the pipeline
  of ``benchmarks/batched_mujoco.py``);
- ``task_no_terms``: the same with ``TaskTransform(..., log_terms=False)`` (no reward breakdown entries);
- ``physics``: the physics floor of the same batch (threaded ``mj_step``, as in ``batched_mujoco.py``).

It prints milliseconds per step (one step = all N envs) and frames/s, and writes ``results.json`` and
``results.md`` into ``--output``. The difference ``task - counters`` is what the task adds (its maths,
its flags, its reward breakdown and, for envs that terminate, the partial resets it causes);
``task - task_no_terms`` is what the breakdown's reward entries cost in TorchRL.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
from pathlib import Path
from typing import Any

import torch
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv

sys.path.insert(0, str(Path(__file__).resolve().parent))
from batched_mujoco import _collector_frames_per_second, floor_threads

from torchtasks.envs import BatchedMujocoEnv
from torchtasks.envs.locomotion import locomotion_state_layout, locomotion_task
from torchtasks.transforms import TaskTransform

VARIANTS = ("physics", "counters", "task", "task_no_terms")


def make_env(env_id: str, num_envs: int, variant: str, num_threads: int) -> TransformedEnv:
    """The pipeline of ``variant`` (see the module docstring)."""
    base = BatchedMujocoEnv(env_id, num_envs, seed=0, num_threads=num_threads)
    transforms = [StepCounter(1000)]
    if variant != "counters":
        task = locomotion_task(env_id)
        layout = list(locomotion_state_layout(env_id))
        transforms.append(TaskTransform(task, state_key=layout, log_terms=variant == "task"))
    transforms.append(RewardSum())
    return TransformedEnv(base, Compose(*transforms))


def measure(env_id: str, num_envs: int, variant: str, steps: int, num_threads: int) -> float:
    """Frames/s of ``variant``."""
    if variant == "physics":
        return floor_threads(env_id, num_envs, steps, num_threads)
    return _collector_frames_per_second(lambda: make_env(env_id, num_envs, variant, num_threads), num_envs, steps)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["HalfCheetah-v5:64", "Hopper-v5:64"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--steps", type=int, default=1000, help="steps per measurement (each step: all N envs)")
    parser.add_argument("--threads", type=int, default=2, help="MuJoCo threads of the env")
    parser.add_argument("--output", type=Path, default=Path("runs/pipeline_costs"))
    args = parser.parse_args(argv)
    rows: list[dict[str, Any]] = []
    load_before = os.getloadavg()
    for spec in args.cases:
        env_id, _, size = spec.partition(":")
        num_envs = int(size)
        samples: dict[str, list[float]] = {variant: [] for variant in VARIANTS}
        for _ in range(args.repeats):
            for variant in VARIANTS:
                samples[variant].append(measure(env_id, num_envs, variant, args.steps, args.threads))
        fps = {variant: statistics.median(values) for variant, values in samples.items()}
        ms = {variant: 1e3 * num_envs / value for variant, value in fps.items()}
        rows.append({"env_id": env_id, "num_envs": num_envs, "frames_per_second": fps, "ms_per_step": ms})
        print(
            f"{env_id} x{num_envs}: "
            + ", ".join(f"{variant} {ms[variant]:.2f} ms ({fps[variant]:,.0f} frames/s)" for variant in VARIANTS),
            flush=True,
        )
    lines = [
        f"ms per step (frames/s), {args.threads} MuJoCo threads, one torch thread, medians of {args.repeats} repeats, "
        f"load average {load_before[0]:.2f} -> {os.getloadavg()[0]:.2f}",
        "",
        "| case | " + " | ".join(VARIANTS) + " | task - counters | task - task_no_terms |",
        "|---|" + "---|" * (len(VARIANTS) + 2),
    ]
    for row in rows:
        ms, fps = row["ms_per_step"], row["frames_per_second"]
        cells = [f"{ms[variant]:.2f} ({fps[variant]:,.0f})" for variant in VARIANTS]
        extra = [f"{ms['task'] - ms['counters']:+.2f}", f"{ms['task'] - ms['task_no_terms']:+.2f}"]
        lines.append(f"| {row['env_id']} × {row['num_envs']} | " + " | ".join(cells + extra) + " |")
    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / "results.md").write_text("\n".join(lines) + "\n")
    meta = {"threads": args.threads, "repeats": args.repeats, "steps": args.steps, "torch": torch.__version__}
    (args.output / "results.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
    print("\n".join(lines))
    print(f"results in {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
