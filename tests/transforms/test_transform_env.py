"""``TaskTransform`` on single-process torch envs: partial resets, gradients, set-up errors and outputs.

Expected values come from independent sources: batch-1 runs of the same sub-envs, central finite
differences, hand computation on a replay env, and closed-form reward terms recomputed from the
stored states.
"""

from __future__ import annotations

import functools
import math
import warnings

import gymnasium as gym
import pytest
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl import set_auto_unwrap_transformed_env
from torchrl.envs import Compose, GymEnv, GymWrapper, RewardSum, StepCounter, TransformedEnv
from torchrl.envs.utils import check_env_specs

from replay_env import ReplayEnv, replay_policy
from torchtasks.envs import PendulumEnv
from torchtasks.rewards import CompoundReward, ConstantReward, QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import (
    BestStateFinalRewardTask,
    DesiredStateTask,
    FinalRewardMode,
    FinalRewardTask,
    proximity_succeeded,
)
from torchtasks.transforms import TaskTransform

F64 = torch.float64
SPEED_LIMIT = 4.5  # failure: |angular speed| > 4.5
SUCCESS_RADIUS = 0.7  # success: within 0.7 of hanging still
PENDULUM_ACTIONS = Box([-2.0], [2.0])


class LinearPolicy(nn.Module):
    """``a = k_angle·θ + k_speed·θ̇ (+ bias)``, written elementwise so every row is computed alike in any batch."""

    def __init__(self, k_angle: float, k_speed: float, bias: float = 0.0) -> None:
        super().__init__()
        self.gains = nn.Parameter(torch.tensor([k_angle, k_speed], dtype=F64))
        self.bias = nn.Parameter(torch.tensor([bias], dtype=F64))

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return observation[..., 0:1] * self.gains[0] + observation[..., 1:2] * self.gains[1] + self.bias


def _policy(k_angle: float = 0.3, k_speed: float = 0.8, bias: float = 0.0) -> TensorDictModule:
    return TensorDictModule(LinearPolicy(k_angle, k_speed, bias), in_keys=["observation"], out_keys=["action"])


def _swing_task() -> FinalRewardTask:
    """Reach 'hanging still' ([π, 0]); fail above a speed limit; final reward ± remaining steps."""
    spec = EnvSpec(Box([-3 * math.pi, -SPEED_LIMIT], [3 * math.pi, SPEED_LIMIT]), PENDULUM_ACTIONS)
    success = functools.partial(proximity_succeeded, threshold=SUCCESS_RADIUS)
    inner = DesiredStateTask(spec, [math.pi, 0.0], QuadraticErrorReward([1.0, 0.1], [0.01]), success)
    return FinalRewardTask(inner, FinalRewardMode(time_dependent=True))


class ScriptedPendulumEnv(PendulumEnv):
    """A batch-1 :class:`PendulumEnv` whose resets start from given states, in order (then zeros)."""

    def __init__(self, init_states: list[torch.Tensor], **kwargs) -> None:
        super().__init__(batch_size=[1], dtype=F64, **kwargs)
        self._init_states = list(init_states)

    def _sample_state(self) -> torch.Tensor:
        state = self._init_states.pop(0) if self._init_states else torch.zeros(2, dtype=F64)
        return state.reshape(1, 2).clone()


def _pendulum_env(base: PendulumEnv, max_steps: int, **transform_kwargs) -> TransformedEnv:
    return TransformedEnv(base, Compose(StepCounter(max_steps), TaskTransform(_swing_task(), **transform_kwargs)))


def _equal(a: torch.Tensor | TensorDictBase, b: torch.Tensor | TensorDictBase) -> bool:
    if isinstance(a, TensorDictBase):
        return (
            a.batch_size == b.batch_size and set(a.keys(True, True)) == set(b.keys(True, True)) and bool((a == b).all())
        )
    return a.shape == b.shape and torch.equal(a, b)


