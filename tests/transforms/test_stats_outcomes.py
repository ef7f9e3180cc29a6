"""Statistics keys only for what the task defines: a tree that cannot succeed writes no success flag and reports no
success rate; one that cannot fail writes no failure flag and reports no failure rate.

The expected keys come from a table written by hand from the way each case is built (``task_trees.CANNOT_SUCCEED``,
``task_trees.NAMED_END_CONDITIONS``), not from the code under test; the facts are checked against behaviour too (a
tree that says it cannot succeed never succeeds over random transitions). The readers of the flags (a gated
Curriculum, DifficultyLevels' default rule, GoalCommand's resampling on success, episode_statistics with a key of
one's own) refuse a flag the task does not write, saying why.
"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDictBase
from torchrl.envs import Compose, StepCounter, TransformedEnv

from task_trees import CANNOT_SUCCEED, NAMED_END_CONDITIONS, all_task_cases, random_transitions
from torchtasks.envs._state_env import StateEnv
from torchtasks.rewards import QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.stats import episode_statistics
from torchtasks.tasks import DesiredStateTask, GoallessTask, Task
from torchtasks.transforms import Curriculum, DifficultyLevels, GoalCommand, TaskTransform, gated

CASES = all_task_cases()
#: the statistics that say how episodes ended (the rest: counts, lengths, returns)
OUTCOME_STATS = {"success_rate", "failure_rate", "timeout_rate", "env_termination_rate"}


class _RandomStates(StateEnv):
    """States drawn at random every step (partly outside the task boxes, partly near 0.25 where goals succeed)."""

    def __init__(self, batch: int, state_size: int, action_size: int, seed: int = 0) -> None:
        super().__init__(
            [batch],
            state_size=state_size,
            action_size=action_size,
            action_bound=1.0,
            dtype=torch.float64,
            device=None,
            seed=seed,
        )

    def _sample_state(self) -> torch.Tensor:
        shape = (*self.batch_size, self.observation_spec["observation"].shape[-1])
        states = torch.rand(shape, generator=self.rng, dtype=torch.float64) * 5.0 - 2.5
        near = torch.rand((*self.batch_size, 1), generator=self.rng, dtype=torch.float64) < 0.4
        return torch.where(near, states * 0.05 + 0.25, states)

    def _next_state(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self._sample_state()


class _SucceedsOnly(Task):
    """A task of one's own that defines a success and no failure (and says so)."""

    def _step_reward(self, state, action, memory, remaining_steps):
        return state.new_zeros(state.shape[:-1]), memory

    def _has_succeeded(self, state, memory):
        return state[..., 0] > 1.0

    def _has_failed(self, state, memory):
        return torch.zeros(state.shape[:-1], dtype=torch.bool, device=state.device)

    @property
    def termination_names(self) -> dict[str, str]:
        return {"success": "success"}


def _rollout(task: Task, steps: int = 24) -> tuple[TransformedEnv, TensorDictBase]:
    transform = TaskTransform(task.double())
    env = TransformedEnv(_RandomStates(8, task.state_size, task.action_size), Compose(StepCounter(4), transform))
    return env, env.rollout(steps, break_when_any_done=False)


def _expected_outcome_stats(case: str) -> set[str]:
    """By hand: every case can fail; those not in CANNOT_SUCCEED can succeed; the env's flags give the rest."""
    expected = {"failure_rate", "timeout_rate", "env_termination_rate"}
    if case not in CANNOT_SUCCEED:
        expected.add("success_rate")
    return expected | {f"ended_by/{name}" for name in NAMED_END_CONDITIONS.get(case, ())}


@pytest.mark.parametrize("case", sorted(CASES))
def test_statistics_report_the_outcomes_the_tree_defines(case: str) -> None:
    env, data = _rollout(CASES[case]())
    nxt = data["next"]
    assert ("success" in nxt.keys()) == (case not in CANNOT_SUCCEED)
    assert "failure" in nxt.keys()
    ended_by = set(nxt["ended_by"].keys()) if "ended_by" in nxt.keys() else set()
    assert ended_by == set(NAMED_END_CONDITIONS.get(case, ()))
    assert ("success" in env.observation_spec.keys()) == (case not in CANNOT_SUCCEED)
    stats = episode_statistics(data)
    assert stats["episodes"] > 0
    got = {key for key in stats if key in OUTCOME_STATS or key.startswith("ended_by/")}
    assert got == _expected_outcome_stats(case)


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_tree_that_says_it_cannot_succeed_never_does(case: str) -> None:
    task = CASES[case]().double()
    assert task.facts.can_succeed == (case not in CANNOT_SUCCEED) and task.facts.can_fail
    draws = random_transitions(task, torch.Generator().manual_seed(1), 12, batch=16)
    memory, succeeded = task.reset(draws["states"][0]), torch.zeros((), dtype=torch.bool)
    for t in range(12):
        goal = draws["goals"][t] if "goals" in draws else None
        out = task.transition(
            draws["states"][t], draws["actions"][t], draws["states"][t + 1], memory, draws["remaining"][t], goal=goal
        )
        succeeded, memory = succeeded | out.success.any(), out.memory
    if case in CANNOT_SUCCEED:
        assert not succeeded


