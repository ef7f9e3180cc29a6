"""dm_control's reacher: bring a two-link arm's fingertip to a target placed at random."""

from __future__ import annotations

import mujoco

from torchtasks.envs import readings
from torchtasks.envs.control_suite.record import ControlSuiteTask, Entries, StateColumns, tolerance
from torchtasks.envs.mujoco_declaration import Resets
from torchtasks.envs.reset_steps import DrawDomain, Ring, UniformJoints
from torchtasks.rewards import RewardFunction


def _to_target() -> readings.Reading:
    return readings.difference(readings.geom_pos("target"), readings.geom_pos("finger"), index=(0, 1))


def _observation(model: mujoco.MjModel) -> Entries:
    return {"position": [readings.joint_pos()], "to_target": [_to_target()], "velocity": [readings.joint_vel()]}


def _state(model: mujoco.MjModel) -> Entries:
    return {"finger_to_target_distance": [readings.norm(_to_target())]}


def _reward(model: mujoco.MjModel, columns: StateColumns) -> RewardFunction:
    radii = float(model.geom("target").size[0] + model.geom("finger").size[0])
    return tolerance(columns, "finger_to_target_distance", bounds=(0.0, radii))


def _resets(model: mujoco.MjModel) -> Resets:
    # the shoulder in [-pi, pi), the wrist in its range; the target at an angle in [0, 2 pi) and a radius in
    # [0.05, 0.2) around the arm's base
    return Resets(steps=(UniformJoints(), DrawDomain("geom_pos:target", Ring((0.0, 0.0), (0.05, 0.2)))))


TASKS = {
    task: ControlSuiteTask("reacher", task, 20.0, None, _observation, _state, _reward, _resets)
    for task in ("easy", "hard")
}
