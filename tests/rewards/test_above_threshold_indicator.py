"""AboveThresholdIndicator: Safety-Gymnasium's ``float(velocity > threshold)`` on state entries.

Expected values come from the formula written here with numpy (``float(x > t)`` for one signed
entry, ``float(np.sqrt(x**2 + y**2) > t)`` for the planar speed, as in Safety-Gymnasium's
``safety_gymnasium/tasks/safe_velocity/safety_*_velocity_v0.py``), never from the code under test.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from torchtasks.rewards import AboveThresholdIndicator, CompoundReward, ConstantReward
from torchtasks.spaces import EnvSpec
from torchtasks.tasks import GoallessTask

F64 = torch.float64


def _signed(state: np.ndarray, index: int, threshold: float) -> np.ndarray:
    return (state[..., index] > threshold).astype(np.float64)


def _planar(state: np.ndarray, indices: list[int], threshold: float) -> np.ndarray:
    return (np.sqrt(sum(state[..., i] ** 2 for i in indices)) > threshold).astype(np.float64)


_finite = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)


@settings(max_examples=200, deadline=None)
@given(
    state=hnp.arrays(np.float64, st.tuples(st.integers(1, 6), st.just(4)), elements=_finite),
    threshold=st.floats(-5.0, 5.0, allow_nan=False),
    index=st.integers(-4, 3),
)
def test_signed_entry_matches_the_formula(state: np.ndarray, threshold: float, index: int) -> None:
    value = AboveThresholdIndicator(threshold, index=index)(torch.from_numpy(state), None)
    np.testing.assert_array_equal(value.numpy(), _signed(state, index, threshold))


@settings(max_examples=200, deadline=None)
@given(
    state=hnp.arrays(np.float64, st.tuples(st.integers(1, 6), st.just(4)), elements=_finite),
    threshold=st.floats(0.0, 8.0, allow_nan=False),
    indices=st.lists(st.integers(0, 3), min_size=1, max_size=4, unique=True),
)
def test_norm_matches_the_formula(state: np.ndarray, threshold: float, indices: list[int]) -> None:
    value = AboveThresholdIndicator(threshold, index=indices, norm=True)(torch.from_numpy(state), None)
    np.testing.assert_array_equal(value.numpy(), _planar(state, indices, threshold))


def test_planar_speed_at_the_threshold_agrees_with_numpy_bit_for_bit() -> None:
    """Velocities whose speed lies within a few ulps of the threshold: the same side as numpy's sqrt(x**2 + y**2)."""
    threshold = 2.6222  # Safety-Gymnasium's Ant v1 threshold
    angles = np.linspace(0.0, 2.0 * math.pi, 257)
    radii = threshold + np.array([-4, -2, -1, 0, 1, 2, 4]) * np.spacing(threshold)
    xy = np.stack([np.outer(radii, np.cos(angles)), np.outer(radii, np.sin(angles))], axis=-1).reshape(-1, 2)
    expected = (np.sqrt(xy[:, 0] ** 2 + xy[:, 1] ** 2) > threshold).astype(np.float64)
    assert 0 < expected.sum() < expected.size  # both sides occur
    value = AboveThresholdIndicator(threshold, index=[0, 1], norm=True)(torch.from_numpy(xy), None)
    np.testing.assert_array_equal(value.numpy(), expected)


def test_the_comparison_is_strict_signed_and_nan_costs_nothing() -> None:
    threshold = 0.7402
    state = torch.tensor(
        [[threshold], [math.nextafter(threshold, math.inf)], [-5.0], [math.inf], [-math.inf], [math.nan]], dtype=F64
    )
    assert AboveThresholdIndicator(threshold)(state, None).tolist() == [0.0, 1.0, 0.0, 1.0, 0.0, 0.0]
    # the norm of one entry is its absolute value: running backwards fast costs too
    assert AboveThresholdIndicator(threshold, index=0, norm=True)(state, None).tolist() == [
        0.0,
        1.0,
        1.0,
        1.0,
        1.0,
        0.0,
    ]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("batch", [(), (5,), (2, 3)])
def test_shape_and_dtype_follow_the_state(dtype: torch.dtype, batch: tuple[int, ...]) -> None:
    generator = torch.Generator().manual_seed(0)
    state = 3.0 * torch.randn(*batch, 3, generator=generator, dtype=F64)
    indicator = AboveThresholdIndicator(1.0, index=[0, 2], norm=True)
    value = indicator(state.to(dtype), torch.zeros(*batch, 2))
    assert value.shape == batch and value.dtype == dtype
    np.testing.assert_array_equal(value.double().numpy(), _planar(state.numpy(), [0, 2], 1.0))


