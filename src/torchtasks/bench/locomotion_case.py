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
DT = 0.05  # HalfCheetah-v5: timestep 0.01 x frame_skip 5
CTRL_COST_WEIGHT = 0.1
ACTION_SIZE = 6


def fused_halfcheetah(
    state: torch.Tensor, action: torch.Tensor, truncated: torch.Tensor, x_last: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """T4 in one function: ``(reward, done, x_last)``; the state is ``[x_position]``."""
    x = state[..., 0]
    reward = (x - x_last) / DT - CTRL_COST_WEIGHT * (action * action).sum(-1)
    done = torch.isnan(state).any(-1) | truncated
    return reward, done, x


class _PyradoForwardVelocity:
    """Pyrado's ``ForwardVelocityRewFcn`` in a ``GoallessTask`` for one environment."""

    def __init__(self, x0: float) -> None:
        self.last_x = x0

    def step_rew(self, state: np.ndarray, act: np.ndarray) -> float:
        velocity = (state[0] - self.last_x) / DT
        self.last_x = state[0]
        return float(velocity - CTRL_COST_WEIGHT * np.sum(np.square(act)))

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
        x0 = torch.rand(batch, 1, generator=generator)
        state = x0 + 0.05 * torch.rand(batch, 1, generator=generator)
        action = torch.rand(batch, ACTION_SIZE, generator=generator) * 2 - 1
        truncated = torch.zeros(batch, dtype=torch.bool)
        x_last = x0[..., 0].clone()
        memory = task.reset(x0)
        reward = task.transition(x0, action, state, memory).reward
        expected, _, _ = fused_halfcheetah(state, action, truncated, x_last)
        if not torch.allclose(reward, expected, rtol=1e-5, atol=1e-5):
            raise AssertionError("T4: the hand-fused function does not compute what the task computes")
        loop = [_PyradoForwardVelocity(float(x)) for x in x0[:, 0]]
        state_np, action_np = state.double().numpy(), action.double().numpy()

        def loop_step() -> object:
            rewards = np.empty(batch)
            for i, env in enumerate(loop):
                env.last_x = float(x0[i, 0])  # the same transition every call, as for the other variants
                rewards[i] = env.step_rew(state_np[i], action_np[i])
                env.is_done(state_np[i])
            return rewards

        return task, x0, action, state, fused_halfcheetah, (state, action, truncated, x_last), loop_step
