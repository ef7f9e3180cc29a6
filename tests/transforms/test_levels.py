"""DifficultyLevels: per-env levels that move at that env's episode ends only, and the per-env values they set.

The expected levels are recomputed from the collected flags by ``walk_env.expected_levels`` (an
independent loop over the frames), never read back from the transform.
"""

from __future__ import annotations

import functools

import pytest
import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector, MultiSyncCollector
from torchrl.envs import Compose, ParallelEnv, StepCounter, TransformedEnv

from torchtasks.rewards import RewardFunction
from torchtasks.spaces import Box
from torchtasks.stats import episode_statistics
from torchtasks.tasks import DesiredStateTask, proximity_succeeded
from torchtasks.transforms import Curriculum, DifficultyLevels, GoalCommand, TaskTransform, linear
from walk_env import SPEC, WalkEnv, expected_levels, make_walk_env, random_walk_policy, walk_task

NUM_LEVELS = 3


def _levels(env: TransformedEnv) -> DifficultyLevels:
    return next(t for t in env.transform if isinstance(t, DifficultyLevels))


def _check_levels(data: TensorDictBase, initial: torch.Tensor) -> None:
    """The levels in ``data`` equal the ones recomputed from its flags; every outcome occurs."""
    expected = expected_levels(data, initial, NUM_LEVELS)
    assert torch.equal(data["next", "curriculum", "level"][..., 0], expected)
    before = torch.cat([initial.unsqueeze(-1), expected[..., :-1]], -1)
    assert torch.equal(data["curriculum", "level"][..., 0], before)  # the root: the level the step was played at
    done = data["next", "done"][..., 0]
    success, failure = data["next", "success"][..., 0], data["next", "failure"][..., 0]
    assert (done & success).any() and (done & failure).any() and (done & ~success & ~failure).any()
    assert ((expected > 0) & (expected < NUM_LEVELS - 1)).any()


def test_levels_move_only_at_that_envs_episode_ends_by_rollout():
    torch.manual_seed(0)
    env = make_walk_env(8)
    data = env.rollout(60, random_walk_policy, break_when_any_done=False)
    _check_levels(data, torch.zeros(8, dtype=torch.int64))
    assert torch.equal(_levels(env).level, data["next", "curriculum", "level"][:, -1, 0])


def test_resets_never_move_a_level():
    torch.manual_seed(1)
    env = make_walk_env(4, num_levels=NUM_LEVELS)
    env.rollout(40, random_walk_policy, break_when_any_done=False)
    levels = _levels(env).level.clone()
    for _ in range(3):  # full resets, and a partial one
        td = env.reset()
        assert torch.equal(td["curriculum", "level"][:, 0], levels)
    td = env.reset(td.set("_reset", torch.tensor([True, False, True, False]).unsqueeze(-1)))
    assert torch.equal(_levels(env).level, levels)


def test_the_first_reset_keeps_the_initial_level():
    env = TransformedEnv(
        WalkEnv([3]), Compose(StepCounter(5), TaskTransform(walk_task()), DifficultyLevels(4, initial_level=2))
    )
    td = env.reset()
    assert td["curriculum", "level"][:, 0].tolist() == [2, 2, 2]


class StartWalkEnv(WalkEnv):
    """A walk whose episodes start at a per-env buffer ``start``, read by the base env at reset."""

    def __init__(self, batch_size: list[int]) -> None:
        super().__init__(batch_size)
        self.register_buffer("start", torch.full(self.batch_size, 9.0))  # no level's row

    def _sample_state(self) -> torch.Tensor:
        return self.start.unsqueeze(-1).clone()


def test_every_episode_starts_at_its_levels_row_the_first_and_a_resumed_one_too():
    """A target the base env reads at reset: the first episode and the first after a resume start from their
    level's row, not from the buffer's value at construction (the rows were written after the env's reset)."""
    table = torch.tensor([0.0, 0.4, -0.4])

    def build() -> TransformedEnv:
        levels = DifficultyLevels(NUM_LEVELS, {"env.start": table.tolist()}, initial_level=1)
        return TransformedEnv(StartWalkEnv([6]), Compose(StepCounter(3), TaskTransform(walk_task()), levels))

    env = build()
    torch.manual_seed(12)
    data = env.rollout(30, random_walk_policy, break_when_any_done=False)
    level = data["curriculum", "level"][..., 0]
    first = torch.ones_like(data["next", "done"][:, :1, 0])
    starts = torch.cat([first, data["next", "done"][:, :-1, 0]], dim=-1)  # each episode's first frame
    assert torch.equal(data["observation"][..., 0][starts], table[level][starts])
    assert (level != 1).any()  # some envs changed level
    resumed = build()
    resumed.transform.load_state_dict(env.transform.state_dict())
    assert torch.equal(resumed.reset()["observation"][:, 0], table[data["next", "curriculum", "level"][:, -1, 0]])


