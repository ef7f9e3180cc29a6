"""What each Gymnasium MuJoCo v5 locomotion env is: one record of facts per env, in one table.

:data:`LOCOMOTION_ENVS` maps each supported id (``HalfCheetah-v5``, ``Hopper-v5``, ``Walker2d-v5``,
``Swimmer-v5``, ``Ant-v5``, ``Humanoid-v5``) to a :class:`LocomotionEnvRecord`: the task state it
is scored on, how its observation is put together, how its resets draw velocities, how its forward
velocity is measured and which reward terms it has, with the rules (contact cost, health) that
differ from env to env, and Safety-Gymnasium's velocity constraint of the env
(:class:`SafetyVelocityRecord`: its v1 threshold and which velocity it bounds). Everything that reads
these facts reads them here:
:class:`~torchtasks.envs.batched_mujoco.BatchedMujocoEnv` (observation, reset noise, forward
position, the velocities it writes), the task factories and the env builders of
:mod:`torchtasks.envs.locomotion` (state layout, reward terms, the safety velocity cost) and
:mod:`torchtasks.parity` (keyword checks). A new env is one more record; a reader
never branches on the id.

Two more things are read for an env and its Gymnasium keyword arguments:
:func:`gymnasium_config` validates the keywords and merges them over Gymnasium's own defaults (read
from the env class's signature), and :class:`ModelFacts` holds what one made Gymnasium env tells
(the MuJoCo model, ``dt``, sizes, initial state, observation size, action bounds), so that a caller
makes the env once and hands the facts on.

This module is the bottom of :mod:`torchtasks.envs`: it imports reward terms and Gymnasium, never
the batched env, the presets or TorchRL transforms.
"""

from __future__ import annotations

import functools
import inspect
import math
import types
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple

import numpy as np

from torchtasks._checks import check_finite_scalar, check_pair, check_positive_int, check_weight
from torchtasks._optional import missing_extra
from torchtasks.rewards.base import RewardFunction
from torchtasks.rewards.terms import ContactCostReward, HealthyReward

# the 'mujoco' extra: without it, importing this module raises an error naming the extra to install
try:
    import gymnasium
    import mujoco
    from gymnasium.envs.mujoco.mujoco_env import MujocoEnv
    from gymnasium.envs.registration import load_env_creator
except ImportError as _error:
    raise missing_extra("mujoco", "torchtasks.envs.gymnasium_v5 (the Gymnasium MuJoCo v5 records)", _error) from _error

from torchtasks.envs._mujoco_log import quiet_model_loading, route_mujoco_warnings
from torchtasks.envs.mujoco_declaration import MujocoDeclaration, Noise, ResolvedResets
from torchtasks.envs.readings import Reading, body_pos, data_field, finite_difference, mass_centre

__all__ = [
    "LOCOMOTION_ENVS",
    "LocomotionEnvRecord",
    "ModelFacts",
    "ObservationPart",
    "SafetyVelocityRecord",
    "gymnasium_config",
    "gymnasium_declaration",
    "locomotion_record",
    "make_v5_env",
]

# MuJoCo's warnings become Python warnings (no MUJOCO_LOG.TXT in the user's directory)
route_mujoco_warnings()

#: MujocoEnv keyword arguments that every MuJoCo env forwards through ``**kwargs``
_MUJOCO_ENV_KWARGS = ("render_mode", "width", "height", "camera_id", "camera_name", "max_geom", "visual_options")


def make_v5_env(env_id: str, *, env_checker: bool = False, **gym_kwargs: Any) -> gymnasium.Env:
    """Return ``gymnasium.make(env_id, **gym_kwargs)`` without MuJoCo's notices about Gymnasium's own model files.

    MuJoCo 4 reports that ``half_cheetah.xml`` uses the deprecated ``settotalmass``; the model is
    Gymnasium's and compiles bit-identically, so torchtasks hides that notice where it builds one
    (other MuJoCo warnings reach Python's ``warnings`` as ``MujocoWarning``). ``env_checker`` turns
    Gymnasium's env checker on.

    Example:
        >>> from torchtasks.envs.gymnasium_v5 import make_v5_env
        >>> env = make_v5_env("HalfCheetah-v5")
        >>> env.observation_space.shape
        (17,)
        >>> env.close()
    """
    with quiet_model_loading():
        return gymnasium.make(env_id, disable_env_checker=not env_checker, **gym_kwargs)


