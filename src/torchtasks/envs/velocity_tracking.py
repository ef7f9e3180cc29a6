"""The velocity-tracking ("joystick") env of the shipped quadruped: :func:`velocity_tracking_env`.

A declaration of :class:`~torchtasks.envs.BatchedMujocoEnv` on ``models/quadruped.xml`` with IsaacLab's
observation (each term its own entry, concatenated last into ``"observation"``), the task state of
:func:`~torchtasks.tasks.velocity_tracking_state` and the task of :func:`~torchtasks.tasks.velocity_tracking_task`,
judged against a :class:`~torchtasks.transforms.GoalCommand` of ``(v_x, v_y, ω_z)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from torchrl.envs import CatTensors, Compose, RewardSum, StepCounter, Transform, TransformedEnv

from torchtasks._checks import (
    as_constant,
    check_int,
    check_non_negative_int,
    check_pair,
    check_positive_int,
    check_weight,
)
from torchtasks.domain import UniformDomainParam
from torchtasks.envs import readings
from torchtasks.envs.batched_mujoco import BatchedMujocoEnv, ZeroBrokenStepReward
from torchtasks.envs.models import model_path
from torchtasks.envs.mujoco_declaration import Actions, FreeJointRanges, Noise, Resets
from torchtasks.spaces import Box
from torchtasks.tasks.velocity_tracking import velocity_tracking_state, velocity_tracking_task
from torchtasks.transforms import (
    Curriculum,
    DomainRandomization,
    EntryNoise,
    GoalCommand,
    ObservationNoise,
    Pushes,
    TaskTransform,
    linear,
)

__all__ = ["COMMAND_KEY", "POLICY_KEYS", "SENSOR_NOISE", "velocity_tracking_env", "velocity_tracking_perturbations"]

LEGS = ("FL", "FR", "RL", "RR")
#: the twelve leg joints, in the order of the actuators
LEG_JOINTS = tuple(f"{leg}_{part}_joint" for leg in LEGS for part in ("hip", "thigh", "calf"))
#: where the command the policy sees (and the task judges) is written: ``(v_x, v_y, ω_z)``
COMMAND_KEY = "command"
#: the entries the policy sees, concatenated in this order into ``"observation"`` (IsaacLab's policy terms)
POLICY_KEYS = ("lin_vel", "ang_vel", "gravity", COMMAND_KEY, "joint_pos", "joint_vel", "last_action")
#: the widest command range: ``v_x`` and ``v_y`` [m/s], ``ω_z`` [rad/s]
COMMAND_LOW = (-1.0, -0.5, -1.0)
COMMAND_HIGH = (1.0, 0.5, 1.0)
#: a Curriculum of command ranges starts from this fraction of the range
CURRICULUM_START = 0.3
CONTROL_STEP = 0.02  # s: 4 substeps of 5 ms
_SQRT3 = math.sqrt(3.0)
#: the sensed policy entries' noise: IsaacLab's uniform noise of the velocity task (half-widths 0.1 m/s, 0.2 rad/s,
#: 0.05, 0.01 rad, 1.5 rad/s; as stds: half-width / √3) and per-episode biases of our own (an IMU mounted slightly
#: tilted, encoder offsets), as ``(std, bias std)`` (``None``: no bias)
SENSOR_NOISE = {
    "lin_vel": (0.1 / _SQRT3, None),
    "ang_vel": (0.2 / _SQRT3, None),
    "gravity": (0.05 / _SQRT3, 0.02),
    "joint_pos": (0.01 / _SQRT3, 0.02),
    "joint_vel": (1.5 / _SQRT3, None),
}


def velocity_tracking_env(
    num_envs: int,
    *,
    seed: int,
    max_steps: int = 1000,
    action_scale: float = 0.5,
    command_low: Sequence[float] = COMMAND_LOW,
    command_high: Sequence[float] = COMMAND_HIGH,
    resample_steps: tuple[int, int] = (150, 500),
    standing_probability: float = 0.1,
    curriculum_frames: int = 0,
    num_threads: int | None = None,
    max_action_delay: int = 0,
    perturbations: Sequence[Transform] = (),
) -> TransformedEnv:
    """``num_envs`` shipped quadrupeds tracking a per-env velocity command, with IsaacLab's rewards and terminations.

    The base env: :class:`~torchtasks.envs.BatchedMujocoEnv` of ``model_path("quadruped")`` at 50 Hz (4 substeps of
    5 ms), actions joint targets ``home + action_scale * action`` (IsaacLab's ``JointPositionAction`` with
    ``use_default_offset``), resets from the keyframe ``"home"`` with each leg joint ±0.1 rad, a yaw in ±π and
    velocities of ±0.1. It observes the policy entries :data:`POLICY_KEYS` (the base's linear and angular velocity
    in its own frame, the projected gravity, the joint positions relative to home, the joint velocities, the last
    action) and the task state of :func:`~torchtasks.tasks.velocity_tracking_state` (true values, apart from the
    policy's, so that observation noise never reaches the reward).

    The transforms, in order: ``StepCounter(max_steps)``; ``TaskTransform(velocity_tracking_task(...),
    goal_key="command")`` (the reward terms under ``("next", "task_reward", <term>)``, the end conditions under
    ``("next", "ended_by", <name>)``); :class:`~torchtasks.envs.ZeroBrokenStepReward`; ``RewardSum``; with
    ``curriculum_frames``, a :class:`~torchtasks.transforms.Curriculum` widening the command range linearly from
    :data:`CURRICULUM_START` of it to all of it over that many frames; the
    :class:`~torchtasks.transforms.GoalCommand` of ``(v_x, v_y, ω_z)`` (resampled every ``resample_steps`` steps,
    zero with ``standing_probability``); then ``perturbations`` (e.g. observation noise on the policy entries,
    pushes, domain randomization: they see the policy entries before they are concatenated); last, ``CatTensors``
    of :data:`POLICY_KEYS` into ``"observation"`` (the entries are kept).

    Args:
        num_envs: envs of the batch.
        seed: the env's seed (initial states; the command's generator is seeded with it too).
        max_steps: the episode length (1000: 20 s).
        action_scale: the joint targets' scale around home [rad per unit action].
        command_low, command_high: the command range (3 numbers each, containing 0).
        resample_steps: the command is drawn again after a number of steps in this inclusive range.
        standing_probability: the probability of a zero command at every draw.
        curriculum_frames: frames over which the command range widens (0: no curriculum, the full range).
        num_threads: threads stepping MuJoCo (``None``: the env's default).
        max_action_delay: the largest per-env action delay in steps, the base env's (its domain field
            ``"action_delay"``, drawn by a :class:`~torchtasks.transforms.DomainRandomization` among the
            ``perturbations``); 0: none.
        perturbations: transforms placed after the command and before the concatenation (e.g. an
            :class:`~torchtasks.transforms.ObservationNoise` of the policy entries).

    Example:
        >>> from torchtasks.envs import velocity_tracking_env
        >>> env = velocity_tracking_env(2, seed=0)
        >>> data = env.rollout(3)
        >>> data["observation"].shape, data["command"].shape
        (torch.Size([2, 3, 48]), torch.Size([2, 3, 3]))
        >>> sorted(data["next", "task_reward"].keys())[:3]
        ['action_rate', 'ang_vel_xy', 'episode_action_rate']
        >>> env.close()
    """
    num_envs = check_positive_int(num_envs, "num_envs")
    max_steps = check_positive_int(max_steps, "max_steps")
    curriculum_frames = check_non_negative_int(curriculum_frames, "curriculum_frames")
    action_scale = check_weight(action_scale, "action_scale")
    if action_scale == 0:
        raise ValueError("action_scale must be positive, got 0.0")
    low = as_constant(command_low, "command_low", ndim=(1,))
    high = as_constant(command_high, "command_high", ndim=(1,))
    if low.shape != (3,) or high.shape != (3,):
        raise ValueError(
            f"command_low and command_high must have 3 entries (v_x, v_y, ω_z), got {low.tolist()} and {high.tolist()}"
        )
    if isinstance(perturbations, (str, bytes)) or not isinstance(perturbations, Sequence):
        raise TypeError(
            "perturbations must be a sequence of torchrl Transforms (e.g. velocity_tracking_perturbations(seed=0)), "
            f"got {type(perturbations).__name__}"
        )
    perturbations = list(perturbations)
    for i, transform in enumerate(perturbations):
        if not isinstance(transform, Transform):
            raise TypeError(f"perturbations[{i}] must be a torchrl Transform, got {type(transform).__name__}")
    layout = velocity_tracking_state(num_joints=len(LEG_JOINTS), num_feet=len(LEGS), num_undesired=len(LEGS))
    # contacts alone (applied=False): a Pushes force on the torso is neither a base contact nor a thigh contact
    thigh_force = [
        readings.norm(readings.contact_force(f"{leg}_thigh", index=(3, 4, 5), applied=False)) for leg in LEGS
    ]
    base = BatchedMujocoEnv(
        model_path("quadruped"),
        num_envs,
        observation={
            "lin_vel": readings.body_lin_vel("torso", frame="local"),
            "ang_vel": readings.body_ang_vel("torso", frame="local"),
            "gravity": readings.projected_gravity("torso"),
            "joint_pos": readings.joint_pos(*LEG_JOINTS, relative_to="home"),
            "joint_vel": readings.joint_vel(*LEG_JOINTS),
            "last_action": readings.last_action(),
        },
        state={
            "base_lin_vel": readings.body_lin_vel("torso", frame="local"),
            "base_ang_vel": readings.body_ang_vel("torso", frame="local"),
            "projected_gravity": readings.projected_gravity("torso"),
            "joint_torques": readings.actuator_force(),
            "foot_contact": [readings.sensor(f"{leg}_touch") for leg in LEGS],
            "undesired_contact": thigh_force,
            "base_contact": readings.norm(readings.contact_force("torso", index=(3, 4, 5), applied=False)),
        },
        actions=Actions(scale=action_scale, offset="home"),
        resets=Resets(
            keyframe="home",
            joint_noise={joint: Noise("uniform", 0.1) for joint in LEG_JOINTS},
            free_joint=FreeJointRanges(
                yaw=(-math.pi, math.pi),
                linear_velocity=((-0.1, 0.1),) * 3,
                angular_velocity=((-0.1, 0.1),) * 3,
            ),
        ),
        frame_skip=4,
        seed=seed,
        num_threads=num_threads,
        max_action_delay=max_action_delay,
    )
    bounds = base.action_spec.space
    task = velocity_tracking_task(
        Box(bounds.low[0], bounds.high[0]),
        num_joints=len(LEG_JOINTS),
        num_feet=len(LEGS),
        num_undesired=len(LEGS),
        dt=CONTROL_STEP,
    )
    command = GoalCommand(
        Box(low, high, labels=["lin_vel_x", "lin_vel_y", "ang_vel_z"]),
        goal_key=COMMAND_KEY,
        resample_steps=tuple(resample_steps),
        zero_goal_probability=standing_probability,
        seed=seed,
    )
    transforms: list[Transform] = [
        StepCounter(max_steps),
        TaskTransform(task, state_key=list(layout), goal_key=COMMAND_KEY),
        ZeroBrokenStepReward(),
        RewardSum(),
    ]
    if curriculum_frames:
        start_low, start_high = (CURRICULUM_START * low).tolist(), (CURRICULUM_START * high).tolist()
        transforms.append(
            Curriculum(
                {
                    "command.low": linear(start_low, low.tolist(), 0, curriculum_frames),
                    "command.high": linear(start_high, high.tolist(), 0, curriculum_frames),
                }
            )
        )
    transforms += [command, *perturbations, CatTensors(list(POLICY_KEYS), "observation", del_keys=False, sort=False)]
    return TransformedEnv(base, Compose(*transforms))


def velocity_tracking_perturbations(
    *,
    seed: int,
    delay: bool = True,
    noise: bool = True,
    pushes: bool = True,
    gains: bool = True,
    physics: bool = True,
    max_action_delay: int = 1,
    push_velocity: float = 0.5,
    push_interval: tuple[float, float] = (5.0, 10.0),
    when: str = "reset",
) -> list[Transform]:
    """The sim-to-real perturbations of the velocity task as transforms for ``velocity_tracking_env(perturbations=)``.

    The peers' set (IsaacLab's velocity task, mjlab): ``noise``: :class:`~torchtasks.transforms.ObservationNoise` on
    the sensed policy entries (:data:`SENSOR_NOISE`: uniform per-step noise; a normal per-episode bias on two);
    ``pushes``: :class:`~torchtasks.transforms.Pushes` of the torso, a planar velocity change of up to
    ``push_velocity`` m/s every ``push_interval`` seconds per env; then one
    :class:`~torchtasks.transforms.DomainRandomization` drawing per env at each reset (``when="startup"``: once per
    env, at its first reset, as IsaacLab's startup events): ``delay``: the action delay
    (0 to ``max_action_delay`` steps; the env needs ``max_action_delay`` at least this large), ``gains``: the servos'
    stiffness ``actuator_kp_scale`` in [0.8, 1.2], ``physics``: ``body_mass_scale`` in [0.9, 1.1] and
    ``geom_friction_scale`` in [0.6, 1.2]. The owners of fields (noise, pushes) come before the randomization, as it
    requires. An empty list when everything is off.

    Args:
        seed: the seed of the transforms' generators (``env.set_seed`` re-seeds them per worker).
        delay, noise, pushes, gains, physics: which perturbations to include.
        max_action_delay: the largest delay drawn, in steps.
        push_velocity: the half-width of the pushes' planar velocity change [m/s].
        push_interval: the seconds between pushes, per env (low, high).
        when: when the randomization draws: ``"reset"`` (every episode) or ``"startup"`` (once per env).

    Example:
        >>> from torchtasks.envs import velocity_tracking_env, velocity_tracking_perturbations
        >>> perturbations = velocity_tracking_perturbations(seed=0)
        >>> env = velocity_tracking_env(2, seed=0, max_action_delay=1, perturbations=perturbations)
        >>> data = env.rollout(3)
        >>> sorted(data["next", "domain"].keys())
        ['action_delay', 'actuator_kp_scale', 'body_mass_scale', 'geom_friction_scale']
        >>> data["next", "push_velocity"].shape
        torch.Size([2, 3, 6])
        >>> env.close()
    """
    seed = check_int(seed, "velocity_tracking_perturbations: seed")
    push_interval = check_pair(push_interval, "velocity_tracking_perturbations: push_interval")
    transforms: list[Transform] = []
    if noise:
        entries = {
            key: EntryNoise(
                std=std, bias=bias, distribution="uniform", bias_distribution=None if bias is None else "normal"
            )
            for key, (std, bias) in SENSOR_NOISE.items()
        }
        transforms.append(ObservationNoise(entries, seed=seed))
    if pushes:
        push_velocity = check_weight(push_velocity, "push_velocity")
        velocity = [push_velocity, push_velocity, 0.0, 0.0, 0.0, 0.0]
        transforms.append(Pushes("torso", velocity=velocity, interval_seconds=push_interval, seed=seed + 1))
    params = []
    if delay:
        max_action_delay = check_positive_int(max_action_delay, "max_action_delay")
        half = max_action_delay / 2
        params.append(UniformDomainParam("action_delay", mean=half, halfspan=half, roundint=True))
    if gains:
        params.append(UniformDomainParam("actuator_kp_scale", mean=1.0, halfspan=0.2))
    if physics:
        params.append(UniformDomainParam("body_mass_scale", mean=1.0, halfspan=0.1))
        params.append(UniformDomainParam("geom_friction_scale", mean=0.9, halfspan=0.3))
    if when not in ("reset", "startup"):
        raise ValueError(f"velocity_tracking_perturbations: when must be 'reset' or 'startup', got {when!r}")
    if params:
        transforms.append(DomainRandomization(params, when=when, seed=seed + 2))
    return transforms
