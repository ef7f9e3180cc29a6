"""Shared builders for task-tree tests: hypothesis strategies, fixed example trees and an env driver.

Every tree is built for :func:`full_spec` (4 labelled state entries, partly bounded, and 2 actions) so
that random trees can be composed freely: leaves that need another size (a masked sub-spec, the 1-D
state of :class:`FlippingTask`) sit inside a :class:`MaskedTask`.

:func:`drive` replays the environment protocol of the TorchRL transform on a batch of environments::

    r      = step_reward(s_{t+1} (or s_t), a_t, memory, remaining)
    done   = is_done(s_{t+1}) | time_limit
    final  = final_reward(s_{t+1}, memory, remaining, done)
    memory = where_memory(done, reset(new_s0, **overrides), memory)   # partial reset

with per-environment random data generated up front (:func:`make_drive_data`), so the same data can
be fed to a batch run and to one batch-1 run per environment.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from hypothesis import strategies as st
from tensordict import TensorDictBase

from torchtasks.rewards import (
    AntForwardReward,
    ConstantReward,
    CosineReward,
    ExpQuadraticErrorReward,
    ForwardVelocityReward,
    QuadraticErrorReward,
    ShiftedCosineReward,
    StateFunctionReward,
)
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import (
    BestStateFinalRewardTask,
    ConditionTask,
    ConstrainedTask,
    DesiredSpaceTask,
    DesiredStateTask,
    FinalRewardMode,
    FinalRewardTask,
    FlippingTask,
    GoallessTask,
    MaskedTask,
    OptimizationTask,
    ParallelTasks,
    PotentialShapingTask,
    RadiallySymmetricDesiredStateTask,
    RewardGroupsTask,
    SequentialTasks,
    Task,
    proximity_succeeded,
)
from torchtasks.tasks.memory import where_memory

__all__ = [
    "ACTION_LABELS",
    "CANNOT_SUCCEED",
    "NAMED_END_CONDITIONS",
    "STATE_LABELS",
    "SUPPORTED_MODES",
    "DriveData",
    "DriveResult",
    "all_task_cases",
    "around_memoryless_cases",
    "assert_memory_equal",
    "assert_same",
    "class_cases",
    "drive",
    "example_trees",
    "full_spec",
    "make_drive_data",
    "memory_leaves",
    "predefined_cases",
    "predefined_spec",
    "random_transitions",
    "reset_overrides_for",
    "reshape_envs",
    "select_env",
    "shaping_potential",
    "task_trees",
]

STATE_LABELS = ("a", "b", "c", "d")
ACTION_LABELS = ("u", "v")

#: every FinalRewardMode combination torchtasks supports (user_input excluded)
SUPPORTED_MODES = (
    FinalRewardMode(),
    FinalRewardMode(always_positive=True),
    FinalRewardMode(always_negative=True),
    FinalRewardMode(state_dependent=True, always_positive=True),
    FinalRewardMode(state_dependent=True, always_negative=True),
    FinalRewardMode(state_dependent=True),
    FinalRewardMode(state_dependent=True, time_dependent=True),
    FinalRewardMode(time_dependent=True),
    FinalRewardMode(time_dependent=True, always_positive=True),
    FinalRewardMode(time_dependent=True, always_negative=True),
)


def full_spec() -> EnvSpec:
    """The spec every generated tree is built for: 4 states (``a, b`` in ±2, ``c`` in ±3, ``d`` free), 2 actions."""
    state = Box([-2.0, -2.0, -3.0, -math.inf], [2.0, 2.0, 3.0, math.inf], labels=STATE_LABELS)
    action = Box([-1.0, -1.0], [1.0, 1.0], labels=ACTION_LABELS)
    return EnvSpec(state, action)


def _sub_spec(spec: EnvSpec, state_positions: list[int], action_positions: list[int] | None) -> EnvSpec:
    action = spec.action_space if action_positions is None else spec.action_space.select(action_positions)
    return EnvSpec(spec.state_space.select(state_positions), action)


def _mixed_selection(spec_box: Box, positions: list[int], as_label: list[bool]) -> list[int | str]:
    """Express positions as ints or labels (mixed), the way users may pass them."""
    if spec_box.labels is None:
        return list(positions)
    return [spec_box.labels[p] if label else p for p, label in zip(positions, as_label, strict=True)]


# ------------------------------------------------------------------------------ hypothesis strategies
_unit = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)


def _draw_vector(draw: Callable, size: int, low: float, high: float) -> list[float]:
    return [draw(st.floats(low, high, allow_nan=False, allow_infinity=False)) for _ in range(size)]


def _draw_subset(draw: Callable, size: int, *, min_size: int = 1) -> list[int]:
    """An ordered selection of distinct positions (order matters for MaskedTask)."""
    count = draw(st.integers(min_size, size))
    return draw(st.permutations(list(range(size))))[:count]


def _draw_weight(draw: Callable, size: int) -> torch.Tensor:
    """A PSD weight: a non-negative diagonal vector or a full matrix ``L Lᵀ + diag``."""
    if size == 0:
        return torch.zeros(0)
    diagonal = torch.tensor(_draw_vector(draw, size, 0.0, 2.0), dtype=torch.float64)
    if draw(st.booleans()):
        return diagonal
    factor = torch.tensor(_draw_vector(draw, size * size, -1.0, 1.0), dtype=torch.float64).reshape(size, size)
    return factor @ factor.T + torch.diag(diagonal)


def _draw_error_reward(draw: Callable, spec: EnvSpec):
    Q = _draw_weight(draw, spec.state_size)
    R = None if draw(st.booleans()) else _draw_weight(draw, spec.action_size)
    if draw(st.booleans()):
        return QuadraticErrorReward(Q, R), "Quadratic"
    return ExpQuadraticErrorReward(0.3 * Q, None if R is None else 0.3 * R), "ExpQuadratic"


def _draw_success(draw: Callable, spec: EnvSpec):
    if draw(st.integers(0, 3)) == 0:
        return None, "never"
    threshold = draw(st.floats(0.6, 2.5)) * math.sqrt(spec.state_size)
    dims = None
    if spec.state_size > 1 and draw(st.booleans()):
        dims = _draw_subset(draw, spec.state_size)
    return functools.partial(proximity_succeeded, threshold=threshold, dims=dims), f"prox({threshold:.2f},{dims})"


def _leaf(draw: Callable, spec: EnvSpec) -> tuple[Task, str]:
    kind = draw(
        st.sampled_from(["desired_state", "radial", "desired_space", "flipping", "goalless", "optim", "condition"])
    )
    n = spec.state_size
    if kind == "desired_state":
        reward, reward_name = _draw_error_reward(draw, spec)
        success, success_name = _draw_success(draw, spec)
        state_des = _draw_vector(draw, n, -1.0, 1.0)
        return DesiredStateTask(spec, state_des, reward, success), f"DesiredState({reward_name},{success_name})"
    if kind == "radial":
        reward, reward_name = _draw_error_reward(draw, spec)
        success, success_name = _draw_success(draw, spec)
        positions = _draw_subset(draw, n)
        indices = _mixed_selection(spec.state_space, positions, [draw(st.booleans()) for _ in positions])
        if draw(st.booleans()):
            modulation: float | list[float] = 2 * math.pi
        else:
            modulation = _draw_vector(draw, len(positions), 1.0, 7.0)
        state_des = _draw_vector(draw, n, -3.0, 3.0)
        task = RadiallySymmetricDesiredStateTask(spec, state_des, reward, indices, modulation, success)
        return task, f"Radial({reward_name},{indices},{success_name})"
    if kind == "desired_space":
        low = _draw_vector(draw, n, -1.5, 0.5)
        width = _draw_vector(draw, n, 0.5, 3.0)
        space = Box(low, [lo + w for lo, w in zip(low, width, strict=True)])
        choice = draw(st.integers(0, 2))
        reward = (
            None
            if choice == 0
            else ConstantReward(draw(st.floats(-1.0, 1.0)))
            if choice == 1
            else _draw_error_reward(draw, spec)[0]
        )
        return DesiredSpaceTask(spec, space, reward), f"DesiredSpace(reward{choice})"
    if kind == "flipping":
        position = draw(st.integers(0, n - 1))
        delta = draw(st.sampled_from([math.pi / 2, math.pi, 1.0, 2.5]))
        tol = draw(st.floats(0.05, 0.6))
        endless = draw(st.booleans())
        reward = CosineReward(0) if draw(st.booleans()) else ShiftedCosineReward(0)
        inner = FlippingTask(_sub_spec(spec, [position], None), delta, reward, angle_tol=tol, endless=endless)
        index = _mixed_selection(spec.state_space, [position], [draw(st.booleans())])
        return MaskedTask(spec, inner, index), f"Masked{index}(Flipping({delta:.2f},{tol:.2f},{endless}))"
    if kind == "goalless":
        index = draw(st.integers(0, n - 1))
        dt = draw(st.floats(0.05, 0.5))
        ctrl = draw(st.floats(0.0, 0.5))
        return GoallessTask(spec, ForwardVelocityReward(dt, index, 1.0, ctrl)), f"Goalless(FwdVel({index}))"
    if kind == "optim":
        weights = torch.tensor(_draw_vector(draw, n, -1.0, 1.0), dtype=torch.float64)
        reward = StateFunctionReward(_WeightedSquares(weights), negate=draw(st.booleans()))
        return OptimizationTask(spec, reward), "Optimization"
    threshold = draw(st.floats(0.5, 1.5))
    is_success = draw(st.booleans())
    return ConditionTask(spec, _FirstAbove(threshold), is_success), f"Condition({threshold:.2f},{is_success})"


class _WeightedSquares:
    """``Σ w_i s_i²`` (a picklable/deep-copyable state function)."""

    def __init__(self, weights: torch.Tensor) -> None:
        self.weights = weights

    def __call__(self, state: torch.Tensor) -> torch.Tensor:
        return (state * state * self.weights.to(device=state.device, dtype=state.dtype)).sum(dim=-1)


class _FirstAbove:
    """``state[..., 0] > threshold``."""

    def __init__(self, threshold: float) -> None:
        self.threshold = threshold

    def __call__(self, state: torch.Tensor) -> torch.Tensor:
        return state[..., 0] > self.threshold


def _tree(draw: Callable, spec: EnvSpec, depth: int, top: bool = False) -> tuple[Task, str]:
    # the root is always a combinator (when depth allows); leaves get likelier further down (the
    # simplest draw is a leaf, so failing examples shrink towards small trees)
    if depth == 0 or (not top and draw(st.integers(0, 9)) < 4 - depth):
        return _leaf(draw, spec)
    kind = draw(st.sampled_from(["final", "parallel", "sequential", "masked", "best"]))
    if kind == "final":
        child, name = _tree(draw, spec, depth - 1)
        mode = draw(st.sampled_from(SUPPORTED_MODES))
        factor = draw(st.floats(-50.0, 50.0).filter(lambda f: abs(f) > 0.1))
        flags = "".join(k[0] for k, v in mode._asdict().items() if v) or "-"
        return FinalRewardTask(child, mode, factor), f"Final[{flags}]({name})"
    if kind == "best":
        child, name = _tree(draw, spec, depth - 1)
        factor = draw(st.floats(-3.0, 3.0).filter(lambda f: abs(f) > 0.1))
        return BestStateFinalRewardTask(child, factor), f"Best({name})"
    if kind == "masked":
        positions = _draw_subset(draw, spec.state_size)
        action_positions = None if draw(st.booleans()) else _draw_subset(draw, spec.action_size)
        child, name = _tree(draw, _sub_spec(spec, positions, action_positions), depth - 1)
        state_indices = _mixed_selection(spec.state_space, positions, [draw(st.booleans()) for _ in positions])
        if action_positions is None:
            action_indices = None
        else:
            flags = [draw(st.booleans()) for _ in action_positions]
            action_indices = _mixed_selection(spec.action_space, action_positions, flags)
        return MaskedTask(spec, child, state_indices, action_indices), f"Masked{state_indices},{action_indices}({name})"
    count = draw(st.integers(2, 3 if depth > 1 else 2))
    children = [_tree(draw, spec, depth - 1) for _ in range(count)]
    tasks = [task for task, _ in children]
    names = ", ".join(name for _, name in children)
    hold = draw(st.booleans())
    if kind == "parallel":
        allow = draw(st.booleans())
        easy = draw(st.booleans())
        task = ParallelTasks(tasks, hold_reward_when_done=hold, allow_failures=allow, easily_satisfied=easy)
        return task, f"Parallel[h={hold},a={allow},e={easy}]({names})"
    start = draw(st.integers(0, count - 1))
    task = SequentialTasks(tasks, start_index=start, hold_reward_when_done=hold)
    return task, f"Sequential[s={start},h={hold}]({names})"


@st.composite
def task_trees(draw: Callable, max_depth: int = 3, spec: EnvSpec | None = None) -> tuple[Task, str]:
    """Strategy of ``(task, description)``: a random task tree on ``spec`` (default :func:`full_spec`)."""
    return _tree(draw, full_spec() if spec is None else spec, max_depth, top=True)


# ------------------------------------------------------------------------------ fixed example trees
def _near(threshold: float) -> functools.partial:
    return functools.partial(proximity_succeeded, threshold=threshold)


def example_trees() -> dict[str, Task]:
    """A few fixed trees that together use every task class (for deterministic tests)."""
    spec = full_spec()
    sub = _sub_spec(spec, [2, 0], [1])

    def goal(values: list[float], threshold: float = 2.0, s: EnvSpec = spec) -> DesiredStateTask:
        Q = torch.linspace(0.5, 1.5, s.state_size, dtype=torch.float64)
        return DesiredStateTask(s, values, QuadraticErrorReward(Q, [0.2] * s.action_size), _near(threshold))

    flip = MaskedTask(
        spec, FlippingTask(spec.select_state(["b"]), math.pi, CosineReward(0), angle_tol=0.5, endless=False), ["b"]
    )
    radial = RadiallySymmetricDesiredStateTask(
        spec, [0.5, 3.0, -2.0, 0.0], ExpQuadraticErrorReward([0.3, 0.3, 0.3, 0.1], [0.1, 0.1]), [1, "c"], 2 * math.pi
    )
    walk = GoallessTask(spec, ForwardVelocityReward(0.2, 3, 1.0, 0.1))
    space = DesiredSpaceTask(spec, Box([-0.5] * 4, [1.0] * 4), QuadraticErrorReward([0.1] * 4, None))
    masked_goal = MaskedTask(spec, goal([0.2, -0.3], 1.2, sub), ["c", 0], ["v"])
    trees = {
        "final_parallel": FinalRewardTask(
            ParallelTasks([goal([0.5, 0.0, 0.0, 0.0]), flip, walk], hold_reward_when_done=True, allow_failures=True),
            FinalRewardMode(state_dependent=True, time_dependent=True),
            factor=10.0,
        ),
        "sequential_nested": SequentialTasks(
            [
                FinalRewardTask(masked_goal, FinalRewardMode(always_positive=True), 5.0),
                BestStateFinalRewardTask(ParallelTasks([radial, space], easily_satisfied=True), 2.0),
                FinalRewardTask(goal([-0.5, 0.5, 0.0, 1.0]), FinalRewardMode(time_dependent=True)),
            ],
            start_index=1,
            hold_reward_when_done=True,
        ),
        "best_masked_sequential": BestStateFinalRewardTask(
            MaskedTask(
                spec,
                SequentialTasks(
                    [
                        goal([0.0, 0.0, 0.0, 0.0], 1.5, spec.select_state(["d", "a", "c", "b"])),
                        FinalRewardTask(
                            OptimizationTask(
                                spec.select_state(["d", "a", "c", "b"]),
                                StateFunctionReward(_WeightedSquares(torch.tensor([1.0, 0.5, 0.0, 0.2]))),
                            )
                        ),
                    ],
                    hold_reward_when_done=False,
                ),
                ["d", "a", "c", "b"],
            ),
            -1.5,
        ),
        "parallel_condition": ParallelTasks(
            [
                ConditionTask(spec, _FirstAbove(1.0), is_success=True),
                FinalRewardTask(walk, FinalRewardMode(state_dependent=True), 3.0),
                FinalRewardTask(flip, FinalRewardMode(always_negative=True, time_dependent=True)),
            ],
            easily_satisfied=True,
        ),
    }
    return trees


# ------------------------------------------------------------------------------ one case per class
def predefined_spec() -> EnvSpec:
    """A spec with every label the predefined factories look for (7 states, 2 actions)."""
    labels = ["x", "z", "phi", "CollCost", "DiscrepTS_y", "GD_DS0", "GD_DS0d"]
    state = Box(
        [-3.0, -2.0, -math.inf, -math.inf, -2.0, -3.0, -3.0], [3.0, 2.0, math.inf, math.inf, 2.0, 3.0, 3.0], labels
    )
    return EnvSpec(state, Box([-1.0, -1.0], [1.0, 1.0], labels=ACTION_LABELS))


def class_cases() -> dict[str, Callable[[], Task]]:
    """Builders of one small task per task class and per notable configuration.

    Constants are dyadic where possible (exact in float32), except angles such as 2π.
    """
    spec = full_spec()
    sub = _sub_spec(spec, [2, 0], [1])

    def goal(s: EnvSpec = spec, threshold: float = 2.0) -> DesiredStateTask:
        n = s.state_size
        Q = torch.full((n, n), 0.125, dtype=torch.float64) + 0.5 * torch.eye(n, dtype=torch.float64)
        des = [0.5, -0.25, 0.0, 0.125][:n]
        return DesiredStateTask(s, des, QuadraticErrorReward(Q, [0.5, 0.25][: s.action_size]), _near(threshold))

    def walk() -> GoallessTask:
        return GoallessTask(spec, ForwardVelocityReward(0.25, 3, 1.0, 0.5))

    def radial() -> RadiallySymmetricDesiredStateTask:
        reward = ExpQuadraticErrorReward([0.25, 0.5, 0.25, 0.125], [0.125, 0.125])
        return RadiallySymmetricDesiredStateTask(
            spec, [0.5, 3.0, -2.5, 0.0], reward, [1, "c"], [2 * math.pi, 3.0], _near(2.5)
        )

    def flip() -> FlippingTask:
        return FlippingTask(EnvSpec(Box(-4.0, 4.0), 2), math.pi / 2, CosineReward(0), angle_tol=0.5, endless=False)

    def masked() -> MaskedTask:
        return MaskedTask(spec, goal(sub, 1.5), ["c", 0], ["v"])

    def final(task: Task, **flags: bool) -> FinalRewardTask:
        return FinalRewardTask(task, FinalRewardMode(**flags), factor=4.0)

    def ant() -> GoallessTask:
        reward = AntForwardReward(
            0.25,
            contact_cost_weight=0.0625,
            healthy_z_range=(-1.0, 1.0),
            terminate_when_unhealthy=True,
            x_index=0,
            z_index=1,
            contact_forces_start=2,
        )
        return GoallessTask(spec, reward)

    return {
        "desired_state": goal,
        "radially_symmetric": radial,
        "desired_space": lambda: DesiredSpaceTask(
            spec, Box([-0.5] * 4, [1.0] * 4), QuadraticErrorReward([0.25] * 4, [0.5, 0.5])
        ),
        "goalless_forward_velocity": walk,
        "goalless_ant": ant,
        "optimization": lambda: OptimizationTask(
            spec, StateFunctionReward(_WeightedSquares(torch.tensor([1.0, 0.5, 0.0, 0.25])))
        ),
        "condition_success": lambda: ConditionTask(spec, _FirstAbove(0.5), is_success=True),
        "condition_failure": lambda: ConditionTask(spec, _FirstAbove(0.5), is_success=False),
        "flipping": flip,
        "final_default": lambda: final(goal()),
        "final_state_time": lambda: final(goal(), state_dependent=True, time_dependent=True),
        "final_state_goalless": lambda: final(walk(), state_dependent=True),
        "final_negative_state": lambda: final(goal(), state_dependent=True, always_negative=True),
        "final_positive_time": lambda: final(goal(), time_dependent=True, always_positive=True),
        "best_state": lambda: BestStateFinalRewardTask(goal(), -2.0),
        "masked": masked,
        "masked_flipping": lambda: MaskedTask(
            spec, FlippingTask(spec.select_state(["b"]), math.pi, CosineReward(0), 0.5), ["b"]
        ),
        "parallel": lambda: ParallelTasks([goal(), walk(), radial()], hold_reward_when_done=True, allow_failures=True),
        "sequential": lambda: SequentialTasks([goal(), masked(), walk()], start_index=1, hold_reward_when_done=True),
        "nested_parallel_sequential": lambda: final(
            ParallelTasks(
                [
                    MaskedTask(spec, SequentialTasks([goal(sub, 1.5), final(goal(sub, 1.0))]), ["c", "a"], ["v"]),
                    BestStateFinalRewardTask(walk(), 0.5),
                ],
                easily_satisfied=True,
            ),
            state_dependent=True,
        ),
        "nested_sequential_masked": lambda: SequentialTasks(
            [
                MaskedTask(spec, final(flip_on_b(spec)), ["b"]),
                ParallelTasks([final(goal(), time_dependent=True), masked()], hold_reward_when_done=True),
            ],
            hold_reward_when_done=True,
        ),
    }


def flip_on_b(spec: EnvSpec) -> FlippingTask:
    return FlippingTask(spec.select_state(["b"]), math.pi / 2, ShiftedCosineReward(0), angle_tol=0.4, endless=False)


def predefined_cases() -> dict[str, Callable[[], Task]]:
    """Builders of every predefined factory on :func:`predefined_spec`."""
    from torchtasks import predefined

    spec = predefined_spec()
    return {
        "predefined_check_all_boundaries": lambda: predefined.check_all_boundaries_task(spec, 8.0),
        "predefined_task_space_discrepancy": lambda: predefined.task_space_discrepancy_task(
            spec, QuadraticErrorReward([2.0], None)
        ),
        "predefined_collision": lambda: predefined.collision_task(spec, 2.0),
        "predefined_force_min": lambda: predefined.force_min_task(spec, ["x", "z"], [[1.0, 0.25], [0.25, 0.5]]),
        "predefined_lifting": lambda: predefined.lifting_task(spec, ["z"], 0.5, success_threshold=0.5),
        "predefined_flipping": lambda: predefined.flipping_task(spec, ["phi"], endless=False),
        "predefined_home_position": lambda: predefined.home_position_task(spec, ["x", "phi"], [0.25, 0.5]),
        "predefined_goal_distance": lambda: predefined.goal_distance_task(
            spec, 0, ExpQuadraticErrorReward([1.0], [0.125, 0.125]), 0.5
        ),
        "predefined_goal_distance_velocity": lambda: predefined.goal_distance_velocity_task(
            spec, 0, QuadraticErrorReward([1.0, 0.5], None), 0.75
        ),
    }


# ------------------------------------------------------------- every task, and random transitions
# (shared by tasks/test_composition.py and transforms/test_transform_entries.py)
def shaping_potential(state: torch.Tensor) -> torch.Tensor:
    return -(state - 0.25).square().sum(-1)


def _shaped_cases() -> dict[str, Callable[[], Task]]:
    cases = class_cases()
    return {
        "shaping_goal": lambda: PotentialShapingTask(cases["desired_state"](), shaping_potential, 0.5),
        "shaping_final": lambda: PotentialShapingTask(cases["final_state_time"](), shaping_potential, 0.9),
        "shaping_walk": lambda: PotentialShapingTask(cases["goalless_forward_velocity"](), shaping_potential, 1.0),
    }


def all_task_cases() -> dict[str, Callable[[], Task]]:
    """:func:`class_cases` and three :class:`PotentialShapingTask` cases around them."""
    return {**class_cases(), **_shaped_cases()}


def memoryless_leaves() -> dict[str, Callable[[], Task]]:
    """Builders of the leaves whose memory holds no tensor: the class cases without memory and a goalless task with
    a stateless reward."""
    cases = class_cases()
    leaves = {name: cases[name] for name in ("desired_space", "optimization", "condition_success", "condition_failure")}
    leaves["goalless_constant"] = lambda: GoallessTask(full_spec(), ConstantReward(0.5))
    return leaves


def around_memoryless_cases() -> dict[str, Callable[[], Task]]:
    """Builders of every wrapper and composite of the tasks package around each memory-less leaf
    (:func:`memoryless_leaves`), and of one tree nesting them: memories with empty sub-memories (a latch beside the
    empty memory of the task it wraps, a composite's flags beside its sub-tasks'). The wrappers whose memory is the
    wrapped task's (a mask, a constraint, reward groups: no memory at all around a memory-less task) wrap one leaf."""
    leaves = memoryless_leaves()
    spec = full_spec()
    sub = _sub_spec(spec, [2, 0], [1])

    def other() -> Task:
        return leaves["goalless_constant"]()

    around: dict[str, Callable[[Task], Task]] = {
        "final": lambda task: FinalRewardTask(task, FinalRewardMode(state_dependent=True), 4.0),
        "best": lambda task: BestStateFinalRewardTask(task, 2.0),
        "shaping": lambda task: PotentialShapingTask(task, shaping_potential, 0.9),
        "sequential": lambda task: SequentialTasks([task, other()], hold_reward_when_done=True),
        "parallel": lambda task: ParallelTasks([task, other()], hold_reward_when_done=True),
    }
    cases = {
        f"{kind}({leaf})": functools.partial(lambda wrap, build: wrap(build()), wrap, build)
        for kind, wrap in around.items()
        for leaf, build in leaves.items()
    }
    cases["constrained(condition_success)"] = lambda: ConstrainedTask(
        leaves["condition_success"](), {"effort": QuadraticErrorReward([0.0] * 4, [0.25, 0.25])}
    )
    cases["groups(goalless_constant)"] = lambda: RewardGroupsTask(other(), {"all": {"step": 1.0}})
    cases["masked(optimization)"] = lambda: MaskedTask(
        spec, OptimizationTask(sub, StateFunctionReward(_WeightedSquares(torch.tensor([1.0, 0.5])))), ["c", "a"], ["v"]
    )
    cases["nested"] = lambda: FinalRewardTask(
        SequentialTasks(
            [
                BestStateFinalRewardTask(leaves["condition_success"](), 2.0),
                ParallelTasks([leaves["desired_space"](), PotentialShapingTask(other(), shaping_potential, 0.5)]),
            ]
        ),
        FinalRewardMode(time_dependent=True),
    )
    return cases


