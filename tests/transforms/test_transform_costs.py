"""TaskTransform with a ConstrainedTask: the cost entries, their sums, offline recomputation and statistics.

Expected costs come from the formula applied to the stored states; episode costs from a loop over the
frames and their done flags, never from the transform or the statistics under test.
"""

from __future__ import annotations

import re

import pytest
import torch
from torchrl.collectors import Collector
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv, swing_up_task
from torchtasks.rewards import StateFunctionReward
from torchtasks.stats import episode_statistics
from torchtasks.tasks import ConstrainedTask, Constraint
from torchtasks.transforms import TaskTransform

SPEED_LIMIT = 3.0


def _fast(state: torch.Tensor) -> torch.Tensor:
    return (state[..., 1].abs() > SPEED_LIMIT).to(state.dtype)


def _far(state: torch.Tensor) -> torch.Tensor:
    return state[..., 0].abs()


def constrained_swing_up() -> ConstrainedTask:
    return ConstrainedTask(
        swing_up_task(),
        {
            "speed": Constraint(StateFunctionReward(_fast, negate=False), limit=2.0),
            "angle": StateFunctionReward(_far, negate=False),
        },
    )


def _env(task, batch: int = 4) -> tuple[TransformedEnv, TaskTransform]:
    transform = TaskTransform(task)
    sums = [RewardSum(in_keys=transform.cost_keys)] if task.cost_names else []
    env = TransformedEnv(PendulumEnv(batch_size=[batch], seed=0), Compose(StepCounter(10), transform, *sums))
    return env, transform


def _policy(td):
    td["action"] = 2.0 * torch.sign(td["observation"][..., 1:2] + 1e-3)  # pumps energy: fast swings
    return td


def _check_costs(data) -> None:
    next_state = data["next", "observation"]
    speed, angle = _fast(next_state), _far(next_state)
    assert torch.equal(data["next", "task_cost", "speed"][..., 0], speed)
    assert torch.equal(data["next", "task_cost", "angle"][..., 0], angle)
    assert torch.equal(data["next", "cost"], torch.stack([speed, angle], -1))
    assert (speed == 1).any() and (speed == 0).any()


def test_cost_entries_are_the_constraints_on_the_next_state():
    env, transform = _env(constrained_swing_up())
    data = env.rollout(40, _policy, break_when_any_done=False)
    _check_costs(data)
    assert transform.cost_names == ("speed", "angle")
    assert env.full_reward_spec["cost"].shape == torch.Size([4, 2])
    assert "cost" not in data.keys()  # reward-spec entries: not carried to the root


def test_reward_sum_over_the_cost_keys_gives_episode_costs():
    env, _ = _env(constrained_swing_up())
    data = env.rollout(40, _policy, break_when_any_done=False)
    cost, done = data["next", "task_cost", "speed"][..., 0], data["next", "done"][..., 0]
    running, expected = torch.zeros(4), []
    for t in range(40):
        running = running + cost[:, t]
        expected.append(running)
        running = torch.where(done[:, t], torch.zeros(4), running)
    assert torch.equal(data["next", "task_cost", "episode_speed"][..., 0], torch.stack(expected, -1))


def test_offline_recomputation_rewrites_the_same_costs():
    env, transform = _env(constrained_swing_up())
    data = env.rollout(30, _policy, break_when_any_done=False)
    stored = data["next", "cost"].clone()
    data["next", "cost"].zero_()
    data["next", "task_cost", "speed"].zero_()
    transform(data)
    assert torch.equal(data["next", "cost"], stored)
    _check_costs(data)


def test_collector_data_carry_the_costs_and_statistics_count_them():
    env, _ = _env(constrained_swing_up(), batch=3)
    collector = Collector(env, _policy, frames_per_batch=3 * 40, total_frames=3 * 40)
    data = next(iter(collector)).clone()
    collector.shutdown()
    _check_costs(data)
    stats = episode_statistics(data, terms_key=None, cost_limits={"speed": 2.0})
    # by hand: rows are envs; an episode is complete when it starts in the batch (the first frame starts one)
    done, cost = data["next", "done"][..., 0], data["next", "task_cost", "speed"][..., 0].double()
    sums, count = [], 0
    for row in range(3):
        total = 0.0
        for t in range(40):
            total += float(cost[row, t])
            if done[row, t]:
                sums.append(total)
                total = 0.0
        count += int(done[row].sum())
    assert stats["episodes"] == count
    assert stats["cost_mean/speed"] == pytest.approx(sum(sums) / len(sums))
    assert stats["cost_violation_rate/speed"] == pytest.approx(sum(s > 2.0 for s in sums) / len(sums))
    assert 0 < stats["cost_violation_rate/speed"] < 1
    assert "cost_mean/angle" in stats and "cost_violation_rate/angle" not in stats
    with pytest.raises(KeyError, match="not costs of the data"):
        episode_statistics(data, terms_key=None, cost_limits={"sped": 2.0})
    with pytest.raises(ValueError, match="finite number >= 0"):
        episode_statistics(data, terms_key=None, cost_limits={"speed": -1.0})


