"""The tables of the Control Suite's tasks on docs/control_suite.md, generated from the presets themselves.

``docs/conf.py`` replaces the page's marker lines with :func:`observation_table` and :func:`reward_table` at every
build, so the tables say what the code does: each task's env (:func:`~torchtasks.envs.control_suite.control_suite_env`
with one env) gives its control step, its observation entries and its task-state entries with their sizes; its task
gives the reward, written out from its module tree (products, weighted sums, affine maps and tolerances); its record
gives the reset steps. ``python docs/_scripts/control_suite_tables.py`` prints both tables.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Mapping, Sequence
from fractions import Fraction
from typing import Any

import torch

from torchtasks.envs.control_suite import CONTROL_SUITE_TASKS, control_suite_env, control_suite_record
from torchtasks.rewards import AffineReward, CompoundReward, ProductReward, RewardFunction, ToleranceReward
from torchtasks.transforms import TaskTransform

#: the line of docs/control_suite.md that :func:`observation_table` replaces
OBSERVATION_MARKER = "<!-- the table of Control Suite observations, generated from CONTROL_SUITE -->"
#: the line of docs/control_suite.md that :func:`reward_table` replaces
REWARD_MARKER = "<!-- the table of Control Suite rewards and resets, generated from CONTROL_SUITE -->"


# ------------------------------------------------------------------------------------------------ numbers
def number(value: float) -> str:
    """A constant as a reader would write it: ``0.6``, ``∞``, ``π``, ``-π``, ``2π``, ``5/6``."""
    value = float(value)
    if math.isinf(value):
        return "∞" if value > 0 else "-∞"
    for multiple, text in ((1, "π"), (-1, "-π"), (2, "2π"), (-2, "-2π"), (0.5, "π/2"), (-0.5, "-π/2")):
        if value == multiple * math.pi:
            return text
    if value == int(value):
        return str(int(value))
    fraction = Fraction(value).limit_denominator(12)
    if fraction.denominator in (3, 6, 7, 9, 11, 12) and float(fraction) == value:
        return f"{fraction.numerator}/{fraction.denominator}"
    return f"{value:.6g}"


def _interval(low: float, high: float) -> str:
    left = "(" if math.isinf(low) else "["
    right = ")" if math.isinf(high) else "]"
    return f"{left}{number(low)}, {number(high)}{right}"


# ------------------------------------------------------------------------------------------------ rewards
def _entries(indices: Sequence[int] | None, labels: Sequence[str]) -> str:
    """The task-state entries of the columns ``indices`` (``control``, or ``control[0]`` for part of one)."""
    columns = range(len(labels)) if indices is None else indices
    names: dict[str, list[str]] = {}
    for column in columns:
        label = labels[column]
        names.setdefault(re.sub(r"\[\d+\]$", "", label), []).append(label)
    parts = []
    for entry, chosen in names.items():
        whole = [label for label in labels if re.sub(r"\[\d+\]$", "", label) == entry]
        parts.append(entry if chosen == whole else ", ".join(chosen))
    return ", ".join(parts)


def _tolerance(reward: ToleranceReward, labels: Sequence[str]) -> str:
    x = _entries(reward.indices, labels)
    count = len(labels) if reward.indices is None else len(reward.indices)
    lower, upper, margin = (getattr(reward, name).reshape(-1).tolist() for name in ("lower", "upper", "margin"))
    same = all(len(set(values)) == 1 for values in (lower, upper, margin))
    if same:
        bounds = _interval(lower[0], upper[0])
        if margin[0] == 0:
            text = f"1[{x} ∈ {bounds}]"
        else:
            text = f"tol({x}, {bounds}, {number(margin[0])}, {reward.sigmoid}, {number(reward.value_at_margin)})"
    else:
        bounds = " × ".join(_interval(low, high) for low, high in zip(lower, upper, strict=True))
        if all(m == 0 for m in margin):
            text = f"1[{x} ∈ {bounds}]"
        else:
            margins = ", ".join(number(m) for m in margin)
            text = f"tol({x}, {bounds}, ({margins}), {reward.sigmoid}, {number(reward.value_at_margin)})"
    if count > 1 and (same or reward.combine == "mean"):
        text = f"{reward.combine} of {text}"
    return text


def _affine(scale: float, offset: float, inner: str) -> str:
    head = inner if scale == 1 else f"{number(scale)}·{inner}"
    if offset == 0:
        return head
    return f"{head} {'+' if offset > 0 else '-'} {number(abs(offset))}"


def _expression(reward: RewardFunction, labels: Sequence[str], definitions: list[str]) -> str:
    """``reward`` as a formula; named terms of products and sums become names, defined in ``definitions`` (in the
    order a reader meets them)."""
    if isinstance(reward, ToleranceReward):
        return _tolerance(reward, labels)
    if isinstance(reward, AffineReward):
        inner = _expression(reward.reward, labels, definitions)
        if " " in inner and not inner.startswith("tol("):
            inner = f"({inner})"
        return _affine(reward.scale, reward.offset, inner)
    if isinstance(reward, CompoundReward):
        weights = {name: float(weight) for name, weight in reward.weights._buffers.items()}
        names = list(reward.rewards)
        for name in names:  # each definition before those of its own terms
            definitions.append(name)
            slot = len(definitions) - 1
            definitions[slot] = f"{name} = {_expression(reward.rewards[name], labels, definitions)}"
        if isinstance(reward, ProductReward):
            return " · ".join(names)
        return " + ".join(f"{number(weights[name])}·{name}" if name in weights else name for name in names)
    raise TypeError(f"no formula for {type(reward).__name__}")


def reward_formula(reward: RewardFunction, labels: Sequence[str]) -> str:
    """The reward as a formula on the task-state entries, then the definitions of its named terms, outermost first.

    Example:
        >>> from torchtasks.envs.control_suite import control_suite_task
        >>> task = control_suite_task("point_mass-easy")
        >>> print(reward_formula(task.reward, task.spec.state_space.labels))
        near_target · small_control; near_target = tol(distance_to_target, [0, 0.015], 0.015, gaussian, 0.1); \
