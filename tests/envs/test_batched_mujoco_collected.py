"""Data collected from the batched MuJoCo presets, recomputed offline.

``gymnasium_env(env_id, num_envs=N)`` (a :class:`BatchedMujocoEnv` under ``StepCounter(1000)``, the
locomotion task's ``TaskTransform`` and ``RewardSum``) is run with random actions by ``env.rollout``,
by a ``Collector``, inside and outside a ``ParallelEnv`` and by a Ray collector. Hopper and Ant under
random actions fall within tens of steps, so TorchRL resets single envs while the others continue
(partial resets); HalfCheetah never falls and runs into the 1000-step limit (it runs with
``exclude_current_positions_from_observation=False``, so that its stored observation holds ``qpos[0]``:
the preset's task state is Gymnasium's ``x_velocity`` only). For every transition:

(a) the reward and each stored term ``("task_reward", name)`` equal

    - the locomotion task evaluated offline on the stored states (``TaskTransform.forward``, the
      task's offline face), and
    - Gymnasium v5's reward formula, written out below from Gymnasium's sources with its default
      weights and evaluated with numpy on the stored ``qpos``/``qvel``/``cfrc_ext``, observations
      and actions: the forward term of HalfCheetah and Hopper from the positions ``qpos[0]`` before and
      after the step, not from the env's ``x_velocity`` (Ant's main-body velocity lags ``qpos`` by a
      substep and is read from the stored ``x_velocity``); the expectation does not come from torchtasks;

(b) episodes end only by the task's failure, which must equal Gymnasium's health condition checked
    here on the stored next state, or by the time limit (``truncated`` exactly where the step count
    reaches 1000), and nowhere else: within an episode the next transition starts from the state the
    previous one ended in, with the step count one higher; after an end it starts at step count 0.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco")
pytest.importorskip("gymnasium")

from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.envs import Compose, ParallelEnv, RewardSum, StepCounter, TransformedEnv

from torchtasks.envs import BatchedMujocoEnv
from torchtasks.envs.locomotion import gymnasium_env, locomotion_state_layout, locomotion_task
from torchtasks.transforms import TaskTransform

pytestmark = pytest.mark.mujoco

ATOL = 1e-9
TIME_LIMIT = 1000

# Gymnasium v5's defaults (gymnasium/envs/mujoco/*_v5.py); dt = model timestep x frame_skip
DT = {"HalfCheetah-v5": 0.01 * 5, "Hopper-v5": 0.002 * 4, "Ant-v5": 0.01 * 5}
FORWARD_WEIGHT = 1.0
CTRL_WEIGHT = {"HalfCheetah-v5": 0.1, "Hopper-v5": 1e-3, "Ant-v5": 0.5}
HEALTHY_REWARD = 1.0
HOPPER_HEALTHY_Z = (0.7, math.inf)  # strict bounds on qpos[1]
HOPPER_HEALTHY_ANGLE = (-0.2, 0.2)  # strict bounds on qpos[2]
HOPPER_HEALTHY_STATE = (-100.0, 100.0)  # strict bounds on (qpos ⊕ qvel)[2:]
ANT_HEALTHY_Z = (0.2, 1.0)  # inclusive bounds on qpos[2], and a finite state
ANT_CONTACT_WEIGHT = 5e-4
ANT_CONTACT_FORCE_RANGE = (-1.0, 1.0)

TERMS = {
    "HalfCheetah-v5": ("forward", "ctrl"),
    "Hopper-v5": ("forward", "ctrl", "survive"),
    "Ant-v5": ("forward", "ctrl", "contact", "survive"),
}


# ------------------------------------------------------------------------ Gymnasium's formulas
def _numpy(data: TensorDictBase, key: Any) -> np.ndarray:
    return data.get(key).detach().cpu().numpy().astype(np.float64)


def gymnasium_healthy(env_id: str, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
    """Gymnasium v5's ``is_healthy`` of the states ``[..., nq]``/``[..., nv]`` (HalfCheetah: always)."""
    if env_id == "HalfCheetah-v5":
        return np.ones(qpos.shape[:-1], dtype=bool)
    state = np.concatenate([qpos, qvel], axis=-1)
    if env_id == "Hopper-v5":
        z, angle, rest = qpos[..., 1], qpos[..., 2], state[..., 2:]
        healthy_state = np.all((HOPPER_HEALTHY_STATE[0] < rest) & (rest < HOPPER_HEALTHY_STATE[1]), axis=-1)
        healthy_z = (HOPPER_HEALTHY_Z[0] < z) & (z < HOPPER_HEALTHY_Z[1])
        healthy_angle = (HOPPER_HEALTHY_ANGLE[0] < angle) & (angle < HOPPER_HEALTHY_ANGLE[1])
        return healthy_state & healthy_z & healthy_angle
    z = state[..., 2]
    return np.isfinite(state).all(axis=-1) & (ANT_HEALTHY_Z[0] <= z) & (z <= ANT_HEALTHY_Z[1])


