"""The entries a task writes into an env's data: one table per :class:`TaskTransform`.

The default names are spelt once, in :mod:`torchtasks.transforms.names`. :func:`task_entries` builds, once per
transform, the :class:`TaskEntries` table: one :class:`Entry` per output (its key, its kind, which fixes its spec,
where its value comes from in the task's transition result and when it is written). The transform's key lists,
collision checks, specs, writes and relabelled entries are all read from that table.
"""

from __future__ import annotations

import operator
from collections.abc import Callable, Collection
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, NamedTuple

from tensordict.utils import NestedKey, unravel_key

from torchtasks._memory import has_leaves
from torchtasks._torchrl import key_parts
from torchtasks.tasks.transition import TRANSITION_FIELDS
from torchtasks.transforms.names import (
    COST_KEY,
    COST_TERMS_KEY,
    DONE_KEY,
    ENDED_BY_KEY,
    FAILURE_KEY,
    FINAL_TERM,
    GROUPS_KEY,
    MEMORY_KEY,
    REWARD_KEY,
    STEP_TERM,
    SUCCESS_KEY,
    TERMINATED_KEY,
    TERMS_KEY,
    VECTOR_REWARD_KEY,
)

if TYPE_CHECKING:
    from torchtasks.tasks.protocol import Task

__all__ = [
    "Entry",
    "TaskEntries",
    "task_entries",
]

# ------------------------------------------------------------------------------------------------ the table
#: what an entry holds; the kind fixes its spec (see :attr:`Entry.specs`) and how a value is written
EntryKind = Literal["reward", "term", "cost", "costs", "group", "groups", "flag", "env_flag", "memory", "goal"]
#: when an entry is written: the env's step, a recomputation of stored transitions (``forward``,
#: ``reward_fn``), a relabelling (``relabel``), the env's reset
Occasion = Literal["step", "offline", "relabel", "reset"]

#: the specs an entry of each kind is registered in ("done": the env's own entry, left as the env declares it;
#: the ``"reward"`` kind is the env's reward entry, whose spec the transform reads and keeps)
KIND_SPECS: dict[str, tuple[str, ...]] = {
    "reward": ("reward",),  # the env's reward entry, [*B, 1] of the reward spec's dtype
    "term": ("reward",),  # a breakdown entry: the reward's shape and dtype
    "cost": ("reward",),  # one cost: the reward's shape and dtype
    "costs": ("reward",),  # all costs stacked: [*B, k] in the reward's dtype
    "group": ("reward",),  # one reward group: the reward's shape, in the groups' dtype (default: the reward's)
    "groups": ("reward",),  # all reward groups stacked (the vector reward): [*B, k] in the groups' dtype
    "flag": ("observation",),  # bool, the done flags' shape; False at reset
    "env_flag": ("done",),  # the env's terminated/done, OR-ed with the task's verdict
    "memory": ("observation", "state"),  # the task memory: carried to the next step as an input
    "goal": ("observation",),  # the achieved goal [*B, k], in the state's dtype
}


EVERY_STEP: frozenset[str] = frozenset({"step", "offline", "relabel"})
EVERY_STEP_AND_RESET: frozenset[str] = EVERY_STEP | {"reset"}
#: the memory after the step: online, and where relabelling rewrites the memory; fresh memory at reset
MEMORY_WRITTEN: frozenset[str] = frozenset({"step", "relabel", "reset"})
#: the achieved goal: online only (stored data keep theirs)
ONLINE: frozenset[str] = frozenset({"step", "reset"})


def transition_field(field: str) -> Callable[[Any], Any]:
    """A reader of one field of the task's transition result (``Task._transition``), by name.

    The one place that knows how that result is laid out.
    """
    if field not in TRANSITION_FIELDS:
        raise ValueError(f"transition_field: unknown field {field!r}; the fields are {list(TRANSITION_FIELDS)}")
    return operator.attrgetter(field)


