"""PotentialShapingTask: the per-step rule and the telescoping identity on data collected by TorchRL.

Over every episode the shaping terms must telescope, ``Σ_t γ^t F_t = γ^T Φ(s_T)·[not terminated] − Φ(s_0)``,
and each step must follow ``F_t = γ·Φ(s_{t+1})·(1 − terminated_{t+1}) − Φ(s_t)``, with ``s_t`` the new
episode's first state right after a partial reset. The data comes from ``env.rollout``, ``SerialEnv``/
``ParallelEnv`` and a ``Collector`` over batched pendulums whose episodes end by success, failure and
truncation at different steps; Φ and the expected values are recomputed here from the stored observations.
"""

from __future__ import annotations

import functools

import pytest
import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.envs import Compose, ParallelEnv, RewardSum, SerialEnv, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv
from torchtasks.rewards import ConstantReward, QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import DesiredStateTask, FinalRewardTask, GoallessTask, PotentialShapingTask, proximity_succeeded
from torchtasks.transforms import TaskTransform

GAMMA = 0.9
MAX_STEPS = 12


def potential(state: torch.Tensor) -> torch.Tensor:
    """Φ(s) = −θ² − 0.1·θ̇²: higher near upright and at rest (recomputed independently in the checks)."""
    return -(state[..., 0] ** 2) - 0.1 * state[..., 1] ** 2


def shaped_task() -> PotentialShapingTask:
    near = functools.partial(proximity_succeeded, threshold=0.2, dims=0)
    spec = EnvSpec(Box([-0.9, -8.5], [0.9, 8.5]), 1)  # failure: |θ| > 0.9
    inner = DesiredStateTask(spec, [0.0, 0.0], QuadraticErrorReward([1.0, 0.1], [0.01]), success=near)
    return PotentialShapingTask(FinalRewardTask(inner, factor=5.0), potential, gamma=GAMMA)


def make_env(batch: int = 8, seed: int = 0, compile: bool = False) -> TransformedEnv:
    base = PendulumEnv(batch_size=[batch], seed=seed, dtype=torch.float64, init_angle=0.6, init_speed=1.5)
    return TransformedEnv(
        base, Compose(StepCounter(MAX_STEPS), TaskTransform(shaped_task(), compile=compile), RewardSum())
    )


def check_shaping(data: TensorDictBase) -> dict[str, int]:
    """Check the per-step rule and the telescoping identity on ``[envs, time]`` data; count episode ends."""
    state, next_state = data["observation"], data["next", "observation"]
    shaping = data["next", "task_reward", "shaping"][..., 0]
    terminated = data["next", "terminated"][..., 0]
    truncated = data["next", "truncated"][..., 0]
    done = data["next", "done"][..., 0]
    expected = GAMMA * torch.where(terminated, 0.0, potential(next_state)) - potential(state)
    torch.testing.assert_close(shaping, expected, rtol=0, atol=1e-12)
    counts = {"success": 0, "failure": 0, "truncation": 0, "episodes": 0}
    for env in range(data.shape[0]):
        start = 0
        for t in range(data.shape[1]):
            last = t == data.shape[1] - 1
            if not (done[env, t] or last):
                continue
            steps = torch.arange(t - start + 1, dtype=torch.float64)
            discounted = (GAMMA**steps * shaping[env, start : t + 1]).sum()
            bootstrap = 0.0 if terminated[env, t] else GAMMA ** (t - start + 1) * potential(next_state[env, t])
            identity = bootstrap - potential(state[env, start])
            torch.testing.assert_close(discounted, torch.as_tensor(identity, dtype=torch.float64), rtol=0, atol=1e-9)
            if done[env, t]:
                counts["episodes"] += 1
                counts["success"] += int(data["next", "success"][env, t, 0])
                counts["failure"] += int(data["next", "failure"][env, t, 0])
                counts["truncation"] += int(truncated[env, t] and not terminated[env, t])
            start = t + 1
    return counts


def test_rollout_follows_the_rule_and_telescopes_with_every_kind_of_episode_end():
    env = make_env(batch=12, seed=1)
    data = env.rollout(60, break_when_any_done=False)
    counts = check_shaping(data)
    assert counts["success"] > 0 and counts["failure"] > 0 and counts["truncation"] > 0, counts
    # right after a partial reset, s_t is the new episode's first state (StepCounter restarted at 0)
    reset_steps = data["step_count"][..., 0] == 0
    assert reset_steps[:, 1:].any()


def test_reward_includes_the_shaping_and_the_breakdown_adds_up():
    data = make_env(batch=6, seed=2).rollout(30, break_when_any_done=False)
    terms = data["next", "task_reward"]
    torch.testing.assert_close(terms["task"] + terms["shaping"], terms["step"], rtol=0, atol=1e-12)
    torch.testing.assert_close(terms["step"] + terms["final"], data["next", "reward"], rtol=0, atol=1e-12)
    # RewardSum reports the shaping term's running sum per episode
    episode = data["next", "task_reward", "episode_shaping"][..., 0]
    shaping = terms["shaping"][..., 0]
    first_step = data["step_count"][..., 0] == 0
    for env in range(episode.shape[0]):
        running = 0.0
        for t in range(episode.shape[1]):
            running = (0.0 if first_step[env, t] else running) + float(shaping[env, t])
            assert abs(float(episode[env, t]) - running) < 1e-9