def x_position(state: TensorDictBase) -> np.ndarray:
    """``qpos[0]`` of stored states: from ``qpos``, or from an observation that starts with it (HalfCheetah)."""
    if "qpos" in state.keys():
        return _numpy(state, "qpos")[..., 0]
    observation = _numpy(state, "observation")
    assert observation.shape[-1] == 18, "HalfCheetah needs exclude_current_positions_from_observation=False"
    return observation[..., 0]


def gymnasium_terms(env_id: str, data: TensorDictBase) -> dict[str, np.ndarray]:
    """Gymnasium v5's ``info["reward_<name>"]`` of every stored transition, shape ``data.shape``."""
    nxt = data["next"]
    action = _numpy(data, "action")
    terms = {"ctrl": -CTRL_WEIGHT[env_id] * np.sum(np.square(action), axis=-1)}
    if env_id == "Ant-v5":
        # the main body's xpos velocity, which lags qpos by a substep: the stored x_velocity (equal to
        # Gymnasium's in the parity tests)
        terms["forward"] = FORWARD_WEIGHT * _numpy(nxt, "x_velocity")[..., 0]
    else:  # Gymnasium's (qpos[0] after - qpos[0] before) / dt, from the stored positions
        terms["forward"] = FORWARD_WEIGHT * (x_position(nxt) - x_position(data)) / DT[env_id]
    if env_id == "Ant-v5":
        forces = np.clip(_numpy(nxt, "cfrc_ext"), *ANT_CONTACT_FORCE_RANGE)
        terms["contact"] = -ANT_CONTACT_WEIGHT * np.sum(np.square(forces), axis=-1)
    if env_id != "HalfCheetah-v5":
        terms["survive"] = HEALTHY_REWARD * stored_healthy(env_id, nxt)
    return terms


def stored_healthy(env_id: str, state: TensorDictBase) -> np.ndarray:
    """:func:`gymnasium_healthy` of stored states (HalfCheetah stores no qpos: it is always healthy)."""
    if env_id == "HalfCheetah-v5":
        return np.ones(state.shape, dtype=bool)
    return gymnasium_healthy(env_id, _numpy(state, "qpos"), _numpy(state, "qvel"))


# ---------------------------------------------------------------------------------- checks
def check_rewards(env_id: str, data: TensorDictBase) -> None:
    """(a): the stored reward and terms against the task offline and Gymnasium's formula."""
    nxt = data["next"]
    # the task, offline, on the stored states, actions and memory
    offline = TaskTransform(locomotion_task(env_id), state_key=list(locomotion_state_layout(env_id)))
    recomputed = offline(data.clone())["next"]
    torch.testing.assert_close(recomputed["reward"], nxt["reward"], rtol=0, atol=ATOL)
    for name in TERMS[env_id]:
        torch.testing.assert_close(recomputed["task_reward", name], nxt["task_reward", name], rtol=0, atol=ATOL)
    for key in ("failure", "terminated", "done"):
        assert torch.equal(recomputed[key], nxt[key]), key
    # Gymnasium's formula
    expected = gymnasium_terms(env_id, data)
    stored_terms = nxt["task_reward"]
    assert set(TERMS[env_id]) <= set(stored_terms.keys())
    for name in TERMS[env_id]:
        np.testing.assert_allclose(_numpy(stored_terms, name)[..., 0], expected[name], rtol=0, atol=ATOL, err_msg=name)
    total = sum(expected.values())
    np.testing.assert_allclose(_numpy(nxt, "reward")[..., 0], total, rtol=0, atol=ATOL)
    # the locomotion tasks pay no final reward, so they write no step/final pair (the terms sum to the reward)
    assert not {"step", "final"} & set(stored_terms.keys())


