"""Gymnasium MuJoCo v5 locomotion presets whose reward and termination come from a torchtasks task.

:func:`locomotion_task` builds, for ``HalfCheetah-v5``, ``Hopper-v5``, ``Walker2d-v5``, ``Swimmer-v5``,
``Ant-v5`` and ``Humanoid-v5``, a :class:`~torchtasks.tasks.GoallessTask` whose reward is a
:class:`~torchtasks.rewards.CompoundReward` with the terms Gymnasium logs in ``info["reward_*"]``:
``forward``, ``ctrl``, ``contact`` and ``survive`` (only those the env has). Unhealthy states are task
failures when ``terminate_when_unhealthy``. Every Gymnasium keyword argument of the env is accepted
and the defaults are Gymnasium's own (read from the env class's signature).

:func:`gymnasium_env` builds the matching TorchRL env: the envs (a
:class:`~torchtasks.envs.batched_mujoco.BatchedMujocoEnv` stepping all of them in one process, the
default for more than one env, or a Gymnasium env in a ``GymWrapper``, or a ``ParallelEnv`` of them),
``StepCounter(1000)``, the :class:`~torchtasks.transforms.TaskTransform` of the task and ``RewardSum``.
The observation the policy sees is Gymnasium's default observation, unchanged. The task's state is
assembled from float64 root entries of the tensordict (read from ``info`` on the Gymnasium path;
:func:`locomotion_state_layout` lists them, in order):

=============  ======================================  =============================================
env            task state (info keys, concatenated)    where the entries come from
=============  ======================================  =============================================
HalfCheetah    ``x_velocity``                          Gymnasium's info (``qpos[0]`` velocity)
Swimmer        ``x_velocity``                          Gymnasium's info (``qpos[0]`` velocity)
Hopper         ``x_velocity``, ``qpos``, ``qvel``      Gymnasium's info, then :class:`MujocoStateInfo`
                                                       (unclipped qvel)
Walker2d       ``x_velocity``, ``qpos``                Gymnasium's info, then :class:`MujocoStateInfo`
Ant            ``x_velocity``, ``qpos``, ``qvel``,     Gymnasium's info (torso ``xpos`` velocity),
               ``cfrc_ext``                            then :class:`MujocoStateInfo`
Humanoid       ``x_velocity``, ``qpos``, ``cfrc_ext``  Gymnasium's info (centre-of-mass velocity),
                                                       then :class:`MujocoStateInfo`
=============  ======================================  =============================================

The forward term is ``forward_reward_weight * x_velocity`` with Gymnasium's ``x_velocity``: the
change of ``qpos[0]`` over the step divided by ``dt`` (HalfCheetah, Swimmer, Hopper, Walker2d), of the
main body's ``xpos`` (Ant) or of the centre of mass from ``xipos`` (Humanoid; both lag ``qpos`` by one
MuJoCo substep, so they cannot be recomputed from ``qpos``). The tasks therefore keep no memory: a
step's reward and failure depend on the state after the step alone.

Safety velocity presets: :func:`safety_velocity_task` and :func:`safety_velocity_env` keep Gymnasium
v5's reward and termination and add Safety-Gymnasium's velocity cost, ``cost = float(velocity >
threshold)`` per step with the thresholds of its ``Safety<Env>Velocity-v1`` tasks
(``safety_gymnasium/tasks/safe_velocity/safety_*_velocity_v1.py``), as a constraint named
``"velocity"`` of a :class:`~torchtasks.tasks.ConstrainedTask`. The velocity is measured as
Safety-Gymnasium measures it (the signed ``x_velocity`` of HalfCheetah, Hopper, Walker2d and Swimmer,
the planar speed ``sqrt(x_velocity² + y_velocity²)`` of Ant's torso and Humanoid's centre of mass),
but on v5's dynamics: Safety-Gymnasium runs Gymnasium's v4 envs (see
:class:`~torchtasks.envs.gymnasium_v5.SafetyVelocityRecord` for the thresholds and the differences).
The task state of Ant and Humanoid gains ``y_velocity`` after ``x_velocity`` (Gymnasium's
``info["y_velocity"]``, written by the batched env too); the others' state is unchanged.

What differs from env to env (the state layout above, the reward terms, the health and contact
rules, the velocity constraint) is read from the env's record in :mod:`torchtasks.envs.gymnasium_v5`;
nothing here branches on the id.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Literal

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs import (
    Compose,
    DoubleToFloat,
    EnvBase,
    ParallelEnv,
    RewardSum,
    StepCounter,
    Transform,
    TransformedEnv,
)
from torchrl.envs.gym_like import default_info_dict_reader

from torchtasks._checks import check_positive_int, check_weight
from torchtasks._optional import missing_extra
from torchtasks.rewards.base import RewardFunction
from torchtasks.rewards.compound import CompoundReward
from torchtasks.rewards.terms import AboveThresholdIndicator, ControlCostReward, VelocityReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks.constrained import ConstrainedTask, Constraint
from torchtasks.tasks.goalless import GoallessTask
from torchtasks.tasks.protocol import Task
from torchtasks.transforms import TaskTransform

# the 'mujoco' extra: without it, importing this module raises an error naming the extra to install
try:
    import gymnasium
    import mujoco  # noqa: F401  (before gymnasium.envs.mujoco, which raises a non-ImportError without it)
except ImportError as _error:
    raise missing_extra("mujoco", "torchtasks.envs.locomotion (the Gymnasium MuJoCo presets)", _error) from _error

from torchtasks.envs.batched_mujoco import BatchedMujocoEnv, ZeroBrokenStepReward
from torchtasks.envs.gymnasium_v5 import (
    LocomotionEnvRecord,
    ModelFacts,
    gymnasium_config,
    locomotion_record,
    make_v5_env,
)

__all__ = [
    "SUPPORTED_ENV_IDS",
    "Float64InfoReader",
    "MujocoStateInfo",
    "gymnasium_env",
    "locomotion_state_layout",
    "locomotion_task",
    "make_base_env",
    "make_gymnasium_env",
    "safety_velocity_env",
    "safety_velocity_task",
]

# written out rather than tuple(LOCOMOTION_ENVS), so that `torchtasks list` reads it from this file without
# the mujoco extra; tests/envs/test_locomotion_records.py checks that it lists the keys of LOCOMOTION_ENVS, in order
#: the Gymnasium ids :func:`locomotion_task` and :func:`gymnasium_env` support
SUPPORTED_ENV_IDS: tuple[str, ...] = (
    "HalfCheetah-v5",
    "Hopper-v5",
    "Walker2d-v5",
    "Swimmer-v5",
    "Ant-v5",
    "Humanoid-v5",
)

#: Gymnasium's time limit of the v5 locomotion envs (their registered ``max_episode_steps``)
MAX_EPISODE_STEPS = 1000

#: the name of the safety presets' constraint (``TaskOutput.costs["velocity"]``, ``("task_cost", "velocity")``)
SAFETY_COST_NAME = "velocity"

#: the safety presets' default limit of the expected episode cost: OmniSafe's ``cost_limit: 25.0``
#: (``omnisafe/configs/on-policy/PPOLag.yaml``), the usual budget of Safety-Gymnasium benchmarks
SAFETY_COST_LIMIT = 25.0

#: info keys that only :class:`MujocoStateInfo` provides (Gymnasium's info lacks them)
_ADDED_INFO_KEYS = ("qpos", "qvel", "cfrc_ext")


# ----------------------------------------------------------------------------------- helpers
def _labels(layout: Mapping[str, int]) -> list[str]:
    labels: list[str] = []
    for key, size in layout.items():
        labels.extend([key] if size == 1 else [f"{key}[{i}]" for i in range(size)])
    return labels


def state_starts(layout: Mapping[str, int]) -> dict[str, int]:
    """Where each entry of a task state ``{key: size}`` starts (for the presets of this package; not in ``__all__``).

    Example:
        >>> state_starts({"qpos": 9, "x_velocity": 1})
        {'qpos': 0, 'x_velocity': 9}
    """
    starts: dict[str, int] = {}
    position = 0
    for key, size in layout.items():
        starts[key] = position
        position += size
    return starts


def _terms(
    record: LocomotionEnvRecord, config: Mapping[str, Any], facts: ModelFacts, keys: tuple[str, ...]
) -> dict[str, RewardFunction]:
    """The named reward terms of the env on the task state of ``keys`` (order: forward, ctrl, contact, survive)."""
    starts = state_starts(record.state_layout(facts, keys))
    # Gymnasium's forward_reward_weight * x_velocity, with x_velocity as Gymnasium computes it
    terms: dict[str, RewardFunction] = {
        "forward": VelocityReward(config["forward_reward_weight"], index=starts["x_velocity"]),
        "ctrl": ControlCostReward(config["ctrl_cost_weight"]),
    }
    if record.contact_cost is not None:
        terms["contact"] = record.contact_cost(config, starts["cfrc_ext"])
    if record.health is not None:
        terms["survive"] = record.health(config, facts, starts["qpos"])
    return terms


def build_locomotion_task(
    record: LocomotionEnvRecord, config: Mapping[str, Any], facts: ModelFacts, keys: tuple[str, ...] | None = None
) -> GoallessTask:
    """The locomotion task of ``record`` for the checked keywords ``config`` on the task state ``keys`` (default: the
    record's), with its named terms: what :func:`locomotion_task` returns, for the presets of this package (the
    multi-objective presets build their groups on it; not in ``__all__``)."""
    keys = record.state_keys if keys is None else keys
    layout = record.state_layout(facts, keys)
    state_space = Box.unbounded(sum(layout.values()), labels=_labels(layout))
    spec = EnvSpec(state_space, Box(facts.action_low, facts.action_high))
    return GoallessTask(spec, CompoundReward(_terms(record, config, facts, keys)))


def _velocity_cost(record: LocomotionEnvRecord, facts: ModelFacts) -> AboveThresholdIndicator:
    """Safety-Gymnasium's ``float(velocity > threshold)`` on the safety task's state (:attr:`safety_state_keys`)."""
    safety = record.safety_velocity
    if safety is None:
        raise ValueError(f"{record.env_id} has no Safety-Gymnasium velocity constraint")
    starts = state_starts(record.state_layout(facts, record.safety_state_keys))
    if safety.planar:  # sqrt(x_velocity² + y_velocity²) > threshold
        return AboveThresholdIndicator(safety.threshold, index=[starts[key] for key in safety.velocity_keys], norm=True)
    return AboveThresholdIndicator(safety.threshold, index=starts[safety.velocity_keys[0]])  # signed x_velocity


def _build_safety_task(
    record: LocomotionEnvRecord, config: Mapping[str, Any], facts: ModelFacts, cost_limit: float | None
) -> ConstrainedTask:
    task = build_locomotion_task(record, config, facts, record.safety_state_keys)
    return ConstrainedTask(task, {SAFETY_COST_NAME: Constraint(_velocity_cost(record, facts), limit=cost_limit)})


def _with_state_info(
    record: LocomotionEnvRecord, gym_env: gymnasium.Env, keys: tuple[str, ...] | None = None
) -> gymnasium.Env:
    """``gym_env`` in the :class:`MujocoStateInfo` that adds the state entries Gymnasium's info lacks (if any)."""
    fields = tuple(key for key in (record.state_keys if keys is None else keys) if key in _ADDED_INFO_KEYS)
    return MujocoStateInfo(gym_env, fields) if fields else gym_env


