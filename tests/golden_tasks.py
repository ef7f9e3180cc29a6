"""Golden task scenarios: torchtasks task builders, the env replay protocol and a numpy oracle.

Three parts, used by ``tasks/test_tasks_golden.py``:

1. **Builders** (:func:`build_task`): turn a Pyrado task spec of the golden file into a torchtasks
   task. Every task is built with its EFFECTIVE spec: Pyrado overwrote each task's ``env_spec`` at
   every reset (Parallel/Sequential pass the env's spec unchanged, a MaskedTask passes the masked
   sub-spec, wrappers pass through), so the ``env_spec`` written inside inner specs is ignored and
   the scenario's top-level ``env_spec`` is threaded down instead. Reward functions, spaces and
   state functions come from ``golden.py``.
2. **Replay** (:func:`replay`): Pyrado's env step order (golden README) on any :class:`Runner`:
   :class:`TorchRunner` drives a torchtasks task through the functional protocol with a batch of
   one; :class:`OracleRunner` drives the numpy oracle.
3. **Oracle** (between the ``ORACLE`` markers): a small per-environment numpy re-implementation of
   Pyrado's task semantics (``/work/shared/reference/pyrado-semantics.md``) with the torchtasks
   fixes of section 10 applied (decisions 1, 2, 9, 10, 11, 13, 15, 16, 18). It reads the golden
   spec dicts directly and uses numpy only (no torch, no torchtasks), so it is an independent
   source of expected values for the scenarios whose Pyrado numbers torchtasks deliberately does
   not reproduce. It also records how close each step's comparisons came to their thresholds,
   which the float32 replay uses to skip flags that are numerically ambiguous.
"""

from __future__ import annotations

import copy
import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import torch

from golden import build_box, build_reward, build_state_function, expected_deviation, scenario
from torchtasks import predefined
from torchtasks.spaces import EnvSpec
from torchtasks.tasks import (
    BestStateFinalRewardTask,
    ConditionTask,
    DesiredSpaceTask,
    DesiredStateTask,
    FinalRewardMode,
    FinalRewardTask,
    FlippingTask,
    GoallessTask,
    MaskedTask,
    OptimizationTask,
    ParallelTasks,
    RadiallySymmetricDesiredStateTask,
    SequentialTasks,
    Task,
    never_succeeded,
    proximity_succeeded,
)

Spec = Mapping[str, Any]

#: Replay tolerances (golden README) for float64 and for the float32 re-run.
RTOL64, ATOL64 = 1e-6, 1e-9
RTOL32, ATOL32 = 1e-4, 1e-4
#: In float32, flags of a step are not compared when a float64 comparison of that step came
#: closer than this to its threshold (see :class:`Margins`).
FLAG_MARGIN32 = 1e-5

COLUMNS = ("remaining_steps", "step_rew", "is_done", "has_succeeded", "has_failed", "time_limit", "done", "final_rew")
FLAG_COLUMNS = ("is_done", "has_succeeded", "has_failed", "done")
FLOAT_COLUMNS = ("step_rew", "final_rew", "reward")


# ==================================================================================================
# Scenario helpers
# ==================================================================================================

FACTORIES = (
    "create_check_all_boundaries_task",
    "create_task_space_discrepancy_task",
    "create_collision_task",
    "create_forcemin_task",
    "create_lifting_task",
    "create_flipping_task",
    "create_home_pos_task",
    "create_goal_dist_task",
    "create_goal_dist_distvel_task",
)


def fixed_spec(scenario: Spec) -> Spec:
    """Return the task spec whose FIXED behaviour torchtasks must show for ``scenario``.

    Identical to ``scenario["spec"]`` except for ``predefined/goal_dist`` (decision 16): the fixed
    factory builds a 1-entry goal for the 1-entry selection, so the golden reward, whose ``Q`` is
    2x2 to fit Pyrado's broadcast 2-entry error, is replaced by its upper-left 1x1 block.
    """
    spec = copy.deepcopy(scenario["spec"])
    if scenario["name"] == "predefined/goal_dist":
        rew = spec["rew_fcn"]
        rew["Q"] = [[rew["Q"][0][0]]]
    return spec


def derived_scenarios() -> list[dict[str, Any]]:
    """Variants of golden scenarios for fixes whose own scenario the README names but the data lacks.

    Each reuses a golden scenario's states and actions with a changed spec; its expected values
    come from the oracle (the golden numbers belong to the original spec).

    - ``derived/ant_term1`` (decision 18; README: goalless/ant_term1): ``goalless/ant_term0`` with
      ``terminate_when_unhealthy=True``; the torso leaves [0.2, 1.0] at the 5th state.
    - ``derived/humanoid_term1_final_rew`` (decision 18): ``goalless/humanoid_term1`` inside a default
      FinalRewTask: the unhealthy state is a failure, so the failure's final reward is paid.
    - ``derived/scaled_exp_quadr`` (decision 2; README: des_state/scaled_exp_quadr):
      ``des_state/exp_quadr_never`` with a ScaledExp reward on the env's boxes and ``min_rew=0.01``.
    - ``derived/int_idcs_unordered`` (decision 13; README: masked/int_idcs_unordered):
      ``masked/labels_with_final_rew`` with the same selection given as unordered ints.
    - ``derived/des_space_quadr_reward`` (decision 1; README: errors/des_space_other_rew_fcn):
      ``des_space/ZeroPerStepRewFcn`` with a non-constant reward of the raw state and action.
    """
    out = []
    ant = copy.deepcopy(scenario("goalless/ant_term0"))
    ant["spec"]["rew_fcn"]["terminate_when_unhealthy"] = True
    out.append({**ant, "name": "derived/ant_term1"})
    humanoid = copy.deepcopy(scenario("goalless/humanoid_term1"))
    humanoid["spec"] = {"type": "FinalRewTask", "wrapped_task": humanoid["spec"], "mode": {}, "factor": 10.0}
    out.append({**humanoid, "name": "derived/humanoid_term1_final_rew"})
    quadr = copy.deepcopy(scenario("des_state/exp_quadr_never"))
    rew = quadr["spec"]["rew_fcn"]
    quadr["spec"]["rew_fcn"] = {
        "type": "ScaledExpQuadrErrRewFcn",
        "Q": rew["Q"],
        "R": rew["R"],
        "state_space": quadr["env_spec"]["state_space"],
        "act_space": quadr["env_spec"]["act_space"],
        "min_rew": 0.01,
    }
    out.append({**quadr, "name": "derived/scaled_exp_quadr"})
    masked = copy.deepcopy(scenario("masked/labels_with_final_rew"))
    labels = masked["env_spec"]["state_space"]["labels"]
    act_labels = masked["env_spec"]["act_space"]["labels"]
    masked["spec"]["state_idcs"] = [labels.index(label) for label in masked["spec"]["state_idcs"]]
    masked["spec"]["action_idcs"] = [act_labels.index(label) for label in masked["spec"]["action_idcs"]]
    out.append({**masked, "name": "derived/int_idcs_unordered"})
    space = copy.deepcopy(scenario("des_space/ZeroPerStepRewFcn"))
    space["spec"]["rew_fcn"] = {"type": "QuadrErrRewFcn", "Q": np.eye(3).tolist(), "R": (0.5 * np.eye(2)).tolist()}
    out.append({**space, "name": "derived/des_space_quadr_reward"})
    return out


