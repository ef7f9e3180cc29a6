"""Curriculum: schedules against hand-computed values at their boundaries; frames follow the steps of all envs, not
their resets (IsaacLab #2079); a scheduled buffer really changes the reward; a gated stage advances only once the
success average passes its threshold; misspelt targets and wrong shapes are refused at set-up; the counters survive
state_dict and a Collector checkpoint (resume continues exactly); the host-evaluated step gives forward()'s values
bit for bit and never changes the data of earlier steps; with ``workers=n`` the workers of a ParallelEnv or a
MultiSyncCollector see the schedule of one process stepping all their envs."""

from __future__ import annotations

import functools
import io
import math
import re

import pytest
import torch
from tensordict.nn import TensorDictModule
from torchrl.collectors import Collector, MultiSyncCollector
from torchrl.envs import Compose, ParallelEnv, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv, swing_up_task
from torchtasks.rewards import CompoundReward, ControlCostReward, QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import DesiredStateTask, FinalRewardTask, proximity_succeeded
from torchtasks.transforms import Curriculum, GoalCommand, TaskTransform, constant, gated, linear, staged
from walk_env import WalkEnv

WEIGHT = "wrapped_task.reward.rewards.effort.weight"
BATCH = 8


def weighted_task(success_threshold: float = 0.1) -> FinalRewardTask:
    """Track [0, 0] (-(θ² + 0.1 θ̇²)) with an effort term -w·u² whose weight w is scheduled; +10 on success."""
    reward = CompoundReward({"track": QuadraticErrorReward([1.0, 0.1]), "effort": ControlCostReward(weight=0.0)})
    near = functools.partial(proximity_succeeded, threshold=success_threshold)
    return FinalRewardTask(DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], reward, near), factor=10.0)


def make_env(
    schedules,
    *,
    task=None,
    max_steps: int = 1000,
    batch: int = BATCH,
    seed: int = 0,
    workers: int = 1,
    dtype: torch.dtype = torch.float32,
) -> TransformedEnv:
    return TransformedEnv(
        PendulumEnv(batch_size=[batch], seed=seed, dtype=dtype),
        Compose(
            StepCounter(max_steps),
            TaskTransform(task if task is not None else weighted_task()),
            Curriculum(schedules, workers=workers),
        ),
    )


def policy() -> TensorDictModule:
    """A deterministic policy: a torque against the angle."""
    return TensorDictModule(lambda obs: (-0.8 * obs[..., :1]).clamp(-2.0, 2.0), ["observation"], ["action"])


def frames(value: int) -> torch.Tensor:
    return torch.tensor(value, dtype=torch.int64)


# ----------------------------------------------------------------------------------------------- schedules
def test_constant_is_its_value_at_every_count():
    schedule = constant(torch.tensor([1.0, 2.0]))
    for count in (0, 1, 10**9):
        assert torch.equal(schedule(frames(count)), torch.tensor([1.0, 2.0], dtype=torch.float64))
    assert schedule.value_shape == (2,)


def test_linear_ramp_endpoints_midpoint_and_clamping():
    ramp = linear(2.0, 4.0, start_frame=1000, end_frame=3000)
    expected = {0: 2.0, 999: 2.0, 1000: 2.0, 1500: 2.5, 2000: 3.0, 3000: 4.0, 3001: 4.0, 10**12: 4.0}
    for count, value in expected.items():
        assert float(ramp(frames(count))) == pytest.approx(value, abs=1e-12), count
    vector = linear([0.0, 10.0], [1.0, 0.0], 0, 10)
    assert torch.allclose(vector(frames(5)), torch.tensor([0.5, 5.0], dtype=torch.float64))
    step = linear(0.0, 1.0, 50, 50)
    assert [float(step(frames(c))) for c in (49, 50, 51)] == [0.0, 1.0, 1.0]
    with pytest.raises(ValueError, match="end_frame must be >= start_frame"):
        linear(0.0, 1.0, 10, 5)
    with pytest.raises(ValueError, match="same shape"):
        linear([0.0, 1.0], [1.0, 2.0, 3.0], 0, 10)


def test_staged_takes_the_last_boundary_reached():
    schedule = staged({50_000: 0.5, 0: 0.0, 100_000: 1.0})  # any order
    expected = {0: 0.0, 49_999: 0.0, 50_000: 0.5, 50_001: 0.5, 99_999: 0.5, 100_000: 1.0, 10**10: 1.0}
    for count, value in expected.items():
        assert float(schedule(frames(count))) == value, count
    with pytest.raises(ValueError, match="first boundary must be 0"):
        staged({10: 1.0})


def test_gated_schedule_unit():
    schedule = gated([0.0, 1.0], threshold=0.5, window=1)  # rate 1: the average is the last step's mean
    schedule.observe(torch.tensor([False, False, False]), torch.tensor([1.0, 1.0, 1.0]))  # no episode ended
    assert int(schedule.stage) == 0 and int(schedule.episodes) == 0
    done = torch.tensor([True, True, False])
    schedule.observe(done, torch.tensor([1.0, 0.0, 1.0]))  # the running env's metric does not count
    assert int(schedule.stage) == 1  # mean 0.5 >= 0.5
    schedule.observe(done, torch.tensor([1.0, 1.0, 1.0]))
    assert int(schedule.stage) == 1  # the last stage stays


