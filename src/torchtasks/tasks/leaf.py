"""Shared machinery of leaf tasks that own one reward function."""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase

from torchtasks._memory import copy_entries, read
from torchtasks.rewards.base import RewardFunction
from torchtasks.spaces import EnvSpec
from torchtasks.tasks.memory import make_memory
from torchtasks.tasks.protocol import Task, outcome_names

__all__ = ["RewardTask"]


class RewardTask(Task):
    """A leaf task with one reward function; a stateful reward's memory lives under ``"reward"``.

    Subclasses say what the reward sees by overriding :meth:`_reward_inputs` (state and action
    errors by default) and add their own memory entries with :meth:`_own_memory`.
    """

    #: whether the reward is called with the raw state (then a reward that can fail, such as an
    #: unhealthy robot, makes the task fail); error-based tasks set it to False
    reward_sees_state: bool = True

    def __init__(self, spec: EnvSpec, reward: RewardFunction) -> None:
        super().__init__(spec)
        if not isinstance(reward, RewardFunction):
            raise TypeError(f"reward must be a torchtasks RewardFunction, got {type(reward).__name__}")
        self._check_reward_sizes(spec, reward)
        self.reward = reward

    @staticmethod
    def _check_reward_sizes(spec: EnvSpec, reward: RewardFunction) -> None:
        """Reject a reward that does not fit the task's state or action size (at construction, not per step).

        :meth:`RewardFunction.check_sizes` sees through containers (every term of a
        :class:`~torchtasks.rewards.CompoundReward`) and checks the state indices of the rewards that
        read single entries, so the unchecked step path cannot broadcast or index out of range.
        """
        try:
            reward.check_sizes(spec.state_size, spec.action_size)
        except ValueError as error:
            if "expects states of size" not in str(error):
                raise
            raise ValueError(
                f"{error}. Build the reward for the task's {spec.state_size} state entries, or, to reward part of "
                "the state, build the task on spec.select_state([...]) and wrap it in MaskedTask(spec, task, [...])"
            ) from None

    def _own_memory(self, init_state: torch.Tensor, overrides: dict[str, Any]) -> dict[str, Any]:
        return {}

    def _reset(self, init_state: torch.Tensor, overrides: dict[str, Any]) -> TensorDict:
        entries = self._own_memory(init_state, overrides)
        if self.reward.stateful:
            entries["reward"] = self.reward.reset(init_state)
        return make_memory(entries, init_state.shape[:-1])

    def _reward_inputs(
        self, state: torch.Tensor, action: torch.Tensor, memory: TensorDictBase
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Return what the reward function is called with (raw state and action by default)."""
        return state, action

    def _evaluate_reward(
        self, state: torch.Tensor, action: torch.Tensor, memory: TensorDictBase
    ) -> tuple[torch.Tensor, TensorDictBase]:
        inputs = self._reward_inputs(state, action, memory)
        if not self.reward.stateful:
            return self.reward._value(*inputs), memory
        value, reward_memory = self.reward._step(*inputs, read(memory, "reward"))
        entries = copy_entries(memory)
        entries["reward"] = reward_memory
        return value, make_memory(entries, memory.batch_size)

    def _step_reward(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        return self._evaluate_reward(state, action, memory)

    @property
    def term_names(self) -> tuple[str, ...]:
        return self.reward.term_names

    def _step_terms(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None = None,
    ) -> tuple[dict[str, torch.Tensor], torch.Tensor, TensorDictBase]:
        if not self.term_names:
            reward, memory = self._step_reward(state, action, memory, remaining_steps, terminated)
            return {}, reward, memory
        inputs = self._reward_inputs(state, action, memory)
        step_terms = getattr(self.reward, "_step_terms", self.reward.step_terms)
        if not self.reward.stateful:
            terms, _ = step_terms(*inputs, memory)
        else:
            terms, reward_memory = step_terms(*inputs, read(memory, "reward"))
            entries = copy_entries(memory)
            entries["reward"] = reward_memory
            memory = make_memory(entries, memory.batch_size)
        return terms, self.reward.combine_terms(terms), memory

    def _has_succeeded(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        return torch.zeros(state.shape[:-1], dtype=torch.bool, device=state.device)

    def _has_failed(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        """Out of the state box, or (for rewards of the raw state that can fail) what the reward says."""
        failed = super()._has_failed(state, memory)
        if self.reward.can_fail and self.reward_sees_state:
            failed = failed | self.reward.has_failed(state)
        return failed

    def _names_failures(self) -> bool:
        """Whether this task's failure is :meth:`RewardTask._has_failed` (its parts can be named)."""
        return type(self)._has_failed is RewardTask._has_failed

    def _has_success_condition(self) -> bool:
        """Whether this task can succeed: its class defines a success (a subclass whose success depends on its
        configuration, e.g. a :class:`DesiredStateTask` without a success function, overrides this)."""
        return type(self)._has_succeeded is not RewardTask._has_succeeded

    @property
    def termination_names(self) -> dict[str, str]:
        if not self._names_failures():
            return outcome_names(self._has_success_condition(), can_fail=True)
        names = {"success": "success"} if self._has_success_condition() else {}
        names["out_of_bounds"] = "failure"  # NaN is out of every box: a leaf can always fail
        if self.reward.can_fail and self.reward_sees_state:
            names["unhealthy"] = "failure"
        return names

    def _termination_terms(
        self, state: torch.Tensor, memory: TensorDictBase, success: torch.Tensor, failure: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        if not self._names_failures():
            return super()._termination_terms(state, memory, success, failure)
        terms = {"success": success} if self._has_success_condition() else {}
        terms["out_of_bounds"] = Task._has_failed(self, state, memory)
        if self.reward.can_fail and self.reward_sees_state:
            terms["unhealthy"] = self.reward.has_failed(state)
        return terms
