"""dm_control's swimmer: swim a planar chain of n links so that its nose reaches a target (swimmer6, swimmer15)."""

from __future__ import annotations

import functools

import mujoco

from torchtasks.envs import readings
from torchtasks.envs.control_suite.record import ControlSuiteTask, Entries, StateColumns, tolerance
from torchtasks.envs.mujoco_declaration import Resets
from torchtasks.envs.reset_steps import Box, Choice, DrawDomain, UniformJoints
from torchtasks.rewards import RewardFunction

#: the chance that the target is near (within 0.3 m of the origin, else within 2 m)
P_CLOSE_TARGET = 0.2


def _to_target() -> readings.Reading:
    # the target relative to the nose, in the head's frame, x and y
    return readings.difference(readings.geom_pos("target"), readings.geom_pos("nose"), frame="body:head", index=(0, 1))


def _observation(model: mujoco.MjModel, *, links: int) -> Entries:
    velocities = [readings.sensor("head_vel", index=(0, 1)), readings.sensor("head_gyro", index=(2,))]
    for i in range(links - 1):
        velocities += [readings.sensor(f"velocimeter_{i}", index=(0, 1)), readings.sensor(f"gyro_{i}", index=(2,))]
    return {"joints": [readings.data_field("qpos", 3)], "to_target": [_to_target()], "body_velocities": velocities}


def _state(model: mujoco.MjModel) -> Entries:
    return {"nose_to_target_distance": [readings.norm(_to_target())]}


def _reward(model: mujoco.MjModel, columns: StateColumns) -> RewardFunction:
    size = float(model.geom("target").size[0])
    return tolerance(columns, "nose_to_target_distance", bounds=(0.0, size), margin=5 * size, sigmoid="long_tail")


def _resets(model: mujoco.MjModel) -> Resets:
    near, far = Box((-0.3, -0.3), (0.3, 0.3)), Box((-2.0, -2.0), (2.0, 2.0))
    target = DrawDomain("geom_pos:target", Choice(((P_CLOSE_TARGET, near), (1 - P_CLOSE_TARGET, far))))
    return Resets(steps=(UniformJoints(), target))  # rootz in [-pi, pi), the links' joints in range


TASKS = {
    task: ControlSuiteTask(
        "swimmer",
        task,
        30.0,
        0.03,
        functools.partial(_observation, links=links),
        _state,
        _reward,
        _resets,
        notes="the target light, a visual, stays where the model puts it",
    )
    for task, links in (("swimmer6", 6), ("swimmer15", 15))
}