class Entry(NamedTuple):
    """One entry a :class:`~torchtasks.transforms.TaskTransform` writes (under ``"next"`` in a step).

    Example:
        >>> from torchtasks.transforms.entries import Entry, EVERY_STEP
        >>> entry = Entry(("task_reward", "track"), "term", "terms_key", "terms", "track", EVERY_STEP)
        >>> entry.specs, "relabel" in entry.written
        (('reward',), True)
    """

    #: the entry's key
    key: NestedKey
    #: what it holds (``"reward"``, ``"term"``, ``"cost"``, ``"costs"``, ``"group"``, ``"groups"``, ``"flag"``,
    #: ``"env_flag"``, ``"memory"``, ``"goal"``): its specs (:attr:`specs`), shape and dtype follow from it
    kind: EntryKind
    #: the transform argument naming the key or the key it is under (``"terms_key"``); ``None``: the env's flags
    argument: str | None
    #: the field of the task's transition result holding the value (``"reward"``, ``"terms"``, ...); ``None``:
    #: the achieved goal, taken from the next state
    source: str | None
    #: the entry of that field when it holds one value per name (a term, a cost, a group, an end condition), else
    #: ``None``
    item: str | None
    #: when it is written: ``"step"`` (the env's step), ``"offline"`` (stored transitions recomputed),
    #: ``"relabel"``, ``"reset"``
    written: frozenset[str]

    @property
    def specs(self) -> tuple[str, ...]:
        """The env specs the entry is registered in (``"reward"``, ``"observation"``, ``"state"``, ``"done"``)."""
        return KIND_SPECS[self.kind]


@dataclass(frozen=True)
class TaskEntries:
    """The entries a :class:`~torchtasks.transforms.TaskTransform` writes, one :class:`Entry` per output.

    Attributes:
        claims: ``(argument, key)`` for every key argument whose key (and all below it) the transform owns: the
            reward, the memory (also for a tree without memory), the flags (also one the tree does not define,
            which is then not written), the breakdown (with ``log_terms``,
            also when it is empty), the costs (for a tree with costs) and the end conditions (for a tree that
            names them). No two claims may overlap, nor an input of the transform.
        rows: the entries, in the order the transform writes them.

    Example:
        >>> from torchtasks.envs import swing_up_task
        >>> from torchtasks.transforms import TaskTransform
        >>> entries = TaskTransform(swing_up_task()).entries
        >>> entries.keys(kinds=("term",))
        [('task_reward', 'step'), ('task_reward', 'final'), ('task_reward', 'track'), ('task_reward', 'effort')]
        >>> entries.keys(occasion="reset")
        ['success', 'failure', 'task']
        >>> entries.names("terms_key")
        ('step', 'final', 'track', 'effort')
    """

    claims: tuple[tuple[str, NestedKey], ...]
    rows: tuple[Entry, ...]

    def select(
        self,
        *,
        kinds: Collection[str] | None = None,
        occasion: str | None = None,
        argument: str | None = None,
        spec: str | None = None,
    ) -> tuple[Entry, ...]:
        """The rows of the given kinds, written on ``occasion``, named by ``argument``, registered in ``spec``."""
        return tuple(
            row
            for row in self.rows
            if (kinds is None or row.kind in kinds)
            and (occasion is None or occasion in row.written)
            and (argument is None or row.argument == argument)
            and (spec is None or spec in row.specs)
        )

    def keys(self, **selection: Any) -> list[NestedKey]:
        """The keys of the rows :meth:`select` picks with the same arguments."""
        return [row.key for row in self.select(**selection)]

    def root(self, argument: str) -> NestedKey:
        """The key the argument ``argument`` names (``KeyError`` if the table claims no such key)."""
        return dict(self.claims)[argument]

    def names(self, argument: str) -> tuple[str, ...]:
        """The names of the entries under the key ``argument`` names (e.g. the breakdown's terms)."""
        rows = self.select(argument=argument)
        depth = len(key_parts(self.root(argument))) if rows else 0
        return tuple("/".join(key_parts(row.key)[depth:]) for row in rows)


