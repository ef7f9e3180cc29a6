"""Load Pyrado's golden data (``tests/data/pyrado_golden.json``) and build torchtasks objects from it.

The golden file (schema in ``/work/shared/golden/README.md``) describes every object as a dict with a
``"type"`` (Pyrado's class or function name) and the constructor parameters under Pyrado's names.
:func:`build` translates such a spec into the torchtasks object through :data:`BUILDERS`, a dict of
builder functions keyed by ``"type"``. Other test modules extend it with :func:`register`::

    @register("DesStateTask")
    def _des_state_task(spec):
        return DesiredStateTask(build(spec["env_spec"]), ..., build(spec["rew_fcn"]))

Reward functions are built in float64 (their constants are float64 buffers); call ``.float()`` on
the module for a float32 run.
"""

from __future__ import annotations

import fnmatch
import functools
import json
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import torch

from torchtasks.rewards import (
    AbsoluteErrorReward,
    AntForwardReward,
    CartPoleSwingUpReward,
    CompoundReward,
    ConstantReward,
    CosineReward,
    ExpQuadraticErrorReward,
    ForwardVelocityReward,
    HumanoidForwardReward,
    QuadraticErrorReward,
    RewardFunction,
    ScaledExpQuadraticErrorReward,
    ShiftedCosineReward,
    StateFunctionReward,
    SwingUpReward,
)
from torchtasks.spaces import Box, EnvSpec

__all__ = [
    "BUILDERS",
    "EXPECTED_DEVIATIONS",
    "EXPECTED_DEVIATION_PATTERNS",
    "GOLDEN_PATH",
    "REWARD_TYPES",
    "STATE_FUNCTION_TYPES",
    "build",
    "build_box",
    "build_env_spec",
    "build_reward",
    "build_state_function",
    "build_value",
    "decode_non_finite",
    "expected_deviation",
    "is_reward_spec",
    "is_spec",
    "load_golden",
    "register",
    "scenario",
    "scenarios",
]

GOLDEN_PATH = Path(__file__).parent / "data" / "pyrado_golden.json"

_NON_FINITE = {"inf": math.inf, "-inf": -math.inf, "nan": math.nan}


# --------------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------------


def decode_non_finite(obj: Any) -> Any:
    """Return ``obj`` with the strings ``"inf"``, ``"-inf"``, ``"nan"`` replaced by floats, recursively."""
    if isinstance(obj, str):
        return _NON_FINITE.get(obj, obj)
    if isinstance(obj, list):
        return [decode_non_finite(item) for item in obj]
    if isinstance(obj, dict):
        return {key: decode_non_finite(value) for key, value in obj.items()}
    return obj


@functools.cache
def load_golden() -> dict[str, Any]:
    """Return the decoded golden data (loaded once per process; treat it as read-only)."""
    with GOLDEN_PATH.open(encoding="utf-8") as file:
        data = decode_non_finite(json.load(file))
    if data.get("format") != "pyrado-tasks-golden" or data.get("format_version") != 1:
        raise ValueError(f"{GOLDEN_PATH} is not pyrado-tasks-golden format version 1")
    return data


def scenarios(kind: str) -> list[dict[str, Any]]:
    """Return the scenarios of one ``kind`` (``rew_fcn_calls``, ``task_rollout``, ...), in file order."""
    return [item for item in load_golden()["scenarios"] if item["kind"] == kind]


def scenario(name: str) -> dict[str, Any]:
    """Return the scenario called ``name`` (``KeyError`` if there is none)."""
    for item in load_golden()["scenarios"]:
        if item["name"] == name:
            return item
    raise KeyError(f"no golden scenario named {name!r}")


# --------------------------------------------------------------------------------------------------
# Expected deviations (golden README, "Expected deviations"; decisions of pyrado-semantics.md §10)
# --------------------------------------------------------------------------------------------------

