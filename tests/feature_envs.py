"""The combinations users build, one env factory per feature, for the invariant suite (``test_invariants.py``).

Every factory is a module-level function of ``(batch, seed)`` (picklable: multi-process collectors and
``ParallelEnv`` workers build their envs from it) returning a ``TransformedEnv`` with a ``StepCounter`` first,
the feature's ``TaskTransform``, its run-state transforms (command, curriculum, levels) and a ``RewardSum``
over the reward, the breakdown, the costs and the reward groups, then a ``BaseEnvState`` (so a checkpoint holds
the base env), as the docs build them. Each feature comes with a deterministic policy (module-level, picklable)
that makes episodes end in every way the feature can end them.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import torch
from tensordict.nn import TensorDictModule
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv

from torchtasks.domain import BernoulliDomainParam, NormalDomainParam, UniformDomainParam
from torchtasks.envs import PendulumEnv, PointMassEnv, swing_up_task
from torchtasks.rewards import QuadraticErrorReward, StateFunctionReward, VelocityReward
from torchtasks.rewards.terms import HealthyReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import (
    ConstrainedTask,
    Constraint,
    DesiredStateTask,
    GoallessTask,
    MaskedTask,
    PotentialShapingTask,
    RewardGroupsTask,
    proximity_succeeded,
)
from torchtasks.transforms import (
    BaseEnvState,
    Curriculum,
    DifficultyLevels,
    DomainRandomization,
    EntryNoise,
    GoalCommand,
    ObservationNoise,
    TaskTransform,
    linear,
)

MAX_STEPS = 12
SCHEDULED = "wrapped_task.reward.rewards.effort.R"  # swing_up_task's effort weight, ramped by the curriculum feature


def summed_keys(task_transform: TaskTransform) -> list:
    """The entries the suite's RewardSum sums: the reward, the breakdown, the costs and the reward groups (the vector
    reward and one entry per group)."""
    groups = task_transform.entries.keys(argument="vector_reward_key") + task_transform.entries.keys(
        argument="groups_key"
    )
    return ["reward", *task_transform.term_keys, *task_transform.cost_keys, *groups]


def _finish(env, task_transform: TaskTransform, *run_state) -> TransformedEnv:
    sums = RewardSum(in_keys=summed_keys(task_transform))
    return TransformedEnv(env, Compose(StepCounter(MAX_STEPS), task_transform, *run_state, sums, BaseEnvState()))


def plain(batch: int, seed: int) -> TransformedEnv:
    """The README's first task: no named terms, no final reward (TaskTransform writes no breakdown)."""
    near = functools.partial(proximity_succeeded, threshold=0.6)
    task = DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], QuadraticErrorReward([1.0, 0.1], [1e-3]), near)
    return _finish(PendulumEnv(batch_size=[batch], seed=seed), TaskTransform(task))


def terms_and_final(batch: int, seed: int) -> TransformedEnv:
    """Named terms (track, effort) and a final reward on success."""
    return _finish(PendulumEnv(batch_size=[batch], seed=seed), TaskTransform(swing_up_task(success_threshold=0.6)))


def _height(state: torch.Tensor) -> torch.Tensor:
    return torch.cos(state[..., 0])


def shaping(batch: int, seed: int) -> TransformedEnv:
    """Potential-based shaping over the swing-up task."""
    task = PotentialShapingTask(swing_up_task(success_threshold=0.6), _height, gamma=0.99)
    return _finish(PendulumEnv(batch_size=[batch], seed=seed), TaskTransform(task))


def _reach_task() -> DesiredStateTask:
    spec = EnvSpec(Box([-1.0, -1.0, -10.0, -10.0], [1.0, 1.0, 10.0, 10.0], labels=PointMassEnv.labels), 2)
    near = functools.partial(proximity_succeeded, threshold=0.3)
    return DesiredStateTask(spec.select_state(["x", "y"]), [0.0, 0.0], QuadraticErrorReward([1.0, 1.0]), near)


def _masked_reach() -> MaskedTask:
    spec = EnvSpec(Box([-1.0, -1.0, -10.0, -10.0], [1.0, 1.0, 10.0, 10.0], labels=PointMassEnv.labels), 2)
    return MaskedTask(spec, _reach_task(), ["x", "y"])


