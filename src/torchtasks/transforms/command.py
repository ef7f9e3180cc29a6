"""Goal commands the policy sees: :class:`GoalCommand`, a TorchRL transform that samples, holds and resamples goals.

IsaacLab and mjlab call these commands: a per-env target (a position to reach, a velocity to
track) that is part of the observation, resampled at reset and on a per-env timer. A
:class:`~torchtasks.transforms.TaskTransform` with ``goal_key=`` passes the goal of step ``t`` (the
one the policy saw) to the task, so the reward and the success flag are judged against it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torchrl.data import Bounded, Composite, Unbounded

from torchtasks._checked_load import CheckedLoad
from torchtasks._checks import check_batch_size, check_finite_scalar, check_int, check_positive_int
from torchtasks._torchrl import container_env, flat_transforms, key_parts, nested_key
from torchtasks.spaces import Box
from torchtasks.transforms.names import SUCCESS_KEY
from torchtasks.transforms.seeding import SeededTransform
from torchtasks.transforms.task import TaskTransform, undefined_flag_note

__all__ = ["GoalCommand"]

Sampler = Callable[[torch.Size, torch.Generator | None], torch.Tensor]


class GoalCommand(CheckedLoad, SeededTransform):
    """Sample per-env goals into the observation; resample at reset, on a per-env timer, or after a success.

    The goal lives under ``goal_key`` (observation AND state spec, so batched envs, collectors and ``env.rollout``
    carry it). Goals are drawn uniformly from a :class:`~torchtasks.spaces.Box` (finite bounds; from its range
    buffers ``low`` and ``high``, which a :class:`~torchtasks.transforms.Curriculum` or
    :class:`~torchtasks.transforms.DifficultyLevels` can set as ``"command.low"``/``"command.high"``, per env after
    :meth:`use_per_env_range`) or by a callable ``sampler(shape, generator) -> goals``, anew at each env's reset, every
    ``resample_steps`` steps (or after a per-env number of steps drawn from ``(low, high)``) and, with
    ``resample_on_success``, right after a success (the command then comes after the
    :class:`~torchtasks.transforms.TaskTransform`). The goal written in step ``t`` is the one the policy sees when it
    chooses ``a_{t+1}``, and the one a ``TaskTransform(task, goal_key=...)`` judges the transition ``t+1`` with.

    Randomness: ``seed=k`` gives the command its own generator; ``seed=None`` draws from torch's global generator
    until ``env.set_seed(s)`` gives it one seeded from ``s`` and its place in the env (workers draw different streams,
    the same ``s`` the same goals). ``state_dict()`` holds the generator and the range buffers: a load draws the goals
    and timers the saved command would have drawn next (the running episodes' goals are not saved). The docs page
    "Goal-conditioned tasks" has the details (timers, seeds, checkpoints, relabelling).

    Args:
        space: the goal space (a ``Box`` of ``k`` finite entries) or a sampler.
        goal_key: where the goal is written.
        resample_steps: ``None`` (only at reset), an int, or an inclusive ``(low, high)`` range.
        resample_on_success: draw a new goal right after a success.
        success_key: the success flag written by the TaskTransform.
        seed: seed of the command's own generator (``None``: torch's global one until ``env.set_seed``).
        goal_size: the number of goal entries when ``space`` is a sampler.
        zero_goal_probability: the probability that a goal drawn (at reset or at a resampling) is all zeros instead,
            per env, from the command's generator: the "standing" envs of a velocity command (IsaacLab's
            ``rel_standing_envs``). 0 (the default) draws exactly as without it; the zero goal must lie in ``space``.

    Example:
        >>> import functools, torch
        >>> from torchrl.envs import Compose, StepCounter, TransformedEnv
        >>> from torchtasks.envs import PendulumEnv
        >>> from torchtasks.rewards import QuadraticErrorReward
        >>> from torchtasks.spaces import Box, EnvSpec
        >>> from torchtasks.tasks import DesiredStateTask, proximity_succeeded
        >>> from torchtasks.transforms import GoalCommand, TaskTransform
        >>> near = functools.partial(proximity_succeeded, threshold=0.1)
        >>> task = DesiredStateTask(EnvSpec(2, 1), [0.0, 0.0], QuadraticErrorReward([1.0, 0.1]), near)
        >>> env = TransformedEnv(PendulumEnv(batch_size=[4]), Compose(
        ...     StepCounter(50),
        ...     TaskTransform(task, goal_key="goal"),
        ...     GoalCommand(Box([-1.0, -0.5], [1.0, 0.5]), resample_steps=(5, 10), seed=0)))
        >>> rollout = env.rollout(12, break_when_any_done=False)  # (a reached goal ends an episode)
        >>> rollout["goal"].shape
        torch.Size([4, 12, 2])
    """

    def __init__(
        self,
        space: Box | Sampler,
        *,
        goal_key: NestedKey = "goal",
        resample_steps: int | tuple[int, int] | None = None,
        resample_on_success: bool = False,
        success_key: NestedKey = SUCCESS_KEY,
        seed: int | None = None,
        goal_size: int | None = None,
        zero_goal_probability: float = 0.0,
    ) -> None:
        zero_goal_probability = check_finite_scalar(zero_goal_probability, "GoalCommand: zero_goal_probability")
        if not 0.0 <= zero_goal_probability <= 1.0:
            raise ValueError(f"GoalCommand: zero_goal_probability must lie in [0, 1], got {zero_goal_probability}")
        if isinstance(space, Box):
            if not (torch.isfinite(space.low).all() and torch.isfinite(space.high).all()):
                raise ValueError("GoalCommand: the goal space must have finite bounds to sample uniformly from it")
            size = space.size
            if zero_goal_probability > 0 and not bool(((space.low <= 0) & (space.high >= 0)).all()):
                raise ValueError(
                    f"GoalCommand: zero_goal_probability={zero_goal_probability} draws all-zero goals, but 0 is "
                    f"outside the goal space (low={space.low.tolist()}, high={space.high.tolist()})"
                )
        elif callable(space):
            if goal_size is None:
                raise ValueError("GoalCommand: a sampler needs goal_size=<number of goal entries>, got None")
            size = check_positive_int(goal_size, "GoalCommand: goal_size")
        else:
            raise TypeError(f"space must be a torchtasks.spaces.Box or a sampler callable, got {type(space).__name__}")
        self.timer_range = _timer_range(resample_steps)
        if not isinstance(resample_on_success, bool):
            raise TypeError(f"resample_on_success must be a bool, got {resample_on_success!r}")
        self.goal_key = nested_key(goal_key, "GoalCommand: goal_key")
        *parent, leaf = key_parts(self.goal_key)
        self.timer_key = (*parent, f"{leaf}_steps_left") if parent else f"{leaf}_steps_left"
        self.success_key = nested_key(success_key, "GoalCommand: success_key")
        seed = None if seed is None else check_int(seed, "GoalCommand: seed")
        in_keys = [self.goal_key, self.timer_key] + ([self.success_key] if resample_on_success else [])
        super().__init__(in_keys=in_keys, out_keys=[self.goal_key, self.timer_key])
        self.space = space
        self.goal_size = size
        self.zero_goal_probability = zero_goal_probability
        self.resample_on_success = resample_on_success
        self.generator = None if seed is None else torch.Generator().manual_seed(seed)
        if isinstance(space, Box):  # the sampling range: registered, so .to(), state_dict and a Curriculum reach it
            self.register_buffer("low", space.low.clone())
            self.register_buffer("high", space.high.clone())

    def set_seed(self, seed: int) -> None:
        """Seed the command's own generator with ``seed`` (created if it had none).

        ``env.set_seed(s)`` calls it with a seed derived from ``s`` (see :mod:`torchtasks.transforms.seeding`). The
        goals and timers of the running episodes are in the env's data and go on: the seed decides the draws from
        then on (a run repeats from its first frame when it is reset after the seed).
        """
        self.generator = torch.Generator().manual_seed(check_int(seed, "GoalCommand.set_seed: seed"))

    def seed_identity(self) -> str:
        """``"GoalCommand(<goal key>)"``: mixed into the seed ``env.set_seed`` derives for this command."""
        return f"{type(self).__name__}({self.goal_key!r})"

    # ---------------------------------------------------------------------------- checkpoints
    def get_extra_state(self) -> dict[str, Any]:
        """The command's generator: ``{"own_generator", "seed", "generator_state"}`` (``None`` without one)."""
        generator = self.generator
        if generator is None:
            return {"own_generator": False, "seed": None, "generator_state": None}
        return {"own_generator": True, "seed": generator.initial_seed(), "generator_state": generator.get_state()}

    def set_extra_state(self, state: Any) -> None:
        """Restore the generator saved by :meth:`get_extra_state` (none saved: use torch's global one)."""
        if not isinstance(state, Mapping) or not {"own_generator", "generator_state"} <= set(state):
            raise ValueError(
                "GoalCommand.load_state_dict: the extra state must be a dict with 'own_generator' and "
                f"'generator_state' (as GoalCommand.state_dict() writes it), got {state!r}"
            )
        if not state["own_generator"]:
            self.generator = None
            return
        saved = state["generator_state"]
        if not isinstance(saved, torch.Tensor) or saved.dtype != torch.uint8:
            raise ValueError(
                f"GoalCommand.load_state_dict: 'generator_state' must be a uint8 tensor, got {type(saved).__name__}"
            )
        generator = torch.Generator()
        generator.set_state(saved.cpu())
        self.generator = generator

    # ----------------------------------------------------------------------- range per env
    def use_per_env_range(self, batch_size: torch.Size | Sequence[int]) -> None:
        """Give every env of the batch its own sampling range: ``low``/``high`` become ``[*batch_size, k]``.

        Each env starts with the current range (a ``[k]`` buffer is expanded and copied). Nothing
        changes if the buffers already have that shape. Goals of env ``i`` are then drawn from
        ``[low[i], high[i]]``, at reset and at every resampling; a transform that sets per-env
        difficulty writes rows of these buffers.

        Raises:
            ValueError: the command samples with a callable (it has no range), or a buffer has another
                per-env shape.
            TypeError: ``batch_size`` is not a sequence of non-negative ints.

        Example:
            >>> import torch
            >>> from torchtasks.transforms import GoalCommand
            >>> from torchtasks.spaces import Box
            >>> command = GoalCommand(Box([-1.0, 0.0], [1.0, 2.0]), seed=0)
            >>> command.use_per_env_range(torch.Size([3]))
            >>> command.low.shape
            torch.Size([3, 2])
            >>> command.high[2] = torch.tensor([-0.5, 0.5], dtype=torch.float64)  # env 2: a narrow range
            >>> goals = command._sample_goals(torch.Size([3]), torch.float64, torch.device("cpu"))
            >>> bool((goals[2] <= torch.tensor([-0.5, 0.5], dtype=torch.float64)).all())
            True
        """
        if not isinstance(self.space, Box):
            raise ValueError(
                "GoalCommand.use_per_env_range: this command draws goals with a sampler callable, which has no "
                "sampling range (low/high buffers); build it with a torchtasks.spaces.Box to give envs their own range"
            )
        batch = check_batch_size(batch_size, "GoalCommand.use_per_env_range: batch_size")
        target = torch.Size([*batch, self.goal_size])
        for name in ("low", "high"):
            shape = self._buffers[name].shape
            if shape != target and shape != (self.goal_size,):
                raise ValueError(
                    f"GoalCommand.use_per_env_range: the range buffer {name!r} has shape {list(shape)}, which is "
                    f"neither one range [{self.goal_size}] nor the requested per-env range {list(target)} "
                    f"(batch_size {list(batch)}, {self.goal_size} goal entries)"
                )
        for name in ("low", "high"):
            buffer = self._buffers[name]
            if buffer.shape != target:
                self._buffers[name] = buffer.expand(target).clone()

    def _check_saved(self, state_dict: Mapping[str, Any], prefix: str) -> None:
        """Refuse the checkpoint of a command of the other kind (Box range or sampler) or of a range of other size."""
        saved_range = prefix + "low" in state_dict or prefix + "high" in state_dict
        if saved_range != isinstance(self.space, Box):
            saved, here = ("a Box range", "a sampler callable") if saved_range else ("a sampler", "a Box range")
            raise ValueError(
                f"GoalCommand.load_state_dict: the checkpoint is of a command drawing goals from {saved}, this one "
                f"(writing {self.goal_key!r}) draws from {here}: build the command as saved"
            )
        for name in ("low", "high") if saved_range else ():
            saved = state_dict.get(prefix + name)
            if isinstance(saved, torch.Tensor) and (saved.dim() == 0 or saved.shape[-1] != self.goal_size):
                raise ValueError(
                    f"GoalCommand.load_state_dict: the saved range {name!r} must have shape [{self.goal_size}] "
                    f"or [*B, {self.goal_size}] ({self.goal_size} goal entries), got {list(saved.shape)}"
                )

    def _prepare_load(self, state_dict: Mapping[str, Any], prefix: str) -> None:
        # a saved range of one shape ([k] or [*B, k]) loads into buffers of the other: the buffers take the saved shape
        for name in ("low", "high") if isinstance(self.space, Box) else ():
            saved, own = state_dict.get(prefix + name), self._buffers.get(name)
            if isinstance(saved, torch.Tensor) and own is not None and saved.shape != own.shape:
                self._buffers[name] = torch.empty(saved.shape, dtype=own.dtype, device=own.device)

    def _check_loaded(self) -> None:
        """Refuse a loaded range that leaves the goal space (the goal spec) or has ``low > high``."""
        if not isinstance(self.space, Box):
            return
        low, high = self._buffers["low"], self._buffers["high"]
        space_low = self.space.low.to(low.device, torch.float64)
        space_high = self.space.high.to(low.device, torch.float64)
        low64, high64 = low.to(torch.float64), high.to(torch.float64)
        inside = (low64 >= space_low) & (high64 <= space_high) & (low64 <= high64)  # False for NaN too
        if not bool(inside.all()):
            raise ValueError(
                f"GoalCommand.load_state_dict: the saved sampling range (low={low.tolist()}, high={high.tolist()}) "
                f"must lie in this command's goal space (low={self.space.low.tolist()}, "
                f"high={self.space.high.tolist()}) with low <= high: goals drawn from it would leave the goal spec; "
                "build the command with a Box that holds the saved range"
            )

    # --------------------------------------------------------------------------- sampling
    def _sample_goals(self, batch: torch.Size, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
        if isinstance(self.space, Box):
            low, high = self.low, self.high
            if low.dim() > 1 or high.dim() > 1:
                self._check_range_batch(batch)
            unit = torch.rand((*batch, self.goal_size), generator=self.generator, dtype=torch.float64)
            goals = low + unit.to(low.device) * (high - low)
        else:
            goals = torch.as_tensor(self.space(torch.Size(batch), self.generator))
            if goals.shape != (*batch, self.goal_size) or not goals.is_floating_point():
                raise ValueError(
                    f"GoalCommand: the sampler must return floating goals of shape {[*batch, self.goal_size]}, "
                    f"got {goals.dtype} {list(goals.shape)}"
                )
        if self.zero_goal_probability > 0:  # a draw per env after the goals: without it, the stream is unchanged
            zero = torch.rand(batch, generator=self.generator, dtype=torch.float64) < self.zero_goal_probability
            goals = torch.where(zero.to(goals.device).unsqueeze(-1), torch.zeros_like(goals), goals)
        return goals.to(device=device, dtype=dtype)

    def _check_range_batch(self, batch: torch.Size) -> None:
        for name in ("low", "high"):
            shape = self._buffers[name].shape
            if len(shape) > 1 and shape[:-1] != batch:
                raise ValueError(
                    f"GoalCommand: the per-env range {name!r} has shape {list(shape)}, but goals are drawn for a "
                    f"batch of {list(batch)} envs; call use_per_env_range({list(batch)}) on a command with one range "
                    "or load a range saved from an env of this batch size"
                )

    def _sample_timers(self, batch: torch.Size, device: torch.device) -> torch.Tensor:
        if self.timer_range is None:
            return torch.zeros(batch, dtype=torch.long, device=device)
        low, high = self.timer_range
        return torch.randint(low, high + 1, batch, generator=self.generator).to(device)

    # ------------------------------------------------------------------------------ specs
    def _goal_dtype(self) -> torch.dtype:
        """The goal's dtype: the parent's ``"observation"``'s if floating, else its first floating entry's, else the
        default; found once with the specs (a walk of every spec entry), then kept."""
        dtype = self.__dict__.get("_dtype")
        if dtype is not None:
            return dtype
        parent = self.parent
        if parent is None:
            return torch.get_default_dtype()
        spec = parent.full_observation_spec
        keys = list(spec.keys(True, True))
        for key in ("observation", *keys):
            if key in keys and spec[key].dtype.is_floating_point:
                return spec[key].dtype
        return torch.get_default_dtype()

    def _specs(self, batch: torch.Size, device: torch.device | None, dtype: torch.dtype) -> dict:
        if isinstance(self.space, Box):
            goal = Bounded(
                low=self.space.low.to(dtype).expand(*batch, self.goal_size),
                high=self.space.high.to(dtype).expand(*batch, self.goal_size),
                shape=(*batch, self.goal_size),
                dtype=dtype,
                device=device,
            )
        else:
            goal = Unbounded(shape=(*batch, self.goal_size), dtype=dtype, device=device)
        timer = Unbounded(shape=batch, dtype=torch.long, device=device)
        return {self.goal_key: goal, self.timer_key: timer}

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        self._check_placement()
        self.__dict__.pop("_dtype", None)  # the specs are built anew: find the dtype again
        dtype = self._goal_dtype()
        self.__dict__["_dtype"] = dtype
        for key, spec in self._specs(observation_spec.shape, observation_spec.device, dtype).items():
            observation_spec[key] = spec
        return observation_spec

    def transform_state_spec(self, state_spec: Composite) -> Composite:
        parent = self.parent
        batch = parent.batch_size if parent is not None else state_spec.shape
        device = None if parent is None else parent.device
        if state_spec is None:
            state_spec = Composite(shape=batch, device=device)
        for key, spec in self._specs(batch, device, self._goal_dtype()).items():
            state_spec[key] = spec
        return state_spec

    def _check_placement(self) -> None:
        """Refuse orders in which the command cannot see success or the task cannot see the goal."""
        transform = getattr(container_env(self), "transform", None)
        if transform is None:
            return
        flat = flat_transforms(transform)
        position = next((i for i, t in enumerate(flat) if t is self), None)
        tasks = [(i, t) for i, t in enumerate(flat) if isinstance(t, TaskTransform)]
        if self.resample_on_success and not any(i < position and t.success_key == self.success_key for i, t in tasks):
            raise ValueError(
                "GoalCommand(resample_on_success=True) must come after the TaskTransform that writes "
                f"{self.success_key!r}: it reads the success of the step to draw the next goal. Put it after "
                "TaskTransform in the Compose."
            )
        note = undefined_flag_note(self, self.success_key) if self.resample_on_success else ""
        if note:  # a task that cannot succeed writes no success flag: the command would never resample
            raise ValueError(
                f"GoalCommand(resample_on_success=True) reads the success of the step ({self.success_key!r}){note}; "
                "give the task a success condition or pass resample_on_success=False"
            )
        for _, task in tasks:
            if task.goal_key != self.goal_key:
                raise ValueError(
                    f"GoalCommand writes the goal to {self.goal_key!r}, but the TaskTransform of "
                    f"{type(task.task).__name__} reads goal_key={task.goal_key!r}: the task would not see the goal. "
                    f"Pass TaskTransform(task, goal_key={self.goal_key!r})."
                )

    # ------------------------------------------------------------------------ TorchRL hooks
    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        batch = tensordict_reset.batch_size
        device = tensordict_reset.device or torch.device("cpu")
        dtype = self._goal_dtype()
        goals = self._sample_goals(batch, dtype, device)
        timers = self._sample_timers(batch, device)
        reset = None if tensordict is None else tensordict.get("_reset", None)
        old_goals = None if tensordict is None else tensordict.get(self.goal_key, None)
        old_timers = None if tensordict is None else tensordict.get(self.timer_key, None)
        if reset is not None and old_goals is not None and old_timers is not None:
            mask = reset.reshape(batch)
            goals = torch.where(mask.unsqueeze(-1), goals, old_goals)
            timers = torch.where(mask, timers, old_timers)
        tensordict_reset.set(self.goal_key, goals)
        tensordict_reset.set(self.timer_key, timers)
        return tensordict_reset

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        goals = tensordict.get(self.goal_key)
        timers = tensordict.get(self.timer_key)
        if goals is None or timers is None:
            raise KeyError(f"GoalCommand: {self.goal_key!r} is missing from the data; call env.reset() first")
        batch = goals.shape[:-1]
        resample = torch.zeros(batch, dtype=torch.bool, device=goals.device)
        if self.timer_range is not None:
            timers = timers - 1
            resample = timers <= 0
        if self.resample_on_success:
            resample = resample | next_tensordict.get(self.success_key).reshape(batch)
        new_goals = self._sample_goals(batch, goals.dtype, goals.device)
        goals = torch.where(resample.unsqueeze(-1), new_goals, goals)
        if self.timer_range is not None:
            timers = torch.where(resample, self._sample_timers(batch, goals.device), timers)
        else:  # never counted down: a copy, so that the entry under "next" is not the root's tensor
            timers = timers.clone()
        next_tensordict.set(self.goal_key, goals)
        next_tensordict.set(self.timer_key, timers)
        return next_tensordict

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(goal_key={self.goal_key!r}, resample_steps={self.timer_range}, "
            f"resample_on_success={self.resample_on_success}"
            + (f", zero_goal_probability={self.zero_goal_probability}" if self.zero_goal_probability else "")
            + ")"
        )


def _timer_range(resample_steps: object) -> tuple[int, int] | None:
    if resample_steps is None:
        return None
    if isinstance(resample_steps, Sequence) and not isinstance(resample_steps, str):
        if len(resample_steps) != 2:
            raise TypeError(f"resample_steps must be None, an int or a (low, high) pair, got {resample_steps!r}")
        low = check_positive_int(resample_steps[0], "GoalCommand: resample_steps[0]")
        high = check_positive_int(resample_steps[1], "GoalCommand: resample_steps[1]")
    else:
        low = high = check_positive_int(resample_steps, "GoalCommand: resample_steps")
    if low > high:
        raise ValueError(f"resample_steps (low, high) needs low <= high, got {resample_steps!r}")
    return low, high
