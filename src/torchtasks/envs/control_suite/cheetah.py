"""dm_control's cheetah: run forward as fast as possible (a planar biped)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from torchtasks.envs import readings
from torchtasks.envs.control_suite.record import ControlSuiteTask, Entries, StateColumns, tolerance
from torchtasks.envs.mujoco_declaration import Resets
from torchtasks.envs.reset_steps import Apply, ResetContext, ResetStep, UniformJoints
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


@dataclass(frozen=True)
class SettleFromDefaultStep(ResetStep):
    """dm_control's cheetah settling: ``substeps`` physics steps with zero controls from the drawn pose, the first of
    which finishes a step begun for the default pose, then the clock back to 0.

    dm_control draws the pose after the reset's forward pass of ``qpos0`` and then calls ``physics.step(200)``,
    whose first substep is an ``mj_step2`` on that forward pass: the velocity the default pose gains in one step
    (``v0``), integrated from the drawn pose. Here each env takes that step from its default pose (its own model:
    per-env masses count), moves the drawn pose by ``v0 * dt``, sets the clock to ``dt`` and steps the rest.

    Example:
        >>> SettleFromDefaultStep(200).substeps
        200
    """

    substeps: int

    def resolve(self, model: mujoco.MjModel) -> Apply:
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, int) or self.substeps < 1:
            raise ValueError(f"SettleFromDefaultStep substeps must be a positive int, got {self.substeps!r}")
        free = [j for j in range(model.njnt) if int(model.jnt_type[j]) in (0, 1)]  # mjJNT_FREE, mjJNT_BALL
        if free or model.nq != model.nv:
            raise ValueError("SettleFromDefaultStep: the model must have hinge and slide joints only")
        default, dt, rest = model.qpos0.copy(), float(model.opt.timestep), self.substeps - 1

        def apply(context: ResetContext, ids: np.ndarray, generators: Sequence[np.random.Generator]) -> None:
            drawn = context.qpos[ids].copy()
            context.qpos[ids] = default
            context.qvel[ids] = 0.0
            context.settle(ids, 1)  # the step dm_control began for the default pose: its velocity v0
            context.qpos[ids] = drawn + dt * context.qvel[ids]  # mj_Euler's mj_integratePos for hinges and slides
            if rest:
                context.data("time")[ids] = dt
                context.settle(ids, rest)

        return apply


def _resets(model: mujoco.MjModel) -> Resets:
    limited = [model.joint(j).name for j in range(model.njnt) if model.jnt_limited[j]]
    # the drawn pose, then 200 physics steps with zero controls so that the cheetah lands (clock back to 0)
    return Resets(steps=(UniformJoints(limited), SettleFromDefaultStep(200)))


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
    )
}
