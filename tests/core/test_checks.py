"""The argument checks of torchtasks._checks: one helper per kind, the same acceptance everywhere.

Integers: Python ints and NumPy integers, never bools or floats. Real numbers: Python and NumPy ints and
floats, never bools or strings. Errors name the argument; a wrong type is a TypeError, a value out of
range a ValueError. Then every public constructor taking an int accepts ``np.int64`` and refuses ``True``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from torchtasks._checks import (
    check_finite_scalar,
    check_int,
    check_non_negative_int,
    check_pair,
    check_positive_int,
    check_weight,
)
from torchtasks.envs import PendulumEnv, PointMassEnv
from torchtasks.rewards import (
    AntForwardReward,
    ContactCostReward,
    CosineReward,
    ForwardVelocityReward,
    HealthyReward,
    QuadraticErrorReward,
    SwingUpReward,
    ToleranceReward,
    VelocityReward,
)
from torchtasks.spaces import Box, EnvSpec
from torchtasks.stats import episode_statistics
from torchtasks.tasks import DesiredStateTask, MaskedTask, SequentialTasks, proximity_succeeded
from torchtasks.transforms import GoalCommand, TaskTransform

NOT_INTS = [True, False, np.bool_(True), 2.0, np.float64(2.0), "2", None, torch.tensor(2), [2]]
NOT_INT_IDS = ["true", "false", "np_bool", "float", "np_float", "str", "none", "tensor", "list"]
NOT_REALS = [True, np.bool_(False), "0.5", None, torch.tensor(True), [0.5], 1 + 2j]
NOT_REAL_IDS = ["true", "np_bool", "str", "none", "bool_tensor", "list", "complex"]
INT_CHECKS = {"int": check_int, "positive": check_positive_int, "non_negative": check_non_negative_int}
REAL_CHECKS = {"finite_scalar": check_finite_scalar, "weight": check_weight}


# ------------------------------------------------------------------------------------------- integers
@pytest.mark.parametrize("check", INT_CHECKS.values(), ids=INT_CHECKS.keys())
@pytest.mark.parametrize(
    "value", [3, np.int64(3), np.int32(3), np.uint8(3), np.intp(3)], ids=["int", "i64", "i32", "u8", "intp"]
)
def test_int_checks_accept_python_and_numpy_integers_as_python_ints(check, value):
    result = check(value, "n")
    assert result == 3 and type(result) is int


@pytest.mark.parametrize("check", INT_CHECKS.values(), ids=INT_CHECKS.keys())
@pytest.mark.parametrize("value", NOT_INTS, ids=NOT_INT_IDS)
def test_int_checks_refuse_bools_floats_and_other_types_with_a_type_error_naming_the_argument(check, value):
    with pytest.raises(TypeError, match=r"^my_arg must be an? .*int, got .* of type "):
        check(value, "my_arg")


def test_int_checks_ranges():
    assert check_int(-4, "i") == -4 and check_int(np.int64(-1), "i") == -1
    assert check_non_negative_int(0, "n") == 0 and check_non_negative_int(np.int64(0), "n") == 0
    assert check_positive_int(1, "n") == 1
    for value in (0, -1, np.int64(0), np.int8(-3)):
        with pytest.raises(ValueError, match=rf"^count must be a positive int, got {int(value)}$"):
            check_positive_int(value, "count")
    for value in (-1, np.int64(-2)):
        with pytest.raises(ValueError, match=rf"^size must be a non-negative int, got {int(value)}$"):
            check_non_negative_int(value, "size")


# --------------------------------------------------------------------------------------- real numbers
@pytest.mark.parametrize("check", REAL_CHECKS.values(), ids=REAL_CHECKS.keys())
@pytest.mark.parametrize(
    "value",
    [2, 2.0, np.int64(2), np.float32(2.0), np.float64(2.0), torch.tensor(2.0), torch.tensor([2]), np.uint8(2)],
    ids=["int", "float", "np_int", "np_float32", "np_float64", "tensor", "one_element_tensor", "np_uint8"],
)
def test_real_checks_accept_python_and_numpy_numbers_as_python_floats(check, value):
    result = check(value, "x")
    assert result == 2.0 and type(result) is float


@pytest.mark.parametrize("check", REAL_CHECKS.values(), ids=REAL_CHECKS.keys())
@pytest.mark.parametrize("value", NOT_REALS, ids=NOT_REAL_IDS)
def test_real_checks_refuse_bools_strings_and_other_types_with_a_type_error_naming_the_argument(check, value):
    with pytest.raises(TypeError, match=r"^my_arg must be a real number, got .* of type "):
        check(value, "my_arg")


@pytest.mark.parametrize("check", REAL_CHECKS.values(), ids=REAL_CHECKS.keys())
@pytest.mark.parametrize(
    "value", [math.nan, math.inf, -math.inf, np.float32("nan"), np.float64("inf"), torch.tensor(math.nan)]
)
def test_real_checks_refuse_nan_and_infinities_with_a_value_error(check, value):
    with pytest.raises(ValueError, match=r"^my_arg must be finite, got"):
        check(value, "my_arg")


def test_weights_may_be_zero_but_not_negative():
    assert check_weight(0, "w") == 0.0 and check_finite_scalar(-1.5, "x") == -1.5
    for value in (-0.1, np.float32(-1.0), np.int64(-2)):
        with pytest.raises(ValueError, match=r"^ctrl_cost_weight must be non-negative, got -"):
            check_weight(value, "ctrl_cost_weight")


# ---------------------------------------------------------------------------------------------- pairs
@pytest.mark.parametrize(
    "value",
    [(0, 1), [0.0, 1.0], (np.float32(0.0), np.int64(1)), np.array([0.0, 1.0]), torch.tensor([0.0, 1.0])],
    ids=["int_tuple", "float_list", "numpy_scalars", "array", "tensor"],
)
def test_pairs_accept_two_real_numbers_as_python_floats(value):
    result = check_pair(value, "r")
    assert result == (0.0, 1.0) and all(type(v) is float for v in result)


def test_pairs_allow_infinities_and_equal_ends():
    assert check_pair((-math.inf, math.inf), "r") == (-math.inf, math.inf)
    assert check_pair((np.float64(2.0), 2), "r") == (2.0, 2.0)


@pytest.mark.parametrize(
    "value",
    ["ab", 1.0, np.float64(1.0), None, (1.0,), (1, 2, 3), ("0", "1"), (True, 1), (0, None), torch.tensor(1.0)],
    ids=["str", "float", "np_float", "none", "one", "three", "strings", "bool_entry", "none_entry", "0d_tensor"],
)
def test_pairs_refuse_non_pairs_with_a_type_error_naming_the_argument(value):
    with pytest.raises(TypeError, match=r"^my_range must be a pair \(low, high\) of real numbers, got .* of type "):
        check_pair(value, "my_range")


def test_pairs_refuse_nan_and_reversed_ends_with_a_value_error():
    with pytest.raises(ValueError, match=r"^my_range must not contain NaN"):
        check_pair((math.nan, 1.0), "my_range")
    with pytest.raises(ValueError, match=r"^my_range must not contain NaN"):
        check_pair(np.array([0.0, np.nan]), "my_range")
    with pytest.raises(ValueError, match=r"^my_range must satisfy low <= high"):
        check_pair((1.0, 0.0), "my_range")


# --------------------------------------------------------------- every constructor that takes an int
def _task(size: int = 2) -> DesiredStateTask:
    near = functools.partial(proximity_succeeded, threshold=0.1)
    return DesiredStateTask(EnvSpec(size, 1), [0.0] * size, QuadraticErrorReward([1.0] * size), near)


def _sampler(shape: torch.Size, generator: torch.Generator | None) -> torch.Tensor:
    return torch.zeros(*shape, 2)


#: name -> (build the object from an int argument n, a valid n, what the result must show)
CONSTRUCTORS: dict[str, tuple[Callable[[object], object], int, Callable[[object], object]]] = {
    "TaskTransform(max_steps)": (lambda n: TaskTransform(_task(), max_steps=n), 10, lambda t: t._explicit_max_steps),
    "GoalCommand(resample_steps=n)": (
        lambda n: GoalCommand(Box([-1.0], [1.0]), resample_steps=n),
        5,
        lambda c: c.timer_range,
    ),
    "GoalCommand(resample_steps=(n, n))": (
        lambda n: GoalCommand(Box([-1.0], [1.0]), resample_steps=(n, n)),
        5,
        lambda c: c.timer_range,
    ),
    "GoalCommand(goal_size)": (lambda n: GoalCommand(_sampler, goal_size=n), 2, lambda c: c.goal_size),
    "GoalCommand(seed)": (
        lambda n: GoalCommand(Box([-1.0], [1.0]), seed=n),
        7,
        lambda c: torch.rand(3, generator=c.generator),
    ),
    "SequentialTasks(start_index)": (
        lambda n: SequentialTasks([_task(), _task()], start_index=n),
        1,
        lambda t: t.start_index,
    ),
    "PendulumEnv(batch_size)": (lambda n: PendulumEnv(batch_size=[n]), 3, lambda e: e.batch_size),
    "PointMassEnv(batch_size)": (lambda n: PointMassEnv(batch_size=(2, n)), 3, lambda e: e.batch_size),
    "PendulumEnv(seed)": (lambda n: PendulumEnv(batch_size=[2], seed=n), 3, lambda e: e.reset()["observation"]),
    "PointMassEnv(seed)": (lambda n: PointMassEnv(batch_size=[2], seed=n), 3, lambda e: e.reset()["observation"]),
    "Box.unbounded(size)": (lambda n: Box.unbounded(n), 3, lambda b: b),
    "EnvSpec(state_space, action_space)": (lambda n: EnvSpec(n, n), 2, lambda s: s),
    "MaskedTask(state_indices)": (lambda n: MaskedTask(EnvSpec(3, 1), _task(1), n), 2, lambda t: t.state_indices),
    "VelocityReward(index)": (lambda n: VelocityReward(index=n), 1, lambda r: r.index),
    "HealthyReward(index=n)": (lambda n: HealthyReward(index=n), 1, lambda r: r.index),
    "HealthyReward(index=[n])": (lambda n: HealthyReward(index=[0, n]), 1, lambda r: r.index),
    "ContactCostReward(start, stop)": (
        lambda n: ContactCostReward(start=n, stop=n + 2),
        1,
        lambda r: (r.start, r.stop),
    ),
    "CosineReward(index)": (lambda n: CosineReward(n), 1, lambda r: r.index),
    "SwingUpReward(index_x, index_theta)": (
        lambda n: SwingUpReward(index_x=n, index_theta=n + 1),
        0,
        lambda r: (r.index_x, r.index_theta),
    ),
    "ForwardVelocityReward(index)": (lambda n: ForwardVelocityReward(0.05, index=n), 1, lambda r: r.x_index),
    "AntForwardReward(x_index, z_index, contact_forces_start)": (
        lambda n: AntForwardReward(0.05, x_index=n, z_index=n, contact_forces_start=n),
        2,
        lambda r: (r.x_index, r.z_index, r.contact_forces_start),
    ),
    "ToleranceReward(indices)": (lambda n: ToleranceReward(indices=[n]), 1, lambda r: r.indices),
}


def _same(a: object, b: object) -> bool:
    if isinstance(a, torch.Tensor):
        return torch.equal(a, b)
    if isinstance(a, tuple) and a and isinstance(a[0], torch.Tensor):
        return all(torch.equal(x, y) for x, y in zip(a, b, strict=True))
    return a == b and type(a) is type(b)


@pytest.mark.parametrize("name", CONSTRUCTORS)
def test_int_arguments_accept_numpy_integers_like_python_ints(name):
    build, n, shown = CONSTRUCTORS[name]
    assert _same(shown(build(np.int64(n))), shown(build(n)))
    assert _same(shown(build(np.int32(n))), shown(build(n)))


@pytest.mark.parametrize("name", CONSTRUCTORS)
@pytest.mark.parametrize("value", [True, False, np.bool_(True), 1.0], ids=["true", "false", "np_bool", "float"])
def test_int_arguments_refuse_bools_and_floats_with_a_type_error(name, value):
    build, _, _ = CONSTRUCTORS[name]
    with pytest.raises(TypeError, match=r"int"):
        build(value)


@pytest.mark.parametrize(
    "build",
    [
        lambda n: TaskTransform(_task(), max_steps=n),
        lambda n: GoalCommand(Box([-1.0], [1.0]), resample_steps=n),
        lambda n: GoalCommand(_sampler, goal_size=n),
        lambda n: PendulumEnv(batch_size=[n]),
    ],
    ids=["max_steps", "resample_steps", "goal_size", "batch_size"],
)
def test_int_arguments_out_of_range_are_value_errors(build):
    with pytest.raises(ValueError, match=r"must be a (positive|non-negative) int, got -1"):
        build(np.int64(-1))


def test_int_arguments_of_functions_accept_numpy_integers_and_refuse_bools():
    error = torch.tensor([[0.0, 5.0]])
    assert torch.equal(proximity_succeeded(error, 0.1, dims=np.int64(0)), proximity_succeeded(error, 0.1, dims=0))
    assert torch.equal(proximity_succeeded(error, 0.1, dims=np.int64(-1)), proximity_succeeded(error, 0.1))
    with pytest.raises(TypeError, match=r"^dims must be an int, got True"):
        proximity_succeeded(error, 0.1, dims=True)
    flags = torch.zeros(2, 3, 1, dtype=torch.bool)
    batch = TensorDict(
        {"next": {"done": flags, "terminated": flags, "truncated": flags, "reward": torch.zeros(2, 3, 1)}},
        batch_size=[2, 3],
    )
    kwargs = {"success_key": None, "failure_key": None, "terms_key": None}
    assert episode_statistics(batch, time_dim=np.int64(1), **kwargs) == episode_statistics(batch, time_dim=1, **kwargs)
    with pytest.raises(TypeError, match=r"^episode_statistics: time_dim must be an int, got True"):
        episode_statistics(batch, time_dim=True, **kwargs)


def test_key_arguments_name_the_argument_and_its_owner():
    with pytest.raises(TypeError, match=r"^GoalCommand: goal_key must be a key \(a string or a tuple of strings\)"):
        GoalCommand(Box([-1.0], [1.0]), goal_key=("goal", 3))
    with pytest.raises(TypeError, match=r"^TaskTransform: reward_key must be a key .* got 3 of type int"):
        TaskTransform(_task(), reward_key=3)
    command = GoalCommand(Box([-1.0], [1.0]), goal_key=("command", ("goal",)))
    assert command.goal_key == ("command", "goal") and command.timer_key == ("command", "goal_steps_left")
    assert GoalCommand(Box([-1.0], [1.0])).timer_key == "goal_steps_left"