def test_offline_reward_fn_recomputes_the_online_rewards():
    env = make_env(batch=6, seed=3)
    data = env.rollout(40, break_when_any_done=False)
    transform = env.transform[1]
    torch.testing.assert_close(transform.reward_fn(data), data["next", "reward"], rtol=0, atol=1e-12)


@pytest.mark.multiprocess
@pytest.mark.parametrize("placement", ["serial", "parallel"])
def test_batched_envs_of_workers(placement: str):
    factory = functools.partial(PendulumEnv, batch_size=[3], dtype=torch.float64, init_angle=0.6, init_speed=1.5)
    if placement == "serial":
        batched = SerialEnv(2, factory)
    else:
        batched = ParallelEnv(2, factory, mp_start_method="fork")
    env = TransformedEnv(batched, Compose(StepCounter(MAX_STEPS), TaskTransform(shaped_task())))
    env.set_seed(4)
    data = env.rollout(40, break_when_any_done=False).reshape(6, 40)
    env.close()
    counts = check_shaping(data)
    assert counts["episodes"] > 6


def test_collector_data():
    env = make_env(batch=8, seed=5)
    collector = Collector(env, None, frames_per_batch=8 * 30, total_frames=8 * 60)
    episodes = 0
    for batch in collector:
        episodes += check_shaping(batch)["episodes"]
    collector.shutdown()
    assert episodes > 8


@pytest.mark.xdist_group("inductor")  # with the other Inductor compilations (test_tasks_autodiff_compile.py)
def test_compiled_transform_equals_eager():
    torch.manual_seed(0)  # the random actions
    eager = make_env(batch=6, seed=6).rollout(20, break_when_any_done=False)
    torch.manual_seed(0)
    compiled = make_env(batch=6, seed=6, compile=True).rollout(20, break_when_any_done=False)
    torch.testing.assert_close(compiled["action"], eager["action"], rtol=0, atol=0)
    torch.testing.assert_close(compiled["next", "reward"], eager["next", "reward"], rtol=0, atol=1e-12)


def test_fine_grained_calls_give_the_transition_numbers():
    task = shaped_task().double()
    generator = torch.Generator().manual_seed(0)
    state = (torch.rand(16, 2, generator=generator, dtype=torch.float64) - 0.5) * 2.2
    memory = task.reset(state)
    action = torch.rand(16, 1, generator=generator, dtype=torch.float64)
    for _ in range(4):
        next_state = state + 0.3 * (torch.rand(16, 2, generator=generator, dtype=torch.float64) - 0.5)
        out = task.transition(state, action, next_state, memory)
        terms, reward, fine = task.step_reward_terms(next_state, action, memory)
        done = task.is_done(next_state, fine)
        final, fine = task.final_reward(next_state, fine, 0, done)
        assert torch.equal(out.step_reward, reward) and torch.equal(out.final_reward, final)
        assert torch.equal(out.terms["shaping"], terms["shaping"])
        assert torch.equal(out.memory["potential"], fine["potential"])
        state, memory = next_state, out.memory


def test_env_termination_is_absorbing_and_truncation_bootstraps():
    task = PotentialShapingTask(GoallessTask(EnvSpec(1, 1), ConstantReward(0.0)), lambda s: s[..., 0], gamma=0.5)
    state, next_state = torch.full((3, 1), 2.0), torch.full((3, 1), 4.0)
    out = task.transition(
        state,
        torch.zeros(3, 1),
        next_state,
        task.reset(state),
        terminated=torch.tensor([False, True, False]),
        truncated=torch.tensor([False, False, True]),
    )
    assert out.reward.tolist() == [0.5 * 4.0 - 2.0, -2.0, 0.5 * 4.0 - 2.0]


def test_gradients_flow_into_a_learnable_potential():
    phi = QuadraticErrorReward([1.0, 0.5], None, learnable=True)
    task = PotentialShapingTask(GoallessTask(EnvSpec(2, 1), ConstantReward(0.0)), phi, gamma=0.99)
    state = torch.ones(4, 2, dtype=torch.float64)
    out = task.transition(state, torch.zeros(4, 1, dtype=torch.float64), 2 * state, task.reset(state))
    out.reward.sum().backward()
    assert phi.Q.grad is not None and torch.isfinite(phi.Q.grad).all() and (phi.Q.grad != 0).all()


def test_bad_arguments():
    inner = GoallessTask(EnvSpec(1, 1), ConstantReward(0.0))
    with pytest.raises(ValueError, match=r"gamma must lie in \[0, 1\]"):
        PotentialShapingTask(inner, lambda s: s[..., 0], gamma=1.5)
    with pytest.raises(TypeError, match="potential must be a callable"):
        PotentialShapingTask(inner, 3.0, gamma=0.9)
    task = PotentialShapingTask(inner, lambda s: s, gamma=0.9)  # returns [*B, 1], not [*B]
    with pytest.raises(ValueError, match=r"potential must return a floating tensor of shape \(2,\)"):
        task.reset(torch.zeros(2, 1))
