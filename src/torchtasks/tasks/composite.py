"""Shared machinery of tasks made of several sub-tasks (parallel and sequential composition)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn

from torchtasks._memory import copy_entries, read
from torchtasks.tasks.memory import make_memory, where_memory
from torchtasks.tasks.protocol import Task

__all__ = ["CompositeTask"]


class CompositeTask(Task):
    """Base of :class:`ParallelTasks` and :class:`SequentialTasks`.

    Memory: ``"succeeded"`` and ``"failed"`` (``bool[*B, K]``, the sub-task bookkeeping),
    ``"held"`` (``[*B, K]``, only with ``hold_reward_when_done``) and each sub-task's memory under
    ``"task0"``, ``"task1"``, ... . The spec is the first sub-task's; all sub-tasks must read
    states and actions of the same sizes.
    """

    def __init__(self, tasks: Sequence[Task], hold_reward_when_done: bool = False) -> None:
        if isinstance(tasks, Task) or not isinstance(tasks, Sequence) or not tasks:
            raise TypeError(f"tasks must be a non-empty sequence of Task, got {tasks!r}")
        for i, task in enumerate(tasks):
            if not isinstance(task, Task):
                raise TypeError(f"tasks[{i}] must be a torchtasks Task, got {type(task).__name__}")
            if (task.state_size, task.action_size) != (tasks[0].state_size, tasks[0].action_size):
                raise ValueError(
                    f"all sub-tasks must read the same state and action sizes; tasks[0] reads "
                    f"({tasks[0].state_size}, {tasks[0].action_size}), tasks[{i}] reads "
                    f"({task.state_size}, {task.action_size})"
                )
        for i, task in enumerate(tasks):
            if task.group_names:
                raise ValueError(
                    f"{type(self).__name__}: tasks[{i}] has reward groups {list(task.group_names)}, but a composite "
                    "reports no terms of its sub-tasks, so their groups cannot be summed for the tree; wrap the "
                    "composite in the RewardGroupsTask instead (its sources are then the composite's 'step' and "
                    "'final' rewards and terms of the group's own)"
                )
        owners: dict[str, int] = {}
        for i, task in enumerate(tasks):
            for name in task.cost_names:
                if name in owners:  # two costs under one name: one would overwrite the other
                    raise ValueError(
                        f"{type(self).__name__}: cost names must be unique in the tree; {name!r} names a cost of "
                        f"tasks[{owners[name]}] and of tasks[{i}] (give the constraints different names)"
                    )
                owners[name] = i
        if not isinstance(hold_reward_when_done, bool):
            raise TypeError(f"hold_reward_when_done must be a bool, got {hold_reward_when_done!r}")
        super().__init__(tasks[0].spec)
        self.tasks = nn.ModuleList(tasks)
        self.hold_reward_when_done = hold_reward_when_done
        self._keys = tuple(f"task{i}" for i in range(len(tasks)))

    def children_tasks(self) -> tuple[Task, ...]:
        return tuple(self.tasks)

    def _child_memory_keys(self) -> tuple[str | None, ...]:
        return self._keys

    @property
    def pays_final_reward(self) -> bool:
        return any(task.pays_final_reward for task in self.tasks)

    @property
    def num_tasks(self) -> int:
        """Number of sub-tasks ``K``."""
        return len(self.tasks)

    def _bookkeeping(self, init_state: torch.Tensor, overrides: dict[str, Any]) -> dict[str, Any]:
        batch = init_state.shape[:-1]
        flags = torch.zeros((*batch, self.num_tasks), dtype=torch.bool, device=init_state.device)
        entries: dict[str, Any] = {"succeeded": flags, "failed": flags.clone()}
        if self.hold_reward_when_done:
            entries["held"] = init_state.new_zeros((*batch, self.num_tasks))
        return entries

    def _reset(self, init_state: torch.Tensor, overrides: dict[str, Any]) -> TensorDict:
        entries = self._bookkeeping(init_state, overrides)
        for key, task in zip(self._keys, self.tasks, strict=True):
            entries[key] = task._reset(init_state, overrides)
        return make_memory(entries, init_state.shape[:-1])

    @staticmethod
    def _finish(
        i: int,
        active: torch.Tensor,
        success: torch.Tensor,
        failure: torch.Tensor,
        succeeded: list[torch.Tensor],
        failed: list[torch.Tensor],
    ) -> torch.Tensor:
        """Record how sub-task ``i`` ended where it is active and done (success checked first).

        Returns the mask of environments where the sub-task has just finished.
        """
        newly_done = active & (success | failure)
        succeeded[i] = succeeded[i] | (newly_done & success)
        failed[i] = failed[i] | (newly_done & ~success)
        return newly_done

    def _compute_final_reward(
        self,
        state: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        done: torch.Tensor,
        flags: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        """Sum of the sub-tasks' own final rewards, judged on the final state (Pyrado's order).

        A sub-task pays its own final reward (Pyrado's ``compute_final_rew``); a wrapper that changes no
        number (a mask, a constraint, shaping) passes the judgement to the task it wraps, so wrapping a
        sub-task in one changes nothing (Pyrado's mask hid the final reward inside it). Sub-tasks that
        already paid give 0 (their final rewards are paid once).
        """
        total = state.new_zeros(state.shape[:-1])
        entries = copy_entries(memory)
        for key, task in zip(self._keys, self.tasks, strict=True):
            value, entries[key] = task._unfinished_final_reward(state, read(memory, key), remaining_steps, done)
            total = total + value
        return total, make_memory(entries, memory.batch_size)

    @staticmethod
    def _gate(condition: torch.Tensor, new: TensorDictBase, old: TensorDictBase) -> TensorDictBase:
        """Keep a sub-task's memory unchanged where it was not evaluated."""
        return where_memory(condition, new, old)
