"""A task that rewards flipping an angle by a fixed amount, again and again."""

from __future__ import annotations

import math
from typing import Any

import torch
from tensordict import TensorDictBase

from torchtasks._checks import check_finite_scalar
from torchtasks._memory import copy_entries, read
from torchtasks.rewards.base import RewardFunction
from torchtasks.spaces import EnvSpec
from torchtasks.tasks.leaf import RewardTask
from torchtasks.tasks.memory import make_memory

__all__ = ["FlippingTask", "wrap_angle"]


def wrap_angle(angle: torch.Tensor) -> torch.Tensor:
    """Wrap angles into ``[-π, π)``.

    Example:
        >>> import math, torch
        >>> wrap_angle(torch.tensor([3 * math.pi / 2, -math.pi, math.pi]))
        tensor([-1.5708, -3.1416, -3.1416])
    """
    return torch.remainder(angle + math.pi, 2 * math.pi) - math.pi


class FlippingTask(RewardTask):
    """Flip a one-dimensional angle by ``±angle_delta`` from the last flip, repeatedly.

    Memory per environment: the angle of the last flip ``last_angle`` (0 at reset), the
    ``held`` reward accumulated by past flips and, when not endless, whether the last step
    flipped (``flipped``). In each step the two targets
    ``last_angle ± angle_delta`` are compared with the state; the one with the smaller wrapped
    error (``wrap(target - s)`` in ``[-π, π)``) is used. The step reward is
    ``held + reward(error, -a)``; when ``|error| <= angle_tol`` the flip is done: that target
    becomes ``last_angle`` and the reward of this step is added to ``held``.
    With ``endless=False`` the task succeeds when a target is within the tolerance or the last
    step reward recorded a flip (so the flip counts whichever state the step reward was evaluated on).

    Args:
        spec: state and action boxes; the state has exactly one entry (use a :class:`MaskedTask`).
        angle_delta: flip amount [rad], positive.
        reward: reward function of the angle error.
        angle_tol: tolerance of a flip [rad].
        endless: never succeed (flip forever) or succeed at the first flip.

    Pyrado name: ``FlippingTask``. Fixed here: Pyrado used the signed minimum of the two errors
    (not the closer target), crashed when both targets matched (``angle_delta = π``) and only
    worked for one environment.

    Example:
        >>> import math, torch
        >>> from torchtasks.rewards import CosineReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import FlippingTask
        >>> task = FlippingTask(EnvSpec(1, 1), math.pi / 2, CosineReward(0))
        >>> memory = task.reset(torch.zeros(1, 1))
        >>> reward, memory = task.step_reward(torch.tensor([[math.pi / 2]]), torch.zeros(1, 1), memory)
        >>> reward, memory["last_angle"], memory["held"]
        (tensor([1.]), tensor([1.5708]), tensor([1.]))
    """

    reward_sees_state = False

    def __init__(
        self,
        spec: EnvSpec,
        angle_delta: float,
        reward: RewardFunction,
        angle_tol: float = math.pi / 180,
        endless: bool = True,
    ) -> None:
        super().__init__(spec, reward)
        if reward.stateful:
            raise TypeError(f"FlippingTask needs a stateless reward function, got {type(reward).__name__}")
        if spec.state_size != 1:
            raise ValueError(
                f"FlippingTask needs a one-dimensional state (the angle), got a state of size {spec.state_size}; "
                "select the angle with a MaskedTask"
            )
        angle_delta = check_finite_scalar(angle_delta, "angle_delta")
        angle_tol = check_finite_scalar(angle_tol, "angle_tol")
        if angle_delta <= 0:
            raise ValueError(f"angle_delta must be positive, got {angle_delta}")
        if angle_tol < 0:
            raise ValueError(f"angle_tol must be non-negative, got {angle_tol}")
        if not isinstance(endless, bool):
            raise TypeError(f"endless must be a bool, got {endless!r}")
        self.angle_delta = angle_delta
        self.angle_tol = angle_tol
        self.endless = endless

    @property
    def term_names(self) -> tuple[str, ...]:
        """No breakdown: the step reward is the held reward plus the reward of the closer target."""
        return ()

    def _own_memory(self, init_state: torch.Tensor, overrides: dict[str, Any]) -> dict[str, Any]:
        zeros = init_state.new_zeros(init_state.shape[:-1])
        entries = {"last_angle": zeros, "held": zeros.clone()}
        if not self.endless:
            entries["flipped"] = torch.zeros(init_state.shape[:-1], dtype=torch.bool, device=init_state.device)
        return entries

    def _closest_target(self, state: torch.Tensor, memory: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        """Return ``(target, wrapped error)`` of the target closer to the state."""
        last = read(memory, "last_angle")
        angle = state[..., 0]
        up = last + self.angle_delta
        down = last - self.angle_delta
        error_up = wrap_angle(up - angle)
        error_down = wrap_angle(down - angle)
        take_down = error_down.abs() < error_up.abs()
        return torch.where(take_down, down, up), torch.where(take_down, error_down, error_up)

    def _step_reward(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        target, error = self._closest_target(state, memory)
        value = self.reward._value(error.unsqueeze(-1), -action)
        held = read(memory, "held")
        flipped = error.abs() <= self.angle_tol
        entries = copy_entries(memory)
        entries["last_angle"] = torch.where(flipped, target, read(memory, "last_angle"))
        entries["held"] = torch.where(flipped, held + value, held)
        if not self.endless:
            entries["flipped"] = flipped
        return held + value, make_memory(entries, memory.batch_size)

    def _has_success_condition(self) -> bool:
        return not self.endless  # an endless flipping task keeps going: it never succeeds

    def _has_succeeded(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        if self.endless:
            return torch.zeros(state.shape[:-1], dtype=torch.bool, device=state.device)
        # a flip recorded by this step's reward (post-step timing) counts, as does a state at a target
        _, error = self._closest_target(state, memory)
        return read(memory, "flipped") | (error.abs() <= self.angle_tol)
