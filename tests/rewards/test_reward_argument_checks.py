"""Rewards fit their task at construction, and bad input gets an error naming the argument.

* A task checks its reward against its state and action sizes when it is built, through every
  term of a :class:`CompoundReward` (nested too) and for the rewards that index into the state,
  also when the task sits inside a :class:`MaskedTask`, :class:`FinalRewardTask` or
  :class:`ParallelTasks`: a wrong size is a ``ValueError`` naming the constant and the task's
  size, never a silent broadcast or an ``IndexError`` at the first step.
* Every reward's public call rejects a tensor argument of the wrong type, dtype, shape or batch.
* Tasks built on the CPU run on ``meta`` inputs (no buffer is pinned to the CPU in the step).
* Small ones: :class:`Box` arguments, duplicate labels, NumPy integer selections, the output of
  a :class:`StateFunctionReward` and the finiteness of :class:`SwingUpReward`'s constants.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from tensordict import TensorDict

import torchtasks.rewards as rewards_module
from task_trees import class_cases, full_spec, make_drive_data, memory_leaves, predefined_cases
from torchtasks.rewards import (
    AboveThresholdIndicator,
    AbsoluteErrorReward,
    ActionRateReward,
    AffineReward,
    AntForwardReward,
    CartPoleSwingUpReward,
    CompoundReward,
    ConstantReward,
    ContactCostReward,
    ContactCountReward,
    ControlCostReward,
    CosineReward,
    DisplacementReward,
    ExpQuadraticErrorReward,
    ExpTrackingReward,
    FeetAirTimeReward,
    ForwardVelocityReward,
    HealthyReward,
    HumanoidForwardReward,
    ProductReward,
    QuadraticErrorReward,
    RewardFunction,
    ScaledExpQuadraticErrorReward,
    ShiftedCosineReward,
    SquaredSumReward,
    StateFunctionReward,
    SwingUpReward,
    ToleranceReward,
    VelocityReward,
)
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import (
    ConditionTask,
    DesiredSpaceTask,
    DesiredStateTask,
    FinalRewardTask,
    FlippingTask,
    GoallessTask,
    MaskedTask,
    OptimizationTask,
    ParallelTasks,
    RadiallySymmetricDesiredStateTask,
    Task,
)

F64 = torch.float64
PROPERTY_SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _entries(count: int) -> str:
    return f"{count} entry" if count == 1 else f"{count} entries"


def _box(size: int) -> Box:
    return Box([-1.0] * size, [1.0] * size)


# ====================================================================================== item 1: sizes at construction
SIZE_MISMATCHES = {
    # name: (task builder, regex the ValueError must match)
    "compound Q of 1 entry on a 2-entry state": (
        lambda: GoallessTask(EnvSpec(2, 1), CompoundReward({"track": QuadraticErrorReward([1.0], None)})),
        r"term 'track' \(QuadraticErrorReward\) expects states of size 1, but the task's state has 2 entries",
    ),
    "compound R of 2 entries on a 1-entry action": (
        lambda: GoallessTask(EnvSpec(1, 1), CompoundReward({"track": QuadraticErrorReward([1.0], [1.0, 1.0])})),
        r"term 'track' \(QuadraticErrorReward\) expects actions of size 2, but the task's action has 1 entry",
    ),
    "compound q of 1 entry on a 2-entry state": (
        lambda: GoallessTask(EnvSpec(2, 1), CompoundReward({"track": AbsoluteErrorReward([1.0], None)})),
        r"term 'track' \(AbsoluteErrorReward\) expects states of size 1, but the task's state has 2 entries",
    ),
    "compound r of 2 entries on a 1-entry action": (
        lambda: GoallessTask(EnvSpec(1, 1), CompoundReward({"track": AbsoluteErrorReward([1.0], [1.0, 1.0])})),
        r"term 'track' \(AbsoluteErrorReward\) expects actions of size 2",
    ),
    "compound exp-quadratic in a desired-state task": (
        lambda: DesiredStateTask(
            EnvSpec(3, 1), [0.0] * 3, CompoundReward([ConstantReward(1.0), ExpQuadraticErrorReward([1.0] * 2)])
        ),
        r"term 'term1' \(ExpQuadraticErrorReward\) expects states of size 2, but the task's state has 3 entries",
    ),
    "nested compound": (
        lambda: GoallessTask(
            EnvSpec(2, 1), CompoundReward({"outer": CompoundReward({"inner": QuadraticErrorReward([1.0], None)})})
        ),
        r"term 'outer' \(CompoundReward\): term 'inner' \(QuadraticErrorReward\) expects states of size 1",
    ),
    "compound inside a masked task's sub-spec task": (
        lambda: MaskedTask(
            full_spec(),
            GoallessTask(
                full_spec().select_state(["a", "c"]), CompoundReward({"track": QuadraticErrorReward([1.0] * 4, None)})
            ),
            ["a", "c"],
        ),
        r"term 'track' \(QuadraticErrorReward\) expects states of size 4, but the task's state has 2 entries",
    ),
    "bare velocity index beyond the state": (
        lambda: GoallessTask(EnvSpec(2, 1), VelocityReward(index=5)),
        r"reward VelocityReward reads state entry index=5, but the task's state has 2 entries",
    ),
    "compound velocity index beyond the state": (
        lambda: GoallessTask(EnvSpec(2, 1), CompoundReward({"run": VelocityReward(index=5)})),
        r"term 'run' \(VelocityReward\) reads state entry index=5, but the task's state has 2 entries",
    ),
    "cosine index below the state": (
        lambda: DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], CosineReward(-3)),
        r"CosineReward reads state entry index=-3, but the task's state has 2 entries",
    ),
    "shifted cosine in a flipping task": (
        lambda: FlippingTask(EnvSpec(1, 1), math.pi, ShiftedCosineReward(1)),
        r"ShiftedCosineReward reads state entry index=1, but the task's state has 1 entry",
    ),
    "healthy indices": (
        lambda: GoallessTask(EnvSpec(3, 1), CompoundReward({"alive": HealthyReward(index=[0, 3])})),
        r"term 'alive' \(HealthyReward\) reads state entries index=\[0, 3\], but the task's state has 3 entries",
    ),
    "contact slice start": (
        lambda: GoallessTask(EnvSpec(3, 1), ContactCostReward(start=3)),
        r"ContactCostReward reads the state slice start=3, stop=None, but the task's state has 3 entries",
    ),
    "contact slice stop": (
        lambda: GoallessTask(EnvSpec(3, 1), ContactCostReward(start=1, stop=4)),
        r"ContactCostReward reads the state slice start=1, stop=4",
    ),
    "forward velocity index": (
        lambda: GoallessTask(EnvSpec(2, 1), ForwardVelocityReward(0.05, index=2)),
        r"ForwardVelocityReward reads state entry index=2, but the task's state has 2 entries",
    ),
    "ant z_index (default layout on a short state)": (
        lambda: GoallessTask(EnvSpec(2, 8), AntForwardReward(0.05)),
        r"AntForwardReward reads state entry z_index=2, but the task's state has 2 entries",
    ),
    "ant contact forces": (
        lambda: GoallessTask(EnvSpec(29, 8), AntForwardReward(0.05)),
        r"AntForwardReward reads the contact forces from contact_forces_start=29, but the task's state has 29",
    ),
    "humanoid x_index": (
        lambda: GoallessTask(EnvSpec(400, 17), HumanoidForwardReward(0.05, x_index=-401)),
        r"HumanoidForwardReward reads state entry x_index=-401, but the task's state has 400 entries",
    ),
    "swing-up index_theta": (
        lambda: DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], SwingUpReward(index_theta=2)),
        r"SwingUpReward reads state entry index_theta=2, but the task's state has 2 entries",
    ),
    "cart-pole swing-up on a 1-entry state": (
        lambda: DesiredStateTask(EnvSpec(1, 1), [0.0], CartPoleSwingUpReward()),
        r"CartPoleSwingUpReward reads state entries 0 and 1 \(x, θ\), but the task's state has 1 entry",
    ),
}


@pytest.mark.parametrize("case", sorted(SIZE_MISMATCHES))
def test_tasks_reject_rewards_that_do_not_fit_at_construction(case):
    build, match = SIZE_MISMATCHES[case]
    with pytest.raises(ValueError, match=match) as error:
        build()
    # a state-size mismatch names both fixes: a reward of the task's size, or a sub-spec task in a MaskedTask
    fixes = "spec.select_state([...]) and wrap it in MaskedTask(spec, task, [...])"
    assert (fixes in str(error.value)) == ("expects states of size" in str(error.value)), str(error.value)


def test_compound_does_not_broadcast_weights_and_the_step_never_indexes_out_of_range():
    """The symptoms of the unchecked path: a 1-entry Q broadcast over 2 entries, an IndexError at step 1."""
    for reward in (QuadraticErrorReward([1.0], None), AbsoluteErrorReward([1.0], None), VelocityReward(index=5)):
        for wrapped in (reward, CompoundReward({"term": reward})):
            with pytest.raises(ValueError, match=r"the task's state has 2 entries"):
                GoallessTask(EnvSpec(2, 1), wrapped)
    # the correct sizes are accepted and give the closed-form values
    task = GoallessTask(EnvSpec(2, 1), CompoundReward({"track": QuadraticErrorReward([1.0, 0.5], [2.0])}))
    state = torch.tensor([[1.0, 2.0]], dtype=F64)
    value, _ = task.step_reward(state, torch.ones(1, 1, dtype=F64), task.reset(state))
    assert value.tolist() == [-(1.0 + 0.5 * 4.0 + 2.0)]


def test_check_sizes_is_public_and_stateless_functions_accept_any_size():
    reward = CompoundReward({"track": QuadraticErrorReward([1.0, 1.0], [1.0]), "run": VelocityReward(index=-2)})
    reward.check_sizes(2, 1)
    with pytest.raises(ValueError, match=r"reward CompoundReward: term 'track' .* expects actions of size 1"):
        reward.check_sizes(2, 3)
    with pytest.raises(ValueError, match=r"term 'track' \(QuadraticErrorReward\) expects states of size 2"):
        reward.check_sizes(1, 1)
    # an action-free term has no action size; a state function cannot be checked
    QuadraticErrorReward([1.0], None).check_sizes(1, 7)
    StateFunctionReward(lambda s: s.sum(-1)).check_sizes(3, 1)
    OptimizationTask(EnvSpec(5, 1), StateFunctionReward(lambda s: s.sum(-1)))


# -------------------------------------------------------------------- (a) property: every sized reward, everywhere
Draw = Callable[..., object]


def _weight(draw: Draw, size: int, *, matrix: bool = True) -> torch.Tensor:
    diagonal = torch.tensor([draw(st.floats(0.1, 2.0)) for _ in range(size)], dtype=F64)
    return torch.diag(diagonal) if matrix and draw(st.booleans()) else diagonal


def _other_size(draw: Draw, size: int) -> int:
    return draw(st.integers(1, 6).filter(lambda k: k != size))


def _in_range(draw: Draw, size: int) -> int:
    return draw(st.integers(-size, size - 1))


def _out_of_range(draw: Draw, size: int) -> int:
    return draw(st.one_of(st.integers(size, size + 4), st.integers(-size - 4, -size - 1)))


def _weights_case(cls: type, *, vectors: bool = False, action_required: bool = False):
    """Fit/misfit builders of the error rewards (weights ``Q``/``R`` or ``q``/``r``)."""

    def make(draw: Draw, state_size: int, action_size: int | None) -> RewardFunction:
        Q = _weight(draw, state_size, matrix=not vectors)
        R = None if action_size is None else _weight(draw, action_size, matrix=not vectors)
        if cls is ScaledExpQuadraticErrorReward:
            return cls(Q, R, _box(state_size), _box(action_size), min_reward=0.01)
        return cls(Q, R)

    def fit(draw: Draw, n: int, m: int) -> RewardFunction:
        with_action = action_required or draw(st.booleans())
        return make(draw, n, m if with_action else None)

    def misfit(draw: Draw, n: int, m: int) -> tuple[RewardFunction, str]:
        if draw(st.booleans()):
            k = _other_size(draw, n)
            with_action = action_required or draw(st.booleans())
            return make(draw, k, m if with_action else None), (
                rf"expects states of size {k}, but the task's state has {_entries(n)}"
            )
        k = _other_size(draw, m)
        return make(draw, n, k), rf"expects actions of size {k}, but the task's action has {_entries(m)}"

    return fit, misfit


def _index_case(build: Callable[[int], RewardFunction], name: str):
    def fit(draw: Draw, n: int, m: int) -> RewardFunction:
        return build(_in_range(draw, n))

    def misfit(draw: Draw, n: int, m: int) -> tuple[RewardFunction, str]:
        index = _out_of_range(draw, n)
        return build(index), rf"reads state entry \b{name}={index}, but the task's state has {_entries(n)}"

    return fit, misfit


def _healthy_case():
    def fit(draw: Draw, n: int, m: int) -> RewardFunction:
        index = draw(st.lists(st.integers(0, n - 1), min_size=1, max_size=n, unique=True))
        return HealthyReward(1.0, index=index, low=-1.0, high=1.0, terminate_when_unhealthy=draw(st.booleans()))

    def misfit(draw: Draw, n: int, m: int) -> tuple[RewardFunction, str]:
        index = draw(st.lists(st.integers(0, n + 3), min_size=1, max_size=n + 1, unique=True).filter(max_at_least(n)))
        return HealthyReward(1.0, index=index), (
            rf"reads state entries index={re.escape(str(index))}, but the task's state has {_entries(n)}"
        )

    return fit, misfit


def max_at_least(size: int) -> Callable[[list[int]], bool]:
    return lambda values: max(values) >= size


def _contact_case():
    def fit(draw: Draw, n: int, m: int) -> RewardFunction:
        start = draw(st.integers(0, n - 1))
        stop = draw(st.one_of(st.none(), st.integers(start + 1, n)))
        return ContactCostReward(0.5, start=start, stop=stop)

    def misfit(draw: Draw, n: int, m: int) -> tuple[RewardFunction, str]:
        if draw(st.booleans()):
            start, stop = draw(st.integers(n, n + 3)), None
        else:
            start = draw(st.integers(0, n - 1))
            stop = draw(st.integers(n + 1, n + 4))
        return ContactCostReward(0.5, start=start, stop=stop), (
            rf"reads the state slice start={start}, stop={stop}, but the task's state has {_entries(n)}"
        )

    return fit, misfit


def _locomotion_case(cls: type):
    def make(x_index: int, z_index: int, start: int) -> RewardFunction:
        return cls(0.05, healthy_z_range=(-1.0, 1.0), x_index=x_index, z_index=z_index, contact_forces_start=start)

    def fit(draw: Draw, n: int, m: int) -> RewardFunction:
        return make(_in_range(draw, n), _in_range(draw, n), draw(st.integers(0, n - 1)))

    def misfit(draw: Draw, n: int, m: int) -> tuple[RewardFunction, str]:
        which = draw(st.sampled_from(["x_index", "z_index", "contact_forces_start"]))
        values = {"x_index": _in_range(draw, n), "z_index": _in_range(draw, n), "contact_forces_start": 0}
        if which == "contact_forces_start":
            values[which] = draw(st.integers(n, n + 4))
            match = rf"reads the contact forces from contact_forces_start={values[which]}, but the task's state has"
        else:
            values[which] = _out_of_range(draw, n)
            match = rf"reads state entry {which}={values[which]}, but the task's state has {_entries(n)}"
        return make(values["x_index"], values["z_index"], values["contact_forces_start"]), match

    return fit, misfit


def _swing_up_case():
    def fit(draw: Draw, n: int, m: int) -> RewardFunction:
        return SwingUpReward(index_x=_in_range(draw, n), index_theta=_in_range(draw, n))

    def misfit(draw: Draw, n: int, m: int) -> tuple[RewardFunction, str]:
        which = draw(st.sampled_from(["index_x", "index_theta"]))
        values = {"index_x": _in_range(draw, n), "index_theta": _in_range(draw, n)}
        values[which] = _out_of_range(draw, n)
        return SwingUpReward(**values), rf"reads state entry {which}={values[which]}, but the task's state has"

    return fit, misfit


def _cart_pole_case():
    def fit(draw: Draw, n: int, m: int) -> RewardFunction:
        return CartPoleSwingUpReward(draw(st.floats(0.0, 1.0)))

    def misfit(draw: Draw, n: int, m: int) -> tuple[RewardFunction, str]:
        return CartPoleSwingUpReward(), rf"reads state entries 0 and 1 \(x, θ\), but the task's state has {_entries(n)}"

    return fit, misfit


def _selection_case(build: Callable[[list[int]], RewardFunction], name: str):
    """Fit/misfit builders of the rewards reading a list of state entries (``indices``, ``contact_indices``)."""

    def fit(draw: Draw, n: int, m: int) -> RewardFunction:
        return build(draw(st.lists(st.integers(0, n - 1), min_size=1, max_size=n, unique=True)))

    def misfit(draw: Draw, n: int, m: int) -> tuple[RewardFunction, str]:
        index = draw(st.lists(st.integers(0, n + 3), min_size=1, max_size=n + 1, unique=True).filter(max_at_least(n)))
        return build(index), rf"reads state entries {name}={re.escape(str(index))}, but the task's state has"

    return fit, misfit


def _action_rate_case():
    def fit(draw: Draw, n: int, m: int) -> RewardFunction:
        return ActionRateReward(m)

    def misfit(draw: Draw, n: int, m: int) -> tuple[RewardFunction, str]:
        k = _other_size(draw, m)
        return ActionRateReward(k), rf"expects actions of size {k}, but the task's action has {_entries(m)}"

    return fit, misfit


@dataclass(frozen=True)
class SizedCase:
    """A reward class with size-carrying constants: builders of fitting and misfitting instances."""

    cls: type
    fit: Callable[[Draw, int, int], RewardFunction]
    misfit: Callable[[Draw, int, int], tuple[RewardFunction, str]]
    fit_sizes: tuple[int, ...] = (1, 2, 3, 4, 5)
    misfit_sizes: tuple[int, ...] = (1, 2, 3, 4, 5)

    @property
    def stateful(self) -> bool:
        return self.cls.stateful


SIZED = {
    "quadratic": SizedCase(QuadraticErrorReward, *_weights_case(QuadraticErrorReward)),
    "exp_quadratic": SizedCase(ExpQuadraticErrorReward, *_weights_case(ExpQuadraticErrorReward)),
    "scaled_exp_quadratic": SizedCase(
        ScaledExpQuadraticErrorReward, *_weights_case(ScaledExpQuadraticErrorReward, action_required=True)
    ),
    "absolute": SizedCase(AbsoluteErrorReward, *_weights_case(AbsoluteErrorReward, vectors=True)),
    "cosine": SizedCase(CosineReward, *_index_case(CosineReward, "index")),
    "shifted_cosine": SizedCase(ShiftedCosineReward, *_index_case(ShiftedCosineReward, "index")),
    "velocity": SizedCase(VelocityReward, *_index_case(lambda i: VelocityReward(0.5, index=i), "index")),
    "displacement": SizedCase(
        DisplacementReward, *_index_case(lambda i: DisplacementReward(10.0, index=i, origin=1.25), "index")
    ),
    "forward_velocity": SizedCase(
        ForwardVelocityReward, *_index_case(lambda i: ForwardVelocityReward(0.05, index=i), "index")
    ),
    "healthy": SizedCase(HealthyReward, *_healthy_case()),
    "contact_cost": SizedCase(ContactCostReward, *_contact_case()),
    "above_threshold": SizedCase(
        AboveThresholdIndicator, *_index_case(lambda i: AboveThresholdIndicator(0.5, index=i), "index")
    ),
    "ant": SizedCase(AntForwardReward, *_locomotion_case(AntForwardReward)),
    "humanoid": SizedCase(HumanoidForwardReward, *_locomotion_case(HumanoidForwardReward)),
    "swing_up": SizedCase(SwingUpReward, *_swing_up_case()),
    "cart_pole_swing_up": SizedCase(CartPoleSwingUpReward, *_cart_pole_case(), fit_sizes=(2, 3, 4), misfit_sizes=(1,)),
    "tolerance": SizedCase(
        ToleranceReward, *_index_case(lambda i: ToleranceReward(bounds=(-1.0, 1.0), margin=0.5, indices=[i]), "indices")
    ),
    "exp_tracking": SizedCase(ExpTrackingReward, *_selection_case(lambda i: ExpTrackingReward(0.5, i), "indices")),
    "squared_sum": SizedCase(SquaredSumReward, *_selection_case(SquaredSumReward, "indices")),
    "contact_count": SizedCase(ContactCountReward, *_selection_case(lambda i: ContactCountReward(1.0, i), "indices")),
    "feet_air_time": SizedCase(
        FeetAirTimeReward, *_selection_case(lambda i: FeetAirTimeReward(0.02, i), "contact_indices")
    ),
    "action_rate": SizedCase(ActionRateReward, *_action_rate_case()),
}

#: reward classes without size-carrying constants (any state and action size fits)
UNSIZED = {
    ConstantReward,
    ControlCostReward,
    StateFunctionReward,
    CompoundReward,
    ProductReward,  # a container: forwards the check to its factors
    AffineReward,  # a container: forwards the check to its reward
    RewardFunction,
}


def _reward_classes() -> set[type]:
    """The reward classes the package exports (its __all__ also lists functions and constants)."""
    exported = (getattr(rewards_module, name) for name in rewards_module.__all__)
    return {obj for obj in exported if isinstance(obj, type)}


def test_sized_cases_cover_every_reward_class_with_size_carrying_constants():
    assert {case.cls for case in SIZED.values()} == _reward_classes() - UNSIZED


CONTAINERS = ("bare", "compound", "nested")


def _contain(reward: RewardFunction, container: str) -> tuple[RewardFunction, str]:
    """Place ``reward`` in a container; return it and the regex of the message's subject."""
    name = re.escape(type(reward).__name__)
    if container == "bare":
        return reward, rf"reward {name} "
    if container == "compound":
        return CompoundReward({"term": reward, "alive": ConstantReward(1.0)}), rf"term 'term' \({name}\) "
    nested = CompoundReward({"outer": CompoundReward([ConstantReward(0.5), reward])})
    return nested, rf"term 'outer' \(CompoundReward\): term 'term1' \({name}\) "