def test_a_transform_between_the_levels_and_their_command():
    """A RewardSum between DifficultyLevels and the GoalCommand whose range they set (TorchRL's view of the
    RewardSum's parent env holds a clone of the levels without the command: it answers for the original)."""
    from torchrl.envs import RewardSum

    high = [[0.1], [0.5], [1.0]]
    levels = DifficultyLevels(NUM_LEVELS, {"command.low": [[-0.1], [-0.5], [-1.0]], "command.high": high})
    command = GoalCommand(Box([-1.0], [1.0]), resample_steps=(2, 3), seed=0)
    env = TransformedEnv(
        WalkEnv([8]), Compose(StepCounter(5), TaskTransform(walk_task(), goal_key="goal"), levels, RewardSum(), command)
    )
    torch.manual_seed(4)
    data = env.rollout(40, random_walk_policy, break_when_any_done=False)
    level = data["curriculum", "level"][..., 0]
    assert (data["goal"][..., 0].abs() <= torch.tensor(high)[:, 0][level]).all() and (level > 0).any()


def test_a_level_row_the_constructor_refuses_is_refused():
    """Levels of a per-env reward weight: a negative row would turn the cost into a reward."""
    from torchtasks.rewards import ControlCostReward

    class PerEnvWeight(ControlCostReward):  # a user's control cost with one weight per env
        def __init__(self, batch: int) -> None:
            super().__init__(weight=1.0)
            self._register_constant("weight", torch.ones(batch), check=check_weights)

    def check_weights(value, name):
        if (torch.as_tensor(value) < 0).any():
            raise ValueError(f"{name} must be non-negative")
        return torch.as_tensor(value, dtype=torch.float64)

    task = DesiredStateTask(SPEC, [0.8], PerEnvWeight(4), functools.partial(proximity_succeeded, threshold=0.15))
    levels = DifficultyLevels(3, {"reward.weight": [1.0, 0.5, -0.5]})
    env = TransformedEnv(WalkEnv([4]), Compose(StepCounter(5), TaskTransform(task), levels))
    with pytest.raises(ValueError, match=r"level 2 of 'reward.weight' can write -0.5 into the PerEnvWeight's weight"):
        env.reset()


def test_levels_persist_across_collector_batches():
    torch.manual_seed(2)
    env = make_walk_env(6)
    collector = Collector(env, random_walk_policy, frames_per_batch=6 * 20, total_frames=6 * 60)
    level = torch.zeros(6, dtype=torch.int64)
    for data in collector:
        _check_levels(data, level) if data["next", "done"].any() else None
        level = data["next", "curriculum", "level"][:, -1, 0]
    collector.shutdown()


