"""What a Curriculum costs per step: the same Collector pipeline with and without it.

``python benchmarks/curriculum_overhead.py [--envs 1024] [--repeats 5] [--batches 20]
[--output runs/curriculum_overhead]``

Two pipelines are timed back to back in each repeat (medians reported), each a
``torchrl.collectors.Collector`` (one torch thread, zero actions, the first batch not timed) over
``PendulumEnv(batch_size=[N])`` + ``StepCounter(200)`` + ``TaskTransform(swing_up_task())``:

- ``task``: nothing more (the floor);
- ``curriculum``: + ``Curriculum`` ramping the effort weight (``linear``) and staging the success bonus
  (``staged``): two scheduled buffers written every step and their entries in the data.

It prints frames/s and the ratio, and writes ``results.json`` into ``--output``. Issue 24's constraint:
the curriculum keeps >= 0.9 of the frames/s of the same pipeline without it at 1,024 pendulums.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch
from tensordict.nn import TensorDictModule
from torchrl.collectors import Collector
from torchrl.envs import Compose, StepCounter, TransformedEnv

from torchtasks.curriculum import Curriculum, linear, staged
from torchtasks.envs import PendulumEnv, swing_up_task
from torchtasks.transforms import TaskTransform


class ZeroActions(torch.nn.Module):
    """The benchmark's policy: zero torques (one small tensor per step, the same in both pipelines)."""

    def __init__(self, envs: int) -> None:
        super().__init__()
        self.register_buffer("zeros", torch.zeros(envs, 1))

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return self.zeros.clone()


def make_env(envs: int, with_curriculum: bool) -> TransformedEnv:
    """The pipeline (see the module docstring)."""
    transforms = [StepCounter(200), TaskTransform(swing_up_task())]
    if with_curriculum:
        effort = "wrapped_task.reward.rewards.effort.R"
        transforms.append(
            Curriculum(
                {
                    effort: linear(torch.zeros(1), torch.full((1,), 0.001), 0, 200_000),
                    "success_value": staged({0: 0.0, 100_000: 100.0}),
                }
            )
        )
    return TransformedEnv(PendulumEnv(batch_size=[envs], seed=0), Compose(*transforms))


def frames_per_second(envs: int, with_curriculum: bool, batches: int) -> float:
    """Frames/s of one pipeline over ``batches`` timed batches of 20 steps."""
    env = make_env(envs, with_curriculum)
    policy = TensorDictModule(ZeroActions(envs), in_keys=["observation"], out_keys=["action"])
    collector = Collector(
        env, policy, frames_per_batch=envs * 20, total_frames=-1, auto_register_policy_transforms=False
    )
    iterator = iter(collector)
    next(iterator)
    frames, started = 0, time.perf_counter()
    for _ in range(batches):
        frames += next(iterator).numel()
    elapsed = time.perf_counter() - started
    collector.shutdown()
    return frames / elapsed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=1024, help="pendulums (default: 1024)")
    parser.add_argument("--repeats", type=int, default=5, help="repeats, medians reported (default: 5)")
    parser.add_argument("--batches", type=int, default=20, help="timed batches of 20 steps (default: 20)")
    parser.add_argument("--output", default="runs/curriculum_overhead", help="results folder")
    args = parser.parse_args(argv)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    samples: dict[str, list[float]] = {"task": [], "curriculum": []}
    try:
        for _ in range(args.repeats):
            for name in samples:
                samples[name].append(frames_per_second(args.envs, name == "curriculum", args.batches))
    finally:
        torch.set_num_threads(threads)
    medians = {name: statistics.median(values) for name, values in samples.items()}
    ratio = medians["curriculum"] / medians["task"]
    print(
        f"PendulumEnv x{args.envs}: task {medians['task']:,.0f} frames/s, + Curriculum {medians['curriculum']:,.0f} "
        f"frames/s: {ratio:.2f} of the pipeline without it (medians of {args.repeats})"
    )
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)
    (output / "results.json").write_text(json.dumps({"samples": samples, "medians": medians, "ratio": ratio}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