def remaining_steps(max_steps: float | int, t: int) -> int:
    """``max_steps - (t + 1)``, or 0 without a step limit (Pyrado's ``max_steps = inf``)."""
    return 0 if max_steps == math.inf else int(max_steps) - (t + 1)


def reset_overrides(episode: Spec) -> dict[str, Any]:
    """Extra reset keywords of an episode in torchtasks names (``"$init_state"`` is implicit)."""
    overrides: dict[str, Any] = {}
    for key, value in (episode.get("reset_kwargs_extra") or {}).items():
        if key == "init_state":
            continue  # torchtasks always takes the initial state
        if key == "start_idx":
            overrides["start_index"] = int(value)
        else:
            raise NotImplementedError(f"reset keyword {key!r} has no torchtasks mapping here")
    return overrides


# ==================================================================================================
# torchtasks builders
# ==================================================================================================


def build_env_spec(env_spec: Spec) -> EnvSpec:
    """The scenario's top-level ``EnvSpec`` (state and action boxes; the obs space is dropped)."""
    return EnvSpec(build_box(env_spec["state_space"]), build_box(env_spec["act_space"]))


def masked_sub_spec(spec: EnvSpec, state_idcs: Any, action_idcs: Any) -> EnvSpec:
    """The spec a MaskedTask hands to its wrapped task (selection in the order given)."""
    state = spec.state_space if state_idcs is None else spec.state_space.select(state_idcs)
    action = spec.action_space if action_idcs is None else spec.action_space.select(action_idcs)
    return EnvSpec(state, action)


def build_success(spec: Spec | None) -> Callable[[torch.Tensor], torch.Tensor] | None:
    """Success function of a DesStateTask: ``None`` (never), never_succeeded or proximity_succeeded."""
    if spec is None:
        return None
    if spec["type"] == "never_succeeded":
        return never_succeeded
    if spec["type"] == "proximity_succeeded":
        dims = spec.get("dims", -1)
        dims = None if dims == -1 else dims  # Pyrado's -1 means "all entries"
        return functools.partial(proximity_succeeded, threshold=spec["thold_dist"], dims=dims)
    raise NotImplementedError(f"no success function {spec['type']!r}")


def final_reward_mode(mode: Spec | None) -> FinalRewardMode:
    return FinalRewardMode(**(mode or {}))


def _reward(spec: Spec | None) -> Any:
    return None if spec is None else build_reward(spec)


def build_task(spec: Spec, env: EnvSpec) -> Task:
    """Build the torchtasks task of a golden task spec, with ``env`` as its effective spec."""
    kind = spec["type"]
    if kind == "DesStateTask":
        return DesiredStateTask(
            env, spec["state_des"], build_reward(spec["rew_fcn"]), build_success(spec["success_fcn"])
        )
    if kind == "RadiallySymmDesStateTask":
        return RadiallySymmetricDesiredStateTask(
            env,
            spec["state_des"],
            build_reward(spec["rew_fcn"]),
            indices=spec["idcs"],
            modulation=spec.get("modulation", 2 * math.pi),
            success=build_success(spec.get("success_fcn")),
        )
    if kind == "DesSpaceTask":
        return DesiredSpaceTask(env, build_box(spec["space_des"]), _reward(spec.get("rew_fcn")))
    if kind == "GoallessTask":
        return GoallessTask(env, build_reward(spec["rew_fcn"]))
    if kind == "OptimProxyTask":
        return OptimizationTask(env, build_reward(spec["rew_fcn"]))
    if kind == "ConditionOnlyTask":
        return ConditionTask(env, build_state_function(spec["condition_fcn"]), spec["is_success_condition"])
    if kind == "FlippingTask":
        return FlippingTask(
            env,
            spec["des_angle_delta"],
            build_reward(spec["rew_fcn"]),
            angle_tol=spec.get("angle_tol", math.pi / 180),
            endless=spec.get("endless", True),
        )
    if kind == "FinalRewTask":
        return FinalRewardTask(
            build_task(spec["wrapped_task"], env), final_reward_mode(spec.get("mode")), spec["factor"]
        )
    if kind == "BestStateFinalRewTask":
        return BestStateFinalRewardTask(build_task(spec["wrapped_task"], env), spec["factor"])
    if kind == "MaskedTask":
        state_idcs, action_idcs = spec["state_idcs"], spec.get("action_idcs")
        inner = build_task(spec["wrapped_task"], masked_sub_spec(env, state_idcs, action_idcs))
        return MaskedTask(env, inner, state_idcs, action_idcs)
    if kind == "ParallelTasks":
        return ParallelTasks(
            [build_task(sub, env) for sub in spec["tasks"]],
            hold_reward_when_done=spec.get("hold_rew_when_done", False),
            allow_failures=spec.get("allow_failures", False),
            easily_satisfied=spec.get("easily_satisfied", False),
        )
    if kind == "SequentialTasks":
        return SequentialTasks(
            [build_task(sub, env) for sub in spec["tasks"]],
            start_index=spec.get("start_idx", 0),
            hold_reward_when_done=spec.get("hold_rew_when_done", False),
        )
    if kind in FACTORIES:
        return build_factory(spec, env)
    raise NotImplementedError(f"no task builder for {kind!r}")


def build_factory(spec: Spec, env: EnvSpec) -> Task:
    """Build a predefined factory through :mod:`torchtasks.predefined` (Pyrado names -> torchtasks)."""
    kind = spec["type"]
    if kind == "create_check_all_boundaries_task":
        return predefined.check_all_boundaries_task(env, spec["penalty"])
    if kind == "create_task_space_discrepancy_task":
        return predefined.task_space_discrepancy_task(env, build_reward(spec["rew_fcn"]))
    if kind == "create_collision_task":
        return predefined.collision_task(env, spec["factor"])
    if kind == "create_forcemin_task":
        return predefined.force_min_task(env, spec["obs_labels"], spec["Q"])
    if kind == "create_lifting_task":
        return predefined.lifting_task(env, spec["obs_labels"], spec["des_height"], spec.get("succ_thold", 0.01))
    if kind == "create_flipping_task":
        return predefined.flipping_task(
            env, spec["obs_labels"], spec.get("des_angle_delta", math.pi / 2), spec.get("endless", True)
        )
    if kind == "create_home_pos_task":
        return predefined.home_position_task(env, spec["obs_labels"], spec["state_des"])
    if kind == "create_goal_dist_task":
        reward = build_reward(spec["rew_fcn"])
        return predefined.goal_distance_task(env, spec["ds_label"], reward, spec.get("succ_thold", 0.01))
    if kind == "create_goal_dist_distvel_task":
        reward = build_reward(spec["rew_fcn"])
        return predefined.goal_distance_velocity_task(env, spec["ds_label"], reward, spec.get("succ_thold", 0.01))
    raise NotImplementedError(f"no factory {kind!r}")


def build_scenario_task(scenario: Spec, *, expanded: bool = False) -> Task:
    """Build a scenario's task (its fixed spec, see :func:`fixed_spec`; or its ``expanded_spec``)."""
    spec = scenario["expanded_spec"] if expanded else fixed_spec(scenario)
    return build_task(spec, build_env_spec(scenario["env_spec"]))