def test_no_gradient_flows_and_the_value_is_a_constant_of_the_state() -> None:
    state = torch.tensor([[3.0, 0.0], [0.5, 0.0]], dtype=F64, requires_grad=True)
    value = AboveThresholdIndicator(1.0, index=[0, 1], norm=True)(state, None)
    assert not value.requires_grad
    assert value.tolist() == [1.0, 0.0]


def test_compiles_with_fullgraph_inside_a_task_step() -> None:
    torch._dynamo.reset()
    task = GoallessTask(EnvSpec(3, 1), CompoundReward({"alive": ConstantReward(1.0)}))
    indicator = AboveThresholdIndicator(1.0, index=[0, 1], norm=True)

    def step(state: torch.Tensor, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        reward, _ = task.step_reward(state, action, task.reset(state), torch.zeros((), dtype=torch.long))
        return reward, indicator(state, action)

    compiled = torch.compile(step, fullgraph=True, backend="aot_eager")
    state = torch.tensor([[0.9, 0.5, 0.0], [0.2, 0.1, 0.0], [-2.0, 0.0, 0.0]], dtype=F64)
    action = torch.zeros(3, 1, dtype=F64)
    reward, cost = compiled(state, action)
    assert cost.tolist() == _planar(state.numpy(), [0, 1], 1.0).tolist() == [1.0, 0.0, 1.0]
    assert reward.tolist() == [1.0, 1.0, 1.0]


def test_constants_move_with_the_module_and_copies_are_independent() -> None:
    indicator = AboveThresholdIndicator(2.0, index=[1, 2], norm=True)
    state = torch.tensor([[0.0, 1.5, 1.5]], dtype=F64)
    assert indicator(state.to("meta"), None).device.type == "meta"
    assert set(indicator.state_dict()) == {"threshold"}
    clone = copy.deepcopy(indicator)
    clone.threshold.fill_(3.0)
    assert indicator(state, None).tolist() == [1.0] and clone(state, None).tolist() == [0.0]
    assert repr(indicator) == "AboveThresholdIndicator(threshold=2.0, index=[1, 2], norm=True)"


# ----------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    ("make", "exception", "match"),
    [
        (lambda: AboveThresholdIndicator(math.nan), ValueError, r"threshold must be finite"),
        (lambda: AboveThresholdIndicator(math.inf), ValueError, r"threshold must be finite"),
        (lambda: AboveThresholdIndicator("1.0"), TypeError, r"threshold"),
        (lambda: AboveThresholdIndicator(True), TypeError, r"threshold"),
        (lambda: AboveThresholdIndicator(1.0, index=1.0), TypeError, r"index must be an int"),
        (lambda: AboveThresholdIndicator(1.0, index=[0, 1]), TypeError, r"index must be one int without norm=True"),
        (lambda: AboveThresholdIndicator(1.0, index=[], norm=True), ValueError, r"index must select at least one"),
        (lambda: AboveThresholdIndicator(1.0, index=[1, 1], norm=True), ValueError, r"index must not contain dup"),
        (lambda: AboveThresholdIndicator(1.0, index=[0, -1], norm=True), ValueError, r"index\[1\]"),
        (lambda: AboveThresholdIndicator(1.0, index=-1, norm=True), ValueError, r"index must be non-negative"),
        (lambda: AboveThresholdIndicator(1.0, norm=1), TypeError, r"norm must be a bool, got 1"),
    ],
)
def test_bad_arguments_name_the_argument(make, exception: type[Exception], match: str) -> None:
    with pytest.raises(exception, match=match):
        make()


def test_bad_calls_name_the_argument_and_the_shape() -> None:
    indicator = AboveThresholdIndicator(1.0, index=[0, 3], norm=True)
    with pytest.raises(ValueError, match=r"index \[0, 3\] is out of range for error_state of shape \(2, 3\)"):
        indicator(torch.zeros(2, 3), None)
    with pytest.raises(ValueError, match=r"index -4 is out of range for error_state of shape \(2, 3\)"):
        AboveThresholdIndicator(1.0, index=-4)(torch.zeros(2, 3), None)
    with pytest.raises(TypeError, match=r"error_state"):
        indicator(torch.zeros(2, 4, dtype=torch.long), None)
    with pytest.raises(ValueError, match=r"error_state and error_action must have the same batch shape"):
        indicator(torch.zeros(2, 4), torch.zeros(3, 1))


def test_a_task_checks_the_indices_at_construction() -> None:
    with pytest.raises(ValueError, match=r"reads state entry index=3, but the task's state has 3 entries"):
        GoallessTask(EnvSpec(3, 1), AboveThresholdIndicator(1.0, index=3))
    with pytest.raises(ValueError, match=r"reads state entries index=\[1, 3\], but the task's state has 3 entries"):
        GoallessTask(EnvSpec(3, 1), AboveThresholdIndicator(1.0, index=[1, 3], norm=True))
    GoallessTask(EnvSpec(3, 1), AboveThresholdIndicator(1.0, index=-3))
