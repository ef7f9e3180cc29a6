"""dm_control's manipulator (bring_ball): bring a ball to a target with a planar arm and a two-finger hand."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from torchtasks.envs import readings
from torchtasks.envs.control_suite.record import ControlSuiteTask, Entries, StateColumns, tolerance
from torchtasks.envs.mujoco_declaration import Resets
from torchtasks.envs.reset_steps import (
    Apply,
    AxisAngle,
    Box,
    CopyJoints,
    DrawDomain,
    ResetContext,
    ResetStep,
    UniformJoints,
    UntilContactFree,
)
from torchtasks.rewards import RewardFunction

#: the arm's joints as dm_control lists them (observed in this order)
ARM_JOINTS = ("arm_root", "arm_shoulder", "arm_elbow", "arm_wrist", "finger", "fingertip", "thumb", "thumbtip")
#: the touch sensors, in dm_control's order
TOUCH_SENSORS = ("palm_touch", "finger_touch", "thumb_touch", "fingertip_touch", "thumbtip_touch")
#: the ball's joints in the order dm_control writes its pose: x, z, then the angle about y
OBJECT_JOINTS = ("ball_x", "ball_z", "ball_y")
#: how often an episode starts with the ball in the hand, at the target (else anywhere, thrown)
P_IN_HAND, P_IN_TARGET = 0.1, 0.1


def _pose_2d(body: str) -> list[readings.Reading]:
    """dm_control's ``body_2d_pose``: x, z of the body, then the w and y of its quaternion."""
    return [readings.body_pos(body, index=(0, 2)), readings.body_quat(body, index=(0, 2))]


def _observation(model: mujoco.MjModel) -> Entries:
    return {
        "arm_pos": [readings.elementwise(readings.joint_pos(*ARM_JOINTS), "sin_cos")],
        "arm_vel": [readings.joint_vel(*ARM_JOINTS)],
        "touch": [readings.elementwise(readings.sensor(name), "log1p") for name in TOUCH_SENSORS],
        "hand_pos": _pose_2d("hand"),
        "object_pos": _pose_2d("ball"),
        "object_vel": [readings.joint_vel(*OBJECT_JOINTS)],
        "target_pos": _pose_2d("target_ball"),
    }


def _state(model: mujoco.MjModel) -> Entries:
    distance = readings.norm(readings.difference(readings.site_pos("ball"), readings.site_pos("target_ball")))
    return {"ball_to_target_distance": [distance]}


def _reward(model: mujoco.MjModel, columns: StateColumns) -> RewardFunction:
    return tolerance(columns, "ball_to_target_distance", bounds=(0.0, 0.01), margin=0.02)


@dataclass(frozen=True)
class PlaceBall(ResetStep):
    """dm_control's ball placement: in the hand (``P_IN_HAND``: at the grasp site, along the grasp direction), at
    the target (``P_IN_TARGET``: the target's pose), else anywhere in ``x ~ U(-0.5, 0.5)``, ``z ~ U(0, 0.7)``,
    ``angle ~ U(0, 2 pi)`` and thrown with ``ball_x`` velocity ``U(-5, 5)``.

    Example:
        >>> PlaceBall().writes_state
        True
    """

    def resolve(self, model: mujoco.MjModel) -> Apply:
        columns = np.array([model.jnt_qposadr[model.joint(name).id] for name in OBJECT_JOINTS])
        velocity = int(model.jnt_dofadr[model.joint("ball_x").id])
        grasp, target = model.site("grasp").id, model.body("target_ball").id

        def apply(context: ResetContext, ids: np.ndarray, generators: Sequence[np.random.Generator]) -> None:
            # one draw of the kind per env, then the uniform pose and throw for the envs of that kind
            kinds = np.array([rng.random() for rng in generators])
            thrown = kinds >= P_IN_HAND + P_IN_TARGET
            uniform = [
                (rng.uniform(-0.5, 0.5), rng.uniform(0.0, 0.7), rng.uniform(0.0, 2 * math.pi), rng.uniform(-5, 5))
                for rng, draw in zip(generators, thrown.tolist(), strict=True)
                if draw
            ]
            context.forward(ids, int(mujoco.mjtStage.mjSTAGE_POS))  # the grasp site and the target of the drawn arm
            site, site_mat = context.data("site_xpos")[ids, grasp], context.data("site_xmat")[ids, grasp]
            body, quat = context.data("xpos")[ids, target], context.data("xquat")[ids, target]
            in_hand = np.stack([site[:, 0], site[:, 2], math.pi - np.arctan2(site_mat[:, 6], site_mat[:, 0])], axis=1)
            in_target = np.stack([body[:, 0], body[:, 2], 2 * np.arctan2(quat[:, 2], quat[:, 0])], axis=1)
            pose = np.where((kinds < P_IN_HAND)[:, None], in_hand, in_target)
            if uniform:
                drawn = np.array(uniform)
                pose[thrown] = drawn[:, :3]
                context.qvel[ids[thrown], velocity] = drawn[:, 3]
            context.qpos[np.ix_(ids, columns)] = pose

        return apply


def _resets(model: mujoco.MjModel) -> Resets:
    draws = (
        UniformJoints(ARM_JOINTS),  # arm_root in [-pi, pi), the others in range
        CopyJoints({"finger": "thumb"}),  # a symmetric hand
        DrawDomain("body_pos:target_ball", Box((-0.4, 0.1), (0.4, 0.4), axes=(0, 2))),
        DrawDomain("body_quat:target_ball", AxisAngle((0.0, 1.0, 0.0), (-math.pi, math.pi))),
        PlaceBall(),
    )
    return Resets(steps=(UntilContactFree(draws),))


TASKS = {
    "bring_ball": ControlSuiteTask(
        "manipulator",
        "bring_ball",
        10.0,
        0.01,
        _observation,
        _state,
        _reward,
        _resets,
        notes="drawn in dm_control's order within each attempt, from torchtasks' per-env generators",
    )
}