#: every task type that takes a reward with size-carrying constants; OptimizationTask takes only a
#: StateFunctionReward (no sizes to check) and ConditionTask takes no reward
LEAVES: dict[str, Callable[[EnvSpec, RewardFunction], Task]] = {
    "desired_state": lambda spec, reward: DesiredStateTask(spec, [0.25] * spec.state_size, reward),
    "radially_symmetric": lambda spec, reward: RadiallySymmetricDesiredStateTask(
        spec, [0.25] * spec.state_size, reward, [0]
    ),
    "goalless": GoallessTask,
    "desired_space": lambda spec, reward: DesiredSpaceTask(spec, _box(spec.state_size), reward),
    "flipping": lambda spec, reward: FlippingTask(spec, math.pi / 2, reward),
}
WRAPPERS = ("none", "masked", "final", "parallel")


def _never(state: torch.Tensor) -> torch.Tensor:
    return torch.zeros(state.shape[:-1], dtype=torch.bool, device=state.device)


def _tree(
    draw: Draw, leaf: str, wrapper: str, n: int, m: int, reward: RewardFunction
) -> tuple[Callable[[], Task], EnvSpec]:
    """A builder of ``wrapper(leaf(reward))``, and the full state and action sizes it reads."""
    sub_spec = EnvSpec(n, m)
    if wrapper == "masked":
        extra_state, extra_action = draw(st.integers(0, 3)), draw(st.integers(0, 2))
        full = EnvSpec(n + extra_state, m + extra_action)
        positions = draw(st.permutations(list(range(n + extra_state))))[:n]
        action_positions = draw(st.permutations(list(range(m + extra_action))))[:m]
        return lambda: MaskedTask(full, LEAVES[leaf](sub_spec, reward), positions, action_positions), full
    if wrapper == "final":
        return lambda: FinalRewardTask(LEAVES[leaf](sub_spec, reward)), sub_spec
    if wrapper == "parallel":
        return lambda: ParallelTasks([LEAVES[leaf](sub_spec, reward), ConditionTask(sub_spec, _never, True)]), sub_spec
    return lambda: LEAVES[leaf](sub_spec, reward), sub_spec


