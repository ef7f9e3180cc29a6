"""Parity check of a locomotion preset against plain Gymnasium (``torchtasks check ENV_ID``).

:func:`check_parity` drives :func:`~torchtasks.envs.locomotion.gymnasium_env` and
``gymnasium.make(env_id)`` with the same keyword arguments, the same seed and the same random
actions, resets both whenever an episode ends (terminated, or truncated at 1000 steps), and compares,
step by step, the task reward with Gymnasium's reward, each logged term ``("task_reward", name)``
with Gymnasium's ``info["reward_<name>"]``, the termination flags and the observations.
:func:`format_parity_table` renders the results as a Markdown table.
"""

from __future__ import annotations

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

from torchtasks.envs.locomotion import _config, gymnasium_env

__all__ = ["TERM_NAMES", "check_parity", "format_parity_table"]

#: the reward terms a locomotion preset may have, in table order (Gymnasium's ``info["reward_<name>"]``)
TERM_NAMES: tuple[str, ...] = ("forward", "ctrl", "contact", "survive")


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
    _config(env_id, gym_kwargs)
    seeds = _check_seeds(seeds)
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise ValueError(f"steps must be a positive int, got {steps!r}")
    started = time.perf_counter()
    reward_diff = 0.0
    term_diff: dict[str, float] = {}
    compared = episodes = termination_mismatches = observation_mismatches = 0
    for seed in seeds:
        env = gymnasium_env(env_id, seed=seed, **gym_kwargs)
        reference = gymnasium.make(env_id, **gym_kwargs)
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
                    difference = abs(float(result["task_reward", name]) - float(info[f"reward_{name}"]))
                    term_diff[name] = max(term_diff[name], difference)
                termination_mismatches += int(
                    bool(result["failure"]) != terminated
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
        if not isinstance(row, Mapping):
            raise TypeError(f"rows must be check_parity results (mappings), got {type(row).__name__}")
        missing = {"env", "seeds", "steps", "max_abs_reward_diff", "max_abs_term_diff"} - set(row)
        if missing:
            raise ValueError(f"a row lacks the check_parity entries {sorted(missing)}")
        name = row["env"]
        if row.get("kwargs"):
            name += " (" + ", ".join(f"{key}={value!r}" for key, value in row["kwargs"].items()) + ")"
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
