"""The DeepMind Control Suite on the batched MuJoCo env: dm_control's tasks as presets whose reward is a task.

:func:`control_suite_env` builds ``"walker-walk"`` (or ``("walker", "walk")``), any of :data:`CONTROL_SUITE_TASKS`
(dm_control's ``suite.BENCHMARKING`` set and quadruped walk and run), as
``TransformedEnv(BatchedMujocoEnv, Compose(StepCounter(1000), TaskTransform(task), ZeroBrokenStepReward(),
RewardSum()))``: dm_control's model (:mod:`~torchtasks.envs.control_suite.models`), control step and substeps, its
observation entries in its order (a dict, or one flat vector), its reward as a torchtasks task of reward terms
(:func:`control_suite_task`: tolerance kernels and products, logged per term), 1000 steps then truncation, and its
episode starts as reset steps drawn per env (targets as per-env model fields). The records, one module per domain,
are in :data:`CONTROL_SUITE`. Docs: the page "The DeepMind Control Suite".
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Mapping
from typing import Any

import torch
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv

from torchtasks._checks import check_positive_int
from torchtasks._did_you_mean import did_you_mean
from torchtasks.envs.batched_mujoco import BatchedMujocoEnv, ZeroBrokenStepReward
from torchtasks.envs.control_suite.models import TASKS, control_suite_model
from torchtasks.envs.control_suite.record import EPISODE_STEPS, ControlSuiteTask
from torchtasks.rewards import RewardFunction
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import GoallessTask
from torchtasks.transforms import TaskTransform

__all__ = [
    "CONTROL_SUITE",
    "CONTROL_SUITE_TASKS",
    "ControlSuiteTask",
    "control_suite_base_env",
    "control_suite_env",
    "control_suite_record",
    "control_suite_task",
]

#: every task, by ``"<domain>-<task>"``, in dm_control's order of domains
CONTROL_SUITE: dict[str, ControlSuiteTask] = {
    record.name: record
    for domain in TASKS  # one module per domain, named as the domain
    for record in importlib.import_module(f"{__name__}.{domain}").TASKS.values()
}
#: the names :func:`control_suite_env` accepts
CONTROL_SUITE_TASKS: tuple[str, ...] = tuple(CONTROL_SUITE)


def control_suite_record(name: str | tuple[str, str]) -> ControlSuiteTask:
    """The record of a task named ``"walker-walk"`` or ``("walker", "walk")``; ``ValueError`` with the closest
    names for another name.

    Example:
        >>> control_suite_record(("walker", "walk")).control_timestep
        0.025
    """
    pair = isinstance(name, tuple) and len(name) == 2 and all(isinstance(n, str) for n in name)
    if not (isinstance(name, str) or pair):
        raise TypeError(f"name must be a task name 'domain-task' or a pair (domain, task) of str, got {name!r}")
    key = "-".join(name) if pair else name
    if key not in CONTROL_SUITE:
        raise ValueError(
            f"unknown Control Suite task {key!r}{did_you_mean(key, list(CONTROL_SUITE))}; the tasks are "
            f"{', '.join(CONTROL_SUITE)}"
        )
    return CONTROL_SUITE[key]


def _layout(record: ControlSuiteTask, model: Any) -> tuple[dict[str, list], dict[str, list[int]]]:
    """The task-state readings and where each entry's columns are in the state vector."""
    entries = record.state(model)
    columns, start = {}, 0
    for key, parts in entries.items():
        size = sum(int(math.prod(part.resolve(model).shape)) for part in parts)
        columns[key] = list(range(start, start + size))
        start += size
    return entries, columns


def _task(record: ControlSuiteTask, model: Any, columns: Mapping[str, list[int]]) -> GoallessTask:
    labels = [f"{key}[{i}]" if len(cols) > 1 else key for key, cols in columns.items() for i in range(len(cols))]
    state = Box.unbounded(len(labels), labels=labels)
    low = torch.as_tensor(model.actuator_ctrlrange[:, 0], dtype=torch.float64)
    high = torch.as_tensor(model.actuator_ctrlrange[:, 1], dtype=torch.float64)
    reward: RewardFunction = record.reward(model, columns)
    return GoallessTask(EnvSpec(state, Box(low, high)), reward)


def control_suite_task(name: str | tuple[str, str]) -> GoallessTask:
    """The task of a Control Suite preset: dm_control's ``get_reward`` as reward terms on the task state
    (:func:`control_suite_env` writes the state's entries; ``task.spec.state_space.labels`` names its columns).

    Example:
        >>> task = control_suite_task("walker-walk")
        >>> task.spec.state_space.labels
        ('torso_height', 'torso_zz', 'speed')
        >>> type(task.reward).__name__, list(task.reward.rewards)
        ('ProductReward', ['stand', 'move'])
    """
    record = control_suite_record(name)
    model = control_suite_model(record.domain, record.task)
    _, columns = _layout(record, model)
    return _task(record, model, columns)