# --------------------------------------------------------------------------------------------- in an env
def test_the_real_names_of_the_task_trees():
    """The names a Curriculum takes are task.named_buffers()' float buffers (checked on two trees)."""
    quadratic = FinalRewardTask(DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], QuadraticErrorReward([1.0, 0.1], [0.1])))
    names = {name for name, buffer in quadratic.named_buffers() if buffer.is_floating_point()}
    assert {"wrapped_task.reward.Q", "wrapped_task.reward.R", "wrapped_task.state_des", "success_value"} <= names
    names = {name for name, buffer in swing_up_task().named_buffers() if buffer.is_floating_point()}
    assert {"wrapped_task.reward.rewards.track.Q", "wrapped_task.reward.rewards.effort.R"} <= names
    env = make_env({"wrapped_task.reward.Q": constant([2.0, 0.5])}, task=quadratic)
    env.rollout(2)
    assert torch.equal(quadratic.wrapped_task.reward.Q, torch.tensor([2.0, 0.5]))


def test_entries_frames_and_values():
    env = make_env({WEIGHT: linear(0.0, 1.0, 0, 80), "wrapped_task.state_des": constant([0.0, 0.0])})
    data = env.rollout(12, policy())
    counts = torch.arange(1, 13) * BATCH
    assert data["next", "curriculum", "frames"].shape == (BATCH, 12, 1)
    assert data["next", "curriculum", "frames"].dtype == torch.int64
    assert torch.equal(data["next", "curriculum", "frames"][:, :, 0], counts.expand(BATCH, 12))
    assert torch.equal(data["curriculum", "frames"][:, :, 0], (counts - BATCH).expand(BATCH, 12))
    weight = data["next", "curriculum", WEIGHT.replace(".", "/")]
    assert weight.shape == (BATCH, 12, 1) and weight.dtype == torch.float32
    assert torch.allclose(weight[0, :, 0], (counts / 80).clamp(max=1.0).float())
    assert data["curriculum", "wrapped_task/state_des"].shape == (BATCH, 12, 2)
    spec = env.observation_spec
    assert ("curriculum", "frames") in spec.keys(True, True)
    assert ("curriculum", WEIGHT.replace(".", "/")) in spec.keys(True, True)


def test_frames_follow_steps_not_resets():
    """IsaacLab #2079: envs that reset every other step and envs that never reset see the same schedule."""
    schedules = {WEIGHT: linear(0.0, 1.0, 0, 64), "success_value": staged({0: 1.0, 40: 2.0, 80: 3.0})}
    often = make_env(schedules, max_steps=2)
    never = make_env({k: v for k, v in schedules.items()}, max_steps=1000)  # the same schedule objects: stateless
    a = often.rollout(14, policy(), break_when_any_done=False)
    b = never.rollout(14, policy(), break_when_any_done=False)
    assert int(a["next", "done"].sum()) == BATCH * 7 and not bool(b["next", "done"].any())
    for key in (("curriculum", "frames"), ("curriculum", WEIGHT.replace(".", "/")), ("curriculum", "success_value")):
        assert torch.equal(a[("next", *key)], b[("next", *key)]), key
    assert torch.equal(
        a["next", "curriculum", "success_value"][0, :, 0], torch.tensor([1.0] * 4 + [2.0] * 5 + [3.0] * 5)
    )


def test_the_first_episode_and_a_resumed_one_read_the_scheduled_desired_state():
    """A desired state the task copies into the episode's memory at reset: the first episode, and the first of a
    resumed run, are played with the schedule's value at the run's frame count, not the value at construction."""

    def build() -> TransformedEnv:
        task = DesiredStateTask(EnvSpec(1, 1), [0.8], QuadraticErrorReward([1.0], [0.0]))  # never ends
        curriculum = Curriculum({"state_des": linear([0.5], [0.9], 0, 40)})
        return TransformedEnv(WalkEnv([2]), Compose(TaskTransform(task), curriculum))  # x stays 0 with no action

    still = {"action": torch.zeros(2, 1)}
    env = build()
    data = env.rollout(5, lambda td: td.update(still), break_when_any_done=False)
    assert torch.allclose(data["next", "reward"][:, 0, 0], torch.full((2,), -(0.5**2)))  # x = 0, goal 0.5
    env.rollout(5, lambda td: td.update(still), break_when_any_done=False)  # 20 frames: the ramp's middle
    resumed = build()
    resumed.transform.load_state_dict(env.transform.state_dict())
    data = resumed.rollout(1, lambda td: td.update(still), break_when_any_done=False)
    assert torch.allclose(data["next", "reward"][:, 0, 0], torch.full((2,), -(0.7**2)))


def test_the_scheduled_weight_changes_the_reward():
    """The weight ramped 0 -> 1 in the task tree is the one each step's reward was computed with."""
    env = make_env({WEIGHT: linear(0.0, 1.0, 0, 10 * BATCH)})
    data = env.rollout(15, policy())
    weight = data["curriculum", WEIGHT.replace(".", "/")]  # the value in force when the step's reward was computed
    state, action = data["next", "observation"].double(), data["action"].double()
    track = -(state[..., :1] ** 2 + 0.1 * state[..., 1:] ** 2)
    final = 10.0 * data["next", "success"].double()
    expected = track - weight.double() * action**2 + final
    assert torch.allclose(data["next", "reward"].double(), expected, atol=1e-5)
    assert float(weight[0, 0]) == 0.0 and float(weight[0, -1]) == 1.0
    assert bool((action.abs() > 0.05).any())  # the effort term matters in the data
    unweighted = track + final
    assert not torch.allclose(data["next", "reward"].double(), unweighted, atol=1e-3)


