"""Curriculum: a transform that sets float buffers of a task tree from schedules of the frames collected.

:class:`Curriculum` is a TorchRL transform placed after the :class:`~torchtasks.transforms.TaskTransform` of an
env: at every step it counts the env's frames, evaluates its schedules (:mod:`torchtasks.transforms.schedules`)
and writes each value into a float buffer of the task tree (``buffer.copy_(value)``). A schedule changes a task
only through its registered buffers.

The frame counter and the state of every gated schedule are buffers of the Curriculum: its
``state_dict()`` (and so TorchRL's ``Collector.state_dict()``, which saves the env's transforms)
restores them on resume, with each schedule's definition (values, frames, threshold, window).
"""

from __future__ import annotations

import itertools
from collections.abc import Hashable, Mapping
from typing import Any, NamedTuple

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torch import nn
from torchrl.data import Composite, Unbounded

from torchtasks._checked_load import CheckedLoad
from torchtasks._checks import check_positive_int
from torchtasks._memory import td_set
from torchtasks._torchrl import key_parts, nested_key
from torchtasks.transforms.names import CURRICULUM_KEY, DOMAIN, FRAMES, entry_name, respelt_entries
from torchtasks.transforms.schedules import (
    GatedSchedule,
    Schedule,
    breakpoint_frames,
    possible_values,
    schedule_kind,
    value_at,
)
from torchtasks.transforms.targets import (
    TASK,
    DomainWrites,
    Target,
    TargetWriter,
    check_domain_writes,
    check_in_goal_space,
    check_low_not_above_high,
    check_one_owner,
    command_ranges,
    resolve_targets,
)
from torchtasks.transforms.task import RecordedValue, undefined_flag_note

__all__ = ["Curriculum"]


class _Written(NamedTuple):
    """What a step wrote last into one target (see :meth:`Curriculum._forget_written`)."""

    #: the schedule's host state (a frame-driven schedule's fraction or stage)
    state: Hashable
    #: the buffer after the write, and its version counter then
    buffer: torch.Tensor
    buffer_version: int
    #: the entry put in the data, and its version counter then
    entry: torch.Tensor
    entry_version: int
    #: the batch of the data the entry was made for
    batch: torch.Size


class _CountMirror(NamedTuple):
    """The frame count as a Python int, with the ``frames`` buffer it mirrors and that buffer's version then."""

    frames: torch.Tensor
    version: int
    count: int


