"""GoalCommand on data collected by TorchRL: goals inside the space, changed only at a reset, at the end of their
timer (lengths within the range) or right after a success; the task judges each transition with the goal the policy
saw; the command's state survives SerialEnv/ParallelEnv and collectors; wrong orders are refused at set-up."""

from __future__ import annotations

import copy
import functools
import io

import pytest
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torchrl.collectors import Collector
from torchrl.envs import Compose, ParallelEnv, SerialEnv, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv
from torchtasks.rewards import QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import DesiredStateTask, FinalRewardTask, MaskedTask, proximity_succeeded
from torchtasks.transforms import Curriculum, GoalCommand, TaskTransform, linear

SPACE = Box([-0.6], [0.6])  # goal angles
MAX_STEPS = 25


def angle_task() -> FinalRewardTask:
    """Reach a goal angle (the first state entry) within 0.25; failure beyond ±1.2 rad."""
    spec = EnvSpec(Box([-1.2, -8.5], [1.2, 8.5]), 1)
    near = functools.partial(proximity_succeeded, threshold=0.25)
    inner = DesiredStateTask(spec.select_state([0]), [0.0], QuadraticErrorReward([1.0]), near)
    return FinalRewardTask(MaskedTask(spec, inner, [0]), factor=5.0)


def transforms(**command) -> Compose:
    return Compose(
        StepCounter(MAX_STEPS),
        TaskTransform(angle_task(), goal_key="goal", achieved_goal_key="achieved_goal"),
        GoalCommand(SPACE, **command),
    )


def make_env(batch: int = 8, seed: int = 0, **command) -> TransformedEnv:
    base = PendulumEnv(batch_size=[batch], seed=seed, dtype=torch.float64, init_angle=0.4, init_speed=0.5)
    return TransformedEnv(base, transforms(**command))


def check(data: TensorDictBase, timer_range: tuple[int, int] | None, on_success: bool) -> dict[str, int]:
    """Every rule of the command, and the task's verdicts recomputed offline with the goal the policy saw."""
    goal, next_goal = data["goal"], data["next", "goal"]
    assert ((goal >= SPACE.low) & (goal <= SPACE.high)).all()
    changed = (next_goal != goal).any(-1)
    success = data["next", "success"][..., 0]
    reset_next = torch.zeros_like(changed)
    reset_next[:, :-1] = data["step_count"][:, 1:, 0] == 0  # the next root entry is a new episode
    counts = {"timer": 0, "success": 0, "reset": 0}
    # the first step of each env's current goal; unknown (None) until the first change or reset inside the
    # batch, unless the batch starts with an episode (a collector's batch may start in the middle of one)
    start = [0 if int(data["step_count"][env, 0, 0]) == 0 else None for env in range(changed.shape[0])]
    for t in range(changed.shape[1]):
        for env in range(changed.shape[0]):
            if changed[env, t]:
                allowed_success = on_success and bool(success[env, t])
                expired = timer_range is not None and int(data["goal_steps_left"][env, t]) == 1
                assert allowed_success or expired, (env, t)
                if timer_range is not None and not allowed_success and start[env] is not None:
                    used = t - start[env] + 1  # transitions judged with this goal
                    assert timer_range[0] <= used <= timer_range[1], (env, t, used)
                counts["success" if allowed_success else "timer"] += 1
                start[env] = t + 1
            elif on_success and success[env, t]:
                raise AssertionError(f"no new goal after the success of env {env} at step {t}")
            if reset_next[env, t]:
                counts["reset"] += 1
                start[env] = t + 1
    # the task judged every transition with the goal at the root (the one the policy saw)
    task = angle_task().double()
    for t in range(data.shape[1]):
        step = data[:, t]
        out = task.transition(
            step["observation"], step["action"], step["next", "observation"], step["task"], goal=step["goal"]
        )
        torch.testing.assert_close(out.reward, step["next", "reward"][..., 0], rtol=0, atol=1e-12)
        assert torch.equal(out.success, step["next", "success"][..., 0])
    return counts


