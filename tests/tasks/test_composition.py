"""Composition: every argument of ``transition`` reaches every task of a tree, whatever wraps it.

For every wrapper and composite ``W`` and every task ``T`` of the library (one per class and notable
configuration, potential-based shaping included), ``W(T).transition(...)`` over random transitions with
random ``terminated``, ``truncated``, goals and remaining steps (and partial resets where an episode
ends) gives what ``T``'s own ``transition`` gives with the same arguments, composed by ``W``'s
documented rule. The rules are written here from the docs, never read from the code under test.

Also the regressions of issue 22, items 1-3: shaping inside any wrapper treats the env's own
termination as absorbing; a sub-task of :class:`SequentialTasks` starts from the state where it becomes
current; negative remaining steps are refused.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import pytest
import torch
from torchrl.envs import Compose, StepCounter, TransformedEnv

from task_trees import all_task_cases, random_transitions, shaping_potential
from torchtasks.envs import PendulumEnv
from torchtasks.rewards import ConstantReward, ForwardVelocityReward, StateFunctionReward
from torchtasks.spaces import Box, EnvSpec, rows_outside
from torchtasks.tasks import (
    BestStateFinalRewardTask,
    ConstrainedTask,
    DesiredStateTask,
    FinalRewardMode,
    FinalRewardTask,
    GoallessTask,
    MaskedTask,
    ParallelTasks,
    PotentialShapingTask,
    SequentialTasks,
    Task,
    all_tasks,
    proximity_succeeded,
)
from torchtasks.tasks.base import Task as BaseTask
from torchtasks.tasks.memory import where_memory
from torchtasks.transforms import TaskTransform

BATCH = 16
STEPS = 12
GAMMA = 0.75
FACTOR = 3.0
BEST_FACTOR = -0.5


TASKS = all_task_cases()
WRAPPER_COST = "wrapper_cost"


def _first_entry_size(state: torch.Tensor) -> torch.Tensor:
    return state[..., 0].abs()


def _extended(spec: EnvSpec) -> EnvSpec:
    """``spec`` with one more, unbounded state entry at the front (the mask drops it)."""
    box = spec.state_space
    inf = torch.tensor([math.inf], dtype=box.low.dtype)
    return EnvSpec(Box(torch.cat([-inf, box.low]), torch.cat([inf, box.high])), spec.action_space)


# each wrapper: (build W from T, how W's state relates to T's state)
WRAPPERS: dict[str, Callable[[Task], Task]] = {
    "final": lambda t: FinalRewardTask(t, factor=FACTOR),
    "final_time": lambda t: FinalRewardTask(t, FinalRewardMode(time_dependent=True)),
    "best_state": lambda t: BestStateFinalRewardTask(t, BEST_FACTOR),
    "masked": lambda t: MaskedTask(_extended(t.spec), t, list(range(1, t.state_size + 1))),
    "constrained": lambda t: ConstrainedTask(t, {WRAPPER_COST: StateFunctionReward(_first_entry_size, negate=False)}),
    "shaping": lambda t: PotentialShapingTask(t, shaping_potential, GAMMA),
    "parallel": lambda t: ParallelTasks([t]),
    "sequential": lambda t: SequentialTasks([t]),
}


def _own_final_only(task: Task) -> bool:
    """Whether at most one task of ``task``'s wrapper chain pays a final reward of its own.

    A composite pays a sub-task that did not finish by itself its own final reward at the episode end
    (Pyrado's ``compute_final_rew`` over the immediate sub-tasks; masks, constraints and shaping pass it
    through); for such a chain that is all of it.
    """
    payers = [t for t in all_tasks(task) if type(t)._compute_final_reward is not BaseTask._compute_final_reward]
    return len(payers) <= 1


def _wrapped_state(name: str, state: torch.Tensor) -> torch.Tensor:
    if name != "masked":
        return state
    return torch.cat([torch.full_like(state[..., :1], 1e6), state], dim=-1)  # the dropped entry: far out


def _check_rule(name: str, task: Task, wrapped_out, out, context: dict) -> None:
    """Assert ``wrapped_out`` (of ``W(task)``) against ``out`` (of ``task``) by W's documented rule."""
    zero = torch.zeros_like(out.reward)
    own_end = out.success | out.failure

    def same(actual: torch.Tensor, expected: torch.Tensor, what: str) -> None:
        if actual.dtype == torch.bool:
            assert torch.equal(actual, expected), f"{name}: {what}"
        else:
            torch.testing.assert_close(actual, expected, rtol=1e-12, atol=1e-12, msg=f"{name}: {what}")

    if name in ("final", "final_time", "best_state", "masked", "shaping", "constrained"):
        for flag in ("success", "failure", "terminated", "done"):
            same(getattr(wrapped_out, flag), getattr(out, flag), flag)
    if name in ("masked", "constrained"):
        for field in ("reward", "step_reward", "final_reward"):
            same(getattr(wrapped_out, field), getattr(out, field), field)
        expected_costs = dict(out.costs)
        if name == "constrained":  # one more cost, on the state the step reward sees; nothing else changes
            expected_costs[WRAPPER_COST] = context["reward_state"][..., 0].abs()
        assert list(wrapped_out.costs) == list(expected_costs)
        for cost_name, cost in expected_costs.items():
            same(wrapped_out.costs[cost_name], cost, f"cost {cost_name}")
    elif name in ("final", "final_time"):
        same(wrapped_out.step_reward, out.step_reward, "step reward")
        magnitude = (
            context["remaining"].to(out.reward.dtype) if name == "final_time" else torch.full_like(out.reward, FACTOR)
        )
        own = torch.where(out.failure, -magnitude, torch.where(out.success, magnitude, zero))
        same(wrapped_out.final_reward, out.final_reward + torch.where(out.done, own, zero), "final reward")
    elif name == "best_state":
        same(wrapped_out.step_reward, out.step_reward, "step reward")
        best = torch.maximum(context["best"], out.step_reward)
        context["best"] = best
        own = torch.where(out.done & (best > -math.inf), BEST_FACTOR * best, zero)
        same(wrapped_out.final_reward, out.final_reward + own, "final reward")
    elif name == "shaping":
        phi_next = shaping_potential(context["next_state"])
        absorbing = out.terminated  # the task's success or failure, or the env's own termination
        shaping = GAMMA * torch.where(absorbing, zero, phi_next) - context["phi"]
        context["phi"] = phi_next
        same(wrapped_out.step_reward, out.step_reward + shaping, "step reward")
        same(wrapped_out.final_reward, out.final_reward, "final reward")
        assert torch.equal(wrapped_out.terms["shaping"], shaping)
    elif name in ("parallel", "sequential"):
        # the sub-task's final reward is paid in the step where it finishes by itself; at an episode end
        # by the env's flags alone, the composite pays its own final reward then (through the wrappers that
        # change no number), as Pyrado's compute_final_rew
        same(wrapped_out.step_reward, out.step_reward + torch.where(own_end, out.final_reward, zero), "step reward")
        same(wrapped_out.success, out.success, "success")
        if name == "parallel":
            same(wrapped_out.failure, out.failure & ~out.success, "failure")
        else:  # a failed sub-task does not end a sequence; leaving the first sub-task's box does
            box = task.spec.state_space
            same(wrapped_out.failure, rows_outside(context["next_state"], box.low, box.high), "failure")
        env_end = out.done & ~own_end
        if _own_final_only(task):
            same(wrapped_out.reward, out.reward, "reward")
        else:
            same(wrapped_out.reward[~env_end], out.reward[~env_end], "reward where the sub-task ended itself")