small_control = 0.2·(mean of tol(control, [0, 0], 1, quadratic, 0)) + 0.8
    """
    definitions: list[str] = []
    formula = _expression(reward, labels, definitions)
    return "; ".join([formula, *definitions])


# ------------------------------------------------------------------------------------------------ resets
def _value(value: Any) -> str:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _step(value)
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, (int, float)):
        return number(value)
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{key}: {_value(item)}" for key, item in value.items()) + "}"
    if isinstance(value, Sequence):
        items = [_value(item) for item in value]
        return f"({items[0]},)" if len(items) == 1 else "(" + ", ".join(items) + ")"
    return repr(value)


def _step(step: Any) -> str:
    """A reset step (a frozen dataclass) as ``Name(arguments)``, leaving out arguments at their defaults."""
    arguments = []
    for field in dataclasses.fields(step):
        value = getattr(step, field.name)
        default = field.default
        if field.default_factory is not dataclasses.MISSING:
            default = field.default_factory()
        if default is dataclasses.MISSING:
            arguments.append(_value(value))
        elif value != default:
            arguments.append(f"{field.name}={_value(value)}")
    return f"{type(step).__name__}({', '.join(arguments)})"


def reset_steps(resets: Any) -> list[str]:
    """What a :class:`~torchtasks.envs.mujoco_declaration.Resets` draws, in order: noise, then each step."""
    drawn = []
    for name in ("qpos_noise", "qvel_noise"):
        noise = getattr(resets, name)
        if noise is not None:
            drawn.append(f"{name}={_step(noise)}")
    drawn.extend(_step(step) for step in resets.steps)
    return drawn


# ------------------------------------------------------------------------------------------------ tables
@dataclasses.dataclass(frozen=True)
class TaskFacts:
    """What the tables say about one task, read from its env."""

    name: str
    timestep: float
    substeps: int
    observation: dict[str, int]
    state: dict[str, int]
    reward: str
    resets: list[str]

    @property
    def flat_size(self) -> int:
        """The size of the flat observation: the sum of the entries' sizes."""
        return sum(self.observation.values())


def _size(spec: Any) -> int:
    return math.prod(spec.shape[1:])


def task_facts(name: str) -> TaskFacts:
    """The facts of the task ``name``, from ``control_suite_env(name, 1)``.

    Example:
        >>> facts = task_facts("walker-walk")
        >>> facts.timestep, facts.substeps, facts.flat_size
        (0.0025, 10, 24)
    """
    env = control_suite_env(name, 1, seed=0)
    try:
        base = env.base_env
        declaration = base.declaration
        spec = base.observation_spec
        task = next(t.task for t in env.transform if isinstance(t, TaskTransform))
        return TaskFacts(
            name=name,
            timestep=float(base.model.opt.timestep),
            substeps=int(base.frame_skip),
            observation={key: _size(spec[key]) for key in declaration.observation},
            state={key: _size(spec[key]) for key in declaration.state},
            reward=reward_formula(task.reward, task.spec.state_space.labels),
            resets=reset_steps(control_suite_record(name).resets(base.model)),
        )
    finally:
        env.close()


def _sized(entries: Mapping[str, int]) -> str:
    return ", ".join(f"`{key}` {size}" for key, size in entries.items())


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def observation_table(facts: Sequence[TaskFacts]) -> str:
    """Per task: the control step (timestep × substeps), the observation entries with their sizes, the flat size."""
    rows = [
        "| task | control step | observation entries (size) | flat |",
        "| --- | --- | --- | ---: |",
    ]
    for fact in facts:
        step = f"{number(fact.timestep)} s × {fact.substeps} = {number(round(fact.timestep * fact.substeps, 12))} s"
        rows.append(f"| {fact.name} | {step} | {_sized(fact.observation)} | {fact.flat_size} |")
    return "\n".join(rows)


def reward_table(facts: Sequence[TaskFacts]) -> str:
    """Per task: the task-state entries with their sizes, the reward as a formula of them, and the reset steps."""
    rows = ["| task | task state (size) | reward | reset steps |", "| --- | --- | --- | --- |"]
    for fact in facts:
        reward = "; ".join(f"`{part}`" for part in fact.reward.split("; "))
        resets = ", ".join(f"`{step}`" for step in fact.resets)
        rows.append(f"| {fact.name} | {_sized(fact.state)} | {_cell(reward)} | {_cell(resets)} |")
    return "\n".join(rows)


def all_task_facts() -> list[TaskFacts]:
    """:func:`task_facts` of every task, in :data:`~torchtasks.envs.control_suite.CONTROL_SUITE_TASKS`' order."""
    with torch.inference_mode():
        return [task_facts(name) for name in CONTROL_SUITE_TASKS]


if __name__ == "__main__":
    facts = all_task_facts()
    print(observation_table(facts), end="\n\n")
    print(reward_table(facts))
