"""The velocity-tracking quadruped with every perturbation active, for the layout and resume tests.

:func:`make_perturbed_env`: ``velocity_tracking_env`` with an action queue, observation noise with biases, pushes
(velocity changes that tip the robot over at times, and held forces, frequent enough to happen within a few steps:
falls end some episodes before the 12-step limit, so resets are partial), a DomainRandomization of the
action delay, the servo gains, the masses and frictions at every reset, short episodes (partial resets) and a
:class:`BaseEnvState` (the physics and the delay queue join the transforms' checkpoint). :func:`make_collector`: a
Collector over it with a deterministic policy. Module-level functions: spawn-safe constructors for ``ParallelEnv``.
"""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule
from torchrl.collectors import Collector
from torchrl.envs import TransformedEnv

from torchtasks.envs import velocity_tracking_env, velocity_tracking_perturbations
from torchtasks.transforms import BaseEnvState, Pushes

#: the action delay's maximum of the perturbed env
MAX_DELAY = 2


def make_perturbed_env(
    num_envs: int = 3, *, pushes: bool = True, seed: int = 0, max_action_delay: int = MAX_DELAY
) -> TransformedEnv:
    """``num_envs`` quadrupeds with all four perturbations and randomized physics; episodes of 12 steps (the delay
    drawn up to :data:`MAX_DELAY` steps, in an env whose queue holds ``max_action_delay``)."""
    perturbations = velocity_tracking_perturbations(seed=seed, max_action_delay=MAX_DELAY, pushes=False)
    if pushes:  # pushes every 2-4 steps: velocity changes (roll and pitch rates that tip it over at times) and forces
        force = [20.0] * 3 + [1.0] * 3
        velocity = [0.3, 0.3, 0.3, 25.0, 25.0, 1.0]
        push = Pushes("torso", velocity=velocity, force=force, duration=2, interval_steps=(2, 4), seed=seed + 7)
        perturbations.insert(1, push)  # after the noise, before the randomization (an owner of fields)
    env = velocity_tracking_env(
        num_envs,
        seed=seed,
        max_steps=12,
        max_action_delay=max_action_delay,
        perturbations=perturbations,
        num_threads=1,
    )
    env.append_transform(BaseEnvState())
    return env


def make_policy(env: TransformedEnv) -> TensorDictModule:
    """A fixed linear policy of the observation (the same weights in every process)."""
    generator = torch.Generator().manual_seed(0)
    size, actions = env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1]
    linear = torch.nn.Linear(size, actions, dtype=torch.float64)
    with torch.no_grad():
        linear.weight.copy_(0.1 * torch.randn(actions, size, generator=generator))
        linear.bias.zero_()
    return TensorDictModule(linear, ["observation"], ["action"])


def make_collector(num_envs: int = 3, *, pushes: bool = True, max_action_delay: int = MAX_DELAY) -> Collector:
    """A Collector of ``3 * num_envs`` frames per batch over :func:`make_perturbed_env`."""
    env = make_perturbed_env(num_envs, pushes=pushes, max_action_delay=max_action_delay)
    return Collector(env, make_policy(env), frames_per_batch=3 * num_envs, total_frames=-1)
