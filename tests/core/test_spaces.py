"""Box and EnvSpec: membership, bounds, selection by index and label, TorchRL specs (semantics §2)."""

from __future__ import annotations

import math

import pytest
import torch
from torchrl.data import Bounded, Unbounded

from torchtasks.spaces import Box, EnvSpec, rows_outside

INF, NAN = math.inf, math.nan


@pytest.fixture
def box() -> Box:
    return Box([-1.0, 0.0, -INF, 2.0], [1.0, 0.5, 3.0, INF], labels=["a", "b", "c", "d"])


# --------------------------------------------------------------------------------------------------
# Construction
# --------------------------------------------------------------------------------------------------


def test_bounds_are_float64_and_scalars_broadcast() -> None:
    box = Box(-2, [1, 2, 3])
    assert box.low.dtype == box.high.dtype == torch.float64
    assert box.low.tolist() == [-2.0, -2.0, -2.0] and box.high.tolist() == [1.0, 2.0, 3.0]
    assert box.size == 3 and box.shape == (3,)
    assert Box([0.0, 1.0], 5.0).high.tolist() == [5.0, 5.0]
    assert Box(0.0, 1.0).size == 1


@pytest.mark.parametrize(
    ("low", "high", "labels", "match"),
    [
        ([0.0, 0.0], [1.0, 1.0, 1.0], None, "same length"),
        ([0.0, 2.0], [1.0, 1.0], None, r"low must be <= high"),
        ([0.0, NAN], [1.0, 1.0], None, r"\blow\b.*NaN"),
        ([0.0, 0.0], [1.0, NAN], None, r"\bhigh\b.*NaN"),
        ([[0.0]], [[1.0]], None, r"\blow\b"),
        ([0.0, 0.0], [1.0, 1.0], ["a"], r"\blabels\b"),
    ],
    ids=["length", "low_above_high", "low_nan", "high_nan", "2d", "labels_length"],
)
def test_invalid_boxes_raise(low: object, high: object, labels: list[str] | None, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        Box(low, high, labels=labels)


def test_labels_must_be_strings() -> None:
    with pytest.raises(TypeError, match=r"\blabels\b"):
        Box([0.0, 0.0], [1.0, 1.0], labels=["a", 1])
    with pytest.raises(TypeError, match=r"labels must be a sequence of strings .* got the string 'xv'"):
        Box([0.0, 0.0], [1.0, 1.0], labels="xv")  # not split into ("x", "v")


@pytest.mark.parametrize(
    "value", [[True, False], torch.tensor([True, False]), [1 + 1j, 0.0], torch.tensor([1 + 1j, 0j])], ids=str
)
def test_bounds_of_bools_or_complex_numbers_are_refused(value: object) -> None:
    with pytest.raises(TypeError, match="low must hold real numbers"):
        Box(value, [2.0, 2.0])


def test_rows_outside_does_not_broadcast_a_bound() -> None:
    x = torch.zeros(4, 3)
    with pytest.raises(ValueError, match=r"low and high must have the 3 entries of x's rows, got shapes \[1\]"):
        rows_outside(x, torch.zeros(1), torch.ones(1))
    assert not rows_outside(x, torch.full((3,), -1.0), torch.ones(3)).any()


def test_equality_compares_bounds_and_labels() -> None:
    assert Box([0.0, -INF], [1.0, INF], labels=["x", "y"]) == Box([0, -INF], [1, INF], labels=("x", "y"))
    assert hash(Box([0.0], [1.0])) == hash(Box([0.0], [1.0]))
    assert Box([0.0], [1.0]) != Box([0.0], [2.0])
    assert Box([0.0], [1.0], labels=["x"]) != Box([0.0], [1.0])
    assert Box([0.0], [1.0]) != Box([0.0, 0.0], [1.0, 1.0])


# --------------------------------------------------------------------------------------------------
# contains
# --------------------------------------------------------------------------------------------------


def test_contains_is_inclusive_and_batched(box: Box) -> None:
    x = torch.tensor(
        [
            [-1.0, 0.0, -1e300, 2.0],  # every bound hit exactly
            [1.0, 0.5, 3.0, 1e300],
            [0.0, 0.25, -INF, INF],  # infinite values on infinite bounds
            [1.0 + 1e-12, 0.0, 0.0, 2.0],  # just above a
            [0.0, -1e-12, 0.0, 2.0],  # just below b
            [0.0, 0.0, 3.0 + 1e-9, 2.0],  # above the finite side of c
            [0.0, 0.0, 0.0, 2.0 - 1e-9],  # below the finite side of d
        ],
        dtype=torch.float64,
    )
    inside = box.contains(x)
    assert inside.dtype == torch.bool
    assert inside.tolist() == [True, True, True, False, False, False, False]
    assert box.contains(x.reshape(7, 1, 4)).shape == (7, 1)
    assert box.contains(torch.stack([x, x])).tolist() == [inside.tolist()] * 2


def test_contains_an_unbatched_row(box: Box) -> None:
    inside = box.contains(torch.tensor([0.0, 0.0, 0.0, 5.0]))
    assert inside.shape == () and bool(inside)
    assert not bool(box.contains(torch.tensor([5.0, 0.0, 0.0, 5.0])))


@pytest.mark.parametrize("position", range(4))
def test_nan_is_never_inside(box: Box, position: int) -> None:
    x = torch.tensor([[0.0, 0.0, 0.0, 5.0]], dtype=torch.float64).repeat(2, 1)
    x[0, position] = NAN
    assert box.contains(x).tolist() == [False, True]
    unbounded = Box.unbounded(4)
    assert unbounded.contains(x).tolist() == [False, True]


def test_unbounded_box_contains_infinities() -> None:
    box = Box.unbounded(2, labels=["x", "y"])
    assert box.low.tolist() == [-INF, -INF] and box.high.tolist() == [INF, INF]
    assert not box.is_bounded and Box([0.0, -INF], [INF, INF]).is_bounded
    assert box.contains(torch.tensor([[INF, -INF], [1e308, 0.0]])).tolist() == [True, True]


def test_contains_follows_the_input_dtype() -> None:
    box = Box([0.0], [0.1])
    x32 = torch.tensor([[0.1], [0.0], [0.2]], dtype=torch.float32)  # 0.1f > 0.1, equal to the float32 bound
    assert box.contains(x32).tolist() == [True, True, False]
    assert box.contains(torch.tensor([[0], [1]])).tolist() == [True, False]  # integer input


@pytest.mark.parametrize(
    "x",
    [torch.zeros(3), torch.zeros(2, 5), torch.tensor(0.5), torch.zeros(4, 0)],
    ids=["short_row", "long_rows", "0d", "empty_rows"],
)
def test_contains_rejects_wrong_shapes(box: Box, x: torch.Tensor) -> None:
    with pytest.raises(ValueError, match=r"\[\*B, 4\]"):
        box.contains(x)


def test_contains_rejects_non_tensors(box: Box) -> None:
    with pytest.raises(TypeError):
        box.contains([0.0, 0.0, 0.0, 5.0])


# --------------------------------------------------------------------------------------------------
# bound_abs_high
# --------------------------------------------------------------------------------------------------


def test_bound_abs_high_is_the_largest_absolute_bound() -> None:
    box = Box([-3.0, -1.0, 0.0, 2.0, -INF, -5.0], [2.0, 4.0, 0.0, 7.0, 1.0, -4.0])
    assert box.bound_abs_high.tolist() == [3.0, 4.0, 0.0, 7.0, INF, 5.0]
    assert box.bound_abs_high.dtype == torch.float64


# --------------------------------------------------------------------------------------------------
# Selection
# --------------------------------------------------------------------------------------------------


SELECTIONS = {
    "labels_reversed": (lambda: ["c", "a"], [2, 0]),
    "ints_reversed": (lambda: [3, 1], [3, 1]),
    "mixed": (lambda: ["d", 0, "b"], [3, 0, 1]),
    "one_label": (lambda: "b", [1]),
    "one_int": (lambda: 2, [2]),
    "negative_int": (lambda: [-1, 0], [3, 0]),
    "generator": (lambda: (label for label in ["b", "a"]), [1, 0]),
}


@pytest.mark.parametrize("name", list(SELECTIONS))
def test_selection_follows_the_given_order(box: Box, name: str) -> None:
    make, positions = SELECTIONS[name]
    assert box.indices(make()) == positions
    sub = box.select(make())
    lows, highs = [-1.0, 0.0, -INF, 2.0], [1.0, 0.5, 3.0, INF]
    assert sub.low.tolist() == [lows[p] for p in positions]
    assert sub.high.tolist() == [highs[p] for p in positions]
    assert sub.labels == tuple("abcd"[p] for p in positions)


def test_selection_of_an_unlabeled_box_by_int() -> None:
    box = Box([0.0, 1.0, 2.0], [10.0, 11.0, 12.0])
    sub = box.select([2, 0])
    assert sub.low.tolist() == [2.0, 0.0] and sub.high.tolist() == [12.0, 10.0] and sub.labels is None


@pytest.mark.parametrize(
    ("selection", "match"),
    [
        (["a", "zz"], "zz"),
        (["a", "a"], "duplicate"),
        ([1, 1], "duplicate"),
        (["b", 1], "duplicate"),
        ([0, -4], "duplicate"),
        ([4], "out of range"),
        ([-5], "out of range"),
    ],
    ids=["unknown_label", "duplicate_label", "duplicate_int", "label_and_int", "negative_alias", "int_4", "int_-5"],
)
def test_invalid_selections_raise(box: Box, selection: list[object], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        box.indices(selection)
    with pytest.raises(ValueError, match=match):
        box.select(selection)


def test_label_selection_needs_labels() -> None:
    with pytest.raises(ValueError, match="labels"):
        Box([0.0], [1.0]).select(["x"])


@pytest.mark.parametrize("item", [True, 1.0, None], ids=["bool", "float", "none"])
def test_selection_rejects_other_types(box: Box, item: object) -> None:
    with pytest.raises(TypeError):
        box.indices([item])


# --------------------------------------------------------------------------------------------------
# TorchRL specs
# --------------------------------------------------------------------------------------------------


def test_from_bounded_spec() -> None:
    spec = Bounded(low=torch.tensor([-1.0, -2.0, 0.0]), high=torch.tensor([1.0, 3.0, 0.5]), shape=(3,))
    box = Box.from_spec(spec, labels=["x", "y", "z"])
    assert box.low.dtype == torch.float64
    assert box.low.tolist() == [-1.0, -2.0, 0.0] and box.high.tolist() == [1.0, 3.0, 0.5]
    assert box.labels == ("x", "y", "z")


def test_from_bounded_spec_with_batch_dimensions() -> None:
    box = Box.from_spec(Bounded(low=-2.0, high=2.0, shape=(4, 2), dtype=torch.float64))
    assert box == Box([-2.0, -2.0], [2.0, 2.0])
    low = torch.tensor([[-1.0, 0.0], [-2.0, 0.0]])
    with pytest.raises(ValueError, match="bounds"):
        Box.from_spec(Bounded(low=low, high=torch.ones(2, 2), shape=(2, 2)))


def test_from_unbounded_spec_gives_infinite_bounds() -> None:
    for dtype in (torch.float32, torch.float64):
        box = Box.from_spec(Unbounded(shape=(3,), dtype=dtype))
        assert box.size == 3
        assert box.low.tolist() == [-INF] * 3 and box.high.tolist() == [INF] * 3, dtype
        assert not box.is_bounded


def test_from_spec_needs_a_shape() -> None:
    with pytest.raises(ValueError, match="dimension"):
        Box.from_spec(Unbounded(shape=()))


# --------------------------------------------------------------------------------------------------
# EnvSpec
# --------------------------------------------------------------------------------------------------


def test_env_spec_int_sizes_are_unbounded_boxes() -> None:
    spec = EnvSpec(3, 2)
    assert spec.state_space == Box.unbounded(3) and spec.action_space == Box.unbounded(2)
    assert spec.state_size == 3 and spec.action_size == 2
    assert not spec.state_space.is_bounded


def test_env_spec_keeps_given_boxes() -> None:
    state = Box([-1.0, 0.0], [1.0, 2.0], labels=["x", "v"])
    spec = EnvSpec(state_space=state, action_space=1)
    assert spec.state_space is state and spec.action_space == Box.unbounded(1)
    assert spec == EnvSpec(Box([-1.0, 0.0], [1.0, 2.0], labels=["x", "v"]), 1)
    assert hash(spec) == hash(EnvSpec(Box([-1.0, 0.0], [1.0, 2.0], labels=["x", "v"]), 1))
    assert spec != EnvSpec(state, 2)
    selected = spec.select_state(["v"])
    assert selected.state_space == Box([0.0], [2.0], labels=["v"]) and selected.action_space == spec.action_space


@pytest.mark.parametrize(
    ("state_space", "action_space", "match"),
    [(None, 1, "state_space"), (3, "a", "action_space"), (True, 1, "state_space"), (2.0, 1, "state_space")],
    ids=["none", "string", "bool", "float"],
)
def test_env_spec_rejects_other_types(state_space: object, action_space: object, match: str) -> None:
    with pytest.raises(TypeError, match=match):
        EnvSpec(state_space, action_space)


def test_env_spec_needs_both_spaces() -> None:
    with pytest.raises(TypeError):
        EnvSpec(3)  # type: ignore[call-arg]
