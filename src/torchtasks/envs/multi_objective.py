"""MO-Gymnasium's MuJoCo v5 envs as presets: Gymnasium's scalar reward plus MO-Gymnasium's vector reward.

:func:`multi_objective_env` builds ``mo-halfcheetah-v5``, ``mo-hopper-v5``, ``mo-hopper-2obj-v5``,
``mo-walker2d-v5``, ``mo-ant-v5``, ``mo-ant-2obj-v5``, ``mo-swimmer-v5`` and ``mo-humanoid-v5`` of MO-Gymnasium
1.3.2 (``mo_gymnasium/envs/mujoco/*_v5.py``) on the stack of :func:`~torchtasks.envs.locomotion.gymnasium_env`
(both backends): ``"reward"`` stays Gymnasium's scalar reward and ``("next", "vector_reward")`` is MO-Gymnasium's
vector reward, float32 ``[*B, k]``, equal to it bit for bit on the same states. The task
(:func:`multi_objective_task`) is a :class:`~torchtasks.tasks.RewardGroupsTask` around the locomotion task of
the base env: each objective is a reward group of the locomotion terms (``forward``, ``ctrl``, ``contact``,
``survive``) and of extra terms read from the task state, accumulated as MO-Gymnasium does (the objective's own
quantity rounded to float32, then each shared term added in place, ``vec += term``, in the env's order).

=================  ===========  ========================================  ===========================
id                 base env     objectives, in the vector's order         added to every objective
=================  ===========  ========================================  ===========================
mo-halfcheetah-v5  HalfCheetah  ``x_velocity``, ``energy``
mo-hopper-v5       Hopper       ``x_velocity``, ``height``, ``energy``    ``survive``
mo-hopper-2obj-v5  Hopper       ``x_velocity``, ``height``                ``ctrl``, ``survive``
mo-walker2d-v5     Walker2d     ``x_velocity``, ``energy``                ``survive``
mo-ant-v5          Ant          ``x_velocity``, ``y_velocity``,           ``survive``, ``contact``
                                ``energy``
mo-ant-2obj-v5     Ant          ``x_velocity``, ``y_velocity``            ``ctrl``, ``survive``, ``contact``
mo-swimmer-v5      Swimmer      ``x_velocity``, ``energy``
mo-humanoid-v5     Humanoid     ``x_velocity``, ``energy``                ``survive``, ``contact``
=================  ===========  ========================================  ===========================

``x_velocity`` and ``y_velocity`` are Gymnasium's ``info`` entries, ``height`` is Hopper's ``10 · (qpos[1] −
init_qpos[1])`` (``10 * info["z_distance_from_origin"]``), ``energy`` is ``info["reward_ctrl"] /
ctrl_cost_weight = −Σa²`` (a ``ctrl_cost_weight`` of 0 is refused: MO-Gymnasium divides 0 by 0 there). The
"2obj" ids add the weighted ``ctrl`` term to the other objectives instead (MO-Gymnasium's
``cost_objective=False``).

Scalarisation: with the weights of :attr:`MultiObjectiveRecord.weights` (MO-Gymnasium's docstrings give those of
HalfCheetah, Swimmer, Hopper, Walker2d, Humanoid and Ant-2obj; Hopper-2obj's and Ant-v5's are derived), TorchRL's
``LineariseRewards`` of the vector gives Gymnasium's scalar reward plus a residual,
:attr:`MultiObjectiveRecord.residual` ``{term: coefficient}``, for Gymnasium's default keywords: 0 for
HalfCheetah, Swimmer, Hopper-2obj and Ant-2obj, ``0.001 · survive`` for Hopper and Walker2d (the docstrings' weights
pay the healthy reward 1.001 times), ``0.35 · (survive + contact)`` for Humanoid (+1.75 per healthy step) and
``0.5 · (survive + contact)`` for Ant-v5 (whose energy objective carries both, weighted by 0.5 to pay the control
cost). Everything that differs between the ids is data in :data:`MULTI_OBJECTIVE_ENVS`; no code branches on the id.
"""

from __future__ import annotations

import types
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple

