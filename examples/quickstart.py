"""Quickstart: build a task, apply it to a TorchRL env, read the outputs.

Run: ``python examples/quickstart.py [--quick]``.
"""

from __future__ import annotations

import functools

import torch
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv
from torchtasks.rewards import CompoundReward, QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.stats import episode_statistics
from torchtasks.tasks import FinalRewardTask, RadiallySymmetricDesiredStateTask, proximity_succeeded
from torchtasks.transforms import TaskTransform


def make_task() -> FinalRewardTask:
    """Swing the pendulum up (θ = 0) and hold it: quadratic tracking + effort, +100 on success."""
    spec = EnvSpec(state_space=Box([-float("inf"), -8.0], [float("inf"), 8.0]), action_space=1)
    reward = CompoundReward(
        {"track": QuadraticErrorReward(Q=[1.0, 0.1], R=None), "effort": QuadraticErrorReward(Q=[0.0, 0.0], R=[1e-3])}
    )
    upright = functools.partial(proximity_succeeded, threshold=0.05)
    inner = RadiallySymmetricDesiredStateTask(spec, [0.0, 0.0], reward, indices=[0], success=upright)
    return FinalRewardTask(inner, factor=100.0)


def main(quick: bool = False) -> None:
    num_envs, steps = (8, 50) if quick else (256, 200)
    env = TransformedEnv(
        PendulumEnv(batch_size=[num_envs], seed=0),
        Compose(StepCounter(max_steps=100), TaskTransform(make_task()), RewardSum()),
    )
    torch.manual_seed(0)
    rollout = env.rollout(steps, break_when_any_done=False)
    nxt = rollout["next"]
    # how the episodes ended and their returns, counted from the flags at each episode's last frame
    stats = episode_statistics(rollout)
    episodes = int(stats["episodes"])
    print(f"{num_envs} envs x {steps} steps: {episodes} episode{'' if episodes == 1 else 's'} ended")
    counts = {name: round(stats.get(f"{name}_rate", 0.0) * episodes) for name in ("success", "failure", "timeout")}
    print(f"  successes: {counts['success']}, failures: {counts['failure']}")
    print(f"  truncations: {counts['timeout']}")
    labels = {
        "step": "step reward (track + effort)",
        "final": "final reward (+100 on success)",
        "track": "track term",
        "effort": "effort term",
    }
    for key, label in labels.items():
        print(f"  mean per step, {label:<30}: {nxt['task_reward', key].mean():+.4f}")
    print(f"  mean episode reward of finished episodes: {stats.get('return_mean', float('nan')):+.3f}")


if __name__ == "__main__":
    from _cli import make_parser, quiet_torchrl

    quiet_torchrl()
    parser = make_parser(__doc__)
    parser.add_argument("--quick", action="store_true", help="a few envs and steps (seconds)")
    main(parser.parse_args().quick)
