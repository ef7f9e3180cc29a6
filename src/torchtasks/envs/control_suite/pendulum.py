"""dm_control's pendulum: swing up and balance a pendulum with a torque too weak to lift it directly."""

from __future__ import annotations

import math

import mujoco

from torchtasks.envs import readings
from torchtasks.envs.control_suite.record import ControlSuiteTask, Entries, StateColumns, tolerance, xmat
from torchtasks.envs.mujoco_declaration import Resets
from torchtasks.envs.reset_steps import UniformJoints
from torchtasks.rewards import RewardFunction

#: the pole counts as up within this angle of vertical
UPRIGHT_ANGLE = math.radians(8)


def _observation(model: mujoco.MjModel) -> Entries:
    return {"orientation": [xmat(model, ("pole", "zz"), ("pole", "xz"))], "velocity": [readings.joint_vel()]}


def _state(model: mujoco.MjModel) -> Entries:
    return {"pole_zz": [xmat(model, ("pole", "zz"))]}


def _reward(model: mujoco.MjModel, columns: StateColumns) -> RewardFunction:
    return tolerance(columns, "pole_zz", bounds=(math.cos(UPRIGHT_ANGLE), 1.0))


def _resets(model: mujoco.MjModel) -> Resets:
    return Resets(steps=(UniformJoints(),))  # the hinge in [-pi, pi)


TASKS = {"swingup": ControlSuiteTask("pendulum", "swingup", 20.0, None, _observation, _state, _reward, _resets)}
