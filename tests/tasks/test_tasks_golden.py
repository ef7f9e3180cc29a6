"""Golden conformance of torchtasks tasks with Pyrado's ``tasks`` module.

Every ``task_rollout`` scenario of ``tests/data/pyrado_golden.json`` is replayed through the
functional protocol (batch of one) in the order of Pyrado's env step (golden README): step reward
on the pre-step state, flags and final reward on the post-step state, final reward only when done.

- Scenarios that torchtasks must reproduce are compared with Pyrado's numbers (float64, rtol 1e-6,
  atol 1e-9; flags exact), including the ``internal`` snapshots mapped onto task memory.
- Expected deviations (golden README; decisions of pyrado-semantics.md section 10) are compared
  with an independent numpy oracle (``golden_tasks``, ORACLE section) that implements the fixed
  behaviour; the oracle is itself checked against Pyrado on every non-deviating scenario. When the
  fixed task ends an episode at another step than Pyrado, the recorded states are replayed only up
  to the oracle's end (the torchtasks episode must end there too).
- The non-deviating scenarios run again in float32 (inputs and ``task.float()``): rewards within
  rtol 1e-4 / atol 1e-4, flags exact except in steps where a float64 comparison of that step (as
  recorded by the oracle: bounds, proximity norms, conditions, ...) lies within 1e-5 of its
  threshold, where float32 rounding may legitimately flip the flag. The float32 replay takes the
  final reward at Pyrado's ``done`` steps so that such a flip cannot shift the rest of the episode.
"""

from __future__ import annotations

import itertools
import math
import re
from typing import Any

import numpy as np
import pytest
import torch

from golden import build_reward, scenarios
from golden_tasks import (
    ATOL32,
    ATOL64,
    FLAG_MARGIN32,
    RTOL32,
    RTOL64,
    SUPPORTED_MODES,
    OEnv,
    OracleRunner,
    TorchRunner,
    build_env_spec,
    build_scenario_task,
    build_success,
    build_task,
    column_mismatches,
    derived_scenarios,
    fixed_spec,
    is_deviation,
    masked_sub_spec,
    oracle_task,
    remaining_steps,
    replay,
    snapshot_mismatches,
)
from repo_paths import TESTS
from torchtasks import predefined
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import (
    DesiredStateTask,
    FinalRewardMode,
    FinalRewardTask,
    MaskedTask,
    never_succeeded,
    proximity_succeeded,
)

ROLLOUTS = scenarios("task_rollout")
MATCHING = [case for case in ROLLOUTS if not is_deviation(case)]
DEVIATING = [case for case in ROLLOUTS if is_deviation(case)]
EXPANDED = [case for case in MATCHING if "expanded_spec" in case]
DERIVED = derived_scenarios()
ERRORS = scenarios("construction_error")
FCN_CALLS = [(case["name"], i, call) for case in scenarios("fcn_calls") for i, call in enumerate(case["calls"])]

#: Known torchtasks (src/) bugs: scenario name -> reason. Each entry is a strict xfail.
XFAIL: dict[str, str] = {}

#: Scenarios not run in float32, with the reason.
FLOAT32_SKIP: dict[str, str] = {}

_MAX_REPORTED = 12


def _params(cases: list[dict[str, Any]], skip: dict[str, str] | None = None) -> list[Any]:
    params = []
    for case in cases:
        marks = []
        if case["name"] in XFAIL:
            marks.append(pytest.mark.xfail(strict=True, reason=XFAIL[case["name"]]))
        if skip and case["name"] in skip:
            marks.append(pytest.mark.skip(reason=skip[case["name"]]))
        params.append(pytest.param(case, id=case["name"], marks=marks))
    return params


def _fail_on(problems: list[str], what: str) -> None:
    if problems:
        shown = "\n  ".join(problems[:_MAX_REPORTED])
        more = f"\n  ... and {len(problems) - _MAX_REPORTED} more" if len(problems) > _MAX_REPORTED else ""
        pytest.fail(f"{what}: {len(problems)} mismatch(es)\n  {shown}{more}")


