"""Costs beside the reward: :class:`ConstrainedTask` adds named costs (constraints of a CMDP) to a task.

A cost is built like a reward term: any stateless torchtasks reward function (an indicator, a
tolerance kernel, a quadratic penalty), evaluated in the same :meth:`~torchtasks.tasks.Task.transition`
call as the reward, on the raw state the step reward sees (``next_state`` by default) and the action.
It is reported beside the reward, never added to it: ``TaskOutput.costs`` holds ``{name: cost[*B]}``, and
a :class:`~torchtasks.transforms.TaskTransform` writes them as ``("next", "cost")`` and per-constraint
entries. Each constraint may carry a limit on its expected episode cost (``cost_limit``, as
Safety-Gymnasium's and OmniSafe's ``cost_limit: 25``), which a Lagrangian method reads.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch
from torch import nn

from torchtasks.rewards.base import RewardFunction
from torchtasks.tasks.protocol import Task
from torchtasks.tasks.wrapper import ForwardingTask

__all__ = ["ConstrainedTask", "Constraint"]


class Constraint(nn.Module):
    """One named cost of a :class:`ConstrainedTask`: a stateless reward function and an optional limit.

    Args:
        cost: the cost per step, a stateless torchtasks :class:`~torchtasks.rewards.RewardFunction`
            called with the raw state ``[*B, n]`` and the action ``[*B, m]`` (returns ``[*B]``).
        limit: the limit on the expected cost per episode (finite, ``>= 0``), or ``None``.

    Example:
        >>> from torchtasks.rewards import StateFunctionReward
        >>> from torchtasks.tasks import Constraint
        >>> over_one = StateFunctionReward(lambda s: (s[..., 0] > 1.0).to(s.dtype), negate=False)
        >>> speeding = Constraint(over_one, limit=25.0)
        >>> speeding.limit
        25.0
    """

    def __init__(self, cost: RewardFunction, limit: float | None = None) -> None:
        super().__init__()
        if not isinstance(cost, RewardFunction):
            raise TypeError(f"Constraint: cost must be a torchtasks RewardFunction, got {type(cost).__name__}")
        if cost.stateful:
            raise ValueError(
                f"Constraint: the cost must be stateless (a function of one transition), got the stateful "
                f"{type(cost).__name__}"
            )
        if limit is not None:
            if isinstance(limit, bool) or not isinstance(limit, (int, float)):
                raise TypeError(f"Constraint: limit must be a number or None, got {limit!r}")
            if not math.isfinite(limit) or limit < 0:
                raise ValueError(f"Constraint: limit must be finite and >= 0, got {limit!r}")
            limit = float(limit)
        self.cost = cost
        self.limit = limit

    def extra_repr(self) -> str:
        return f"limit={self.limit}"


class ConstrainedTask(ForwardingTask):
    """A task with named costs beside its reward: ``transition`` returns them in ``TaskOutput.costs``.

    The wrapped task's reward, flags, final rewards, memory and goals are unchanged: the constrained
    task forwards everything to it (its memory is the wrapped task's memory, no extra level) and adds
    its constraints' costs, evaluated on the raw state the step reward sees (``next_state``, or
    ``state`` with ``reward_on="state"``) and the action. Costs compose like reward terms: a
    ``ConstrainedTask`` anywhere in a tree (inside masks, wrappers, composites) adds its costs to the
    tree's, under unique names; a :class:`~torchtasks.tasks.MaskedTask` hands its selection to the
    costs inside it; shaping (:class:`~torchtasks.tasks.PotentialShapingTask`) and final rewards never
    change them. Costs are not added to the reward and end no episode: a constraint that should end
    the episode is a failure condition.

    Args:
        task: the task whose reward and flags are kept.
        constraints: ``{name: Constraint}`` (or ``{name: RewardFunction}`` for a cost without a limit);
            names are identifiers, unique in the tree.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import ConstantReward, StateFunctionReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import ConstrainedTask, Constraint, GoallessTask
        >>> speeding = StateFunctionReward(lambda s: (s[..., 0].abs() > 1.0).to(s.dtype), negate=False)
        >>> task = ConstrainedTask(GoallessTask(EnvSpec(1, 1), ConstantReward(1.0)),
        ...                        {"speed": Constraint(speeding, limit=25.0)})
        >>> state, next_state = torch.zeros(2, 1), torch.tensor([[0.5], [2.0]])
        >>> out = task.transition(state, torch.zeros(2, 1), next_state, task.reset(state))
        >>> out.reward, out.costs["speed"], task.cost_limits
        (tensor([1., 1.]), tensor([0., 1.]), {'speed': 25.0})
    """

    def __init__(self, task: Task, constraints: Mapping[str, Constraint | RewardFunction]) -> None:
        if not isinstance(task, Task):
            raise TypeError(f"ConstrainedTask: task must be a torchtasks Task, got {type(task).__name__}")
        super().__init__(task.spec, task)
        if not isinstance(constraints, Mapping) or not constraints:
            raise TypeError(
                f"ConstrainedTask: constraints must be a non-empty mapping {{name: Constraint}}, got {constraints!r}"
            )
        built: dict[str, Constraint] = {}
        for name, constraint in constraints.items():
            if not isinstance(name, str) or not name.isidentifier():
                raise ValueError(f"ConstrainedTask: constraint names must be identifiers, got {name!r}")
            if isinstance(constraint, RewardFunction):
                constraint = Constraint(constraint)
            if not isinstance(constraint, Constraint):
                raise TypeError(
                    f"ConstrainedTask: the constraint {name!r} must be a Constraint or a RewardFunction, got "
                    f"{type(constraint).__name__}"
                )
            constraint.cost.check_sizes(task.state_size, task.action_size)
            built[name] = constraint
        taken = set(task.cost_names) & set(built)
        if taken:
            raise ValueError(
                f"ConstrainedTask: cost names must be unique in the tree; {sorted(taken)} already name costs of the "
                f"wrapped task (its costs: {list(task.cost_names)})"
            )
        self.constraints = nn.ModuleDict(built)

    @property
    def cost_names(self) -> tuple[str, ...]:
        return (*self.wrapped_task.cost_names, *self.constraints.keys())

    @property
    def cost_limits(self) -> dict[str, float | None]:
        limits = self.wrapped_task.cost_limits
        limits.update((name, constraint.limit) for name, constraint in self.constraints.items())
        return limits

    # ------------------------------------------------------------------ evaluation
    def _step_costs(self, state: torch.Tensor, action: torch.Tensor) -> dict[str, torch.Tensor]:
        costs = self.wrapped_task._step_costs(state, action)
        for name, constraint in self.constraints.items():
            costs[name] = constraint.cost._value(state, action)
        return costs
