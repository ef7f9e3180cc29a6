"""Ready environments: a batched torch pendulum and, with the ``mujoco`` extra, Gymnasium presets and batched MuJoCo."""

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

__all__ = ["PendulumEnv", "PointMassEnv", "pendulum_dynamics", "swing_up_task", *_LOCOMOTION, *_BATCHED_MUJOCO]


def __getattr__(name: str) -> Any:
    if name in _LOCOMOTION:
        from torchtasks.envs import locomotion

        return getattr(locomotion, name)
    if name in _BATCHED_MUJOCO:
        from torchtasks.envs import batched_mujoco

        return getattr(batched_mujoco, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
