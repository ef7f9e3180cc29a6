"""The table of the entries a TaskTransform writes: it says what the transform does, and names are spelt once.

For task trees of every shape (memory or none, terms, a final reward, costs, named end conditions, an achieved
goal, ``log_terms=False``) the entries the transform writes in a step, offline, when relabelling and at reset,
and the entries it adds to each spec, are observed and compared with the rules of the docs, counted here from
the task's own public facts; the table (``TaskTransform.entries``) must list exactly those.
"""

from __future__ import annotations

import ast
import functools
import inspect
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
from tensordict import TensorDictBase
from torchrl.envs import Compose, StepCounter, TransformedEnv

import torchtasks
from torchtasks.envs import PendulumEnv, PointMassEnv, swing_up_task
from torchtasks.rewards import QuadraticErrorReward, StateFunctionReward
from torchtasks.rewards.terms import HealthyReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.stats import episode_statistics
from torchtasks.tasks import ConstrainedTask, DesiredStateTask, GoallessTask, MaskedTask, proximity_succeeded
from torchtasks.transforms import GoalCommand, TaskTransform, gated

POINT_SPEC = EnvSpec(Box([-0.9, -0.9, -10.0, -10.0], [0.9, 0.9, 10.0, 10.0], labels=PointMassEnv.labels), 2)


def _fast(state: torch.Tensor) -> torch.Tensor:
    return (state[..., 1].abs() > 1.0).to(state.dtype)


def _far(state: torch.Tensor) -> torch.Tensor:
    return state[..., 0].abs()


def _pendulum(task, **kwargs) -> TransformedEnv:
    return TransformedEnv(PendulumEnv(batch_size=[4], seed=0), Compose(StepCounter(20), TaskTransform(task, **kwargs)))


def _desired_state(**kwargs) -> TransformedEnv:
    near = functools.partial(proximity_succeeded, threshold=0.5)
    return _pendulum(DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], QuadraticErrorReward([1.0, 0.1]), near), **kwargs)


def _memoryless() -> TransformedEnv:
    return _pendulum(GoallessTask(EnvSpec(2, 1), QuadraticErrorReward([1.0, 0.1])))


def _constrained() -> TransformedEnv:
    costs = {"speed": StateFunctionReward(_fast, negate=False), "angle": StateFunctionReward(_far, negate=False)}
    return _pendulum(ConstrainedTask(swing_up_task(), costs))


def _end_conditions() -> TransformedEnv:
    alive = HealthyReward(1.0, index=[2], low=-0.8, high=0.8, terminate_when_unhealthy=True)
    task = GoallessTask(POINT_SPEC, alive)
    env = PointMassEnv(batch_size=[4], seed=0, max_force=2.0)
    return TransformedEnv(env, Compose(StepCounter(20), TaskTransform(task, ended_by_key=("why", "ended"))))


def _achieved_goal() -> TransformedEnv:
    near = functools.partial(proximity_succeeded, threshold=0.3)
    reach = DesiredStateTask(POINT_SPEC.select_state(["x", "y"]), [0.0, 0.0], QuadraticErrorReward([1.0, 1.0]), near)
    transform = TaskTransform(MaskedTask(POINT_SPEC, reach, ["x", "y"]), goal_key="goal", achieved_goal_key="reached")
    command = GoalCommand(Box([-0.5, -0.5], [0.5, 0.5]), seed=0)
    return TransformedEnv(PointMassEnv(batch_size=[4], seed=0), Compose(StepCounter(20), transform, command))


CASES: dict[str, Callable[[], TransformedEnv]] = {
    "desired_state": _desired_state,
    "memoryless": _memoryless,
    "terms_and_final": lambda: _pendulum(swing_up_task()),
    "terms_and_final_own_keys": lambda: _pendulum(swing_up_task(), terms_key=("log", "terms"), memory_key="mem"),
    "no_log_terms": lambda: _pendulum(swing_up_task(), log_terms=False),
    "constrained": _constrained,
    "end_conditions": _end_conditions,
    "achieved_goal": _achieved_goal,
}


def _transform(env: TransformedEnv) -> TaskTransform:
    return next(t for t in env.transform if isinstance(t, TaskTransform))


def _key(*parts) -> object:
    """A key as TensorDict unravels it: a string for one part, else a flat tuple."""
    flat = [p for part in parts for p in ((part,) if isinstance(part, str) else part)]
    return flat[0] if len(flat) == 1 else tuple(flat)