def _draw_placement(draw: Draw, case: SizedCase, sizes: tuple[int, ...]) -> tuple[str, str, str, int, int]:
    container = draw(st.sampled_from(CONTAINERS))
    leaves = [name for name in LEAVES if not (name == "flipping" and case.stateful)]
    leaf = draw(st.sampled_from(leaves))
    wrapper = draw(st.sampled_from(WRAPPERS))
    n = 1 if leaf == "flipping" else draw(st.sampled_from(sizes))
    m = draw(st.integers(1, 3))
    return container, leaf, wrapper, n, m


@PROPERTY_SETTINGS
@given(name=st.sampled_from(sorted(SIZED)), data=st.data())
def test_property_constants_of_the_wrong_size_are_rejected_at_construction(name, data):
    case = SIZED[name]
    sizes = case.misfit_sizes
    container, leaf, wrapper, n, m = _draw_placement(data.draw, case, sizes)
    if n not in sizes:  # a flipping task's 1-entry state cannot misfit this reward
        return
    reward, problem = case.misfit(data.draw, n, m)
    contained, subject = _contain(reward, container)
    build, _ = _tree(data.draw, leaf, wrapper, n, m, contained)
    with pytest.raises(ValueError, match=subject + problem):
        build()
    with pytest.raises(ValueError, match=problem):  # the reward alone refuses these sizes too
        reward.check_sizes(n, m)


