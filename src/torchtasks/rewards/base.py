"""The reward-function protocol: stateless calls and the functional memory protocol."""

from __future__ import annotations

from collections.abc import Mapping

import torch
from tensordict import TensorDict
from torch import nn

from torchtasks._checks import as_constant, check_input, check_same_batch

__all__ = ["RewardFunction", "empty_memory", "sum_terms"]


def sum_terms(values: Mapping[str, torch.Tensor]) -> torch.Tensor:
    """Sum named reward terms left to right (the order Pyrado adds them in)."""
    iterator = iter(values.values())
    total = next(iterator)
    for value in iterator:
        total = total + value
    return total


def squared_sum(x: torch.Tensor) -> torch.Tensor:
    """Return ``(x * x).sum(-1)`` as a matrix-vector product: 2-3x faster on the CPU for a short last dim.

    Example:
        >>> import torch
        >>> squared_sum(torch.tensor([[1.0, 2.0], [3.0, 0.0]]))
        tensor([5., 9.])
    """
    return (x * x) @ x.new_ones(x.shape[-1])


def empty_memory(reference: torch.Tensor) -> TensorDict:
    """Return an empty memory TensorDict whose batch size is ``reference.shape[:-1]``."""
    return TensorDict({}, batch_size=reference.shape[:-1])


class RewardFunction(nn.Module):
    """Base class of reward functions: ``nn.Module``\\ s mapping batched errors to ``Tensor[*B]``.

    A stateless reward is called as ``reward(error_state, error_action)`` with ``[*B, n]`` and
    ``[*B, m]`` inputs (``error_action`` may be ``None`` for rewards that ignore the action) and
    returns one value per environment. Every reward also speaks the functional memory protocol
    of tasks, so stateful rewards (the forward-velocity family) and stateless ones are used the
    same way::

        memory = reward.reset(init_state)                  # TensorDict, batch = init_state.shape[:-1]
        value, memory = reward.step(state, action, memory)

    Class attributes:
        stateful: whether :meth:`step` reads and writes memory.
        can_fail: whether :meth:`has_failed` may return True (e.g. an unhealthy robot with
            ``terminate_when_unhealthy``); tasks OR it into their failure.
        uses_action: whether the action input is read.
        term_names: names of the named terms of rewards made of several (compound and
            locomotion rewards), which also offer ``step_terms(state, action, memory) ->
            ({name: value}, memory)``.

    Pyrado name: ``RewFcn``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import QuadraticErrorReward
        >>> reward = QuadraticErrorReward(Q=[1.0, 2.0], R=[0.5])
        >>> memory = reward.reset(torch.zeros(4, 2))
        >>> value, memory = reward.step(torch.ones(4, 2), torch.ones(4, 1), memory)
        >>> value
        tensor([-3.5000, -3.5000, -3.5000, -3.5000])
    """

    stateful: bool = False
    can_fail: bool = False
    uses_action: bool = True
    #: names of the terms :meth:`step_terms` returns (empty for single-term rewards)
    term_names: tuple[str, ...] = ()

    def _register_constant(self, name: str, value: torch.Tensor, learnable: bool = False) -> None:
        """Register ``value`` as a buffer, or as a parameter when ``learnable``."""
        if learnable:
            self.register_parameter(name, nn.Parameter(value))
        else:
            self.register_buffer(name, value)

    def _register_scalar(self, name: str, value: object, learnable: bool = False) -> None:
        """Register a 0-d float64 constant (0-d tensors keep the input dtype in arithmetic)."""
        self._register_constant(name, as_constant(value, name, ndim=(0,)), learnable)

    def _check_inputs(
        self,
        error_state: torch.Tensor,
        error_action: torch.Tensor | None,
        state_size: int | None = None,
        action_size: int | None = None,
    ) -> None:
        """Validate the shapes of a call's inputs (raises ``TypeError``/``ValueError``)."""
        check_input(error_state, "error_state", state_size)
        if not self.uses_action:
            return
        if error_action is None:
            raise TypeError(f"{type(self).__name__} reads the action: error_action must be a tensor, got None")
        check_input(error_action, "error_action", action_size)
        check_same_batch(error_state, error_action, "error_state", "error_action")

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        """The value without input validation (tasks call it after validating sizes once).

        Subclasses override it with their maths and validate in :meth:`forward`; the default
        simply calls the module.
        """
        return self(error_state, error_action)

    def _step(
        self, state: torch.Tensor, action: torch.Tensor | None, memory: TensorDict
    ) -> tuple[torch.Tensor, TensorDict]:
        """:meth:`step` without input validation."""
        if self.stateful:
            return self.step(state, action, memory)
        return self._value(state, action), memory

    def reset(self, init_state: torch.Tensor) -> TensorDict:
        """Return fresh memory for a batch of episodes starting in ``init_state`` (``[*B, n]``)."""
        return empty_memory(init_state)

    def step(
        self, state: torch.Tensor, action: torch.Tensor | None, memory: TensorDict
    ) -> tuple[torch.Tensor, TensorDict]:
        """Return ``(value[*B], memory)`` for one step; stateless rewards pass memory through."""
        return self(state, action), memory

    def has_failed(self, state: torch.Tensor) -> torch.Tensor:
        """Return ``bool[*B]``: whether the state ends the episode as a failure (never, by default)."""
        return torch.zeros(state.shape[:-1], dtype=torch.bool, device=state.device)
