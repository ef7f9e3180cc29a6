"""Where a Collector step over the batched preset goes: the physics, then the pipeline one transform at a time.

``python benchmarks/pipeline_costs.py [--cases HalfCheetah-v5:64 Hopper-v5:64] [--repeats 5] [--steps 500]
[--threads 2] [--output runs/pipeline_costs]``

For every case, these are timed back to back in each repeat (medians reported), each Collector with one torch
thread and the uniform random policy of ``benchmarks/batched_mujoco.py`` (``UniformActions``), the first batch not
timed:

- ``physics``: ``ctrl = action`` + ``mujoco.batch.Batch.step(nstep=frame_skip)`` of the env's own batch (the
  floor of ``batched_mujoco.py``, no TorchRL);
- ``env``: a Collector over ``BatchedMujocoEnv(env_id, N)`` alone;
- ``+StepCounter``: the same with ``StepCounter(1000)``;
- ``+task``: and the locomotion task's ``TaskTransform`` (its reward, terms, success/failure flags);
- ``+ZeroBrokenStepReward``: and the transform that pays 0 for broken steps;
- ``preset``: ``gymnasium_env(env_id, num_envs=N, backend="batched")``, the stack above plus ``RewardSum()``
  over the reward and the terms: what users build;
- ``preset, no physics``: the preset's four transforms over an env with ``BatchedMujocoEnv``'s specs that
  simulates nothing (it returns zeros): what TorchRL and the transforms cost per step without MuJoCo;
- ``preset + domain``: the preset with a ``DomainRandomization`` appended that draws every env's total mass and
  friction (``body_mass_scale``, ``geom_friction_scale``, uniform ±30%) at each of its resets: masses need
  ``mj_setConst`` for the reset envs. The ``domain cost`` column is ``1 - frames/s(preset + domain) /
  frames/s(preset)`` of each repeat, the median over repeats (a random policy ends Hopper's episodes within ~20
  steps, so some env resets in almost every step; HalfCheetah never ends before 1000 steps: there the cost is the
  entries written at every step).
- ``MO preset``: ``multi_objective_env("mo-<env>-v5", num_envs=N, backend="batched")``, the preset whose task is
  a ``RewardGroupsTask`` writing MO-Gymnasium's float32 vector reward and one entry per objective (summed by its
  ``RewardSum`` too). The ``groups cost`` column is ``1 - frames/s(MO preset) / frames/s(preset)``, the median over
  repeats: what the reward groups cost when used. (Unused, they cost nothing: ``preset`` builds no group.)

It prints milliseconds per step (one step = all N envs) and frames/s, and writes ``results.json`` and
``results.md`` into ``--output``. A layer's cost is the difference to the row before it; ``preset`` minus
``physics`` against ``preset, no physics`` says how much of the pipeline's own time the physics' threads slow
down (the Python of a step runs with caches the physics just used).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import Compose, EnvBase, RewardSum, StepCounter, TransformedEnv

sys.path.insert(0, str(Path(__file__).resolve().parent))
from batched_mujoco import _collector_frames_per_second, floor_batch

from torchtasks.domain import UniformDomainParam
from torchtasks.envs import BatchedMujocoEnv, gymnasium_env
from torchtasks.envs.batched_mujoco import ZeroBrokenStepReward
from torchtasks.envs.locomotion import locomotion_state_layout, locomotion_task
from torchtasks.envs.multi_objective import multi_objective_env
from torchtasks.transforms import DomainRandomization, TaskTransform

VARIANTS = (
    "physics",
    "env",
    "+StepCounter",
    "+task",
    "+ZeroBrokenStepReward",
    "preset",
    "preset, no physics",
    "preset + domain",
    "MO preset",
)


class NoPhysicsEnv(EnvBase):
    """An env with the specs of ``BatchedMujocoEnv(env_id, num_envs)`` that simulates nothing: every entry is zero.

    Its outputs are fresh tensors each step, as the batched env's are, so a Collector over it pays what TorchRL and
    the transforms cost per step and nothing else.
    """

    batch_locked = True

    def __init__(self, like: BatchedMujocoEnv) -> None:
        super().__init__(batch_size=like.batch_size)
        self.observation_spec = like.observation_spec.clone()
        self.action_spec = like.action_spec.clone()
        self.reward_spec = like.reward_spec.clone()
        self.done_spec = like.done_spec.clone()
        self.last_step_broken = False  # what ZeroBrokenStepReward reads from a BatchedMujocoEnv
        entries = {**self.observation_spec, **self.done_spec}
        self._entries = {key: (spec.shape, spec.dtype) for key, spec in entries.items()}
        self._reward = (self.reward_spec.shape, self.reward_spec.dtype)

    def _outputs(self, reward: bool) -> TensorDictBase:
        out = {key: torch.zeros(shape, dtype=dtype) for key, (shape, dtype) in self._entries.items()}
        if reward:
            out["reward"] = torch.zeros(self._reward[0], dtype=self._reward[1])
        return TensorDict._new_unsafe(out, batch_size=self.batch_size)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        return self._outputs(reward=True)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        return self._outputs(reward=False)

    def _set_seed(self, seed: int | None) -> None:
        pass


#: the fields the ``preset + domain`` variant draws at every reset
DOMAIN_FIELDS = ("body_mass_scale", "geom_friction_scale")


def _stack(base: EnvBase, env_id: str, layers: int) -> EnvBase:
    """``base`` with the first ``layers`` transforms of the batched preset (0: the env alone)."""
    if layers == 0:
        return base
    transforms = [
        StepCounter(1000),
        TaskTransform(locomotion_task(env_id), state_key=list(locomotion_state_layout(env_id))),
        ZeroBrokenStepReward(),
        RewardSum(),
    ][:layers]
    return TransformedEnv(base, Compose(*transforms))


def make_env(env_id: str, num_envs: int, variant: str, num_threads: int) -> EnvBase:
    """The pipeline of ``variant`` (see the module docstring)."""
    if variant == "MO preset":  # MO-Gymnasium's id of the same env: "mo-halfcheetah-v5" for "HalfCheetah-v5"
        mo_id = "mo-" + env_id.lower()
        return multi_objective_env(mo_id, num_envs=num_envs, seed=0, backend="batched", num_threads=num_threads)
    if variant in ("preset", "preset + domain"):
        env = gymnasium_env(env_id, num_envs=num_envs, seed=0, backend="batched", num_threads=num_threads)
        if variant == "preset + domain":
            params = [UniformDomainParam(name, mean=1.0, halfspan=0.3) for name in DOMAIN_FIELDS]
            env.append_transform(DomainRandomization(params, seed=0))
        return env
    base = BatchedMujocoEnv(env_id, num_envs, seed=0, num_threads=num_threads)
    if variant == "preset, no physics":
        return _stack(NoPhysicsEnv(base), env_id, 4)
    layers = ("env", "+StepCounter", "+task", "+ZeroBrokenStepReward").index(variant)
    return _stack(base, env_id, layers)


def measure(env_id: str, num_envs: int, variant: str, steps: int, num_threads: int) -> float:
    """Frames/s of ``variant``."""
    if variant == "physics":
        return floor_batch(env_id, num_envs, steps, num_threads)
    make: Callable[[], EnvBase] = lambda: make_env(env_id, num_envs, variant, num_threads)  # noqa: E731
    return _collector_frames_per_second(make, num_envs, steps)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["HalfCheetah-v5:64", "Hopper-v5:64"])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--steps", type=int, default=500, help="steps per measurement (each step: all N envs)")
    parser.add_argument("--threads", type=int, default=2, help="MuJoCo threads of the env")
    parser.add_argument("--output", type=Path, default=Path("runs/pipeline_costs"))
    args = parser.parse_args(argv)
    command = shlex.join(["python", "benchmarks/pipeline_costs.py", *(sys.argv[1:] if argv is None else argv)])
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
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
        # each repeat's ratio to its own physics floor, the median over repeats
        ratio = {
            variant: statistics.median(v / p for v, p in zip(values, samples["physics"], strict=True))
            for variant, values in samples.items()
        }
        domain_cost = statistics.median(
            1.0 - d / p for d, p in zip(samples["preset + domain"], samples["preset"], strict=True)
        )
        groups_cost = statistics.median(
            1.0 - m / p for m, p in zip(samples["MO preset"], samples["preset"], strict=True)
        )
        rows.append(
            {
                "domain_cost": domain_cost,
                "groups_cost": groups_cost,
                "env_id": env_id,
                "num_envs": num_envs,
                "frames_per_second": fps,
                "ms_per_step": ms,
                "ratio_to_physics": ratio,
                "raw_frames_per_second": samples,
            }
        )
        print(
            f"{env_id} x{num_envs}: "
            + ", ".join(f"{variant} {ms[variant]:.2f} ms ({ratio[variant]:.2f})" for variant in VARIANTS)
            + f"; domain cost {100 * domain_cost:.1f}%; groups cost {100 * groups_cost:.1f}%",
            flush=True,
        )
    load_after = os.getloadavg()
    lines = [
        f"ms per step (in brackets: frames/s ÷ the physics floor's frames/s of the same repeat; medians of "
        f"{args.repeats} repeats, {args.threads} MuJoCo threads, one torch thread; {started}, 1-minute load average "
        f"{load_before[0]:.2f} before, {load_after[0]:.2f} after; `{command}`)",
        "",
        "| case | " + " | ".join(VARIANTS) + " | domain cost | groups cost |",
        "|---|" + "---|" * (len(VARIANTS) + 2),
    ]
    for row in rows:
        ms, ratio = row["ms_per_step"], row["ratio_to_physics"]
        cells = [f"{ms[variant]:.2f} ({ratio[variant]:.2f})" for variant in VARIANTS]
        cells.append(f"{100 * row['domain_cost']:.1f}%")
        cells.append(f"{100 * row['groups_cost']:.1f}%")
        lines.append(f"| {row['env_id']} × {row['num_envs']} | " + " | ".join(cells) + " |")
    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / "results.md").write_text("\n".join(lines) + "\n")
    meta = {
        "threads": args.threads,
        "repeats": args.repeats,
        "steps": args.steps,
        "torch": torch.__version__,
        "command": command,
        "time": started,
        "load_average_before": load_before,
        "load_average_after": load_after,
    }
    (args.output / "results.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
    print("\n".join(lines))
    print(f"results in {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