def control_suite_base_env(
    name: str | tuple[str, str],
    num_envs: int = 1,
    *,
    flat_observation: bool = False,
    seed: int | None = None,
    device: torch.device | str | None = None,
    num_threads: int | None = None,
    max_action_delay: int = 0,
) -> BatchedMujocoEnv:
    """The batched env of a Control Suite task without its task: observation and task-state entries, no reward.

    Args: as :func:`control_suite_env`.

    Example:
        >>> env = control_suite_base_env("cartpole-swingup", 2, seed=0)
        >>> list(env.declaration.observation), env.frame_skip
        (['position', 'velocity'], 1)
        >>> env.close()
    """
    record = control_suite_record(name)
    model = control_suite_model(record.domain, record.task)
    observation = record.observation(model)
    if not isinstance(flat_observation, bool):
        raise TypeError(f"flat_observation must be a bool, got {flat_observation!r}")
    if flat_observation:
        observation = {"observation": [part for parts in observation.values() for part in parts]}
    state, _ = _layout(record, model)
    return BatchedMujocoEnv(
        model,
        check_positive_int(num_envs, "num_envs"),
        observation=observation,
        state=state,
        resets=record.resets(model),
        control_timestep=record.control_timestep,
        stage="velocity",
        seed=seed,
        device=device,
        num_threads=num_threads,
        max_action_delay=max_action_delay,
    )


def control_suite_env(
    name: str | tuple[str, str],
    num_envs: int = 1,
    *,
    flat_observation: bool = False,
    seed: int | None = None,
    device: torch.device | str | None = None,
    num_threads: int | None = None,
    max_action_delay: int = 0,
) -> TransformedEnv:
    """A Control Suite task as a TorchRL env of ``num_envs`` simulations stepped in one ``mujoco.batch`` call.

    ``TransformedEnv(base, Compose(StepCounter(1000), TaskTransform(task), ZeroBrokenStepReward(), RewardSum()))``:
    the base env (:func:`control_suite_base_env`) writes dm_control's observation entries (float64, under their
    dm_control names, or one ``"observation"`` vector in the same order) and the task-state entries; the task
    (:func:`control_suite_task`) pays dm_control's reward (``"reward"``, float64, with its terms under
    ``("task_reward", name)``); episodes are truncated after 1000 steps (dm_control's tasks never terminate). Resets
    draw dm_control's initial states per env (targets as per-env model fields, :meth:`BatchedMujocoEnv.domain_values`).

    Args:
        name: ``"walker-walk"`` or ``("walker", "walk")``: one of :data:`CONTROL_SUITE_TASKS`.
        num_envs: number of simulations.
        flat_observation: one ``"observation"`` vector instead of dm_control's entries.
        seed: seed of the per-env reset generators (``None``: fresh entropy).
        device: device of the output tensors (the simulation runs on the CPU).
        num_threads: threads that step the envs (default: the CPUs this process may use).
        max_action_delay: the largest per-env action delay in steps (the ``"action_delay"`` domain field, drawn by a
            :class:`~torchtasks.transforms.DomainRandomization`; :class:`~torchtasks.envs.BatchedMujocoEnv`); 0: none.

    Example:
        >>> env = control_suite_env("walker-walk", num_envs=4, seed=0)
        >>> rollout = env.rollout(3)
        >>> rollout["next", "orientations"].shape, rollout["next", "reward"].shape
        (torch.Size([4, 3, 14]), torch.Size([4, 3, 1]))
        >>> rollout["next", "task_reward", "move"].shape  # each factor of the reward, and its episode sum
        torch.Size([4, 3, 1])
        >>> env.close()
    """
    record = control_suite_record(name)
    base = control_suite_base_env(
        record.name,
        num_envs,
        flat_observation=flat_observation,
        seed=seed,
        device=device,
        num_threads=num_threads,
        max_action_delay=max_action_delay,
    )
    _, columns = _layout(record, base.model)
    task = _task(record, base.model, columns)
    if device is not None:
        task = task.to(device)
    transforms = Compose(
        StepCounter(EPISODE_STEPS),
        TaskTransform(task, state_key=list(columns)),
        ZeroBrokenStepReward(),
        RewardSum(),
    )
    return TransformedEnv(base, transforms)
