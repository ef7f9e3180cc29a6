"""The one target resolver: where a value of the run goes, the checks it passes, and its write.

A transform that writes values of the run into an env (a :class:`~torchtasks.transforms.Curriculum`'s
schedules, the level tables of :class:`~torchtasks.transforms.DifficultyLevels`) names each target by a
string. :func:`resolve_targets` turns the names into :class:`Target`\\ s once, when the env's specs are built:

- a float buffer of the task tree, as ``task.named_buffers()`` names it (``"wrapped_task.reward.Q"``);
- a buffer of a :class:`~torchtasks.transforms.GoalCommand`'s sampling range, ``"command.low"`` /
  ``"command.high"`` with one GoalCommand in the env, ``"command.<goal key>.low"`` (a nested goal key joined by
  ``"/"``) always;
- with ``env_fields=True``, a float buffer of the base env as ``"env.<name>"``;
- a distribution parameter of a :class:`~torchtasks.transforms.DomainRandomization`'s param,
  ``"domain.<field>.<parameter>"`` (``"domain.body_mass_scale.halfspan"``).

A misspelt name is refused with one message listing every name the writer can set. A :class:`Target` checks
the values a writer may put into it (:meth:`Target.check_values`: the rules of a reward's constants and of a
domain distribution, whose draws must stay in the env's field; :func:`check_in_goal_space` and
:func:`check_low_not_above_high` for a GoalCommand's range) and writes one (:meth:`Target.write`). A
:class:`TargetWriter` answers which targets it writes, so that a buffer has one owner (:func:`check_one_owner`).
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Iterable, Sequence
from typing import NamedTuple

import torch
from torch import nn
from torchrl.envs.transforms import Transform, TransformedEnv

from torchtasks._checks import did_you_mean
from torchtasks._torchrl import container_env, flat_transforms, key_parts
from torchtasks.rewards import RewardFunction
from torchtasks.rewards.base import check_written_value
from torchtasks.transforms._base import EnvDerivedTransform, ResetWritingTransform
from torchtasks.transforms.command import GoalCommand
from torchtasks.transforms.domain import DomainRandomization
from torchtasks.transforms.names import (
    COMMAND,
    DOMAIN,
    ENV,
    entry_name,
    names_task_buffer,
    short_names,
    suffix_matches,
)
from torchtasks.transforms.task import RecordedValue, TaskTransform, buffer_owner

__all__ = [
    "TASK",
    "DomainWrites",
    "Placement",
    "ResolvedTargets",
    "Target",
    "TargetRow",
    "TargetTable",
    "TargetWriter",
    "check_domain_writes",
    "check_in_goal_space",
    "check_low_not_above_high",
    "check_one_owner",
    "check_written_together",
    "command_ranges",
    "find_placement",
    "resolve_targets",
    "target_names",
]

#: the source of a target in the task tree (the others are :data:`~torchtasks.transforms.names.COMMAND`,
#: :data:`~torchtasks.transforms.names.ENV` and :data:`~torchtasks.transforms.names.DOMAIN`, the prefixes of their
#: names)
TASK = "task"


class Target(NamedTuple):
    """A value of the run's destination: the buffer a name resolves to (:func:`resolve_targets`).

    Example:
        >>> import torch
        >>> from torchtasks.rewards import QuadraticErrorReward
        >>> reward = QuadraticErrorReward([1.0, 0.5])
        >>> target = Target("reward.Q", reward, "Q", TASK, torch.Size([2]), per_env=False)
        >>> target.entry
        'reward/Q'
        >>> target.check_values(torch.tensor([[1.0, 2.0]]), "a schedule")  # a weight the reward accepts
        >>> target.write(torch.tensor([2.0, 1.0], dtype=torch.float64), replace=False).tolist()
        [2.0, 1.0]
    """

    #: the name as the user wrote it
    name: str
    #: the module holding the buffer: a module of the task tree, a GoalCommand, the base env or a DomainParam
    module: nn.Module
    #: the buffer's name in ``module`` (``"Q"``, a GoalCommand's ``"low"`` or ``"high"``)
    buffer: str
    #: where it lives: :data:`TASK`, ``"command"``, ``"env"`` or ``"domain"``
    source: str
    #: the shape of one written value: the buffer's shape, or one env's row of a per-env buffer
    value_shape: torch.Size
    #: whether the buffer holds one value per env (``[*B, *value_shape]``)
    per_env: bool
    #: the name ``name`` stands for: a task-tree buffer's ``task.named_buffers()`` name when ``name`` is a short name
    #: of it; ``""``: ``name`` itself
    full_name: str = ""

    @property
    def path(self) -> str:
        """The target's full name: :attr:`full_name`, or :attr:`name` when that is empty."""
        return self.full_name or self.name

    @property
    def entry(self) -> str:
        """The entry's name under ``curriculum_key`` (:func:`~torchtasks.transforms.names.entry_name`)."""
        return entry_name(self.name)

    @property
    def value(self) -> torch.Tensor:
        """The buffer's tensor now (a write under grad mode puts a new one in its place)."""
        return self.module._buffers[self.buffer]

    def check_values(self, values: Iterable[torch.Tensor], writer: str | Sequence[str]) -> None:
        """Refuse a value the target's reward would refuse at construction (e.g. a negative cost weight).

        Args:
            values: the values the writer may put into the target, each of :attr:`value_shape` or broadcastable to
                it (a scalar); e.g. a schedule's values at its breakpoints, a table's rows.
            writer: who writes the values, for the message: one string, or one per value.
        """
        if isinstance(self.module, RewardFunction):
            check = functools.partial(check_written_value, self.module)
        else:  # a module that states its own rule (a distribution, reward groups), or none
            check = getattr(self.module, "check_written_value", None)
            if check is None:
                return
        shape = self.value.shape
        for i, value in enumerate(values):
            label = writer if isinstance(writer, str) else writer[i]
            check(self.buffer, value if self.per_env else value.expand(shape), label)

    def write(self, value: torch.Tensor | float, *, replace: bool) -> torch.Tensor:
        """Write ``value`` into the buffer and return the buffer that holds it.

        ``value``: a tensor of the buffer's dtype and device, broadcastable to its shape, or a Python float (every
        element). ``replace=False``: ``copy_`` (``fill_``) into the buffer, as under ``no_grad`` in a collector.
        ``replace=True``: put a new tensor in the buffer's place, so that the autograd graph of earlier steps (a
        differentiable ``env.rollout``) keeps the values it saved.
        """
        buffer = self.module._buffers[self.buffer]
        if isinstance(value, float):
            if not replace:
                return buffer.fill_(value)
            buffer = torch.full_like(buffer, value)
        elif not replace:
            return buffer.copy_(value)
        else:
            buffer = value.expand_as(buffer).clone()
        self.module._buffers[self.buffer] = buffer
        return buffer