#: Scenario-name patterns (fnmatch) whose Pyrado numbers torchtasks deliberately does not reproduce,
#: mapped to the number of the torchtasks decision that fixes the quirk. Copied from the README list,
#: including names that the current data does not contain.
EXPECTED_DEVIATION_PATTERNS: dict[str, int] = {
    "errors/des_space_default_rew_fcn": 1,
    "errors/des_space_other_rew_fcn": 1,
    "des_state/scaled_exp_quadr": 2,
    "radially_symm/*": 9,
    "flipping/*": 10,
    "predefined/flipping_*": 10,
    "final_rew/unsupported_*": 11,
    "masked/final_rew_hidden_behind_mask": 13,
    "masked/int_idcs_unordered": 13,
    "masked/labels_with_final_rew": 13,
    "sequential/reset_start_idx_stuck": 15,
    "sequential/start_idx_constructor": 15,
    "predefined/goal_dist": 16,
    "goalless/ant_term1": 18,
    "goalless/humanoid_term1": 18,
    "rew/forward_velocity_ant_term1": 18,
    "rew/forward_velocity_humanoid_term1": 18,
}


def expected_deviation(name: str) -> int | None:
    """Return the decision number if scenario ``name`` is an expected deviation, else ``None``."""
    for pattern, decision in EXPECTED_DEVIATION_PATTERNS.items():
        if fnmatch.fnmatchcase(name, pattern):
            return decision
    return None


def _expected_deviation_names() -> frozenset[str]:
    literal = {pattern for pattern in EXPECTED_DEVIATION_PATTERNS if not any(c in pattern for c in "*?[")}
    matched = {item["name"] for item in load_golden()["scenarios"] if expected_deviation(item["name"])}
    return frozenset(literal | matched)


#: Names of the expected deviations: the literal names of the README list plus every scenario of the
#: data that matches one of its wildcard patterns.
EXPECTED_DEVIATIONS: frozenset[str] = _expected_deviation_names()


# --------------------------------------------------------------------------------------------------
# Builders
# --------------------------------------------------------------------------------------------------

Builder = Callable[[Mapping[str, Any]], Any]

#: Builder functions keyed by the spec ``"type"``; each takes the whole spec dict.
BUILDERS: dict[str, Builder] = {}

#: Spec types that are reward functions (filled by :func:`_register_reward`).
REWARD_TYPES: set[str] = set()

#: Spec types that are functions of the state (objectives, conditions).
STATE_FUNCTION_TYPES: set[str] = set()


def register(*types: str) -> Callable[[Builder], Builder]:
    """Decorator: register a builder for the spec types ``types`` (each type only once)."""

    def decorator(builder: Builder) -> Builder:
        for spec_type in types:
            if spec_type in BUILDERS:
                raise ValueError(f"a builder for {spec_type!r} is already registered")
            BUILDERS[spec_type] = builder
        return builder

    return decorator


def _register_reward(*types: str) -> Callable[[Builder], Builder]:
    REWARD_TYPES.update(types)
    return register(*types)


def _register_state_function(*types: str) -> Callable[[Builder], Builder]:
    STATE_FUNCTION_TYPES.update(types)
    return register(*types)


def is_spec(value: Any) -> bool:
    """Whether ``value`` is an object spec (a dict with a ``"type"``)."""
    return isinstance(value, Mapping) and "type" in value


def is_reward_spec(value: Any) -> bool:
    """Whether ``value`` is the spec of a reward function."""
    return is_spec(value) and value["type"] in REWARD_TYPES


def build(spec: Mapping[str, Any]) -> Any:
    """Build the torchtasks object described by ``spec`` (dispatch on ``spec["type"]``)."""
    if not is_spec(spec):
        raise TypeError(f"expected an object spec (a dict with a 'type'), got {spec!r}")
    try:
        builder = BUILDERS[spec["type"]]
    except KeyError:
        raise NotImplementedError(f"no builder registered for spec type {spec['type']!r}") from None
    return builder(spec)


def build_value(value: Any) -> Any:
    """Build a parameter value: object specs are built, (nested) lists become float64 tensors."""
    if is_spec(value):
        return build(value)
    if isinstance(value, list):
        return torch.tensor(value, dtype=torch.float64)
    return value


def _kwargs(spec: Mapping[str, Any], names: Mapping[str, str]) -> dict[str, Any]:
    """Rename the spec's parameters (Pyrado name -> torchtasks name); unknown parameters raise."""
    unknown = set(spec) - set(names) - {"type"}
    if unknown:
        raise KeyError(f"spec of type {spec['type']!r} has unsupported parameters {sorted(unknown)}")
    return {names[key]: value for key, value in spec.items() if key != "type"}


def _as_tuple(value: Any) -> Any:
    return tuple(value) if isinstance(value, list) else value


# Spaces ---------------------------------------------------------------------------------------


