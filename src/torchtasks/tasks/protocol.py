"""The functional task protocol: :class:`Task`.

A task is an ``nn.Module`` whose configuration is fixed at construction and whose
per-environment memory is an explicit TensorDict, passed in and returned::

    memory = task.reset(init_state)                       # batch_size = init_state.shape[:-1]
    reward, memory = task.step_reward(state, action, memory, remaining_steps)
    success = task.has_succeeded(state, memory)           # pure
    failure = task.has_failed(state, memory)              # pure
    done = task.is_done(state, memory)                    # success | failure
    final, memory = task.final_reward(state, memory, remaining_steps, done)

and, for a whole transition at once (each quantity evaluated once)::

    out = task.transition(state, action, next_state, memory, remaining_steps,
                          terminated=None, truncated=None, reward_on="next")

The public methods validate their inputs (the checks of :mod:`torchtasks.tasks._validation`) and
call the private ``_``-methods, which composite tasks call on their children without validating
again. :meth:`Task._transition` is the one implementation of a transition, returning a named
:class:`~torchtasks.tasks.transition.Transition`: the :class:`~torchtasks.transforms.TaskTransform`
(online, offline and compiled) runs it too. Wrappers of a task live in :mod:`torchtasks.tasks.wrapper`.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable, Mapping
from typing import Any, Literal, TypeVar

import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn

from torchtasks._checks import cast_like, check_input
from torchtasks.spaces import Box, EnvSpec, rows_outside
from torchtasks.tasks._validation import (
    as_remaining_steps,
    check_action,
    check_done,
    check_memory,
    check_state,
    check_transition,
)
from torchtasks.tasks.goals import GoalSlot, replace_goals
from torchtasks.tasks.memory import MemoryLayout, make_memory, memory_layout
from torchtasks.tasks.output import TaskOutput
from torchtasks.tasks.transition import FINAL_SOURCE, STEP_SOURCE, TaskFacts, Transition

__all__ = ["Task"]

RewardOn = Literal["next", "state"]

_Fact = TypeVar("_Fact")

#: the end conditions of a tree that names none beyond its success and its failure
DEFAULT_TERMINATIONS = {"success": "success", "failure": "failure"}


def outcome_names(can_succeed: bool, can_fail: bool) -> dict[str, str]:
    """The end conditions of a tree that names none beyond its success and its failure, for those it has."""
    names = {"success": "success"} if can_succeed else {}
    if can_fail:
        names["failure"] = "failure"
    return names


def _without_terminated(method: Callable[..., Any]) -> Callable[..., Any]:
    """Adapt a ``_step_reward``/``_step_terms`` written without the ``terminated`` argument (it is dropped)."""

    @functools.wraps(method)
    def adapted(
        self: Task,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None = None,
    ) -> Any:
        return method(self, state, action, memory, remaining_steps)

    return adapted


class Task(nn.Module):
    """Base class of tasks: what an agent should do, evaluated for a batch of environments.

    Subclasses implement ``_reset``, ``_step_reward`` and ``_has_succeeded`` and may override
    ``_has_failed`` (default: the state left ``spec.state_space``; NaN is always outside) and
    ``_compute_final_reward`` (default 0). Every per-environment quantity that changes during an
    episode lives in the memory TensorDict, so environments of a batch are independent.
    ``_step_reward(state, action, memory, remaining_steps, terminated=None)`` receives the env's own
    termination of the transition when the step reward sees ``next_state``; a task that does not read
    it may leave the argument out, and a task that wraps others passes it on to them.

    Args:
        spec: the task's :class:`~torchtasks.spaces.EnvSpec` (state and action boxes).

    Example:
        >>> import torch
        >>> from torchtasks.rewards import QuadraticErrorReward
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> from torchtasks.tasks import DesiredStateTask
        >>> task = DesiredStateTask(EnvSpec(Box(-1.0, 1.0).select([0]), 1), [0.5], QuadraticErrorReward([1.0], [0.0]))
        >>> memory = task.reset(torch.zeros(2, 1))
        >>> reward, memory = task.step_reward(torch.tensor([[0.0], [2.0]]), torch.zeros(2, 1), memory, 0)
        >>> reward, task.has_failed(torch.tensor([[0.0], [2.0]]), memory)
        (tensor([-0.2500, -2.2500]), tensor([False,  True]))
    """

    #: names of the per-environment overrides this task's ``reset`` understands
    reset_keys: tuple[str, ...] = ()
    #: this task's own memory entries that stay as they are when it starts as the current sub-task of a
    #: :class:`SequentialTasks` (its goal, a final-reward latch); the rest is re-initialised
    kept_at_start: tuple[str, ...] = ()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        # a task of one's own may write its step reward without ``terminated`` (only a step reward that
        # treats the env's own termination as absorbing reads it): it is called without it
        super().__init_subclass__(**kwargs)
        for name in ("_step_reward", "_step_terms"):
            method = cls.__dict__.get(name)
            if callable(method) and "terminated" not in inspect.signature(method).parameters:
                setattr(cls, name, _without_terminated(method))

    def __init__(self, spec: EnvSpec) -> None:
        super().__init__()
        if not isinstance(spec, EnvSpec):
            raise TypeError(f"spec must be a torchtasks.spaces.EnvSpec, got {type(spec).__name__}")
        self.spec = spec
        self.register_buffer("state_low", spec.state_space.low.clone())
        self.register_buffer("state_high", spec.state_space.high.clone())
        self._state_bounded = spec.state_space.is_bounded
        # the remaining steps handed to trees that do not read them (follows the task's device)
        self.register_buffer("no_remaining_steps", torch.zeros((), dtype=torch.long), persistent=False)

    def _load_from_state_dict(self, state_dict: dict[str, Any], prefix: str, *args: Any, **kwargs: Any) -> None:
        # the state box lives in two places (the buffers, for .to()/state_dict(), and self.spec, for
        # users and the bounds check); after loading new bounds, the spec and the bounds check follow
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        box = self.spec.state_space
        low = self.state_low.detach().to(dtype=box.low.dtype, device=box.low.device)
        high = self.state_high.detach().to(dtype=box.high.dtype, device=box.high.device)
        if not (torch.equal(low, box.low) and torch.equal(high, box.high)):
            self.spec = EnvSpec(Box(low, high, labels=box.labels), self.spec.action_space)
        self._state_bounded = self.spec.state_space.is_bounded

    # ----------------------------------------------------------------------------- properties
    @property
    def state_size(self) -> int:
        """Number of state entries the task reads."""
        return self.spec.state_size

    @property
    def action_size(self) -> int:
        """Number of action entries the task reads."""
        return self.spec.action_size

    def children_tasks(self) -> tuple[Task, ...]:
        """The tasks this one is made of (empty for a leaf task)."""
        return ()

    def _child_memory_keys(self) -> tuple[str | None, ...]:
        """The memory key of each child task (``None``: the child's memory is this task's own)."""
        return ()

    def _goal_slots(self, prefix: tuple[str, ...], indices: tuple[int, ...] | None) -> list[GoalSlot]:
        """The goal slots of this subtree, its memory at ``prefix``, seeing ``state[..., indices]``."""
        slots: list[GoalSlot] = []
        for key, child in zip(self._child_memory_keys(), self.children_tasks(), strict=True):
            slots += child._goal_slots(prefix if key is None else (*prefix, key), indices)
        return slots

    def _kept_paths(self, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
        """The memory paths of the entries this subtree keeps when it starts (see :attr:`kept_at_start`)."""
        paths = [(*prefix, key) for key in self.kept_at_start]
        for key, child in zip(self._child_memory_keys(), self.children_tasks(), strict=True):
            paths += child._kept_paths(prefix if key is None else (*prefix, key))
        return paths

    def _cached(self, key: str, compute: Callable[[], _Fact]) -> _Fact:
        """``compute()``, computed on the first call and kept under ``key`` in the instance's ``__dict__``.

        For facts fixed by the task tree that the per-step path reads (a plain attribute, so ``nn.Module``'s
        attribute machinery, ``state_dict`` and ``torch.compile`` do not see it).
        """
        value = self.__dict__.get(key)
        if value is None:
            value = compute()
            self.__dict__[key] = value
        return value

    @property
    def goal_slots(self) -> tuple[GoalSlot, ...]:
        """The tasks of this tree that take a goal (desired-state tasks), by the dotted path of their goal.

        A goal passed to :meth:`transition` (or to the fine-grained calls) replaces their desired
        state: a ``[*B, k]`` tensor when the tree has exactly one, or ``{name: goal}``.
        """
        return self._cached("_goal_slot_cache", lambda: tuple(self._goal_slots((), None)))

    def _resolve_goal(self, goal: object, state: torch.Tensor) -> dict[GoalSlot, torch.Tensor]:
        """Validate ``goal`` (a tensor or ``{name: tensor}``) and map it to the goal slots it fills."""
        slots = {slot.name: slot for slot in self.goal_slots}
        if not slots:
            raise ValueError(f"goal was given, but no task of this {type(self).__name__} tree takes a goal")
        if isinstance(goal, torch.Tensor):
            if len(slots) > 1:
                raise ValueError(
                    f"this task tree has {len(slots)} tasks that take a goal ({sorted(slots)}); pass "
                    "goal={name: tensor} to say which"
                )
            goals = {next(iter(slots)): goal}
        elif isinstance(goal, Mapping):
            goals = dict(goal)
            unknown = set(goals) - set(slots)
            if unknown:
                raise ValueError(f"unknown goal name(s) {sorted(unknown)}; this task tree takes goals {sorted(slots)}")
        else:
            raise TypeError(f"goal must be a tensor [*B, k] or a mapping {{name: tensor}}, got {type(goal).__name__}")
        resolved = {}
        for name, value in goals.items():
            slot = slots[name]
            label = "goal" if len(goals) == 1 else f"goal[{name!r}]"
            check_input(value, label, slot.size)
            if value.shape[:-1] != state.shape[:-1]:
                raise ValueError(
                    f"{label} must have shape {[*state.shape[:-1], slot.size]} (the batch of the state and "
                    f"the {slot.size} entries of the goal task), got {list(value.shape)}"
                )
            resolved[slot] = value if value.dtype == state.dtype else value.to(state.dtype)
        return resolved

    def with_goal(self, memory: TensorDictBase, goal: object, state: torch.Tensor) -> TensorDictBase:
        """Return ``memory`` with the desired state of the goal task(s) replaced by ``goal`` (validated).

        This is what ``goal=`` does in :meth:`transition` and the fine-grained calls; ``state`` gives
        the batch shape and dtype.

        Example:
            >>> import torch
            >>> from torchtasks.rewards import QuadraticErrorReward
            >>> from torchtasks.spaces import EnvSpec
            >>> from torchtasks.tasks import DesiredStateTask, FinalRewardTask
            >>> task = FinalRewardTask(DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], QuadraticErrorReward([1.0, 1.0])))
            >>> [slot.name for slot in task.goal_slots]
            ['wrapped.state_des']
            >>> state = torch.zeros(1, 2)
            >>> task.with_goal(task.reset(state), torch.tensor([[1.0, 2.0]]), state)["wrapped", "state_des"]
            tensor([[1., 2.]])
        """
        if goal is None:
            return memory
        return replace_goals(memory, self._resolve_goal(goal, state))

    @property
    def term_names(self) -> tuple[str, ...]:
        """Names of the step-reward terms :meth:`step_reward_terms` reports (empty: no breakdown)."""
        return ()

    @property
    def uses_remaining_steps(self) -> bool:
        """Whether any task of this tree reads ``remaining_steps`` (time-dependent final rewards)."""
        return any(child.uses_remaining_steps for child in self.children_tasks())

    @property
    def pays_final_reward(self) -> bool:
        """Whether any task of this tree can pay a final reward (else ``final_reward`` is always 0).

        A task pays one when it defines its own ``_compute_final_reward`` (or its own ``_final_reward``,
        see :meth:`_pays_own_final_reward`); a task that only forwards its children's (a mask, a composite)
        says so by overriding this property.
        """
        return self._pays_own_final_reward() or any(child.pays_final_reward for child in self.children_tasks())

    def _pays_own_final_reward(self) -> bool:
        """Whether this task's class defines a final reward of its own (its children's aside).

        A class that overrides ``_final_reward`` to combine its own ``_compute_final_reward`` with its
        children's (a wrapper) overrides this method to look past its combination.
        """
        cls = type(self)
        return (
            cls._compute_final_reward is not Task._compute_final_reward or cls._final_reward is not Task._final_reward
        )

    def all_reset_keys(self) -> set[str]:
        """Names of the reset overrides understood anywhere in this task tree."""
        keys = set(self.reset_keys)
        for child in self.children_tasks():
            keys |= child.all_reset_keys()
        return keys

    @property
    def cost_names(self) -> tuple[str, ...]:
        """The names of the tree's costs (:class:`~torchtasks.tasks.ConstrainedTask`), in evaluation order."""
        return tuple(name for child in self.children_tasks() for name in child.cost_names)

    @property
    def cost_limits(self) -> dict[str, float | None]:
        """``{cost name: limit}`` (``None``: no limit given) for every cost of the tree."""
        limits: dict[str, float | None] = {}
        for child in self.children_tasks():
            limits.update(child.cost_limits)
        return limits

    def _step_costs(self, state: torch.Tensor, action: torch.Tensor) -> dict[str, torch.Tensor]:
        """``{name: cost [*B]}`` of the tree on ``state`` (raw, the task's state space) and ``action``.

        Composites hand the state they give their children (a :class:`MaskedTask` its selection);
        a :class:`~torchtasks.tasks.ConstrainedTask` adds its own.
        """
        costs: dict[str, torch.Tensor] = {}
        for child in self.children_tasks():
            costs.update(child._step_costs(state, action))
        return costs

    @property
    def group_names(self) -> tuple[str, ...]:
        """The names of the tree's reward groups (:class:`~torchtasks.tasks.RewardGroupsTask`), in order."""
        return tuple(name for child in self.children_tasks() for name in child.group_names)

    @property
    def group_dtype(self) -> torch.dtype | None:
        """The dtype the tree's reward groups are accumulated and written in (``None``: the reward's)."""
        return next((child.group_dtype for child in self.children_tasks() if child.group_names), None)

    def _reward_groups(
        self, sources: Mapping[str, torch.Tensor], state: torch.Tensor, action: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        """``{name: value [*B]}`` of the tree's reward groups, from the tree's ``sources`` (its named step-reward
        terms, ``"step"`` and ``"final"``) and, for a group's own extra terms, ``state`` and ``action``.

        Wrappers hand down the state they give their task (a :class:`MaskedTask` its selection); a
        :class:`~torchtasks.tasks.RewardGroupsTask` computes its own.
        """
        groups: dict[str, torch.Tensor] = {}
        for child in self.children_tasks():
            groups.update(child._reward_groups(sources, state, action))
        return groups

    @property
    def termination_names(self) -> dict[str, str]:
        """The tree's named end conditions: ``{name: "success" | "failure"}``, only those the tree has.

        By default the task's success and failure themselves (``{"success": "success", "failure": "failure"}``);
        a leaf task with a reward names its failures (``"out_of_bounds"``: the state left the box or is NaN;
        ``"unhealthy"``: the reward's own failure, e.g. a fallen robot) and names ``"success"`` only when it has
        a success condition (a :class:`GoallessTask` has none); wrappers and masks keep their task's names;
        composites report their own success and failure, each when their sub-tasks can reach it. A tree without
        a ``"success"`` condition cannot succeed (:attr:`TaskFacts.can_succeed
        <torchtasks.tasks.transition.TaskFacts.can_succeed>` is False): a :class:`~torchtasks.transforms.TaskTransform`
        writes no success flag for it, and statistics report no success rate.
        """
        return dict(DEFAULT_TERMINATIONS)

    def _termination_terms(
        self, state: torch.Tensor, memory: TensorDictBase, success: torch.Tensor, failure: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        """``{name: flag [*B]}`` of :attr:`termination_names` on ``state``, given the task's ``success`` and
        ``failure`` there: the OR of the success conditions is ``success``, that of the failure ones ``failure``."""
        flags = {"success": success, "failure": failure}
        return {name: flags[name] for name in self.termination_names}

    @property
    def memory_layout(self) -> MemoryLayout:
        """The keys of this task's memory (nested for the memory of sub-tasks), fixed by the task tree."""

        def probe_reset() -> MemoryLayout:
            probe = torch.zeros(1, self.state_size, dtype=self.state_low.dtype, device=self.state_low.device)
            return memory_layout(self._reset(probe, {}))

        return self._cached("_memory_layout", probe_reset)

    @property
    def facts(self) -> TaskFacts:
        """What a caller needs to know about this task tree, by name (a :class:`TaskFacts`; computed once).

        Example:
            >>> from torchtasks.rewards import CompoundReward, ConstantReward
            >>> from torchtasks.spaces import EnvSpec
            >>> from torchtasks.tasks import GoallessTask
            >>> task = GoallessTask(EnvSpec(1, 1), CompoundReward({"alive": ConstantReward(1.0)}))
            >>> task.facts.has_terms, task.facts.pays_final_reward, task.facts.can_succeed, task.facts.can_fail
            (True, False, False, True)
        """
        return self._cached("_facts", self._derive_facts)

    def _derive_facts(self) -> TaskFacts:
        # named flags say more than success and failure only where a kind has two or more conditions
        kinds = list(self.termination_names.values())
        return TaskFacts(
            can_succeed="success" in kinds,
            can_fail="failure" in kinds,
            has_terms=bool(self.term_names),
            reads_remaining_steps=self.uses_remaining_steps,
            pays_final_reward=self.pays_final_reward,
            has_costs=bool(self.cost_names),
            has_groups=bool(self.group_names),
            names_end_conditions=kinds.count("success") > 1 or kinds.count("failure") > 1,
        )

    def _remaining_steps(self, remaining_steps: int | torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """The checked ``remaining_steps`` of a public call as a tensor (a shared 0 when the tree does not read it)."""
        unread = None if self.facts.reads_remaining_steps else self.no_remaining_steps
        return as_remaining_steps(remaining_steps, state, unread)

    # ------------------------------------------------------------------------ public API
    def reset(self, init_state: torch.Tensor, **overrides: Any) -> TensorDict:
        """Return fresh memory for episodes starting in ``init_state`` (``[*B, n]``).

        ``overrides`` are per-environment reset values understood by tasks of the tree (e.g.
        ``state_des`` of :class:`DesiredStateTask`, ``start_index`` of :class:`SequentialTasks`);
        composite tasks forward them to their children. Unknown names raise ``TypeError``.
        """
        check_state(self, init_state, "init_state")
        self.check_reset_overrides(overrides)
        return self._reset(init_state, overrides)

    def check_reset_overrides(self, overrides: Mapping[str, Any], source: str = "") -> None:
        """Raise ``TypeError`` unless every name of ``overrides`` is a reset override of this tree.

        ``source`` starts the message (e.g. ``"TaskTransform: reset_overrides returned "``).

        Example:
            >>> from torchtasks.rewards import ConstantReward
            >>> from torchtasks.spaces import EnvSpec
            >>> from torchtasks.tasks import DesiredStateTask
            >>> task = DesiredStateTask(EnvSpec(1, 1), [0.0], ConstantReward(0.0))
            >>> task.check_reset_overrides({"state_des": None})
            >>> try:
            ...     task.check_reset_overrides({"goal": None})
            ... except TypeError as error:
            ...     print(error)
            unknown reset override(s) ['goal']; this task understands ['state_des']
        """
        unknown = set(overrides) - self.all_reset_keys()
        if unknown:
            raise TypeError(
                f"{source}unknown reset override(s) {sorted(unknown)}; this task understands "
                f"{sorted(self.all_reset_keys())}"
            )

    def step_reward(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: int | torch.Tensor = 0,
        *,
        goal: torch.Tensor | Mapping[str, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        """Return ``(reward[*B], memory)`` of one step taken from ``state`` with ``action``.

        ``goal`` replaces the desired state of the tree's goal task for this call (see :meth:`transition`).
        """
        check_state(self, state)
        check_action(self, state, action)
        check_memory(self, state, memory)
        memory = self.with_goal(memory, goal, state)
        return self._step_reward(state, action, memory, self._remaining_steps(remaining_steps, state))

    def step_reward_terms(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: int | torch.Tensor = 0,
        *,
        goal: torch.Tensor | Mapping[str, torch.Tensor] | None = None,
    ) -> tuple[dict[str, torch.Tensor], torch.Tensor, TensorDictBase]:
        """Like :meth:`step_reward`, with the named terms: ``({name: value[*B]}, reward[*B], memory)``.

        The terms are those of a compound, product or locomotion reward reached through wrappers and
        masks (:attr:`term_names`); the reward combines them (a sum, or a product of factors). Other
        tasks report no terms.
        """
        check_state(self, state)
        check_action(self, state, action)
        check_memory(self, state, memory)
        memory = self.with_goal(memory, goal, state)
        return self._step_terms(state, action, memory, self._remaining_steps(remaining_steps, state))

    def has_succeeded(
        self,
        state: torch.Tensor,
        memory: TensorDictBase,
        *,
        goal: torch.Tensor | Mapping[str, torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """Return ``bool[*B]``: whether each environment's episode is a success (pure)."""
        check_state(self, state)
        check_memory(self, state, memory)
        return self._has_succeeded(state, self.with_goal(memory, goal, state))

    def has_failed(
        self,
        state: torch.Tensor,
        memory: TensorDictBase,
        *,
        goal: torch.Tensor | Mapping[str, torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """Return ``bool[*B]``: whether each environment's episode is a failure (pure)."""
        check_state(self, state)
        check_memory(self, state, memory)
        return self._has_failed(state, self.with_goal(memory, goal, state))

    def is_done(
        self,
        state: torch.Tensor,
        memory: TensorDictBase,
        *,
        goal: torch.Tensor | Mapping[str, torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """Return ``bool[*B]``: success or failure (pure)."""
        check_state(self, state)
        check_memory(self, state, memory)
        return self._is_done(state, self.with_goal(memory, goal, state))

    def final_reward(
        self,
        state: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: int | torch.Tensor,
        done: torch.Tensor,
        *,
        goal: torch.Tensor | Mapping[str, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        """Return ``(final_reward[*B], memory)``: the one-off reward, paid once and only where ``done``.

        It sums the final rewards of this task and of the tasks it wraps (Pyrado's
        ``final_rew`` over ``all_tasks``).
        """
        check_state(self, state)
        check_memory(self, state, memory)
        check_done(done, state)
        memory = self.with_goal(memory, goal, state)
        return self._final_reward(state, memory, self._remaining_steps(remaining_steps, state), done)

    def transition(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        next_state: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: int | torch.Tensor = 0,
        *,
        terminated: torch.Tensor | None = None,
        truncated: torch.Tensor | None = None,
        reward_on: RewardOn = "next",
        goal: torch.Tensor | Mapping[str, torch.Tensor] | None = None,
    ) -> TaskOutput:
        """Evaluate one transition ``(s_t, a_t, s_{t+1})`` for a batch of environments: the one call per step.

        The step reward is evaluated on ``next_state`` (``reward_on="next"``, the Gymnasium
        convention) or on ``state`` (``"state"``, Pyrado's order); success, failure and the final
        reward on ``next_state``. The episode ends where the task succeeds or fails, where the
        env's own ``terminated`` holds, or where ``truncated`` holds (a time limit); the final
        reward is paid there, once per episode. Each quantity is evaluated once, and the numbers
        equal those of the fine-grained calls (:meth:`step_reward`, :meth:`has_succeeded`,
        :meth:`has_failed`, :meth:`final_reward`) made in that order.

        Args:
            state: ``s_t``, ``[*B, n]`` (float32 or float64).
            action: ``a_t``, ``[*B, m]``.
            next_state: ``s_{t+1}``, the shape and dtype of ``state``.
            memory: the task memory from :meth:`reset` or the previous call's ``out.memory``.
            remaining_steps: steps left before the time limit (int, or an int tensor broadcastable
                to ``[*B]``; 0 when there is no limit, as in Pyrado), never negative (``ValueError``).
                Only time-dependent final rewards read it.
            terminated: the env's own termination, ``bool[*B]``, or None.
            truncated: truncation (time limit), ``bool[*B]``, or None.
            reward_on: ``"next"`` or ``"state"``: the state the step reward is evaluated on.
            goal: a goal ``[*B, k]`` replacing the desired state of the tree's goal task (a
                :class:`DesiredStateTask`, also inside wrappers, masks and composites; ``k`` is the
                size of the state it sees) for this call, or ``{name: goal}`` when the tree has
                several (:attr:`goal_slots` lists them). The returned memory carries it.

        Returns:
            a :class:`TaskOutput` (reward, step and final reward, flags, memory, named terms).

        Example:
            >>> import functools, torch
            >>> from torchtasks.rewards import QuadraticErrorReward
            >>> from torchtasks.spaces import Box, EnvSpec
            >>> from torchtasks.tasks import DesiredStateTask, FinalRewardTask, proximity_succeeded
            >>> spec = EnvSpec(Box([-1.0], [1.0]), 1)
            >>> task = FinalRewardTask(DesiredStateTask(spec, [0.5], QuadraticErrorReward([1.0], [0.0]),
            ...     success=functools.partial(proximity_succeeded, threshold=0.1)), factor=10.0)
            >>> state = torch.zeros(3, 1)
            >>> memory = task.reset(state)
            >>> next_state = torch.tensor([[0.5], [2.0], [0.0]])
            >>> out = task.transition(state, torch.zeros(3, 1), next_state, memory)
            >>> out.reward
            tensor([ 10.0000, -12.2500,  -0.2500])
            >>> out.success, out.failure, out.done
            (tensor([ True, False, False]), tensor([False,  True, False]), tensor([ True,  True, False]))
        """
        check_transition(self, state, action, next_state, memory, terminated, truncated, reward_on)
        memory = self.with_goal(memory, goal, state)
        remaining = self._remaining_steps(remaining_steps, state)
        values = self._transition(state, action, next_state, memory, remaining, terminated, truncated, reward_on)
        return TaskOutput(**values._asdict())

    forward = transition

    def _transition(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        next_state: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None = None,
        truncated: torch.Tensor | None = None,
        reward_on: RewardOn = "next",
        with_terms: bool = True,
    ) -> Transition:
        """The one implementation of a transition, without checks (pure tensor code; compiles with fullgraph).

        ``with_terms=False`` skips the named terms (returned empty) where nobody reads them.
        """
        facts = self.facts
        # the step reward sees next_state (and then the env's own termination of this transition, which
        # shaping treats as absorbing) or, in Pyrado's order, state (whose step does not end here)
        if reward_on == "next":
            source, step_terminated = next_state, terminated
        else:
            source, step_terminated = state, None
        if (with_terms or facts.has_groups) and facts.has_terms:  # groups are sums of the named terms
            terms, step_reward, memory = self._step_terms(source, action, memory, remaining_steps, step_terminated)
        else:
            terms = {}
            step_reward, memory = self._step_reward(source, action, memory, remaining_steps, step_terminated)
        # costs: stateless functions of the state the step reward sees (and the action), never shaped or paid once
        costs = self._step_costs(source, action) if facts.has_costs else {}
        success = self._has_succeeded(next_state, memory)
        failure = self._has_failed(next_state, memory)
        ended = success | failure
        if terminated is not None:
            ended = ended | terminated
        done = ended if truncated is None else ended | truncated
        # which named condition ended the episode: from the flags just computed (read before the final reward
        # updates the memory, as success and failure were)
        ends = (
            self._termination_terms(next_state, memory, success, failure)
            if with_terms and facts.names_end_conditions
            else {}
        )
        if facts.pays_final_reward:
            final, memory = self._final_reward(next_state, memory, remaining_steps, done, (success, failure))
            reward = step_reward + final
        else:  # no task of the tree pays a final reward: it is 0
            final, reward = torch.zeros_like(step_reward), step_reward
        # reward groups: weighted sums of the named terms, the step and the final reward (and their own terms)
        groups = (
            self._reward_groups({**terms, STEP_SOURCE: step_reward, FINAL_SOURCE: final}, source, action)
            if facts.has_groups
            else {}
        )
        if not with_terms:
            terms = {}
        return Transition(
            reward=reward,
            step_reward=step_reward,
            final_reward=final,
            success=success,
            failure=failure,
            terminated=ended,
            done=done,
            memory=memory,
            terms=terms,
            costs=costs,
            ended_by=ends,
            groups=groups,
        )

    # ------------------------------------------------------------------- implementation
    def _reset(self, init_state: torch.Tensor, overrides: dict[str, Any]) -> TensorDict:
        return make_memory({}, init_state.shape[:-1])

    def _step_reward(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        raise NotImplementedError

    def _step_terms(
        self,
        state: torch.Tensor,
        action: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        terminated: torch.Tensor | None = None,
    ) -> tuple[dict[str, torch.Tensor], torch.Tensor, TensorDictBase]:
        reward, memory = self._step_reward(state, action, memory, remaining_steps, terminated)
        return {}, reward, memory

    def _has_succeeded(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        raise NotImplementedError

    def _has_failed(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        if not self._state_bounded:
            return torch.isnan(state).count_nonzero(dim=-1) != 0
        return rows_outside(state, cast_like(self.state_low, state), cast_like(self.state_high, state))

    def _is_done(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        return self._has_succeeded(state, memory) | self._has_failed(state, memory)

    def _compute_final_reward(
        self,
        state: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        done: torch.Tensor,
        flags: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        """This task's own final reward (Pyrado's ``compute_final_rew``): 0 by default.

        ``flags`` optionally carries ``(success, failure)`` already computed for this task on
        ``state`` and ``memory``, so they are not evaluated twice in a step.
        """
        return state.new_zeros(state.shape[:-1]), memory

    def _final_reward(
        self,
        state: torch.Tensor,
        memory: TensorDictBase,
        remaining_steps: torch.Tensor,
        done: torch.Tensor,
        flags: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> tuple[torch.Tensor, TensorDictBase]:
        return self._compute_final_reward(state, memory, remaining_steps, done, flags)

    def _unfinished_final_reward(
        self, state: torch.Tensor, memory: TensorDictBase, remaining_steps: torch.Tensor, done: torch.Tensor
    ) -> tuple[torch.Tensor, TensorDictBase]:
        """What a composite pays this sub-task at the episode end if it did not finish by itself: its own final
        reward (Pyrado's ``compute_final_rew`` of the sub-task). A wrapper that changes no number (a mask, a
        constraint, shaping) passes the question to the task it wraps."""
        return self._compute_final_reward(state, memory, remaining_steps, done)
