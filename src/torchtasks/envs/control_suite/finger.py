"""dm_control's finger: spin a hinged body, or turn it so that its tip reaches a target, with a two-link finger."""

from __future__ import annotations

import functools
import math

import mujoco
import numpy as np

from torchtasks.envs import readings
from torchtasks.envs.control_suite.record import ControlSuiteTask, Entries, StateColumns, tolerance
from torchtasks.envs.mujoco_declaration import Resets
from torchtasks.envs.reset_steps import DrawDomain, Ring, UniformJoints, UntilContactFree
from torchtasks.rewards import RewardFunction

#: the hinge's angular velocity below which spin pays 1 (rad/s)
SPIN_VELOCITY = -15.0


def _relative(name: str) -> readings.Reading:
    """A sensor's x and z relative to the spinner's (dm_control's ``tip_position``, ``target_position``)."""
    return readings.difference(readings.sensor(name), readings.sensor("spinner"), index=(0, 2))


def _target_distance(model: mujoco.MjModel) -> readings.Reading:
    # dm_control: |target_position - tip_position| - the target's radius; both relative to the spinner
    tip_to_target = readings.difference(readings.sensor("target"), readings.sensor("tip"), index=(0, 2))
    return readings.norm(tip_to_target, offset=-float(model.site("target").size[0]))


def _observation(model: mujoco.MjModel, *, turn: bool) -> Entries:
    entries: Entries = {
        "position": [readings.sensor("proximal"), readings.sensor("distal"), _relative("tip")],
        "velocity": [readings.sensor(name) for name in ("proximal_velocity", "distal_velocity", "hinge_velocity")],
        "touch": [readings.elementwise(readings.sensor(name), "log1p") for name in ("touchtop", "touchbottom")],
    }
    if turn:
        entries["target_position"] = [_relative("target")]
        entries["dist_to_target"] = [_target_distance(model)]
    return entries


def _state(model: mujoco.MjModel, *, turn: bool) -> Entries:
    if turn:
        return {"tip_to_target_distance": [_target_distance(model)]}
    return {"hinge_velocity": [readings.sensor("hinge_velocity")]}


def _reward(model: mujoco.MjModel, columns: StateColumns, *, turn: bool) -> RewardFunction:
    if turn:  # float(dist_to_target <= 0)
        return tolerance(columns, "tip_to_target_distance", bounds=(-math.inf, 0.0))
    return tolerance(columns, "hinge_velocity", bounds=(-math.inf, SPIN_VELOCITY))  # float(velocity <= -15)


def _resets(model: mujoco.MjModel, *, turn: bool) -> Resets:
    steps: list = []
    if turn:  # the target on a circle around the hinge, of the radius of the body's tip
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        hinge = data.xanchor[model.joint("hinge").id]
        radius = float(np.sum(model.geom("cap1").size))
        centre = (float(hinge[0]), float(hinge[2]))
        steps.append(DrawDomain("site_pos:target", Ring(centre, radius, axes=(0, 2), angle=(-math.pi, math.pi))))
    steps.append(UntilContactFree((UniformJoints(),)))  # proximal, distal in range, the hinge in [-pi, pi)
    return Resets(steps=tuple(steps))


TASKS = {
    task: ControlSuiteTask(
        "finger",
        task,
        20.0,
        0.02,
        functools.partial(_observation, turn=turn),
        functools.partial(_state, turn=turn),
        functools.partial(_reward, turn=turn),
        functools.partial(_resets, turn=turn),
    )
    for task, turn in (("spin", False), ("turn_easy", True), ("turn_hard", True))
}