# ==================================================================================================
# Memory <-> golden ``internal`` snapshots
# ==================================================================================================

#: golden internal field -> torchtasks memory key
MEMORY_KEYS = {
    "yielded_final_rew": "paid",
    "best_rew": "best",
    "last_angle": "last_angle",
    "held_rew": "held",
    "succeeded_tasks": "succeeded",
    "failed_tasks": "failed",
    "held_rews": "held",
    "idx_curr": "index",
    "last_x_pos": "x_last",
}

_FACTORY_CHILD = {"create_flipping_task": "FlippingTask"}


def _path_segments(path: str) -> list[tuple[str, int | None]]:
    """``"root.tasks[1].rew_fcn"`` -> ``[("tasks", 1), ("rew_fcn", None)]``."""
    segments = []
    for part in path.split(".")[1:]:
        if part.endswith("]"):
            name, index = part[:-1].split("[")
            segments.append((name, int(index)))
        else:
            segments.append((part, None))
    return segments


def memory_at(spec: Spec, memory: Any, path: str) -> Any:
    """The torchtasks memory of the object at a golden snapshot ``path`` of task ``spec``.

    Wrappers keep the wrapped task's memory under ``"wrapped"``, composites under ``"task<i>"``,
    a MaskedTask's memory IS the wrapped task's, a task's stateful reward is under ``"reward"``
    and a compound reward's terms under ``"term<i>"``. Factories are MaskedTasks, except
    ``create_check_all_boundaries_task``, a FinalRewTask.
    """
    node: Spec = spec
    for name, index in _path_segments(path):
        kind = node["type"]
        if name == "wrapped_task":
            if kind in FACTORIES:
                wrapper = kind == "create_check_all_boundaries_task"
                node = {"type": _FACTORY_CHILD.get(kind, "DesStateTask")}
            else:
                wrapper = kind != "MaskedTask"
                node = node["wrapped_task"]
            memory = memory["wrapped"] if wrapper else memory
        elif name == "tasks":
            node, memory = node["tasks"][index], memory[f"task{index}"]
        elif name == "rew_fcn":
            node, memory = node["rew_fcn"], memory["reward"]
        elif name == "rew_fcns":
            node, memory = node["rew_fcns"][index], memory[f"term{index}"]
        else:
            raise NotImplementedError(f"path segment {name!r} of {path!r}")
    return memory


def snapshot_mismatches(spec: Spec, memory: Any, expected: Mapping[str, Mapping[str, Any]], rtol: float, atol: float):
    """Yield messages for every field of a golden-format snapshot that memory does not match."""
    for path, fields in expected.items():
        sub = memory_at(spec, memory, path)
        for name, value in fields.items():
            if name not in MEMORY_KEYS:
                continue  # e.g. ScaledExp's c_max: a constant, not memory
            actual = sub[MEMORY_KEYS[name]][0].detach().cpu().numpy()
            wanted = np.asarray(value)
            if wanted.dtype == bool or actual.dtype == bool or name == "idx_curr":
                ok = actual.shape == wanted.shape and bool(np.all(actual == wanted))
            else:
                ok = actual.shape == wanted.shape and np.allclose(
                    actual.astype(np.float64), wanted.astype(np.float64), rtol=rtol, atol=atol, equal_nan=True
                )
            if not ok:
                yield f"{path}.{name} (memory {MEMORY_KEYS[name]!r}): got {actual.tolist()}, expected {wanted.tolist()}"


# ==================================================================================================
# Replay protocol
# ==================================================================================================


class Runner(Protocol):
    """One environment's task driven call by call (the Pyrado task interface, per env)."""

    def reset(self, init_state: Sequence[float], overrides: Mapping[str, Any]) -> None: ...
    def step_rew(self, state: Sequence[float], action: Sequence[float], remaining: int) -> float: ...
    def is_done(self, state: Sequence[float]) -> bool: ...
    def has_succeeded(self, state: Sequence[float]) -> bool: ...
    def has_failed(self, state: Sequence[float]) -> bool: ...
    def final_rew(self, state: Sequence[float], remaining: int) -> float: ...


class TorchRunner:
    """Drives a torchtasks task through the functional protocol with a batch of one."""

    def __init__(self, task: Task, dtype: torch.dtype = torch.float64) -> None:
        self.task = task.float() if dtype == torch.float32 else task
        self.dtype = dtype
        self.memory: Any = None

    def _row(self, values: Sequence[float]) -> torch.Tensor:
        return torch.tensor([list(values)], dtype=self.dtype)

    def reset(self, init_state: Sequence[float], overrides: Mapping[str, Any]) -> None:
        self.memory = self.task.reset(self._row(init_state), **overrides)

    def step_rew(self, state: Sequence[float], action: Sequence[float], remaining: int) -> float:
        reward, self.memory = self.task.step_reward(self._row(state), self._row(action), self.memory, remaining)
        assert reward.shape == (1,) and reward.dtype == self.dtype, (reward.shape, reward.dtype)
        return float(reward[0])

    def _flag(self, value: torch.Tensor) -> bool:
        assert value.shape == (1,) and value.dtype == torch.bool, (value.shape, value.dtype)
        return bool(value[0])

    def is_done(self, state: Sequence[float]) -> bool:
        return self._flag(self.task.is_done(self._row(state), self.memory))

    def has_succeeded(self, state: Sequence[float]) -> bool:
        return self._flag(self.task.has_succeeded(self._row(state), self.memory))

    def has_failed(self, state: Sequence[float]) -> bool:
        return self._flag(self.task.has_failed(self._row(state), self.memory))

    def final_rew(self, state: Sequence[float], remaining: int) -> float:
        done = torch.tensor([True])
        final, self.memory = self.task.final_reward(self._row(state), self.memory, remaining, done)
        assert final.shape == (1,) and final.dtype == self.dtype, (final.shape, final.dtype)
        return float(final[0])


@dataclass
class Replay:
    """Columns of one replayed episode (golden ``expected`` layout) plus per-step extras."""

    columns: dict[str, list[Any]] = field(default_factory=lambda: {name: [] for name in (*COLUMNS, "reward")})
    snapshots: list[dict[str, dict[str, Any]]] = field(default_factory=list)
    margins: list[float] = field(default_factory=list)
    memories: list[Any] = field(default_factory=list)

    @property
    def num_steps(self) -> int:
        return len(self.columns["step_rew"])


