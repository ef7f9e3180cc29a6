"""The drawn physics in the data have TorchRL's shapes: a scalar field's entry is ``[*B, 1]`` (as ``"reward"``), a
vector field's ``[*B, *value_shape]``, so the privileged-critic recipe (``CatTensors`` of the observation and the drawn
values) builds without an ``UnsqueezeTransform``, and the statistics of the drawn values are the values' means."""

from __future__ import annotations

import pytest
import torch
from torchrl.envs import CatTensors, Compose, DoubleToFloat, StepCounter, TransformedEnv
from torchrl.envs.utils import check_env_specs

from feature_envs import _pendulum_params, pendulum_policy
from torchtasks.domain import UniformDomainParam
from torchtasks.envs import PendulumEnv
from torchtasks.stats import episode_statistics
from torchtasks.transforms import DomainRandomization

FIELDS = ("mass", "length", "gravity")


def _critic_env(dtype: torch.dtype, *before_cat) -> TransformedEnv:
    keys = ["observation", *[("domain", name) for name in FIELDS]]
    return TransformedEnv(
        PendulumEnv(batch_size=[3], seed=0, dtype=dtype),
        Compose(
            StepCounter(4),
            DomainRandomization(_pendulum_params(), seed=0),
            *before_cat,
            CatTensors(keys, "critic_in", del_keys=False, sort=False),
        ),
    )


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["float64", "float32"])
def test_the_privileged_critic_input_concatenates_the_observation_and_the_drawn_physics(dtype: torch.dtype):
    # a float32 network's input: the float64 values cast first, as the docs say (DoubleToFloat)
    cast = [DoubleToFloat(in_keys=[("domain", name) for name in FIELDS])] if dtype == torch.float32 else []
    env = _critic_env(dtype, *cast)
    check_env_specs(env, seed=0)
    for name in FIELDS:
        assert env.observation_spec["domain", name].shape == (3, 1)
    data = env.rollout(9, pendulum_policy(), break_when_any_done=False)
    expected = torch.cat([data["observation"], *[data["domain", name].to(dtype) for name in FIELDS]], -1)
    assert data["critic_in"].shape == (3, 9, 5) and data["critic_in"].dtype == dtype
    assert torch.equal(data["critic_in"], expected)
    base = env.base_env.domain_values(list(FIELDS))  # the entries are the env's values, one per env
    last = data["next"][:, -1]
    for name in FIELDS:
        assert torch.equal(last["domain", name], base[name].unsqueeze(-1).to(dtype))


def test_the_statistics_are_the_means_of_the_drawn_values():
    env = _critic_env(torch.float64)
    data = env.rollout(12, pendulum_policy(), break_when_any_done=False)
    stats = episode_statistics(data)
    done = data["next", "done"].squeeze(-1)
    for name in FIELDS:  # the value each ended episode ran with, one number per field (the scalar's one element)
        assert stats[f"domain/{name}"] == data["next", "domain", name][done].mean().item()
        assert f"domain/{name}/0" not in stats


@pytest.mark.mujoco
def test_a_batched_mujoco_preset_feeds_scalar_and_vector_fields_to_a_critic():
    pytest.importorskip("mujoco")
    pytest.importorskip("gymnasium")
    from torchtasks.envs import gymnasium_env

    env = gymnasium_env("Hopper-v5", num_envs=2, seed=0, backend="batched", num_threads=1)
    params = [
        UniformDomainParam("body_mass_scale", mean=1.0, halfspan=0.3),
        UniformDomainParam("gravity", mean=[0.0, 0.0, -9.81], halfspan=[0.0, 0.0, 1.0]),
    ]
    env.append_transform(DomainRandomization(params, seed=0))
    keys = ["observation", ("domain", "body_mass_scale"), ("domain", "gravity")]
    env.append_transform(CatTensors(keys, "critic_in", del_keys=False, sort=False))
    check_env_specs(env, seed=0)
    assert env.observation_spec["domain", "body_mass_scale"].shape == (2, 1)
    assert env.observation_spec["domain", "gravity"].shape == (2, 3)
    data = env.rollout(3, break_when_any_done=False)
    size = env.observation_spec["observation"].shape[-1]
    assert data["critic_in"].shape == (2, 3, size + 4)
    assert torch.equal(data["critic_in"], torch.cat([data[key] for key in keys], -1))
    env.close()
