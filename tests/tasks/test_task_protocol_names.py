"""What crosses the wall between a task and its callers is named: ``Transition`` and ``Task.facts``.

``Task._transition`` (the function ``TaskTransform`` runs online, offline and compiled) returns a
``Transition`` named tuple whose fields are those of the public ``TaskOutput``, equal to it field by
field, also when compiled with ``fullgraph=True``. ``Task.facts`` names what the transform needs to know
about a tree; the expected facts of every case are written here by hand from the way the case is built.
Whether a tree pays a final reward follows the classes that define one (a wrapper's own combination of
final rewards is not one). The modules of ``torchtasks.tasks`` import downwards only: the protocol
(``protocol.py``) knows neither its wrappers nor any task built on it, and ``tasks.base`` is only the
old path, re-exporting.
"""

from __future__ import annotations

import ast
import dataclasses
import graphlib
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
from tensordict import TensorDictBase

import torchtasks.tasks
import torchtasks.tasks.base
from task_trees import CANNOT_SUCCEED, all_task_cases, assert_memory_equal, assert_same, class_cases, random_transitions
from torchtasks.rewards import ConstantReward, StateFunctionReward, VelocityReward
from torchtasks.spaces import EnvSpec
from torchtasks.tasks import (
    ConstrainedTask,
    Constraint,
    FinalRewardTask,
    GoallessTask,
    RewardGroupsTask,
    Task,
    TaskWrapper,
)
from torchtasks.tasks.output import TaskOutput
from torchtasks.tasks.transition import TaskFacts, Transition


def _constrained_cases() -> dict[str, Callable[[], Task]]:
    cases = class_cases()
    return {
        "constrained_final_time": lambda: ConstrainedTask(
            cases["final_state_time"](), {"effort": Constraint(VelocityReward(1.0, index=1), limit=1.0)}
        ),
        "constrained_ant": lambda: ConstrainedTask(
            cases["goalless_ant"](), {"first": StateFunctionReward(lambda s: s[..., 0], negate=False)}
        ),
    }


def _grouped_cases() -> dict[str, Callable[[], Task]]:
    cases = class_cases()
    return {
        "grouped_ant": lambda: RewardGroupsTask(
            cases["goalless_ant"](), {"run": {"forward": 1.0, "healthy": 1.0}, "save": {"ctrl": 2.0, "contact": 1.0}}
        ),
        "final_grouped": lambda: FinalRewardTask(
            RewardGroupsTask(cases["goalless_forward_velocity"](), {"all": {"step": 1.0, "final": 1.0}})
        ),
    }


CASES = {**all_task_cases(), **_constrained_cases(), **_grouped_cases()}

# the cases for which a fact holds, read off the builders in task_trees.py and above
HOLDS = {
    # a success condition where the tree's success needs it (task_trees.CANNOT_SUCCEED lists the cases without; of
    # the cases above, the Ant and walking ones have none)
    "can_succeed": (set(all_task_cases()) - CANNOT_SUCCEED) | {"constrained_final_time"},
    # every leaf fails out of its box (or on NaN); the one parallel case fails when all its sub-tasks do
    "can_fail": set(CASES),
    # rewards with named terms: forward velocity (forward, ctrl), Ant (forward, ctrl, healthy, contact), shaping
    "has_terms": {
        "goalless_forward_velocity",
        "goalless_ant",
        "final_state_goalless",
        "shaping_goal",
        "shaping_final",
        "shaping_walk",
        "constrained_ant",
        "grouped_ant",
        "final_grouped",
    },
    # final rewards with FinalRewardMode(time_dependent=True)
    "reads_remaining_steps": {
        "final_state_time",
        "final_positive_time",
        "nested_sequential_masked",
        "shaping_final",
        "constrained_final_time",
    },
    # a FinalRewardTask or BestStateFinalRewardTask somewhere in the tree
    "pays_final_reward": {
        "final_default",
        "final_state_time",
        "final_state_goalless",
        "final_negative_state",
        "final_positive_time",
        "best_state",
        "nested_parallel_sequential",
        "nested_sequential_masked",
        "shaping_final",
        "constrained_final_time",
        "final_grouped",
    },
    "has_costs": {"constrained_final_time", "constrained_ant"},
    "has_groups": {"grouped_ant", "final_grouped"},
    # Ant with terminate_when_unhealthy: two failures (out of bounds, unhealthy)
    "names_end_conditions": {"goalless_ant", "constrained_ant", "grouped_ant"},
}


def _arguments(task: Task) -> tuple:
    draws = random_transitions(task, torch.Generator().manual_seed(3), 1, 6)
    state, next_state = draws["states"][0], draws["states"][1]
    remaining = draws["remaining"][0] if task.uses_remaining_steps else task.no_remaining_steps
    memory = task.reset(state)
    return state, draws["actions"][0], next_state, memory, remaining, draws["terminated"][0], draws["truncated"][0]


def _assert_same_field(name: str, got: object, want: object, what: str) -> None:
    if isinstance(want, TensorDictBase):
        assert_memory_equal(got, want, f"{what}.{name}")
    elif isinstance(want, dict):
        assert isinstance(got, dict) and list(got) == list(want), f"{what}.{name}: {list(got)} != {list(want)}"
        for key in want:
            assert_same(got[key], want[key], f"{what}.{name}[{key!r}]")
    else:
        assert_same(got, want, f"{what}.{name}")