# --------------------------------------------------------------------------------------------------
# Partial resets
# --------------------------------------------------------------------------------------------------

BATCH, STEPS, MAX_STEPS, SEED = 6, 60, 25, 3


@pytest.fixture(scope="module")
def batched_rollout() -> TensorDictBase:
    env = _pendulum_env(PendulumEnv([BATCH], dtype=F64, seed=SEED), MAX_STEPS)
    with torch.no_grad():
        return env.rollout(STEPS, _policy(), break_when_any_done=False)


def test_partial_resets_happen_at_different_times(batched_rollout: TensorDictBase) -> None:
    """The set-up is meaningful: envs end at different steps, by success, failure and time limit."""
    done = batched_rollout["next", "done"].squeeze(-1)
    assert done.sum() >= 2 * BATCH
    first_ends = {int(row.nonzero()[0]) for row in done if row.any()}
    assert len(first_ends) >= 3, first_ends
    assert batched_rollout["next", "success"].any() and batched_rollout["next", "failure"].any()
    assert batched_rollout["next", "truncated"].any()
    # some step has done and not-done envs side by side
    assert ((done.sum(0) > 0) & (done.sum(0) < BATCH)).any()


def test_partial_reset_leaves_other_envs_untouched(batched_rollout: TensorDictBase) -> None:
    """Env not done at t: memory, state and step count carry over to t+1; env done at t: fresh memory."""
    data = batched_rollout
    task = _swing_task().double()
    done = data["next", "done"].squeeze(-1)
    for t in range(STEPS - 1):
        for b in range(BATCH):
            if not done[b, t]:
                assert _equal(data["task"][b, t + 1], data["next", "task"][b, t]), (b, t)
                assert _equal(data["observation"][b, t + 1], data["next", "observation"][b, t]), (b, t)
                assert int(data["step_count"][b, t + 1]) == int(data["next", "step_count"][b, t])
                assert bool(data["success"][b, t + 1]) == bool(data["next", "success"][b, t])
            else:
                fresh = task.reset(data["observation"][b, t + 1].unsqueeze(0))[0]
                assert _equal(data["task"][b, t + 1], fresh), (b, t)
                assert int(data["step_count"][b, t + 1]) == 0
                assert not data["success"][b, t + 1].any() and not data["failure"][b, t + 1].any()


def test_partial_resets_equal_independent_single_env_runs(batched_rollout: TensorDictBase) -> None:
    """Each row of the batch equals a batch-1 run started from the same initial states with the same policy."""
    data = batched_rollout
    done = data["next", "done"].squeeze(-1)
    keys = [
        "observation",
        "action",
        "step_count",
        "task",
        "success",
        "failure",
        ("next", "observation"),
        ("next", "reward"),
        ("next", "done"),
        ("next", "terminated"),
        ("next", "truncated"),
        ("next", "success"),
        ("next", "failure"),
        ("next", "step_count"),
        ("next", "task"),
        ("next", "task_reward"),
    ]
    for b in range(BATCH):
        starts = [data["observation"][b, 0]] + [data["observation"][b, t + 1] for t in range(STEPS - 1) if done[b, t]]
        env = _pendulum_env(ScriptedPendulumEnv(starts, seed=0), MAX_STEPS)
        with torch.no_grad():
            single = env.rollout(STEPS, _policy(), break_when_any_done=False)[0]
        for key in keys:
            assert _equal(single[key], data[key][b]), f"env {b}: {key} differs from its batch-1 run"


def test_pendulum_env_specs() -> None:
    check_env_specs(_pendulum_env(PendulumEnv([BATCH], dtype=F64, seed=SEED), MAX_STEPS), seed=None)
    check_env_specs(_pendulum_env(PendulumEnv([2, 3], seed=SEED), MAX_STEPS), seed=None)
    check_env_specs(_pendulum_env(ScriptedPendulumEnv([]), MAX_STEPS), seed=None)


