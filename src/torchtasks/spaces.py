"""Boxes of states and actions: bounds, labels and per-environment membership.

A :class:`Box` is the torchtasks counterpart of Pyrado's ``BoxSpace``: a one-dimensional box
``low <= x <= high`` with optional labels. Its bounds are float64 tensors (infinite bounds are
fine) and :meth:`Box.contains` answers per environment of a batch. :class:`EnvSpec` pairs a state
box with an action box; tasks read their bounds from it.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Iterable, Sequence

import torch

from torchtasks._checks import check_non_negative_int, check_real_numbers

__all__ = [
    "Box",
    "EnvSpec",
    "rows_outside",
]

Index = int | str


def _as_bound(value: object, name: str) -> torch.Tensor:
    """Return ``value`` as a 1-D float64 tensor, rejecting NaN."""
    check_real_numbers(value, name)
    try:
        tensor = torch.as_tensor(value, dtype=torch.float64).detach().clone()
    except (TypeError, ValueError, RuntimeError) as error:
        raise TypeError(
            f"{name} must be a number or a 1-D sequence of numbers, got {value!r} of type {type(value).__name__}"
        ) from error
    if tensor.ndim == 0:
        tensor = tensor.reshape(1)
    if tensor.ndim != 1:
        raise ValueError(f"{name} must be a scalar or a 1-D sequence, got shape {tuple(tensor.shape)}")
    if torch.isnan(tensor).any():
        raise ValueError(f"{name} must not contain NaN, got {tensor.tolist()}")
    return tensor


def rows_outside(x: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> torch.Tensor:
    """Return ``bool[*B]``: whether a row of ``x`` (``[*B, n]``) leaves ``[low, high]`` or holds a NaN.

    Bounds are inclusive (an infinite entry inside an infinite bound is inside). One clamp, one
    comparison and a count: about twice as fast on the CPU as ``~((x >= low) & (x <= high)).all(-1)``
    (bool reductions over a short last dim are slow), and NaN needs no separate check (``NaN != NaN``).

    Example:
        >>> import torch
        >>> rows_outside(torch.tensor([[0.5, 0.0], [2.0, 0.0], [float("nan"), 0.0]]),
        ...              torch.tensor([-1.0, -1.0]), torch.tensor([1.0, 1.0]))
        tensor([False,  True,  True])
    """
    if low.shape[-1:] != x.shape[-1:] or high.shape[-1:] != x.shape[-1:]:  # static shapes: no broadcast of a bound
        raise ValueError(
            f"low and high must have the {x.shape[-1]} entries of x's rows, got shapes {list(low.shape)} and "
            f"{list(high.shape)} for x of shape {list(x.shape)}"
        )
    return torch.clamp(x, low, high).ne(x).count_nonzero(dim=-1) != 0


def _is_scalar_array(value: object) -> bool:
    """Whether ``value`` is a 0-d tensor or array (iterable in type, but not in fact)."""
    return getattr(value, "ndim", None) == 0


def _as_position(item: object) -> int:
    """Return an integer index (int, NumPy integer, 0-d integer tensor or array); refuse bools and floats."""
    dtype = getattr(item, "dtype", None)
    if isinstance(item, bool) or (dtype is not None and str(dtype) in ("bool", "torch.bool")):
        raise TypeError(f"indices must be ints or labels, got the bool {item!r}")
    if isinstance(item, torch.Tensor) and item.ndim != 0:
        raise TypeError(f"indices must be ints or labels, got a tensor of shape {tuple(item.shape)}")
    try:
        return operator.index(item)  # type: ignore[arg-type]
    except TypeError:
        raise TypeError(f"indices must be ints or labels, got {item!r} of type {type(item).__name__}") from None


class Box:
    """A 1-D box of states or actions, ``low <= x <= high`` elementwise, with optional labels.

    Args:
        low: lower bounds, a scalar or a sequence of ``n`` numbers (``-inf`` allowed).
        high: upper bounds, same length as ``low`` (``inf`` allowed); a scalar broadcasts to the
            length of ``low`` and vice versa only when one of them is a scalar.
        labels: optional names of the ``n`` entries, used to select entries by name.

    Pyrado name: ``BoxSpace``.

    Example:
        >>> import torch
        >>> from torchtasks.spaces import Box
        >>> box = Box([-1.0, 0.0], [1.0, float("inf")], labels=["x", "v"])
        >>> box.contains(torch.tensor([[0.5, 3.0], [2.0, 0.0]]))
        tensor([ True, False])
        >>> box.select(["v"]).high
        tensor([inf], dtype=torch.float64)
    """

    def __init__(
        self,
        low: object,
        high: object,
        labels: Sequence[str] | None = None,
    ) -> None:
        low_t = _as_bound(low, "low")
        high_t = _as_bound(high, "high")
        if low_t.numel() == 1 and high_t.numel() > 1:
            low_t = low_t.expand_as(high_t).clone()
        elif high_t.numel() == 1 and low_t.numel() > 1:
            high_t = high_t.expand_as(low_t).clone()
        if low_t.shape != high_t.shape:
            raise ValueError(f"low and high must have the same length, got {low_t.numel()} and {high_t.numel()}")
        if (low_t > high_t).any():
            raise ValueError(f"low must be <= high elementwise, got low={low_t.tolist()}, high={high_t.tolist()}")
        self.low = low_t
        self.high = high_t
        if labels is not None:
            if isinstance(labels, str):  # tuple("xv") would be ("x", "v")
                raise TypeError(f"labels must be a sequence of strings (one per dimension), got the string {labels!r}")
            labels = tuple(labels)
            if len(labels) != low_t.numel():
                raise ValueError(f"labels must have {low_t.numel()} entries (one per dimension), got {len(labels)}")
            if not all(isinstance(label, str) for label in labels):
                raise TypeError(f"labels must be strings, got {labels!r}")
            if len(set(labels)) != len(labels):
                duplicates = sorted({label for label in labels if labels.count(label) > 1})
                raise ValueError(f"labels must be distinct, got {list(labels)} (repeated: {duplicates})")
        self.labels: tuple[str, ...] | None = labels

    @classmethod
    def unbounded(cls, size: int, labels: Sequence[str] | None = None) -> Box:
        """Return a box of ``size`` entries with infinite bounds (only NaN is outside).

        Example:
            >>> Box.unbounded(2).bound_abs_high
            tensor([inf, inf], dtype=torch.float64)
        """
        size = check_non_negative_int(size, "size")
        return cls(torch.full((size,), -math.inf), torch.full((size,), math.inf), labels=labels)

    @classmethod
    def from_spec(cls, spec: object, labels: Sequence[str] | None = None) -> Box:
        """Build a box from a TorchRL tensor spec (``Bounded``, ``Unbounded`` or any spec with a shape).

        Bounded specs give their bounds; other specs give infinite bounds. The last dimension of the
        spec's shape is the box size (leading batch dimensions of the spec are dropped when every
        row has the same bounds).

        Example:
            >>> from torchrl.data import Bounded
            >>> Box.from_spec(Bounded(low=-2.0, high=2.0, shape=(3,))).high
            tensor([2., 2., 2.], dtype=torch.float64)
        """
        shape = getattr(spec, "shape", None)
        if shape is None or len(shape) == 0:
            raise ValueError(f"spec must have at least one dimension, got {spec!r}")
        size = int(shape[-1])
        space = getattr(spec, "space", None)
        low = getattr(space, "low", None)
        high = getattr(space, "high", None)
        if low is None or high is None or type(spec).__name__.startswith("Unbounded"):
            return cls.unbounded(size, labels=labels)
        dtype_max = torch.finfo(low.dtype).max if low.is_floating_point() else torch.iinfo(low.dtype).max
        low = torch.as_tensor(low, dtype=torch.float64).reshape(-1, size)
        high = torch.as_tensor(high, dtype=torch.float64).reshape(-1, size)
        # TorchRL stores "no bound" as the dtype's extreme values
        low = torch.where(low <= -dtype_max, -math.inf, low)
        high = torch.where(high >= dtype_max, math.inf, high)
        if not (low == low[0]).all() or not (high == high[0]).all():
            raise ValueError("spec has different bounds per batch row; build one Box per row instead")
        return cls(low[0], high[0], labels=labels)

    @property
    def size(self) -> int:
        """Number of entries of the box."""
        return int(self.low.numel())

    @property
    def shape(self) -> torch.Size:
        """Shape of one element of the box, ``(size,)``."""
        return self.low.shape

    @property
    def bound_abs_high(self) -> torch.Tensor:
        """Largest absolute value per entry, ``max(|low|, |high|)`` (Pyrado's ``bound_abs_up``)."""
        return torch.maximum(self.low.abs(), self.high.abs())

    @property
    def is_bounded(self) -> bool:
        """Whether any bound is finite (an all-infinite box only rejects NaN)."""
        return bool(torch.isfinite(self.low).any() or torch.isfinite(self.high).any())

    def contains(self, x: torch.Tensor) -> torch.Tensor:
        """Return ``bool[*B]``: whether each row of ``x`` (``[*B, size]``) lies in the box.

        Bounds are inclusive and a row with a NaN entry is never inside.
        """
        if not isinstance(x, torch.Tensor):
            raise TypeError(f"x must be a torch.Tensor, got {type(x).__name__}")
        if x.ndim == 0 or x.shape[-1] != self.size:
            raise ValueError(f"x must have shape [*B, {self.size}], got {tuple(x.shape)}")
        low = self.low.to(device=x.device, dtype=x.dtype if x.is_floating_point() else torch.float64)
        high = self.high.to(device=low.device, dtype=low.dtype)
        return ~rows_outside(x, low, high)

    def indices(self, selection: Index | Iterable[Index]) -> list[int]:
        """Resolve ints and labels to a list of integer positions, in the order given.

        Integers may be Python ints, NumPy integers or 0-d integer tensors; bools and floats are
        refused (``TypeError``). Raises ``ValueError`` for unknown labels, out-of-range ints and
        duplicates.

        Example:
            >>> Box([0, 0, 0], [1, 1, 1], labels=["a", "b", "c"]).indices(["c", 0])
            [2, 0]
        """
        if isinstance(selection, str) or not isinstance(selection, Iterable) or _is_scalar_array(selection):
            selection = [selection]
        result: list[int] = []
        for item in selection:
            if isinstance(item, str):
                if self.labels is None:
                    raise ValueError(f"cannot select label {item!r}: the box has no labels")
                if item not in self.labels:
                    raise ValueError(f"unknown label {item!r}; the box has labels {list(self.labels)}")
                position = self.labels.index(item)
            else:
                position = _as_position(item)
                if not -self.size <= position < self.size:
                    raise ValueError(f"index {position} is out of range for a box of size {self.size}")
                position %= self.size
            if position in result:
                raise ValueError(f"duplicate entry {item!r} (position {position}) in the selection")
            result.append(position)
        return result

    def select(self, selection: Index | Iterable[Index]) -> Box:
        """Return the sub-box of the selected entries (ints or labels), in the order given."""
        positions = self.indices(selection)
        index = torch.tensor(positions, dtype=torch.long)
        labels = None if self.labels is None else [self.labels[i] for i in positions]
        return Box(self.low[index], self.high[index], labels=labels)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Box):
            return NotImplemented
        return (
            self.low.shape == other.low.shape
            and bool(torch.equal(self.low, other.low) and torch.equal(self.high, other.high))
            and self.labels == other.labels
        )

    def __hash__(self) -> int:
        return hash((tuple(self.low.tolist()), tuple(self.high.tolist()), self.labels))

    def __repr__(self) -> str:
        labels = "" if self.labels is None else f", labels={list(self.labels)}"
        return f"Box(low={self.low.tolist()}, high={self.high.tolist()}{labels})"


