"""The reward-function protocol: stateless calls and the functional memory protocol."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import torch
from tensordict import TensorDict
from torch import nn

from torchtasks._checked_load import CheckedLoad
from torchtasks._checks import as_constant, cast_like, check_input, check_same_batch

#: ``check(value, name) -> value``: a constant's validation, at construction and for every value written later
ConstantCheck = Callable[[Any, str], Any]

__all__ = ["RewardFunction", "empty_memory", "sum_terms"]


def entries(count: int) -> str:
    """``"1 entry"``, ``"3 entries"``: a size as the task-size messages spell it."""
    return f"{count} {'entry' if count == 1 else 'entries'}"


def index_problem(who: str, name: str, index: int, state_size: int) -> str | None:
    """Why ``state[..., index]`` cannot be read from a state of ``state_size`` entries (``None`` if it can)."""
    if -state_size <= index < state_size:
        return None
    return f"{who} reads state entry {name}={index}, but the task's state has {entries(state_size)}"


def sum_terms(values: Mapping[str, torch.Tensor]) -> torch.Tensor:
    """Sum named reward terms left to right (the order Pyrado adds them in)."""
    iterator = iter(values.values())
    total = next(iterator)
    for value in iterator:
        total = total + value
    return total


def row_sum(x: torch.Tensor) -> torch.Tensor:
    """Return ``x.sum(-1)`` summed in the same order for every row, whatever the batch shape or memory layout.

    A row's sum then has the same rounding in a batch of one env, of 4096 envs or of offline data ``[T, B, n]``
    (what makes offline recomputation equal the online step bit for bit). A matrix-vector product does not
    guarantee that: MKL's AVX-512 kernels round a row differently with the number of rows; nor does an ATen
    reduction over a last dim that is not contiguous. So the last dim is made contiguous (free when it is).

    Example:
        >>> import torch
        >>> x = torch.rand(100, 7, dtype=torch.float64)
        >>> torch.equal(row_sum(x)[3:4], row_sum(x[3:4])), torch.equal(row_sum(x.t().contiguous().t()), row_sum(x))
        (True, True)
    """
    return x.contiguous().sum(-1)


def squared_sum(x: torch.Tensor) -> torch.Tensor:
    """Return ``(x * x).sum(-1)``, summed as :func:`row_sum` does.

    Example:
        >>> import torch
        >>> squared_sum(torch.tensor([[1.0, 2.0], [3.0, 0.0]]))
        tensor([5., 9.])
    """
    return row_sum(x * x)


def row_dot(x: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Return ``Σ_i x_i w_i`` per row of ``x`` (``[*B, n]``), for weights shared by all rows (``[n]``) or one row of
    weights per row of ``x`` (``[*B, n]``: per-frame values, as offline recomputation swaps them in).

    Both sum as :func:`row_sum` does, so a row gets the same sum (the same rounding) either way.

    Example:
        >>> import torch
        >>> x = torch.tensor([[1.0, 2.0], [3.0, 0.0]])
        >>> row_dot(x, torch.tensor([1.0, 0.5])), row_dot(x, torch.tensor([[1.0, 0.5], [2.0, 0.0]]))
        (tensor([2., 3.]), tensor([2., 6.]))
    """
    return row_sum(x * weight)


