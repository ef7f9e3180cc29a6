"""A TorchRL env that replays recorded golden episodes, and spawn-safe constructors for the transform tests.

:class:`ReplayEnv` emits the states of golden ``task_rollout`` episodes (``tests/data/pyrado_golden.json``):
a reset emits ``states[0]`` of the next episode (cycling through the episodes), the step after action
``t`` emits ``states[t + 1]``. The env pays reward 0 and never ends an episode by itself (``done`` and
``terminated`` are always False): the task decides. Its observation also carries the action recorded
for the current state (``"recorded_action"``), so that :func:`replay_policy` replays the episode, and
bookkeeping entries that let a test check any collector output frame by frame, whatever the order:

- ``"env_id"``: the constant id given at construction (which env of a batch or which worker),
- ``"episode"``: index of the current episode in the episode list (``first_episode`` after the first
  reset, then cycling),
- ``"t"``: index of the current state in its episode (0 after a reset),
- ``"frame"``: number of steps this env has taken so far (never reset).

Everything is float64 (states, actions, reward). Past the end of the recorded data the env keeps
emitting the last state (a task that does not end the episode where Pyrado did is caught by the test,
not by the env).

The module-level functions (:func:`make_replay_env`, :func:`make_task_env`, :func:`replay_policy`)
are what multi-process tests hand to ``ParallelEnv``/collectors through :func:`functools.partial`: they
pickle by reference and rebuild everything (golden data, task) in the worker.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Categorical, Composite, Unbounded
from torchrl.envs import Compose, EnvBase, StepCounter, TransformedEnv

from golden import scenario
from golden_tasks import OracleRunner, build_scenario_task, is_deviation, replay, reset_overrides
from torchtasks.transforms import TaskTransform

__all__ = [
    "BOOKKEEPING_KEYS",
    "CopyRecordedAction",
    "ReplayEnv",
    "constant_overrides",
    "expected_columns",
    "make_replay_env",
    "make_task_env",
    "replay_policy",
    "scenario_overrides",
    "task_transform",
]

#: Integer observation entries that :class:`ReplayEnv` adds for bookkeeping.
BOOKKEEPING_KEYS = ("env_id", "episode", "t", "frame")


class ReplayEnv(EnvBase):
    """Emit the recorded states of a list of episodes, one after the other (batch size ``[]``).

    Args:
        episodes: ``(states, acts)`` pairs: ``N + 1`` states and ``N`` actions per episode.
        env_id: constant written to ``"env_id"``.
        first_episode: index of the episode the first reset starts (the following resets go on
            cyclically).
        dtype: dtype of states, actions and reward.
    """

    batch_locked = True

    def __init__(
        self,
        episodes: Sequence[tuple[Sequence[Sequence[float]], Sequence[Sequence[float]]]],
        *,
        env_id: int = 0,
        first_episode: int = 0,
        dtype: torch.dtype = torch.float64,
    ) -> None:
        super().__init__(batch_size=torch.Size([]))
        if not episodes:
            raise ValueError("ReplayEnv needs at least one episode")
        self._states = [torch.as_tensor(states, dtype=dtype) for states, _ in episodes]
        self._acts = [torch.as_tensor(acts, dtype=dtype) for _, acts in episodes]
        n_state = self._states[0].shape[-1]
        n_action = self._acts[0].shape[-1]
        for states, acts in zip(self._states, self._acts, strict=True):
            if states.shape[-1] != n_state or acts.shape[-1] != n_action or states.shape[0] != acts.shape[0] + 1:
                raise ValueError("every episode needs N + 1 states and N actions of the same sizes")
        self.env_id = int(env_id)
        self.first_episode = int(first_episode)
        self.dtype_ = dtype
        self._episode = -1  # number of resets so far minus one
        self._t = 0
        self._frame = 0
        index = Unbounded(shape=(1,), dtype=torch.int64)
        self.observation_spec = Composite(
            observation=Unbounded(shape=(n_state,), dtype=dtype),
            recorded_action=Unbounded(shape=(n_action,), dtype=dtype),
            **{key: index.clone() for key in BOOKKEEPING_KEYS},
        )
        # recorded actions may exceed the real env's bounds: tasks see them unclipped
        self.action_spec = Unbounded(shape=(n_action,), dtype=dtype)
        self.reward_spec = Unbounded(shape=(1,), dtype=dtype)
        self.done_spec = Composite(
            done=Categorical(2, shape=(1,), dtype=torch.bool),
            terminated=Categorical(2, shape=(1,), dtype=torch.bool),
        )

    @property
    def num_episodes(self) -> int:
        return len(self._states)

    def golden_episode(self, episode: int) -> int:
        """Index in the episode list of this env's ``episode``-th episode."""
        return (self.first_episode + episode) % self.num_episodes

    def _observation(self) -> dict[str, torch.Tensor]:
        index = self.golden_episode(self._episode)
        states, acts = self._states[index], self._acts[index]
        t_state = min(self._t, states.shape[0] - 1)
        t_action = min(self._t, acts.shape[0] - 1)
        return {
            "observation": states[t_state].clone(),
            "recorded_action": acts[t_action].clone(),
            "env_id": torch.tensor([self.env_id]),
            "episode": torch.tensor([index]),
            "t": torch.tensor([self._t]),
            "frame": torch.tensor([self._frame]),
        }

    def _reset(self, tensordict: TensorDictBase | None, **kwargs: Any) -> TensorDictBase:
        self._episode += 1
        self._t = 0
        flags = torch.zeros(1, dtype=torch.bool)
        return TensorDict({**self._observation(), "done": flags, "terminated": flags.clone()}, batch_size=[])

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self._episode < 0:
            raise RuntimeError("ReplayEnv stepped before its first reset")
        self._t += 1
        self._frame += 1
        flags = torch.zeros(1, dtype=torch.bool)
        return TensorDict(
            {
                **self._observation(),
                "reward": torch.zeros(1, dtype=self.dtype_),
                "done": flags,
                "terminated": flags.clone(),
            },
            batch_size=[],
        )

    def _set_seed(self, seed: int | None) -> None:
        return None


