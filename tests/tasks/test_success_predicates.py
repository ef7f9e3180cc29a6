"""Success predicates are checked at construction; ``threshold=`` is ``success=proximity_succeeded`` with it.

Issue 26, item 5: ``success=proximity_succeeded`` without a bound threshold used to fail only at the
first step; a desired-state task now refuses it when built, naming the unbound parameters and the fix.
"""

from __future__ import annotations

import functools
import math

import pytest
import torch

from torchtasks.rewards import QuadraticErrorReward
from torchtasks.spaces import EnvSpec
from torchtasks.tasks import DesiredStateTask, RadiallySymmetricDesiredStateTask, proximity_succeeded


def reward() -> QuadraticErrorReward:
    return QuadraticErrorReward([1.0, 1.0], [0.1])


def desired(**kwargs: object) -> DesiredStateTask:
    return DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], reward(), **kwargs)


def radial(**kwargs: object) -> RadiallySymmetricDesiredStateTask:
    return RadiallySymmetricDesiredStateTask(EnvSpec(2, 1), [0.0, math.pi], reward(), indices=[1], **kwargs)


@pytest.mark.parametrize("make", [desired, radial], ids=["desired", "radial"])
def test_unbound_proximity_succeeded_is_refused_at_construction(make) -> None:
    with pytest.raises(TypeError) as error:
        make(success=proximity_succeeded)
    message = str(error.value)
    assert message.startswith("success must be callable with one positional argument")
    assert "proximity_succeeded has the required parameter(s) ['threshold'] left unbound" in message
    assert "functools.partial(proximity_succeeded, threshold=" in message
    assert "threshold=0.1" in message


@pytest.mark.parametrize(
    ("success", "named"),
    [
        (lambda error, scale: error.norm(dim=-1) < scale, "['scale']"),
        (lambda error, *, scale: error.norm(dim=-1) < scale, "['scale']"),
        (lambda error, a, b: error.norm(dim=-1) < a + b, "['a', 'b']"),
        (lambda: None, "takes no positional argument"),
        (lambda *, error: None, "takes no positional argument"),
    ],
    ids=["positional", "keyword-only", "two", "none", "keyword-only-error"],
)
def test_other_unusable_signatures_are_refused(success, named) -> None:
    with pytest.raises(TypeError, match="success must be callable with one positional argument") as error:
        desired(success=success)
    assert named in str(error.value)


class _ModuleSuccess(torch.nn.Module):
    def forward(self, error: torch.Tensor) -> torch.Tensor:
        return error.abs().amax(dim=-1) < 0.5


@pytest.mark.parametrize(
    "success",
    [
        functools.partial(proximity_succeeded, threshold=0.5),
        functools.partial(proximity_succeeded, threshold=0.5, dims=[0, 1]),
        lambda error, scale=0.5: error.norm(dim=-1) < scale,
        lambda *args: args[0].norm(dim=-1) < 0.5,
        _ModuleSuccess(),
    ],
    ids=["partial", "partial-dims", "default", "varargs", "module"],
)
def test_callables_of_the_error_alone_are_accepted_and_used(success) -> None:
    task = desired(success=success)
    state = torch.tensor([[0.1, 0.1], [2.0, 0.0]])
    assert task.has_succeeded(state, task.reset(state)).tolist() == [True, False]


def test_a_non_callable_success_is_still_a_type_error() -> None:
    with pytest.raises(TypeError, match="success must be callable or None, got float"):
        desired(success=0.1)


@pytest.mark.parametrize("make", [desired, radial], ids=["desired", "radial"])
def test_threshold_is_proximity_succeeded_with_that_threshold(make) -> None:
    generator = torch.Generator().manual_seed(0)
    shortcut = make(threshold=0.3)
    state = shortcut.state_des + 0.3 * torch.randn(64, 2, generator=generator, dtype=torch.float64)
    explicit = make(success=functools.partial(proximity_succeeded, threshold=0.3))
    memory = shortcut.reset(state)
    got = shortcut.has_succeeded(state, memory)
    assert torch.equal(got, explicit.has_succeeded(state, explicit.reset(state)))
    assert got.any() and not got.all()  # the sample has states on both sides of the threshold


