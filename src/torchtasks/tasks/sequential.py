"""Several tasks pursued one after the other."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase

from torchtasks._checks import check_int
from torchtasks._memory import copy_entries, read
from torchtasks.tasks.composite import CompositeTask
from torchtasks.tasks.goals import replace_entry
from torchtasks.tasks.memory import MemoryLayout, make_memory
from torchtasks.tasks.protocol import Task, outcome_names

__all__ = ["SequentialTasks"]


def _leaf_paths(layout: MemoryLayout, prefix: tuple[str, ...] = ()) -> set[tuple[str, ...]]:
    """The paths of the tensor entries of a memory layout."""
    paths: set[tuple[str, ...]] = set()
    for key in layout.keys:
        if key in layout.nested:
            paths |= _leaf_paths(layout.nested[key], (*prefix, key))
        else:
            paths.add((*prefix, key))
    return paths


class SequentialTasks(CompositeTask):
    """Pursue sub-tasks one after the other; each environment has its own current sub-task.

    In every step only the current sub-task (memory ``"index"``, ``int64[*B]``) pays its step
    reward (plus, with ``hold_reward_when_done``, the held rewards of finished ones). When it is
    done on this state it is marked succeeded or failed, its step reward is held (evaluated
    once more with 0 remaining steps), its final reward is paid and the index moves on
    (wrapping to 0 after the last). Goals reached out of order are ignored until they are
    current. A sub-task starts when it becomes current: its memory is re-initialised as
    ``reset`` would on the state of that step (the state the finished sub-task was judged on, which
    is the state the next step starts from), keeping its goal and whether its final reward was paid
    (:attr:`~Task.kept_at_start`). So a shaped sub-task's first step pays
    ``γ·Φ(s') − Φ(s)`` from where it took over, a forward-velocity reward measures from there, a
    :class:`BestStateFinalRewardTask` tracks the best of its own steps and a :class:`FlippingTask`
    counts flips from 0, as at an episode start. Where the episode ends, every sub-task that has not
    finished is judged on the final state, as in Pyrado: its own final reward (e.g. a
    :class:`FinalRewardTask`'s success or failure value, if the final state meets its goal or leaves
    its box; through a mask, a constraint or shaping, that of the task inside) is paid then, whether or
    not it was current; a
    :class:`BestStateFinalRewardTask` that never became current pays 0. The task succeeds when every
    sub-task succeeded; it fails when the state leaves the first sub-task's state box (a failed
    sub-task does not end the episode by itself).

    Args:
        tasks: the sub-tasks in order (same state and action sizes).
        start_index: the sub-task to start with at every reset (earlier ones count as
            succeeded); ``reset(..., start_index=...)`` overrides it per environment.
        hold_reward_when_done: keep paying finished sub-tasks' last rewards.

    Pyrado name: ``SequentialTasks``. Fixed here: Pyrado forgot ``start_idx`` at reset (and got
    stuck when it was passed to ``reset``).

    Example:
        >>> import functools, torch
        >>> from torchtasks.rewards import ConstantReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import DesiredStateTask, SequentialTasks, proximity_succeeded
        >>> near = functools.partial(proximity_succeeded, threshold=0.1)
        >>> goal = lambda g: DesiredStateTask(EnvSpec(1, 1), [g], ConstantReward(-1.0), near)
        >>> task = SequentialTasks([goal(0.0), goal(1.0)])
        >>> memory = task.reset(torch.zeros(2, 1), start_index=torch.tensor([0, 1]))
        >>> reward, memory = task.step_reward(torch.ones(2, 1), torch.zeros(2, 1), memory)
        >>> memory["index"], task.has_succeeded(torch.ones(2, 1), memory)
        (tensor([0, 0]), tensor([False,  True]))
    """

    reset_keys = ("start_index",)

    def __init__(self, tasks: Sequence[Task], start_index: int = 0, hold_reward_when_done: bool = False) -> None:
        super().__init__(tasks, hold_reward_when_done)
        self.start_index = self._check_start(start_index)

    def _check_start(self, start_index: int) -> int:
        start_index = check_int(start_index, "start_index")
        if not 0 <= start_index < self.num_tasks:
            raise ValueError(f"start_index must lie in [0, {self.num_tasks - 1}], got {start_index}")
        return start_index

    def _bookkeeping(self, init_state: torch.Tensor, overrides: dict[str, Any]) -> dict[str, Any]:
        entries = super()._bookkeeping(init_state, overrides)
        batch = init_state.shape[:-1]
        start = overrides.get("start_index")
        if start is None or isinstance(start, (int, np.integer)):
            start = self.start_index if start is None else self._check_start(start)
            index = torch.full(batch, start, dtype=torch.long, device=init_state.device)
        else:
            index = torch.as_tensor(start, device=init_state.device)
            if index.is_floating_point() or index.dtype == torch.bool or index.shape not in (torch.Size([]), batch):
                raise ValueError(
                    f"start_index override must be an int or an integer tensor of shape {tuple(batch)}, "
                    f"got {index.dtype} {tuple(index.shape)}"
                )
            if ((index < 0) | (index >= self.num_tasks)).any():
                raise ValueError(f"start_index override must lie in [0, {self.num_tasks - 1}], got {index.tolist()}")
            index = index.to(torch.long).expand(batch).clone()
        positions = torch.arange(self.num_tasks, device=init_state.device)
        entries["succeeded"] = positions < index.unsqueeze(-1)
        entries["index"] = index
        return entries

    @property
    def _keeps_progress(self) -> tuple[bool, ...]:
        """Per sub-task: whether its memory holds anything a start re-initialises (beyond kept entries)."""
        return self._cached(
            "_keeps_progress_cache",
            lambda: tuple(bool(_leaf_paths(task.memory_layout) - set(task._kept_paths())) for task in self.tasks),
        )

    @staticmethod
    def _restart(task: Task, state: torch.Tensor, memory: TensorDictBase) -> TensorDictBase:
        """``task``'s memory at an episode start in ``state``, its kept entries (goal, latch) taken from ``memory``."""
        fresh = task._reset(state, {})
        for path in task._kept_paths():
            value = memory
            for key in path:
                value = read(value, key)
            fresh = replace_entry(fresh, path, value)
        return fresh

    def _step_reward(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        index = read(memory, "index")
        succeeded = list(read(memory, "succeeded").unbind(-1))
        failed = list(read(memory, "failed").unbind(-1))
        held = list(read(memory, "held").unbind(-1)) if self.hold_reward_when_done else None
        zero = state.new_zeros(state.shape[:-1])
        total = zero
        if held is not None:
            for i in range(self.num_tasks):
                total = total + torch.where(succeeded[i] | failed[i], held[i], zero)
        new_index = index
        entries = copy_entries(memory)
        finished: list[torch.Tensor] = []
        for i, (key, task) in enumerate(zip(self._keys, self.tasks, strict=True)):
            active = (index == i) & ~(succeeded[i] | failed[i])
            old_memory = read(memory, key)
            value, sub_memory = task._step_reward(state, action, old_memory, remaining_steps, terminated)
            total = total + torch.where(active, value, zero)
            flags = (task._has_succeeded(state, sub_memory), task._has_failed(state, sub_memory))
            newly_done = self._finish(i, active, *flags, succeeded, failed)
            if held is not None:
                value, after_hold = task._step_reward(
                    state, action, sub_memory, torch.zeros_like(remaining_steps), terminated
                )
                held[i] = torch.where(newly_done, value, held[i])
                sub_memory = self._gate(newly_done, after_hold, sub_memory)
            final, sub_memory = task._final_reward(state, sub_memory, remaining_steps, newly_done)
            total = total + torch.where(newly_done, final, zero)
            new_index = torch.where(newly_done, (i + 1) % self.num_tasks, new_index)
            finished.append(newly_done)
            entries[key] = self._gate(active, sub_memory, old_memory)
        # a sub-task that becomes current starts here, as if the episode began in this state (goals kept)
        for j, (key, task) in enumerate(zip(self._keys, self.tasks, strict=True)):
            if j == 0 or not self._keeps_progress[j]:
                continue
            starts = finished[j - 1] & ~(succeeded[j] | failed[j])
            entries[key] = self._gate(starts, self._restart(task, state, entries[key]), entries[key])
        entries["index"] = new_index
        entries["succeeded"] = torch.stack(succeeded, dim=-1)
        entries["failed"] = torch.stack(failed, dim=-1)
        if held is not None:
            entries["held"] = torch.stack(held, dim=-1)
        return total, make_memory(entries, memory.batch_size)

    @property
    def termination_names(self) -> dict[str, str]:
        # success: every sub-task from the start on succeeded; a start (``start_index``, also per reset) may skip
        # all but the last, so the tree can succeed when its last sub-task can. Failure: the state left the box.
        return outcome_names(self.tasks[-1].facts.can_succeed, can_fail=True)

    def _has_succeeded(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        return read(memory, "succeeded").all(dim=-1)
