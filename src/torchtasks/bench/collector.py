"""Collector-overhead benchmark: frames/s with TaskTransform against an identity and a minimal transform."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.collectors import Collector
from torchrl.data import Categorical, Composite, Unbounded
from torchrl.envs import Compose, EnvBase, StepCounter, Transform, TransformedEnv

from torchtasks.bench.cases import BenchConfig
from torchtasks.envs import PendulumEnv
from torchtasks.rewards import QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import DesiredStateTask, FinalRewardTask, Task, proximity_succeeded
from torchtasks.transforms import TaskTransform
from torchtasks.transforms.names import (
    FAILURE_KEY,
    FINAL_TERM,
    MEMORY_KEY,
    STEP_TERM,
    SUCCESS_KEY,
    TERMS_KEY,
)

__all__ = [
    "FewestT1Transform",
    "IdentityTransform",
    "MinimalT1Transform",
    "UniformActions",
    "run_collector_benchmark",
    "t1_for",
    "uniform_policy",
]

# The collector benchmark measures what the transform costs, not what shorter episodes cost: with
# these bounds and this threshold the task's episodes end only by truncation (StepCounter), as with
# the identity transform, so both variants reset equally often (the task still evaluates success,
# failure and the final reward in every step).
BOUND = 1e4
THRESHOLD = 1e-6


def t1_for(state_size: int, action_size: int, bound: float = BOUND, threshold: float = THRESHOLD) -> Task:
    """T1 sized for an env: FinalRewardTask(DesiredStateTask(QuadraticErrorReward)) with a ±bound state box."""
    import functools

    spec = EnvSpec(Box([-bound] * state_size, [bound] * state_size), action_size)
    reward = QuadraticErrorReward(torch.ones(state_size), torch.full((action_size,), 0.1))
    success = functools.partial(proximity_succeeded, threshold=threshold)
    return FinalRewardTask(
        DesiredStateTask(spec, torch.zeros(state_size), reward, success), factor=BenchConfig().factor
    )


class IdentityTransform(Transform):
    """A transform that changes nothing (the baseline of TorchRL's own per-transform cost)."""

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return tensordict_reset


class MinimalT1Transform(Transform):
    """The floor: T1's maths written by hand in one transform, with the same keys and specs as TaskTransform.

    Writes ``reward``, ``success``, ``failure``, ``terminated``/``done``, the memory
    ``("task", "paid")`` and ``("task", "wrapped", "state_des")`` and the breakdown
    ``("task_reward", "step"|"final")``, and nothing else.
    """

    def __init__(self, state_size: int, bound: float = BOUND, threshold: float = THRESHOLD) -> None:
        super().__init__(in_keys=["observation"], out_keys=["reward"])
        self.state_size = state_size
        self.bound = bound
        self.threshold = threshold
        self.factor = BenchConfig().factor

    def _constants(self, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        cached = self.__dict__.get("_cached")
        if cached is None or cached[0].dtype != like.dtype:
            cached = (
                torch.tensor(self.factor, dtype=like.dtype),
                torch.tensor(0.0, dtype=like.dtype),
                torch.tensor(0.1, dtype=like.dtype),
            )
            self.__dict__["_cached"] = cached
        return cached

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        state = next_tensordict.get("observation")
        action = tensordict.get("action").to(state.dtype)
        paid = tensordict.get((MEMORY_KEY, "paid"))
        goal = tensordict.get((MEMORY_KEY, "wrapped", "state_des"))
        factor, zero, r = self._constants(state)
        error = goal - state
        step = -((error * error).sum(-1) + r * (action * action).sum(-1))
        success = torch.linalg.vector_norm(error, dim=-1) < self.threshold
        failure = (state.abs() > self.bound).any(-1) | torch.isnan(state).any(-1)
        done = next_tensordict.get("done")
        ended = (success | failure).unsqueeze(-1)
        finished = done.squeeze(-1) | success | failure
        final = torch.where(finished & ~paid, torch.where(failure, -factor, torch.where(success, factor, zero)), zero)
        reward_spec_dtype = torch.float32
        next_tensordict.set("reward", (step + final).unsqueeze(-1).to(reward_spec_dtype))
        next_tensordict.set(SUCCESS_KEY, success.unsqueeze(-1))
        next_tensordict.set(FAILURE_KEY, failure.unsqueeze(-1))
        next_tensordict.set("terminated", next_tensordict.get("terminated") | ended)
        next_tensordict.set("done", done | ended)
        next_tensordict.set((MEMORY_KEY, "paid"), paid | finished)
        next_tensordict.set((MEMORY_KEY, "wrapped", "state_des"), goal)
        next_tensordict.set((TERMS_KEY, STEP_TERM), step.unsqueeze(-1).to(reward_spec_dtype))
        next_tensordict.set((TERMS_KEY, FINAL_TERM), final.unsqueeze(-1).to(reward_spec_dtype))
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        state = tensordict_reset.get("observation")
        batch = state.shape[:-1]
        memory = TensorDict(
            {"paid": torch.zeros(batch, dtype=torch.bool), "wrapped": {"state_des": torch.zeros_like(state)}},
            batch_size=batch,
        )
        reset = None if tensordict is None else tensordict.get("_reset", None)
        old = None if tensordict is None else tensordict.get(MEMORY_KEY, None)
        if reset is not None and old is not None:
            memory = old.where(~reset.reshape(batch), memory)
        tensordict_reset.set(MEMORY_KEY, memory)
        flags = torch.zeros((*batch, 1), dtype=torch.bool)
        tensordict_reset.set(SUCCESS_KEY, flags)
        tensordict_reset.set(FAILURE_KEY, flags.clone())
        return tensordict_reset

    def _memory_spec(self, batch: torch.Size, dtype: torch.dtype) -> Composite:
        return Composite(
            paid=Categorical(2, shape=batch, dtype=torch.bool),
            wrapped=Composite(state_des=Unbounded(shape=(*batch, self.state_size), dtype=dtype), shape=batch),
            shape=batch,
        )

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        batch = observation_spec.shape
        dtype = observation_spec["observation"].dtype
        observation_spec[SUCCESS_KEY] = Categorical(2, shape=(*batch, 1), dtype=torch.bool)
        observation_spec[FAILURE_KEY] = Categorical(2, shape=(*batch, 1), dtype=torch.bool)
        observation_spec[MEMORY_KEY] = self._memory_spec(batch, dtype)
        return observation_spec

    def transform_state_spec(self, state_spec: Composite) -> Composite:
        observation_spec = self.parent.full_observation_spec
        state_spec[MEMORY_KEY] = self._memory_spec(observation_spec.shape, observation_spec["observation"].dtype)
        return state_spec

    def transform_reward_spec(self, reward_spec: Composite) -> Composite:
        base = reward_spec["reward"]
        for name in (STEP_TERM, FINAL_TERM):
            reward_spec[(TERMS_KEY, name)] = Unbounded(shape=base.shape, dtype=base.dtype)
        return reward_spec


class FewestT1Transform(Transform):
    """The floor with the fewest entries: T1's reward, flags and final-reward latch, nothing else.

    Writes ``reward``, ``success``, ``failure``, ``terminated``, ``done`` and the latch ``("task",
    "paid")`` (the one per-env state T1 needs when its goal is a constant); no goal in memory, no
    reward breakdown. ``TaskTransform(t1, log_terms=False)`` is compared with it.
    """

    def __init__(self, state_size: int, bound: float = BOUND, threshold: float = THRESHOLD) -> None:
        super().__init__(in_keys=["observation"], out_keys=["reward"])
        self.state_size = state_size
        self.bound = bound
        self.threshold = threshold
        self.factor = BenchConfig().factor

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        state = next_tensordict.get("observation")
        action = tensordict.get("action").to(state.dtype)
        paid = tensordict.get((MEMORY_KEY, "paid"))
        step = -((state * state).sum(-1) + 0.1 * (action * action).sum(-1))  # the goal is the origin
        success = torch.linalg.vector_norm(state, dim=-1) < self.threshold
        failure = (state.abs() > self.bound).any(-1) | torch.isnan(state).any(-1)
        done = next_tensordict.get("done")
        finished = done.squeeze(-1) | success | failure
        constants = self.__dict__.get("_constants")
        if constants is None or constants[0].dtype != state.dtype:  # 0-d constants, built once
            constants = self.__dict__["_constants"] = tuple(
                torch.tensor(v, dtype=state.dtype) for v in (self.factor, -self.factor, 0.0)
            )
        on_success, on_failure, zero = constants
        final = torch.where(
            finished & ~paid, torch.where(failure, on_failure, torch.where(success, on_success, zero)), zero
        )
        next_tensordict.set("reward", (step + final).unsqueeze(-1).to(torch.float32))
        next_tensordict.set(SUCCESS_KEY, success.unsqueeze(-1))
        next_tensordict.set(FAILURE_KEY, failure.unsqueeze(-1))
        ended = (success | failure).unsqueeze(-1)
        next_tensordict.set("terminated", next_tensordict.get("terminated") | ended)
        next_tensordict.set("done", done | ended)
        next_tensordict.set((MEMORY_KEY, "paid"), paid | finished)
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        batch = tensordict_reset.batch_size
        paid = torch.zeros(batch, dtype=torch.bool)
        reset = None if tensordict is None else tensordict.get("_reset", None)
        old = None if tensordict is None else tensordict.get((MEMORY_KEY, "paid"), None)
        if reset is not None and old is not None:
            paid = torch.where(reset.reshape(batch), paid, old)
        tensordict_reset.set((MEMORY_KEY, "paid"), paid)
        flags = torch.zeros((*batch, 1), dtype=torch.bool)
        tensordict_reset.set(SUCCESS_KEY, flags)
        tensordict_reset.set(FAILURE_KEY, flags.clone())
        return tensordict_reset

    def _memory_spec(self, batch: torch.Size) -> Composite:
        return Composite(paid=Categorical(2, shape=batch, dtype=torch.bool), shape=batch)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        batch = observation_spec.shape
        observation_spec[SUCCESS_KEY] = Categorical(2, shape=(*batch, 1), dtype=torch.bool)
        observation_spec[FAILURE_KEY] = Categorical(2, shape=(*batch, 1), dtype=torch.bool)
        observation_spec[MEMORY_KEY] = self._memory_spec(batch)
        return observation_spec

    def transform_state_spec(self, state_spec: Composite) -> Composite:
        state_spec[MEMORY_KEY] = self._memory_spec(self.parent.full_observation_spec.shape)
        return state_spec


class UniformActions(TensorDictModuleBase):
    """The benchmarks' policy: writes ``"action"``, drawn uniformly within the env's action bounds (one ``torch.rand``).

    Every Collector of the benchmarks uses it (here, ``benchmarks/batched_mujoco.py`` and
    ``benchmarks/pipeline_costs.py``), so the columns differ only in the env. It writes its output
    itself: a ``TensorDictModule`` passes every output through ``TensorDict.from_any``, which for a
    plain tensor searches the import path for pandas on every call (tensordict 0.14.3, ~0.1 ms per
    step on a 2-core machine without pandas), and ``policy=None`` (TorchRL's ``RandomPolicy``) builds
    its TensorDict through the same search. Both are costs of the policy's wrapper, not of the env.

    Args:
        env: the env whose ``action_spec`` (a bounded spec) the actions are drawn from.

    Example:
        >>> from torchtasks.envs import PendulumEnv
        >>> env = PendulumEnv(batch_size=[4])
        >>> policy = uniform_policy(env)
        >>> bool(env.action_spec.is_in(policy(env.reset())["action"]))
        True
    """

    def __init__(self, env: EnvBase) -> None:
        super().__init__()
        self.in_keys: list[str] = []
        self.out_keys: list[str] = ["action"]
        space = env.action_spec.space
        self.register_buffer("low", torch.as_tensor(space.low).expand(env.action_spec.shape).clone())
        self.register_buffer("width", torch.as_tensor(space.high).expand(env.action_spec.shape) - self.low)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = torch.rand(self.low.shape, dtype=self.low.dtype, device=self.low.device) * self.width + self.low
        return tensordict.set("action", action)


def uniform_policy(env: EnvBase) -> UniformActions:
    """The benchmarks' policy for ``env``: :class:`UniformActions` (writes ``"action"``, reads nothing)."""
    return UniformActions(env)


def _frames_per_second(env: EnvBase, frames_per_batch: int, batches: int) -> float:
    collector = Collector(
        env,
        uniform_policy(env),
        frames_per_batch=frames_per_batch,
        total_frames=frames_per_batch * (batches + 1),
        auto_register_policy_transforms=False,
    )
    iterator = iter(collector)
    next(iterator)  # warm-up batch
    start = time.perf_counter()
    frames = 0
    for batch in iterator:
        frames += batch.numel()
    seconds = time.perf_counter() - start
    collector.shutdown()
    return frames / seconds


def _compare(
    variants: dict[str, Callable[[], EnvBase]], frames_per_batch: int, batches: int, repeats: int
) -> dict[str, float]:
    """Median frames/s per variant; variants are interleaved in every repeat so drifts hit all alike."""
    envs = {name: make() for name, make in variants.items()}
    samples: dict[str, list[float]] = {name: [] for name in variants}
    for _ in range(repeats):
        for name, env in envs.items():
            samples[name].append(_frames_per_second(env, frames_per_batch, batches))
    for env in envs.values():
        env.close()
    return {name: statistics.median(values) for name, values in samples.items()}


def _halfcheetah_single() -> EnvBase:
    from torchrl.envs import GymEnv

    return GymEnv("HalfCheetah-v5")


def _halfcheetah_vector(num_envs: int) -> EnvBase:
    import gymnasium as gym
    from torchrl.envs import GymWrapper

    return GymWrapper(
        gym.make_vec(
            "HalfCheetah-v5",
            num_envs=num_envs,
            vectorization_mode="sync",
            vector_kwargs={"autoreset_mode": gym.vector.AutoresetMode.DISABLED},
        )
    )


def _with(
    base: Callable[[], EnvBase], transform: Callable[[], Transform], max_steps: int = 1000
) -> Callable[[], EnvBase]:
    return lambda: TransformedEnv(base(), Compose(StepCounter(max_steps), transform()))


def run_collector_benchmark(*, tiny: bool = False, repeats: int = 5) -> list[dict[str, Any]]:
    """Frames/s ratios of TaskTransform(T1) against the identity and the hand-written minimal transform."""
    rows = []
    cheetah_size, cheetah_actions = 17, 6
    setups: list[tuple[str, Callable[[], EnvBase], int, int]] = []
    num_vector = 2 if tiny else 16
    batched = 8 if tiny else 1024
    setups.append(
        (
            f"HalfCheetah-v5 vectorised x{num_vector}",
            lambda: _halfcheetah_vector(num_vector),
            cheetah_size,
            cheetah_actions,
        )
    )
    setups.append(("HalfCheetah-v5 single GymEnv", _halfcheetah_single, cheetah_size, cheetah_actions))
    setups.append((f"PendulumEnv batch {batched}", lambda: PendulumEnv(batch_size=[batched], seed=0), 2, 1))
    for name, base, state_size, action_size in setups:
        variants = {
            "identity": _with(base, IdentityTransform),
            "task": _with(base, lambda s=state_size, a=action_size: TaskTransform(t1_for(s, a), log_terms=True)),
        }
        variants["minimal"] = _with(base, lambda s=state_size: MinimalT1Transform(s))
        variants["task_no_terms"] = _with(
            base, lambda s=state_size, a=action_size: TaskTransform(t1_for(s, a), log_terms=False)
        )
        variants["fewest"] = _with(base, lambda s=state_size: FewestT1Transform(s))
        probe = base()
        env_batch = max(1, probe.batch_size.numel())
        probe.close()
        frames_per_batch = env_batch * (8 if tiny else (200 if env_batch < 64 else 20))
        batches = 1 if tiny else 5
        fps = _compare(variants, frames_per_batch, batches, 1 if tiny else repeats)
        rows.append(
            {
                "setup": name,
                "fps": fps,
                "task_over_identity": fps["task"] / fps["identity"],
                "minimal_over_identity": fps["minimal"] / fps["identity"],
                "task_over_minimal": fps["task"] / fps["minimal"],
                "no_terms_over_fewest": fps["task_no_terms"] / fps["fewest"],
            }
        )
    return rows
