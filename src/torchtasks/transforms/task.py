"""TorchRL face of a task: :class:`TaskTransform` turns env outputs into task rewards and flags."""

from __future__ import annotations

import functools
import math
import operator
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Literal, NamedTuple

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey, unravel_key
from torch import nn
from torchrl.data import Categorical, Composite, Unbounded
from torchrl.envs.transforms import RewardSum, StepCounter, Transform, TransformedEnv
from torchrl.envs.utils import make_composite_from_td

from torchtasks._checks import SUPPORTED_FLOATS, check_input, check_positive_int
from torchtasks._memory import hollow_paths, td_get, td_set, unshared, with_hollow, without_hollow
from torchtasks._torchrl import container_env, flat_transforms, key_parts, keys_text, nested_key
from torchtasks.tasks.goals import GoalSlot, replace_goals
from torchtasks.tasks.memory import where_memory
from torchtasks.tasks.protocol import Task
from torchtasks.tasks.transition import Transition
from torchtasks.transforms._base import EnvDerivedTransform
from torchtasks.transforms.entries import Entry, TaskEntries, task_entries, transition_field
from torchtasks.transforms.names import (
    COST_KEY,
    COST_TERMS_KEY,
    CURRICULUM_KEY,
    DONE_KEY,
    ENDED_BY_KEY,
    EPISODE_SUM_PREFIX,
    FAILURE_KEY,
    FINAL_TERM,
    FRAMES,
    GROUPS_KEY,
    LEVEL,
    MEMORY_KEY,
    REWARD_KEY,
    STEP_TERM,
    SUCCESS_KEY,
    TERMINATED_KEY,
    TERMS_KEY,
    TRUNCATED_KEY,
    VECTOR_REWARD_KEY,
    names_task_buffer,
    suffix_matches,
    target_name,
)

__all__ = ["TaskTransform", "undefined_flag_note"]

ResetOverrides = Callable[[torch.Tensor], dict[str, Any]]


def _state_keys(state_key: object) -> list[NestedKey]:
    """The state keys: one key, or a non-empty list of keys concatenated on the last dim."""
    if isinstance(state_key, str) or (
        isinstance(state_key, tuple) and state_key and not isinstance(state_key[0], (tuple, list))
    ):
        return [nested_key(state_key, "TaskTransform: state_key")]
    if not isinstance(state_key, Sequence):
        raise TypeError(
            "TaskTransform: state_key must be a key (a string or a tuple of strings) or a non-empty list of keys, "
            f"got {state_key!r} of type {type(state_key).__name__}"
        )
    if len(state_key) == 0:
        raise ValueError("TaskTransform: state_key must name at least one entry, got an empty list")
    return [nested_key(key, f"TaskTransform: state_key[{i}]") for i, key in enumerate(state_key)]


def _overlap(a: NestedKey, b: NestedKey) -> bool:
    """Whether writing one key would overwrite the other (equal, or one nested under the other)."""
    a, b = key_parts(a), key_parts(b)
    n = min(len(a), len(b))
    return a[:n] == b[:n]


def _refuse_episode_sums(names: Sequence[str], what: str, argument: str, key: NestedKey) -> None:
    """Refuse a name ``episode_<x>`` beside a name ``<x>`` among the entries written under ``key``.

    TorchRL's ``RewardSum`` writes the running sum of an entry it sums as ``episode_<name>`` beside it: that sum
    would overwrite the entry named ``episode_<x>`` after every step, and the statistics would drop it.
    """
    written = set(names)
    for name in names:
        summed = name.removeprefix(EPISODE_SUM_PREFIX)
        if summed != name and summed in written:
            raise ValueError(
                f"TaskTransform: the {what} {name!r} is written beside {summed!r} under {argument}={key!r}, and "
                f"TorchRL's RewardSum writes the episode sum of {summed!r} there as {name!r} (it writes "
                f"episode_<name> beside each entry it sums): the sum would overwrite the {what} and the statistics "
                f"would drop it. Rename one of them."
            )


def _refuse_summed_over(entries: TaskEntries) -> None:
    """Refuse a reward-spec entry named ``episode_<x>`` beside another one named ``<x>`` (e.g.
    ``vector_reward_key="episode_reward"`` beside ``reward_key="reward"``): TorchRL's ``RewardSum`` writes the
    episode sum of ``<x>`` there and would overwrite it (or fail on its shape)."""
    rows = entries.select(spec="reward")
    by_key = {key_parts(row.key): row for row in rows}
    for parts, row in by_key.items():
        summed = parts[-1].removeprefix(EPISODE_SUM_PREFIX)
        other = by_key.get((*parts[:-1], summed))
        if summed != parts[-1] and other is not None:
            raise ValueError(
                f"TaskTransform: {row.key!r} ({row.argument}) is written beside {other.key!r} ({other.argument}), "
                f"and TorchRL's RewardSum writes the episode sum of {other.key!r} as {row.key!r}: the sum would "
                "overwrite it. Pick another key."
            )


def undefined_flag_note(transform: Transform, key: NestedKey) -> str:
    """``"; <why>"`` when a TaskTransform of ``transform``'s env writes no ``key`` because its task cannot reach that
    outcome (see :meth:`TaskTransform.undefined_flag`), else ``""``: the end of the error of a reader of the flag.

    Example:
        >>> from torchrl.envs import Compose, TransformedEnv
        >>> from torchtasks.envs import PendulumEnv
        >>> from torchtasks.rewards import ConstantReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import GoallessTask
        >>> reader = Transform()
        >>> task = TaskTransform(GoallessTask(EnvSpec(3, 1), ConstantReward(1.0)))
        >>> env = TransformedEnv(PendulumEnv(batch_size=[2]), Compose(task, reader))
        >>> undefined_flag_note(reader, "success")[:38]
        '; its task (GoallessTask) has no succe'
    """
    container = container_env(transform)
    if container is None or getattr(container, "transform", None) is None:
        return ""
    for other in flat_transforms(container.transform):
        reason = other.undefined_flag(key) if isinstance(other, TaskTransform) else None
        if reason is not None:
            return "; " + reason
    return ""


class RecordedValue(NamedTuple):
    """A buffer of the task tree that a transform of the env sets at every step, and the entry recording its value.

    A :class:`~torchtasks.transforms.Curriculum` or :class:`~torchtasks.transforms.DifficultyLevels` after the
    :class:`TaskTransform` names these (``recorded_task_values()``), and offline recomputation evaluates each
    frame with the value recorded for it, never with the buffer's value of today.
    """

    #: the buffer's name in ``task.named_buffers()``
    buffer: str
    #: the root entry holding, for every frame, the value the step's task used
    key: tuple[str, ...]
    #: the shape of one env's value for a buffer holding one value per env (``[*B_env, *row_shape]``, set by
    #: levels); ``None`` for a value shared by all envs (a schedule's value: the buffer's shape, or a scalar)
    row_shape: torch.Size | None


class TimeLimit(NamedTuple):
    """The time limit a :class:`TaskTransform` derives from the env it is in (see ``TaskTransform._time_limit``)."""

    #: the limit for the remaining steps (None: no limit, or a task tree that does not read them)
    max_steps: int | None
    #: the entry holding the step count (that of the StepCounter with the limit)
    step_count_key: NestedKey
    #: whether a StepCounter of the env truncates at ``max_steps`` (else the step counts met are checked)
    enforced: bool


def buffer_owner(task: nn.Module, name: str) -> tuple[nn.Module, str]:
    """The module holding the buffer ``name`` of ``task.named_buffers()`` and the buffer's name in it.

    Walks the submodules by key: ``get_submodule`` reads attributes, and a reward term may be named like a method
    of ``nn.Module`` (``forward``).
    """
    *path, leaf = name.split(".")
    module = task
    for part in path:
        module = module._modules[part]
    return module, leaf


def _frame_values(entry: torch.Tensor, buffer: torch.Tensor, batch: torch.Size, record: RecordedValue) -> torch.Tensor:
    """The recorded values of a buffer as one value per frame: ``[*B, *buffer.shape]`` for a value shared by all
    envs (``[*B]`` for a scalar buffer), ``[*B, *row_shape]`` for one env's value, in the buffer's dtype."""
    trailing, same_batch = entry.shape[len(batch) :], entry.shape[: len(batch)] == batch
    if record.row_shape is None:  # a schedule's value: of the buffer's shape, or a scalar (written [*B, 1])
        expected, fits = [*batch, *buffer.shape], same_batch and trailing in (buffer.shape, (1,))
        if fits and trailing != buffer.shape:  # the scalar filled the buffer
            entry = entry.reshape(*batch, *[1] * buffer.dim()).expand(*batch, *buffer.shape)
    else:  # one env's row of a per-env buffer
        expected, fits = [*batch, *record.row_shape], same_batch and trailing == record.row_shape
    if not fits:
        kind = " (or [*batch, 1] for a scalar)" if record.row_shape is None else " (one env's value per frame)"
        raise ValueError(
            f"TaskTransform: the recorded values {record.key!r} of the task buffer {record.buffer!r} (shape "
            f"{list(buffer.shape)}) must have shape {expected}{kind} for the data's batch {list(batch)}, got "
            f"{list(entry.shape)}"
        )
    return entry if entry.dtype == buffer.dtype and entry.device == buffer.device else entry.to(buffer)