#: the cases of :func:`all_task_cases` whose tree cannot succeed, read off the builders above: a leaf without a success
#: condition (walking, Ant, optimising, a failure condition, endless flipping, a wrapper or shaping around one), or a
#: composite whose success needs one (a parallel's all sub-tasks, unless easily satisfied; a sequence's last)
CANNOT_SUCCEED = frozenset(
    {
        "goalless_forward_velocity",
        "goalless_ant",
        "optimization",
        "condition_failure",
        "final_state_goalless",
        "masked_flipping",
        "parallel",
        "sequential",
        "shaping_walk",
    }
)
#: the cases whose tree names two or more conditions of a kind, with the names (Ant: out of its box or unhealthy);
#: every case can fail (each leaf fails out of its box or on NaN; the parallel case fails when all its sub-tasks do)
NAMED_END_CONDITIONS = {"goalless_ant": ("out_of_bounds", "unhealthy")}


def random_transitions(task: Task, generator: torch.Generator, steps: int, batch: int) -> dict[str, torch.Tensor]:
    """Random states (partly outside the box), actions, episode-end flags, remaining steps and goals."""
    n, m = task.state_size, task.action_size
    shape = (steps + 1, batch)
    states = (torch.rand((*shape, n), generator=generator, dtype=torch.float64) * 5.0 - 2.5).to(torch.float64)
    # nudge some states onto 0.5-ish values so goal tasks succeed now and then
    near = torch.rand((*shape, 1), generator=generator, dtype=torch.float64) < 0.3
    states = torch.where(near, states * 0.05 + 0.25, states)
    draws = {
        "states": states,
        "actions": torch.rand((steps, batch, m), generator=generator, dtype=torch.float64) * 2 - 1,
        "terminated": torch.rand((steps, batch), generator=generator) < 0.15,
        "truncated": torch.rand((steps, batch), generator=generator) < 0.15,
        "remaining": torch.randint(0, 20, (steps, batch), generator=generator),
        "resets": torch.rand((steps, batch, n), generator=generator, dtype=torch.float64) * 2 - 1,
    }
    slots = task.goal_slots
    if len(slots) == 1:
        draws["goals"] = torch.rand((steps, batch, slots[0].size), generator=generator, dtype=torch.float64) - 0.5
    return draws


