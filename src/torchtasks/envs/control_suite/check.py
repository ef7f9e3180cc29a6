"""Compare a Control Suite preset with dm_control itself, state by state: what ``torchtasks check <task>`` runs.

:func:`compare_with_dm_control` rolls the preset out (random actions, a little beyond the action bounds since
dm_control does not clip them; partial resets with new targets along the way) and gives dm_control every state the
preset was in: from each state before a step, dm_control's own step (its ``before_step``, ``physics.step``,
``get_reward`` and ``get_observation``, on the model fields the env drew for that episode) must give the preset's
reward, observation entries and next state; each reset state must give its observation. dm_control runs in a
reference venv (:mod:`~torchtasks.envs.control_suite.reference`: dm-control 1.0.50 on MuJoCo 3.17.0), so a step's
physics differs by MuJoCo's version alone (~1e-12 from the same state); everything else must agree to that.
:func:`trajectory_drift` measures how far a whole episode drifts apart when neither side is resynchronised.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from torchrl.envs.utils import step_mdp

from torchtasks.envs.batched_mujoco import BatchedMujocoEnv
from torchtasks.envs.control_suite import control_suite_env, control_suite_record
from torchtasks.envs.control_suite.reference import DmControlReference

__all__ = ["CHECK_TOLERANCE", "compare_with_dm_control", "passed", "physics_state", "trajectory_drift"]

#: the largest difference ``torchtasks check`` accepts between the preset and dm_control, per quantity: one control
#: step from the same state in MuJoCo 4.0.0 and 3.17.0 differs by ~1e-12 (contact-rich steps by more), rounding
#: differences of the formulas are ~1e-16
CHECK_TOLERANCE = 1e-8
#: the model fields the env may give each simulation its own values of (the per-episode targets among them)
_MODEL_FIELDS = ("geom_pos", "site_pos", "body_pos", "body_quat")


def physics_state(env: BatchedMujocoEnv, ids: Sequence[int] | np.ndarray | None = None) -> dict[str, Any]:
    """Copies of what dm_control needs to be in the state of the env's simulations ``ids`` (None: all): ``qpos``,
    ``qvel``, ``act``, ``time``, ``qacc_warmstart`` and the per-simulation model fields (``{name: [n, ...]}``).

    Example:
        >>> from torchtasks.envs.control_suite import control_suite_base_env
        >>> env = control_suite_base_env("reacher-easy", 2, seed=0)
        >>> _ = env.reset()
        >>> state = physics_state(env)
        >>> state["qpos"].shape, sorted(state["model_fields"])
        ((2, 2), ['geom_pos'])
        >>> env.close()
    """
    rows = slice(None) if ids is None else np.asarray(ids)
    batch = env.batch
    state: dict[str, Any] = {
        name: np.array(batch.bind(name)[rows], dtype=np.float64)
        for name in ("qpos", "qvel", "act", "time", "qacc_warmstart")
    }
    state["time"] = state["time"].reshape(-1)
    state["model_fields"] = {
        name: np.array(values[rows]) for name in _MODEL_FIELDS if (values := batch.expanded(name)) is not None
    }
    return state


def _stack(states: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Many :func:`physics_state` results as one."""
    out: dict[str, Any] = {key: np.concatenate([s[key] for s in states]) for key in states[0] if key != "model_fields"}
    out["model_fields"] = {
        name: np.concatenate([s["model_fields"][name] for s in states]) for name in states[0]["model_fields"]
    }
    return out


def _largest(ours: np.ndarray, theirs: np.ndarray) -> float:
    ours, theirs = np.asarray(ours, dtype=np.float64), np.asarray(theirs, dtype=np.float64)
    if ours.shape != theirs.shape:
        raise AssertionError(f"shapes differ: torchtasks {ours.shape}, dm_control {theirs.shape}")
    return float(np.max(np.abs(ours - theirs), initial=0.0))