def _gymnasium_base_env(
    record: LocomotionEnvRecord,
    gym_kwargs: Mapping[str, Any],
    device: torch.device | str | None,
    keys: tuple[str, ...] | None = None,
) -> tuple[EnvBase, ModelFacts]:
    """:func:`make_base_env` without the keyword checks, and the facts of its one Gymnasium env."""
    from torchrl.envs.libs.gym import GymWrapper

    keys = record.state_keys if keys is None else keys
    gym_env = _with_state_info(record, make_v5_env(record.env_id, **gym_kwargs), keys)
    facts = ModelFacts.of(gym_env)
    env = GymWrapper(gym_env, device=device)
    env.set_info_dict_reader(Float64InfoReader(record.state_layout(facts, keys)))
    return env, facts


# ------------------------------------------------------------------------------- public API
def locomotion_task(env_id: str, **gym_kwargs: Any) -> GoallessTask:
    """Return the task that reproduces the reward and termination of a Gymnasium MuJoCo v5 locomotion env.

    A :class:`~torchtasks.tasks.GoallessTask` with a :class:`~torchtasks.rewards.CompoundReward`
    whose terms are named like Gymnasium's ``info["reward_*"]``: ``forward``
    (:class:`~torchtasks.rewards.terms.VelocityReward` on Gymnasium's ``x_velocity``),
    ``ctrl`` (:class:`~torchtasks.rewards.terms.ControlCostReward`), ``contact`` (Ant, Humanoid:
    :class:`~torchtasks.rewards.terms.ContactCostReward`) and ``survive`` (Hopper, Walker2d, Ant,
    Humanoid: :class:`~torchtasks.rewards.terms.HealthyReward`, a failure when unhealthy and
    ``terminate_when_unhealthy``). The task's state is the concatenation of the info entries
    :func:`locomotion_state_layout` lists (see the module docstring); the step reward is evaluated
    on the state after the step (``TaskTransform(reward_on="next")``).

    The env is made once (``gymnasium.make``) to read ``dt``, the model sizes and the action bounds,
    so keywords such as ``frame_skip`` or ``xml_file`` are honoured.

    Args:
        env_id: one of :data:`SUPPORTED_ENV_IDS`.
        **gym_kwargs: the env's Gymnasium keyword arguments (``forward_reward_weight``,
            ``ctrl_cost_weight``, ``contact_cost_weight``, ``healthy_reward``, ``healthy_z_range``,
            ``healthy_state_range``, ``healthy_angle_range``, ``contact_force_range``,
            ``contact_cost_range``, ``terminate_when_unhealthy``, ``frame_skip``, ...); defaults
            are Gymnasium v5's. Unknown keywords raise ``TypeError``; weights must be finite (cost
            weights non-negative) and ranges ``(low, high)`` pairs with ``low <= high``.

    Example:
        >>> import torch
        >>> from torchtasks.envs.locomotion import locomotion_task
        >>> task = locomotion_task("Walker2d-v5", healthy_reward=2.0)
        >>> task.term_names
        ('forward', 'ctrl', 'survive')
        >>> start = torch.zeros(1, 10, dtype=torch.float64); start[:, 2] = 1.25  # [x_velocity, qpos]: z = 1.25 m
        >>> moved = start.clone(); moved[:, 0] = 1.0  # moving forward at 1 m/s
        >>> action = torch.zeros(1, 6, dtype=torch.float64)
        >>> terms, reward, memory = task.step_reward_terms(moved, action, task.reset(start))
        >>> reward, task.has_failed(moved, memory)
        (tensor([3.], dtype=torch.float64), tensor([False]))
    """
    config = gymnasium_config(env_id, gym_kwargs)
    return build_locomotion_task(locomotion_record(env_id), config, ModelFacts.make(env_id, gym_kwargs))