import torch
from torchrl.envs import TransformedEnv

from torchtasks._checks import did_you_mean
from torchtasks._optional import missing_extra
from torchtasks.rewards.base import RewardFunction
from torchtasks.rewards.terms import DisplacementReward
from torchtasks.tasks.groups import RewardGroupsTask
from torchtasks.tasks.protocol import Task

try:
    import gymnasium  # noqa: F401
    import mujoco  # noqa: F401
except ImportError as _error:
    raise missing_extra("mujoco", "torchtasks.envs.multi_objective (the MO-Gymnasium presets)", _error) from _error

from torchtasks.envs.gymnasium_v5 import LocomotionEnvRecord, ModelFacts, gymnasium_config, locomotion_record
from torchtasks.envs.locomotion import build_locomotion_task, preset_env, state_starts

__all__ = [
    "MULTI_OBJECTIVE_ENVS",
    "MULTI_OBJECTIVE_ENV_IDS",
    "InverseOf",
    "MultiObjectiveRecord",
    "StateTerm",
    "multi_objective_env",
    "multi_objective_record",
    "multi_objective_task",
]

# written out rather than tuple(MULTI_OBJECTIVE_ENVS), so that `torchtasks list` and `check` read it from this file
# without the mujoco extra; tests/envs/test_multi_objective.py checks that it lists the table's keys, in order
#: the MO-Gymnasium ids :func:`multi_objective_env` supports
MULTI_OBJECTIVE_ENV_IDS: tuple[str, ...] = (
    "mo-halfcheetah-v5",
    "mo-hopper-v5",
    "mo-hopper-2obj-v5",
    "mo-walker2d-v5",
    "mo-ant-v5",
    "mo-ant-2obj-v5",
    "mo-swimmer-v5",
    "mo-humanoid-v5",
)

#: the dtype of MO-Gymnasium's vector reward (``np.array([...], dtype=np.float32)``)
VECTOR_REWARD_DTYPE = torch.float32


class InverseOf(NamedTuple):
    """A coefficient that is ``1 / config[keyword]``: the control objective is ``reward_ctrl / ctrl_cost_weight``.

    Example:
        >>> from torchtasks.envs.multi_objective import InverseOf
        >>> InverseOf("ctrl_cost_weight").value({"ctrl_cost_weight": 0.1}, "mo-halfcheetah-v5")
        10.0
    """

    keyword: str

    def value(self, config: Mapping[str, Any], env_id: str) -> float:
        """``1 / config[keyword]``; a ``ValueError`` when it is 0 (the objective would be 0/0)."""
        divisor = float(config[self.keyword])
        if divisor == 0.0:
            raise ValueError(
                f"{env_id}: {self.keyword} must be > 0 (its control objective is reward_ctrl / {self.keyword}, "
                f"which MO-Gymnasium computes as 0/0 = nan), got {config[self.keyword]!r}"
            )
        return 1.0 / divisor


class StateTerm(NamedTuple):
    """An extra term read from the task state: ``scale · (state[key][entry] − origin)``.

    ``origin`` is 0, or with ``from_initial`` the entry's value in the model's initial state (``init_qpos`` or
    ``init_qvel``). Built as a :class:`~torchtasks.rewards.DisplacementReward` (the difference first, in the
    state's float64): ``StateTerm("x_velocity")`` is Gymnasium's ``info["x_velocity"]`` itself, and Hopper's
    ``StateTerm("qpos", 1, scale=10.0, from_initial=True)`` is MO-Gymnasium's ``10 * (qpos[1] − init_qpos[1])``.

    Example:
        >>> from torchtasks.envs.multi_objective import StateTerm
        >>> StateTerm("qpos", 1, scale=10.0, from_initial=True).entry
        1
    """

    key: str
    entry: int = 0
    scale: float = 1.0
    from_initial: bool = False

    def build(self, facts: ModelFacts, starts: Mapping[str, int]) -> RewardFunction:
        """The term on the task state whose entries start at ``starts`` (``{key: first index}``)."""
        initial = {"qpos": facts.init_qpos, "qvel": facts.init_qvel}
        origin = float(initial[self.key][self.entry]) if self.from_initial else 0.0
        return DisplacementReward(self.scale, index=starts[self.key] + self.entry, origin=origin)