def _run(task_name: str, wrapper_name: str, seed: int, reward_on: str, batch: int = BATCH) -> None:
    task = TASKS[task_name]().double()
    if wrapper_name == "shaping" and "shaping" in task.term_names:
        with pytest.raises(ValueError, match="already has a term named 'shaping'"):
            WRAPPERS[wrapper_name](task)  # shaping twice would report two terms under one name
        return
    wrapped = WRAPPERS[wrapper_name](task).double()
    generator = torch.Generator().manual_seed(seed)
    draws = random_transitions(task, generator, STEPS, batch=batch)
    state = draws["states"][0]
    memory = task.reset(state)
    wrapped_memory = wrapped.reset(_wrapped_state(wrapper_name, state))
    context = {
        "best": torch.full((batch,), -math.inf, dtype=torch.float64),
        "phi": shaping_potential(state),
    }
    for t in range(STEPS):
        next_state = draws["states"][t + 1]
        kwargs = {
            "terminated": draws["terminated"][t],
            "truncated": draws["truncated"][t],
            "reward_on": reward_on,
            "goal": draws["goals"][t] if "goals" in draws else None,
        }
        remaining = draws["remaining"][t]
        out = task.transition(state, draws["actions"][t], next_state, memory, remaining, **kwargs)
        wrapped_out = wrapped.transition(
            _wrapped_state(wrapper_name, state),
            draws["actions"][t],
            _wrapped_state(wrapper_name, next_state),
            wrapped_memory,
            remaining,
            **kwargs,
        )
        reward_state = next_state if reward_on == "next" else state
        context.update(next_state=next_state, remaining=remaining, reward_state=reward_state)
        _check_rule(wrapper_name, task, wrapped_out, out, context)
        # partial reset of both where the task's episode ended
        reset_state = torch.where(out.done.unsqueeze(-1), draws["resets"][t], next_state)
        memory = where_memory(out.done, task.reset(reset_state), out.memory)
        wrapped_memory = where_memory(
            out.done, wrapped.reset(_wrapped_state(wrapper_name, reset_state)), wrapped_out.memory
        )
        context["best"] = torch.where(out.done, -math.inf, context["best"])
        context["phi"] = torch.where(out.done, shaping_potential(reset_state), context["phi"])
        state = reset_state


