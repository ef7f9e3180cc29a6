"""Golden conformance through ``TaskTransform``: replaying Pyrado's recorded episodes in a TorchRL env.

A :class:`~replay_env.ReplayEnv` emits the recorded states of a golden ``task_rollout`` scenario; with
``StepCounter(max_steps)`` (none for ``max_steps = "inf"``: remaining steps 0) and
``TaskTransform(task, reward_on="state")`` it must reproduce, step by step, Pyrado's env-level
reward (step reward on the pre-step state plus the final reward when done), ``done`` (success,
failure or time limit), the success/failure flags on the post-step state and the reward breakdown.
Episodes follow each other through TorchRL's auto-reset (the env's reset emits the next episode's
initial state), so the task memory must be reset between episodes. Expected deviations (golden
README) are compared with the fixed-behaviour numpy oracle of ``golden_tasks``. The task memory
after every step is compared with Pyrado's ``internal`` snapshots (the oracle's for deviations).
"""

from __future__ import annotations

from typing import Any

import pytest
from torchrl.envs.utils import check_env_specs

from golden import scenarios
from golden_tasks import (
    ATOL64,
    RTOL64,
    OracleRunner,
    fixed_spec,
    is_deviation,
    replay,
    snapshot_mismatches,
)
from replay_env import expected_columns, frame_problems, make_task_env, replay_policy

ROLLOUTS = scenarios("task_rollout")

#: Known torchtasks (src/) bugs: scenario name -> reason (strict xfail).
XFAIL: dict[str, str] = {}

_MAX_REPORTED = 12


def _params(xfail: dict[str, str] | None = None) -> list[Any]:
    xfail = xfail or {}
    params = []
    for case in ROLLOUTS:
        marks = [pytest.mark.xfail(strict=True, reason=xfail[case["name"]])] if case["name"] in xfail else []
        params.append(pytest.param(case, id=case["name"], marks=marks))
    return params


def _fail_on(problems: list[str], what: str) -> None:
    if problems:
        shown = "\n  ".join(problems[:_MAX_REPORTED])
        more = f"\n  ... and {len(problems) - _MAX_REPORTED} more" if len(problems) > _MAX_REPORTED else ""
        pytest.fail(f"{what}: {len(problems)} mismatch(es)\n  {shown}{more}")


def _expected_snapshots(case: dict[str, Any]) -> list[list[dict[str, Any]] | None]:
    """Per episode, the internal state after every step: Pyrado's, or the oracle's for a deviation."""
    if is_deviation(case):
        return [replay(OracleRunner(case), case, episode).snapshots for episode in case["episodes"]]
    return [episode.get("internal") for episode in case["episodes"]]


def _rollouts(case: dict[str, Any], lengths: list[int], all_end_done: bool, **transform_kwargs: Any) -> list[Any]:
    """Run the scenario through the transform; return one tensordict of transitions per episode."""
    env = make_task_env(case["name"], **transform_kwargs)
    policy = replay_policy()
    if all_end_done:
        # one rollout over all episodes: TorchRL resets the env (and the task memory) after each end
        data = env.rollout(sum(lengths), policy, break_when_any_done=False)
        bounds = [sum(lengths[:e]) for e in range(len(lengths) + 1)]
        return [data[bounds[e] : bounds[e + 1]] for e in range(len(lengths))]
    # an episode whose recorded data ends before the task ends it: explicit resets between episodes
    pieces = []
    for length in lengths:
        pieces.append(env.rollout(length, policy, auto_reset=False, tensordict=env.reset()))
    return pieces


@pytest.mark.parametrize("case", _params(XFAIL))
def test_replay_through_transform(case: dict[str, Any]) -> None:
    """Every step of every episode: reward, flags and breakdown as in Pyrado (or the oracle), and memory."""
    _check_replay(case)


def _has_compound_reward(spec: Any) -> bool:
    if isinstance(spec, dict):
        return spec.get("type") == "CompoundRewFcn" or any(_has_compound_reward(v) for v in spec.values())
    if isinstance(spec, list):
        return any(_has_compound_reward(v) for v in spec)
    return False


@pytest.mark.parametrize("case", [case for case in _params(XFAIL) if _has_compound_reward(case.values[0]["spec"])])
def test_replay_without_breakdown(case: dict[str, Any]) -> None:
    """Tasks with named reward terms replay the same without the breakdown (``log_terms=False``)."""
    _check_replay(case, log_terms=False)


def _check_replay(case: dict[str, Any], **transform_kwargs: Any) -> None:
    name = case["name"]
    columns = expected_columns(name)
    lengths = [len(item["reward"]) for item in columns]
    all_end_done = all(item["done"][-1] for item in columns)
    pieces = _rollouts(case, lengths, all_end_done, **transform_kwargs)

    problems = []
    for e, (piece, length) in enumerate(zip(pieces, lengths, strict=True)):
        if piece.shape[0] != length:
            problems.append(f"episode {e}: {piece.shape[0]} transitions, expected {length}")
        episodes = piece.get("episode").reshape(-1).tolist()
        steps = piece.get("t").reshape(-1).tolist()
        if episodes != [e] * len(episodes) or steps != list(range(len(steps))):
            problems.append(f"episode {e}: the env replayed episodes {episodes} at steps {steps}")
        problems += [f"episode {e}: {p}" for p in frame_problems(piece, name)]
    _fail_on(problems, name)

    spec = fixed_spec(case)
    for e, (piece, snapshots) in enumerate(zip(pieces, _expected_snapshots(case), strict=True)):
        if snapshots is None:
            continue
        for t in range(min(piece.shape[0], len(snapshots))):
            memory = piece.get(("next", "task"))[t].unsqueeze(0)
            found = snapshot_mismatches(spec, memory, snapshots[t], RTOL64, ATOL64)
            problems += [f"episode {e} step {t} memory {p}" for p in found]
    _fail_on(problems, f"{name} (memory)")


@pytest.mark.parametrize("case", _params())
def test_replay_env_specs(case: dict[str, Any]) -> None:
    """``check_env_specs`` passes for the replay env with the scenario's task."""
    check_env_specs(make_task_env(case["name"]), seed=None)


def test_replay_detects_a_wrong_task() -> None:
    """The comparison can fail: the scenario's episodes replayed with another scenario's task disagree."""
    name = "final_rew/default"
    env = make_task_env(name, reward_on="next")  # the step reward on s_{t+1} is not Pyrado's order
    data = env.rollout(
        sum(len(c["reward"]) for c in expected_columns(name)), replay_policy(), break_when_any_done=False
    )
    problems = frame_problems(data, name)
    assert any("step reward" in p for p in problems), problems