def test_a_differentiable_rollout_through_scheduled_buffers():
    """Under grad mode the buffer is replaced, not written into: the graph of earlier steps stays valid."""
    track_q = "wrapped_task.reward.rewards.track.Q"
    env = make_env({WEIGHT: linear(0.0, 1.0, 0, 40), track_q: linear([1.0, 0.1], [2.0, 0.2], 0, 40)})
    torch.manual_seed(0)
    layer = torch.nn.Linear(2, 1)
    # an episode that ends early (a random layer may swing a pendulum into the goal) must not end the rollout
    data = env.rollout(6, TensorDictModule(layer, ["observation"], ["action"]), break_when_any_done=False)
    data["next", "reward"].sum().backward()
    assert layer.weight.grad is not None and bool(torch.isfinite(layer.weight.grad).all())
    assert torch.allclose(data["next", "curriculum", track_q.replace(".", "/")][0, -1], torch.tensor([2.0, 0.2]))


def test_gated_stage_advances_only_after_the_success_average_passes():
    """Success is controlled by a switch the task's success function reads."""
    switch = torch.tensor(False)

    def succeeded(error: torch.Tensor) -> torch.Tensor:
        return switch.expand(error.shape[:-1]).clone()

    task = DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], QuadraticErrorReward([1.0, 0.0]), succeeded)
    batch, window, threshold = 2, 8, 0.8
    curriculum_schedules = {"reward.Q": gated([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]], threshold=threshold, window=window)}
    env = make_env(curriculum_schedules, task=task, max_steps=2, batch=batch)
    curriculum = env.transform[-1]
    td = env.reset()
    for _ in range(20):  # failures only (episodes truncated every 2 steps): the average stays 0
        td = env.step_and_maybe_reset(policy()(td))[1]
    assert int(curriculum.schedules["reward/Q"].stage) == 0 and float(curriculum.schedules["reward/Q"].average) == 0.0
    switch.fill_(True)  # from now on every step ends every episode with a success
    keep = 1.0 - 1.0 / window
    failures = batch * 10  # the episodes that ended (truncated) before: they stay in the average, weighted less

    def average(successes: int) -> float:  # the bias-corrected moving average, in closed form
        return (1.0 - keep**successes) / (1.0 - keep ** (failures + successes))

    needed = next(n for n in range(1, 100) if average(batch * n) >= threshold)
    assert needed > 1
    for n in range(1, needed + 1):
        td = env.step_and_maybe_reset(policy()(td))[1]
        stage = int(curriculum.schedules["reward/Q"].stage)
        assert stage == (1 if n == needed else 0), n
        if n < needed:
            assert float(curriculum.schedules["reward/Q"].average) == pytest.approx(average(batch * n), rel=1e-12)
    assert float(curriculum.schedules["reward/Q"].average) == 0.0  # restarted in the new stage
    assert int(curriculum.schedules["reward/Q"].episodes) == 0
    assert torch.equal(task.reward.Q, torch.tensor([2.0, 0.0]))  # the stage's value is in the task
    assert torch.equal(td["curriculum", "reward/Q"], torch.tensor([[2.0, 0.0]] * batch))
    for _ in range(2 * needed):
        td = env.step_and_maybe_reset(policy()(td))[1]
    assert int(curriculum.schedules["reward/Q"].stage) == 2  # the last stage, where it stays
    assert math.isclose(float(task.reward.Q[0]), 3.0)


def test_a_gated_schedule_on_an_episode_return():
    from torchrl.envs import RewardSum

    env = TransformedEnv(
        PendulumEnv(batch_size=[BATCH], seed=0),
        Compose(
            StepCounter(3),
            TaskTransform(weighted_task()),
            RewardSum(in_keys=[("task_reward", "track")]),
            Curriculum({WEIGHT: gated([0.0, 1.0], metric=("task_reward", "episode_track"), threshold=-1e9, window=1)}),
        ),
    )
    data = env.rollout(3, policy())
    stage = data["next", "curriculum", WEIGHT.replace(".", "/")][0, :, 0]
    assert torch.equal(stage, torch.tensor([0.0, 0.0, 1.0]))  # the first episodes end at step 3
    with pytest.raises(ValueError, match="not in the env's observation spec"):
        make_env({WEIGHT: gated([0.0, 1.0], metric="episode_reward")}).observation_spec  # noqa: B018


def test_a_misspelt_target_lists_the_schedulable_names():
    env = make_env({"wrapped_task.reward.rewards.efort.weight": constant(1.0), "success_value": constant(1.0)})
    with pytest.raises(ValueError, match="unknown target") as error:
        env.reset()
    message = str(error.value)
    assert message.startswith(
        f"Curriculum: unknown target 'wrapped_task.reward.rewards.efort.weight'; did you mean {WEIGHT!r}?"
    )
    for name in (WEIGHT, "wrapped_task.reward.rewards.track.Q", "wrapped_task.state_des", "success_value"):
        assert repr(name) in message
    assert "no_remaining_steps" not in message  # an int buffer is not schedulable


