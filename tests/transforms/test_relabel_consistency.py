"""``TaskTransform.relabel`` leaves a batch consistent in every entry (issue 22, item 5).

Data: point masses reaching goals drawn by a ``GoalCommand`` (several goals per env and episode, a
timer redraws them), collected with ``env.rollout`` and a ``Collector``; the task pays a step reward of
two named terms and a time-dependent final reward, so the reward, its breakdown, the flags and the
task memory all depend on the goal. After relabelling with new goals:

- the reward is the breakdown's ``step + final`` (and ``step`` the sum of the named terms), ``done``
  is ``terminated | truncated``, and what relabelling leaves (inputs, truncation, step counts,
  RewardSum's running sums) is as stored;
- ``episode_statistics`` of the relabelled batch equals the statistics counted by hand from its flags
  and rewards;
- every relabelled entry equals ``task.transition`` run step by step with the new goal (hypothesis over
  random goals), and relabelling goes through the task's own transition function.
"""

from __future__ import annotations

import functools
import math

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv

from torchtasks.envs import PointMassEnv
from torchtasks.rewards import CompoundReward, QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.stats import episode_statistics
from torchtasks.tasks import DesiredStateTask, FinalRewardTask, MaskedTask, proximity_succeeded
from torchtasks.tasks.final_reward import FinalRewardMode
from torchtasks.transforms import GoalCommand, TaskTransform

MAX_STEPS = 25
MAX_FORCE = 4.0
RADIUS = 0.15
GOALS = Box([-0.8, -0.8], [0.8, 0.8])
NAMED_TERMS = ("distance", "effort")
TERMS = ("step", "final", *NAMED_TERMS)
#: what relabel writes under "next" (the online step's outputs that depend on the goal): flags, the reward and
#: its breakdown, and the task memory (every entry under "task")
REWRITTEN = {
    *(("next", key) for key in ("reward", "success", "failure", "terminated", "done")),
    *(("next", "task_reward", term) for term in TERMS),
}


def make_task() -> FinalRewardTask:
    """Quadratic distance to the goal and effort per step; success within RADIUS pays the steps left (+rem)."""
    inf = float("inf")
    states = Box([-1.0, -1.0, -inf, -inf], [1.0, 1.0, inf, inf], labels=PointMassEnv.labels)
    spec = EnvSpec(states, Box([-MAX_FORCE] * 2, [MAX_FORCE] * 2))
    reward = CompoundReward(
        {"distance": QuadraticErrorReward([1.0, 1.0], None), "effort": QuadraticErrorReward([0.0, 0.0], [0.01, 0.01])}
    )
    near = functools.partial(proximity_succeeded, threshold=RADIUS)
    reach = DesiredStateTask(spec.select_state(["x", "y"]), [0.0, 0.0], reward, success=near)
    mode = FinalRewardMode(time_dependent=True, always_positive=True)
    return FinalRewardTask(MaskedTask(spec, reach, ["x", "y"]), mode)


def make_env(seed: int = 0) -> TransformedEnv:
    return TransformedEnv(
        PointMassEnv(batch_size=[6], max_force=MAX_FORCE, seed=seed),
        Compose(
            StepCounter(MAX_STEPS),
            TaskTransform(make_task(), goal_key="goal", achieved_goal_key="achieved_goal"),
            GoalCommand(GOALS, resample_steps=(4, 10), seed=seed),
            RewardSum(),
        ),
    )


def offline_transform() -> TaskTransform:
    """A TaskTransform outside any env (as in a replay buffer): the time limit is given."""
    return TaskTransform(make_task(), goal_key="goal", achieved_goal_key="achieved_goal", max_steps=MAX_STEPS)


