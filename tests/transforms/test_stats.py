"""episode_statistics on data collected with TorchRL equals the same statistics counted by hand.

The env is a batch of pendulums with a desired-state task whose episodes end by success (near upright),
failure (the angle leaves ±0.9) and truncation (StepCounter(8)) at different steps. Every statistic is
checked against a plain Python loop over envs and time that reads the raw flags and rewards.
"""

from __future__ import annotations

import csv
import functools
import math
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.collectors.utils import split_trajectories
from torchrl.envs import Compose, InitTracker, RewardSum, StepCounter, TransformedEnv
from torchrl.record import CSVLogger

from torchtasks.envs import PendulumEnv, PointMassEnv
from torchtasks.rewards import CompoundReward, ConstantReward, QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.stats import episode_statistics
from torchtasks.tasks import DesiredStateTask, FinalRewardTask, MaskedTask, proximity_succeeded
from torchtasks.transforms import Curriculum, GoalCommand, linear

MAX_STEPS = 8
TERMS = ("step", "final", "track", "effort")
GOAL = ("task", "wrapped", "state_des")  # the task's desired state, in its memory


def make_task() -> FinalRewardTask:
    reward = CompoundReward(
        {"track": QuadraticErrorReward([1.0, 0.1], None), "effort": QuadraticErrorReward([0.0, 0.0], [0.01])}
    )
    success = functools.partial(proximity_succeeded, threshold=0.2, dims=0)
    inner = DesiredStateTask(EnvSpec(Box([-0.9, -8.5], [0.9, 8.5]), 1), [0.0, 0.0], reward, success=success)
    return FinalRewardTask(inner, factor=5)


def make_env(batch_size=(8,), *extra, seed: int = 1) -> TransformedEnv:
    from torchtasks.transforms import TaskTransform

    base = PendulumEnv(batch_size=list(batch_size), init_angle=0.6, init_speed=1.5, seed=seed)
    return TransformedEnv(base, Compose(StepCounter(MAX_STEPS), TaskTransform(make_task()), *extra))


def rollout(batch_size=(8,), steps: int = 40, *extra, seed: int = 1) -> TensorDictBase:
    env = make_env(batch_size, *extra, seed=seed)
    torch.manual_seed(seed)  # the random policy's actions
    return env.rollout(steps, break_when_any_done=False)


@pytest.fixture(scope="module")
def data() -> TensorDictBase:
    return rollout()


@pytest.fixture(scope="module")
def collector_batches() -> list[TensorDictBase]:
    """Batches of [8 envs, 5 frames] from a Collector: all but the first start in the middle of episodes."""
    threads = torch.get_num_threads()
    torch.manual_seed(2)
    collector = Collector(functools.partial(make_env, (8,), InitTracker()), None, frames_per_batch=40, total_frames=320)
    try:
        batches = [batch.clone() for batch in collector]
    finally:
        collector.shutdown()
        torch.set_num_threads(threads)
    return batches


# --------------------------------------------------------------------------------------------------
# The independent count: a Python loop over envs and time
# --------------------------------------------------------------------------------------------------


def _item(data: TensorDictBase, key, e: int, t: int):
    return data.get(key)[e, t].reshape(-1).tolist()


