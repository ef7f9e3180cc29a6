"""Presets with float32 observations: ``observation_dtype=torch.float32`` on every preset family and backend.

A float32 policy runs in a Collector (with the float64 default it fails in torch's matmul); the cast comes after the
TaskTransform, so the task judges the float64 state: rewards, flags, terms, costs and vector rewards equal the float64
preset's bit for bit with the same seed and actions, and the observation is the float64 one rounded to float32.
"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs.utils import check_env_specs

pytest.importorskip("mujoco")
pytest.importorskip("gymnasium")

from torchtasks.envs import gymnasium_env, safety_velocity_env
from torchtasks.envs.multi_objective import multi_objective_env

PRESETS = {
    "gymnasium_env": lambda **kwargs: gymnasium_env("Hopper-v5", **kwargs),
    "safety_velocity_env": lambda **kwargs: safety_velocity_env("Hopper-v5", **kwargs),
    "multi_objective_env": lambda **kwargs: multi_objective_env("mo-hopper-v5", **kwargs),
}
BACKENDS = {"gymnasium": 1, "batched": 2}  # backend: num_envs
STEPS = 40  # Hopper under random actions falls within this: episodes end and reset in the rollout


def _make(preset: str, backend: str, observation_dtype: torch.dtype | None = None):
    kwargs = {} if observation_dtype is None else {"observation_dtype": observation_dtype}
    return PRESETS[preset](num_envs=BACKENDS[backend], backend=backend, seed=3, **kwargs)


class _SeededActions:
    """The same float32 actions, call after call, for any env of the same action spec."""

    def __init__(self, seed: int) -> None:
        self.generator = torch.Generator().manual_seed(seed)

    def __call__(self, tensordict: TensorDictBase) -> TensorDictBase:
        shape = (*tensordict.batch_size, 3)  # Hopper: 3 actuators
        action = torch.rand(shape, generator=self.generator, dtype=torch.float32) * 2 - 1
        return tensordict.set("action", action)


@pytest.mark.parametrize("backend", list(BACKENDS))
@pytest.mark.parametrize("preset", list(PRESETS))
def test_float32_observations_leave_the_task_on_the_float64_state(preset: str, backend: str) -> None:
    env32, env64 = _make(preset, backend, torch.float32), _make(preset, backend)
    assert env32.observation_spec["observation"].dtype == torch.float32
    assert env64.observation_spec["observation"].dtype == torch.float64  # the default is unchanged
    assert env32.action_spec.dtype == env64.action_spec.dtype == torch.float32  # Gymnasium's action space
    data32 = env32.rollout(STEPS, _SeededActions(0), break_when_any_done=False)
    data64 = env64.rollout(STEPS, _SeededActions(0), break_when_any_done=False)
    assert data64["next", "done"].any()  # some episode ended and was reset
    assert data32["observation"].dtype == data32["next", "observation"].dtype == torch.float32
    assert torch.equal(data32["next", "observation"], data64["next", "observation"].to(torch.float32))
    keys = [key for key in data64.keys(True, True) if key not in ("observation", ("next", "observation"))]
    assert set(data32.keys(True, True)) - {"observation", ("next", "observation")} == set(keys)
    for key in keys:  # reward, flags, terms, costs, vector reward, the task state: the float64 preset's, exactly
        assert data32[key].dtype == data64[key].dtype, key
        assert torch.equal(data32[key], data64[key]), key
    check_env_specs(env32)
    env32.close()
    env64.close()


class _Float32Policy(nn.Module):
    def __init__(self, observations: int, actions: int) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Linear(observations, 16), nn.Tanh(), nn.Linear(16, actions), nn.Tanh())

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return self.net(observation)


@pytest.mark.parametrize("backend", list(BACKENDS))
@pytest.mark.parametrize("preset", list(PRESETS))
def test_a_float32_policy_runs_in_a_collector(preset: str, backend: str) -> None:
    env = _make(preset, backend, torch.float32)
    size = env.observation_spec["observation"].shape[-1]
    policy = TensorDictModule(_Float32Policy(size, 3), in_keys=["observation"], out_keys=["action"])
    frames = 8 * BACKENDS[backend]
    collector = Collector(
        env, policy, frames_per_batch=frames, total_frames=frames, auto_register_policy_transforms=False
    )
    batch = next(iter(collector))
    collector.shutdown()
    assert batch["observation"].dtype == torch.float32 and batch["action"].dtype == torch.float32
    assert batch.numel() == 8 * BACKENDS[backend]
    with pytest.raises(RuntimeError, match="same dtype"):  # what the float64 default gives such a policy
        _make(preset, backend).rollout(2, policy)


@pytest.mark.parametrize("preset", list(PRESETS))
@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16, "float32", None])
def test_other_observation_dtypes_are_refused(preset: str, dtype: object) -> None:
    with pytest.raises(ValueError, match=r"observation_dtype must be torch.float32 .* or torch.float64 .* got"):
        PRESETS[preset](observation_dtype=dtype)


def test_dtype_as_a_gymnasium_keyword_names_the_argument() -> None:
    with pytest.raises(TypeError, match=r"observation_dtype=torch\.float32"):
        gymnasium_env("Hopper-v5", dtype=torch.float32)
