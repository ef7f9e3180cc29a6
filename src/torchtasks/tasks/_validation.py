"""The argument checks of a task's public calls (:meth:`Task.transition <torchtasks.tasks.Task.transition>`,
``reset``, ``step_reward``, the flags and ``final_reward``).

They read shapes, dtypes and the memory's layout, never values (one exception: a ``remaining_steps`` tensor
is checked for negative values outside a compiled graph), and raise a ``TypeError`` or ``ValueError`` that
names the argument, what was expected and what was received. The unchecked ``_``-methods that composite
tasks call on their children, and that :class:`~torchtasks.transforms.TaskTransform` runs, skip them.
"""

from __future__ import annotations

from typing import Protocol

import torch
from tensordict import TensorDictBase

from torchtasks._checks import check_input, check_same_batch
from torchtasks.tasks.memory import MemoryLayout, check_memory_layout

__all__ = [
    "as_remaining_steps",
    "check_action",
    "check_done",
    "check_flag_argument",
    "check_memory",
    "check_state",
    "check_transition",
]


class CheckedTask(Protocol):
    """What the checks read of a task: the sizes of its state and action and the layout of its memory."""

    @property
    def state_size(self) -> int: ...

    @property
    def action_size(self) -> int: ...

    @property
    def memory_layout(self) -> MemoryLayout: ...


def check_state(task: CheckedTask, state: object, name: str = "state") -> None:
    """``state`` is a float tensor ``[*B, n]`` with the task's ``n`` state entries."""
    check_input(state, name, task.state_size)


def check_action(task: CheckedTask, state: torch.Tensor, action: object) -> None:
    """``action`` is a tensor ``[*B, m]`` with the task's ``m`` action entries, the batch and dtype of ``state``."""
    check_input(action, "action", task.action_size)
    check_same_batch(state, action, "state", "action")
    if action.dtype != state.dtype:  # would promote the reward and the memory to the wider dtype
        raise TypeError(
            f"action must have the dtype of state ({state.dtype}), got {action.dtype}; cast it, e.g. "
            "action.to(state.dtype) (a TaskTransform casts the env's action to the state's dtype)"
        )


def check_memory(task: CheckedTask, state: torch.Tensor, memory: object) -> None:
    """``memory`` is a TensorDict of the task's layout, with the batch of ``state`` and its float dtype."""
    if not isinstance(memory, TensorDictBase):
        raise TypeError(f"memory must be the TensorDict returned by reset(), got {type(memory).__name__}")
    if memory.batch_size != state.shape[:-1]:
        raise ValueError(
            f"memory has batch size {tuple(memory.batch_size)} but the state has batch shape "
            f"{tuple(state.shape[:-1])}; call reset() with a state of the same batch shape"
        )
    check_memory_layout(memory, task.memory_layout, type(task).__name__)
    for key, value in memory.items(include_nested=True, leaves_only=True):
        if value.is_floating_point() and value.dtype != state.dtype:  # would silently promote the outputs
            raise TypeError(
                f"memory[{key!r}] is {value.dtype} but the state is {state.dtype}; call reset() with a state "
                f"of the dtype the task is called with"
            )


def check_flag_argument(flag: object, name: str, batch: torch.Size) -> None:
    """``flag`` is None or a bool tensor of shape ``batch``."""
    if flag is None:
        return
    if not isinstance(flag, torch.Tensor) or flag.dtype != torch.bool:
        got = f"a {flag.dtype} tensor" if isinstance(flag, torch.Tensor) else type(flag).__name__
        raise TypeError(f"{name} must be None or a bool tensor of shape {tuple(batch)}, got {got}")
    if flag.shape != batch:
        raise ValueError(f"{name} must have the batch shape {tuple(batch)}, got {tuple(flag.shape)}")


def check_transition(
    task: CheckedTask,
    state: torch.Tensor,
    action: torch.Tensor,
    next_state: torch.Tensor,
    memory: TensorDictBase,
    terminated: torch.Tensor | None,
    truncated: torch.Tensor | None,
    reward_on: str,
) -> None:
    """Validate the arguments of :meth:`Task.transition` (shapes, dtypes and the memory's layout; once per call)."""
    check_state(task, state)
    check_action(task, state, action)
    check_input(next_state, "next_state", task.state_size)
    if next_state.shape != state.shape:
        raise ValueError(f"next_state must have the shape of state {tuple(state.shape)}, got {tuple(next_state.shape)}")
    if next_state.dtype != state.dtype:
        raise TypeError(f"next_state must have the dtype of state ({state.dtype}), got {next_state.dtype}")
    check_memory(task, state, memory)
    batch = state.shape[:-1]
    check_flag_argument(terminated, "terminated", batch)
    check_flag_argument(truncated, "truncated", batch)
    if reward_on not in ("next", "state"):
        raise ValueError(f"reward_on must be 'next' or 'state', got {reward_on!r}")


def as_remaining_steps(
    remaining_steps: int | torch.Tensor, state: torch.Tensor, unread: torch.Tensor | None
) -> torch.Tensor:
    """Check ``remaining_steps`` (an int >= 0, or an integer tensor >= 0 broadcastable to the batch of ``state``)
    and return it as a tensor.

    ``unread`` is what an int becomes when no task of the tree reads the remaining steps (no tensor to build);
    ``None`` when some task reads them.
    """
    if isinstance(remaining_steps, bool):
        raise TypeError("remaining_steps must be an int or an integer tensor, got a bool")
    if isinstance(remaining_steps, int):
        if remaining_steps < 0:
            raise ValueError(
                f"remaining_steps must be >= 0 (the steps left before the time limit; 0 without a limit), "
                f"got {remaining_steps}"
            )
        if unread is not None:
            return unread
        return torch.tensor(remaining_steps, device=state.device)
    if not isinstance(remaining_steps, torch.Tensor):
        raise TypeError(f"remaining_steps must be an int or a tensor, got {type(remaining_steps).__name__}")
    if remaining_steps.is_floating_point() or remaining_steps.dtype == torch.bool:
        raise TypeError(f"remaining_steps must be an integer tensor, got dtype {remaining_steps.dtype}")
    batch = state.shape[:-1]
    try:
        broadcast = torch.broadcast_shapes(remaining_steps.shape, batch)
    except RuntimeError:
        broadcast = None
    if broadcast != batch:
        raise ValueError(
            f"remaining_steps must be broadcastable to the batch shape {tuple(batch)}, "
            f"got shape {tuple(remaining_steps.shape)}"
        )
    # a value check (one host sync) in the checked public calls; a compiled graph and meta tensors skip it
    if (
        not torch.compiler.is_compiling()
        and remaining_steps.device.type != "meta"
        and bool((remaining_steps < 0).any())
    ):
        raise ValueError(
            "remaining_steps must be >= 0 (the steps left before the time limit; 0 without a limit), got "
            f"values down to {int(remaining_steps.min())}: a step count beyond the limit (data collected with "
            "a longer limit, or a max_steps below the env's own) would flip the sign of a time-dependent "
            "final reward"
        )
    return remaining_steps


def check_done(done: object, state: torch.Tensor) -> None:
    """``done`` is a bool tensor of the batch shape of ``state``."""
    if not isinstance(done, torch.Tensor) or done.dtype != torch.bool:
        raise TypeError(f"done must be a bool tensor of shape {tuple(state.shape[:-1])}, got {done!r}")
    if done.shape != state.shape[:-1]:
        raise ValueError(f"done must have shape {tuple(state.shape[:-1])}, got {tuple(done.shape)}")