def locomotion_state_layout(env_id: str, **gym_kwargs: Any) -> dict[str, int]:
    """Return the info entries that make up the task's state: ``{info key: size}``, in order.

    Example:
        >>> from torchtasks.envs.locomotion import locomotion_state_layout
        >>> locomotion_state_layout("Hopper-v5")
        {'x_velocity': 1, 'qpos': 6, 'qvel': 6}
        >>> locomotion_state_layout("Ant-v5")
        {'x_velocity': 1, 'qpos': 15, 'qvel': 14, 'cfrc_ext': 84}
    """
    gymnasium_config(env_id, gym_kwargs)
    return locomotion_record(env_id).state_layout(ModelFacts.make(env_id, gym_kwargs))


class MujocoStateInfo(gymnasium.Wrapper):
    """Add copies of MuJoCo state arrays to ``info`` at every reset and step.

    Gymnasium's info lacks some of what an exact reproduction of the reward needs: Hopper's health
    check reads the unclipped velocities (the observation clips them to ±10), Walker2d's, Ant's and
    Humanoid's read ``qpos`` entries that are not in info, and Ant's and Humanoid's contact costs read
    all external contact forces. For each name in ``fields`` this wrapper adds
    ``info[name] = env.unwrapped.data.<name>.flatten()`` (a float64 copy) to the info returned by
    the wrapped env's ``reset`` and ``step``. It only reads ``env.unwrapped``; observations,
    rewards and termination flags pass through unchanged and existing info entries are kept.

    Args:
        env: a Gymnasium MuJoCo env (possibly wrapped).
        fields: names of ``mujoco.MjData`` arrays to add, e.g. ``("qpos", "qvel", "cfrc_ext")``.

    Example:
        >>> import gymnasium
        >>> from torchtasks.envs.locomotion import MujocoStateInfo
        >>> env = MujocoStateInfo(gymnasium.make("Hopper-v5"), fields=("qpos", "qvel"))
        >>> observation, info = env.reset(seed=0)
        >>> info["qpos"].shape, info["qvel"].dtype, bool(info["qpos"][0] == info["x_position"])
        ((6,), dtype('float64'), True)
    """

    def __init__(self, env: gymnasium.Env, fields: tuple[str, ...] = _ADDED_INFO_KEYS) -> None:
        super().__init__(env)
        if isinstance(fields, str):
            raise TypeError(f"fields must be a tuple of names, got the string {fields!r}")
        fields = tuple(fields)
        data = getattr(env.unwrapped, "data", None)
        if data is None:
            raise TypeError(f"env must be a Gymnasium MuJoCo env (with unwrapped.data), got {env!r}")
        for field in fields:
            if not isinstance(field, str) or not isinstance(getattr(data, field, None), np.ndarray):
                raise ValueError(f"fields must name arrays of mujoco.MjData, got {field!r}")
        self.fields = fields

    def _with_state(self, info: dict[str, Any]) -> dict[str, Any]:
        data = self.env.unwrapped.data
        added = {field: np.array(getattr(data, field), dtype=np.float64).ravel() for field in self.fields}
        return {**info, **added}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        observation, info = self.env.reset(seed=seed, options=options)
        return observation, self._with_state(info)

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        return observation, reward, terminated, truncated, self._with_state(info)