# --------------------------------------------------------------------------------------------------
# Gradients through env.rollout
# --------------------------------------------------------------------------------------------------

GRAD_STEPS = 12


def _gradient_env() -> TransformedEnv:
    """No success or failure (unbounded box), truncation at the last step: BestState pays its final reward."""
    spec = EnvSpec(2, PENDULUM_ACTIONS)
    inner = DesiredStateTask(spec, [0.0, 0.0], QuadraticErrorReward([1.0, 0.1], [0.05]))
    task = BestStateFinalRewardTask(inner, 2.0)
    base = PendulumEnv([3], dtype=F64, seed=7, init_angle=0.6, init_speed=0.5)
    return TransformedEnv(base, Compose(StepCounter(GRAD_STEPS), TaskTransform(task)))


def _total_reward(policy: TensorDictModule) -> tuple[torch.Tensor, TensorDictBase]:
    data = _gradient_env().rollout(GRAD_STEPS, policy, break_when_any_done=False)
    return data["next", "reward"].sum(), data


def test_gradient_of_rewards_matches_finite_differences() -> None:
    check_env_specs(_gradient_env(), seed=None)
    policy = _policy(-0.2, -0.1, 0.1)
    total, data = _total_reward(policy)
    # the finite differences need a smooth rollout: no clipping, no episode end before the last step
    assert data["action"].abs().max() < 2.0 and data["next", "observation"][..., 1].abs().max() < 8.0
    assert not data["next", "done"][:, :-1].any() and data["next", "truncated"][:, -1].all()
    assert (data["next", "task_reward", "final"][:, -1] != 0).all()
    params = list(policy.parameters())
    grads = torch.autograd.grad(total, params)
    eps = 1e-6
    for param, grad in zip(params, grads, strict=True):
        assert grad.abs().sum() > 0
        numeric = torch.zeros_like(param)
        for i in range(param.numel()):
            values = []
            for sign in (1.0, -1.0):
                with torch.no_grad():
                    param.view(-1)[i] += sign * eps
                    values.append(_total_reward(policy)[0])
                    param.view(-1)[i] -= sign * eps
            numeric.view(-1)[i] = (values[0] - values[1]) / (2 * eps)
        torch.testing.assert_close(grad, numeric, rtol=1e-5, atol=1e-7)


# --------------------------------------------------------------------------------------------------
# Set-ups that cannot work fail loudly, with the fix in the message
# --------------------------------------------------------------------------------------------------


def _pendulum_task(state_size: int = 2) -> DesiredStateTask:
    return DesiredStateTask(EnvSpec(state_size, 1), [0.0] * state_size, QuadraticErrorReward([1.0] * state_size, None))


def _build_and_reset(make_env) -> None:
    env = make_env()
    env.reset()


MISSING_KEY = (
    r"state key 'joint_pos' is not in the observation spec; available keys are \['observation'\]\. Pass state_key="
)


def _missing_key_env() -> TransformedEnv:
    return TransformedEnv(PendulumEnv([2]), TaskTransform(_pendulum_task(), state_key="joint_pos"))


def test_missing_state_key_raises_when_specs_are_built() -> None:
    env = _missing_key_env()
    with pytest.raises(KeyError, match=MISSING_KEY):
        env.observation_spec  # noqa: B018


def test_missing_state_key_raises_at_first_reset() -> None:
    env = _missing_key_env()
    with pytest.raises(KeyError, match=MISSING_KEY):
        env.reset()


def test_wrong_state_size_raises() -> None:
    def make():
        return TransformedEnv(PendulumEnv([2]), TaskTransform(_pendulum_task(3)))

    with pytest.raises(ValueError, match=r"size 3 .* 2 entries; build the task for this env's state or pick another"):
        _build_and_reset(make)