def replay(
    runner: Runner,
    scenario: Spec,
    episode: Spec,
    *,
    forced_done: Sequence[bool] | None = None,
    num_steps: int | None = None,
) -> Replay:
    """Replay one episode in Pyrado's env order (golden README) and return its columns.

    The episode stops at the first step where ``is_done or time_limit`` holds (or after
    ``num_steps``, default: the recorded steps). With ``forced_done`` the caller decides instead
    at which steps the final reward is taken (used by the float32 re-run, whose own flags may
    legitimately differ at steps that are numerically on a threshold).
    """
    max_steps = scenario["max_steps"]
    states, acts = episode["states"], episode["acts"]
    steps = len(acts) if num_steps is None else num_steps
    result = Replay()
    runner.reset(states[0], reset_overrides(episode))
    margins = MARGINS
    for t in range(steps):
        margins.clear()
        remaining = remaining_steps(max_steps, t)
        step_rew = runner.step_rew(states[t], acts[t], remaining)
        is_done = runner.is_done(states[t + 1])
        succeeded = runner.has_succeeded(states[t + 1])
        failed = runner.has_failed(states[t + 1])
        time_limit = (t + 1) >= max_steps
        done = (is_done or time_limit) if forced_done is None else forced_done[t]
        final = runner.final_rew(states[t + 1], remaining) if done else None
        values = (remaining, step_rew, is_done, succeeded, failed, time_limit, done, final)
        for name, value in zip(COLUMNS, values, strict=True):
            result.columns[name].append(value)
        result.columns["reward"].append(step_rew + (final or 0.0))
        result.margins.append(min(margins, default=math.inf))
        if isinstance(runner, OracleRunner):
            result.snapshots.append(runner.snapshot())
        elif isinstance(runner, TorchRunner):
            result.memories.append(runner.memory)
        if done:
            break
    return result


def column_mismatches(
    actual: Mapping[str, list[Any]],
    expected: Mapping[str, list[Any]],
    steps: Sequence[int],
    rtol: float,
    atol: float,
    *,
    skip_flags: Sequence[int] = (),
) -> list[str]:
    """Messages for every (step, column) where ``actual`` differs from ``expected``."""
    problems = []
    for t in steps:
        for name in (*COLUMNS, "reward"):
            if name not in expected:
                continue
            if t in skip_flags and name in FLAG_COLUMNS:
                continue
            got, want = actual[name][t], expected[name][t]
            if name in FLOAT_COLUMNS:
                if (got is None) != (want is None):
                    ok = False
                else:
                    ok = got is None or bool(np.isclose(got, want, rtol=rtol, atol=atol, equal_nan=True))
            else:
                ok = got == want
            if not ok:
                problems.append(f"step {t} {name}: got {got!r}, expected {want!r}")
    return problems


# ==================================================================================================
# ORACLE (begin) -- numpy only: no torch, no torchtasks in this section
# ==================================================================================================


class Margins(list):
    """Distances of the current step's comparisons to their thresholds (float64, absolute)."""

    def near(self, a: Any, b: Any) -> None:
        diff = np.abs(np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64))
        diff = diff[np.isfinite(diff)]
        if diff.size:
            self.append(float(diff.min()))


MARGINS = Margins()


def _arr(values: Any) -> np.ndarray:
    return np.atleast_1d(np.asarray(values, dtype=np.float64))


