"""Tasks are differentiable, compile to one graph, and follow dtype/device; copies and state dicts work.

* gradcheck (float64) of step rewards w.r.t. state and action (and of a state-dependent final
  reward w.r.t. the state), plus the exact pattern of which input entries the gradient reaches;
* ``torch.compile(fullgraph=True)`` of one whole transition (step reward, done, final reward) of
  every task class and predefined factory agrees with eager, and dynamo reports no graph break.
  Most cases use the ``aot_eager`` backend (dynamo + AOTAutograd tracing, eager kernels: results
  must be bitwise equal); a few representative ones use the default inductor backend, whose fused
  kernels may reorder float64 arithmetic (compared with rtol = atol = 1e-12);
* float32 inputs give float32 outputs, ``.float()`` / ``.double()`` / ``.to(meta)`` move the
  constants, ``copy.deepcopy`` and ``state_dict`` round trips.
"""

from __future__ import annotations

import copy
import functools
import importlib.util
import math

import pytest
import torch
from tensordict import TensorDictBase

from task_trees import (
    assert_memory_equal,
    assert_same,
    class_cases,
    full_spec,
    make_drive_data,
    memory_leaves,
    predefined_cases,
)
from torchtasks.rewards import ExpQuadraticErrorReward, ForwardVelocityReward, QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import (
    BestStateFinalRewardTask,
    DesiredStateTask,
    FinalRewardMode,
    FinalRewardTask,
    GoallessTask,
    MaskedTask,
    ParallelTasks,
    RadiallySymmetricDesiredStateTask,
    SequentialTasks,
    proximity_succeeded,
)


def _control_suite_cases() -> dict:
    """The Control Suite's rewards (products of tolerances, affine maps, weighted sums, means); needs mujoco."""
    if importlib.util.find_spec("mujoco") is None:
        return {}
    from torchtasks.envs.control_suite import control_suite_task

    names = ("walker-walk", "humanoid-stand")  # between them every reward kind of the suite
    return {f"control_suite[{name}]": functools.partial(control_suite_task, name) for name in names}


CASES = {**class_cases(), **predefined_cases(), **_control_suite_cases()}
#: representative cases compiled with the default (inductor) backend: a leaf, a wrapper over a
#: stateful reward, and a nested Sequential/Parallel/Masked/FinalReward tree
INDUCTOR_CASES = ("desired_state", "final_state_goalless", "sequential")
#: the xdist group of every test that compiles with Inductor (here, test_shaping.py, test_transform_env.py): the
#: first Inductor compilation in a test process costs ~7 s more than the next ones (Inductor's imports and C++
#: toolchain checks), so one worker pays it
INDUCTOR = pytest.mark.xdist_group("inductor")
N_ENVS = 6
REMAINING = torch.tensor([0, 1, 2, 5, 3, 7])


def _near(threshold: float) -> functools.partial:
    return functools.partial(proximity_succeeded, threshold=threshold)


def _transition(task):
    """One whole transition through the private (unchecked) methods, the way the transform runs it."""

    def step(state, action, next_state, memory, remaining):
        reward, memory = task._step_reward(state, action, memory, remaining)
        done = task._is_done(next_state, memory)
        final, memory = task._final_reward(next_state, memory, remaining, done)
        return reward + final, done, memory

    return step


def _rollout_inputs(task, seed: int = 0, steps: int = 2):
    data = make_drive_data(task, N_ENVS, steps, seed)
    return data, task.reset(data.states[0])


