"""dm_control's point_mass: bring a point mass to the target at the centre of a plane."""

from __future__ import annotations

import mujoco

from torchtasks.envs import readings
from torchtasks.envs.control_suite.record import ControlSuiteTask, Entries, StateColumns, small_control, tolerance
from torchtasks.envs.mujoco_declaration import Resets
from torchtasks.envs.reset_steps import UniformJoints
from torchtasks.rewards import ProductReward, RewardFunction


def _observation(model: mujoco.MjModel) -> Entries:
    return {"position": [readings.joint_pos()], "velocity": [readings.joint_vel()]}


def _state(model: mujoco.MjModel) -> Entries:
    distance = readings.norm(readings.difference(readings.geom_pos("pointmass"), readings.geom_pos("target")))
    return {"distance_to_target": [distance], "control": [readings.actuator_ctrl()]}


def _reward(model: mujoco.MjModel, columns: StateColumns) -> RewardFunction:
    size = float(model.geom("target").size[0])
    near = tolerance(columns, "distance_to_target", bounds=(0.0, size), margin=size)
    return ProductReward({"near_target": near, "small_control": small_control(columns)})


def _resets(model: mujoco.MjModel) -> Resets:
    return Resets(steps=(UniformJoints(),))  # both limited slides in range


TASKS = {"easy": ControlSuiteTask("point_mass", "easy", 20.0, None, _observation, _state, _reward, _resets)}
