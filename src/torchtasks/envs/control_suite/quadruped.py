"""dm_control's quadruped (walk, run): move forward on flat ground (a 3D four-legged robot)."""

from __future__ import annotations

import functools
import math

import mujoco

from torchtasks.envs import readings
from torchtasks.envs.control_suite.record import ControlSuiteTask, Entries, StateColumns, tolerance, upright, xmat
from torchtasks.envs.mujoco_declaration import Resets
from torchtasks.envs.reset_steps import RaiseUntilContactFree, RandomOrientation
from torchtasks.rewards import ProductReward, RewardFunction

#: the speeds of walk and run (m/s)
SPEEDS = {"walk": 0.5, "run": 5.0}


def _sensors(model: mujoco.MjModel, *kinds: mujoco.mjtSensor) -> list[str]:
    """The names of the model's sensors of these types, in id order (dm_control's ``_get_sensor_names``)."""
    wanted = {int(kind) for kind in kinds}
    return [model.sensor(i).name for i in range(model.nsensor) if int(model.sensor_type[i]) in wanted]


def _observation(model: mujoco.MjModel) -> Entries:
    hinges = [model.joint(j).name for j in range(model.njnt) if int(model.jnt_type[j]) == mujoco.mjtJoint.mjJNT_HINGE]
    kinds = mujoco.mjtSensor
    imu = _sensors(model, kinds.mjSENS_GYRO, kinds.mjSENS_ACCELEROMETER)
    force_torque = _sensors(model, kinds.mjSENS_FORCE, kinds.mjSENS_TORQUE)
    return {
        # dm_control's egocentric state: the hinges' positions and velocities, then the actuators' activations
        "egocentric_state": [readings.joint_pos(*hinges), readings.joint_vel(*hinges), readings.data_field("act")],
        "torso_velocity": [readings.sensor("velocimeter")],
        "torso_upright": [xmat(model, ("torso", "zz"))],
        "imu": [readings.sensor(name) for name in imu],
        "force_torque": [readings.elementwise(readings.sensor(name), "arcsinh") for name in force_torque],
    }


def _state(model: mujoco.MjModel) -> Entries:
    return {"torso_zz": [xmat(model, ("torso", "zz"))], "speed": [readings.sensor("velocimeter", index=(0,))]}


def _reward(model: mujoco.MjModel, columns: StateColumns, *, speed: float) -> RewardFunction:
    move = tolerance(columns, "speed", bounds=(speed, math.inf), margin=speed, sigmoid="linear", value_at_margin=0.5)
    return ProductReward({"upright": upright(columns, "torso_zz"), "move": move})


def _resets(model: mujoco.MjModel) -> Resets:
    # a uniform random orientation, then the lowest height (from 0, in 1 cm steps) at which nothing touches
    return Resets(steps=(RandomOrientation("root", "uniform"), RaiseUntilContactFree("root")))


TASKS = {
    task: ControlSuiteTask(
        "quadruped", task, 20.0, 0.02, _observation, _state, functools.partial(_reward, speed=speed), _resets
    )
    for task, speed in SPEEDS.items()
}