@pytest.mark.parametrize(
    ("target", "schedule", "match"),
    [
        (WEIGHT, linear(0.0, -1.0, 0, 100), r"can write -[\d.]+ into the ControlCostReward's weight, which it refuses"),
        (WEIGHT, staged({0: 0.5, 50: math.inf}), r"can write inf into the ControlCostReward's weight.*must be finite"),
        ("wrapped_task.reward.rewards.track.Q", constant([-1.0, 0.1]), r"can write \[-1.0, 0.1\] into the Quad"),
        (WEIGHT, gated([0.0, 1.0, -2.0], window=4), r"can write -2.0 into the ControlCostReward's weight"),
    ],
    ids=["linear-end", "staged-stage", "constant-Q", "gated-stage"],
)
def test_a_schedule_that_can_write_a_value_the_constructor_refuses_is_refused(target, schedule, match):
    """A negative cost weight would turn a cost into a reward: refused at every value the schedule can take."""
    with pytest.raises(ValueError, match=rf"Curriculum: the schedule of '{re.escape(target)}' {match}"):
        make_env({target: schedule}).reset()
    make_env({target: linear(0.0, 2.0, 0, 100)}).reset()  # values the constructor accepts


def test_a_value_of_the_wrong_shape_names_target_and_shapes():
    env = make_env({"wrapped_task.reward.rewards.track.Q": linear([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 0, 10)})
    with pytest.raises(ValueError, match=r"'wrapped_task\.reward\.rewards\.track\.Q'.*\(3,\).*\(2,\)"):
        env.reset()


def test_placement_is_checked():
    env = TransformedEnv(
        PendulumEnv(batch_size=[2]),
        Compose(StepCounter(5), Curriculum({"success_value": constant(1.0)}), TaskTransform(weighted_task())),
    )
    with pytest.raises(ValueError, match="after TaskTransform"):
        env.reset()
    with pytest.raises(TypeError, match="Schedule"):
        Curriculum({"success_value": 1.0})


def test_state_dict_round_trip():
    def build():
        return make_env(
            {WEIGHT: linear(0.0, 1.0, 0, 400), "success_value": gated([1.0, 2.0, 3.0], window=60)},
            task=weighted_task(success_threshold=100.0),
        )  # every step a success

    env = build()
    env.rollout(6, policy(), break_when_any_done=False)
    state = env.transform[-1].state_dict()
    assert int(state["frames"]) == 6 * BATCH
    gate = "schedules.success_value."  # keyed by target, not by position
    assert {"frames", gate + "stage", gate + "average", gate + "episodes"} <= set(state)
    assert int(state[gate + "episodes"]) == 6 * BATCH and int(state[gate + "stage"]) == 0
    fresh = build()
    fresh.transform[-1].load_state_dict(state)
    assert torch.equal(fresh.transform[-1].frames, torch.tensor(6 * BATCH))
    a = env.rollout(4, policy(), break_when_any_done=False)
    b = fresh.rollout(4, policy(), break_when_any_done=False)  # rollout resets: the same values are written
    for key in (("curriculum", "frames"), ("curriculum", WEIGHT.replace(".", "/")), ("curriculum", "success_value")):
        assert torch.equal(a[("next", *key)], b[("next", *key)]), key
        assert torch.equal(a[key], b[key]), key
    # the gated schedule moved after 60 episodes (step 8), and equally in both
    gates = env.transform[-1].schedules["success_value"], fresh.transform[-1].schedules["success_value"]
    assert int(gates[0].stage) == 1 == int(gates[1].stage)
    assert torch.equal(gates[0].average, gates[1].average)


def test_a_checkpoint_restores_each_schedule_whole():
    """Values, frame boundaries, threshold and window all come from the checkpoint: a schedule edited in the code
    is not mixed with the saved one (the saved values with the edited frames)."""
    saved = {WEIGHT: linear(0.0, 100.0, 0, 400), "success_value": gated([1.0, 2.0], threshold=0.3, window=60)}
    env = make_env(saved, task=weighted_task(success_threshold=100.0))
    env.rollout(3, policy(), break_when_any_done=False)
    edited = {WEIGHT: linear(0.0, 200.0, 0, 4000), "success_value": gated([5.0, 6.0], threshold=0.9, window=7)}
    resumed = make_env(edited, task=weighted_task(success_threshold=100.0))
    resumed.transform[-1].load_state_dict(torch.load(_saved(env.transform[-1].state_dict()), weights_only=True))
    ramp, gate = resumed.transform[-1].schedules.values()
    assert (float(ramp.end_value), ramp.start_frame, ramp.end_frame) == (100.0, 0, 400)
    assert (gate.values.tolist(), gate.threshold, gate.window) == ([1.0, 2.0], 0.3, 60)
    assert float(gate.keep) == 1.0 - 1.0 / 60
    frames = torch.tensor(3 * BATCH)
    assert torch.equal(ramp(frames), saved[WEIGHT](frames))
    with pytest.raises(ValueError, match="end_frame must be >= start_frame"):
        ramp.set_extra_state({"start_frame": 10, "end_frame": 5})
    # as a multi-process collector gathers the workers' state dicts (numbers as 0-d tensors): the same numbers
    gate.set_extra_state({key: torch.as_tensor(value) for key, value in gate.get_extra_state().items()})
    assert (gate.threshold, gate.window) == (0.3, 60) and type(gate.window) is int


def _saved(state: dict) -> io.BytesIO:
    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    return buffer


def test_a_collector_checkpoint_resumes_the_curriculum():
    """Collector.state_dict() saves the env's transforms, so the Curriculum's frames and gated stage; a fresh
    collector that loads it continues the schedules exactly where an uninterrupted one goes on."""

    def collector() -> Collector:
        task = weighted_task(success_threshold=100.0)  # every step ends every episode with a success
        schedules = {WEIGHT: linear(0.0, 1.0, 0, 20 * 32), "success_value": gated([0.0, 10.0, 20.0, 30.0], window=200)}
        return Collector(
            make_env(schedules, task=task, max_steps=50), policy(), frames_per_batch=4 * BATCH, total_frames=-1
        )

    running = collector()
    batches = iter(running)
    for _ in range(12):
        next(batches)
    buffer = io.BytesIO()
    torch.save(running.state_dict(), buffer)
    buffer.seek(0)
    saved = torch.load(buffer)
    assert int(saved["env_state_dict"]["transforms.2.frames"]) == 12 * 4 * BATCH
    assert "transforms.2.schedules.success_value.stage" in saved["env_state_dict"]
    fresh = collector()  # a new collector and env, as in a new process
    fresh.load_state_dict(saved)
    fresh.reset()  # a loaded collector starts fresh trajectories: the reset writes the restored values at the root
    expected = next(batches)
    resumed = next(iter(fresh))
    keys = [("curriculum", "frames"), ("curriculum", WEIGHT.replace(".", "/")), ("curriculum", "success_value")]
    for key in keys:
        assert torch.equal(expected[("next", *key)], resumed[("next", *key)]), key
        assert torch.equal(expected[key], resumed[key]), key
    # the gated stage went up during the run and the next batch continues from it
    assert float(expected["curriculum", "success_value"].min()) > 0.0
    assert int(expected["next", "curriculum", "frames"].max()) == 13 * 4 * BATCH
    running.shutdown()
    fresh.shutdown()


# ------------------------------------------------------------------------------------------ the cheap step
def assert_forwards_values(env: TransformedEnv, schedules: dict, dtype: torch.dtype, steps: int = 30) -> None:
    """Every entry of a rollout and the buffers after it equal forward() at the entry's count, cast to ``dtype``."""
    data = env.rollout(steps, policy())
    batch = env.batch_size[0]
    counts = data["next", "curriculum", "frames"][0, :, 0]
    assert torch.equal(counts, torch.arange(1, steps + 1) * batch)
    for target, schedule in schedules.items():
        entry = data["next", "curriculum", target.replace(".", "/")]
        for t, count in enumerate(counts.tolist()):
            expected = schedule(frames(count)).to(dtype).expand(entry.shape[2:])
            assert torch.equal(entry[:, t], expected.expand(batch, *expected.shape)), (target, t)
        buffer = env.transform[1].task.get_buffer(target)
        assert torch.equal(buffer, schedule(frames(steps * batch)).to(dtype).expand_as(buffer)), target


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["float64", "float32"])
def test_the_host_evaluated_values_are_forwards_bit_for_bit(dtype):
    """Frame-driven schedules are evaluated on the host in a step: every entry and the buffers equal forward() at the
    entry's frame count, cast to the env's dtype, exactly, on counts that round (a batch of 7, odd ramp spans);
    scalars, one-element values (the swing-up task's effort weight R, shape [1]) and vectors."""
    schedules = {
        WEIGHT: linear(0.1, 0.7, start_frame=3, end_frame=1001),
        "success_value": staged({0: 0.3, 50: 1.0 / 3.0, 100: 2.0 / 7.0}),
        "wrapped_task.reward.rewards.track.Q": linear([1.0, 0.1], [1.0 / 3.0, 0.7], 10, 10 + 7 * 11),
        "wrapped_task.state_des": constant([0.1, -0.2]),
        "failure_value": linear(0.0, -1.0, 70, 70),  # a step at frame 70
    }
    assert_forwards_values(make_env(schedules, batch=7, dtype=dtype), schedules, dtype)
    effort = "wrapped_task.reward.rewards.effort.R"
    for schedule in (linear([0.1], [1.0 / 3.0], 3, 1001), staged({0: [0.3], 50: [2.0 / 7.0]}), constant([1.0 / 3.0])):
        env = make_env({effort: schedule}, task=swing_up_task(), batch=7, dtype=dtype)
        assert_forwards_values(env, {effort: schedule}, dtype)


