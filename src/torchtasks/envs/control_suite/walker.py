"""dm_control's walker: stand, walk or run (a planar biped)."""

from __future__ import annotations

import functools
import math

import mujoco

from torchtasks.envs import readings
from torchtasks.envs.control_suite.record import ControlSuiteTask, Entries, StateColumns, tolerance, upright, xmat
from torchtasks.envs.mujoco_declaration import Resets
from torchtasks.envs.reset_steps import UniformJoints
from torchtasks.rewards import AffineReward, CompoundReward, ProductReward, RewardFunction

#: the torso height above which the walker stands (m)
STAND_HEIGHT = 1.2
#: the speeds of walk and run (m/s)
SPEEDS = {"stand": 0.0, "walk": 1.0, "run": 8.0}


def _observation(model: mujoco.MjModel) -> Entries:
    bodies = [model.body(b).name for b in range(1, model.nbody)]
    pairs = [(body, component) for body in bodies for component in ("xx", "xz")]
    return {
        "orientations": [xmat(model, *pairs)],
        "height": [readings.body_pos("torso", index=(2,))],
        "velocity": [readings.joint_vel()],
    }


def _state(model: mujoco.MjModel) -> Entries:
    return {
        "torso_height": [readings.body_pos("torso", index=(2,))],
        "torso_zz": [xmat(model, ("torso", "zz"))],
        "speed": [readings.sensor("torso_subtreelinvel", index=(0,))],
    }


def _reward(model: mujoco.MjModel, columns: StateColumns, *, speed: float) -> RewardFunction:
    # stand = (3 * standing + upright) / 4, upright = (1 + zz) / 2
    standing = tolerance(columns, "torso_height", bounds=(STAND_HEIGHT, math.inf), margin=STAND_HEIGHT / 2)
    stand = CompoundReward(
        {"standing": standing, "upright": upright(columns, "torso_zz")}, weights={"standing": 0.75, "upright": 0.25}
    )
    if speed == 0:
        return stand
    move = tolerance(
        columns, "speed", bounds=(speed, math.inf), margin=speed / 2, sigmoid="linear", value_at_margin=0.5
    )
    return ProductReward({"stand": stand, "move": AffineReward(move, scale=5 / 6, offset=1 / 6)})


def _resets(model: mujoco.MjModel) -> Resets:
    return Resets(steps=(UniformJoints(),))  # rooty in [-pi, pi), the legs' joints in range; no contact check


TASKS = {
    task: ControlSuiteTask(
        "walker", task, 25.0, 0.025, _observation, _state, functools.partial(_reward, speed=speed), _resets
    )
    for task, speed in SPEEDS.items()
}
