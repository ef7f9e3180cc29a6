"""TorchRL face of a task: :class:`TaskTransform` turns env outputs into task rewards and flags."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Literal

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey, unravel_key
from torchrl.data import Categorical, Composite, Unbounded
from torchrl.envs.transforms import Compose, StepCounter, Transform
from torchrl.envs.utils import make_composite_from_td

from torchtasks._checks import SUPPORTED_FLOATS
from torchtasks._memory import td_get, td_set
from torchtasks.tasks.base import Task
from torchtasks.tasks.memory import where_memory

__all__ = ["TaskTransform"]

ResetOverrides = Callable[[torch.Tensor], dict[str, Any]]


def _flat_transforms(transform: Transform) -> list[Transform]:
    if isinstance(transform, Compose):
        return [leaf for child in transform.transforms for leaf in _flat_transforms(child)]
    return [transform]


def _as_entry(value: torch.Tensor, shape: torch.Size, dtype: torch.dtype) -> torch.Tensor:
    """``value`` reshaped to the env's ``[*B, 1]`` entry shape, in the spec's dtype (no cast when it already is)."""
    value = value.reshape(shape)
    return value if value.dtype == dtype else value.to(dtype)


def _check_vector_gym(base_env: Any) -> None:
    """Reject Gymnasium vector envs that reset sub-envs by themselves (they cannot take task resets)."""
    gym_env = base_env.__dict__.get("_env")
    if gym_env is None or not hasattr(gym_env, "num_envs"):
        return
    mode = getattr(gym_env, "metadata", {}).get("autoreset_mode")
    if mode is not None and str(getattr(mode, "name", mode)).upper() == "DISABLED":
        return
    raise ValueError(
        f"{type(base_env).__name__} wraps a Gymnasium vector env that resets its sub-envs itself, so it cannot "
        "end episodes when the task says so. Use ParallelEnv/SerialEnv of single envs, or "
        "GymWrapper(gymnasium.make_vec(..., vector_kwargs={'autoreset_mode': "
        "gymnasium.vector.AutoresetMode.DISABLED}))."
    )


class TaskTransform(Transform):
    """Apply a task to a TorchRL env: task reward, success, failure and termination on every step.

    In each step the transform reads ``s_t`` and ``a_t`` from the root tensordict, ``s_{t+1}`` from
    ``"next"`` and the task memory from ``memory_key``. The step reward is evaluated on
    ``s_{t+1}`` (``reward_on="next"``, the Gymnasium convention) or ``s_t`` (``reward_on="state"``,
    Pyrado's order); success, failure and the final reward on ``s_{t+1}``. The final reward is
    paid once, in the step where the episode ends (success, failure, the env's own termination
    or truncation). The reward written to ``"reward"`` replaces the env's reward and is cast to
    the reward spec's dtype. ``terminated`` and ``done`` are OR-ed with success and failure;
    ``truncated`` is left untouched.

    The remaining steps passed to the task are ``max_steps - step_count`` when a
    ``StepCounter(max_steps)`` precedes this transform (0 without a limit, as in Pyrado).

    When the specs are first built, the task is moved to the dtype of the state entry
    (``task.to(dtype)``, in place), so constants are cast once and not at every step; build a
    separate task object if you need the original precision elsewhere.

    Written entries: ``success`` and ``failure`` (bool, observation spec), the memory under
    ``memory_key`` (observation AND state spec, so batched and multi-process envs carry it), and,
    with ``log_terms``, the reward breakdown ``(terms_key, "step")``, ``(terms_key, "final")`` and
    one entry per named term of a compound or locomotion reward (reward spec, so a following
    ``RewardSum()`` reports per-term episode sums).

    Args:
        task: the task to apply.
        state_key: the key (or keys, concatenated on the last dim) holding the task's state.
        action_key: the action key.
        reward_on: ``"next"`` or ``"state"``: which state the step reward is evaluated on.
        memory_key, success_key, failure_key, terms_key: output keys.
        log_terms: write the reward breakdown.
        max_steps: time limit for the remaining steps; by default read from a preceding StepCounter.
        reset_overrides: ``init_state -> {name: value}`` per-env reset overrides (e.g. a goal
            sampler returning ``{"state_des": goals}``); must be picklable for multi-process envs.
        compile: evaluate the task with ``torch.compile(fullgraph=True)``.

    Example:
        >>> import torch
        >>> from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv
        >>> from torchtasks.envs import PendulumEnv
        >>> from torchtasks.rewards import QuadraticErrorReward
        >>> from torchtasks.spaces import EnvSpec
        >>> from torchtasks.tasks import RadiallySymmetricDesiredStateTask
        >>> task = RadiallySymmetricDesiredStateTask(
        ...     EnvSpec(2, 1), [0.0, 0.0], QuadraticErrorReward([1.0, 0.1], [0.001]), indices=[0])
        >>> transforms = Compose(StepCounter(50), TaskTransform(task), RewardSum())
        >>> env = TransformedEnv(PendulumEnv(batch_size=[4]), transforms)
        >>> rollout = env.rollout(10)
        >>> rollout["next", "reward"].shape, rollout["next", "success"].dtype
        (torch.Size([4, 10, 1]), torch.bool)
    """

    def __init__(
        self,
        task: Task,
        *,
        state_key: NestedKey | Sequence[NestedKey] = "observation",
        action_key: NestedKey = "action",
        reward_on: Literal["next", "state"] = "next",
        reward_key: NestedKey = "reward",
        memory_key: NestedKey = "task",
        success_key: NestedKey = "success",
        failure_key: NestedKey = "failure",
        terms_key: NestedKey = "task_reward",
        log_terms: bool = True,
        max_steps: int | None = None,
        reset_overrides: ResetOverrides | None = None,
        compile: bool = False,
    ) -> None:
        if not isinstance(task, Task):
            raise TypeError(f"task must be a torchtasks Task, got {type(task).__name__}")
        if reward_on not in ("next", "state"):
            raise ValueError(f"reward_on must be 'next' or 'state', got {reward_on!r}")
        if max_steps is not None and (isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 1):
            raise ValueError(f"max_steps must be a positive int or None, got {max_steps!r}")
        if reset_overrides is not None and not callable(reset_overrides):
            raise TypeError(f"reset_overrides must be callable, got {type(reset_overrides).__name__}")
        if isinstance(state_key, (str, tuple)) and not (
            isinstance(state_key, tuple) and state_key and isinstance(state_key[0], tuple)
        ):
            state_keys = [unravel_key(state_key)]
        else:
            state_keys = [unravel_key(key) for key in state_key]
        reserved = {"step", "final"} & set(task.term_names)
        if log_terms and reserved:
            raise ValueError(f"reward terms may not be named {sorted(reserved)}: those names are the breakdown's")
        self.state_keys = state_keys
        self.action_key = unravel_key(action_key)
        self.reward_key = unravel_key(reward_key)
        self.memory_key = unravel_key(memory_key)
        self.success_key = unravel_key(success_key)
        self.failure_key = unravel_key(failure_key)
        self.terms_key = unravel_key(terms_key)
        self.reward_on = reward_on
        self.log_terms = log_terms
        self.reset_overrides = reset_overrides
        self.compile = compile
        self._explicit_max_steps = max_steps
        in_keys = [*state_keys, self.action_key, self.memory_key]
        out_keys = [self.reward_key, self.memory_key, self.success_key, self.failure_key]
        super().__init__(in_keys=in_keys, out_keys=out_keys)
        self.task = task
        # static per task tree: computed once, read every step
        self._term_names = tuple(task.term_names) if log_terms else ()
        self._term_keys = [self._key(name) for name in ("step", "final", *self._term_names)] if log_terms else []

    # ------------------------------------------------------------------ configuration
    def _key(self, *parts: str) -> NestedKey:
        base = (self.terms_key,) if isinstance(self.terms_key, str) else self.terms_key
        return unravel_key((*base, *parts))

    @property
    def term_keys(self) -> list[NestedKey]:
        """Keys of the reward breakdown: step reward, final reward, then the named terms."""
        return list(self._term_keys)

    def _setup(self) -> None:
        """Find the time limit and reject set-ups that cannot work (once, when specs are built)."""
        if "_max_steps" in self.__dict__:
            return
        max_steps = self._explicit_max_steps
        try:
            container = self.container
        except (AttributeError, ValueError):  # not in an env (e.g. a replay buffer's transform)
            container = None
        if container is not None and getattr(container, "transform", None) is not None:
            transforms = _flat_transforms(container.transform)
            position = next((i for i, t in enumerate(transforms) if t is self), None)
            for i, transform in enumerate(transforms):
                if not isinstance(transform, StepCounter):
                    continue
                if position is not None and i > position:
                    raise ValueError(
                        "StepCounter is placed after TaskTransform: the task would not see step_count and "
                        "truncation. Put StepCounter(max_steps) before TaskTransform in the Compose."
                    )
                if max_steps is None and transform.max_steps is not None:
                    max_steps = transform.max_steps
            _check_vector_gym(container.base_env)
        self.__dict__["_max_steps"] = max_steps
        self.__dict__["_needs_remaining"] = max_steps is not None and self.task.uses_remaining_steps

    @property
    def max_steps(self) -> int | None:
        """The time limit used for the remaining steps (None: no limit, remaining steps are 0)."""
        self._setup()
        return self.__dict__["_max_steps"]

    # ------------------------------------------------------------------------- specs
    def _state_spec_size(self, observation_spec: Composite) -> tuple[int, torch.dtype, torch.Size]:
        size = 0
        dtype = None
        batch = observation_spec.shape
        for key in self.state_keys:
            if key not in observation_spec.keys(True, True):
                raise KeyError(
                    f"TaskTransform: the state key {key!r} is not in the observation spec; available keys are "
                    f"{sorted(map(str, observation_spec.keys(True, True)))}. Pass state_key=... naming the entry "
                    "that holds the task's state."
                )
            spec = observation_spec[key]
            if spec.shape[: len(batch)] != batch or len(spec.shape) != len(batch) + 1:
                raise ValueError(
                    f"TaskTransform: the state entry {key!r} must have shape [*batch, n], got {tuple(spec.shape)}"
                )
            size += spec.shape[-1]
            dtype = spec.dtype if dtype is None else torch.promote_types(dtype, spec.dtype)
        if dtype not in SUPPORTED_FLOATS:
            raise TypeError(
                f"TaskTransform: the state entries {self.state_keys} have dtype {dtype}; tasks evaluate float32 or "
                "float64 states (cast the observation first, e.g. with torchrl's DTypeCastTransform)"
            )
        if size != self.task.state_size:
            raise ValueError(
                f"TaskTransform: the task reads states of size {self.task.state_size} but {self.state_keys} "
                f"holds {size} entries; build the task for this env's state or pick another state_key"
            )
        return size, dtype, batch

    def _memory_spec(self, batch: torch.Size, dtype: torch.dtype, device: torch.device | None) -> Composite:
        init_state = torch.zeros((*batch, self.task.state_size), dtype=dtype, device=device)
        memory = self.task._reset(init_state, self._overrides(init_state))
        spec = make_composite_from_td(memory, unsqueeze_null_shapes=False)
        return spec.to(device) if device is not None else spec

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        self._setup()
        _, dtype, batch = self._state_spec_size(observation_spec)
        self.task.to(dtype)
        self.__dict__["_state_dtype"] = dtype
        device = observation_spec.device
        done_shape = self.parent.full_done_spec["done"].shape if self.parent is not None else (*batch, 1)
        observation_spec[self.success_key] = Categorical(2, shape=done_shape, dtype=torch.bool, device=device)
        observation_spec[self.failure_key] = Categorical(2, shape=done_shape, dtype=torch.bool, device=device)
        observation_spec[self.memory_key] = self._memory_spec(batch, dtype, device)
        return observation_spec

    def transform_state_spec(self, state_spec: Composite) -> Composite:
        parent = self.parent
        observation_spec = parent.full_observation_spec
        _, dtype, batch = self._state_spec_size(observation_spec)
        if state_spec is None:
            state_spec = Composite(shape=batch, device=observation_spec.device)
        state_spec[self.memory_key] = self._memory_spec(batch, dtype, observation_spec.device)
        return state_spec

    def transform_reward_spec(self, reward_spec: Composite) -> Composite:
        if self.reward_key not in reward_spec.keys(True, True):
            raise KeyError(f"TaskTransform: the reward key {self.reward_key!r} is not in the reward spec")
        base = reward_spec[self.reward_key]
        self.__dict__["_reward_dtype"] = base.dtype
        for key in self.term_keys:
            reward_spec[key] = Unbounded(shape=base.shape, dtype=base.dtype, device=base.device)
        return reward_spec

    # ----------------------------------------------------------------------- helpers
    def _overrides(self, init_state: torch.Tensor) -> dict[str, Any]:
        return {} if self.reset_overrides is None else dict(self.reset_overrides(init_state))

    def _read_state(self, tensordict: TensorDictBase) -> torch.Tensor:
        if len(self.state_keys) == 1:
            state = td_get(tensordict, self.state_keys[0])
            if state is None:
                self._missing_state(tensordict)
            return state
        parts = [td_get(tensordict, key) for key in self.state_keys]
        if any(part is None for part in parts):
            self._missing_state(tensordict)
        return torch.cat(parts, dim=-1)

    def _missing_state(self, tensordict: TensorDictBase) -> None:
        try:
            parent = self.parent
        except (AttributeError, ValueError):
            parent = None
        if parent is not None:  # the spec check says which keys the env offers
            self._state_spec_size(parent.full_observation_spec)
        raise KeyError(
            f"TaskTransform: the state key(s) {self.state_keys} are missing from the data; available keys are "
            f"{sorted(map(str, tensordict.keys(True, True)))}. Pass state_key=... naming the entry that holds "
            "the task's state."
        )

    def _remaining(self, next_tensordict: TensorDictBase, reference: torch.Tensor) -> torch.Tensor:
        self._setup()
        if not self.__dict__["_needs_remaining"]:
            # no limit (Pyrado passes 0), or no task of the tree reads it: skip the arithmetic
            return self.task.no_remaining_steps
        max_steps = self.__dict__["_max_steps"]
        step_count = next_tensordict.get("step_count")
        return max_steps - step_count.reshape(reference.shape[:-1])

    def _evaluator(self) -> Callable[..., Any]:
        """The task's transition function (:meth:`Task._transition`), compiled with ``compile=True``."""
        if not self.compile:
            return self.task._transition
        compiled = self.__dict__.get("_compiled_transition")
        if compiled is None:
            compiled = torch.compile(self.task._transition, fullgraph=True, dynamic=False)
            self.__dict__["_compiled_transition"] = compiled
        return compiled

    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()
        state.pop("_compiled_transition", None)
        return state

    def _episode_end_flags(
        self, next_tensordict: TensorDictBase, batch: torch.Size, offline: bool
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None, bool]:
        """Return ``(done, terminated, truncated, has_terminated)``: the env's own end flags, the last two ``[*B]``.

        Online the env's flags are its own. Offline (stored transitions, possibly relabelled) the
        stored ``terminated`` already includes the task's old success and failure: only what the
        task did not cause (the env's own termination and the truncation) is kept, so the task
        judges the episode end anew.
        """
        done = td_get(next_tensordict, "done")
        terminated = td_get(next_tensordict, "terminated")
        truncated = td_get(next_tensordict, "truncated")
        has_terminated = terminated is not None
        if truncated is None and has_terminated:
            truncated = done & ~terminated
        if not has_terminated:
            terminated = done
        if offline:
            old_success = td_get(next_tensordict, self.success_key)
            old_failure = td_get(next_tensordict, self.failure_key)
            if old_success is not None and old_failure is not None:
                terminated = terminated & ~(old_success | old_failure)
        truncated = None if truncated is None else truncated.reshape(batch)
        return done, terminated.reshape(batch), truncated, has_terminated

    def _transition(
        self, tensordict: TensorDictBase, next_tensordict: TensorDictBase, *, offline: bool = False
    ) -> TensorDictBase:
        """Evaluate the task on one batch of transitions and write its outputs into ``next_tensordict``.

        The evaluation is :meth:`Task._transition`, the function behind :meth:`Task.transition`.
        Offline, the stored next memory is left as it was.
        """
        state = self._read_state(tensordict)
        next_state = self._read_state(next_tensordict)
        action = td_get(tensordict, self.action_key)
        if action.dtype != state.dtype:
            action = action.to(state.dtype)
        memory = td_get(tensordict, self.memory_key)
        done, env_terminated, truncated, has_terminated = self._episode_end_flags(
            next_tensordict, state.shape[:-1], offline
        )
        remaining = self._remaining(next_tensordict, state)
        reward, step_reward, final, success, failure, terminated, done_now, memory, terms = self._evaluator()(
            state, action, next_state, memory, remaining, env_terminated, truncated, self.reward_on, self.log_terms
        )
        reward_dtype = self.__dict__.get("_reward_dtype")
        if reward_dtype is None:
            stored = td_get(next_tensordict, self.reward_key)
            reward_dtype = state.dtype if stored is None else stored.dtype
        shape = done.shape
        td_set(next_tensordict, self.reward_key, _as_entry(reward, shape, reward_dtype))
        td_set(next_tensordict, self.success_key, success.reshape(shape))
        td_set(next_tensordict, self.failure_key, failure.reshape(shape))
        if has_terminated:
            td_set(next_tensordict, "terminated", terminated.reshape(shape))
        td_set(next_tensordict, "done", done_now.reshape(shape))
        if not offline:
            td_set(next_tensordict, self.memory_key, memory)
        if self.log_terms:
            values = [step_reward, final, *(terms[name] for name in self._term_names)]
            for key, value in zip(self._term_keys, values, strict=True):
                td_set(next_tensordict, key, _as_entry(value, shape, reward_dtype))
        return next_tensordict

    # ------------------------------------------------------------------- TorchRL hooks
    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        return self._transition(tensordict, next_tensordict)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        init_state = self._read_state(tensordict_reset)
        memory = self.task._reset(init_state, self._overrides(init_state))
        reset_mask = None if tensordict is None else tensordict.get("_reset", None)
        old = None if tensordict is None else tensordict.get(self.memory_key, None)
        if reset_mask is not None and old is not None and old.batch_size == memory.batch_size:
            memory = where_memory(reset_mask.reshape(memory.batch_size), memory, old)
        tensordict_reset.set(self.memory_key, memory)
        flags = torch.zeros(
            (*init_state.shape[:-1], 1) if self.parent is None else self.parent.full_done_spec["done"].shape,
            dtype=torch.bool,
            device=init_state.device,
        )
        tensordict_reset.set(self.success_key, flags)
        tensordict_reset.set(self.failure_key, flags.clone())
        return tensordict_reset

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Recompute rewards and flags of stored transitions (replay buffers, relabelling).

        ``tensordict`` holds transitions as collected: the state, action and task memory at the
        root and the next state (and ``done``, and ``step_count`` for time-dependent tasks) under
        ``"next"``. The reward, success, failure, done flags and the reward breakdown under
        ``"next"`` are rewritten; the stored next memory is left as it was. An episode end that the
        stored success/failure flags attribute to the task is re-judged (a relabelled goal may
        change it); truncation and the env's own termination are kept.
        """
        next_tensordict = tensordict.get("next")
        self._transition(tensordict, next_tensordict, offline=True)
        return tensordict

    def reward_fn(self, tensordict: TensorDictBase) -> torch.Tensor:
        """Return the task reward ``[*B, 1]`` of stored transitions (e.g. ``HERReplayBuffer(reward_fn=...)``).

        The data is not modified.
        """
        data = tensordict.select(*self.state_keys, self.action_key, self.memory_key, "next", strict=False)
        next_data = tensordict.get("next").copy()
        self._transition(data, next_data, offline=True)
        return next_data.get(self.reward_key)

    def __repr__(self) -> str:
        name = type(self.task).__name__
        return f"{type(self).__name__}(task={name}, state_keys={self.state_keys}, reward_on={self.reward_on!r})"