class ObservationPart(NamedTuple):
    """One piece of an observation: ``data.<source>[start:]``, flattened, clipped to ``clip`` unless it is None.

    ``source`` names a ``mujoco.MjData`` array (``"qpos"``, ``"qvel"``, ``"cfrc_ext"``, ``"cinert"``,
    ...); ``start`` is the number of leading entries (rows of 2-D arrays) left out: the skipped
    positions of ``qpos``, the world body of the per-body arrays, the free joint of ``qfrc_actuator``.

    Example:
        >>> from torchtasks.envs.gymnasium_v5 import ObservationPart
        >>> ObservationPart("qvel", 0, (-10.0, 10.0)).clip
        (-10.0, 10.0)
    """

    source: str
    start: int
    clip: tuple[float, float] | None


def _no_extras(config: Mapping[str, Any]) -> tuple[ObservationPart, ...]:
    return ()


#: where Safety-Gymnasium's velocity tasks live (github.com/PKU-Alignment/safety-gymnasium)
SAFETY_VELOCITY_SOURCE = "safety_gymnasium/tasks/safe_velocity"


@dataclass(frozen=True)
class SafetyVelocityRecord:
    """Safety-Gymnasium's velocity constraint of one env: ``cost = float(velocity > threshold)`` per step.

    Safety-Gymnasium's ``Safety<Env>Velocity-v1`` (github.com/PKU-Alignment/safety-gymnasium,
    ``safety_gymnasium/tasks/safe_velocity/safety_<env>_velocity_v1.py``) subclasses its ``_v0``
    class, which subclasses Gymnasium's **v4** env and returns ``(observation, reward, cost,
    terminated, truncated, info)`` from ``step``; v1 changes only ``self._velocity_threshold`` (and,
    for Swimmer, the quantity: v1's own ``step`` compares ``x_velocity``, v0 the planar speed). The
    velocity is finite-differenced over the step exactly as Gymnasium v5 computes its
    ``info["x_velocity"]``/``info["y_velocity"]``:

    ============  =========  ======================================================================
    env           threshold  velocity (``before``/``after`` the ``frame_skip`` substeps, ``/ dt``)
    ============  =========  ======================================================================
    HalfCheetah   3.2096     ``x_velocity``: ``qpos[0]``, signed
    Hopper        0.7402     ``x_velocity``: ``qpos[0]``, signed
    Walker2d      2.3415     ``x_velocity``: ``qpos[0]``, signed
    Swimmer       0.2282     ``x_velocity``: ``qpos[0]`` (of ``qpos[0:2]``), signed
    Ant           2.6222     ``sqrt(x_velocity² + y_velocity²)``: the torso's ``xpos[:2]``
                             (``get_body_com("torso")``; v5's ``main_body``, default the torso)
    Humanoid      1.4149     ``sqrt(x_velocity² + y_velocity²)``: the centre of mass
                             ``Σ body_mass · xipos / Σ body_mass``, ``[:2]`` (``mass_center``)
    ============  =========  ======================================================================

    ``dt = timestep · frame_skip`` is the same in v4 and v5 (0.05, 0.008, 0.008, 0.04, 0.05, 0.015).
    The comparison is strict and signed for the x-only envs (running backwards never costs, although
    Safety-Gymnasium's documentation writes ``abs(x_velocity)``; its code compares the signed value).
    torchtasks measures this velocity on Gymnasium **v5**'s dynamics, reward and termination, which
    differ from the v4 envs Safety-Gymnasium runs: Walker2d-v5's right foot has the left foot's
    friction (1.9, v4: 0.9), so its dynamics differ; Hopper, Walker2d, Ant and Humanoid v5 pay
    ``healthy_reward`` only while healthy (v4 also on the terminating step); Ant-v5 always has a
    contact cost and observes the contact forces (v4 with Safety-Gymnasium's defaults does neither);
    Humanoid-v5 has a contact cost again and leaves the world body out of its observation. The
    thresholds were set by Safety-Gymnasium from v4 runs (half the top speed of PPO after 1e7 steps,
    ``docs/environments/safe_velocity.rst``) and are used unchanged.

    Attributes:
        safety_id: Safety-Gymnasium's id (``"SafetyHopperVelocity-v1"``).
        threshold: the v1 ``_velocity_threshold``.
        velocity_keys: the velocity entries compared: ``("x_velocity",)`` (the signed entry) or
            ``("x_velocity", "y_velocity")`` (their Euclidean norm).
        source: the file in Safety-Gymnasium's repository that sets the threshold.

    Example:
        >>> from torchtasks.envs.gymnasium_v5 import locomotion_record
        >>> safety = locomotion_record("Ant-v5").safety_velocity
        >>> safety.threshold, safety.velocity_keys, safety.planar
        (2.6222, ('x_velocity', 'y_velocity'), True)
        >>> safety.source
        'safety_gymnasium/tasks/safe_velocity/safety_ant_velocity_v1.py'
    """

    safety_id: str
    threshold: float
    velocity_keys: tuple[str, ...]
    source: str

    @property
    def planar(self) -> bool:
        """Whether the speed in the plane (the norm of x and y velocities) is bounded, not the signed x velocity."""
        return len(self.velocity_keys) > 1