def test_whatever_else_writes_the_counter_or_a_buffer_is_written_over():
    """A write by anyone else (a user's fill_, load_state_dict) into the frame counter, a scheduled buffer or a
    schedule's parameters is noticed: the next step counts on from the buffer and writes the schedule's value."""
    env = make_env({WEIGHT: constant(0.5)})
    curriculum, task = env.transform[-1], env.transform[1].task
    td = env.reset()
    td = env.step_and_maybe_reset(policy()(td))[1]
    task.get_buffer(WEIGHT).fill_(3.0)
    data, td = env.step_and_maybe_reset(policy()(td))
    assert float(task.get_buffer(WEIGHT)) == 0.5 and bool(
        (data["next", "curriculum", WEIGHT.replace(".", "/")] == 0.5).all()
    )
    curriculum.frames.fill_(1000)
    data, td = env.step_and_maybe_reset(policy()(td))
    assert bool((data["next", "curriculum", "frames"] == 1000 + BATCH).all())
    state = curriculum.state_dict()
    state["frames"] = torch.tensor(5000)
    # a different constant, same host state
    state[f"schedules.{WEIGHT.replace('.', '/')}.value"] = torch.tensor(0.25, dtype=torch.float64)
    curriculum.load_state_dict(state)
    data, td = env.step_and_maybe_reset(policy()(td))
    assert bool((data["next", "curriculum", "frames"] == 5000 + BATCH).all())
    assert float(task.get_buffer(WEIGHT)) == 0.25 and bool(
        (data["next", "curriculum", WEIGHT.replace(".", "/")] == 0.25).all()
    )