def _expected(transform: TaskTransform) -> dict[str, set | list]:
    """The entries the docs say the transform writes, from the task's public facts and the transform's keys."""
    task = transform.task
    memory = task.reset(torch.zeros(1, task.state_size, dtype=torch.float64))
    has_memory = len(list(memory.keys(True, True))) > 0
    kinds = list(task.termination_names.values())
    # the flag of each outcome the tree has a condition for (a tree that cannot succeed writes no success flag)
    flags = {
        key for kind, key in (("success", transform.success_key), ("failure", transform.failure_key)) if kind in kinds
    }
    if transform.log_terms and (kinds.count("success") > 1 or kinds.count("failure") > 1):
        flags |= {_key(transform.ended_by_key, name) for name in task.termination_names}
    term_keys = []  # in the documented order: step and final reward, then the named terms
    if transform.log_terms:
        if task.pays_final_reward:
            term_keys += [_key(transform.terms_key, "step"), _key(transform.terms_key, "final")]
        term_keys += [_key(transform.terms_key, name) for name in task.term_names]
    cost_keys = [_key(transform.cost_terms_key, name) for name in task.cost_names]
    terms, costs = set(term_keys), set(cost_keys) | ({transform.cost_key} if task.cost_names else set())
    memory_keys = {transform.memory_key} if has_memory else set()
    goal = set() if transform.achieved_goal_key is None else {transform.achieved_goal_key}
    judged = {transform.reward_key, *flags, "terminated", "done", *terms, *costs}
    return {
        "step": judged | memory_keys | goal,
        "offline": judged,
        "relabel": judged | memory_keys,
        "reset": flags | memory_keys | goal,
        "observation": flags | memory_keys | goal,
        "state": memory_keys,
        "reward": terms | costs,
        "term_keys": term_keys,
        "cost_keys": cost_keys,
    }


def _written(before: TensorDictBase, after: TensorDictBase, memory_key) -> set:
    """Keys of ``after`` that are new or hold another tensor than in ``before`` (the memory counted as one key)."""
    written = set()
    for key in after.keys(True, True):
        if before.get(key, None) is after.get(key):
            continue
        parts = (key,) if isinstance(key, str) else key
        memory = (memory_key,) if isinstance(memory_key, str) else memory_key
        written.add(memory_key if parts[: len(memory)] == memory else key)
    return written


def _spec_keys(spec, memory_key) -> set:
    return {memory_key if _under(key, memory_key) else key for key in spec.keys(True, True)}


def _under(key, root) -> bool:
    parts, root = ((key,) if isinstance(key, str) else key), ((root,) if isinstance(root, str) else root)
    return parts[: len(root)] == root


@pytest.fixture(scope="module", params=sorted(CASES))
def case(request):
    env = CASES[request.param]()
    data = env.rollout(3, break_when_any_done=False)
    return env, _transform(env), data


def test_the_table_lists_what_each_occasion_writes(case) -> None:
    _, transform, _ = case
    expected = _expected(transform)
    for occasion in ("step", "offline", "relabel", "reset"):
        assert set(transform.entries.keys(occasion=occasion)) == expected[occasion], occasion
    for spec in ("observation", "state"):
        assert set(transform.entries.keys(spec=spec)) == expected[spec], spec
    assert set(transform.entries.keys(spec="reward")) == expected["reward"] | {transform.reward_key}
    assert transform.term_keys == expected["term_keys"]
    assert transform.cost_keys == expected["cost_keys"]


@pytest.mark.parametrize("has_terminated", [True, False])
def test_a_step_writes_the_documented_entries(case, has_terminated: bool) -> None:
    _env, transform, data = case
    root = data[..., 1]
    base_keys = [*transform.state_keys, "reward", "done", "truncated", "step_count"]
    base_keys += ["terminated"] if has_terminated else []
    next_td = root["next"].select(*base_keys).clone()
    before = next_td.clone(recurse=False)
    transform._step(root, next_td)
    expected = _expected(transform)["step"] - (set() if has_terminated else {"terminated"})
    assert _written(before, next_td, transform.memory_key) == expected


def test_recomputing_stored_transitions_writes_the_documented_entries(case) -> None:
    _, transform, data = case
    stored = data.clone()
    before = stored["next"].clone(recurse=False)
    transform.forward(stored)
    assert _written(before, stored["next"], transform.memory_key) == _expected(transform)["offline"]


