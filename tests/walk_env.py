"""A 1-D random walk whose episodes end in success, failure or truncation, for the difficulty-level tests.

:class:`WalkEnv` moves ``x`` by ``step_size * action`` (``step_size`` a per-env float buffer, a parameter
a :class:`~torchtasks.transforms.DifficultyLevels` can set); resets put ``x`` at 0. :func:`walk_task` succeeds
near ``x = 0.8`` and fails outside ``[-1, 1]``. :func:`expected_levels` recomputes from collected data,
independently of the transform, what each env's level must be. The module-level constructors are what
multi-process tests hand to ``ParallelEnv`` and collectors (they pickle by reference).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping

import torch
from tensordict import TensorDictBase
from torchrl.envs import Compose, StepCounter, TransformedEnv

from torchtasks.envs._state_env import StateEnv
from torchtasks.rewards import QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import DesiredStateTask, proximity_succeeded
from torchtasks.transforms import DifficultyLevels, GoalCommand, TaskTransform

SPEC = EnvSpec(Box([-1.0], [1.0], labels=["x"]), 1)
TARGET = 0.8


class WalkEnv(StateEnv):
    """``x_{t+1} = x_t + step_size * a_t`` per env (``step_size`` a float buffer ``[*B]``), ``x_0 = 0``."""

    def __init__(self, batch_size: list[int], seed: int = 0) -> None:
        super().__init__(
            batch_size, state_size=1, action_size=1, action_bound=1.0, dtype=torch.float32, device=None, seed=seed
        )
        self.register_buffer("step_size", torch.full(self.batch_size, 0.4))

    def _sample_state(self) -> torch.Tensor:
        return torch.zeros((*self.batch_size, 1))

    def _next_state(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return state + self.step_size.unsqueeze(-1) * action.clamp(-1.0, 1.0)


def walk_task(goal: bool = False) -> DesiredStateTask:
    """Success within 0.15 of ``x = 0.8`` (or of the goal), failure outside ``[-1, 1]``."""
    near = functools.partial(proximity_succeeded, threshold=0.15)
    return DesiredStateTask(SPEC, [TARGET], QuadraticErrorReward([1.0], [0.0]), near)


def make_walk_env(
    batch: int = 6,
    *,
    num_levels: int = 3,
    values: Mapping[str, object] | None = None,
    max_steps: int = 5,
    seed: int = 0,
    goals: bool = False,
) -> TransformedEnv:
    """A WalkEnv of ``batch`` envs with StepCounter, TaskTransform, DifficultyLevels (and a GoalCommand)."""
    transforms = [
        StepCounter(max_steps),
        TaskTransform(walk_task(), goal_key="goal" if goals else None),
        DifficultyLevels(num_levels, values),
    ]
    if goals:
        transforms.append(GoalCommand(Box([-1.0], [1.0]), resample_steps=(2, 3), seed=seed))
    return TransformedEnv(WalkEnv([batch], seed=seed), Compose(*transforms))


def random_walk_policy(tensordict: TensorDictBase) -> TensorDictBase:
    """Steps of -1, 0 or +1 drawn from torch's global generator (seed it for a reproducible run)."""
    shape = tensordict.get("observation").shape
    tensordict.set("action", torch.randint(-1, 2, shape).to(torch.float32))
    return tensordict


def expected_levels(data: TensorDictBase, initial: torch.Tensor, num_levels: int) -> torch.Tensor:
    """Each frame's level after its step, from the flags alone: at an episode's last step (``done``) the level
    moves by ``success - failure``, clamped to ``[0, num_levels - 1]``; ``initial`` is the level before the first
    frame of each row (``[*B]``, time is the last batch dim)."""
    done = data["next", "done"][..., 0]
    change = data["next", "success"][..., 0].long() - data["next", "failure"][..., 0].long()
    level = initial.clone()
    levels = []
    for t in range(done.shape[-1]):
        level = torch.where(done[..., t], (level + change[..., t]).clamp(0, num_levels - 1), level)
        levels.append(level)
    return torch.stack(levels, -1)