@PROPERTY_SETTINGS
@given(name=st.sampled_from(sorted(SIZED)), data=st.data())
def test_property_constants_of_the_right_size_are_accepted_and_step(name, data):
    case = SIZED[name]
    container, leaf, wrapper, n, m = _draw_placement(data.draw, case, case.fit_sizes)
    if n not in case.fit_sizes:
        return
    reward, _ = _contain(case.fit(data.draw, n, m), container)
    build, spec = _tree(data.draw, leaf, wrapper, n, m, reward)
    task = build()
    generator = torch.Generator().manual_seed(0)
    state = 0.5 * torch.randn(3, spec.state_size, dtype=F64, generator=generator)
    action = torch.randn(3, spec.action_size, dtype=F64, generator=generator)
    memory = task.reset(state)
    value, memory = task.step_reward(state + 0.1, action, memory)
    assert value.shape == (3,) and value.dtype == F64
    assert task.is_done(state, memory).shape == (3,)


# ====================================================================================== (b) public calls
@dataclass(frozen=True)
class CallCase:
    """A reward, the sizes of its inputs and which sizes its public call enforces."""

    make: Callable[[], RewardFunction]
    state_size: int = 5
    action_size: int = 2
    exact_state: bool = False  # the state must have exactly state_size entries
    min_state: int | None = None  # fewer entries are refused (the reward reads entry min_state - 1)
    exact_action: bool = False
    state_name: str = "error_state"

    @property
    def reward(self) -> RewardFunction:
        return self.make()


