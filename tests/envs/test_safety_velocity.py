"""Safety velocity presets: Gymnasium v5's reward and termination plus Safety-Gymnasium's velocity cost.

Safety-Gymnasium's ``Safety<Env>Velocity-v1`` (github.com/PKU-Alignment/safety-gymnasium,
``safety_gymnasium/tasks/safe_velocity/safety_<env>_velocity_v1.py`` and the ``_v0`` files they
subclass) pays ``cost = float(velocity > threshold)`` per step, where ``velocity`` is Gymnasium's
``info["x_velocity"]`` (HalfCheetah, Hopper, Walker2d, Swimmer: v1's Swimmer compares x only) or
``np.sqrt(x_velocity**2 + y_velocity**2)`` (Ant, Humanoid). The thresholds and that formula are
written out below from those files, and the expected cost of every step is computed from a plain
``gymnasium.make(env_id)`` env's ``info``: never from torchtasks' records or code.

The lockstep runs drive the batched safety preset, the batched plain preset (``gymnasium_env``) and
one plain Gymnasium env per batch entry with the same actions; after every reset of a batched env
(TorchRL's, or one forced to restart the episode) the Gymnasium env is put into its state with
``torchtasks.parity.sync_gymnasium_env`` (as the batched reward parity tests do). The thresholds are
half of PPO's top speed after 1e7 steps (Safety-Gymnasium's ``docs/environments/safe_velocity.rst``),
which random actions from Gymnasium's initial states rarely or never reach (HalfCheetah, Walker2d and
Humanoid: not once in 300 steps). So the runs widen the initial state distribution with Gymnasium's
own ``reset_noise_scale`` (both envs get it) and restart every episode after a few steps, so that
the velocity is above the threshold in a good share of the steps and below it in the others.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco")
gymnasium = pytest.importorskip("gymnasium")


from tensordict import TensorDictBase  # noqa: E402
from torchrl.collectors import Collector  # noqa: E402

from torchtasks.envs import BatchedMujocoEnv  # noqa: E402
from torchtasks.envs.gymnasium_v5 import LOCOMOTION_ENVS, locomotion_record, make_v5_env  # noqa: E402
from torchtasks.envs.locomotion import (  # noqa: E402
    gymnasium_env,
    locomotion_task,
    safety_velocity_env,
    safety_velocity_task,
)
from torchtasks.parity import sync_gymnasium_env  # noqa: E402
from torchtasks.stats import episode_statistics  # noqa: E402

pytestmark = pytest.mark.mujoco

#: Safety-Gymnasium v1: ``(id, self._velocity_threshold, planar)`` from
#: safety_gymnasium/tasks/safe_velocity/safety_<env>_velocity_v1.py; planar: the norm of x and y velocity
SAFETY_GYMNASIUM_V1: dict[str, tuple[str, float, bool]] = {
    "HalfCheetah-v5": ("SafetyHalfCheetahVelocity-v1", 3.2096, False),
    "Hopper-v5": ("SafetyHopperVelocity-v1", 0.7402, False),
    "Walker2d-v5": ("SafetyWalker2dVelocity-v1", 2.3415, False),
    "Swimmer-v5": ("SafetySwimmerVelocity-v1", 0.2282, False),  # v1's step: x_velocity only (v0: planar)
    "Ant-v5": ("SafetyAntVelocity-v1", 2.6222, True),
    "Humanoid-v5": ("SafetyHumanoidVelocity-v1", 1.4149, True),
}
ENV_IDS = list(SAFETY_GYMNASIUM_V1)

#: the lockstep runs: ``(reset_noise_scale, steps after which each episode is restarted)``, chosen so that
#: the velocity is above the threshold in roughly 20-60 % of the steps (Gymnasium's default noise: 0.1 for
#: HalfCheetah, Swimmer and Ant, 0.005 for Hopper and Walker2d, 0.01 for Humanoid)
LOCKSTEP_RUNS: dict[str, tuple[float, int]] = {
    "HalfCheetah-v5": (4.0, 8),
    "Hopper-v5": (2.0, 10),
    "Walker2d-v5": (4.0, 8),
    "Swimmer-v5": (1.0, 30),
    "Ant-v5": (1.0, 10),
    "Humanoid-v5": (2.0, 10),
}
NUM_ENVS = 2
STEPS = 150
ATOL = 1e-9  # the reward against Gymnasium's (the batched reward parity's tolerance)
#: the share of steps with cost 1 that a run must reach (and leave to cost 0)
MIN_SHARE = 0.1


def safety_gymnasium_cost(env_id: str, info: dict[str, Any]) -> float:
    """Safety-Gymnasium v1's cost of a step from Gymnasium's ``info`` (safety_*_velocity_v0/v1.py ``step``)."""
    _, threshold, planar = SAFETY_GYMNASIUM_V1[env_id]
    x_velocity = info["x_velocity"]
    if planar:
        velocity = np.sqrt(x_velocity**2 + info["y_velocity"] ** 2)
        return float(velocity > threshold)
    return float(x_velocity > threshold)


# ------------------------------------------------------------------------------------ the records
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_records_hold_safety_gymnasiums_v1_thresholds_and_velocities(env_id: str) -> None:
    safety_id, threshold, planar = SAFETY_GYMNASIUM_V1[env_id]
    safety = locomotion_record(env_id).safety_velocity
    assert safety.safety_id == safety_id
    assert safety.threshold == threshold
    assert safety.planar is planar
    assert safety.velocity_keys == (("x_velocity", "y_velocity") if planar else ("x_velocity",))
    name = {"HalfCheetah-v5": "half_cheetah"}.get(env_id, env_id.removesuffix("-v5").lower())
    assert safety.source == f"safety_gymnasium/tasks/safe_velocity/safety_{name}_velocity_v1.py"


def test_every_record_has_a_safety_velocity_constraint() -> None:
    assert set(LOCOMOTION_ENVS) == set(SAFETY_GYMNASIUM_V1)
    assert all(record.safety_velocity is not None for record in LOCOMOTION_ENVS.values())


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_velocity_keys_are_the_velocities_gymnasiums_info_reports(env_id: str) -> None:
    reference = make_v5_env(env_id)
    reference.reset(seed=0)
    info = reference.step(reference.action_space.sample())[-1]
    reference.close()
    record = locomotion_record(env_id)
    assert record.velocity_keys == tuple(key for key in ("x_velocity", "y_velocity") if key in info)
    state_keys = record.safety_state_keys
    assert state_keys[: len(record.safety_velocity.velocity_keys)] == record.safety_velocity.velocity_keys
    assert [key for key in state_keys if key != "y_velocity"] == list(record.state_keys)


# ---------------------------------------------------------------------------- the batched velocities
def _lockstep_velocities(env_id: str, keys: tuple[str, ...], steps: int, **kwargs: Any) -> tuple[float, int]:
    """Step a BatchedMujocoEnv writing ``keys`` and synced Gymnasium envs; return the largest velocity difference."""
    env = BatchedMujocoEnv(env_id, NUM_ENVS, seed=5, task_state_keys=keys, **kwargs)
    references = [make_v5_env(env_id, **kwargs) for _ in range(NUM_ENVS)]
    root = env.reset()
    for i, reference in enumerate(references):
        reference.reset(seed=i)
        sync_gymnasium_env(reference, env, i)
    assert torch.equal(root["y_velocity"], torch.zeros(NUM_ENVS, 1, dtype=torch.float64))
    rng = np.random.default_rng(0)
    low, high = references[0].action_space.low, references[0].action_space.high
    largest, compared = 0.0, 0
    for step in range(steps):
        actions = rng.uniform(low, high, size=(NUM_ENVS, low.size)).astype(np.float32)
        out = env.step(root.set("action", torch.from_numpy(actions)))["next"]
        assert list(out.keys())[: len(keys) + 1] == ["observation", *keys]
        for i, reference in enumerate(references):
            info = reference.step(actions[i].astype(np.float64))[-1]
            for key in ("x_velocity", "y_velocity"):
                largest = max(largest, abs(out[key][i, 0].item() - info[key]))
                compared += 1
        if step % 20 == 19:  # restart env 0 (a partial reset) and its reference
            root = env.reset(out.exclude("reward").set("_reset", torch.tensor([[True], [False]])))
            sync_gymnasium_env(references[0], env, 0)
            assert root["y_velocity"][0, 0].item() == 0.0
        else:
            root = out
    env.close()
    for reference in references:
        reference.close()
    return largest, compared


@pytest.mark.parametrize("env_id", ["Swimmer-v5", "Ant-v5", "Humanoid-v5"])
def test_batched_env_writes_gymnasiums_x_and_y_velocity_bit_for_bit(env_id: str) -> None:
    keys = ("x_velocity", "y_velocity", "qpos")
    largest, compared = _lockstep_velocities(env_id, keys, 60)
    assert compared == 60 * NUM_ENVS * 2 and largest == 0.0


def test_batched_y_velocity_follows_the_main_body_keyword() -> None:
    largest, _ = _lockstep_velocities("Ant-v5", ("x_velocity", "y_velocity"), 40, main_body=2)
    assert largest == 0.0


def test_a_broken_step_writes_zero_velocities() -> None:
    env = BatchedMujocoEnv("Ant-v5", 2, seed=0, task_state_keys=("x_velocity", "y_velocity"))
    root = env.reset()
    action = torch.full((2, 8), 0.5)
    root = env.step(root.set("action", action))["next"].exclude("reward")
    assert (root["x_velocity"] != 0).all() and (root["y_velocity"] != 0).all()
    action[1, 0] = math.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        out = env.step(root.set("action", action))["next"]
    assert out["broken"][:, 0].tolist() == [False, True]
    assert out["x_velocity"][1, 0].item() == out["y_velocity"][1, 0].item() == 0.0
    assert out["y_velocity"][0, 0].item() != 0.0
    env.close()


@pytest.mark.parametrize(
    ("env_id", "keys", "error", "match"),
    [
        ("Hopper-v5", "qpos", TypeError, r"task_state_keys must be a sequence of entry names, got 'qpos'"),
        ("Hopper-v5", ("x_velocity", "y_velocity"), ValueError, r"task_state_keys must be distinct names among"),
        ("Ant-v5", ("qpos", "qpos"), ValueError, r"got \['qpos', 'qpos'\]"),
        ("Ant-v5", (), ValueError, r"task_state_keys must be distinct names"),
        ("Ant-v5", ("xpos",), ValueError, r"\['x_velocity', 'y_velocity', 'qpos', 'qvel', 'cfrc_ext'\] \(Ant-v5\)"),
    ],
)
def test_bad_task_state_keys_are_rejected_by_name(env_id: str, keys: Any, error: type, match: str) -> None:
    with pytest.raises(error, match=match):
        BatchedMujocoEnv(env_id, 1, task_state_keys=keys)


# ------------------------------------------------------------------------ the presets against Gymnasium
def _step(env: Any, root: TensorDictBase, actions: np.ndarray) -> tuple[TensorDictBase, TensorDictBase]:
    root["action"] = torch.from_numpy(actions)
    data, next_root = env.step_and_maybe_reset(root)
    return data["next"], next_root


def _restart(env: Any, root: TensorDictBase, mask: torch.Tensor) -> TensorDictBase:
    return env.reset(root.set("_reset", mask))


def _lockstep(env_id: str, seed: int, steps: int) -> dict[str, Any]:
    """The safety preset, the plain preset and synced Gymnasium envs, stepped with the same actions.

    Asserts, for every transition: the safety preset's observation equals Gymnasium's (bit for bit: the
    two simulations are in the same state) and the plain preset's; its reward, terms and flags equal the
    plain preset's bit for bit, its reward Gymnasium's within ``ATOL`` and ``terminated``/``truncated``
    Gymnasium's; its ``y_velocity`` (Ant, Humanoid) Gymnasium's ``info["y_velocity"]``. Returns the
    preset's costs and Safety-Gymnasium's costs from Gymnasium's ``info``.
    """
    noise, restart_every = LOCKSTEP_RUNS[env_id]
    kwargs = {"reset_noise_scale": noise}
    safety = safety_velocity_env(env_id, num_envs=NUM_ENVS, seed=seed, backend="batched", **kwargs)
    plain = gymnasium_env(env_id, num_envs=NUM_ENVS, seed=seed, backend="batched", **kwargs)
    references = [make_v5_env(env_id, **kwargs) for _ in range(NUM_ENVS)]
    names = plain.transform[1].task.term_names
    assert safety.transform[1].task.term_names == names
    planar = SAFETY_GYMNASIUM_V1[env_id][2]
    out: dict[str, list[float]] = {"cost": [], "cost_entry": [], "expected": [], "terminated": []}
    try:
        root, plain_root = safety.reset(), plain.reset()
        for i, reference in enumerate(references):
            reference.reset(seed=seed * NUM_ENVS + i)
            expected = sync_gymnasium_env(reference, safety.base_env, i)
            np.testing.assert_array_equal(root["observation"][i].numpy(), expected)
        assert torch.equal(root["observation"], plain_root["observation"])
        rng = np.random.default_rng(seed)
        low, high = references[0].action_space.low, references[0].action_space.high
        age = np.arange(NUM_ENVS) * (restart_every // NUM_ENVS)  # staggered episode starts
        for step in range(steps):
            actions = rng.uniform(low, high, size=(NUM_ENVS, low.size)).astype(np.float32)
            result, root = _step(safety, root, actions)
            plain_result, plain_root = _step(plain, plain_root, actions)
            for key in ("observation", "reward", "terminated", "truncated", "done", "failure", "episode_reward"):
                assert torch.equal(result[key], plain_result[key]), f"{key} differs from the plain preset at {step}"
            for name in names:
                assert torch.equal(result["task_reward", name], plain_result["task_reward", name]), name
            age += 1
            for i, reference in enumerate(references):
                where = f"{env_id} seed {seed} env {i} step {step}"
                observation, reward, terminated, truncated, info = reference.step(actions[i].astype(np.float64))
                np.testing.assert_array_equal(result["observation"][i].numpy(), observation, err_msg=where)
                assert abs(result["reward"][i, 0].item() - reward) <= ATOL, where
                assert result["terminated"][i, 0].item() == terminated, where
                assert result["truncated"][i, 0].item() == truncated, where
                if planar:
                    assert result["y_velocity"][i, 0].item() == info["y_velocity"], where
                out["cost"].append(result["task_cost", "velocity"][i, 0].item())
                out["cost_entry"].append(result["cost"][i, 0].item())
                out["expected"].append(safety_gymnasium_cost(env_id, info))
                out["terminated"].append(float(terminated))
                if result["done"][i, 0].item():  # TorchRL has reset env i: follow it
                    age[i] = 0
                    sync_gymnasium_env(reference, safety.base_env, i)
            restart = age >= restart_every
            if restart.any():
                mask = torch.from_numpy(restart).reshape(NUM_ENVS, 1)
                root, plain_root = _restart(safety, root, mask.clone()), _restart(plain, plain_root, mask.clone())
                assert torch.equal(root["observation"], plain_root["observation"])
                for i in np.flatnonzero(restart):
                    age[i] = 0
                    expected = sync_gymnasium_env(references[i], safety.base_env, int(i))
                    np.testing.assert_array_equal(root["observation"][i].numpy(), expected)
    finally:
        for env in (safety, plain):
            env.close()
        for reference in references:
            reference.close()
    return out


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_the_cost_is_safety_gymnasiums_formula_on_gymnasiums_info(env_id: str) -> None:
    out = _lockstep(env_id, seed=0, steps=STEPS)
    cost, expected = np.asarray(out["cost"]), np.asarray(out["expected"])
    assert cost.size == STEPS * NUM_ENVS
    np.testing.assert_array_equal(cost, expected)
    np.testing.assert_array_equal(np.asarray(out["cost_entry"]), expected)
    # the velocity is above the threshold in a good share of the steps, and below it in a good share
    share = expected.mean()
    assert MIN_SHARE <= share <= 1.0 - MIN_SHARE, f"{env_id}: cost 1 in {share:.0%} of the steps"


def test_the_gymnasium_backend_reads_the_velocities_from_info() -> None:
    """One Gymnasium env in a GymWrapper (Float64InfoReader): Ant's planar speed from info, seeded like Gymnasium."""
    env_id, seed = "Ant-v5", 3
    kwargs = {"reset_noise_scale": LOCKSTEP_RUNS[env_id][0]}
    env = safety_velocity_env(env_id, seed=seed, backend="gymnasium", **kwargs)
    reference = make_v5_env(env_id, **kwargs)
    reference.reset(seed=seed)
    reference.reset()
    root = env.reset()
    costs, expected = [], []
    rng = np.random.default_rng(seed)
    for _ in range(60):
        action = rng.uniform(reference.action_space.low, reference.action_space.high).astype(np.float32)
        result, root = _step(env, root, action)
        _, _, terminated, truncated, info = reference.step(action)
        costs.append(result["cost"][0].item())
        expected.append(safety_gymnasium_cost(env_id, info))
        assert result["y_velocity"][0].item() == info["y_velocity"]
        if terminated or truncated:
            reference.reset()
    env.close()
    reference.close()
    assert costs == expected and 0.0 in expected and 1.0 in expected


