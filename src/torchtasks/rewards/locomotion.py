"""Forward-progress rewards of locomotion tasks (HalfCheetah, Hopper, Ant, Humanoid).

These rewards are stateful: the velocity is the finite difference of the forward position
between two calls, so the previous position lives in memory (key ``"x_last"``), set by
:meth:`reset` from the initial state and advanced by every :meth:`step`.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict

from torchtasks._checks import (
    cast_like,
    check_finite_scalar,
    check_input,
    check_int,
    check_pair,
    check_same_batch,
    check_weight,
)
from torchtasks._memory import read
from torchtasks.rewards.base import (
    RewardFunction,
    check_reward_memory,
    entries,
    index_problem,
    row_scalar,
    squared_sum,
    sum_terms,
)

__all__ = ["AntForwardReward", "ForwardVelocityReward", "HumanoidForwardReward"]


class _ForwardProgressReward(RewardFunction):
    """Shared memory protocol and velocity/control terms of the forward-progress rewards."""

    stateful = True
    term_names = ("forward", "ctrl")
    #: the constructor argument that sets ``x_index`` (named in error messages)
    _x_index_name = "x_index"

    def __init__(self, dt: float, x_index: int, forward_reward_weight: float, ctrl_cost_weight: float) -> None:
        super().__init__()
        dt = check_finite_scalar(dt, "dt")
        if dt <= 0:
            raise ValueError(f"dt must be positive, got {dt}")
        self.dt = dt
        self.x_index = check_int(x_index, self._x_index_name)
        self._register_scalar(
            "forward_reward_weight", check_finite_scalar(forward_reward_weight, "forward_reward_weight")
        )
        self._register_scalar("ctrl_cost_weight", ctrl_cost_weight, check=check_weight)

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        return index_problem(who, self._x_index_name, self.x_index, state_size)

    def _check_state(self, state: torch.Tensor, name: str) -> None:
        """Check ``state`` and that it holds every entry the reward reads (shape checks only)."""
        check_input(state, name)
        size = state.shape[-1]
        if not -size <= self.x_index < size:
            raise ValueError(
                f"{self._x_index_name}={self.x_index} is out of range for {name} of shape {tuple(state.shape)}"
            )

    def _x(self, state: torch.Tensor) -> torch.Tensor:
        return state[..., self.x_index]

    def reset(self, init_state: torch.Tensor) -> TensorDict:
        self._check_state(init_state, "init_state")
        return TensorDict({"x_last": self._x(init_state).clone()}, batch_size=init_state.shape[:-1])

    def _check_step(self, state: torch.Tensor, action: torch.Tensor, memory: TensorDict) -> None:
        self._check_state(state, "state")
        check_input(action, "action")
        check_same_batch(state, action, "state", "action")
        check_reward_memory(memory, state, "x_last", type(self).__name__)

    def _common_terms(self, state: torch.Tensor, action: torch.Tensor, memory: TensorDict) -> dict[str, torch.Tensor]:
        x = self._x(state)
        velocity = (x - read(memory, "x_last")) / self.dt
        return {
            "forward": cast_like(self.forward_reward_weight, velocity) * velocity,
            "ctrl": -cast_like(self.ctrl_cost_weight, state) * squared_sum(action),
        }

    def terms_of(self, state: torch.Tensor, action: torch.Tensor, memory: TensorDict) -> dict[str, torch.Tensor]:
        """Return the named reward terms of one step (costs are negative)."""
        self._check_step(state, action, memory)
        return self._terms_of(state, action, memory)

    def _terms_of(self, state: torch.Tensor, action: torch.Tensor, memory: TensorDict) -> dict[str, torch.Tensor]:
        """:meth:`terms_of` without input validation."""
        return self._common_terms(state, action, memory)

    def step_terms(
        self, state: torch.Tensor, action: torch.Tensor, memory: TensorDict
    ) -> tuple[dict[str, torch.Tensor], TensorDict]:
        """Return ``({term: value[*B]}, memory)``: the named terms and the advanced memory."""
        self._check_step(state, action, memory)
        return self._step_terms(state, action, memory)

    def _step_terms(
        self, state: torch.Tensor, action: torch.Tensor, memory: TensorDict
    ) -> tuple[dict[str, torch.Tensor], TensorDict]:
        values = self._terms_of(state, action, memory)
        new_memory = TensorDict._new_unsafe({"x_last": self._x(state).clone()}, batch_size=memory.batch_size)
        return values, new_memory

    def _step(self, state: torch.Tensor, action: torch.Tensor, memory: TensorDict) -> tuple[torch.Tensor, TensorDict]:
        values, memory = self._step_terms(state, action, memory)
        return sum_terms(values), memory

    def step(self, state: torch.Tensor, action: torch.Tensor, memory: TensorDict) -> tuple[torch.Tensor, TensorDict]:
        self._check_step(state, action, memory)
        return self._step(state, action, memory)

    def forward(self, state: torch.Tensor, action: torch.Tensor, memory: TensorDict) -> tuple[torch.Tensor, TensorDict]:
        return self.step(state, action, memory)


class ForwardVelocityReward(_ForwardProgressReward):
    """Forward velocity minus control cost: ``w_f·(x - x_last)/dt - w_ctrl·Σ a²``.

    Reads the raw state (``x = state[index]``) and action. Stateful: the previous ``x`` is in
    memory, so the first step after :meth:`reset` measures ``x_1 - x_0``.

    Args:
        dt: time between two calls [s].
        index: position of the forward coordinate in the state.
        forward_reward_weight: weight ``w_f`` of the velocity.
        ctrl_cost_weight: weight ``w_ctrl`` of the control cost.

    Pyrado name: ``ForwardVelocityRewFcn``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import ForwardVelocityReward
        >>> reward = ForwardVelocityReward(dt=0.05, index=0)
        >>> memory = reward.reset(torch.zeros(1, 2))
        >>> value, memory = reward.step(torch.tensor([[0.1, 0.0]]), torch.ones(1, 3), memory)
        >>> value, memory["x_last"]
        (tensor([1.7000]), tensor([0.1000]))
    """

    _x_index_name = "index"

    def __init__(
        self, dt: float, index: int = 0, forward_reward_weight: float = 1.0, ctrl_cost_weight: float = 0.1
    ) -> None:
        super().__init__(dt, index, forward_reward_weight, ctrl_cost_weight)


class _HealthyForwardReward(_ForwardProgressReward):
    """Forward progress with a healthy reward and an optional "unhealthy = failure" rule."""

    term_names = ("forward", "ctrl", "healthy", "contact")

    def __init__(
        self,
        dt: float,
        *,
        forward_reward_weight: float,
        ctrl_cost_weight: float,
        contact_cost_weight: float,
        healthy_reward: float,
        terminate_when_unhealthy: bool,
        healthy_z_range: tuple[float, float],
        x_index: int,
        z_index: int,
        contact_forces_start: int,
    ) -> None:
        super().__init__(dt, x_index, forward_reward_weight, ctrl_cost_weight)
        self._register_scalar("contact_cost_weight", contact_cost_weight, check=check_weight)
        self._register_scalar("healthy_reward", check_finite_scalar(healthy_reward, "healthy_reward"))
        if not isinstance(terminate_when_unhealthy, bool):
            raise TypeError(f"terminate_when_unhealthy must be a bool, got {terminate_when_unhealthy!r}")
        self.terminate_when_unhealthy = terminate_when_unhealthy
        self.can_fail = terminate_when_unhealthy
        low, high = check_pair(healthy_z_range, "healthy_z_range")
        self._register_scalar("healthy_z_low", low)
        self._register_scalar("healthy_z_high", high)
        self.z_index = check_int(z_index, "z_index")
        self.contact_forces_start = check_int(contact_forces_start, "contact_forces_start")

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        problem = super()._size_problem(state_size, action_size, who) or index_problem(
            who, "z_index", self.z_index, state_size
        )
        if problem is None and self.contact_forces_start >= state_size:
            problem = (
                f"{who} reads the contact forces from contact_forces_start={self.contact_forces_start}, "
                f"but the task's state has {entries(state_size)}"
            )
        return problem

    def _check_z(self, state: torch.Tensor, name: str) -> None:
        check_input(state, name)
        if not -state.shape[-1] <= self.z_index < state.shape[-1]:
            raise ValueError(f"z_index={self.z_index} is out of range for {name} of shape {tuple(state.shape)}")

    def _check_state(self, state: torch.Tensor, name: str) -> None:
        super()._check_state(state, name)
        self._check_z(state, name)
        if self.contact_forces_start >= state.shape[-1]:
            raise ValueError(
                f"contact_forces_start={self.contact_forces_start} is beyond {name} of shape {tuple(state.shape)}"
            )

    def _z(self, state: torch.Tensor) -> torch.Tensor:
        return state[..., self.z_index]

    def _contact_forces(self, state: torch.Tensor) -> torch.Tensor:
        return state[..., self.contact_forces_start :]

    def is_healthy(self, state: torch.Tensor) -> torch.Tensor:
        """Return ``bool[*B]``: whether the body is in its healthy height range."""
        self._check_z(state, "state")
        return self._is_healthy(state)

    def _is_healthy(self, state: torch.Tensor) -> torch.Tensor:
        """:meth:`is_healthy` without input validation."""
        raise NotImplementedError

    def _contact_cost(self, state: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def _terms_of(self, state: torch.Tensor, action: torch.Tensor, memory: TensorDict) -> dict[str, torch.Tensor]:
        values = self._common_terms(state, action, memory)
        healthy = self._is_healthy(state).to(state.dtype)
        values["healthy"] = cast_like(self.healthy_reward, healthy) * healthy
        values["contact"] = -self._contact_cost(state)
        return values

    def has_failed(self, state: torch.Tensor) -> torch.Tensor:
        if not self.terminate_when_unhealthy:
            return super().has_failed(state)
        return ~self.is_healthy(state)


class AntForwardReward(_HealthyForwardReward):
    """Ant locomotion reward: velocity + healthy reward - control cost - contact cost.

    ``w_f·(x - x_last)/dt + healthy_reward·is_healthy - w_ctrl·Σ a² - w_c·Σ clip(f, lo, hi)²`` where
    ``f = state[contact_forces_start:]`` are the external contact forces and
    ``is_healthy = all(isfinite(state)) and z_lo <= state[z_index] <= z_hi`` (inclusive bounds).
    The healthy reward is paid only when healthy; with ``terminate_when_unhealthy`` an unhealthy
    state is a failure (:meth:`has_failed`), as in Gymnasium's Ant-v5. Defaults are Ant-v5's.

    Args:
        dt: time between two calls [s].
        contact_cost_weight, ctrl_cost_weight, forward_reward_weight: weights.
        healthy_reward: reward per healthy step.
        terminate_when_unhealthy: whether an unhealthy state is a task failure.
        healthy_z_range: inclusive range of the torso height.
        contact_force_range: range each contact force is clipped to before squaring.
        x_index, z_index, contact_forces_start: layout of the state (Pyrado's AntSim: 0, 2, 29).

    Pyrado name: ``ForwardVelocityRewFcnAnt`` (whose ``terminate_when_unhealthy`` never terminated).

    Example:
        >>> import torch
        >>> from torchtasks.rewards import AntForwardReward
        >>> reward = AntForwardReward(dt=0.05)
        >>> state = torch.zeros(1, 113); state[:, 2] = 0.5
        >>> value, memory = reward.step(state, torch.zeros(1, 8), reward.reset(state))
        >>> value, reward.has_failed(state)
        (tensor([1.]), tensor([False]))
    """

    def __init__(
        self,
        dt: float,
        contact_cost_weight: float = 5e-4,
        ctrl_cost_weight: float = 0.5,
        healthy_reward: float = 1.0,
        terminate_when_unhealthy: bool = True,
        healthy_z_range: tuple[float, float] = (0.2, 1.0),
        contact_force_range: tuple[float, float] = (-1.0, 1.0),
        forward_reward_weight: float = 1.0,
        *,
        x_index: int = 0,
        z_index: int = 2,
        contact_forces_start: int = 29,
    ) -> None:
        super().__init__(
            dt,
            forward_reward_weight=forward_reward_weight,
            ctrl_cost_weight=ctrl_cost_weight,
            contact_cost_weight=contact_cost_weight,
            healthy_reward=healthy_reward,
            terminate_when_unhealthy=terminate_when_unhealthy,
            healthy_z_range=healthy_z_range,
            x_index=x_index,
            z_index=z_index,
            contact_forces_start=contact_forces_start,
        )
        low, high = check_pair(contact_force_range, "contact_force_range")
        self._register_scalar("contact_force_low", low)
        self._register_scalar("contact_force_high", high)

    def _is_healthy(self, state: torch.Tensor) -> torch.Tensor:
        z = self._z(state)
        finite = torch.isfinite(state).all(dim=-1)
        return finite & (z >= self.healthy_z_low) & (z <= self.healthy_z_high)

    def _contact_cost(self, state: torch.Tensor) -> torch.Tensor:
        forces = self._contact_forces(state)
        forces = forces.clamp(row_scalar(self.contact_force_low, forces), row_scalar(self.contact_force_high, forces))
        return cast_like(self.contact_cost_weight, state) * squared_sum(forces)


class HumanoidForwardReward(_HealthyForwardReward):
    """Humanoid locomotion reward: velocity + healthy reward - control cost - clipped contact cost.

    ``w_f·(x - x_last)/dt + healthy_reward·is_healthy - w_ctrl·Σ a² - clip(w_c·Σ f², lo_c, hi_c)``
    with ``f = state[contact_forces_start:]`` and ``is_healthy = z_lo < state[z_index] < z_hi``
    (strict bounds, no finiteness check). The healthy reward is paid only when healthy; with
    ``terminate_when_unhealthy`` an unhealthy state is a failure. Defaults are Humanoid-v5's.

    Args:
        dt: time between two calls [s].
        contact_cost_weight, ctrl_cost_weight, forward_reward_weight: weights.
        healthy_reward: reward per healthy step.
        terminate_when_unhealthy: whether an unhealthy state is a task failure.
        healthy_z_range: open range of the torso height.
        contact_cost_range: range the weighted contact cost is clipped to.
        x_index, z_index, contact_forces_start: layout of the state (Pyrado's HumanoidSim: 0, 2, 294).

    Pyrado name: ``ForwardVelocityRewFcnHumanoid``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import HumanoidForwardReward
        >>> reward = HumanoidForwardReward(dt=0.015)
        >>> state = torch.zeros(1, 378); state[:, 2] = 1.4
        >>> value, memory = reward.step(state, torch.zeros(1, 17), reward.reset(state))
        >>> value
        tensor([5.])
    """

    def __init__(
        self,
        dt: float,
        contact_cost_weight: float = 5e-7,
        ctrl_cost_weight: float = 0.1,
        forward_reward_weight: float = 1.25,
        healthy_reward: float = 5.0,
        terminate_when_unhealthy: bool = True,
        healthy_z_range: tuple[float, float] = (1.0, 2.0),
        contact_cost_range: tuple[float, float] = (float("-inf"), 10.0),
        *,
        x_index: int = 0,
        z_index: int = 2,
        contact_forces_start: int = 294,
    ) -> None:
        super().__init__(
            dt,
            forward_reward_weight=forward_reward_weight,
            ctrl_cost_weight=ctrl_cost_weight,
            contact_cost_weight=contact_cost_weight,
            healthy_reward=healthy_reward,
            terminate_when_unhealthy=terminate_when_unhealthy,
            healthy_z_range=healthy_z_range,
            x_index=x_index,
            z_index=z_index,
            contact_forces_start=contact_forces_start,
        )
        low, high = check_pair(contact_cost_range, "contact_cost_range")
        self._register_scalar("contact_cost_low", low)
        self._register_scalar("contact_cost_high", high)

    def _is_healthy(self, state: torch.Tensor) -> torch.Tensor:
        z = self._z(state)
        return (z > self.healthy_z_low) & (z < self.healthy_z_high)

    def _contact_cost(self, state: torch.Tensor) -> torch.Tensor:
        forces = self._contact_forces(state)
        cost = cast_like(self.contact_cost_weight, state) * squared_sum(forces)
        return cost.clamp(cast_like(self.contact_cost_low, state), cast_like(self.contact_cost_high, state))