def _as_box(value: Box | int, name: str) -> Box:
    if isinstance(value, Box):
        return value
    try:
        size = check_non_negative_int(value, name)
    except TypeError:
        raise TypeError(f"{name} must be a Box or an int size, got {value!r} of type {type(value).__name__}") from None
    return Box.unbounded(size)


class EnvSpec:
    """The state and action boxes of an environment, as seen by a task.

    Args:
        state_space: box of the task's state (failure = leaving it); an int ``n`` means an
            unbounded box of ``n`` entries.
        action_space: box of the actions; an int ``m`` means an unbounded box of ``m`` entries.

    Pyrado name: ``EnvSpec`` (whose default state space was the ``EmptySpace`` class; here an
    int size gives an unbounded box).

    Example:
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> spec = EnvSpec(state_space=3, action_space=Box([-1.0], [1.0]))
        >>> spec.state_space.is_bounded, spec.action_space.size
        (False, 1)
    """

    __slots__ = ("action_space", "state_space")

    def __init__(self, state_space: Box | int, action_space: Box | int) -> None:
        self.state_space = _as_box(state_space, "state_space")
        self.action_space = _as_box(action_space, "action_space")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, EnvSpec):
            return NotImplemented
        return self.state_space == other.state_space and self.action_space == other.action_space

    def __hash__(self) -> int:
        return hash((self.state_space, self.action_space))

    def __repr__(self) -> str:
        return f"EnvSpec(state_space={self.state_space!r}, action_space={self.action_space!r})"

    @property
    def state_size(self) -> int:
        """Number of state entries."""
        return self.state_space.size

    @property
    def action_size(self) -> int:
        """Number of action entries."""
        return self.action_space.size

    def select_state(self, selection: Index | Iterable[Index]) -> EnvSpec:
        """Return the spec whose state box is the selected entries (action box unchanged)."""
        return EnvSpec(self.state_space.select(selection), self.action_space)