_Q5, _R2 = [1.0, 0.5, 0.25, 2.0, 1.0], [0.5, 1.0]
CALL_CASES = {
    "constant": CallCase(lambda: ConstantReward(1.0)),
    "cosine": CallCase(lambda: CosineReward(4), min_state=5),
    "shifted_cosine": CallCase(lambda: ShiftedCosineReward(-5), min_state=5),
    "absolute": CallCase(lambda: AbsoluteErrorReward(_Q5, _R2), exact_state=True, exact_action=True),
    "absolute_no_action": CallCase(lambda: AbsoluteErrorReward(_Q5), exact_state=True),
    "quadratic": CallCase(lambda: QuadraticErrorReward(torch.eye(5), _R2), exact_state=True, exact_action=True),
    "exp_quadratic": CallCase(lambda: ExpQuadraticErrorReward(_Q5, None), exact_state=True),
    "scaled_exp_quadratic": CallCase(
        lambda: ScaledExpQuadraticErrorReward(_Q5, _R2, _box(5), _box(2)), exact_state=True, exact_action=True
    ),
    "swing_up": CallCase(lambda: SwingUpReward(index_x=4, index_theta=1), min_state=5),
    "cart_pole_swing_up": CallCase(lambda: CartPoleSwingUpReward(0.5), min_state=2),
    "compound": CallCase(
        lambda: CompoundReward({"track": QuadraticErrorReward(_Q5, _R2), "angle": CosineReward(0)}),
        exact_state=True,
        exact_action=True,
    ),
    "state_function": CallCase(lambda: StateFunctionReward(lambda s: (s * s).sum(-1)), state_name="state"),
    "velocity": CallCase(lambda: VelocityReward(1.5, index=4), min_state=5),
    "displacement": CallCase(lambda: DisplacementReward(10.0, index=4, origin=0.5), min_state=5),
    "control_cost": CallCase(lambda: ControlCostReward(0.1)),
    "healthy": CallCase(lambda: HealthyReward(1.0, index=[0, 4], low=-1.0, high=1.0), min_state=5),
    "contact_cost": CallCase(lambda: ContactCostReward(0.5, start=2, stop=5), min_state=5),
    "above_threshold": CallCase(lambda: AboveThresholdIndicator(0.5, index=[0, 4], norm=True), min_state=5),
    # stateful: step(state, action, memory) after reset(init_state)
    "forward_velocity": CallCase(lambda: ForwardVelocityReward(0.05, index=4), min_state=5, state_name="state"),
    "ant": CallCase(lambda: AntForwardReward(0.05, contact_forces_start=4), min_state=5, state_name="state"),
    "humanoid": CallCase(lambda: HumanoidForwardReward(0.05, contact_forces_start=4), min_state=5, state_name="state"),
    "compound_stateful": CallCase(
        lambda: CompoundReward({"run": ForwardVelocityReward(0.05, index=4), "alive": ConstantReward(1.0)}),
        min_state=5,
        state_name="state",
    ),
    "tolerance": CallCase(lambda: ToleranceReward(bounds=(0.0, 1.0), margin=0.5, indices=[0, 4]), min_state=5),
    "exp_tracking": CallCase(lambda: ExpTrackingReward(0.5, [0, 4]), min_state=5),
    "squared_sum": CallCase(lambda: SquaredSumReward([4, 1]), min_state=5),
    "contact_count": CallCase(lambda: ContactCountReward(0.1, [0, 4]), min_state=5),
    "action_rate": CallCase(lambda: ActionRateReward(2), exact_action=True, state_name="state"),
    "feet_air_time": CallCase(
        lambda: FeetAirTimeReward(0.02, [0, 4], command_indices=[1, 2]), min_state=5, state_name="state"
    ),
    "product": CallCase(
        lambda: ProductReward({"track": QuadraticErrorReward(_Q5, _R2), "angle": CosineReward(0)}),
        exact_state=True,
        exact_action=True,
    ),
    "affine": CallCase(
        lambda: AffineReward(QuadraticErrorReward(_Q5, _R2), scale=2.0, offset=1.0), exact_state=True, exact_action=True
    ),
}


