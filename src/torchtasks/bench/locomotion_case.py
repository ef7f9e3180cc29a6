"""T4: the HalfCheetah-v5 locomotion task (forward velocity + control cost), needs the ``mujoco`` extra."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from torchtasks.envs.locomotion import locomotion_task
from torchtasks.tasks import Task

__all__ = ["HalfCheetahCase"]

ENV_ID = "HalfCheetah-v5"
CTRL_COST_WEIGHT = 0.1
ACTION_SIZE = 6


def fused_halfcheetah(
    state: torch.Tensor, action: torch.Tensor, truncated: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """T4 in one function: ``(reward, done)``; the state is ``[x_velocity]`` (forward weight 1)."""
    reward = state[..., 0] - CTRL_COST_WEIGHT * (action * action).sum(-1)
    done = torch.isnan(state).any(-1) | truncated
    return reward, done


class _PyradoForwardVelocity:
    """The same reward in a Pyrado-style ``GoallessTask`` for one environment (numpy, one env per call)."""

    def step_rew(self, state: np.ndarray, act: np.ndarray) -> float:
        return float(state[0] - CTRL_COST_WEIGHT * np.sum(np.square(act)))

    def is_done(self, state: np.ndarray) -> bool:
        return bool(np.isnan(state).any())


class HalfCheetahCase:
    """Builds T4 (torchtasks task, inputs, hand-fused function and Pyrado loop) for a batch size."""

    state_size = 1

    def task(self) -> Task:
        """The torchtasks task (float32)."""
        return locomotion_task(ENV_ID).float()

    def build(
        self, batch: int
    ) -> tuple[
        Task, torch.Tensor, torch.Tensor, torch.Tensor, Callable[..., Any], tuple[Any, ...], Callable[[], object]
    ]:
        """``(task, state, action, next_state, fused function, its arguments, Pyrado loop step)``."""
        task = self.task()
        generator = torch.Generator().manual_seed(batch)
        x0 = torch.rand(batch, 1, generator=generator)  # [x_velocity] before and after the step
        state = x0 + 0.05 * torch.rand(batch, 1, generator=generator)
        action = torch.rand(batch, ACTION_SIZE, generator=generator) * 2 - 1
        truncated = torch.zeros(batch, dtype=torch.bool)
        memory = task.reset(x0)
        reward = task.transition(x0, action, state, memory).reward
        expected, _ = fused_halfcheetah(state, action, truncated)
        if not torch.allclose(reward, expected, rtol=1e-5, atol=1e-5):
            raise AssertionError("T4: the hand-fused function does not compute what the task computes")
        loop = [_PyradoForwardVelocity() for _ in range(batch)]
        state_np, action_np = state.double().numpy(), action.double().numpy()

        def loop_step() -> object:
            rewards = np.empty(batch)
            for i, env in enumerate(loop):
                rewards[i] = env.step_rew(state_np[i], action_np[i])
                env.is_done(state_np[i])
            return rewards

        return task, x0, action, state, fused_halfcheetah, (state, action, truncated), loop_step