def _error_step_problems(runner: Any, case: dict[str, Any], episode: dict[str, Any]) -> list[str]:
    """A non-deviating error episode: the same steps before the error, then the same call raises."""
    error = episode["error"]
    t = error["t"]
    result = replay(runner, case, episode, num_steps=t)
    problems = column_mismatches(result.columns, episode["expected"], range(min(t, result.num_steps)), RTOL64, ATOL64)
    if result.num_steps != t:
        return [*problems, f"the episode ended after {result.num_steps} steps, before the error step {t}"]
    s, a, s_next = episode["states"][t], episode["acts"][t], episode["states"][t + 1]
    rem = remaining_steps(case["max_steps"], t)
    calls = {
        "step_rew": lambda: runner.step_rew(s, a, rem),
        "is_done": lambda: runner.is_done(s_next),
        "has_succeeded": lambda: runner.has_succeeded(s_next),
        "has_failed": lambda: runner.has_failed(s_next),
        "final_rew": lambda: runner.final_rew(s_next, rem),
    }
    for stage, call in calls.items():
        if stage == error["stage"]:
            with pytest.raises((TypeError, ValueError)):  # Pyrado's TypeError / ValueErr / ShapeErr
                call()
            return problems
        call()
    raise AssertionError(f"unknown error stage {error['stage']!r}")


def _pyrado_problems(runner: Any, case: dict[str, Any], spec: dict[str, Any]) -> list[str]:
    """Replay every episode on ``runner`` and list the differences from Pyrado's numbers."""
    problems = []
    for e, episode in enumerate(case["episodes"]):
        if "error" in episode:
            problems += [f"episode {e}: {p}" for p in _error_step_problems(runner, case, episode)]
            continue
        n = episode["num_steps"]
        result = replay(runner, case, episode)
        if result.num_steps != n:
            problems.append(f"episode {e}: ended after {result.num_steps} steps, Pyrado after {n}")
        steps = range(min(n, result.num_steps))
        problems += [
            f"episode {e}: {p}" for p in column_mismatches(result.columns, episode["expected"], steps, RTOL64, ATOL64)
        ]
        for t in steps if "internal" in episode else ():
            expected = episode["internal"][t]
            if result.memories:
                found = snapshot_mismatches(spec, result.memories[t], expected, RTOL64, ATOL64)
            else:
                found = _oracle_snapshot_mismatches(result.snapshots[t], expected)
            problems += [f"episode {e} step {t} internal {p}" for p in found]
    return problems


def _oracle_snapshot_mismatches(actual: dict[str, dict[str, Any]], expected: dict[str, dict[str, Any]]) -> list[str]:
    problems = []
    for path, fields in expected.items():
        for name, value in fields.items():
            if name == "c_max":
                continue
            got = actual.get(path, {}).get(name)
            if got is None or not np.allclose(np.asarray(got, float), np.asarray(value, float), RTOL64, ATOL64):
                problems.append(f"{path}.{name}: got {got!r}, expected {value!r}")
    return problems


# --------------------------------------------------------------------------------------------------
# Scenarios torchtasks reproduces
# --------------------------------------------------------------------------------------------------


@pytest.mark.quick
@pytest.mark.parametrize("case", _params(MATCHING))
def test_rollout_matches_pyrado(case: dict[str, Any]) -> None:
    """Replay in float64: every column of every step, and the internal state, as in Pyrado."""
    task = build_scenario_task(case)
    _fail_on(_pyrado_problems(TorchRunner(task), case, case["spec"]), case["name"])


