"""Parity check of a locomotion preset against plain Gymnasium (``torchtasks check ENV_ID``).

:func:`check_parity` drives :func:`~torchtasks.envs.locomotion.gymnasium_env` and
``gymnasium.make(env_id)`` with the same keyword arguments, the same seed and the same random
actions, resets both whenever an episode ends (terminated, or truncated at 1000 steps), and compares,
step by step, the task reward with Gymnasium's reward, each logged term ``("task_reward", name)``
with Gymnasium's ``info["reward_<name>"]``, the termination flags and the observations.
:func:`format_parity_table` renders the results as a Markdown table.

:func:`check_batched_parity` (``torchtasks check ENV_ID --backend batched``) does the same for the
batched backend (:class:`~torchtasks.envs.batched_mujoco.BatchedMujocoEnv`): it drives
``gymnasium_env(env_id, num_envs=N, backend="batched")`` and ``N`` plain ``gymnasium.make(env_id)``
envs in lockstep with :func:`compare_batched_with_gymnasium`. After every reset of a batched env
(the first one, TorchRL's reset at the end of an episode, or a partial reset forced in the middle of
an episode while the other envs continue) the batched env's ``qpos``/``qvel`` are copied into the
matching Gymnasium env (:func:`sync_gymnasium_env`), then both get the same actions; the largest
absolute differences of the observations, the reward, every reward term and the ``terminated``,
``truncated`` and ``done`` flags are reported (:func:`format_batched_parity_table`), and the check
passes when all of them are at most :data:`BATCHED_PARITY_TOLERANCE`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import torch

from torchtasks._optional import missing_extra

try:
    import gymnasium
except ImportError as _error:
    raise missing_extra("mujoco", "torchtasks.parity (torchtasks check)", _error) from _error

from torchrl.envs import Compose, TransformedEnv

from torchtasks.envs.batched_mujoco import BatchedMujocoEnv
from torchtasks.envs.gymnasium_v5 import gymnasium_config, make_v5_env
from torchtasks.envs.locomotion import gymnasium_env
from torchtasks.transforms import TaskTransform
from torchtasks.transforms.names import FAILURE_KEY, TERMS_KEY

__all__ = [
    "BATCHED_PARITY_TOLERANCE",
    "TERM_NAMES",
    "batched_parity_passed",
    "check_batched_parity",
    "check_parity",
    "compare_batched_with_gymnasium",
    "format_batched_parity_table",
    "format_parity_table",
    "sync_gymnasium_env",
]

#: the reward terms a locomotion preset may have, in table order (Gymnasium's ``info["reward_<name>"]``)
TERM_NAMES: tuple[str, ...] = ("forward", "ctrl", "contact", "survive")

#: largest absolute difference to Gymnasium (observation, reward, terms, flags) that the batched check accepts
BATCHED_PARITY_TOLERANCE = 1e-9

#: the quantities :func:`compare_batched_with_gymnasium` compares besides the reward terms, in table order
_BATCHED_QUANTITIES: tuple[str, ...] = ("observation", "reward", "terminated", "truncated", "done")


def _check_seeds(seeds: object) -> list[int]:
    if isinstance(seeds, (int, str, bytes)) or not isinstance(seeds, Iterable):
        raise TypeError(f"seeds must be a sequence of ints, got {seeds!r}")
    seeds = list(seeds)
    if not seeds:
        raise ValueError("seeds must contain at least one seed, got an empty sequence")
    for seed in seeds:
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seeds must be non-negative ints, got {seed!r}")
    return [int(seed) for seed in seeds]


def check_parity(env_id: str, seeds: Sequence[int] = (0, 1, 2), steps: int = 1000, **gym_kwargs: Any) -> dict[str, Any]:
    """Compare a preset with plain Gymnasium for ``steps`` random steps per seed.

    For each seed both envs are seeded the same way (``gymnasium_env(..., seed=seed)`` calls the
    Gymnasium env's ``reset(seed=seed)``; the reference does the same), then reset once more and
    driven with the same actions, drawn uniformly from the action box by
    ``numpy.random.default_rng(seed)`` in float32 (the action dtype TorchRL passes on). Episodes end
    and restart as they do in Gymnasium (terminated, or truncated by the 1000-step time limit); a
    termination mismatch also desynchronises the envs, which then shows as observation mismatches.

    Args:
        env_id: a Gymnasium id of :data:`~torchtasks.envs.locomotion.SUPPORTED_ENV_IDS`.
        seeds: the seeds, one run of ``steps`` steps each.
        steps: steps compared per seed (``>= 1``).
        **gym_kwargs: Gymnasium keyword arguments used by both envs (e.g. ``ctrl_cost_weight=0.5``).

    Returns:
        ``{"env", "kwargs", "seeds", "steps" (compared, all seeds), "episodes" (ended),
        "max_abs_reward_diff", "max_abs_term_diff" ({term: value} for the env's terms),
        "termination_mismatches" (steps where the task's ``failure`` or TorchRL's ``terminated``
        differ from Gymnasium's ``terminated``, or ``truncated`` differs), "observation_mismatches"
        (steps whose observations are not bit-identical), "seconds"}``.

    Example:
        >>> from torchtasks.parity import check_parity
        >>> row = check_parity("Hopper-v5", seeds=[0], steps=50)
        >>> row["steps"], row["max_abs_reward_diff"] < 1e-5, row["termination_mismatches"]
        (50, True, 0)
    """
    gymnasium_config(env_id, gym_kwargs)
    seeds = _check_seeds(seeds)
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise ValueError(f"steps must be a positive int, got {steps!r}")
    started = time.perf_counter()
    reward_diff = 0.0
    term_diff: dict[str, float] = {}
    compared = episodes = termination_mismatches = observation_mismatches = 0
    for seed in seeds:
        env = gymnasium_env(env_id, seed=seed, **gym_kwargs)
        reference = make_v5_env(env_id, env_checker=True, **gym_kwargs)
        try:
            names = env.transform[1].task.term_names
            for name in names:
                term_diff.setdefault(name, 0.0)
            reference.reset(seed=seed)
            expected_observation, _ = reference.reset()
            tensordict = env.reset()
            observation_mismatches += int(not np.array_equal(tensordict["observation"].numpy(), expected_observation))
            rng = np.random.default_rng(seed)
            low, high = reference.action_space.low, reference.action_space.high
            for _ in range(steps):
                action = rng.uniform(low, high).astype(reference.action_space.dtype)
                tensordict["action"] = torch.from_numpy(action)
                tensordict, next_root = env.step_and_maybe_reset(tensordict)
                expected_observation, reward, terminated, truncated, info = reference.step(action)
                result = tensordict["next"]
                compared += 1
                reward_diff = max(reward_diff, abs(float(result["reward"]) - float(reward)))
                for name in names:
                    difference = abs(float(result[TERMS_KEY, name]) - float(info[f"reward_{name}"]))
                    term_diff[name] = max(term_diff[name], difference)
                termination_mismatches += int(
                    bool(result[FAILURE_KEY]) != terminated
                    or bool(result["terminated"]) != terminated
                    or bool(result["truncated"]) != truncated
                )
                observation_mismatches += int(not np.array_equal(result["observation"].numpy(), expected_observation))
                if terminated or truncated:
                    episodes += 1
                    reference.reset()
                tensordict = next_root
        finally:
            env.close()
            reference.close()
    return {
        "env": env_id,
        "kwargs": dict(gym_kwargs),
        "seeds": seeds,
        "steps": compared,
        "episodes": episodes,
        "max_abs_reward_diff": reward_diff,
        "max_abs_term_diff": term_diff,
        "termination_mismatches": termination_mismatches,
        "observation_mismatches": observation_mismatches,
        "seconds": time.perf_counter() - started,
    }


def _number(value: float) -> str:
    return "0" if value == 0 else f"{value:.1e}"


def _row_name(row: object, producer: str, entries: set[str]) -> str:
    """Check one row of ``producer``'s results and return its table name: the env id and its keywords."""
    if not isinstance(row, Mapping):
        raise TypeError(f"rows must be {producer} results (mappings), got {type(row).__name__}")
    missing = {"env", "seeds", "steps", "max_abs_term_diff", *entries} - set(row)
    if missing:
        raise ValueError(f"a row lacks the {producer} entries {sorted(missing)}")
    name = row["env"]
    if row.get("kwargs"):
        name += " (" + ", ".join(f"{key}={value!r}" for key, value in row["kwargs"].items()) + ")"
    return name


def format_parity_table(rows: Iterable[Mapping[str, Any]]) -> str:
    """Render :func:`check_parity` results as a Markdown table (one row per result).

    Term columns follow :data:`TERM_NAMES`; ``–`` marks a term the env does not have.

    Example:
        >>> from torchtasks.parity import format_parity_table
        >>> row = {"env": "Swimmer-v5", "kwargs": {}, "seeds": [0], "steps": 10, "episodes": 0,
        ...        "max_abs_reward_diff": 2.5e-8, "max_abs_term_diff": {"forward": 0.0, "ctrl": 1e-9},
        ...        "termination_mismatches": 0, "observation_mismatches": 0, "seconds": 0.1}
        >>> print(format_parity_table([row]).splitlines()[-1])
        | Swimmer-v5 | 0 | 10 | 0 | 2.5e-08 | 0 | 1.0e-09 | – | – | 0 | 0 | 0.1 |
    """
    header = (
        "| env | seeds | steps | episodes | max abs reward diff | "
        + " | ".join(f"max abs `{name}` diff" for name in TERM_NAMES)
        + " | termination mismatches | observation mismatches | seconds |"
    )
    lines = [header, "|" + "---|" * (header.count("|") - 1)]
    for row in rows:
        name = _row_name(row, "check_parity", {"max_abs_reward_diff"})
        terms = row["max_abs_term_diff"]
        cells = [
            name,
            ",".join(str(seed) for seed in row["seeds"]),
            str(row["steps"]),
            str(row.get("episodes", "")),
            _number(row["max_abs_reward_diff"]),
            *(_number(terms[term]) if term in terms else "–" for term in TERM_NAMES),
            str(row.get("termination_mismatches", "")),
            str(row.get("observation_mismatches", "")),
            f"{row['seconds']:.1f}" if "seconds" in row else "",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


# ------------------------------------------------------------------------------ batched backend
def sync_gymnasium_env(reference: gymnasium.Env, env: BatchedMujocoEnv, index: int) -> np.ndarray:
    """Start a fresh episode of Gymnasium env ``reference`` in batched env ``index``'s state; return its observation.

    Calls ``reference.reset()`` (so Gymnasium's time limit restarts), then copies the batched env's
    ``qpos`` and ``qvel`` with Gymnasium's ``set_state`` (``mj_forward`` included), which leaves the
    Gymnasium ``MjData`` as :class:`~torchtasks.envs.batched_mujoco.BatchedMujocoEnv`'s reset leaves
    it. The returned observation is computed by Gymnasium (its ``_get_obs``) from the copied state.

    Args:
        reference: a Gymnasium MuJoCo env of the same id and keyword arguments.
        env: the batched env.
        index: which of the batched envs, ``0 <= index < env.num_envs``.

    Example:
        >>> import gymnasium, numpy as np
        >>> from torchtasks.envs import BatchedMujocoEnv
        >>> from torchtasks.parity import sync_gymnasium_env
        >>> env = BatchedMujocoEnv("Hopper-v5", num_envs=2, seed=0)
        >>> observation = env.reset()["observation"][1].numpy()
        >>> reference = gymnasium.make("Hopper-v5")
        >>> bool(np.array_equal(sync_gymnasium_env(reference, env, 1), observation))
        True
    """
    if not isinstance(env, BatchedMujocoEnv):
        raise TypeError(f"env must be a BatchedMujocoEnv, got {type(env).__name__}")
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < env.num_envs:
        raise ValueError(f"index must be an int in [0, {env.num_envs}), got {index!r}")
    unwrapped = getattr(reference, "unwrapped", None)
    if not hasattr(unwrapped, "set_state") or not hasattr(unwrapped, "_get_obs"):
        raise TypeError(f"reference must be a Gymnasium MuJoCo env, got {type(reference).__name__}")
    reference.reset()
    unwrapped.set_state(env.batch.qpos[int(index)].copy(), env.batch.qvel[int(index)].copy())
    return unwrapped._get_obs()


def _difference(value: Any, expected: Any) -> float:
    """``max |value - expected|`` over all entries; ``inf`` where exactly one of them is NaN or they differ in shape."""
    value = np.asarray(value, dtype=np.float64)
    expected = np.asarray(expected, dtype=np.float64)
    if value.shape != expected.shape:
        return math.inf
    both_nan = np.isnan(value) & np.isnan(expected)
    difference = np.where(both_nan, 0.0, np.abs(value - expected))
    difference = np.where(np.isnan(difference), math.inf, difference)
    return float(difference.max(initial=0.0))


def _physics_state(env: BatchedMujocoEnv, index: int) -> tuple[float, np.ndarray, np.ndarray]:
    """``(time, qpos, qvel)`` copies of env ``index`` of a batched env."""
    batch = env.batch
    return float(batch.time[index]), batch.qpos[index].copy(), batch.qvel[index].copy()


def _same_physics_state(a: tuple[float, np.ndarray, np.ndarray], b: tuple[float, np.ndarray, np.ndarray]) -> bool:
    return a[0] == b[0] and np.array_equal(a[1], b[1], equal_nan=True) and np.array_equal(a[2], b[2], equal_nan=True)


def _task_transform(env: TransformedEnv) -> TaskTransform:
    transforms = list(env.transform) if isinstance(env.transform, Compose) else [env.transform]
    for transform in transforms:
        if isinstance(transform, TaskTransform):
            return transform
    raise ValueError("env must hold a TaskTransform (e.g. gymnasium_env(env_id, num_envs=N, backend='batched'))")


def _check_forced_resets(forced_resets: object, num_envs: int) -> dict[int, list[int]]:
    if forced_resets is None:
        return {}
    if not isinstance(forced_resets, Mapping):
        raise TypeError(f"forced_resets must be a mapping {{step: [env indices]}}, got {type(forced_resets).__name__}")
    checked: dict[int, list[int]] = {}
    for step, indices in forced_resets.items():
        if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or step < 0:
            raise ValueError(f"forced_resets keys must be non-negative step indices, got {step!r}")
        if isinstance(indices, (str, bytes)) or not isinstance(indices, Iterable):
            raise TypeError(f"forced_resets[{step}] must be a sequence of env indices, got {indices!r}")
        indices = list(indices)
        for index in indices:
            if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < num_envs:
                raise ValueError(f"forced_resets[{step}] must hold env indices in [0, {num_envs}), got {index!r}")
        checked[int(step)] = sorted({int(index) for index in indices})
    return checked


def compare_batched_with_gymnasium(
    env: TransformedEnv,
    steps: int,
    *,
    seed: int = 0,
    forced_resets: Mapping[int, Sequence[int]] | None = None,
    reference_kwargs: Mapping[str, Any] | None = None,
    float64_reference_actions: bool = True,
    tolerance: float = BATCHED_PARITY_TOLERANCE,
) -> dict[str, Any]:
    """Step a batched preset and one plain Gymnasium env per batch entry in lockstep; return the largest differences.

    ``env`` is a ``TransformedEnv`` of a :class:`~torchtasks.envs.batched_mujoco.BatchedMujocoEnv` with a
    :class:`~torchtasks.transforms.TaskTransform` (``gymnasium_env(env_id, num_envs=N, backend="batched")``
    or a hand-built stack). ``N`` references ``gymnasium.make(env_id, **reference_kwargs)`` are made.
    The batched env is reset; after this and every later reset of a batched env (TorchRL's, where an
    episode ended, and the partial resets of ``forced_resets``) the matching reference is put into its
    state with :func:`sync_gymnasium_env`. Then, ``steps`` times, both get the same actions, drawn
    uniformly from the action box by ``numpy.random.default_rng(seed)`` in float32 (TorchRL's
    action dtype), and the batched outputs are compared with Gymnasium's:

    - ``"observation"``: the observation after the step, and the one after every reset;
    - ``"reward"`` and each term ``("task_reward", name)`` with ``reward`` and ``info["reward_<name>"]``;
    - ``"terminated"``, ``"truncated"``, ``"done"`` as 0/1 (the batched ``done`` against Gymnasium's
      ``terminated or truncated``).

    Gymnasium gets the float32 actions as float64 values (``float64_reference_actions``): given a float32
    action, Gymnasium computes its control cost in float32, which is off by up to ~1e-7 relative.
    A Gymnasium env that ends an episode the batched env continues is stepped on (the mismatch is
    counted); a batched env that ends one resyncs its reference as above.

    Args:
        env: the batched env with its task (closed at the end).
        steps: batched steps (``>= 1``).
        seed: seed of the action generator.
        forced_resets: ``{step: [env indices]}``: after step ``step`` (0-based) these envs are reset
            through TorchRL's ``"_reset"`` mask while the others continue.
        reference_kwargs: keyword arguments of ``gymnasium.make`` for the references (e.g. the env's
            Gymnasium keywords and ``max_episode_steps``); ``None``: the batched env's ``gym_kwargs``.
        float64_reference_actions: give Gymnasium the actions as float64 (else float32).
        tolerance: the largest difference that counts as equal (``"passed"`` and ``"first_mismatch"``).

    Returns:
        ``{"env", "kwargs" (the references'), "num_envs", "seeds" ([seed]), "steps" (batched steps),
        "transitions" (compared per env and step), "episodes" (ended by the batched env), "terminated",
        "truncated" (Gymnasium's counts), "forced_resets" (envs reset by ``forced_resets``),
        "max_abs_diff" ({quantity: value} for observation, reward, terminated, truncated, done),
        "max_abs_term_diff" ({term: value}), "partial_reset_problems" (forced resets that changed another
        env's observation or MuJoCo state, or did not restart the step count), "first_mismatch" (where a
        difference first exceeded ``tolerance``, or None), "passed", "seconds"}``.

    Example:
        >>> from torchtasks.envs.locomotion import gymnasium_env
        >>> from torchtasks.parity import compare_batched_with_gymnasium
        >>> env = gymnasium_env("Hopper-v5", num_envs=2, seed=0, backend="batched")
        >>> row = compare_batched_with_gymnasium(env, 40, forced_resets={20: [1]})
        >>> row["passed"], row["forced_resets"], row["max_abs_diff"]["observation"]
        (True, 1, 0.0)
    """
    started = time.perf_counter()
    if not isinstance(env, TransformedEnv) or not isinstance(env.base_env, BatchedMujocoEnv):
        raise TypeError(f"env must be a TransformedEnv of a BatchedMujocoEnv, got {type(env).__name__}")
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise ValueError(f"steps must be a positive int, got {steps!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed!r}")
    if isinstance(tolerance, bool) or not isinstance(tolerance, (int, float)) or not tolerance >= 0:
        raise ValueError(f"tolerance must be a non-negative number, got {tolerance!r}")
    if reference_kwargs is not None and not isinstance(reference_kwargs, Mapping):
        raise TypeError(f"reference_kwargs must be a mapping or None, got {type(reference_kwargs).__name__}")
    base: BatchedMujocoEnv = env.base_env
    n = base.num_envs
    forced = _check_forced_resets(forced_resets, n)
    names = _task_transform(env).task.term_names
    env_id = base.env_id
    kwargs = dict(base.gym_kwargs if reference_kwargs is None else reference_kwargs)
    maxima = dict.fromkeys(_BATCHED_QUANTITIES, 0.0)
    term_maxima = dict.fromkeys(names, 0.0)
    counts = {"episodes": 0, "terminated": 0, "truncated": 0, "forced_resets": 0, "partial_reset_problems": 0}
    first_mismatch: str | None = None

    def record(table: dict[str, float], key: str, value: float, where: str) -> None:
        nonlocal first_mismatch
        table[key] = max(table[key], value)
        if first_mismatch is None and not value <= tolerance:
            first_mismatch = f"{key} differs by {value:.3g} at {where}"

    def resync(observation: torch.Tensor, i: int, where: str) -> None:
        expected = sync_gymnasium_env(references[i], base, i)
        record(maxima, "observation", _difference(observation.numpy(), expected), where)

    references = [make_v5_env(env_id, env_checker=True, **kwargs) for _ in range(n)]
    try:
        for i, reference in enumerate(references):
            reference.reset(seed=seed * n + i)
        tensordict = env.reset()
        for i in range(n):
            resync(tensordict["observation"][i], i, f"env {i} first reset")
        rng = np.random.default_rng(seed)
        low, high = references[0].action_space.low, references[0].action_space.high
        for step in range(steps):
            actions = rng.uniform(low, high, size=(n, low.size)).astype(np.float32)
            tensordict["action"] = torch.from_numpy(actions)
            tensordict, next_root = env.step_and_maybe_reset(tensordict)
            out = tensordict["next"]
            for i, reference in enumerate(references):
                action = actions[i].astype(np.float64) if float64_reference_actions else actions[i]
                observation, reward, terminated, truncated, info = reference.step(action)
                where = f"env {i} step {step}"
                record(maxima, "observation", _difference(out["observation"][i].numpy(), observation), where)
                record(maxima, "reward", _difference(out["reward"][i].item(), reward), where)
                for name in names:
                    value = _difference(out[TERMS_KEY, name][i].item(), info[f"reward_{name}"])
                    record(term_maxima, name, value, f"{where} (term {name!r})")
                ended = bool(out["done"][i].item())
                flags = {
                    "terminated": (bool(out["terminated"][i].item()), bool(terminated)),
                    "truncated": (bool(out["truncated"][i].item()), bool(truncated)),
                    "done": (ended, bool(terminated or truncated)),
                }
                for key, (value, expected) in flags.items():
                    record(maxima, key, float(value != expected), where)
                counts["terminated"] += int(terminated)
                counts["truncated"] += int(truncated)
                if ended:  # TorchRL has reset env i: follow it
                    counts["episodes"] += 1
                    resync(next_root["observation"][i], i, f"env {i} reset after step {step}")
            if forced.get(step):
                mask = torch.zeros(n, 1, dtype=torch.bool)
                mask[forced[step]] = True
                before = next_root["observation"].clone()
                states = [_physics_state(base, i) for i in range(n)]
                next_root.set("_reset", mask)
                next_root = env.reset(next_root)
                kept = ~mask[:, 0]
                changed = not torch.equal(next_root["observation"][kept], before[kept]) or any(
                    not _same_physics_state(states[i], _physics_state(base, i)) for i in range(n) if kept[i]
                )
                restarted = "step_count" not in next_root.keys() or bool(
                    (next_root["step_count"][mask[:, 0]] == 0).all()
                )
                if changed or not restarted:
                    counts["partial_reset_problems"] += 1
                    if first_mismatch is None:
                        first_mismatch = f"the forced reset of envs {forced[step]} after step {step} " + (
                            "changed other envs" if changed else "did not restart the step count"
                        )
                for i in forced[step]:
                    counts["forced_resets"] += 1
                    resync(next_root["observation"][i], i, f"env {i} forced reset after step {step}")
            tensordict = next_root
    finally:
        env.close()
        for reference in references:
            reference.close()
    passed = (
        all(value <= tolerance for value in (*maxima.values(), *term_maxima.values()))
        and counts["partial_reset_problems"] == 0
    )
    return {
        "env": env_id,
        "kwargs": kwargs,
        "num_envs": n,
        "seeds": [int(seed)],
        "steps": int(steps),
        "transitions": int(steps) * n,
        **counts,
        "max_abs_diff": maxima,
        "max_abs_term_diff": term_maxima,
        "first_mismatch": first_mismatch,
        "passed": passed,
        "seconds": time.perf_counter() - started,
    }


def _flag_number(value: float) -> str:
    """A flag difference: ``0`` or ``1`` (0/1 flags), else as :func:`_number`."""
    return str(int(value)) if value in (0.0, 1.0) else _number(value)


def _default_forced_resets(steps: int, num_envs: int) -> dict[int, list[int]]:
    """Reset env 0 after a third of the steps, and envs 0 and ``num_envs - 1`` after two thirds."""
    schedule: dict[int, list[int]] = {}
    for step, indices in ((steps // 3, [0]), ((2 * steps) // 3, [0, num_envs - 1])):
        schedule[step] = sorted(set(schedule.get(step, [])) | set(indices))
    return schedule


def check_batched_parity(
    env_id: str,
    seeds: Sequence[int] = (0, 1, 2),
    steps: int = 1000,
    num_envs: int = 3,
    forced_resets: Mapping[int, Sequence[int]] | None = None,
    **gym_kwargs: Any,
) -> dict[str, Any]:
    """Compare the batched preset with plain Gymnasium for ``steps`` random steps per seed, partial resets included.

    For each seed, ``gymnasium_env(env_id, num_envs=num_envs, seed=seed, backend="batched", **gym_kwargs)``
    and ``num_envs`` envs ``gymnasium.make(env_id, **gym_kwargs)`` are driven in lockstep by
    :func:`compare_batched_with_gymnasium` (same states after every reset, same actions). Episodes end
    as they do in the preset (the task's failure, or the 1000-step limit); on top of that, partial
    resets are forced in the middle of episodes: by default env 0 after a third of the steps and
    envs 0 and ``num_envs - 1`` after two thirds, while the other envs continue.

    Args:
        env_id: a Gymnasium id of :data:`~torchtasks.envs.locomotion.SUPPORTED_ENV_IDS`.
        seeds: the seeds (of the batched env's resets and of the actions), one run each.
        steps: batched steps per seed (``>= 1``).
        num_envs: envs of the batched env (``>= 1``).
        forced_resets: ``{step: [env indices]}`` of partial resets (see
            :func:`compare_batched_with_gymnasium`); ``None``: the default schedule above.
        **gym_kwargs: Gymnasium keyword arguments used by both (e.g. ``ctrl_cost_weight=0.5``).

    Returns:
        the entries of :func:`compare_batched_with_gymnasium`, over all seeds: ``"max_abs_diff"`` and
        ``"max_abs_term_diff"`` are maxima, the counts are sums, ``"first_mismatch"`` is the first
        seed's that has one, ``"passed"`` holds when every difference is at most
        :data:`BATCHED_PARITY_TOLERANCE` and no partial reset disturbed another env.

    Example:
        >>> from torchtasks.parity import check_batched_parity
        >>> row = check_batched_parity("Hopper-v5", seeds=[0], steps=60, num_envs=2)
        >>> row["passed"], row["forced_resets"] >= 1, row["max_abs_diff"]["reward"] <= 1e-9
        (True, True, True)
    """
    gymnasium_config(env_id, gym_kwargs)
    seeds = _check_seeds(seeds)
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise ValueError(f"steps must be a positive int, got {steps!r}")
    if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
        raise ValueError(f"num_envs must be a positive int, got {num_envs!r}")
    schedule = _default_forced_resets(steps, num_envs) if forced_resets is None else forced_resets
    _check_forced_resets(schedule, num_envs)
    started = time.perf_counter()
    rows = []
    for seed in seeds:
        env = gymnasium_env(env_id, num_envs=num_envs, seed=seed, backend="batched", **gym_kwargs)
        rows.append(
            compare_batched_with_gymnasium(env, steps, seed=seed, forced_resets=schedule, reference_kwargs=gym_kwargs)
        )
    result = dict(rows[0])
    result["kwargs"] = dict(gym_kwargs)
    result["seeds"] = seeds
    for key in (
        "steps",
        "transitions",
        "episodes",
        "terminated",
        "truncated",
        "forced_resets",
        "partial_reset_problems",
    ):
        result[key] = sum(row[key] for row in rows)
    for key in ("max_abs_diff", "max_abs_term_diff"):
        result[key] = {name: max(row[key][name] for row in rows) for name in rows[0][key]}
    result["first_mismatch"] = next((row["first_mismatch"] for row in rows if row["first_mismatch"]), None)
    result["passed"] = all(row["passed"] for row in rows)
    result["seconds"] = time.perf_counter() - started
    return result


def batched_parity_passed(row: Mapping[str, Any], tolerance: float = BATCHED_PARITY_TOLERANCE) -> bool:
    """Whether a :func:`check_batched_parity` result meets ``tolerance``: every difference within it, no reset problem.

    Example:
        >>> from torchtasks.parity import batched_parity_passed
        >>> row = {"max_abs_diff": {"observation": 0.0, "reward": 2e-9}, "max_abs_term_diff": {"ctrl": 0.0},
        ...        "partial_reset_problems": 0}
        >>> batched_parity_passed(row), batched_parity_passed(row, tolerance=1e-8)
        (False, True)
    """
    if not isinstance(row, Mapping):
        raise TypeError(f"row must be a check_batched_parity result (a mapping), got {type(row).__name__}")
    missing = {"max_abs_diff", "max_abs_term_diff"} - set(row)
    if missing:
        raise ValueError(f"row lacks the check_batched_parity entries {sorted(missing)}")
    values = [*row["max_abs_diff"].values(), *row["max_abs_term_diff"].values()]
    return all(value <= tolerance for value in values) and not row.get("partial_reset_problems", 0)


def format_batched_parity_table(rows: Iterable[Mapping[str, Any]], tolerance: float = BATCHED_PARITY_TOLERANCE) -> str:
    """Render :func:`check_batched_parity` results as a Markdown table with a PASS/FAIL column.

    Difference columns: the observation, the reward, each term of :data:`TERM_NAMES` (``–`` where the
    env has no such term) and the ``terminated``/``truncated`` flags; ``result`` is ``PASS`` when
    :func:`batched_parity_passed` holds for ``tolerance``.

    Example:
        >>> from torchtasks.parity import format_batched_parity_table
        >>> row = {"env": "Swimmer-v5", "kwargs": {}, "num_envs": 2, "seeds": [0], "steps": 10, "episodes": 0,
        ...        "forced_resets": 1, "max_abs_diff": {"observation": 0.0, "reward": 0.0, "terminated": 0.0,
        ...        "truncated": 1.0, "done": 1.0}, "max_abs_term_diff": {"forward": 0.0, "ctrl": 0.0},
        ...        "partial_reset_problems": 0, "seconds": 0.1}
        >>> print(format_batched_parity_table([row]).splitlines()[-1])
        | Swimmer-v5 | 2 | 0 | 10 | 0 | 1 | 0 | 0 | 0 | 0 | – | – | 0 | 1 | FAIL | 0.1 |
    """
    header = (
        "| env | envs | seeds | steps | episodes | forced resets | max abs observation diff | max abs reward diff | "
        + " | ".join(f"max abs `{name}` diff" for name in TERM_NAMES)
        + " | max abs terminated diff | max abs truncated diff | result | seconds |"
    )
    lines = [header, "|" + "---|" * (header.count("|") - 1)]
    for row in rows:
        name = _row_name(row, "check_batched_parity", {"max_abs_diff"})
        differences, terms = row["max_abs_diff"], row["max_abs_term_diff"]
        cells = [
            name,
            str(row.get("num_envs", "")),
            ",".join(str(seed) for seed in row["seeds"]),
            str(row["steps"]),
            str(row.get("episodes", "")),
            str(row.get("forced_resets", "")),
            *(_number(differences[key]) for key in ("observation", "reward")),
            *(_number(terms[term]) if term in terms else "–" for term in TERM_NAMES),
            *(_flag_number(differences[key]) for key in ("terminated", "truncated")),
            "PASS" if batched_parity_passed(row, tolerance) else "FAIL",
            f"{row['seconds']:.1f}" if "seconds" in row else "",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
