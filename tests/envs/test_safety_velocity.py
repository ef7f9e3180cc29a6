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


from torchtasks.envs import BatchedMujocoEnv  # noqa: E402
from torchtasks.envs.gymnasium_v5 import LOCOMOTION_ENVS, locomotion_record, make_v5_env  # noqa: E402
from torchtasks.parity import sync_gymnasium_env  # noqa: E402

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
#: the velocity is above the threshold in roughly 20-60 % of the steps (Gymnasium's defaults: 0.1, 0.005, ...)
LOCKSTEP_RUNS: dict[str, tuple[float, int]] = {
    "HalfCheetah-v5": (4.0, 8),
    "Hopper-v5": (2.0, 10),
    "Walker2d-v5": (4.0, 8),
    "Swimmer-v5": (0.1, 30),
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
