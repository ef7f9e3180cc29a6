"""Bad input raises a clear error naming the argument; the fixed decisions behave as documented.

The first part feeds wrong shapes, dtypes, sizes, labels and types to the public API and checks
the exception type and that its message names what was wrong. The second part pins down the
torchtasks decisions of ``reference/pyrado-semantics.md`` §10 with small cases whose expected
values are computed by hand (written out next to each assertion).
"""

from __future__ import annotations

import functools
import math

import pytest
import torch

from task_trees import class_cases, full_spec, make_drive_data, memory_leaves, predefined_cases
from torchtasks import predefined
from torchtasks.rewards import (
    ConstantReward,
    CosineReward,
    ForwardVelocityReward,
    QuadraticErrorReward,
    StateFunctionReward,
)
from torchtasks.spaces import Box, EnvSpec
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
    TaskWrapper,
    proximity_succeeded,
)
from torchtasks.tasks.memory import where_memory

F64 = torch.float64


def _near(threshold: float, dims=None) -> functools.partial:
    return functools.partial(proximity_succeeded, threshold=threshold, dims=dims)


def _t(values, dtype=F64) -> torch.Tensor:
    return torch.tensor(values, dtype=dtype)


def _goal_task(spec: EnvSpec | None = None) -> DesiredStateTask:
    spec = full_spec() if spec is None else spec
    n, m = spec.state_size, spec.action_size
    return DesiredStateTask(spec, [0.0] * n, QuadraticErrorReward([1.0] * n, [1.0] * m), _near(1.0))


S = torch.zeros(3, 4, dtype=F64)
A = torch.zeros(3, 2, dtype=F64)


# ====================================================================================== bad input
def _step(task=None, state=S, action=A, memory=None, remaining=0):
    task = _goal_task() if task is None else task
    memory = task.reset(torch.zeros(3, 4, dtype=F64)) if memory is None else memory
    return task.step_reward(state, action, memory, remaining)


def _final(done, remaining=0, state=S):
    task = _goal_task()
    return task.final_reward(state, task.reset(S), remaining, done)


BAD_STEP_INPUTS = {
    # name: (call, exception, regex the message must match)
    "action batch differs from state batch": (
        lambda: _step(action=torch.zeros(2, 2, dtype=F64)),
        ValueError,
        r"state and action must have the same batch shape",
    ),
    "action of the wrong size": (lambda: _step(action=torch.zeros(3, 3, dtype=F64)), ValueError, r"action must have"),
    "state of the wrong trailing size": (
        lambda: _step(state=torch.zeros(3, 5, dtype=F64)),
        ValueError,
        r"state must have shape \[\*B, 4\]",
    ),
    "0-d state": (lambda: _step(state=torch.tensor(1.0)), ValueError, r"state must have shape"),
    "integer state": (lambda: _step(state=torch.zeros(3, 4, dtype=torch.long)), TypeError, r"state must be a float32"),
    "state not a tensor": (lambda: _step(state=[[0.0] * 4] * 3), TypeError, r"state must be a torch.Tensor"),
    "integer action": (lambda: _step(action=torch.zeros(3, 2, dtype=torch.long)), TypeError, r"action must be a float"),
    "init_state of the wrong size": (
        lambda: _goal_task().reset(torch.zeros(3, 3, dtype=F64)),
        ValueError,
        r"init_state must have shape",
    ),
    "remaining_steps of the wrong shape": (
        lambda: _step(remaining=torch.zeros(4, dtype=torch.long)),
        ValueError,
        r"remaining_steps must be broadcastable",
    ),
    "remaining_steps with an extra dim": (
        lambda: _step(remaining=torch.zeros(3, 2, dtype=torch.long)),
        ValueError,
        r"remaining_steps must be broadcastable",
    ),
    "float remaining_steps tensor": (
        lambda: _step(remaining=torch.zeros(3, dtype=F64)),
        TypeError,
        r"remaining_steps must be an integer tensor",
    ),
    "bool remaining_steps tensor": (
        lambda: _step(remaining=torch.zeros(3, dtype=torch.bool)),
        TypeError,
        r"remaining_steps must be an integer tensor",
    ),
    "Python float remaining_steps": (lambda: _step(remaining=2.5), TypeError, r"remaining_steps must be an int"),
    "Python bool remaining_steps": (lambda: _step(remaining=True), TypeError, r"remaining_steps .*bool"),
    "float remaining_steps in final_reward": (
        lambda: _final(torch.ones(3, dtype=torch.bool), remaining=torch.ones(3)),
        TypeError,
        r"remaining_steps must be an integer tensor",
    ),
    "done of the wrong shape": (lambda: _final(torch.ones(2, dtype=torch.bool)), ValueError, r"done must have shape"),
    "done with a trailing 1": (lambda: _final(torch.ones(3, 1, dtype=torch.bool)), ValueError, r"done must have shape"),
    "float done": (lambda: _final(torch.ones(3)), TypeError, r"done must be a bool tensor"),
    "done not a tensor": (lambda: _final([True] * 3), TypeError, r"done must be a bool tensor"),
    "memory of another batch size": (
        lambda: _step(state=torch.zeros(2, 4, dtype=F64), action=torch.zeros(2, 2, dtype=F64)),
        ValueError,
        r"memory has batch size \(3,\) but the state has batch shape \(2,\)",
    ),
    "memory not a TensorDict": (lambda: _step(memory={}), TypeError, r"memory must be the TensorDict"),
}


@pytest.mark.parametrize("case", sorted(BAD_STEP_INPUTS))
def test_bad_step_input_raises_a_clear_error(case):
    call, exception, match = BAD_STEP_INPUTS[case]
    with pytest.raises(exception, match=match):
        call()


@pytest.mark.parametrize("method", ["has_succeeded", "has_failed", "is_done"])
def test_flag_methods_validate_state_and_memory(method):
    task = _goal_task()
    memory = task.reset(S)
    with pytest.raises(ValueError, match=r"state must have shape"):
        getattr(task, method)(torch.zeros(3, 2, dtype=F64), memory)
    with pytest.raises(ValueError, match=r"memory has batch size"):
        getattr(task, method)(torch.zeros(5, 4, dtype=F64), memory)


def test_memory_of_a_two_dim_batch_must_match_exactly():
    task = _goal_task()
    memory = task.reset(torch.zeros(2, 3, 4, dtype=F64))
    with pytest.raises(ValueError, match=r"memory has batch size \(2, 3\) but the state has batch shape \(3, 2\)"):
        task.step_reward(torch.zeros(3, 2, 4, dtype=F64), torch.zeros(3, 2, 2, dtype=F64), memory)


