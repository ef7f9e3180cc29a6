"""What a Curriculum costs per step: the same Collector pipeline with and without it.

``python benchmarks/curriculum_overhead.py [--envs 1024] [--repeats 5] [--batches 20]
[--output runs/curriculum_overhead]``

Three pipelines are timed back to back in each repeat (medians reported), each the public
``torchrl.collectors.Collector`` (one torch thread, zero actions, the first batch not timed) over
``PendulumEnv(batch_size=[N])`` + ``StepCounter(200)`` + ``TaskTransform(swing_up_task())``:

- ``task``: nothing more (the reference);
- ``curriculum``: + ``Curriculum`` ramping the effort weight (``linear`` over 200,000 frames: a new value
  at every step for the first half of the default run) and staging the success bonus (``staged``, at
  100,000 frames): two scheduled buffers and the three entries ``("curriculum", ...)`` in the data;
- ``entries``: + a transform that only puts three prebuilt tensors of the same keys, shapes and dtypes
  in the data (registered in the observation spec as the Curriculum's): what TorchRL's carrying of the
  entries costs (one more transform, the spec, ``step_mdp``, the per-step copies and the final stack),
  the floor of any transform that reports its values in the data.

It prints frames/s and the ratios, and writes ``results.json`` into ``--output``. The measured ratios are in
``docs/curriculum.md`` ("Cost").
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from torchrl.collectors import Collector
from torchrl.data import Composite, Unbounded
from torchrl.envs import Compose, StepCounter, Transform, TransformedEnv

from torchtasks.envs import PendulumEnv, swing_up_task
from torchtasks.transforms import Curriculum, TaskTransform, linear, staged


class ZeroActions(torch.nn.Module):
    """The benchmark's policy: zero torques (one small tensor per step, the same in both pipelines)."""

    def __init__(self, envs: int) -> None:
        super().__init__()
        self.register_buffer("zeros", torch.zeros(envs, 1))

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return self.zeros.clone()


EFFORT = "wrapped_task.reward.rewards.effort.R"
ENTRIES = {"frames": torch.int64, EFFORT.replace(".", "/"): torch.float32, "success_value": torch.float32}
PIPELINES = ("task", "curriculum", "entries")


class PrebuiltEntries(Transform):
    """The floor: the Curriculum's three entries ``[N, 1]``, prebuilt once and put in the data at every step."""

    def __init__(self) -> None:
        super().__init__(in_keys=[], out_keys=[("curriculum", name) for name in ENTRIES])

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        for name, dtype in ENTRIES.items():
            observation_spec["curriculum", name] = Unbounded(shape=(*observation_spec.shape, 1), dtype=dtype)
        return observation_spec

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        entries = self.__dict__.get("_entries")
        if entries is None:
            batch = next_tensordict.batch_size
            entries = self.__dict__["_entries"] = {name: torch.zeros(*batch, 1, dtype=t) for name, t in ENTRIES.items()}
        node = TensorDict._new_unsafe(dict(entries), batch_size=next_tensordict.batch_size)
        next_tensordict._set_str("curriculum", node, inplace=False, validated=True)
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return self._step(tensordict, tensordict_reset)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        return tensordict


def make_env(envs: int, pipeline: str) -> TransformedEnv:
    """One of :data:`PIPELINES` (see the module docstring)."""
    transforms = [StepCounter(200), TaskTransform(swing_up_task())]
    if pipeline == "curriculum":
        schedules = {
            EFFORT: linear(torch.zeros(1), torch.full((1,), 0.001), 0, 200_000),
            "success_value": staged({0: 0.0, 100_000: 100.0}),
        }
        transforms.append(Curriculum(schedules))
    elif pipeline == "entries":
        transforms.append(PrebuiltEntries())
    elif pipeline != "task":
        raise ValueError(f"pipeline must be one of {PIPELINES}, got {pipeline!r}")
    return TransformedEnv(PendulumEnv(batch_size=[envs], seed=0), Compose(*transforms))


def frames_per_second(envs: int, pipeline: str, batches: int) -> float:
    """Frames/s of one pipeline over ``batches`` timed batches of 20 steps."""
    env = make_env(envs, pipeline)
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
    samples: dict[str, list[float]] = {name: [] for name in PIPELINES}
    try:
        for _ in range(args.repeats):
            for name in samples:
                samples[name].append(frames_per_second(args.envs, name, args.batches))
    finally:
        torch.set_num_threads(threads)
    medians = {name: statistics.median(values) for name, values in samples.items()}
    ratio = medians["curriculum"] / medians["task"]
    floor = medians["entries"] / medians["task"]
    print(
        f"PendulumEnv x{args.envs} in a Collector (medians of {args.repeats}): task {medians['task']:,.0f} frames/s; "
        f"+ Curriculum {medians['curriculum']:,.0f} frames/s = {ratio:.3f} of it; "
        f"+ its three entries prebuilt (the floor) {medians['entries']:,.0f} frames/s = {floor:.3f}"
    )
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)
    results = {"samples": samples, "medians": medians, "ratio": ratio, "floor_ratio": floor}
    (output / "results.json").write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
