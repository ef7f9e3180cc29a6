"""``tolerance`` against dm_control's own ``rewards.tolerance``, its gradients, errors and ``ToleranceReward``.

dm_control (``pip install --no-deps dm-control==1.0.50``, done by ``make setup``) is the reference: its
numpy function is evaluated on the same grids, never the code under test.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch
from dm_control.utils import rewards as dm_rewards

from torchtasks.rewards.tolerance import SIGMOIDS, ToleranceReward, tolerance

COMPACT = ("cosine", "linear", "quadratic")
BOUNDS = [(0.0, 0.0), (-1.0, 1.0), (0.25, 0.75), (-math.inf, 1.0), (0.5, math.inf), (-math.inf, math.inf)]
MARGINS = [0.0, 0.3, 1.0, 2.5]
# a grid through the bounds, the margins and far outside, with the exact bound and margin points
GRID = np.unique(
    np.concatenate(
        [np.linspace(-6.0, 6.0, 1201), [-3.5, -2.5, -1.3, -1.0, -0.3, 0.0, 0.25, 0.75, 1.0, 1.3, 2.0, 3.5, 1e3, -1e3]]
    )
)


def _values_at_margin(sigmoid: str) -> list[float]:
    return [0.0, 0.1, 0.5, 0.95] if sigmoid in COMPACT else [1e-6, 0.1, 0.5, 0.95]


CASES = [
    (sigmoid, value, bounds, margin)
    for sigmoid in SIGMOIDS
    for value in _values_at_margin(sigmoid)
    for bounds in BOUNDS
    for margin in MARGINS
]


@pytest.mark.parametrize("sigmoid", SIGMOIDS)
def test_float64_equals_dm_control_to_1e_12(sigmoid: str) -> None:
    with np.errstate(all="ignore"):  # dm_control's cosh overflows far outside (its value is still 0)
        for _, value, bounds, margin in (case for case in CASES if case[0] == sigmoid):
            expected = dm_rewards.tolerance(GRID, bounds=bounds, margin=margin, sigmoid=sigmoid, value_at_margin=value)
            got = tolerance(torch.tensor(GRID), bounds=bounds, margin=margin, sigmoid=sigmoid, value_at_margin=value)
            assert got.dtype == torch.float64
            np.testing.assert_allclose(got.numpy(), expected, rtol=0, atol=1e-12, err_msg=str((value, bounds, margin)))


@pytest.mark.parametrize("sigmoid", SIGMOIDS)
def test_float32_within_1e_6(sigmoid: str) -> None:
    with np.errstate(all="ignore"):
        for _, value, bounds, margin in (case for case in CASES if case[0] == sigmoid):
            x = torch.tensor(GRID, dtype=torch.float32)
            expected = dm_rewards.tolerance(x.double().numpy(), bounds, margin, sigmoid, value)
            got = tolerance(x, bounds=bounds, margin=margin, sigmoid=sigmoid, value_at_margin=value)
            assert got.dtype == torch.float32
            np.testing.assert_allclose(got.double().numpy(), expected, rtol=0, atol=1e-6)


def test_tensor_bounds_and_margins_per_entry_and_per_env() -> None:
    generator = torch.Generator().manual_seed(0)
    x = torch.randn(5, 3, generator=generator, dtype=torch.float64) * 2
    lower = torch.tensor([-1.0, 0.0, -math.inf], dtype=torch.float64)  # per entry
    upper = torch.tensor([[1.0], [0.5], [2.0], [0.0], [math.inf]], dtype=torch.float64)  # per env
    margin = torch.tensor([0.0, 0.5, 2.0], dtype=torch.float64)  # per entry, one of them 0
    got = tolerance(x, bounds=(lower, upper), margin=margin, sigmoid="long_tail", value_at_margin=0.2)
    assert got.shape == (5, 3)
    for env, entry in itertools.product(range(5), range(3)):
        expected = dm_rewards.tolerance(
            float(x[env, entry]),
            bounds=(float(lower[entry]), float(upper[env, 0])),
            margin=float(margin[entry]),
            sigmoid="long_tail",
            value_at_margin=0.2,
        )
        assert abs(float(got[env, entry]) - expected) <= 1e-12


# ------------------------------------------------------------------------------------------- gradients
@pytest.mark.parametrize("sigmoid", SIGMOIDS)
def test_gradcheck_away_from_the_kinks(sigmoid: str) -> None:
    value = 0.1
    # points strictly inside, and outside away from the bounds and from the compact sigmoids' ends
    x = torch.tensor([-2.9, -1.7, -1.2, 0.3, 1.15, 1.45, 2.2], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: tolerance(t, (-1.0, 1.0), 1.0, sigmoid, value), (x,))
    bounds = (torch.tensor(-1.0, dtype=torch.float64, requires_grad=True), torch.tensor(1.0, dtype=torch.float64))
    fixed = x.detach()
    assert torch.autograd.gradcheck(lambda lo: tolerance(fixed, (lo, bounds[1]), 1.0, sigmoid, value), (bounds[0],))


@pytest.mark.parametrize("sigmoid", SIGMOIDS)
@pytest.mark.parametrize("bounds", BOUNDS[1:])
def test_gradients_are_finite_everywhere_and_nonzero_where_the_sigmoid_slopes(sigmoid: str, bounds) -> None:
    value = 0.0 if sigmoid in COMPACT else 0.1
    lower, upper = bounds
    special = [lower, upper, lower - 1.0, upper + 1.0, lower - 1 / 0.9, upper + 1e3]  # bounds, margins, far
    points = [p for p in special if math.isfinite(p)] + [0.0, 1e6, -1e6]
    x = torch.tensor(points, dtype=torch.float64, requires_grad=True)
    y = tolerance(x, bounds=bounds, margin=1.0, sigmoid=sigmoid, value_at_margin=value)
    (grad,) = torch.autograd.grad(y.sum(), x)
    assert torch.isfinite(grad).all(), (sigmoid, bounds, grad)
    # strictly outside, within the margin (not flat there for any sigmoid): a non-zero slope towards the bounds
    outside = []
    if math.isfinite(upper):
        outside.append(upper + 0.5)
    if math.isfinite(lower):
        outside.append(lower - 0.5)
    if outside:
        x = torch.tensor(outside, dtype=torch.float64, requires_grad=True)
        (grad,) = torch.autograd.grad(tolerance(x, bounds, 1.0, sigmoid, value).sum(), x)
        assert (grad != 0).all(), (sigmoid, bounds, grad)


# ----------------------------------------- issue 22, item 6: tiny value_at_margin, margin=0, x = ±inf
# values at and beyond ±inf, huge finite ones (whose distance or scaled distance overflows), the bounds, inside
FAR = [-math.inf, -1e308, -1e30, -3.0, -1.0, -0.5, 0.0, 0.75, 1.0, 1.2, 4.0, 1e30, 1e308, math.inf]


def _assert_equals_dm_control(got: torch.Tensor, x: np.ndarray, bounds, margin, sigmoid: str, value: float) -> None:
    with np.errstate(all="ignore"):  # dm_control's own inf * 0, inf / inf and cosh overflows
        expected = dm_rewards.tolerance(x, bounds=bounds, margin=margin, sigmoid=sigmoid, value_at_margin=value)
    # dm_control's values in float64 (to 1e-12, as the grids above), exactly at x = ±inf, and NaN exactly where
    # dm_control's is NaN (inf / inf with an infinite margin, 0 * inf with an infinite scale)
    got = got.detach().numpy()
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12, err_msg=str((sigmoid, value, bounds, margin)))
    exact = np.isnan(expected) | np.isinf(x)
    np.testing.assert_array_equal(got[exact], expected[exact], err_msg=str((sigmoid, value, bounds, margin)))


@pytest.mark.parametrize("value", [1.1e-16, 1e-17, 1e-100, 1e-300, 5e-324])
def test_tanh_squared_with_value_at_margin_below_1e_16_equals_dm_control(value: float) -> None:
    # 1 - value rounds to 1 below ~1.1e-16: atanh(1) raised a bare "math domain error"; dm_control (numpy) gets an
    # infinite scale: 0 outside the bounds, 1 inside (and NaN where the distance over the margin is 0 outside)
    for bounds, margin in itertools.product(BOUNDS, [*MARGINS, 1e-10, 1e10, math.inf]):
        x = torch.tensor(FAR, dtype=torch.float64, requires_grad=True)
        y = tolerance(x, bounds=bounds, margin=margin, sigmoid="tanh_squared", value_at_margin=value)
        _assert_equals_dm_control(y, np.array(FAR), bounds, margin, "tanh_squared", value)
        (grad,) = torch.autograd.grad(y.sum(), x)
        assert torch.isfinite(grad).all(), (value, bounds, margin, grad)
    x = torch.tensor(GRID)
    _assert_equals_dm_control(
        tolerance(x, (-1.0, 1.0), 0.5, "tanh_squared", value), GRID, (-1.0, 1.0), 0.5, "tanh_squared", value
    )
    reward = ToleranceReward(bounds=(-1.0, 1.0), margin=0.5, sigmoid="tanh_squared", value_at_margin=value)
    _assert_equals_dm_control(reward(x[:, None], None), GRID, (-1.0, 1.0), 0.5, "tanh_squared", value)


def test_tanh_squared_keeps_dm_controls_value_errors() -> None:
    x = torch.zeros(3, dtype=torch.float64)
    for bad in (0.0, -1e-300, 1.0):
        with pytest.raises(ValueError, match="value_at_1"):
            tolerance(x, (0.0, 1.0), 1.0, "tanh_squared", bad)
        with pytest.raises(ValueError, match="value_at_1"):
            dm_rewards.tolerance(np.zeros(3) + 5, (0.0, 1.0), 1.0, "tanh_squared", bad)


@pytest.mark.parametrize("sigmoid", ["hyperbolic", "long_tail", "reciprocal"])
def test_subnormal_value_at_margin_infinite_scale_equals_dm_control_with_finite_gradients(sigmoid: str) -> None:
    # 1 / 5e-324 overflows: an infinite scale as for tanh_squared above, whose d * inf had a NaN gradient
    for bounds, margin in itertools.product(BOUNDS, [0.3, 1.0, math.inf]):
        x = torch.tensor(FAR, dtype=torch.float64, requires_grad=True)
        y = tolerance(x, bounds=bounds, margin=margin, sigmoid=sigmoid, value_at_margin=5e-324)
        _assert_equals_dm_control(y, np.array(FAR), bounds, margin, sigmoid, 5e-324)
        (grad,) = torch.autograd.grad(y.sum(), x)
        assert torch.isfinite(grad).all(), (sigmoid, bounds, margin, grad)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_margin_zero_output_is_on_the_graph_with_zero_gradients(dtype: torch.dtype) -> None:
    # the 0/1 indicator was built from constants only: no grad_fn, so backward() raised
    for bounds in BOUNDS:
        x = torch.tensor([*FAR, math.nan], dtype=dtype, requires_grad=True)
        lower = torch.tensor(bounds[0], dtype=dtype, requires_grad=True)
        upper = torch.tensor(bounds[1], dtype=dtype, requires_grad=True)
        for sigmoid in SIGMOIDS:
            y = tolerance(x, bounds=(lower, upper), margin=0, sigmoid=sigmoid)
            assert y.requires_grad
            expected = dm_rewards.tolerance(x.detach().double().numpy(), bounds=bounds, margin=0.0)  # NaN x: 0
            np.testing.assert_array_equal(y.detach().double().numpy(), expected)
            y.sum().backward()
            for grad in (x.grad, lower.grad, upper.grad):
                assert grad is not None and torch.equal(grad, torch.zeros_like(grad)), (bounds, sigmoid, grad)
            x.grad = lower.grad = upper.grad = None
    x = torch.tensor([-2.0, 0.5, 3.0], dtype=dtype, requires_grad=True)
    tolerance(x, bounds=(0.0, 1.0)).sum().backward()  # margin=0 is the default
    assert torch.equal(x.grad, torch.zeros_like(x))


@pytest.mark.parametrize("sigmoid", SIGMOIDS)
def test_infinite_and_huge_x_equal_dm_control_with_finite_gradients(sigmoid: str) -> None:
    # at x = ±inf (and where distance / margin or its scaled value overflows) the sigmoids' derivatives were
    # 0 * inf = NaN, and cos(pi * z) of the cosine NaN where pi * z overflows
    margins = [0.3, 1.0, 2.5, 1e-10, 1e10, math.inf]
    for value, bounds, margin in itertools.product(_values_at_margin(sigmoid), BOUNDS, margins):
        x = torch.tensor(FAR, dtype=torch.float64, requires_grad=True)
        y = tolerance(x, bounds=bounds, margin=margin, sigmoid=sigmoid, value_at_margin=value)
        _assert_equals_dm_control(y, np.array(FAR), bounds, margin, sigmoid, value)
        (grad,) = torch.autograd.grad(y.sum(), x)
        assert torch.isfinite(grad).all(), (value, bounds, margin, grad)
        assert grad[0] == 0 and grad[-1] == 0, (value, bounds, margin, grad)  # flat at ±inf
    # tensor bounds and margins (per entry): finite gradients for x, the bounds and the margin
    x = torch.tensor(FAR, dtype=torch.float64, requires_grad=True)
    lower = torch.tensor([-1.0, -math.inf] * 7, dtype=torch.float64, requires_grad=True)
    upper = torch.tensor([1.0, 1.0, math.inf, 0.5] * 3 + [1.0, 1.0], dtype=torch.float64, requires_grad=True)
    margin = torch.tensor([0.0, 0.5, 2.0, math.inf, 1.0, 1e-3, 7.0] * 2, dtype=torch.float64, requires_grad=True)
    value = _values_at_margin(sigmoid)[1]
    y = tolerance(x, bounds=(lower, upper), margin=margin, sigmoid=sigmoid, value_at_margin=value)
    for i, point in enumerate(FAR):
        with np.errstate(all="ignore"):
            expected = dm_rewards.tolerance(point, (lower[i].item(), upper[i].item()), margin[i].item(), sigmoid, value)
        got = y[i].item()
        assert abs(got - expected) <= 1e-12 or (math.isnan(expected) and math.isnan(got)), (i, got, expected)
    y.sum().backward()
    for grad in (x.grad, lower.grad, upper.grad, margin.grad):
        assert torch.isfinite(grad).all(), (sigmoid, grad)


@pytest.mark.parametrize("sigmoid", SIGMOIDS)
def test_infinite_x_in_float32_is_right_with_finite_gradients(sigmoid: str) -> None:
    # float32 too, with value_at_margin whose scale overflows float32 (long_tail, reciprocal at 1e-300)
    values = [*_values_at_margin(sigmoid), 1e-300] if sigmoid not in COMPACT else _values_at_margin(sigmoid)
    for value, bounds in itertools.product(values, BOUNDS):
        x = torch.tensor(FAR, dtype=torch.float32, requires_grad=True)
        y = tolerance(x, bounds=bounds, margin=1.0, sigmoid=sigmoid, value_at_margin=value)
        with np.errstate(all="ignore"):
            expected = dm_rewards.tolerance(x.detach().double().numpy(), bounds, 1.0, sigmoid, value)
        np.testing.assert_allclose(y.detach().double().numpy(), expected, rtol=0, atol=1e-6)
        (grad,) = torch.autograd.grad(y.sum(), x)
        assert torch.isfinite(grad).all(), (value, bounds, grad)


def test_the_new_paths_compile_with_fullgraph() -> None:
    x = torch.tensor(FAR, dtype=torch.float64)
    for args in [
        ((-1.0, 1.0), 0.0, "gaussian", 0.1),
        ((-1.0, 1.0), 1.0, "tanh_squared", 1e-17),
        ((0.5, math.inf), 1.0, "cosine", 0.0),
    ]:
        compiled = torch.compile(lambda t, args=args: tolerance(t, *args), fullgraph=True, backend="aot_eager")
        a, b = x.clone().requires_grad_(), x.clone().requires_grad_()
        y = compiled(a)
        torch.testing.assert_close(y, tolerance(b, *args), equal_nan=True)
        y.sum().backward()
        tolerance(b, *args).sum().backward()
        assert torch.isfinite(a.grad).all() and torch.equal(a.grad, b.grad)


# -------------------------------------------------------------------------------------------- errors
def test_errors_are_dm_controls() -> None:
    x = torch.zeros(3, dtype=torch.float64)
    with pytest.raises(ValueError, match="Lower bound must be <= upper bound"):
        tolerance(x, bounds=(1.0, 0.0))
    with pytest.raises(ValueError, match="Lower bound must be <= upper bound"):
        tolerance(x, bounds=(torch.tensor([0.0, 2.0]), torch.tensor([1.0, 1.0])), margin=1.0)
    with pytest.raises(ValueError, match="`margin` must be non-negative"):
        tolerance(x, bounds=(0.0, 1.0), margin=-0.1)
    for sigmoid in SIGMOIDS:
        for bad in (1.0, -0.1) if sigmoid in COMPACT else (0.0, 1.0, 1.5):
            with pytest.raises(ValueError, match="value_at_1"):
                tolerance(x, (0.0, 1.0), 1.0, sigmoid, bad)
            with pytest.raises(ValueError):  # dm_control refuses the same value
                dm_rewards.tolerance(np.zeros(3) + 5, (0.0, 1.0), 1.0, sigmoid, bad)
    with pytest.raises(ValueError, match=r"Unknown sigmoid type 'logistic'; valid sigmoids are \['gaussian'"):
        tolerance(x, (0.0, 1.0), 1.0, "logistic")
    with pytest.raises(ValueError, match=r"Unknown sigmoid type 'logistic'"):  # stricter: dm_control ignores it
        tolerance(x, (0.0, 1.0), 0.0, "logistic")
    # stricter than dm_control, whose comparisons with a NaN bound give a number for a point inside the other bound
    with pytest.raises(ValueError, match="bounds must not be NaN"):
        tolerance(x, (math.nan, 1.0), 1.0)
    with pytest.raises(ValueError, match="bounds must not be NaN"):
        tolerance(x, (torch.tensor([0.0, math.nan, 0.0]), 1.0), 1.0)
    with pytest.raises(TypeError, match="half precision is not supported"):
        tolerance(x.half(), (0.0, 1.0), 1.0)


@pytest.mark.parametrize("sigmoid", SIGMOIDS)
def test_a_zero_margin_ignores_value_at_margin_as_dm_control(sigmoid: str) -> None:
    """With ``margin=0`` the output is the bounds' indicator: dm_control never checks ``value_at_margin`` then."""
    x = np.array(FAR)
    for bounds, value in itertools.product(BOUNDS, (0.0, 1.0, 1.5, -0.1)):
        got = tolerance(torch.tensor(x), bounds=bounds, margin=0, sigmoid=sigmoid, value_at_margin=value)
        _assert_equals_dm_control(got, x, bounds, 0, sigmoid, value)