# ---------------------------------------------------------------------------------- the task itself
def _formula(env_id: str, state: np.ndarray, labels: list[str]) -> np.ndarray:
    """Safety-Gymnasium's cost of task states whose entries are named by ``labels``."""
    _, threshold, planar = SAFETY_GYMNASIUM_V1[env_id]
    x_velocity = state[..., labels.index("x_velocity")]
    if planar:
        y_velocity = state[..., labels.index("y_velocity")]
        return (np.sqrt(x_velocity**2 + y_velocity**2) > threshold).astype(np.float64)
    return (x_velocity > threshold).astype(np.float64)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_the_task_keeps_the_locomotion_reward_and_adds_the_velocity_cost(env_id: str) -> None:
    task, plain = safety_velocity_task(env_id), locomotion_task(env_id)
    assert task.cost_names == ("velocity",) and task.cost_limits == {"velocity": 25.0}
    assert task.term_names == plain.term_names
    labels, plain_labels = list(task.spec.state_space.labels), list(plain.spec.state_space.labels)
    planar = SAFETY_GYMNASIUM_V1[env_id][2]
    assert labels == (["x_velocity", "y_velocity", *plain_labels[1:]] if planar else plain_labels)
    # random states: reward, terms and flags are the plain task's on the same entries, the cost the formula
    generator = torch.Generator().manual_seed(0)
    state = torch.randn(256, task.state_size, generator=generator, dtype=torch.float64)
    threshold = SAFETY_GYMNASIUM_V1[env_id][1]
    state[:, : 1 + planar] *= threshold * (1.0 if planar else 2.0)  # velocities on both sides of the threshold
    action = torch.randn(256, task.action_size, generator=generator, dtype=torch.float64)
    plain_state = state[:, [labels.index(label) for label in plain_labels]]
    out = task.transition(state, action, state, task.reset(state))
    want = plain.transition(plain_state, action, plain_state, plain.reset(plain_state))
    for key in ("reward", "step_reward", "final_reward", "success", "failure", "terminated", "done"):
        assert torch.equal(getattr(out, key), getattr(want, key)), key
    assert out.terms.keys() == want.terms.keys() and all(torch.equal(out.terms[k], want.terms[k]) for k in want.terms)
    expected = _formula(env_id, state.numpy(), labels)
    assert 0.2 < expected.mean() < 0.8
    np.testing.assert_array_equal(out.costs["velocity"].numpy(), expected)