def reference_statistics(data: TensorDictBase, *, use_step_count: bool = True, goal=None) -> dict[str, float]:
    """Count episodes of ``[*envs, time]`` data frame by frame.

    An episode's start is in the batch after a done frame of the same env, or at the first frame when the
    root step count is 0 (``use_step_count``) or ``is_init`` is set. Its length is the step count at its
    last frame (``use_step_count``), else the number of its frames.
    """
    data = data.reshape(-1, data.shape[-1])
    envs, steps = data.shape
    ended = []
    for e in range(envs):
        known_start = False
        if use_step_count:
            known_start = data["step_count"][e, 0].item() == 0
        if "is_init" in data.keys():
            known_start = known_start or bool(data["is_init"][e, 0].item())
        returns = dict.fromkeys(("reward", *TERMS), 0.0)
        frames = 0
        for t in range(steps):
            frames += 1
            returns["reward"] += data["next", "reward"][e, t].item()
            for term in TERMS:
                returns[term] += data["next", "task_reward", term][e, t].item()
            if not data["next", "done"][e, t].item():
                continue
            episode = {flag: bool(data["next", flag][e, t].item()) for flag in ("success", "failure")}
            episode.update({flag: bool(data["next", flag][e, t].item()) for flag in ("terminated", "truncated")})
            episode["length"] = data["next", "step_count"][e, t].item() if use_step_count else frames
            episode["complete"] = known_start
            episode["returns"] = dict(returns)
            if goal is not None:  # the goal at the root (the one that judged the step), the achieved one after it
                episode["distance"] = math.dist(_item(data, goal[0], e, t), _item(data, ("next", goal[1]), e, t))
            ended.append(episode)
            known_start, frames, returns = True, 0, dict.fromkeys(returns, 0.0)

    def mean(values):
        values = list(values)
        return sum(values) / len(values)

    complete = [episode for episode in ended if episode["complete"]]
    stats = {"episodes": float(len(ended)), "complete_episodes": float(len(complete))}
    if not ended:
        return stats
    stats["success_rate"] = mean(ep["success"] for ep in ended)
    stats["failure_rate"] = mean(ep["failure"] for ep in ended)
    by_task = [ep["success"] or ep["failure"] for ep in ended]
    stats["timeout_rate"] = mean(
        ep["truncated"] and not ep["terminated"] and not task for ep, task in zip(ended, by_task, strict=True)
    )
    stats["env_termination_rate"] = mean(ep["terminated"] and not task for ep, task in zip(ended, by_task, strict=True))
    lengths = ended if use_step_count else complete
    if lengths:
        stats["episode_length_mean"] = mean(ep["length"] for ep in lengths)
    if complete:
        stats["return_mean"] = mean(ep["returns"]["reward"] for ep in complete)
        for term in TERMS:
            stats[f"return_mean/{term}"] = mean(ep["returns"][term] for ep in complete)
    if goal is not None:
        stats["final_goal_distance_mean"] = mean(ep["distance"] for ep in ended)
    return stats


def assert_same(got: dict[str, float], want: dict[str, float]) -> None:
    assert list(got) == list(want) or set(got) == set(want), f"keys {sorted(got)} != {sorted(want)}"
    assert all(type(value) is float and math.isfinite(value) for value in got.values()), got
    assert got == pytest.approx(want, rel=1e-9, abs=1e-9)


# --------------------------------------------------------------------------------------------------
# env.rollout
# --------------------------------------------------------------------------------------------------


def test_all_three_endings_occur_at_different_steps(data: TensorDictBase) -> None:
    nxt = data["next"]
    done = nxt["done"]
    timeout = nxt["truncated"] & ~nxt["terminated"]
    for flag in (nxt["success"], nxt["failure"], timeout):
        assert flag.any()
        assert flag.sum() < done.sum()
    lengths = {
        ending: set(nxt["step_count"][flag & done].tolist())
        for ending, flag in (("success", nxt["success"]), ("failure", nxt["failure"]))
    }
    assert len(lengths["success"]) > 1 and len(lengths["failure"]) > 1
    assert set(nxt["step_count"][timeout].tolist()) == {MAX_STEPS}


def test_rollout_matches_the_loop(data: TensorDictBase) -> None:
    stats = episode_statistics(data)
    assert_same(stats, reference_statistics(data))
    # the rollout starts at reset: every episode that ends in it is complete, and the outcomes partition them
    assert stats["episodes"] == stats["complete_episodes"] > 10
    assert min(stats["success_rate"], stats["failure_rate"], stats["timeout_rate"]) > 0
    assert stats["env_termination_rate"] == 0.0
    total = stats["success_rate"] + stats["failure_rate"] + stats["timeout_rate"]
    assert total == pytest.approx(1.0)
    assert set(stats) >= {f"return_mean/{term}" for term in TERMS}


