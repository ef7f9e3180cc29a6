"""``TaskTransform`` offline: recomputing stored transitions in replay buffers, and HER relabelling.

Transitions are collected once from a batched pendulum (episodes end by success, failure and time
limit). Expected values: the rewards and flags recorded online (recomputation must reproduce them
from the stored state, action and memory), and, for relabelled goals, the task's reward written out
by hand for the new goal.
"""

from __future__ import annotations

import functools
import math

import pytest
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import HERReplayBuffer, LazyTensorStorage, SamplerWithoutReplacement, TensorDictReplayBuffer
from torchrl.envs import Compose, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv
from torchtasks.rewards import QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import DesiredStateTask, FinalRewardMode, FinalRewardTask, proximity_succeeded
from torchtasks.transforms import TaskTransform

F64 = torch.float64
BATCH, STEPS, MAX_STEPS = 4, 50, 20
GOAL = (math.pi, 0.0)
RADIUS, SPEED_LIMIT, ANGLE_LIMIT = 0.7, 4.5, 3 * math.pi
Q, R = (1.0, 0.1), 0.01
GOAL_KEY = ("task", "wrapped", "state_des")


def _task() -> FinalRewardTask:
    """Reach hanging still; fail above the speed limit; final reward ± remaining steps."""
    spec = EnvSpec(Box([-ANGLE_LIMIT, -SPEED_LIMIT], [ANGLE_LIMIT, SPEED_LIMIT]), Box([-2.0], [2.0]))
    success = functools.partial(proximity_succeeded, threshold=RADIUS)
    inner = DesiredStateTask(spec, list(GOAL), QuadraticErrorReward(list(Q), [R]), success)
    return FinalRewardTask(inner, FinalRewardMode(time_dependent=True))


class _Policy(nn.Module):
    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return 0.3 * observation[..., 0:1] + 0.8 * observation[..., 1:2]


@pytest.fixture(scope="module")
def collected() -> TensorDictBase:
    """Flat transitions ``[BATCH * STEPS]`` (each env's steps in order) with online rewards and flags."""
    env = TransformedEnv(
        PendulumEnv([BATCH], dtype=F64, seed=3), Compose(StepCounter(MAX_STEPS), TaskTransform(_task()))
    )
    policy = TensorDictModule(_Policy(), in_keys=["observation"], out_keys=["action"])
    with torch.no_grad():
        data = env.rollout(STEPS, policy, break_when_any_done=False)
    nxt = data["next"]
    assert nxt["success"].any() and nxt["failure"].any() and nxt["truncated"].any()
    return data.reshape(-1)


def _offline_transform() -> TaskTransform:
    return TaskTransform(_task().double(), max_steps=MAX_STEPS)


def _stripped(data: TensorDictBase) -> TensorDictBase:
    """The transitions as a plain env would have stored them: no task reward or flags, done = truncated."""
    data = data.clone()
    nxt = data["next"]
    nxt["reward"].zero_()
    nxt["success"].zero_()
    nxt["failure"].zero_()
    nxt["terminated"].zero_()
    nxt["done"].copy_(nxt["truncated"])
    nxt["task_reward"].zero_()
    return data


RECOMPUTED = [
    ("next", "reward"),
    ("next", "success"),
    ("next", "failure"),
    ("next", "done"),
    ("next", "terminated"),
    ("next", "task_reward", "step"),
    ("next", "task_reward", "final"),
]


def test_forward_recomputes_stored_transitions(collected: TensorDictBase) -> None:
    stripped = _stripped(collected)
    assert not torch.equal(stripped["next", "reward"], collected["next", "reward"])
    recomputed = _offline_transform()(stripped.clone())
    for key in RECOMPUTED:
        assert torch.equal(recomputed[key], collected[key]), key
    # the stored next memory is left as it was
    assert (recomputed["next", "task"] == stripped["next", "task"]).all()


