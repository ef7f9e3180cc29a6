"""Schedules: values that follow the frames collected, evaluated by a :class:`~torchtasks.transforms.Curriculum`.

A schedule maps the number of frames collected so far (an int64 tensor) to a value: :func:`constant`,
:func:`linear` (a clamped ramp), :func:`staged` (piecewise constant, as mjlab's reward curriculum) and
:func:`gated` (a stage that advances only when a moving average of the success rate, or of an episode
return, passes a threshold, as ksim's curricula). A schedule is an ``nn.Module``: its definition and
state (a gated schedule's stage and average) are in its ``state_dict``.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections.abc import Hashable, Mapping, Sequence
from typing import Any

import torch
from tensordict.utils import NestedKey
from torch import nn

from torchtasks._checks import check_finite_scalar, check_non_negative_int, check_positive_int
from torchtasks._torchrl import nested_key
from torchtasks.transforms.names import SUCCESS_KEY

__all__ = ["GatedSchedule", "Schedule", "constant", "gated", "linear", "staged"]


def _as_value(value: object, name: str) -> torch.Tensor:
    """``value`` as a float64 tensor (a scalar or a tensor of the target's shape), rejecting NaN."""
    if isinstance(value, torch.Tensor):
        tensor = value.detach().to(dtype=torch.float64).clone()
    else:
        try:
            tensor = torch.as_tensor(value, dtype=torch.float64).clone()
        except (TypeError, ValueError, RuntimeError) as error:
            raise TypeError(f"{name} must be a number or a tensor of numbers, got {value!r}") from error
    if torch.isnan(tensor).any():
        raise ValueError(f"{name} must not contain NaN, got {tensor.tolist()}")
    return tensor


def _saved_number(value: object) -> object:
    """A number of a loaded state dict as a Python number: TorchRL's multi-process collectors gather the workers'
    state dicts in TensorDicts, which turn Python numbers into 0-d tensors (a host copy, once at a load)."""
    if isinstance(value, torch.Tensor) and value.numel() == 1 and value.dtype != torch.bool:
        return value.item()
    return value


def _stack_values(values: Sequence[object], name: str) -> torch.Tensor:
    """The values of a schedule's stages stacked on a new first dim (all of one shape)."""
    tensors = [_as_value(value, f"{name}[{i}]") for i, value in enumerate(values)]
    shapes = {tuple(t.shape) for t in tensors}
    if len(shapes) > 1:
        raise ValueError(f"{name}: all values must have the same shape, got shapes {[tuple(t.shape) for t in tensors]}")
    return torch.stack(tensors)


class Schedule(nn.Module):
    """A value that follows the frames collected: ``schedule(frames) -> value`` (float64, shape :attr:`value_shape`).

    ``frames`` is a 0-d int64 tensor; evaluation is tensor code (no ``.item()``, no host sync). A schedule
    whose value also follows the episodes (:class:`GatedSchedule`) names the entry it reads in
    :attr:`metric_key` and is told about finished episodes by :meth:`observe`; its state is registered
    buffers. Build schedules with :func:`constant`, :func:`linear`, :func:`staged` and :func:`gated`.

    Example:
        >>> import torch
        >>> from torchtasks.transforms import linear
        >>> linear(0.0, 1.0, 0, 100)(torch.tensor(25))
        tensor(0.2500, dtype=torch.float64)
    """

    #: the entry of the collected data (under ``"next"``) that :meth:`observe` reads; ``None``: reads none
    metric_key: NestedKey | None = None

    @property
    def value_shape(self) -> torch.Size:
        """The shape of the value (``()`` for a scalar, which is broadcast to its target)."""
        raise NotImplementedError

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def observe(self, done: torch.Tensor, metric: torch.Tensor) -> None:
        """Take note of the episodes that ended in a step (``done`` bool ``[*B]``, ``metric`` ``[*B]``); no-op here."""

    def _check_state(self, owner: str) -> None:
        """Raise ``ValueError`` (naming ``owner``) if loaded buffers break a rule the constructor enforces."""

    # A frame-driven schedule can also be evaluated on the host, from a Python int frame count (a host fact:
    # the Curriculum counts batch sizes), so that the Curriculum writes its buffer and entry only when the value
    # changes. Both hooks give what forward() gives, bit for bit. A schedule that also follows tensor state
    # (GatedSchedule) keeps the default: None, evaluate forward() every step.
    def _state_at(self, frames: int) -> Hashable | None:
        """A host fact that fixes the value at ``frames`` (equal facts: equal values), or ``None`` (tensor state)."""
        return None

    def _value_of(self, state: Hashable) -> torch.Tensor | float | list:
        """The value for a :meth:`_state_at` fact: a Python float for a value of one element (of any shape), else a
        float64 tensor or (a small value computed on the host) nested lists of Python floats of its shape."""
        raise NotImplementedError

    def _host_copy(self, name: str) -> float | list:
        """``self.<name>.tolist()``, cached until that buffer is replaced or written to (a host copy taken once)."""
        buffer = self._buffers[name]
        cache = self.__dict__.setdefault("_host_copies", {})
        cached = cache.get(name)
        if cached is None or cached[0] is not buffer or cached[1] != buffer._version:
            cached = cache[name] = (buffer, buffer._version, buffer.tolist())
        return cached[2]


class _Constant(Schedule):
    def __init__(self, value: object) -> None:
        super().__init__()
        self.register_buffer("value", _as_value(value, "constant: value"))

    @property
    def value_shape(self) -> torch.Size:
        return self.value.shape

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        return self.value

    def _state_at(self, frames: int) -> Hashable:
        return 0

    def _value_of(self, state: Hashable) -> torch.Tensor | float:
        return _single(self._host_copy("value")) if self.value.numel() == 1 else self.value

    def extra_repr(self) -> str:
        return f"value={self.value.tolist()}"


_HOST_VALUES = 64  # a linear schedule's values of at most this many elements are computed on the host


def _single(value: float | list) -> float:
    """The one float of a value of one element (``x``, ``[x]``, ``[[x]]``, ...)."""
    while isinstance(value, list):
        (value,) = value
    return value


def _lerp(start: float | list, end: float | list, fraction: float) -> float | list:
    """``start + fraction * (end - start)`` on nested lists of Python floats, element by element."""
    if isinstance(start, list):
        return [_lerp(s, e, fraction) for s, e in zip(start, end, strict=True)]
    return start + fraction * (end - start)


class _Linear(Schedule):
    def __init__(self, start_value: object, end_value: object, start_frame: int, end_frame: int) -> None:
        super().__init__()
        values = _stack_values([start_value, end_value], "linear: (start_value, end_value)")
        self.register_buffer("start_value", values[0].clone())
        self.register_buffer("end_value", values[1].clone())
        self.start_frame = check_non_negative_int(start_frame, "linear: start_frame")
        self.end_frame = check_non_negative_int(end_frame, "linear: end_frame")
        if self.end_frame < self.start_frame:
            raise ValueError(f"linear: end_frame must be >= start_frame, got {start_frame} and {end_frame}")

    @property
    def value_shape(self) -> torch.Size:
        return self.start_value.shape

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        if self.end_frame == self.start_frame:  # a step at start_frame
            fraction = (frames >= self.start_frame).to(torch.float64)
        else:
            fraction = ((frames - self.start_frame).to(torch.float64) / (self.end_frame - self.start_frame)).clamp(
                0.0, 1.0
            )
        return self.start_value + fraction * (self.end_value - self.start_value)

    def _state_at(self, frames: int) -> Hashable:
        # the fraction of forward() in Python floats: an int64 count below 2**53 converts exactly, and the
        # division and the clamp round as torch's float64 ops do
        if self.end_frame == self.start_frame:
            return float(frames >= self.start_frame)
        return min(max((frames - self.start_frame) / (self.end_frame - self.start_frame), 0.0), 1.0)

    def _value_of(self, state: Hashable) -> torch.Tensor | float | list:
        if self.start_value.numel() > _HOST_VALUES:
            return self.start_value + state * (self.end_value - self.start_value)
        # forward()'s three float64 ops, in its order, on the host: one tensor to make instead of four ops
        value = _lerp(self._host_copy("start_value"), self._host_copy("end_value"), state)
        return _single(value) if self.start_value.numel() == 1 else value

    def get_extra_state(self) -> dict[str, int]:
        """The ramp's frames, saved beside its values: a checkpoint restores the whole schedule."""
        return {"start_frame": self.start_frame, "end_frame": self.end_frame}

    def set_extra_state(self, state: Any) -> None:
        """Restore the frames saved by :meth:`get_extra_state` (checked as the constructor checks them)."""
        if not isinstance(state, Mapping) or set(state) != {"start_frame", "end_frame"}:
            raise ValueError(f"linear.load_state_dict: expected {{'start_frame', 'end_frame'}}, got {state!r}")
        start = check_non_negative_int(_saved_number(state["start_frame"]), "linear.load_state_dict: start_frame")
        end = check_non_negative_int(_saved_number(state["end_frame"]), "linear.load_state_dict: end_frame")
        if end < start:
            raise ValueError(f"linear.load_state_dict: end_frame must be >= start_frame, got {start} and {end}")
        self.start_frame, self.end_frame = start, end

    def extra_repr(self) -> str:
        return (
            f"start_value={self.start_value.tolist()}, end_value={self.end_value.tolist()}, "
            f"start_frame={self.start_frame}, end_frame={self.end_frame}"
        )


class _Staged(Schedule):
    def __init__(self, stages: Mapping[int, object]) -> None:
        super().__init__()
        if not isinstance(stages, Mapping) or not stages:
            raise TypeError(f"staged: stages must be a non-empty mapping {{frames: value}}, got {stages!r}")
        boundaries = sorted(check_non_negative_int(frames, "staged: a boundary") for frames in stages)
        if boundaries[0] != 0:
            raise ValueError(f"staged: the first boundary must be 0 (a value from the start), got {boundaries}")
        self.register_buffer("boundaries", torch.tensor(boundaries, dtype=torch.int64))
        self.register_buffer("values", _stack_values([stages[b] for b in boundaries], "staged: values"))

    @property
    def value_shape(self) -> torch.Size:
        return self.values.shape[1:]

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        index = (frames >= self.boundaries).sum() - 1  # >= 0: the first boundary is 0 and frames >= 0
        return self.values[index]

    def _state_at(self, frames: int) -> Hashable:
        return bisect.bisect_right(self._host_copy("boundaries"), frames) - 1

    def _check_state(self, owner: str) -> None:
        boundaries = self.boundaries.tolist()
        if (
            self.boundaries.dtype != torch.int64
            or not boundaries
            or boundaries[0] != 0
            or any(b <= a for a, b in itertools.pairwise(boundaries))
            or len(boundaries) != self.values.shape[0]
        ):
            raise ValueError(
                f"{owner}: a staged schedule's boundaries must be increasing int64 frame counts from 0, one per "
                f"stage ({self.values.shape[0]}), got {boundaries}"
            )

    def _value_of(self, state: Hashable) -> torch.Tensor | float:
        return _single(self._host_copy("values")[state]) if self.values[0].numel() == 1 else self.values[state]

    def extra_repr(self) -> str:
        return f"boundaries={self.boundaries.tolist()}"


class GatedSchedule(Schedule):
    """A stage index that advances when a moving average over finished episodes passes a threshold.

    The moving average is an exponential moving average over the episodes finished in the current
    stage, with rate ``1 / window`` and bias-corrected as Adam's (so it is a weighted mean of those
    episodes' metrics, the latest weighted most: episode ``j`` episodes ago has weight
    ``(1 - 1/window)^j``); the ``k`` episodes that end in one step count as ``k`` episodes of their
    mean. After a step in which episodes ended, the stage advances by one (up to the last) when at
    least ``window`` episodes ended in the stage and ``average >= threshold``; the average and the
    episode count then restart in the new stage. A stage never goes back. Build it with
    :func:`gated`; the value is ``values[stage]``.

    ``stage``, ``average`` and ``episodes`` are registered buffers (``state_dict()`` restores them), and so
    are the values; the threshold and window are saved beside them (``"_extra_state"``).
    """

    def __init__(self, values: Sequence[object], metric: NestedKey, threshold: float, window: int) -> None:
        super().__init__()
        if isinstance(values, (str, Mapping)) or not isinstance(values, Sequence) or len(values) < 1:
            raise TypeError(f"gated: values must be a non-empty sequence of stage values, got {values!r}")
        self.register_buffer("values", _stack_values(list(values), "gated: values"))
        self.metric_key = nested_key(metric, "gated: metric")
        self.threshold = check_finite_scalar(threshold, "gated: threshold")
        self.window = check_positive_int(window, "gated: window")
        self.register_buffer("stage", torch.zeros((), dtype=torch.int64))
        self.register_buffer("average", torch.zeros((), dtype=torch.float64))
        self.register_buffer("episodes", torch.zeros((), dtype=torch.int64))
        self.register_buffer("keep", torch.tensor(1.0 - 1.0 / self.window, dtype=torch.float64), persistent=False)

    def observe(self, done: torch.Tensor, metric: torch.Tensor) -> None:
        """Fold the episodes that ended (``done``) into the moving average; advance the stage if it passes."""
        done = done.reshape(-1)
        metric = metric.reshape(-1).to(torch.float64)
        count = done.sum()
        mean = torch.where(done, metric, torch.zeros_like(metric)).sum() / count.clamp(min=1)
        decay = self.keep.pow(count)  # the weight left to the earlier episodes of the stage
        old_weight = 1.0 - self.keep.pow(self.episodes)  # the total weight of the bias-corrected mean so far
        new_weight = decay * old_weight + (1.0 - decay)
        total = decay * old_weight * self.average + (1.0 - decay) * mean
        average = torch.where(new_weight > 0, total / new_weight.clamp(min=1e-300), self.average)
        episodes = self.episodes + count
        advance = (
            (count > 0)
            & (episodes >= self.window)
            & (average >= self.threshold)
            & (self.stage < self.values.shape[0] - 1)
        )
        self.stage.add_(advance.to(torch.int64))
        self.average.copy_(torch.where(advance, torch.zeros_like(average), average))
        self.episodes.copy_(torch.where(advance, torch.zeros_like(episodes), episodes))

    @property
    def value_shape(self) -> torch.Size:
        return self.values.shape[1:]

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        return self.values[self.stage]

    def _check_state(self, owner: str) -> None:
        stage, episodes, average = int(self.stage), int(self.episodes), float(self.average)
        if not 0 <= stage < self.values.shape[0] or episodes < 0 or not math.isfinite(average):
            raise ValueError(
                f"{owner}: a gated schedule needs a stage in [0, {self.values.shape[0] - 1}], episodes >= 0 and a "
                f"finite average, got stage {stage}, episodes {episodes}, average {average}"
            )

    def get_extra_state(self) -> dict[str, torch.Tensor | int]:
        """The gate's threshold and window, saved beside its values and state: a checkpoint restores it whole.

        The threshold is saved as a float64 tensor: a Python float would come back as float32 from the TensorDict
        in which a multi-process collector gathers its workers' state dicts.
        """
        return {"threshold": torch.tensor(self.threshold, dtype=torch.float64), "window": self.window}

    def set_extra_state(self, state: Any) -> None:
        """Restore the threshold and window saved by :meth:`get_extra_state` (checked as the constructor does)."""
        if not isinstance(state, Mapping) or set(state) != {"threshold", "window"}:
            raise ValueError(f"gated.load_state_dict: expected {{'threshold', 'window'}}, got {state!r}")
        self.threshold = check_finite_scalar(_saved_number(state["threshold"]), "gated.load_state_dict: threshold")
        self.window = check_positive_int(_saved_number(state["window"]), "gated.load_state_dict: window")
        self.keep.fill_(1.0 - 1.0 / self.window)

    def extra_repr(self) -> str:
        return f"stages={self.values.shape[0]}, metric={self.metric_key!r}, threshold={self.threshold}, " + (
            f"window={self.window}"
        )


def constant(value: object) -> Schedule:
    """A schedule that is ``value`` at every frame count (a scalar or a tensor of the target's shape).

    Example:
        >>> import torch
        >>> from torchtasks.transforms import constant
        >>> constant(0.5)(torch.tensor(10_000))
        tensor(0.5000, dtype=torch.float64)
    """
    return _Constant(value)


def linear(start_value: object, end_value: object, start_frame: int, end_frame: int) -> Schedule:
    """A linear ramp from ``start_value`` at ``start_frame`` to ``end_value`` at ``end_frame``, clamped outside.

    ``start_frame == end_frame`` is a step to ``end_value`` at that frame count.

    Example:
        >>> import torch
        >>> from torchtasks.transforms import linear
        >>> ramp = linear(0.0, 1.0, start_frame=100, end_frame=300)
        >>> [round(float(ramp(torch.tensor(f))), 3) for f in (0, 100, 200, 300, 1000)]
        [0.0, 0.0, 0.5, 1.0, 1.0]
    """
    return _Linear(start_value, end_value, start_frame, end_frame)


def staged(stages: Mapping[int, object]) -> Schedule:
    """A piecewise-constant schedule: the value of the last boundary ``b`` with ``frames >= b``.

    ``stages`` maps frame counts to values (mjlab's reward curriculum); a boundary at 0 is required.

    Example:
        >>> import torch
        >>> from torchtasks.transforms import staged
        >>> weight = staged({0: 0.0, 50_000: 0.5, 100_000: 1.0})
        >>> [float(weight(torch.tensor(f))) for f in (49_999, 50_000, 100_000)]
        [0.0, 0.5, 1.0]
    """
    return _Staged(stages)


def gated(
    values: Sequence[object], metric: NestedKey = SUCCESS_KEY, threshold: float = 0.8, window: int = 100
) -> GatedSchedule:
    """A schedule through ``values`` that advances a stage when the episodes' moving average passes ``threshold``.

    ``metric`` is the entry read at the end of every episode (under ``"next"``): the success flag by
    default, or an episode return such as a ``RewardSum``'s ``"episode_reward"`` or
    ``("task_reward", "episode_track")`` (then the Curriculum must come after that ``RewardSum``).
    The average is a bias-corrected exponential moving average over the episodes finished in the
    stage, with rate ``1 / window``; a stage lasts at least ``window`` episodes (see :class:`GatedSchedule`).

    Example:
        >>> import torch
        >>> from torchtasks.transforms import gated
        >>> levels = gated([0.1, 0.5, 1.0], threshold=0.8, window=2)
        >>> done = torch.tensor([True, True])
        >>> levels.observe(done, torch.tensor([1.0, 0.0]))  # a success and a failure: average 0.5 < 0.8
        >>> levels.stage, float(levels.average), float(levels(torch.tensor(0)))
        (tensor(0), 0.5, 0.1)
        >>> levels.observe(done, torch.tensor([1.0, 1.0]))  # average 0.9: the next stage; the average restarts
        >>> levels.stage, float(levels.average), float(levels(torch.tensor(0)))
        (tensor(1), 0.0, 0.5)
    """
    return GatedSchedule(values, metric, threshold, window)


_KINDS = {  # a schedule's kind, from the names of its saved entries
    frozenset({"value"}): "constant",
    frozenset({"start_value", "end_value", "_extra_state"}): "linear",
    frozenset({"boundaries", "values"}): "staged",
    frozenset({"values", "stage", "average", "episodes", "_extra_state"}): "gated",
}


def schedule_kind(state: Mapping[str, Any]) -> str:
    """The kind of schedule (``"linear"``, ...) whose ``state_dict()`` is ``state``; its entries if none matches."""
    return _KINDS.get(frozenset(state), f"unknown ({sorted(state)})")


def breakpoint_frames(schedule: Schedule) -> set[int]:
    """The frame counts at which a frame-driven schedule's extremes lie: 0 and each breakpoint ``b`` and ``b - 1``.

    Between two consecutive breakpoints a constant, linear or staged schedule is linear (or constant) in
    the integer frame count, so a linear inequality between two of them that holds at these counts holds at all.
    """
    if isinstance(schedule, _Linear):
        points = [schedule.start_frame, schedule.end_frame]
    elif isinstance(schedule, _Staged):
        points = schedule.boundaries.tolist()
    else:
        points = []
    return {0} | set(points) | {p - 1 for p in points if p > 0}


def possible_values(schedule: Schedule | None, current: torch.Tensor) -> torch.Tensor:
    """The values a bound can take, stacked on a first dim (float64, CPU): the stages of a gated schedule, a
    frame-driven schedule's values at its :func:`breakpoint_frames`, the buffer's current value if unscheduled."""
    if schedule is None:
        return current.detach().to("cpu", torch.float64)[None]
    if isinstance(schedule, GatedSchedule):
        values = schedule.values.detach().to("cpu", torch.float64)
    else:
        values = torch.stack([value_at(schedule, count) for count in sorted(breakpoint_frames(schedule))])
    return values.reshape(-1, *([1] * current.dim())) if schedule.value_shape == torch.Size(()) else values


def value_at(schedule: Schedule, count: int) -> torch.Tensor:
    return schedule(torch.tensor(count, dtype=torch.int64)).detach().to("cpu", torch.float64)