# ------------------------------------------------------------------------------ driving a batch
@dataclass
class DriveData:
    """Per-environment inputs of a rollout; environment dims are ``[*B]`` after the time dim.

    ``states[t]`` (t = 0..T) are the states the env reports, ``actions[t]`` (t < T) the actions,
    ``reset_states[t]`` the initial state used when the env is reset after step t,
    ``limit[*B]`` the episode-length limit per env (0: no limit, remaining steps then 0),
    ``overrides[t]`` the reset overrides used at reset number t (t = 0: the first reset).
    """

    states: torch.Tensor
    actions: torch.Tensor
    reset_states: torch.Tensor
    limit: torch.Tensor
    overrides: list[dict[str, torch.Tensor]] = field(default_factory=list)

    @property
    def steps(self) -> int:
        return self.actions.shape[0]

    @property
    def batch_shape(self) -> torch.Size:
        return self.limit.shape


@dataclass
class DriveResult:
    """Outputs of :func:`drive`, stacked over time (``[T, *B]``), and the last memory."""

    reward: torch.Tensor
    success: torch.Tensor
    failure: torch.Tensor
    done: torch.Tensor
    final: torch.Tensor
    memory: TensorDictBase
    terms: dict[str, torch.Tensor] = field(default_factory=dict)


def _collect(tasks: list[Task], task: Task) -> None:
    tasks.append(task)
    for child in task.children_tasks():
        _collect(tasks, child)


