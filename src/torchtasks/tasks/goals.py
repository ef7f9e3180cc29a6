"""Goals passed per transition: where in a task tree the desired state lives, and how a goal replaces it.

A goal-taking task (a :class:`~torchtasks.tasks.DesiredStateTask`) keeps its desired state in its
memory (``"state_des"``). A goal given to :meth:`Task.transition <torchtasks.tasks.Task.transition>`
(or to the fine-grained calls) replaces that entry for the call, wherever the task sits in the tree
(inside wrappers, masks and composites): the evaluation itself is unchanged, and the memory it
returns carries the goal it was judged against.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

import torch
from tensordict import TensorDictBase

from torchtasks._memory import copy_entries, make_memory, read

__all__ = ["GoalSlot", "replace_entry", "replace_goals"]

#: the memory key of a desired state
GOAL_ENTRY = "state_des"


class GoalSlot(NamedTuple):
    """One goal-taking task of a tree: where its goal lives and what it is compared with.

    Attributes:
        name: the dotted memory path of the goal entry (``"state_des"``, ``"wrapped.state_des"``,
            ``"task1.wrapped.state_des"``): how a tree with several goal tasks names them.
        path: the same path as a tuple of memory keys.
        size: the number of goal entries ``k`` (the state size of the goal task).
        state_indices: the entries of the full state the goal task sees (masks compose), or ``None``
            for all of them: the *achieved goal* of a state is ``state[..., state_indices]``.
    """

    name: str
    path: tuple[str, ...]
    size: int
    state_indices: tuple[int, ...] | None

    def achieved(self, state: torch.Tensor) -> torch.Tensor:
        """The entries of ``state`` (``[*B, n]``) this goal is compared with (``[*B, k]``)."""
        if self.state_indices is None:
            return state
        index = torch.tensor(self.state_indices, dtype=torch.long, device=state.device)
        return state.index_select(-1, index)


def replace_entry(memory: TensorDictBase, path: tuple[str, ...], value: torch.Tensor) -> TensorDictBase:
    """Return ``memory`` with the entry at ``path`` (a tuple of keys into nested memory) replaced by ``value``."""
    entries = copy_entries(memory)
    if len(path) == 1:
        entries[path[0]] = value
    else:
        entries[path[0]] = replace_entry(read(memory, path[0]), path[1:], value)
    return make_memory(entries, memory.batch_size)


def replace_goals(memory: TensorDictBase, goals: Mapping[GoalSlot, torch.Tensor]) -> TensorDictBase:
    """Return ``memory`` with the desired state of every slot replaced by its goal (``[*B, k]``, unchecked)."""
    for slot, goal in goals.items():
        memory = replace_entry(memory, slot.path, goal)
    return memory