class Placement(NamedTuple):
    """Where a writer sits: the leaf transforms of its env, its index among them, the TaskTransform before it."""

    transforms: list[Transform]
    position: int
    task_transform: TaskTransform


class ResolvedTargets(NamedTuple):
    """The answer of :func:`resolve_targets`: the writer's placement and one :class:`Target` per name."""

    placement: Placement
    targets: list[Target]


class TargetWriter(ResetWritingTransform):
    """A transform that writes values of the run into :class:`Target`\\ s of its env.

    Subclasses answer :meth:`written_targets` (resolved, e.g. for :func:`check_one_owner`) and
    :meth:`recorded_task_values` (the task buffers whose every step's value they record, which offline
    recomputation with the env's :class:`~torchtasks.transforms.TaskTransform` reads).
    """

    def written_targets(self) -> list[Target]:
        """The targets this transform writes, resolved in its env (``ValueError`` if one is refused)."""
        raise NotImplementedError

    def recorded_task_values(self) -> list[RecordedValue]:
        """The task-tree buffers this transform sets at every step, each with the entry recording its values."""
        raise NotImplementedError

    def domain_writes(self) -> list[DomainWrites]:
        """What this transform can write into each domain distribution among its targets (for
        :func:`check_domain_writes`), resolved in its env."""
        raise NotImplementedError


def find_placement(writer: EnvDerivedTransform) -> Placement:
    """The env's transforms around ``writer``, which must come after exactly one TaskTransform.

    Example:
        >>> from torchrl.envs import Compose, TransformedEnv
        >>> from torchtasks.envs import PendulumEnv, swing_up_task
        >>> from torchtasks.transforms import Curriculum, TaskTransform, constant
        >>> curriculum = Curriculum({"success_value": constant(1.0)})
        >>> env = TransformedEnv(PendulumEnv(batch_size=[2]), Compose(TaskTransform(swing_up_task()), curriculum))
        >>> find_placement(curriculum).position
        1
    """
    who = type(writer).__name__
    home = writer.home_transforms()
    if home is None:
        raise ValueError(f"{who} must sit in a TransformedEnv, after the TaskTransform whose task it sets")
    flat, position = home
    tasks = [t for t in flat[:position] if isinstance(t, TaskTransform)]
    if len(tasks) != 1:
        after = any(isinstance(t, TaskTransform) for t in flat[position:])
        raise ValueError(
            f"{who} must come after exactly one TaskTransform in its env, found {len(tasks)} before it"
            + (f" (put {who} after TaskTransform in the Compose)" if after and not tasks else "")
        )
    return Placement(flat, position, tasks[0])


class _Candidate(NamedTuple):
    """A name a writer can set: the module whose ``named_buffers()`` names it, the buffer's name there, its source."""

    root: nn.Module
    path: str
    source: str


class _Choices(NamedTuple):
    """The names a writer can set, the short command names that several GoalCommands share (with their qualified
    choices), the names an error lists, and the task tree's float buffer names (which a dotted suffix may stand for,
    :func:`~torchtasks.transforms.names.suffix_matches`)."""

    named: dict[str, _Candidate]
    ambiguous: dict[str, list[str]]
    listed: list[str]
    task_names: list[str]