def test_call_cases_cover_every_reward_class():
    assert {type(case.reward) for case in CALL_CASES.values()} == _reward_classes() - {RewardFunction}


TENSOR_MUTATIONS = {
    # name: (mutate(x), exception)
    "not_a_tensor": (lambda x: x.numpy(), TypeError),
    "nested_list": (lambda x: x.tolist(), TypeError),
    "integer": (lambda x: x.long(), TypeError),
    "bool": (lambda x: x > 0, TypeError),
    "half": (lambda x: x.half(), TypeError),
    "bfloat16": (lambda x: x.bfloat16(), TypeError),
    "zero_d": (lambda x: x.new_tensor(0.5), ValueError),
    "other_batch": (lambda x: torch.cat([x, x[:1]]), ValueError),
}


def _call(reward: RewardFunction, state, action, memory=None):
    if reward.stateful:
        return reward.step(state, action, memory)
    return reward(state, action)


def _valid_inputs(case: CallCase, batch: tuple[int, ...]):
    generator = torch.Generator().manual_seed(1)
    state = 0.5 * torch.randn(*batch, case.state_size, dtype=F64, generator=generator)
    action = torch.randn(*batch, case.action_size, dtype=F64, generator=generator)
    return state, action


@PROPERTY_SETTINGS
@given(
    name=st.sampled_from(sorted(CALL_CASES)),
    batch=st.sampled_from([(4,), (2, 3)]),
    argument=st.sampled_from(["state", "action", "memory", "init_state"]),
    mutation=st.sampled_from([*TENSOR_MUTATIONS, "size", "none", "memory_dict", "memory_empty", "memory_batch"]),
    dtype=st.sampled_from([torch.float32, F64]),
)
def test_property_public_calls_reject_bad_tensor_arguments(name, batch, argument, mutation, dtype):
    case = CALL_CASES[name]
    reward = case.reward
    state, action = (x.to(dtype) for x in _valid_inputs(case, batch))
    memory = reward.reset(state) if reward.stateful else None
    # the valid call works and gives one value per environment
    value = _call(reward, state, action, memory)
    value = value[0] if reward.stateful else value
    assert value.shape == batch and value.dtype == dtype
    action_name = "action" if reward.stateful else "error_action"
    if argument == "memory" and not reward.stateful:
        argument = "action"
    if argument == "init_state" and not reward.stateful:
        argument = "state"
    if (argument == "memory") != mutation.startswith("memory_"):
        return  # memory mutations apply to memory only
    names = {"state": case.state_name, "action": action_name, "init_state": "init_state", "memory": "memory"}
    arg_name = names[argument]

    if mutation.startswith("memory_"):
        bad = {
            "memory_dict": {},
            "memory_empty": TensorDict({}, batch_size=batch),
            "memory_batch": reward.reset(torch.cat([state, state[:1]])),
        }[mutation]
        exception = ValueError if mutation == "memory_batch" else TypeError
        with pytest.raises(exception, match=r"\bmemory\b"):
            reward.step(state, action, bad)
        return

    x = action if argument == "action" else state
    if mutation == "size":
        if argument == "action":
            if not case.exact_action:
                return
            bad = torch.cat([x, x[..., :1]], dim=-1)
        elif case.exact_state:
            bad = torch.cat([x, x[..., :1]], dim=-1)
        elif case.min_state is not None:
            bad = x[..., : case.min_state - 1]
        else:
            return
        exception = ValueError
    elif mutation == "none":
        if argument != "action" or not reward.uses_action:
            return
        bad, exception = None, TypeError
    else:
        mutate, exception = TENSOR_MUTATIONS[mutation]
        bad = mutate(x)

    if argument == "init_state":
        if mutation == "other_batch":
            return  # reset takes one tensor: any batch is fine
        with pytest.raises(exception, match=rf"\b{arg_name}\b"):
            reward.reset(bad)
        return
    args = {"state": state, "action": action}
    args[argument] = bad
    if mutation == "other_batch":
        match = rf"{case.state_name} and {action_name} must have the same batch shape"
        if reward.stateful and argument == "state":
            match = rf"{match}|memory has batch size"
    else:
        match = rf"\b{arg_name}\b"
    with pytest.raises(exception, match=match):
        _call(reward, args["state"], args["action"], memory)