def compare_with_dm_control(
    name: str | tuple[str, str],
    reference: DmControlReference,
    *,
    num_envs: int = 4,
    steps: int = 100,
    seed: int = 0,
    reset_every: int = 25,
) -> dict[str, Any]:
    """Roll the preset ``name`` out and compare every step and reset with dm_control (see the module docstring).

    Returns ``{"task", "envs", "steps", "states", "reward", "observation": {entry: difference}, "reset_observation":
    {entry: difference}, "physics": {"qpos", "qvel", "act": difference}, "worst"}``: the largest absolute
    differences (``worst`` is the largest of all).

    Args:
        name: the task (``"walker-walk"``).
        reference: a started :class:`~torchtasks.envs.control_suite.reference.DmControlReference`.
        num_envs, steps, seed: the rollout (random actions from a generator of ``seed``).
        reset_every: every this many steps, about half of the envs (drawn) reset.
    """
    record = control_suite_record(name)
    env = control_suite_env(record.name, num_envs, seed=seed)
    base = env.base_env
    keys = list(base.declaration.observation)
    rng = np.random.default_rng(seed)
    low, high = base.model.actuator_ctrlrange[:, 0], base.model.actuator_ctrlrange[:, 1]
    span = high - low
    before, actions, after_obs, rewards, after_state = [], [], [], [], []
    reset_states, reset_obs = [], []
    td = env.reset()
    reset_states.append(physics_state(base))
    reset_obs.append({key: td[key].numpy().copy() for key in keys})
    for t in range(steps):
        if t and t % reset_every == 0:
            mask = rng.random(num_envs) < 0.5
            if mask.any():
                td["_reset"] = torch.from_numpy(mask).reshape(num_envs, 1)
                td = env.reset(td)
                ids = np.flatnonzero(mask)
                reset_states.append(physics_state(base, ids))
                reset_obs.append({key: td[key].numpy()[ids].copy() for key in keys})
        # beyond the bounds by 10% of the range on either side: dm_control writes the action unclipped
        action = rng.uniform(low - 0.1 * span, high + 0.1 * span, size=(num_envs, base.model.nu))
        before.append(physics_state(base))
        actions.append(action)
        td["action"] = torch.from_numpy(action)
        td = env.step(td)
        after_obs.append({key: td["next", key].numpy().copy() for key in keys})
        rewards.append(td["next", "reward"].numpy().reshape(-1).copy())
        after_state.append(physics_state(base))
        td = step_mdp(td)
    env.close()

    stepped = _stack(before)
    # physics_state's keys are evaluate's keyword arguments
    theirs = reference.evaluate(record.domain, record.task, **stepped, action=np.concatenate(actions))
    ours_after = _stack(after_state)
    count = len(ours_after["qpos"])
    observation = {
        key: _largest(np.concatenate([o[key] for o in after_obs]), _flat(theirs["observation"][key], count))
        for key in keys
    }
    started = _stack(reset_states)
    at_reset = reference.evaluate(record.domain, record.task, **started)
    started_count = len(started["qpos"])
    reset_observation = {
        key: _largest(np.concatenate([o[key] for o in reset_obs]), _flat(at_reset["observation"][key], started_count))
        for key in keys
    }
    physics = {field: _largest(ours_after[field], theirs[field]) for field in ("qpos", "qvel", "act")}
    reward = _largest(np.concatenate(rewards), theirs["reward"])
    worst = max(reward, *observation.values(), *reset_observation.values(), *physics.values())
    return {
        "task": record.name,
        "envs": num_envs,
        "steps": steps,
        "states": count + started_count,
        "reward": reward,
        "observation": observation,
        "reset_observation": reset_observation,
        "physics": physics,
        "worst": worst,
    }


def _flat(values: np.ndarray, count: int) -> np.ndarray:
    """dm_control's entry for ``count`` states as ``[count, size]`` (a scalar entry has size 1)."""
    return np.asarray(values, dtype=np.float64).reshape(count, -1)


def trajectory_drift(
    name: str | tuple[str, str],
    reference: DmControlReference,
    *,
    num_envs: int = 2,
    steps: int = 1000,
    seed: int = 0,
) -> dict[str, Any]:
    """How far a whole episode of the preset and of dm_control drift apart from the same start with the same
    actions, never resynchronised: MuJoCo 4.0.0 against 3.17.0, one ~1e-12 difference per step growing with the
    dynamics' sensitivity (chaotic tasks grow fastest).

    Returns ``{"task", "steps", "qpos": [largest |difference| after each step], "first_above": {threshold: step}}``.
    """
    record = control_suite_record(name)
    env = control_suite_env(record.name, num_envs, seed=seed)
    base = env.base_env
    rng = np.random.default_rng(seed)
    low, high = base.model.actuator_ctrlrange[:, 0], base.model.actuator_ctrlrange[:, 1]
    td = env.reset()
    start = physics_state(base)
    actions = rng.uniform(low, high, size=(num_envs, steps, base.model.nu))
    ours = np.empty((num_envs, steps, base.model.nq))
    for t in range(steps):
        td["action"] = torch.from_numpy(actions[:, t])
        td = step_mdp(env.step(td))
        ours[:, t] = base.batch.bind("qpos")
    env.close()
    theirs = reference.rollout(
        record.domain,
        record.task,
        qpos=start["qpos"],
        qvel=start["qvel"],
        act=start["act"],
        time=start["time"],
        model_fields=start["model_fields"],
        actions=actions,
    )
    drift = np.max(np.abs(ours - theirs["qpos"]), axis=(0, 2))
    first = {
        threshold: (int(np.argmax(drift > threshold)) + 1 if (drift > threshold).any() else None)
        for threshold in (1e-9, 1e-6, 1e-3)
    }
    return {
        "task": record.name,
        "steps": steps,
        "qpos": drift.tolist(),
        "first_above": first,
        "final": float(drift[-1]),
    }


def passed(row: Mapping[str, Any], tolerance: float = CHECK_TOLERANCE) -> bool:
    """Whether every difference of a :func:`compare_with_dm_control` row is within ``tolerance``."""
    return math.isfinite(row["worst"]) and row["worst"] <= tolerance