def check_episode_ends(env_id: str, data: TensorDictBase) -> dict[str, int]:
    """(b): ends only by failure (Gymnasium's health check) or at step count 1000; returns what ended how."""
    nxt = data["next"]
    step_count = data["step_count"][..., 0]
    next_count = nxt["step_count"][..., 0]
    terminated, truncated, done = (nxt[key][..., 0] for key in ("terminated", "truncated", "done"))
    unhealthy = torch.from_numpy(~stored_healthy(env_id, nxt))
    assert torch.equal(nxt["failure"][..., 0], unhealthy), "failure is not Gymnasium's health check"
    assert "success" not in nxt.keys()  # a locomotion task cannot succeed: no success flag is written
    assert torch.equal(terminated, unhealthy)
    assert torch.equal(truncated, next_count == TIME_LIMIT)
    assert torch.equal(done, unhealthy | (next_count == TIME_LIMIT))
    assert torch.equal(next_count, step_count + 1)
    assert (next_count <= TIME_LIMIT).all()
    # continuity along time: an episode goes on from where it was, a new one starts at step count 0
    flat = data.reshape(-1, data.shape[-1])
    ended = flat["next", "done"][:, :-1, 0]
    state, previous_next_state = flat["observation"][:, 1:], flat["next", "observation"][:, :-1]
    same_state = (state == previous_next_state).all(-1)
    assert torch.equal(same_state, ~ended), "a state changed within an episode, or an ended one was continued"
    assert torch.equal(flat["step_count"][:, 1:, 0] == 0, ended)
    partial = ended.any(0) & ~ended.all(0)  # steps where some envs were reset and others continued
    return {
        "failures": int(unhealthy.sum()),
        "truncations": int(truncated.sum()),
        "partial_reset_steps": int(partial.sum()),
    }


def check_collected(env_id: str, data: TensorDictBase) -> dict[str, int]:
    check_rewards(env_id, data)
    return check_episode_ends(env_id, data)


# ------------------------------------------------------------------------ rollout and Collector
#: (env_id, num_envs, steps): Hopper and Ant fall (partial resets), HalfCheetah reaches the time limit
CASES = [("Hopper-v5", 4, 250), ("HalfCheetah-v5", 2, TIME_LIMIT + 20), ("Ant-v5", 3, 250)]
#: Gymnasium keywords of the presets: HalfCheetah observes qpos[0], the forward term is recomputed from it
KWARGS = {"HalfCheetah-v5": {"exclude_current_positions_from_observation": False}}


def _collect(env_id: str, num_envs: int, steps: int, how: str) -> TensorDictBase:
    env = gymnasium_env(env_id, num_envs=num_envs, seed=0, backend="batched", **KWARGS.get(env_id, {}))
    assert isinstance(env.base_env, BatchedMujocoEnv)
    torch.manual_seed(0)
    if how == "rollout":
        try:
            return env.rollout(steps, break_when_any_done=False)
        finally:
            env.close()
    collector = Collector(env, policy=None, frames_per_batch=num_envs * steps, total_frames=num_envs * steps)
    try:
        return next(iter(collector))
    finally:
        collector.shutdown()


