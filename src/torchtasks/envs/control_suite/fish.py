"""dm_control's fish: keep a swimming fish upright, or swim its mouth to a target."""

from __future__ import annotations

import functools

import mujoco

from torchtasks.envs import readings
from torchtasks.envs.control_suite.record import ControlSuiteTask, Entries, StateColumns, tolerance, upright, xmat
from torchtasks.envs.mujoco_declaration import Resets
from torchtasks.envs.reset_steps import Box, DrawDomain, RandomOrientation, UniformJoints
from torchtasks.rewards import CompoundReward, RewardFunction

#: the joints dm_control observes, in its order
JOINTS = ("tail1", "tail_twist", "tail2", "finright_roll", "finright_pitch", "finleft_roll", "finleft_pitch")


def _target(model: mujoco.MjModel) -> readings.Reading:
    # the target relative to the mouth, in the mouth geom's frame
    return readings.difference(readings.geom_pos("target"), readings.geom_pos("mouth"), frame="geom:mouth")


def _observation(model: mujoco.MjModel, *, swim: bool) -> Entries:
    entries: Entries = {"joint_angles": [readings.joint_pos(*JOINTS)], "upright": [xmat(model, ("torso", "zz"))]}
    if swim:
        entries["target"] = [_target(model)]
    entries["velocity"] = [readings.joint_vel()]
    return entries


def _state(model: mujoco.MjModel, *, swim: bool) -> Entries:
    entries: Entries = {"torso_zz": [xmat(model, ("torso", "zz"))]}
    if swim:
        entries["mouth_to_target"] = [readings.norm(_target(model))]
    return entries


def _reward(model: mujoco.MjModel, columns: StateColumns, *, swim: bool) -> RewardFunction:
    if not swim:
        return tolerance(columns, "torso_zz", bounds=(1.0, 1.0), margin=1.0)
    radius = float(model.geom("mouth").size[0] + model.geom("target").size[0])
    in_mouth = tolerance(columns, "mouth_to_target", bounds=(0.0, radius), margin=2 * radius)
    # (7 * in_mouth + 0.5 * (upright + 1)) / 8
    return CompoundReward(
        {"in_mouth": in_mouth, "upright": upright(columns, "torso_zz")}, weights={"in_mouth": 7 / 8, "upright": 1 / 8}
    )


def _resets(model: mujoco.MjModel, *, swim: bool) -> Resets:
    steps: list = [RandomOrientation("root", "uniform"), UniformJoints({joint: (-0.2, 0.2) for joint in JOINTS})]
    if swim:
        steps.append(DrawDomain("geom_pos:target", Box((-0.4, -0.4, 0.1), (0.4, 0.4, 0.3))))
    return Resets(steps=tuple(steps))


TASKS = {
    task: ControlSuiteTask(
        "fish",
        task,
        40.0,
        0.04,
        functools.partial(_observation, swim=swim),
        functools.partial(_state, swim=swim),
        functools.partial(_reward, swim=swim),
        functools.partial(_resets, swim=swim),
    )
    for task, swim in (("upright", False), ("swim", True))
}