def _spec(n: int = 4, m: int = 2) -> EnvSpec:
    return EnvSpec(n, m)


def _quadratic(n: int = 4, m: int | None = 2) -> QuadraticErrorReward:
    return QuadraticErrorReward([1.0] * n, None if m is None else [1.0] * m)


BAD_CONSTRUCTION = {
    "desired state of the wrong size": (
        lambda: DesiredStateTask(full_spec(), [0.0, 0.0, 0.0], _quadratic()),
        ValueError,
        r"state_des must have 4 entries",
    ),
    "desired state 2-D": (
        lambda: DesiredStateTask(full_spec(), [[0.0] * 4], _quadratic()),
        ValueError,
        r"state_des must be 0-D or 1-D",
    ),
    "desired state with NaN": (
        lambda: DesiredStateTask(full_spec(), [0.0, math.nan, 0.0, 0.0], _quadratic()),
        ValueError,
        r"state_des must not contain NaN",
    ),
    "spec not an EnvSpec": (lambda: DesiredStateTask(4, [0.0] * 4, _quadratic()), TypeError, r"spec must be"),
    "reward not a RewardFunction": (
        lambda: GoallessTask(_spec(), lambda s, a: s.sum(-1)),
        TypeError,
        r"reward must be a torchtasks RewardFunction",
    ),
    "success not callable": (
        lambda: DesiredStateTask(_spec(), [0.0] * 4, _quadratic(), success=0.5),
        TypeError,
        r"success must be callable",
    ),
    "optimization needs a StateFunctionReward": (
        lambda: OptimizationTask(_spec(), _quadratic()),
        TypeError,
        r"reward must be a StateFunctionReward",
    ),
    "condition not callable": (lambda: ConditionTask(_spec(), None, True), TypeError, r"condition must be callable"),
    "is_success not a bool": (
        lambda: ConditionTask(_spec(), lambda s: s[..., 0] > 0, 1),
        TypeError,
        r"is_success must be a bool",
    ),
    "desired space of another size": (
        lambda: DesiredSpaceTask(_spec(), Box([0.0], [1.0])),
        ValueError,
        r"space_des must have 4 entries",
    ),
    "desired space not a Box": (lambda: DesiredSpaceTask(_spec(), (0.0, 1.0)), TypeError, r"space_des must be"),
    "radially symmetric unknown label": (
        lambda: RadiallySymmetricDesiredStateTask(full_spec(), [0.0] * 4, _quadratic(), ["phi"]),
        ValueError,
        r"unknown label 'phi'",
    ),
    "radially symmetric duplicate index": (
        lambda: RadiallySymmetricDesiredStateTask(full_spec(), [0.0] * 4, _quadratic(), ["b", 1]),
        ValueError,
        r"duplicate entry",
    ),
    "radially symmetric modulation count": (
        lambda: RadiallySymmetricDesiredStateTask(full_spec(), [0.0] * 4, _quadratic(), [0, 1], [1.0, 2.0, 3.0]),
        ValueError,
        r"modulation must be one number or one per index \(2\)",
    ),
    "radially symmetric modulation sign": (
        lambda: RadiallySymmetricDesiredStateTask(full_spec(), [0.0] * 4, _quadratic(), [0], -1.0),
        ValueError,
        r"modulation must be finite and positive",
    ),
    "flipping with a 2-D state": (
        lambda: FlippingTask(_spec(2, 1), math.pi / 2, CosineReward(0)),
        ValueError,
        r"FlippingTask needs a one-dimensional state .* size 2",
    ),
    "flipping angle_delta": (
        lambda: FlippingTask(_spec(1, 1), 0.0, CosineReward(0)),
        ValueError,
        r"angle_delta must be positive",
    ),
    "flipping angle_tol": (
        lambda: FlippingTask(_spec(1, 1), 1.0, CosineReward(0), angle_tol=-0.1),
        ValueError,
        r"angle_tol must be non-negative",
    ),
    "flipping stateful reward": (
        lambda: FlippingTask(_spec(1, 1), 1.0, ForwardVelocityReward(0.1, 0)),
        TypeError,
        r"FlippingTask needs a stateless reward",
    ),
    "final reward: always_positive and always_negative": (
        lambda: FinalRewardTask(_goal_task(), FinalRewardMode(always_positive=True, always_negative=True)),
        ValueError,
        r"unsupported combination of FinalRewardMode",
    ),
    "final reward: state, time and always_positive": (
        lambda: FinalRewardTask(
            _goal_task(), FinalRewardMode(state_dependent=True, time_dependent=True, always_positive=True)
        ),
        ValueError,
        r"unsupported combination of FinalRewardMode",
    ),
    "final reward: state, time and always_negative": (
        lambda: FinalRewardTask(
            _goal_task(), FinalRewardMode(state_dependent=True, time_dependent=True, always_negative=True)
        ),
        ValueError,
        r"unsupported combination of FinalRewardMode",
    ),
    "final reward: user_input": (
        lambda: FinalRewardTask(_goal_task(), FinalRewardMode(user_input=True)),
        ValueError,
        r"user_input",
    ),
    "final reward: user_input with another flag": (
        lambda: FinalRewardTask(_goal_task(), FinalRewardMode(always_positive=True, user_input=True)),
        ValueError,
        r"user_input",
    ),
    "final reward: mode not a FinalRewardMode": (
        lambda: FinalRewardTask(_goal_task(), (False,) * 5),
        TypeError,
        r"mode must be a FinalRewardMode",
    ),
    "final reward: NaN factor": (
        lambda: FinalRewardTask(_goal_task(), factor=math.nan),
        ValueError,
        r"factor must be finite",
    ),
    "best state: infinite factor": (
        lambda: BestStateFinalRewardTask(_goal_task(), math.inf),
        ValueError,
        r"factor must be finite",
    ),
    "masked: unknown state label": (
        lambda: MaskedTask(full_spec(), _goal_task(_spec(2, 2)), ["a", "zz"]),
        ValueError,
        r"unknown label 'zz'",
    ),
    "masked: unknown action label": (
        lambda: MaskedTask(full_spec(), _goal_task(_spec(4, 1)), None, ["w"]),
        ValueError,
        r"unknown label 'w'",
    ),
    "masked: duplicate label": (
        lambda: MaskedTask(full_spec(), _goal_task(_spec(2, 2)), ["b", "b"]),
        ValueError,
        r"duplicate entry 'b'",
    ),
    "masked: label and int of the same entry": (
        lambda: MaskedTask(full_spec(), _goal_task(_spec(2, 2)), ["a", 0]),
        ValueError,
        r"duplicate entry",
    ),
    "masked: duplicate action index": (
        lambda: MaskedTask(full_spec(), _goal_task(_spec(4, 2)), None, [1, 1]),
        ValueError,
        r"duplicate entry 1",
    ),
    "masked: index out of range": (
        lambda: MaskedTask(full_spec(), _goal_task(_spec(1, 2)), [4]),
        ValueError,
        r"index 4 is out of range",
    ),
    "masked: wrapped task of another size": (
        lambda: MaskedTask(full_spec(), _goal_task(_spec(3, 2)), ["a", "b"]),
        ValueError,
        r"wrapped task reads 3 state entries but 2 are selected",
    ),
    "masked: non-Task": (
        lambda: MaskedTask(full_spec(), _quadratic(), ["a"]),
        TypeError,
        r"task must be a torchtasks Task",
    ),
    "final reward: non-Task": (lambda: FinalRewardTask(_quadratic()), TypeError, r"task must be a torchtasks Task"),
    "best state: non-Task": (
        lambda: BestStateFinalRewardTask(None, 1.0),
        TypeError,
        r"task must be a torchtasks Task",
    ),
    "task wrapper: non-Task": (lambda: TaskWrapper(full_spec()), TypeError, r"task must be a torchtasks Task"),
    "parallel: sub-tasks of different state sizes": (
        lambda: ParallelTasks([_goal_task(), _goal_task(_spec(3, 2))]),
        ValueError,
        r"same state and action sizes.*tasks\[1\] reads \(3, 2\)",
    ),
    "parallel: sub-tasks of different action sizes": (
        lambda: ParallelTasks([_goal_task(), _goal_task(_spec(4, 1))]),
        ValueError,
        r"same state and action sizes.*tasks\[1\] reads \(4, 1\)",
    ),
    "sequential: sub-tasks of different sizes": (
        lambda: SequentialTasks([_goal_task(), _goal_task(_spec(5, 2))]),
        ValueError,
        r"same state and action sizes",
    ),
    "parallel: empty": (lambda: ParallelTasks([]), TypeError, r"tasks must be a non-empty sequence"),
    "parallel: a single task, not a list": (
        lambda: ParallelTasks(_goal_task()),
        TypeError,
        r"tasks must be a non-empty sequence",
    ),
    "parallel: non-Task entry": (
        lambda: ParallelTasks([_goal_task(), "goal"]),
        TypeError,
        r"tasks\[1\] must be a torchtasks Task",
    ),
    "parallel: non-bool flag": (
        lambda: ParallelTasks([_goal_task()], allow_failures=1),
        TypeError,
        r"allow_failures must be a bool",
    ),
    "sequential: start_index too large": (
        lambda: SequentialTasks([_goal_task(), _goal_task()], start_index=2),
        ValueError,
        r"start_index must lie in \[0, 1\], got 2",
    ),
    "sequential: negative start_index": (
        lambda: SequentialTasks([_goal_task(), _goal_task()], start_index=-1),
        ValueError,
        r"start_index must lie in \[0, 1\], got -1",
    ),
    "sequential: float start_index": (
        lambda: SequentialTasks([_goal_task(), _goal_task()], start_index=1.0),
        TypeError,
        r"start_index must be an int",
    ),
    "sequential: non-bool hold": (
        lambda: SequentialTasks([_goal_task()], hold_reward_when_done="yes"),
        TypeError,
        r"hold_reward_when_done must be a bool",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_CONSTRUCTION))