#: a group's coefficient: a number, or ``1 / config[keyword]``
Coefficient = float | InverseOf


@dataclass(frozen=True, eq=False)
class MultiObjectiveRecord:
    """One MO-Gymnasium MuJoCo v5 env: its base env, its objectives as reward groups and its scalarisation.

    Attributes:
        env_id: MO-Gymnasium's id (``"mo-hopper-v5"``).
        base_id: the Gymnasium env it subclasses (``"Hopper-v5"``): its locomotion task gives the scalar reward.
        objectives: ``{objective: {source: coefficient}}`` in MO-Gymnasium's order, each objective's own quantity
            first and then the shared terms in the order MO-Gymnasium adds them; a source is a term of the
            locomotion task (``forward``, ``ctrl``, ``contact``, ``survive``) or of :attr:`extras`.
        extras: the terms the objectives read that the scalar reward does not pay (:class:`StateTerm`).
        state_keys: the task state (the base record's keys, plus ``y_velocity`` where an objective reads it).
        weights: the scalarisation weights for Gymnasium's default keywords (``LineariseRewards``' ``weights``).
        weights_from: ``"docstring"`` (MO-Gymnasium's class docstring gives them) or ``"derived"``.
        residual: ``{term: coefficient}``: the weighted vector minus Gymnasium's scalar reward is
            ``Σ coefficient · term`` (the locomotion task's terms, Gymnasium's default keywords); empty: none.
        notes: what else the record's reproduction depends on (e.g. Hopper's Python-float healthy reward).

    Example:
        >>> from torchtasks.envs.multi_objective import multi_objective_record
        >>> record = multi_objective_record("mo-walker2d-v5")
        >>> record.base_id, list(record.objectives), record.weights, record.residual
        ('Walker2d-v5', ['x_velocity', 'energy'], (1.0, 0.001), {'survive': 0.001})
    """

    env_id: str
    base_id: str
    objectives: Mapping[str, Mapping[str, Coefficient]]
    extras: Mapping[str, StateTerm]
    state_keys: tuple[str, ...]
    weights: tuple[float, ...]
    weights_from: Literal["docstring", "derived"]
    residual: Mapping[str, float]
    notes: str = ""

    @property
    def base(self) -> LocomotionEnvRecord:
        """The base env's record (:mod:`torchtasks.envs.gymnasium_v5`)."""
        return locomotion_record(self.base_id)

    @property
    def objective_names(self) -> tuple[str, ...]:
        """The objectives in the vector's order (the groups' names)."""
        return tuple(self.objectives)

    def groups(self, config: Mapping[str, Any]) -> dict[str, dict[str, float]]:
        """The reward groups for the keywords ``config`` (of :func:`~torchtasks.envs.gymnasium_v5.gymnasium_config`).

        Raises ``ValueError`` when a coefficient ``1 / config[keyword]`` would divide by 0.
        """
        return {
            objective: {
                source: coefficient.value(config, self.env_id) if isinstance(coefficient, InverseOf) else coefficient
                for source, coefficient in sources.items()
            }
            for objective, sources in self.objectives.items()
        }


_ENERGY = InverseOf("ctrl_cost_weight")
_X = StateTerm("x_velocity")
_Y = StateTerm("y_velocity")
#: Hopper's height objective: 10 * info["z_distance_from_origin"], with z = qpos[1] - init_qpos[1]
_HEIGHT = StateTerm("qpos", 1, scale=10.0, from_initial=True)
_HOPPER_NOTE = (
    "MO-Gymnasium adds info['reward_survive'], a Python float, which numpy rounds to float32 before the addition; "
    "the groups add it in float64 and round once: the same for healthy_reward values float32 represents (the "
    "default 1.0)"
)

