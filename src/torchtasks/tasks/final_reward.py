"""One-off rewards at the end of an episode: :class:`FinalRewardTask` and :class:`BestStateFinalRewardTask`."""

from __future__ import annotations

from typing import NamedTuple

import torch
from tensordict import TensorDictBase

from torchtasks._checks import cast_like, check_finite_scalar
from torchtasks._memory import read
from torchtasks.tasks.protocol import Task
from torchtasks.tasks.wrapper import TaskWrapper

__all__ = ["BestStateFinalRewardTask", "FinalRewardMode", "FinalRewardTask"]


class FinalRewardMode(NamedTuple):
    """How :class:`FinalRewardTask` computes its final reward (all flags False: ``±factor``).

    Supported combinations (others raise ``ValueError``), with ``k = |factor|``, ``rem`` the
    remaining steps and ``r_s = |step reward of the final state with a zero action|``:

    ============================================  =============  =============
    flags                                         failure         success
    ============================================  =============  =============
    (none)                                        ``-k``          ``+k``
    always_positive                               0               ``+k``
    always_negative                               ``-k``          0
    always_positive, state_dependent              0               ``+k·r_s``
    always_negative, state_dependent              ``-k·r_s``      0
    state_dependent                               ``-k·r_s``      ``+k·r_s``
    state_dependent, time_dependent               ``-rem·r_s``    ``+rem·r_s``
    time_dependent                                ``-rem``        ``+rem``
    always_positive, time_dependent               0               ``+rem``
    always_negative, time_dependent               ``-rem``        0
    ============================================  =============  =============

    ``user_input`` (ask a human on stdin) is not supported in batched evaluation.

    Pyrado name: ``FinalRewMode``.

    Example:
        >>> mode = FinalRewardMode(always_negative=True)
        >>> mode.always_negative, mode.state_dependent
        (True, False)
    """

    state_dependent: bool = False
    time_dependent: bool = False
    always_positive: bool = False
    always_negative: bool = False
    user_input: bool = False


_SUPPORTED_MODES = {
    (False, False, False, False),
    (False, False, True, False),
    (False, False, False, True),
    (True, False, True, False),
    (True, False, False, True),
    (True, False, False, False),
    (True, True, False, False),
    (False, True, False, False),
    (False, True, True, False),
    (False, True, False, True),
}


