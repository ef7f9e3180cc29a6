"""Collect with a torchtasks task on a Ray cluster: ``Collector(backend="ray")`` with a ``TaskTransform``.

What it shows: the task travels with the env. Each Ray worker builds its own env with ``StepCounter`` +
``TaskTransform`` + ``RewardSum`` from a picklable module-level constructor, runs a TorchRL
``Collector`` in a Ray actor and ships batches back; the task's reward, its flags, the episode ends
and the per-term reward breakdown (``("task_reward", name)`` and their ``RewardSum`` episode sums)
arrive in the driver like any other entry. The driver then recomputes every collected reward offline
from the stored states with the task (``TaskTransform.reward_fn``) and prints the largest difference.

Two kinds of env (``--env``):

- a Gymnasium MuJoCo v5 locomotion id (default ``Hopper-v5``): each worker steps ``--envs`` copies
  in one :class:`~torchtasks.envs.BatchedMujocoEnv` (``gymnasium_env(env_id, num_envs=N,
  backend="batched")``: Gymnasium's observations, the reward and termination of
  :func:`~torchtasks.envs.locomotion.locomotion_task`), driven by random actions. Hopper falls within
  tens of steps, so episodes end by the task's failure and single envs are reset while the others
  continue; needs the ``mujoco`` extra;
- ``pendulum``: batched torch pendulums (:class:`~torchtasks.envs.PendulumEnv`) with
  ``swing_up_task()``, driven by the classical swing-up controller of ``torchtasks demo`` (no
  learning), so episodes end in success and the success counts are meaningful.

Set-up:

- ``--workers`` remote collectors (one Ray actor each, ``num_cpus=1``), each stepping ``--envs``
  envs as one batch (a batched MuJoCo env steps them in one thread: the actor has one CPU); episodes
  are truncated after 1000 steps (MuJoCo, Gymnasium's limit) or ``PENDULUM_MAX_STEPS`` (pendulum).
- Env constructors are ``functools.partial`` objects of the module-level :func:`make_env`, so they
  pickle (a lambda or a closure would not survive the trip to a worker).
- By default a local Ray cluster is started with ``ray.init(num_cpus=...)`` and shut down at the end.

Run it on this machine::

    python examples/distributed_ray.py                   # 2 workers x 32 batched Hopper envs, 64k frames
    python examples/distributed_ray.py --quick           # a few seconds once Ray is up (used by the tests)
    python examples/distributed_ray.py --env Ant-v5      # any id of torchtasks.envs.locomotion.SUPPORTED_ENV_IDS
    python examples/distributed_ray.py --env pendulum    # the swing-up controller on torch pendulums

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

import functools
import os
import time
import warnings
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

PENDULUM = "pendulum"
PENDULUM_MAX_STEPS = 200  # episode time limit of the pendulum (StepCounter)


def make_env(env: str, num_envs: int, seed: int) -> TransformedEnv:
    """Return ``num_envs`` batched envs with their task (module level: picklable for Ray workers).

    ``env``: a MuJoCo locomotion id (``gymnasium_env(env, num_envs, backend="batched")``, one thread)
    or ``"pendulum"`` (torch pendulums with the swing-up task).
    """
    if env == PENDULUM:
        return TransformedEnv(
            PendulumEnv(batch_size=[num_envs], seed=seed),
            Compose(StepCounter(PENDULUM_MAX_STEPS), TaskTransform(swing_up_task()), RewardSum()),
        )
    from torchtasks.envs.locomotion import gymnasium_env

    return gymnasium_env(env, num_envs=num_envs, seed=seed, backend="batched", num_threads=1)


def make_offline_transform(env: str) -> TaskTransform:
    """The task of ``env`` as a stand-alone ``TaskTransform``, to recompute rewards from stored transitions."""
    if env == PENDULUM:
        return TaskTransform(swing_up_task(), max_steps=PENDULUM_MAX_STEPS)
    from torchtasks.envs.locomotion import locomotion_state_layout, locomotion_task

    return TaskTransform(locomotion_task(env), state_key=list(locomotion_state_layout(env)))


def make_policy(env: str) -> TensorDictModule | None:
    """The swing-up controller of ``torchtasks demo`` for the pendulum; ``None`` (random actions) for MuJoCo."""
    if env != PENDULUM:
        return None
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
    """Running sums of the episodes that ended in collected batches, and the offline recomputation."""

    def __init__(self, offline: TaskTransform) -> None:
        self.offline = offline
        self.frames = 0
        self.batches = 0
        self.episodes = 0
        self.successes = 0
        self.failures = 0
        self.outcomes: tuple[str, ...] = ()  # the flags the task writes: the outcomes it defines
        self.truncations = 0
        self.episode_reward = 0.0
        self.terms: dict[str, float] = {}
        self.max_offline_diff = 0.0

    def update(self, batch: TensorDictBase) -> None:
        nxt = batch["next"]
        ended = nxt["done"]
        self.frames += batch.numel()
        self.batches += 1
        self.episodes += int(ended.sum())
        # a task writes the flags of the outcomes it has: a locomotion task, which cannot succeed, writes no "success"
        self.outcomes = tuple(flag for flag in ("success", "failure") if flag in nxt.keys())
        never = torch.zeros_like(ended)
        success, failure = nxt.get("success", never), nxt.get("failure", never)
        self.successes += int(success.sum())
        self.failures += int(failure.sum())
        self.truncations += int((nxt["truncated"] & ~success & ~failure).sum())
        self.episode_reward += float(nxt["episode_reward"][ended].sum())
        for key in nxt["task_reward"].keys():
            if key.startswith("episode_"):
                name = key[len("episode_") :]
                self.terms[name] = self.terms.get(name, 0.0) + float(nxt["task_reward", key][ended].sum())
        recomputed = self.offline.reward_fn(batch)  # the task on the stored states, actions and memory
        self.max_offline_diff = max(self.max_offline_diff, float((recomputed - nxt["reward"]).abs().max()))

    def report(self) -> str:
        n = max(self.episodes, 1)
        counted = {"success": f"successes: {self.successes}, ", "failure": f"failures: {self.failures}, "}
        counts = [counted[flag] for flag in self.outcomes]  # no count of an outcome the task does not define
        lines = [
            f"frames collected: {self.frames} in {self.batches} batches",
            f"episodes ended: {self.episodes} ({', '.join(counts)}truncations: {self.truncations})",
            f"mean episode reward: {self.episode_reward / n:+.3f}",
            "mean episode reward per term:",
        ]
        lines += [f"  {name:<7} {value / n:+10.3f}" for name, value in self.terms.items()]
        lines.append(
            f"rewards recomputed offline from the stored states: max abs difference {self.max_offline_diff:.1e}"
        )
        return "\n".join(lines)


def main(
    quick: bool = False,
    address: str | None = None,
    workers: int = 2,
    num_envs: int | None = None,
    total_frames: int | None = None,
    env: str = "Hopper-v5",
) -> EpisodeStats:
    """Collect ``total_frames`` frames of ``env`` with ``workers`` Ray collectors and print the task's statistics."""
    num_envs = num_envs or (8 if quick else 32)
    frames_per_batch = num_envs * (50 if quick else 200)
    total_frames = total_frames or (6 * frames_per_batch if quick else 64_000)
    torch.manual_seed(0)
    stats = EpisodeStats(make_offline_transform(env))  # also checks the env name before Ray starts
    start_ray(address, num_cpus=workers)
    try:
        env_fns = [functools.partial(make_env, env, num_envs, seed) for seed in range(workers)]
        policy = make_policy(env)
        start = time.perf_counter()
        with warnings.catch_warnings():
            # random actions (policy=None) have no weights to send to the workers
            warnings.filterwarnings("ignore", message=".*policy is not an nn.Module.*")
            collector = Collector(
                env_fns,
                policy,
                backend="ray",
                frames_per_batch=frames_per_batch,
                total_frames=total_frames,
                remote_configs={"num_cpus": 1, "memory": 512 * 1024**2},
            )
        if policy is not None:
            # the controller has no weights to train, but this also sets up the weight sync (no warning)
            collector.update_policy_weights_(policy)
        kind = "pendulums" if env == PENDULUM else f"{env} envs (BatchedMujocoEnv)"
        print(f"Ray collector: {workers} workers x {num_envs} {kind}, {frames_per_batch} frames per batch")
        print(f"collector start-up (Ray actors, env and policy construction): {time.perf_counter() - start:.1f} s")
        start = time.perf_counter()
        try:
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message=".*before weight synchronization was initialized.*")
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
    from _cli import default_text, make_parser, quiet_torchrl

    quiet_torchrl()
    parser = make_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="a few thousand frames (seconds once Ray is up)")
    parser.add_argument(
        "--address",
        default=None,
        help=f"an existing Ray cluster, e.g. HEAD_IP:6379 or auto {default_text('start a local one')}",
    )
    parser.add_argument("--workers", type=int, default=2, help="remote collectors, one Ray actor each")
    parser.add_argument("--envs", type=int, default=None, help=f"envs per worker {default_text(32, '8 with --quick')}")
    parser.add_argument(
        "--frames", type=int, default=None, help=f"frames to collect {default_text(64_000, '6 batches with --quick')}"
    )
    parser.add_argument(
        "--env",
        default="Hopper-v5",
        metavar="ID",
        help="a Gymnasium MuJoCo v5 locomotion id, batched with random actions, or pendulum",
    )
    args = parser.parse_args()
    main(args.quick, args.address, args.workers, args.envs, args.frames, args.env)