def _as_entry(value: torch.Tensor, shape: torch.Size, dtype: torch.dtype) -> torch.Tensor:
    """``value`` reshaped to the env's ``[*B, 1]`` entry shape, in the spec's dtype (no cast when it already is)."""
    value = value.reshape(shape)
    return value if value.dtype == dtype else value.to(dtype)


def _as_flag(value: torch.Tensor, shape: torch.Size, dtype: torch.dtype) -> torch.Tensor:
    """A flag ``[*B]`` as the env's ``[*B, 1]`` done-shaped entry (bool, as the task returned it)."""
    return value.reshape(shape)


def _as_is(value: Any, shape: torch.Size, dtype: torch.dtype) -> Any:
    """The value as the task returned it (the memory)."""
    return value


def _as_stacked(names: tuple[str, ...], values: Mapping[str, torch.Tensor], shape: torch.Size, dtype: torch.dtype):
    """The named values ``[*B]`` stacked on a last dim in ``names`` order (``[*B, k]``), in the reward's dtype."""
    return torch.stack([values[name] for name in names], -1).to(dtype)


def _as_group(dtype: torch.dtype | None, value: torch.Tensor, shape: torch.Size, reward_dtype: torch.dtype):
    """One reward group ``[*B]`` as a ``[*B, 1]`` entry in the groups' dtype (``None``: the reward's)."""
    return _as_entry(value, shape, reward_dtype if dtype is None else dtype)


def _as_vector(
    names: tuple[str, ...],
    dtype: torch.dtype | None,
    values: Mapping[str, torch.Tensor],
    shape: torch.Size,
    reward_dtype: torch.dtype,
) -> torch.Tensor:
    """The reward groups stacked in ``names`` order (``[*B, k]``), in the groups' dtype (``None``: the reward's)."""
    return _as_stacked(names, values, shape, reward_dtype if dtype is None else dtype)


def _as_achieved(slot: GoalSlot, next_state: torch.Tensor, shape: torch.Size, dtype: torch.dtype) -> torch.Tensor:
    """The achieved goal of the next state (``[*B, k]``)."""
    return slot.achieved(next_state)


#: how a value of each kind is written: (value, the done flags' shape, the reward's dtype) -> entry
_WRITE_AS = {
    "reward": _as_entry,
    "term": _as_entry,
    "cost": _as_entry,
    "flag": _as_flag,
    "env_flag": _as_flag,
    "memory": _as_is,
}

#: the reward of the task's transition result (read by name, like every field the transform writes)
_reward_of = transition_field("reward")


def _goal_slot(task: Task, goal_name: str | None) -> GoalSlot:
    """The goal slot a TaskTransform's goal keys are about (the tree's only one, or the one named)."""
    slots = {slot.name: slot for slot in task.goal_slots}
    if not slots:
        raise ValueError(
            f"TaskTransform: goal_key/achieved_goal_key were given, but no task of the {type(task).__name__} tree "
            "takes a goal (a DesiredStateTask, also inside wrappers, masks and composites)"
        )
    if goal_name is None:
        if len(slots) > 1:
            raise ValueError(
                f"TaskTransform: the task tree has {len(slots)} goal tasks {sorted(slots)}; pass goal_name=... to "
                "say which one the goal is for"
            )
        return next(iter(slots.values()))
    if goal_name not in slots:
        raise ValueError(f"TaskTransform: unknown goal_name {goal_name!r}; the task tree's goals are {sorted(slots)}")
    return slots[goal_name]


def _check_vector_gym(base_env: Any) -> None:
    """Reject Gymnasium vector envs that reset sub-envs by themselves (they cannot take task resets)."""
    gym_env = base_env.__dict__.get("_env")
    if gym_env is None or not hasattr(gym_env, "num_envs"):
        return
    mode = getattr(gym_env, "metadata", {}).get("autoreset_mode")
    if mode is not None and str(getattr(mode, "name", mode)).upper() == "DISABLED":
        return
    raise ValueError(
        f"{type(base_env).__name__} wraps a Gymnasium vector env that resets its sub-envs itself, so it cannot "
        "end episodes when the task says so. Use ParallelEnv/SerialEnv of single envs, or "
        "GymWrapper(gymnasium.make_vec(..., vector_kwargs={'autoreset_mode': "
        "gymnasium.vector.AutoresetMode.DISABLED}))."
    )


def _check_within_limit(
    remaining: torch.Tensor, step_count: torch.Tensor, max_steps: int, step_count_key: NestedKey
) -> None:
    """Refuse step counts beyond the time limit (their remaining steps would be negative)."""
    if bool((remaining < 0).any()):
        raise ValueError(
            f"TaskTransform: step counts up to {int(step_count.max())} under ('next', {step_count_key!r}) exceed "
            f"max_steps={max_steps}: the remaining steps would be negative and flip the sign of a time-dependent "
            "final reward. Pass the limit the data was collected with (TaskTransform(..., max_steps=...))."
        )


