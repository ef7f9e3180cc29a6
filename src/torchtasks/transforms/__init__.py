"""The TorchRL face of torchtasks: transforms that put a task, goals, curricula and run state into an env.

- :class:`TaskTransform` (:mod:`.task`): a task's reward, flags, terms and costs at every step of an env, each
  entry it writes a row of its table (:mod:`.entries`, where the default entry names are spelt);
- :class:`GoalCommand` (:mod:`.command`): per-env goals drawn from a box and resampled;
- :class:`Curriculum` (:mod:`.curriculum`) with the schedules of :mod:`.schedules`, and
  :class:`DifficultyLevels` (:mod:`.levels`): values of the run written into the task (or the command);
- :class:`DomainRandomization` (:mod:`.domain`): per-env physics drawn from domain distributions, routed to the
  owners of the fields (:mod:`.domain_owners`);
- :class:`ObservationNoise` and :class:`EntryNoise` (:mod:`.noise`): per-step noise and a per-episode bias per
  observation entry and per env, their stds domain fields;
- :class:`Pushes` (:mod:`.pushes`): per-env pushes and external forces at random intervals, their ranges domain
  fields;
- :class:`SeededTransform` and :func:`seed_transforms` (:mod:`.seeding`): per-worker seeds from ``set_seed``;
- :class:`BaseEnvState`, :func:`collector_state`, :func:`load_collector_state` (:mod:`.checkpoint`): saving
  and resuming a run, episodes included.

:mod:`.targets` is the one resolver of the values of the run (a name to a buffer of the task tree, a GoalCommand's
range, the base env or a domain distribution; the checks; the write) that curricula and levels share;
:mod:`.entries` is the table of the entries a task writes; :mod:`.names` spells every default entry name once.

The modules of the package import only from below it (rewards, tasks, spaces) and from one another in this
order: ``names``, ``_base``, ``entries``, ``seeding``, ``task``, ``command``, ``domain_owners``, ``domain``, ``noise``,
``pushes``, ``schedules``, ``targets``, ``curriculum``, ``levels``, ``checkpoint``.
The old paths (``torchtasks.commands``, ``torchtasks.curriculum``, ``torchtasks.levels``,
``torchtasks.seeding``, ``torchtasks.checkpoint``) re-export the same objects.
"""

from torchtasks.transforms.checkpoint import BaseEnvState, collector_state, load_collector_state
from torchtasks.transforms.command import GoalCommand
from torchtasks.transforms.curriculum import Curriculum
from torchtasks.transforms.domain import DomainRandomization
from torchtasks.transforms.levels import DifficultyLevels, LevelRule
from torchtasks.transforms.noise import EntryNoise, ObservationNoise
from torchtasks.transforms.pushes import PushableEnv, Pushes
from torchtasks.transforms.schedules import GatedSchedule, Schedule, constant, gated, linear, staged
from torchtasks.transforms.seeding import SeededTransform, SeedHook, derived_seed, seed_transforms
from torchtasks.transforms.targets import TargetTable, target_names
from torchtasks.transforms.task import TaskTransform

__all__ = [
    "BaseEnvState",
    "Curriculum",
    "DifficultyLevels",
    "DomainRandomization",
    "EntryNoise",
    "GatedSchedule",
    "GoalCommand",
    "LevelRule",
    "ObservationNoise",
    "PushableEnv",
    "Pushes",
    "Schedule",
    "SeedHook",
    "SeededTransform",
    "TargetTable",
    "TaskTransform",
    "collector_state",
    "constant",
    "derived_seed",
    "gated",
    "linear",
    "load_collector_state",
    "seed_transforms",
    "staged",
    "target_names",
]