def test_action_free_rewards_still_accept_any_action_size_and_none():
    state = torch.zeros(3, 5, dtype=F64)
    for name, case in CALL_CASES.items():
        reward = case.reward
        if reward.uses_action:
            continue
        for action in (None, torch.zeros(3, 7), torch.zeros(3, 1, dtype=F64)):
            if reward.stateful:  # an action-free stateful reward (feet air time) steps its memory
                assert reward.step(state, action, reward.reset(state))[0].shape == (3,), name
            else:
                assert reward(state, action).shape == (3,), name


# ====================================================================================== item 12: meta inputs
_ALL_TASKS = {**class_cases(), **predefined_cases()}


@pytest.mark.parametrize("name", sorted(_ALL_TASKS))
def test_cpu_tasks_run_on_meta_inputs(name):
    """A task built on the CPU moves its constants (wrap mask, masked indices, ...) to the inputs' device."""
    task = _ALL_TASKS[name]()
    assert all(buffer.device.type == "cpu" for buffer in task.buffers())
    data = make_drive_data(task, 3, 1, 0)
    state, action, next_state = (x.to("meta") for x in (data.states[0], data.actions[0], data.states[1]))
    memory = task.reset(state)
    reward, memory = task.step_reward(next_state, action, memory, torch.tensor([1, 2, 0], device="meta"))
    done = task.is_done(next_state, memory)
    final, memory = task.final_reward(next_state, memory, 0, done)
    assert reward.device.type == done.device.type == final.device.type == "meta"
    assert all(value.device.type == "meta" for value in memory_leaves(memory).values())


def test_radially_symmetric_state_error_on_meta_inputs():
    reward = QuadraticErrorReward([1.0, 1.0, 1.0], [0.5])
    task = RadiallySymmetricDesiredStateTask(EnvSpec(3, 1), [0.0, math.pi, 0.0], reward, indices=[1])
    state = torch.zeros(2, 3, device="meta")
    memory = task.reset(state)
    error = task.state_error(state, memory)
    assert error.device.type == "meta" and error.shape == (2, 3)
    masked = MaskedTask(EnvSpec(5, 2), task, [4, 0, 2], [1])
    value, _ = masked.step_reward(
        torch.zeros(2, 5, device="meta"),
        torch.zeros(2, 2, device="meta"),
        masked.reset(torch.zeros(2, 5, device="meta")),
    )
    assert value.device.type == "meta" and value.shape == (2,)


# ====================================================================================== small ones: spaces
@pytest.mark.parametrize(
    ("low", "high", "name"),
    [("a", "b", "low"), ([0.0], "b", "high"), ([0.0], {"x": 1.0}, "high"), (None, [1.0], "low")],
    ids=["strings", "string_high", "dict_high", "none_low"],
)
def test_box_rejects_non_numeric_bounds_with_a_type_error_naming_them(low, high, name):
    with pytest.raises(TypeError, match=rf"^{name} must be a number or a 1-D sequence of numbers, got"):
        Box(low, high)


@pytest.mark.parametrize("size", [True, False, 2.0, "2", None], ids=["true", "false", "float", "str", "none"])
def test_unbounded_box_size_must_be_an_int(size):
    with pytest.raises(TypeError, match=r"^size must be a non-negative int, got .* of type"):
        Box.unbounded(size)