def row_scalar(constant: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """A scalar constant ready for an elementwise op with ``like`` (``[*B, k]``), in ``like``'s dtype and device.

    A 0-d constant is returned as it is; one value per row (``[*B]``: a per-frame value swapped in by offline
    recomputation, or a per-env value of difficulty levels) becomes ``[*B, 1]``, so it meets its own row.

    Example:
        >>> import torch
        >>> forces = torch.tensor([[3.0, -3.0], [3.0, -3.0]])
        >>> forces.clamp(max=row_scalar(torch.tensor([1.0, 2.0]), forces))
        tensor([[ 1., -3.],
                [ 2., -3.]])
    """
    constant = cast_like(constant, like)
    return constant if constant.ndim == 0 else constant.unsqueeze(-1)


def check_ignored_action(error_state: torch.Tensor, error_action: object, state_name: str = "error_state") -> None:
    """Check an action a reward ignores: ``None``, or a floating tensor of the state's batch (any size)."""
    if error_action is not None:
        check_input(error_action, "error_action")
        check_same_batch(error_state, error_action, state_name, "error_action")


def check_reward_memory(memory: object, state: torch.Tensor, key: str, owner: str) -> None:
    """Check a stateful reward's memory: the TensorDict ``owner.reset`` returns (holding ``key``), of the state's batch.

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> memory = TensorDict({"x_last": torch.zeros(2)}, batch_size=[2])
        >>> check_reward_memory(memory, torch.zeros(2, 3), "x_last", "MyReward")
        >>> check_reward_memory(memory, torch.zeros(4, 3), "x_last", "MyReward")
        Traceback (most recent call last):
        ...
        ValueError: memory has batch size (2,) but the state has batch shape (4,)
    """
    if not isinstance(memory, TensorDict) or key not in memory.keys():
        raise TypeError(f"memory must be the TensorDict returned by {owner}.reset(init_state)")
    if memory.batch_size != state.shape[:-1]:
        raise ValueError(
            f"memory has batch size {tuple(memory.batch_size)} but the state has batch shape {tuple(state.shape[:-1])}"
        )


def empty_memory(reference: torch.Tensor) -> TensorDict:
    """Return an empty memory TensorDict whose batch size is ``reference.shape[:-1]``."""
    return TensorDict({}, batch_size=reference.shape[:-1])


def check_written_value(module: RewardFunction, name: str, value: torch.Tensor, writer: str) -> None:
    """Raise ``ValueError`` naming ``writer`` unless ``module`` accepts ``value`` for its constant ``name``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import QuadraticErrorReward
        >>> try:
        ...     check_written_value(QuadraticErrorReward([1.0]), "Q", torch.tensor([-1.0]), "a schedule")
        ... except ValueError as error:
        ...     print(str(error).split(": ")[0])
        a schedule can write [-1.0] into the QuadraticErrorReward's Q, which it refuses
    """
    try:
        module.check_constant(name, value)
    except (TypeError, ValueError) as error:
        raise ValueError(
            f"{writer} can write {value.tolist()} into the {type(module).__name__}'s {name}, which it refuses: {error}"
        ) from None


class RewardFunction(CheckedLoad, nn.Module):
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

    Tasks check at construction that a reward fits their state and action sizes with
    :meth:`check_sizes`; a reward with size-carrying constants (weights of a given length, state
    indices) says what it needs by overriding :meth:`_size_problem`, and containers (such as
    :class:`~torchtasks.rewards.CompoundReward`) forward the check to their terms.

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

    def check_sizes(self, state_size: int, action_size: int | None) -> None:
        """Raise ``ValueError`` unless the reward can read states of ``state_size`` entries and actions
        of ``action_size`` entries (``None``: no action is passed).

        Tasks call it once at construction, so the step path needs no size checks. Rewards whose
        needs cannot be known (a :class:`~torchtasks.rewards.StateFunctionReward`) accept any size.

        Example:
            >>> from torchtasks.rewards import CompoundReward, QuadraticErrorReward
            >>> CompoundReward({"track": QuadraticErrorReward([1.0], None)}).check_sizes(2, 1)
            Traceback (most recent call last):
            ...
            ValueError: reward CompoundReward: term 'track' (QuadraticErrorReward) expects states of size 1, \
but the task's state has 2 entries
        """
        problem = self._size_problem(state_size, action_size, f"reward {type(self).__name__}")
        if problem is not None:
            raise ValueError(problem)

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        """Return why the reward cannot read inputs of these sizes, as a sentence about ``who``; ``None`` if it can.

        The default compares ``state_size``/``action_size`` attributes when a reward has them (the
        error rewards: the sizes of their weights); rewards that index into the state override it.
        """
        expected_state = getattr(self, "state_size", None)
        if expected_state is not None and expected_state != state_size:
            return f"{who} expects states of size {expected_state}, but the task's state has {entries(state_size)}"
        expected_action = getattr(self, "action_size", None)
        if self.uses_action and action_size is not None and expected_action is not None:
            if expected_action != action_size:
                return (
                    f"{who} expects actions of size {expected_action}, but the task's action has {entries(action_size)}"
                )
        return None

    def combine_terms(self, values: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """The reward from its named terms (:attr:`term_names`): their sum, left to right, by default.

        A :class:`~torchtasks.rewards.ProductReward` multiplies its factors instead. Tasks call it to
        turn the breakdown they log into the step reward, so both always agree.
        """
        return sum_terms(values)

    def _register_constant(
        self, name: str, value: object, learnable: bool = False, check: ConstantCheck | None = None
    ) -> None:
        """Register ``value`` as a buffer, or as a parameter when ``learnable``.

        ``check(value, name)`` validates the value and returns it as a tensor; it is kept, so that a value
        written later (a Curriculum's schedule, a level's row) is checked by the same rule
        (:meth:`check_constant`).
        """
        if check is not None:
            value = check(value, name)
            self.__dict__.setdefault("_constant_checks", {})[name] = check
        if learnable:
            self.register_parameter(name, nn.Parameter(value))
        else:
            self.register_buffer(name, value)

    def _register_scalar(
        self, name: str, value: object, learnable: bool = False, check: ConstantCheck | None = None
    ) -> None:
        """Register a 0-d float64 constant (0-d tensors keep the input dtype in arithmetic); ``check`` as for
        :meth:`_register_constant` (e.g. :func:`~torchtasks._checks.check_weight`)."""
        if check is not None:
            self.__dict__.setdefault("_constant_checks", {})[name] = check
            value = check(value, name)
        self._register_constant(name, as_constant(value, name, ndim=(0,)), learnable)

    def check_constant(self, name: str, value: torch.Tensor) -> None:
        """Raise ``ValueError``/``TypeError`` unless ``value`` is one the constructor accepts for the constant ``name``.

        Curricula and difficulty levels call it for every value they may write into the constant.

        Example:
            >>> import torch
            >>> from torchtasks.rewards import QuadraticErrorReward
            >>> reward = QuadraticErrorReward([1.0, 1.0])
            >>> reward.check_constant("Q", torch.tensor([2.0, 0.5]))
            >>> try:
            ...     reward.check_constant("Q", torch.tensor([-1.0, 0.5]))
            ... except ValueError as error:
            ...     print(error)
            Q (a diagonal) must be non-negative, got [-1.0, 0.5]
        """
        check = self.__dict__.get("_constant_checks", {}).get(name)
        if check is not None:
            check(value, name)

    def _check_loaded(self) -> None:
        """A loaded constant passes the rule its constructor ran (a checkpoint's negative cost weight is refused).

        Learnable constants (parameters) are not checked: training may move them anywhere.
        """
        for name in self.__dict__.get("_constant_checks", {}):
            if name in self._buffers:
                check_written_value(self, name, self._buffers[name], f"{type(self).__name__}.load_state_dict")

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
            check_ignored_action(error_state, error_action)
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
        check_input(init_state, "init_state")
        return empty_memory(init_state)

    def step(
        self, state: torch.Tensor, action: torch.Tensor | None, memory: TensorDict
    ) -> tuple[torch.Tensor, TensorDict]:
        """Return ``(value[*B], memory)`` for one step; stateless rewards pass memory through."""
        return self(state, action), memory

    def has_failed(self, state: torch.Tensor) -> torch.Tensor:
        """Return ``bool[*B]``: whether the state ends the episode as a failure (never, by default)."""
        return torch.zeros(state.shape[:-1], dtype=torch.bool, device=state.device)