@pytest.mark.parametrize("case", _params(EXPANDED))
def test_expanded_spec_rollout_matches_pyrado(case: dict[str, Any]) -> None:
    """The basic task tree equivalent to a predefined factory gives Pyrado's numbers too."""
    task = build_scenario_task(case, expanded=True)
    _fail_on(_pyrado_problems(TorchRunner(task), case, case["expanded_spec"]), case["name"])


@pytest.mark.parametrize("case", _params(MATCHING))
def test_oracle_matches_pyrado(case: dict[str, Any]) -> None:
    """The numpy oracle reproduces Pyrado wherever no fix applies (so it can be trusted where one does)."""
    _fail_on(_pyrado_problems(OracleRunner(case), case, case["spec"]), f"oracle on {case['name']}")


@pytest.mark.parametrize("case", _params(MATCHING, skip=FLOAT32_SKIP))
def test_rollout_float32(case: dict[str, Any]) -> None:
    """Replay in float32: rewards close, flags exact except in steps on a threshold (module docstring)."""
    problems = []
    for e, episode in enumerate(case["episodes"]):
        assert "error" not in episode, "float32 replay of error episodes is not implemented"
        n, expected = episode["num_steps"], episode["expected"]
        margins = replay(OracleRunner(case), case, episode).margins
        runner = TorchRunner(build_scenario_task(case), dtype=torch.float32)
        result = replay(runner, case, episode, forced_done=expected["done"], num_steps=n)
        ambiguous = [t for t in range(n) if margins[t] < FLAG_MARGIN32]
        found = column_mismatches(result.columns, expected, range(n), RTOL32, ATOL32, skip_flags=ambiguous)
        problems += [f"episode {e}: {p}" for p in found]
    _fail_on(problems, f"{case['name']} (float32)")


def _expected_columns(case: dict[str, Any], episode: dict[str, Any]) -> dict[str, list[Any]]:
    """Pyrado's columns, or the oracle's for an expected deviation."""
    if is_deviation(case):
        return replay(OracleRunner(case), case, episode).columns
    return episode["expected"]


BATCHABLE = [case for case in ROLLOUTS if len(case["episodes"]) > 1 and not any("error" in e for e in case["episodes"])]


@pytest.mark.parametrize("case", _params(BATCHABLE))
def test_rollout_batched_episodes(case: dict[str, Any]) -> None:
    """All episodes of a scenario as one batch (every episode starts with a reset, so they are
    independent): each environment must get its own episode's numbers. An environment whose
    episode is over keeps receiving its last state; its outputs are ignored, and the final reward
    is requested with a per-environment ``done`` mask (0 must be paid where not done)."""
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
        rem = remaining_steps(case["max_steps"], t)
        state, action, next_state = rows("states", 0, t), rows("acts", 0, t), rows("states", 1, t)
        active = [t < n for n in lengths]
        step_rew, memory = task.step_reward(state, action, memory, rem)
        flags = {
            "is_done": task.is_done(next_state, memory),
            "has_succeeded": task.has_succeeded(next_state, memory),
            "has_failed": task.has_failed(next_state, memory),
        }
        done = torch.tensor([a and bool(cols["done"][t]) for a, cols in zip(active, expected, strict=True)])
        final, memory = task.final_reward(next_state, memory, rem, done)
        for b, columns in enumerate(expected):
            if not active[b]:
                continue
            want_final = columns["final_rew"][t] if done[b] else 0.0
            pairs = [
                ("step_rew", float(step_rew[b]), columns["step_rew"][t]),
                ("final_rew", float(final[b]), want_final),
            ]
            for name, got, want in pairs:
                if not np.isclose(got, want, rtol=RTOL64, atol=ATOL64):
                    problems.append(f"env {b} step {t} {name}: got {got!r}, expected {want!r}")
            for name, value in flags.items():
                if bool(value[b]) != columns[name][t]:
                    problems.append(f"env {b} step {t} {name}: got {bool(value[b])}, expected {columns[name][t]}")
    _fail_on(problems, f"{case['name']} (batched)")


