"""Checkpoints are loaded by meaning and checked: a Curriculum's schedules and a DifficultyLevels' tables by their
target (any order), never by position; a checkpoint of other targets, kinds or shapes is refused naming both sides;
a loaded value passes the check its constructor or spec building ran (a reward's rule, the goal Box, low <= high),
and a refused load leaves the transform as it was. Checked for direct loads and for a Collector's checkpoint.

The expected values are the schedules' own formulas written out in the tests (a linear ramp at 400 of 1000 frames).
"""

from __future__ import annotations

import io

import pytest
import torch
from test_curriculum import WEIGHT, policy, weighted_task
from torchrl.collectors import Collector
from torchrl.envs import Compose, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv
from torchtasks.spaces import Box
from torchtasks.transforms import (
    BaseEnvState,
    Curriculum,
    DifficultyLevels,
    GoalCommand,
    TaskTransform,
    collector_state,
    constant,
    gated,
    linear,
    load_collector_state,
    staged,
)
from walk_env import WalkEnv, walk_task

BATCH = 4
SUCCESS = "success_value"


def pendulum_env(schedules: dict) -> TransformedEnv:
    return TransformedEnv(
        PendulumEnv(batch_size=[BATCH], seed=0),
        Compose(StepCounter(1000), TaskTransform(weighted_task()), Curriculum(schedules)),
    )


def saved(state: dict) -> dict:
    """What ``torch.save`` wrote, read back (a checkpoint is the file, not the live references)."""
    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    return torch.load(buffer, weights_only=False)