class CopyRecordedAction(nn.Module):
    """``action = recorded_action`` (a copy): the policy that replays a golden episode."""

    def forward(self, recorded_action: torch.Tensor) -> torch.Tensor:
        return recorded_action.clone()


def replay_policy() -> TensorDictModule:
    """The deterministic policy of replay envs: copy ``"recorded_action"`` to ``"action"``."""
    return TensorDictModule(CopyRecordedAction(), in_keys=["recorded_action"], out_keys=["action"])


# --------------------------------------------------------------------------------------------------
# Golden scenarios
# --------------------------------------------------------------------------------------------------


def constant_overrides(overrides: Mapping[str, Any], init_state: torch.Tensor) -> dict[str, Any]:
    """``reset_overrides`` of a TaskTransform that returns the same overrides at every reset."""
    return dict(overrides)


def scenario_overrides(case: Mapping[str, Any]) -> dict[str, Any]:
    """The reset overrides of a scenario (the same for all its episodes; else NotImplementedError)."""
    found = [reset_overrides(episode) for episode in case["episodes"]]
    if any(item != found[0] for item in found):
        raise NotImplementedError(f"{case['name']}: episodes with different reset overrides")
    return found[0]


def task_transform(case: Mapping[str, Any], *, reward_on: str = "state", **kwargs: Any) -> TaskTransform:
    """``TaskTransform`` of a golden scenario's task (fixed spec), with the scenario's reset overrides."""
    overrides = scenario_overrides(case)
    if overrides:
        kwargs.setdefault("reset_overrides", functools.partial(constant_overrides, overrides))
    return TaskTransform(build_scenario_task(case), reward_on=reward_on, **kwargs)


def max_steps_of(case: Mapping[str, Any]) -> int | None:
    """The scenario's ``max_steps`` as a StepCounter limit (``None`` for ``"inf"``)."""
    return None if case["max_steps"] == math.inf else int(case["max_steps"])


def episodes_of(case: Mapping[str, Any]) -> list[tuple[list[Any], list[Any]]]:
    return [(episode["states"], episode["acts"]) for episode in case["episodes"]]


def make_replay_env(name: str, env_id: int = 0, first_episode: int = 0) -> ReplayEnv:
    """A bare :class:`ReplayEnv` of the golden scenario ``name`` (spawn-safe constructor)."""
    return ReplayEnv(episodes_of(scenario(name)), env_id=env_id, first_episode=first_episode)