def test_bad_construction_raises_a_clear_error(case):
    call, exception, match = BAD_CONSTRUCTION[case]
    with pytest.raises(exception, match=match):
        call()


def _sequence() -> SequentialTasks:
    return SequentialTasks([_goal_task(), _goal_task(), _goal_task()])


BAD_RESET = {
    "unknown override": (
        lambda: _goal_task().reset(S, goal=torch.zeros(3, 4)),
        TypeError,
        r"unknown reset override\(s\) \['goal'\]",
    ),
    "override of another task class": (
        lambda: _goal_task().reset(S, start_index=1),
        TypeError,
        r"unknown reset override\(s\) \['start_index'\]",
    ),
    "unknown override in a tree": (
        lambda: FinalRewardTask(MaskedTask(full_spec(), _goal_task(_spec(1, 2)), ["c"])).reset(S, start_idx=1),
        TypeError,
        r"unknown reset override\(s\) \['start_idx'\]",
    ),
    "state_des override of the wrong size": (
        lambda: _goal_task().reset(S, state_des=torch.zeros(3, 3)),
        ValueError,
        r"state_des override must have shape \[4\] or \[3, 4\]",
    ),
    "state_des override of the wrong batch": (
        lambda: _goal_task().reset(S, state_des=torch.zeros(2, 4)),
        ValueError,
        r"state_des override must have shape",
    ),
    "state_des override in a masked tree": (
        lambda: MaskedTask(full_spec(), _goal_task(_spec(2, 2)), ["c", "a"]).reset(S, state_des=torch.zeros(3, 4)),
        ValueError,
        r"state_des override must have shape \[2\] or \[3, 2\]",
    ),
    "bool state_des override": (
        lambda: MaskedTask(full_spec(), _goal_task(_spec(2, 2)), ["c", "a"]).reset(S, state_des=torch.ones(2).bool()),
        TypeError,
        r"state_des override must be a float32 or float64 tensor",
    ),
    "complex state_des override": (
        lambda: MaskedTask(full_spec(), _goal_task(_spec(2, 2)), ["c", "a"]).reset(S, state_des=[1 + 2j, 0.0]),
        TypeError,
        r"state_des override must hold real numbers, got complex values",
    ),
    "string state_des override": (
        lambda: MaskedTask(full_spec(), _goal_task(_spec(2, 2)), ["c", "a"]).reset(S, state_des="far"),
        TypeError,
        r"state_des override must be a number or an array of numbers, got 'far'",
    ),
    "start_index override too large (int)": (
        lambda: _sequence().reset(S, start_index=3),
        ValueError,
        r"start_index must lie in \[0, 2\], got 3",
    ),
    "start_index override out of range (tensor)": (
        lambda: _sequence().reset(S, start_index=torch.tensor([0, 3, 1])),
        ValueError,
        r"start_index override must lie in \[0, 2\]",
    ),
    "negative start_index override (tensor)": (
        lambda: _sequence().reset(S, start_index=torch.tensor([0, -1, 1])),
        ValueError,
        r"start_index override must lie in \[0, 2\]",
    ),
    "float start_index override": (
        lambda: _sequence().reset(S, start_index=torch.tensor([0.0, 1.0, 1.0])),
        ValueError,
        r"start_index override must be an int or an integer tensor",
    ),
    "start_index override of the wrong batch": (
        lambda: _sequence().reset(S, start_index=torch.tensor([0, 1])),
        ValueError,
        r"start_index override must be an int or an integer tensor of shape \(3,\)",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_RESET))