# --------------------------------------------------------------------------------------------------
# Expected deviations: the fixed behaviour, from the numpy oracle
# --------------------------------------------------------------------------------------------------


def _fixed_behaviour_problems(case: dict[str, Any]) -> tuple[list[str], bool]:
    """Replay torchtasks and the oracle; return the mismatches and whether the oracle differs from Pyrado."""
    torch_runner, oracle_runner = TorchRunner(build_scenario_task(case)), OracleRunner(case)
    spec = fixed_spec(case)
    problems, differs_from_pyrado = [], False
    for e, episode in enumerate(case["episodes"]):
        actual, expected = replay(torch_runner, case, episode), replay(oracle_runner, case, episode)
        if actual.num_steps != expected.num_steps:
            problems.append(
                f"episode {e}: ended after {actual.num_steps} steps, the fixed task after {expected.num_steps}"
            )
        steps = range(min(actual.num_steps, expected.num_steps))
        found = column_mismatches(actual.columns, expected.columns, steps, RTOL64, ATOL64)
        problems += [f"episode {e}: {p}" for p in found]
        for t in steps:
            found = snapshot_mismatches(spec, actual.memories[t], expected.snapshots[t], RTOL64, ATOL64)
            problems += [f"episode {e} step {t} memory {p}" for p in found]
        if "error" in episode and actual.num_steps <= episode["error"]["t"]:
            problems.append(f"episode {e}: did not get past Pyrado's error step {episode['error']['t']}")
        n = min(expected.num_steps, episode["num_steps"])
        differs_from_pyrado |= expected.num_steps != episode["num_steps"] or bool(
            column_mismatches(expected.columns, episode["expected"], range(n), RTOL64, ATOL64)
        )
    return problems, differs_from_pyrado


@pytest.mark.parametrize("case", _params(DEVIATING))
def test_rollout_fixed_behaviour(case: dict[str, Any]) -> None:
    """Replay in float64 and compare with the oracle's fixed behaviour: columns, episode end, memory.

    Where Pyrado raised (flipping with delta = pi), the fixed task must get through that step.
    """
    problems, differs_from_pyrado = _fixed_behaviour_problems(case)
    _fail_on(problems, f"{case['name']} (fixed behaviour)")
    assert differs_from_pyrado, "the fix does not change this scenario: it should not be an expected deviation"


@pytest.mark.parametrize("case", _params(DERIVED))
def test_derived_fixed_behaviour(case: dict[str, Any]) -> None:
    """Fixes whose own golden scenario is missing, on golden inputs with a changed spec (see derived_scenarios)."""
    problems, _ = _fixed_behaviour_problems(case)
    _fail_on(problems, f"{case['name']} (fixed behaviour)")


def test_flipping_delta_pi_exact_tie() -> None:
    """Decision 10: with delta = pi both targets are equally close; the tie goes to last_angle + delta."""
    spec = {"type": "FlippingTask", "des_angle_delta": math.pi, "rew_fcn": {"type": "CosOfOneEleRewFcn", "idx": 0}}
    env = EnvSpec(Box([-10.0], [10.0]), Box([-1.0], [1.0]))
    task = build_task(spec, env)
    oracle = oracle_task(spec, OEnv(np.array([-10.0]), np.array([10.0]), None, np.array([-1.0]), np.array([1.0]), None))
    state = torch.tensor([[math.pi]], dtype=torch.float64)
    memory = task.reset(state)
    oracle.reset(state[0].numpy())
    reward, memory = task.step_reward(state, torch.zeros(1, 1, dtype=torch.float64), memory)
    expected = oracle.step_rew(state[0].numpy(), np.zeros(1), 0)
    assert float(reward[0]) == pytest.approx(expected, rel=RTOL64, abs=ATOL64)
    assert float(memory["last_angle"][0]) == pytest.approx(oracle.last) == pytest.approx(math.pi)
    assert float(memory["held"][0]) == pytest.approx(oracle.held) == pytest.approx(1.0)