def test_unbounded_box_size_must_be_non_negative():
    with pytest.raises(ValueError, match=r"size must be a non-negative int, got -1"):
        Box.unbounded(-1)
    assert Box.unbounded(np.int64(2)) == Box.unbounded(2)


@pytest.mark.parametrize("labels", [["x", "x"], ["x", "y", "x"], ("a", "b", "b")], ids=["pair", "apart", "tuple"])
def test_box_rejects_duplicate_labels(labels):
    with pytest.raises(ValueError, match=r"labels must be distinct, got .*repeated"):
        Box([0.0] * len(labels), [1.0] * len(labels), labels=labels)
    with pytest.raises(ValueError, match=r"labels must be distinct"):
        Box.unbounded(len(labels), labels=labels)


@pytest.mark.parametrize(
    "item",
    [np.int64(1), np.int32(1), np.uint8(1), np.intp(-3), torch.tensor(1), torch.tensor(-3, dtype=torch.int32), 1],
    ids=["np_int64", "np_int32", "np_uint8", "np_intp_negative", "tensor", "tensor_int32_negative", "int"],
)
def test_box_selection_accepts_numpy_integers_like_ints(item):
    box = Box([0.0, 1.0, 2.0, 3.0], [5.0] * 4, labels=["a", "b", "c", "d"])
    assert box.indices([item]) == [1]
    assert box.indices(item) == [1]
    assert box.select([item]) == box.select([1])
    assert box.indices(np.array([2, 0])) == [2, 0] and box.indices(torch.tensor([2, 0])) == [2, 0]


@pytest.mark.parametrize(
    "item",
    [1.0, np.float64(1.0), np.float32(1.0), torch.tensor(1.0), True, np.bool_(True), torch.tensor(True), None],
    ids=["float", "np_float64", "np_float32", "float_tensor", "bool", "np_bool", "bool_tensor", "none"],
)
def test_box_selection_rejects_floats_and_bools_consistently(item):
    box = Box([0.0, 1.0, 2.0], [5.0] * 3)
    with pytest.raises(TypeError, match=r"indices must be ints or labels, got"):
        box.indices([item])
    with pytest.raises(TypeError, match=r"indices must be ints or labels, got"):
        box.select([item])
    with pytest.raises(TypeError, match=r"indices must be ints or labels, got"):
        box.indices(item)


def test_masked_task_takes_numpy_integer_selections():
    spec = full_spec()
    inner = DesiredStateTask(spec.select_state([2, 0]), [0.0, 0.0], QuadraticErrorReward([1.0, 1.0], None))
    by_numpy = MaskedTask(spec, inner, np.array([2, 0]))
    assert by_numpy.state_indices == MaskedTask(spec, inner, ["c", "a"]).state_indices == [2, 0]


# ====================================================================================== small ones: rewards
@pytest.mark.parametrize(
    ("fn", "got"),
    [
        (lambda s: s[..., 0] > 0, r"got a torch.bool tensor"),
        (lambda s: s[..., 0].long(), r"got a torch.int64 tensor"),
        (lambda s: (s[..., 0] > 0).int(), r"got a torch.int32 tensor"),
        (lambda s: s[..., 0].half(), r"got a torch.float16 tensor"),
        (lambda s: 1, r"got 1 of type int"),
        (lambda s: True, r"got True of type bool"),
        (lambda s: 0.5, r"got 0.5 of type float"),
    ],
    ids=["bool_tensor", "int64_tensor", "int32_tensor", "half_tensor", "python_int", "python_bool", "python_float"],
)
def test_state_function_must_return_a_floating_tensor(fn, got):
    reward = StateFunctionReward(fn)
    message = rf"fn must return a floating \(float32 or float64\) tensor of shape \[\*B\] = \(3,\) .*{got}"
    with pytest.raises(TypeError, match=message):
        reward(torch.zeros(3, 2), None)
    task = OptimizationTask(EnvSpec(2, 1), reward)  # the task's first step is the first call
    with pytest.raises(TypeError, match=message):
        task.step_reward(torch.zeros(3, 2), torch.zeros(3, 1), task.reset(torch.zeros(3, 2)))


def test_state_function_shape_errors_stay_value_errors():
    with pytest.raises(
        ValueError, match=r"fn must return a floating tensor of shape \[\*B\] = \(3,\) .*got shape \(3, 2\)"
    ):
        StateFunctionReward(lambda s: s)(torch.zeros(3, 2), None)
    assert StateFunctionReward(lambda s: s.sum(-1).float())(torch.zeros(3, 2, dtype=F64), None).dtype == torch.float32


@pytest.mark.parametrize("name", ["c_pole", "c_cart", "c_act", "c_theta_sq", "c_theta_log"])
@pytest.mark.parametrize("value", [math.inf, -math.inf, math.nan], ids=["inf", "-inf", "nan"])
def test_swing_up_constants_must_be_finite(name, value):
    with pytest.raises(ValueError, match=rf"^{name} must be finite, got"):
        SwingUpReward(**{name: value})


@pytest.mark.parametrize("name", ["c_pole", "c_cart", "c_act", "c_theta_sq", "c_theta_log"])
def test_swing_up_constants_must_be_numbers(name):
    with pytest.raises(TypeError, match=rf"^{name} must be a real number"):
        SwingUpReward(**{name: "1.0"})


def test_cart_pole_factor_must_be_a_finite_number():
    with pytest.raises(TypeError, match=r"^factor must be a real number"):
        CartPoleSwingUpReward("0.5")
    with pytest.raises(ValueError, match=r"^factor must be finite"):
        CartPoleSwingUpReward(math.inf)