def test_bad_reset_raises_a_clear_error(case):
    call, exception, match = BAD_RESET[case]
    with pytest.raises(exception, match=match):
        call()


def _flag_task(kind: str, fn):
    spec = _spec()
    if kind == "success":
        return DesiredStateTask(spec, [0.0] * 4, _quadratic(), success=fn)
    return ConditionTask(spec, fn, is_success=kind == "condition_success")


@pytest.mark.parametrize("kind", ["success", "condition_success", "condition_failure"])
@pytest.mark.parametrize(
    "fn, got",
    [
        (lambda x: torch.zeros(x.shape, dtype=torch.bool), r"got torch.bool \(3, 4\)"),  # per entry, not per env
        (lambda x: x.norm(dim=-1), r"got torch.float64 \(3,\)"),  # not a bool
        (lambda x: (x.sum(-1) > 0).unsqueeze(-1), r"got torch.bool \(3, 1\)"),  # trailing singleton
        (lambda x: bool((x > 0).any()), r"got bool"),  # a Python bool
    ],
    ids=["per_entry", "float", "trailing_one", "python_bool"],
)
def test_user_functions_must_return_bool_per_env(kind, fn, got):
    task = _flag_task(kind, fn)
    name = "success" if kind == "success" else "condition"
    memory = task.reset(S)
    for method in ("is_done", "has_succeeded" if kind != "condition_failure" else "has_failed"):
        with pytest.raises(ValueError, match=rf"{name} must return a bool tensor of shape \(3,\), {got}"):
            getattr(task, method)(S, memory)


PREDEFINED_SPEC = EnvSpec(Box.unbounded(4, labels=["x", "z", "phi", "GD_DS0"]), 2)

BAD_PREDEFINED = {
    "lifting: unknown label": (
        lambda: predefined.lifting_task(PREDEFINED_SPEC, ["height"], 0.5),
        ValueError,
        r"unknown label 'height'",
    ),
    "lifting: duplicate label": (
        lambda: predefined.lifting_task(PREDEFINED_SPEC, ["z", "z"], [0.5, 0.5]),
        ValueError,
        r"duplicate entry 'z'",
    ),
    "home position: label and int of the same entry": (
        lambda: predefined.home_position_task(PREDEFINED_SPEC, ["x", 0], [0.0, 0.0]),
        ValueError,
        r"duplicate entry",
    ),
    "home position: goal of the wrong size": (
        lambda: predefined.home_position_task(PREDEFINED_SPEC, ["x", "z"], [0.0]),
        ValueError,
        r"state_des must have 2 entries",
    ),
    "force min: unknown label": (
        lambda: predefined.force_min_task(PREDEFINED_SPEC, ["x", "f"], [1.0, 1.0]),
        ValueError,
        r"unknown label 'f'",
    ),
    "force min: no labels": (
        lambda: predefined.force_min_task(PREDEFINED_SPEC, [], [1.0]),
        ValueError,
        r"state_labels must name at least one",
    ),
    "flipping: unknown label": (
        lambda: predefined.flipping_task(PREDEFINED_SPEC, ["theta"]),
        ValueError,
        r"unknown label 'theta'",
    ),
    "flipping: two labels": (
        lambda: predefined.flipping_task(PREDEFINED_SPEC, ["x", "phi"]),
        ValueError,
        r"one-dimensional state",
    ),
    "collision: no CollCost entry": (
        lambda: predefined.collision_task(PREDEFINED_SPEC, 1.0),
        ValueError,
        r"unknown label 'CollCost'",
    ),
    "collision: negative factor": (
        lambda: predefined.collision_task(EnvSpec(Box.unbounded(1, labels=["CollCost"]), 1), -1.0),
        ValueError,
        r"factor must be non-negative",
    ),
    "task-space discrepancy: no entry": (
        lambda: predefined.task_space_discrepancy_task(PREDEFINED_SPEC, _quadratic(1, None)),
        ValueError,
        r"DiscrepTS",
    ),
    "goal distance: unknown goal": (
        lambda: predefined.goal_distance_task(PREDEFINED_SPEC, 1, _quadratic(1, None)),
        ValueError,
        r"unknown label 'GD_DS1'",
    ),
    "goal distance velocity: missing rate entry": (
        lambda: predefined.goal_distance_velocity_task(PREDEFINED_SPEC, 0, _quadratic(2, None)),
        ValueError,
        r"unknown label 'GD_DS0d'",
    ),
    "lifting: a height that is not a number": (
        lambda: predefined.lifting_task(EnvSpec(Box.unbounded(2, labels=["x", "z"]), 1), ["z"], des_height="x"),
        TypeError,
        r"des_height must be a number or an array of numbers, got 'x'",
    ),
    "home position: a bool goal": (
        lambda: predefined.home_position_task(EnvSpec(Box.unbounded(2, labels=["x", "z"]), 1), ["x"], [True]),
        TypeError,
        r"state_des must hold real numbers, got bool values",
    ),
    "goal distance: non-positive threshold": (
        lambda: predefined.goal_distance_task(PREDEFINED_SPEC, 0, _quadratic(1, None), success_threshold=0.0),
        ValueError,
        r"success_threshold must be positive",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_PREDEFINED))
def test_bad_predefined_arguments_raise_a_clear_error(case):
    call, exception, match = BAD_PREDEFINED[case]
    with pytest.raises(exception, match=match):
        call()