def _choices(
    who: str, task: nn.Module, transforms: Sequence[Transform], base_env: nn.Module | None, names: Sequence[str]
) -> _Choices:
    """Every name a writer can set in an env: the task tree's float buffers, with ``base_env`` its float buffers as
    ``"env.<name>"``, the distribution parameters of the DomainRandomizations and the ranges of the GoalCommands among
    ``transforms``. The one walk of the targets: writers resolve through it, :func:`target_names` lists it."""
    named = {name: _Candidate(task, name, TASK) for name, buffer in task.named_buffers() if buffer.is_floating_point()}
    task_names = list(named)
    listed = sorted(named)
    if base_env is not None:
        fields = {
            f"{ENV}.{n}": _Candidate(base_env, n, ENV) for n, b in base_env.named_buffers() if b.is_floating_point()
        }
        named.update(fields)
        listed += sorted(fields)
    for randomization in (t for t in transforms if isinstance(t, DomainRandomization)):
        for name, _ in randomization.params.named_buffers():
            named[f"{DOMAIN}.{name}"] = _Candidate(randomization.params, name, DOMAIN)
            listed.append(f"{DOMAIN}.{name}")
    commands = [t for t in transforms if isinstance(t, GoalCommand)]
    goal_keys = [command.goal_key for command in commands]
    if len(set(goal_keys)) < len(goal_keys) and any(name.startswith(COMMAND + ".") for name in names):
        raise ValueError(
            f"{who}: several GoalCommands of the env write the same goal key (goal keys "
            f"{goal_keys}): their {COMMAND + '.'!r} targets cannot be told apart"
        )
    short: dict[str, list[str]] = {}
    for command in commands:
        qualifier = "/".join(key_parts(command.goal_key))
        for leaf, buffer in command.named_buffers(recurse=False):
            if buffer.is_floating_point():
                named[f"{COMMAND}.{qualifier}.{leaf}"] = _Candidate(command, leaf, COMMAND)
                short.setdefault(f"{COMMAND}.{leaf}", []).append(f"{COMMAND}.{qualifier}.{leaf}")
    if len(commands) == 1:
        named.update({name: named[full] for name, (full,) in short.items()})
        return _Choices(named, {}, listed + sorted(short), task_names)
    qualified = sorted(choice for choices in short.values() for choice in choices)
    return _Choices(named, short, listed + qualified, task_names)


def _writer_choices(
    writer: EnvDerivedTransform, placement: Placement, env_fields: bool, names: Sequence[str]
) -> _Choices:
    base = container_env(writer).base_env if env_fields else None
    return _choices(type(writer).__name__, placement.task_transform.task, placement.transforms, base, names)


def _full_names(
    writer: EnvDerivedTransform, placement: Placement, choices: _Choices, names: Sequence[str], env_fields: bool
) -> list[str]:
    """The name each of ``names`` stands for (itself, or the task-tree name a dotted suffix stands for alone); the one
    message for a name that is no target, one that is ambiguous, and two names of one target."""
    who = type(writer).__name__
    for name in names:
        if name in choices.ambiguous:
            raise ValueError(
                f"{who}: the target {name!r} is ambiguous: the env has several GoalCommands; name one of "
                f'{choices.ambiguous[name]} ("{COMMAND}.<goal key>.<buffer>")'
            )
    full: list[str | None] = []
    for name in names:
        if name in choices.named:
            full.append(name)
            continue
        matches = suffix_matches(name, choices.task_names) if names_task_buffer(name) else []
        if len(matches) > 1:
            aliases = short_names(choices.task_names)
            listed = " or ".join(repr(aliases[match]) for match in matches)
            raise ValueError(
                f"{who}: the target {name!r} is ambiguous: it ends {len(matches)} buffer names of the task tree, "
                f"{matches}; did you mean {listed}? (a short name must end one name only)"
            )
        full.append(matches[0] if matches else None)
    unknown = [name for name, found in zip(names, full, strict=True) if found is None]
    if unknown:
        _refuse_unknown(who, placement, choices, unknown, env_fields)
    seen: dict[tuple[int, str], str] = {}
    for name, found in zip(names, full, strict=True):
        candidate = choices.named[found]
        first = seen.setdefault((id(candidate.root), candidate.path), name)
        if first != name:
            raise ValueError(
                f"{who}: {first!r} and {name!r} name the same target ({candidate.source} buffer "
                f"{candidate.path!r}); name it once"
            )
    return full