def test_goals_change_only_at_reset_and_at_the_end_of_their_timer():
    torch.manual_seed(0)
    data = make_env(resample_steps=(3, 6), seed=1).rollout(60, break_when_any_done=False)
    counts = check(data, (3, 6), on_success=False)
    assert counts["timer"] > 10 and counts["reset"] > 0, counts
    # a reset draws a new goal for the envs being reset only: the root goal after a reset is fresh
    assert ((data["goal_steps_left"] >= 1) & (data["goal_steps_left"] <= 6)).all()


def test_goals_are_resampled_right_after_a_success():
    torch.manual_seed(1)
    data = make_env(resample_on_success=True, seed=2).rollout(80, break_when_any_done=False)
    counts = check(data, None, on_success=True)
    assert counts["success"] > 0, counts


def test_the_command_is_reproducible_with_its_seed():
    first = make_env(resample_steps=4, seed=3)
    second = make_env(resample_steps=4, seed=3)
    for env in (first, second):
        env.transform[-1].set_seed(7)
    torch.manual_seed(0)
    a = first.rollout(20, break_when_any_done=False)
    torch.manual_seed(0)
    b = second.rollout(20, break_when_any_done=False)
    assert torch.equal(a["goal"], b["goal"])


@pytest.mark.multiprocess
@pytest.mark.parametrize("placement", ["serial", "parallel"])
def test_the_state_survives_batched_envs(placement: str):
    factory = functools.partial(PendulumEnv, batch_size=[3], dtype=torch.float64, init_angle=0.4, init_speed=0.5)
    batched = SerialEnv(2, factory) if placement == "serial" else ParallelEnv(2, factory, mp_start_method="fork")
    env = TransformedEnv(batched, transforms(resample_steps=(2, 4)))
    torch.manual_seed(4)
    data = env.rollout(30, break_when_any_done=False).reshape(6, 30)
    env.close()
    check(data, (2, 4), on_success=False)


def test_collector_batches():
    env = make_env(resample_steps=(3, 5), seed=5)
    collector = Collector(env, None, frames_per_batch=8 * 30, total_frames=8 * 60)
    for batch in collector:
        check(batch, (3, 5), on_success=False)
    collector.shutdown()


def test_wrong_orders_are_refused_at_set_up():
    base = PendulumEnv(batch_size=[2])
    before = Compose(
        StepCounter(5), GoalCommand(SPACE, resample_on_success=True), TaskTransform(angle_task(), goal_key="goal")
    )
    with pytest.raises(ValueError, match="must come after the TaskTransform"):
        TransformedEnv(base, before).reset()
    unseen = Compose(StepCounter(5), TaskTransform(angle_task()), GoalCommand(SPACE))
    with pytest.raises(ValueError, match="the task would not see the goal"):
        TransformedEnv(PendulumEnv(batch_size=[2]), unseen).reset()
    with pytest.raises(ValueError, match="finite bounds"):
        GoalCommand(Box([-1.0], [float("inf")]))
    with pytest.raises(ValueError, match="low <= high"):
        GoalCommand(SPACE, resample_steps=(5, 2))


# ------------------------------------------------------------------------------------------- checkpoints
def resumed(env: TransformedEnv, **command) -> TransformedEnv:
    """A fresh env (other seeds) into which the transforms' and the base env's states of ``env`` are loaded."""
    fresh = make_env(seed=99, **command)
    fresh.load_state_dict(env.state_dict())
    fresh.base_env.load_state_dict(env.base_env.state_dict())
    return fresh