def test_remaining_steps_may_be_any_shape_broadcastable_to_the_batch():
    task = FinalRewardTask(_goal_task(), FinalRewardMode(time_dependent=True))
    state = torch.full((2, 3, 4), 5.0, dtype=F64)  # outside the box: every env failed, final = -remaining
    memory = task.reset(state)
    done = torch.ones(2, 3, dtype=torch.bool)
    full = torch.tensor([[4, 4, 4], [7, 7, 7]])
    expected, _ = task.final_reward(state, memory, full, done)
    for remaining in (torch.tensor([[4], [7]]), full[:, :1]):
        got, _ = task.final_reward(state, memory, remaining, done)
        torch.testing.assert_close(got, expected)
    flat_state = torch.zeros(3, 4, dtype=F64)
    got, _ = task.step_reward(flat_state, torch.zeros(3, 2, dtype=F64), task.reset(flat_state), torch.tensor([5]))
    assert got.shape == (3,)


# ====================================================================================== decisions (§10)
def _box1(low: float = -1.0, high: float = 1.0) -> EnvSpec:
    return EnvSpec(Box([low], [high]), 1)


def test_final_reward_is_paid_exactly_once_and_only_where_done():
    # success: |0 - s| < 0.1; failure: s outside [-1, 1]; k = |-10| = 10
    inner = DesiredStateTask(_box1(), [0.0], ConstantReward(-1.0), _near(0.1))
    task = FinalRewardTask(inner, FinalRewardMode(), factor=-10.0)
    memory = task.reset(torch.zeros(4, 1, dtype=F64))
    calls = [
        # states per env,              done per env,              expected final reward
        ([0.0, 0.5, 2.0, 0.5], [True, False, True, False], [10.0, 0.0, -10.0, 0.0]),  # success / - / failure / -
        ([0.0, 0.05, 2.0, 0.0], [True, True, True, False], [0.0, 10.0, 0.0, 0.0]),  # env3 succeeds but is not done
        ([0.0, 0.0, 2.0, 2.0], [True, True, True, True], [0.0, 0.0, 0.0, -10.0]),  # env3 ends now, by failure
        ([0.0, 0.0, 0.0, 0.0], [True, True, True, True], [0.0, 0.0, 0.0, 0.0]),  # every env has been paid
    ]
    for states, done, expected in calls:
        value, memory = task.final_reward(_t(states).unsqueeze(-1), memory, 0, torch.tensor(done))
        assert torch.equal(value, _t(expected)), (states, value)
    assert memory["paid"].all()
    # a partial reset re-arms only the reset envs: env1 pays +10 again, env0 (not reset) pays nothing
    memory = where_memory(torch.tensor([False, True, False, False]), task.reset(torch.zeros(4, 1, dtype=F64)), memory)
    value, memory = task.final_reward(torch.zeros(4, 1, dtype=F64), memory, 0, torch.ones(4, dtype=torch.bool))
    assert torch.equal(value, _t([0.0, 10.0, 0.0, 0.0]))


def test_final_reward_failure_wins_over_success():
    # desired state 3 is outside [-1, 1]: at s = 3 the task has both succeeded and failed
    task = FinalRewardTask(DesiredStateTask(_box1(), [3.0], ConstantReward(0.0), _near(0.5)), factor=7.0)
    state = _t([[3.0]])
    memory = task.reset(state)
    assert task.has_succeeded(state, memory).item() and task.has_failed(state, memory).item()
    value, _ = task.final_reward(state, memory, 0, torch.tensor([True]))
    assert torch.equal(value, _t([-7.0]))


@pytest.mark.parametrize(
    "flags, expected",
    [
        # envs: success (r_s = 0.5, rem 3), failure (r_s = 2, rem 5), neither (r_s = 2, rem 7); k = 4
        ({}, [4.0, -4.0, 0.0]),
        ({"always_positive": True}, [4.0, 0.0, 0.0]),
        ({"always_negative": True}, [0.0, -4.0, 0.0]),
        ({"always_positive": True, "state_dependent": True}, [2.0, 0.0, 0.0]),
        ({"always_negative": True, "state_dependent": True}, [0.0, -8.0, 0.0]),
        ({"state_dependent": True}, [2.0, -8.0, 0.0]),
        ({"state_dependent": True, "time_dependent": True}, [1.5, -10.0, 0.0]),
        ({"time_dependent": True}, [3.0, -5.0, 0.0]),
        ({"always_positive": True, "time_dependent": True}, [3.0, 0.0, 0.0]),
        ({"always_negative": True, "time_dependent": True}, [0.0, -5.0, 0.0]),
    ],
    ids=lambda v: ",".join(k for k in v) or "none" if isinstance(v, dict) else None,
)
def test_final_reward_modes_hand_computed(flags, expected):
    # step reward = -2·(0.5 - s)², r_s = |step reward| with a zero action; success: |0.5 - s| < 0.6
    # s = 0.0: success, r_s = 2·0.25 = 0.5; s = 1.5: outside [-1, 1], r_s = 2·1 = 2; s = -0.5: neither, r_s = 2
    inner = DesiredStateTask(_box1(), [0.5], QuadraticErrorReward([2.0], [1.0]), _near(0.6))
    task = FinalRewardTask(inner, FinalRewardMode(**flags), factor=-4.0)
    state = _t([[0.0], [1.5], [-0.5]])
    memory = task.reset(state)
    value, memory = task.final_reward(state, memory, torch.tensor([3, 5, 7]), torch.ones(3, dtype=torch.bool))
    assert torch.equal(value, _t(expected))


def test_state_dependent_final_reward_does_not_change_memory():
    # v = (x - x_last)/0.5, ctrl = -0.25·Σa²; state box [-2, 2]
    inner = GoallessTask(EnvSpec(Box([-2.0], [2.0]), 1), ForwardVelocityReward(0.5, 0, 1.0, 0.25))
    task = FinalRewardTask(inner, FinalRewardMode(state_dependent=True), factor=2.0)
    memory = task.reset(_t([[1.0], [1.0]]))
    reward, memory = task.step_reward(_t([[2.0], [1.5]]), _t([[1.0], [2.0]]), memory)
    assert torch.equal(reward, _t([1.75, 0.0]))  # (2-1)/0.5 - 0.25 ; (1.5-1)/0.5 - 0.25·4
    assert torch.equal(memory["wrapped", "reward", "x_last"], _t([2.0, 1.5]))
    before = memory.clone()
    # env0: x = 3 leaves the box: failure, -k·|(3-2)/0.5| = -4; env1: neither, 0
    final, memory = task.final_reward(_t([[3.0], [1.0]]), memory, 0, torch.tensor([True, True]))
    assert torch.equal(final, _t([-4.0, 0.0]))
    assert torch.equal(memory["wrapped", "reward", "x_last"], _t([2.0, 1.5]))  # not advanced to [3, 1]
    assert torch.equal(memory["wrapped"]["reward"]["x_last"], before["wrapped"]["reward"]["x_last"])
    reward, _ = task.step_reward(_t([[2.5], [2.0]]), torch.zeros(2, 1, dtype=F64), memory)
    assert torch.equal(reward, _t([1.0, 1.0]))  # (2.5-2)/0.5 ; (2-1.5)/0.5


