"""Offline recomputation uses the values each step used, not today's buffers (issue 30, defect 5).

Data is collected while a :class:`~torchtasks.transforms.Curriculum` ramps a task buffer (a scalar reward
weight, the final reward's ``success_value``, a vector weight, a scalar filling a vector weight) or
:class:`~torchtasks.transforms.DifficultyLevels` sets per-env buffers (a scalar and a vector per env) from its
tables. Recomputing the stored transitions (``forward``, ``reward_fn``, ``relabel`` with the original goal)
must give the rewards and flags the env paid, on the rollout's ``[B, T]``, flattened ``[N]`` and a replay
buffer's random sample, with the env's own TaskTransform and with one outside any env (a replay buffer's
transform). Expected values: the rewards and flags recorded online. The buffers' values of today (the
ramp's end, the levels after the last step) give other rewards: each case checks that they do. Data
lacking the recorded values, recorded values of the wrong shape and a reward that cannot take one value
per frame are refused.

The first test checks the kernels themselves: every float buffer of every task tree takes one value per
row (what recomputation puts in the buffers' places), against an independent loop that evaluates the
batch once per row with that row's value in the buffer's own shape.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Callable

import pytest
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import LazyTensorStorage, ReplayBuffer, SamplerWithoutReplacement
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv
from torchrl.envs.utils import check_env_specs

from task_trees import all_task_cases, example_trees, predefined_cases, random_transitions
from torchtasks.envs import PendulumEnv, swing_up_task
from torchtasks.envs.locomotion import safety_velocity_task
from torchtasks.rewards import (
    AbsoluteErrorReward,
    CompoundReward,
    ExpQuadraticErrorReward,
    QuadraticErrorReward,
    RewardFunction,
    ScaledExpQuadraticErrorReward,
    ToleranceReward,
)
from torchtasks.rewards.terms import AboveThresholdIndicator, ContactCostReward, HealthyReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import DesiredStateTask, FinalRewardTask, Task, proximity_succeeded
from torchtasks.transforms import Curriculum, DifficultyLevels, TaskTransform, linear

# ------------------------------------------------------------------------------------------------------------------
# Kernels: one value per row of every float buffer
# ------------------------------------------------------------------------------------------------------------------
ROWS = 7


def _kernel_zoo() -> dict[str, Callable[[], Task]]:
    """Rewards whose constants meet the state in a product, a clamp or a matrix (not only elementwise)."""
    spec = EnvSpec(Box([-2.0] * 3, [2.0] * 3), Box([-1.0] * 2, [1.0] * 2))
    rewards = {
        "matrix": QuadraticErrorReward(torch.eye(3) * 2 + 0.25, torch.eye(2)),
        "exp": ExpQuadraticErrorReward([1.0, 2.0, 3.0], [1.0, 0.5]),
        "absolute": AbsoluteErrorReward([1.0, 2.0, 3.0], [1.0, 1.0]),
        "scaled": ScaledExpQuadraticErrorReward([1.0] * 3, [1.0] * 2, spec.state_space, spec.action_space),
        "contacts": ContactCostReward(0.5, start=1, force_range=(-1.0, 1.0), cost_range=(0.0, 1.0)),
        "one_contact": ContactCostReward(0.5, start=2, force_range=(-1.0, 1.0)),  # [*B, 1] forces
        "healthy": HealthyReward(1.0, index=[0, 1], low=-1.0, high=1.0),
        "above": AboveThresholdIndicator(0.3, index=[0, 1], norm=True),
        "tolerance": ToleranceReward(([-0.5, -0.2, 0.0], [0.5, 0.3, 0.4]), margin=[0.3, 0.1, 0.2]),
    }
    near = functools.partial(proximity_succeeded, threshold=1.0)
    return {
        "kernel_zoo": lambda: FinalRewardTask(
            DesiredStateTask(spec, [0.0] * 3, CompoundReward(rewards, weights={"matrix": 0.5}), near)
        ),
        "swing_up": swing_up_task,
        "safety_ant": lambda: safety_velocity_task("Ant-v5"),  # locomotion terms, contact clamps, a cost
    }


KERNEL_CASES = {**all_task_cases(), **predefined_cases(), **_kernel_zoo()}
KERNEL_CASES.update({f"tree_{name}": functools.partial(lambda n: example_trees()[n], name) for name in example_trees()})


def _owner(task: nn.Module, name: str) -> tuple[nn.Module, str]:
    *path, leaf = name.split(".")
    for part in path:
        task = task._modules[part]
    return task, leaf


def _evaluate(task: Task, values: dict[tuple[nn.Module, str], torch.Tensor], arguments: tuple) -> tuple:
    saved = {slot: slot[0]._buffers[slot[1]] for slot in values}
    try:
        for (module, leaf), value in values.items():
            module._buffers[leaf] = value
        return task._transition(*arguments, "next", True)
    finally:
        for (module, leaf), buffer in saved.items():
            module._buffers[leaf] = buffer


def _row(value: object, row: int) -> object:
    if isinstance(value, dict):
        return {name: _row(entry, row) for name, entry in value.items()}
    if isinstance(value, TensorDictBase):
        return value[row]
    return value.expand(ROWS)[row] if value.dim() == 0 else value[row]


@pytest.mark.parametrize("case", KERNEL_CASES)
def test_every_float_buffer_takes_one_value_per_row(case: str) -> None:
    task = KERNEL_CASES[case]().double()
    generator = torch.Generator().manual_seed(0)
    draws = random_transitions(task, generator, 1, ROWS)
    state, next_state = draws["states"][0], draws["states"][1]
    remaining = draws["remaining"][0] if task.uses_remaining_steps else task.no_remaining_steps.expand(ROWS)
    arguments = (
        state,
        draws["actions"][0],
        next_state,
        task._reset(state, {}),
        remaining,
        draws["terminated"][0],
        draws["truncated"][0],
    )
    # every float buffer gets a different value in each row: its value times a factor in [0.5, 1.5)
    per_row = {}
    for name, buffer in task.named_buffers():
        if buffer.is_floating_point():
            factor = 0.5 + torch.rand(ROWS, generator=generator, dtype=buffer.dtype)
            per_row[_owner(task, name)] = buffer * factor.reshape(ROWS, *[1] * buffer.dim())
    assert per_row
    task._transition(*arguments, "next", True)  # derives what a task caches (memory layouts) from its own buffers
    outputs = _evaluate(task, per_row, arguments)
    for row in range(ROWS):  # the batch evaluated with row `row`'s values in the buffers' own shapes
        expected = _evaluate(task, {slot: value[row] for slot, value in per_row.items()}, arguments)
        for i, (got, want) in enumerate(zip(outputs, expected, strict=True)):
            got, want = _row(got, row), _row(want, row)
            if isinstance(want, dict):
                assert got.keys() == want.keys(), i
                for name in want:
                    assert torch.equal(got[name], want[name]), (row, i, name)
            elif isinstance(want, TensorDictBase):
                assert (got == want).all(), (row, i)
            else:
                assert torch.equal(got, want), (row, i)


# ------------------------------------------------------------------------------------------------------------------
# Collected data
# ------------------------------------------------------------------------------------------------------------------
ENVS, STEPS, MAX_STEPS = 8, 60, 20
FRAMES = ENVS * STEPS
GOAL, RADIUS, SPEED_LIMIT = (math.pi, 0.0), 0.7, 4.5


def reach_task() -> FinalRewardTask:
    """Reach hanging still (success within RADIUS), fail above the speed limit; weighted track and effort terms."""
    spec = EnvSpec(Box([-3 * math.pi, -SPEED_LIMIT], [3 * math.pi, SPEED_LIMIT]), Box([-2.0], [2.0]))
    reward = CompoundReward(
        {"track": QuadraticErrorReward([1.0, 0.1], None), "effort": QuadraticErrorReward([0.0, 0.0], [0.01])},
        weights={"effort": 1.0},
    )
    near = functools.partial(proximity_succeeded, threshold=RADIUS)
    return FinalRewardTask(DesiredStateTask(spec, list(GOAL), reward, near), factor=10.0)


class PerEnvDistance(RewardFunction):
    """``-scale · Σ_i q_i e_i²`` with one ``scale`` (``[B]``) and one ``q`` (``[B, 2]``) per env, set by levels."""

    uses_action = False

    def __init__(self, envs: int) -> None:
        super().__init__()
        self.register_buffer("scale", torch.ones(envs, dtype=torch.float64))
        self.register_buffer("q", torch.ones(envs, 2, dtype=torch.float64))

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None = None) -> torch.Tensor:
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        q = self.q.to(error_state.dtype)
        return -self.scale.to(error_state.dtype) * (error_state * error_state * q).sum(-1)


def levelled_task() -> FinalRewardTask:
    spec = EnvSpec(Box([-3 * math.pi, -SPEED_LIMIT], [3 * math.pi, SPEED_LIMIT]), Box([-2.0], [2.0]))
    near = functools.partial(proximity_succeeded, threshold=RADIUS)
    return FinalRewardTask(DesiredStateTask(spec, list(GOAL), PerEnvDistance(ENVS), near), factor=10.0)


def _up_at_every_end(tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> torch.Tensor:
    return torch.ones(next_tensordict.batch_size, dtype=torch.int64)  # every episode end moves its env up a level


LEVEL_TABLES = {
    "wrapped_task.reward.scale": [1.0, 2.0, 4.0],
    "wrapped_task.reward.q": [[1.0, 0.1], [0.5, 1.0], [2.0, 0.25]],
}

#: case -> (task builder, the transform after the TaskTransform, the buffers it sets)
CASES = {
    "scalar weight": (
        reach_task,
        lambda: Curriculum({"wrapped_task.reward.weights.effort": linear(0.0, 8.0, 0, FRAMES)}),
        ["wrapped_task.reward.weights.effort"],
    ),
    "success_value": (
        reach_task,
        lambda: Curriculum({"success_value": linear(0.0, 100.0, 0, FRAMES)}),
        ["success_value"],
    ),
    "vector weight": (
        reach_task,
        lambda: Curriculum({"wrapped_task.reward.rewards.track.Q": linear([1.0, 0.1], [0.25, 1.0], 0, FRAMES)}),
        ["wrapped_task.reward.rewards.track.Q"],
    ),
    "scalar over a vector": (  # one value filling the buffer: recorded as [*B, 1]
        reach_task,
        lambda: Curriculum({"wrapped_task.reward.rewards.track.Q": linear(0.25, 2.0, 0, FRAMES)}),
        ["wrapped_task.reward.rewards.track.Q"],
    ),
    "levels": (
        levelled_task,
        lambda: DifficultyLevels(3, LEVEL_TABLES, rule=_up_at_every_end),
        list(LEVEL_TABLES),
    ),
}


class _Policy(nn.Module):
    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return 0.3 * observation[..., 0:1] + 0.8 * observation[..., 1:2]


def make_env(case: str) -> TransformedEnv:
    make_task, make_setter, _ = CASES[case]
    return TransformedEnv(
        PendulumEnv([ENVS], seed=3),
        Compose(StepCounter(MAX_STEPS), TaskTransform(make_task()), make_setter(), RewardSum()),
    )


@pytest.fixture(scope="module", params=list(CASES))
def collected(request) -> tuple[str, TransformedEnv, TensorDictBase]:
    """A rollout ``[ENVS, STEPS]`` with its env (whose buffers now hold the values of the last step)."""
    case = request.param
    env = make_env(case)
    policy = TensorDictModule(_Policy(), in_keys=["observation"], out_keys=["action"])
    with torch.no_grad():
        data = env.rollout(STEPS, policy, break_when_any_done=False)
    nxt = data["next"]
    assert nxt["success"].any() and nxt["failure"].any() and nxt["truncated"].any()
    return case, env, data


def _layout(data: TensorDictBase, layout: str) -> TensorDictBase:
    if layout == "rollout":
        return data.clone()
    flat = data.reshape(-1)
    if layout == "flat":
        return flat.clone()
    # every frame once, in a random order (a random sample of some frames may hold no success)
    buffer = ReplayBuffer(storage=LazyTensorStorage(FRAMES), sampler=SamplerWithoutReplacement(), batch_size=FRAMES)
    buffer.extend(flat)
    torch.manual_seed(7)
    sample = buffer.sample().clone()
    assert not torch.equal(sample["observation"], flat["observation"])
    return sample


def _transform(case: str, env: TransformedEnv, where: str) -> TaskTransform:
    if where == "env":
        return env.transform[1]
    return TaskTransform(CASES[case][0](), max_steps=MAX_STEPS)  # a replay buffer's transform: no env


RECOMPUTED = [("next", key) for key in ("reward", "success", "failure", "terminated", "done")] + [
    ("next", "task_reward", term) for term in ("step", "final")
]


def _stripped(data: TensorDictBase) -> TensorDictBase:
    """The transitions with the task's outputs zeroed (done = the truncation): recomputation must write them."""
    data = data.clone()
    nxt = data["next"]
    for key in ("reward", "success", "failure", "terminated"):
        nxt[key].zero_()
    nxt["done"].copy_(nxt["truncated"])
    nxt["task_reward"].zero_()
    return data


