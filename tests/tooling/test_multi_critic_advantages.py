"""The pieces of ``examples/train_multi_objective_ppo.py`` (PPO with one critic per reward group), in-process.

Its per-group GAE (TorchRL's ``GAE`` on ``k`` values at once, the done flags expanded to ``k`` columns) is held to a
plain Python GAE recursion run on each group alone, and to numbers worked out by hand; the combined advantage
``Σ_i w_i A_i`` to the GAE of the scalarised reward with the scalarised critic (the reason the example normalises
after combining); the critic loss to one mean squared error per group. The end-to-end ``--quick`` run is in
``test_examples_training.py``.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from types import ModuleType

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn

from example_runs import EXAMPLES

GAMMA, LMBDA = 0.5, 0.5  # γλ = 1/4: the hand-worked numbers below are short binary fractions


@pytest.fixture(scope="module")
def example() -> ModuleType:
    """The example as a module (it imports ``train_locomotion_ppo.py``, hence MuJoCo's presets)."""
    pytest.importorskip("mujoco")
    pytest.importorskip("gymnasium")
    name = "train_multi_objective_ppo"
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses resolve the module of the config class by name
    spec.loader.exec_module(module)
    return module


def reference_gae(
    reward: list[float], value: list[float], next_value: list[float], done: list[bool], terminated: list[bool]
) -> list[float]:
    """GAE of one env and one group, backwards in time: δ = r + γ (1 − terminated) V' − V, A = δ + γλ (1 − done) A'."""
    advantage, running = [0.0] * len(reward), 0.0
    for t in reversed(range(len(reward))):
        delta = reward[t] + GAMMA * (not terminated[t]) * next_value[t] - value[t]
        running = delta + GAMMA * LMBDA * (not done[t]) * running
        advantage[t] = running
    return advantage


def batch(reward: torch.Tensor, value: torch.Tensor, next_value: torch.Tensor, done: list, terminated: list):
    """A ``[envs, time]`` batch whose observations ARE the critic's values (the critic is the identity)."""
    envs, steps = reward.shape[:2]
    flags = {"done": torch.tensor(done).reshape(envs, steps, 1), "terminated": torch.tensor(terminated)}
    flags["terminated"] = flags["terminated"].reshape(envs, steps, 1)
    nxt = {"observation": next_value, "group_reward": reward, **flags}
    return TensorDict({"observation": value, "next": nxt}, [envs, steps])


def identity_critic(example: ModuleType):
    from torchrl.modules import ValueOperator

    return example.make_group_gae(ValueOperator(nn.Identity(), in_keys=["observation"]), GAMMA, LMBDA)


NEVER = [[False] * 4, [False] * 4]
#: (done, terminated) of two envs x four steps: no end; terminations (env 0 then a new episode, env 1 at its last
#: step: no bootstrap); truncations (done without terminated: the next state's value is bootstrapped)
LAYOUTS = {
    "no end": (NEVER, NEVER),
    "terminated": ([[False, True, False, False], [False, False, False, True]],) * 2,
    "truncated": ([[False, True, False, False], [False, False, True, False]], NEVER),
}


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_group_advantages_equal_each_group_alone(example: ModuleType, layout: str) -> None:
    done, terminated = LAYOUTS[layout]
    generator = torch.Generator().manual_seed(0)
    reward, value, next_value = (torch.randn(2, 4, 2, generator=generator, dtype=torch.float64) for _ in range(3))
    data = example.group_advantages(identity_critic(example), batch(reward, value, next_value, done, terminated))
    assert data["group_advantage"].shape == data["group_value_target"].shape == (2, 4, 2)
    for env in range(2):
        for group in range(2):
            expected = reference_gae(
                reward[env, :, group].tolist(),
                value[env, :, group].tolist(),
                next_value[env, :, group].tolist(),
                done[env],
                terminated[env],
            )
            got = data["group_advantage"][env, :, group]
            torch.testing.assert_close(got, torch.tensor(expected, dtype=torch.float64))
            torch.testing.assert_close(data["group_value_target"][env, :, group], got + value[env, :, group])


def test_group_advantages_by_hand(example: ModuleType) -> None:
    """One env, three steps, values 0, γ = λ = 1/2: each group's advantage is Σ_j (1/4)^j r_{t+j} within its episode.

    Group 0 is paid 1 on every step, group 1 only 4 on the last; the episode is cut (terminated) after step 1 in
    the second case, so group 1's payment no longer reaches steps 0 and 1.
    """
    reward = torch.tensor([[[1.0, 0.0], [1.0, 0.0], [1.0, 4.0]]], dtype=torch.float64)
    zeros = torch.zeros(1, 3, 2, dtype=torch.float64)
    gae = identity_critic(example)
    whole = example.group_advantages(gae, batch(reward, zeros, zeros, [[False] * 3], [[False] * 3]))
    expected = [[1 + 1 / 4 + 1 / 16, 4 / 16], [1 + 1 / 4, 4 / 4], [1.0, 4.0]]
    torch.testing.assert_close(whole["group_advantage"][0], torch.tensor(expected, dtype=torch.float64))
    cut = [[False, True, False]]
    split = example.group_advantages(gae, batch(reward, zeros, zeros, cut, cut))
    expected = [[1 + 1 / 4, 0.0], [1.0, 0.0], [1.0, 4.0]]
    torch.testing.assert_close(split["group_advantage"][0], torch.tensor(expected, dtype=torch.float64))


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
@pytest.mark.parametrize("weights", [(1.0, 0.1), (1.0, 2.0), (0.5, -1.0)])
def test_combined_advantage_is_the_scalarised_gae(
    example: ModuleType, weights: tuple[float, float], layout: str
) -> None:
    """``Σ_i w_i A_i`` is the GAE of the reward ``w·r`` with the critic ``w·V`` (GAE is linear in both)."""
    done, terminated = LAYOUTS[layout]
    generator = torch.Generator().manual_seed(1)
    reward, value, next_value = (torch.randn(2, 4, 2, generator=generator, dtype=torch.float64) for _ in range(3))
    data = example.group_advantages(identity_critic(example), batch(reward, value, next_value, done, terminated))
    w = torch.tensor(weights, dtype=torch.float64)
    combined = example.combined_advantage(data["group_advantage"], w)
    assert combined.shape == (2, 4, 1)
    for env in range(2):
        expected = reference_gae(
            (reward[env] @ w).tolist(),
            (value[env] @ w).tolist(),
            (next_value[env] @ w).tolist(),
            done[env],
            terminated[env],
        )
        torch.testing.assert_close(combined[env, :, 0], torch.tensor(expected, dtype=torch.float64))


def test_mismatched_shapes_are_refused(example: ModuleType) -> None:
    with pytest.raises(ValueError, match=r"weights must be \[k\] for advantages \[\.\.\., k\], got weights \[3\]"):
        example.combined_advantage(torch.zeros(4, 2), torch.ones(3))
    with pytest.raises(ValueError, match=r"weights must be \[k\].*got weights \[1, 2\]"):
        example.combined_advantage(torch.zeros(4, 2), torch.ones(1, 2))
    data = batch(torch.zeros(1, 3), torch.zeros(1, 3, 2), torch.zeros(1, 3, 2), [[False] * 3], [[False] * 3])
    with pytest.raises(ValueError, match=r"must be \[\*B, T, k\] for a \[\*B, T\] batch \[1, 3\], got \[1, 3\]"):
        example.group_advantages(identity_critic(example), data)


def test_weight_vectors_parse_or_say_why(example: ModuleType) -> None:
    assert example.weight_vector("1,0.05") == (1.0, 0.05)
    assert example.weight_vector("0, -2.5, 1e-3") == (0.0, -2.5, 0.001)
    for text in ("1;0.1", "1,", "a,b"):
        with pytest.raises(argparse.ArgumentTypeError, match="comma-separated numbers"):
            example.weight_vector(text)
    for text in ("0,0", "1,nan", "inf,1"):
        with pytest.raises(argparse.ArgumentTypeError, match="finite weights, not all zero"):
            example.weight_vector(text)


def test_critic_loss_is_one_mean_squared_error_per_group(example: ModuleType) -> None:
    from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator

    torch.manual_seed(0)
    actor = ProbabilisticActor(
        TensorDictModule(nn.Sequential(nn.Linear(2, 2), NormalParamExtractor()), ["observation"], ["loc", "scale"]),
        in_keys=["loc", "scale"],
        distribution_class=TanhNormal,
        return_log_prob=True,
    )
    critic = ValueOperator(nn.Identity(), in_keys=["observation"])  # the values are the observation
    loss = example.MultiCriticPPOLoss(actor, critic, clip_epsilon=0.2, critic_coeff=0.5)
    observation = torch.tensor([[1.0, 2.0], [3.0, -1.0], [0.0, 0.0]])
    with torch.no_grad():  # the collector acts without gradients
        data = actor(TensorDict({"observation": observation}, [3]))
    data["advantage"] = torch.tensor([[1.0], [-1.0], [0.5]])
    data["group_value_target"] = torch.tensor([[0.0, 2.0], [1.0, 1.0], [2.0, 3.0]])
    losses = loss(data)
    # squared errors, group 0: 1, 4, 4 (mean 3); group 1: 0, 4, 9 (mean 13/3); times critic_coeff 0.5
    torch.testing.assert_close(losses["loss_critic_groups"], torch.tensor([1.5, 13 / 6]))
    torch.testing.assert_close(losses["loss_critic"], torch.tensor(1.5 + 13 / 6))
    assert {"loss_objective", "clip_fraction"} <= set(losses.keys())


def test_weights_must_match_the_groups(example: ModuleType) -> None:
    """A weight vector of the wrong length is refused before any training, naming the preset's groups."""
    with pytest.raises(ValueError, match=r"--weights: mo-halfcheetah-v5 has 2 reward groups .*got 1,2,3"):
        example.train(example.QUICK, (1.0, 2.0, 3.0), seed=0)