@dataclass(frozen=True)
class LocomotionEnvRecord:
    """The facts of one Gymnasium MuJoCo v5 locomotion env that differ from env to env.

    Attributes:
        env_id: the Gymnasium id.
        state_keys: the task's state, in concatenation order: ``"x_velocity"`` (Gymnasium's
            ``info["x_velocity"]``), then the ``mujoco.MjData`` arrays the reward and health rules
            read that Gymnasium's info lacks (``"qpos"``, ``"qvel"``, ``"cfrc_ext"``, flattened).
        skipped_positions: leading ``qpos`` entries the observation leaves out with
            ``exclude_current_positions_from_observation`` (x, or x and y).
        velocity_clip: the bound ``b`` of ``clip(qvel, -b, b)`` in the observation; None: unclipped.
        velocity_noise: the distribution of the reset noise of ``qvel``: ``"uniform"`` (half-width
            ``reset_noise_scale``) or ``"normal"`` (standard deviation ``reset_noise_scale``); the
            noise of ``qpos`` is uniform for every env.
        forward_position: what Gymnasium finite-differences into ``x_velocity``: ``"qpos"``
            (``qpos[0]``), ``"main_body"`` (the ``main_body`` keyword's body's ``xpos``) or
            ``"mass_centre"`` (the centre of mass of the bodies' ``xipos``).
        velocity_keys: the velocities Gymnasium's ``info`` reports, the coordinates of the forward
            position in order: ``("x_velocity",)``, or ``("x_velocity", "y_velocity")`` where it
            finite-differences ``qpos[0:2]`` (Swimmer) or a position's ``[:2]`` (Ant, Humanoid).
        observation_extras: ``config -> parts`` of the observation after ``qpos`` and ``qvel``
            (e.g. the contact forces), as the keywords in ``config`` select them.
        contact_cost: ``(config, start) -> term``, the ``"contact"`` term on the contact forces
            that start at ``start`` in the task state; None: the env has none.
        health: ``(config, facts, start) -> term``, the ``"survive"`` term (a failure when unhealthy
            and ``terminate_when_unhealthy``) on the ``qpos`` (and ``qvel``) that start at
            ``start`` in the task state; None: the env is always healthy and pays no survival reward.
        safety_velocity: Safety-Gymnasium's velocity constraint of the env (:class:`SafetyVelocityRecord`).

    Example:
        >>> from torchtasks.envs.gymnasium_v5 import locomotion_record
        >>> record = locomotion_record("Hopper-v5")
        >>> record.state_keys, record.velocity_clip, record.term_names
        (('x_velocity', 'qpos', 'qvel'), 10.0, ('forward', 'ctrl', 'survive'))
        >>> locomotion_record("Humanoid-v5").safety_state_keys
        ('x_velocity', 'y_velocity', 'qpos', 'cfrc_ext')
    """

    env_id: str
    state_keys: tuple[str, ...]
    skipped_positions: int
    velocity_clip: float | None = None
    velocity_noise: Literal["uniform", "normal"] = "uniform"
    forward_position: Literal["qpos", "main_body", "mass_centre"] = "qpos"
    observation_extras: Callable[[Mapping[str, Any]], tuple[ObservationPart, ...]] = _no_extras
    contact_cost: Callable[[Mapping[str, Any], int], RewardFunction] | None = None
    health: Callable[[Mapping[str, Any], ModelFacts, int], RewardFunction] | None = None
    velocity_keys: tuple[str, ...] = ("x_velocity",)
    safety_velocity: SafetyVelocityRecord | None = None

    @property
    def safety_state_keys(self) -> tuple[str, ...]:
        """The state of the safety velocity task: :attr:`state_keys` with the bounded velocities after ``x_velocity``.

        The velocities the constraint reads that the reward's state lacks (``y_velocity`` of Ant and
        Humanoid) come right after ``x_velocity``, so the reward terms read the same entries by name.
        """
        if self.safety_velocity is None:
            raise ValueError(f"{self.env_id} has no Safety-Gymnasium velocity constraint")
        added = tuple(key for key in self.safety_velocity.velocity_keys if key not in self.state_keys)
        position = self.state_keys.index("x_velocity") + 1
        return (*self.state_keys[:position], *added, *self.state_keys[position:])

    @property
    def term_names(self) -> tuple[str, ...]:
        """The reward terms, named like Gymnasium's ``info["reward_<name>"]``, in the task's order."""
        return (
            "forward",
            "ctrl",
            *(("contact",) if self.contact_cost is not None else ()),
            *(("survive",) if self.health is not None else ()),
        )

    def state_layout(self, facts: ModelFacts, keys: tuple[str, ...] | None = None) -> dict[str, int]:
        """The task's state for this model: ``{key: size}`` in concatenation order.

        ``keys``: the entries (default :attr:`state_keys`; e.g. :attr:`safety_state_keys`), among
        ``x_velocity``, the other :attr:`velocity_keys`, ``qpos``, ``qvel`` and ``cfrc_ext``.
        """
        sizes = {"qpos": facts.nq, "qvel": facts.nv, "cfrc_ext": facts.n_contact_forces}
        sizes.update(dict.fromkeys(self.velocity_keys, 1))
        keys = self.state_keys if keys is None else tuple(keys)
        unknown = [key for key in keys if key not in sizes]
        if unknown:
            raise ValueError(f"{self.env_id}: state entries must be among {sorted(sizes)}, got {unknown}")
        return {key: sizes[key] for key in keys}

    def observation_parts(self, config: Mapping[str, Any]) -> tuple[ObservationPart, ...]:
        """Gymnasium's observation for the keywords ``config`` (of :func:`gymnasium_config`): its parts in order."""
        skip = self.skipped_positions if config["exclude_current_positions_from_observation"] else 0
        clip = None if self.velocity_clip is None else (-self.velocity_clip, self.velocity_clip)
        return (ObservationPart("qpos", skip, None), ObservationPart("qvel", 0, clip), *self.observation_extras(config))


