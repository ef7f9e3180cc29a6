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
from torchtasks.envs.multi_objective import multi_objective_env, multi_objective_record
from torchtasks.transforms import TaskTransform
from torchtasks.transforms.names import FAILURE_KEY, TERMS_KEY, VECTOR_REWARD_KEY

__all__ = [
    "BATCHED_PARITY_TOLERANCE",
    "MO_GYMNASIUM_INSTALL",
    "TERM_NAMES",
    "batched_parity_passed",
    "check_batched_parity",
    "check_multi_objective_parity",
    "check_parity",
    "compare_batched_with_gymnasium",
    "format_batched_parity_table",
    "format_multi_objective_parity_table",
    "format_parity_table",
    "multi_objective_parity_passed",
    "sync_gymnasium_env",
]

#: the reward terms a locomotion preset may have, in table order (Gymnasium's ``info["reward_<name>"]``)
TERM_NAMES: tuple[str, ...] = ("forward", "ctrl", "contact", "survive")

#: largest absolute difference to Gymnasium (observation, reward, terms, flags) that the batched check accepts
BATCHED_PARITY_TOLERANCE = 1e-9

#: largest absolute difference of a float32 reward (the Gymnasium backend's reward spec) to Gymnasium's float64 one
#: (``torchtasks.cli.PARITY_TOLERANCE`` of ``torchtasks check``)
_FLOAT32_REWARD_TOLERANCE = 1e-5

#: the quantities :func:`compare_batched_with_gymnasium` compares besides the reward terms, in table order
_BATCHED_QUANTITIES: tuple[str, ...] = ("observation", "reward", "terminated", "truncated", "done")

#: the name of the vector reward's difference in the results (a vector-reward reference's ``step`` returns it)
VECTOR_REWARD = "vector_reward"

#: how to install the reference of the multi-objective check: MO-Gymnasium 1.3.2 (a test reference of torchtasks,
#: never one of its dependencies; its MuJoCo envs need pygame and scipy, which it does not require itself)
MO_GYMNASIUM_INSTALL = "pip install mo-gymnasium==1.3.2 pygame scipy"


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
    runs = []
    for seed in seeds:
        env = gymnasium_env(env_id, seed=seed, **gym_kwargs)
        reference = make_v5_env(env_id, env_checker=True, **gym_kwargs)
        runs.append(_lockstep_one_env(env, reference, seed, steps))
    term_diff = {name: max(run["term_diff"][name] for run in runs) for name in runs[0]["term_diff"]}
    return {
        "env": env_id,
        "kwargs": dict(gym_kwargs),
        "seeds": seeds,
        "steps": sum(run["steps"] for run in runs),
        "episodes": sum(run["episodes"] for run in runs),
        "max_abs_reward_diff": max(run["max_abs_diff"]["reward"] for run in runs),
        "max_abs_term_diff": term_diff,
        "termination_mismatches": sum(run["termination_mismatches"] for run in runs),
        "observation_mismatches": sum(run["observation_mismatches"] for run in runs),
        "seconds": time.perf_counter() - started,
    }