def test_the_cost_limit_is_a_keyword() -> None:
    assert safety_velocity_task("Hopper-v5", cost_limit=10).cost_limits == {"velocity": 10.0}
    assert safety_velocity_task("Hopper-v5", cost_limit=None).cost_limits == {"velocity": None}
    with pytest.raises(ValueError, match=r"cost_limit must be non-negative, got -1"):
        safety_velocity_task("Hopper-v5", cost_limit=-1)
    with pytest.raises(TypeError, match=r"cost_limit"):
        safety_velocity_env("Hopper-v5", cost_limit="25")
    with pytest.raises(TypeError, match=r"unexpected keyword argument\(s\) \['cost_limt'\]"):
        safety_velocity_task("Hopper-v5", cost_limt=25.0)


@pytest.mark.parametrize("env_id", ["Hopper-v5", "Humanoid-v5"])
def test_a_task_step_compiles_with_fullgraph(env_id: str) -> None:
    torch._dynamo.reset()
    task = safety_velocity_task(env_id)
    generator = torch.Generator().manual_seed(1)
    state = torch.randn(4, task.state_size, generator=generator, dtype=torch.float64)
    next_state = state + torch.randn(4, task.state_size, generator=generator, dtype=torch.float64)
    action = torch.zeros(4, task.action_size, dtype=torch.float64)
    remaining = torch.zeros((), dtype=torch.long)
    compiled = torch.compile(task.transition, fullgraph=True, backend="aot_eager")
    got = compiled(state, action, next_state, task.reset(state), remaining)
    want = task.transition(state, action, next_state, task.reset(state), remaining)
    assert torch.equal(got.costs["velocity"], want.costs["velocity"]) and torch.equal(got.reward, want.reward)