def _recompute(transform: TaskTransform, data: TensorDictBase, method: str) -> dict:
    stripped = _stripped(data)
    if method == "forward":
        out = transform(stripped)
        return {key: out[key] for key in RECOMPUTED}
    if method == "reward_fn":
        return {("next", "reward"): transform.reward_fn(stripped)}
    reward = transform.relabel(stripped)  # the goal in the data is the original one: a relabelling that changes nothing
    assert torch.equal(reward, stripped["next", "reward"])
    return {key: stripped[key] for key in [*RECOMPUTED, ("next", "task")]}


# ------------------------------------------------------------------------------------------------------------------
# Recomputation equals what the env paid
# ------------------------------------------------------------------------------------------------------------------
def _with_todays_values(case: str, env: TransformedEnv, data: TensorDictBase) -> TensorDictBase:
    """``data`` whose recorded values are replaced by the buffers' values of today (after the last step)."""
    data = data.clone()
    task = env.transform[1].task
    buffers = dict(task.named_buffers())
    for name in CASES[case][2]:
        key, buffer = ("curriculum", name.replace(".", "/")), buffers[name]
        if case == "levels":  # one value per env: env i's row in all of its frames
            buffer = buffer.unsqueeze(1)
        elif buffer.dim() and data[key].shape[-1:] != buffer.shape[-1:]:  # a scalar schedule filling the buffer
            buffer = buffer[:1]
        data[key] = buffer.to(data[key].dtype).expand_as(data[key]).clone()
    return data