def ramped_state() -> dict:
    """The Curriculum's state after 400 frames of success_value 0 -> 100 and the effort weight 0 -> 1e-3."""
    env = pendulum_env({SUCCESS: linear(0.0, 100.0, 0, 1000), WEIGHT: linear(0.0, 1e-3, 0, 1000)})
    env.rollout(400 // BATCH, policy(), break_when_any_done=False)
    return saved(env.transform[-1].state_dict())


def written_values(env: TransformedEnv) -> dict[str, float]:
    """The values one more step writes into the task's buffers (no frames are added at a reset)."""
    env.reset()
    task = env.transform[1].task
    return {name: float(task.get_buffer(name)) for name in (SUCCESS, WEIGHT)}


# ------------------------------------------------------------------------------------- keyed by target
def test_targets_listed_in_another_order_load_into_their_own_buffers():
    state = ramped_state()
    reordered = pendulum_env({WEIGHT: linear(0.0, 1e-3, 0, 1000), SUCCESS: linear(0.0, 100.0, 0, 1000)})
    reordered.transform[-1].load_state_dict(state)
    values = written_values(reordered)
    assert values[SUCCESS] == pytest.approx(40.0, rel=1e-12)  # 100 * 400 / 1000
    assert values[WEIGHT] == pytest.approx(4e-4, rel=1e-6)  # 1e-3 * 400 / 1000 (float32 buffer)


@pytest.mark.parametrize(
    ("schedules", "match"),
    [
        # a target renamed (or another one): both sides named
        ({SUCCESS: linear(0.0, 100.0, 0, 1000), "wrapped_task.reward.rewards.track.weight": linear(0.0, 1.0, 0, 1)},
         r"other targets.*saved \[.*effort/weight.*here \[.*track/weight"),
        # one target fewer
        ({SUCCESS: linear(0.0, 100.0, 0, 1000)}, "other targets"),
        # another kind of schedule for the same target
        ({SUCCESS: staged({0: 0.0, 500: 100.0}), WEIGHT: linear(0.0, 1e-3, 0, 1000)},
         "'success_value' is staged here, but the checkpoint holds a linear schedule"),
    ],
)  # fmt: skip
def test_a_checkpoint_of_other_targets_or_kinds_is_refused_naming_both(schedules, match):
    state = ramped_state()
    env = pendulum_env(schedules)
    before = {key: value.clone() for key, value in env.transform[-1].state_dict().items() if torch.is_tensor(value)}
    with pytest.raises(ValueError, match=match):
        env.transform[-1].load_state_dict(state)
    after = env.transform[-1].state_dict()
    assert all(torch.equal(after[key], value) for key, value in before.items())


def test_a_schedule_of_another_shape_is_refused():
    source = pendulum_env({SUCCESS: staged({0: 0.0, 100: 1.0, 200: 2.0})})
    state = saved(source.transform[-1].state_dict())
    with pytest.raises(ValueError, match=r"'boundaries' of shape \[2\] here, but \[3\] in the checkpoint"):
        pendulum_env({SUCCESS: staged({0: 0.0, 100: 1.0})}).transform[-1].load_state_dict(state)


def test_a_positional_checkpoint_is_refused():
    """The layout of earlier versions (``schedules.0...``) cannot say which buffer a value was for."""
    state = {"frames": torch.tensor(400), "schedules.0.value": torch.tensor(1.0, dtype=torch.float64)}
    with pytest.raises(ValueError, match=r"saved \['0'\], here \['success_value'\]"):
        pendulum_env({SUCCESS: constant(0.0)}).transform[-1].load_state_dict(state)


def test_a_collector_checkpoint_is_loaded_by_target_too():
    def collector(schedules: dict) -> Collector:
        return Collector(
            pendulum_env(schedules),
            policy(),
            frames_per_batch=BATCH * 10,
            total_frames=-1,
            auto_register_policy_transforms=False,
        )

    running = collector({SUCCESS: linear(0.0, 100.0, 0, 1000), WEIGHT: linear(0.0, 1e-3, 0, 1000)})
    batches = iter(running)
    for _ in range(10):  # 400 frames
        next(batches)
    state = saved(running.state_dict())
    running.shutdown()
    resumed = collector({WEIGHT: linear(0.0, 1e-3, 0, 1000), SUCCESS: linear(0.0, 100.0, 0, 1000)})
    resumed.load_state_dict(state)
    curriculum = resumed.env.transform[-1]
    assert int(curriculum.frames) == 400
    values = written_values(resumed.env)
    assert values[SUCCESS] == pytest.approx(40.0, rel=1e-12)
    assert values[WEIGHT] == pytest.approx(4e-4, rel=1e-6)
    renamed = collector({SUCCESS: linear(0.0, 100.0, 0, 1000)})
    with pytest.raises(ValueError, match="other targets"):
        renamed.load_state_dict(state)
    resumed.shutdown()
    renamed.shutdown()


# ------------------------------------------------------------------------------------- loaded values checked
def test_a_loaded_schedule_the_target_refuses_is_refused_and_nothing_changes():
    """A cost weight ramping to -1 is refused at construction; arriving through a checkpoint it is refused too."""
    with pytest.raises(ValueError, match="effort"):
        pendulum_env({WEIGHT: linear(0.0, -1.0, 0, 1000)}).reset()
    env = pendulum_env({WEIGHT: linear(0.0, 1.0, 0, 1000)})
    env.reset()  # the specs are built: the Curriculum is set up
    state = env.transform[-1].state_dict()
    state[f"schedules.{WEIGHT.replace('.', '/')}.end_value"] = torch.tensor(-1.0, dtype=torch.float64)
    state["frames"] = torch.tensor(400)
    with pytest.raises(ValueError, match="effort"):
        env.transform[-1].load_state_dict(state)
    ramp = env.transform[-1].schedules[WEIGHT.replace(".", "/")]
    assert float(ramp.end_value) == 1.0 and int(env.transform[-1].frames) == 0  # put back as it was
    data = env.rollout(3, policy(), break_when_any_done=False)
    assert bool((data["next", "curriculum", WEIGHT.replace(".", "/")] >= 0).all())


def test_a_checkpoint_loaded_before_the_env_is_built_is_checked_when_it_is():
    source = pendulum_env({WEIGHT: linear(0.0, 1.0, 0, 1000)})
    state = source.transform[-1].state_dict()
    state[f"schedules.{WEIGHT.replace('.', '/')}.end_value"] = torch.tensor(-1.0, dtype=torch.float64)
    curriculum = Curriculum({WEIGHT: linear(0.0, 1.0, 0, 1000)})
    curriculum.load_state_dict(state)  # not in an env: nothing to check against yet
    env = TransformedEnv(
        PendulumEnv(batch_size=[BATCH]), Compose(StepCounter(10), TaskTransform(weighted_task()), curriculum)
    )
    with pytest.raises(ValueError, match="effort"):
        env.reset()


def goal_env(box: float, *, levels: DifficultyLevels | None = None, curriculum: Curriculum | None = None):
    command = GoalCommand(Box([-box], [box]), seed=0)
    extra = [t for t in (curriculum, levels) if t is not None]
    return TransformedEnv(
        WalkEnv([BATCH]), Compose(StepCounter(5), TaskTransform(walk_task(), goal_key="goal"), *extra, command)
    )


def test_a_goal_range_from_a_wider_box_is_refused():
    wide = goal_env(5.0)
    wide.reset()
    state = saved(wide.transform[-1].state_dict())
    narrow = goal_env(1.0)
    with pytest.raises(ValueError, match=r"saved sampling range \(low=\[-5.0\], high=\[5.0\]\).*low=\[-1.0\]"):
        narrow.transform[-1].load_state_dict(state)
    assert narrow.transform[-1].low.tolist() == [-1.0]  # unchanged
    goals = narrow.rollout(20, break_when_any_done=False)["goal"]
    assert bool((goals.abs() <= 1.0).all())
    crossed = dict(state, low=torch.tensor([0.5], dtype=torch.float64), high=torch.tensor([0.2], dtype=torch.float64))
    with pytest.raises(ValueError, match="low <= high"):
        goal_env(1.0).transform[-1].load_state_dict(crossed)
    within = dict(state, low=torch.tensor([-0.5], dtype=torch.float64), high=torch.tensor([0.5], dtype=torch.float64))
    goal_env(1.0).transform[-1].load_state_dict(within)  # a range the Box holds loads


def test_a_sampler_command_refuses_a_box_commands_checkpoint():
    box = GoalCommand(Box([-1.0], [1.0]))
    sampler = GoalCommand(lambda batch, generator: torch.zeros(*batch, 1), goal_size=1)
    with pytest.raises(ValueError, match=r"from a Box range, this one .* from a sampler"):
        sampler.load_state_dict(box.state_dict())
    with pytest.raises(ValueError, match=r"from a sampler, this one .* from a Box range"):
        box.load_state_dict(sampler.state_dict())


def test_a_scheduled_range_leaving_the_box_is_refused_when_loaded():
    schedules = {"command.high": linear(0.2, 1.0, 0, 100)}
    env = goal_env(1.0, curriculum=Curriculum(schedules))
    env.reset()
    curriculum = env.transform[2]
    state = curriculum.state_dict()
    state["schedules.command/high.end_value"] = torch.tensor(3.0, dtype=torch.float64)
    with pytest.raises(ValueError, match="leaves the GoalCommand's space"):
        curriculum.load_state_dict(state)


LEVEL_TABLES = {"command.low": [[-0.2], [-0.6], [-1.0]], "command.high": [[0.2], [0.6], [1.0]]}


def test_level_tables_load_by_target_and_are_checked():
    source = goal_env(1.0, levels=DifficultyLevels(3, LEVEL_TABLES))
    source.rollout(10, break_when_any_done=False)
    state = saved(source.transform[2].state_dict())
    reordered = goal_env(1.0, levels=DifficultyLevels(3, dict(reversed(list(LEVEL_TABLES.items())))))
    reordered.reset()
    reordered.transform[2].load_state_dict(state)
    assert reordered.transform[2].tables.get_buffer("command/low")[:, 0].tolist() == [-0.2, -0.6, -1.0]
    assert reordered.transform[2].tables.get_buffer("command/high")[:, 0].tolist() == [0.2, 0.6, 1.0]
    with pytest.raises(ValueError, match=r"other targets.*saved \['command/high', 'command/low'\], here"):
        goal_env(1.0, levels=DifficultyLevels(3, {"command.low": [[-0.2], [-0.6], [-1.0]]})).transform[
            2
        ].load_state_dict(state)
    with pytest.raises(ValueError, match=r"shape \[2, 1\] here.*\[3, 1\] in the checkpoint"):
        two = {target: table[:2] for target, table in LEVEL_TABLES.items()}
        goal_env(1.0, levels=DifficultyLevels(2, two)).transform[2].load_state_dict(state)
    outside = dict(state)
    outside["tables.command/high"] = torch.tensor([[0.2], [0.6], [2.0]], dtype=torch.float64)
    target = goal_env(1.0, levels=DifficultyLevels(3, LEVEL_TABLES))
    target.reset()
    with pytest.raises(ValueError, match=r"level 2.*leaves the goal space"):
        target.transform[2].load_state_dict(outside)
    assert target.transform[2].tables.get_buffer("command/high")[2, 0].item() == 1.0  # put back


def test_gated_schedules_and_levels_keep_their_run_state_through_a_by_target_load():
    """The round trip still restores the run state (stage, average, episodes, levels)."""
    env = pendulum_env({SUCCESS: gated([1.0, 2.0, 3.0], window=4, threshold=-1.0), WEIGHT: constant(0.5)})
    env.rollout(30, policy(), break_when_any_done=False)
    state = saved(env.transform[-1].state_dict())
    fresh = pendulum_env({WEIGHT: constant(0.5), SUCCESS: gated([1.0, 2.0, 3.0], window=4, threshold=-1.0)})
    fresh.transform[-1].load_state_dict(state)
    for name in ("stage", "average", "episodes"):
        assert torch.equal(
            getattr(fresh.transform[-1].schedules[SUCCESS], name), getattr(env.transform[-1].schedules[SUCCESS], name)
        )


def test_a_task_buffer_the_reward_refuses_is_refused_in_a_collector_checkpoint():
    """The task's buffers travel with the TaskTransform's state: a negative cost weight there is refused too."""
    env = pendulum_env({SUCCESS: constant(1.0)})
    env.reset()
    state = saved(env.transform.state_dict())
    key = next(k for k in state if k.endswith("effort.weight"))
    state[key] = torch.full_like(state[key], -1.0)
    with pytest.raises(ValueError, match=r"load_state_dict can write \[?-1.0\]? into the ControlCostReward's weight"):
        pendulum_env({SUCCESS: constant(1.0)}).transform.load_state_dict(state)
    within = saved(env.transform.state_dict())  # a value within the rule loads
    within[key] = torch.full_like(within[key], 0.25)
    fresh = pendulum_env({SUCCESS: constant(1.0)})
    fresh.transform.load_state_dict(within)
    assert float(fresh.transform[1].task.get_buffer(WEIGHT)) == 0.25


# ------------------------------------------------------------------------------------------------ found from outside
def _collector(schedules: dict) -> Collector:
    env = pendulum_env(schedules)
    env.append_transform(BaseEnvState())
    return Collector(env, policy(), frames_per_batch=BATCH * 10, total_frames=-1, auto_register_policy_transforms=False)


def test_a_resumed_run_pays_the_scheduled_value_from_its_first_step():
    """A final reward's success_value is not in the task's own state: the load writes the schedule's value."""
    ramp = {SUCCESS: linear(0.0, 100.0, 0, 500), WEIGHT: linear(0.0, 1e-3, 0, 500)}
    running = _collector(ramp)
    running.set_seed(0)
    batches = iter(running)
    for _ in range(3):  # 120 frames
        next(batches)
    checkpoint = saved(collector_state(running))
    running.shutdown()
    resumed = _collector({SUCCESS: linear(0.0, 100.0, 0, 500), WEIGHT: linear(0.0, 1e-3, 0, 500)})
    load_collector_state(resumed, checkpoint)
    task = resumed.env.transform[1].task
    assert float(task.get_buffer(SUCCESS)) == pytest.approx(24.0, rel=1e-12)  # 100 * 120 / 500, before any step
    assert float(task.get_buffer(WEIGHT)) == pytest.approx(2.4e-4, rel=1e-6)
    resumed.shutdown()


def test_a_refused_load_of_another_shape_leaves_the_range_and_the_levels_as_they_were():
    command = GoalCommand(Box([-1.0, -1.0], [1.0, 1.0]))
    wide = {"low": torch.full((4, 2), -3.0, dtype=torch.float64), "high": torch.full((4, 2), 3.0, dtype=torch.float64)}
    with pytest.raises(ValueError, match="must lie in this command's goal space"):
        command.load_state_dict({**command.state_dict(), **wide})
    assert command.low.shape == (2,) and command.low.tolist() == [-1.0, -1.0] and command.high.tolist() == [1.0, 1.0]
    eight = goal_env(1.0, levels=DifficultyLevels(3, LEVEL_TABLES))
    eight.reset()  # the levels are created with the specs
    four = goal_env(1.0, levels=DifficultyLevels(3, LEVEL_TABLES))
    four.transform[2]._setup(torch.Size([2]))  # a checkpoint of an env of 2
    state = saved(four.transform[2].state_dict())
    with pytest.raises(ValueError, match=r"levels \(loaded\) have shape \[2\], but the env's batch is \[4\]"):
        eight.transform[2].load_state_dict(state)
    assert eight.transform[2].level.shape == (BATCH,)
    eight.rollout(3, break_when_any_done=False)  # the env still runs


def test_a_refused_collector_load_changes_nothing():
    """The GoalCommand refuses its range after the transforms before it loaded: load_collector_state puts them back."""

    def collector() -> Collector:
        schedules = {"command.high": linear(0.2, 1.0, 0, 400)}
        env = goal_env(1.0, curriculum=Curriculum(schedules))
        env.append_transform(BaseEnvState())
        return Collector(
            env, policy(), frames_per_batch=BATCH * 10, total_frames=-1, auto_register_policy_transforms=False
        )

    running = collector()
    batches = iter(running)
    for _ in range(5):
        next(batches)
    checkpoint = saved(collector_state(running))
    running.shutdown()
    low = next(key for key in checkpoint["state_dict"]["env_state_dict"] if key.endswith(".low"))
    checkpoint["state_dict"]["env_state_dict"][low] = torch.tensor([-7.0], dtype=torch.float64)
    other = collector()
    next(iter(other))
    before = saved(collector_state(other))
    with pytest.raises(ValueError, match="must lie in this command's goal space"):
        load_collector_state(other, checkpoint)
    after = saved(collector_state(other))
    frames = next(key for key in before["state_dict"]["env_state_dict"] if key.endswith("frames"))
    assert (
        int(after["state_dict"]["env_state_dict"][frames])
        == BATCH * 10
        != int(checkpoint["state_dict"]["env_state_dict"][frames])
    )
    for key, value in before["state_dict"]["env_state_dict"].items():
        if isinstance(value, torch.Tensor):
            assert torch.equal(after["state_dict"]["env_state_dict"][key], value), key
    assert torch.equal(after["carried"][0]["observation"], before["carried"][0]["observation"])
    other.shutdown()


@pytest.mark.parametrize(
    ("schedule", "edit", "match"),
    [
        (staged({0: 1.0, 1000: 50.0}), {"boundaries": torch.tensor([500, 1000])}, "boundaries must be increasing"),
        (staged({0: 1.0, 1000: 50.0}), {"boundaries": torch.tensor([0, 0])}, "boundaries must be increasing"),
        (gated([1.0, 5.0, 10.0]), {"stage": torch.tensor(7)}, r"stage in \[0, 2\]"),
        (gated([1.0, 5.0, 10.0]), {"stage": torch.tensor(-1)}, r"stage in \[0, 2\]"),
        (gated([1.0, 5.0, 10.0]), {"episodes": torch.tensor(-3)}, "episodes >= 0"),
        (constant(1.0), {"frames": torch.tensor(-500)}, "frame count must be >= 0"),
    ],
)
def test_schedule_state_a_constructor_refuses_is_refused_when_loaded(schedule, edit, match):
    curriculum = Curriculum({SUCCESS: schedule})
    state = curriculum.state_dict()
    for name, value in edit.items():
        state[name if name == "frames" else f"schedules.{SUCCESS}.{name}"] = value
    before = {key: value.clone() for key, value in curriculum.state_dict().items() if torch.is_tensor(value)}
    with pytest.raises(ValueError, match=match):
        curriculum.load_state_dict(state)
    assert all(torch.equal(curriculum.state_dict()[key], value) for key, value in before.items())