@pytest.mark.parametrize(("method", "occasion"), [("forward", "offline"), ("relabel", "relabel")])
def test_stored_outputs_are_restored_where_the_occasion_writes_them(case, method: str, occasion: str) -> None:
    """Outputs the recomputation does not read (reward, breakdown, costs, next memory, achieved goal) are spoilt;
    the entries the occasion writes get the online step's values back, the others stay spoilt."""
    _, transform, data = case
    expected = _expected(transform)
    outputs = expected["step"] - {transform.success_key, transform.failure_key, "terminated", "done"}  # read offline
    stored = data.clone()
    spoilt = [leaf for leaf in stored["next"].keys(True, True) if any(_under(leaf, key) for key in outputs)]
    assert spoilt
    for leaf in spoilt:
        value = stored["next", leaf]
        stored["next", leaf] = ~value if value.dtype == torch.bool else value + 1000
    getattr(transform, method)(stored)
    for leaf in spoilt:
        restored = torch.equal(stored["next", leaf], data["next", leaf])
        assert restored == any(_under(leaf, key) for key in expected[occasion]), (leaf, restored)


def test_a_reset_writes_the_documented_entries(case) -> None:
    _env, transform, data = case
    reset = data[..., 0].select(*transform.state_keys, "done", "terminated", "truncated").clone()
    before = reset.clone(recurse=False)
    out = transform._reset(None, reset)
    written = _written(before, out, transform.memory_key)
    assert written == _expected(transform)["reset"]
    for key in written - {transform.memory_key} - ({transform.achieved_goal_key} - {None}):
        assert out[key].dtype == torch.bool and not out[key].any(), key


def test_the_specs_hold_the_documented_entries(case) -> None:
    _env, transform, _ = case
    parent = transform.parent
    expected = _expected(transform)
    observation = parent.full_observation_spec
    added = _spec_keys(transform.transform_observation_spec(observation.clone()), transform.memory_key)
    assert added - _spec_keys(observation, transform.memory_key) == expected["observation"]
    state = parent.full_state_spec
    added = _spec_keys(transform.transform_state_spec(state.clone()), transform.memory_key)
    assert added - _spec_keys(state, transform.memory_key) == expected["state"]
    reward = parent.full_reward_spec
    assert (
        set(transform.transform_reward_spec(reward.clone()).keys(True, True)) - set(reward.keys(True, True))
        == (expected["reward"])
    )


# ------------------------------------------------------------------------------------------------ names spelt once
#: the default names of the entries a task writes
DEFAULT_NAMES = {"reward", "task", "success", "failure", "task_reward", "cost", "task_cost", "ended_by"}
#: names that mean nothing else in the package: never spelt in code outside the entries module
UNAMBIGUOUS = {"task_reward", "task_cost", "ended_by"}


def _code_strings(path: Path) -> tuple[list[tuple[int, str]], list[tuple[int, str]]]:
    """The string constants of a module outside docstrings, and its parameters' string defaults."""
    tree = ast.parse(path.read_text())
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            first = node.body[0] if node.body else None
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                docstrings.add(id(first.value))
    strings, defaults = [], []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
            strings.append((node.lineno, node.value))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for default in [*node.args.defaults, *node.args.kw_defaults]:
                if isinstance(default, ast.Constant) and isinstance(default.value, str):
                    defaults.append((default.lineno, default.value))
    return strings, defaults


def test_the_entry_names_are_spelt_in_the_names_module_only() -> None:
    """Outside the layers below the TorchRL wing (rewards and tasks know no entries: their "success" and "failure"
    are kinds of end conditions), no module spells an entry name as a default or a key; they import it."""
    package = Path(torchtasks.__file__).parent
    found = []
    for path in sorted(package.rglob("*.py")):
        relative = path.relative_to(package).as_posix()
        # names.py spells them; entries.py names the fields of a Transition, some of which share an entry's name
        if relative.startswith(("tasks/", "rewards/")) or relative in ("transforms/names.py", "transforms/entries.py"):
            continue
        strings, defaults = _code_strings(path)
        found += [f"{relative}:{line}: {value!r}" for line, value in strings if value in UNAMBIGUOUS]
        found += [f"{relative}:{line}: default {value!r}" for line, value in defaults if value in DEFAULT_NAMES]
    assert not found, found


def test_readers_default_to_the_transforms_names() -> None:
    transform = inspect.signature(TaskTransform).parameters
    stats = inspect.signature(episode_statistics).parameters
    for name in ("reward_key", "success_key", "failure_key", "terms_key", "cost_terms_key", "ended_by_key"):
        assert stats[name].default == transform[name].default, name
    assert inspect.signature(GoalCommand).parameters["success_key"].default == transform["success_key"].default
    assert inspect.signature(gated).parameters["metric"].default == transform["success_key"].default