def test_goal_distance_rejects_pyrado_two_entry_reward() -> None:
    """Decision 16: the goal has the selection's size (1), so Pyrado's 2x2 reward no longer fits."""
    case = next(item for item in ROLLOUTS if item["name"] == "predefined/goal_dist")
    env = build_env_spec(case["env_spec"])
    spec = case["spec"]
    state = torch.zeros(1, env.state_size, dtype=torch.float64)
    with pytest.raises(ValueError):
        task = predefined.goal_distance_task(env, spec["ds_label"], build_reward(spec["rew_fcn"]), spec["succ_thold"])
        task.step_reward(state, torch.zeros(1, env.action_size, dtype=torch.float64), task.reset(state))


def test_final_reward_mode_combinations() -> None:
    """Decision 11: the ten supported FinalRewardMode combinations build; all others raise ValueError."""
    inner = DesiredStateTask(
        EnvSpec(Box([-1.0], [1.0]), Box([-1.0], [1.0])), [0.0], build_reward({"type": "ZeroPerStepRewFcn"})
    )
    for flags in itertools.product((False, True), repeat=5):
        mode = FinalRewardMode(*flags)
        if flags[:4] in SUPPORTED_MODES and not mode.user_input:
            FinalRewardTask(inner, mode, 1.0)
        else:
            with pytest.raises(ValueError):
                FinalRewardTask(inner, mode, 1.0)


# --------------------------------------------------------------------------------------------------
# Construction errors
# --------------------------------------------------------------------------------------------------


def _build_any(spec: dict[str, Any]) -> Any:
    if "env_spec" in spec:
        return build_task(spec, build_env_spec(spec["env_spec"]))
    return build_reward(spec)


@pytest.mark.parametrize("case", _params(ERRORS))
def test_construction_error(case: dict[str, Any]) -> None:
    """Building raises ValueError/TypeError like Pyrado, except where decision 1 makes it valid."""
    spec = case["spec"]
    if not is_deviation(case):
        with pytest.raises((ValueError, TypeError)):
            _build_any(spec)
        if spec["type"] == "MaskedTask":  # the MaskedTask itself rejects the indices (not only the sub-spec)
            env = build_env_spec(spec["env_spec"])
            inner_env = EnvSpec(Box.unbounded(len(spec["wrapped_task"]["state_des"])), env.action_space)
            inner = build_task(spec["wrapped_task"], inner_env)
            with pytest.raises(ValueError):
                MaskedTask(env, inner, spec["state_idcs"], spec["action_idcs"])
        return
    # decision 1: a DesSpaceTask without (or with any) reward builds; the reward is the given one or 0
    task = _build_any(spec)
    oracle = oracle_task(spec, OEnv.from_spec(spec["env_spec"]))
    rng = np.random.default_rng(0)
    env = build_env_spec(spec["env_spec"])
    for _ in range(5):
        s = rng.uniform(-0.15, 0.15, env.state_size)
        a = rng.uniform(-1.0, 1.0, env.action_size)
        state, action = torch.tensor(s[None]), torch.tensor(a[None])
        memory = task.reset(state)
        reward, memory = task.step_reward(state, action, memory)
        assert float(reward[0]) == pytest.approx(oracle.step_rew(s, a, 0), rel=RTOL64, abs=ATOL64)
        assert bool(task.has_succeeded(state, memory)[0]) == oracle.has_succeeded(s)


# --------------------------------------------------------------------------------------------------
# Success functions (fcn_calls)
# --------------------------------------------------------------------------------------------------


def _success_fn(call: dict[str, Any]) -> Any:
    kwargs = call["kwargs"]
    if call["fcn"] == "never_succeeded":
        return never_succeeded
    return build_success({"type": call["fcn"], "thold_dist": kwargs["thold_dist"], "dims": kwargs.get("dims", -1)})


