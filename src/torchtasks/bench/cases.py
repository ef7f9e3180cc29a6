"""The benchmarked tasks T1–T3 (T4, the HalfCheetah-v5 locomotion task, lives in :mod:`.locomotion_case`)."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import torch

from torchtasks.rewards import QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import (
    DesiredStateTask,
    FinalRewardTask,
    ParallelTasks,
    SequentialTasks,
    Task,
    proximity_succeeded,
)

__all__ = ["BenchConfig", "make_t1", "make_t2", "make_t3"]


@dataclass(frozen=True)
class BenchConfig:
    """Sizes and constants shared by the task, the numpy loop and the hand-fused function."""

    state_size: int = 17
    action_size: int = 6
    bound: float = 3.0
    threshold: float = 0.05
    factor: float = 100.0
    goals: tuple[float, ...] = (0.0, 0.4, -0.4)

    def q(self) -> torch.Tensor:
        return torch.linspace(1.0, 2.0, self.state_size, dtype=torch.float64)

    def r(self) -> torch.Tensor:
        return torch.full((self.action_size,), 0.1, dtype=torch.float64)

    def spec(self) -> EnvSpec:
        box = Box([-self.bound] * self.state_size, [self.bound] * self.state_size)
        return EnvSpec(box, Box([-1.0] * self.action_size, [1.0] * self.action_size))


def _desired_state(config: BenchConfig, goal: float) -> FinalRewardTask:
    success = functools.partial(proximity_succeeded, threshold=config.threshold)
    inner = DesiredStateTask(
        config.spec(), [goal] * config.state_size, QuadraticErrorReward(config.q(), config.r()), success
    )
    return FinalRewardTask(inner, factor=config.factor)


def make_t1(config: BenchConfig) -> Task:
    """T1 = FinalRewardTask(DesiredStateTask(QuadraticErrorReward))."""
    return _desired_state(config, config.goals[0])


def make_t2(config: BenchConfig) -> Task:
    """T2 = ParallelTasks of three T1 with different goals."""
    return ParallelTasks([_desired_state(config, goal) for goal in config.goals])


def make_t3(config: BenchConfig) -> Task:
    """T3 = SequentialTasks of three T1 with different goals."""
    return SequentialTasks([_desired_state(config, goal) for goal in config.goals])