def test_a_custom_rule_moves_levels_by_its_change():
    torch.manual_seed(3)

    def farther_than_half(tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> torch.Tensor:
        x = next_tensordict["observation"][..., 0]
        return torch.where(x.abs() > 0.5, 1, -1)  # mjlab's terrain levels: up if far enough, else down

    env = TransformedEnv(
        WalkEnv([6]), Compose(StepCounter(4), TaskTransform(walk_task()), DifficultyLevels(5, rule=farther_than_half))
    )
    data = env.rollout(40, random_walk_policy, break_when_any_done=False)
    done = data["next", "done"][..., 0]
    far = data["next", "observation"][..., 0].abs() > 0.5
    level, expected = torch.zeros(6, dtype=torch.int64), []
    for t in range(40):
        level = torch.where(done[:, t], (level + torch.where(far[:, t], 1, -1)).clamp(0, 4), level)
        expected.append(level)
    assert torch.equal(data["next", "curriculum", "level"][..., 0], torch.stack(expected, -1))
    assert (torch.stack(expected, -1) > 0).any()


@pytest.mark.parametrize(
    "result",
    [torch.ones(6), torch.ones(6, dtype=torch.bool), torch.ones(3, dtype=torch.int64), 1],
    ids=["float", "bool", "wrong-shape", "int"],
)
def test_a_rule_must_return_integer_changes_per_env(result):
    levels = DifficultyLevels(3, rule=lambda td, next_td: result)
    env = TransformedEnv(WalkEnv([6]), Compose(StepCounter(4), TaskTransform(walk_task()), levels))
    with pytest.raises(ValueError, match="integer tensor of shape \\[6\\]"):
        env.rollout(5, random_walk_policy, break_when_any_done=False)


@pytest.mark.parametrize("argument", ["success_key", "failure_key"])
def test_a_misspelt_flag_key_names_the_argument_and_the_entries(argument: str) -> None:
    levels = DifficultyLevels(3, **{argument: "succes"})
    env = TransformedEnv(WalkEnv([2]), Compose(StepCounter(4), TaskTransform(walk_task()), levels))
    with pytest.raises(ValueError, match=rf"{argument}='succes' is not an entry .* 'success'"):
        env.rollout(2, random_walk_policy)
    levels = DifficultyLevels(3, **{argument: "reward"})  # a float entry, not a flag
    env = TransformedEnv(WalkEnv([2]), Compose(StepCounter(4), TaskTransform(walk_task()), levels))
    with pytest.raises(TypeError, match=rf"{argument}='reward' must name a bool flag, got an entry of torch.float32"):
        env.rollout(2, random_walk_policy)


def test_levels_without_a_curriculum_in_a_flat_batch_say_what_to_do():
    """A flat batch has no order to find each env's latest level without a Curriculum's frame count."""
    torch.manual_seed(3)
    data = make_walk_env(4).rollout(12, random_walk_policy, break_when_any_done=False)
    done = data["next", "done"][..., 0].long()
    episode = done.cumsum(-1) - done  # the episodes each env finished before the frame
    data["collector", "traj_ids"] = torch.arange(4).unsqueeze(-1) * 100 + episode  # one id per episode
    assert "curriculum/level" in episode_statistics(data, terms_key=None)
    with pytest.raises(ValueError, match="pass the batch time-major"):
        episode_statistics(data.reshape(-1), terms_key=None)
    assert "curriculum/level" not in episode_statistics(data.reshape(-1), terms_key=None, curriculum_key=None)


def test_goals_are_drawn_in_the_range_of_their_envs_level():
    torch.manual_seed(4)
    low = [[-0.1], [-0.5], [-1.0]]
    high = [[0.1], [0.5], [1.0]]
    env = make_walk_env(8, values={"command.low": low, "command.high": high}, goals=True)
    data = env.rollout(80, random_walk_policy, break_when_any_done=False)
    level = data["curriculum", "level"][..., 0]  # the level the step was played at, fixed in an episode
    goal = data["goal"][..., 0]
    bound = torch.tensor(high)[:, 0][level]
    assert (goal.abs() <= bound).all()
    assert (level == NUM_LEVELS - 1).any() and (goal.abs() > 0.5).any()  # the top level's goals reach farther
    assert torch.equal(data["next", "curriculum", "level"][..., 0], expected_levels(data, torch.zeros(8).long(), 3))


def test_levels_set_per_env_buffers_of_the_base_env_and_the_task():
    class ScaledDistance(RewardFunction):  # a user's reward with a per-env weight
        uses_action = False

        def __init__(self, batch: int) -> None:
            super().__init__()
            self.register_buffer("weight", torch.ones(batch))

        def forward(self, error_state, error_action=None):
            return -self.weight * error_state.norm(dim=-1)

    task = DesiredStateTask(SPEC, [0.8], ScaledDistance(5), functools.partial(proximity_succeeded, threshold=0.15))
    levels = DifficultyLevels(3, {"env.step_size": [0.4, 0.2, 0.1], "reward.weight": [1.0, 2.0, 4.0]})
    env = TransformedEnv(WalkEnv([5]), Compose(StepCounter(5), TaskTransform(task), levels))
    torch.manual_seed(5)
    data = env.rollout(60, random_walk_policy, break_when_any_done=False)
    level = data["curriculum", "level"][..., 0]
    moved = (data["next", "observation"] - data["observation"])[..., 0].abs()
    step = torch.tensor([0.4, 0.2, 0.1])[level]
    playing = data["action"][..., 0] != 0
    assert torch.allclose(moved[playing], step[playing])  # the walk's per-env step size followed the level
    distance = (data["next", "observation"][..., 0] - 0.8).abs()
    assert torch.allclose(data["next", "reward"][..., 0], -torch.tensor([1.0, 2.0, 4.0])[level] * distance)
    assert (level > 0).any()


def test_statistics_report_the_mean_level_and_its_distribution():
    torch.manual_seed(6)
    env = make_walk_env(8)
    data = env.rollout(60, random_walk_policy, break_when_any_done=False)
    stats = episode_statistics(data, terms_key=None)
    last = data["next", "curriculum", "level"][:, -1, 0]
    assert stats["curriculum/level"] == pytest.approx(last.double().mean().item())
    for k in range(int(last.max()) + 1):
        assert stats[f"curriculum/level_fraction/{k}"] == pytest.approx((last == k).double().mean().item())
    assert f"curriculum/level_fraction/{int(last.max()) + 1}" not in stats
    assert "success_rate" in stats


def test_state_dict_restores_levels_also_before_the_specs_are_built():
    torch.manual_seed(7)
    env = make_walk_env(6)
    env.rollout(50, random_walk_policy, break_when_any_done=False)
    saved = env.state_dict()
    fresh = make_walk_env(6)  # its DifficultyLevels has no levels yet
    fresh.load_state_dict(saved)
    assert torch.equal(fresh.reset()["curriculum", "level"][:, 0], _levels(env).level)
    with pytest.raises(ValueError, match="num_levels"):
        make_walk_env(6, num_levels=2).load_state_dict({**saved, "transforms.2.level": torch.full((6,), 2)})
    with pytest.raises(ValueError, match="batch"):
        smaller = make_walk_env(3)
        smaller.load_state_dict(saved)
        smaller.reset()


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"num_levels": 0}, ValueError, "num_levels"),
        ({"num_levels": 3, "initial_level": -1}, ValueError, "initial_level"),
        ({"num_levels": 3, "initial_level": 3}, ValueError, "initial_level"),
        ({"num_levels": 3, "values": {"command.low": [[-0.1], [-0.2]]}}, ValueError, "one row per level"),
        ({"num_levels": 2, "values": {"command.low": ["a", "b"]}}, TypeError, "one value per level"),
        ({"num_levels": 2, "values": {"command.low": [[float("nan")], [0.0]]}}, ValueError, "NaN"),
        ({"num_levels": 2, "rule": 3}, TypeError, "rule"),
    ],
)
def test_bad_arguments_are_refused_at_construction(kwargs, error, match):
    with pytest.raises(error, match=match):
        DifficultyLevels(**kwargs)