@pytest.mark.parametrize(
    ("name", "index", "call"), [pytest.param(*item, id=f"{item[0]}-{item[1]}") for item in FCN_CALLS]
)
def test_success_function_call(name: str, index: int, call: dict[str, Any]) -> None:
    result = _success_fn(call)(torch.tensor([call["kwargs"]["err"]], dtype=torch.float64))
    assert result.dtype == torch.bool and result.shape == (1,)
    assert bool(result[0]) is call["expected"]


def test_success_function_calls_batched() -> None:
    """All calls of one function and configuration in a single batched call (two batch dims too)."""
    groups: dict[tuple[str, float | None, str], list[dict[str, Any]]] = {}
    for _, _, call in FCN_CALLS:
        kwargs = call["kwargs"]
        key = (call["fcn"], kwargs.get("thold_dist"), repr(kwargs.get("dims")))
        groups.setdefault(key, []).append(call)
    for key, calls in groups.items():
        errors = torch.tensor([call["kwargs"]["err"] for call in calls], dtype=torch.float64)
        expected = [call["expected"] for call in calls]
        assert _success_fn(calls[0])(errors).tolist() == expected, key
        stacked = torch.stack([errors, errors.flip(0)])
        assert _success_fn(calls[0])(stacked).tolist() == [expected, expected[::-1]], key


def test_proximity_dims_mapping() -> None:
    """Pyrado's dims=-1 means all entries; torchtasks spells that dims=None (an int -1 is the last entry)."""
    error = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    assert build_success({"type": "proximity_succeeded", "thold_dist": 0.5, "dims": -1})(error).tolist() == [False]
    assert build_success({"type": "proximity_succeeded", "thold_dist": 0.5, "dims": [0, 1]})(error).tolist() == [True]
    assert proximity_succeeded(error, 0.5, dims=-1).tolist() == [False]  # torchtasks: -1 is the last entry
    assert proximity_succeeded(error, 1.5, dims=-1).tolist() == [True]


# --------------------------------------------------------------------------------------------------
# Sanity of the test machinery itself
# --------------------------------------------------------------------------------------------------


def test_oracle_section_is_numpy_only() -> None:
    """The oracle must be independent of the code under test: no torch/torchtasks in its section."""
    source = (TESTS / "golden_tasks.py").read_text(encoding="utf-8")
    match = re.search(r"# ORACLE \(begin\)(.*)# ORACLE \(end\)", source, flags=re.DOTALL)
    assert match is not None
    body = match.group(1).split("\n", 1)[1]  # skip the marker line's own comment
    assert "torch" not in body


def test_masked_sub_spec_keeps_the_given_order() -> None:
    env = EnvSpec(Box([0.0, 1.0, 2.0], [10.0, 11.0, 12.0], labels=["a", "b", "c"]), Box([-1.0, -2.0], [1.0, 2.0]))
    sub = masked_sub_spec(env, ["c", "a"], [1])
    assert sub.state_space.low.tolist() == [2.0, 0.0] and sub.action_space.high.tolist() == [2.0]


def test_scenario_partition() -> None:
    """Each rollout is tested exactly one way; the deviating ones are the README's names present in the data."""
    names = [case["name"] for case in ROLLOUTS]
    assert len(set(names)) == len(names) == len(MATCHING) + len(DEVIATING) > 0
    assert {case["name"] for case in DEVIATING} == {
        "flipping/compound_wide_tol",
        "flipping/delta_pi_double_match_error",
        "flipping/not_endless",
        "goalless/humanoid_term1",
        "masked/final_rew_hidden_behind_mask",
        "masked/labels_with_final_rew",
        "predefined/goal_dist",
        "radially_symm/multi_modulation",
        "radially_symm/qube_quadr",
        "sequential/reset_start_idx_stuck",
        "sequential/start_idx_constructor",
    }
