"""Collect with a torchtasks task on a Ray cluster: ``Collector(backend="ray")`` with a ``TaskTransform``.

What it shows: the task travels with the env. Each Ray worker builds its own batched torch pendulum
(:class:`~torchtasks.envs.PendulumEnv`) with ``StepCounter`` + ``TaskTransform(swing_up_task())`` +
``RewardSum`` from a picklable module-level constructor, runs a TorchRL ``Collector`` in a Ray actor
and ships batches back; the task's reward, success flag, episode ends and per-term reward breakdown
(``("task_reward", "track" | "effort" | "step" | "final")`` and their ``RewardSum`` episode sums)
arrive in the driver like any other entry. The policy is the classical swing-up controller of the
``torchtasks demo`` (no learning), so episodes end in success and the counts are meaningful.

Set-up:

- ``--workers`` remote collectors (one Ray actor each, ``num_cpus=1``), each stepping ``--envs``
  pendulums as one batch; episodes are truncated after ``MAX_STEPS`` steps.
- Env constructors are ``functools.partial`` objects of the module-level :func:`make_env`, so they
  pickle (a lambda or a closure would not survive the trip to a worker).
- By default a local Ray cluster is started with ``ray.init(num_cpus=...)`` and shut down at the end.

Run it on this machine::

    python examples/distributed_ray.py            # 2 workers, 64k frames
    python examples/distributed_ray.py --quick    # a few seconds once Ray is up (used by the tests)

Run it on an existing Ray cluster: start the cluster (``ray start --head`` on the head node,
``ray start --address=HEAD_IP:6379`` on the others; torch, torchrl and torchtasks must be
importable on every node), then pass its address, which goes to ``ray.init(address=...)``::

    python examples/distributed_ray.py --address HEAD_IP:6379 --workers 8
    python examples/distributed_ray.py --address auto        # from a node of the cluster

With ``--address`` the script connects to the cluster and only disconnects at the end
(``ray.shutdown()`` in a client leaves the cluster running). Recent Ray versions start clusters with
token authentication: the driver then needs the cluster's token (see Ray's token-auth docs), or start
a private test cluster with ``RAY_AUTH_MODE=disabled ray start --head``.
"""

from __future__ import annotations

import argparse
import functools
import os
import time
from pathlib import Path

import ray
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torchrl.collectors import Collector
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv

from torchtasks.demo import SwingUpController
from torchtasks.envs import PendulumEnv, swing_up_task
from torchtasks.transforms import TaskTransform

MAX_STEPS = 200  # episode time limit (StepCounter)
TERMS = ("track", "effort", "step", "final")  # the reward breakdown written by TaskTransform


def make_env(num_envs: int, seed: int) -> TransformedEnv:
    """Return ``num_envs`` batched pendulums with the swing-up task (module level: picklable for Ray workers)."""
    return TransformedEnv(
        PendulumEnv(batch_size=[num_envs], seed=seed),
        Compose(StepCounter(MAX_STEPS), TaskTransform(swing_up_task()), RewardSum()),
    )


def make_policy() -> TensorDictModule:
    """The energy-pumping + PD swing-up controller of ``torchtasks demo``, reading ``"observation"``."""
    return TensorDictModule(SwingUpController(), in_keys=["observation"], out_keys=["action"])


def start_ray(address: str | None, num_cpus: int) -> None:
    """Connect to the cluster at ``address`` or start a local one with ``num_cpus`` CPUs."""
    if address is not None:
        ray.init(address=address, log_to_driver=False)
        return
    # Workers start from this interpreter; make this folder importable in them too (harmless when the
    # example runs as a script, whose module-level functions Ray pickles by value).
    here = str(Path(__file__).resolve().parent)
    python_path = os.pathsep.join(filter(None, [here, os.environ.get("PYTHONPATH")]))
    ray.init(
        num_cpus=num_cpus,
        include_dashboard=False,
        log_to_driver=False,
        runtime_env={"env_vars": {"PYTHONPATH": python_path}},
    )


class EpisodeStats:
    """Running sums of the episodes that ended in collected batches."""

    def __init__(self) -> None:
        self.frames = 0
        self.batches = 0
        self.episodes = 0
        self.successes = 0
        self.truncations = 0
        self.episode_reward = 0.0
        self.terms = dict.fromkeys(TERMS, 0.0)

    def update(self, batch: TensorDictBase) -> None:
        nxt = batch["next"]
        ended = nxt["done"]
        self.frames += batch.numel()
        self.batches += 1
        self.episodes += int(ended.sum())
        self.successes += int(nxt["success"].sum())
        self.truncations += int((nxt["truncated"] & ~nxt["success"] & ~nxt["failure"]).sum())
        self.episode_reward += float(nxt["episode_reward"][ended].sum())
        for name in TERMS:
            self.terms[name] += float(nxt["task_reward", f"episode_{name}"][ended].sum())

    def report(self) -> str:
        n = max(self.episodes, 1)
        lines = [
            f"frames collected: {self.frames} in {self.batches} batches",
            f"episodes ended: {self.episodes} (successes: {self.successes}, truncations: {self.truncations})",
            f"mean episode reward: {self.episode_reward / n:+.3f}",
            "mean episode reward per term:",
        ]
        lines += [f"  {name:<7} {value / n:+10.3f}" for name, value in self.terms.items()]
        return "\n".join(lines)


def main(
    quick: bool = False,
    address: str | None = None,
    workers: int = 2,
    num_envs: int | None = None,
    total_frames: int | None = None,
) -> EpisodeStats:
    """Collect ``total_frames`` frames with ``workers`` Ray collectors and print the task's statistics."""
    num_envs = num_envs or (8 if quick else 32)
    frames_per_batch = num_envs * (50 if quick else 200)
    total_frames = total_frames or (6 * frames_per_batch if quick else 64_000)
    torch.manual_seed(0)
    start_ray(address, num_cpus=workers)
    stats = EpisodeStats()
    try:
        env_fns = [functools.partial(make_env, num_envs, seed) for seed in range(workers)]
        policy = make_policy()
        start = time.perf_counter()
        collector = Collector(
            env_fns,
            policy,
            backend="ray",
            frames_per_batch=frames_per_batch,
            total_frames=total_frames,
            remote_configs={"num_cpus": 1, "memory": 512 * 1024**2},
        )
        # the controller has no weights to train, but this also sets up the weight sync (no warning)
        collector.update_policy_weights_(policy)
        print(f"Ray collector: {workers} workers x {num_envs} pendulums, {frames_per_batch} frames per batch")
        print(f"collector start-up (Ray actors, env and policy construction): {time.perf_counter() - start:.1f} s")
        start = time.perf_counter()
        try:
            for batch in collector:
                stats.update(batch)
        finally:
            collector.shutdown()
        seconds = time.perf_counter() - start
    finally:
        ray.shutdown()
    print(stats.report())
    print(f"collection time: {seconds:.1f} s ({stats.frames / seconds:,.0f} frames/s)")
    return stats


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="a few thousand frames (seconds once Ray is up)")
    parser.add_argument(
        "--address", default=None, help="address of an existing Ray cluster, e.g. HEAD_IP:6379 or 'auto' (ray.init)"
    )
    parser.add_argument("--workers", type=int, default=2, help="number of remote collectors (Ray actors)")
    parser.add_argument("--envs", type=int, default=None, help="pendulums per worker (default 32, 8 with --quick)")
    parser.add_argument("--frames", type=int, default=None, help="total frames to collect")
    args = parser.parse_args()
    main(args.quick, args.address, args.workers, args.envs, args.frames)