# ------------------------------------------------------------------------------------ collected data
#: dt = model timestep x frame_skip of Gymnasium v5's defaults (gymnasium/envs/mujoco/*_v5.py)
DT = {"Swimmer-v5": 0.01 * 4, "Hopper-v5": 0.002 * 4}


def _numpy(data: TensorDictBase, key: Any) -> np.ndarray:
    return data.get(key).detach().cpu().numpy().astype(np.float64)


def _offline_cost(env_id: str, data: TensorDictBase) -> np.ndarray:
    """Safety-Gymnasium's formula on the stored states: x from the positions before and after each step.

    Swimmer and Hopper: ``(qpos[0] after - qpos[0] before) / dt`` (Swimmer's from its observation,
    which holds ``qpos[0]`` with ``exclude_current_positions_from_observation=False``); Ant: its stored
    ``x_velocity``/``y_velocity`` (the torso's ``xpos`` lags ``qpos`` by a substep, so it is not in the state).
    """
    _, threshold, planar = SAFETY_GYMNASIUM_V1[env_id]
    if planar:
        x_velocity, y_velocity = _numpy(data, ("next", "x_velocity")), _numpy(data, ("next", "y_velocity"))
        return (np.sqrt(x_velocity**2 + y_velocity**2) > threshold).astype(np.float64)
    key = "observation" if env_id == "Swimmer-v5" else "qpos"
    before, after = _numpy(data, key)[..., :1], _numpy(data, ("next", key))[..., :1]
    return ((after - before) / DT[env_id] > threshold).astype(np.float64)


