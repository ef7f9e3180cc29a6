"""A batched, differentiable pendulum in torch whose reward and termination come from a task."""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import torch

from torchtasks.envs._state_env import StateEnv
from torchtasks.rewards import CompoundReward, QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import FinalRewardTask, RadiallySymmetricDesiredStateTask, Task, proximity_succeeded

__all__ = ["PendulumEnv", "pendulum_dynamics", "swing_up_task"]


def pendulum_dynamics(
    state: torch.Tensor,
    torque: torch.Tensor,
    *,
    dt: float = 0.05,
    gravity: float = 10.0,
    mass: float = 1.0,
    length: float = 1.0,
    max_speed: float = 8.0,
) -> torch.Tensor:
    """Return the next ``[θ, θ̇]`` of a rod pendulum (θ = 0 upright), semi-implicit Euler.

    ``θ̈ = 3g/(2l)·sin θ + 3/(m l²)·u`` (Gymnasium's Pendulum physics); the angular speed is
    clipped to ``±max_speed``. Pure, batched and differentiable (``state [*B, 2]``,
    ``torque [*B, 1]``); the angle is not wrapped.

    Example:
        >>> import torch
        >>> pendulum_dynamics(torch.tensor([[0.0, 0.0]]), torch.tensor([[1.0]]))
        tensor([[0.0075, 0.1500]])
    """
    theta, speed = state[..., 0], state[..., 1]
    acceleration = 3.0 * gravity / (2.0 * length) * torch.sin(theta) + 3.0 / (mass * length**2) * torque[..., 0]
    speed = torch.clamp(speed + dt * acceleration, -max_speed, max_speed)
    return torch.stack((theta + dt * speed, speed), dim=-1)


class PendulumEnv(StateEnv):
    """A batch of torque-limited pendulums simulated in torch, for swing-up tasks (see :func:`swing_up_task`).

    The observation is the raw state ``[θ, θ̇]`` (θ = 0 upright, not wrapped). The env pays no
    reward and never ends an episode by itself: put a :class:`~torchtasks.transforms.TaskTransform`
    (and a ``StepCounter``) on it. The dynamics (:func:`pendulum_dynamics`) are differentiable,
    so ``env.rollout`` keeps the autograd graph from the policy's actions to the task's rewards.

    Args:
        batch_size: number of pendulums (any shape).
        dt: time step [s].
        max_torque: torque bound (the action is clipped to ``±max_torque``).
        max_speed: speed bound (the angular speed is clipped to ``±max_speed``).
        init_angle, init_speed: half-widths of the uniform initial state distribution.
        device, dtype: where and in which precision the state lives.
        seed: seed of the env's own random generator.

    Example:
        >>> import torch
        >>> env = PendulumEnv(batch_size=[3], seed=0)
        >>> td = env.rand_step(env.reset())
        >>> td["next", "observation"].shape
        torch.Size([3, 2])
    """

    def __init__(
        self,
        batch_size: Sequence[int] | torch.Size = (),
        *,
        dt: float = 0.05,
        max_torque: float = 2.0,
        max_speed: float = 8.0,
        init_angle: float = math.pi,
        init_speed: float = 1.0,
        device: torch.device | str | None = None,
        dtype: torch.dtype = torch.float32,
        seed: int | None = None,
    ) -> None:
        super().__init__(
            batch_size,
            state_size=2,
            action_size=1,
            action_bound=float(max_torque),
            dtype=dtype,
            device=device,
            seed=seed,
        )
        self.dt = float(dt)
        self.max_torque = float(max_torque)
        self.max_speed = float(max_speed)
        self.init_angle = float(init_angle)
        self.init_speed = float(init_speed)

    def _sample_state(self) -> torch.Tensor:
        shape = (*self.batch_size, 2)
        uniform = torch.rand(shape, generator=self.rng, device=self.rng.device, dtype=self.dtype_)
        scale = torch.tensor([self.init_angle, self.init_speed], dtype=self.dtype_, device=self.rng.device)
        return ((2 * uniform - 1) * scale).to(self.device or "cpu")

    def _next_state(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        torque = action.clamp(-self.max_torque, self.max_torque)
        return pendulum_dynamics(state, torque, dt=self.dt, max_speed=self.max_speed)


def swing_up_task(
    success_threshold: float = 0.1, success_reward: float = 100.0, max_torque: float = 2.0, max_speed: float = 8.0
) -> Task:
    """Return the swing-up task of :class:`PendulumEnv`: reach and hold the upright state ``[0, 0]``.

    A :class:`~torchtasks.tasks.RadiallySymmetricDesiredStateTask` (the angle error is wrapped)
    with named reward terms ``track = -(θ² + 0.1·θ̇²)`` and ``effort = -0.001·u²`` (Gymnasium
    Pendulum's cost), succeeding when ``‖[θ, θ̇]‖ < success_threshold``, inside a
    :class:`~torchtasks.tasks.FinalRewardTask` paying ``+success_reward`` on success (failure,
    leaving the speed bounds, cannot happen with the env's speed clip).

    Example:
        >>> import torch
        >>> task = swing_up_task()
        >>> memory = task.reset(torch.zeros(2, 2))
        >>> task.is_done(torch.tensor([[0.01, 0.0], [3.0, 0.0]]), memory)
        tensor([ True, False])
    """
    inf = float("inf")
    spec = EnvSpec(Box([-inf, -max_speed], [inf, max_speed]), Box(-max_torque, max_torque))
    reward = CompoundReward(
        {"track": QuadraticErrorReward(Q=[1.0, 0.1], R=None), "effort": QuadraticErrorReward(Q=[0.0, 0.0], R=[1e-3])}
    )
    success = functools.partial(proximity_succeeded, threshold=success_threshold)
    inner = RadiallySymmetricDesiredStateTask(spec, [0.0, 0.0], reward, indices=[0], success=success)
    return FinalRewardTask(inner, factor=success_reward)