def test_best_state_keeps_minus_inf_until_a_step_and_ignores_nan():
    inner = OptimizationTask(EnvSpec(1, 1), StateFunctionReward(lambda s: s[..., 0], negate=False))  # reward = s
    task = BestStateFinalRewardTask(inner, factor=2.0)
    memory = task.reset(torch.zeros(3, 1, dtype=F64))
    assert torch.equal(memory["best"], _t([-math.inf] * 3))
    # env0 ends before any step: no best state, so it pays 0 (Pyrado paid -inf·2; no reward is infinite here)
    value, memory = task.final_reward(torch.zeros(3, 1, dtype=F64), memory, 0, torch.tensor([True, False, False]))
    assert torch.equal(value, _t([0.0, 0.0, 0.0]))
    nan = math.nan
    # env1 sees rewards 1, NaN, 0.5 -> best 1; env2 sees NaN, -3, -4 -> best stays -inf after NaN, then -3
    expected_best = [[-math.inf, 1.0, -math.inf], [-math.inf, 1.0, -3.0], [-math.inf, 1.0, -3.0]]
    for states, best in zip(
        ([[0.0], [1.0], [nan]], [[0.0], [nan], [-3.0]], [[0.0], [0.5], [-4.0]]), expected_best, strict=True
    ):
        state = _t(states)
        _, memory = task.step_reward(state, torch.zeros(3, 1, dtype=F64), memory)
        assert torch.equal(memory["best"][1:], _t(best[1:])), memory["best"]
    value, _ = task.final_reward(torch.zeros(3, 1, dtype=F64), memory, 0, torch.tensor([False, True, True]))
    assert torch.equal(value, _t([0.0, 2.0, -6.0]))


def _goals_1d(*goals: float, reward: float = -1.0) -> list[DesiredStateTask]:
    return [DesiredStateTask(EnvSpec(1, 1), [g], ConstantReward(reward), _near(0.1)) for g in goals]


def test_sequential_reset_returns_to_start_index():
    task = SequentialTasks(_goals_1d(0.0, 1.0, 2.0), start_index=1)
    zeros = torch.zeros(2, 1, dtype=F64)
    first = task.reset(zeros)
    assert torch.equal(first["index"], torch.tensor([1, 1]))
    assert torch.equal(first["succeeded"], torch.tensor([[True, False, False]] * 2))
    # env0 reaches goal 1 (current) and moves to 2; env1 is far from every goal; the current sub-task pays -1
    reward, memory = task.step_reward(_t([[1.0], [5.0]]), torch.zeros(2, 1, dtype=F64), first)
    assert torch.equal(reward, _t([-1.0, -1.0]))
    assert torch.equal(memory["index"], torch.tensor([2, 1]))
    # env0 reaches goal 2, the last one: the index wraps to 0 and every sub-task has succeeded
    _, memory = task.step_reward(_t([[2.0], [5.0]]), torch.zeros(2, 1, dtype=F64), memory)
    assert torch.equal(memory["index"], torch.tensor([0, 1]))
    assert torch.equal(task.has_succeeded(zeros, memory), torch.tensor([True, False]))
    # a (partial) reset goes back to start_index 1, not to 0 (Pyrado forgot start_idx)
    again = where_memory(torch.tensor([True, False]), task.reset(zeros), memory)
    assert torch.equal(again["index"], torch.tensor([1, 1]))
    assert torch.equal(again["succeeded"], torch.tensor([[True, False, False], [True, False, False]]))
    # per-env override (Pyrado got stuck here: idx stayed 0 with task 0 already checked off)
    override = task.reset(zeros, start_index=torch.tensor([0, 2]))
    assert torch.equal(override["index"], torch.tensor([0, 2]))
    assert torch.equal(override["succeeded"], torch.tensor([[False, False, False], [True, True, False]]))
    reward, override = task.step_reward(_t([[0.0], [2.0]]), torch.zeros(2, 1, dtype=F64), override)
    assert torch.equal(override["index"], torch.tensor([1, 0]))  # both advanced: not stuck
    assert torch.equal(task.reset(zeros, start_index=2)["index"], torch.tensor([2, 2]))


def test_masked_task_selects_in_the_order_given():
    spec = EnvSpec(Box.unbounded(3, labels=["x", "y", "z"]), Box.unbounded(2, labels=["u", "v"]))
    inner = DesiredStateTask(EnvSpec(2, 1), [1.0, 0.0], QuadraticErrorReward([1.0, 10.0], [100.0]))
    state = _t([[2.0, 7.0, 3.0]])
    action = _t([[0.5, 0.25]])
    # the inner task sees [z, x] = [3, 2]: error [1-3, 0-2] -> 1·4 + 10·4 = 44; action v = 0.25 -> 100·0.0625
    # (Pyrado's boolean mask gave [x, z] = [2, 3]: 1·1 + 10·9 = 91)
    for state_indices, action_indices in ((["z", "x"], ["v"]), ([2, 0], [1]), (["z", 0], [-1])):
        task = MaskedTask(spec, inner, state_indices, action_indices)
        reward, _ = task.step_reward(state, action, task.reset(state))
        assert torch.equal(reward, _t([-50.25])), (state_indices, reward)


def test_final_rewards_inside_a_masked_task_are_paid():
    spec = EnvSpec(Box.unbounded(2, labels=["x", "y"]), 1)
    inner = FinalRewardTask(DesiredStateTask(EnvSpec(1, 1), [0.0], ConstantReward(0.0), _near(0.1)), factor=1.0)
    task = FinalRewardTask(MaskedTask(spec, inner, ["y"]), factor=10.0)
    state = _t([[5.0, 0.0], [5.0, 3.0]])  # env0: y at its goal (success); env1: neither
    memory = task.reset(state)
    value, _ = task.final_reward(state, memory, 0, torch.tensor([True, True]))
    assert torch.equal(value, _t([11.0, 0.0]))  # outer 10 + inner 1 (Pyrado paid only 10)