@register("BoxSpace")
def build_box(spec: Mapping[str, Any]) -> Box:
    """``BoxSpace(bound_lo, bound_up, labels)`` -> :class:`~torchtasks.spaces.Box`."""
    kwargs = _kwargs(spec, {"bound_lo": "low", "bound_up": "high", "labels": "labels"})
    return Box(kwargs["low"], kwargs["high"], labels=kwargs.get("labels"))


@register("EmptySpace")
def _build_empty_space(spec: Mapping[str, Any]) -> None:
    """Pyrado's ``EmptySpace`` (the default state space of an EnvSpec) has no torchtasks counterpart."""
    _kwargs(spec, {})
    return None


@register("EnvSpec")
def build_env_spec(spec: Mapping[str, Any]) -> EnvSpec:
    """``EnvSpec(obs_space, act_space, state_space)`` -> ``EnvSpec(state_space, action_space)``.

    The observation space is not part of a torchtasks spec (tasks see the state).
    """
    kwargs = _kwargs(spec, {"obs_space": "obs", "act_space": "action", "state_space": "state"})
    state_space = build(kwargs["state"]) if "state" in kwargs else None
    if state_space is None:
        raise NotImplementedError("EnvSpec with an EmptySpace state space: no torchtasks equivalent chosen yet")
    return EnvSpec(state_space=state_space, action_space=build(kwargs["action"]))


# State functions --------------------------------------------------------------------------------


@_register_state_function("sum_of_squares")
def _sum_of_squares(spec: Mapping[str, Any]) -> Callable[[torch.Tensor], torch.Tensor]:
    _kwargs(spec, {})

    def sum_of_squares(x: torch.Tensor) -> torch.Tensor:
        return (x * x).sum(dim=-1)

    return sum_of_squares


@_register_state_function("rosenbrock")
def _rosenbrock(spec: Mapping[str, Any]) -> Callable[[torch.Tensor], torch.Tensor]:
    _kwargs(spec, {})

    def rosenbrock(x: torch.Tensor) -> torch.Tensor:
        head, tail = x[..., :-1], x[..., 1:]
        return (100.0 * (tail - head * head) ** 2 + (1.0 - head) ** 2).sum(dim=-1)

    return rosenbrock


@_register_state_function("norm_below")
def _norm_below(spec: Mapping[str, Any]) -> Callable[[torch.Tensor], torch.Tensor]:
    kwargs = _kwargs(spec, {"center": "center", "radius": "radius"})
    center = torch.tensor(kwargs["center"], dtype=torch.float64)
    radius = float(kwargs["radius"])

    def norm_below(x: torch.Tensor) -> torch.Tensor:
        return torch.linalg.vector_norm(x - center.to(dtype=x.dtype, device=x.device), dim=-1) < radius

    return norm_below


@_register_state_function("component_above")
def _component_above(spec: Mapping[str, Any]) -> Callable[[torch.Tensor], torch.Tensor]:
    kwargs = _kwargs(spec, {"idx": "index", "value": "value"})
    index, value = int(kwargs["index"]), float(kwargs["value"])

    def component_above(x: torch.Tensor) -> torch.Tensor:
        return x[..., index] > value

    return component_above


def build_state_function(spec: Mapping[str, Any]) -> Callable[[torch.Tensor], torch.Tensor]:
    """Build a batched function of the state ``[*B, n] -> [*B]`` from a function spec."""
    if not is_spec(spec) or spec["type"] not in STATE_FUNCTION_TYPES:
        raise ValueError(f"not a state-function spec: {spec!r}")
    return build(spec)


# Reward functions -------------------------------------------------------------------------------

_CONSTANTS = {"ZeroPerStepRewFcn": 0.0, "PlusOnePerStepRewFcn": 1.0, "MinusOnePerStepRewFcn": -1.0}


@_register_reward(*_CONSTANTS)
def _constant(spec: Mapping[str, Any]) -> ConstantReward:
    _kwargs(spec, {})
    return ConstantReward(_CONSTANTS[spec["type"]])


@_register_reward("CosOfOneEleRewFcn", "SSCosOfOneEleRewFcn")
def _cosine(spec: Mapping[str, Any]) -> CosineReward:
    cls = CosineReward if spec["type"] == "CosOfOneEleRewFcn" else ShiftedCosineReward
    return cls(**_kwargs(spec, {"idx": "index"}))