def test_goal_distance(data: TensorDictBase) -> None:
    stats = episode_statistics(data, goal_key=GOAL, achieved_goal_key="observation")
    assert_same(stats, reference_statistics(data, goal=(GOAL, "observation")))
    # the goal is read at the root and the achieved goal under "next", never the other way round
    with pytest.raises(KeyError, match=r"goal_key=.*looked at the root"):
        episode_statistics(data.exclude(GOAL), goal_key=GOAL, achieved_goal_key="observation")
    with pytest.raises(KeyError, match=r"achieved_goal_key='observation'.*looked under 'next'"):
        episode_statistics(data.exclude(("next", "observation")), goal_key=GOAL, achieved_goal_key="observation")
    # a ("next", ...) key is read as written (here the memory after the step holds the same desired state)
    after = episode_statistics(data.exclude(GOAL), goal_key=("next", *GOAL), achieved_goal_key=("next", "observation"))
    assert after == stats


def test_several_env_dims_and_time_dim(data: TensorDictBase) -> None:
    grid = rollout((2, 3), 30)
    assert grid.shape == (2, 3, 30)
    assert_same(episode_statistics(grid), reference_statistics(grid))
    time_first = data.permute(1, 0).contiguous()
    assert time_first.shape == (40, 8)
    assert_same(episode_statistics(time_first, time_dim=0), episode_statistics(data))
    assert_same(episode_statistics(time_first, time_dim=-2), episode_statistics(data))
    single = data[3]  # one env's time series
    assert_same(episode_statistics(single), reference_statistics(single.unsqueeze(0)))


def test_reward_sum_changes_nothing(data: TensorDictBase) -> None:
    summed = rollout((8,), 40, RewardSum(in_keys=None))
    assert ("next", "task_reward", "episode_track") in summed.keys(True, True)
    assert (summed["next", "reward"] == data["next", "reward"]).all()  # same seeds, same data
    assert episode_statistics(summed) == episode_statistics(data)


def test_no_episode_ended(data: TensorDictBase) -> None:
    first = data[:, :1]
    quiet = first[~first["next", "done"][:, 0, 0]]
    assert quiet.numel() > 0
    assert episode_statistics(quiet) == {"episodes": 0.0, "complete_episodes": 0.0}
    assert episode_statistics(quiet, goal_key=GOAL, achieved_goal_key="observation") == {
        "episodes": 0.0,
        "complete_episodes": 0.0,
    }


# --------------------------------------------------------------------------------------------------
# Collector batches: episodes that started before the batch
# --------------------------------------------------------------------------------------------------


def test_collector_batches_match_the_loop(collector_batches: list[TensorDictBase]) -> None:
    assert [batch.shape for batch in collector_batches] == [torch.Size([8, 5])] * 8
    partial = 0
    for batch in collector_batches:
        stats = episode_statistics(batch)
        assert_same(stats, reference_statistics(batch))
        # split_trajs=True layout: one trajectory per row, zero-padded (pads come after the done frame)
        assert_same(episode_statistics(split_trajectories(batch)), stats)
        partial += stats["episodes"] - stats["complete_episodes"]
    assert partial > 0  # some episodes started before their batch: counted in the rates, not in the returns


def test_collector_batches_count_each_episode_once(collector_batches: list[TensorDictBase]) -> None:
    whole = torch.cat(collector_batches, dim=-1)
    assert whole.shape == (8, 40)
    per_batch = [episode_statistics(batch) for batch in collector_batches]
    total = episode_statistics(whole)
    assert sum(stats["episodes"] for stats in per_batch) == total["episodes"]
    for rate in ("success_rate", "failure_rate", "timeout_rate", "episode_length_mean"):
        weighted = sum(stats["episodes"] * stats.get(rate, 0.0) for stats in per_batch) / total["episodes"]
        assert weighted == pytest.approx(total[rate])
    assert_same(total, reference_statistics(whole))