def test_a_loaded_command_draws_the_goals_of_the_uninterrupted_one():
    env = make_env(resample_steps=(2, 5), seed=3)
    env.transform[-1].set_seed(11)
    torch.manual_seed(0)
    env.rollout(17, break_when_any_done=False)
    env.reset()
    state = env.transform[-1].state_dict()
    assert state["_extra_state"]["own_generator"] and state["_extra_state"]["seed"] == 11
    fresh = resumed(env, resample_steps=(2, 5))  # its command had no generator: the state gives it one
    assert fresh.transform[-1].generator is not None
    for _ in range(2):
        torch.manual_seed(1)
        a = env.rollout(30, break_when_any_done=False)
        torch.manual_seed(1)
        b = fresh.rollout(30, break_when_any_done=False)
        for key in ("goal", "goal_steps_left", ("next", "goal"), ("next", "goal_steps_left"), "observation"):
            assert torch.equal(a[key], b[key]), key
    # the command alone: the same next draws, bit for bit
    command, loaded = env.transform[-1], GoalCommand(SPACE, resample_steps=(2, 5), seed=5)
    loaded.load_state_dict(command.state_dict())
    batch = torch.Size([8])
    assert torch.equal(
        command._sample_goals(batch, torch.float64, torch.device("cpu")),
        loaded._sample_goals(batch, torch.float64, torch.device("cpu")),
    )
    assert torch.equal(
        command._sample_timers(batch, torch.device("cpu")), loaded._sample_timers(batch, torch.device("cpu"))
    )


def test_a_command_on_the_global_generator_has_nothing_to_restore():
    unseeded = GoalCommand(SPACE)
    assert unseeded.state_dict()["_extra_state"] == {"own_generator": False, "seed": None, "generator_state": None}
    seeded = GoalCommand(SPACE, seed=3)
    seeded.load_state_dict(unseeded.state_dict())
    assert seeded.generator is None  # it draws from torch's global generator, as the saved one did
    with pytest.raises(ValueError, match="extra state must be a dict"):
        seeded.load_state_dict({**seeded.state_dict(), "_extra_state": {"seed": 3}})
    with pytest.raises(ValueError, match="uint8 tensor"):
        seeded.load_state_dict(
            {**seeded.state_dict(), "_extra_state": {"own_generator": True, "generator_state": [1, 2]}}
        )


def test_a_collector_checkpoint_restores_the_command():
    def collector(seed: int) -> Collector:
        torch.manual_seed(seed)
        policy = TensorDictModule(torch.nn.Linear(2, 1, dtype=torch.float64), ["observation"], ["action"])
        env = make_env(resample_steps=(3, 5), seed=seed)
        return Collector(env, policy, frames_per_batch=8 * 10, total_frames=-1, auto_register_policy_transforms=False)

    running = collector(5)
    running.env.transform[-1].set_seed(6)
    batches = iter(running)
    for _ in range(3):
        next(batches)
    saved = {"collector": running.state_dict(), "base_env": running.env.base_env.state_dict()}
    assert "transforms.2._extra_state" in saved["collector"]["env_state_dict"]
    buffer = io.BytesIO()
    torch.save(saved, buffer)
    buffer.seek(0)
    loaded = torch.load(buffer)
    fresh = collector(42)
    fresh.load_state_dict(loaded["collector"])
    fresh.env.base_env.load_state_dict(loaded["base_env"])
    # the command inside draws what the uninterrupted one draws, given the same calls
    assert torch.equal(fresh.env.transform[-1].generator.get_state(), running.env.transform[-1].generator.get_state())
    for source in (running, fresh):
        source.reset()  # a loaded collector starts fresh trajectories: start them in both
    fresh_batches = iter(fresh)
    for _ in range(2):
        a, b = next(batches), next(fresh_batches)
        for key in ("goal", "goal_steps_left", ("next", "goal"), "observation", ("next", "observation"), "action"):
            assert torch.equal(a[key], b[key]), key
        check(b, (3, 5), on_success=False)
    running.shutdown()
    fresh.shutdown()