# ------------------------------------------------------------------------------------ torch.compile
@pytest.mark.parametrize(
    "name", [pytest.param(name, marks=[INDUCTOR] if name in INDUCTOR_CASES else []) for name in sorted(CASES)]
)
def test_compiled_transition_matches_eager(name):
    torch._dynamo.reset()
    task = CASES[name]()
    step = _transition(task)
    inductor = name in INDUCTOR_CASES
    compiled = torch.compile(step, fullgraph=True, backend="inductor" if inductor else "aot_eager")
    tolerance = {"rtol": 1e-12, "atol": 1e-12} if inductor else {"rtol": 0.0, "atol": 0.0}
    data, memory = _rollout_inputs(task, steps=3)
    # one eager step first: the compiled function sees the memory of a running episode (whose
    # layout differs from reset memory, e.g. x_last is then no longer a strided view: that
    # would cost a second compilation)
    _, _, memory = step(data.states[0], data.actions[0], data.states[1], memory, REMAINING)
    eager_memory = compiled_memory = memory
    for t in (1, 2):
        args = (data.states[t], data.actions[t], data.states[t + 1])
        eager_value, eager_done, eager_memory = step(*args, eager_memory, REMAINING)
        value, done, compiled_memory = compiled(*args, compiled_memory, REMAINING)
        torch.testing.assert_close(value, eager_value, equal_nan=True, **tolerance)
        assert_same(done, eager_done, f"{name} done (step {t})")
        assert isinstance(compiled_memory, TensorDictBase)
        compiled_leaves, eager_leaves = memory_leaves(compiled_memory), memory_leaves(eager_memory)
        assert set(compiled_leaves) == set(eager_leaves)
        for key, expected in eager_leaves.items():
            torch.testing.assert_close(compiled_leaves[key], expected, equal_nan=True, msg=str(key), **tolerance)


# every task class and factory (the nested trees are left to the fullgraph compile above: their
# explain run alone takes ~5 s each)
@pytest.mark.parametrize("name", sorted(name for name in CASES if not name.startswith("nested")))
def test_dynamo_finds_no_graph_break(name):
    torch._dynamo.reset()
    task = CASES[name]()
    data, memory = _rollout_inputs(task)
    explanation = torch._dynamo.explain(_transition(task))(
        data.states[0], data.actions[0], data.states[1], memory, REMAINING
    )
    assert explanation.graph_break_count == 0, explanation.break_reasons
    assert explanation.graph_count == 1


def test_compiled_public_methods_match_eager():
    """The validating public methods also compile to one graph (checks are on shapes only)."""
    torch._dynamo.reset()
    task = CASES["best_state"]()

    def public_step(state, action, memory, remaining):
        reward, memory = task.step_reward(state, action, memory, remaining)
        done = task.is_done(state, memory)
        success = task.has_succeeded(state, memory)
        failure = task.has_failed(state, memory)
        final, memory = task.final_reward(state, memory, remaining, done)
        return reward + final, done, success, failure, memory

    compiled = torch.compile(public_step, fullgraph=True, backend="aot_eager")
    data, memory = _rollout_inputs(task, seed=4)
    expected = public_step(data.states[1], data.actions[0], memory, REMAINING)
    actual = compiled(data.states[1], data.actions[0], memory, REMAINING)
    for got, want in zip(actual[:4], expected[:4], strict=True):
        assert_same(got, want, "public step")
    assert_memory_equal(actual[4], expected[4], "public step")


# ------------------------------------------------------------------------------------ autodiff
def _inputs(seed: int, n_state: int = 4, n_action: int = 2, batch: int = 3, scale: float = 0.5):
    generator = torch.Generator().manual_seed(seed)
    state = scale * torch.randn(batch, n_state, generator=generator, dtype=torch.float64)
    action = scale * torch.randn(batch, n_action, generator=generator, dtype=torch.float64)
    return state.requires_grad_(), action.requires_grad_()


def _step_fn(task, memory):
    return lambda state, action: task.step_reward(state, action, memory, 3)[0]


def _nonzero_pattern(fn, state, action):
    grad_state, grad_action = torch.autograd.grad(fn(state, action).sum(), (state, action), allow_unused=True)
    grad_state = torch.zeros_like(state) if grad_state is None else grad_state
    grad_action = torch.zeros_like(action) if grad_action is None else grad_action
    return grad_state != 0, grad_action != 0


def _goal(spec=None, threshold: float = 0.05, action_weight=(0.5, 0.25)) -> DesiredStateTask:
    spec = full_spec() if spec is None else spec
    n = spec.state_size
    Q = 0.5 * torch.eye(n, dtype=torch.float64) + 0.125
    des = [0.5, -0.25, 0.0, 0.125][:n]
    return DesiredStateTask(
        spec, des, QuadraticErrorReward(Q, list(action_weight)[: spec.action_size]), _near(threshold)
    )