class Float64InfoReader(default_info_dict_reader):
    """TorchRL info-dict reader that writes info entries as float64 ``[size]`` tensors.

    TorchRL's :class:`~torchrl.envs.gym_like.default_info_dict_reader` with float64 specs, except
    that every value is reshaped to its spec's shape ``[size]`` (Gymnasium's scalar entries such as
    ``x_position`` become ``[1]``, so they can be concatenated into a task state) and cast to
    float64. Entries missing from an info dict (``x_velocity`` at reset) are written as zeros,
    as TorchRL's reader does. Register it with ``env.set_info_dict_reader(reader)``.

    Args:
        layout: ``{info key: size}`` of the entries to read.

    Example:
        >>> import numpy as np
        >>> from tensordict import TensorDict
        >>> from torchtasks.envs.locomotion import Float64InfoReader
        >>> reader = Float64InfoReader({"x_velocity": 1, "qpos": 2})
        >>> td = reader({"qpos": np.array([0.5, 1.0])}, TensorDict())
        >>> td["x_velocity"], td["qpos"]
        (tensor([0.], dtype=torch.float64), tensor([0.5000, 1.0000], dtype=torch.float64))
    """

    def __init__(self, layout: Mapping[str, int]) -> None:
        if not isinstance(layout, Mapping) or not layout:
            raise TypeError(f"layout must be a non-empty mapping {{info key: size}}, got {layout!r}")
        self.layout: dict[str, int] = {}
        for key, size in layout.items():
            if not isinstance(key, str):
                raise TypeError(f"layout keys must be strings, got {key!r}")
            self.layout[key] = check_positive_int(size, f"the layout size of {key!r}")
        spec = Composite(
            {key: Unbounded(shape=(size,), dtype=torch.float64) for key, size in self.layout.items()}, shape=()
        )
        super().__init__(keys=list(self.layout), spec=spec)

    def __call__(self, info_dict: dict[str, Any], tensordict: TensorDictBase) -> TensorDictBase:
        device = tensordict.device
        for key, size in self.layout.items():
            value = info_dict.get(key)
            if value is None:
                tensor = torch.zeros(size, dtype=torch.float64, device=device)
            else:
                tensor = torch.as_tensor(np.asarray(value, dtype=np.float64).reshape(size), device=device)
            tensordict.set(key, tensor)
        return tensordict