def make_task_env(name: str, env_id: int = 0, first_episode: int = 0, **transform_kwargs: Any) -> TransformedEnv:
    """``ReplayEnv`` + ``StepCounter(max_steps)`` + the scenario's ``TaskTransform`` (spawn-safe constructor).

    ``transform_kwargs`` go to the ``TaskTransform`` (``reward_on`` defaults to ``"state"``).
    """
    case = scenario(name)
    return TransformedEnv(
        ReplayEnv(episodes_of(case), env_id=env_id, first_episode=first_episode),
        task_transforms(name, **transform_kwargs),
    )


def task_transforms(name: str, **transform_kwargs: Any) -> Compose:
    """``Compose(StepCounter(max_steps), TaskTransform(task))`` of the golden scenario ``name``."""
    case = scenario(name)
    max_steps = max_steps_of(case)
    if max_steps is None:  # Pyrado's max_steps=inf: no limit on purpose (remaining steps 0, no warning)
        transform_kwargs.setdefault("max_steps", math.inf)
    transforms = [] if max_steps is None else [StepCounter(max_steps)]
    return Compose(*transforms, task_transform(case, **transform_kwargs))


@functools.cache
def expected_columns(name: str) -> tuple[dict[str, list[Any]], ...]:
    """Per episode: the golden columns, or, for an expected deviation, the fixed-behaviour oracle's."""
    case = scenario(name)
    if is_deviation(case):
        return tuple(replay(OracleRunner(case), case, episode).columns for episode in case["episodes"])
    return tuple(episode["expected"] for episode in case["episodes"])


# --------------------------------------------------------------------------------------------------
# Checking collected frames against the golden columns
# --------------------------------------------------------------------------------------------------

RTOL, ATOL = 1e-6, 1e-9


def _column(data: TensorDictBase, key: Any, n: int) -> list[Any]:
    value = data.get(key)
    return value.reshape(n, -1).tolist() if value.ndim > 1 else value.reshape(n, 1).tolist()


def _close(got: float, want: float) -> bool:
    return math.isclose(got, want, rel_tol=RTOL, abs_tol=ATOL) or (math.isnan(got) and math.isnan(want))


def frame_problems(data: TensorDictBase, name: str, *, limit: int = 12) -> list[str]:
    """Compare every transition of ``data`` (any batch shape, any order) with scenario ``name``.

    Each frame names its episode and step (``"episode"``, ``"t"``); the expected values are the
    golden columns of that episode and step (the fixed-behaviour oracle's for expected deviations):
    reward, done, terminated (= is_done), success, failure, truncated (= time_limit), the reward
    breakdown (step and final reward), the states and the action of the transition.
    """
    case = scenario(name)
    columns = expected_columns(name)
    episodes = case["episodes"]
    flat = data.reshape(-1)
    n = flat.numel()
    if n == 0:
        return ["no frames"]
    keys = {
        "episode": "episode",
        "t": "t",
        "env_id": "env_id",
        "obs": "observation",
        "action": "action",
        "next_obs": ("next", "observation"),
        "next_t": ("next", "t"),
        "reward": ("next", "reward"),
        "done": ("next", "done"),
        "terminated": ("next", "terminated"),
    }
    nested = flat.keys(True, True)
    for flag in ("success", "failure"):  # written for the outcomes the task has: an absent flag is never set
        if ("next", flag) in nested:
            keys[flag] = ("next", flag)
    if ("next", "task_reward", "step") in nested:
        keys["step"] = ("next", "task_reward", "step")
        keys["final"] = ("next", "task_reward", "final")
    if ("next", "truncated") in nested:
        keys["truncated"] = ("next", "truncated")
    if ("next", "step_count") in nested:
        keys["step_count"] = ("next", "step_count")
    values = {name_: _column(flat, key, n) for name_, key in keys.items()}
    problems: list[str] = []
    for i in range(n):
        row = {name_: column[i] for name_, column in values.items()}
        e, t = row["episode"][0], row["t"][0]
        where = f"frame {i} (env {row['env_id'][0]}, episode {e}, t {t})"
        expected = columns[e]
        if t >= len(expected["reward"]):
            problems.append(f"{where}: the episode should have ended after {len(expected['reward'])} steps")
            continue
        episode = episodes[e]
        final = expected["final_rew"][t]
        checks = [("reward", row["reward"][0], expected["reward"][t])]
        if "step" in row:
            checks.append(("step reward", row["step"][0], expected["step_rew"][t]))
            checks.append(("final reward", row["final"][0], 0.0 if final is None else final))
        for what, got, want in checks:
            if not _close(got, want):
                problems.append(f"{where}: {what} {got!r}, expected {want!r}")
        flags = [
            ("done", row["done"][0], expected["done"][t]),
            ("terminated", row["terminated"][0], expected["is_done"][t]),
            ("success", row["success"][0] if "success" in row else False, expected["has_succeeded"][t]),
            ("failure", row["failure"][0] if "failure" in row else False, expected["has_failed"][t]),
            ("next t", row["next_t"][0], t + 1),
        ]
        if "truncated" in row:
            flags.append(("truncated", row["truncated"][0], expected["time_limit"][t]))
        if "step_count" in row:
            flags.append(("step_count", row["step_count"][0], t + 1))
        for what, got, want in flags:
            if got != want:
                problems.append(f"{where}: {what} {got!r}, expected {want!r}")
        transition = [
            ("state", row["obs"], episode["states"][t]),
            ("next state", row["next_obs"], episode["states"][t + 1]),
            ("action", row["action"], episode["acts"][t]),
        ]
        for what, got, want in transition:
            if not all(_close(a, b) for a, b in zip(got, want, strict=True)):
                problems.append(f"{where}: {what} {got!r}, expected {want!r}")
        if len(problems) >= limit:
            problems.append("... (stopped)")
            break
    return problems