@dataclass(frozen=True, eq=False)
class ModelFacts:
    """What a made Gymnasium env says about its MuJoCo model (for the keywords it was made with).

    Read once with :meth:`of` (or :meth:`make`) and handed on, so that building a task and a batched
    env for the same keywords makes one Gymnasium env.

    Example:
        >>> from torchtasks.envs.gymnasium_v5 import ModelFacts
        >>> facts = ModelFacts.make("Hopper-v5", {"frame_skip": 2})
        >>> facts.nq, facts.nv, facts.frame_skip, facts.dt, facts.observation_size
        (6, 6, 2, 0.004, 11)
    """

    model: mujoco.MjModel
    dt: float
    frame_skip: int
    init_qpos: np.ndarray
    init_qvel: np.ndarray
    observation_size: int
    action_low: np.ndarray
    action_high: np.ndarray

    @property
    def nq(self) -> int:
        """Size of ``qpos``."""
        return int(self.model.nq)

    @property
    def nv(self) -> int:
        """Size of ``qvel``."""
        return int(self.model.nv)

    @property
    def n_contact_forces(self) -> int:
        """Size of the flattened ``cfrc_ext`` (6 per body)."""
        return 6 * int(self.model.nbody)

    @classmethod
    def of(cls, gym_env: Any) -> ModelFacts:
        """Read the facts of a made (possibly wrapped) Gymnasium MuJoCo env."""
        unwrapped = gym_env.unwrapped
        return cls(
            model=unwrapped.model,
            dt=float(unwrapped.dt),
            frame_skip=int(unwrapped.frame_skip),
            init_qpos=unwrapped.init_qpos.copy(),
            init_qvel=unwrapped.init_qvel.copy(),
            observation_size=int(gym_env.observation_space.shape[0]),
            action_low=np.asarray(gym_env.action_space.low, dtype=np.float64),
            action_high=np.asarray(gym_env.action_space.high, dtype=np.float64),
        )

    @classmethod
    def make(cls, env_id: str, gym_kwargs: Mapping[str, Any]) -> ModelFacts:
        """Make ``gymnasium.make(env_id, **gym_kwargs)`` once, read its facts and close it."""
        gym_env = make_v5_env(env_id, **gym_kwargs)
        try:
            return cls.of(gym_env)
        finally:
            gym_env.close()


