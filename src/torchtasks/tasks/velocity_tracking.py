"""The velocity-tracking ("joystick") task of legged robots, in IsaacLab's terms: :func:`velocity_tracking_task`.

The task reads a task state of named entries (:func:`velocity_tracking_state`), knows nothing of the env that
writes them, and tracks a command ``(v_x, v_y, ω_z)`` in the base's frame (its goal, e.g. a
:class:`~torchtasks.transforms.GoalCommand`'s).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from torchtasks._checks import check_finite_scalar, check_positive_int
from torchtasks.rewards import (
    ActionRateReward,
    CompoundReward,
    ContactCountReward,
    ExpTrackingReward,
    FeetAirTimeReward,
    SquaredSumReward,
)
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks.command_tracking import CommandTrackingTask

__all__ = ["VELOCITY_TRACKING_WEIGHTS", "velocity_tracking_state", "velocity_tracking_task"]

#: the reward terms and their weights per second (IsaacLab's ``velocity_env_cfg.RewardsCfg``, with
#: ``flat_orientation_l2`` at -1 where the base config has 0 and IsaacLab's robot configs set it); the task
#: multiplies them by the control step ``dt``, as IsaacLab's reward manager does
VELOCITY_TRACKING_WEIGHTS: dict[str, float] = {
    "track_lin_vel_xy": 1.0,
    "track_ang_vel_z": 0.5,
    "lin_vel_z": -2.0,
    "ang_vel_xy": -0.05,
    "joint_torques": -1e-5,
    "action_rate": -0.01,
    "feet_air_time": 0.125,
    "undesired_contacts": -1.0,
    "flat_orientation": -1.0,
}

#: the tracked entries: the command is (v_x, v_y, ω_z) in the base's frame
TRACKED = ("lin_vel_x", "lin_vel_y", "ang_vel_z")


def velocity_tracking_state(num_joints: int, num_feet: int, num_undesired: int) -> dict[str, list[str]]:
    """The task state the velocity-tracking task reads: ``{entry name: labels of its elements}``, in order.

    - ``base_lin_vel`` (3): the base's linear velocity in its own frame (``lin_vel_x/y/z``);
    - ``base_ang_vel`` (3): its angular velocity in its own frame (``ang_vel_x/y/z``);
    - ``projected_gravity`` (3): the unit gravity vector in the base's frame (``gravity_x/y/z``; ``-1`` in z upright);
    - ``joint_torques`` (``num_joints``): the actuator forces;
    - ``foot_contact`` (``num_feet``): one contact force (or touch) per foot;
    - ``undesired_contact`` (``num_undesired``): one contact force magnitude per body that must not touch (thighs);
    - ``base_contact`` (1): the contact force magnitude on the base.

    Example:
        >>> layout = velocity_tracking_state(num_joints=2, num_feet=1, num_undesired=1)
        >>> {name: len(labels) for name, labels in layout.items()}
        {'base_lin_vel': 3, 'base_ang_vel': 3, 'projected_gravity': 3, 'joint_torques': 2, 'foot_contact': 1, \
'undesired_contact': 1, 'base_contact': 1}
    """
    num_joints = check_positive_int(num_joints, "num_joints")
    num_feet = check_positive_int(num_feet, "num_feet")
    num_undesired = check_positive_int(num_undesired, "num_undesired")
    return {
        "base_lin_vel": ["lin_vel_x", "lin_vel_y", "lin_vel_z"],
        "base_ang_vel": ["ang_vel_x", "ang_vel_y", "ang_vel_z"],
        "projected_gravity": ["gravity_x", "gravity_y", "gravity_z"],
        "joint_torques": [f"joint_torque_{i}" for i in range(num_joints)],
        "foot_contact": [f"foot_contact_{i}" for i in range(num_feet)],
        "undesired_contact": [f"undesired_contact_{i}" for i in range(num_undesired)],
        "base_contact": ["base_contact"],
    }


def velocity_tracking_task(
    action_space: Box,
    *,
    num_joints: int,
    num_feet: int,
    num_undesired: int,
    dt: float,
    weights: Mapping[str, float] | None = None,
    tracking_std: float = math.sqrt(0.25),
    air_time_threshold: float = 0.5,
    contact_threshold: float = 1.0,
    max_tilt: float = math.radians(70.0),
) -> CommandTrackingTask:
    """Track a planar velocity and yaw-rate command with IsaacLab's reward terms; fail on a base contact or a fall.

    A :class:`~torchtasks.tasks.CommandTrackingTask` on :func:`velocity_tracking_state` (its entries concatenated
    in that order; ``TaskTransform(task, state_key=list(velocity_tracking_state(...)))``) tracking
    ``(lin_vel_x, lin_vel_y, ang_vel_z)``. Its reward is a :class:`~torchtasks.rewards.CompoundReward` whose terms
    are logged one by one (weights: :data:`VELOCITY_TRACKING_WEIGHTS` times ``dt``, updated by ``weights``):

    - ``track_lin_vel_xy``: ``exp(-|v_xy* - v_xy|² / std²)``; ``track_ang_vel_z``: ``exp(-(ω_z* - ω_z)² / std²)``
      (:class:`~torchtasks.rewards.ExpTrackingReward`);
    - ``lin_vel_z`` (``v_z²``), ``ang_vel_xy`` (``ω_x² + ω_y²``), ``joint_torques`` (``Σ τ²``), ``flat_orientation``
      (``g_x² + g_y²``): :class:`~torchtasks.rewards.SquaredSumReward`;
    - ``action_rate``: ``Σ (a - a_prev)²`` (:class:`~torchtasks.rewards.ActionRateReward`);
    - ``feet_air_time``: ``Σ (t_air - threshold)`` over the feet landing, paid when ``|v_xy*| > 0.1``
      (:class:`~torchtasks.rewards.FeetAirTimeReward`);
    - ``undesired_contacts``: the number of undesired contacts above ``contact_threshold``
      (:class:`~torchtasks.rewards.ContactCountReward`).

    Terminations (named end conditions): ``base_contact`` (the base's contact force above ``contact_threshold``),
    ``bad_orientation`` (the base tilted beyond ``max_tilt``: ``gravity_z > -cos(max_tilt)``), and ``out_of_bounds``
    (a NaN state).

    Args:
        action_space: the env's action box (its size is the action rate's).
        num_joints, num_feet, num_undesired: the sizes of the task state's entries.
        dt: the control step [s] (the air time's clock and the weights' factor).
        weights: weights per second replacing the defaults' (names of :data:`VELOCITY_TRACKING_WEIGHTS`).
        tracking_std: the tracking kernels' width (IsaacLab: ``sqrt(0.25)``).
        air_time_threshold: the air time a step must exceed to pay (IsaacLab: 0.5 s).
        contact_threshold: the force [N] above which a contact counts (IsaacLab: 1 N).
        max_tilt: the base's tilt [rad] beyond which the episode fails (mjlab: 70°).

    Example:
        >>> import torch
        >>> from torchtasks.spaces import Box
        >>> actions = Box([-1.0] * 2, [1.0] * 2)
        >>> task = velocity_tracking_task(actions, num_joints=2, num_feet=1, num_undesired=1, dt=0.02)
        >>> task.term_names[:3], task.termination_names
        (('track_lin_vel_xy', 'track_ang_vel_z', 'lin_vel_z'), {'out_of_bounds': 'failure', \
'base_contact': 'failure', 'bad_orientation': 'failure'})
        >>> state = torch.zeros(1, task.state_size); state[0, 8] = -1.0  # standing still, upright
        >>> out = task.transition(state, torch.zeros(1, 2), state, task.reset(state), goal=torch.zeros(1, 3))
        >>> out.terms["track_lin_vel_xy"], out.failure
        (tensor([0.0200]), tensor([False]))
    """
    if not isinstance(action_space, Box):
        raise TypeError(f"action_space must be a torchtasks.spaces.Box, got {type(action_space).__name__}")
    dt = check_finite_scalar(dt, "dt")
    if dt <= 0:
        raise ValueError(f"dt must be positive, got {dt}")
    rates = dict(VELOCITY_TRACKING_WEIGHTS)
    if weights is not None:
        unknown = sorted(set(weights) - set(rates))
        if unknown:
            raise ValueError(f"weights names unknown terms {unknown}; the terms are {list(rates)}")
        rates.update({name: check_finite_scalar(value, f"weights[{name!r}]") for name, value in weights.items()})
    max_tilt = check_finite_scalar(max_tilt, "max_tilt")
    if not 0 < max_tilt <= math.pi:
        raise ValueError(f"max_tilt must lie in (0, pi] rad, got {max_tilt}")
    layout = velocity_tracking_state(num_joints, num_feet, num_undesired)
    labels = [label for entry in layout.values() for label in entry]
    state_space = Box.unbounded(len(labels), labels=labels)
    spec = EnvSpec(state_space, action_space)
    space = CommandTrackingTask(spec, TRACKED, SquaredSumReward([0])).reward_space  # [state, command, error] labels
    terms = {
        "track_lin_vel_xy": ExpTrackingReward(tracking_std, ["error_lin_vel_x", "error_lin_vel_y"], space=space),
        "track_ang_vel_z": ExpTrackingReward(tracking_std, ["error_ang_vel_z"], space=space),
        "lin_vel_z": SquaredSumReward(["lin_vel_z"], space=space),
        "ang_vel_xy": SquaredSumReward(["ang_vel_x", "ang_vel_y"], space=space),
        "joint_torques": SquaredSumReward(layout["joint_torques"], space=space),
        "action_rate": ActionRateReward(action_space.size),
        "feet_air_time": FeetAirTimeReward(
            dt,
            layout["foot_contact"],
            threshold=air_time_threshold,
            contact_threshold=contact_threshold,
            command_indices=["command_lin_vel_x", "command_lin_vel_y"],
            space=space,
        ),
        "undesired_contacts": ContactCountReward(contact_threshold, layout["undesired_contact"], space=space),
        "flat_orientation": SquaredSumReward(["gravity_x", "gravity_y"], space=space),
    }
    reward = CompoundReward(terms, weights={name: rate * dt for name, rate in rates.items()})
    terminations = {
        "base_contact": ("base_contact", -math.inf, contact_threshold),
        "bad_orientation": ("gravity_z", -math.inf, -math.cos(max_tilt)),
    }
    return CommandTrackingTask(spec, TRACKED, reward, terminations=terminations)