#: the supported ids: ``{env_id: record}``, one table (read-only)
MULTI_OBJECTIVE_ENVS: Mapping[str, MultiObjectiveRecord] = types.MappingProxyType(
    {
        record.env_id: record
        for record in (
            MultiObjectiveRecord(
                "mo-halfcheetah-v5",
                base_id="HalfCheetah-v5",
                objectives={"x_velocity": {"x_velocity": 1.0}, "energy": {"ctrl": _ENERGY}},
                extras={"x_velocity": _X},
                state_keys=("x_velocity",),
                weights=(1.0, 0.1),
                weights_from="docstring",
                residual={},
            ),
            MultiObjectiveRecord(
                "mo-hopper-v5",
                base_id="Hopper-v5",
                objectives={
                    "x_velocity": {"x_velocity": 1.0, "survive": 1.0},
                    "height": {"height": 1.0, "survive": 1.0},
                    "energy": {"ctrl": _ENERGY, "survive": 1.0},
                },
                extras={"x_velocity": _X, "height": _HEIGHT},
                state_keys=("x_velocity", "qpos", "qvel"),
                weights=(1.0, 0.0, 1e-3),
                weights_from="docstring",
                residual={"survive": 1e-3},
                notes=_HOPPER_NOTE,
            ),
            MultiObjectiveRecord(
                "mo-hopper-2obj-v5",
                base_id="Hopper-v5",
                objectives={
                    "x_velocity": {"x_velocity": 1.0, "ctrl": 1.0, "survive": 1.0},
                    "height": {"height": 1.0, "ctrl": 1.0, "survive": 1.0},
                },
                extras={"x_velocity": _X, "height": _HEIGHT},
                state_keys=("x_velocity", "qpos", "qvel"),
                weights=(1.0, 0.0),
                weights_from="derived",
                residual={},
                notes=_HOPPER_NOTE,
            ),
            MultiObjectiveRecord(
                "mo-walker2d-v5",
                base_id="Walker2d-v5",
                objectives={
                    "x_velocity": {"x_velocity": 1.0, "survive": 1.0},
                    "energy": {"ctrl": _ENERGY, "survive": 1.0},
                },
                extras={"x_velocity": _X},
                state_keys=("x_velocity", "qpos"),
                weights=(1.0, 1e-3),
                weights_from="docstring",
                residual={"survive": 1e-3},
            ),
            MultiObjectiveRecord(
                "mo-ant-v5",
                base_id="Ant-v5",
                objectives={
                    "x_velocity": {"x_velocity": 1.0, "survive": 1.0, "contact": 1.0},
                    "y_velocity": {"y_velocity": 1.0, "survive": 1.0, "contact": 1.0},
                    "energy": {"ctrl": _ENERGY, "survive": 1.0, "contact": 1.0},
                },
                extras={"x_velocity": _X, "y_velocity": _Y},
                state_keys=("x_velocity", "y_velocity", "qpos", "qvel", "cfrc_ext"),
                weights=(1.0, 0.0, 0.5),
                weights_from="derived",
                residual={"survive": 0.5, "contact": 0.5},
            ),
            MultiObjectiveRecord(
                "mo-ant-2obj-v5",
                base_id="Ant-v5",
                objectives={
                    "x_velocity": {"x_velocity": 1.0, "ctrl": 1.0, "survive": 1.0, "contact": 1.0},
                    "y_velocity": {"y_velocity": 1.0, "ctrl": 1.0, "survive": 1.0, "contact": 1.0},
                },
                extras={"x_velocity": _X, "y_velocity": _Y},
                state_keys=("x_velocity", "y_velocity", "qpos", "qvel", "cfrc_ext"),
                weights=(1.0, 0.0),
                weights_from="docstring",  # MO-Gymnasium's Ant docstring: cost_objective=False, weight [1, 0]
                residual={},
            ),
            MultiObjectiveRecord(
                "mo-swimmer-v5",
                base_id="Swimmer-v5",
                objectives={"x_velocity": {"x_velocity": 1.0}, "energy": {"ctrl": _ENERGY}},
                extras={"x_velocity": _X},
                state_keys=("x_velocity",),
                weights=(1.0, 1e-4),
                weights_from="docstring",
                residual={},
            ),
            MultiObjectiveRecord(
                "mo-humanoid-v5",
                base_id="Humanoid-v5",
                objectives={
                    "x_velocity": {"x_velocity": 1.0, "survive": 1.0, "contact": 1.0},
                    "energy": {"ctrl": _ENERGY, "survive": 1.0, "contact": 1.0},
                },
                extras={"x_velocity": _X},
                state_keys=("x_velocity", "qpos", "cfrc_ext"),
                weights=(1.25, 0.1),
                weights_from="docstring",
                residual={"survive": 0.35, "contact": 0.35},
            ),
        )
    }
)