def reset_overrides_for(task: Task) -> dict[str, int]:
    """Which overrides can be passed to ``task.reset``: ``{"state_des": k, "start_index": K}``.

    An override goes to every task of the tree that understands it, so ``state_des`` is only
    usable when all desired-state tasks have the same size ``k``, and ``start_index`` must be
    below the smallest number of sub-tasks ``K`` of the sequences.
    """
    tasks: list[Task] = []
    _collect(tasks, task)
    result: dict[str, int] = {}
    sizes = {t.state_size for t in tasks if isinstance(t, DesiredStateTask)}
    if len(sizes) == 1:
        result["state_des"] = sizes.pop()
    counts = [t.num_tasks for t in tasks if isinstance(t, SequentialTasks)]
    if counts:
        result["start_index"] = min(counts)
    return result


def make_drive_data(
    task: Task,
    n_envs: int,
    steps: int,
    seed: int,
    *,
    use_overrides: bool = True,
    state_scale: float = 1.0,
) -> DriveData:
    """Random per-environment data for :func:`drive` (float64, batch ``[n_envs]``)."""
    generator = torch.Generator().manual_seed(seed)
    n, m = task.state_size, task.action_size

    def normal(*shape: int) -> torch.Tensor:
        return torch.randn(*shape, generator=generator, dtype=torch.float64)

    states = state_scale * normal(steps + 1, n_envs, n)
    actions = normal(steps, n_envs, m).clamp(-1.0, 1.0)
    reset_states = 0.5 * normal(steps, n_envs, n)
    limit = torch.randint(0, steps + 1, (n_envs,), generator=generator)
    overrides: list[dict[str, torch.Tensor]] = []
    available = reset_overrides_for(task) if use_overrides else {}
    for _ in range(steps + 1):
        entry: dict[str, torch.Tensor] = {}
        if "state_des" in available:
            entry["state_des"] = 0.7 * normal(n_envs, available["state_des"])
        if "start_index" in available:
            entry["start_index"] = torch.randint(0, available["start_index"], (n_envs,), generator=generator)
        overrides.append(entry)
    return DriveData(states, actions, reset_states, limit, overrides)