def _lockstep_one_env(
    env: TransformedEnv,
    reference: gymnasium.Env,
    seed: int,
    steps: int,
    *,
    vector_reward_key: str | None = None,
    forced_resets: Iterable[int] = (),
) -> dict[str, Any]:
    """Step a one-env preset and a Gymnasium env seeded alike with the same actions; return the differences.

    Both are seeded with ``seed`` (the preset by ``set_seed``, the reference by ``reset(seed=seed)``) and reset
    once more, so both draw the same initial states from then on; a Gymnasium episode that ends is restarted
    (TorchRL restarts the preset's), and after the steps in ``forced_resets`` both are reset mid-episode. The
    actions are drawn uniformly from the action box by ``numpy.random.default_rng(seed)`` in float32 (TorchRL's
    dtype). With ``vector_reward_key`` the reference is a vector-reward env: it gets the actions as float64 (so
    that its control cost is computed in float64, as the task computes it), its reward is compared bit for bit
    with ``out[vector_reward_key]`` and the preset's scalar reward with the sum of ``info["reward_<term>"]``.
    Both envs are closed at the end.

    Returns ``{"steps", "episodes", "forced_resets", "termination_mismatches" (the task's failure, TorchRL's
    terminated or truncated differ), "observation_mismatches" (not bit-identical), "vector_reward_mismatches",
    "max_abs_diff" ({quantity: value} as :func:`compare_batched_with_gymnasium`'s), "term_diff" ({term: value}),
    "first_mismatch" (the first vector reward that differs, or None)}``.
    """
    forced = set(forced_resets)
    vector = vector_reward_key is not None
    result: dict[str, Any] = dict.fromkeys(
        ("steps", "episodes", "forced_resets", "termination_mismatches", "observation_mismatches"), 0
    )
    result["vector_reward_mismatches"] = 0
    maxima = result["max_abs_diff"] = dict.fromkeys((*_BATCHED_QUANTITIES, *((VECTOR_REWARD,) if vector else ())), 0.0)
    result["first_mismatch"] = None

    def observed(observation: torch.Tensor, expected: np.ndarray) -> None:
        result["observation_mismatches"] += int(not np.array_equal(observation.numpy(), expected))
        maxima["observation"] = max(maxima["observation"], _difference(observation.numpy(), expected))

    try:
        names = _task_transform(env).task.term_names
        term_diff = result["term_diff"] = dict.fromkeys(names, 0.0)
        reference.reset(seed=seed)
        expected_observation, _ = reference.reset()
        tensordict = env.reset()
        observed(tensordict["observation"], expected_observation)
        rng = np.random.default_rng(seed)
        low, high = reference.action_space.low, reference.action_space.high
        for step in range(steps):
            action = rng.uniform(low, high).astype(reference.action_space.dtype)
            tensordict["action"] = torch.from_numpy(action)
            tensordict, next_root = env.step_and_maybe_reset(tensordict)
            step_action = action.astype(np.float64) if vector else action
            expected_observation, reward, terminated, truncated, info = reference.step(step_action)
            out = tensordict["next"]
            result["steps"] += 1
            scalar = _info_reward(info, names) if vector else float(reward)
            maxima["reward"] = max(maxima["reward"], abs(float(out["reward"]) - scalar))
            for name in names:
                term_diff[name] = max(term_diff[name], abs(float(out[TERMS_KEY, name]) - float(info[f"reward_{name}"])))
            if vector:
                value = out[vector_reward_key].numpy()
                maxima[VECTOR_REWARD] = max(maxima[VECTOR_REWARD], _difference(value, reward))
                if not _bit_identical(value, reward):
                    result["vector_reward_mismatches"] += 1
                    if result["first_mismatch"] is None:
                        result["first_mismatch"] = (
                            f"{VECTOR_REWARD} {value.tolist()} != {np.asarray(reward).tolist()} at step {step}"
                        )
            flags = {
                "terminated": bool(out["terminated"]) != terminated,
                "truncated": bool(out["truncated"]) != truncated,
                "done": bool(out["done"]) != (terminated or truncated),
            }
            for key, differs in flags.items():
                maxima[key] = max(maxima[key], float(differs))
            result["termination_mismatches"] += int(
                bool(out[FAILURE_KEY]) != terminated or flags["terminated"] or flags["truncated"]
            )
            observed(out["observation"], expected_observation)
            if terminated or truncated:
                result["episodes"] += 1
                reference.reset()
            tensordict = next_root
            if step in forced and not (terminated or truncated):  # restart both mid-episode
                result["forced_resets"] += 1
                expected_observation, _ = reference.reset()
                tensordict = env.reset()
                observed(tensordict["observation"], expected_observation)
    finally:
        env.close()
        reference.close()
    return result


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


def _bit_identical(value: Any, expected: Any) -> bool:
    """Whether two arrays are equal bit for bit: the same dtype, shape and bytes (``-0.0 != 0.0``, NaN payloads)."""
    value, expected = np.asarray(value), np.asarray(expected)
    return value.dtype == expected.dtype and value.shape == expected.shape and value.tobytes() == expected.tobytes()


def _info_reward(info: Mapping[str, Any], names: Iterable[str]) -> float:
    """Gymnasium's scalar reward from ``info["reward_<term>"]`` (a vector-reward env's ``step`` returns no scalar)."""
    return float(sum(float(info[f"reward_{name}"]) for name in names))


