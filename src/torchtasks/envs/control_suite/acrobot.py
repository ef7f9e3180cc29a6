"""dm_control's acrobot: swing a two-link arm actuated at the elbow until its tip reaches a target above it."""

from __future__ import annotations

import functools

import mujoco

from torchtasks.envs import readings
from torchtasks.envs.control_suite.record import ControlSuiteTask, Entries, StateColumns, tolerance, xmat
from torchtasks.envs.mujoco_declaration import Resets
from torchtasks.envs.reset_steps import UniformJoints
from torchtasks.rewards import RewardFunction


def _observation(model: mujoco.MjModel) -> Entries:
    pairs = (("upper_arm", "xz"), ("lower_arm", "xz"), ("upper_arm", "zz"), ("lower_arm", "zz"))
    return {"orientations": [xmat(model, *pairs)], "velocity": [readings.joint_vel()]}


def _state(model: mujoco.MjModel) -> Entries:
    return {
        "tip_to_target": [readings.norm(readings.difference(readings.site_pos("target"), readings.site_pos("tip")))]
    }


def _reward(model: mujoco.MjModel, columns: StateColumns, *, sparse: bool) -> RewardFunction:
    radius = float(model.site("target").size[0])
    return tolerance(columns, "tip_to_target", bounds=(0.0, radius), margin=0.0 if sparse else 1.0)


def _resets(model: mujoco.MjModel) -> Resets:
    return Resets(steps=(UniformJoints(["shoulder", "elbow"]),))  # unlimited hinges: [-pi, pi)


TASKS = {
    task: ControlSuiteTask(
        "acrobot", task, 10.0, None, _observation, _state, functools.partial(_reward, sparse=sparse), _resets
    )
    for task, sparse in (("swingup", False), ("swingup_sparse", True))
}