def test_the_data_records_values_that_changed_and_todays_values_pay_other_rewards(collected) -> None:
    case, env, data = collected
    for name in CASES[case][2]:  # one value per frame, and not one value for the whole rollout
        values = data["curriculum", name.replace(".", "/")].reshape(ENVS * STEPS, -1)
        assert (values != values[:1]).any(-1).any(), name
    # the buffers' values of today (after the last step) give other rewards than the env paid
    today = _with_todays_values(case, env, data)
    recomputed = TaskTransform(CASES[case][0](), max_steps=MAX_STEPS)(_stripped(today))["next", "reward"]
    assert (recomputed - data["next", "reward"]).abs().max() > 0.05


@pytest.mark.parametrize("collected", [case for case in CASES if case != "levels"], indirect=True)
def test_without_a_curriculum_key_a_transform_outside_the_env_uses_todays_buffers(collected) -> None:
    case, env, data = collected  # (today's per-env buffers of levels do not broadcast over a rollout's frames)
    today = TaskTransform(env.transform[1].task, curriculum_key=None)(_stripped(data))
    expected = TaskTransform(CASES[case][0](), max_steps=MAX_STEPS)(_stripped(_with_todays_values(case, env, data)))
    assert torch.equal(today["next", "reward"], expected["next", "reward"])