def _goal_env(levels: DifficultyLevels, *, command_first: bool = False, curriculum: Curriculum | None = None):
    command = GoalCommand(Box([-1.0], [1.0]))
    task = TaskTransform(walk_task(), goal_key="goal")
    order = [levels, command] if not command_first else [command, levels]
    extra = [] if curriculum is None else [curriculum]
    return TransformedEnv(WalkEnv([4]), Compose(StepCounter(5), task, *extra, *order))


@pytest.mark.parametrize(
    ("values", "match"),
    [
        ({"comand.low": [[-0.1], [-1.0]]}, "unknown target 'comand.low'.*float buffers are"),
        ({"command.low": [[-0.1], [-1.5]]}, "level 1.*leaves the goal space"),
        ({"command.low": [[0.5], [-1.0]], "command.high": [[0.2], [1.0]]}, "level 0.*low > high"),
        ({"command.low": [[-0.1, 0.0], [-1.0, 0.0]]}, "shape \\[2, 1\\]"),
        ({"env.step_siz": [0.4, 0.2]}, "unknown target 'env.step_siz'; did you mean 'env.step_size'\\?"),
        ({"state_des": [[0.1], [0.2]]}, "needs a buffer of shape \\[4, 1\\]"),
    ],
)
def test_bad_targets_are_refused_when_the_env_is_built(values, match):
    with pytest.raises(ValueError, match=match):
        _goal_env(DifficultyLevels(2, values)).reset()


def test_placement_and_ownership_are_checked():
    with pytest.raises(ValueError, match="put DifficultyLevels before it"):
        _goal_env(DifficultyLevels(2, {"command.low": [[-0.1], [-1.0]]}), command_first=True).reset()
    with pytest.raises(ValueError, match="after exactly one TaskTransform"):
        TransformedEnv(WalkEnv([2]), Compose(StepCounter(5), DifficultyLevels(2), TaskTransform(walk_task()))).reset()
    scheduled = Curriculum({"command.low": linear(-0.1, -1.0, 0, 100)})
    with pytest.raises(ValueError, match="a buffer has one owner"):
        _goal_env(DifficultyLevels(2, {"command.low": [[-0.1], [-1.0]]}), curriculum=scheduled).reset()


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
def test_levels_in_parallel_env_workers_follow_their_own_episodes(fork_start_method):
    env = ParallelEnv(2, functools.partial(make_walk_env, 4))
    collector = Collector(env, random_walk_policy, frames_per_batch=8 * 25, total_frames=8 * 50)
    torch.manual_seed(8)
    try:
        batches = [batch.clone() for batch in collector]
    finally:
        collector.shutdown()
    data = torch.cat(batches, -1)  # [workers, envs, time]: each row one env's frames in order
    _check_levels(data, torch.zeros(2, 4, dtype=torch.int64))


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
def test_levels_in_multi_sync_collector_workers_follow_their_own_episodes(fork_start_method):
    collector = MultiSyncCollector(
        [functools.partial(make_walk_env, 4)] * 2, random_walk_policy, frames_per_batch=8 * 25, total_frames=8 * 50
    )
    try:
        batches = [batch.clone() for batch in collector]
    finally:
        collector.shutdown()
    data = torch.cat([batch.reshape(8, -1) for batch in batches], -1)
    _check_levels(data, torch.zeros(8, dtype=torch.int64))
