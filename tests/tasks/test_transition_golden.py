"""Golden conformance of ``Task.transition`` with Pyrado: the golden ``task_rollout`` scenarios, one call per step.

``test_tasks_golden.py`` replays every scenario through the fine-grained calls in the order of Pyrado's
env step. Here each step is ONE call::

    out = task.transition(s_t, a_t, s_{t+1}, memory, remaining_steps,
                          reward_on="state", truncated=time_limit)

(Pyrado's order: step reward on the pre-step state; flags and final reward on the post-step state;
``done = success | failure | time limit``; the final reward paid where done) and the columns are
read off the output: ``step_rew = out.step_reward``, ``is_done = out.terminated``, ``has_succeeded``,
``has_failed``, ``done``, ``final_rew = out.final_reward`` (and 0 where not done),
``reward = out.reward``. Every scenario the fine-grained golden tests replay is covered, with their
tolerances:

- scenarios torchtasks reproduces: Pyrado's numbers in float64 (rtol 1e-6, atol 1e-9, flags exact,
  the ``internal`` snapshots against ``out.memory``), also with the ``expanded_spec`` trees, and in
  float32 (rtol/atol 1e-4; flags skipped on steps within 1e-5 of a threshold; ``truncated`` is
  Pyrado's ``done``, as the fine-grained float32 replay takes the final reward at Pyrado's done steps);
- expected deviations and the derived scenarios: the numpy oracle's fixed behaviour (columns, the
  episode end, memory); Pyrado's error step (flipping with delta = pi) must now go through;
- scenarios with several episodes: all episodes as one batch, each env with its own episode.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest
import torch

from golden import scenarios
from golden_tasks import (
    ATOL32,
    ATOL64,
    COLUMNS,
    FLAG_MARGIN32,
    RTOL32,
    RTOL64,
    OracleRunner,
    Replay,
    build_scenario_task,
    column_mismatches,
    derived_scenarios,
    fixed_spec,
    is_deviation,
    remaining_steps,
    replay,
    reset_overrides,
    snapshot_mismatches,
)
from torchtasks.tasks import Task

ROLLOUTS = scenarios("task_rollout")
MATCHING = [case for case in ROLLOUTS if not is_deviation(case)]
DEVIATING = [case for case in ROLLOUTS if is_deviation(case)]
EXPANDED = [case for case in MATCHING if "expanded_spec" in case]
DERIVED = derived_scenarios()
BATCHABLE = [case for case in ROLLOUTS if len(case["episodes"]) > 1 and not any("error" in e for e in case["episodes"])]

#: Known torchtasks (src/) bugs: scenario name -> reason. Each entry is a strict xfail.
XFAIL: dict[str, str] = {}

_MAX_REPORTED = 12


def _params(cases: list[dict[str, Any]]) -> list[Any]:
    params = []
    for case in cases:
        marks = [pytest.mark.xfail(strict=True, reason=XFAIL[case["name"]])] if case["name"] in XFAIL else []
        params.append(pytest.param(case, id=case["name"], marks=marks))
    return params


def _fail_on(problems: list[str], what: str) -> None:
    if problems:
        shown = "\n  ".join(problems[:_MAX_REPORTED])
        more = f"\n  ... and {len(problems) - _MAX_REPORTED} more" if len(problems) > _MAX_REPORTED else ""
        pytest.fail(f"{what}: {len(problems)} mismatch(es)\n  {shown}{more}")


def _row(values: Sequence[float], dtype: torch.dtype) -> torch.Tensor:
    return torch.tensor([list(values)], dtype=dtype)


def _scalar(value: torch.Tensor, dtype: torch.dtype) -> float:
    assert value.shape == (1,) and value.dtype == dtype, (value.shape, value.dtype)
    return float(value[0])


def _flag(value: torch.Tensor) -> bool:
    assert value.shape == (1,) and value.dtype == torch.bool, (value.shape, value.dtype)
    return bool(value[0])


def transition_replay(
    task: Task,
    scenario: dict[str, Any],
    episode: dict[str, Any],
    *,
    dtype: torch.dtype = torch.float64,
    forced_done: Sequence[bool] | None = None,
    num_steps: int | None = None,
) -> Replay:
    """Replay one episode with one ``transition`` per step (the env order of ``golden_tasks.replay``).

    ``truncated`` is the time limit, or ``forced_done`` (Pyrado's done column, for the float32 run).
    The episode stops where ``out.done`` (or the forced done) holds, or after ``num_steps``.
    """
    max_steps = scenario["max_steps"]
    states, acts = episode["states"], episode["acts"]
    steps = len(acts) if num_steps is None else num_steps
    result = Replay()
    memory = task.reset(_row(states[0], dtype), **reset_overrides(episode))
    for t in range(steps):
        remaining = remaining_steps(max_steps, t)
        time_limit = (t + 1) >= max_steps
        truncated = time_limit if forced_done is None else bool(forced_done[t])
        out = task.transition(
            _row(states[t], dtype),
            _row(acts[t], dtype),
            _row(states[t + 1], dtype),
            memory,
            remaining,
            truncated=torch.tensor([truncated]),
            reward_on="state",
        )
        memory = out.memory
        step_rew = _scalar(out.step_reward, dtype)
        final = _scalar(out.final_reward, dtype)
        done = _flag(out.done)
        if forced_done is not None:
            done = bool(forced_done[t])
        elif not done:
            assert final == 0.0, f"step {t}: a final reward {final} was paid where not done"
        succeeded, failed, is_done = _flag(out.success), _flag(out.failure), _flag(out.terminated)
        values = (remaining, step_rew, is_done, succeeded, failed, time_limit, done, final if done else None)
        for name, value in zip(COLUMNS, values, strict=True):
            result.columns[name].append(value)
        result.columns["reward"].append(_scalar(out.reward, dtype))
        result.memories.append(memory)
        if done:
            break
    return result


def _error_episode_problems(task: Task, case: dict[str, Any], episode: dict[str, Any]) -> list[str]:
    """A non-deviating error episode: the same steps before Pyrado's error, then the transition raises."""
    t = episode["error"]["t"]
    result = transition_replay(task, case, episode, num_steps=t)
    problems = column_mismatches(result.columns, episode["expected"], range(min(t, result.num_steps)), RTOL64, ATOL64)
    if result.num_steps != t:
        return [*problems, f"the episode ended after {result.num_steps} steps, before the error step {t}"]
    states, memory = episode["states"], result.memories[-1] if result.memories else None
    if memory is None:
        memory = task.reset(_row(states[0], torch.float64), **reset_overrides(episode))
    with pytest.raises((TypeError, ValueError)):  # Pyrado's TypeError / ValueErr / ShapeErr
        task.transition(
            _row(states[t], torch.float64),
            _row(episode["acts"][t], torch.float64),
            _row(states[t + 1], torch.float64),
            memory,
            remaining_steps(case["max_steps"], t),
            truncated=torch.tensor([(t + 1) >= case["max_steps"]]),
            reward_on="state",
        )
    return problems


def _pyrado_problems(case: dict[str, Any], *, expanded: bool = False) -> list[str]:
    """Replay every episode through ``transition`` and list the differences from Pyrado's numbers."""
    spec = case["expanded_spec"] if expanded else case["spec"]
    task = build_scenario_task(case, expanded=expanded)
    problems = []
    for e, episode in enumerate(case["episodes"]):
        if "error" in episode:
            problems += [f"episode {e}: {p}" for p in _error_episode_problems(task, case, episode)]
            continue
        n = episode["num_steps"]
        result = transition_replay(task, case, episode)
        if result.num_steps != n:
            problems.append(f"episode {e}: ended after {result.num_steps} steps, Pyrado after {n}")
        steps = range(min(n, result.num_steps))
        found = column_mismatches(result.columns, episode["expected"], steps, RTOL64, ATOL64)
        problems += [f"episode {e}: {p}" for p in found]
        for t in steps if "internal" in episode else ():
            found = snapshot_mismatches(spec, result.memories[t], episode["internal"][t], RTOL64, ATOL64)
            problems += [f"episode {e} step {t} internal {p}" for p in found]
    return problems


# --------------------------------------------------------------------------------------------------
# Scenarios torchtasks reproduces
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("case", _params(MATCHING))
def test_transition_rollout_matches_pyrado(case: dict[str, Any]) -> None:
    """Float64: every column of every step, and the internal state, as in Pyrado."""
    _fail_on(_pyrado_problems(case), case["name"])


@pytest.mark.parametrize("case", _params(EXPANDED))
def test_transition_expanded_spec_rollout_matches_pyrado(case: dict[str, Any]) -> None:
    """The basic task tree equivalent to a predefined factory gives Pyrado's numbers through transition too."""
    _fail_on(_pyrado_problems(case, expanded=True), case["name"])


@pytest.mark.parametrize("case", _params(MATCHING))
def test_transition_rollout_float32(case: dict[str, Any]) -> None:
    """Float32 (inputs and ``task.float()``): rewards close, flags exact except on steps at a threshold."""
    problems = []
    for e, episode in enumerate(case["episodes"]):
        assert "error" not in episode, "float32 replay of error episodes is not implemented"
        n, expected = episode["num_steps"], episode["expected"]
        margins = replay(OracleRunner(case), case, episode).margins
        task = build_scenario_task(case).float()
        result = transition_replay(task, case, episode, dtype=torch.float32, forced_done=expected["done"], num_steps=n)
        ambiguous = [t for t in range(n) if margins[t] < FLAG_MARGIN32]
        found = column_mismatches(result.columns, expected, range(n), RTOL32, ATOL32, skip_flags=ambiguous)
        problems += [f"episode {e}: {p}" for p in found]
    _fail_on(problems, f"{case['name']} (float32)")


# --------------------------------------------------------------------------------------------------
# Expected deviations: the fixed behaviour, from the numpy oracle
# --------------------------------------------------------------------------------------------------


def _fixed_behaviour_problems(case: dict[str, Any]) -> list[str]:
    task, oracle = build_scenario_task(case), OracleRunner(case)
    spec = fixed_spec(case)
    problems = []
    for e, episode in enumerate(case["episodes"]):
        actual, expected = transition_replay(task, case, episode), replay(oracle, case, episode)
        if actual.num_steps != expected.num_steps:
            problems.append(
                f"episode {e}: ended after {actual.num_steps} steps, the fixed task after {expected.num_steps}"
            )
        steps = range(min(actual.num_steps, expected.num_steps))
        problems += [
            f"episode {e}: {p}" for p in column_mismatches(actual.columns, expected.columns, steps, RTOL64, ATOL64)
        ]
        for t in steps:
            found = snapshot_mismatches(spec, actual.memories[t], expected.snapshots[t], RTOL64, ATOL64)
            problems += [f"episode {e} step {t} memory {p}" for p in found]
        if "error" in episode and actual.num_steps <= episode["error"]["t"]:
            problems.append(f"episode {e}: did not get past Pyrado's error step {episode['error']['t']}")
    return problems


@pytest.mark.parametrize("case", _params(DEVIATING))
def test_transition_rollout_fixed_behaviour(case: dict[str, Any]) -> None:
    """Float64 against the oracle's fixed behaviour: columns, episode end, memory."""
    _fail_on(_fixed_behaviour_problems(case), f"{case['name']} (fixed behaviour)")


@pytest.mark.parametrize("case", _params(DERIVED))
def test_transition_derived_fixed_behaviour(case: dict[str, Any]) -> None:
    """Fixes whose own golden scenario is missing (golden_tasks.derived_scenarios), against the oracle."""
    _fail_on(_fixed_behaviour_problems(case), f"{case['name']} (fixed behaviour)")


# --------------------------------------------------------------------------------------------------
# All episodes of a scenario as one batch
# --------------------------------------------------------------------------------------------------


def _expected_columns(case: dict[str, Any], episode: dict[str, Any]) -> dict[str, list[Any]]:
    """Pyrado's columns, or the oracle's for an expected deviation."""
    if is_deviation(case):
        return replay(OracleRunner(case), case, episode).columns
    return episode["expected"]


@pytest.mark.parametrize("case", _params(BATCHABLE))
def test_transition_rollout_batched_episodes(case: dict[str, Any]) -> None:
    """Every episode of a scenario in its own env of one batch, one transition per step for all envs.

    An env whose episode is over keeps receiving its last transition; its outputs are ignored.
    ``truncated`` is the time limit of the envs still running, so ``done`` is the task's own end there.
    """
    episodes = case["episodes"]
    expected = [_expected_columns(case, episode) for episode in episodes]
    lengths = [len(columns["step_rew"]) for columns in expected]
    task = build_scenario_task(case)

    def rows(key: str, offset: int, t: int) -> torch.Tensor:
        values = [ep[key][min(t + offset, n - 1 + offset)] for ep, n in zip(episodes, lengths, strict=True)]
        return torch.tensor(values, dtype=torch.float64)

    overrides = {}
    if any(ep.get("reset_kwargs_extra", {}).get("start_idx") is not None for ep in episodes):
        starts = [
            ep.get("reset_kwargs_extra", {}).get("start_idx", case["spec"].get("start_idx", 0)) for ep in episodes
        ]
        overrides["start_index"] = torch.tensor(starts)
    memory = task.reset(rows("states", 0, 0), **overrides)
    problems = []
    for t in range(max(lengths)):
        active = [t < n for n in lengths]
        time_limit = torch.tensor([a and (t + 1) >= case["max_steps"] for a in active])
        out = task.transition(
            rows("states", 0, t),
            rows("acts", 0, t),
            rows("states", 1, t),
            memory,
            remaining_steps(case["max_steps"], t),
            truncated=time_limit,
            reward_on="state",
        )
        memory = out.memory
        for b, columns in enumerate(expected):
            if not active[b]:
                continue
            done = columns["done"][t]
            want_final = columns["final_rew"][t] if done else 0.0
            for name, got, want in (
                ("step_rew", float(out.step_reward[b]), columns["step_rew"][t]),
                ("final_rew", float(out.final_reward[b]), want_final),
                ("reward", float(out.reward[b]), columns["reward"][t]),
            ):
                if not np.isclose(got, want, rtol=RTOL64, atol=ATOL64):
                    problems.append(f"env {b} step {t} {name}: got {got!r}, expected {want!r}")
            for name, value in (
                ("is_done", out.terminated),
                ("has_succeeded", out.success),
                ("has_failed", out.failure),
                ("done", out.done),
            ):
                if bool(value[b]) != columns[name][t]:
                    problems.append(f"env {b} step {t} {name}: got {bool(value[b])}, expected {columns[name][t]}")
    _fail_on(problems, f"{case['name']} (batched)")


# --------------------------------------------------------------------------------------------------
# Coverage
# --------------------------------------------------------------------------------------------------


def test_every_golden_rollout_is_replayed_through_transition() -> None:
    """Each task_rollout scenario is in exactly one of the float64 groups (as in test_tasks_golden)."""
    names = [case["name"] for case in ROLLOUTS]
    assert len(set(names)) == len(names) == len(MATCHING) + len(DEVIATING) > 0
    assert {case["name"] for case in MATCHING} | {case["name"] for case in DEVIATING} == set(names)
    assert len(DERIVED) > 0 and len(EXPANDED) > 0 and len(BATCHABLE) > 0