def _refuse_unknown(
    who: str, placement: Placement, choices: _Choices, unknown: Sequence[str], env_fields: bool
) -> None:
    """The one message for names that are no target: every name the writer can set, and the closest one."""
    commands = [t for t in placement.transforms if isinstance(t, GoalCommand)]
    samplers = [repr(c.goal_key) for c in commands if not any(b.is_floating_point() for b in c.buffers(False))]
    where = f"the {type(placement.task_transform.task).__name__} tree" + (", the base env" if env_fields else "")
    if commands:
        where += " or the env's GoalCommands"
    elif any(name.startswith(COMMAND + ".") for name in unknown):
        where += " (the env has no GoalCommand)"
    if samplers:
        where += f" (the GoalCommand(s) writing {', '.join(samplers)} sample with a callable: no range to set)"
    if any(isinstance(t, DomainRandomization) for t in placement.transforms):
        where += " or the env's DomainRandomizations"
    elif any(name.startswith(DOMAIN + ".") for name in unknown):
        where += " (the env has no DomainRandomization)"
    legend = "float buffers are named as named_buffers() names them"
    legend += f", those of the base env under {ENV + '.'!r}" if env_fields else ""
    aliases = [alias for full, alias in short_names(choices.task_names).items() if alias != full]
    raise ValueError(
        f"{who}: unknown target {unknown[0]!r}{did_you_mean(unknown[0], choices.listed + aliases) or '.'} "
        + (f"(Also unknown: {unknown[1:]}.) " if len(unknown) > 1 else "")
        + f"It is not in {where}; the names {who} can set are {choices.listed} ({legend}, a GoalCommand's "
        f"sampling range under {COMMAND + '.'!r}, a domain distribution under {DOMAIN + '.<field>.'!r}; a task "
        "buffer also by a dotted suffix that ends its name only, e.g. its short name that "
        "torchtasks.transforms.target_names(env) lists)"
    )


def resolve_targets(
    writer: EnvDerivedTransform,
    names: Sequence[str],
    value_shapes: Sequence[torch.Size],
    *,
    batch: torch.Size | None = None,
    rows: int | None = None,
    env_fields: bool = False,
) -> ResolvedTargets:
    """Resolve the target names of ``writer`` in its env: one :class:`Target` per name, shapes checked.

    A GoalCommand's range must come after ``writer`` (the goal drawn in a step uses that step's range); a
    DomainRandomization's distribution before it (the randomization draws in TorchRL's pre-reset hook, which runs the
    transforms last to first: the writer's values of the reset are written before the draw).

    Args:
        writer: the transform that writes the values; it must come after exactly one TaskTransform.
        names: the targets, as the user wrote them.
        value_shapes: the shape of the values written into each target. A value shared by all envs has the
            buffer's shape or ``()``; with ``batch``, one env's row.
        batch: the env's batch for per-env values: a task-tree or base-env buffer must then hold one value per env
            (``[*batch, *row]``), and a GoalCommand's range is made per env
            (:meth:`~torchtasks.transforms.GoalCommand.use_per_env_range`). ``None``: one value for all envs.
        rows: how many rows the writer's values have (e.g. levels), for the messages; ``None`` for none.
        env_fields: whether ``"env.<name>"`` names a float buffer of the base env.

    Example:
        >>> import torch
        >>> from torchrl.envs import Compose, TransformedEnv
        >>> from torchtasks.envs import PendulumEnv, swing_up_task
        >>> from torchtasks.transforms import Curriculum, TaskTransform, constant
        >>> curriculum = Curriculum({"success_value": constant(1.0)})
        >>> env = TransformedEnv(PendulumEnv(batch_size=[2]), Compose(TaskTransform(swing_up_task()), curriculum))
        >>> (target,) = resolve_targets(curriculum, ["success_value"], [torch.Size([])]).targets
        >>> target.buffer, target.source, target.per_env
        ('success_value', 'task', False)
        >>> try:
        ...     resolve_targets(curriculum, ["sucess_value"], [torch.Size([])])
        ... except ValueError as error:
        ...     print(str(error).split(" It is")[0])
        Curriculum: unknown target 'sucess_value'; did you mean 'success_value'?
    """
    who = type(writer).__name__
    placement = find_placement(writer)
    choices = _writer_choices(writer, placement, env_fields, names)
    fulls = _full_names(writer, placement, choices, names, env_fields)
    found = [choices.named[full] for full in fulls]
    leading = [] if rows is None else [rows]
    for command in (t for t in placement.transforms[: placement.position] if isinstance(t, GoalCommand)):
        ranges = [repr(name) for name, candidate in zip(names, found, strict=True) if candidate.root is command]
        if ranges:
            raise ValueError(
                f"{who} sets {', '.join(ranges)} of the GoalCommand writing {command.goal_key!r}, which comes before "
                f"it: put {who} before it (before that GoalCommand in the Compose, after the TaskTransform), so that "
                "the goal drawn in a step uses that step's range"
            )
    for randomization in placement.transforms[placement.position + 1 :]:
        if not isinstance(randomization, DomainRandomization):
            continue
        params = [
            repr(name) for name, candidate in zip(names, found, strict=True) if candidate.root is randomization.params
        ]
        if params:
            raise ValueError(
                f"{who} sets {', '.join(params)} of a DomainRandomization that comes after it: put {who} after it (in "
                "the Compose, after the TaskTransform and the DomainRandomization). TorchRL runs the transforms' "
                "pre-reset hooks last to first, and the randomization draws there, before the base env resets: the "
                "writer after it writes the reset's values first"
            )
    for randomization in placement.transforms[: placement.position]:
        if not isinstance(randomization, DomainRandomization):
            continue
        params = [repr(n) for n, candidate in zip(names, found, strict=True) if candidate.root is randomization.params]
        if not params:
            continue
        reason = randomization.unwritable_reason()
        if reason is not None:
            raise ValueError(
                f"{who} sets {', '.join(params)} of a DomainRandomization with {reason}: values written after that are "
                "never drawn, and the data would report a distribution the physics do not follow. To draw from the "
                "written values, randomize with when='reset' or when='interval' and no cycle; for fixed values, build "
                "the distribution (or the cycle) with them"
            )
        randomization.fields()  # its params bound to the env's fields: their checks include the ranges
    targets = []
    for name, full, candidate, received in zip(names, fulls, found, value_shapes, strict=True):
        module, leaf = buffer_owner(candidate.root, candidate.path)
        source = candidate.source
        shape = module._buffers[leaf].shape
        if source == DOMAIN:  # one env's row: the buffer is per env once a DifficultyLevels writes it
            shape = module.parameter_shape(leaf)
        if batch is None:
            if received != torch.Size(()) and received != shape:
                raise ValueError(
                    f"{who}: the values of {name!r} have shape {tuple(received)}, but the target has shape "
                    f"{tuple(shape)}; give values of shape {tuple(shape)} or scalars"
                )
            targets.append(Target(name, module, leaf, source, shape, False, full))
        elif source == DOMAIN:  # made per env below
            if received != shape:
                raise ValueError(
                    f"{who}: the values of {name!r} must have shape {[*leading, *shape]} (one distribution parameter "
                    f"per row), got {[*leading, *received]}"
                )
            targets.append(Target(name, module, leaf, source, shape, True, full))
        elif source == COMMAND:  # made per env below
            if received != shape[-1:]:
                raise ValueError(
                    f"{who}: the values of {name!r} must have shape {[*leading, *shape[-1:]]} (one range bound per "
                    f"row), got {[*leading, *received]}"
                )
            targets.append(Target(name, module, leaf, source, shape[-1:], True, full))
        else:
            expected = (*batch, *received)
            if tuple(shape) != expected:
                raise ValueError(
                    f"{who}: the target {name!r} has shape {list(shape)}, but a per-env value of shape "
                    f"{list(received)} needs a buffer of shape {list(expected)} (the env batch {list(batch)} first); "
                    "a value shared by all envs is scheduled with a Curriculum"
                )
            targets.append(Target(name, module, leaf, source, received, True, full))
    if batch is not None:
        for command in command_ranges(targets):
            command.use_per_env_range(batch)
        for target in targets:
            if target.source == DOMAIN:
                target.module.use_per_env(batch)
    return ResolvedTargets(placement, targets)


