"""Ready environments: a batched torch pendulum (and, with the ``mujoco`` extra, Gymnasium presets)."""

from torchtasks.envs.pendulum import PendulumEnv, pendulum_dynamics, swing_up_task

__all__ = ["PendulumEnv", "pendulum_dynamics", "swing_up_task"]