@pytest.mark.parametrize("where", ["env", "standalone"])
@pytest.mark.parametrize("method", ["forward", "reward_fn", "relabel"])
@pytest.mark.parametrize("layout", ["rollout", "flat", "replay sample"])
def test_offline_recomputation_equals_what_the_env_paid(collected, layout: str, method: str, where: str) -> None:
    case, env, data = collected
    data = _layout(data, layout)
    recomputed = _recompute(_transform(case, env, where), data, method)
    for key, value in recomputed.items():
        assert value.shape == data[key].shape, key
        assert (value == data[key]).all(), (key, (value.double() - data[key].double()).abs().max())


@pytest.mark.parametrize("method", ["forward", "reward_fn", "relabel"])
def test_data_without_the_recorded_values_is_refused_by_the_envs_transform(collected, method: str) -> None:
    case, env, data = collected
    missing = ("curriculum", CASES[case][2][0].replace(".", "/"))
    lacking = data.exclude(missing)
    with pytest.raises(
        ValueError,
        match=re.escape(f"the data lacks {missing!r}, the value") + " of the task buffer .*sets at every step",
    ):
        _recompute(env.transform[1], lacking, method)


def test_the_buffers_are_back_after_recomputation(collected) -> None:
    _, env, data = collected
    task = env.transform[1].task
    before = {name: (buffer, buffer.clone()) for name, buffer in task.named_buffers()}
    _recompute(env.transform[1], data, "forward")
    for name, buffer in task.named_buffers():
        assert buffer is before[name][0] and torch.equal(buffer, before[name][1]), name