@pytest.mark.parametrize("wrapper_name", sorted(WRAPPERS))
@pytest.mark.parametrize("task_name", sorted(TASKS))
def test_wrapper_composes_the_task_transition(task_name: str, wrapper_name: str) -> None:
    # 3 * BATCH envs in one run: as many episodes as 3 seeds of BATCH envs, a third of the (per-step) cost
    _run(task_name, wrapper_name, 0, "next", batch=3 * BATCH)
    # in Pyrado's order the step reward sees s_t: shaping lags (tested in test_shaping.py) and composites
    # judge their sub-tasks on s_t (the golden scenarios test that order); wrappers pass it through
    if wrapper_name not in ("shaping", "parallel", "sequential"):
        _run(task_name, wrapper_name, 3, "state")


# transparent wrappers: each changes nothing of a task's reward, flags or final reward
TRANSPARENT: dict[str, Callable[[Task], Task]] = {
    "identity_mask": lambda t: MaskedTask(t.spec, t, list(range(t.state_size))),
    "constrained": WRAPPERS["constrained"],
    "zero_potential": lambda t: PotentialShapingTask(t, lambda s: s.new_zeros(s.shape[:-1]), GAMMA),
}
COMPOSITES: dict[str, Callable[[Task], Task]] = {
    "parallel": lambda t: ParallelTasks([t]),
    "parallel_hold": lambda t: ParallelTasks([t], hold_reward_when_done=True),
    "sequential": lambda t: SequentialTasks([t]),
    "final_of_sequential": lambda t: FinalRewardTask(SequentialTasks([t]), factor=FACTOR),
}


