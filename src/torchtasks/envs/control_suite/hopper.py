"""dm_control's hopper: stand up, or hop forward, on one leg (planar)."""

from __future__ import annotations

import functools
import math

import mujoco

from torchtasks.envs import readings
from torchtasks.envs.control_suite.record import ControlSuiteTask, Entries, StateColumns, small_control, tolerance
from torchtasks.envs.mujoco_declaration import Resets
from torchtasks.envs.reset_steps import UniformJoints
from torchtasks.rewards import ProductReward, RewardFunction

#: the height of the torso's centre of mass above the foot's that counts as standing (m)
STAND_HEIGHT = 0.6
#: the forward speed above which hopping pays 1 (m/s)
HOP_SPEED = 2.0


def _observation(model: mujoco.MjModel) -> Entries:
    touch = [readings.elementwise(readings.sensor(name), "log1p") for name in ("touch_toe", "touch_heel")]
    return {"position": [readings.data_field("qpos", 1)], "velocity": [readings.joint_vel()], "touch": touch}


def _state(model: mujoco.MjModel) -> Entries:
    # dm_control's height: the torso's centre of mass (xipos) above the foot's
    height = readings.difference(
        readings.body_pos("torso", point="com"), readings.body_pos("foot", point="com"), index=(2,)
    )
    return {
        "torso_height": [height],
        "speed": [readings.sensor("torso_subtreelinvel", index=(0,))],
        "control": [readings.actuator_ctrl()],
    }


def _reward(model: mujoco.MjModel, columns: StateColumns, *, hop: bool) -> RewardFunction:
    standing = tolerance(columns, "torso_height", bounds=(STAND_HEIGHT, 2.0))
    if hop:
        hopping = tolerance(
            columns, "speed", bounds=(HOP_SPEED, math.inf), margin=HOP_SPEED / 2, sigmoid="linear", value_at_margin=0.5
        )
        return ProductReward({"standing": standing, "hopping": hopping})
    return ProductReward({"standing": standing, "small_control": small_control(columns)})


def _resets(model: mujoco.MjModel) -> Resets:
    return Resets(steps=(UniformJoints(),))  # rooty in [-pi, pi), the limited joints in range; no contact check


TASKS = {
    task: ControlSuiteTask(
        "hopper", task, 20.0, 0.02, _observation, _state, functools.partial(_reward, hop=hop), _resets
    )
    for task, hop in (("stand", False), ("hop", True))
}