# ---------------------------------------------------------------------------- the rules per env
def _ant_observation_extras(config: Mapping[str, Any]) -> tuple[ObservationPart, ...]:
    # the contact forces of all bodies but the world, clipped to contact_force_range (Gymnasium tests truthiness)
    if config["include_cfrc_ext_in_observation"]:
        return (ObservationPart("cfrc_ext", 1, tuple(config["contact_force_range"])),)
    return ()


def _humanoid_observation_extras(config: Mapping[str, Any]) -> tuple[ObservationPart, ...]:
    parts = []
    for flag, source, start in (
        ("include_cinert_in_observation", "cinert", 1),
        ("include_cvel_in_observation", "cvel", 1),
        ("include_qfrc_actuator_in_observation", "qfrc_actuator", 6),  # without the free joint's 6 dofs
        ("include_cfrc_ext_in_observation", "cfrc_ext", 1),
    ):
        if config[flag] is True:  # Gymnasium tests `is True`
            parts.append(ObservationPart(source, start, None))
    return tuple(parts)


def _ant_contact_cost(config: Mapping[str, Any], start: int) -> RewardFunction:
    # the forces are clipped to contact_force_range before they are squared
    return ContactCostReward(config["contact_cost_weight"], start=start, force_range=config["contact_force_range"])


def _humanoid_contact_cost(config: Mapping[str, Any], start: int) -> RewardFunction:
    # the cost itself is clipped to contact_cost_range
    return ContactCostReward(config["contact_cost_weight"], start=start, cost_range=config["contact_cost_range"])


def _hopper_health(config: Mapping[str, Any], facts: ModelFacts, start: int) -> RewardFunction:
    # z_low < qpos[1] < z_high, angle_low < qpos[2] < angle_high and
    # state_low < (qpos ⊕ qvel)[2:] < state_high, strict, on the unclipped velocities
    nq, nv = facts.nq, facts.nv
    state_low, state_high = config["healthy_state_range"]
    low = [config["healthy_z_range"][0]] + [state_low] * (nq + nv - 2)
    high = [config["healthy_z_range"][1]] + [state_high] * (nq + nv - 2)
    angle_low, angle_high = config["healthy_angle_range"]
    low[1], high[1] = max(state_low, angle_low), min(state_high, angle_high)
    if low[1] > high[1]:  # empty intersection: never healthy (strict bounds with low == high)
        high[1] = low[1]
    return HealthyReward(
        config["healthy_reward"],
        index=list(range(start + 1, start + nq + nv)),  # (qpos ⊕ qvel)[1:]
        low=low,
        high=high,
        terminate_when_unhealthy=bool(config["terminate_when_unhealthy"]),
    )