def _inside(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Inclusive box membership; NaN is outside."""
    MARGINS.near(x, lo)
    MARGINS.near(x, hi)
    return bool(np.all((lo <= x) & (x <= hi)))


def wrap_pi(x: Any) -> Any:
    """Wrap into [-pi, pi)."""
    return np.remainder(x + math.pi, 2 * math.pi) - math.pi


@dataclass
class OEnv:
    """Effective spec of an oracle task: state and action bounds and labels."""

    lo: np.ndarray
    hi: np.ndarray
    labels: list[str] | None
    act_lo: np.ndarray
    act_hi: np.ndarray
    act_labels: list[str] | None

    @classmethod
    def from_spec(cls, env_spec: Spec) -> OEnv:
        state, act = env_spec["state_space"], env_spec["act_space"]
        return cls(
            _arr(state["bound_lo"]),
            _arr(state["bound_up"]),
            state.get("labels"),
            _arr(act["bound_lo"]),
            _arr(act["bound_up"]),
            act.get("labels"),
        )

    @staticmethod
    def positions(selection: Any, size: int, labels: list[str] | None) -> list[int]:
        """Ints or labels -> positions, in the order given (decision 13); unknown/duplicate raise."""
        if selection is None:
            return list(range(size))
        if isinstance(selection, (int, str)):
            selection = [selection]
        out: list[int] = []
        for item in selection:
            if isinstance(item, str):
                if labels is None or item not in labels:
                    raise ValueError(f"unknown label {item!r}")
                position = labels.index(item)
            else:
                position = int(item) % size
            if position in out:
                raise ValueError(f"duplicate entry {item!r}")
            out.append(position)
        return out

    def select(self, state_idcs: Any, act_idcs: Any) -> tuple[OEnv, list[int], list[int]]:
        s = self.positions(state_idcs, self.lo.size, self.labels)
        a = self.positions(act_idcs, self.act_lo.size, self.act_labels)
        labels = None if self.labels is None else [self.labels[i] for i in s]
        act_labels = None if self.act_labels is None else [self.act_labels[i] for i in a]
        return OEnv(self.lo[s], self.hi[s], labels, self.act_lo[a], self.act_hi[a], act_labels), s, a


# ---- reward functions -----------------------------------------------------------------------------


class ORew:
    """Oracle reward function: ``f(e_s, e_a)``; stateful ones remember the last forward position."""

    def reset(self, init_state: np.ndarray) -> None:
        pass

    def __call__(self, es: np.ndarray, ea: np.ndarray | None) -> float:
        raise NotImplementedError

    def fails(self, state: np.ndarray) -> bool:
        return False

    def snapshot(self, path: str) -> dict[str, dict[str, Any]]:
        return {}


class OFn(ORew):
    def __init__(self, fn: Callable[[np.ndarray, np.ndarray | None], float]) -> None:
        self.fn = fn

    def __call__(self, es: np.ndarray, ea: np.ndarray | None) -> float:
        return float(self.fn(es, ea))


def _quad(W: Any, e: np.ndarray) -> float:
    W = np.atleast_2d(np.asarray(W, dtype=np.float64))
    return float(e @ W @ e)


def _scaled_exp_c_max(spec: Spec) -> float:
    """Decision 2: the scale comes from the constructor's spaces and min_rew, and is kept."""
    s_max = np.maximum(np.abs(_arr(spec["state_space"]["bound_lo"])), np.abs(_arr(spec["state_space"]["bound_up"])))
    a_max = np.maximum(np.abs(_arr(spec["act_space"]["bound_lo"])), np.abs(_arr(spec["act_space"]["bound_up"])))

    def worst(W: Any, m: np.ndarray) -> float:
        terms = np.atleast_2d(np.asarray(W, dtype=np.float64)) * np.outer(m, m)
        return float(np.where(np.atleast_2d(W) == 0, 0.0, terms).sum())  # zero weights do not count

    return -math.log(spec.get("min_rew", 1e-4)) / (worst(spec["Q"], s_max) + worst(spec["R"], a_max))


class OForward(ORew):
    """ForwardVelocity / Ant / Humanoid rewards (decision 18: healthy reward only when healthy)."""

    def __init__(self, spec: Spec) -> None:
        self.spec, self.kind, self.x_last = spec, spec["type"], None

    def reset(self, init_state: np.ndarray) -> None:
        self.x_last = float(init_state[self.spec.get("idx_fwd", 0)])

    def healthy(self, s: np.ndarray) -> bool:
        lo, hi = self.spec["healthy_z_range"]
        MARGINS.near(s[2], [lo, hi])
        if self.kind == "ForwardVelocityRewFcnAnt":
            return bool(np.all(np.isfinite(s)) and lo <= s[2] <= hi)
        return bool(lo < s[2] < hi)

    def fails(self, s: np.ndarray) -> bool:
        return bool(self.spec.get("terminate_when_unhealthy", False)) and not self.healthy(s)

    def __call__(self, s: np.ndarray, a: np.ndarray | None) -> float:
        sp, x = self.spec, float(s[self.spec.get("idx_fwd", 0)])
        velocity = (x - self.x_last) / sp["dt"]
        self.x_last = x
        ctrl = sp.get("ctrl_cost_weight", 0.1) * float(np.sum(a * a))
        if self.kind == "ForwardVelocityRewFcn":
            return sp.get("fwd_rew_weight", 1.0) * velocity - ctrl
        healthy = sp["healthy_reward"] * float(self.healthy(s))
        if self.kind == "ForwardVelocityRewFcnAnt":
            lo, hi = sp["contact_force_range"]
            contact = sp["contact_cost_weight"] * float(np.sum(np.clip(s[29:], lo, hi) ** 2))
            return velocity + healthy - ctrl - contact
        lo, hi = sp["contact_cost_range"]
        contact = float(np.clip(sp["contact_cost_weight"] * np.sum(s[294:] ** 2), lo, hi))
        return sp["forward_reward_weight"] * velocity + healthy - ctrl - contact

    def snapshot(self, path: str) -> dict[str, dict[str, Any]]:
        return {path: {"last_x_pos": self.x_last}}


class OCompound(ORew):
    def __init__(self, parts: list[ORew]) -> None:
        self.parts = parts

    def reset(self, init_state: np.ndarray) -> None:
        for part in self.parts:
            part.reset(init_state)

    def __call__(self, es: np.ndarray, ea: np.ndarray | None) -> float:
        total = 0.0
        for part in self.parts:
            total += part(es, ea)
        return total

    def fails(self, state: np.ndarray) -> bool:
        return any(part.fails(state) for part in self.parts)

    def snapshot(self, path: str) -> dict[str, dict[str, Any]]:
        out: dict[str, dict[str, Any]] = {}
        for i, part in enumerate(self.parts):
            out.update(part.snapshot(f"{path}.rew_fcns[{i}]"))
        return out


def _state_fn(spec: Spec) -> Callable[[np.ndarray], Any]:
    kind = spec["type"]
    if kind == "sum_of_squares":
        return lambda x: float(np.sum(x * x))
    if kind == "rosenbrock":
        return lambda x: float(np.sum(100.0 * (x[1:] - x[:-1] ** 2) ** 2 + (1.0 - x[:-1]) ** 2))
    if kind == "norm_below":
        center, radius = _arr(spec["center"]), spec["radius"]

        def norm_below(x: np.ndarray) -> bool:
            norm = float(np.linalg.norm(x - center))
            MARGINS.near(norm, radius)
            return norm < radius

        return norm_below
    if kind == "component_above":
        idx, value = spec["idx"], spec["value"]

        def component_above(x: np.ndarray) -> bool:
            MARGINS.near(x[idx], value)
            return bool(x[idx] > value)

        return component_above
    raise NotImplementedError(kind)


def oracle_reward(spec: Spec) -> ORew:
    kind, sp = spec["type"], spec
    constants = {"ZeroPerStepRewFcn": 0.0, "PlusOnePerStepRewFcn": 1.0, "MinusOnePerStepRewFcn": -1.0}
    if kind in constants:
        value = constants[kind]
        return OFn(lambda es, ea: value)
    if kind == "CosOfOneEleRewFcn":
        return OFn(lambda es, ea: math.cos(es[sp["idx"]]))
    if kind == "SSCosOfOneEleRewFcn":
        return OFn(lambda es, ea: 0.5 * (math.cos(es[sp["idx"]]) + 1.0))
    if kind == "AbsErrRewFcn":
        q, r = _arr(sp["q"]), _arr(sp["r"])
        return OFn(lambda es, ea: -(float(np.abs(es) @ q) + float(np.abs(ea) @ r)))
    if kind == "QuadrErrRewFcn":
        return OFn(lambda es, ea: -(_quad(sp["Q"], es) + _quad(sp["R"], ea)))
    if kind == "ExpQuadrErrRewFcn":
        return OFn(lambda es, ea: math.exp(-(_quad(sp["Q"], es) + _quad(sp["R"], ea))))
    if kind == "ScaledExpQuadrErrRewFcn":
        c_max = _scaled_exp_c_max(sp)
        return OFn(lambda es, ea: math.exp(-c_max * (_quad(sp["Q"], es) + _quad(sp["R"], ea))))
    if kind == "UnderActuatedSwingUpRewFcn":
        c = {
            "c_pole": 1.0,
            "c_cart": 0.2,
            "c_act": 1e-3,
            "c_theta_sq": 1.0,
            "c_theta_log": 0.1,
            "idx_x": 0,
            "idx_th": 1,
        }
        c.update({key: sp[key] for key in c if key in sp})

        def swing_up(es: np.ndarray, ea: np.ndarray) -> float:
            th = es[c["idx_th"]]
            pole = c["c_pole"] * (c["c_theta_sq"] * th**2 + math.log(th**2 + c["c_theta_log"]))
            return 10.0 - pole - c["c_cart"] * abs(es[c["idx_x"]]) - c["c_act"] * float(np.sum(ea * ea))

        return OFn(swing_up)
    if kind == "QCartPoleSwingUpRewFcn":
        f = sp.get("factor", 0.9)
        return OFn(lambda es, ea: f * (1.0 - (abs(es[1]) / math.pi) ** 2) + (1.0 - f) * abs(es[0]))
    if kind == "CompoundRewFcn":
        return OCompound([oracle_reward(part) for part in sp["rew_fcns"]])
    if kind == "StateBasedRewFcn":
        fn = _state_fn(sp["fcn"])
        return OFn(lambda s, a: -fn(s))  # Pyrado always negates
    if kind.startswith("ForwardVelocityRewFcn"):
        return OForward(sp)
    raise NotImplementedError(kind)


# ---- tasks --------------------------------------------------------------------------------------


def _success(spec: Spec | None) -> Callable[[np.ndarray], bool]:
    if spec is None or spec["type"] == "never_succeeded":
        return lambda err: False
    thold, dims = spec["thold_dist"], spec.get("dims", -1)

    def proximity(err: np.ndarray) -> bool:
        norm = float(np.linalg.norm(err if dims == -1 else err[np.atleast_1d(dims)]))
        MARGINS.near(norm, thold)
        return norm < thold

    return proximity


class OTask:
    """Oracle task for one environment (Pyrado's mutable style, fixes of section 10 applied)."""

    wrapper = False

    def __init__(self, env: OEnv) -> None:
        self.env = env

    def reset(self, init_state: np.ndarray, **kw: Any) -> None:
        pass

    def step_rew(self, s: np.ndarray, a: np.ndarray, rem: int) -> float:
        raise NotImplementedError

    def has_succeeded(self, s: np.ndarray) -> bool:
        return False

    def has_failed(self, s: np.ndarray) -> bool:
        return not _inside(s, self.env.lo, self.env.hi)

    def is_done(self, s: np.ndarray) -> bool:
        return self.has_succeeded(s) or self.has_failed(s)

    def compute_final_rew(self, s: np.ndarray, rem: int) -> float:
        return 0.0

    def final_rew(self, s: np.ndarray, rem: int) -> float:
        """Sum of compute_final_rew over the wrapper chain (a MaskedTask pays its inner task, fix 13)."""
        total, task = 0.0, self
        while True:
            total += task.compute_final_rew(s, rem)
            if not task.wrapper:
                return total
            task = task.wrapped

    def snapshot(self, path: str) -> dict[str, dict[str, Any]]:
        return {}


class ODesState(OTask):
    def __init__(self, env: OEnv, state_des: Any, rew: ORew, success: Spec | None) -> None:
        super().__init__(env)
        self.state_des, self.rew, self.success = _arr(state_des), rew, _success(success)
        if self.state_des.size != env.lo.size:
            raise ValueError("state_des must have the state's size")

    def reset(self, init_state: np.ndarray, **kw: Any) -> None:
        self.rew.reset(init_state)

    def error(self, s: np.ndarray) -> np.ndarray:
        return self.state_des - s

    def step_rew(self, s: np.ndarray, a: np.ndarray, rem: int) -> float:
        return self.rew(self.error(s), -a)

    def has_succeeded(self, s: np.ndarray) -> bool:
        return self.success(self.error(s))


class ORadSymm(ODesState):
    """Decision 9: only the listed entries are wrapped into [-m/2, m/2); success sees the same error."""

    def __init__(self, env: OEnv, spec: Spec) -> None:
        super().__init__(env, spec["state_des"], oracle_reward(spec["rew_fcn"]), spec.get("success_fcn"))
        self.idcs = OEnv.positions(spec["idcs"], env.lo.size, env.labels)
        self.mod = _arr(spec.get("modulation", 2 * math.pi)) * np.ones(len(self.idcs))

    def error(self, s: np.ndarray) -> np.ndarray:
        e = self.state_des - s
        for i, m in zip(self.idcs, self.mod, strict=True):
            turns = (e[i] + m / 2) / m
            MARGINS.near(turns * m, round(turns) * m)  # distance to the wrap discontinuity
            e[i] = e[i] - m * math.floor(turns)
        return e


class ODesSpace(OTask):
    """Decision 1: the default reward is 0 and any reward function is accepted."""

    def __init__(self, env: OEnv, spec: Spec) -> None:
        super().__init__(env)
        self.space_lo, self.space_hi = _arr(spec["space_des"]["bound_lo"]), _arr(spec["space_des"]["bound_up"])
        self.rew = oracle_reward(spec.get("rew_fcn") or {"type": "ZeroPerStepRewFcn"})

    def step_rew(self, s: np.ndarray, a: np.ndarray, rem: int) -> float:
        return self.rew(s, a)

    def has_succeeded(self, s: np.ndarray) -> bool:
        return _inside(s, self.space_lo, self.space_hi)


class OGoalless(OTask):
    """GoallessTask; with decision 18 an unhealthy state is a failure when the reward says so."""

    def __init__(self, env: OEnv, rew: ORew) -> None:
        super().__init__(env)
        self.rew = rew

    def reset(self, init_state: np.ndarray, **kw: Any) -> None:
        self.rew.reset(init_state)

    def step_rew(self, s: np.ndarray, a: np.ndarray, rem: int) -> float:
        return self.rew(s, a)

    def has_failed(self, s: np.ndarray) -> bool:
        return super().has_failed(s) or self.rew.fails(s)

    def snapshot(self, path: str) -> dict[str, dict[str, Any]]:
        return self.rew.snapshot(f"{path}.rew_fcn")


class OCondition(OTask):
    def __init__(self, env: OEnv, spec: Spec) -> None:
        super().__init__(env)
        self.condition, self.is_success = _state_fn(spec["condition_fcn"]), spec["is_success_condition"]

    def step_rew(self, s: np.ndarray, a: np.ndarray, rem: int) -> float:
        return 0.0

    def has_succeeded(self, s: np.ndarray) -> bool:
        return bool(self.is_success and self.condition(s))

    def has_failed(self, s: np.ndarray) -> bool:
        return super().has_failed(s) if self.is_success else bool(self.condition(s))


class OFlipping(OTask):
    """Decision 10: the target with the smaller wrapped error (ties: L+delta) is used."""

    def __init__(self, env: OEnv, spec: Spec) -> None:
        super().__init__(env)
        self.delta, self.rew = spec["des_angle_delta"], oracle_reward(spec["rew_fcn"])
        self.tol, self.endless = spec.get("angle_tol", math.pi / 180), spec.get("endless", True)
        self.last, self.held = 0.0, 0.0

    def reset(self, init_state: np.ndarray, **kw: Any) -> None:
        self.last, self.held = 0.0, 0.0

    def closest(self, s: np.ndarray) -> tuple[float, float]:
        up, down = self.last + self.delta, self.last - self.delta
        e_up, e_down = float(wrap_pi(up - s[0])), float(wrap_pi(down - s[0]))
        MARGINS.near(abs(e_up), abs(e_down))
        return (down, e_down) if abs(e_down) < abs(e_up) else (up, e_up)

    def step_rew(self, s: np.ndarray, a: np.ndarray, rem: int) -> float:
        target, err = self.closest(s)
        value = self.rew(np.array([err]), -a)
        out = self.held + value
        MARGINS.near(abs(err), self.tol)
        if abs(err) <= self.tol:
            self.last, self.held = target, self.held + value
        return out

    def has_succeeded(self, s: np.ndarray) -> bool:
        if self.endless:
            return False
        _, err = self.closest(s)
        MARGINS.near(abs(err), self.tol)
        return abs(err) <= self.tol

    def snapshot(self, path: str) -> dict[str, dict[str, Any]]:
        return {path: {"last_angle": self.last, "held_rew": self.held}}


class OOptim(OTask):
    def __init__(self, env: OEnv, rew: ORew) -> None:
        super().__init__(env)
        self.rew = rew

    def step_rew(self, s: np.ndarray, a: np.ndarray, rem: int) -> float:
        return self.rew(s, None)


class OWrapper(OTask):
    wrapper = True

    def __init__(self, wrapped: OTask) -> None:
        super().__init__(wrapped.env)
        self.wrapped, self.yielded = wrapped, False

    def reset(self, init_state: np.ndarray, **kw: Any) -> None:
        self.wrapped.reset(init_state, **kw)
        self.yielded = False

    def step_rew(self, s: np.ndarray, a: np.ndarray, rem: int) -> float:
        return self.wrapped.step_rew(s, a, rem)

    def has_succeeded(self, s: np.ndarray) -> bool:
        return self.wrapped.has_succeeded(s)

    def has_failed(self, s: np.ndarray) -> bool:
        return self.wrapped.has_failed(s)

    def is_done(self, s: np.ndarray) -> bool:
        return self.wrapped.is_done(s)

    def snapshot(self, path: str) -> dict[str, dict[str, Any]]:
        return self.wrapped.snapshot(f"{path}.wrapped_task")


SUPPORTED_MODES = {  # (state_dependent, time_dependent, always_positive, always_negative)
    (False, False, False, False),
    (False, False, True, False),
    (False, False, False, True),
    (True, False, True, False),
    (True, False, False, True),
    (True, False, False, False),
    (True, True, False, False),
    (False, True, False, False),
    (False, True, True, False),
    (False, True, False, True),
}


class OFinalRew(OWrapper):
    """Decision 11: paid once (the oracle only asks when done), failure first, no memory change."""

    def __init__(self, wrapped: OTask, mode: Spec | None, factor: float) -> None:
        super().__init__(wrapped)
        mode = dict(mode or {})
        key = tuple(bool(mode.get(name, False)) for name in _MODE_FLAGS)
        if mode.get("user_input", False) or key not in SUPPORTED_MODES:
            raise ValueError(f"unsupported final reward mode {mode}")
        self.state_dep, self.time_dep, self.positive, self.negative = key
        self.factor = abs(factor)

    def compute_final_rew(self, s: np.ndarray, rem: int) -> float:
        if self.yielded:
            return 0.0
        self.yielded = True
        magnitude = float(rem) if self.time_dep else self.factor
        if self.state_dep:  # evaluated on a copy: the extra evaluation never changes state
            probe = copy.deepcopy(self.wrapped)
            magnitude *= abs(probe.step_rew(s, np.zeros(self.env.act_lo.size), rem))
        if self.wrapped.has_failed(s):
            return 0.0 if self.positive else -magnitude
        if self.wrapped.has_succeeded(s):
            return 0.0 if self.negative else magnitude
        return 0.0

    def snapshot(self, path: str) -> dict[str, dict[str, Any]]:
        return {path: {"yielded_final_rew": self.yielded}, **super().snapshot(path)}


_MODE_FLAGS = ("state_dependent", "time_dependent", "always_positive", "always_negative")


class OBestState(OWrapper):
    def __init__(self, wrapped: OTask, factor: float) -> None:
        super().__init__(wrapped)
        self.factor, self.best = factor, -math.inf

    def reset(self, init_state: np.ndarray, **kw: Any) -> None:
        super().reset(init_state, **kw)
        self.best = -math.inf

    def step_rew(self, s: np.ndarray, a: np.ndarray, rem: int) -> float:
        r = self.wrapped.step_rew(s, a, rem)
        if r > self.best:
            self.best = r
        return r

    def compute_final_rew(self, s: np.ndarray, rem: int) -> float:
        if self.yielded:
            return 0.0
        self.yielded = True
        return self.best * self.factor

    def snapshot(self, path: str) -> dict[str, dict[str, Any]]:
        return {path: {"best_rew": self.best, "yielded_final_rew": self.yielded}, **super().snapshot(path)}


class OMasked(OTask):
    """Decision 13: indices in the order given; the inner final rewards are paid."""

    def __init__(self, env: OEnv, spec: Spec) -> None:
        super().__init__(env)
        sub_env, self.s_idx, self.a_idx = env.select(spec["state_idcs"], spec.get("action_idcs"))
        self.wrapped = oracle_task(spec["wrapped_task"], sub_env)

    def reset(self, init_state: np.ndarray, **kw: Any) -> None:
        self.wrapped.reset(init_state[self.s_idx], **kw)

    def step_rew(self, s: np.ndarray, a: np.ndarray, rem: int) -> float:
        return self.wrapped.step_rew(s[self.s_idx], a[self.a_idx], rem)

    def has_succeeded(self, s: np.ndarray) -> bool:
        return self.wrapped.has_succeeded(s[self.s_idx])

    def has_failed(self, s: np.ndarray) -> bool:
        return self.wrapped.has_failed(s[self.s_idx])

    def compute_final_rew(self, s: np.ndarray, rem: int) -> float:
        return self.wrapped.final_rew(s[self.s_idx], rem)

    def snapshot(self, path: str) -> dict[str, dict[str, Any]]:
        return self.wrapped.snapshot(f"{path}.wrapped_task")


class OComposite(OTask):
    def __init__(self, env: OEnv, spec: Spec) -> None:
        super().__init__(env)
        self.tasks = [oracle_task(sub, env) for sub in spec["tasks"]]
        self.hold = spec.get("hold_rew_when_done", False)
        k = len(self.tasks)
        self.succ, self.fail, self.held = [False] * k, [False] * k, [0.0] * k

    def reset(self, init_state: np.ndarray, **kw: Any) -> None:
        for task in self.tasks:
            task.reset(init_state, **kw)
        k = len(self.tasks)
        self.succ, self.fail, self.held = [False] * k, [False] * k, [0.0] * k

    def done(self, i: int) -> bool:
        return self.succ[i] or self.fail[i]

    def mark(self, i: int, s: np.ndarray) -> None:
        if self.tasks[i].has_succeeded(s):
            self.succ[i] = True
        elif self.tasks[i].has_failed(s):
            self.fail[i] = True
        else:
            raise ValueError("a done sub-task neither succeeded nor failed")

    def compute_final_rew(self, s: np.ndarray, rem: int) -> float:
        return sum(task.compute_final_rew(s, rem) for task in self.tasks)

    def snapshot(self, path: str) -> dict[str, dict[str, Any]]:
        own: dict[str, Any] = {"succeeded_tasks": list(self.succ), "failed_tasks": list(self.fail)}
        if self.hold:
            own["held_rews"] = list(self.held)
        out = {path: own}
        for i, task in enumerate(self.tasks):
            out.update(task.snapshot(f"{path}.tasks[{i}]"))
        return out


class OParallel(OComposite):
    def __init__(self, env: OEnv, spec: Spec) -> None:
        super().__init__(env, spec)
        self.allow_failures = spec.get("allow_failures", False)
        self.easily_satisfied = spec.get("easily_satisfied", False)

    def step_rew(self, s: np.ndarray, a: np.ndarray, rem: int) -> float:
        r = 0.0
        for i, task in enumerate(self.tasks):
            if not self.done(i):
                r += task.step_rew(s, a, rem)
            elif self.hold:
                r += self.held[i]
        for i, task in enumerate(self.tasks):
            if not self.done(i) and task.is_done(s):
                self.mark(i, s)
                r += task.final_rew(s, rem)
                if self.hold:
                    self.held[i] = task.step_rew(s, a, rem)
        return r

    def has_succeeded(self, s: np.ndarray) -> bool:
        return any(self.succ) if self.easily_satisfied else all(self.succ)

    def has_failed(self, s: np.ndarray) -> bool:
        return all(self.fail) if self.allow_failures else any(self.fail)


class OSequential(OComposite):
    """Decision 15: every reset starts at start_idx (or the reset's start_idx); earlier ones count as done."""

    def __init__(self, env: OEnv, spec: Spec) -> None:
        super().__init__(env, spec)
        self.start_idx = spec.get("start_idx", 0)
        self.idx = self.start_idx

    def reset(self, init_state: np.ndarray, **kw: Any) -> None:
        super().reset(init_state, **kw)
        self.idx = kw.get("start_idx", self.start_idx)
        self.succ = [i < self.idx for i in range(len(self.tasks))]

    def step_rew(self, s: np.ndarray, a: np.ndarray, rem: int) -> float:
        r = sum(self.held[i] for i in range(len(self.tasks)) if self.done(i)) if self.hold else 0.0
        i, task = self.idx, self.tasks[self.idx]
        if not self.done(i):
            r += task.step_rew(s, a, rem)
            if task.is_done(s):
                self.mark(i, s)
                if self.hold:
                    self.held[i] = task.step_rew(s, a, 0)
                r += task.final_rew(s, rem)
                self.idx = (i + 1) % len(self.tasks)
        return r

    def has_succeeded(self, s: np.ndarray) -> bool:
        return all(self.succ)

    def snapshot(self, path: str) -> dict[str, dict[str, Any]]:
        out = super().snapshot(path)
        out[path]["idx_curr"] = self.idx
        return out


def expand_factory(spec: Spec, env: OEnv) -> dict[str, Any]:
    """Pyrado's predefined factories (section 7) as basic spec trees, with decision 16 applied."""
    kind, n_act = spec["type"], env.act_lo.size

    def masked(labels: list[Any], inner: dict[str, Any]) -> dict[str, Any]:
        return {"type": "MaskedTask", "state_idcs": labels, "action_idcs": None, "wrapped_task": inner}

    def des_state(state_des: Any, rew: Spec, success: Spec | None) -> dict[str, Any]:
        return {"type": "DesStateTask", "state_des": state_des, "rew_fcn": rew, "success_fcn": success}

    never = {"type": "never_succeeded"}

    def proximity() -> dict[str, Any]:
        return {"type": "proximity_succeeded", "thold_dist": spec.get("succ_thold", 0.01), "dims": -1}

    if kind == "create_check_all_boundaries_task":
        inner = des_state([0.0] * env.lo.size, {"type": "ZeroPerStepRewFcn"}, never)
        return {
            "type": "FinalRewTask",
            "wrapped_task": inner,
            "mode": {"always_negative": True},
            "factor": spec["penalty"],
        }
    if kind == "create_task_space_discrepancy_task":
        labels = [label for label in env.labels or [] if "DiscrepTS" in label]
        if not labels:
            raise ValueError("no DiscrepTS label")
        return masked(labels, des_state([0.0] * len(labels), spec["rew_fcn"], never))
    if kind == "create_collision_task":
        if spec["factor"] < 0:
            raise ValueError("factor must be >= 0")
        rew = {"type": "AbsErrRewFcn", "q": [spec["factor"]], "r": [0.0] * n_act}
        return masked(["CollCost"], des_state([0.0], rew, never))
    if kind == "create_forcemin_task":
        labels = spec["obs_labels"]
        rew = {"type": "QuadrErrRewFcn", "Q": spec["Q"], "R": np.zeros((n_act, n_act)).tolist()}
        return masked(labels, des_state([0.0] * len(labels), rew, never))
    if kind == "create_lifting_task":
        rew = {"type": "ExpQuadrErrRewFcn", "Q": [[600.0]], "R": (0.1 * np.eye(n_act)).tolist()}
        return masked(spec["obs_labels"], des_state(_arr(spec["des_height"]).tolist(), rew, proximity()))
    if kind == "create_flipping_task":
        inner = {
            "type": "FlippingTask",
            "des_angle_delta": spec.get("des_angle_delta", math.pi / 2),
            "rew_fcn": {"type": "CosOfOneEleRewFcn", "idx": 0},
            "endless": spec.get("endless", True),
        }
        return masked(spec["obs_labels"], inner)
    if kind == "create_home_pos_task":
        n = len(spec["state_des"])
        rew = {"type": "ExpQuadrErrRewFcn", "Q": (10.0 * np.eye(n)).tolist(), "R": (0.1 * np.eye(n_act)).tolist()}
        return masked(spec["obs_labels"], des_state(spec["state_des"], rew, None))
    if kind == "create_goal_dist_task":  # decision 16: one goal entry for the one selected entry
        return masked([f"GD_DS{spec['ds_label']}"], des_state([0.0], spec["rew_fcn"], proximity()))
    if kind == "create_goal_dist_distvel_task":
        labels = [f"GD_DS{spec['ds_label']}", f"GD_DS{spec['ds_label']}d"]
        return masked(labels, des_state([0.0, 0.0], spec["rew_fcn"], proximity()))
    raise NotImplementedError(kind)


def oracle_task(spec: Spec, env: OEnv) -> OTask:
    """Build the oracle of a golden task spec with ``env`` as its effective spec."""
    kind = spec["type"]
    if kind.startswith("create_"):
        return oracle_task(expand_factory(spec, env), env)
    if kind == "DesStateTask":
        return ODesState(env, spec["state_des"], oracle_reward(spec["rew_fcn"]), spec.get("success_fcn"))
    if kind == "RadiallySymmDesStateTask":
        return ORadSymm(env, spec)
    if kind == "DesSpaceTask":
        return ODesSpace(env, spec)
    if kind == "GoallessTask":
        return OGoalless(env, oracle_reward(spec["rew_fcn"]))
    if kind == "OptimProxyTask":
        return OOptim(env, oracle_reward(spec["rew_fcn"]))
    if kind == "ConditionOnlyTask":
        return OCondition(env, spec)
    if kind == "FlippingTask":
        return OFlipping(env, spec)
    if kind == "FinalRewTask":
        return OFinalRew(oracle_task(spec["wrapped_task"], env), spec.get("mode"), spec.get("factor", 1e3))
    if kind == "BestStateFinalRewTask":
        return OBestState(oracle_task(spec["wrapped_task"], env), spec["factor"])
    if kind == "MaskedTask":
        return OMasked(env, spec)
    if kind == "ParallelTasks":
        return OParallel(env, spec)
    if kind == "SequentialTasks":
        return OSequential(env, spec)
    raise NotImplementedError(kind)


class OracleRunner:
    """Drives the oracle task of a scenario (kw names are Pyrado's: start_idx)."""

    def __init__(self, scenario: Spec) -> None:
        self.task = oracle_task(fixed_spec(scenario), OEnv.from_spec(scenario["env_spec"]))

    def reset(self, init_state: Sequence[float], overrides: Mapping[str, Any]) -> None:
        kw = {"start_idx": overrides["start_index"]} if "start_index" in overrides else {}
        self.task.reset(_arr(init_state), **kw)

    def step_rew(self, state: Sequence[float], action: Sequence[float], remaining: int) -> float:
        return float(self.task.step_rew(_arr(state), _arr(action), remaining))

    def is_done(self, state: Sequence[float]) -> bool:
        return bool(self.task.is_done(_arr(state)))

    def has_succeeded(self, state: Sequence[float]) -> bool:
        return bool(self.task.has_succeeded(_arr(state)))

    def has_failed(self, state: Sequence[float]) -> bool:
        return bool(self.task.has_failed(_arr(state)))

    def final_rew(self, state: Sequence[float], remaining: int) -> float:
        return float(self.task.final_rew(_arr(state), remaining))

    def snapshot(self) -> dict[str, dict[str, Any]]:
        return self.task.snapshot("root")


# ==================================================================================================
# ORACLE (end)
# ==================================================================================================


def is_deviation(scenario: Spec) -> bool:
    return expected_deviation(scenario["name"]) is not None