def make_gymnasium_env(env_id: str, **gym_kwargs: Any) -> gymnasium.Env:
    """Return ``gymnasium.make(env_id, **gym_kwargs)`` wrapped in the :class:`MujocoStateInfo` the preset needs.

    Only the info entries of :func:`locomotion_state_layout` that Gymnasium lacks are added (none for
    HalfCheetah and Swimmer, which are returned as made). The env checker is disabled.

    Example:
        >>> from torchtasks.envs.locomotion import make_gymnasium_env
        >>> env = make_gymnasium_env("Walker2d-v5")
        >>> sorted(env.reset(seed=0)[1])
        ['qpos', 'x_position', 'z_distance_from_origin']
    """
    gymnasium_config(env_id, gym_kwargs)
    return _with_state_info(locomotion_record(env_id), make_v5_env(env_id, **gym_kwargs))


def make_base_env(
    env_id: str,
    gym_kwargs: Mapping[str, Any] | None = None,
    device: torch.device | str | None = None,
    task_state_keys: Sequence[str] | None = None,
) -> EnvBase:
    """Return the TorchRL ``GymWrapper`` of :func:`make_gymnasium_env` with the task's info entries registered.

    A module-level constructor, so ``functools.partial(make_base_env, env_id, gym_kwargs)`` can be
    sent to spawned ``ParallelEnv`` workers. The observation is Gymnasium's; the entries of
    :func:`locomotion_state_layout` (or those ``task_state_keys`` names, e.g. the record's
    ``safety_state_keys``) are read from info by a :class:`Float64InfoReader`.

    Example:
        >>> from torchtasks.envs.locomotion import make_base_env
        >>> env = make_base_env("Swimmer-v5")
        >>> env.reset()["x_velocity"].dtype, env.observation_spec["observation"].shape
        (torch.float64, torch.Size([8]))
    """
    gym_kwargs = {} if gym_kwargs is None else dict(gym_kwargs)
    gymnasium_config(env_id, gym_kwargs)
    record = locomotion_record(env_id)
    keys = None if task_state_keys is None else _check_task_state_keys(task_state_keys, record)
    return _gymnasium_base_env(record, gym_kwargs, device, keys)[0]


def _check_task_state_keys(task_state_keys: object, record: LocomotionEnvRecord) -> tuple[str, ...]:
    if isinstance(task_state_keys, (str, bytes)) or not isinstance(task_state_keys, Sequence):
        raise TypeError(f"task_state_keys must be a sequence of info keys, got {task_state_keys!r}")
    keys = tuple(task_state_keys)
    known = (*record.velocity_keys, *_ADDED_INFO_KEYS)
    if not keys or len(set(keys)) != len(keys) or not all(isinstance(key, str) and key in known for key in keys):
        raise ValueError(f"task_state_keys must be distinct names among {list(known)} ({record.env_id}), got {keys!r}")
    return keys