def _walker2d_health(config: Mapping[str, Any], facts: ModelFacts, start: int) -> RewardFunction:
    # z_low < qpos[1] < z_high and angle_low < qpos[2] < angle_high
    (z_low, z_high), (angle_low, angle_high) = config["healthy_z_range"], config["healthy_angle_range"]
    return HealthyReward(
        config["healthy_reward"],
        index=[start + 1, start + 2],
        low=[z_low, angle_low],
        high=[z_high, angle_high],
        terminate_when_unhealthy=bool(config["terminate_when_unhealthy"]),
    )


def _ant_health(config: Mapping[str, Any], facts: ModelFacts, start: int) -> RewardFunction:
    # np.isfinite(qpos ⊕ qvel).all() and z_low <= qpos[2] <= z_high (inclusive)
    size = facts.nq + facts.nv
    low = [-math.inf] * size
    high = [math.inf] * size
    low[2], high[2] = config["healthy_z_range"]
    return HealthyReward(
        config["healthy_reward"],
        index=list(range(start, start + size)),
        low=low,
        high=high,
        inclusive=True,
        check_finite=True,
        terminate_when_unhealthy=bool(config["terminate_when_unhealthy"]),
    )


def _humanoid_health(config: Mapping[str, Any], facts: ModelFacts, start: int) -> RewardFunction:
    z_low, z_high = config["healthy_z_range"]  # z_low < qpos[2] < z_high
    return HealthyReward(
        config["healthy_reward"],
        index=[start + 2],
        low=z_low,
        high=z_high,
        terminate_when_unhealthy=bool(config["terminate_when_unhealthy"]),
    )


#: the supported envs: ``{env_id: record}``, one table (read-only)
LOCOMOTION_ENVS: Mapping[str, LocomotionEnvRecord] = types.MappingProxyType(
    {
        record.env_id: record
        for record in (
            LocomotionEnvRecord(
                "HalfCheetah-v5",
                state_keys=("x_velocity",),
                skipped_positions=1,
                velocity_noise="normal",
                safety_velocity=SafetyVelocityRecord(
                    "SafetyHalfCheetahVelocity-v1",
                    threshold=3.2096,
                    velocity_keys=("x_velocity",),
                    source=f"{SAFETY_VELOCITY_SOURCE}/safety_half_cheetah_velocity_v1.py",
                ),
            ),
            LocomotionEnvRecord(
                "Hopper-v5",
                state_keys=("x_velocity", "qpos", "qvel"),  # the health rule reads the unclipped qvel
                skipped_positions=1,
                velocity_clip=10.0,
                health=_hopper_health,
                safety_velocity=SafetyVelocityRecord(
                    "SafetyHopperVelocity-v1",
                    threshold=0.7402,
                    velocity_keys=("x_velocity",),
                    source=f"{SAFETY_VELOCITY_SOURCE}/safety_hopper_velocity_v1.py",
                ),
            ),
            LocomotionEnvRecord(
                "Walker2d-v5",
                state_keys=("x_velocity", "qpos"),
                skipped_positions=1,
                velocity_clip=10.0,
                health=_walker2d_health,
                safety_velocity=SafetyVelocityRecord(
                    "SafetyWalker2dVelocity-v1",
                    threshold=2.3415,
                    velocity_keys=("x_velocity",),
                    source=f"{SAFETY_VELOCITY_SOURCE}/safety_walker2d_velocity_v1.py",
                ),
            ),
            LocomotionEnvRecord(
                "Swimmer-v5",
                state_keys=("x_velocity",),
                skipped_positions=2,
                velocity_keys=("x_velocity", "y_velocity"),  # qpos[0:2]
                # v1's own step compares x_velocity only (v0: the planar speed)
                safety_velocity=SafetyVelocityRecord(
                    "SafetySwimmerVelocity-v1",
                    threshold=0.2282,
                    velocity_keys=("x_velocity",),
                    source=f"{SAFETY_VELOCITY_SOURCE}/safety_swimmer_velocity_v1.py",
                ),
            ),
            LocomotionEnvRecord(
                "Ant-v5",
                state_keys=("x_velocity", "qpos", "qvel", "cfrc_ext"),
                skipped_positions=2,
                velocity_noise="normal",
                forward_position="main_body",
                observation_extras=_ant_observation_extras,
                contact_cost=_ant_contact_cost,
                health=_ant_health,
                velocity_keys=("x_velocity", "y_velocity"),
                safety_velocity=SafetyVelocityRecord(
                    "SafetyAntVelocity-v1",
                    threshold=2.6222,
                    velocity_keys=("x_velocity", "y_velocity"),
                    source=f"{SAFETY_VELOCITY_SOURCE}/safety_ant_velocity_v1.py",
                ),
            ),
            LocomotionEnvRecord(
                "Humanoid-v5",
                state_keys=("x_velocity", "qpos", "cfrc_ext"),
                skipped_positions=2,
                forward_position="mass_centre",
                observation_extras=_humanoid_observation_extras,
                contact_cost=_humanoid_contact_cost,
                health=_humanoid_health,
                velocity_keys=("x_velocity", "y_velocity"),
                safety_velocity=SafetyVelocityRecord(
                    "SafetyHumanoidVelocity-v1",
                    threshold=1.4149,
                    velocity_keys=("x_velocity", "y_velocity"),
                    source=f"{SAFETY_VELOCITY_SOURCE}/safety_humanoid_velocity_v1.py",
                ),
            ),
        )
    }
)


