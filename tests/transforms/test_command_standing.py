"""GoalCommand's zero_goal_probability (the standing fraction of a velocity command): drawn per env from the
command's own generator after the goals, exactly as the definition says; 0 leaves the stream as it was."""

from __future__ import annotations

import pytest
import torch
from torchrl.envs import Compose, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv
from torchtasks.spaces import Box
from torchtasks.transforms import GoalCommand

LOW, HIGH = [-1.0, -0.5, 0.0], [1.0, 0.5, 2.0]


def _rollout(steps: int = 6, **options):
    command = GoalCommand(Box(LOW, HIGH), resample_steps=2, seed=7, **options)
    env = TransformedEnv(PendulumEnv(batch_size=[5], seed=0), Compose(StepCounter(50), command))
    return env.rollout(steps, break_when_any_done=False)


def test_zero_goals_are_drawn_per_env_after_the_goals():
    data = _rollout(zero_goal_probability=0.4)
    generator = torch.Generator().manual_seed(7)
    low, high = torch.tensor(LOW, dtype=torch.float64), torch.tensor(HIGH, dtype=torch.float64)

    def draw():
        goals = low + torch.rand(5, 3, generator=generator, dtype=torch.float64) * (high - low)
        zero = torch.rand(5, generator=generator, dtype=torch.float64) < 0.4
        return torch.where(zero.unsqueeze(-1), torch.zeros_like(goals), goals)

    goals = draw()
    torch.randint(2, 3, (5,), generator=generator)  # the reset's timers
    expected = [goals]
    for _ in range(5):  # each step draws goals for every env, used where the timer ran out (every 2nd step)
        new = draw()
        expected.append(new if len(expected) % 2 == 0 else expected[-1])
        torch.randint(2, 3, (5,), generator=generator)
    expected = torch.stack(expected[:6], dim=1)
    assert torch.equal(data["goal"].double(), expected.to(data["goal"].dtype).double())
    standing = (data["goal"] == 0).all(-1)
    assert standing.any() and not standing.all()


def test_probability_zero_draws_as_without_the_option_and_one_draws_only_zeros():
    assert torch.equal(_rollout(zero_goal_probability=0.0)["goal"], _rollout()["goal"])
    assert (_rollout(zero_goal_probability=1.0)["goal"] == 0).all()


def test_bad_probabilities_are_refused():
    with pytest.raises(ValueError, match=r"zero_goal_probability must lie in \[0, 1\], got 1.5"):
        GoalCommand(Box(LOW, HIGH), zero_goal_probability=1.5)
    with pytest.raises(ValueError, match="0 is outside the goal space"):
        GoalCommand(Box([0.5], [1.0]), zero_goal_probability=0.1)
    with pytest.raises(TypeError, match="zero_goal_probability must be a real number"):
        GoalCommand(Box(LOW, HIGH), zero_goal_probability="often")
