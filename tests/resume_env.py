"""Point-mass goal reaching with every piece of run-long state, for the resume tests.

The env (:func:`make_resume_env`) holds a frame-driven and a gated schedule (:class:`Curriculum`), per-env
difficulty levels that set the goal range (:class:`DifficultyLevels`), a :class:`GoalCommand` drawing
goals and timers, a base env drawing random initial positions, and :class:`BaseEnvState` carrying the
base env's generator into the transforms' state. :func:`reach_policy` is a deterministic PD controller
towards the goal, so episodes end in success often enough for the levels and the gated stage to move.
Module-level functions: spawn-safe constructors for ``ParallelEnv`` and multi-process collectors.
"""

from __future__ import annotations

import functools

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torchrl.envs import Compose, ParallelEnv, RewardSum, StepCounter, TransformedEnv

from torchtasks.envs import PointMassEnv
from torchtasks.rewards import QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import DesiredStateTask, MaskedTask, proximity_succeeded
from torchtasks.transforms import BaseEnvState, Curriculum, DifficultyLevels, GoalCommand, TaskTransform, gated, linear

SPEC = EnvSpec(Box([-1.0] * 4, [1.0] * 4, labels=["x", "y", "vx", "vy"]), 2)


def reach_task() -> MaskedTask:
    near = functools.partial(proximity_succeeded, threshold=0.1)
    reward = QuadraticErrorReward([1.0, 1.0], [0.0, 0.0])
    return MaskedTask(SPEC, DesiredStateTask(SPEC.select_state(["x", "y"]), [0.0, 0.0], reward, near), ["x", "y"])


def make_resume_env(batch: int = 4, workers: int = 1) -> TransformedEnv:
    """PointMassEnv(batch) with StepCounter, TaskTransform, Curriculum, DifficultyLevels, GoalCommand, BaseEnvState."""
    curriculum = Curriculum(
        {
            "wrapped_task.reward.R": linear(0.0, 0.01, 0, 600),
            "wrapped_task.reward.Q": gated([1.0, 2.0, 3.0], metric="success", threshold=0.5, window=4),
        },
        workers=workers,
    )
    half_widths = torch.tensor([0.3, 0.6, 0.9]).unsqueeze(-1).expand(3, 2)
    levels = DifficultyLevels(3, {"command.low": -half_widths, "command.high": half_widths})
    return TransformedEnv(
        PointMassEnv(batch_size=[batch], max_force=2.0),
        Compose(
            StepCounter(30),
            TaskTransform(reach_task(), goal_key="goal"),
            RewardSum(),
            curriculum,
            levels,
            GoalCommand(Box([-0.9, -0.9], [0.9, 0.9]), resample_steps=(10, 20)),
            BaseEnvState(),
        ),
    )


def make_parallel_resume_env(batch: int = 2) -> ParallelEnv:
    """Two workers of :func:`make_resume_env` (each counting the frames of both).

    Without shared buffers: TorchRL 0.14.1's ``ParallelEnv.load_state_dict`` leaves the workers' shared-memory
    done flags set, so with buffers the next reset or step may read the workers' results before they are
    written (fixed upstream in pytorch/rl#4341).
    """
    return ParallelEnv(2, functools.partial(make_resume_env, batch, 2), use_buffers=False)


class PDController(torch.nn.Module):
    """``a = 6 (goal - x) - 2 v``, clipped to the force bound (deterministic, no parameters)."""

    def forward(self, observation: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        action = 6.0 * (goal.to(observation.dtype) - observation[..., :2]) - 2.0 * observation[..., 2:]
        return action.clamp(-2.0, 2.0)


def reach_policy() -> TensorDictModule:
    """The PD controller towards the goal as a policy module (its empty state_dict is what collectors save)."""
    return TensorDictModule(PDController(), in_keys=["observation", "goal"], out_keys=["action"])


def compared(batch: TensorDictBase) -> TensorDictBase:
    """The collected entries without the collector's bookkeeping (trajectory ids are new after a load)."""
    return batch.exclude("collector")


def equal_batches(first: TensorDictBase, second: TensorDictBase) -> list[str]:
    """The keys whose tensors differ (bit for bit) between two batches; [] if none."""
    first, second = compared(first), compared(second)
    keys = set(first.keys(True, True)) | set(second.keys(True, True))
    return sorted(
        str(key)
        for key in keys
        if key not in first.keys(True, True)
        or key not in second.keys(True, True)
        or not torch.equal(first.get(key), second.get(key))
    )