COLLECTED = {
    "Hopper-v5": {"reset_noise_scale": LOCKSTEP_RUNS["Hopper-v5"][0]},
    "Swimmer-v5": {"exclude_current_positions_from_observation": False},
    "Ant-v5": {"reset_noise_scale": LOCKSTEP_RUNS["Ant-v5"][0]},
}


@pytest.mark.parametrize("how", ["rollout", "collector"])
@pytest.mark.parametrize("env_id", list(COLLECTED))
def test_collected_costs_equal_the_formula_on_the_stored_states(env_id: str, how: str) -> None:
    num_envs, steps = 4, 100
    env = safety_velocity_env(env_id, num_envs=num_envs, seed=2, backend="batched", **COLLECTED[env_id])
    assert isinstance(env.base_env, BatchedMujocoEnv)
    torch.manual_seed(0)
    if how == "rollout":
        data = env.rollout(steps, break_when_any_done=False)
        env.close()
    else:
        collector = Collector(env, policy=None, frames_per_batch=num_envs * steps, total_frames=num_envs * steps)
        data = next(iter(collector))
        collector.shutdown()
    assert data["next", "cost"].shape == (num_envs, steps, 1)
    expected = _offline_cost(env_id, data)
    np.testing.assert_array_equal(_numpy(data, ("next", "cost")), expected)
    np.testing.assert_array_equal(_numpy(data, ("next", "task_cost", "velocity")), expected)
    assert 0.0 < expected.mean() < 1.0  # both costs occur
    # the episode statistics sum the same costs: the mean over the episodes that ended of their summed cost
    done = _numpy(data, ("next", "done"))[..., 0] > 0
    sums = []
    for row_cost, row_done in zip(expected[..., 0], done, strict=True):
        total = 0.0
        for cost, ended in zip(row_cost, row_done, strict=True):
            total += cost
            if ended:
                sums.append(total)
                total = 0.0
    if sums:
        stats = episode_statistics(data, cost_limits={"velocity": 2.0})
        assert stats["cost_mean/velocity"] == pytest.approx(np.mean(sums), rel=1e-12)
        assert stats["cost_violation_rate/velocity"] == pytest.approx(np.mean(np.asarray(sums) > 2.0), rel=1e-12)
    else:
        assert env_id == "Swimmer-v5"  # never falls: no episode ends in 100 steps