def _map_envs(data: DriveData, fn: Callable[[torch.Tensor, int], torch.Tensor]) -> DriveData:
    """Apply ``fn(tensor, first_env_dim)`` to every tensor of ``data``."""
    return DriveData(
        states=fn(data.states, 1),
        actions=fn(data.actions, 1),
        reset_states=fn(data.reset_states, 1),
        limit=fn(data.limit, 0),
        overrides=[{k: fn(v, 0) for k, v in entry.items()} for entry in data.overrides],
    )


def select_env(data: DriveData, index: int) -> DriveData:
    """The data of environment ``index`` as a batch of one (``[1]``)."""
    return _map_envs(data, lambda x, dim: x.narrow(dim, index, 1))


def reshape_envs(data: DriveData, batch_shape: tuple[int, ...]) -> DriveData:
    """Reshape the environment dim ``[N]`` of ``data`` into ``batch_shape``."""

    def reshape(x: torch.Tensor, dim: int) -> torch.Tensor:
        return x.reshape(*x.shape[:dim], *batch_shape, *x.shape[dim + 1 :])

    return _map_envs(data, reshape)


ResetHook = Callable[[TensorDictBase, TensorDictBase, TensorDictBase, torch.Tensor], None]


def drive(
    task: Task,
    data: DriveData,
    *,
    reward_on: str = "next",
    terms: bool = False,
    on_reset: ResetHook | None = None,
) -> DriveResult:
    """Run ``task`` through ``data`` with the transform's protocol and partial resets (public API).

    With ``terms`` the step reward comes from ``step_reward_terms`` (what the transform calls
    when it logs the reward breakdown) and the named terms are returned too.
    ``on_reset(memory_before, fresh, memory_after, done)`` is called after every partial reset.
    """
    if reward_on not in ("next", "state"):
        raise ValueError(f"reward_on must be 'next' or 'state', got {reward_on!r}")
    batch = data.batch_shape
    state = data.states[0]
    memory = task.reset(state, **data.overrides[0])
    step_count = torch.zeros(batch, dtype=torch.long)
    limited = data.limit > 0
    outputs: dict[str, list[torch.Tensor]] = {k: [] for k in ("reward", "success", "failure", "done", "final")}
    term_values: dict[str, list[torch.Tensor]] = {}
    for t in range(data.steps):
        action = data.actions[t]
        next_state = data.states[t + 1]
        remaining = torch.where(limited, data.limit - step_count, torch.zeros_like(step_count))
        source = next_state if reward_on == "next" else state
        if terms:
            named, reward, memory = task.step_reward_terms(source, action, memory, remaining)
            for name, value in named.items():
                term_values.setdefault(name, []).append(value)
        else:
            reward, memory = task.step_reward(source, action, memory, remaining)
        success = task.has_succeeded(next_state, memory)
        failure = task.has_failed(next_state, memory)
        task_done = task.is_done(next_state, memory)
        if not torch.equal(task_done, success | failure):
            raise AssertionError(f"is_done {task_done} != success | failure {success | failure}")
        done = task_done | (limited & (step_count + 1 >= data.limit))
        final, memory = task.final_reward(next_state, memory, remaining, done)
        for key, value in zip(outputs, (reward, success, failure, done, final), strict=True):
            outputs[key].append(value)
        fresh = task.reset(data.reset_states[t], **data.overrides[t + 1])
        new_memory = where_memory(done, fresh, memory)
        if on_reset is not None:
            on_reset(memory, fresh, new_memory, done)
        memory = new_memory
        state = torch.where(done.unsqueeze(-1), data.reset_states[t], next_state)
        step_count = torch.where(done, torch.zeros_like(step_count), step_count + 1)
    stacked = {k: torch.stack(v) for k, v in outputs.items()}
    return DriveResult(memory=memory, terms={k: torch.stack(v) for k, v in term_values.items()}, **stacked)


