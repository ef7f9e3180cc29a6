"""Reward functions against Pyrado's golden numbers (``rew_fcn_calls`` and reward construction errors).

Every ``rew_fcn_calls`` scenario is replayed op by op on ONE reward instance, in float64 (golden
tolerance) and in float32, and once more with all calls stacked into a batch. Expected deviations
(pyrado-semantics.md §10) are checked against the fixed behaviour:

- decision 2 (ScaledExp keeps ``min_reward``): only the calls before the first ``reset`` op apply;
- decision 18 (Ant/Humanoid): the healthy reward is paid only when healthy, and with
  ``terminate_when_unhealthy`` an unhealthy state is a failure. The expected value is Pyrado's minus
  the healthy reward Pyrado paid, plus the one the fixed rule pays (computed here from the rule).

The data lacks some scenarios the golden README lists (no ScaledExp calls, no Humanoid with
``terminate_when_unhealthy=True``, no Ant without it). They are added here: ``derived/*`` flips
``terminate_when_unhealthy`` of a golden Ant/Humanoid scenario (Pyrado's numbers for it follow from
semantics §4), ``synthetic/scaled_exp_quadr_err`` is written in the golden format with closed-form
Pyrado numbers.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pytest
import torch

from golden import (
    EXPECTED_DEVIATIONS,
    REWARD_TYPES,
    build,
    build_reward,
    expected_deviation,
    is_reward_spec,
    load_golden,
    scenarios,
)
from torchtasks.rewards import RewardFunction

DTYPES = {
    # name: (torch dtype, numpy dtype, rtol, atol)
    "float64": (torch.float64, np.float64, 1e-6, 1e-9),
    "float32": (torch.float32, np.float32, 1e-5, 1e-5),
}

REWARD_SCENARIOS = scenarios("rew_fcn_calls")
REWARD_ERROR_SCENARIOS = [item for item in scenarios("construction_error") if is_reward_spec(item["spec"])]

#: Pyrado reward class -> torchtasks class (pyrado-semantics.md §11).
TORCHTASKS_CLASS = {
    "ZeroPerStepRewFcn": "ConstantReward",
    "PlusOnePerStepRewFcn": "ConstantReward",
    "MinusOnePerStepRewFcn": "ConstantReward",
    "CosOfOneEleRewFcn": "CosineReward",
    "SSCosOfOneEleRewFcn": "ShiftedCosineReward",
    "AbsErrRewFcn": "AbsoluteErrorReward",
    "QuadrErrRewFcn": "QuadraticErrorReward",
    "ExpQuadrErrRewFcn": "ExpQuadraticErrorReward",
    "ScaledExpQuadrErrRewFcn": "ScaledExpQuadraticErrorReward",
    "UnderActuatedSwingUpRewFcn": "SwingUpReward",
    "QCartPoleSwingUpRewFcn": "CartPoleSwingUpReward",
    "CompoundRewFcn": "CompoundReward",
    "StateBasedRewFcn": "StateFunctionReward",
    "ForwardVelocityRewFcn": "ForwardVelocityReward",
    "ForwardVelocityRewFcnAnt": "AntForwardReward",
    "ForwardVelocityRewFcnHumanoid": "HumanoidForwardReward",
}


def _names(items: list[dict[str, Any]]) -> list[str]:
    return [item["name"] for item in items]


# --------------------------------------------------------------------------------------------------
# The fixed healthy rule (decision 18), written from pyrado-semantics.md §4, evaluated in a dtype
# --------------------------------------------------------------------------------------------------


def _ant_healthy(state: np.ndarray, z_range: list[float]) -> bool:
    low, high = (state.dtype.type(bound) for bound in z_range)
    return bool(np.isfinite(state).all() and low <= state[2] <= high)


def _humanoid_healthy(state: np.ndarray, z_range: list[float]) -> bool:
    low, high = (state.dtype.type(bound) for bound in z_range)
    return bool(low < state[2] < high)


HEALTH_RULES = {"ForwardVelocityRewFcnAnt": _ant_healthy, "ForwardVelocityRewFcnHumanoid": _humanoid_healthy}
STATEFUL_TYPES = {"ForwardVelocityRewFcn", *HEALTH_RULES}


def _is_stateful_spec(spec: Mapping[str, Any]) -> bool:
    if spec["type"] == "CompoundRewFcn":
        return any(_is_stateful_spec(item) for item in spec["rew_fcns"])
    return spec["type"] in STATEFUL_TYPES


def _healthy(spec: Mapping[str, Any], state: list[float], np_dtype: type) -> bool | None:
    """The fixed rule's verdict on ``state`` rounded to ``np_dtype`` (None if the reward has no rule)."""
    rule = HEALTH_RULES.get(spec["type"])
    if rule is None:
        return None
    return rule(np.asarray(state, dtype=np.float64).astype(np_dtype), spec["healthy_z_range"])


