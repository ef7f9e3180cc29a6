"""Vector rewards: :class:`RewardGroupsTask` reports named, ordered groups of a task's reward terms.

A group is a weighted sum of named sources: the tree's step-reward terms (``forward``, ``ctrl``, ...), its step
reward (``"step"``) and final reward (``"final"``), and terms of the group's own (stateless reward functions
evaluated like costs, e.g. a height objective that the scalar reward does not pay). The groups are evaluated in the
same :meth:`~torchtasks.tasks.Task.transition` call as the reward and reported beside it, never instead of it:
``TaskOutput.groups`` holds ``{name: value[*B]}`` and a :class:`~torchtasks.transforms.TaskTransform` writes them
stacked as ``("next", "vector_reward")`` (``[*B, k]``, for one critic per group, TorchRL's ``LineariseRewards`` or
multi-objective RL) and one entry per group.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from torch import nn

from torchtasks._checked_load import CheckedLoad
from torchtasks._checks import SUPPORTED_FLOATS, check_finite_scalar, did_you_mean
from torchtasks.rewards.base import RewardFunction
from torchtasks.tasks.protocol import Task
from torchtasks.tasks.transition import FINAL_SOURCE, STEP_SOURCE
from torchtasks.tasks.wrapper import ForwardingTask

__all__ = ["RewardGroupsTask"]


def _identifier(name: object, what: str) -> str:
    if not isinstance(name, str) or not name.isidentifier():
        raise ValueError(f"RewardGroupsTask: {what} names must be identifiers, got {name!r}")
    return name


#: the prefix of a group's weights buffer (``weights_<group>``: one coefficient per source, in order)
WEIGHTS_PREFIX = "weights_"


class RewardGroupsTask(CheckedLoad, ForwardingTask):
    """A task that reports named groups of its reward terms beside its reward: a vector reward ``[*B, k]``.

    The wrapped task's reward, flags, final rewards, memory, terms, costs and goals are unchanged (its memory is
    this task's memory). Each group is an ordered mapping ``{source: coefficient}``; a source is a named term of
    the wrapped tree's step reward (:attr:`~torchtasks.tasks.Task.term_names`), ``"step"`` (the tree's step
    reward), ``"final"`` (its final reward) or a name of ``terms``: stateless reward functions of the group's own,
    evaluated on the state the step reward sees and the action (like costs) and paid to no scalar reward.

    A group's value is accumulated source by source, in the order given, and rounded to ``dtype`` after each
    addition: ``g = dtype(c0·v0)``, then ``g = dtype(g + c·v)``, each sum computed in the sources' dtype (the
    state's). With the default ``dtype=None`` that is an ordinary sum in the sources' dtype (the groups are then
    written in the reward's dtype). With ``dtype=torch.float32`` and float64 sources it is what numpy's in-place
    ``vec += term`` does on a float32 vector, term after term: MO-Gymnasium's arithmetic, which the
    multi-objective presets reproduce bit for bit. ``dtype=torch.float64`` over float32 sources adds in float32
    and stores float64.

    Each group's coefficients are a buffer ``weights_<group>`` (one per source, in order): in ``state_dict``,
    moved by ``.to()``, a target a :class:`~torchtasks.transforms.Curriculum` can ramp (finite values only). A
    checkpoint of other groups (names, sources, their order, dtype) is refused, and so are non-finite values.

    A tree holds one ``RewardGroupsTask``; wrappers (final rewards, masks, shaping, constraints) may wrap it and
    keep its groups, where ``"step"`` and ``"final"`` are the whole tree's step and final reward. A composite
    (:class:`~torchtasks.tasks.ParallelTasks`, :class:`~torchtasks.tasks.SequentialTasks`) cannot hold one (its
    sub-tasks' terms are not the tree's): wrap the composite instead.

    Args:
        task: the task whose reward terms are grouped.
        groups: ``{group name: {source: coefficient}}``, in order (names are identifiers; coefficients finite).
        terms: ``{name: stateless RewardFunction}``, extra sources (``[*B, n]`` state and ``[*B, m]`` action in,
            ``[*B]`` out); names are identifiers, distinct from the tree's terms, ``"step"`` and ``"final"``.
        dtype: the float dtype the groups are accumulated and written in; ``None``: the terms' dtype, written in
            the reward's dtype.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import CompoundReward, ConstantReward, ControlCostReward, VelocityReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import GoallessTask, RewardGroupsTask
        >>> reward = CompoundReward({"forward": VelocityReward(1.0, index=0), "ctrl": ControlCostReward(0.1),
        ...                          "alive": ConstantReward(1.0)})
        >>> task = RewardGroupsTask(GoallessTask(EnvSpec(1, 2), reward),
        ...                         {"speed": {"forward": 1.0, "alive": 1.0}, "energy": {"ctrl": 10.0}})
        >>> state, action = torch.tensor([[2.0]]), torch.tensor([[1.0, 1.0]])
        >>> out = task.transition(state, action, state, task.reset(state))
        >>> out.reward, out.groups["speed"], out.groups["energy"], task.group_names
        (tensor([2.8000]), tensor([3.]), tensor([-2.]), ('speed', 'energy'))
    """

    def __init__(
        self,
        task: Task,
        groups: Mapping[str, Mapping[str, float]],
        *,
        terms: Mapping[str, RewardFunction] | None = None,
        dtype: torch.dtype | None = None,
    ) -> None:
        if not isinstance(task, Task):
            raise TypeError(f"RewardGroupsTask: task must be a torchtasks Task, got {type(task).__name__}")
        super().__init__(task.spec, task)
        if task.group_names:
            raise ValueError(
                f"RewardGroupsTask: the task already has reward groups {list(task.group_names)}; a tree holds one "
                "RewardGroupsTask (put all groups in it)"
            )
        if dtype is not None and dtype not in SUPPORTED_FLOATS:
            raise TypeError(f"RewardGroupsTask: dtype must be torch.float32, torch.float64 or None, got {dtype!r}")
        built = self._build_terms(task, {} if terms is None else terms)
        sources = (*task.term_names, STEP_SOURCE, FINAL_SOURCE, *built)
        if not isinstance(groups, Mapping) or not groups:
            raise TypeError(
                f"RewardGroupsTask: groups must be a non-empty mapping {{group: {{source: coefficient}}}}, got "
                f"{groups!r}"
            )
        plan: list[tuple[str, str, tuple[str, ...]]] = []
        weights_of: dict[str, torch.Tensor] = {}
        for group, weights in groups.items():
            _identifier(group, "group")
            if not isinstance(weights, Mapping) or not weights:
                raise TypeError(
                    f"RewardGroupsTask: the group {group!r} must be a non-empty mapping {{source: coefficient}}, got "
                    f"{weights!r}"
                )
            for source in weights:
                if source not in sources:
                    raise ValueError(
                        f"RewardGroupsTask: the group {group!r} reads {source!r}, which is not a source"
                        f"{did_you_mean(str(source), sources)} (the sources: the task's terms "
                        f"{list(task.term_names)}, {STEP_SOURCE!r}, {FINAL_SOURCE!r} and the terms given "
                        f"{list(built)})"
                    )
            values = [
                check_finite_scalar(c, f"RewardGroupsTask: groups[{group!r}][{source!r}]")
                for source, c in weights.items()
            ]
            buffer = WEIGHTS_PREFIX + group
            weights_of[buffer] = torch.tensor(values, dtype=torch.float64)
            plan.append((group, buffer, tuple(weights)))
        unread = sorted(set(built) - {source for _, _, names in plan for source in names})
        if unread:
            raise ValueError(
                f"RewardGroupsTask: the terms {unread} are read by no group (they would be evaluated at every step "
                "for nothing); drop them or add them to a group"
            )
        self.terms = nn.ModuleDict(built)
        for buffer, values in weights_of.items():  # one buffer per group: state_dict, .to, a schedulable target
            self.register_buffer(buffer, values)
        self._plan = tuple(plan)
        self.dtype = dtype

    @staticmethod
    def _build_terms(task: Task, terms: Mapping[str, RewardFunction]) -> dict[str, RewardFunction]:
        if not isinstance(terms, Mapping):
            raise TypeError(f"RewardGroupsTask: terms must be a mapping {{name: RewardFunction}}, got {terms!r}")
        taken = {*task.term_names, STEP_SOURCE, FINAL_SOURCE}
        built: dict[str, RewardFunction] = {}
        for name, function in terms.items():
            _identifier(name, "term")
            if name in taken:
                raise ValueError(
                    f"RewardGroupsTask: the term name {name!r} is taken (the task's terms {list(task.term_names)}, "
                    f"{STEP_SOURCE!r} and {FINAL_SOURCE!r} are sources already)"
                )
            if not isinstance(function, RewardFunction):
                raise TypeError(
                    f"RewardGroupsTask: the term {name!r} must be a torchtasks RewardFunction, got "
                    f"{type(function).__name__}"
                )
            if function.stateful:
                raise ValueError(
                    f"RewardGroupsTask: the term {name!r} must be stateless (a function of one transition), got the "
                    f"stateful {type(function).__name__}"
                )
            function.check_sizes(task.state_size, task.action_size)
            built[name] = function
        return built

    @property
    def group_names(self) -> tuple[str, ...]:
        return tuple(group for group, _, _ in self._plan)

    @property
    def group_dtype(self) -> torch.dtype | None:
        return self.dtype

    @property
    def groups(self) -> dict[str, dict[str, float]]:
        """The groups: ``{group: {source: coefficient}}``, with the coefficients as they are now."""
        return {
            group: dict(zip(sources, self._buffers[buffer].tolist(), strict=True))
            for group, buffer, sources in self._plan
        }

    def check_written_value(self, name: str, value: torch.Tensor, writer: str) -> None:
        """Raise ``ValueError`` naming ``writer`` unless ``value`` fits the weights ``name`` (``weights_<group>``).

        A writer (a :class:`~torchtasks.transforms.Curriculum`, levels) may write finite coefficients of the
        group's shape (one per source; ``[*B, n]`` for one row per env). Another buffer of the task (a state bound)
        has no rule here.

        Example:
            >>> import torch
            >>> from torchtasks.rewards import ConstantReward
            >>> from torchtasks.spaces import EnvSpec
            >>> from torchtasks.tasks import GoallessTask, RewardGroupsTask
            >>> task = RewardGroupsTask(GoallessTask(EnvSpec(1, 1), ConstantReward(1.0)), {"all": {"step": 1.0}})
            >>> try:
            ...     task.check_written_value("weights_all", torch.tensor([float("inf")]), "a schedule")
            ... except ValueError as error:
            ...     print(error)
            a schedule can write [inf] into the reward group 'all' (sources ['step']), whose coefficients must be finite
        """
        if all(buffer != name for _, buffer, _ in self._plan):
            return  # another buffer of the task (its state bounds): no rule of the groups
        group, sources = self._group_of(name)
        value = torch.as_tensor(value)
        if value.shape[-1:] != (len(sources),):
            raise ValueError(
                f"{writer} writes a value of shape {list(value.shape)} into the reward group {group!r}, which has "
                f"{len(sources)} coefficients (sources {list(sources)})"
            )
        if not bool(torch.isfinite(value).all()):
            raise ValueError(
                f"{writer} can write {value.tolist()} into the reward group {group!r} (sources {list(sources)}), "
                "whose coefficients must be finite"
            )

    def _group_of(self, name: str) -> tuple[str, tuple[str, ...]]:
        for group, buffer, sources in self._plan:
            if buffer == name:
                return group, sources
        raise KeyError(f"RewardGroupsTask: {name!r} is not a group's weights; they are {[b for _, b, _ in self._plan]}")

    # ------------------------------------------------------------------ checkpoints
    def get_extra_state(self) -> dict[str, Any]:
        """The groups' structure a checkpoint must match: ``{group: [sources]}``, in order, and the dtype."""
        return {"groups": {group: list(sources) for group, _, sources in self._plan}, "dtype": str(self.dtype)}

    def set_extra_state(self, state: Any) -> None:
        """Nothing to restore: the structure is checked before the load (:meth:`_check_saved`)."""

    def _check_saved(self, state_dict: Mapping[str, Any], prefix: str) -> None:
        """Refuse the checkpoint of other groups (other names, sources, order or dtype) before anything is written."""
        saved, own = state_dict.get(prefix + "_extra_state"), self.get_extra_state()
        same = (  # the groups' order is the vector reward's layout: compared too
            isinstance(saved, Mapping)
            and isinstance(saved.get("groups"), Mapping)
            and list(saved["groups"].items()) == list(own["groups"].items())
            and saved.get("dtype") == own["dtype"]
        )
        if not same:
            saved_groups = saved.get("groups") if isinstance(saved, Mapping) else saved
            saved_dtype = saved.get("dtype") if isinstance(saved, Mapping) else None
            raise ValueError(
                f"RewardGroupsTask.load_state_dict: the checkpoint holds other reward groups: saved {saved_groups!r}, "
                f"here {own['groups']!r} (dtype saved {saved_dtype}, here {own['dtype']}); build the "
                "RewardGroupsTask as saved"
            )

    def _check_loaded(self) -> None:
        for _, buffer, _ in self._plan:
            self.check_written_value(buffer, self._buffers[buffer], "RewardGroupsTask.load_state_dict")

    def extra_repr(self) -> str:
        return f"groups={list(self.group_names)}, dtype={self.dtype}"

    # ------------------------------------------------------------------ evaluation
    def _reward_groups(
        self, sources: Mapping[str, torch.Tensor], state: torch.Tensor, action: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        values = dict(sources)
        for name, function in self.terms.items():
            values[name] = function._value(state, action)
        dtype = self.dtype
        groups: dict[str, torch.Tensor] = {}
        for group, buffer, names in self._plan:
            weights = self._buffers[buffer]  # [n], or [*B, n]: one row per frame (recomputed with recorded values)
            total = None
            for source, weight in zip(names, weights.unbind(-1), strict=True):  # one op for all coefficients
                # a weight of the task's dtype (the state's, after the transform moved the task), or one row per frame
                value = values[source]
                added = (weight if weight.dtype == value.dtype else weight.to(value.dtype)) * value
                if total is None:
                    total = added
                else:  # summed in the sources' dtype
                    total = (total if total.dtype == added.dtype else total.to(added.dtype)) + added
                if dtype is not None:  # rounded after every addition (numpy's `vec += term` on a float32 vector)
                    total = total.to(dtype)
            groups[group] = total
        return groups
