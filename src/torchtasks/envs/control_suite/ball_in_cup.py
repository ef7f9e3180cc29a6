"""dm_control's ball_in_cup: swing a ball on a string into a cup moved in a plane."""

from __future__ import annotations

import mujoco

from torchtasks.envs import readings
from torchtasks.envs.control_suite.record import ControlSuiteTask, Entries, StateColumns
from torchtasks.envs.mujoco_declaration import Resets
from torchtasks.envs.reset_steps import UniformJoints, UntilContactFree
from torchtasks.rewards import RewardFunction, ToleranceReward


def _observation(model: mujoco.MjModel) -> Entries:
    return {"position": [readings.joint_pos()], "velocity": [readings.joint_vel()]}


def _state(model: mujoco.MjModel) -> Entries:
    # the ball's x and z relative to the cup's target site
    return {
        "ball_to_target": [readings.difference(readings.body_pos("ball"), readings.site_pos("target"), index=(0, 2))]
    }


def _reward(model: mujoco.MjModel, columns: StateColumns) -> RewardFunction:
    # dm_control: float(all(|target - ball| < target size - ball radius)) over x and z (a strict <: this is <=, which
    # differs only where a difference equals the bound)
    inside = model.site("target").size[[0, 2]] - model.geom("ball").size[0]
    bounds = ([-float(v) for v in inside], [float(v) for v in inside])
    return ToleranceReward(bounds=bounds, margin=0.0, indices=list(columns["ball_to_target"]))


def _resets(model: mujoco.MjModel) -> Resets:
    return Resets(steps=(UntilContactFree((UniformJoints({"ball_x": (-0.2, 0.2), "ball_z": (0.2, 0.5)}),)),))


TASKS = {"catch": ControlSuiteTask("ball_in_cup", "catch", 20.0, 0.02, _observation, _state, _reward, _resets)}