# ------------------------------------------------------------------------------- look-ups
def multi_objective_record(env_id: object) -> MultiObjectiveRecord:
    """Return the record of ``env_id``; raise ``TypeError``/``ValueError`` naming the closest ids otherwise.

    Example:
        >>> from torchtasks.envs.multi_objective import multi_objective_record
        >>> multi_objective_record("mo-ant-2obj-v5").objective_names
        ('x_velocity', 'y_velocity')
        >>> try:
        ...     multi_objective_record("Hopper-v5")
        ... except ValueError as error:
        ...     print(str(error).split(" (")[0])
        unknown MO-Gymnasium env 'Hopper-v5'; did you mean 'mo-hopper-v5'?
    """
    if not isinstance(env_id, str):
        raise TypeError(f"env_id must be a string, got {type(env_id).__name__}")
    record = MULTI_OBJECTIVE_ENVS.get(env_id)
    if record is None:
        hint = did_you_mean(env_id.lower(), MULTI_OBJECTIVE_ENV_IDS, n=2)
        raise ValueError(f"unknown MO-Gymnasium env {env_id!r}{hint} (the ids: {', '.join(MULTI_OBJECTIVE_ENV_IDS)})")
    return record


def _config(
    record: MultiObjectiveRecord, gym_kwargs: Mapping[str, Any]
) -> tuple[dict[str, Any], dict[str, dict[str, float]]]:
    """The checked keywords merged over the base env's defaults, and the groups they give."""
    if "cost_objective" in gym_kwargs:
        raise TypeError(
            f"{record.env_id} got the keyword cost_objective, which the id fixes (MO-Gymnasium's '-2obj' ids pass "
            "cost_objective=False); choose the id instead"
        )
    config = gymnasium_config(record.base_id, gym_kwargs)
    return config, record.groups(config)


def _build_multi_objective_task(
    record: MultiObjectiveRecord, config: Mapping[str, Any], facts: ModelFacts, groups: Mapping[str, Any]
) -> RewardGroupsTask:
    base = record.base
    starts = state_starts(base.state_layout(facts, record.state_keys))
    extras = {name: term.build(facts, starts) for name, term in record.extras.items()}
    task = build_locomotion_task(base, config, facts, record.state_keys)
    return RewardGroupsTask(task, groups, terms=extras, dtype=VECTOR_REWARD_DTYPE)


# ------------------------------------------------------------------------------- public API
def multi_objective_task(env_id: str, **gym_kwargs: Any) -> RewardGroupsTask:
    """Return the task of an MO-Gymnasium MuJoCo v5 env: Gymnasium's reward, and MO-Gymnasium's objectives as groups.

    A :class:`~torchtasks.tasks.RewardGroupsTask` (float32 groups) around
    :func:`~torchtasks.envs.locomotion.locomotion_task`'s task of the base env on the record's state keys: the
    reward, the terms and the termination are Gymnasium's; the groups, in :attr:`~torchtasks.tasks.Task.group_names`
    order, are MO-Gymnasium's objectives (see the module docstring and :data:`MULTI_OBJECTIVE_ENVS`).

    Args:
        env_id: one of :data:`MULTI_OBJECTIVE_ENV_IDS`.
        **gym_kwargs: the base env's Gymnasium keyword arguments (checked as by
            :func:`~torchtasks.envs.locomotion.locomotion_task`); ``ctrl_cost_weight`` must be > 0 for the ids
            with an energy objective; ``cost_objective`` is fixed by the id.

    Example:
        >>> import torch
        >>> from torchtasks.envs.multi_objective import multi_objective_task
        >>> task = multi_objective_task("mo-halfcheetah-v5")
        >>> task.group_names, task.group_dtype
        (('x_velocity', 'energy'), torch.float32)
        >>> state = torch.tensor([[1.5]], dtype=torch.float64)  # x_velocity
        >>> action = torch.full((1, 6), 0.5, dtype=torch.float64)
        >>> out = task.transition(state, action, state, task.reset(state))
        >>> out.reward, out.groups["x_velocity"], out.groups["energy"]
        (tensor([1.3500], dtype=torch.float64), tensor([1.5000]), tensor([-1.5000]))
    """
    record = multi_objective_record(env_id)
    config, groups = _config(record, gym_kwargs)
    return _build_multi_objective_task(record, config, ModelFacts.make(record.base_id, gym_kwargs), groups)


