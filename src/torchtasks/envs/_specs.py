"""The specs shared by the batched torch envs (pendulum, point mass): one state vector, a box action, done flags."""

from __future__ import annotations

import torch
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase


def set_box_env_specs(env: EnvBase, state_size: int, action_size: int, action_bound: float, dtype: torch.dtype) -> None:
    """Give ``env`` (batch ``B``) its specs: ``observation [*B, state_size]``, an action in ``±action_bound``
    ``[*B, action_size]``, a ``[*B, 1]`` reward and ``done``/``terminated`` flags, all on ``env.device``.
    """
    batch, device = env.batch_size, env.device
    env.observation_spec = Composite(
        observation=Unbounded(shape=(*batch, state_size), dtype=dtype, device=device), shape=batch
    )
    env.action_spec = Bounded(
        low=-action_bound, high=action_bound, shape=(*batch, action_size), dtype=dtype, device=device
    )
    env.reward_spec = Unbounded(shape=(*batch, 1), dtype=dtype, device=device)
    env.done_spec = Composite(
        done=Categorical(2, shape=(*batch, 1), dtype=torch.bool, device=device),
        terminated=Categorical(2, shape=(*batch, 1), dtype=torch.bool, device=device),
        shape=batch,
    )