#: the writers, as :class:`TargetRow` names them
_CURRICULUM, _LEVELS = "Curriculum", "DifficultyLevels"


class TargetRow(NamedTuple):
    """One target an env's writers can set (a row of :class:`TargetTable`)."""

    #: the short name to type: the shortest dotted suffix of two parts or more that ends this name only
    alias: str
    #: the full name (also accepted)
    name: str
    #: where it lives: ``"task"``, ``"command"``, ``"env"`` or ``"domain"``
    source: str
    #: the buffer's shape now
    shape: torch.Size
    #: the writers that accept it: ``"Curriculum"`` and/or ``"DifficultyLevels"``
    writers: tuple[str, ...]
    #: the buffer's value now, shortened for the table
    value: str


class TargetTable(tuple):
    """The targets of an env (:func:`target_names`): a tuple of :class:`TargetRow`\\ s that prints as a table."""

    @property
    def aliases(self) -> list[str]:
        """The short names, row by row."""
        return [row.alias for row in self]

    @property
    def names(self) -> list[str]:
        """The full names, row by row."""
        return [row.name for row in self]

    def __str__(self) -> str:
        header = ("alias", "name", "source", "shape", "writers", "value")
        cells = [header] + [
            (row.alias, row.name, row.source, str(list(row.shape)), ", ".join(row.writers) or "-", row.value)
            for row in self
        ]
        widths = [max(len(line[i]) for line in cells) for i in range(len(header) - 1)]
        return "\n".join(
            "  ".join(cell.ljust(width) for cell, width in zip(line[:-1], widths, strict=True)) + "  " + line[-1]
            for line in cells
        )

    __repr__ = __str__


def _short_value(value: torch.Tensor) -> str:
    flat = value.detach().reshape(-1)[:4].to("cpu", torch.float64).tolist()
    text = ", ".join(f"{v:.4g}" for v in flat[:3])
    if value.dim() == 0:
        return text
    return f"[{text}{', ...' if value.numel() > 3 else ''}]"