def expected_call_value(spec: Mapping[str, Any], op: Mapping[str, Any], np_dtype: type) -> float:
    """Expected value of a ``call`` op: Pyrado's number, with the healthy term of the fixed rule."""
    value = op["expected"]
    healthy = _healthy(spec, op["err_s"], np_dtype)
    if healthy is None:
        return value
    bonus = spec["healthy_reward"]
    paid_by_pyrado = bonus * float(_healthy(spec, op["err_s"], np.float64) or spec["terminate_when_unhealthy"])
    return value - paid_by_pyrado + bonus * float(healthy)


def expected_failure(spec: Mapping[str, Any], state: list[float], np_dtype: type) -> bool:
    """Fixed behaviour: unhealthy is a failure only with ``terminate_when_unhealthy``."""
    healthy = _healthy(spec, state, np_dtype)
    return healthy is not None and spec["terminate_when_unhealthy"] and not healthy


def compared_ops(case: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The ops whose numbers torchtasks must reproduce (ScaledExp: before the first reset, decision 2)."""
    ops = case["ops"]
    if case["spec"]["type"] == "ScaledExpQuadrErrRewFcn":
        resets = [i for i, op in enumerate(ops) if op["op"] == "reset"]
        return ops[: resets[0]] if resets else ops
    return ops


def _row(values: list[float], dtype: torch.dtype) -> torch.Tensor:
    """One golden vector as a batch of one row ``[1, n]``."""
    return torch.tensor(values, dtype=torch.float64).to(dtype)[None]


def _check_internal(
    internal: Mapping[str, Any] | None, reward: torch.nn.Module, memory: Any, rtol: float, atol: float, where: str
) -> None:
    if not internal:
        return
    for path, snapshot in internal.items():
        assert path == "rew_fcn", f"{where}: unexpected internal path {path!r}"
        for key, expected in snapshot.items():
            if key == "last_x_pos":
                actual = memory["x_last"]
                assert actual.shape == (1,), where
                actual = actual[0].item()
            elif key == "c_max":
                actual = float(reward.c_max)
            else:
                pytest.fail(f"{where}: no torchtasks counterpart known for internal state {key!r}")
            np.testing.assert_allclose(actual, expected, rtol=rtol, atol=atol, err_msg=f"{where}: {key}")


# --------------------------------------------------------------------------------------------------
# Scenarios derived from the golden data and synthetic ones (for cases the data lacks)
# --------------------------------------------------------------------------------------------------


def flip_terminate(case: dict[str, Any]) -> dict[str, Any]:
    """The Ant/Humanoid scenario with ``terminate_when_unhealthy`` negated and Pyrado's numbers for it.

    Pyrado pays ``healthy_reward · (is_healthy or terminate_when_unhealthy)`` (semantics §4), so only
    the healthy term of the expected values changes; ``internal`` (x_last) is unaffected.
    """
    spec = case["spec"]
    flipped = {**spec, "terminate_when_unhealthy": not spec["terminate_when_unhealthy"]}
    bonus = spec["healthy_reward"]
    ops = []
    for op in case["ops"]:
        if op["op"] == "call":
            healthy = _healthy(spec, op["err_s"], np.float64)
            before = bonus * float(healthy or spec["terminate_when_unhealthy"])
            after = bonus * float(healthy or flipped["terminate_when_unhealthy"])
            op = {**op, "expected": op["expected"] - before + after}
        ops.append(op)
    term = "term1" if flipped["terminate_when_unhealthy"] else "term0"
    name = "derived/" + case["name"].rsplit("/", 1)[-1].replace("_term0", "").replace("_term1", "") + "_" + term
    return {**case, "name": name, "spec": flipped, "ops": ops}


def scaled_exp_scenario() -> dict[str, Any]:
    """A ScaledExp scenario in the golden format (the data has none), with Pyrado's numbers.

    Pyrado scales with the constructor's ``min_rew`` until the first ``reset``, which silently
    reverts to 1e-4 (quirk 2); the calls after the reset carry those numbers and must be skipped.
    """
    rng = np.random.default_rng(42)
    Q = np.array([[2.0, 0.3, 0.0], [0.3, 1.0, 0.0], [0.0, 0.0, 0.5]])
    R = np.diag([0.2, 0.1])
    lo_s, hi_s, lo_a, hi_a = [-1.0, -2.0, 0.5], [1.5, 1.0, 3.0], [-1.0, -1.0], [1.0, 0.5]
    s_max = np.maximum(np.abs(lo_s), np.abs(hi_s))
    a_max = np.maximum(np.abs(lo_a), np.abs(hi_a))
    worst = s_max @ Q @ s_max + a_max @ R @ a_max

    def box(lo: list[float], hi: list[float]) -> dict[str, Any]:
        return {"type": "BoxSpace", "bound_lo": lo, "bound_up": hi, "labels": None}

    def call(min_rew: float) -> dict[str, Any]:
        e_s, e_a = rng.uniform(-2.0, 2.0, 3), rng.uniform(-1.0, 1.0, 2)
        c_max = -np.log(min_rew) / worst
        expected = float(np.exp(-c_max * (e_s @ Q @ e_s + e_a @ R @ e_a)))
        op = {"op": "call", "err_s": e_s.tolist(), "err_a": e_a.tolist(), "remaining_steps": 3, "expected": expected}
        return {**op, "internal": {"rew_fcn": {"c_max": float(c_max)}}}

    spec = {
        "type": "ScaledExpQuadrErrRewFcn",
        "Q": Q.tolist(),
        "R": R.tolist(),
        "state_space": box(lo_s, hi_s),
        "act_space": box(lo_a, hi_a),
        "min_rew": 0.01,
    }
    reset = {"op": "reset", "kwargs": {"state_space": box(lo_s, hi_s), "act_space": box(lo_a, hi_a)}}
    ops = [call(0.01) for _ in range(5)] + [reset] + [call(1e-4) for _ in range(3)]
    return {"kind": "rew_fcn_calls", "name": "synthetic/scaled_exp_quadr_err", "spec": spec, "ops": ops}


DERIVED = [flip_terminate(case) for case in REWARD_SCENARIOS if case["spec"]["type"] in HEALTH_RULES]
REPLAYED = REWARD_SCENARIOS + DERIVED + [scaled_exp_scenario()]


# --------------------------------------------------------------------------------------------------
# The data and the builders
# --------------------------------------------------------------------------------------------------


def test_golden_data_is_decoded(golden: dict[str, Any]) -> None:
    assert len(golden["scenarios"]) == 76
    assert REWARD_SCENARIOS, "no rew_fcn_calls scenarios in the golden file"

    def leftover_strings(obj: Any) -> list[str]:
        if isinstance(obj, str):
            return [obj] if obj in ("inf", "-inf", "nan") else []
        if isinstance(obj, list):
            return [s for item in obj for s in leftover_strings(item)]
        if isinstance(obj, dict):
            return [s for value in obj.values() for s in leftover_strings(value)]
        return []

    assert leftover_strings(golden["scenarios"]) == []
    humanoid = next(item for item in REWARD_SCENARIOS if item["spec"]["type"] == "ForwardVelocityRewFcnHumanoid")
    assert humanoid["spec"]["contact_cost_range"][0] == float("-inf")
    assert load_golden() is golden  # cached


def test_every_golden_reward_spec_builds(golden: dict[str, Any]) -> None:
    """Every reward spec anywhere in the data (also inside tasks) builds to the class of §11."""
    found: dict[str, int] = {}

    def walk(obj: Any) -> None:
        if isinstance(obj, dict):
            if (isinstance(obj.get("type"), str) and obj["type"].endswith("RewFcn")) or is_reward_spec(obj):
                assert obj["type"] in REWARD_TYPES, f"no builder for reward type {obj['type']!r}"
                reward = build_reward(obj)
                assert type(reward).__name__ == TORCHTASKS_CLASS[obj["type"]]
                assert reward.stateful is _is_stateful_spec(obj)
                found[obj["type"]] = found.get(obj["type"], 0) + 1
            for value in obj.values():
                walk(value)
        elif isinstance(obj, list):
            for value in obj:
                walk(value)

    for item in golden["scenarios"]:
        if item["kind"] != "construction_error":
            walk(item)
    assert set(found) <= set(TORCHTASKS_CLASS)
    assert len(found) >= 15


def test_expected_deviations_match_the_generic_handling() -> None:
    """A rew_fcn_calls scenario changes its expected numbers iff it is listed as a deviation."""
    assert {"rew/forward_velocity_ant_term1", "rew/forward_velocity_humanoid_term1"} <= EXPECTED_DEVIATIONS
    assert expected_deviation("rew/forward_velocity_ant_term1") == 18
    assert expected_deviation("radially_symm/anything") == 9
    assert expected_deviation("rew/forward_velocity") is None
    for case in REWARD_SCENARIOS:
        changed = [
            op
            for op in compared_ops(case)
            if op["op"] == "call" and expected_call_value(case["spec"], op, np.float64) != op["expected"]
        ]
        assert bool(changed) == (case["name"] in EXPECTED_DEVIATIONS), case["name"]


# --------------------------------------------------------------------------------------------------
# Replay
# --------------------------------------------------------------------------------------------------


def replay(case: dict[str, Any], dtype_name: str) -> RewardFunction:
    """Replay the ops of a ``rew_fcn_calls`` scenario on ONE instance, comparing every call."""
    dtype, np_dtype, rtol, atol = DTYPES[dtype_name]
    spec = case["spec"]
    reward = build_reward(spec)
    if dtype == torch.float32:
        reward = reward.float()
    stateful = _is_stateful_spec(spec)
    memory = None
    compared = 0
    for index, op in enumerate(compared_ops(case)):
        where = f"{case['name']} op {index} ({op['op']}, {dtype_name})"
        if op["op"] == "reset":
            if stateful:
                memory = reward.reset(_row(op["kwargs"]["init_state"], dtype))
        elif op["op"] in ("call", "call_state"):
            if op["op"] == "call_state":
                state, action = _row(op["state"], dtype), None
                value = reward(state, None)
                expected = op["expected"]
            else:
                state, action = _row(op["err_s"], dtype), _row(op["err_a"], dtype)
                if stateful:
                    assert memory is not None, f"{where}: a stateful reward is called before any reset"
                    value, memory = reward.step(state, action, memory)
                else:
                    value = reward(state, action)
                expected = expected_call_value(spec, op, np_dtype)
                raw_state = op["err_s"]
                failed = reward.has_failed(state)
                assert failed.dtype == torch.bool and failed.shape == (1,), where
                assert bool(failed[0]) == expected_failure(spec, raw_state, np_dtype), where
            assert value.shape == (1,) and value.dtype == dtype, where
            np.testing.assert_allclose(value[0].item(), expected, rtol=rtol, atol=atol, err_msg=where)
            compared += 1
        else:
            pytest.fail(f"{where}: unknown op")
        _check_internal(op.get("internal"), reward, memory, rtol, atol, where)
    assert compared > 0
    return reward


@pytest.mark.parametrize("dtype_name", list(DTYPES))
@pytest.mark.parametrize("case", REPLAYED, ids=_names(REPLAYED))
def test_replay(case: dict[str, Any], dtype_name: str) -> None:
    replay(case, dtype_name)


def _episodes(ops: list[dict[str, Any]]) -> list[tuple[list[float], list[dict[str, Any]]]]:
    """Split ops into ``(init_state, calls)`` per reset (stateful rewards)."""
    episodes: list[tuple[list[float], list[dict[str, Any]]]] = []
    for op in ops:
        if op["op"] == "reset":
            episodes.append((op["kwargs"]["init_state"], []))
        else:
            assert op["op"] == "call" and episodes, "a stateful scenario must start with a reset"
            episodes[-1][1].append(op)
    return episodes


@pytest.mark.parametrize("case", REPLAYED, ids=_names(REPLAYED))
def test_replay_batched(case: dict[str, Any]) -> None:
    """All golden calls at once: one row per call (stateless), one env per episode (stateful)."""
    _, np_dtype, rtol, atol = DTYPES["float64"]
    spec = case["spec"]
    reward = build_reward(spec)
    ops = compared_ops(case)
    if not _is_stateful_spec(spec):
        calls = [op for op in ops if op["op"] in ("call", "call_state")]
        if calls[0]["op"] == "call_state":
            assert all(op["op"] == "call_state" for op in calls)
            values = reward(torch.tensor([op["state"] for op in calls], dtype=torch.float64), None)
            expected = [op["expected"] for op in calls]
        else:
            states = torch.tensor([op["err_s"] for op in calls], dtype=torch.float64)
            actions = torch.tensor([op["err_a"] for op in calls], dtype=torch.float64)
            values = reward(states, actions)
            expected = [expected_call_value(spec, op, np_dtype) for op in calls]
        assert values.shape == (len(calls),)
        np.testing.assert_allclose(values.numpy(), expected, rtol=rtol, atol=atol)
        return

    episodes = _episodes(ops)
    length = min(len(calls) for _, calls in episodes)
    assert length > 0
    memory = reward.reset(torch.tensor([init for init, _ in episodes], dtype=torch.float64))
    assert memory.batch_size == (len(episodes),)
    for t in range(length):
        step_ops = [calls[t] for _, calls in episodes]
        states = torch.tensor([op["err_s"] for op in step_ops], dtype=torch.float64)
        actions = torch.tensor([op["err_a"] for op in step_ops], dtype=torch.float64)
        values, memory = reward.step(states, actions, memory)
        expected = [expected_call_value(spec, op, np_dtype) for op in step_ops]
        np.testing.assert_allclose(values.numpy(), expected, rtol=rtol, atol=atol, err_msg=f"step {t}")
        failed = reward.has_failed(states)
        assert failed.tolist() == [expected_failure(spec, op["err_s"], np_dtype) for op in step_ops]
        last_x = [op.get("internal", {}).get("rew_fcn", {}).get("last_x_pos") for op in step_ops]
        if all(x is not None for x in last_x):
            np.testing.assert_allclose(memory["x_last"].numpy(), last_x, rtol=rtol, atol=atol)


@pytest.mark.parametrize("case", REWARD_ERROR_SCENARIOS, ids=_names(REWARD_ERROR_SCENARIOS))
def test_construction_error(case: dict[str, Any]) -> None:
    assert expected_deviation(case["name"]) is None
    with pytest.raises((ValueError, TypeError)):
        build_reward(case["spec"])


def test_scaled_exp_keeps_min_reward_after_a_reset() -> None:
    """Decision 2: the calls after Pyrado's reset are skipped, and min_reward is still the given one."""
    case = scaled_exp_scenario()
    assert len(compared_ops(case)) == 5
    reward = replay(case, "float64")
    spec = case["spec"]
    state_box, action_box = build(spec["state_space"]), build(spec["act_space"])
    assert reward.reset(torch.zeros(1, 3)).batch_size == (1,)
    worst = reward(state_box.bound_abs_high[None], -action_box.bound_abs_high[None])
    np.testing.assert_allclose(worst.item(), spec["min_rew"], rtol=1e-12)
    after = case["ops"][6:]
    values = reward(torch.tensor([op["err_s"] for op in after]).double(), torch.tensor([op["err_a"] for op in after]))
    assert not np.allclose(values.numpy(), [op["expected"] for op in after], rtol=1e-6)  # Pyrado's 1e-4 differs


def test_derived_scenarios_cover_both_terminate_settings() -> None:
    kinds = {(case["spec"]["type"], case["spec"].get("terminate_when_unhealthy")) for case in REPLAYED}
    for reward_type in HEALTH_RULES:
        assert {(reward_type, False), (reward_type, True)} <= kinds
