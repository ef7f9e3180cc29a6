"""dm_control's humanoid: stand, walk or run (a 21-joint 3D humanoid)."""

from __future__ import annotations

import functools
import math

import mujoco

from torchtasks.envs import readings
from torchtasks.envs.control_suite.record import ControlSuiteTask, Entries, StateColumns, small_control, tolerance, xmat
from torchtasks.envs.mujoco_declaration import Resets
from torchtasks.envs.reset_steps import RandomOrientation, UniformJoints, UntilContactFree
from torchtasks.rewards import AffineReward, ProductReward, RewardFunction

#: the head height above which the humanoid stands (m)
STAND_HEIGHT = 1.4
#: the speeds of walk and run (m/s)
SPEEDS = {"stand": 0.0, "walk": 1.0, "run": 10.0}


def _observation(model: mujoco.MjModel) -> Entries:
    extremities = [
        readings.difference(readings.body_pos(side + limb), readings.body_pos("torso"), frame="body:torso")
        for side in ("left_", "right_")
        for limb in ("hand", "foot")
    ]
    return {
        "joint_angles": [readings.data_field("qpos", 7)],
        "head_height": [readings.body_pos("head", index=(2,))],
        "extremities": extremities,
        "torso_vertical": [xmat(model, ("torso", "zx"), ("torso", "zy"), ("torso", "zz"))],
        "com_velocity": [readings.sensor("torso_subtreelinvel")],
        "velocity": [readings.joint_vel()],
    }


def _state(model: mujoco.MjModel) -> Entries:
    return {
        "head_z": [readings.body_pos("head", index=(2,))],
        "torso_zz": [xmat(model, ("torso", "zz"))],
        "control": [readings.actuator_ctrl()],
        "horizontal_velocity": [readings.sensor("torso_subtreelinvel", index=(0, 1))],
        "horizontal_speed": [readings.norm(readings.sensor("torso_subtreelinvel", index=(0, 1)))],
    }


def _reward(model: mujoco.MjModel, columns: StateColumns, *, speed: float) -> RewardFunction:
    factors = {
        "small_control": small_control(columns),
        "standing": tolerance(columns, "head_z", bounds=(STAND_HEIGHT, math.inf), margin=STAND_HEIGHT / 4),
        "upright": tolerance(columns, "torso_zz", bounds=(0.9, math.inf), margin=1.9, sigmoid="linear",
                             value_at_margin=0.0),
    }  # fmt: skip
    if speed == 0:
        factors["dont_move"] = tolerance(columns, "horizontal_velocity", margin=2.0, combine="mean")
    else:
        move = tolerance(
            columns, "horizontal_speed", bounds=(speed, math.inf), margin=speed, sigmoid="linear", value_at_margin=0.0
        )
        factors["move"] = AffineReward(move, scale=5 / 6, offset=1 / 6)
    return ProductReward(factors)


def _resets(model: mujoco.MjModel) -> Resets:
    # dm_control's randomize_limited_and_rotational_joints until nothing touches: the root's orientation a normalised
    # rand(4) (all components >= 0, kept for benchmark continuity), every limited hinge in its range
    return Resets(steps=(UntilContactFree((RandomOrientation("root", "positive"), UniformJoints())),))


TASKS = {
    task: ControlSuiteTask(
        "humanoid", task, 25.0, 0.025, _observation, _state, functools.partial(_reward, speed=speed), _resets
    )
    for task, speed in SPEEDS.items()
}