def test_the_transition_fields_are_the_task_output_fields() -> None:
    assert Transition._fields == tuple(field.name for field in dataclasses.fields(TaskOutput))
    assert TaskFacts._fields == (
        "can_succeed",
        "can_fail",
        "has_terms",
        "reads_remaining_steps",
        "pays_final_reward",
        "has_costs",
        "has_groups",
        "names_end_conditions",
    )


@pytest.mark.parametrize("case", sorted(CASES))
def test_transition_is_named_and_is_what_transition_returns(case: str) -> None:
    task = CASES[case]().double()
    state, action, next_state, memory, remaining, terminated, truncated = _arguments(task)
    values = task._transition(state, action, next_state, memory, remaining, terminated, truncated)
    out = task.transition(state, action, next_state, memory, remaining, terminated=terminated, truncated=truncated)
    assert type(values) is Transition
    for name in Transition._fields:
        _assert_same_field(name, getattr(values, name), getattr(out, name), case)
    assert bool(values.costs) == (case in HOLDS["has_costs"])
    assert bool(values.ended_by) == (case in HOLDS["names_end_conditions"])
    assert bool(values.groups) == (case in HOLDS["has_groups"])


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_facts_name_what_the_tree_is(case: str) -> None:
    task = CASES[case]()
    facts = task.facts
    assert type(facts) is TaskFacts
    assert facts._asdict() == {name: case in cases for name, cases in HOLDS.items()}
    assert task.facts is facts  # computed once


@pytest.mark.parametrize("case", ["goalless_ant", "shaping_final", "constrained_final_time", "grouped_ant"])
def test_the_compiled_transition_returns_the_named_tuple(case: str) -> None:
    torch._dynamo.reset()
    task = CASES[case]().double()
    arguments = _arguments(task)
    want = task._transition(*arguments)
    got = torch.compile(task._transition, fullgraph=True, backend="eager")(*arguments)
    assert type(got) is Transition
    for name in Transition._fields:
        _assert_same_field(name, getattr(got, name), getattr(want, name), f"compiled {case}")


class _PaysInWrapper(TaskWrapper):
    def _compute_final_reward(self, state, memory, remaining_steps, done, flags=None):
        return torch.where(done, 1.0, 0.0).to(state.dtype), memory


class _OwnFinalWrapper(TaskWrapper):
    def _final_reward(self, state, memory, remaining_steps, done, flags=None):
        return super()._final_reward(state, memory, remaining_steps, done, flags)


class _OwnFinalLeaf(GoallessTask):
    def _final_reward(self, state, memory, remaining_steps, done, flags=None):
        return torch.where(done, 2.0, 0.0).to(state.dtype), memory


def _leaf() -> GoallessTask:
    return GoallessTask(EnvSpec(2, 1), ConstantReward(1.0))


@pytest.mark.parametrize(
    ("build", "pays"),
    [
        (lambda: TaskWrapper(_leaf()), False),  # a wrapper's own combination pays nothing by itself
        (lambda: TaskWrapper(TaskWrapper(_leaf())), False),
        (lambda: _PaysInWrapper(_leaf()), True),
        (lambda: _OwnFinalWrapper(_leaf()), True),
        (lambda: TaskWrapper(FinalRewardTask(_leaf())), True),
        (lambda: _OwnFinalLeaf(EnvSpec(2, 1), ConstantReward(1.0)), True),
        (lambda: TaskWrapper(_OwnFinalLeaf(EnvSpec(2, 1), ConstantReward(1.0))), True),
    ],
)
def test_a_task_pays_a_final_reward_when_some_class_of_the_tree_defines_one(build: Callable[[], Task], pays: bool):
    task = build()
    assert task.pays_final_reward is pays and task.facts.pays_final_reward is pays


# ------------------------------------------------------------------------------ the layout of tasks/
TASKS_DIR = Path(torchtasks.tasks.__file__).parent
PACKAGE_DIR = TASKS_DIR.parent


def _torchtasks_imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("torchtasks"):
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name.startswith("torchtasks"))
    return found


def test_the_task_modules_import_downwards_without_a_circle() -> None:
    modules = {path.stem for path in TASKS_DIR.glob("*.py")} - {"__init__", "base"}  # base: the old path
    graph = {
        name: {
            module.rsplit(".", 1)[1]
            for module in _torchtasks_imports(TASKS_DIR / f"{name}.py")
            if module.startswith("torchtasks.tasks.")
        }
        for name in modules
    }
    order = list(graphlib.TopologicalSorter(graph).static_order())  # CycleError on a circle
    assert set(order) >= modules
    # the protocol knows its argument checks and what it returns, never a task built on it
    assert graph["protocol"] == {"_validation", "goals", "memory", "output", "transition"}
    assert graph["wrapper"] == {"memory", "protocol"}
    assert graph["_validation"] == {"memory"} and graph["transition"] == set()


def test_the_package_imports_the_tasks_from_their_modules_and_the_old_path_re_exports_them() -> None:
    users = sorted(
        str(path.relative_to(PACKAGE_DIR))
        for path in PACKAGE_DIR.rglob("*.py")
        if path != TASKS_DIR / "base.py" and "torchtasks.tasks.base" in _torchtasks_imports(path)
    )
    assert users == []
    for name in ("Task", "TaskWrapper", "ForwardingTask", "TaskOutput", "all_tasks"):
        assert getattr(torchtasks.tasks.base, name) is getattr(torchtasks.tasks, name), name