# ------------------------------------------------------------------------------- look-ups
def locomotion_record(env_id: object) -> LocomotionEnvRecord:
    """Return the record of ``env_id``; raise ``TypeError``/``ValueError`` naming the supported ids otherwise.

    Example:
        >>> from torchtasks.envs.gymnasium_v5 import locomotion_record
        >>> locomotion_record("Ant-v5").forward_position
        'main_body'
    """
    if not isinstance(env_id, str):
        raise TypeError(f"env_id must be a string, got {type(env_id).__name__}")
    record = LOCOMOTION_ENVS.get(env_id)
    if record is None:
        raise ValueError(f"env_id must be one of {list(LOCOMOTION_ENVS)}, got {env_id!r}")
    return record


@functools.cache
def _gymnasium_defaults(env_id: str) -> dict[str, Any]:
    """Return ``{keyword: default}`` of the env's constructor (and of MujocoEnv's forwarded ones)."""
    creator = load_env_creator(gymnasium.spec(env_id).entry_point)
    defaults: dict[str, Any] = {}
    keyword_kinds = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    for name, parameter in inspect.signature(creator).parameters.items():
        if parameter.kind in keyword_kinds:
            defaults[name] = parameter.default
    base = inspect.signature(MujocoEnv.__init__).parameters
    for name in _MUJOCO_ENV_KWARGS:
        defaults.setdefault(name, base[name].default)
    return defaults


