"""What crosses the wall between a task and its callers, by name: :class:`Transition` and :class:`TaskFacts`."""

from __future__ import annotations

from typing import NamedTuple

import torch
from tensordict import TensorDictBase

__all__ = ["FINAL_SOURCE", "STEP_SOURCE", "TRANSITION_FIELDS", "TaskFacts", "Transition"]

#: the names under which a reward group (:class:`~torchtasks.tasks.RewardGroupsTask`) reads the tree's step reward
#: and final reward beside its named terms (the names the reward breakdown writes them under, too)
STEP_SOURCE = "step"
FINAL_SOURCE = "final"


class Transition(NamedTuple):
    """What :meth:`Task._transition <torchtasks.tasks.Task.transition>` returns for a batch of transitions.

    The unchecked twin of :class:`~torchtasks.tasks.TaskOutput` (same fields, same meaning): a named tuple, so
    building it costs what a tuple costs and ``torch.compile(fullgraph=True)`` traces it. Read it by name.

    Fields:
        reward: ``step_reward + final_reward``, ``[*B]``.
        step_reward: the step reward, ``[*B]``.
        final_reward: the one-off final reward, ``[*B]`` (zeros when no task of the tree pays one).
        success: the task's success on ``next_state``, bool ``[*B]``.
        failure: the task's failure on ``next_state``, bool ``[*B]``.
        terminated: ``success | failure | terminated`` (the env's own termination, if given), bool ``[*B]``.
        done: ``terminated | truncated``, bool ``[*B]``.
        memory: the task memory after the transition.
        terms: ``{name: value[*B]}``, the named terms of the step reward (empty unless asked for and named).
        costs: ``{name: cost[*B]}``, the named costs of the tree (empty when it has none).
        ended_by: ``{name: flag[*B]}``, the named end conditions (empty unless a kind has two or more).
        groups: ``{name: value[*B]}``, the tree's reward groups (empty when it has none), in
            :attr:`~torchtasks.tasks.Task.group_dtype` (the terms' dtype when that is ``None``).

    Example:
        >>> import torch
        >>> from torchtasks.rewards import ConstantReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import GoallessTask
        >>> task = GoallessTask(EnvSpec(1, 1), ConstantReward(1.0))
        >>> state = torch.zeros(2, 1)
        >>> out = task._transition(state, torch.zeros(2, 1), state, task.reset(state), task.no_remaining_steps)
        >>> type(out).__name__, out.reward, out.done
        ('Transition', tensor([1., 1.]), tensor([False, False]))
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
    costs: dict[str, torch.Tensor]
    ended_by: dict[str, torch.Tensor]
    groups: dict[str, torch.Tensor]


#: the names of :class:`Transition`'s fields, in order: what a reader of one field by name may ask for
TRANSITION_FIELDS: tuple[str, ...] = Transition._fields


class TaskFacts(NamedTuple):
    """What a caller of a task tree (a :class:`~torchtasks.transforms.TaskTransform`) needs to know about it.

    Fixed by the tree's structure at construction; :attr:`Task.facts <torchtasks.tasks.Task.facts>` computes
    them once and caches them, since the per-step path reads them to skip work nobody needs.

    Fields:
        can_succeed: some named end condition of the tree is a success (:attr:`~torchtasks.tasks.Task.termination_names`
            holds a ``"success"`` kind); else its success flag is always False and is not written.
        can_fail: likewise for failure.
        has_terms: the step reward has named terms (:attr:`~torchtasks.tasks.Task.term_names` is not empty).
        reads_remaining_steps: some task of the tree reads ``remaining_steps``
            (:attr:`~torchtasks.tasks.Task.uses_remaining_steps`).
        pays_final_reward: some task of the tree can pay a final reward
            (:attr:`~torchtasks.tasks.Task.pays_final_reward`; else the final reward is always 0).
        has_costs: the tree has named costs (:attr:`~torchtasks.tasks.Task.cost_names` is not empty).
        has_groups: the tree has reward groups (:attr:`~torchtasks.tasks.Task.group_names` is not empty).
        names_end_conditions: some kind of end (success or failure) has two or more named conditions
            (:attr:`~torchtasks.tasks.Task.termination_names`), so the named flags say more than
            ``success`` and ``failure`` do.

    Example:
        >>> from torchtasks.rewards import ConstantReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import FinalRewardTask, GoallessTask
        >>> facts = FinalRewardTask(GoallessTask(EnvSpec(1, 1), ConstantReward(1.0))).facts
        >>> facts.pays_final_reward, facts.has_terms, facts.reads_remaining_steps, facts.can_succeed
        (True, False, False, False)
    """

    can_succeed: bool
    can_fail: bool
    has_terms: bool
    reads_remaining_steps: bool
    pays_final_reward: bool
    has_costs: bool
    has_groups: bool
    names_end_conditions: bool
