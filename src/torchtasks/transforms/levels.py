"""Per-env difficulty levels: :class:`DifficultyLevels` moves each env's level at its episode ends.

Each env of a batch has an integer level in ``[0, num_levels - 1]`` that persists across its episodes.
When an env's episode ends, a rule decides the change: by default up one level after an episode that
ends in success and down one after one that ends in failure (the flags of its last step, as the
:class:`~torchtasks.transforms.TaskTransform` writes them); any rule of the step's data can replace
it, e.g. the distance walked, as mjlab's terrain levels. The level changes at that env's episode ends
only: never at a reset (so not at the first one, mjlab #1094), never for the other envs, and not
because some other env ended its episode (IsaacLab #2079 computes curriculum terms only when an env
resets; here a level is a per-env fact of that env's episodes).

The level drives per-env values through tables, one row per level: the sampling range of a
:class:`~torchtasks.transforms.GoalCommand` (``"command.low"``/``"command.high"``: goals near at level 0,
the full space at the top), a per-env float buffer of the task tree or of the base env. The levels are
a registered buffer (``state_dict()``, and so TorchRL's ``Collector.state_dict()``, restores them).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torch import nn
from torchrl.data import Bounded, Composite, Unbounded

from torchtasks._checked_load import CheckedLoad
from torchtasks._checks import check_non_negative_int, check_positive_int
from torchtasks._memory import td_set
from torchtasks._torchrl import container_env, key_parts, keys_text, nested_key
from torchtasks.transforms.names import COMMAND, CURRICULUM_KEY, DOMAIN, FRAMES, LEVEL, entry_name, respelt_entries
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
    find_placement,
    resolve_targets,
)
from torchtasks.transforms.task import RecordedValue

__all__ = ["DifficultyLevels", "LevelRule"]

#: ``rule(tensordict, next_tensordict) -> change``: the level change of every env (an integer tensor ``[*B]`` or
#: ``[*B, 1]``), applied where the env's episode ended in this step
LevelRule = Callable[[TensorDictBase, TensorDictBase], torch.Tensor]


def _table(values: object, num_levels: int, name: str) -> torch.Tensor:
    """``values`` as a float64 table ``[num_levels, *value_shape]`` (one row per level), rejecting NaN."""
    if isinstance(values, torch.Tensor):
        table = values.detach().to(torch.float64).clone()
    else:
        try:
            table = torch.as_tensor(values, dtype=torch.float64).clone()
        except (TypeError, ValueError, RuntimeError) as error:
            raise TypeError(
                f"DifficultyLevels: the values of {name!r} must be one value per level (a sequence or a tensor of "
                f"numbers with a first dim of {num_levels}), got {values!r}"
            ) from error
    if table.dim() == 0 or table.shape[0] != num_levels:
        raise ValueError(
            f"DifficultyLevels: the values of {name!r} must have one row per level, shape [{num_levels}, ...], got "
            f"shape {list(table.shape)}"
        )
    if torch.isnan(table).any():
        raise ValueError(f"DifficultyLevels: the values of {name!r} must not contain NaN, got {table.tolist()}")
    return table


class DifficultyLevels(CheckedLoad, TargetWriter):
    """Keep an integer difficulty level per env, moved at that env's episode ends; set per-env values from it.

    Place it after the :class:`~torchtasks.transforms.TaskTransform` of the env and before the
    :class:`~torchtasks.transforms.GoalCommand` whose range it sets (in the same ``Compose``). At every step, for each
    env whose episode ended (its ``done`` flag), the level moves by the rule's change, clamped to
    ``[0, num_levels - 1]``; by default ``success - failure`` of the step's flags (up after a success, down after a
    failure, unchanged after a truncation). Resets never change a level. ``values`` maps targets to tables with one
    row per level; after every step and before every reset each env's row, ``table[level]``, is written into the
    target: the GoalCommand's range (``"command.low"``/``"command.high"``, made per env), or a float buffer of the
    task tree or of the base env (``"env.<name>"``) that holds one value per env. A misspelt target, a table of the
    wrong shape, a range that leaves the goal space and a target a Curriculum also schedules are a ``ValueError``
    when the env's specs are built. It writes ``(curriculum_key, "level")`` (int64 ``[*B, 1]``: at the root of a step
    the level the step was played at) and each env's row of every task-tree and base-env target; ``level`` is a
    registered buffer (``state_dict()``). The docs page "Curriculum" has the rules in full.

    Args:
        num_levels: the number of levels (levels ``0 .. num_levels - 1``).
        values: ``{target: table}``, one row per level.
        initial_level: every env's level at the start.
        rule: ``rule(tensordict, next_tensordict) -> change`` (integer ``[*B]`` or ``[*B, 1]``), read at every step
            and applied where the episode ended; ``None``: ``success - failure``.
        success_key, failure_key: the flags of the default rule; ``None``: the TaskTransform's.
        curriculum_key: where the ``"level"`` entry is written (a Curriculum's key may be shared).

    Example:
        >>> import functools, torch
        >>> from torchrl.envs import Compose, StepCounter, TransformedEnv
        >>> from torchtasks.envs import PointMassEnv
        >>> from torchtasks.rewards import ConstantReward
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> from torchtasks.tasks import DesiredStateTask, MaskedTask, proximity_succeeded
        >>> from torchtasks.transforms import DifficultyLevels, GoalCommand, TaskTransform
        >>> spec = EnvSpec(Box([-1.0] * 4, [1.0] * 4, labels=["x", "y", "vx", "vy"]), 2)
        >>> near = functools.partial(proximity_succeeded, threshold=0.1)
        >>> reach = DesiredStateTask(spec.select_state(["x", "y"]), [0.0, 0.0], ConstantReward(-1.0), near)
        >>> levels = DifficultyLevels(3, {  # goals within 0.2, 0.6, then 1.0 of the origin
        ...     "command.low": [[-0.2, -0.2], [-0.6, -0.6], [-1.0, -1.0]],
        ...     "command.high": [[0.2, 0.2], [0.6, 0.6], [1.0, 1.0]]})
        >>> env = TransformedEnv(PointMassEnv(batch_size=[4], seed=0), Compose(
        ...     StepCounter(20), TaskTransform(MaskedTask(spec, reach, ["x", "y"]), goal_key="goal"), levels,
        ...     GoalCommand(Box([-1.0, -1.0], [1.0, 1.0]), seed=0)))
        >>> data = env.rollout(40, break_when_any_done=False)
        >>> ended = data["next", "done"]  # levels move only at an episode's last step
        >>> moved = data["next", "curriculum", "level"] != data["curriculum", "level"]
        >>> bool((moved <= ended).all())
        True
    """

    def __init__(
        self,
        num_levels: int,
        values: Mapping[str, object] | None = None,
        *,
        initial_level: int = 0,
        rule: LevelRule | None = None,
        success_key: NestedKey | None = None,
        failure_key: NestedKey | None = None,
        curriculum_key: NestedKey = CURRICULUM_KEY,
    ) -> None:
        self.num_levels = check_positive_int(num_levels, "DifficultyLevels: num_levels")
        self.initial_level = check_non_negative_int(initial_level, "DifficultyLevels: initial_level")
        if self.initial_level >= self.num_levels:
            raise ValueError(
                f"DifficultyLevels: initial_level must be in [0, {self.num_levels - 1}] (num_levels={num_levels}), "
                f"got {initial_level}"
            )
        values = {} if values is None else values
        if not isinstance(values, Mapping):
            raise TypeError(f"DifficultyLevels: values must be a mapping {{target: table}}, got {values!r}")
        for target in values:
            if not isinstance(target, str):
                raise TypeError(f"DifficultyLevels: targets must be buffer names (strings), got {target!r}")
        if rule is not None and not callable(rule):
            raise TypeError(f"DifficultyLevels: rule must be callable or None, got {type(rule).__name__}")
        self.rule = rule
        self.success_key = None if success_key is None else nested_key(success_key, "DifficultyLevels: success_key")
        self.failure_key = None if failure_key is None else nested_key(failure_key, "DifficultyLevels: failure_key")
        self.curriculum_key = nested_key(curriculum_key, "DifficultyLevels: curriculum_key")
        self._level_key = (*key_parts(self.curriculum_key), LEVEL)
        entries = [entry_name(target) for target in values]  # each target's name in the data and the state
        if len(set(entries)) < len(entries):
            raise ValueError(
                f"DifficultyLevels: targets {list(values)} give the same entry name twice ('.' becomes '/')"
            )
        # the entries recording the per-env value of each task-tree and base-env target, by target index
        self.__dict__["_value_keys"] = {
            i: (*key_parts(self.curriculum_key), entry)
            for i, (target, entry) in enumerate(zip(values, entries, strict=True))
            if not target.startswith(COMMAND + ".")
        }
        for key in self._value_keys.values():
            if key[-1] in (LEVEL, FRAMES):
                raise ValueError(
                    f"DifficultyLevels: a target may not be named {key[-1]!r}: its per-env values would be written "
                    f"over the entry {key!r} (the levels, or a Curriculum's frame count)"
                )
        super().__init__(in_keys=[], out_keys=[self._level_key, *self._value_keys.values()])
        self.targets = tuple(values)
        # one buffer per target, named by its entry: a checkpoint is keyed by target, not by position
        self._entries = entries
        self.tables = nn.Module()
        for target, entry in zip(self.targets, self._entries, strict=True):
            self.tables.register_buffer(entry, _table(values[target], self.num_levels, target))
        self.register_buffer("level", torch.zeros(0, dtype=torch.int64))

    def _table(self, index: int) -> torch.Tensor:
        """The table of the ``index``-th target, ``[num_levels, *value_shape]``."""
        return self.tables._buffers[self._entries[index]]

    # ------------------------------------------------------------------ state
    def _check_saved(self, state_dict: dict, prefix: str) -> None:
        self._check_saved_tables(state_dict, prefix)
        saved = state_dict.get(prefix + "level")
        if isinstance(saved, torch.Tensor):
            if saved.dtype != torch.int64 or (saved.numel() > 0 and bool((saved < 0).any())):
                raise ValueError(
                    f"DifficultyLevels.load_state_dict: 'level' must be a non-negative int64 tensor, got {saved}"
                )
            if (saved >= self.num_levels).any():
                raise ValueError(
                    f"DifficultyLevels.load_state_dict: saved levels reach {int(saved.max())}, but num_levels is "
                    f"{self.num_levels}"
                )

    def _prepare_load(self, state_dict: dict, prefix: str) -> None:
        saved = state_dict.get(prefix + "level")
        if isinstance(saved, torch.Tensor) and saved.shape != self.level.shape:  # levels saved by an env of batch B
            self.level = torch.zeros_like(saved, device=self.level.device)  # load before this one's specs exist
        self._forget_setup()

    def _check_saved_tables(self, state_dict: dict, prefix: str) -> None:
        """Refuse a checkpoint whose tables are not this one's: other targets or shapes (levels, value shape)."""
        head = prefix + "tables."
        saved = {key[len(head) :]: value for key, value in state_dict.items() if key.startswith(head)}
        own = dict(self.tables.named_buffers())
        if set(saved) != set(own):  # a non-strict load of a partial state dict has ours in place of the missing
            raise ValueError(
                "DifficultyLevels.load_state_dict: the checkpoint sets other targets than this DifficultyLevels: "
                f"saved {sorted(saved)}, here {sorted(own)} (the targets with '/' for '.'; loaded by target, "
                "in any order, never by position). Build it with the saved targets"
                + respelt_entries(set(saved) - set(own), set(own) - set(saved))
            )
        for entry in sorted(set(saved) & set(own)):
            if isinstance(saved[entry], torch.Tensor) and saved[entry].shape != own[entry].shape:
                raise ValueError(
                    f"DifficultyLevels.load_state_dict: the table of {entry!r} has shape {list(own[entry].shape)} here "
                    f"([num_levels={self.num_levels}, *value_shape]), but {list(saved[entry].shape)} in the checkpoint"
                )

    def _check_loaded(self) -> None:
        """Run the set-up checks on the loaded tables and levels (ranges in the goal space, values a target refuses)."""
        self._forget_setup()
        env = container_env(self)
        if env is not None and self.home_transforms() is not None:  # else checked when the env's specs are built
            self._setup(env.batch_size)
            self._write_run_values()  # each env's row into its targets before the next step reads them

    # ------------------------------------------------------------------ setup
    def _forget_setup(self) -> None:
        self.__dict__.pop("_resolved", None)

    def _setup(self, batch: torch.Size) -> list[Target]:
        """Resolve the targets, make the levels and the command ranges per env; cached until the env changes."""
        targets = self.__dict__.get("_resolved")
        if targets is not None:
            return targets
        placement = find_placement(self)
        if self.rule is None:
            task_transform = placement.task_transform
            flags = (self.success_key or task_transform.success_key, self.failure_key or task_transform.failure_key)
            for argument, key in zip(("success_key", "failure_key"), flags, strict=True):
                reason = task_transform.undefined_flag(key)
                if reason is not None:  # the default rule moves up on success and down on failure: it needs both
                    raise ValueError(
                        f"DifficultyLevels: the default rule (a level up on success, down on failure) reads "
                        f"{argument}={key!r}, but {reason}; pass rule=... with the level change your task can "
                        "decide, or a task with both outcomes"
                    )
            self.__dict__["_flags"] = flags
        if self.level.numel() == 0:
            self.level = torch.full(batch, self.initial_level, dtype=torch.int64, device=self.level.device)
        elif self.level.shape != batch:
            raise ValueError(
                f"DifficultyLevels: the levels (loaded) have shape {list(self.level.shape)}, but the env's batch is "
                f"{list(batch)}"
            )
        rows = [self._table(i).shape[1:] for i in range(len(self.targets))]
        targets = resolve_targets(self, self.targets, rows, batch=batch, rows=self.num_levels, env_fields=True).targets
        for i, target in enumerate(targets):  # every level's row, as the reward's constructor would check the value
            if target.source != DOMAIN:  # a distribution's values: with its other writers' (check_domain_writes)
                levels = [f"DifficultyLevels: level {level} of {target.name!r}" for level in range(self.num_levels)]
                target.check_values(self._table(i), levels)
        self._check_ranges(targets)
        self.__dict__["_resolved"] = targets  # what written_targets() answers while the env's other writers are asked
        try:
            check_one_owner(self, targets, placement, " (schedule the level tables' rows instead)")
            check_domain_writes(self, placement)
        except ValueError:
            self._forget_setup()
            raise
        return targets

    def _check_ranges(self, targets: list[Target]) -> None:
        """Refuse a level's range that leaves the command's Box or has ``low > high``."""
        for command, bounds in command_ranges(targets).items():
            for leaf, i in bounds.items():
                table = self._table(i)
                rows = [f"level {level}'s row {row}" for level, row in enumerate(table.tolist())]
                check_in_goal_space(targets[i], table, f"DifficultyLevels: the {leaf} bound of the levels", rows)
            current = {  # the bound no table sets: the command's range (env 0's, if already per env)
                leaf: getattr(command, leaf).to("cpu", torch.float64).reshape(-1, command.goal_size)[:1]
                for leaf in ("low", "high")
            }
            low = self._table(bounds["low"]) if "low" in bounds else current["low"]
            high = self._table(bounds["high"]) if "high" in bounds else current["high"]
            low, high = torch.broadcast_tensors(low.to("cpu"), high.to("cpu"))
            where = f"of the GoalCommand writing {command.goal_key!r}"
            levels = [f"DifficultyLevels: level {level} {where}" for level in range(len(low))]
            check_low_not_above_high(zip(low, high, strict=True), levels)

    def domain_writes(self) -> list[DomainWrites]:
        """The rows of values the level tables write into each domain distribution among the targets: level ``k`` of
        every table of one distribution together, each level for any env."""
        targets = self.written_targets()
        groups: dict[int, list[int]] = {}
        for i, target in enumerate(targets):
            if target.source == DOMAIN:
                groups.setdefault(id(target.module), []).append(i)
        writes = []
        for indices in groups.values():
            names = " and ".join(repr(targets[i].name) for i in indices)
            labels = tuple(f"level {level} of {names}" for level in range(self.num_levels))
            values = {targets[i].buffer: self._table(i) for i in indices}
            writes.append(DomainWrites(targets[indices[0]].module, "DifficultyLevels", values, labels))
        return writes

    def recorded_task_values(self) -> list[RecordedValue]:
        """The task-tree targets, each with the entry recording every env's value of the step (one row of its
        table); offline recomputation with the env's TaskTransform reads them."""
        targets = self.written_targets()  # by the buffer's full name: a target may be written by its short name
        return [
            RecordedValue(targets[i].path, key, self._table(i).shape[1:])
            for i, key in self._value_keys.items()
            if targets[i].source == TASK
        ]

    def written_targets(self) -> list[Target]:
        """The targets these levels write, resolved in their env (``ValueError`` if one is refused).

        Example:
            >>> import functools
            >>> from torchrl.envs import Compose, TransformedEnv
            >>> from torchtasks.envs import PointMassEnv
            >>> from torchtasks.rewards import ConstantReward
            >>> from torchtasks.spaces import Box, EnvSpec
            >>> from torchtasks.tasks import DesiredStateTask, MaskedTask, proximity_succeeded
            >>> from torchtasks.transforms import DifficultyLevels, GoalCommand, TaskTransform
            >>> spec = EnvSpec(Box([-1.0] * 4, [1.0] * 4, labels=["x", "y", "vx", "vy"]), 2)
            >>> near = functools.partial(proximity_succeeded, threshold=0.1)
            >>> reach = DesiredStateTask(spec.select_state(["x", "y"]), [0.0, 0.0], ConstantReward(-1.0), near)
            >>> levels = DifficultyLevels(2, {"command.high": [[0.5, 0.5], [1.0, 1.0]]})
            >>> env = TransformedEnv(PointMassEnv(batch_size=[3]), Compose(
            ...     TaskTransform(MaskedTask(spec, reach, ["x", "y"]), goal_key="goal"), levels,
            ...     GoalCommand(Box([-1.0, -1.0], [1.0, 1.0]))))
            >>> [(target.name, target.buffer, target.per_env) for target in levels.written_targets()]
            [('command.high', 'high', True)]
            >>> env.transform[-1].high.shape  # the GoalCommand's range, made per env
            torch.Size([3, 2])
        """
        env = container_env(self)
        if env is None:
            find_placement(self)  # raises: not in an env
        return self._setup(env.batch_size)

    # ------------------------------------------------------------------ specs
    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        batch, device = observation_spec.shape, observation_spec.device
        targets = self._setup(batch)
        observation_spec[self._level_key] = Bounded(
            low=0, high=self.num_levels - 1, shape=(*batch, 1), dtype=torch.int64, device=device
        )
        for i, key in self._value_keys.items():
            shape = (*batch, *self._table(i).shape[1:])
            observation_spec[key] = Unbounded(shape=shape, dtype=targets[i].value.dtype, device=device)
        return observation_spec

    # ------------------------------------------------------------------ TorchRL hooks
    def _write_levels(self, tensordict: TensorDictBase, replace: bool) -> TensorDictBase:
        """Write each env's row of every table into its target, and the levels and the rows set (but a GoalCommand's
        range: the goal drawn is in the data) into ``tensordict``."""
        targets = self._setup(tensordict.batch_size)  # first: it creates the levels at the first call
        level = self.level
        value_keys = self._value_keys
        for i, target in enumerate(targets):
            buffer = target.module._buffers[target.buffer]
            table = self._table(i)
            if table.dtype != buffer.dtype or table.device != buffer.device:
                table = table.to(device=buffer.device, dtype=buffer.dtype)
            value = table[level.to(table.device)]
            target.write(value, replace=replace)  # under grad mode a copy takes the buffer's place
            if i in value_keys:  # a new tensor: never written into afterwards (the buffer holds a copy of it)
                td_set(tensordict, value_keys[i], value)
        td_set(tensordict, self._level_key, level.unsqueeze(-1).clone())
        return tensordict

    def _change(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> torch.Tensor:
        batch = next_tensordict.batch_size
        if self.rule is None:
            success_key, failure_key = self.__dict__["_flags"]
            success = next_tensordict.get(success_key, None)
            failure = next_tensordict.get(failure_key, None)
            for argument, key, flag in (("success_key", success_key, success), ("failure_key", failure_key, failure)):
                if flag is None:
                    raise ValueError(
                        f"DifficultyLevels: {argument}={key!r} is not an entry of the step's data under 'next' "
                        f"(its entries: {keys_text(next_tensordict.keys(True, True))})"
                    )
                if flag.dtype != torch.bool:  # a float entry would be truncated to 0 or 1 per env
                    raise TypeError(
                        f"DifficultyLevels: {argument}={key!r} must name a bool flag, got an entry of {flag.dtype}"
                    )
            return success.reshape(batch).to(torch.int64) - failure.reshape(batch).to(torch.int64)
        change = self.rule(tensordict, next_tensordict)
        if (
            not isinstance(change, torch.Tensor)
            or change.dtype.is_floating_point
            or change.dtype == torch.bool
            or change.dtype.is_complex
            or tuple(change.shape) not in (tuple(batch), (*batch, 1))
        ):
            shape = list(change.shape) if isinstance(change, torch.Tensor) else None
            raise ValueError(
                f"DifficultyLevels: the rule must return an integer tensor of shape {list(batch)} or "
                f"{[*batch, 1]} (each env's level change), got "
                f"{type(change).__name__ if shape is None else f'{change.dtype} {shape}'}"
            )
        return change.reshape(batch).to(torch.int64)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        replace = torch.is_grad_enabled()
        with torch.no_grad():
            return self._write_levels(tensordict_reset, replace)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        replace = torch.is_grad_enabled()
        with torch.no_grad():
            self._setup(next_tensordict.batch_size)
            done = next_tensordict.get("done").reshape(next_tensordict.batch_size)
            change = self._change(tensordict, next_tensordict).to(self.level.device)
            moved = self.level + torch.where(done.to(self.level.device), change, torch.zeros_like(change))
            self.level.copy_(moved.clamp(0, self.num_levels - 1))
            return self._write_levels(next_tensordict, replace)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Leave stored data as it is: levels follow the collection, not replayed transitions."""
        return tensordict

    def extra_repr(self) -> str:
        return f"num_levels={self.num_levels}, targets={list(self.targets)}"

    def __repr__(self) -> str:
        return f"{type(self).__name__}(num_levels={self.num_levels}, targets={list(self.targets)})"