def test_recorded_values_of_the_wrong_shape_are_refused() -> None:
    env = make_env("vector weight")
    data = env.rollout(3)
    data["curriculum", "wrapped_task/reward/rewards/track/Q"] = torch.zeros(ENVS, 3, 3)
    with pytest.raises(
        ValueError,
        match=r"task buffer 'wrapped_task.reward.rewards.track.Q' \(shape \[2\]\) must have shape \[8, 3, 2\]",
    ):
        TaskTransform(reach_task(), max_steps=MAX_STEPS)(data)


class _Unbroadcast(RewardFunction):
    """A reward whose weight meets the state in a way that ignores leading dims of the weight."""

    uses_action = False

    def __init__(self, how: str) -> None:
        super().__init__()
        self.how = how
        self.register_buffer("w", torch.tensor([1.0, 0.5], dtype=torch.float64))
        self.register_buffer("s", torch.tensor(1.0, dtype=torch.float64))

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None = None) -> torch.Tensor:
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        squares = error_state * error_state
        if self.how == "matmul":  # [N, 2] @ [N, 2] does not multiply
            return -squares @ self.w.to(error_state.dtype)
        # [N, 1] * [N] broadcasts to [N, N]: the squeeze leaves it so
        return (-squares.sum(-1, keepdim=True) * self.s.to(error_state.dtype)).squeeze(-1)


@pytest.mark.parametrize(
    ("how", "schedule", "message"),
    [
        ("matmul", {"reward.w": linear([1.0, 0.5], [2.0, 1.0], 0, 40)}, "failed to evaluate stored transitions"),
        ("keepdim", {"reward.s": linear(1.0, 2.0, 0, 40)}, "returned rewards of shape [48, 48] for a batch [48]"),
    ],
)
def test_a_reward_that_cannot_take_one_value_per_frame_is_refused(how: str, schedule: dict, message: str) -> None:
    spec = EnvSpec(Box([-10.0, -10.0], [10.0, 10.0]), Box([-2.0], [2.0]))
    task = DesiredStateTask(spec, [0.0, 0.0], _Unbroadcast(how))
    env = TransformedEnv(
        PendulumEnv([ENVS], seed=0), Compose(StepCounter(MAX_STEPS), TaskTransform(task), Curriculum(schedule))
    )
    data = env.rollout(6)
    with pytest.raises(ValueError, match=re.escape(message)):
        env.transform[1](data.reshape(-1))


def test_levels_record_each_envs_row_at_the_root_of_every_step() -> None:
    env = make_env("levels")
    check_env_specs(env)
    data = env.rollout(STEPS, break_when_any_done=False)
    level = data["curriculum", "level"][..., 0]  # the level each step was played at
    assert level.unique().numel() == 3
    for name, table in LEVEL_TABLES.items():  # the row of that level, of the buffer's dtype
        recorded = data["curriculum", name.replace(".", "/")]
        assert torch.equal(recorded, torch.tensor(table, dtype=recorded.dtype)[level])
        assert recorded.shape == (ENVS, STEPS, *torch.tensor(table).shape[1:])


@pytest.mark.parametrize("target", ["level", "frames"])
def test_a_level_target_named_like_an_entry_of_the_key_is_refused(target: str) -> None:
    with pytest.raises(ValueError, match=f"a target may not be named {target!r}"):
        DifficultyLevels(2, {target: [0.0, 1.0]})