def gymnasium_config(env_id: str, gym_kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """Validate an env's Gymnasium keyword arguments and return them merged over Gymnasium's defaults.

    The defaults are read from the env class's signature (and MujocoEnv's forwarded keywords).
    Unknown keywords raise ``TypeError``; weights must be finite real numbers (cost weights and
    ``reset_noise_scale`` non-negative), ranges ``(low, high)`` pairs with ``low <= high``,
    ``terminate_when_unhealthy`` a bool and ``frame_skip`` a positive int.

    Example:
        >>> from torchtasks.envs.gymnasium_v5 import gymnasium_config
        >>> config = gymnasium_config("Hopper-v5", {"healthy_reward": 2})
        >>> config["healthy_reward"], config["frame_skip"], config["healthy_z_range"]
        (2.0, 4, (0.7, inf))
    """
    locomotion_record(env_id)
    defaults = _gymnasium_defaults(env_id)
    unknown = sorted(set(gym_kwargs) - set(defaults))
    if unknown:
        hint = "; for float32 observations pass observation_dtype=torch.float32" if "dtype" in unknown else ""
        raise TypeError(
            f"{env_id} got unexpected keyword argument(s) {unknown}; its keyword arguments are {sorted(defaults)}"
            + hint
        )
    config = {**defaults, **gym_kwargs}
    checks: dict[str, Callable[[object, str], object]] = {
        "forward_reward_weight": check_finite_scalar,
        "healthy_reward": check_finite_scalar,
        "ctrl_cost_weight": check_weight,
        "contact_cost_weight": check_weight,
        "healthy_z_range": check_pair,
        "healthy_angle_range": check_pair,
        "healthy_state_range": check_pair,
        "contact_force_range": check_pair,
        "contact_cost_range": check_pair,
        # Gymnasium's resets draw uniform(-scale, scale): checked here, not at the first reset by numpy
        "reset_noise_scale": check_weight,
    }
    for name, check in checks.items():
        if name in config:
            config[name] = check(config[name], name)
    if "terminate_when_unhealthy" in config and not isinstance(config["terminate_when_unhealthy"], (bool, np.bool_)):
        raise TypeError(f"terminate_when_unhealthy must be a bool, got {config['terminate_when_unhealthy']!r}")
    check_positive_int(config["frame_skip"], "frame_skip")
    return config


def _forward_position(record: LocomotionEnvRecord, config: Mapping[str, Any], facts: ModelFacts) -> list[Reading]:
    """The readings Gymnasium finite-differences into each of the record's velocities, one per coordinate."""
    coordinates = range(len(record.velocity_keys))
    if record.forward_position == "main_body":
        body = facts.model.body(config["main_body"]).name
        return [body_pos(body, index=(i,)) for i in coordinates]
    if record.forward_position == "mass_centre":
        return [mass_centre(index=(i,)) for i in coordinates]
    return [data_field("qpos", i, i + 1) for i in coordinates]


def gymnasium_declaration(
    record: LocomotionEnvRecord, config: Mapping[str, Any], facts: ModelFacts, keys: tuple[str, ...]
) -> MujocoDeclaration:
    """The Gymnasium v5 env of ``record`` and ``config`` as a declaration of the batched MuJoCo env.

    Its observation is Gymnasium's (``qpos`` without the skipped positions, ``qvel`` clipped where Gymnasium clips
    it, the extras the keywords select), its task state the entries ``keys`` (velocities finite-differenced from
    the record's forward position, ``qpos``, ``qvel``, ``cfrc_ext``), its resets Gymnasium's (``init_qpos`` plus
    uniform noise on every ``qpos`` coordinate, then ``qvel`` noise), the readings taken as ``mj_step`` leaves
    ``MjData`` and the contact forces an ``mj_rnePostConstraint`` after the step.

    Example:
        >>> from torchtasks.envs.gymnasium_v5 import ModelFacts, gymnasium_config, gymnasium_declaration
        >>> from torchtasks.envs.gymnasium_v5 import locomotion_record
        >>> record = locomotion_record("Hopper-v5")
        >>> config = gymnasium_config("Hopper-v5", {})
        >>> declaration = gymnasium_declaration(record, config, ModelFacts.make("Hopper-v5", {}), record.state_keys)
        >>> declaration.frame_skip, list(declaration.state), declaration.stage
        (4, ['x_velocity', 'qpos', 'qvel'], 'step')
    """
    model = facts.model
    if not (np.array_equal(facts.init_qpos, model.qpos0) and not facts.init_qvel.any()):
        raise RuntimeError(f"{record.env_id}: Gymnasium's initial state is not qpos0 and zero velocities")
    observation = tuple(
        data_field(part.source, part.start, clip=part.clip) for part in record.observation_parts(config)
    )
    positions = _forward_position(record, config, facts)
    state: dict[str, tuple[Reading, ...]] = {}
    for key in keys:
        if key in record.velocity_keys:
            state[key] = (finite_difference(positions[record.velocity_keys.index(key)]),)
        else:
            state[key] = (data_field(key),)
    scale = float(config["reset_noise_scale"])
    resets = ResolvedResets(
        keyframe=-1,
        noise=(
            ("qpos", np.arange(model.nq), Noise("uniform", scale)),
            ("qvel", np.arange(model.nv), Noise(record.velocity_noise, scale)),
        ),
        free_joint=None,
    )
    return MujocoDeclaration(
        name=record.env_id,
        model=model,
        frame_skip=facts.frame_skip,
        observation_readings={"observation": observation},
        state_readings=state,
        action_scale=np.ones(model.nu),
        action_offset=np.zeros(model.nu),
        action_low=facts.action_low,
        action_high=facts.action_high,
        resets=resets,
        stage="step",
        contact_forces="after_step",
    )