def test_collector_batches_without_step_counts(collector_batches: list[TensorDictBase]) -> None:
    """Without step counts, starts come from InitTracker's is_init or a done frame before them."""
    for batch in collector_batches:
        with_counts = episode_statistics(batch)
        bare = batch.exclude("step_count", ("next", "step_count"))
        assert_same(episode_statistics(bare), reference_statistics(bare, use_step_count=False))
        assert episode_statistics(bare)["complete_episodes"] == with_counts["complete_episodes"]
        neither = bare.exclude("is_init", ("next", "is_init"))
        stats = episode_statistics(neither)
        assert_same(stats, reference_statistics(neither, use_step_count=False))
        # the first episode of each env is never complete without evidence of its start
        assert stats["episodes"] == with_counts["episodes"]
        assert stats["complete_episodes"] <= with_counts["complete_episodes"]
    first = collector_batches[0].exclude("step_count", ("next", "step_count"), "is_init", ("next", "is_init"))
    assert (
        episode_statistics(first)["complete_episodes"] < episode_statistics(collector_batches[0])["complete_episodes"]
    )


def test_flat_collector_batch(collector_batches: list[TensorDictBase]) -> None:
    """A flat [N] batch is grouped by the collector's trajectory ids: same numbers, whatever the frame order."""
    generator = torch.Generator().manual_seed(0)
    holes = 0
    for batch in collector_batches:
        flat = batch.reshape(-1)
        assert ("collector", "traj_ids") in flat.keys(True)
        assert_same(episode_statistics(flat), episode_statistics(batch))
        shuffled = flat[torch.randperm(flat.shape[0], generator=generator)]
        assert_same(episode_statistics(shuffled), episode_statistics(batch))
        # a frame missing from a complete episode makes it incomplete (the step count tells)
        traj_ids, lengths = flat["collector", "traj_ids"], flat["next", "step_count"].squeeze(-1)
        for end in flat["next", "done"].squeeze(-1).nonzero().squeeze(-1).tolist():
            frames = int((traj_ids == traj_ids[end]).sum())
            if lengths[end] >= 2 and frames == lengths[end]:
                holey = torch.cat([flat[: end - 1], flat[end:]])
                stats = episode_statistics(holey)
                assert stats["complete_episodes"] == episode_statistics(flat)["complete_episodes"] - 1
                assert stats["episodes"] == episode_statistics(flat)["episodes"]
                holes += 1
    assert holes > 0


# --------------------------------------------------------------------------------------------------
# Goals from a GoalCommand: the final distance is to the goal that judged the last step
# --------------------------------------------------------------------------------------------------

GOAL_RADIUS = 0.1  # success: the point mass within this distance of its goal
MAX_FORCE = 4.0


def reach_task() -> FinalRewardTask:
    """-1 per step until the point mass is within GOAL_RADIUS of the goal; success ends the episode."""
    inf = float("inf")
    states = Box([-1.0, -1.0, -inf, -inf], [1.0, 1.0, inf, inf], labels=PointMassEnv.labels)
    spec = EnvSpec(states, Box([-MAX_FORCE] * 2, [MAX_FORCE] * 2))
    near = functools.partial(proximity_succeeded, threshold=GOAL_RADIUS)
    reach = DesiredStateTask(spec.select_state(["x", "y"]), [0.0, 0.0], ConstantReward(-1.0), success=near)
    return FinalRewardTask(MaskedTask(spec, reach, ["x", "y"]), factor=10.0)