# ------------------------------------------------------------------------------ comparisons
def memory_leaves(memory: TensorDictBase) -> dict[tuple[str, ...] | str, torch.Tensor]:
    """All leaf tensors of a memory TensorDict, keyed by their nested key."""
    return dict(memory.items(include_nested=True, leaves_only=True))


def assert_same(actual: torch.Tensor, expected: torch.Tensor, what: str = "", *, atol: float = 0.0) -> None:
    """Exact equality (NaN equal to NaN, same dtype and shape); ``atol`` for documented op-order slack."""
    torch.testing.assert_close(actual, expected, rtol=0.0, atol=atol, equal_nan=True, msg=lambda m: f"{what}: {m}")


def assert_memory_equal(actual: TensorDictBase, expected: TensorDictBase, what: str = "", *, atol: float = 0.0) -> None:
    """Same keys, batch size and leaf values (NaN equal to NaN)."""
    actual_leaves, expected_leaves = memory_leaves(actual), memory_leaves(expected)
    assert set(actual_leaves) == set(expected_leaves), f"{what}: keys {set(actual_leaves)} != {set(expected_leaves)}"
    assert actual.batch_size == expected.batch_size, f"{what}: {actual.batch_size} != {expected.batch_size}"
    for key, value in expected_leaves.items():
        assert_same(actual_leaves[key], value, f"{what} memory[{key}]", atol=atol)