def test_entries_of_earlier_steps_keep_their_values():
    """An unchanged value puts the same entry tensor in the data (no new tensor per step); a new value gets a new
    tensor, so the data of earlier steps, held until the end (as env.rollout does), keep theirs; an entry someone
    wrote into is not handed out again."""
    env = make_env({"success_value": staged({0: 1.0, 3 * BATCH: 2.0})})
    td = env.reset()
    steps = []
    for _ in range(5):
        data, td = env.step_and_maybe_reset(policy()(td))
        steps.append(data)
    key = ("next", "curriculum", "success_value")
    assert [float(step[key][0, 0]) for step in steps] == [1.0, 1.0, 2.0, 2.0, 2.0]
    assert steps[0][key] is steps[1][key] and steps[2][key] is steps[4][key]
    steps[4][key].zero_()  # a user writes into the entry of the last step
    data, td = env.step_and_maybe_reset(policy()(td))
    assert bool((data[key] == 2.0).all()) and float(steps[1][key][0, 0]) == 1.0


# ----------------------------------------------------------------------------------------------- workers
def test_workers_multiply_the_frame_count():
    """workers=3: each step counts three copies of the env's batch (a linear ramp follows the global count)."""
    env = make_env({WEIGHT: linear(0.0, 1.0, 0, 3 * 10 * BATCH)}, workers=3)
    data = env.rollout(12, policy())
    counts = torch.arange(1, 13) * 3 * BATCH
    assert torch.equal(data["next", "curriculum", "frames"][0, :, 0], counts)
    assert torch.equal(
        data["next", "curriculum", WEIGHT.replace(".", "/")][0, :, 0], (counts / (30 * BATCH)).clamp(max=1.0)
    )
    assert env.transform[-1].workers == 3 and int(env.transform[-1].frames) == 12 * 3 * BATCH
    with pytest.raises(ValueError, match="workers"):
        Curriculum({"success_value": constant(1.0)}, workers=0)
    for wrong in (2.0, True, "2"):
        with pytest.raises(TypeError, match="workers"):
            Curriculum({"success_value": constant(1.0)}, workers=wrong)


def test_a_gated_schedule_gates_on_its_own_episodes_whatever_the_workers():
    """workers scales the frame count only: a gated stage advances after the same episodes of this copy's envs."""

    def stages(workers: int) -> torch.Tensor:
        schedules = {"success_value": gated([1.0, 2.0, 3.0], threshold=0.5, window=3 * BATCH)}
        env = make_env(schedules, task=weighted_task(success_threshold=100.0), max_steps=2, workers=workers)
        return env.rollout(12, policy(), break_when_any_done=False)["next", "curriculum", "success_value"][0, :, 0]

    single = stages(1)
    assert torch.equal(single, torch.tensor([1.0] * 2 + [2.0] * 3 + [3.0] * 7))  # every episode one step long
    assert torch.equal(stages(3), single)


class ZeroTorque(torch.nn.Module):
    """The workers' policy (a module: picklable, no autograd state)."""

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return torch.zeros(*observation.shape[:-1], 1, dtype=observation.dtype)


WORKER_BATCH, WORKER_STEPS, BATCHES = 4, 6, 2
WORKER_TARGETS = ("success_value", "wrapped_task.reward.rewards.effort.R")


def worker_env(batch: int, workers: int) -> TransformedEnv:
    """The swing-up pendulums with a ramped success bonus and a staged effort weight over a 2-worker run's frames."""
    frames_per_step = 2 * WORKER_BATCH
    schedules = {
        "success_value": linear(0.0, 100.0, 0, frames_per_step * 10),
        "wrapped_task.reward.rewards.effort.R": staged({0: [0.0], frames_per_step * 3: [0.001]}),
    }
    return TransformedEnv(
        PendulumEnv(batch_size=[batch], seed=0),
        Compose(StepCounter(4), TaskTransform(swing_up_task()), Curriculum(schedules, workers=workers)),
    )


def collect(collector) -> list:
    try:
        return [batch.clone() for batch in collector]
    finally:
        collector.shutdown()


def single_process_batches() -> list:
    """One env of 2 x WORKER_BATCH pendulums in one process: the reference schedule, per step."""
    frames_per_batch = 2 * WORKER_BATCH * WORKER_STEPS
    env = worker_env(2 * WORKER_BATCH, workers=1)
    policy = TensorDictModule(ZeroTorque(), ["observation"], ["action"])
    return collect(Collector(env, policy, frames_per_batch=frames_per_batch, total_frames=BATCHES * frames_per_batch))


