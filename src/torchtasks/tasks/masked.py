"""A task that sees only selected entries of the state and action."""

from __future__ import annotations

from collections.abc import Iterable

import torch

from torchtasks.spaces import EnvSpec
from torchtasks.tasks.protocol import Task
from torchtasks.tasks.wrapper import ForwardingTask

__all__ = ["MaskedTask"]


def _on_device(index: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``index`` on the device of ``x`` (a no-op when it is there already, as after ``task.to(device)``)."""
    return index if index.device == x.device else index.to(x.device)


class MaskedTask(ForwardingTask):
    """Evaluate a task on selected state (and action) entries, in the order given.

    The wrapped task is built for the sub-spec (e.g. ``spec.select_state(indices)``) and sees
    ``state[..., indices]`` and ``action[..., action_indices]``. Entries that are not selected
    cannot make it fail. Its memory is the wrapped task's memory, and its final rewards are
    paid (also when the masked task is itself wrapped).

    Args:
        spec: the full state and action boxes.
        task: the task on the selected entries.
        state_indices: ints or labels of the state entries (order kept; unknown labels and
            duplicates raise ``ValueError``); ``None`` selects all.
        action_indices: ints or labels of the action entries; ``None`` selects all.

    Pyrado name: ``MaskedTask`` (whose boolean masks ignored the order given and hid inner final
    rewards from an outer wrapper).

    Example:
        >>> import torch
        >>> from torchtasks.rewards import QuadraticErrorReward
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> from torchtasks.tasks import DesiredStateTask, MaskedTask
        >>> spec = EnvSpec(Box([-1.0] * 3, [1.0] * 3, labels=["x", "y", "z"]), 1)
        >>> inner = DesiredStateTask(spec.select_state(["z", "x"]), [1.0, 0.0], QuadraticErrorReward([1.0, 1.0], None))
        >>> task = MaskedTask(spec, inner, ["z", "x"])
        >>> task.step_reward(torch.tensor([[0.5, 9.0, 1.0]]), torch.zeros(1, 1), task.reset(torch.zeros(1, 3)))[0]
        tensor([-0.2500])
    """

    def __init__(
        self,
        spec: EnvSpec,
        task: Task,
        state_indices: Iterable[int | str] | int | str | None,
        action_indices: Iterable[int | str] | int | str | None = None,
    ) -> None:
        super().__init__(spec, task)
        state_positions = (
            list(range(spec.state_size)) if state_indices is None else spec.state_space.indices(state_indices)
        )
        action_positions = (
            list(range(spec.action_size)) if action_indices is None else spec.action_space.indices(action_indices)
        )
        if task.state_size != len(state_positions):
            raise ValueError(
                f"the wrapped task reads {task.state_size} state entries but {len(state_positions)} are selected"
            )
        if task.action_size != len(action_positions):
            raise ValueError(
                f"the wrapped task reads {task.action_size} action entries but {len(action_positions)} are selected"
            )
        self.state_indices = state_positions
        self.action_indices = action_positions
        self.register_buffer("state_index", torch.tensor(state_positions, dtype=torch.long))
        self.register_buffer("action_index", torch.tensor(action_positions, dtype=torch.long))

    def _goal_slots(self, prefix: tuple[str, ...], indices: tuple[int, ...] | None) -> list:
        selected = tuple(self.state_indices) if indices is None else tuple(indices[i] for i in self.state_indices)
        return self.wrapped_task._goal_slots(prefix, selected)

    def _state(self, state: torch.Tensor) -> torch.Tensor:
        return state.index_select(-1, _on_device(self.state_index, state))

    def _action(self, action: torch.Tensor) -> torch.Tensor:
        return action.index_select(-1, _on_device(self.action_index, action))
