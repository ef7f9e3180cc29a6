"""Small, general reward terms: velocity, displacement, control cost, healthy and contact terms, a threshold indicator.

Each term is one :class:`~torchtasks.rewards.RewardFunction` with one job, meant to be a named term
of a :class:`~torchtasks.rewards.CompoundReward` (as Gymnasium's MuJoCo locomotion envs log
``info["reward_forward" | "reward_ctrl" | "reward_contact" | "reward_survive"]``). Costs inside a
reward are returned as negative rewards. :class:`AboveThresholdIndicator` is the exception: it is a
constraint cost (Safety-Gymnasium's ``float(velocity > threshold)``), 1.0 where a state quantity
exceeds a threshold and 0.0 elsewhere, meant for a task's cost channel rather than its reward. All
terms are stateless, batched over any leading dims, follow the dtype and device of their inputs and
contain no Python branching on tensor values.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from torchtasks._checks import (
    as_constant,
    cast_like,
    check_finite_scalar,
    check_input,
    check_int,
    check_non_negative_int,
    check_pair,
    check_weight,
)
from torchtasks.rewards.base import (
    RewardFunction,
    check_ignored_action,
    entries,
    index_problem,
    row_scalar,
    squared_sum,
)

__all__ = [
    "AboveThresholdIndicator",
    "ContactCostReward",
    "ControlCostReward",
    "DisplacementReward",
    "HealthyReward",
    "VelocityReward",
]


def _check_state_entry(state: torch.Tensor, index: int, owner: str, name: str) -> None:
    """Raise unless ``index`` addresses an entry of ``state``'s last dimension (a shape check)."""
    size = state.shape[-1]
    if not -size <= index < size:
        raise ValueError(f"{owner}: index {index} is out of range for {name} of shape {tuple(state.shape)}")


class VelocityReward(RewardFunction):
    """A weighted velocity read from the state: ``weight · state[index]``.

    For envs whose state carries the velocity itself (e.g. Gymnasium's ``info["x_velocity"]``);
    use :class:`~torchtasks.rewards.ForwardVelocityReward` to finite-difference a position instead.
    Linear, hence differentiable; ignores the action.

    Args:
        weight: the finite factor ``w`` (Gymnasium's ``forward_reward_weight``).
        index: position of the velocity in the state's last dimension (negative counts from the end).

    Example:
        >>> import torch
        >>> from torchtasks.rewards.terms import VelocityReward
        >>> VelocityReward(weight=1.25, index=0)(torch.tensor([[2.0, 9.0], [-1.0, 9.0]]), None)
        tensor([ 2.5000, -1.2500])
    """

    uses_action = False

    def __init__(self, weight: float = 1.0, index: int = 0) -> None:
        super().__init__()
        self._register_scalar("weight", check_finite_scalar(weight, "weight"))
        self.index = check_int(index, "index")

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        return index_problem(who, "index", self.index, state_size)

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None = None) -> torch.Tensor:
        check_input(error_state, "error_state")
        _check_state_entry(error_state, self.index, type(self).__name__, "error_state")
        check_ignored_action(error_state, error_action)
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        return cast_like(self.weight, error_state) * error_state[..., self.index]

    def extra_repr(self) -> str:
        return f"weight={float(self.weight)}, index={self.index}"


class DisplacementReward(VelocityReward):
    """A weighted displacement of a state entry from a fixed origin: ``weight · (state[index] − origin)``.

    A :class:`VelocityReward` (a weighted state entry) measured from ``origin`` instead of 0.

    Computed in that order (the difference first, then the product), so that a value Gymnasium or
    MO-Gymnasium compute as ``weight * (qpos[1] - init_qpos[1])`` in float64 is reproduced bit for bit:
    MO-Gymnasium's Hopper height objective is ``DisplacementReward(10.0, index=<qpos[1]>,
    origin=init_qpos[1])``. Linear, hence differentiable; ignores the action.

    Args:
        weight: the finite factor ``w``.
        index: position of the entry in the state's last dimension (negative counts from the end).
        origin: the finite value the displacement is measured from.

    Example:
        >>> import torch
        >>> from torchtasks.rewards.terms import DisplacementReward
        >>> DisplacementReward(10.0, index=1, origin=1.25)(torch.tensor([[0.0, 1.5], [0.0, 1.0]]), None)
        tensor([ 2.5000, -2.5000])
    """

    def __init__(self, weight: float = 1.0, index: int = 0, origin: float = 0.0) -> None:
        super().__init__(weight, index)
        self._register_scalar("origin", check_finite_scalar(origin, "origin"))

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        displacement = error_state[..., self.index] - cast_like(self.origin, error_state)
        return cast_like(self.weight, error_state) * displacement

    def extra_repr(self) -> str:
        return f"{super().extra_repr()}, origin={float(self.origin)}"