def assert_same_schedule(batches: list, reference: list) -> None:
    """Every worker's data ``[2, B, T]`` hold, at every step, the entries of the single process's step."""
    assert len(batches) == len(reference) == BATCHES
    names = ["frames", *(target.replace(".", "/") for target in WORKER_TARGETS)]
    for batch, expected in zip(batches, reference, strict=True):
        assert batch.shape == (2, WORKER_BATCH, WORKER_STEPS)
        for key in [(*prefix, "curriculum", name) for prefix in ((), ("next",)) for name in names]:
            assert torch.equal(batch[key], expected[key].reshape(batch[key].shape)), key
    counts = torch.cat([b["next", "curriculum", "frames"][0, 0, :, 0] for b in batches])
    assert torch.equal(counts, torch.arange(1, BATCHES * WORKER_STEPS + 1) * 2 * WORKER_BATCH)  # the global count


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
def test_a_parallel_env_of_two_workers_sees_the_single_process_schedule():
    frames_per_batch = 2 * WORKER_BATCH * WORKER_STEPS
    env = ParallelEnv(2, functools.partial(worker_env, WORKER_BATCH, 2), mp_start_method="fork")
    policy = TensorDictModule(ZeroTorque(), ["observation"], ["action"])
    batches = collect(
        Collector(env, policy, frames_per_batch=frames_per_batch, total_frames=BATCHES * frames_per_batch)
    )
    assert_same_schedule(batches, single_process_batches())


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
def test_a_multi_sync_collector_of_two_workers_sees_the_single_process_schedule(fork_start_method):
    frames_per_batch = 2 * WORKER_BATCH * WORKER_STEPS
    policy = TensorDictModule(ZeroTorque(), ["observation"], ["action"])
    collector = MultiSyncCollector(
        [functools.partial(worker_env, WORKER_BATCH, 2)] * 2,
        policy,
        frames_per_batch=frames_per_batch,
        total_frames=BATCHES * frames_per_batch,
    )
    assert_same_schedule(collect(collector), single_process_batches())


# ------------------------------------------------------------------------------------------ goal ranges
GOAL_SPACE = Box([-1.0, -0.5], [1.0, 0.5])  # the goal spec: the widest range a schedule may reach


def goal_env(schedules, *, command=None, max_steps: int = 5, batch: int = BATCH, between: tuple = ()) -> TransformedEnv:
    """A pendulum tracking a goal state drawn by a GoalCommand whose range the Curriculum schedules (``between``:
    transforms placed between the Curriculum and the GoalCommand)."""
    near = functools.partial(proximity_succeeded, threshold=0.1)
    task = DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], QuadraticErrorReward([1.0, 0.1]), near)
    command = command if command is not None else GoalCommand(GOAL_SPACE, resample_steps=1, seed=0)
    return TransformedEnv(
        PendulumEnv(batch_size=[batch], seed=0, dtype=torch.float64),
        Compose(StepCounter(max_steps), TaskTransform(task, goal_key="goal"), Curriculum(schedules), *between, command),
    )


@pytest.mark.parametrize("between", ["RewardSum", "DifficultyLevels"])
def test_transforms_between_the_curriculum_and_its_command(between: str) -> None:
    """Other transforms may sit between a Curriculum and the GoalCommand it schedules (TorchRL's view of a later
    transform's parent env holds a clone of the Curriculum without the command: it answers for the original)."""
    from torchrl.envs import RewardSum

    from torchtasks.transforms import DifficultyLevels

    middle = RewardSum() if between == "RewardSum" else DifficultyLevels(2)  # levels without a target
    env = goal_env({"command.high": linear([0.1, 0.05], [1.0, 0.5], 0, 40 * BATCH)}, between=(middle,))
    data = env.rollout(4, policy(), break_when_any_done=False)
    high = data["next", "curriculum", "command/high"]
    assert (data["next", "goal"] <= high).all() and high[0, -1, 0] > 0.1


def test_a_widening_goal_range_bounds_every_goal_drawn():
    """high widens from 0.1 to 1.0 (and low from -0.05 to -0.5 on the second entry) over N frames; goals are
    drawn at every reset and every step, each within the range of the frame count it was drawn at."""
    n = 40 * BATCH
    schedules = {
        "command.high": linear([0.1, 0.05], [1.0, 0.5], 0, n),
        "command.low": linear([-0.1, -0.05], [-1.0, -0.5], 0, n),
    }
    data = goal_env(schedules).rollout(60, policy(), break_when_any_done=False)
    assert int(data["next", "done"].sum()) == BATCH * 12  # episodes of 5 steps: goals drawn at resets too
    for prefix in ((), ("next",)):
        count = data[(*prefix, "curriculum", "frames")].double()  # [B, T, 1]
        fraction = (count / n).clamp(0.0, 1.0)  # the schedule's formula, recomputed here
        high = torch.tensor([0.1, 0.05], dtype=torch.float64) + fraction * torch.tensor(
            [0.9, 0.45], dtype=torch.float64
        )
        low = torch.tensor([-0.1, -0.05], dtype=torch.float64) + fraction * torch.tensor(
            [-0.9, -0.45], dtype=torch.float64
        )
        goal = data[(*prefix, "goal")]
        assert ((goal >= low - 1e-12) & (goal <= high + 1e-12)).all(), prefix
        torch.testing.assert_close(data[(*prefix, "curriculum", "command/high")], high, rtol=0, atol=1e-12)
        torch.testing.assert_close(data[(*prefix, "curriculum", "command/low")], low, rtol=0, atol=1e-12)
    goal, count = data["next", "goal"], data["next", "curriculum", "frames"][..., 0]
    early = goal[..., 0][count <= 4 * BATCH].abs()  # within 0.1 + 0.9 * 4 / 40 = 0.19
    assert bool((goal[..., 0] > 0.5).any()) and bool((early <= 0.19 + 1e-12).all()) and bool((early > 0.1).any())
    assert bool((data["next", "goal"] != data["goal"]).all())  # a new goal at every step
    command = goal_env(schedules).transform[-1]
    assert torch.equal(command.low, GOAL_SPACE.low) and torch.equal(command.high, GOAL_SPACE.high)  # before a reset


