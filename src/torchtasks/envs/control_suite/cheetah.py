"""dm_control's cheetah: run forward as fast as possible (a planar biped)."""

from __future__ import annotations

import math

import mujoco

from torchtasks.envs import readings
from torchtasks.envs.control_suite.record import ControlSuiteTask, Entries, StateColumns, tolerance
from torchtasks.envs.mujoco_declaration import Resets
from torchtasks.envs.reset_steps import Settle, UniformJoints
from torchtasks.rewards import RewardFunction

#: the speed above which the reward is 1 (m/s)
RUN_SPEED = 10.0


def _observation(model: mujoco.MjModel) -> Entries:
    return {"position": [readings.data_field("qpos", 1)], "velocity": [readings.joint_vel()]}


def _state(model: mujoco.MjModel) -> Entries:
    return {"speed": [readings.sensor("torso_subtreelinvel", index=(0,))]}


def _reward(model: mujoco.MjModel, columns: StateColumns) -> RewardFunction:
    return tolerance(
        columns, "speed", bounds=(RUN_SPEED, math.inf), margin=RUN_SPEED, sigmoid="linear", value_at_margin=0.0
    )


def _resets(model: mujoco.MjModel) -> Resets:
    limited = [model.joint(j).name for j in range(model.njnt) if model.jnt_limited[j]]
    # the drawn pose, then 200 physics steps with zero controls so that the cheetah lands (clock back to 0)
    return Resets(steps=(UniformJoints(limited), Settle(200)))


TASKS = {
    "run": ControlSuiteTask(
        "cheetah",
        "run",
        10.0,
        None,
        _observation,
        _state,
        _reward,
        _resets,
        notes="dm_control's first settling substep is an mj_step2 on the forward results of qpos0 (computed before the "
        "pose was drawn); here every settling substep starts from the drawn pose, so a settled pose differs from "
        "dm_control's for the same draw (by up to ~0.05 in qpos)",
    )
}