def frames_by_env(data: TensorDictBase) -> dict[int, TensorDictBase]:
    """Split frames by ``"env_id"`` and sort each env's frames by ``"frame"`` (collector outputs in any order)."""
    flat = data.reshape(-1)
    env_ids = flat.get("env_id").reshape(-1)
    result = {}
    for env_id in sorted(set(env_ids.tolist())):
        frames = flat[env_ids == env_id]
        order = torch.argsort(frames.get("frame").reshape(-1))
        result[env_id] = frames[order]
    return result


def missing_frames(data: TensorDictBase) -> list[str]:
    """Problems if an env's frames are not exactly ``0, 1, ..., n - 1`` (a frame dropped or repeated)."""
    problems = []
    for env_id, frames in frames_by_env(data).items():
        got = frames.get("frame").reshape(-1).tolist()
        if got != list(range(len(got))):
            problems.append(f"env {env_id}: frames {got} are not 0..{len(got) - 1}")
        following = frames.get(("next", "frame")).reshape(-1).tolist()
        if following != [f + 1 for f in got]:
            problems.append(f"env {env_id}: next frames {following} do not follow {got}")
    return problems


def recomputation_problems(data: TensorDictBase, name: str) -> list[str]:
    """Recompute every stored transition offline with ``TaskTransform.forward`` and compare.

    The transform reads the state, action and task memory at the root and the next state (and
    ``step_count``, ``done``) under ``"next"``; the recomputed reward, flags and breakdown must equal
    the stored ones exactly (same code, same inputs: nothing was dropped or misaligned on the way).
    """
    case = scenario(name)
    transform = task_transform(case, max_steps=max_steps_of(case))
    stored = data.reshape(-1)
    recomputed = transform.forward(stored.clone())
    problems = []
    keys = [("next", "reward"), ("next", "success"), ("next", "failure"), ("next", "done"), ("next", "terminated")]
    keys += [("next", *((key,) if isinstance(key, str) else key)) for key in transform.term_keys]
    for key in keys:
        got, want = recomputed.get(key, None), stored.get(key, None)
        if got is None and want is None:  # a flag of an outcome the task does not have: written neither time
            continue
        if got is None or want is None or not torch.equal(got, want):
            if got is None or want is None:
                problems.append(f"{key}: written {'offline only' if want is None else 'online only'}")
                continue
            bad = (got != want).reshape(got.shape[0], -1).any(-1).nonzero().reshape(-1).tolist()
            problems.append(f"{key}: recomputed values differ from the stored ones at frames {bad[:10]}")
    return problems