@_register_reward("AbsErrRewFcn")
def _absolute_error(spec: Mapping[str, Any]) -> AbsoluteErrorReward:
    kwargs = _kwargs(spec, {"q": "q", "r": "r"})
    return AbsoluteErrorReward(build_value(kwargs["q"]), build_value(kwargs.get("r")))


@_register_reward("QuadrErrRewFcn", "ExpQuadrErrRewFcn")
def _quadratic_error(spec: Mapping[str, Any]) -> QuadraticErrorReward | ExpQuadraticErrorReward:
    cls = QuadraticErrorReward if spec["type"] == "QuadrErrRewFcn" else ExpQuadraticErrorReward
    kwargs = _kwargs(spec, {"Q": "Q", "R": "R"})
    return cls(build_value(kwargs["Q"]), build_value(kwargs.get("R")))


@_register_reward("ScaledExpQuadrErrRewFcn")
def _scaled_exp_quadratic_error(spec: Mapping[str, Any]) -> ScaledExpQuadraticErrorReward:
    names = {"Q": "Q", "R": "R", "state_space": "state_space", "act_space": "action_space", "min_rew": "min_reward"}
    kwargs = {key: build_value(value) for key, value in _kwargs(spec, names).items()}
    return ScaledExpQuadraticErrorReward(**kwargs)


@_register_reward("UnderActuatedSwingUpRewFcn")
def _swing_up(spec: Mapping[str, Any]) -> SwingUpReward:
    names = {name: name for name in ("c_pole", "c_cart", "c_act", "c_theta_sq", "c_theta_log")}
    names.update(idx_x="index_x", idx_th="index_theta")
    return SwingUpReward(**_kwargs(spec, names))


@_register_reward("QCartPoleSwingUpRewFcn")
def _cart_pole_swing_up(spec: Mapping[str, Any]) -> CartPoleSwingUpReward:
    return CartPoleSwingUpReward(**_kwargs(spec, {"factor": "factor"}))


@_register_reward("CompoundRewFcn")
def _compound(spec: Mapping[str, Any]) -> CompoundReward:
    kwargs = _kwargs(spec, {"rew_fcns": "rewards"})
    return CompoundReward([build(item) for item in kwargs["rewards"]])


@_register_reward("StateBasedRewFcn")
def _state_based(spec: Mapping[str, Any]) -> StateFunctionReward:
    # Pyrado always negates (`-(1 ** flip_sign) * fcn`), whatever flip_sign says: negate=True.
    kwargs = _kwargs(spec, {"fcn": "fn", "flip_sign": "flip_sign"})
    return StateFunctionReward(build_state_function(kwargs["fn"]), negate=True)


@_register_reward("ForwardVelocityRewFcn")
def _forward_velocity(spec: Mapping[str, Any]) -> ForwardVelocityReward:
    names = {
        "dt": "dt",
        "idx_fwd": "index",
        "fwd_rew_weight": "forward_reward_weight",
        "ctrl_cost_weight": "ctrl_cost_weight",
    }
    return ForwardVelocityReward(**_kwargs(spec, names))


_HEALTHY_COMMON = (
    "dt",
    "contact_cost_weight",
    "ctrl_cost_weight",
    "healthy_reward",
    "terminate_when_unhealthy",
    "healthy_z_range",
)


@_register_reward("ForwardVelocityRewFcnAnt")
def _ant(spec: Mapping[str, Any]) -> AntForwardReward:
    names = {name: name for name in (*_HEALTHY_COMMON, "contact_force_range")}
    return AntForwardReward(**{key: _as_tuple(value) for key, value in _kwargs(spec, names).items()})


@_register_reward("ForwardVelocityRewFcnHumanoid")
def _humanoid(spec: Mapping[str, Any]) -> HumanoidForwardReward:
    names = {name: name for name in (*_HEALTHY_COMMON, "forward_reward_weight", "contact_cost_range")}
    return HumanoidForwardReward(**{key: _as_tuple(value) for key, value in _kwargs(spec, names).items()})


def build_reward(spec: Mapping[str, Any]) -> RewardFunction:
    """Build a torchtasks reward function (float64 constants) from a Pyrado reward-function spec."""
    if not is_reward_spec(spec):
        raise ValueError(f"not a reward-function spec: {spec!r}")
    reward = build(spec)
    if not isinstance(reward, RewardFunction):
        raise TypeError(f"the builder of {spec['type']!r} returned {type(reward).__name__}")
    return reward
