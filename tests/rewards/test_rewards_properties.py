"""Properties of the reward functions: batching, closed forms, gradients, compilation, dtypes, validation.

Expected values come from closed-form numpy references written here (pyrado-semantics.md §4 and
the torchtasks decisions of §10), never from the code under test.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest
import torch
from dm_control.utils import rewards as dm_rewards
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from tensordict import TensorDict
from torch import nn

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
from torchtasks.spaces import Box

COMPILE_BACKEND = "aot_eager"  # dynamo fullgraph tracing without inductor's C++ build (~30 s cold)

Q3 = np.array([[2.0, 0.5, 0.0], [0.5, 1.0, -0.2], [0.0, -0.2, 0.3]])  # symmetric PD
R2 = np.array([[0.3, 0.1], [0.1, 0.2]])  # symmetric PD
Q_DIAG = np.array([1.0, 2.0, 0.5])
R_DIAG = np.array([0.1, 0.0])
Q_ABS = np.array([1.0, 0.5, 2.0])
R_ABS = np.array([0.3, 0.0])
STATE_LOW, STATE_HIGH = np.array([-1.0, -3.0, 0.5]), np.array([2.0, 1.0, 4.0])
ACTION_LOW, ACTION_HIGH = np.array([-1.0, -0.5]), np.array([1.0, 2.0])


def rosenbrock(x: torch.Tensor) -> torch.Tensor:
    head, tail = x[..., :-1], x[..., 1:]
    return (100.0 * (tail - head * head) ** 2 + (1.0 - head) ** 2).sum(dim=-1)


def np_rosenbrock(x: np.ndarray) -> np.ndarray:
    head, tail = x[..., :-1], x[..., 1:]
    return (100.0 * (tail - head**2) ** 2 + (1.0 - head) ** 2).sum(-1)


def np_quadratic(weight: np.ndarray, error: np.ndarray) -> np.ndarray:
    if weight.ndim == 1:
        return (error**2 * weight).sum(-1)
    return np.einsum("...i,ij,...j->...", error, weight, error)


def np_scaled_exp(s: np.ndarray, a: np.ndarray, min_reward: float = 0.01) -> np.ndarray:
    s_max = np.maximum(np.abs(STATE_LOW), np.abs(STATE_HIGH))
    a_max = np.maximum(np.abs(ACTION_LOW), np.abs(ACTION_HIGH))
    c_max = -math.log(min_reward) / (s_max @ Q3 @ s_max + a_max @ R2 @ a_max)
    return np.exp(-c_max * (np_quadratic(Q3, s) + np_quadratic(R2, a)))


def np_swing_up(s: np.ndarray, a: np.ndarray) -> np.ndarray:
    # c_pole=0.5, c_cart=1.0, c_act=0.01, c_theta_sq=2.0, c_theta_log=0.5, index_x=2, index_theta=0
    theta_sq = s[..., 0] ** 2
    pole = 2.0 * theta_sq + np.log(theta_sq + 0.5)
    return 10.0 - (0.5 * pole + 1.0 * np.abs(s[..., 2]) + 0.01 * (a**2).sum(-1))


def np_ant(s: np.ndarray, a: np.ndarray, x_last: np.ndarray) -> np.ndarray:
    healthy = np.isfinite(s).all(-1) & (s[..., 2] >= -0.5) & (s[..., 2] <= 0.5)
    forces = np.clip(s[..., 4:], -0.8, 0.8)
    return 1.3 * (s[..., 0] - x_last) / 0.05 + 1.0 * healthy - 0.5 * (a**2).sum(-1) - 0.5 * (forces**2).sum(-1)


def np_humanoid(s: np.ndarray, a: np.ndarray, x_last: np.ndarray) -> np.ndarray:
    healthy = (s[..., 2] > -0.5) & (s[..., 2] < 0.5)
    contact = np.clip(0.2 * (s[..., 4:] ** 2).sum(-1), -np.inf, 1.0)
    return 1.25 * (s[..., 0] - x_last) / 0.05 + 5.0 * healthy - 0.1 * (a**2).sum(-1) - contact


@dataclass(frozen=True)
class Case:
    """A reward to test, its input sizes and a closed-form numpy reference."""

    name: str
    make: Callable[[], RewardFunction]
    reference: Callable[..., np.ndarray] = field(repr=False)
    state_size: int = 3
    action_size: int = 2
    uses_action: bool = True
    stateful: bool = False
    differentiable: bool = True
    x_index: int = 0  # stateful rewards: position of the forward coordinate
    #: stateful rewards: the memory is the forward coordinate's last value (``x_last``); the others' memory is
    #: checked in their own test files (tests/rewards/test_velocity_terms.py)
    x_last_memory: bool = True

    def inputs(
        self, batch_shape: tuple[int, ...], dtype: torch.dtype = torch.float64, seed: int = 0
    ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
        """Return ``(state, action or None, init_state)`` of the given batch shape."""
        generator = torch.Generator().manual_seed(seed)
        state = torch.randn((*batch_shape, self.state_size), generator=generator, dtype=torch.float64)
        action = torch.randn((*batch_shape, self.action_size), generator=generator, dtype=torch.float64)
        init_state = torch.randn((*batch_shape, self.state_size), generator=generator, dtype=torch.float64)
        action = action.to(dtype) if self.uses_action or self.stateful else None
        return state.to(dtype), action, init_state.to(dtype)

    def expected(self, state: torch.Tensor, action: torch.Tensor | None, init_state: torch.Tensor) -> np.ndarray:
        s = state.double().numpy()
        a = None if action is None else action.double().numpy()
        if self.stateful:
            return self.reference(s, a, init_state.double().numpy())
        return self.reference(s, a)

    def run(self, reward: RewardFunction, state, action, init_state) -> tuple[torch.Tensor, Any]:
        """One value per row: ``reward(state, action)`` or ``step`` after ``reset(init_state)``."""
        if self.stateful:
            return reward.step(state, action, reward.reset(init_state))
        return reward(state, action), None


CASES = [
    Case(
        "constant",
        lambda: ConstantReward(-1.0),
        lambda s, a: np.full(s.shape[:-1], -1.0),
        uses_action=False,
        differentiable=False,
    ),
    Case("cosine", lambda: CosineReward(1), lambda s, a: np.cos(s[..., 1]), uses_action=False),
    Case(
        "shifted_cosine",
        lambda: ShiftedCosineReward(-1),
        lambda s, a: 0.5 * (np.cos(s[..., -1]) + 1.0),
        uses_action=False,
    ),
    Case(
        "absolute",
        lambda: AbsoluteErrorReward(Q_ABS, R_ABS),
        lambda s, a: -(np.abs(s) @ Q_ABS + np.abs(a) @ R_ABS),
    ),
    Case(
        "quadratic_full",
        lambda: QuadraticErrorReward(Q3, R2),
        lambda s, a: -(np_quadratic(Q3, s) + np_quadratic(R2, a)),
    ),
    Case(
        "quadratic_diag",
        lambda: QuadraticErrorReward(Q_DIAG, R_DIAG),
        lambda s, a: -(np_quadratic(Q_DIAG, s) + np_quadratic(R_DIAG, a)),
    ),
    Case(
        "quadratic_no_action",
        lambda: QuadraticErrorReward(Q3, None),
        lambda s, a: -np_quadratic(Q3, s),
        uses_action=False,
    ),
    Case(
        "exp_quadratic",
        lambda: ExpQuadraticErrorReward(Q3, R_DIAG),
        lambda s, a: np.exp(-(np_quadratic(Q3, s) + np_quadratic(R_DIAG, a))),
    ),
    Case(
        "scaled_exp_quadratic",
        lambda: ScaledExpQuadraticErrorReward(
            Q3, R2, Box(STATE_LOW, STATE_HIGH), Box(ACTION_LOW, ACTION_HIGH), min_reward=0.01
        ),
        np_scaled_exp,
    ),
    Case(
        "swing_up",
        lambda: SwingUpReward(
            c_pole=0.5, c_cart=1.0, c_act=0.01, c_theta_sq=2.0, c_theta_log=0.5, index_x=2, index_theta=0
        ),
        np_swing_up,
    ),
    Case(
        "cart_pole_swing_up",
        lambda: CartPoleSwingUpReward(0.7),
        lambda s, a: 0.7 * (1.0 - (np.abs(s[..., 1]) / np.pi) ** 2) + 0.3 * np.abs(s[..., 0]),
        uses_action=False,
    ),
    Case(
        "compound",
        lambda: CompoundReward(
            {"abs": AbsoluteErrorReward(Q_ABS, R_ABS), "cos": ShiftedCosineReward(1), "alive": ConstantReward(1.0)}
        ),
        lambda s, a: -(np.abs(s) @ Q_ABS + np.abs(a) @ R_ABS) + 0.5 * (np.cos(s[..., 1]) + 1.0) + 1.0,
    ),
    Case(
        "state_function",
        lambda: StateFunctionReward(rosenbrock, negate=True),
        lambda s, a: -np_rosenbrock(s),
        uses_action=False,
    ),
    Case("velocity", lambda: VelocityReward(1.25, index=2), lambda s, a: 1.25 * s[..., 2], uses_action=False),
    Case(
        "displacement",
        lambda: DisplacementReward(10.0, index=1, origin=0.3),
        lambda s, a: 10.0 * (s[..., 1] - 0.3),
        uses_action=False,
    ),
    Case("control_cost", lambda: ControlCostReward(0.3), lambda s, a: -0.3 * (a**2).sum(-1)),
    Case(
        "healthy",
        lambda: HealthyReward(5.0, index=[0, 2], low=[-0.5, -1.0], high=[0.5, 1.0], terminate_when_unhealthy=True),
        lambda s, a: 5.0 * ((np.abs(s[..., 0]) < 0.5) & (np.abs(s[..., 2]) < 1.0)),
        uses_action=False,
        differentiable=False,
    ),
    Case(
        "above_threshold",
        lambda: AboveThresholdIndicator(0.8, index=[0, 2], norm=True),
        lambda s, a: (np.sqrt(s[..., 0] ** 2 + s[..., 2] ** 2) > 0.8).astype(np.float64),
        uses_action=False,
        differentiable=False,
    ),
    Case(
        "contact_cost",
        lambda: ContactCostReward(0.5, start=1, force_range=(-0.8, 0.8), cost_range=(-math.inf, 0.3)),
        lambda s, a: -np.minimum(0.5 * (np.clip(s[..., 1:], -0.8, 0.8) ** 2).sum(-1), 0.3),
        uses_action=False,
    ),
    Case(
        "forward_velocity",
        lambda: ForwardVelocityReward(dt=0.05, index=1, forward_reward_weight=0.8, ctrl_cost_weight=0.1),
        lambda s, a, s0: 0.8 * (s[..., 1] - s0[..., 1]) / 0.05 - 0.1 * (a**2).sum(-1),
        stateful=True,
        x_index=1,
    ),
    Case(
        "ant",
        lambda: AntForwardReward(
            dt=0.05,
            contact_cost_weight=0.5,
            ctrl_cost_weight=0.5,
            healthy_reward=1.0,
            terminate_when_unhealthy=True,
            healthy_z_range=(-0.5, 0.5),
            contact_force_range=(-0.8, 0.8),
            forward_reward_weight=1.3,
            contact_forces_start=4,
        ),
        lambda s, a, s0: np_ant(s, a, s0[..., 0]),
        state_size=8,
        stateful=True,
    ),
    Case(
        "humanoid",
        lambda: HumanoidForwardReward(
            dt=0.05,
            contact_cost_weight=0.2,
            ctrl_cost_weight=0.1,
            forward_reward_weight=1.25,
            healthy_reward=5.0,
            terminate_when_unhealthy=False,
            healthy_z_range=(-0.5, 0.5),
            contact_cost_range=(-math.inf, 1.0),
            contact_forces_start=4,
        ),
        lambda s, a, s0: np_humanoid(s, a, s0[..., 0]),
        state_size=8,
        stateful=True,
    ),
    Case(
        "tolerance",
        lambda: ToleranceReward(bounds=([-0.5, 0.0], [0.5, math.inf]), margin=[1.0, 0.5], indices=[0, 2]),
        lambda s, a: (
            dm_rewards.tolerance(s[..., 0], (-0.5, 0.5), 1.0) * dm_rewards.tolerance(s[..., 2], (0.0, math.inf), 0.5)
        ),
        uses_action=False,
    ),
    Case(
        "product",
        lambda: ProductReward(
            {"alive": ConstantReward(2.0), "track": QuadraticErrorReward([1.0, 2.0, 0.5], [1.0, 0.5])}
        ),
        lambda s, a: 2.0 * -((s**2 * [1.0, 2.0, 0.5]).sum(-1) + (a**2 * [1.0, 0.5]).sum(-1)),
    ),
    Case(
        "affine",
        lambda: AffineReward(QuadraticErrorReward([1.0, 2.0, 0.5], [1.0, 0.5]), scale=0.5, offset=3.0),
        lambda s, a: 0.5 * -((s**2 * [1.0, 2.0, 0.5]).sum(-1) + (a**2 * [1.0, 0.5]).sum(-1)) + 3.0,
    ),
    Case(
        "exp_tracking",
        lambda: ExpTrackingReward(0.7, indices=[0, 2]),
        lambda s, a: np.exp(-(s[..., 0] ** 2 + s[..., 2] ** 2) / 0.49),
        uses_action=False,
    ),
    Case(
        "squared_sum",
        lambda: SquaredSumReward([1, 2]),
        lambda s, a: s[..., 1] ** 2 + s[..., 2] ** 2,
        uses_action=False,
    ),
    Case(
        "contact_count",
        lambda: ContactCountReward(0.3, [0, 1, 2]),
        lambda s, a: (s > 0.3).sum(-1).astype(np.float64),
        uses_action=False,
        differentiable=False,
    ),
    Case(
        "action_rate",  # the first step after a reset: the previous action is 0
        lambda: ActionRateReward(2),
        lambda s, a, s0: (a**2).sum(-1),
        stateful=True,
        x_last_memory=False,
    ),
    Case(
        "feet_air_time",  # the first step after a reset: no foot has been in the air, nothing lands
        lambda: FeetAirTimeReward(0.1, [0, 1], threshold=0.05, contact_threshold=0.0, command_indices=[2]),
        lambda s, a, s0: np.zeros(s.shape[:-1]),
        uses_action=False,
        stateful=True,
        differentiable=False,
        x_last_memory=False,
    ),
    Case(
        "compound_stateful",
        lambda: CompoundReward({"run": ForwardVelocityReward(dt=0.1, index=0), "alive": ConstantReward(1.0)}),
        lambda s, a, s0: (s[..., 0] - s0[..., 0]) / 0.1 - 0.1 * (a**2).sum(-1) + 1.0,
        stateful=True,
    ),
]
CASE_IDS = [case.name for case in CASES]
STATELESS = [case for case in CASES if not case.stateful]
STATEFUL = [case for case in CASES if case.stateful]
X_LAST = [case for case in STATEFUL if case.x_last_memory]


def test_cases_cover_every_reward_class() -> None:
    import torchtasks.rewards as rewards

    classes = {
        name
        for name in rewards.__all__
        if isinstance(getattr(rewards, name), type) and getattr(rewards, name) is not RewardFunction
    }
    assert {type(case.make()).__name__ for case in CASES} == classes
    for case in CASES:
        reward = case.make()
        assert reward.stateful is case.stateful, case.name
        assert reward.uses_action is case.uses_action, case.name


# --------------------------------------------------------------------------------------------------
# Values and batch shapes
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_matches_closed_form(case: Case) -> None:
    state, action, init_state = case.inputs((64,), seed=1)
    value, _ = case.run(case.make(), state, action, init_state)
    np.testing.assert_allclose(value.numpy(), case.expected(state, action, init_state), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("batch_shape", [(), (7,), (2, 3)], ids=["unbatched", "B7", "B2x3"])
@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_batch_shapes_match_a_loop_over_rows(case: Case, batch_shape: tuple[int, ...]) -> None:
    reward = case.make()
    state, action, init_state = case.inputs(batch_shape, seed=2)
    value, memory = case.run(reward, state, action, init_state)
    assert value.shape == batch_shape
    if case.stateful:
        assert memory.batch_size == batch_shape
    np.testing.assert_allclose(value.numpy(), case.expected(state, action, init_state), rtol=1e-12, atol=1e-12)
    rows = list(np.ndindex(batch_shape)) if batch_shape else [None]
    for row in rows:
        if row is None:  # the unbatched value must equal the value of a batch of one row
            single = case.run(reward, state[None], None if action is None else action[None], init_state[None])[0]
            assert single.shape == (1,)
            single, batched = single[0], value
        else:
            single = case.run(reward, state[row], None if action is None else action[row], init_state[row])[0]
            batched = value[row]
        assert single.shape == ()
        torch.testing.assert_close(single, batched, rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["float32", "float64"])
@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_dtype_and_device_follow_the_inputs(case: Case, dtype: torch.dtype) -> None:
    reward = case.make()
    state, action, init_state = case.inputs((5,), dtype=dtype, seed=3)
    value, memory = case.run(reward, state, action, init_state)
    assert value.dtype == dtype and value.device == state.device
    if case.stateful:
        for key, leaf in memory.items(include_nested=True, leaves_only=True):
            assert leaf.dtype == dtype and leaf.device == state.device, key
    np.testing.assert_allclose(value.double().numpy(), case.expected(state, action, init_state), rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("case", X_LAST, ids=[case.name for case in X_LAST])
def test_stateful_memory_is_functional(case: Case) -> None:
    """step returns new memory (x_last = the state's x) and leaves the given memory untouched."""
    reward = case.make()
    state, action, init_state = case.inputs((4,), seed=4)
    memory = reward.reset(init_state)
    before = memory.clone()
    _, new_memory = reward.step(state, action, memory)
    assert (memory == before).all()
    leaves = dict(new_memory.items(include_nested=True, leaves_only=True))
    assert leaves, "a stateful reward must keep memory"
    for key, leaf in leaves.items():
        assert key == "x_last" or key[-1] == "x_last"
        torch.testing.assert_close(leaf, state[..., case.x_index], rtol=0, atol=0)
    # the second step measures the velocity from the new memory (state -> state: zero velocity)
    value, _ = reward.step(state, action, new_memory)
    np.testing.assert_allclose(value.numpy(), case.expected(state, action, state), rtol=1e-12, atol=1e-12)


# --------------------------------------------------------------------------------------------------
# Gradients and compilation
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_gradcheck(case: Case) -> None:
    reward = case.make()
    state, action, init_state = case.inputs((3,), seed=5)
    if not case.differentiable:
        state.requires_grad_(True)
        value, _ = case.run(reward, state, action, init_state)
        if value.requires_grad:
            (grad,) = torch.autograd.grad(value.sum(), state, allow_unused=True)
            assert grad is None or not grad.any()
        return
    if case.stateful:
        inputs = (state, action, init_state)

        def fn(s: torch.Tensor, a: torch.Tensor, s0: torch.Tensor) -> torch.Tensor:
            return reward.step(s, a, reward.reset(s0))[0]

    elif case.uses_action:
        inputs = (state, action)

        def fn(s: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
            return reward(s, a)

    else:
        inputs = (state,)

        def fn(s: torch.Tensor) -> torch.Tensor:
            return reward(s, None)

    inputs = tuple(x.detach().requires_grad_(True) for x in inputs)
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("case", STATELESS, ids=[case.name for case in STATELESS])
def test_compile_fullgraph_stateless(case: Case) -> None:
    torch._dynamo.reset()
    reward = case.make()
    compiled = torch.compile(reward, fullgraph=True, backend=COMPILE_BACKEND)
    for seed, batch_shape in ((6, (5,)), (7, (2, 4))):
        state, action, _ = case.inputs(batch_shape, seed=seed)
        torch.testing.assert_close(compiled(state, action), reward(state, action), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("case", X_LAST, ids=[case.name for case in X_LAST])
def test_compile_fullgraph_stateful(case: Case) -> None:
    torch._dynamo.reset()
    reward = case.make()
    memory_key = "run" if isinstance(reward, CompoundReward) else None

    def step(s: torch.Tensor, a: torch.Tensor, x_last: torch.Tensor) -> tuple[torch.Tensor, TensorDict]:
        memory = TensorDict({"x_last": x_last}, batch_size=s.shape[:-1])
        if memory_key is not None:
            memory = TensorDict({memory_key: memory}, batch_size=s.shape[:-1])
        return reward.step(s, a, memory)

    compiled = torch.compile(step, fullgraph=True, backend=COMPILE_BACKEND)
    state, action, init_state = case.inputs((5,), seed=8)
    x_last = init_state[..., case.x_index]
    value, memory = compiled(state, action, x_last)
    eager_value, eager_memory = step(state, action, x_last)
    torch.testing.assert_close(value, eager_value, rtol=1e-12, atol=1e-12)
    assert (memory == eager_memory).all()
    np.testing.assert_allclose(value.numpy(), case.expected(state, action, init_state), rtol=1e-12, atol=1e-12)


# --------------------------------------------------------------------------------------------------
# Hypothesis properties
# --------------------------------------------------------------------------------------------------

_floats = st.floats(-3.0, 3.0, allow_nan=False, allow_infinity=False)


@st.composite
def psd_weight(draw: st.DrawFn, size: int, *, full: bool | None = None, positive: bool = False) -> np.ndarray:
    """A PSD weight: a full ``A Aᵀ`` (+ 0.1 I if positive) or a non-negative diagonal vector."""
    full = draw(st.booleans()) if full is None else full
    if full:
        factor = draw(hnp.arrays(np.float64, (size, size), elements=_floats))
        return factor @ factor.T + (0.1 * np.eye(size) if positive else 0.0)
    low = 0.05 if positive else 0.0
    return draw(hnp.arrays(np.float64, (size,), elements=st.floats(low, 5.0)))


@st.composite
def weights_and_errors(draw: st.DrawFn, error_bound: float) -> tuple[np.ndarray, ...]:
    n, m = draw(st.integers(1, 4)), draw(st.integers(1, 3))
    batch = draw(st.integers(1, 5))
    elements = st.floats(-error_bound, error_bound, allow_nan=False)
    e_s = draw(hnp.arrays(np.float64, (batch, n), elements=elements))
    e_a = draw(hnp.arrays(np.float64, (batch, m), elements=elements))
    return draw(psd_weight(n)), draw(psd_weight(m)), e_s, e_a


@settings(max_examples=50, deadline=None)
@given(weights_and_errors(error_bound=10.0))
def test_quadratic_error_reward_is_never_positive(data: tuple[np.ndarray, ...]) -> None:
    Q, R, e_s, e_a = data
    value = QuadraticErrorReward(Q, R)(torch.from_numpy(e_s), torch.from_numpy(e_a)).numpy()
    scale = 1.0 + np.abs(Q).sum() * (e_s**2).sum(-1) + np.abs(R).sum() * (e_a**2).sum(-1)
    assert (value <= 1e-12 * scale).all()
    np.testing.assert_allclose(-value, np_quadratic(Q, e_s) + np_quadratic(R, e_a), rtol=1e-9, atol=1e-9 * scale.max())


@settings(max_examples=50, deadline=None)
@given(weights_and_errors(error_bound=4.0))
def test_exp_quadratic_error_reward_lies_in_unit_interval(data: tuple[np.ndarray, ...]) -> None:
    Q, R, e_s, e_a = data
    value = ExpQuadraticErrorReward(Q, R)(torch.from_numpy(e_s), torch.from_numpy(e_a)).numpy()
    cost = np_quadratic(Q, e_s) + np_quadratic(R, e_a)
    assert ((value >= 0.0) & (value <= 1.0)).all()
    assert (value[cost < 700.0] > 0.0).all()  # exp(-700) is still a normal float64
    np.testing.assert_allclose(value, np.exp(-cost), rtol=1e-9, atol=1e-300)


@st.composite
def boxes_and_weights(draw: st.DrawFn) -> tuple[Any, ...]:
    n, m = draw(st.integers(1, 4)), draw(st.integers(1, 3))
    full = draw(st.booleans())

    def box(size: int) -> tuple[np.ndarray, np.ndarray]:
        low = draw(hnp.arrays(np.float64, (size,), elements=st.floats(-5.0, 5.0)))
        width = draw(hnp.arrays(np.float64, (size,), elements=st.floats(0.1, 5.0)))
        return low, low + width

    min_reward = draw(st.floats(1e-6, 1.0 - 1e-6, exclude_min=True, exclude_max=True))
    signs = draw(hnp.arrays(np.float64, (n + m,), elements=st.sampled_from([-1.0, 1.0])))
    if full:  # the worst case of a full form is at ±bound with ONE sign (mixed signs may cost less)
        signs = np.full(n + m, signs[0])
    Q = draw(psd_weight(n, full=full, positive=True))
    R = draw(psd_weight(m, full=full, positive=True))
    return box(n), box(m), Q, R, min_reward, signs


@settings(max_examples=50, deadline=None)
@given(boxes_and_weights())
def test_scaled_exp_reward_is_min_reward_at_the_worst_case(data: tuple[Any, ...]) -> None:
    (s_low, s_high), (a_low, a_high), Q, R, min_reward, signs = data
    reward = ScaledExpQuadraticErrorReward(Q, R, Box(s_low, s_high), Box(a_low, a_high), min_reward=min_reward)
    n = len(s_low)
    s_max = np.maximum(np.abs(s_low), np.abs(s_high))
    a_max = np.maximum(np.abs(a_low), np.abs(a_high))
    e_s = torch.from_numpy(np.stack([signs[:n] * s_max, np.zeros(n)]))
    e_a = torch.from_numpy(np.stack([signs[n:] * a_max, np.zeros(len(a_low))]))
    worst, zero = reward(e_s, e_a).tolist()
    assert worst == pytest.approx(min_reward, rel=1e-9)
    assert zero == 1.0


# --------------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------------

_BOX3, _BOX2 = Box(STATE_LOW, STATE_HIGH), Box(ACTION_LOW, ACTION_HIGH)
_S, _A = torch.zeros(4, 3), torch.zeros(4, 2)

VALIDATION = {
    "Q_not_square": (lambda: QuadraticErrorReward(np.ones((2, 3)), np.eye(2)), r"\bQ\b"),
    "Q_3d": (lambda: QuadraticErrorReward(np.ones((2, 2, 2)), np.eye(2)), r"\bQ\b"),
    "R_not_square": (lambda: ExpQuadraticErrorReward(np.eye(3), np.ones((1, 2))), r"\bR\b"),
    "Q_negative_eigenvalue": (lambda: QuadraticErrorReward([[1.0, 2.0], [2.0, 1.0]], np.eye(1)), r"\bQ\b"),
    "R_negative_eigenvalue": (lambda: ExpQuadraticErrorReward(np.eye(2), [[1.0, 2.0], [2.0, 1.0]]), r"\bR\b"),
    "scaled_Q_negative_eigenvalue": (
        lambda: ScaledExpQuadraticErrorReward(-np.eye(3), np.eye(2), _BOX3, _BOX2),
        r"\bQ\b",
    ),
    "Q_negative_diagonal": (lambda: QuadraticErrorReward([1.0, -0.5], None), r"\bQ\b"),
    "R_negative_diagonal": (lambda: QuadraticErrorReward([1.0], [-0.5]), r"\bR\b"),
    "q_negative": (lambda: AbsoluteErrorReward([1.0, -1.0], [1.0]), r"\bq\b"),
    "r_negative": (lambda: AbsoluteErrorReward([1.0], [-1.0]), r"\br\b"),
    "q_nan": (lambda: AbsoluteErrorReward([1.0, math.nan], [1.0]), r"\bq\b"),
    "Q_nan": (lambda: QuadraticErrorReward([[1.0, math.nan], [math.nan, 1.0]], np.eye(1)), r"\bQ\b"),
    "R_nan": (lambda: ExpQuadraticErrorReward(np.eye(1), [math.nan]), r"\bR\b"),
    "value_nan": (lambda: ConstantReward(math.nan), r"\bvalue\b"),
    "factor_nan": (lambda: CartPoleSwingUpReward(math.nan), r"\bfactor\b"),
    "c_pole_nan": (lambda: SwingUpReward(c_pole=math.nan), r"\bc_pole\b"),
    "dt_nan": (lambda: ForwardVelocityReward(dt=math.nan), r"\bdt\b"),
    "healthy_z_range_nan": (lambda: AntForwardReward(0.05, healthy_z_range=(math.nan, 1.0)), "healthy_z_range"),
    "compound_empty_list": (lambda: CompoundReward([]), r"\brewards\b"),
    "compound_empty_dict": (lambda: CompoundReward({}), r"\brewards\b"),
    "scaled_state_space_size": (
        lambda: ScaledExpQuadraticErrorReward(np.eye(2), np.eye(2), _BOX3, _BOX2),
        r"\bstate_space\b",
    ),
    "quadratic_state_size": (lambda: QuadraticErrorReward(np.eye(2), np.eye(2))(_S, _A), r"\berror_state\b"),
    "quadratic_action_size": (lambda: QuadraticErrorReward(Q3, np.eye(3))(_S, _A), r"\berror_action\b"),
    "quadratic_action_missing": (lambda: QuadraticErrorReward(Q3, R2)(_S, None), r"\berror_action\b"),
    "quadratic_batch_mismatch": (lambda: QuadraticErrorReward(Q3, R2)(_S, _A[:3]), "batch shape"),
    "exp_state_size": (lambda: ExpQuadraticErrorReward(Q_DIAG, None)(torch.zeros(4, 4), None), r"\berror_state\b"),
    "scaled_action_size": (
        lambda: ScaledExpQuadraticErrorReward(Q3, R2, _BOX3, _BOX2)(_S, torch.zeros(4, 3)),
        r"\berror_action\b",
    ),
    "absolute_state_size": (lambda: AbsoluteErrorReward([1.0, 1.0], [1.0, 1.0])(_S, _A), r"\berror_state\b"),
    "absolute_action_size": (lambda: AbsoluteErrorReward(Q_ABS, [1.0])(_S, _A), r"\berror_action\b"),
    "cosine_index_out_of_range": (lambda: CosineReward(3)(_S, None), r"\bindex\b"),
    "swing_up_index_out_of_range": (lambda: SwingUpReward(index_theta=5)(_S, _A[:, :1]), r"\bindex_theta\b"),
    "swing_up_action_missing": (lambda: SwingUpReward()(_S, None), r"\berror_action\b"),
    "cart_pole_state_too_short": (lambda: CartPoleSwingUpReward()(torch.zeros(4, 1), None), r"\berror_state\b"),
    "state_function_wrong_output": (
        lambda: StateFunctionReward(lambda s: s)(_S, None),
        r"\bfn\b",
    ),
    "state_function_not_callable": (lambda: StateFunctionReward(3.0), r"\bfn\b"),
    "ant_state_too_short": (
        lambda: AntForwardReward(0.05).step(_S, _A, AntForwardReward(0.05).reset(_S)),
        r"\bcontact_forces_start\b",
    ),
    "forward_velocity_batch_mismatch": (
        lambda: ForwardVelocityReward(0.05).step(_S, _A[:3], ForwardVelocityReward(0.05).reset(_S)),
        "batch shape",
    ),
    "forward_velocity_no_memory": (
        lambda: ForwardVelocityReward(0.05).step(_S, _A, TensorDict({}, batch_size=[4])),
        r"\bmemory\b",
    ),
    "wrong_input_type": (lambda: QuadraticErrorReward(Q3, R2)(np.zeros((4, 3)), _A), r"\berror_state\b"),
    "integer_input": (lambda: CosineReward(0)(torch.zeros(4, 3, dtype=torch.long), None), r"\berror_state\b"),
}


@pytest.mark.parametrize("min_reward", [0.0, 1.0, -0.5, 1.5, math.nan, math.inf])
def test_scaled_exp_rejects_min_reward_outside_the_open_unit_interval(min_reward: float) -> None:
    with pytest.raises((ValueError, TypeError), match=r"\bmin_reward\b"):
        ScaledExpQuadraticErrorReward(Q3, R2, _BOX3, _BOX2, min_reward=min_reward)


@pytest.mark.parametrize("make", list(VALIDATION.values()), ids=list(VALIDATION))
def test_invalid_arguments_raise_and_name_the_argument(make: tuple[Callable[[], Any], str]) -> None:
    build, match = make
    with pytest.raises((ValueError, TypeError), match=match):
        build()


# --------------------------------------------------------------------------------------------------
# Learnable weights
# --------------------------------------------------------------------------------------------------

LEARNABLE = {
    "quadratic": (lambda learnable: QuadraticErrorReward(Q3, R2, learnable=learnable), ("Q", "R")),
    "exp_quadratic": (lambda learnable: ExpQuadraticErrorReward(Q_DIAG, R2, learnable=learnable), ("Q", "R")),
    "scaled_exp_quadratic": (
        lambda learnable: ScaledExpQuadraticErrorReward(Q3, R_DIAG + 0.1, _BOX3, _BOX2, learnable=learnable),
        ("Q", "R"),
    ),
    "absolute": (lambda learnable: AbsoluteErrorReward(Q_ABS, R_ABS, learnable=learnable), ("q", "r")),
}


@pytest.mark.parametrize("name", list(LEARNABLE))
def test_weights_are_buffers_by_default(name: str) -> None:
    make, weights = LEARNABLE[name]
    reward = make(False)
    assert list(reward.parameters()) == []
    buffers = dict(reward.named_buffers())
    for weight in weights:
        assert weight in buffers and weight in reward.state_dict()
        assert buffers[weight].dtype == torch.float64


@pytest.mark.parametrize("name", list(LEARNABLE))
def test_learnable_weights_are_parameters_with_gradients(name: str) -> None:
    make, weights = LEARNABLE[name]
    reward = make(True)
    parameters = dict(reward.named_parameters())
    assert set(parameters) == set(weights)
    assert all(isinstance(parameter, nn.Parameter) for parameter in parameters.values())
    e_s = torch.randn(6, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(9))
    e_a = torch.randn(6, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(10))
    reward(e_s, e_a).sum().backward()
    for weight in weights:
        grad = parameters[weight].grad
        assert grad is not None and torch.isfinite(grad).all() and grad.abs().sum() > 0, weight
    if name == "quadratic":  # d/dQ Σ -(eᵀQe) = -Σ e eᵀ
        torch.testing.assert_close(parameters["Q"].grad, -torch.einsum("bi,bj->ij", e_s, e_s))
        torch.testing.assert_close(parameters["R"].grad, -torch.einsum("bi,bj->ij", e_a, e_a))
    if name == "absolute":  # d/dq Σ -(|e|·q) = -Σ |e|
        torch.testing.assert_close(parameters["q"].grad, -e_s.abs().sum(0))
        torch.testing.assert_close(parameters["r"].grad, -e_a.abs().sum(0))


# --------------------------------------------------------------------------------------------------
# CompoundReward and StateFunctionReward
# --------------------------------------------------------------------------------------------------


def test_compound_with_a_dict_keeps_names_and_terms_sum_to_the_total() -> None:
    reward = CompoundReward(
        {"track": QuadraticErrorReward(Q3, R2), "angle": CosineReward(0), "alive": ConstantReward(1.0)}
    )
    assert reward.term_names == ("track", "angle", "alive")
    e_s = torch.randn(5, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(11))
    e_a = torch.randn(5, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(12))
    terms = reward.terms(e_s, e_a)
    assert list(terms) == ["track", "angle", "alive"]
    s, a = e_s.numpy(), e_a.numpy()
    np.testing.assert_allclose(terms["track"].numpy(), -(np_quadratic(Q3, s) + np_quadratic(R2, a)), rtol=1e-12)
    np.testing.assert_allclose(terms["angle"].numpy(), np.cos(s[:, 0]), rtol=1e-12)
    np.testing.assert_allclose(terms["alive"].numpy(), np.ones(5))
    total = reward(e_s, e_a)
    torch.testing.assert_close(total, terms["track"] + terms["angle"] + terms["alive"], rtol=1e-14, atol=1e-14)
    value, memory = reward.step(e_s, e_a, reward.reset(e_s))
    torch.testing.assert_close(value, total, rtol=0, atol=0)
    assert memory.batch_size == (5,)


def test_compound_with_a_list_names_terms_in_order() -> None:
    reward = CompoundReward([ConstantReward(2.0), ConstantReward(-0.5), CosineReward(1)])
    assert reward.term_names == ("term0", "term1", "term2")
    state = torch.zeros(2, 3)
    terms = reward.terms(state, None)
    assert list(terms) == ["term0", "term1", "term2"]
    assert terms["term0"].tolist() == [2.0, 2.0] and terms["term1"].tolist() == [-0.5, -0.5]
    assert reward(state, None).tolist() == [2.5, 2.5]


def test_compound_with_a_forward_velocity_term_steps_with_memory() -> None:
    run = ForwardVelocityReward(dt=0.1, index=0, forward_reward_weight=2.0, ctrl_cost_weight=0.5)
    reward = CompoundReward({"run": run, "alive": ConstantReward(1.0)})  # Pyrado's HopperSim reward
    assert reward.stateful
    init_state = torch.tensor([[0.0, 5.0], [1.0, 5.0]], dtype=torch.float64)
    states = [torch.tensor([[0.2, 0.0], [0.9, 0.0]]).double(), torch.tensor([[0.3, 0.0], [0.9, 0.0]]).double()]
    action = torch.tensor([[1.0], [2.0]], dtype=torch.float64)
    memory = reward.reset(init_state)
    assert memory["run", "x_last"].tolist() == [0.0, 1.0]
    with pytest.raises(TypeError, match="step_terms"):
        reward.terms(states[0], action)
    x_last = init_state[:, 0].numpy()
    for state in states:
        terms, new_memory = reward.step_terms(state, action, memory)
        x = state[:, 0].numpy()
        np.testing.assert_allclose(terms["run"].numpy(), 2.0 * (x - x_last) / 0.1 - 0.5 * np.array([1.0, 4.0]))
        assert terms["alive"].tolist() == [1.0, 1.0]
        value, stepped = reward.step(state, action, memory)
        torch.testing.assert_close(value, terms["run"] + terms["alive"], rtol=0, atol=0)
        assert (stepped == new_memory).all()
        np.testing.assert_allclose(new_memory["run", "x_last"].numpy(), x)
        memory, x_last = new_memory, x


def test_compound_fails_when_a_term_fails() -> None:
    ant = AntForwardReward(0.05, terminate_when_unhealthy=True, contact_forces_start=4)
    reward = CompoundReward({"ant": ant, "alive": ConstantReward(1.0)})
    assert reward.can_fail
    state = torch.zeros(3, 8, dtype=torch.float64)
    state[:, 2] = torch.tensor([0.5, 0.1, 1.5])  # Ant-v5 default healthy range [0.2, 1.0]
    assert reward.has_failed(state).tolist() == [False, True, True]
    assert not CompoundReward([ConstantReward(1.0)]).has_failed(state).any()


def test_healthy_reward_only_when_healthy_and_failure_only_with_terminate() -> None:
    """Decision 18 at the boundaries: Ant's range is closed and needs finite states, Humanoid's is open."""
    z = torch.tensor([0.2, 1.0, 0.19, 1.01, math.nan, 0.5], dtype=torch.float64)
    ant_state = torch.zeros(6, 30, dtype=torch.float64)
    ant_state[:, 2] = z
    ant_state[5, 10] = math.inf  # z fine, but a non-finite entry is unhealthy for the Ant
    ant_healthy = [True, True, False, False, False, False]
    humanoid_state = torch.zeros(6, 295, dtype=torch.float64)
    humanoid_state[:, 2] = torch.tensor([1.0, 1.5, 2.0, 0.99, math.nan, 1.999], dtype=torch.float64)
    humanoid_healthy = [False, True, False, False, False, True]  # Humanoid-v5 default range (1, 2), open
    for cls, state, healthy, bonus in (
        (AntForwardReward, ant_state, ant_healthy, 1.0),
        (HumanoidForwardReward, humanoid_state, humanoid_healthy, 5.0),
    ):
        for terminate in (False, True):
            reward = cls(0.05, terminate_when_unhealthy=terminate, ctrl_cost_weight=0.0, contact_cost_weight=0.0)
            value, _ = reward.step(state, torch.zeros(6, 1, dtype=torch.float64), reward.reset(state))
            assert value.tolist() == [bonus * h for h in healthy], (cls.__name__, terminate)
            failed = [terminate and not h for h in healthy]
            assert reward.has_failed(state).tolist() == failed, (cls.__name__, terminate)
            assert reward.can_fail is terminate


@pytest.mark.parametrize("name", ["forward_velocity", "ant", "humanoid"])
def test_locomotion_step_terms_are_named_and_sum_to_the_step_value(name: str) -> None:
    case = next(case for case in CASES if case.name == name)
    reward = case.make()
    state, action, init_state = case.inputs((6,), seed=14)
    memory = reward.reset(init_state)
    terms, new_memory = reward.step_terms(state, action, memory)
    assert tuple(terms) == reward.term_names
    value, stepped = reward.step(state, action, memory)
    torch.testing.assert_close(sum(terms.values()), value, rtol=1e-14, atol=1e-14)
    assert (stepped == new_memory).all()
    s, a, s0 = state.numpy(), action.numpy(), init_state.numpy()
    index = case.x_index
    weight = {"forward_velocity": 0.8, "ant": 1.3, "humanoid": 1.25}[name]
    np.testing.assert_allclose(terms["forward"].numpy(), weight * (s[:, index] - s0[:, index]) / 0.05, rtol=1e-12)
    ctrl_weight = {"forward_velocity": 0.1, "ant": 0.5, "humanoid": 0.1}[name]
    np.testing.assert_allclose(terms["ctrl"].numpy(), -ctrl_weight * (a**2).sum(-1), rtol=1e-12)
    if name == "ant":
        healthy = (s[:, 2] >= -0.5) & (s[:, 2] <= 0.5)
        np.testing.assert_allclose(terms["healthy"].numpy(), 1.0 * healthy)
        np.testing.assert_allclose(terms["contact"].numpy(), -0.5 * (np.clip(s[:, 4:], -0.8, 0.8) ** 2).sum(-1))


@pytest.mark.parametrize("negate", [False, True])
def test_state_function_reward_sign(negate: bool) -> None:
    state = torch.randn(4, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(13))
    expected = np_rosenbrock(state.numpy())
    value = StateFunctionReward(rosenbrock, negate=negate)(state, None).numpy()
    np.testing.assert_allclose(value, -expected if negate else expected, rtol=1e-12)
    assert StateFunctionReward(rosenbrock).negate is True  # Pyrado's behaviour is the default


def test_action_free_terms_accept_an_action() -> None:
    """A term without action weight ignores a given action, so it mixes with action-dependent terms."""
    e_s = torch.ones(2, 1, dtype=torch.float64)
    e_a = torch.full((2, 1), 3.0, dtype=torch.float64)
    reward = CompoundReward({"track": QuadraticErrorReward([1.0], [1.0]), "extra": QuadraticErrorReward([2.0], None)})
    assert reward(e_s, e_a).tolist() == [-12.0, -12.0]
    assert AbsoluteErrorReward([3.0], None)(e_s, e_a).tolist() == [-3.0, -3.0]
    assert ExpQuadraticErrorReward([0.5], None)(e_s, torch.ones(2, 4)).tolist() == [math.exp(-0.5)] * 2


def test_scaled_exp_with_infinite_bounds_is_one_for_a_diagonal_weight() -> None:
    reward = ScaledExpQuadraticErrorReward(Q_DIAG, R_DIAG, Box.unbounded(3), _BOX2)
    assert float(reward.c_max) == 0.0
    assert reward(torch.full((2, 3), 100.0), torch.ones(2, 2)).tolist() == [1.0, 1.0]


def test_scaled_exp_with_infinite_bounds_is_one_for_a_full_weight() -> None:
    """A negative off-diagonal weight must not turn C_max into inf - inf = NaN."""
    for state_box in (Box.unbounded(3), Box([-1.0, -math.inf, 0.0], [1.0, 2.0, 1.0])):
        reward = ScaledExpQuadraticErrorReward(Q3, R2, state_box, _BOX2)
        assert float(reward.c_max) == 0.0
        assert reward(torch.ones(2, 3), torch.ones(2, 2)).tolist() == [1.0, 1.0]