def gymnasium_env(
    env_id: str,
    *,
    num_envs: int = 1,
    seed: int | None = None,
    device: torch.device | str | None = None,
    backend: Literal["batched", "gymnasium"] | None = None,
    num_threads: int | None = None,
    observation_dtype: torch.dtype = torch.float64,
    **gym_kwargs: Any,
) -> TransformedEnv:
    """Return a TorchRL env of a Gymnasium MuJoCo v5 locomotion env whose reward comes from :func:`locomotion_task`.

    ``TransformedEnv(base, Compose(StepCounter(1000), TaskTransform(task, state_key=[...]), RewardSum()))``
    where ``base`` is, with ``backend="batched"`` (the default for ``num_envs > 1``), a
    :class:`~torchtasks.envs.batched_mujoco.BatchedMujocoEnv` that steps all ``num_envs`` envs in
    this process with native threads, or, with ``backend="gymnasium"`` (the default for
    ``num_envs == 1``), :func:`make_base_env` (one ``gymnasium.make`` env) or a ``ParallelEnv`` of
    ``num_envs`` of them (built in spawned workers from a ``functools.partial`` of
    :func:`make_base_env`; far slower, kept for parity checks). The keywords are checked once
    and one Gymnasium env is made here: its model facts shape the task and the batched env, or it is
    the single env of the Gymnasium backend (a ``ParallelEnv``'s constructor is also run once here, by
    TorchRL, to read the specs). The policy's ``"observation"`` is
    Gymnasium's, unchanged; the task's state entries (:func:`locomotion_state_layout`) are float64
    root entries. ``"reward"`` is the task reward (float64 with the batched backend, float32 with
    Gymnasium's), ``"success"``/``"failure"`` the task flags (failure = unhealthy with
    ``terminate_when_unhealthy``), ``("task_reward", name)`` the named terms and ``RewardSum``
    writes ``"episode_reward"`` and the per-term episode sums. The batched backend adds
    :class:`~torchtasks.envs.batched_mujoco.ZeroBrokenStepReward` before ``RewardSum``: a broken
    step (a non-finite action or a diverged simulation, marked ``("next", "broken")``) ends that
    env's episode and pays 0 in the reward and every term, so the episode sums stay finite.

    Extending the preset: it is a finished ``TransformedEnv``, so append to it (``env.append_transform``).
    :func:`~torchtasks.transforms.target_names` lists what a :class:`~torchtasks.transforms.Curriculum` or
    :class:`~torchtasks.transforms.DifficultyLevels` can set, with short names (``forward.weight``,
    ``ctrl.weight``, ``survive.healthy_reward``). Append :class:`~torchtasks.transforms.BaseEnvState` too if you
    checkpoint: TorchRL saves the transforms' state, not the base env's (generators, physics). The recipe, with
    the resume: "Extending a preset" in docs/torchrl_integration.md.

    Args:
        env_id: one of :data:`SUPPORTED_ENV_IDS`.
        num_envs: number of environments (both backends handle partial resets).
        seed: ``backend="gymnasium"``: seed passed to ``env.set_seed``: TorchRL then calls the
            Gymnasium env's ``reset(seed=seed)`` once, so plain Gymnasium is reproduced by
            ``reset(seed=seed)`` followed by one ``reset()`` per TorchRL reset.
            ``backend="batched"``: the seed of the per-env reset generators. ``None``: unseeded.
        device: device of the TorchRL env and the task.
        backend: ``"batched"`` or ``"gymnasium"``; ``None``: ``"batched"`` when ``num_envs > 1``.
        num_threads: threads of the batched backend (default: the CPUs this process may use).
        observation_dtype: ``torch.float64`` (Gymnasium's ``"observation"``, the default) or ``torch.float32``:
            a ``DoubleToFloat(in_keys=["observation"])`` after ``RewardSum`` casts the policy's observation, for
            a float32 policy (else torch says ``mat1 and mat2 must have the same dtype``). The task still judges
            the float64 state entries, so rewards, flags and terms are those of the float64 env; the action is
            float32 in both (Gymnasium's action space), cast to float64 for the physics. Other dtypes:
            ``ValueError``.
        **gym_kwargs: the env's Gymnasium keyword arguments, used by both Gymnasium and the task
            (see :func:`locomotion_task`).

    Example:
        >>> import torch
        >>> from torchtasks.envs.locomotion import gymnasium_env
        >>> env = gymnasium_env("Hopper-v5", seed=0)
        >>> rollout = env.rollout(5, break_when_any_done=False)
        >>> rollout["next", "reward"].shape, rollout["next", "task_reward", "survive"][:, 0]
        (torch.Size([5, 1]), tensor([1., 1., 1., 1., 1.]))
        >>> batched = gymnasium_env("Hopper-v5", num_envs=2, seed=0)
        >>> batched.rollout(3)["next", "reward"].shape
        torch.Size([2, 3, 1])
        >>> gymnasium_env("Hopper-v5", seed=0, observation_dtype=torch.float32).reset()["observation"].dtype
        torch.float32

        Extended with a curriculum on the forward weight, and the base env's state for checkpoints:

        >>> from torchrl.collectors import Collector
        >>> from torchtasks.transforms import BaseEnvState, Curriculum, linear, target_names
        >>> print(target_names(batched))  # doctest: +ELLIPSIS
        alias                   name                                   source  shape  writers     value
        ...
        forward.weight          reward.rewards.forward.weight          task    []     Curriculum  1
        ...
        >>> _ = batched.append_transform(Curriculum({"forward.weight": linear(0.0, 1.0, 0, 100)}))
        >>> _ = batched.append_transform(BaseEnvState())  # collector.state_dict() then holds the physics too
        >>> collector = Collector(batched, None, frames_per_batch=20, total_frames=20)  # None: random actions
        >>> [batch["curriculum", "forward/weight"][0, :3, 0].tolist() for batch in collector]
        [[0.0, 0.02, 0.04]]
        >>> collector.shutdown()
    """
    record = locomotion_record(env_id)
    config = gymnasium_config(env_id, gym_kwargs)

    def build_task(facts: ModelFacts) -> Task:
        return build_locomotion_task(record, config, facts)

    keys = record.state_keys
    return preset_env(
        record, config, gym_kwargs, num_envs, seed, device, backend, num_threads, keys, build_task, observation_dtype
    )