def _assert_pattern(fn, state, action, state_pattern, action_pattern):
    got_state, got_action = _nonzero_pattern(fn, state, action)
    expected_state = torch.tensor(state_pattern).expand_as(got_state)
    expected_action = torch.tensor(action_pattern).expand_as(got_action)
    assert torch.equal(got_state, expected_state), got_state
    assert torch.equal(got_action, expected_action), got_action


def test_desired_state_gradcheck_and_closed_form_gradient():
    task = _goal()
    state, action = _inputs(0)
    memory = task.reset(state.detach())
    fn = _step_fn(task, memory)
    assert torch.autograd.gradcheck(fn, (state, action))
    _assert_pattern(fn, state, action, [True] * 4, [True, True])
    # reward = -(eᵀQe + aᵀRa) with e = s* - s:  d/ds = 2Qe, d/da = -2Ra
    grad_state, grad_action = torch.autograd.grad(fn(state, action).sum(), (state, action))
    Q = 0.5 * torch.eye(4, dtype=torch.float64) + 0.125
    error = torch.tensor([0.5, -0.25, 0.0, 0.125], dtype=torch.float64) - state.detach()
    torch.testing.assert_close(grad_state, 2 * error @ Q, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(grad_action, -2 * action.detach() * torch.tensor([0.5, 0.25]), rtol=1e-12, atol=1e-12)


def test_radially_symmetric_gradcheck_away_from_the_wrap():
    reward = ExpQuadraticErrorReward([0.25, 0.5, 0.25, 0.125], [0.125, 0.125])
    task = RadiallySymmetricDesiredStateTask(full_spec(), [0.5, 3.0, -2.5, 0.0], reward, [1, "c"], [2 * math.pi, 3.0])
    state, action = _inputs(1)
    with torch.no_grad():  # wrapped errors: index 1 near -0.3 - 2π·0, index 2 near 0.5 - 3·(-1): far from ±m/2
        state[:, 1] = 3.3 + 0.1 * state[:, 1]
        state[:, 2] = 0.5 + 0.1 * state[:, 2]
    memory = task.reset(state.detach())
    error = task.state_error(state.detach(), memory)
    assert (error[:, 1].abs() < 0.5 * math.pi).all() and (error[:, 2].abs() < 1.0).all()
    fn = _step_fn(task, memory)
    assert torch.autograd.gradcheck(fn, (state, action))
    _assert_pattern(fn, state, action, [True] * 4, [True, True])


def test_masked_task_gradient_reaches_only_the_selected_entries():
    spec = full_spec()
    inner = _goal(EnvSpec(spec.state_space.select(["c", 0]), spec.action_space.select(["v"])), action_weight=(0.5,))
    task = MaskedTask(spec, inner, ["c", 0], ["v"])
    state, action = _inputs(2)
    fn = _step_fn(task, task.reset(state.detach()))
    assert torch.autograd.gradcheck(fn, (state, action))
    _assert_pattern(fn, state, action, [True, False, True, False], [False, True])


@pytest.mark.parametrize(
    "mode",
    [
        FinalRewardMode(state_dependent=True),
        FinalRewardMode(state_dependent=True, time_dependent=True),
        FinalRewardMode(state_dependent=True, always_positive=True),
    ],
)
def test_state_dependent_final_reward_gradcheck_wrt_state(mode):
    task = FinalRewardTask(_goal(threshold=100.0), mode, factor=3.0)  # threshold: every env succeeds
    state, _ = _inputs(3)
    memory = task.reset(state.detach())
    done = torch.tensor([True, True, True])

    def final(state):
        return task.final_reward(state, memory, torch.tensor([2, 4, 1]), done)[0]

    assert (final(state.detach()) > 0).all()
    assert torch.autograd.gradcheck(final, (state,))
    (grad,) = torch.autograd.grad(final(state).sum(), (state,))
    assert (grad != 0).all()


def test_parallel_and_sequential_step_reward_gradcheck():
    spec = full_spec()
    walk = GoallessTask(spec, ForwardVelocityReward(0.25, 3, 1.0, 0.5))
    parallel = ParallelTasks([_goal(), walk], hold_reward_when_done=True)
    sequential = SequentialTasks([_goal(), walk], hold_reward_when_done=True)
    state, action = _inputs(4)
    for task in (parallel, sequential):
        fn = _step_fn(task, task.reset(torch.zeros(3, 4, dtype=torch.float64)))
        assert torch.autograd.gradcheck(fn, (state, action))
        _assert_pattern(fn, state, action, [True] * 4, [True, True])
    # with walk current in the sequence, only its forward coordinate (index 3) and the action matter
    fn = _step_fn(sequential, sequential.reset(torch.zeros(3, 4, dtype=torch.float64), start_index=1))
    assert torch.autograd.gradcheck(fn, (state, action))
    _assert_pattern(fn, state, action, [False, False, False, True], [True, True])


def test_goalless_forward_velocity_gradcheck_through_memory():
    """The gradient reaches the state, the action and, through memory, the initial state."""
    task = GoallessTask(full_spec(), ForwardVelocityReward(0.25, 1, 1.0, 0.5))
    state, action = _inputs(5)
    init_state = _inputs(6)[0]

    def fn(state, action, init_state):
        return task.step_reward(state, action, task.reset(init_state), 0)[0]

    assert torch.autograd.gradcheck(fn, (state, action, init_state))
    grads = torch.autograd.grad(fn(state, action, init_state).sum(), (state, action, init_state))
    expected = torch.tensor([False, True, False, False]).expand(3, 4)
    assert torch.equal(grads[0] != 0, expected) and torch.equal(grads[2] != 0, expected)
    assert (grads[1] != 0).all()
    torch.testing.assert_close(grads[0][:, 1], torch.full((3,), 4.0, dtype=torch.float64))  # w_f / dt
    torch.testing.assert_close(grads[2][:, 1], torch.full((3,), -4.0, dtype=torch.float64))


def test_best_state_step_reward_passes_the_gradient():
    task = BestStateFinalRewardTask(_goal(), 2.0)
    state, action = _inputs(7)
    fn = _step_fn(task, task.reset(state.detach()))
    assert torch.autograd.gradcheck(fn, (state, action))


# ------------------------------------------------------------------------------------ dtype, device, copies
def _run(task, dtype: torch.dtype = torch.float64, seed: int = 0, device: str | torch.device = "cpu"):
    data = make_drive_data(task, N_ENVS, 1, seed)
    state, action, next_state = (
        x.to(device=device, dtype=dtype) for x in (data.states[0], data.actions[0], data.states[1])
    )
    memory = task.reset(state)
    remaining = REMAINING.to(device)
    reward, memory = task.step_reward(next_state, action, memory, remaining)
    done = task.is_done(next_state, memory)
    final, memory = task.final_reward(next_state, memory, remaining, done)
    return reward, done, final, memory


def _floating_buffers(task):
    return {name: b for name, b in task.named_buffers() if b.is_floating_point()}


@pytest.mark.parametrize("name", sorted(CASES))
def test_float32_inputs_give_float32_outputs(name):
    task = CASES[name]()
    reward, done, final, memory = _run(task, torch.float32)
    assert reward.dtype == torch.float32 and final.dtype == torch.float32
    assert done.dtype == torch.bool
    for key, value in memory_leaves(memory).items():
        assert value.dtype in (torch.float32, torch.bool, torch.int64), (key, value.dtype)
    reward64, done64, final64, _ = _run(task, torch.float64)
    assert torch.equal(done, done64)
    torch.testing.assert_close(reward, reward64.float(), rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(final, final64.float(), rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("name", sorted(CASES))
def test_float_and_double_move_the_constants(name):
    task = CASES[name]()
    expected32 = _run(task, torch.float32)
    expected64 = _run(task, torch.float64)
    task.float()
    assert all(b.dtype == torch.float32 for b in _floating_buffers(task).values())
    # constants are cast to the input dtype anyway: a float32 task on float32 inputs is the same computation
    for got, want in zip(_run(task, torch.float32)[:3], expected32[:3], strict=True):
        assert_same(got, want, f"{name} float()")
    task.to(torch.float64)
    assert all(b.dtype == torch.float64 for b in _floating_buffers(task).values())
    # back in float64 the constants carry float32 rounding (2π, a modulation): equal to ~1e-7
    for got, want in zip(_run(task, torch.float64)[:3], expected64[:3], strict=True):
        assert got.dtype == want.dtype
        torch.testing.assert_close(got, want, rtol=1e-6, atol=1e-6, equal_nan=True)


@pytest.mark.parametrize("name", ["nested_parallel_sequential", "nested_sequential_masked", "goalless_ant"])
def test_meta_device_nothing_is_pinned_to_cpu(name):
    task = CASES[name]().to("meta")
    assert all(b.device.type == "meta" for b in task.buffers())
    reward, done, final, memory = _run(task, torch.float64, device="meta")
    assert reward.device.type == done.device.type == final.device.type == "meta"
    assert all(value.device.type == "meta" for value in memory_leaves(memory).values())


@pytest.mark.parametrize("name", sorted(CASES))
def test_deepcopy_is_equal_and_independent(name):
    task = CASES[name]()
    clone = copy.deepcopy(task)
    expected = _run(task)
    got = _run(clone)
    for a, b in zip(got[:3], expected[:3], strict=True):
        assert_same(a, b, name)
    assert_memory_equal(got[3], expected[3], name)
    for buffer in _floating_buffers(clone).values():
        buffer.add_(0.5)
    after = _run(task)
    for a, b in zip(after[:3], expected[:3], strict=True):
        assert_same(a, b, f"{name}: original changed by editing the copy")


def _goal_pair():
    spec = full_spec()
    a = DesiredStateTask(spec, [0.5, 0.0, -0.5, 1.0], QuadraticErrorReward([1.0, 0.5, 0.25, 2.0], [0.5, 0.5]))
    b = DesiredStateTask(spec, [0.0, 0.0, 0.0, 0.0], QuadraticErrorReward([1.0, 1.0, 1.0, 1.0], [1.0, 1.0]))
    return a, b


def _tree_pair():
    def build(offset: float, weight: float):
        spec = full_spec()
        goal = DesiredStateTask(spec, [offset] * 4, ExpQuadraticErrorReward([weight] * 4, [weight] * 2))
        radial = RadiallySymmetricDesiredStateTask(
            spec, [offset, 2.0, 0.0, 0.0], QuadraticErrorReward([weight] * 4, None), [1], 2 * math.pi + offset
        )
        inner = DesiredStateTask(spec.select_state(["c", "a"]), [offset, -offset], QuadraticErrorReward([weight] * 2))
        return FinalRewardTask(
            ParallelTasks([goal, SequentialTasks([radial, MaskedTask(spec, inner, ["c", "a"])])]),
            FinalRewardMode(state_dependent=True),
        )

    return build(0.5, 0.25), build(0.0, 1.0)


@pytest.mark.parametrize("pair", [_goal_pair, _tree_pair], ids=["desired_state", "tree"])
def test_state_dict_round_trip(pair):
    source, target = pair()
    before = _run(target)
    assert not torch.equal(before[0], _run(source)[0])
    target.load_state_dict(source.state_dict())
    got, want = _run(target), _run(source)
    for a, b in zip(got[:3], want[:3], strict=True):
        assert_same(a, b, "after load_state_dict")
    assert_memory_equal(got[3], want[3], "after load_state_dict")
    assert set(source.state_dict()) == set(target.state_dict())
    assert any(key.endswith("state_des") for key in source.state_dict())


def test_learnable_reward_weights_get_gradients_through_a_task():
    spec = EnvSpec(Box.unbounded(2), 1)
    reward = QuadraticErrorReward([1.0, 2.0], [0.5], learnable=True)
    task = FinalRewardTask(DesiredStateTask(spec, [0.0, 0.0], reward), FinalRewardMode(state_dependent=True))
    state = torch.tensor([[1.0, 2.0]], dtype=torch.float64)
    action = torch.tensor([[2.0]], dtype=torch.float64)
    memory = task.reset(state)
    value, memory = task.step_reward(state, action, memory, 0)
    value.sum().backward()
    # reward = -(Q0·1 + Q1·4 + R·4): dQ = [-1, -4], dR = [-4]
    torch.testing.assert_close(reward.Q.grad, torch.tensor([-1.0, -4.0], dtype=torch.float64))
    torch.testing.assert_close(reward.R.grad, torch.tensor([-4.0], dtype=torch.float64))