def _check_vector_reward_options(reference_id: object, vector_reward_key: object) -> None:
    if reference_id is not None and not isinstance(reference_id, str):
        raise TypeError(f"reference_id must be a Gymnasium id (a string) or None, got {reference_id!r}")
    if vector_reward_key is not None and not isinstance(vector_reward_key, str):
        raise TypeError(f"vector_reward_key must be an entry name (a string) or None, got {vector_reward_key!r}")


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
    reference_id: str | None = None,
    vector_reward_key: str | None = None,
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

    With ``vector_reward_key`` the references are vector-reward envs (MO-Gymnasium's, ``reference_id``): the
    reward their ``step`` returns is compared with ``out[vector_reward_key]`` bit for bit (``"vector_reward"``:
    the largest difference, ``"vector_reward_mismatches"``: the transitions whose vectors are not bit-identical,
    dtype included), and ``"reward"`` with the sum of Gymnasium's ``info["reward_<term>"]`` (Gymnasium's scalar
    reward, up to the order of its additions).

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
        reference_id: the Gymnasium id of the references (default: the batched env's), e.g. an MO-Gymnasium id.
        vector_reward_key: the entry of ``env``'s vector reward, compared with the references' rewards as above;
            ``None``: the references return Gymnasium's scalar reward.

    Returns:
        ``{"env", "kwargs" (the references'), "num_envs", "seeds" ([seed]), "steps" (batched steps),
        "transitions" (compared per env and step), "episodes" (ended by the batched env), "terminated",
        "truncated" (Gymnasium's counts), "forced_resets" (envs reset by ``forced_resets``),
        "max_abs_diff" ({quantity: value} for observation, reward, terminated, truncated, done, and
        vector_reward with ``vector_reward_key``), "vector_reward_mismatches" (with ``vector_reward_key``),
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
    _check_vector_reward_options(reference_id, vector_reward_key)
    base: BatchedMujocoEnv = env.base_env
    n = base.num_envs
    forced = _check_forced_resets(forced_resets, n)
    names = _task_transform(env).task.term_names
    env_id = base.env_id
    kwargs = dict(base.gym_kwargs if reference_kwargs is None else reference_kwargs)
    vector = vector_reward_key is not None
    maxima = dict.fromkeys((*_BATCHED_QUANTITIES, *((VECTOR_REWARD,) if vector else ())), 0.0)
    term_maxima = dict.fromkeys(names, 0.0)
    counts = {"episodes": 0, "terminated": 0, "truncated": 0, "forced_resets": 0, "partial_reset_problems": 0}
    if vector:
        counts["vector_reward_mismatches"] = 0
    first_mismatch: str | None = None

    def record(table: dict[str, float], key: str, value: float, where: str) -> None:
        nonlocal first_mismatch
        table[key] = max(table[key], value)
        if first_mismatch is None and not value <= tolerance:
            first_mismatch = f"{key} differs by {value:.3g} at {where}"

    def resync(observation: torch.Tensor, i: int, where: str) -> None:
        expected = sync_gymnasium_env(references[i], base, i)
        record(maxima, "observation", _difference(observation.numpy(), expected), where)

    # Gymnasium's env checker warns about a vector reward (a reward must be a number): not for vector references
    reference_id = env_id if reference_id is None else reference_id
    references = [make_v5_env(reference_id, env_checker=not vector, **kwargs) for _ in range(n)]
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
                scalar = _info_reward(info, names) if vector else reward
                record(maxima, "reward", _difference(out["reward"][i].item(), scalar), where)
                if vector:
                    value = out[vector_reward_key][i].numpy()
                    maxima[VECTOR_REWARD] = max(maxima[VECTOR_REWARD], _difference(value, reward))
                    if not _bit_identical(value, reward):
                        counts["vector_reward_mismatches"] += 1
                        if first_mismatch is None:
                            first_mismatch = (
                                f"{VECTOR_REWARD} {value.tolist()} != {np.asarray(reward).tolist()} at {where}"
                            )
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
        and not counts.get("vector_reward_mismatches", 0)
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
    problems = row.get("partial_reset_problems", 0) or row.get("vector_reward_mismatches", 0)
    return all(value <= tolerance for value in values) and not problems


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


# ------------------------------------------------------------------------------ multi-objective presets
def _import_mo_gymnasium() -> None:
    """Import MO-Gymnasium (which registers its ``mo-*`` ids with Gymnasium), or raise an ImportError saying how."""
    try:
        import mo_gymnasium  # noqa: F401
    except ImportError as error:
        raise ImportError(
            f"the multi-objective check compares with MO-Gymnasium 1.3.2: {MO_GYMNASIUM_INSTALL}"
        ) from error


def check_multi_objective_parity(
    env_id: str,
    seeds: Sequence[int] = (0, 1, 2),
    steps: int = 1000,
    *,
    backend: str = "gymnasium",
    num_envs: int = 3,
    forced_resets: Mapping[int, Sequence[int]] | None = None,
    **gym_kwargs: Any,
) -> dict[str, Any]:
    """Compare a multi-objective preset with MO-Gymnasium 1.3.2 for ``steps`` random steps per seed, resets included.

    ``multi_objective_env(env_id, ..., backend=backend)`` and MO-Gymnasium's ``gymnasium.make(env_id)`` (float64
    actions, so that both compute the control cost in float64) are driven in lockstep:
    ``backend="batched"``: ``num_envs`` envs and one MO-Gymnasium env each, put into the batched env's state after
    every reset (:func:`compare_batched_with_gymnasium`); ``backend="gymnasium"``: one env, seeded as the
    reference is. Resets are forced mid-episode as :func:`check_batched_parity` forces them (one env: at the
    same steps, the whole env). The vector rewards must be bit-identical (``"vector_reward_mismatches"``); the
    scalar reward is compared with the sum of Gymnasium's ``info["reward_<term>"]``, the terms, flags and
    observations as by the other checks. MO-Gymnasium must be installed (:data:`MO_GYMNASIUM_INSTALL`); it is
    a reference of this check only.

    Args:
        env_id: one of :data:`~torchtasks.envs.multi_objective.MULTI_OBJECTIVE_ENV_IDS`.
        seeds: the seeds (of the resets and the actions), one run each.
        steps: steps per seed (batched: steps of all ``num_envs`` envs at once).
        backend: ``"gymnasium"`` or ``"batched"``.
        num_envs: envs of the batched backend.
        forced_resets: ``{step: [env indices]}`` of forced resets; ``None``: after a third and two thirds of the
            steps (env 0, then envs 0 and ``num_envs - 1``).
        **gym_kwargs: the base env's keyword arguments, used by both.

    Returns:
        ``{"env", "kwargs", "backend", "num_envs", "seeds", "steps", "transitions" (env steps compared),
        "episodes", "forced_resets", "vector_reward_mismatches", "max_abs_diff" ({quantity: value} for
        observation, reward, terminated, truncated, done, vector_reward), "max_abs_term_diff", "first_mismatch",
        "seconds"}``; :func:`multi_objective_parity_passed` says whether it passes.

    Example:
        >>> from torchtasks.parity import check_multi_objective_parity, multi_objective_parity_passed
        >>> row = check_multi_objective_parity("mo-hopper-v5", seeds=[0], steps=60, backend="batched", num_envs=2)
        >>> row["transitions"], row["vector_reward_mismatches"], multi_objective_parity_passed(row)
        (120, 0, True)
    """
    record = multi_objective_record(env_id)
    record.groups(gymnasium_config(record.base_id, gym_kwargs))  # the keywords, before MO-Gymnasium is imported
    seeds = _check_seeds(seeds)
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise ValueError(f"steps must be a positive int, got {steps!r}")
    if backend not in ("gymnasium", "batched"):
        raise ValueError(f"backend must be 'gymnasium' or 'batched', got {backend!r}")
    if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
        raise ValueError(f"num_envs must be a positive int, got {num_envs!r}")
    num_envs = num_envs if backend == "batched" else 1
    schedule = _default_forced_resets(steps, num_envs) if forced_resets is None else forced_resets
    schedule = _check_forced_resets(schedule, num_envs)
    _import_mo_gymnasium()
    started = time.perf_counter()
    runs = []
    for seed in seeds:
        env = multi_objective_env(env_id, num_envs=num_envs, seed=seed, backend=backend, **gym_kwargs)
        if backend == "batched":
            run = compare_batched_with_gymnasium(
                env,
                steps,
                seed=seed,
                forced_resets=schedule,
                reference_kwargs=gym_kwargs,
                reference_id=env_id,
                vector_reward_key=VECTOR_REWARD_KEY,
            )
        else:
            reference = make_v5_env(env_id, **gym_kwargs)
            run = _lockstep_one_env(
                env, reference, seed, steps, vector_reward_key=VECTOR_REWARD_KEY, forced_resets=schedule
            )
            run["max_abs_term_diff"] = run.pop("term_diff")
        runs.append(run)
    counts = ("episodes", "forced_resets", "vector_reward_mismatches")
    return {
        "env": env_id,
        "kwargs": dict(gym_kwargs),
        "backend": backend,
        "num_envs": num_envs,
        "seeds": seeds,
        "steps": steps * len(seeds),
        "transitions": steps * len(seeds) * num_envs,
        **{key: sum(run[key] for run in runs) for key in counts},
        "max_abs_diff": {key: max(run["max_abs_diff"][key] for run in runs) for key in runs[0]["max_abs_diff"]},
        "max_abs_term_diff": {
            key: max(run["max_abs_term_diff"][key] for run in runs) for key in runs[0]["max_abs_term_diff"]
        },
        "first_mismatch": next((run["first_mismatch"] for run in runs if run["first_mismatch"]), None),
        "seconds": time.perf_counter() - started,
    }


def multi_objective_parity_passed(row: Mapping[str, Any], reward_tolerance: float | None = None) -> bool:
    """Whether a :func:`check_multi_objective_parity` result passes.

    The vector rewards are bit-identical everywhere, the flags and the observations equal (within
    :data:`BATCHED_PARITY_TOLERANCE`) and the scalar reward and the terms within ``reward_tolerance`` (default:
    :data:`BATCHED_PARITY_TOLERANCE` for the batched backend, whose reward is float64, and 1e-5 for the
    Gymnasium backend, whose reward spec is float32, as ``torchtasks check`` holds it).

    Example:
        >>> from torchtasks.parity import multi_objective_parity_passed
        >>> row = {"backend": "gymnasium", "vector_reward_mismatches": 0, "max_abs_term_diff": {"ctrl": 3e-8},
        ...        "max_abs_diff": {"observation": 0.0, "reward": 2e-7, "done": 0.0, "vector_reward": 0.0}}
        >>> multi_objective_parity_passed(row), multi_objective_parity_passed({**row, "vector_reward_mismatches": 1})
        (True, False)
    """
    if not isinstance(row, Mapping):
        raise TypeError(f"row must be a check_multi_objective_parity result (a mapping), got {type(row).__name__}")
    missing = {"backend", "vector_reward_mismatches", "max_abs_diff", "max_abs_term_diff"} - set(row)
    if missing:
        raise ValueError(f"row lacks the check_multi_objective_parity entries {sorted(missing)}")
    if reward_tolerance is None:
        reward_tolerance = BATCHED_PARITY_TOLERANCE if row["backend"] == "batched" else _FLOAT32_REWARD_TOLERANCE
    rewards = [row["max_abs_diff"]["reward"], *row["max_abs_term_diff"].values()]
    others = [value for key, value in row["max_abs_diff"].items() if key not in ("reward", VECTOR_REWARD)]
    return (
        not row["vector_reward_mismatches"]
        and all(value <= reward_tolerance for value in rewards)
        and all(value <= BATCHED_PARITY_TOLERANCE for value in others)
    )


def format_multi_objective_parity_table(rows: Iterable[Mapping[str, Any]]) -> str:
    """Render :func:`check_multi_objective_parity` results as a Markdown table with a PASS/FAIL column.

    Example:
        >>> from torchtasks.parity import format_multi_objective_parity_table
        >>> row = {"env": "mo-swimmer-v5", "kwargs": {}, "backend": "batched", "num_envs": 2, "seeds": [0],
        ...        "steps": 10, "transitions": 20, "episodes": 0, "forced_resets": 3, "vector_reward_mismatches": 0,
        ...        "max_abs_diff": {"observation": 0.0, "reward": 1e-15, "terminated": 0.0, "truncated": 0.0,
        ...        "done": 0.0, "vector_reward": 0.0}, "max_abs_term_diff": {"forward": 0.0, "ctrl": 0.0},
        ...        "seconds": 0.1}
        >>> print(format_multi_objective_parity_table([row]).splitlines()[-1])
        | mo-swimmer-v5 | batched | 2 | 0 | 20 | 0 | 3 | 0 | 0 | 1.0e-15 | 0 | 0 | 0 | PASS | 0.1 |
    """
    header = (
        "| env | backend | envs | seeds | transitions | episodes | forced resets | vector mismatches | "
        "max abs vector diff | max abs reward diff | max abs term diff | max abs observation diff | "
        "max abs flag diff | result | seconds |"
    )
    lines = [header, "|" + "---|" * (header.count("|") - 1)]
    for row in rows:
        name = _row_name(row, "check_multi_objective_parity", {"max_abs_diff", "vector_reward_mismatches", "backend"})
        differences = row["max_abs_diff"]
        cells = [
            name,
            row["backend"],
            str(row.get("num_envs", "")),
            ",".join(str(seed) for seed in row["seeds"]),
            str(row.get("transitions", "")),
            str(row.get("episodes", "")),
            str(row.get("forced_resets", "")),
            str(row["vector_reward_mismatches"]),
            _number(differences[VECTOR_REWARD]),
            _number(differences["reward"]),
            _number(max(row["max_abs_term_diff"].values(), default=0.0)),
            _number(differences["observation"]),
            _flag_number(max(differences[key] for key in ("terminated", "truncated", "done"))),
            "PASS" if multi_objective_parity_passed(row) else "FAIL",
            f"{row['seconds']:.1f}" if "seconds" in row else "",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
