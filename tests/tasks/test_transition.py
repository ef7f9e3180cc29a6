"""``Task.transition``: equal, bit for bit, to the fine-grained calls made in its documented order.

For random task trees of every task type (``task_trees.task_trees``; trees around compound and
locomotion rewards with named terms; every fixed case of ``task_trees``) driven through random
multi-step trajectories, one transition must equal::

    source = next_state if reward_on == "next" else state
    r, m = task.step_reward(source, action, memory, rem)
    s, f = task.has_succeeded(next_state, m), task.has_failed(next_state, m)
    done = s | f | terminated | truncated
    final, m = task.final_reward(next_state, m, rem, done)

with ``out.terms`` equal to ``step_reward_terms``' terms. Both paths run the same ops, so every field
(memory leaves included) is compared exactly (NaN equal to NaN, dtype and shape checked). Trajectories
vary the batch shape (``()``, ``(1,)``, ``(3,)``, ``(5,)``, ``(2, 3)``), the dtype (float32 inputs on
the float64-built tasks, float64), ``reward_on``, the env's ``terminated`` / ``truncated`` flags
(absent, random, a per-env time limit), ``remaining_steps`` (omitted, an int, a ``[*B]`` or a
broadcast int tensor), NaN states, and the memory between steps (partial resets with ``where_memory``
as ``TaskTransform`` does, random resets, or no reset at all, so finished episodes go on). Along the
way: ``task(...)`` equals ``transition``, the input memory is never modified, the fields have the
batch shape and flags are bool, ``reward == step_reward + final_reward``, the final reward is 0
where not done, and once an episode is done no later call pays a final reward until a reset.

The second part checks that ``transition`` rejects malformed arguments, naming the argument.

Hypothesis runs derandomized (stable examples and runtime); drop ``derandomize`` or raise
``max_examples`` locally to explore more.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from tensordict import TensorDict, TensorDictBase

from task_trees import (
    SUPPORTED_MODES,
    assert_memory_equal,
    assert_same,
    class_cases,
    example_trees,
    full_spec,
    predefined_cases,
    reset_overrides_for,
    task_trees,
)
from torchtasks.rewards import (
    AntForwardReward,
    CompoundReward,
    ConstantReward,
    ContactCostReward,
    ControlCostReward,
    ExpQuadraticErrorReward,
    ForwardVelocityReward,
    HealthyReward,
    QuadraticErrorReward,
    VelocityReward,
)
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import (
    BestStateFinalRewardTask,
    DesiredSpaceTask,
    DesiredStateTask,
    FinalRewardTask,
    GoallessTask,
    MaskedTask,
    ParallelTasks,
    SequentialTasks,
    Task,
    proximity_succeeded,
)
from torchtasks.tasks.memory import where_memory
from torchtasks.tasks.output import TaskOutput

SETTINGS = settings(
    max_examples=100,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    derandomize=True,
)

TENSOR_FIELDS = ("reward", "step_reward", "final_reward", "success", "failure", "terminated", "done")
FLAG_FIELDS = ("success", "failure", "terminated", "done")
REWARD_FIELDS = ("reward", "step_reward", "final_reward")
BATCH_SHAPES = ((), (1,), (3,), (5,), (2, 3))

#: every fixed tree of task_trees: one per task class / notable configuration, predefined factories, examples
FIXED_CASES: dict[str, Callable[[], Task]] = {
    **class_cases(),
    **predefined_cases(),
    **{f"example_{name}": functools.partial(lambda key: example_trees()[key], name) for name in example_trees()},
}

#: marker: call transition / step_reward without remaining_steps (the default 0)
OMIT = "omit"


# ------------------------------------------------------------------------------ trees with named reward terms
def _compound_leaf(draw: Callable, spec: EnvSpec) -> tuple[Task, str]:
    """A leaf whose reward reports named terms: compound (stateless or stateful) or locomotion rewards."""
    kind = draw(st.sampled_from(["locomotion_terms", "stateful_compound", "error_compound", "space_compound", "ant"]))
    weight = draw(st.floats(0.1, 2.0))
    if kind == "locomotion_terms":
        reward = CompoundReward(
            {
                "forward": VelocityReward(weight, draw(st.integers(0, 3))),
                "ctrl": ControlCostReward(draw(st.floats(0.0, 0.5))),
                "healthy": HealthyReward(
                    1.0, index=[0, 1], low=-1.5, high=1.5, terminate_when_unhealthy=draw(st.booleans())
                ),
                "contact": ContactCostReward(0.25, start=2, force_range=(-1.0, 1.0)),
            }
        )
        return GoallessTask(spec, reward), "Goalless(Compound[velocity, ctrl, healthy, contact])"
    if kind == "stateful_compound":
        reward = CompoundReward(
            {"fwd": ForwardVelocityReward(0.25, draw(st.integers(0, 3)), weight, 0.125), "alive": ConstantReward(0.5)}
        )
        return GoallessTask(spec, reward), "Goalless(Compound[ForwardVelocity, alive])"
    if kind == "ant":
        reward = AntForwardReward(
            0.25,
            contact_cost_weight=0.0625,
            healthy_z_range=(-1.0, 1.0),
            terminate_when_unhealthy=draw(st.booleans()),
            x_index=0,
            z_index=1,
            contact_forces_start=2,
        )
        return GoallessTask(spec, reward), "Goalless(Ant)"
    Q = torch.linspace(0.25, 1.0, spec.state_size, dtype=torch.float64) * weight
    reward = CompoundReward(
        [
            QuadraticErrorReward(Q, [0.5] * spec.action_size),
            ExpQuadraticErrorReward(0.5 * Q, None),
            ConstantReward(0.25),
        ]
    )
    if kind == "space_compound":
        return DesiredSpaceTask(spec, Box([-0.5] * 4, [1.0] * 4), reward), "DesiredSpace(Compound[3])"
    threshold = draw(st.floats(0.6, 2.5)) * math.sqrt(spec.state_size)
    success = functools.partial(proximity_succeeded, threshold=threshold)
    state_des = [draw(st.floats(-1.0, 1.0)) for _ in range(spec.state_size)]
    return DesiredStateTask(spec, state_des, reward, success), "DesiredState(Compound[3])"


@st.composite
def term_trees(draw: Callable) -> tuple[Task, str]:
    """A leaf with named terms under 0-3 wrappers (final reward of any mode, best state, a reordering
    mask), sometimes inside a parallel or sequential composition with a random sibling."""
    spec = full_spec()
    task, name = _compound_leaf(draw, spec)
    for _ in range(draw(st.integers(0, 3))):
        kind = draw(st.sampled_from(["final", "best", "masked"]))
        if kind == "final":
            mode = draw(st.sampled_from(SUPPORTED_MODES))
            task, name = FinalRewardTask(task, mode, draw(st.floats(0.5, 20.0))), f"Final({name})"
        elif kind == "best":
            task, name = BestStateFinalRewardTask(task, draw(st.floats(-2.0, 2.0))), f"Best({name})"
        else:
            # a permutation of all entries keeps the sizes (all a mask checks), so any leaf can sit inside
            state_order = draw(st.permutations(list(range(spec.state_size))))
            action_order = draw(st.permutations(list(range(spec.action_size))))
            task, name = MaskedTask(spec, task, state_order, action_order), f"Masked{state_order}({name})"
    composition = draw(st.sampled_from(["none", "none", "parallel", "sequential"]))
    if composition != "none":
        sibling, sibling_name = draw(task_trees(max_depth=1))
        children = [task, sibling] if draw(st.booleans()) else [sibling, task]
        hold = draw(st.booleans())
        if composition == "parallel":
            task = ParallelTasks(children, hold_reward_when_done=hold, easily_satisfied=draw(st.booleans()))
        else:
            task = SequentialTasks(children, start_index=draw(st.integers(0, 1)), hold_reward_when_done=hold)
        name = f"{composition}({name}, {sibling_name})"
    return task, name


@st.composite
def any_task(draw: Callable) -> tuple[Task, str]:
    """A random tree of every task type, a tree with named terms, or one of the fixed cases."""
    kind = draw(st.sampled_from(["random_tree", "term_tree", "fixed"]))
    if kind == "random_tree":
        return draw(task_trees(max_depth=3))
    if kind == "term_tree":
        return draw(term_trees())
    name = draw(st.sampled_from(sorted(FIXED_CASES)))
    return FIXED_CASES[name](), name


# ------------------------------------------------------------------------------ trajectories
@dataclass(frozen=True)
class Config:
    """How a trajectory is generated (the numbers themselves come from ``seed``)."""

    batch: tuple[int, ...]
    steps: int
    dtype: torch.dtype
    reward_on: str
    terminated: str  # "none" | "random"
    truncated: str  # "none" | "random" | "limit" (per-env time limit)
    remaining: str  # OMIT | "int" | "tensor" | "broadcast" | "limit"
    resets: str  # "done" (where_memory on done, as TaskTransform) | "random" | "never"
    overrides: bool
    nan: bool
    state_scale: float
    seed: int


configs = st.builds(
    Config,
    batch=st.sampled_from(BATCH_SHAPES),
    steps=st.integers(3, 10),
    dtype=st.sampled_from([torch.float64, torch.float32]),
    reward_on=st.sampled_from(["next", "state"]),
    terminated=st.sampled_from(["none", "random"]),
    truncated=st.sampled_from(["none", "random", "limit"]),
    remaining=st.sampled_from([OMIT, "int", "tensor", "broadcast", "limit"]),
    resets=st.sampled_from(["done", "done", "random", "never"]),
    overrides=st.booleans(),
    nan=st.booleans(),
    state_scale=st.sampled_from([0.5, 1.0, 2.0]),
    seed=st.integers(0, 2**31 - 1),
)


@dataclass
class Stats:
    """What a run exercised (so the deterministic tests can check the driver reaches every case)."""

    steps: int = 0
    success: int = 0
    failure: int = 0
    terminated_by_env: int = 0
    truncated: int = 0
    final_paid: int = 0
    latched: int = 0  # a final reward was paid, and the repeated done call with that memory paid 0
    terms: int = 0


def _fine_grained(
    task: Task,
    state: torch.Tensor,
    action: torch.Tensor,
    next_state: torch.Tensor,
    memory: TensorDictBase,
    remaining: object,
    terminated: torch.Tensor | None,
    truncated: torch.Tensor | None,
    reward_on: str,
) -> TaskOutput:
    """The transition spelled with the fine-grained public calls, in the documented order."""
    rem = 0 if remaining is OMIT else remaining
    source = next_state if reward_on == "next" else state
    if remaining is OMIT:
        reward, memory_after_step = task.step_reward(source, action, memory)
    else:
        reward, memory_after_step = task.step_reward(source, action, memory, rem)
    terms, terms_reward, terms_memory = task.step_reward_terms(source, action, memory, rem)
    assert_same(terms_reward, reward, "step_reward_terms' reward vs step_reward")
    assert_memory_equal(terms_memory, memory_after_step, "step_reward_terms' memory vs step_reward")
    success = task.has_succeeded(next_state, memory_after_step)
    failure = task.has_failed(next_state, memory_after_step)
    assert_same(task.is_done(next_state, memory_after_step), success | failure, "is_done vs success | failure")
    ended = success | failure
    if terminated is not None:
        ended = ended | terminated
    done = ended if truncated is None else ended | truncated
    final, memory_after = task.final_reward(next_state, memory_after_step, rem, done)
    return TaskOutput(reward + final, reward, final, success, failure, ended, done, memory_after, terms)


def _call(
    method: Callable, state, action, next_state, memory, remaining, terminated, truncated, reward_on, explicit=False
):
    args = (state, action, next_state, memory) if remaining is OMIT else (state, action, next_state, memory, remaining)
    kwargs: dict[str, object] = {}
    if terminated is not None:
        kwargs["terminated"] = terminated
    if truncated is not None:
        kwargs["truncated"] = truncated
    if reward_on != "next" or explicit:  # the default "next" is passed explicitly at every other step
        kwargs["reward_on"] = reward_on
    return method(*args, **kwargs)


def assert_outputs_equal(actual: TaskOutput, expected: TaskOutput, what: str) -> None:
    """Every field exactly equal (NaN == NaN, same dtype and shape), memory leaves and terms included."""
    for name in TENSOR_FIELDS:
        assert_same(getattr(actual, name), getattr(expected, name), f"{what}: {name}")
    assert_memory_equal(actual.memory, expected.memory, f"{what}: memory")
    assert list(actual.terms) == list(expected.terms), f"{what}: terms {list(actual.terms)} != {list(expected.terms)}"
    for name, value in expected.terms.items():
        assert_same(actual.terms[name], value, f"{what}: term {name}")


def check_step(
    task: Task,
    state: torch.Tensor,
    action: torch.Tensor,
    next_state: torch.Tensor,
    memory: TensorDictBase,
    remaining: object,
    terminated: torch.Tensor | None,
    truncated: torch.Tensor | None,
    reward_on: str,
    what: str,
    explicit: bool = False,
) -> TaskOutput:
    """One transition, checked against the fine-grained calls, ``task(...)`` and the output invariants."""
    inputs = (state, action, next_state, memory, remaining, terminated, truncated, reward_on)
    snapshot = memory.clone()
    out = _call(task.transition, *inputs, explicit=explicit)
    assert isinstance(out, TaskOutput)
    assert_outputs_equal(_call(task, *inputs, explicit=not explicit), out, f"{what}: task(...) vs transition")
    assert_outputs_equal(out, _fine_grained(task, *inputs), f"{what}: transition vs fine-grained calls")
    assert_memory_equal(memory, snapshot, f"{what}: the input memory was modified")
    batch = state.shape[:-1]
    for name in TENSOR_FIELDS:
        value = getattr(out, name)
        assert value.shape == batch, f"{what}: {name} has shape {tuple(value.shape)}, expected {tuple(batch)}"
    for name in FLAG_FIELDS:
        assert getattr(out, name).dtype == torch.bool, f"{what}: {name} is {getattr(out, name).dtype}"
    for name in REWARD_FIELDS:
        assert getattr(out, name).is_floating_point(), f"{what}: {name} is {getattr(out, name).dtype}"
    assert out.memory.batch_size == batch
    assert set(out.terms) == set(task.term_names), f"{what}: terms {set(out.terms)} != {set(task.term_names)}"
    for name, value in out.terms.items():
        assert value.shape == batch, f"{what}: term {name} has shape {tuple(value.shape)}"
    assert_same(out.reward, out.step_reward + out.final_reward, f"{what}: reward != step_reward + final_reward")
    assert bool((out.final_reward[~out.done] == 0).all()), f"{what}: final reward paid where not done"
    assert torch.equal(out.terminated, out.success | out.failure | (False if terminated is None else terminated))
    assert torch.equal(out.done, out.terminated | (False if truncated is None else truncated))
    return out


def drive_transitions(task: Task, config: Config, what: str = "") -> Stats:
    """Drive ``task`` through a random trajectory with :func:`check_step` at every step."""
    generator = torch.Generator().manual_seed(config.seed)
    batch, dtype = torch.Size(config.batch), config.dtype
    n, m = task.state_size, task.action_size
    stats = Stats()

    def normal(*shape: int) -> torch.Tensor:
        return torch.randn(*shape, generator=generator, dtype=torch.float64).to(dtype)

    def coin(p: float) -> torch.Tensor:
        return torch.rand(batch, generator=generator) < p

    available = reset_overrides_for(task) if config.overrides else {}

    def reset(init_state: torch.Tensor) -> TensorDict:
        overrides: dict[str, torch.Tensor] = {}
        if "state_des" in available:
            overrides["state_des"] = 0.7 * normal(*batch, available["state_des"])
        if "start_index" in available:
            overrides["start_index"] = torch.randint(0, available["start_index"], batch, generator=generator)
        return task.reset(init_state, **overrides)

    state = 0.5 * normal(*batch, n)
    memory = reset(state)
    limit = torch.randint(1, config.steps + 1, batch, generator=generator)
    step_count = torch.zeros(batch, dtype=torch.long)
    ended_before = torch.zeros(batch, dtype=torch.bool)  # done earlier in the current episode
    everywhere = torch.ones(batch, dtype=torch.bool)
    for t in range(config.steps):
        action = normal(*batch, m).clamp(-1.0, 1.0)
        next_state = config.state_scale * normal(*batch, n)
        if config.nan:
            hole = torch.rand((*batch, n), generator=generator) < 0.05
            next_state = torch.where(hole, torch.full_like(next_state, math.nan), next_state)
        terminated = coin(0.15) if config.terminated == "random" else None
        at_limit = step_count + 1 >= limit
        truncated = {"none": None, "random": coin(0.15), "limit": at_limit}[config.truncated]
        if config.remaining == OMIT:
            remaining: object = OMIT
        elif config.remaining == "int":
            remaining = int(torch.randint(0, 12, (), generator=generator))
        elif config.remaining == "tensor":
            int_dtype = torch.int32 if t % 2 else torch.int64
            remaining = torch.randint(0, 12, batch, generator=generator, dtype=int_dtype)
        elif config.remaining == "broadcast":
            remaining = torch.randint(0, 12, batch[-1:], generator=generator)
        else:
            remaining = (limit - step_count - 1).clamp(min=0)
        step_what = f"{what} step {t}"
        inputs = (state, action, next_state, memory, remaining, terminated, truncated, config.reward_on)
        out = check_step(task, *inputs, step_what, explicit=bool(t % 2))
        assert bool((out.final_reward[ended_before] == 0).all()), f"{step_what}: final reward paid twice"
        # the same memory again, with every env done: no env that just ended (or ended before) is paid again
        again = task.transition(
            next_state, action, next_state, out.memory, 0 if remaining is OMIT else remaining, truncated=everywhere
        )
        ended = ended_before | out.done
        assert bool((again.final_reward[ended] == 0).all()), f"{step_what}: final reward paid again after done"
        stats.steps += 1
        stats.success += int(out.success.sum())
        stats.failure += int(out.failure.sum())
        stats.terminated_by_env += int((out.terminated & ~out.success & ~out.failure).sum())
        stats.truncated += int((out.done & ~out.terminated).sum())
        paid = out.final_reward != 0
        stats.final_paid += int(paid.sum())
        stats.latched += int((paid & (again.final_reward == 0)).sum())
        stats.terms += len(out.terms)
        # the next state and memory
        if config.resets == "never":
            reset_rows = torch.zeros(batch, dtype=torch.bool)
        elif config.resets == "random":
            reset_rows = coin(0.3)
        else:
            reset_rows = out.done
        fresh_state = 0.5 * normal(*batch, n)
        memory = where_memory(reset_rows, reset(fresh_state), out.memory)
        state = torch.where(reset_rows.unsqueeze(-1), fresh_state, next_state)
        step_count = torch.where(reset_rows, torch.zeros_like(step_count), step_count + 1)
        ended_before = ended & ~reset_rows
    return stats


# ------------------------------------------------------------------------------ properties
@SETTINGS
@given(tree=any_task(), config=configs)
def test_transition_equals_fine_grained_calls(tree: tuple[Task, str], config: Config) -> None:
    task, description = tree
    drive_transitions(task, config, f"{description} {config}")


@settings(SETTINGS, max_examples=50)
@given(tree=term_trees(), config=configs)
def test_transition_terms_equal_step_reward_terms(tree: tuple[Task, str], config: Config) -> None:
    """Trees around rewards with named terms (compound, locomotion; stateful and stateless)."""
    task, description = tree
    stats = drive_transitions(task, config, f"{description} {config}")
    assert stats.terms == (len(task.term_names) * stats.steps)


@pytest.mark.parametrize("reward_on", ["next", "state"])
@pytest.mark.parametrize("name", sorted(FIXED_CASES))
def test_fixed_cases_transition_equals_fine_grained_calls(name: str, reward_on: str) -> None:
    """Every task class, predefined factory and example tree (deterministic): float64 and float32."""
    for dtype, batch in ((torch.float64, (2, 3)), (torch.float32, (4,))):
        config = Config(batch, 8, dtype, reward_on, "random", "limit", "limit", "done", True, False, 1.0, seed=5)
        drive_transitions(FIXED_CASES[name](), config, f"{name} {dtype}")


def test_driver_exercises_every_kind_of_episode_end() -> None:
    """The properties above only bite if successes, failures, env terminations, truncations, paid final
    rewards and the paid-once latch all occur."""
    total = Stats()
    for name in sorted(FIXED_CASES):
        for seed, resets in ((1, "done"), (2, "never")):
            config = Config((6,), 10, torch.float64, "next", "random", "limit", "limit", resets, True, False, 1.0, seed)
            stats = drive_transitions(FIXED_CASES[name](), config, name)
            for field in vars(total):
                setattr(total, field, getattr(total, field) + getattr(stats, field))
    assert all(value > 0 for value in vars(total).values()), total


def test_final_reward_is_paid_once_per_episode() -> None:
    """A done transition pays the final reward; the same memory pays 0 on every later done call; a reset pays again."""
    spec = EnvSpec(Box([-1.0], [1.0]), 1)
    near = functools.partial(proximity_succeeded, threshold=0.1)
    task = FinalRewardTask(DesiredStateTask(spec, [0.5], QuadraticErrorReward([1.0], None), near), factor=10.0)
    state, action = torch.zeros(3, 1), torch.zeros(3, 1)
    next_state = torch.tensor([[0.5], [2.0], [0.0]])  # success, failure, neither
    truncated = torch.tensor([False, False, True])
    memory = task.reset(state)
    out = task.transition(state, action, next_state, memory, truncated=truncated)
    assert out.done.tolist() == [True, True, True]
    assert out.final_reward.tolist() == [10.0, -10.0, 0.0]
    for _ in range(2):
        out = task.transition(state, action, next_state, out.memory, truncated=truncated)
        assert out.done.tolist() == [True, True, True]
        assert out.final_reward.tolist() == [0.0, 0.0, 0.0]
    memory = where_memory(torch.tensor([True, False, False]), task.reset(state), out.memory)
    out = task.transition(state, action, next_state, memory, truncated=truncated)
    assert out.final_reward.tolist() == [10.0, 0.0, 0.0]


def _dtype_params() -> list[object]:
    params = []
    for name in sorted(FIXED_CASES):
        for batch in ((), (3,)):
            params.append(pytest.param(name, batch, id=f"{name}-{batch}"))
    return params


@pytest.mark.parametrize(("name", "batch"), _dtype_params())
def test_outputs_follow_the_state_dtype(name: str, batch: tuple[int, ...]) -> None:
    """Float32 states on a task built with float64 constants: rewards, terms and float memory stay float32."""
    task = FIXED_CASES[name]()
    generator = torch.Generator().manual_seed(3)
    state = torch.randn(*batch, task.state_size, generator=generator)
    action = torch.randn(*batch, task.action_size, generator=generator).clamp(-1.0, 1.0)
    memory = task.reset(state)
    for t in range(3):
        next_state = torch.randn(*batch, task.state_size, generator=generator)
        truncated = torch.full(batch, t == 2)
        out = task.transition(state, action, next_state, memory, 2 - t, truncated=truncated, reward_on="state")
        found = {field: getattr(out, field).dtype for field in REWARD_FIELDS}
        found.update({f"term {key}": value.dtype for key, value in out.terms.items()})
        found.update(
            {
                f"memory {key}": value.dtype
                for key, value in out.memory.items(include_nested=True, leaves_only=True)
                if value.is_floating_point()
            }
        )
        wrong = {key: dtype for key, dtype in found.items() if dtype != torch.float32}
        assert not wrong, f"step {t}: not float32: {wrong}"
        state, memory = next_state, out.memory


# ------------------------------------------------------------------------------ validation
N_ENVS = 4


def _validation_task() -> FinalRewardTask:
    spec = full_spec()
    near = functools.partial(proximity_succeeded, threshold=1.0)
    inner = DesiredStateTask(spec, [0.0] * 4, QuadraticErrorReward([1.0] * 4, [0.5, 0.5]), near)
    return FinalRewardTask(inner, factor=5.0)


def _valid_arguments(task: Task) -> dict[str, object]:
    generator = torch.Generator().manual_seed(0)
    state = torch.randn(N_ENVS, task.state_size, generator=generator, dtype=torch.float64)
    return {
        "state": state,
        "action": torch.zeros(N_ENVS, task.action_size, dtype=torch.float64),
        "next_state": state + 0.5,
        "memory": task.reset(state),
        "remaining_steps": 3,
        "terminated": torch.zeros(N_ENVS, dtype=torch.bool),
        "truncated": torch.tensor([False, True, False, True]),
        "reward_on": "next",
    }


def _other_memory(task: Task) -> TensorDictBase:
    """The memory of another task tree (a goalless task with a stateful reward) for the same states."""
    other = GoallessTask(task.spec, ForwardVelocityReward(0.1, 0))
    return other.reset(torch.zeros(N_ENVS, task.state_size, dtype=torch.float64))


def _without(memory: TensorDictBase, key: str | tuple[str, ...]) -> TensorDictBase:
    memory = memory.clone()
    del memory[key]
    return memory


#: (id, argument, bad value builder (task, valid memory) -> value, error); the match is MATCH[id] or the argument
INVALID = [
    ("next_state_one_env", "next_state", lambda t, m: torch.zeros(1, t.state_size, dtype=torch.float64), ValueError),
    (
        "next_state_wider",
        "next_state",
        lambda t, m: torch.zeros(N_ENVS, t.state_size + 1, dtype=torch.float64),
        ValueError,
    ),
    ("next_state_int", "next_state", lambda t, m: torch.zeros(N_ENVS, t.state_size, dtype=torch.long), TypeError),
    ("next_state_not_tensor", "next_state", lambda t, m: [[0.0] * t.state_size] * N_ENVS, TypeError),
    ("next_state_float32", "next_state", lambda t, m: torch.zeros(N_ENVS, t.state_size), TypeError),
    ("truncated_column", "truncated", lambda t, m: torch.zeros(N_ENVS, 1, dtype=torch.bool), ValueError),
    ("truncated_one_env", "truncated", lambda t, m: torch.zeros(1, dtype=torch.bool), ValueError),
    ("truncated_float", "truncated", lambda t, m: torch.zeros(N_ENVS), TypeError),
    ("truncated_python_bool", "truncated", lambda t, m: True, TypeError),
    ("terminated_column", "terminated", lambda t, m: torch.zeros(N_ENVS, 1, dtype=torch.bool), ValueError),
    ("terminated_float", "terminated", lambda t, m: torch.zeros(N_ENVS, dtype=torch.float64), TypeError),
    ("terminated_int", "terminated", lambda t, m: torch.zeros(N_ENVS, dtype=torch.long), TypeError),
    ("reward_on_bogus", "reward_on", lambda t, m: "bogus", ValueError),
    ("memory_of_other_tree", "memory", lambda t, m: _other_memory(t), ValueError),
    ("memory_key_deleted", "memory", lambda t, m: _without(m, "paid"), ValueError),
    ("memory_nested_key_deleted", "memory", lambda t, m: _without(m, ("wrapped", "state_des")), ValueError),
    ("memory_batch_size", "memory", lambda t, m: t.reset(torch.zeros(N_ENVS - 1, t.state_size)), ValueError),
    ("memory_not_tensordict", "memory", lambda t, m: dict(m.items()), TypeError),
]

#: what the error message must name (the argument, or the offending memory keys)
MATCH = {
    "memory_of_other_tree": r"missing key\(s\) \['paid', 'wrapped'\] and unexpected key\(s\) \['reward'\]",
    "memory_key_deleted": r"missing key\(s\) \['paid'\]",
    "memory_nested_key_deleted": r"memory\[\('wrapped',\)\] has missing key\(s\) \['state_des'\]",
    "memory_batch_size": r"memory has batch size \(3,\)",
    "memory_not_tensordict": r"memory must be the TensorDict returned by reset\(\), got dict",
}


def test_valid_arguments_are_accepted() -> None:
    """The baseline of the validation tests: only the one replaced argument makes them fail."""
    task = _validation_task()
    out = task.transition(**_valid_arguments(task))
    assert out.done.tolist() == [bool(v) for v in out.success | out.failure | torch.tensor([False, True, False, True])]
    for argument in ("terminated", "truncated"):
        task.transition(**{**_valid_arguments(task), argument: None})
    task.transition(**{**_valid_arguments(task), "reward_on": "state"})


@pytest.mark.parametrize(("argument", "bad", "error"), [pytest.param(*case[1:], id=case[0]) for case in INVALID])
def test_transition_rejects_invalid_argument(request: pytest.FixtureRequest, argument: str, bad, error) -> None:
    task = _validation_task()
    arguments = _valid_arguments(task)
    arguments[argument] = bad(task, arguments["memory"])
    match = MATCH.get(request.node.callspec.id, argument)
    with pytest.raises(error, match=match):
        task.transition(**arguments)


def test_parallel_rejects_memory_of_a_longer_parallel() -> None:
    """ParallelTasks([a, b]) given the memory of ParallelTasks([a, b, c]) (same sub-task memories, one more)."""
    spec = full_spec()
    leaves = [
        DesiredStateTask(spec, [0.0] * 4, QuadraticErrorReward([1.0] * 4, None)),
        GoallessTask(spec, ForwardVelocityReward(0.1, 3)),
        DesiredStateTask(spec, [1.0] * 4, QuadraticErrorReward([1.0] * 4, None)),
    ]
    two, three = ParallelTasks(leaves[:2]), ParallelTasks(leaves)
    arguments = _valid_arguments(two)
    arguments["memory"] = three.reset(arguments["state"])
    with pytest.raises(ValueError, match=r"memory has unexpected key\(s\) \['task2'\]"):
        two.transition(**arguments)
    # the sub-tasks' memories are the same: with the extra entry dropped the memory is accepted
    arguments["memory"] = two.reset(arguments["state"])
    two.transition(**arguments)