def test_dtype_and_device_follow_x_and_compile_traces() -> None:
    x = torch.linspace(-3, 3, 11)
    assert tolerance(x, (-1.0, 1.0), 1.0).dtype == torch.float32
    assert tolerance(x.to("meta"), (-1.0, 1.0), 1.0).device.type == "meta"
    compiled = torch.compile(
        lambda t: tolerance(t, (-1.0, 1.0), 0.5, "hyperbolic", 0.2), fullgraph=True, backend="aot_eager"
    )
    torch.testing.assert_close(compiled(x), tolerance(x, (-1.0, 1.0), 0.5, "hyperbolic", 0.2))


# ------------------------------------------------------------------------------------ ToleranceReward
def test_tolerance_reward_product_and_mean_of_selected_entries() -> None:
    from torchtasks.spaces import Box

    space = Box([-5.0] * 3, [5.0] * 3, labels=["height", "tilt", "speed"])
    state = torch.tensor([[1.5, 0.1, 3.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    kwargs = dict(bounds=([1.2, -0.2], [math.inf, 0.2]), margin=[0.6, 0.5], sigmoid="linear", value_at_margin=0.0)
    product = ToleranceReward(**kwargs, indices=["height", "tilt"], space=space)
    mean = ToleranceReward(**kwargs, indices=[0, 1], combine="mean")
    height = [dm_rewards.tolerance(h, (1.2, math.inf), 0.6, "linear", 0.0) for h in (1.5, 1.0)]
    tilt = [dm_rewards.tolerance(t, (-0.2, 0.2), 0.5, "linear", 0.0) for t in (0.1, 0.0)]
    torch.testing.assert_close(
        product(state, None), torch.tensor([h * t for h, t in zip(height, tilt, strict=True)]).double()
    )
    torch.testing.assert_close(
        mean(state, None), torch.tensor([(h + t) / 2 for h, t in zip(height, tilt, strict=True)]).double()
    )


def test_tolerance_reward_learnable_bounds_get_gradients() -> None:
    reward = ToleranceReward(bounds=(-0.5, 0.5), margin=1.0, learnable=True)
    value = reward(torch.tensor([[0.9], [-1.2]]), None).sum()
    value.backward()
    assert reward.lower.grad is not None and reward.upper.grad is not None and reward.margin.grad is not None
    assert torch.isfinite(reward.upper.grad).all() and (reward.upper.grad != 0).all()


def test_tolerance_reward_in_tasks_and_size_errors() -> None:
    from torchtasks.spaces import EnvSpec
    from torchtasks.tasks import DesiredStateTask, GoallessTask

    near = ToleranceReward(bounds=(-0.1, 0.1), margin=0.5, sigmoid="gaussian")  # on the error, every entry
    task = DesiredStateTask(EnvSpec(2, 1), [1.0, 0.0], near)
    state = torch.tensor([[1.0, 0.0], [1.6, 0.0]], dtype=torch.float64)
    out = task.transition(state, torch.zeros(2, 1, dtype=torch.float64), state, task.reset(state))
    expected = [dm_rewards.tolerance(e, (-0.1, 0.1), 0.5) for e in (0.0, -0.6)]
    torch.testing.assert_close(out.reward, torch.tensor(expected, dtype=torch.float64))
    upright = GoallessTask(EnvSpec(3, 1), ToleranceReward(bounds=(1.0, 2.0), margin=1.0, indices=[2]))
    state = torch.tensor([[0.0, 0.0, 1.5], [0.0, 0.0, 0.0]])
    out = upright.transition(state, torch.zeros(2, 1), state, upright.reset(state))
    torch.testing.assert_close(out.reward, torch.tensor([1.0, 0.1]))
    with pytest.raises(ValueError, match="indices"):
        GoallessTask(EnvSpec(2, 1), ToleranceReward(bounds=(1.0, 2.0), indices=[2]))
    with pytest.raises(ValueError, match="bounds for 3 entries"):
        GoallessTask(EnvSpec(2, 1), ToleranceReward(bounds=([0.0] * 3, [1.0] * 3)))
    with pytest.raises(ValueError, match="one entry per selected entry"):
        ToleranceReward(bounds=([0.0, 0.0], [1.0, 1.0]), indices=[0, 1, 2])
    with pytest.raises(ValueError, match="Lower bound must be <= upper bound"):
        ToleranceReward(bounds=(1.0, 0.0))
