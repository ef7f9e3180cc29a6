"""Ready environments: a batched torch pendulum and, with the ``mujoco`` extra, Gymnasium, MO-Gymnasium and
DeepMind Control Suite presets and batched MuJoCo."""

from typing import Any

from torchtasks.envs.pendulum import PendulumEnv, pendulum_dynamics, swing_up_task
from torchtasks.envs.point_mass import PointMassEnv

#: Gymnasium MuJoCo v5 locomotion presets (torchtasks.envs.locomotion), imported on first access so
#: that ``import torchtasks.envs`` works without the ``mujoco`` extra (gymnasium, mujoco)
_LOCOMOTION = (
    "SUPPORTED_ENV_IDS",
    "Float64InfoReader",
    "MujocoStateInfo",
    "gymnasium_env",
    "locomotion_state_layout",
    "locomotion_task",
    "make_base_env",
    "make_gymnasium_env",
    "safety_velocity_env",
    "safety_velocity_task",
)

#: the batched MuJoCo env and its broken-step transform (torchtasks.envs.batched_mujoco), imported on first
#: access for the same reason
_BATCHED_MUJOCO = ("BatchedMujocoEnv", "ZeroBrokenStepReward")

#: how a batched env of one's own model acts and resets (torchtasks.envs.mujoco_declaration), imported on first
#: access for the same reason; the readings are the module torchtasks.envs.readings
_DECLARATION = ("Actions", "FreeJointRanges", "Noise", "Resets")

#: the DeepMind Control Suite as presets on the batched env (torchtasks.envs.control_suite), imported on first access
#: for the same reason
_CONTROL_SUITE = ("CONTROL_SUITE_TASKS", "control_suite_env", "control_suite_task")

#: the velocity-tracking quadruped (torchtasks.envs.velocity_tracking), imported on first access for the same reason
_VELOCITY_TRACKING = ("velocity_tracking_env", "velocity_tracking_perturbations")

#: MO-Gymnasium's MuJoCo v5 envs as presets with a vector reward (torchtasks.envs.multi_objective), imported on
#: first access for the same reason
_MULTI_OBJECTIVE = ("MULTI_OBJECTIVE_ENV_IDS", "multi_objective_env", "multi_objective_record", "multi_objective_task")

__all__ = [
    "PendulumEnv",
    "PointMassEnv",
    "pendulum_dynamics",
    "swing_up_task",
    *_LOCOMOTION,
    *_BATCHED_MUJOCO,
    *_DECLARATION,
    *_MULTI_OBJECTIVE,
    *_CONTROL_SUITE,
    *_VELOCITY_TRACKING,
]


def __getattr__(name: str) -> Any:
    if name in _LOCOMOTION:
        from torchtasks.envs import locomotion

        return getattr(locomotion, name)
    if name in _BATCHED_MUJOCO:
        from torchtasks.envs import batched_mujoco

        return getattr(batched_mujoco, name)
    if name in _DECLARATION:
        from torchtasks.envs import mujoco_declaration

        return getattr(mujoco_declaration, name)
    if name in _CONTROL_SUITE:
        from torchtasks.envs import control_suite

        return getattr(control_suite, name)
    if name in _MULTI_OBJECTIVE:
        from torchtasks.envs import multi_objective

        return getattr(multi_objective, name)
    if name in _VELOCITY_TRACKING:
        from torchtasks.envs import velocity_tracking

        return getattr(velocity_tracking, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