def target_names(env: TransformedEnv) -> TargetTable:
    """List what a :class:`~torchtasks.transforms.Curriculum` or :class:`~torchtasks.transforms.DifficultyLevels`
    added to ``env`` could set: one :class:`TargetRow` per target, printed as a table.

    Call it on the env before adding the writer (a preset, any ``TransformedEnv`` with one
    :class:`~torchtasks.transforms.TaskTransform`). The rows are the names the writers' resolver walks:

    - ``"task"``: a float buffer of the task tree (``task.named_buffers()``). A Curriculum schedules any of them (one
      value for all envs); DifficultyLevels only one that holds a value per env (its shape starts with the env's
      batch);
    - ``"command"``: a GoalCommand's sampling range, both writers, which must come before the GoalCommand (insert the
      writer before it rather than appending it);
    - ``"env"``: a float buffer of the base env, DifficultyLevels only and only one with a value per env;
    - ``"domain"``: a DomainRandomization's distribution parameter, both writers, which must come after it; none
      for a randomization that never draws written values (``when="startup"``, a ``cycle``).

    Both writers take a row's ``alias`` or its full ``name``: the alias is the shortest dotted suffix of two parts
    or more that ends no other task buffer's name (a GoalCommand's range: ``"command.low"`` with one command);
    any suffix that ends one name only is accepted too, one that ends several is refused naming them. The data
    and the checkpoints key a target by the name as written (see :func:`resolve_targets`).

    Args:
        env: a ``TransformedEnv`` whose transforms hold one TaskTransform.

    Example:
        >>> from torchrl.envs import Compose, TransformedEnv
        >>> from torchtasks.envs import PendulumEnv, swing_up_task
        >>> from torchtasks.transforms import TaskTransform
        >>> env = TransformedEnv(PendulumEnv(batch_size=[4]), Compose(TaskTransform(swing_up_task())))
        >>> table = target_names(env)
        >>> table.aliases[-3:]
        ['track.Q', 'effort.Q', 'effort.R']
        >>> print(table)  # doctest: +ELLIPSIS
        alias                    name                                  source  shape  writers     value
        state_low                state_low                             task    [2]    Curriculum  [-inf, -8]
        ...
        track.Q                  wrapped_task.reward.rewards.track.Q   task    [2]    Curriculum  [1, 0.1]
        ...
    """
    transform = getattr(env, "transform", None)
    if transform is None or not hasattr(env, "base_env"):
        raise TypeError(f"target_names: env must be a TransformedEnv holding a TaskTransform, got {type(env).__name__}")
    transforms = flat_transforms(transform)
    tasks = [t for t in transforms if isinstance(t, TaskTransform)]
    if len(tasks) != 1:
        raise ValueError(f"target_names: env must hold exactly one TaskTransform, found {len(tasks)}")
    base = env.base_env
    choices = _choices("target_names", tasks[0].task, transforms, base, ())
    aliases = short_names(choices.task_names)
    for name, candidate in choices.named.items():  # a GoalCommand's short range name, with one command
        if candidate.source == COMMAND and name.count(".") == 1:
            qualified = next(full for full, other in choices.named.items() if other is candidate and full != name)
            aliases[qualified] = name
    batch = tuple(env.batch_size)
    undrawn = [  # the distributions of randomizations that never draw written values (the writers refuse them)
        t.params for t in transforms if isinstance(t, DomainRandomization) and t.unwritable_reason() is not None
    ]
    rows = []
    for name, candidate in choices.named.items():
        if name in aliases.values() and name not in aliases:  # a short name, listed with its full name
            continue
        module, leaf = buffer_owner(candidate.root, candidate.path)
        value = module._buffers[leaf]
        per_env = tuple(value.shape[: len(batch)]) == batch
        writers = {
            TASK: (_CURRICULUM, _LEVELS) if per_env else (_CURRICULUM,),
            ENV: (_LEVELS,) if per_env else (),
            DOMAIN: () if any(candidate.root is params for params in undrawn) else (_CURRICULUM, _LEVELS),
        }.get(candidate.source, (_CURRICULUM, _LEVELS))
        rows.append(
            TargetRow(aliases.get(name, name), name, candidate.source, value.shape, writers, _short_value(value))
        )
    return TargetTable(rows)


def command_ranges(targets: Sequence[Target]) -> dict[GoalCommand, dict[str, int]]:
    """The GoalCommands whose range ``targets`` set, each with ``{"low" or "high": index in targets}``."""
    ranges: dict[GoalCommand, dict[str, int]] = {}
    for i, target in enumerate(targets):
        if target.source == COMMAND:
            ranges.setdefault(target.module, {})[target.buffer] = i
    return ranges


class DomainWrites(NamedTuple):
    """What one writer can write into one domain distribution (:meth:`TargetWriter.domain_writes`).

    Row ``k`` of every buffer's values is one combination the writer writes at once (one level of every table; every
    schedule at one frame count, or at one stage of a gated one). Every value the writer can put into the
    distribution is one of these rows or, for a schedule between two breakpoints, bounded by them as
    :func:`check_domain_writes` needs.
    """

    #: the DomainParam written
    param: nn.Module
    #: the writer's kind, for messages (``"Curriculum"``)
    writer: str
    #: the rows ``[n, *parameter shape]`` written into each buffer, by buffer name
    values: dict[str, torch.Tensor]
    #: what each row is, for messages (``"the schedule of 'domain.mass.mean' at frame 100"``)
    labels: tuple[str, ...]