class ControlCostReward(RewardFunction):
    """The negative quadratic control cost ``-weight · Σ_i a_i²`` of the action.

    Gymnasium's ``reward_ctrl`` of the MuJoCo locomotion envs. Ignores the state (only its batch
    shape is checked against the action's); differentiable in the action.

    Args:
        weight: the finite, non-negative factor ``w`` (Gymnasium's ``ctrl_cost_weight``).

    Example:
        >>> import torch
        >>> from torchtasks.rewards.terms import ControlCostReward
        >>> ControlCostReward(weight=0.1)(torch.zeros(2, 5), torch.tensor([[1.0, 2.0], [0.0, -1.0]]))
        tensor([-0.5000, -0.1000])
    """

    def __init__(self, weight: float = 0.1) -> None:
        super().__init__()
        self._register_scalar("weight", weight, check=check_weight)

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        self._check_inputs(error_state, error_action)
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        return -(cast_like(self.weight, error_action) * squared_sum(error_action))

    def extra_repr(self) -> str:
        return f"weight={float(self.weight)}"


class HealthyReward(RewardFunction):
    """A reward paid only while the state is healthy: ``healthy_reward · is_healthy(state)``.

    ``is_healthy`` holds when every selected entry ``state[index[k]]`` lies in its range
    ``(low[k], high[k])`` — strict bounds by default, inclusive with ``inclusive=True`` — and, with
    ``check_finite=True``, is finite (needed with inclusive infinite bounds, which ``±inf`` would
    pass). NaN is never healthy. With ``terminate_when_unhealthy`` the reward can fail:
    :meth:`has_failed` is ``~is_healthy`` and a :class:`~torchtasks.tasks.GoallessTask` ends the
    episode as a failure (Gymnasium's ``terminated``). The value is piecewise constant, so its
    gradient is zero almost everywhere.

    Args:
        healthy_reward: the finite reward per healthy step (Gymnasium's ``healthy_reward``).
        index: the state entries checked (a non-negative int or a non-empty sequence of distinct ones).
        low, high: the bounds of the checked entries, scalars or one per entry of ``index``
            (``±inf`` leaves a side unchecked); ``low <= high`` elementwise.
        inclusive: compare with ``<=`` instead of ``<``.
        check_finite: also require the selected entries to be finite.
        terminate_when_unhealthy: whether an unhealthy state is a failure.

    Example:
        >>> import torch
        >>> from torchtasks.rewards.terms import HealthyReward
        >>> reward = HealthyReward(5.0, index=[1], low=1.0, high=2.0, terminate_when_unhealthy=True)
        >>> state = torch.tensor([[0.0, 1.4], [0.0, 0.9], [0.0, 2.0]])
        >>> reward(state, None), reward.has_failed(state)
        (tensor([5., 0., 0.]), tensor([False,  True,  True]))
    """

    uses_action = False

    def __init__(
        self,
        healthy_reward: float = 1.0,
        *,
        index: int | Sequence[int],
        low: float | Sequence[float] = -math.inf,
        high: float | Sequence[float] = math.inf,
        inclusive: bool = False,
        check_finite: bool = False,
        terminate_when_unhealthy: bool = False,
    ) -> None:
        super().__init__()
        self._register_scalar("healthy_reward", check_finite_scalar(healthy_reward, "healthy_reward"))
        if isinstance(index, (str, bytes)) or not isinstance(index, Sequence):
            indices = [check_non_negative_int(index, "index")]
        else:
            indices = [check_non_negative_int(i, f"index[{n}]") for n, i in enumerate(index)]
        if not indices:
            raise ValueError("index must select at least one state entry, got an empty sequence")
        if len(set(indices)) != len(indices):
            raise ValueError(f"index must not contain duplicates, got {indices}")
        bounds = []
        for name, value in (("low", low), ("high", high)):
            bound = as_constant(value, name, ndim=(0, 1))
            if bound.ndim == 1 and bound.numel() != len(indices):
                raise ValueError(
                    f"{name} must be a scalar or have {len(indices)} entries (one per index), got {bound.numel()}"
                )
            bounds.append(bound.expand(len(indices)).clone())
        if (bounds[0] > bounds[1]).any():
            raise ValueError(
                f"low must be <= high elementwise, got low={bounds[0].tolist()}, high={bounds[1].tolist()}"
            )
        for name, flag in (
            ("inclusive", inclusive),
            ("check_finite", check_finite),
            ("terminate_when_unhealthy", terminate_when_unhealthy),
        ):
            if not isinstance(flag, bool):
                raise TypeError(f"{name} must be a bool, got {flag!r}")
        self.register_buffer("index", torch.tensor(indices, dtype=torch.long))
        self.register_buffer("low", bounds[0])
        self.register_buffer("high", bounds[1])
        self._min_size = max(indices) + 1
        self.inclusive = inclusive
        self.check_finite = check_finite
        self.terminate_when_unhealthy = terminate_when_unhealthy
        self.can_fail = terminate_when_unhealthy

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        if state_size >= self._min_size:
            return None
        return f"{who} reads state entries index={self.index.tolist()}, but the task's state has {entries(state_size)}"

    def _check_state(self, state: torch.Tensor, name: str) -> None:
        check_input(state, name)
        if state.shape[-1] < self._min_size:
            raise ValueError(
                f"HealthyReward: index {self.index.tolist()} is out of range for {name} of shape {tuple(state.shape)}"
            )

    def is_healthy(self, state: torch.Tensor) -> torch.Tensor:
        """Return ``bool[*B]``: whether every selected entry of ``state`` is in its range."""
        self._check_state(state, "state")
        return self._is_healthy(state)

    def _is_healthy(self, state: torch.Tensor) -> torch.Tensor:
        index = self.index if self.index.device == state.device else self.index.to(state.device)
        selected = state.index_select(-1, index)
        low = cast_like(self.low, selected)
        high = cast_like(self.high, selected)
        if self.inclusive:
            healthy = ((selected >= low) & (selected <= high)).all(dim=-1)
        else:
            healthy = ((selected > low) & (selected < high)).all(dim=-1)
        if self.check_finite:
            healthy = healthy & torch.isfinite(selected).all(dim=-1)
        return healthy

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None = None) -> torch.Tensor:
        self._check_state(error_state, "error_state")
        check_ignored_action(error_state, error_action)
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        healthy = self._is_healthy(error_state)
        return cast_like(self.healthy_reward, error_state) * healthy.to(error_state.dtype)

    def has_failed(self, state: torch.Tensor) -> torch.Tensor:
        if not self.terminate_when_unhealthy:
            return super().has_failed(state)
        return ~self.is_healthy(state)

    def extra_repr(self) -> str:
        return (
            f"healthy_reward={float(self.healthy_reward)}, index={self.index.tolist()}, "
            f"inclusive={self.inclusive}, check_finite={self.check_finite}, "
            f"terminate_when_unhealthy={self.terminate_when_unhealthy}"
        )


