"""The names of the entries the run's values are written under, and of the prefixes of their targets.

A :class:`~torchtasks.transforms.Curriculum` and :class:`~torchtasks.transforms.DifficultyLevels` write under
``curriculum_key`` (default :data:`CURRICULUM_KEY`): the frame count (:data:`FRAMES`), the levels
(:data:`LEVEL`) and one entry per target, named by :func:`entry_name`. A target names a float buffer of the
task tree as ``task.named_buffers()`` does, a GoalCommand's range under :data:`COMMAND` and a buffer of the
base env under :data:`ENV`. The transforms, offline recomputation and :func:`~torchtasks.stats.episode_statistics`
read these names from here.
"""

from __future__ import annotations

__all__ = ["COMMAND", "CURRICULUM_KEY", "ENV", "FRAMES", "LEVEL", "entry_name", "target_name"]

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
