"""The default names of the entries torchtasks writes into an env's data, spelt once.

The task's entries (:data:`REWARD_KEY`, :data:`SUCCESS_KEY`, the reward breakdown under :data:`TERMS_KEY`, ...),
read by :class:`~torchtasks.transforms.TaskTransform`'s entry table (:mod:`torchtasks.transforms.entries`), and the
run's values.

A :class:`~torchtasks.transforms.Curriculum` and :class:`~torchtasks.transforms.DifficultyLevels` write under
``curriculum_key`` (default :data:`CURRICULUM_KEY`): the frame count (:data:`FRAMES`), the levels
(:data:`LEVEL`) and one entry per target, named by :func:`entry_name`. A target names a float buffer of the
task tree as ``task.named_buffers()`` does, a GoalCommand's range under :data:`COMMAND`, a buffer of the
base env under :data:`ENV` and a DomainRandomization's distribution parameter under :data:`DOMAIN`; the drawn
physics values are written under :data:`DOMAIN_KEY`. The transforms, offline recomputation and
:func:`~torchtasks.stats.episode_statistics` read these names from here.

A task-tree buffer may also be named by a dotted suffix of its name that no other buffer of the tree ends with
(:func:`suffix_matches`); :func:`short_names` gives each its shortest such suffix of two parts or more, the alias
:func:`~torchtasks.transforms.target_names` lists (``"forward.weight"`` for
``"wrapped_task.reward.rewards.forward.weight"``).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from torchtasks.tasks.transition import FINAL_SOURCE, STEP_SOURCE

__all__ = [
    "BIAS_KEY",
    "COMMAND",
    "COST_KEY",
    "COST_TERMS_KEY",
    "CURRICULUM_KEY",
    "DOMAIN",
    "DOMAIN_KEY",
    "DONE_KEY",
    "ENDED_BY_KEY",
    "ENV",
    "EPISODE_SUM_PREFIX",
    "FAILURE_KEY",
    "FINAL_TERM",
    "FRAMES",
    "GROUPS_KEY",
    "LEVEL",
    "MEMORY_KEY",
    "PUSH_KEY",
    "PUSH_RECORDS",
    "REWARD_KEY",
    "STEP_TERM",
    "SUCCESS_KEY",
    "TERMINATED_KEY",
    "TERMS_KEY",
    "TRUNCATED_KEY",
    "VECTOR_REWARD_KEY",
    "entry_name",
    "names_task_buffer",
    "record_entry",
    "respelt_entries",
    "short_names",
    "suffix_matches",
    "target_name",
]

# ------------------------------------------------------------------------------------------ the task's entries
#: the reward entry the task's reward replaces (TorchRL's default reward key)
REWARD_KEY = "reward"
#: the task memory (``memory_key``)
MEMORY_KEY = "task"
#: the task's success and failure flags (``success_key``, ``failure_key``)
SUCCESS_KEY = "success"
FAILURE_KEY = "failure"
#: the reward breakdown (``terms_key``): ``(TERMS_KEY, STEP_TERM)``, ``(TERMS_KEY, FINAL_TERM)``, one entry per term
TERMS_KEY = "task_reward"
#: (the names a reward group reads the step and final reward under: :class:`~torchtasks.tasks.RewardGroupsTask`)
STEP_TERM = STEP_SOURCE
FINAL_TERM = FINAL_SOURCE
#: all reward groups stacked, ``[*B, k]`` (``vector_reward_key``; MO-Gymnasium's ``info["vector_reward"]``), and one
#: entry per group (``groups_key``)
VECTOR_REWARD_KEY = "vector_reward"
GROUPS_KEY = "reward_groups"
#: all costs stacked (``cost_key``) and one entry per cost (``cost_terms_key``)
COST_KEY = "cost"
COST_TERMS_KEY = "task_cost"
#: one flag per named end condition (``ended_by_key``)
ENDED_BY_KEY = "ended_by"
#: the env's end-of-episode flags (TorchRL's names); the task ORs its verdict into the first two
DONE_KEY = "done"
TERMINATED_KEY = "terminated"
TRUNCATED_KEY = "truncated"
#: the prefix TorchRL's ``RewardSum`` gives the running episode sum of an entry it sums (``episode_<name>``)
EPISODE_SUM_PREFIX = "episode_"

# ------------------------------------------------------------------------------------------ the run's values
#: the default key under which the run's values are written (``curriculum_key``)
CURRICULUM_KEY = "curriculum"
#: a Curriculum's frame count, under ``curriculum_key``
FRAMES = "frames"
#: the per-env levels of a DifficultyLevels, under ``curriculum_key``
LEVEL = "level"
#: the prefix of the targets that name a GoalCommand's sampling range (``"command.low"``, ``"command.goal.high"``)
COMMAND = "command"
#: the prefix of the targets that name a buffer of the base env (``"env.step_size"``)
ENV = "env"
#: the prefix of the targets that name a distribution parameter of a DomainRandomization
#: (``"domain.body_mass:torso.halfspan"``)
DOMAIN = "domain"
#: the default key under which a DomainRandomization writes every env's drawn values (``entry_key``), one entry
#: per domain field (``("domain", "body_mass:torso")``)
DOMAIN_KEY = "domain"
#: the default prefix of an ObservationNoise's bias entries (``entry_key``): ``"observation_bias_<entry>"`` per noisy
#: entry with a bias (:func:`record_entry`)
BIAS_KEY = "observation_bias"
#: the default prefix of a Pushes' entries (``entry_key``): ``"push_velocity"``, ``"push_wrench"``
#: (:func:`record_entry`)
PUSH_KEY = "push"
#: what a Pushes records, by the suffix of its entries: the velocity change of a step, the wrench held in it
PUSH_RECORDS = ("velocity", "wrench")


def names_task_buffer(target: str) -> bool:
    """Whether a target names a buffer of the task tree (not a GoalCommand's range, a base-env or a domain buffer).

    Example:
        >>> names_task_buffer("wrapped_task.reward.Q"), names_task_buffer("domain.body_mass_scale.halfspan")
        (True, False)
    """
    return not target.startswith((COMMAND + ".", ENV + ".", DOMAIN + "."))


def entry_name(target: str) -> str:
    """The name of the entry recording a target's values under ``curriculum_key``: the target with ``"/"`` for ``"."``.

    Example:
        >>> entry_name("wrapped_task.reward.Q")
        'wrapped_task/reward/Q'
    """
    return target.replace(".", "/")


def target_name(entry: str) -> str:
    """The target whose values an entry under ``curriculum_key`` records: the inverse of :func:`entry_name`.

    Example:
        >>> target_name("wrapped_task/reward/Q")
        'wrapped_task.reward.Q'
    """
    return entry.replace("/", ".")


def suffix_matches(name: str, names: Iterable[str]) -> list[str]:
    """The names ``name`` stands for among ``names``: itself if it is one of them, else each that ends with it.

    "Ends with" is on dot boundaries: ``"forward.weight"`` matches ``"reward.rewards.forward.weight"``, not
    ``"reward.rewards.backforward.weight"``. One match: ``name`` is that name or an alias of it; several: ``name`` is
    ambiguous; none: unknown. A name given in full always means itself, even if it ends another name.

    Example:
        >>> names = ["reward.rewards.forward.weight", "reward.rewards.ctrl.weight", "state_low"]
        >>> suffix_matches("forward.weight", names), suffix_matches("weight", names)
        (['reward.rewards.forward.weight'], ['reward.rewards.forward.weight', 'reward.rewards.ctrl.weight'])
        >>> suffix_matches("state_low", names + ["wrapped_task.state_low"])
        ['state_low']
    """
    names = list(names)
    if name in names:
        return [name]
    return [full for full in names if full.endswith("." + name)]


def short_names(names: Sequence[str]) -> dict[str, str]:
    """Each task-tree name's alias: its shortest dotted suffix of two parts or more that stands for it alone.

    A suffix stands for a name alone when :func:`suffix_matches` finds that name only among ``names`` and the suffix
    names no target of another source (it does not start with ``"command."``, ``"env."`` or ``"domain."``). A name
    of one or two parts, or one with no such suffix, is its own alias.

    Example:
        >>> names = ["wrapped_task.reward.rewards.forward.weight", "wrapped_task.reward.rewards.ctrl.weight",
        ...          "state_low", "wrapped_task.state_low", "a.cost.threshold", "b.cost.threshold"]
        >>> list(short_names(names).values())
        ['forward.weight', 'ctrl.weight', 'state_low', 'wrapped_task.state_low', 'a.cost.threshold', 'b.cost.threshold']
    """
    aliases = {}
    for name in names:
        parts = name.split(".")
        aliases[name] = name
        for start in range(len(parts) - 2, 0, -1):  # the suffixes of 2, 3, ... parts, shorter than the name
            suffix = ".".join(parts[start:])
            if names_task_buffer(suffix) and suffix_matches(suffix, names) == [name]:
                aliases[name] = suffix
                break
    return aliases


def respelt_entries(saved: Iterable[str], own: Iterable[str]) -> str:
    """The sentence a refused checkpoint load adds when saved and own entries may be one target spelt two ways.

    Entries are keyed by the target as written (:func:`entry_name`); a short name and the full name of one buffer give
    two entries, one ending the other. ``""`` when no pair of ``saved`` and ``own`` entries does.

    Example:
        >>> print(respelt_entries(["wrapped_task/reward/rewards/forward/weight"], ["forward/weight"])[:80])
         ('forward/weight' here may be 'wrapped_task/reward/rewards/forward/weight' of t
        >>> respelt_entries(["reward/Q"], ["reward/R"])
        ''
    """
    own = list(own)
    for entry in saved:
        for mine in own:
            if mine != entry and (entry.endswith("/" + mine) or mine.endswith("/" + entry)):
                return (
                    f" ({mine!r} here may be {entry!r} of the checkpoint spelt another way: a checkpoint is keyed by "
                    "the targets as written; build the writer with the saved spelling)"
                )
    return ""


def record_entry(prefix: tuple[str, ...], suffix: str) -> tuple[str, ...]:
    """The key of a transform's record ``suffix`` for the entry prefix ``prefix`` (key parts): the last part and the
    suffix joined with ``"_"``, so that a transform's records are leaves beside the other entries, not a node of their
    own (each node of a step's data costs TorchRL's step, partial reset and collector more than its leaves do).

    Example:
        >>> record_entry(("push",), "velocity"), record_entry(("robot", "observation_bias"), "joint_pos")
        (('push_velocity',), ('robot', 'observation_bias_joint_pos'))
    """
    return (*prefix[:-1], f"{prefix[-1]}_{suffix}")
