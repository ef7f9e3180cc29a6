"""Track a command (a target velocity) with a reward that also sees the raw state: :class:`CommandTrackingTask`."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase

from torchtasks._checks import as_constant, cast_like, check_input
from torchtasks._memory import read
from torchtasks.rewards.base import RewardFunction
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks.goals import GOAL_ENTRY, GoalSlot
from torchtasks.tasks.leaf import RewardTask
from torchtasks.tasks.memory import make_memory

__all__ = ["CommandTrackingTask"]

#: a named termination: the state entry (a label or a position) and the range it must stay in
TerminationRange = tuple[int | str, float, float]


class CommandTrackingTask(RewardTask):
    """Track a per-env command: the reward sees the state, the command and the tracking errors; it never succeeds.

    The command (``k`` numbers, e.g. a planar velocity and a yaw rate) is compared with the ``tracked`` entries of
    the state. The reward is called with ``[state, command, command - state[tracked]]`` (``n + 2k`` entries,
    labelled ``<label>``, ``command_<label>`` and ``error_<label>`` after the state's labels: :attr:`reward_space`),
    so that tracking kernels read the errors and regularisers read the raw state in one
    :class:`~torchtasks.rewards.CompoundReward`, whose terms are logged one by one. The command is the task's goal
    (memory ``"state_des"``, ``[*B, k]``): a :class:`~torchtasks.transforms.GoalCommand` and
    ``TaskTransform(task, goal_key=...)`` pass the command the policy saw; without one, the ``command`` given here.

    The episode fails when the state leaves ``spec.state_space`` or is NaN (``"out_of_bounds"``) or when a named
    termination's entry leaves its range (``terminations={"base_contact": ("torso_contact", -inf, 1.0)}``, the
    entry's value NaN included); each is an end condition of its own in the data
    (:attr:`~torchtasks.tasks.Task.termination_names`).

    Args:
        spec: the task state's boxes (labels name the entries).
        tracked: the ``k`` state entries the command is compared with (labels or positions).
        reward: a reward function of ``(reward input [*B, n + 2k], action)``; may be stateful.
        command: the command used without a goal (``k`` numbers; default zeros).
        terminations: ``{name: (entry, low, high)}``: failure where the entry leaves ``[low, high]``.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import CompoundReward, ExpTrackingReward, SquaredSumReward
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> from torchtasks.tasks import CommandTrackingTask
        >>> spec = EnvSpec(Box.unbounded(3, labels=["vx", "vz", "tilt"]), 2)
        >>> probe = CommandTrackingTask(spec, ["vx"], SquaredSumReward([0], space=None))
        >>> probe.reward_space.labels
        ('vx', 'vz', 'tilt', 'command_vx', 'error_vx')
        >>> space = probe.reward_space
        >>> reward = CompoundReward({"track": ExpTrackingReward(0.5, ["error_vx"], space=space),
        ...                          "vz": SquaredSumReward(["vz"], space=space)}, weights={"vz": -2.0})
        >>> task = CommandTrackingTask(spec, ["vx"], reward, terminations={"tilted": ("tilt", -0.5, 0.5)})
        >>> state = torch.tensor([[0.5, 0.1, 0.0], [0.0, 0.0, 0.9]])
        >>> out = task.transition(state, torch.zeros(2, 2), state, task.reset(state), goal=torch.tensor([[0.5], [0.5]]))
        >>> out.terms["track"], out.terms["vz"], out.failure
        (tensor([1.0000, 0.3679]), tensor([-0.0200, -0.0000]), tensor([False,  True]))
    """

    reset_keys = ("state_des",)
    kept_at_start = (GOAL_ENTRY,)
    reward_sees_state = False

    def __init__(
        self,
        spec: EnvSpec,
        tracked: Iterable[int | str] | int | str,
        reward: RewardFunction,
        *,
        command: Sequence[float] | torch.Tensor | None = None,
        terminations: Mapping[str, TerminationRange] | None = None,
    ) -> None:
        if not isinstance(spec, EnvSpec):
            raise TypeError(f"spec must be a torchtasks.spaces.EnvSpec, got {type(spec).__name__}")
        positions = spec.state_space.indices(tracked)
        if not positions:
            raise ValueError("tracked must name at least one state entry (the command's size)")
        labels = spec.state_space.labels
        if labels is None:
            names = [str(i) for i in range(spec.state_size)]
        else:
            names = list(labels)
        tracked_names = [names[i] for i in positions]
        reward_labels = (
            names + [f"command_{name}" for name in tracked_names] + [f"error_{name}" for name in tracked_names]
        )
        # read by _check_reward_sizes, which RewardTask.__init__ calls: set before it (a plain attribute)
        self.__dict__["reward_space"] = Box.unbounded(len(reward_labels), labels=reward_labels)
        super().__init__(spec, reward)
        self.tracked = positions
        self.register_buffer("tracked_index", torch.tensor(positions, dtype=torch.long))
        size = len(positions)
        default = (
            torch.zeros(size, dtype=torch.float64) if command is None else as_constant(command, "command", ndim=(1,))
        )
        if default.numel() != size:
            raise ValueError(f"command must have {size} entries (one per tracked entry), got {default.numel()}")
        self.register_buffer("state_des", default)
        self.terminations = self._check_terminations(spec, terminations)
        for name, (_, low, high) in self.terminations.items():
            self.register_buffer(f"termination_{name}_range", torch.tensor([low, high], dtype=torch.float64))
        self.register_buffer(
            "termination_index", torch.tensor([index for index, _, _ in self.terminations.values()], dtype=torch.long)
        )

    def _check_reward_sizes(self, spec: EnvSpec, reward: RewardFunction) -> None:  # type: ignore[override]
        """The reward reads ``[state, command, error]``: check it against that size (:attr:`reward_space`)."""
        RewardTask._check_reward_sizes(EnvSpec(self.reward_space, spec.action_space), reward)

    @staticmethod
    def _check_terminations(
        spec: EnvSpec, terminations: Mapping[str, TerminationRange] | None
    ) -> dict[str, tuple[int, float, float]]:
        if terminations is None:
            return {}
        if not isinstance(terminations, Mapping):
            raise TypeError(
                f"terminations must be a mapping {{name: (state entry, low, high)}}, got {type(terminations).__name__}"
            )
        checked: dict[str, tuple[int, float, float]] = {}
        for name, value in terminations.items():
            if not isinstance(name, str) or not name.isidentifier() or name == "out_of_bounds":
                raise ValueError(f"termination names must be identifiers other than 'out_of_bounds', got {name!r}")
            if not (isinstance(value, (tuple, list)) and len(value) == 3):
                raise TypeError(f"terminations[{name!r}] must be (state entry, low, high), got {value!r}")
            (position,) = spec.state_space.indices([value[0]])
            low, high = (float(as_constant(bound, f"terminations[{name!r}] bound", ndim=(0,))) for bound in value[1:])
            if low > high:
                raise ValueError(f"terminations[{name!r}] needs low <= high, got ({low}, {high})")
            checked[name] = (position, low, high)
        return checked

    @property
    def command_size(self) -> int:
        """The number of command entries ``k``."""
        return len(self.tracked)

    # --------------------------------------------------------------------------------- memory
    def _command(self, init_state: torch.Tensor, overrides: dict[str, Any]) -> torch.Tensor:
        batch = init_state.shape[:-1]
        goal = overrides.get("state_des")
        if goal is None:
            goal = self.state_des.to(device=init_state.device, dtype=init_state.dtype)
        else:
            goal = (
                check_input(goal, "state_des override")
                if isinstance(goal, torch.Tensor)
                else as_constant(goal, "state_des override")
            )
            goal = goal.to(device=init_state.device, dtype=init_state.dtype)
            if goal.shape not in (torch.Size([self.command_size]), (*batch, self.command_size)):
                raise ValueError(
                    f"state_des override must have shape [{self.command_size}] or {[*batch, self.command_size]}, "
                    f"got {list(goal.shape)}"
                )
        return goal.expand(*batch, self.command_size).clone()

    def _reset(self, init_state: torch.Tensor, overrides: dict[str, Any]) -> TensorDict:
        command = self._command(init_state, overrides)
        entries: dict[str, Any] = {GOAL_ENTRY: command}
        if self.reward.stateful:
            entries["reward"] = self.reward.reset(self._reward_state(init_state, command))
        return make_memory(entries, init_state.shape[:-1])

    def _goal_slots(self, prefix: tuple[str, ...], indices: tuple[int, ...] | None) -> list[GoalSlot]:
        selected = tuple(self.tracked) if indices is None else tuple(indices[i] for i in self.tracked)
        path = (*prefix, GOAL_ENTRY)
        return [GoalSlot(".".join(path), path, self.command_size, selected)]

    # --------------------------------------------------------------------------------- reward
    def _reward_state(self, state: torch.Tensor, command: torch.Tensor) -> torch.Tensor:
        index = self.tracked_index if self.tracked_index.device == state.device else self.tracked_index.to(state.device)
        command = command.to(state.dtype)
        return torch.cat((state, command, command - state.index_select(-1, index)), dim=-1)

    def _reward_inputs(
        self, state: torch.Tensor, action: torch.Tensor, memory: TensorDictBase
    ) -> tuple[torch.Tensor, torch.Tensor]:
        return self._reward_state(state, read(memory, GOAL_ENTRY)), action

    # --------------------------------------------------------------------------- terminations
    def _named_failures(self, state: torch.Tensor) -> dict[str, torch.Tensor]:
        if not self.terminations:
            return {}
        index = self.termination_index
        values = state.index_select(-1, index if index.device == state.device else index.to(state.device))
        failures = {}
        for column, name in enumerate(self.terminations):
            bounds = cast_like(self._buffers[f"termination_{name}_range"], values)
            value = values[..., column]
            failures[name] = ~((value >= bounds[0]) & (value <= bounds[1]))  # NaN: outside
        return failures

    def _has_failed(self, state: torch.Tensor, memory: TensorDictBase) -> torch.Tensor:
        failed = super()._has_failed(state, memory)
        for flag in self._named_failures(state).values():
            failed = failed | flag
        return failed

    @property
    def termination_names(self) -> dict[str, str]:
        return {"out_of_bounds": "failure", **dict.fromkeys(self.terminations, "failure")}

    def _termination_terms(
        self, state: torch.Tensor, memory: TensorDictBase, success: torch.Tensor, failure: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        return {"out_of_bounds": super()._has_failed(state, memory), **self._named_failures(state)}

    def extra_repr(self) -> str:
        return f"tracked={self.tracked}, terminations={self.terminations}"
