"""Steps of a legged robot rewarded by how long each foot was in the air: :class:`FeetAirTimeReward`."""

from __future__ import annotations

from collections.abc import Iterable

import torch
from tensordict import TensorDict

from torchtasks._checks import cast_like, check_finite_scalar, check_input, check_same_batch, check_weight
from torchtasks._memory import make_memory, read
from torchtasks.rewards._selection import EntrySelection
from torchtasks.rewards.base import RewardFunction, row_sum, squared_sum
from torchtasks.spaces import Box

__all__ = ["FeetAirTimeReward"]


class FeetAirTimeReward(RewardFunction):
    """``Σ_f (t_air_f - threshold) · [foot f lands now]``: steps longer than ``threshold`` pay, shorter ones cost.

    IsaacLab's ``feet_air_time`` on contact entries of the state (one per foot: a touch sensor or a contact force
    magnitude). A foot is in contact when its entry exceeds ``contact_threshold``. Its air time ``t_air`` is the
    control time it has spent in the air: ``dt`` for every step whose state had it out of contact, counted from the
    last contact (or from the reset). A foot *lands* in a step when it is in contact and its air time is positive;
    the step pays ``t_air - threshold`` for each landing foot and its air time restarts at 0. With
    ``command_indices``, the reward is paid only where the norm of those entries (the planar velocity command)
    exceeds ``min_command`` (IsaacLab: 0.1): a robot told to stand is not paid for stepping.

    Stateful: the air time of each foot lives in memory (``"air_time"``, ``[*B, feet]``), 0 at :meth:`reset` (per
    env at a partial reset). Piecewise linear in the stored air times; ignores the action.

    Args:
        dt: the control step [s] (positive).
        contact_indices: the contact entries, one per foot (non-negative ints or labels of ``space``).
        threshold: the air time [s] a step must exceed to pay (IsaacLab: 0.5).
        contact_threshold: the contact entry above which a foot is in contact (non-negative, e.g. 1 N).
        command_indices: the command entries whose norm gates the reward (``None``: always paid).
        min_command: the command norm the reward needs (strictly above).
        space: a :class:`~torchtasks.spaces.Box` whose labels name the entries.

    Example:
        >>> import torch
        >>> from torchtasks.rewards import FeetAirTimeReward
        >>> reward = FeetAirTimeReward(dt=0.1, contact_indices=[0, 1], threshold=0.15)
        >>> memory = reward.reset(torch.zeros(1, 2))
        >>> for touch in ([5.0, 0.0], [5.0, 0.0], [5.0, 0.0], [5.0, 5.0]):  # foot 1 in the air for 3 steps, lands
        ...     value, memory = reward.step(torch.tensor([touch]), None, memory)
        >>> value, memory["air_time"]
        (tensor([0.1500]), tensor([[0., 0.]]))
    """

    stateful = True
    uses_action = False

    def __init__(
        self,
        dt: float,
        contact_indices: Iterable[int | str] | int | str,
        *,
        threshold: float = 0.5,
        contact_threshold: float = 1.0,
        command_indices: Iterable[int | str] | int | str | None = None,
        min_command: float = 0.1,
        space: Box | None = None,
    ) -> None:
        super().__init__()
        dt = check_finite_scalar(dt, "dt")
        if dt <= 0:
            raise ValueError(f"dt must be positive, got {dt}")
        self._register_scalar("dt", dt)
        self._register_scalar("threshold", check_finite_scalar(threshold, "threshold"))
        self._register_scalar("contact_threshold", check_weight(contact_threshold, "contact_threshold"))
        self._register_scalar("min_command", check_weight(min_command, "min_command"))
        self.feet = EntrySelection(contact_indices, space, "contact_indices")
        self.command = None if command_indices is None else EntrySelection(command_indices, space, "command_indices")

    @property
    def num_feet(self) -> int:
        """The number of feet (contact entries)."""
        return len(self.feet.positions)

    def _size_problem(self, state_size: int, action_size: int | None, who: str) -> str | None:
        problem = self.feet.size_problem(state_size, who)
        if problem is None and self.command is not None:
            problem = self.command.size_problem(state_size, who)
        return problem

    def reset(self, init_state: torch.Tensor) -> TensorDict:
        self.feet.check(init_state, "init_state", type(self).__name__)
        zeros = init_state.new_zeros((*init_state.shape[:-1], self.num_feet))
        return TensorDict({"air_time": zeros}, batch_size=init_state.shape[:-1])

    def step(
        self, state: torch.Tensor, action: torch.Tensor | None, memory: TensorDict
    ) -> tuple[torch.Tensor, TensorDict]:
        self.feet.check(state, "state", type(self).__name__)
        if self.command is not None:
            self.command.check(state, "state", type(self).__name__)
        if action is not None:
            check_input(action, "action")
            check_same_batch(state, action, "state", "action")
        if not isinstance(memory, TensorDict) or "air_time" not in memory.keys():
            raise TypeError("memory must be the TensorDict returned by FeetAirTimeReward.reset(init_state)")
        if memory.batch_size != state.shape[:-1]:
            raise ValueError(
                f"memory has batch size {tuple(memory.batch_size)} but the state has batch shape "
                f"{tuple(state.shape[:-1])}"
            )
        return self._step(state, action, memory)

    def _step(
        self, state: torch.Tensor, action: torch.Tensor | None, memory: TensorDict
    ) -> tuple[torch.Tensor, TensorDict]:
        air_time = read(memory, "air_time")
        forces = self.feet.select(state)
        contact = forces > cast_like(self.contact_threshold, forces)
        landing = contact & (air_time > 0)
        zero = torch.zeros((), dtype=air_time.dtype, device=air_time.device)
        paid = torch.where(landing, air_time - cast_like(self.threshold, air_time), zero)
        value = row_sum(paid)
        if self.command is not None:
            command = self.command.select(state)
            moving = squared_sum(command).sqrt() > cast_like(self.min_command, command)
            value = torch.where(moving, value, zero)
        air_time = torch.where(contact, zero, air_time + cast_like(self.dt, air_time))
        return value, make_memory({"air_time": air_time}, memory.batch_size)

    def forward(
        self, state: torch.Tensor, action: torch.Tensor | None, memory: TensorDict
    ) -> tuple[torch.Tensor, TensorDict]:
        return self.step(state, action, memory)

    def extra_repr(self) -> str:
        command = None if self.command is None else self.command.positions
        return (
            f"dt={float(self.dt)}, contact_indices={self.feet.positions}, threshold={float(self.threshold)}, "
            f"contact_threshold={float(self.contact_threshold)}, command_indices={command}, "
            f"min_command={float(self.min_command)}"
        )