@pytest.mark.parametrize("composite_name", sorted(COMPOSITES))
@pytest.mark.parametrize("wrapper_name", sorted(TRANSPARENT))
@pytest.mark.parametrize("task_name", sorted(TASKS))
def test_a_composite_pays_a_wrapped_sub_task_what_it_pays_the_bare_one(
    task_name: str, wrapper_name: str, composite_name: str
) -> None:
    """``C([W(T)])`` gives ``C([T])``'s reward, final reward and flags for a wrapper ``W`` that changes nothing:
    the final rewards inside ``W`` are paid in the step where the sub-task finishes and at the episode end."""
    task = TASKS[task_name]().double()
    if wrapper_name == "zero_potential" and "shaping" in task.term_names:
        return  # shaping twice is refused (tested above)
    bare = COMPOSITES[composite_name](task)
    wrapped = COMPOSITES[composite_name](TRANSPARENT[wrapper_name](TASKS[task_name]().double()))
    draws = random_transitions(task, torch.Generator().manual_seed(7), STEPS, batch=BATCH)
    state = draws["states"][0]
    memory, wrapped_memory = bare.reset(state), wrapped.reset(state)
    for t in range(STEPS):
        args = (state, draws["actions"][t], draws["states"][t + 1])
        kwargs = {
            "remaining_steps": draws["remaining"][t],
            "terminated": draws["terminated"][t],
            "truncated": draws["truncated"][t],
            "goal": draws["goals"][t] if "goals" in draws else None,
        }
        out = bare.transition(*args, memory, **kwargs)
        wrapped_out = wrapped.transition(*args, wrapped_memory, **kwargs)
        for field in ("reward", "final_reward", "success", "failure", "done"):
            assert torch.equal(getattr(wrapped_out, field), getattr(out, field)), (field, t)
        state = torch.where(out.done.unsqueeze(-1), draws["resets"][t], draws["states"][t + 1])
        memory = where_memory(out.done, bare.reset(state), out.memory)
        wrapped_memory = where_memory(out.done, wrapped.reset(state), wrapped_out.memory)


def test_a_wrapper_chain_sub_task_is_judged_by_its_own_final_reward_at_the_episode_end() -> None:
    """Pyrado's rule, kept: an unfinished ``FinalRewardTask(BestStateFinalRewardTask(T))`` sub-task pays the outer
    task's own final reward at a time limit (0: neither success nor failure), not the inner best-state reward,
    which it pays when it ends by itself (here the sub-task alone pays 10 at the same time limit)."""
    spec = EnvSpec(Box(-5.0, 5.0), 1)
    chain = FinalRewardTask(BestStateFinalRewardTask(GoallessTask(spec, ConstantReward(1.0)), 10.0), factor=3.0)
    state, action = torch.zeros(1, 1), torch.zeros(1, 1)
    truncated = torch.tensor([True])
    alone = chain.transition(state, action, state, chain.reset(state), truncated=truncated)
    assert alone.final_reward.tolist() == [10.0]
    for composite in (ParallelTasks([chain]), SequentialTasks([chain])):
        out = composite.transition(state, action, state, composite.reset(state), truncated=truncated)
        assert (out.step_reward.tolist(), out.final_reward.tolist()) == ([1.0], [0.0]), type(composite).__name__


# ----------------------------------------------------------------------------------- regressions
SPEC = EnvSpec(1, 1)
NEAR = functools.partial(proximity_succeeded, threshold=0.1)


def _shaped_goalless() -> PotentialShapingTask:
    return PotentialShapingTask(GoallessTask(SPEC, ConstantReward(0.0)), lambda s: -s[..., 0].abs(), 0.9)


@pytest.mark.parametrize(
    ("wrap", "copies"),
    [
        (lambda t: t, 1),
        (lambda t: FinalRewardTask(t), 1),
        (lambda t: BestStateFinalRewardTask(t, 1.0), 1),
        (lambda t: MaskedTask(SPEC, t, [0]), 1),
        (lambda t: ParallelTasks([t]), 1),
        (lambda t: SequentialTasks([t]), 1),
        (lambda t: FinalRewardTask(MaskedTask(SPEC, ParallelTasks([t, _shaped_goalless()]), [0])), 2),
    ],
    ids=["bare", "final", "best", "masked", "parallel", "sequential", "nested"],
)
def test_shaping_is_absorbing_at_the_envs_termination_inside_any_wrapper(
    wrap: Callable[[Task], Task], copies: int
) -> None:
    # Φ(s) = -2, Φ(s') = -1, γ = 0.9: truncation pays 0.9·(-1) + 2 = 1.1, termination pays 0 + 2 = 2.0
    task = wrap(_shaped_goalless())
    state, next_state = torch.tensor([[2.0], [2.0], [2.0]]), torch.tensor([[1.0], [1.0], [1.0]])
    out = task.transition(
        state,
        torch.zeros(3, 1),
        next_state,
        task.reset(state),
        terminated=torch.tensor([True, False, False]),
        truncated=torch.tensor([False, True, False]),
    )
    torch.testing.assert_close(out.step_reward, torch.tensor([2.0, 1.1, 1.1]) * copies)