def test_a_tree_that_cannot_fail_writes_no_failure_flag_and_reports_no_failure_rate() -> None:
    task = _SucceedsOnly(EnvSpec(2, 1))
    assert (task.facts.can_succeed, task.facts.can_fail) == (True, False)
    _, data = _rollout(task)
    assert "failure" not in data["next"].keys() and data["next", "success"].any()
    stats = episode_statistics(data)
    ended = data["next", "done"]
    assert stats["success_rate"] == pytest.approx((data["next", "success"] & ended).sum().item() / ended.sum().item())
    assert {key for key in stats if key in OUTCOME_STATS} == {"success_rate", "timeout_rate", "env_termination_rate"}


def test_an_outcome_without_a_flag_never_happens_for_the_end_kinds() -> None:
    """Without a success flag the task ends episodes by failure only: timeouts are the truncations without it."""
    _, data = _rollout(CASES["goalless_forward_velocity"]())
    nxt = data["next"]
    done, failure, truncated = nxt["done"], nxt["failure"], nxt["truncated"]
    stats = episode_statistics(data)
    ended = done.sum().item()
    assert stats["failure_rate"] == pytest.approx((done & failure).sum().item() / ended)
    assert stats["timeout_rate"] == pytest.approx((done & truncated & ~failure).sum().item() / ended)
    assert stats["env_termination_rate"] == 0.0  # the env never ends an episode by itself
    # a flag under a key of one's own must be there; the default one may be absent (a tree without that outcome)
    with pytest.raises(KeyError, match="success_key='won'"):
        episode_statistics(data, success_key="won")
    assert "env_termination_rate" not in episode_statistics(data, success_key=None)


# ------------------------------------------------------------------------------------------- readers refuse
SPEC = EnvSpec(Box([-2.0], [2.0]), 1)


def _walk(task: Task, *after) -> TransformedEnv:
    env = _RandomStates(4, 1, 1)
    return TransformedEnv(env, Compose(StepCounter(4), TaskTransform(task), *after))


def test_a_gated_curriculum_on_success_refuses_a_task_that_cannot_succeed() -> None:
    curriculum = Curriculum({"reward.Q": gated([[1.0], [2.0]], metric="success", threshold=0.5, window=2)})
    with pytest.raises(ValueError, match=r"reads 'success'.*GoallessTask\) has no success condition"):
        _walk(GoallessTask(SPEC, QuadraticErrorReward([1.0], [0.0])), curriculum).rollout(2)


def test_difficulty_levels_default_rule_refuses_a_task_that_cannot_succeed() -> None:
    levels = DifficultyLevels(2, {"reward.Q": [[1.0], [2.0]]})
    with pytest.raises(ValueError, match=r"default rule .* success_key='success', but its task .* rule="):
        _walk(GoallessTask(SPEC, QuadraticErrorReward([1.0], [0.0])), levels).rollout(2)


def test_goal_command_resampling_on_success_refuses_a_goal_task_without_success() -> None:
    task = DesiredStateTask(SPEC, [0.0], QuadraticErrorReward([1.0], [0.0]))  # no success function: never succeeds
    command = GoalCommand(Box([-1.0], [1.0]), resample_on_success=True, seed=0)
    with pytest.raises(ValueError, match=r"resample_on_success=True\) reads .*no success condition"):
        env = _RandomStates(4, 1, 1)
        TransformedEnv(env, Compose(StepCounter(4), TaskTransform(task, goal_key="goal"), command)).rollout(2)


def test_a_reader_of_a_defined_flag_is_unchanged() -> None:
    """The same gated curriculum on a task that can succeed runs (the refusal is about the task, not the reader)."""
    near = DesiredStateTask(SPEC, [0.25], QuadraticErrorReward([1.0], [0.0]), threshold=0.3)
    curriculum = Curriculum({"reward.Q": gated([[1.0], [2.0]], metric="success", threshold=0.5, window=2)})
    data = _walk(near, curriculum).rollout(6, break_when_any_done=False)
    assert "success" in data["next"].keys() and "curriculum" in data["next"].keys()


def test_the_hopper_preset_reports_no_success() -> None:
    """The case of the issue: Hopper's task has no success condition, so neither its data nor its statistics do."""
    pytest.importorskip("mujoco")
    pytest.importorskip("gymnasium")
    from torchtasks.envs import gymnasium_env

    env = gymnasium_env("Hopper-v5", seed=0)
    task = next(t for t in env.transform if isinstance(t, TaskTransform)).task
    assert task.termination_names == {"out_of_bounds": "failure", "unhealthy": "failure"}
    torch.manual_seed(0)
    data = env.rollout(100, break_when_any_done=False)
    assert "success" not in data["next"].keys() and "success" not in env.observation_spec.keys()
    stats = episode_statistics(data)
    assert stats["episodes"] > 0
    got = {key for key in stats if key in OUTCOME_STATS or key.startswith("ended_by/")}
    ended_by = {"ended_by/out_of_bounds", "ended_by/unhealthy"}
    assert got == {"failure_rate", "timeout_rate", "env_termination_rate"} | ended_by