def test_step_counter_after_transform_raises() -> None:
    def make():
        return TransformedEnv(PendulumEnv([2]), Compose(TaskTransform(_pendulum_task()), StepCounter(10)))

    with pytest.raises(ValueError, match=r"Put StepCounter\(max_steps\) before TaskTransform"):
        _build_and_reset(make)


def _gym_pendulum_task() -> DesiredStateTask:
    """Gymnasium's Pendulum-v1 observes [cos θ, sin θ, θ̇]."""
    return DesiredStateTask(EnvSpec(3, 1), [1.0, 0.0, 0.0], QuadraticErrorReward([1.0, 1.0, 0.1], [0.001]))


def _make_vec(mode: gym.vector.AutoresetMode) -> GymWrapper:
    vector_env = gym.make_vec(
        "Pendulum-v1", num_envs=2, vectorization_mode="sync", vector_kwargs={"autoreset_mode": mode}
    )
    return GymWrapper(vector_env)


def test_autoresetting_gymnasium_vector_env_raises() -> None:
    def make():
        return TransformedEnv(_make_vec(gym.vector.AutoresetMode.SAME_STEP), TaskTransform(_gym_pendulum_task()))

    with set_auto_unwrap_transformed_env(True), pytest.raises(ValueError, match="ParallelEnv"):  # nesting on purpose
        _build_and_reset(make)


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
def test_gym_env_num_envs_raises() -> None:
    base = GymEnv("Pendulum-v1", num_envs=2)
    try:
        # GymEnv(num_envs=2) is a TransformedEnv: the nesting is the test's point
        with set_auto_unwrap_transformed_env(True), pytest.raises(ValueError, match="ParallelEnv"):
            env = TransformedEnv(base, Compose(StepCounter(10), TaskTransform(_gym_pendulum_task())))
            env.reset()
    finally:
        base.close()


def test_vector_env_without_autoreset_works() -> None:
    """The fix the error message names: a Gymnasium vector env with autoreset DISABLED."""
    env = TransformedEnv(
        _make_vec(gym.vector.AutoresetMode.DISABLED), Compose(StepCounter(5), TaskTransform(_gym_pendulum_task()))
    )
    check_env_specs(env, seed=None)
    data = env.rollout(12, break_when_any_done=False)
    assert data["next", "truncated"].squeeze(-1).sum(-1).tolist() == [2, 2]
    # the reward is the task's (recomputed by hand from the stored next observation and action)
    obs, action = data["next", "observation"].double(), data["action"].double()
    expected = -((obs - torch.tensor([1.0, 0.0, 0.0], dtype=F64)) ** 2 * torch.tensor([1.0, 1.0, 0.1], dtype=F64)).sum(
        -1
    )
    expected = expected - 0.001 * action[..., 0] ** 2
    torch.testing.assert_close(data["next", "reward"].squeeze(-1).double(), expected, rtol=1e-5, atol=1e-5)


# --------------------------------------------------------------------------------------------------
# Outputs: reward breakdown, reward_on, remaining steps, compile
# --------------------------------------------------------------------------------------------------


def _terms_task() -> FinalRewardTask:
    spec = EnvSpec(Box([-3 * math.pi, -SPEED_LIMIT], [3 * math.pi, SPEED_LIMIT]), PENDULUM_ACTIONS)
    reward = CompoundReward(
        {
            "angle": QuadraticErrorReward([1.0, 0.0], None),
            "speed": QuadraticErrorReward([0.0, 0.1], None),
            "effort": QuadraticErrorReward([0.0, 0.0], [0.01]),
            "alive": ConstantReward(0.5),
        }
    )
    success = functools.partial(proximity_succeeded, threshold=SUCCESS_RADIUS)
    inner = DesiredStateTask(spec, [math.pi, 0.0], reward, success)
    return FinalRewardTask(inner, FinalRewardMode(), factor=10.0)