def test_replay_buffer_transform_recomputes_sampled_transitions(collected: TensorDictBase) -> None:
    """``TensorDictReplayBuffer(transform=TaskTransform(...))`` rewrites rewards and flags of every sample."""
    n = collected.shape[0]
    buffer = TensorDictReplayBuffer(
        storage=LazyTensorStorage(n),
        sampler=SamplerWithoutReplacement(),
        batch_size=n // 4,
        transform=_offline_transform(),
    )
    buffer.extend(_stripped(collected))
    seen = []
    for _ in range(4):
        sample = buffer.sample()
        index = sample["index"]
        seen.append(index)
        for key in RECOMPUTED:
            assert torch.equal(sample[key], collected[key][index]), key
    assert sorted(torch.cat(seen).tolist()) == list(range(n))


def test_reward_fn_does_not_modify_the_data(collected: TensorDictBase) -> None:
    stripped = _stripped(collected)
    before = stripped.clone()
    reward = _offline_transform().reward_fn(stripped)
    assert torch.equal(reward, collected["next", "reward"])
    assert (stripped == before).all()


def _reward_by_hand(data: TensorDictBase, goal: torch.Tensor) -> torch.Tensor:
    """The task's reward ``[N, 1]`` of the stored transitions for desired state ``goal`` (``[N, 2]``)."""
    state = data["next", "observation"]
    action = data["action"][..., 0]
    error = goal - state
    step = -(Q[0] * error[..., 0] ** 2 + Q[1] * error[..., 1] ** 2 + R * action**2)
    success = torch.linalg.vector_norm(error, dim=-1) < RADIUS
    failure = (state[..., 0].abs() > ANGLE_LIMIT) | (state[..., 1].abs() > SPEED_LIMIT)
    remaining = (MAX_STEPS - data["next", "step_count"][..., 0]).to(F64)
    ended = success | failure | data["next", "truncated"][..., 0]
    paid = data["task", "paid"]
    final = torch.where(failure, -remaining, torch.where(success, remaining, torch.zeros_like(remaining)))
    final = torch.where(ended & ~paid, final, torch.zeros_like(final))
    return (step + final).unsqueeze(-1)