def task_entries(
    task: Task,
    *,
    reward_key: NestedKey = REWARD_KEY,
    memory_key: NestedKey = MEMORY_KEY,
    success_key: NestedKey = SUCCESS_KEY,
    failure_key: NestedKey = FAILURE_KEY,
    terms_key: NestedKey = TERMS_KEY,
    cost_key: NestedKey = COST_KEY,
    cost_terms_key: NestedKey = COST_TERMS_KEY,
    ended_by_key: NestedKey = ENDED_BY_KEY,
    achieved_goal_key: NestedKey | None = None,
    log_terms: bool = True,
    vector_reward_key: NestedKey = VECTOR_REWARD_KEY,
    groups_key: NestedKey = GROUPS_KEY,
) -> TaskEntries:
    """The table of the entries a ``TaskTransform`` with these (unravelled) keys writes for ``task``.

    From the task tree: the success flag when the tree can succeed and the failure flag when it can fail
    (``task.facts.can_succeed``, ``task.facts.can_fail``); a memory entry when its memory holds a tensor; the
    breakdown (with ``log_terms``) of the step and final reward when some task pays a final reward, then one entry
    per named term; the costs
    (all stacked under ``cost_key``, and one per cost under ``cost_terms_key``) when it has costs; the reward groups
    (all stacked under ``vector_reward_key``, and one per group under ``groups_key``) when it has some; one flag per
    end condition (with ``log_terms``) when a kind of end has two or more named conditions.

    Args:
        task: the task tree.
        reward_key: the transform's ``reward_key``; likewise ``memory_key``, ``success_key``, ``failure_key``,
            ``terms_key``, ``cost_key``, ``cost_terms_key``, ``ended_by_key``, ``vector_reward_key``, ``groups_key``
            and ``achieved_goal_key``
            (``None``: no achieved goal), as the transform unravelled them.
        log_terms: whether the breakdown and the end conditions are written.

    Example:
        >>> from torchtasks.envs import swing_up_task
        >>> from torchtasks.transforms.entries import task_entries
        >>> table = task_entries(swing_up_task())
        >>> [(row.key, row.kind) for row in table.select(occasion="relabel", kinds=("flag", "memory"))]
        [('success', 'flag'), ('failure', 'flag'), ('task', 'memory')]
        >>> table.keys(spec="reward", kinds=("reward", "cost", "costs")), table.names("terms_key")
        (['reward'], ('step', 'final', 'track', 'effort'))
    """
    names_ends = task.facts.names_end_conditions
    cost_names = tuple(task.cost_names)
    group_names = tuple(task.group_names)
    termination_names = tuple(task.termination_names) if log_terms and names_ends else ()

    def under(root: NestedKey, name: str) -> NestedKey:
        return unravel_key((*key_parts(root), name))

    claims = [
        ("reward_key", reward_key),
        ("memory_key", memory_key),
        ("success_key", success_key),
        ("failure_key", failure_key),
    ]
    claims += [("terms_key", terms_key)] if log_terms else []
    claims += [("cost_key", cost_key), ("cost_terms_key", cost_terms_key)] if cost_names else []
    claims += [("vector_reward_key", vector_reward_key), ("groups_key", groups_key)] if group_names else []
    claims += [("ended_by_key", ended_by_key)] if termination_names else []

    rows = [Entry(reward_key, "reward", "reward_key", "reward", None, EVERY_STEP)]
    # the outcome flags the tree defines: no success flag for a tree that cannot succeed, no failure flag for one
    # that cannot fail, so the data say what the task is (and statistics of it report only what applies)
    if task.facts.can_succeed:
        rows.append(Entry(success_key, "flag", "success_key", "success", None, EVERY_STEP_AND_RESET))
    if task.facts.can_fail:
        rows.append(Entry(failure_key, "flag", "failure_key", "failure", None, EVERY_STEP_AND_RESET))
    rows += [
        Entry(under(ended_by_key, name), "flag", "ended_by_key", "ended_by", name, EVERY_STEP_AND_RESET)
        for name in termination_names
    ]
    rows += [
        Entry(TERMINATED_KEY, "env_flag", None, "terminated", None, EVERY_STEP),
        Entry(DONE_KEY, "env_flag", None, "done", None, EVERY_STEP),
    ]
    if has_leaves(task.memory_layout):  # a tree without memory tensors writes no memory (batched envs refuse it)
        rows.append(Entry(memory_key, "memory", "memory_key", "memory", None, MEMORY_WRITTEN))
    if achieved_goal_key is not None:
        rows.append(Entry(achieved_goal_key, "goal", "achieved_goal_key", None, None, ONLINE))
    if log_terms:
        if task.pays_final_reward:  # else the step reward is the reward and the final reward is 0: neither written
            rows.append(Entry(under(terms_key, STEP_TERM), "term", "terms_key", "step_reward", None, EVERY_STEP))
            rows.append(Entry(under(terms_key, FINAL_TERM), "term", "terms_key", "final_reward", None, EVERY_STEP))
        rows += [
            Entry(under(terms_key, name), "term", "terms_key", "terms", name, EVERY_STEP) for name in task.term_names
        ]
    if cost_names:
        rows.append(Entry(cost_key, "costs", "cost_key", "costs", None, EVERY_STEP))
        rows += [
            Entry(under(cost_terms_key, name), "cost", "cost_terms_key", "costs", name, EVERY_STEP)
            for name in cost_names
        ]
    if group_names:
        rows.append(Entry(vector_reward_key, "groups", "vector_reward_key", "groups", None, EVERY_STEP))
        rows += [
            Entry(under(groups_key, name), "group", "groups_key", "groups", name, EVERY_STEP) for name in group_names
        ]
    return TaskEntries(tuple(claims), tuple(rows))