def goal_command(batch: int, seed: int) -> TransformedEnv:
    """Goals drawn per env by a GoalCommand, redrawn on a timer; the task judges the goal the policy saw."""
    command = GoalCommand(Box([-0.5, -0.5], [0.5, 0.5]), resample_steps=(3, 5), seed=seed)
    return _finish(
        PointMassEnv(batch_size=[batch], seed=seed), TaskTransform(_masked_reach(), goal_key="goal"), command
    )


def curriculum(batch: int, seed: int) -> TransformedEnv:
    """A Curriculum ramping the effort weight and the success reward over the first frames."""
    schedules = {SCHEDULED: linear(0.0, 1.0, 0, 200), "success_value": linear(10.0, 100.0, 0, 200)}
    task = TaskTransform(swing_up_task(success_threshold=0.6))
    return _finish(PendulumEnv(batch_size=[batch], seed=seed), task, Curriculum(schedules))


def levels(batch: int, seed: int) -> TransformedEnv:
    """Per-env difficulty levels setting the GoalCommand's range, moved at each env's episode ends."""
    tables = {
        "command.low": [[-0.1, -0.1], [-0.3, -0.3], [-0.5, -0.5]],
        "command.high": [[0.1, 0.1], [0.3, 0.3], [0.5, 0.5]],
    }
    command = GoalCommand(Box([-0.5, -0.5], [0.5, 0.5]), seed=seed)
    task = TaskTransform(_masked_reach(), goal_key="goal")
    return _finish(PointMassEnv(batch_size=[batch], seed=seed), task, DifficultyLevels(3, tables), command)


def _pendulum_params() -> list:
    return [
        UniformDomainParam("mass", mean=1.0, halfspan=0.0),
        NormalDomainParam("length", mean=1.0, std=0.1, clip_lo=0.7, clip_up=1.3),
        BernoulliDomainParam("gravity", val_0=9.0, val_1=11.0, prob_1=0.5),
    ]


def domain(batch: int, seed: int) -> TransformedEnv:
    """Per-env pendulum physics drawn at every reset, the mass's range widened by a Curriculum."""
    task = TaskTransform(swing_up_task(success_threshold=0.6))
    curriculum = Curriculum({"domain.mass.halfspan": linear(0.0, 0.5, 0, 200)})
    randomization = DomainRandomization(_pendulum_params(), seed=seed)
    return _finish(PendulumEnv(batch_size=[batch], seed=seed), task, randomization, curriculum)


def observation_noise(batch: int, seed: int) -> TransformedEnv:
    """Noise and a per-episode bias on a copy of the pendulum's observation (the policy's), each env's noise std drawn
    at every reset and its range widened by a Curriculum."""
    task = TaskTransform(swing_up_task(success_threshold=0.6))
    noise = ObservationNoise({"observation": EntryNoise(std=0.05, bias=0.1, out_key="noisy_observation")}, seed=seed)
    stds = UniformDomainParam("observation_noise:observation", mean=[0.05, 0.05], halfspan=[0.0, 0.0])
    randomization = DomainRandomization([stds], seed=seed + 1)
    curriculum = Curriculum({"domain.observation_noise:observation.halfspan": linear(0.0, 0.05, 0, 200)})
    return _finish(PendulumEnv(batch_size=[batch], seed=seed), task, noise, randomization, curriculum)


def domain_levels(batch: int, seed: int) -> TransformedEnv:
    """Per-env physics redrawn every 4 steps (across episodes), each env's mass range set by its level."""
    task = TaskTransform(swing_up_task(success_threshold=0.6))
    levels = DifficultyLevels(3, {"domain.mass.halfspan": [0.0, 0.2, 0.4]})
    randomization = DomainRandomization(_pendulum_params(), when="interval", every=4, seed=seed)
    return _finish(PendulumEnv(batch_size=[batch], seed=seed), task, randomization, levels)