class FinalRewardTask(TaskWrapper):
    """Add a one-off reward at the end of an episode, depending on success or failure.

    The final reward is paid exactly once per episode, in the step where the episode ends
    (success, failure or time limit: the caller's ``done``). Failure is checked before success
    (if both hold, the failure value is paid); an episode that ends by time limit in neither
    state gets 0. The value follows :class:`FinalRewardMode`. A state-dependent mode evaluates
    the wrapped task's step reward on the final state with a zero action; that extra
    evaluation never changes memory.

    Memory: ``"paid"`` (bool) and the wrapped task's memory under ``"wrapped"``.

    Args:
        task: the wrapped task.
        mode: a :class:`FinalRewardMode`.
        factor: magnitude ``k`` of the final reward (its absolute value is used).

    Pyrado name: ``FinalRewTask``. Fixed here: Pyrado set its "paid" latch even when the episode
    had not ended, let the extra step-reward call change the wrapped task's state, and raised
    only at the first final reward for unsupported modes (here: at construction).

    Example:
        >>> import torch
        >>> from torchtasks.rewards import ConstantReward
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> from torchtasks.tasks import DesiredStateTask, FinalRewardTask
        >>> inner = DesiredStateTask(EnvSpec(Box(-1.0, 1.0).select([0]), 1), [0.0], ConstantReward(-1.0))
        >>> task = FinalRewardTask(inner, factor=100.0)
        >>> memory = task.reset(torch.zeros(2, 1))
        >>> state = torch.tensor([[0.5], [3.0]])
        >>> done = task.is_done(state, memory)
        >>> task.final_reward(state, memory, 0, done)[0]
        tensor([   0., -100.])
    """

    def __init__(self, task: Task, mode: FinalRewardMode | None = None, factor: float = 1e3) -> None:
        super().__init__(task)
        mode = FinalRewardMode() if mode is None else mode
        if not isinstance(mode, FinalRewardMode):
            raise TypeError(f"mode must be a FinalRewardMode, got {type(mode).__name__}")
        if mode.user_input:
            raise ValueError("FinalRewardMode(user_input=True) is not supported: a batched task cannot ask stdin")
        if tuple(mode[:4]) not in _SUPPORTED_MODES:
            raise ValueError(f"unsupported combination of FinalRewardMode flags: {mode}")
        self.mode = mode
        self.factor = abs(check_finite_scalar(factor, "factor"))
        # the values paid on success and on failure when they depend on neither the state nor the time:
        # 0-d constants, so a step makes no Python-scalar tensor ops
        on_success = 0.0 if mode.always_negative else self.factor
        on_failure = 0.0 if mode.always_positive else -self.factor
        self.register_buffer("success_value", torch.tensor(on_success, dtype=torch.float64), persistent=False)
        self.register_buffer("failure_value", torch.tensor(on_failure, dtype=torch.float64), persistent=False)

    @property
    def uses_remaining_steps(self) -> bool:
        return self.mode.time_dependent or super().uses_remaining_steps

    kept_at_start = ("paid",)

    def _own_memory(self, init_state: torch.Tensor) -> dict[str, torch.Tensor]:
        return {"paid": torch.zeros(init_state.shape[:-1], dtype=torch.bool, device=init_state.device)}

    def _outcome_values(
        self, state: torch.Tensor, inner: TensorDictBase, remaining_steps: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Return the final reward on success and on failure (0-d constants, or ``[*B]`` when they vary).

        Magnitudes before the sign: ``k``, ``rem``, ``k·r_s`` or ``rem·r_s`` (see :class:`FinalRewardMode`).
        """
        mode = self.mode
        if not (mode.time_dependent or mode.state_dependent):
            return cast_like(self.success_value, state), cast_like(self.failure_value, state)
        if mode.time_dependent:
            magnitude: torch.Tensor | float = remaining_steps.to(state.dtype)
        else:
            magnitude = self.factor
        if mode.state_dependent:
            zero_action = state.new_zeros((*state.shape[:-1], self.action_size))
            step_value, _ = self.wrapped_task._step_reward(state, zero_action, inner, remaining_steps)
            magnitude = magnitude * step_value.abs()
        zero = state.new_zeros(())
        magnitude = zero + magnitude
        return (zero if mode.always_negative else magnitude), (zero if mode.always_positive else -magnitude)

    def _compute_final_reward(
        self,
        state: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        done: torch.Tensor,
        flags: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        inner = read(memory, "wrapped")
        if flags is None:
            flags = (self.wrapped_task._has_succeeded(state, inner), self.wrapped_task._has_failed(state, inner))
        succeeded, failed = flags
        on_success, on_failure = self._outcome_values(state, inner, remaining_steps)
        zero = torch.zeros((), dtype=state.dtype, device=state.device)
        value = torch.where(failed, on_failure, torch.where(succeeded, on_success, zero))
        paid = read(memory, "paid")
        # pay where the episode ends and nothing was paid yet (for bools, done > paid is done & ~paid)
        value = torch.where(done > paid, value, zero)
        return value, self._replace(memory, paid=paid | done)


class BestStateFinalRewardTask(TaskWrapper):
    """Pay ``factor`` times the best step reward of the episode as the final reward.

    Memory: the best step reward so far ``"best"`` (``-inf`` at reset; NaN never replaces it),
    ``"paid"``, and the wrapped task's memory. Paid once, where the episode ends, whatever the
    outcome (success, failure or time limit). An episode in which the wrapped task paid no step
    reward (its best is still ``-inf``, e.g. a sub-task of :class:`SequentialTasks` that never became
    current) pays 0: no reward is ever infinite. (Pyrado paid ``factor · -inf`` there.)

    Args:
        task: the wrapped task.
        factor: multiplier of the best reward (sign kept).

    Pyrado name: ``BestStateFinalRewTask``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import StateFunctionReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import BestStateFinalRewardTask, OptimizationTask
        >>> inner = OptimizationTask(EnvSpec(1, 1), StateFunctionReward(lambda s: s[..., 0]))
        >>> task = BestStateFinalRewardTask(inner, 2.0)
        >>> memory = task.reset(torch.zeros(1, 1))
        >>> for x in (3.0, 1.0, 2.0):
        ...     _, memory = task.step_reward(torch.tensor([[x]]), torch.zeros(1, 1), memory)
        >>> task.final_reward(torch.zeros(1, 1), memory, 0, torch.tensor([True]))[0]
        tensor([-2.])
    """

    def __init__(self, task: Task, factor: float) -> None:
        super().__init__(task)
        self.factor = check_finite_scalar(factor, "factor")

    kept_at_start = ("paid",)

    def _own_memory(self, init_state: torch.Tensor) -> dict[str, torch.Tensor]:
        batch = init_state.shape[:-1]
        return {
            "best": init_state.new_full(batch, float("-inf")),
            "paid": torch.zeros(batch, dtype=torch.bool, device=init_state.device),
        }

    def _after_step(self, reward: torch.Tensor, memory: TensorDictBase, inner: TensorDictBase) -> TensorDictBase:
        best = read(memory, "best")
        best = torch.where(reward > best, reward.to(best.dtype), best)
        return self._replace(memory, wrapped=inner, best=best)

    def _compute_final_reward(
        self,
        state: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        done: torch.Tensor,
        flags: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        paid = read(memory, "paid")
        best = read(memory, "best").to(state.dtype)
        zero = state.new_zeros(state.shape[:-1])
        # an episode in which the wrapped task paid no step reward (best still -inf, e.g. a later
        # sub-task of SequentialTasks that never became current) pays 0, never an infinite reward
        value = torch.where(done & ~paid & (best > float("-inf")), best * self.factor, zero)
        return value, self._replace(memory, paid=paid | done)