class TaskTransform(EnvDerivedTransform):
    """Apply a task to a TorchRL env: task reward, success, failure and termination on every step.

    Each step reads ``s_t`` and ``a_t`` from the root, ``s_{t+1}`` from ``"next"`` and the task memory from
    ``memory_key``, and evaluates the task once: the step reward on ``s_{t+1}`` (``reward_on="next"``, Gymnasium's
    convention) or on ``s_t`` (``"state"``, Pyrado's order), success, failure and the final reward on ``s_{t+1}``, the
    final reward paid once, where the episode ends. The reward replaces the env's (cast to the reward spec's dtype);
    ``terminated`` and ``done`` are OR-ed with success and failure, ``truncated`` is left alone. The remaining steps
    are ``max_steps - step_count`` of a preceding ``StepCounter`` (0 without a limit). Whenever the env's specs are
    built the transform sets itself up for the env it is in (sizes, dtype, time limit, transform order) and casts the
    task to the state's dtype, in place. :attr:`entries` lists what it writes and when; the docs page "TorchRL
    integration" gives the rules in full (specs, order, time limits, offline use).

    Args:
        task: the task to apply.
        state_key: the key (or keys, concatenated on the last dim) holding the task's state.
        action_key: the action key.
        reward_on: ``"next"`` or ``"state"``: which state the step reward is evaluated on.
        memory_key, success_key, failure_key, terms_key: output keys (the success flag only for a tree that can
            succeed, the failure flag only for one that can fail: ``task.facts``).
        log_terms: write the reward breakdown, ``(terms_key, <term>)`` per named term, for a ``RewardSum`` after it.
        max_steps: the time limit of the remaining steps (default: a preceding StepCounter's; ``math.inf``: none,
            on purpose); needed offline and when the env's StepCounters are out of the transform's sight.
        reset_overrides: ``init_state -> {name: value}`` per-env reset overrides (picklable for workers).
        compile: evaluate the task with ``torch.compile(fullgraph=True)``.
        goal_key: the root entry holding the goal the policy saw at step ``t`` (e.g. a
            :class:`~torchtasks.transforms.GoalCommand`'s), passed to the task as ``goal=``.
        achieved_goal_key: where to write the achieved goal of ``s_{t+1}`` (and of the initial state at reset).
        goal_name: which goal task of the tree (:attr:`Task.goal_slots`) the goal is for, when it has several.
        ended_by_key: where a tree that names its end conditions writes one flag per condition (with ``log_terms``).
        cost_key, cost_terms_key: where a tree with costs writes them: ``[*B, k]``, and ``[*B, 1]`` each.
        vector_reward_key, groups_key: where a tree with reward groups writes them: ``[*B, k]``, and ``[*B, 1]`` each.
        curriculum_key: offline, the entries holding the values a Curriculum or DifficultyLevels set per step.

    Example:
        >>> import torch
        >>> from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv
        >>> from torchtasks.envs import PendulumEnv
        >>> from torchtasks.rewards import QuadraticErrorReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import RadiallySymmetricDesiredStateTask
        >>> task = RadiallySymmetricDesiredStateTask(
        ...     EnvSpec(2, 1), [0.0, 0.0], QuadraticErrorReward([1.0, 0.1], [0.001]), indices=[0], threshold=0.1)
        >>> transforms = Compose(StepCounter(50), TaskTransform(task), RewardSum())
        >>> env = TransformedEnv(PendulumEnv(batch_size=[4]), transforms)
        >>> rollout = env.rollout(10, break_when_any_done=False)  # a success would end the rollout early
        >>> rollout["next", "reward"].shape, rollout["next", "success"].dtype
        (torch.Size([4, 10, 1]), torch.bool)
    """

    def __init__(
        self,
        task: Task,
        *,
        state_key: NestedKey | Sequence[NestedKey] = "observation",
        action_key: NestedKey = "action",
        reward_on: Literal["next", "state"] = "next",
        reward_key: NestedKey = REWARD_KEY,
        memory_key: NestedKey = MEMORY_KEY,
        success_key: NestedKey = SUCCESS_KEY,
        failure_key: NestedKey = FAILURE_KEY,
        terms_key: NestedKey = TERMS_KEY,
        log_terms: bool = True,
        max_steps: int | float | None = None,
        reset_overrides: ResetOverrides | None = None,
        compile: bool = False,
        goal_key: NestedKey | None = None,
        achieved_goal_key: NestedKey | None = None,
        goal_name: str | None = None,
        cost_key: NestedKey = COST_KEY,
        cost_terms_key: NestedKey = COST_TERMS_KEY,
        ended_by_key: NestedKey = ENDED_BY_KEY,
        curriculum_key: NestedKey | None = CURRICULUM_KEY,
        vector_reward_key: NestedKey = VECTOR_REWARD_KEY,
        groups_key: NestedKey = GROUPS_KEY,
    ) -> None:
        if not isinstance(task, Task):
            raise TypeError(f"task must be a torchtasks Task, got {type(task).__name__}")
        if reward_on not in ("next", "state"):
            raise ValueError(f"reward_on must be 'next' or 'state', got {reward_on!r}")
        # math.inf: no time limit on purpose (Pyrado's max_steps=inf): the remaining steps are 0, without a warning
        self._no_limit = isinstance(max_steps, float) and max_steps == math.inf
        if self._no_limit or max_steps is None:
            max_steps = None
        else:
            max_steps = check_positive_int(max_steps, "TaskTransform: max_steps")
        if reset_overrides is not None and not callable(reset_overrides):
            raise TypeError(f"reset_overrides must be callable, got {type(reset_overrides).__name__}")
        for name, flag in (("log_terms", log_terms), ("compile", compile)):
            if not isinstance(flag, bool):
                raise TypeError(f"TaskTransform: {name} must be a bool, got {flag!r}")
        if goal_name is not None and goal_key is None and achieved_goal_key is None:
            raise ValueError(
                f"TaskTransform: goal_name={goal_name!r} names the goal task that goal_key (or achieved_goal_key) "
                "feeds; pass goal_key=... too"
            )
        state_keys = _state_keys(state_key)
        reserved = {STEP_TERM, FINAL_TERM} & set(task.term_names)
        if log_terms and reserved:
            raise ValueError(f"reward terms may not be named {sorted(reserved)}: those names are the breakdown's")
        self.state_keys = state_keys
        self.action_key = nested_key(action_key, "TaskTransform: action_key")
        self.reward_key = nested_key(reward_key, "TaskTransform: reward_key")
        self.memory_key = nested_key(memory_key, "TaskTransform: memory_key")
        self.success_key = nested_key(success_key, "TaskTransform: success_key")
        self.failure_key = nested_key(failure_key, "TaskTransform: failure_key")
        self.terms_key = nested_key(terms_key, "TaskTransform: terms_key")
        self.cost_key = nested_key(cost_key, "TaskTransform: cost_key")
        self.cost_terms_key = nested_key(cost_terms_key, "TaskTransform: cost_terms_key")
        self.cost_names = tuple(task.cost_names)
        self.vector_reward_key = nested_key(vector_reward_key, "TaskTransform: vector_reward_key")
        self.groups_key = nested_key(groups_key, "TaskTransform: groups_key")
        self.group_names = tuple(task.group_names)
        self.ended_by_key = nested_key(ended_by_key, "TaskTransform: ended_by_key")
        self.curriculum_key = (
            None if curriculum_key is None else nested_key(curriculum_key, "TaskTransform: curriculum_key")
        )
        self.reward_on = reward_on
        self.log_terms = log_terms
        self.goal_key = None if goal_key is None else nested_key(goal_key, "TaskTransform: goal_key")
        self.achieved_goal_key = (
            None if achieved_goal_key is None else nested_key(achieved_goal_key, "TaskTransform: achieved_goal_key")
        )
        self._goal_slot = (
            _goal_slot(task, goal_name) if (goal_key is not None or achieved_goal_key is not None) else None
        )
        self.reset_overrides = reset_overrides
        self.compile = compile
        self._explicit_max_steps = max_steps
        # every entry the transform writes, once: keys, specs, writes and relabelling read this table
        entries = task_entries(
            task,
            reward_key=self.reward_key,
            memory_key=self.memory_key,
            success_key=self.success_key,
            failure_key=self.failure_key,
            terms_key=self.terms_key,
            cost_key=self.cost_key,
            cost_terms_key=self.cost_terms_key,
            ended_by_key=self.ended_by_key,
            achieved_goal_key=self.achieved_goal_key,
            log_terms=log_terms,
            vector_reward_key=self.vector_reward_key,
            groups_key=self.groups_key,
        )
        self._entries = entries
        # the named end conditions, written when a kind has two or more (else success and failure say it)
        self.termination_names = entries.names("ended_by_key")
        self._ended_by_keys = entries.keys(argument="ended_by_key")
        # a task tree without memory tensors (e.g. GoallessTask) registers and writes no memory entry: batched
        # envs refuse empty specs; its (empty) memory is built in the step. Likewise the empty sub-memories of
        # memory-less sub-tasks (a FinalRewardTask's "wrapped" around a GoallessTask) are neither registered nor
        # written, and are put back when the memory is read
        self._has_memory = bool(entries.select(kinds=("memory",)))
        self._hollow = hollow_paths(task.memory_layout) if self._has_memory else ()
        self._uses_remaining = task.uses_remaining_steps
        self._check_key_collisions()
        memory_keys = entries.keys(kinds=("memory",))
        goal_keys = [] if self.goal_key is None else [self.goal_key]
        in_keys = [*state_keys, self.action_key, *memory_keys, *goal_keys]
        out_keys = [row.key for row in entries.rows if row.argument is not None]
        super().__init__(in_keys=in_keys, out_keys=out_keys)
        self.task = task
        self._writes = self._write_plans(entries)
        self._reset_flags = tuple(entries.keys(occasion="reset", kinds=("flag",)))
        # the success and failure flags the tree defines (see TaskFacts.can_succeed, can_fail)
        self._outcome_keys = tuple(row.key for row in entries.select(kinds=("flag",)) if row.item is None)
        if log_terms:
            _refuse_episode_sums(entries.names("terms_key"), "reward term", "terms_key", self.terms_key)
        _refuse_episode_sums(entries.names("cost_terms_key"), "cost", "cost_terms_key", self.cost_terms_key)
        _refuse_episode_sums(entries.names("groups_key"), "reward group", "groups_key", self.groups_key)
        _refuse_summed_over(entries)

    def _write_plans(self, entries: TaskEntries) -> dict[tuple[str, bool], tuple[tuple[Any, ...], ...]]:
        """What a step writes, per occasion and per whether the data holds the env's ``terminated`` flag: rows of
        ``(key, read the field, the entry of the field or None, write as)``, derived once from the table."""
        write_as = dict(_WRITE_AS)
        write_as["costs"] = functools.partial(_as_stacked, entries.names("cost_terms_key"))
        group_dtype = self.task.group_dtype
        write_as["group"] = functools.partial(_as_group, group_dtype)
        write_as["groups"] = functools.partial(_as_vector, entries.names("groups_key"), group_dtype)
        write_as["goal"] = None if self._goal_slot is None else functools.partial(_as_achieved, self._goal_slot)

        def plan(row: Entry) -> tuple[Any, ...]:
            read = None if row.source is None else transition_field(row.source)
            return row.key, read, row.item, write_as[row.kind]

        plans = {}
        for occasion in ("step", "offline", "relabel"):
            for has_terminated in (False, True):
                rows = entries.select(occasion=occasion)
                if not has_terminated:  # the env's terminated flag is written only where the data holds it
                    rows = tuple(row for row in rows if row.key != TERMINATED_KEY)
                plans[occasion, has_terminated] = tuple(plan(row) for row in rows)
        return plans

    def _check_key_collisions(self) -> None:
        """Refuse output keys that would overwrite each other, the env's done flags or the transform's inputs."""
        outputs = [(f"{argument}={key!r}", key) for argument, key in self._entries.claims]
        others = [(f"the env's {flag!r} flag", flag) for flag in (DONE_KEY, TERMINATED_KEY, TRUNCATED_KEY)]
        others += [(f"the state key {key!r}", key) for key in self.state_keys]
        others.append((f"action_key={self.action_key!r}", self.action_key))
        if self.curriculum_key is not None:  # read offline: the values a Curriculum or levels recorded
            others.append((f"curriculum_key={self.curriculum_key!r}", self.curriculum_key))
        for i, (name, key) in enumerate(outputs):
            for other_name, other in outputs[i + 1 :] + others:
                if _overlap(key, other):
                    raise ValueError(
                        f"TaskTransform: {name} collides with {other_name}: the transform writes each output under "
                        "its own key, so no key may equal another or contain it; pick distinct keys"
                    )

    # ------------------------------------------------------------------ configuration
    @property
    def entries(self) -> TaskEntries:
        """The table of the entries this transform writes: one row per output (key, kind, source, when written).

        Example:
            >>> from torchtasks.envs import swing_up_task
            >>> transform = TaskTransform(swing_up_task(), terms_key="terms")
            >>> transform.entries.keys(occasion="relabel", kinds=("reward", "flag", "env_flag"))
            ['reward', 'success', 'failure', 'terminated', 'done']
        """
        return self._entries

    def undefined_flag(self, key: NestedKey) -> str | None:
        """Why this transform writes no entry ``key``, when ``key`` is its success (failure) key and the task tree
        cannot succeed (fail); ``None`` otherwise. For the errors of the transforms that read the flags.

        Example:
            >>> from torchtasks.rewards import ConstantReward
            >>> from torchtasks.spaces import EnvSpec
            >>> from torchtasks.tasks import GoallessTask
            >>> transform = TaskTransform(GoallessTask(EnvSpec(1, 1), ConstantReward(1.0)))
            >>> print(transform.undefined_flag("success"))  # doctest: +NORMALIZE_WHITESPACE
            its task (GoallessTask) has no success condition (task.facts.can_succeed is False), so the
            TaskTransform writes no success_key='success'
            >>> transform.undefined_flag("failure") is None
            True
        """
        key = unravel_key(key)
        facts = self.task.facts
        for name, flag_key, fact in (
            ("success", self.success_key, "can_succeed"),
            ("failure", self.failure_key, "can_fail"),
        ):
            if key == flag_key and not getattr(facts, fact):
                return (
                    f"its task ({type(self.task).__name__}) has no {name} condition (task.facts.{fact} is False), "
                    f"so the TaskTransform writes no {name}_key={flag_key!r}"
                )
        return None

    @property
    def term_keys(self) -> list[NestedKey]:
        """Keys of the reward breakdown: step and final reward (if the tree pays a final reward), then the terms."""
        return self._entries.keys(argument="terms_key")

    @property
    def cost_keys(self) -> list[NestedKey]:
        """Keys of the per-constraint costs ``(cost_terms_key, name)``, one per cost of the tree (none without)."""
        return self._entries.keys(argument="cost_terms_key")

    @property
    def group_keys(self) -> list[NestedKey]:
        """Keys of the reward groups: the vector ``vector_reward_key`` then ``(groups_key, name)`` per group (none
        for a tree without groups), e.g. for ``RewardSum(in_keys=[...])``."""
        return self._entries.keys(kinds=("groups", "group"))

    def _container_env(self) -> Any:
        return container_env(self)  # None when not in an env (e.g. a replay buffer's transform)

    def _time_limit(self, observation_spec: Composite | None = None) -> TimeLimit:
        """Return the :class:`TimeLimit` (``max_steps``, ``step_count_key``, ``enforced``) of the env the transform
        is in now.

        ``max_steps`` is the explicit one or that of the first ``StepCounter`` with a limit preceding this
        transform (in its Compose, or in a TransformedEnv it wraps); ``enforced`` says whether that
        StepCounter truncates there (an explicit limit must then equal it: ``ValueError`` otherwise).
        Derived from the current container every time (never cached here): a transform moved, cloned or
        deep-copied into another env finds that env's limit. Raises ``ValueError`` for a StepCounter after
        the transform and, given the observation spec, for a time-dependent task in an env that counts
        steps with a limit the transform cannot see.
        """
        max_steps, step_count_key, counters = self._explicit_max_steps, "step_count", []
        container = self._container_env()
        if container is not None and getattr(container, "transform", None) is not None:
            transforms = flat_transforms(container.transform)
            position = next((i for i, t in enumerate(transforms) if t is self), None)
            for i, transform in enumerate(transforms):
                if not isinstance(transform, StepCounter):
                    continue
                if position is not None and i > position:
                    raise ValueError(
                        "StepCounter is placed after TaskTransform: the task would not see step_count and "
                        "truncation. Put StepCounter(max_steps) before TaskTransform in the Compose."
                    )
                counters.append(transform)
            inner = container.base_env  # envs wrapped with auto_unwrap=False: their transforms come first
            while isinstance(inner, TransformedEnv):
                counters[:0] = [t for t in flat_transforms(inner.transform) if isinstance(t, StepCounter)]
                inner = inner.base_env
            _check_vector_gym(container.base_env)
        counter = next((c for c in counters if c.max_steps is not None), None)
        if self._no_limit:
            if counter is not None:
                raise ValueError(
                    f"TaskTransform(max_steps=math.inf) says the env has no time limit, but StepCounter(max_steps="
                    f"{counter.max_steps}) precedes it. Leave max_steps out (the transform reads the StepCounter's "
                    "limit) or remove the StepCounter's limit."
                )
            return TimeLimit(None, step_count_key, enforced=False)
        if max_steps is None:
            if counter is not None:
                max_steps, step_count_key = counter.max_steps, counter.step_count_key
        elif counter is not None and counter.max_steps != max_steps:
            raise ValueError(
                f"TaskTransform(max_steps={max_steps}) disagrees with the preceding StepCounter(max_steps="
                f"{counter.max_steps}): the remaining steps max_steps - step_count would be wrong"
                + (f", and negative after step {max_steps}" if counter.max_steps > max_steps else "")
                + ". Leave max_steps out (the transform reads the StepCounter's limit) or pass the same limit."
            )
        if (
            max_steps is None
            and not counters
            and self._uses_remaining
            and observation_spec is not None
            and "step_count" in observation_spec.keys()
        ):
            raise ValueError(
                f"TaskTransform: {type(self.task).__name__} reads the remaining steps (a time-dependent final "
                "reward) and the env counts steps ('step_count' is in its observation spec), but no time limit "
                "reaches the transform: max_steps is not given and no StepCounter precedes TaskTransform in its "
                "Compose (e.g. a StepCounter inside the workers of a batched env is not visible to it). "
                "Pass TaskTransform(..., max_steps=<the env's limit>), or put StepCounter(max_steps) before "
                "TaskTransform in the same Compose."
            )
        return TimeLimit(max_steps, step_count_key, enforced=counter is not None)

    def _preceding_transforms(self) -> list[tuple[Transform, bool]]:
        """The transforms that run before this one in its env, each with whether it sits in a wrapped env.

        Those of the TransformedEnvs the container wraps (``auto_unwrap=False``) come first, then the ones
        before this transform in its (flattened) Compose. Empty outside an env.
        """
        container = self._container_env()
        if container is None or getattr(container, "transform", None) is None:
            return []
        transforms = flat_transforms(container.transform)
        position = next((i for i, t in enumerate(transforms) if t is self), len(transforms))
        preceding = [(t, False) for t in transforms[:position]]
        inner = container.base_env
        while isinstance(inner, TransformedEnv):
            preceding[:0] = [(t, True) for t in flat_transforms(inner.transform)]
            inner = inner.base_env
        return preceding

    def _overwritten_keys(self) -> list[tuple[NestedKey, str]]:
        """The reward-spec entries this transform writes, each with the argument that names it."""
        entries = self._entries
        under = {
            "term": "a reward term",
            "cost": "a cost",
            "group": "a reward group",
        }  # entries under an argument's key
        return [
            (row.key, f"{under[row.kind]} of {row.argument}={entries.root(row.argument)!r}")
            if row.kind in under
            else (row.key, row.argument)
            for row in entries.select(spec="reward")
        ]

    def _check_reward_sums(self) -> None:
        """Refuse a ``RewardSum`` before this transform that sums an entry this transform overwrites.

        Transforms run in order: such a RewardSum adds up the env's value of the entry (e.g. a reward
        that is always 0), and the task's value written afterwards never reaches the episode sum.
        A RewardSum of other entries (an env reward the task does not write) may precede the task.
        """
        written = self._overwritten_keys()
        for transform, wrapped in self._preceding_transforms():
            if not isinstance(transform, RewardSum):
                continue
            in_keys = list(transform.in_keys)
            for key, argument in written:
                index = next((i for i, in_key in enumerate(in_keys) if _overlap(in_key, key)), None)
                if index is None:
                    continue
                where = (
                    "in a TransformedEnv that TaskTransform wraps (its transforms run first)"
                    if wrapped
                    else "before TaskTransform in the Compose"
                )
                fix = (
                    "Remove it from the wrapped env and put RewardSum after TaskTransform"
                    if wrapped
                    else "Put RewardSum after TaskTransform in the Compose"
                )
                raise ValueError(
                    f"TaskTransform: a RewardSum(in_keys={in_keys!r}) is placed {where}; it sums {key!r} "
                    f"({argument}), which TaskTransform overwrites afterwards, so its episode sum "
                    f"{transform.out_keys[index]!r} would add up the env's values, not the task's (e.g. stay 0). "
                    f"{fix}, e.g. Compose(StepCounter(max_steps), TaskTransform(task), RewardSum())."
                )

    def _warn_no_time_limit(self, max_steps: int | None) -> None:
        """Warn (once per env) that a time-dependent task gets no time limit: its remaining steps are 0."""
        if self._no_limit or not self._uses_remaining or max_steps is not None or self.__dict__.get("_warned_no_limit"):
            return
        original = self.__dict__.get("_original")
        source = None if original is None else original()
        if source is not None and source is not self:
            env, home = self._container_env(), source._container_env()
            if home is not None and getattr(env, "base_env", None) is getattr(home, "base_env", self):
                return  # TorchRL's clone in a later transform's view of the same env: the transform itself warns
        self.__dict__["_warned_no_limit"] = True
        counters = [t for t, _ in self._preceding_transforms() if isinstance(t, StepCounter)]
        seen = "a StepCounter without max_steps" if counters else "no StepCounter"
        warnings.warn(
            f"TaskTransform: {type(self.task).__name__} reads the remaining steps (a time-dependent final reward), "
            f"but no time limit reaches the transform: max_steps is not given and {seen} precedes it, so the "
            "remaining steps are 0 (Pyrado's 'no limit') and the final reward does not depend on time. Put "
            "StepCounter(max_steps) before TaskTransform in the Compose, or pass TaskTransform(..., max_steps=...) "
            "(max_steps=math.inf: no limit on purpose, and no warning).",
            UserWarning,
            stacklevel=2,
        )

    def _setup(self, observation_spec: Composite | None = None) -> TimeLimit:
        """Derive the time limit for the current container and store what the step reads (at spec building).

        Given the observation spec (spec building), also check the transforms before this one: a
        ``RewardSum`` of an entry the task overwrites is refused, a missing limit for a time-dependent
        task is warned about.
        """
        max_steps, step_count_key, enforced = self._time_limit(observation_spec)
        if observation_spec is not None:
            self._check_reward_sums()
            if self._container_env() is not None:
                self._warn_no_time_limit(max_steps)
        # the step computes the remaining steps only for a task tree that reads them and a known limit;
        # a limit no StepCounter enforces (given as max_steps) is checked against the step counts it meets
        limit = TimeLimit(max_steps if self._uses_remaining else None, step_count_key, enforced)
        self.__dict__["_limit"] = limit
        return limit

    def _forget_setup(self) -> None:
        """Drop what was derived for the previous env (the next spec building or step derives it again)."""
        self.__dict__.pop("_limit", None)
        self.__dict__.pop("_warned_no_limit", None)

    @property
    def max_steps(self) -> int | None:
        """The time limit used for the remaining steps (None: no limit, remaining steps are 0).

        Read from the env the transform is in now (nothing is frozen by reading it).
        """
        return self._time_limit().max_steps

    # ------------------------------------------------------------------------- specs
    def _state_spec_size(self, observation_spec: Composite) -> tuple[int, torch.dtype, torch.Size]:
        size = 0
        dtype = None
        batch = observation_spec.shape
        for key in self.state_keys:
            if key not in observation_spec.keys(True, True):
                raise KeyError(
                    f"TaskTransform: the state key {key!r} is not in the observation spec; available keys are "
                    f"{keys_text(observation_spec.keys(True, True))}. Pass state_key=... naming the entry "
                    "that holds the task's state."
                )
            spec = observation_spec[key]
            if spec.shape[: len(batch)] != batch or len(spec.shape) != len(batch) + 1:
                raise ValueError(
                    f"TaskTransform: the state entry {key!r} must have shape [*batch, n], got {tuple(spec.shape)}"
                )
            if spec.dtype not in SUPPORTED_FLOATS:
                kind = "half precision is not supported" if spec.dtype.is_floating_point else "not a float dtype"
                raise TypeError(
                    f"TaskTransform: the state entries {self.state_keys} have dtype {spec.dtype} (state key "
                    f"{key!r}: {spec.dtype}, {kind}); tasks evaluate float32 or float64 states. Cast the entry "
                    "first (e.g. with torchrl's DTypeCastTransform) or pick another state_key"
                )
            size += spec.shape[-1]
            dtype = spec.dtype if dtype is None else torch.promote_types(dtype, spec.dtype)
        if size != self.task.state_size:
            raise ValueError(
                f"TaskTransform: the task reads states of size {self.task.state_size} but {self.state_keys} "
                f"holds {size} entries; build the task for this env's state or pick another state_key"
            )
        return size, dtype, batch

    def _check_action_spec(self, batch: torch.Size) -> None:
        """The action entry exists in the env's action spec and has the task's action size."""
        parent = self.parent
        if parent is None:
            return
        action_spec = parent.full_action_spec
        keys = list(action_spec.keys(True, True))
        if self.action_key not in keys:
            raise KeyError(
                f"TaskTransform: the action key {self.action_key!r} is not in the env's action spec; available "
                f"keys are {keys_text(keys)}. Pass action_key=... naming the action entry."
            )
        shape = action_spec[self.action_key].shape
        if len(shape) != len(batch) + 1 or shape[: len(batch)] != batch:
            raise ValueError(
                f"TaskTransform: the action entry {self.action_key!r} must have shape [*batch, m] with batch "
                f"{tuple(batch)}, got {tuple(shape)}"
            )
        if shape[-1] != self.task.action_size:
            raise ValueError(
                f"TaskTransform: the task reads actions of size {self.task.action_size} but the env's action "
                f"{self.action_key!r} (action_key) has {shape[-1]} entries; build the task for this env's actions "
                "or pick another action_key"
            )

    def _memory_spec(self, batch: torch.Size, dtype: torch.dtype, device: torch.device | None) -> Composite:
        init_state = torch.zeros((*batch, self.task.state_size), dtype=dtype, device=device)
        memory = without_hollow(self.task._reset(init_state, self._overrides(init_state)), self._hollow)
        spec = make_composite_from_td(memory, unsqueeze_null_shapes=False)
        return spec.to(device) if device is not None else spec

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        _, dtype, batch = self._state_spec_size(observation_spec)
        self._check_action_spec(batch)
        self._setup(observation_spec)
        self.task.to(dtype)
        self.__dict__["_state_dtype"] = dtype
        device = observation_spec.device
        done_shape = self.parent.full_done_spec[DONE_KEY].shape if self.parent is not None else (*batch, 1)
        for row in self._entries.select(spec="observation"):
            if row.kind == "flag":
                observation_spec[row.key] = Categorical(2, shape=done_shape, dtype=torch.bool, device=device)
            elif row.kind == "memory":
                observation_spec[row.key] = self._memory_spec(batch, dtype, device)
            else:  # the achieved goal
                size = self._goal_slot.size
                observation_spec[row.key] = Unbounded(shape=(*batch, size), dtype=dtype, device=device)
        return observation_spec

    def transform_state_spec(self, state_spec: Composite) -> Composite:
        parent = self.parent
        observation_spec = parent.full_observation_spec
        _, dtype, batch = self._state_spec_size(observation_spec)
        if state_spec is None:
            state_spec = Composite(shape=batch, device=observation_spec.device)
        for row in self._entries.select(spec="state"):  # the memory: an input of the next step
            state_spec[row.key] = self._memory_spec(batch, dtype, observation_spec.device)
        return state_spec

    def transform_reward_spec(self, reward_spec: Composite) -> Composite:
        if self.reward_key not in reward_spec.keys(True, True):
            raise KeyError(f"TaskTransform: the reward key {self.reward_key!r} is not in the reward spec")
        base = reward_spec[self.reward_key]
        self.__dict__["_reward_dtype"] = base.dtype
        group_dtype = base.dtype if self.task.group_dtype is None else self.task.group_dtype
        stacked = {"costs": len(self.cost_names), "groups": len(self.group_names)}  # [*B, k] entries
        for row in self._entries.select(spec="reward", kinds=("term", "cost", "costs", "group", "groups")):
            shape = (*base.shape[:-1], stacked[row.kind]) if row.kind in stacked else base.shape
            dtype = group_dtype if row.kind in ("group", "groups") else base.dtype
            reward_spec[row.key] = Unbounded(shape=shape, dtype=dtype, device=base.device)
        return reward_spec

    # ----------------------------------------------------------------------- helpers
    def _overrides(self, init_state: torch.Tensor) -> dict[str, Any]:
        if self.reset_overrides is None:
            return {}
        overrides = self.reset_overrides(init_state)
        if not isinstance(overrides, Mapping):
            raise TypeError(
                "TaskTransform: reset_overrides must return a mapping {name: per-env value}, got "
                f"{type(overrides).__name__}"
            )
        self.task.check_reset_overrides(overrides, "TaskTransform: reset_overrides returned ")
        return dict(overrides)

    def _check_stored(
        self, tensordict: TensorDictBase, state: torch.Tensor, next_state: torch.Tensor, action: torch.Tensor
    ) -> None:
        """Stored transitions must fit the task as an env's data does: sizes, float dtypes, the data's batch shape."""
        keys = self.state_keys[0] if len(self.state_keys) == 1 else self.state_keys
        batch = tuple(tensordict.batch_size)
        for name, value, size in (
            (f"the stored state {keys!r}", state, self.task.state_size),
            (f"the stored next state ('next', {keys!r})", next_state, self.task.state_size),
            (f"the stored action {self.action_key!r}", action, self.task.action_size),
        ):
            check_input(value, f"TaskTransform: {name}", size)
            if tuple(value.shape[:-1]) != batch:
                raise ValueError(
                    f"TaskTransform: {name} must have shape {[*batch, size]} (the data's batch size {list(batch)}, "
                    f"then the task's {size} entries), got {list(value.shape)}"
                )

    def _read_state(self, tensordict: TensorDictBase) -> torch.Tensor:
        if len(self.state_keys) == 1:
            state = td_get(tensordict, self.state_keys[0])
            if state is None:
                self._missing_state(tensordict)
            return state
        parts = [td_get(tensordict, key) for key in self.state_keys]
        if any(part is None for part in parts):
            self._missing_state(tensordict)
        return torch.cat(parts, dim=-1)

    def _missing_state(self, tensordict: TensorDictBase) -> None:
        try:
            parent = self.parent
        except (AttributeError, ValueError):
            parent = None
        if parent is not None:  # the spec check says which keys the env offers
            self._state_spec_size(parent.full_observation_spec)
        raise KeyError(
            f"TaskTransform: the state key(s) {self.state_keys} are missing from the data; available keys are "
            f"{keys_text(tensordict.keys(True, True))}. Pass state_key=... naming the entry that holds "
            "the task's state."
        )

    def _missing_entry(self, tensordict: TensorDictBase, what: str, hint: str) -> None:
        raise KeyError(
            f"TaskTransform: {what} is missing from the data; available keys are "
            f"{keys_text(tensordict.keys(True, True))}. {hint}"
        )

    def _missing_memory(self, tensordict: TensorDictBase, offline: bool) -> None:
        if offline:
            hint = (
                "Stored transitions need the task memory before the step at the root, as collected with this "
                "TaskTransform (pass memory_key=... if it was collected under another key)."
            )
        else:
            hint = (
                "The memory is written at reset: call env.reset() first and step from the tensordict it "
                "returns (then from env.step_mdp(...) of each step's output)."
            )
        self._missing_entry(tensordict, f"the task memory (memory_key={self.memory_key!r})", hint)

    def _missing_action(self, tensordict: TensorDictBase) -> None:
        try:
            parent = self.parent
        except (AttributeError, ValueError):
            parent = None
        if parent is not None:  # the spec check names the keys of the env's action spec
            self._check_action_spec(parent.full_observation_spec.shape)
        self._missing_entry(
            tensordict, f"the action (action_key={self.action_key!r})", "Pass action_key=... naming the action entry."
        )

    def _read_goal(self, tensordict: TensorDictBase, state: torch.Tensor) -> torch.Tensor:
        goal = td_get(tensordict, self.goal_key)
        size = self._goal_slot.size
        if goal is None:
            self._missing_entry(
                tensordict,
                f"the goal {self.goal_key!r}",
                "Write the goal the policy sees at the root of the data (e.g. with a GoalCommand in the env), or "
                "drop goal_key to use the task's own desired state.",
            )
        if goal.shape != (*state.shape[:-1], size):
            raise ValueError(
                f"TaskTransform: the goal {self.goal_key!r} must have shape {[*state.shape[:-1], size]} (the "
                f"{size} entries of the goal task {self._goal_slot.name!r}), got {list(goal.shape)}"
            )
        return goal if goal.dtype == state.dtype else goal.to(state.dtype)

    def _remaining(self, next_tensordict: TensorDictBase, reference: torch.Tensor, offline: bool) -> torch.Tensor:
        limit = self.__dict__.get("_limit")
        if limit is None:
            limit = self._setup()
        max_steps, step_count_key, enforced = limit
        if max_steps is None:
            # no limit (Pyrado passes 0), or no task of the tree reads it: skip the arithmetic
            return self.task.no_remaining_steps
        step_count = td_get(next_tensordict, step_count_key)
        if step_count is None:
            self._missing_entry(
                next_tensordict,
                f"the step count ('next', {step_count_key!r})",
                f"{type(self.task).__name__} reads the remaining steps, max_steps - step_count with "
                f"max_steps={max_steps}: the data must hold the step count after each step under "
                f"('next', {step_count_key!r}) (as written by StepCounter).",
            )
        remaining = max_steps - step_count.reshape(reference.shape[:-1])
        if offline or not enforced:  # a limit no StepCounter enforces here: check the counts it meets
            _check_within_limit(remaining, step_count, max_steps, step_count_key)
        return remaining

    def _empty_memory(self, state: torch.Tensor) -> TensorDictBase:
        """The memory of a task tree without memory tensors, for the batch of ``state`` (cached per batch shape)."""
        memory = self.__dict__.get("_empty_template")
        if memory is None or memory.batch_size != state.shape[:-1]:
            memory = self.task._reset(state, {})
            self.__dict__["_empty_template"] = memory
        return memory

    def _evaluator(self) -> Callable[..., Any]:
        """The task's transition function (:meth:`Task._transition`), compiled with ``compile=True``."""
        if not self.compile:
            return self.task._transition
        compiled = self.__dict__.get("_compiled_transition")
        if compiled is None:
            compiled = torch.compile(self.task._transition, fullgraph=True, dynamic=False)
            self.__dict__["_compiled_transition"] = compiled
        return compiled

    # ----------------------------------------------------------- recorded buffer values (offline)
    def _recorded_in_env(self) -> dict[str, tuple[RecordedValue, str]]:
        """The task buffers that transforms after this one in its env set at every step (a Curriculum's schedules,
        levels' per-env values), each with its record and the name of the transform that sets it."""
        home = self.home_transforms()
        if home is None:
            return {}
        flat, position = home
        found = {}
        for transform in flat[position + 1 :]:
            recorded = getattr(transform, "recorded_task_values", None)
            if recorded is not None:
                found.update((record.buffer, (record, type(transform).__name__)) for record in recorded())
        return found

    def _recorded_in_data(self, tensordict: TensorDictBase, batch: torch.Size) -> dict[str, RecordedValue]:
        """The entries under ``curriculum_key`` that name a float buffer of the task (``"/"`` for ``"."``).

        Whether a buffer held one value shared by all envs or one per env is read from the shapes: an entry of the
        buffer's shape, or ``[*B, 1]``, is a shared value; a per-env buffer ``[*B_env, *row]`` has entries
        ``[*B, *row]``.
        """
        node = None if self.curriculum_key is None else td_get(tensordict, self.curriculum_key)
        if not isinstance(node, TensorDictBase):
            return {}
        buffers = {name: buffer for name, buffer in self.task.named_buffers() if buffer.is_floating_point()}
        found = {}
        for name in node.keys():
            target = target_name(name)  # a buffer's name in full, or a short name of it (a suffix ending it only)
            recorded = names_task_buffer(target) and name not in (FRAMES, LEVEL)
            matches = suffix_matches(target, buffers) if recorded else []
            if len(matches) != 1:
                continue  # e.g. the frame count, the levels, a GoalCommand's range or an env field
            buffer = buffers[matches[0]]
            trailing, shape = node.get(name).shape[len(batch) :], buffer.shape
            per_env = (
                trailing not in (shape, (1,))
                and len(shape) > len(trailing)
                and shape[len(shape) - len(trailing) :] == trailing
            )
            record = RecordedValue(matches[0], (*key_parts(self.curriculum_key), name), trailing if per_env else None)
            found[record.buffer] = record
        return found

    def _recorded_values(
        self, tensordict: TensorDictBase, batch: torch.Size
    ) -> list[tuple[nn.Module, str, torch.Tensor]]:
        """``(module, buffer name, values)`` for every task buffer whose values the data records, one value per frame.

        In an env whose transforms set task buffers, their entries must be in the data (``ValueError`` otherwise:
        today's value would pay rewards no step paid); outside, the entries under ``curriculum_key`` are read.
        """
        in_env = self._recorded_in_env()
        records = self._recorded_in_data(tensordict, batch)
        records.update((name, record) for name, (record, _) in in_env.items())
        values = []
        for name, record in records.items():
            entry = td_get(tensordict, record.key)
            if entry is None:
                _, owner = in_env[name]
                raise ValueError(
                    f"TaskTransform: the data lacks {record.key!r}, the value of the task buffer {name!r} that the "
                    f"env's {owner} sets at every step; recomputing with its value of today would pay rewards no step "
                    f"paid. Keep that entry with the stored transitions (the env writes it at the root of every "
                    f"step), or recompute with a TaskTransform outside this env (curriculum_key=None: with the "
                    f"task's buffers as they are now)."
                )
            module, leaf = buffer_owner(self.task, name)
            values.append((module, leaf, _frame_values(entry, module._buffers[leaf], batch, record)))
        return values

    def _evaluate_recorded(self, tensordict: TensorDictBase, arguments: tuple, batch: torch.Size) -> Transition:
        """Evaluate stored transitions; the task buffers the data records hold each frame's value for the call.

        ``arguments`` are those of :meth:`Task._transition` for the frames of batch shape ``batch``. The values go
        into the buffers' places (as the Curriculum replaces a buffer under grad mode) and the buffers are put back
        afterwards; kernels take a constant with leading batch dims (one value per row).
        """
        values = self._recorded_values(tensordict, batch)
        if not values:
            return self._evaluator()(*arguments, self.log_terms)
        for module in self.task.modules():  # facts a task derives once (its memory layout probes a reset with its
            if isinstance(module, Task):  # buffers): derived now, from the buffers' own values
                _ = module.memory_layout
        saved = [(module, leaf, module._buffers[leaf]) for module, leaf, _ in values]
        try:
            for module, leaf, value in values:
                module._buffers[leaf] = value
            outputs = self.task._transition(*arguments, self.log_terms)
        except RuntimeError as error:  # a kernel that reads a constant without broadcasting over leading dims
            names = [f"{type(module).__name__}.{leaf}" for module, leaf, _ in values]
            raise ValueError(
                f"TaskTransform: the task failed to evaluate stored transitions with one value per frame of the "
                f"buffers {names} (the values the data records): {error}"
            ) from error
        finally:
            for module, leaf, buffer in saved:
                module._buffers[leaf] = buffer
        reward = _reward_of(outputs)
        if reward.shape != batch:
            raise ValueError(
                f"TaskTransform: with one value per frame of the recorded task buffers "
                f"{[f'{type(m).__name__}.{leaf}' for m, leaf, _ in values]}, the task returned rewards of shape "
                f"{list(reward.shape)} for a batch {list(batch)}: a reward reads one of them without broadcasting "
                "over leading batch dims"
            )
        return outputs

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        for key in ("_compiled_transition", "_limit", "_empty_template"):
            state.pop(key, None)
        return state

    def _episode_end_flags(
        self, next_tensordict: TensorDictBase, batch: torch.Size, offline: bool
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None, bool]:
        """Return ``(done, terminated, truncated, has_terminated)``: the env's own end flags, the last two ``[*B]``.

        Online the env's flags are its own. Offline (stored transitions, possibly relabelled) the
        stored ``terminated`` already includes the task's old success and failure: only what the
        task did not cause (the env's own termination and the truncation) is kept, so the task
        judges the episode end anew.
        """
        done = td_get(next_tensordict, DONE_KEY)
        terminated = td_get(next_tensordict, TERMINATED_KEY)
        truncated = td_get(next_tensordict, TRUNCATED_KEY)
        has_terminated = terminated is not None
        if truncated is None and has_terminated:
            truncated = done & ~terminated
        if not has_terminated:
            terminated = done
        if offline:  # the stored verdicts of the outcome flags the tree defines (all of them, or none, stored)
            old = [td_get(next_tensordict, key) for key in self._outcome_keys]
            if old and all(flag is not None for flag in old):
                terminated = terminated & ~functools.reduce(operator.or_, old)
        truncated = None if truncated is None else truncated.reshape(batch)
        return done, terminated.reshape(batch), truncated, has_terminated

    def _transition(
        self,
        tensordict: TensorDictBase,
        next_tensordict: TensorDictBase,
        occasion: Literal["step", "offline", "relabel"] = "step",
    ) -> TensorDictBase:
        """Evaluate the task on one batch of transitions and write its outputs into ``next_tensordict``.

        The evaluation is :meth:`Task._transition`, the function behind :meth:`Task.transition`. ``occasion``:
        the env's step, or stored transitions (``"offline"``: the stored next memory is left as it was;
        ``"relabel"``: it is rewritten); the entries written are the table's rows for that occasion.
        """
        offline = occasion != "step"
        state = self._read_state(tensordict)
        next_state = self._read_state(next_tensordict)
        action = td_get(tensordict, self.action_key)
        if action is None:
            self._missing_action(tensordict)
        if offline:  # stored data: no env spec was checked for it
            self._check_stored(tensordict, state, next_state, action)
        if action.dtype != state.dtype:
            action = action.to(state.dtype)
        if self._has_memory:
            memory = td_get(tensordict, self.memory_key)
            if memory is None:
                self._missing_memory(tensordict, offline)
            if self._hollow:  # the empty sub-memories of memory-less sub-tasks, which the data do not hold
                memory = with_hollow(memory, self._hollow)
        else:
            memory = self._empty_memory(state)
        if self.goal_key is not None:
            memory = replace_goals(memory, {self._goal_slot: self._read_goal(tensordict, state)})
        done, env_terminated, truncated, has_terminated = self._episode_end_flags(
            next_tensordict, state.shape[:-1], offline
        )
        remaining = self._remaining(next_tensordict, state, offline)
        arguments = (state, action, next_state, memory, remaining, env_terminated, truncated, self.reward_on)
        if offline:  # stored data: each frame with the values its step used for the buffers the data records
            outputs = self._evaluate_recorded(tensordict, arguments, state.shape[:-1])
        else:
            outputs = self._evaluator()(*arguments, self.log_terms)
        reward_dtype = self.__dict__.get("_reward_dtype")
        if reward_dtype is None:
            stored = td_get(next_tensordict, self.reward_key)
            reward_dtype = state.dtype if stored is None else stored.dtype
        shape = done.shape
        for key, read, item, write_as in self._writes[occasion, has_terminated]:  # the table's rows, precomputed
            value = next_state if read is None else read(outputs)
            if write_as is _as_is:  # the memory: never a tensor of the root (the given memory, the goal) under "next",
                # nor the empty sub-memories of memory-less sub-tasks (the specs have none: batched envs refuse them)
                value = unshared(without_hollow(value, self._hollow), memory, state, action)
            if item is not None:
                value = value[item]
            td_set(next_tensordict, key, write_as(value, shape, reward_dtype))
        return next_tensordict

    # ------------------------------------------------------------------- TorchRL hooks
    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        return self._transition(tensordict, next_tensordict)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        # a task without memory and without an achieved goal needs no state at reset (the step checks it)
        needs_state = self._has_memory or self.achieved_goal_key is not None
        init_state = self._read_state(tensordict_reset) if needs_state else None
        if self._has_memory:
            memory = without_hollow(self.task._reset(init_state, self._overrides(init_state)), self._hollow)
            reset_mask = None if tensordict is None else tensordict.get("_reset", None)
            old = None if tensordict is None else tensordict.get(self.memory_key, None)
            if reset_mask is not None and old is not None and old.batch_size == memory.batch_size:
                memory = where_memory(reset_mask.reshape(memory.batch_size), memory, old)
            tensordict_reset.set(self.memory_key, memory)
        done = td_get(tensordict_reset, DONE_KEY)  # the env's reset flags (TorchRL completes them before transforms)
        if done is not None and done.dtype == torch.bool:
            flags = torch.zeros_like(done)
        else:
            if init_state is None:
                init_state = self._read_state(tensordict_reset)
            flags = torch.zeros(
                (*init_state.shape[:-1], 1) if self.parent is None else self.parent.full_done_spec[DONE_KEY].shape,
                dtype=torch.bool,
                device=init_state.device,
            )
        for i, key in enumerate(self._reset_flags):  # success, failure, the end conditions: False
            td_set(tensordict_reset, key, flags if i == 0 else flags.clone())
        if self.achieved_goal_key is not None:
            tensordict_reset.set(self.achieved_goal_key, self._goal_slot.achieved(init_state))
        return tensordict_reset

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Recompute rewards and flags of stored transitions (replay buffers, relabelling).

        ``tensordict`` holds transitions as collected: the state, action and task memory at the
        root and the next state (and ``done``, and ``step_count`` for time-dependent tasks) under
        ``"next"``. The reward, success, failure, done flags and the reward breakdown under
        ``"next"`` are rewritten, and so are the costs and the reward groups (:attr:`cost_keys`, ``vector_reward_key``,
        ``groups_key``) of a tree that has them; the stored next memory is left as it was. An episode end that the
        stored success/failure flags attribute to the task is re-judged (a relabelled goal may
        change it); truncation and the env's own termination are kept.

        Task buffers that a :class:`~torchtasks.transforms.Curriculum` or
        :class:`~torchtasks.transforms.DifficultyLevels` set at every step are evaluated, frame by frame, with the
        values the data records at the root (``(curriculum_key, <buffer name with "/" for ".">)``: the values that
        step used), never with their values of today;
        in the env of such a transform, data lacking one of its entries is a ``ValueError``.
        The buffers are put back afterwards. (Also for :meth:`reward_fn` and :meth:`relabel`.)
        """
        next_tensordict = self._offline_next(tensordict)
        self._transition(tensordict, next_tensordict, "offline")
        return tensordict

    def _offline_next(self, tensordict: TensorDictBase) -> TensorDictBase:
        """The ``"next"`` entry of stored transitions, after the checks of offline use."""
        next_tensordict = tensordict.get("next", None)
        if next_tensordict is None:
            self._missing_entry(tensordict, "'next'", "Stored transitions hold the next state and flags under 'next'.")
        limit = self.__dict__.get("_limit")
        if limit is None:
            limit = self._setup()
        if self._uses_remaining and limit.max_steps is None and "step_count" in next_tensordict.keys():
            raise ValueError(
                f"TaskTransform: {type(self.task).__name__} reads the remaining steps (a time-dependent final "
                "reward) and the data holds ('next', 'step_count'), but max_steps is not known: outside an env "
                "there is no StepCounter to read it from. Pass TaskTransform(..., max_steps=<the limit the data "
                "was collected with>)."
            )
        return next_tensordict

    def reward_fn(self, tensordict: TensorDictBase) -> torch.Tensor:
        """Return the task reward ``[*B, 1]`` of stored transitions (e.g. ``HERReplayBuffer(reward_fn=...)``).

        The data is not modified.
        """
        next_data = self._offline_next(tensordict).copy()
        goal_keys = [] if self.goal_key is None else [self.goal_key]
        recorded = [record.key for record, _ in self._recorded_in_env().values()]
        recorded += [] if self.curriculum_key is None else [self.curriculum_key]
        data = tensordict.select(
            *self.state_keys, self.action_key, self.memory_key, *goal_keys, *recorded, strict=False
        )
        self._transition(data, next_data, "offline")
        return next_data.get(self.reward_key)

    def relabel(self, tensordict: TensorDictBase) -> torch.Tensor:
        """Re-judge stored transitions in place and return their reward: the ``reward_fn`` for hindsight relabelling.

        TorchRL's ``HERReplayBuffer`` writes a relabelled goal into a sampled batch and asks its
        ``reward_fn`` for the new reward only; but where reaching the goal ends the episode, the
        relabelled transition's ``success``, ``terminated`` and ``done`` change too, and bootstrapping
        with the stored ones is wrong. This function judges every transition of the batch anew for the
        goal now in the data (``goal_key`` at the root, or the desired state in the memory at the root
        without a ``goal_key``), through the same evaluation as the online step, and writes everything
        the online step derives from the goal into ``"next"``, so that the batch is consistent in every
        entry it holds (``reward == step + final``, ``done == terminated | truncated``):

        - ``reward`` (cast to the stored reward's dtype and ``[*B, 1]`` shape), ``success``,
          ``failure``, ``terminated`` (the env's own termination OR-ed with the new verdict) and
          ``done`` (that OR-ed with the truncation);
        - the reward breakdown (:attr:`term_keys`: ``step``, ``final``, the named terms);
        - the costs and the reward groups of a tree that has them (``cost_key``, :attr:`cost_keys`,
          ``vector_reward_key`` and the entries under ``groups_key``);
        - the task memory after the step (``memory_key``): it carries the goal the step was judged with
          and the latches the step sets (e.g. a final reward's "paid").

        Entries are overwritten in place (``copy_``), so a view of a larger batch (the slice the
        buffer hands to its ``reward_fn``) is rewritten too; an entry the batch lacks is added.
        Left as stored: the inputs (states, action, the memory and the goal at the root, the goal and
        the achieved goal under ``"next"``), ``truncated`` and ``step_count``, and running sums over
        the episode such as ``RewardSum``'s ``episode_reward``: each transition is judged on its own,
        from the memory stored before it, and a sampled batch holds no earlier frames to sum (recount
        them with :func:`~torchtasks.stats.episode_statistics`, which sums the rewards). In a
        relabelled trajectory an episode may now end before the stored one did; its later frames
        keep their stored step counts. An env termination that coincided with an old success or
        failure cannot be told from it and is judged anew (see :meth:`forward`).

        Returns the reward ``[*B, 1]`` (equal to the one written). Use it as
        ``HERReplayBuffer(reward_fn=transform.relabel, goal_key=<this transform's goal_key>,
        achieved_goal_key=...)``.

        Example:
            >>> import functools, torch
            >>> from torchrl.envs import Compose, StepCounter, TransformedEnv
            >>> from torchtasks.transforms import GoalCommand
            >>> from torchtasks.envs import PendulumEnv
            >>> from torchtasks.rewards import QuadraticErrorReward
            >>> from torchtasks.spaces import Box, EnvSpec
            >>> from torchtasks.tasks import DesiredStateTask, proximity_succeeded
            >>> near = functools.partial(proximity_succeeded, threshold=0.1)
            >>> task = DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], QuadraticErrorReward([1.0, 0.1]), near)
            >>> transform = TaskTransform(task, goal_key="goal", achieved_goal_key="achieved_goal")
            >>> env = TransformedEnv(PendulumEnv(batch_size=[4]), Compose(
            ...     StepCounter(20), transform, GoalCommand(Box([5.0, 5.0], [6.0, 6.0]))))  # unreachable goals
            >>> data = env.rollout(5)
            >>> data["goal"] = data["next", "achieved_goal"]  # hindsight: the goal is where the pendulum got to
            >>> reward = transform.relabel(data)
            >>> bool(data["next", "success"].all()), bool(data["next", "done"].all())
            (True, True)
            >>> torch.equal(data["next", "reward"], reward), bool((reward == 0).all())
            (True, True)
        """
        next_tensordict = self._offline_next(tensordict)
        work = next_tensordict.copy()
        self._transition(tensordict, work, "relabel")
        for key in self._relabelled_keys():
            value = work.get(key, None)
            if value is None:  # the env's terminated flag in data that has only "done"
                continue
            stored = next_tensordict.get(key, None)
            if stored is None:
                next_tensordict.set(key, value)
            else:
                stored.copy_(value)
        return work.get(self.reward_key)

    def _relabelled_keys(self) -> list[NestedKey]:
        """The ``"next"`` entries :meth:`relabel` rewrites: every output of the step that depends on the goal."""
        return self._entries.keys(occasion="relabel")

    def __repr__(self) -> str:
        name = type(self.task).__name__
        return f"{type(self).__name__}(task={name}, state_keys={self.state_keys}, reward_on={self.reward_on!r})"