@pytest.mark.parametrize("how", ["rollout", "collector"])
@pytest.mark.parametrize(("env_id", "num_envs", "steps"), CASES, ids=[case[0] for case in CASES])
def test_collected_rewards_and_episode_ends(env_id: str, num_envs: int, steps: int, how: str) -> None:
    data = _collect(env_id, num_envs, steps, how)
    assert data.shape == (num_envs, steps)
    assert data["next", "reward"].dtype == torch.float64
    counts = check_collected(env_id, data)
    if env_id == "HalfCheetah-v5":
        assert counts == {"failures": 0, "truncations": num_envs, "partial_reset_steps": 0}
        assert (data["next", "step_count"][:, TIME_LIMIT - 1] == TIME_LIMIT).all()
    else:
        assert counts["failures"] >= num_envs and counts["partial_reset_steps"] > 0, counts
        assert counts["truncations"] == 0


def test_checks_catch_a_wrong_reward_or_a_hidden_episode_end() -> None:
    """The checks are not vacuous: a reward off by 1e-8 and an episode end the task did not cause fail them."""
    data = _collect("Hopper-v5", 2, 60, "rollout")
    check_collected("Hopper-v5", data)
    wrong = data.clone()
    wrong["next", "reward"][0, 10] += 1e-8
    with pytest.raises(AssertionError):
        check_rewards("Hopper-v5", wrong)
    wrong = data.clone()
    wrong["next", "task_reward", "survive"][1, 3] = 1.0 - wrong["next", "task_reward", "survive"][1, 3]
    with pytest.raises(AssertionError):
        check_rewards("Hopper-v5", wrong)
    for key in ("done", "terminated"):
        hidden = data.clone()
        hidden["next", key][0, 5] = ~hidden["next", key][0, 5]
        with pytest.raises(AssertionError):
            check_episode_ends("Hopper-v5", hidden)
    skipped = data.clone()  # a reset that no end explains: the next step starts elsewhere
    skipped["observation"][1, 7] += 1e-3
    with pytest.raises(AssertionError, match="within an episode"):
        check_episode_ends("Hopper-v5", skipped)


def test_gymnasium_formulas_match_gymnasium_itself() -> None:
    """The formulas above reproduce Gymnasium's own ``info`` for stepped Gymnasium envs (so they are Gymnasium's)."""
    import gymnasium
    from tensordict import TensorDict

    rng = np.random.default_rng(0)
    for env_id in TERMS:
        env = gymnasium.make(env_id, **KWARGS.get(env_id, {}))
        observation, _ = env.reset(seed=0)
        data = env.unwrapped.data
        rows: list[dict[str, Any]] = []
        for _ in range(40):
            before = {"observation": observation, "qpos": data.qpos.copy(), "qvel": data.qvel.copy()}
            action = rng.uniform(env.action_space.low, env.action_space.high)
            observation, reward, terminated, _, info = env.step(action)
            after = {"observation": observation, "qpos": data.qpos.copy(), "qvel": data.qvel.copy()}
            after["cfrc_ext"] = data.cfrc_ext.ravel().copy()
            after["x_velocity"] = np.array([info.get("x_velocity", 0.0)])
            rows.append({"before": before, "after": after, "action": action, "reward": reward, "info": info})
            rows[-1]["terminated"] = terminated
            if terminated:
                observation, _ = env.reset()

        def stack(part: str, key: str, rows: list[dict[str, Any]] = rows) -> torch.Tensor:
            return torch.as_tensor(np.stack([row[part][key] for row in rows]))

        keys = ("observation",) if env_id == "HalfCheetah-v5" else ("observation", "qpos", "qvel")
        transitions = TensorDict(
            {
                "action": torch.as_tensor(np.stack([row["action"] for row in rows])),
                **{key: stack("before", key) for key in keys},
                "next": {key: stack("after", key) for key in (*keys, "cfrc_ext", "x_velocity")},
            },
            batch_size=[len(rows)],
        )
        expected = gymnasium_terms(env_id, transitions)
        for name in TERMS[env_id]:
            np.testing.assert_allclose(expected[name], [row["info"][f"reward_{name}"] for row in rows], atol=1e-12)
        np.testing.assert_allclose(sum(expected.values()), [row["reward"] for row in rows], atol=1e-12)
        healthy = stored_healthy(env_id, transitions["next"])
        np.testing.assert_array_equal(~healthy, [row["terminated"] for row in rows])
        env.close()