def test_flipping_at_angle_delta_pi_works_per_env():
    task = FlippingTask(EnvSpec(1, 1), math.pi, CosineReward(0), angle_tol=0.1)
    memory = task.reset(torch.zeros(3, 1, dtype=F64))
    zeros = torch.zeros(3, 1, dtype=F64)
    # targets 0 ± π coincide (mod 2π). env0 at π-0.05 and env2 at -π+0.02 flip; env1 at 0 is π away from both
    reward, memory = task.step_reward(_t([[math.pi - 0.05], [0.0], [-math.pi + 0.02]]), zeros, memory)
    expected = _t([math.cos(0.05), -1.0, math.cos(0.02)])
    torch.testing.assert_close(reward, expected, rtol=0, atol=1e-12)
    torch.testing.assert_close(memory["held"], _t([math.cos(0.05), 0.0, math.cos(0.02)]), rtol=0, atol=1e-12)
    torch.testing.assert_close(torch.cos(memory["last_angle"]), _t([-1.0, 1.0, -1.0]), rtol=0, atol=1e-12)
    # second flip back to 0 (mod 2π) for env0 (error 0) and env2 (error -0.03); env1 now flips at π
    reward, memory = task.step_reward(_t([[0.0], [math.pi], [0.03]]), zeros, memory)
    expected = _t([math.cos(0.05) + 1.0, 1.0, math.cos(0.02) + math.cos(0.03)])
    torch.testing.assert_close(reward, expected, rtol=0, atol=1e-12)


def test_flipping_uses_the_target_with_the_smaller_wrapped_error():
    task = FlippingTask(EnvSpec(1, 1), math.pi / 2, CosineReward(0), angle_tol=0.01)
    memory = task.reset(torch.zeros(2, 1, dtype=F64))
    # s = 1.2: errors to +π/2 and -π/2 are 0.3708 and wrap(-π/2-1.2) = -2.7708: +π/2 is closer.
    # s = -1.2: -π/2 is closer (error -0.3708). Pyrado's signed minimum picked -2.7708 for s = 1.2.
    reward, _ = task.step_reward(_t([[1.2], [-1.2]]), torch.zeros(2, 1, dtype=F64), memory)
    torch.testing.assert_close(reward, _t([math.cos(math.pi / 2 - 1.2)] * 2), rtol=0, atol=1e-12)


def test_flipping_not_endless_succeeds_when_the_next_state_reaches_a_target():
    task = FlippingTask(EnvSpec(1, 1), math.pi / 2, CosineReward(0), angle_tol=0.1, endless=False)
    memory = task.reset(torch.zeros(2, 1, dtype=F64))
    next_state = _t([[math.pi / 2], [0.5]])  # env0 reached the +π/2 target, env1 did not
    _, memory = task.step_reward(next_state, torch.zeros(2, 1, dtype=F64), memory)  # reward_on="next"
    assert torch.equal(task.has_succeeded(next_state, memory), torch.tensor([True, False]))


def test_radially_symmetric_wraps_only_the_listed_indices():
    reward = QuadraticErrorReward([1.0, 1.0, 1.0], None)
    task = RadiallySymmetricDesiredStateTask(EnvSpec(3, 1), [0.0, 0.0, 0.0], reward, indices=[1])
    state = _t([[4.0, 4.0, 0.5]])
    memory = task.reset(state)
    # error [-4, -4, -0.5]; only index 1 wraps into [-π, π): -4 + 2π. Index 0 stays -4 (Pyrado folded it).
    wrapped = 2 * math.pi - 4.0
    torch.testing.assert_close(task.state_error(state, memory), _t([[-4.0, wrapped, -0.5]]), rtol=0, atol=1e-15)
    value, _ = task.step_reward(state, torch.zeros(1, 1, dtype=F64), memory)
    torch.testing.assert_close(value, _t([-(16.0 + wrapped**2 + 0.25)]), rtol=0, atol=1e-12)


def test_radially_symmetric_per_index_modulation_boundary_and_success():
    reward = QuadraticErrorReward([1.0, 1.0, 1.0], None)
    near = _near(0.5, dims=[1])
    task = RadiallySymmetricDesiredStateTask(EnvSpec(3, 1), [0.0, 0.0, 0.0], reward, [1, 2], [2 * math.pi, 3.0], near)
    # env0: index 1 error -π -> stays -π ([-m/2, m/2)); index 2 error 2 -> 2 - 3 = -1
    # env1: index 1 error π -> -π (the upper end maps to the lower); env2: error -(2π - 0.1) -> 0.1
    state = _t([[0.0, math.pi, -2.0], [0.0, -math.pi, 0.0], [0.0, 2 * math.pi - 0.1, 0.0]])
    memory = task.reset(state)
    error = task.state_error(state, memory)
    assert torch.equal(error[:2, 1], _t([-math.pi, -math.pi]))
    assert torch.equal(error[0, 2], _t(-1.0))
    torch.testing.assert_close(error[2, 1], _t(0.1), rtol=0, atol=1e-14)
    # success sees the wrapped error (Pyrado: the unwrapped one, |2π - 0.1| > 0.5)
    assert torch.equal(task.has_succeeded(state, memory), torch.tensor([False, False, True]))


def test_desired_space_default_reward_is_zero_and_any_reward_is_accepted():
    space = Box([0.0, 0.0], [1.0, 1.0])
    state = _t([[0.5, 1.0], [0.5, 1.5]])
    default = DesiredSpaceTask(EnvSpec(2, 1), space)
    reward, memory = default.step_reward(state, torch.zeros(2, 1, dtype=F64), default.reset(state))
    assert torch.equal(reward, _t([0.0, 0.0]))
    assert torch.equal(default.has_succeeded(state, memory), torch.tensor([True, False]))  # inclusive bounds
    quadratic = DesiredSpaceTask(EnvSpec(2, 1), space, QuadraticErrorReward([1.0, 2.0], [4.0]))
    reward, _ = quadratic.step_reward(state, _t([[0.5], [0.0]]), quadratic.reset(state))
    assert torch.equal(reward, _t([-(0.25 + 2.0 + 1.0), -(0.25 + 4.5)]))  # raw state and action