class ContactCostReward(RewardFunction):
    """The negative contact cost ``-clip(weight · Σ_i clip(f_i, *force_range)², *cost_range)``.

    ``f = state[..., start:stop]`` are external contact forces (e.g. MuJoCo's flattened
    ``cfrc_ext``). Each force is clipped to ``force_range`` before squaring (Gymnasium's Ant) and
    the weighted sum is clipped to ``cost_range`` (Gymnasium's Humanoid); infinite bounds disable
    a clip. Differentiable in the forces wherever no clip is active.

    Args:
        weight: the finite, non-negative factor ``w`` (Gymnasium's ``contact_cost_weight``).
        start, stop: the slice of the state holding the forces (``stop=None``: to the end).
        force_range: ``(low, high)`` each force is clipped to.
        cost_range: ``(low, high)`` the weighted cost is clipped to.

    Example:
        >>> import torch
        >>> from torchtasks.rewards.terms import ContactCostReward
        >>> forces = torch.tensor([[0.0, 3.0, -0.5]])
        >>> ContactCostReward(0.5, start=1, force_range=(-1.0, 1.0))(forces, None)
        tensor([-0.6250])
        >>> ContactCostReward(0.5, start=1, cost_range=(float("-inf"), 2.0))(forces, None)
        tensor([-2.])
    """

    uses_action = False

    def __init__(
        self,
        weight: float = 5e-4,
        *,
        start: int = 0,
        stop: int | None = None,
        force_range: tuple[float, float] = (-math.inf, math.inf),
        cost_range: tuple[float, float] = (-math.inf, math.inf),
    ) -> None:
        super().__init__()
        self._register_scalar("weight", weight, check=check_weight)
        self.start = check_int(start, "start")
        self.stop = None if stop is None else check_int(stop, "stop")
        if self.start < 0 or (self.stop is not None and self.stop <= self.start):
            raise ValueError(f"start and stop must satisfy 0 <= start < stop, got start={start}, stop={stop}")
        force_low, force_high = check_pair(force_range, "force_range")
        cost_low, cost_high = check_pair(cost_range, "cost_range")
        self._register_scalar("force_low", force_low)
        self._register_scalar("force_high", force_high)
        self._register_scalar("cost_low", cost_low)
        self._register_scalar("cost_high", cost_high)

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        end = state_size if self.stop is None else self.stop
        if self.start < state_size and end <= state_size:
            return None
        return (
            f"{who} reads the state slice start={self.start}, stop={self.stop}, "
            f"but the task's state has {entries(state_size)}"
        )

    def _check_state(self, state: torch.Tensor, name: str) -> None:
        check_input(state, name)
        end = state.shape[-1] if self.stop is None else self.stop
        if end > state.shape[-1] or self.start >= state.shape[-1]:
            raise ValueError(
                f"ContactCostReward: the slice [{self.start}:{self.stop}] is beyond {name} of shape "
                f"{tuple(state.shape)}"
            )

    def contact_forces(self, state: torch.Tensor) -> torch.Tensor:
        """Return the unclipped forces ``state[..., start:stop]`` (``[*B, n_forces]``)."""
        self._check_state(state, "state")
        return state[..., self.start : self.stop]

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None = None) -> torch.Tensor:
        self._check_state(error_state, "error_state")
        check_ignored_action(error_state, error_action)
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        forces = error_state[..., self.start : self.stop]
        forces = forces.clamp(row_scalar(self.force_low, forces), row_scalar(self.force_high, forces))
        cost = cast_like(self.weight, forces) * squared_sum(forces)
        return -cost.clamp(cast_like(self.cost_low, cost), cast_like(self.cost_high, cost))

    def extra_repr(self) -> str:
        return (
            f"weight={float(self.weight)}, start={self.start}, stop={self.stop}, "
            f"force_range=({float(self.force_low)}, {float(self.force_high)}), "
            f"cost_range=({float(self.cost_low)}, {float(self.cost_high)})"
        )