def test_shaped_sub_task_starts_from_the_state_where_it_becomes_current() -> None:
    first = DesiredStateTask(SPEC, [1.0], ConstantReward(0.0), NEAR)
    shaped = PotentialShapingTask(
        DesiredStateTask(SPEC, [-1.0], ConstantReward(0.0), NEAR), lambda s: -(s[..., 0] + 1).abs(), 1.0
    )
    task = SequentialTasks([first, shaped])
    memory = task.reset(torch.tensor([[0.0]]))
    out = task.transition(torch.tensor([[0.0]]), torch.zeros(1, 1), torch.tensor([[1.0]]), memory)
    assert out.memory["index"].tolist() == [1]
    # the first step of the shaped sub-task: from 1.0 to 0.5, towards -1: Φ = -2 → -1.5, pays +0.5
    out = task.transition(torch.tensor([[1.0]]), torch.zeros(1, 1), torch.tensor([[0.5]]), out.memory)
    torch.testing.assert_close(out.step_reward, torch.tensor([0.5]))


def test_forward_velocity_sub_task_measures_from_where_it_takes_over() -> None:
    spec = EnvSpec(2, 1)
    first = DesiredStateTask(spec, [5.0, 0.0], ConstantReward(0.0), NEAR)
    walk = GoallessTask(spec, ForwardVelocityReward(dt=1.0, index=0, forward_reward_weight=1.0, ctrl_cost_weight=0.0))
    task = SequentialTasks([first, walk])
    state = torch.tensor([[0.0, 0.0]])
    memory = task.reset(state)
    out = task.transition(state, torch.zeros(1, 1), torch.tensor([[5.0, 0.0]]), memory)  # the first is done at x=5
    out = task.transition(torch.tensor([[5.0, 0.0]]), torch.zeros(1, 1), torch.tensor([[5.5, 0.0]]), out.memory)
    torch.testing.assert_close(out.step_reward, torch.tensor([0.5]))  # 0.5 / dt, not (5.5 - 0) / dt


def test_goal_of_a_sub_task_survives_its_start() -> None:
    first = DesiredStateTask(SPEC, [1.0], ConstantReward(0.0), NEAR)
    second = PotentialShapingTask(
        DesiredStateTask(SPEC, [-1.0], ConstantReward(0.0), NEAR), lambda s: -(s[..., 0] + 1).abs(), 1.0
    )
    task = SequentialTasks([first, second])
    goal = {"task1.wrapped.state_des": torch.tensor([[3.0]])}
    memory = task.reset(torch.tensor([[0.0]]), state_des=torch.tensor([[1.0]]))
    memory = task.with_goal(memory, goal, torch.zeros(1, 1))
    out = task.transition(torch.tensor([[0.0]]), torch.zeros(1, 1), torch.tensor([[1.0]]), memory)
    assert out.memory["task1", "wrapped", "state_des"].tolist() == [[3.0]]


def _time_task(n: int, m: int) -> FinalRewardTask:
    return FinalRewardTask(GoallessTask(EnvSpec(n, m), ConstantReward(0.0)), FinalRewardMode(time_dependent=True))


