"""A batched, differentiable pendulum in torch whose reward and termination come from a task."""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from typing import Any

import torch

from torchtasks.domain import DomainField, check_domain_values, select_fields
from torchtasks.envs._state_env import StateEnv
from torchtasks.rewards import CompoundReward, QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import FinalRewardTask, RadiallySymmetricDesiredStateTask, Task, proximity_succeeded

__all__ = ["PENDULUM_FIELDS", "PendulumEnv", "pendulum_dynamics", "swing_up_task"]


def _field(name: str, nominal: float, low: float, low_open: bool, description: str) -> DomainField:
    value = torch.tensor(nominal, dtype=torch.float64)
    return DomainField(name, torch.Size([]), value, low, math.inf, low_open, (name,), False, description)


#: the pendulum's domain fields (Pyrado's pendulum domain parameters g, m_pole, l_pole): one value per env each
PENDULUM_FIELDS = {
    "mass": _field("mass", 1.0, 0.0, True, "the rod's mass (kg)"),
    "length": _field("length", 1.0, 0.0, True, "the rod's length (m)"),
    "gravity": _field("gravity", 10.0, -math.inf, False, "the gravitational acceleration (m/s^2)"),
}


def pendulum_dynamics(
    state: torch.Tensor,
    torque: torch.Tensor,
    *,
    dt: float = 0.05,
    gravity: float | torch.Tensor = 10.0,
    mass: float | torch.Tensor = 1.0,
    length: float | torch.Tensor = 1.0,
    max_speed: float = 8.0,
) -> torch.Tensor:
    """Return the next ``[θ, θ̇]`` of a rod pendulum (θ = 0 upright), semi-implicit Euler.

    ``θ̈ = 3g/(2l)·sin θ + 3/(m l²)·u`` (Gymnasium's Pendulum physics); the angular speed is
    clipped to ``±max_speed``. Pure, batched and differentiable (``state [*B, 2]``,
    ``torque [*B, 1]``; ``gravity``, ``mass``, ``length`` numbers or per-env tensors ``[*B]``); the angle is
    not wrapped.

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

    Per-env physics: the rod's ``"mass"``, ``"length"`` and ``"gravity"`` are domain fields
    (:data:`PENDULUM_FIELDS`, :class:`~torchtasks.domain.DomainEnv`): ``set_domain`` gives each env its own
    values (kept until set again, in the env's dtype in the dynamics, saved in ``state_dict``), as a
    :class:`~torchtasks.transforms.DomainRandomization` does; ``domain_values`` reads them.

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
        #: the per-env domain values set so far (float64 ``[*batch_size]`` by field; the others are nominal)
        self._domain: dict[str, torch.Tensor] = {}
        #: the same in the state's dtype and device, as the dynamics read them
        self._physics: dict[str, torch.Tensor] = {}

    def _sample_state(self) -> torch.Tensor:
        shape = (*self.batch_size, 2)
        uniform = torch.rand(shape, generator=self.rng, device=self.rng.device, dtype=self.dtype_)
        scale = torch.tensor([self.init_angle, self.init_speed], dtype=self.dtype_, device=self.rng.device)
        return ((2 * uniform - 1) * scale).to(self.device or "cpu")

    def _next_state(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        torque = action.clamp(-self.max_torque, self.max_torque)
        return pendulum_dynamics(state, torque, dt=self.dt, max_speed=self.max_speed, **self._physics)

    # ------------------------------------------------------------------ per-env physics
    def domain_fields(self, names: Sequence[str] | None = None) -> list[DomainField]:
        """The domain fields ``names`` names (``None``: all of :data:`PENDULUM_FIELDS`); see :class:`DomainEnv`."""
        return select_fields(PENDULUM_FIELDS, names, type(self).__name__)

    def set_domain(self, values: Mapping[str, torch.Tensor], mask: torch.Tensor | None = None) -> None:
        """Give the envs of ``mask`` (bool ``batch_size``; ``None``: all) the values ``values[name]`` (float64
        ``[*batch_size]``); the other envs keep theirs. Refused: unknown names, other shapes or dtypes, values
        outside a field's range (a mass <= 0)."""
        mask = check_domain_values(PENDULUM_FIELDS, values, mask, self.batch_size, type(self).__name__)
        device = self.device or torch.device("cpu")
        for name, value in values.items():
            old = self._domain.get(name)
            if old is None:
                old = PENDULUM_FIELDS[name].nominal.expand(self.batch_size).to(device)
            new = torch.where(mask.to(device), value.to(device), old)
            self._domain[name] = new
            self._physics[name] = new.to(self.dtype_)

    def domain_values(self, names: Sequence[str] | None = None) -> dict[str, torch.Tensor]:
        """Every env's current value of each field (float64 ``[*batch_size]``; nominal if never set)."""
        device = self.device or torch.device("cpu")
        return {
            field.name: self._domain[field.name].clone()
            if field.name in self._domain
            else field.nominal.expand(self.batch_size).to(device).clone()
            for field in self.domain_fields(names)
        }

    def get_extra_state(self) -> dict[str, Any]:
        """The reset generator, the batch size and the domain values set so far (``"domain"``)."""
        state = super().get_extra_state()
        state["domain"] = {name: value.clone() for name, value in self._domain.items()}
        return state

    def set_extra_state(self, state: Any) -> None:
        """Restore :meth:`get_extra_state`'s state; the domain values are checked as ``set_domain`` checks them."""
        domain = state.get("domain", {}) if isinstance(state, Mapping) else {}  # absent from older checkpoints
        if not isinstance(domain, Mapping):
            raise ValueError(f"PendulumEnv.load_state_dict: 'domain' must be a dict of field -> tensor, got {domain!r}")
        check_domain_values(PENDULUM_FIELDS, domain, None, self.batch_size, "PendulumEnv.load_state_dict")
        super().set_extra_state(state)
        self._domain, self._physics = {}, {}
        if domain:
            self.set_domain(domain)


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