class NoisyReacher(nn.Module):
    """A PD controller towards the goal the policy sees, with Gaussian noise: some episodes succeed, some time out."""

    def forward(self, observation: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        force = 8.0 * (goal - observation[..., :2]) - observation[..., 2:] + torch.randn_like(goal)
        return force.clamp(-MAX_FORCE, MAX_FORCE)


def make_goal_env(seed: int = 0) -> TransformedEnv:
    """Point masses whose goal is redrawn after every success and when a 5-15 step timer runs out; 30-step limit."""
    from torchtasks.transforms import TaskTransform

    command = GoalCommand(Box([-0.7, -0.7], [0.7, 0.7]), resample_steps=(5, 15), resample_on_success=True, seed=seed)
    return TransformedEnv(
        PointMassEnv(batch_size=[8], max_force=MAX_FORCE, seed=seed),
        Compose(
            StepCounter(30), TaskTransform(reach_task(), goal_key="goal", achieved_goal_key="achieved_goal"), command
        ),
    )


def reacher() -> TensorDictModule:
    return TensorDictModule(NoisyReacher(), in_keys=["observation", "goal"], out_keys=["action"])


@pytest.fixture(scope="module")
def goal_batches() -> list[TensorDictBase]:
    """An env.rollout [8, 100] and four Collector batches [8, 20] (these start in the middle of episodes)."""
    torch.manual_seed(0)
    with torch.no_grad():
        rollout_data = make_goal_env().rollout(100, reacher(), break_when_any_done=False)
    threads = torch.get_num_threads()
    torch.manual_seed(1)
    collector = Collector(
        functools.partial(make_goal_env, 1), reacher(), frames_per_batch=160, total_frames=640, split_trajs=False
    )
    try:
        batches = [batch.clone() for batch in collector]
    finally:
        collector.shutdown()
        torch.set_num_threads(threads)
    return [rollout_data, *batches]


def test_final_goal_distance_is_to_the_goal_that_judged_the_last_step(goal_batches: list[TensorDictBase]) -> None:
    """Issue 22, item 4: under "next" of an episode's last frame is the goal drawn for the step after it."""
    task = reach_task()
    redrawn = {"success": 0, "timeout": 0}
    for batch in goal_batches:
        nxt = batch["next"]
        # the goal at the root is the one the task judged the step with: its verdicts are the stored ones
        out = task.transition(
            batch["observation"], batch["action"], nxt["observation"], batch["task"], goal=batch["goal"]
        )
        assert torch.equal(out.success, nxt["success"][..., 0])
        # the final distance of every ended episode, by hand, from the stored next state and that goal
        distances, successes = [], []
        envs, steps = batch.shape
        for e in range(envs):
            for t in range(steps):
                if not nxt["done"][e, t].item():
                    continue
                distance = math.dist(nxt["observation"][e, t, :2].tolist(), batch["goal"][e, t].tolist())
                success = bool(nxt["success"][e, t].item())
                assert not success or distance < GOAL_RADIUS, (e, t, distance)
                distances.append(distance)
                successes.append(success)
                if not torch.equal(nxt["goal"][e, t], batch["goal"][e, t]):  # the command drew the next goal
                    redrawn["success" if success else "timeout"] += 1
        stats = episode_statistics(batch, goal_key="goal", achieved_goal_key="achieved_goal")
        assert stats["episodes"] == len(distances) > 0
        assert stats["final_goal_distance_mean"] == pytest.approx(sum(distances) / len(distances), rel=1e-6)
        assert stats["success_rate"] == pytest.approx(sum(successes) / len(successes))
    # the data holds both cases of the issue: goals redrawn after a success and by a timer on the last step
    assert redrawn["success"] >= 5 and redrawn["timeout"] >= 2, redrawn


def test_final_goal_distance_of_successful_episodes(goal_batches: list[TensorDictBase]) -> None:
    """The episodes that ended in success, selected by trajectory id: all of them within the success radius."""
    checked = 0
    for batch in goal_batches[1:]:
        flat = batch.reshape(-1)
        traj_ids = flat["collector", "traj_ids"]
        ends = flat["next", "done"][..., 0] & flat["next", "success"][..., 0]
        successful = flat[torch.isin(traj_ids, traj_ids[ends])]
        if not ends.any():
            continue
        stats = episode_statistics(successful, goal_key="goal", achieved_goal_key="achieved_goal")
        assert stats["success_rate"] == 1.0
        assert stats["final_goal_distance_mean"] < GOAL_RADIUS
        checked += 1
    assert checked >= 2


# --------------------------------------------------------------------------------------------------
# Outcome flags, keys and arguments
# --------------------------------------------------------------------------------------------------


def _episodes(*endings: str) -> TensorDict:
    """One env; one 2-frame episode per ending (success, failure, timeout, env, success+trunc, env+trunc)."""
    done, terminated, truncated, success, failure = ([] for _ in range(5))
    for ending in endings:
        done += [False, True]
        terminated += [False, ending in ("success", "failure", "env", "success+trunc", "env+trunc")]
        truncated += [False, ending in ("timeout", "success+trunc", "env+trunc")]
        success += [False, ending in ("success", "success+trunc")]
        failure += [False, ending == "failure"]
    n = len(done)

    def column(values):
        return torch.tensor(values).reshape(1, n, 1)

    return TensorDict(
        {
            "step_count": column([i % 2 for i in range(n)]),
            "next": {
                "done": column(done),
                "terminated": column(terminated),
                "truncated": column(truncated),
                "success": column(success),
                "failure": column(failure),
                "reward": column([1.0] * n),
                "step_count": column([i % 2 + 1 for i in range(n)]),
                "task_reward": {"step": column([1.0] * n), "final": column([0.0] * n)},
            },
        },
        batch_size=[1, n],
    )


def test_outcome_flags() -> None:
    batch = _episodes("success", "failure", "timeout", "env", "success+trunc", "env+trunc", "env", "timeout")
    stats = episode_statistics(batch)
    assert stats["episodes"] == stats["complete_episodes"] == 8.0
    assert stats["success_rate"] == 2 / 8
    assert stats["failure_rate"] == 1 / 8
    assert stats["timeout_rate"] == 2 / 8
    assert stats["env_termination_rate"] == 3 / 8
    assert stats["episode_length_mean"] == 2.0 and stats["return_mean"] == 2.0 and stats["return_mean/step"] == 2.0
    # without truncated, timeouts are what is done but not terminated; without both, no end-kind rates
    no_truncated = batch.exclude(("next", "truncated"))
    assert episode_statistics(no_truncated)["timeout_rate"] == 2 / 8
    neither = batch.exclude(("next", "truncated"), ("next", "terminated"))
    assert "timeout_rate" not in episode_statistics(neither) and "env_termination_rate" not in episode_statistics(
        neither
    )
    # without the failure flag, the env's own termination cannot be told from a task failure
    stats = episode_statistics(batch, failure_key=None)
    assert "failure_rate" not in stats and "env_termination_rate" not in stats


def test_keys_and_arguments(data: TensorDictBase) -> None:
    with pytest.raises(KeyError, match="success_key='won'"):
        episode_statistics(data, success_key="won")
    # the breakdown is optional, as a TaskTransform writes none for a tree without terms and final reward
    stats = episode_statistics(data.exclude(("next", "task_reward")), terms_key=None)
    assert "return_mean" in stats and not any(key.startswith("return_mean/") for key in stats)
    assert episode_statistics(data.exclude(("next", "task_reward"))) == stats
    with pytest.raises(TypeError, match=r"named entries .* terms_key=None"):
        episode_statistics(data, terms_key="reward")
    stats = episode_statistics(data, reward_key=None, success_key=None)
    assert "return_mean" not in stats and "success_rate" not in stats and "return_mean/track" in stats
    with pytest.raises(ValueError, match="both goal_key and achieved_goal_key"):
        episode_statistics(data, goal_key=GOAL)
    with pytest.raises(ValueError, match="time_dim"):
        episode_statistics(data, time_dim=2)
    with pytest.raises(ValueError, match="no batch dims"):
        episode_statistics(data[0, 0])
    with pytest.raises(TypeError, match="TensorDict"):
        episode_statistics({"next": {}})
    with pytest.raises(TypeError, match="key"):
        episode_statistics(data, reward_key=3)
    two_rewards = data.clone()
    two_rewards["next", "reward"] = two_rewards["next", "reward"].expand(8, 40, 2).clone()
    with pytest.raises(ValueError, match="one value per frame"):
        episode_statistics(two_rewards)


# --------------------------------------------------------------------------------------------------
# The curriculum's scheduled values at the end of the batch
# --------------------------------------------------------------------------------------------------

EFFORT_R = "wrapped_task.reward.rewards.effort.R"  # [1] buffer, scalar schedule
TRACK_Q = "wrapped_task.reward.rewards.track.Q"  # [2] buffer, tensor schedule
R_RAMP = (0.0, 0.02, 40, 440)  # start_value, end_value, start_frame, end_frame
Q_RAMP = ((1.0, 0.1), (3.0, 0.5), 0, 1000)


def make_curriculum(**kwargs) -> Curriculum:
    return Curriculum(
        {
            EFFORT_R: linear(R_RAMP[0], R_RAMP[1], start_frame=R_RAMP[2], end_frame=R_RAMP[3]),
            TRACK_Q: linear(list(Q_RAMP[0]), list(Q_RAMP[1]), start_frame=Q_RAMP[2], end_frame=Q_RAMP[3]),
        },
        **kwargs,
    )


def ramp(frames: int, start, end, first: int, last: int) -> float:
    """The linear schedule's formula in plain Python: clamped interpolation."""
    fraction = min(max((frames - first) / (last - first), 0.0), 1.0)
    return start + (end - start) * fraction


def expected_schedule(frames: int) -> dict[str, float]:
    """The values at ``frames`` in the buffers' dtype: the TaskTransform casts the task to the env's float32."""
    q = [ramp(frames, start, end, *Q_RAMP[2:]) for start, end in zip(*Q_RAMP[:2], strict=True)]
    values = {
        "curriculum/wrapped_task/reward/rewards/effort/R": ramp(frames, *R_RAMP),
        "curriculum/wrapped_task/reward/rewards/track/Q/0": q[0],
        "curriculum/wrapped_task/reward/rewards/track/Q/1": q[1],
    }
    return {"curriculum/frames": float(frames)} | {
        name: torch.tensor(value, dtype=torch.float32).item() for name, value in values.items()
    }


def without_curriculum(data: TensorDictBase, key=("curriculum",)) -> TensorDictBase:
    return data.exclude(key, ("next", *key))


def test_curriculum_values_of_a_rollout(data: TensorDictBase) -> None:
    scheduled = rollout((8,), 40, make_curriculum())
    assert int(scheduled["next", "curriculum", "frames"][0, -1]) == 8 * 40
    assert (scheduled["next", "reward"] != data["next", "reward"]).any()  # the schedule changed the rewards
    stats = episode_statistics(scheduled)
    bare = episode_statistics(without_curriculum(scheduled))
    assert not any(key.startswith("curriculum/") for key in bare)
    assert_same(bare, reference_statistics(scheduled))
    assert_same(stats, {**bare, **expected_schedule(8 * 40)})
    assert list(stats)[: len(bare)] == list(bare)  # the scheduled values come after the episode statistics
    assert 0.0 < stats["curriculum/wrapped_task/reward/rewards/effort/R"] < R_RAMP[1]  # mid-ramp: not clamped
    assert episode_statistics(scheduled, curriculum_key=None) == bare
    # the end of a shorter stretch of the same data: the value at that frame count
    head = scheduled[:, :13]
    assert_same(episode_statistics(head), {**episode_statistics(without_curriculum(head)), **expected_schedule(8 * 13)})
    # several env dims, time first
    grid = rollout((2, 3), 30, make_curriculum())
    assert_same(episode_statistics(grid), {**reference_statistics(grid), **expected_schedule(6 * 30)})
    time_first = scheduled.permute(1, 0).contiguous()
    assert_same(episode_statistics(time_first, time_dim=0), stats)
    # no episode ended: the schedule is still reported
    quiet = scheduled[:, :1][~scheduled[:, :1]["next", "done"][:, 0, 0]]
    assert episode_statistics(quiet) == {"episodes": 0.0, "complete_episodes": 0.0, **expected_schedule(8)}


def test_curriculum_values_of_collector_batches() -> None:
    threads = torch.get_num_threads()
    torch.manual_seed(2)
    env = functools.partial(make_env, (8,), InitTracker(), make_curriculum())
    collector = Collector(env, None, frames_per_batch=40, total_frames=320)
    try:
        batches = [batch.clone() for batch in collector]
    finally:
        collector.shutdown()
        torch.set_num_threads(threads)
    assert len(batches) == 8
    for index, batch in enumerate(batches, start=1):
        frames = 40 * index  # frames collected at the end of the batch
        assert (batch["next", "curriculum", "frames"][:, -1] == frames).all()
        stats = episode_statistics(batch)
        assert_same(stats, {**reference_statistics(batch), **expected_schedule(frames)})
        flat = batch.reshape(-1)  # grouped by trajectory ids; the latest frames have the largest count
        assert_same(episode_statistics(flat), stats)
        assert_same(episode_statistics(flat.flip(0)), stats)


def test_curriculum_key_and_entries(data: TensorDictBase) -> None:
    scheduled = rollout((4,), 12, make_curriculum(curriculum_key=("schedule", "values")))
    bare = episode_statistics(without_curriculum(scheduled, ("schedule",)))
    assert episode_statistics(scheduled) == bare  # the default key finds nothing: unchanged output
    stats = episode_statistics(scheduled, curriculum_key=("schedule", "values"))
    assert_same(stats, {**bare, **expected_schedule(4 * 12)})
    assert all(type(value) is float for value in stats.values())
    with pytest.raises(TypeError, match="Curriculum's entries"):
        episode_statistics(data, curriculum_key="reward")
    with pytest.raises(TypeError, match="key"):
        episode_statistics(data, curriculum_key=3)
    flat = scheduled.reshape(-1).exclude(("next", "schedule", "values", "frames"))
    flat["collector", "traj_ids"] = torch.zeros(flat.shape[0], dtype=torch.long)
    with pytest.raises(ValueError, match=r"frame count .* pass the batch time-major .* curriculum_key=None"):
        episode_statistics(flat[:5], curriculum_key=("schedule", "values"))


# --------------------------------------------------------------------------------------------------
# Logging
# --------------------------------------------------------------------------------------------------


def test_logger_round_trip(data: TensorDictBase, tmp_path: Path) -> None:
    stats = episode_statistics(data, goal_key=GOAL, achieved_goal_key="observation")
    logger = CSVLogger(exp_name="stats", log_dir=str(tmp_path))
    for step in (0, 1):
        for name, value in stats.items():
            logger.log_scalar(name, value, step=step)
    scalars = next(tmp_path.rglob("scalars"))
    logged = {}
    for path in scalars.rglob("*.csv"):
        with path.open() as file:
            rows = list(csv.reader(file))
        assert [int(row[0]) for row in rows] == [0, 1]
        logged[path.relative_to(scalars).with_suffix("").as_posix()] = float(rows[-1][1])
    assert logged == stats