#: a DomainRandomization per pendulum field, each of its own mode; the two sets hold every moment of a draw with fresh
#: draws, a drawn stored set and a given one (the seeding and layout tests: tests/transforms/test_domain_layouts.py)
DOMAIN_MODES: dict[str, dict[str, dict]] = {
    "fresh": {
        "mass": {"when": "reset"},
        "length": {"when": "interval", "every": 3},
        "gravity": {"when": "startup", "cycle": 4},
    },
    "stored": {
        "mass": {"when": "reset", "cycle": 3},
        "length": {"when": "startup"},
        "gravity": {"when": "interval", "every": 2, "cycle": {"gravity": torch.arange(8.0, 13.0, dtype=torch.float64)}},
    },
}


def domain_modes(batch: int, seed: int | None, modes: str = "fresh") -> TransformedEnv:
    """Per-env pendulum physics, each field drawn in the mode ``DOMAIN_MODES[modes]`` gives it, beside goals drawn by
    a GoalCommand on a timer; with ``seed=None`` nothing is seeded (torch's global generator until ``set_seed``)."""
    params = {
        "mass": UniformDomainParam("mass", mean=1.0, halfspan=0.5),
        "length": NormalDomainParam("length", mean=1.0, std=0.2, clip_lo=0.5),
        "gravity": UniformDomainParam("gravity", mean=10.0, halfspan=2.0),
    }
    randomizations = [
        DomainRandomization([params[name]], seed=seed, **kwargs) for name, kwargs in DOMAIN_MODES[modes].items()
    ]
    command = GoalCommand(Box([-0.5, -0.5], [0.5, 0.5]), resample_steps=(2, 4), seed=seed)
    task = TaskTransform(swing_up_task(success_threshold=0.6), goal_key="goal")
    return _finish(PendulumEnv(batch_size=[batch], seed=seed), task, *randomizations, command)


def _fast(state: torch.Tensor) -> torch.Tensor:
    return (state[..., 1].abs() > 1.0).to(state.dtype)


def _far(state: torch.Tensor) -> torch.Tensor:
    return state[..., 0].abs()


def constraints(batch: int, seed: int) -> TransformedEnv:
    """Two named costs beside the swing-up reward (a ConstrainedTask)."""
    costs = {
        "speed": Constraint(StateFunctionReward(_fast, negate=False), limit=2.0),
        "angle": StateFunctionReward(_far, negate=False),
    }
    task = ConstrainedTask(swing_up_task(success_threshold=0.6), costs)
    return _finish(PendulumEnv(batch_size=[batch], seed=seed), TaskTransform(task))


def end_conditions(batch: int, seed: int) -> TransformedEnv:
    """Two named failures (out of bounds, unhealthy) written under ended_by."""
    spec = EnvSpec(Box([-0.9, -0.9, -10.0, -10.0], [0.9, 0.9, 10.0, 10.0], labels=PointMassEnv.labels), 2)
    alive = HealthyReward(1.0, index=[2], low=-0.8, high=0.8, terminate_when_unhealthy=True)
    env = PointMassEnv(batch_size=[batch], seed=seed, max_force=2.0)
    return _finish(env, TaskTransform(GoallessTask(spec, alive)))


#: swing_up_task's terms in two groups, with its final and step rewards and a term of the groups' own (the speed)
GROUPS = {"tracking": {"track": 1.0, "final": 0.5}, "energy": {"effort": 1000.0, "speed": -0.25, "step": 0.125}}
#: the groups_scheduled ramp: each group's weights (its buffer ``weights_<group>``) from the start to the end values
GROUP_RAMPS = {
    "weights_tracking": linear([1.0, 0.5], [2.0, 0.0], 0, 200),
    "weights_energy": linear([1000.0, -0.25, 0.125], [10.0, -1.0, 1.0], 0, 200),
}


def _grouped_swing_up(dtype: torch.dtype | None) -> RewardGroupsTask:
    return RewardGroupsTask(
        swing_up_task(success_threshold=0.6), GROUPS, terms={"speed": VelocityReward(1.0, index=1)}, dtype=dtype
    )


def groups(batch: int, seed: int) -> TransformedEnv:
    """Reward groups accumulated in float32 over a float64 pendulum (MO-Gymnasium's arithmetic, a float64 reward)."""
    env = PendulumEnv(batch_size=[batch], seed=seed, dtype=torch.float64)
    return _finish(env, TaskTransform(_grouped_swing_up(torch.float32)))