# ---------------------------------------------------------------------------------- ParallelEnv
def _task_transforms(env_id: str) -> Compose:
    task = locomotion_task(env_id)
    return Compose(
        StepCounter(TIME_LIMIT), TaskTransform(task, state_key=list(locomotion_state_layout(env_id))), RewardSum()
    )


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
@pytest.mark.parametrize("placement", ["inside", "outside"])
def test_parallel_env_of_batched_envs(placement: str) -> None:
    """``ParallelEnv(2, <4 batched Hopper envs>)``: the task in each worker, or once outside on the ``[2, 4]`` batch.

    Outside, the workers are built from a lambda, as a user would write it (TorchRL wraps it in an
    ``EnvCreator``, which builds one env in the main process first and warns about it); inside, from a
    ``functools.partial`` of ``gymnasium_env``. The workers are forked: spawning them (TorchRL's default)
    works the same but costs 3-4 s on an idle 2-core machine and ~20 s on a loaded one; the partials
    are pickled to fresh processes by the Ray test below.
    """
    env_id, steps = "Hopper-v5", 150
    if placement == "inside":
        make = [functools.partial(gymnasium_env, env_id, num_envs=4, seed=i, num_threads=1) for i in range(2)]
        env = ParallelEnv(2, make, mp_start_method="fork")
    else:
        with pytest.warns(UserWarning, match="lambda"):
            parallel = ParallelEnv(
                2, lambda: BatchedMujocoEnv("Hopper-v5", 4, seed=0, num_threads=1), mp_start_method="fork"
            )
        env = TransformedEnv(parallel, _task_transforms(env_id))
    torch.manual_seed(0)
    try:
        data = env.rollout(steps, break_when_any_done=False)
    finally:
        env.close()
    assert data.shape == (2, 4, steps)
    counts = check_collected(env_id, data)
    assert counts["failures"] >= 8 and counts["partial_reset_steps"] > 0, counts
    assert not torch.equal(data["next", "qpos"][0], data["next", "qpos"][1])  # the workers step their own envs


# ------------------------------------------------------------------------------------------ Ray
# the test's policy is a plain callable with no weights: TorchRL's notices about syncing weights do not apply
@pytest.mark.filterwarnings("ignore:The policy is not an nn.Module:UserWarning")
@pytest.mark.filterwarnings("ignore:RayCollector iteration started before weight synchronization:UserWarning")
@pytest.mark.ray
@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
def test_ray_collector_over_batched_envs(ray_cluster) -> None:
    """``Collector(backend="ray")``: two Ray actors, each collecting from its own batched Hopper preset.

    The cluster is shared with the other Ray tests (the ``ray_cluster`` fixture); the two actors importing torch,
    mujoco and gymnasium take most of this test's time on this 2-core machine, the collection under a second.
    """
    make = [functools.partial(gymnasium_env, "Hopper-v5", num_envs=4, seed=i, num_threads=1) for i in range(2)]
    collector = Collector(
        make,
        None,
        backend="ray",
        frames_per_batch=400,
        total_frames=1200,
        remote_configs={"num_cpus": 1, "memory": 512 * 1024**2},
    )
    try:
        batches = [batch.clone() for batch in collector]
    finally:
        collector.shutdown()
    assert [batch.shape for batch in batches] == [torch.Size([4, 100])] * 3
    totals = {"failures": 0, "partial_reset_steps": 0}
    for batch in batches:
        counts = check_collected("Hopper-v5", batch)
        for key in totals:
            totals[key] += counts[key]
    assert totals["failures"] >= 4 and totals["partial_reset_steps"] > 0, totals