def test_the_qualified_command_name_and_scalar_values():
    env = goal_env({"command.goal.high": staged({0: 0.2, 3 * BATCH: 0.4})})
    data = env.rollout(4, policy())
    high = data["next", "curriculum", "command/goal/high"]
    assert high.shape == (BATCH, 4, 1)  # a scalar value, as every scalar schedule's entry
    assert torch.equal(high[0, :, 0], torch.tensor([0.2, 0.2, 0.4, 0.4], dtype=torch.float64))
    assert torch.equal(env.transform[-1].high, torch.tensor([0.4, 0.4], dtype=torch.float64))
    assert (data["next", "goal"] <= high).all()


def test_misspelt_and_ambiguous_command_names():
    with pytest.raises(ValueError, match="unknown target") as error:
        goal_env({"command.hihg": constant(0.5)}).reset()
    for name in ("command.low", "command.high", "reward.Q", "state_des"):
        assert repr(name) in str(error.value), name
    second = GoalCommand(Box([0.0], [1.0]), goal_key="other_goal")
    env = goal_env({"command.high": constant(0.5)})
    env.append_transform(second)
    with pytest.raises(ValueError, match="ambiguous") as error:
        env.reset()
    assert "'command.goal.high'" in str(error.value) and "'command.other_goal.high'" in str(error.value)
    sampler = GoalCommand(lambda shape, generator: torch.zeros(*shape, 2), goal_size=2)
    with pytest.raises(ValueError, match="unknown target"):  # a sampler has no range buffers
        goal_env({"command.high": constant(0.5)}, command=sampler).reset()


def test_a_scheduled_range_with_low_above_high_is_refused():
    cases = {
        # the ramps cross: low reaches 0.4 at frame 100, where high starts from 0.1
        "linear": {"command.low": linear(0.0, 0.4, 0, 100), "command.high": linear(0.1, 0.5, 100, 200)},
        # a staged low jumps to 0.5 at frame 50, where the linear high is 0.2
        "staged": {"command.low": staged({0: -0.1, 50: 0.5}), "command.high": linear(0.1, 0.5, 0, 200)},
        # constant values: 0.3 > 0.2 on the second entry
        "constant": {"command.low": constant([0.0, 0.3]), "command.high": constant([0.5, 0.2])},
        # a gated stage may be reached at any frame: low's 0.3 against high's 0.2
        "gated": {"command.low": gated([-0.1, 0.3]), "command.high": gated([0.2, 0.5])},
    }
    for name, schedules in cases.items():
        with pytest.raises(ValueError, match="low > high") as error:
            goal_env(schedules).reset()
        assert "'command.low'" in str(error.value), name
    goal_env({"command.low": gated([-0.1, -0.3]), "command.high": gated([0.2, 0.4])}).reset()  # valid: accepted
    goal_env({"command.low": linear(0.0, -0.4, 0, 10), "command.high": linear(0.05, 0.4, 5, 10)}).reset()
    with pytest.raises(ValueError, match=r"'command\.high' leaves the GoalCommand's space"):
        goal_env({"command.high": linear(0.1, 2.0, 0, 100)}).reset()
    with pytest.raises(ValueError, match=r"shape \(3,\)"):
        goal_env({"command.high": constant([0.1, 0.1, 0.1])}).reset()


def test_the_curriculum_must_come_before_the_command_it_schedules():
    near = functools.partial(proximity_succeeded, threshold=0.1)
    task = DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], QuadraticErrorReward([1.0, 0.1]), near)
    env = TransformedEnv(
        PendulumEnv(batch_size=[2]),
        Compose(
            StepCounter(5),
            TaskTransform(task, goal_key="goal"),
            GoalCommand(GOAL_SPACE),
            Curriculum({"command.high": constant(0.5)}),
        ),
    )
    with pytest.raises(ValueError, match="before that GoalCommand"):
        env.reset()


def test_overhead_benchmark_script_runs(tmp_path) -> None:
    """``benchmarks/curriculum_overhead.py`` on a tiny case: both pipelines measured, the results written."""
    import importlib.util
    import json

    from repo_paths import ROOT

    spec = importlib.util.spec_from_file_location("curriculum_overhead", ROOT / "benchmarks" / "curriculum_overhead.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    threads = torch.get_num_threads()
    assert module.main(["--envs", "4", "--repeats", "1", "--batches", "1", "--output", str(tmp_path)]) == 0
    assert torch.get_num_threads() == threads
    results = json.loads((tmp_path / "results.json").read_text())
    assert set(results["medians"]) == {"task", "curriculum", "entries"} and all(
        v > 0 for v in results["medians"].values()
    )
    assert results["ratio"] == results["medians"]["curriculum"] / results["medians"]["task"]
    entries = {name: module.make_env(4, name).observation_spec["curriculum"] for name in ("curriculum", "entries")}
    assert entries["entries"] == entries["curriculum"]  # the floor carries the Curriculum's entries exactly


@pytest.mark.mujoco
def test_a_term_named_like_a_module_method_can_be_scheduled():
    """The locomotion presets' ``forward`` term (``nn.Module.forward`` is a method): found by key, not attribute."""
    from torchtasks.envs import gymnasium_env

    env = gymnasium_env("HalfCheetah-v5", num_envs=2, backend="batched")
    env.append_transform(Curriculum({"reward.rewards.forward.weight": linear(0.0, 1.0, 0, 100)}))
    data = env.rollout(3)
    assert data["curriculum", "reward/rewards/forward/weight"][0, :, 0].tolist() == [0.0, 0.02, 0.04]
