"""Several tasks pursued at the same time."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase

from torchtasks._memory import copy_entries, read
from torchtasks.tasks.composite import CompositeTask
from torchtasks.tasks.memory import make_memory
from torchtasks.tasks.protocol import Task, outcome_names

__all__ = ["ParallelTasks"]


class ParallelTasks(CompositeTask):
    """Pursue several tasks at once; each sub-task is checked off when it is done.

    In every step, the sub-tasks not yet done pay their step reward (done ones pay their held
    reward when ``hold_reward_when_done``); then each sub-task that is done on this state is
    marked succeeded or failed and pays its final reward (and, with hold, its step reward is
    evaluated once more and held). The whole task succeeds when all sub-tasks succeeded (any,
    with ``easily_satisfied``) and fails when any failed (all, with ``allow_failures``). The
    bookkeeping is updated in :meth:`step_reward` only; success and failure read it.

    Args:
        tasks: the sub-tasks (same state and action sizes).
        hold_reward_when_done: keep paying a finished sub-task's last reward.
        allow_failures: fail only when all sub-tasks failed.
        easily_satisfied: succeed when any sub-task succeeded.

    Pyrado name: ``ParallelTasks``.

    Example:
        >>> import functools, torch
        >>> from torchtasks.rewards import ConstantReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import DesiredStateTask, ParallelTasks, proximity_succeeded
        >>> near = functools.partial(proximity_succeeded, threshold=0.1)
        >>> goal = lambda g: DesiredStateTask(EnvSpec(1, 1), [g], ConstantReward(-1.0), near)
        >>> task = ParallelTasks([goal(0.0), goal(1.0)])
        >>> memory = task.reset(torch.zeros(1, 1))
        >>> reward, memory = task.step_reward(torch.zeros(1, 1), torch.zeros(1, 1), memory)
        >>> reward, memory["succeeded"], task.has_succeeded(torch.zeros(1, 1), memory)
        (tensor([-2.]), tensor([[ True, False]]), tensor([False]))
    """

    def __init__(
        self,
        tasks: Sequence[Task],
        hold_reward_when_done: bool = False,
        allow_failures: bool = False,
        easily_satisfied: bool = False,
    ) -> None:
        super().__init__(tasks, hold_reward_when_done)
        for name, value in (("allow_failures", allow_failures), ("easily_satisfied", easily_satisfied)):
            if not isinstance(value, bool):
                raise TypeError(f"{name} must be a bool, got {value!r}")
        self.allow_failures = allow_failures
        self.easily_satisfied = easily_satisfied

    def _step_reward(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        succeeded = list(read(memory, "succeeded").unbind(-1))
        failed = list(read(memory, "failed").unbind(-1))
        held = list(read(memory, "held").unbind(-1)) if self.hold_reward_when_done else None
        zero = state.new_zeros(state.shape[:-1])
        total = zero
        entries = copy_entries(memory)
        # first pass: step rewards of the active sub-tasks (and held rewards of done ones)
        active: list[torch.Tensor] = []
        stepped: list[TensorDictBase] = []
        for i, (key, task) in enumerate(zip(self._keys, self.tasks, strict=True)):
            is_active = ~(succeeded[i] | failed[i])
            value, sub_memory = task._step_reward(state, action, read(memory, key), remaining_steps, terminated)
            total = total + torch.where(is_active, value, zero)
            if held is not None:
                total = total + torch.where(is_active, zero, held[i])
            active.append(is_active)
            stepped.append(sub_memory)
        # second pass: sub-tasks that are done on this state
        for i, (key, task) in enumerate(zip(self._keys, self.tasks, strict=True)):
            sub_memory = stepped[i]
            flags = (task._has_succeeded(state, sub_memory), task._has_failed(state, sub_memory))
            newly_done = self._finish(i, active[i], *flags, succeeded, failed)
            final, sub_memory = task._final_reward(state, sub_memory, remaining_steps, newly_done, flags)
            total = total + torch.where(newly_done, final, zero)
            if held is not None:
                value, after_hold = task._step_reward(state, action, sub_memory, remaining_steps, terminated)
                held[i] = torch.where(newly_done, value, held[i])
                sub_memory = self._gate(newly_done, after_hold, sub_memory)
            entries[key] = self._gate(active[i], sub_memory, read(memory, key))
        entries["succeeded"] = torch.stack(succeeded, dim=-1)
        entries["failed"] = torch.stack(failed, dim=-1)
        if held is not None:
            entries["held"] = torch.stack(held, dim=-1)
        return total, make_memory(entries, memory.batch_size)

    @property
    def termination_names(self) -> dict[str, str]:
        # success: all sub-tasks succeeded (any, easily satisfied); failure: any failed (all, allowing failures)
        successes = [task.facts.can_succeed for task in self.tasks]
        failures = [task.facts.can_fail for task in self.tasks]
        return outcome_names(
            any(successes) if self.easily_satisfied else all(successes),
            all(failures) if self.allow_failures else any(failures),
        )

    def _has_succeeded(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        succeeded = read(memory, "succeeded")
        return succeeded.any(dim=-1) if self.easily_satisfied else succeeded.all(dim=-1)

    def _has_failed(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        failed = read(memory, "failed")
        return failed.all(dim=-1) if self.allow_failures else failed.any(dim=-1)