def safety_velocity_task(
    env_id: str, *, cost_limit: float | None = SAFETY_COST_LIMIT, **gym_kwargs: Any
) -> ConstrainedTask:
    """Return Gymnasium v5's locomotion task with Safety-Gymnasium's velocity cost as the constraint ``"velocity"``.

    A :class:`~torchtasks.tasks.ConstrainedTask` around the task of :func:`locomotion_task` (the
    same reward terms and failure, so the same reward and termination) whose state is the record's
    ``safety_state_keys``: the locomotion state, plus ``y_velocity`` right after ``x_velocity`` for
    Ant and Humanoid. Its one cost, ``"velocity"``, is an
    :class:`~torchtasks.rewards.AboveThresholdIndicator` of Safety-Gymnasium v1's velocity:
    ``float(x_velocity > threshold)`` for HalfCheetah (3.2096), Hopper (0.7402), Walker2d (2.3415) and
    Swimmer (0.2282); ``float(sqrt(x_velocity² + y_velocity²) > threshold)`` for Ant (2.6222, its
    torso) and Humanoid (1.4149, its centre of mass), each from
    ``safety_gymnasium/tasks/safe_velocity/safety_<env>_velocity_v1.py``, evaluated on the state after
    the step (the state the reward sees). The velocity is measured as Safety-Gymnasium measures it
    but on Gymnasium v5's dynamics, reward and termination, not on the v4 envs Safety-Gymnasium
    subclasses (Walker2d-v5 has other foot friction; see
    :class:`~torchtasks.envs.gymnasium_v5.SafetyVelocityRecord`).

    Args:
        env_id: one of :data:`SUPPORTED_ENV_IDS`.
        cost_limit: the constraint's limit on the expected episode cost (``task.cost_limits``;
            default 25, OmniSafe's); ``None``: no limit.
        **gym_kwargs: the env's Gymnasium keyword arguments (see :func:`locomotion_task`).

    Example:
        >>> import torch
        >>> from torchtasks.envs.locomotion import safety_velocity_task
        >>> task = safety_velocity_task("Ant-v5")
        >>> task.cost_names, task.cost_limits, task.spec.state_space.labels[:3]
        (('velocity',), {'velocity': 25.0}, ('x_velocity', 'y_velocity', 'qpos[0]'))
        >>> state = torch.zeros(3, task.state_size, dtype=torch.float64)
        >>> state[:, :2] = torch.tensor([[2.0, 0.0], [2.0, 1.8], [0.0, -2.7]])  # x_velocity, y_velocity
        >>> state[:, 4] = 0.75  # qpos[2]: the torso at z = 0.75 m (healthy)
        >>> out = task.transition(state, torch.zeros(3, 8, dtype=torch.float64), state, task.reset(state))
        >>> out.costs["velocity"], out.reward
        (tensor([0., 1., 1.], dtype=torch.float64), tensor([3., 3., 1.], dtype=torch.float64))
    """
    config = gymnasium_config(env_id, gym_kwargs)
    cost_limit = _check_cost_limit(cost_limit)
    return _build_safety_task(locomotion_record(env_id), config, ModelFacts.make(env_id, gym_kwargs), cost_limit)


def safety_velocity_env(
    env_id: str,
    *,
    num_envs: int = 1,
    seed: int | None = None,
    device: torch.device | str | None = None,
    backend: Literal["batched", "gymnasium"] | None = None,
    num_threads: int | None = None,
    cost_limit: float | None = SAFETY_COST_LIMIT,
    observation_dtype: torch.dtype = torch.float64,
    **gym_kwargs: Any,
) -> TransformedEnv:
    """Return :func:`gymnasium_env` with the task of :func:`safety_velocity_task`: v5's reward plus the velocity cost.

    The same stack as :func:`gymnasium_env` (``StepCounter(1000)``, the ``TaskTransform``, on the
    batched backend :class:`~torchtasks.envs.batched_mujoco.ZeroBrokenStepReward`, ``RewardSum``),
    the same observation, reward, terms and termination, plus the cost: the ``TaskTransform``
    writes ``("next", "cost")`` (``[*B, 1]``) and ``("next", "task_cost", "velocity")``, 1.0 on the
    steps where Safety-Gymnasium v1's velocity exceeds its threshold (see :func:`safety_velocity_task`),
    0.0 elsewhere (and on a broken step of the batched backend). The task state gains
    ``"y_velocity"`` for Ant and Humanoid (Gymnasium's ``info["y_velocity"]``; the batched env writes it
    too, bit-identical).

    Extending the preset: as for :func:`gymnasium_env` (append a writer; its short names, e.g. the velocity cost's
    ``cost.threshold``, from :func:`~torchtasks.transforms.target_names`).

    Args:
        env_id, num_envs, seed, device, backend, num_threads, observation_dtype: as for :func:`gymnasium_env`.
        cost_limit: the constraint's limit on the expected episode cost (default 25); ``None``: none.
        **gym_kwargs: the env's Gymnasium keyword arguments.

    Example:
        >>> import torch
        >>> from torchtasks.envs.locomotion import safety_velocity_env
        >>> env = safety_velocity_env("Hopper-v5", num_envs=2, seed=0)
        >>> rollout = env.rollout(5, break_when_any_done=False)
        >>> rollout["next", "cost"].shape, rollout["next", "task_cost", "velocity"].shape
        (torch.Size([2, 5, 1]), torch.Size([2, 5, 1]))
        >>> speeding = (rollout["next", "x_velocity"] > 0.7402).to(torch.float64)
        >>> bool((rollout["next", "cost"] == speeding).all())
        True
        >>> from torchtasks.transforms import Curriculum, linear, target_names
        >>> target_names(env).aliases[-6:]
        ['forward.weight', 'ctrl.weight', 'survive.healthy_reward', 'survive.low', 'survive.high', 'cost.threshold']
        >>> _ = env.append_transform(Curriculum({"cost.threshold": linear(2.0, 0.7402, 0, 100)}))  # tighten the limit
        >>> env.rollout(3)["curriculum", "cost/threshold"][0, :, 0].tolist()
        [2.0, 1.97480..., 1.94960...]
        >>> env.close()
    """
    record = locomotion_record(env_id)
    config = gymnasium_config(env_id, gym_kwargs)
    cost_limit = _check_cost_limit(cost_limit)

    def build_task(facts: ModelFacts) -> Task:
        return _build_safety_task(record, config, facts, cost_limit)

    keys = record.safety_state_keys
    return preset_env(
        record, config, gym_kwargs, num_envs, seed, device, backend, num_threads, keys, build_task, observation_dtype
    )