class NoisyReacher(nn.Module):
    """A PD controller towards the goal the policy sees, with noise: some episodes succeed, others time out."""

    def forward(self, observation: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        force = 6.0 * (goal - observation[..., :2]) - observation[..., 2:] + 1.5 * torch.randn_like(goal)
        return force.clamp(-MAX_FORCE, MAX_FORCE)


def reacher() -> TensorDictModule:
    return TensorDictModule(NoisyReacher(), in_keys=["observation", "goal"], out_keys=["action"])


@pytest.fixture(scope="module")
def rollout_env() -> TransformedEnv:
    return make_env()


@pytest.fixture(scope="module")
def rollout_data(rollout_env: TransformedEnv) -> TensorDictBase:
    torch.manual_seed(0)
    with torch.no_grad():
        return rollout_env.rollout(60, reacher(), break_when_any_done=False)


@pytest.fixture(scope="module")
def collector_batches() -> list[TensorDictBase]:
    """Three Collector batches [6, 20] (the later ones start in the middle of episodes)."""
    threads = torch.get_num_threads()
    torch.manual_seed(1)
    collector = Collector(functools.partial(make_env, 1), reacher(), frames_per_batch=120, total_frames=360)
    try:
        batches = [batch.clone() for batch in collector]
    finally:
        collector.shutdown()
        torch.set_num_threads(threads)
    return batches


@pytest.fixture(scope="module")
def datasets(rollout_env, rollout_data, collector_batches) -> list[tuple[TaskTransform, TensorDictBase]]:
    """Each batch with the transform that relabels it: the env's own for the rollout, an offline one else."""
    return [(rollout_env.transform[1], rollout_data), *((offline_transform(), batch) for batch in collector_batches)]


# --------------------------------------------------------------------------------------------------
# New goals
# --------------------------------------------------------------------------------------------------


def hindsight_goals(data: TensorDictBase, generator: torch.Generator) -> torch.Tensor:
    """HER's "future" strategy: each frame's goal is the achieved goal of itself or a later frame of its row."""
    achieved = data["next", "achieved_goal"]
    steps = data.shape[-1]
    t = torch.arange(steps)
    later = t + (torch.rand(data.shape, generator=generator) * (steps - t)).long()
    return torch.gather(achieved, -2, later.unsqueeze(-1).expand_as(achieved))


def new_goals(data: TensorDictBase, mode: str, seed: int, scale: float = 0.0) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    shape = (*data.shape, 2)
    if mode == "uniform":  # a new goal for every frame, anywhere in the goal space
        goals = GOALS.low + torch.rand(shape, generator=generator) * (GOALS.high - GOALS.low)
    elif mode == "per_row":  # one goal for all frames of an env
        goals = GOALS.low + torch.rand((shape[0], 1, 2), generator=generator) * (GOALS.high - GOALS.low)
        goals = goals.expand(shape)
    elif mode == "hindsight":
        goals = hindsight_goals(data, generator)
    else:  # "near": the achieved goal moved by about the success radius (verdicts on both sides of it)
        direction = torch.nn.functional.normalize(torch.randn(shape, generator=generator), dim=-1)
        goals = data["next", "achieved_goal"] + scale * RADIUS * direction
    return goals.to(data["goal"].dtype).contiguous()


def relabelled(transform: TaskTransform, data: TensorDictBase, goals: torch.Tensor) -> TensorDictBase:
    copy = data.clone()
    copy["goal"] = goals
    reward = transform.relabel(copy)
    assert torch.equal(reward, copy["next", "reward"])  # the reward returned is the one written
    return copy


# --------------------------------------------------------------------------------------------------
# The batch after relabelling: consistent in every entry
# --------------------------------------------------------------------------------------------------


def check_consistent(before: TensorDictBase, after: TensorDictBase) -> None:
    nxt = after["next"]
    breakdown = nxt["task_reward"]
    # the reward is its breakdown, the step reward the sum of its named terms
    torch.testing.assert_close(nxt["reward"], breakdown["step"] + breakdown["final"], rtol=0, atol=0)
    torch.testing.assert_close(breakdown["step"], breakdown["distance"] + breakdown["effort"])
    assert (
        nxt["reward"].dtype == before["next", "reward"].dtype and nxt["reward"].shape == before["next", "reward"].shape
    )
    # the flags: done is terminated | truncated, and terminated is the task's verdict (the env ends nothing)
    assert torch.equal(nxt["done"], nxt["terminated"] | nxt["truncated"])
    assert torch.equal(nxt["terminated"], nxt["success"] | nxt["failure"])
    # the final reward is paid exactly where the episode now ends by success (+ the steps left)
    remaining = (MAX_STEPS - nxt["step_count"]).to(breakdown["final"].dtype)
    assert torch.equal(breakdown["final"], torch.where(nxt["success"], remaining, torch.zeros_like(remaining)))
    # the memory after the step carries the goal the step was judged with and its "paid" latch
    assert torch.equal(nxt["task", "wrapped", "state_des"], after["goal"])
    assert torch.equal(nxt["task", "paid"], nxt["done"][..., 0])
    # left as stored: inputs, truncation, step counts, achieved goals, RewardSum's running sums
    kept = [
        key for key in before.keys(True, True) if key != "goal" and key not in REWRITTEN and key[:2] != ("next", "task")
    ]
    assert {("next", "episode_reward"), ("next", "truncated"), ("next", "achieved_goal"), ("task", "paid")} <= set(kept)
    for key in kept:
        assert torch.equal(after[key], before[key]), key


def test_relabel_rewrites_the_reward_with_the_flags(datasets) -> None:
    """The regression: the stored reward was left at the old goal's value while the flags changed."""
    for transform, data in datasets:
        after = relabelled(transform, data, new_goals(data, "hindsight", seed=0))
        changed = after["next", "success"] != data["next", "success"]
        assert changed.any()  # the new goals change the verdicts...
        assert not torch.equal(after["next", "reward"], data["next", "reward"])  # ...and with them the reward
        breakdown = after["next", "task_reward"]
        assert torch.equal(after["next", "reward"], breakdown["step"] + breakdown["final"])


@pytest.mark.parametrize("mode", ["uniform", "per_row", "hindsight", "near"])
def test_relabelled_batches_are_consistent(datasets, mode: str) -> None:
    for i, (transform, data) in enumerate(datasets):
        after = relabelled(transform, data, new_goals(data, mode, seed=i, scale=1.0))
        check_consistent(data, after)


def test_relabelling_with_the_stored_goals_changes_nothing(datasets) -> None:
    """The goals the data was collected with give back every stored entry: relabelling is the online step."""
    for transform, data in datasets:
        after = relabelled(transform, data, data["goal"].clone())
        for key in data.keys(True, True):
            assert torch.equal(after[key], data[key]), key
        # relabelled data relabels like collected data: a second relabel with the same goals changes nothing
        again = relabelled(transform, after, new_goals(data, "hindsight", seed=3))
        assert (again["next", "success"] != data["next", "success"]).any()
        assert (relabelled(transform, again, again["goal"].clone()) == again).all()


def test_relabel_writes_through_a_view(rollout_env, rollout_data) -> None:
    """HERReplayBuffer hands the relabelled part of its sample as a slice: the whole batch is rewritten."""
    data = rollout_data.clone()
    data["goal"] = new_goals(data, "hindsight", seed=5)
    expected = relabelled(rollout_env.transform[1], data, data["goal"])
    part = data[:3]
    rollout_env.transform[1].relabel(part)
    for key in ("reward", "success", "terminated", "done", ("task_reward", "final"), ("task", "paid")):
        key = ("next", *((key,) if isinstance(key, str) else key))
        assert torch.equal(data[key][:3], expected[key][:3]), key
        assert torch.equal(data[key][3:], rollout_data[key][3:]), key


# --------------------------------------------------------------------------------------------------
# Statistics of a relabelled batch, counted by hand
# --------------------------------------------------------------------------------------------------


def statistics_by_hand(data: TensorDictBase) -> dict[str, float]:
    """Episodes end at done frames; the length is the step count at the end, the episode complete (returns
    counted) when all its frames are in the batch (as many frames since the previous end as steps)."""
    nxt = data["next"]
    ended = []
    for e in range(data.shape[0]):
        frames, returns = 0, dict.fromkeys(("reward", *TERMS), 0.0)
        for t in range(data.shape[1]):
            frames += 1
            returns["reward"] += nxt["reward"][e, t].item()
            for term in TERMS:
                returns[term] += nxt["task_reward", term][e, t].item()
            if not nxt["done"][e, t].item():
                continue
            length = nxt["step_count"][e, t].item()
            flags = {name: bool(nxt[name][e, t].item()) for name in ("success", "failure", "terminated", "truncated")}
            ended.append({**flags, "length": length, "complete": frames == length, "returns": dict(returns)})
            frames, returns = 0, dict.fromkeys(returns, 0.0)
    complete = [episode for episode in ended if episode["complete"]]

    def mean(values) -> float:
        values = list(values)
        return sum(values) / len(values)

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
    stats["episode_length_mean"] = mean(ep["length"] for ep in ended)
    if complete:
        stats["return_mean"] = mean(ep["returns"]["reward"] for ep in complete)
        for term in TERMS:
            stats[f"return_mean/{term}"] = mean(ep["returns"][term] for ep in complete)
    stats["final_goal_distance_mean"] = mean(
        math.dist(data["goal"][e, t].tolist(), nxt["achieved_goal"][e, t].tolist())
        for e, t in nxt["done"][..., 0].nonzero().tolist()
    )
    return stats


@pytest.mark.parametrize("mode", ["hindsight", "near", "per_row"])
def test_statistics_of_a_relabelled_batch(datasets, mode: str) -> None:
    counted = 0.0
    for i, (transform, data) in enumerate(datasets):
        after = relabelled(transform, data, new_goals(data, mode, seed=10 + i, scale=1.0))
        stats = episode_statistics(after, goal_key="goal", achieved_goal_key="achieved_goal")
        by_hand = statistics_by_hand(after)
        assert set(stats) == set(by_hand)
        assert stats == pytest.approx(by_hand, rel=1e-6, abs=1e-6)
        counted += stats["complete_episodes"]
        if mode == "hindsight":  # many relabelled goals are reached: more episodes end, by success
            before = episode_statistics(data)
            successes = stats["episodes"] * stats["success_rate"]
            assert successes > before["episodes"] * before.get("success_rate", 0.0)
    assert counted >= 5


# --------------------------------------------------------------------------------------------------
# The same function: relabelled entries equal the task's transition, step by step
# --------------------------------------------------------------------------------------------------


def transitions_step_by_step(task: FinalRewardTask, data: TensorDictBase, goals: torch.Tensor) -> dict:
    """``task.transition`` per time step with the new goals, from the stored memory before each step; the env's
    own termination is the stored one without the old task verdict (the point mass never ends by itself)."""
    nxt = data["next"]
    old_verdict = nxt["success"] | nxt["failure"]
    env_terminated = nxt["terminated"] & ~old_verdict
    assert not env_terminated.any()
    outputs = []
    for t in range(data.shape[-1]):
        step = data[:, t]
        outputs.append(
            task.transition(
                step["observation"],
                step["action"],
                step["next", "observation"],
                step["task"],
                MAX_STEPS - step["next", "step_count"][..., 0],
                terminated=env_terminated[:, t, 0],
                truncated=step["next", "truncated"][..., 0],
                goal=goals[:, t],
            )
        )
    stack = functools.partial(torch.stack, dim=1)
    return {
        "reward": stack([out.reward for out in outputs]),
        "step": stack([out.step_reward for out in outputs]),
        "final": stack([out.final_reward for out in outputs]),
        "success": stack([out.success for out in outputs]),
        "failure": stack([out.failure for out in outputs]),
        "terminated": stack([out.terminated for out in outputs]),
        "done": stack([out.done for out in outputs]),
        **{name: stack([out.terms[name] for out in outputs]) for name in NAMED_TERMS},
        "memory": torch.stack([out.memory for out in outputs], dim=1),
    }


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    which=st.integers(0, 3),
    mode=st.sampled_from(["uniform", "per_row", "hindsight", "near"]),
    seed=st.integers(0, 2**31 - 1),
    scale=st.floats(0.0, 3.0),
)
def test_relabelled_entries_are_the_tasks_transition(datasets, which: int, mode: str, seed: int, scale: float) -> None:
    transform, data = datasets[which]
    goals = new_goals(data, mode, seed, scale)
    after = relabelled(transform, data, goals)
    want = transitions_step_by_step(make_task(), data, goals)
    nxt = after["next"]
    assert torch.equal(nxt["reward"][..., 0], want["reward"].to(nxt["reward"].dtype))
    for flag in ("success", "failure", "terminated", "done"):
        assert torch.equal(nxt[flag][..., 0], want[flag]), flag
    for term in TERMS:
        assert torch.equal(nxt["task_reward", term][..., 0], want[term].to(nxt["reward"].dtype)), term
    assert (nxt["task"] == want["memory"]).all()


def test_relabel_calls_the_tasks_transition_once(rollout_data, monkeypatch: pytest.MonkeyPatch) -> None:
    """Relabelling evaluates the task through its own transition function, once for the whole batch."""
    transform = offline_transform()
    calls = []
    original = transform.task._transition

    def spy(*args, **kwargs):
        calls.append(args[0].shape)
        return original(*args, **kwargs)

    monkeypatch.setattr(transform.task, "_transition", spy)
    data = rollout_data.clone()
    data["goal"] = new_goals(data, "uniform", seed=0)
    transform.relabel(data)
    assert calls == [(*data.shape, 4)]