def test_reward_breakdown_and_episode_sums() -> None:
    transforms = Compose(StepCounter(MAX_STEPS), TaskTransform(_terms_task()), RewardSum())
    env = TransformedEnv(PendulumEnv([BATCH], dtype=F64, seed=SEED), transforms)
    check_env_specs(env, seed=None)
    with torch.no_grad():
        data = env.rollout(STEPS, _policy(), break_when_any_done=False)
    nxt = data["next"]
    names = ("angle", "speed", "effort", "alive")
    for key in ("step", "final", *names):
        assert ("task_reward", key) in nxt.keys(True, True)
    # the terms, by hand from the next state (reward_on="next") and the action
    state, action = nxt["observation"], data["action"]
    by_hand = {
        "angle": -((math.pi - state[..., 0]) ** 2),
        "speed": -0.1 * state[..., 1] ** 2,
        "effort": -0.01 * action[..., 0] ** 2,
        "alive": torch.full_like(state[..., 0], 0.5),
    }
    for name in names:
        torch.testing.assert_close(nxt["task_reward", name].squeeze(-1), by_hand[name], rtol=1e-12, atol=1e-12)
    term_sum = sum(nxt["task_reward", name] for name in names)
    torch.testing.assert_close(nxt["task_reward", "step"], term_sum, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(nxt["reward"], nxt["task_reward", "step"] + nxt["task_reward", "final"])
    # the final reward is ±10 exactly where an episode ends by success or failure, 0 elsewhere
    final = nxt["task_reward", "final"]
    expected_final = 10.0 * nxt["success"].to(F64) * ~nxt["failure"] - 10.0 * nxt["failure"].to(F64)
    torch.testing.assert_close(final, expected_final)
    assert (final != 0).any()
    # RewardSum: per-term episode sums, restarted after each end
    done = nxt["done"].squeeze(-1)
    for name, out in [("reward", "episode_reward")] + [
        (("task_reward", n), ("task_reward", f"episode_{n}")) for n in ("step", "final", *names)
    ]:
        values = nxt[name].squeeze(-1)
        running = torch.zeros(BATCH, dtype=F64)
        expected = torch.zeros_like(values)
        for t in range(STEPS):
            running = running + values[:, t]
            expected[:, t] = running
            running = torch.where(done[:, t], torch.zeros_like(running), running)
        torch.testing.assert_close(nxt[out].squeeze(-1), expected, rtol=1e-12, atol=1e-12)


def _line_env(states: list[float], actions: list[float], transforms) -> TransformedEnv:
    episode = ([[s] for s in states], [[a] for a in actions])
    return TransformedEnv(ReplayEnv([episode]), transforms)


@pytest.mark.parametrize(
    ("reward_on", "expected"),
    [("state", [-0.5, -1.5, -9.5]), ("next", [-1.5, -9.5, -36.5])],
)
def test_reward_on_state_or_next(reward_on: str, expected: list[float]) -> None:
    """Reward -(e² + 2a²) with e = 0 - s and a = 0.5 on states 0, 1, 3, 6: on s_t or on s_{t+1}."""
    task = DesiredStateTask(EnvSpec(1, 1), [0.0], QuadraticErrorReward([1.0], [2.0]))
    env = _line_env([0.0, 1.0, 3.0, 6.0], [0.5, 0.5, 0.5], TaskTransform(task, reward_on=reward_on))
    check_env_specs(_line_env([0.0, 1.0, 3.0, 6.0], [0.5, 0.5, 0.5], TaskTransform(task, reward_on=reward_on)))
    data = env.rollout(3, replay_policy())
    assert data["next", "reward"].squeeze(-1).tolist() == expected


def _goal_task() -> FinalRewardTask:
    """Step reward -1; success within 0.5 of 3; failure outside [-10, 10]; final reward ±remaining steps."""
    spec = EnvSpec(Box([-10.0], [10.0]), Box([-1.0], [1.0]))
    success = functools.partial(proximity_succeeded, threshold=0.5)
    inner = DesiredStateTask(spec, [3.0], ConstantReward(-1.0), success)
    return FinalRewardTask(inner, FinalRewardMode(time_dependent=True))


@pytest.mark.parametrize(
    ("states", "max_steps", "expected"),
    [
        ([0.0, 1.0, 2.0, 3.0], 10, [-1.0, -1.0, -1.0 + 7.0]),  # success at step_count 3: +(10 - 3)
        ([0.0, 5.0, 11.0], 10, [-1.0, -1.0 - 8.0]),  # failure at step_count 2: -(10 - 2)
        ([0.0, 1.0, 2.0, 3.0], 3, [-1.0, -1.0, -1.0 + 0.0]),  # success on the last allowed step: +0
        ([0.0, 1.0, 1.0, 1.0, 1.0], 4, [-1.0, -1.0, -1.0, -1.0]),  # time limit, neither: 0
        ([0.0, 1.0, 2.0, 3.0], None, [-1.0, -1.0, -1.0]),  # no StepCounter: remaining steps are 0, with a warning
        ([0.0, 1.0, 2.0, 3.0], math.inf, [-1.0, -1.0, -1.0]),  # no limit on purpose: the same, without a warning
    ],
)
def test_remaining_steps_reach_the_task(
    states: list[float], max_steps: int | float | None, expected: list[float]
) -> None:
    actions = [0.0] * (len(states) - 1)

    def make() -> TransformedEnv:
        transforms = [StepCounter(max_steps)] if isinstance(max_steps, int) else []
        no_limit = {"max_steps": max_steps} if max_steps == math.inf else {}
        task = TaskTransform(_goal_task(), reward_on="state", **no_limit)
        return _line_env(states, actions, Compose(*transforms, task))

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env_specs(make(), seed=None)
        data = make().rollout(len(expected), replay_policy(), break_when_any_done=True)
    no_limit_warnings = [w for w in caught if "no time limit reaches the transform" in str(w.message)]
    assert len(no_limit_warnings) == (2 if max_steps is None else 0)  # once per env
    assert data["next", "reward"].squeeze(-1).tolist() == expected
    assert data["next", "done"][-1].item() and not data["next", "done"][:-1].any()


@pytest.mark.slow
@pytest.mark.xdist_group("inductor")  # with the other Inductor compilations (test_tasks_autodiff_compile.py)
def test_compile_gives_the_eager_rollout() -> None:
    def run(compile: bool) -> TensorDictBase:
        env = _pendulum_env(PendulumEnv([4], dtype=F64, seed=SEED), MAX_STEPS, compile=compile)
        with torch.no_grad():
            return env.rollout(30, _policy(), break_when_any_done=False)

    eager, compiled = run(False), run(True)
    check_env_specs(_pendulum_env(PendulumEnv([4], dtype=F64, seed=SEED), MAX_STEPS, compile=True), seed=None)
    assert eager["next", "done"].any()
    for key in [("next", "done"), ("next", "success"), ("next", "failure"), "observation", "step_count"]:
        assert torch.equal(compiled[key], eager[key]), key
    for key in [("next", "reward"), ("next", "task_reward", "final"), ("next", "task", "wrapped", "state_des")]:
        torch.testing.assert_close(compiled[key], eager[key], rtol=1e-12, atol=1e-12)
    assert torch.equal(compiled["next", "task", "paid"], eager["next", "task", "paid"])


def test_transform_output_dtypes() -> None:
    """Flags are bool [*B, 1]; a float32 env gets a float32 reward; the memory follows the state dtype."""
    env = _pendulum_env(PendulumEnv([3], seed=SEED), MAX_STEPS)
    data = env.rollout(5, break_when_any_done=False)
    assert data["next", "success"].dtype == torch.bool and data["next", "success"].shape == (3, 5, 1)
    assert data["next", "reward"].dtype == torch.float32
    assert data["next", "task", "wrapped", "state_des"].dtype == torch.float32
