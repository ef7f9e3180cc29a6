"""What one transition of a task produces: :class:`TaskOutput`."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from tensordict import TensorDictBase

__all__ = ["TaskOutput"]


@dataclass(frozen=True)
class TaskOutput:
    """The result of :meth:`Task.transition <torchtasks.tasks.Task.transition>` for a batch of transitions.

    Every tensor has the batch shape ``[*B]`` of the states (flags are bool).

    Attributes:
        reward: ``step_reward + final_reward``: what the agent is paid for the transition.
        step_reward: the step reward (on ``next_state`` or on ``state``, see ``reward_on``).
        final_reward: the one-off final reward, non-zero only where the episode ends, once per episode.
        success: the task's success on ``next_state``.
        failure: the task's failure on ``next_state``.
        terminated: ``success | failure | terminated`` (the env's own termination, if given).
        done: ``terminated | truncated``.
        memory: the task memory after the transition (pass it to the next call).
        terms: ``{name: value[*B]}``, the named terms of the step reward (empty when the task has
            none); for a sum of terms (:class:`~torchtasks.rewards.CompoundReward`) they add up to
            ``step_reward``.
        costs: ``{name: cost[*B]}``, the named costs of the tree's constraints on the state the step
            reward sees (empty when the task has none, see :class:`~torchtasks.tasks.ConstrainedTask`).
        ended_by: ``{name: flag[*B]}``, the tree's named end conditions on ``next_state``
            (:attr:`Task.termination_names <torchtasks.tasks.Task.termination_names>`; the conditions
            of each kind OR to ``success`` and ``failure``); empty when no kind has two or more
            conditions (then ``success`` and ``failure`` say which one held).
        groups: ``{name: value[*B]}``, the tree's reward groups (empty when it has none, see
            :class:`~torchtasks.tasks.RewardGroupsTask`).

    Example:
        >>> import torch
        >>> from torchtasks.rewards import ConstantReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import GoallessTask
        >>> task = GoallessTask(EnvSpec(1, 1), ConstantReward(1.0))
        >>> state = torch.zeros(2, 1)
        >>> out = task.transition(state, torch.zeros(2, 1), state, task.reset(state))
        >>> out.reward, out.done
        (tensor([1., 1.]), tensor([False, False]))
    """

    reward: torch.Tensor
    step_reward: torch.Tensor
    final_reward: torch.Tensor
    success: torch.Tensor
    failure: torch.Tensor
    terminated: torch.Tensor
    done: torch.Tensor
    memory: TensorDictBase
    terms: dict[str, torch.Tensor]
    costs: dict[str, torch.Tensor] = field(default_factory=dict)
    ended_by: dict[str, torch.Tensor] = field(default_factory=dict)
    groups: dict[str, torch.Tensor] = field(default_factory=dict)