class AboveThresholdIndicator(RewardFunction):
    """1.0 where a state quantity is above a threshold, else 0.0: ``float(v(state) > threshold)``.

    The quantity ``v`` is one signed state entry, ``state[..., index]`` (``norm=False``, the
    default), or the Euclidean norm of several entries, ``sqrt(Σ_k state[..., index[k]]²)``
    (``norm=True``). This is Safety-Gymnasium's velocity cost ``cost = float(velocity >
    threshold)``: the signed x velocity for Hopper, HalfCheetah, Walker2d and Swimmer, the planar
    speed ``sqrt(x_velocity² + y_velocity²)`` for Ant and Humanoid
    (``safety_gymnasium/tasks/safe_velocity/safety_*_velocity_v0.py``; the ``_v1`` files change the
    thresholds and, for Swimmer, the quantity). The comparison is strict (a value equal to the
    threshold costs 0) and a NaN value costs 0, as in Python's ``float(nan > threshold)``.

    It is a cost, not a reward: the value is non-negative, meant for a constraint of a task's cost
    channel (not to be added to a reward with a positive weight). The output has the state's
    floating dtype and is piecewise constant: its gradient is zero (it is built from a comparison,
    so it carries no autograd graph). Ignores the action.

    Args:
        threshold: the finite threshold the quantity must exceed to cost 1.
        index: the entry read (an int, negative counts from the end), or with ``norm=True`` an int or
            a non-empty sequence of distinct non-negative ints: the entries whose norm is taken.
        norm: take the Euclidean norm of the selected entries instead of one signed entry (with a
            single index that is its absolute value).

    Example:
        >>> import torch
        >>> from torchtasks.rewards.terms import AboveThresholdIndicator
        >>> state = torch.tensor([[1.0, 0.0], [3.0, 0.0], [-3.0, 0.0], [1.5, 2.0]])
        >>> AboveThresholdIndicator(2.0, index=0)(state, None)
        tensor([0., 1., 0., 0.])
        >>> AboveThresholdIndicator(2.0, index=[0, 1], norm=True)(state, None)
        tensor([0., 1., 1., 1.])
    """

    uses_action = False

    def __init__(self, threshold: float, index: int | Sequence[int] = 0, *, norm: bool = False) -> None:
        super().__init__()
        if not isinstance(norm, bool):
            raise TypeError(f"norm must be a bool, got {norm!r}")
        self._register_scalar("threshold", check_finite_scalar(threshold, "threshold"))
        self.norm = norm
        if isinstance(index, (str, bytes)) or not isinstance(index, Sequence):
            self.index: int | list[int] = check_int(index, "index")
            if norm and self.index < 0:
                raise ValueError(f"index must be non-negative with norm=True, got {index!r}")
            indices = [self.index]
        else:
            if not norm:
                raise TypeError(
                    f"index must be one int without norm=True (the signed entry compared), got the sequence {index!r}"
                )
            indices = [check_non_negative_int(i, f"index[{n}]") for n, i in enumerate(index)]
            if not indices:
                raise ValueError("index must select at least one state entry, got an empty sequence")
            if len(set(indices)) != len(indices):
                raise ValueError(f"index must not contain duplicates, got {indices}")
            self.index = indices
        self.register_buffer("_indices", torch.tensor(indices, dtype=torch.long), persistent=False)

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        if isinstance(self.index, int):
            return index_problem(who, "index", self.index, state_size)
        if max(self.index) < state_size:
            return None
        return f"{who} reads state entries index={self.index}, but the task's state has {entries(state_size)}"

    def _check_state(self, state: torch.Tensor, name: str) -> None:
        check_input(state, name)
        if self._size_problem(state.shape[-1], None, "") is not None:
            raise ValueError(
                f"AboveThresholdIndicator: index {self.index} is out of range for {name} of shape {tuple(state.shape)}"
            )

    def value(self, state: torch.Tensor) -> torch.Tensor:
        """Return the compared quantity ``v(state)`` (``[*B]``): the signed entry or the norm of the entries."""
        self._check_state(state, "state")
        return self._quantity(state)

    def _quantity(self, state: torch.Tensor) -> torch.Tensor:
        if not self.norm:
            return state[..., self.index]
        indices = self._indices if self._indices.device == state.device else self._indices.to(state.device)
        return squared_sum(state.index_select(-1, indices)).sqrt()

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None = None) -> torch.Tensor:
        self._check_state(error_state, "error_state")
        check_ignored_action(error_state, error_action)
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        quantity = self._quantity(error_state)
        return (quantity > cast_like(self.threshold, quantity)).to(error_state.dtype)

    def extra_repr(self) -> str:
        return f"threshold={float(self.threshold)}, index={self.index}, norm={self.norm}"