def test_a_task_without_costs_writes_no_cost_entry():
    env, transform = _env(swing_up_task())
    data = env.rollout(5, _policy)
    assert transform.cost_keys == [] and ("next", "cost") not in data.keys(True) and "task_cost" not in data["next"]
    assert not any(key.startswith("cost") for key in episode_statistics(data, terms_key=None))


def _with_terms(names: tuple[str, ...], final: bool):
    """A pendulum task whose reward has the named terms (each -θ²), inside a final reward or not."""
    from torchtasks.rewards import CompoundReward, QuadraticErrorReward
    from torchtasks.spaces import Box, EnvSpec
    from torchtasks.tasks import FinalRewardTask, GoallessTask

    spec = EnvSpec(Box([-10.0, -10.0], [10.0, 10.0]), Box([-2.0], [2.0]))
    reward = CompoundReward({name: QuadraticErrorReward([1.0, 0.0]) for name in names})
    task = GoallessTask(spec, reward)
    return FinalRewardTask(task) if final else task


# RewardSum(in_keys=...) writes ("task_cost", "episode_<x>") / ("task_reward", "episode_<x>") beside each entry it
# sums: an entry of that name beside <x> would be overwritten by the running sum of <x> after every step
CLASHES = {
    "costs": (
        lambda: ConstrainedTask(swing_up_task(), {"speed": _fast_cost(), "episode_speed": _fast_cost()}),
        "cost 'episode_speed' is written beside 'speed' under cost_terms_key='task_cost'",
    ),
    "costs, sum first": (
        lambda: ConstrainedTask(swing_up_task(), {"episode_x": _fast_cost(), "x": _fast_cost()}),
        "cost 'episode_x' is written beside 'x'",
    ),
    "terms": (
        lambda: _with_terms(("track", "episode_track"), final=False),
        "reward term 'episode_track' is written beside 'track' under terms_key='task_reward'",
    ),
    "a term beside the step reward": (
        lambda: _with_terms(("episode_step",), final=True),
        "reward term 'episode_step' is written beside 'step'",
    ),
    "a term beside the final reward": (
        lambda: _with_terms(("track", "episode_final"), final=True),
        "reward term 'episode_final' is written beside 'final'",
    ),
}


def _fast_cost() -> StateFunctionReward:
    return StateFunctionReward(_fast, negate=False)


@pytest.mark.parametrize("case", CLASHES)
def test_a_name_that_reward_sum_writes_beside_another_is_refused(case: str) -> None:
    make, message = CLASHES[case]
    with pytest.raises(
        ValueError,
        match=re.escape(message) + ".*RewardSum writes the episode sum.*it writes episode_<name> beside each entry",
    ):
        TaskTransform(make())


@pytest.mark.parametrize(
    "make",
    [
        lambda: ConstrainedTask(swing_up_task(), {"episode_speed": _fast_cost()}),  # nothing named "speed" beside it
        lambda: _with_terms(("episode_step",), final=False),  # no final reward: no "step" entry is written
        lambda: _with_terms(("track", "episode_track"), final=False),  # the breakdown is not written
    ],
    ids=["cost alone", "term without a step entry", "log_terms=False"],
)
def test_episode_names_without_the_entry_they_would_sum_are_accepted(make) -> None:
    task = make()
    log_terms = "episode_track" not in task.term_names
    env = TransformedEnv(
        PendulumEnv(batch_size=[2], seed=0), Compose(StepCounter(5), TaskTransform(task, log_terms=log_terms))
    )
    env = env.append_transform(RewardSum(in_keys=env.reward_keys))
    data = env.rollout(3, _policy)
    next_state = data["next", "observation"]
    for name in task.cost_names:  # the cost is the constraint on the next state, not a running sum
        assert torch.equal(data["next", "task_cost", name][..., 0], _fast(next_state))
    for name in [n for n in task.term_names if n.startswith("episode_")] if log_terms else ():
        # the term is -θ² of the next state, not a running sum
        assert torch.equal(data["next", "task_reward", name][..., 0], -(next_state[..., 0] ** 2))
