"""Tasks around one task: :class:`TaskWrapper` (the wrapped task's memory one level down),
:class:`ForwardingTask` (the wrapped task's memory is its own) and :func:`all_tasks`."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase

from torchtasks._memory import copy_entries, read
from torchtasks.spaces import EnvSpec
from torchtasks.tasks.memory import make_memory
from torchtasks.tasks.protocol import DEFAULT_TERMINATIONS, Task

__all__ = ["ForwardingTask", "TaskWrapper", "all_tasks"]


class TaskWrapper(Task):
    """A task that wraps another one and forwards everything it does not change.

    The wrapped task's memory is kept under the key ``"wrapped"``; :meth:`final_reward` adds this
    wrapper's own final reward to the wrapped task's (so nested wrappers each pay once).

    Args:
        task: the wrapped task.

    Example:
        >>> from torchtasks.rewards import ConstantReward
        >>> from torchtasks.spaces import Box, EnvSpec, rows_outside
        >>> from torchtasks.tasks import GoallessTask, TaskWrapper
        >>> wrapper = TaskWrapper(GoallessTask(EnvSpec(2, 1), ConstantReward(1.0)))
        >>> wrapper.wrapped_task.__class__.__name__
        'GoallessTask'
    """

    def __init__(self, task: Task) -> None:
        if not isinstance(task, Task):
            raise TypeError(f"task must be a torchtasks Task, got {type(task).__name__}")
        super().__init__(task.spec)
        self.wrapped_task = task

    def children_tasks(self) -> tuple[Task, ...]:
        return (self.wrapped_task,)

    def _child_memory_keys(self) -> tuple[str | None, ...]:
        return ("wrapped",)

    @property
    def term_names(self) -> tuple[str, ...]:
        return self.wrapped_task.term_names

    def _own_memory(self, init_state: torch.Tensor) -> dict[str, torch.Tensor]:
        """This wrapper's own memory entries at reset (none by default)."""
        return {}

    def _reset(self, init_state: torch.Tensor, overrides: dict[str, Any]) -> TensorDict:
        entries: dict[str, Any] = self._own_memory(init_state)
        entries["wrapped"] = self.wrapped_task._reset(init_state, overrides)
        return make_memory(entries, init_state.shape[:-1])

    @staticmethod
    def _replace(memory: TensorDictBase, **entries: Any) -> TensorDictBase:
        """Return a shallow copy of ``memory`` with ``entries`` replaced."""
        values = copy_entries(memory)
        values.update(entries)
        return make_memory(values, memory.batch_size)

    def _after_step(self, reward: torch.Tensor, memory: TensorDictBase, inner: TensorDictBase) -> TensorDictBase:
        """Return this wrapper's memory after a step of the wrapped task (``inner`` is its new memory)."""
        return self._with_inner(memory, inner)

    def _with_inner(self, memory: TensorDictBase, inner: TensorDictBase) -> TensorDictBase:
        """``memory`` with the wrapped task's memory replaced (no copy when it did not change)."""
        if inner is read(memory, "wrapped"):
            return memory
        return self._replace(memory, wrapped=inner)

    def _step_reward(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        reward, inner = self.wrapped_task._step_reward(
            state, action, read(memory, "wrapped"), remaining_steps, terminated
        )
        return reward, self._after_step(reward, memory, inner)

    def _step_terms(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None = None,
    ) -> tuple[dict[str, torch.Tensor], torch.Tensor, TensorDictBase]:
        terms, reward, inner = self.wrapped_task._step_terms(
            state, action, read(memory, "wrapped"), remaining_steps, terminated
        )
        return terms, reward, self._after_step(reward, memory, inner)

    def _forwards_flags(self) -> bool:
        """Whether this wrapper's success and failure are its wrapped task's (no override of either)."""
        cls = type(self)
        return cls._has_succeeded is TaskWrapper._has_succeeded and cls._has_failed is TaskWrapper._has_failed

    @property
    def termination_names(self) -> dict[str, str]:
        return self.wrapped_task.termination_names if self._forwards_flags() else dict(DEFAULT_TERMINATIONS)

    def _termination_terms(
        self, state: torch.Tensor, memory: TensorDictBase, success: torch.Tensor, failure: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        if not self._forwards_flags():
            return super()._termination_terms(state, memory, success, failure)
        return self.wrapped_task._termination_terms(state, read(memory, "wrapped"), success, failure)

    def _has_succeeded(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        return self.wrapped_task._has_succeeded(state, read(memory, "wrapped"))

    def _has_failed(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        return self.wrapped_task._has_failed(state, read(memory, "wrapped"))

    def _is_done(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        return self.wrapped_task._is_done(state, read(memory, "wrapped"))

    def _pays_own_final_reward(self) -> bool:
        # this class's _final_reward adds the wrapper's own _compute_final_reward to the wrapped task's
        cls = type(self)
        return (
            cls._compute_final_reward is not Task._compute_final_reward
            or cls._final_reward is not TaskWrapper._final_reward
        )

    def _final_reward(
        self,
        state: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        done: torch.Tensor,
        flags: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        # a wrapper's success and failure are its wrapped task's, so the flags pass down unchanged
        own, memory = self._compute_final_reward(state, memory, remaining_steps, done, flags)
        inner_reward, inner = self.wrapped_task._final_reward(
            state, read(memory, "wrapped"), remaining_steps, done, flags
        )
        return own + inner_reward, self._with_inner(memory, inner)


class ForwardingTask(Task):
    """A task that forwards every call to one wrapped task, whose memory is its own (no extra level).

    Subclasses change what the wrapped task sees (:meth:`_state`, :meth:`_action`: identity here) or add
    to what the tree reports (costs); the reward, flags, final rewards, terms, goals and end conditions
    are the wrapped task's.

    Args:
        spec: this task's state and action boxes.
        task: the wrapped task.

    Example:
        >>> from torchtasks.rewards import ConstantReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import ForwardingTask, GoallessTask
        >>> task = ForwardingTask(EnvSpec(2, 1), GoallessTask(EnvSpec(2, 1), ConstantReward(1.0)))
        >>> task.term_names, task.termination_names == task.wrapped_task.termination_names
        ((), True)
    """

    def __init__(self, spec: EnvSpec, task: Task) -> None:
        super().__init__(spec)
        if not isinstance(task, Task):
            raise TypeError(f"task must be a torchtasks Task, got {type(task).__name__}")
        self.wrapped_task = task

    def _state(self, state: torch.Tensor) -> torch.Tensor:
        """What the wrapped task sees of a state (all of it here)."""
        return state

    def _action(self, action: torch.Tensor) -> torch.Tensor:
        """What the wrapped task sees of an action (all of it here)."""
        return action

    def children_tasks(self) -> tuple[Task, ...]:
        return (self.wrapped_task,)

    def _child_memory_keys(self) -> tuple[str | None, ...]:
        return (None,)  # the wrapped task's memory is this task's memory

    @property
    def term_names(self) -> tuple[str, ...]:
        return self.wrapped_task.term_names

    @property
    def pays_final_reward(self) -> bool:
        return self.wrapped_task.pays_final_reward

    @property
    def termination_names(self) -> dict[str, str]:
        return self.wrapped_task.termination_names

    def _termination_terms(
        self, state: torch.Tensor, memory: TensorDictBase, success: torch.Tensor, failure: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        return self.wrapped_task._termination_terms(self._state(state), memory, success, failure)

    def _step_costs(self, state: torch.Tensor, action: torch.Tensor) -> dict[str, torch.Tensor]:
        return self.wrapped_task._step_costs(self._state(state), self._action(action))

    def _reward_groups(
        self, sources: Mapping[str, torch.Tensor], state: torch.Tensor, action: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        return self.wrapped_task._reward_groups(sources, self._state(state), self._action(action))

    def _reset(self, init_state: torch.Tensor, overrides: dict[str, Any]) -> TensorDict:
        return self.wrapped_task._reset(self._state(init_state), overrides)

    def _step_reward(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        action = self._action(action)
        return self.wrapped_task._step_reward(self._state(state), action, memory, remaining_steps, terminated)

    def _step_terms(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None = None,
    ) -> tuple[dict[str, torch.Tensor], torch.Tensor, TensorDictBase]:
        action = self._action(action)
        return self.wrapped_task._step_terms(self._state(state), action, memory, remaining_steps, terminated)

    def _has_succeeded(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        return self.wrapped_task._has_succeeded(self._state(state), memory)

    def _has_failed(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        return self.wrapped_task._has_failed(self._state(state), memory)

    def _is_done(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        return self.wrapped_task._is_done(self._state(state), memory)

    def _final_reward(
        self,
        state: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        done: torch.Tensor,
        flags: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        return self.wrapped_task._final_reward(self._state(state), memory, remaining_steps, done, flags)

    def _unfinished_final_reward(
        self, state: torch.Tensor, memory: TensorDictBase, remaining_steps: torch.Tensor, done: torch.Tensor
    ) -> tuple[torch.Tensor, TensorDictBase]:
        return self.wrapped_task._unfinished_final_reward(self._state(state), memory, remaining_steps, done)


def all_tasks(task: Task) -> Iterator[Task]:
    """Yield ``task`` and, while the current one is a :class:`TaskWrapper`, the task it wraps.

    Outermost first. Like Pyrado's ``all_tasks``, it stops at the first task that is not a
    wrapper (composite tasks such as :class:`ParallelTasks` are not descended into).

    Example:
        >>> from torchtasks.rewards import ConstantReward
        >>> from torchtasks.spaces import Box, EnvSpec, rows_outside
        >>> from torchtasks.tasks import FinalRewardTask, GoallessTask, all_tasks
        >>> task = FinalRewardTask(GoallessTask(EnvSpec(1, 1), ConstantReward(0.0)))
        >>> [type(t).__name__ for t in all_tasks(task)]
        ['FinalRewardTask', 'GoallessTask']
    """
    if not isinstance(task, Task):
        raise TypeError(f"task must be a torchtasks Task, got {type(task).__name__}")
    current = task
    yield current
    while isinstance(current, TaskWrapper):
        current = current.wrapped_task
        yield current