@pytest.mark.parametrize("remaining", [-1, torch.tensor([3, -2]), torch.tensor(-1)])
def test_negative_remaining_steps_are_refused_at_the_call(remaining: int | torch.Tensor) -> None:
    task = _time_task(1, 1)
    state = torch.zeros(2, 1)
    with pytest.raises(ValueError, match="remaining_steps must be >= 0"):
        task.transition(state, torch.zeros(2, 1), state, task.reset(state), remaining)
    with pytest.raises(ValueError, match="remaining_steps must be >= 0"):
        task.final_reward(state, task.reset(state), remaining, torch.ones(2, dtype=torch.bool))


def _pendulum_task(env: PendulumEnv) -> FinalRewardTask:
    return _time_task(env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1])


def test_a_max_steps_that_disagrees_with_the_step_counter_is_refused_at_set_up() -> None:
    base = PendulumEnv(batch_size=[2])
    env = TransformedEnv(base, Compose(StepCounter(10), TaskTransform(_pendulum_task(base), max_steps=3)))
    with pytest.raises(ValueError, match=r"max_steps=3\) disagrees with the preceding StepCounter\(max_steps=10\)"):
        env.reset()  # when the env's specs are built


def test_no_limit_on_purpose_is_refused_beside_a_step_counter_with_a_limit() -> None:
    base = PendulumEnv(batch_size=[2])
    env = TransformedEnv(base, Compose(StepCounter(10), TaskTransform(_pendulum_task(base), max_steps=math.inf)))
    with pytest.raises(ValueError, match=r"max_steps=math.inf\) says the env has no time limit, but StepCounter"):
        env.reset()
    for bad in (-math.inf, math.nan, 2.0):
        with pytest.raises(TypeError, match="max_steps must be a positive int"):
            TaskTransform(_pendulum_task(base), max_steps=bad)


def test_offline_data_beyond_the_limit_is_refused() -> None:
    base = PendulumEnv(batch_size=[2])
    env = TransformedEnv(base, Compose(StepCounter(10), TaskTransform(_pendulum_task(base))))
    data = env.rollout(10, break_when_any_done=False)
    with pytest.raises(ValueError, match=r"step counts up to 10 .* exceed max_steps=3"):
        TaskTransform(_pendulum_task(base), max_steps=3).reward_fn(data)
    # the limit the data was collected with re-judges it exactly
    expected = data["next", "reward"]
    assert torch.equal(TaskTransform(_pendulum_task(base), max_steps=10).reward_fn(data), expected)


def test_a_limit_no_step_counter_enforces_is_checked_online() -> None:
    base = PendulumEnv(batch_size=[2])
    env = TransformedEnv(base, Compose(StepCounter(), TaskTransform(_pendulum_task(base), max_steps=3)))
    env.rollout(3, break_when_any_done=False)  # within the limit: fine
    with pytest.raises(ValueError, match="exceed max_steps=3"):
        env.rollout(5, break_when_any_done=False)


class _StayAbove(Task):
    """A task of one's own, written without the ``terminated`` argument (as the concepts page shows)."""

    def _step_reward(self, state, action, memory, remaining_steps):
        return (state[..., 0] > 0).to(state.dtype), memory

    def _has_succeeded(self, state, memory):
        return torch.zeros(state.shape[:-1], dtype=torch.bool, device=state.device)


@pytest.mark.parametrize("wrap", list(WRAPPERS.values()), ids=list(WRAPPERS))
def test_a_task_of_ones_own_without_terminated_composes(wrap: Callable[[Task], Task]) -> None:
    inner = _StayAbove(EnvSpec(Box([-1.0], [math.inf]), 1))
    task = wrap(inner)
    n = task.state_size
    state = torch.full((2, n), 0.5)
    out = task.transition(state, torch.zeros(2, 1), state, task.reset(state), terminated=torch.tensor([True, False]))
    bare = inner.transition(
        state[..., -1:], torch.zeros(2, 1), state[..., -1:], inner.reset(state[..., -1:]), terminated=None
    )
    expected = bare.step_reward + out.terms.get("shaping", torch.zeros(2))
    torch.testing.assert_close(out.step_reward, expected)
    assert bare.step_reward.tolist() == [1.0, 1.0]
