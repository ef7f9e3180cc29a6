"""dm_control's cartpole: balance or swing up a pole on a cart (one pole)."""

from __future__ import annotations

import functools
import math

import mujoco

from torchtasks.envs import readings
from torchtasks.envs.control_suite.record import (
    ControlSuiteTask,
    Entries,
    StateColumns,
    small_control,
    tolerance,
    upright,
    xmat,
)
from torchtasks.envs.mujoco_declaration import Noise, Resets
from torchtasks.envs.reset_steps import NormalJoints, UniformJoints
from torchtasks.rewards import AffineReward, ProductReward, RewardFunction


def _observation(model: mujoco.MjModel) -> Entries:
    position = [readings.joint_pos("slider"), xmat(model, ("pole_1", "zz"), ("pole_1", "xz"))]
    return {"position": position, "velocity": [readings.joint_vel()]}


def _state(model: mujoco.MjModel) -> Entries:
    return {
        "cart_position": [readings.joint_pos("slider")],
        "pole_angle_cosine": [xmat(model, ("pole_1", "zz"))],
        "pole_angular_velocity": [readings.joint_vel("hinge_1")],
        "control": [readings.actuator_ctrl()],
    }


def _reward(model: mujoco.MjModel, columns: StateColumns, *, sparse: bool) -> RewardFunction:
    if sparse:
        return ProductReward(
            {
                "centered": tolerance(columns, "cart_position", bounds=(-0.25, 0.25)),
                "upright": tolerance(columns, "pole_angle_cosine", bounds=(0.995, 1.0)),
            }
        )
    return ProductReward(
        {
            "upright": upright(columns, "pole_angle_cosine"),
            "small_control": small_control(columns),
            "small_velocity": AffineReward(tolerance(columns, "pole_angular_velocity", margin=5.0), 0.5, 0.5),
            "centered": AffineReward(tolerance(columns, "cart_position", margin=2.0), 0.5, 0.5),
        }
    )


def _resets(model: mujoco.MjModel, *, swing_up: bool) -> Resets:
    if swing_up:
        pose = NormalJoints({"slider": (0.0, 0.01), "hinge_1": (math.pi, 0.01)})
    else:
        pose = UniformJoints({"slider": (-0.1, 0.1), "hinge_1": (-0.034, 0.034)})
    return Resets(qvel_noise=Noise("normal", 0.01), steps=(pose,))


TASKS = {
    task: ControlSuiteTask(
        "cartpole",
        task,
        10.0,
        0.01,
        _observation,
        _state,
        functools.partial(_reward, sparse=sparse),
        functools.partial(_resets, swing_up=swing_up),
    )
    for task, swing_up, sparse in (
        ("balance", False, False),
        ("balance_sparse", False, True),
        ("swingup", True, False),
        ("swingup_sparse", True, True),
    )
}