def check_domain_writes(writer: TargetWriter, placement: Placement) -> None:
    """Refuse values that the env's writers can put into a domain distribution of ``writer``'s together and that the
    distribution (its rules, the field's range) refuses; naming the first such combination.

    Every writer of the distribution (``writer`` and the other :class:`TargetWriter`\\ s among the env's transforms)
    gives its rows (:class:`DomainWrites`); a writer's rows are taken together, and every row of one writer with
    every row of the others (they move independently: levels at episode ends, schedules with frames or gates). The
    unwritten buffers keep their current values (every env's). A buffer written by two writers is refused (one owner).

    Why these rows suffice. A distribution's rules and the range of its draws (:meth:`DomainParam.support`: ``mean
    -/+ halfspan``, ``min``/``max`` of a Bernoulli's values, unbounded for normals, then clipped and rounded) are
    monotone in each parameter, elementwise: a bound that holds at every corner of a box of parameters holds inside
    it. Level tables and gated stages take only their rows. A frame-driven schedule is linear between consecutive
    breakpoints (:func:`~torchtasks.transforms.schedules.breakpoint_frames`), where its buffers move together: the
    unclipped range is linear (uniform) or concave/convex (a Bernoulli's ``min``/``max``) along that segment, so its
    extremes are at the segment's ends, and so are the linear rules (a halfspan >= 0, ``clip_lo <= clip_up``,
    ``prob_1`` in [0, 1]) and positive definiteness (a segment between two such matrices holds only such matrices).
    A clipping bound moving in the same segment as the range is the one exception (the clipped range is not convex
    along it): the Curriculum adds the mixed corners of that segment (one at one end, the others at the other).

    Example:
        >>> from torchrl.envs import Compose, TransformedEnv
        >>> from torchtasks.domain import UniformDomainParam
        >>> from torchtasks.envs import PendulumEnv, swing_up_task
        >>> from torchtasks.transforms import Curriculum, DifficultyLevels, DomainRandomization, TaskTransform, linear
        >>> randomization = DomainRandomization([UniformDomainParam("mass", mean=1.0, halfspan=0.0)])
        >>> lighter = Curriculum({"domain.mass.mean": linear(1.0, 0.3, 0, 100)})  # alone: masses of 0.3 at least
        >>> wider = DifficultyLevels(2, {"domain.mass.halfspan": [0.0, 0.5]})  # alone: masses of 0.5 at least
        >>> env = TransformedEnv(PendulumEnv(batch_size=[2]), Compose(
        ...     TaskTransform(swing_up_task()), randomization, lighter, wider))
        >>> try:
        ...     env.reset()
        ... except ValueError as error:
        ...     print(str(error).split(" can write")[0])
        Curriculum: the schedule of 'domain.mass.mean' at frame 99 with level 1 of 'domain.mass.halfspan' (a \
DifficultyLevels of the env)
    """
    own = writer.domain_writes()
    if not own:
        return
    who = type(writer).__name__
    others = [t for i, t in enumerate(placement.transforms) if i != placement.position and isinstance(t, TargetWriter)]
    for mine in own:
        writes = [mine]
        for other in others:  # resolves the other writers (their own checks first); they find this one resolved
            writes += [write for write in other.domain_writes() if write.param is mine.param]
        check_written_together(who, writes)


def check_written_together(who: str, writes: Sequence[DomainWrites]) -> None:
    """Refuse a combination of rows of ``writes`` (of one distribution; the first one's writer is ``who``) that the
    distribution refuses: every row of each writer with every row of the others (see :func:`check_domain_writes`).

    Example:
        >>> import math, torch
        >>> from torchtasks.domain import DomainField, UniformDomainParam
        >>> nominal = torch.tensor(1.0, dtype=torch.float64)
        >>> param = UniformDomainParam("mass", mean=1.0, halfspan=0.0)
        >>> param.bind_field(DomainField("mass", torch.Size([]), nominal, 0.0, math.inf, True, (), True, "mass (kg)"))
        >>> means = DomainWrites(param, "Curriculum", {"mean": torch.tensor([1.0, 0.5], dtype=torch.float64)},
        ...                      ("the schedule of 'domain.mass.mean' at frame 0", "the schedule ... at frame 9"))
        >>> spans = torch.tensor([0.0, 0.8], dtype=torch.float64)
        >>> halfspans = DomainWrites(param, "DifficultyLevels", {"halfspan": spans},
        ...                          ("level 0 of 'domain.mass.halfspan'", "level 1 of 'domain.mass.halfspan'"))
        >>> try:
        ...     check_written_together("DifficultyLevels", [halfspans, means])
        ... except ValueError as error:
        ...     print(str(error).split(" together")[0])
        DifficultyLevels: level 1 of 'domain.mass.halfspan' with the schedule ... at frame 9 (a Curriculum of the env) \
can write halfspan=[0.8] and mean=[0.5]
    """
    param = writes[0].param
    owners: dict[str, str] = {}
    for write in writes:
        for buffer in write.values:
            if buffer in owners:
                raise ValueError(
                    f"{who}: a {owners[buffer]} and a {write.writer} of the env both write {buffer!r} of {param!r}: a "
                    "buffer has one owner"
                )
            owners[buffer] = write.writer
    kept = [_distinct_rows(write) for write in writes]
    picks = list(itertools.product(*kept))
    values = {
        buffer: value[[pick[i] for pick in picks]]
        for i, write in enumerate(writes)
        for buffer, value in write.values.items()
    }
    try:
        param.check_written_values(values, who, as_rows=True)
    except ValueError:
        for pick in picks:  # the failing combination, named (the refusal's path only)
            label = f"{who}: " + " with ".join(
                write.labels[k]
                if i == 0
                else f"{write.labels[k]} ({'another' if write.writer == who else 'a'} {write.writer} of the env)"
                for i, (write, k) in enumerate(zip(writes, pick, strict=True))
            )
            one = {
                buffer: value[pick[i] : pick[i] + 1]
                for i, write in enumerate(writes)
                for buffer, value in write.values.items()
            }
            param.check_written_values(one, label, as_rows=True)
        raise