def multi_objective_env(
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
    """Return a TorchRL env of an MO-Gymnasium MuJoCo v5 env: Gymnasium's scalar reward and the vector reward.

    The stack of :func:`~torchtasks.envs.locomotion.gymnasium_env` on the base env (``StepCounter(1000)``, the
    ``TaskTransform``, :class:`~torchtasks.envs.batched_mujoco.ZeroBrokenStepReward` on the batched backend,
    ``RewardSum``) with :func:`multi_objective_task`'s task: ``("next", "reward")`` is Gymnasium's scalar reward,
    ``("next", "vector_reward")`` MO-Gymnasium's vector reward (float32 ``[*B, k]``, the objectives in
    :attr:`~torchtasks.tasks.Task.group_names` order; 0 on a broken step of the batched backend),
    ``("next", "reward_groups", name)`` each objective, and ``RewardSum`` writes ``"episode_vector_reward"``
    beside ``"episode_reward"``. Append TorchRL's ``LineariseRewards(in_keys=["vector_reward"], out_keys=[...],
    weights=record.weights)`` to scalarise (see :class:`MultiObjectiveRecord` for what the weights leave over).
    MO-Gymnasium itself is not used: the Gymnasium backend runs ``gymnasium.make(base id)``. Extending the
    preset: as for :func:`~torchtasks.envs.locomotion.gymnasium_env` (append a writer; its short names, e.g. an
    objective's ``weights_energy``, from :func:`~torchtasks.transforms.target_names`).

    Args:
        env_id: one of :data:`MULTI_OBJECTIVE_ENV_IDS`.
        num_envs, seed, device, backend, num_threads, observation_dtype: as for
            :func:`~torchtasks.envs.locomotion.gymnasium_env` (``torch.float32``: a float32 ``"observation"``).
        **gym_kwargs: the base env's Gymnasium keyword arguments (see :func:`multi_objective_task`).

    Example:
        >>> import torch
        >>> from torchtasks.envs.multi_objective import multi_objective_env
        >>> env = multi_objective_env("mo-hopper-v5", num_envs=2, seed=0)
        >>> rollout = env.rollout(3)
        >>> vector = rollout["next", "vector_reward"]
        >>> vector.shape, vector.dtype, rollout["next", "reward"].shape
        (torch.Size([2, 3, 3]), torch.float32, torch.Size([2, 3, 1]))
        >>> rollout["next", "episode_vector_reward"].shape
        torch.Size([2, 3, 3])
        >>> from torchtasks.transforms import Curriculum, constant, target_names
        >>> "weights_energy" in target_names(env).aliases
        True
        >>> _ = env.append_transform(Curriculum({"weights_energy": constant([0.0, 0.0])}))  # energy objective off
        >>> env.rollout(2)["next", "reward_groups", "energy"].abs().max().item()
        0.0
        >>> env.close()
    """
    record = multi_objective_record(env_id)
    config, groups = _config(record, gym_kwargs)

    def build_task(facts: ModelFacts) -> Task:
        return _build_multi_objective_task(record, config, facts, groups)

    keys, base = record.state_keys, record.base
    return preset_env(
        base, config, gym_kwargs, num_envs, seed, device, backend, num_threads, keys, build_task, observation_dtype
    )