def test_goal_distance_goal_has_the_selection_size():
    spec = EnvSpec(Box.unbounded(2, labels=["GD_DS0", "GD_DS0d"]), 1)
    task = predefined.goal_distance_task(spec, 0, QuadraticErrorReward([1.0], None), success_threshold=0.01)
    state = _t([[0.009, 5.0], [0.02, 0.0]])
    memory = task.reset(state)
    # |0.009| < 0.01 succeeds (Pyrado's broadcast 2-D goal needed √2·0.009 = 0.0127 < 0.01: no)
    assert torch.equal(task.has_succeeded(state, memory), torch.tensor([True, False]))
    reward, _ = task.step_reward(state, torch.zeros(2, 1, dtype=F64), memory)
    torch.testing.assert_close(reward, _t([-(0.009**2), -(0.02**2)]), rtol=0, atol=1e-18)


def test_has_succeeded_has_failed_is_done_do_not_change_memory():
    for build in class_cases().values():
        task = build()
        data = make_drive_data(task, 4, 1, 0)
        memory = task.reset(data.states[0])
        _, memory = task.step_reward(data.states[1], data.actions[0], memory, 2)
        before = memory.clone()
        for method in (task.has_succeeded, task.has_failed, task.is_done):
            method(data.states[1], memory)
        for key, value in memory_leaves(before).items():
            assert torch.equal(memory.get(key), value), (type(task).__name__, key)


_ALL_CASES = {**class_cases(), **predefined_cases()}


@pytest.mark.parametrize("name", sorted(_ALL_CASES))
def test_memory_does_not_alias_the_callers_tensors(name):
    task = _ALL_CASES[name]()
    data = make_drive_data(task, 4, 1, 0)
    init_state, next_state, action = data.states[0].clone(), data.states[1].clone(), data.actions[0].clone()
    memory = task.reset(init_state)
    snapshot = memory.clone()
    init_state.add_(1.0)  # an env reusing its observation buffer
    for key, value in memory_leaves(snapshot).items():
        assert torch.equal(memory.get(key), value), ("reset", key)
    _, memory = task.step_reward(next_state, action, snapshot, 2)
    snapshot = memory.clone()
    next_state.add_(1.0)
    action.add_(1.0)
    for key, value in memory_leaves(snapshot).items():
        assert torch.equal(memory.get(key), value), ("step", key)


@pytest.mark.parametrize("name", sorted(_ALL_CASES))
def test_memory_of_another_float_dtype_is_refused_not_promoted(name):
    """Memory from a float64 reset passed with float32 states: a TypeError naming the entry and both dtypes
    (it promoted the reward to float64); a memory without float entries works and keeps float32."""
    task = _ALL_CASES[name]()
    data = make_drive_data(task, 4, 1, 0)
    state, next_state, action = data.states[0].float(), data.states[1].float(), data.actions[0].float()
    memory = task.reset(state.double())
    floats = [key for key, value in memory_leaves(memory).items() if value.is_floating_point()]
    if floats:
        with pytest.raises(TypeError, match=r"memory\[.*\] is torch.float64 but the state is torch.float32"):
            task.transition(state, action, next_state, memory, 3)
    else:
        assert task.transition(state, action, next_state, memory, 3).reward.dtype == torch.float32


@pytest.mark.parametrize("name", sorted(_ALL_CASES))
def test_an_action_of_another_float_dtype_is_refused_not_promoted(name):
    """A float64 action with float32 states promoted the reward (and a held reward in memory) to float64."""
    task = _ALL_CASES[name]()
    data = make_drive_data(task, 4, 1, 0)
    state, next_state = data.states[0].float(), data.states[1].float()
    memory = task.reset(state)
    with pytest.raises(TypeError, match=r"action must have the dtype of state \(torch.float32\), got torch.float64"):
        task.transition(state, data.actions[0].double(), next_state, memory, 3)
    assert task.transition(state, data.actions[0].float(), next_state, memory, 3).reward.dtype == torch.float32


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_half_precision_is_refused_by_tasks_rewards_and_the_transform(dtype):
    from torchrl.envs import Compose, DTypeCastTransform, TransformedEnv

    from torchtasks.envs import PendulumEnv
    from torchtasks.transforms import TaskTransform

    task = FinalRewardTask(DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], QuadraticErrorReward([1.0, 1.0], [0.1])))
    state = torch.zeros(3, 2)
    memory = task.reset(state)
    with pytest.raises(TypeError, match=r"state must be a float32 or float64 tensor .*half precision"):
        task.transition(state.to(dtype), torch.zeros(3, 1), state.to(dtype), memory)
    with pytest.raises(TypeError, match=r"next_state must be a float32 or float64"):
        task.transition(state, torch.zeros(3, 1), state.to(dtype), memory)
    with pytest.raises(TypeError, match=r"action must be a float32 or float64"):
        task.step_reward(state, torch.zeros(3, 1, dtype=dtype), memory)
    with pytest.raises(TypeError, match=r"error_state must be a float32 or float64"):
        QuadraticErrorReward([1.0, 1.0])(state.to(dtype), None)
    cast = DTypeCastTransform(torch.float32, dtype, in_keys=["observation"])
    env = TransformedEnv(PendulumEnv(batch_size=[2]), Compose(cast, TaskTransform(task)))
    with pytest.raises(TypeError, match=r"TaskTransform: the state entries \['observation'\] have dtype"):
        env.reset()


def test_memory_of_another_task_tree_names_the_missing_and_unexpected_keys():
    goal = functools.partial(proximity_succeeded, threshold=0.1)
    leaf = [DesiredStateTask(EnvSpec(1, 1), [float(g)], ConstantReward(-1.0), goal) for g in range(3)]
    two, three = ParallelTasks(leaf[:2]), ParallelTasks(leaf)
    state = torch.zeros(4, 1)
    with pytest.raises(ValueError, match=r"unexpected key\(s\) \['task2'\].*expects the layout"):
        two.transition(state, torch.zeros(4, 1), state, three.reset(state))
    memory = FinalRewardTask(leaf[0]).reset(state)
    del memory["wrapped", "state_des"]
    with pytest.raises(ValueError, match=r"memory\[\('wrapped',\)\] has missing key\(s\) \['state_des'\]"):
        FinalRewardTask(leaf[0]).transition(state, torch.zeros(4, 1), state, memory)
    with pytest.raises(ValueError, match=r"missing key\(s\) \['paid', 'wrapped'\]"):
        FinalRewardTask(leaf[0]).has_succeeded(state, two.reset(state))