def _observation_cast(observation_dtype: object) -> list[Transform]:
    """The transforms that give the policy's observation ``observation_dtype`` (float64 as is, or float32)."""
    if observation_dtype is torch.float64:
        return []
    if observation_dtype is torch.float32:
        return [DoubleToFloat(in_keys=["observation"], in_keys_inv=[])]
    raise ValueError(
        f"observation_dtype must be torch.float32 (for a float32 policy) or torch.float64 (Gymnasium's, the "
        f"default), got {observation_dtype!r}"
    )


def _check_cost_limit(cost_limit: object) -> float | None:
    if cost_limit is None:
        return None
    return check_weight(cost_limit, "cost_limit")


def preset_env(
    record: LocomotionEnvRecord,
    config: Mapping[str, Any],
    gym_kwargs: Mapping[str, Any],
    num_envs: int,
    seed: int | None,
    device: torch.device | str | None,
    backend: str | None,
    num_threads: int | None,
    keys: tuple[str, ...],
    build_task: Callable[[ModelFacts], Task],
    observation_dtype: torch.dtype = torch.float64,
) -> TransformedEnv:
    """The preset stack on the task state ``keys`` for the task ``build_task(facts)`` (of the one env made here).

    The one builder of :func:`gymnasium_env`, :func:`safety_velocity_env` and the multi-objective presets
    (:mod:`torchtasks.envs.multi_objective`); not in ``__all__``.
    """
    env_id = record.env_id
    num_envs = check_positive_int(num_envs, "num_envs")
    cast = _observation_cast(observation_dtype)
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))):
        raise TypeError(f"seed must be an int or None, got {seed!r}")
    if backend is None:
        backend = "batched" if num_envs > 1 else "gymnasium"
    if backend not in ("batched", "gymnasium"):
        raise ValueError(f"backend must be 'batched' or 'gymnasium', got {backend!r}")
    if num_threads is not None and backend != "batched":
        raise ValueError("num_threads applies to backend='batched' only")
    # one Gymnasium env is made here: its facts shape the task and, on the batched backend, the batched env
    base: EnvBase
    if backend == "gymnasium" and num_envs == 1:
        base, facts = _gymnasium_base_env(record, gym_kwargs, device, keys)
    else:
        facts = ModelFacts.make(env_id, gym_kwargs)
        if backend == "batched":
            base = BatchedMujocoEnv(
                env_id,
                num_envs,
                seed=seed,
                device=device,
                num_threads=num_threads,
                task_state_keys=keys,
                _checked=(config, facts),
                **gym_kwargs,
            )
        else:  # the workers make their own envs when the ParallelEnv starts
            create_env = functools.partial(make_base_env, env_id, dict(gym_kwargs), device, keys)
            base = ParallelEnv(num_envs, create_env, device=device)
    task = build_task(facts)
    if device is not None:
        task = task.to(device)
    transforms: list[Transform] = [
        StepCounter(MAX_EPISODE_STEPS),
        TaskTransform(task, state_key=list(keys)),
    ]
    if backend == "batched":
        transforms.append(ZeroBrokenStepReward())  # a broken step (marked "broken") pays 0, not a NaN control cost
    # the cast comes last: the task reads the float64 state entries, never the policy's observation
    env = TransformedEnv(base, Compose(*transforms, RewardSum(), *cast))
    if seed is not None and backend == "gymnasium":
        env.set_seed(int(seed))
    return env