def groups_scheduled(batch: int, seed: int) -> TransformedEnv:
    """Reward groups (in the reward's dtype) whose coefficients a Curriculum ramps over the first frames."""
    curriculum = Curriculum(GROUP_RAMPS)
    task = TaskTransform(_grouped_swing_up(None))
    return _finish(PendulumEnv(batch_size=[batch], seed=seed), task, curriculum)


def every_run_state(batch: int, seed: int) -> TransformedEnv:
    """Every stateful transform in one env (for the layouts that build few envs, e.g. worker processes): per-env
    physics redrawn every 4 steps, the mass range and the reward groups' coefficients ramped by a Curriculum, goals
    redrawn on a timer in ranges set by each env's level, and the base env's state."""
    task = TaskTransform(_grouped_swing_up(None), goal_key="goal")
    randomization = DomainRandomization(_pendulum_params(), when="interval", every=4, seed=seed)
    curriculum = Curriculum({**GROUP_RAMPS, "domain.mass.halfspan": linear(0.0, 0.5, 0, 200)})
    tables = {
        "command.low": [[-0.1, -0.5], [-0.3, -1.0], [-0.5, -2.0]],
        "command.high": [[0.1, 0.5], [0.3, 1.0], [0.5, 2.0]],
    }
    command = GoalCommand(Box([-0.5, -2.0], [0.5, 2.0]), resample_steps=(3, 5), seed=seed)
    env = PendulumEnv(batch_size=[batch], seed=seed)
    return _finish(env, task, randomization, curriculum, DifficultyLevels(3, tables), command)


class _Torque(torch.nn.Module):
    """A torque against the angle, with a per-env gain: some pendulums reach the top, some do not."""

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        gain = torch.linspace(-2.0, 2.0, observation.shape[-2], dtype=observation.dtype).unsqueeze(-1)
        return (-gain * observation[..., :1] - 0.3 * observation[..., 1:2]).clamp(-2.0, 2.0)


class _Push(torch.nn.Module):
    """A force towards the goal (or the origin) for some point masses, a fast push for others."""

    def forward(self, observation: torch.Tensor, goal: torch.Tensor | None = None) -> torch.Tensor:
        target = torch.zeros_like(observation[..., :2]) if goal is None else goal.to(observation.dtype)
        toward = 3.0 * (target - observation[..., :2]) - 1.5 * observation[..., 2:]
        rows = torch.arange(observation.shape[-2]).unsqueeze(-1)
        push = torch.tensor([2.0, 0.6], dtype=observation.dtype).expand_as(toward)
        return torch.where(rows % 3 == 0, push, toward).clamp(-2.0, 2.0)


def pendulum_policy() -> TensorDictModule:
    return TensorDictModule(_Torque(), ["observation"], ["action"])


def point_policy(goal: bool) -> TensorDictModule:
    return TensorDictModule(_Push(), ["observation", "goal"] if goal else ["observation"], ["action"])


@dataclass(frozen=True)
class Feature:
    """An env factory ``(batch, seed) -> env`` and the policy that drives it."""

    make_env: Callable[[int, int], TransformedEnv]
    make_policy: Callable[[], TensorDictModule]


FEATURES: dict[str, Feature] = {
    "plain": Feature(plain, pendulum_policy),
    "terms_and_final": Feature(terms_and_final, pendulum_policy),
    "shaping": Feature(shaping, pendulum_policy),
    "goal_command": Feature(goal_command, functools.partial(point_policy, True)),
    "curriculum": Feature(curriculum, pendulum_policy),
    "levels": Feature(levels, functools.partial(point_policy, True)),
    "constraints": Feature(constraints, pendulum_policy),
    "end_conditions": Feature(end_conditions, functools.partial(point_policy, False)),
    "domain": Feature(domain, pendulum_policy),
    "domain_levels": Feature(domain_levels, pendulum_policy),
    "observation_noise": Feature(observation_noise, pendulum_policy),
    "groups": Feature(groups, pendulum_policy),
    "groups_scheduled": Feature(groups_scheduled, pendulum_policy),
}


def task_transform(env: TransformedEnv) -> TaskTransform:
    return next(t for t in env.transform if isinstance(t, TaskTransform))