# ----------------------------------------------------------------------------------------- range buffers
def test_the_range_is_registered_buffers_and_goals_are_drawn_as_before():
    command = GoalCommand(Box([-1.0, 0.5], [1.0, 2.0]), seed=3)
    state = command.state_dict()
    assert torch.equal(state["low"], torch.tensor([-1.0, 0.5], dtype=torch.float64))
    assert torch.equal(state["high"], torch.tensor([1.0, 2.0], dtype=torch.float64))
    # the formula of the goals drawn before the range was a buffer, on the same generator
    unit = torch.rand((5, 2), generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    expected = torch.tensor([-1.0, 0.5], dtype=torch.float64) + unit * torch.tensor([2.0, 1.5], dtype=torch.float64)
    assert torch.equal(command._sample_goals(torch.Size([5]), torch.float64, torch.device("cpu")), expected)
    # a narrower range loaded from a state_dict is the one sampled from
    narrow = GoalCommand(Box([-1.0, 0.5], [1.0, 2.0]), seed=4)
    narrow.high.fill_(0.6)
    narrow.low.fill_(0.5)
    command.load_state_dict(narrow.state_dict())
    goals = command._sample_goals(torch.Size([100]), torch.float64, torch.device("cpu"))
    assert ((goals >= 0.5) & (goals <= 0.6)).all()
    sampler = GoalCommand(lambda shape, generator: torch.zeros(*shape, 1), goal_size=1)
    assert dict(sampler.named_buffers()) == {}


# ------------------------------------------------------------------------------------------- ranges per env
def per_env_ranges(batch: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Disjoint ranges inside SPACE, one per env: [low_i, low_i + 0.1]."""
    low = torch.linspace(-0.6, 0.45, batch, dtype=torch.float64).unsqueeze(-1)
    return low, low + 0.1


def saved_and_loaded(state: dict) -> dict:
    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    return torch.load(buffer)


def in_own_range(goals: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> bool:
    """Whether every goal of env ``i`` (``goals[i, ...]``, any time dims in between) lies in ``[low[i], high[i]]``."""
    shape = (low.shape[0],) + (1,) * (goals.dim() - 2) + (low.shape[-1],)
    return bool(((goals >= low.reshape(shape)) & (goals <= high.reshape(shape))).all())


def test_each_env_draws_its_goals_from_its_own_range():
    env = make_env(resample_steps=(1, 3), seed=2)
    command = env.transform[-1]
    command.use_per_env_range(env.batch_size)
    assert command.low.shape == command.high.shape == (8, 1)
    assert torch.equal(command.low, SPACE.low.to(torch.float64).expand(8, 1))  # each env starts with the range
    low, high = per_env_ranges(8)
    command.low.copy_(low)
    command.high.copy_(high)
    command.set_seed(0)
    data = env.rollout(60, break_when_any_done=False)  # resets at 25 and 50 steps, goals drawn at every step
    assert in_own_range(data["goal"], low, high) and in_own_range(data["next", "goal"], low, high)
    check(data, (1, 3), on_success=False)
    # a partial reset draws for the whole batch and keeps the new goals of the envs being reset only
    td = env.reset()
    td = env.step(td.set("action", env.action_spec.zero()))["next"]
    reset = torch.zeros(8, 1, dtype=torch.bool)
    reset[[1, 6]] = True
    after = env.reset(td.clone().set("_reset", reset))
    assert in_own_range(after["goal"], low, high)
    kept = ~reset[:, 0]
    assert torch.equal(after["goal"][kept], td["goal"][kept])
    assert not torch.equal(after["goal"][~kept], td["goal"][~kept])


def test_use_per_env_range_is_idempotent_and_checks_its_input():
    command = GoalCommand(Box([-1.0, 0.0], [1.0, 2.0]), seed=0)
    command.use_per_env_range(torch.Size([2, 3]))
    low = command.low
    command.use_per_env_range([2, 3])
    assert command.low is low and low.shape == (2, 3, 2)
    with pytest.raises(ValueError, match=r"'low' has shape \[2, 3, 2\], which is neither one range \[2\] nor the "):
        command.use_per_env_range([4])
    with pytest.raises(TypeError, match=r"batch_size must be a torch\.Size or a sequence of non-negative ints, got 4"):
        command.use_per_env_range(4)
    with pytest.raises(TypeError, match=r"batch_size\[0\] must be a non-negative int, got 2.0"):
        command.use_per_env_range([2.0])
    sampler = GoalCommand(lambda shape, generator: torch.zeros(*shape, 1), goal_size=1)
    with pytest.raises(ValueError, match="draws goals with a sampler callable, which has no sampling range"):
        sampler.use_per_env_range([2])
    # a range per env of another batch than the env's is refused when goals are drawn
    env = make_env(batch=4)
    env.transform[-1].use_per_env_range([3])
    with pytest.raises(ValueError, match=r"per-env range 'low' has shape \[3, 1\], but goals are drawn for a batch of"):
        env.reset()


def test_a_per_env_range_moves_and_loads_into_a_command_of_either_shape():
    command = GoalCommand(SPACE, resample_steps=(2, 5), seed=1)
    command.use_per_env_range([8])
    low, high = per_env_ranges(8)
    command.low.copy_(low)
    command.high.copy_(high)
    moved = copy.deepcopy(command).to("meta")
    assert moved.low.shape == (8, 1) and moved.low.device.type == "meta"
    # a checkpoint of a per-env command loads into a freshly built one (one range): the buffers take the saved shape
    fresh = GoalCommand(SPACE, resample_steps=(2, 5))
    fresh.load_state_dict(saved_and_loaded(command.state_dict()))
    assert torch.equal(fresh.low, low) and torch.equal(fresh.high, high)
    batch = torch.Size([8])
    draws = [c._sample_goals(batch, torch.float64, torch.device("cpu")) for c in (command, fresh)]
    assert torch.equal(draws[0], draws[1]) and in_own_range(draws[0], low, high)
    # and back: one range into a per-env command
    fresh.load_state_dict(GoalCommand(SPACE, seed=2).state_dict())
    assert fresh.low.shape == fresh.high.shape == (1,)
    state = command.state_dict()
    state["low"] = torch.zeros(8, 2, dtype=torch.float64)
    with pytest.raises(ValueError, match=r"the saved range 'low' must have shape \[1\] or \[\*B, 1\] .* got \[8, 2\]"):
        fresh.load_state_dict(state)
    # through the env's state (what a collector checkpoint holds)
    env = make_env(resample_steps=(2, 5))
    env.transform[-1].use_per_env_range(env.batch_size)
    env.transform[-1].high.copy_(high)
    rebuilt = make_env(resample_steps=(2, 5))
    rebuilt.load_state_dict(env.state_dict())
    assert torch.equal(rebuilt.transform[-1].high, high) and rebuilt.transform[-1].low.shape == (8, 1)


def test_a_curriculum_schedules_a_per_env_range():
    """A scalar schedule is written into every env's row (the buffer keeps its shape [B, k])."""
    command = GoalCommand(SPACE, resample_steps=1, seed=0)
    command.use_per_env_range([8])
    env = TransformedEnv(
        PendulumEnv(batch_size=[8], seed=0, dtype=torch.float64),
        Compose(
            StepCounter(MAX_STEPS),
            TaskTransform(angle_task(), goal_key="goal"),
            Curriculum({"command.high": linear(-0.5, 0.5, 0, 8 * 20)}),
            command,
        ),
    )
    data = env.rollout(20, break_when_any_done=False)
    high = data["next", "curriculum", "command/high"]  # the value of each step, with which its goal was drawn
    assert (data["next", "goal"] <= high).all() and (data["next", "goal"] >= SPACE.low).all()
    assert command.high.shape == (8, 1) and torch.equal(command.high, torch.full((8, 1), 0.5, dtype=torch.float64))