def test_radial_threshold_sees_the_wrapped_error() -> None:
    task = radial(threshold=0.2)
    state = torch.tensor([[0.0, -math.pi + 0.1], [0.0, 0.0]])  # 0.1 from pi once wrapped; pi away
    assert task.has_succeeded(state, task.reset(state)).tolist() == [True, False]


def test_threshold_and_success_together_are_refused() -> None:
    with pytest.raises(ValueError, match=r"give success= or threshold=.*not both"):
        desired(success=functools.partial(proximity_succeeded, threshold=0.1), threshold=0.1)


@pytest.mark.parametrize(
    ("threshold", "error", "match"),
    [
        (0.0, ValueError, "threshold must be positive"),
        (-0.1, ValueError, "threshold must be positive"),
        (math.inf, ValueError, "threshold must be finite"),
        (math.nan, ValueError, "threshold must be finite"),
        (True, TypeError, "threshold must be a real number"),
        ("0.1", TypeError, "threshold must be a real number"),
    ],
)
def test_bad_thresholds_are_refused(threshold, error, match) -> None:
    with pytest.raises(error, match=match):
        desired(threshold=threshold)


def test_threshold_is_keyword_only() -> None:
    with pytest.raises(TypeError):
        DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], reward(), None, 0.1)  # type: ignore[misc]


def test_a_threshold_task_step_compiles_to_one_graph() -> None:
    task = radial(threshold=0.2)
    state = torch.tensor([[0.0, 3.0], [1.0, 0.0]], dtype=torch.float64)
    action = torch.tensor([[0.5], [-0.5]], dtype=torch.float64)
    next_state = torch.tensor([[0.0, -math.pi + 0.1], [1.0, 0.1]], dtype=torch.float64)
    memory = task.reset(state)

    def step(state, action, next_state, memory):
        out = task.transition(state, action, next_state, memory)
        return out.reward, out.success, out.done

    torch._dynamo.reset()
    compiled = torch.compile(step, fullgraph=True, backend="aot_eager")
    eager = step(state, action, next_state, memory)
    got = compiled(state, action, next_state, memory)
    for expected, value in zip(eager, got, strict=True):
        assert torch.equal(expected, value)
    assert got[1].tolist() == [True, False]


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"dims": 2}, ValueError, r"dims=2 is not an index of the error's 2 entries"),
        ({"dims": -3}, ValueError, r"dims=-3 is not an index"),
        ({"dims": [0, 5]}, ValueError, r"dims\[1\]=5 is not an index"),
        ({"dims": [False, True]}, TypeError, r"dims\[0\] must be an int"),
        ({"dims": "ab"}, TypeError, "dims must be an int, a non-empty list of ints or None"),
        ({"dims": []}, TypeError, "dims must be an int, a non-empty list of ints or None"),
        ({"threshold": -1.0}, ValueError, "threshold must be non-negative"),
        ({"threshold": math.nan}, ValueError, "threshold must be finite"),
    ],
)
def test_proximity_succeeded_refuses_dims_and_thresholds_that_mean_nothing(kwargs, error, match) -> None:
    """An index past the error's entries used to select nothing: a norm of 0, a success far from the goal."""
    arguments = {"threshold": 0.1, **kwargs}
    with pytest.raises(error, match=match):
        proximity_succeeded(torch.tensor([[5.0, 5.0]]), **arguments)
    task = DesiredStateTask(
        EnvSpec(2, 1), [0.0, 0.0], QuadraticErrorReward([1.0, 1.0]), functools.partial(proximity_succeeded, **arguments)
    )
    state = torch.tensor([[5.0, 5.0]])
    with pytest.raises(error, match=match):
        task.transition(state, torch.zeros(1, 1), state, task.reset(state))
