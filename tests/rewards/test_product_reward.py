"""ProductReward and AffineReward: dm_control's walker reward rebuilt and checked against dm_control's own formula,
Meta-World's Hamacher product, and the factors in the breakdown of a task and of TaskTransform."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from dm_control.utils import rewards as dm_rewards
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv
from torchtasks.rewards import (
    AffineReward,
    CompoundReward,
    ConstantReward,
    ProductReward,
    StateFunctionReward,
    ToleranceReward,
    hamacher_product,
)
from torchtasks.spaces import EnvSpec
from torchtasks.tasks import GoallessTask
from torchtasks.transforms import TaskTransform

STAND_HEIGHT, MOVE_SPEED = 1.2, 1.0  # dm_control walker: _STAND_HEIGHT and _WALK_SPEED


def walker_reward() -> ProductReward:
    """dm_control's walker reward on the state [torso_height, torso_upright, horizontal_velocity]."""
    standing = ToleranceReward(bounds=(STAND_HEIGHT, math.inf), margin=STAND_HEIGHT / 2, indices=[0])
    upright = StateFunctionReward(lambda s: s[..., 1], negate=False)  # torso_upright in [-1, 1]
    stand = CompoundReward(  # (3·standing + upright)/4, upright = (1 + torso_upright)/2
        {"standing": AffineReward(standing, scale=3 / 4), "upright": AffineReward(upright, scale=1 / 8, offset=1 / 8)}
    )
    move = ToleranceReward(
        bounds=(MOVE_SPEED, math.inf), margin=MOVE_SPEED / 2, sigmoid="linear", value_at_margin=0.5, indices=[2]
    )
    return ProductReward({"stand": stand, "move": AffineReward(move, scale=5 / 6, offset=1 / 6)})


def dm_control_walker(height: float, upright: float, velocity: float) -> float:
    """dm_control.suite.walker.PlanarWalker.get_reward, written out with dm_control's own tolerance."""
    standing = dm_rewards.tolerance(height, bounds=(STAND_HEIGHT, float("inf")), margin=STAND_HEIGHT / 2)
    stand_reward = (3 * standing + (1 + upright) / 2) / 4
    move_reward = dm_rewards.tolerance(
        velocity, bounds=(MOVE_SPEED, float("inf")), margin=MOVE_SPEED / 2, value_at_margin=0.5, sigmoid="linear"
    )
    return stand_reward * (5 * move_reward + 1) / 6


def test_the_walker_reward_equals_dm_controls_formula():
    generator = torch.Generator().manual_seed(0)
    state = torch.stack(
        [
            torch.rand(512, generator=generator, dtype=torch.float64) * 2.0,  # torso height 0..2
            torch.rand(512, generator=generator, dtype=torch.float64) * 2 - 1,  # upright -1..1
            torch.rand(512, generator=generator, dtype=torch.float64) * 3 - 0.5,  # velocity -0.5..2.5
        ],
        dim=-1,
    )
    task = GoallessTask(EnvSpec(3, 1), walker_reward())
    out = task.transition(state, torch.zeros(512, 1, dtype=torch.float64), state, task.reset(state))
    expected = torch.tensor([dm_control_walker(*row) for row in state.tolist()], dtype=torch.float64)
    torch.testing.assert_close(out.reward, expected, rtol=0, atol=1e-12)
    # the breakdown holds the factors, and the reward is their product
    assert set(out.terms) == {"stand", "move"}
    torch.testing.assert_close(out.terms["stand"] * out.terms["move"], out.step_reward, rtol=0, atol=1e-15)


def test_hamacher_product_is_meta_worlds():
    def meta_world(a: float, b: float) -> float:  # metaworld.envs.mujoco.utils.reward_utils.hamacher_product
        denominator = a + b - a * b
        return (a * b) / denominator if denominator > 0 else 0.0

    values = np.linspace(0.0, 1.0, 11)
    a, b = np.meshgrid(values, values)
    got = hamacher_product(torch.tensor(a), torch.tensor(b))
    expected = np.vectorize(meta_world)(a, b)
    np.testing.assert_allclose(got.numpy(), expected, rtol=0, atol=1e-15)
    reward = ProductReward(
        {"x": ConstantReward(0.5), "y": ConstantReward(0.25), "z": ConstantReward(1.0)}, hamacher=True
    )
    left_to_right = meta_world(meta_world(0.5, 0.25), 1.0)
    assert abs(float(reward(torch.zeros(1, 1, dtype=torch.float64), None)) - left_to_right) < 1e-15
    # the zero case keeps gradients finite
    x = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    hamacher_product(x, x).sum().backward()
    assert torch.isfinite(x.grad).all()


def test_factors_are_logged_by_task_transform_and_summed_per_episode_by_reward_sum():
    reward = ProductReward(
        {"near": ToleranceReward(bounds=(-0.5, 0.5), margin=1.0, indices=[0]), "half": ConstantReward(0.5)}
    )
    task = GoallessTask(EnvSpec(2, 1), reward)
    env = TransformedEnv(PendulumEnv(batch_size=[3], seed=0), Compose(StepCounter(5), TaskTransform(task), RewardSum()))
    data = env.rollout(4)
    terms = data["next", "task_reward"]
    torch.testing.assert_close(terms["near"] * terms["half"], data["next", "reward"])
    assert ("task_reward", "episode_near") in data["next"].keys(True, True)


def test_affine_reward_keeps_a_stateful_reward_and_checks_sizes():
    from torchtasks.rewards import ForwardVelocityReward, QuadraticErrorReward

    velocity = AffineReward(ForwardVelocityReward(dt=0.5, index=0, ctrl_cost_weight=0.0), scale=2.0, offset=1.0)
    assert velocity.stateful
    task = GoallessTask(EnvSpec(1, 1), velocity)
    state = torch.zeros(2, 1)
    out = task.transition(state, torch.zeros(2, 1), torch.ones(2, 1), task.reset(state))
    assert out.reward.tolist() == [2.0 * 2.0 + 1.0] * 2  # velocity (1 - 0)/0.5 = 2
    with pytest.raises(ValueError, match=r"term 'track' .*expects states of size 1, but the task's state has 2"):
        GoallessTask(EnvSpec(2, 1), ProductReward({"track": AffineReward(QuadraticErrorReward([1.0]), 2.0)}))
    with pytest.raises(ValueError, match="scale must be finite"):
        AffineReward(ConstantReward(1.0), scale=math.inf)