class Curriculum(CheckedLoad, TargetWriter):
    """Set float buffers of the env's task tree from schedules that follow the frames collected.

    Place it after the :class:`~torchtasks.transforms.TaskTransform` of the env (in the same ``Compose``, and after a
    ``RewardSum`` whose episode sums a gated schedule reads). Each key of ``schedules`` names a float buffer of that
    transform's task (``task.named_buffers()``'s name, e.g. ``"wrapped_task.reward.Q"``, or a short name:
    :func:`~torchtasks.transforms.target_names` lists them) or, as ``"command.low"``/``"command.high"``, the range of a
    :class:`~torchtasks.transforms.GoalCommand` placed after it. A misspelt or ambiguous name, a value of another shape
    than the buffer's and a value the buffer's owner refuses (a negative cost weight, a range that leaves the goal
    space) are a ``ValueError`` when the env's specs are built, checked at every breakpoint and stage.

    At every step the frame counter grows by ``workers`` times the env's batch size (frames follow the steps of all
    envs, not their resets) and every schedule's value at the new count is written into its buffer, where the next
    step's reward reads it; at reset the current values are written before the env and the TaskTransform reset. The
    entries ``(curriculum_key, "frames")`` and ``(curriculum_key, <target with "/" for ".">)`` record the count and
    the values each step used (offline recomputation reads them). The counter and each gated schedule's stage are
    registered buffers: ``state_dict()`` restores them, also through TorchRL's ``Collector.state_dict()``. Each worker
    of a ``ParallelEnv`` or multi-process collector runs its own copy: ``workers=n`` makes it count the frames of the
    ``n`` copies that step in lockstep. The docs page "Curriculum" has the rules in full (targets, entries, workers,
    gradients, checkpoints).

    Args:
        schedules: ``{target buffer name: schedule}``.
        curriculum_key: where the entries are written.
        workers: how many copies of this env (processes, workers) step in lockstep with it; the frame counter grows
            by ``workers`` times the batch size per step. A positive int.

    Example:
        >>> import torch
        >>> from torchrl.envs import Compose, StepCounter, TransformedEnv
        >>> from torchtasks.transforms import Curriculum, linear
        >>> from torchtasks.envs import PendulumEnv, swing_up_task
        >>> from torchtasks.transforms import TaskTransform
        >>> curriculum = Curriculum({"success_value": linear(0.0, 100.0, 0, 40)})  # the final reward on success
        >>> env = TransformedEnv(PendulumEnv(batch_size=[4]), Compose(
        ...     StepCounter(50), TaskTransform(swing_up_task()), curriculum))
        >>> data = env.rollout(5, break_when_any_done=False)
        >>> data["next", "curriculum", "frames"][0, :, 0]
        tensor([ 4,  8, 12, 16, 20])
        >>> data["curriculum", "success_value"][0, :, 0]  # the value each step's reward was computed with
        tensor([ 0., 10., 20., 30., 40.])
    """

    def __init__(
        self, schedules: Mapping[str, Schedule], *, curriculum_key: NestedKey = CURRICULUM_KEY, workers: int = 1
    ) -> None:
        if not isinstance(schedules, Mapping) or not schedules:
            raise TypeError(
                f"Curriculum: schedules must be a non-empty mapping {{target: schedule}}, got {schedules!r}"
            )
        for target, schedule in schedules.items():
            if not isinstance(target, str):
                raise TypeError(f"Curriculum: targets must be buffer names (strings), got {target!r}")
            if not isinstance(schedule, Schedule):
                raise TypeError(
                    f"Curriculum: the schedule of {target!r} must be a torchtasks.transforms Schedule (constant, "
                    f"linear, staged, gated), got {type(schedule).__name__}"
                )
        self.curriculum_key = nested_key(curriculum_key, "Curriculum: curriculum_key")
        self.workers = check_positive_int(workers, "Curriculum: workers")
        self.targets = tuple(schedules)
        entries = [entry_name(target) for target in self.targets]
        if FRAMES in entries:
            raise ValueError(f"Curriculum: a target may not be named {FRAMES!r}: that entry is the frame count")
        if len(set(entries)) < len(entries):
            raise ValueError(
                f"Curriculum: targets {list(self.targets)} give the same entry name twice (entries {entries}: '.' "
                "becomes '/'); name each buffer once"
            )
        self._prefix = key_parts(self.curriculum_key)
        self._value_keys = [(*key_parts(self.curriculum_key), name) for name in entries]
        self._frames_key = (*key_parts(self.curriculum_key), FRAMES)
        metrics = [s.metric_key for s in schedules.values() if s.metric_key is not None]
        super().__init__(in_keys=[], out_keys=[self._frames_key, *self._value_keys])
        self._metric_keys = metrics
        # keyed by target (its entry name: a module name may not hold "."), so a checkpoint is keyed by meaning
        self.schedules = nn.ModuleDict(zip(entries, schedules.values(), strict=True))
        self.register_buffer("frames", torch.zeros((), dtype=torch.int64))
        # construction-time facts for the step (plain attributes: a submodule's lookup costs ~1 µs a step): per
        # target its entry's name and shape and its schedule, and the schedules that observe episodes
        self.__dict__["_plan"] = [
            (name, s.value_shape if s.value_shape != torch.Size(()) else torch.Size([1]), s)
            for name, s in self.schedules.items()
        ]
        self.__dict__["_observing"] = [s for s in self.schedules.values() if s.metric_key is not None]
        self._forget_written()

    # ------------------------------------------------------------------ host mirrors
    # The hot path keeps two kinds of host facts beside the registered state. The frame count as a Python int
    # (``_count_of``): the sum of batch sizes the ``frames`` buffer also adds, kept with that buffer's identity
    # and version counter, so that any other write to the buffer (load_state_dict, .to(), a user's fill_)
    # is noticed and the mirror re-read from it. And per target what was written last (``_written``): the
    # schedule's host state (a frame-driven schedule's fraction or stage), the buffer and its version after
    # the write, and the entry tensor put in the data. When the state, the buffer and the entry are as they
    # were, the value is the same: the buffer is not written again and the same entry tensor goes into the
    # step's data. That entry is never written into afterwards (a changed value gets a new tensor), so the
    # data of earlier steps that hold it, e.g. until env.rollout stacks them, keep their values.
    def _forget_written(self) -> None:
        self.__dict__["_written"] = [None] * len(self.targets)
        self.__dict__["_count_of"] = None  # a _CountMirror

    def _frame_count(self) -> int:
        """The frame count as a Python int, re-read from the ``frames`` buffer if anything but this wrote to it."""
        frames = self._buffers["frames"]
        mirror = self.__dict__["_count_of"]
        if mirror is not None and mirror.frames is frames and mirror.version == frames._version:
            return mirror.count
        count = int(frames)  # a host copy: once after a load or a move, never in a step of a running collection
        self.__dict__["_count_of"] = _CountMirror(frames, frames._version, count)
        return count

    def _add_frames(self, added: int) -> int:
        count = self._frame_count() + added
        frames = self._buffers["frames"]
        frames.fill_(count)
        self.__dict__["_count_of"] = _CountMirror(frames, frames._version, count)
        return count

    def _prepare_load(self, state_dict: Mapping[str, Any], prefix: str) -> None:
        self._forget_written()  # the schedules' values and parameters change with the load

    def _check_saved(self, state_dict: Mapping[str, Any], prefix: str) -> None:
        """Refuse a checkpoint whose schedules are not this Curriculum's: other targets, kinds or shapes.

        The saved keys say it all: ``schedules.<target entry>.<buffer>`` (the buffers name the kind).
        """
        head = prefix + "schedules."
        saved: dict[str, dict[str, Any]] = {}
        for key, value in state_dict.items():
            if key.startswith(head):
                entry, _, name = key[len(head) :].partition(".")
                saved.setdefault(entry, {})[name] = value
        own = {entry: dict(schedule.state_dict()) for entry, schedule in self.schedules.items()}
        missing, unknown = sorted(set(own) - set(saved)), sorted(set(saved) - set(own))
        if missing or unknown:  # a non-strict load of a partial state dict has ours in place of the missing ones
            raise ValueError(
                "Curriculum.load_state_dict: the checkpoint schedules other targets than this Curriculum: saved "
                f"{sorted(saved)}, here {sorted(own)} (entry names: the targets with '/' for '.'; a checkpoint is "
                "loaded by target, in any order, never by position). Build the Curriculum with the saved targets"
                + respelt_entries(unknown, missing)
            )
        for entry in sorted(set(own) & set(saved)):
            own_kind, saved_kind = schedule_kind(own[entry]), schedule_kind(saved[entry])
            if own_kind != saved_kind:
                raise ValueError(
                    f"Curriculum.load_state_dict: the schedule of {entry!r} is {own_kind} here, but the checkpoint "
                    f"holds a {saved_kind} schedule (its entries {sorted(saved[entry])})"
                )
            for name, value in saved[entry].items():
                mine = own[entry].get(name)
                if isinstance(value, torch.Tensor) and isinstance(mine, torch.Tensor) and value.shape != mine.shape:
                    raise ValueError(
                        f"Curriculum.load_state_dict: the {own_kind} schedule of {entry!r} has {name!r} of shape "
                        f"{list(mine.shape)} here, but {list(value.shape)} in the checkpoint (another value shape or "
                        "number of stages): build the schedule as saved"
                    )

    def _check_loaded(self) -> None:
        """Check the loaded schedules as their constructors and spec building do; in a built env, write their values.

        The write puts each target at the loaded frame count's value before the next step reads it (a task keeps
        some scheduled buffers, e.g. a final reward's ``success_value``, out of its own state).
        """
        if int(self._buffers["frames"]) < 0:
            raise ValueError(f"Curriculum.load_state_dict: the frame count must be >= 0, got {int(self.frames)}")
        for entry, schedule in self.schedules.items():
            schedule._check_state(f"Curriculum.load_state_dict: the schedule of {entry!r}")
        self._forget_setup()
        if self.home_transforms() is not None:  # in an env: check now; else when the env's specs are built
            self._resolve()
            self._write_run_values()

    def _apply(self, fn, *args, **kwargs):
        self._forget_written()
        return super()._apply(fn, *args, **kwargs)

    # ------------------------------------------------------------------ setup
    def _resolve(self) -> list[Target]:
        """Resolve the targets in the env (names, shapes, every value a schedule can write), cached until it changes."""
        schedules = list(self.schedules.values())
        placement, targets = resolve_targets(self, self.targets, [schedule.value_shape for schedule in schedules])
        for target, schedule in zip(targets, schedules, strict=True):  # as the reward's constructor would check them
            if target.source != DOMAIN:  # a distribution's values: with its other writers' (check_domain_writes)
                label = f"Curriculum: the schedule of {target.name!r}"
                target.check_values(possible_values(schedule, target.value), label)
        self._check_ranges(targets, schedules)
        self._forget_written()
        self.__dict__["_resolved"] = targets  # what written_targets() answers while the env's other writers are asked
        try:
            check_one_owner(self, targets, placement)
            check_domain_writes(self, placement)
        except ValueError:
            self._forget_setup()
            raise
        return targets

    def _check_ranges(self, targets: list[Target], schedules: list[Schedule]) -> None:
        """Refuse a scheduled GoalCommand range that leaves its Box or has ``low > high``: at every breakpoint of
        constant, linear and staged schedules (where their extremes lie), and every stage value of a gated schedule
        against every value the other bound can take."""
        for command, bounds in command_ranges(targets).items():
            names = ", ".join(repr(targets[i].name) for i in bounds.values())
            for i in bounds.values():
                values = possible_values(schedules[i], targets[i].value)
                label = f"Curriculum: the schedule of {targets[i].name!r}"
                among = f"of its values at its breakpoints or stages, {values.tolist()}"
                check_in_goal_space(targets[i], values, label, [f"its value {v} ({among})" for v in values.tolist()])
            low = schedules[bounds["low"]] if "low" in bounds else None
            high = schedules[bounds["high"]] if "high" in bounds else None
            scheduled = f"Curriculum: the scheduled range {names} of the GoalCommand writing {command.goal_key!r}"
            if not (isinstance(low, GatedSchedule) or isinstance(high, GatedSchedule)):
                # both follow the frames only: compare them at every breakpoint of either
                counts = sorted(set().union(*(breakpoint_frames(s) for s in (low, high) if s is not None)))
                pairs = [
                    (
                        command.low if low is None else value_at(low, count),
                        command.high if high is None else value_at(high, count),
                    )
                    for count in counts
                ]
                check_low_not_above_high(pairs, [f"{scheduled}, at frame {count}," for count in counts])
            else:  # a gated stage may be reached at any frame: every value of one bound against every one of the other
                lows, highs = possible_values(low, command.low), possible_values(high, command.high)
                gated = (
                    f"{scheduled} (a gated stage may be reached at any frame: low takes {lows.tolist()}, high takes "
                    f"{highs.tolist()}; the highest low against the lowest high)"
                )
                check_low_not_above_high([(lows.amax(0), highs.amin(0))], [gated])

    def domain_writes(self) -> list[DomainWrites]:
        """The rows of values the schedules can write into each domain distribution among the targets: the
        frame-driven schedules together at every breakpoint of any of them (and, where a clipping bound moves with
        the rest between two breakpoints, the mixed corners of that segment; see
        :func:`~torchtasks.transforms.targets.check_domain_writes`), with every stage of every gated one."""
        targets = self.written_targets()
        schedules = list(self.schedules.values())
        groups: dict[int, list[int]] = {}
        for i, target in enumerate(targets):
            if target.source == DOMAIN:
                groups.setdefault(id(target.module), []).append(i)
        return [self._domain_rows(targets, schedules, indices) for indices in groups.values()]

    @staticmethod
    def _domain_rows(targets: list[Target], schedules: list[Schedule], indices: list[int]) -> DomainWrites:
        """The :class:`DomainWrites` of the schedules of ``indices`` (targets of one distribution)."""
        param = targets[indices[0]].module
        frame_driven = [i for i in indices if not isinstance(schedules[i], GatedSchedule)]
        gates = [i for i in indices if isinstance(schedules[i], GatedSchedule)]
        counts = sorted(set().union(*(breakpoint_frames(schedules[i]) for i in frame_driven)))
        # one row of the frame-driven schedules: (label, {target index: count whose value it takes})
        moments = [(f"at frame {count}", dict.fromkeys(frame_driven, count)) for count in counts] or [("", {})]
        parts = {}  # the frame-driven targets by the part of the clipped range they move: the two bounds, the rest
        for i in frame_driven:
            parts.setdefault(targets[i].buffer if targets[i].buffer in ("clip_lo", "clip_up") else "", []).append(i)
        if len(parts) > 1:  # a clipping bound moving with the rest: the mixed corners of each segment with inner frames
            for a, b in itertools.pairwise(counts):
                if b - a < 2:
                    continue
                for ends in itertools.product((a, b), repeat=len(parts)):
                    if len(set(ends)) > 1:
                        at = {i: end for part, end in zip(parts.values(), ends, strict=True) for i in part}
                        moments.append((f"between frames {a} and {b} (mixed)", at))
        stages = [range(schedules[i].values.shape[0]) for i in gates]
        labels, rows = [], {i: [] for i in indices}
        for (moment, at), picked in itertools.product(moments, itertools.product(*stages)):
            for i, count in at.items():
                rows[i].append(value_at(schedules[i], count))
            for i, stage in zip(gates, picked, strict=True):
                rows[i].append(schedules[i].values[stage].detach().to("cpu", torch.float64))
            gated_at = [
                f"at stage {stage}" if len(indices) == 1 else f"{targets[i].name!r} at its stage {stage}"
                for i, stage in zip(gates, picked, strict=True)
            ]
            labels.append(", ".join(part for part in (moment, *gated_at) if part))
        names = ", ".join(repr(targets[i].name) for i in indices)
        head = f"the schedule{'s' if len(indices) > 1 else ''} of {names}"
        values = {
            targets[i].buffer: torch.stack([row.expand(targets[i].value_shape) for row in rows[i]]) for i in indices
        }
        return DomainWrites(param, "Curriculum", values, tuple(f"{head} {label}" for label in labels))

    def recorded_task_values(self) -> list[RecordedValue]:
        """The task buffers this Curriculum sets, each with the entry recording the value every step used (shared by
        all envs); offline recomputation with the env's TaskTransform reads them (a GoalCommand's range needs none:
        the goal drawn is in the data)."""
        return [  # by the buffer's full name: a target may be written by its short name
            RecordedValue(target.path, key, None)
            for target, key in zip(self.written_targets(), self._value_keys, strict=True)
            if target.source == TASK
        ]

    def written_targets(self) -> list[Target]:
        """The targets this Curriculum writes, resolved in its env (``ValueError`` if one is refused).

        Example:
            >>> from torchrl.envs import Compose, TransformedEnv
            >>> from torchtasks.envs import PendulumEnv, swing_up_task
            >>> from torchtasks.transforms import Curriculum, TaskTransform, linear
            >>> curriculum = Curriculum({"success_value": linear(0.0, 100.0, 0, 40)})
            >>> env = TransformedEnv(PendulumEnv(batch_size=[2]), Compose(TaskTransform(swing_up_task()), curriculum))
            >>> [(target.name, type(target.module).__name__, target.buffer) for target in curriculum.written_targets()]
            [('success_value', 'FinalRewardTask', 'success_value')]
        """
        targets = self.__dict__.get("_resolved")
        return self._resolve() if targets is None else targets

    def _forget_setup(self) -> None:
        self.__dict__.pop("_resolved", None)
        self._forget_written()

    # ------------------------------------------------------------------ specs
    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        targets = self._resolve()
        batch, device = observation_spec.shape, observation_spec.device
        for key in self._metric_keys:
            if key not in observation_spec.keys(True, True):
                raise ValueError(
                    f"Curriculum: a gated schedule reads {key!r}, which is not in the env's observation spec (put "
                    "Curriculum after the transform that writes it, e.g. the TaskTransform or a RewardSum)"
                    + undefined_flag_note(self, key)
                )
        observation_spec[self._frames_key] = Unbounded(shape=(*batch, 1), dtype=torch.int64, device=device)
        for key, target, schedule in zip(self._value_keys, targets, self.schedules.values(), strict=True):
            shape = schedule.value_shape if schedule.value_shape != torch.Size(()) else torch.Size([1])
            observation_spec[key] = Unbounded(shape=(*batch, *shape), dtype=target.value.dtype, device=device)
        return observation_spec

    # ------------------------------------------------------------------ TorchRL hooks
    def _write(self, tensordict: TensorDictBase, count: int, replace: bool) -> TensorDictBase:
        """Write every schedule's value at ``count`` frames into its buffer and into ``tensordict``.

        ``replace``: put a new tensor in the buffer's place instead of writing into it, so that the autograd
        graph of earlier steps (a differentiable ``env.rollout`` under grad mode) keeps the values it saved.
        A frame-driven schedule is evaluated on the host; its buffer and entry are written only when its value
        changed (see :meth:`_forget_written`). A gated schedule is evaluated and written every step.
        """
        batch = tensordict.batch_size
        frames = self._buffers["frames"]
        entries = {FRAMES: torch.full((*batch, 1), count, dtype=torch.int64, device=frames.device)}
        targets = self.__dict__.get("_resolved")
        if targets is None:
            targets = self._resolve()
        written = self.__dict__["_written"]
        for i, ((name, shape, schedule), target) in enumerate(zip(self.__dict__["_plan"], targets, strict=True)):
            buffer = target.module._buffers[target.buffer]
            state = schedule._state_at(count)
            last = written[i]
            if (
                state is not None
                and last is not None
                and last.state == state
                and last.buffer is buffer
                and last.buffer_version == buffer._version
                and last.entry._version == last.entry_version
                and last.batch == batch
            ):
                entries[name] = last.entry  # the same value: the entry of the last write
                continue
            value = schedule(frames) if state is None else schedule._value_of(state)
            if isinstance(value, list):
                value = torch.tensor(value, dtype=buffer.dtype, device=buffer.device)
            if isinstance(value, float):  # a frame-driven value of one element, on the host
                buffer = target.write(value, replace=replace)
                entry = torch.full((*batch, *shape), value, dtype=buffer.dtype, device=buffer.device)
            else:
                if value.dtype != buffer.dtype or value.device != buffer.device:
                    value = value.to(device=buffer.device, dtype=buffer.dtype)
                buffer = target.write(value, replace=replace)
                entry = value.expand(*batch, *shape).clone()
            entries[name] = entry
            written[i] = (
                None if state is None else _Written(state, buffer, buffer._version, entry, entry._version, batch)
            )
        self._put(tensordict, batch, entries)
        return tensordict

    def _put(self, tensordict: TensorDictBase, batch: torch.Size, entries: dict[str, torch.Tensor]) -> None:
        """Set ``entries`` under ``curriculum_key`` (one new sub-TensorDict when there is none yet: the usual case)."""
        prefix = self._prefix
        if (
            type(tensordict) is TensorDict
            and len(prefix) == 1
            and not tensordict._has_names()
            and tensordict._get_str(prefix[0], None) is None
        ):
            node = TensorDict._new_unsafe(entries, batch_size=batch, device=tensordict.device)
            tensordict._set_str(prefix[0], node, inplace=False, validated=True)
            return
        for name, value in entries.items():
            td_set(tensordict, (*prefix, name), value)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        if torch.is_grad_enabled():  # a host fact: collectors run under no_grad, a differentiable rollout not
            with torch.no_grad():
                return self._write(tensordict_reset, self._frame_count(), replace=True)
        return self._write(tensordict_reset, self._frame_count(), replace=False)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        if torch.is_grad_enabled():
            with torch.no_grad():
                return self._advance(next_tensordict, replace=True)
        return self._advance(next_tensordict, replace=False)

    def _advance(self, next_tensordict: TensorDictBase, replace: bool) -> TensorDictBase:
        # the global frame count of a synchronous run: every one of the `workers` copies of this env steps as well
        count = self._add_frames(self.workers * next_tensordict.batch_size.numel())
        observing = self.__dict__["_observing"]
        if observing:
            done = next_tensordict.get("done", None)
            if done is None:
                raise KeyError("Curriculum: a gated schedule needs the 'done' flags of the step")
            for schedule in observing:
                schedule.observe(done, next_tensordict.get(schedule.metric_key))
        return self._write(next_tensordict, count, replace)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Leave stored data as it is: a curriculum follows the collection, not replayed transitions."""
        return tensordict

    def __repr__(self) -> str:
        return f"{type(self).__name__}(targets={list(self.targets)})"