def _distinct_rows(write: DomainWrites) -> list[int]:
    """The index of the first of every distinct row of ``write`` (a row: its values in every buffer)."""
    flat = torch.cat([value.reshape(len(value), -1) for value in write.values.values()], 1)
    first: dict[tuple[float, ...], int] = {}
    for k, row in enumerate(flat.tolist()):
        first.setdefault(tuple(row), k)
    return list(first.values())


def check_in_goal_space(target: Target, values: torch.Tensor, label: str, offenders: Sequence[str]) -> None:
    """Refuse a value of a GoalCommand's range bound that leaves the command's ``Box`` (its goal spec).

    Args:
        target: a ``"command"`` target.
        values: the values the bound may take, stacked on a first dim (``[n, *value_shape]``, or broadcastable).
        label: who writes them, e.g. ``"Curriculum: the schedule of 'command.high'"``.
        offenders: what each value is, for the message naming the first one outside.

    Example:
        >>> import torch
        >>> from torchtasks.spaces import Box
        >>> from torchtasks.transforms import GoalCommand
        >>> command = GoalCommand(Box([-1.0], [1.0]))
        >>> high = Target("command.high", command, "high", "command", torch.Size([1]), per_env=False)
        >>> try:
        ...     check_in_goal_space(high, torch.tensor([[0.5], [1.5]]), "a table", ["row 0", "row 1"])
        ... except ValueError as error:
        ...     print(str(error).split(" (")[0])
        a table leaves the GoalCommand's space: row 1 leaves the goal space of the GoalCommand writing 'goal'
    """
    command = target.module
    space_low = command.space.low.to("cpu", torch.float64)
    space_high = command.space.high.to("cpu", torch.float64)
    values = values.to("cpu", torch.float64)
    outside = ((values < space_low) | (values > space_high)).reshape(len(values), -1).any(-1)
    if outside.any():
        raise ValueError(
            f"{label} leaves the GoalCommand's space: {offenders[int(outside.nonzero()[0, 0])]} leaves the goal space "
            f"of the GoalCommand writing {command.goal_key!r} (its goal spec, low={space_low.tolist()}, "
            f"high={space_high.tolist()}); build the GoalCommand with a Box that holds the widest range"
        )


def check_low_not_above_high(pairs: Iterable[tuple[torch.Tensor, torch.Tensor]], labels: Sequence[str]) -> None:
    """Refuse a GoalCommand range with ``low > high`` in some entry.

    Args:
        pairs: ``(low, high)`` pairs the range may take together (broadcastable tensors).
        labels: what each pair is, for the message naming the first crossed one.

    Example:
        >>> import torch
        >>> pairs = [(torch.tensor([0.0]), torch.tensor([0.5])), (torch.tensor([0.75]), torch.tensor([0.5]))]
        >>> try:
        ...     check_low_not_above_high(pairs, ["level 0", "level 1"])
        ... except ValueError as error:
        ...     print(error)
        level 1 has low > high: low=[0.75], high=[0.5]
    """
    for i, (low, high) in enumerate(pairs):
        low, high = low.to("cpu", torch.float64), high.to("cpu", torch.float64)
        if (low > high).any():
            raise ValueError(f"{labels[i]} has low > high: low={low.tolist()}, high={high.tolist()}")


def check_one_owner(writer: TargetWriter, targets: Sequence[Target], placement: Placement, advice: str = "") -> None:
    """Refuse a target that another :class:`TargetWriter` of the env also writes, and an entry both write.

    ``advice`` ends the message (e.g. what to do instead).
    """
    who = type(writer).__name__
    mine = {(id(target.module), target.buffer): target.name for target in targets}
    own_entries = set(writer.out_keys)
    for i, other in enumerate(placement.transforms):
        if i == placement.position or not isinstance(other, TargetWriter):  # the writer (or what it was cloned from)
            continue
        for target in other.written_targets():
            if (id(target.module), target.buffer) in mine:
                raise ValueError(
                    f"{who} sets {mine[(id(target.module), target.buffer)]!r}, which a {type(other).__name__} of the "
                    f"env also sets as {target.name!r}: a buffer has one owner{advice}"
                )
        for key in other.out_keys:
            if key in own_entries:
                raise ValueError(f"{who} writes {key!r}, which a {type(other).__name__} of the env also writes")