def test_reward_by_hand_matches_online_rewards(collected: TensorDictBase) -> None:
    """The hand-written reward used for HER is right on the original goal."""
    goal = torch.tensor(GOAL, dtype=F64).expand(collected.shape[0], 2)
    torch.testing.assert_close(_reward_by_hand(collected, goal), collected["next", "reward"], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("strategy", ["future", "final", "episode"])
def test_her_relabelled_rewards(collected: TensorDictBase, strategy: str) -> None:
    """``transform.reward_fn`` in ``HERReplayBuffer``: relabelled rewards are the task's for the new goal."""
    torch.manual_seed(0)
    n = collected.shape[0]
    transform = _offline_transform()
    buffer = HERReplayBuffer(
        reward_fn=transform.reward_fn,
        her_ratio=0.5,
        strategy=strategy,
        goal_key=GOAL_KEY,
        achieved_goal_key=("next", "observation"),
        storage=LazyTensorStorage(n),
        batch_size=100,
    )
    buffer.extend(collected.clone())
    sample = buffer.sample()
    index = sample["index"]
    n_her = 50
    relabelled, kept = sample[:n_her], sample[n_her:]
    goals = relabelled[GOAL_KEY]
    # relabelled goals are achieved states of the buffer, not the original goal
    achieved = collected["next", "observation"]
    assert all((achieved == goal).all(-1).any() for goal in goals)
    assert not (goals == torch.tensor(GOAL, dtype=F64)).all(-1).any()
    torch.testing.assert_close(relabelled["next", "reward"], _reward_by_hand(relabelled, goals), rtol=1e-12, atol=1e-12)
    # the other half keeps its goal and its online reward
    assert torch.equal(kept[GOAL_KEY], collected[GOAL_KEY][index[n_her:]])
    assert torch.equal(kept["next", "reward"], collected["next", "reward"][index[n_her:]])
    # the relabelling reaches the success branch: some new goals are reached by the transition itself
    reached = torch.linalg.vector_norm(goals - relabelled["next", "observation"], dim=-1) < RADIUS
    assert reached.any()


def test_relabelled_goal_rejudges_an_end_the_task_caused() -> None:
    """A stored end caused by the old goal's success is re-judged for the new goal (not paid again)."""
    import functools

    from tensordict import TensorDict

    from torchtasks.rewards import QuadraticErrorReward
    from torchtasks.spaces import EnvSpec
    from torchtasks.tasks import BestStateFinalRewardTask, DesiredStateTask, proximity_succeeded
    from torchtasks.transforms import TaskTransform

    f64 = torch.float64
    inner = DesiredStateTask(
        EnvSpec(1, 1), [1.0], QuadraticErrorReward([1.0], None), functools.partial(proximity_succeeded, threshold=0.1)
    )
    transform = TaskTransform(BestStateFinalRewardTask(inner, 1.0))
    memory = transform.task.reset(torch.zeros(1, 1, dtype=f64))
    flag = functools.partial(torch.full, (1, 1), dtype=torch.bool)
    data = TensorDict(
        {
            "observation": torch.zeros(1, 1, dtype=f64),
            "action": torch.zeros(1, 1, dtype=f64),
            "task": memory,
            "next": {
                "observation": torch.ones(1, 1, dtype=f64),
                "done": flag(True),
                "terminated": flag(True),
                "truncated": flag(False),
                "success": flag(True),
                "failure": flag(False),
            },
        },
        [1],
    )
    data["task", "wrapped", "state_des"] = torch.full((1, 1), 5.0, dtype=f64)
    # goal 5 is not reached at x = 1: only the step reward -(5 - 1)² = -16, no final reward of the best state
    assert transform.reward_fn(data).tolist() == [[-16.0]]
    # a truncated end is kept: the best-state final reward (best = -16, factor 1) is paid on top
    data["next", "truncated"] = flag(True)
    data["next", "success"] = flag(False)
    assert transform.reward_fn(data).tolist() == [[-32.0]]


@pytest.mark.parametrize(
    ("change", "error", "match"),
    [
        (lambda d: d.set("observation", d["observation"][..., :1]), ValueError, r"stored state 'observation' must"),
        (lambda d: d.set(("next", "observation"), d["next", "observation"].repeat(1, 2)), ValueError, "next state"),
        (lambda d: d.set("action", d["action"].repeat(1, 3)), ValueError, r"stored action 'action' must have"),
        (lambda d: d.set("observation", d["observation"].long()), TypeError, "float32 or float64"),
    ],
    ids=["state-size", "next-state-size", "action-size", "integer-state"],
)
def test_stored_data_that_does_not_fit_the_task_is_refused(collected: TensorDictBase, change, error, match) -> None:
    """Offline there is no env spec: a stored state or action of another size was broadcast against the task's
    constants (a size-1 state gave plausible rewards), or evaluated on the wrong entries."""
    transform = _offline_transform()
    for call in (transform, transform.reward_fn):
        with pytest.raises(error, match=match):
            call(change(_stripped(collected[:4])))


def test_reset_overrides_must_return_known_names() -> None:
    """A misspelt override name was dropped: the episodes started with the default goal."""
    task = DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], QuadraticErrorReward([1.0, 1.0]))
    for overrides, match in (
        (lambda s: {"goal": s}, r"reset_overrides returned unknown reset override\(s\) \['goal'\].*\['state_des'\]"),
        (lambda s: [("state_des", s)], "reset_overrides must return a mapping"),
    ):
        env = TransformedEnv(PendulumEnv(batch_size=[2]), TaskTransform(task, reset_overrides=overrides))
        with pytest.raises(TypeError, match=match):
            env.reset()
    with pytest.raises(TypeError, match="log_terms must be a bool"):
        TaskTransform(task, log_terms="no")
    with pytest.raises(ValueError, match="goal_name='goal' names the goal task that goal_key"):
        TaskTransform(task, goal_name="goal")
